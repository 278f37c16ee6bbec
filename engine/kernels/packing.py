"""Random sequential addition of non-overlapping disks (a granular gas for Gilabert's method 1)."""

import math

import numpy as np

from .jit import JIT, njit


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
            x = np.empty(2)
            for a in range(2):
                margin = 0.0 if periodic[a] else r
                x[a] = lo[a] + margin + np.random.random() * (length[a] - 2.0 * margin)
            cx = min(cells[0] - 1, int((x[0] - lo[0]) / width[0]))
            cy = min(cells[1] - 1, int((x[1] - lo[1]) / width[1]))
            free = True
            for oy in range(-1, 2):
                gy = cy + oy
                if gy < 0 or gy >= cells[1]:
                    if not periodic[1]:
                        continue
                    gy %= cells[1]
                for ox in range(-1, 2):
                    gx = cx + ox
                    if gx < 0 or gx >= cells[0]:
                        if not periodic[0]:
                            continue
                        gx %= cells[0]
                    j = head[gy * cells[0] + gx]
                    while j >= 0 and free:
                        dx = x[0] - position[j, 0]
                        dy = x[1] - position[j, 1]
                        if periodic[0]:
                            dx -= length[0] * math.floor(dx / length[0] + 0.5)
                        if periodic[1]:
                            dy -= length[1] * math.floor(dy / length[1] + 0.5)
                        if dx * dx + dy * dy < (r + radius[j]) ** 2:
                            free = False
                        j = nxt[j]
                if not free:
                    break
            if free:
                position[i, 0] = x[0]
                position[i, 1] = x[1]
                c = cy * cells[0] + cx
                nxt[i] = head[c]
                head[c] = i
                placed = True
                break
        if not placed:
            return i
    return n
