"""The gathered contact pass (engine/kernels/gathered.py) against the direct one: the same run,
bit for bit, for every tangential and normal model, with walls, rolling resistance, cohesion and a
deforming cell. Each run is checked to have exercised what it claims (sticking and sliding rows,
rows that open and close)."""

import dataclasses

import numpy as np
import pytest

from granlab.engine import ContactLaw, Integration, ParticleState, PeriodicCell, Simulation, Wall
from granlab.engine.generate import radii, random_gas
from granlab.engine.kernels.gathered import BLOCK, C_HOT
from granlab.engine.params import NORMAL_MODELS, TANGENTIAL_MODELS
from granlab.engine.state import STATUS_SLIDE_NEG, STATUS_SLIDE_POS, STATUS_STICK

from .conftest import periodic_gas

LAW = ContactLaw(normal_stiffness=1e3, tangential_stiffness=700.0, friction=0.4, damping_ratio=0.3,
                 tangential_damping=2.0)


def dense_gas(law, cell=None):
    """120 disks at a solid fraction of 0.52 in a periodic cell: contacts that stick, slide, open and close."""
    sim = periodic_gas(count=120, length=13.5, seed=3, speed=1.0, law=law)
    if cell is not None:
        sim = Simulation(sim.particles, law, sim.integration, cell=cell)
    return sim


def settled_box(law):
    """80 disks falling onto a floor between two side walls, with gravity."""
    r = radii(80, radius_min=0.4, radius_max=0.6, distribution="uniform", seed=5)
    positions = random_gas(r, (0.0, 10.0, 0.0, 14.0), periodic=(False, False), seed=5)
    walls = (Wall((0.0, 1.0), 0.0, name="floor"), Wall((1.0, 0.0), 0.0, name="left"),
             Wall((-1.0, 0.0), -10.0, name="right"))
    return Simulation(ParticleState(positions, r), law, Integration(dt_safety=0.1), walls=walls, gravity=(0.0, -5.0))


def run_state(make, gathered, steps, law):
    sim = make(law)
    sim.gathered = gathered
    touching = sliding = 0
    for _ in range(steps // 50):
        sim.run(50)
        status = sim.contacts.arrays().status[:sim.contacts.count]
        touching += int(np.isin(status, (STATUS_STICK, STATUS_SLIDE_POS, STATUS_SLIDE_NEG)).sum())
        sliding += int(np.isin(status, (STATUS_SLIDE_POS, STATUS_SLIDE_NEG)).sum())
    p, ct = sim.particles.arrays(), sim.contacts.arrays()
    arrays = {name: np.array(getattr(p, name)) for name in ("position", "velocity", "angle", "omega", "force",
                                                            "torque")}
    arrays.update({name: np.array(getattr(ct, name))[:sim.contacts.count] for name in (
        "particle_i", "particle_j", "status", "tangential_spring", "rolling_spring", "anchor_angle_i",
        "anchor_angle_j", "normal_force", "tangential_force", "surface_gap")})
    arrays["energy"] = np.array(sim.workspace.energy)
    arrays["cell"] = np.array(sim.cell.arrays().length)
    hot = int(sim.workspace.row_columns[:, C_HOT * BLOCK:(C_HOT + 1) * BLOCK].sum())
    return arrays, touching, sliding, hot


def assert_same_run(make, law, steps=400):
    direct, touching, sliding, _ = run_state(make, False, steps, law)
    gathered, _, _, hot = run_state(make, True, steps, law)
    assert touching > 100 and sliding > 5, (touching, sliding)
    # the last block's rows computed over gathered columns: none where the models run every row directly
    assert (hot > 0) == (law.normal_model == "linear"), hot
    for name, value in direct.items():
        assert np.array_equal(gathered[name], value, equal_nan=True), name


@pytest.mark.parametrize("normal", NORMAL_MODELS)
@pytest.mark.parametrize("tangential", TANGENTIAL_MODELS)
def test_every_model_the_same_bit_for_bit(tangential, normal):
    law = dataclasses.replace(LAW, tangential_model=tangential, normal_model=normal)
    assert_same_run(dense_gas, law)


@pytest.mark.parametrize("tangential", TANGENTIAL_MODELS)
def test_walls_gravity_and_rolling_resistance(tangential):
    law = dataclasses.replace(LAW, tangential_model=tangential, rolling_stiffness=50.0, rolling_friction=0.05,
                              rolling_damping_ratio=0.2)
    assert_same_run(settled_box, law, steps=3000)


def test_cohesion_and_a_cell_under_stress():
    law = dataclasses.replace(LAW, cohesion_force=5.0, cohesion_range=0.05, rolling_stiffness=50.0,
                              rolling_friction=0.05)
    cell = PeriodicCell((13.5, 13.5), control=("stress", "stress"), stress=(1.0, 1.0))
    assert_same_run(lambda law: dense_gas(law, cell), law)
