"""The stiffness matrix k = c K S cᵀ against the engine's own forces, the stability form as a contact
sum, the null-space count against dense linear algebra, and the textbook rigidity cases."""

import functools
import math

import numpy as np
import pytest

from granlab.engine.analysis.report import analyze
from granlab.engine.analysis.rigidity import rigidity
from granlab.engine.analysis.states import PackingState
from granlab.engine.analysis.stiffness import Network, network, null_space, quadratic_form, stiffness_matrix
from granlab.engine.params import ContactLaw
from granlab.engine.protocols.prepare import gilabert_law, method1
from granlab.engine.protocols.presets import make_preset, preset_settings
from granlab.engine.simulation import Simulation
from granlab.engine.state import (CELL_STRAIN_RATE, CELL_STRESS, STATUS_SLIDE_NEG, STATUS_SLIDE_POS, WALL_FORCE,
                                  WALL_VELOCITY, ParticleState)


@functools.cache
def _packed_state(model: str):
    preset = make_preset("ratchet16", preset_settings("ratchet16", tangential_model=model))
    while preset.sim.time < 12.0:
        preset.advance(5000)
    return preset.sim


def packed_box(model: str, friction: float = 0.3) -> Simulation:
    """The 16-disk ratchet box after its compression ramp (a packing with wall contacts), with
    the damping switched off so that forces depend on positions and springs only."""
    sim = _packed_state(model).clone(damping_ratio=0.0, tangential_damping=0.0, friction=friction)
    sim.run(1)
    return sim


def generalized_forces(sim: Simulation, mobile: np.ndarray) -> np.ndarray:
    """(f_x, f_y, torque / r) of each disk, then the normal force on each mobile wall."""
    p = sim.particles
    disks = np.column_stack([p.force, p.torque / p.radius]).ravel()
    return np.concatenate([disks, sim.walls.particle_force[mobile]])


def driven_box(friction: float) -> tuple[Simulation, np.ndarray, float]:
    """The packed box with no inertia left (its disks move only as :func:`impose` says), which
    walls are mobile, and its largest overlap."""
    sim = packed_box("cundall-strack", friction=friction)
    sim.particles.inv_mass[:] = 0.0
    sim.particles.inv_inertia[:] = 0.0
    return sim, sim.walls.mode == WALL_FORCE, -sim.snapshot().contacts.surface_gap.min()


def impose(sim: Simulation, mobile: np.ndarray, dx: np.ndarray) -> None:
    """One step in which every disk and mobile wall moves by ``dx`` (kinematically: the disks
    have no inertia left, the mobile walls are driven for the step)."""
    p, h, n = sim.particles, sim.dt, sim.particles.count
    p.velocity[:] = dx[: 3 * n].reshape(n, 3)[:, :2] / h
    p.omega[:] = dx[: 3 * n].reshape(n, 3)[:, 2] / p.radius / h
    sim.walls.mode[mobile] = WALL_VELOCITY
    sim.walls.velocity[mobile] = dx[3 * n:] / h
    sim.run(1)
    sim.walls.mode[mobile] = WALL_FORCE
    sim.walls.velocity[mobile] = 0.0


@pytest.mark.parametrize("model", ["cundall-strack", "alpha", "angle"])
@pytest.mark.parametrize("sliding", [False, True])
def test_k_predicts_the_force_change_of_a_small_displacement(model, sliding):
    """Impose a small displacement dx on every body (disks move and turn at prescribed velocities
    for one step h; mobile walls too), statuses frozen: the engine's forces change by -k dx. In
    the sliding case every disk was first turned the same way until its contacts slid
    (mu = 0.05), and dx keeps turning them."""
    sim = packed_box(model, friction=0.05 if sliding else 0.3)
    mobile = sim.walls.mode == WALL_FORCE
    n = sim.particles.count
    p = sim.particles
    p.inv_mass[:] = 0.0
    p.inv_inertia[:] = 0.0
    snap = sim.snapshot()
    overlap = -snap.contacts.surface_gap[snap.contacts.surface_gap < 0].mean()
    turn = np.zeros(3 * n + int(mobile.sum()))
    if sliding:
        turn[2: 3 * n: 3] = 0.02 * overlap
        for _ in range(10):
            impose(sim, mobile, turn)
    impose(sim, mobile, np.zeros_like(turn))  # forces at x, nothing moving
    before = generalized_forces(sim, mobile)
    net = network(sim.snapshot())
    assert net.contacts > 20 and net.dof == 3 * n + 2
    rng = np.random.default_rng(7)
    dx = turn + rng.normal(size=net.dof) * 1e-3 * overlap
    impose(sim, mobile, dx)
    after = network(sim.snapshot())
    assert np.array_equal(after.first, net.first) and np.array_equal(after.second, net.second)
    df = generalized_forces(sim, mobile) - before
    predicted = -(stiffness_matrix(net, after.sliding) @ dx)
    assert np.linalg.norm(df - predicted) < 1e-2 * np.linalg.norm(df)
    if sliding:
        assert after.sliding.sum() > net.contacts // 2
        wrong = stiffness_matrix(net, np.zeros(net.contacts, dtype=bool))  # as if all stuck
        assert np.linalg.norm(df + wrong @ dx) > 0.1 * np.linalg.norm(df)


def test_a_frictionless_contact_is_not_sliding_and_carries_no_tangential_stiffness():
    """mu = 0: the kernels mark a contact that moves sideways as sliding (its anchors follow the
    slip), but it is read as non-sliding: it is not held at a limit, F_t = 0 whatever the motion.
    Its row of k has no tangential stiffness, which k's prediction of the engine's forces checks."""
    sim, mobile, overlap = driven_box(0.0)
    n = sim.particles.count
    turn = np.zeros(3 * n + int(mobile.sum()))
    turn[2: 3 * n: 3] = 0.02 * overlap
    impose(sim, mobile, turn)
    marked = sim.contacts.status[:sim.contacts.count]
    assert np.count_nonzero((marked == STATUS_SLIDE_POS) | (marked == STATUS_SLIDE_NEG)) > 20
    counts = sim.status_counts()
    assert counts["sliding+"] == counts["sliding-"] == 0 and counts["non-sliding"] > 20
    before = generalized_forces(sim, mobile)
    net = network(sim.snapshot())
    assert not net.sliding.any()
    k = stiffness_matrix(net)
    assert abs(k - stiffness_matrix(net, np.ones(net.contacts, dtype=bool))).max() < 1e-12 * abs(k).max()
    dx = np.random.default_rng(3).normal(size=net.dof) * 1e-3 * overlap
    impose(sim, mobile, dx)
    df = generalized_forces(sim, mobile) - before
    assert np.linalg.norm(df + k @ dx) < 1e-2 * np.linalg.norm(df)


def test_quadratic_form_is_the_contact_sum_of_eqs_43_to_45():
    sim = packed_box("cundall-strack")
    net = network(sim.snapshot())
    rng = np.random.default_rng(1)
    for _ in range(5):
        sliding = rng.random(net.contacts) < 0.3
        v = rng.normal(size=net.dof)
        k = stiffness_matrix(net, sliding)
        assert quadratic_form(net, v, sliding) == pytest.approx(v @ (k @ v), rel=1e-10)


def test_null_space_count_matches_dense_linear_algebra():
    rng = np.random.default_rng(5)
    for rank in (0, 3, 17, 40):
        a = rng.normal(size=(40, rank))
        matrix = a @ a.T
        from scipy import sparse
        count, basis = null_space(sparse.csc_matrix(matrix))
        assert count == 40 - np.linalg.matrix_rank(matrix)
        if count:
            assert np.abs(matrix @ basis).max() <= 1e-8 * np.abs(matrix).max()


def test_the_sparse_solve_and_mechanisms_agree_with_the_dense_ones(monkeypatch):
    """Packings above DENSE_SIZE velocity components (SOLVE_DENSE_SIZE for a solve) go through
    SuperLU (diagonal pivots on a symmetric ordering) and ARPACK: forced onto that path, the
    16-disk box with 19 of its 37
    contacts sliding (k not symmetric) gives the dense answers, and so does the enumeration of the
    2^5 states of five of its critical contacts."""
    from granlab.engine.analysis import status as ss
    from granlab.engine.analysis import stiffness as st

    net = turned_box(3, 1)
    load = deviatoric_load(net)
    dense_v = st.response(net, load)
    dense = st.mechanisms(net, load)
    critical = ss.critical_contacts(net)[:5]
    states = ss.enumerate_states(net, load, critical)
    monkeypatch.setattr(st, "DENSE_SIZE", 0)
    monkeypatch.setattr(st, "SOLVE_DENSE_SIZE", 0)
    np.testing.assert_allclose(st.response(net, load), dense_v, rtol=1e-8, atol=1e-12 * np.abs(dense_v).max())
    assert st.mechanisms(net, load).as_dict() == dense.as_dict()
    assert ss.enumerate_states(net, load, critical).as_dict() == states.as_dict()
    assert len(states.unstable_states) > 0 and states.states_checked == 32  # a case with something to agree on


def glued(positions, radii, law: ContactLaw) -> Network:
    """The network of disks placed at ``positions``, each touching pair overlapped by 1e-6."""
    positions = np.asarray(positions, dtype=float)
    state = ParticleState(positions, np.asarray(radii, dtype=float), density=1.0)
    sim = Simulation(state, law)
    sim.run(1)
    return network(sim.snapshot())


def test_a_triangle_of_disks_is_isostatic_and_a_double_triangle_has_h_1():
    law = ContactLaw(friction=0.5)
    d = 2.0 - 1e-6  # centre distance of touching unit disks, overlapped by 1e-6
    triangle = [(0.0, 0.0), (d, 0.0), (d / 2, d * math.sqrt(3) / 2)]
    r = rigidity(glued(triangle, [1.0] * 3, law))
    assert (r.degrees_of_freedom, r.constraints, r.floppy_modes, r.hyperstaticity) == (9, 6, 3, 0)
    double = triangle + [(3 * d / 2, d * math.sqrt(3) / 2)]  # Gilabert Figs. 13, 18: 4 disks, 5 contacts
    r = rigidity(glued(double, [1.0] * 4, law))
    assert (r.degrees_of_freedom, r.constraints, r.floppy_modes, r.hyperstaticity) == (12, 10, 3, 1)
    assert r.balanced


def test_h_comes_from_rank_nullity_where_superlu_runs_out_of_memory_on_g_gt(monkeypatch):
    """SuperLU ran out of memory factorising GGᵀ of a 5600-disk packing: H is then M − rank G and the
    balance is not claimed."""
    from granlab.engine.analysis import rigidity as module

    def null_space(matrix, tolerance, vectors):
        if matrix.shape[0] == 10:  # GGᵀ of the double triangle: M × M
            raise MemoryError("Not enough memory to perform factorization.")
        return measured(matrix, tolerance, vectors=vectors)

    measured = module.null_space
    monkeypatch.setattr(module, "null_space", null_space)
    d = 2.0 - 1e-6
    double = [(0.0, 0.0), (d, 0.0), (d / 2, d * math.sqrt(3) / 2), (3 * d / 2, d * math.sqrt(3) / 2)]
    r = rigidity(glued(double, [1.0] * 4, ContactLaw(friction=0.5)))
    assert (r.degrees_of_freedom, r.constraints, r.floppy_modes, r.hyperstaticity) == (12, 10, 3, 1)
    assert r.balanced is None and r.as_dict()["balanced"] is None


def test_frictionless_cohesive_aggregates_have_4_minus_z_n_over_2_floppy_modes():
    """A loop-free aggregate (each disk glued to one earlier disk) is not hyperstatic, so by
    Gilabert Eq. 22 its floppy modes number 2N - N_c = (4 - z) N / 2."""
    rng = np.random.default_rng(11)
    law = ContactLaw(friction=0.0, cohesion_force=1.0, cohesion_range=1e-9)
    positions = [np.zeros(2)]
    while len(positions) < 30:
        parent = positions[rng.integers(len(positions))]
        angle = rng.uniform(0, 2 * np.pi)
        candidate = parent + (2.0 - 1e-6) * np.array([np.cos(angle), np.sin(angle)])
        if all(np.linalg.norm(candidate - q) > 2.05 for q in positions if q is not parent):
            positions.append(candidate)
    net = glued(positions, [1.0] * 30, law)
    r = rigidity(net)
    n, contacts = 30, net.contacts
    z = 2.0 * contacts / n
    assert contacts == n - 1 and r.hyperstaticity == 0
    assert r.floppy_modes == 2 * n - contacts == round((4 - z) * n / 2)
    assert r.balanced


def turned_box(turns: int, seed: int) -> Network:
    """The 16-disk box at mu = 0.05 after ``turns`` steps of every disk turning the same way (and a
    random jiggle), so that part of its contacts reached the Coulomb cone."""
    sim, mobile, overlap = driven_box(0.05)
    n = sim.particles.count
    rng = np.random.default_rng(seed)
    for _ in range(turns):
        dx = rng.normal(size=3 * n + 2) * 0.01 * overlap
        dx[2: 3 * n: 3] += 0.004 * overlap
        impose(sim, mobile, dx)
    return network(sim.snapshot())


def deviatoric_load(net: Network, snap_walls=("right", "top")) -> np.ndarray:
    """Push the top wall (its load up by one) and let the right wall back (down by one)."""
    load = np.zeros(net.dof)
    walls = net.wall_dof[net.wall_dof >= 0]
    load[walls] = [-1.0, 1.0]
    return load


@pytest.mark.parametrize("seed", [1, 2])
def test_exactly_one_contact_state_is_consistent(seed):
    """Quasi-rigidity Sec. II D on small packings: every state is stable here (checked), so the
    consistency map C must be a bijection of {0,1}^M_c and exactly one state obey the principle of
    minimum sliding; the iterative solver and the dynamics find that state."""
    from granlab.engine.analysis.status import critical_contacts, enumerate_states, solve_status

    net = turned_box(1, seed)
    critical = critical_contacts(net)
    assert 8 <= len(critical) <= 16
    load = deviatoric_load(net)
    found = enumerate_states(net, load, critical)
    assert found.states_checked == 2 ** len(critical)
    assert found.unstable_states == []  # the theorem's premise, checked
    assert found.bijective and len(found.consistent_states) == 1
    solution = solve_status(net, load, critical)
    assert "".join("1" if b else "0" for b in solution.sliding[critical]) == found.consistent_states[0]


def test_mechanisms_of_a_free_triangle_are_its_rigid_motions_and_a_net_force_collapses_it():
    """Quasi-rigidity Sec. III E: a frictional triangle in free space has exactly the three rigid
    motions as null modes of k; a self-balanced load (two disks pulled apart along their line)
    leaves them unexcited, a net force excites one (no quasi-static solution: collapse). A fourth,
    distant disk adds three rattler modes."""
    from granlab.engine.analysis.stiffness import mechanisms

    d = 2.0 - 1e-6
    triangle = [(0.0, 0.0), (d, 0.0), (d / 2, d * math.sqrt(3) / 2)]
    net = glued(triangle + [(20.0, 0.0)], [1.0] * 4, ContactLaw(friction=0.5))
    balanced = np.zeros(net.dof)
    balanced[0], balanced[3] = -1.0, 1.0
    m = mechanisms(net, balanced)
    assert (m.count, m.rigid_body, m.rattlers, m.unexcited, m.collapse, m.unstable) == (6, 3, 3, 0, False, 0)
    pushed = np.zeros(net.dof)
    pushed[1] = 1.0  # disk 0 pushed along y: a net force on the triangle
    m = mechanisms(net, pushed)
    assert m.collapse and (m.rigid_body, m.unexcited) == (3, 0)
    assert np.abs(m.collapse_mode[3 * 3:]).max() == 0.0  # the rattler takes no part


@functools.cache
def _stress_controlled_cell():
    # the packing the test was written on, in equilibrium at 120 T0 (at the preparations' longer step
    # this seed is another sample, in equilibrium only at 345 T0)
    law = gilabert_law(friction=0.5, kappa=1e4, cohesion=False, rolling=False, pressure=0.01)
    return method1(40, 0.36, 0.01, law, seed=3, max_time=200.0, cell_mass_reading="per-length", dt_safety=0.3)


def test_k_with_the_cells_two_strain_degrees_of_freedom_predicts_the_engines_force_changes(tmp_path):
    """Gilabert App. A: a periodic cell under stress control adds dL_x/dt and dL_y/dt to the bodies'
    velocities. A small displacement of the disks and of the cell's lengths (the lengths driven for
    one step) changes the engine's forces on the disks and its virial by -k dx; the load on the cell,
    -sigma^M A / L_a, is what the packing in equilibrium pushes back with."""
    prepared = _stress_controlled_cell()
    assert prepared.equilibrated
    sim = prepared.sim.clone(damping_ratio=0.0, tangential_damping=0.0)
    p, n = sim.particles, sim.particles.count
    p.inv_mass[:] = 0.0
    p.inv_inertia[:] = 0.0

    def forces():
        return np.concatenate([np.column_stack([p.force, p.torque / p.radius]).ravel(),
                               np.diag(sim.cell.virial) / sim.cell.length])

    def impose(dx):
        p.velocity[:] = dx[: 3 * n].reshape(n, 3)[:, :2] / sim.dt
        p.omega[:] = dx[: 3 * n].reshape(n, 3)[:, 2] / p.radius / sim.dt
        sim.cell.control[:] = CELL_STRAIN_RATE
        sim.cell.rate[:] = dx[3 * n:] / sim.dt
        sim.run(1)
        sim.cell.control[:] = CELL_STRESS
        sim.cell.rate[:] = 0.0

    impose(np.zeros(3 * n + 2))
    before = forces()
    snap = sim.snapshot()
    assert snap.cell_control == ("stress", "stress")
    net = network(snap)
    assert net.dof == 3 * n + 2 and list(net.cell_dof) == [3 * n, 3 * n + 1]
    # in equilibrium the packing's push on each axis balances the target stress
    assert before[3 * n:] == pytest.approx(-net.external[3 * n:], rel=1e-3)
    assert net.external[3 * n:] == pytest.approx(-0.01 * np.prod(snap.box_lengths) / snap.cell_lengths)
    overlap = -snap.contacts.surface_gap[snap.contacts.surface_gap < 0].mean()
    dx = np.random.default_rng(7).normal(size=net.dof) * 1e-3 * overlap
    dx[3 * n:] *= 10.0  # the cell's lengths move as much as the disks' contacts
    impose(dx)
    df = forces() - before
    k = stiffness_matrix(net, network(sim.snapshot()).sliding)
    assert np.linalg.norm(df - -(k @ dx)) < 1e-3 * np.linalg.norm(df)
    assert np.abs(df[3 * n:] - -(k @ dx)[3 * n:]).max() < 1e-3 * np.abs(df[3 * n:]).max()
    fixed_cell = k[: 3 * n, : 3 * n] @ dx[: 3 * n]  # the disks' rows of the old k (cell held fixed)
    assert np.linalg.norm(df[: 3 * n] + fixed_cell) > 0.1 * np.linalg.norm(df[: 3 * n])

    # the run file carries the cell's control and target: the analysis of the file sees the same bodies
    from granlab.engine.analysis.states import read_state
    from granlab.engine.io.h5md import RunWriter

    with RunWriter(tmp_path / "cell.h5", sim) as writer:
        writer.write_frame(snap)
    state = read_state(tmp_path / "cell.h5")
    assert state.cell_control == ("stress", "stress")
    again = network(state)
    assert list(again.cell_dof) == list(net.cell_dof) and np.array_equal(again.external, net.external)
    counts = rigidity(net)
    assert counts.degrees_of_freedom == 3 * n + 2 and counts.balanced

    from granlab.engine.analysis.stiffness import load_increment
    from granlab.engine.errors import GranLabError

    increment, kind = load_increment(net, "cell")
    assert kind == "cell" and np.flatnonzero(increment).tolist() == [3 * n, 3 * n + 1]
    assert increment[3 * n:] == pytest.approx(net.external[3 * n:] / np.linalg.norm(net.external[3 * n:]))
    with pytest.raises(GranLabError, match="load 'cell' needs a periodic cell under stress control"):
        load_increment(network(packed_box("cundall-strack").snapshot()), "cell")


def test_a_random_load_on_a_pair_of_disks_alone_is_none_and_excites_nothing():
    """The closed-path preset's two disks: no disk has two interactions, so a random load has
    nothing to push. It was a 0/0 (NaN) increment, with warnings on the lab's console."""
    import warnings

    from granlab.engine.analysis.stiffness import load_increment

    pair = make_preset("closed-path", preset_settings("closed-path"))
    pair.advance(3000)
    state = PackingState.from_snapshot(pair.sim.snapshot())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        increment, kind = load_increment(network(state))
        stiffness_report, status_report = analyze(state, "stiffness"), analyze(state, "status")
    assert kind == "none" and not increment.any()
    assert stiffness_report.values["load"] == status_report.values["load"] == "none"
    assert stiffness_report.values["null_modes"] == 4 and stiffness_report.values["collapse"] is False
    assert stiffness_report.texts["load"].startswith("none: no disk touches two others")


def test_a_periodic_packing_whose_null_modes_are_its_translations_and_rattlers_draws_no_mechanism():
    """The compression preset's packing: the null modes of k are the periodic cell's two translations
    and the rattlers'. The lab drew the first null mode, a translation, as "the mechanism": the same
    arrow on every disk."""
    box = make_preset("compression", preset_settings("compression"))
    box.advance(20000)
    report = analyze(PackingState.from_snapshot(box.sim.snapshot()), "stiffness")
    values = report.values
    assert values["rigid_body_modes"] == 2 and values["rattler_modes"] > 0
    assert values["null_modes"] == values["rigid_body_modes"] + values["rattler_modes"]
    assert report.result.modes.shape[1] == 2 and report.result.internal.shape[1] == 0
    assert report.result.drawn_mode is None and report.figures == ()
