"""Preparing packings: the biaxial box of the ratcheting paper and Gilabert's methods 1 and 2.

Each function returns a :class:`Prepared`: the simulation, ready for the next stage, the
last equilibrium report (Gilabert Sec. II D) and the simulated and wall-clock time it took.
A preparation that does not reach equilibrium within its time limit is returned as such
(``equilibrated`` false): the caller decides.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..errors import ParameterError
from ..generate import radii, random_gas, square_lattice, strip_order
from ..observables import clusters, columns
from ..params import (GILABERT_DT_SAFETY, ContactLaw, Integration, Load, PeriodicCell, box_walls,
                      check_cell_mass_reading, nonnegative, positive, whole)
from ..simulation import PARALLEL_MIN_DISKS, Simulation
from ..state import CELL_MASS_FRACTION, ParticleState, default_cell_mass
from .equilibrium import EquilibriumReport, Progress, advance, equilibrium, measured_pressure, relax


@dataclass
class Prepared:
    """A prepared packing; ``stages`` maps each stage of method 2 or of compress to its (simulated, wall-clock) time."""

    sim: Simulation
    report: EquilibriumReport
    sim_time: float
    wall_time_s: float
    method: str
    pressure: float
    stages: dict = field(default_factory=dict)

    @property
    def equilibrated(self) -> bool:
        return self.report.equilibrated


# ---------------------------------------------------------------------------------------------- biaxial box
def biaxial_law(stiffness: float = 100.0, damping_ratio: float = 0.3, normal_model: str = "linear",
                tangential_model: str = "cundall-strack") -> ContactLaw:
    """The contact law of the biaxial box: ``K_n = K_t = stiffness``, frictionless."""
    return ContactLaw(normal_stiffness=stiffness, tangential_stiffness=stiffness, friction=0.0,
                      damping_ratio=damping_ratio, normal_model=normal_model, tangential_model=tangential_model)


LOADED_WALLS = ("right", "top")

COMPRESSION_RAMP = 10.0
"""Time over which the load on the biaxial box rises from 0 to P0: the loose lattice collapses
under a fraction of P0, then is pressed slowly. At P0 at once, even walls of one row hit 5600
disks hard enough to overlap them by half a radius (t = 0.63); with the ramp their overlaps
stay below 0.12 of a radius (0.08 at rest)."""

COMPRESSION_CHECK = 0.1
"""How often (in tau) the compression tests Gilabert's criteria. Near equilibrium the largest
force on a disk swings about its tolerance for a while: tested every tau, 5600 disks stopped at
t = 36, though the criteria had held at t = 27.9 already. A test costs about 2 steps of 1600
disks, and a tenth of tau is 1300 of their steps."""


def biaxial_box(count: int = 16, seed: int = 0, pressure: float = 1.0, stiffness: float = 100.0,
                box: float = 1.0, density: float = 1.0, damping_ratio: float = 0.3, normal_model: str = "linear",
                tangential_model: str = "cundall-strack", wall_mass: float | None = None, dt: float | None = None,
                dt_safety: float = 0.2, wall_mass_fraction: float | None = None) -> Simulation:
    """The initial biaxial box of ratcheting Sec. IV B 1, before compression.

    Units: box length L, pressure p (a 2D pressure, force per length) and density rho, so the
    time unit is ``tau = sqrt(rho L² / p)``. Radii are uniform in ``r_max [0.7, 1]`` with
    ``r_max = L / (2 s)``, the disks on the sites of an ``s × s`` square lattice (the first
    ``count`` sites, ``s = ceil(sqrt(count))``); ``K_n = K_t = stiffness × p``; the left and
    bottom walls are fixed, the right and top ones pushed with ``pressure`` per unit length
    (mass ``wall_mass``, default ``wall_mass_fraction`` times the total mass of the disks, by
    default ``1 / s``: a wall as heavy as the row of disks it pushes). Frictionless (mu = 0).

    The paper gives no wall mass, and none changes the equilibrium. Walls as heavy as the whole
    packing ring on it, hardly damped (their mode's damping ratio falls as ``1 / s``): pushed at
    P0 they overlapped 5600 disks by half a radius (t = 1.88), and under a ramped load the
    pressure on 5600 disks still swung by 8 % at t = 12. Walls of one row are damped by the
    packing within a fraction of tau.
    """
    whole("particles", count, 1)
    pressure = positive("pressure", pressure)
    side = math.ceil(math.sqrt(count))
    r_max = box / (2.0 * side)
    r = r_max * np.random.default_rng(seed).uniform(0.7, 1.0, count)
    positions = square_lattice(side, side, box / side, origin=(r_max, r_max))[:count]
    particles = ParticleState(positions, r, density=density)
    law = biaxial_law(stiffness * pressure, damping_ratio, normal_model, tangential_model)
    fraction = 1.0 / side if wall_mass_fraction is None else wall_mass_fraction
    mass = fraction * float(particles.mass.sum()) if wall_mass is None else wall_mass
    walls = box_walls(0.0, box, 0.0, box, loads={name: Load(base=pressure) for name in LOADED_WALLS}, wall_mass=mass)
    return Simulation(particles, law, Integration(dt=dt, dt_safety=dt_safety), walls=walls)


def ramp_load(sim: Simulation, pressure: float, ramp: float) -> None:
    """Load the box's walls with ``pressure (1 - cos(pi t / ramp)) / 2``: from 0 at t = 0 to
    ``pressure`` at ``ramp``, smoothly (then :func:`hold_load`, before it falls again)."""
    for name in LOADED_WALLS:
        sim.set_wall_load(name, Load(amplitude=pressure / 2.0, period=2.0 * ramp))


def hold_load(sim: Simulation, pressure: float) -> None:
    """Load the box's walls with a constant ``pressure``."""
    for name in LOADED_WALLS:
        sim.set_wall_load(name, Load(base=pressure))


def compress(count: int = 16, seed: int = 0, pressure: float = 1.0, friction: float = 0.2,
             max_time: float = 400.0, ramp: float = COMPRESSION_RAMP,
             progress: Callable[[str], None] | None = None, backend: str = "cpu", **box_options) -> Prepared:
    """Ratcheting Sec. IV B 1: compress the biaxial box frictionless to ``pressure``, then switch
    friction on.

    The load rises to ``pressure`` over ``ramp`` (:data:`COMPRESSION_RAMP`; 0: at once), then
    holds until Gilabert's equilibrium criteria hold (F1 = P a) or for at most ``max_time``.
    ``progress(line)``, if given, gets a line on the state about once a second of wall clock; the steps run
    on ``backend`` (:meth:`~granlab.engine.simulation.Simulation.use_backend`)."""
    start = time.perf_counter()
    sim = biaxial_box(count, seed, pressure, **box_options)
    sim.use_backend(backend)
    ramp = nonnegative("ramp", ramp)
    reporter = None if progress is None else Progress(progress, pressure, "compressing")
    stages = {}
    if ramp > 0:
        ramp_load(sim, pressure, ramp)
        advance(sim, max(1, int(round(ramp / sim.dt))), reporter)
        hold_load(sim, pressure)
        stages["ramp"] = (sim.time, time.perf_counter() - start)
    relaxation = relax(sim, pressure, max_time, check_every=COMPRESSION_CHECK, progress=reporter)
    stages["relaxation"] = (relaxation.sim_time, relaxation.wall_time_s)
    sim.set_law(friction=friction)
    return Prepared(sim, relaxation.report, sim.time, time.perf_counter() - start, "compress", pressure, stages)


# ---------------------------------------------------------------------------------------------- Gilabert
def gilabert_radii(count: int, diameter: float = 1.0, seed: int = 0) -> np.ndarray:
    """Diameters uniform in [a/2, a] (Gilabert Sec. II A)."""
    return radii(count, radius_min=diameter / 4.0, radius_max=diameter / 2.0, distribution="uniform", seed=seed)


def gilabert_law(friction: float = 0.15, kappa: float = 1e5, cohesion: bool = True, rolling: bool = False,
                 pressure: float = 0.01, diameter: float = 1.0, damping_ratio: float = 0.8,
                 rolling_damping_ratio: float = 0.0) -> ContactLaw:
    """The interaction law of Gilabert Table I, in units of the largest diameter ``a`` and of
    ``F0`` (cohesive: ``F0 = 1``, ``kappa = a K_N / F0``, ``D0 = 1e-3 a``) or of ``P a``
    (cohesionless: ``kappa = K_N / P``); ``K_T = K_N``; with rolling resistance
    ``K_r = 1e-4 K_N a²`` and ``mu_r = 1e-2 mu a``.

    ``rolling_damping_ratio`` (not in the paper, which has none) adds a viscous rolling moment
    (see :class:`granlab.engine.params.ContactLaw`; without rolling resistance it has nothing to act on)."""
    force_scale = 1.0 if cohesion else pressure * diameter
    kn = kappa * force_scale / diameter
    kr = 1e-4 * kn * diameter ** 2 if rolling else 0.0
    return ContactLaw(normal_stiffness=kn, tangential_stiffness=kn, friction=friction, damping_ratio=damping_ratio,
                      cohesion_force=1.0 if cohesion else 0.0, cohesion_range=1e-3 * diameter if cohesion else 0.0,
                      rolling_stiffness=kr, rolling_friction=1e-2 * friction * diameter if rolling else 0.0,
                      rolling_damping_ratio=rolling_damping_ratio)


def gilabert_gas(count: int, solid_fraction: float, seed: int, diameter: float = 1.0):
    """Gilabert's gas (Sec. III): radii of :func:`gilabert_radii` placed at random without overlap in a
    periodic square cell at ``solid_fraction``; returns (radii, positions (N, 2), cell length). From
    :data:`granlab.engine.simulation.PARALLEL_MIN_DISKS` disks on, where a run takes every thread, the
    disks are numbered in strips two diameters high (:func:`granlab.engine.generate.strip_order`)."""
    r = gilabert_radii(count, diameter, seed)
    fraction = positive("solid_fraction", solid_fraction)
    if fraction >= 0.55:
        raise ParameterError("solid_fraction", fraction, "a gas fraction below 0.55 (random placement jams)")
    length = math.sqrt(math.pi * float(np.sum(r ** 2)) / fraction)
    positions = random_gas(r, (0.0, length, 0.0, length), periodic=(True, True), seed=seed)
    if count < PARALLEL_MIN_DISKS:  # one thread: the numbering does not matter, and the samples stay as they were
        return r, positions, length
    order = strip_order(positions, 2.0 * diameter)
    return r[order], positions[order], length




def cell_mass(radii, length: float, diameter: float = 1.0, disks: int | None = None,
              reading: str = "mass") -> float:
    """Gilabert's generalized mass ``M`` of Eq. 3 by ``reading`` (:data:`CELL_MASS_READINGS`) for a
    sample of ``disks`` disks (default: these) with the same radii and solid fraction, at the density
    of the preparations (a disk of diameter ``a`` has mass 1).

    ``M`` grows with the sample, like ``N`` (``mass``) or ``sqrt(N)`` (``per-length``), and the
    strain acceleration of the cell is ``(sigma_I - sigma_M) / M``: a small sample compacts faster
    than the paper's (and ends looser and less coordinated) unless it borrows the ``M`` of the
    paper's size."""
    count = len(radii)
    disks = count if disks is None else disks
    whole("cell_mass_disks", disks, 1)
    check_cell_mass_reading(reading)
    grain_mass = 4.0 / diameter ** 2 * float(np.sum(np.asarray(radii) ** 2))
    if reading == "mass":
        return CELL_MASS_FRACTION * grain_mass * disks / count
    return default_cell_mass(grain_mass, (length / diameter, length / diameter)) * math.sqrt(disks / count)


def method1(count: int = 200, solid_fraction: float = 0.36, pressure: float = 0.01, law: ContactLaw | None = None,
            seed: int = 0, diameter: float = 1.0, max_time: float = 2000.0, cell_mass_disks: int | None = None,
            dt_safety: float = GILABERT_DT_SAFETY, cell_mass_reading: str = "mass",
            progress: Callable[[str], None] | None = None, backend: str = "cpu") -> Prepared:
    """Gilabert Sec. III A: a granular gas at ``solid_fraction`` in a periodic cell, at rest, brought
    to equilibrium under the isotropic ``pressure`` by stress control of the cell (Eq. 3), whose
    generalized mass is that of a sample of ``cell_mass_disks`` disks by ``cell_mass_reading``
    (:func:`cell_mass`). ``progress(line)``, if given, gets a line on the state about once a second; the
    steps run on ``backend``."""
    start = time.perf_counter()
    law = law or gilabert_law(pressure=pressure, diameter=diameter)
    r, positions, length = gilabert_gas(count, solid_fraction, seed, diameter)
    cell = PeriodicCell((length, length), control=("stress", "stress"), stress=(pressure, pressure),
                        mass=cell_mass(r, length, diameter, cell_mass_disks, cell_mass_reading))
    sim = Simulation(ParticleState(positions, r, density=4.0 / math.pi / diameter ** 2), law,
                     Integration(dt_safety=dt_safety), cell=cell)
    sim.use_backend(backend)
    reporter = None if progress is None else Progress(progress, pressure, "compressing")
    relaxation = relax(sim, pressure, max_time, progress=reporter)
    return Prepared(sim, relaxation.report, relaxation.sim_time, time.perf_counter() - start, "1", pressure)




def method2(count: int = 200, solid_fraction: float = 0.36, pressure: float = 0.01, law: ContactLaw | None = None,
            speed: float | None = None, seed: int = 0, diameter: float = 1.0, max_time: float = 4000.0,
            max_strain_rate: float = 1e-3, accelerated: bool = False, soft_kappa: float = 100.0,
            cell_mass_disks: int | None = None, dt_safety: float = GILABERT_DT_SAFETY,
            cell_mass_reading: str = "mass",
            on_stage: Callable[[str, Simulation], None] | None = None,
            progress: Callable[[str], None] | None = None, backend: str = "cpu") -> Prepared:
    """Gilabert Sec. III B, for cohesive laws.

    1. A gas at ``solid_fraction`` with Maxwellian velocities of mean quadratic velocity ``speed``
       (default ``V* = sqrt(F0 D0)``, Gilabert Eq. 7) aggregates in a cell of fixed size until
       it forms one cluster with balanced forces and moments (a compact aggregate may still
       spin as a rigid body, which nothing damps: the kinetic criterion waits for stage 2);
    2. it relaxes at ``P* = 0`` with the cell free (stress control to zero) until forces, moments
       and stress balance;
    3. it is compressed to ``pressure`` under the strain-rate cap ``max_strain_rate``.

    ``accelerated`` (series B): aggregate with soft contacts ``kappa = soft_kappa`` and then
    stiffen them slowly to the law's ``kappa`` before stage 2. ``max_time`` bounds each stage.
    The cell's generalized mass is that of a sample of ``cell_mass_disks`` disks by ``cell_mass_reading``
    (:func:`cell_mass`).
    ``on_stage(name, sim)`` is called at the end of each stage (``aggregation``, ``relaxation``:
    the packing at ``P* = 0`` of Gilabert Table IV, ``compression``); ``progress(line)``, if given,
    gets a line on the state about once a second. The steps run on ``backend``.
    """
    start = time.perf_counter()
    law = law or gilabert_law(pressure=pressure, diameter=diameter)
    if law.cohesion_force <= 0:
        raise ParameterError("cohesion_force", law.cohesion_force, "a cohesive law (F0 > 0) for method 2")
    r, positions, length = gilabert_gas(count, solid_fraction, seed, diameter)
    rng = np.random.default_rng(seed + 7)
    speed = math.sqrt(law.cohesion_force * law.cohesion_range) if speed is None else speed
    velocity = rng.normal(0.0, speed / math.sqrt(2.0), size=(count, 2))
    mass = r ** 2
    velocity -= (mass[:, None] * velocity).sum(axis=0) / mass.sum()
    particles = ParticleState(positions, r, velocity=velocity, density=4.0 / math.pi / diameter ** 2)
    target_kn = law.normal_stiffness
    first_law = law.replace(normal_stiffness=soft_kappa * law.cohesion_force / diameter,
                            tangential_stiffness=soft_kappa * law.cohesion_force / diameter) if accelerated else law
    cell = PeriodicCell((length, length), control=("fixed", "fixed"),
                        mass=cell_mass(r, length, diameter, cell_mass_disks, cell_mass_reading))
    sim = Simulation(particles, first_law, Integration(dt_safety=dt_safety), cell=cell)
    sim.use_backend(backend)
    sim_time = 0.0
    # stage 1: aggregation at fixed size, until one cluster in equilibrium
    check = max(sim.dt, 1.0)
    stage_start = time.perf_counter()
    reporter = None if progress is None else Progress(progress, 0.0, "aggregating")
    while sim.time < max_time:
        advance(sim, int(round(check / sim.dt)), reporter)
        if clusters(*columns(sim)) == 1:
            report = equilibrium(sim, measured_pressure(sim))
            if report.force < 1.0 and report.moment < 1.0:
                break
    stages = {"aggregation": (sim.time, time.perf_counter() - stage_start)}
    if accelerated:
        if reporter is not None:
            reporter.stage = "stiffening"
        _stiffen(sim, target_kn, law, reporter)
    sim_time += sim.time
    if on_stage is not None:
        on_stage("aggregation", sim)
    # stage 2: relaxation with the cell free at zero stress
    sim.set_cell_stress(0.0, max_strain_rate)
    if reporter is not None:
        reporter.stage = "relaxing"
    relaxation = relax(sim, 0.0, max_time, kinetic=False, progress=reporter)
    stages["relaxation"] = (relaxation.sim_time, relaxation.wall_time_s)
    sim_time += relaxation.sim_time
    if on_stage is not None:
        on_stage("relaxation", sim)
    # stage 3: compression to the target pressure
    sim.set_cell_stress(pressure, max_strain_rate)
    if reporter is not None:
        reporter.stage, reporter.pressure = "compressing", pressure
    relaxation = relax(sim, pressure, max_time, progress=reporter)
    stages["compression"] = (relaxation.sim_time, relaxation.wall_time_s)
    sim_time += relaxation.sim_time
    if on_stage is not None:
        on_stage("compression", sim)
    return Prepared(sim, relaxation.report, sim_time, time.perf_counter() - start, "2B" if accelerated else "2",
                    pressure, stages)


def _stiffen(sim: Simulation, target_kn: float, law: ContactLaw, reporter: Progress | None, steps: int = 20) -> None:
    """Raise K_N and K_T geometrically to ``target_kn`` in ``steps`` stages, relaxing after each."""
    factor = (target_kn / sim.law.normal_stiffness) ** (1.0 / steps)
    for _ in range(steps):
        kn = min(target_kn, sim.law.normal_stiffness * factor)
        sim.set_law(normal_stiffness=kn, tangential_stiffness=kn * law.tangential_stiffness / law.normal_stiffness)
        advance(sim, int(round(20.0 * math.sqrt(float(sim.particles.mass.min()) / kn) * 2.0 * math.pi / sim.dt)),
                reporter)
    sim.set_law(**{k: getattr(law, k) for k in ("normal_stiffness", "tangential_stiffness")})
