"""LAMMPS's ``pair_style gran/hooke/history`` (and ``fix wall/gran hooke/history``), as LAMMPS
integrates it, so that a LAMMPS run can be reproduced step for step.

- The history is a shear-displacement vector: each step LAMMPS adds ``V_t dt`` (the relative
  velocity of the contact points, without ``alpha``) and removes the component along the new
  normal. In 2D the vector stays on the tangent line, ``D_t t``, so that is
  ``D_t <- D_t (n_old · n) + rate dt``; a fresh contact starts from ``rate dt``.
- Coulomb limits ``|K_t D_t + Gamma_t V_t|`` by ``mu |F_n|``, the *total* normal force, damping
  (and here cohesion) included, where GranLab's own models limit by the elastic part ``N^e``
  (Gilabert Eq. 8). On sliding LAMMPS rescales the elastic and viscous parts together:
  ``D_t = ratio (D_t + Gamma_t V_t / K_t) - Gamma_t V_t / K_t``.
- The dashpots use the half-step velocities, as LAMMPS's velocity-Verlet does (the registry's
  ``whole_step_dashpots=False``): first order in dt where damping acts.

LAMMPS's ``m_eff gamma_n`` is GranLab's ``eta = 2 zeta sqrt(K_n m_eff)`` and its ``m_eff gamma_t``
is ``Gamma_t``: equal for one pair of masses (a collision), not across a polydisperse packing.
"""

import math

from ...state import STATUS_SLIDE_NEG, STATUS_SLIDE_POS, STATUS_STICK
from ..jit import KERNEL, njit


@njit(**KERNEL)
def spring_rate(vt, spin_sum, alpha):
    """``vtr · t``: the relative velocity of the contact points, ``alpha`` not applied."""
    return vt - spin_sum


@njit(**KERNEL)
def trial_spring(previous, rate, dt, fresh, row):
    """The vector of the step before, projected on the new tangent, plus ``rate dt``.

    The normal of the step before is that of ``r - dt V``: the disks drifted by their half-step
    velocities since (exact to rounding unless the periodic cell deforms). A wall's normal is fixed.
    """
    if fresh:
        return rate * dt
    if row.is_wall:
        return previous + rate * dt
    old_x = row.rx - dt * row.dvx
    old_y = row.ry - dt * row.dvy
    turn = (old_x * row.nx + old_y * row.ny) / math.sqrt(old_x * old_x + old_y * old_y)
    return previous * turn + rate * dt


@njit(**KERNEL)
def limit(kt, mu, gamma_t, ne, fn, trial, rate):
    """Coulomb on ``mu |F_n|`` with the viscous part inside the limit, as LAMMPS rescales it.

    Returns ``(D_t, F_t, status, slip)`` as :func:`granlab.engine.kernels.laws.coulomb` does.
    """
    ft = -kt * trial - gamma_t * rate
    bound = mu * abs(fn)
    if not abs(ft) > bound:  # also mu = inf with F_n = 0 (a NaN bound): no limit
        return trial, ft, STATUS_STICK, 0.0
    if trial == 0.0:
        # LAMMPS: a force from the dashpot alone, beyond the limit, is dropped
        return trial, 0.0, STATUS_SLIDE_POS if ft > 0.0 else STATUS_SLIDE_NEG, 0.0
    ratio = bound / abs(ft)
    viscous = gamma_t * rate / kt
    spring = ratio * (trial + viscous) - viscous
    return spring, ft * ratio, STATUS_SLIDE_POS if ft > 0.0 else STATUS_SLIDE_NEG, trial - spring


@njit(**KERNEL)
def centre_factor(alpha):
    """``F_t`` acts on the centres as it is."""
    return 1.0
