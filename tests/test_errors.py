"""Bad input gets a clear error naming the parameter, the value and what is allowed; nothing is lost."""

import math

import numpy as np
import pytest

from granlab.engine import (ContactLaw, DivergenceError, Integration, Load, ParameterError, ParticleState,
                            PeriodicCell, SceneError, Simulation, Wall, box_walls)
from granlab.engine.io.scene import parse_scene


@pytest.mark.parametrize("field,value,allowed", [
    ("normal_stiffness", 0.0, "positive"),
    ("normal_stiffness", -5.0, "positive"),
    ("tangential_stiffness", -1.0, "positive"),
    ("friction", -0.1, "a friction coefficient >= 0, or inf (no sliding)"),
    ("damping_ratio", 1.0, "[0, 1)"),
    ("damping_ratio", -0.2, ">= 0"),
    ("friction", math.nan, "not NaN"),
    ("normal_stiffness", math.inf, "finite"),
    ("tangential_model", "hertz", "'cundall-strack', 'alpha', 'angle', 'lammps'"),
    ("normal_model", "cubic", "'linear', 'area'"),
    ("cohesion_force", -1.0, ">= 0"),
    ("rolling_friction", -0.01, ">= 0"),
])
def test_invalid_contact_law_names_parameter_value_and_allowed(field, value, allowed):
    with pytest.raises(ParameterError) as error:
        ContactLaw(**{field: value})
    message = str(error.value)
    assert message.startswith(f"{field} = ")
    assert allowed in message
    assert error.value.name == field


def test_cohesion_without_a_range_is_refused():
    with pytest.raises(ParameterError, match=r"cohesion_range = 0.0 is not allowed: a range > 0 with "
                                             r"cohesion_force = 0.3"):
        ContactLaw(cohesion_force=0.3)
    assert ContactLaw(cohesion_force=0.3, cohesion_range=0.01).cohesion_range == 0.01


def test_invalid_radius_and_positions():
    with pytest.raises(ParameterError, match=r"radius\[1\] = 0.0 is not allowed: a positive radius"):
        ParticleState([[0, 0], [3, 0]], [1.0, 0.0])
    with pytest.raises(ParameterError, match=r"position\[1\] = \[nan, 0.0\] is not allowed: finite numbers"):
        ParticleState([[0, 0], [math.nan, 0]], [1.0, 1.0])
    with pytest.raises(ParameterError, match=r"kind\[0\] = 'frozen'.*dynamic, fixed, kinematic"):
        ParticleState([[0, 0]], [1.0], kind=["frozen"])


def test_overlapping_initial_disks_beyond_tolerance_are_refused():
    particles = ParticleState([[0, 0], [1.7, 0]], [1.0, 1.0])
    with pytest.raises(ParameterError) as error:
        Simulation(particles, ContactLaw())
    assert "initial overlap of disk 0 and disk 1 / smaller radius = 0.3 is not allowed: at most 0.1" in str(error.value)
    Simulation(ParticleState([[0, 0], [1.95, 0]], [1.0, 1.0]), ContactLaw())


def test_time_step_above_stability_bound_is_refused():
    particles = ParticleState([[0, 0], [3, 0]], [1.0, 1.0], mass=[1.0, 1.0])
    with pytest.raises(ParameterError, match=r"dt = 1.0 is not allowed: a time step at most the stability bound"):
        Simulation(particles, ContactLaw(normal_stiffness=1e4), Integration(dt=1.0))


def test_runtime_changes_are_validated_and_lose_nothing():
    particles = ParticleState([[0, 0], [3, 0]], [1.0, 1.0], mass=[1.0, 1.0])
    sim = Simulation(particles, ContactLaw(normal_stiffness=1e3), Integration(dt=0.002))
    law = sim.law
    with pytest.raises(ParameterError, match="friction = -1"):
        sim.set_law(friction=-1.0)
    with pytest.raises(ParameterError, match="dt = 0.002 is not allowed"):
        sim.set_law(normal_stiffness=1e7)
    with pytest.raises(ParameterError, match="spring = 3"):
        sim.set_law(spring=3)
    assert sim.law is law and sim.dt == 0.002
    sim.set_law(friction=0.2, tangential_model="angle")
    assert sim.law.friction == 0.2 and sim.law.tangential_model == "angle"


def _dense_box():
    x, y = np.meshgrid(np.arange(5) * 1.0 + 0.5, np.arange(5) * 1.0 + 0.5)
    particles = ParticleState(np.column_stack([x.ravel(), y.ravel()]), 0.49, mass=np.ones(25))
    return Simulation(particles, ContactLaw(normal_stiffness=100.0, damping_ratio=0.3),
                      walls=box_walls(0, 5, 0, 5), gravity=(0.0, -1.0))


def test_overlap_divergence_stops_and_keeps_last_good_state():
    sim = _dense_box()
    sim.run(200)
    good = sim.particles.position.copy()
    good_time = sim.time
    sim.set_gravity(0.0, -1e5)
    # the overlap check, or the step-length check that sees the same blow-up a step sooner
    with pytest.raises(DivergenceError, match=r"an overlap reached .* of a radius, above max_overlap = 0.5|"
                                              r"moved .* of its radius in one step"):
        sim.run(5000)
    assert sim.time == good_time
    np.testing.assert_array_equal(sim.particles.position, good)
    sim.set_gravity(0.0, -1.0)
    sim.run(100)
    assert sim.time > good_time


def test_a_fast_disk_with_nothing_in_reach_flies_on_until_something_is():
    """A disk moving 20 radii a step, 2000 radii from the only other disk and the walls, is no
    tunnelling risk (was stopped at once); heading for a wall it is stopped before it reaches it."""
    wall = Wall(normal=(-1.0, 0.0), position=-3000.0, name="right")
    particles = ParticleState([[0.0, 0.0], [-2000.0, 0.0]], [0.5, 0.5], velocity=[[-1e4, 0.0], [0.0, 0.0]])
    sim = Simulation(particles, ContactLaw(), Integration(dt=1e-3), walls=(wall,))
    sim.run(50)  # 500 of its 2000 radii to the other disk
    assert sim.particles.position[0, 0] == pytest.approx(-500.0)
    sim.particles.velocity[0] = (1e4, 0.0)
    with pytest.raises(DivergenceError, match="disk 0 moved 20 of its radius in one step"):
        sim.run(1000)
    assert 2999.5 - sim.particles.position[0, 0] > 40.0  # stopped short of the wall, nothing passed


@pytest.mark.parametrize("block", [1, 1000])
def test_a_disk_that_would_tunnel_through_another_stops_the_run_naming_it(block):
    """Two disks head-on at +-1e4 with dt = 1e-3 move 20 radii a step: without the check they
    pass through each other and never touch."""
    particles = ParticleState([[-50.0, 0.0], [50.0, 0.0]], [0.5, 0.5], velocity=[[1e4, 0.0], [-1e4, 0.0]])
    sim = Simulation(particles, ContactLaw(), Integration(dt=1e-3))
    with pytest.raises(DivergenceError) as error:
        for _ in range(1000 // block):
            sim.run(block)
    assert error.value.reason == ("disk 0 moved 20 of its radius in one step (speed 1e+04, dt = 0.001), above "
                                  "max_overlap / 2 = 0.25: it could pass through a neighbour (time step too large "
                                  "for this speed)")
    # they flew free while more than 40 apart (twice their moves); the step that brought them in
    # reach of each other is undone
    assert sim.particles.position[1, 0] - sim.particles.position[0, 0] - 1.0 == 59.0
    slow = Simulation(ParticleState([[-1.0, 0.0], [1.0, 0.0]], [0.5, 0.5], velocity=[[1.0, 0.0], [-1.0, 0.0]]),
                      ContactLaw(), Integration(dt=1e-3))
    slow.run(2000)  # 0.002 of a radius a step: they collide and bounce
    assert slow.particles.velocity[0, 0] < 0


def test_nan_divergence_stops_and_keeps_last_good_state():
    sim = _dense_box()
    sim.run(100)
    good = sim.particles.velocity.copy()
    sim.set_gravity(0.0, -1e308)
    with pytest.raises(DivergenceError, match="NaN or infinite|moved .* of its radius in one step"):
        sim.run(50)
    np.testing.assert_array_equal(sim.particles.velocity, good)
    sim.set_gravity(0.0, -1.0)
    assert np.isfinite(sim.energy().balance)
    sim.run(50)


def test_scene_errors_name_the_key_and_what_is_allowed():
    base = "[simulation]\nsteps = 10\n[[particles.disk]]\nx = 0\ny = 0\nr = 1\n"
    cases = {
        base + "[contact]\nfrction = 0.3\n": "unknown key contact.frction: allowed keys are cohesion_force",
        base + "[contact]\nfriction = -0.3\n":
            "[contact] friction = -0.3 is not allowed: a friction coefficient >= 0, or inf (no sliding)",
        base + "[contact]\ntangential_model = 'spring'\n": "tangential_model = 'spring' is not allowed: one of",
        base.replace("steps = 10", "steps = -3"): "simulation.steps = -3 is not allowed: a whole number >= 0",
        base.replace("r = 1", "r = 'big'"): "particles.disk[0].r = 'big' is not allowed: a number",
        base + "[box]\nx = [0, 1]\n": "[box] needs x = [x0, x1] and y = [y0, y1]",
        "[simulation]\nsteps = 1\n": "[particles] is missing",
        base + "friction = = 1\n": "not valid TOML",
        base + "[cell]\nlengths = [10, 10]\ncontrol = ['stress', 'squeeze']\n": "cell.control[1] = 'squeeze'",
        base.replace("x = 0", "x = nan"): "particles.disk[0].x = nan is not allowed: a number",
        base + "[[particles.lattice]]\nrows = 2\ncolumns = 2\nspacing = 3\nradius = 1\nvelocity_spread = nan\n":
            "particles.lattice[0].velocity_spread = nan is not allowed: a number",
        base + "[[particles.lattice]]\nrows = 1000000\ncolumns = 1000000\nspacing = 3\nradius = 1\n":
            "rows × columns = 1000000000000 is not allowed: at most 4000000 disks",
        base.replace("steps = 10", "steps = 10\nthreads = 1000"): "simulation.threads = 1000 is not allowed: at most",
        "title = 5\n" + base: "scene.title = 5 is not allowed: a string",
        base + "[cell]\nlengths = [10, 10]\nstrain_rate = [0.01, 0.01]\n":  # was run as a fixed cell
            "cell.strain_rate = [0.01, 0.01] is not allowed with cell.control = ['fixed', 'fixed']: the cell would "
            "ignore it; give cell.control = ['strain-rate', 'strain-rate']",
        base + "[cell]\nlengths = [10, 10]\ncontrol = ['stress', 'fixed']\nstress = [1, 1]\n":
            "give cell.control = ['stress', 'stress'], or stress 0 on the axes not under stress control",
    }
    for text, expected in cases.items():
        with pytest.raises(SceneError) as error:
            parse_scene(text, origin="test.toml")
        assert expected in str(error.value), str(error.value)
        assert str(error.value).startswith("test.toml")


def test_one_whole_number_check_names_both_bounds():
    """Every count of the engine (steps, cycles, disks, samples, seeds...) goes through one check."""
    from granlab.engine.params import whole

    assert whole("cycles", np.int64(3), 1) == 3 and type(whole("cycles", np.int64(3), 1)) is int
    for value in (True, 2.0, "3", 0, None):
        with pytest.raises(ParameterError, match=f"cycles = {value!r} is not allowed: a whole number >= 1"):
            whole("cycles", value, 1)
    with pytest.raises(ParameterError, match="seed = 4294967296 is not allowed: a whole number from 0 to 4294967295"):
        whole("seed", 2 ** 32, 0, 2 ** 32 - 1)


def _stepper_with_friction(mu):
    from granlab.engine.io.scene import load_scene
    from granlab.engine.protocols.quasistatic import Targets, follow

    sim = load_scene("block").build()
    sim.set_law(friction=mu)
    follow(sim, Targets(forces={0: (0.1, 0.0)}), steps=1)


@pytest.mark.parametrize("make, message", [
    (lambda: ContactLaw(friction=-0.2),
     "friction = -0.2 is not allowed: a friction coefficient >= 0, or inf (no sliding)"),
    (lambda: __import__("granlab.engine.studies", fromlist=["RatchetStudy"]).RatchetStudy(friction=-1.0),
     "friction = -1.0 is not allowed: a friction coefficient >= 0, or inf (no sliding)"),
    (lambda: __import__("granlab.engine.protocols.settings", fromlist=["LabSettings"]).LabSettings(friction=11.0),
     "friction = 11.0 is not allowed: a friction coefficient from 0 to 10, or inf (no sliding)"),
    (lambda: _stepper_with_friction(math.inf),
     "friction = inf is not allowed: a friction coefficient >= 0 (the stepper follows contacts that can slide"),
    (lambda: __import__("granlab.engine.protocols.teaching", fromlist=["block"]).block(mu=0.0),
     "mu = 0.0 is not allowed: a friction coefficient > 0 (the block holds, then slides)"),
])
def test_a_friction_coefficient_has_one_rule_and_each_context_says_what_it_adds(make, message):
    """ContactLaw, a ratchet study, the lab, the quasi-static stepper and the block of quasi-rigidity
    Fig. 2 check μ with params.friction_coefficient: one wording, and what each context asks more."""
    with pytest.raises(ParameterError) as raised:
        make()
    assert message in str(raised.value)


CYCLED_BOX = """
[simulation]
duration = 1.0
[box]
x = [0.0, 6.0]
y = [0.0, 6.0]
wall_mass = 1.0
[box.loads.top]
base = {base}
amplitude = 0.1
period = {period}
[[particles.gas]]
count = 20
radius_min = 0.3
radius_max = 0.5
seed = 1
"""


def test_nonsense_a_scene_could_hold_is_refused_in_one_line():
    """A load period of 10^-6 (and 10^-300) with dt = 1.1e-3 sampled the load hundreds of periods apart, a
    load base of -10^149 pulled the wall away, and a disk wider than its periodic cell overlapped its own
    image: each ran to an exit 0."""
    for period in (1e-6, 1e-300):
        with pytest.raises(SceneError, match=r"scene cannot start: wall 'top' \(\[box\] x, y\) load.period = "
                                             rf"{period:g} is not allowed: at least 20 time steps of 0.00114"):
            parse_scene(CYCLED_BOX.format(base=1.0, period=period)).build()
    parse_scene(CYCLED_BOX.format(base=1.0, period=0.03)).build()  # 26 steps: a load it can follow
    with pytest.raises(SceneError, match=r"^scene: \[box.loads.top\] wall 'top' load.base = -1e\+149 is not allowed: a load "
                                         r"that never pulls: base >= 0 \(a wall pushes on the disks\)$"):
        parse_scene(CYCLED_BOX.format(base=-1e149, period=10.0))
    with pytest.raises(ParameterError, match=r"wall 'top' load.amplitude = -0.3 is not allowed: a load that never "
                                             r"pulls: base \+ 2 amplitude >= 0, so at least -0.25 with base = 0.5"):
        Wall((0.0, -1.0), -6.0, "force", mass=1.0, load=Load(base=0.5, amplitude=-0.3), name="top")
    Wall((0.0, -1.0), -6.0, "force", mass=1.0, load=Load(base=0.5, amplitude=-0.25), name="top")  # down to 0
    Wall((0.0, -1.0), -6.0, "velocity", load=Load(base=-1.0), name="top")  # a load it does not feel
    sim = parse_scene(CYCLED_BOX.format(base=1.0, period=10.0)).build()
    with pytest.raises(ParameterError, match="load.period = 0.001 is not allowed: at least 20 time steps"):
        sim.set_wall_load("top", Load(base=1.0, amplitude=0.1, period=1e-3))
    assert sim.walls.load[sim.wall_index("top"), 2] == pytest.approx(2 * math.pi / 10.0)  # the last good load
    with pytest.raises(ParameterError, match=r"cell length along x = 0.9 is not allowed: more than the widest disk's "
                                             r"diameter 1 \(a disk as wide as its periodic cell would overlap its own "
                                             r"image\)"):
        Simulation(ParticleState([[0.4, 5.0]], [0.5]), ContactLaw(), cell=PeriodicCell((0.9, 10.0)))


def test_a_cell_running_away_stops_the_run_with_the_last_good_state():
    """A periodic cell under a stress of 10^6 with a generalised mass of 10^-6 blew up to disk positions
    of 6·10^11 and the run ended with exit 0."""
    rng = np.random.default_rng(1)
    positions = np.column_stack([np.tile(np.arange(5), 5), np.repeat(np.arange(5), 5)]) * 2.0 + 1.0
    particles = ParticleState(positions + rng.uniform(-0.1, 0.1, (25, 2)), rng.uniform(0.4, 0.6, 25))
    cell = PeriodicCell((10.0, 10.0), control=("stress", "stress"), stress=(1e6, 1e6), mass=1e-6)
    sim = Simulation(particles, ContactLaw(normal_stiffness=1e3, tangential_stiffness=1e3, friction=0.3,
                                           damping_ratio=0.2), cell=cell)
    before = sim.particles.position.copy()
    with pytest.raises(DivergenceError, match=r"more than 1000 times the system's size"):
        sim.run(20000)
    assert sim.step == 0 and np.array_equal(sim.particles.position, before)


def test_a_gas_spreading_in_open_space_is_no_divergence():
    sim = Simulation(ParticleState([[0.0, 0.0], [3.0, 0.0]], [0.5, 0.5], velocity=[[-100.0, 0.0], [100.0, 0.0]]),
                     ContactLaw(), Integration(dt=1e-3))
    sim.run_for(10.0)  # 1000 m apart after 5 000 sizes: no box, so nothing runs away
    assert sim.particles.position[1, 0] - sim.particles.position[0, 0] > 1999.0
