"""GranLab in a notebook: results as bokeh figures shown inline, and the live lab in a cell.

Figures are shown with bokeh's resources inlined in the notebook (no request leaves the machine:
a classroom may have no network). :func:`lab` serves the lab (engine thread, viser scene, panel
dashboard) from a thread of the kernel on this machine and shows it in the cell.
"""

from __future__ import annotations

import asyncio
import html
import threading
from pathlib import Path

import numpy as np
import rich
from bokeh.models import ColumnDataSource

from granlab.engine.analysis.report import AnalysisReport
from granlab.engine.analysis.states import PackingState
from granlab.engine.studies import RatchetCurve

from .lab.analysis import AnalysisResult
from .lab.plots import MODEL_STYLES, AnalysisFigures, compact, lab_figure, legend_beside

_shown_inline = False


def show(figure) -> None:
    """Show a bokeh figure (or layout) in the notebook's output, bokeh's files inlined."""
    global _shown_inline
    from bokeh.io import output_notebook
    from bokeh.io import show as bokeh_show
    from bokeh.resources import INLINE

    if not _shown_inline:
        output_notebook(resources=INLINE, hide_banner=True)
        _shown_inline = True
    bokeh_show(figure)


def strain_figure(curves: list[RatchetCurve]):
    """γ(N) of each curve from its reference cycle on (ratcheting Fig. 12) side by side, each on its
    own scale: a point per cycle and the fitted line, the title naming the model and its strain
    per cycle Δγ (or that it does not ratchet by the paper's rule)."""
    from bokeh.layouts import row

    figures = []
    for curve in curves:
        color = MODEL_STYLES[curve.model][0]
        cycles = curve.cycles[curve.reference_cycle:]
        verdict = curve.verdict
        verdict_text = f"Δγ = {compact(verdict.dgamma)} per cycle" if verdict.ratcheting else "no ratcheting"
        fig = lab_figure(f"strain-{curve.model}", f"{curve.model}: {verdict_text}", "load cycle N",
                         "γ − γ(reference cycle)", height=400, width=380, sizing_mode="fixed")
        fig.scatter(cycles, curve.gamma, color=color, size=5, legend_label="γ at the start of a cycle")
        fitted = verdict.dgamma * (cycles - cycles.mean()) + curve.gamma.mean()
        fig.line(cycles, fitted, color=color, line_width=2, legend_label="line fitted (Sec. IV B 1)")
        legend_beside(fig)
        figures.append(fig)
    return row(*figures)


def analysis_figure(state: PackingState, report: AnalysisReport, name: str | None = None):
    """The figure of an analysis report (``network`` for status, ``forces`` for packing,
    ``structure`` for fractal; the first it has unless ``name``), as the lab's Analysis tab draws it."""
    figures = AnalysisFigures()
    drawn = [kind for kind in figures.show(AnalysisResult(1, report.kind, state, report)) if kind in figures.figures]
    if not drawn:
        raise ValueError(f"the {report.kind} analysis has no figure (figures: network for status, forces for "
                         f"packing, structure for fractal)")
    fig = figures.figures[name or drawn[0]]
    fig.sizing_mode, fig.width, fig.height = "fixed", 640, 600
    return fig


def force_network_figure(state: PackingState, title: str = "Force network"):
    """The disks and their contacts, each a segment from centre to centre (to the nearest
    periodic image) whose width grows with |F| (the status colours of the lab: blue non-sliding,
    red sliding)."""
    c = state.contacts
    n = state.disks
    pairs = c.j < n
    i, j = c.i[pairs], c.j[pairs]
    start = state.positions[i]
    end = state.positions[j] + c.image[pairs] * state.box_lengths
    force = np.hypot(c.normal_force[pairs], c.tangential_force[pairs])
    width = 0.5 + 5.0 * force / force.max() if force.size and force.max() > 0 else np.ones(i.size)
    sliding = np.isin(c.status[pairs], (2, 3))
    fig = lab_figure("force-network", title, "x", "y", match_aspect=True, height=600, width=640, sizing_mode="fixed")
    fig.circle(state.positions[:, 0], state.positions[:, 1], radius=state.radii, fill_color="#dddddd",
               line_color="#999999", legend_label="disk")
    source = ColumnDataSource({"x0": start[:, 0], "y0": start[:, 1], "x1": end[:, 0], "y1": end[:, 1],
                               "width": width, "color": np.where(sliding, "#d62728", "#1f77b4")})
    fig.segment("x0", "y0", "x1", "y1", line_width="width", color="color", source=source)
    for color, text in (("#1f77b4", "non-sliding contact (width ∝ |F|)"), ("#d62728", "sliding contact")):
        fig.line([np.nan], [np.nan], color=color, line_width=3, legend_label=text)
    if any(state.periodic):
        lx, ly = state.box_lengths
        fig.line([0, lx, lx, 0, 0], [0, 0, ly, ly, 0], color="#7570b3", line_dash="dashed", legend_label="periodic cell")
    legend_beside(fig)
    return fig


class NotebookLab:
    """The lab served from a thread of this kernel, on this machine only; shown in a cell (its
    dashboard, with the 3D scene inside) by displaying it. :meth:`stop` ends it."""

    def __init__(self, preset: str = "ratchet16", data_dir: str | Path = "granlab-data", port: int = 0,
                 height: int = 820, **changes):
        self.height = height
        self._ready = threading.Event()
        self._failure: BaseException | None = None
        self._lab = None
        self._thread = threading.Thread(target=self._serve, args=(preset, data_dir, port, changes),
                                        name="granlab-notebook-lab", daemon=True)
        self._thread.start()
        self._ready.wait()
        if self._failure is not None:
            raise self._failure

    def _serve(self, preset: str, data_dir, port: int, changes: dict) -> None:
        from .lab.server import Lab

        asyncio.set_event_loop(asyncio.new_event_loop())  # the panel server's loop, apart from the kernel's
        try:
            with rich.get_console().capture():  # viser's banner: in a notebook rich writes it into the cell
                self._lab = Lab(port=port, data_dir=data_dir, preset=preset, **changes)
            self._lab.start()
        except BaseException as error:  # handed to the caller's thread
            self._failure = error
            self._ready.set()
            return
        if not self._lab.compiles:  # a second or two: the cell then shows a lab that answers
            self._lab.wait_ready(60)
        self._ready.set()
        self._lab.server.io_loop.start()

    @property
    def url(self) -> str:
        return self._lab.url

    def status(self) -> dict:
        """What ``GET /status`` answers: the state, time, settings, readout..."""
        return self._lab.status()

    def submit(self, command: str, **payload) -> None:
        """Send the engine a command as a control of the page does (``apply`` with ``changes``, ``play``...),
        once the engine has started (a first run compiles its kernels first)."""
        self._lab.wait_ready()
        self._lab.engine.submit(command, **payload)

    def stop(self) -> None:
        """Stop the engine, the scene and the server (on the server's own loop)."""
        if self._lab is not None and self._thread.is_alive():
            loop = self._lab.server.io_loop

            def shut_down():
                self._lab.stop()
                loop.stop()

            with rich.get_console().capture():  # viser's "Server stopped"
                loop.add_callback(shut_down)
                self._thread.join(timeout=30)

    def _repr_html_(self) -> str:
        return (f'<iframe src="{html.escape(self.url)}" width="100%" height="{self.height}" '
                f'style="border:1px solid #ccc"></iframe><div>GranLab lab at <a href="{html.escape(self.url)}" '
                f'target="_blank">{html.escape(self.url)}</a></div>')


def lab(preset: str = "ratchet16", **options) -> NotebookLab:
    """The live lab in a notebook cell: ``lab("ratchet16")`` as the last line of a cell shows it;
    ``options``: ``data_dir``, ``port``, ``height`` of the frame and the preset's settings
    (``particles``, ``seed``...)."""
    return NotebookLab(preset, **options)
