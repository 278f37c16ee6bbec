"""Energies of a state and per-contact rolling distances (computed on demand, not per step)."""

import math

from ..state import STATUS_NONE, WALL_FORCE
from .jit import JIT, njit
from . import normal
from .laws import D0, F0, KN, KR, KT, cohesion_potential, disk_arc, wall_arc

(KINETIC_TRANSLATION, KINETIC_ROTATION, NORMAL_ELASTIC, COHESION, TANGENTIAL_ELASTIC, ROLLING_ELASTIC,
 GRAVITY, WALL_KINETIC) = range(8)
ENERGY_SIZE = 8


@njit(**JIT)
def energy_terms(p, w, ct, law, normal_model, gravity, out):
    """Kinetic, stored and gravitational energies of the current state.

    Stored energy per contact: the normal spring's (its law's energy; ``K_n D_n²/2`` for the linear
    law, ratcheting Eq. 12), the cohesion potential, ``K_t D_t²/2`` and ``K_r dtheta²/2``.
    Gravity: ``-sum m g · x`` over dynamic disks. Walls: kinetic energy of
    force-controlled walls. Fixed and kinematic disks carry no kinetic energy here
    (their motion is prescribed; its work is tallied separately).
    """
    for k in range(ENERGY_SIZE):
        out[k] = 0.0
    n = p.position.shape[0]
    for i in range(n):
        if p.inv_mass[i] > 0.0:
            m = p.mass[i]
            out[KINETIC_TRANSLATION] += 0.5 * m * (p.velocity[i, 0] ** 2 + p.velocity[i, 1] ** 2)
            out[GRAVITY] -= m * (gravity[0] * p.position[i, 0] + gravity[1] * p.position[i, 1])
        if p.inv_inertia[i] > 0.0:
            out[KINETIC_ROTATION] += 0.5 * p.omega[i] ** 2 / p.inv_inertia[i]
    for k in range(ct.count[0]):
        if ct.status[k] == STATUS_NONE:
            continue
        i = ct.particle_i[k]
        j = ct.particle_j[k]
        is_wall = j >= n
        rj = 0.0 if is_wall else p.radius[j]
        gap = ct.surface_gap[k]
        out[NORMAL_ELASTIC] += normal.energy(normal_model, law[KN], -gap, p.radius[i], rj, is_wall)
        out[COHESION] += cohesion_potential(law[F0], law[D0], gap)
        out[TANGENTIAL_ELASTIC] += 0.5 * law[KT] * ct.tangential_spring[k] ** 2
        out[ROLLING_ELASTIC] += 0.5 * law[KR] * ct.rolling_spring[k] ** 2
    for m in range(w.offset.shape[0]):
        if w.mode[m] == WALL_FORCE:
            out[WALL_KINETIC] += 0.5 * w.velocity[m] ** 2 / w.inv_mass[m]


@njit(**JIT)
def rolling_distance(p, w, cell, ct, out):
    """Rolling distance of each row (ratcheting Eq. 20): ``(s_i - s_j) / 2``.

    ``s_i = r_i wrap(phi + pi - theta_i - a_i)`` and ``s_j = r_j wrap(phi - theta_j - a_j)``
    are the signed arcs from the material points of first contact to the current contact
    points (for a wall, ``s_j`` is the distance along the wall). Zero for rows not touching.
    """
    n = p.position.shape[0]
    for k in range(ct.count[0]):
        out[k] = 0.0
        if ct.status[k] == STATUS_NONE or ct.surface_gap[k] >= 0.0:
            continue
        i = ct.particle_i[k]
        j = ct.particle_j[k]
        ri = p.radius[i]
        if j < n:
            rx = p.position[i, 0] - p.position[j, 0] - ct.image[k, 0] * cell.length[0]
            ry = p.position[i, 1] - p.position[j, 1] - ct.image[k, 1] * cell.length[1]
            phi = math.atan2(ry, rx)
            s_j = disk_arc(p.radius[j], phi, p.angle[j], ct.anchor_angle_j[k])
        else:
            wall = j - n
            nx = w.normal[wall, 0]
            ny = w.normal[wall, 1]
            phi = math.atan2(ny, nx)
            s_j = wall_arc(-ny, nx, p.position[i, 0], p.position[i, 1], w.tangential_position[wall],
                           ct.anchor_angle_j[k])
        s_i = disk_arc(ri, phi + math.pi, p.angle[i], ct.anchor_angle_i[k])
        out[k] = 0.5 * (s_i - s_j)


@njit(**JIT)
def elastic_normal_forces(p, ct, law, normal_model, out):
    """``N^e`` of each row from its gap: the part of F_n that bounds F_t and the rolling moment."""
    n = p.position.shape[0]
    for k in range(ct.count[0]):
        i = ct.particle_i[k]
        j = ct.particle_j[k]
        is_wall = j >= n
        rj = 0.0 if is_wall else p.radius[j]
        out[k] = normal.force(normal_model, law[KN], -ct.surface_gap[k], p.radius[i], rj, is_wall)
