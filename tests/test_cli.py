"""The granlab command: JSON outputs and clear errors."""

import json
import re
import os
import subprocess
import sys

import numpy as np
import pytest

from granlab.engine.params import TANGENTIAL_MODELS


def granlab(*args, check=True):
    process = subprocess.run([sys.executable, "-m", "granlab.app.commands", *args], capture_output=True, text=True,
                             timeout=600)
    if check and process.returncode != 0:
        raise AssertionError(process.stderr)
    return process


PAIR = """
[simulation]
duration = 3.0
dt = 1e-4
[contact]
normal_stiffness = 1e4
tangential_stiffness = 1e4
[[particles.disk]]
x = 0.0
y = 0.0
r = 0.5
vx = 1.0
[[particles.disk]]
x = 2.0
y = 0.0
r = 0.5
mass = 3.0
"""


def test_run_json_reports_final_state_in_input_order_and_energy(tmp_path):
    scene = tmp_path / "pair.toml"
    scene.write_text(PAIR)
    result = json.loads(granlab("run", str(scene), "--json").stdout)
    positions = np.array(result["positions"])
    assert positions.shape == (2, 2)
    assert len(result["velocities"]) == 2 and len(result["omegas"]) == 2
    # an elastic collision of masses pi/4 and 3: momentum and energy are conserved
    m = [np.pi * 0.25, 3.0]
    v = np.array(result["velocities"])[:, 0]
    assert m[0] * v[0] + m[1] * v[1] == pytest.approx(m[0] * 1.0, rel=1e-9)
    assert result["energy"]["kinetic"] == pytest.approx(0.5 * m[0], rel=1e-4)
    assert v[1] == pytest.approx(2 * m[0] / (m[0] + m[1]), rel=1e-4)
    assert result["steps"] == 30000


def test_run_builtin_scene_summary():
    process = granlab("run", "elastic-gas")
    assert "200 disks" in process.stdout and "energy balance" in process.stdout


def test_experiment_json_keys():
    collision = json.loads(granlab("experiment", "collision", "--zeta", "0.4", "--json").stdout)
    assert {"restitution", "restitution_predicted"} <= set(collision)
    closed = json.loads(granlab("experiment", "closed-path", "--model", "angle", "--json").stdout)
    assert {"delta_Dt", "predicted_delta_Dt", "enclosed_area"} <= set(closed)
    assert closed["delta_Dt"] == 0.0
    every = json.loads(granlab("experiment", "closed-path", "--model", "all", "--json").stdout)
    assert [one["model"] for one in every["models"]] == list(TANGENTIAL_MODELS)
    block = json.loads(granlab("experiment", "block", "--mu", "0.3", "--json").stdout)
    assert {"max_Ft_over_muFn", "friction_work_positive"} <= set(block)
    assert block["friction_work_positive"] is False


def test_bench_profile_splits_a_particle_step_between_the_passes():
    result = json.loads(granlab("bench", "--profile", "--side", "10", "--steps", "100", "--json").stdout)
    assert result["rows_per_disk"] == pytest.approx(2.0)
    assert result["contact_pass_ns_per_row"] > 0 and result["particle_pass_ns_per_disk"] > 0
    assert result["contact_pass_ns_per_disk"] == pytest.approx(2.0 * result["contact_pass_ns_per_row"])


def test_bench_json_keys_on_a_small_system():
    result = json.loads(granlab("bench", "--side", "10", "--steps", "50", "--json").stdout)
    assert result["particle_steps_per_s_1thread"] > 0 and result["particle_steps_per_s_all"] > 0
    assert result["contacts_per_disk"] == pytest.approx(2.0)


def test_bench_batch_times_a_study_side_by_side_and_one_by_one():
    """``bench --batch``: both ways timed three times each, the per-sample ratio from their medians."""
    result = json.loads(granlab("bench", "--batch", "3", "--json").stdout)
    assert result["samples"] == 3 and result["alone_samples"] == 3 and len(result["batch_times_s"]) == 3
    assert result["speedup_per_sample"] == pytest.approx(result["alone_s"] / result["batch_s"])


def test_study_batch_prints_where_it_ran_and_refuses_run_files():
    text = granlab("study", "ratchet", "--particles", "6", "--samples", "2", "--cycles", "3", "--period", "0.5",
                   "--reference-cycle", "0", "--batch").stdout
    assert "2 samples of 6 disks, 3 cycles" in text and "on one batch (cpu)" in text
    refused = granlab("study", "ratchet", "--samples", "2", "--batch", "--out", "runs", check=False)
    assert refused.returncode == 2 and "--batch writes no run files" in refused.stderr


def test_errors_exit_with_status_2_and_name_the_problem(tmp_path):
    missing = granlab("run", str(tmp_path / "none.toml"), check=False)
    assert missing.returncode == 2 and "does not exist" in missing.stderr
    broken = tmp_path / "broken.toml"
    broken.write_text("[simulation]\nsteps = 1\n[contact]\ndamping_ratio = 1.5\n[[particles.disk]]\nx=0\ny=0\nr=1\n")
    process = granlab("run", str(broken), check=False)
    assert process.returncode == 2
    assert "damping_ratio = 1.5 is not allowed: a fraction of critical damping in [0, 1)" in process.stderr
    bad_zeta = granlab("experiment", "collision", "--zeta", "1.2", check=False)
    assert bad_zeta.returncode == 2 and "damping_ratio = 1.2" in bad_zeta.stderr
    bad_mu = granlab("experiment", "block", "--mu", "inf", check=False)
    assert bad_mu.returncode == 2 and "mu = inf is not allowed" in bad_mu.stderr



def test_an_output_never_writes_over_an_input_or_an_existing_file_unless_forced(tmp_path):
    scene = tmp_path / "pair.toml"
    scene.write_text(PAIR)
    out = tmp_path / "run.h5"
    granlab("run", str(scene), "--out", str(out))
    kept = out.read_bytes()
    hard_link = tmp_path / "same.h5"
    os.link(out, hard_link)
    refusals = {
        ("run", "--resume", str(out), "--out", str(hard_link), "--force"):
            f"--out {str(hard_link)!r} is the input file: writing it would lose what it holds",
        ("run", str(scene), "--out", str(out)):
            f"--out {str(out)!r} exists: give --force to write over it, or another name "
            f"({str(tmp_path / 'run-2.h5')!r} is free)",
        ("run", "--resume", str(out), "--out", str(out), "--force"):
            f"--out {str(out)!r} is the input file: writing it would lose what it holds; give another name "
            f"({str(tmp_path / 'run-2.h5')!r} is free)",
        ("prepare", "--method", "compress", "--out", str(out)): f"--out {str(out)!r} exists",
        ("run", str(scene), "--out", str(tmp_path)): f"--out {str(tmp_path)!r} is a folder: give a file name inside it",
        ("run", str(scene), "--out", "/proc/granlab.h5"): "--out '/proc/granlab.h5' cannot be written: no file can "
                                                          "be made in '/proc'",
        ("study", "ratchet", "--samples", "1", "--out", str(out)): f"--out {str(out)!r} is a file, not a folder",
    }
    for args, message in refusals.items():
        process = granlab(*args, check=False)
        assert process.returncode == 2 and process.stderr.count("\n") == 1, (args, process.stderr)
        assert message in process.stderr, (args, process.stderr)
    assert out.read_bytes() == kept
    granlab("run", "--resume", str(out))
    again = granlab("run", "--resume", str(out), check=False)
    assert again.returncode == 2 and f"({str(tmp_path / 'run-resumed-2.h5')!r} is free)" in again.stderr
    scene.write_text(PAIR.replace("duration = 3.0", "duration = 3.5"))
    granlab("run", str(scene), "--out", str(out), "--force")
    assert json.loads(granlab("info", str(out), "--json").stdout)["last_time"] == pytest.approx(3.5)


@pytest.mark.parametrize("args, message", [
    (["study", "ratchet", "--samples", "1000000000"], "samples = 1000000000 is not allowed: a whole number from 1 to 10000"),
    (["study", "ratchet", "--cycles", "1000000000000"], "cycles = 1000000000000 is not allowed: a whole number from 1 to"),
    (["study", "ratchet", "--period", "1e-300"], "period = 1e-300 is not allowed: from 0.1 to 10000 τ"),
    (["reproduce", "gilabert-method1", "--samples", "100000000"], "samples = 100000000 is not allowed: a whole number from 1 to"),
    (["reproduce", "gilabert-method1", "--workers", "100000"], "--workers = 100000 is not allowed: from 1 to 256"),
    (["reproduce", "gilabert-method1", "--max-time", "1e300"], "max_time = 1e+300 is not allowed: a duration > 0 and at most"),
    (["prepare", "--method", "1", "--dt-safety", "1.5"], "dt_safety = 1.5 is not allowed: a fraction of the"),
    (["prepare", "--method", "compress", "--dt-safety", "0.5"], "--dt-safety = 0.5 is not allowed: an option of"),
])
def test_absurd_sizes_are_refused_in_one_line_before_any_work(tmp_path, capsys, monkeypatch, args, message):
    from granlab.app import commands as cli

    monkeypatch.chdir(tmp_path)
    assert cli.main(args + ["--out", str(tmp_path / "out")]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and message in error
    assert list(tmp_path.iterdir()) == []  # no folder made, no cluster started


def test_a_prepared_packings_run_file_keeps_the_step_it_was_made_with(tmp_path):
    import h5py

    from granlab.engine.protocols.prepare import GILABERT_DT_SAFETY

    for given, kept in ((["--dt-safety", "0.3"], 0.3), ([], GILABERT_DT_SAFETY)):
        out = tmp_path / f"packing{len(given)}.h5"
        granlab("prepare", "--method", "1", "--particles", "20", *given, "--out", str(out))
        with h5py.File(out) as f:
            assert json.loads(f["parameters"].attrs["protocol_json"])["dt_safety"] == kept


def test_a_reproduction_whose_every_sample_failed_exits_2(monkeypatch, capsys):
    from granlab.app import commands as cli
    from granlab.engine import reproduce

    failed = [{"case": "noncohesive", "seed": seed, "error": "DivergenceError: overlap"} for seed in (0, 1)]
    monkeypatch.setattr(reproduce, "run_reproduction", lambda *a, **k: {"failed": failed, "samples": failed})
    assert cli.main(["reproduce", "gilabert-method1"]) == 2
    assert "every sample failed (2 of 2); seed 0 (noncohesive): DivergenceError: overlap" in capsys.readouterr().err


def test_every_analysis_refuses_a_frame_with_nan_positions_by_name(tmp_path, capsys):
    import h5py

    from granlab.app import commands as cli

    scene = tmp_path / "pair.toml"
    scene.write_text(PAIR)
    out = tmp_path / "run.h5"
    granlab("run", str(scene), "--out", str(out))
    with h5py.File(out, "r+") as f:
        f["particles/all/position/value"][-1, 1] = np.nan
        frames = f["particles/all/position/value"].shape[0]
    for analysis in ("stiffness", "status", "rigidity", "packing", "fractal"):
        assert cli.main(["analyze", str(out), analysis]) == 2
        error = capsys.readouterr().err
        assert error == (f"granlab analyze: error: {str(out)!r} is damaged (frame {frames - 1}: /particles/all/"
                         "position of disk 1 of 2 is [nan nan]; finite numbers below 1e150 are needed (a run that "
                         "diverged writes NaN: an earlier frame may be whole)); frame 0 (t = 0) is the last that reads "
                         "whole, a checkpoint at step 30000\n"), analysis
    assert cli.main(["analyze", str(out), "packing", "--frame", "0"]) == 0


def test_serve_refuses_an_address_or_data_folder_it_cannot_use_before_starting(tmp_path):
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        refusals = {
            ("--port", "-1"): "--port -1 is not allowed: a port from 1 to 65535, or 0 for any free port",
            ("--port", "99999"): "--port 99999 is not allowed",
            ("--port", str(port)): f"--port {port} is in use by another program",
            ("--host", "nosuch.invalid"): "--host 'nosuch.invalid' is not an address of this machine",
            ("--port", "0", "--data-dir", __file__): f"--data-dir {__file__!r} is a file, not a folder",
            ("--port", "0", "--history-mib", "0"): "--history-mib 0 is not allowed: more than 0 and at most",
            ("--port", "0", "--history-mib", "nan"): "--history-mib nan is not allowed",
            ("--port", "0", "--pause-without-pages", "-1"): "--pause-without-pages -1 is not allowed: seconds from 0 "
                                                             "(never pause) to 86400 (a day)",
            ("--port", "0", "--pause-without-pages", "nan"): "--pause-without-pages nan is not allowed",
        }
        for args, message in refusals.items():
            process = subprocess.run([sys.executable, "-m", "granlab.app.commands", "serve", *args], capture_output=True,
                                     text=True, timeout=120)
            assert process.returncode == 2 and process.stderr.count("\n") == 1, (args, process.stderr)
            assert process.stderr.startswith(f"granlab serve: error: {message}"), (args, process.stderr)
    folder = granlab("run", str(tmp_path), check=False)
    assert folder.returncode == 2 and f"{str(tmp_path)!r} is a folder, not a file: give a scene file" in folder.stderr
    assert granlab("--version").stdout.startswith("granlab ")


def test_bench_scaling_reports_each_size_with_its_memory_and_rebuild_share():
    from granlab.engine import bench

    result = bench.scaling(sides=(6, 12), steps=300)
    assert [row["particles"] for row in result["sizes"]] == [36, 144]
    for row in result["sizes"]:
        assert row["steps"] == 300 and row["ns_per_particle_step"] == pytest.approx(1e9 / row["particle_steps_per_s"])
        assert 500 < row["bytes_per_disk"] < 5000
        assert 0.0 <= row["rebuild_share"] <= 1.0 and (row["rebuild_share"] > 0) == (row["rebuilds"] > 0)
        assert row["rebuild_in_steps"] > 0.0
    assert result["worst_over_best"] >= 1.0
    assert bench.rebuild_seconds(bench.reference_system(12)) > 0.0


def test_a_long_run_shows_its_progress_once_a_second_and_its_json_stays_one_object():
    """The built-in scene runs for seconds (3 s on an idle 2-core machine, a line of progress; more on a busy
    one): it printed nothing until its end."""
    process = granlab("run", "--json")
    lines = process.stderr.splitlines()
    assert len(lines) >= 1 and all(re.fullmatch(r"running: step \d+ of 110560 \(\d+ %\), t = [0-9.e+-]+, \d+ s, "
                                                                r"about \d+ s left", line)
                                   for line in lines), lines
    steps = [int(line.split()[2]) for line in lines]
    assert steps == sorted(steps) and steps[-1] < 110560
    assert json.loads(process.stdout)["steps"] == 110560


def test_output_cut_short_by_its_reader_ends_without_a_traceback():
    """``granlab analyze ... | head -1`` printed a BrokenPipeError traceback under the line. Here
    the reader is gone before the first line is written."""
    read, write = os.pipe()
    process = subprocess.Popen([sys.executable, "-m", "granlab.app.commands", "analyze", "tests/data/lammps/packing.dump",
                                "packing"], stdout=write, stderr=subprocess.PIPE, text=True,
                               cwd=os.path.dirname(os.path.dirname(__file__)))
    os.close(write)
    os.close(read)
    assert process.wait(timeout=60) == 1 and process.stderr.read() == ""


HELP_PROBE = """
import contextlib, io, json, sys
from granlab.app.commands import main
with contextlib.redirect_stdout(io.StringIO()) as shown:
    try:
        main(sys.argv[1:])
    except SystemExit:
        pass
print(json.dumps({"shown": shown.getvalue(), "modules": sorted({m.split('.')[0] for m in sys.modules})}))
"""


@pytest.mark.parametrize("command", ["", "run", "experiment", "bench", "prepare", "study ratchet", "reproduce",
                                     "analyze", "quasistatic", "info", "compile", "serve", "render", "export"])
def test_help_is_read_without_the_engine_numba_or_numpy(command):
    """``--help`` answered within 0.3 s needs the parser built before any engine import (it took 1.4 s
    idle, 7 s on a busy machine): the help of every command comes without numpy, numba or the kernels."""
    process = subprocess.run([sys.executable, "-c", HELP_PROBE, *command.split(), "--help"], capture_output=True,
                             text=True, timeout=120, check=True)
    result = json.loads(process.stdout)
    assert "usage: granlab" in result["shown"]
    assert not {"numpy", "numba", "scipy", "h5py", "panel", "bokeh"} & set(result["modules"])


def test_a_special_file_given_as_input_is_named_as_what_it_is(tmp_path, capsys):
    """Before: a FIFO and a link to /dev/zero were "does not exist"; a folder too, for a run file."""
    import os

    from granlab.app.commands import main

    os.mkfifo(tmp_path / "pipe")
    (tmp_path / "zero").symlink_to("/dev/zero")
    (tmp_path / "nowhere").symlink_to(tmp_path / "gone")
    what = {"pipe": "is a named pipe (FIFO), not a file", "zero": "is a device (/dev/zero), not a file",
            "nowhere": "is a link to nowhere", ".": "is a folder, not a file"}
    for name, reason in what.items():
        path = str(tmp_path / name)
        for command in (["run", path], ["info", path], ["analyze", path, "packing"], ["render", path, "--out",
                                                                                     str(tmp_path / "a.png")]):
            assert main(command) == 2
            err = capsys.readouterr().err
            assert err.count("\n") == 1 and f"{path!r} {reason}" in err, (command, err)


LATTICE = """
[simulation]
steps = {steps}
record_every = 10
[[particles.lattice]]
rows = 30
columns = 30
spacing = 1.0
radius = 0.45
"""


def test_what_a_command_will_take_is_said_and_refused_before_any_work(tmp_path, capsys, monkeypatch):
    """Before: 10¹⁸ steps ran at "0 %" for ever, a 2000 × 2000 lattice reached 2.9 GB with no line."""
    from granlab.app.commands import main
    from granlab.engine import costs

    scene = tmp_path / "lattice.toml"
    scene.write_text(LATTICE.format(steps=10 ** 13))
    assert main(["run", str(scene)]) == 2
    assert capsys.readouterr().err == (f"granlab run: error: simulation.steps = {10 ** 13} is not allowed: 1e+13 steps "
                                       f"of dt = 0.001681, at most 1e+12 (a shorter run, or a larger time step: a lower "
                                       f"stiffness or a higher mass)\n")
    scene.write_text(LATTICE.format(steps=100))
    monkeypatch.setattr(costs, "memory_room", lambda: 1_000_000)
    assert main(["run", str(scene)]) == 2
    assert capsys.readouterr().err == (f"granlab run: error: {scene}: [particles.lattice[0]] rows × columns or count: "
                                       "900 disks need about 1.6 MB of memory (1800 bytes a disk); 1 MB is free to "
                                       "this process: use fewer disks\n")
    monkeypatch.undo()
    monkeypatch.setattr(costs, "room_for_one_file", lambda folder: 500_000)
    assert main(["run", str(scene), "--out", str(tmp_path / "run.h5")]) == 2
    assert capsys.readouterr().err == (f"granlab run: error: --out {str(tmp_path / 'run.h5')!r}: 11 frames of 900 "
                                       "disks need up to 2 MB; 500 kB free there: fewer frames (--frame-every, "
                                       "simulation.record_every), or another disk\n")
    assert main(["study", "ratchet", "--particles", "400", "--samples", "8", "--out", str(tmp_path / "study")]) == 2
    assert capsys.readouterr().err == (f"granlab study: error: --out {tmp_path / 'study'}: 8 run files of 400 disks "
                                       "need up to 19 MB; 500 kB free there: fewer samples, cycles or frames, or "
                                       "another disk\n")
    assert not any(tmp_path.glob("*.h5")) and not (tmp_path / "study").exists()
    monkeypatch.undo()
    monkeypatch.setattr(costs, "ANNOUNCE_BYTES", 1)
    assert main(["run", str(scene), "--out", str(tmp_path / "run.h5")]) == 0
    said = capsys.readouterr().err.splitlines()
    assert said[:2] == ["building 900 disks (up to 1.6 MB of memory)", f"writing 11 frames to {tmp_path / 'run.h5'} "
                                                                        "(up to 2 MB)"]


def test_a_run_whose_energy_balance_drifts_says_so_on_stderr_and_in_its_run_file(tmp_path, monkeypatch, capsys):
    """The engine's own drift at the default step is a few 10^-4 of the energy turned over: a run told
    to warn above 10^-6 warns, on standard error and in the run file's notes, which ``granlab info``
    prints; the threshold as shipped (1 %) stays silent."""
    from granlab.app.commands import main
    from granlab.engine import simulation

    scene = tmp_path / "pair.toml"
    scene.write_text(PAIR.replace("normal_stiffness = 1e4", "normal_stiffness = 1e4\nfriction = 1e6")
                     .replace("vx = 1.0", "vx = 1.0\nvy = 0.4\nomega = 3.0").replace("dt = 1e-4", "dt = 2e-3"))
    assert main(["run", str(scene), "--out", str(tmp_path / "quiet.h5")]) == 0
    assert "warning" not in capsys.readouterr().err
    monkeypatch.setattr(simulation, "UNBOOKED_SHARE", 1e-6)
    assert main(["run", str(scene), "--out", str(tmp_path / "told.h5")]) == 0
    warning = capsys.readouterr().err.strip().splitlines()[-1]
    assert re.fullmatch(r"granlab run: warning: the energy balance drifted by [+-][0-9.e-]+ % of the energy the run "
                        r"turned over, more than 0.0001 %: the time step is too large for this run \(a smaller "
                        r"simulation.dt_safety or dt\)", warning), warning
    assert main(["info", str(tmp_path / "told.h5")]) == 0
    assert f"  note: {warning.removeprefix('granlab run: warning: ')}" in capsys.readouterr().out
    assert main(["info", str(tmp_path / "quiet.h5")]) == 0
    assert "note:" not in capsys.readouterr().out
