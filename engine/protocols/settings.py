"""The lab's settings: every control, validated, and what each is called on the page."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass


from ..errors import ParameterError
from ..params import ContactLaw, finite, friction_coefficient, nonnegative, positive, whole

CONTROL_LABELS = {
    "particles": "Disks N", "seed": "Seed", "pressure": "Pressure P0", "amplitude": "Amplitude Δσ",
    "period": "Period T", "phase": "Loading phase φ", "friction": "Friction μ", "rolling_friction": "Rolling friction μr",
    "rolling_stiffness": "Rolling stiffness Kr", "cohesion_force": "Cohesion F0", "cohesion_range": "Cohesion range D0",
    "normal_model": "Normal spring", "tangential_model": "Tangential spring", "damping_ratio": "Damping ζ",
    "speed": "Speed", "frames_per_cycle": "Frames kept",
}
"""The name each control has on the lab's page."""


@dataclass(frozen=True)
class LabSettings:
    """Every control of the lab, validated. Angles in degrees; ``friction`` may be inf.

    ``particles`` and ``seed`` take effect on reset; the others live. ``speed`` is in clock
    units of the preset (e.g. load cycles) per second of wall clock; inf runs as fast as possible.
    """

    particles: int = 256
    seed: int = 0
    pressure: float = 1.0
    amplitude: float = 0.2
    period: float = 10.0
    phase: float = 0.0
    friction: float = 0.2
    rolling_friction: float = 0.0
    rolling_stiffness: float = 0.0
    cohesion_force: float = 0.0
    cohesion_range: float = 0.0
    normal_model: str = "linear"
    tangential_model: str = "cundall-strack"
    damping_ratio: float = 0.3
    speed: float = 1.0
    frames_per_cycle: float = 10.0

    def __post_init__(self):
        whole("particles", self.particles, 1, 20000)
        whole("seed", self.seed, 0, 2 ** 32 - 1)
        positive("pressure", self.pressure)
        nonnegative("amplitude", self.amplitude)
        positive("period", self.period)
        if not -180.0 <= finite("phase", self.phase) <= 180.0:
            raise ParameterError("phase", self.phase, "an angle from -180 to 180 degrees")
        if not (MIN_SPEED <= positive("speed", self.speed, allow_inf=True) <= MAX_SPEED or self.speed == math.inf):
            raise ParameterError("speed", self.speed, f"from {MIN_SPEED:g} to {MAX_SPEED:g} clock units (load cycles, "
                                                      f"loops, T₀) per second, or inf (as fast as it can)")
        if not 0.0 < finite("frames_per_cycle", self.frames_per_cycle) <= 100.0:
            raise ParameterError("frames_per_cycle", self.frames_per_cycle,
                                 "from more than 0 to 100 frames kept per clock unit (a load cycle, a loop, T_0)")
        law = ContactLaw(friction=self.friction, rolling_friction=self.rolling_friction,
                         rolling_stiffness=self.rolling_stiffness, cohesion_force=self.cohesion_force,
                         cohesion_range=self.cohesion_range, normal_model=self.normal_model,
                         tangential_model=self.tangential_model,
                         damping_ratio=self.damping_ratio)
        friction_coefficient("friction", law.friction, largest=MAX_FRICTION)  # the lab's packings stop sliding here

    def replace(self, **changes) -> "LabSettings":
        names = {f.name for f in dataclasses.fields(self)}
        for key, value in changes.items():
            if key not in names:
                raise ParameterError(key, value, "one of " + ", ".join(sorted(names)))
        return dataclasses.replace(self, **changes)


MIN_SPEED, MAX_SPEED = 0.01, 100.0
MAX_FRICTION = 10.0
"""Beyond it no contact of the lab's packings slides: μ = ∞ says so."""

LAW_CONTROLS = ("friction", "rolling_friction", "rolling_stiffness", "cohesion_force", "cohesion_range",
                "normal_model", "tangential_model", "damping_ratio")
RESET_CONTROLS = ("particles", "seed")
