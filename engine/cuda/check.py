"""A run on the device beside the same run on the CPU engine: how far apart they end.

Each array of the state is compared by its largest difference relative to its largest value (an
array of zeros by its largest difference): the device adds a disk's forces in another order, so
the two runs part by rounding, and a chaotic packing makes that grow with the steps.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from ..simulation import Simulation

TOLERANCE = 1e-12
"""What ``granlab bench --backend cuda --check`` allows (relative, as :func:`compare` measures)."""

COMPARED = {"particles": ("position", "velocity", "angle", "omega", "force", "torque"),
            "walls": ("offset", "velocity", "particle_force"), "cell": ("length", "rate", "virial")}


def relative_difference(a: np.ndarray, b: np.ndarray) -> float:
    difference = float(np.max(np.abs(a - b), initial=0.0))
    scale = float(np.max(np.abs(a), initial=0.0))
    return difference / scale if scale > 0.0 else difference


def compare(make: Callable[[], Simulation], steps: int) -> dict:
    """``make()`` run ``steps`` steps on the CPU (every row directly, as the device computes them) and on the
    device: the relative difference of each state array, of the energy ledger and of the contacts' springs,
    and the largest (``worst``). Contacts are compared where the two tables hold the same rows with the same
    status (``same_contacts``)."""
    cpu, device = make(), make()
    cpu.gathered = False
    device.use_backend("cuda")
    cpu.run(steps)
    device.run(steps)
    differences = {f"{part}.{name}": relative_difference(getattr(getattr(cpu, part), name),
                                                         getattr(getattr(device, part), name))
                   for part, names in COMPARED.items() for name in names}
    ledgers = [np.array(dataclasses.astuple(sim.energy())) for sim in (cpu, device)]
    differences["energy"] = relative_difference(*ledgers)  # each term against the largest
    a, b = cpu.contacts, device.contacts
    rows = slice(0, a.count)
    same_pairs = a.count == b.count and np.array_equal(a.particle_i[rows], b.particle_i[rows]) and \
        np.array_equal(a.particle_j[rows], b.particle_j[rows]) and np.array_equal(a.status[rows], b.status[rows])
    if same_pairs:
        for name in ("tangential_spring", "rolling_spring", "normal_force", "tangential_force"):
            differences[f"contacts.{name}"] = relative_difference(getattr(a, name)[rows], getattr(b, name)[rows])
    return {"steps": steps, "particles": cpu.particles.count, "contacts": int(a.count), "same_contacts": bool(same_pairs),
            "differences": differences, "worst": max(differences.values()),
            "tolerance": TOLERANCE}
