"""The state the analyses read: from a live simulation, a GranLab run file or any H5MD file.

:class:`PackingState` holds what :mod:`engine.analysis.stiffness`, :mod:`engine.analysis.packing` and
:mod:`engine.analysis.fractal` need, under the attribute names of
:class:`engine.simulation.Snapshot` (so a snapshot serves as well).

A GranLab run file gives everything, contact forces and statuses included; the contact law and
the wall modes of the frame come from ``/observables/law`` and ``/observables/walls/mode`` (files
written before those existed: from ``/parameters``). Any other H5MD file needs positions, radii
(a ``radius`` or ``diameter`` element) and a 2D box; its contacts are found from the geometry
(pairs closer than ``gap`` are touching, status non-sliding) and it has no forces.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
from scipy.spatial import cKDTree

from ..errors import GranLabError
from ..io.h5md import RunFileError, open_run, parameters, read_frame, walls_from_json
from ..params import WALL_MODES, ContactLaw
from ..simulation import ContactSnapshot, Snapshot
from ..state import STATUS_STICK

CONTACT_GAP = 1e-6
"""Generic H5MD files: disks closer than this fraction of the mean diameter touch."""


@dataclass(frozen=True)
class PackingState:
    """One state as the analyses read it. ``forces_known`` is false for a generic H5MD file
    (contacts from the geometry, forces zero); ``source`` says where it came from."""

    positions: np.ndarray
    radii: np.ndarray
    contacts: ContactSnapshot
    law: ContactLaw
    wall_names: tuple[str, ...]
    wall_normals: np.ndarray
    wall_offsets: np.ndarray
    wall_forces: np.ndarray
    wall_modes: tuple[str, ...]
    cell_lengths: np.ndarray
    box_lengths: np.ndarray
    periodic: tuple[bool, bool]
    stress: np.ndarray
    time: float
    step: int
    forces_known: bool
    source: str

    @classmethod
    def from_snapshot(cls, snap: Snapshot, source: str = "simulation") -> "PackingState":
        return cls(snap.positions, snap.radii, snap.contacts, snap.law, tuple(snap.wall_names),
                   np.asarray(snap.wall_normals), np.asarray(snap.wall_offsets), np.asarray(snap.wall_forces),
                   tuple(snap.wall_modes), np.asarray(snap.cell_lengths), np.asarray(snap.box_lengths),
                   tuple(snap.periodic), np.asarray(snap.stress), float(snap.time), int(snap.step), True, source)

    @property
    def disks(self) -> int:
        return int(self.radii.shape[0])


def read_state(path: str | Path, frame: int = -1, friction: float | None = None,
               gap: float = CONTACT_GAP) -> PackingState:
    """Frame ``frame`` (negative counts from the end) of a GranLab run file or an H5MD file.
    ``friction`` replaces the law's friction (for a generic file the law is otherwise the
    default :class:`ContactLaw`); ``gap`` is the contact tolerance of generic files."""
    with open_run(path) as f:
        if "h5md" not in f or "particles" not in f:
            raise RunFileError(f"{str(path)!r} is not an H5MD file: it has no /h5md and /particles groups")
        creator = f["h5md/creator"].attrs.get("name", "") if "h5md/creator" in f else ""
        if isinstance(creator, bytes):
            creator = creator.decode()
        if creator == "GranLab" and "contacts/offset" in f:
            state = _granlab_state(f, frame, str(path))
        else:
            state = _generic_state(f, frame, str(path), gap)
    if state.disks == 0:
        raise RunFileError(f"frame {frame} of {str(path)!r} holds no disks: nothing to analyse")
    _check_finite(state)
    if friction is not None:
        state = dataclasses.replace(state, law=state.law.replace(friction=friction))
    return state


def _check_finite(state: PackingState) -> None:
    """A frame written as a run diverged holds NaN or infinite values: every analysis of it would
    be meaningless (a singular stiffness matrix, numbers from NaN), so it is refused by name."""
    bad = np.flatnonzero(~np.all(np.isfinite(state.positions), axis=1) | ~(np.isfinite(state.radii) & (state.radii > 0)))
    if bad.size:
        shown = ", ".join(str(i) for i in bad[:5]) + (f" and {bad.size - 5} more" if bad.size > 5 else "")
        raise RunFileError(f"{state.source} has non-finite positions or radii (disk {shown} of {state.disks}): "
                           "the run had diverged when it was written; analyse an earlier frame (--frame)")
    if not (np.all(np.isfinite(state.box_lengths)) and np.all(np.isfinite(state.cell_lengths))):
        raise RunFileError(f"{state.source} has a non-finite box: the run had diverged when it was written; "
                           "analyse an earlier frame (--frame)")


def _granlab_state(f: h5py.File, index: int, path: str) -> PackingState:
    frame = read_frame(f, index)
    params = parameters(f)
    walls = walls_from_json(params["walls_json"])
    law = ContactLaw(**json.loads(frame.get("law_json", params["law_json"])))
    modes = tuple(WALL_MODES[m] for m in frame["wall_mode"]) if "wall_mode" in frame else tuple(w.mode for w in walls)
    c = frame["contacts"]
    contacts = ContactSnapshot(
        i=c["pair"][:, 0].astype(np.int64), j=c["pair"][:, 1].astype(np.int64), image=c["image"].astype(np.int64),
        status=c["status"].astype(np.int8), normal_force=c["normal_force"],
        elastic_normal_force=c["elastic_normal_force"], tangential_force=c["tangential_force"],
        surface_gap=c["surface_gap"], tangential_spring=c["tangential_spring"], rolling_spring=c["rolling_spring"],
        rolling_distance=c["rolling_distance"])
    periodic = tuple(b == "periodic" for b in frame["boundary"])
    nw = len(walls)
    return PackingState(
        frame["position"], frame["radius"], contacts, law, tuple(w.name for w in walls),
        np.array([w.normal for w in walls], dtype=float).reshape(nw, 2),
        np.asarray(frame.get("wall_position", [w.position for w in walls]), dtype=float),
        np.asarray(frame.get("wall_force", np.zeros(nw)), dtype=float), modes,
        np.asarray(frame["edges"], dtype=float), np.asarray(frame["edges"], dtype=float), periodic,
        np.asarray(frame.get("stress", np.zeros((2, 2))), dtype=float), frame["time"], frame["step"],
        True, f"{path} frame {frame['index']}")


def _particle_group(f: h5py.File, path: str) -> h5py.Group:
    groups = [name for name in f["particles"] if isinstance(f["particles"][name], h5py.Group)]
    if not groups:
        raise RunFileError(f"{path!r} has no particle group under /particles")
    if len(groups) > 1 and "all" not in groups:
        raise RunFileError(f"{path!r} has several particle groups ({', '.join(groups)}) and none named 'all'")
    return f["particles"]["all" if "all" in groups else groups[0]]


def _element(group: h5py.Group, name: str, index: int, frames: int):
    """Frame ``index`` of an H5MD element: a time-dependent group (``value``) or a fixed dataset."""
    element = group[name]
    if isinstance(element, h5py.Group):
        values = element["value"]
        return values[index] if values.shape[0] == frames else values[-1]
    return element[()]


def _generic_state(f: h5py.File, index: int, path: str, gap: float) -> PackingState:
    group = _particle_group(f, path)
    if "position" not in group:
        raise RunFileError(f"{path!r} has no position element in {group.name}: not an H5MD particle file")
    if "box" not in group:
        raise RunFileError(f"{path!r} has no box in {group.name}: a 2D box is needed")
    box = group["box"]
    if int(box.attrs.get("dimension", 0)) != 2:
        raise RunFileError(f"{path!r}: the box has dimension {box.attrs.get('dimension')}; only 2D boxes can be analysed")
    position = group["position"]
    frames = position["value"].shape[0] if isinstance(position, h5py.Group) else 1
    if frames == 0:
        raise RunFileError(f"{path!r} holds no frame")
    if not -frames <= index < frames:
        raise RunFileError(f"frame {index} is out of range: {path!r} holds frames 0..{frames - 1}")
    index %= frames
    positions = np.asarray(_element(group, "position", index, frames), dtype=float)
    if positions.ndim != 2 or positions.shape[1] != 2:
        raise RunFileError(f"{path!r}: positions have shape {positions.shape}; (N, 2) is needed")
    if "radius" in group:
        radii = np.asarray(_element(group, "radius", index, frames), dtype=float)
    elif "diameter" in group:
        radii = 0.5 * np.asarray(_element(group, "diameter", index, frames), dtype=float)
    else:
        raise RunFileError(f"{path!r} has no radius or diameter element in {group.name}: disk sizes are needed")
    if positions.shape[0] == 0:
        raise RunFileError(f"frame {index} of {path!r} holds no disks: nothing to analyse")
    radii = np.broadcast_to(radii, positions.shape[:1]).astype(float)
    edges = np.asarray(_element(box, "edges", index, frames), dtype=float)
    if edges.shape == (2, 2):
        if edges[0, 1] != 0.0 or edges[1, 0] != 0.0:
            raise RunFileError(f"{path!r}: the box is triclinic; only rectangular boxes can be analysed")
        edges = np.diag(edges).copy()
    if edges.shape != (2,) or not np.all(edges > 0):
        raise RunFileError(f"{path!r}: box edges {edges.tolist()} are not two positive lengths")
    boundary = [b.decode() if isinstance(b, bytes) else str(b) for b in box.attrs.get("boundary", ["none", "none"])]
    periodic = tuple(b == "periodic" for b in boundary)
    contacts = geometric_contacts(positions, radii, edges, periodic, gap)
    step = int(group["position/step"][index]) if isinstance(position, h5py.Group) else 0
    time = float(group["position/time"][index]) if isinstance(position, h5py.Group) and "time" in position else 0.0
    return PackingState(positions, radii, contacts, ContactLaw(), (), np.zeros((0, 2)), np.zeros(0), np.zeros(0), (),
                        edges, edges, periodic, np.zeros((2, 2)), time, step, False, f"{path} frame {index}")


def geometric_contacts(positions: np.ndarray, radii: np.ndarray, lengths: np.ndarray, periodic: tuple[bool, bool],
                       gap: float = CONTACT_GAP) -> ContactSnapshot:
    """Touching pairs (surface gap below ``gap`` times the mean diameter) with their periodic
    images, as non-sliding contacts carrying no force."""
    lengths = np.asarray(lengths, dtype=float)
    wrap = np.array(periodic, dtype=bool)
    x = np.asarray(positions, dtype=float).copy()
    x[:, wrap] = np.mod(x[:, wrap], lengths[wrap])
    tolerance = gap * 2.0 * float(radii.mean())
    x[:, ~wrap] -= x.min(axis=0)[~wrap]
    span = np.where(wrap, lengths, 3.0 * (x.max(axis=0) + 1.0))
    tree = cKDTree(x, boxsize=span)
    pairs = tree.query_pairs(2.0 * float(radii.max(initial=0.0)) + tolerance, output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    delta = positions[i] - positions[j]
    image = np.where(wrap, np.round(delta / lengths), 0.0)
    branch = delta - image * lengths
    surface = np.hypot(branch[:, 0], branch[:, 1]) - radii[i] - radii[j]
    keep = surface <= tolerance
    m = int(np.count_nonzero(keep))
    zeros = np.zeros(m)
    return ContactSnapshot(i=i[keep].astype(np.int64), j=j[keep].astype(np.int64),
                           image=image[keep].astype(np.int64), status=np.full(m, STATUS_STICK, dtype=np.int8),
                           normal_force=zeros, elastic_normal_force=zeros, tangential_force=zeros,
                           surface_gap=surface[keep], tangential_spring=zeros, rolling_spring=zeros,
                           rolling_distance=zeros)


def require_forces(state: PackingState, analysis: str) -> None:
    """Stop an analysis that needs contact forces on a state that has none."""
    if not state.forces_known:
        raise GranLabError(f"{analysis} needs contact forces and statuses, which {state.source} does not hold "
                           f"(a generic H5MD file: contacts are found from the geometry); use a GranLab run file")
