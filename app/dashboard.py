"""The dashboard of one browser tab: controls, the embedded 3D scene, live plots.

Every tab builds its own widgets, bokeh figures and ColumnDataSources (bokeh models cannot be
shared between sessions) and pulls, every 200 ms, the rows it has not seen from the engine's
ring buffers. Controls only queue commands for the engine thread; nothing here waits on it.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import panel as pn
from bokeh.models import ColumnDataSource, Span
from bokeh.plotting import figure

from engine.analysis.report import ANALYSES
from engine.errors import ParameterError
from engine.params import TANGENTIAL_MODELS
from engine.protocols.presets import PRESETS, LabSettings

from . import analysis
from .buffers import Cursor
from .drawing import COLOR_FIELDS

STATIC = Path(__file__).resolve().parent.parent / "static"
TOOLS = "pan,wheel_zoom,box_zoom,reset,save"
ROLLOVER = 5000
PRESET_OPTIONS = {cls.title: name for name, cls in PRESETS.items()}
REPLAY = "replay"
STATUS_COLORS = {0: "#bbbbbb", 1: "#1f77b4", 2: "#d62728", 3: "#ff7f0e", 4: "#2ca02c"}


def teaching_text(preset: str) -> str:
    path = STATIC / "teaching" / f"{preset}.md"
    return path.read_text() if path.is_file() else f"*No teaching text for preset {preset!r}.*"


def _figure(name: str, title: str, x: str, y: str, **kwargs):
    fig = figure(name=f"figure-{name}", title=title, tools=TOOLS, height=260, sizing_mode="stretch_width",
                 x_axis_label=x, y_axis_label=y, **kwargs)
    fig.toolbar.logo = None
    return fig


class Dashboard:
    """The page of one tab. ``scene_url`` is the viser client's address."""

    def __init__(self, engine, scene, scene_url: str):
        self.engine = engine
        self.scene = scene
        self.cursors: dict[str, Cursor] = {}
        self.message_cursor = Cursor()
        self.preset_shown = None
        self.sources: dict[str, ColumnDataSource] = {}
        self._all_sources: dict[str, ColumnDataSource] = {}
        self._panes: dict[str, pn.pane.Bokeh] = {}
        self._syncing = False
        self._analysis_seen = 0
        status = engine.status()
        self._build_widgets(status)
        self.analysis_view = self._build_analysis()
        self.tab_choice = pn.widgets.RadioButtonGroup(options=["Plots", "Analysis"], value="Plots",
                                                      css_classes=["tab-choice"])
        self.tab_choice.param.watch(self._show_tab, "value")
        self.plots = pn.Column(sizing_mode="stretch_width")
        self.teaching = pn.pane.Markdown("", sizing_mode="stretch_width", css_classes=["teaching"])
        self.status_line = pn.pane.Markdown("", css_classes=["status-line"])
        self.alert = pn.pane.Alert("", alert_type="info", visible=False, css_classes=["lab-message"])
        self.scene_pane = pn.pane.HTML(
            f'<iframe src="{scene_url}" title="3D scene" style="width:100%;height:520px;border:0"></iframe>',
            sizing_mode="stretch_width", height=530)
        self._refresh()

    # ------------------------------------------------------------------ widgets
    def _build_widgets(self, status: dict) -> None:
        settings = status.get("settings") or vars(LabSettings())
        W = pn.widgets
        self.preset = W.Select(name="Preset", options=PRESET_OPTIONS, value="ratchet", css_classes=["preset-select"])
        self.play = W.Button(name="Pause", button_type="primary", css_classes=["play-button"])
        self.step = W.Button(name="Step", css_classes=["step-button"])
        self.reset = W.Button(name="Reset", button_type="warning", css_classes=["reset-button"])
        self.phase = W.FloatSlider(name="Loading phase φ (°)", start=-180, end=180, step=5,
                                   value=float(settings["phase"]), css_classes=["phase-slider"])
        self.amplitude = W.FloatInput(name="Amplitude Δσ", value=float(settings["amplitude"]), step=0.05,
                                      css_classes=["amplitude-input"])
        self.pressure = W.FloatInput(name="Pressure P0", value=float(settings["pressure"]), step=0.1,
                                     css_classes=["pressure-input"])
        self.period = W.FloatInput(name="Period T", value=float(settings["period"]), step=1.0,
                                   css_classes=["period-input"])
        friction = settings["friction"]
        infinite = not isinstance(friction, (int, float)) or math.isinf(float(friction))
        self.friction = W.FloatSlider(name="Friction μ", start=0.0, end=1.0, step=0.01,
                                      value=0.2 if infinite else float(friction), css_classes=["friction-slider"])
        self.no_sliding = W.Checkbox(name="μ = ∞ (no sliding)", value=infinite, css_classes=["friction-infinite"])
        self.rolling_friction = W.FloatInput(name="Rolling friction μr", value=float(settings["rolling_friction"]),
                                             step=0.001, css_classes=["rolling-friction-input"])
        self.rolling_stiffness = W.FloatInput(name="Rolling stiffness Kr", value=float(settings["rolling_stiffness"]),
                                              step=0.1, css_classes=["rolling-stiffness-input"])
        self.cohesion_force = W.FloatInput(name="Cohesion F0", value=float(settings["cohesion_force"]), step=0.1,
                                           css_classes=["cohesion-force-input"])
        self.cohesion_range = W.FloatInput(name="Cohesion range D0", value=float(settings["cohesion_range"]),
                                           step=0.001, css_classes=["cohesion-range-input"])
        self.model = W.Select(name="Tangential spring", options=list(TANGENTIAL_MODELS),
                              value=settings["tangential_model"], css_classes=["model-select"])
        self.damping = W.FloatSlider(name="Damping ζ", start=0.0, end=0.95, step=0.05,
                                     value=float(settings["damping_ratio"]), css_classes=["damping-slider"])
        self.particles = W.IntInput(name="Disks N", value=int(settings["particles"]), css_classes=["particles-input"])
        self.seed = W.IntInput(name="Seed", value=int(settings["seed"]), css_classes=["seed-input"])
        self.apply_reset = W.Button(name="Apply N and seed (reset)", css_classes=["apply-reset-button"])
        self.speed = W.IntSlider(name="Speed (steps per frame)", start=1, end=2000,
                                 value=int(settings["steps_per_frame"]), css_classes=["speed-slider"])
        self.color = W.Select(name="Colour disks by", options=list(COLOR_FIELDS), value=self.scene.color_field,
                              css_classes=["color-select"])
        self.watch = W.TextInput(name="Watch contact (i j)", placeholder="e.g. 3 7", css_classes=["watch-input"])
        self.watch_button = W.Button(name="Watch / unwatch", css_classes=["watch-button"])
        self.save_name = W.TextInput(name="Save as", placeholder="run1.h5", css_classes=["save-name"])
        self.save = W.Button(name="Save run", css_classes=["save-button"])
        self.load_name = W.Select(name="Replay a saved run", options=self.engine.saved_files(),
                                  css_classes=["load-select"])
        self.load = W.Button(name="Load and replay", css_classes=["load-button"])

        self.preset.param.watch(lambda e: e.new in PRESETS and self._command("preset", name=e.new), "value")
        self.play.on_click(self._toggle_play)
        self.step.on_click(lambda e: self.engine.submit("step"))
        self.reset.on_click(lambda e: self.engine.submit("reset"))
        live = [(self.phase, "phase"), (self.amplitude, "amplitude"), (self.pressure, "pressure"),
                (self.period, "period"), (self.rolling_friction, "rolling_friction"),
                (self.rolling_stiffness, "rolling_stiffness"), (self.cohesion_force, "cohesion_force"),
                (self.cohesion_range, "cohesion_range"), (self.model, "tangential_model"),
                (self.damping, "damping_ratio"), (self.speed, "steps_per_frame")]
        for widget, key in live:
            widget.param.watch(lambda e, key=key: self._control(key, e.new), "value")
        self.settings_widgets = live + [(self.friction, "friction"), (self.no_sliding, "friction"),
                                        (self.particles, "particles"), (self.seed, "seed")]
        self.friction.param.watch(lambda e: self._friction(), "value_throttled")
        self.no_sliding.param.watch(lambda e: self._friction(), "value")
        self.apply_reset.on_click(lambda e: self._control_many(particles=self.particles.value, seed=self.seed.value))
        self.color.param.watch(self._color, "value")
        self.watch_button.on_click(self._watch)
        self.save.on_click(lambda e: self._command("save", name=self.save_name.value.strip()))
        self.load.on_click(lambda e: self._command("load", name=self.load_name.value or ""))

    def _toggle_play(self, event) -> None:
        self.engine.submit("pause" if self.play.name == "Pause" else "play")

    def _friction(self) -> None:
        self._control("friction", math.inf if self.no_sliding.value else float(self.friction.value))

    def _control(self, key: str, value) -> None:
        self._control_many(**{key: value})

    def _control_many(self, **changes) -> None:
        if self._syncing:
            return
        try:
            LabSettings().replace(**changes)
        except (ParameterError, TypeError) as error:
            self._show("error", str(error))
            return
        self._command("apply", changes=changes)

    def _command(self, command: str, **payload) -> None:
        if self._syncing:
            return
        self.engine.submit(command, **payload)

    def _color(self, event) -> None:
        try:
            self.scene.color_field = event.new
        except ValueError as error:
            self._show("error", str(error))

    def _watch(self, event) -> None:
        try:
            i, j = (int(v) for v in self.watch.value.split())
        except ValueError:
            self._show("error", f"watch contact = {self.watch.value!r} is not allowed: two disk indices 'i j' "
                                "(j >= N names a wall)")
            return
        self.engine.submit("watch", pair=(i, j))

    def _show(self, level: str, text: str) -> None:
        self.alert.alert_type = "danger" if level == "error" else "info"
        self.alert.object = text
        self.alert.visible = True

    # ------------------------------------------------------------------ plots
    def _build_plots(self, preset: str, series: list[str]) -> None:
        """Show the figures of ``preset``. Each figure and source is made once per tab and reused
        when a later preset needs it again (bokeh keeps removed models in the document)."""
        self.sources = {}
        figures = []
        if "cycles" in series:
            self._use("cycles", ("cycle", "gamma"), "strain-cycles")
            self._use("fit", ("cycle", "gamma"), "strain-fit")
            figures.append(self._figure_once("strain-per-cycle", self._strain_figure))
        if "time" in series:
            columns = PRESETS[preset].series["time"]
            gilabert = "phi" in columns
            self._use("time", columns, "gilabert-series" if gilabert else "time-series")
            if gilabert:
                figures += [self._figure_once("coordination-gilabert", lambda: self._line_figure(
                                "coordination-gilabert", "Coordination number z", "t", "z", "z")),
                            self._figure_once("solid-fraction", lambda: self._line_figure(
                                "solid-fraction", "Solid fraction Φ", "t", "Φ", "phi"))]
            else:
                figures += [self._figure_once("q-gamma", self._q_gamma_figure),
                            self._figure_once("energy", self._energy_figure),
                            self._figure_once("coordination", lambda: self._line_figure(
                                "coordination", "Coordination number z", "t", "z", "z"))]
        if "contacts" in series:
            self._use("contacts", ("watch", "t", "normal", "tangential", "status", "color"), "cone-paths")
            self._use("cone", ("x", "y"), "cone-lines")
            figures.append(self._figure_once("coulomb-cone", lambda: self._cone_figure(
                "coulomb-cone", "Watched contacts in the (F_n, F_t) plane", "contacts")))
        if "springs" in series:
            self._use("springs", PRESETS["closed-path"].series["springs"], "springs")
            figures += [self._figure_once("springs", self._springs_figure),
                        self._figure_once("spring-path", self._spring_path_figure)]
        if "block" in series:
            self._use("block", ("t", "load_ratio", "normal", "tangential", "status", "velocity", "color"), "block")
            self._use("cone", ("x", "y"), "cone-lines")
            figures += [self._figure_once("block-cone", lambda: self._cone_figure(
                            "block-cone", "Block contact in the (F_n, F_t) plane", "block")),
                        self._figure_once("block-load", self._block_load_figure)]
        if "replay" in series:
            self._use("replay", ("t", "step", "kinetic", "stored", "dissipated", "balance"), "replay-energy")
            figures.append(self._figure_once("replay-energy", self._replay_figure))
        self.plots.objects = [self._panes[name] for name in figures]

    def _use(self, key: str, columns, name: str) -> ColumnDataSource:
        """The tab's source ``name`` (made once), emptied, for series ``key``."""
        source = self._all_sources.get(name)
        if source is None:
            source = self._all_sources[name] = ColumnDataSource({column: [] for column in columns}, name=name)
        source.data = {column: [] for column in columns}
        self.sources[key] = source
        self.cursors[key] = Cursor()
        return source

    def _figure_once(self, name: str, make) -> str:
        if name not in self._panes:
            self._panes[name] = pn.pane.Bokeh(make(), sizing_mode="stretch_width")
        return name

    def _strain_figure(self):
        fig = _figure("strain-per-cycle", "Strain γ at the start of each cycle", "cycle N", "γ")
        fig.scatter("cycle", "gamma", source=self.sources["cycles"], size=6)
        fig.line("cycle", "gamma", source=self.sources["fit"], color="#d62728", line_width=2)
        return fig

    def _line_figure(self, name, title, x_label, y_label, column):
        fig = _figure(name, title, x_label, y_label)
        fig.line("t", column, source=self.sources["time"])
        return fig

    def _q_gamma_figure(self):
        fig = _figure("q-gamma", "Load q against strain γ", "γ", "q")
        fig.line("gamma", "q", source=self.sources["time"])
        return fig

    def _energy_figure(self):
        fig = _figure("energy", "Energy budget", "t", "energy")
        for key, color in (("kinetic", "#1f77b4"), ("stored", "#2ca02c"), ("dissipated", "#d62728"),
                           ("balance", "#000000")):
            fig.line("t", key, source=self.sources["time"], color=color, legend_label=key)
        fig.legend.location = "top_left"
        return fig

    def _cone_figure(self, name, title, key):
        fig = _figure(name, title, "F_n", "F_t")
        fig.scatter("normal", "tangential", source=self.sources[key], color="color", size=3)
        fig.line("x", "y", source=self.sources["cone"], color="#555555", line_dash="dashed")
        return fig

    def _springs_figure(self):
        fig = _figure("springs", "Tangential spring D_t of the three models", "t", "D_t")
        for key, color, label in (("dt_cundall_strack", "#d62728", "Cundall-Strack"),
                                  ("dt_alpha", "#1f77b4", "alpha-corrected"), ("dt_angle", "#2ca02c", "angle")):
            fig.line("t", key, source=self.sources["springs"], color=color, legend_label=label)
        fig.legend.location = "top_left"
        return fig

    def _spring_path_figure(self):
        fig = _figure("spring-path", "(D_t, D_n) along the path", "D_t", "D_n")
        fig.line("dt_cundall_strack", "dn_cundall_strack", source=self.sources["springs"], color="#d62728")
        fig.line("dt_angle", "dn_angle", source=self.sources["springs"], color="#2ca02c")
        return fig

    def _block_load_figure(self):
        fig = _figure("block-load", "Load / μF_n and velocity", "t", "")
        fig.line("t", "load_ratio", source=self.sources["block"], legend_label="load / μF_n")
        fig.line("t", "velocity", source=self.sources["block"], color="#d62728", legend_label="velocity")
        fig.add_layout(Span(location=1.0, dimension="width", line_dash="dotted"))
        return fig

    def _replay_figure(self):
        fig = _figure("replay-energy", "Energy budget of the replayed run", "t", "energy")
        for key, color in (("kinetic", "#1f77b4"), ("stored", "#2ca02c"), ("balance", "#000000")):
            fig.line("t", key, source=self.sources["replay"], color=color, legend_label=key)
        return fig

    # ------------------------------------------------------------------ the Analysis tab
    def _build_analysis(self):
        self.analysis_kind = pn.widgets.Select(name="Analysis", options=list(ANALYSES), value="status",
                                               css_classes=["analysis-select"])
        self.analysis_button = pn.widgets.Button(name="Analyse the current state", button_type="primary",
                                                 css_classes=["analysis-button"])
        self.analysis_button.on_click(lambda e: self._command("analyze", kind=self.analysis_kind.value))
        self.analysis_text = pn.pane.Markdown(
            "Pick an analysis and press the button: it runs on the state of that moment, on its own thread. "
            "*status* draws the force network coloured by the consistent status (blue non-sliding, red sliding; "
            "critical contacts marked, red where the dynamics disagrees); *stiffness* draws the mechanism as "
            "green arrows in the 3D scene; *packing* the (N, T) scatter with the lines T = ±√3 N; *fractal* "
            "I(k) with its fit.", css_classes=["analysis-summary"], sizing_mode="stretch_width")
        self.analysis_sources = {name: ColumnDataSource(columns, name=f"analysis-{name}") for name, columns in (
            ("segments", {"x0": [], "y0": [], "x1": [], "y1": [], "color": []}),
            ("critical", {"x": [], "y": [], "color": []}), ("forces", {"normal": [], "tangential": []}),
            ("lines", {"xs": [], "ys": []}), ("data", {"k": [], "intensity": []}), ("fit", {"k": [], "fitted": []}))}
        src = self.analysis_sources
        network = _figure("analysis-network", "Force network by consistent status", "x", "y", match_aspect=True)
        network.segment("x0", "y0", "x1", "y1", color="color", source=src["segments"], line_width=1.5)
        network.scatter("x", "y", color="color", source=src["critical"], size=7, marker="diamond")
        forces = _figure("analysis-forces", "Contact forces (N, T), lines T = ±√3 N", "N", "T")
        forces.scatter("normal", "tangential", source=src["forces"], size=3, alpha=0.5)
        forces.multi_line("xs", "ys", source=src["lines"], color="#555555", line_dash="dashed")
        structure = _figure("analysis-structure", "I(k) and its fit by Gilabert Eq. 28", "k", "I(k)",
                            x_axis_type="log", y_axis_type="log")
        structure.scatter("k", "intensity", source=src["data"], size=4)
        structure.line("k", "fitted", source=src["fit"], color="#d62728", line_width=2)
        return pn.Column(pn.Row(self.analysis_kind, self.analysis_button), self.analysis_text,
                         *(pn.pane.Bokeh(fig, sizing_mode="stretch_width") for fig in (network, forces, structure)),
                         sizing_mode="stretch_width", visible=False)

    def _show_tab(self, event) -> None:
        """The two tabs below the scene (pn.Tabs would fetch its stylesheets from a CDN)."""
        self.plots.visible = event.new == "Plots"
        self.analysis_view.visible = event.new == "Analysis"

    def _update_analysis(self) -> None:
        result = self.engine.analysis.latest()
        if result.seq == self._analysis_seen:
            return
        self._analysis_seen = result.seq
        self.analysis_text.object = analysis.summary(result)
        if result.report is None:
            return
        kind, src = result.kind, self.analysis_sources
        if kind == "status":
            for name, columns in analysis.network_segments(result).items():
                src[name].data = columns
        elif kind == "packing" and result.state.forces_known:
            for name, columns in analysis.force_scatter(result).items():
                src["forces" if name == "points" else "lines"].data = columns
        elif kind == "fractal":
            for name, columns in analysis.structure_curve(result).items():
                src[name].data = columns
        elif kind == "stiffness":
            self.scene.show_arrows(analysis.mechanism_arrows(result), float(result.state.radii.mean()))

    # ------------------------------------------------------------------ the periodic pull
    def _refresh(self) -> None:
        status = self.engine.status()
        preset = status.get("preset", "")
        if preset != self.preset_shown:
            self.preset_shown = preset
            series = list(PRESETS[preset].series) if preset in PRESETS else ["replay"]
            self._build_plots(preset, series)
            self.teaching.object = teaching_text(preset) if preset in PRESETS else \
                f"## {status.get('title', 'Replay')}\nA saved run played back frame by frame."
            self._sync(status)
        self.play.name = "Pause" if status.get("state") == "running" else "Play"
        self.status_line.object = (f"**{status.get('title', '')}** — {status.get('stage', '')}; "
                                   f"t = {status.get('time', 0):.4g}, step {status.get('step', 0)}, "
                                   f"{status.get('steps_per_s', 0):.0f} steps/s, "
                                   f"{status.get('particles', 0)} disks, state: {status.get('state', '')}")
        cursor, reset, columns = self.engine.messages.since(self.message_cursor)
        self.message_cursor = cursor
        if columns.get("level"):
            self._show(columns["level"][-1], columns["text"][-1])
        elif status.get("error") and not self.alert.visible:
            self._show("error", status["error"])
        for key, source in self.sources.items():
            if key in ("fit", "cone"):
                continue
            self.cursors[key], reset, columns = self.engine.series(key, self.cursors[key])
            if key in ("contacts", "block") and "status" in columns:
                columns["color"] = [STATUS_COLORS.get(int(s), "#000000") for s in columns["status"]]
                if key == "contacts":
                    f0 = float((status.get("settings") or {}).get("cohesion_force", 0.0))
                    columns["normal"] = [n - f0 for n in columns["normal"]]
            columns = {name: values for name, values in columns.items() if name in source.data}
            if reset:
                source.data = columns
            elif columns and len(next(iter(columns.values()))):
                source.stream(columns, rollover=ROLLOVER)
        self._update_fit()
        self._update_cone(status)
        self._update_analysis()
        self.load_name.options = self.engine.saved_files()

    def _sync(self, status: dict) -> None:
        """Show the settings of a new preset in the widgets (without sending them back). During a
        replay the preset list shows "Replay", so that choosing any preset leaves the replay."""
        self._syncing = True
        try:
            self._sync_preset(status)
        finally:
            self._syncing = False

    def _sync_preset(self, status: dict) -> None:
        settings = status.get("settings")
        if status["preset"] not in PRESETS or not settings:
            self.preset.options = {**PRESET_OPTIONS, status.get("title", "Replay"): REPLAY}
            self.preset.value = REPLAY
            for widget, _ in self.settings_widgets:
                widget.disabled = True
            return
        self.preset.options = PRESET_OPTIONS
        self.preset.value = status["preset"]
        enabled = set(PRESETS[status["preset"]].controls) | {"steps_per_frame"}
        for widget, key in self.settings_widgets:
            widget.disabled = key not in enabled
            if widget is self.no_sliding:
                widget.value = isinstance(settings[key], str) or math.isinf(float(settings[key]))
            elif widget is self.friction:
                widget.value = 0.2 if isinstance(settings[key], str) or math.isinf(settings[key]) else settings[key]
            else:
                widget.value = settings[key]

    def _update_fit(self) -> None:
        source = self.sources.get("cycles")
        if source is None:
            return
        cycles = np.asarray(source.data["cycle"], dtype=float)
        gamma = np.asarray(source.data["gamma"], dtype=float)
        start = 30 if cycles.size and cycles.max() >= 40 else 5
        use = cycles >= start
        if use.sum() < 3:
            return
        slope, intercept = np.polyfit(cycles[use], gamma[use], 1)
        x = np.array([cycles[use].min(), cycles[use].max()])
        self.sources["fit"].data = {"cycle": x, "gamma": slope * x + intercept}
        rms = float(np.sqrt(np.mean((gamma[use] - slope * cycles[use] - intercept) ** 2)))
        verdict = "ratcheting" if rms < abs(slope) else "no clear ratcheting"
        self._panes["strain-per-cycle"].object.title.text = f"Strain γ per cycle: Δγ = {slope:.3g} per cycle ({verdict}, from cycle {start})"

    def _update_cone(self, status: dict) -> None:
        source = self.sources.get("cone")
        if source is None:
            return
        settings = status.get("settings") or {}
        friction = settings.get("friction", 0.5)
        mu = math.inf if isinstance(friction, str) else float(friction)
        data = self.sources.get("contacts") or self.sources.get("block")
        top = max([1e-12] + [abs(v) for v in data.data.get("normal", [])])
        f0 = float(settings.get("cohesion_force", 0.0))
        if math.isinf(mu):
            source.data = {"x": [], "y": []}
            return
        xs = [top, -f0, top]
        source.data = {"x": xs, "y": [mu * (top + f0), 0.0, -mu * (top + f0)]}

    # ------------------------------------------------------------------ layout
    def view(self):
        controls = pn.Column(
            self.preset, pn.Row(self.play, self.step, self.reset), self.alert,
            pn.pane.Markdown("**Loading**"), self.phase, self.amplitude, self.pressure, self.period,
            pn.pane.Markdown("**Contacts**"), self.friction, self.no_sliding, self.model, self.damping,
            self.rolling_friction, self.rolling_stiffness, self.cohesion_force, self.cohesion_range,
            pn.pane.Markdown("**Sample**"), self.particles, self.seed, self.apply_reset, self.speed,
            pn.pane.Markdown("**View**"), self.color, self.watch, self.watch_button,
            pn.pane.Markdown("**Files**"), self.save_name, self.save, self.load_name, self.load,
            width=300)
        main = pn.Column(self.status_line, pn.Row(self.scene_pane, self.teaching), self.tab_choice, self.plots,
                         self.analysis_view, sizing_mode="stretch_width")
        page = pn.Row(controls, main, sizing_mode="stretch_width")
        pn.state.add_periodic_callback(self._refresh, period=200)
        return page
