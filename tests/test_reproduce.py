"""The Gilabert reproductions: published values as printed, Dask equal to serial, the physics of
small samples, and bad input."""

import json
import math
import os
import re
import signal
import subprocess
import sys
import time
from dataclasses import asdict
from pathlib import Path
from types import SimpleNamespace

import numba
import numpy as np
import pytest

from granlab.engine import ParameterError
from granlab.app.commands.reproduce import _print_reproduce
from granlab.engine.reproduce import (HOLE_RADIUS, METHOD1_COLUMNS, PHI_I, TABLE_II, TABLE_III, TABLE_IV, TABLE_V,
                                      TABLE_VII, Case, Published, Reproduction, gilabert_sample, published,
                                      resume_folder, run_reproduction, sample_key, start_folder, summarize)

PAPER = Path(__file__).resolve().parents[2] / "shared" / "papers" / "003_8b3722194af85a9b.txt"
NUMBER = re.compile(r"\d+\.\d+")


def granlab(*args):
    return subprocess.run([sys.executable, "-m", "granlab.app.commands", *args], capture_output=True, text=True,
                          timeout=300)


def _numbers(line):
    return [float(x) for x in NUMBER.findall(line)]


def _flat(row):
    return [x for p in row for x in (p.value, p.error)]


@pytest.fixture(scope="module")
def paper_lines():
    if not PAPER.exists():
        pytest.skip(f"the paper's text is not at {PAPER}")
    return PAPER.read_text(encoding="utf-8").splitlines()


def _block(lines, start, end):
    """Rows (lines starting with a number) after the line containing ``start``, up to ``end``."""
    first = next(k for k, line in enumerate(lines) if start in line)
    last = next(k for k in range(first, len(lines)) if lines[k].startswith(end))
    return [line for line in lines[first:last] if line[:1].isdigit()]


@pytest.mark.parametrize("table, start, end", [(TABLE_II, "Non-Cohesive samples", "TABLE II:"),
                                               (TABLE_III, "\tCohesive samples", "TABLE III:")])
def test_tables_ii_and_iii_are_transcribed_as_printed(paper_lines, table, start, end):
    rows = _block(paper_lines, start, end)
    assert len(rows) == 6  # three Phi_I, solid fraction then coordination number
    for line, (quantity, label) in zip(rows, [(q, l) for q in ("phi", "z") for l in table["phi"]]):
        printed = _numbers(line)
        assert printed[:2] == _numbers(label)
        assert printed[2:] == _flat(table[quantity][label])


def test_tables_iv_v_vii_and_hole_radius_are_transcribed_as_printed(paper_lines):
    for table, caption in ((TABLE_IV, "TABLE IV:"), (TABLE_V, "TABLE V:")):
        end = next(k for k, line in enumerate(paper_lines) if line.startswith(caption))
        rows = [line for line in paper_lines[end - 6:end] if line[:1].isdigit()]
        assert len(rows) == len(table)
        for line, (label, values) in zip(rows, table.items()):
            assert _numbers(line)[:2] == _numbers(label)
            assert _numbers(line)[2:] == _flat(values)
    d_f = next(line for line in paper_lines if line.startswith("d_F\t"))
    xi = next(line for line in paper_lines if line.startswith("ξ/a\t"))
    assert _numbers(d_f) == _flat(TABLE_VII["d_F"]) and _numbers(xi) == _flat(TABLE_VII["xi"])
    text = "\n".join(paper_lines)
    assert "= 6.6 \\pm 0.2$" in text and "= 5.47 \\pm 0.14$ with RR" in text
    assert _flat(HOLE_RADIUS) == [6.6, 0.2, 5.47, 0.14]


def test_each_case_gets_its_own_column():
    assert published("gilabert-method1", Case(True, 0.5, True)) == {
        "phi": Published(0.688, 0.001, "Table III"), "z": Published(2.971, 0.006, "Table III")}
    assert published("gilabert-method1", Case(False, 0.15, True))["z"] == Published(3.123, 0.013, "Table II")
    rr = published("gilabert-method2", Case(True, 0.5, True))
    assert (rr["phi_0"].value, rr["z_0"].value, rr["phi"].value, rr["z"].value) == (0.361, 2.660, 0.524, 2.973)
    assert (rr["d_F_0"].value, rr["xi_0"].value, rr["d_F"].value, rr["xi"].value) == (1.53, 9.3, 1.51, 5.06)
    assert published("gilabert-method2", Case(True, 0.5, False))["hole_radius_w"] == Published(6.6, 0.2, "Sec. V D")
    # k0 = Phi (xi/a)^(2 - d_F) of Tables IV, V and VII: 0.361 * 9.3^0.47, 0.524 * 5.06^0.49, ...
    no_rr = published("gilabert-method2", Case(True, 0.5, False))
    assert [q["k0_0"].value for q in (rr, no_rr)] + [q["k0"].value for q in (rr, no_rr)] == pytest.approx(
        [1.030, 0.424, 1.160, 0.536], abs=1e-3)
    assert 0.05 < rr["k0_0"].error / rr["k0_0"].value < 0.15  # mostly d_F's error bar: ln 9.3 * 0.04
    assert len({(c.friction, c.rolling) for c in Reproduction("gilabert-method1").cases}) == len(METHOD1_COLUMNS)
    assert [c.rolling for c in Reproduction("gilabert-method2", rolling="RR").cases] == [True]
    assert {c.rolling for c in Reproduction("gilabert-method1", rolling="noRR").cases} == {False}


def test_summary_gives_mean_and_standard_error():
    reproduction = Reproduction("gilabert-method1", samples=3)
    case = Case(False, 0.15, False)
    rows = [{"case": case.label, "seed": s, "phi": phi, "z": 3.0, "equilibrated": True, "wall_time_s": 1.0,
             "error": None} for s, phi in enumerate((0.80, 0.82, 0.84))]
    rows.append({"case": case.label, "seed": 3, "error": "DivergenceError: boom"})
    first = summarize(reproduction, rows)["cases"][0]
    phi = first["quantities"]["phi"]
    assert phi["mean"] == pytest.approx(0.82) and phi["n"] == 3
    assert phi["std"] == pytest.approx(0.02) and phi["sem"] == pytest.approx(0.02 / math.sqrt(3))
    assert phi["published"] == {"value": 0.8256, "error": 0.0005, "source": "Table II"}
    assert first["quantities"]["z"]["sem"] == 0.0 and first["completed"] == 3
    assert summarize(reproduction, rows)["failed"] == [{"case": case.label, "seed": 3, "error": "DivergenceError: boom"}]


def test_dask_gives_the_numbers_of_a_serial_run(capsys):
    # short stages (10 T0): out of equilibrium, but every number must still depend on the seed only
    reproduction = Reproduction("gilabert-method1", particles=30, samples=2, first_seed=5, max_time=10.0)
    calls = []
    result = run_reproduction(reproduction, workers=1, progress=lambda *call: calls.append(call))
    assert result["failed"] == [] and len(result["samples"]) == 16
    # the phases are seen to pass once a second, not only as samples finish (16 calls before)
    assert len(calls) > 16 and calls[-1] == (16, 16, "running")
    assert {phase for _, _, phase in calls} <= {"compiling the kernels", "starting the workers", "running"}
    for row in result["samples"][::5]:
        case = Case(row["cohesive"], row["friction"], row["rolling"])
        serial = gilabert_sample(reproduction, case, row["seed"])
        assert (serial["phi"], serial["z"], serial["sim_time"]) == (row["phi"], row["z"], row["sim_time"])
    assert [c["quantities"]["phi"]["n"] for c in result["cases"]] == [2] * 8
    _print_reproduce(result)
    printed = capsys.readouterr().out
    assert "cohesive, mu = 0.5, RR: 0/2 samples in equilibrium" in printed and "Table III" in printed


def test_a_sample_runs_on_the_threads_and_step_of_its_reproduction_and_the_cluster_leaves_them_the_cores(
        monkeypatch):
    from granlab.engine import studies
    from granlab.engine.protocols import prepare

    seen = []

    def method1(*args, **kwargs):
        seen.append((numba.get_num_threads(), kwargs["dt_safety"]))
        raise RuntimeError("measured enough")

    monkeypatch.setattr(prepare, "method1", method1)
    before = numba.get_num_threads()
    row = gilabert_sample(Reproduction("gilabert-method1", threads_per_sample=2, dt_safety=0.45),
                          Case(True, 0.15, False), 0)
    assert seen == [(2, 0.45)] and row["error"] == "RuntimeError: measured enough" and numba.get_num_threads() == before
    workers = []
    monkeypatch.setattr(studies, "run_tasks", lambda *args, **kwargs: workers.append(kwargs["workers"]) or [])
    run_reproduction(Reproduction("gilabert-method1", threads_per_sample=2))
    run_reproduction(Reproduction("gilabert-method1"))
    assert workers == [max(1, os.cpu_count() // 2), os.cpu_count()]


def test_method1_compresses_the_gas_and_cohesion_keeps_it_looser():
    reproduction = Reproduction("gilabert-method1", particles=40)
    dry = gilabert_sample(reproduction, Case(False, 0.15, False), 0)
    wet = gilabert_sample(reproduction, Case(True, 0.15, False), 0)
    assert dry["equilibrated"] and wet["equilibrated"]
    # Tables II and III: 0.8256 and 0.727 at N = 1400; a 40-disk sample is within a few percent
    assert PHI_I < wet["phi"] < dry["phi"]
    assert dry["phi"] == pytest.approx(0.8256, abs=0.03) and wet["phi"] == pytest.approx(0.727, abs=0.04)
    assert dry["rattlers"] > 0 and dry["z_star"] > dry["z"]


def test_method2_barely_moves_at_zero_pressure_then_collapses():
    row = gilabert_sample(Reproduction("gilabert-method2", particles=30), Case(True, 0.5, False), 0)
    assert row["error"] is None and row["balanced_0"] and row["equilibrated"]
    # Table IV: Phi at P* = 0 stays close to Phi_I; Table V: it rises under P* = 0.01, but stays loose
    assert row["phi_0"] == pytest.approx(PHI_I, abs=0.02)
    assert row["phi_0"] + 0.05 < row["phi"] < 0.7
    assert 2.0 <= row["z_0"] <= 4.0 and row["z"] >= 2.0


def test_bad_input_is_refused_clearly():
    with pytest.raises(ParameterError, match="table = 'gilabert-method3' is not allowed: one of gilabert-method1"):
        Reproduction("gilabert-method3")
    with pytest.raises(ParameterError, match="samples = 0 is not allowed: a whole number from 1 to 10000"):
        Reproduction("gilabert-method1", samples=0)
    with pytest.raises(ParameterError, match="max_time = -1.0 is not allowed"):
        Reproduction("gilabert-method2", max_time=-1.0)
    with pytest.raises(ParameterError, match="rolling_damping_ratio = -0.5 is not allowed: a number >= 0"):
        Reproduction("gilabert-method1", rolling_damping_ratio=-0.5)
    with pytest.raises(ParameterError, match="cell_mass_disks = 0 is not allowed: a whole number from 1 to 20000"):
        Reproduction("gilabert-method1", cell_mass_disks=0)
    with pytest.raises(ParameterError, match="cell_mass = 'per-area' is not allowed: one of mass, per-length"):
        Reproduction("gilabert-method1", cell_mass="per-area")
    with pytest.raises(ParameterError, match="rolling = 'yes' is not allowed: one of both, RR, noRR"):
        Reproduction("gilabert-method1", rolling="yes")
    cores = numba.config.NUMBA_NUM_THREADS
    with pytest.raises(ParameterError, match=f"threads_per_sample = {cores + 1} is not allowed: a whole number from 1 "
                                             f"to {cores}"):
        Reproduction("gilabert-method1", threads_per_sample=cores + 1)
    with pytest.raises(ParameterError, match=r"dt_safety = 1.5 is not allowed: a fraction of the stability bound in "
                                             r"\(0, 1\]"):
        Reproduction("gilabert-method2", dt_safety=1.5)
    process = granlab("reproduce", "gilabert-method1", "--cell-mass", "per-area")
    assert process.returncode == 2 and "invalid choice: 'per-area' (choose from 'mass', 'per-length')" in process.stderr
    process = granlab("reproduce", "gilabert-method1", "--samples", "0")
    assert process.returncode == 2 and "0 is not allowed: a whole number > 0" in process.stderr
    process = granlab("reproduce", "gilabert-table9")
    assert process.returncode == 2 and "invalid choice: 'gilabert-table9'" in process.stderr
    process = granlab("reproduce", "gilabert-method1", "--max-time", "0")
    assert process.returncode == 2 and "max_time = 0.0 is not allowed: a duration > 0 and at most 100000 T0" in process.stderr
    process = granlab("prepare", "--method", "1", "--rolling", "--rolling-damping", "-1")
    assert process.returncode == 2 and "rolling_damping_ratio = -1.0 is not allowed: a number >= 0" in process.stderr


def test_a_failed_fit_keeps_the_hole_radius():
    from granlab.engine.reproduce import _fractal

    # a square lattice of overlapping disks with one disk in nine missing: no fractal range, and
    # holes no wider than a missing disk with its four interstices
    side = 12
    x, y = np.meshgrid(np.arange(side) + 0.5, np.arange(side) + 0.5)
    row, column = np.meshgrid(np.arange(side), np.arange(side), indexing="ij")
    keep = ~((row % 3 == 1) & (column % 3 == 1)).ravel()
    positions = np.column_stack([x.ravel(), y.ravel()])[keep]
    snapshot = SimpleNamespace(positions=positions, radii=np.full(len(positions), 0.52),
                               box_lengths=np.array([side, side], float))
    values = _fractal(snapshot, "")
    assert values["d_F"] is None and "did not converge" in values["fractal_error"]
    assert 0.3 < values["hole_radius_w"] < 1.0


def test_intensities_of_boxes_of_different_sizes_are_averaged_on_common_bins():
    from granlab.engine.analysis.fractal import average_intensity, fit_structure, structure_model

    phi, d_F, xi, ell, constant = 0.3, 1.6, 8.0, 0.5, 2e-3
    # two samples' bins: shells 2 pi / L wide, boxes 10 % apart, the second with 10 % more intensity
    small, large = (np.geomspace(2.0 * math.pi / length, 6.0, 40) for length in (60.0, 66.0))
    k, mean = average_intensity([small, large], [structure_model(small, phi, d_F, xi, ell, constant),
                                                 1.1 * structure_model(large, phi, d_F, xi, ell, constant)])
    assert k[0] == small[0] and k[-1] == small[-1] and k.size == small.size  # the smaller box's bins
    assert mean == pytest.approx(1.05 * structure_model(k, phi, d_F, xi, ell, constant), rel=2e-3)
    assert fit_structure(k, mean, phi, k_range=(0.0, 6.0)).d_F == pytest.approx(d_F, abs=0.01)
    with pytest.raises(ParameterError, match="samples whose I\\(k\\) overlap in k"):
        average_intensity([np.geomspace(0.1, 1.0, 5), np.geomspace(2.0, 9.0, 5)], [np.ones(5), np.ones(5)])
    with pytest.raises(ParameterError, match="at least 2 such bins per sample"):
        average_intensity([np.geomspace(0.1, 1.0, 5)], [np.zeros(5)])


def test_a_series_of_two_box_sizes_reaches_below_the_smaller_box_with_the_larger_alone():
    from granlab.engine.analysis.fractal import average_intensity, average_series_intensity, structure_model

    phi, d_F, xi, ell, constant = 0.36, 1.6, 8.0, 0.5, 2e-3
    small, large = (np.geomspace(2.0 * math.pi / length, 6.0, 40) for length in (42.0, 84.0))

    def model(k):
        return structure_model(k, phi, d_F, xi, ell, constant)

    # 4 samples of the small box with the model's intensity, 2 of the large one with 1.3 times it
    k, mean = average_series_intensity([([small] * 4, [model(small)] * 4), ([large] * 2, [1.3 * model(large)] * 2)])
    below = k < small[0]
    assert k[0] == large[0] and np.all(np.isin(k[below], large)) and np.all(np.isin(k[~below], small))
    assert mean[below] == pytest.approx(1.3 * model(k[below]), rel=1e-9)
    assert mean[~below] == pytest.approx(1.1 * model(k[~below]), rel=2e-3)  # (4 + 2 * 1.3) / 6
    one = average_intensity([small, small * 1.02], [model(small), model(small * 1.02)])
    assert average_series_intensity([([small, small * 1.02], [model(small), model(small * 1.02)])])[1] == \
        pytest.approx(one[1], rel=1e-12)


def _series_folder(folder, particles, samples, length, **settings):
    """A method-2 folder of ``samples`` per case whose I(k) is Eq. 28's in boxes ``length`` wide."""
    from granlab.engine.analysis.fractal import structure_model
    from granlab.engine.reproduce import _write_json

    reproduction = Reproduction("gilabert-method2", particles=particles, samples=samples, **settings)
    start_folder(folder, reproduction)
    k = np.geomspace(2.0 * math.pi / length, 2.0 * math.pi, 30)
    intensity = structure_model(k, PHI_I, 1.6, 3.0, 0.4, 0.0).tolist()
    for case in reproduction.cases:
        for seed in range(samples):
            row = {"case": case.label, **asdict(case), "seed": seed, "error": None, "equilibrated": True,
                   "balanced_0": True, "wall_time_s": 1.0, "k_0": k.tolist(), "intensity_0": intensity,
                   "grid_phi_0": PHI_I, "k": k.tolist(), "intensity": intensity, "grid_phi": PHI_I,
                   **{q: 1.0 for q in ("phi_0", "z_0", "d_F_0", "xi_0", "phi", "z", "d_F", "xi", "hole_radius_w")}}
            _write_json(folder / "samples" / f"{sample_key(case, seed)}.json", row)
    return folder


def test_folders_of_two_sizes_are_summarised_as_one_series(tmp_path):
    small = _series_folder(tmp_path / "1400", 1400, 4, 42.0)
    large = _series_folder(tmp_path / "5600", 5600, 2, 84.0, cell_mass_disks=5600)
    process = granlab("reproduce", "gilabert-method2", "--series", str(small), str(large), "--json")
    assert process.returncode == 0, process.stderr
    result = json.loads(process.stdout)
    assert [(s["particles"], s["samples"]) for s in result["series"]] == [(1400, 8), (5600, 4)]
    for case in result["cases"]:
        assert case["completed"] == 6
        fits = case["averaged_fit"]
        for fit in (fits["at_zero_pressure"], fits["under_pressure"]):
            assert fit["samples"] == 6 and fit["d_F"] == pytest.approx(1.6, abs=1e-3)
            assert fit["xi"] == pytest.approx(3.0, rel=1e-3)
        # samples measured before the Hann window was: its fits say so, the rest stands
        assert fits["under_pressure, Hann window"] == {"samples": 0, "d_F": None, "d_F_error": None, "xi": None,
                                                       "xi_error": None, "k0": None, "error": "no sample's I(k)"}
    printed = granlab("reproduce", "gilabert-method2", "--series", str(small), str(large)).stdout
    assert f"{small} (8 samples of 1400 disks in all cases) + {large} (4 samples of 5600 disks" in printed
    assert "d_F_0 <I(k)>        1.600" in printed
    assert "k0_0 <I(k)>" in printed and "k0 <I(k)>" in printed

    other = _series_folder(tmp_path / "longer", 1400, 1, 42.0, max_time=1000.0)
    process = granlab("reproduce", "gilabert-method2", "--series", str(small), str(other))
    assert process.returncode == 2 and f"{other} differs from {small} in max_time: a series may differ only in " \
        "particles, samples, first_seed, cell_mass_disks" in process.stderr
    process = granlab("reproduce", "gilabert-method1", "--series", str(small))
    assert process.returncode == 2 and "holds gilabert-method2, not gilabert-method1" in process.stderr
    process = granlab("reproduce", "gilabert-method2", "--series", str(small), "--samples", "3", "--workers", "1")
    assert process.returncode == 2 and "runs nothing: drop --samples, --workers" in process.stderr
    process = granlab("reproduce", "gilabert-method2", "--series", str(small), str(tmp_path / "1400" / "."))
    assert process.returncode == 2 and "a folder is named twice" in process.stderr
    empty = start_folder(tmp_path / "empty", Reproduction("gilabert-method2"))
    process = granlab("reproduce", "gilabert-method2", "--series", str(empty))
    assert process.returncode == 2 and f"no finished sample in {empty}" in process.stderr


def test_a_reproduction_interrupted_goes_on_from_its_folder(tmp_path):
    folder = tmp_path / "method2"
    command = [sys.executable, "-m", "granlab.app.commands", "reproduce", "gilabert-method2", "--particles", "30",
               "--samples", "2", "--max-time", "40", "--workers", "1", "--json"]
    # Ctrl-C's default action, whatever this process inherited: a shell's background job ignores SIGINT
    process = subprocess.Popen([*command, "--out", str(folder)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True, start_new_session=True,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    samples = folder / "samples"
    deadline = time.monotonic() + 240
    while not list(samples.glob("*.json")) and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    os.killpg(process.pid, signal.SIGINT)  # Ctrl-C, to the process and its Dask workers, after a first sample
    _, stderr = process.communicate(timeout=60)
    before = {path.name: path.read_text() for path in samples.glob("*.json")}
    assert 1 <= len(before) < 4 and not list(samples.glob("*.partial"))
    assert process.returncode == 130 and "Traceback" not in stderr
    assert f"interrupted: {len(before)} of 4 samples are in {folder}; go on with granlab reproduce gilabert-method2 " \
           f"--resume {folder}" in stderr

    resumed = subprocess.run([*command[:5], "--resume", str(folder), "--json"], capture_output=True, text=True,
                             timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    result = json.loads(resumed.stdout)
    assert result["resumed"] == len(before) and result["failed"] == [] and len(result["samples"]) == 4
    assert result["settings"]["particles"] == 30 and result["settings"]["max_time"] == 40.0
    # a sample written before the interruption is the one a run from scratch would give, and is left as it was
    assert {path.name: path.read_text() for path in samples.glob("*.json") if path.name in before} == before
    row = json.loads(next(iter(before.values())))
    reproduction = Reproduction("gilabert-method2", particles=30, samples=2, max_time=40.0)
    serial = gilabert_sample(reproduction, Case(row["cohesive"], row["friction"], row["rolling"]), row["seed"])
    assert (serial["phi"], serial["z"], serial["sim_time"]) == (row["phi"], row["z"], row["sim_time"])
    # each sample measured under both conventions: 4- and 8-connected holes, periodic and windowed I(k)
    assert {"hole_radius_w", "hole_radius_w8", "intensity_hann", "intensity_hann_0"} <= set(row)
    for case in result["cases"]:
        assert set(case["averaged_fit"]) == {"at_zero_pressure", "under_pressure", "at_zero_pressure, Hann window",
                                             "under_pressure, Hann window"}
        assert all(fit["samples"] == 2 for fit in case["averaged_fit"].values())

    process = granlab("reproduce", "gilabert-method2", "--resume", str(folder), "--samples", "3")
    assert process.returncode == 2 and "continues with the settings it was started with: drop --samples" in \
        process.stderr
    process = granlab("reproduce", "gilabert-method1", "--resume", str(folder))
    assert process.returncode == 2 and "holds gilabert-method2, not gilabert-method1" in process.stderr
    process = granlab("reproduce", "gilabert-method2", "--out", str(folder))
    assert process.returncode == 2 and "holds a reproduction already: continue it with --resume" in process.stderr
    process = granlab("reproduce", "gilabert-method2", "--resume", str(tmp_path / "none"))
    assert process.returncode == 2 and "holds no reproduction (settings.json is missing)" in process.stderr


def test_a_folder_from_before_a_setting_goes_on_with_the_value_it_was_made_with(tmp_path):
    # the cell mass readings and the longer step (27 Nov 2026) came after the first folders
    folder = start_folder(tmp_path / "new", Reproduction("gilabert-method1", particles=30))
    assert resume_folder(folder).cell_mass == "mass" and resume_folder(folder).dt_safety == 0.6
    settings = json.loads((folder / "settings.json").read_text())
    del settings["cell_mass"]
    (folder / "settings.json").write_text(json.dumps(settings))
    assert resume_folder(folder) == Reproduction("gilabert-method1", particles=30, cell_mass="per-length")
    del settings["dt_safety"]
    (folder / "settings.json").write_text(json.dumps(settings))
    assert resume_folder(folder) == Reproduction("gilabert-method1", particles=30, cell_mass="per-length",
                                                 dt_safety=0.3)
