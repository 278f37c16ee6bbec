"""Fractal geometry of a packing (Gilabert, Roux & Castellanos Sec. V): scattering function, fractal
dimension, blob size and holes.

The solid indicator chi(r) (1 inside a disk, 0 outside) is sampled at the centres of a periodic grid
of cells ``dx × dy`` (Sec. V C: "of the order of a/100"); ``field[i, j]`` is the point
``((i + 1/2) dx, (j + 1/2) dy)``, so ``field.shape = (nx, ny)`` and ``spacing = (dx, dy)``.

- Scattering function (Eq. 25): ``I(k) = |chi_hat(k)|² / A`` with ``chi_hat(k) = ∫ chi(r) e^{-i k·r} d²r``
  (``dx dy`` times the FFT), averaged over the wavevectors of each bin of ``|k|``; ``k = 0`` left out.
  It is the Fourier transform of ``C(r) - Phi²`` (Eq. 24).
- Fit (Eqs. 27-28): ``C(r) - Phi² = Phi (r/ell)^(d_F - 2) e^(-r/xi)`` transforms into
  ``I(k) = Cst + Phi 2 pi ell² Gamma(d_F) (xi/ell)^d_F 2F1[(1 + d_F)/2, d_F/2; 1; -xi² k²]``, which
  falls as ``k^-d_F`` for ``2 pi/xi << k << 2 pi/a`` (Eq. 26). It is fitted by Levenberg-Marquardt on
  ``log I`` (relative errors, every bin weighted alike) from ``2 pi / L`` to ``2 pi / a``, ``ell`` free;
  a packing without a power-law range (a gas, a dense packing) makes the fit fail with
  :class:`FitError`.
- Holes (Eqs. 29-30): the connected regions of ``chi = 0`` (4-neighbour connectivity, joined across
  the periodic edges), each with ``N_H`` cells and equivalent radius
  ``R_H = sqrt(2/N_H sum |r_i - r_H^c|²)`` (a disk of radius R has R_H = R) computed on the
  periodically unwrapped hole, and their mass average ``<R>_w = sum N_H R_H / sum N_H``.

:func:`curdled_packing` builds aggregates of known fractal dimension (the tests' reference);
``granlab bench --analysis`` times each stage on 5600 disks at the default grid ``a / 100``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import scipy.fft
import scipy.ndimage
import scipy.optimize
import scipy.special

from ..errors import GranLabError, ParameterError
from ..kernels.grid import label_moments, paint_disks, shell_sums
from ..params import whole
from .report import AnalysisReport, Clock

LABELS = {
    "d_F": "Fractal dimension d_F (fit of Gilabert Eq. 28) [dimensionless]",
    "d_F_error": "One-sigma error of d_F",
    "xi": "Blob size ξ, the cut-off length of Eqs. 27–28 [length]",
    "xi_error": "One-sigma error of ξ [length]",
    "constant": "Constant Cst of Eq. 28 [length²]",
    "ell": "Length ℓ of Eq. 27 [length]",
    "phi": "Solid fraction Φ of the grid, the mean of χ [dimensionless]",
    "spacing": "Grid cell dx × dy (Sec. V C: about a/100) [length]",
    "shape": "Grid cells nx × ny",
    "fit_range": "k range of the fit [1/length]",
    "holes": "Holes: connected empty regions",
    "mean_hole_radius_w": "Weighted mean hole radius ⟨R⟩_w (Gilabert Eq. 30) [length]",
    "fit_error": "Fit of Eq. 28 to I(k) (Gilabert Eq. 25)",
}
"""The label of each value of the fractal analysis (:func:`run`)."""
MAX_CELLS = 80_000_000
"""Largest grid allowed: 8e7 cells, about 1 GB at the peak (the field in float32 and its transform,
0.3 GB each; 0.77 GB measured at 6.6e7 cells)."""
CELLS_PER_DIAMETER = 100
"""Default grid: ``dx = a / 100``, ``a`` the largest diameter (Gilabert Sec. V C)."""
BINS_PER_DECADE = 20
"""Bins of ``|k|``: shells ``2 pi / L`` wide (``L`` the longer box side), merged into bins
``10^(1/20)`` wide in ``k`` where a shell is narrower than that."""
FIT_K_MAX = 2.0 * math.pi
"""The fit uses ``2 pi / L <= k <= FIT_K_MAX / a``: the whole range below the disk scale ``2 pi / a``
that bounds the power law of Eq. 26 (the crossover at ``xi`` is part of Eq. 28). On
:func:`curdled_packing` (d_F from 1.26 to 1.89, 5 samples each) this recovered d_F within 0.07;
stopping at ``pi / a`` gave d_F too large by up to 0.09 for d_F <= 1.5, the crossover, which Eq. 28
models only roughly, then weighing more."""
D_F_RANGE = (0.0, 3.0)
"""A fit ending outside this range of d_F counts as failed (I(k) is then no power law)."""
MIN_XI_K_MAX = 2.0
"""A fit whose blob size ``xi`` is below ``MIN_XI_K_MAX / k_max`` (about a / pi) counts as failed: Eq. 28
is then flat over the whole fitted range and its d_F describes no power law there (a dense packing
fits that way)."""
NOT_FINITE_RESIDUAL = 1e3
"""Residual of log I put where Eq. 28 overflows during the fit, so that Levenberg-Marquardt steps back."""
NO_POWER_LAW = ("no power-law range in I(k) to fit by Eq. 28: a dense or random packing, or too small a cell, "
                "has none")
TOO_FEW_WAVEVECTORS = "too few wavevectors below 2π/a for a fit of Eq. 28: the cell is too small"
NO_FIT = "no fit of Eq. 28, see d_F"
ELL_DROPS_OUT = "d_F ≈ 2: ℓ drops out of Eq. 28"
HOLES_PERCOLATE = ("a hole wraps around the periodic cell: the holes percolate and ⟨R⟩_w is not defined "
                   "(Gilabert Sec. V C)")
NO_HOLES = "no holes: the disks cover the whole cell"


class FitError(GranLabError, RuntimeError):
    """The fit of Eq. 28 did not converge."""


@dataclass(frozen=True)
class StructureFit:
    """Eq. 28 fitted to ``I(k)``: ``d_F``, ``xi`` with their one-sigma errors (from the Jacobian at
    the optimum and the scatter of the residuals), ``constant`` (Cst), ``ell``, ``amplitude``
    ``B = Phi 2 pi ell² Gamma(d_F) (xi/ell)^d_F``, ``fit_range`` ``(k_min, k_max)``, ``points`` (bins
    used) and ``rms`` (RMS residual of ``log I``)."""

    d_F: float
    d_F_error: float
    xi: float
    xi_error: float
    constant: float
    ell: float
    amplitude: float
    fit_range: tuple[float, float]
    points: int
    rms: float

    def model(self, k) -> np.ndarray:
        """Eq. 28 at ``k`` with the fitted parameters."""
        return _eq28(np.asarray(k, dtype=float), self.d_F, self.xi, self.amplitude, self.constant)


@dataclass(frozen=True)
class FractalAnalysis:
    """The geometry of a packing (Gilabert Sec. V).

    ``d_F``, ``xi`` (with one-sigma errors), ``constant`` (Cst) and ``ell``: the fit of Eq. 28 (ell
    fitted with the others, see :func:`fit_structure`); ``phi``: the solid fraction
    of the grid (mean of chi); ``spacing`` (dx, dy) and ``shape`` (nx, ny) of the grid; ``k``,
    ``intensity``: binned ``|k|`` and ``I(k)`` (Eq. 25); ``fitted``: Eq. 28 at those ``k``;
    ``fit_range``: the ``k`` range of the fit; ``holes``: number of holes; ``mean_hole_radius_w``:
    ``<R>_w`` (Eq. 30), ``inf`` if a hole wraps around the periodic box (the holes percolate and
    ``<R>_w`` is not defined, Sec. V C), ``nan`` without holes; ``fit_error``: why the fit failed
    (its values are then NaN), empty when it succeeded; ``reasons``: for each value that is NaN or
    inf, why, in a few words for people (not in :meth:`as_dict`).
    """

    d_F: float
    d_F_error: float
    xi: float
    xi_error: float
    constant: float
    ell: float
    phi: float
    spacing: tuple[float, float]
    shape: tuple[int, int]
    k: np.ndarray
    intensity: np.ndarray
    fitted: np.ndarray
    fit_range: tuple[float, float]
    holes: int
    mean_hole_radius_w: float
    fit_error: str = ""
    reasons: dict[str, str] = dataclasses.field(default_factory=dict)

    def as_dict(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k not in ("k", "intensity", "fitted", "reasons")}


def small_scale_amplitude(phi: float, xi_over_a: float, d_F: float) -> float:
    """``k0 = Phi (xi/a)^(2 - d_F)``: the solid fraction at the scale of one diameter that the
    fractal law implies when it meets the mean density at xi (``Phi (r/xi)^(d_F - 2)`` at ``r = a``).
    It separates the small scale from xi: at a fixed k0 a fitted d_F and xi trade against each other
    (near d_F = 2 a small change of k0 moves xi by a factor). From the paper's Tables IV, V and VII:
    1.03 and 1.16 with rolling resistance (P* = 0, 0.01: above 1, the law cannot hold down to one
    diameter), 0.42 and 0.54 without."""
    return phi * xi_over_a ** (2.0 - d_F)


# ---------------------------------------------------------------------------------------- grid

def grid_shape(box_lengths, spacing) -> tuple[int, int]:
    """Cells ``(nx, ny)``: the smallest sizes fast for the FFT whose cells are no wider than
    ``spacing`` (a length or ``(dx, dy)``); at most ``MAX_CELLS`` in all."""
    shape = _cells(_box(box_lengths), spacing)
    if shape[0] * shape[1] > MAX_CELLS:
        raise ParameterError("spacing", spacing, f"a grid of at most {MAX_CELLS:.0e} cells (this one has "
                                                 f"{shape[0]} × {shape[1]}); use a coarser spacing")
    return shape


def default_spacing(box_lengths, diameter: float) -> float:
    """``diameter / CELLS_PER_DIAMETER``, coarsened by steps of 1 % until the grid holds at most
    ``MAX_CELLS`` cells."""
    lengths = _box(box_lengths)
    step = max(_positive("diameter", diameter) / CELLS_PER_DIAMETER, math.sqrt(lengths[0] * lengths[1] / MAX_CELLS))
    while math.prod(_cells(lengths, step)) > MAX_CELLS:
        step *= 1.01
    return step


def _cells(lengths, spacing) -> tuple[int, int]:
    steps = (spacing, spacing) if np.ndim(spacing) == 0 else tuple(spacing)
    if len(steps) != 2:
        raise ParameterError("spacing", spacing, "a positive length or two, (dx, dy)")
    steps = tuple(_positive("spacing", s) for s in steps)
    return tuple(scipy.fft.next_fast_len(max(8, math.ceil(length / step - 1e-9)), real=True)
                 for length, step in zip(lengths, steps))


def density_field(positions, radii, box_lengths, spacing) -> np.ndarray:
    """chi on the periodic grid of :func:`grid_shape` (``uint8``, shape ``(nx, ny)``, cell
    ``(L_x / nx, L_y / ny)``); positions are wrapped into the box ``[0, L_x) × [0, L_y)``."""
    positions, radii = _disks(positions, radii)
    lengths = _box(box_lengths)
    nx, ny = grid_shape(lengths, spacing)
    field = np.zeros((nx, ny), dtype=np.uint8)
    paint_disks(np.mod(positions, lengths), radii, lengths[0] / nx, lengths[1] / ny, field)
    return field


# -------------------------------------------------------------------------- scattering function

TRANSFORMS = ("periodic", "hann")
"""How :func:`structure_factor` transforms the field: as the periodic cell it is (the paper's cells are
periodic), or as a window cut from a larger packing: ``chi - Phi`` times a 2D Hann window, its power
scaled by the window's mean square (what one would do with a picture of a packing with edges)."""


def structure_factor(field, box_lengths, bins_per_decade: int = BINS_PER_DECADE,
                     transform: str = "periodic") -> tuple[np.ndarray, np.ndarray]:
    """Binned ``|k|`` and ``I(k) = |chi_hat(k)|² / A`` (Eq. 25) of a periodic ``field`` (``(nx, ny)``
    over the box), ``k = 0`` left out: the mean ``|k|`` and the mean ``I`` of the wavevectors of
    each bin (shells ``2 pi / L`` wide, merged into ``bins_per_decade`` logarithmic bins where
    those are wider). ``transform``: one of :data:`TRANSFORMS`."""
    field = np.asarray(field)
    lengths = _box(box_lengths)
    if field.ndim != 2 or min(field.shape) < 2:
        raise ParameterError("field", f"shape {field.shape}", "a 2D grid, at least 2 cells each way")
    whole("bins_per_decade", bins_per_decade, 1)
    if transform not in TRANSFORMS:
        raise ParameterError("transform", transform, " or ".join(TRANSFORMS))
    nx, ny = field.shape
    dx, dy = lengths[0] / nx, lengths[1] / ny
    values = field.astype(np.float32)
    if transform == "hann":
        wx, wy = (0.5 - 0.5 * np.cos(2.0 * math.pi * np.arange(n) / n) for n in (nx, ny))  # periodic Hann
        values -= np.float32(values.mean(dtype=np.float64))
        values *= (wx / math.sqrt(np.mean(wx ** 2))).astype(np.float32)[:, None]
        values *= (wy / math.sqrt(np.mean(wy ** 2))).astype(np.float32)[None, :]
    spectrum = scipy.fft.rfft2(values, overwrite_x=True)  # workers: scipy.fft.set_workers (analysis_threads)
    dk = 2.0 * math.pi / max(lengths)
    shells = int(math.hypot(math.pi / dx, math.pi / dy) / dk) + 2
    count, k_sum, power_sum = np.zeros(shells), np.zeros(shells), np.zeros(shells)
    shell_sums(spectrum, ny, 2.0 * math.pi / lengths[0], 2.0 * math.pi / lengths[1], dk, count, k_sum, power_sum)
    shell = np.arange(shells)
    ratio = 10.0 ** (1.0 / bins_per_decade)
    linear_until = 1.0 / (ratio - 1.0)  # shells wider than the logarithmic bins
    bin_index = np.where(shell <= linear_until, shell,
                         np.floor(linear_until + np.log(np.maximum(shell, 1) / linear_until) / np.log(ratio)))
    bin_index = bin_index.astype(np.int64)
    count, k_sum, power_sum = (np.bincount(bin_index, weights=w) for w in (count, k_sum, power_sum))
    used = count > 0
    scale = (dx * dy) ** 2 / (lengths[0] * lengths[1])
    return k_sum[used] / count[used], scale * power_sum[used] / count[used]


def average_intensity(ks, intensities) -> tuple[np.ndarray, np.ndarray]:
    """``I(k)`` averaged over samples (Gilabert Sec. V fits the average over a series' samples, not
    each sample). Boxes of one series differ a little in size, so their bins differ: each sample's
    ``I`` is interpolated, linear in ``log I`` against ``log k`` (exact on a power law), at the bins
    of the smallest box (the coarsest) within the range of ``k`` every sample covers, and the
    values are averaged there. Bins with ``I <= 0`` are left out of a sample's interpolation."""
    pairs = []
    for k, intensity in zip(ks, intensities, strict=True):
        k, intensity = np.asarray(k, dtype=float), np.asarray(intensity, dtype=float)
        if k.ndim != 1 or k.shape != intensity.shape:
            raise ParameterError("intensity", f"shape {intensity.shape}", f"a 1D array, one value per k ({k.shape})")
        use = (k > 0.0) & (intensity > 0.0) & np.isfinite(intensity)
        if np.count_nonzero(use) < 2:
            raise ParameterError("intensity", f"{np.count_nonzero(use)} bins with k > 0 and I > 0",
                                 "at least 2 such bins per sample")
        pairs.append((k[use], intensity[use]))
    if not pairs:
        raise ParameterError("samples", 0, "at least one sample's I(k)")
    low = max(k[0] for k, _ in pairs)
    high = min(k[-1] for k, _ in pairs)
    coarsest = max(pairs, key=lambda pair: pair[0][0])[0]
    grid = coarsest[(coarsest >= low) & (coarsest <= high)]
    if grid.size < 2:
        raise ParameterError("k", f"common range [{low:.4g}, {high:.4g}]", "samples whose I(k) overlap in k")
    log_grid = np.log(grid)
    mean = np.mean([np.exp(np.interp(log_grid, np.log(k), np.log(intensity))) for k, intensity in pairs], axis=0)
    return grid, mean


def average_series_intensity(groups) -> tuple[np.ndarray, np.ndarray]:
    """``I(k)`` averaged over a series whose samples come in boxes of several sizes, as Gilabert's
    Table VII fits 4 samples of 1400 disks and 2 of 5600 together. ``groups``: per size, the
    ``(ks, intensities)`` of its samples, each averaged by :func:`average_intensity`. The bins are
    the coarsest size's, extended below its first bin by the bins of the larger boxes, which alone
    reach there; each bin is the mean over the samples whose size covers it."""
    averaged = sorted(((*average_intensity(ks, intensities), len(ks)) for ks, intensities in groups),
                      key=lambda group: -group[0][0])
    if not averaged:
        raise ParameterError("samples", 0, "at least one sample's I(k)")
    high = min(k[-1] for k, _, _ in averaged)
    grid = averaged[0][0][averaged[0][0] <= high]
    for k, _, _ in averaged[1:]:
        grid = np.concatenate([k[k < grid[0]], grid])
    log_grid = np.log(grid)
    total, samples = np.zeros_like(grid), np.zeros_like(grid)
    for k, intensity, count in averaged:
        covered = (grid >= k[0]) & (grid <= k[-1])
        total[covered] += count * np.exp(np.interp(log_grid[covered], np.log(k), np.log(intensity)))
        samples[covered] += count
    return grid, total / samples


# ------------------------------------------------------------------------------------- the fit

def ell_of_amplitude(amplitude: float, phi: float, d_F: float, xi: float) -> float:
    """``ell = (B / (Phi 2 pi Gamma(d_F) xi^d_F))^(1 / (2 - d_F))``, or ``nan`` where it is not a
    finite positive number: near ``d_F = 2`` the power takes any ratio other than 1 past the range of
    a float (it was ``inf``, with numpy's overflow warning)."""
    base = amplitude / (phi * 2.0 * math.pi * scipy.special.gamma(d_F) * xi ** d_F)
    if abs(2.0 - d_F) <= 1e-6 or not base > 0.0:
        return math.nan
    exponent = math.log(base) / (2.0 - d_F)
    return math.exp(exponent) if abs(exponent) < 700.0 else math.nan


def structure_model(k, phi: float, d_F: float, xi: float, ell: float, constant: float) -> np.ndarray:
    """Eq. 28: ``Cst + Phi 2 pi ell² Gamma(d_F) (xi/ell)^d_F 2F1[(1+d_F)/2, d_F/2; 1; -xi² k²]``."""
    amplitude = phi * 2.0 * math.pi * ell ** 2 * scipy.special.gamma(d_F) * (xi / ell) ** d_F
    return _eq28(np.asarray(k, dtype=float), d_F, xi, amplitude, constant)


def _eq28(k, d_F, xi, amplitude, constant):
    return constant + amplitude * scipy.special.hyp2f1(0.5 * (1.0 + d_F), 0.5 * d_F, 1.0, -(xi * k) ** 2)


def fit_structure(k, intensity, phi: float, diameter: float | None = None, k_range=None,
                  ell: float | None = None) -> StructureFit:
    """Fit Eq. 28 to ``I(k)`` by Levenberg-Marquardt (``scipy.optimize.least_squares(method="lm")``)
    on ``log I`` (relative errors, every bin weighted alike).

    ``k_range = (k_min, k_max)``; default: from the smallest ``k`` to ``FIT_K_MAX / diameter``
    (``diameter`` required then). ``ell``: fixed if given, else fitted. With ``ell`` free the fit
    has four parameters: ``d_F``, ``log xi``, Cst and ``log B`` with
    ``B = Phi 2 pi Gamma(d_F) ell^(2 - d_F) xi^d_F`` the amplitude of the power law (well defined
    for any ``d_F``); ``ell = (B / (Phi 2 pi Gamma(d_F) xi^d_F))^(1 / (2 - d_F))`` is derived from it
    (``nan`` near ``d_F = 2``, where ``ell`` drops out of Eq. 28). With ``ell`` fixed B follows from
    ``d_F`` and ``xi`` and the fit has three. Starts from several blob sizes (``xi`` from
    ``2 / k_max`` to ``2 / k_min``) and keeps the best fit. Raises :class:`FitError` when none
    converges to ``D_F_RANGE[0] < d_F < D_F_RANGE[1]`` with ``xi >= MIN_XI_K_MAX / k_max``.
    """
    k = np.asarray(k, dtype=float)
    intensity = np.asarray(intensity, dtype=float)
    if k.ndim != 1 or k.shape != intensity.shape:
        raise ParameterError("intensity", f"shape {intensity.shape}", f"a 1D array, one value per k ({k.shape})")
    phi = float(phi)
    if not 0.0 < phi < 1.0:
        raise ParameterError("phi", phi, "a solid fraction in (0, 1)")
    if ell is not None:
        ell = _positive("ell", ell)
    if k_range is None:
        if diameter is None:
            raise ParameterError("diameter", diameter, "a positive diameter when k_range is not given")
        k_range = (float(k.min()) if k.size else 0.0, FIT_K_MAX / _positive("diameter", diameter))
    k_min, k_max = (float(v) for v in k_range)
    if not 0.0 <= k_min < k_max:
        raise ParameterError("k_range", tuple(k_range), "(k_min, k_max) with 0 <= k_min < k_max")
    use = (k >= k_min) & (k <= k_max) & (k > 0.0) & (intensity > 0.0) & np.isfinite(intensity)
    needed = (3 if ell is not None else 4) + 2
    if np.count_nonzero(use) < needed:
        raise ParameterError("k_range", (k_min, k_max), f"a range holding at least {needed} bins of I(k) > 0 "
                                                        f"(it holds {np.count_nonzero(use)}): a larger box or "
                                                        f"a wider range")
    kk, log_i = k[use], np.log(intensity[use])
    scale = float(np.exp(np.median(log_i)))

    def unpack(p):
        d, xi, constant = p[0], math.exp(p[1]), p[2] * scale
        if ell is None:
            return d, xi, math.exp(p[3]), constant
        return d, xi, phi * 2.0 * math.pi * scipy.special.gamma(d) * ell ** (2.0 - d) * xi ** d, constant

    def residual(p):
        r = np.log(np.maximum(_eq28(kk, *unpack(p)), 1e-12 * scale)) - log_i
        return np.where(np.isfinite(r), r, NOT_FINITE_RESIDUAL)

    upper = kk.size // 2
    d0 = float(np.clip(-np.polyfit(np.log(kk[upper:]), log_i[upper:], 1)[0], 1.0, 2.0))
    best = None
    for xi0 in np.geomspace(2.0 / k_max, 2.0 / kk[0], 4):
        start = [d0, math.log(xi0), 0.0]
        if ell is None:
            shape = scipy.special.hyp2f1(0.5 * (1.0 + d0), 0.5 * d0, 1.0, -(xi0 * kk[0]) ** 2)
            start.append(float(log_i[0] - math.log(max(shape, 1e-300))))
        try:
            with np.errstate(all="ignore"):
                result = scipy.optimize.least_squares(residual, start, method="lm", x_scale="jac")
        except (ValueError, OverflowError):
            continue
        good = (result.success and np.all(np.isfinite(result.x)) and D_F_RANGE[0] < result.x[0] < D_F_RANGE[1]
                and math.exp(result.x[1]) * k_max >= MIN_XI_K_MAX)
        if good and (best is None or result.cost < best.cost):
            best = result
    if best is None:
        raise FitError(f"the fit of Eq. 28 to I(k) on {kk.size} bins in k = [{k_min:.4g}, {k_max:.4g}] did not "
                       f"converge to a fractal dimension in {D_F_RANGE} with a blob size xi >= "
                       f"{MIN_XI_K_MAX:g} / k_max: I(k) does not decay like a power law "
                       f"there (a dense or random packing has no fractal range)")
    d, xi, amplitude, constant = unpack(best.x)
    variance = 2.0 * best.cost / max(1, kk.size - best.x.size)
    errors = np.sqrt(np.maximum(np.diag(np.linalg.pinv(best.jac.T @ best.jac)), 0.0) * variance)
    if ell is None:
        ell = ell_of_amplitude(amplitude, phi, d, xi)
    return StructureFit(d_F=float(d), d_F_error=float(errors[0]), xi=float(xi), xi_error=float(xi * errors[1]),
                        constant=float(constant), ell=float(ell), amplitude=float(amplitude),
                        fit_range=(k_min, k_max), points=int(kk.size), rms=float(math.sqrt(variance)))


# ------------------------------------------------------------------------------------------ holes

def _edge_pairs(labels, connectivity: int) -> list[tuple[np.ndarray, np.ndarray, tuple[int, int]]]:
    """The cells that touch across the periodic edges: (cells at a high edge, the cells of the low
    edge they touch, the box those sit one further on in); with ``connectivity`` 8, through corners too."""
    last, first = labels[-1, :], labels[0, :]  # the x edge, along y
    top, bottom = labels[:, -1], labels[:, 0]  # the y edge, along x
    pairs = [(last, first, (1, 0)), (top, bottom, (0, 1))]
    if connectivity == 8:
        pairs += [(last[:-1], first[1:], (1, 0)), (last[-1:], first[:1], (1, 1)),
                  (last[1:], first[:-1], (1, 0)), (last[:1], first[-1:], (1, -1)),
                  (top[:-1], bottom[1:], (0, 1)), (top[-1:], bottom[:1], (1, 1)),
                  (top[1:], bottom[:-1], (0, 1)), (top[:1], bottom[-1:], (-1, 1))]
    return pairs


def _periodic_images(labels, connectivity: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Join the labels that touch across the periodic edges (union-find that keeps the periodic
    image of each label relative to its root, as :func:`granlab.engine.analysis.packing.percolation_force`
    does for disks). Returns per label its root, its image ``(s_x, s_y)`` (its cells sit at
    ``(i + s_x nx, j + s_y ny)`` in the unwrapped hole) and whether its hole wraps around the box."""
    size = int(labels.max()) + 1
    parent = np.arange(size)
    shift = np.zeros((size, 2), dtype=np.int64)
    wraps = np.zeros(size, dtype=bool)

    def root(a):
        sx = sy = 0
        while parent[a] != a:
            sx, sy = sx + shift[a, 0], sy + shift[a, 1]
            a = parent[a]
        return a, sx, sy

    for high, low, (ex, ey) in _edge_pairs(labels, connectivity):
        touching = (low > 0) & (high > 0)
        for a, b in np.unique(np.column_stack([high[touching], low[touching]]), axis=0):
            # the cells of b (low edge) continue those of a (high edge) one box further on
            ra, ax, ay = root(a)
            rb, bx, by = root(b)
            want = (ax + ex, ay + ey)
            if ra == rb:
                wraps[ra] |= (bx, by) != want
                continue
            parent[rb] = ra
            shift[rb] = (want[0] - bx, want[1] - by)
            wraps[ra] |= wraps[rb]
    roots = np.arange(size)
    images = np.zeros((size, 2), dtype=np.int64)
    for label in np.flatnonzero(parent != roots):
        roots[label], images[label, 0], images[label, 1] = root(label)
    return roots, images, wraps[roots]


def hole_radii(field, spacing, connectivity: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """``(N_H, R_H)`` of every hole of a periodic ``field`` (``(nx, ny)``, cell ``spacing = (dx, dy)``):
    the 4-connected (or with ``connectivity`` 8, also through corners) regions of ``field == 0``
    joined across the edges, ``R_H`` from Eq. 29 on the unwrapped hole, ``inf`` for a hole that
    wraps around the box (it has no centre)."""
    field = np.asarray(field)
    if field.ndim != 2 or min(field.shape) < 2:
        raise ParameterError("field", f"shape {field.shape}", "a 2D grid, at least 2 cells each way")
    if connectivity not in (4, 8):
        raise ParameterError("connectivity", connectivity, "4 (cells sharing a side) or 8 (a side or a corner)")
    if np.ndim(spacing) == 0:
        spacing = (spacing, spacing)
    dx, dy = (_positive("spacing", s) for s in spacing)
    nx, ny = field.shape
    labels, found = scipy.ndimage.label(field == 0, structure=np.ones((3, 3)) if connectivity == 8 else None)
    if found == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    count, sum_i, sum_j, sum_ii, sum_jj = (np.zeros(found + 1) for _ in range(5))
    label_moments(labels, count, sum_i, sum_j, sum_ii, sum_jj)
    roots, images, wraps = _periodic_images(labels, connectivity)
    del labels
    ox, oy = images[:, 0] * nx, images[:, 1] * ny
    sum_i, sum_ii = sum_i + ox * count, sum_ii + 2.0 * ox * sum_i + ox ** 2 * count
    sum_j, sum_jj = sum_j + oy * count, sum_jj + 2.0 * oy * sum_j + oy ** 2 * count
    holes = np.unique(roots[1:])
    n, si, sj, sii, sjj = (np.bincount(roots, weights=w)[holes] for w in (count, sum_i, sum_j, sum_ii, sum_jj))
    variance = dx ** 2 * (sii / n - (si / n) ** 2) + dy ** 2 * (sjj / n - (sj / n) ** 2)
    radius = np.where(wraps[holes], np.inf, np.sqrt(2.0 * np.maximum(variance, 0.0)))
    return n.astype(np.int64), radius


def weighted_hole_radius(sizes, radii) -> float:
    """``<R>_w = sum N_H R_H / sum N_H`` (Eq. 30): the mass average, which large holes dominate;
    ``inf`` if a hole wraps around the box, ``nan`` without holes."""
    sizes = np.asarray(sizes, dtype=float)
    return float(np.sum(sizes * np.asarray(radii, dtype=float)) / np.sum(sizes)) if sizes.size else math.nan


# --------------------------------------------------------------------------------------- facade

def fractal_analysis(positions, radii, box_lengths, spacing=None, diameter=None, lap=None, connectivity: int = 4,
                     transform: str = "periodic") -> FractalAnalysis:
    """The analysis of Gilabert Sec. V on the disks ``positions (N, 2)``, ``radii (N,)`` of the
    periodic box ``box_lengths`` (positions are wrapped into it).

    ``diameter`` (a): default the largest disk diameter. ``spacing``: default ``a / 100`` (Sec. V C),
    coarsened to keep the grid within ``MAX_CELLS``; a given ``spacing`` that needs more cells
    raises :class:`ParameterError`. I(k) is fitted by Eq. 28 from the smallest ``k`` (``2 pi / L``)
    to ``FIT_K_MAX / a`` (:func:`fit_structure`, ``ell`` fitted); when the fit fails (no power-law
    range, or too few wavevectors in a small box) the fit's values are NaN and ``fit_error`` says
    why, and I(k) and the holes are still returned. ``connectivity`` (4 or 8) joins the holes' cells
    (:func:`hole_radii`); ``transform`` is :func:`structure_factor`'s. ``lap(stage)``, if given, is
    called at the end of each stage (for timings).
    """
    lap = lap or (lambda stage: None)
    positions, radii = _disks(positions, radii)
    lengths = _box(box_lengths)
    a = 2.0 * float(radii.max()) if diameter is None else _positive("diameter", diameter)
    field = density_field(positions, radii, lengths, default_spacing(lengths, a) if spacing is None else spacing)
    lap("density field")
    nx, ny = field.shape
    dx, dy = lengths[0] / nx, lengths[1] / ny
    phi = float(field.mean(dtype=np.float64))
    k, intensity = structure_factor(field, lengths, transform=transform)
    lap("structure factor")
    reasons = {}
    try:
        fit, fit_error = fit_structure(k, intensity, phi, diameter=a), ""
    except FitError as error:
        fit, fit_error, reasons["d_F"] = None, str(error), NO_POWER_LAW
    except ParameterError as error:
        fit, fit_error = None, str(error)
        reasons["d_F"] = TOO_FEW_WAVEVECTORS if error.name == "k_range" else f"no fit of Eq. 28: {error}"
    lap("fit")
    sizes, radius = hole_radii(field, (dx, dy), connectivity)
    lap("holes")
    values = dict(d_F=math.nan, d_F_error=math.nan, xi=math.nan, xi_error=math.nan, constant=math.nan,
                  ell=math.nan, fitted=np.full(k.shape, math.nan), fit_range=(math.nan, math.nan))
    if fit is None:
        reasons.update({key: NO_FIT for key in ("d_F_error", "xi", "xi_error", "constant", "ell", "fit_range")})
    else:
        values = dict(d_F=fit.d_F, d_F_error=fit.d_F_error, xi=fit.xi, xi_error=fit.xi_error, constant=fit.constant,
                      ell=fit.ell, fitted=fit.model(k), fit_range=fit.fit_range)
        if not math.isfinite(fit.ell):
            reasons["ell"] = ELL_DROPS_OUT
    if not sizes.size:
        reasons["mean_hole_radius_w"] = NO_HOLES
    elif np.isinf(radius).any():
        reasons["mean_hole_radius_w"] = HOLES_PERCOLATE
    return FractalAnalysis(phi=phi, spacing=(dx, dy), shape=(nx, ny), k=k, intensity=intensity,
                           holes=int(sizes.size), mean_hole_radius_w=weighted_hole_radius(sizes, radius),
                           fit_error=fit_error, reasons=reasons, **values)


# ---------------------------------------------------------------- a fractal of known dimension

_SUBSQUARES = np.array([(i, j) for i in (-1, 0, 1) for j in (-1, 0, 1)], dtype=float)


def run(state, clock: Clock, load: str, seed: int) -> AnalysisReport:
    """The :class:`FractalAnalysis` of ``state`` at the default grid; ``load`` and ``seed`` are not used."""
    result = fractal_analysis(state.positions, state.radii, state.box_lengths, lap=clock.lap)
    return AnalysisReport("fractal", result.as_dict(), result, reasons=result.reasons,
                          figures=("structure",) if 0.0 < result.phi < 1.0 else ())


def curdled_blob(kept: int, generations: int, rng: np.random.Generator) -> np.ndarray:
    """Centres ``(kept^generations, 2)`` of Mandelbrot's random curdling, turned at random: a square
    of side ``3^generations`` (centred on 0) is cut into 3 × 3, ``kept`` of the nine squares,
    chosen at random, are kept and the pattern is turned about the centre by a random angle, and
    so on in every kept square down to squares of side 1, whose centres are returned. Its mass
    dimension is ``log(kept) / log 3`` between 1 and ``3^generations``."""
    whole("kept", kept, 1, 9)
    if not isinstance(generations, (int, np.integer)) or generations < 1 or kept ** generations > 10 ** 7:
        raise ParameterError("generations", generations, "a whole number >= 1 with kept^generations <= 1e7")
    centres = np.zeros((1, 2))
    size = 3.0 ** generations
    for _ in range(generations):
        size /= 3.0
        offsets = _SUBSQUARES[np.argsort(rng.random((len(centres), 9)), axis=1)[:, :kept]]
        angle = rng.uniform(0.0, 2.0 * math.pi, len(centres))
        cos, sin = np.cos(angle)[:, None], np.sin(angle)[:, None]
        turned = np.stack([cos * offsets[..., 0] - sin * offsets[..., 1],
                           sin * offsets[..., 0] + cos * offsets[..., 1]], axis=-1)
        centres = (centres[:, None, :] + size * turned).reshape(-1, 2)
    return centres


def curdled_packing(count: int, box_lengths, kept: int = 7, generations: int = 3, diameters=(0.5, 1.0),
                    seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``count`` disks ``(positions, radii)`` in blobs of :func:`curdled_blob` (unit squares: the
    largest diameter), each blob centred uniformly at random in the periodic box (blobs may overlap;
    the last one is cut to ``count``); diameters uniform in ``diameters`` (Gilabert's ``[a/2, a]``
    with ``a = 1`` by default). A synthetic aggregate of fractal dimension ``log(kept) / log 3`` up
    to the blob size ``3^generations``."""
    if not isinstance(count, (int, np.integer)) or count < 1:
        raise ParameterError("count", count, "a whole number >= 1")
    lengths = np.array(_box(box_lengths))
    low, high = (float(d) for d in diameters)
    if not 0.0 < low <= high:
        raise ParameterError("diameters", tuple(diameters), "(smallest, largest) with 0 < smallest <= largest")
    rng = np.random.default_rng(seed)
    blobs = -(-count // kept ** generations)
    positions = np.vstack([high * curdled_blob(kept, generations, rng) + rng.uniform(0.0, 1.0, 2) * lengths
                           for _ in range(blobs)])[:count]
    return np.mod(positions, lengths), 0.5 * rng.uniform(low, high, count)


def _positive(name: str, value) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ParameterError(name, value, "a positive number") from None
    if not (value > 0.0 and math.isfinite(value)):
        raise ParameterError(name, value, "a positive finite number")
    return value


def _box(box_lengths) -> tuple[float, float]:
    try:
        lengths = np.asarray(box_lengths, dtype=float).ravel()
    except (TypeError, ValueError):
        lengths = np.zeros(0)
    if lengths.shape != (2,) or not np.all(np.isfinite(lengths)) or not np.all(lengths > 0.0):
        raise ParameterError("box_lengths", box_lengths, "two positive finite lengths (L_x, L_y) of the periodic box")
    return float(lengths[0]), float(lengths[1])


def _disks(positions, radii) -> tuple[np.ndarray, np.ndarray]:
    positions = np.ascontiguousarray(positions, dtype=np.float64)
    radii = np.ascontiguousarray(radii, dtype=np.float64)
    if radii.ndim != 1 or radii.size == 0:
        raise ParameterError("radii", f"shape {radii.shape}", "at least one disk: a 1D array of radii")
    if positions.shape != (radii.size, 2):
        raise ParameterError("positions", f"shape {positions.shape}", f"(N, 2) with N = {radii.size} (one per radius)")
    if not (np.all(np.isfinite(positions)) and np.all(np.isfinite(radii)) and np.all(radii > 0.0)):
        raise ParameterError("radii", "non-finite or non-positive values", "finite positions and positive radii")
    return positions, radii
