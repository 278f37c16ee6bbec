"""Frozen, validated parameter dataclasses.

Every constructor checks its values and raises :class:`ParameterError` naming
the parameter, the value and what is allowed. Use :meth:`ContactLaw.replace`
(and the like) to change a value at run time: the result is validated again.

Sign conventions are those of the ratcheting paper: ``n`` points from ``j`` to
``i``, ``t = z × n``, ``F_n > 0`` is repulsion, ``D_n < 0`` is an overlap.
Stresses are counted positive in compression (Gilabert Sec. II A).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass

from .errors import ParameterError

@dataclass(frozen=True)
class TangentialModel:
    """A tangential spring model: its ``name`` (what scenes, the command line and the lab take),
    the ``code`` the kernels switch on, its ``title`` in words and its ``label`` in a legend;
    whether its tangential force and spring rate carry ``alpha = (r_i + r_j) / |x_i - x_j|``
    (ratcheting Eqs. 23-25, 30; the angle spring's force does too); whether a closed path leaves
    it the residue a / (r_i + r_j) of ratcheting Eq. 17 (``path_dependent``); and whether its
    dashpots take the velocities predicted at the whole step, the energy balance's error then
    falling faster than dt (``whole_step_dashpots``), or the half-step ones, as dt (LAMMPS's
    integration); and whether its spring reads the direction of the contact, ``atan2(n_y, n_x)``
    (``reads_direction``: the contact loop computes it for such a model only, outside the loop
    that vectorises)."""

    name: str
    code: int
    title: str
    label: str
    alpha_factor: bool
    path_dependent: bool
    whole_step_dashpots: bool = True
    reads_direction: bool = False

    @property
    def key(self) -> str:
        """The name as an identifier (series columns, the kernels' module)."""
        return self.name.replace("-", "_")


TANGENTIAL = {model.name: model for model in (
    TangentialModel("cundall-strack", 0, "Cundall–Strack (ratcheting Eqs. 7–11)", "Cundall–Strack", False, True),
    TangentialModel("alpha", 1, "α-corrected integration (ratcheting Eqs. 23–25, 30)", "α-corrected", True, False),
    TangentialModel("angle", 2, "angle-based spring (ratcheting Eqs. 18–22)", "angle-based", True, False,
                    reads_direction=True),
    TangentialModel("lammps", 3, "LAMMPS gran/hooke/history (shear vector; Coulomb on the total normal force)",
                    "LAMMPS hooke/history", False, True, whole_step_dashpots=False))}
"""The one registry of tangential models, by name; every other list of them is made from it. The
kernels of a model are the module of :mod:`granlab.engine.kernels.tangential` named after it."""
TANGENTIAL_MODELS = tuple(TANGENTIAL)

BACKENDS = ("cpu", "cuda")
"""Where the steps run (:meth:`granlab.engine.simulation.Simulation.use_backend`): the CPU's threads or an NVIDIA
GPU. Here, not in :mod:`granlab.engine.cuda`, so that the commands' parsers name them without numba."""


@dataclass(frozen=True)
class NormalModel:
    """A normal elastic law: its ``name`` (scenes, the command line, ``ContactLaw.normal_model``),
    the ``code`` the kernels switch on, its ``title`` in words and its ``label`` in a legend."""

    name: str
    code: int
    title: str
    label: str

    @property
    def key(self) -> str:
        """The name as an identifier (the law's module in :mod:`granlab.engine.kernels.normal`)."""
        return self.name.replace("-", "_")


NORMAL = {model.name: model for model in (
    NormalModel("linear", 0, "linear spring N^e = -K_n D_n (ratcheting Eq. 6)", "linear"),
    NormalModel("area", 1, "force proportional to the overlap area, N^e = K_n A / (r_i + r_j) (ratcheting Sec. II B)",
                "overlap area"))}
"""The one registry of normal elastic laws, by name; the kernels' codes and every list come from it. The
kernels of a law (its force, energy and tangent stiffness) are the module of
:mod:`granlab.engine.kernels.normal` named after it."""
NORMAL_MODELS = tuple(NORMAL)
WALL_MODES = ("fixed", "velocity", "force")
CELL_CONTROLS = ("fixed", "stress", "strain-rate")

GILABERT_DT_SAFETY = 0.6
"""The time step of Gilabert's preparations (methods 1 and 2), as a fraction of the engine's
stability bound (:func:`granlab.engine.simulation.stability_bound`). That bound assumes 6 contacts on
every disk; on equilibrated packings of 150 to 5600 disks the highest frequency of the contact
network is 1.78-2.0 times below it, so 0.6 is about a third of the packings' own bound. Against
0.3 (27 Nov 2026): method 1 at 200 disks, 8 cases x 2 seeds, the same Phi and z to 4 digits in 3
of the 8 cohesive pairs and within the seeds' spread in the others; method 2 at 150 disks, 10
seeds, Phi and z within 1.3 standard errors (docs/gilabert.md). A sample takes half the time."""

CELL_MASS_READINGS = ("mass", "per-length")
"""Two readings of Gilabert's generalized mass ``M`` (Eq. 3, Sec. II A): ``mass``, 3/10 of the grain
mass, a mass as Eq. 3 needs in 2D (its stresses are forces per length, its strain has no
dimension); ``per-length``, 3/10 of the grain mass over the cell size ``L`` (the paper's words,
which it calls "dimensionally correct": so they are for stresses per area, in 3D), in units of the
largest diameter. The first reproduces Table III, the second compacts faster and ends looser and
less coordinated (docs/gilabert.md, "The cohesive z gap")."""


def check_cell_mass_reading(reading: str) -> str:
    """``reading`` if it is one of :data:`CELL_MASS_READINGS`; a ParameterError naming them if not."""
    if reading not in CELL_MASS_READINGS:
        raise ParameterError("cell_mass", reading, "one of " + ", ".join(CELL_MASS_READINGS))
    return reading


STUDY_LIMITS = {"particles": 20000, "samples": 10000, "cycles": 100000, "period": (0.1, 1e4), "workers": 256}
"""The largest study run here (the lab's largest box; a count of samples, cycles and workers, a
period in τ whose work a cluster finishes in days, not years), checked before any work starts."""


def _number(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(name, value, "a real number")
    value = float(value)
    if math.isnan(value):
        raise ParameterError(name, value, "a number, not NaN")
    return value


def finite(name: str, value) -> float:
    value = _number(name, value)
    if not math.isfinite(value):
        raise ParameterError(name, value, "a finite number")
    return value


def positive(name: str, value, allow_inf: bool = False) -> float:
    value = _number(name, value)
    if not value > 0 or (math.isinf(value) and not allow_inf):
        allowed = "a positive number" + (" or inf" if allow_inf else " (finite)")
        raise ParameterError(name, value, allowed)
    return value


def nonnegative(name: str, value, allow_inf: bool = False) -> float:
    value = _number(name, value)
    if value < 0 or (math.isinf(value) and not allow_inf):
        allowed = "a number >= 0" + (" or inf" if allow_inf else " (finite)")
        raise ParameterError(name, value, allowed)
    return value


def friction_coefficient(name: str, value, largest: float = math.inf, slides: bool = False, holds: bool = False,
                         why: str = "") -> float:
    """The one rule of a friction coefficient (Coulomb's μ): a number from 0 up, or ``inf`` for
    contacts that never slide. A context may ask more: at most ``largest`` below ``inf`` (the lab's
    packings), contacts that can slide (``slides``: finite), that hold before they slide (``holds``:
    above 0); the error says what is allowed, and ``why`` here."""
    value = _number(name, value)
    lowest = "above 0" if holds else "from 0"
    upper = f"{lowest} to {largest:g}" if largest < math.inf else ("> 0" if holds else ">= 0")
    allowed = f"a friction coefficient {upper}" + ("" if slides else ", or inf (no sliding)") + (
        f" ({why})" if why else "")
    never_slides = value == math.inf and not slides
    if value < 0 or (holds and value == 0) or (slides and math.isinf(value)) or (value > largest and not never_slides):
        raise ParameterError(name, value, allowed)
    return value


def fraction(name: str, value, of: str) -> float:
    """A number in (0, 1]: a fraction ``of`` something (the error names it)."""
    value = positive(name, value)
    if value > 1:
        raise ParameterError(name, value, f"a fraction of {of} in (0, 1]")
    return value


def whole(name: str, value, least: int = 0, most: int | None = None) -> int:
    """``value`` as an int: a whole number (not a bool) from ``least`` to ``most`` (no upper bound
    without ``most``)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < least \
            or (most is not None and value > most):
        raise ParameterError(name, value, f"a whole number from {least} to {most}" if most is not None
                             else f"a whole number >= {least}")
    return int(value)


def choice(name: str, value, choices: tuple[str, ...]) -> str:
    if value not in choices:
        raise ParameterError(name, value, "one of " + ", ".join(repr(c) for c in choices))
    return value


def pair(name: str, value, check) -> tuple:
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise ParameterError(name, value, "a pair of values (x, y)")
    return (check(f"{name}[0]", value[0]), check(f"{name}[1]", value[1]))


class _Replaceable:
    def replace(self, **changes):
        """A validated copy with ``changes`` applied (unknown names are refused)."""
        names = {f.name for f in dataclasses.fields(self)}
        for key in changes:
            if key not in names:
                raise ParameterError(key, changes[key], "one of " + ", ".join(sorted(names)))
        return dataclasses.replace(self, **changes)


@dataclass(frozen=True)
class ContactLaw(_Replaceable):
    """The interaction law between two disks (and between a disk and a wall).

    - normal: ``N^e = -K_n D_n`` (ratcheting Eq. 6, Gilabert ``N^e = -K_N h``) or,
      with ``normal_model="area"``, ``N^e = K_n A / l`` with ``A`` the overlap area and
      ``l = r_i + r_j`` (``2 r_i`` for a wall), so ``K_n`` bounds its tangent stiffness
      (ratcheting Sec. II B); viscous damping ``N^v = -eta V_n`` with
      ``eta = zeta sqrt(4 K_n m_i m_j / (m_i + m_j))`` (Gilabert Eq. 6).
    - cohesion: ``N^a = -F0 (1 - h/D0)`` for a gap ``0 <= h <= D0`` and ``-F0`` in
      contact (Gilabert Eqs. 4-5).
    - tangential: spring ``F_t = -K_t D_t - Gamma_t V_t`` (quasi-rigidity Eq. 7) with
      ``|F_t| <= mu N^e`` (Gilabert Eq. 8); ``D_t`` follows ``tangential_model``:
      ``"cundall-strack"`` (ratcheting Eqs. 7-11), ``"alpha"`` (Eqs. 23-25, 30),
      ``"angle"`` (Eqs. 18-22) or ``"lammps"`` (LAMMPS's ``gran/hooke/history``: a shear vector
      projected on the new tangent each step, ``|F_t| <= mu |F_n|`` with the total ``F_n``).
    - rolling: moment ``-K_r dtheta - Gamma_r (w_i - w_j)`` with ``|moment| <= mu_r N^e``
      (Gilabert Eq. 10) and ``Gamma_r = 2 zeta_r sqrt(K_r I_i I_j / (I_i + I_j))`` (``I_i``
      against a wall). Gilabert has no viscous part (``zeta_r = 0``); with it, a disk held by
      one contact stops rolling on its partner instead of swinging on the rolling spring for ever.

    ``friction`` (mu) and ``rolling_friction`` (mu_r, a length) may be ``inf``.
    """

    normal_stiffness: float = 1000.0
    tangential_stiffness: float = 1000.0
    friction: float = 0.5
    damping_ratio: float = 0.0
    tangential_damping: float = 0.0
    normal_model: str = "linear"
    tangential_model: str = "cundall-strack"
    cohesion_force: float = 0.0
    cohesion_range: float = 0.0
    rolling_stiffness: float = 0.0
    rolling_friction: float = 0.0
    rolling_damping_ratio: float = 0.0

    def __post_init__(self):
        set_ = object.__setattr__
        set_(self, "normal_stiffness", positive("normal_stiffness", self.normal_stiffness))
        set_(self, "tangential_stiffness", positive("tangential_stiffness", self.tangential_stiffness))
        set_(self, "friction", friction_coefficient("friction", self.friction))
        zeta = nonnegative("damping_ratio", self.damping_ratio)
        if zeta >= 1.0:
            raise ParameterError("damping_ratio", zeta, "a fraction of critical damping in [0, 1)")
        set_(self, "damping_ratio", zeta)
        set_(self, "tangential_damping", nonnegative("tangential_damping", self.tangential_damping))
        choice("normal_model", self.normal_model, NORMAL_MODELS)
        choice("tangential_model", self.tangential_model, TANGENTIAL_MODELS)
        set_(self, "cohesion_force", nonnegative("cohesion_force", self.cohesion_force))
        set_(self, "cohesion_range", nonnegative("cohesion_range", self.cohesion_range))
        if self.cohesion_force > 0 and self.cohesion_range == 0:
            # F0 would pull at contact and vanish at once on opening: work done on no path
            raise ParameterError("cohesion_range", 0.0, f"a range > 0 with cohesion_force = {self.cohesion_force:g} "
                                                        "(the attraction falls from F0 to 0 over it; or "
                                                        "cohesion_force = 0)")
        set_(self, "rolling_stiffness", nonnegative("rolling_stiffness", self.rolling_stiffness))
        set_(self, "rolling_friction", nonnegative("rolling_friction", self.rolling_friction, allow_inf=True))
        set_(self, "rolling_damping_ratio", nonnegative("rolling_damping_ratio", self.rolling_damping_ratio))


@dataclass(frozen=True)
class Integration(_Replaceable):
    """Time stepping and neighbour-list settings.

    - ``dt``: the time step; ``None`` means ``dt_safety`` times the stability bound
      (see :func:`granlab.engine.simulation.stability_bound`). A ``dt`` above the bound is refused.
    - ``skin``: Verlet skin added to the interaction range of the neighbour list;
      ``None`` means 0.2 times the mean radius.
    - ``max_overlap``: a run whose largest overlap exceeds this fraction of the smaller
      radius of a contact is declared diverging.
    - ``initial_overlap``: overlaps up to this fraction of the smaller radius are
      accepted in an initial configuration (a prepared packing overlaps a little).
    """

    dt: float | None = None
    dt_safety: float = 0.2
    skin: float | None = None
    max_overlap: float = 0.5
    initial_overlap: float = 0.1

    def __post_init__(self):
        set_ = object.__setattr__
        if self.dt is not None:
            set_(self, "dt", positive("dt", self.dt))
        set_(self, "dt_safety", fraction("dt_safety", self.dt_safety, "the stability bound"))
        if self.skin is not None:
            set_(self, "skin", positive("skin", self.skin))
        overlap = fraction("max_overlap", self.max_overlap, "the radius")
        set_(self, "max_overlap", overlap)
        initial = nonnegative("initial_overlap", self.initial_overlap)
        if initial >= overlap:
            raise ParameterError("initial_overlap", initial, f"a fraction below max_overlap = {overlap}")
        set_(self, "initial_overlap", initial)


@dataclass(frozen=True)
class Load(_Replaceable):
    """A load ``base + amplitude (1 - cos(2 pi t / period + phase))`` (ratcheting Eqs. 1, 5).

    For a wall whose load is per length, ``base`` is the pressure P0 and
    ``amplitude`` is Delta sigma; otherwise both are forces.
    """

    base: float = 0.0
    amplitude: float = 0.0
    period: float = math.inf
    phase: float = 0.0

    def __post_init__(self):
        set_ = object.__setattr__
        set_(self, "base", finite("load.base", self.base))
        set_(self, "amplitude", finite("load.amplitude", self.amplitude))
        set_(self, "period", positive("load.period", self.period, allow_inf=True))
        set_(self, "phase", finite("load.phase", self.phase))

    @property
    def angular_frequency(self) -> float:
        return 2.0 * math.pi / self.period

    def value(self, t: float) -> float:
        return self.base + self.amplitude * (1.0 - math.cos(self.angular_frequency * t + self.phase))


@dataclass(frozen=True)
class Wall(_Replaceable):
    """A rigid straight wall: the line ``normal · x = position``.

    ``normal`` is a unit vector pointing into the domain (it is normalised). The wall
    translates along its normal only; ``tangential_velocity`` slides its surface along
    ``t = z × n`` (for a floor, ``n = +y`` and ``t = -x``).

    - ``mode="fixed"``: does not move;
    - ``mode="velocity"``: ``d position/dt = velocity`` (positive moves into the domain);
    - ``mode="force"``: ``mass d²position/dt² = load(t) * length + force from the disks``,
      where ``length`` is the distance between the two walls named in
      ``load_per_length_of`` (the biaxial box of ratcheting Eq. 1) or 1 if it is ``None``.

    ``disks = (first, stop)``: only disks ``first`` to ``stop - 1`` meet the wall (boxes side by side in one
    simulation, :mod:`granlab.engine.batch`); ``None``: every disk.
    """

    normal: tuple[float, float] = (0.0, 1.0)
    position: float = 0.0
    mode: str = "fixed"
    velocity: float = 0.0
    tangential_velocity: float = 0.0
    mass: float = 0.0
    load: Load = Load()
    load_per_length_of: tuple[str, str] | None = None
    name: str = ""
    disks: tuple[int, int] | None = None

    def __post_init__(self):
        set_ = object.__setattr__
        nx, ny = pair(f"wall {self.name!r} normal", self.normal, finite)
        norm = math.hypot(nx, ny)
        if norm == 0:
            raise ParameterError(f"wall {self.name!r} normal", self.normal, "a non-zero vector")
        set_(self, "normal", (nx / norm, ny / norm))
        set_(self, "position", finite(f"wall {self.name!r} position", self.position))
        choice(f"wall {self.name!r} mode", self.mode, WALL_MODES)
        if not isinstance(self.load, Load):
            raise ParameterError(f"wall {self.name!r} load", self.load, "a Load")
        set_(self, "velocity", finite(f"wall {self.name!r} velocity", self.velocity))
        set_(self, "tangential_velocity", finite(f"wall {self.name!r} tangential_velocity", self.tangential_velocity))
        if self.mode == "force":
            set_(self, "mass", positive(f"wall {self.name!r} mass", self.mass))
            check_wall_load(self.name, self.load)
        else:
            set_(self, "mass", nonnegative(f"wall {self.name!r} mass", self.mass))
        if self.disks is not None:
            first, stop = pair(f"wall {self.name!r} disks", self.disks, whole)
            if not first < stop:
                raise ParameterError(f"wall {self.name!r} disks", self.disks, "(first, stop) with first < stop")
            set_(self, "disks", (first, stop))


def check_wall_load(name: str, load: Load) -> None:
    """Refuse a force-controlled wall's load that pulls at any time of its cycle: a wall pushes on the
    disks (``base >= 0`` and ``base + 2 amplitude >= 0``)."""
    if load.base < 0.0:
        raise ParameterError(f"wall {name!r} load.base", load.base, "a load that never pulls: base >= 0 (a wall pushes "
                                                                   "on the disks)")
    if load.base + 2.0 * load.amplitude < 0.0:
        raise ParameterError(f"wall {name!r} load.amplitude", load.amplitude,
                             f"a load that never pulls: base + 2 amplitude >= 0, so at least {-load.base / 2:g} with "
                             f"base = {load.base:g} (a wall pushes on the disks)")


def box_walls(x0: float, x1: float, y0: float, y1: float, loads: dict[str, Load] | None = None,
              wall_mass: float = 1.0) -> tuple[Wall, ...]:
    """The four walls of a rectangular box ``[x0, x1] × [y0, y1]``: left, right, bottom, top.

    A wall named in ``loads`` is force-controlled, its load applied per unit length of
    the box side it closes (``F_x = sigma_x L_y``, ``F_y = sigma_y L_x``: ratcheting Eq. 1);
    the others are fixed.
    """
    loads = dict(loads or {})
    names = ("left", "right", "bottom", "top")
    unknown = set(loads) - set(names)
    if unknown:
        raise ParameterError("loads", sorted(unknown), "wall names among left, right, bottom, top")
    if not x1 > x0:
        raise ParameterError("box x1", x1, f"greater than x0 = {x0}")
    if not y1 > y0:
        raise ParameterError("box y1", y1, f"greater than y0 = {y0}")
    geometry = {
        "left": ((1.0, 0.0), x0, ("bottom", "top")),
        "right": ((-1.0, 0.0), -x1, ("bottom", "top")),
        "bottom": ((0.0, 1.0), y0, ("left", "right")),
        "top": ((0.0, -1.0), -y1, ("left", "right")),
    }
    walls = []
    for name in names:
        normal, position, across = geometry[name]
        if name in loads:
            walls.append(Wall(normal, position, "force", mass=wall_mass, load=loads[name],
                              load_per_length_of=across, name=name))
        else:
            walls.append(Wall(normal, position, "fixed", name=name))
    return tuple(walls)


@dataclass(frozen=True)
class PeriodicCell(_Replaceable):
    """A rectangular cell ``[0, L_x) × [0, L_y)`` periodic along the chosen axes.

    Along a periodic axis the length is ``"fixed"``, follows a prescribed
    ``strain_rate`` (``-dL/dt / L0``, compression positive), or is ``"stress"``-controlled
    by Gilabert Eq. 3: ``M d²eps/dt² = sigma^I - sigma^M`` with ``eps = -(L - L0)/L0``,
    ``M = mass`` (``None``: 3/10 of the total grain mass divided by sqrt(L_x L_y),
    as in Gilabert Sec. II A) and ``|d eps/dt| <= max_strain_rate``.
    """

    lengths: tuple[float, float] = (1.0, 1.0)
    periodic: tuple[bool, bool] = (True, True)
    control: tuple[str, str] = ("fixed", "fixed")
    stress: tuple[float, float] = (0.0, 0.0)
    strain_rate: tuple[float, float] = (0.0, 0.0)
    mass: float | None = None
    max_strain_rate: float = math.inf

    def __post_init__(self):
        set_ = object.__setattr__
        set_(self, "lengths", pair("cell.lengths", self.lengths, positive))
        if not isinstance(self.periodic, (tuple, list)) or len(self.periodic) != 2 or \
                not all(isinstance(p, bool) for p in self.periodic):
            raise ParameterError("cell.periodic", self.periodic, "a pair of booleans")
        set_(self, "periodic", tuple(self.periodic))
        if not any(self.periodic):
            raise ParameterError("cell.periodic", self.periodic, "at least one periodic axis")
        if not isinstance(self.control, (tuple, list)) or len(self.control) != 2:
            raise ParameterError("cell.control", self.control, "a pair of controls")
        for axis in range(2):
            choice(f"cell.control[{axis}]", self.control[axis], CELL_CONTROLS)
            if self.control[axis] != "fixed" and not self.periodic[axis]:
                raise ParameterError(f"cell.control[{axis}]", self.control[axis],
                                     "'fixed' along a non-periodic axis")
        set_(self, "control", tuple(self.control))
        set_(self, "stress", pair("cell.stress", self.stress, finite))
        set_(self, "strain_rate", pair("cell.strain_rate", self.strain_rate, finite))
        if self.mass is not None:
            set_(self, "mass", positive("cell.mass", self.mass))
        set_(self, "max_strain_rate", positive("cell.max_strain_rate", self.max_strain_rate, allow_inf=True))
