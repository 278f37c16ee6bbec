"""The observables of a packing, each defined once: which contacts touch, slide or interact, the
coordination z, the rattlers and the backbone's z*, the solid fraction Φ and the clusters.

Each takes the columns of a contact table and the number of disks, ``(status, i, j, n)`` (rows
with ``j >= n`` are walls), so a running :class:`~granlab.engine.simulation.Simulation`
(``coordination(*columns(sim))``), a snapshot, a frame read back from a file and another code's
packing are measured alike by the presets, the preparations, the studies, the analyses and the
lab.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from .state import STATUS_NONE, STATUS_SLIDE_NEG, STATUS_SLIDE_POS, STATUS_STICK

TOUCHING = (STATUS_STICK, STATUS_SLIDE_POS, STATUS_SLIDE_NEG)
"""The statuses of a contact whose disks overlap (a distant cohesive pair interacts, but does not touch)."""


def columns(sim) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """``(status, i, j, n)`` of ``sim``'s contact table, the status as :meth:`Simulation.contact_status`
    reads it (a frictionless contact never counts as sliding)."""
    rows = sim.contacts.count
    return sim.contact_status(), sim.contacts.particle_i[:rows], sim.contacts.particle_j[:rows], sim.particles.count


def touching(status) -> np.ndarray:
    """Whether each contact touches: sticking or sliding."""
    return np.isin(status, TOUCHING)


def sliding(status) -> np.ndarray:
    """Whether each contact slides, on either side of the Coulomb cone."""
    status = np.asarray(status)
    return (status == STATUS_SLIDE_POS) | (status == STATUS_SLIDE_NEG)


def interacting(status) -> np.ndarray:
    """Whether each row carries an interaction: touching, or cohesive at a distance."""
    return np.asarray(status) != STATUS_NONE


def coordination(status, i, j, n: int, distant: bool = False) -> float:
    """z = 2 M / N, M the disk–disk contacts that touch (``distant``: that interact, the distant
    cohesive pairs counted too, Gilabert's z of a cohesive packing)."""
    counted = interacting(status) if distant else touching(status)
    return 2.0 * int(np.count_nonzero(counted & (np.asarray(j) < n))) / n


def disk_contacts(counted, i, j, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Per disk, the ``counted`` rows (a mask of the table) with another disk and those with a wall."""
    i, j, counted = np.asarray(i), np.asarray(j), np.asarray(counted, dtype=bool)
    pair = counted & (j < n)
    with_disks = np.bincount(i[pair], minlength=n) + np.bincount(j[pair], minlength=n)
    return with_disks, np.bincount(i[counted & (j >= n)], minlength=n)


def backbone(with_disks, with_walls) -> tuple[float, float, int]:
    """``(z, z*, rattlers)`` from the per-disk counts of :func:`disk_contacts`: a rattler has none
    (with disks or walls); ``z* = 2 M / (N - rattlers)`` (Gilabert Eq. 13), 0 when every disk rattles."""
    n = len(with_disks)
    rattlers = int(np.count_nonzero(with_disks + with_walls == 0))
    pairs = int(with_disks.sum()) // 2
    return 2.0 * pairs / n, (2.0 * pairs / (n - rattlers) if n > rattlers else 0.0), rattlers


def solid_fraction(radii, box_lengths=None, area: float | None = None) -> float:
    """Area of the disks over ``area`` (default: that of the box ``box_lengths``)."""
    if area is None:
        area = float(np.prod(np.asarray(box_lengths, dtype=float)))
    return math.pi * float(np.sum(np.asarray(radii, dtype=float) ** 2)) / area


def clusters(status, i, j, n: int) -> int:
    """Number of clusters: disks joined by touching contacts or distant cohesive interactions."""
    linked = interacting(status) & (np.asarray(j) < n)
    i, j = np.asarray(i)[linked], np.asarray(j)[linked]
    graph = coo_matrix((np.ones(i.size), (i, j)), shape=(n, n))
    return int(connected_components(graph, directed=False)[0])
