"""The lab's file jobs (app.jobs): a child process per job, its progress, its outcome, and the lab
never held by it — a child that hangs is given up after its time limit or killed on Cancel, one
that crashes says how it ended."""

import os
import resource
import threading
import time

import numpy as np
import pytest

from granlab.app.lab.jobs import Jobs
from granlab.engine.errors import GranLabError


def counting(report, count):
    for k in range(count):
        report((k + 1) / count)
    return count


def hanging(report):
    report(0.25)
    time.sleep(3600)


def crashing(report):
    os.abort()


def refusing(report, name):
    raise GranLabError(f"{name} is not a run file")


class Outcomes:
    def __init__(self):
        self.done = threading.Event()
        self.outcome = None

    def __call__(self, outcome):
        self.outcome = outcome
        self.done.set()

    def wait(self, timeout=60.0):
        assert self.done.wait(timeout), "the job never ended"
        return self.outcome


@pytest.fixture
def jobs():
    outcomes = Outcomes()
    runner = Jobs(on_done=outcomes)
    yield runner, outcomes
    runner.close()


def test_a_job_returns_its_result_and_is_listed_while_it_runs(jobs):
    runner, outcomes = jobs
    job = runner.start("save", "saving run1.h5", counting, (5,))
    assert [j.label for j in runner.running()] == ["saving run1.h5"]
    with pytest.raises(GranLabError, match="saving run1.h5 is still going .* wait for it or cancel it first"):
        runner.start("save", "saving run2.h5", counting, (5,))
    outcome = outcomes.wait()
    assert outcome.job is job and outcome.result == 5 and not outcome.error and job.progress == 1.0
    assert runner.running() == []


def test_an_error_in_the_child_comes_back_as_its_message(jobs):
    runner, outcomes = jobs
    runner.start("load", "reading bad.xyz", refusing, ("bad.xyz",))
    assert outcomes.wait().error == "bad.xyz is not a run file"


def test_a_hanging_child_is_given_up_after_its_time_limit(jobs):
    runner, outcomes = jobs
    start = time.monotonic()
    job = runner.start("load", "reading bad.xyz", hanging, (), time_limit=3.0)
    outcome = outcomes.wait()
    assert 3.0 <= time.monotonic() - start < 10.0 and job.progress == 0.25
    assert outcome.error == "reading bad.xyz gave up after 3 s (the file may be damaged or far larger than it looks)"


def test_cancel_kills_the_child_at_once(jobs):
    runner, outcomes = jobs
    job = runner.start("record", "recording movie.gif", hanging, ())
    while job.progress == 0.0:  # the child has started
        time.sleep(0.05)
    start = time.monotonic()
    assert runner.cancel("record") is job
    assert outcomes.wait().cancelled and time.monotonic() - start < 2.0
    assert runner.cancel("record") is None


def test_a_crashing_child_says_how_it_ended(jobs):
    runner, outcomes = jobs
    runner.start("save", "saving run1.h5", crashing, ())
    assert outcomes.wait().error == ("saving run1.h5 failed: its process ended without an answer (killed by "
                                     "signal 6)")


def saving(report, path, room):
    """The lab's "Save run" of three frames of a 400-disk packing where only 20 kB more fit (a file
    size limit, as a full disk); ``room``: what the look before the save finds (``None``: the same
    20 kB; else that many bytes, the disk filled by another program while it saves)."""
    from granlab.app.lab import replay
    from granlab.engine import ContactLaw, Integration, ParticleState, Simulation
    from granlab.engine.generate import square_lattice

    resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))
    if room is not None:
        replay.room_for_one_file = lambda folder: room
    sim = Simulation(ParticleState(square_lattice(20, 20, 1.0), np.full(400, 0.5)), ContactLaw(), Integration())
    frames = [(sim.snapshot(), "{}", "still")] * 3
    return replay.write_run(report, path, sim, True, frames, {}, {}, {}, [])


def test_a_save_the_disk_cannot_hold_is_refused_before_it_starts(jobs, tmp_path):
    runner, outcomes = jobs
    runner.start("save", "saving run1.h5", saving, (tmp_path / "run1.h5", None))
    assert outcomes.wait().error == ("saving run1.h5: 3 frames of 400 disks need up to 1.5 MB; 20 kB free in the "
                                     "data folder")
    assert list(tmp_path.iterdir()) == []


def test_a_save_onto_a_full_disk_says_in_one_line_that_nothing_was_written(jobs, tmp_path):
    """Before: "... What was written before stays readable; ...; nothing was written under its name" (both)."""
    runner, outcomes = jobs
    runner.start("save", "saving run1.h5", saving, (tmp_path / "run1.h5", 10 ** 12))
    error = outcomes.wait().error
    assert error.startswith(f"writing {str(tmp_path / 'run1.h5')!r} failed: File too large; nothing was written"), error
    assert "stays readable" not in error and "\n" not in error
    assert list(tmp_path.iterdir()) == []


def test_a_replay_this_machine_has_no_memory_for_is_refused_before_it_is_read(tmp_path, monkeypatch):
    from granlab.app.lab import replay

    run = tmp_path / "run.h5"
    run.write_bytes(bytes(2_000_000))
    monkeypatch.setattr(replay.costs, "memory_room", lambda: 1_000_000)
    with pytest.raises(GranLabError) as error:
        replay.read_replay(lambda fraction: None, run)
    assert str(error.value) == ("run.h5 (2 MB) needs about 6 MB of memory to replay; 1 MB is free: close other "
                                "programs, or render it (granlab render)")
