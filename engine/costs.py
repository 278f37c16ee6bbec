"""What a command will take, said and checked before it starts: memory for its disks, disk room
for its run file, its number of steps. What this machine cannot hold is refused in one line with
the figures; what it can is said on standard error when it is large, so a long start is never silent.
"""

from __future__ import annotations

import os
import resource
from pathlib import Path

from .errors import GranLabError

MEMORY_PER_DISK = 1800
"""Bytes a simulation holds per disk at most: its state and tables (1449 bytes a disk, measured by
``granlab.engine.bench.state_bytes`` on lattices of 9·10⁴ and 10⁶ disks, touching or not), the
scene's own copy of the disks and a frame being written. A 4·10⁶-disk run peaked at 2.25 GB
resident: its contact table's spare room is reserved, not yet touched."""
MEMORY_BASE = 600 * 2 ** 20
"""What Python, numpy, numba and h5py hold before a simulation (528 MB of address space measured)."""
MAX_STEPS = 10 ** 12
"""The most steps a run may take: beyond, the step count and t = step · dt lose whole steps to
rounding long before it could end (10¹² steps of one disk alone take about a day here)."""
ANNOUNCE_BYTES = 2 ** 30
"""A run whose memory or run file may reach this says what it will take before it starts."""


class CostError(GranLabError, MemoryError):
    """A command that would need more memory, disk room or steps than it may have."""


def size(count: float) -> str:
    """``count`` bytes for a person: ``2.3 GB``, ``410 MB``, ``12 kB``."""
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if count >= scale:
            return f"{count / scale:.2g} {unit}" if count < 10 * scale else f"{count / scale:.0f} {unit}"
    return f"{count:.0f} bytes"


def duration(seconds: float) -> str:
    """``seconds`` for a person: ``40 s``, ``12 min``, ``3.5 h``, ``9 days``."""
    for unit, scale in (("days", 86400), ("h", 3600), ("min", 60)):
        if seconds >= 2 * scale:
            return f"{seconds / scale:.2g} {unit}" if seconds < 10 * scale else f"{seconds / scale:.0f} {unit}"
    return f"{seconds:.0f} s"


def memory_room() -> int:
    """Bytes this process may still take: the memory the system has available, or less under an
    address-space limit (``ulimit -v``)."""
    room = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    try:
        with open("/proc/meminfo") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    room = int(line.split()[1]) * 1024  # the page cache it may reclaim counts too
    except OSError:
        pass
    limit = resource.getrlimit(resource.RLIMIT_AS)[0]
    if limit != resource.RLIM_INFINITY:
        try:
            with open("/proc/self/statm") as statm:
                used = int(statm.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
        except OSError:
            used = MEMORY_BASE
        room = min(room, limit - used)
    return room


def simulation_memory(disks: int) -> int:
    return MEMORY_PER_DISK * disks


def check_memory(disks: int, what: str) -> int:
    """The memory a simulation of ``disks`` disks takes, refused beyond what this process may take."""
    need, room = simulation_memory(disks), memory_room()
    if need > room:
        raise CostError(f"{what}: {disks} disks need about {size(need)} of memory ({MEMORY_PER_DISK} bytes a disk); "
                        f"{size(max(room, 0))} is free to this process: use fewer disks")
    return need


def check_steps(steps: float, what: str, dt: float) -> int:
    """A step count that is finite and at most :data:`MAX_STEPS`, as an integer."""
    if not steps <= MAX_STEPS:  # NaN and inf too
        raise CostError(f"{what} is not allowed: {steps:.4g} steps of dt = {dt:.4g}, at most {MAX_STEPS:.0e} "
                        f"(a shorter run, or a larger time step: a lower stiffness or a higher mass)")
    return int(steps)


FRAME_BYTES_PER_DISK = 200
"""A frame of a run file, per disk: its six elements (64 bytes) and two contacts' rows (67 bytes each)."""
CHECKPOINT_BYTES_PER_DISK = 310
"""A checkpoint, per disk (302 bytes measured on lattices of 9·10⁴ and 10⁶ touching disks)."""


def run_files_bytes(files: int, frames: int, disks: int) -> int:
    """Up to how many bytes ``files`` run files of ``frames`` frames of ``disks`` disks take (two
    checkpoint slots and HDF5's metadata each)."""
    return files * (frames * (FRAME_BYTES_PER_DISK * disks + 2 ** 12) + 2 * CHECKPOINT_BYTES_PER_DISK * disks + 2 ** 20)


def free_bytes(folder) -> int:
    """Room left for files in ``folder`` (its nearest existing parent)."""
    folder = Path(folder).absolute()
    while not folder.exists():
        folder = folder.parent
    status = os.statvfs(folder)
    return status.f_bavail * status.f_frsize


def room_for_one_file(folder) -> int:
    """The largest file that may be written into ``folder``: its free bytes, or less under a file
    size limit (``ulimit -f``)."""
    limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    return min(free_bytes(folder), limit) if limit != resource.RLIM_INFINITY else free_bytes(folder)


def check_disk(need: int, folder, what: str, fewer: str = "fewer samples, cycles or frames") -> None:
    """Refuse ``need`` bytes of files in ``folder`` (its nearest existing parent) beyond its free room,
    saying what ``fewer`` of would take less."""
    room = room_for_one_file(folder)
    if need > room:
        raise CostError(f"{what} need up to {size(need)}; {size(room)} free there: {fewer}, or another disk")
