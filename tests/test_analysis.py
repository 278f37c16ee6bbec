"""Packing statistics, states read from run files and generic H5MD files, and `granlab analyze`."""

import functools
import json
import math

import h5py
import numpy as np
import pytest

from granlab.engine.analysis import stiffness as st
from granlab.engine.analysis.packing import packing_stats, percolation_force
from granlab.engine.analysis.report import analyze
from granlab.engine.analysis.states import PackingState, read_state
from granlab.engine.io.h5md import RunWriter
from granlab.engine.params import ContactLaw
from granlab.engine.protocols import prepare
from granlab.engine.simulation import ContactSnapshot
from granlab.engine.state import STATUS_STICK
from tests.test_cli import granlab


@functools.cache
def method1_packing():
    """150 cohesionless disks of Gilabert's size distribution, prepared by method 1 (mu = 0.5) with
    the per-length cell mass, the packing the tolerances below were measured on (F_N 4.5 % below
    Rumpf's Eq. 17, the mass reading's 4.4 %; at the step of 0.3 of the bound, before 27 Nov 2026,
    3.8 and 4.8 %)."""
    law = prepare.gilabert_law(friction=0.5, cohesion=False, pressure=1e-2)
    prepared = prepare.method1(count=150, pressure=1e-2, law=law, seed=1, cell_mass_reading="per-length")
    assert prepared.equilibrated
    return prepared.sim


def test_rumpf_relation_on_a_prepared_packing():
    """Gilabert Eqs. 15-18: the mean normal force F_N = pi <d^2>/<d> P / (z Phi) up to the
    correlations of Eq. 16 (Gilabert finds it "remarkably accurate"); the stress it rests on is the
    exact sum P = sum N l / 2A."""
    sim = method1_packing()
    snap = sim.snapshot()
    stats = packing_stats(PackingState.from_snapshot(snap))
    c = snap.contacts
    pairs = c.j < snap.positions.shape[0]
    branch = snap.positions[c.i[pairs]] - snap.positions[c.j[pairs]] - c.image[pairs] * snap.cell_lengths
    area = float(np.prod(snap.box_lengths))
    exact = np.sum(c.normal_force[pairs] * np.hypot(branch[:, 0], branch[:, 1])) / (2.0 * area)
    assert exact == pytest.approx(stats.pressure, rel=0.02)  # the kinetic part is below 2 %
    assert stats.mean_normal_force == pytest.approx(stats.rumpf_force, rel=0.06)
    assert stats.mean_normal_force == pytest.approx(stats.rumpf_force_eq18, rel=0.08)
    assert sum(stats.coordination) == pytest.approx(1.0)
    assert sum(k * x for k, x in enumerate(stats.coordination)) == pytest.approx(stats.z)
    assert stats.z_star == pytest.approx(stats.z / (1.0 - stats.coordination[0]))
    # Gilabert: up to 18 % without cohesion. One 150-disk sample: seeds 1-6 give 0.10-0.25 (mean
    # 0.17), and which end a seed lands at changes with the last bit of the preparation's arithmetic
    assert 0.05 < stats.rattlers / stats.particles < 0.3


def test_the_preparations_step_is_within_a_third_of_the_packings_own_stability_bound():
    """The time step of Gilabert's preparations (GILABERT_DT_SAFETY of the engine's bound, which
    assumes 6 contacts on every disk) against the highest frequency of the packing's own contact
    network, found by brute force: the largest eigenvalue of M^-1/2 k M^-1/2, k the stiffness
    matrix with every contact sticking, on the disks' velocities (x, y and r w, whose mass is I/r²)."""
    sim = method1_packing()
    net = st.network(sim.snapshot())
    dof = 3 * sim.particles.count
    k = st.stiffness_matrix(net, sliding=np.zeros(net.contacts, dtype=bool)).toarray()[:dof, :dof]
    p = sim.particles
    scale = np.sqrt(np.column_stack([p.inv_mass, p.inv_mass, p.inv_inertia * p.radius ** 2]).ravel())
    omega = math.sqrt(np.linalg.eigvalsh(scale[:, None] * k * scale[None, :])[-1])
    zeta = sim.law.damping_ratio
    own_bound = 2.0 * (math.sqrt(1.0 + zeta * zeta) - zeta) / omega
    assert sim.integration.dt_safety == prepare.GILABERT_DT_SAFETY and sim.dt == pytest.approx(sim.auto_dt(), rel=1e-12)
    # the engine's bound is twice this packing's own (on packings of 400-5600 disks, 1.78-1.86 times)
    assert 0.25 < sim.dt / own_bound < 0.4


def chain_state(forces, periodic=True, walls=False):
    """Disks of radius 0.5 in a row along x (touching, one per unit length), joined by contacts
    carrying ``forces``; periodic: the row wraps around a cell of its length; walls: the row
    stands between a left and a right wall instead. Plus a side disk with a large force."""
    n = len(forces) if periodic else len(forces) - 1
    positions = np.column_stack([np.arange(n) + 0.5, np.full(n, 0.5)])
    positions = np.vstack([positions, [0.5, 1.5]])
    radii = np.full(n + 1, 0.5)
    i = list(range(1, n)) + ([0] if periodic else [])
    j = list(range(0, n - 1)) + ([n - 1] if periodic else [])
    image = [[0, 0]] * (n - 1) + ([[-1, 0]] if periodic else [])
    force = list(forces[:len(i)])
    if walls:  # walls are j >= N: left wall = N, right wall = N + 1
        i += [0, n - 1]
        j += [n + 1, n + 2]
        image += [[0, 0], [0, 0]]
        force += list(forces[len(i) - 2:])
    i.append(n)
    j.append(0)
    image.append([0, 0])
    force.append(100.0)
    m = len(i)
    zeros = np.zeros(m)
    contacts = ContactSnapshot(np.array(i), np.array(j), np.array(image), np.full(m, STATUS_STICK, np.int8),
                               np.array(force), np.array(force), zeros, zeros - 1e-3, zeros, zeros, zeros)
    normals = np.array([[1.0, 0.0], [-1.0, 0.0]]) if walls else np.zeros((0, 2))
    lengths = np.array([float(n), 2.0])
    return PackingState(positions, radii, contacts, ContactLaw(), ("left", "right")[:len(normals)], normals,
                        np.zeros(len(normals)), np.zeros(len(normals)), ("fixed",) * len(normals), lengths,
                        lengths, (periodic, False), np.zeros((2, 2)), 0.0, 0, True, "chain")


def test_percolation_threshold_is_the_weakest_link_of_the_percolating_path():
    forces = [5.0, 3.0, 7.0, 2.5, 6.0]
    state = chain_state(forces)
    c = state.contacts
    assert percolation_force(state, c.normal_force, np.ones(c.count, bool)) == 2.5
    # the same row, cut once: nothing wraps around
    usable = np.ones(c.count, bool)
    usable[3] = False
    assert percolation_force(state, c.normal_force, usable) is None
    walled = chain_state([4.0, 1.5, 9.0, 3.0, 2.0], periodic=False, walls=True)
    assert percolation_force(walled, walled.contacts.normal_force, np.ones(walled.contacts.count, bool)) == 1.5


def test_a_run_file_frame_gives_the_same_analysis_as_the_live_state(tmp_path):
    """The law, wall modes, wall forces and contacts of a frame come back from the run file: k,
    the rigidity counts and the packing statistics equal those of the live snapshot. The friction
    changes after the file was opened: the frame's law is the one read."""
    sim = prepare.compress(16, seed=3, friction=0.2).sim
    path = tmp_path / "box.h5"
    with RunWriter(path, sim) as writer:
        sim.set_law(friction=0.3)
        writer.write_frame(sim)
    live = PackingState.from_snapshot(sim.snapshot())
    stored = read_state(path)
    assert stored.law == sim.law and stored.law.friction == 0.3
    assert stored.wall_modes == live.wall_modes and "force" in stored.wall_modes
    np.testing.assert_allclose(stored.wall_forces, live.wall_forces)
    k_live = st.stiffness_matrix(st.network(live))
    k_file = st.stiffness_matrix(st.network(stored))
    assert k_live.shape == k_file.shape and abs(k_live - k_file).max() <= 1e-12 * abs(k_live).max()
    assert analyze(stored, "rigidity").values == analyze(live, "rigidity").values
    assert analyze(stored, "packing").values == analyze(live, "packing").values


def write_generic_h5md(path, positions, diameters, edges, periodic=True):
    """A minimal H5MD file as another program would write it: a particle group with a
    time-dependent position, a fixed diameter and a fixed box."""
    with h5py.File(path, "w") as f:
        f.create_group("h5md").attrs["version"] = [1, 1]
        f["h5md"].create_group("creator").attrs["name"] = "another code"
        group = f.create_group("particles/atoms")
        box = group.create_group("box")
        box.attrs["dimension"] = 2
        box.attrs["boundary"] = np.array(["periodic" if periodic else "none"] * 2, dtype="S8")
        box.create_dataset("edges", data=np.asarray(edges, dtype=float))
        position = group.create_group("position")
        position.create_dataset("value", data=np.asarray(positions, dtype=float)[None])
        position.create_dataset("step", data=[0])
        position.create_dataset("time", data=[0.0])
        group.create_dataset("diameter", data=np.asarray(diameters, dtype=float))


def triangular_lattice(columns=6, rows=6, d=1.0):
    """Equal touching disks on a triangular lattice that tiles a periodic cell."""
    h = d * math.sqrt(3.0) / 2.0
    positions = [((c + 0.5 * (r % 2)) * d, r * h) for r in range(rows) for c in range(columns)]
    return np.array(positions), (columns * d, rows * h)


def test_a_generic_h5md_lattice_has_z_6_and_the_rigidity_counts_of_its_contacts(tmp_path):
    """A triangular lattice from an H5MD file of another program: contacts from the geometry give
    z = 6 and Phi = pi / (2 sqrt 3); frictionless, N_f = 2N, M = 3N, K = 2 translations, so
    H = N + 2 (N_f + H = M + K)."""
    positions, edges = triangular_lattice()
    n = len(positions)
    path = tmp_path / "lattice.h5"
    write_generic_h5md(path, positions, np.ones(n), edges)
    packing = json.loads(granlab("analyze", str(path), "packing", "--json").stdout)
    assert packing["z"] == 6.0 and packing["forces_known"] is False
    assert packing["phi"] == pytest.approx(math.pi / (2.0 * math.sqrt(3.0)))
    rigidity = json.loads(granlab("analyze", str(path), "rigidity", "--mu", "0", "--json").stdout)
    assert (rigidity["degrees_of_freedom"], rigidity["constraints"]) == (2 * n, 3 * n)
    assert (rigidity["floppy_modes"], rigidity["hyperstaticity"]) == (2, n + 2)
    refused = granlab("analyze", str(path), "stiffness", check=False)
    assert refused.returncode == 2 and "needs contact forces" in refused.stderr


def test_bad_input_gets_a_clear_error(tmp_path):
    not_h5md = tmp_path / "notes.h5"
    not_h5md.write_text("not HDF5 at all")
    plain = tmp_path / "plain.h5"
    with h5py.File(plain, "w") as f:
        f["data"] = [1, 2, 3]
    empty = tmp_path / "empty.h5"
    write_generic_h5md(empty, np.zeros((0, 2)), np.zeros(0), (10.0, 10.0))
    positions, edges = triangular_lattice()
    lattice = tmp_path / "lattice.h5"
    write_generic_h5md(lattice, positions, np.ones(len(positions)), edges)
    gas = tmp_path / "gas.h5"
    write_generic_h5md(gas, [[1.0, 1.0], [5.0, 5.0]], [1.0, 1.0], (10.0, 10.0))
    cases = [((str(not_h5md), "packing"), "is not a readable HDF5 file"),
             ((str(plain), "packing"), "is not an H5MD file"),
             ((str(tmp_path / "missing.h5"), "packing"), "does not exist"),
             ((str(empty), "packing"), "holds no disks"),
             ((str(lattice), "packing", "--frame", "3"), "frame 3 is out of range"),
             ((str(gas), "rigidity"), "has no contacts")]
    for args, message in cases:
        process = granlab("analyze", *args, check=False)
        assert process.returncode == 2, args
        assert message in process.stderr and "Traceback" not in process.stderr, (args, process.stderr)


def test_bench_analysis_prepares_a_packing_once_and_times_every_analysis(tmp_path):
    path = tmp_path / "packing.h5"
    first = json.loads(granlab("bench", "--analysis", str(path), "--particles", "40", "--json").stdout)
    assert first["particles"] == 40 and first["preparation_s"] > 0 and path.exists()
    assert set(first["timings_s"]) == {"stiffness", "status", "rigidity", "packing", "fractal"}
    assert "a larger box" in first["values"]["fractal"]["fit_error"]  # 40 disks: too few wavevectors to fit
    assert first["values"]["rigidity"]["balanced"] is True
    again = json.loads(granlab("bench", "--analysis", str(path), "--json").stdout)
    assert again["preparation_s"] is None and again["values"]["packing"] == first["values"]["packing"]
