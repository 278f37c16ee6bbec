"""The state the analyses read: from a live simulation, a GranLab run file, any H5MD file, a
LAMMPS dump or an extended XYZ file.

:class:`PackingState` holds what :mod:`granlab.engine.analysis.stiffness`, :mod:`granlab.engine.analysis.packing` and
:mod:`granlab.engine.analysis.fractal` need, under the attribute names of
:class:`granlab.engine.simulation.Snapshot` (so a snapshot serves as well).

A GranLab run file gives everything, contact forces and statuses included; the contact law and
the wall modes of the frame come from ``/observables/law`` and ``/observables/walls/mode`` (files
written before those existed: from ``/parameters``). Any other H5MD file needs positions, radii
(a ``radius`` or ``diameter`` element) and a 2D box; so does an extended XYZ file (a ``radius``
or ``diameter`` column, ``Lattice`` and ``pbc``) and a LAMMPS ``dump custom`` (``id``, ``x``,
``y``, ``radius`` or ``diameter``; the box and its periodicity from its header). A 3D file whose
disks all lie in one plane z = const is read as 2D. Their contacts are found from the geometry
(pairs closer than ``gap`` are touching, status non-sliding) and they have no forces, except a
LAMMPS dump given with a ``dump local`` of its contacts (:func:`lammps_contacts`): there the
forces are LAMMPS's, and a contact whose tangential force is on the Coulomb cone is sliding.
Other codes' files carry no contact law: it is :class:`ContactLaw`'s default, or what ``law`` says.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
from scipy.spatial import cKDTree

from ..errors import GranLabError
from ..io.extxyz import DIAMETER_NAMES, RADIUS_NAMES, XYZFrame, read_xyz_frames
from ..io.h5md import RunFileError, cell_control_of, frame_count, open_run, read_frame, run_law, run_walls
from ..io.inputs import require_file
from ..io.lammps import ATOM_ITEM, LOCAL_ITEM, Dump
from ..params import WALL_MODES, ContactLaw
from ..simulation import ContactSnapshot, Snapshot
from ..state import HUGE, STATUS_SLIDE_NEG, STATUS_SLIDE_POS, STATUS_STICK

CONTACT_GAP = 1e-6
"""Generic H5MD files: disks closer than this fraction of the mean diameter touch."""


@dataclass(frozen=True)
class PackingState:
    """One state as the analyses read it. ``forces_known`` is false for a generic H5MD file
    (contacts from the geometry, forces zero); ``source`` says where it came from; ``law_given``
    is false when the file carries no contact law (the law is then assumed)."""

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
    law_given: bool = True
    cell_control: tuple[str, ...] = ()
    """Per axis ``"none"`` or the cell's control; empty: a fixed cell (as in other codes' files)."""
    cell_target_stress: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(2))

    @classmethod
    def from_snapshot(cls, snap: Snapshot, source: str = "simulation") -> "PackingState":
        return cls(snap.positions, snap.radii, snap.contacts, snap.law, tuple(snap.wall_names),
                   np.asarray(snap.wall_normals), np.asarray(snap.wall_offsets), np.asarray(snap.wall_forces),
                   tuple(snap.wall_modes), np.asarray(snap.cell_lengths), np.asarray(snap.box_lengths),
                   tuple(snap.periodic), np.asarray(snap.stress), float(snap.time), int(snap.step), True, source,
                   cell_control=tuple(snap.cell_control), cell_target_stress=np.asarray(snap.cell_target_stress))

    @property
    def disks(self) -> int:
        return int(self.radii.shape[0])


FORMATS = ("h5md", "lammps", "xyz")
"""The formats :func:`read_state` reads: H5MD (GranLab's run files included), LAMMPS text dumps,
extended XYZ."""

SLIDING_TOLERANCE = 1e-6
"""A contact read from another code slides when |F_t| >= (1 - this) mu F_n (the same tolerance as
:func:`granlab.engine.analysis.status.critical_contacts`)."""

CONTACT_NAMES = {"id1": ("id1", "patom1"), "id2": ("id2", "patom2"), "fx": ("fx", "fnx"), "fy": ("fy", "fny"),
                 "ftx": ("ftx",), "fty": ("fty",)}
"""What the columns of a contacts dump may be called (``dump_modify colname``), by meaning: the two
atom ids, and the force on the first atom, as a vector ``(fx, fy)`` (or ``(fnx, fny)``) plus, when the pair style
gives it apart (granular styles give the normal part as fx, fy and the tangential part as the
first extra values p1, p2), ``(ftx, fty)``."""


def detect_format(path: str | Path) -> str:
    """The format of ``path`` among :data:`FORMATS`, from its first bytes (a file named ``.h5``,
    ``.hdf5`` or ``.h5md`` is H5MD, so that a broken one is named as a broken HDF5 file)."""
    path = Path(path)
    require_file(path, "file", RunFileError)
    if path.suffix.lower() in (".h5", ".hdf5", ".h5md") or h5py.is_hdf5(path):
        return "h5md"
    with open(path, "rb") as f:
        lines = f.read(1024).split(b"\n")
    if lines[0].strip().startswith(b"ITEM:"):
        return "lammps"
    if lines[0].strip().isdigit() and len(lines) > 1:
        return "xyz"
    raise RunFileError(f"{str(path)!r} is neither an H5MD file, a LAMMPS text dump (first line 'ITEM: ...') nor an "
                       f"extended XYZ file (first line the number of particles)")


def read_state(path: str | Path, frame: int = -1, law: dict | None = None, gap: float = CONTACT_GAP,
               contacts: str | Path | None = None, contact_columns: tuple[str, ...] | None = None) -> PackingState:
    """Frame ``frame`` (negative counts from the end) of a file of :data:`FORMATS`.

    ``law``: values of :class:`ContactLaw` to use instead of the file's (another code's file has
    none: :class:`ContactLaw`'s default otherwise); ``gap`` the contact tolerance of files without
    contacts; ``contacts`` a LAMMPS ``dump local`` of the contacts of a LAMMPS dump, its columns
    named as in :data:`CONTACT_NAMES` or by ``contact_columns`` (one name per column, ``-`` for a
    column to leave out)."""
    reader = StateReader(path, law, gap, contacts, contact_columns)
    return reader.read(reader.index(frame))


def read_states(path: str | Path, **options) -> list[PackingState]:
    """Every frame of a file, each file read (or indexed) once; ``options`` as :func:`read_state`'s."""
    reader = StateReader(path, **options)
    return [reader.read(k) for k in range(reader.count)]


class StateReader:
    """The frames of one file of :data:`FORMATS` (arguments as :func:`read_state`'s): ``count``
    frames, :meth:`read` one."""

    def __init__(self, path: str | Path, law: dict | None = None, gap: float = CONTACT_GAP,
                 contacts: str | Path | None = None, contact_columns: tuple[str, ...] | None = None):
        self.path, self.law, self.gap, self.contact_columns = path, law or {}, gap, contact_columns
        self.kind = detect_format(path)
        if contacts is not None and self.kind != "lammps":
            raise RunFileError(f"contacts from {str(contacts)!r} go with a LAMMPS dump, and {str(path)!r} is "
                               f"{'an H5MD' if self.kind == 'h5md' else 'an extended XYZ'} file")
        if self.kind == "lammps":
            self.dump = Dump(path, ATOM_ITEM)
            self.contacts = None if contacts is None else Dump(contacts, LOCAL_ITEM)
            self.count = len(self.dump)
        elif self.kind == "xyz":
            self.frames = read_xyz_frames(path)
            self.count = len(self.frames)
        else:
            self.count = _h5md_frames(path)

    def index(self, frame: int) -> int:
        """``frame`` (negative counts from the end) checked against the file's frames."""
        if not -self.count <= frame < self.count:
            raise RunFileError(f"frame {frame} is out of range: {self.path} holds frames 0..{self.count - 1}")
        return frame % self.count

    def read(self, index: int) -> PackingState:
        if self.kind == "lammps":
            state = _lammps_state(self.dump, index, self.law, self.gap, self.contacts, self.contact_columns)
        elif self.kind == "xyz":
            state = _xyz_state(self.frames[index], self.path, self.law, self.gap)
        else:
            state = _h5md_state(self.path, index, self.gap)
            if self.law:
                state = dataclasses.replace(state, law=state.law.replace(**self.law))
        if state.disks == 0:
            raise RunFileError(f"{state.source} holds no disks: nothing to analyse")
        _check_finite(state)
        return state


def _h5md_frames(path: str | Path) -> int:
    """Frames of an H5MD file: complete frames of a GranLab run file, else of its position element."""
    with open_run(path) as f:
        if "h5md" not in f or "particles" not in f:
            raise RunFileError(f"{str(path)!r} is not an H5MD file: it has no /h5md and /particles groups")
        if "contacts/offset" in f:
            return frame_count(f)
        group = _particle_group(f, str(path))
        if "position" not in group:
            raise RunFileError(f"{str(path)!r} has no position element in {group.name}: not an H5MD particle file")
        return _frames_of(group["position"], str(path))


def _h5md_state(path: str | Path, frame: int, gap: float) -> PackingState:
    with open_run(path) as f:
        if "h5md" not in f or "particles" not in f:
            raise RunFileError(f"{str(path)!r} is not an H5MD file: it has no /h5md and /particles groups")
        creator = f["h5md/creator"].attrs.get("name", "") if "h5md/creator" in f else ""
        if isinstance(creator, bytes):
            creator = creator.decode()
        if creator == "GranLab" and "contacts/offset" in f:
            return _granlab_state(f, frame, str(path))
        return _generic_state(f, frame, str(path), gap)


def _check_finite(state: PackingState) -> None:
    _refuse_non_finite(state.source, state.positions, state.radii, np.concatenate([state.box_lengths,
                                                                                   state.cell_lengths]))


DECLARED_SIZE_FACTOR = 64
"""A foreign H5MD dataset may declare at most this many times its file's size (compression of
floating-point positions gains far less): a larger one is damaged, and reading it would exhaust memory."""


def _refuse_non_finite(source: str, positions: np.ndarray, radii: np.ndarray, lengths: np.ndarray) -> None:
    """NaN or infinite values (a run that diverged writes them; so does a careless edit) would make
    every analysis meaningless (a singular stiffness matrix, numbers from NaN): refused by name,
    before any geometry is built from them."""
    bad = np.flatnonzero(~np.all(np.abs(positions) < HUGE, axis=1) | ~((radii < HUGE) & (radii > 0)))
    if bad.size:
        shown = ", ".join(str(i) for i in bad[:5]) + (f" and {bad.size - 5} more" if bad.size > 5 else "")
        raise RunFileError(f"{source} has non-finite or huge (> 1e150) positions or radii, or radii not > 0 (disk "
                           f"{shown} of {positions.shape[0]}): a run that diverged writes NaN; analyse an earlier "
                           f"frame (--frame)")
    if not np.all(np.abs(lengths) < HUGE):
        raise RunFileError(f"{source} has a non-finite or huge box ({np.asarray(lengths).tolist()}): a run that diverged "
                           f"writes NaN; analyse an earlier frame (--frame)")


def _granlab_state(f: h5py.File, index: int, path: str) -> PackingState:
    frame = read_frame(f, index)
    walls, law = run_walls(f), run_law(f, frame.get("law_json"))
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
        True, f"{path} frame {frame['index']}", cell_control=cell_control_of(frame, periodic),
        cell_target_stress=np.asarray(frame.get("cell_target_stress", np.zeros(2)), dtype=float))


def _particle_group(f: h5py.File, path: str) -> h5py.Group:
    groups = [name for name in f["particles"] if isinstance(f["particles"][name], h5py.Group)]
    if not groups:
        raise RunFileError(f"{path!r} has no particle group under /particles")
    if len(groups) > 1 and "all" not in groups:
        raise RunFileError(f"{path!r} has several particle groups ({', '.join(groups)}) and none named 'all'")
    return f["particles"]["all" if "all" in groups else groups[0]]


def _element(group: h5py.Group, name: str, index: int, frames: int):
    """Frame ``index`` of an H5MD element: a time-dependent group (``value``) or a fixed dataset,
    its declared size checked against the file's first."""
    element = group[name]
    values = element["value"] if isinstance(element, h5py.Group) else element
    per_frame = values.size // max(values.shape[0], 1) if isinstance(element, h5py.Group) else values.size
    declared = per_frame * values.dtype.itemsize
    size = os.path.getsize(group.file.filename)
    if declared > DECLARED_SIZE_FACTOR * size + 2 ** 20:
        raise RunFileError(f"{group.file.filename!r}: {values.name} declares shape {values.shape}, "
                           f"{declared / 2 ** 20:.4g} MiB a frame, in a file of {size / 2 ** 20:.4g} MiB: damaged or "
                           f"not what it says (at most {DECLARED_SIZE_FACTOR} times the file's size is read)")
    if isinstance(element, h5py.Group):
        return values[index] if values.shape[0] == frames else values[-1]
    return element[()]


def _frames_of(position, path: str) -> int:
    """Frames of an H5MD position element: a group whose ``value`` is a (frames, N, dimension)
    dataset, or a fixed (N, dimension) dataset (one frame)."""
    values = position.get("value") if isinstance(position, h5py.Group) else position
    if not isinstance(values, h5py.Dataset) or values.ndim != (3 if isinstance(position, h5py.Group) else 2):
        found = "missing" if values is None else "a group" if isinstance(values, h5py.Group) else \
            f"of shape {values.shape}"
        raise RunFileError(f"{path!r}: {position.name}{'/value' if isinstance(position, h5py.Group) else ''} is "
                           f"{found}; a dataset of shape (frames, N, dimension) is needed (H5MD's time-dependent "
                           f"position)")
    return values.shape[0] if isinstance(position, h5py.Group) else 1


def _sampled(position: h5py.Group, name: str, index: int, frames: int, path: str) -> float:
    """Frame ``index``'s ``step`` or ``time`` of an H5MD element: one number per frame, or H5MD's
    fixed interval (a scalar, from its ``offset``)."""
    data = position.get(name)
    if not isinstance(data, h5py.Dataset) or data.dtype.kind not in "iuf" or data.shape not in ((), (frames,)):
        shape = "missing" if data is None else "a group" if isinstance(data, h5py.Group) else \
            f"{data.dtype} of shape {data.shape}"
        raise RunFileError(f"{path!r}: {position.name}/{name} is {shape}; numbers, one per frame ({frames}) or one "
                           f"fixed interval, are needed")
    offset = data.attrs.get("offset", 0)
    if not isinstance(offset, (int, float, np.integer, np.floating)):
        raise RunFileError(f"{path!r}: {position.name}/{name}'s offset is {offset!r}; a number is needed")
    value = float(data[()] * index + offset) if data.shape == () else float(data[index])
    if not math.isfinite(value):
        raise RunFileError(f"{path!r}: {position.name}/{name} of frame {index} is {value}; a finite number is needed")
    return value


def _generic_state(f: h5py.File, index: int, path: str, gap: float) -> PackingState:
    group = _particle_group(f, path)
    if "position" not in group:
        raise RunFileError(f"{path!r} has no position element in {group.name}: not an H5MD particle file")
    if "box" not in group:
        raise RunFileError(f"{path!r} has no box in {group.name}: a 2D box is needed")
    box = group["box"]
    dimension = int(box.attrs.get("dimension", 0))
    if dimension not in (2, 3):
        raise RunFileError(f"{path!r}: the box has dimension {box.attrs.get('dimension')}; 2D boxes (or 3D ones whose "
                           f"disks lie in one plane) can be analysed")
    position = group["position"]
    frames = _frames_of(position, path)
    if frames == 0:
        raise RunFileError(f"{path!r} holds no frame")
    if not -frames <= index < frames:
        raise RunFileError(f"frame {index} is out of range: {path!r} holds frames 0..{frames - 1}")
    index %= frames
    source = f"{path} frame {index}"
    positions = np.asarray(_element(group, "position", index, frames), dtype=float)
    if positions.ndim != 2 or positions.shape[1] != dimension:
        raise RunFileError(f"{path!r}: positions have shape {positions.shape}; (N, {dimension}) is needed")
    if "radius" in group:
        radii = np.asarray(_element(group, "radius", index, frames), dtype=float)
    elif "diameter" in group:
        radii = 0.5 * np.asarray(_element(group, "diameter", index, frames), dtype=float)
    else:
        raise RunFileError(f"{path!r} has no radius or diameter element in {group.name}: disk sizes are needed")
    if positions.shape[0] == 0:
        raise RunFileError(f"frame {index} of {path!r} holds no disks: nothing to analyse")
    if radii.shape not in ((), (1,), positions.shape[:1]):
        raise RunFileError(f"{path!r}: {radii.size} radii for {positions.shape[0]} positions; one per disk (or one "
                           f"for all) is needed")
    radii = np.broadcast_to(radii, positions.shape[:1]).astype(float)
    edges = np.asarray(_element(box, "edges", index, frames), dtype=float)
    if edges.shape == (dimension, dimension):
        if np.count_nonzero(edges - np.diag(np.diag(edges))):
            raise RunFileError(f"{path!r}: the box is triclinic; only rectangular boxes can be analysed")
        edges = np.diag(edges).copy()
    if edges.shape == (dimension,):
        _refuse_non_finite(source, positions, radii, edges)
    if edges.shape != (dimension,) or not np.all(edges[:2] > 0):
        raise RunFileError(f"{path!r}: box edges {edges.tolist()} are not {dimension} lengths, the first two positive")
    boundary = [b.decode() if isinstance(b, bytes) else str(b)
                for b in box.attrs.get("boundary", ["none"] * dimension)]
    periodic = tuple(b == "periodic" for b in boundary[:2])
    positions = _planar(positions, radii, source)
    contacts = geometric_contacts(positions, radii, edges[:2], periodic, gap)
    step = int(_sampled(position, "step", index, frames, path)) if isinstance(position, h5py.Group) else 0
    time = _sampled(position, "time", index, frames, path) if isinstance(position, h5py.Group) and "time" in position \
        else 0.0
    return _without_walls(positions, radii, contacts, ContactLaw(), edges[:2], periodic, time, step, False, source)


def _planar(positions: np.ndarray, radii: np.ndarray, source: str) -> np.ndarray:
    """The (N, 2) positions of disks given in 2D or in 3D in one plane z = const; a 3D packing
    (z spread beyond 1e-9 of the mean diameter) is refused."""
    if positions.shape[1] == 2:
        return positions
    z = positions[:, 2]
    spread = float(np.ptp(z)) if z.size else 0.0
    if not spread <= 1e-9 * 2.0 * float(np.mean(radii)):
        raise RunFileError(f"{source} is a 3D packing: z spreads over {spread:.6g} (from {z.min():.6g} to "
                           f"{z.max():.6g}); GranLab analyses 2D disks, all at one z")
    return np.ascontiguousarray(positions[:, :2])


def _without_walls(positions, radii, contacts, law, lengths, periodic, time, step, forces_known, source,
                   stress=None) -> PackingState:
    lengths = np.asarray(lengths, dtype=float)
    return PackingState(positions, radii, contacts, law, (), np.zeros((0, 2)), np.zeros(0), np.zeros(0), (),
                        lengths, lengths, tuple(periodic), np.zeros((2, 2)) if stress is None else stress, time, step,
                        forces_known, source, law_given=False)


def _xyz_state(data: XYZFrame, path: str | Path, law: dict, gap: float) -> PackingState:
    source = f"{path} frame {data.index}"
    cell = data.cell
    if np.count_nonzero(cell[:2, :2] - np.diag(np.diag(cell[:2, :2]))) or np.count_nonzero(cell[:2, 2]) \
            or np.count_nonzero(cell[2, :2]):
        raise RunFileError(f"{source}: the Lattice {cell.tolist()} is not rectangular in x and y; only rectangular "
                           f"cells can be analysed")
    lengths = np.diag(cell)[:2].copy()
    if not np.all(lengths > 0):
        raise RunFileError(f"{source}: the Lattice's x and y lengths {lengths.tolist()} are not positive: a cell "
                           f"(Lattice=\"Lx 0 0 0 Ly 0 0 0 Lz\") is needed")
    radii = _sizes(data.arrays, source, "column (Properties=...:radius:R:1)")
    _refuse_non_finite(source, data.positions, radii, lengths)
    positions = _planar(data.positions, radii, source)
    periodic = data.pbc[:2]
    contacts = geometric_contacts(positions, radii, lengths, periodic, gap)
    time = float(data.info.get("Time", data.info.get("time", 0.0)))
    step = int(data.info.get("Timestep", data.info.get("step", 0)))
    return _without_walls(positions, radii, contacts, ContactLaw(**law), lengths, periodic, time, step, False, source)


def _sizes(arrays: dict[str, np.ndarray], source: str, how: str) -> np.ndarray:
    for name in RADIUS_NAMES:
        if name in arrays:
            return np.asarray(arrays[name], dtype=float).reshape(-1)
    for name in DIAMETER_NAMES:
        if name in arrays:
            return 0.5 * np.asarray(arrays[name], dtype=float).reshape(-1)
    raise RunFileError(f"{source} has no radius or diameter {how}: disk sizes are needed "
                       f"(columns: {', '.join(sorted(arrays)) or 'none'})")


def _lammps_state(dump: Dump, frame: int, law: dict, gap: float, contacts: Dump | None,
                  contact_columns: tuple[str, ...] | None) -> PackingState:
    data = dump.frame(frame)
    source = f"{dump.path} frame {data.index} (timestep {data.timestep})"
    columns = {name: data.rows[:, k] for k, name in enumerate(data.columns)}
    if "id" not in columns:
        raise RunFileError(f"{source} has no id column (columns: {' '.join(data.columns)}): dump custom with "
                           f"'id x y radius' is needed")
    ids = columns["id"].astype(np.int64)
    order = np.argsort(ids, kind="stable")
    ids = ids[order]
    if ids.size and np.any(ids[1:] == ids[:-1]):
        raise RunFileError(f"{source} lists atom id {int(ids[1:][ids[1:] == ids[:-1]][0])} twice")
    lower, upper = data.bounds[:, 0], data.bounds[:, 1]
    axes = []
    for axis in "xyz":
        found = next((name for name in (axis, f"{axis}u", f"{axis}s", f"{axis}su") if name in columns), None)
        if found is None:
            if axis == "z":
                break
            raise RunFileError(f"{source} has no {axis} column (columns: {' '.join(data.columns)}): positions x, y "
                               f"(or xu, xs, xsu) are needed")
        k = "xyz".index(axis)
        values = columns[found][order]
        axes.append(lower[k] + values * (upper[k] - lower[k]) if "s" in found else values)
    radii = _sizes(columns, source, "column (dump custom ... radius)")[order]
    lengths = (upper - lower)[:2]
    _refuse_non_finite(source, np.column_stack(axes), radii, np.concatenate([lower, upper]))
    positions = _planar(np.column_stack(axes), radii, source) - lower[:2]
    if not np.all(lengths > 0):
        raise RunFileError(f"{source}: the box's x and y lengths {lengths.tolist()} are not positive")
    periodic = data.periodic[:2]
    wrap = np.array(periodic)
    positions[:, wrap] = np.mod(positions[:, wrap], lengths[wrap])
    contact_law = ContactLaw(**law)
    if contacts is None:
        found = geometric_contacts(positions, radii, lengths, periodic, gap)
        return _without_walls(positions, radii, found, contact_law, lengths, periodic, data.time or 0.0,
                              data.timestep, False, source)
    found = lammps_contacts(contacts, data.timestep, ids, positions, radii, lengths, periodic, contact_law,
                            contact_columns, gap)
    return _without_walls(positions, radii, found, contact_law, lengths, periodic, data.time or 0.0, data.timestep,
                          True, source, contact_stress(positions, found, lengths))


def lammps_contacts(dump: Dump, timestep: int, ids: np.ndarray, positions: np.ndarray, radii: np.ndarray,
                    lengths: np.ndarray, periodic: tuple[bool, bool], law: ContactLaw,
                    columns: tuple[str, ...] | None = None, gap: float = CONTACT_GAP) -> ContactSnapshot:
    """The contacts of a LAMMPS ``dump local`` (indexed) at ``timestep`` for the disks with atom ``ids``
    (sorted) at ``positions``: F_n = F·n and F_t = F·t of the force F on the first atom (n from the
    second atom's nearest image to the first, t = z × n); the elastic normal force is F_n (no
    cohesion, and no damping at rest), the tangential spring -F_t / K_t (Cundall-Strack); a contact
    slides when |F_t| reaches mu F_n. Pairs of the neighbour list that do not touch (a gap above
    the contact tolerance and no force) are left out."""
    path = dump.path
    if timestep not in dump.timesteps:
        raise RunFileError(f"{path} has no contacts at timestep {timestep}, the timestep of the packing's frame; it "
                           f"holds timesteps {', '.join(str(t) for t in dump.timesteps[:8])}"
                           + (", ..." if len(dump) > 8 else "") + " (pick the matching frame with --frame)")
    data = dump.frame(dump.timesteps.index(timestep))
    source = f"{path} timestep {timestep}"
    if columns is not None:
        if len(columns) != len(data.columns):
            raise RunFileError(f"--contact-columns names {len(columns)} columns and {source} has {len(data.columns)} "
                               f"({' '.join(data.columns)}): one name per column, - for one to leave out")
        names = tuple(columns)
    else:
        names = data.columns
    meaning = {}
    for key, aliases in CONTACT_NAMES.items():
        found = [k for k, name in enumerate(names) if name in aliases]
        if found:
            meaning[key] = data.rows[:, found[0]]
    missing = [key for key in ("id1", "id2", "fx", "fy") if key not in meaning]
    if missing:
        raise RunFileError(f"{source} has no {', '.join(missing)} column (columns: {' '.join(data.columns)}): name "
                           f"them with dump_modify colname or --contact-columns, e.g. id1 id2 fx fy ftx fty")
    first, second = meaning["id1"].astype(np.int64), meaning["id2"].astype(np.int64)
    i, j = np.searchsorted(ids, first), np.searchsorted(ids, second)
    unknown = np.unique(np.concatenate([first[ids[np.minimum(i, ids.size - 1)] != first],
                                        second[ids[np.minimum(j, ids.size - 1)] != second]]))
    if unknown.size:
        raise RunFileError(f"{source} names atom ids the packing's frame does not hold: "
                           f"{', '.join(str(v) for v in unknown[:5])}" + (" and more" if unknown.size > 5 else ""))
    force = np.column_stack([meaning["fx"], meaning["fy"]])
    if "ftx" in meaning and "fty" in meaning:
        force = force + np.column_stack([meaning["ftx"], meaning["fty"]])
    bad = np.flatnonzero(~np.all(np.abs(force) < HUGE, axis=1))
    if bad.size:
        raise RunFileError(f"{source} has non-finite or huge (> 1e150) forces in {bad.size} of its {force.shape[0]} "
                           f"entries (the first between atoms {first[bad[0]]} and {second[bad[0]]}): forces must be "
                           f"finite numbers")
    wrap = np.array(periodic)
    delta = positions[i] - positions[j]
    image = np.where(wrap, np.round(delta / lengths), 0.0)
    branch = delta - image * lengths
    distance = np.hypot(branch[:, 0], branch[:, 1])
    surface = distance - radii[i] - radii[j]
    keep = (np.abs(force).sum(axis=1) > 0) | (surface <= gap * 2.0 * float(radii.mean()))
    i, j, image, branch, distance, surface, force = (a[keep] for a in (i, j, image, branch, distance, surface, force))
    pairs = np.sort(np.column_stack([i, j]), axis=1)
    if np.unique(pairs, axis=0).shape[0] != pairs.shape[0]:
        raise RunFileError(f"{source} lists a pair of atoms twice (dump the contacts with newton_pair on, or one "
                           f"processor)")
    normal = branch / distance[:, None]
    fn = np.einsum("ij,ij->i", force, normal)
    ft = force[:, 1] * normal[:, 0] - force[:, 0] * normal[:, 1]
    swap = i > j
    i, j = np.where(swap, j, i), np.where(swap, i, j)
    image = np.where(swap[:, None], -image, image)
    limit = law.friction * np.maximum(fn, 0.0)
    sliding = np.abs(ft) >= (1.0 - SLIDING_TOLERANCE) * limit
    status = np.where(sliding & (limit > 0), np.where(ft > 0, STATUS_SLIDE_POS, STATUS_SLIDE_NEG), STATUS_STICK)
    return ContactSnapshot(i=i.astype(np.int64), j=j.astype(np.int64), image=image.astype(np.int64),
                           status=status.astype(np.int8), normal_force=fn, elastic_normal_force=fn.copy(),
                           tangential_force=ft, surface_gap=surface, tangential_spring=-ft / law.tangential_stiffness,
                           rolling_spring=np.zeros_like(fn), rolling_distance=np.zeros_like(fn))


def contact_force_vectors(positions: np.ndarray, contacts: ContactSnapshot, lengths: np.ndarray,
                          rows=slice(None)) -> tuple[np.ndarray, np.ndarray]:
    """The branch vectors l from j's image to i and the forces F = F_n n + F_t t on disk i of the
    disk-disk ``contacts`` (their ``rows``)."""
    delta = positions[contacts.i[rows]] - positions[contacts.j[rows]] - contacts.image[rows] * lengths
    normal = delta / np.hypot(delta[:, 0], delta[:, 1])[:, None]
    tangent = np.column_stack([-normal[:, 1], normal[:, 0]])
    force = contacts.normal_force[rows][:, None] * normal + contacts.tangential_force[rows][:, None] * tangent
    return delta, force


def contact_stress(positions: np.ndarray, contacts: ContactSnapshot, lengths: np.ndarray) -> np.ndarray:
    """The disk-disk stress (1/A) sum F ⊗ l (2 × 2, compression positive) of ``contacts``
    (:func:`contact_force_vectors`)."""
    delta, force = contact_force_vectors(positions, contacts, lengths)
    return force.T @ delta / float(lengths[0] * lengths[1])


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
    extent = np.ptp(positions, axis=0) if positions.size else np.zeros(2)
    if np.any(wrap & (extent > 1e9 * lengths)):
        raise RunFileError(f"the periodic box {lengths.tolist()} is too small for positions spread over "
                           f"{extent.tolist()}: its lengths or the positions are wrong")
    image = np.where(wrap, np.round(delta / np.where(wrap, lengths, 1.0)), 0.0)
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
