"""α-corrected integration: the relative velocity of the centres counts ``alpha = (r_i + r_j)/|r|``
times (ratcheting Eqs. 23–25), so the spring measures the rolling-free displacement of the contact
points and a closed path leaves no residue; the force on the centres carries ``alpha`` too (Eq. 30).
The spring is integrated and limited as Cundall–Strack's."""

from ..jit import KERNEL, njit
from .cundall_strack import limit, trial_spring

__all__ = ["spring_rate", "trial_spring", "limit", "centre_factor"]


@njit(**KERNEL)
def spring_rate(vt, spin_sum, alpha):
    """``dD_t/dt = alpha (v_i - v_j)·t - r_i w_i - r_j w_j`` (Eqs. 24–25)."""
    return alpha * vt - spin_sum


@njit(**KERNEL)
def centre_factor(alpha):
    """``alpha F_t`` on the centres (Eq. 30), so that the work of ``F_t`` is that of its spring."""
    return alpha
