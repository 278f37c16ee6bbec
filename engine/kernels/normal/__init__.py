"""Normal elastic laws: one module each, named in the registry :data:`granlab.engine.params.NORMAL`.

A law module holds three small kernels of ``(kn, overlap, ri, rj, is_wall)``, for an overlap
``δ = -D_n > 0`` of disk i (radius ``ri``) with disk j (``rj``) or with a wall (``is_wall``,
``rj = 0``) and the law's stiffness scale ``K_n``:

- ``force``: the elastic repulsion ``N^e >= 0``, the part of ``F_n`` that bounds ``F_t`` and the
  rolling moment (Gilabert Eqs. 8, 10);
- ``energy``: what the spring stores, the integral of ``force`` from 0 to ``δ``;
- ``stiffness``: ``dN^e/dδ``, the tangent stiffness the stiffness matrix, the contact status and the
  quasi-static stepper take (quasi-rigidity Sec. 2), and the time step's bound
  (:func:`largest_stiffness`).

A module without one of the three does not register: importing the engine says which it lacks
(:class:`granlab.engine.errors.RegistryError`). Adding a law is its module here and its line in the
registry.

The functions below dispatch on a law's code at run time, one branch per law, the same branch for
every row of a run. The gathered contact pass computes its rows with :data:`GATHERED`'s law alone:
its force has no branch and vectorises; a row of any other law is computed by the direct pass.
"""

import importlib

import numpy as np

from ...errors import RegistryError
from ...params import NORMAL
from ..jit import JIT, KERNEL, njit

PARTS = ("force", "energy", "stiffness")
MODELS = {model.code: importlib.import_module(f".{model.key}", __name__) for model in NORMAL.values()}
CODES = tuple(sorted(MODELS))
GATHERED = NORMAL["linear"].code
"""The law the gathered contact pass is compiled for (:mod:`granlab.engine.kernels.gathered`)."""


def _check_parts():
    for model in NORMAL.values():
        missing = [part for part in PARTS if not callable(getattr(MODELS[model.code], part, None))]
        if missing:
            raise RegistryError("normal law", model.name, MODELS[model.code].__file__, missing,
                                "force, energy and stiffness of (kn, overlap, ri, rj, is_wall)")


_check_parts()

_INLINED = {**KERNEL, "cache": False, "inline": "always"}
"""The dispatchers are compiled into the kernels that call them (which are cached), not on their own."""


def _branch(code, law, rest):
    @njit(**_INLINED)
    def branch(model, kn, overlap, ri, rj, is_wall):
        if model == code:
            return law(kn, overlap, ri, rj, is_wall)
        return rest(model, kn, overlap, ri, rj, is_wall)

    return branch


def _dispatcher(part):
    """``part`` of the law whose code is the first argument: a chain of one branch per law (the
    last law's is taken for any code, which the registry guarantees to be one of them)."""
    last = getattr(MODELS[CODES[-1]], part)

    @njit(**_INLINED)
    def dispatch(model, kn, overlap, ri, rj, is_wall):
        return last(kn, overlap, ri, rj, is_wall)

    for code in reversed(CODES[:-1]):
        dispatch = _branch(code, getattr(MODELS[code], part), dispatch)
    return dispatch


_force, _energy, stiffness = (_dispatcher(part) for part in PARTS)


@njit(**_INLINED)
def force(model, kn, overlap, ri, rj, is_wall):
    """``N^e`` of law ``model`` (a code); zero when apart (``overlap <= 0``)."""
    if overlap <= 0.0:
        return 0.0
    return _force(model, kn, overlap, ri, rj, is_wall)


@njit(**_INLINED)
def energy(model, kn, overlap, ri, rj, is_wall):
    """The energy law ``model`` stores; zero when apart."""
    if overlap <= 0.0:
        return 0.0
    return _energy(model, kn, overlap, ri, rj, is_wall)


@njit(**JIT)
def _rows(model, kn, overlap, ri, rj, is_wall, tangent):
    out = np.empty(overlap.shape[0])
    for k in range(overlap.shape[0]):
        if tangent:
            out[k] = stiffness(model, kn, overlap[k], ri[k], rj[k], is_wall[k])
        else:
            out[k] = force(model, kn, overlap[k], ri[k], rj[k], is_wall[k])
    return out


def forces(model, kn, overlap, ri, rj, is_wall):
    """:func:`force` of each row of the arrays ``overlap``, ``ri``, ``rj``, ``is_wall``."""
    return _rows(model, kn, overlap, ri, rj, is_wall, False)


def stiffnesses(model, kn, overlap, ri, rj, is_wall):
    """:func:`stiffness` of each row, at overlaps ``>= 0``."""
    return _rows(model, kn, overlap, ri, rj, is_wall, True)


def largest_stiffness(name: str, kn: float, radius: np.ndarray, max_overlap: float = 0.5) -> float:
    """The time step's stiffness for law ``name`` and disks of radii ``radius``: ``K_n``, or the law's
    tangent stiffness where it exceeds ``K_n`` at overlaps up to ``max_overlap`` of the smaller radius
    (pairs of the smallest and of the largest disks, and each against a wall)."""
    small, large = float(np.min(radius)), float(np.max(radius))
    fractions = np.linspace(0.0, max_overlap, 33)[1:]
    ri, rj, is_wall = [], [], []
    for a, b, wall in ((small, small, False), (large, large, False), (small, large, False), (small, 0.0, True),
                       (large, 0.0, True)):
        ri.append(np.full(fractions.size, a))
        rj.append(np.full(fractions.size, b))
        is_wall.append(np.full(fractions.size, wall))
    ri, rj, is_wall = np.concatenate(ri), np.concatenate(rj), np.concatenate(is_wall)
    overlap = np.tile(fractions, 5) * np.where(is_wall, ri, np.minimum(ri, rj))
    return max(kn, float(np.max(stiffnesses(NORMAL[name].code, kn, overlap, ri, rj, is_wall))))
