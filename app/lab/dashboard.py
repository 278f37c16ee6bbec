"""The page of one browser tab: one projector screen.

A header with the preset, play/pause/step/restart, the speed in the preset's clock units and a
readout strip; below it the controls on the left (each with its own message line), the 3D
scene with its legend (and a timeline during a replay) in the middle, and on the right the two
plots the preset is about, with the other plots, the preset's explanation and the Analysis tab
one click away. The controls column scrolls where the screen is too short for it (a line at its
foot says so, 1366×768 included); nothing else needs scrolling at 1920×1080 or 1366×768.

Every tab builds its own widgets, bokeh figures and sources (bokeh models cannot be shared
between sessions) and pulls, every 200 ms (a viewer's every second), the rows it has not seen from
the engine's ring buffers; it sends them, with every other change of that refresh, in one message,
once the page has drawn the last one (:mod:`.pace`): a page that draws slowly gets fewer refreshes,
never a queue. Controls only queue commands for the engine thread; nothing here waits on it. A value
the engine refuses goes back to the value in effect, with the message next to its control.
"""

from __future__ import annotations

import json
import math
import time
import urllib.parse
from html import escape
from pathlib import Path

import numpy as np
import panel as pn

from granlab.engine.analysis import ANALYSES
from granlab.engine.errors import ParameterError
from granlab.engine.params import NORMAL_MODELS, TANGENTIAL_MODELS
from granlab.engine.protocols.presets import (FIELD_TYPES, PRESETS, Preset, parse_setup, query_text, setup_text,
                                             speed_text as link_speed)
from granlab.engine.protocols.settings import CONTROL_LABELS

from . import analysis, lessons
from .buffers import Cursor
from .keyboard import Keyboard
from .live import UPDATE_SECONDS, LiveText, describe
from .pace import DRAW_WAIT_SECONDS, Pacer
from .preferences import CALM_SECONDS, Preferences
from ..media.drawing import COLOR_FIELDS, legend_html
from .plots import VIEWER_SHARE, WAITS, AnalysisFigures, compact, make_plot

STATIC = Path(__file__).resolve().parents[2] / "static"
PRESET_OPTIONS = {cls.menu_name: name for name, cls in PRESETS.items()}
REPLAY = "replay"
REFRESH_MS = 200
VIEWER_REFRESH_MS = 1000
"""How often a page pulls the engine's new rows and status (milliseconds): the presenter's often,
for controls that answer at once; a viewer's, one of thirty in a classroom that share the
server's one core for Python with the engine, once a second (its plots get the same rows, in fewer
messages; its scene comes on the viewers' stream, about 12 frames a second). With 30 viewers at 256
disks, 500 ms against 1000 ms: the presenter's latency 854 against 165 ms median, the engine's
share 0.09 against 0.24 (granlab bench --lab --viewers 30 --particles 256, same sitting)."""
FOCUS_CSS = ":focus-visible, .noUi-handle:focus { outline: 3px solid #e65100 !important; outline-offset: 2px; }"
"""Where the keyboard is, in every control: a thick orange ring, visible on a projector."""
NARROW = "@media (max-width: 1100px)"
"""Narrower than this (a tablet held either way, a phone), a viewer's page stacks the scene above the key plots."""
NARROW_PAGE_CSS = NARROW + """ {
  :host { height: auto !important; min-height: 100vh; min-width: 0 !important; }
  .header { height: auto !important; flex: none !important; flex-wrap: wrap !important; min-width: 0 !important; }
  .readout-row { height: auto !important; flex: none !important; min-width: 0 !important; }
  .body { height: auto !important; flex-direction: column !important; min-width: 0 !important; }
}"""
"""(panel gives a row the sum of its children's widths as its min-width: here they wrap instead)"""
NARROW_HEADER_CSS = NARROW + " { .play-button, .step-button, .reset-button, .keys { display: none !important; } }"
"""(a viewer's buttons are disabled: on a small screen they go)"""
NARROW_BODY_CSS = NARROW + """ {
  .controls { display: none !important; }
  .centre { width: auto !important; min-width: 0 !important; height: 60vh !important; flex: none !important; }
  .right { width: auto !important; height: 90vh !important; flex: none !important; }
}"""
CONTROLS_SCROLL_CSS = """:host { overflow-y: scroll !important; scrollbar-color: #8a8f98 #eceef1; scrollbar-width: auto; }
:host::-webkit-scrollbar { width: 12px; } :host::-webkit-scrollbar-thumb { background: #8a8f98; border-radius: 6px; }
:host::-webkit-scrollbar-track { background: #eceef1; }"""
"""The controls column's scroll bar always drawn, wide and grey: a screen too short for the column shows it scrolls."""
MORE_BELOW = "<div class='cue'>▼ more controls below: scroll</div>"
MORE_BELOW_CSS = """:host { position: sticky !important; bottom: 0; z-index: 2;
  animation: more-below linear both; animation-timeline: scroll(nearest); }
@keyframes more-below { 0%, 92% { opacity: 1; } 100% { opacity: 0; } }
.cue { font-size: 13px; color: #fff; background: rgba(60, 64, 72, 0.88); padding: 4px 10px; text-align: center; }"""
"""A line at the foot of the controls column while more of it lies below (it fades out at the end of the
column where the browser ties animations to scrolling; elsewhere it stays)."""
FRICTION_SLIDER_END = 1.0
SPEED_NAMES = ("slow", "normal", "fast")
"""Each preset's named speeds (:attr:`granlab.engine.protocols.presets.Preset.speeds`), on buttons beside the slider."""
COPY_LINK_JS = """
const page = new URLSearchParams(window.location.search)
const query = new URLSearchParams(JSON.parse(link.value))
if (page.get("token")) query.set("token", page.get("token"))
const url = window.location.origin + window.location.pathname + "?" + query.toString()
if (navigator.clipboard) {
  navigator.clipboard.writeText(url).catch(() => window.prompt("Copy this link:", url))
} else {  // a page served on a network over http has no clipboard API
  window.prompt("Copy this link:", url)
}
"""
SPEEDS = {"0.05": 0.05, "0.1": 0.1, "0.2": 0.2, "0.5": 0.5, "1": 1.0, "2": 2.0, "5": 5.0, "10": 10.0, "20": 20.0,
          "50": 50.0, "max": math.inf}
"""Speeds offered, in the preset's clock units per second of wall clock ("max": as fast as it can)."""
ASKED_SECONDS = 10.0
"""How long a widget keeps a value its page asked for while the engine has not answered (then: the value in effect)."""
RESTART_KEYS = ("particles", "seed")
"""The settings typed first and applied by their own button, with a restart."""
JOB_KINDS = ("save", "load", "handout", "record")
"""The file jobs, each shown beside its button while it runs (:mod:`granlab.app.lab.jobs`)."""
PANES = ("Key plots", "More plots", "About", "Lesson", "Analysis")
HEADER_HEIGHT = 58
HEADER_NOTES = ("preset", "run", "speed")
"""Messages shown in the header, beside the buttons that cause them."""
NOTE_SECONDS = 12.0
"""How long a confirmation stays next to its control (errors stay until the next message)."""


def teaching_text(preset: str) -> str:
    path = STATIC / "teaching" / f"{preset}.md"
    return path.read_text() if path.is_file() else f"*No teaching text for preset {preset!r}.*"


def lesson_pane(preset: str) -> str:
    """The preset's lesson sheet with a link to its printable page (served by the lab at ``lesson``)."""
    sheet = lessons.lesson(preset)
    if sheet is None:
        return f"<p><i>No lesson sheet for preset {escape(preset)}.</i></p>"
    return (f"<p style='font-size:13px'><a href='lesson?preset={escape(preset)}' target='_blank'>Print this sheet</a> "
            f"(one page; its shaded boxes are for the teacher)</p>" + lessons.lesson_html(sheet))


def _speed_label(speed) -> str:
    value = math.inf if isinstance(speed, str) else float(speed)
    return min(SPEEDS, key=lambda label: abs(math.log(SPEEDS[label]) - math.log(value))
               if math.isfinite(SPEEDS[label]) and math.isfinite(value) else (0 if SPEEDS[label] == value else 99))


def _note(level: str, text: str, one_line: bool = False) -> str:
    """A message as HTML; ``one_line`` (the header's): cut with an ellipsis, whole on hover."""
    color = {"error": "#b00020", "warning": "#8a5a00"}.get(level, "#1b5e20")
    cut = "white-space:nowrap;overflow:hidden;text-overflow:ellipsis;" if one_line else ""
    return f"<div title='{escape(text, quote=True)}' style='font-size:12px;color:{color};line-height:1.3;{cut}'>" \
           f"{escape(text)}</div>"


class Dashboard:
    """The page of one tab. ``scene_url`` is the viser client's address. A ``viewer`` sees
    everything live but changes nothing: its controls show the values in effect, disabled, its
    Files group is hidden, and the server ignores any command from its page."""

    def __init__(self, engine, scene, scene_url: str, viewer: bool = False, query: dict[str, str] | None = None):
        self.engine = engine
        self.viewer = viewer
        self.scene = scene
        self.cursors: dict[str, Cursor] = {}
        self.message_seq = engine.messages.latest_seq
        self.preset_shown = None
        self.plots: dict = {}
        self.shown: list = []
        self._syncing = False
        self._analysis_seen = 0
        self._legend_key = None
        self._replay_shown = None
        self._settings_shown = None
        self._restart_values_shown: dict[str, object] = {}
        self._asked: dict[str, tuple[object, float]] = {}
        self._pending_shown: set[str] = set()
        self.notes: dict[str, pn.pane.HTML] = {}
        self._note_shown: dict[str, float] = {}
        self._build_widgets()
        self.analysis_view = self._build_analysis()
        self.pane_choice = pn.widgets.RadioButtonGroup(options=list(PANES), value=PANES[0], height=30,
                                                       margin=(4, 10, 2, 10), css_classes=["pane-choice"],
                                                       sizing_mode="stretch_width")
        self.pane_choice.param.watch(lambda e: self._show_pane(), "value")
        self.right = pn.Column(sizing_mode="stretch_both", styles={"flex": "1 1 0"})
        self.waiting = pn.pane.HTML("", visible=False, sizing_mode="stretch_width", css_classes=["plots-waiting"],
                                    margin=(2, 10))
        self.teaching = pn.pane.Markdown("", sizing_mode="stretch_width", css_classes=["teaching"])
        self.about = pn.Column(self.teaching, sizing_mode="stretch_both", scroll=True)
        self.lesson = pn.pane.HTML("", sizing_mode="stretch_width", css_classes=["lesson"])
        self.lesson_view = pn.Column(self.lesson, sizing_mode="stretch_both", scroll=True)
        self.readout = pn.pane.HTML("", css_classes=["readout"], styles={"flex": "0 1 auto", "min-width": "0"},
                                    stylesheets=[NARROW + " { div { white-space: normal !important; } }"]
                                    if viewer else [])
        self.legend = pn.pane.HTML("", sizing_mode="stretch_width", css_classes=["legend"])
        self.scene_pane = pn.pane.HTML(
            f'<iframe src="{scene_url}" title="{"2D" if viewer else "3D"} scene" tabindex="-1" '
            'style="width:100%;height:100%;border:0">'
            '</iframe>',  # out of the Tab order: its viser panel would hold a keyboard user for a dozen stops
            sizing_mode="stretch_both", min_height=300, css_classes=["scene"])
        self.key_names: list[str] = []
        self.page = self._layout()
        for widget in {id(w): w for root in (self.page, self.analysis_view, self.right, self.pane_choice)
                       for w in root.select(pn.widgets.Widget)}.values():
            widget.stylesheets = [*widget.stylesheets, FOCUS_CSS]
        self.preferences.projector = (query or {}).get("profile") == "projector"
        if not viewer:
            self._open_link(query or {})
        self._refresh()

    def _open_link(self, query: dict[str, str]) -> None:
        """The setup a link's address holds (preset, settings, speed), checked here: a link with a
        value the lab does not allow changes nothing and says why."""
        if not set(query) & (set(FIELD_TYPES) | {"preset"}):
            return
        try:
            name, changes = parse_setup(query)
        except ParameterError as error:
            self._note("preset", "error", f"this link's setup was not used (the lab goes on as it was): {error}")
            return
        # said here too: bokeh may build this tab's page twice, and to the second the setup is already running
        self._note("preset", "info", setup_text(name, changes))
        self.engine.submit("setup", name=name, changes=changes)

    # ------------------------------------------------------------------ widgets
    def _note_pane(self, key: str) -> pn.pane.HTML:
        pane = self.notes[key] = pn.pane.HTML("", visible=False, sizing_mode="stretch_width",
                                              css_classes=[f"note-{key}", "control-note"], margin=(0, 10, 4, 10))
        return pane

    def _build_widgets(self) -> None:
        W = pn.widgets
        wide = {"sizing_mode": "stretch_width"}
        self.preset = W.Select(options=PRESET_OPTIONS, value="ratchet", css_classes=["preset-select"], width=270,
                               margin=(12, 10, 5, 10))
        self.play = W.Button(name="Pause", button_type="primary", css_classes=["play-button"], width=72,
                             margin=(12, 4, 5, 4))
        self.step = W.Button(name="Step", css_classes=["step-button"], width=56, margin=(12, 4, 5, 4))
        self.reset = W.Button(name="Restart", button_type="warning", css_classes=["reset-button"], width=76,
                              margin=(12, 4, 5, 4))
        self.defaults = W.Button(name="Reset settings", css_classes=["defaults-button"], width=106,
                                 margin=(12, 4, 5, 4))
        self.speed = W.DiscreteSlider(name="Speed", options=SPEEDS, value=1.0, css_classes=["speed-slider"],
                                      width=150, margin=(2, 8, 5, 12))
        self.named_speeds = {name: W.Button(name=name, css_classes=["named-speed", f"speed-{name}"], width=54,
                                            margin=(12, 1, 5, 1)) for name in SPEED_NAMES}
        self.copy_link = W.Button(name="Copy link", css_classes=["copy-link-button"], width=84, margin=(12, 4, 5, 6))
        self.live = LiveText(css_classes=["live-text"], width=1, height=1, margin=0)
        self.pacer = Pacer(width=0, height=0, margin=0)
        self._sent_at = -math.inf
        self._live_said = -math.inf
        self._live_run: tuple[str, float] | None = None  # (preset, time) at the last refresh
        self.keyboard = Keyboard(enabled=not self.viewer, css_classes=["keys"], width=68, height=31,
                                 margin=(12, 4, 5, 4))
        self.preferences = Preferences(css_classes=["preferences"], width=98, height=31, margin=(12, 4, 5, 4))
        self._refreshes = None  # the page's periodic pull, once the page is served
        # the link's query, which the button's script reads in the page (the clipboard is the page's)
        self.link_query = W.TextInput(value="{}", visible=False, width=10, css_classes=["link-query"])
        # a viewer is shown the speed as text: panel draws a disabled DiscreteSlider with its handle
        # at the far end, whatever its value
        self.speed_text = pn.pane.HTML("", css_classes=["speed-text"], width=230, margin=(14, 12, 5, 12))
        self.phase = W.FloatSlider(name="Loading phase φ (°)", start=-180, end=180, step=5, value=0.0,
                                   css_classes=["phase-slider"], **wide)
        self.amplitude = W.FloatInput(name="Amplitude Δσ", value=0.2, step=0.05, css_classes=["amplitude-input"], **wide)
        self.pressure = W.FloatInput(name="Pressure P0", value=1.0, step=0.1, css_classes=["pressure-input"], **wide)
        self.period = W.FloatInput(name="Period T", value=10.0, step=1.0, css_classes=["period-input"], **wide)
        self.friction = W.FloatSlider(name="Friction μ", start=0.0, end=FRICTION_SLIDER_END, step=0.01, value=0.2,
                                      css_classes=["friction-slider"], **wide)
        self.no_sliding = W.Checkbox(name="μ = ∞ (no sliding)", value=False, css_classes=["friction-infinite"])
        self.model = W.Select(name="Tangential spring", options=list(TANGENTIAL_MODELS), css_classes=["model-select"],
                              **wide)
        self.normal = W.Select(name="Normal spring", options=list(NORMAL_MODELS), css_classes=["normal-select"], **wide)
        self.damping = W.FloatSlider(name="Damping ζ", start=0.0, end=0.95, step=0.05, value=0.3,
                                     css_classes=["damping-slider"], **wide)
        self.rolling_friction = W.FloatInput(name="Rolling friction μr", value=0.0, step=0.001,
                                             css_classes=["rolling-friction-input"], **wide)
        self.rolling_stiffness = W.FloatInput(name="Rolling stiffness Kr", value=0.0, step=0.1,
                                              css_classes=["rolling-stiffness-input"], **wide)
        self.cohesion_force = W.FloatInput(name="Cohesion F0", value=0.0, step=0.1,
                                           css_classes=["cohesion-force-input"], **wide)
        self.cohesion_range = W.FloatInput(name="Cohesion range D0", value=0.0, step=0.001,
                                           css_classes=["cohesion-range-input"], **wide)
        self.particles = W.IntInput(name="Disks N", value=256, css_classes=["particles-input"], **wide)
        self.seed = W.IntInput(name="Seed", value=0, css_classes=["seed-input"], **wide)
        self.apply_reset = W.Button(name="Apply N and seed (restart)", css_classes=["apply-reset-button"], **wide)
        self.cancel_pending = W.Button(name="Cancel the waiting changes", css_classes=["cancel-pending-button"],
                                       visible=False, **wide)
        self.fit_now = W.Button(name="Fit the strain from the next cycle", css_classes=["fit-now-button"], **wide)
        self.color = W.Select(name="Colour disks by", options=list(COLOR_FIELDS), value=self.scene.color_field,
                              css_classes=["color-select"], **wide)
        self.watch = W.TextInput(name="Watch a contact: disks i j (or click a disk)", placeholder="e.g. 3 7",
                                 css_classes=["watch-input"], **wide)
        self.watch_button = W.Button(name="Watch / unwatch", css_classes=["watch-button"], **wide)
        self.save_name = W.TextInput(name="Save the run as", placeholder="run1.h5", css_classes=["save-name"], **wide)
        self.save = W.Button(name="Save run", css_classes=["save-button"], **wide)
        self.load_name = W.Select(name="Replay a saved run", options=self.engine.saved_files(),
                                  css_classes=["load-select"], **wide)
        self.load = W.Button(name="Load and replay", css_classes=["load-button"], **wide)
        self.handout = W.Button(name="Handout: one HTML page of it", css_classes=["handout-button"], **wide)
        self.frames_kept = W.FloatInput(name="Frames kept (replays, movies) per cycle", value=10.0, step=1.0,
                                        start=0.0, css_classes=["frames-input"], **wide)
        self.record_name = W.TextInput(name="Movie of the recent frames", placeholder="movie1.gif or .mp4",
                                       css_classes=["record-name"], **wide)
        self.record_seconds = W.FloatInput(name="of the last (simulated time)", value=20.0, step=5.0,
                                           css_classes=["record-seconds"], **wide)
        self.record = W.Button(name="Record movie", css_classes=["record-button"], **wide)
        self.job_rows = {kind: self._job_row(kind) for kind in JOB_KINDS}
        self.timeline = W.IntSlider(name="Frame", start=1, end=2, value=1, css_classes=["replay-slider"],
                                    sizing_mode="stretch_width")

        self.preset.param.watch(lambda e: e.new in PRESETS and self._command("preset", name=e.new), "value")
        self.play.on_click(lambda e: self._play_pause())
        self.step.on_click(lambda e: self._command("step"))
        self.reset.on_click(lambda e: self._command("reset"))
        self.defaults.on_click(lambda e: self._command("defaults"))
        self.keyboard.param.watch(self._key, "action")
        for name, button in self.named_speeds.items():
            button.on_click(lambda e, name=name: self._control("speed", self._speeds().get(name, 1.0)))
        self.copy_link.js_on_click(args={"link": self.link_query}, code=COPY_LINK_JS)
        self.copy_link.on_click(lambda e: self._note("preset", "info", "link copied: this page's address with ?" +
                                                     urllib.parse.urlencode(json.loads(self.link_query.value))))
        self.speed.param.watch(lambda e: self._control("speed", e.new), "value")
        live = [(self.phase, "phase"), (self.amplitude, "amplitude"), (self.pressure, "pressure"),
                (self.period, "period"), (self.rolling_friction, "rolling_friction"),
                (self.rolling_stiffness, "rolling_stiffness"), (self.cohesion_force, "cohesion_force"),
                (self.cohesion_range, "cohesion_range"), (self.model, "tangential_model"),
                (self.normal, "normal_model"),
                (self.frames_kept, "frames_per_cycle")]
        for widget, key in live:
            widget.param.watch(lambda e, key=key: self._control(key, e.new), "value")
        self.damping.param.watch(lambda e: self._control("damping_ratio", e.new), "value_throttled")
        self.friction.param.watch(lambda e: self._friction(), "value_throttled")
        self.no_sliding.param.watch(lambda e: self._friction(), "value")
        self.settings_widgets = live + [(self.damping, "damping_ratio"), (self.friction, "friction"),
                                        (self.no_sliding, "friction"), (self.particles, "particles"),
                                        (self.seed, "seed")]
        self.cancel_pending.on_click(lambda e: self._command("cancel_pending"))
        self.fit_now.on_click(lambda e: self._command("fit_from_now"))
        self.apply_reset.on_click(lambda e: self._command("apply", changes={"particles": self.particles.value,
                                                                             "seed": self.seed.value}))
        self.color.param.watch(self._color, "value")
        self.preferences.param.watch(lambda e: self._set_projector(), "projector")
        self.preferences.param.watch(lambda e: setattr(self.keyboard, "single_keys", e.new), "single_keys")
        self.preferences.param.watch(lambda e: self._set_pace(), "reduced_motion")
        self.watch_button.on_click(self._watch)
        self.save.on_click(lambda e: self._command("save", name=self.save_name.value.strip()))
        self.load.on_click(lambda e: self._command("load", name=self.load_name.value or ""))
        self.handout.on_click(lambda e: self._command("handout", name=self.load_name.value or ""))
        self.record.on_click(lambda e: self._command("record", name=self.record_name.value.strip(),
                                                     seconds=self.record_seconds.value, color=self.scene.color_field))
        self.timeline.param.watch(lambda e: self._command("seek", index=int(e.new) - 1), "value_throttled")

    def _key(self, event) -> None:
        """A key of the page (:mod:`granlab.app.lab.keyboard`): what its button would do."""
        action = event.new.split(":")[0]
        if action == "play-pause":
            self._play_pause()
        elif action in ("step", "defaults"):
            self._command(action)
        elif action == "restart":
            self._command("reset")

    def _set_projector(self) -> None:
        """This tab's profile: the projector's (large text, thick lines) or the screen's."""
        for plot in self.plots.values():
            plot.set_projector(self.preferences.projector)
        self._legend_key = None
        self._settings_shown = None  # the link says the profile too

    def _set_pace(self) -> None:
        """This tab's refreshes: every :data:`CALM_SECONDS` in reduced motion, else the usual period."""
        if self._refreshes is not None:
            self._refreshes.period = self._refresh_period()

    def _refresh_period(self) -> int:
        if self.preferences.reduced_motion:
            return int(CALM_SECONDS * 1000)
        return VIEWER_REFRESH_MS if self.viewer else REFRESH_MS

    def _play_pause(self) -> None:
        """Pause a running simulation, play a paused one: as it is now, not as the button last showed it."""
        running = self.engine.status().get("state") in ("running", "stepping")
        self._command("pause" if running else "play")

    def _speeds(self) -> dict[str, float]:
        """The named speeds of the preset shown (of the replayed run's preset in a replay)."""
        cls = PRESETS.get(self.preset_shown) or PRESETS.get((self.engine.status().get("replay") or {}).get("of"))
        return cls.speeds if cls else Preset.speeds

    def _friction(self) -> None:
        self._friction_in_effect(not self.no_sliding.value)
        self._control("friction", math.inf if self.no_sliding.value else float(self.friction.value))

    def _control(self, key: str, value) -> None:
        if self._syncing or self.viewer:
            return
        self._asked[key] = (value, time.monotonic())
        self._command("apply", changes={key: value})
        # at once, not at the paced refresh (a second or more after on a busy machine): a Copy link
        # pressed next copies what was asked, and a named speed pressed lights
        self._show_speed_and_link(self.engine.status())

    def _asked_for(self, key: str, in_effect, pending: dict) -> bool:
        """Whether this page asked for another value of ``key`` that the engine has yet to answer
        (apply it, keep it for later, or refuse it): its widget keeps the value asked meanwhile, so a
        refresh with a status from before the change never puts the old value back (and sends it)."""
        if key not in self._asked:
            return False
        value, at = self._asked[key]
        waiting = pending.get(key)
        if in_effect == value or (math.inf if waiting == "inf" else waiting) == value \
                or time.monotonic() - at > ASKED_SECONDS:
            del self._asked[key]
            return False
        return True

    def _friction_in_effect(self, in_effect: bool, locked: bool = False) -> None:
        """With μ = ∞ the slider's value is not in effect: it is disabled and says so (``locked``:
        disabled anyway, in a replay)."""
        self.friction.disabled = locked or not in_effect or self.viewer
        self.friction.name = "Friction μ" if in_effect else "Friction μ (not in effect: μ = ∞)"

    def _job_row(self, kind: str) -> pn.Row:
        """What a file job is doing ("saving run1.h5… 40 %") and its Cancel button, shown while it runs."""
        text = pn.pane.HTML("", css_classes=[f"job-{kind}"], sizing_mode="stretch_width", margin=(8, 4, 0, 10))
        cancel = pn.widgets.Button(name="Cancel", css_classes=[f"cancel-{kind}"], width=70, margin=(4, 10, 4, 0))
        cancel.on_click(lambda e: self._command("cancel", kind=kind))
        return pn.Row(text, cancel, visible=False, sizing_mode="stretch_width")

    def _show_jobs(self, jobs: list[dict]) -> list[str]:
        """Each running job beside its button; returns its short form for the readout strip."""
        running = {job["kind"]: job for job in jobs}
        shown = []
        for kind, row in self.job_rows.items():
            job = running.get(kind)
            row.visible = job is not None and not self.viewer
            if job is None:
                continue
            text = f"{job['label']}… {100 * job['progress']:.0f} %"
            row[0].object = f"<div style='font-size:12px;color:#8a5a00'>{escape(text)} ({job['seconds']:.0f} s)</div>"
            shown.append(text)
        return shown

    def _command(self, command: str, **payload) -> None:
        if self._syncing or self.viewer:
            return
        self._clear_errors()
        if command in ("defaults", "reset"):  # (a preset switch: _new_source)
            self._restart_values_shown = {}  # the settings in effect, N and seed too, back in every box
            self._asked = {}  # and no value asked before keeps its box: Defaults answers them all
        # the widgets this page changed no longer show the settings it showed last: the next refresh shows
        # those in effect even when the engine comes back to them (a value changed, then Defaults, between
        # two late refreshes, left N and ζ on the values the page had asked for)
        self._settings_shown = None
        self.engine.submit(command, **payload)

    def _clear_errors(self) -> None:
        """A new action: the refusals of earlier ones go (the values they concern show the values in effect)."""
        for key, shown in list(self._note_shown.items()):
            if shown == math.inf:
                self.notes[key].visible = False
                del self._note_shown[key]

    def _color(self, event) -> None:
        if self.viewer:  # the scene is shared: its colours are the presenter's choice
            return
        self.scene.color_field = event.new
        self._legend_key = None

    def _watch(self, event) -> None:
        try:
            i, j = (int(v) for v in self.watch.value.split())
        except ValueError:
            self._note("watch", "error", f"“{self.watch.value}” is not a contact: two disk numbers “i j” "
                                         "(a number from N on names a wall)")
            return
        self._command("watch", pair=(i, j))

    def _note(self, key: str, level: str, text: str) -> None:
        key = key if key in self.notes else "run"
        pane = self.notes[key]
        pane.object = _note(level, text, one_line=key in HEADER_NOTES)
        pane.visible = True
        self._note_shown[key] = math.inf if level == "error" else time.monotonic()

    def _expire_notes(self) -> None:
        now = time.monotonic()
        for key, shown in list(self._note_shown.items()):
            if now - shown > NOTE_SECONDS:
                self.notes[key].visible = False
                del self._note_shown[key]

    # ------------------------------------------------------------------ plots
    def _use_plots(self, names: list[str], time_label: str, columns: dict, reference_cycle: int = 0) -> None:
        """Show the plots ``names`` (made once per tab and time axis, emptied for the new source; the
        others emptied too, so that none holds another run's rows when it is shown again)."""
        self.cursors = {}
        self.shown = []
        for plot in self.plots.values():
            plot.clear()
        for name in names:
            key = (name, time_label, tuple(sorted((k, tuple(v)) for k, v in columns.items())), reference_cycle)
            plot = self.plots.get(key)
            if plot is None:  # a plot of the same name may read other columns in another preset
                plot = self.plots[key] = make_plot(name, time_label, columns, reference_cycle)
                plot.set_projector(self.preferences.projector)
                plot.share = VIEWER_SHARE if self.viewer else 1.0
            for series in plot.reads:
                self.cursors[series] = Cursor()
            self.shown.append(plot)

    def plot_bytes(self) -> int:
        """The bytes this page's plots hold (on the server, a copy of what its browser draws)."""
        return sum(plot.nbytes() for plot in self.plots.values())

    @staticmethod
    def _plot_column(panes: list) -> pn.Column:
        """Plots one above the other, each at least PLOT_HEIGHT high: those that do not fit scroll."""
        return pn.Column(*panes, sizing_mode="stretch_both", scroll=True, margin=0)

    def _show_pane(self) -> None:
        choice = self.pane_choice.value
        plots = self.shown
        keys = [p for p in plots if p.name in self.key_names] or plots[:2]
        if choice == "Key plots":
            self.right.objects = [self.pane_choice, self.waiting, self._plot_column([p.pane for p in keys])]
        elif choice == "More plots":
            others = [p.pane for p in plots if p not in keys]
            self.right.objects = [self.pane_choice, self._plot_column(others) if others else
                                  pn.pane.Markdown("*This preset has no other plots.*")]
        elif choice == "About":
            self.right.objects = [self.pane_choice, self.about]
        elif choice == "Lesson":
            self.right.objects = [self.pane_choice, self.lesson_view]
        else:
            self.right.objects = [self.pane_choice, self.analysis_view]

    # ------------------------------------------------------------------ the Analysis tab
    def _build_analysis(self):
        self.analysis_kind = pn.widgets.Select(name="Analysis", options=list(ANALYSES), value="status",
                                               css_classes=["analysis-select"], width=160)
        self.analysis_button = pn.widgets.Button(name="Analyse the current state", button_type="primary",
                                                 css_classes=["analysis-button"], margin=(24, 10, 5, 10))
        self.analysis_button.on_click(lambda e: self._command("analyze", kind=self.analysis_kind.value))
        self.analysis_text = pn.pane.HTML(
            "<p>Pick an analysis and press the button: it runs on the state of that moment, on its own thread, "
            "while the simulation goes on. <i>status</i>: the critical contacts and the consistent state by "
            "minimum sliding, drawn as a force network; <i>stiffness</i>: the mechanism, as arrows in the scene "
            "(their colour in its legend); <i>rigidity</i>: Gilabert's counts; <i>packing</i>: Φ, z, forces, "
            "with the (N, T) scatter; <i>fractal</i>: I(k) and its fit.</p>",
            css_classes=["analysis-summary"], sizing_mode="stretch_width")
        self.analysis_plots = AnalysisFigures()
        for fig in self.analysis_plots.figures.values():
            fig.visible = False  # a hidden pane alone still draws its figure's empty frame
        self.analysis_figures = {name: pn.pane.Bokeh(fig, sizing_mode="stretch_both", min_height=320, visible=False)
                                 for name, fig in self.analysis_plots.figures.items()}
        # the pictures first: on a 768-pixel screen the table below them scrolls
        return pn.Column(pn.Row(self.analysis_kind, self.analysis_button), self._note_pane("analysis"),
                         *self.analysis_figures.values(), self.analysis_text, sizing_mode="stretch_both", scroll=True)

    def _update_analysis(self) -> None:
        result = self.engine.analysis.latest()
        if result.seq == self._analysis_seen:
            return
        self._analysis_seen = result.seq
        self.analysis_text.object = analysis.summary(result)
        figures = self.analysis_plots.show(result)
        for name, pane in self.analysis_figures.items():
            pane.visible = pane.object.visible = name in figures
        if result.report is None:
            return
        self.scene.show_arrows(analysis.mechanism_arrows(result) if "mechanism" in figures else np.zeros((0, 2, 2)),
                               float(result.state.radii.mean()))

    # ------------------------------------------------------------------ the periodic pull
    def _refresh(self) -> None:
        """The page's next refresh, in one message, once the page has drawn the last one."""
        if self.pacer.waiting() and time.monotonic() - self._sent_at < DRAW_WAIT_SECONDS:
            return
        with pn.io.hold():
            self._update()
            self.pacer.sent += 1
        self._sent_at = time.monotonic()

    def _update(self) -> None:
        status = self.engine.status()
        preset = status.get("preset", "")
        replay = status.get("replay")
        shown_as = (replay or {}).get("of") if replay else preset
        if preset != self.preset_shown:
            self.preset_shown = preset
            self._new_source(status, shown_as)
        self._pull(status)
        self._say_what_plots_wait_for(status)
        self._expire_notes()
        self._messages(status)
        settings_key = repr((status.get("settings"), status.get("pending")))
        if settings_key != self._settings_shown:  # another tab's change, a change that waited, a refusal
            self._settings_shown = settings_key
            self._sync(status)
        self._show_status(status)
        self._show_pending(status)
        self._update_analysis()
        self.load_name.options = self.engine.saved_files()

    def _new_source(self, status: dict, shown_as: str | None) -> None:
        """A new preset or replay: its plots, its text, its settings in the widgets."""
        cls = PRESETS.get(shown_as)
        if cls is None:
            plot = (status.get("replay") or {}).get("plot", "replay-energy")
            self.key_names = [plot]
            self._use_plots(self.key_names, "t", {})
            self.lesson.object = "<p><i>The lesson sheets go with the presets: choose one.</i></p>"
            if plot == "replay-energy":
                self.teaching.object = f"## {status.get('title', 'Replay')}\nA saved run played back frame by frame."
            else:
                self.teaching.object = (f"## {status.get('title', 'Replay')}\nA packing made by another code, played "
                                        "back frame by frame: its coordination z per frame, and the forces of its "
                                        "contacts when a LAMMPS dump came with `NAME-contacts.dump` beside it. The "
                                        "Analysis tab analyses the frame shown.")
                self.color.value = "coordination"  # another code's disks have no rotation angle
        else:
            self.key_names = list(cls.key_plots)
            self._use_plots(list(cls.plots), cls.time_label, cls.series, getattr(cls, "reference_cycle", 0))
            self.teaching.object = teaching_text(shown_as)
            self.lesson.object = lesson_pane(shown_as)
        self.pane_choice.value = PANES[0]
        self._show_pane()
        self._restart_values_shown = {}
        self._sync(status)
        self._legend_key = None

    def _pull(self, status: dict) -> None:
        for series, cursor in list(self.cursors.items()):
            now, reset, columns = self.engine.series(series, cursor)
            if now.run != status.get("run"):  # rows of a run the status is not yet (or no longer) about
                continue
            self.cursors[series] = now
            if not reset and not (columns and len(next(iter(columns.values())))):
                continue
            for plot in self.shown:
                if series in plot.reads:
                    plot.feed(series, columns, reset, status)
        for plot in self.shown:
            plot.refresh(status)

    def _say_what_plots_wait_for(self, status: dict) -> None:
        """Above the key plots, while any is empty: what it waits for, and what the run does now."""
        empty = [plot for plot in self.shown if plot.name in self.key_names and plot.empty()]
        text = " ".join(f"<b>{escape(plot.title)}</b>: "
                        f"{escape(WAITS.get(plot.name, 'waiting for its first samples'))}." for plot in empty)
        if text and status.get("stage"):
            text += (f" Now: <i>{escape(status['stage'])}</i>, {escape(status.get('time_label', 't'))} = "
                     f"{compact(status.get('time', 0.0))}.")
        if text:
            self.waiting.object = f"<div style='font-size:13px;color:#8a5a00;line-height:1.3'>{text}</div>"
        self.waiting.visible = bool(text)

    def _messages(self, status: dict) -> None:
        """Each new message next to the control that caused it; a refused setting goes back to
        the value in effect."""
        for message in self.engine.messages.since(self.message_seq):
            self.message_seq = message.seq
            self._note(message.control, message.level, message.text)
            if message.level == "error" and message.control in CONTROL_LABELS:
                self._restart_values_shown.pop(message.control, None)
                self._asked.pop(message.control, None)
                self._sync(status)

    def _show_pending(self, status: dict) -> None:
        """Beside each control whose change waits: the value it will take, and in how long."""
        pending = status.get("pending") or {}
        if not pending and not self._pending_shown:
            return
        left = float(status.get("pending_at", 0.0)) - float(status.get("time", 0.0))
        pace = float(status.get("speed_achieved", 0.0)) * float(status.get("cycle_time", 0.0))
        when = f"in {left / pace:.0f} s" if pace > 0 else "when the run goes on"
        for key in self._pending_shown - set(pending):
            self.notes[key].visible = False
        for key, value in pending.items():
            if key in self.notes:
                shown = "∞" if value == "inf" else (f"{value:g}" if isinstance(value, (int, float)) else value)
                self.notes[key].object = _note("warning", f"from {status.get('pending_from', 'later')}: "
                                                          f"{CONTROL_LABELS.get(key, key)} = {shown} ({when})")
                self.notes[key].visible = True
                self._note_shown.pop(key, None)
        self._pending_shown = set(pending)
        self.cancel_pending.visible = bool(pending) and not self.viewer

    def _show_status(self, status: dict) -> None:
        state = status.get("state", "")
        self.play.name = "Pause" if state in ("running", "stepping") else "Play"
        if state == "error" and not self.notes["run"].visible:
            self._note("run", "error", status.get("error", ""))
        unit = status.get("clock_unit", "")
        self.speed.name = f"Speed ({unit} per second)" if unit else "Speed"
        self.speed_text.object = (f"<div style='font-size:14px'>{escape(self.speed.name)}: "
                                  f"<b>{_speed_label(self.speed.value)}</b></div>")
        self.frames_kept.name = f"Frames kept (replays, movies) per {unit.split()[-1].rstrip('s')}"
        self._show_speed_and_link(status)
        self._say(status)
        readout = status.get("readout") or {}
        fit = status.get("strain") or {}
        parts = [f"<b>{status.get('stage', '')}</b>",
                 f"{status.get('time_label', 't')} = {compact(status.get('time', 0.0))}"]
        if "cycle" in status:
            parts.append(f"cycle {status['cycle']}")
        if fit:
            parts.append(f"Δγ/cycle = {compact(fit.get('dgamma'))}")
        shown = {"phi": lambda v: f"Φ = {v:.3f}", "z": lambda v: f"z = {v:.2f}",
                 "sliding": lambda v: f"sliding: {v}", "loops": lambda v: f"loop {v}",
                 "load": lambda v: f"load = {v:.2f} μF_n", "collisions": lambda v: f"collisions: {v}",
                 "restitution": lambda v: "" if v is None else f"e_N = {v:.4f} measured",
                 "predicted": lambda v: f"{v:.4f} predicted"}
        parts += [shown[key](value) for key, value in readout.items() if key in shown]
        achieved = status.get("speed_achieved", 0.0)
        if state == "stepping":
            state = f"stepping… {100 * status.get('step_progress', 0.0):.0f} %"
        parts.append(f"{achieved:.2g} {unit.split()[-1]}/s" if state == "running" and unit else state)
        if state == "running":
            parts.append(f"{status.get('steps_per_s', 0.0) / 1000.0:.3g} k steps/s")
        parts += [f"<span style='color:#8a5a00'>{escape(job)}</span>" for job in self._show_jobs(status.get("jobs", []))]
        size = 16 if self.preferences.projector else 14  # 16 px: the most the strip's 26 px hold
        self.readout.object = (f"<div style='font-size:{size}px;line-height:1.3;padding:2px 0 0 10px;"
                               "white-space:nowrap'>" + " · ".join(p for p in parts if p) + "</div>")
        scene = self.scene.state()
        key = (self.scene.color_field, tuple(status.get("watched_labels") or ()), scene.get("walls", 0) > 0,
               scene.get("cell") is not None, scene.get("mechanism", False), self.preferences.projector)
        if key != self._legend_key:
            self._legend_key = key
            legend = legend_html(self.scene.color_field, list(key[1]), *key[2:5])
            self.legend.object = f"<div style='zoom:1.2'>{legend}</div>" if self.preferences.projector else legend
        self._show_replay(status)

    def _say(self, status: dict) -> None:
        """The live text: the state every few seconds, an alert when the run starts again."""
        now = time.monotonic()
        run = (status.get("preset", ""), float(status.get("time", 0.0)))
        last = self._live_run or run
        if status.get("replay") is None and (run[0] != last[0] or run[1] < last[1]):
            self.live.alert = escape(f"{time.strftime('%H:%M:%S')}: {status.get('title', run[0])} starts from t = 0 "
                                     f"({status.get('state', '')}).")
            self._live_said = -math.inf
        self._live_run = run
        if now - self._live_said >= UPDATE_SECONDS:
            self._live_said = now
            self.live.polite = escape(describe(status, self.scene.state()))

    def _show_speed_and_link(self, status: dict) -> None:
        """The named speed in effect highlighted and the link's query kept for the Copy link button, each
        with what this page asked for and the engine has yet to answer."""
        replay = status.get("replay")
        settings = status.get("settings") or {}
        pending = status.get("pending") or {}
        link = dict(status.get("link") or {"preset": status.get("preset", "ratchet")})
        speed = status.get("speed") if replay else settings.get("speed")
        for key, (value, _) in list(self._asked.items()):
            in_effect = speed if key == "speed" else settings.get(key)
            if self._asked_for(key, math.inf if in_effect == "inf" else in_effect, pending):
                named = key == "speed" and link.get("preset") in PRESETS
                link[key] = link_speed(link["preset"], value) if named else query_text(value)
                speed = value if key == "speed" else speed
        speed = math.inf if speed == "inf" else speed
        speeds = self._speeds()
        for name, button in self.named_speeds.items():
            button.button_type = "primary" if speeds.get(name) == speed else "default"
        link = json.dumps({**link, **({"profile": "projector"} if self.preferences.projector else {})})
        if self.link_query.value != link:
            self.link_query.value = link

    def _show_replay(self, status: dict) -> None:
        replay = status.get("replay")
        self.timeline_row.visible = replay is not None
        if replay is None:
            return
        frame, frames = replay["frame"], replay["frames"]
        if (frame, frames) != self._replay_shown:
            self._replay_shown = (frame, frames)
            self._syncing = True
            try:
                if self.timeline.end != max(2, frames):  # frames counted from 1, as the label beside it
                    self.timeline.end = max(2, frames)
                self.timeline.value = frame + 1
            finally:
                self._syncing = False
            self.timeline_label.object = (f"<div style='font-size:13px;padding-top:18px'>frame {frame + 1} of "
                                          f"{frames}, {status.get('time_label', 't')} = "
                                          f"{compact(status.get('time', 0.0))}</div>")
            self._sync(status)

    def _sync(self, status: dict) -> None:
        """Show the settings in effect (or those of the replayed frame) in the widgets, without
        sending them back; show only the controls the preset uses."""
        self._syncing = True
        try:
            self._sync_widgets(status)
        finally:
            self._syncing = False

    def _sync_widgets(self, status: dict) -> None:
        settings = status.get("settings")
        replay = status.get("replay")
        if replay is not None:
            self.preset.options = {**PRESET_OPTIONS, status.get("title", "Replay"): REPLAY}
            self.preset.value = REPLAY
        else:
            self.preset.options = PRESET_OPTIONS
            self.preset.value = status["preset"]
        pending = status.get("pending") or {}
        speed = status.get("speed") if replay is not None else (settings or {}).get("speed")
        if speed is not None and not self._asked_for("speed", math.inf if speed == "inf" else speed, pending):
            self.speed.value = SPEEDS[_speed_label(speed)]
        cls = PRESETS.get(replay["of"] if replay else status["preset"])
        used = set(cls.controls) if cls else set()
        for widget, key in self.settings_widgets:
            widget.visible = key in used or key == "frames_per_cycle"
            widget.disabled = replay is not None or self.viewer
            if not settings or key not in settings:
                continue
            value = math.inf if settings[key] == "inf" else settings[key]  # JSON carries inf as "inf"
            if self._asked_for(key, value, pending):
                continue
            if key in RESTART_KEYS:  # a value typed, waiting for its Apply button, stays until the run's own changes
                if self._restart_values_shown.get(key) == value:
                    continue
                self._restart_values_shown[key] = value
            if widget is self.no_sliding:
                widget.value = value == math.inf
            elif widget is self.friction:
                if value != math.inf:  # a μ beyond the slider's end (a link's, up to 10) moves the end
                    widget.end = max(FRICTION_SLIDER_END, float(value))
                    widget.value = float(value)
                self._friction_in_effect(value != math.inf, locked=widget.disabled)
            else:
                widget.value = value
        self.apply_reset.visible = "particles" in used
        self.fit_now.visible = "strain-per-cycle" in getattr(cls, "plots", ()) and replay is None and not self.viewer
        for group, keys in self.groups.items():
            group.visible = bool(used & keys)
        self.no_controls.visible = not used
        self.no_controls.object = ("<i>A replay of a run file that has no lab settings: only its speed and its "
                                   "timeline.</i>" if replay is not None else
                                   "<i>This preset has no live controls: only its speed.</i>")

    # ------------------------------------------------------------------ layout
    def view(self):
        self._refreshes = pn.state.add_periodic_callback(self._refresh, period=self._refresh_period())
        return self.page

    def _layout(self):
        def labelled(widget, key):
            return [widget, self._note_pane(key)]

        loading = pn.Column(pn.pane.HTML("<b>Loading</b>"), *labelled(self.phase, "phase"),
                            *labelled(self.amplitude, "amplitude"), *labelled(self.pressure, "pressure"),
                            *labelled(self.period, "period"), self.cancel_pending, self._note_pane("pending"),
                            self.fit_now, self._note_pane("fit"), sizing_mode="stretch_width")
        contacts = pn.Column(pn.pane.HTML("<b>Contacts</b>"), self.friction, *labelled(self.no_sliding, "friction"),
                             *labelled(self.model, "tangential_model"), *labelled(self.normal, "normal_model"),
                             *labelled(self.damping, "damping_ratio"),
                             *labelled(self.rolling_friction, "rolling_friction"),
                             *labelled(self.rolling_stiffness, "rolling_stiffness"),
                             *labelled(self.cohesion_force, "cohesion_force"),
                             *labelled(self.cohesion_range, "cohesion_range"), sizing_mode="stretch_width")
        sample = pn.Column(pn.pane.HTML("<b>Sample</b>"), *labelled(self.particles, "particles"),
                           *labelled(self.seed, "seed"), self.apply_reset, sizing_mode="stretch_width")
        self.groups = {loading: {"phase", "amplitude", "pressure", "period"},
                       contacts: {"friction", "tangential_model", "normal_model", "damping_ratio", "rolling_friction",
                                  "rolling_stiffness", "cohesion_force", "cohesion_range"},
                       sample: {"particles", "seed"}}
        self.no_controls = pn.pane.HTML("<i>This preset has no live controls: only its speed.</i>",
                                        sizing_mode="stretch_width")
        view = pn.Column(pn.pane.HTML("<b>View</b>"), self.color, self.watch, self.watch_button,
                         self._note_pane("watch"), sizing_mode="stretch_width")
        files = pn.Column(pn.pane.HTML("<b>Files</b> (in the lab's data folder)"),
                          *labelled(self.frames_kept, "frames_per_cycle"), self.save_name, self.save,
                          self.job_rows["save"], self._note_pane("save"), self.load_name, self.load,
                          self.job_rows["load"], self._note_pane("load"), self.handout,
                          self.job_rows["handout"], self._note_pane("handout"), self.record_name, self.record_seconds,
                          self.record, self.job_rows["record"], self._note_pane("record"),
                          sizing_mode="stretch_width")
        if self.viewer:
            files.visible = False
            self.fit_now.visible = False
            for widget in (self.preset, self.play, self.step, self.reset, self.apply_reset, self.color,
                           self.watch, self.watch_button, self.analysis_kind, self.analysis_button, self.timeline):
                widget.disabled = True
        more = pn.pane.HTML(MORE_BELOW, css_classes=["more-below"], sizing_mode="stretch_width", margin=0,
                            stylesheets=[MORE_BELOW_CSS])
        sidebar = pn.Column(self.no_controls, loading, contacts, sample, view, files, self.link_query, self.live, more,
                            width=250, sizing_mode="stretch_height", scroll=True, css_classes=["controls"],
                            stylesheets=[CONTROLS_SCROLL_CSS])
        title = ("GranLab<div class='viewer-badge' style='font-size:13px;font-weight:normal'>viewer: the presenter "
                 "runs it</div>" if self.viewer else "GranLab")
        # only what this tab shows: a hidden widget in a row still widens it
        controls = ([self.speed_text, self.keyboard, self.preferences] if self.viewer else
                    [self.defaults, self.speed, *self.named_speeds.values(), self.copy_link, self.keyboard,
                     self.preferences])
        header = pn.Row(pn.pane.HTML(f"<div style='font-size:22px;font-weight:bold;padding-top:8px'>{title}</div>",
                                     width=105 + 95 * self.viewer),
                        self.preset, self.play, self.step, self.reset, *controls,
                        height=HEADER_HEIGHT, sizing_mode="stretch_width", styles={"overflow": "hidden"},
                        css_classes=["header"], stylesheets=[NARROW_HEADER_CSS] if self.viewer else [])
        # the readout on a line of its own, of fixed height: nothing below it moves as it changes; the
        # header's messages at its right end, beside the buttons that cause them
        notes = pn.Column(*(self._note_pane(key) for key in HEADER_NOTES), sizing_mode="stretch_width",
                          margin=(5, 0, 0, 0), styles={"flex": "1 1 0", "min-width": "0", "overflow": "hidden"})
        readout = pn.Row(self.readout, notes, self.pacer, height=26, sizing_mode="stretch_width", margin=0,
                         styles={"border-bottom": "1px solid #ddd", "background": "#f6f7f9", "overflow": "hidden"},
                         css_classes=["readout-row"])
        self.timeline_label = pn.pane.HTML("", width=220)
        self.timeline_row = pn.Row(self.timeline, self.timeline_label, self._note_pane("replay"),
                                   sizing_mode="stretch_width", visible=False, css_classes=["timeline"])
        # at least 600 px: narrower, viser lays its control panel over the scene as a bottom sheet
        centre = pn.Column(self.scene_pane, self.legend, self.timeline_row, sizing_mode="stretch_both", min_width=600,
                           styles={"flex": "1.25 1 0"}, css_classes=["centre"])
        self.right.css_classes = ["right"]
        # a viewer's tablet or phone: the scene, then the key plots, one above the other
        narrow = [NARROW_PAGE_CSS] if self.viewer else []
        body = pn.Row(sidebar, centre, self.right, sizing_mode="stretch_both", css_classes=["body"],
                      stylesheets=[NARROW_BODY_CSS] if self.viewer else [])
        return pn.Column(header, readout, body, sizing_mode="stretch_both", stylesheets=narrow)
