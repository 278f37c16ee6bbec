"""One analysis of one state, as ``granlab analyze`` prints it and the lab's Analysis tab shows it.

:func:`analyze` runs an analysis of the registry :data:`granlab.engine.analysis.ANALYSES` and returns
an :class:`AnalysisReport`: ``values`` (JSON scalars and short lists, what ``--json`` prints, NaN
and None included), ``result`` (the analysis's own dataclass, with the arrays the lab's plots, the
scene and a notebook read), the wall time of each stage, and, for people:

- ``reasons``: why a value is missing (NaN, inf, None, or a number that stands for nothing, such
  as z* without a backbone), recorded by the analysis that knows it;
- :meth:`AnalysisReport.rows`: one :class:`Row` ``(key, label, text, note)`` per value. ``label``
  comes from the analysis module's ``LABELS``: words, the paper's symbol and equation, and a unit in
  brackets — ``[length]``, ``[force]``, ``[force/length]`` (a 2D stress), ``[length²]``,
  ``[1/length]`` in the state's own units (for Gilabert's preparations the paper's a and F0, or Pa
  without cohesion), ``[degrees]`` or ``[dimensionless]``; counts have none. ``text`` is the value
  (4 significant digits, "yes"/"no", lists in words, or the analysis's own words in ``texts``) or
  "—" when it is missing, and then ``note`` says why; ``note`` also carries the message of a
  failed fit or a skipped enumeration;
- ``figures``: the pictures the report can draw, among :data:`FIGURES`.

The analyses themselves, and the load increment of ``stiffness`` and ``status``, are described in
their modules (:mod:`~granlab.engine.analysis.stiffness`, :mod:`~granlab.engine.analysis.status`,
:mod:`~granlab.engine.analysis.rigidity`, :mod:`~granlab.engine.analysis.packing`,
:mod:`~granlab.engine.analysis.fractal`).
"""

from __future__ import annotations

import math
import os
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import ParameterError
from . import ANALYSES

FIGURES = ("network", "forces", "structure", "mechanism")
"""What a report can draw: ``network`` the contacts coloured by the status minimum sliding gives
(status); ``forces`` the (N, T) of every interaction with T = ±sqrt(3) N (packing, with forces,
Gilabert Fig. 14); ``structure`` I(k) and its fit (fractal, unless the grid is all solid: I(k) is then zero);
``mechanism`` arrows along the mode that collapses the packing, or else the first null mode of k
(stiffness, when that mode moves disks)."""

MISSING = "—"
"""The text of a value that is missing; its row's note says why."""


def label(kind: str, key: str) -> str:
    """The label of the value ``key`` of the analysis ``kind`` (its module's ``LABELS``); the key
    itself if it has none."""
    return ANALYSES[kind].load().LABELS.get(key, key) if kind in ANALYSES else key


@dataclass(frozen=True)
class Row:
    """One value of a report for people: its ``key`` in ``values``, its ``label``, its ``text``
    (``MISSING`` when there is none) and a ``note`` (why it is missing, or the message of a failed
    fit or a skipped enumeration; empty otherwise)."""

    key: str
    label: str
    text: str
    note: str = ""


@dataclass
class AnalysisReport:
    """``kind``, ``values`` (JSON-able), ``result`` (the analysis's own dataclass), ``timings``
    (seconds per stage), ``reasons`` (key -> why that value is missing), ``texts`` (key -> the
    value in the analysis's own words) and ``figures`` (among :data:`FIGURES`)."""

    kind: str
    values: dict
    result: Any = None
    timings: dict = field(default_factory=dict)
    reasons: dict = field(default_factory=dict)
    texts: dict = field(default_factory=dict)
    figures: tuple[str, ...] = ()

    def as_dict(self) -> ReportDict:
        return ReportDict(self, {"analysis": self.kind, **self.values, "timings_s": self.timings})

    def rows(self) -> list[Row]:
        """One :class:`Row` per value, in the order of ``values``."""
        return [self._row(key, value) for key, value in self.values.items()]

    def _row(self, key: str, value) -> Row:
        name = label(self.kind, key)
        if key in self.reasons:
            return Row(key, name, MISSING, self.reasons[key])
        if key in self.texts:
            return Row(key, name, self.texts[key])
        if key == "fit_error":
            return Row(key, name, "failed" if value else "converged", value)
        if key == "enumeration_skipped":
            return Row(key, name, "skipped", value)
        if key == "coordination":
            return Row(key, name, ", ".join(f"x_{k} = {x:.4g}" for k, x in enumerate(value)))
        if key.endswith("_histogram"):
            edges, fractions = value
            return Row(key, name, f"{len(fractions)} bins from {edges[0]:.4g} to {edges[-1]:.4g}")
        if key == "fit_range":
            return Row(key, name, " to ".join(_number_text(v) for v in value))
        if isinstance(value, (tuple, list)):
            return Row(key, name, " × ".join(_number_text(v) for v in value))
        return Row(key, name, _number_text(value))


class ReportDict(dict):
    """:meth:`AnalysisReport.as_dict`: the report as one JSON object, which also keeps the report
    itself (``report``) for whoever prints it for people."""

    def __init__(self, report: AnalysisReport, values: dict):
        super().__init__(values)
        self.report = report


def _number_text(value) -> str:
    """A scalar for people: "yes"/"no", a whole number, a float to 4 digits; ``MISSING`` for None,
    NaN or inf (whose reason the report's ``reasons`` hold)."""
    if isinstance(value, (bool, np.bool_)):
        return "yes" if value else "no"
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return MISSING
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


class Clock:
    """The wall time of an analysis's stages: :meth:`lap` names the stage that just ended."""

    def __init__(self):
        self.timings = {}
        self._last = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.timings[name] = now - self._last
        self._last = now


@contextmanager
def analysis_threads(threads: int | None):
    """Run the block with ``threads`` threads for numba's kernels, the FFT and BLAS (LAPACK, SuperLU's
    BLAS, ARPACK), on the calling thread (numba, the FFT) and in the process (BLAS); None: every core.
    Beside a simulation, more threads than cores are free slow both: with three busy processes on
    two cores, the rigidity analysis took 2.66 s with the default BLAS threads and 1.11 s with one."""
    import numba
    import scipy.fft
    from threadpoolctl import threadpool_limits

    count = (os.cpu_count() or 1) if threads is None else int(threads)
    previous = numba.get_num_threads()
    numba.set_num_threads(max(1, min(count, numba.config.NUMBA_NUM_THREADS)))
    try:
        with threadpool_limits(limits=threads, user_api="blas"), scipy.fft.set_workers(count):
            yield
    finally:
        numba.set_num_threads(previous)


def analyze(state, kind: str, load: str = "auto", seed: int = 0, threads: int | None = None) -> AnalysisReport:
    """Run the analysis ``kind`` (a name in :data:`granlab.engine.analysis.ANALYSES`) on ``state``, with
    ``threads`` threads (:func:`analysis_threads`; None: every core)."""
    if kind not in ANALYSES:
        raise ParameterError("analysis", kind, f"one of {', '.join(ANALYSES)}")
    if threads is not None and (int(threads) != threads or threads < 1):
        raise ParameterError("threads", threads, "a whole number >= 1, or None for every core")
    clock = Clock()
    with analysis_threads(threads):
        report = ANALYSES[kind].load().run(state, clock, load, seed)
    report.timings = dict(clock.timings, total=sum(clock.timings.values()))
    return report
