"""What the device's kernels and the host agree on: block size, the call's state, the run's numbers."""

import math
from collections import namedtuple

from . import simulated

THREADS = 8 if simulated() else 128
"""Threads a block (the simulator runs a Python thread for each: its blocks are small)."""


def blocks(count: int) -> int:
    """Blocks of :data:`THREADS` threads for ``count`` threads (one at least)."""
    return max(1, math.ceil(count / THREADS))

RUN_STOP, RUN_CODE, RUN_STEP = range(3)
RUN_SIZE = 3

# the run's numbers (``Device.numbers``) and whole numbers (``Device.counts``)
N_DT, N_TIME_ORIGIN, N_SKIN, N_MAX_OVERLAP = range(4)
C_NORMAL_MODEL, C_HAS_LOADS, C_STEP_OFFSET, C_N_STEPS = range(4)

START, STEP = 0, 1
"""What a pass over the disks does: a call's first half kick and drift, or a step's."""

Device = namedtuple("Device", "law gravity numbers counts run block_tallies block_gather")
"""What the kernels read besides the state: the law's slots, gravity, the run's numbers and counts,
the call's state (``RUN_*``) and the blocks' sums."""

R_ROWS, R_DISKS, R_WALLS, R_SEGMENT = 0, 2, 4, 6
"""Columns of ``Samples.ranges``: each sample's first and past-the-last row, disk and wall, and the rows of its
segment of the contact table."""

Samples = namedtuple("Samples", "ranges run length_ref tally_buffer virial_correction lagged_virial lagged_kinetic "
                                "length_reference scale gather flags energy info cell")
"""What ``samples_in_blocks`` keeps a sample each (a leading axis of samples): its ranges, its call's state
(``RUN_*``), its walls' ``length_ref`` counted from its first wall, the workspace's sums and flags that are
the whole system's on the CPU, and the cell's arrays (a ``CellArrays``)."""
