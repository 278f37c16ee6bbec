"""The lab's presets: each sets up a figure of the papers and advances it step by step.

A preset owns its simulation(s) and the protocol around them (compression then cyclic
loading, a closed path carried over and over, a load ramp, aggregation then compression).
The lab's engine thread calls :meth:`Preset.advance`, then reads :meth:`Preset.rows`,
:meth:`Preset.views` and :meth:`Preset.watched`; controls reach it through :meth:`Preset.apply`.

Everything a preset records is sampled in simulated time, never by how often someone asks:
each preset has a clock unit (a load cycle, a loop of the closed path, Gilabert's T_0) that
lasts :meth:`Preset.cycle_time`, and :meth:`Preset.advance` stops on its way at every sample
time to record the time series (``samples_per_cycle`` per unit), the paths of watched
contacts (``path_samples_per_cycle``) and, through ``on_frame``, the frames a replay keeps
(the setting ``frames_per_cycle``). A fast preset therefore draws smooth paths however fast it runs.
Nothing here imports a UI library: presets run headless in tests.
"""

from __future__ import annotations

import dataclasses
import math
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..analysis.ratchet import ratchet_verdict
from ..errors import ParameterError
from ..observables import clusters, columns, coordination, sliding, solid_fraction
from ..params import TANGENTIAL, TANGENTIAL_MODELS, ContactLaw, Integration, PeriodicCell, Wall
from ..simulation import Simulation, Snapshot, side_by_side
from ..state import ParticleState
from .cyclic import CyclicLoad, apply_load
from .equilibrium import equilibrium, measured_pressure
from .measures import PairMaximum, contact_rows, mobilisation, pair_label
from .prepare import COMPRESSION_RAMP, biaxial_box, gilabert_gas, gilabert_law, hold_load, ramp_load
from .settings import LAW_CONTROLS, LabSettings

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
                   "tangential_model": "spring", "damping_ratio": "ζ"}
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
        if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 1:
            raise ParameterError("steps", steps, "a whole number >= 1")
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
        text = ", ".join(f"{CONTROL_SYMBOLS.get(key, key)} = {_value_text(value)}" for key, value in self.pending.items())
        self.pending = {}
        return f"cancelled: {text} (the values in effect stay)"

    def _log_changes(self, before: LabSettings) -> None:
        """Record each setting of the physics that changed since ``before``, with the time and the
        position in the clock (the plots mark them; a fit starts after them)."""
        for key, symbol in CONTROL_SYMBOLS.items():
            old, new = getattr(before, key), getattr(self.settings, key)
            if old != new:
                self.changes.append({"t": self.sim.time, "cycle": self._clock_position(), "key": key,
                                     "text": f"{symbol} {_value_text(old)} → {_value_text(new)}"})
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
        rolling, cohesion, reach = (_real(values[key]) for key in ("rolling_friction", "cohesion_force",
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
        period = _real(values["period"])
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


def _value_text(value) -> str:
    if isinstance(value, float):
        return "∞" if value == math.inf else f"{value:.4g}"
    return str(value)


def _real(value) -> float:
    """``value`` as a float, NaN if it is not a number (a rule on it then fails)."""
    return float(value) if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool) \
        else math.nan


# ---------------------------------------------------------------------------------------------- ratchet
class RatchetPreset(Preset):
    """A biaxial box compressed frictionless to P0, then cyclically loaded (ratcheting Eq. 1).

    Stages: ``compressing`` (until Gilabert's equilibrium or 200 tau), then ``cycling``. While
    cycling, P0, the amplitude and the phase wait for the next cycle start, where q = 0 (they are
    ``pending`` until then); a new period acts at once, at the same fraction of the cycle, so that
    the load goes on smoothly; each cycle ends on a step (the time step is fitted to it). Series: ``time`` (t, cycle, q,
    gamma, energies, z; cycle -1 while compressing), ``cycles`` (cycle, gamma at the start of the
    cycle, t, step, box lengths), ``contacts`` (i, j, t, F_n, F_t, status of the watched pairs).
    The watched contacts are the ``watch_count`` that came closest to the Coulomb cone during
    the first cycle (the ones that slid, if any), until the user picks others. The strain per
    cycle is fitted (:func:`granlab.engine.analysis.ratchet.ratchet_verdict`) from ``reference_cycle``
    on: the first cycles settle the packing; after a change of the physics, from the second
    whole cycle after it (``fit_from``), or from the next cycle start on request (:meth:`fit_from_now`).
    """

    name = "ratchet"
    title = "Biaxial box under cyclic loading"
    menu_name = "Biaxial box, cyclic loading"
    controls = ("pressure", "amplitude", "period", "phase", "particles", "seed") + LAW_CONTROLS
    defaults = {"particles": 256, "speed": math.inf}
    series = {"time": ("t", "cycle", "q", "gamma", "kinetic", "stored", "dissipated", "balance", "z"),
              "cycles": ("cycle", "gamma", "t", "step", "length_x", "length_y"),
              "contacts": ("i", "j", "t", "normal", "tangential", "status")}
    path_series = ("contacts",)
    plots = ("strain-per-cycle", "q-gamma", "coulomb-cone", "energy", "coordination")
    key_plots = ("q-gamma", "strain-per-cycle")
    time_label = "t (τ = √(ρL²/P))"
    particle_range = (4, 20000)
    elliptic = False
    compression_limit = 200.0
    watch_count = 4
    reference_cycle = 2

    def _build(self) -> None:
        s = self.settings
        # compressed as by prepare.compress, a step at a time: walls of one row, the load ramped
        self._sim = biaxial_box(s.particles, seed=s.seed, pressure=s.pressure, damping_ratio=s.damping_ratio,
                                tangential_model=s.tangential_model)
        ramp_load(self._sim, s.pressure, COMPRESSION_RAMP)
        self.stage = "compressing"
        self._ramping = True
        self._cycle = 0
        self._next_check = 1.0
        self._start = None
        self.fit_from = self.reference_cycle
        self.fit_after = ""
        self._cycle_end = math.inf
        self._cycle_gamma: list[tuple[int, float]] = []
        self.verdict = None

    def _rules(self, values: dict) -> dict[str, tuple[bool, str]]:
        pressure, amplitude = _real(values["pressure"]), _real(values["amplitude"])
        stiffness = self.sim.law.normal_stiffness
        low, high = stiffness / 1e4, stiffness / 20.0
        return {**super()._rules(values),
                "amplitude": (0.0 <= amplitude <= 2.0 * pressure,
                              f"an amplitude from 0 to 2 P0 = {2.0 * pressure:g} (P0 = {pressure:g}): the load must "
                              f"not swing further than the box is pressed; raise P0 first to load harder"),
                "pressure": (low <= pressure <= high and pressure >= 0.5 * amplitude,
                             f"a pressure from {low:.3g} to {high:.3g} (K_N / P0 from 10⁴ to 20, K_N = {stiffness:g}: "
                             f"harder, the disks sink into each other) and at least Δσ/2 = {0.5 * amplitude:g} "
                             f"(Δσ = {amplitude:g}); lower Δσ first to unload further"),
                "period": self._period_rule(values)}

    def _load(self) -> CyclicLoad:
        s = self.settings
        phase = math.radians(s.phase) if (self.elliptic or s.phase != 0.0) else None
        return CyclicLoad(pressure=s.pressure, amplitude=s.amplitude, period=s.period, phase=phase)

    def cycle_time(self) -> float:
        return self.load.period if self.stage == "cycling" else self.settings.period

    def _live_law_controls(self) -> tuple[str, ...]:
        # the compression is frictionless: friction and rolling resistance wait for the cycling
        waiting = ("friction", "rolling_friction", "rolling_stiffness") if self.stage == "compressing" else ()
        return tuple(key for key in super()._live_law_controls() if key not in waiting)

    def _waiting_controls(self) -> tuple[str, ...]:
        return ("pressure", "amplitude", "phase") if self.stage == "cycling" else ()

    def _changed(self, changes: dict) -> None:
        """A new period acts at once: the cycle under way goes on at the same fraction of it."""
        if "period" in changes and self.stage == "cycling":
            sim = self._sim
            fraction = (sim.time - self._start) / self.load.period
            self.load = dataclasses.replace(self.load, period=self.settings.period)
            self._start = apply_load(sim, self.load, start=sim.time - fraction * self.load.period)
            self._cycle_end = self._start + self.load.period
            sim.set_dt(None)
            self._fit_dt()

    def _clock_position(self) -> float | None:
        if self.stage != "cycling":
            return None
        return self._cycle + (self._sim.time - self._start) / self.load.period

    def _log_changes(self, before: LabSettings) -> None:
        count = len(self.changes)
        super()._log_changes(before)
        if len(self.changes) > count and self.stage == "cycling":
            change = self.changes[-1]
            self.fit_from = math.ceil(change["cycle"] - 1e-9) + self.reference_cycle
            self.fit_after = "after " + "; ".join(c["text"] for c in self.changes[count:][-2:])
            self._fit_verdict()

    def fit_from_now(self) -> str:
        """Fit the strain from the next cycle start on (no settling cycles); says so, for the user."""
        if self.stage != "cycling":
            raise ParameterError("fit from now", self.stage, "a box that is being cycled (it is still compressing)")
        self.fit_from = math.ceil(self._clock_position() - 1e-9)
        self.fit_after = "from a chosen cycle"
        self._fit_verdict()
        return f"the strain is fitted from cycle {self.fit_from} on"

    def _fit_dt(self) -> None:
        """End the current cycle on a step: the rest of it in whole steps no longer than the
        stability allows (the next cycle starts from the automatic step again)."""
        sim = self._sim
        if self.stage != "cycling":
            return
        remaining = self._cycle_end - sim.time
        if remaining > 0.5 * sim.dt:
            sim.set_dt(remaining / math.ceil(remaining / sim.dt - 1e-9))

    def _lengths(self):
        lengths = self._sim.box_lengths()
        return float(lengths[0]), float(lengths[1])

    def _advance(self, steps: int) -> int:
        sim = self._sim
        if self.stage == "compressing":
            sim.run(steps)
            if self._ramping and sim.time >= COMPRESSION_RAMP:
                self._ramping = False
                hold_load(sim, self.settings.pressure)
            if not self._ramping and sim.time >= self._next_check:
                self._next_check = sim.time + 1.0
                if equilibrium(sim, self.settings.pressure).equilibrated or sim.time > self.compression_limit:
                    self._start_cycling()
            return steps
        steps = min(steps, max(1, round((self._cycle_end - sim.time) / sim.dt)))
        sim.run(steps)
        if self._cycle == 0 and self.auto_watch:
            self.mobilised.add(*mobilisation(sim))
        if sim.time >= self._cycle_end - 0.5 * sim.dt:
            self._cycle_done()
        return steps

    def _start_cycling(self) -> None:
        sim = self._sim
        sim.set_law(friction=self.settings.friction, rolling_friction=self.settings.rolling_friction,
                    rolling_stiffness=self.settings.rolling_stiffness)
        self._lx0, self._ly0 = self._lengths()
        self.stage = "cycling"
        self._apply_load(self._load())
        self._emit_cycle()
        self.mobilised = PairMaximum()

    def _apply_load(self, load: CyclicLoad) -> None:
        """Start a cycle of ``load`` now (q = 0), with the largest stable step that divides its
        period (the automatic one if the law changed since)."""
        sim = self._sim
        self.load = load
        self._start = apply_load(sim, load)
        sim.set_dt(None)
        sim.set_dt(load.period / math.ceil(load.period / sim.dt - 1e-9))
        self._cycle_end = sim.time + load.period
        self._restart_clock()

    def _cycle_done(self) -> None:
        self._cycle += 1
        if self._cycle == 1 and self.auto_watch:
            self.watch = self.mobilised.largest(self.watch_count)
        self._emit_cycle()
        self._start = self._sim.time  # the next cycle starts now, with the changes that waited for it
        self._apply_pending()
        self._apply_load(self._load())

    def _emit_cycle(self) -> None:
        sim = self._sim
        lx, ly = self._lengths()
        gamma = self._gamma()
        self._emit("cycles", (self._cycle, gamma, sim.time, sim.step, lx, ly))
        self._cycle_gamma.append((self._cycle, gamma))
        self._fit_verdict()

    def _fit_verdict(self) -> None:
        """The ratchet verdict of the cycles from ``fit_from`` on (None before three)."""
        used = [(c, g) for c, g in self._cycle_gamma if c >= self.fit_from]
        self.verdict = None
        if len(used) >= 3:
            cycles, gammas = np.array(used, dtype=float).T
            self.verdict = ratchet_verdict(cycles, gammas)

    def _gamma(self) -> float:
        if self.stage != "cycling":
            return 0.0
        lx, ly = self._lengths()
        return ly / self._ly0 - lx / self._lx0

    def sample(self) -> None:
        sim = self._sim
        energy = sim.energy()
        cycling = self.stage == "cycling"
        q = self.load.q(sim.time - self._start) if cycling else 0.0
        self._emit("time", (sim.time, self._cycle if cycling else -1, q, self._gamma(), energy.kinetic,
                            energy.stored, energy.dissipated, energy.balance, coordination(*columns(sim))))

    def sample_paths(self) -> None:
        time = self._sim.time
        for i, j, normal, tangential, status in contact_rows(self._sim, self.watch):
            self._emit("contacts", (i, j, time, normal, tangential, status))

    def status(self) -> dict:
        out = super().status()
        out["cycle"] = self._cycle
        out["strain"] = self._strain_fit()
        out["fit_from"] = {"cycle": self.fit_from, "after": self.fit_after}
        if self.pending:
            out["pending_at"] = self._cycle_end
            out["pending_from"] = "the next cycle"
        return out

    def _strain_fit(self) -> dict | None:
        return strain_fit(self._cycle_gamma, self.fit_from, self.verdict)

    def phase(self) -> str:
        """``compressing to P0 = 1``, then ``cycle 12 · q = 0.312, rising`` (q rises over the first
        half of each cycle and falls back over the second)."""
        if self.stage != "cycling":
            return f"{self.stage} to P0 = {self.settings.pressure:g}"
        elapsed = self._sim.time - self._start
        rising = elapsed % self.load.period < 0.5 * self.load.period
        return f"cycle {self._cycle} · q = {self.load.q(elapsed):.3f}, {'rising' if rising else 'falling'}"


def strain_fit(cycle_gamma, reference_cycle: int, verdict=None) -> dict | None:
    """The strain per cycle fitted from ``reference_cycle`` on, given (cycle, γ) pairs (None
    before three cycles); the line passes through the mean of the fitted points. ``verdict``:
    the :func:`ratchet_verdict` of those cycles if already known (a preset keeps it)."""
    used = [(c, g) for c, g in cycle_gamma if c >= reference_cycle]
    if len(used) < 3:
        return None
    cycles, gammas = np.array(used, dtype=float).T
    v = verdict or ratchet_verdict(cycles, gammas)
    gamma_ref = dict(cycle_gamma)[reference_cycle]
    return {"reference_cycle": reference_cycle, "gamma_ref": gamma_ref, "dgamma": v.dgamma,
            "rms": v.rms_deviation, "ratcheting": v.ratcheting, "cycles_used": v.cycles_used,
            "mean_cycle": float(np.mean(cycles)), "mean_gamma": float(np.mean(v.gamma))}


class Ratchet16Preset(RatchetPreset):
    name = "ratchet16"
    title = "Ratcheting with 16 disks (ratcheting Figs. 1-4)"
    menu_name = "Ratcheting, 16 disks (Figs. 1–4)"
    defaults = {"particles": 16, "speed": 0.5}
    key_plots = ("strain-per-cycle", "coulomb-cone")
    watch_count = 6


class EllipticPreset(RatchetPreset):
    name = "elliptic"
    title = "Elliptic loading without sliding (ratcheting Figs. 5-6)"
    menu_name = "Elliptic loading (Figs. 5–6)"
    defaults = {"particles": 16, "friction": math.inf, "phase": 90.0, "speed": 0.5}
    key_plots = ("strain-per-cycle", "coulomb-cone")
    elliptic = True
    watch_count = 6


# ---------------------------------------------------------------------------------------------- closed path
class ClosedPathPreset(Preset):
    """Ratcheting Fig. 8 side by side for every registered tangential model, one pair each.

    The upper disk of each pair is carried A -> B -> C -> D -> A over and over, without rotating
    or sliding (mu = inf). Series ``springs``: (t, D_t and D_n of each model), sampled along the
    loop (its clock unit).
    """

    name = "closed-path"
    title = "A closed path, every tangential spring (ratcheting Figs. 8-9)"
    menu_name = "Closed path, every spring (Figs. 8–9)"
    controls = ()
    defaults = {"particles": 2, "friction": math.inf, "damping_ratio": 0.0, "speed": 0.5}
    series = {"springs": ("t",) + tuple(f"dt_{model.key}" for model in TANGENTIAL.values())
              + tuple(f"dn_{model.key}" for model in TANGENTIAL.values())}
    path_series = ("springs",)
    plots = key_plots = ("spring-path", "springs")
    clock_unit = "loops"
    time_label = "t (one loop lasts 0.4)"
    path_samples_per_cycle = 200
    window_cycles = 15
    radius = 0.5
    overlap = 0.01
    depth = 0.02
    turn = 0.2
    steps_per_side = 100
    dt = 1e-3

    def _build(self) -> None:
        d_a = 2 * self.radius - self.overlap
        d_b = d_a - self.depth
        phi0 = 0.5 * math.pi
        self._corners = [(d_a, phi0), (d_b, phi0), (d_b, phi0 + self.turn), (d_a, phi0 + self.turn)]
        self._sims = []
        for model in TANGENTIAL_MODELS:
            law = ContactLaw(normal_stiffness=1e4, tangential_stiffness=1e4, friction=math.inf, tangential_model=model)
            particles = ParticleState([[0.0, d_a], [0.0, 0.0]], [self.radius, self.radius], kind=["kinematic", "fixed"])
            self._sims.append(Simulation(particles, law, Integration(dt=self.dt, initial_overlap=0.05)))
        self._k = 0
        self.stage = "looping"

    def cycle_time(self) -> float:
        return 4 * self.steps_per_side * self.dt

    def views(self) -> list[View]:
        return [View(sim, (3.0 * index, 0.0), TANGENTIAL[sim.law.tangential_model].label)
                for index, sim in enumerate(self._sims)]

    def _target(self, k: int) -> np.ndarray:
        side, step = divmod(k, self.steps_per_side)
        (r0, a0), (r1, a1) = self._corners[side % 4], self._corners[(side + 1) % 4]
        s = (step + 1) / self.steps_per_side
        r, a = r0 + (r1 - r0) * s, a0 + (a1 - a0) * s
        return np.array([r * math.cos(a), r * math.sin(a)])

    def _advance(self, steps: int) -> int:
        for _ in range(steps):
            target = self._target(self._k)
            for sim in self._sims:
                sim.set_motion(0, (target - sim.particles.position[0]) / sim.dt, 0.0)
                sim.run(1)
            self._k += 1
        return steps

    def sample(self) -> None:
        """The springs are the only series, sampled along the loop (:meth:`sample_paths`)."""

    def sample_paths(self) -> None:
        row = [self._sims[0].time]
        row += [float(sim.contacts.tangential_spring[0]) for sim in self._sims]
        row += [float(sim.contacts.surface_gap[0]) for sim in self._sims]
        self._emit("springs", tuple(row))

    def status(self) -> dict:
        out = super().status()
        out["loops"] = self._k // (4 * self.steps_per_side)
        return out

    def readout(self) -> dict:
        return {"loops": self._k // (4 * self.steps_per_side)}

    def phase(self) -> str:
        """``loop 3 · B → C``: the loop and the side of the path A → B → C → D → A being drawn."""
        side = (self._k // self.steps_per_side) % 4
        return f"loop {self._k // (4 * self.steps_per_side)} · {'ABCD'[side]} → {'ABCD'[(side + 1) % 4]}"


# ---------------------------------------------------------------------------------------------- block
class BlockPreset(Preset):
    """Quasi-rigidity Figs. 2-3: a disk that cannot turn, pressed on a wall, pushed sideways by a
    load that rises to 1.5 mu F_n and falls back, over and over (period ``period``).

    Series ``block`` (t, load / (mu F_n), N^e, F_t, status, velocity), sampled as a path.
    """

    name = "block"
    title = "A block on a plane: the principle of minimum sliding (quasi-rigidity Figs. 2-3)"
    menu_name = "Block on a plane: minimum sliding"
    controls = ("friction", "period", "damping_ratio")
    defaults = {"particles": 1, "friction": 0.5, "period": 20.0, "damping_ratio": 0.7, "speed": 0.5}
    series = {"block": ("t", "load_ratio", "normal", "tangential", "status", "velocity")}
    path_series = ("block",)
    plots = key_plots = ("block-cone", "block-load")
    time_label = "t (units of m = 1, F_n = 1, K = 1000)"
    load_every = 10

    def _build(self) -> None:
        s = self.settings
        stiffness, load = 1e3, 1.0
        damping = 2.0 * s.damping_ratio * math.sqrt(stiffness)
        law = ContactLaw(normal_stiffness=stiffness, tangential_stiffness=stiffness, friction=s.friction,
                         damping_ratio=s.damping_ratio, tangential_damping=damping)
        particles = ParticleState([[0.0, 0.5 - load / stiffness]], [0.5], mass=[1.0], inertia=[math.inf])
        particles.external_force[0] = (0.0, -load)
        self._sim = Simulation(particles, law, Integration(dt_safety=0.3), walls=(Wall((0.0, 1.0), 0.0, name="floor"),))
        self._normal_load = load
        self.watch = [(0, 1)]
        self.stage = "loading"

    def _rules(self, values: dict) -> dict[str, tuple[bool, str]]:
        return {**super()._rules(values), "period": self._period_rule(values)}

    def _advance(self, steps: int) -> int:
        """The sideways load is set every ``load_every`` steps (a ramp in small stairs)."""
        sim = self._sim
        done = 0
        while done < steps:
            block = min(self.load_every, steps - done)
            sim.particles.external_force[0, 0] = self._load_ratio() * sim.law.friction * self._normal_load
            sim.run(block)
            done += block
        return done

    def readout(self) -> dict:
        return {"sliding": int(sliding(self._sim.contact_status()).sum()), "load": self._load_ratio()}

    def _load_ratio(self) -> float:
        phase = (self._sim.time % self.settings.period) / self.settings.period
        return 1.5 * (2.0 * phase if phase < 0.5 else 2.0 - 2.0 * phase)

    def phase(self) -> str:
        """``load 0.75 μF_n, rising``: the sideways load rises over the first half of the period."""
        rising = self._sim.time % self.settings.period < 0.5 * self.settings.period
        return f"load {self._load_ratio():.2f} μF_n, {'rising' if rising else 'falling'}"

    def sample(self) -> None:
        """The block's series is a path, sampled at the path cadence (:meth:`sample_paths`)."""

    def sample_paths(self) -> None:
        sim = self._sim
        contact = sim.contact_snapshot()
        touching = contact.count > 0
        self._emit("block", (sim.time, self._load_ratio(), float(contact.elastic_normal_force[0]) if touching else 0.0,
                             float(contact.tangential_force[0]) if touching else 0.0,
                             int(contact.status[0]) if touching else 0, float(sim.particles.velocity[0, 0])))


# ---------------------------------------------------------------------------------------------- Gilabert
class GilabertPreset(Preset):
    """The presets of Gilabert's preparations: time in T_0 = sqrt(m a / F_1) (1 here: a disk of
    diameter a = 1 has mass 1, F_1 = 1); the rolling dashpot's damping ratio is the normal one,
    ``damping_ratio``, also when that control changes."""

    clock_unit = "T₀"
    time_label = "t (T₀ = √(m a/F₁))"
    window_cycles = 0
    samples_per_cycle = 2
    path_samples_per_cycle = 2
    particle_range = (10, 20000)

    def cycle_time(self) -> float:
        return 1.0

    def _changed(self, changes: dict) -> None:
        if "damping_ratio" in changes:
            self._sim.set_law(rolling_damping_ratio=self.settings.damping_ratio)


class AggregationPreset(GilabertPreset):
    """Gilabert method 2 live: a cohesive gas aggregates at fixed cell size, then the cell is put
    under stress control, relaxed at P* = 0 and compressed to P* = 0.01 (strain-rate cap).
    Each stage ends at Gilabert's criteria or at its time limit (``stage_limits``).

    Soft grains (kappa = 10^3) so that it runs at a teaching pace. Series ``time`` (t, z, phi,
    clusters, kinetic).
    """

    name = "aggregation"
    title = "Cohesive powder: aggregation (Gilabert method 2, Figs. 4 and 11)"
    menu_name = "Cohesive aggregation (Gilabert 2)"
    controls = ("friction", "rolling_friction", "rolling_stiffness", "particles", "seed", "damping_ratio")
    defaults = {"particles": 300, "friction": 0.15, "cohesion_force": 1.0, "cohesion_range": 1e-3,
                "damping_ratio": 0.8, "speed": math.inf, "frames_per_cycle": 0.2}
    series = {"time": ("t", "z", "phi", "clusters", "kinetic")}
    plots = ("clusters", "coordination-gilabert", "solid-fraction", "kinetic")
    key_plots = ("clusters", "coordination-gilabert")
    kappa = 1e3
    pressure = 0.01
    #: longest time of each stage: a stage that has not met its criterion by then ends anyway
    #: (tangential springs are undamped: floppy arms can swing for a long time)
    stage_limits = {"aggregating": 1000.0, "relaxing": 500.0, "compressing": 1500.0}

    def _build(self) -> None:
        s = self.settings
        law = gilabert_law(friction=s.friction, kappa=self.kappa, cohesion=True, rolling=s.rolling_friction > 0,
                           damping_ratio=s.damping_ratio, rolling_damping_ratio=s.damping_ratio)
        if s.rolling_friction > 0:
            law = law.replace(rolling_friction=s.rolling_friction,
                              rolling_stiffness=s.rolling_stiffness or law.rolling_stiffness)
        r, positions, length = gilabert_gas(s.particles, 0.36, s.seed)
        rng = np.random.default_rng(s.seed + 7)
        speed = math.sqrt(law.cohesion_force * law.cohesion_range)
        velocity = rng.normal(0.0, speed / math.sqrt(2.0), size=(s.particles, 2))
        velocity -= (r[:, None] ** 2 * velocity).sum(axis=0) / (r ** 2).sum()
        self._sim = Simulation(ParticleState(positions, r, velocity=velocity, density=4.0 / math.pi), law,
                               Integration(dt_safety=0.3), cell=PeriodicCell((length, length)))
        self.stage = "aggregating"
        self.late: list[str] = []
        self._stage_start = 0.0
        self._next_check = 0.0

    def _advance(self, steps: int) -> int:
        sim = self._sim
        sim.run(steps)
        if sim.time < self._next_check:
            return steps
        self._next_check = sim.time + 5.0
        late = sim.time - self._stage_start > self.stage_limits.get(self.stage, math.inf)
        if self.stage == "aggregating":
            report = equilibrium(sim, measured_pressure(sim))
            if (clusters(*columns(sim)) == 1 and report.force < 1.0 and report.moment < 1.0) or late:
                self._next_stage("relaxing", late, 0.0)
        elif self.stage == "relaxing":
            report = equilibrium(sim, 0.0)
            if (report.force < 1.0 and report.moment < 1.0 and report.pressure < 1.0) or late:
                self._next_stage("compressing", late, self.pressure)
        elif self.stage == "compressing":
            if equilibrium(sim, self.pressure).equilibrated:
                self._next_stage("equilibrated", False)
            elif late:
                self._next_stage("compressed", True)
        return steps

    def _next_stage(self, stage: str, late: bool, pressure: float | None = None) -> None:
        """Go on to ``stage`` (``late``: the time limit of the last one ran out before its
        criterion was met; the stage's name says so)."""
        if pressure is not None:
            self._sim.set_cell_stress(pressure, 1e-3)
        self.late = self.late + [self.stage] if late else self.late
        self.stage = stage
        self._stage_start = self._sim.time

    def status(self) -> dict:
        out = super().status()
        if self.late:
            out["stage"] = f"{self.stage} (time limit reached while {', '.join(self.late)})"
        return out

    def sample(self) -> None:
        sim = self._sim
        table = columns(sim)
        self._emit("time", (sim.time, coordination(*table), solid_fraction(sim.particles.radius, sim.box_lengths()),
                            clusters(*table), sim.energy().kinetic))


class CompressionPreset(GilabertPreset):
    """Gilabert method 1 live: a gas at rest at solid fraction 0.36 compressed isotropically to
    P by stress control of the cell. Cohesive if F0 > 0 (P* = 0.01), else P = 1 and
    kappa = K_N / P = 10^3. Series ``time`` (t, z, phi, pressure, kinetic)."""

    name = "compression"
    title = "Compression of a granular gas (Gilabert method 1)"
    menu_name = "Compression of a gas (Gilabert 1)"
    controls = ("friction", "rolling_friction", "rolling_stiffness", "cohesion_force", "particles", "seed",
                "damping_ratio")
    defaults = {"particles": 300, "friction": 0.15, "damping_ratio": 0.8, "speed": math.inf, "frames_per_cycle": 0.2}
    series = {"time": ("t", "z", "phi", "pressure", "kinetic")}
    plots = ("solid-fraction", "coordination-gilabert", "pressure", "kinetic")
    key_plots = ("solid-fraction", "coordination-gilabert")

    def _build(self) -> None:
        s = self.settings
        cohesive = s.cohesion_force > 0
        self.pressure = 0.01 if cohesive else 1.0
        law = gilabert_law(friction=s.friction, kappa=1e3, cohesion=cohesive, rolling=s.rolling_friction > 0,
                           pressure=self.pressure, damping_ratio=s.damping_ratio, rolling_damping_ratio=s.damping_ratio)
        r, positions, length = gilabert_gas(s.particles, 0.36, s.seed)
        cell = PeriodicCell((length, length), control=("stress", "stress"), stress=(self.pressure, self.pressure))
        self._sim = Simulation(ParticleState(positions, r, density=4.0 / math.pi), law, Integration(dt_safety=0.3),
                               cell=cell)
        self.stage = "compressing"
        self._next_check = 0.0

    def _advance(self, steps: int) -> int:
        sim = self._sim
        sim.run(steps)
        if sim.time >= self._next_check:
            self._next_check = sim.time + 2.0
            if self.stage == "compressing" and equilibrium(sim, self.pressure).equilibrated:
                self.stage = "equilibrated"
        return steps

    def sample(self) -> None:
        sim = self._sim
        self._emit("time", (sim.time, coordination(*columns(sim)),
                            solid_fraction(sim.particles.radius, sim.box_lengths()), measured_pressure(sim),
                            sim.energy().kinetic))


PRESETS = {cls.name: cls for cls in (RatchetPreset, Ratchet16Preset, EllipticPreset, ClosedPathPreset, BlockPreset,
                                     AggregationPreset, CompressionPreset)}


def preset_settings(name: str, **changes) -> LabSettings:
    """The settings preset ``name`` starts from, with ``changes`` (validated)."""
    if name not in PRESETS:
        raise ParameterError("preset", name, "one of " + ", ".join(PRESETS))
    return LabSettings().replace(**{**PRESETS[name].defaults, **changes})


def make_preset(name: str, settings: LabSettings | None = None) -> Preset:
    if name not in PRESETS:
        raise ParameterError("preset", name, "one of " + ", ".join(PRESETS))
    return PRESETS[name](settings)
