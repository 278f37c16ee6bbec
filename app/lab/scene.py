"""The lab's 3D scene: one viser server per process drawing `SceneFrame`s.

The simulation is 2D: disks lie in the plane z = 0 of viser's world (z up) and
the camera looks down the -z axis with +y up on the screen. Lengths are in the
simulation's units; forces and pressures only set widths and colours, so their
units do not matter.

What is drawn (all handles live under ``/granlab``):

- disks: one batched mesh of a unit cylinder (axis z, radius 1, height 1,
  centred on z = 0), instance k scaled by (r_k, r_k, h) with h = 0.2 mean
  radius and coloured by `SceneView.color_field`;
- spokes: one segment per disk from its centre to its rim at angle theta;
- force network: contact segments binned by |F| / max|F| into
  `FORCE_CLASSES` width classes (viser's line width is per handle), coloured
  by kind (compressive, tensile, sliding);
- watched contacts, walls and the periodic cell outline: one handle each.

Picking: viser 1.1.1 does report the clicked instance of a batched mesh that
has a node on_click callback (the event's instance_index; its docstring still
says None for all but batched axes), but such a clickable mesh makes the client
build and refit a BVH over all instances at every update. The view listens to
scene-wide clicks instead, which carry the click's ray in world coordinates
without making anything clickable, and `pick_disk` intersects that ray with
the plane of the disks' top faces.
"""

from __future__ import annotations

import http
import threading
from collections import deque
from time import monotonic
from typing import Callable

import numpy as np
import viser
from viser import _messages as viser_messages
import websockets.asyncio.server
from websockets.http11 import Request

from granlab.engine.frames import SceneFrame, cell_outline

from ..media.drawing import (CELL_COLOR, COLOR_FIELDS, CONTACT_KINDS, FORCE_CLASSES, MECHANISM_COLOR, PALETTES, SPOKE_COLOR,
                      WALL_COLOR, WATCHED_COLORS, WATCHED_THICKNESS, color_index, force_class_thickness, force_classes,
                      frame_bounds)

DISK_SEGMENTS = 16
"""Sides of the polygon standing for a disk: 60 triangles a disk (caps and
side), 336 000 for 5600 disks, kept low for software-rendered WebGL."""

DISK_HEIGHT = 0.2
"""Cylinder height as a fraction of the frame's mean radius."""

SPOKE_THICKNESS = 0.08
WALL_THICKNESS = 0.2
CELL_THICKNESS = 0.1
MECHANISM_THICKNESS = 0.25
"""Line thicknesses as fractions of the mean radius (world units)."""

ENVIRONMENT_INTENSITY = 0.3
"""Intensity of viser's environment map: at 1 (viser's default) the lit top
faces show about a third brighter than their palette colours."""

CAMERA_FOV = np.radians(30.0)
"""Vertical field of view of the initial camera (radians): narrow, so the
perspective hardly distorts the 2D picture."""

MIN_ASPECT = 0.75
"""The narrowest view (width / height) the framing allows for: the lab's
scene is about square, a little taller than wide at 1920 × 1080."""

_ROOT = "/granlab"


def srgb_to_linear(colors: np.ndarray) -> np.ndarray:
    """uint8 sRGB colours (any shape) -> uint8 linear-light values, rounded.

    viser 1.1.1's client reads per-instance mesh colours and per-vertex line
    colours as linear values (three.js Color.setRGB(c / 255)) and encodes them
    to sRGB on output, so an sRGB colour sent as is shows up paler; a single
    (3,) colour of a handle goes through Color(hex) and is taken as sRGB.
    """
    c = np.asarray(colors, dtype=np.float64) / 255.0
    linear = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    return np.round(255.0 * linear).astype(np.uint8)


_WIRE_TABLES = {field: srgb_to_linear(table) for field, table in PALETTES.items()}
_WIRE_TABLES["contact kind"] = srgb_to_linear(np.array([color for _, color in CONTACT_KINDS]))
_WIRE_TABLES["watched"] = srgb_to_linear(WATCHED_COLORS)
"""The palettes of :mod:`granlab.app.media.drawing` as sent to viser (linear values)."""


def unit_cylinder(segments: int = DISK_SEGMENTS) -> tuple[np.ndarray, np.ndarray]:
    """Closed cylinder along z, z in [-1/2, 1/2], as (vertices (4s, 3) float32,
    faces (4s - 4, 3) uint32), outward counter-clockwise winding.

    The s-gon's circumradius is chosen so that its area is pi (the unit disk's),
    so drawn disks cover the plane as the physical ones do. Caps and side have
    their own vertices so the client's vertex normals stay flat on the caps.
    """
    phi = 2.0 * np.pi * np.arange(segments) / segments
    ring_radius = np.sqrt(2.0 * np.pi / (segments * np.sin(2.0 * np.pi / segments)))
    ring = np.stack([ring_radius * np.cos(phi), ring_radius * np.sin(phi)], axis=1)
    bottom = np.column_stack([ring, np.full(segments, -0.5)])
    top = np.column_stack([ring, np.full(segments, 0.5)])
    vertices = np.concatenate([bottom, top, bottom, top]).astype(np.float32)

    k = np.arange(segments)
    nxt = (k + 1) % segments
    side_bottom, side_top = 2 * segments, 3 * segments
    side = np.concatenate([
        np.stack([side_bottom + k, side_bottom + nxt, side_top + nxt], axis=1),
        np.stack([side_bottom + k, side_top + nxt, side_top + k], axis=1),
    ])
    fan = np.arange(1, segments - 1)
    top_cap = np.stack([np.full_like(fan, segments), segments + fan, segments + fan + 1], axis=1)
    bottom_cap = np.stack([np.zeros_like(fan), fan + 1, fan], axis=1)
    faces = np.concatenate([side, top_cap, bottom_cap]).astype(np.uint32)
    return vertices, faces


def pick_disk(ray_origin, ray_direction, positions: np.ndarray, radii: np.ndarray,
              plane_z: float = 0.0) -> int | None:
    """Index of the disk under a click, or None.

    ray_origin, ray_direction: (3,) world coordinates of the click's ray;
    positions (N, 2), radii (N,); plane_z: height of the plane the disks are
    cut at (their top faces). The ray meets the plane at p; the disk k with
    |p - x_k| <= r_k is returned (of overlapping disks, the smallest
    |p - x_k| / r_k). None if the ray misses the plane or every disk.
    """
    ox, oy, oz = (float(v) for v in ray_origin)
    dx, dy, dz = (float(v) for v in ray_direction)
    if dz == 0.0 or len(radii) == 0:
        return None
    t = (plane_z - oz) / dz
    if t < 0.0:
        return None
    hit = np.array([ox + t * dx, oy + t * dy])
    relative = np.hypot(positions[:, 0] - hit[0], positions[:, 1] - hit[1]) / radii
    k = int(np.argmin(relative))
    return k if relative[k] <= 1.0 else None


def _segments_3d(segments: np.ndarray, z: float) -> np.ndarray:
    """(S, 2, 2) planar segments -> (S, 2, 3) float32 at height z."""
    points = np.empty((len(segments), 2, 3), dtype=np.float32)
    points[:, :, :2] = segments
    points[:, :, 2] = z
    return points


_SERVE_PATCH = threading.Lock()


def _guarded_server(host: str, port: int, admit: Callable[[Request], str | None]) -> viser.ViserServer:
    """A viser server whose websocket handshakes pass ``admit`` first (None: admitted; a text: the
    reason of a 403). viser 1.1.1 accepts any Origin and has no hook on the handshake, but it
    starts its server with ``websockets.asyncio.server.serve`` from inside its constructor, which
    returns once the server listens: that function is wrapped for the constructor's duration."""
    original = websockets.asyncio.server.serve

    def serve(*args, process_request=None, **kwargs):
        def guard(connection, request: Request):
            if request.headers.get("Upgrade", "").lower() == "websocket":
                refusal = admit(request)
                if refusal is not None:
                    return connection.respond(http.HTTPStatus.FORBIDDEN, refusal + "\n")
            return process_request(connection, request) if process_request else None
        return original(*args, process_request=guard, **kwargs)

    with _SERVE_PATCH:
        websockets.asyncio.server.serve = serve
        try:
            return viser.ViserServer(host=host, port=port, verbose=False)
        finally:
            websockets.asyncio.server.serve = original


class SceneView:
    """The lab's viser scene: one ViserServer per process, drawing SceneFrames.

    `draw` may be called from one thread (the engine thread); `color_field`,
    `on_pick`, `fps` and the properties from any thread.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 0,
                 admit: Callable[[Request], str | None] | None = None,
                 may_pick: Callable[[str], bool] | None = None):
        self._server = _guarded_server(host, port, admit) if admit else viser.ViserServer(host=host, port=port,
                                                                                          verbose=False)
        self._server.gui.configure_theme(show_logo=False, show_share_button=False)
        self._server.gui.main_panel.minimize()
        # what a client may ask that the lab has no use for, a public share link first (it would
        # open a tunnel from the presenter's machine to viser's relay): only clicks are heard
        handlers = self._server._websock_server._incoming_handlers
        for message in [m for m in handlers if m is not viser_messages.ScenePointerMessage]:
            self._server._websock_server.unregister_handler(message)
        self._server.scene.configure_default_lights(enabled=True, cast_shadow=False)
        self._server.scene.configure_environment_map(environment_intensity=ENVIRONMENT_INTENSITY)
        self._lock = threading.Lock()
        self._color_field = "rotation"
        self._pick_callbacks: list[Callable[[int], None]] = []
        self._may_pick = may_pick
        self._draw_times: deque[float] = deque()
        self._created = monotonic()
        self.frames_pushed = 0

        self._frame: SceneFrame | None = None
        self._arrows = np.zeros((0, 2, 2))
        self._framed = (0.0, 0.0, 0.0)  # centre x, y and half-width of the square the camera shows
        self._disks: viser.BatchedMeshHandle | None = None
        self._disk_top = 0.0
        self._positions3 = np.zeros((0, 3), dtype=np.float32)
        self._scales3 = np.zeros((0, 3), dtype=np.float32)
        self._colors = np.zeros((0, 3), dtype=np.uint8)
        self._lut_index = np.zeros(0, dtype=np.intp)
        self._scratch = np.zeros(0, dtype=np.float64)
        self._spoke_points = np.zeros((0, 2, 3), dtype=np.float32)
        self._contact_points = np.zeros((0, 2, 3), dtype=np.float32)
        self._contact_colors = np.zeros((0, 2, 3), dtype=np.uint8)

        scene = self._server.scene
        empty = np.zeros((1, 2, 3), dtype=np.float32)

        def lines(name: str, color: tuple[int, int, int]) -> viser.LineSegmentsHandle:
            return scene.add_line_segments(f"{_ROOT}/{name}", empty, color, visible=False)

        def coloured_lines(name: str) -> viser.LineSegmentsHandle:
            """Segments coloured one by one, from the start: viser 1.1.1's client does not switch a
            line from one colour to per-segment colours (it draws them near white), so a handle
            that starts with one colour and gets per-segment ones later, as a client watches, would
            show white lines."""
            return scene.add_line_segments(f"{_ROOT}/{name}", empty, np.zeros((1, 2, 3), dtype=np.uint8),
                                           visible=False)

        self._spokes = lines("spokes", SPOKE_COLOR)
        self._forces = [coloured_lines(f"forces/class{k}") for k in range(FORCE_CLASSES)]
        self._watched = coloured_lines("watched")
        self._walls = lines("walls", WALL_COLOR)
        self._cell = lines("cell", CELL_COLOR)
        self._mechanism = lines("mechanism", MECHANISM_COLOR)
        self._labels: list[viser.LabelHandle] = []
        self._label_texts: tuple = ()
        scene.on_click()(self._on_scene_click)
        self._pose = None
        self._server.on_client_connect(self._on_client)

    @property
    def port(self) -> int:
        """TCP port of the viser server (the client is at http://host:port)."""
        return self._server.get_port()

    @property
    def server(self) -> viser.ViserServer:
        """The underlying viser server (for GUI elements or client queries)."""
        return self._server

    @property
    def handles(self) -> dict:
        """The viser handles, to read back what was sent: "disks" (batched mesh,
        None before the first draw), "spokes", "forces" (list, class 0 first),
        "watched", "walls", "cell", "mechanism" (line segments), "labels" (list of the names under
        groups of disks)."""
        return {"disks": self._disks, "spokes": self._spokes, "forces": list(self._forces),
                "watched": self._watched, "walls": self._walls, "cell": self._cell, "mechanism": self._mechanism,
                "labels": list(self._labels)}

    @property
    def connected_clients(self) -> int:
        """Number of browser clients connected to the viser server."""
        return len(self._server.get_clients())

    @property
    def color_field(self) -> str:
        """What colours the disks: one of COLOR_FIELDS."""
        return self._color_field

    @color_field.setter
    def color_field(self, value: str) -> None:
        if value not in COLOR_FIELDS:
            raise ValueError(f"color_field {value!r} is not allowed: one of {', '.join(COLOR_FIELDS)}")
        with self._lock:
            self._color_field = value
            if self._frame is not None and self._disks is not None:
                self._fill_colors(self._frame)
                with self._server.atomic():
                    self._disks.batched_colors = self._colors

    def _client_path(self, client_id: int) -> str:
        """The path of the websocket a client connected with ("" once it has gone): viser keeps
        the connections of its live clients by id, and tells nothing else of how one came."""
        connection = self._server._websock_server._live_connections.get(client_id)
        return connection.request.path if connection is not None and connection.request is not None else ""

    def on_pick(self, callback: Callable[[int], None]) -> None:
        """Call callback(disk_index) when a browser click lands on a disk
        (indices of the last drawn frame; runs on viser's thread pool)."""
        self._pick_callbacks.append(callback)

    def state(self) -> dict:
        """What the scene holds now (``GET /scene``): disks drawn and how many of them lie inside
        the square the camera was framed on, contact segments, walls, watched contacts, the
        cell, that square (xmin, xmax, ymin, ymax) and the colour field."""
        with self._lock:
            frame = self._frame
            if frame is None:
                return {"frames": 0, "disks": 0, "disks_in_view": 0}
            cx, cy, half = self._framed
            x, y, r = frame.positions[:, 0], frame.positions[:, 1], frame.radii
            inside = (x - r >= cx - half) & (x + r <= cx + half) & (y - r >= cy - half) & (y + r <= cy + half)
            return {"frames": self.frames_pushed, "disks": int(len(r)), "disks_in_view": int(inside.sum()),
                    "contacts": int(len(frame.contacts)), "walls": int(len(frame.walls)),
                    "watched": int(len(frame.watched)), "cell": frame.cell, "mechanism": bool(self._mechanism.visible),
                    "view": [cx - half, cx + half, cy - half, cy + half], "color_field": self._color_field}

    def fps(self) -> float:
        """Draws completed per second over the last 2 s (or since construction
        if that is shorter)."""
        now = monotonic()
        with self._lock:
            self._forget_draws_before(now - 2.0)
            count = len(self._draw_times)
        window = min(2.0, now - self._created)
        return count / window if window > 0.0 else 0.0

    def show_arrows(self, segments: np.ndarray, mean_radius: float) -> None:
        """Draw (S, 2, 2) segments above the disks: the arrows of a mechanism found by the
        Analysis tab, where the disks were when it was analysed. No segments hide them."""
        with self._lock, self._server.atomic():
            z = 3.0 * self._disk_top + DISK_HEIGHT * mean_radius
            self._arrows = np.asarray(segments, dtype=float).reshape(-1, 2, 2)
            self._show(self._mechanism, _segments_3d(self._arrows, z), MECHANISM_THICKNESS * mean_radius)

    @property
    def arrows(self) -> np.ndarray:
        """The (S, 2, 2) segments :meth:`show_arrows` shows (S = 0: none)."""
        return self._arrows

    def close(self) -> None:
        """Stop the viser server."""
        self._server.stop()

    def draw(self, frame: SceneFrame) -> None:
        """Show `frame`: the disk mesh is rebuilt when N changes, otherwise its
        arrays are updated in place. The camera is framed on the picture when
        the mesh is rebuilt, when the picture leaves the framed square (a block
        sliding away) or shrinks below a third of it (a cell compressed)."""
        with self._lock:
            n = len(frame.radii)
            mean_radius = float(frame.radii.mean()) if n else 1.0
            height = DISK_HEIGHT * mean_radius
            self._frame = frame
            self._disk_top = 0.5 * height
            self._fill_disks(frame, height)
            self._fill_colors(frame)
            self._fill_spokes(frame, 0.7 * height)
            with self._server.atomic():
                if self._disks is None or len(self._disks.batched_positions) != n:
                    self._rebuild_disks()
                    self._frame_camera(frame)
                else:
                    if self._needs_framing(frame):
                        self._frame_camera(frame)
                    self._disks.batched_positions = self._positions3
                    self._disks.batched_scales = self._scales3
                    self._disks.batched_colors = self._colors
                self._show(self._spokes, self._spoke_points, SPOKE_THICKNESS * mean_radius)
                self._draw_forces(frame, 0.6 * height, mean_radius)
                watched_colors = _WIRE_TABLES["watched"][frame.watched_index % len(WATCHED_COLORS)]
                self._show(self._watched, _segments_3d(frame.watched, 0.8 * height),
                           WATCHED_THICKNESS * mean_radius, np.repeat(watched_colors[:, None, :], 2, axis=1))
                self._show(self._walls, _segments_3d(frame.walls, 0.0), WALL_THICKNESS * mean_radius)
                outline = cell_outline(frame.cell) if frame.cell is not None else np.zeros((0, 2, 2))
                self._show(self._cell, _segments_3d(outline, 0.0), CELL_THICKNESS * mean_radius)
                self._show_labels(frame.labels)
            self.frames_pushed += 1
            now = monotonic()
            self._draw_times.append(now)
            self._forget_draws_before(now - 2.0)

    def _show_labels(self, labels: tuple) -> None:
        """The names under groups of disks (the closed path's pairs): made when the names change,
        moved when their place does."""
        texts = tuple(text for text, _, _ in labels)
        if texts != self._label_texts:
            for handle in self._labels:
                handle.remove()
            self._labels = [self._server.scene.add_label(f"{_ROOT}/labels/{k}", text, position=(x, y, 0.0),
                                                         anchor="top-center")
                            for k, (text, x, y) in enumerate(labels)]
            self._label_texts = texts
            return
        for handle, (_, x, y) in zip(self._labels, labels):
            if not np.allclose(handle.position, (x, y, 0.0)):
                handle.position = (x, y, 0.0)

    def _forget_draws_before(self, oldest: float) -> None:
        while self._draw_times and self._draw_times[0] < oldest:
            self._draw_times.popleft()

    def _fill_disks(self, frame: SceneFrame, height: float) -> None:
        """Instance positions (N, 3) and per-axis scales (r, r, h) into the buffers."""
        n = len(frame.radii)
        if len(self._positions3) != n:
            self._positions3 = np.zeros((n, 3), dtype=np.float32)
            self._scales3 = np.zeros((n, 3), dtype=np.float32)
            self._colors = np.zeros((n, 3), dtype=np.uint8)
            self._lut_index = np.zeros(n, dtype=np.intp)
            self._scratch = np.zeros(n, dtype=np.float64)
            self._spoke_points = np.zeros((n, 2, 3), dtype=np.float32)
        self._positions3[:, :2] = frame.positions
        self._scales3[:, 0] = frame.radii
        self._scales3[:, 1] = frame.radii
        self._scales3[:, 2] = height

    def _fill_colors(self, frame: SceneFrame) -> None:
        """Disk colours (N, 3) uint8 of `color_field`, as sent (linear), into the colour buffer."""
        color_index(frame, self._color_field, self._lut_index, self._scratch)
        np.take(_WIRE_TABLES[self._color_field], self._lut_index, axis=0, out=self._colors)

    def _fill_spokes(self, frame: SceneFrame, z: float) -> None:
        """Spokes (N, 2, 3): centre -> centre + r (cos theta, sin theta), at height z."""
        spokes, scratch = self._spoke_points, self._scratch
        spokes[:, 0, :2] = frame.positions
        np.cos(frame.angles, out=scratch)
        scratch *= frame.radii
        scratch += frame.positions[:, 0]
        spokes[:, 1, 0] = scratch
        np.sin(frame.angles, out=scratch)
        scratch *= frame.radii
        scratch += frame.positions[:, 1]
        spokes[:, 1, 1] = scratch
        spokes[:, :, 2] = z

    def _rebuild_disks(self) -> None:
        if self._disks is not None:
            self._disks.remove()
        vertices, faces = unit_cylinder()
        wxyzs = np.zeros((len(self._positions3), 4), dtype=np.float32)
        wxyzs[:, 0] = 1.0
        self._disks = self._server.scene.add_batched_meshes_simple(
            f"{_ROOT}/disks", vertices, faces, wxyzs, self._positions3,
            batched_scales=self._scales3, batched_colors=self._colors,
            lod="off", cast_shadow=False, receive_shadow=False,
        )

    def _needs_framing(self, frame: SceneFrame) -> bool:
        xmin, xmax, ymin, ymax = frame_bounds(frame)
        cx, cy, half = self._framed
        outside = xmin < cx - half or xmax > cx + half or ymin < cy - half or ymax > cy + half
        return outside or max(xmax - xmin, ymax - ymin) < 2.0 * half / 3.0

    def _frame_camera(self, frame: SceneFrame) -> None:
        """Point the initial camera (and every connected client's) down -z at
        the frame, +y up, far enough that the frame fills a square view."""
        xmin, xmax, ymin, ymax = frame_bounds(frame)
        centre = np.array([0.5 * (xmin + xmax), 0.5 * (ymin + ymax), 0.0])
        half = 0.55 * max((xmax - xmin) / MIN_ASPECT, ymax - ymin, 1e-9)
        self._framed = (float(centre[0]), float(centre[1]), half)
        distance = half / np.tan(0.5 * CAMERA_FOV)
        position = centre + np.array([0.0, 0.0, distance])
        far = float(max(1000.0, 20.0 * distance))
        camera = self._server.initial_camera
        camera.fov = float(CAMERA_FOV)
        camera.far = far
        camera.up = (0.0, 1.0, 0.0)
        camera.position = position
        camera.look_at = centre
        self._pose = (position, centre, far)
        for client in self._server.get_clients().values():
            self._aim(client)

    def _aim(self, client: viser.ClientHandle) -> None:
        """Point ``client``'s camera at the framed square."""
        position, centre, far = self._pose
        client.camera.up_direction = (0.0, 1.0, 0.0)
        client.camera.fov = float(CAMERA_FOV)
        client.camera.far = far
        client.camera.position = position
        client.camera.look_at = centre

    def _on_client(self, client: viser.ClientHandle) -> None:
        """Aim a new client's camera once it reports its first pose: viser sends a client the
        initial camera of the moment it connected, and a client still loading when the picture
        was framed again (a new preset) would keep the old view."""
        aimed = []

        def first_report(camera) -> None:
            if not aimed and self._pose is not None:
                aimed.append(True)
                with self._lock:
                    self._aim(client)

        client.camera.on_update(first_report)

    def _draw_forces(self, frame: SceneFrame, z: float, mean_radius: float) -> None:
        """Contact segments sorted into FORCE_CLASSES handles by |F|, coloured by
        kind, through buffers that grow geometrically with M."""
        m = len(frame.contact_force)
        if len(self._contact_points) < m:
            capacity = max(m, 2 * len(self._contact_points))
            self._contact_points = np.zeros((capacity, 2, 3), dtype=np.float32)
            self._contact_colors = np.zeros((capacity, 2, 3), dtype=np.uint8)
        points, colors = self._contact_points[:m], self._contact_colors[:m]
        klass = force_classes(frame.contact_force)
        order = np.argsort(klass, kind="stable")
        bounds = np.zeros(FORCE_CLASSES + 1, dtype=np.intp)
        np.cumsum(np.bincount(klass, minlength=FORCE_CLASSES), out=bounds[1:])
        points[:, :, :2] = frame.contacts[order]
        points[:, :, 2] = z
        kind_colors = _WIRE_TABLES["contact kind"]
        kind = np.clip(frame.contact_kind[order], 0, len(kind_colors) - 1)
        colors[:] = kind_colors[kind][:, None, :]
        for k, handle in enumerate(self._forces):
            self._show(handle, points[bounds[k]:bounds[k + 1]], force_class_thickness(k, mean_radius),
                       colors[bounds[k]:bounds[k + 1]])

    @staticmethod
    def _show(handle: viser.LineSegmentsHandle, points: np.ndarray, thickness: float,
              colors: np.ndarray | None = None) -> None:
        """Give a line handle its segments (S, 2, 3); hide it when S = 0 (the
        client is never sent empty line geometry)."""
        if len(points) == 0:
            handle.visible = False
            return
        handle.points = points
        if colors is not None:
            handle.colors = colors
        handle.thickness = thickness
        handle.visible = True

    def _on_scene_click(self, event: viser.SceneClickEvent) -> None:
        frame = self._frame
        if frame is None or (self._may_pick is not None and not self._may_pick(self._client_path(event.client_id))):
            return
        hit = pick_disk(event.ray_origin, event.ray_direction, frame.positions, frame.radii,
                        plane_z=self._disk_top)
        if hit is not None:
            for callback in list(self._pick_callbacks):
                callback(hit)
