"""SIGTERM and Ctrl-C ask a command to stop where what it writes is whole (engine/stopping.py): run and
export signalled at random moments, some with three signals 50 ms apart, end within 5 s with 130 or 143,
leave every output whole or absent and no process behind; a lab stopped while it compiles, and a compile
killed outright, leave no compile worker."""

import os
import random
import signal
import subprocess
import sys
import threading
import time

import psutil
import pytest

from granlab.engine import stopping
from granlab.engine.io import h5md

SCENE = """
[simulation]
duration = 30.0
record_every = 200
[contact]
normal_stiffness = 1e3
tangential_stiffness = 1e3
friction = 0.3
damping_ratio = 0.1
[box]
x = [0.0, 20.0]
y = [0.0, 20.0]
[[particles.gas]]
count = 200
radius_min = 0.4
radius_max = 0.6
seed = 1
velocity_spread = 1.0
"""

MOMENTS = 10
"""Moments a command is signalled at, each of run and export."""


def command(*args: str) -> list[str]:
    return [sys.executable, "-m", "granlab.app.commands", *args]


def signalled(args: list[str], delay: float, signals: tuple[int, ...]) -> dict:
    """Run ``args``, send ``signals`` 50 ms apart from ``delay`` s after its start; what it did."""
    process = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    time.sleep(delay)
    children = []
    if process.poll() is None:
        children = psutil.Process(process.pid).children(recursive=True)
    sent = time.monotonic()
    for k, signum in enumerate(signals):
        if process.poll() is None:
            process.send_signal(signum)
        if k + 1 < len(signals):
            time.sleep(0.05)
    _, stderr = process.communicate(timeout=60)
    ended = time.monotonic() - sent
    left = [child.pid for child in children if child.is_running() and child.status() != psutil.STATUS_ZOMBIE]
    return {"code": process.returncode, "seconds": ended, "stderr": stderr, "left": left}


def cases(rng: random.Random) -> list[tuple[float, tuple[int, ...]]]:
    """Random moments from 0.4 s (Python's own start is before the lab's handlers) to 3 s, a third of them with
    three signals 50 ms apart, the first SIGTERM or SIGINT."""
    picked = []
    for k in range(MOMENTS):
        first = rng.choice((signal.SIGTERM, signal.SIGINT))
        picked.append((rng.uniform(0.4, 3.0), (first, signal.SIGTERM, signal.SIGINT) if k % 3 == 0 else (first,)))
    return picked


def check_stop(result: dict, signals: tuple[int, ...], what: str) -> bool:
    """Whether the command was stopped (else it had done its work: 0, or killed on its way out)."""
    assert "Traceback" not in result["stderr"] and "Exception ignored" not in result["stderr"], result["stderr"]
    assert not result["left"], f"{what}: processes left behind: {result['left']}"
    if result["code"] in (0, -signals[0]):  # done before the signal, or after its work, on its way out
        return False
    assert result["code"] == 128 + signals[0], (what, result)
    assert result["seconds"] < 5.0, (what, result)
    assert result["stderr"].splitlines()[-1].endswith(f"stopped by {stopping.SIGNALS[signals[0]]}"), result["stderr"]
    return True


def test_run_and_export_stopped_at_random_moments_leave_whole_outputs_and_no_process(tmp_path):
    rng = random.Random(61)
    scene = tmp_path / "gas.toml"
    scene.write_text(SCENE)
    full = tmp_path / "run-full.h5"
    subprocess.run(command("run", str(scene), "--out", str(full)), check=True, capture_output=True, timeout=300)
    frames = h5md.summary(full)["frames"]
    stopped = 0
    for k, (delay, signals) in enumerate(cases(rng)):
        out = tmp_path / f"run{k}.h5"
        result = signalled(command("run", str(scene), "--out", str(out), "--checkpoint-every", "1"), delay, signals)
        was_stopped = check_stop(result, signals, f"run at {delay:.2f} s")
        stopped += was_stopped
        if out.exists():  # begun: every frame in it whole, its checkpoint one of them
            summary = h5md.summary(out)
            assert summary["frames"] >= 1 and summary["checkpoint_step"] is not None, summary
            assert was_stopped or summary["frames"] == frames
            with h5md.open_run(out) as f:
                h5md.read_frame(f, -1)
    for k, (delay, signals) in enumerate(cases(rng)):
        out = tmp_path / f"vtk{k}"
        result = signalled(command("export", str(full), "--format", "vtk", "--out", str(out)), delay, signals)
        stopped += check_stop(result, signals, f"export at {delay:.2f} s")
        assert not list(tmp_path.glob(".*.part")), "an export's part files were left"
        if out.exists():  # written whole or not at all
            assert len(list(out.iterdir())) == 1 + 3 * frames
    assert stopped >= MOMENTS  # most moments land in the work, not after it


def test_a_stop_waits_for_a_check_then_raises_where_the_work_is_but_never_inside_a_shielded_part():
    """The handler only asks; a second signal changes nothing; work that reaches no check within
    CHECK_SECONDS is stopped where it is, a shielded part first written whole."""
    handlers = {signum: signal.getsignal(signum) for signum in stopping.SIGNALS}
    try:
        stop_waits_then_raises()
    finally:
        for signum, handler in handlers.items():
            signal.signal(signum, handler)


def stop_waits_then_raises():
    seen = []
    with stopping.stop_on_signals(on_first=seen.append):
        os.kill(os.getpid(), signal.SIGTERM)
        os.kill(os.getpid(), signal.SIGINT)  # changes nothing
        assert stopping.asked() == signal.SIGTERM and seen == [signal.SIGTERM]
        with pytest.raises(stopping.Stopped) as stop:
            stopping.check()
        assert stop.value.exit_status == 143
        begun = time.monotonic()
        with pytest.raises(stopping.Stopped):
            with stopping.shielded():
                time.sleep(stopping.CHECK_SECONDS + 0.5)  # no check: the late stop waits for the part's end
                written = time.monotonic()
        assert written - begun > stopping.CHECK_SECONDS
    assert stopping.asked() == 0 and signal.getsignal(signal.SIGTERM) is signal.SIG_IGN  # the process is ending
    threads = []
    with stopping.stop_on_signals():
        threading.Thread(target=lambda: threads.append(stopping.check())).start()
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.1)
        begun = time.monotonic()
        with pytest.raises(stopping.Stopped):
            time.sleep(30)  # a read that hangs: stopped where it is
        assert time.monotonic() - begun < stopping.CHECK_SECONDS + 0.5
    assert threads == [None]  # another thread's work is the main thread's to stop


def test_a_lab_stopped_while_it_compiles_ends_its_compile_workers(tmp_path):
    """``granlab serve`` stopped by SIGTERM while it compiled left its compile worker running, reparented to
    init, blocked on a pipe read (267 MB, still there 36 minutes later)."""
    env = {**os.environ, "GRANLAB_CACHE_DIR": str(tmp_path / "cache")}
    process = subprocess.Popen(command("serve", "--port", "0", "--data-dir", str(tmp_path / "data")),
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        while "compiling kernels" not in process.stdout.readline():
            assert process.poll() is None
        deadline = time.monotonic() + 60
        while not (workers := psutil.Process(process.pid).children(recursive=True)) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert workers
        process.send_signal(signal.SIGTERM)
        sent = time.monotonic()
        output, _ = process.communicate(timeout=30)
        assert time.monotonic() - sent < 5.0 and process.returncode == 143
    finally:
        process.kill()
    assert output.splitlines()[-1] == "granlab serve: stopped by SIGTERM" and "Traceback" not in output
    assert "compile stopped after" in output
    time.sleep(0.5)
    assert not [w.pid for w in workers if w.is_running() and w.status() != psutil.STATUS_ZOMBIE]


def test_compile_workers_end_with_a_parent_killed_outright(tmp_path):
    env = {**os.environ, "GRANLAB_CACHE_DIR": str(tmp_path / "cache")}
    process = subprocess.Popen(command("compile", "--workers", "2"), stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL, env=env)
    deadline = time.monotonic() + 60
    workers = []
    while len(workers) < 2 and time.monotonic() < deadline:
        time.sleep(0.1)
        workers = [w for w in psutil.Process(process.pid).children(recursive=True) if "spawn_main" in " ".join(w.cmdline())]
    process.kill()
    process.wait(timeout=30)
    deadline = time.monotonic() + 5
    while any(w.is_running() and w.status() != psutil.STATUS_ZOMBIE for w in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert len(workers) == 2 and not [w.pid for w in workers if w.is_running() and w.status() != psutil.STATUS_ZOMBIE]
