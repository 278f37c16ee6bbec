"""Teaching experiments against the formulas they illustrate."""

import math

import pytest

from granlab.engine.protocols import teaching


@pytest.mark.parametrize("zeta", [0.0, 0.3, 0.7])
def test_collision_restitution_and_duration_match_spring_dashpot(zeta):
    result = teaching.collision(zeta=zeta, steps_per_collision=400)
    assert result.restitution == pytest.approx(math.exp(-math.pi * zeta / math.sqrt(1 - zeta ** 2)), abs=5e-3)
    assert result.restitution == pytest.approx(result.restitution_predicted, abs=5e-3)
    assert result.contact_duration == pytest.approx(result.contact_duration_predicted, abs=2 * result.dt)


@pytest.mark.parametrize("zeta", [0.3, 0.7])
def test_collision_restitution_error_is_second_order_in_the_time_step(zeta):
    """The dashpots take the velocities predicted at the whole step and the share of each step's
    window the contact spends touching: the error falls ~4 times per halving of dt, whatever the
    phase of the contact's ends between steps (dt = duration / 100.37: no whole number of steps)."""
    duration = teaching.collision(zeta=zeta).contact_duration_predicted
    errors = [abs(r.restitution / r.restitution_predicted - 1.0)
              for r in (teaching.collision(zeta=zeta, dt=duration / (100.37 * 2 ** k)) for k in range(4))]
    # each halving divides the error by ~4 (first order: 2); the phase of the ends adds a little noise
    assert all(errors[k] / errors[k + 1] > 2.8 for k in range(3)), errors
    assert 1.8 < math.log2(errors[0] / errors[3]) / 3 < 2.2, errors


@pytest.mark.parametrize("zeta", [0.1, 0.3, 0.5, 0.7])
def test_collision_restitution_is_within_a_thousandth_at_the_default_step(zeta):
    result = teaching.collision(zeta=zeta)  # 200 steps per contact
    assert result.restitution == pytest.approx(result.restitution_predicted, rel=1e-3)


def test_collision_with_friction_and_tangential_models_is_head_on():
    for model in ("cundall-strack", "alpha", "angle"):
        result = teaching.collision(model=model, zeta=0.2, mu=0.5)
        assert result.restitution == pytest.approx(result.restitution_predicted, abs=1e-2)


def test_block_obeys_the_principle_of_minimum_sliding():
    result = teaching.block(mu=0.5)
    assert result.max_Ft_over_muFn <= 1.0 + 1e-12
    assert result.slid and result.stuck_again
    # it slides only once the load exceeds mu F_n, and stops only after the load fell below it
    # (the elastic part reaches mu F_n a little after the load does: the viscous part carries the rest)
    assert result.slide_start_load_ratio == pytest.approx(1.0, abs=1e-2)
    assert result.slide_end_load_ratio < 1.0
    assert result.sliding_while_load_below_limit_and_at_rest == 0
    assert not result.friction_work_positive
    assert all(work < 0 for work in result.friction_work_per_slide)
    assert len(result.path) == len(result.load) == len(result.sliding)


def test_block_that_is_never_pushed_past_the_cone_never_slides():
    result = teaching.block(mu=0.5, peak_ratio=0.9)
    assert not result.slid
    assert result.max_Ft_over_muFn < 0.91
    assert abs(result.slip_distance) < 1e-3


def test_closed_path_result_reports_the_paper_quantities():
    result = teaching.closed_path(model="cundall-strack").as_dict()
    for key in ("delta_Dt", "predicted_delta_Dt", "enclosed_area"):
        assert isinstance(result[key], float)
    assert result["enclosed_area"] > 0


def test_one_registry_names_the_tangential_models_for_the_kernels_the_command_line_and_the_experiments():
    """engine.params.TANGENTIAL is the only list of the models: the kernels' modules and codes, the choices of
    the command line and the lab, and the closed path's prediction (Eq. 17's residue only for a
    path-dependent spring) come from it."""
    from granlab.app.commands import build_parser
    from granlab.engine.kernels import tangential
    from granlab.engine.params import TANGENTIAL, TANGENTIAL_MODELS
    from granlab.engine.protocols.settings import LabSettings

    codes = [model.code for model in TANGENTIAL.values()]
    assert TANGENTIAL_MODELS == tuple(TANGENTIAL) and len(set(codes)) == len(codes)
    assert tangential.CODES == tuple(sorted(codes))
    for model in TANGENTIAL.values():
        laws = tangential.MODELS[model.code]
        assert all(callable(getattr(laws, f)) for f in ("spring_rate", "trial_spring", "limit", "centre_factor"))
    commands = next(a for a in build_parser()._actions if a.dest == "command").choices
    experiment = next(a for a in commands["experiment"]._actions if a.dest == "model")
    study = next(a for a in next(a for a in commands["study"]._actions if a.dest == "kind").choices["ratchet"]._actions
                 if a.dest == "model")
    assert tuple(experiment.choices) == tuple(study.choices) == TANGENTIAL_MODELS + ("all",)
    for name, model in TANGENTIAL.items():
        assert LabSettings(tangential_model=name).tangential_model == name
        predicted = teaching.closed_path(model=name).predicted_delta_Dt
        assert (predicted != 0.0) == model.path_dependent
