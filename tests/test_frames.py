"""Scene frames from the engine's arrays, checked against a hand-built configuration."""

import numpy as np

from granlab.app.media.drawing import LABEL_SIZE, frame_bounds
from granlab.engine.frames import FrameData, build_frame
from granlab.engine.state import STATUS_COHESIVE, STATUS_NONE, STATUS_SLIDE_NEG, STATUS_STICK


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
    # the watched pairs, in table order, each with its place in the watch list (its colour)
    np.testing.assert_allclose(frame.watched, frame.contacts[[1, 4]])
    assert frame.watched_index.tolist() == [0, 1]
    reordered = build_frame([(data, (0.0, 0.0))], [[(0, 3), (1, 2)]])
    assert reordered.watched_index.tolist() == [1, 0]


def test_parts_side_by_side_are_shifted_and_watched_separately():
    data = three_disks_on_a_floor()
    frame = build_frame([(data, (0.0, 0.0)), (data, (10.0, 0.0))], [[(0, 1)], []])
    assert frame.positions.shape == (6, 2)
    np.testing.assert_allclose(frame.positions[3:], data.positions + [10.0, 0.0])
    np.testing.assert_allclose(frame.watched, [frame.contacts[0]])
    assert build_frame([(data, (0.0, 0.0))], [[(2, 0)]]).watched.shape == (0, 2, 2)  # pairs are ordered i < j


def test_groups_of_disks_are_named_under_them_and_inside_the_frame_bounds():
    data = three_disks_on_a_floor()
    frame = build_frame([(data, (0.0, 0.0)), (data, (10.0, 0.0))], groups=[("first", 3), ("second", 3)])
    # centred under each group's disks (x from -1 to 5, shifted by 10), half a radius below the lowest
    assert frame.labels == (("first", 2.0, -0.5), ("second", 12.0, -0.5))
    xmin, xmax, ymin, _ = frame_bounds(frame)
    assert ymin < -0.5 - LABEL_SIZE and xmin <= -1.0 and xmax >= 15.0
    assert build_frame([(data, (0.0, 0.0))]).labels == ()


def test_frame_from_a_live_simulation_matches_its_snapshot():
    """The lean copy the engine thread takes gives the frame a full snapshot gives, and the
    frame's contact segments have the lengths the contact table implies (r_i + r_j + gap for
    a pair, r_i + gap to a wall)."""
    from granlab.engine.protocols.presets import make_preset, preset_settings

    preset = make_preset("ratchet16", preset_settings("ratchet16"))
    while preset.sim.time < 12.0:  # past the compression ramp: a packed box
        preset.advance(5000)
    sim = preset.sim
    snap = sim.snapshot()
    c = snap.contacts
    assert c.count > 10
    from_snapshot = FrameData(snap.positions, snap.radii, snap.angles, np.column_stack([c.i, c.j]), c.image, c.status,
                              c.normal_force, c.tangential_force, c.surface_gap, snap.wall_normals,
                              snap.wall_offsets, np.zeros(2))
    lean = FrameData.from_simulation(sim)
    a, b = build_frame([(from_snapshot, (0.0, 0.0))]), build_frame([(lean, (0.0, 0.0))])
    for name in ("positions", "coordination", "pressure", "sliding", "contacts", "contact_force", "contact_kind",
                 "walls"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    n = len(snap.radii)
    partner = np.where(c.j < n, snap.radii[np.minimum(c.j, n - 1)], 0.0)
    length = np.linalg.norm(b.contacts[:, 1] - b.contacts[:, 0], axis=1)
    np.testing.assert_allclose(length, snap.radii[c.i] + partner + c.surface_gap, rtol=1e-9)
    from granlab.engine.kernels.fields import contact_fields
    assert len(contact_fields.signatures) == 1  # hand-built, snapshot and live arrays: one compilation
