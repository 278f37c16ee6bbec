"""Random sequential addition of non-overlapping disks (a granular gas for Gilabert's method 1)."""

import math

import numpy as np

from .jit import JIT, njit


@njit(**JIT, inline="always")
def neighbour_cell(g, cells, periodic):
    """Cell index ``g`` along an axis of ``cells`` cells: ``(inside, index, image)``, wrapped (with the
    image it crosses) on a periodic axis, outside beyond a wall (the contact table's grid uses it too)."""
    if 0 <= g < cells:
        return True, g, 0
    if not periodic:
        return False, g, 0
    shift = -1 if g < 0 else 1
    return True, g - shift * cells, shift


@njit(**JIT)
def random_sequential_addition(radius, lo, hi, periodic, seed, max_attempts, position):
    """Place disks of ``radius (N,)`` (largest first works best) one by one at uniformly random
    centres in the box ``[lo, hi]`` (centres at least a radius inside along open axes), rejecting
    overlaps. Fills ``position (N, 2)``; returns how many disks were placed (less than N when
    ``max_attempts`` per disk were not enough).
    """
    np.random.seed(seed)
    n = radius.shape[0]
    length = np.empty(2)
    for a in range(2):
        length[a] = hi[a] - lo[a]
    cell_size = 2.0 * radius.max()
    cells = np.empty(2, dtype=np.int64)
    for a in range(2):
        cells[a] = max(1, int(length[a] / cell_size))
    width = np.empty(2)
    for a in range(2):
        width[a] = length[a] / cells[a]
    head = np.full(cells[0] * cells[1], -1, dtype=np.int64)
    nxt = np.full(n, -1, dtype=np.int64)
    for i in range(n):
        r = radius[i]
        placed = False
        for _ in range(max_attempts):
            x, y = _random_centre(r, lo, length, periodic)
            cx = min(cells[0] - 1, int((x - lo[0]) / width[0]))
            cy = min(cells[1] - 1, int((y - lo[1]) / width[1]))
            if _free(x, y, r, cx, cy, head, nxt, position, radius, cells, periodic, length):
                position[i, 0] = x
                position[i, 1] = y
                c = cy * cells[0] + cx
                nxt[i] = head[c]
                head[c] = i
                placed = True
                break
        if not placed:
            return i
    return n


@njit(**JIT)
def _random_centre(r, lo, length, periodic):
    """A uniformly random centre for a disk of radius ``r`` (a radius inside along open axes)."""
    centre = np.empty(2)
    for a in range(2):
        margin = 0.0 if periodic[a] else r
        centre[a] = lo[a] + margin + np.random.random() * (length[a] - 2.0 * margin)
    return centre[0], centre[1]


@njit(**JIT)
def _free(x, y, r, cx, cy, head, nxt, position, radius, cells, periodic, length):
    """Whether a disk of radius ``r`` at ``(x, y)`` (in cell ``(cx, cy)``) overlaps none of the disks
    placed (the linked lists ``head``, ``nxt`` by cell)."""
    for oy in range(-1, 2):
        inside_y, gy, _ = neighbour_cell(cy + oy, cells[1], periodic[1])
        for ox in range(-1, 2):
            inside_x, gx, _ = neighbour_cell(cx + ox, cells[0], periodic[0])
            if not (inside_x and inside_y):
                continue
            j = head[gy * cells[0] + gx]
            while j >= 0:
                dx = x - position[j, 0]
                dy = y - position[j, 1]
                if periodic[0]:
                    dx -= length[0] * math.floor(dx / length[0] + 0.5)
                if periodic[1]:
                    dy -= length[1] * math.floor(dy / length[1] + 0.5)
                if dx * dx + dy * dy < (r + radius[j]) ** 2:
                    return False
                j = nxt[j]
    return True
