"""The contact table rebuilt on the device, the state staying there: the CPU engine's table, row for row.

The CPU's :func:`granlab.engine.kernels.integrate.rebuild` wraps the disks into the cell, bins them in a grid
of cells, walks each disk's cell and the eight around it, and carries each old row's history to the new row of
the same pair and image. The device does the same with the same functions (:func:`~granlab.engine.kernels.
neighbours.wrap_disk`, :func:`~granlab.engine.kernels.neighbours.fit_grid`, :func:`~granlab.engine.kernels.
neighbours.cell_of_disk`, :func:`~granlab.engine.kernels.neighbours.disk_rows`, :func:`~granlab.engine.kernels.
neighbours.row_history`), a thread a disk or a row:

1. each disk wrapped, the grid's bounds by atomic minimum and maximum, the grid fitted by one thread;
2. the disks binned (atomic counts, a scan, atomic places), each cell's disks sorted by number (as the CPU's
   lists hold them);
3. each disk's rows counted, a scan gives each disk its first row, each disk's rows written there;
4. each new row's history found among the old rows of its disk; the rows, positions and references committed.

The rows come in the CPU's order, disk by disk, each disk's in the same order: the tables are equal. The host
reads two numbers a rebuild (its code and the rows, to size the next launches) and nothing else.
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import int64

from . import numba_cuda
from ..kernels.integrate import CODE_LOST_CONTACT, CODE_OK, CODE_OVERFLOW, INFO_LOST, INFO_NEEDED, \
    rebuilt_boundaries, rebuilt_disks
from ..kernels.laws import touching
from ..kernels.neighbours import MAX_CELLS_PER_PARTICLE, cell_of_disk, copy_row, disk_rows, fit_grid, row_history, \
    wrap_disk
from ..state import CELL_NONE, ContactArrays
from .layout import THREADS, blocks
from .transfer import device_scratch, on_host

cuda = numba_cuda()

SCAN_PER_THREAD = 8
"""Values a thread adds up in a scan's tile (a tile: ``THREADS`` threads' worth)."""

TILE = THREADS * SCAN_PER_THREAD

RESULT_CODE, RESULT_ROWS = 0, 1
MATCHED, ACTIVE = 0, 1


@cuda.jit
def _scan_tiles(values, sums):
    """Each block's tile of ``values`` replaced by its running sum; the tile's sum into ``sums``."""
    tid = cuda.threadIdx.x
    totals = cuda.shared.array(THREADS, int64)
    first = cuda.blockIdx.x * TILE + tid * SCAN_PER_THREAD
    stop = min(first + SCAN_PER_THREAD, values.shape[0])
    running = 0
    for k in range(first, stop):
        running += values[k]
        values[k] = running
    totals[tid] = running
    offset = 1
    while offset < THREADS:  # the threads' totals scanned in the block (Hillis and Steele)
        cuda.syncthreads()
        before = totals[tid - offset] if tid >= offset else 0
        cuda.syncthreads()
        totals[tid] += before
        offset *= 2
    cuda.syncthreads()
    below = totals[tid - 1] if tid > 0 else 0
    for k in range(first, stop):
        values[k] += below
    if tid == THREADS - 1:
        sums[cuda.blockIdx.x] = totals[tid]


@cuda.jit
def _add_tiles(values, sums):
    """Each tile after the first raised by the sum of the tiles before it (``sums`` scanned)."""
    k = cuda.grid(1)
    tile = k // TILE
    if tile > 0 and k < values.shape[0]:
        values[k] += sums[tile - 1]


def running_sum(values) -> None:
    """``values`` (int64, on the device) replaced by its running (inclusive) sum: tiles scanned a block each,
    their sums scanned the same way, each tile raised by those before it."""
    tiles = math.ceil(values.shape[0] / TILE)
    sums = device_scratch(tiles, np.int64)  # each tile writes its sum
    _scan_tiles[tiles, THREADS](values, sums)
    if tiles > 1:
        running_sum(sums)
        _add_tiles[blocks(values.shape[0]), THREADS](values, sums)


@cuda.jit
def _reset(bounds, tally):
    """The bounds at nothing yet seen, the tally at zero (one thread)."""
    for a in range(2):
        bounds[a, 0] = math.inf
        bounds[a, 1] = -math.inf
        tally[a] = 0


@cuda.jit
def _clear(values):
    k = cuda.grid(1)
    if k < values.shape[0]:
        values[k] = 0


@cuda.jit
def _wrap_and_bound(p, cell, ws, lists):
    i = cuda.grid(1)
    if i < p.position.shape[0]:
        periodic = (cell.control[0] != CELL_NONE, cell.control[1] != CELL_NONE)
        wrap_disk(p.position, i, cell.length, periodic, ws.wrapped, ws.wraps)
        for a in range(2):
            cuda.atomic.min(lists.bounds, (a, 0), ws.wrapped[i, a])
            cuda.atomic.max(lists.bounds, (a, 1), ws.wrapped[i, a])


@cuda.jit
def _fit(cell, cell_size, n, lists):
    periodic = (cell.control[0] != CELL_NONE, cell.control[1] != CELL_NONE)
    fit_grid(lists.bounds, cell.length, periodic, cell_size, n, lists.origin, lists.cells, lists.width)


@cuda.jit
def _bin(ws, lists):
    i = cuda.grid(1)
    if i < ws.wrapped.shape[0]:
        c = cell_of_disk(ws.wrapped, i, lists.origin, lists.cells, lists.width)
        lists.cell_of[i] = c
        cuda.atomic.add(lists.start, c + 1, 1)


@cuda.jit
def _place(lists):
    i = cuda.grid(1)
    if i < lists.cell_of.shape[0]:
        c = lists.cell_of[i]
        lists.items[lists.start[c] + cuda.atomic.add(lists.filled, c, 1)] = i


@cuda.jit
def _sort_cells(lists):
    """Each cell's disks in the order of their numbers (placed in any order by the atomic places)."""
    c = cuda.grid(1)
    start, items = lists.start, lists.items
    if c < lists.cells[0] * lists.cells[1]:
        for k in range(start[c] + 1, start[c + 1]):
            disk = items[k]
            m = k
            while m > start[c] and items[m - 1] > disk:
                items[m] = items[m - 1]
                m -= 1
            items[m] = disk


@cuda.jit
def _disk_rows(p, w, cell, ws, extra, lists, new, write):
    """Disk ``i``'s rows: counted into ``row_start[i + 1]``, or (``write``) written from ``row_start[i]`` on."""
    i = cuda.grid(1)
    if i < p.position.shape[0]:
        periodic = (cell.control[0] != CELL_NONE, cell.control[1] != CELL_NONE)
        first_row = lists.row_start[i] if write else 0
        capacity = new.particle_i.shape[0] if write else 0
        rows = disk_rows(i, ws.wrapped, p.radius, p.inv_mass, cell.length, periodic, w.normal, w.offset, w.reach,
                         extra, lists.cell_of, lists.cells, lists.start, lists.items, new, first_row, capacity)
        if not write:
            lists.row_start[i + 1] = rows


@cuda.jit
def _first_rows(old, n, lists):
    """``first[i]``: the first row of disk ``i`` in the old table (its rows consecutive), ``first[n]`` its
    rows; a thread a row, each writing the disks from the one after the previous row's to its own."""
    k = cuda.grid(1)
    count = old.count[0]
    first = lists.first
    if k < count:
        lo = old.particle_i[k - 1] + 1 if k > 0 else 0
        for i in range(lo, old.particle_i[k] + 1):
            first[i] = k
        if k == count - 1:
            for i in range(old.particle_i[k] + 1, n + 1):
                first[i] = count
    elif k == 0:
        for i in range(n + 1):
            first[i] = 0


@cuda.jit
def _history(old, new, ws, cell, w, lists):
    """Row ``k`` of the new table takes its history (:func:`row_history`); the touching rows found, and the old
    table's touching rows, counted into ``tally``."""
    k = cuda.grid(1)
    n = ws.wraps.shape[0]
    rows = lists.row_start[n]
    if k < rows and rows <= new.particle_i.shape[0]:
        if row_history(old, lists.first, new, k, ws.wraps, cell.length, w.normal, n):
            cuda.atomic.add(lists.tally, MATCHED, 1)
    if k < old.count[0] and touching(old.status[k]):
        cuda.atomic.add(lists.tally, ACTIVE, 1)


@cuda.jit
def _commit(p, w, cell, ct, new, ws, lists):
    """The new rows into ``ct``, the disks at their wrapped positions, the references at the state rebuilt; or
    why not (``result``: its code and the rows): the table too small, a touching contact left out."""
    k = cuda.grid(1)
    n = p.position.shape[0]
    rows = lists.row_start[n]
    lost = lists.tally[ACTIVE] - lists.tally[MATCHED]
    result = lists.result
    if rows > new.particle_i.shape[0] or lost > 0:
        if k == 0:
            result[RESULT_ROWS] = rows
            if rows > new.particle_i.shape[0]:
                ws.info[INFO_NEEDED] = rows
                result[RESULT_CODE] = CODE_OVERFLOW
            else:
                ws.info[INFO_LOST] = lost
                result[RESULT_CODE] = CODE_LOST_CONTACT
        return
    if k < rows:
        copy_row(new, k, ct, k)
    rebuilt_disks(p, ws, k, min(k + 1, n))
    if k == 0:
        ct.count[0] = rows
        rebuilt_boundaries(w, cell, ws)
        result[RESULT_CODE] = CODE_OK
        result[RESULT_ROWS] = rows



Lists = namedtuple("Lists", "bounds origin cells width cell_of start filled items row_start first tally result")
"""A rebuild's scratch on the device: the grid's bounds, origin, cells and cell width; each disk's cell, the
cells' first places (``start``) and places filled, the disks by cell (``items``); each disk's first new row
(``row_start``) and first old row (``first``); the touching rows matched and present (``tally``); the rebuild's
code and rows (``result``)."""


class DeviceTable:
    """Rebuilds the contact table of a run's state on the device (``state``: its arrays there, the stepper's
    ``DeviceState``), into a spare table of the same capacity; made at the state's first rebuild, it goes with the
    state (its scratch made once, not at each rebuild)."""

    def __init__(self, state, radius: np.ndarray, extra: float):
        n = radius.shape[0]
        self.n = n
        self.extra = extra
        self.cell_size = 2.0 * float(radius.max()) + extra
        cells = max(16, MAX_CELLS_PER_PARTICLE * n)
        # nothing is sent: every array is cleared or written on the device before it is read
        self.spare = ContactArrays(*(device_scratch(a.shape, a.dtype) for a in state.host[3]))
        whole = np.int64
        self.lists = Lists(bounds=device_scratch((2, 2)), origin=device_scratch(2), cells=device_scratch(2, whole),
                           width=device_scratch(2), cell_of=device_scratch(n, whole),
                           start=device_scratch(cells + 1, whole), filled=device_scratch(cells, whole),
                           items=device_scratch(n, whole), row_start=device_scratch(n + 1, whole),
                           first=device_scratch(n + 1, whole), tally=device_scratch(2, whole),
                           result=device_scratch(2, whole))

    def rebuild(self, state) -> tuple[int, int]:
        """The table of ``state`` rebuilt: ``(code, rows)``."""
        n, disk_blocks, lists = self.n, blocks(self.n), self.lists
        _reset[1, 1](lists.bounds, lists.tally)
        for array in (lists.start, lists.filled, lists.row_start):
            _clear[blocks(array.shape[0]), THREADS](array)
        _wrap_and_bound[disk_blocks, THREADS](state.p, state.cell, state.ws, lists)
        _fit[1, 1](state.cell, self.cell_size, n, lists)
        _bin[disk_blocks, THREADS](state.ws, lists)
        running_sum(lists.start)
        _place[disk_blocks, THREADS](lists)
        _sort_cells[blocks(lists.filled.shape[0]), THREADS](lists)
        _disk_rows[disk_blocks, THREADS](state.p, state.w, state.cell, state.ws, self.extra, lists, self.spare, False)
        running_sum(lists.row_start)
        _disk_rows[disk_blocks, THREADS](state.p, state.w, state.cell, state.ws, self.extra, lists, self.spare, True)
        capacity = self.spare.particle_i.shape[0]  # the old table's too: enough threads for either's rows
        _first_rows[blocks(capacity), THREADS](state.ct, n, lists)
        _history[blocks(capacity), THREADS](state.ct, self.spare, state.ws, state.cell, state.w, lists)
        _commit[blocks(max(capacity, n)), THREADS](state.p, state.w, state.cell, state.ct, self.spare, state.ws,
                                                    lists)
        result = on_host(lists.result)
        return int(result[RESULT_CODE]), int(result[RESULT_ROWS])
