"""The one generic contact loop: geometry of each row of the contact table, then the laws.

Forces and torques are accumulated per chunk of rows into private buffers (no write
races between threads); :func:`granlab.engine.kernels.integrate.particle_pass` sums them. The
virial ``sum_c f_c ⊗ r_c`` is ``sum_i F_i ⊗ x_i`` over disks (summed by the particle
pass) minus the terms this loop adds for the rare rows where that differs: contacts
with walls and through periodic images.

Per row, with ``r = x_i - x_j - image · L`` (for a wall: the distance to the wall
along its normal), ``n = r/|r|``, ``t = z × n``:

- ``V_n = (v_i - v_j) · n`` and ``(v_i - v_j) · t`` include the affine velocity of a
  deforming periodic cell and the velocity of a moving wall;
- the tangential spring ``D_t``, its rate, its Coulomb limit and the factor of ``F_t`` on the
  centres are those of the row's tangential model (:mod:`granlab.engine.kernels.tangential`): the
  loop sets the anchors (body-frame angles of the material points of first contact, ratcheting
  Eq. 21) and hands the model the row's geometry;
- the moment of ``F_t`` is ``-r F_t`` on both disks; the rolling moment ``-K_r dtheta`` on i
  and ``+K_r dtheta`` on j with ``d dtheta/dt = w_i - w_j`` (Gilabert Eq. 10).

On sliding, both anchors move by half the slip, so the rolling distance of Eq. 20 is kept.

Rows are taken in blocks of :data:`granlab.engine.kernels.gathered.BLOCK`: with a linear normal
spring, the rows of a block that touched at the step before and still overlap are computed
together over gathered columns (:mod:`granlab.engine.kernels.gathered`) and only committed here,
in row order; every other row is computed by the loop itself.
"""

import math
from collections import namedtuple

import numpy as np
from numba import literally, prange, uint64

from ..state import STATUS_COHESIVE, STATUS_NONE, STATUS_STICK
from . import tangential
from .gathered import (BLOCK, C_FN, C_FT, C_FX, C_FY, C_GAP, C_HOT, C_NORMAL_DAMPING, C_OVERLAP_EXCESS, C_ROLL,
                       C_ROLLING_SLIP, C_ROLLING_WORK, C_SLIDING, C_SLIP, C_SPRING, C_STATUS, C_TANGENTIAL_WORK,
                       C_TORQUE_I, C_TORQUE_J, compute_block, gather_block)
from .cache import for_model
from .jit import KERNEL, PARALLEL, njit
from .laws import (D0, F0, GAMMA_T, KN, KR, KT, MU, MU_R, ZETA, ZETA_R, cohesion_force,
                   opened_dashpot_share, touching)
from .normal import GATHERED
from .pair import History, Rates, touching_laws
from .tangential import RowGeometry, model_key

# per-chunk scalar tallies
TALLY_DAMPING, TALLY_SLIDING, TALLY_ROLLING, TALLY_WALL_WORK = 0, 1, 2, 3
TALLY_VXX, TALLY_VXY, TALLY_VYX, TALLY_VYY = 4, 5, 6, 7
TALLY_OVERLAPPING, TALLY_MAX_OVERLAP, TALLY_OPENING = 8, 9, 10
TALLY_SIZE = 11

Laws = namedtuple("Laws", "kn kt mu gamma_t f0 d0 kr mu_r gamma_r_factor eta_factor overlap_limit")
"""The contact law's scalars as the loop reads them (:func:`chunk_laws`); the dashpots' factors
are multiplied by the root of a row's reduced mass (normal) or inertia (rolling)."""


@njit(**KERNEL)
def forget(k, status, tangential_spring, rolling_spring, normal_force, tangential_force, kt, kr, springs_after):
    """Row ``k`` stops interacting: its history is forgotten (ratcheting Sec. III A).

    Returns the energy its tangential and rolling springs held if it was touching: released
    without doing work when a contact opens, it is tallied as dissipated. A spring ``D`` that would be
    ``D'`` at the end of the step the contact opened in (``springs_after``: ``(D_t, rolling spring)``)
    held ``K D D' / 2``: the force ``-K D`` of the step before acts on the motion half a step more
    (velocity Verlet's second half-kick), doing the work ``-K D (D' - D) / 2`` on it, and booked so
    the energy closes to second order in dt. ``K D² / 2`` left that work unbooked (an error of first
    order at every opening), ``K ((D + D') / 2)² / 2`` booked ``K (D' - D)² / 8`` too much (a gain of
    second order, of one sign: docs/engine.md, "Energy").
    """
    released = 0.0
    if touching(status[k]):
        spring_after, roll_after = springs_after
        released = 0.5 * (kt * tangential_spring[k] * spring_after + kr * rolling_spring[k] * roll_after)
    status[k] = STATUS_NONE
    tangential_spring[k] = 0.0
    rolling_spring[k] = 0.0
    normal_force[k] = 0.0
    tangential_force[k] = 0.0
    return released


@njit(**KERNEL)
def predicted_relative_motion(predicted, i, j, is_wall, wall_vx, wall_vy, affine_x, affine_y, nx, ny, ri, rj):
    """The dashpots' velocities of a row: ``(V_n, V_t, r_i w_i + r_j w_j, w_i - w_j)`` from the
    velocities and spins predicted at the whole step, where the springs' forces are (second
    order; the half-step ones lag by dt/2). ``affine``: the cell's affine velocity of ``r``."""
    vx = predicted[i, 0] - wall_vx
    vy = predicted[i, 1] - wall_vy
    spin_sum = ri * predicted[i, 2]
    relative_spin = predicted[i, 2]
    if not is_wall:
        vx += affine_x - predicted[j, 0]
        vy += affine_y - predicted[j, 1]
        spin_sum += rj * predicted[j, 2]
        relative_spin -= predicted[j, 2]
    return vx * nx + vy * ny, vy * nx - vx * ny, spin_sum, relative_spin


@njit(**KERNEL)
def image_virial(fx, fy, sx, sy, vxx, vxy, vyx, vyy):
    """The virial corrections with the force ``(fx, fy)`` of a row through the periodic image shifted
    by ``(sx, sy)`` subtracted."""
    return vxx - fx * sx, vxy - fx * sy, vyx - fy * sx, vyy - fy * sy


@njit(**KERNEL)
def chunk_laws(law, overlap_limit):
    """The :data:`Laws` of the law array ``law`` (its slots: :mod:`granlab.engine.kernels.laws`) and
    the run's overlap limit."""
    return Laws(law[KN], law[KT], law[MU], law[GAMMA_T], law[F0], law[D0], law[KR], law[MU_R],
                2.0 * law[ZETA_R] * math.sqrt(law[KR]), 2.0 * law[ZETA] * math.sqrt(law[KN]), overlap_limit)


@njit(**KERNEL)
def anchor(ct, k, angle, i, j, nx, ny, is_wall, xi, yi, wall_shift):
    """A fresh contact: the body-frame angles of the material points that touch (ratcheting
    Eq. 21; along a wall, the point's position along it) and springs at zero."""
    phi = math.atan2(ny, nx)
    ct.anchor_angle_i[k] = phi + math.pi - angle[i]
    if is_wall:
        ct.anchor_angle_j[k] = -ny * xi + nx * yi - wall_shift
    else:
        ct.anchor_angle_j[k] = phi - angle[j]
    ct.tangential_spring[k] = 0.0
    ct.rolling_spring[k] = 0.0


@njit(**KERNEL)
def separated_row(ct, k, laws, gap, vn_d, eta, dt, whole_step, tallies, opening, springs_after):
    """Stage two for a row whose disks do not overlap: what its normal dashpot did in this step's
    window before it opened, its history forgotten (its springs' energy as :func:`forget` takes it,
    with ``springs_after``), the cohesive pull within ``D0``. Returns ``F_n``, whether the row acts
    (``F_n != 0`` or it is cohesive) and the tallies (as :func:`touching_row`'s) and ``opening`` with
    this row's shares added."""
    damping, sliding, rolling_loss, overlapping, max_overlap = tallies
    fn = 0.0
    if whole_step and touching(ct.status[k]):
        share = opened_dashpot_share(gap, vn_d, dt)
        fn = -share * eta * vn_d
        damping += share * eta * vn_d * vn_d * dt
    opening += forget(k, ct.status, ct.tangential_spring, ct.rolling_spring, ct.normal_force, ct.tangential_force,
                      laws.kt, laws.kr, springs_after)
    if laws.f0 > 0.0 and gap < laws.d0:
        fn += cohesion_force(laws.f0, laws.d0, gap)
        ct.status[k] = STATUS_COHESIVE
    acts = fn != 0.0 or ct.status[k] == STATUS_COHESIVE
    return fn, acts, (damping, sliding, rolling_loss, overlapping, max_overlap), opening


@njit(**KERNEL)
def store_row(ct, k, fn, ft, gap, store):
    """The results of row ``k`` kept when ``store`` (the last step of a run)."""
    if store:
        ct.normal_force[k] = fn
        ct.tangential_force[k] = ft
        ct.surface_gap[k] = gap


@njit(**KERNEL)
def contact_forces(p, w, cell, ct, ws, law, run, store, tangential_model, parallel):
    """Contact forces of every row of ``ct``, accumulated into ``run.n_chunks`` chunk buffers of
    the workspace ``ws``, with the normal model, step and overlap limit of ``run``
    (:class:`granlab.engine.state.RunOptions`) and tangential model ``tangential_model`` (a code).

    ``ws.force_buffer (T, N, 3)`` (force x, y and torque per chunk) must be zero on entry
    (the particle pass zeroes it, each chunk's between the disks ``ws.touched`` says its rows touch:
    :func:`granlab.engine.kernels.integrate.chunk_reach`); ``ws.wall_buffer (T, nw)`` and ``ws.tally_buffer (T, TALLY_SIZE)``
    are overwritten. The ``TALLY_V..`` slots get the virial corrections of wall and image rows.
    History (springs, anchors, status) is updated every call; the results ``normal_force``,
    ``tangential_force`` and ``surface_gap`` only when ``store`` (the last step of a run).

    With ``parallel`` None one chunk runs here, in the calling thread, and nothing parallel is
    compiled; with ``parallel`` True the chunks run in parallel. (A parallel launch takes the GIL: a
    single-threaded run never does, so a busy Python thread cannot stall it.) The loop is compiled
    for the model it is called with, which it reads as a literal: nothing is decided per row, and a
    command compiles the models it uses only.
    """
    literally(tangential_model)
    if parallel is None:
        contact_chunk(p, w, cell, ct, ws, law, run, tangential_model, store, np.int64(0))
    else:
        contact_chunks_parallel(p, w, cell, ct, ws, law, run, tangential_model, store)


def _contact_forces_for(tangential_model: int):
    """:func:`contact_forces` with the code of a tangential model as a constant, for calls from Python
    (as :data:`granlab.engine.kernels.integrate.ADVANCE`)."""

    def contact_forces_model(p, w, cell, ct, ws, law, run, store, parallel):
        contact_forces(p, w, cell, ct, ws, law, run, store, tangential_model, parallel)

    contact_forces_model.__qualname__ = contact_forces_model.__name__ = f"contact_forces_{model_key(tangential_model)}"
    return njit(**KERNEL)(for_model(contact_forces_model, tangential_model))


CONTACT_FORCES = {code: _contact_forces_for(code) for code in tangential.MODELS}
"""The contact pass alone by tangential model code (the benchmark's profile times it)."""


@njit(**PARALLEL)
def contact_chunks_parallel(p, w, cell, ct, ws, law, run, tangential_model, store):
    literally(tangential_model)
    for c in prange(run.n_chunks):
        contact_chunk(p, w, cell, ct, ws, law, run, tangential_model, store, np.int64(c))


Geometry = namedtuple("Geometry", "rj nx ny rx ry dvx dvy spin_sum relative_spin alpha gap angle_j wall_shift "
                                   "wall_vx wall_vy")
"""A row's geometry (:func:`pair_geometry`, :func:`wall_geometry`): the other radius (0 for a wall),
normal, branch vector (for a wall, from the wall to the centre), relative velocity of the centres and
spins, ``alpha = (r_i + r_j)/|r|``, the gap ``D_n``, the other body's angle, how far the wall has slid
along itself and its velocity (zero for a disk)."""


@njit(**KERNEL)
def pair_geometry(p, image, k, i, j, length_x, length_y, strain_x, strain_y, reach, status, store):
    """Stage one for a pair of disks: ``(near, Geometry)``. A row not touching (by its ``status``)
    whose centres are ``reach`` or more apart is not near, and only its gap (when ``store``) is computed."""
    ri = p.radius[i]
    rj = p.radius[j]
    rx = p.position[i, 0] - p.position[j, 0] - image[k, 0] * length_x
    ry = p.position[i, 1] - p.position[j, 1] - image[k, 1] * length_y
    r2 = rx * rx + ry * ry
    if r2 >= reach * reach and not touching(status):
        gap = math.sqrt(r2) - ri - rj if store else 0.0
        return False, Geometry(rj, 0.0, 0.0, rx, ry, 0.0, 0.0, 0.0, 0.0, 0.0, gap, 0.0, 0.0, 0.0, 0.0)
    dist = math.sqrt(r2)
    inv_dist = 1.0 / dist
    return True, Geometry(rj, rx * inv_dist, ry * inv_dist, rx, ry,
                          p.velocity[i, 0] - p.velocity[j, 0] + strain_x * rx,
                          p.velocity[i, 1] - p.velocity[j, 1] + strain_y * ry,
                          ri * p.omega[i] + rj * p.omega[j], p.omega[i] - p.omega[j], (ri + rj) * inv_dist,
                          dist - ri - rj, p.angle[j], 0.0, 0.0, 0.0)


@njit(**KERNEL)
def wall_geometry(p, w, i, wall, d0, status):
    """Stage one for a disk and a wall: ``(near, Geometry)``; a row not touching (by its ``status``)
    with a gap of ``d0`` or more is not near."""
    ri = p.radius[i]
    nx = w.normal[wall, 0]
    ny = w.normal[wall, 1]
    dist = nx * p.position[i, 0] + ny * p.position[i, 1] - w.offset[wall]
    gap = dist - ri
    if gap >= d0 and not touching(status):
        return False, Geometry(0.0, nx, ny, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, gap, 0.0, 0.0, 0.0, 0.0)
    wall_vx = w.velocity[wall] * nx - w.tangential_velocity[wall] * ny
    wall_vy = w.velocity[wall] * ny + w.tangential_velocity[wall] * nx
    return True, Geometry(0.0, nx, ny, dist * nx, dist * ny, p.velocity[i, 0] - wall_vx, p.velocity[i, 1] - wall_vy,
                          ri * p.omega[i], p.omega[i], 1.0, gap, 0.0, w.tangential_position[wall], wall_vx, wall_vy)


@njit(**KERNEL)
def far_row(ct, k, laws, gap, store, opening):
    """A row out of reach: its history forgotten if it had one (the released energy added to
    ``opening``, returned: its springs as they were, the row's geometry not computed), its gap kept
    when ``store``."""
    if ct.status[k] != STATUS_NONE:
        opening += forget(k, ct.status, ct.tangential_spring, ct.rolling_spring, ct.normal_force, ct.tangential_force,
                          laws.kt, laws.kr, (ct.tangential_spring[k], ct.rolling_spring[k]))
    if store:
        ct.surface_gap[k] = gap
    return opening


@njit(**KERNEL, inline="always")
def row_geometry(p, ct, k, i, g, is_wall, tangential_model):
    """What the tangential model reads of row ``k`` (a :data:`RowGeometry`) from its :data:`Geometry` ``g``."""
    phi = math.atan2(g.ny, g.nx) if tangential.reads_direction(tangential_model) else 0.0
    return RowGeometry(g.nx, g.ny, g.rx, g.ry, g.dvx, g.dvy, p.radius[i], g.rj, p.angle[i], g.angle_j,
                       ct.anchor_angle_i[k], ct.anchor_angle_j[k], is_wall, p.position[i, 0], p.position[i, 1],
                       g.wall_shift, phi, g.alpha)


@njit(**KERNEL)
def springs_after(p, ct, k, i, g, is_wall, tangential_model, rates, dt):
    """``(D_t, rolling spring)`` of a touching row ``k`` at the end of this step, had it not opened: its
    springs advanced as the laws of a touching row advance them (the trial spring, before any limit)."""
    rate = tangential.spring_rate(tangential_model, rates.vt, rates.spin_sum, g.alpha)
    row = row_geometry(p, ct, k, i, g, is_wall, tangential_model)
    return (tangential.trial_spring(tangential_model, ct.tangential_spring[k], rate, dt, False, row),
            ct.rolling_spring[k] + rates.relative_spin * dt)


@njit(**KERNEL, inline="always")
def touching_row(p, ct, k, i, j, g, is_wall, laws, tangential_model, normal_model, dt, whole_step, eta, rates,
                 tallies):
    """Stage two for a row that overlaps: its anchors set if it is fresh, its laws
    (:func:`granlab.engine.kernels.pair.touching_laws`), its history committed. ``tallies`` is
    ``(damping, sliding, rolling, overlapping, max_overlap)`` before the row; returns ``F_n``, ``F_t``,
    the rolling moment on i and the tallies with the row's shares added, in the loop's order."""
    damping, sliding, rolling_loss, overlapping, max_overlap = tallies
    ri = p.radius[i]
    overlap = -g.gap
    limit_radius = ri if is_wall else min(ri, g.rj)
    if overlap > laws.overlap_limit * limit_radius:
        overlapping += 1
        max_overlap = max(max_overlap, overlap / limit_radius)
    status = ct.status[k]
    fresh = status == STATUS_NONE or status == STATUS_COHESIVE
    if fresh:
        anchor(ct, k, p.angle, i, j, g.nx, g.ny, is_wall, p.position[i, 0], p.position[i, 1], g.wall_shift)
    row = row_geometry(p, ct, k, i, g, is_wall, tangential_model)
    rolling = laws.kr > 0.0
    inv_reduced = p.inv_inertia[i] + (0.0 if is_wall else p.inv_inertia[j]) if rolling else 0.0
    history = History(fresh, 0.0 if fresh else ct.tangential_spring[k], rolling, inv_reduced,
                      0.0 if fresh or not rolling else ct.rolling_spring[k])
    (fn, ft, moment, spring, state, slip, roll, normal_damping, tangential_work, slip_energy, rolling_work,
     rolling_slip) = touching_laws(normal_model, tangential_model, laws, dt, whole_step, overlap, eta, row, rates,
                                   history)
    damping += normal_damping
    if tangential.whole_step_dashpots(tangential_model):
        damping += tangential_work
    else:
        # LAMMPS's model (the only one with half-step dashpots) limits the dashpot's force with the
        # spring's and rescales the two together, which can load the spring as it slides, and a
        # contact can chatter between sticking and sliding: split, either tally could go negative;
        # as one, only by what the rescale itself creates
        sliding += tangential_work
    if state != STATUS_STICK:
        sliding += slip_energy
        ct.anchor_angle_i[k] += 0.5 * slip / ri
        ct.anchor_angle_j[k] += 0.5 * slip if is_wall else 0.5 * slip / g.rj
    ct.tangential_spring[k] = spring
    ct.status[k] = state
    if rolling:
        damping += rolling_work
        rolling_loss += rolling_slip
        ct.rolling_spring[k] = roll
    return fn, ft, moment, (damping, sliding, rolling_loss, overlapping, max_overlap)


@njit(**KERNEL, inline="always")
def gathered_row(ct, columns, c, q, k, radius, i, j, kr, tangential_model, store, tallies):
    """Stage two for a row the gathered pass computed (:mod:`granlab.engine.kernels.gathered`): its
    history committed from the columns; returns its force on i, its torques on i and j and the
    tallies (as :func:`touching_row`'s) with its shares added, in the direct pass's order."""
    damping, sliding, rolling_loss, overlapping, max_overlap = tallies
    excess = columns[c, C_OVERLAP_EXCESS * BLOCK + q]
    if excess != 0.0:
        overlapping += 1
        max_overlap = max(max_overlap, excess)
    damping += columns[c, C_NORMAL_DAMPING * BLOCK + q]
    if tangential.whole_step_dashpots(tangential_model):
        damping += columns[c, C_TANGENTIAL_WORK * BLOCK + q]
    else:
        sliding += columns[c, C_TANGENTIAL_WORK * BLOCK + q]
    state = int(columns[c, C_STATUS * BLOCK + q])
    if state != STATUS_STICK:
        slip = columns[c, C_SLIP * BLOCK + q]
        sliding += columns[c, C_SLIDING * BLOCK + q]
        ct.anchor_angle_i[k] += 0.5 * slip / radius[i]
        ct.anchor_angle_j[k] += 0.5 * slip / radius[j]
    ct.tangential_spring[k] = columns[c, C_SPRING * BLOCK + q]
    ct.status[k] = state
    if kr > 0.0:
        damping += columns[c, C_ROLLING_WORK * BLOCK + q]
        rolling_loss += columns[c, C_ROLLING_SLIP * BLOCK + q]
        ct.rolling_spring[k] = columns[c, C_ROLL * BLOCK + q]
    if store:
        ct.normal_force[k] = columns[c, C_FN * BLOCK + q]
        ct.tangential_force[k] = columns[c, C_FT * BLOCK + q]
        ct.surface_gap[k] = columns[c, C_GAP * BLOCK + q]
    return (columns[c, C_FX * BLOCK + q], columns[c, C_FY * BLOCK + q], columns[c, C_TORQUE_I * BLOCK + q],
            columns[c, C_TORQUE_J * BLOCK + q], (damping, sliding, rolling_loss, overlapping, max_overlap))


Frame = namedtuple("Frame", "n length_x length_y strain_x strain_y dt whole_step store normal_model")
"""What every row of a contact pass shares: the number of disks (a row's ``j`` at or past it is a wall),
the periodic cell's lengths and affine strain rates, the step, whether the dashpots take the
whole-step velocities, whether the results are kept (``store``) and the normal law's code."""


@njit(**KERNEL, inline="always")
def direct_row(p, w, ct, k, i, j, frame, laws, tangential_model, tallies, opening):
    """Stages one and two of row ``k`` (disks or disk and wall ``i``, ``j``), as the contact loop
    computes a row itself: its geometry, then its laws (a touching or a separated row) or its history
    forgotten (a row out of reach). Returns ``(acts, is_wall, Geometry, F_x, F_y, torque on i, torque
    on j, tallies, opening)``: a row that does not act adds no force. Shared by the contact loop and
    the CUDA backend's (:mod:`granlab.engine.cuda`), which add the force each in its own way."""
    is_wall = j >= frame.n
    if is_wall:
        near, g = wall_geometry(p, w, i, j - frame.n, laws.d0, ct.status[k])
    else:
        near, g = pair_geometry(p, ct.image, k, i, j, frame.length_x, frame.length_y, frame.strain_x,
                                frame.strain_y, p.radius[i] + p.radius[j] + laws.d0, ct.status[k], frame.store)
    if not near:
        opening = far_row(ct, k, laws, g.gap, frame.store, opening)
        return False, is_wall, g, 0.0, 0.0, 0.0, 0.0, tallies, opening
    rates = dashpot_rates(p, i, j, is_wall, g, frame.strain_x, frame.strain_y, frame.whole_step)
    eta = laws.eta_factor * ct.root_reduced_mass[k]
    if g.gap < 0.0:
        fn, ft, moment, tallies = touching_row(p, ct, k, i, j, g, is_wall, laws, tangential_model,
                                               frame.normal_model, frame.dt, frame.whole_step, eta, rates, tallies)
    else:
        after = (0.0, 0.0)
        if touching(ct.status[k]):
            after = springs_after(p, ct, k, i, g, is_wall, tangential_model, rates, frame.dt)
        fn, acts, tallies, opening = separated_row(ct, k, laws, g.gap, rates.vn_d, eta, frame.dt, frame.whole_step,
                                                   tallies, opening, after)
        ft = 0.0
        moment = 0.0
        if not acts:
            if frame.store:
                ct.surface_gap[k] = g.gap
            return False, is_wall, g, 0.0, 0.0, 0.0, 0.0, tallies, opening
    store_row(ct, k, fn, ft, g.gap, frame.store)
    ft_centre = tangential.centre_factor(tangential_model, g.alpha) * ft
    fx = fn * g.nx + ft_centre * -g.ny
    fy = fn * g.ny + ft_centre * g.nx
    ri = p.radius[i]
    return True, is_wall, g, fx, fy, -ri * ft + moment, -g.rj * ft - moment, tallies, opening


@njit(**KERNEL)
def dashpot_rates(p, i, j, is_wall, g, strain_x, strain_y, whole_step):
    """The row's :data:`Rates`: the relative velocities the springs take (half-step) and the ones the
    dashpots take (:func:`predicted_relative_motion` with ``whole_step``, else the same)."""
    vn = g.dvx * g.nx + g.dvy * g.ny
    vt = g.dvx * -g.ny + g.dvy * g.nx
    if whole_step:
        vn_d, vt_d, spin_d, relative_spin_d = predicted_relative_motion(
            p.predicted_motion, i, j, is_wall, g.wall_vx, g.wall_vy, strain_x * g.rx, strain_y * g.ry, g.nx, g.ny,
            p.radius[i], g.rj)
        return Rates(vn_d, vt, vt_d, g.spin_sum, spin_d, g.relative_spin, relative_spin_d)
    return Rates(vn, vt, vt, g.spin_sum, g.spin_sum, g.relative_spin, g.relative_spin)


@njit(**KERNEL)
def add_pair_force(force_buffer, c, i, j, fx, fy, torque_i, torque_j, image, k, length_x, length_y, virial):
    """Stage three for a pair: the force on i and its opposite on j, the torques, into chunk ``c``'s
    buffer; ``virial`` ``(vxx, vxy, vyx, vyy)`` corrected for a row through a periodic image."""
    force_buffer[c, i, 0] += fx
    force_buffer[c, i, 1] += fy
    force_buffer[c, i, 2] += torque_i
    force_buffer[c, j, 0] -= fx
    force_buffer[c, j, 1] -= fy
    force_buffer[c, j, 2] += torque_j
    if image[k, 0] != 0 or image[k, 1] != 0:
        vxx, vxy, vyx, vyy = virial
        return image_virial(fx, fy, image[k, 0] * length_x, image[k, 1] * length_y, vxx, vxy, vyx, vyy)
    return virial


@njit(**KERNEL)
def add_wall_force(force_buffer, wall_buffer, c, i, wall, fx, fy, torque_i, g, x, y, dt, wall_work, virial):
    """Stage three for a wall: the force on disk i and its push on the wall along its normal; the
    wall's work on the disk added to ``wall_work`` and the virial corrected (returned)."""
    force_buffer[c, i, 0] += fx
    force_buffer[c, i, 1] += fy
    force_buffer[c, i, 2] += torque_i
    wall_buffer[c, wall] -= fx * g.nx + fy * g.ny
    wall_work += (fx * g.wall_vx + fy * g.wall_vy) * dt
    vxx, vxy, vyx, vyy = virial
    return wall_work, (vxx - fx * x, vxy - fx * y, vyx - fy * x, vyy - fy * y)


@njit(**KERNEL)
def write_tallies(tally_buffer, c, tallies, wall_work, virial, opening):
    """Stage four: chunk ``c``'s tallies (``TALLY_*``)."""
    damping, sliding, rolling_loss, overlapping, max_overlap = tallies
    tally_buffer[c, TALLY_DAMPING] = damping
    tally_buffer[c, TALLY_SLIDING] = sliding
    tally_buffer[c, TALLY_ROLLING] = rolling_loss
    tally_buffer[c, TALLY_WALL_WORK] = wall_work
    tally_buffer[c, TALLY_VXX] = virial[0]
    tally_buffer[c, TALLY_VXY] = virial[1]
    tally_buffer[c, TALLY_VYX] = virial[2]
    tally_buffer[c, TALLY_VYY] = virial[3]
    tally_buffer[c, TALLY_OVERLAPPING] = overlapping
    tally_buffer[c, TALLY_MAX_OVERLAP] = max_overlap
    tally_buffer[c, TALLY_OPENING] = opening


@njit(**KERNEL)
def contact_chunk(p, w, cell, ct, ws, law, run, tangential_model, store, c):
    """Rows ``[c count / n_chunks, (c + 1) count / n_chunks)`` into chunk buffer ``c``, with the laws
    of tangential model ``tangential_model`` (a compile-time code), in four stages: a row's geometry
    (:func:`pair_geometry`, :func:`wall_geometry`), the laws of a touching row (:func:`touching_row`,
    or :func:`gathered_row` for a row the gathered pass computed; :func:`separated_row` for one that
    does not overlap; the first two stages of a row are :func:`direct_row`), its force added to the chunk's buffers (:func:`add_pair_force`,
    :func:`add_wall_force`), and the chunk's tallies (:func:`write_tallies`). The stages that carry
    the laws are inlined at Numba's level (as :func:`granlab.engine.kernels.pair.touching_laws`); the
    others are left to LLVM, which inlines them: forced, the direct pass took 5 % longer a row.
    Each stage adds its shares to the tallies in the order of the loop before it was staged: the
    sums, and so the runs, are the same bit for bit."""
    literally(tangential_model)
    dt, n_chunks = run.dt, run.n_chunks
    force_buffer, wall_buffer = ws.force_buffer, ws.wall_buffer
    length_x = cell.length[0]
    length_y = cell.length[1]
    strain_x = cell.rate[0] / length_x if length_x > 0.0 else 0.0
    strain_y = cell.rate[1] / length_y if length_y > 0.0 else 0.0
    count = ct.count[0]
    n = uint64(p.position.shape[0])
    laws = chunk_laws(law, run.max_overlap)
    # without a dashpot the dashpots' velocities multiply zero: the half-step ones serve, unread
    whole_step = tangential.whole_step_dashpots(tangential_model) and (
        laws.eta_factor > 0.0 or laws.gamma_t > 0.0 or laws.gamma_r_factor > 0.0)
    lo = uint64(c * count // n_chunks)
    hi = uint64((c + 1) * count // n_chunks)
    for m in range(w.offset.shape[0]):
        wall_buffer[c, m] = 0.0
    tallies = (0.0, 0.0, 0.0, 0, 0.0)  # damping, sliding, rolling, overlapping, max_overlap
    wall_work = opening = 0.0
    virial = (0.0, 0.0, 0.0, 0.0)  # corrections: vxx, vxy, vyx, vyy
    columns = ws.row_columns
    gathered = run.gathered and run.normal_model == GATHERED
    frame = Frame(n, length_x, length_y, strain_x, strain_y, dt, whole_step, store, run.normal_model)
    for k in range(lo, hi):
        q = (k - lo) % BLOCK
        if gathered and q == 0:
            end = min(hi, k + BLOCK)
            gather_block(p, cell.length, (strain_x, strain_y), ct, columns, c, k, end, laws.kr > 0.0,
                         tangential.reads_direction(tangential_model))
            compute_block(columns, c, end - k, laws, tangential_model, dt, run.max_overlap, whole_step)
        i = uint64(ct.particle_i[k])
        j = uint64(ct.particle_j[k])
        if gathered and columns[c, C_HOT * BLOCK + q] != 0.0:
            fx, fy, torque_i, torque_j, tallies = gathered_row(ct, columns, c, q, k, p.radius, i, j, laws.kr,
                                                               tangential_model, store, tallies)
            virial = add_pair_force(force_buffer, c, i, j, fx, fy, torque_i, torque_j, ct.image, k, length_x,
                                    length_y, virial)
            continue
        acts, is_wall, g, fx, fy, torque_i, torque_j, tallies, opening = direct_row(
            p, w, ct, k, i, j, frame, laws, tangential_model, tallies, opening)
        if not acts:
            continue
        if is_wall:
            wall_work, virial = add_wall_force(force_buffer, wall_buffer, c, i, j - frame.n, fx, fy, torque_i, g,
                                               p.position[i, 0], p.position[i, 1], dt, wall_work, virial)
        else:
            virial = add_pair_force(force_buffer, c, i, j, fx, fy, torque_i, torque_j, ct.image, k, length_x,
                                    length_y, virial)
    write_tallies(ws.tally_buffer, c, tallies, wall_work, virial, opening)


def _single_row_for(tangential_model: int):
    """:func:`direct_row` for one row alone, with tangential model ``tangential_model`` as a constant: its
    force and tallies returned, not added (the CUDA backend adds them, a thread a row)."""

    def single_row(p, w, cell, ct, law, k, dt, max_overlap, normal_model, store):
        """Returns whether row ``k`` acts, whether on a wall, its disk ``i``, its disk or wall ``j``, its force
        and torques on i and j, its push on a wall along the wall's normal, and its tallies (in the order of
        the ``TALLY_*`` slots)."""
        length_x = cell.length[0]
        length_y = cell.length[1]
        strain_x = cell.rate[0] / length_x if length_x > 0.0 else 0.0
        strain_y = cell.rate[1] / length_y if length_y > 0.0 else 0.0
        laws = chunk_laws(law, max_overlap)
        whole_step = tangential.whole_step_dashpots(tangential_model) and (
            laws.eta_factor > 0.0 or laws.gamma_t > 0.0 or laws.gamma_r_factor > 0.0)
        n = uint64(p.position.shape[0])
        frame = Frame(n, length_x, length_y, strain_x, strain_y, dt, whole_step, store, normal_model)
        i = uint64(ct.particle_i[k])
        j = uint64(ct.particle_j[k])
        acts, is_wall, g, fx, fy, torque_i, torque_j, tallies, opening = direct_row(
            p, w, ct, k, i, j, frame, laws, tangential_model, (0.0, 0.0, 0.0, 0, 0.0), 0.0)
        damping, sliding, rolling_loss, overlapping, max_overlap = tallies
        wall_work = vxx = vxy = vyx = vyy = 0.0
        if acts and is_wall:
            x = p.position[i, 0]
            y = p.position[i, 1]
            wall_work = (fx * g.wall_vx + fy * g.wall_vy) * dt
            vxx, vxy, vyx, vyy = -fx * x, -fx * y, -fy * x, -fy * y
        elif acts and (ct.image[k, 0] != 0 or ct.image[k, 1] != 0):
            vxx, vxy, vyx, vyy = image_virial(fx, fy, ct.image[k, 0] * length_x, ct.image[k, 1] * length_y,
                                              0.0, 0.0, 0.0, 0.0)
        return (acts, is_wall, i, j - n if is_wall else j, fx, fy, torque_i, torque_j, fx * g.nx + fy * g.ny,
                (damping, sliding, rolling_loss, wall_work, vxx, vxy, vyx, vyy, float(overlapping), max_overlap,
                 opening))

    single_row.__qualname__ = single_row.__name__ = f"single_row_{model_key(tangential_model)}"
    return njit(**KERNEL)(for_model(single_row, tangential_model))


SINGLE_ROW = {code: _single_row_for(code) for code in tangential.MODELS}
"""One row alone by tangential model code (:func:`_single_row_for`)."""
