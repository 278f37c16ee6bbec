"""``vtk`` (ParaView): a folder with ``STEM.pvd``, the time series, and per frame three ``.vtu`` parts.

``STEM_disks_K.vtu``: the disks as points with ``radius``, ``velocity``, ``omega``, ``angle`` θ,
``mass``, and the lab's colour fields ``coordination``, ``pressure``, ``sliding``;
``STEM_contacts_K.vtu``: the force network as line cells from each disk's centre to its partner's
nearest image or to the wall, with ``normal_force`` F_n, ``tangential_force`` F_t, ``force`` |F|,
``status``, ``tangential_spring`` D_t, ``surface_gap``, ``kind`` and the disks ``i``, ``j``
(``j >= N`` is wall ``j - N``); ``STEM_boundary_K.vtu``: the walls and the periodic cell as lines,
``kind`` 0 wall, 1 cell edge.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from granlab.engine.frames import cell_outline
from granlab.engine.io.vtk import VTK_LINE, VTK_VERTEX, write_pvd, write_vtu

PARTS = ("disks", "contacts", "boundary")


def files(out: Path, stem: str, indices: list[int]) -> list[Path]:
    return [out / f"{stem}.pvd"] + [out / f"{stem}_{part}_{index:05d}.vtu" for index in indices for part in PARTS]


def write(frames, out: Path, stem: str, indices: list[int]) -> None:
    entries = []
    for index, frame in zip(indices, frames):
        raw, scene, contacts = frame.raw, frame.scene, frame.contacts
        field = {"TimeValue": np.array([raw["time"]]), "step": np.array([raw["step"]], dtype=np.int64)}
        names = [f"{stem}_{part}_{index:05d}.vtu" for part in PARTS]
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
