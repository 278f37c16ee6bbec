"""``xyz`` (OVITO, ASE): one extended XYZ file of the frames with ``Lattice``, ``Origin``, ``pbc`` and
the columns ``id``, ``radius``, ``velo``, ``omega``, ``angle``, ``mass``, ``coordination``,
``pressure``, ``sliding``; ``Time`` and ``Timestep`` per frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from granlab.engine.io.extxyz import write_xyz


def files(out: Path, stem: str, indices: list[int]) -> list[Path]:
    return [out]


def write(frames, out: Path, stem: str, indices: list[int]) -> None:
    with open(out, "w") as f:
        for frame in frames:
            raw = frame.raw
            columns = {"id": np.arange(1, frame.n + 1), "radius": raw["radius"],
                       "velo": np.column_stack([raw["velocity"], np.zeros(frame.n)]), **frame.disk_columns()}
            write_xyz(f, raw["position"], frame.lengths, frame.periodic, columns,
                      {"Time": f"{raw['time']:.17g}", "Timestep": raw["step"]}, frame.lower)
