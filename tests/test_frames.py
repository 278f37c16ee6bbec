"""Scene frames from the engine's arrays, checked against a hand-built configuration."""

import numpy as np

from app.frames import FrameData, build_frame
from engine.state import STATUS_COHESIVE, STATUS_NONE, STATUS_SLIDE_NEG, STATUS_STICK


def three_disks_on_a_floor():
    """Disks 0 and 1 touch (stick), 1 and 2 slide, 0 and 2 are a candidate pair, 2 is attracted
    to the floor (wall 0: the line y = 0, normal +y) across a gap, 0 rests on it."""
    positions = np.array([[0.0, 1.0], [2.0, 1.0], [4.0, 1.2]])
    pair = np.array([[0, 1], [1, 2], [0, 2], [2, 3], [0, 3]])
    status = np.array([STATUS_STICK, STATUS_SLIDE_NEG, STATUS_NONE, STATUS_COHESIVE, STATUS_STICK])
    normal = np.array([3.0, 4.0, 0.0, -0.5, 2.0])
    tangential = np.array([0.0, -3.0, 0.0, 0.0, 1.0])
    gap = np.array([0.0, 0.0, 1.0, 0.2, -0.01])
    return FrameData(positions, np.ones(3), np.array([0.1, 0.2, 0.3]), pair, np.zeros((5, 2)), status, normal,
                     tangential, gap, np.array([[0.0, 1.0]]), np.array([0.0]), np.zeros(2))


def test_fields_per_disk_and_per_contact():
    data = three_disks_on_a_floor()
    frame = build_frame([(data, (0.0, 0.0))], [[(1, 2), (0, 3)]])
    # touching contacts: 0-1, 1-2, 0-floor; the wall contact counts for the disk only
    assert frame.coordination.tolist() == [2, 2, 1]
    assert frame.sliding.tolist() == [False, True, True]
    # pressure: sum of |F_n| over the disk's interactions / its perimeter
    np.testing.assert_allclose(frame.pressure, np.array([3 + 2, 3 + 4, 4 + 0.5]) / (2 * np.pi))
    assert frame.contact_kind.tolist() == [0, 2, 0, 1, 0]  # compressive, sliding, tensile/cohesive
    np.testing.assert_allclose(frame.contact_force, np.hypot(data.normal_force, data.tangential_force))
    # a segment runs from the centre to the partner, or to the wall (radius + gap below)
    np.testing.assert_allclose(frame.contacts[1], [[2.0, 1.0], [4.0, 1.2]])
    np.testing.assert_allclose(frame.contacts[3], [[4.0, 1.2], [4.0, 0.0]])
    np.testing.assert_allclose(frame.contacts[4], [[0.0, 1.0], [0.0, 0.01]])
    # the watched pairs, in table order
    np.testing.assert_allclose(frame.watched, frame.contacts[[1, 4]])


def test_parts_side_by_side_are_shifted_and_watched_separately():
    data = three_disks_on_a_floor()
    frame = build_frame([(data, (0.0, 0.0)), (data, (10.0, 0.0))], [[(0, 1)], []])
    assert frame.positions.shape == (6, 2)
    np.testing.assert_allclose(frame.positions[3:], data.positions + [10.0, 0.0])
    np.testing.assert_allclose(frame.watched, [frame.contacts[0]])
    assert build_frame([(data, (0.0, 0.0))], [[(2, 0)]]).watched.shape == (0, 2, 2)  # pairs are ordered i < j
