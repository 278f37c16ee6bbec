"""Angle-based spring: ``D_t`` is the sum of the arcs from the material points of first contact to
the current contact points (ratcheting Eqs. 18–22), a function of the present configuration only,
so no path leaves a residue; its rate (Eq. 24, for the viscous part and the tallies) and its
force on the centres are the α-corrected ones, its Coulomb limit Cundall–Strack's."""

import math

from ..jit import KERNEL, njit
from ..laws import disk_arc, wall_arc
from .alpha import centre_factor, spring_rate
from .cundall_strack import limit

__all__ = ["spring_rate", "trial_spring", "limit", "centre_factor"]


@njit(**KERNEL)
def trial_spring(previous, rate, dt, fresh, row):
    """``r_i wrap(phi + pi - theta_i - a_i) + r_j wrap(phi - theta_j - a_j)`` (Eqs. 19, 21–22); for a
    wall, the distance along it from the anchor replaces the second arc."""
    phi = row.phi
    arc = disk_arc(row.ri, phi + math.pi, row.angle_i, row.anchor_i)
    if row.is_wall:
        return arc + wall_arc(-row.ny, row.nx, row.xi, row.yi, row.wall_shift, row.anchor_j)
    return arc + disk_arc(row.rj, phi, row.angle_j, row.anchor_j)
