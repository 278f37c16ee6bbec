"""Every registered tangential model (engine.params.TANGENTIAL), a fourth added as the proof that a
model is one module: the closed path of ratcheting Fig. 8, energy with mu = 0, random impacts."""

import math

import numpy as np
import pytest

from granlab.engine import ContactLaw, Integration, ParameterError, ParticleState, Simulation
from granlab.engine.params import TANGENTIAL
from granlab.engine.protocols import teaching

from .conftest import periodic_gas


@pytest.mark.parametrize("model", list(TANGENTIAL))
def test_every_model_runs_the_closed_path_and_leaves_the_residue_its_registry_entry_promises(model):
    result = teaching.closed_path(model=model)
    assert not result.slid and result.final_position_error < 1e-12
    if TANGENTIAL[model].path_dependent:
        # Eq. 17: a / (r_i + r_j), to O(overlap / radius)
        assert result.delta_Dt == pytest.approx(result.predicted_delta_Dt, rel=1e-2)
        assert abs(result.delta_Dt) > 1e-3 * result.max_abs_Dt
    else:
        assert result.predicted_delta_Dt == 0.0
        assert abs(result.delta_Dt) < 1e-9 * result.max_abs_Dt


@pytest.mark.parametrize("model", list(TANGENTIAL))
def test_every_model_conserves_the_energy_of_a_spinning_gas_without_friction(model):
    law = ContactLaw(normal_stiffness=1e3, tangential_stiffness=1e3, friction=0.0, tangential_model=model)
    sim = periodic_gas(law=law, count=80, length=16.0)
    start = sim.energy()
    sim.run(8000)
    end = sim.energy()
    assert sim.workspace.info[4] > 10  # rebuilds: the disks travelled
    assert end.dissipated == 0.0
    assert abs(end.balance - start.balance) < 5e-4 * start.balance


def _kinetic(sim):
    p = sim.particles
    return float(0.5 * np.sum(p.mass * np.sum(p.velocity ** 2, axis=1)) + 0.5 * np.sum(p.inertia * p.omega ** 2))


@pytest.mark.parametrize("model", list(TANGENTIAL))
def test_every_model_takes_energy_out_of_random_oblique_impacts_never_puts_it_in(model):
    """30 random impacts of two disks (sizes, offsets, spins, friction, damping): once they part,
    the kinetic energy (translation and rotation) is below what it was, and the tallies account
    for the loss. (LAMMPS's rescaling of a damped spring can stretch it as it slides: its sliding
    tally alone may be negative, the sum is not.)"""
    rng = np.random.default_rng(11)
    for _ in range(30):
        radius = rng.uniform(0.3, 0.6, 2)
        offset = rng.uniform(-0.95, 0.95) * radius.sum()
        x = -math.sqrt((radius.sum() + 0.01) ** 2 - offset ** 2)
        law = ContactLaw(normal_stiffness=1e4, tangential_stiffness=rng.uniform(0.2, 1.0) * 1e4,
                         friction=rng.uniform(0.05, 1.5), damping_ratio=rng.uniform(0.05, 0.7),
                         tangential_damping=rng.choice([0.0, rng.uniform(0.0, 5.0)]), tangential_model=model)
        particles = ParticleState([[0.0, 0.0], [x, offset]], radius, velocity=[[0.0, 0.0], [1.0, 0.0]],
                                  omega=rng.normal(0.0, 3.0, 2))
        sim = Simulation(particles, law, Integration(dt_safety=0.05))
        before = _kinetic(sim)
        sim.run_for(0.4)
        assert np.all(sim.contacts.surface_gap[:sim.contacts.count] > 0.0)  # parted
        after = _kinetic(sim)
        budget = sim.energy()
        assert after < before
        assert budget.dissipated > 0.0
        # second order with GranLab's whole-step dashpots (worst 2e-4 here), first with LAMMPS's (5e-3)
        assert abs(budget.balance - before) < (1e-3 if TANGENTIAL[model].whole_step_dashpots else 1e-2) * before


def test_any_number_of_models_gets_a_colour_and_a_line_of_its_own():
    """A fifth, seventh or seventieth registered model is drawn in a style no other model has (the
    colours were zipped with six, and a seventh model stopped ``import granlab.app.lab.plots``)."""
    from granlab.app.lab.plots import LINES, MODEL_STYLES, model_styles

    styles = model_styles([f"model-{i}" for i in range(70)])
    assert len(set(styles.values())) == 70
    assert MODEL_STYLES == model_styles(TANGENTIAL)
    assert [line[2:] for line in LINES["springs"]["lines"]] == [(m.label, *MODEL_STYLES[m.name])
                                                                for m in TANGENTIAL.values()]


def test_the_kernels_dispatch_from_python_to_each_model_s_own_kernel():
    """The dispatchers the contact loop compiles per model returned None when called from Python."""
    from granlab.engine.kernels import tangential

    row = tangential.RowGeometry(1.0, 0.0, 1.9, 0.0, 0.0, 0.3, 1.0, 0.9, 0.1, 0.2, 0.05, 0.1, False, 0.0, 0.0, 0.0,
                                 0.0, 1.0)
    for model in TANGENTIAL.values():
        own = tangential.MODELS[model.code]
        assert tangential.spring_rate(model.code, 0.3, 0.1, 1.02) == own.spring_rate(0.3, 0.1, 1.02) is not None
        assert tangential.trial_spring(model.code, 0.01, 0.2, 1e-3, False, row) == \
            own.trial_spring(0.01, 0.2, 1e-3, False, row)
        assert tangential.limit(model.code, 100.0, 0.5, 0.0, 1.0, 1.0, 0.02, 0.1) == \
            own.limit(100.0, 0.5, 0.0, 1.0, 1.0, 0.02, 0.1)
        assert tangential.centre_factor(model.code, 1.02) == own.centre_factor(1.02)
        assert tangential.whole_step_dashpots(model.code) is model.whole_step_dashpots


def test_normal_laws_have_one_registry_the_kernels_and_the_simulation_read():
    from granlab.engine.kernels import normal
    from granlab.engine.params import NORMAL, NORMAL_MODELS

    assert NORMAL_MODELS == tuple(NORMAL) == ("linear", "area")
    assert normal.CODES == tuple(sorted(model.code for model in NORMAL.values()))
    assert {code: law.__name__.rpartition(".")[2] for code, law in normal.MODELS.items()} == \
        {model.code: model.key for model in NORMAL.values()}
    assert len({model.code for model in NORMAL.values()}) == len(NORMAL)
    for name, model in NORMAL.items():
        sim = periodic_gas(count=20, length=12.0, law=ContactLaw(normal_model=name))
        assert sim.normal_model_code == model.code
    with pytest.raises(ParameterError, match="one of 'linear', 'area'"):
        ContactLaw(normal_model="hertz")
