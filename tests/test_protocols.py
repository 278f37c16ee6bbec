"""Preparation protocols reach Gilabert's equilibrium; cyclic loading reproduces the ratcheting paper."""

import math

import numpy as np
import pytest

from granlab.engine import ContactLaw, ParameterError, ParticleState, PeriodicCell, Simulation, box_walls
from granlab.engine.analysis.ratchet import deviatoric_strain, ratchet_verdict
from granlab.engine.protocols.cyclic import CyclicLoad, apply_load, run_cycles, steps_per_cycle
from granlab.engine.observables import clusters, columns
from granlab.engine.protocols.equilibrium import equilibrium, measured_pressure
from granlab.engine.protocols.prepare import (cell_mass, compress, gilabert_gas, gilabert_law, gilabert_radii, method1,
                                               method2)


@pytest.fixture(scope="module")
def box16():
    return compress(16, seed=0, friction=0.2)


def test_compress_reaches_equilibrium_at_the_imposed_pressure(box16):
    report = box16.report
    assert box16.equilibrated
    assert max(report.force, report.moment, report.pressure, report.kinetic) < 1.0
    sim = box16.sim
    lx, ly = sim.box_lengths()
    # ratcheting Eq. 1 with q = 0: F_x = P0 L_y, F_y = P0 L_x
    assert -sim.walls.particle_force[sim.wall_index("right")] == pytest.approx(ly, rel=1e-3)
    assert -sim.walls.particle_force[sim.wall_index("top")] == pytest.approx(lx, rel=1e-3)
    assert sim.law.friction == 0.2 and sim.law.normal_stiffness == 100.0


def test_equilibrium_test_rejects_a_moving_packing(box16):
    sim = box16.sim.clone()
    sim.particles.velocity[3] = (0.05, 0.0)
    report = equilibrium(sim, 1.0)
    assert not report.equilibrated and report.kinetic > 1.0


@pytest.mark.parametrize("cohesion, rolling", [(False, False), (True, False), (True, True)])
def test_method1_reaches_equilibrium_under_stress_control(cohesion, rolling):
    # with rolling resistance, the rolling dashpot stops the disks that hang by one contact
    pressure = 0.01
    law = gilabert_law(cohesion=cohesion, rolling=rolling, pressure=pressure, rolling_damping_ratio=0.8)
    prepared = method1(60, pressure=pressure, law=law, max_time=1500)
    assert prepared.equilibrated
    assert measured_pressure(prepared.sim) == pytest.approx(pressure, abs=1e-4 * prepared.report.force_scale)
    phi = np.pi * np.sum(prepared.sim.particles.radius ** 2) / np.prod(prepared.sim.cell.length)
    assert 0.6 < phi < 0.9


def test_cell_mass_reads_gilabert_either_way_and_borrows_the_size_of_a_larger_sample():
    # Gilabert Sec. II A: M = 3/10 of the grain mass (a mass, as Eq. 3 needs in 2D), or that over L
    # (the paper's words), the engine's default cell mass; a sample borrows the M of a larger one
    r, positions, length = gilabert_gas(50, 0.36, 3, 1.0)
    sim = Simulation(ParticleState(positions, r, density=4.0 / np.pi), gilabert_law(),
                     cell=PeriodicCell((length, length)))
    grain_mass = float(sim.particles.mass.sum())
    assert cell_mass(r, length) == pytest.approx(0.3 * grain_mass, rel=1e-12)
    assert cell_mass(r, length, disks=200) == pytest.approx(4.0 * 0.3 * grain_mass, rel=1e-12)
    assert cell_mass(r, length, reading="per-length") == pytest.approx(sim.cell.mass[0], rel=1e-12)
    assert cell_mass(r, length, disks=200, reading="per-length") == pytest.approx(2.0 * sim.cell.mass[0], rel=1e-12)
    prepared = method1(50, law=gilabert_law(), seed=3, max_time=1.0, cell_mass_disks=200,
                       cell_mass_reading="per-length")
    assert prepared.sim.cell.mass[0] == pytest.approx(2.0 * sim.cell.mass[0], rel=1e-12)
    with pytest.raises(ParameterError, match="cell_mass = 'per-area' is not allowed: one of mass, per-length"):
        cell_mass(r, length, reading="per-area")


def test_gilabert_gas_numbers_the_disks_in_strips_so_that_threads_share_few_neighbours():
    # the engine's two threads take the first and the second half of the disks' numbers: in strips,
    # few pairs of neighbours straddle the halves (numbered at random, half of them would)
    r, positions, length = gilabert_gas(1400, 0.36, 1, 1.0)
    assert np.array_equal(np.sort(r), np.sort(gilabert_radii(1400, 1.0, 1)))
    sim = Simulation(ParticleState(positions, r, density=4.0 / np.pi), gilabert_law(),
                     cell=PeriodicCell((length, length)))
    table = sim.contacts
    first_half = np.arange(1400) < 700
    straddling = np.mean(first_half[table.particle_i[:table.count]] != first_half[table.particle_j[:table.count]])
    assert 0 < straddling < 0.1
    y = positions[:, 1]
    assert np.median(y[:700]) < 0.3 * length < 0.7 * length < np.median(y[700:])


def test_method2_aggregates_into_one_cluster_in_equilibrium():
    law = gilabert_law(cohesion=True, pressure=0.01, kappa=1e4)
    prepared = method2(20, pressure=0.01, law=law, accelerated=True, max_time=2000)
    assert prepared.equilibrated
    assert clusters(*columns(prepared.sim)) == 1
    assert prepared.sim.law.normal_stiffness == law.normal_stiffness
    with pytest.raises(ParameterError, match="cohesive law"):
        method2(10, law=gilabert_law(cohesion=False))


def test_cyclic_load_is_ratcheting_eq1_and_cycles_are_whole_steps(box16):
    sim = box16.sim.clone()
    load = CyclicLoad(pressure=1.0, amplitude=0.2, period=10.0)
    start = apply_load(sim, load)
    steps = steps_per_cycle(sim, load)
    assert steps * sim.dt == pytest.approx(10.0, rel=1e-12)
    from granlab.engine.kernels.integrate import wall_load
    top = sim.wall_index("top")
    lx = sim.box_lengths()[0]
    w = sim.walls.arrays()
    assert wall_load(w, top, start) == pytest.approx(lx * 1.0)
    assert wall_load(w, top, start + 5.0) == pytest.approx(lx * (1.0 + 0.4))
    assert wall_load(w, sim.wall_index("right"), start + 5.0) == pytest.approx(sim.box_lengths()[1])
    series = run_cycles(sim, load, 3)
    assert series.cycle == [0, 1, 2, 3]
    assert series.time[-1] - series.time[0] == pytest.approx(30.0, rel=1e-12)


def test_a_zero_mean_load_cycles_about_p0_least_at_each_cycle_start(box16):
    sim = box16.sim.clone()
    load = CyclicLoad(pressure=1.0, amplitude=0.15, period=10.0, zero_mean=True)
    start = apply_load(sim, load)
    from granlab.engine.kernels.integrate import wall_load
    top, right = sim.wall_index("top"), sim.wall_index("right")
    lx, ly = sim.box_lengths()
    w = sim.walls.arrays()
    times = start + np.linspace(0.0, 10.0, 400, endpoint=False)
    top_load = np.array([wall_load(w, top, t) for t in times]) / lx
    assert top_load.mean() == pytest.approx(1.0, abs=1e-12)  # Eq. 1's mean would be 1.15
    assert top_load.min() == pytest.approx(top_load[0]) == pytest.approx(0.85)
    assert top_load.max() == pytest.approx(1.15, rel=1e-3)
    assert wall_load(w, right, start + 2.5) == pytest.approx(ly)
    assert [load.q(t) for t in (0.0, 5.0)] == pytest.approx([-0.15, 0.15])
    with pytest.raises(ParameterError, match="amplitude = 1.2 is not allowed: below the pressure P0 = 1"):
        CyclicLoad(pressure=1.0, amplitude=1.2, zero_mean=True)


def _dgamma(base, model, dt_factor=0.2, cycles=40, reference=10, **load):
    sim = base.clone(tangential_model=model)
    sim.set_dt(dt_factor * math.sqrt(sim.particles.mass.min() / sim.law.normal_stiffness))
    series = run_cycles(sim, CyclicLoad(1.0, 0.2, 10.0, **load), cycles)
    cycles, lx, ly = series.arrays()
    gamma = deviatoric_strain(lx[reference:], ly[reference:], lx[reference], ly[reference])
    return ratchet_verdict(cycles[reference:], gamma)


def test_cundall_strack_ratchets_and_the_angle_spring_does_not(box16):
    cs = _dgamma(box16.sim, "cundall-strack")
    angle = _dgamma(box16.sim, "angle")
    assert cs.ratcheting and abs(cs.dgamma) > 1e-9
    assert not angle.ratcheting and abs(angle.dgamma) < 1e-6 * abs(cs.dgamma)


def test_alpha_residue_scales_with_dt_and_cundall_strack_does_not(box16):
    # ratcheting Fig. 14
    cs = [_dgamma(box16.sim, "cundall-strack", f).dgamma for f in (0.2, 0.1)]
    alpha = [_dgamma(box16.sim, "alpha", f).dgamma for f in (0.2, 0.1)]
    assert cs[1] == pytest.approx(cs[0], rel=0.02)
    assert alpha[1] == pytest.approx(alpha[0] / 2, rel=0.05)
    assert abs(alpha[0]) < 0.1 * abs(cs[0])


def test_elliptic_loading_without_sliding_gives_dgamma_proportional_to_sin_phi():
    # ratcheting Eqs. 4-5, Fig. 5 (mu = inf)
    base = compress(16, seed=0, friction=math.inf).sim
    values = {deg: _dgamma(base, "cundall-strack", cycles=15, reference=5, phase=math.radians(deg)).dgamma
              for deg in (-90, 30, 90)}
    # this packing gives 1.005, for 15 cycles as for 30: the sample's own asymmetry, not a transient
    # (the one compressed at P0 at once under walls as heavy as the packing: 1.022)
    assert values[90] == pytest.approx(-values[-90], rel=0.03)
    assert values[30] == pytest.approx(0.5 * values[90], rel=0.05)
    assert abs(values[90]) > 1e-7


def test_cyclic_loading_needs_a_biaxial_box_and_whole_cycles():
    sim = Simulation(ParticleState([[1.0, 1.0]], [0.5]), ContactLaw(), walls=box_walls(0, 3, 0, 3))
    with pytest.raises(ParameterError, match="cycles = 0 is not allowed"):
        run_cycles(sim, CyclicLoad(), 0)
    free = Simulation(ParticleState([[1.0, 1.0]], [0.5]), ContactLaw())
    with pytest.raises(ParameterError, match="walls named right and top"):
        run_cycles(free, CyclicLoad(), 2)
