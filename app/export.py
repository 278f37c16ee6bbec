"""``granlab export``: frames of a GranLab run file for the tools people already use.

- ``vtk`` (ParaView): a folder with ``STEM.pvd``, the time series, and per frame three ``.vtu``
  parts: ``STEM_disks_K.vtu`` (the disks as points with ``radius``, ``velocity``, ``omega``,
  ``angle`` θ, ``mass``, and the lab's colour fields ``coordination``, ``pressure``,
  ``sliding``), ``STEM_contacts_K.vtu`` (the force network as line cells from each disk's centre
  to its partner's nearest image or to the wall, with ``normal_force`` F_n, ``tangential_force``
  F_t, ``force`` |F|, ``status``, ``tangential_spring`` D_t, ``surface_gap``, ``kind`` and the
  disks ``i``, ``j``; ``j >= N`` is wall ``j - N``) and ``STEM_boundary_K.vtu`` (the walls and
  the periodic cell as lines, ``kind`` 0 wall, 1 cell edge);
- ``xyz`` (OVITO, ASE): one extended XYZ file of the frames with ``Lattice``, ``Origin``,
  ``pbc`` and the columns ``id``, ``radius``, ``velo``, ``omega``, ``angle``, ``mass``,
  ``coordination``, ``pressure``, ``sliding``; ``Time`` and ``Timestep`` per frame;
- ``lammps``: a LAMMPS ``dump custom`` text file (``id type x y z radius mass vx vy vz omegaz``
  and the same extra columns; ``type`` is 1 + the disk's kind) and beside it ``STEM-contacts.dump``,
  a ``dump local`` of the disk-disk contacts (``id1 id2 fnx fny ftx fty`` as ``granlab analyze
  --contacts`` reads them, then ``fn ft status dt gap``);
- ``h5md`` (MDAnalysis): an H5MD file of the positions and velocities in a 3D box: the disks in
  the plane z = 0, the box's third edge the largest diameter and not periodic (MDAnalysis reads
  only 3D boxes); ``/particles/trajectory`` as MDAnalysis names it, and the radii.

GranLab's units are the user's, so no file claims a unit (open the H5MD file in MDAnalysis with
``convert_units=False``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import h5py
import numpy as np

from granlab.engine.errors import OutputError, ParameterError
from granlab.engine.io import h5md
from granlab.engine.io.extxyz import write_xyz
from granlab.engine.io.lammps import LOCAL_ITEM, write_dump
from granlab.engine.io.outputs import check_output, room_for_one_file, staged
from granlab.engine.io.vtk import VTK_LINE, VTK_VERTEX, write_pvd, write_vtu

from .drawing import cell_outline
from .frames import FrameData, build_frame
from .render import reporting, select_frames

EXPORT_FORMATS = ("vtk", "xyz", "lammps", "h5md")
SUFFIXES = {"xyz": ".xyz", "lammps": ".dump", "h5md": ".h5md"}
"""The suffix of each format's ``--out`` file (``vtk`` writes into a folder)."""


def contacts_dump_name(out: Path) -> Path:
    """The ``dump local`` of the contacts written beside a LAMMPS dump ``out``."""
    return out.with_name(f"{out.stem}-contacts{out.suffix}")


class _Frame:
    """One frame of a run file with what every format writes: the lab's colour fields and the
    force network's segments (:func:`granlab.app.frames.build_frame`), the box's lower corner."""

    def __init__(self, raw: dict, normals: np.ndarray, kind: np.ndarray):
        self.raw = raw
        self.kind = kind
        self.scene = build_frame([(FrameData.from_run_frame(raw, normals), (0.0, 0.0))])
        self.periodic = tuple(b == "periodic" for b in raw["boundary"])
        self.lengths = np.asarray(raw["edges"], dtype=float)
        self.lower = _lower_corner(raw, normals, self.periodic)
        self.n = raw["position"].shape[0]
        contacts = raw["contacts"]
        self.pair = contacts["pair"].astype(np.int64)
        self.contacts = contacts

    def disk_columns(self) -> dict[str, np.ndarray]:
        return {"omega": self.raw["omega"], "angle": self.raw["angle"], "mass": self.raw["mass"],
                "coordination": self.scene.coordination, "pressure": self.scene.pressure,
                "sliding": self.scene.sliding.astype(np.int64)}


def _lower_corner(raw: dict, normals: np.ndarray, periodic: tuple[bool, ...]) -> np.ndarray:
    """The box's lower corner: 0 along a periodic axis, a wall facing +x (+y) where there is one,
    else the lowest disk edge."""
    lower = np.zeros(2)
    offsets = np.asarray(raw.get("wall_position", np.zeros(len(normals))), dtype=float)
    for axis in range(2):
        if periodic[axis]:
            continue
        facing = [k for k, normal in enumerate(normals) if np.allclose(normal, np.eye(2)[axis])]
        lower[axis] = offsets[facing[0]] if facing else float(np.min(raw["position"][:, axis] - raw["radius"]))
    return lower


def export_run(path, fmt: str, out, frames=None, force: bool = False,
               progress: Callable[[int, int], None] | None = None) -> dict:
    """Write frames ``frames`` (:func:`granlab.app.render.select_frames`; default every frame) of the
    GranLab run file ``path`` as ``fmt`` (:data:`EXPORT_FORMATS`) into ``out`` (a folder for
    ``vtk``, else a file with the format's suffix). Nothing that exists is written over unless
    ``force``; ``progress(done, total)`` is called as frames are written. Returns ``out``, the
    ``files`` written, the frame ``indices`` and ``seconds``."""
    start = time.perf_counter()
    if fmt not in EXPORT_FORMATS:
        raise ParameterError("--format", fmt, f"one of {', '.join(EXPORT_FORMATS)}")
    out = Path(out)
    if fmt == "vtk":
        if out.suffix:
            raise ParameterError("--out", str(out), "a folder for the .pvd and .vtu files (a name without a suffix)")
    elif out.suffix != SUFFIXES[fmt]:
        raise ParameterError("--out", str(out), f"a file name ending in {SUFFIXES[fmt]} for --format {fmt}")
    with h5md.open_run(path) as f:
        h5md.require_run_file(f, "export")
        count = h5md.frame_count(f)
        if count == 0:
            raise h5md.RunFileError(f"{str(path)!r} holds no complete frame")
        indices = select_frames(":" if frames is None else frames, count, "--frames")
        stem = Path(path).stem
        targets = _targets(fmt, out, stem, indices)
        for target in targets:
            check_output(target, force=force, inputs=[path])
        walls = h5md.walls_from_json(h5md.parameters(f)["walls_json"])
        normals = np.array([wall.normal for wall in walls], dtype=float).reshape(-1, 2)
        kind = f["particles/all/kind"][()] if "particles/all/kind" in f else None
        frames_read = (_Frame(h5md.read_frame(f, index), normals, kind) for index in indices)
        if progress is not None:
            frames_read = reporting(frames_read, len(indices), progress)
        if fmt == "h5md":
            # HDF5 crashes on a write that fails inside it: the room is checked first
            needed = len(indices) * f["particles/all/position/value"][0].nbytes * 3 + 2 ** 20
            room = room_for_one_file(out.parent)
            if room < needed:
                raise OutputError(f"writing {str(out)!r} needs about {needed / 2 ** 20:.3g} MiB and there is room "
                                  f"for {room / 2 ** 20:.3g} MiB (free space, ulimit -f): nothing was written")
        if fmt == "vtk":
            with staged(out, last=[targets[0].name]) as folder:
                WRITERS[fmt](frames_read, folder, stem, indices)
        else:
            with staged(out.parent, last=[out.name]) as folder:
                WRITERS[fmt](frames_read, folder / out.name, stem, indices)
        if progress is not None:
            progress(len(indices), len(indices))
    return {"run_file": str(path), "format": fmt, "out": str(out), "files": [str(t) for t in targets],
            "frames": len(indices), "indices": [indices[0], indices[-1]], "seconds": time.perf_counter() - start}


def _targets(fmt: str, out: Path, stem: str, indices: list[int]) -> list[Path]:
    if fmt == "vtk":
        return [out / f"{stem}.pvd"] + [out / f"{stem}_{part}_{index:05d}.vtu" for index in indices
                                         for part in ("disks", "contacts", "boundary")]
    if fmt == "lammps":
        return [out, contacts_dump_name(out)]
    return [out]


def _write_vtk(frames, out: Path, stem: str, indices: list[int]) -> None:
    entries = []
    for index, frame in zip(indices, frames):
        raw, scene, contacts = frame.raw, frame.scene, frame.contacts
        field = {"TimeValue": np.array([raw["time"]]), "step": np.array([raw["step"]], dtype=np.int64)}
        names = [f"{stem}_{part}_{index:05d}.vtu" for part in ("disks", "contacts", "boundary")]
        velocity = np.column_stack([raw["velocity"], np.zeros(frame.n)])
        write_vtu(out / names[0], raw["position"], VTK_VERTEX, np.arange(frame.n),
                  {"radius": raw["radius"], "velocity": velocity, **frame.disk_columns()}, None, field)
        m = frame.pair.shape[0]
        write_vtu(out / names[1], scene.contacts.reshape(-1, 2), VTK_LINE, np.arange(2 * m).reshape(m, 2), None,
                  {"normal_force": contacts["normal_force"], "tangential_force": contacts["tangential_force"],
                   "force": scene.contact_force, "status": contacts["status"],
                   "tangential_spring": contacts["tangential_spring"], "surface_gap": contacts["surface_gap"],
                   "kind": scene.contact_kind, "i": frame.pair[:, 0], "j": frame.pair[:, 1]}, field)
        edges = scene.walls.reshape(-1, 2, 2)
        kind = np.zeros(len(edges), dtype=np.int8)
        if any(frame.periodic):
            outline = cell_outline(tuple(frame.lengths))
            edges = np.concatenate([edges, outline])
            kind = np.concatenate([kind, np.ones(len(outline), dtype=np.int8)])
        write_vtu(out / names[2], edges.reshape(-1, 2), VTK_LINE, np.arange(2 * len(edges)).reshape(-1, 2), None,
                  {"kind": kind}, field)
        entries += [(raw["time"], part, name) for part, name in enumerate(names)]
    write_pvd(out / f"{stem}.pvd", entries)


def _write_xyz(frames, out: Path, stem: str, indices: list[int]) -> None:
    with open(out, "w") as f:
        for frame in frames:
            raw = frame.raw
            columns = {"id": np.arange(1, frame.n + 1), "radius": raw["radius"],
                       "velo": np.column_stack([raw["velocity"], np.zeros(frame.n)]), **frame.disk_columns()}
            write_xyz(f, raw["position"], frame.lengths, frame.periodic, columns,
                      {"Time": f"{raw['time']:.17g}", "Timestep": raw["step"]}, frame.lower)


def _write_lammps(frames, out: Path, stem: str, indices: list[int]) -> None:
    with open(out, "w") as atoms, open(contacts_dump_name(out), "w") as local:
        for frame in frames:
            raw, contacts, n = frame.raw, frame.contacts, frame.n
            lower, upper = frame.lower, frame.lower + frame.lengths
            kind = np.zeros(n, dtype=np.int64) if frame.kind is None else frame.kind.astype(np.int64)
            columns = {"id": np.arange(1, n + 1), "type": kind + 1,
                       "x": raw["position"][:, 0], "y": raw["position"][:, 1], "z": np.zeros(n),
                       "radius": raw["radius"], "mass": raw["mass"], "vx": raw["velocity"][:, 0],
                       "vy": raw["velocity"][:, 1], "vz": np.zeros(n), "omegaz": raw["omega"],
                       **{k: v for k, v in frame.disk_columns().items() if k not in ("omega", "mass")}}
            write_dump(atoms, raw["step"], raw["time"], lower, upper, frame.periodic, tuple(columns),
                       np.column_stack(list(columns.values())), formats=_formats(columns))
            pairs = frame.pair[:, 1] < n
            i, j = frame.pair[pairs, 0], frame.pair[pairs, 1]
            segment = frame.scene.contacts[pairs]
            branch = segment[:, 0] - segment[:, 1]
            normal = branch / np.hypot(branch[:, 0], branch[:, 1])[:, None]
            fn, ft = contacts["normal_force"][pairs], contacts["tangential_force"][pairs]
            entries = {"id1": i + 1, "id2": j + 1, "fnx": fn * normal[:, 0], "fny": fn * normal[:, 1],
                       "ftx": -ft * normal[:, 1], "fty": ft * normal[:, 0], "fn": fn, "ft": ft,
                       "status": contacts["status"][pairs], "dt": contacts["tangential_spring"][pairs],
                       "gap": contacts["surface_gap"][pairs]}
            write_dump(local, raw["step"], raw["time"], lower, upper, frame.periodic, tuple(entries),
                       np.column_stack(list(entries.values())), item=LOCAL_ITEM, formats=_formats(entries))


def _formats(columns: dict[str, np.ndarray]) -> tuple[str, ...]:
    return tuple("%d" if np.issubdtype(np.asarray(v).dtype, np.integer) or np.asarray(v).dtype == bool else "%.17g"
                 for v in columns.values())


def _write_h5md(frames, out: Path, stem: str, indices: list[int]) -> None:
    with h5py.File(out, "w") as f:
        h5md.write_h5md_header(f, creator="GranLab export")
        group = f.create_group("particles/trajectory")
        box = group.create_group("box")
        box.attrs["dimension"] = 3
        first = True
        for frame in frames:
            raw = frame.raw
            if first:
                box.attrs["boundary"] = np.array(["periodic" if p else "none" for p in frame.periodic] + ["none"],
                                                 dtype="S8")
                elements = {name: h5md.time_dependent(group, name, shape)
                            for name, shape in (("position", (frame.n, 3)), ("velocity", (frame.n, 3)),
                                                ("radius", (frame.n,)))}
                elements["edges"] = h5md.time_dependent(box, "edges", (3,))
                first = False
            flat = np.zeros(frame.n)
            values = {"position": np.column_stack([raw["position"] - frame.lower, flat]),
                      "velocity": np.column_stack([raw["velocity"], flat]), "radius": raw["radius"],
                      "edges": [*frame.lengths, 2.0 * float(raw["radius"].max())]}
            for name, element in elements.items():
                for key, value in (("value", values[name]), ("step", raw["step"]), ("time", raw["time"])):
                    h5md.append_row(element[key], value)


WRITERS = {"vtk": _write_vtk, "xyz": _write_xyz, "lammps": _write_lammps, "h5md": _write_h5md}


def print_summary(result: dict) -> None:
    """What ``granlab export`` prints without ``--json``."""
    files = result["files"]
    first, last = result["indices"]
    frames = f"frame {first}" if result["frames"] == 1 else f"{result['frames']} frames ({first}..{last})"
    where = result["out"] if len(files) <= 2 else f"{result['out']} ({len(files)} files)"
    print(f"wrote {where}: {frames} of {result['run_file']} as {result['format']} in {result['seconds']:.2f} s")
    if result["format"] == "lammps":
        print(f"  contacts: {files[1]} (granlab analyze {files[0]} --contacts {files[1]})")
