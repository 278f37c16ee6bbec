"""The viewers' stream: the scene as compact binary frames, encoded once for every viewer's page.

viser sends each array whole, as float32, and encodes each message once per client: at 5600
disks the positions alone are 5.4 Mbit/s at 10 frames/s a viewer. The viewers' pages draw the
scene on a 2D canvas instead (``static/viewer/scene.html``), fed by this stream:

- positions quantised to 14 bits in a box around the picture (kept while the picture stays in it
  and fills most of it; a tenth of a pixel on a 1920-pixel canvas), the x of every disk then every y;
  an angle and a colour (the row of the colour field's palette) a byte each;
- contacts as pairs of disks (a negative partner for a wall's point, whose position is sent) with a byte of force
  class and kind;
- each frame as the change from the last one: the disks' arrays as differences modulo 2¹⁶ or 2⁸,
  the contacts as those gone (the steps between their ascending rows) and those added (sorted by
  their first disk: the steps between those, and each second disk less its first), then the
  change of each one's byte;
- the arrows of a mechanism the presenter's analysis found (float32 segments, x0 y0 x1 y1 each) in a
  key frame and in the frame where they change, not in the others;
- a key frame (every array whole) to a page that opens, or falls behind, or when the box, the
  number of disks or the colour field changes;
- 16-bit arrays as their low bytes then their high bytes (small changes leave the high bytes 0 or 255),
  the whole message compressed with zlib once (the page inflates it with DecompressionStream).

At 5600 disks in compression, frames 200 steps apart: a change 10.8 kB with 16-bit positions, x and
y interleaved, contacts unsorted; 6.6 kB so.

A message: a 4-byte little-endian header length, the header (JSON: ``seq``, ``key``, ``parts``
naming each array, its dtype, length, mode and coding, and the frame's few floats), then the
arrays, each padded to 4 bytes. A page applies messages in ``seq`` order and reopens its socket at a gap.
"""

from __future__ import annotations

import dataclasses
import json
import struct
import threading
import time
import urllib.parse
import zlib

import numpy as np
import tornado.web
import tornado.websocket

from granlab.engine.frames import meeting_walls

from ..media.drawing import (CELL_COLOR, CONTACT_KINDS, FORCE_CLASSES, MAX_FORCE_THICKNESS, MECHANISM_COLOR, PALETTES,
                             SPOKE_COLOR, WALL_COLOR, WATCHED_COLORS, WATCHED_THICKNESS, color_index, force_classes,
                             frame_bounds)
from .access import Access
from .scene import MECHANISM_THICKNESS

MAX_IN_FLIGHT = 8
"""Messages a socket may have on their way (written, not yet handed to the network) before it
misses the next ones and gets a key frame once it has caught up: a busy server loop completes the
writes of one message only after the next is queued, and a page on a slow network falls behind."""

STREAM_RATES = (11.0, 20.0)
"""Frames per second on the viewers' stream, at least (while the scene has them) and at most (the
presenter's 3D scene draws up to 30)."""

STREAM_BUDGET = 100_000
"""Bytes per second the stream may take, a viewer, above its least rate: 0.8 Mbit/s, and frames of a
few hundred bytes (256 disks) go at the most rate; a 5600-disk compression's frames of 10 kB at the least."""

LEVELS = 2 ** 14 - 1
"""The positions' quantisation: the box's side in quanta."""

BOX_MARGIN = 0.05
"""The quantisation box reaches this fraction of the picture's size past it on each side."""

BOX_FILL = 0.7
"""A new box (a key frame) once the picture spans less than this fraction of the box along an axis."""

LEVEL = 6
"""zlib's level: a change of a 5600-disk compression's frame (116 steps apart) 8.1 kB in 3.6 ms (level 1:
9.2 kB in 2.9 ms; level 9: 7.9 kB in 8.9 ms), the compression outside the GIL."""


def _hex(rgb) -> str:
    return "#%02x%02x%02x" % tuple(int(c) for c in rgb)


def style() -> dict:
    """The colours and widths the page draws with (those of the 3D scene)."""
    return {"spoke": _hex(SPOKE_COLOR), "wall": _hex(WALL_COLOR), "cell": _hex(CELL_COLOR),
            "kinds": [_hex(color) for _, color in CONTACT_KINDS], "watched": [_hex(c) for c in WATCHED_COLORS],
            "classes": FORCE_CLASSES, "forceWidth": MAX_FORCE_THICKNESS, "watchedWidth": WATCHED_THICKNESS,
            "mechanism": _hex(MECHANISM_COLOR), "mechanismWidth": MECHANISM_THICKNESS}


def _pack(header: dict, parts: list[tuple]) -> bytes:
    """One message: header and arrays (name, array, mode and optionally coding: "steps" or "less ci"),
    compressed."""
    header["parts"] = [[name, array.dtype.str[1:], int(array.size), mode, coding[0] if coding else ""]
                       for name, array, mode, *coding in parts]
    text = json.dumps(header, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    chunks = [struct.pack("<I", len(text)), text]
    for _, array, *_ in parts:
        data = np.ascontiguousarray(array).astype(array.dtype.newbyteorder("<"), copy=False)
        if data.dtype.itemsize == 2:
            data = data.view(np.uint8).reshape(-1, 2).T
        data = data.tobytes()
        chunks.append(data + b"\0" * (-len(data) % 4))
    return zlib.compress(b"".join(chunks), LEVEL)


def _steps(ascending: np.ndarray) -> np.ndarray:
    """An ascending list as the steps between its values (the first from 0)."""
    return np.diff(ascending, prepend=ascending.dtype.type(0)).astype(ascending.dtype)


def unpack(message: bytes) -> tuple[dict, dict[str, tuple[np.ndarray, str]]]:
    """The header and the arrays (with their modes) of a message (as a page decodes it)."""
    data = zlib.decompress(message)
    (length,) = struct.unpack_from("<I", data)
    header = json.loads(data[4:4 + length])
    offset, arrays = 4 + length, {}
    for name, dtype, count, mode, coding in header["parts"]:
        kind = np.dtype(dtype).newbyteorder("<")
        size = count * kind.itemsize
        raw = np.frombuffer(data, dtype=np.uint8, count=size, offset=offset)
        if kind.itemsize == 2:
            raw = raw.reshape(2, -1).T.copy()
        array = raw.view(kind).ravel()
        if coding == "steps":
            array = np.cumsum(array, dtype=kind)
        elif coding == "less ci":
            array = array + arrays["ci"][0]
        arrays[name] = (array, mode)
        offset += size + (-size % 4)
    return header, arrays


class Encoder:
    """The stream's state (what every page up to date holds) and the messages that change it.

    ``encode`` is called from one thread (the scene's); ``keyframe`` from any (the server's loop,
    for a page that opens): both under one lock."""

    def __init__(self):
        self._lock = threading.Lock()
        self.seq = 0
        self._box: tuple[float, float, float, float] | None = None  # x0, y0, step x, step y
        self._field = ""
        self._state: dict[str, np.ndarray] = {}
        self._header: dict = {}
        self._index = np.zeros(0, dtype=np.intp)
        self._scratch = np.zeros(0)
        self._key: tuple[int, bytes] | None = None  # the last key frame made, by seq
        self._arrows = np.zeros(0, dtype=np.float32)

    def encode(self, frame, field: str, arrows: np.ndarray | None = None) -> bytes:
        """The message that brings a page from the last frame to ``frame`` coloured by ``field``, with
        the (S, 2, 2) segments ``arrows`` over it (None: none); a ValueError, and the stream as it
        was, for a frame whose disks are not all at finite places."""
        if not (np.isfinite(frame.positions).all() and np.isfinite(frame.radii).all()):
            raise ValueError("a frame with disks at non-finite places (a diverging run) is not sent to viewers")
        drawn = np.zeros(0, dtype=np.float32) if arrows is None else np.asarray(arrows, dtype=np.float32).ravel()
        with self._lock:
            arrows_changed = not np.array_equal(drawn, self._arrows)
            self._arrows = drawn
            n = len(frame.radii)
            frame = dataclasses.replace(frame, walls=_meeting(frame))
            bounds = frame_bounds(frame)
            key = (not self._state or len(self._state["radius"]) != n or field != self._field
                   or not self._box_holds(bounds))
            if key:
                self._box = self._new_box(bounds)
            state = self._arrays(frame, field)
            self.seq += 1
            self._header = self._frame_header(frame, field, bounds)
            if key:
                self._state, self._field = state, field
                return self._keyframe()
            previous, self._state, self._field = self._state, state, field
            parts = [(name, state[name] - previous[name], "delta")  # unsigned: modulo 2¹⁶ or 2⁸
                     for name in ("pos", "angle", "color")]
            if not np.array_equal(state["radius"], previous["radius"]):
                parts.append(("radius", state["radius"], "abs"))
            parts += self._contact_parts(previous, state)
            if arrows_changed:
                parts.append(("arrows", drawn, "abs"))
            return _pack({**self._header, "seq": self.seq, "key": False}, parts)

    def keyframe(self) -> bytes | None:
        """The message that brings a page with nothing to the last frame (None before the first)."""
        with self._lock:
            return self._keyframe() if self._state else None

    def _keyframe(self) -> bytes:
        """Made once per frame, whoever asks for it (a class joining at once)."""
        if self._key is None or self._key[0] != self.seq:
            self._key = (self.seq, self._make_keyframe())
        return self._key[1]

    def _make_keyframe(self) -> bytes:
        s = self._state
        parts = [(name, s[name], "abs") for name in ("pos", "angle", "color", "radius", "ci", "cj", "cls", "far")]
        parts.append(("arrows", self._arrows, "abs"))
        header = {**self._header, "seq": self.seq, "key": True, "field": self._field,
                  "palette": [_hex(c) for c in PALETTES[self._field]], "style": style()}
        return _pack(header, parts)

    def _contact_parts(self, previous: dict, state: dict) -> list:
        """The contacts' change: none gone or added (the same pairs in the same order), or those gone
        (their rows in the page's list) and those added (appended), then each row's byte and wall
        point as the change from the page's rows (0 for an added one)."""
        old, new = previous["code"], state["code"]
        if np.array_equal(old, new):
            return [("cls", state["cls"] - previous["cls"], "delta"), ("far", state["far"] - previous["far"], "delta")]
        by_code = np.argsort(new, kind="stable")
        sorted_new = new[by_code]
        if np.any(sorted_new[1:] == sorted_new[:-1]):  # the same pair twice (two images in a tiny cell)
            return [(name, state[name], "abs") for name in ("ci", "cj", "cls", "far")]
        kept = _among(old, sorted_new)
        added = np.sort(new[~_among(new, np.sort(old))])  # by first disk, then second
        order = np.concatenate([old[kept], added])
        rows = by_code[np.searchsorted(sorted_new, order)]  # each of the page's rows in this frame
        for name in ("code", "ci", "cj", "cls"):
            state[name] = state[name][rows]
        state["far"] = state["far"].reshape(-1, 2)[rows].ravel()
        base_cls = np.concatenate([previous["cls"][kept], np.zeros(len(added), dtype=np.uint8)])
        base_far = np.concatenate([previous["far"].reshape(-1, 2)[kept].ravel(),
                                   np.zeros(2 * len(added), dtype=np.uint16)])
        first, second = state["ci"][len(order) - len(added):], state["cj"][len(order) - len(added):]
        return [("gone", _steps(np.flatnonzero(~kept).astype(np.uint32)), "abs", "steps"),
                ("ci", _steps(first), "append", "steps"),
                ("cj", second - first, "append", "less ci"),
                ("cls", state["cls"] - base_cls, "delta"),
                ("far", state["far"] - base_far, "delta")]

    def _arrays(self, frame, field: str) -> dict[str, np.ndarray]:
        n, m = len(frame.radii), len(frame.contacts)
        if len(self._index) != n:
            self._index, self._scratch = np.zeros(n, dtype=np.intp), np.zeros(n)
        color_index(frame, field, self._index, self._scratch)
        ends = frame.ends if frame.ends is not None else np.full((m, 2), -1, dtype=np.int64)
        wall = ends[:, 1] < 0
        far = np.zeros((m, 2), dtype=np.uint16)
        far[wall] = self._quantise(frame.contacts[wall, 1])
        kind = np.clip(frame.contact_kind, 0, len(CONTACT_KINDS) - 1).astype(np.intp)
        return {"pos": self._quantise(frame.positions).T.ravel(),
                "angle": (np.floor(np.mod(frame.angles, 2.0 * np.pi) * (256 / (2.0 * np.pi))).astype(np.int64)
                          % 256).astype(np.uint8),
                "color": self._index.astype(np.uint8), "radius": frame.radii.astype(np.float32),
                "code": (ends[:, 0] << 32) + ends[:, 1] + (1 << 31), "ci": ends[:, 0].astype(np.int32),
                "cj": ends[:, 1].astype(np.int32),
                "cls": (force_classes(frame.contact_force) + FORCE_CLASSES * kind).astype(np.uint8),
                "far": far.ravel()}

    def _quantise(self, points: np.ndarray) -> np.ndarray:
        x0, y0, sx, sy = self._box
        q = np.empty(np.shape(points), dtype=np.uint16)
        q[..., 0] = np.clip(np.rint((points[..., 0] - x0) / sx), 0, LEVELS)
        q[..., 1] = np.clip(np.rint((points[..., 1] - y0) / sy), 0, LEVELS)
        return q

    @staticmethod
    def _new_box(bounds) -> tuple[float, float, float, float]:
        xmin, xmax, ymin, ymax = bounds
        size = max(xmax - xmin, ymax - ymin, 1e-12)
        pad = BOX_MARGIN * size
        return (xmin - pad, ymin - pad, (xmax - xmin + 2 * pad) / LEVELS, (ymax - ymin + 2 * pad) / LEVELS)

    def _box_holds(self, bounds) -> bool:
        if self._box is None:
            return False
        x0, y0, sx, sy = self._box
        x1, y1 = x0 + LEVELS * sx, y0 + LEVELS * sy
        xmin, xmax, ymin, ymax = bounds
        inside = x0 <= xmin and xmax <= x1 and y0 <= ymin and ymax <= y1
        return inside and xmax - xmin >= BOX_FILL * (x1 - x0) and ymax - ymin >= BOX_FILL * (y1 - y0)

    def _frame_header(self, frame, field: str, bounds) -> dict:
        def rounded(values) -> list:
            return [round(float(v), 7) for v in np.ravel(values)]

        return {"n": len(frame.radii), "box": list(self._box), "bounds": rounded(bounds), "field": field,
                "cell": list(frame.cell) if frame.cell is not None else None, "walls": rounded(frame.walls),
                "watched": rounded(frame.watched), "watchedIndex": [int(k) for k in frame.watched_index],
                "labels": [[text, round(x, 7), round(y, 7)] for text, x, y in frame.labels],
                "meanRadius": float(frame.radii.mean()) if len(frame.radii) else 1.0}


def _meeting(frame) -> np.ndarray:
    """The frame's walls ending where they meet (the 3D scene's run four radii past the disks, and
    the picture, framed on them, shows the packing smaller: on a phone, half its width)."""
    walls = frame.walls
    if not len(walls) or not len(frame.radii):
        return walls
    tangents = walls[:, 1] - walls[:, 0]
    tangents /= np.linalg.norm(tangents, axis=1)[:, None]
    normals = np.column_stack([tangents[:, 1], -tangents[:, 0]])
    met = meeting_walls(normals, np.einsum("ij,ij->i", normals, walls[:, 0]), frame.positions, frame.radii)
    return met[~np.isnan(met).any(axis=(1, 2))]


def _among(values: np.ndarray, sorted_set: np.ndarray) -> np.ndarray:
    """Whether each of ``values`` is in ``sorted_set`` (sorted): np.isin without its hashing, 5× slower here."""
    if not len(sorted_set):
        return np.zeros(len(values), dtype=bool)
    at = np.minimum(np.searchsorted(sorted_set, values), len(sorted_set) - 1)
    return sorted_set[at] == values


class ViewerStream:
    """The encoder and the open viewers' sockets: ``publish`` (the scene's thread) encodes a frame
    at the rate :data:`STREAM_BUDGET` allows within :data:`STREAM_RATES` and hands it to the
    server's loop, which writes it to every socket not too far behind; one that is gets a key frame
    once it has caught up."""

    def __init__(self, io_loop=None):
        self.encoder = Encoder()
        self.io_loop = io_loop
        self.sockets: dict["StreamSocket", bool] = {}  # socket -> whether it missed a message
        self.messages = 0
        self._due = 0.0
        self._size = 0.0  # of a message, a running mean

    def publish(self, frame, field: str, arrows: np.ndarray | None = None) -> None:
        now = time.monotonic()
        if self.io_loop is None or now < self._due:
            return
        try:
            message = self.encoder.encode(frame, field, arrows)
        except ValueError:  # the pages keep the last frame they could draw
            return
        self._size += 0.2 * (len(message) - self._size)
        least, most = STREAM_RATES
        interval = min(1.0 / least, max(1.0 / most, self._size / STREAM_BUDGET))
        # due on a grid: a scene's frames coming every 45 ms give 11 frames/s, not one in two
        self._due = max(self._due + interval, now - 0.5 * interval)
        self.io_loop.add_callback(self._send, message)

    def _send(self, message: bytes) -> None:
        self.messages += 1
        for socket, missed in list(self.sockets.items()):
            if socket.in_flight >= MAX_IN_FLIGHT:
                self.sockets[socket] = True
                continue
            if missed:
                self.sockets[socket] = False
                keyframe = self.encoder.keyframe()
                socket.send(keyframe if keyframe is not None else message)
            else:
                socket.send(message)

    def opened(self, socket: "StreamSocket") -> None:
        self.sockets[socket] = False
        keyframe = self.encoder.keyframe()
        if keyframe is not None:
            socket.send(keyframe)

    def closed(self, socket: "StreamSocket") -> None:
        self.sockets.pop(socket, None)


class StreamSocket(tornado.websocket.WebSocketHandler):
    """``/viewer-stream``: a page that ``access`` admits (by one of the lab's names; with tokens, a
    valid one in its cookie or address), from one of the lab's own pages, receives the stream; what
    it sends is ignored."""

    def initialize(self, stream: ViewerStream, access: Access):
        self.stream = stream
        self.access = access
        self.in_flight = 0

    def prepare(self):
        if self.access.admit(self) is None:
            raise tornado.web.HTTPError(403, "a valid token is needed")

    def check_origin(self, origin: str) -> bool:
        return self.access.admits_host(urllib.parse.urlsplit(origin).netloc)

    def open(self):
        self.stream.opened(self)

    def on_close(self):
        self.stream.closed(self)

    def on_message(self, message):
        pass

    def send(self, message: bytes) -> None:
        """Write ``message``, counted ``in_flight`` until it has gone to the network."""
        try:
            future = self.write_message(message, binary=True)
        except tornado.websocket.WebSocketClosedError:
            self.stream.closed(self)
            return
        self.in_flight += 1
        future.add_done_callback(self._sent)

    def _sent(self, future) -> None:
        self.in_flight -= 1
        if future.exception() is not None:  # the page went while this was on its way
            self.stream.closed(self)
