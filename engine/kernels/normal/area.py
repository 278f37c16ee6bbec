"""Overlap-area law: ``N^e = K_n A / l``, ``A`` the area the disks (or a disk and a wall) share and
``l = r_i + r_j`` (``2 r_i`` for a wall) (ratcheting Sec. II B). Its tangent stiffness
``K_n chord / l`` never exceeds ``K_n``."""

import math

from ..jit import KERNEL, njit
from .quadrature import NODES, WEIGHTS


@njit(**KERNEL)
def _x_minus_sin_x(x):
    if abs(x) < 0.2:
        x2 = x * x
        return x * x2 / 6.0 * (1.0 - x2 / 20.0 * (1.0 - x2 / 42.0 * (1.0 - x2 / 72.0)))
    return x - math.sin(x)


@njit(**KERNEL)
def segment_area(r, h):
    """Area of the circular segment of height ``h`` (0 <= h <= 2r) of a disk of radius ``r``.

    Written with the half-angle ``beta`` (area ``r²/2 (2 beta - sin 2 beta)``) so that it
    keeps full relative precision for the tiny overlaps of stiff grains.
    """
    if h <= 0.0:
        return 0.0
    if h >= 2.0 * r:
        return math.pi * r * r
    beta = math.atan2(math.sqrt(h * (2.0 * r - h)), r - h)
    return 0.5 * r * r * _x_minus_sin_x(2.0 * beta)


@njit(**KERNEL)
def overlap_area(overlap, ri, rj, is_wall):
    """Overlap area of disk i with disk j (or with a wall) for an overlap ``δ``."""
    if overlap <= 0.0:
        return 0.0
    if is_wall:
        return segment_area(ri, overlap)
    dist = ri + rj - overlap
    if dist <= abs(ri - rj):
        r = min(ri, rj)
        return math.pi * r * r
    hi = overlap * (rj - ri + dist) / (2.0 * dist)
    hj = overlap * (ri - rj + dist) / (2.0 * dist)
    return segment_area(ri, hi) + segment_area(rj, hj)


@njit(**KERNEL)
def _length(ri, rj, is_wall):
    return 2.0 * ri if is_wall else ri + rj


@njit(**KERNEL)
def force(kn, overlap, ri, rj, is_wall):
    """``K_n A / l``."""
    return kn * overlap_area(overlap, ri, rj, is_wall) / _length(ri, rj, is_wall)


@njit(**KERNEL)
def energy(kn, overlap, ri, rj, is_wall):
    """The integral of :func:`force` over the overlap, by Gauss-Legendre quadrature in ``u`` with
    ``s = δ u²``: the integrand is smooth, the quadrature exact to rounding."""
    total = 0.0
    for k in range(len(NODES)):
        u = NODES[k]
        total += WEIGHTS[k] * force(kn, overlap * u * u, ri, rj, is_wall) * 2.0 * u
    return total * overlap


@njit(**KERNEL)
def stiffness(kn, overlap, ri, rj, is_wall):
    """``K_n chord / l``: the area grows by the chord of the lens (or segment) per unit of overlap."""
    if is_wall:
        along = ri - overlap  # the centre's distance to the wall
    else:
        distance = ri + rj - overlap
        along = (distance * distance + ri * ri - rj * rj) / (2.0 * max(distance, 1e-300))
    chord = 2.0 * math.sqrt(max(ri * ri - along * along, 0.0))
    return kn * chord / _length(ri, rj, is_wall)
