"""What the presets of Gilabert's packings share: time in T₀, their sampling, and a rolling dashpot
that follows the damping ratio."""

from __future__ import annotations

import math

from .base import Preset


class GilabertPreset(Preset):
    """The presets of Gilabert's preparations: time in T_0 = sqrt(m a / F_1) (1 here: a disk of
    diameter a = 1 has mass 1, F_1 = 1); the rolling dashpot's damping ratio is the normal one,
    ``damping_ratio``, also when that control changes."""

    clock_unit = "T₀"
    speeds = {"slow": 2.0, "normal": 10.0, "fast": math.inf}  # 300 disks: a few tens of T₀ a second at most
    time_label = "t (T₀ = √(m a/F₁))"
    window_cycles = 0
    samples_per_cycle = 2
    path_samples_per_cycle = 2
    particle_range = (10, 20000)

    def cycle_time(self) -> float:
        return 1.0

    def _changed(self, changes: dict) -> None:
        if "damping_ratio" in changes:
            self._sim.set_law(rolling_damping_ratio=self.settings.damping_ratio)
