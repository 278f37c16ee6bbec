"""Scene frames: what the 3D view draws, computed from a simulation state (or a run-file frame).

Everything here is numpy over arrays the engine thread copied: building a frame never touches
the live simulation, so the scene thread can draw it while the engine runs on.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from engine.state import STATUS_COHESIVE, STATUS_SLIDE_NEG, STATUS_SLIDE_POS, STATUS_STICK

from .scene import SceneFrame


@dataclass(frozen=True)
class FrameData:
    """The arrays a frame is built from (a :class:`engine.simulation.Snapshot` or a run-file frame).

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
    def from_snapshot(cls, snap) -> "FrameData":
        c = snap.contacts
        return cls(snap.positions, snap.radii, snap.angles, np.column_stack([c.i, c.j]), c.image, c.status,
                   c.normal_force, c.tangential_force, c.surface_gap, snap.wall_normals, snap.wall_offsets,
                   np.where(np.array(snap.periodic), snap.cell_lengths, 0.0))


def _contact_geometry(data: FrameData):
    """Segments from each disk's centre to its partner (the periodic image next to it) or to the wall."""
    n = data.positions.shape[0]
    i, j = data.pair[:, 0], data.pair[:, 1]
    start = data.positions[i]
    end = np.empty_like(start)
    pair = j < n
    jj = j[pair]
    end[pair] = data.positions[jj] + data.image[pair] * data.cell
    wall = ~pair
    if wall.any():
        w = j[wall] - n
        normal = data.wall_normal[w]
        distance = data.radii[i[wall]] + data.surface_gap[wall]
        end[wall] = start[wall] - distance[:, None] * normal
    return np.stack([start, end], axis=1)


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


def _rows_of(pair: np.ndarray, wanted) -> np.ndarray:
    """Rows of the pair table ``pair`` that are among the pairs ``wanted``."""
    if not len(wanted) or not len(pair):
        return np.zeros(0, dtype=np.int64)
    wanted = np.asarray(wanted, dtype=np.int64).reshape(-1, 2)
    base = int(max(pair.max(), wanted.max())) + 1
    codes = pair[:, 0].astype(np.int64) * base + pair[:, 1]
    return np.flatnonzero(np.isin(codes, wanted[:, 0] * base + wanted[:, 1]))


def build_frame(parts: list[tuple[FrameData, tuple[float, float]]],
                watched: list[list[tuple[int, int]]] | None = None) -> SceneFrame:
    """A scene frame of one or more states drawn side by side (each shifted by its offset).

    ``watched[k]`` lists the pairs (i, j) of part k to highlight.
    """
    watched = watched or [[] for _ in parts]
    arrays = {key: [] for key in ("positions", "radii", "angles", "coordination", "pressure", "sliding", "contacts",
                                  "force", "kind", "walls", "watched")}
    cell = None
    for (data, offset), pairs in zip(parts, watched):
        shift = np.asarray(offset, dtype=float)
        n = data.positions.shape[0]
        touching = np.isin(data.status, (STATUS_STICK, STATUS_SLIDE_POS, STATUS_SLIDE_NEG))
        sliding = np.isin(data.status, (STATUS_SLIDE_POS, STATUS_SLIDE_NEG))
        i, j = data.pair[:, 0], data.pair[:, 1]
        disk_pair = j < n
        coordination = np.bincount(i[touching], minlength=n) + np.bincount(j[touching & disk_pair], minlength=n)
        load = np.abs(data.normal_force)
        pressure = (np.bincount(i, weights=load, minlength=n)
                    + np.bincount(j[disk_pair], weights=load[disk_pair], minlength=n)) / (2 * np.pi * data.radii)
        slides = np.zeros(n, dtype=bool)
        slides[i[sliding]] = True
        slides[j[sliding & disk_pair]] = True
        segments = _contact_geometry(data) + shift
        kind = np.where(sliding, 2, np.where((data.normal_force < 0) | (data.status == STATUS_COHESIVE), 1, 0))
        arrays["positions"].append(data.positions + shift)
        arrays["radii"].append(data.radii)
        arrays["angles"].append(data.angles)
        arrays["coordination"].append(coordination)
        arrays["pressure"].append(pressure)
        arrays["sliding"].append(slides)
        arrays["contacts"].append(segments)
        arrays["force"].append(np.hypot(data.normal_force, data.tangential_force))
        arrays["kind"].append(kind.astype(np.int8))
        arrays["walls"].append(_wall_segments(data) + shift)
        arrays["watched"].append(segments[_rows_of(data.pair, pairs)].reshape(-1, 2, 2))
        if data.cell.any() and len(parts) == 1:
            cell = (float(data.cell[0]), float(data.cell[1]))
    joined = {key: np.concatenate(value) for key, value in arrays.items()}
    return SceneFrame(positions=joined["positions"], radii=joined["radii"], angles=joined["angles"],
                      coordination=joined["coordination"].astype(np.int64), pressure=joined["pressure"],
                      sliding=joined["sliding"], contacts=joined["contacts"].reshape(-1, 2, 2),
                      contact_force=joined["force"], contact_kind=joined["kind"],
                      walls=joined["walls"].reshape(-1, 2, 2), cell=cell, watched=joined["watched"].reshape(-1, 2, 2))
