"""The biaxial box under cyclic loading (ratcheting Sec. IV, Eq. 1): 256 disks, its 16-disk
variant (Figs. 1-4) and the elliptic loading without sliding (Figs. 5-6)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ...analysis.ratchet import ratchet_verdict, strain_fit
from ...errors import ParameterError
from ...observables import columns, coordination
from ..cyclic import CyclicLoad, apply_load
from ..equilibrium import equilibrium
from ..measures import PairMaximum, contact_rows, mobilisation
from ..prepare import COMPRESSION_RAMP, biaxial_box, hold_load, ramp_load
from ..settings import LAW_CONTROLS, LabSettings
from .base import Preset, as_number


class RatchetPreset(Preset):
    """A biaxial box compressed frictionless to P0, then cyclically loaded (ratcheting Eq. 1).

    Stages: ``compressing`` (until Gilabert's equilibrium or 200 tau), then ``cycling``. While
    cycling, P0, the amplitude and the phase wait for the next cycle start, where q = 0 (they are
    ``pending`` until then); a new period acts at once, at the same fraction of the cycle, so that
    the load goes on smoothly; each cycle ends on a step (the time step is fitted to it). Series: ``time`` (t, cycle, q,
    gamma, energies, z; cycle -1 while compressing), ``cycles`` (cycle, gamma at the start of the
    cycle, t, step, box lengths), ``contacts`` (i, j, t, F_n, F_t, status of the watched pairs).
    The watched contacts are the ``watch_count`` that came closest to the Coulomb cone during
    the first cycle (the ones that slid, if any), until the user picks others. The strain per
    cycle is fitted (:func:`granlab.engine.analysis.ratchet.ratchet_verdict`) from ``reference_cycle``
    on: the first cycles settle the packing; after a change of the physics, from the second
    whole cycle after it (``fit_from``), or from the next cycle start on request (:meth:`fit_from_now`).
    """

    name = "ratchet"
    title = "Biaxial box under cyclic loading"
    menu_name = "Biaxial box, cyclic loading"
    controls = ("pressure", "amplitude", "period", "phase", "particles", "seed") + LAW_CONTROLS
    defaults = {"particles": 256, "speed": math.inf}
    speeds = {"slow": 0.1, "normal": 0.5, "fast": math.inf}  # 256 disks: about 1 load cycle a second at most
    series = {"time": ("t", "cycle", "q", "gamma", "kinetic", "stored", "dissipated", "balance", "z"),
              "cycles": ("cycle", "gamma", "t", "step", "length_x", "length_y"),
              "contacts": ("i", "j", "t", "normal", "tangential", "status")}
    path_series = ("contacts",)
    plots = ("strain-per-cycle", "q-gamma", "coulomb-cone", "energy", "coordination")
    key_plots = ("q-gamma", "strain-per-cycle")
    time_label = "t (τ = √(ρL²/P))"
    particle_range = (4, 20000)
    elliptic = False
    compression_limit = 200.0
    watch_count = 4
    reference_cycle = 2

    def _build(self) -> None:
        s = self.settings
        # compressed as by prepare.compress, a step at a time: walls of one row, the load ramped
        self._sim = biaxial_box(s.particles, seed=s.seed, pressure=s.pressure, damping_ratio=s.damping_ratio,
                                normal_model=s.normal_model, tangential_model=s.tangential_model)
        ramp_load(self._sim, s.pressure, COMPRESSION_RAMP)
        self.stage = "compressing"
        self._ramping = True
        self._cycle = 0
        self._next_check = 1.0
        self._start = None
        self.fit_from = self.reference_cycle
        self.fit_after = ""
        self._cycle_end = math.inf
        self._cycle_gamma: list[tuple[int, float]] = []
        self.verdict = None

    def _rules(self, values: dict) -> dict[str, tuple[bool, str]]:
        pressure, amplitude = as_number(values["pressure"]), as_number(values["amplitude"])
        stiffness = self.sim.law.normal_stiffness
        low, high = stiffness / 1e4, stiffness / 20.0
        return {**super()._rules(values),
                "amplitude": (0.0 <= amplitude <= 2.0 * pressure,
                              f"an amplitude from 0 to 2 P0 = {2.0 * pressure:g} (P0 = {pressure:g}): the load must "
                              f"not swing further than the box is pressed; raise P0 first to load harder"),
                "pressure": (low <= pressure <= high and pressure >= 0.5 * amplitude,
                             f"a pressure from {low:.3g} to {high:.3g} (K_N / P0 from 10⁴ to 20, K_N = {stiffness:g}: "
                             f"harder, the disks sink into each other) and at least Δσ/2 = {0.5 * amplitude:g} "
                             f"(Δσ = {amplitude:g}); lower Δσ first to unload further"),
                "period": self._period_rule(values)}

    def _load(self) -> CyclicLoad:
        s = self.settings
        phase = math.radians(s.phase) if (self.elliptic or s.phase != 0.0) else None
        return CyclicLoad(pressure=s.pressure, amplitude=s.amplitude, period=s.period, phase=phase)

    def cycle_time(self) -> float:
        return self.load.period if self.stage == "cycling" else self.settings.period

    def _live_law_controls(self) -> tuple[str, ...]:
        # the compression is frictionless: friction and rolling resistance wait for the cycling
        waiting = ("friction", "rolling_friction", "rolling_stiffness") if self.stage == "compressing" else ()
        return tuple(key for key in super()._live_law_controls() if key not in waiting)

    def _waiting_controls(self) -> tuple[str, ...]:
        return ("pressure", "amplitude", "phase") if self.stage == "cycling" else ()

    def _changed(self, changes: dict) -> None:
        """A new period acts at once: the cycle under way goes on at the same fraction of it."""
        if "period" in changes and self.stage == "cycling":
            sim = self._sim
            fraction = (sim.time - self._start) / self.load.period
            self.load = dataclasses.replace(self.load, period=self.settings.period)
            self._start = apply_load(sim, self.load, start=sim.time - fraction * self.load.period)
            self._cycle_end = self._start + self.load.period
            sim.set_dt(None)
            self._fit_dt()

    def _clock_position(self) -> float | None:
        if self.stage != "cycling":
            return None
        return self._cycle + (self._sim.time - self._start) / self.load.period

    def _log_changes(self, before: LabSettings) -> None:
        count = len(self.changes)
        super()._log_changes(before)
        if len(self.changes) > count and self.stage == "cycling":
            change = self.changes[-1]
            self.fit_from = math.ceil(change["cycle"] - 1e-9) + self.reference_cycle
            self.fit_after = "after " + "; ".join(c["text"] for c in self.changes[count:][-2:])
            self._fit_verdict()

    def fit_from_now(self) -> str:
        """Fit the strain from the next cycle start on (no settling cycles); says so, for the user."""
        if self.stage != "cycling":
            raise ParameterError("fit from now", self.stage, "a box that is being cycled (it is still compressing)")
        self.fit_from = math.ceil(self._clock_position() - 1e-9)
        self.fit_after = "from a chosen cycle"
        self._fit_verdict()
        return f"the strain is fitted from cycle {self.fit_from} on"

    def _fit_dt(self) -> None:
        """End the current cycle on a step: the rest of it in whole steps no longer than the
        stability allows (the next cycle starts from the automatic step again)."""
        sim = self._sim
        if self.stage != "cycling":
            return
        remaining = self._cycle_end - sim.time
        if remaining > 0.5 * sim.dt:
            sim.fit_dt(remaining)

    def _lengths(self):
        lengths = self._sim.box_lengths()
        return float(lengths[0]), float(lengths[1])

    def _advance(self, steps: int) -> int:
        sim = self._sim
        if self.stage == "compressing":
            sim.run(steps)
            if self._ramping and sim.time >= COMPRESSION_RAMP:
                self._ramping = False
                hold_load(sim, self.settings.pressure)
            if not self._ramping and sim.time >= self._next_check:
                self._next_check = sim.time + 1.0
                if equilibrium(sim, self.settings.pressure).equilibrated or sim.time > self.compression_limit:
                    self._start_cycling()
            return steps
        steps = min(steps, max(1, round((self._cycle_end - sim.time) / sim.dt)))
        sim.run(steps)
        if self._cycle == 0 and self.auto_watch:
            self.mobilised.add(*mobilisation(sim))
        if sim.time >= self._cycle_end - 0.5 * sim.dt:
            self._cycle_done()
        return steps

    def _start_cycling(self) -> None:
        sim = self._sim
        sim.set_law(friction=self.settings.friction, rolling_friction=self.settings.rolling_friction,
                    rolling_stiffness=self.settings.rolling_stiffness)
        self._lx0, self._ly0 = self._lengths()
        self.stage = "cycling"
        self._apply_load(self._load())
        self._emit_cycle()
        self.mobilised = PairMaximum()

    def _apply_load(self, load: CyclicLoad) -> None:
        """Start a cycle of ``load`` now (q = 0), with the largest stable step that divides its
        period (the automatic one if the law changed since)."""
        sim = self._sim
        self.load = load
        self._start = apply_load(sim, load)
        sim.set_dt(None)
        sim.fit_dt(load.period)
        self._cycle_end = sim.time + load.period
        self._restart_clock()

    def _cycle_done(self) -> None:
        self._cycle += 1
        if self._cycle == 1 and self.auto_watch:
            self.watch = self.mobilised.largest(self.watch_count)
        self._emit_cycle()
        self._start = self._sim.time  # the next cycle starts now, with the changes that waited for it
        self._apply_pending()
        self._apply_load(self._load())

    def _emit_cycle(self) -> None:
        sim = self._sim
        lx, ly = self._lengths()
        gamma = self._gamma()
        self._emit("cycles", (self._cycle, gamma, sim.time, sim.step, lx, ly))
        self._cycle_gamma.append((self._cycle, gamma))
        self._fit_verdict()

    def _fit_verdict(self) -> None:
        """The ratchet verdict of the cycles from ``fit_from`` on (None before three)."""
        used = [(c, g) for c, g in self._cycle_gamma if c >= self.fit_from]
        self.verdict = None
        if len(used) >= 3:
            cycles, gammas = np.array(used, dtype=float).T
            self.verdict = ratchet_verdict(cycles, gammas)

    def _gamma(self) -> float:
        if self.stage != "cycling":
            return 0.0
        lx, ly = self._lengths()
        return ly / self._ly0 - lx / self._lx0

    def sample(self) -> None:
        sim = self._sim
        energy = sim.energy()
        cycling = self.stage == "cycling"
        q = self.load.q(sim.time - self._start) if cycling else 0.0
        self._emit("time", (sim.time, self._cycle if cycling else -1, q, self._gamma(), energy.kinetic,
                            energy.stored, energy.dissipated, energy.balance, coordination(*columns(sim))))

    def sample_paths(self) -> None:
        time = self._sim.time
        for i, j, normal, tangential, status in contact_rows(self._sim, self.watch):
            self._emit("contacts", (i, j, time, normal, tangential, status))

    def status(self) -> dict:
        out = super().status()
        out["cycle"] = self._cycle
        out["strain"] = self._strain_fit()
        out["fit_from"] = {"cycle": self.fit_from, "after": self.fit_after}
        if self.pending:
            out["pending_at"] = self._cycle_end
            out["pending_from"] = "the next cycle"
        return out

    def _strain_fit(self) -> dict | None:
        return strain_fit(self._cycle_gamma, self.fit_from, self.verdict)

    def phase(self) -> str:
        """``compressing to P0 = 1``, then ``cycle 12 · q = 0.312, rising`` (q rises over the first
        half of each cycle and falls back over the second)."""
        if self.stage != "cycling":
            return f"{self.stage} to P0 = {self.settings.pressure:g}"
        elapsed = self._sim.time - self._start
        rising = elapsed % self.load.period < 0.5 * self.load.period
        return f"cycle {self._cycle} · q = {self.load.q(elapsed):.3f}, {'rising' if rising else 'falling'}"


class Ratchet16Preset(RatchetPreset):
    name = "ratchet16"
    title = "Ratcheting with 16 disks (ratcheting Figs. 1-4)"
    menu_name = "Ratcheting, 16 disks (Figs. 1–4)"
    defaults = {"particles": 16, "speed": 0.5}
    speeds = Preset.speeds
    key_plots = ("strain-per-cycle", "coulomb-cone")
    watch_count = 6


class EllipticPreset(RatchetPreset):
    name = "elliptic"
    title = "Elliptic loading without sliding (ratcheting Figs. 5-6)"
    menu_name = "Elliptic loading (Figs. 5–6)"
    defaults = {"particles": 16, "friction": math.inf, "phase": 90.0, "speed": 0.5}
    speeds = Preset.speeds
    key_plots = ("strain-per-cycle", "coulomb-cone")
    elliptic = True
    watch_count = 6
