"""Boundaries: walls (fixed, moving, force-controlled), periodic cell control, gravity, prescribed motion."""

import math

import numpy as np
import pytest

from granlab.engine import ContactLaw, Load, ParameterError, ParticleState, PeriodicCell, Simulation, Wall, box_walls
from granlab.engine.generate import radii, random_gas, square_lattice


def test_force_controlled_wall_balances_pressure_times_length():
    # ratcheting Eq. 1: F_y = L_x P0 on the top wall of a biaxial box
    positions = square_lattice(6, 6, 1.0, origin=(0.5, 0.5))
    r = radii(36, radius_min=0.35, radius_max=0.5, distribution="uniform", seed=3)
    pressure = 50.0
    walls = box_walls(0.0, 6.0, 0.0, 6.2, loads={"top": Load(base=pressure)}, wall_mass=5.0)
    law = ContactLaw(normal_stiffness=1e4, tangential_stiffness=1e4, friction=0.3, damping_ratio=0.7)
    sim = Simulation(ParticleState(positions, r), law, walls=walls)
    sim.run_for(40.0)
    top = sim.wall_index("top")
    length_x = 6.0
    assert sim.walls.particle_force[top] == pytest.approx(-pressure * length_x, rel=1e-4)
    assert abs(sim.walls.velocity[top]) < 1e-5
    # the fixed bottom wall carries the same load
    assert sim.walls.particle_force[sim.wall_index("bottom")] == pytest.approx(-pressure * length_x, rel=1e-4)


def test_periodic_cell_reaches_the_imposed_stress():
    # Gilabert Eq. 3: the cell lengths move until sigma^M = sigma^I on both axes
    r = radii(100, radius_min=0.25, radius_max=0.5, distribution="uniform", seed=1)
    length = 16.0
    positions = random_gas(r, (0, length, 0, length), periodic=(True, True), seed=1)
    law = ContactLaw(normal_stiffness=1e3, tangential_stiffness=1e3, friction=0.3, damping_ratio=0.7)
    cell = PeriodicCell((length, length), control=("stress", "stress"), stress=(1.0, 2.0), max_strain_rate=0.05)
    sim = Simulation(ParticleState(positions, r), law, cell=cell)
    sim.run_for(80.0)  # the transient is chaotic: at 60 one scheme or the other may still be settling
    c = sim.cell
    area = c.length[0] * c.length[1]
    for axis, target in enumerate((1.0, 2.0)):
        assert (c.kinetic[axis] + c.virial[axis, axis]) / area == pytest.approx(target, rel=1e-3)
    assert area < 0.4 * length ** 2


def test_strain_rate_cap_limits_the_cell_speed():
    r = radii(50, radius_min=0.25, radius_max=0.5, distribution="uniform", seed=2)
    positions = random_gas(r, (0, 20, 0, 20), periodic=(True, True), seed=2)
    cell = PeriodicCell((20.0, 20.0), control=("stress", "stress"), stress=(5.0, 5.0), max_strain_rate=0.01)
    sim = Simulation(ParticleState(positions, r), ContactLaw(damping_ratio=0.5), cell=cell)
    sim.run_for(10.0)
    assert sim.cell.length[0] == pytest.approx(20.0 * (1 - 0.01 * 10.0), rel=1e-3)


def test_prescribed_strain_rate_shrinks_the_cell_linearly():
    r = np.full(20, 0.3)
    positions = random_gas(r, (0, 10, 0, 10), periodic=(True, True), seed=4)
    cell = PeriodicCell((10.0, 10.0), control=("strain-rate", "fixed"), strain_rate=(0.02, 0.0))
    sim = Simulation(ParticleState(positions, r), ContactLaw(), cell=cell)
    sim.run_for(5.0)
    assert sim.cell.length[0] == pytest.approx(10.0 * (1 - 0.02 * sim.time), rel=1e-12)
    assert sim.cell.length[1] == 10.0


def test_floor_carries_the_weight_of_a_settled_pile():
    # periodic along x (no side walls to hold part of the weight by friction), a floor along y
    r = radii(60, radius_min=0.35, radius_max=0.5, distribution="uniform", seed=6)
    positions = random_gas(r, (0, 8, 0, 20), periodic=(True, False), seed=6)
    law = ContactLaw(normal_stiffness=2e4, tangential_stiffness=2e4, friction=0.5, damping_ratio=0.6)
    sim = Simulation(ParticleState(positions, r), law, walls=(Wall((0.0, 1.0), 0.0, name="bottom"),),
                     cell=PeriodicCell((8.0, 1.0), periodic=(True, False)), gravity=(0.0, -1.0))
    sim.run_for(40.0)
    weight = sim.particles.mass.sum()
    assert -sim.walls.particle_force[sim.wall_index("bottom")] == pytest.approx(weight, rel=1e-3)
    assert sim.energy().kinetic < 1e-6 * weight


def test_velocity_wall_moves_at_its_velocity_and_fixed_wall_stays():
    walls = (Wall((0.0, 1.0), 0.0, mode="velocity", velocity=0.3, name="piston"), Wall((0.0, -1.0), -10.0, name="lid"))
    sim = Simulation(ParticleState([[5.0, 5.0]], [0.5]), ContactLaw(), walls=walls)
    sim.run_for(2.0)
    assert sim.walls.offset[0] == pytest.approx(0.3 * sim.time, rel=1e-12)
    assert sim.walls.offset[1] == -10.0


def test_sliding_floor_drags_a_block_to_its_speed():
    # the surface slides along t = z × n: for a floor (n = +y) a positive speed moves it towards -x
    particles = ParticleState([[0.0, 0.4999]], [0.5], mass=[1.0], inertia=[math.inf])
    floor = Wall((0.0, 1.0), 0.0, tangential_velocity=0.5, name="belt")
    law = ContactLaw(normal_stiffness=1e4, tangential_stiffness=1e4, friction=0.5, damping_ratio=0.5,
                     tangential_damping=100.0)
    sim = Simulation(particles, law, walls=(floor,), gravity=(0.0, -1.0))
    sim.run_for(5.0)
    assert sim.particles.velocity[0, 0] == pytest.approx(-0.5, rel=1e-4)
    # friction accelerated it at mu g while sliding: it needed 0.5 / (0.5 * 1) = 1 time unit
    assert sim.energy().work_walls > 0


def test_kinematic_disk_follows_its_prescribed_motion_and_fixed_disk_stays():
    particles = ParticleState([[0.0, 0.0], [3.0, 0.0], [6.0, 0.0]], [0.5, 0.5, 0.5],
                              velocity=[[1.0, 0.0], [0.0, 0.0], [0.0, 0.0]], kind=["dynamic", "kinematic", "fixed"])
    sim = Simulation(particles, ContactLaw(normal_stiffness=1e3, damping_ratio=0.2))
    sim.set_motion(1, (0.0, 0.2), omega=1.0)
    sim.run_for(5.0)
    assert sim.particles.position[1] == pytest.approx([3.0, 0.2 * sim.time])
    assert sim.particles.angle[1] == pytest.approx(sim.time)
    assert np.array_equal(sim.particles.position[2], [6.0, 0.0])
    with pytest.raises(ParameterError, match="kind of disk 0 = 'dynamic' is not allowed: 'kinematic'"):
        sim.set_motion(0, (1.0, 0.0))


def test_walls_along_periodic_axes_and_unknown_walls_are_refused():
    with pytest.raises(ParameterError, match="no component along periodic axis x"):
        Simulation(ParticleState([[1.0, 1.0]], [0.5]), ContactLaw(), walls=(Wall((1.0, 0.0), 0.0),),
                   cell=PeriodicCell((5.0, 5.0)))
    sim = Simulation(ParticleState([[1.0, 1.0]], [0.5]), ContactLaw(), walls=box_walls(0, 5, 0, 5))
    with pytest.raises(ParameterError, match="wall = 'roof' is not allowed: one of left, right, bottom, top"):
        sim.set_wall_load("roof", Load(base=1.0))
