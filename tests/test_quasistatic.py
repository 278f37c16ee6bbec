"""The quasi-static stepper (granlab.engine.protocols.quasistatic): the block of quasi-rigidity
Fig. 2 against its analytic path, the consistent status unique on every step of a biaxial packing,
the dynamics converging to the stepper as the load is ramped more slowly, and its refusals."""

import math

import numpy as np
import pytest

from granlab.app.commands import main
from granlab.engine.errors import GranLabError, ParameterError
from granlab.engine.io.scene import load_scene
from granlab.engine.params import ContactLaw, Integration, PeriodicCell, Wall
from granlab.engine.protocols.prepare import compress
from granlab.engine.protocols.quasistatic import (Targets, compare, difference, follow, follow_dynamically,
                                                  out_of_balance)
from granlab.engine.simulation import Simulation
from granlab.engine.state import ParticleState

MU, WEIGHT, K = 0.5, 1.0, 1.0e3  # the built-in scene "block"


@pytest.fixture(scope="module")
def block():
    scene = load_scene("block")
    sim = scene.build()
    sim.run(scene.step_count(sim.dt))
    return sim


@pytest.fixture(scope="module")
def box():
    return compress(16, seed=0, pressure=1.0, friction=0.2).sim


def test_the_block_follows_its_spring_and_gives_way_at_mu_times_its_weight(block):
    """Quasi-rigidity Sec. II C: F_t^ext <= mu F_n keeps the block in place on its tangential spring,
    x = F_t / K_t; past mu F_n no equilibrium exists and the stepper stops there, naming the contact."""
    path = follow(block, Targets(forces={0: (1.5 * MU * WEIGHT, 0.0)}), steps=20)
    assert path.stop == "collapse"
    assert path.reached == pytest.approx(1.0 / 1.5, abs=1e-4)
    assert path.reached < 1.0 / 1.5
    assert "0–wall 'floor' sliding" in path.stop_detail
    moved = path.positions[:, 0] - path.positions[0, 0]
    np.testing.assert_allclose(moved[:, 0], path.load * 1.5 * MU * WEIGHT / K, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(moved[:, 1], 0.0, atol=1e-15)
    assert (path.sliding == 0).all()


def test_a_block_lifted_off_the_floor_stops_where_its_contact_opens(block):
    path = follow(block, Targets(forces={0: (0.0, 1.5 * WEIGHT)}), steps=10)
    assert path.stop == "network"
    assert path.reached == pytest.approx(1.0 / 1.5, abs=1e-4)
    assert path.stop_detail.endswith("contact 0–wall 'floor' opens")


def test_the_block_in_the_dynamics_converges_to_the_stepper(block):
    """Ramped ten times more slowly, the dynamics end ten times closer (or more) to the quasi-static state."""
    targets = Targets(forces={0: (0.8 * MU * WEIGHT, 0.0)})
    path = follow(block, targets, steps=10)
    assert path.stop == "target"
    fast, slow = (difference(path, follow_dynamically(block, targets, t), np.zeros(1, bool)) for t in (5.0, 50.0))
    assert slow["disks"] < fast["disks"] / 10
    assert slow["disks"] < 1e-4


def _corner(gap: float, push: float) -> Simulation:
    """The block in a corner: on the floor (friction 0.5), the wall 'left' at ``gap`` from it, pushed
    along x by ``push``, settled."""
    law = ContactLaw(normal_stiffness=K, tangential_stiffness=K, friction=MU, damping_ratio=0.7)
    disk = ParticleState([[0.0, 0.5 - WEIGHT / K]], [0.5], mass=[1.0], inertia=[math.inf])
    disk.external_force[0] = (push, 0.0)
    walls = (Wall((0.0, 1.0), 0.0, name="floor"), Wall((1.0, 0.0), -0.5 - gap, name="left"))
    sim = Simulation(disk, law, Integration(dt_safety=0.3), walls=walls, gravity=(0.0, -WEIGHT))
    sim.run_for(20.0)
    return sim


def test_contacts_that_open_and_close_on_the_way_are_followed():
    """Pushed into the corner by 0.2, the block rests on the wall's normal spring and the floor's
    tangential one side by side (x = -0.2 / 2K); pulled out by 0.2, it leaves the wall at half the
    change and ends on the floor's spring alone (x = 0.2 / K). 10^-5 from the wall and pushed by 0.3,
    it reaches the wall at 0.01 (K_t 10^-5), and the two springs share the rest."""
    pulled = follow(_corner(0.0, -0.2), Targets(forces={0: (0.2, 0.0)}), steps=10)
    assert pulled.stop == "target"
    assert [(kind, name) for _, kind, name in pulled.events] == [("opened", "0–wall 'left'")]
    assert 0.5 <= pulled.events[0][0] <= 0.6
    moved = pulled.positions[-1, 0, 0] - pulled.positions[0, 0, 0]
    assert moved == pytest.approx(0.2 / K + 0.2 / (2 * K), rel=1e-6)
    pushed = follow(_corner(1e-5, 0.0), Targets(forces={0: (-0.3, 0.0)}), steps=10)
    assert pushed.stop == "target"
    assert [(kind, name) for _, kind, name in pushed.events] == [("closed", "0–wall 'left'")]
    assert pushed.events[0][0] <= 0.1
    moved = pushed.positions[-1, 0, 0] - pushed.positions[0, 0, 0]
    assert moved == pytest.approx(-1e-5 - 0.29 / (2 * K), rel=1e-6)


def test_the_consistent_status_is_unique_on_every_step_and_the_dynamics_converge(box):
    """A 16-disk biaxial packing (ratcheting Sec. IV B 1, mu = 0.2) under 10 % more load on its top
    wall: contacts reach the Coulomb cone on the way, every step has exactly one consistent state
    of its critical contacts (all 2^M_c enumerated), and the dynamics approach the stepper's end as
    the ramp slows."""
    targets = Targets(walls={"top": 1.1})
    path = follow(box, targets, steps=20, check_unique=True)
    assert path.stop == "target"
    checked = path.consistent_states[path.consistent_states >= 0]
    assert len(checked) >= 3 and (checked == 1).all()
    top = path.wall_names.index("top")
    assert path.wall_offsets[-1, top] > path.wall_offsets[0, top]
    mobile = np.array([name in ("top", "right") for name in path.wall_names])
    fast, slow = (difference(path, follow_dynamically(box, targets, t), mobile) for t in (10.0, 100.0))
    assert slow["walls"] < fast["walls"] / 10
    assert slow["disks"] < fast["disks"] / 10
    assert slow["disks"] < 1e-4


def test_the_start_must_be_in_equilibrium(block):
    unsettled = block.clone()
    unsettled.particles.external_force[0] = (0.3, 0.0)
    assert out_of_balance(unsettled) > 1e-3
    assert out_of_balance(block) < 1e-6
    with pytest.raises(GranLabError, match="the start is not in equilibrium"):
        compare(unsettled, Targets(forces={0: (0.1, 0.0)}))


def test_what_the_stepper_cannot_follow_is_refused_by_name(block):
    with pytest.raises(ParameterError, match="wall = 'top' is not allowed: one of floor"):
        follow(block, Targets(walls={"top": 1.0}))
    with pytest.raises(ParameterError, match="in force mode"):
        follow(block, Targets(walls={"floor": 1.0}))
    with pytest.raises(ParameterError, match="0 <= index < 1"):
        follow(block, Targets(forces={3: (1.0, 0.0)}))
    gas = Simulation(ParticleState([[1.0, 1.0]], [0.5]), ContactLaw(), Integration(), cell=PeriodicCell((4.0, 4.0)))
    with pytest.raises(ParameterError, match="periodic"):
        follow(gas, Targets(forces={0: (1.0, 0.0)}))
    sticky = block.clone(cohesion_force=0.1, cohesion_range=0.01)
    with pytest.raises(ParameterError, match="without cohesion"):
        follow(sticky, Targets(forces={0: (0.1, 0.0)}))


def test_the_command_prints_the_path_the_stop_and_the_comparison(capsys):
    assert main(["quasistatic", "block", "--force", "0=0.75,0", "--steps", "10", "--compare", "5", "50"]) == 0
    out = capsys.readouterr().out
    assert "stopped at load fraction 0.6666" in out
    assert "the load excites a mechanism" in out and "0–wall 'floor' sliding" in out
    assert "the dynamics ramping the same load" in out


@pytest.mark.parametrize("args, message", [
    (["--wall", "top"], "--wall = 'top' is not allowed: NAME=LOAD"),
    (["--force", "0=1"], "--force = '0=1' is not allowed: I=FX,FY"),
    (["--force", "0=nan,0"], "finite numbers"),
    ([], "at least one --wall NAME=LOAD or --force I=FX,FY"),
    (["--force", "0=0.1,0", "--compare", "-1"], "durations > 0"),
    (["--force", "0=0.1,0", "--steps", "1000000"], "steps = 1000000 is not allowed: a whole number from 1 to 100000"),
])
def test_the_command_refuses_bad_loads_in_one_line(args, message, capsys):
    assert main(["quasistatic", "block", *args]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
