"""Run under numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``) by tests/test_cuda.py: small runs of every
law on the device beside the CPU engine, in one block a batch of steps and in four launches a step, a batch of
boxes a block a box; prints one JSON object a case."""

import json

import numpy as np

from granlab.engine import ContactLaw, Integration, ParticleState, PeriodicCell, Simulation
from granlab.engine.batch import Batch
from granlab.engine.cuda import stepper, transfer
from granlab.engine.cuda.check import compare
from granlab.engine.generate import radii, random_gas
from granlab.engine.params import TANGENTIAL
from granlab.engine.protocols.prepare import biaxial_box

STEPS = 30
BATCH_START = 50
"""The batch's steps on the CPU before the comparison: its disks meet from the 60th on."""
BATCH_STEPS = 80
"""The batch's steps compared: its compression rebuilds its rows seven times in them."""


def loaded_box(tangential_model):
    """16 disks pressed by two loaded walls, the overlap-area normal law, friction and rolling resistance:
    the walls' load, their push and work, the contacts' history."""
    sim = biaxial_box(16, seed=2, normal_model="area", tangential_model=tangential_model, dt_safety=0.3)
    sim.run(400)
    sim.set_law(friction=0.3, rolling_stiffness=20.0, rolling_friction=0.05)
    return sim


def cohesive_cell(tangential_model):
    """24 disks in a periodic cell under stress control: cohesion, rolling resistance, images, the cell's kick."""
    rng = np.random.default_rng(5)
    r = radii(24, radius_min=0.4, radius_max=0.6, distribution="uniform", seed=5)
    positions = random_gas(r, (0.0, 6.5, 0.0, 6.5), periodic=(True, True), seed=5)
    law = ContactLaw(normal_stiffness=1e3, tangential_stiffness=500.0, friction=0.4, damping_ratio=0.2,
                     tangential_model=tangential_model, rolling_stiffness=100.0, rolling_friction=0.05,
                     cohesion_force=2.0, cohesion_range=0.05)
    sim = Simulation(ParticleState(positions, r, velocity=rng.normal(0.0, 1.0, (24, 2)), omega=rng.normal(0.0, 1.0, 24)),
                     law, Integration(dt_safety=0.1), cell=PeriodicCell((6.5, 6.5)))
    sim.set_cell_stress(5.0)
    return sim


def batched_boxes(tangential_model):
    """Three boxes of 12 disks side by side in one batch, their walls pressing (the rows rebuilt every few steps
    once the disks meet, from the CPU's 60th step on): each wall meets its own box's disks alone."""
    sim = Batch([biaxial_box(12, seed=seed, tangential_model=tangential_model, dt_safety=0.3)
                 for seed in range(3)]).sim
    sim.run(BATCH_START)
    return sim


def report(case, model, launches, steps=STEPS):
    result = compare(lambda: case(model), steps)
    print(json.dumps({"case": case.__name__, "model": model, "launches": launches, **result}), flush=True)


for case in (loaded_box, cohesive_cell):  # small tables: a batch of steps in one block
    for model in TANGENTIAL:
        report(case, model, "one a batch")
report(batched_boxes, "lammps", "a block a sample", BATCH_STEPS)
full = stepper.segment_capacity
stepper.segment_capacity = lambda ranges: int(np.max(ranges[:, 1] - ranges[:, 0])) + 1  # the first rebuild overflows
report(batched_boxes, "lammps", "a block a sample, then one system", BATCH_STEPS)
stepper.segment_capacity = full
stepper.SAMPLES_IN_BLOCKS = False
report(batched_boxes, "lammps", "one a batch", BATCH_STEPS)
stepper.ONE_BLOCK_ROWS = 0  # the four launches a step of a larger table, its rows and disks over many blocks
for case, model in ((loaded_box, "angle"), (cohesive_cell, "alpha"), (batched_boxes, "lammps")):
    report(case, model, "four a step", BATCH_STEPS if case is batched_boxes else STEPS)


def resident_cases():
    """A run of several checkpoint blocks (10 steps each here): on the device the state stays there from one
    block to the next, sent once and brought back once, where six calls of one block each send it and bring it
    back six times; a run diverging in its fourth block is put back, on the device as on the CPU, at the state
    that block started from."""
    from granlab.engine import simulation
    from granlab.engine.errors import DivergenceError

    simulation.CHECKPOINT_STEPS = 10

    def crossed(run):
        sim = loaded_box("angle")
        sim.use_backend("cuda")
        before = sum(transfer.CROSSED.values())
        run(sim)
        return sum(transfer.CROSSED.values()) - before

    result = compare(lambda: loaded_box("angle"), 60)
    one_run = crossed(lambda sim: sim.run(60))
    six_runs = crossed(lambda sim: [sim.run(10) for _ in range(6)])
    print(json.dumps({"resident": "six blocks", **result, "bytes_one_run": one_run, "bytes_six_runs": six_runs}),
          flush=True)

    def colliding():
        """Two disks meeting head on, a soft spring: their overlap passes max_overlap in step 36."""
        return Simulation(ParticleState(np.array([[0.0, 0.0], [2.6, 0.0]]), np.array([1.0, 1.0]),
                                        velocity=np.array([[1.0, 0.0], [-1.0, 0.0]])),
                          ContactLaw(normal_stiffness=1.0, tangential_stiffness=0.5),
                          Integration(dt=0.01, max_overlap=0.1, initial_overlap=0.05))

    ends = []
    for backend in ("cpu", "cuda"):
        sim = colliding()
        sim.use_backend(backend)
        try:
            sim.run(100)
        except DivergenceError as error:
            ends.append({"failed_step": error.step, "step": sim.step, "position": sim.particles.position.tolist(),
                         "velocity": sim.particles.velocity.tolist(), "contacts": int(sim.contacts.count)})
    print(json.dumps({"resident": "a divergence in the fourth block", "ends": ends}), flush=True)


resident_cases()
