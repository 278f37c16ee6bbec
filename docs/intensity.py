"""I(k) of method-2 series beside Eq. 28 with the paper's d_F and xi (docs/gilabert.md).

    python docs/intensity.py DIR [DIR ...] [--label TEXT ...] [--out docs/images/gilabert-intensity.png]

Each DIR is a folder of ``granlab reproduce gilabert-method2 --out DIR``. For each, at P* = 0 and
at P* = 0.01 and for its cases with rolling resistance: the samples' I(k) averaged (periodic
transform), Eq. 28 fitted freely (GranLab's reading), Eq. 28 with Table VII's xi held (d_F, ell,
Cst fitted), and with its d_F and xi held (ell and Cst fitted). Prints each fit's RMS residual of
log I over the bins up to 2 pi / a, and draws the first and the last.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import scipy.optimize
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import NullFormatter

from granlab.engine.analysis.fractal import FIT_K_MAX, average_intensity, fit_structure, structure_model
from granlab.engine.reproduce import TABLE_VII

STAGES = (("_0", "P* = 0", 0), ("", "P* = 0.01", 1))
"""Key suffix, label and Table VII column offset (with RR: columns 2 and 3)."""


def held_xi_fit(k, intensity, phi, xi, d_F=None):
    """Eq. 28 with ``xi`` held (and ``d_F`` if given): the rest (d_F, ell, Cst) fitted on log I.
    Returns (d_F, ell, Cst, rms)."""

    def residual(p):
        model = structure_model(k, phi, d_F if d_F is not None else p[2], xi, math.exp(p[0]), p[1])
        return np.log(np.maximum(model, 1e-300)) - np.log(intensity)

    start = [math.log(0.1), 0.0] + ([] if d_F is not None else [1.6])
    best = scipy.optimize.least_squares(residual, start, method="lm")
    fitted = d_F if d_F is not None else float(best.x[2])
    return fitted, math.exp(best.x[0]), best.x[1], float(np.sqrt(np.mean(best.fun ** 2)))


def series(folder: Path, suffix: str):
    rows = [json.loads(path.read_text()) for path in sorted((folder / "samples").glob("*RR-seed*.json"))]
    rows = [r for r in rows if r.get("rolling") and r.get("error") is None and r.get("k" + suffix)]
    k, intensity = average_intensity([r["k" + suffix] for r in rows], [r["intensity" + suffix] for r in rows])
    phi = float(np.mean([r["grid_phi" + suffix] for r in rows]))
    keep = k <= FIT_K_MAX
    return k[keep], intensity[keep], phi, len(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", nargs="+", type=Path)
    parser.add_argument("--label", nargs="+", help="one label per folder (default: its name)")
    parser.add_argument("--out", type=Path, default=Path("docs/images/gilabert-intensity.png"))
    args = parser.parse_args()
    labels = args.label or [folder.name for folder in args.folders]
    figure = Figure(figsize=(10, 4.2), dpi=100)
    FigureCanvasAgg(figure)
    axes = figure.subplots(1, 2, sharey=True)
    colours = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd")
    for (suffix, stage, offset), ax in zip(STAGES, axes):
        d_F, xi = TABLE_VII["d_F"][2 + offset].value, TABLE_VII["xi"][2 + offset].value
        for folder, label, colour in zip(args.folders, labels, colours):
            k, intensity, phi, n = series(folder, suffix)
            free = fit_structure(k, intensity, phi, diameter=1.0)
            free_rms = float(np.sqrt(np.mean((np.log(free.model(k)) - np.log(intensity)) ** 2)))
            _, ell, constant, paper_rms = held_xi_fit(k, intensity, phi, xi, d_F)
            xi_only_d_F, _, _, xi_only_rms = held_xi_fit(k, intensity, phi, xi)
            print(f"{label}, {stage}, {n} samples: free fit d_F {free.d_F:.3f}, xi {free.xi:.2f} a, RMS log I "
                  f"{free_rms:.3f}; paper's xi {xi} a held: d_F {xi_only_d_F:.3f}, RMS {xi_only_rms:.3f}; paper's "
                  f"d_F {d_F} and xi held: ell {ell:.3g} a, Cst {constant:.3g}, RMS {paper_rms:.3f}")
            ax.loglog(k, intensity, "o", color=colour, markersize=4, label=f"{label} (n = {n})")
            ax.loglog(k, free.model(k), "-", color=colour, linewidth=1,
                      label=f"Eq. 28 fitted: d_F {free.d_F:.2f}, ξ {free.xi:.1f} a")
            ax.loglog(k, structure_model(k, phi, d_F, xi, ell, constant), "--", color=colour, linewidth=1,
                      label=f"Eq. 28, paper's d_F {d_F}, ξ {xi} a, amplitude fitted")
        ax.axvline(1.0 / xi, color="grey", linestyle=":", linewidth=1, label="k = 1/ξ of the paper")
        ax.set(xlabel="k (1/a)", title=f"with RR, {stage}", xlim=(0.08, 8.0))
        ax.set_xticks([0.1, 0.2, 0.5, 1, 2, 5], ["0.1", "0.2", "0.5", "1", "2", "5"])
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.legend(fontsize=7)
    axes[0].set_ylabel("I(k) (a²)")
    figure.tight_layout()
    figure.savefig(args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
