"""Contact physics against the papers: cohesion, rolling resistance, tangential models, history."""

import math

import numpy as np
import pytest

from granlab.engine import ContactLaw, Integration, ParticleState, Simulation, Wall
from granlab.engine.protocols import teaching
from granlab.engine.state import STATUS_SLIDE_NEG, STATUS_SLIDE_POS, STATUS_STICK

from .conftest import periodic_gas


def test_isolated_cohesive_pair_settles_at_gilabert_deflection():
    # Gilabert Eq. 11: under the attraction -F0 alone, the contact deflects by h0 = F0 / K_N
    f0, kn = 2.0, 1.0e4
    law = ContactLaw(normal_stiffness=kn, tangential_stiffness=kn, damping_ratio=0.5, cohesion_force=f0,
                     cohesion_range=0.01, friction=0.3)
    sim = Simulation(ParticleState([[0.0, 0.0], [1.005, 0.0]], [0.5, 0.5]), law)
    sim.run_for(20.0)
    assert sim.contacts.status[0] == STATUS_STICK
    assert -sim.contacts.surface_gap[0] == pytest.approx(f0 / kn, rel=1e-6)
    assert abs(sim.contacts.normal_force[0]) < 1e-6 * f0


def test_cohesive_pair_beyond_range_does_not_attract():
    law = ContactLaw(cohesion_force=2.0, cohesion_range=0.01)
    sim = Simulation(ParticleState([[0.0, 0.0], [1.02, 0.0]], [0.5, 0.5]), law)
    sim.run(1000)
    assert np.allclose(sim.particles.velocity, 0.0)


def _disk_on_floor_with_torque(torque, ramp=60.0, hold=20.0):
    kr, mu_r, load = 1.0, 0.01, 10.0
    law = ContactLaw(normal_stiffness=1e4, tangential_stiffness=1e4, friction=1.0, damping_ratio=0.5,
                     tangential_damping=50.0, rolling_stiffness=kr, rolling_friction=mu_r)
    particles = ParticleState([[0.0, 0.5 - load / 1e4]], [0.5], mass=[1.0])
    particles.external_force[0] = (0.0, -load)
    sim = Simulation(particles, law, walls=(Wall((0.0, 1.0), 0.0, name="floor"),))
    steps = int(ramp / sim.dt)
    block = max(1, steps // 200)
    for k in range(0, steps, block):
        # a smooth ramp excites no lasting oscillation of the (undamped) rolling spring
        sim.particles.external_torque[0] = torque * 0.5 * (1.0 - math.cos(math.pi * min(1.0, (k + block) / steps)))
        sim.run(block)
    sim.run_for(hold)
    return sim, kr, mu_r, load


def test_rolling_resistance_holds_a_moment_below_mu_r_times_normal_force():
    limit = 0.01 * 10.0
    sim, kr, mu_r, load = _disk_on_floor_with_torque(0.5 * limit)
    assert sim.contacts.rolling_spring[0] == pytest.approx(0.5 * limit / kr, rel=1e-3)
    assert abs(sim.particles.omega[0]) < 1e-4
    assert sim.energy().dissipated_rolling == 0.0


def test_rolling_resistance_yields_beyond_mu_r_times_normal_force():
    limit = 0.01 * 10.0
    sim, kr, mu_r, load = _disk_on_floor_with_torque(2.0 * limit, hold=5.0)
    n_elastic = -sim.contacts.surface_gap[0] * 1e4
    assert abs(sim.contacts.rolling_spring[0]) * kr == pytest.approx(mu_r * n_elastic, rel=1e-6)
    assert abs(sim.particles.omega[0]) > 0.5
    assert sim.energy().dissipated_rolling > 0


@pytest.mark.parametrize("zeta_r", [0.0, 0.15])
def test_a_disk_rocking_on_its_rolling_spring_is_a_damped_oscillator(zeta_r):
    # rolling without slip on a floor: (I + m r²) theta'' = -K_r theta - Gamma_r theta', with
    # Gamma_r = 2 zeta_r sqrt(K_r I) against a wall, so theta = (w0 / w_d) exp(-gamma t) sin(w_d t)
    # with gamma = Gamma_r / (2 I_eff); Gilabert's undamped spring (zeta_r = 0) swings for ever
    kr, r, m, load, w0 = 1.0, 0.5, 1.0, 10.0, 0.02
    law = ContactLaw(normal_stiffness=1e5, tangential_stiffness=1e5, friction=math.inf, damping_ratio=0.5,
                     rolling_stiffness=kr, rolling_friction=math.inf, rolling_damping_ratio=zeta_r)
    particles = ParticleState([[0.0, r - load / 1e5]], [r], mass=[m])
    particles.external_force[0] = (0.0, -load)
    particles.velocity[0] = (-w0 * r, 0.0)  # rolling: the contact point is at rest
    particles.omega[0] = w0
    sim = Simulation(particles, law, walls=(Wall((0.0, 1.0), 0.0, name="floor"),))
    inertia = 0.5 * m * r * r
    i_eff = inertia + m * r * r
    gamma = 2.0 * zeta_r * math.sqrt(kr * inertia) / (2.0 * i_eff)
    w_d = math.sqrt(kr / i_eff - gamma * gamma)
    errors = []
    while sim.time < 4.0 * 2.0 * math.pi / w_d:
        sim.run(20)
        exact = w0 / w_d * math.exp(-gamma * sim.time) * math.sin(w_d * sim.time)
        errors.append(sim.contacts.rolling_spring[0] - exact)
    assert np.max(np.abs(errors)) < 0.01 * w0 / w_d
    assert sim.energy().dissipated_damping == pytest.approx(
        0.5 * i_eff * w0 * w0 - 0.5 * i_eff * sim.particles.omega[0] ** 2
        - 0.5 * kr * sim.contacts.rolling_spring[0] ** 2, rel=0.02, abs=1e-4 * i_eff * w0 * w0)


@pytest.mark.parametrize("model", ["cundall-strack", "alpha", "angle"])
def test_closed_path_changes_the_spring_as_ratcheting_eq17_says(model):
    result = teaching.closed_path(model=model)
    assert not result.slid
    assert result.final_position_error < 1e-12
    if model == "cundall-strack":
        # Eq. 17 (a / (r_i + r_j)) holds up to O(overlap / radius)
        assert result.delta_Dt == pytest.approx(result.predicted_delta_Dt, rel=1e-2)
        assert abs(result.delta_Dt) > 1e-3 * result.max_abs_Dt
    elif model == "alpha":
        # the alpha-corrected integration leaves an integration error only
        assert abs(result.delta_Dt) < 1e-9 * result.max_abs_Dt
    else:
        assert abs(result.delta_Dt) < 1e-14


def _circle_loop(model, steps, radius_of_loop=0.015):
    """Carry the upper disk once around a circle of radius rho (area pi rho²) in a fixed time."""
    law = ContactLaw(normal_stiffness=1e5, tangential_stiffness=1e5, friction=math.inf, tangential_model=model)
    start = np.array([0.0, 0.96])
    particles = ParticleState([start, [0.0, 0.0]], [0.5, 0.5], kind=["kinematic", "fixed"])
    sim = Simulation(particles, law, Integration(dt=1.0 / steps, initial_overlap=0.1))
    for k in range(1, steps + 1):
        psi = 2 * math.pi * k / steps
        target = start + radius_of_loop * np.array([math.cos(psi) - 1.0, math.sin(psi)])
        sim.set_motion(0, (target - sim.particles.position[0]) / sim.dt)
        sim.run(1)
    return sim.contacts.tangential_spring[0]


def test_loop_of_ratcheting_eq17_and_the_alpha_residue_that_scales_with_dt():
    # ratcheting Eq. 17 for Cundall-Strack; Fig. 14: the alpha residue shrinks with dt, CS's does not
    area = math.pi * 0.015 ** 2
    cs = [_circle_loop("cundall-strack", n) for n in (400, 800)]
    alpha = [_circle_loop("alpha", n) for n in (400, 800)]
    angle = _circle_loop("angle", 400)
    # counter-clockwise around a point above the lower disk, D_t grows by the integral of dA / |x_i - x_j|
    # (Green's theorem on Eq. 9), which Eq. 17 approximates by a / (r_i + r_j) to O(overlap / radius)
    assert cs[0] == pytest.approx(area / 0.96, rel=1e-3)
    assert cs[0] == pytest.approx(area / 1.0, rel=0.05)
    assert cs[1] == pytest.approx(cs[0], rel=2e-3)
    assert abs(alpha[0]) < 1e-2 * abs(cs[0])
    assert abs(alpha[1]) == pytest.approx(abs(alpha[0]) / 2, rel=0.1)
    assert abs(angle) < 1e-14


HEIGHT = 0.9


def _sheared_pair(model, shift):
    """Upper disk moved sideways by ``shift`` at height HEIGHT (no rotation, mu = inf) from first contact."""
    law = ContactLaw(normal_stiffness=1e5, tangential_stiffness=1e5, friction=math.inf, tangential_model=model)
    particles = ParticleState([[0.0, HEIGHT], [0.0, 0.0]], [0.5, 0.5], kind=["kinematic", "fixed"])
    sim = Simulation(particles, law, Integration(dt=1e-4, initial_overlap=0.3))
    steps = 100
    sim.set_motion(0, (shift / (steps * sim.dt), 0.0))
    sim.run(steps)
    return sim.contacts.tangential_spring[0]


def test_tangential_models_agree_for_small_and_differ_for_large_displacements():
    # sliding the upper disk sideways by s at height h: CS accumulates h asinh(s/h) (Eq. 9),
    # alpha and angle (r_i + r_j) atan(s/h) (Eqs. 19, 24): equal to first order in s
    h = HEIGHT
    small = [_sheared_pair(m, 1e-6) for m in ("cundall-strack", "alpha", "angle")]
    alpha_factor = 1.0 / h
    assert small[1] == pytest.approx(small[2], rel=1e-9)
    assert small[0] * alpha_factor == pytest.approx(small[2], rel=1e-9)
    large = [_sheared_pair(m, 0.3) for m in ("cundall-strack", "alpha", "angle")]
    assert large[0] == pytest.approx(-h * math.asinh(0.3 / h), rel=1e-3)
    assert large[2] == pytest.approx(-math.atan(0.3 / h), rel=1e-12)
    assert large[1] == pytest.approx(large[2], rel=2e-3)  # alpha: integration error of 100 steps
    assert abs(large[0] - large[2]) > 0.05 * abs(large[2])


def test_sliding_status_names_the_side_of_the_cone():
    result = teaching.block(mu=0.4)
    statuses = set()
    law = ContactLaw(normal_stiffness=1e3, tangential_stiffness=1e3, friction=0.4)
    particles = ParticleState([[0.0, 0.499]], [0.5], mass=[1.0], inertia=[math.inf])
    particles.external_force[0] = (2.0, -1.0)
    sim = Simulation(particles, law, walls=(Wall((0.0, 1.0), 0.0, name="floor"),))
    sim.run(3000)
    statuses.add(int(sim.contacts.status[0]))
    # pushed to +x, the friction on the disk points to -x; t = z × n = -x, so F_t = +mu N^e
    assert statuses == {STATUS_SLIDE_POS}
    assert sim.contacts.tangential_force[0] == pytest.approx(0.4 * -sim.contacts.surface_gap[0] * 1e3)
    particles = ParticleState([[0.0, 0.499]], [0.5], mass=[1.0], inertia=[math.inf])
    particles.external_force[0] = (-2.0, -1.0)
    sim = Simulation(particles, law, walls=(Wall((0.0, 1.0), 0.0, name="floor"),))
    sim.run(3000)
    assert sim.contacts.status[0] == STATUS_SLIDE_NEG
    assert result.max_Ft_over_muFn <= 1.0 + 1e-12


@pytest.mark.parametrize("model", ["cundall-strack", "angle"])
def test_history_survives_neighbour_rebuilds(model):
    law = ContactLaw(normal_stiffness=1e3, tangential_stiffness=800.0, friction=0.5, damping_ratio=0.3,
                     tangential_model=model, cohesion_force=5.0, cohesion_range=0.05, rolling_stiffness=3.0,
                     rolling_friction=0.05)
    rare = periodic_gas(law=law, skin=2.0, seed=3)
    often = periodic_gas(law=law, skin=0.02, seed=3)
    rare.run(4000)
    often.run(4000)
    assert often.workspace.info[4] > 20 * rare.workspace.info[4]
    assert often.status_counts()["non-sliding"] > 30
    np.testing.assert_allclose(often.particles.position, rare.particles.position, atol=1e-9)
    np.testing.assert_allclose(often.particles.omega, rare.particles.omega, atol=1e-7)


def test_a_contact_that_opens_forgets_its_history():
    law = ContactLaw(normal_stiffness=1e4, tangential_stiffness=1e4, friction=math.inf)
    particles = ParticleState([[0.0, 0.999], [0.0, 0.0]], [0.5, 0.5], kind=["kinematic", "fixed"])
    sim = Simulation(particles, law, Integration(dt=1e-4, skin=1.0))
    sim.set_motion(0, (0.1, 0.0))
    sim.run(100)
    loaded = sim.contacts.tangential_spring[0]
    assert abs(loaded) > 5e-4
    sim.set_motion(0, (0.0, 0.1))
    sim.run(100)
    assert sim.contacts.status[0] == 0 and sim.contacts.tangential_spring[0] == 0.0
    sim.set_motion(0, (0.0, -0.1))
    sim.run(100)
    assert sim.contacts.status[0] == STATUS_STICK
    # the new contact only knows the little tangential motion since it closed
    assert abs(sim.contacts.tangential_spring[0]) < 0.01 * abs(loaded)


def test_rolling_distance_of_ratcheting_eq20_for_a_disk_rolling_on_a_fixed_disk():
    # the upper disk rolls over the lower one without sliding: its contact point moves by r psi
    # on each disk for a turn psi of the line of centres, so it turns by (r_i + r_j) psi / r_i;
    # D_t (Eq. 19) stays 0 and the rolling distance (Eq. 20) is r psi
    law = ContactLaw(normal_stiffness=1e5, tangential_stiffness=1e5, friction=math.inf, tangential_model="angle")
    d = 0.999
    particles = ParticleState([[0.0, d], [0.0, 0.0]], [0.5, 0.5], kind=["kinematic", "fixed"])
    sim = Simulation(particles, law, Integration(dt=1e-4, initial_overlap=0.05))
    turn, steps = 0.3, 300
    for k in range(1, steps + 1):
        psi = turn * k / steps
        target = d * np.array([-math.sin(psi), math.cos(psi)])
        velocity = (target - sim.particles.position[0]) / sim.dt
        sim.set_motion(0, velocity, 2.0 * (turn / steps) / sim.dt)
        sim.run(1)
    contact = sim.contact_snapshot()
    assert abs(contact.tangential_spring[0]) < 1e-12
    assert abs(contact.rolling_distance[0]) == pytest.approx(0.5 * turn, rel=1e-9)


def test_kernels_release_the_gil_and_a_busy_python_thread_does_not_stall_them():
    import threading
    import time

    import numba

    sim = periodic_gas(count=400, length=40.0)
    sim.run(10)

    def timed_run(busy):
        done = threading.Event()
        elapsed = []

        def work():
            numba.set_num_threads(1)  # a single-threaded run never asks for the GIL
            start = time.perf_counter()
            sim.run(3000)
            elapsed.append(time.perf_counter() - start)
            done.set()

        thread = threading.Thread(target=work)
        counter = 0
        start = time.perf_counter()
        thread.start()
        if busy:
            while not done.is_set():
                counter += 1
        thread.join()
        return elapsed[0], counter / (time.perf_counter() - start)

    quiet, _ = timed_run(busy=False)
    contended, rate = timed_run(busy=True)
    solo = 0
    solo_start = time.perf_counter()
    while time.perf_counter() - solo_start < 0.2:
        solo += 1
    # this thread kept counting at a good share of its solo rate: the kernel did not hold the GIL
    assert rate > 0.2 * solo / 0.2
    # and the kernel, which needs the GIL only between blocks of steps, was not starved by it
    assert contended < 5 * quiet + 0.2
