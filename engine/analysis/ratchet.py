"""Strain per cycle and the ratchet verdict of McNamara, García-Rojo & Herrmann (Sec. IV B 1),
and the statistics of a study of many samples: the share ratcheting and its sign with Wilson
intervals, the geometric mean of |Δγ| with its t interval, under each verdict rule.

Pure functions of the wall positions recorded at the minimum of the load of each cycle.
"""

from __future__ import annotations

import math
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


def ratchet_verdict(cycles, gamma, threshold: float = 1.0) -> RatchetVerdict:
    """Judge a strain series ``gamma`` recorded at the cycles ``cycles`` (at least 3 points):
    ratcheting if the RMS distance from the fitted line is below ``threshold`` times its slope (the
    paper: 1)."""
    cycles = np.asarray(cycles, dtype=float)
    gamma = np.asarray(gamma, dtype=float)
    if cycles.shape != gamma.shape or cycles.ndim != 1:
        raise ParameterError("gamma", f"shape {gamma.shape}", f"one value per cycle ({cycles.shape})")
    if cycles.size < 3:
        raise ParameterError("cycles", int(cycles.size), "at least 3 cycles after the reference cycle")
    if not np.all(np.isfinite(gamma)):
        raise ParameterError("gamma", "non-finite values", "finite strains")
    if not threshold > 0:
        raise ParameterError("threshold", threshold, "a positive multiple of |Δγ|")
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
    return RatchetVerdict(dgamma=slope, rms_deviation=rms, ratcheting=bool(rms < threshold * abs(slope)),
                          shakedown=shakedown, outlier_cycles=outliers, cycles_used=int(cycles.size), gamma=gamma,
                          dgamma_without_outliers=slope_smooth,
                          ratcheting_without_outliers=bool(rms_smooth < threshold * abs(slope_smooth)))


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


def wilson_interval(successes: int, trials: int) -> tuple[float, float] | None:
    """Wilson's 95 % score interval for a share ``successes / trials`` (None without trials): unlike
    the normal approximation it stays within [0, 1] and holds for shares near 0 or 1 and few trials."""
    from scipy.stats import binomtest

    if trials <= 0:
        return None
    if not 0 <= successes <= trials:
        raise ParameterError("successes", successes, f"from 0 to the trials ({trials})")
    interval = binomtest(successes, trials).proportion_ci(confidence_level=0.95, method="wilson")
    return float(interval.low), float(interval.high)


def geometric_mean_interval(values) -> tuple[float, tuple[float, float] | None] | None:
    """The geometric mean of positive ``values`` and its 95 % interval (Student's t on their
    logarithms: |Δγ| spans decades, its logarithm is the quantity that is roughly normal); None
    without values, no interval with one."""
    from scipy.stats import t

    logs = np.log(np.asarray(values, dtype=float))
    if logs.size == 0:
        return None
    mean = float(np.mean(logs))
    if logs.size < 2:
        return math.exp(mean), None
    half = float(t.ppf(0.975, logs.size - 1)) * float(np.std(logs, ddof=1)) / math.sqrt(logs.size)
    return math.exp(mean), (math.exp(mean - half), math.exp(mean + half))


@dataclass(frozen=True)
class VerdictRule:
    """A verdict rule of a study: the strain fitted from cycle ``first_share`` × cycles on (None:
    the study's reference cycle), ratcheting if RMS < ``threshold`` |Δγ|; ``jumps``: False to
    judge the series with a rattler's jumps taken out (:class:`RatchetVerdict`)."""

    first_share: float | None = None
    threshold: float = 1.0
    jumps: bool = True

    def reference_cycle(self, cycles: int, study_reference: int) -> int:
        if self.first_share is None:
            return study_reference
        return min(round(self.first_share * cycles), cycles - 3)

    def describe(self, cycles: int, study_reference: int) -> str:
        """E.g. "cycles 30-100, RMS < |Δγ|" (the paper's rule on 100 cycles)."""
        factor = "" if self.threshold == 1.0 else f"{self.threshold:g} "
        text = f"cycles {self.reference_cycle(cycles, study_reference)}-{cycles}, RMS < {factor}|Δγ|"
        return text + ("" if self.jumps else ", a rattler's jumps out")


VERDICT_RULES = (VerdictRule(), VerdictRule(first_share=0.1), VerdictRule(first_share=0.6),
                 VerdictRule(first_share=0.8), VerdictRule(threshold=0.5), VerdictRule(threshold=2.0),
                 VerdictRule(jumps=False))
"""The rules a study's samples are judged by, the paper's first (from the reference cycle, 30 of 100,
RMS < |Δγ|): its verdict depends on how many cycles are fitted and on a threshold it does not justify."""


def judge(length_x, length_y, reference_cycle: int, rule: VerdictRule) -> tuple[bool, float]:
    """Whether a sample ratchets under ``rule``, and its Δγ, from the box lengths at the start of
    each cycle (cycle k at index k) and the study's reference cycle."""
    length_x, length_y = np.asarray(length_x, dtype=float), np.asarray(length_y, dtype=float)
    cycles = length_x.size - 1
    first = rule.reference_cycle(cycles, reference_cycle)
    gamma = deviatoric_strain(length_x[first:], length_y[first:], length_x[first], length_y[first])
    verdict = ratchet_verdict(np.arange(first, cycles + 1), gamma, rule.threshold)
    if rule.jumps:
        return verdict.ratcheting, verdict.dgamma
    return verdict.ratcheting_without_outliers, verdict.dgamma_without_outliers


def share_statistics(verdicts: list[tuple[bool, float]]) -> dict:
    """Of the samples' (ratcheting, Δγ): how many ratchet, and of those how many are negative, each
    with its Wilson interval; the geometric mean of |Δγ| over those ratcheting, with its interval."""
    ratcheting = [dgamma for ratchets, dgamma in verdicts if ratchets]
    negative = sum(1 for dgamma in ratcheting if dgamma < 0)
    magnitudes = [abs(d) for d in ratcheting if d != 0]
    geomean = geometric_mean_interval(magnitudes)
    return {"samples": len(verdicts), "ratcheting": len(ratcheting),
            "ratcheting_interval": wilson_interval(len(ratcheting), len(verdicts)),
            "negative": negative, "negative_interval": wilson_interval(negative, len(ratcheting)),
            "geomean_abs_dgamma": geomean[0] if geomean else None,
            "geomean_interval": geomean[1] if geomean else None}
