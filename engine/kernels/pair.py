"""The laws of one touching contact, shared by the contact loop and the gathered pass.

:func:`touching_laws` takes what a row's geometry and history give (overlap, relative velocities,
the springs of the step before) and returns its forces, springs and energies. Both callers compute
a touching row with it, so the gathered pass gives the contact loop's results bit for bit by
construction. It is inlined where it is called (``inline="always"``, at Numba's level): as a call, LLVM
would not inline it (too large), and the gathered loop would neither vectorise nor keep its speed
(18 -> 44 ns a row); the direct loop took 38 ns a row instead of 24.
"""

from collections import namedtuple

from . import normal, tangential
from .jit import KERNEL, njit
from .laws import cohesion_force, dashpot_share, rolling_step


Rates = namedtuple("Rates", "vn_d vt vt_d spin_sum spin_d relative_spin relative_spin_d")
"""A touching row's rates: the relative tangential velocity of the centres ``vt``, the spins' sum
``r_i w_i + r_j w_j`` and difference ``w_i - w_j`` the springs take (half-step), and those the
dashpots take (``_d``: whole-step or half-step, as the tangential model says), ``V_n`` among them."""

History = namedtuple("History", "fresh previous rolling inv_reduced previous_roll")
"""What a touching row brings from the step before: whether it is ``fresh`` (its first step), its
tangential spring, whether a rolling spring acts (``rolling``), ``1/I_i + 1/I_j`` (0 unless it does)
and its rolling spring."""


@njit(**KERNEL, inline="always")
def touching_laws(normal_model, tangential_model, laws, dt, whole_step, overlap, eta, row, rates, history):
    """The step of a contact that overlaps by ``overlap`` > 0 (its geometry ``row``, a
    :data:`granlab.engine.kernels.tangential.RowGeometry`): normal spring of law ``normal_model`` and
    dashpot ``eta`` (its share of the step, :func:`dashpot_share`, with whole-step dashpots), cohesion,
    the tangential spring of ``tangential_model`` and, if ``history.rolling``, the rolling spring (a
    zero moment without a rolling spring: the gathered pass computes it on every row, with or without,
    and has no branch).

    Returns ``(F_n, F_t, moment on i, tangential spring, status, slip, rolling spring, normal
    dashpot's work, tangential viscous work, energy the slip lets go, rolling dashpot's work, energy
    the rolling slip lets go)``."""
    kt = laws.kt
    vn_d = rates.vn_d
    ne = normal.force(normal_model, laws.kn, overlap, row.ri, row.rj, row.is_wall)
    share = dashpot_share(overlap, vn_d, dt, history.fresh) if whole_step else 1.0
    fn = ne - share * eta * vn_d + cohesion_force(laws.f0, laws.d0, -overlap)
    rate = tangential.spring_rate(tangential_model, rates.vt, rates.spin_sum, row.alpha)
    trial = tangential.trial_spring(tangential_model, history.previous, rate, dt, history.fresh, row)
    rate_d = tangential.spring_rate(tangential_model, rates.vt_d, rates.spin_d, row.alpha)
    spring, ft, state, slip = tangential.limit(tangential_model, kt, laws.mu, laws.gamma_t, ne, fn, trial, rate_d)
    roll = moment = rolling_work = rolling_slip = 0.0
    if history.rolling:
        roll, moment, rolling_work, rolling_slip = rolling_step(laws.kr, laws.mu_r, laws.gamma_r_factor,
                                                                history.inv_reduced, ne, history.previous_roll,
                                                                rates.relative_spin, rates.relative_spin_d, dt)
    # the viscous part of F_t, F_t + K_t D_t, does work (zero while a GranLab spring slides); the
    # elastic force of the step before and of this one are averaged over a slip as velocity Verlet
    # averages them in the kinetic energy: first-order errors cancel
    return (fn, ft, moment if laws.kr > 0.0 else 0.0, spring, state, slip, roll, share * eta * vn_d * vn_d * dt,
            -(ft + kt * spring) * rate_d * dt, 0.5 * kt * (history.previous + spring) * slip, rolling_work,
            rolling_slip)
