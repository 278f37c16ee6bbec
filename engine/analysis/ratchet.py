"""Strain per cycle and the ratchet verdict of McNamara, García-Rojo & Herrmann (Sec. IV B 1).

Pure functions of the wall positions recorded at the minimum of the load of each cycle.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import ParameterError


def deviatoric_strain(length_x, length_y, length_x0: float, length_y0: float) -> np.ndarray:
    """``gamma = L_y / L_y0 - L_x / L_x0`` (ratcheting Eq. 2)."""
    return np.asarray(length_y, dtype=float) / length_y0 - np.asarray(length_x, dtype=float) / length_x0


@dataclass(frozen=True)
class RatchetVerdict:
    """The paper's criterion and the behaviours of Sec. IV B 3.

    - ``dgamma``: slope of the line fitted to gamma(N), the strain per cycle;
    - ``rms_deviation``: RMS distance of the points from that line;
    - ``ratcheting``: ``rms_deviation < |dgamma|`` (the paper's rule);
    - ``shakedown``: the strain increments shrink (their size in the last third of the
      cycles is below half that in the first third, with a negative trend);
    - ``outlier_cycles``: cycles whose increment lies more than 6 robust standard
      deviations (1.4826 × median absolute deviation, at least 5 % of the median increment)
      from the median increment;
    - ``dgamma_without_outliers``, ``ratcheting_without_outliers``: the same fit and rule on the
      series with each outlier increment replaced by the median increment: the verdict without the
      jumps a rattler's collisions make (Sec. IV B 3, Figs. 15-16).
    """

    dgamma: float
    rms_deviation: float
    ratcheting: bool
    shakedown: bool
    outlier_cycles: list[int] = field(default_factory=list)
    cycles_used: int = 0
    gamma: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    dgamma_without_outliers: float = 0.0
    ratcheting_without_outliers: bool = False


def _line(cycles, gamma) -> tuple[float, float]:
    """Slope of the least-squares line through ``gamma(cycles)`` and the RMS distance from it."""
    slope, intercept = np.polyfit(cycles, gamma, 1)
    return float(slope), float(np.sqrt(np.mean((gamma - (slope * cycles + intercept)) ** 2)))


def ratchet_verdict(cycles, gamma) -> RatchetVerdict:
    """Judge a strain series ``gamma`` recorded at the cycles ``cycles`` (at least 3 points)."""
    cycles = np.asarray(cycles, dtype=float)
    gamma = np.asarray(gamma, dtype=float)
    if cycles.shape != gamma.shape or cycles.ndim != 1:
        raise ParameterError("gamma", f"shape {gamma.shape}", f"one value per cycle ({cycles.shape})")
    if cycles.size < 3:
        raise ParameterError("cycles", int(cycles.size), "at least 3 cycles after the reference cycle")
    if not np.all(np.isfinite(gamma)):
        raise ParameterError("gamma", "non-finite values", "finite strains")
    slope, rms = _line(cycles, gamma)
    increments = np.diff(gamma)
    median = np.median(increments)
    spread = max(1.4826 * np.median(np.abs(increments - median)), 0.05 * abs(median),
                 1e-12 * float(np.max(np.abs(gamma))))
    jumps = np.abs(increments - median) > 6.0 * spread
    outliers = [int(cycles[k + 1]) for k in np.flatnonzero(jumps)]
    slope_smooth, rms_smooth = slope, rms
    if outliers:
        smoothed = np.concatenate([[gamma[0]], gamma[0] + np.cumsum(np.where(jumps, median, increments))])
        slope_smooth, rms_smooth = _line(cycles, smoothed)
    third = max(1, increments.size // 3)
    size = np.abs(increments)
    early, late = float(np.mean(size[:third])), float(np.mean(size[-third:]))
    trend = np.polyfit(np.arange(size.size), size, 1)[0] if size.size >= 2 else 0.0
    shakedown = bool(increments.size >= 6 and early > 0 and late < 0.5 * early and trend < 0)
    return RatchetVerdict(dgamma=slope, rms_deviation=rms, ratcheting=bool(rms < abs(slope)),
                          shakedown=shakedown, outlier_cycles=outliers, cycles_used=int(cycles.size), gamma=gamma,
                          dgamma_without_outliers=slope_smooth,
                          ratcheting_without_outliers=bool(rms_smooth < abs(slope_smooth)))


def strain_fit(cycle_gamma, reference_cycle: int, verdict=None) -> dict | None:
    """The strain per cycle fitted from ``reference_cycle`` on, given (cycle, γ) pairs (None
    before three cycles); the line passes through the mean of the fitted points. ``verdict``:
    the :func:`ratchet_verdict` of those cycles if already known (a preset keeps it)."""
    used = [(c, g) for c, g in cycle_gamma if c >= reference_cycle]
    if len(used) < 3:
        return None
    cycles, gammas = np.array(used, dtype=float).T
    v = verdict or ratchet_verdict(cycles, gammas)
    gamma_ref = dict(cycle_gamma)[reference_cycle]
    return {"reference_cycle": reference_cycle, "gamma_ref": gamma_ref, "dgamma": v.dgamma,
            "rms": v.rms_deviation, "ratcheting": v.ratcheting, "cycles_used": v.cycles_used,
            "mean_cycle": float(np.mean(cycles)), "mean_gamma": float(np.mean(v.gamma))}
