"""Two disks head-on, launched again and again: the restitution the dashpot gives (Gilabert Sec. II C)."""

from __future__ import annotations

import math

import numpy as np

from ...params import ContactLaw, Integration
from ...simulation import Simulation
from ...state import ParticleState
from ..teaching import contact_duration, restitution
from .base import Preset


class CollisionPreset(Preset):
    """Two equal disks (radius 0.5, mass 1, K_n = 10⁴) approach head-on at a relative speed 2, collide
    and part; every ``period`` they are launched again from the same places. A change of the damping
    ratio ζ acts at once while they approach, else from the next launch (one collision, one ζ).

    Series ``collision`` (t, collision, overlap δ, normal force F_n, spring K_n δ), sampled along each contact
    (path cadence), and ``collisions`` (collision, ζ, e_N measured, e_N predicted), one row a collision.
    """

    name = "collision"
    title = "Two disks collide head-on: restitution from the dashpot (Gilabert Sec. II C)"
    menu_name = "Two disks collide: restitution"
    controls = ("damping_ratio",)
    defaults = {"particles": 2, "friction": 0.5, "damping_ratio": 0.3, "period": 0.2, "speed": 1.0}
    series = {"collision": ("t", "collision", "overlap", "force", "spring"),
              "collisions": ("collision", "zeta", "restitution", "predicted")}
    path_series = ("collision",)
    plots = key_plots = ("collision-force", "restitution")
    clock_unit = "collisions"
    speeds = {"slow": 0.2, "normal": 1.0, "fast": 5.0}
    time_label = "t (units of m = 1, K_n = 10⁴; a launch every 0.2)"
    window_cycles = 0
    path_samples_per_cycle = 400
    """About 45 samples along a contact (0.022 to 0.03 long, ζ = 0 to 0.7: an eighth of the period or less)."""
    radius, mass, stiffness, speed, gap = 0.5, 1.0, 1.0e4, 1.0, 0.05
    steps_per_contact = 200
    """Time steps along a contact of ζ = 0: e_N measured within 5×10⁻⁵ of the formula at ζ = 0, 0.3, 0.5 and 0.8."""

    def _build(self) -> None:
        s = self.settings
        law = ContactLaw(normal_stiffness=self.stiffness, tangential_stiffness=self.stiffness, friction=s.friction,
                         damping_ratio=s.damping_ratio)
        reach = self.radius + 0.5 * self.gap
        self._start = np.array([[-reach, 0.0], [reach, 0.0]])
        particles = ParticleState(self._start, [self.radius, self.radius], mass=[self.mass, self.mass])
        dt = contact_duration(0.0, self.stiffness, 0.5 * self.mass) / self.steps_per_contact
        self._sim = Simulation(particles, law, Integration(dt=dt))
        self._collisions = 0
        self._measured: float | None = None
        self._parted_at = 0.0
        self._launch()

    def _launch(self) -> None:
        """The disks back at their places, moving towards each other; the next launch one period on."""
        particles = self._sim.particles
        particles.position[:] = self._start
        particles.velocity[:] = ((self.speed, 0.0), (-self.speed, 0.0))
        particles.omega[:] = 0.0
        particles.angle[:] = 0.0
        self._next_launch = self._sim.time + self.settings.period
        self._zeta = self.settings.damping_ratio
        self._touched = False
        self.stage = "approaching"

    def _waiting_controls(self) -> tuple[str, ...]:
        """ζ waits for the next launch once the disks have touched: one collision, one ζ."""
        return ("damping_ratio",) if self._touched or self.stage != "approaching" else ()

    def _changed(self, changes: dict) -> None:
        if "damping_ratio" in changes:  # before the disks touch: this launch's collision has the new ζ
            self._zeta = self.settings.damping_ratio

    def _advance(self, steps: int) -> int:
        sim = self._sim
        steps = min(steps, max(1, math.ceil((self._next_launch - sim.time) / sim.dt - 1e-6)))
        sim.run(steps)
        if sim.time >= self._next_launch - 1e-6 * sim.dt:
            self._apply_pending()
            self._set_law(damping_ratio=self.settings.damping_ratio)
            self._launch()
        return steps

    def _collided(self) -> None:
        """The launch's collision, measured in free flight after it: e_N = the parting speed over the approach."""
        velocity = self._sim.particles.velocity
        self._collisions += 1
        self._measured = float(velocity[1, 0] - velocity[0, 0]) / (2 * self.speed)
        self._emit("collisions", (self._collisions, self._zeta, self._measured, float(restitution(self._zeta))))
        self.stage = "parted"

    def _overlap(self) -> float:
        position = self._sim.particles.position
        return 2 * self.radius - float(np.hypot(*(position[1] - position[0])))

    def sample(self) -> None:
        """Both series come at the path cadence (:meth:`sample_paths`): the contact's samples, and each
        collision's row once the disks have parted."""

    def sample_paths(self) -> None:
        overlap = self._overlap()
        if overlap <= 0.0:
            if self._touched and self.stage == "in contact":
                self.stage = "parting"
                self._parted_at = self._sim.time
            elif self.stage == "parting" and self._sim.time >= self._parted_at + 1.5 * self._sim.dt:
                self._collided()  # a step after the one that found them apart: its half kick is in
            return
        self._touched = True
        self.stage = "in contact"
        contact = self._sim.contact_snapshot()
        force = float(contact.normal_force[0]) if contact.count else 0.0
        self._emit("collision", (self._sim.time, self._collisions + 1, overlap, force, self.stiffness * overlap))

    def readout(self) -> dict:
        """The collisions so far, the last one's e_N (None before the first) and the formula's for ζ in effect."""
        return {"collisions": self._collisions, "restitution": self._measured,
                "predicted": float(restitution(self.settings.damping_ratio))}

    def phase(self) -> str:
        """``collision 4 · in contact``."""
        return f"collision {self._collisions + 1} · {self.stage}"
