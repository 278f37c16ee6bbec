"""The ratchet verdict of ratcheting Sec. IV B 1 on synthetic strain series, and the statistics of a
study of many samples."""

import numpy as np
import pytest

from granlab.engine import ParameterError
from granlab.engine.analysis.ratchet import (VERDICT_RULES, VerdictRule, deviatoric_strain, geometric_mean_interval,
                                            judge, ratchet_verdict, share_statistics, wilson_interval)


def test_deviatoric_strain_is_eq2():
    assert deviatoric_strain(0.99, 1.02, 1.0, 1.0) == pytest.approx(0.03)
    np.testing.assert_allclose(deviatoric_strain([2.0, 2.2], [1.0, 0.9], 2.0, 1.0), [0.0, -0.2])


def test_linear_creep_with_small_noise_ratchets_with_its_slope():
    cycles = np.arange(30, 101)
    noise = np.random.default_rng(0).normal(0.0, 1e-10, cycles.size)
    gamma = -3e-9 * (cycles - 30) + noise
    verdict = ratchet_verdict(cycles, gamma)
    assert verdict.ratcheting
    assert verdict.dgamma == pytest.approx(-3e-9, rel=1e-2)
    assert verdict.rms_deviation < 2e-10
    assert not verdict.shakedown and verdict.outlier_cycles == []
    assert verdict.ratcheting_without_outliers and verdict.dgamma_without_outliers == verdict.dgamma


def test_noise_without_trend_does_not_ratchet():
    cycles = np.arange(30, 101)
    gamma = np.random.default_rng(1).normal(0.0, 1e-9, cycles.size)
    verdict = ratchet_verdict(cycles, gamma)
    assert not verdict.ratcheting and not verdict.ratcheting_without_outliers
    assert verdict.rms_deviation > abs(verdict.dgamma)


def test_decaying_increments_are_shakedown():
    cycles = np.arange(0, 60)
    gamma = 1e-6 * (1.0 - np.exp(-cycles / 8.0))
    verdict = ratchet_verdict(cycles, gamma)
    assert verdict.shakedown


def test_isolated_jumps_are_outliers():
    cycles = np.arange(30, 101)
    gamma = 2e-9 * (cycles - 30)
    gamma[40:] += 5e-7  # a rattler hit its cage in cycle 70
    gamma[55] += 3e-7   # and bumped once more in cycle 85
    verdict = ratchet_verdict(cycles, gamma)
    assert verdict.outlier_cycles == [70, 85, 86]
    # the jumps hide the creep from the paper's rule; without them it is there, at its own slope
    assert not verdict.ratcheting and verdict.dgamma > 4e-9
    assert verdict.ratcheting_without_outliers and verdict.dgamma_without_outliers == pytest.approx(2e-9)


def test_bad_series_are_refused():
    with pytest.raises(ParameterError, match="at least 3 cycles"):
        ratchet_verdict([30, 31], [0.0, 1e-9])
    with pytest.raises(ParameterError, match="one value per cycle"):
        ratchet_verdict([30, 31, 32], [0.0, 1e-9])
    with pytest.raises(ParameterError, match="finite strains"):
        ratchet_verdict([1, 2, 3], [0.0, np.nan, 1.0])


def test_wilson_intervals_are_newcombe_s_and_cover_the_share_95_times_in_100():
    # Newcombe, Statistics in Medicine 17 (1998) 857, Table I, method 3 (Wilson's score, no correction)
    assert wilson_interval(81, 263) == pytest.approx((0.2553, 0.3662), abs=5e-5)
    assert wilson_interval(15, 148) == pytest.approx((0.0624, 0.1605), abs=5e-5)
    assert wilson_interval(0, 20) == pytest.approx((0.0, 0.1611), abs=5e-5)
    assert wilson_interval(1, 29) == pytest.approx((0.0061, 0.1718), abs=5e-5)
    assert wilson_interval(0, 0) is None
    rng = np.random.default_rng(3)
    share, trials = 0.71, 100
    covered = [low <= share <= high for low, high in (wilson_interval(int(k), trials)
                                                      for k in rng.binomial(trials, share, 4000))]
    assert 0.93 <= np.mean(covered) <= 0.97


def test_the_geometric_mean_s_interval_covers_a_log_normal_s_median_95_times_in_100():
    rng = np.random.default_rng(4)
    median = 3e-8
    covered = []
    for _ in range(2000):
        mean, (low, high) = geometric_mean_interval(median * np.exp(rng.normal(0.0, 2.3, 20)))
        assert low < mean < high
        covered.append(low <= median <= high)
    assert 0.93 <= np.mean(covered) <= 0.97
    assert geometric_mean_interval([]) is None and geometric_mean_interval([2e-9]) == (pytest.approx(2e-9), None)


def _lengths(dgamma, cycles=100, noise=0.0, seed=0):
    """Box lengths whose strain from any cycle creeps by ``dgamma`` a cycle, with noise."""
    rng = np.random.default_rng(seed)
    gamma = dgamma * np.arange(cycles + 1) + rng.normal(0.0, noise, cycles + 1)
    return np.ones(cycles + 1), 1.0 + gamma


def test_verdict_rules_judge_the_samples_as_the_paper_s_verdict_and_order_by_threshold():
    length_x, length_y = _lengths(-2e-9, noise=2e-9)
    gamma = deviatoric_strain(length_x[30:], length_y[30:], 1.0, length_y[30])
    verdict = ratchet_verdict(np.arange(30, 101), gamma)
    assert judge(length_x, length_y, 30, VERDICT_RULES[0]) == (verdict.ratcheting, pytest.approx(verdict.dgamma))
    assert VERDICT_RULES[0].describe(100, 30) == "cycles 30-100, RMS < |Δγ|"
    assert [rule.describe(100, 30) for rule in VERDICT_RULES[1:4]] == [
        "cycles 10-100, RMS < |Δγ|", "cycles 60-100, RMS < |Δγ|", "cycles 80-100, RMS < |Δγ|"]
    samples = [_lengths(d, noise=3e-9, seed=k) for k, d in enumerate(np.linspace(-8e-9, 4e-9, 40))]
    counts = {}
    for threshold in (0.5, 1.0, 2.0):
        rule = VerdictRule(threshold=threshold)
        counts[threshold] = share_statistics([judge(x, y, 30, rule) for x, y in samples])
    assert counts[0.5]["ratcheting"] <= counts[1.0]["ratcheting"] <= counts[2.0]["ratcheting"]
    assert counts[0.5]["ratcheting"] < counts[2.0]["ratcheting"]
    one = counts[1.0]
    assert one["ratcheting_interval"] == pytest.approx(wilson_interval(one["ratcheting"], 40))
    assert one["negative_interval"] == pytest.approx(wilson_interval(one["negative"], one["ratcheting"]))
    assert one["negative"] > one["ratcheting"] - one["negative"]  # two thirds of the slopes are negative
