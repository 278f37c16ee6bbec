"""The ``lammps`` tangential model against LAMMPS itself: oblique two-disk impacts made by
``pair_style gran/hooke/history`` (``tests/data/lammps/make_impacts.py``) replayed in GranLab."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from granlab.engine import ContactLaw, Integration, ParticleState, Simulation
from granlab.engine.io.lammps import Dump

IMPACTS = Path(__file__).parent / "data" / "lammps" / "impacts"
RECORD = json.loads((IMPACTS / "cases.json").read_text())
CASES = {case["name"]: case for case in RECORD["cases"]}


def lammps_frames(name):
    dump = Dump(IMPACTS / f"{name}.dump")
    frames = [dump.frame(k) for k in range(len(dump))]
    return [(f.timestep, np.column_stack([f.column(c) for c in ("x", "y", "vx", "vy", "omegaz")])) for f in frames]


def granlab_impact(name, model):
    """The impact of ``name`` in GranLab, LAMMPS's parameters converted: ``eta = m_eff gamma_n`` is
    ``2 zeta sqrt(K_n m_eff)`` and ``Gamma_t = m_eff gamma_t`` (one pair of masses)."""
    case, common = CASES[name], RECORD["common"]
    first = lammps_frames(name)[0][1]
    radius = np.array([case["d1"], case["d2"]]) / 2.0
    mass = math.pi * radius ** 2
    meff = mass[0] * mass[1] / mass.sum()
    law = ContactLaw(normal_stiffness=common["kn"], tangential_stiffness=common["kt"], friction=case["mu"],
                     damping_ratio=case["gn"] * meff / (2.0 * math.sqrt(common["kn"] * meff)),
                     tangential_damping=meff * case["gt"] * case["damp"], tangential_model=model)
    particles = ParticleState(first[:, :2], radius, velocity=first[:, 2:4], omega=first[:, 4], mass=mass,
                              inertia=0.5 * mass * radius ** 2)
    return Simulation(particles, law, Integration(dt=common["dt"]))


def largest_difference(name, model):
    """Largest difference over the dump's frames of positions, velocities and ``r w``, over the
    impact speed (1) and, for positions, the diameter (1)."""
    frames = lammps_frames(name)
    sim = granlab_impact(name, model)
    radius = sim.particles.radius
    worst = 0.0
    for step, theirs in frames[1:]:
        sim.run(step - sim.step)
        p = sim.particles
        ours = np.column_stack([p.position, p.velocity, p.omega])
        scale = np.array([1.0, 1.0, 1.0, 1.0, 0.0])[None, :] + np.column_stack([np.zeros((2, 4)), radius])
        worst = max(worst, float(np.abs((ours - theirs) * scale).max()))
    return worst


@pytest.mark.parametrize("name", sorted(CASES))
def test_the_lammps_model_replays_lammps_impacts_to_a_ten_thousandth_of_the_impact_speed(name):
    assert largest_difference(name, "lammps") < 1e-12  # the issue asked 1e-4: it is rounding


def test_granlab_own_springs_differ_from_lammps_where_the_coulomb_convention_differs():
    """Cundall–Strack with Coulomb on N^e (Gilabert Eq. 8) against LAMMPS's total F_n: the damped,
    sliding impacts part by far more than the lammps model's rounding."""
    gaps = {name: largest_difference(name, "cundall-strack") for name in CASES}
    assert max(gaps.values()) > 1e-3, gaps


def test_the_lammps_model_books_its_tangential_losses_as_sliding_never_far_below_zero():
    """LAMMPS limits its tangential dashpot with its spring: booked apart, the sliding tally of this
    damped oblique impact of a spinning disk fell to -0.97 of the impact energy (the dashpot's tally
    taking the difference); booked as one it stays above -1e-3 of it, and the balance closes."""
    angle = math.radians(71.6)
    particles = ParticleState([[0.0, 0.0], [-1.05 * math.cos(angle), math.sin(angle)]], [0.5, 0.5],
                              velocity=[[0.0, 0.0], [1.0, 0.0]], omega=[0.0, 4.24])
    law = ContactLaw(normal_stiffness=1e4, tangential_stiffness=8.5e3, friction=0.099, damping_ratio=0.753,
                     tangential_damping=5.3, tangential_model="lammps")
    sim = Simulation(particles, law, Integration(dt_safety=0.05))
    start = sim.energy()
    lowest = 0.0
    for _ in range(40):
        sim.run_for(0.005)
        lowest = min(lowest, sim.energy().dissipated_sliding / start.kinetic)
    end = sim.energy()
    assert lowest > -1e-3 and end.dissipated_sliding > 0.0 and end.dissipated_damping > 0.0
    assert end.balance == pytest.approx(start.balance, rel=1e-2)
