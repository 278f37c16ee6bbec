"""The ratchet study on a real local Dask cluster, its failures, and its bad input."""

import json
import subprocess
import sys

import numpy as np
import pytest

from granlab.engine import ParameterError
from granlab.engine.io import h5md
from granlab.engine.params import TANGENTIAL
from granlab.engine.studies import RatchetStudy, ratchet_sample, summarize


def granlab(*args):
    return subprocess.run([sys.executable, "-m", "granlab.app.commands", *args], capture_output=True, text=True,
                          timeout=900)


def test_tiny_study_runs_on_a_local_dask_cluster(tmp_path):
    process = granlab("study", "ratchet", "--particles", "9", "--samples", "2", "--cycles", "12", "--period", "2",
                      "--reference-cycle", "2", "--model", "all", "--out", str(tmp_path), "--json")
    assert process.returncode == 0, process.stderr
    summary = json.loads(process.stdout)
    assert summary["scheduler"] == "local"
    assert set(summary["models"]) == set(TANGENTIAL)
    for model, data in summary["models"].items():
        assert data["completed"] == 2 and 0.0 <= data["fraction_ratcheting"] <= 1.0
        assert [s["seed"] for s in data["samples"]] == [0, 1]
        for sample in data["samples"]:
            assert isinstance(sample["dgamma"], float) and isinstance(sample["ratcheting"], bool)
            info = h5md.summary(sample["run_file"])
            assert info["cycles"] == 13 and info["protocol"]["model"] == model
        paper = data["rules"][0]
        assert paper["rule"] == "cycles 2-12, RMS < |Δγ|" and len(data["rules"]) == 7
        assert (paper["ratcheting"], paper["samples"]) == (data["ratcheting"], 2)
        low, high = paper["ratcheting_interval"]
        assert 0.0 <= low <= paper["ratcheting"] / 2 <= high <= 1.0
    assert summary["failed"] == []


def test_a_zero_mean_study_cycles_about_p0_and_says_so_in_its_run_files(tmp_path):
    process = granlab("study", "ratchet", "--particles", "9", "--samples", "1", "--cycles", "4", "--period", "2",
                      "--reference-cycle", "0", "--amplitude", "0.15", "--zero-mean", "--out", str(tmp_path), "--json")
    assert process.returncode == 0, process.stderr
    sample = json.loads(process.stdout)["models"]["cundall-strack"]["samples"][0]
    assert h5md.summary(sample["run_file"])["protocol"]["zero_mean"] in (True, 1)
    refused = granlab("study", "ratchet", "--amplitude", "1.5", "--zero-mean")
    assert refused.returncode != 0 and "amplitude = 1.5 is not allowed: below the pressure P0 = 1" in refused.stderr


def test_an_amplitude_sweep_cycles_the_same_samples_at_each_amplitude(tmp_path):
    process = granlab("study", "ratchet", "--particles", "9", "--samples", "2", "--cycles", "8", "--period", "2",
                      "--reference-cycle", "2", "--amplitude", "0.1", "0.4", "--out", str(tmp_path), "--json")
    assert process.returncode == 0, process.stderr
    sweep = json.loads(process.stdout)
    assert sweep["amplitudes"] == [0.1, 0.4] and [r["settings"]["amplitude"] for r in sweep["results"]] == [0.1, 0.4]
    small, large = (r["models"]["cundall-strack"] for r in sweep["results"])
    assert small["completed"] == large["completed"] == 2
    for data in (small, large):
        assert 0 <= data["ratcheting_without_outliers"] <= 2
        for sample in data["samples"]:
            assert isinstance(sample["ratcheting_without_outliers"], bool)
            assert sample["dgamma_without_outliers"] == sample["dgamma"] or sample["outlier_cycles"]
    # the same packing each time (seeds 0, 1), each amplitude in its own folder
    assert sorted(p.name for p in (tmp_path / "amplitude-0.1").iterdir()) == [
        "ratchet_cundall-strack_seed0.h5", "ratchet_cundall-strack_seed1.h5"]
    first = [h5md.summary(tmp_path / f"amplitude-{a}" / "ratchet_cundall-strack_seed0.h5") for a in ("0.1", "0.4")]
    assert first[0]["protocol"]["amplitude"] == 0.1 and first[1]["protocol"]["amplitude"] == 0.4
    printed = granlab("study", "ratchet", "--particles", "9", "--samples", "1", "--cycles", "4", "--period", "2",
                      "--reference-cycle", "0", "--amplitude", "0.1", "0.2").stdout
    assert "amplitude  model            ratcheting (95 %, %)  negative (95 %, %) without jumps" in printed
    assert "      0.2  cundall-strack" in printed


def test_a_failing_sample_is_reported_and_does_not_stop_the_others():
    bad = RatchetStudy(particles=4, samples=1, cycles=5, reference_cycle=0, gravity=1e3)
    results = ratchet_sample(bad, 3, None)
    assert results[0]["error"].startswith("DivergenceError: run diverged")
    good = ratchet_sample(RatchetStudy(particles=4, samples=1, cycles=5, reference_cycle=0, period=1.0), 4, None)
    summary = summarize(RatchetStudy(particles=4, samples=2, cycles=5, reference_cycle=0), results + good)
    data = summary["models"]["cundall-strack"]
    assert data["completed"] == 1
    assert summary["failed"] == [{"seed": 3, "model": "cundall-strack", "error": results[0]["error"]}]
    assert [s["seed"] for s in data["samples"]] == [3, 4]


def test_bad_study_input_is_refused_clearly():
    with pytest.raises(ParameterError, match="model = 'hooke'"):
        RatchetStudy(models=("hooke",))
    with pytest.raises(ParameterError, match="reference_cycle = 30 is not allowed: a cycle from 0 to cycles - 3 = 7"):
        RatchetStudy(cycles=10, reference_cycle=30)
    assert [RatchetStudy(cycles=c).reference_cycle for c in (3, 4, 10, 100, 200)] == [0, 1, 3, 30, 60]
    with pytest.raises(ParameterError, match="cycles = 2 is not allowed: at least 3"):
        RatchetStudy(cycles=2)
    with pytest.raises(ParameterError, match=r"dt_factor = 0.25 is not allowed: at most 0.248"):
        RatchetStudy(dt_factor=0.25)
    refusals = {("--cycles", "0"): "0 is not allowed: a whole number > 0",
                ("--phase", "nan"): "phase = nan is not allowed", ("--phase", "inf"): "phase = inf is not allowed",
                ("--dt-factor", "5"): "dt_factor = 5.0 is not allowed: at most 0.248"}
    for args, message in refusals.items():
        process = granlab("study", "ratchet", *args)
        assert process.returncode == 2 and message in process.stderr and process.stderr.count("\n") == 1, args
    process = granlab("study", "ratchet", "--model", "hooke")
    assert process.returncode == 2 and "invalid choice: 'hooke'" in process.stderr
    process = granlab("study", "ratchet", "--samples", "1", "--cycles", "5", "--reference-cycle", "0",
                      "--scheduler", "tcp://127.0.0.1:9")
    assert process.returncode == 2 and "cannot reach the Dask scheduler at 'tcp://127.0.0.1:9'" in process.stderr


def test_a_study_whose_samples_all_fail_exits_with_an_error():
    process = granlab("study", "ratchet", "--particles", "4", "--samples", "2", "--cycles", "3", "--period", "1",
                      "--gravity", "1000")
    assert process.returncode == 2
    assert process.stderr.splitlines()[-1].startswith("granlab study: error: every sample failed (2 of 2); seed 0 (cundall-strack): "
                                     "DivergenceError: run diverged"), process.stderr


def test_watched_contacts_trace_paths_inside_the_coulomb_cone(tmp_path):
    # ratcheting Figs. 3-4: every sample of every watched contact lies in |F_t| <= mu N^e
    study = RatchetStudy(particles=16, samples=1, cycles=6, reference_cycle=0, watch_samples=25)
    result = ratchet_sample(study, 1, str(tmp_path))[0]
    import h5py
    with h5py.File(result["run_file"], "r", libver="latest", swmr=True) as f:
        paths = f["observables/contact_paths"]
        fn, ft, status = paths["elastic_normal_force"][()], paths["tangential_force"][()], paths["status"][()]
        assert paths["pair"].shape[0] == fn.shape[1] > 20
        assert fn.shape[0] == 6 * 25
    touching = np.isin(status, (1, 2, 3))
    assert touching.mean() > 0.8  # a few weak contacts open as the load swings (0.86 of the samples touch)
    assert np.all(np.abs(ft[touching]) <= 0.2 * fn[touching] * (1 + 1e-12))
    sliding = np.isin(status, (2, 3))
    assert sliding.any()
    assert np.all(np.sign(ft[status == 2]) > 0) and np.all(np.sign(ft[status == 3]) < 0)
    np.testing.assert_allclose(np.abs(ft[sliding]), 0.2 * fn[sliding], rtol=1e-12)
