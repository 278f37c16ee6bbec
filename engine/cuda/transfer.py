"""Arrays sent to the device and brought back (on numba's simulator, copies in this memory), counted."""

from __future__ import annotations

import numpy as np

from . import numba_cuda, simulated

CROSSED = {"to_device": 0, "to_host": 0}
"""Bytes of arrays sent to the device and brought back by runs on it, since the process started (the bench and
the tests read it)."""


def to_device(array: np.ndarray):
    """A copy of ``array`` on the device (the simulator's device is this memory: a copy of its own)."""
    array = np.ascontiguousarray(array)
    CROSSED["to_device"] += array.nbytes
    return array.copy() if simulated() else numba_cuda().to_device(array)


def to_host(device, host: np.ndarray) -> None:
    CROSSED["to_host"] += host.nbytes
    if simulated():
        host[...] = device
    elif host.flags.c_contiguous:
        device.copy_to_host(host)
    else:
        host[...] = device.copy_to_host()


def on_host(device) -> np.ndarray:
    """A host copy of a device array."""
    CROSSED["to_host"] += device.nbytes
    return np.array(device) if simulated() else device.copy_to_host()


def copied(device):
    """A copy on the device of a device array."""
    if simulated():
        return device.copy()
    copy = numba_cuda().device_array_like(device)
    copy.copy_to_device(device)
    return copy


def rows_to_device(array: np.ndarray, rows: int):
    """A device array of ``array``'s shape holding its first ``rows`` rows (the others never read before written)."""
    CROSSED["to_device"] += array[:rows].nbytes
    if simulated():
        device = np.zeros_like(array)
        device[:rows] = array[:rows]
        return device
    device = numba_cuda().device_array(array.shape, array.dtype)
    if rows:
        device[:rows].copy_to_device(np.ascontiguousarray(array[:rows]))
    return device


def device_scratch(shape, dtype=np.float64):
    """An array on the device whose values the kernels write before they read them: nothing is sent."""
    return np.zeros(shape, dtype) if simulated() else numba_cuda().device_array(shape, dtype)
