"""``granlab export``'s work: a run file's frames read, drawn as the lab draws them, and written by
the format's module (:data:`granlab.engine.io.export.EXPORT_FORMATS`)."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from granlab.engine import stopping
from granlab.engine.errors import ParameterError
from granlab.engine.frames import FrameData, build_frame
from granlab.engine.io import h5md as run_files
from granlab.engine.io.export import EXPORT_FORMATS
from granlab.engine.io.frame_selection import reporting, select_frames
from granlab.engine.io.outputs import check_output, staged


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
        walls = run_files.run_walls(f)
        normals = np.array([wall.normal for wall in walls], dtype=float).reshape(-1, 2)
        kind = f["particles/all/kind"][()] if "particles/all/kind" in f else None
        # a stop asked for ends the export between two frames (its part files then go)
        frames_read = (_Frame(run_files.read_frame(f, index), normals, kind) for index in stopping.checked(indices))
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
