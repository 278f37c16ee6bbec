"""Numba kernels: pure ``@njit(nogil=True, cache=True)`` functions over arrays.

Kernels take arrays (bundled in the named tuples of :mod:`granlab.engine.state`) and
scalars only; every parameter a slider can change is a runtime argument.
Parallel kernels are thin ``prange`` wrappers around serial chunk functions, used only
when more than one numba thread is asked for: a parallel launch takes the GIL, so a
single-threaded run (the lab's engine thread, a study worker) never waits for Python.
Inside a ``prange`` loop, write through local names or pass the named tuples on to a
function: numba loses writes made through a named tuple's attribute in the loop body.
"""
