"""GranLab engine: a numba 2D discrete-element core for granular mechanics.

Layers (imports point downwards only): ``cli``/``studies`` > ``io`` > ``analysis`` >
``protocols`` > ``simulation`` > ``kernels`` > ``state``/``params``.
"""

from .errors import DivergenceError, GranLabError, ParameterError, SceneError
from .params import ContactLaw, Integration, Load, PeriodicCell, Wall, box_walls
from .simulation import EnergyBudget, Simulation, Snapshot, stability_bound
from .state import ParticleState

__version__ = "0.1.0"

__all__ = [
    "ContactLaw", "DivergenceError", "EnergyBudget", "GranLabError", "Integration", "Load", "ParameterError",
    "ParticleState", "PeriodicCell", "SceneError", "Simulation", "Snapshot", "Wall", "box_walls",
    "stability_bound",
]
