"""Linear spring: ``N^e = K_n δ`` for an overlap ``δ = -D_n`` (ratcheting Eq. 6)."""

from ..jit import KERNEL, njit


@njit(**KERNEL)
def force(kn, overlap, ri, rj, is_wall):
    """``K_n δ``."""
    return kn * overlap


@njit(**KERNEL)
def energy(kn, overlap, ri, rj, is_wall):
    """``K_n δ² / 2``."""
    return 0.5 * kn * overlap * overlap


@njit(**KERNEL)
def stiffness(kn, overlap, ri, rj, is_wall):
    """``K_n``, at every overlap."""
    return kn
