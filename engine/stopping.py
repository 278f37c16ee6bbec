"""Stopping a command where what it writes is whole.

SIGTERM and Ctrl-C (SIGINT) only ask a command to stop (:func:`asked`): the work looks at the
request at points where its outputs are whole (:func:`check`: between blocks of steps, between
frames, between samples) and unwinds from there with :class:`Stopped`, closing its files on the way
(a run file at its last whole frame, an export's part files removed). A second and a third signal
change nothing. Raised from the handler itself, as before, the exception landed wherever the main
thread was: in a weakref callback, where Python reports and drops it (an export ran on 25 s to exit
0), or in the middle of a frame being written (a run file left damaged).

Work that reaches no check within :data:`CHECK_SECONDS` (a read that hangs) is then stopped where it
is, :class:`Stopped` raised in the main thread but outside the parts :func:`shielded` keeps whole; if
that too has not ended it :data:`UNWIND_SECONDS` later, the process ends at once. Either way a
command ends within five seconds, with 130 (Ctrl-C) or 143 (SIGTERM).

Child processes end with their parent whatever ends it, SIGKILL included (:func:`die_with_parent`,
called first thing in each child): a compile worker left behind held 267 MB for half an hour.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterable, Iterator

CHECK_SECONDS = 3.0
"""How long the work has, after the first signal, to reach a point where it stops whole."""

UNWIND_SECONDS = 1.5
"""How long :class:`Stopped`, raised where the work is, has to unwind before the process ends."""

SIGNALS = {signal.SIGINT: "Ctrl-C", signal.SIGTERM: "SIGTERM"}
PR_SET_PDEATHSIG = 1


class Stopped(KeyboardInterrupt):
    """The command was asked to stop by ``signum``; its exit status is ``128 + signum``."""

    def __init__(self, signum: int):
        super().__init__(SIGNALS.get(signum, f"signal {signum}"))
        self.signum = signum

    @property
    def exit_status(self) -> int:
        return 128 + self.signum

    @property
    def by(self) -> str:
        return SIGNALS.get(self.signum, f"signal {self.signum}")


class _Request:
    """The first signal this process got (0: none), and how far its stop has gone."""

    def __init__(self):
        self.signum = 0
        self.raise_now = False  # the work reached no check in time: raise where it is
        self.shields = 0  # how deep the main thread is in parts kept whole
        self.deferred = False  # a raise due while shielded
        self.timers: list[threading.Timer] = []


_REQUEST = _Request()
_HANDLERS: list = []  # the handlers of the blocks of stop_on_signals open, innermost last


def asked() -> int:
    """The signal a stop was asked by (0: none)."""
    return _REQUEST.signum


def check() -> None:
    """Raise :class:`Stopped` if a stop was asked (in the main thread only: other threads' work is the
    main thread's to stop)."""
    if _REQUEST.signum and threading.current_thread() is threading.main_thread():
        raise Stopped(_REQUEST.signum)


def checked(items: Iterable) -> Iterator:
    """``items``, with :func:`check` before each."""
    for item in items:
        check()
        yield item


@contextlib.contextmanager
def shielded():
    """A part of the main thread's work that a late stop (:data:`CHECK_SECONDS` after the signal) does not
    interrupt, such as a run file's frame being written: the stop is raised as it ends."""
    main = threading.current_thread() is threading.main_thread()
    if main:
        _REQUEST.shields += 1
    try:
        yield
    finally:
        if main:
            _REQUEST.shields -= 1
            if not _REQUEST.shields and _REQUEST.deferred:
                _REQUEST.deferred = False
                raise Stopped(_REQUEST.signum)


def _handler(on_first: Callable[[int], None] | None):
    def handle(signum, frame):
        request = _REQUEST
        if request.raise_now:
            request.raise_now = False
            if request.shields:
                request.deferred = True
                return
            raise Stopped(request.signum)
        if request.signum:
            return  # a second and third signal change nothing
        request.signum = signum
        request.timers = [threading.Timer(CHECK_SECONDS, _raise_where_it_is),
                          threading.Timer(CHECK_SECONDS + UNWIND_SECONDS, _end_at_once, args=(signum,))]
        for timer in request.timers:
            timer.daemon = True
            timer.start()
        if on_first is not None:
            on_first(signum)
    return handle


def _raise_where_it_is() -> None:
    _REQUEST.raise_now = True
    signal.pthread_kill(threading.main_thread().ident, _REQUEST.signum)


def _end_at_once(signum: int) -> None:
    name = os.path.basename(sys.argv[0]) if sys.argv and sys.argv[0] else "granlab"
    print(f"{'granlab' if name in ('__main__.py', '-c') else name}: stopped by {SIGNALS.get(signum, signum)}, "
          "at once: the work did not stop within "
          f"{CHECK_SECONDS + UNWIND_SECONDS:g} s", file=sys.stderr, flush=True)
    os._exit(128 + signum)


@contextlib.contextmanager
def stop_on_signals(on_first: Callable[[int], None] | None = None):
    """Within this block SIGTERM and SIGINT ask for a stop (``on_first(signum)`` is called from the
    handler at the first, or at once if a block around this one was already asked), as this module
    says. In the main thread only (elsewhere a signal's handler cannot be set, and nothing changes).
    The handlers before are put back as the block ends, but where the outermost block was asked to
    stop: the process is ending, and the later signals of a burst are ignored to its end (a SIGTERM
    50 ms after a Ctrl-C would otherwise kill it on its way out). The outermost block forgets the
    request."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    outermost = not _HANDLERS
    handler = _handler(on_first)
    previous = {signum: signal.signal(signum, handler) for signum in SIGNALS}
    _HANDLERS.append(handler)
    if _REQUEST.signum and on_first is not None:
        on_first(_REQUEST.signum)
    try:
        yield
    finally:
        _HANDLERS.pop()
        for signum, before in previous.items():
            signal.signal(signum, signal.SIG_IGN if outermost and _REQUEST.signum else before)
        if outermost:
            for timer in _REQUEST.timers:
                timer.cancel()
            _REQUEST.__init__()


def die_with_parent(parent: int) -> None:
    """In a child process: end it (SIGKILL) as soon as the process that started it ends, however it
    ends (Linux; elsewhere nothing), and at once if that has already happened (``parent``: its pid)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    except (OSError, AttributeError):  # not Linux
        return
    if os.getppid() != parent:
        os._exit(1)
