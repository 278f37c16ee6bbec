"""Gilabert's equilibrium criteria (Sec. II D) and a runner that stops on them."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError
from ..simulation import Simulation
from ..state import STATUS_NONE, WALL_FORCE

FORCE_TOLERANCE = 1e-4
PRESSURE_TOLERANCE = 1e-4
KINETIC_TOLERANCE = 5e-8


@dataclass(frozen=True)
class EquilibriumReport:
    """Gilabert Sec. II D, with ``F1 = max(F0, P a)`` and ``a`` the largest diameter:
    net force < 1e-4 F1 and moment < 1e-4 F1 a on every disk, pressure mismatch < 1e-4 F1/a,
    kinetic energy per grain < 5e-8 F1 a. Each value is reported in units of its tolerance.

    The kinetic energy counts the disks with two interactions or more: a rattler keeps its spin
    forever, and a disk held by one cohesive contact rolls on its partner undamped (Gilabert
    Sec. IV A); neither carries the backbone's forces. In a fully periodic cell velocities are
    taken relative to the centre of mass (a uniform drift is still an equilibrium)."""

    equilibrated: bool
    force: float
    moment: float
    pressure: float
    kinetic: float
    force_scale: float
    diameter: float
    measured_pressure: float

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def measured_pressure(sim: Simulation) -> float:
    """Pressure on the sample: ``(sigma_xx + sigma_yy) / 2`` of a periodic cell (Gilabert Eq. 3),
    or, for a box, the mean force per unit length on its force-controlled walls."""
    cell = sim.cell
    if all(sim.periodic):
        area = cell.length[0] * cell.length[1]
        return float((cell.kinetic.sum() + cell.virial[0, 0] + cell.virial[1, 1]) / (2.0 * area))
    walls = sim.walls
    loaded = np.flatnonzero(walls.mode == WALL_FORCE)
    values = []
    for m in loaded:
        a, b = walls.length_ref[m]
        length = -(walls.offset[a] + walls.offset[b]) if a >= 0 else 1.0
        values.append(-walls.particle_force[m] / length)
    return float(np.mean(values)) if values else 0.0


def equilibrium(sim: Simulation, pressure: float) -> EquilibriumReport:
    """Evaluate the criteria on the current state for an imposed ``pressure``."""
    p = sim.particles
    dynamic = p.inv_mass > 0
    diameter = 2.0 * float(p.radius.max())
    force_scale = max(sim.law.cohesion_force, pressure * diameter)
    if force_scale <= 0:
        raise ParameterError("pressure", pressure, "a positive pressure or a cohesive law (F1 = max(F0, P a) > 0)")
    force = float(np.max(np.hypot(p.force[dynamic, 0], p.force[dynamic, 1]), initial=0.0))
    moment = float(np.max(np.abs(p.torque[dynamic]), initial=0.0))
    measured = measured_pressure(sim)
    kinetic = backbone_kinetic_energy(sim) / max(1, int(dynamic.sum()))
    ratios = dict(
        force=force / (FORCE_TOLERANCE * force_scale),
        moment=moment / (FORCE_TOLERANCE * force_scale * diameter),
        pressure=abs(measured - pressure) / (PRESSURE_TOLERANCE * force_scale / diameter),
        kinetic=kinetic / (KINETIC_TOLERANCE * force_scale * diameter),
    )
    return EquilibriumReport(equilibrated=all(v < 1.0 for v in ratios.values()), force_scale=force_scale,
                             diameter=diameter, measured_pressure=measured, **ratios)


def backbone_kinetic_energy(sim: Simulation) -> float:
    p = sim.particles
    n = p.count
    table = sim.contacts
    rows = table.count
    active = table.status[:rows] != STATUS_NONE
    j = table.particle_j[:rows][active]
    count = np.bincount(table.particle_i[:rows][active], minlength=n) + np.bincount(j[j < n], minlength=n)
    linked = (count >= 2) & (p.inv_mass > 0)
    velocity = p.velocity
    dynamic = p.inv_mass > 0
    if all(sim.periodic) and dynamic.any():
        drift = (p.mass[dynamic, None] * velocity[dynamic]).sum(axis=0) / p.mass[dynamic].sum()
        velocity = velocity - drift
    translation = 0.5 * p.mass[linked] * np.sum(velocity[linked] ** 2, axis=1)
    rotation = 0.5 * p.inertia[linked] * p.omega[linked] ** 2
    finite_inertia = np.isfinite(p.inertia[linked])
    return float(translation.sum() + rotation[finite_inertia].sum())


@dataclass(frozen=True)
class Relaxation:
    """Outcome of :func:`relax`: the last report, and the simulated and wall-clock time taken."""

    report: EquilibriumReport
    sim_time: float
    wall_time_s: float


class Progress:
    """Reports a preparation's state as one line, ``emit(line)``, at most every ``every`` seconds
    of wall clock: a large packing can run for minutes between two results.

    :meth:`run` steps a simulation in pieces of about ``every`` seconds (each piece the same
    steps as one run of them all); ``stage`` names what it is doing in the next lines."""

    def __init__(self, emit: Callable[[str], None], pressure: float, stage: str = "relaxing", every: float = 1.0):
        self.emit, self.pressure, self.stage, self.every = emit, pressure, stage, every
        self.start = self.last = time.perf_counter()
        self.piece = 1

    def run(self, sim: Simulation, steps: int) -> None:
        while steps > 0:
            piece = min(steps, self.piece)
            began = time.perf_counter()
            sim.run(piece)
            now = time.perf_counter()
            steps -= piece
            self.piece = max(1, min(2 * piece, int(piece * self.every / max(now - began, 1e-9))))
            if now - self.last >= self.every:
                self.last = now
                self.emit(self.line(sim, now - self.start))

    def line(self, sim: Simulation, elapsed: float) -> str:
        p = sim.particles
        kinetic = 0.5 * float(np.sum(p.mass * np.sum(p.velocity ** 2, axis=1)))
        report = equilibrium(sim, self.pressure)
        ratios = {name: getattr(report, name) for name in ("force", "moment", "pressure", "kinetic")}
        furthest = max(ratios, key=ratios.get)
        pressure = (f"pressure {report.measured_pressure / self.pressure:.4f} of P0" if self.pressure > 0
                    else f"pressure {report.measured_pressure:.3g}")
        return (f"{self.stage}: t = {sim.time:.1f}, {pressure}, kinetic energy {kinetic:.2g}, "
                f"{furthest} {ratios[furthest]:.3g}x its equilibrium tolerance, {elapsed:.0f} s")


def advance(sim: Simulation, steps: int, progress: Progress | None) -> None:
    """``sim.run(steps)``, reporting to ``progress`` if given."""
    if progress is None:
        sim.run(steps)
    else:
        progress.run(sim, steps)


def relax(sim: Simulation, pressure: float, max_time: float, check_every: float | None = None,
          kinetic: bool = True, progress: Progress | None = None) -> Relaxation:
    """Run until :func:`equilibrium` holds (checked every ``check_every``) or ``max_time`` has passed,
    reporting to ``progress`` (if given) as it goes.

    ``kinetic=False`` waits for balanced forces, moments and pressure only (an isolated aggregate
    can spin as a rigid body for ever)."""
    if not max_time > 0:
        raise ParameterError("max_time", max_time, "a positive duration")
    if check_every is None:
        check_every = max(sim.dt, max_time / 400.0)
    steps = max(1, int(round(check_every / sim.dt)))
    start_time, start_wall = sim.time, time.perf_counter()
    def done(report):
        if kinetic:
            return report.equilibrated
        return report.force < 1.0 and report.moment < 1.0 and report.pressure < 1.0

    report = equilibrium(sim, pressure)
    while not done(report) and sim.time - start_time < max_time - 0.5 * sim.dt:
        advance(sim, min(steps, max(1, int(math.ceil((max_time - (sim.time - start_time)) / sim.dt)))), progress)
        report = equilibrium(sim, pressure)
    return Relaxation(report, sim.time - start_time, time.perf_counter() - start_wall)
