"""A block on a plane under a sideways load (quasi-rigidity Figs. 2-3, the principle of minimum
sliding): it slides once the load reaches μF_n."""

from __future__ import annotations

import math

from ...observables import sliding
from ...params import ContactLaw, Integration, Wall
from ...simulation import Simulation
from ...state import ParticleState
from .base import Preset


class BlockPreset(Preset):
    """Quasi-rigidity Figs. 2-3: a disk that cannot turn, pressed on a wall, pushed sideways by a
    load that rises to 1.5 mu F_n and falls back, over and over (period ``period``).

    Series ``block`` (t, load / (mu F_n), N^e, F_t, status, velocity), sampled as a path.
    """

    name = "block"
    title = "A block on a plane: the principle of minimum sliding (quasi-rigidity Figs. 2-3)"
    menu_name = "Block on a plane: minimum sliding"
    controls = ("friction", "period", "damping_ratio")
    defaults = {"particles": 1, "friction": 0.5, "period": 20.0, "damping_ratio": 0.7, "speed": 0.5}
    series = {"block": ("t", "load_ratio", "normal", "tangential", "status", "velocity")}
    path_series = ("block",)
    plots = key_plots = ("block-cone", "block-load")
    time_label = "t (units of m = 1, F_n = 1, K = 1000)"
    load_every = 10

    def _build(self) -> None:
        s = self.settings
        stiffness, load = 1e3, 1.0
        damping = 2.0 * s.damping_ratio * math.sqrt(stiffness)
        law = ContactLaw(normal_stiffness=stiffness, tangential_stiffness=stiffness, friction=s.friction,
                         damping_ratio=s.damping_ratio, tangential_damping=damping)
        particles = ParticleState([[0.0, 0.5 - load / stiffness]], [0.5], mass=[1.0], inertia=[math.inf])
        particles.external_force[0] = (0.0, -load)
        self._sim = Simulation(particles, law, Integration(dt_safety=0.3), walls=(Wall((0.0, 1.0), 0.0, name="floor"),))
        self._normal_load = load
        self.watch = [(0, 1)]
        self.stage = "loading"

    def _rules(self, values: dict) -> dict[str, tuple[bool, str]]:
        return {**super()._rules(values), "period": self._period_rule(values)}

    def _advance(self, steps: int) -> int:
        """The sideways load is set every ``load_every`` steps (a ramp in small stairs)."""
        sim = self._sim
        done = 0
        while done < steps:
            block = min(self.load_every, steps - done)
            sim.particles.external_force[0, 0] = self._load_ratio() * sim.law.friction * self._normal_load
            sim.run(block)
            done += block
        return done

    def readout(self) -> dict:
        return {"sliding": int(sliding(self._sim.contact_status()).sum()), "load": self._load_ratio()}

    def _load_ratio(self) -> float:
        phase = (self._sim.time % self.settings.period) / self.settings.period
        return 1.5 * (2.0 * phase if phase < 0.5 else 2.0 - 2.0 * phase)

    def phase(self) -> str:
        """``load 0.75 μF_n, rising``: the sideways load rises over the first half of the period."""
        rising = self._sim.time % self.settings.period < 0.5 * self.settings.period
        return f"load {self._load_ratio():.2f} μF_n, {'rising' if rising else 'falling'}"

    def sample(self) -> None:
        """The block's series is a path, sampled at the path cadence (:meth:`sample_paths`)."""

    def sample_paths(self) -> None:
        sim = self._sim
        contact = sim.contact_snapshot()
        touching = contact.count > 0
        self._emit("block", (sim.time, self._load_ratio(), float(contact.elastic_normal_force[0]) if touching else 0.0,
                             float(contact.tangential_force[0]) if touching else 0.0,
                             int(contact.status[0]) if touching else 0, float(sim.particles.velocity[0, 0])))
