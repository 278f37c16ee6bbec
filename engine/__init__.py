"""GranLab engine: a numba 2D discrete-element core for granular mechanics.

Layers (imports point downwards only): ``studies``/``reproduce`` > ``io`` > ``analysis`` >
``protocols`` > ``simulation`` > ``kernels`` > ``state``/``params``.

The names below are imported on first use: ``import granlab.engine.params`` (the command line's
options, a registry) costs neither numba nor the kernels.
"""

import importlib

__version__ = "0.1.0"

_HOMES = {
    "errors": ("DivergenceError", "GranLabError", "ParameterError", "SceneError"),
    "params": ("ContactLaw", "Integration", "Load", "PeriodicCell", "Wall", "box_walls"),
    "simulation": ("EnergyBudget", "Simulation", "Snapshot", "stability_bound"),
    "state": ("ParticleState",),
}
_HOME = {name: module for module, names in _HOMES.items() for name in names}

__all__ = sorted(_HOME)


def __getattr__(name: str):
    if name not in _HOME:
        raise AttributeError(f"module 'granlab.engine' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{_HOME[name]}", __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
