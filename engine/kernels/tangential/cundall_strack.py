"""Cundall–Strack: the spring integrates the relative tangential velocity of the contact points
(ratcheting Eqs. 7–11); a closed path leaves it the residue of Eq. 17."""

from ..jit import KERNEL, njit
from ..laws import coulomb


@njit(**KERNEL)
def spring_rate(vt, spin_sum, alpha):
    """``dD_t/dt = (v_i - v_j)·t - r_i w_i - r_j w_j`` (Eq. 9)."""
    return vt - spin_sum


@njit(**KERNEL)
def trial_spring(previous, rate, dt, fresh, row):
    """The spring of the step before, advanced by ``rate dt``; a fresh contact starts unstretched."""
    if fresh:
        return 0.0
    return previous + rate * dt


@njit(**KERNEL)
def limit(kt, mu, gamma_t, ne, fn, trial, rate):
    """Coulomb on the elastic normal force ``N^e`` (Gilabert Eq. 8): :func:`granlab.engine.kernels.laws.coulomb`."""
    return coulomb(kt, mu, gamma_t, ne, trial, rate)


@njit(**KERNEL)
def centre_factor(alpha):
    """``F_t`` acts on the centres as it is."""
    return 1.0
