"""Gilabert Sec. V: the fit of Eq. 28 recovers known fractal dimensions, I(k) of Eq. 25 matches the
transform of a disk, Eq. 29 gives the radius of circular and square holes, holes across the
periodic edges count once, and bad input is refused with a clear message."""

import math
import warnings

import numpy as np
import pytest
import scipy.special

from granlab.engine.analysis.fractal import (MAX_CELLS, FitError, curdled_packing, default_spacing, density_field,
                                             ell_of_amplitude, fit_structure, fractal_analysis, grid_shape, hole_radii,
                                             structure_factor, structure_model, weighted_hole_radius)
from granlab.engine.errors import GranLabError, ParameterError
from granlab.engine.generate import radii as make_radii, random_gas

BLOB_GENERATIONS = 4
BLOBS = 30
BOX = 700.0


@pytest.mark.parametrize("kept", [5, 8])
def test_fit_recovers_known_fractal_dimension(kept):
    """Random curdling keeping 5 or 8 squares of 9 (d_F = log 5 / log 3 = 1.465, log 8 / log 3 = 1.893)
    down to unit disks, 4 generations (blobs 81 diameters wide), 30 blobs at random in a periodic box
    of 700 diameters, on a grid of a / 4."""
    known = math.log(kept) / math.log(3.0)
    positions, radii = curdled_packing(BLOBS * kept ** BLOB_GENERATIONS, (BOX, BOX), kept=kept,
                                       generations=BLOB_GENERATIONS, diameters=(1.0, 1.0), seed=0)

    result = fractal_analysis(positions, radii, (BOX, BOX), spacing=0.25)

    assert abs(result.d_F - known) < 0.1
    assert 0.0 < result.d_F_error < 0.05
    assert result.fit_range == pytest.approx((result.k[0], 2.0 * math.pi))
    assert 3.0 < result.xi < 2.0 * 3.0 ** BLOB_GENERATIONS  # the cut-off is of the order of the blob size
    assert result.mean_hole_radius_w == math.inf  # the empty space between the blobs wraps around the box


def test_dimensions_are_told_apart():
    """Two other samples (seed 1) do not give one constant: their fitted d_F differ as the known ones do."""
    fitted = {}
    for kept in (5, 8):
        positions, radii = curdled_packing(BLOBS * kept ** BLOB_GENERATIONS, (BOX, BOX), kept=kept,
                                           generations=BLOB_GENERATIONS, diameters=(1.0, 1.0), seed=1)
        fitted[kept] = fractal_analysis(positions, radii, (BOX, BOX), spacing=0.25).d_F
    assert fitted[8] - fitted[5] == pytest.approx(math.log(8.0 / 5.0) / math.log(3.0), abs=0.1)


def test_fit_of_eq28_returns_its_parameters():
    """Noise-free Eq. 28 gives back d_F, xi, ell, Cst; 5 % noise stays within three standard errors."""
    k = np.geomspace(0.02, 6.0, 50)
    phi, d_F, xi, ell, constant = 0.3, 1.6, 8.0, 0.5, 2e-3
    exact = structure_model(k, phi, d_F, xi, ell, constant)

    free = fit_structure(k, exact, phi, k_range=(0.0, 6.0))
    fixed = fit_structure(k, exact, phi, k_range=(0.0, 6.0), ell=ell)
    noisy = fit_structure(k, exact * np.exp(0.05 * np.random.default_rng(3).standard_normal(k.size)), phi,
                          k_range=(0.0, 6.0))

    for fit in (free, fixed):
        assert (fit.d_F, fit.xi, fit.ell, fit.constant) == pytest.approx((d_F, xi, ell, constant), rel=1e-4)
        assert fit.model(k) == pytest.approx(exact, rel=1e-5)
    assert abs(noisy.d_F - d_F) < 3.0 * noisy.d_F_error < 0.1
    assert abs(noisy.xi - xi) < 3.0 * noisy.xi_error
    assert noisy.rms == pytest.approx(0.05, rel=0.3)


def test_ell_is_given_back_from_the_amplitude_and_is_nan_where_d_f_near_2_takes_it_past_a_float():
    phi, xi, ell = 0.3, 8.0, 0.5
    for d_F in (1.2, 1.6, 1.99):
        amplitude = phi * 2.0 * math.pi * ell ** 2 * scipy.special.gamma(d_F) * (xi / ell) ** d_F
        assert ell_of_amplitude(amplitude, phi, d_F, xi) == pytest.approx(ell, rel=1e-9)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for d_F in (1.999_999_5, 2.0, 1.9999, 2.0001):  # (B / ...)^(1 / (2 - d_F)) past 1e308 or below 1e-308
            assert math.isnan(ell_of_amplitude(np.float64(0.1), phi, d_F, xi))
        assert math.isnan(ell_of_amplitude(0.0, phi, 1.6, xi))


@pytest.mark.parametrize("box, centre", [((40.0, 40.0), (20.0, 20.0)), ((40.0, 30.0), (0.3, 29.9))])
def test_intensity_of_one_disk_is_its_transform(box, centre):
    """Eq. 25 for one disk of radius R (here across the periodic corner in the second case):
    I(k) = (2 pi R J1(kR) / k)² / A for kR < 2.5 (the first zero of J1 is at kR = 3.83; near it the
    average over a bin of |k| departs from the value at the mean |k|)."""
    radius = 2.0
    area = box[0] * box[1]
    field = density_field([centre], [radius], box, 0.02)

    k, intensity = structure_factor(field, box)

    assert field.mean() * area == pytest.approx(np.pi * radius ** 2, rel=1e-3)
    low = k * radius < 2.5
    expected = (2.0 * np.pi * radius * scipy.special.j1(k * radius) / k) ** 2 / area
    assert np.count_nonzero(low) >= 6
    assert intensity[low] == pytest.approx(expected[low], rel=0.01)


def test_binned_intensity_matches_a_full_transform_shell_by_shell():
    """Brute force on an anisotropic field in a rectangular box: the full complex FFT, every
    wavevector put in the shell round(|k| / (2 pi / L_max)); the first shells (narrower than the
    logarithmic bins, so one bin each) give the same mean |k| and mean I as structure_factor."""
    box = (40.0, 30.0)
    rng = np.random.default_rng(5)
    field = density_field(rng.uniform(0.0, 40.0, (30, 2)) * (1.0, 0.75), rng.uniform(0.5, 3.0, 30), box, 0.1)
    field[:, 100:130] = 1  # a stripe along x: power on the k_y axis
    nx, ny = field.shape
    kx = 2.0 * np.pi * np.fft.fftfreq(nx, box[0] / nx)[:, None]
    ky = 2.0 * np.pi * np.fft.fftfreq(ny, box[1] / ny)[None, :]
    modulus = np.hypot(kx, ky).ravel()
    power = ((box[0] * box[1] / (nx * ny)) ** 2 / (box[0] * box[1]) * np.abs(np.fft.fft2(field)) ** 2).ravel()
    shell = np.floor(modulus / (2.0 * np.pi / 40.0) + 0.5).astype(int)

    k, intensity = structure_factor(field, box)

    for s in range(1, 9):
        assert k[s - 1] == pytest.approx(modulus[shell == s].mean(), rel=1e-9)
        assert intensity[s - 1] == pytest.approx(power[shell == s].mean(), rel=1e-4)


def _field_with_holes(shape, spacing, holes):
    """A solid grid with holes given as functions of the cell-centre coordinates (x, y) -> bool."""
    x = (np.arange(shape[0]) + 0.5)[:, None] * spacing
    y = (np.arange(shape[1]) + 0.5)[None, :] * spacing
    field = np.ones(shape, dtype=np.uint8)
    for inside in holes:
        field[inside(x, y)] = 0
    return field


def _periodic_disk(centre, radius, box):
    def inside(x, y):
        dx = (x - centre[0] + 0.5 * box[0]) % box[0] - 0.5 * box[0]
        dy = (y - centre[1] + 0.5 * box[1]) % box[1] - 0.5 * box[1]
        return dx ** 2 + dy ** 2 < radius ** 2
    return inside


def test_circular_hole_across_the_corner_counts_once_with_its_radius():
    """A disk-shaped hole of radius R cut by both periodic edges: one hole, R_H = R (Eq. 29), area pi R²."""
    spacing, shape = 0.02, (1000, 800)
    box = (shape[0] * spacing, shape[1] * spacing)
    field = _field_with_holes(shape, spacing, [_periodic_disk((0.0, 0.0), 3.0, box)])

    sizes, radius = hole_radii(field, spacing)

    assert sizes.size == 1
    assert sizes[0] * spacing ** 2 == pytest.approx(np.pi * 9.0, rel=0.005)
    assert radius[0] == pytest.approx(3.0, abs=spacing)


def test_square_hole_across_an_edge_and_a_wrapping_strip():
    """A square hole of side s across the x edge has R_H = s / sqrt 3; a strip across the whole box
    wraps around it, has no centre and gets R_H = inf; the two count as two holes."""
    spacing, shape = 0.05, (400, 300)
    box = (shape[0] * spacing, shape[1] * spacing)
    side = 4.0

    def square(x, y):
        return ((x < 0.5 * side) | (x > box[0] - 0.5 * side)) & (np.abs(y - 5.0) < 0.5 * side)

    def strip(x, y):
        return np.broadcast_to(np.abs(y - 12.0) < 0.5, np.broadcast_shapes(x.shape, y.shape))

    sizes, radius = hole_radii(_field_with_holes(shape, spacing, [square, strip]), spacing)

    order = np.argsort(radius)
    assert sizes.size == 2
    assert sizes[order[0]] * spacing ** 2 == pytest.approx(side ** 2, rel=1e-9)
    assert radius[order[0]] == pytest.approx(side / math.sqrt(3.0), abs=spacing)
    assert radius[order[1]] == math.inf


def test_hole_inside_a_ring_of_disks():
    """n disks of radius r on a circle of radius R_c (centred on the periodic corner) enclose a hole
    lying between the circles of radii R_c - r and R_c cos(pi/n) - sqrt(r² - R_c² sin²(pi/n));
    R_H² = ∫ rho⁴ / ∫ rho² lies between their squares. The outside wraps around the box."""
    count, ring, r, spacing = 60, 10.0, 1.0, 0.02
    box = (30.0, 30.0)
    angle = 2.0 * np.pi * np.arange(count) / count
    positions = ring * np.column_stack([np.cos(angle), np.sin(angle)])
    field = density_field(positions, np.full(count, r), box, spacing)
    half = np.pi / count
    outer = ring * math.cos(half) - math.sqrt(r ** 2 - (ring * math.sin(half)) ** 2)

    sizes, radius = hole_radii(field, spacing)

    finite = np.isfinite(radius)
    assert sizes.size == 2 and np.count_nonzero(finite) == 1
    assert ring - r - spacing < radius[finite][0] < outer + spacing


def test_holes_touching_at_a_corner_are_one_with_8_connectivity_also_across_the_periodic_corner():
    """Two empty squares meeting at a corner inside the grid, two more meeting across the periodic
    corner, and a diagonal line of empty cells around the box: 4-connected, 2 + 2 holes and every
    cell of the line alone; 8-connected, two holes of two squares each and one that wraps around
    the box. A pair of squares of side s = 4 cells about their shared corner: each axis's variance
    (s² - 1)/12 + s²/4 = 5.25, R_H² = 2 (5.25 + 5.25) = 21 (Eq. 29)."""
    field = np.ones((60, 60), dtype=np.uint8)
    field[10:14, 10:14] = field[14:18, 14:18] = 0  # meet at the corner (14, 14)
    field[56:60, 56:60] = field[0:4, 0:4] = 0  # meet across the periodic corner
    line = np.arange(20, 80)
    field[line % 60, (line - 20 + 30) % 60] = 0  # from (20, 30) a step of (1, 1): wraps around the box
    four_sizes, four = hole_radii(field, 1.0)
    eight_sizes, eight = hole_radii(field, 1.0, connectivity=8)
    assert sorted(four_sizes.tolist()) == [1] * 60 + [16] * 4
    assert sorted(eight_sizes.tolist()) == [32, 32, 60]
    squares = np.sort(eight[eight_sizes == 32])
    assert squares == pytest.approx([math.sqrt(21.0)] * 2, rel=1e-9)
    assert eight[eight_sizes == 60][0] == math.inf
    with pytest.raises(ParameterError, match="connectivity = 6 is not allowed: 4"):
        hole_radii(field, 1.0, connectivity=6)


def test_a_hann_window_s_intensity_is_the_periodic_one_where_the_window_does_not_reach():
    """On a random gas (no correlation beyond a disk: I(k) the same in every part of the box), the
    windowed transform, scaled by the window's mean square, gives the periodic I(k) from ten cells of
    k on: on average within 3 %, every bin within 20 % (a bin of the lowest k holds a few dozen
    wavevectors, and the two transforms weigh them differently)."""
    box = (200.0, 200.0)
    radii = np.full(4000, 0.5)
    positions = random_gas(radii, (0.0, box[0], 0.0, box[1]), periodic=(True, True), seed=5)
    field = density_field(positions, radii, box, 0.1)
    k, periodic = structure_factor(field, box)
    k_hann, hann = structure_factor(field, box, transform="hann")
    assert np.array_equal(k, k_hann)
    middle = (k > 10 * 2.0 * math.pi / box[0]) & (k < 2.0 * math.pi)
    ratio = hann[middle] / periodic[middle]
    assert abs(ratio.mean() - 1.0) < 0.03 and np.abs(ratio - 1.0).max() < 0.2
    with pytest.raises(ParameterError, match="transform = 'blackman' is not allowed: periodic or hann"):
        structure_factor(field, box, transform="blackman")


def test_mass_average_of_hole_radii():
    """Eq. 30 weights each hole by its cells: for circular holes of radii R1, R2,
    <R>_w = (R1³ + R2³) / (R1² + R2²), not the number average."""
    spacing, shape = 0.02, (1500, 1000)
    box = (shape[0] * spacing, shape[1] * spacing)
    field = _field_with_holes(shape, spacing, [_periodic_disk((5.0, 5.0), 1.0, box),
                                               _periodic_disk((20.0, 12.0), 4.0, box)])

    sizes, radius = hole_radii(field, spacing)

    assert weighted_hole_radius(sizes, radius) == pytest.approx((1.0 + 64.0) / (1.0 + 16.0), abs=spacing)
    assert math.isnan(weighted_hole_radius(np.zeros(0, dtype=np.int64), np.zeros(0)))


@pytest.mark.parametrize("call, name, allowed", [
    (lambda: fractal_analysis(np.zeros((0, 2)), np.zeros(0), (10.0, 10.0)), "radii", "at least one disk"),
    (lambda: fractal_analysis([(1.0, 1.0)], [0.5], (10.0, -1.0)), "box_lengths", "two positive"),
    (lambda: fractal_analysis([(1.0, 1.0)], [0.5], (10.0,)), "box_lengths", "two positive"),
    (lambda: fractal_analysis([(1.0, 1.0), (2.0, 2.0)], [0.5], (10.0, 10.0)), "positions", "(N, 2)"),
    (lambda: fractal_analysis([(1.0, 1.0)], [-0.5], (10.0, 10.0)), "radii", "positive radii"),
    (lambda: fractal_analysis([(1.0, 1.0)], [0.5], (1000.0, 1000.0), spacing=0.1), "spacing",
     f"at most {MAX_CELLS:.0e} cells"),
    (lambda: density_field([(1.0, 1.0)], [0.5], (10.0, 10.0), 0.0), "spacing", "positive"),
    (lambda: fit_structure([1.0, 2.0], [1.0], 0.3, diameter=1.0), "intensity", "one value per k"),
    (lambda: fit_structure(np.arange(1.0, 4.0), np.ones(3), 0.3, diameter=1.0), "k_range", "at least 6 bins"),
    (lambda: fit_structure(np.arange(1.0, 9.0), np.ones(8), 1.5, diameter=1.0), "phi", "(0, 1)"),
])
def test_bad_input_is_refused_with_a_clear_message(call, name, allowed):
    with pytest.raises(ParameterError) as raised:
        call()
    assert raised.value.name == name
    assert allowed in str(raised.value)


def test_default_grid_is_a_hundredth_of_the_largest_diameter_within_the_cap():
    """a / 100 by default (cells a little smaller, to sizes fast for the FFT); a box that would need
    more than MAX_CELLS cells at a / 100 gets a coarser grid instead of an error."""
    positions, radii = curdled_packing(2 * 7 ** 3, (30.0, 30.0), seed=2)
    diameter = 2.0 * radii.max()

    spacing = fractal_analysis(positions, radii, (30.0, 30.0)).spacing

    assert diameter / 100.0 * 0.97 < min(spacing) <= max(spacing) <= diameter / 100.0
    big = (1.2 * math.sqrt(MAX_CELLS) / 100.0,) * 2
    coarse = default_spacing(big, 1.0)
    assert 1.0 / 100.0 < coarse < 1.1 * 1.2 / 100.0
    assert math.prod(grid_shape(big, coarse)) <= MAX_CELLS


def test_a_random_gas_is_no_fractal_and_the_fit_says_so():
    """A random gas has no power-law range: the fit fails with a GranLab error naming Eq. 28; the
    analysis still returns I(k) and the holes, with the fit's values NaN and the reason."""
    r = make_radii(300, radius_min=0.25, radius_max=0.5, distribution="uniform", seed=3)
    side = math.sqrt(np.pi * np.sum(r ** 2) / 0.45)
    positions = random_gas(r, (0.0, side, 0.0, side), periodic=(True, True), seed=3)
    field = density_field(positions, r, (side, side), 0.05)
    k, intensity = structure_factor(field, (side, side))
    with pytest.raises(FitError, match="Eq. 28") as raised:
        fit_structure(k, intensity, float(field.mean()), diameter=2.0 * r.max())
    assert isinstance(raised.value, GranLabError)
    result = fractal_analysis(positions, r, (side, side), spacing=0.05)
    assert "Eq. 28" in result.fit_error and math.isnan(result.d_F) and np.isnan(result.fitted).all()
    np.testing.assert_allclose(result.intensity, intensity)
    assert result.holes >= 1 and math.isinf(result.mean_hole_radius_w)  # the void of a gas percolates
