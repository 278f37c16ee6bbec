"""The lesson sheets (static/teaching/lessons/): their loader and HTML, and every observation a
sheet promises, each preset run headless as the lab runs it, step after step, for as long as the
sheet says.

Each step of a sheet names its ``**Check:**``; :data:`CHECKS` maps that id to the test below that
asserts what the step's ``**See:**`` promises (registered with :func:`check`), and a step without
a test fails. The runs are shared: one per preset (:func:`run`), its steps in the sheet's order,
with each control changed through the preset's own ``apply`` and a restart as the lab's Restart
does it (the preset anew with the settings in effect).
"""

from __future__ import annotations

import functools
import math
import re
from collections import defaultdict

import numpy as np
import pytest

from granlab.app.lab.lessons import (LESSONS, STATIC, LessonError, inline, lesson, lesson_html, lesson_presets,
                                     parse_lesson)
from granlab.engine.analysis.packing import packing_stats
from granlab.engine.analysis.states import PackingState
from granlab.engine.observables import columns, sliding, touching
from granlab.engine.protocols.measures import pair_label
from granlab.engine.protocols.presets import PRESETS, make_preset, preset_settings
from granlab.engine.state import STATUS_SLIDE_NEG, STATUS_SLIDE_POS

CHECKS: dict[str, object] = {}
"""Check id -> the test of the steps that name it."""


def check(check_id: str):
    """Register the decorated test as the check ``check_id`` of the sheets."""
    def register(test):
        CHECKS[check_id] = test
        return test
    return register


class Lab:
    """A preset driven as the lab's engine thread drives it: sample time after sample time, its
    series kept; and, for each step of its sheet, the clock units and simulated time it ran."""

    def __init__(self, name: str):
        self.name = name
        self.preset = make_preset(name)
        self.series = defaultdict(list)
        self.units: dict[str, float] = {}
        self.spans: dict[str, float] = {}
        self.seen: dict[str, dict] = {}
        self._units = self._span = 0.0

    def run(self, until, each=None) -> None:
        """Advance until ``until(preset)``, calling ``each(preset)`` after every sample time."""
        preset = self.preset
        while not until(preset):
            before, unit = preset.sim.time, preset.cycle_time()
            preset.advance(preset.steps_to_next_sample())
            self._units += (preset.sim.time - before) / unit
            self._span += preset.sim.time - before
            for name, rows in preset.rows().items():
                self.series[name].extend(rows)
            if each is not None:
                each(preset)

    def run_for(self, duration: float) -> None:
        end = self.preset.sim.time + duration
        self.run(lambda p: p.sim.time >= end - 0.5 * p.sim.dt)

    def restart(self) -> None:
        """The lab's Restart: the preset from t = 0 with the settings in effect, its series anew."""
        self.preset = make_preset(self.name, self.preset.settings)
        self.series = defaultdict(list)

    def step_done(self, check_id: str, **seen) -> None:
        """The step ``check_id`` ends here: what it saw, and the time it ran."""
        self.seen[check_id] = seen
        self.units[check_id], self.spans[check_id] = self._units, self._span
        self._units = self._span = 0.0


def fitted(p) -> bool:
    """The strain fit after the last change has its three cycles (no change waits)."""
    return not p.pending and p._cycle >= p.fit_from + 2


def watched_paths(rows, start: float, end: float) -> dict:
    """(F_n, F_t, status) arrays of each watched contact between the times ``start`` and ``end``."""
    paths = defaultdict(list)
    for i, j, t, normal, tangential, status in rows:
        if start - 1e-9 <= t <= end + 1e-9:
            paths[(i, j)].append((normal, tangential, status))
    return {pair: np.array(path) for pair, path in paths.items()}


def enclosed(path: np.ndarray) -> float:
    """The area a path (F_n, F_t) encloses."""
    fn, ft = path[:, 0], path[:, 1]
    return 0.5 * abs(float(np.sum(fn[:-1] * ft[1:] - fn[1:] * ft[:-1])))


def loop_area(path: np.ndarray) -> float:
    """The area a path encloses over the box it spans: π/4 for an ellipse, 0 for a line."""
    return enclosed(path) / (np.ptp(path[:, 0]) * np.ptp(path[:, 1]))


def closure(path: np.ndarray) -> float:
    """How far a path ends from its start, over its extent."""
    return float(np.hypot(*(path[-1, :2] - path[0, :2])) / max(np.ptp(path[:, 0]), np.ptp(path[:, 1])))


class SlidingLog:
    """Per contact, the slides that start during a run sample by sample (from ``preset``'s state
    now): their statuses, in order (a slide under way at the start is not counted)."""

    def __init__(self, preset):
        self.episodes = defaultdict(list)
        self._before = self._sliding(preset)

    @staticmethod
    def _sliding(p) -> dict:
        status, i, j, _ = columns(p.sim)
        return {(int(a), int(b)): int(s) for a, b, s in zip(i, j, status) if s in (STATUS_SLIDE_POS, STATUS_SLIDE_NEG)}

    def __call__(self, p) -> None:
        now = self._sliding(p)
        for pair, s in now.items():
            if self._before.get(pair) != s:
                self.episodes[pair].append(s)
        self._before = now


# ---------------------------------------------------------------------------------------- the runs
@functools.cache
def run(name: str) -> Lab:
    """The headless run of preset ``name``'s sheet, step after step."""
    lab = Lab(name)
    RUNS[name](lab)
    return lab


def run_ratchet16(lab: Lab) -> None:
    lab.run(lambda p: p.stage == "cycling" and p._cycle >= 2)
    lab.step_done("ratchet16-first-cycles")
    lab.run(lambda p: p._cycle >= 8)
    lab.step_done("ratchet16-strain-per-cycle", fit=lab.preset.status()["strain"])
    log = SlidingLog(lab.preset)
    start = lab.preset.sim.time
    lab.run(lambda p: p._cycle >= 9, each=log)
    lab.step_done("ratchet16-sliding-contacts", episodes=dict(log.episodes), start=start, end=lab.preset.sim.time,
                  contacts=int(touching(columns(lab.preset.sim)[0]).sum()))
    lab.run_for(0.5 * lab.preset.load.period)  # ticked mid-cycle, as a class would: the fit waits two whole cycles
    lab.preset.apply(friction=math.inf)
    log = SlidingLog(lab.preset)
    lab.run(fitted, each=log)
    lab.step_done("ratchet16-no-sliding", fit=lab.preset.status()["strain"], episodes=dict(log.episodes))


def run_elliptic(lab: Lab) -> None:
    # the first sample of the cycling still shows the statuses of the frictionless compression
    lab.run(lambda p: p.stage == "cycling" and p.sim.time > p._start)
    log = SlidingLog(lab.preset)
    lab.run(lambda p: p._cycle >= 3, each=log)
    lab.step_done("elliptic-loops", episodes=dict(log.episodes))
    lab.run(lambda p: p._cycle >= 5, each=log)
    lab.step_done("elliptic-ratchets", fit=lab.preset.status()["strain"], episodes=dict(log.episodes))
    lab.run_for(0.5 * lab.preset.load.period)
    lab.preset.apply(phase=30.0)
    lab.run(fitted, each=log)
    lab.step_done("elliptic-phase", fit=lab.preset.status()["strain"], episodes=dict(log.episodes))
    before = dict(lab.preset._cycle_gamma)[lab.preset._cycle]
    lab.run_for(0.5 * lab.preset.load.period)
    lab.preset.apply(tangential_model="angle")
    lab.run(fitted)
    lab.step_done("elliptic-angle-spring", fit=lab.preset.status()["strain"], before=before)


def run_ratchet(lab: Lab) -> None:
    readout = {}
    lab.run(lambda p: p._cycle >= 1, each=lambda p: readout.setdefault(p.stage, p.readout()))
    lab.step_done("ratchet-first-cycle", readout=readout["cycling"])
    counts, slid, touched = [], set(), set()

    def count(p):
        status, i, j, _ = columns(p.sim)
        counts.append((p._clock_position() - 1, int(sliding(status).sum())))
        slid.update(zip(i[sliding(status)].tolist(), j[sliding(status)].tolist()))
        touched.update(zip(i[touching(status)].tolist(), j[touching(status)].tolist()))

    lab.run(lambda p: p._cycle >= 2, each=count)
    lab.step_done("ratchet-sliding-follows-load", counts=np.array(counts[:-1]), slid=len(slid), touched=len(touched))
    lab.run(lambda p: p._cycle >= 3)
    lab.step_done("ratchet-energy")
    lab.run(lambda p: p._cycle >= 4)
    lab.step_done("ratchet-settling", fit=lab.preset.status()["strain"])


def run_closed_path(lab: Lab) -> None:
    def loops(count):
        return lambda p: p._k >= count * 4 * p.steps_per_side

    lab.run(loops(1))
    lab.step_done("closed-path-one-loop")
    lab.run(loops(5))
    lab.step_done("closed-path-staircase")
    lab.run(loops(6))
    lab.step_done("closed-path-lammps")
    lab.run(loops(7))
    lab.step_done("closed-path-springs-return")


def run_block(lab: Lab) -> None:
    def block_until(time):
        lab.run(lambda p: p.sim.time >= time)

    block_until(7.0)
    lab.step_done("block-starts-at-mu")
    block_until(14.0)
    lab.step_done("block-fastest")
    block_until(20.0)
    sim = lab.preset.sim
    lab.step_done("block-stops-at-rest", rows=np.array(lab.series["block"]), x=float(sim.particles.position[0, 0]),
                  friction_work=sim.energy().dissipated_sliding)
    lab.preset.apply(period=40.0)
    lab.restart()
    block_until(40.0)
    sim = lab.preset.sim
    lab.step_done("block-double-period", rows=np.array(lab.series["block"]), x=float(sim.particles.position[0, 0]),
                  friction_work=sim.energy().dissipated_sliding, period=lab.preset.settings.period)
    lab.preset.apply(period=20.0, friction=0.25)
    lab.restart()
    block_until(20.0)
    sim = lab.preset.sim
    lab.step_done("block-half-friction", rows=np.array(lab.series["block"]), x=float(sim.particles.position[0, 0]),
                  friction_work=sim.energy().dissipated_sliding)


def run_collision(lab: Lab) -> None:
    """Each step's ζ typed at a launch, while the disks approach: it acts at once; three collisions."""
    for zeta, check_id in ((0.0, "collision-elastic"), (0.5, "collision-restitution-predicted"),
                           (0.8, "collision-gilabert-damping")):
        lab.preset.apply(damping_ratio=zeta)
        lab.run_for(3 * lab.preset.cycle_time())
        lab.step_done(check_id, collisions=np.array(lab.series["collisions"]), path=np.array(lab.series["collision"]))


def run_aggregation(lab: Lab) -> None:
    lab.run(lambda p: p.sim.time >= 60.0)
    lab.step_done("aggregation-clusters-merge", rows=np.array(lab.series["time"]))
    lab.run(lambda p: p.sim.time >= 150.0)
    lab.step_done("aggregation-slow-settling", rows=np.array(lab.series["time"]))
    lab.preset.apply(rolling_friction=0.0015, rolling_stiffness=0.1)
    lab.restart()
    lab.run(lambda p: p.sim.time >= 150.0)
    lab.step_done("aggregation-rolling-resistance", rows=np.array(lab.series["time"]), law=lab.preset.sim.law)


def run_compression(lab: Lab) -> None:
    def jam():
        lab.run(lambda p: p.stage == "equilibrated")
        sim = lab.preset.sim
        return dict(t=sim.time, rows=np.array(lab.series["time"]), readout=lab.preset.readout(),
                    stats=packing_stats(PackingState.from_snapshot(sim.snapshot())))

    lab.step_done("compression-jams", **jam())
    lab.step_done("compression-rattlers", stats=packing_stats(PackingState.from_snapshot(lab.preset.sim.snapshot())))
    lab.preset.apply(friction=0.5)
    lab.restart()
    lab.step_done("compression-friction", **jam())
    lab.preset.apply(rolling_friction=0.005, rolling_stiffness=0.1)
    lab.restart()
    lab.step_done("compression-rolling", **jam())


RUNS = {"ratchet": run_ratchet, "ratchet16": run_ratchet16, "elliptic": run_elliptic, "closed-path": run_closed_path,
        "block": run_block, "collision": run_collision, "aggregation": run_aggregation, "compression": run_compression}

LAB_PACE = {"ratchet": 10.0 / 3.0, "aggregation": 15.0, "compression": 15.0}
"""Simulated time per second of wall clock of the presets that run at "max" by default, as the
sheets state it: the lab's engine runs at about half its headless rate on two cores when a tab draws
the scene (docs/performance.md), some 3 s a load cycle of 256 disks and 15 T₀ a second of 300."""


# ------------------------------------------------------------------------------------ the sheets
def test_every_preset_has_a_sheet_of_three_to_five_steps_each_with_a_check():
    assert set(lesson_presets()) == set(PRESETS)
    for name in PRESETS:
        sheet = lesson(name)
        assert sheet is not None and sheet.preset == name and sheet.title and sheet.intro
        assert 3 <= len(sheet.steps) <= 5, name
        for step in sheet.steps:
            assert step.check in CHECKS, f"{name}: step {step.title!r} promises {step.check!r}, which no test checks"
            assert re.match(r"(ratcheting|quasi-rigidity|Gilabert) ", step.paper), step.paper


def test_every_check_is_a_step_of_a_sheet():
    used = {step.check for name in PRESETS for step in lesson(name).steps}
    assert set(CHECKS) <= used, f"checks of no step: {sorted(set(CHECKS) - used)}"


@pytest.mark.parametrize("name", list(PRESETS))
def test_each_step_takes_the_time_its_sheet_says(name):
    """A step's seconds are its clock units at the preset's default speed, or at "max" its simulated
    time at the lab's pace (:data:`LAB_PACE`); a step that runs no simulated time (an analysis of
    the paused state) is given a few seconds."""
    sheet, lab, speed = lesson(name), run(name), preset_settings(name).speed
    for step in sheet.steps:
        if lab.spans[step.check] == 0.0:
            assert step.seconds <= 5, step.title
            continue
        expected = lab.units[step.check] / speed if math.isfinite(speed) else lab.spans[step.check] / LAB_PACE[name]
        assert abs(step.seconds - expected) <= max(1.0, 0.25 * expected), (step.title, step.time, expected)
        stated = SPAN.search(step.time)
        if stated:
            value, unit = float(stated.group(1)), stated.group(2)
            ran = lab.spans[step.check] if unit in ("τ", "T₀") else lab.units[step.check]
            assert value == pytest.approx(ran, rel=0.15, abs=1.0), (step.title, step.time, ran)


SPAN = re.compile(r"(\d+(?:\.\d+)?) (τ|T₀|load cycles?|loops?|cycles?|collisions?)")
"""The simulated time a step's Time states first: in τ or T₀, or in the preset's clock units."""


# ------------------------------------------------------------------- ratcheting with 16 disks
def cycle_times(lab: Lab) -> dict[int, float]:
    """The time each load cycle started."""
    return {int(row[0]): row[2] for row in lab.series["cycles"]}


@check("ratchet16-first-cycles")
def test_ratchet16_flattens_in_its_first_cycle_then_closes_its_loop():
    lab = run("ratchet16")
    gamma, starts = dict(lab.preset._cycle_gamma), cycle_times(lab)
    assert starts[0] == pytest.approx(23.0, abs=1.5)
    t, cycle, q, strain = np.array([row[:4] for row in lab.series["time"]]).T
    assert strain[cycle == 0].min() == pytest.approx(-4.2e-3, rel=0.03)
    assert gamma[1] == pytest.approx(-3.2e-4, rel=0.03)
    assert abs(gamma[2] - gamma[1]) < 2.5e-8


@check("ratchet16-strain-per-cycle")
def test_ratchet16_ratchets_upwards_by_5e_8_a_cycle():
    fit = run("ratchet16").seen["ratchet16-strain-per-cycle"]["fit"]
    assert fit["reference_cycle"] == 2 and fit["cycles_used"] == 7
    assert fit["dgamma"] == pytest.approx(5.1e-8, rel=0.03) and fit["ratcheting"]
    assert fit["dgamma"] / fit["rms"] == pytest.approx(5000, rel=0.3)


@check("ratchet16-sliding-contacts")
def test_ratchet16_two_wall_contacts_slide_twice_a_cycle_each_on_both_edges():
    lab = run("ratchet16")
    seen = lab.seen["ratchet16-sliding-contacts"]
    sim = lab.preset.sim
    labels = {pair: pair_name(sim, pair) for pair in seen["episodes"]}
    assert sorted(labels.values()) == ["11–right", "12–left"]
    for pair, episodes in seen["episodes"].items():
        assert sorted(episodes) == [STATUS_SLIDE_POS, STATUS_SLIDE_NEG], labels[pair]
    assert seen["contacts"] == 37
    paths = watched_paths(lab.series["contacts"], seen["start"], seen["end"])
    for pair, path in paths.items():
        slid = set(path[:, 2].astype(int)) - {1}
        assert slid == ({STATUS_SLIDE_POS, STATUS_SLIDE_NEG} if pair in seen["episodes"] else set())
        assert closure(path) < 1e-3
    named = {pair_name(sim, pair): path for pair, path in paths.items()}
    assert loop_area(named["12–left"]) > 0.8
    # every slide ends when the load turns: at the top of the load (mid-cycle) or at its bottom
    mu = preset_settings("ratchet16").friction  # the sheet's last step sets it to ∞
    period = lab.preset.load.period
    for pair, path in paths.items():
        times = np.array([row[2] for row in lab.series["contacts"]
                          if (row[0], row[1]) == pair and seen["start"] - 1e-9 <= row[2] <= seen["end"] + 1e-9])
        ends = np.flatnonzero((path[:-1, 2] != 1) & (path[1:, 2] == 1)) + 1
        phases = ((times[ends] - seen["start"]) / period) % 1.0
        assert np.all(np.minimum(np.abs(phases - 0.5), np.minimum(phases, 1.0 - phases)) < 0.01), pair
        on_edge = path[:, 2] != 1
        assert np.abs(path[on_edge, 1]) == pytest.approx(mu * path[on_edge, 0], rel=1e-9)


def pair_name(sim, pair) -> str:
    return pair_label(pair, sim.particles.count, sim.walls.names)


@check("ratchet16-no-sliding")
def test_ratchet16_without_sliding_drifts_20_to_25_times_less():
    lab = run("ratchet16")
    seen = lab.seen["ratchet16-no-sliding"]
    before = lab.seen["ratchet16-strain-per-cycle"]["fit"]["dgamma"]
    assert seen["episodes"] == {}
    fit = seen["fit"]
    assert fit["reference_cycle"] == 12  # ticked at cycle 9.5: two whole cycles after it
    gamma = dict(lab.preset._cycle_gamma)
    assert abs(gamma[10] - gamma[9]) > 100 * before  # the jump
    assert fit["dgamma"] == pytest.approx(2e-9, rel=0.15)
    assert 20 <= before / fit["dgamma"] <= 25
    starts = cycle_times(lab)
    last = max(starts)
    for pair, path in watched_paths(lab.series["contacts"], starts[last - 1], starts[last]).items():
        assert loop_area(path) < 0.02, pair  # the trapezoids are lines


# ---------------------------------------------------------------------------- elliptic loading
def cycle_paths(lab: Lab, cycle: int) -> dict:
    starts = cycle_times(lab)
    return watched_paths(lab.series["contacts"], starts[cycle], starts[cycle + 1])


@check("elliptic-loops")
def test_elliptic_contacts_run_round_closed_loops_without_sliding():
    lab = run("elliptic")
    assert lab.seen["elliptic-loops"]["episodes"] == {}
    assert cycle_times(lab)[0] == pytest.approx(23.0, abs=1.5)
    sim = lab.preset.sim
    paths = {pair_name(sim, pair): path for pair, path in cycle_paths(lab, 2).items()}
    assert all(closure(path) < 3e-3 for path in paths.values())
    assert all(np.all(path[:, 2] == 1) for path in paths.values())
    assert min(loop_area(paths["12–left"]), loop_area(paths["14–top"])) > 0.7  # full ellipses: π/4 of their box
    assert max(loop_area(paths["1–2"]), loop_area(paths["14–15"])) < 0.2


@check("elliptic-ratchets")
def test_elliptic_loading_ratchets_60_times_faster_than_ratchet16():
    fit = run("elliptic").seen["elliptic-ratchets"]["fit"]
    assert fit["dgamma"] == pytest.approx(-2.9e-6, rel=0.03) and fit["ratcheting"]
    assert run("elliptic").seen["elliptic-ratchets"]["episodes"] == {}
    ratchet16 = run("ratchet16").seen["ratchet16-strain-per-cycle"]["fit"]["dgamma"]
    assert -fit["dgamma"] / ratchet16 == pytest.approx(60, rel=0.1)


@check("elliptic-phase")
def test_elliptic_phase_of_30_degrees_halves_the_loops_and_the_strain_per_cycle():
    lab = run("elliptic")
    seen = lab.seen["elliptic-phase"]
    assert seen["episodes"] == {}
    fit = seen["fit"]
    assert fit["dgamma"] == pytest.approx(-1.5e-6, rel=0.03)
    assert fit["reference_cycle"] == math.ceil(lab.preset.changes[0]["cycle"]) + 2
    assert fit["dgamma"] / lab.seen["elliptic-ratchets"]["fit"]["dgamma"] == pytest.approx(0.5, abs=0.02)
    at_90, at_30 = cycle_paths(lab, 2), cycle_paths(lab, fit["reference_cycle"])
    for pair in at_90:
        assert enclosed(at_30[pair]) / enclosed(at_90[pair]) == pytest.approx(0.5, abs=0.03), pair


@check("elliptic-angle-spring")
def test_elliptic_with_the_angle_spring_jumps_once_then_stays_put():
    lab = run("elliptic")
    seen = lab.seen["elliptic-angle-spring"]
    gamma = dict(lab.preset._cycle_gamma)
    fit = seen["fit"]
    assert abs(fit["dgamma"]) < 1e-14
    fitted_from = fit["reference_cycle"]
    assert 0.5e-4 < gamma[fitted_from] - seen["before"] < 2e-4
    before = cycle_paths(lab, lab.seen["elliptic-phase"]["fit"]["reference_cycle"])
    for pair, path in cycle_paths(lab, fitted_from).items():
        assert enclosed(path) / enclosed(before[pair]) == pytest.approx(1.0, abs=0.03), pair


# ------------------------------------------------------------------ the biaxial box, 256 disks
def cycle_rows(lab: Lab, cycle: int) -> np.ndarray:
    """The rows of the time series of load cycle ``cycle`` (t, cycle, q, gamma, kinetic, stored, ...)."""
    rows = np.array(lab.series["time"])
    return rows[rows[:, 1] == cycle]


@check("ratchet-first-cycle")
def test_ratchet_box_is_flattened_by_its_first_cycle():
    lab = run("ratchet")
    readout = lab.seen["ratchet-first-cycle"]["readout"]
    assert cycle_times(lab)[0] == pytest.approx(20.0, abs=2.0)
    assert readout["phi"] == pytest.approx(0.84, abs=0.005) and readout["z"] == pytest.approx(4.05, abs=0.03)
    assert cycle_rows(lab, 0)[:, 3].min() == pytest.approx(-3.3e-3, rel=0.03)
    assert dict(lab.preset._cycle_gamma)[1] == pytest.approx(-7.2e-4, rel=0.03)


@check("ratchet-sliding-follows-load")
def test_ratchet_sliding_grows_with_the_load_and_stops_when_it_turns():
    seen = run("ratchet").seen["ratchet-sliding-follows-load"]
    phase, count = seen["counts"].T
    assert count[phase < 0.5].max() == pytest.approx(45, abs=8)
    assert count[(phase > 0.51) & (phase < 0.6)].max() <= 2  # within a hundredth of a cycle of the top
    assert count[(phase > 0.9) & (phase < 1.0)].max() == pytest.approx(25, abs=6)
    assert count[(phase > 0.005) & (phase < 0.05)].max() <= 2
    assert seen["touched"] == pytest.approx(575, abs=10)
    assert seen["slid"] == pytest.approx(65, abs=8) and 8 <= seen["touched"] / seen["slid"] <= 10


@check("ratchet-energy")
def test_ratchet_cycle_stores_nothing_and_dissipates_8e_5():
    lab = run("ratchet")
    stored = [cycle_rows(lab, c)[0, 5] for c in (1, 2, 3)]
    assert stored == pytest.approx([0.0098] * 3, abs=5e-5)
    dissipated = [cycle_rows(lab, c)[:, 6] for c in (0, 1, 2)]
    gains = [d[-1] - d[0] for d in dissipated]
    assert gains[0] == pytest.approx(1.8e-4, rel=0.05)
    assert gains[2] == pytest.approx(7.8e-5, rel=0.05)
    assert np.abs(np.diff(stored)).max() < 0.1 * gains[2]


@check("ratchet-settling")
def test_ratchet_increments_shrink_while_the_packing_settles():
    lab = run("ratchet")
    gamma = [g for _, g in lab.preset._cycle_gamma]
    steps = np.diff(gamma)[1:]
    assert steps * 1e6 == pytest.approx([-9.6, -3.0, -1.1], abs=0.1)
    fit = lab.seen["ratchet-settling"]["fit"]
    assert fit["dgamma"] == pytest.approx(-2.1e-6, rel=0.1)


# --------------------------------------------------------------------------------- closed path
def springs(lab: Lab) -> dict[str, np.ndarray]:
    """The springs series by column, the sample at each corner of the path (every 50) kept."""
    rows = np.array(lab.series["springs"])
    return dict(zip(lab.preset.series["springs"], rows.T))


@check("closed-path-one-loop")
def test_closed_path_returns_d_n_but_not_the_cundall_strack_d_t():
    s = springs(run("closed-path"))
    corners = slice(0, 201, 50)  # A, B, C, D, A again: 200 samples a loop
    assert s["dn_cundall_strack"][corners] == pytest.approx([-0.01, -0.03, -0.03, -0.01, -0.01], abs=1e-9)
    dt = s["dt_cundall_strack"][corners]
    assert np.diff(dt) == pytest.approx([0.0, 0.194, 0.0, -0.198], abs=1e-6)
    assert dt[-1] == pytest.approx(-0.004, abs=1e-6)


@check("closed-path-staircase")
def test_closed_path_cundall_strack_climbs_a_staircase_of_eq17():
    lab = run("closed-path")
    s = springs(lab)
    ends = s["dt_cundall_strack"][::200]
    assert ends[:6] == pytest.approx(-0.004 * np.arange(6), abs=1e-6)
    assert s["dn_cundall_strack"][::200][:6] == pytest.approx([-0.01] * 6, abs=1e-9)
    p = lab.preset
    (d_a, _), (d_b, _) = p._corners[0], p._corners[1]
    area = 0.5 * p.turn * (d_a ** 2 - d_b ** 2)  # ratcheting Eq. 17: a / (r_i + r_j), r_i + r_j = 1
    assert area / (2 * p.radius) == pytest.approx(0.0039, abs=5e-5)
    stiffness = p._sims[0].law.tangential_stiffness
    assert 0.5 * stiffness * ends[5] ** 2 == pytest.approx(2.0, rel=1e-3)


@check("closed-path-lammps")
def test_closed_path_lammps_climbs_the_same_staircase_one_percent_steeper():
    s = springs(run("closed-path"))
    lammps, cundall = s["dt_lammps"][::200], s["dt_cundall_strack"][::200]
    assert lammps[1] == pytest.approx(-0.0040, abs=5e-5)
    assert lammps[6] == pytest.approx(-0.0242, abs=5e-5) and cundall[6] == pytest.approx(-0.0240, abs=1e-6)
    assert np.diff(lammps[:7]) / np.diff(cundall[:7]) == pytest.approx([1.01] * 6, abs=0.005)


@check("closed-path-springs-return")
def test_closed_path_alpha_and_angle_springs_return_after_every_loop():
    s = springs(run("closed-path"))
    for model in ("alpha", "angle"):
        assert np.abs(s[f"dt_{model}"][::200]).max() < 1e-14, model
        assert s[f"dn_{model}"][::200] == pytest.approx([-0.01] * 8, abs=1e-9)


# ---------------------------------------------------------------------------------- the block
def block_events(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The samples where sliding starts and where it stops."""
    slides = np.isin(rows[:, 4], (STATUS_SLIDE_POS, STATUS_SLIDE_NEG)).astype(int)
    change = np.flatnonzero(np.diff(slides)) + 1
    return change[slides[change] == 1], change[slides[change] == 0]


@check("block-starts-at-mu")
def test_block_starts_sliding_when_the_load_reaches_mu_fn():
    rows = run("block").seen["block-stops-at-rest"]["rows"]
    t, ratio, normal, tangential, status, velocity = rows.T
    (start,), _ = block_events(rows)
    assert t[start] == pytest.approx(20.0 / 3.0, abs=0.15) and ratio[start] == pytest.approx(1.0, abs=0.015)
    assert np.abs(velocity[:start]).max() < 1e-3
    assert tangential[:start] == pytest.approx(0.5 * ratio[:start], abs=0.003)  # F_t follows the load, μ = 0.5
    assert tangential[start] == pytest.approx(0.5 * normal[start], rel=1e-9) and normal[start] == pytest.approx(1.0)


@check("block-fastest")
def test_block_is_fastest_when_the_load_falls_back_to_mu_fn():
    rows = run("block").seen["block-stops-at-rest"]["rows"]
    t, ratio, velocity = rows[:, 0], rows[:, 1], rows[:, 5]
    fastest = velocity.argmax()
    assert velocity[fastest] == pytest.approx(0.5 * 20.0 / 12.0, rel=0.005)
    assert t[fastest] == pytest.approx(13.3, abs=0.15) and ratio[fastest] == pytest.approx(1.0, abs=0.02)


@check("block-stops-at-rest")
def test_block_stops_sliding_only_at_rest_at_0_29_mu_fn():
    seen = run("block").seen["block-stops-at-rest"]
    rows = seen["rows"]
    t, ratio, velocity = rows[:, 0], rows[:, 1], rows[:, 5]
    (start,), (stop,) = block_events(rows)
    assert t[stop] == pytest.approx(18.1, abs=0.1) and ratio[stop] == pytest.approx(0.29, abs=0.01)
    assert abs(velocity[stop]) < 3e-3 * velocity.max()
    assert np.all(np.abs(rows[stop:, 3]) < 0.99 * 0.5 * rows[stop:, 2])  # stuck, inside the cone
    assert velocity.min() > -5e-3 * velocity.max()  # never back: only the contact spring rings after the stop
    assert seen["x"] == pytest.approx(5.4, abs=0.05)
    assert seen["friction_work"] == pytest.approx(0.5 * seen["x"], rel=1e-3)  # μF_n × the distance slid


@check("block-double-period")
def test_block_slower_load_same_thresholds_twice_as_fast_four_times_as_far():
    lab = run("block")
    seen, before = lab.seen["block-double-period"], lab.seen["block-stops-at-rest"]
    assert seen["period"] == 40.0
    rows = seen["rows"]
    t, ratio, velocity = rows[:, 0], rows[:, 1], rows[:, 5]
    (start,), (stop,) = block_events(rows)
    assert ratio[start] == pytest.approx(1.0, abs=0.015) and ratio[stop] == pytest.approx(0.29, abs=0.01)
    assert t[start] / 40.0 == pytest.approx(1 / 3, abs=0.005) and t[stop] / 40.0 == pytest.approx(0.90, abs=0.005)
    assert velocity.max() == pytest.approx(1.67, abs=0.01)
    assert seen["x"] == pytest.approx(21.6, abs=0.1) and seen["x"] / before["x"] == pytest.approx(4.0, rel=0.01)
    assert seen["friction_work"] == pytest.approx(10.8, abs=0.05)


@check("block-half-friction")
def test_block_with_half_the_friction_matches_the_numbers_predicted_from_the_closed_form():
    """The step's predictions, from the equation of motion while sliding (m dv/dt = (r − 1) μF_n):
    the load at the start μF_n, the peak speed μF_n T / (12 m), the distance and friction's work
    scaled from the step with μ = 0.5 by μ and μ²."""
    lab = run("block")
    seen, full = lab.seen["block-half-friction"], lab.seen["block-stops-at-rest"]
    assert lab.preset.settings.friction == 0.25 and lab.preset.settings.period == 20.0
    rows = seen["rows"]
    t, ratio, normal, tangential, velocity = rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], rows[:, 5]
    (start,), (stop,) = block_events(rows)
    assert ratio[start] * 0.25 * normal[start] == pytest.approx(0.25, abs=0.004)  # the load, in units of F_n
    assert t[start] == pytest.approx(20.0 / 3.0, abs=0.15) and t[stop] == pytest.approx(18.1, abs=0.1)
    assert velocity.max() == pytest.approx(0.25 * 20.0 / 12.0, rel=0.01)
    assert t[velocity.argmax()] == pytest.approx(13.3, abs=0.15)
    assert seen["x"] == pytest.approx(2.7, abs=0.03) and seen["x"] / full["x"] == pytest.approx(0.5, rel=0.01)
    assert seen["friction_work"] / full["friction_work"] == pytest.approx(0.25, rel=0.01)


# ------------------------------------------------------------------------------- the collision
APPROACH_ENERGY = 0.5 * 0.5 * 2.0 ** 2
"""½ m_eff v² of the collision preset: m_eff = 1/2, approach speed 2."""


def collisions_at(seen: dict, zeta: float) -> tuple[np.ndarray, np.ndarray]:
    """The collisions of damping ``zeta`` (rows: number, ζ, e_N, predicted) and their contacts' samples
    (t, collision, δ, F_n, K_n δ)."""
    rows = seen["collisions"][seen["collisions"][:, 1] == zeta]
    path = seen["path"]
    return rows, path[np.isin(path[:, 1], rows[:, 0])]


def dashpot_work(path: np.ndarray) -> float:
    """∮ F_n dδ over one collision's samples: the energy the dashpot took (trapezoids). The loop is
    closed at δ = 0 at the first and last samples' forces: near the edges the dashpot's c·v is most
    of the force and changes little between samples."""
    overlap = np.concatenate([[0.0], path[:, 2], [0.0]])
    force = np.concatenate([path[:1, 3], path[:, 3], path[-1:, 3]])
    return float(np.trapezoid(force, overlap))


@check("collision-elastic")
def test_collision_without_damping_bounces_back_at_its_approach_speed_along_the_spring_line():
    rows, path = collisions_at(run("collision").seen["collision-elastic"], 0.0)
    assert len(rows) == 3
    assert rows[:, 2] == pytest.approx(1.0, abs=1e-5)
    assert path[:, 3] == pytest.approx(path[:, 4], rel=1e-9)  # the force is the spring's alone
    assert path[:, 2].max() == pytest.approx(2.0 * math.sqrt(0.5 / 1e4), rel=2e-3)  # δ_max = v √(m_eff / K_n)


@check("collision-restitution-predicted")
def test_collision_restitution_at_zeta_one_half_is_the_formulas_to_the_fourth_decimal():
    rows, path = collisions_at(run("collision").seen["collision-restitution-predicted"], 0.5)
    predicted = math.exp(-math.pi * 0.5 / math.sqrt(0.75))
    assert len(rows) == 3 and predicted == pytest.approx(0.163, abs=5e-4)
    assert rows[:, 2] == pytest.approx(predicted, abs=5e-5) and rows[:, 3] == pytest.approx(predicted, rel=1e-12)
    first = path[path[:, 1] == rows[0, 0]]
    assert dashpot_work(first) == pytest.approx((1.0 - predicted ** 2) * APPROACH_ENERGY, rel=0.03)


@check("collision-gilabert-damping")
def test_collision_at_gilabert_damping_hardly_bounces_pulls_at_the_end_and_lasts_longer():
    rows, path = collisions_at(run("collision").seen["collision-gilabert-damping"], 0.8)
    assert len(rows) == 3 and rows[:, 2] == pytest.approx(0.0152, abs=1e-4)
    first = path[path[:, 1] == rows[0, 0]]
    assert first[-1, 3] < 0.0  # the dashpot pulls the parting disks
    duration = first[-1, 0] - first[0, 0]
    assert duration == pytest.approx(math.pi / (math.sqrt(1e4 / 0.5) * 0.6), abs=1.2e-3)  # 0.037


# ------------------------------------------------------------------------------- aggregation
def at(rows: np.ndarray, time: float) -> np.ndarray:
    """The sample nearest ``time``."""
    return rows[np.abs(rows[:, 0] - time).argmin()]


@check("aggregation-clusters-merge")
def test_aggregation_merges_300_disks_into_50_clusters_at_fixed_density():
    rows = run("aggregation").seen["aggregation-clusters-merge"]["rows"]
    t, z, phi, count, kinetic = at(rows, 60.0)
    assert rows[0, 3] == 300 and count == pytest.approx(50, abs=8)
    assert np.all(rows[:, 2] == pytest.approx(0.36, rel=1e-12))
    assert rows[0, 1] == 0 and z == pytest.approx(1.8, abs=0.1)


@check("aggregation-slow-settling")
def test_aggregation_slows_down():
    rows = run("aggregation").seen["aggregation-slow-settling"]["rows"]
    t, z, phi, count, kinetic = at(rows, 150.0)
    assert count == pytest.approx(16, abs=4) and z == pytest.approx(2.5, abs=0.1)
    assert z > at(rows, 120.0)[1]  # still rising
    assert rows[0, 4] / kinetic == pytest.approx(13, rel=0.2)
    # the clusters' merging slows: fewer merge in the 90 T₀ after 60 T₀ than in the first 60
    assert at(rows, 60.0)[3] - count < 300 - at(rows, 60.0)[3]


@check("aggregation-rolling-resistance")
def test_aggregation_with_rolling_resistance_has_fewer_contacts():
    lab = run("aggregation")
    seen = lab.seen["aggregation-rolling-resistance"]
    assert seen["law"].rolling_friction == 0.0015 and seen["law"].rolling_stiffness == 0.1
    with_rr = at(seen["rows"], 150.0)
    without = at(lab.seen["aggregation-slow-settling"]["rows"], 150.0)
    assert with_rr[1] == pytest.approx(1.9, abs=0.1) and without[1] - with_rr[1] > 0.4
    assert with_rr[3] == pytest.approx(15, abs=4) and abs(with_rr[3] - without[3]) <= 4
    assert with_rr[4] < without[4]


# ------------------------------------------------------------------------------- compression
@check("compression-jams")
def test_compression_jams_at_0_825():
    lab = run("compression")
    seen = lab.seen["compression-jams"]
    t, z, phi, pressure, kinetic = seen["rows"][-1]
    assert seen["t"] == pytest.approx(30.0, abs=5.0)
    assert phi == pytest.approx(0.825, abs=0.002) and z == pytest.approx(3.45, abs=0.03)
    assert pressure == pytest.approx(1.0, abs=0.005)
    assert at(seen["rows"], 4.0)[2] > 0.81


@check("compression-rattlers")
def test_compression_has_7_percent_rattlers():
    lab = run("compression")
    stats = lab.seen["compression-rattlers"]["stats"]
    assert stats.particles == 300 and stats.rattlers == pytest.approx(20, abs=3)
    assert stats.z == pytest.approx(lab.seen["compression-jams"]["rows"][-1, 1])
    assert stats.z_star == pytest.approx(stats.z / (1 - stats.rattlers / 300)) and stats.z_star == pytest.approx(3.7,
                                                                                                             abs=0.05)


@check("compression-friction")
def test_compression_with_more_friction_is_looser_with_fewer_contacts():
    seen = run("compression").seen["compression-friction"]
    assert seen["readout"]["phi"] == pytest.approx(0.81, abs=0.005)
    assert seen["readout"]["z"] == pytest.approx(2.85, abs=0.05)
    assert seen["stats"].rattlers == pytest.approx(45, abs=8)


@check("compression-rolling")
def test_compression_rolling_resistance_loosens_it_a_little():
    lab = run("compression")
    seen, before = lab.seen["compression-rolling"], lab.seen["compression-friction"]
    assert lab.preset.sim.law.rolling_friction == 0.005 and lab.preset.sim.law.friction == 0.5
    assert seen["readout"]["phi"] == pytest.approx(0.79, abs=0.005)
    assert 0.005 < before["readout"]["phi"] - seen["readout"]["phi"] < 0.02
    assert seen["readout"]["z"] == pytest.approx(before["readout"]["z"], abs=0.1)


# --------------------------------------------------------------------------- loader and HTML
SHEET = """# Lesson: a test

An introduction
on two lines.

A second paragraph.

## Step 1: First
**Do:** Press Restart.
**Ask:** What happens?
**See:** It runs,
and goes on.
**Time:** about 3 s (1 load cycle)
**Answer:** Because.
**Paper:** ratcheting Fig. 1
**Check:** a-check
"""


def test_a_sheet_is_read_field_by_field():
    sheet = parse_lesson(SHEET, "ratchet")
    assert sheet.title == "Lesson: a test" and sheet.preset == "ratchet"
    assert sheet.intro == "An introduction\non two lines.\n\nA second paragraph."
    (step,) = sheet.steps
    assert step.title == "First" and step.see == "It runs, and goes on." and step.check == "a-check"
    assert step.seconds == 3.0 and sheet.seconds == 3.0


@pytest.mark.parametrize("change, line, message", [
    (("# Lesson: a test", "Lesson: a test"), 1, "starts with its title"),
    (("An introduction\non two lines.\n\nA second paragraph.\n", ""), 2, "followed by an introduction"),
    (("## Step 1: First", "## Step 2: First"), 8, "this is step 1, not 2"),
    (("## Step 1: First", "## First"), 8, "'## Step 1: <title>'"),
    (("**Ask:** What happens?\n", ""), 10, "expected '**Ask:** ...' here, not '**See:**'"),
    (("**Check:** a-check\n", ""), 15, "ends without '**Check:** ...'"),
    (("about 3 s (1 load cycle)", "one cycle"), 13, "its Time starts with the seconds"),
    (("**Check:** a-check", "**Check:** A check"), 16, "its Check is one id"),
    (("**Answer:** Because.", "**Answer:**"), 14, "its Answer is empty"),
    (("**Do:** Press Restart.", "Press Restart."), 9, "goes on with '**Do:** ...'"),
])
def test_a_malformed_sheet_is_refused_naming_its_file_and_line(change, line, message):
    old, new = change
    with pytest.raises(LessonError) as error:
        parse_lesson(SHEET.replace(old, new), "ratchet", LESSONS / "ratchet.md")
    assert str(error.value).startswith(f"static/teaching/lessons/ratchet.md, line {line}: ")
    assert message in str(error.value)


def test_a_repeated_check_is_refused():
    two = SHEET + SHEET[SHEET.index("## Step 1"):].replace("Step 1", "Step 2")
    with pytest.raises(LessonError, match=r"line 17: step 2 repeats the check 'a-check' of step 1"):
        parse_lesson(two, "ratchet", "x.md")


@pytest.mark.parametrize("name", ["experiment", "../teaching/ratchet", "ratchet.md", "", "Ratchet", None])
def test_a_preset_without_a_sheet_has_no_lesson(name):
    assert lesson(name) is None


def test_inline_markdown_is_escaped_then_rendered():
    assert inline("a < b & `x_1 <y>` **bold** *it* 2 * 3 * 4") == \
        "a &lt; b &amp; <code>x_1 &lt;y&gt;</code> <strong>bold</strong> <em>it</em> 2 * 3 * 4"


def test_the_html_keeps_the_teacher_apart():
    sheet = lesson("ratchet16")
    html = lesson_html(sheet)
    assert "<html" not in html and html.count('class="lesson-step"') == len(sheet.steps)
    for step in sheet.steps:
        assert f'data-check="{step.check}"' in html
        start = html.index(f'data-check="{step.check}"')
        teacher = html.index('class="lesson-teacher"', start)
        assert html.index(inline(step.ask), start) < teacher < html.index(inline(step.see), start)
        assert html.index(inline(step.answer), start) > teacher


@pytest.mark.parametrize("name", list(PRESETS))
def test_the_standalone_page_asks_nothing_of_any_host(name):
    html = lesson_html(lesson(name), standalone=True)
    assert html.startswith("<!DOCTYPE html>") and "@page" in html and '<meta charset="utf-8">' in html
    assert not re.search(r"(src|href)\s*=|url\(|@import|//", html.replace("</", ""))


def test_every_sheet_prints_on_one_a4_and_one_letter_page(browser):
    requests = []
    page = browser.new_page()
    page.on("request", lambda request: requests.append(request.url))
    for name in PRESETS:
        page.set_content(lesson_html(lesson(name), standalone=True))
        for paper in ("A4", "Letter"):
            pdf = page.pdf(format=paper, print_background=True)
            assert len(re.findall(rb"/Type\s*/Page\b(?!s)", pdf)) == 1, (name, paper)
    page.close()
    assert requests == []


def test_the_static_readme_lists_every_sheet_with_its_steps_and_time():
    rows = re.findall(r"^\| `([\w-]+)\.md` \| (\d) \| (\d+) s \|", (STATIC / "README.md").read_text(), re.MULTILINE)
    assert {name: (int(steps), int(seconds)) for name, steps, seconds in rows} == \
        {name: (len(lesson(name).steps), round(lesson(name).seconds)) for name in PRESETS}
