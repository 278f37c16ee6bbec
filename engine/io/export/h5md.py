"""``h5md`` (MDAnalysis): an H5MD file of the positions and velocities in a 3D box: the disks in the
plane z = 0, the box's third edge the largest diameter and not periodic (MDAnalysis reads only 3D
boxes); ``/particles/trajectory`` as MDAnalysis names it, and the radii. The file claims no unit:
open it in MDAnalysis with ``convert_units=False``."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

from granlab.engine.costs import room_for_one_file
from granlab.engine.errors import OutputError
from granlab.engine.io import h5md


def files(out: Path, stem: str, indices: list[int]) -> list[Path]:
    return [out]


def check_room(run: h5py.File, out: Path, indices: list[int]) -> None:
    """HDF5 crashes on a write that fails inside it: the room is checked first."""
    needed = len(indices) * run["particles/all/position/value"][0].nbytes * 3 + 2 ** 20
    room = room_for_one_file(out.parent)
    if room < needed:
        raise OutputError(f"writing {str(out)!r} needs about {needed / 2 ** 20:.3g} MiB and there is room "
                          f"for {room / 2 ** 20:.3g} MiB (free space, ulimit -f): nothing was written")


def write(frames, out: Path, stem: str, indices: list[int]) -> None:
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
