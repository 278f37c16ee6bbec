"""Tangential spring models: one module each, named in the registry :data:`granlab.engine.params.TANGENTIAL`.

A model module holds four small kernels, which the one contact loop calls for each touching row:

- ``spring_rate(vt, spin_sum, alpha)``: the rate of ``D_t`` from the relative tangential velocity of
  the centres ``vt``, the spins ``r_i w_i + r_j w_j`` and ``alpha = (r_i + r_j)/|r|``;
- ``trial_spring(previous, rate, dt, fresh, row)``: ``D_t`` before the Coulomb limit, from the
  spring of the step before (``fresh`` on the first step of a contact) and the row's
  :data:`RowGeometry`;
- ``limit(kt, mu, gamma_t, ne, fn, trial, rate)``: ``(D_t, F_t, status, slip)`` after the Coulomb
  limit, given the elastic ``ne`` and total ``fn`` normal forces;
- ``centre_factor(alpha)``: what ``F_t`` is multiplied by on the centres (its moment is ``-r F_t``).

Whether the dashpots (normal, tangential, rolling) take the velocities predicted at the whole step
or the half-step ones is the registry's ``whole_step_dashpots``.

The functions below dispatch on a model code known when the contact loop is compiled (a literal):
each model gets its own loop, with its laws inlined, and nothing is decided per row. Called from
Python (a test, a notebook), they run the model's own kernel. Adding a model
is its module here and its line in the registry; a module without one of the four kernels does not
register (:class:`granlab.engine.errors.RegistryError` names it).
"""

import importlib
from collections import namedtuple

from numba import types
from numba.extending import overload

from ...errors import RegistryError
from ...params import TANGENTIAL

RowGeometry = namedtuple("RowGeometry", "nx ny rx ry dvx dvy ri rj angle_i angle_j anchor_i anchor_j is_wall xi yi "
                                        "wall_shift phi alpha")
"""What a model may read of a touching row: normal ``n``, branch vector ``r`` (for a wall, from the
wall to the centre), relative velocity ``V`` of the centres, radii (``rj = 0`` for a wall), body
angles and anchors (for a wall, ``anchor_j`` is along the wall and ``angle_j = 0``), the centre of
disk i, how far the wall has slid along itself, the direction of ``n``, ``phi = atan2(n_y, n_x)``
(0 unless the model :func:`reads_direction`), and ``alpha = (r_i + r_j)/|r|`` (1 for a wall)."""

MODELS = {model.code: importlib.import_module(f".{model.key}", __name__) for model in TANGENTIAL.values()}
_WHOLE_STEP_DASHPOTS = {model.code: model.whole_step_dashpots for model in TANGENTIAL.values()}
_READS_DIRECTION = {model.code: model.reads_direction for model in TANGENTIAL.values()}
CODES = tuple(sorted(MODELS))
"""The models' codes: the contact loop is compiled for each, when a run first uses it."""
PARTS = ("spring_rate", "trial_spring", "limit", "centre_factor")


def _check_parts():
    for model in TANGENTIAL.values():
        missing = [part for part in PARTS if not callable(getattr(MODELS[model.code], part, None))]
        if missing:
            raise RegistryError("tangential model", model.name, MODELS[model.code].__file__, missing,
                                ", ".join(PARTS))


_check_parts()


def model_key(code: int) -> str:
    """The name of model ``code``'s module (an identifier)."""
    return MODELS[code].__name__.rpartition(".")[2]


def _model(code):
    if not isinstance(code, types.IntegerLiteral):
        return None
    return MODELS[code.literal_value]


def spring_rate(model, vt, spin_sum, alpha):
    """``dD_t/dt`` of model ``model`` (a compile-time code)."""
    return MODELS[model].spring_rate(vt, spin_sum, alpha)


def trial_spring(model, previous, rate, dt, fresh, row):
    """``D_t`` before the Coulomb limit."""
    return MODELS[model].trial_spring(previous, rate, dt, fresh, row)


def limit(model, kt, mu, gamma_t, ne, fn, trial, rate):
    """``(D_t, F_t, status, slip)`` after the Coulomb limit."""
    return MODELS[model].limit(kt, mu, gamma_t, ne, fn, trial, rate)


def centre_factor(model, alpha):
    """The factor of ``F_t`` on the centres."""
    return MODELS[model].centre_factor(alpha)


def whole_step_dashpots(model):
    """Whether the dashpots take the velocities predicted at the whole step."""
    return _WHOLE_STEP_DASHPOTS[model]


def reads_direction(model):
    """Whether the model's spring reads ``RowGeometry.phi``."""
    return _READS_DIRECTION[model]


@overload(spring_rate, prefer_literal=True)
def _spring_rate(model, vt, spin_sum, alpha):
    law = _model(model)
    if law is not None:
        impl = law.spring_rate
        return lambda model, vt, spin_sum, alpha: impl(vt, spin_sum, alpha)


@overload(trial_spring, prefer_literal=True)
def _trial_spring(model, previous, rate, dt, fresh, row):
    law = _model(model)
    if law is not None:
        impl = law.trial_spring
        return lambda model, previous, rate, dt, fresh, row: impl(previous, rate, dt, fresh, row)


@overload(limit, prefer_literal=True)
def _limit(model, kt, mu, gamma_t, ne, fn, trial, rate):
    law = _model(model)
    if law is not None:
        impl = law.limit
        return lambda model, kt, mu, gamma_t, ne, fn, trial, rate: impl(kt, mu, gamma_t, ne, fn, trial, rate)


@overload(centre_factor, prefer_literal=True)
def _centre_factor(model, alpha):
    law = _model(model)
    if law is not None:
        impl = law.centre_factor
        return lambda model, alpha: impl(alpha)


@overload(whole_step_dashpots, prefer_literal=True)
def _whole_step_dashpots(model):
    if isinstance(model, types.IntegerLiteral):
        flag = _WHOLE_STEP_DASHPOTS[model.literal_value]
        return lambda model: flag


@overload(reads_direction, prefer_literal=True)
def _reads_direction(model):
    if isinstance(model, types.IntegerLiteral):
        flag = _READS_DIRECTION[model.literal_value]
        return lambda model: flag
