"""The ratchet verdict of ratcheting Sec. IV B 1 on synthetic strain series."""

import numpy as np
import pytest

from granlab.engine import ParameterError
from granlab.engine.analysis.ratchet import deviatoric_strain, ratchet_verdict


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
