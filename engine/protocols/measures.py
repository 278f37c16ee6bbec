"""What presets and the lab follow of a running simulation: the rows of watched contacts, the
pairs of the contact table as codes and the mobilisation of friction (the packing's own
observables, z, Φ, sliding contacts, are :mod:`granlab.engine.observables`)."""

from __future__ import annotations

import numpy as np

from ..observables import touching
from ..simulation import Simulation


def pair_label(pair: tuple[int, int], disks: int, wall_names) -> str:
    """``i–j`` of a watched pair (``i–top`` for a wall)."""
    i, j = pair
    return f"{i}–{j}" if j < disks else f"{i}–{wall_names[j - disks]}"


def contact_rows(sim: Simulation, pairs: list[tuple[int, int]]):
    """(i, j, F_n, F_t, status) of the watched pairs present in ``sim``'s table, with
    ``F_n = N^e + N^a`` the normal force without its viscous part: ``N^e - F0`` in contact
    (Gilabert Eq. 4), the attraction alone at a distance. The Coulomb condition
    ``|F_t| <= mu N^e`` (Gilabert Eq. 8) is then the cone ``|F_t| <= mu (F_n + F0)``."""
    if not pairs:
        return []
    snap = sim.contact_snapshot()
    cohesion = sim.law.cohesion_force
    keys = np.array(pairs, dtype=np.int64)
    out = []
    for k in np.flatnonzero(np.isin(pair_codes(snap.i, snap.j), pair_codes(keys[:, 0], keys[:, 1]))):
        normal = snap.elastic_normal_force[k] - cohesion if touching(snap.status[k]) else snap.normal_force[k]
        out.append((int(snap.i[k]), int(snap.j[k]), float(normal), float(snap.tangential_force[k]),
                    int(snap.status[k])))
    return out


def pair_codes(i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """One int64 per pair (i, j) of the contact table (indices below 2^31)."""
    return (np.asarray(i, dtype=np.int64) << 32) | np.asarray(j, dtype=np.int64)


def mobilisation(sim: Simulation) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (K, 2) and |F_t| / N^e (K,) of the touching contacts with N^e > 0 (the ratio
    reaches mu on the Coulomb cone)."""
    snap = sim.contact_snapshot()
    keep = np.flatnonzero(touching(snap.status) & (snap.elastic_normal_force > 0))
    ratio = np.abs(snap.tangential_force[keep]) / snap.elastic_normal_force[keep]
    return np.column_stack([snap.i[keep], snap.j[keep]]), ratio


class PairMaximum:
    """The largest value seen for each pair (i, j), merged in bulk (one sort per merge)."""

    def __init__(self):
        self.codes = np.zeros(0, dtype=np.int64)
        self.values = np.zeros(0)

    def add(self, pairs: np.ndarray, values: np.ndarray) -> None:
        codes = np.concatenate([self.codes, pair_codes(pairs[:, 0], pairs[:, 1])])
        values = np.concatenate([self.values, values])
        order = np.lexsort((-values, codes))
        codes, values = codes[order], values[order]
        first = np.ones(len(codes), dtype=bool)
        first[1:] = codes[1:] != codes[:-1]
        self.codes, self.values = codes[first], values[first]

    def as_dict(self) -> dict[tuple[int, int], float]:
        return {(int(c >> 32), int(c & 0xFFFFFFFF)): float(v) for c, v in zip(self.codes, self.values)}

    def largest(self, count: int) -> list[tuple[int, int]]:
        """The ``count`` pairs of largest value, largest first."""
        top = np.argsort(-self.values, kind="stable")[:count]
        return [(int(c >> 32), int(c & 0xFFFFFFFF)) for c in self.codes[top]]
