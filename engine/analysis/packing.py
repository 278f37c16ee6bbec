"""Packing statistics of a state (Gilabert Secs. III-IV): solid fraction, coordination, rattlers,
local coordinations, force distributions, the Rumpf relation and the force-percolation threshold.

A state is a :class:`granlab.engine.simulation.Snapshot` or an :class:`granlab.engine.analysis.states.PackingState`.
Forces follow the engine's conventions: ``N`` (total normal force, > 0 repulsive) along ``n``
from j to i, ``T`` along ``t = z × n``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..observables import backbone, disk_contacts, interacting, solid_fraction
from .report import AnalysisReport, Clock

LABELS = {
    "phi": "Solid fraction Φ [dimensionless]",
    "z": "Coordination number z: force-carrying disk–disk interactions per disk",
    "z_star": "Backbone coordination z* = z / (1 − x_0) (Gilabert Eq. 13)",
    "rattlers": "Rattlers: disks with no interaction above 10⁻⁴ F1",
    "contacts": "Force-carrying disk–disk interactions",
    "particles": "Disks N",
    "coordination": "Local coordinations x_k: fraction of disks with k interactions",
    "forces_known": "Contact forces known",
    "force_unit": "Force unit of the histogram: F0, or ⟨N⟩ without cohesion [force]",
    "normal_force_histogram": "Histogram of N / force unit (Gilabert Fig. 9)",
    "theta_histogram": "Histogram of the angle θ between n and F (Gilabert Fig. 15) [degrees]",
    "mean_normal_force": "Mean normal force F_N = ⟨N⟩ [force]",
    "pressure": "Pressure P of the disk–disk stress [force/length]",
    "rumpf_force": "F_N by Rumpf, π ⟨d²⟩/⟨d⟩ P / (zΦ) (Gilabert Eq. 17) [force]",
    "rumpf_force_eq18": "F_N by Rumpf, 7πa P / (9 zΦ) (Gilabert Eq. 18) [force]",
    "percolation_force": "Force-percolation threshold F_perc (Gilabert Sec. IV B) [force]",
}
"""The label of each value of the packing analysis (:func:`run`)."""

RATTLER_FORCE_TOLERANCE = 1e-4
"""Interactions carrying less than this fraction of F1 = max(F0, P a) count as carrying no force
(Gilabert Sec. III A)."""
FORCE_BINS = 40
THETA_BINS = 36
NO_FORCES = "no contact forces in this state (contacts found from the geometry)"
NO_BACKBONE = "every disk is a rattler: there is no backbone"
NO_INTERACTIONS = "no disk–disk interactions (z Φ = 0)"
NO_PERCOLATION = "the force-carrying contacts never percolate: none wraps around the cell or joins opposite walls"
FORCE_VALUES = ("force_unit", "normal_force_histogram", "theta_histogram", "mean_normal_force", "pressure",
                "rumpf_force", "rumpf_force_eq18", "percolation_force")
"""The values of :class:`PackingStats` that need contact forces."""


@dataclass(frozen=True)
class PackingStats:
    """``phi``: solid fraction; ``z``: mean number of force-carrying disk-disk interactions per disk
    (rattlers included, ``2 M / N``); ``z_star``: the same on the backbone, ``z / (1 - x0)``
    (Gilabert Eq. 13); ``rattlers``: disks whose interactions all carry less than the tolerance
    ``1e-4 F1``; ``contacts``: force-carrying disk-disk interactions; ``coordination``: x_k, the
    fraction of disks with k force-carrying disk-disk interactions (k = 0, 1, ...).

    With forces known (``forces_known``): ``force_unit`` (F0 with cohesion, else the mean normal
    force), ``normal_force_histogram`` (edges, fractions) of N / force_unit, ``theta_histogram``
    (edges in degrees, fractions) of the angle between n and F (Gilabert Fig. 15: 0 for a pure
    repulsion, 180 for a pure attraction), ``mean_normal_force`` F_N = <N> over all disk-disk
    interactions, ``pressure`` P of the disk-disk stress, ``rumpf_force`` F_N from Eq. 17 with the
    sample's <d> and <d^2>, ``rumpf_force_eq18`` (7 pi a / 9) P / (z Phi) for Gilabert's
    distribution (Eq. 18), and ``percolation_force`` F_perc: the largest threshold such that the
    interactions with |F| >= F_perc percolate (wrap around a periodic axis or join two opposite
    walls). ``normal``, ``tangential`` are the (N, T) of every interaction, for the scatter of
    Gilabert Fig. 14 with its lines T = ±sqrt(3) N (Eq. 20). ``reasons``: for each value that is
    None or made up (``z_star`` = 0 without a backbone), why, in a few words for people (not in
    :meth:`as_dict`)."""

    phi: float
    z: float
    z_star: float
    rattlers: int
    contacts: int
    particles: int
    coordination: list[float]
    forces_known: bool = True
    force_unit: float | None = None
    normal_force_histogram: tuple[list[float], list[float]] | None = None
    theta_histogram: tuple[list[float], list[float]] | None = None
    mean_normal_force: float | None = None
    pressure: float | None = None
    rumpf_force: float | None = None
    rumpf_force_eq18: float | None = None
    percolation_force: float | None = None
    normal: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    tangential: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    reasons: dict[str, str] = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k not in ("normal", "tangential", "reasons")}


def pressure(state) -> float:
    """(sigma_xx + sigma_yy) / 2 of the state's disk-disk stress (compression positive)."""
    return 0.5 * float(state.stress[0, 0] + state.stress[1, 1])


def force_scale(state) -> float:
    """Gilabert's F1 = max(F0, P a): F0 the cohesion force, P the pressure, a the largest diameter."""
    return max(float(state.law.cohesion_force), pressure(state) * 2.0 * float(state.radii.max()))


def packing_stats(state, force_scale_value: float | None = None, area: float | None = None) -> PackingStats:
    """Statistics of ``state``; interactions carrying less than ``1e-4 F1`` (default F1:
    :func:`force_scale`) are ignored, and a disk with none left is a rattler. A state without
    forces (a generic H5MD file) counts every touching pair and leaves the force statistics out."""
    n = state.positions.shape[0]
    c = state.contacts
    forces_known = getattr(state, "forces_known", True)
    scale = force_scale(state) if force_scale_value is None else force_scale_value
    force = np.hypot(c.normal_force, c.tangential_force)
    carrying = interacting(c.status) & ((force > RATTLER_FORCE_TOLERANCE * scale) | (not forces_known))
    per_disk, with_walls = disk_contacts(carrying, c.i, c.j, n)
    z, z_star, rattlers = backbone(per_disk, with_walls)
    phi = solid_fraction(state.radii, state.box_lengths, area)
    stats = dict(phi=phi, z=z, z_star=z_star, rattlers=rattlers,
                 contacts=int(per_disk.sum()) // 2, particles=n, coordination=(np.bincount(per_disk) / n).tolist(),
                 forces_known=forces_known)
    reasons = {} if rattlers < n else {"z_star": NO_BACKBONE}
    if forces_known:
        forces, force_reasons = _force_statistics(state, phi, scale)
        stats.update(forces)
        reasons.update(force_reasons)
    else:
        reasons.update(dict.fromkeys(FORCE_VALUES, NO_FORCES))
    return PackingStats(**stats, reasons=reasons)


def _histogram(values: np.ndarray, bins, value_range) -> tuple[list[float], list[float]]:
    counts, edges = np.histogram(values, bins=bins, range=value_range)
    return edges.tolist(), (counts / max(1, len(values))).tolist()


def _force_statistics(state, phi: float, scale: float) -> tuple[dict, dict]:
    """The values of ``FORCE_VALUES`` and ``normal``, ``tangential``; and the reasons of those that are None."""
    n = state.positions.shape[0]
    c = state.contacts
    pairs = interacting(c.status) & (c.j < n)
    normal, tangential = c.normal_force[pairs], c.tangential_force[pairs]
    count = len(normal)
    mean = float(normal.mean()) if count else 0.0
    cohesive = float(state.law.cohesion_force) > 0.0
    unit = float(state.law.cohesion_force) if cohesive else mean
    scaled = normal / unit if unit > 0 else normal
    low, high = (float(scaled.min()), float(scaled.max())) if count else (0.0, 1.0)
    theta = np.degrees(np.arctan2(np.abs(tangential), normal))
    p = pressure(state)
    z = 2.0 * count / n
    diameters = 2.0 * np.asarray(state.radii)
    denominator = z * phi
    percolation = percolation_force(state, np.hypot(c.normal_force, c.tangential_force), interacting(c.status))
    reasons = {} if denominator > 0 else dict.fromkeys(("rumpf_force", "rumpf_force_eq18"), NO_INTERACTIONS)
    if percolation is None:
        reasons["percolation_force"] = NO_PERCOLATION
    return dict(
        force_unit=unit, normal_force_histogram=_histogram(scaled, FORCE_BINS, (low, max(high, low + 1e-12))),
        theta_histogram=_histogram(theta, THETA_BINS, (0.0, 180.0)), mean_normal_force=mean, pressure=p,
        rumpf_force=float(np.pi * np.mean(diameters ** 2) / np.mean(diameters) * p / denominator)
        if denominator > 0 else None,
        rumpf_force_eq18=float(7.0 * np.pi * diameters.max() / 9.0 * p / denominator) if denominator > 0 else None,
        percolation_force=percolation, normal=normal, tangential=tangential), reasons


def percolation_force(state, force: np.ndarray, usable: np.ndarray) -> float | None:
    """F_perc (Gilabert Sec. IV B 1): add the interactions from the largest |F| down, joining
    disks (and walls) in clusters (union by size) that remember the periodic image of each member
    relative to its root; the force of the interaction that first closes a loop wrapping around a
    periodic axis, or first joins two walls facing each other, is F_perc. ``None`` if they never
    percolate."""
    n = state.positions.shape[0]
    c = state.contacts
    normals = np.asarray(state.wall_normals)
    parent = list(range(n + len(normals)))
    size = [1] * len(parent)
    shift = [(0, 0)] * len(parent)
    walls = {n + w: [w] for w in range(len(normals))}

    def root(a):
        sx = sy = 0
        while parent[a] != a:
            sx, sy = sx + shift[a][0], sy + shift[a][1]
            a = parent[a]
        return a, sx, sy

    for row in np.argsort(-force, kind="stable"):
        if not usable[row]:
            continue
        i, j = int(c.i[row]), int(c.j[row])
        kx, ky = (int(c.image[row][0]), int(c.image[row][1])) if j < n else (0, 0)
        ri, ix, iy = root(i)
        rj, jx, jy = root(j)
        if ri == rj:
            if (ix - jx + kx, iy - jy + ky) != (0, 0):
                return float(force[row])
            continue
        if size[ri] > size[rj]:  # attach j's cluster to i's: s_i - s_j + image = 0 must hold
            ri, rj, ix, iy, jx, jy, kx, ky = rj, ri, jx, jy, ix, iy, -kx, -ky
        parent[ri] = rj
        size[rj] += size[ri]
        shift[ri] = (jx - ix - kx, jy - iy - ky)
        joined = walls.pop(ri, []) + walls.get(rj, [])
        if joined:
            walls[rj] = joined
            if float((normals[joined] @ normals[joined].T).min()) < -0.99:
                return float(force[row])
    return None


def run(state, clock: Clock, load: str, seed: int) -> AnalysisReport:
    """The :class:`PackingStats` of ``state`` (Gilabert Secs. III–IV); ``load`` and ``seed`` are not used."""
    stats = packing_stats(state)
    clock.lap("packing")
    return AnalysisReport("packing", stats.as_dict(), stats, reasons=stats.reasons,
                          figures=("forces",) if stats.forces_known else ())
