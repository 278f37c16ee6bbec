"""Aggregation of a cohesive gas, then its relaxation and compression (Gilabert Sec. III B,
method 2): clusters merge into one."""

from __future__ import annotations

import math

import numpy as np

from ...observables import clusters, columns, coordination, solid_fraction
from ...params import Integration, PeriodicCell
from ...simulation import Simulation
from ...state import ParticleState
from ..equilibrium import equilibrium, measured_pressure
from ..prepare import gilabert_gas, gilabert_law
from .gilabert import GilabertPreset


class AggregationPreset(GilabertPreset):
    """Gilabert method 2 live: a cohesive gas aggregates at fixed cell size, then the cell is put
    under stress control, relaxed at P* = 0 and compressed to P* = 0.01 (strain-rate cap).
    Each stage ends at Gilabert's criteria or at its time limit (``stage_limits``).

    Soft grains (kappa = 10^3) so that it runs at a teaching pace. Series ``time`` (t, z, phi,
    clusters, kinetic).
    """

    name = "aggregation"
    title = "Cohesive powder: aggregation (Gilabert method 2, Figs. 4 and 11)"
    menu_name = "Cohesive aggregation (Gilabert 2)"
    controls = ("friction", "rolling_friction", "rolling_stiffness", "particles", "seed", "damping_ratio")
    defaults = {"particles": 300, "friction": 0.15, "cohesion_force": 1.0, "cohesion_range": 1e-3,
                "damping_ratio": 0.8, "speed": math.inf, "frames_per_cycle": 0.2}
    series = {"time": ("t", "z", "phi", "clusters", "kinetic")}
    plots = ("clusters", "coordination-gilabert", "solid-fraction", "kinetic")
    key_plots = ("clusters", "coordination-gilabert")
    kappa = 1e3
    pressure = 0.01
    #: longest time of each stage: a stage that has not met its criterion by then ends anyway
    #: (tangential springs are undamped: floppy arms can swing for a long time)
    stage_limits = {"aggregating": 1000.0, "relaxing": 500.0, "compressing": 1500.0}

    def _build(self) -> None:
        s = self.settings
        law = gilabert_law(friction=s.friction, kappa=self.kappa, cohesion=True, rolling=s.rolling_friction > 0,
                           damping_ratio=s.damping_ratio, rolling_damping_ratio=s.damping_ratio)
        if s.rolling_friction > 0:
            law = law.replace(rolling_friction=s.rolling_friction,
                              rolling_stiffness=s.rolling_stiffness or law.rolling_stiffness)
        r, positions, length = gilabert_gas(s.particles, 0.36, s.seed)
        rng = np.random.default_rng(s.seed + 7)
        speed = math.sqrt(law.cohesion_force * law.cohesion_range)
        velocity = rng.normal(0.0, speed / math.sqrt(2.0), size=(s.particles, 2))
        velocity -= (r[:, None] ** 2 * velocity).sum(axis=0) / (r ** 2).sum()
        self._sim = Simulation(ParticleState(positions, r, velocity=velocity, density=4.0 / math.pi), law,
                               Integration(dt_safety=0.3), cell=PeriodicCell((length, length)))
        self.stage = "aggregating"
        self.late: list[str] = []
        self._stage_start = 0.0
        self._next_check = 0.0

    def _advance(self, steps: int) -> int:
        sim = self._sim
        sim.run(steps)
        if sim.time < self._next_check:
            return steps
        self._next_check = sim.time + 5.0
        late = sim.time - self._stage_start > self.stage_limits.get(self.stage, math.inf)
        if self.stage == "aggregating":
            report = equilibrium(sim, measured_pressure(sim))
            if (clusters(*columns(sim)) == 1 and report.force < 1.0 and report.moment < 1.0) or late:
                self._next_stage("relaxing", late, 0.0)
        elif self.stage == "relaxing":
            report = equilibrium(sim, 0.0)
            if (report.force < 1.0 and report.moment < 1.0 and report.pressure < 1.0) or late:
                self._next_stage("compressing", late, self.pressure)
        elif self.stage == "compressing":
            if equilibrium(sim, self.pressure).equilibrated:
                self._next_stage("equilibrated", False)
            elif late:
                self._next_stage("compressed", True)
        return steps

    def _next_stage(self, stage: str, late: bool, pressure: float | None = None) -> None:
        """Go on to ``stage`` (``late``: the time limit of the last one ran out before its
        criterion was met; the stage's name says so)."""
        if pressure is not None:
            self._sim.set_cell_stress(pressure, 1e-3)
        self.late = self.late + [self.stage] if late else self.late
        self.stage = stage
        self._stage_start = self._sim.time

    def status(self) -> dict:
        out = super().status()
        if self.late:
            out["stage"] = f"{self.stage} (time limit reached while {', '.join(self.late)})"
        return out

    def sample(self) -> None:
        sim = self._sim
        table = columns(sim)
        self._emit("time", (sim.time, coordination(*table), solid_fraction(sim.particles.radius, sim.box_lengths()),
                            clusters(*table), sim.energy().kinetic))
