"""Shared JIT flags, and :func:`njit`, numba's with the kernel cache of :mod:`.cache`.

``nogil`` lets the lab's event loops run while a kernel computes; ``cache`` keeps compiled kernels
on disk; ``error_model="numpy"`` turns a division by zero into inf/NaN (caught by the divergence
checks) instead of a branch per division. The thread-safe layer (OpenMP or TBB) lets parallel
kernels be launched from several Python threads at once.
"""

import numba
from numba.core import event

from .cache import KernelCache
from .watchers import WATCHERS

numba.config.THREADING_LAYER = "threadsafe"

JIT = dict(nogil=True, cache=True, error_model="numpy")
PARALLEL = dict(JIT, parallel=True)
#: for kernels that never allocate: no reference counting. Numba otherwise wraps every array
#: taken from a named tuple in atomic increments and decrements, some 60 per call of the
#: contact loop, which cost 4.5 us per call on these machines (more than all the work of a
#: 16-disk step). Numba refuses to compile an allocation in such a kernel. One of LLVM's
#: fast-math liberties, and only that one: ``x / y`` as ``x * (1 / y)`` (``arcp``, within an ulp).
#: Not fused multiply-adds (``contract``): which product LLVM fuses into an addition depends on
#: the code around it, so the gathered contact pass (vector code) and the direct one (scalar)
#: rounded the same row differently; unfused, they agree bit for bit, and a run gives the same
#: numbers on a processor without fused multiply-adds. None that assumes finite values (the
#: divergence checks test for NaN and inf) or reorders sums (the energy tallies, and the
#: bit-for-bit resumption, depend on their order).
KERNEL = dict(JIT, _nrt=False, fastmath={"arcp"})


def njit(function=None, **flags):
    """``numba.njit(**flags)``; with ``cache=True`` the kernel is cached as :mod:`.cache` says
    (stamped by every source it is compiled from, shared by copies of them, saved under a lock)."""

    def decorate(function):
        dispatcher = numba.njit(**{**flags, "cache": False})(function)
        if flags.get("cache"):
            dispatcher._cache = KernelCache(function)
        return dispatcher

    return decorate if function is None else decorate(function)


class _Relay(event.Listener):
    """Tells :data:`.watchers.WATCHERS` when the outermost compile of a kernel of this package starts
    and ends (Numba compiles the functions a kernel calls inside its compile)."""

    def __init__(self):
        self.depth = 0
        self.ours = False

    def on_start(self, ev) -> None:
        self.depth += 1
        if self.depth == 1:
            function = ev.data["dispatcher"].py_func
            self.ours = function.__module__.startswith(__package__)
            if self.ours:
                for watcher in list(WATCHERS):
                    watcher.started(function.__name__)

    def on_end(self, ev) -> None:
        self.depth -= 1
        if self.depth == 0 and self.ours:
            for watcher in list(WATCHERS):
                watcher.ended()


event.register("numba:compile", _Relay())
