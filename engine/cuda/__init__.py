"""The CUDA backend: the engine's steps on an NVIDIA GPU (numba.cuda), with the engine's own laws.

A contact row's geometry and laws are :func:`granlab.engine.kernels.contacts.direct_row`, a disk's
kick and drift :func:`granlab.engine.kernels.integrate.particle_range`, the walls, the cell under
stress control and the end of a step the CPU engine's kernels too: Numba compiles them for the
device from the same source. What the device does differently is how the rows' forces meet (atomic
additions, one thread a row) and how sums are taken (within a block, then over the blocks, in a fixed
order): a run agrees with the CPU engine to rounding, not bit for bit.

Without a GPU, numba's simulator (``NUMBA_ENABLE_CUDASIM=1``) runs the same kernels, thread by
thread, with the functions they call compiled for the CPU: the tests use it on small systems.
"""

from __future__ import annotations

import numba
import numpy as np

from ..errors import ParameterError
from ..params import BACKENDS


def simulated() -> bool:
    """Whether numba's CUDA simulator stands in for a GPU (``NUMBA_ENABLE_CUDASIM=1``)."""
    return bool(numba.config.ENABLE_CUDASIM)


def numba_cuda():
    """``numba.cuda``. The numba-cuda of some machines still names ``numpy.row_stack``, which numpy 2.5
    removed: it is the same function as ``numpy.vstack``."""
    if not hasattr(np, "row_stack"):
        np.row_stack = np.vstack
    from numba import cuda as module

    return module


def check_backend(backend: str) -> str:
    """``backend`` if this machine can run it; a :class:`ParameterError` naming what it can run if not."""
    if backend not in BACKENDS:
        raise ParameterError("backend", backend, " or ".join(BACKENDS))
    if backend == "cuda" and not simulated() and not numba_cuda().is_available():
        raise ParameterError("backend", backend, "cpu (numba finds no CUDA GPU on this machine; its simulator stands "
                                                 "in for one with NUMBA_ENABLE_CUDASIM=1)")
    return backend
