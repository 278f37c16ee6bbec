"""Contact-law kernels against closed forms, quadrature and finite differences."""

import math

import numpy as np
import pytest

from granlab.engine.kernels import laws, normal
from granlab.engine.kernels.normal import area
from granlab.engine.params import NORMAL
from granlab.engine.state import STATUS_SLIDE_NEG, STATUS_SLIDE_POS, STATUS_STICK


def lens_area_reference(ri, rj, d):
    """Textbook lens area of two circles (a formula independent of the kernel's half-angle form)."""
    a = ri * ri * math.acos((d * d + ri * ri - rj * rj) / (2 * d * ri))
    b = rj * rj * math.acos((d * d + rj * rj - ri * ri) / (2 * d * rj))
    c = 0.5 * math.sqrt((-d + ri + rj) * (d + ri - rj) * (d - ri + rj) * (d + ri + rj))
    return a + b - c


@pytest.mark.parametrize("ri,rj,overlap", [(1.0, 1.0, 0.3), (0.5, 0.8, 0.1), (0.7, 0.35, 0.05), (1.0, 1.0, 1e-3)])
def test_overlap_area_matches_textbook_lens(ri, rj, overlap):
    d = ri + rj - overlap
    assert area.overlap_area(overlap, ri, rj, False) == pytest.approx(lens_area_reference(ri, rj, d), rel=1e-12)


def test_overlap_area_keeps_precision_for_tiny_overlaps():
    # for small overlap delta of equal disks, A = (4/3) sqrt(r) delta^(3/2) (1 + O(delta/r))
    r, delta = 1.0, 1e-9
    expected = 4.0 / 3.0 * math.sqrt(r) * delta ** 1.5
    assert area.overlap_area(delta, r, r, False) == pytest.approx(expected, rel=1e-6)


def test_wall_segment_area_is_half_of_symmetric_lens():
    r, delta = 0.8, 0.2
    # a lens of two equal disks is two equal segments of height delta / 2
    assert 2 * area.overlap_area(delta / 2, r, 0.0, True) == pytest.approx(area.overlap_area(delta, r, r, False))


@pytest.mark.parametrize("name", NORMAL)
@pytest.mark.parametrize("is_wall", [False, True])
def test_each_normal_law_stores_the_integral_of_its_force_and_its_stiffness_is_its_derivative(name, is_wall):
    model = NORMAL[name].code
    kn, ri, rj, overlap = 1e4, 0.6, 0.4, 0.03
    h = 1e-6
    derivative = (normal.energy(model, kn, overlap + h, ri, rj, is_wall)
                  - normal.energy(model, kn, overlap - h, ri, rj, is_wall)) / (2 * h)
    assert derivative == pytest.approx(normal.force(model, kn, overlap, ri, rj, is_wall), rel=1e-7)
    slope = (normal.force(model, kn, overlap + h, ri, rj, is_wall)
             - normal.force(model, kn, overlap - h, ri, rj, is_wall)) / (2 * h)
    assert slope == pytest.approx(normal.stiffness(model, kn, overlap, ri, rj, is_wall), rel=1e-6)
    assert normal.force(model, kn, 0.0, ri, rj, is_wall) == normal.energy(model, kn, -0.1, ri, rj, is_wall) == 0.0


def test_area_law_stiffness_never_exceeds_kn():
    kn, r = 1e4, 0.5
    overlaps = np.linspace(1e-6, 0.9 * r, 200)
    forces = np.array([normal.force(NORMAL["area"].code, kn, d, r, r, False) for d in overlaps])
    assert np.all(np.diff(forces) / np.diff(overlaps) <= kn * (1 + 1e-9))
    assert normal.largest_stiffness("area", kn, np.array([0.3, r])) == kn


@pytest.mark.parametrize("gap", [-0.01, 0.0, 0.002, 0.005, 0.0099])
def test_cohesion_potential_derivative_is_minus_force(gap):
    f0, d0, h = 2.0, 0.01, 1e-8
    derivative = (laws.cohesion_potential(f0, d0, gap + h) - laws.cohesion_potential(f0, d0, gap - h)) / (2 * h)
    assert -derivative == pytest.approx(laws.cohesion_force(f0, d0, gap), rel=1e-6)


def test_cohesion_force_is_gilabert_eq4():
    assert laws.cohesion_force(1.5, 0.01, -0.1) == -1.5
    assert laws.cohesion_force(1.5, 0.01, 0.0025) == pytest.approx(-1.5 * 0.75)
    assert laws.cohesion_force(1.5, 0.01, 0.02) == 0.0


def test_coulomb_sticks_inside_and_slides_on_the_cone():
    kt, mu, ne = 100.0, 0.5, 10.0
    spring, ft, status, slip = laws.coulomb(kt, mu, 0.0, ne, 0.01, 0.0)
    assert (spring, ft, status, slip) == (0.01, -1.0, STATUS_STICK, 0.0)
    spring, ft, status, slip = laws.coulomb(kt, mu, 0.0, ne, 0.2, 0.0)
    assert ft == -5.0 and status == STATUS_SLIDE_NEG and spring == pytest.approx(0.05) and slip == pytest.approx(0.15)
    spring, ft, status, slip = laws.coulomb(kt, mu, 0.0, ne, -0.2, 0.0)
    assert ft == 5.0 and status == STATUS_SLIDE_POS and spring == pytest.approx(-0.05)


def test_coulomb_with_infinite_friction_never_slides():
    spring, ft, status, slip = laws.coulomb(100.0, math.inf, 0.0, 1e-9, 1e6, 0.0)
    assert status == STATUS_STICK and ft == -1e8 and slip == 0.0


def test_rolling_spring_is_elastic_then_plastic():
    kr, mu_r, ne = 10.0, 0.01, 5.0
    spring, moment, slip = laws.rolling(kr, mu_r, 0.0, ne, 0.001, 0.3)
    assert moment == pytest.approx(-0.01) and slip == 0.0
    spring, moment, slip = laws.rolling(kr, mu_r, 0.0, ne, 0.02, 0.3)
    assert moment == pytest.approx(-mu_r * ne) and spring == pytest.approx(mu_r * ne / kr)
    assert slip == pytest.approx(0.02 - mu_r * ne / kr)


def test_viscous_rolling_moment_acts_while_the_spring_holds_and_stays_within_the_limit():
    kr, mu_r, gamma_r, ne = 10.0, 0.01, 0.1, 5.0
    spring, moment, slip = laws.rolling(kr, mu_r, gamma_r, ne, 0.001, 0.2)
    assert moment == pytest.approx(-0.01 - 0.02) and slip == 0.0 and spring == 0.001
    spring, moment, slip = laws.rolling(kr, mu_r, gamma_r, ne, 0.001, 2.0)
    assert moment == pytest.approx(-mu_r * ne) and slip == 0.0  # clipped, the spring kept
    spring, moment, slip = laws.rolling(kr, mu_r, gamma_r, ne, 0.02, -2.0)
    assert moment == pytest.approx(-mu_r * ne) and slip == pytest.approx(0.02 - mu_r * ne / kr)


def test_wrap_angle_range():
    values = np.array([laws.wrap_angle(x) for x in np.linspace(-20, 20, 1001)])
    assert values.min() >= -math.pi and values.max() < math.pi
    assert laws.wrap_angle(3 * math.pi + 0.1) == pytest.approx(-math.pi + 0.1)
