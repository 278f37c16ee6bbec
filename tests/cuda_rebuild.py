"""Run under numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``) by tests/test_cuda.py: the contact table
rebuilt on the device beside the CPU engine's rebuild of the same state; prints one JSON object a case."""

import json

import numpy as np

from granlab.engine import ContactLaw, Integration, ParticleState, PeriodicCell, Simulation, Wall
from granlab.engine.cuda.neighbours import DeviceTable
from granlab.engine.cuda.stepper import DeviceState
from granlab.engine.generate import radii, random_gas
from granlab.engine.kernels.integrate import INFO_LOST, INFO_NEEDED, rebuild
from granlab.engine.kernels.laws import D0
from granlab.engine.state import STATUS_NONE, ContactArrays

N = 60


def cohesive_gas():
    """Cohesive disks with rolling resistance in a cell periodic along both axes, under stress control."""
    rng = np.random.default_rng(4)
    r = radii(N, radius_min=0.4, radius_max=0.6, distribution="uniform", seed=4)
    side = float(np.sqrt(np.pi * np.sum(r ** 2) / 0.5))
    law = ContactLaw(normal_stiffness=1e3, tangential_stiffness=500.0, friction=0.4, damping_ratio=0.2,
                     tangential_model="angle", rolling_stiffness=100.0, rolling_friction=0.05, cohesion_force=2.0,
                     cohesion_range=0.05)
    sim = Simulation(ParticleState(random_gas(r, (0.0, side, 0.0, side), periodic=(True, True), seed=4), r,
                                   velocity=rng.normal(0.0, 3.0, (N, 2)), omega=rng.normal(0.0, 1.0, N)),
                     law, Integration(dt_safety=0.1), cell=PeriodicCell((side, side)))
    sim.set_cell_stress(5.0)
    return sim


def sheared_layer():
    """Disks between a sliding floor and a lid pressing down, periodic along x, under gravity: wall rows
    whose anchors move when their disk is wrapped."""
    rng = np.random.default_rng(4)
    r = radii(N, radius_min=0.4, radius_max=0.6, distribution="uniform", seed=4)
    side = float(np.sqrt(np.pi * np.sum(r ** 2) / 0.45))
    law = ContactLaw(normal_stiffness=1e3, tangential_stiffness=500.0, friction=0.4, damping_ratio=0.2,
                     tangential_model="alpha")
    walls = [Wall(normal=(0.0, 1.0), position=0.0, tangential_velocity=2.0, name="floor"),
             Wall(normal=(0.0, -1.0), position=-side, mode="velocity", velocity=0.2, name="lid")]
    return Simulation(ParticleState(random_gas(r, (0.0, side, 0.6, side - 0.6), periodic=(True, False), seed=4), r,
                                    velocity=rng.normal(0.0, 2.0, (N, 2))),
                      law, Integration(dt_safety=0.1), walls=walls, cell=PeriodicCell((side, side), periodic=(True, False)),
                      gravity=(0.0, -1.0))


def both(sim, capacity=None):
    """The state of ``sim`` rebuilt by the CPU engine and on the device (each from its own copy; ``capacity``: a
    table of that many rows instead): ``(cpu, device)``, each ``(code, arrays...)``."""
    def state():
        arrays = [type(t)(*(np.array(a) for a in t)) for t in (sim.particles.arrays(), sim.walls.arrays(),
                                                               sim.cell.arrays(), sim.contacts.arrays(),
                                                               sim._spare.arrays())]
        if capacity is not None:
            for k in (3, 4):
                arrays[k] = ContactArrays(*(np.zeros(1, np.int64) if name == "count" else a[:capacity]
                                            for name, a in zip(ContactArrays._fields, arrays[k])))
        return arrays + [type(sim.workspace)(*(np.array(a) for a in sim.workspace))]

    extra = sim._law_vector[D0] + sim.skin
    p, w, cell, ct, spare, ws = cpu = state()
    cpu_code = rebuild(p, w, cell, ct, spare, ws, sim._law_vector, sim.skin)
    p, w, cell, ct, spare, ws = device = state()
    on_device = DeviceState(p, w, cell, ct, ws)
    device_code, _ = DeviceTable(on_device, p.radius, extra).rebuild(on_device)
    on_device.download()
    return (cpu_code, *cpu), (device_code, *device)


def report(case, sim, capacity=None):
    (cpu_code, p, w, cell, ct, _, ws), (device_code, dp, _, _, dct, _, dws) = both(sim, capacity)
    rows = int(ct.count[0])
    wall_rows = (ct.particle_j[:rows] >= p.position.shape[0]) & (ct.status[:rows] != STATUS_NONE)
    print(json.dumps({
        "case": case, "codes": [int(cpu_code), int(device_code)], "rows": [rows, int(dct.count[0])],
        "touching": int(np.sum(ct.status[:rows] != STATUS_NONE)),
        "wrapped": int(np.sum(np.any(ws.wraps != 0, axis=1))),
        "touching_walls_wrapped": int(np.sum(np.any(ws.wraps[ct.particle_i[:rows][wall_rows]] != 0, axis=1))),
        "needed": [float(ws.info[INFO_NEEDED]), float(dws.info[INFO_NEEDED])],
        "lost": [float(ws.info[INFO_LOST]), float(dws.info[INFO_LOST])],
        "table_equal": all(np.array_equal(getattr(ct, name)[:rows], getattr(dct, name)[:rows])
                           for name in ContactArrays._fields),
        "disks_equal": bool(np.array_equal(p.position, dp.position)),
        "workspace_equal": all(np.array_equal(getattr(ws, name), getattr(dws, name))
                               for name in ("wrapped", "wraps", "reference", "wall_reference", "length_reference",
                                            "flags", "info")),
    }), flush=True)


for name, make in (("cohesive_gas", cohesive_gas), ("sheared_layer", sheared_layer)):
    sim = make()
    sim.run(600)
    # a translation: every pair as it was, a third of the disks now past the cell's far side
    sim.particles.position[:, 0] += 0.37 * sim.cell.length[0]
    report(name, sim)
    report(f"{name}, a table of 10 rows", sim, capacity=10)
    # a touching disk moved by the cell's length: the old rows' images no longer those of its pairs
    rows = sim.contacts.count
    sim.particles.position[sim.contacts.particle_i[np.argmax(sim.contacts.status[:rows] != STATUS_NONE)], 0] += \
        sim.cell.length[0]
    report(f"{name}, a touching disk moved by the cell's length", sim)
