"""A command of the ``granlab`` CLI run in a child forked from the process of a fuzz harness (the
engine imported and its kernels loaded once: milliseconds a case, not seconds), its address
space limited and its standard output and error written to files; the harness bounds its time."""

from __future__ import annotations

import os
import resource
import signal
import sys
import time
import traceback
from pathlib import Path

MEMORY_LIMIT = 3 * 2 ** 30
"""A child's address space: a reader that trusts a declared size runs into it."""


def start(main, argv: list[str], out: Path, err: Path) -> int:
    """The child's pid: it runs ``main(argv)`` and exits with its status (1 after a traceback)."""
    sys.stdout.flush()
    sys.stderr.flush()
    pid = os.fork()
    if pid:
        return pid
    code = 1
    try:
        resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))
        os.dup2(os.open(out, os.O_WRONLY | os.O_CREAT | os.O_TRUNC), 1)
        os.dup2(os.open(err, os.O_WRONLY | os.O_CREAT | os.O_TRUNC), 2)
        code = main(argv)
    except SystemExit as exit_:
        code = exit_.code if isinstance(exit_.code, int) else 1
    except BaseException:
        traceback.print_exc()
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)


def ended(pid: int, started: float, deadline: float) -> tuple[bool, int | None, resource.struct_rusage | None]:
    """Whether the child has ended, its exit status (None: killed at ``deadline`` seconds after
    ``started``) and its resource usage."""
    done, status, usage = os.wait4(pid, os.WNOHANG)
    if done:
        return True, os.waitstatus_to_exitcode(status), usage
    if time.perf_counter() - started < deadline:
        return False, None, None
    os.kill(pid, signal.SIGKILL)
    _, _, usage = os.wait4(pid, 0)
    return True, None, usage


def run(main, argv: list[str], out: Path, err: Path, deadline: float) -> tuple[int | None, float]:
    """One child to its end: its exit status (None: killed at the deadline) and its seconds."""
    started = time.perf_counter()
    pid = start(main, argv, out, err)
    while True:
        done, code, _ = ended(pid, started, deadline)
        if done:
            return code, time.perf_counter() - started
        time.sleep(0.005)
