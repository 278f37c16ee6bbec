"""The observables of a packing, defined once (granlab.engine.observables), against packings whose
counts are known by hand."""

import math

import numpy as np
import pytest

from granlab.engine import observables
from granlab.engine.state import STATUS_COHESIVE, STATUS_NONE, STATUS_SLIDE_NEG, STATUS_SLIDE_POS, STATUS_STICK

from .conftest import periodic_gas

# five disks and a wall (index 5): a triangle 0-1-2 (one contact sliding), disk 3 held by a distant
# cohesive pair with 2, disk 4 alone but for a candidate row, and disk 0 on the wall
STATUS = np.array([STATUS_STICK, STATUS_SLIDE_POS, STATUS_SLIDE_NEG, STATUS_COHESIVE, STATUS_NONE, STATUS_STICK])
I = np.array([0, 1, 0, 2, 3, 0])
J = np.array([1, 2, 2, 3, 4, 5])
N = 5


def test_touching_sliding_and_interacting_rows():
    assert observables.touching(STATUS).tolist() == [True, True, True, False, False, True]
    assert observables.sliding(STATUS).tolist() == [False, True, True, False, False, False]
    assert observables.interacting(STATUS).tolist() == [True, True, True, True, False, True]


def test_coordination_counts_disk_pairs_only_and_distant_pairs_on_request():
    assert observables.coordination(STATUS, I, J, N) == 2 * 3 / 5  # the wall contact is not a pair
    assert observables.coordination(STATUS, I, J, N, distant=True) == 2 * 4 / 5


def test_backbone_rattlers_and_z_star():
    with_disks, with_walls = observables.disk_contacts(observables.touching(STATUS), I, J, N)
    assert with_disks.tolist() == [2, 2, 2, 0, 0] and with_walls.tolist() == [1, 0, 0, 0, 0]
    z, z_star, rattlers = observables.backbone(with_disks, with_walls)
    assert (z, z_star, rattlers) == (6 / 5, 6 / 3, 2)
    assert observables.backbone(*observables.disk_contacts(np.zeros(6, dtype=bool), I, J, N)) == (0.0, 0.0, 5)


def test_clusters_join_touching_and_distant_cohesive_pairs():
    assert observables.clusters(STATUS, I, J, N) == 2  # {0, 1, 2, 3} and {4}
    assert observables.clusters(np.full(6, STATUS_NONE), I, J, N) == 5


def test_solid_fraction_of_the_box_or_a_given_area():
    radii = np.array([1.0, 2.0])
    assert observables.solid_fraction(radii, (5.0, 4.0)) == pytest.approx(5 * math.pi / 20)
    assert observables.solid_fraction(radii, area=10 * math.pi) == pytest.approx(0.5)


def test_a_running_simulation_is_measured_from_its_table_as_the_engine_reads_it():
    """A dense frictional gas after some collisions: the touching rows are those that overlap, and
    z, the clusters and Φ agree with counts made from the engine's own contact snapshot."""
    sim = periodic_gas(count=200, length=18.0, seed=3, speed=0.5)
    sim.run(400)
    status, i, j, n = observables.columns(sim)
    assert n == 200 and len(status) == len(i) == len(j) == sim.contacts.count
    snapshot = sim.contact_snapshot()
    overlapping = snapshot.surface_gap < 0
    assert 0 < int(observables.touching(status).sum()) == int(overlapping.sum())
    assert observables.coordination(status, i, j, n) == 2 * int(np.count_nonzero(overlapping & (snapshot.j < n))) / n
    assert observables.solid_fraction(sim.particles.radius, sim.box_lengths()) == pytest.approx(
        math.pi * float(np.sum(sim.particles.radius ** 2)) / 18.0 ** 2)
    assert 1 <= observables.clusters(status, i, j, n) < n
