"""Shared helpers: small packings built from the engine's own generators."""

import numpy as np
import pytest

from granlab.engine import ContactLaw, Integration, ParticleState, PeriodicCell, Simulation
from granlab.engine.generate import radii, random_gas


def periodic_gas(count=120, length=20.0, seed=1, speed=1.0, law=None, dt_safety=0.1, skin=None, radius_range=(0.4, 0.6)):
    """A polydisperse gas of ``count`` disks in a periodic square cell, random velocities and spins."""
    rng = np.random.default_rng(seed)
    r = radii(count, radius_min=radius_range[0], radius_max=radius_range[1], distribution="uniform", seed=seed)
    positions = random_gas(r, (0.0, length, 0.0, length), periodic=(True, True), seed=seed)
    velocity = rng.normal(0.0, speed, (count, 2))
    omega = rng.normal(0.0, speed, count)
    law = law or ContactLaw(normal_stiffness=1e3, tangential_stiffness=1e3, friction=0.0)
    return Simulation(ParticleState(positions, r, velocity=velocity, omega=omega), law,
                      Integration(dt_safety=dt_safety, skin=skin), cell=PeriodicCell((length, length)))


@pytest.fixture
def gas_factory():
    return periodic_gas
