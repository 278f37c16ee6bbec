"""The viewers' stream (app/lab/stream.py): what a page holds after applying its messages, as
``static/viewer/scene.html`` applies them, is the frame the scene drew, to the quantum of its box."""

import numpy as np
import pytest

from granlab.app.lab.stream import Encoder, unpack
from granlab.app.media.drawing import FORCE_CLASSES, color_index, force_classes
from granlab.engine.frames import FrameData, build_frame
from granlab.engine.protocols.presets import make_preset, preset_settings


class Page:
    """A viewer's page as scene.html keeps it: the arrays of the last frame applied."""

    def __init__(self):
        self.seq = -1
        self.header = None
        self.a: dict[str, np.ndarray] = {}
        self.arrows = np.zeros((0, 2, 2), dtype=np.float32)

    def apply(self, message: bytes) -> None:
        header, parts = unpack(message)
        if header["key"]:
            self.a = {name: parts[name][0].copy() for name in ("pos", "angle", "color", "radius", "ci", "cj", "cls",
                                                               "far")}
            self.arrows = parts["arrows"][0].reshape(-1, 2, 2)
        else:
            if header["seq"] <= self.seq:
                return
            assert header["seq"] == self.seq + 1, "a message missed"
            if "arrows" in parts:
                self.arrows = parts["arrows"][0].reshape(-1, 2, 2)
            for name in ("pos", "angle", "color"):
                self.a[name] = self.a[name] + parts[name][0]
            if "radius" in parts:
                self.a["radius"] = parts["radius"][0].copy()
            if "gone" in parts:
                kept = np.ones(len(self.a["ci"]), dtype=bool)
                kept[parts["gone"][0]] = False
                added = len(parts["ci"][0])
                for name in ("ci", "cj"):
                    self.a[name] = np.concatenate([self.a[name][kept], parts[name][0]])
                self.a["cls"] = np.concatenate([self.a["cls"][kept], np.zeros(added, dtype=np.uint8)])
                self.a["far"] = np.concatenate([self.a["far"].reshape(-1, 2)[kept].ravel(),
                                                np.zeros(2 * added, dtype=np.uint16)])
            elif "ci" in parts:
                for name in ("ci", "cj", "cls", "far"):
                    self.a[name] = parts[name][0].copy()
            if parts["cls"][1] == "delta":
                self.a["cls"] = self.a["cls"] + parts["cls"][0]
                self.a["far"] = self.a["far"] + parts["far"][0]
        self.seq = header["seq"]
        self.header = header

    def positions(self) -> np.ndarray:
        x0, y0, sx, sy = self.header["box"]
        x, y = self.a["pos"].reshape(2, -1)
        return np.column_stack([x0 + sx * x, y0 + sy * y])

    def contacts(self) -> dict:
        """(i, j) -> (class byte, wall point or None)."""
        x0, y0, sx, sy = self.header["box"]
        far = self.a["far"].reshape(-1, 2)
        return {(int(i), int(j)): (int(c), None if j >= 0 else (x0 + sx * f[0], y0 + sy * f[1]))
                for i, j, c, f in zip(self.a["ci"], self.a["cj"], self.a["cls"], far)}


def assert_shows(page: Page, frame, field: str) -> None:
    box = page.header["box"]
    assert page.header["n"] == len(frame.radii)
    assert np.all(np.abs(page.positions() - frame.positions).max(axis=0) <= np.array(box[2:]) * 0.5 + 1e-12)
    assert np.array_equal(page.a["radius"], frame.radii.astype(np.float32))
    wanted_angle = np.floor(np.mod(frame.angles, 2 * np.pi) * 256 / (2 * np.pi)).astype(int) % 256
    assert np.array_equal(page.a["angle"], wanted_angle)
    index = np.zeros(len(frame.radii), dtype=np.intp)
    color_index(frame, field, index, np.zeros(len(frame.radii)))
    assert np.array_equal(page.a["color"], index)
    classes = force_classes(frame.contact_force) + FORCE_CLASSES * frame.contact_kind
    shown = page.contacts()
    assert len(shown) == len(frame.ends)
    for (i, j), klass, segment in zip(frame.ends, classes, frame.contacts):
        byte, point = shown[(int(i), int(j))]
        assert byte == klass
        if j < 0:
            assert np.abs(np.array(point) - segment[1]).max() <= max(box[2:]) * 0.5 + 1e-12


def frames_of(preset: str, count: int, steps: int, **settings):
    p = make_preset(preset, preset_settings(preset, **settings))
    for _ in range(count):
        p.advance(steps)
        yield build_frame([(FrameData.from_simulation(p.sim), (0.0, 0.0))])


@pytest.mark.parametrize("preset, steps, settings", [("ratchet16", 200, {}),
                                                      ("compression", 300, {"particles": 200})])
def test_a_page_that_applies_every_message_shows_each_frame_and_one_that_opens_later_the_same(preset, steps,
                                                                                           settings):
    encoder = Encoder()
    page, late = Page(), None
    contacts_changed = 0
    fields = ["rotation"] * 20 + ["pressure"] * 5 + ["coordination"] * 5
    for k, frame in enumerate(frames_of(preset, len(fields), steps, **settings)):
        message = encoder.encode(frame, fields[k])
        header, parts = unpack(message)
        contacts_changed += "gone" in parts
        page.apply(message)
        assert_shows(page, frame, fields[k])
        if k == 10:
            late = Page()
            late.apply(encoder.keyframe())
        elif late is not None:
            late.apply(message)
            assert_shows(late, frame, fields[k])
    assert contacts_changed >= 3  # contacts were born and lost on the way, and sent as changes


def test_a_frame_whose_disks_leave_the_box_or_change_in_number_is_a_key_frame():
    encoder = Encoder()
    frames = list(frames_of("ratchet16", 2, 10))
    assert unpack(encoder.encode(frames[0], "rotation"))[0]["key"]
    assert not unpack(encoder.encode(frames[1], "rotation"))[0]["key"]
    moved = build_frame([(FrameData.from_simulation(make_preset("ratchet16", preset_settings("ratchet16")).sim),
                          (100.0, 0.0))])
    assert unpack(encoder.encode(moved, "rotation"))[0]["key"]
    fewer = build_frame([(FrameData.from_simulation(make_preset("compression", preset_settings(
        "compression", particles=50)).sim), (0.0, 0.0))])
    page = Page()
    page.apply(encoder.encode(fewer, "rotation"))
    assert page.header["key"] and page.header["n"] == 50
    assert_shows(page, fewer, "rotation")


def test_a_boxs_walls_meet_at_its_corners_and_frame_the_picture():
    """The 3D scene draws walls four radii past the disks; the stream sends them ending where they meet."""
    [frame] = frames_of("ratchet16", 1, 10)
    header, _ = unpack(Encoder().encode(frame, "rotation"))
    walls = np.array(header["walls"]).reshape(-1, 2, 2)
    corners, counts = np.unique(walls.reshape(-1, 2).round(9), axis=0, return_counts=True)
    assert len(walls) == 4 and len(corners) == 4 and np.all(counts == 2)
    xmin, xmax, ymin, ymax = header["bounds"]
    assert (xmin, ymin) == pytest.approx(tuple(corners.min(axis=0))) and \
        (xmax, ymax) == pytest.approx(tuple(corners.max(axis=0)))


def test_the_arrows_of_a_mechanism_reach_every_page_once_and_a_page_that_opens_later():
    """The presenter's stiffness analysis draws arrows over the 3D scene; a viewer's 2D scene draws
    them too. They travel in the frame where they change and in key frames only."""
    encoder = Encoder()
    frames = list(frames_of("ratchet16", 5, 50))
    arrows = np.array([[[1.0, 2.0], [1.5, 2.25]], [[1.5, 2.25], [1.4, 2.3]], [[-3.0, 0.5], [-3.0, 1.5]]])
    page = Page()
    sent = []
    for k, frame in enumerate(frames):
        message = encoder.encode(frame, "rotation", arrows if 1 <= k <= 3 else None)
        sent.append("arrows" in unpack(message)[1])
        page.apply(message)
        assert_shows(page, frame, "rotation")
        if k == 2:
            late = Page()
            late.apply(encoder.keyframe())
            assert np.array_equal(late.arrows, arrows.astype(np.float32))
        assert np.array_equal(page.arrows, arrows.astype(np.float32) if 1 <= k <= 3 else np.zeros((0, 2, 2)))
    assert sent == [True, True, False, False, True]  # the key frame, then where they come and go


class FakeSocket:
    def __init__(self):
        self.in_flight = 0
        self.received: list[bytes] = []

    def send(self, message: bytes) -> None:
        self.received.append(message)


def test_a_page_too_far_behind_misses_frames_then_catches_up_with_a_key_frame():
    from granlab.app.lab.stream import MAX_IN_FLIGHT, ViewerStream

    stream = ViewerStream()
    frames = list(frames_of("ratchet16", 6, 50))
    quick, slow = FakeSocket(), FakeSocket()
    stream._send(stream.encoder.encode(frames[0], "rotation"))  # before any page: nobody gets it
    stream.opened(quick)
    stream.opened(slow)
    slow.in_flight = MAX_IN_FLIGHT
    for frame in frames[1:4]:
        stream._send(stream.encoder.encode(frame, "rotation"))
    slow.in_flight = 0
    for frame in frames[4:]:
        stream._send(stream.encoder.encode(frame, "rotation"))
    assert len(quick.received) == 6 and len(slow.received) == 3  # its key frame, then the last 2 as the others
    pages = [Page(), Page()]
    for page, socket in zip(pages, (quick, slow)):
        for message in socket.received:
            page.apply(message)
        assert_shows(page, frames[-1], "rotation")
    assert [unpack(m)[0]["key"] for m in slow.received] == [True, True, False]


def test_a_frame_of_a_diverging_run_is_refused_and_the_stream_goes_on_from_the_last_good_one():
    import dataclasses

    encoder = Encoder()
    first, second = frames_of("ratchet16", 2, 50)
    page = Page()
    page.apply(encoder.encode(first, "rotation"))
    broken = first.positions.copy()
    broken[3] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        encoder.encode(dataclasses.replace(first, positions=broken), "rotation")
    page.apply(encoder.encode(second, "rotation"))
    assert not page.header["key"]
    assert_shows(page, second, "rotation")


class FakeLoop:
    def __init__(self):
        self.sent: list[bytes] = []

    def add_callback(self, function, message: bytes) -> None:
        self.sent.append(message)


@pytest.mark.parametrize("size, rate", [(600, 20.0), (30_000, 11.0)])
def test_the_stream_sends_as_many_frames_as_its_budget_allows_within_its_rates(monkeypatch, size, rate):
    """A scene's frame every 45 ms for 10 s: frames of a few hundred bytes go at the most rate, frames
    whose rate would pass the budget at the least (not one scene frame in two: 11.1 a second)."""
    import granlab.app.lab.stream as stream_module

    clock = [100.0]
    monkeypatch.setattr(stream_module.time, "monotonic", lambda: clock[0])
    stream = stream_module.ViewerStream(io_loop=FakeLoop())
    monkeypatch.setattr(stream.encoder, "encode", lambda frame, field, arrows: b"x" * size)
    for _ in range(round(10.0 / 0.045)):
        stream.publish(None, "rotation")
        clock[0] += 0.045
    assert len(stream.io_loop.sent) / 10.0 == pytest.approx(rate, rel=0.08)
