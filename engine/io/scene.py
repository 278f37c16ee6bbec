"""TOML scene files: a complete description of a simulation.

A scene has the sections ``[simulation]``, ``[contact]``, ``[particles]`` (explicit
``[[particles.disk]]`` entries and/or generated ``[[particles.lattice]]`` and
``[[particles.gas]]`` groups), and optionally ``[box]``, ``[[walls]]`` and ``[cell]``.
docs/scenes.md documents every key. A broken file raises :class:`SceneError` naming the key
and what is allowed.
"""

from __future__ import annotations

import math
import re
import reprlib
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numba
import numpy as np

from .. import costs, generate
from ..errors import ParameterError, SceneError
from ..params import ContactLaw, Integration, Load, PeriodicCell, Wall, box_walls, check_wall_load
from ..simulation import Simulation
from ..state import HUGE, ParticleState
from .inputs import require_file

SIMULATION_KEYS = {"duration", "steps", "dt", "dt_safety", "skin", "max_overlap", "initial_overlap", "gravity",
                   "record_every", "threads"}
CONTACT_KEYS = {"normal_stiffness", "tangential_stiffness", "friction", "damping_ratio", "tangential_damping",
                "normal_model", "tangential_model", "cohesion_force", "cohesion_range", "rolling_stiffness",
                "rolling_friction", "rolling_damping_ratio"}
DISK_KEYS = {"x", "y", "r", "vx", "vy", "omega", "angle", "mass", "density", "inertia", "kind"}
RADIUS_KEYS = {"radius", "radius_min", "radius_max", "seed"}
GROUP_KEYS = {"density", "kind", "velocity", "velocity_spread"} | RADIUS_KEYS
LATTICE_KEYS = {"pattern", "rows", "columns", "spacing", "origin"} | GROUP_KEYS
GAS_KEYS = {"region", "count", "solid_fraction"} | GROUP_KEYS
WALL_KEYS = {"name", "normal", "position", "mode", "velocity", "tangential_velocity", "mass", "load",
             "load_per_length_of"}
LOAD_KEYS = {"base", "amplitude", "period", "phase"}
BOX_KEYS = {"x", "y", "wall_mass", "loads"}
CELL_KEYS = {"lengths", "periodic", "control", "stress", "strain_rate", "mass", "max_strain_rate"}
TOP_KEYS = {"simulation", "contact", "particles", "walls", "box", "cell", "title"}


@dataclass
class Scene:
    """A parsed scene: everything needed to build a :class:`Simulation` and run it."""

    particles: ParticleState
    law: ContactLaw
    integration: Integration
    walls: tuple[Wall, ...] = ()
    cell: PeriodicCell | None = None
    gravity: tuple[float, float] = (0.0, 0.0)
    duration: float | None = None
    steps: int | None = None
    record_every: int = 0
    threads: int | None = None
    title: str = ""
    source: str = field(default="", repr=False)
    owners: "Owners" = field(default_factory=lambda: Owners(), repr=False)
    box_walls: int = 0
    """How many of ``walls`` come from ``[box]`` (the first ones); the rest are ``[[walls]]``."""

    def build(self) -> Simulation:
        """A new simulation of this scene (each call starts from the initial state); a scene that
        cannot start, or whose disks would fly through each other in the first step, is refused
        naming the tables of the disks and walls at fault."""
        try:
            sim = Simulation(self.particles.copy(), self.law, self.integration, self.walls, self.cell, self.gravity)
        except ParameterError as error:
            where = "simulation." if error.name in ("dt", "dt_safety") else ""
            raise SceneError(f"scene cannot start: {where}{self._owned(str(error))}") from error
        speed = np.hypot(*sim.particles.velocity.T) * sim.dt / sim.particles.radius
        limit = 0.5 * sim.integration.max_overlap
        if np.any(speed > limit):
            disk = int(np.argmax(speed))
            raise SceneError(f"[{self.owners.table(disk)}] vx, vy or velocity, velocity_spread: disk {disk} would move "
                             f"{speed[disk]:.3g} of its radius in the first step of dt = {sim.dt:.4g}; at most "
                             f"max_overlap / 2 = {limit:.3g} (it could pass through a neighbour)")
        return sim

    def _owned(self, message: str) -> str:
        """``message`` with each disk and wall it names followed by the table that made it."""
        names = {wall.name: "[box] x, y" if k < self.box_walls else f"[walls[{k - self.box_walls}]] position"
                 for k, wall in enumerate(self.walls)}
        message = re.sub(r"\bdisk (\d+)\b", lambda m: f"{m.group(0)} ([{self.owners.table(int(m.group(1)))}])",
                         message)
        return re.sub(r"\bwall '([^']*)'", lambda m: f"{m.group(0)} ({names.get(m.group(1), 'walls')})", message)

    def step_count(self, dt: float) -> int:
        """Steps of ``dt`` the scene runs: its steps, or its duration's (at most :data:`costs.MAX_STEPS`)."""
        if self.steps is not None:
            return costs.check_steps(self.steps, f"simulation.steps = {self.steps}", dt)
        steps = self.duration / dt if dt > 0 else math.inf
        return costs.check_steps(round(steps) if steps < math.inf else steps,
                                 f"simulation.duration = {self.duration:.6g}", dt)


def builtin_scenes() -> list[str]:
    """Names of the scenes shipped with GranLab (``granlab run NAME``)."""
    folder = resources.files(__package__) / "scenes"
    return sorted(entry.name[:-5] for entry in folder.iterdir() if entry.name.endswith(".toml"))


def load_scene(path_or_name: str | Path) -> Scene:
    """Read a scene from a TOML file, or a built-in scene by name."""
    path = Path(path_or_name)
    if not path.suffix and str(path_or_name) in builtin_scenes():
        text = (resources.files(__package__) / "scenes" / f"{path_or_name}.toml").read_text()
        return parse_scene(text, origin=f"built-in scene {path_or_name!r}")
    require_file(path, "scene file", SceneError, hint=f": give a scene file (.toml) or a built-in scene "
                                                       f"({', '.join(builtin_scenes())})")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise SceneError(f"scene file {str(path)!r} cannot be read as UTF-8 text: {error}") from error
    return parse_scene(text, origin=str(path))


def parse_scene(text: str, origin: str = "scene") -> Scene:
    """Parse the text of a TOML scene."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        places = _where(text)
        said = re.sub(r"\(at line (\d+), column (\d+)\)",
                      lambda m: f"at {places.get(int(m.group(1)), 'line ' + m.group(1))}, column {m.group(2)}",
                      str(error))
        raise SceneError(f"{origin} is not valid TOML: {said}") from error
    except RecursionError:
        raise SceneError(f"{origin} cannot be read: {_deepest(text)}") from None
    try:
        with np.errstate(over="ignore", invalid="ignore"):  # what overflows is refused by name, not warned of
            return _scene(data, text)
    except SceneError as error:
        raise SceneError(f"{origin}: {error}") from error


def _where(text: str) -> dict[int, str]:
    """Each line of ``text`` that starts a value or a table, as a person finds it: ``line 9
    (gravity in [simulation])``."""
    section, depth, places = "", 0, {}
    for number, line in enumerate(text.splitlines(), 1):
        header = re.fullmatch(r"\s*\[+\s*([^\]=]+?)\s*\]+\s*(#.*)?", line) if depth == 0 else None
        key = re.match(r"\s*([\w.\-\"']+)\s*=", line) if depth == 0 else None
        section = header.group(1) if header else section
        what = f"[{section}]" if header else key.group(1) + (f" in [{section}]" if section else "") if key else ""
        places[number] = f"line {number}" + (f" ({what})" if what else "")
        depth = max(0, depth + sum((char in "[{") - (char in "]}") for char in line)) if not header else 0
    return places


def _deepest(text: str) -> str:
    """Where ``text`` nests brackets deepest, as a reader that gave up on it would want to know."""
    depth, deepest, start = 0, (0, 1), 1
    for number, line in enumerate(text.splitlines(), 1):
        start = number if depth == 0 else start
        for char in line:
            depth += (char in "[{") - (char in "]}")
            deepest = max(deepest, (depth, start))
    return (f"{_where(text)[deepest[1]]} nests arrays or inline tables {deepest[0]} deep, too deep for its "
            f"reader; a scene needs two levels")


# ---------------------------------------------------------------------------------------------- helpers
def _keys(table, path: str, allowed: set[str]) -> dict:
    if not isinstance(table, dict):
        raise SceneError(f"[{path}] must be a table, not {type(table).__name__}")
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise SceneError(f"unknown key {path}.{unknown[0]}: allowed keys are {', '.join(sorted(allowed))}")
    return table


_short = reprlib.Repr()  # its keyword arguments are Python 3.12's
_short.maxlevel, _short.maxlist, _short.maxdict, _short.maxstring, _short.maxother = 2, 4, 4, 40, 40
_shown = _short.repr
"""A value in a message, cut short: a list nested 5000 deep is shown as ``[[...]]``."""


def _sound(value, allow_inf=False) -> bool:
    """A number, not NaN, below :data:`HUGE` in size (or infinite, where ``allow_inf``)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    return abs(value) < HUGE or allow_inf and math.isinf(value)


def _number(table, key, path, default=None, allow_inf=False):
    value = table.get(key, default)
    if value is None:
        return None
    if not _sound(value, allow_inf):
        raise SceneError(f"{path}.{key} = {_shown(value)} is not allowed: a number below 1e150 in size"
                         + (" (or inf)" if allow_inf else ""))
    return float(value)


def _integer(table, key, path, default=None, minimum=None):
    value = table.get(key, default)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or (minimum is not None and value < minimum):
        allowed = "a whole number" + (f" >= {minimum}" if minimum is not None else "")
        raise SceneError(f"{path}.{key} = {_shown(value)} is not allowed: {allowed}")
    return value


def _vector(table, key, path, size=2, default=None):
    value = table.get(key, default)
    if value is None:
        return None
    if not isinstance(value, list) or len(value) != size or not all(_sound(v) for v in value):
        raise SceneError(f"{path}.{key} = {_shown(value)} is not allowed: a list of {size} numbers below 1e150 in "
                         f"size")
    return tuple(float(v) for v in value)


def _string(table, key, path, default=None):
    value = table.get(key, default)
    if value is not None and not isinstance(value, str):
        raise SceneError(f"{path}.{key} = {_shown(value)} is not allowed: a string")
    return value


def _build(path: str, factory, **kwargs):
    """Call a validated constructor, turning its ParameterError into a SceneError at ``path``."""
    try:
        return factory(**{k: v for k, v in kwargs.items() if v is not None})
    except ParameterError as error:
        raise SceneError(f"[{path}] {error}") from error


# ---------------------------------------------------------------------------------------------- sections
def _scene(data: dict, text: str) -> Scene:
    _keys(data, "scene", TOP_KEYS)
    sim = _keys(data.get("simulation", {}), "simulation", SIMULATION_KEYS)
    contact = _keys(data.get("contact", {}), "contact", CONTACT_KEYS)
    for key, value in contact.items():
        if isinstance(value, (int, float)) and not isinstance(value, bool) and not _sound(value, allow_inf=True):
            raise SceneError(f"contact.{key} = {value!r} is not allowed: a number below 1e150 in size")
    law = _build("contact", ContactLaw, **{key: contact[key] for key in contact})
    integration = _build("simulation", Integration, dt=_number(sim, "dt", "simulation"),
                         dt_safety=_number(sim, "dt_safety", "simulation"),
                         skin=_number(sim, "skin", "simulation"),
                         max_overlap=_number(sim, "max_overlap", "simulation"),
                         initial_overlap=_number(sim, "initial_overlap", "simulation"))
    duration = _number(sim, "duration", "simulation")
    steps = _integer(sim, "steps", "simulation", minimum=0)
    if duration is None and steps is None:
        raise SceneError("[simulation] needs duration (simulated time) or steps (number of steps)")
    if duration is not None and steps is not None:
        raise SceneError("[simulation] takes duration or steps, not both")
    if duration is not None and not (duration >= 0 and math.isfinite(duration)):
        raise SceneError(f"simulation.duration = {duration!r} is not allowed: a finite duration >= 0")
    gravity = _vector(sim, "gravity", "simulation", default=[0.0, 0.0])
    cell = _cell(data["cell"]) if "cell" in data else None
    walls = _walls(data)
    particles, owners = _particles(data.get("particles"), cell, data.get("box"))
    return Scene(particles=particles, law=law, integration=integration, walls=walls, cell=cell, gravity=gravity,
                 duration=duration, steps=steps, record_every=_integer(sim, "record_every", "simulation", 0, 0),
                 threads=_threads(sim), title=_string(data, "title", "scene", ""),
                 source=text, owners=owners, box_walls=4 if "box" in data else 0)


def _threads(sim) -> int | None:
    threads = _integer(sim, "threads", "simulation", minimum=1)
    if threads is not None and threads > numba.config.NUMBA_NUM_THREADS:
        raise SceneError(f"simulation.threads = {threads} is not allowed: at most {numba.config.NUMBA_NUM_THREADS}, "
                         "the threads numba may use on this machine (leave threads out to use them all)")
    return threads


def _load(table, path, wall: str | None = None) -> Load:
    """The load at ``path``; on ``wall`` (force-controlled), refused where it would pull, naming the key."""
    _keys(table, path, LOAD_KEYS)
    load = _build(path, Load, base=_number(table, "base", path), amplitude=_number(table, "amplitude", path),
                  period=_number(table, "period", path), phase=_number(table, "phase", path))
    if wall is not None:
        _build(path, check_wall_load, name=wall, load=load)
    return load


def _walls(data) -> tuple[Wall, ...]:
    walls = []
    if "box" in data:
        box = _keys(data["box"], "box", BOX_KEYS)
        x = _vector(box, "x", "box")
        y = _vector(box, "y", "box")
        if x is None or y is None:
            raise SceneError("[box] needs x = [x0, x1] and y = [y0, y1]")
        loads_table = _keys(box.get("loads", {}), "box.loads", {"left", "right", "bottom", "top"})
        loads = {name: _load(value, f"box.loads.{name}", wall=name) for name, value in loads_table.items()}
        wall_mass = _number(box, "wall_mass", "box")
        if wall_mass is not None and not wall_mass > 0:
            raise SceneError(f"box.wall_mass = {wall_mass!r} is not allowed: a positive mass (that of each wall)")
        walls.extend(_build("box", box_walls, x0=x[0], x1=x[1], y0=y[0], y1=y[1], loads=loads, wall_mass=wall_mass))
    entries = data.get("walls", [])
    if not isinstance(entries, list):
        raise SceneError("walls must be an array of tables: [[walls]]")
    for k, entry in enumerate(entries):
        path = f"walls[{k}]"
        _keys(entry, path, WALL_KEYS)
        per_length = entry.get("load_per_length_of")
        if per_length is not None and (not isinstance(per_length, list) or len(per_length) != 2
                                       or not all(isinstance(n, str) for n in per_length)):
            raise SceneError(f"{path}.load_per_length_of = {_shown(per_length)} is not allowed: two wall names")
        mode, name = _string(entry, "mode", path), _string(entry, "name", path, default=f"wall{len(walls)}")
        walls.append(_build(path, Wall, normal=_vector(entry, "normal", path), position=_number(entry, "position", path),
                            mode=mode, velocity=_number(entry, "velocity", path),
                            tangential_velocity=_number(entry, "tangential_velocity", path),
                            mass=_number(entry, "mass", path),
                            load=_load(entry["load"], f"{path}.load", wall=name if mode == "force" else None)
                            if "load" in entry else None,
                            load_per_length_of=tuple(per_length) if per_length else None, name=name))
    return tuple(walls)


def _cell(table) -> PeriodicCell:
    _keys(table, "cell", CELL_KEYS)
    periodic = table.get("periodic")
    if periodic is not None and (not isinstance(periodic, list) or len(periodic) != 2
                                 or not all(isinstance(p, bool) for p in periodic)):
        raise SceneError(f"cell.periodic = {_shown(periodic)} is not allowed: two booleans")
    control = table.get("control")
    if control is not None and (not isinstance(control, list) or len(control) != 2):
        raise SceneError(f"cell.control = {_shown(control)} is not allowed: two of fixed, stress, strain-rate")
    stress, strain_rate = _vector(table, "stress", "cell"), _vector(table, "strain_rate", "cell")
    for key, target, mode in (("stress", stress, "stress"), ("strain_rate", strain_rate, "strain-rate")):
        # a target on an axis not under its control would be ignored without a word
        idle = [axis for axis in range(2) if target is not None and target[axis] != 0.0
                and (control is None or control[axis] != mode)]
        if idle:
            wanted = [mode if axis in idle else (control[axis] if control else "fixed") for axis in range(2)]
            raise SceneError(f"cell.{key} = {list(target)!r} is not allowed with cell.control = "
                             f"{list(control) if control else ['fixed', 'fixed']!r}: the cell would ignore it; "
                             f"give cell.control = {wanted!r}, or {key} 0 on the axes not under {mode} control")
    return _build("cell", PeriodicCell, lengths=_vector(table, "lengths", "cell"),
                  periodic=tuple(periodic) if periodic else None, control=tuple(control) if control else None,
                  stress=stress, strain_rate=strain_rate,
                  mass=_number(table, "mass", "cell"),
                  max_strain_rate=_number(table, "max_strain_rate", "cell", allow_inf=True))


def _particles(table, cell: PeriodicCell | None, box) -> tuple[ParticleState, "Owners"]:
    if table is None:
        raise SceneError("[particles] is missing: list disks with [[particles.disk]] or generate them")
    _keys(table, "particles", {"density", "disk", "lattice", "gas"})
    default_density = _number(table, "density", "particles", 1.0)
    if not default_density > 0:
        raise SceneError(f"particles.density = {default_density!r} is not allowed: a positive areal density")
    columns = {name: [] for name in ("position", "radius", "velocity", "omega", "angle", "mass", "inertia", "kind")}
    owners: list[tuple[int, str]] = []  # (disks so far, the table that made them)

    def add(table, position, radius, velocity, omega, angle, mass, inertia, kind):
        owners.append((owners[-1][0] + len(radius) if owners else len(radius), table))
        columns["position"].append(position)
        columns["radius"].append(radius)
        columns["velocity"].append(velocity)
        columns["omega"].append(omega)
        columns["angle"].append(angle)
        columns["mass"].append(mass)
        columns["inertia"].append(inertia)
        columns["kind"].append(kind)

    for k, disk in enumerate(_array(table, "disk")):
        path = f"particles.disk[{k}]"
        _keys(disk, path, DISK_KEYS)
        x, y, r = (_number(disk, key, path) for key in ("x", "y", "r"))
        if x is None or y is None or r is None:
            raise SceneError(f"{path} needs x, y and r")
        if not r > 0:
            raise SceneError(f"{path}.r = {r!r} is not allowed: a positive radius")
        if "mass" in disk and "density" in disk:
            raise SceneError(f"{path} takes mass or density, not both")
        density = _number(disk, "density", path, default_density)
        mass = _number(disk, "mass", path) if "mass" in disk else \
            _made(path, "mass = density × π r²", density * math.pi * r * r)
        inertia = _number(disk, "inertia", path, allow_inf=True) if "inertia" in disk else \
            _made(path, "inertia = mass r² / 2", 0.5 * mass * r * r)
        add(path, np.array([[x, y]]), np.array([r]), np.array([[_number(disk, "vx", path, 0.0), _number(disk, "vy", path, 0.0)]]),
            np.array([_number(disk, "omega", path, 0.0)]), np.array([_number(disk, "angle", path, 0.0)]),
            np.array([mass]), np.array([inertia]), [_string(disk, "kind", path, "dynamic")])

    for k, group in enumerate(_array(table, "lattice")):
        path = f"particles.lattice[{k}]"
        _keys(group, path, LATTICE_KEYS)
        rows = _integer(group, "rows", path, minimum=1)
        cols = _integer(group, "columns", path, minimum=1)
        if rows is None or cols is None:
            raise SceneError(f"{path} needs rows and columns")
        pattern = _string(group, "pattern", path, "square")
        if pattern not in ("square", "triangular"):
            raise SceneError(f"{path}.pattern = {pattern!r} is not allowed: 'square' or 'triangular'")
        _check_memory(owners, rows * cols, path)
        maker = generate.square_lattice if pattern == "square" else generate.triangular_lattice
        spacing = _number(group, "spacing", path)
        if spacing is None:
            raise SceneError(f"{path} needs spacing (distance between neighbouring centres)")
        positions = _build(path, maker, rows=rows, columns=cols, spacing=spacing,
                           origin=_vector(group, "origin", path, default=[0.0, 0.0]))
        _add_group(add, group, path, positions, default_density)

    for k, group in enumerate(_array(table, "gas")):
        path = f"particles.gas[{k}]"
        _keys(group, path, GAS_KEYS)
        region = _vector(group, "region", path, size=4)
        periodic = (False, False)
        if region is None:
            if cell is not None:
                region = (0.0, cell.lengths[0], 0.0, cell.lengths[1])
                periodic = cell.periodic
            elif isinstance(box, dict) and "x" in box and "y" in box:
                region = (box["x"][0], box["x"][1], box["y"][0], box["y"][1])
            else:
                raise SceneError(f"{path} needs region = [x0, x1, y0, y1] (no [cell] or [box] to fill)")
        count = _integer(group, "count", path, minimum=1)
        fraction = _number(group, "solid_fraction", path)
        if (count is None) == (fraction is None):
            raise SceneError(f"{path} takes count or solid_fraction (one of them)")
        if count is None:
            sample = _radii(group, path, 1000)
            area = (region[1] - region[0]) * (region[3] - region[2])
            count = _build(path, generate.gas_count_for_fraction, solid_fraction=fraction, area=area,
                           mean_square_radius=float(np.mean(sample ** 2)))
        _check_memory(owners, count, path)
        radius = _radii(group, path, count)
        seed = _integer(group, "seed", path, 0, minimum=0)
        positions = _build(path, generate.random_gas, radius=radius, region=region, periodic=periodic, seed=seed)
        _add_group(add, group, path, positions, default_density, radius)

    if not columns["position"]:
        raise SceneError("[particles] holds no disks: add [[particles.disk]], [[particles.lattice]] or "
                         "[[particles.gas]]")
    kinds = [kind for group in columns["kind"] for kind in group]
    with np.errstate(over="ignore"):  # a mass or a position that overflows is refused below, by its table
        columns = {name: np.concatenate(values) for name, values in columns.items() if name != "kind"}
    try:
        particles = ParticleState(columns["position"], columns["radius"], velocity=columns["velocity"],
                                  omega=columns["omega"], angle=columns["angle"], mass=columns["mass"],
                                  inertia=columns["inertia"], kind=kinds)
    except ParameterError as error:
        found = re.fullmatch(r"(\w+)\[(\d+)\]", error.name)
        if found is None:
            raise SceneError(f"[particles] {error}") from error
        owner = Owners(tuple(owners)).table(int(found.group(2)))
        raise SceneError(f"[{owner}] {error} (from {MADE_FROM[found.group(1)]})") from error
    return particles, Owners(tuple(owners))


MADE_FROM = {"position": "x, y or spacing, origin, region", "radius": "r or radius, radius_min, radius_max",
             "velocity": "vx, vy or velocity, velocity_spread", "omega": "omega", "angle": "angle",
             "mass": "mass or density and r or radius", "inertia": "inertia", "kind": "kind"}
"""The keys a disk's value is made from, in [[particles.disk]] or in a group."""


@dataclass(frozen=True)
class Owners:
    """Which table of the scene made each disk: ``ends`` pairs (disks so far, table)."""

    ends: tuple[tuple[int, str], ...] = ()

    def table(self, disk: int) -> str:
        return next((table for end, table in self.ends if disk < end), "particles")


def _check_memory(owners: list[tuple[int, str]], more: int, path: str) -> None:
    """Refuse, before they are made, disks this machine cannot simulate (with those made so far);
    a group above the generators' own limit is left to them to refuse, naming it."""
    if more > generate.MAX_DISKS:
        return
    try:
        costs.check_memory((owners[-1][0] if owners else 0) + more, f"[{path}] rows × columns or count")
    except costs.CostError as error:
        raise SceneError(str(error)) from None


def _made(path: str, how: str, value: float) -> float:
    """A disk's value made from others (its mass from its density and radius): refused, naming
    how it is made, where it overflows, rather than taken for a value given as inf."""
    if not abs(value) < HUGE:
        raise SceneError(f"[{path}] {how} = {value:.4g} is not allowed: below 1e150 in size")
    return value


def _array(table, key):
    value = table.get(key, [])
    if not isinstance(value, list):
        raise SceneError(f"particles.{key} must be an array of tables: [[particles.{key}]]")
    return value


def _radii(group, path, count) -> np.ndarray:
    radius = _number(group, "radius", path)
    lo = _number(group, "radius_min", path)
    hi = _number(group, "radius_max", path)
    if radius is not None and (lo is not None or hi is not None):
        raise SceneError(f"{path} takes radius, or radius_min and radius_max, not both")
    if radius is None and (lo is None or hi is None):
        raise SceneError(f"{path} needs radius, or radius_min and radius_max (uniform distribution)")
    distribution = "constant" if radius is not None else "uniform"
    return _build(path, generate.radii, count=count, radius=radius, radius_min=lo, radius_max=hi,
                  distribution=distribution, seed=_integer(group, "seed", path, 0, minimum=0))


def _add_group(add, group, path, positions, default_density, radius=None):
    n = positions.shape[0]
    if radius is None:
        radius = _radii(group, path, n)
    density = _number(group, "density", path, default_density)
    if not density > 0:
        raise SceneError(f"{path}.density = {density!r} is not allowed: a positive areal density")
    mass = density * math.pi * radius ** 2
    velocity = np.tile(_vector(group, "velocity", path, default=[0.0, 0.0]), (n, 1))
    spread = _number(group, "velocity_spread", path, 0.0)
    if not spread >= 0:
        raise SceneError(f"{path}.velocity_spread = {spread!r} is not allowed: a standard deviation >= 0")
    if spread > 0:
        velocity += np.random.default_rng(_integer(group, "seed", path, 0, minimum=0) + 1).normal(0.0, spread, (n, 2))
    add(path, positions, radius, velocity, np.zeros(n), np.zeros(n), mass, 0.5 * mass * radius ** 2,
        [_string(group, "kind", path, "dynamic")] * n)
