"""What people read of an analysis: a label for every value, texts without nan/inf/None, a missing
value shown as "—" with the reason the analysis recorded, the states of the critical contacts in
words, the figures each report can draw, and ``granlab analyze`` printing the rows (its --json unchanged)."""

import dataclasses
import functools
import json
import math
import re

import numpy as np
import pytest

from granlab.app import commands as cli
from granlab.engine.analysis import ANALYSES
from granlab.engine.analysis import report as rp
from granlab.engine.analysis import rigidity as rg
from granlab.engine.analysis import status as ss
from granlab.engine.analysis import stiffness as st
from granlab.engine.analysis.report import MISSING, AnalysisReport, analyze
from granlab.engine.analysis.states import PackingState, read_state
from granlab.engine.errors import ParameterError
from granlab.engine.generate import radii as make_radii, random_gas
from granlab.engine.io.h5md import RunWriter
from granlab.engine.params import ContactLaw
from granlab.engine.simulation import ContactSnapshot
from granlab.engine.state import STATUS_SLIDE_NEG
from tests.test_analysis import chain_state, method1_packing


@functools.cache
def sliding_packing() -> PackingState:
    """The packing of method 1 (150 disks, mu = 0.5) with its first three loaded disk-disk contacts
    put on the Coulomb cone (F_t = mu N^e, sliding): three critical contacts, eight states to enumerate."""
    state = PackingState.from_snapshot(method1_packing().snapshot())
    c = state.contacts
    rows = np.flatnonzero((c.j < state.disks) & (c.elastic_normal_force > 0.0))[:3]
    tangential, status = c.tangential_force.copy(), c.status.copy()
    tangential[rows] = state.law.friction * c.elastic_normal_force[rows]
    status[rows] = STATUS_SLIDE_NEG
    return dataclasses.replace(state, contacts=dataclasses.replace(c, tangential_force=tangential, status=status))


def free_disks(positions, radii, side: float, source: str) -> PackingState:
    """Disks without contacts in a periodic square cell of side ``side``."""
    none = np.zeros(0)
    contacts = ContactSnapshot(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 2), np.int64),
                               np.zeros(0, np.int8), none, none, none, none, none, none, none)
    lengths = np.array([side, side])
    return PackingState(np.asarray(positions, float), np.asarray(radii, float), contacts, ContactLaw(), (),
                        np.zeros((0, 2)), none, none, (), lengths, lengths, (True, True), np.zeros((2, 2)), 0.0, 0,
                        True, source)


@functools.cache
def gas(count: int) -> PackingState:
    """``count`` disks placed at random (Φ = 0.45): no power law in I(k), and the void percolates."""
    r = make_radii(count, radius_min=0.25, radius_max=0.5, distribution="uniform", seed=3)
    side = math.sqrt(np.pi * np.sum(r ** 2) / 0.45)
    return free_disks(random_gas(r, (0.0, side, 0.0, side), periodic=(True, True), seed=3), r, side, "gas")


def covered_cell() -> PackingState:
    """Two disks larger than their cell: no empty space at all."""
    return free_disks([[0.25, 0.25], [0.75, 0.75]], [1.0, 1.0], 1.0, "covered")


@functools.cache
def reports() -> dict:
    """(state name, analysis) -> report, for every analysis each state allows."""
    out = {("sliding", kind): analyze(sliding_packing(), kind) for kind in ANALYSES}
    no_forces = dataclasses.replace(sliding_packing(), forces_known=False)
    out[("no forces", "packing")] = analyze(no_forces, "packing")
    for name, state in (("gas", gas(150)), ("small gas", gas(12)), ("covered", covered_cell())):
        for kind in ("packing", "fractal"):
            out[(name, kind)] = analyze(state, kind)
    return out


def rows_of(report: AnalysisReport) -> dict:
    return {row.key: row for row in report.rows()}


def is_missing(value) -> bool:
    if isinstance(value, (tuple, list)) and value and not isinstance(value[0], (str, list)):
        return any(is_missing(v) for v in value)
    return value is None or (isinstance(value, float) and not math.isfinite(value))


def test_every_value_has_a_label_and_a_text_without_nan_inf_or_none():
    for (name, kind), report in reports().items():
        rows = report.rows()
        assert [row.key for row in rows] == list(report.values)
        for row in rows:
            assert row.label == ANALYSES[kind].load().LABELS[row.key], (kind, row.key)
            assert not re.search(r"\b(nan|inf|None)\b", row.text, re.IGNORECASE), (name, kind, row)
            assert row.text, (name, kind, row)
            if row.text == MISSING:
                assert row.note, (name, kind, row.key)
            if is_missing(report.values[row.key]):
                assert row.text == MISSING, (name, kind, row)


def test_the_labels_name_the_paper_symbols_and_units():
    assert rp.label("status", "critical_contacts") == "Critical contacts M_c (on the Coulomb cone)"
    assert rp.label("fractal", "d_F") == "Fractal dimension d_F (fit of Gilabert Eq. 28) [dimensionless]"
    assert rp.label("fractal", "xi") == "Blob size ξ, the cut-off length of Eqs. 27–28 [length]"
    assert rp.label("fractal", "mean_hole_radius_w") == "Weighted mean hole radius ⟨R⟩_w (Gilabert Eq. 30) [length]"
    assert rp.label("packing", "contacts") == "Force-carrying disk–disk interactions"
    assert rp.label("status", "contacts") == "Interactions M: contacts and distant cohesive pairs"
    # a ring of 5 disks (normal forces 5, 3, 7, 2.5, 6) with a sixth disk pressed on it by 100
    chain = rows_of(analyze(chain_state([5.0, 3.0, 7.0, 2.5, 6.0]), "packing"))
    assert chain["coordination"].text == "x_0 = 0, x_1 = 0.1667, x_2 = 0.6667, x_3 = 0.1667"
    assert chain["mean_normal_force"].text == "20.58"  # 123.5 / 6
    assert chain["normal_force_histogram"].text == "40 bins from 0.1215 to 4.858"  # 2.5 and 100 over 20.58
    assert chain["theta_histogram"].text == "36 bins from 0 to 180"
    assert chain["percolation_force"].text == "2.5"  # the weakest link of the ring
    assert chain["forces_known"].text == "yes"
    assert rows_of(reports()[("sliding", "stiffness")])["load"].text == \
        "random forces on the disks, adding up to zero (seeded)"


def test_a_failed_fit_and_percolating_holes_read_as_dashes_with_their_reasons():
    no_power_law = ("no power-law range in I(k) to fit by Eq. 28: a dense or random packing, or too small a cell, "
                    "has none")
    dense = rows_of(reports()[("sliding", "fractal")])
    assert (dense["d_F"].text, dense["d_F"].note) == (MISSING, no_power_law)
    assert (dense["xi"].text, dense["xi"].note) == (MISSING, "no fit of Eq. 28, see d_F")
    assert dense["fit_error"].text == "failed" and "does not decay like a power law" in dense["fit_error"].note
    assert re.fullmatch(r"0\.\d+", dense["mean_hole_radius_w"].text) and dense["mean_hole_radius_w"].note == ""
    small = rows_of(reports()[("small gas", "fractal")])
    assert small["d_F"].note == "too few wavevectors below 2π/a for a fit of Eq. 28: the cell is too small"
    assert small["fit_error"].text == "failed" and "a larger box" in small["fit_error"].note
    loose = rows_of(reports()[("gas", "fractal")])
    assert (loose["d_F"].text, loose["d_F"].note) == (MISSING, no_power_law)
    assert loose["mean_hole_radius_w"].text == MISSING
    assert loose["mean_hole_radius_w"].note.startswith("a hole wraps around the periodic cell: the holes percolate")
    covered = rows_of(reports()[("covered", "fractal")])
    assert covered["mean_hole_radius_w"].note == "no holes: the disks cover the whole cell"
    assert covered["d_F"].note.startswith("no fit of Eq. 28: phi = 1.0")


def test_packing_values_without_forces_or_contacts_say_why():
    no_forces = rows_of(reports()[("no forces", "packing")])
    for key in ("force_unit", "mean_normal_force", "rumpf_force", "percolation_force", "theta_histogram"):
        assert (no_forces[key].text, no_forces[key].note) == \
            (MISSING, "no contact forces in this state (contacts found from the geometry)")
    assert no_forces["forces_known"].text == "no"
    loose = rows_of(reports()[("gas", "packing")])
    assert (loose["z_star"].text, loose["z_star"].note) == (MISSING, "every disk is a rattler: there is no backbone")
    assert loose["rumpf_force"].note == "no disk–disk interactions (z Φ = 0)"
    assert loose["percolation_force"].note.startswith("the force-carrying contacts never percolate")


def test_states_of_the_critical_contacts_in_words():
    names = ("3–7", "5–wall 'top'")
    for states, text in ((["00"], "1 state: none sliding"),
                         (["01", "11"],
                          "2 states: contact 5–wall 'top' sliding; contacts 3–7, 5–wall 'top' sliding"),
                         ([], "none"),
                         ([""], "1 state: no critical contact")):
        assert ss.states_text(states, names) == text
    report = reports()[("sliding", "status")]
    net, values = report.result.network, report.values
    assert values["critical_contacts"] == 3 and values["states_checked"] == 8
    described = []
    for state in values["consistent_states"]:
        sliding = [f"{net.first[a]}–{net.second[a]}"
                   for a, bit in zip(report.result.solution.critical, state) if bit == "1"]
        described.append(f"contact{'s' if len(sliding) > 1 else ''} {', '.join(sliding)} sliding" if sliding
                         else "none sliding")
    count = len(described)
    assert rows_of(report)["consistent_states"].text == \
        f"{count} state{'s' if count > 1 else ''}: " + "; ".join(described)


def test_a_skipped_enumeration_and_unclassified_modes_say_why(monkeypatch):
    monkeypatch.setattr(ss, "MAX_ENUMERATED", 2)
    monkeypatch.setattr(st, "MODE_VECTORS", 1)
    monkeypatch.setattr(rg, "MODE_VECTORS", 1)
    status = rows_of(analyze(sliding_packing(), "status"))
    for key in ("states_checked", "consistent_states", "unstable_states", "bijective"):
        assert (status[key].text, status[key].note) == (MISSING, "not enumerated: too many critical contacts")
    assert status["enumeration_skipped"].label == "Enumeration of the 2^M_c states"
    assert status["enumeration_skipped"].text == "skipped"
    assert status["enumeration_skipped"].note.startswith("3 critical contacts: all states are enumerated for at most 2")
    unclassified = ("more than 1 null modes besides the rattlers': their vectors are not computed, so they are not "
                    "classified")
    stiffness = rows_of(analyze(sliding_packing(), "stiffness"))
    for key in ("rigid_body_modes", "unexcited_mechanisms", "collapse"):
        assert (stiffness[key].text, stiffness[key].note) == (MISSING, unclassified)
    rigidity = rows_of(analyze(sliding_packing(), "rigidity"))
    assert (rigidity["stiffness_positive_definite"].text, rigidity["stiffness_positive_definite"].note) == \
        (MISSING, unclassified)


def test_each_report_names_the_figures_it_can_draw():
    figures = {key: report.figures for key, report in reports().items()}
    assert figures[("sliding", "stiffness")] == ()  # its null modes are its translations: no mechanism to draw
    assert figures[("sliding", "status")] == ("network",)
    assert figures[("sliding", "rigidity")] == ()
    assert figures[("sliding", "packing")] == ("forces",)
    assert figures[("no forces", "packing")] == ()
    assert figures[("sliding", "fractal")] == ("structure",)
    assert figures[("covered", "fractal")] == ()  # an all-solid grid: I(k) = 0 for k != 0
    for found in figures.values():
        assert set(found) <= set(rp.FIGURES)


def test_granlab_analyze_prints_the_rows_and_its_json_keeps_nan(tmp_path, capsys):
    path = tmp_path / "packing.h5"
    sim = method1_packing()
    with RunWriter(path, sim) as writer:
        writer.write_frame(sim)
    assert cli.main(["analyze", str(path), "fractal"]) == 0
    lines = capsys.readouterr().out.splitlines()
    d_f = next(line for line in lines if line.lstrip().startswith("Fractal dimension"))
    assert re.fullmatch(r"  Fractal dimension d_F \(fit of Gilabert Eq. 28\) \[dimensionless\]: +— {2}"
                        r"\(no power-law range in I\(k\) to fit by Eq. 28: a dense or random packing, or too small "
                        r"a cell, has none\)", d_f)
    report = analyze(read_state(path), "fractal")
    columns = set()
    for row, line in zip(report.rows(), lines[1:-1]):
        after = line[len(f"  {row.label}:"):]
        assert line.startswith(f"  {row.label}:") and after.lstrip().startswith(row.text)
        columns.add(len(line) - len(after.lstrip()))
    assert len(columns) == 1  # the texts start in one column
    assert cli.main(["analyze", str(path), "fractal", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["d_F"] == "nan" and result["fit_range"] == ["nan", "nan"]
    assert set(result) == {"analysis", "timings_s", "run_file", "source", "particles", "forces_known", "law", "warnings",
                           *report.values}


def test_an_analysis_runs_on_the_threads_it_is_given_and_gives_the_same_values():
    """The lab gives an analysis the cores its engine leaves free: numba's kernels, the FFT and BLAS
    run on that many threads during it, and on as many as before after it; the values do not change."""
    import numba
    import scipy.fft
    from threadpoolctl import threadpool_info

    state = PackingState.from_snapshot(method1_packing().snapshot())
    before = numba.get_num_threads(), scipy.fft.get_workers()
    with rp.analysis_threads(1):
        assert (numba.get_num_threads(), scipy.fft.get_workers()) == (1, 1)
        assert all(pool["num_threads"] == 1 for pool in threadpool_info() if pool["user_api"] == "blas")
    assert (numba.get_num_threads(), scipy.fft.get_workers()) == before
    for kind in ("rigidity", "fractal"):
        one, every = analyze(state, kind, threads=1).values, analyze(state, kind).values
        assert json.dumps(one, default=str) == json.dumps(every, default=str)
    with pytest.raises(ParameterError, match="threads = 0 is not allowed"):
        analyze(state, "packing", threads=0)
