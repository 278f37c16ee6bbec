"""The CUDA backend (engine/cuda) on numba's simulator: every law on the device beside the CPU engine,
the command line's --backend, and a machine without a GPU saying so."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from granlab.engine.errors import ParameterError
from granlab.engine.kernels.integrate import CODE_LOST_CONTACT, CODE_OK, CODE_OVERFLOW
from granlab.engine.params import TANGENTIAL

from .conftest import periodic_gas

HERE = Path(__file__).parent
ROOT = HERE.parent
SIMULATOR = {**os.environ, "NUMBA_ENABLE_CUDASIM": "1"}


def test_every_law_on_the_device_ends_where_the_cpu_engine_does():
    """A box of 16 disks pressed by loaded walls (overlap-area normal law, friction, rolling resistance)
    and 24 cohesive disks in a periodic cell under stress control with rolling resistance, each with the
    four tangential models, stepped by one block 32 steps a launch, two also in four launches a step (as a
    larger table is); three boxes side by side in one batch being compressed (80 steps from the 50th, rows
    rebuilt seven times), a block a box (each rebuilding its box's rows), then with segments too small (run again as one
    system), then as one system in one block and in four launches a step: a whole system's table rebuilt on the
    device as often as the CPU engine rebuilds its own, and at the end the state (disks, walls, cell), the
    energy ledger and the interacting contacts' springs and forces differ from the CPU
    engine's by at most 1e-12 relative. A run of six checkpoint blocks keeps the state on the device from one
    to the next (under a quarter of the bytes six runs of a block move), and one diverging in its fourth block is
    put back where that block started, as on the CPU."""
    done = subprocess.run([sys.executable, str(HERE / "cuda_cases.py")], env=SIMULATOR, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    lines = [json.loads(line) for line in done.stdout.splitlines()]
    cases = [line for line in lines if "case" in line]
    resident = {line["resident"]: line for line in lines if "resident" in line}
    one_block = {(name, model, "one a batch") for name in ("loaded_box", "cohesive_cell") for model in TANGENTIAL}
    batch = {("batched_boxes", "lammps", launches) for launches in (
        "a block a sample", "a block a sample, then one system", "one a batch", "four a step")}
    assert {(case["case"], case["model"], case["launches"]) for case in cases} == one_block | batch | {
        ("loaded_box", "angle", "four a step"), ("cohesive_cell", "alpha", "four a step")}
    for case in cases:
        assert case["same_contacts"] and case["contacts"] >= 5, case
        cpu_rebuilds, device_rebuilds = case["rebuilds"]
        if case["launches"] == "a block a sample":  # each box rebuilt its own rows, when it needed to
            assert cpu_rebuilds >= 2 and device_rebuilds > cpu_rebuilds, case
        else:  # the whole table rebuilt on the device when the CPU engine rebuilt its own
            assert device_rebuilds == cpu_rebuilds, case
        assert case["worst"] <= 1e-12, (case["case"], case["model"], case["differences"])
    # a run of six checkpoint blocks: the state stays on the device between them
    blocks = resident["six blocks"]
    assert blocks["worst"] <= 1e-12 and blocks["same_contacts"], blocks
    assert blocks["bytes_six_runs"] > 4 * blocks["bytes_one_run"], blocks
    cpu, device = resident["a divergence in the fourth block"]["ends"]
    assert cpu["failed_step"] == device["failed_step"] == 36 and cpu["step"] == device["step"] == 30
    assert cpu["contacts"] == device["contacts"]
    for key in ("position", "velocity"):
        assert np.allclose(device[key], cpu[key], rtol=1e-12, atol=1e-15), key


def test_the_device_rebuilds_the_cpu_engines_contact_table_row_for_row():
    """A cohesive gas periodic along both axes and a sheared layer periodic along x between two walls, each
    translated by a third of the cell so that a third of the disks are past its side: the table the device
    rebuilds is the CPU engine's row for row (pairs, images, histories carried, wall anchors moved with a
    wrapped disk), the disks wrapped alike; a table too small asks for the same rows; a disk whose old rows no
    longer fit it loses the same touching contacts."""
    done = subprocess.run([sys.executable, str(HERE / "cuda_rebuild.py")], env=SIMULATOR, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    cases = {case["case"]: case for case in map(json.loads, done.stdout.splitlines())}
    assert len(cases) == 6
    for name, case in cases.items():
        assert case["table_equal"] and case["disks_equal"] and case["workspace_equal"], case
        cpu_code, device_code = case["codes"]
        assert cpu_code == device_code and case["wrapped"] >= 10, case
        if "10 rows" in name:
            assert cpu_code == CODE_OVERFLOW and case["needed"][0] == case["needed"][1] > 10, case
        elif "moved" in name:
            assert cpu_code == CODE_LOST_CONTACT and case["lost"][0] == case["lost"][1] >= 1, case
        else:
            assert cpu_code == CODE_OK and case["touching"] >= 5, case
    assert cases["sheared_layer"]["touching_walls_wrapped"] >= 1


def test_bench_check_compares_the_device_with_the_cpu_and_says_so():
    done = subprocess.run([sys.executable, "-m", "granlab.app.commands", "bench", "--backend", "cuda", "--check",
                           "20", "--side", "6", "--model", "lammps"], env=SIMULATOR, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "after 20 steps on the device and on the CPU" in done.stdout and "agree" in done.stdout


def test_granlab_run_takes_the_cuda_backend_and_ends_where_the_cpu_does(tmp_path):
    """The block of quasi-rigidity Fig. 2 for 0.3 time units (105 steps): a run file written from the device's
    state, the same disk and energies as on the CPU."""
    scene = tmp_path / "block.toml"
    scene.write_text((ROOT / "engine" / "io" / "scenes" / "block.toml").read_text().replace("duration = 20.0",
                                                                                           "duration = 0.3"))
    results = {}
    for backend in ("cpu", "cuda"):
        done = subprocess.run([sys.executable, "-m", "granlab.app.commands", "run", str(scene), "--backend", backend,
                               "--out", str(tmp_path / f"{backend}.h5"), "--json"], env=SIMULATOR,
                              capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr[-2000:]
        results[backend] = json.loads(done.stdout)
    cpu, device = results["cpu"], results["cuda"]
    assert device["steps"] == cpu["steps"] == 105
    for key in ("positions", "velocities", "omegas"):
        assert np.allclose(device[key], cpu[key], rtol=1e-12, atol=1e-15), key
    assert device["energy"]["balance"] == pytest.approx(cpu["energy"]["balance"], rel=1e-12)
    assert (tmp_path / "cuda.h5").stat().st_size > 0


def test_a_ratchet_study_cycles_on_the_device_as_one_batch():
    """``granlab study ratchet --backend cuda --batch``: the boxes prepared on the CPU, their cycles on the device
    side by side (2 samples of 4 disks, 3 short cycles), both completed and the study saying where it ran."""
    done = subprocess.run([sys.executable, "-m", "granlab.app.commands", "study", "ratchet", "--particles", "4",
                           "--samples", "2", "--cycles", "3", "--period", "0.5", "--reference-cycle", "0",
                           "--backend", "cuda", "--batch", "--json"], env=SIMULATOR, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(done.stdout)
    assert result["settings"]["backend"] == "cuda" and result["scheduler"] == "one batch (cuda)"
    assert result["models"]["cundall-strack"]["completed"] == 2 and result["failed"] == []


def test_without_a_gpu_the_cuda_backend_is_refused_in_one_line_naming_what_runs():
    if os.environ.get("NUMBA_ENABLE_CUDASIM") == "1":
        pytest.skip("the simulator stands in for a GPU")
    sim = periodic_gas(count=20)
    with pytest.raises(ParameterError, match=r"backend = 'cuda' is not allowed: cpu \(numba finds no CUDA GPU"):
        sim.use_backend("cuda")
    assert sim.backend == "cpu"
    with pytest.raises(ParameterError, match="cpu or cuda"):
        sim.use_backend("opencl")
    for command in (["run"], ["prepare", "--method", "compress"], ["study", "ratchet"]):
        done = subprocess.run([sys.executable, "-m", "granlab.app.commands", *command, "--backend", "cuda"],
                              capture_output=True, text=True, timeout=300)
        assert done.returncode == 2 and done.stderr.count("\n") == 1, (command, done.stderr)
        assert "backend = 'cuda' is not allowed" in done.stderr and "no CUDA GPU" in done.stderr
