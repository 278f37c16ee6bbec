"""Pictures of the packing as geometry, numpy only: the lab's scene, its movies and the headless export
draw the same thing.

A :class:`SceneFrame` is one picture: the disks with their coordination, pressure and sliding, the
force network as segments, the walls, the periodic cell and the watched contacts.
:func:`build_frame` computes it from :class:`FrameData`, a copy of the arrays it needs: the lab's
engine thread only copies them (:meth:`FrameData.from_simulation`, the contact rows in use) and
its scene thread builds the frame, so building never touches the live simulation and costs the
engine thread nothing but the copy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .kernels.fields import contact_fields
from .protocols.measures import pair_codes
from .state import STATUS_NONE


@dataclass(frozen=True)
class SceneFrame:
    """One picture of the simulation (2D disks in the x-y plane).

    N disks, M contacts, W walls, K watched contacts; lengths in simulation units.
    """

    positions: np.ndarray      # (N, 2) float64 disk centres
    radii: np.ndarray          # (N,) float64
    angles: np.ndarray         # (N,) float64 rotation angle theta of each disk (radians)
    coordination: np.ndarray   # (N,) int number of contacts of each disk
    pressure: np.ndarray       # (N,) float64 a per-disk pressure value (>= 0)
    sliding: np.ndarray        # (N,) bool: the disk has a sliding contact
    contacts: np.ndarray       # (M, 2, 2) float64 segments: centre of i -> centre of j (or wall point)
    contact_force: np.ndarray  # (M,) float64 magnitude of the contact force (>= 0)
    contact_kind: np.ndarray   # (M,) int8: 0 compressive, 1 tensile (cohesive pull or dashpot), 2 sliding
    walls: np.ndarray          # (W, 2, 2) float64 wall segments (endpoints), may be (0, 2, 2)
    cell: tuple[float, float] | None  # periodic cell lengths (outline [0,Lx]x[0,Ly]) or None
    watched: np.ndarray        # (K, 2, 2) float64 segments of watched contacts, may be (0, 2, 2)
    watched_index: np.ndarray | None = None  # (K,) int: position of each watched segment's pair in
    #                                           the watch list (its colour); None: 0, 1, 2, ...
    labels: tuple[tuple[str, float, float], ...] = ()  # (text, x, y): a name whose top centre is at (x, y)
    ends: np.ndarray | None = None  # (M, 2) int: the disk at each end of each contact's segment, -1 - w for
    #                                  wall w's point (the viewers' stream sends pairs, not segments)

    def __post_init__(self) -> None:
        sizes = {"N": np.shape(self.positions)[0] if np.ndim(self.positions) else 0,
                 "M": np.shape(self.contacts)[0] if np.ndim(self.contacts) else 0}
        expected = {
            "positions": ("N", 2), "radii": ("N",), "angles": ("N",), "coordination": ("N",),
            "pressure": ("N",), "sliding": ("N",), "contacts": ("M", 2, 2), "contact_force": ("M",),
            "contact_kind": ("M",), "walls": ("W", 2, 2), "watched": ("K", 2, 2),
        }
        for name, shape in expected.items():
            actual = np.shape(getattr(self, name))
            wanted = tuple(sizes.get(d, a) if isinstance(d, str) else d for d, a in zip(shape, actual))
            if actual != wanted or len(actual) != len(shape):
                allowed = ", ".join(map(str, shape)) + ("," if len(shape) == 1 else "")
                raise ValueError(f"SceneFrame.{name} has shape {actual}; allowed: ({allowed}) "
                                 f"with N = {sizes['N']} disks, M = {sizes['M']} contacts")
        if self.ends is not None and np.shape(self.ends) != (sizes["M"], 2):
            raise ValueError(f"SceneFrame.ends has shape {np.shape(self.ends)}; allowed: ({sizes['M']}, 2), "
                             "two disks per contact")
        if self.watched_index is None:
            object.__setattr__(self, "watched_index", np.arange(len(self.watched)))
        elif np.shape(self.watched_index) != (len(self.watched),):
            raise ValueError(f"SceneFrame.watched_index has shape {np.shape(self.watched_index)}; allowed: "
                             f"({len(self.watched)},), one index per watched segment")
        if self.cell is not None and (len(self.cell) != 2 or not all(np.isfinite(self.cell))
                                      or min(self.cell) < 0.0):
            raise ValueError(f"SceneFrame.cell = {self.cell!r}; allowed: None or two finite lengths >= 0")


@dataclass(frozen=True)
class FrameData:
    """The arrays a frame is built from (a :class:`granlab.engine.simulation.Snapshot` or a run-file frame).

    ``pair (M, 2)`` with ``j >= N`` for wall ``j - N``; ``image (M, 2)``; ``wall_normal (W, 2)``
    and ``wall_offset (W,)`` (the line ``n · x = s``); ``cell (2,)`` periodic lengths (0 along an
    open axis).
    """

    positions: np.ndarray
    radii: np.ndarray
    angles: np.ndarray
    pair: np.ndarray
    image: np.ndarray
    status: np.ndarray
    normal_force: np.ndarray
    tangential_force: np.ndarray
    surface_gap: np.ndarray
    wall_normal: np.ndarray
    wall_offset: np.ndarray
    cell: np.ndarray

    @classmethod
    def from_simulation(cls, sim) -> "FrameData":
        """A copy of what a frame needs from a live :class:`granlab.engine.simulation.Simulation`: the
        disks and the contact rows in use (a fraction of a full snapshot's cost)."""
        p, table = sim.particles, sim.contacts
        status = sim.contact_status()
        rows = np.flatnonzero(status != STATUS_NONE)
        return cls(p.position.copy(), p.radius.copy(), p.angle.copy(),
                   np.column_stack([table.particle_i[rows], table.particle_j[rows]]), table.image[rows],
                   status[rows], table.normal_force[rows], table.tangential_force[rows],
                   table.surface_gap[rows], sim.walls.normal.copy(), sim.walls.offset.copy(),
                   np.where(np.array(sim.periodic), sim.cell.length, 0.0))

    @classmethod
    def from_snapshot(cls, snap) -> "FrameData":
        """What a frame needs from a :class:`granlab.engine.simulation.Snapshot` (its arrays are copies
        already: nothing is copied again)."""
        c = snap.contacts
        return cls(snap.positions, snap.radii, snap.angles, np.column_stack([c.i, c.j]), c.image, c.status,
                   c.normal_force, c.tangential_force, c.surface_gap, snap.wall_normals, snap.wall_offsets,
                   np.where(np.array(snap.periodic), snap.cell_lengths, 0.0))

    @classmethod
    def from_run_frame(cls, frame: dict, wall_normal: np.ndarray) -> "FrameData":
        """What a frame needs from a run-file frame (:func:`granlab.engine.io.h5md.read_frame`), with the
        walls' normals ``(W, 2)`` (from the file's parameters; the offsets are per frame)."""
        contacts = frame["contacts"]
        periodic = np.array([b == "periodic" for b in frame["boundary"]])
        offsets = np.asarray(frame.get("wall_position", np.zeros(len(wall_normal))), dtype=float)
        return cls(frame["position"], frame["radius"], frame["angle"], contacts["pair"].astype(np.int64),
                   contacts["image"].astype(np.int64), contacts["status"], contacts["normal_force"],
                   contacts["tangential_force"], contacts["surface_gap"], np.asarray(wall_normal, dtype=float),
                   offsets, np.where(periodic, frame["edges"], 0.0))


def _wall_segments(data: FrameData) -> np.ndarray:
    """Each wall's line clipped to the disks' bounding box, widened by two diameters."""
    if data.wall_offset.shape[0] == 0:
        return np.zeros((0, 2, 2))
    margin = 4.0 * float(data.radii.max())
    lo = data.positions.min(axis=0) - margin
    hi = data.positions.max(axis=0) + margin
    segments = []
    for normal, offset in zip(data.wall_normal, data.wall_offset):
        point = offset * normal
        tangent = np.array([-normal[1], normal[0]])
        lo_u, hi_u = -np.inf, np.inf
        for axis in range(2):
            if abs(tangent[axis]) > 1e-12:
                a = (lo[axis] - point[axis]) / tangent[axis]
                b = (hi[axis] - point[axis]) / tangent[axis]
                lo_u, hi_u = max(lo_u, min(a, b)), min(hi_u, max(a, b))
        if lo_u < hi_u:
            segments.append([point + lo_u * tangent, point + hi_u * tangent])
    return np.array(segments, dtype=float).reshape(-1, 2, 2)


def _rows_of(pair: np.ndarray, wanted) -> tuple[np.ndarray, np.ndarray]:
    """Rows of the pair table ``pair`` that are among the pairs ``wanted``, and the position of
    each one's pair in ``wanted``."""
    if not len(wanted) or not len(pair):
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    wanted = np.asarray(wanted, dtype=np.int64).reshape(-1, 2)
    codes = pair_codes(pair[:, 0], pair[:, 1])
    wanted_codes = pair_codes(wanted[:, 0], wanted[:, 1])
    rows = np.flatnonzero(np.isin(codes, wanted_codes))
    order = np.argsort(wanted_codes, kind="stable")
    return rows, order[np.searchsorted(wanted_codes, codes[rows], sorter=order)]


def _f64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


def _i64(a) -> np.ndarray:
    """Integers as int64: live tables (int32, int8) and run files give one compiled signature of
    :func:`contact_fields` (a new one would compile for seconds on the scene thread)."""
    return np.ascontiguousarray(a, dtype=np.int64)


def group_labels(positions: np.ndarray, radii: np.ndarray, groups) -> tuple[tuple[str, float, float], ...]:
    """(text, x, y) of a label under each group of disks: ``groups`` lists (text, number of disks)
    of consecutive disks; each label is centred under its group, half a mean radius below it."""
    labels, start = [], 0
    gap = 0.5 * float(radii.mean()) if len(radii) else 0.0
    for text, count in groups:
        x, r = positions[start:start + count, 0], radii[start:start + count]
        bottom = positions[start:start + count, 1] - r
        if count and text:
            labels.append((str(text), float(0.5 * ((x - r).min() + (x + r).max())), float(bottom.min()) - gap))
        start += count
    return tuple(labels)


def build_frame(parts: list[tuple[FrameData, tuple[float, float]]],
                watched: list[list[tuple[int, int]]] | None = None, groups=()) -> SceneFrame:
    """A scene frame of one or more states drawn side by side (each shifted by its offset).

    ``watched[k]`` lists the pairs (i, j) of part k to highlight; ``groups`` names groups of
    consecutive disks (:func:`group_labels`). The per-disk and per-contact fields are filled by one
    compiled pass over each part's contact table (the GIL released).
    """
    watched = watched or [[] for _ in parts]
    n_total = sum(data.positions.shape[0] for data, _ in parts)
    m_total = sum(data.pair.shape[0] for data, _ in parts)
    coordination = np.zeros(n_total, dtype=np.int64)
    pressure = np.zeros(n_total)
    sliding = np.zeros(n_total, dtype=np.bool_)
    segments = np.empty((m_total, 2, 2))
    ends = np.empty((m_total, 2), dtype=np.int64)
    force = np.empty(m_total)
    kind = np.empty(m_total, dtype=np.int8)
    positions, walls, watched_segments, watched_index = [], [], [], []
    cell = None
    n0 = m0 = w0 = 0
    for (data, offset), pairs in zip(parts, watched):
        shift = np.asarray(offset, dtype=float)
        n, m = data.positions.shape[0], data.pair.shape[0]
        contact_fields(_f64(data.positions), _f64(data.radii), _i64(data.pair), _i64(data.image), _i64(data.status),
                       _f64(data.normal_force), _f64(data.tangential_force), _f64(data.surface_gap),
                       _f64(data.wall_normal).reshape(-1, 2), _f64(data.cell), shift, coordination[n0:n0 + n],
                       pressure[n0:n0 + n], sliding[n0:n0 + n], segments[m0:m0 + m], force[m0:m0 + m],
                       kind[m0:m0 + m])
        ends[m0:m0 + m, 0] = data.pair[:, 0] + n0
        ends[m0:m0 + m, 1] = np.where(data.pair[:, 1] < n, data.pair[:, 1] + n0, n - 1 - w0 - data.pair[:, 1])
        positions.append(data.positions + shift)
        walls.append(_wall_segments(data) + shift)
        rows, index = _rows_of(data.pair, pairs)
        watched_segments.append(segments[m0 + rows])
        watched_index.append(index)
        if data.cell.any() and len(parts) == 1:
            cell = (float(data.cell[0]), float(data.cell[1]))
        n0, m0, w0 = n0 + n, m0 + m, w0 + data.wall_normal.reshape(-1, 2).shape[0]
    positions, radii = np.concatenate(positions), np.concatenate([d.radii for d, _ in parts])
    return SceneFrame(positions=positions, radii=radii,
                      angles=np.concatenate([d.angles for d, _ in parts]), coordination=coordination,
                      pressure=pressure, sliding=sliding, contacts=segments, contact_force=force,
                      contact_kind=kind, walls=np.concatenate(walls).reshape(-1, 2, 2), cell=cell,
                      watched=np.concatenate(watched_segments).reshape(-1, 2, 2),
                      watched_index=np.concatenate(watched_index).astype(np.int64),
                      labels=group_labels(positions, radii, groups), ends=ends)


def meeting_walls(normals: np.ndarray, offsets: np.ndarray, positions: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """(W, 2, 2) each wall ``n · x = s`` as a segment across the disks and the other walls, ending
    where they end (a box's walls meet at its corners); NaN where a wall misses that region."""
    lo = (positions - radii[:, None]).min(axis=0)
    hi = (positions + radii[:, None]).max(axis=0)
    for normal, offset in zip(normals, offsets):
        for axis in range(2):
            if abs(abs(normal[axis]) - 1.0) < 1e-12:  # a wall across this axis bounds the region along it
                lo[axis], hi[axis] = min(lo[axis], offset * normal[axis]), max(hi[axis], offset * normal[axis])
    segments = np.full((len(normals), 2, 2), np.nan)
    for k, (normal, offset) in enumerate(zip(normals, offsets)):
        point, tangent = offset * normal, np.array([-normal[1], normal[0]])
        ends = [-np.inf, np.inf]
        for axis in range(2):
            if abs(tangent[axis]) > 1e-12:
                a, b = sorted(((lo[axis] - point[axis]) / tangent[axis], (hi[axis] - point[axis]) / tangent[axis]))
                ends = [max(ends[0], a), min(ends[1], b)]
            elif not lo[axis] <= point[axis] <= hi[axis]:
                ends = [1.0, 0.0]
        if ends[0] < ends[1]:
            segments[k] = [point + ends[0] * tangent, point + ends[1] * tangent]
    return segments


def cell_outline(cell: tuple[float, float]) -> np.ndarray:
    """(4, 2, 2) edges of the rectangle [0, Lx] x [0, Ly]."""
    lx, ly = cell
    corners = np.array([(0.0, 0.0), (lx, 0.0), (lx, ly), (0.0, ly)])
    return np.stack([corners, np.roll(corners, -1, axis=0)], axis=1)
