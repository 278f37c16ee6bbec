"""The lab's live plots: each one a bokeh figure with its sources, fed the rows of the engine's
series as a tab pulls them.

A :class:`LivePlot` names the series it reads (``reads``), turns their new rows into its
sources (:meth:`LivePlot.feed`) and redraws what depends on the status, such as a fitted line
or the Coulomb cone at the current friction (:meth:`LivePlot.refresh`). Paths are drawn as
segments between consecutive samples of the same path, so they are continuous lines that can
be coloured piece by piece (by cycle, by contact, by status) and streamed. Every colour has a
legend; numbers on axes are compact (``5×10⁻⁸``); axis labels carry units or say "paper units".

Bokeh models belong to one document: every tab builds its own plots (:func:`make_plot`).
"""

from __future__ import annotations

import math

import numpy as np
import panel as pn
from bokeh.models import (BasicTicker, ColorBar, ColumnDataSource, CustomJSTickFormatter, LabelSet, LinearColorMapper,
                          Range1d, Span)
from bokeh.palettes import Blues256
from bokeh.plotting import figure

from granlab.engine.observables import sliding
from granlab.engine.params import TANGENTIAL
from granlab.engine.protocols.teaching import restitution
from granlab.engine.state import STATUS_SLIDE_NEG, STATUS_SLIDE_POS

from . import analysis
from ..media.drawing import STATUS_LEGEND, WATCHED_COLORS, hex_color

TOOLS = "pan,wheel_zoom,box_zoom,reset,save"
LINE_ROLLOVER = 40000
PATH_ROLLOVER = 12000
"""Rows a tab keeps of a time series, and segments of a path (a few load cycles of watched contacts)."""
VIEWER_SHARE = 0.25
"""The share of those a viewer's page keeps (10 000 rows: 50 load cycles of the ratchet, five times what its
plots follow): the server holds a copy of every page's plots, and a class of forty pages at the presenter's
share would hold 160 MiB, taken over an hour as the rows come."""
DOTS_ROLLOVER = 2000
"""The restitution plot's last collisions: at "max" speed some 30 a second land on a few places."""
CYCLES_ROLLOVER = 2000
"""The load cycles a strain plot keeps (the ratchet's reference cycle kept with them): each cycle redraws
them all, and a school day at the highest speed cycles some 20 000 times."""
PLOT_HEIGHT = 316
"""The least height of a plot: its drawing area is then at least 250 px under a one-line title,
above its x axis (two plots fill the right of a 1366×768 screen; more scroll)."""
CHANGE_COLOR = "#7b1fa2"
"""The colour of the change markers: none of the lines' or paths' colours."""
CYCLES_SHOWN = 6
"""The q–γ plot colours the last cycles from light to dark; older ones are light grey."""

COMPACT = """
const SUP = {"-": "⁻", "0": "⁰", "1": "¹", "2": "²", "3": "³", "4": "⁴", "5": "⁵", "6": "⁶", "7": "⁷", "8": "⁸", "9": "⁹"};
if (tick === 0) return "0";
const a = Math.abs(tick);
if (a >= 1e-3 && a < 1e5) return String(Number(tick.toPrecision(4))).replace("-", "−");
const parts = tick.toExponential(2).split("e");
const mantissa = String(Number(parts[0])).replace("-", "−");
const exponent = String(Number(parts[1])).split("").map(c => SUP[c] || c).join("");
return (mantissa === "1" ? "" : mantissa === "−1" ? "−" : mantissa + "×") + "10" + exponent;
"""
"""Tick labels: plain numbers from 10⁻³ to 10⁵, else ``m×10ⁿ`` with at most three digits."""


def compact(value: float) -> str:
    """A number as the axes show it (``5.06×10⁻⁸``), for titles and readouts."""
    if value is None or not math.isfinite(value):
        return "—"
    if value == 0 or 1e-3 <= abs(value) < 1e5:
        return f"{value:.{5 if abs(value) >= 1e3 else 4}g}".replace("-", "−")
    mantissa, exponent = f"{value:.2e}".split("e")
    superscript = str(int(exponent)).translate(str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹"))
    return f"{float(mantissa):g}".replace("-", "−") + "×10" + superscript


def lab_figure(name: str, title: str, x_label: str, y_label: str, **kwargs):
    """A figure that fills its place (unless ``kwargs`` size it), with compact tick labels and the lab's tools."""
    kwargs = {"sizing_mode": "stretch_both", "min_height": PLOT_HEIGHT, **kwargs}
    fig = figure(name=f"figure-{name}", title=title, tools=TOOLS, x_axis_label=x_label, y_axis_label=y_label,
                 **kwargs)
    fig.toolbar.logo = None
    fig.toolbar.autohide = True
    fig.title.text_font_size = "14px"
    fig.title.standoff = 2  # every pixel of height goes to the drawing area on a 768-pixel screen
    fig.xaxis.ticker.desired_num_ticks = 5  # a plot beside its legend is narrow: long tick labels must not touch
    for axis in (fig.xaxis, fig.yaxis):
        axis.axis_label_text_font_size = "13px"
        axis.axis_label_text_font_style = "normal"
        axis.axis_label_standoff = 2
        axis.major_label_text_font_size = "12px"
        axis.major_label_standoff = 3
        axis.formatter = CustomJSTickFormatter(code=COMPACT)
    return fig


PROFILE_FONTS = {"title": ("14px", "17px"), "axis_label": ("13px", "17px"), "major_label": ("12px", "15px"),
                 "legend": ("11px", "14px")}
"""The figures' text sizes on a screen and in the projector profile (read across a classroom)."""


def set_projector(fig, on: bool, base_widths: dict) -> None:
    """The projector profile of ``fig`` (``on``) or the screen's: larger text, lines twice as thick and
    markers half as large again. ``base_widths`` keeps each glyph's own sizes (by glyph id) to go back to."""
    profile = int(on)
    fig.title.text_font_size = PROFILE_FONTS["title"][profile]
    for axis in (*fig.xaxis, *fig.yaxis):
        axis.axis_label_text_font_size = PROFILE_FONTS["axis_label"][profile]
        axis.major_label_text_font_size = PROFILE_FONTS["major_label"][profile]
        axis.axis_line_width = axis.major_tick_line_width = 1 + profile
    for legend in fig.legend:
        legend.label_text_font_size = PROFILE_FONTS["legend"][profile]
        legend.label_height = legend.glyph_height = (14, 18)[profile]
    for renderer in fig.renderers:
        glyph = getattr(renderer, "glyph", None)
        if glyph is None:
            continue
        base = base_widths.setdefault(glyph.id, {key: getattr(glyph, key) for key in ("line_width", "size")
                                                 if isinstance(getattr(glyph, key, None), (int, float))})
        for key, value in base.items():
            setattr(glyph, key, value * ((2.0, 1.5)[key == "size"] if on else 1.0))


def legend_beside(fig) -> None:
    """Move the figure's legend to the right of the plot, one entry a line: there it hides no data,
    and it takes width, of which a projector's screen has more to spare than height."""
    legend = fig.legend[0]
    fig.add_layout(legend, "right")
    legend.orientation = "vertical"
    legend.label_text_font_size = "11px"
    legend.label_height = 14
    legend.glyph_height = 14
    legend.glyph_width = 16
    legend.padding = 3
    legend.spacing = 2
    legend.margin = 4
    legend.border_line_alpha = 0.0


class ChangeMarks:
    """A labelled vertical line at each change of the physics on a plot whose x is time (or the
    load cycle): what changed, from → to, written along the line."""

    def __init__(self, fig, name: str, x: str):
        self.x = x
        self.source = ColumnDataSource({"x": [], "text": []}, name=f"{name}-changes")
        fig.vspan(x="x", source=self.source, line_color=CHANGE_COLOR, line_dash="dashed", line_width=1.5)
        fig.add_layout(LabelSet(x="x", y=4, y_units="screen", text="text", source=self.source, angle=math.pi / 2,
                                x_offset=-3, text_font_size="11px", text_color=CHANGE_COLOR, text_align="left",
                                text_baseline="bottom"))
        self._shown = None

    def show(self, changes: list[dict]) -> None:
        marks = [c for c in changes if c.get(self.x) is not None]
        key = tuple((c[self.x], c["text"]) for c in marks)
        if key == self._shown:
            return
        self._shown = key
        # changes at one moment share one line and one label
        moments: dict[float, list[str]] = {}
        for change in marks:
            moments.setdefault(change[self.x], []).append(change["text"])
        self.source.data = {"x": list(moments), "text": ["; ".join(texts) for texts in moments.values()]}


def _empty(columns) -> dict:
    return {column: [] for column in columns}


class LivePlot:
    """A figure fed by series. ``reads``: series names; ``pane``: what the page shows."""

    reads: tuple[str, ...] = ()

    def __init__(self, name: str, fig):
        self.name = name
        self.figure = fig
        self.title = fig.title.text
        self.sources: list[ColumnDataSource] = []
        self.pane = pn.pane.Bokeh(fig, sizing_mode="stretch_both", min_height=PLOT_HEIGHT, margin=(0, 4, 4, 0))
        self._base_widths: dict = {}
        self.share = 1.0
        """The share of each rollover this plot keeps (VIEWER_SHARE on a viewer's page)."""

    def rows(self, rollover: int) -> int:
        """The rows this plot keeps of a source whose rollover is ``rollover``."""
        return max(1, int(rollover * self.share))

    def nbytes(self) -> int:
        """The bytes of the columns its sources hold (the server keeps them for the page)."""
        return sum(values.nbytes if isinstance(values, np.ndarray) else 8 * len(values)
                   for source in self.sources for values in source.data.values())

    def set_projector(self, on: bool) -> None:
        set_projector(self.figure, on, self._base_widths)

    def empty(self) -> bool:
        """Whether the plot has nothing to draw yet."""
        return all(len(next(iter(source.data.values()), ())) == 0 for source in self.sources)

    def clear(self) -> None:
        """Empty the sources of the data (a new preset, a reset, a replay's jump back) and put back
        the title that says what the plot shows (not what the last run made of it); the legend's
        placeholders stay."""
        for source in self.sources:
            source.data = _empty(source.data)
        self.figure.title.text = self.title

    def feed(self, series: str, columns: dict, reset: bool, status: dict) -> None:
        """New rows of ``series`` (columns of lists); ``reset``: they replace what was shown."""

    def refresh(self, status: dict) -> None:
        """Redraw what depends on the status (fits, the cone, ranges)."""


def _last(columns: dict, rows: int) -> dict:
    """The last ``rows`` rows of ``columns``: a new tab pulls whole ring buffers, a path plot keeps
    ``rows`` segments of them."""
    return {name: values[-rows:] for name, values in columns.items()}


def _stream(source: ColumnDataSource, columns: dict, reset: bool, rollover: int) -> None:
    columns = {name: values for name, values in columns.items() if name in source.data}
    if reset:
        source.data = {name: columns.get(name, []) for name in source.data}
    elif columns and len(next(iter(columns.values()))):
        source.stream(columns, rollover=rollover)


class LinePlot(LivePlot):
    """Lines of one series: ``lines`` is a list of (x column, y column, legend label, colour[, dash])."""

    def __init__(self, name, title, series, lines, x_label, y_label, columns, **kwargs):
        super().__init__(name, lab_figure(name, title, x_label, y_label, **kwargs))
        self.reads = (series,)
        # only the columns its lines draw: each page's server-side document keeps up to LINE_ROLLOVER rows of
        # them, and the energy and coordination plots held all nine of the ratchet's (3.5 MB a page more)
        drawn = {column for line in lines for column in line[:2]}
        self.source = ColumnDataSource(_empty([column for column in columns if column in drawn]), name=f"series-{name}")
        self.sources = [self.source]
        self.lines = lines
        for x, y, label, color, *dash in lines:
            options = {"legend_label": label} if len(lines) > 1 else {}
            self.figure.line(x, y, source=self.source, color=color, line_width=2, line_dash=dash[0] if dash else "solid",
                             **options)
        if len(lines) > 1:
            legend_beside(self.figure)
        self.marks = ChangeMarks(self.figure, name, "t") if lines[0][0] == "t" else None

    def clear(self):
        super().clear()
        if self.marks is not None:
            self.marks.source.data = {"x": [], "text": []}
            self.marks._shown = None

    def feed(self, series, columns, reset, status):
        _stream(self.source, columns, reset, self.rows(LINE_ROLLOVER))

    def refresh(self, status):
        """Plots against time follow the last ``window`` of simulated time (a few load cycles, so
        the cycles can be told apart on a projector), or show the whole run."""
        if self.marks is not None:
            self.marks.show(status.get("changes") or [])
        window = float(status.get("window") or 0.0)
        x_range = self.figure.x_range
        if self.lines[0][0] != "t" or (x_range.follow_interval or 0.0) == window:
            return
        x_range.follow, x_range.follow_interval = ("end", window) if window > 0 else (None, None)


class Segments:
    """Turns samples of paths into segments between consecutive samples of the same path
    (keyed), remembering the last sample of each path across pulls."""

    def __init__(self):
        self.last: dict = {}

    def reset(self) -> None:
        self.last = {}

    def add(self, keys, xs, ys, extra: dict) -> dict:
        """Columns x0, y0, x1, y1 and the ``extra`` columns (of the segment's end sample) of the
        new segments, as arrays; ``keys`` (n, k) name the path of each of the n samples."""
        xs, ys = np.asarray(xs, dtype=float), np.asarray(ys, dtype=float)
        x0, y0 = np.empty_like(xs), np.empty_like(ys)
        first = np.zeros(len(xs), dtype=bool)  # a path's first sample ends no segment
        paths, path = np.unique(keys, axis=0, return_inverse=True)
        path = path.reshape(-1)  # NumPy 2.0.0 gives it the shape of keys
        for p, key in enumerate(map(tuple, paths.tolist())):
            rows = np.flatnonzero(path == p)
            x0[rows[1:]], y0[rows[1:]] = xs[rows[:-1]], ys[rows[:-1]]
            if key in self.last:
                x0[rows[0]], y0[rows[0]] = self.last[key]
            else:
                first[rows[0]] = True
            self.last[key] = (xs[rows[-1]], ys[rows[-1]])
        keep = ~first
        return {"x0": x0[keep], "y0": y0[keep], "x1": xs[keep], "y1": ys[keep],
                **{name: np.asarray(values)[keep] for name, values in extra.items()}}


class StrainPlot(LivePlot):
    """Ratcheting Fig. 2: γ at the start of each cycle, from the reference cycle on (the first
    cycles settle the packing), with the strain per cycle fitted from the cycle the preset fits
    from (``fit_from`` of the status: after the last change of the physics, whose marker is drawn);
    the cycles before it are grey. The y-range fits these points."""

    reads = ("cycles",)

    def __init__(self, reference: int, name="strain-per-cycle"):
        self.reference = reference
        fig = lab_figure(name, "Strain at the start of each cycle", "cycle N", "γ(N) − γ(N_ref)  (Eq. 2)")
        super().__init__(name, fig)
        fig.x_range = Range1d(0, 1)
        fig.y_range = Range1d(-1, 1)
        self.points = ColumnDataSource({"cycle": [], "strain": []}, name="strain-cycles")
        self.before = ColumnDataSource({"cycle": [], "strain": []}, name="strain-before-fit")
        self.fit = ColumnDataSource({"cycle": [], "strain": []}, name="strain-fit")
        self.sources = [self.points, self.before, self.fit]
        fig.scatter("cycle", "strain", source=self.before, size=7, color="#b0b0b0", legend_label="settling")
        fig.scatter("cycle", "strain", source=self.points, size=7, legend_label="γ at a cycle start")
        fig.line("cycle", "strain", source=self.fit, color="#d62728", line_width=2, legend_label="fit")
        legend_beside(fig)
        self.settle_item, _, self.fit_item = fig.legend[0].items
        self.marks = ChangeMarks(fig, name, "cycle")
        self.cycles: dict[int, float] = {}
        self._shown = None
        self._start = reference
        self._oldest = 0
        """The oldest cycle drawn (later than the first once the page has held CYCLES_ROLLOVER cycles)."""

    def clear(self):
        super().clear()
        self.cycles = {}
        self._shown = None
        self._oldest = 0
        self.marks.source.data = {"x": [], "text": []}
        self.marks._shown = None

    def feed(self, series, columns, reset, status):
        if reset:
            self.cycles = {}
        self.cycles.update(zip(map(int, columns.get("cycle", [])), columns.get("gamma", [])))
        kept = self.rows(CYCLES_ROLLOVER)
        if len(self.cycles) > kept + kept // 4:  # trimmed now and then, not at every cycle
            self._oldest = max(self.cycles) - kept + 1
            self.cycles = {cycle: gamma for cycle, gamma in self.cycles.items()
                           if cycle >= self._oldest or cycle in (self.reference, self._start)}

    def refresh(self, status):
        self.marks.show(status.get("changes") or [])
        fit = status.get("strain")
        fit_from = status.get("fit_from") or {"cycle": self.reference, "after": ""}
        start = self._start = fit_from["cycle"]
        key = (len(self.cycles), start, fit_from.get("after"), None if fit is None else fit["dgamma"])
        if key == self._shown:
            return
        self._shown = key
        self.settle_item.label = {"value": fit_from.get("after") or "settling"}
        fig = self.figure
        first = min(self.reference, start)
        # a legend before the first point would show its labels without their marks
        fig.legend[0].visible = first in self.cycles
        if first not in self.cycles:
            for source in self.sources:
                source.data = {"cycle": [], "strain": []}
            fig.title.text = f"Strain per cycle, from cycle {first} (not reached yet)"
            return
        reference = start if start in self.cycles else first
        cycles = np.array(sorted(c for c in self.cycles if c >= max(first, self._oldest)), dtype=float)
        strain = np.array([self.cycles[int(c)] for c in cycles]) - self.cycles[reference]
        fitted = cycles >= start
        self.points.data = {"cycle": cycles[fitted], "strain": strain[fitted]}
        self.before.data = {"cycle": cycles[~fitted], "strain": strain[~fitted]}
        self.settle_item.visible = bool(np.any(~fitted))  # a legend entry only for points drawn
        fig.x_range.start, fig.x_range.end = cycles[0] - 0.5, max(cycles[-1], start + 3) + 0.5
        low, high = float(strain.min()), float(strain.max())
        if fit is None:
            self.fit.data = {"cycle": [], "strain": []}
            fig.title.text = f"Strain per cycle: the fit from cycle {start} needs 3 cycles"
        else:
            ends = np.array([start, cycles[-1]], dtype=float)
            line = fit["mean_gamma"] - fit["gamma_ref"] + fit["dgamma"] * (ends - fit["mean_cycle"])
            self.fit.data = {"cycle": ends, "strain": line}
            low, high = min(low, float(line.min())), max(high, float(line.max()))
            verdict = "ratcheting" if fit["ratcheting"] else "no clear ratcheting"
            fig.title.text = f"Δγ = {compact(fit['dgamma'])} per cycle from cycle {start}: {verdict}"
            self.fit_item.label = {"value": "fit" + (" (scatter > drift)" if not fit["ratcheting"] else "")}
        pad = 0.08 * (high - low) if high > low else max(abs(high), 1e-12)
        fig.y_range.start, fig.y_range.end = low - pad, high + pad


class LoadStrainPlot(LivePlot):
    """Ratcheting Fig. 1: the load q against the strain γ, one continuous line, each cycle in a
    shade of blue darker than the one before (a colour bar names the cycles)."""

    reads = ("time",)

    def __init__(self, name="q-gamma"):
        fig = lab_figure(name, "Load q against strain γ (ratcheting Fig. 1)", "γ = L_y/L_y0 − L_x/L_x0  (Eq. 2)",
                         "q  (Eq. 1, units of P0)")
        super().__init__(name, fig)
        self.source = ColumnDataSource({"x0": [], "y0": [], "x1": [], "y1": [], "cycle": []}, name="q-gamma-path")
        self.sources = [self.source]
        # the lighter quarter of Blues256 left out: the first cycle shown stays apart from the grey of older ones,
        # and the quarters of the scale apart, also for a protanope (tests/test_colour_vision.py)
        palette = list(reversed(Blues256[:160]))
        self.mapper = LinearColorMapper(palette=palette, low=0, high=1, low_color="#dddddd")
        fig.segment("x0", "y0", "x1", "y1", source=self.source, line_width=2,
                    color={"field": "cycle", "transform": self.mapper})
        # whole cycles only: each cycle's colour spans cycle ± 0.5, and "cycle -0.4" would mean nothing
        fig.add_layout(ColorBar(color_mapper=self.mapper, title="cycle", width=10, title_text_font_size="11px",
                                major_label_text_font_size="10px", ticker=BasicTicker(min_interval=1)), "right")
        self.segments = Segments()
        self.cycle = 0

    def clear(self):
        super().clear()
        self.segments.reset()

    def feed(self, series, columns, reset, status):
        if reset:
            self.segments.reset()
        columns = _last(columns, self.rows(PATH_ROLLOVER))
        cycle = np.asarray(columns.get("cycle", []))
        keep = cycle >= 0
        rows = self.segments.add(np.zeros((int(keep.sum()), 1)), np.asarray(columns.get("gamma", []))[keep],
                                 np.asarray(columns.get("q", []))[keep], {"cycle": cycle[keep]})
        _stream(self.source, rows, reset, self.rows(PATH_ROLLOVER))
        if len(cycle) and cycle[keep].size:
            self.cycle = int(cycle[keep].max())
        self.mapper.low, self.mapper.high = max(0, self.cycle - CYCLES_SHOWN + 1) - 0.5, self.cycle + 0.5


class ConePlot(LivePlot):
    """Watched contacts in the (F_n, F_t) plane (ratcheting Figs. 3-4, 6; quasi-rigidity Fig. 3):
    each contact a continuous line in its own colour (the colour it has in the scene), its
    sliding samples marked by side, and the Coulomb cone |F_t| = μ (F_n + F0) dashed."""

    def __init__(self, name, title, series, keyed: bool):
        fig = lab_figure(name, title, "F_n = Nᵉ − F0  (elastic normal force)", "F_t  (tangential force)")
        super().__init__(name, fig)
        self.reads = (series,)
        self.keyed = keyed
        self.paths = ColumnDataSource({"x0": [], "y0": [], "x1": [], "y1": [], "t": [], "color": [], "label": []},
                                      name=f"{name}-paths")
        self.sliding = ColumnDataSource({"x": [], "y": [], "color": [], "marker": []}, name=f"{name}-sliding")
        self.cone = ColumnDataSource({"x": [], "y": []}, name=f"{name}-cone")
        self.sources = [self.paths, self.sliding, self.cone]
        fig.line("x", "y", source=self.cone, color="#333333", line_dash="dashed", line_width=1.5,
                 legend_label="|F_t| = μ(F_n+F0)")
        fig.segment("x0", "y0", "x1", "y1", source=self.paths, color="color", line_width=2, legend_field="label")
        fig.scatter("x", "y", source=self.sliding, color="color", marker="marker", size=7)
        for code, marker in ((STATUS_SLIDE_POS, "triangle"), (STATUS_SLIDE_NEG, "inverted_triangle")):
            # an empty renderer per sliding side: the legend names the markers drawn above
            label, color = STATUS_LEGEND[code]
            fig.scatter(np.array([np.nan]), np.array([np.nan]), color=color, marker=marker, size=7, legend_label=label)
        legend_beside(fig)
        items = fig.legend[0].items
        #: the cone and the sliding marks: not in the legend where μ = ∞ (neither can occur)
        self.friction_items = [items[0]] + items[-2:]
        self.segments = Segments()
        self.top = 0.0
        self._cone_key = None

    def clear(self):
        super().clear()
        self.segments.reset()
        self.top = 0.0
        self._cone_key = None

    def feed(self, series, columns, reset, status):
        if reset:
            self.segments.reset()
        columns = _last(columns, self.rows(PATH_ROLLOVER))
        normal = np.asarray(columns.get("normal", []), dtype=float)
        tangential = np.asarray(columns.get("tangential", []), dtype=float)
        state = np.asarray(columns.get("status", []), dtype=int)
        watched = [tuple(p) for p in status.get("watched") or []]
        if self.keyed:
            pairs = np.column_stack([columns.get("i", []), columns.get("j", [])]).astype(int)
        else:
            pairs = np.tile(watched[0] if watched else (0, 1), (len(normal), 1))
        labels = dict(zip(watched, status.get("watched_labels") or []))
        # a colour and a name per contact, not per sample: a new tab pulls tens of thousands of samples
        paths, path = np.unique(pairs, axis=0, return_inverse=True)
        paths, path = [tuple(p) for p in paths.tolist()], path.reshape(-1)
        colors = np.array([hex_color(WATCHED_COLORS[(watched.index(p) if p in watched else len(watched))
                                                    % len(WATCHED_COLORS)]) for p in paths] or [""])
        names = np.array([labels.get(p, "%d–%d" % p) for p in paths] or [""])
        rows = self.segments.add(pairs, normal, tangential, {"t": columns.get("t", []), "color": colors[path],
                                                             "label": names[path]})
        _stream(self.paths, rows, reset, self.rows(PATH_ROLLOVER))
        if len(normal):
            self.top = max(self.top, float(np.abs(normal).max()))
        slides = np.flatnonzero(sliding(state))
        positive = state[slides] == STATUS_SLIDE_POS
        marks = {"x": normal[slides], "y": tangential[slides],
                 "color": np.where(positive, STATUS_LEGEND[STATUS_SLIDE_POS][1], STATUS_LEGEND[STATUS_SLIDE_NEG][1]),
                 "marker": np.where(positive, "triangle", "inverted_triangle")}
        _stream(self.sliding, marks, reset, self.rows(PATH_ROLLOVER))

    def refresh(self, status):
        settings = status.get("settings") or {}
        friction = settings.get("friction", 0.5)
        mu = math.inf if isinstance(friction, str) else float(friction)
        f0 = float(settings.get("cohesion_force", 0.0) or 0.0)
        key = (mu, f0, round(self.top, 12))
        if key == self._cone_key:
            return
        self._cone_key = key
        for item in self.friction_items:
            item.visible = not math.isinf(mu)
        self.figure.title.text = self.title + (" — μ = ∞, no cone" if math.isinf(mu) else f" — μ = {mu:g}")
        if math.isinf(mu) or self.top <= 0.0:  # no cone, or no force yet to draw it to
            self.cone.data = {"x": [], "y": []}
            return
        top = 1.1 * self.top
        self.cone.data = {"x": [top, -f0, top], "y": [mu * (top + f0), 0.0, -mu * (top + f0)]}


class CollisionForcePlot(LivePlot):
    """Gilabert Sec. II C: the normal force against the overlap along each collision, the spring's
    line K_n δ beside it; each collision a loop of its own (no line joins one to the next), whose
    area is the energy the dashpot took."""

    reads = ("collision",)

    def __init__(self, name="collision-force"):
        fig = lab_figure(name, "Normal force against overlap, along each collision", "overlap δ (paper units)",
                         "normal force F_n (paper units)")
        super().__init__(name, fig)
        self.lines = {}
        for column, label, color, dash in (("force", "F_n: spring + dashpot", "#d55e00", "solid"),
                                           ("spring", "K_n δ: the spring alone", "#0072b2", "dashed")):
            source = ColumnDataSource({"x0": [], "y0": [], "x1": [], "y1": []}, name=f"{name}-{column}")
            fig.segment("x0", "y0", "x1", "y1", source=source, color=color, line_width=2, line_dash=dash,
                        legend_label=label)
            self.lines[column] = (source, Segments())
        self.sources = [source for source, _ in self.lines.values()]
        legend_beside(fig)

    def clear(self):
        super().clear()
        for _, segments in self.lines.values():
            segments.reset()

    def feed(self, series, columns, reset, status):
        columns = _last(columns, self.rows(PATH_ROLLOVER))
        keys = np.asarray(columns.get("collision", []), dtype=int).reshape(-1, 1)
        for column, (source, segments) in self.lines.items():
            _stream(source, segments.add(keys, columns.get("overlap", []), columns.get(column, []), {}), reset,
                    self.rows(PATH_ROLLOVER))


class RestitutionPlot(LivePlot):
    """Gilabert Sec. II C: the restitution e_N of each collision against its damping ratio ζ (dots),
    over the linear spring-dashpot's e_N = exp(−πζ / √(1 − ζ²)) (line): a dot off the line is a
    collision the formula does not describe. The title gives the last collision's pair of numbers."""

    reads = ("collisions",)

    def __init__(self, name="restitution"):
        fig = lab_figure(name, "Restitution e_N against the damping ratio ζ", "ζ (fraction of critical damping)",
                         "e_N = parting speed / approach speed")
        super().__init__(name, fig)
        fig.x_range = Range1d(0, 1)
        fig.y_range = Range1d(0, 1.05)
        zeta = np.linspace(0.0, 0.995, 200)
        fig.line(zeta, restitution(zeta), color="#0072b2", line_width=2,
                 legend_label="exp(−πζ / √(1 − ζ²))")
        self.points = ColumnDataSource({"zeta": [], "restitution": []}, name="restitution-points")
        self.sources = [self.points]
        fig.scatter("zeta", "restitution", source=self.points, size=9, color="#d55e00", marker="circle",
                    legend_label="measured, one dot a collision")
        legend_beside(fig)

    def feed(self, series, columns, reset, status):
        _stream(self.points, columns, reset, self.rows(DOTS_ROLLOVER))
        if len(columns.get("restitution", ())):
            zeta, measured, predicted = columns["zeta"][-1], columns["restitution"][-1], columns["predicted"][-1]
            self.figure.title.text = f"e_N = {measured:.4f} measured, {predicted:.4f} predicted (ζ = {zeta:.2f})"


WAITS = {"strain-per-cycle": "its first point comes with the reference cycle, once the box is cycled",
         "q-gamma": "the load–strain loop starts with cycling",
         "coulomb-cone": "its contacts are chosen, and watched, from the first load cycle",
         "restitution": "its first dot comes when the first collision is over",
         "collision-force": "its loop is drawn while the disks touch"}
"""What an empty plot waits for, said above the key plots until it draws (a plot not named here: its first samples)."""


def make_plot(name: str, time_label: str, series: dict, reference_cycle: int = 0) -> LivePlot:
    """The plot ``name`` with ``time_label`` on its time axis; ``series`` (name -> columns) are
    the series of the preset it shows, ``reference_cycle`` the cycle its strain is counted from."""
    if name == "strain-per-cycle":
        return StrainPlot(reference_cycle)
    if name == "q-gamma":
        return LoadStrainPlot()
    if name == "coulomb-cone":
        return ConePlot(name, "Watched contacts, Coulomb cone", "contacts", keyed=True)
    if name == "block-cone":
        return ConePlot(name, "The block's contact, Coulomb cone (Fig. 3)", "block", keyed=False)
    if name == "restitution":
        return RestitutionPlot()
    if name == "collision-force":
        return CollisionForcePlot()
    lines = LINES[name]
    plot = LinePlot(name, lines["title"], lines["series"], lines["lines"], lines.get("x", time_label), lines["y"],
                    series.get(lines["series"], lines.get("columns", ())), **lines.get("options", {}))
    if name == "block-load":
        plot.figure.add_layout(Span(location=1.0, dimension="width", line_dash="dotted", line_color="#555555"))
        plot.figure.line(np.array([np.nan]), np.array([np.nan]), line_dash="dotted", color="#555555",
                         legend_label="μF_n: sliding can start")
    return plot


MODEL_PALETTE = ("#d62728", "#1f77b4", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#ff7f0e", "#17becf", "#bcbd22",
                 "#7f7f7f")
MODEL_LINES = ("solid", "solid", "dashed", "dashed", "dotted", "dotdash", "dashdot", "solid", "solid", "solid")
"""The line of each of the first ten models: the angle spring's lies on the α-corrected one and
LAMMPS's on Cundall–Strack's, so the later of each pair is dashed and the earlier shows through."""


def model_styles(names) -> dict[str, tuple[str, str]]:
    """(colour, line) of each model in ``names``, in order, all different however many there are:
    past the ten colours, each comes round again with a dash of its round ("4 3", "6 3", ...)."""
    return {name: (MODEL_PALETTE[i % len(MODEL_PALETTE)],
                   MODEL_LINES[i] if i < len(MODEL_LINES) else f"{2 * (i // len(MODEL_PALETTE)) + 2} 3")
            for i, name in enumerate(names)}


MODEL_STYLES = model_styles(TANGENTIAL)
"""The style of each registered tangential model, in every plot that compares them."""

LINES = {
    "energy": {"title": "Energy budget", "series": "time", "y": "energy (paper units)",
               "lines": [("t", "kinetic", "kinetic", "#0072b2"), ("t", "stored", "stored in springs", "#009e73"),
                         ("t", "dissipated", "dissipated", "#d55e00"),
                         ("t", "balance", "balance (should stay 0)", "#000000")]},
    "coordination": {"title": "Coordination number z = 2M/N", "series": "time", "y": "z (contacts per disk)",
                     "lines": [("t", "z", "z", "#1f77b4")]},
    "springs": {"title": "Spring D_t of each tangential model (ratcheting Fig. 9)", "series": "springs",
                "y": "D_t (length, paper units)",
                "lines": [("t", f"dt_{m.key}", m.label, *MODEL_STYLES[m.name])
                          for m in TANGENTIAL.values()]},
    "spring-path": {"title": "(D_t, D_n) along the closed path A→B→C→D→A", "series": "springs",
                    "x": "D_t (length, paper units)", "y": "D_n (gap, < 0: overlap)",
                    "lines": [(f"dt_{m.key}", f"dn_{m.key}", m.label, *MODEL_STYLES[m.name])
                              for m in TANGENTIAL.values()]},
    "block-load": {"title": "Sideways load and the block's velocity", "series": "block",
                   "y": "load / μF_n;  velocity (paper units)",
                   "lines": [("t", "load_ratio", "load / μF_n", "#1f77b4"), ("t", "velocity", "velocity", "#d62728")]},
    "clusters": {"title": "Number of clusters", "series": "time", "y": "clusters", "lines": [("t", "clusters", "", "#1f77b4")]},
    "coordination-gilabert": {"title": "Coordination number z", "series": "time", "y": "z (contacts per disk)",
                              "lines": [("t", "z", "", "#1f77b4")]},
    "solid-fraction": {"title": "Solid fraction Φ", "series": "time", "y": "Φ", "lines": [("t", "phi", "", "#1f77b4")]},
    "pressure": {"title": "Pressure on the cell (Gilabert Eq. 3)", "series": "time", "y": "P (units of F₁/a)",
                 "lines": [("t", "pressure", "", "#1f77b4")]},
    "kinetic": {"title": "Kinetic energy", "series": "time", "y": "kinetic energy (units of F₁ a)",
                "lines": [("t", "kinetic", "", "#1f77b4")], "options": {"y_axis_type": "log"}},
    "replay-energy": {"title": "Energy budget of the replayed run", "series": "replay", "y": "energy (paper units)",
                      "columns": ("t", "step", "kinetic", "stored", "dissipated", "balance"),
                      "lines": [("t", "kinetic", "kinetic", "#0072b2"), ("t", "stored", "stored in springs", "#009e73"),
                                ("t", "dissipated", "dissipated", "#d55e00"), ("t", "balance", "balance", "#000000")]},
    "replay-structure": {"title": "Coordination of the replayed packing", "series": "replay", "x": "frame",
                         "y": "z (contacts per disk)", "columns": ("t", "step", "frame", "z", "phi"),
                         "lines": [("frame", "z", "z", "#1f77b4")]},
}
"""The plots that are lines of one series: title, series, axis labels (x: the preset's time
label unless given) and lines (x column, y column, legend label, colour)."""


class AnalysisFigures:
    """The figures of an analysis (:data:`granlab.engine.analysis.report.FIGURES` that a plot draws):
    ``network`` the contacts by the status minimum sliding gives, ``forces`` the (N, T) scatter,
    ``structure`` I(k) and its fit; each fed by its own sources (the lab's Analysis tab and a
    notebook draw the same)."""

    def __init__(self):
        self.sources = {name: ColumnDataSource(columns, name=f"analysis-{name}") for name, columns in (
            ("segments", {"x0": [], "y0": [], "x1": [], "y1": [], "color": []}),
            ("critical", {"x": [], "y": [], "color": []}), ("forces", {"normal": [], "tangential": []}),
            ("lines", {"xs": [], "ys": []}), ("data", {"k": [], "intensity": []}), ("fit", {"k": [], "fitted": []}))}
        src = self.sources
        network = lab_figure("analysis-network", "Contacts by the status minimum sliding gives", "x", "y",
                             match_aspect=True, aspect_scale=1.0)
        network.segment("x0", "y0", "x1", "y1", color="color", source=src["segments"], line_width=1.5)
        network.scatter("x", "y", color="color", source=src["critical"], size=8, marker="diamond")
        for color, text, glyph in (("#1f77b4", "non-sliding", "line"), ("#d62728", "sliding", "line"),
                                   ("#ff7f0e", "critical, as the dynamics has it", "diamond"),
                                   ("#d62728", "critical, the dynamics disagrees", "diamond")):
            nowhere = np.array([np.nan])
            if glyph == "line":
                network.line(nowhere, nowhere, color=color, line_width=2, legend_label=text)
            else:
                network.scatter(nowhere, nowhere, color=color, marker="diamond", size=8, legend_label=text)
        legend_beside(network)
        forces = lab_figure("analysis-forces", "Interaction forces (N, T) (Gilabert Fig. 14)", "N (paper units)",
                            "T (paper units)")
        forces.scatter("normal", "tangential", source=src["forces"], size=3, alpha=0.5, legend_label="an interaction")
        forces.multi_line("xs", "ys", source=src["lines"], color="#555555", line_dash="dashed",
                          legend_label="T = ±√3 N")
        legend_beside(forces)
        structure = lab_figure("analysis-structure", "I(k) and its fit by Gilabert Eq. 28", "k (1/length)",
                               "I(k) (Eq. 25)", x_axis_type="log", y_axis_type="log")
        structure.scatter("k", "intensity", source=src["data"], size=4, legend_label="I(k) of the state")
        structure.line("k", "fitted", source=src["fit"], color="#d62728", line_width=2, legend_label="fit of Eq. 28")
        legend_beside(structure)
        self.figures = {"network": network, "forces": forces, "structure": structure}

    def show(self, result) -> tuple[str, ...]:
        """Feed the figures from ``result`` (an :class:`granlab.app.lab.analysis.AnalysisResult`); the names of
        the figures its report has (:data:`granlab.engine.analysis.report.FIGURES`)."""
        figures = tuple(result.report.figures) if result.report is not None else ()
        src = self.sources
        if "network" in figures:
            for name, columns in analysis.network_segments(result).items():
                src[name].data = columns
        if "forces" in figures:
            for name, columns in analysis.force_scatter(result).items():
                src["forces" if name == "points" else "lines"].data = columns
        if "structure" in figures:
            for name, columns in analysis.structure_curve(result).items():
                src[name].data = columns
        return figures

