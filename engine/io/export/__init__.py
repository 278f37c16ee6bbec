"""``granlab export``: frames of a GranLab run file for the tools people already use.

One module of this package per format (its files and its writer; what the files hold is in its
docstring) and one entry of :data:`EXPORT_FORMATS`, which the command's ``--format``, the checks
of ``--out`` and ``granlab.export`` all read: adding a format is a module, an entry and its docs.
GranLab's units are the user's, so no file claims a unit.
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

import numpy as np

# Absolute imports, and no io module under its own name: importing a format module binds its name
# (vtk, xyz, lammps, h5md) in this package, over an io module imported as it.
from granlab.engine.errors import ParameterError
from granlab.engine.frames import FrameData, build_frame
from granlab.engine.io import h5md as run_files
from granlab.engine.io.frame_selection import reporting, select_frames
from granlab.engine.io.outputs import check_output, staged


@dataclass(frozen=True)
class ExportFormat:
    """A format of ``granlab export``: its ``--format`` name; the module writing it, loaded on first
    use (so that listing the formats costs nothing), which defines ``files(out, stem, indices)``
    (what it writes) and ``write(frames, out, stem, indices)`` (the frames as :class:`_Frame`), and
    may define ``check_room(run, out, indices)`` (called before anything is written) and
    ``read_run(run, indices)`` (what it needs of the run file beyond its frames, given to ``write``
    as ``run=``); what it is, in a line; the suffix of its ``--out`` file, "" for a folder."""

    name: str
    module: str
    title: str
    suffix: str

    def writer(self) -> ModuleType:
        return importlib.import_module(self.module)


EXPORT_FORMATS = {fmt.name: fmt for fmt in (
    ExportFormat("vtk", f"{__name__}.vtk", "ParaView: a folder of .pvd and .vtu files", ""),
    ExportFormat("xyz", f"{__name__}.xyz", "OVITO, ASE: extended XYZ", ".xyz"),
    ExportFormat("lammps", f"{__name__}.lammps", "LAMMPS, OVITO: a dump custom and a dump local of the contacts",
                 ".dump"),
    ExportFormat("h5md", f"{__name__}.h5md", "MDAnalysis: H5MD in a 3D box", ".h5md"),
    ExportFormat("html", f"{__name__}.html", "a handout: one page replaying the run in a browser, offline", ".html"),
)}
"""Every format of ``granlab export`` by name (iterating gives the names)."""


def contacts_dump_name(out: Path) -> Path:
    """The ``dump local`` of the contacts written beside a LAMMPS dump ``out``."""
    return out.with_name(f"{out.stem}-contacts{out.suffix}")


class _Frame:
    """One frame of a run file with what every format writes: the lab's colour fields and the
    force network's segments (:func:`granlab.engine.frames.build_frame`), the box's lower corner."""

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
    """Write frames ``frames`` (:func:`granlab.engine.io.frame_selection.select_frames`; default every
    frame) of the GranLab run file ``path`` as ``fmt`` (:data:`EXPORT_FORMATS`) into ``out`` (a folder
    or a file with the format's suffix). Nothing that exists is written over unless ``force``;
    ``progress(done, total)`` is called as frames are written. Returns ``out``, the ``files``
    written, the frame ``indices`` and ``seconds``."""
    start = time.perf_counter()
    if fmt not in EXPORT_FORMATS:
        raise ParameterError("--format", fmt, f"one of {', '.join(EXPORT_FORMATS)}")
    suffix = EXPORT_FORMATS[fmt].suffix
    out = Path(out)
    if not suffix:
        if out.suffix:
            raise ParameterError("--out", str(out), f"a folder (a name without a suffix) for --format {fmt}")
    elif out.suffix != suffix:
        raise ParameterError("--out", str(out), f"a file name ending in {suffix} for --format {fmt}")
    writer = EXPORT_FORMATS[fmt].writer()
    with run_files.open_run(path) as f:
        run_files.require_run_file(f, "export")
        count = run_files.frame_count(f)
        if count == 0:
            raise run_files.RunFileError(f"{str(path)!r} holds no complete frame")
        indices = select_frames(":" if frames is None else frames, count, "--frames")
        stem = Path(path).stem
        targets = writer.files(out, stem, indices)
        for target in targets:
            check_output(target, force=force, inputs=[path])
        walls = run_files.walls_from_json(run_files.parameters(f)["walls_json"])
        normals = np.array([wall.normal for wall in walls], dtype=float).reshape(-1, 2)
        kind = f["particles/all/kind"][()] if "particles/all/kind" in f else None
        frames_read = (_Frame(run_files.read_frame(f, index), normals, kind) for index in indices)
        if progress is not None:
            frames_read = reporting(frames_read, len(indices), progress)
        if hasattr(writer, "check_room"):
            writer.check_room(f, out, indices)
        run = {"run": writer.read_run(f, indices)} if hasattr(writer, "read_run") else {}
        if suffix:
            with staged(out.parent, last=[out.name]) as folder:
                writer.write(frames_read, folder / out.name, stem, indices, **run)
        else:
            with staged(out, last=[targets[0].name]) as folder:
                writer.write(frames_read, folder, stem, indices, **run)
        if progress is not None:
            progress(len(indices), len(indices))
    return {"run_file": str(path), "format": fmt, "out": str(out), "files": [str(t) for t in targets],
            "frames": len(indices), "indices": [indices[0], indices[-1]], "seconds": time.perf_counter() - start}


def print_summary(result: dict) -> None:
    """What ``granlab export`` prints without ``--json``."""
    files = result["files"]
    first, last = result["indices"]
    frames = f"frame {first}" if result["frames"] == 1 else f"{result['frames']} frames ({first}..{last})"
    where = result["out"] if len(files) <= 2 else f"{result['out']} ({len(files)} files)"
    print(f"wrote {where}: {frames} of {result['run_file']} as {result['format']} in {result['seconds']:.2f} s")
    if result["format"] == "lammps":
        print(f"  contacts: {files[1]} (granlab analyze {files[0]} --contacts {files[1]})")
