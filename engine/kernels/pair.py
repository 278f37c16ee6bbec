"""The laws of one touching contact, shared by the contact loop and the gathered pass.

:func:`touching_laws` takes what a row's geometry and history give (overlap, relative velocities,
the springs of the step before) and returns its forces, springs and energies. Both callers compute
a touching row with it, so the gathered pass gives the contact loop's results bit for bit by
construction. It is inlined where it is called (``inline="always"``, at Numba's level): as a call, LLVM
would not inline it (too large), and the gathered loop would neither vectorise nor keep its speed
(18 -> 44 ns a row); the direct loop took 38 ns a row instead of 24.
"""

from . import normal, tangential
from .jit import KERNEL, njit
from .laws import cohesion_force, dashpot_share, rolling_step


@njit(**KERNEL, inline="always")
def touching_laws(normal_model, tangential_model, laws, dt, whole_step, overlap, ri, rj, is_wall, eta, vn_d, vt, vt_d,
                  spin_sum, spin_d, alpha, fresh, previous, row, rolling, inv_reduced, previous_roll, relative_spin,
                  relative_spin_d):
    """The step of a contact that overlaps by ``overlap`` > 0: normal spring and dashpot (its share of
    the step, :func:`dashpot_share`, with whole-step dashpots), cohesion, the tangential spring of
    ``tangential_model`` from ``previous`` and, if ``rolling``, the rolling spring from
    ``previous_roll`` (a zero moment without a rolling spring: the gathered pass computes it on
    every row, with or without, and has no branch). The ``_d`` velocities are the dashpots'
    (whole-step or half-step).

    Returns ``(F_n, F_t, moment on i, tangential spring, status, slip, rolling spring, normal
    dashpot's work, tangential viscous work, energy the slip lets go, rolling dashpot's work, energy
    the rolling slip lets go)``."""
    kt = laws.kt
    ne = normal.force(normal_model, laws.kn, overlap, ri, rj, is_wall)
    share = dashpot_share(overlap, vn_d, dt, fresh) if whole_step else 1.0
    fn = ne - share * eta * vn_d + cohesion_force(laws.f0, laws.d0, -overlap)
    rate = tangential.spring_rate(tangential_model, vt, spin_sum, alpha)
    trial = tangential.trial_spring(tangential_model, previous, rate, dt, fresh, row)
    rate_d = tangential.spring_rate(tangential_model, vt_d, spin_d, alpha)
    spring, ft, state, slip = tangential.limit(tangential_model, kt, laws.mu, laws.gamma_t, ne, fn, trial, rate_d)
    roll = moment = rolling_work = rolling_slip = 0.0
    if rolling:
        roll, moment, rolling_work, rolling_slip = rolling_step(laws.kr, laws.mu_r, laws.gamma_r_factor, inv_reduced,
                                                                ne, previous_roll, relative_spin, relative_spin_d, dt)
    # the viscous part of F_t, F_t + K_t D_t, does work (zero while a GranLab spring slides); the
    # elastic force of the step before and of this one are averaged over a slip as velocity Verlet
    # averages them in the kinetic energy: first-order errors cancel
    return (fn, ft, moment if laws.kr > 0.0 else 0.0, spring, state, slip, roll, share * eta * vn_d * vn_d * dt,
            -(ft + kt * spring) * rate_d * dt, 0.5 * kt * (previous + spring) * slip, rolling_work, rolling_slip)
