"""A run on the device beside the same run on the CPU engine: how far apart they end.

Each array of the state is compared by its largest difference relative to its largest value (an
array of zeros by its largest difference): the device adds a disk's forces in another order, so
the two runs part by rounding, and a chaotic packing makes that grow with the steps.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from ..kernels.integrate import INFO_REBUILDS
from ..simulation import Simulation
from ..state import STATUS_NONE

TOLERANCE = 1e-12
"""What ``granlab bench --backend cuda --check`` allows (relative, as :func:`compare` measures)."""

COMPARED = {"particles": ("position", "velocity", "angle", "omega", "force", "torque"),
            "walls": ("offset", "velocity", "particle_force"), "cell": ("length", "rate", "virial")}


def relative_difference(a: np.ndarray, b: np.ndarray) -> float:
    difference = float(np.max(np.abs(a - b), initial=0.0))
    scale = float(np.max(np.abs(a), initial=0.0))
    return difference / scale if scale > 0.0 else difference


def interacting(table) -> np.ndarray:
    """The rows of a contact table that interact (status not none), sorted by disk, other disk or wall, and
    image: the two backends may hold them in another order, and other candidate rows beside them (a batch on
    the device rebuilds each sample's rows when that sample needs it)."""
    count = table.count
    rows = np.flatnonzero(table.status[:count] != STATUS_NONE)
    fields = ("tangential_spring", "rolling_spring", "normal_force", "tangential_force")
    record = np.zeros(rows.size, dtype=[("i", np.int64), ("j", np.int64), ("image_x", np.int64), ("image_y", np.int64),
                                        ("status", np.int8)] + [(name, np.float64) for name in fields])
    record["i"], record["j"], record["status"] = table.particle_i[rows], table.particle_j[rows], table.status[rows]
    record["image_x"], record["image_y"] = table.image[rows, 0], table.image[rows, 1]
    for name in fields:
        record[name] = getattr(table, name)[rows]
    return np.sort(record, order=("i", "j", "image_x", "image_y"))


def compare(make: Callable[[], Simulation], steps: int) -> dict:
    """``make()`` run ``steps`` steps on the CPU (every row directly, as the device computes them) and on the
    device: the relative difference of each state array, of the energy ledger and of the contacts' springs,
    and the largest (``worst``). Contacts are compared where the two tables hold the same interacting rows
    with the same status (``same_contacts``, :func:`interacting`); ``rebuilds``: the tables' rebuilds on each
    (a batch's samples on the device count theirs one by one)."""
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
    a, b = interacting(cpu.contacts), interacting(device.contacts)
    same_pairs = a.size == b.size and all(np.array_equal(a[key], b[key])
                                          for key in ("i", "j", "image_x", "image_y", "status"))
    if same_pairs:
        for name in ("tangential_spring", "rolling_spring", "normal_force", "tangential_force"):
            differences[f"contacts.{name}"] = relative_difference(a[name], b[name])
    rebuilds = [int(sim.workspace.info[INFO_REBUILDS]) for sim in (cpu, device)]
    return {"steps": steps, "particles": cpu.particles.count, "contacts": int(a.size), "same_contacts": bool(same_pairs),
            "rebuilds": rebuilds,
            "differences": differences, "worst": max(differences.values()),
            "tolerance": TOLERANCE}
