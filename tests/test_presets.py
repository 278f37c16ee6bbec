"""The lab's presets, headless: each one carries out its figure of the papers step by step."""

import copy
import math

import numpy as np
import pytest

from engine import ParameterError
from engine.protocols.presets import PRESETS, LabSettings, PairMaximum, make_preset, mobilisation, preset_settings
from engine.state import STATUS_SLIDE_NEG, STATUS_SLIDE_POS


def run_until(preset, predicate, steps=200, limit=400_000):
    done = 0
    while not predicate(preset):
        preset.advance(steps)
        preset.sample()
        done += steps
        assert done < limit, f"{preset.name}: stage {preset.stage!r} after {done} steps"


@pytest.fixture(scope="module")
def ratchet16():
    preset = make_preset("ratchet16")
    rows = {"contacts": [], "cycles": [], "time": []}

    def two_cycles(p):
        for name, new in p.rows().items():
            rows[name] += new
        return p.stage == "cycling" and p._cycle >= 2

    run_until(preset, two_cycles, steps=preset.settings.steps_per_frame)
    return preset, rows


def test_ratchet16_watches_the_contacts_that_reach_the_coulomb_cone(ratchet16):
    preset, rows = ratchet16
    mu = preset.settings.friction
    assert len(preset.watch) == preset.watch_count
    # chosen during the first cycle: the first watched contact slid (|F_t| reached mu N^e)
    mobilised = preset.mobilised.as_dict()
    assert mobilised[preset.watch[0]] == pytest.approx(mu, rel=1e-6)
    assert all(mobilised[p] >= v for p in preset.watch for q, v in mobilised.items() if q not in preset.watch)
    # the recorded paths stay inside the cone |F_t| <= mu N^e (ratcheting Eq. 8), on it when sliding
    assert_in_cone(rows["contacts"], mu, 0.0)


def assert_in_cone(contacts, mu, cohesion):
    """Watched paths (F_n, F_t) inside |F_t| <= mu (F_n + F0), on its edge while sliding."""
    contact = np.array([row[2:] for row in contacts])
    assert contact.size
    normal, tangential, status = contact[:, 0] + cohesion, contact[:, 1], contact[:, 2]
    assert np.all(np.abs(tangential) <= mu * normal * (1 + 1e-9) + 1e-15)
    sliding = np.isin(status, (STATUS_SLIDE_POS, STATUS_SLIDE_NEG))
    assert sliding.any()
    assert np.abs(tangential[sliding]) == pytest.approx(mu * normal[sliding], rel=1e-9)


def test_the_cone_of_watched_contacts_is_shifted_by_cohesion(ratchet16):
    preset = copy.deepcopy(ratchet16[0])
    preset.apply(cohesion_force=0.2, cohesion_range=1e-3)
    preset.rows()
    cycle = preset._cycle
    run_until(preset, lambda p: p._cycle > cycle, steps=preset.settings.steps_per_frame)
    assert_in_cone(preset.rows()["contacts"], preset.settings.friction, 0.2)


def test_ratchet16_records_strain_and_load_of_eq1(ratchet16):
    preset, rows = ratchet16
    assert [row[0] for row in rows["cycles"]] == [0, 1, 2]
    t, q = np.array([(row[0], row[1]) for row in rows["time"] if row[0] >= preset._start]).T
    # ratcheting Eq. 1: q = amplitude * (1 - cos(2 pi (t - t0) / T))
    load = preset.load
    expected = load.amplitude * (1 - np.cos(2 * math.pi * (t - preset._start) / load.period))
    assert q == pytest.approx(expected, abs=1e-12)
    assert q.max() > 1.9 * load.amplitude


def test_loading_controls_wait_for_the_next_cycle_and_law_controls_act_at_once():
    preset = make_preset("ratchet16")
    run_until(preset, lambda p: p.stage == "cycling")
    preset.apply(friction=0.35, amplitude=0.1)
    assert preset.sim.law.friction == 0.35
    assert preset.load.amplitude == 0.2
    run_until(preset, lambda p: p._cycle >= 1)
    assert preset.load.amplitude == 0.1


def test_invalid_control_changes_nothing():
    preset = make_preset("ratchet16")
    before = preset.settings
    with pytest.raises(ParameterError, match="amplitude"):
        preset.apply(friction=0.5, amplitude=-1.0)
    with pytest.raises(ParameterError, match="one of"):
        preset.apply(viscosity=1.0)
    assert preset.settings == before and preset.sim.law.friction == 0.0


@pytest.mark.parametrize("changes, allowed", [({"particles": 0}, "from 1 to 20000"), ({"seed": -1}, ">= 0"),
                                              ({"friction": -0.1}, "friction"),
                                              ({"tangential_model": "euler"}, "cundall-strack")])
def test_lab_settings_are_validated(changes, allowed):
    with pytest.raises(ParameterError, match=allowed):
        LabSettings().replace(**changes)


def test_closed_path_preset_shows_eq17_for_cundall_strack_only():
    preset = make_preset("closed-path")
    loop = 4 * preset.steps_per_side
    preset.sample()
    start = preset.rows()["springs"][0]
    preset.advance(loop)
    preset.sample()
    end = preset.rows()["springs"][0]
    (d_a, _), (d_b, _) = preset._corners[0], preset._corners[1]
    # ratcheting Eq. 17: Delta D_t = a / (r_i + r_j), a the signed area enclosed
    predicted = 0.5 * preset.turn * (d_b ** 2 - d_a ** 2) / (2 * preset.radius)
    cundall, alpha, angle = (end[k] - start[k] for k in (1, 2, 3))
    assert cundall == pytest.approx(predicted, rel=0.03)
    assert abs(alpha) < 1e-3 * abs(predicted)
    assert abs(angle) < 1e-9 * abs(predicted)


def test_block_starts_sliding_only_when_the_load_reaches_mu_fn():
    preset = make_preset("block")
    while preset.sim.time < 1.2 * preset.settings.period:
        preset.advance(20)
        preset.sample()
    t, ratio, normal, tangential, status, velocity = np.array(preset.rows()["block"]).T
    sliding = np.isin(status, (STATUS_SLIDE_POS, STATUS_SLIDE_NEG))
    first = np.flatnonzero(sliding)[0]
    # quasi-rigidity Figs. 2-3: no sliding below the Coulomb limit; at it, |F_t| = mu N
    # (the load is set every 10 steps: a sample's ratio runs up to one increment ahead of it)
    increment = np.diff(ratio[:first]).max()
    assert ratio[:first].max() < 1.0 + increment
    assert ratio[first] == pytest.approx(1.0, abs=0.02)
    mu = preset.settings.friction
    assert np.abs(tangential) == pytest.approx(np.minimum(np.abs(tangential), mu * normal * (1 + 1e-9)))
    assert np.abs(velocity[~sliding & (ratio < 0.9)]).max() < 1e-2 * np.abs(velocity).max()


def test_aggregation_keeps_the_cell_and_merges_clusters():
    preset = make_preset("aggregation", preset_settings("aggregation", particles=120))
    preset.sample()
    start = preset.rows()["time"][0]
    while preset.sim.time < 150:
        preset.advance(500)
    preset.sample()
    end = preset.rows()["time"][0]
    t, z, phi, count, kinetic = zip(start, end)
    assert phi[1] == pytest.approx(phi[0], rel=1e-12)
    assert count[0] > 100 and count[1] < count[0] / 4
    assert z[1] > 1.5 and kinetic[1] < kinetic[0]


def test_compression_preset_reaches_the_imposed_pressure():
    preset = make_preset("compression", preset_settings("compression", particles=100))
    run_until(preset, lambda p: p.stage == "equilibrated", steps=500)
    preset.sample()
    t, z, phi, pressure, kinetic = preset.rows()["time"][-1]
    assert pressure == pytest.approx(preset.pressure, rel=0.02)
    assert 0.75 < phi < 0.86 and z > 3.0


@pytest.mark.parametrize("name", ["aggregation", "compression"])
def test_gilabert_presets_damp_rolling_with_the_normal_damping_ratio(name):
    preset = make_preset(name, preset_settings(name, particles=20, rolling_friction=0.005))
    assert preset.sim.law.rolling_stiffness > 0 and preset.sim.law.rolling_damping_ratio == 0.8
    preset.apply(damping_ratio=0.5)
    assert preset.sim.law.damping_ratio == 0.5 and preset.sim.law.rolling_damping_ratio == 0.5


def test_watch_disk_toggles_its_contacts():
    preset = make_preset("ratchet16")
    run_until(preset, lambda p: len(mobilisation(p.sim)[1]), steps=200)
    disk = int(mobilisation(preset.sim)[0][0, 0])
    preset.watch_disk(disk)
    assert preset.watch and all(disk in pair for pair in preset.watch) and not preset.auto_watch
    preset.watch_disk(disk)
    assert preset.watch == []


def test_every_preset_runs_and_reports_its_series():
    for name, cls in PRESETS.items():
        preset = make_preset(name, preset_settings(name, particles=min(cls.defaults.get("particles", 256), 60)))
        preset.advance(5)
        preset.sample()
        status = preset.status()
        assert status["preset"] == name and status["settings"]["particles"] >= 1
        assert set(preset.rows()) <= set(cls.series)


def test_pair_maximum_keeps_the_largest_value_of_each_pair():
    rng = np.random.default_rng(3)
    merged, expected = PairMaximum(), {}
    for _ in range(5):
        pairs = rng.integers(0, 6, size=(40, 2))
        values = rng.random(40)
        merged.add(pairs, values)
        for (i, j), v in zip(pairs.tolist(), values):
            expected[(i, j)] = max(v, expected.get((i, j), -1.0))
    assert merged.as_dict() == expected
    assert merged.largest(3) == sorted(expected, key=expected.get, reverse=True)[:3]
