"""Shared JIT flags.

``nogil`` lets the lab's event loops run while a kernel computes; ``cache``
keeps compiled kernels on disk; ``error_model="numpy"`` turns a division by
zero into inf/NaN (caught by the divergence checks) instead of a branch per
division. The thread-safe layer (OpenMP or TBB) lets parallel kernels be
launched from several Python threads at once.
"""

import numba

numba.config.THREADING_LAYER = "threadsafe"

JIT = dict(nogil=True, cache=True, error_model="numpy")
PARALLEL = dict(JIT, parallel=True)
