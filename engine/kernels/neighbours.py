"""Neighbour search: a cell list with a Verlet skin, periodic images, and history transfer.

:func:`build_table` fills a fresh contact table with every pair (i < j, any periodic
image) and every disk-wall pair (of a wall's reach) closer than the interaction range plus ``extra``
(the cohesion range D0 plus the skin), copies the history of pairs that were
already in the old table, and reports whether any interacting contact was lost.
It never writes past the capacity: it returns the number of rows it needs.

Its pieces, a disk wrapped (:func:`wrap_disk`), the grid (:func:`fit_grid`), a disk's cell
(:func:`cell_of_disk`), a disk's rows (:func:`disk_rows`) and a row's history (:func:`row_history`), are
the device's too: :mod:`granlab.engine.cuda.neighbours` runs them a thread a disk or a row.
"""

import math

import numpy as np

from ..state import STATUS_NONE
from .jit import JIT, KERNEL, njit
from .laws import root_reduced_mass, touching
from .packing import neighbour_cell

MAX_CELLS_PER_PARTICLE = 4


@njit(**JIT)
def wrap_positions(position, length, periodic, wrapped, wraps):
    """Positions brought into the cell ``[0, L)`` along periodic axes, with the image counts."""
    for i in range(position.shape[0]):
        wrap_disk(position, i, length, periodic, wrapped, wraps)


@njit(**JIT)
def wrap_disk(position, i, length, periodic, wrapped, wraps):
    """Disk ``i``'s position brought into the cell along periodic axes (``wrapped[i]``), with its image counts
    (``wraps[i]``)."""
    for a in range(2):
        x = position[i, a]
        if periodic[a]:
            w = math.floor(x / length[a])
            xw = x - w * length[a]
            if xw >= length[a]:
                xw -= length[a]
                w += 1
            wraps[i, a] = w
            wrapped[i, a] = xw
        else:
            wraps[i, a] = 0
            wrapped[i, a] = x


@njit(**JIT)
def _grid(wrapped, length, periodic, cell_size, n):
    """Cell grid: origin, number of cells and cell width per axis (:func:`fit_grid`)."""
    bounds = np.zeros((2, 2))
    for a in range(2):
        if not periodic[a]:
            bounds[a, 0] = wrapped[0, a]
            bounds[a, 1] = wrapped[0, a]
            for i in range(n):
                bounds[a, 0] = min(bounds[a, 0], wrapped[i, a])
                bounds[a, 1] = max(bounds[a, 1], wrapped[i, a])
    origin = np.zeros(2)
    cells = np.ones(2, dtype=np.int64)
    width = np.zeros(2)
    fit_grid(bounds, length, periodic, cell_size, n, origin, cells, width)
    return origin, cells, width


@njit(**JIT)
def fit_grid(bounds, length, periodic, cell_size, n, origin, cells, width):
    """The cell grid over the disks' ``bounds`` (``[axis, lowest/highest]`` of the wrapped positions; the cell
    along a periodic axis): its ``origin``, number of ``cells`` and cell ``width`` per axis, cells at least
    ``cell_size`` wide and at most ~4 a disk."""
    extent0 = 0.0
    extent1 = 0.0
    for a in range(2):
        if periodic[a]:
            origin[a] = 0.0
            extent = length[a]
        else:
            lo = bounds[a, 0]
            hi = bounds[a, 1]
            origin[a] = lo - 1e-9 * (1.0 + abs(lo))
            extent = hi - origin[a] + 1e-9 * (1.0 + abs(hi))
        cells[a] = max(1, int(extent / cell_size))
        if a == 0:
            extent0 = extent
        else:
            extent1 = extent
    limit = max(16, MAX_CELLS_PER_PARTICLE * n)
    while cells[0] * cells[1] > limit:
        for a in range(2):
            cells[a] = max(1, cells[a] // 2)
    width[0] = extent0 / cells[0]
    width[1] = extent1 / cells[1]


@njit(**JIT)
def cell_of_disk(wrapped, i, origin, cells, width):
    """The cell of the grid holding disk ``i`` (row by row; a disk on the grid's edge in its last cell)."""
    cx = min(cells[0] - 1, max(0, int((wrapped[i, 0] - origin[0]) / width[0])))
    cy = min(cells[1] - 1, max(0, int((wrapped[i, 1] - origin[1]) / width[1])))
    return cy * cells[0] + cx


@njit(**JIT)
def _cell_lists(wrapped, origin, cells, width):
    """The disks binned by cell: each disk's cell, and ``items[start[c]:start[c + 1]]`` the disks of cell ``c``
    (in the order of their numbers)."""
    n = wrapped.shape[0]
    cell_of = np.empty(n, dtype=np.int64)
    start = np.zeros(cells[0] * cells[1] + 1, dtype=np.int64)
    for i in range(n):
        cell_of[i] = cell_of_disk(wrapped, i, origin, cells, width)
        start[cell_of[i] + 1] += 1
    for c in range(cells[0] * cells[1]):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    items = np.empty(n, dtype=np.int64)
    for i in range(n):
        items[fill[cell_of[i]]] = i
        fill[cell_of[i]] += 1
    return cell_of, start, items


@njit(**JIT)
def build_table(position, radius, inv_mass, length, periodic, wall_normal, wall_offset, wall_reach, extra,
                old, new, wrapped, wraps):
    """Build the candidate-pair table ``new`` and carry over the history of ``old``.

    Arguments: ``position (N, 2)``, ``radius (N,)``, ``inv_mass (N,)``, cell ``length (2,)``, ``periodic``
    (two booleans), ``wall_normal (nw, 2)``, ``wall_offset (nw,)``, ``wall_reach (nw, 2)`` (the disks
    ``first`` to ``stop - 1`` a wall meets), ``extra`` (D0 + skin),
    ``old``/``new`` contact tables (``ContactArrays``), scratch ``wrapped (N, 2)`` and
    ``wraps (N, 2)`` filled with the wrapped positions and image counts.

    Returns ``(needed, lost)``: the rows needed (larger than the capacity means nothing
    was committed) and the number of touching old contacts that found no new row.
    A pair interacts when ``|r_ij| < r_i + r_j + extra``; a disk and a wall when the gap
    is below ``extra``.
    """
    n = position.shape[0]
    wrap_positions(position, length, periodic, wrapped, wraps)
    origin, cells, width = _grid(wrapped, length, periodic, 2.0 * radius.max() + extra, n)
    cell_of, start, items = _cell_lists(wrapped, origin, cells, width)
    capacity = new.particle_i.shape[0]
    count = _table_rows(wrapped, radius, inv_mass, length, periodic, wall_normal, wall_offset, wall_reach, extra,
                        cell_of, cells, start, items, new, capacity)
    if count > capacity:
        return count, 0
    new.count[0] = count
    lost = _transfer_history(old, new, wraps, length, wall_normal, n)
    return count, lost


@njit(**KERNEL)
def _table_rows(wrapped, radius, inv_mass, length, periodic, wall_normal, wall_offset, wall_reach, extra, cell_of,
                cells, start, items, new, capacity):
    """Every disk's rows (:func:`disk_rows`), one disk after another: the rows needed. Without reference counts
    (``KERNEL``), into which :func:`disk_rows` is inlined: called a disk at a time from a function that counts
    them, each of its arrays taken from ``new`` is counted, and the rebuild took 1.7 times as long."""
    count = 0
    for i in range(wrapped.shape[0]):
        count += disk_rows(i, wrapped, radius, inv_mass, length, periodic, wall_normal, wall_offset, wall_reach, extra,
                           cell_of, cells, start, items, new, count, capacity)
    return count


@njit(**JIT, inline="always")
def disk_rows(i, wrapped, radius, inv_mass, length, periodic, wall_normal, wall_offset, wall_reach, extra, cell_of,
              cells, start, items, new, first_row, capacity):
    """Disk ``i``'s rows of the table ``new`` from row ``first_row`` on: every disk ``j > i`` (any periodic image)
    in its cell and the eight around it, then every wall of its reach, closer than ``extra``; a row is written
    only below ``capacity``. Returns the number of rows."""
    n = wrapped.shape[0]
    count = 0
    cx = cell_of[i] % cells[0]
    cy = cell_of[i] // cells[0]
    for oy in range(-1, 2):
        inside_y, gy, sy = neighbour_cell(cy + oy, cells[1], periodic[1])
        for ox in range(-1, 2):
            inside_x, gx, sx = neighbour_cell(cx + ox, cells[0], periodic[0])
            if inside_x and inside_y:
                c = gy * cells[0] + gx
                for k in range(start[c], start[c + 1]):
                    j = items[k]
                    if j <= i:
                        continue
                    rx = wrapped[i, 0] - wrapped[j, 0] - sx * length[0]
                    ry = wrapped[i, 1] - wrapped[j, 1] - sy * length[1]
                    reach = radius[i] + radius[j] + extra
                    if rx * rx + ry * ry < reach * reach:
                        row = first_row + count
                        if row < capacity:
                            new.particle_i[row] = i
                            new.particle_j[row] = j
                            new.image[row, 0] = sx
                            new.image[row, 1] = sy
                            new.root_reduced_mass[row] = root_reduced_mass(inv_mass[i], inv_mass[j])
                        count += 1
    for w in range(wall_offset.shape[0]):
        if not wall_reach[w, 0] <= i < wall_reach[w, 1]:
            continue
        gap = wall_normal[w, 0] * wrapped[i, 0] + wall_normal[w, 1] * wrapped[i, 1] - wall_offset[w] - radius[i]
        if gap < extra:
            row = first_row + count
            if row < capacity:
                new.particle_i[row] = i
                new.particle_j[row] = n + w
                new.image[row, 0] = 0
                new.image[row, 1] = 0
                new.root_reduced_mass[row] = root_reduced_mass(inv_mass[i], 0.0)
            count += 1
    return count


@njit(**JIT)
def _transfer_history(old, new, wraps, length, wall_normal, n):
    """Copy each old row's history to the new row of the same pair and image.

    The image of a pair changes when a disk is wrapped back into the cell:
    ``image_new = image_old + wraps_j - wraps_i``. A wall anchor (a coordinate along the
    wall) shifts with the wrap of its disk. Returns the number of interacting old rows
    that found no new row. Only touching contacts count: they always lie within range, while a
    distant cohesive row may legitimately drop out when the cohesion range was reduced.
    """
    old_count = old.count[0]
    first = np.zeros(n + 1, dtype=np.int64)
    for k in range(old_count):
        first[old.particle_i[k] + 1] += 1
    for i in range(n):
        first[i + 1] += first[i]
    active = 0
    for k in range(old_count):
        if touching(old.status[k]):
            active += 1
    return active - _carry_histories(old, first, new, wraps, length, wall_normal, n)


@njit(**KERNEL)
def _carry_histories(old, first, new, wraps, length, wall_normal, n):
    """Every new row's history (:func:`row_history`): the touching old rows found."""
    matched = 0
    for k in range(new.count[0]):
        matched += row_history(old, first, new, k, wraps, length, wall_normal, n)
    return matched


@njit(**JIT, inline="always")
def row_history(old, first, new, k, wraps, length, wall_normal, n):
    """Row ``k`` of ``new`` takes the history of the row of ``old`` of the same pair and image (``first[i]``:
    the first row of disk ``i`` in ``old``, its rows consecutive), or starts afresh. Returns 1 if that old row
    touched, else 0."""
    i = new.particle_i[k]
    j = new.particle_j[k]
    if j < n:
        ix = new.image[k, 0] - wraps[j, 0] + wraps[i, 0]
        iy = new.image[k, 1] - wraps[j, 1] + wraps[i, 1]
    else:
        ix = 0
        iy = 0
    found = -1
    for m in range(first[i], first[i + 1]):
        if old.particle_j[m] == j and old.image[m, 0] == ix and old.image[m, 1] == iy:
            found = m
            break
    if found < 0:
        no_history(new, k)
        return 0
    carry_history(old, found, new, k)
    if j >= n:
        w = j - n
        # t = z × n = (-n_y, n_x); the wrapped disk moved by -wraps_i · L
        new.anchor_angle_j[k] -= -wall_normal[w, 1] * wraps[i, 0] * length[0] \
            + wall_normal[w, 0] * wraps[i, 1] * length[1]
    return 1 if touching(old.status[found]) else 0


@njit(**JIT)
def no_history(table, k):
    """Row ``k`` of ``table`` starts afresh: no status, springs or anchors, no force, its gap unknown."""
    table.status[k] = STATUS_NONE
    table.tangential_spring[k] = 0.0
    table.rolling_spring[k] = 0.0
    table.anchor_angle_i[k] = 0.0
    table.anchor_angle_j[k] = 0.0
    table.normal_force[k] = 0.0
    table.tangential_force[k] = 0.0
    table.surface_gap[k] = math.inf


@njit(**JIT)
def carry_history(old, found, new, k):
    """Row ``k`` of table ``new`` takes the history of row ``found`` of ``old``: status, springs, anchors, the
    last forces and gap."""
    new.status[k] = old.status[found]
    new.tangential_spring[k] = old.tangential_spring[found]
    new.rolling_spring[k] = old.rolling_spring[found]
    new.anchor_angle_i[k] = old.anchor_angle_i[found]
    new.anchor_angle_j[k] = old.anchor_angle_j[found]
    new.normal_force[k] = old.normal_force[found]
    new.tangential_force[k] = old.tangential_force[found]
    new.surface_gap[k] = old.surface_gap[found]


@njit(**JIT)
def copy_table(source, target):
    """Copy the rows in use of contact table ``source`` into ``target`` (same capacity)."""
    count = source.count[0]
    for k in range(count):
        copy_row(source, k, target, k)
    target.count[0] = count


@njit(**JIT)
def copy_row(source, k, target, m):
    """Row ``m`` of table ``target`` becomes row ``k`` of ``source``: its pair, image, reduced mass and history."""
    target.particle_i[m] = source.particle_i[k]
    target.particle_j[m] = source.particle_j[k]
    target.image[m, 0] = source.image[k, 0]
    target.image[m, 1] = source.image[k, 1]
    target.root_reduced_mass[m] = source.root_reduced_mass[k]
    carry_history(source, k, target, m)
