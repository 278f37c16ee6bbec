"""``lammps``: a LAMMPS ``dump custom`` text file (``id type x y z radius mass vx vy vz omegaz`` and the
columns ``angle``, ``coordination``, ``pressure``, ``sliding``; ``type`` is 1 + the disk's kind)
and beside it ``STEM-contacts.dump``, a ``dump local`` of the disk-disk contacts (``id1 id2 fnx
fny ftx fty`` as ``granlab analyze --contacts`` reads them, then ``fn ft status dt gap``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from granlab.engine.io.export import contacts_dump_name
from granlab.engine.io.lammps import LOCAL_ITEM, write_dump


def files(out: Path, stem: str, indices: list[int]) -> list[Path]:
    return [out, contacts_dump_name(out)]


def write(frames, out: Path, stem: str, indices: list[int]) -> None:
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
