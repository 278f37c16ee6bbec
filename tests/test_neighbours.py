"""The cell-list neighbour table against brute force, periodic images and walls included."""

import itertools

import numpy as np
import pytest

from granlab.engine import ContactLaw, Integration, ParticleState, PeriodicCell, Simulation, Wall
from granlab.engine.generate import radii, random_gas


def brute_force_pairs(position, radius, lengths, periodic, extra):
    """Every (i, j, image) with i < j and |x_i - x_j - image L| < r_i + r_j + extra (images up to ±2)."""
    pairs = set()
    shifts = [range(-2, 3) if periodic[a] else range(0, 1) for a in range(2)]
    for i, j in itertools.combinations(range(len(radius)), 2):
        for sx, sy in itertools.product(*shifts):
            r = position[i] - position[j] - np.array([sx * lengths[0], sy * lengths[1]])
            if np.hypot(*r) < radius[i] + radius[j] + extra:
                pairs.add((i, j, sx, sy))
    return pairs


def table_pairs(sim):
    t = sim.contacts
    n = sim.particles.count
    rows = range(t.count)
    return {(int(t.particle_i[k]), int(t.particle_j[k]), int(t.image[k, 0]), int(t.image[k, 1]))
            for k in rows if t.particle_j[k] < n}


@pytest.mark.parametrize("length,count,seed", [(12.0, 150, 1), (3.1, 6, 2), (1.9, 2, 3)])
def test_periodic_table_equals_brute_force(length, count, seed):
    r = radii(count, radius_min=0.3, radius_max=0.45, distribution="uniform", seed=seed)
    positions = random_gas(r, (0, length, 0, length), periodic=(True, True), seed=seed)
    skin = 0.3
    sim = Simulation(ParticleState(positions, r), ContactLaw(cohesion_force=1.0, cohesion_range=0.05),
                     Integration(skin=skin), cell=PeriodicCell((length, length)))
    expected = brute_force_pairs(sim.particles.position, r, (length, length), (True, True), 0.05 + skin)
    found = table_pairs(sim)
    assert found == expected
    assert len(found) > 0


def test_small_cell_keeps_two_images_of_the_same_pair():
    # two disks in a cell barely wider than their diameter touch through two images
    length = 2.05
    sim = Simulation(ParticleState([[0.5, 0.5], [1.5, 0.5]], [0.5, 0.5]), ContactLaw(),
                     Integration(skin=0.1), cell=PeriodicCell((length, 5.0)))
    images = {(sx, sy) for (_, _, sx, sy) in table_pairs(sim)}
    assert images == {(0, 0), (-1, 0)}  # r = x_i - x_j - image L = -1.0 and +1.05


def test_open_box_with_walls_equals_brute_force():
    r = radii(80, radius_min=0.3, radius_max=0.5, distribution="uniform", seed=4)
    positions = random_gas(r, (0, 10, 0, 10), seed=4)
    walls = (Wall((0.0, 1.0), 0.0, name="floor"), Wall((1.0, 0.0), 0.0, name="left"),
             Wall((-1.0, 0.0), -10.0, name="right"))
    sim = Simulation(ParticleState(positions, r), ContactLaw(), Integration(skin=0.25), walls=walls)
    assert table_pairs(sim) == brute_force_pairs(positions, r, (0, 0), (False, False), 0.25)
    t = sim.contacts
    n = sim.particles.count
    wall_rows = {(int(t.particle_i[k]), int(t.particle_j[k]) - n) for k in range(t.count) if t.particle_j[k] >= n}
    expected = set()
    for i in range(n):
        for w, wall in enumerate(walls):
            if np.dot(wall.normal, positions[i]) - wall.position - r[i] < 0.25:
                expected.add((i, w))
    assert wall_rows == expected


def test_table_grows_instead_of_dropping_contacts():
    # a dense lattice needs more rows than the initial capacity of 8 N + 64 when the skin is large
    side = 12
    x, y = np.meshgrid(np.arange(side) * 1.0, np.arange(side) * 1.0)
    positions = np.column_stack([x.ravel(), y.ravel()])
    sim = Simulation(ParticleState(positions, 0.5), ContactLaw(), Integration(skin=2.6),
                     cell=PeriodicCell((side * 1.0, side * 1.0)))
    assert sim.contacts.count > 8 * positions.shape[0] + 64
    assert sim.contacts.capacity >= sim.contacts.count
    expected = brute_force_pairs(sim.particles.position, np.full(side * side, 0.5), (side, side), (True, True), 2.6)
    assert table_pairs(sim) == expected


def test_each_chunk_reads_its_force_buffer_only_between_the_disks_its_rows_touch():
    """The pass over the disks reads and zeroes chunk c's buffer between ``touched[c]`` only: those are the
    lowest and highest disk of its rows (brute force over the table), and after a contact pass its buffer
    holds nothing outside them. 1200 disks of a dense gas in two chunks, with walls: their rows touch one disk."""
    import numba

    from granlab.engine.kernels.contacts import CONTACT_FORCES

    numba.set_num_threads(2)
    count = 1200
    r = radii(count, radius_min=0.4, radius_max=0.6, distribution="uniform", seed=3)
    positions = random_gas(r, (0.0, 40.0, 0.0, 40.0), periodic=(True, False), seed=3)
    walls = (Wall((0.0, 1.0), 0.0, name="floor"), Wall((0.0, -1.0), -40.0, name="ceiling"))
    sim = Simulation(ParticleState(positions, r, velocity=np.random.default_rng(3).normal(0.0, 1.0, (count, 2))),
                     ContactLaw(normal_stiffness=1e3, tangential_stiffness=500.0, friction=0.3),
                     Integration(dt_safety=0.1), walls=walls, cell=PeriodicCell((40.0, 40.0), periodic=(True, False)),
                     gravity=(0.0, -1.0))
    sim.run(300)
    run = sim.run_options(sim.dt, 1)
    assert run.n_chunks == 2
    table, ws = sim.contacts, sim.workspace
    rows = table.count
    for c in range(2):
        lo, hi = c * rows // 2, (c + 1) * rows // 2
        i, j = table.particle_i[lo:hi], table.particle_j[lo:hi]
        disks = np.concatenate([i, j[j < count]])
        assert tuple(ws.touched[c]) == (disks.min(), disks.max())
    assert (table.particle_j[:rows] >= count).any()  # wall rows among them
    CONTACT_FORCES[sim.tangential_model_code](sim.particles.arrays(), sim.walls.arrays(), sim.cell.arrays(),
                                              table.arrays(), ws, sim._law_vector, run, False, True)
    for c in range(2):
        outside = np.ones(count, bool)
        outside[int(ws.touched[c, 0]):int(ws.touched[c, 1]) + 1] = False
        assert ws.force_buffer[c][outside].any(axis=1).sum() == 0
        assert ws.force_buffer[c][~outside].any(axis=1).sum() > 0
