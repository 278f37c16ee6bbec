"""The lab's file jobs: saving a run, reading a file to replay, recording a movie.

Each job runs a function in a process of its own (spawned: none of the lab's threads or locks
is copied into it), beside the simulation, so that nothing a file holds and nothing a disk does
can stop the lab: a reader stuck in a damaged or hostile file, a writer on a full disk, a crash
inside a library. The function gets a ``report(fraction)`` callback and its arguments, and its
return value comes back through a pipe. A thread of the lab per job starts the process (sending
the arguments, which can be megabytes, is never done on the engine's thread), follows its
progress, kills it when the user cancels or its time limit runs out, and hands the outcome to
``on_done`` — the engine queues it and applies it between two steps.

A job's outcome is a :class:`JobOutcome`: its result, or an error message that says what went
wrong (a child that dies says how), or that it was cancelled.

As with any spawned process (and Dask's local cluster), a script that starts the lab's engine
itself must do so under ``if __name__ == "__main__":``: the child imports the script's module.
``granlab serve`` and notebooks need nothing.
"""

from __future__ import annotations

import itertools
import multiprocessing
import os
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable

from granlab.engine.errors import GranLabError
from granlab.engine.stopping import die_with_parent

SPAWN = multiprocessing.get_context("spawn")
POLL_SECONDS = 0.1


@dataclass(frozen=True)
class JobOutcome:
    """What a job ended with: ``result`` (on success), ``error`` (a message), or ``cancelled``."""

    job: "Job"
    result: Any = None
    error: str = ""
    cancelled: bool = False


class Job:
    """One function running in a child process. ``kind`` (``save``, ``load``, ``record``) names
    the control it belongs to, ``label`` what it does (``saving run1.h5``)."""

    def __init__(self, number: int, kind: str, label: str, time_limit: float | None):
        self.number = number
        self.kind = kind
        self.label = label
        self.time_limit = time_limit
        self.progress = 0.0
        self.started = time.monotonic()
        self._cancel = threading.Event()

    def cancel(self) -> None:
        self._cancel.set()

    @property
    def cancelled(self) -> bool:
        return self._cancel.is_set()

    def describe(self) -> dict:
        return {"id": self.number, "kind": self.kind, "label": self.label, "progress": self.progress,
                "seconds": time.monotonic() - self.started}


class Jobs:
    """The running jobs, at most one of each kind. ``on_done(outcome)`` is called on the job's
    own thread when it ends, however it ends."""

    def __init__(self, on_done: Callable[[JobOutcome], None]):
        self._on_done = on_done
        self._jobs: dict[str, Job] = {}
        self._lock = threading.Lock()
        self._numbers = itertools.count(1)
        self._threads: list[threading.Thread] = []

    def start(self, kind: str, label: str, function: Callable, args: tuple, time_limit: float | None = None) -> Job:
        """Run ``function(report, *args)`` in a child process; refused while a job of ``kind`` runs."""
        with self._lock:
            running = self._jobs.get(kind)
            if running is not None:
                raise GranLabError(f"{running.label} is still going ({100 * running.progress:.0f} %): wait for it "
                                   f"or cancel it first")
            job = self._jobs[kind] = Job(next(self._numbers), kind, label, time_limit)
        thread = threading.Thread(target=self._follow, args=(job, function, args), name=f"granlab-{kind}",
                                  daemon=True)
        self._threads = [t for t in self._threads if t.is_alive()] + [thread]
        thread.start()
        return job

    def cancel(self, kind: str) -> Job | None:
        """Cancel the job of ``kind`` (its process is killed); None if none runs."""
        with self._lock:
            job = self._jobs.get(kind)
        if job is not None:
            job.cancel()
        return job

    def running(self) -> list[Job]:
        with self._lock:
            return list(self._jobs.values())

    def close(self, timeout: float = 10.0) -> None:
        """Cancel every job and wait for their threads (their processes are killed)."""
        for job in self.running():
            job.cancel()
        deadline = time.monotonic() + timeout
        for thread in self._threads:
            thread.join(max(0.0, deadline - time.monotonic()))

    def _follow(self, job: Job, function: Callable, args: tuple) -> None:
        outcome = self._run(job, function, args)
        with self._lock:
            del self._jobs[job.kind]
        self._on_done(outcome)

    def _run(self, job: Job, function: Callable, args: tuple) -> JobOutcome:
        ours, theirs = SPAWN.Pipe(duplex=False)
        process = SPAWN.Process(target=_child, args=(theirs, os.getpid(), function, args), name=f"granlab-{job.kind}",
                                daemon=True)
        try:
            process.start()
        except (OSError, RuntimeError, TypeError, AttributeError) as error:  # no process, or arguments that do not pickle
            return JobOutcome(job, error=f"{job.label} could not start: {error}")
        theirs.close()
        try:
            while True:
                if job.cancelled:
                    return JobOutcome(job, cancelled=True)
                if job.time_limit is not None and time.monotonic() - job.started > job.time_limit:
                    return JobOutcome(job, error=f"{job.label} gave up after {job.time_limit:.0f} s (the file may "
                                                 f"be damaged or far larger than it looks)")
                if not ours.poll(POLL_SECONDS):
                    continue
                try:
                    kind, value = ours.recv()
                except (EOFError, OSError):
                    process.join(5.0)
                    return JobOutcome(job, error=f"{job.label} failed: its process ended without an answer "
                                                 f"({_exit_text(process.exitcode)})")
                if kind == "progress":
                    job.progress = value
                elif kind == "done":
                    job.progress = 1.0
                    return JobOutcome(job, result=value)
                else:
                    return JobOutcome(job, error=value)
        finally:
            ours.close()
            if process.is_alive():
                process.kill()
            process.join(5.0)


def _exit_text(code: int | None) -> str:
    if code is None:
        return "it is still running"
    if code < 0:
        return f"killed by signal {-code}" + (" — out of memory?" if -code == 9 else "") + \
            (" — a crash, e.g. a full disk" if -code in (7, 11) else "")
    return f"exit code {code}"


def _child(conn, parent: int, function: Callable, args: tuple) -> None:
    """The job's process: run ``function``, send its progress and its outcome; it ends with the lab
    (process ``parent``), however the lab ends."""
    die_with_parent(parent)

    def report(fraction: float) -> None:
        conn.send(("progress", min(1.0, max(0.0, float(fraction)))))

    try:
        result = function(report, *args)
    except (GranLabError, OSError, ValueError) as error:
        conn.send(("error", str(error)))
    except MemoryError:
        conn.send(("error", "out of memory"))
    except Exception as error:  # a library's own failure: say which, never leave the lab waiting
        conn.send(("error", f"{type(error).__name__}: {error}"))
    else:
        conn.send(("done", result))
    finally:
        conn.close()
