"""Numba kernels: pure ``@njit(nogil=True, cache=True)`` functions over arrays.

Kernels take arrays (bundled in the named tuples of :mod:`engine.state`) and
scalars only; every parameter a slider can change is a runtime argument.
Inside a ``prange`` loop a kernel touches only local names: numba loses writes
made through a named tuple's attribute there.
"""
