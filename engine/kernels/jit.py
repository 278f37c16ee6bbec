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
#: for kernels that never allocate: no reference counting. Numba otherwise wraps every array
#: taken from a named tuple in atomic increments and decrements, some 60 per call of the
#: contact loop, which cost 4.5 us per call on these machines (more than all the work of a
#: 16-disk step). Numba refuses to compile an allocation in such a kernel.
KERNEL = dict(JIT, _nrt=False)
