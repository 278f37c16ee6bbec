"""The gathered contact pass: the common rows of the contact table computed over contiguous data.

A row whose disks touched at the step before and still overlap (no wall, no new contact) is almost
every row of a packing. For a block of rows, :func:`gather_block` copies what each row reads of its
disks and of its history (branch vector, relative velocities, radii, springs) into columns, one per
quantity; :func:`compute_block` runs the laws over the columns, a loop without indexed loads or
branches, which the compiler vectorises (eight rows at once, packed square roots and divisions);
the contact loop (:func:`granlab.engine.kernels.contacts.contact_chunk`) commits the history,
tallies and forces of those rows in row order, and computes every other row (walls, fresh and
opening contacts, distant pairs, cohesion at a distance) itself. It is used with a linear normal
spring (the area law calls atan2 and sin, which do not vectorise); for the angle spring, the gather
computes the direction of each contact (atan2) and the angles, the rest vectorises.

The laws of a row are the contact loop's own function (:func:`granlab.engine.kernels.pair.touching_laws`,
inlined in both), without fused multiply-adds (:data:`granlab.engine.kernels.jit.KERNEL`), and the
loop accumulates forces and tallies in the same order: the results are the same bit for bit
(tests/test_gathered.py).
"""

import math

from numba import uint64

from . import tangential
from .jit import KERNEL, njit
from .laws import touching
from .normal import GATHERED
from .pair import History, Rates, touching_laws
from .tangential import RowGeometry

BLOCK = 128
"""Rows per block: its columns stay in the first-level cache. A column is ``BLOCK`` consecutive
numbers of one chunk's row of ``Workspace.row_columns``: the compiler sees the distance between
two columns (a constant) and vectorises without checking at run time that they do not overlap."""

# gathered columns
(C_RX, C_RY, C_DVX, C_DVY, C_SPIN, C_RELATIVE_SPIN, C_RI, C_RJ, C_PREDICTED_X, C_PREDICTED_Y, C_PREDICTED_SPIN,
 C_PREDICTED_RELATIVE_SPIN, C_INV_INERTIA, C_ROOT_REDUCED_MASS, C_PREVIOUS, C_PREVIOUS_ROLL, C_TOUCHED, C_PHI,
 C_ANGLE_I, C_ANGLE_J, C_ANCHOR_I, C_ANCHOR_J,
 # computed columns
 C_HOT, C_FX, C_FY, C_TORQUE_I, C_TORQUE_J, C_FN, C_FT, C_GAP, C_SPRING, C_STATUS, C_SLIP, C_NORMAL_DAMPING,
 C_TANGENTIAL_WORK, C_SLIDING, C_ROLL, C_ROLLING_WORK, C_ROLLING_SLIP, C_OVERLAP_EXCESS) = range(40)
COLUMNS = 40


@njit(**KERNEL)
def gather_block(p, cell_length, strain, ct, columns, c, b0, b1, rolling, direction):
    """Chunk ``c``'s gathered columns get the data of rows ``[b0, b1)``, row ``b0 + q`` at ``q`` (the
    rolling spring's only with ``rolling``; with ``direction``, the direction of the contact, computed
    here as the contact loop computes it, and the angles and anchors). ``C_TOUCHED`` is 1 for a pair of
    disks that touched at the step before; the other columns of a wall's row are disk i's with itself,
    not read."""
    position, velocity, omega, radius, predicted = p.position, p.velocity, p.omega, p.radius, p.predicted_motion
    n = uint64(position.shape[0])
    for k in range(uint64(b0), uint64(b1)):
        q = k - uint64(b0)
        i = uint64(ct.particle_i[k])
        j = uint64(ct.particle_j[k])
        columns[c, C_TOUCHED * BLOCK + q] = 1.0 if j < n and touching(ct.status[k]) else 0.0
        if j >= n:
            j = i
        ri = radius[i]
        rj = radius[j]
        rx = position[i, 0] - position[j, 0] - ct.image[k, 0] * cell_length[0]
        ry = position[i, 1] - position[j, 1] - ct.image[k, 1] * cell_length[1]
        columns[c, C_RX * BLOCK + q] = rx
        columns[c, C_RY * BLOCK + q] = ry
        columns[c, C_DVX * BLOCK + q] = velocity[i, 0] - velocity[j, 0] + strain[0] * rx
        columns[c, C_DVY * BLOCK + q] = velocity[i, 1] - velocity[j, 1] + strain[1] * ry
        columns[c, C_SPIN * BLOCK + q] = ri * omega[i] + rj * omega[j]
        columns[c, C_RELATIVE_SPIN * BLOCK + q] = omega[i] - omega[j]
        columns[c, C_RI * BLOCK + q] = ri
        columns[c, C_RJ * BLOCK + q] = rj
        # as predicted_relative_motion adds them, term by term
        vx = predicted[i, 0] - 0.0
        vy = predicted[i, 1] - 0.0
        spin_sum = ri * predicted[i, 2]
        vx += strain[0] * rx - predicted[j, 0]
        vy += strain[1] * ry - predicted[j, 1]
        spin_sum += rj * predicted[j, 2]
        columns[c, C_PREDICTED_X * BLOCK + q] = vx
        columns[c, C_PREDICTED_Y * BLOCK + q] = vy
        columns[c, C_PREDICTED_SPIN * BLOCK + q] = spin_sum
        columns[c, C_PREDICTED_RELATIVE_SPIN * BLOCK + q] = predicted[i, 2] - predicted[j, 2]
        columns[c, C_ROOT_REDUCED_MASS * BLOCK + q] = ct.root_reduced_mass[k]
        columns[c, C_PREVIOUS * BLOCK + q] = ct.tangential_spring[k]
        if rolling:
            columns[c, C_INV_INERTIA * BLOCK + q] = p.inv_inertia[i] + p.inv_inertia[j]
            columns[c, C_PREVIOUS_ROLL * BLOCK + q] = ct.rolling_spring[k]
        if direction:
            inv_dist = 1.0 / math.sqrt(rx * rx + ry * ry)
            columns[c, C_PHI * BLOCK + q] = math.atan2(ry * inv_dist, rx * inv_dist)
            columns[c, C_ANGLE_I * BLOCK + q] = p.angle[i]
            columns[c, C_ANGLE_J * BLOCK + q] = p.angle[j]
            columns[c, C_ANCHOR_I * BLOCK + q] = ct.anchor_angle_i[k]
            columns[c, C_ANCHOR_J * BLOCK + q] = ct.anchor_angle_j[k]


@njit(**KERNEL)
def compute_block(columns, c, count, laws, tangential_model, dt, overlap_limit, whole_step):
    """The laws of the first ``count`` rows of chunk ``c``'s gathered columns (a linear normal
    spring), into its computed columns; ``C_HOT`` is 1 where the row touched at the step before and
    still overlaps (a disk pair), and only there are the other computed columns the row's. Every
    quantity is computed for every row, the rolling spring's too: the loop has no branch and reads
    nothing but the columns."""
    for q in range(uint64(count)):
        rx = columns[c, C_RX * BLOCK + q]
        ry = columns[c, C_RY * BLOCK + q]
        ri = columns[c, C_RI * BLOCK + q]
        rj = columns[c, C_RJ * BLOCK + q]
        dvx = columns[c, C_DVX * BLOCK + q]
        dvy = columns[c, C_DVY * BLOCK + q]
        spin_sum = columns[c, C_SPIN * BLOCK + q]
        relative_spin = columns[c, C_RELATIVE_SPIN * BLOCK + q]
        dist = math.sqrt(rx * rx + ry * ry)
        inv_dist = 1.0 / dist
        nx = rx * inv_dist
        ny = ry * inv_dist
        alpha = (ri + rj) * inv_dist
        gap = dist - ri - rj
        tx = -ny
        ty = nx
        vn = dvx * nx + dvy * ny
        vt = dvx * tx + dvy * ty
        vx = columns[c, C_PREDICTED_X * BLOCK + q]
        vy = columns[c, C_PREDICTED_Y * BLOCK + q]
        vn_d = vx * nx + vy * ny if whole_step else vn
        vt_d = vy * nx - vx * ny if whole_step else vt
        spin_d = columns[c, C_PREDICTED_SPIN * BLOCK + q] if whole_step else spin_sum
        relative_spin_d = columns[c, C_PREDICTED_RELATIVE_SPIN * BLOCK + q] if whole_step else relative_spin
        eta = laws.eta_factor * columns[c, C_ROOT_REDUCED_MASS * BLOCK + q]
        overlap = -gap
        limit_radius = min(ri, rj)
        excess = overlap / limit_radius if overlap > overlap_limit * limit_radius else 0.0
        row = RowGeometry(nx, ny, rx, ry, dvx, dvy, ri, rj, columns[c, C_ANGLE_I * BLOCK + q],
                          columns[c, C_ANGLE_J * BLOCK + q], columns[c, C_ANCHOR_I * BLOCK + q],
                          columns[c, C_ANCHOR_J * BLOCK + q], False, 0.0, 0.0, 0.0, columns[c, C_PHI * BLOCK + q],
                          alpha)
        rates = Rates(vn_d, vt, vt_d, spin_sum, spin_d, relative_spin, relative_spin_d)
        history = History(False, columns[c, C_PREVIOUS * BLOCK + q], True, columns[c, C_INV_INERTIA * BLOCK + q],
                          columns[c, C_PREVIOUS_ROLL * BLOCK + q])
        (fn, ft, moment, spring, state, slip, roll, normal_damping, tangential_work, sliding, rolling_work,
         rolling_slip) = touching_laws(GATHERED, tangential_model, laws, dt, whole_step, overlap, eta, row, rates,
                                       history)
        ft_centre = tangential.centre_factor(tangential_model, alpha) * ft
        columns[c, C_HOT * BLOCK + q] = 1.0 if columns[c, C_TOUCHED * BLOCK + q] != 0.0 and gap < 0.0 else 0.0
        columns[c, C_FX * BLOCK + q] = fn * nx + ft_centre * tx
        columns[c, C_FY * BLOCK + q] = fn * ny + ft_centre * ty
        columns[c, C_TORQUE_I * BLOCK + q] = -ri * ft + moment
        columns[c, C_TORQUE_J * BLOCK + q] = -rj * ft - moment
        columns[c, C_FN * BLOCK + q] = fn
        columns[c, C_FT * BLOCK + q] = ft
        columns[c, C_GAP * BLOCK + q] = gap
        columns[c, C_SPRING * BLOCK + q] = spring
        columns[c, C_STATUS * BLOCK + q] = state
        columns[c, C_SLIP * BLOCK + q] = slip
        columns[c, C_NORMAL_DAMPING * BLOCK + q] = normal_damping
        columns[c, C_TANGENTIAL_WORK * BLOCK + q] = tangential_work
        columns[c, C_SLIDING * BLOCK + q] = sliding
        columns[c, C_ROLL * BLOCK + q] = roll
        columns[c, C_ROLLING_WORK * BLOCK + q] = rolling_work
        columns[c, C_ROLLING_SLIP * BLOCK + q] = rolling_slip
        columns[c, C_OVERLAP_EXCESS * BLOCK + q] = excess
