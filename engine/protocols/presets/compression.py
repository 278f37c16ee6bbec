"""Compression of a granular gas, cohesive or not, in a periodic cell under stress control
(Gilabert Sec. III A, method 1)."""

from __future__ import annotations

import math

from ...observables import columns, coordination, solid_fraction
from ...params import Integration, PeriodicCell
from ...simulation import Simulation
from ...state import ParticleState
from ..equilibrium import equilibrium, measured_pressure
from ..prepare import gilabert_gas, gilabert_law
from .gilabert import GilabertPreset


class CompressionPreset(GilabertPreset):
    """Gilabert method 1 live: a gas at rest at solid fraction 0.36 compressed isotropically to
    P by stress control of the cell. Cohesive if F0 > 0 (P* = 0.01), else P = 1 and
    kappa = K_N / P = 10^3. Series ``time`` (t, z, phi, pressure, kinetic)."""

    name = "compression"
    title = "Compression of a granular gas (Gilabert method 1)"
    menu_name = "Compression of a gas (Gilabert 1)"
    controls = ("friction", "rolling_friction", "rolling_stiffness", "cohesion_force", "particles", "seed",
                "damping_ratio")
    defaults = {"particles": 300, "friction": 0.15, "damping_ratio": 0.8, "speed": math.inf, "frames_per_cycle": 0.2}
    series = {"time": ("t", "z", "phi", "pressure", "kinetic")}
    plots = ("solid-fraction", "coordination-gilabert", "pressure", "kinetic")
    key_plots = ("solid-fraction", "coordination-gilabert")

    def _build(self) -> None:
        s = self.settings
        cohesive = s.cohesion_force > 0
        self.pressure = 0.01 if cohesive else 1.0
        law = gilabert_law(friction=s.friction, kappa=1e3, cohesion=cohesive, rolling=s.rolling_friction > 0,
                           pressure=self.pressure, damping_ratio=s.damping_ratio, rolling_damping_ratio=s.damping_ratio)
        r, positions, length = gilabert_gas(s.particles, 0.36, s.seed)
        cell = PeriodicCell((length, length), control=("stress", "stress"), stress=(self.pressure, self.pressure))
        self._sim = Simulation(ParticleState(positions, r, density=4.0 / math.pi), law, Integration(dt_safety=0.3),
                               cell=cell)
        self.stage = "compressing"
        self._next_check = 0.0

    def _advance(self, steps: int) -> int:
        sim = self._sim
        sim.run(steps)
        if sim.time >= self._next_check:
            self._next_check = sim.time + 2.0
            if self.stage == "compressing" and equilibrium(sim, self.pressure).equilibrated:
                self.stage = "equilibrated"
        return steps

    def sample(self) -> None:
        sim = self._sim
        self._emit("time", (sim.time, coordination(*columns(sim)),
                            solid_fraction(sim.particles.radius, sim.box_lengths()), measured_pressure(sim),
                            sim.energy().kinetic))
