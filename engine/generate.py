"""Initial configurations: radius distributions, lattices and random non-overlapping gases.

Each function returns plain arrays (positions ``(N, 2)``, radii ``(N,)``) that go into
:class:`granlab.engine.state.ParticleState`.
"""

from __future__ import annotations

import math

import numpy as np

from .errors import ParameterError
from .kernels.packing import random_sequential_addition
from .params import positive

RADIUS_DISTRIBUTIONS = ("constant", "uniform")
MAX_DISKS = 4_000_000
"""Larger systems are refused before any array is made: a disk costs about 600 bytes of state,
contact and neighbour tables (10⁷ disks took 5–7 GB), and a 10⁶ × 10⁶ lattice would ask for TiB."""


def radii(count: int, radius: float | None = None, radius_min: float | None = None,
          radius_max: float | None = None, distribution: str = "constant", seed: int = 0) -> np.ndarray:
    """``count`` radii: all ``radius``, or uniform in ``[radius_min, radius_max]``.

    Gilabert Sec. II A (diameters uniform in [a/2, a]): ``uniform`` with
    ``radius_min = a/4, radius_max = a/2``; ratcheting Sec. IV B 1: ``radius_max [0.7, 1]``.
    """
    if not isinstance(count, (int, np.integer)) or not 1 <= count <= MAX_DISKS:
        raise ParameterError("count", count, f"a whole number from 1 to {MAX_DISKS}")
    if distribution == "constant":
        if radius is None:
            raise ParameterError("radius", radius, "a positive radius for the constant distribution")
        return np.full(count, positive("radius", radius))
    if distribution == "uniform":
        lo = positive("radius_min", radius_min if radius_min is not None else math.nan)
        hi = positive("radius_max", radius_max if radius_max is not None else math.nan)
        if hi < lo:
            raise ParameterError("radius_max", hi, f"at least radius_min = {lo}")
        return np.random.default_rng(seed).uniform(lo, hi, count)
    raise ParameterError("distribution", distribution, "one of " + ", ".join(RADIUS_DISTRIBUTIONS))


def square_lattice(rows: int, columns: int, spacing: float, origin=(0.0, 0.0)) -> np.ndarray:
    """Centres of a ``rows × columns`` square lattice (row-major from ``origin``)."""
    _counts(rows, columns)
    spacing = positive("spacing", spacing)
    x, y = np.meshgrid(np.arange(columns) * spacing, np.arange(rows) * spacing, indexing="xy")
    return np.column_stack([x.ravel() + origin[0], y.ravel() + origin[1]])


def triangular_lattice(rows: int, columns: int, spacing: float, origin=(0.0, 0.0)) -> np.ndarray:
    """Centres of a triangular lattice: odd rows shifted by half a spacing, rows ``spacing sqrt(3)/2`` apart."""
    _counts(rows, columns)
    spacing = positive("spacing", spacing)
    positions = square_lattice(rows, columns, spacing, origin)
    row = np.repeat(np.arange(rows), columns)
    positions[:, 0] += 0.5 * spacing * (row % 2)
    positions[:, 1] = origin[1] + row * spacing * math.sqrt(3.0) / 2.0
    return positions


def _counts(rows, columns):
    for name, value in (("rows", rows), ("columns", columns)):
        if not isinstance(value, (int, np.integer)) or value < 1:
            raise ParameterError(name, value, "a whole number >= 1")
    if rows * columns > MAX_DISKS:
        raise ParameterError("rows × columns", rows * columns, f"at most {MAX_DISKS} disks")


def random_gas(radius: np.ndarray, region, periodic=(False, False), seed: int = 0,
               max_attempts: int = 100_000) -> np.ndarray:
    """Non-overlapping disks placed at random in ``region = (x0, x1, y0, y1)``.

    Random sequential addition, largest disks first; along an open axis centres stay a
    radius away from the edges. Returns positions in the order of ``radius``. Raises a
    :class:`ParameterError` if the disks do not fit (random addition jams near a solid
    fraction of 0.5; denser packings come from compression).
    """
    radius = np.asarray(radius, dtype=np.float64)
    x0, x1, y0, y1 = (float(v) for v in region)
    if not (x1 > x0 and y1 > y0):
        raise ParameterError("region", tuple(region), "(x0, x1, y0, y1) with x1 > x0 and y1 > y0")
    order = np.argsort(-radius, kind="stable")
    placed_positions = np.zeros((radius.size, 2))
    placed = random_sequential_addition(radius[order], np.array([x0, y0]), np.array([x1, y1]),
                                        np.array(periodic, dtype=np.bool_), int(seed), int(max_attempts),
                                        placed_positions)
    if placed < radius.size:
        fraction = math.pi * float(np.sum(radius ** 2)) / ((x1 - x0) * (y1 - y0))
        raise ParameterError("solid fraction (solid_fraction, or count × π r² / area)", round(fraction, 4),
                             f"a gas that random placement can reach (placed {placed} of {radius.size} disks); "
                             "use a lower solid fraction and compress")
    positions = np.empty_like(placed_positions)
    positions[order] = placed_positions
    return positions


def strip_order(positions: np.ndarray, strip: float) -> np.ndarray:
    """The order that numbers disks along horizontal strips of height ``strip``, bottom to top,
    each strip left to right and the next right to left: disks with neighbouring numbers are
    neighbours in space.

    The engine's threads split the disks and the contact rows by number; numbered at random, each
    thread's disks lie all over the cell, and every step moves the cache lines of the force buffers
    and of the disks from one core to the other (a 1400-disk gas of Gilabert's method 2 ran 2.3
    times slower on two threads than on one). Numbered in strips, a thread's disks are one band of
    the cell, and only the rows across its edges are shared."""
    positions = np.asarray(positions, dtype=np.float64)
    row = np.floor((positions[:, 1] - positions[:, 1].min()) / positive("strip", strip))
    along = np.where(row % 2 == 0, positions[:, 0], -positions[:, 0])
    return np.lexsort((along, row))


def gas_count_for_fraction(solid_fraction: float, area: float, mean_square_radius: float) -> int:
    """Number of disks of mean square radius ``<r²>`` that fill ``solid_fraction`` of ``area``."""
    fraction = positive("solid_fraction", solid_fraction)
    if fraction >= 1:
        raise ParameterError("solid_fraction", fraction, "a fraction in (0, 1)")
    return max(1, int(round(fraction * area / (math.pi * mean_square_radius))))
