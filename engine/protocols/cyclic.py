"""Cyclic loading of the biaxial box (ratcheting Eqs. 1, 4, 5).

The top wall carries ``L_x (P0 + q_y(t))`` and the right wall ``L_y (P0 + q_x(t))`` with
``q_y = Delta sigma (1 - cos(w t))`` and, for elliptic loading, ``q_x = Delta sigma (1 - cos(w t + phi))``
(``q_x = 0`` otherwise); a zero-mean load subtracts Delta sigma from each cycling q. Time is counted
from the start of the loading, so every cycle starts at the minimum of the load, where the wall
positions are recorded.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import ParameterError
from ..params import Load, finite, nonnegative, positive, whole
from ..simulation import Simulation


@dataclass(frozen=True)
class CyclicLoad:
    """``pressure`` P0, ``amplitude`` Delta sigma, ``period`` T, ``phase`` phi (radians) of the
    elliptic loading of Eqs. 4-5, or ``None`` for the loading of Eq. 1 (only the top wall cycles).
    ``zero_mean``: ``q = -Delta sigma cos(w t)`` instead, a load whose mean over a cycle is P0 on
    every wall (Eq. 1's mean is P0 + Delta sigma on the top wall, P0 on the right one), still least at
    the start of each cycle."""

    pressure: float = 1.0
    amplitude: float = 0.2
    period: float = 10.0
    phase: float | None = None
    zero_mean: bool = False

    def __post_init__(self):
        positive("pressure", self.pressure)
        nonnegative("amplitude", self.amplitude)
        positive("period", self.period)
        if self.phase is not None:
            finite("phase", self.phase)
        if self.zero_mean and not self.amplitude < self.pressure:
            raise ParameterError("amplitude", self.amplitude, f"below the pressure P0 = {self.pressure:g} for a "
                                                              f"zero-mean load (the wall's least load is P0 - Δσ)")

    def q(self, t: float) -> float:
        """The deviatoric load ``q(t)`` on the top wall, t counted from the start of the loading."""
        return self.amplitude * (1.0 - math.cos(2.0 * math.pi * t / self.period)) - self.offset

    @property
    def offset(self) -> float:
        """What the load's base is below P0: Delta sigma for a zero-mean load."""
        return self.amplitude if self.zero_mean else 0.0


@dataclass
class CycleSeries:
    """Wall positions at the start of each cycle (the minimum of the load): ``cycle[k]`` = k."""

    cycle: list[int] = field(default_factory=list)
    time: list[float] = field(default_factory=list)
    length_x: list[float] = field(default_factory=list)
    length_y: list[float] = field(default_factory=list)

    def arrays(self):
        return (np.array(self.cycle), np.array(self.length_x), np.array(self.length_y))


def apply_load(sim: Simulation, load: CyclicLoad, start: float | None = None) -> float:
    """Load the box's right and top walls, the loading started at ``start`` (default: now);
    returns that start time."""
    for name in ("right", "top"):
        if name not in sim.walls.names:
            raise ParameterError("walls", sim.walls.names, "a biaxial box with walls named right and top")
    start = sim.time if start is None else start
    for name, wall_load in wall_loads(load, start).items():
        sim.set_wall_load(name, wall_load)
    return start


def wall_loads(load: CyclicLoad, start: float) -> dict[str, Load]:
    """The loads of the box's top and right walls for ``load`` started at time ``start``."""
    omega = 2.0 * math.pi / load.period
    origin = -omega * start
    base = load.pressure - load.offset
    x_amplitude = 0.0 if load.phase is None else load.amplitude
    x_phase = origin + (0.0 if load.phase is None else load.phase)
    x_base = load.pressure if load.phase is None else base
    return {"top": Load(base=base, amplitude=load.amplitude, period=load.period, phase=origin),
            "right": Load(base=x_base, amplitude=x_amplitude, period=load.period, phase=x_phase)}


def steps_per_cycle(sim: Simulation, load: CyclicLoad) -> int:
    """Make the time step divide the period exactly (never larger than it was); returns T / dt."""
    return sim.fit_dt(load.period)


def box_lengths(sim: Simulation) -> tuple[float, float]:
    lengths = sim.box_lengths()
    return float(lengths[0]), float(lengths[1])


def run_cycles(sim: Simulation, load: CyclicLoad, cycles: int, on_cycle=None, samples_per_cycle: int = 0,
               on_sample=None, series: CycleSeries | None = None) -> CycleSeries:
    """Apply ``cycles`` cycles of ``load`` to a prepared biaxial box.

    Records ``L_x, L_y`` at the start of every cycle (cycle 0 is the start of the loading).
    ``on_cycle(k, sim, length_x, length_y)`` is called at each record; with ``samples_per_cycle``
    > 0, ``on_sample(sim)`` is called that many times per cycle (e.g. to record the paths of
    contacts in the Coulomb cone). ``series`` continues an earlier record.
    """
    whole("cycles", cycles, 1)
    series = series if series is not None else CycleSeries()
    per_cycle = steps_per_cycle(sim, load)
    first = series.cycle[-1] if series.cycle else 0
    if not series.cycle:
        apply_load(sim, load)
        _record(series, 0, sim, on_cycle)
    chunks = [per_cycle]
    if samples_per_cycle > 0:
        base = per_cycle // samples_per_cycle
        chunks = [base] * (samples_per_cycle - 1) + [per_cycle - base * (samples_per_cycle - 1)]
    for cycle in range(first + 1, first + cycles + 1):
        for steps in chunks:
            sim.run(steps)
            if on_sample is not None:
                on_sample(sim)
        _record(series, cycle, sim, on_cycle)
    return series


def _record(series: CycleSeries, cycle: int, sim: Simulation, on_cycle) -> None:
    length_x, length_y = box_lengths(sim)
    series.cycle.append(cycle)
    series.time.append(sim.time)
    series.length_x.append(length_x)
    series.length_y.append(length_y)
    if on_cycle is not None:
        on_cycle(cycle, sim, length_x, length_y)
