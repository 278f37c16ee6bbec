"""The samples of a batch on the device, a block each (``samples_in_blocks``): which they are, their rows in
segments of the contact table, and their sums and flags split from the whole system's and joined back.

A batch's samples are the parts its walls' reach cuts it into (:attr:`granlab.engine.params.Wall.disks`,
:class:`~granlab.engine.batch.Batch`): each with its disks, its walls and the contact rows of its disks
(consecutive: the table is built disk by disk). On the device each sample's rows lie in a segment of their own
of ``capacity`` rows, so that a block rebuilds its sample's rows without moving another's, and the blocks
never wait for one another. On the CPU the walls' reactions, the energy tallies, the disks' sums, the flags and
the cell are the whole system's; a block keeps its own (:class:`~granlab.engine.cuda.layout.Samples`), and
:func:`join` adds them up again when the call ends.
"""

from __future__ import annotations

import numpy as np

from ..kernels.contacts import TALLY_SIZE
from ..kernels.integrate import (FLAG_REBUILD, G_BAD, G_DISPLACEMENT, G_MOVER, G_STEP_MOVE, INFO_MAX_OVERLAP,
                                 INFO_OVERLAPPING, INFO_REBUILDS)
from ..state import CELL_NONE, CellArrays, ContactArrays
from .layout import R_DISKS, R_ROWS, R_WALLS, RUN_SIZE, Samples

SAMPLE_DISKS = 256
"""The most disks a sample of a batch may have to be stepped by a block of its own: the block rebuilds its rows
by testing every pair, on one thread."""

SPLIT = ("virial_correction", "lagged_virial", "lagged_kinetic", "length_reference", "scale", "gather", "flags",
         "energy", "info")
"""The workspace's arrays each sample keeps its own copy of."""

SUMMED = ("virial_correction", "lagged_virial", "lagged_kinetic", "energy")
"""Of those, the ones whose whole-system value is the samples' sum (the energy: sample 0 starts with the
system's, the others with nothing)."""


def batch_ranges(w, cell, ct, n: int) -> np.ndarray | None:
    """``(samples, 6)``: each sample's rows, disks and walls (first, past the last) if the walls' reach cuts the
    disks into two or more consecutive parts of at most :data:`SAMPLE_DISKS` disks, each with its own
    consecutive walls, no periodic axis and no row joining two parts; else ``None``."""
    reach = np.asarray(w.reach)
    if reach.shape[0] == 0 or np.any(np.asarray(cell.control) != CELL_NONE):
        return None
    starts = [0] + [m for m in range(1, reach.shape[0]) if not np.array_equal(reach[m], reach[m - 1])]
    disks = np.array([reach[m] for m in starts])
    if len(starts) < 2 or disks[0, 0] != 0 or disks[-1, 1] != n or np.any(disks[1:, 0] != disks[:-1, 1]) \
            or np.max(disks[:, 1] - disks[:, 0]) > SAMPLE_DISKS or len({tuple(d) for d in disks}) != len(starts):
        return None
    rows = int(ct.count[0])
    i = np.asarray(ct.particle_i[:rows])
    j = np.asarray(ct.particle_j[:rows])
    first_disks = np.append(disks[:, 0], n)
    if np.any(np.diff(i) < 0):
        return None
    disk_rows = j < n
    if np.any(np.searchsorted(first_disks, i[disk_rows], side="right")
              != np.searchsorted(first_disks, j[disk_rows], side="right")):
        return None
    first_rows = np.searchsorted(i, first_disks)
    first_walls = np.array(starts + [reach.shape[0]], np.int64)
    return np.column_stack([first_rows[:-1], first_rows[1:], disks, first_walls[:-1], first_walls[1:]]).astype(np.int64)


def segment_capacity(ranges: np.ndarray) -> int:
    """Rows of each sample's segment: as a simulation's table, 8 a disk and 64 more, for the largest sample."""
    return int(8 * np.max(ranges[:, R_DISKS + 1] - ranges[:, R_DISKS]) + 64)


def segmented(ct, ranges: np.ndarray, capacity: int) -> tuple[ContactArrays, np.ndarray]:
    """The table's rows, each sample's moved to a segment of its own (``capacity`` rows, sample ``b`` from row
    ``b capacity``), and the ranges with those rows and the segments' size (``R_SEGMENT``)."""
    count = ranges.shape[0]
    arrays = {}
    for name in ContactArrays._fields:
        if name == "count":
            arrays[name] = np.zeros(1, np.int64)
            continue
        whole = np.asarray(getattr(ct, name))
        arrays[name] = np.zeros((count * capacity,) + whole.shape[1:], whole.dtype)
        for b, (lo, hi) in enumerate(ranges[:, R_ROWS:R_ROWS + 2]):
            arrays[name][b * capacity:b * capacity + hi - lo] = whole[lo:hi]
    moved = np.column_stack([ranges, np.full(count, capacity, np.int64)])
    moved[:, R_ROWS] = np.arange(count) * capacity
    moved[:, R_ROWS + 1] = moved[:, R_ROWS] + ranges[:, R_ROWS + 1] - ranges[:, R_ROWS]
    return ContactArrays(**arrays), moved


def compact(segments: ContactArrays, ranges: np.ndarray, ct) -> None:
    """The segments' rows back in the host's table ``ct``, one sample after another."""
    row = 0
    for lo, hi in ranges[:, R_ROWS:R_ROWS + 2]:
        for name in ContactArrays._fields:
            if name != "count":
                getattr(ct, name)[row:row + hi - lo] = getattr(segments, name)[lo:hi]
        row += hi - lo
    ct.count[0] = row


def rows_needed(ranges: np.ndarray) -> int:
    """The rows of every sample together."""
    return int(np.sum(ranges[:, R_ROWS + 1] - ranges[:, R_ROWS]))


def split(ranges: np.ndarray, length_ref: np.ndarray, workspace: dict, cell: dict) -> Samples:
    """Each sample's own arrays (on the host), from the whole system's ``workspace`` arrays (those of
    :data:`SPLIT`) and ``cell`` arrays, at the start of a call."""
    count = ranges.shape[0]

    def each(value):
        return np.repeat(np.asarray(value)[None], count, axis=0)

    own = {name: each(workspace[name]) for name in SPLIT}
    own["energy"][1:] = 0.0
    own["info"][1:, INFO_REBUILDS] = 0.0
    local = np.array(length_ref, np.int64)
    for lo, hi in ranges[:, R_WALLS:R_WALLS + 2]:
        part = local[lo:hi]
        part[part >= 0] -= lo
    return Samples(ranges=ranges, run=np.zeros((count, RUN_SIZE), np.int64), length_ref=local,
                   tally_buffer=np.zeros((count, 1, TALLY_SIZE)),
                   cell=CellArrays(*(each(cell[name]) for name in CellArrays._fields)), **own)


def join(own: Samples, failed: int | None) -> tuple[dict, dict]:
    """The whole system's workspace arrays (:data:`SPLIT`) and cell arrays from the samples' (on the host):
    sums added, the largest displacement, overlap and step kept, a rebuild flagged if any sample flags one; the
    disks' sums and the call's information of sample ``failed`` if one failed (its reason the call's)."""
    workspace = {name: total(getattr(own, name)) if name in SUMMED else getattr(own, name)[0].copy()
                 for name in SPLIT}
    gather, info = workspace["gather"], workspace["info"]
    if failed is not None:
        gather[...] = own.gather[failed]
        info[...] = own.info[failed]
    else:
        fastest = int(np.argmax(own.gather[:, G_STEP_MOVE]))
        gather[...] = total(own.gather)
        gather[G_DISPLACEMENT] = own.gather[:, G_DISPLACEMENT].max()
        gather[G_BAD] = own.gather[:, G_BAD].sum()
        gather[G_STEP_MOVE] = own.gather[fastest, G_STEP_MOVE]
        gather[G_MOVER] = own.gather[fastest, G_MOVER]
        info[INFO_OVERLAPPING] = own.info[:, INFO_OVERLAPPING].sum()
        info[INFO_MAX_OVERLAP] = own.info[:, INFO_MAX_OVERLAP].max()
    info[INFO_REBUILDS] = own.info[:, INFO_REBUILDS].sum()
    workspace["flags"][FLAG_REBUILD] = own.flags[:, FLAG_REBUILD].max()
    cell = {name: getattr(own.cell, name)[0].copy() for name in CellArrays._fields}
    for name in ("virial", "kinetic"):
        cell[name] = total(getattr(own.cell, name))
    return workspace, cell


def total(values: np.ndarray) -> np.ndarray:
    """The samples' values added, in sample order."""
    added = values[0].copy()
    for value in values[1:]:
        added += value
    return added
