"""The closed path of ratcheting Fig. 8, for every registered tangential spring side by side."""

from __future__ import annotations

import math

import numpy as np

from ...params import TANGENTIAL, TANGENTIAL_MODELS, ContactLaw, Integration
from ...simulation import Simulation
from ...state import ParticleState
from .base import Preset, View


class ClosedPathPreset(Preset):
    """Ratcheting Fig. 8 side by side for every registered tangential model, one pair each.

    The upper disk of each pair is carried A -> B -> C -> D -> A over and over, without rotating
    or sliding (mu = inf). Series ``springs``: (t, D_t and D_n of each model), sampled along the
    loop (its clock unit).
    """

    name = "closed-path"
    title = "A closed path, every tangential spring (ratcheting Figs. 8-9)"
    menu_name = "Closed path, every spring (Figs. 8–9)"
    controls = ()
    defaults = {"particles": 2, "friction": math.inf, "damping_ratio": 0.0, "speed": 0.5}
    series = {"springs": ("t",) + tuple(f"dt_{model.key}" for model in TANGENTIAL.values())
              + tuple(f"dn_{model.key}" for model in TANGENTIAL.values())}
    path_series = ("springs",)
    plots = key_plots = ("spring-path", "springs")
    clock_unit = "loops"
    time_label = "t (one loop lasts 0.4)"
    path_samples_per_cycle = 200
    window_cycles = 15
    radius = 0.5
    overlap = 0.01
    depth = 0.02
    turn = 0.2
    steps_per_side = 100
    dt = 1e-3

    def _build(self) -> None:
        d_a = 2 * self.radius - self.overlap
        d_b = d_a - self.depth
        phi0 = 0.5 * math.pi
        self._corners = [(d_a, phi0), (d_b, phi0), (d_b, phi0 + self.turn), (d_a, phi0 + self.turn)]
        self._sims = []
        for model in TANGENTIAL_MODELS:
            law = ContactLaw(normal_stiffness=1e4, tangential_stiffness=1e4, friction=math.inf, tangential_model=model)
            particles = ParticleState([[0.0, d_a], [0.0, 0.0]], [self.radius, self.radius], kind=["kinematic", "fixed"])
            self._sims.append(Simulation(particles, law, Integration(dt=self.dt, initial_overlap=0.05)))
        self._k = 0
        self.stage = "looping"

    def cycle_time(self) -> float:
        return 4 * self.steps_per_side * self.dt

    def views(self) -> list[View]:
        return [View(sim, (3.0 * index, 0.0), TANGENTIAL[sim.law.tangential_model].label)
                for index, sim in enumerate(self._sims)]

    def _target(self, k: int) -> np.ndarray:
        side, step = divmod(k, self.steps_per_side)
        (r0, a0), (r1, a1) = self._corners[side % 4], self._corners[(side + 1) % 4]
        s = (step + 1) / self.steps_per_side
        r, a = r0 + (r1 - r0) * s, a0 + (a1 - a0) * s
        return np.array([r * math.cos(a), r * math.sin(a)])

    def _advance(self, steps: int) -> int:
        for _ in range(steps):
            target = self._target(self._k)
            for sim in self._sims:
                sim.set_motion(0, (target - sim.particles.position[0]) / sim.dt, 0.0)
                sim.run(1)
            self._k += 1
        return steps

    def sample(self) -> None:
        """The springs are the only series, sampled along the loop (:meth:`sample_paths`)."""

    def sample_paths(self) -> None:
        row = [self._sims[0].time]
        row += [float(sim.contacts.tangential_spring[0]) for sim in self._sims]
        row += [float(sim.contacts.surface_gap[0]) for sim in self._sims]
        self._emit("springs", tuple(row))

    def status(self) -> dict:
        out = super().status()
        out["loops"] = self._k // (4 * self.steps_per_side)
        return out

    def readout(self) -> dict:
        return {"loops": self._k // (4 * self.steps_per_side)}

    def phase(self) -> str:
        """``loop 3 · B → C``: the loop and the side of the path A → B → C → D → A being drawn."""
        side = (self._k // self.steps_per_side) % 4
        return f"loop {self._k // (4 * self.steps_per_side)} · {'ABCD'[side]} → {'ABCD'[(side + 1) % 4]}"
