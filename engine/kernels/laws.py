"""Contact laws: small scalar functions called by the one generic contact loop (the normal elastic
laws are a family of their own, :mod:`granlab.engine.kernels.normal`).

Conventions (ratcheting paper, Fig. 7): ``n`` points from j to i, ``t = z × n``,
``F_n > 0`` repels, ``D_n < 0`` is an overlap (Gilabert's ``h = D_n``). The
elastic repulsive part ``N^e >= 0`` alone bounds the tangential force and the
rolling moment (Gilabert Eqs. 8, 10).

The runtime parameters travel in one float64 vector indexed by ``KN, KT, ...``
(see :func:`granlab.engine.simulation.law_vector`), so a slider never recompiles a kernel.
"""

import math

from ..state import STATUS_SLIDE_NEG, STATUS_SLIDE_POS, STATUS_STICK
from .jit import KERNEL, njit

# layout of the law vector
KN, KT, MU, ZETA, GAMMA_T, F0, D0, KR, MU_R, ZETA_R = range(10)
LAW_SIZE = 10

TWO_PI = 2.0 * math.pi


@njit(**KERNEL)
def touching(status):
    """Whether a row of this status is a contact, sticking or sliding (not a distant attraction)."""
    return status == STATUS_STICK or status == STATUS_SLIDE_POS or status == STATUS_SLIDE_NEG


@njit(**KERNEL)
def wrap_angle(x):
    """``x`` brought into [-pi, pi)."""
    return x - TWO_PI * math.floor((x + math.pi) / TWO_PI)


@njit(**KERNEL)
def disk_arc(radius, phi, angle, anchor):
    """Signed arc ``r wrap(phi - theta - a)`` on a disk of angle ``theta`` from the material point
    of first contact (at ``a`` in the disk's frame) to the contact point in direction ``phi``
    (ratcheting Eqs. 18-20; the first disk of a pair sees its contact in direction ``phi + pi``)."""
    return radius * wrap_angle(phi - angle - anchor)


@njit(**KERNEL)
def wall_arc(tx, ty, x, y, wall_shift, anchor):
    """Distance along a wall (tangent ``(tx, ty)``, slid by ``wall_shift``) from the point of first
    contact ``anchor`` to the foot of a disk at ``(x, y)``: a wall's :func:`disk_arc`."""
    return tx * x + ty * y - wall_shift - anchor


@njit(**KERNEL)
def cohesion_force(f0, d0, gap):
    """Attraction ``N^a <= 0`` (Gilabert Eqs. 4-5): ``-F0`` in contact, linear to zero at ``gap = D0``."""
    if f0 == 0.0 or gap > d0:
        return 0.0
    if gap <= 0.0:
        return -f0
    return -f0 * (1.0 - gap / d0)


@njit(**KERNEL)
def cohesion_potential(f0, d0, gap):
    """Potential of :func:`cohesion_force` (zero beyond ``D0``, continuous at contact)."""
    if f0 == 0.0 or gap >= d0:
        return 0.0
    if gap >= 0.0:
        return -0.5 * f0 * (d0 - gap) ** 2 / d0
    return -0.5 * f0 * d0 + f0 * gap


@njit(**KERNEL)
def root_reduced_mass(inv_mass_i, inv_mass_j):
    """``sqrt(m_i m_j / (m_i + m_j))``; walls and fixed disks have 1/m = 0 (0 if both do).

    The viscous coefficient of Gilabert Eq. 6 is
    ``eta = zeta sqrt(4 K_n m_i m_j / (m_i + m_j)) = 2 zeta sqrt(K_n) root_reduced_mass``.
    """
    inv_sum = inv_mass_i + inv_mass_j
    if inv_sum == 0.0:
        return 0.0
    return math.sqrt(1.0 / inv_sum)


@njit(**KERNEL)
def coulomb(kt, mu, gamma_t, ne, spring, rate):
    """Tangential force with the Coulomb limit (quasi-rigidity Eqs. 7, 11-12; ratcheting Eq. 11).

    The contact slides when its elastic force ``|K_t D_t|`` would exceed ``mu N^e``: then
    ``F_t = ±mu N^e`` with no viscous part (quasi-rigidity: Gamma_t = 0 while sliding) and
    ``D_t = -F_t / K_t``. Otherwise it sticks: ``F_t = -K_t D_t - Gamma_t V_t``, the viscous
    part clipped so that ``|F_t| <= mu N^e``.
    Returns ``(D_t, F_t, status, slip)`` where ``slip = D_t(trial) - D_t``.
    """
    elastic = -kt * spring
    limit = mu * ne
    if abs(elastic) <= limit:
        ft = min(limit, max(-limit, elastic - gamma_t * rate))
        return spring, ft, STATUS_STICK, 0.0
    if elastic > 0.0:
        new_spring = -limit / kt
        return new_spring, limit, STATUS_SLIDE_POS, spring - new_spring
    new_spring = limit / kt
    return new_spring, -limit, STATUS_SLIDE_NEG, spring - new_spring


@njit(**KERNEL)
def rolling(kr, mu_r, gamma_r, ne, spring, rate):
    """Elastic-plastic rolling spring (Gilabert Eq. 10), with an optional viscous part.

    ``spring`` is the trial elastic relative rotation and ``rate = w_i - w_j``; the moment on
    disk i is ``-K_r spring - Gamma_r rate``, limited by ``mu_r N^e`` (the viscous part acts
    while the spring holds, like ``Gamma_t`` in :func:`coulomb`). Returns ``(spring, moment_i, slip)``.
    """
    elastic = -kr * spring
    limit = mu_r * ne
    if abs(elastic) <= limit:
        return spring, min(limit, max(-limit, elastic - gamma_r * rate)), 0.0
    bounded = limit if elastic > 0.0 else -limit
    new_spring = -bounded / kr
    return new_spring, bounded, spring - new_spring


@njit(**KERNEL)
def opened_dashpot_share(gap, vn, dt):
    """For a contact that opened since the step before: the share of this step's window before
    it opened, ``gap / V_n`` ago (see :func:`dashpot_share`)."""
    if vn > 0.0 and gap < 0.5 * vn * dt:
        return 0.5 - gap / (vn * dt)
    return 0.0

@njit(**KERNEL)
def dashpot_share(overlap, vn, dt, fresh):
    """The share of the step's window ``[t - dt/2, t + dt/2]`` the contact spends touching,
    estimated from its overlap and normal velocity, by which its normal dashpot is multiplied.

    Velocity Verlet applies the force of step t over that window. The spring's force vanishes
    where a contact begins and ends, the dashpot's does not: applied over whole windows, it
    starts and stops up to dt/2 early or late, a first-order error. A fresh contact began
    ``overlap / -V_n`` ago, and what of that lies in the window before (which had no force) is
    added here; a separating one opens in ``overlap / V_n``, and only what lies in this window
    counts (the rest is :func:`opened_dashpot_share`'s, at the next step).
    """
    share = 1.0
    # V_n's sign flips at random in a packing at rest: each test below is one predictable branch
    if fresh and overlap < -min(vn, 0.0) * dt:
        share = overlap / (-vn * dt) + 0.5
    if overlap < 0.5 * max(vn, 0.0) * dt:
        share += overlap / (vn * dt) - 0.5
    return share

@njit(**KERNEL)
def rolling_step(kr, mu_r, gamma_r_factor, inv_reduced, ne, previous, relative_spin, relative_spin_d, dt):
    """The rolling spring of a contact over one step (Gilabert Eq. 10): its relative rotation
    advanced by the half-step spins, its dashpot on the whole-step ones. Returns the spring, the
    moment on disk i, the work of the dashpot and the energy the slip lets go."""
    gamma_r = 0.0
    if gamma_r_factor > 0.0 and inv_reduced > 0.0:
        gamma_r = gamma_r_factor / math.sqrt(inv_reduced)
    roll, moment, slip = rolling(kr, mu_r, gamma_r, ne, previous + relative_spin * dt, relative_spin_d)
    viscous_work = -(moment + kr * roll) * relative_spin_d * dt if slip == 0.0 else 0.0
    return roll, moment, viscous_work, 0.5 * kr * (previous + roll) * slip
