"""Fields of a frame for its pictures (the lab's scene and ``granlab render``): per disk its
touching contacts, the pressure on it and whether one of its contacts slides; per contact its
segment, its force and its kind."""

import math

from ..state import STATUS_COHESIVE, STATUS_SLIDE_NEG, STATUS_SLIDE_POS, STATUS_STICK
from .jit import KERNEL, njit


@njit(**KERNEL)
def contact_fields(positions, radii, pair, image, status, normal_force, tangential_force, surface_gap, wall_normal,
                   cell, shift, coordination, pressure, sliding, segments, force, kind):
    """One pass over a contact table (rows ``pair`` with ``j >= N`` for wall ``j - N``).

    Per disk: ``coordination`` (touching contacts: stick or sliding), ``pressure`` (sum of |F_n|
    over its rows / its perimeter), ``sliding`` (one of its contacts slides); the outputs are
    overwritten. Per row: ``segments`` from the centre of i to its partner (the periodic image
    next to it) or to the wall point at distance r_i + gap, shifted by ``shift``; ``force``
    |F|; ``kind`` 2 sliding, 1 tensile (F_n < 0 or a distant cohesive pair), else 0.
    """
    n = positions.shape[0]
    for k in range(n):
        coordination[k] = 0
        pressure[k] = 0.0
        sliding[k] = False
    for c in range(pair.shape[0]):
        i, j, s = pair[c, 0], pair[c, 1], status[c]
        slides = s == STATUS_SLIDE_POS or s == STATUS_SLIDE_NEG
        touching = slides or s == STATUS_STICK
        load = abs(normal_force[c])
        x0, y0 = positions[i, 0], positions[i, 1]
        if j < n:
            x1 = positions[j, 0] + image[c, 0] * cell[0]
            y1 = positions[j, 1] + image[c, 1] * cell[1]
            coordination[j] += touching
            pressure[j] += load
            sliding[j] |= slides
        else:
            distance = radii[i] + surface_gap[c]
            x1 = x0 - distance * wall_normal[j - n, 0]
            y1 = y0 - distance * wall_normal[j - n, 1]
        coordination[i] += touching
        pressure[i] += load
        sliding[i] |= slides
        segments[c, 0, 0] = x0 + shift[0]
        segments[c, 0, 1] = y0 + shift[1]
        segments[c, 1, 0] = x1 + shift[0]
        segments[c, 1, 1] = y1 + shift[1]
        force[c] = math.hypot(normal_force[c], tangential_force[c])
        kind[c] = 2 if slides else (1 if normal_force[c] < 0.0 or s == STATUS_COHESIVE else 0)
    for k in range(n):
        pressure[k] /= 2.0 * math.pi * radii[k]
