"""JSON that browsers and ``json.loads`` both read: arrays as lists, inf and NaN as strings."""

import math

import numpy as np


def jsonable(value):
    """A copy of ``value`` made of dicts, lists, str, int, float (finite), bool and None."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, (np.floating, float)):
        value = float(value)
        return value if math.isfinite(value) else str(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value
