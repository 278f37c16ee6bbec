"""Structure-of-arrays state of a simulation and the codes the kernels share.

The kernels receive the arrays bundled in named tuples (``ParticleArrays``,
``WallArrays``, ``CellArrays``, ``ContactArrays``); a 1-element array stands
for a scalar the kernels update in place.
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

from .errors import ParameterError
from .params import CELL_CONTROLS, WALL_MODES, PeriodicCell, Wall

# particle kinds
KIND_DYNAMIC, KIND_FIXED, KIND_KINEMATIC = 0, 1, 2
KIND_NAMES = ("dynamic", "fixed", "kinematic")

# wall modes and cell controls (index in params.WALL_MODES / params.CELL_CONTROLS;
# CELL_NONE marks a non-periodic axis)
WALL_FIXED, WALL_VELOCITY, WALL_FORCE = range(3)
CELL_NONE = -1
CELL_FIXED, CELL_STRESS, CELL_STRAIN_RATE = range(3)

# contact status (kept in the contact table)
STATUS_NONE = 0  # candidate pair of the neighbour list, no interaction
STATUS_STICK = 1  # contact inside the Coulomb cone (non-sliding)
STATUS_SLIDE_POS = 2  # sliding on the +mu side: F_t = +mu N^e
STATUS_SLIDE_NEG = 3  # sliding on the -mu side: F_t = -mu N^e
STATUS_COHESIVE = 4  # distant cohesive interaction, 0 <= gap <= D0
STATUS_NAMES = ("none", "non-sliding", "sliding+", "sliding-", "cohesive")

ParticleArrays = namedtuple(
    "ParticleArrays",
    "position velocity angle omega radius mass inv_mass inv_inertia force torque external_force external_torque "
    "predicted_motion",
)
WallArrays = namedtuple(
    "WallArrays",
    "normal offset velocity tangential_velocity tangential_position mode inv_mass load length_ref particle_force reach",
)
CellArrays = namedtuple(
    "CellArrays",
    "length rate control target_stress strain_rate reference_length mass max_strain_rate virial kinetic",
)
ContactArrays = namedtuple(
    "ContactArrays",
    "count particle_i particle_j image root_reduced_mass tangential_spring anchor_angle_i anchor_angle_j "
    "rolling_spring status normal_force tangential_force surface_gap",
)

RunOptions = namedtuple(
    "RunOptions",
    "normal_model gravity has_loads dt time_origin step_offset n_steps skin max_overlap n_chunks gathered",
)
"""What one call of the step driver needs besides the state and the tangential model (which it is
compiled for, :data:`granlab.engine.kernels.integrate.ADVANCE`): the normal model's code, gravity (2,),
whether disks carry applied loads, the step, the clock (``time_origin``, ``step_offset``), the
number of steps, the Verlet skin, the overlap that counts as a divergence, the thread chunks and whether the
contact loop gathers its common rows (:mod:`granlab.engine.kernels.gathered`)."""

Workspace = namedtuple(
    "Workspace",
    "force_buffer touched wall_buffer tally_buffer virial_correction lagged_virial lagged_kinetic wrapped wraps "
    "reference wall_reference length_reference scale gather partial_gather flags energy info row_columns",
)


class _Copyable:
    """``copy()`` duplicates every array attribute (other attributes are shared)."""

    def copy(self):
        clone = object.__new__(type(self))
        for key, value in vars(self).items():
            setattr(clone, key, value.copy() if isinstance(value, np.ndarray) else value)
        return clone


CELL_MASS_FRACTION = 0.3
"""Gilabert's generalized mass of the cell is this fraction of the grain mass (Sec. II A)."""


def default_cell_mass(total_mass: float, lengths) -> float:
    """Gilabert's generalized mass of the cell (Eq. 3, Sec. II A): 3/10 of the grain mass over the
    cell size ``sqrt(L_x L_y)``."""
    return CELL_MASS_FRACTION * total_mass / math.sqrt(float(lengths[0]) * float(lengths[1]))


HUGE = 1e150
"""A disk's numbers stay below this in size: beyond, their squares (distances, energies) overflow."""


def _column(name: str, value, n: int, default: float, width: int | None = None) -> np.ndarray:
    shape = (n,) if width is None else (n, width)
    if value is None:
        return np.full(shape, default, dtype=np.float64)
    array = np.array(value, dtype=np.float64)
    if array.ndim == 0 and width is None:
        array = np.full(shape, float(array))
    if array.shape != shape:
        raise ParameterError(name, f"array of shape {array.shape}", f"shape {shape}")
    sound = np.abs(array) < HUGE
    if not np.all(sound):
        bad = int(np.flatnonzero(~sound.reshape(n, -1).all(axis=1))[0])
        raise ParameterError(f"{name}[{bad}]", array[bad].tolist(), "finite numbers below 1e150 in size")
    return array


class ParticleState(_Copyable):
    """N disks: position, velocity, rotation angle, spin, radius, mass, inertia, kind.

    Arrays (float64 unless noted): ``position (N, 2)``, ``velocity (N, 2)``,
    ``angle (N,)`` (theta), ``omega (N,)``, ``radius (N,)``, ``mass (N,)`` (given, or
    ``density × pi r²`` from an areal density, default 1), ``inertia (N,)`` (given, or the
    disc's ``I = m r² / 2``; ``inf`` makes a disk that never turns), ``kind (N,) int8`` (dynamic, fixed,
    kinematic), ``force (N, 2)`` and ``torque (N,)`` of the last step,
    ``external_force (N, 2)`` and ``external_torque (N,)`` applied loads. ``predicted_motion
    (N, 3)``, written by every pass of the step driver, holds the velocity and spin predicted at
    the next whole step, ``v + dt/2 f/m`` and ``w + dt/2 tau/I`` (the dashpots' velocities; one
    row per disk, so the contact loop reads them in one go); they follow from the velocities and
    forces at a whole step, so a checkpoint need not keep them.

    Fixed and kinematic disks keep their prescribed velocity and spin: their
    inverse mass and inertia are zero.
    """

    def __init__(self, position, radius, velocity=None, omega=None, angle=None,
                 mass=None, density=None, inertia=None, kind=None):
        position = np.array(position, dtype=np.float64)
        if position.ndim != 2 or position.shape[1] != 2 or position.shape[0] == 0:
            raise ParameterError("position", f"array of shape {position.shape}", "shape (N, 2) with N >= 1")
        n = position.shape[0]
        self.position = _column("position", position, n, 0.0, 2)
        self.radius = _column("radius", radius, n, 1.0)
        bad = np.flatnonzero(self.radius <= 0)
        if bad.size:
            raise ParameterError(f"radius[{bad[0]}]", float(self.radius[bad[0]]), "a positive radius")
        self.velocity = _column("velocity", velocity, n, 0.0, 2)
        self.omega = _column("omega", omega, n, 0.0)
        self.angle = _column("angle", angle, n, 0.0)
        if mass is not None and density is not None:
            raise ParameterError("density", density, "unset when mass is given (give one of them)")
        if mass is None:
            rho = 1.0 if density is None else density
            rho = _column("density", rho, n, 1.0)
            self.mass = rho * math.pi * self.radius ** 2
        else:
            self.mass = _column("mass", mass, n, 1.0)
        bad = np.flatnonzero(~(self.mass > 0))
        if bad.size:
            raise ParameterError(f"mass[{bad[0]}]", float(self.mass[bad[0]]), "a positive mass (or density)")
        if inertia is None:
            self.inertia = 0.5 * self.mass * self.radius ** 2
        else:
            self.inertia = np.array(np.broadcast_to(np.asarray(inertia, dtype=np.float64), (n,)))
            bad = np.flatnonzero(~(self.inertia > 0))
            if bad.size:
                raise ParameterError(f"inertia[{bad[0]}]", float(self.inertia[bad[0]]),
                                     "a positive moment of inertia (inf: the disk never turns)")
        self.kind = np.zeros(n, dtype=np.int8)
        if kind is not None:
            self.set_kind(kind)
        self.inv_mass = np.empty(n)
        self.inv_inertia = np.empty(n)
        self.refresh_inverse()
        self.force = np.zeros((n, 2))
        self.torque = np.zeros(n)
        self.external_force = np.zeros((n, 2))
        self.external_torque = np.zeros(n)
        self.predicted_motion = np.zeros((n, 3))

    @property
    def count(self) -> int:
        return self.position.shape[0]

    def set_kind(self, kind) -> None:
        """Set kinds from names ("dynamic", "fixed", "kinematic") or codes."""
        values = np.atleast_1d(np.asarray(kind, dtype=object))
        if values.size == 1:
            values = np.repeat(values, self.count)
        if values.size != self.count:
            raise ParameterError("kind", f"{values.size} values", f"{self.count} values (one per particle)")
        codes = np.empty(self.count, dtype=np.int8)
        for index, value in enumerate(values):
            if isinstance(value, str) and value in KIND_NAMES:
                codes[index] = KIND_NAMES.index(value)
            elif isinstance(value, (int, np.integer)) and 0 <= value < len(KIND_NAMES):
                codes[index] = value
            else:
                raise ParameterError(f"kind[{index}]", value, "one of " + ", ".join(KIND_NAMES))
        self.kind[:] = codes
        if hasattr(self, "inv_mass"):
            self.refresh_inverse()

    def refresh_inverse(self) -> None:
        dynamic = self.kind == KIND_DYNAMIC
        self.inv_mass[:] = np.where(dynamic, 1.0 / self.mass, 0.0)
        self.inv_inertia[:] = np.where(dynamic, 1.0 / self.inertia, 0.0)
        self.omega[dynamic & np.isinf(self.inertia)] = 0.0
        fixed = self.kind == KIND_FIXED
        self.velocity[fixed] = 0.0
        self.omega[fixed] = 0.0

    def arrays(self) -> ParticleArrays:
        return ParticleArrays(self.position, self.velocity, self.angle, self.omega, self.radius, self.mass,
                              self.inv_mass, self.inv_inertia, self.force, self.torque,
                              self.external_force, self.external_torque, self.predicted_motion)


class WallState(_Copyable):
    """The rigid walls as arrays (see :class:`granlab.engine.params.Wall`).

    ``offset`` is s in ``n · x = s``; ``velocity`` its rate ds/dt; ``tangential_position``
    the distance the wall surface has slid along ``t = z × n``; ``load (nw, 4)`` holds
    (base, amplitude, angular frequency, phase); ``length_ref (nw, 2)`` the indices of the
    two walls whose distance multiplies the load (-1: none); ``particle_force`` the normal
    force the disks exerted on each wall in the last step (negative when pushed outward);
    ``reach (nw, 2)`` the disks ``first`` to ``stop - 1`` that meet each wall (every disk but in a batch).
    """

    def __init__(self, walls: tuple[Wall, ...], n: int):
        self.names = [w.name or f"wall{k}" for k, w in enumerate(walls)]
        if len(set(self.names)) != len(self.names):
            raise ParameterError("wall names", self.names, "distinct names")
        nw = len(walls)
        self.normal = np.array([w.normal for w in walls], dtype=np.float64).reshape(nw, 2)
        self.offset = np.array([w.position for w in walls], dtype=np.float64)
        self.velocity = np.array([w.velocity if w.mode == "velocity" else 0.0 for w in walls])
        self.tangential_velocity = np.array([w.tangential_velocity for w in walls], dtype=np.float64)
        self.tangential_position = np.zeros(nw)
        self.mode = np.array([WALL_MODES.index(w.mode) for w in walls], dtype=np.int8)
        self.inv_mass = np.array([1.0 / w.mass if w.mode == "force" else 0.0 for w in walls])
        self.load = np.array([[w.load.base, w.load.amplitude, w.load.angular_frequency, w.load.phase]
                              for w in walls], dtype=np.float64).reshape(nw, 4)
        self.length_ref = np.full((nw, 2), -1, dtype=np.int64)
        for k, wall in enumerate(walls):
            if wall.load_per_length_of is not None:
                for side, name in enumerate(wall.load_per_length_of):
                    if name not in self.names:
                        raise ParameterError(f"wall {self.names[k]!r} load_per_length_of", name,
                                             "the name of another wall: " + ", ".join(self.names))
                    self.length_ref[k, side] = self.names.index(name)
                a, b = self.length_ref[k]
                if not np.allclose(self.normal[a], -self.normal[b]):
                    raise ParameterError(f"wall {self.names[k]!r} load_per_length_of", wall.load_per_length_of,
                                         "two walls facing each other (opposite normals)")
        self.particle_force = np.zeros(nw)
        self.reach = np.array([w.disks or (0, n) for w in walls], dtype=np.int64).reshape(nw, 2)
        for k, (first, stop) in enumerate(self.reach):
            if stop > n:
                raise ParameterError(f"wall {self.names[k]!r} disks", (int(first), int(stop)),
                                     f"a range of the {n} disks: stop at most {n}")

    @property
    def count(self) -> int:
        return self.offset.shape[0]

    def arrays(self) -> WallArrays:
        return WallArrays(self.normal, self.offset, self.velocity, self.tangential_velocity,
                          self.tangential_position, self.mode, self.inv_mass, self.load, self.length_ref,
                          self.particle_force, self.reach)


class CellState(_Copyable):
    """The periodic cell as arrays (lengths zero and control CELL_NONE on open axes).

    ``rate`` is dL/dt; ``virial (2, 2)`` is ``sum_contacts f_i ⊗ r_ij`` and ``kinetic (2,)``
    ``sum m v_a²`` of the last step, from which the measured stress
    ``sigma^M = (kinetic + virial) / A`` of Gilabert Eq. 3 follows.
    """

    def __init__(self, cell: PeriodicCell | None, total_mass: float):
        self.length = np.zeros(2)
        self.rate = np.zeros(2)
        self.control = np.full(2, CELL_NONE, dtype=np.int8)
        self.target_stress = np.zeros(2)
        self.strain_rate = np.zeros(2)
        self.reference_length = np.zeros(2)
        self.mass = np.zeros(1)
        self.max_strain_rate = np.full(1, math.inf)
        self.virial = np.zeros((2, 2))
        self.kinetic = np.zeros(2)
        if cell is None:
            return
        for axis in range(2):
            if cell.periodic[axis]:
                self.length[axis] = cell.lengths[axis]
                self.control[axis] = CELL_CONTROLS.index(cell.control[axis])
                self.target_stress[axis] = cell.stress[axis]
                self.strain_rate[axis] = cell.strain_rate[axis]
                self.reference_length[axis] = cell.lengths[axis]
                if cell.control[axis] == "strain-rate":
                    self.rate[axis] = -cell.strain_rate[axis] * cell.lengths[axis]
        self.mass[0] = cell.mass if cell.mass is not None else default_cell_mass(total_mass, cell.lengths)
        self.max_strain_rate[0] = cell.max_strain_rate

    @property
    def periodic(self) -> tuple[bool, bool]:
        return tuple(bool(c != CELL_NONE) for c in self.control)

    def arrays(self) -> CellArrays:
        return CellArrays(self.length, self.rate, self.control, self.target_stress, self.strain_rate,
                          self.reference_length, self.mass, self.max_strain_rate, self.virial, self.kinetic)


class ContactTable(_Copyable):
    """Fixed-capacity contact table (one row per candidate pair of the neighbour list).

    Rows ``[0, count)`` are in use, sorted by ``particle_i``. ``particle_j >= N`` denotes
    wall ``particle_j - N``. ``image (C, 2) int8`` is the periodic image of j
    (``r_ij = x_i - x_j - image · L``); ``root_reduced_mass`` is ``sqrt(m_i m_j / (m_i + m_j))``
    (``sqrt(m_i)`` against a wall, 0 between two non-dynamic bodies). History per row: ``tangential_spring`` (D_t),
    ``anchor_angle_i``/``anchor_angle_j`` (body-frame angles of the material points of
    first contact, ratcheting Eq. 21; for a wall, the anchor's coordinate along the wall),
    ``rolling_spring`` (Gilabert's elastic rolling angle), ``status``. Results of the last
    step: ``normal_force`` (F_n, total), ``tangential_force`` (F_t), ``surface_gap`` (D_n).
    """

    FIELDS = (("particle_i", np.int32), ("particle_j", np.int32), ("root_reduced_mass", np.float64),
              ("tangential_spring", np.float64),
              ("anchor_angle_i", np.float64), ("anchor_angle_j", np.float64), ("rolling_spring", np.float64),
              ("status", np.int8), ("normal_force", np.float64), ("tangential_force", np.float64),
              ("surface_gap", np.float64))

    def __init__(self, capacity: int):
        self.capacity = int(capacity)
        self.count_array = np.zeros(1, dtype=np.int64)
        for name, dtype in self.FIELDS:
            setattr(self, name, np.zeros(self.capacity, dtype=dtype))
        self.image = np.zeros((self.capacity, 2), dtype=np.int8)

    @property
    def count(self) -> int:
        return int(self.count_array[0])

    def copy(self) -> "ContactTable":
        """A table of the same capacity holding a copy of the rows in use (the rest is zero: the
        kernels never read past ``count``), so that a checkpoint costs the contacts, not the
        capacity."""
        clone = ContactTable.__new__(ContactTable)
        clone.capacity = self.capacity
        clone.count_array = self.count_array.copy()
        n = self.count
        for name, _ in self.FIELDS + (("image", None),):
            old = getattr(self, name)
            new = np.zeros(old.shape, dtype=old.dtype)
            new[:n] = old[:n]
            setattr(clone, name, new)
        return clone

    def grow(self, capacity: int) -> None:
        """Enlarge to ``capacity`` rows, keeping the rows in use."""
        n = self.count
        for name, _ in self.FIELDS + (("image", None),):
            old = getattr(self, name)
            new = np.zeros((capacity,) + old.shape[1:], dtype=old.dtype)
            new[:n] = old[:n]
            setattr(self, name, new)
        self.capacity = int(capacity)

    def arrays(self) -> ContactArrays:
        return ContactArrays(self.count_array, self.particle_i, self.particle_j, self.image,
                             self.root_reduced_mass, self.tangential_spring, self.anchor_angle_i, self.anchor_angle_j,
                             self.rolling_spring, self.status, self.normal_force, self.tangential_force,
                             self.surface_gap)

