"""What every preset is: the :class:`Preset` base the lab's engine thread drives (see the
package's docstring), the :class:`View` of one simulation, and the bounds every preset's
controls share."""

from __future__ import annotations

import dataclasses
import math
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ...errors import ParameterError
from ...observables import columns, coordination, sliding, solid_fraction
from ...params import NORMAL, TANGENTIAL, whole
from ...simulation import Simulation, Snapshot, side_by_side
from ...state import ParticleState
from ..measures import pair_label
from ..settings import LAW_CONTROLS, LabSettings

MAX_CYCLE_STEPS = 1e7
MAX_CYCLE_DISK_STEPS = 2e9
"""The longest period the lab takes: at most these steps, and these steps times disks (about three
minutes of one core: the lab runs some 12 million disk-steps per second, small samples some
60 000 steps per second)."""
MIN_COHESION_KAPPA = 100.0
"""Gilabert's κ = a K_N / F0 is 10³ to 10⁵; the lab goes down to this."""
MAX_SLOWDOWN = 10.0
"""A law change may shorten the preset's time step this much at most."""
CONTROL_SYMBOLS = {"pressure": "P0", "amplitude": "Δσ", "period": "T", "phase": "φ", "friction": "μ",
                   "rolling_friction": "μr", "rolling_stiffness": "Kr", "cohesion_force": "F0", "cohesion_range": "D0",
                   "normal_model": "normal spring", "tangential_model": "spring", "damping_ratio": "ζ"}
"""The settings of the physics, as the plots' change markers name them (speed and the frames kept
change nothing the plots show)."""
MAX_CHANGES = 200
"""Changes remembered (the oldest go first)."""


@dataclass(frozen=True)
class View:
    """A simulation to draw, shifted by ``offset`` (several side by side in one scene), named by
    ``label`` under its disks (none for a preset of one simulation)."""

    sim: Simulation
    offset: tuple[float, float] = (0.0, 0.0)
    label: str = ""


class Preset(ABC):
    """Base of the presets. Subclasses set ``name``, ``title``, ``controls``, ``defaults``,
    ``series`` (and ``path_series``, ``key_plots``, the clock) and implement ``_build``,
    ``_advance`` and ``sample``."""

    name = ""
    title = ""
    #: the preset selector's short name (whole at 1366×768)
    menu_name = ""
    #: controls that act on this preset (the dashboard greys out the others)
    controls: tuple[str, ...] = ()
    #: settings this preset starts from, over LabSettings' defaults
    defaults: dict = {}
    #: observable series it publishes: name -> column names
    series: dict[str, tuple[str, ...]] = {}
    #: the series sampled at the path cadence (paths drawn as lines: watched contacts, springs)
    path_series: tuple[str, ...] = ()
    #: the plots of the preset (the lab's names), and the two that show what it is about
    plots: tuple[str, ...] = ()
    key_plots: tuple[str, ...] = ()
    #: what the speed control counts per second of wall clock (plural); one lasts :meth:`cycle_time`
    clock_unit = "load cycles"
    #: the named speeds beside the numeric one, in clock units per second (inf: as fast as it can);
    #: each is one of the lab's speeds
    speeds = {"slow": 0.2, "normal": 0.5, "fast": 2.0}
    #: the time axes' label (the preset's unit of time)
    time_label = "t"
    #: the time plots show the last ``window_cycles`` clock units (0: the whole run)
    window_cycles = 10
    #: time-series samples per clock unit
    samples_per_cycle = 200
    #: path samples per clock unit: at least one per 1 % of the load amplitude (max |dq/dt| =
    #: 2 pi Delta sigma / T, so 2 pi * 50 = 315 per period)
    path_samples_per_cycle = 320
    #: fewest and most disks the preset can use
    particle_range = (1, 20000)

    def __init__(self, settings: LabSettings | None = None):
        settings = settings if settings is not None else LabSettings().replace(**self.defaults)
        low, high = self.particle_range
        if "particles" in self.controls and not low <= settings.particles <= high:
            raise ParameterError("particles", settings.particles, f"{low} to {high} disks for the {self.name} preset")
        self.settings = settings
        #: changes typed that wait for the start of the next clock unit: key -> value
        self.pending: dict = {}
        #: the changes of the physics so far: {"t", "cycle", "key", "text"}
        self.changes: list[dict] = []
        self.stage = ""
        self._rows = {name: [] for name in self.series}
        self.watch: list[tuple[int, int]] = []
        #: the preset chooses the watched contacts until the user does
        self.auto_watch = True
        #: called (on the engine thread) at each frame time; the engine keeps the frame
        self.on_frame: Callable[[], None] | None = None
        self._build()
        self._own_dt = self.sim.auto_dt()
        self._restart_clock()

    @abstractmethod
    def _build(self) -> None:
        """Create the simulation(s) from ``self.settings``."""

    @abstractmethod
    def _advance(self, steps: int) -> int:
        """Run at most ``steps`` steps of the protocol (at least one); returns the steps run."""

    @abstractmethod
    def sample(self) -> None:
        """Emit the rows of the time series for the current state."""

    def sample_paths(self) -> None:
        """Emit the rows of the path series for the current state."""

    def cycle_time(self) -> float:
        """Simulated time of one clock unit."""
        return self.settings.period

    # -- the engine thread's interface
    @property
    def sim(self) -> Simulation:
        return self.views()[0].sim

    def views(self) -> list[View]:
        return [View(self._sim)]

    def snapshot(self) -> Snapshot:
        """The state of every view as one snapshot (a frame kept for saves and movies)."""
        views = self.views()
        if len(views) == 1:
            return views[0].sim.snapshot()
        return side_by_side([view.sim.snapshot() for view in views], [view.offset for view in views])

    def file_simulation(self) -> tuple[Simulation, bool]:
        """The simulation a run file of this preset is laid out on, and whether the file can hold
        its checkpoint: the preset's own, or for several views a stand-in holding the disks of
        :meth:`snapshot` (with the first view's law), whose state resumes nothing."""
        views = self.views()
        if len(views) == 1:
            return views[0].sim, True
        snap = self.snapshot()
        particles = ParticleState(snap.positions, snap.radii, mass=snap.masses, kind=snap.kinds)
        first = views[0].sim
        return Simulation(particles, first.law, first.integration.replace(dt=first.dt),
                          check_initial_overlap=False), False

    def advance(self, steps: int, deadline: float | None = None) -> int:
        """Run up to ``steps`` steps of the protocol, stopping on the way at every sample time
        (recording the series) and frame time (calling ``on_frame``); returns the steps run.
        With ``deadline`` (a :func:`time.perf_counter` value) it returns at the first sample time
        after it, so that a caller slicing its work by wall clock is never held long."""
        whole("steps", steps, 1)
        done = 0
        while done < steps and (deadline is None or done == 0 or time.perf_counter() < deadline):
            done += self._advance(min(int(steps) - done, self.steps_to_next_sample()))
            self._record_due()
        return done

    def steps_to_next_sample(self) -> int:
        """Steps to the next sample time (of a series, a path or a frame)."""
        return self._steps_until(min(self._due.values()))

    def _steps_until(self, time: float) -> int:
        sim = self.sim
        return max(1, math.ceil((time - sim.time) / sim.dt - 1e-6))

    def _restart_clock(self) -> None:
        """Sample, and take a frame, now; the next ones one interval later (a new stage or a new
        period starts the sampling grid afresh)."""
        now = self.sim.time
        self._due = {"sample": now, "path": now, "frame": now}
        self._record_due()

    def _record_due(self) -> None:
        now, tolerance = self.sim.time, 1e-6 * self.sim.dt
        unit = self.cycle_time()
        for key, per_cycle, record in (("sample", self.samples_per_cycle, self.sample),
                                       ("path", self.path_samples_per_cycle, self._record_paths),
                                       ("frame", self.settings.frames_per_cycle, self._record_frame)):
            if now >= self._due[key] - tolerance:
                record()
                interval = unit / per_cycle
                self._due[key] = max(self._due[key] + interval, now + 0.5 * interval)

    def _record_paths(self) -> None:
        if self.path_series:
            self.sample_paths()

    def _record_frame(self) -> None:
        if self.on_frame is not None:
            self.on_frame()

    def apply(self, **changes) -> list[str]:
        """Change controls (validated first: on error nothing changes). Law controls act at once
        (or wait for the stage that uses them). Returns notes for the user (e.g. the new time step)."""
        values = {**dataclasses.asdict(self.settings), **self.pending, **changes}
        for key, (holds, allowed) in self._rules(values).items():
            if key in changes and not holds:
                raise ParameterError(key, changes[key], allowed)
        self.settings.replace(**{**self.pending, **changes})  # the settings once every change acts
        waiting = {key: value for key, value in changes.items() if key in self._waiting_controls()}
        now = {key: value for key, value in changes.items() if key not in waiting}
        settings = self.settings.replace(**now)
        self._check_time_step({key: getattr(settings, key) for key in LAW_CONTROLS
                               if key in changes and key in self.controls})
        law_changes = {key: getattr(settings, key) for key in self._live_law_controls() if key in now}
        notes = self._set_law(**law_changes) if law_changes else []
        before, self.settings = self.settings, settings
        self._changed(now)
        self._log_changes(before)
        for key, value in waiting.items():  # a value back to the one in effect cancels the change
            if value == getattr(settings, key):
                self.pending.pop(key, None)
            else:
                self.pending[key] = value
        if "rolling_friction" in changes and settings.rolling_friction > 0 and settings.rolling_stiffness == 0 \
                and "rolling_stiffness" in self.controls:
            notes.append("Rolling friction μr acts only through the rolling spring: with Kr = 0 there is no rolling "
                         "moment. Set Kr > 0 (Gilabert: Kr = 1e-4 K_N a²).")
        return notes

    def _waiting_controls(self) -> tuple[str, ...]:
        """Controls that, now, wait for the start of the next clock unit (e.g. a load cycle):
        :meth:`apply` keeps them in ``pending``, the preset applies them with
        :meth:`_apply_pending`."""
        return ()

    def _apply_pending(self) -> None:
        """Let the waiting changes act (the preset calls it where they can)."""
        if self.pending:
            before, self.settings, self.pending = self.settings, self.settings.replace(**self.pending), {}
            self._log_changes(before)

    def cancel_pending(self) -> str:
        """Drop the waiting changes; says which, for the user."""
        if not self.pending:
            return "no change was waiting"
        text = ", ".join(f"{CONTROL_SYMBOLS.get(key, key)} = {setting_text(value)}" for key, value in self.pending.items())
        self.pending = {}
        return f"cancelled: {text} (the values in effect stay)"

    def _log_changes(self, before: LabSettings) -> None:
        """Record each setting of the physics that changed since ``before``, with the time and the
        position in the clock (the plots mark them; a fit starts after them)."""
        for key, symbol in CONTROL_SYMBOLS.items():
            old, new = getattr(before, key), getattr(self.settings, key)
            if old != new:
                self.changes.append({"t": self.sim.time, "cycle": self._clock_position(), "key": key,
                                     "text": f"{symbol} {setting_text(old)} → {setting_text(new)}"})
        del self.changes[:-MAX_CHANGES]

    def _clock_position(self) -> float | None:
        """Where the protocol's clock stands in its units (e.g. 41.3 load cycles), if it counts them."""
        return None

    def _rules(self, values: dict) -> dict[str, tuple[bool, str]]:
        """This preset's rules on its settings given the others (beyond LabSettings' own checks):
        key -> (whether ``values`` keep it, what is allowed and what to change). The bounds of the
        contact law's lengths and forces follow the disks' size and stiffness."""
        sim = self.sim
        radius = float(sim.particles.radius.max())
        stiffness = sim.law.normal_stiffness
        rolling, cohesion, reach = (as_number(values[key]) for key in ("rolling_friction", "cohesion_force",
                                                                   "cohesion_range"))
        return {"rolling_friction": (0.0 <= rolling <= radius or rolling == math.inf,
                                     f"a rolling friction length from 0 to the largest disk's radius {radius:.3g}, or "
                                     f"∞ (no rolling): a rolling moment is at most μr F_n"),
                "cohesion_force": (0.0 <= cohesion <= stiffness * 2.0 * radius / MIN_COHESION_KAPPA,
                                   f"a cohesion from 0 to {stiffness * 2.0 * radius / MIN_COHESION_KAPPA:.3g}: "
                                   f"κ = a K_N / F0 of at least {MIN_COHESION_KAPPA:g} (a = {2.0 * radius:.3g}, "
                                   f"K_N = {stiffness:.3g}); stronger, it presses the disks into each other"),
                "cohesion_range": (0.0 <= reach <= 0.2 * radius,
                                   f"a range from 0 to a tenth of the largest diameter, {0.2 * radius:.3g} (Gilabert: "
                                   f"D0 = 10⁻³ a)")}

    def _period_rule(self, values: dict) -> tuple[bool, str]:
        """From 100 time steps to a cycle the lab runs in a few minutes (and at least the preset's own)."""
        sim = self.sim
        dt, disks = sim.dt, sum(view.sim.particles.count for view in self.views())
        steps = min(MAX_CYCLE_STEPS, MAX_CYCLE_DISK_STEPS / disks)
        longest = max(steps * dt, LabSettings().replace(**self.defaults).period)
        period = as_number(values["period"])
        return (100 * dt <= period <= longest,
                f"a period from 100 time steps to the {steps:,.0f} steps the lab runs in about three minutes: "
                f"{100 * dt:.3g} <= T <= {longest:.4g} (the time step {dt:.3g} follows the stiffness of the "
                f"contacts and the size of the disks)")

    def _check_time_step(self, law_changes: dict) -> None:
        """Refuse a law that would need a time step more than MAX_SLOWDOWN times shorter than the
        preset's own (a stiffer rolling spring, a stronger cohesion): the lab would crawl. Controls
        that wait for a later stage are checked now, when they are typed."""
        if not law_changes:
            return
        dt = self.sim.auto_dt(self.sim.law.replace(**law_changes))
        if dt < self._own_dt / MAX_SLOWDOWN:
            key, value = next(iter(law_changes.items()))
            raise ParameterError(key, value, f"a value whose law needs a time step at most {MAX_SLOWDOWN:g}× shorter "
                                             f"than the preset's {self._own_dt:.3g} (it would need {dt:.3g}: the run "
                                             f"would slow {self._own_dt / dt:.0f}×)")

    def _set_law(self, **changes) -> list[str]:
        """Change the law of every view. The lab's time step is never the user's: when the new law
        (a stiffness, a damping ratio, the cohesion) needs a shorter one, it takes the automatic
        step, which :meth:`_fit_dt` may shorten to end a cycle on a step."""
        before = self.sim.dt
        for view in self.views():
            sim = view.sim
            if sim.dt > sim.auto_dt(sim.law.replace(**changes)):
                sim.set_dt(None)
            sim.set_law(**changes)
        if self.sim.dt != before:
            self._fit_dt()
        after = self.sim.dt
        if abs(after - before) > 1e-3 * before:
            return [f"time step now {after:.3g} (stability bound of the new law; was {before:.3g}): "
                    f"the simulation takes {before / after:.2g}× as many steps per unit of time"]
        return []

    def _fit_dt(self) -> None:
        """Adjust the time step after a law change (hook: a cycle must end on a step)."""

    def _live_law_controls(self) -> tuple[str, ...]:
        """Law controls that act on the simulation now (others wait for a stage of the protocol)."""
        return tuple(key for key in LAW_CONTROLS if key in self.controls)

    def _changed(self, changes: dict) -> None:
        """Hook for controls that act on the protocol."""

    def rows(self) -> dict[str, list[tuple]]:
        """Rows appended to each series since the last call."""
        out = {name: rows for name, rows in self._rows.items() if rows}
        self._rows = {name: [] for name in self.series}
        return out

    def _emit(self, series: str, row: tuple) -> None:
        self._rows[series].append(row)

    def watched(self) -> list[tuple[int, int]]:
        return list(self.watch)

    def watched_labels(self) -> list[str]:
        """The watched contacts' names, as the lab, its saves and its movies show them."""
        sim = self.views()[0].sim
        return [pair_label(pair, sim.particles.count, sim.walls.names) for pair in self.watched()]

    def toggle_watch(self, pair: tuple[int, int]) -> str:
        """Watch (or stop watching) the contact ``pair`` = (i, j), ``j >= N`` for a wall; returns
        what happened, for the user. A pair that cannot exist is refused."""
        sim = self.views()[0].sim
        pair = self._pair(sim, int(pair[0]), int(pair[1]))
        self.auto_watch = False
        label = pair_label(pair, sim.particles.count, sim.walls.names)
        if pair in self.watch:
            self.watch.remove(pair)
            return f"contact {label}: no longer watched"
        self.watch.append(pair)
        snap = sim.contact_snapshot()
        if not np.any((snap.i == pair[0]) & (snap.j == pair[1])):
            return f"contact {label}: watched; not touching now, its path starts when it touches"
        return f"contact {label}: watched"

    @staticmethod
    def _pair(sim: Simulation, i: int, j: int) -> tuple[int, int]:
        """The table's order of a pair: (min, max) for two disks, (disk, N + wall) for a wall."""
        n, walls = sim.particles.count, sim.walls.count
        wall_text = f", walls {n} to {n + walls - 1} ({', '.join(sim.walls.names)})" if walls else ""
        allowed = f"two different disks 0 to {n - 1}{wall_text}"
        if i == j or min(i, j) < 0 or max(i, j) >= n + walls or min(i, j) >= n:
            raise ParameterError("watch contact", f"{i} {j}", allowed)
        return (min(i, j), max(i, j))

    def watch_disk(self, index: int) -> str:
        """Watch every contact of disk ``index`` of the first view (or stop, if one is watched)."""
        sim = self.views()[0].sim
        n = sim.particles.count
        if not 0 <= index < n:
            raise ParameterError("disk", index, f"a disk 0 to {n - 1}")
        snap = sim.contact_snapshot()
        pairs = [(int(i), int(j)) for i, j in zip(snap.i, snap.j) if index in (i, j)]
        self.auto_watch = False
        if any(pair in self.watch for pair in pairs):
            self.watch = [pair for pair in self.watch if pair not in pairs]
            return f"disk {index}: its contacts are no longer watched"
        self.watch.extend(pairs)
        return f"disk {index}: watching its {len(pairs)} contacts" if pairs else f"disk {index} touches nothing"

    def status(self) -> dict:
        return {"preset": self.name, "title": self.title, "stage": self.stage,
                "settings": dataclasses.asdict(self.settings), "pending": dict(self.pending),
                "changes": list(self.changes), "clock_unit": self.clock_unit,
                "cycle_time": self.cycle_time(), "window": self.window_cycles * self.cycle_time(),
                "readout": self.readout()}

    def phase(self) -> str:
        """Where the protocol is, in a few words, for a movie's caption: its stage by default."""
        return self.stage

    def readout(self) -> dict:
        """Figures for the lab's readout strip (those that mean something for the preset): solid
        fraction, coordination, sliding contacts."""
        sim = self.views()[0].sim
        table = columns(sim)
        return {"phi": solid_fraction(sim.particles.radius, sim.box_lengths()), "z": coordination(*table),
                "sliding": int(sliding(table[0]).sum())}


LAW_LABELS = {name: model.label for registry in (NORMAL, TANGENTIAL) for name, model in registry.items()}


def setting_text(value) -> str:
    """A setting as the plots' change markers and the handout say it: a number to four digits, ∞ (also
    as JSON's ``"inf"``), a law by its label."""
    if isinstance(value, float):
        return "∞" if value == math.inf else f"{value:.4g}"
    if value == "inf":
        return "∞"
    return LAW_LABELS.get(value, str(value)) if isinstance(value, str) else str(value)


def as_number(value) -> float:
    """``value`` as a float, NaN if it is not a number (a rule on it then fails)."""
    return float(value) if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool) \
        else math.nan
