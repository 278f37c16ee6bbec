"""The lab's presets, headless: each one carries out its figure of the papers step by step."""

import copy
import re
import math

import numpy as np
import pytest

from granlab.engine import ParameterError
from granlab.engine.protocols.measures import PairMaximum, mobilisation
from granlab.engine.protocols.presets import PRESETS, make_preset, parse_setup, preset_settings, setup_query
from granlab.engine.protocols.settings import LabSettings
from granlab.engine.state import STATUS_SLIDE_NEG, STATUS_SLIDE_POS


def run_until(preset, predicate, steps=200, limit=400_000):
    done = 0
    while not predicate(preset):
        done += preset.advance(steps)
        assert done < limit, f"{preset.name}: stage {preset.stage!r} after {done} steps"


@pytest.fixture(scope="module")
def ratchet16():
    preset = make_preset("ratchet16")
    rows = {"contacts": [], "cycles": [], "time": []}
    frames = []
    preset.on_frame = lambda: frames.append(preset.sim.time)

    def two_cycles(p):
        for name, new in p.rows().items():
            rows[name] += new
        return p.stage == "cycling" and p._cycle >= 2

    run_until(preset, two_cycles, steps=997)
    return preset, rows, frames


def test_ratchet16_watches_the_contacts_that_reach_the_coulomb_cone(ratchet16):
    preset, rows, _ = ratchet16
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
    contact = np.array([row[3:] for row in contacts])
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
    run_until(preset, lambda p: p._cycle > cycle)
    assert_in_cone(preset.rows()["contacts"], preset.settings.friction, 0.2)


def test_ratchet16_records_strain_and_load_of_eq1(ratchet16):
    preset, rows, _ = ratchet16
    cycles = np.array(rows["cycles"])
    assert cycles[:, 0].tolist() == [0, 1, 2]
    load = preset.load
    start = cycles[0, 2]
    # every cycle lasts exactly one period: the time step is fitted to it
    assert np.diff(cycles[:, 2]) == pytest.approx([load.period] * 2, rel=1e-12)
    t, cycle, q = np.array([row[:3] for row in rows["time"] if row[0] >= start]).T
    # ratcheting Eq. 1: q = amplitude * (1 - cos(2 pi (t - t0) / T))
    expected = load.amplitude * (1 - np.cos(2 * math.pi * (t - start) / load.period))
    assert q == pytest.approx(expected, abs=1e-12)
    assert q.max() > 1.9 * load.amplitude
    assert cycle.tolist() == np.floor((t - start) / load.period + 1e-9).clip(max=2).tolist()


def test_series_are_sampled_in_simulated_time_whatever_the_step_count_asked(ratchet16):
    """At least 200 samples of the time series per load cycle, one sample of a watched contact per
    1 % of the load amplitude (2 pi * 50 per cycle), 10 frames: however many steps advance asks for."""
    preset, rows, frames = ratchet16
    start, period = rows["cycles"][0][2], preset.load.period
    t = np.array([row[0] for row in rows["time"]])
    first_cycle = (t >= start) & (t < start + period - 1e-9)
    assert first_cycle.sum() == preset.samples_per_cycle == 200
    assert np.diff(t[first_cycle]) == pytest.approx(period / 200, abs=preset.sim.dt)  # on the nearest step
    # the watched contacts are chosen at the end of the first cycle: their paths in the second
    paths = np.array([row[:3] for row in rows["contacts"] if start + period <= row[2] < start + 2 * period - 1e-9])
    per_contact = [np.sum((paths[:, 0] == i) & (paths[:, 1] == j)) for i, j in set(map(tuple, paths[:, :2]))]
    assert max(per_contact) == preset.path_samples_per_cycle >= 2 * math.pi * 50
    frames = np.array(frames)
    assert np.sum((frames >= start) & (frames < start + period - 1e-9)) == preset.settings.frames_per_cycle == 10


def test_loading_controls_wait_for_the_next_cycle_and_law_controls_act_at_once():
    preset = make_preset("ratchet16")
    run_until(preset, lambda p: p.stage == "cycling")
    preset.apply(friction=0.35, amplitude=0.1)
    assert preset.sim.law.friction == 0.35
    assert preset.load.amplitude == 0.2
    run_until(preset, lambda p: p._cycle >= 1)
    assert preset.load.amplitude == 0.1


def test_a_law_changed_is_marked_by_its_label_as_the_legends_name_it():
    """The plots' markers say a law as its menu's legend does: "spring Cundall–Strack → α-corrected"."""
    preset = make_preset("ratchet16")
    preset.apply(tangential_model="alpha", normal_model="area")
    assert [change["text"] for change in preset.changes[-2:]] == ["normal spring linear → overlap area",
                                                                "spring Cundall–Strack → α-corrected"]


def test_invalid_control_changes_nothing():
    preset = make_preset("ratchet16")
    before = preset.settings
    with pytest.raises(ParameterError, match="amplitude"):
        preset.apply(friction=0.5, amplitude=-1.0)
    with pytest.raises(ParameterError, match="one of"):
        preset.apply(viscosity=1.0)
    assert preset.settings == before and preset.sim.law.friction == 0.0


@pytest.mark.parametrize("changes, allowed", [({"particles": 0}, "from 1 to 20000"), ({"seed": -1}, "from 0 to 4294967295"),
                                              ({"friction": -0.1}, "friction"),
                                              ({"tangential_model": "euler"}, "cundall-strack")])
def test_lab_settings_are_validated(changes, allowed):
    with pytest.raises(ParameterError, match=allowed):
        LabSettings().replace(**changes)


def test_closed_path_preset_shows_eq17_for_the_path_dependent_springs_only():
    preset = make_preset("closed-path")
    loop = 4 * preset.steps_per_side
    preset.advance(loop)
    rows = preset.rows()["springs"]
    start, end = rows[0], rows[-1]
    assert len(rows) == preset.path_samples_per_cycle + 1 and end[0] == pytest.approx(loop * preset.dt)
    (d_a, _), (d_b, _) = preset._corners[0], preset._corners[1]
    # ratcheting Eq. 17: Delta D_t = a / (r_i + r_j), a the signed area enclosed
    predicted = 0.5 * preset.turn * (d_b ** 2 - d_a ** 2) / (2 * preset.radius)
    cundall, alpha, angle, lammps = (end[k] - start[k] for k in (1, 2, 3, 4))
    assert cundall == pytest.approx(predicted, rel=0.03)
    assert lammps == pytest.approx(cundall, rel=0.02)  # its projection adds 1 % per loop here
    assert abs(alpha) < 1e-3 * abs(predicted)
    assert abs(angle) < 1e-9 * abs(predicted)


def test_block_starts_sliding_only_when_the_load_reaches_mu_fn():
    preset = make_preset("block")
    while preset.sim.time < 1.2 * preset.settings.period:
        preset.advance(20)
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
    while preset.sim.time < 150:
        preset.advance(500)
    rows = preset.rows()["time"]
    start, end = rows[0], rows[-1]
    t, z, phi, count, kinetic = zip(start, end)
    assert phi[1] == pytest.approx(phi[0], rel=1e-12)
    assert count[0] > 100 and count[1] < count[0] / 4
    assert z[1] > 1.5 and kinetic[1] < kinetic[0]


def test_compression_preset_reaches_the_imposed_pressure():
    preset = make_preset("compression", preset_settings("compression", particles=100))
    run_until(preset, lambda p: p.stage == "equilibrated", steps=500)
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


def test_a_stiffer_law_shortens_the_time_step_and_the_cycle_still_lasts_one_period():
    """The lab's time step is never pinned by the user: a rolling stiffness that needs a shorter
    step gets it (mid-cycle), and the cycle still ends exactly one period after it began."""
    preset = make_preset("ratchet16")
    run_until(preset, lambda p: p.stage == "cycling")
    preset.advance(997)
    before = preset.sim.dt
    notes = preset.apply(rolling_stiffness=50.0, rolling_friction=0.01)
    assert preset.sim.law.rolling_stiffness == 50.0 and preset.sim.dt < before / 5
    assert preset.sim.dt <= preset.sim.auto_dt() * (1 + 1e-12)
    assert any("time step now" in note for note in notes)
    run_until(preset, lambda p: p._cycle >= 2)
    cycles = np.array(preset.rows()["cycles"])
    assert np.diff(cycles[:, 2]) == pytest.approx([preset.load.period] * 2, rel=1e-9)


@pytest.mark.parametrize("changes, allowed", [
    ({"amplitude": 3.0}, "an amplitude from 0 to 2 P0 = 2 (P0 = 1)"),
    ({"amplitude": -0.5}, "an amplitude from 0 to 2 P0 = 2"),
    ({"pressure": 0.05}, "at least Δσ/2 = 0.1"),
    ({"period": 0.0}, "a period from 100 time steps to the 10,000,000 steps the lab runs in about three minutes: "
                      "0.077 <= T <= 7702"),
    ({"period": 1e7}, "0.077 <= T <= 7702"),  # one cycle would be 10^10 steps: hours
    ({"pressure": 100.0}, "a pressure from 0.01 to 5 (K_N / P0 from 10⁴ to 20, K_N = 100"),
    ({"rolling_friction": 5.0}, "a rolling friction length from 0 to the largest disk's radius 0.123, or ∞"),
    ({"cohesion_force": 1e6}, "a cohesion from 0 to 0.245: κ = a K_N / F0 of at least 100"),
    # waits for the cycling, checked when typed: it would need a time step 10^4 times shorter
    ({"rolling_stiffness": 1e9}, "a value whose law needs a time step at most 10× shorter than the preset's"),
    ({"friction": 50.0}, "a friction coefficient from 0 to 10, or inf (no sliding)"),
    ({"speed": 1000.0}, "from 0.01 to 100 clock units (load cycles, loops, T₀) per second, or inf"),
    ({"seed": 2 ** 40}, "a whole number from 0 to 4294967295"),
])
def test_a_refused_control_names_what_is_allowed_given_the_other_settings(changes, allowed):
    preset = make_preset("ratchet16")
    before = preset.settings
    with pytest.raises(ParameterError, match=re.escape(allowed)):
        preset.apply(**changes)
    assert preset.settings == before


def test_rolling_friction_without_a_rolling_spring_says_so():
    preset = make_preset("ratchet16")
    notes = preset.apply(rolling_friction=0.01)
    assert preset.settings.rolling_friction == 0.01
    assert any("Set Kr > 0" in note for note in notes)


def test_watching_a_pair_checks_that_it_can_exist():
    preset = make_preset("ratchet16")
    run_until(preset, lambda p: p.stage == "cycling")
    with pytest.raises(ParameterError, match="two different disks 0 to 15, walls 16 to 19 "
                                             r"\(left, right, bottom, top\)"):
        preset.toggle_watch((3, 99))
    with pytest.raises(ParameterError, match="two different disks"):
        preset.toggle_watch((3, 3))
    i, j = (int(k) for k in mobilisation(preset.sim)[0][0])
    assert preset.toggle_watch((j, i)) == f"contact {i}–{j}: watched"  # either order names the pair
    assert (i, j) in preset.watch
    assert "not touching now" in preset.toggle_watch((0, 15 if (0, 15) != (i, j) else 14))


def test_every_preset_is_a_module_of_the_package_with_its_teaching_text():
    """Adding a preset is one module of ``engine/protocols/presets/``, its text in
    ``static/teaching/`` and one entry of the registry."""
    from pathlib import Path

    from granlab.app.lab.dashboard import STATIC, teaching_text
    from granlab.engine.protocols import presets

    folder = Path(presets.__file__).parent
    for name, cls in PRESETS.items():
        module = Path(__import__(cls.__module__, fromlist=["_"]).__file__)
        assert module.parent == folder and module.name != "__init__.py", name
        assert (STATIC / "teaching" / f"{name}.md").is_file() and teaching_text(name).startswith("# "), name


@pytest.mark.parametrize("name", list(PRESETS))
def test_a_links_query_reads_back_as_the_exact_settings_of_every_preset(name):
    changes = {"friction": 0.37, "tangential_model": "angle", "damping_ratio": 0.55, "pressure": 1.1,
               "amplitude": 0.15, "period": 0.1 + 0.2, "phase": -45.0, "seed": 3, "rolling_friction": 1e-3,
               "cohesion_range": 2e-3, "speed": 20.0}
    settings = preset_settings(name, **changes)
    query = setup_query(name, settings)
    assert query["preset"] == name and query["speed"] == "20"
    again_name, again = parse_setup(query)
    assert again_name == name and preset_settings(name, **again) == settings  # 0.1 + 0.2 too: repr reads back
    # the preset's own settings: the link holds only the preset and its speed, by name
    own = setup_query(name, preset_settings(name))
    assert set(own) == {"preset", "speed"}
    assert own["speed"] in PRESETS[name].speeds or PRESETS[name].defaults.get("speed", 1.0) not in \
        PRESETS[name].speeds.values()


def test_every_named_speed_is_one_the_lab_offers():
    from granlab.app.lab.dashboard import SPEED_NAMES, SPEEDS

    for cls in PRESETS.values():
        assert tuple(cls.speeds) == SPEED_NAMES and set(cls.speeds.values()) <= set(SPEEDS.values())
        assert list(cls.speeds.values()) == sorted(cls.speeds.values())


@pytest.mark.parametrize("query, message", [
    ({"preset": "nowhere"}, "preset = 'nowhere' is not allowed: one of ratchet, ratchet16"),
    ({"preset": "block", "friction": "much"}, "friction = 'much' is not allowed: a number, or inf"),
    ({"preset": "block", "friction": "-1"}, "friction = -1.0 is not allowed"),
    ({"preset": "block", "seed": "1.5"}, "seed = '1.5' is not allowed: a whole number"),
    ({"preset": "block", "speed": "warp"}, "or a named speed: slow, normal, fast"),
    ({"preset": "block", "tangential_model": "glue"}, "tangential_model = 'glue' is not allowed"),
])
def test_a_link_with_a_value_that_is_not_allowed_names_it_and_what_is(query, message):
    with pytest.raises(ParameterError, match=re.escape(message)):
        parse_setup(query)
