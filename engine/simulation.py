"""The Simulation facade: state, parameters, and the order of one step.

Typical use::

    sim = Simulation(ParticleState(positions, radii), ContactLaw(...), walls=box_walls(...))
    sim.run(10_000)
    snap = sim.snapshot()

See :meth:`Simulation.run` for the order of operations in a step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np

from . import stopping
from .checkpoint import CheckpointError, check_state
from .cuda import check_backend
from .cuda.stepper import DeviceRun, DeviceState
from .errors import DivergenceError, ParameterError
from .kernels import gathered as k_gathered, integrate as k_integrate
from .kernels.energy import (COHESION, ENERGY_SIZE, GRAVITY, KINETIC_ROTATION, KINETIC_TRANSLATION, NORMAL_ELASTIC,
                             ROLLING_ELASTIC, TANGENTIAL_ELASTIC, WALL_KINETIC, elastic_normal_forces, energy_terms,
                             rolling_distance)
from .kernels.contacts import TALLY_SIZE
from .kernels.laws import D0, F0, GAMMA_T, KN, KR, KT, LAW_SIZE, MU, MU_R, ZETA, ZETA_R
from .kernels.normal import largest_stiffness
from .params import (CELL_CONTROLS, NORMAL, TANGENTIAL, WALL_MODES, ContactLaw, Integration, Load, PeriodicCell, Wall,
                     check_wall_load, finite, positive, whole)
from .state import (CELL_NONE, CELL_STRESS, KIND_KINEMATIC, KIND_NAMES, STATUS_NAMES, STATUS_NONE, STATUS_SLIDE_NEG,
                    STATUS_SLIDE_POS, STATUS_STICK, WALL_VELOCITY, CellState, ContactTable, ParticleState, RunOptions,
                    WallState, Workspace)


#: largest number of contacts per disk assumed by the time-step bound (2D, equal disks)
Z_MAX = 6
#: steps run between two checkpoints of the last good state
CHECKPOINT_STEPS = 2000
#: fewer disks than this run on one thread (a parallel launch costs more than it saves)
PARALLEL_MIN_DISKS = 1000
#: a walled or periodic system whose disks, walls or cell reach this many times its size at the start
#: from where they began is diverging (a wall or cell running away): the run stops
RUNAWAY = 1000.0
#: a load's period must hold at least this many time steps (fewer sample it at an alias of itself)
MIN_LOAD_PERIOD_STEPS = 20
#: a run whose energy balance drifts by more than this share of the energy it turned over is told so
#: (``granlab run``: on standard error and in the run file's notes); the engine's own error at its default
#: step is a few 10⁻⁴ (docs/engine.md, "Energy")
UNBOOKED_SHARE = 0.01


def law_vector(law: ContactLaw) -> np.ndarray:
    """The float64 vector the kernels read (indices KN, KT, ... of :mod:`granlab.engine.kernels.laws`)."""
    vector = np.zeros(LAW_SIZE)
    vector[KN] = law.normal_stiffness
    vector[KT] = law.tangential_stiffness
    vector[MU] = law.friction
    vector[ZETA] = law.damping_ratio
    vector[GAMMA_T] = law.tangential_damping
    vector[F0] = law.cohesion_force
    vector[D0] = law.cohesion_range
    vector[KR] = law.rolling_stiffness
    vector[MU_R] = law.rolling_friction
    vector[ZETA_R] = law.rolling_damping_ratio
    return vector


def stability_bound(law: ContactLaw, mass: np.ndarray, radius: np.ndarray, inertia: np.ndarray,
                    max_overlap: float = 0.5) -> float:
    """Largest stable time step of velocity Verlet for this law and these (dynamic) disks.

    A Gershgorin estimate of the highest contact frequency with at most ``Z_MAX = 6``
    contacts per disk: ``omega_max² = 2 Z_MAX max(k_n / m, K_t (1/m + r²/I), K_r / I, F0 / (D0 m))``
    (a tangential spring moves and turns a disk: ``1/m + r²/I = 3/m`` for a disc), where ``k_n`` is
    ``K_n`` or the normal law's tangent stiffness where it is larger at overlaps up to ``max_overlap``
    of a radius (:func:`largest_stiffness`).
    With damping ratio ``zeta`` (normal, or tangential ``Gamma_t / (2 sqrt(K_t m_t))`` with
    ``m_t = 1 / (2 max(1/m + r²/I))``) the bound of an explicit damped oscillator is
    ``2 (sqrt(1 + zeta²) - zeta) / omega_max``. A viscous rolling moment adds the same bound
    for the rolling springs alone, with ``omega_r² = 2 Z_MAX K_r / I`` and its damping ratio.
    """
    inv_m = float(np.max(1.0 / mass))
    inv_i = float(np.max(1.0 / inertia))
    inv_t = float(np.max(1.0 / mass + radius ** 2 / inertia))
    normal = largest_stiffness(law.normal_model, law.normal_stiffness, radius, max_overlap)
    rates = [normal * inv_m, law.tangential_stiffness * inv_t, law.rolling_stiffness * inv_i]
    if law.cohesion_range > 0:
        rates.append(law.cohesion_force / law.cohesion_range * inv_m)
    omega_max = math.sqrt(2.0 * Z_MAX * max(rates))
    zeta_t = law.tangential_damping / (2.0 * math.sqrt(law.tangential_stiffness / (2.0 * inv_t)))
    zeta = max(law.damping_ratio, zeta_t)
    bound = _damped_bound(zeta, omega_max)
    if law.rolling_damping_ratio > 0 and law.rolling_stiffness > 0:  # no rolling spring: no rolling moment
        omega_r = math.sqrt(2.0 * Z_MAX * law.rolling_stiffness * inv_i)
        bound = min(bound, _damped_bound(law.rolling_damping_ratio, omega_r))
    return bound


def _damped_bound(zeta: float, omega: float) -> float:
    return 2.0 * (math.sqrt(1.0 + zeta * zeta) - zeta) / omega


@dataclass(frozen=True)
class EnergyBudget:
    """Energies (stored, kinetic) and cumulative work and dissipation since the start.

    Dissipation: viscous damping, sliding (``mu N^e |slip|``), rolling (``mu_r N^e |slip|``)
    and ``opening``: the energy left in the tangential and rolling springs of contacts that
    open, which the model forgets (ratcheting Sec. III A).

    ``balance`` = kinetic + stored + gravity + dissipated - work_in is conserved by the
    exact dynamics; its drift measures the integration error.
    """

    kinetic_translation: float
    kinetic_rotation: float
    normal_elastic: float
    cohesion: float
    tangential_elastic: float
    rolling_elastic: float
    gravity: float
    wall_kinetic: float
    dissipated_damping: float
    dissipated_sliding: float
    dissipated_rolling: float
    dissipated_opening: float
    work_walls: float
    work_cell: float
    work_prescribed: float
    work_external: float

    @property
    def kinetic(self) -> float:
        return self.kinetic_translation + self.kinetic_rotation

    @property
    def stored(self) -> float:
        return self.normal_elastic + self.cohesion + self.tangential_elastic + self.rolling_elastic

    @property
    def dissipated(self) -> float:
        return self.dissipated_damping + self.dissipated_sliding + self.dissipated_rolling + self.dissipated_opening

    @property
    def work_in(self) -> float:
        return self.work_walls + self.work_cell + self.work_prescribed + self.work_external

    @property
    def balance(self) -> float:
        return self.kinetic + self.stored + self.gravity + self.dissipated - self.work_in

    def unbooked_share(self, start: EnergyBudget) -> float:
        """The drift of :attr:`balance` since ``start``, as a share of the energy turned over: the kinetic
        and stored energy at ``start``, and what has been dissipated, done as work and gained or lost
        to gravity since (0 where that is 0)."""
        scale = (abs(start.kinetic) + abs(start.stored) + abs(self.dissipated - start.dissipated)
                 + abs(self.work_in - start.work_in) + abs(self.gravity - start.gravity))
        return (self.balance - start.balance) / scale if scale > 0.0 else 0.0

    def as_dict(self) -> dict:
        values = {name: getattr(self, name) for name in self.__dataclass_fields__}
        for name in ("kinetic", "stored", "dissipated", "work_in", "balance"):
            values[name] = getattr(self, name)
        return values


@dataclass(frozen=True)
class ContactSnapshot:
    """Interacting contacts (status != none): arrays of length M.

    ``j >= N`` denotes wall ``j - N``. ``status`` codes are named in ``STATUS_NAMES``.
    ``normal_force`` is the total F_n (elastic, viscous and cohesive parts);
    ``elastic_normal_force`` its elastic repulsive part N^e, which bounds the tangential force
    (``|F_t| <= mu N^e``) and the rolling moment.
    """

    i: np.ndarray
    j: np.ndarray
    image: np.ndarray
    status: np.ndarray
    normal_force: np.ndarray
    elastic_normal_force: np.ndarray
    tangential_force: np.ndarray
    surface_gap: np.ndarray
    tangential_spring: np.ndarray
    rolling_spring: np.ndarray
    rolling_distance: np.ndarray

    @property
    def count(self) -> int:
        return int(self.i.shape[0])

    @property
    def nbytes(self) -> int:
        """Bytes of its arrays."""
        return sum(getattr(self, name).nbytes for name in self.__dataclass_fields__)


def cell_control_names(codes) -> tuple[str, str]:
    """The control of each axis of a cell's ``control`` codes: ``"none"`` where not periodic."""
    return tuple("none" if code == CELL_NONE else CELL_CONTROLS[code] for code in codes)


def fixed_cell_control(periodic) -> tuple[str, ...]:
    """The control of each axis of a cell of fixed size: what states that name none have."""
    return tuple("fixed" if p else "none" for p in periodic)


@dataclass(frozen=True)
class Snapshot:
    """A copy of the state at one instant (safe to hand to another thread)."""

    time: float
    step: int
    positions: np.ndarray
    velocities: np.ndarray
    angles: np.ndarray
    omegas: np.ndarray
    radii: np.ndarray
    masses: np.ndarray
    kinds: np.ndarray
    forces: np.ndarray
    torques: np.ndarray
    contacts: ContactSnapshot
    wall_names: tuple[str, ...]
    wall_normals: np.ndarray
    wall_offsets: np.ndarray
    wall_forces: np.ndarray
    cell_lengths: np.ndarray
    box_lengths: np.ndarray
    periodic: tuple[bool, bool]
    virial: np.ndarray
    stress: np.ndarray
    energy: EnergyBudget
    law: ContactLaw
    dt: float
    extra: dict = field(default_factory=dict)
    wall_modes: tuple[str, ...] = ()
    cell_control: tuple[str, ...] = ()
    """Per axis: ``"none"`` (not periodic) or the cell's control (:data:`granlab.engine.params.CELL_CONTROLS`);
    empty: a fixed cell."""
    cell_target_stress: np.ndarray = field(default_factory=lambda: np.zeros(2))
    """sigma_aa the stress-controlled axes are driven to (compression positive)."""

    @property
    def nbytes(self) -> int:
        """Bytes of its arrays (the contacts' included)."""
        values = (getattr(self, name) for name in self.__dataclass_fields__)
        return self.contacts.nbytes + sum(value.nbytes for value in values if isinstance(value, np.ndarray))


def side_by_side(snapshots: list[Snapshot], offsets) -> Snapshot:
    """One snapshot of several simulations without walls or periodic axes, drawn side by side
    (the lab's closed path, a pair per tangential model): the disks of each shifted by its offset
    and numbered on, its contacts renumbered with them, the energies summed; the time, step, law,
    time step, box and stress are the first's."""
    if any(len(snap.wall_names) or any(snap.periodic) for snap in snapshots):
        raise ParameterError("snapshots", "with walls or a periodic cell", "simulations without walls or periodic axes")
    starts = np.cumsum([0] + [len(snap.radii) for snap in snapshots])

    def joined(name):
        return np.concatenate([getattr(snap, name) for snap in snapshots])

    def joined_contacts(name):
        values = [getattr(snap.contacts, name) + (start if name in ("i", "j") else 0)
                  for snap, start in zip(snapshots, starts)]
        return np.concatenate(values)

    first = snapshots[0]
    contacts = ContactSnapshot(**{name: joined_contacts(name) for name in ContactSnapshot.__dataclass_fields__})
    energy = EnergyBudget(**{name: sum(getattr(snap.energy, name) for snap in snapshots)
                             for name in EnergyBudget.__dataclass_fields__})
    shifted = np.concatenate([snap.positions + np.asarray(offset, dtype=float)
                              for snap, offset in zip(snapshots, offsets)])
    return Snapshot(time=first.time, step=first.step, positions=shifted, velocities=joined("velocities"),
                    angles=joined("angles"), omegas=joined("omegas"), radii=joined("radii"), masses=joined("masses"),
                    kinds=joined("kinds"), forces=joined("forces"), torques=joined("torques"), contacts=contacts,
                    wall_names=(), wall_normals=np.zeros((0, 2)), wall_offsets=np.zeros(0), wall_forces=np.zeros(0),
                    cell_lengths=first.cell_lengths, box_lengths=first.box_lengths, periodic=first.periodic,
                    virial=sum(snap.virial for snap in snapshots), stress=first.stress, energy=energy, law=first.law,
                    dt=first.dt, cell_control=first.cell_control, cell_target_stress=first.cell_target_stress)


def domain_lengths(cell_length, wall_names, wall_offset, position, radius) -> np.ndarray:
    """Lengths of a simulation's domain (:meth:`Simulation.box_lengths`) from its arrays."""
    edges = np.array(cell_length, dtype=float)
    for axis, (low, high) in enumerate((("left", "right"), ("bottom", "top"))):
        if edges[axis] > 0:
            continue
        if low in wall_names and high in wall_names:
            edges[axis] = -(wall_offset[wall_names.index(low)] + wall_offset[wall_names.index(high)])
        else:
            edges[axis] = float(np.ptp(position[:, axis]) + 2.0 * radius.max())
    return edges


class Simulation:
    """A 2D DEM simulation of disks, walls and an optional periodic cell.

    Arguments: ``particles`` (:class:`ParticleState`), ``law`` (:class:`ContactLaw`),
    ``integration`` (:class:`Integration`), ``walls`` (tuple of :class:`Wall`),
    ``cell`` (:class:`PeriodicCell` or ``None`` for open axes), ``gravity`` (gx, gy).
    ``check_initial_overlap=False`` skips the test of the initial overlaps (for a state about to
    be replaced by :meth:`restore_state`).
    """

    gathered = True
    """Whether the contact loop gathers its common rows into contiguous blocks
    (:mod:`granlab.engine.kernels.gathered`): the same results bit for bit, faster; ``False`` runs
    every row directly (the reference the tests and the bench compare with)."""

    backend = "cpu"
    """Where the steps run: ``"cpu"``, the numba kernels on :meth:`threads` threads, or ``"cuda"``, an NVIDIA
    GPU (:mod:`granlab.engine.cuda`, the same laws): :meth:`use_backend`."""

    _device_run: DeviceRun | None = None
    """Within :meth:`run` on the CUDA backend, the driver holding the state on the device between blocks."""

    def __init__(self, particles: ParticleState, law: ContactLaw = ContactLaw(),
                 integration: Integration = Integration(), walls: tuple[Wall, ...] = (),
                 cell: PeriodicCell | None = None, gravity=(0.0, 0.0), check_initial_overlap: bool = True):
        self._arrange(particles, law, integration, walls, cell, gravity, check_initial_overlap)
        self._advance(0.0, 1)
        if check_initial_overlap:
            self._check_initial_overlap()

    @classmethod
    def unstarted(cls, particles: ParticleState, law: ContactLaw = ContactLaw(),
                  integration: Integration = Integration(), walls: tuple[Wall, ...] = (),
                  cell: PeriodicCell | None = None, gravity=(0.0, 0.0)) -> Simulation:
        """The simulation's state and work arrays before its first force evaluation (which compiles
        the time step on a first run): what :mod:`granlab.engine.compilation` compiles the step's
        kernels for, one by one. It may not be run."""
        sim = cls.__new__(cls)
        sim._arrange(particles, law, integration, walls, cell, gravity, True)
        return sim

    def _arrange(self, particles, law, integration, walls, cell, gravity, check_initial_overlap) -> None:
        """Check the arguments of :meth:`__init__` and make the state and work arrays."""
        if not isinstance(particles, ParticleState):
            raise ParameterError("particles", type(particles).__name__, "a ParticleState")
        self.particles = particles
        self.law = law
        self.integration = integration
        self.cell_params = cell
        self.wall_params = tuple(walls)
        self._check_geometry(walls, cell, particles)
        self.walls = WallState(tuple(walls), particles.count)
        if check_initial_overlap:
            self._check_disks_inside_walls()
        self.cell = CellState(cell, float(particles.mass.sum()))
        self.gravity = np.array([finite("gravity[0]", gravity[0]), finite("gravity[1]", gravity[1])])
        self.step = 0
        self._time_origin = 0.0
        self._step_origin = 0
        self._law_vector = law_vector(law)
        self._dt = self._choose_dt(law, integration.dt)
        self._start_extent = self._extent()
        self._start_walls = self.walls.offset.copy()
        self.skin = integration.skin if integration.skin is not None else 0.2 * float(particles.radius.mean())
        n = particles.count
        capacity = 8 * n + 64
        self.contacts = ContactTable(capacity)
        self._spare = ContactTable(capacity)
        threads = numba.config.NUMBA_NUM_THREADS
        nw = self.walls.count
        flags = np.zeros(k_integrate.FLAG_SIZE, dtype=np.int64)
        flags[k_integrate.FLAG_REBUILD] = 1
        self.workspace = Workspace(
            force_buffer=np.zeros((threads, n, 3)), touched=np.zeros((threads, 2), dtype=np.uint64),
            wall_buffer=np.zeros((threads, nw)),
            tally_buffer=np.zeros((threads, TALLY_SIZE)), virial_correction=np.zeros((2, 2)),
            wrapped=np.zeros((n, 2)), wraps=np.zeros((n, 2), dtype=np.int64), reference=np.zeros((n, 2)),
            wall_reference=np.zeros(nw), length_reference=np.zeros(2), scale=np.ones(2),
            lagged_virial=np.zeros((2, 2)), lagged_kinetic=np.zeros(2),
            gather=np.zeros(k_integrate.GATHER_SIZE), partial_gather=np.zeros((threads, k_integrate.GATHER_SIZE)),
            flags=flags,
            energy=np.zeros(k_integrate.ENERGY_TALLY_SIZE), info=np.zeros(k_integrate.INFO_SIZE),
            row_columns=np.zeros((threads, k_gathered.COLUMNS * k_gathered.BLOCK)))

    # ------------------------------------------------------------------ set-up checks
    @staticmethod
    def _check_geometry(walls, cell, particles):
        if cell is not None and particles.count:
            for axis in range(2):
                widest = 2.0 * float(particles.radius.max())
                if cell.periodic[axis] and widest >= cell.lengths[axis]:
                    raise ParameterError(f"cell length along {'xy'[axis]}", cell.lengths[axis],
                                         f"more than the widest disk's diameter {widest:g} (a disk as wide as its "
                                         "periodic cell would overlap its own image)")
        for wall in walls:
            if not isinstance(wall, Wall):
                raise ParameterError("walls", type(wall).__name__, "Wall objects")
            if cell is not None:
                for axis in range(2):
                    if cell.periodic[axis] and abs(wall.normal[axis]) > 1e-12:
                        raise ParameterError(f"wall {wall.name!r} normal", wall.normal,
                                             f"a normal with no component along periodic axis {'xy'[axis]}")
        if cell is not None and "stress" in cell.control and not all(cell.periodic):
            raise ParameterError("cell.control", cell.control, "stress control with both axes periodic")

    def _bound(self, law: ContactLaw) -> float:
        p = self.particles
        dynamic = p.inv_mass > 0
        moving = dynamic if dynamic.any() else np.ones_like(dynamic)
        return stability_bound(law, p.mass[moving], p.radius[moving], p.inertia[moving], self.integration.max_overlap)

    def auto_dt(self, law: ContactLaw | None = None) -> float:
        """The automatic time step for ``law`` (default: the current one): ``dt_safety`` times
        the stability bound of these disks."""
        return self.integration.dt_safety * self._bound(self.law if law is None else law)

    def _choose_dt(self, law: ContactLaw, dt: float | None) -> float:
        bound = self._bound(law)
        if dt is None:
            dt = self.integration.dt_safety * bound
        elif dt > bound and np.any(self.particles.inv_mass > 0):
            raise ParameterError("dt", dt, f"a time step at most the stability bound {bound:.6g} "
                                           "(see engine.simulation.stability_bound)")
        for m in range(self.walls.count):
            if self.walls.load[m, 2] > 0.0:  # a cyclic load (its angular frequency)
                self._check_load_period(self.walls.names[m], float(f"{2.0 * math.pi / self.walls.load[m, 2]:.12g}"), dt)
        return float(dt)

    def _check_load_period(self, name: str, period: float, dt: float) -> None:
        """Refuse a cyclic load on wall ``name`` of fewer than MIN_LOAD_PERIOD_STEPS steps of ``dt``: the steps
        would sample it far apart on its cycle, at an alias of its period."""
        if period < MIN_LOAD_PERIOD_STEPS * dt:
            raise ParameterError(f"wall {name!r} load.period", period,
                                 f"at least {MIN_LOAD_PERIOD_STEPS} time steps of {dt:.4g}, "
                                 f"{MIN_LOAD_PERIOD_STEPS * dt:.4g} (or inf for a constant load)")

    def _extent(self) -> tuple[np.ndarray, float]:
        """Where the system is: the disks' centre, and its size (the domain's longer side, at least a
        diameter)."""
        position = self.particles.position
        centre = position.mean(axis=0) if len(position) else np.zeros(2)
        size = float(np.max(domain_lengths(self.cell.length, self.walls.names, self.walls.offset, position,
                                           self.particles.radius), initial=0.0))
        return centre, max(size, 2.0 * float(self.particles.radius.max(initial=0.0)))

    def _runaway(self) -> str | None:
        """Why the run is diverging though every number is finite, or None: a disk, a wall or a periodic
        length of a walled or periodic system has gone RUNAWAY times the system's starting size from
        where it began (a gas in open space may spread as far as it likes)."""
        if not self.walls.count and self.cell_params is None:
            return None
        (centre, size), limit = self._start_extent, RUNAWAY * self._start_extent[1]
        lengths = self.cell.length[self.cell.length > 0]
        if lengths.size and lengths.max() > limit:
            return (f"the periodic cell's length reached {lengths.max():.3g}, more than {RUNAWAY:g} times the system's "
                    f"size at the start ({size:.3g}): the cell is running away (a stress-controlled cell too light "
                    f"for its stress, or a stress far from the packing's)")
        walls = np.abs(self.walls.offset - self._start_walls) if self.walls.count else np.zeros(1)
        if walls.max() > limit:
            m = int(np.argmax(walls))
            return (f"wall {self.walls.names[m]!r} moved {walls[m]:.3g} from where it began, more than {RUNAWAY:g} "
                    f"times the system's size at the start ({size:.3g}): it is running away (a force-controlled wall "
                    f"too light for its load, or a load far from the packing's)")
        distance = np.abs(self.particles.position - centre).max(axis=1) if self.particles.count else np.zeros(1)
        if distance.max() > limit:
            i = int(np.argmax(distance))
            return (f"disk {i} is {distance[i]:.3g} from the system's centre at the start, more than {RUNAWAY:g} times "
                    f"the system's size there ({size:.3g}): it has run off, through a wall or with a cell running away")
        return None

    def _check_disks_inside_walls(self):
        """The walls' part of :meth:`_check_initial_overlap`, before any table is made: a large
        system placed outside its box is refused in a moment, not after its set-up."""
        for w in range(self.walls.count):
            first, stop = self.walls.reach[w]
            radius = self.particles.radius[first:stop]
            ratio = (self.walls.offset[w] + radius - self.particles.position[first:stop] @ self.walls.normal[w]) / radius
            k = int(np.argmax(ratio))
            if ratio[k] > self.integration.initial_overlap:
                raise self._overlap_error(first + k, f"wall {self.walls.names[w]!r}", ratio[k])

    def _overlap_error(self, i: int, other: str, ratio: float) -> ParameterError:
        return ParameterError(f"initial overlap of disk {i} and {other} / smaller radius", round(float(ratio), 6),
                              f"at most {self.integration.initial_overlap} (Integration.initial_overlap)")

    def _check_initial_overlap(self):
        table = self.contacts
        n = self.particles.count
        rows = np.flatnonzero(table.surface_gap[:table.count] < 0)
        if rows.size == 0:
            return
        i = table.particle_i[rows]
        j = table.particle_j[rows]
        radius = self.particles.radius
        smaller = np.where(j < n, np.minimum(radius[i], radius[np.minimum(j, n - 1)]), radius[i])
        ratio = -table.surface_gap[rows] / smaller
        k = int(np.argmax(ratio))
        if ratio[k] <= self.integration.initial_overlap:
            return
        other = f"disk {j[k]}" if j[k] < n else f"wall {self.walls.names[j[k] - n]!r}"
        raise self._overlap_error(i[k], other, ratio[k])

    # ------------------------------------------------------------------ running
    @property
    def time(self) -> float:
        """Simulated time: ``t0 + (step - step0) dt`` since the last change of ``dt`` (computed the
        same way by the kernels, so a run split into pieces keeps the same times)."""
        return self._time_origin + (self.step - self._step_origin) * self._dt

    @property
    def dt(self) -> float:
        return self._dt

    @dt.setter
    def dt(self, value: float) -> None:
        if float(value) != self._dt:
            self._time_origin = self.time
            self._step_origin = self.step
            self._dt = float(value)

    @property
    def periodic(self) -> tuple[bool, bool]:
        return self.cell.periodic

    @property
    def normal_model_code(self) -> int:
        return NORMAL[self.law.normal_model].code

    @property
    def tangential_model_code(self) -> int:
        return TANGENTIAL[self.law.tangential_model].code

    def threads(self) -> int:
        """Threads a run uses: numba's thread count of the calling thread (``numba.set_num_threads``),
        or 1 below ``PARALLEL_MIN_DISKS`` disks."""
        return numba.get_num_threads() if self.particles.count >= PARALLEL_MIN_DISKS else 1

    def _has_loads(self) -> bool:
        p = self.particles
        return bool(p.external_force.any() or p.external_torque.any())

    def use_backend(self, backend: str) -> None:
        """Run the next steps on ``backend`` (:attr:`backend`); one this machine cannot run is refused, and
        the message says what it can."""
        self.backend = check_backend(backend)

    def run_options(self, dt: float, n_steps: int) -> RunOptions:
        """What the kernels take for ``n_steps`` steps of ``dt`` from the current state."""
        return RunOptions(self.normal_model_code, self.gravity, self._has_loads(), dt,
                          self._time_origin, self.step - self._step_origin, n_steps, self.skin,
                          self.integration.max_overlap, self.threads(), bool(self.gathered))

    def _advance(self, dt: float, n_steps: int) -> tuple[int, int]:
        """One call of the kernel driver, growing the contact table until it fits."""
        while True:
            run = self.run_options(dt, n_steps)
            code = self.tangential_model_code
            advance = k_integrate.ADVANCE[code] if self.backend == "cpu" else self._device_run or DeviceRun(code)
            done, code = advance(self.particles.arrays(), self.walls.arrays(), self.cell.arrays(),
                                 self.contacts.arrays(), self._spare.arrays(), self.workspace, self._law_vector, run,
                                 None if run.n_chunks == 1 else True)
            if dt > 0:
                self.step += done
            if code != k_integrate.CODE_OVERFLOW:
                return done, code
            needed = int(self.workspace.info[k_integrate.INFO_NEEDED])
            capacity = max(needed + needed // 4, 2 * self.contacts.capacity)
            self.contacts.grow(capacity)
            self._spare.grow(capacity)
            n_steps -= done

    def run(self, n_steps: int) -> None:
        """Advance ``n_steps`` steps of ``dt``.

        Order of one step (velocity Verlet; kernels in :mod:`granlab.engine.kernels.integrate`):

        1. if the previous step predicted the skin would be used up, rebuild the contact
           table (cell list, periodic images, walls), carrying the history over;
        2. half kick of disks, force-controlled walls and a stress-controlled cell with the
           forces of the previous step; drift of walls, cell lengths (affine on positions),
           positions and angles by ``dt``;
        3. contact forces at the new positions (tangential springs, Coulomb limit, rolling
           springs, cohesion, damping with half-step velocities);
        4. gravity and applied loads; second half kick; energy tallies; divergence checks
           (NaN, an overlap above ``max_overlap``); prediction for the rebuild test.

        After each block of steps a walled or periodic system that is running away (:meth:`_runaway`)
        is diverging too. A diverging run raises :class:`DivergenceError` and the simulation is restored to
        its state before the block of steps that failed (at most ``CHECKPOINT_STEPS`` earlier).
        """
        remaining = whole("n_steps", n_steps, 0)
        if self.backend == "cuda":  # the state stays on the device from one block to the next
            self._device_run = DeviceRun(self.tangential_model_code, resident=True)
        try:
            while remaining > 0:
                stopping.check()  # between blocks the state is a whole step
                block = min(remaining, CHECKPOINT_STEPS)
                saved = self._checkpoint()
                done, code = self._advance(self.dt, block)
                if code == k_integrate.CODE_TUNNEL and self._fast_disks_fly_free():
                    # the step is whole; its test for a rebuild was skipped by the early return
                    self.workspace.flags[k_integrate.FLAG_REBUILD] = 1
                    remaining -= done
                    continue
                reason = self._failure_reason(code) if code != k_integrate.CODE_OK else self._runaway()
                if reason is not None:
                    failed_step = self.step
                    self._restore(saved)
                    raise DivergenceError(reason, failed_step, self.time)
                remaining -= done
        finally:
            if self._device_run is not None:
                self._device_run.release()
                self._device_run = None

    def run_for(self, duration: float) -> None:
        """Advance by ``duration`` (rounded to a whole number of steps)."""
        duration = finite("duration", duration)
        if duration < 0:
            raise ParameterError("duration", duration, "a duration >= 0")
        self.run(int(round(duration / self.dt)))

    def _fast_disks_fly_free(self) -> bool:
        """Whether every disk moving more than ``max_overlap / 2`` of its radius a step has nothing
        in reach: no disk surface and no wall within twice what it and the fastest disk move in a
        step. Such a disk cannot pass through anything before the next step's check."""
        p = self.particles
        moves = np.hypot(p.velocity[:, 0], p.velocity[:, 1]) * self.dt
        fast = np.flatnonzero(~(moves <= 0.5 * self.integration.max_overlap * p.radius))
        if not np.all(np.isfinite(moves[fast])):
            return False
        lengths = self.cell.length  # 0 along an axis that is not periodic
        for disk in fast:
            reach = 2.0 * (moves[disk] + moves.max())
            offset = p.position - p.position[disk]
            for axis in np.flatnonzero(lengths > 0):
                offset[:, axis] -= lengths[axis] * np.round(offset[:, axis] / lengths[axis])
            gaps = np.hypot(offset[:, 0], offset[:, 1]) - p.radius - p.radius[disk]
            gaps[disk] = np.inf
            met = (self.walls.reach[:, 0] <= disk) & (disk < self.walls.reach[:, 1])
            wall_gaps = self.walls.normal[met] @ p.position[disk] - self.walls.offset[met] - p.radius[disk]
            if min(gaps.min(), wall_gaps.min(initial=np.inf)) <= reach:
                return False
        return True

    def _failure_reason(self, code: int) -> str:
        info = self.workspace.info
        if code == k_integrate.CODE_NAN:
            return "a position or velocity became NaN or infinite"
        if code == k_integrate.CODE_OVERLAP:
            return (f"an overlap reached {info[k_integrate.INFO_MAX_OVERLAP]:.3g} of a radius, above "
                    f"max_overlap = {self.integration.max_overlap} (time step too large or stiffness too low)")
        if code == k_integrate.CODE_TUNNEL:
            disk = int(info[k_integrate.INFO_MOVER])
            speed = float(np.hypot(*self.particles.velocity[disk]))  # the kernel's square may overflow
            return (f"disk {disk} moved {speed * self.dt / self.particles.radius[disk]:.3g} of its radius in one "
                    f"step (speed "
                    f"{speed:.3g}, dt = {self.dt:.3g}), above max_overlap / 2 = {self.integration.max_overlap / 2:.3g}: "
                    f"it could pass through a neighbour (time step too large for this speed)")
        if code == k_integrate.CODE_LOST_CONTACT:
            return (f"{int(info[k_integrate.INFO_LOST])} touching contact(s) left the neighbour list "
                    "at a rebuild (an internal inconsistency: please report it)")
        return f"kernel returned code {code}"

    def _checkpoint(self):
        """The state to go back to if the next block of steps fails: a copy on the host, or on the device while
        the device holds the state (nothing crosses between the two)."""
        clock = (self.step, self._step_origin, self._time_origin, self._dt)
        if self._device_run is not None and self._device_run.state is not None:
            return self._device_run.state.copy(), clock
        ws = self.workspace
        return (self.particles.copy(), self.walls.copy(), self.cell.copy(), self.contacts.copy(),
                {name: getattr(ws, name).copy() for name in self.STATE_ARRAYS["workspace"] + ("gather",)}), clock

    def _restore(self, saved) -> None:
        state, (self.step, self._step_origin, self._time_origin, self._dt) = saved
        if isinstance(state, DeviceState):
            state.download((self.particles.arrays(), self.walls.arrays(), self.cell.arrays(), self.contacts.arrays(),
                            self.workspace))
        else:
            particles, walls, cell, contacts, arrays = state
            self.particles, self.walls, self.cell = particles, walls, cell
            self.contacts = contacts
            self._spare = ContactTable(contacts.capacity)
            for name, value in arrays.items():
                getattr(self.workspace, name)[...] = value
        self.workspace.force_buffer[...] = 0.0

    # ------------------------------------------------------------------ changing parameters
    def set_law(self, **changes) -> ContactLaw:
        """Change contact-law parameters between steps (validated; no recompilation).

        A change that makes a user-chosen ``dt`` unstable is refused and nothing changes;
        with an automatic ``dt`` the step is recomputed.
        """
        law = self.law.replace(**changes)
        dt = self._choose_dt(law, self.integration.dt)
        self.law, self.dt = law, dt
        self._law_vector[:] = law_vector(law)
        if "cohesion_range" in changes:
            self.workspace.flags[k_integrate.FLAG_REBUILD] = 1
        return law

    def set_dt(self, dt: float | None) -> float:
        """Set the time step (``None``: automatic); a step above the stability bound is refused."""
        integration = self.integration.replace(dt=dt)
        self.dt = self._choose_dt(self.law, integration.dt)
        self.integration = integration
        return self.dt

    def fit_dt(self, duration: float) -> int:
        """Shorten the time step, never lengthen it, to divide ``duration`` into whole steps (a load
        cycle, or what is left of one, ends on a step); returns their count."""
        steps = math.ceil(positive("duration", duration) / self.dt - 1e-9)
        self.set_dt(duration / steps)
        return steps

    def set_cell_stress(self, stress: float, max_strain_rate: float | None = None) -> None:
        """Put both axes of a periodic cell under isotropic stress control at ``stress``
        (Gilabert Eq. 3), measuring strains from the current lengths."""
        if not all(self.periodic):
            raise ParameterError("cell", self.periodic, "a cell periodic along both axes for stress control")
        cell = self.cell
        cell.control[:] = CELL_STRESS
        cell.target_stress[:] = finite("stress", stress)
        cell.reference_length[:] = cell.length
        if max_strain_rate is not None:
            cell.max_strain_rate[0] = positive("max_strain_rate", max_strain_rate, allow_inf=True)

    def set_gravity(self, gx: float, gy: float) -> None:
        self.gravity[:] = (finite("gravity[0]", gx), finite("gravity[1]", gy))

    def wall_index(self, name: str) -> int:
        if name not in self.walls.names:
            raise ParameterError("wall", name, "one of " + ", ".join(self.walls.names))
        return self.walls.names.index(name)

    def set_wall_load(self, name: str, load: Load) -> None:
        """Replace the load of a force-controlled wall (time still counts from t = 0)."""
        m = self.wall_index(name)
        if not isinstance(load, Load):
            raise ParameterError(f"wall {name!r} load", load, "a Load")
        check_wall_load(name, load)
        self._check_load_period(name, load.period, self.dt)
        self.walls.load[m] = (load.base, load.amplitude, load.angular_frequency, load.phase)

    def set_wall_velocity(self, name: str, velocity: float, tangential_velocity: float = 0.0) -> None:
        """Prescribe the velocity of a wall in velocity mode (or only the sliding of its surface)."""
        m = self.wall_index(name)
        if self.walls.mode[m] == WALL_VELOCITY:
            self.walls.velocity[m] = finite(f"wall {name!r} velocity", velocity)
        elif velocity != 0.0:
            raise ParameterError(f"wall {name!r} velocity", velocity, "0 unless the wall is in velocity mode")
        self.walls.tangential_velocity[m] = finite(f"wall {name!r} tangential_velocity", tangential_velocity)

    def set_motion(self, index: int, velocity, omega: float = 0.0) -> None:
        """Prescribe the velocity and spin of a kinematic disk."""
        if not 0 <= index < self.particles.count:
            raise ParameterError("particle index", index, f"0 <= index < {self.particles.count}")
        if self.particles.kind[index] != KIND_KINEMATIC:
            raise ParameterError(f"kind of disk {index}", KIND_NAMES[self.particles.kind[index]],
                                 "'kinematic' to prescribe its motion")
        self.particles.velocity[index] = (finite("velocity[0]", velocity[0]), finite("velocity[1]", velocity[1]))
        self.particles.omega[index] = finite("omega", omega)

    # ------------------------------------------------------------------ checkpoints
    STATE_ARRAYS = {
        "particles": ("position", "velocity", "angle", "omega", "radius", "mass", "inertia", "kind", "inv_mass",
                      "inv_inertia", "force", "torque", "external_force", "external_torque"),
        "walls": ("normal", "offset", "velocity", "tangential_velocity", "tangential_position", "mode", "inv_mass",
                  "load", "length_ref", "particle_force"),
        "cell": ("length", "rate", "control", "target_stress", "strain_rate", "reference_length", "mass",
                 "max_strain_rate", "virial", "kinetic"),
        "workspace": ("reference", "wall_reference", "length_reference", "flags", "energy", "info",
                      "virial_correction", "lagged_virial", "lagged_kinetic"),
    }

    def export_state(self) -> dict[str, np.ndarray]:
        """Every array the dynamics depends on, keyed ``"group/name"`` (copies), plus
        ``step``, the time origin, ``dt`` and ``threads``: enough to continue the run bit for bit
        (with the same number of threads) from :meth:`restore_state`."""
        sources = {"particles": self.particles, "walls": self.walls, "cell": self.cell}
        state = {}
        for group, names in self.STATE_ARRAYS.items():
            for name in names:
                source = getattr(self.workspace, name) if group == "workspace" else getattr(sources[group], name)
                state[f"{group}/{name}"] = np.array(source, copy=True)
        rows = self.contacts.count
        for name, _ in ContactTable.FIELDS:
            state[f"contacts/{name}"] = getattr(self.contacts, name)[:rows].copy()
        state["contacts/image"] = self.contacts.image[:rows].copy()
        state["step"] = np.int64(self.step)
        state["time_origin"] = np.float64(self._time_origin)
        state["step_origin"] = np.int64(self._step_origin)
        state["dt"] = np.float64(self._dt)
        state["threads"] = np.int64(self.threads())
        return state

    def restore_state(self, state: dict) -> None:
        """Overwrite this simulation's state with one from :meth:`export_state` (same disks and
        walls), checked first (:func:`granlab.engine.checkpoint.check_state`): a state refused
        leaves this simulation as it was."""
        rows = check_state(state, self.export_state(), self.particles.count, self.walls.count)
        lengths = domain_lengths(state["cell/length"], self.walls.names, state["walls/offset"],
                                 state["particles/position"], state["particles/radius"])
        if not np.all(lengths > 0):
            raise CheckpointError(f"cell/length and walls/offset make a domain of lengths {lengths.tolist()}; "
                                  f"positive lengths are needed")
        sources = {"particles": self.particles, "walls": self.walls, "cell": self.cell}
        for group, names in self.STATE_ARRAYS.items():
            for name in names:
                target = getattr(self.workspace, name) if group == "workspace" else getattr(sources[group], name)
                target[...] = state[f"{group}/{name}"]
        if rows > self.contacts.capacity:
            self.contacts.grow(rows + rows // 4)
            self._spare.grow(rows + rows // 4)
        for name, _ in ContactTable.FIELDS + (("image", None),):
            getattr(self.contacts, name)[:rows] = state[f"contacts/{name}"]
        self.contacts.count_array[0] = rows
        self.workspace.force_buffer[...] = 0.0
        self.step = int(state["step"])
        self._time_origin = float(state["time_origin"])
        self._step_origin = int(state["step_origin"])
        self._dt = float(state["dt"])

    def clone(self, **law_changes) -> "Simulation":
        """An independent simulation in the same state (optionally with other law parameters)."""
        p = self.particles
        clone = Simulation(ParticleState(p.position, p.radius, mass=p.mass, inertia=p.inertia, kind=p.kind),
                           self.law, self.integration.replace(dt=self.dt), self.wall_params, self.cell_params,
                           tuple(self.gravity), check_initial_overlap=False)
        clone.restore_state(self.export_state())
        if law_changes:
            clone.set_law(**law_changes)
        return clone

    # ------------------------------------------------------------------ reading
    def energy(self) -> EnergyBudget:
        terms = np.zeros(ENERGY_SIZE)
        energy_terms(self.particles.arrays(), self.walls.arrays(), self.contacts.arrays(), self._law_vector,
                     self.normal_model_code, self.gravity, terms)
        tally = self.workspace.energy
        return EnergyBudget(
            kinetic_translation=terms[KINETIC_TRANSLATION], kinetic_rotation=terms[KINETIC_ROTATION],
            normal_elastic=terms[NORMAL_ELASTIC], cohesion=terms[COHESION],
            tangential_elastic=terms[TANGENTIAL_ELASTIC], rolling_elastic=terms[ROLLING_ELASTIC],
            gravity=terms[GRAVITY], wall_kinetic=terms[WALL_KINETIC],
            dissipated_damping=tally[k_integrate.E_DAMPING], dissipated_sliding=tally[k_integrate.E_SLIDING],
            dissipated_rolling=tally[k_integrate.E_ROLLING], dissipated_opening=tally[k_integrate.E_OPENING],
            work_walls=tally[k_integrate.E_WALL_WORK],
            work_cell=tally[k_integrate.E_CELL_WORK], work_prescribed=tally[k_integrate.E_PRESCRIBED_WORK],
            work_external=tally[k_integrate.E_EXTERNAL_WORK])

    def contact_snapshot(self) -> ContactSnapshot:
        table = self.contacts
        count = table.count
        roll = np.zeros(count)
        rolling_distance(self.particles.arrays(), self.walls.arrays(), self.cell.arrays(), table.arrays(), roll)
        elastic = np.zeros(count)
        elastic_normal_forces(self.particles.arrays(), table.arrays(), self._law_vector, self.normal_model_code,
                              elastic)
        status = self.contact_status()
        rows = np.flatnonzero(status != STATUS_NONE)
        return ContactSnapshot(
            i=table.particle_i[rows].astype(np.int64), j=table.particle_j[rows].astype(np.int64),
            image=table.image[rows].astype(np.int64), status=status[rows],
            normal_force=table.normal_force[rows].copy(), elastic_normal_force=elastic[rows],
            tangential_force=table.tangential_force[rows].copy(),
            surface_gap=table.surface_gap[rows].copy(), tangential_spring=table.tangential_spring[rows].copy(),
            rolling_spring=table.rolling_spring[rows].copy(), rolling_distance=roll[rows])

    def snapshot(self) -> Snapshot:
        p = self.particles
        return Snapshot(
            time=self.time, step=self.step, positions=p.position.copy(), velocities=p.velocity.copy(),
            angles=p.angle.copy(), omegas=p.omega.copy(), radii=p.radius.copy(), masses=p.mass.copy(),
            kinds=p.kind.copy(), forces=p.force.copy(), torques=p.torque.copy(),
            contacts=self.contact_snapshot(), wall_names=tuple(self.walls.names),
            wall_normals=self.walls.normal.copy(), wall_offsets=self.walls.offset.copy(),
            wall_forces=self.walls.particle_force.copy(), cell_lengths=self.cell.length.copy(),
            box_lengths=self.box_lengths(),
            periodic=self.periodic, virial=self.cell.virial.copy(), stress=self.stress(), energy=self.energy(),
            law=self.law,
            dt=self.dt, wall_modes=tuple(WALL_MODES[m] for m in self.walls.mode),
            cell_control=cell_control_names(self.cell.control), cell_target_stress=self.cell.target_stress.copy())

    def box_lengths(self) -> np.ndarray:
        """Lengths of the domain: periodic lengths, the distance between the walls named
        left/right (bottom/top), or else the extent of the disks along the axis."""
        return domain_lengths(self.cell.length, self.walls.names, self.walls.offset, self.particles.position,
                              self.particles.radius)

    def stress(self) -> np.ndarray:
        """Mean stress ``(sum m v ⊗ v + sum_contacts f ⊗ r) / A`` (2 × 2, compression positive) over
        the domain of :meth:`box_lengths`, from disk-disk contacts (the loads on walls give the
        stress at a walled boundary). The kinetic part counts the diagonal only."""
        lengths = self.box_lengths()
        return (self.cell.virial + np.diag(self.cell.kinetic)) / float(lengths[0] * lengths[1])

    def contact_status(self) -> np.ndarray:
        """The status of each row of the contact table, as it is read (a copy). Without friction
        (mu = 0) no contact slides: its Coulomb limit is 0 and F_t = 0, a frictionless contact, not
        one held at a limit. The kernels mark it sliding, so that its anchors follow the slip
        (Gilabert Eq. 20)."""
        status = self.contacts.status[:self.contacts.count].copy()
        if self.law.friction == 0.0:
            status[(status == STATUS_SLIDE_POS) | (status == STATUS_SLIDE_NEG)] = STATUS_STICK
        return status

    def status_counts(self) -> dict[str, int]:
        """Number of contacts per status name."""
        status = self.contact_status()
        return {name: int(np.count_nonzero(status == code)) for code, name in enumerate(STATUS_NAMES) if code}
