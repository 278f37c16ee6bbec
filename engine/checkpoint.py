"""A saved state checked before a simulation takes it (:meth:`Simulation.restore_state`): every
array present, numeric, of its simulation's shape; no NaN; no infinite or huge value but where a
parameter may be infinite; every index and code in its range; the derived arrays as the disks'
masses and kinds make them. A checkpoint of a damaged or edited run file stops here, named, before
a step is computed from it (the kernels index with these numbers: an index out of range was a
segmentation fault, a step of -2⁶³ a run of 9.2·10¹⁸ steps, an infinite velocity a resumed run that
exited 0)."""

from __future__ import annotations

import numpy as np

from .errors import GranLabError
from .params import CELL_CONTROLS, WALL_MODES
from .state import HUGE, KIND_NAMES, STATUS_NAMES

MAY_BE_INFINITE = {"particles/mass", "particles/inertia", "cell/mass", "cell/max_strain_rate"}
"""Parameters whose inf means "never": a disk that never moves or turns, no limit on the cell's rate."""
CODES = {"particles/kind": (0, len(KIND_NAMES)), "walls/mode": (0, len(WALL_MODES)),
         "cell/control": (-1, len(CELL_CONTROLS)), "contacts/status": (0, len(STATUS_NAMES))}
"""Integer codes and their range [low, high)."""
POSITIVE = {"particles/radius", "particles/mass", "particles/inertia"}
NON_NEGATIVE = {"walls/inv_mass", "cell/length", "cell/reference_length", "cell/mass"}


class CheckpointError(GranLabError, ValueError):
    """A saved state a simulation cannot take: names the array and what is allowed."""


def check_state(state: dict, expected: dict[str, np.ndarray], disks: int, walls: int) -> int:
    """Refuse ``state`` unless it could have been exported by a simulation whose own state is
    ``expected`` (its :meth:`export_state`: the shapes and kinds to match); returns its contacts."""
    rows = _contacts(state, expected)
    for key, like in expected.items():
        if key == "threads":
            continue
        value = _present(state, key)
        shape = (rows,) + like.shape[1:] if key.startswith("contacts/") else like.shape
        if value.shape != shape:
            raise CheckpointError(f"{key} has shape {value.shape}; {shape} is needed")
        if value.dtype.kind == "f" and like.dtype.kind in "iub" and not np.array_equal(value, np.round(value)):
            raise CheckpointError(f"{key} holds fractions; whole numbers are needed")
        _check_values(key, value)
    _check_indices(state, rows, disks, walls)
    _check_inverses(state)
    step, origin, dt = int(state["step"]), int(state["step_origin"]), float(state["dt"])
    if not 0 <= origin <= step:
        raise CheckpointError(f"step = {step}, step_origin = {origin}; 0 <= step_origin <= step is needed")
    if not 0 < dt < HUGE:
        raise CheckpointError(f"dt = {dt!r}; a positive time step is needed")
    return rows


def _present(state: dict, key: str) -> np.ndarray:
    if key not in state:
        raise CheckpointError(f"{key} is missing")
    value = np.asarray(state[key])
    if value.dtype.kind not in "biuf":
        raise CheckpointError(f"{key} holds {value.dtype}; numbers are needed")
    return value


def _contacts(state: dict, expected: dict) -> int:
    """The rows of the contact table: the same in every one of its arrays."""
    names = [key for key in expected if key.startswith("contacts/")]
    rows = {key: _present(state, key).shape[:1] for key in names}
    if len(set(rows.values())) != 1 or () in rows.values():
        raise CheckpointError("the contact table's arrays have different lengths: "
                              + ", ".join(f"{key} {shape}" for key, shape in rows.items()))
    return next(iter(rows.values()))[0]


def _check_values(key: str, value: np.ndarray) -> None:
    if value.dtype.kind == "f":
        if np.isnan(value).any():
            raise CheckpointError(f"{key} holds NaN")
        finite = np.abs(value) < HUGE
        if key not in MAY_BE_INFINITE and not finite.all():
            raise CheckpointError(f"{key} holds {value[~finite].flat[0]:.4g}; values below 1e150 in size are needed")
    if key in POSITIVE and not (value > 0).all() or key in NON_NEGATIVE and not (value >= 0).all():
        raise CheckpointError(f"{key} holds {value.min():.4g}; {'positive' if key in POSITIVE else 'non-negative'} "
                              f"values are needed")
    if key in CODES:
        low, high = CODES[key]
        if value.size and not (low <= value.min() and value.max() < high):
            raise CheckpointError(f"{key} holds codes from {value.min()} to {value.max()}; {low} to {high - 1} are "
                                  f"allowed")


def _check_indices(state: dict, rows: int, disks: int, walls: int) -> None:
    """A contact joins disk i to disk j > i, or to wall j - N."""
    if not rows:
        return
    i, j = np.asarray(state["contacts/particle_i"]), np.asarray(state["contacts/particle_j"])
    if not (0 <= i.min() and i.max() < disks):
        raise CheckpointError(f"contacts/particle_i holds {i.min()} to {i.max()}; disks 0 to {disks - 1} are allowed")
    if not (0 <= j.min() and j.max() < disks + walls):
        raise CheckpointError(f"contacts/particle_j holds {j.min()} to {j.max()}; disks and walls 0 to "
                              f"{disks + walls - 1} are allowed")
    if not np.all(i < j):
        row = int(np.flatnonzero(i >= j)[0])
        raise CheckpointError(f"contact {row} joins {i[row]} to {j[row]}; particle_i < particle_j is needed")


def _check_inverses(state: dict) -> None:
    """A disk's inverse mass and inertia are what its mass, inertia and kind make them (the
    kernels use only the inverses: an inverse mass of -1 pushed a disk up a potential hill)."""
    dynamic = state["particles/kind"] == KIND_NAMES.index("dynamic")
    with np.errstate(divide="ignore"):
        for name, of in (("inv_mass", "mass"), ("inv_inertia", "inertia")):
            made = np.where(dynamic, 1.0 / state[f"particles/{of}"], 0.0)
            if not np.array_equal(state[f"particles/{name}"], made):
                raise CheckpointError(f"particles/{name} is not what particles/{of} and kind make it (1/{of} for "
                                      f"a dynamic disk, 0 for another)")
