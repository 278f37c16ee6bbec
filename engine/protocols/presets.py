"""The lab's presets: each sets up a figure of the papers and advances it step by step.

A preset owns its simulation(s) and the protocol around them (compression then cyclic
loading, a closed path carried over and over, a load ramp, aggregation then compression).
The lab's engine thread calls :meth:`Preset.advance`, and a few times a second
:meth:`Preset.sample` (which records the time series), then reads :meth:`Preset.rows`,
:meth:`Preset.views` and :meth:`Preset.watched`; controls reach it through :meth:`Preset.apply`.
Nothing here imports a UI library: presets run headless in tests.
"""

from __future__ import annotations

import dataclasses
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError
from ..params import (TANGENTIAL_MODELS, ContactLaw, Integration, Load, PeriodicCell, Wall, finite, nonnegative,
                      positive)
from ..simulation import Simulation
from ..state import STATUS_SLIDE_NEG, STATUS_SLIDE_POS, STATUS_STICK, ParticleState
from .cyclic import CyclicLoad, apply_load, steps_per_cycle
from .equilibrium import equilibrium, measured_pressure
from .prepare import _gas, biaxial_box, clusters, gilabert_law


@dataclass(frozen=True)
class LabSettings:
    """Every control of the lab, validated. Angles in degrees; ``friction`` may be inf.

    ``particles`` and ``seed`` take effect on reset; the others live.
    """

    particles: int = 256
    seed: int = 0
    pressure: float = 1.0
    amplitude: float = 0.2
    period: float = 10.0
    phase: float = 0.0
    friction: float = 0.2
    rolling_friction: float = 0.0
    rolling_stiffness: float = 0.0
    cohesion_force: float = 0.0
    cohesion_range: float = 0.0
    tangential_model: str = "cundall-strack"
    damping_ratio: float = 0.3
    steps_per_frame: int = 50

    def __post_init__(self):
        for name in ("particles", "steps_per_frame"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 1 <= value <= 20000:
                raise ParameterError(name, value, "a whole number from 1 to 20000")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise ParameterError("seed", self.seed, "a whole number >= 0")
        positive("pressure", self.pressure)
        nonnegative("amplitude", self.amplitude)
        positive("period", self.period)
        finite("phase", self.phase)
        ContactLaw(friction=self.friction, rolling_friction=self.rolling_friction,
                   rolling_stiffness=self.rolling_stiffness, cohesion_force=self.cohesion_force,
                   cohesion_range=self.cohesion_range, tangential_model=self.tangential_model,
                   damping_ratio=self.damping_ratio)

    def replace(self, **changes) -> "LabSettings":
        names = {f.name for f in dataclasses.fields(self)}
        for key, value in changes.items():
            if key not in names:
                raise ParameterError(key, value, "one of " + ", ".join(sorted(names)))
        return dataclasses.replace(self, **changes)


LAW_CONTROLS = ("friction", "rolling_friction", "rolling_stiffness", "cohesion_force", "cohesion_range",
                "tangential_model", "damping_ratio")
RESET_CONTROLS = ("particles", "seed")


@dataclass(frozen=True)
class View:
    """A simulation to draw, shifted by ``offset`` (several side by side in one scene)."""

    sim: Simulation
    offset: tuple[float, float] = (0.0, 0.0)


class Preset(ABC):
    """Base of the presets. Subclasses set ``name``, ``title``, ``controls``, ``defaults`` and
    ``series`` and implement ``_build`` and ``_advance``."""

    name = ""
    title = ""
    #: controls that act on this preset (the dashboard greys out the others)
    controls: tuple[str, ...] = ()
    #: settings this preset starts from, over LabSettings' defaults
    defaults: dict = {}
    #: observable series it publishes: name -> column names
    series: dict[str, tuple[str, ...]] = {}

    def __init__(self, settings: LabSettings | None = None):
        self.settings = settings if settings is not None else LabSettings().replace(**self.defaults)
        self.stage = ""
        self._rows = {name: [] for name in self.series}
        self.watch: list[tuple[int, int]] = []
        #: the preset chooses the watched contacts until the user does
        self.auto_watch = True
        self._build()

    @abstractmethod
    def _build(self) -> None:
        """Create the simulation(s) from ``self.settings``."""

    @abstractmethod
    def _advance(self, steps: int) -> None:
        """Run about ``steps`` steps of the protocol (emitting the rows of events, e.g. cycles)."""

    @abstractmethod
    def sample(self) -> None:
        """Emit the rows of the time series for the current state."""

    # -- the engine thread's interface
    @property
    def sim(self) -> Simulation:
        return self.views()[0].sim

    def views(self) -> list[View]:
        return [View(self._sim)]

    def advance(self, steps: int) -> None:
        """Run about ``steps`` steps of the protocol (it may stop early at a stage's boundary)."""
        if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 1:
            raise ParameterError("steps", steps, "a whole number >= 1")
        self._advance(int(steps))

    def apply(self, **changes) -> LabSettings:
        """Change controls (validated first: on error nothing changes). Law controls act at once."""
        settings = self.settings.replace(**changes)
        law_changes = {key: getattr(settings, key) for key in self._live_law_controls() if key in changes}
        if law_changes:
            for view in self.views():
                view.sim.set_law(**law_changes)
        self.settings = settings
        self._changed(changes)
        return settings

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

    def toggle_watch(self, pair: tuple[int, int]) -> None:
        """Watch (or stop watching) the contact ``pair`` = (i, j), j >= N for a wall."""
        pair = (int(pair[0]), int(pair[1]))
        self.auto_watch = False
        if pair in self.watch:
            self.watch.remove(pair)
        else:
            self.watch.append(pair)

    def watch_disk(self, index: int) -> None:
        """Watch every contact of disk ``index`` of the first view (or stop, if one is watched)."""
        snap = self.views()[0].sim.contact_snapshot()
        pairs = [(int(i), int(j)) for i, j in zip(snap.i, snap.j) if index in (i, j)]
        self.auto_watch = False
        if any(pair in self.watch for pair in pairs):
            self.watch = [pair for pair in self.watch if pair not in pairs]
        else:
            self.watch.extend(pairs)

    def status(self) -> dict:
        return {"preset": self.name, "title": self.title, "stage": self.stage,
                "settings": dataclasses.asdict(self.settings)}


def _contact_rows(sim: Simulation, pairs: list[tuple[int, int]]):
    """(pair index, F_n, F_t, status) of the watched pairs present in ``sim``'s table, with
    ``F_n = N^e + N^a`` the normal force without its viscous part: ``N^e - F0`` in contact
    (Gilabert Eq. 4), the attraction alone at a distance. The Coulomb condition
    ``|F_t| <= mu N^e`` (Gilabert Eq. 8) is then the cone ``|F_t| <= mu (F_n + F0)``."""
    if not pairs:
        return []
    snap = sim.contact_snapshot()
    n = sim.particles.count
    cohesion = sim.law.cohesion_force
    ordered = [(min(i, j), max(i, j)) if j < n else (i, j) for i, j in pairs]
    index = {pair: k for k, pair in enumerate(ordered)}
    keys = np.array(ordered, dtype=np.int64)
    out = []
    for k in np.flatnonzero(np.isin(pair_codes(snap.i, snap.j), pair_codes(keys[:, 0], keys[:, 1]))):
        touching = snap.status[k] in (STATUS_STICK, STATUS_SLIDE_POS, STATUS_SLIDE_NEG)
        normal = snap.elastic_normal_force[k] - cohesion if touching else snap.normal_force[k]
        out.append((index[(int(snap.i[k]), int(snap.j[k]))], float(normal), float(snap.tangential_force[k]),
                    int(snap.status[k])))
    return sorted(out)


def pair_codes(i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """One int64 per pair (i, j) of the contact table (indices below 2^31)."""
    return (np.asarray(i, dtype=np.int64) << 32) | np.asarray(j, dtype=np.int64)


def mobilisation(sim: Simulation) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (K, 2) and |F_t| / N^e (K,) of the touching contacts with N^e > 0 (the ratio
    reaches mu on the Coulomb cone)."""
    snap = sim.contact_snapshot()
    touching = np.isin(snap.status, (STATUS_STICK, STATUS_SLIDE_POS, STATUS_SLIDE_NEG))
    keep = np.flatnonzero(touching & (snap.elastic_normal_force > 0))
    ratio = np.abs(snap.tangential_force[keep]) / snap.elastic_normal_force[keep]
    return np.column_stack([snap.i[keep], snap.j[keep]]), ratio


class PairMaximum:
    """The largest value seen for each pair (i, j), merged in bulk (one sort per merge)."""

    def __init__(self):
        self.codes = np.zeros(0, dtype=np.int64)
        self.values = np.zeros(0)

    def add(self, pairs: np.ndarray, values: np.ndarray) -> None:
        codes = np.concatenate([self.codes, pair_codes(pairs[:, 0], pairs[:, 1])])
        values = np.concatenate([self.values, values])
        order = np.lexsort((-values, codes))
        codes, values = codes[order], values[order]
        first = np.ones(len(codes), dtype=bool)
        first[1:] = codes[1:] != codes[:-1]
        self.codes, self.values = codes[first], values[first]

    def as_dict(self) -> dict[tuple[int, int], float]:
        return {(int(c >> 32), int(c & 0xFFFFFFFF)): float(v) for c, v in zip(self.codes, self.values)}

    def largest(self, count: int) -> list[tuple[int, int]]:
        """The ``count`` pairs of largest value, largest first."""
        top = np.argsort(-self.values, kind="stable")[:count]
        return [(int(c >> 32), int(c & 0xFFFFFFFF)) for c in self.codes[top]]


# ---------------------------------------------------------------------------------------------- ratchet
class RatchetPreset(Preset):
    """A biaxial box compressed frictionless to P0, then cyclically loaded (ratcheting Eq. 1).

    Stages: ``compressing`` (until Gilabert's equilibrium or 200 tau), then ``cycling``. Loading
    controls (P0, amplitude, period, phase) take effect at the next cycle start, where q = 0.
    Series: ``time`` (t, q, gamma, kinetic, stored, dissipated, balance, z), ``cycles`` (cycle,
    gamma at the start of the cycle), ``contacts`` (watched index, t, N^e, F_t, status).
    The watched contacts are the ``watch_count`` that came closest to the Coulomb cone during
    the first cycle (the ones that slid, if any), until the user picks others.
    """

    name = "ratchet"
    title = "Biaxial box under cyclic loading"
    controls = ("pressure", "amplitude", "period", "phase", "particles", "seed") + LAW_CONTROLS
    defaults = {"particles": 256}
    series = {"time": ("t", "q", "gamma", "kinetic", "stored", "dissipated", "balance", "z"),
              "cycles": ("cycle", "gamma"),
              "contacts": ("watch", "t", "normal", "tangential", "status")}
    elliptic = False
    compression_limit = 200.0
    compression_ramp = 10.0
    watch_count = 4

    def _build(self) -> None:
        s = self.settings
        # walls as heavy as one row of disks: walls as heavy as the whole packing (the study's)
        # hit a large loose lattice hard enough to overlap disks by a radius (5600 disks: t = 1.9)
        self._sim = biaxial_box(s.particles, seed=s.seed, pressure=s.pressure, damping_ratio=s.damping_ratio,
                                tangential_model=s.tangential_model,
                                wall_mass_fraction=1.0 / math.ceil(math.sqrt(s.particles)))
        # the pressure rises smoothly from 0 to P0 over the ramp, so that the loose lattice
        # collapses slowly: at the full pressure at once, large samples meet at speeds that
        # overlap disks by half a radius
        ramp = Load(amplitude=s.pressure / 2.0, period=2.0 * self.compression_ramp)
        for wall in ("right", "top"):
            self._sim.set_wall_load(wall, ramp)
        self.stage = "compressing"
        self._ramping = True
        self._cycle = 0
        self._next_check = 1.0
        self._pending_load = None
        self._start = None

    def _load(self) -> CyclicLoad:
        s = self.settings
        phase = math.radians(s.phase) if (self.elliptic or s.phase != 0.0) else None
        return CyclicLoad(pressure=s.pressure, amplitude=s.amplitude, period=s.period, phase=phase)

    def _live_law_controls(self) -> tuple[str, ...]:
        # the compression is frictionless: friction and rolling resistance wait for the cycling
        waiting = ("friction", "rolling_friction", "rolling_stiffness") if self.stage == "compressing" else ()
        return tuple(key for key in super()._live_law_controls() if key not in waiting)

    def _changed(self, changes: dict) -> None:
        if any(key in changes for key in ("pressure", "amplitude", "period", "phase")) and self.stage == "cycling":
            self._pending_load = self._load()

    def _lengths(self):
        lengths = self._sim.box_lengths()
        return float(lengths[0]), float(lengths[1])

    def _advance(self, steps: int) -> None:
        sim = self._sim
        if self.stage == "compressing":
            sim.run(steps)
            if self._ramping and sim.time >= self.compression_ramp:
                self._ramping = False
                for wall in ("right", "top"):
                    sim.set_wall_load(wall, Load(base=self.settings.pressure))
            if not self._ramping and sim.time >= self._next_check:
                self._next_check = sim.time + 1.0
                if equilibrium(sim, self.settings.pressure).equilibrated or sim.time > self.compression_limit:
                    self._start_cycling()
        else:
            to_boundary = self._per_cycle - (sim.step - self._cycle_step) % self._per_cycle
            sim.run(min(steps, to_boundary))
            if self._cycle == 0 and self.auto_watch:
                self.mobilised.add(*mobilisation(sim))
            if (sim.step - self._cycle_step) % self._per_cycle == 0:
                self._cycle_done()

    def _start_cycling(self) -> None:
        sim = self._sim
        sim.set_law(friction=self.settings.friction, rolling_friction=self.settings.rolling_friction,
                    rolling_stiffness=self.settings.rolling_stiffness)
        self._apply_load(self._load())
        self._lx0, self._ly0 = self._lengths()
        self.stage = "cycling"
        self._emit("cycles", (0, 0.0))
        self.mobilised = PairMaximum()

    def _apply_load(self, load: CyclicLoad) -> None:
        self.load = load
        self._start = apply_load(self._sim, load)
        self._per_cycle = steps_per_cycle(self._sim, load)
        self._cycle_step = self._sim.step

    def _cycle_done(self) -> None:
        self._cycle += 1
        if self._cycle == 1 and self.auto_watch:
            self.watch = self.mobilised.largest(self.watch_count)
        self._emit("cycles", (self._cycle, self._gamma()))
        if self._pending_load is not None:
            self._apply_load(self._pending_load)
            self._pending_load = None

    def _gamma(self) -> float:
        if self.stage != "cycling":
            return 0.0
        lx, ly = self._lengths()
        return ly / self._ly0 - lx / self._lx0

    def sample(self) -> None:
        sim = self._sim
        energy = sim.energy()
        q = self.load.q(sim.time - self._start) if self.stage == "cycling" else 0.0
        self._emit("time", (sim.time, q, self._gamma(), energy.kinetic, energy.stored, energy.dissipated,
                            energy.balance, coordination(sim)))
        for row in _contact_rows(sim, self.watch):
            self._emit("contacts", (row[0], sim.time) + row[1:])

    def status(self) -> dict:
        out = super().status()
        out["cycle"] = self._cycle
        return out


class Ratchet16Preset(RatchetPreset):
    name = "ratchet16"
    title = "Ratcheting with 16 disks (ratcheting Figs. 1-4)"
    defaults = {"particles": 16, "steps_per_frame": 20}
    watch_count = 6


class EllipticPreset(RatchetPreset):
    name = "elliptic"
    title = "Elliptic loading without sliding (ratcheting Figs. 5-6)"
    defaults = {"particles": 16, "friction": math.inf, "phase": 90.0, "steps_per_frame": 20}
    elliptic = True
    watch_count = 6


def coordination(sim: Simulation) -> float:
    """Mean number of touching disk-disk contacts per disk, 2 M / N."""
    table = sim.contacts
    rows = table.count
    n = sim.particles.count
    touching = np.isin(table.status[:rows], (STATUS_STICK, STATUS_SLIDE_POS, STATUS_SLIDE_NEG))
    return 2.0 * int(np.count_nonzero(touching & (table.particle_j[:rows] < n))) / n


# ---------------------------------------------------------------------------------------------- closed path
class ClosedPathPreset(Preset):
    """Ratcheting Fig. 8 three times side by side: one pair per tangential model.

    The upper disk of each pair is carried A -> B -> C -> D -> A over and over, without rotating
    or sliding (mu = inf). Series ``springs``: (t, D_t and D_n of each model).
    """

    name = "closed-path"
    title = "A closed path, three tangential springs (ratcheting Figs. 8-9)"
    controls = ()
    defaults = {"particles": 2, "friction": math.inf, "damping_ratio": 0.0, "steps_per_frame": 10}
    series = {"springs": ("t", "dt_cundall_strack", "dt_alpha", "dt_angle", "dn_cundall_strack", "dn_alpha",
                          "dn_angle")}
    radius = 0.5
    overlap = 0.01
    depth = 0.02
    turn = 0.2
    steps_per_side = 100

    def _build(self) -> None:
        d_a = 2 * self.radius - self.overlap
        d_b = d_a - self.depth
        phi0 = 0.5 * math.pi
        self._corners = [(d_a, phi0), (d_b, phi0), (d_b, phi0 + self.turn), (d_a, phi0 + self.turn)]
        self._sims = []
        for model in TANGENTIAL_MODELS:
            law = ContactLaw(normal_stiffness=1e4, tangential_stiffness=1e4, friction=math.inf, tangential_model=model)
            particles = ParticleState([[0.0, d_a], [0.0, 0.0]], [self.radius, self.radius], kind=["kinematic", "fixed"])
            self._sims.append(Simulation(particles, law, Integration(dt=1e-3, initial_overlap=0.05)))
        self._k = 0
        self.stage = "looping"

    def views(self) -> list[View]:
        return [View(sim, (3.0 * index, 0.0)) for index, sim in enumerate(self._sims)]

    def _target(self, k: int) -> np.ndarray:
        side, step = divmod(k, self.steps_per_side)
        (r0, a0), (r1, a1) = self._corners[side % 4], self._corners[(side + 1) % 4]
        s = (step + 1) / self.steps_per_side
        r, a = r0 + (r1 - r0) * s, a0 + (a1 - a0) * s
        return np.array([r * math.cos(a), r * math.sin(a)])

    def _advance(self, steps: int) -> None:
        for _ in range(steps):
            target = self._target(self._k)
            for sim in self._sims:
                sim.set_motion(0, (target - sim.particles.position[0]) / sim.dt, 0.0)
                sim.run(1)
            self._k += 1

    def sample(self) -> None:
        row = [self._sims[0].time]
        row += [float(sim.contacts.tangential_spring[0]) for sim in self._sims]
        row += [float(sim.contacts.surface_gap[0]) for sim in self._sims]
        self._emit("springs", tuple(row))

    def status(self) -> dict:
        out = super().status()
        out["loops"] = self._k // (4 * self.steps_per_side)
        return out


# ---------------------------------------------------------------------------------------------- block
class BlockPreset(Preset):
    """Quasi-rigidity Figs. 2-3: a disk that cannot turn, pressed on a wall, pushed sideways by a
    load that rises to 1.5 mu F_n and falls back, over and over (period ``period``).

    Series ``block`` (t, load / (mu F_n), N^e, F_t, status, velocity).
    """

    name = "block"
    title = "A block on a plane: the principle of minimum sliding (quasi-rigidity Figs. 2-3)"
    controls = ("friction", "period", "damping_ratio")
    defaults = {"particles": 1, "friction": 0.5, "period": 20.0, "damping_ratio": 0.7, "steps_per_frame": 20}
    series = {"block": ("t", "load_ratio", "normal", "tangential", "status", "velocity")}

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

    def _advance(self, steps: int) -> None:
        sim = self._sim
        for _ in range(max(1, steps // 10)):
            sim.particles.external_force[0, 0] = self._load_ratio() * sim.law.friction * self._normal_load
            sim.run(10)

    def _load_ratio(self) -> float:
        phase = (self._sim.time % self.settings.period) / self.settings.period
        return 1.5 * (2.0 * phase if phase < 0.5 else 2.0 - 2.0 * phase)

    def sample(self) -> None:
        sim = self._sim
        contact = sim.contact_snapshot()
        touching = contact.count > 0
        self._emit("block", (sim.time, self._load_ratio(), float(contact.elastic_normal_force[0]) if touching else 0.0,
                             float(contact.tangential_force[0]) if touching else 0.0,
                             int(contact.status[0]) if touching else 0, float(sim.particles.velocity[0, 0])))


# ---------------------------------------------------------------------------------------------- Gilabert
class GilabertPreset(Preset):
    """The presets of Gilabert's preparations: the rolling dashpot's damping ratio is the normal
    one, ``damping_ratio``, also when that control changes."""

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
    controls = ("friction", "rolling_friction", "rolling_stiffness", "particles", "seed", "damping_ratio")
    defaults = {"particles": 300, "friction": 0.15, "cohesion_force": 1.0, "cohesion_range": 1e-3,
                "damping_ratio": 0.8, "steps_per_frame": 100}
    series = {"time": ("t", "z", "phi", "clusters", "kinetic")}
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
        r, positions, length = _gas(s.particles, 0.36, s.seed, 1.0)
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

    def _advance(self, steps: int) -> None:
        sim = self._sim
        sim.run(steps)
        if sim.time < self._next_check:
            return
        self._next_check = sim.time + 5.0
        late = sim.time - self._stage_start > self.stage_limits.get(self.stage, math.inf)
        if self.stage == "aggregating":
            report = equilibrium(sim, measured_pressure(sim))
            if (clusters(sim) == 1 and report.force < 1.0 and report.moment < 1.0) or late:
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
        phi = math.pi * float(np.sum(sim.particles.radius ** 2)) / float(np.prod(sim.cell.length))
        self._emit("time", (sim.time, coordination(sim), phi, clusters(sim), sim.energy().kinetic))


class CompressionPreset(GilabertPreset):
    """Gilabert method 1 live: a gas at rest at solid fraction 0.36 compressed isotropically to
    P by stress control of the cell. Cohesive if F0 > 0 (P* = 0.01), else P = 1 and
    kappa = K_N / P = 10^3. Series ``time`` (t, z, phi, pressure, kinetic)."""

    name = "compression"
    title = "Compression of a granular gas (Gilabert method 1)"
    controls = ("friction", "rolling_friction", "rolling_stiffness", "cohesion_force", "particles", "seed",
                "damping_ratio")
    defaults = {"particles": 300, "friction": 0.15, "damping_ratio": 0.8, "steps_per_frame": 100}
    series = {"time": ("t", "z", "phi", "pressure", "kinetic")}

    def _build(self) -> None:
        s = self.settings
        cohesive = s.cohesion_force > 0
        self.pressure = 0.01 if cohesive else 1.0
        law = gilabert_law(friction=s.friction, kappa=1e3, cohesion=cohesive, rolling=s.rolling_friction > 0,
                           pressure=self.pressure, damping_ratio=s.damping_ratio, rolling_damping_ratio=s.damping_ratio)
        r, positions, length = _gas(s.particles, 0.36, s.seed, 1.0)
        cell = PeriodicCell((length, length), control=("stress", "stress"), stress=(self.pressure, self.pressure))
        self._sim = Simulation(ParticleState(positions, r, density=4.0 / math.pi), law, Integration(dt_safety=0.3),
                               cell=cell)
        self.stage = "compressing"
        self._next_check = 0.0

    def _advance(self, steps: int) -> None:
        sim = self._sim
        sim.run(steps)
        if sim.time >= self._next_check:
            self._next_check = sim.time + 2.0
            if self.stage == "compressing" and equilibrium(sim, self.pressure).equilibrated:
                self.stage = "equilibrated"

    def sample(self) -> None:
        sim = self._sim
        phi = math.pi * float(np.sum(sim.particles.radius ** 2)) / float(np.prod(sim.cell.length))
        self._emit("time", (sim.time, coordination(sim), phi, measured_pressure(sim), sim.energy().kinetic))


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
