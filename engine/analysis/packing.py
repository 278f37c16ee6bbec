"""Packing statistics of a snapshot (Gilabert Secs. III-IV): solid fraction, coordination, rattlers."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..simulation import Snapshot
from ..state import STATUS_NONE

RATTLER_FORCE_TOLERANCE = 1e-4


@dataclass(frozen=True)
class PackingStats:
    """``phi``: solid fraction; ``z``: mean number of force-carrying disk-disk interactions per disk
    (rattlers included, as ``2 M / N``); ``z_star``: the same on the backbone, ``z / (1 - x0)``
    (Gilabert Eq. 13); ``rattlers``: disks whose interactions all carry less than the tolerance
    ``1e-4 F1`` (Gilabert Sec. III A); ``contacts``: force-carrying disk-disk interactions."""

    phi: float
    z: float
    z_star: float
    rattlers: int
    contacts: int
    particles: int

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def solid_fraction(snapshot: Snapshot, area: float | None = None) -> float:
    """Area of the disks over the area of the domain (``area``, or the snapshot's box)."""
    if area is None:
        area = float(np.prod(snapshot.box_lengths))
    return float(np.pi * np.sum(snapshot.radii ** 2) / area)


def packing_stats(snapshot: Snapshot, force_scale: float, area: float | None = None) -> PackingStats:
    """Statistics of ``snapshot``; interactions carrying less than ``1e-4 force_scale`` (Gilabert's F1)
    are ignored, and a disk with none left is a rattler."""
    n = snapshot.positions.shape[0]
    c = snapshot.contacts
    force = np.hypot(c.normal_force, c.tangential_force)
    carrying = (c.status != STATUS_NONE) & (force > RATTLER_FORCE_TOLERANCE * force_scale)
    pair = carrying & (c.j < n)
    per_disk = np.bincount(c.i[pair], minlength=n) + np.bincount(c.j[pair], minlength=n)
    with_walls = per_disk + np.bincount(c.i[carrying & (c.j >= n)], minlength=n)
    rattlers = int(np.count_nonzero(with_walls == 0))
    contacts = int(np.count_nonzero(pair))
    z = 2.0 * contacts / n
    backbone = n - rattlers
    return PackingStats(phi=solid_fraction(snapshot, area), z=z, z_star=2.0 * contacts / backbone if backbone else 0.0,
                        rattlers=rattlers, contacts=contacts, particles=n)
