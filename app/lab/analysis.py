"""The lab's Analysis tab: analyses of the current state, run on their own thread.

The engine thread takes the state (a snapshot, or the replayed frame read from its run file) and
hands it to :class:`AnalysisRunner`, whose single worker thread runs
:func:`granlab.engine.analysis.report.analyze`; neither the engine nor the UI waits for it. Each result
gets a sequence number; tabs poll :meth:`AnalysisRunner.latest` and redraw when it changes.
The functions below turn a result into what the plots and the 3D scene draw.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from html import escape
from dataclasses import dataclass

import numpy as np

from granlab.engine.analysis.report import AnalysisReport, analyze
from granlab.engine.analysis.states import PackingState
from granlab.engine.errors import GranLabError

SQRT3 = float(np.sqrt(3.0))
ANALYSIS_THREADS = max(1, (os.cpu_count() or 1) - 1)
"""Threads of an analysis (numba, FFT, BLAS): the cores the engine's one thread leaves free."""


@dataclass(frozen=True)
class AnalysisResult:
    """``seq`` (1, 2, ...), ``kind``, the analysed ``state``, the ``report`` or an ``error``."""

    seq: int
    kind: str
    state: PackingState | None
    report: AnalysisReport | None
    error: str = ""


class AnalysisRunner:
    """One worker thread; a request while one runs is queued behind it."""

    def __init__(self, on_done=None):
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="granlab-analysis")
        self._lock = threading.Lock()
        self._seq = 0
        self._latest = AnalysisResult(0, "", None, None)
        self._on_done = on_done
        self.busy = False

    def request(self, state: PackingState | Callable[[], PackingState], kind: str) -> None:
        """Analyse ``state`` (or the state a function returns: a frame read from a file is read on
        the analysis thread too)."""
        self.busy = True
        self._pool.submit(self._run, state, kind)

    def latest(self) -> AnalysisResult:
        with self._lock:
            return self._latest

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)

    def _run(self, state, kind: str) -> None:
        try:
            state = state() if callable(state) else state
            report, error = analyze(state, kind, threads=ANALYSIS_THREADS), ""
        except (GranLabError, ValueError, MemoryError) as failure:
            state = state if isinstance(state, PackingState) else None
            report, error = None, str(failure)
        with self._lock:
            self._seq += 1
            self._latest = AnalysisResult(self._seq, kind, state, report, error)
        self.busy = False
        if self._on_done is not None:
            self._on_done(self._latest)


def summary(result: AnalysisResult) -> str:
    """HTML: what was analysed and how long it took, then a table of the report's rows (label,
    value, and why a value is missing)."""
    if result.error:
        return f"<p><b>{escape(result.kind)}</b>: {escape(result.error)}</p>"
    head = (f"<p><b>{escape(result.kind)}</b> of {escape(result.state.source)} at t = {result.state.time:.4g} "
            f"({result.state.disks} disks), {result.report.timings['total']:.2f} s</p>")
    rows = "".join(f"<tr><td style='padding:2px 10px 2px 0'>{escape(row.label)}</td><td><b>{escape(row.text)}</b>"
                   + (f" <span style='color:#666'>({escape(row.note)})</span>" if row.note else "") + "</td></tr>"
                   for row in result.report.rows())
    return head + f"<table style='font-size:13px;border-collapse:collapse'>{rows}</table>"


def network_segments(result: AnalysisResult) -> dict:
    """Columns for the force-network plot of a status analysis: one segment per contact from the
    centre of its first disk towards the second (or the wall), coloured by the status the solver
    found; critical contacts get a marker, red where the solver and the dynamics disagree."""
    found, state = result.report.result, result.state
    net, critical = found.network, found.solution.critical
    first, second = net.first, net.second
    start = state.positions[first]
    reach = state.radii[first] + np.where(second >= 0, state.radii[np.maximum(second, 0)], 0.0)
    end = start - net.normal * reach[:, None]
    sliding = found.solution.sliding
    disagree = sliding[critical] != net.sliding[critical]
    middle = 0.5 * (start + end)[critical]
    return {"segments": {"x0": start[:, 0], "y0": start[:, 1], "x1": end[:, 0], "y1": end[:, 1],
                         "color": np.where(sliding, "#d62728", "#1f77b4")},
            "critical": {"x": middle[:, 0], "y": middle[:, 1],
                         "color": np.where(disagree, "#d62728", "#ff7f0e")}}


def force_scatter(result: AnalysisResult) -> dict:
    """(N, T) of every disk-disk interaction and the lines T = ±sqrt(3) N (Gilabert Fig. 14)."""
    normal, tangential = result.report.result.normal, result.report.result.tangential
    top = float(np.abs(normal).max()) if len(normal) else 1.0
    return {"points": {"normal": normal, "tangential": tangential},
            "lines": {"xs": [[-top, top], [-top, top]], "ys": [[-SQRT3 * top, SQRT3 * top],
                                                            [SQRT3 * top, -SQRT3 * top]]}}


def structure_curve(result: AnalysisResult) -> dict:
    """I(k) and its fit by Gilabert Eq. 28 (positive values, for log axes)."""
    fractal = result.report.result
    keep = (fractal.k > 0) & (fractal.intensity > 0)
    return {"data": {"k": fractal.k[keep], "intensity": fractal.intensity[keep]},
            "fit": {"k": fractal.k[keep], "fitted": fractal.fitted[keep]}}


def mechanism_arrows(result: AnalysisResult, head: float = 0.3) -> np.ndarray:
    """(S, 2, 2) segments: an arrow on each disk along the translation of the mode the stiffness
    analysis draws (:attr:`granlab.engine.analysis.stiffness.Mechanisms.drawn_mode`; none without
    one), the longest one disk diameter long; each arrow is a shaft and two head strokes."""
    mode, state = result.report.result.drawn_mode, result.state
    if mode is None:
        return np.zeros((0, 2, 2))
    n = state.disks
    v = np.column_stack([mode[0:3 * n:3], mode[1:3 * n:3]])
    size = np.hypot(v[:, 0], v[:, 1])
    top = float(size.max())
    if top == 0.0:
        return np.zeros((0, 2, 2))
    moving = size > 1e-3 * top
    start = state.positions[moving]
    shaft = v[moving] * (2.0 * float(state.radii.mean()) / top)
    tip = start + shaft
    back = -head * shaft
    side = np.column_stack([-back[:, 1], back[:, 0]]) * 0.5
    return np.concatenate([np.stack([start, tip], axis=1), np.stack([tip, tip + back + side], axis=1),
                           np.stack([tip, tip + back - side], axis=1)])
