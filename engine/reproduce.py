"""Reproducing Gilabert, Roux & Castellanos, Phys. Rev. E 75, 011303 (2007): packings of model
cohesive powders prepared by methods 1 and 2, measured and set beside the published values.

- ``gilabert-method1`` (Sec. III A, Tables II and III): a gas at ``Phi_I = 0.36`` compressed at
  once by the isotropic pressure; cohesionless (``P / K_N = 1e-5``: ``kappa = K_N / P = 1e5``) and
  cohesive (``P* = P a / F0 = 0.01``, ``kappa = K_N a / F0 = 1e5``), ``mu = 0.15`` and ``0.5``, with
  and without rolling resistance (RR: ``mu_r = 1e-2 mu a``, Table I). Measured: ``Phi`` and ``z``.
- ``gilabert-method2`` (Sec. III B, series A: ``Phi_I = 0.36``, ``kappa = 1e5``, ``mu = 0.5``,
  ``V0 = 9.48 V*``, strain rate at most ``0.05 / T0``), without and with RR: ``Phi`` and ``z`` at
  ``P* = 0`` (Table IV) and ``P* = 0.01`` (Table V), ``d_F`` and ``xi`` of the fit of Eq. 28
  (Table VII) and the mean hole radius ``<R>_w`` at ``P* = 0.01`` (Sec. V D).

``z`` is Gilabert's: the mean number of interactions per disk, rattlers included (``2 M / N``).
Without cohesion an interaction is a contact carrying at least ``1e-4 P a`` (Sec. III A, as in
:func:`granlab.engine.analysis.packing.packing_stats`); with cohesion every contact and distant attraction
counts, those carrying no force included (Sec. IV A: a quarter of the contacts at ``P* = 0``).

Units: the largest diameter ``a``, the mass of a disk of diameter ``a`` and ``F0`` (cohesive) or
``P a`` (cohesionless), so ``T0 = sqrt(m a / F0) = 1``. Samples run in parallel on Dask
(:func:`granlab.engine.studies.run_tasks`), one thread each; a sample's numbers depend on its seed only.

A reproduction given a folder writes its settings there and each sample as it finishes
(``settings.json``, ``samples/KEY.json``); run again on that folder it runs only the samples not
yet there, so a reproduction of hours survives an interruption. With method 2, ``d_F`` and ``xi``
are also fitted to ``I(k)`` averaged over the samples of a case, as Gilabert does (Sec. V), and
the folders of several sizes can be summarised as one series (:func:`summarize_series`).
"""

from __future__ import annotations

import json
import math
import os
import time
import traceback
from dataclasses import asdict, dataclass
from pathlib import Path

from .errors import GranLabError, ParameterError
from .params import GILABERT_DT_SAFETY, STUDY_LIMITS, check_cell_mass_reading, fraction, nonnegative, whole

PHI_I = 0.36
"""Solid fraction of the initial gas (the I-state; Tables II-V use ``Phi_I = 0.3631 ± 0.0006``)."""
P_STAR = 0.01
"""Reduced pressure ``P* = P a / F0`` of the cohesive samples (and ``P / K_N = 1e-5`` without cohesion)."""
KAPPA = 1e5
"""Stiffness parameter (Table I): ``K_N a / F0``, or ``K_N / P`` without cohesion."""
SPEED = 9.48
"""Method 2: ``V0 = 9.48 V*``, ``V* = sqrt(F0 D0)`` (Sec. III B 1, Eq. 7)."""
MAX_STRAIN_RATE = 0.05
"""Method 2: the strain rate is capped at ``0.05 / T0`` (Sec. III B 1)."""


@dataclass(frozen=True)
class Published:
    """A published value with its error bar, and where it is printed."""

    value: float
    error: float
    source: str


def _row(source: str, *numbers: float) -> tuple[Published, ...]:
    """``(value, error, value, error, ...)`` of a printed row."""
    return tuple(Published(v, e, source) for v, e in zip(numbers[::2], numbers[1::2]))


# Tables II and III: rows are Phi_I, columns (no RR mu 0.15, no RR mu 0.5, RR mu 0.15, RR mu 0.5);
# the error bars are standard deviations over the samples (Sec. III A).
METHOD1_COLUMNS = ((0.15, False), (0.5, False), (0.15, True), (0.5, True))
TABLE_II = {
    "phi": {"0.130 ± 0.001": _row("Table II", 0.8262, 0.0007, 0.811, 0.001, 0.8238, 0.0014, 0.803, 0.002),
            "0.3631 ± 0.0006": _row("Table II", 0.8256, 0.0005, 0.811, 0.001, 0.8231, 0.0013, 0.805, 0.002),
            "0.5244 ± 0.0012": _row("Table II", 0.8236, 0.0007, 0.8092, 0.0005, 0.8215, 0.0005, 0.803, 0.011)},
    "z": {"0.130 ± 0.001": _row("Table II", 3.174, 0.012, 2.607, 0.022, 3.160, 0.024, 2.526, 0.021),
          "0.3631 ± 0.0006": _row("Table II", 3.187, 0.025, 2.65, 0.02, 3.123, 0.013, 2.475, 0.025),
          "0.5244 ± 0.0012": _row("Table II", 3.181, 0.015, 2.63, 0.02, 3.15, 0.03, 2.52, 0.02)},
}
TABLE_III = {
    "phi": {"0.130 ± 0.001": _row("Table III", 0.7635, 0.0023, 0.751, 0.001, 0.757, 0.002, 0.709, 0.001),
            "0.3631 ± 0.0006": _row("Table III", 0.727, 0.001, 0.7232, 0.0012, 0.710, 0.002, 0.688, 0.001),
            "0.5244 ± 0.0012": _row("Table III", 0.737, 0.002, 0.733, 0.002, 0.7248, 0.0002, 0.733, 0.002)},
    "z": {"0.130 ± 0.001": _row("Table III", 3.563, 0.005, 3.163, 0.004, 3.189, 0.008, 3.059, 0.003),
          "0.3631 ± 0.0006": _row("Table III", 3.345, 0.009, 3.103, 0.006, 3.253, 0.003, 2.971, 0.006),
          "0.5244 ± 0.0012": _row("Table III", 3.189, 0.008, 3.059, 0.003, 3.096, 0.002, 2.851, 0.001)},
}
# Tables IV (P* = 0) and V (P* = 0.01), mu = 0.5: rows are the series with their Phi_I, columns
# (no RR Phi, no RR z, RR Phi, RR z). Series B has kappa = 1e4, the others kappa = 1e5.
TABLE_IV = {
    "A0 (Phi_I = 0.1301 ± 0.0003)": _row("Table IV", 0.1303, 0.0003, 3.197, 0.002, 0.1304, 0.0003, 2.656, 0.007),
    "B (Phi_I = 0.2649 ± 0.0006)": _row("Table IV", 0.265, 0.001, 3.123, 0.004, 0.2652, 0.023, 2.963, 0.006),
    "A (Phi_I = 0.361 ± 0.007)": _row("Table IV", 0.3616, 0.0003, 3.1407, 0.0016, 0.361, 0.009, 2.660, 0.004),
}
TABLE_V = {
    "B (Phi_I = 0.2649 ± 0.0006)": _row("Table V", 0.448, 0.006, 3.235, 0.003, 0.42, 0.01, 3.085, 0.005),
    "A (Phi_I = 0.361 ± 0.007)": _row("Table V", 0.472, 0.008, 3.175, 0.003, 0.524, 0.008, 2.973, 0.004),
}
# Table VII (series A): columns (no RR P* = 0, no RR P* = 0.01, RR P* = 0, RR P* = 0.01); xi in units of a.
TABLE_VII = {
    "d_F": _row("Table VII", 1.925, 0.024, 1.93, 0.04, 1.53, 0.04, 1.51, 0.04),
    "xi": _row("Table VII", 8.29, 0.15, 6.07, 0.2, 9.3, 0.4, 5.06, 0.21),
}
# Sec. V D: <R>_w / a at P* = 0.01 (no RR, RR).
HOLE_RADIUS = _row("Sec. V D", 6.6, 0.2, 5.47, 0.14)


@dataclass(frozen=True)
class Case:
    """One column of a table: the contact law of one set of samples."""

    cohesive: bool
    friction: float
    rolling: bool

    @property
    def label(self) -> str:
        return (f"{'cohesive' if self.cohesive else 'cohesionless'}, mu = {self.friction:g}, "
                f"{'RR' if self.rolling else 'no RR'}")


def method1_cases() -> tuple[Case, ...]:
    return tuple(Case(cohesive, mu, rolling) for cohesive in (False, True) for mu, rolling in METHOD1_COLUMNS)


def method2_cases() -> tuple[Case, ...]:
    return (Case(True, 0.5, False), Case(True, 0.5, True))


def published(name: str, case: Case) -> dict[str, Published]:
    """The published values of ``case`` in reproduction ``name`` (``Phi_I = 0.36``, series A)."""
    if name == "gilabert-method1":
        table = TABLE_III if case.cohesive else TABLE_II
        column = METHOD1_COLUMNS.index((case.friction, case.rolling))
        return {q: table[q]["0.3631 ± 0.0006"][column] for q in ("phi", "z")}
    rr = 1 if case.rolling else 0
    at_zero = TABLE_IV["A (Phi_I = 0.361 ± 0.007)"]
    at_p = TABLE_V["A (Phi_I = 0.361 ± 0.007)"]
    values = {"phi_0": at_zero[2 * rr], "z_0": at_zero[2 * rr + 1], "phi": at_p[2 * rr], "z": at_p[2 * rr + 1],
              "d_F_0": TABLE_VII["d_F"][2 * rr], "xi_0": TABLE_VII["xi"][2 * rr],
              "d_F": TABLE_VII["d_F"][2 * rr + 1], "xi": TABLE_VII["xi"][2 * rr + 1],
              "hole_radius_w": HOLE_RADIUS[rr], "hole_radius_w8": HOLE_RADIUS[rr]}
    for suffix in ("_0", ""):
        values["k0" + suffix] = _published_k0(values["phi" + suffix], values["xi" + suffix], values["d_F" + suffix])
    return values


def _published_k0(phi: Published, xi: Published, d_F: Published) -> Published:
    """``k0 = Phi (xi/a)^(2 - d_F)`` of published values, its error propagated from theirs (independent)."""
    from .analysis.fractal import small_scale_amplitude

    k0 = small_scale_amplitude(phi.value, xi.value, d_F.value)
    relative = math.hypot(phi.error / phi.value, (2.0 - d_F.value) * xi.error / xi.value,
                          math.log(xi.value) * d_F.error)
    return Published(round(k0, 3), round(k0 * relative, 3), f"{phi.source}, {xi.source}: Phi (xi/a)^(2 - d_F)")


REPRODUCTIONS = {"gilabert-method1": method1_cases, "gilabert-method2": method2_cases}
PAPER_SIZE = {"gilabert-method1": (1400, 4), "gilabert-method2": (1400, 4)}
"""Disks and samples per case at the paper's size: ``N = 1400`` (Sec. III A); method 2's series A
is four samples of 1400 disks (and three of 5600, Sec. III B 2). The paper does not say how many
samples each set of method 1 holds: four as well."""
QUANTITIES = {
    "gilabert-method1": ("phi", "z"),
    "gilabert-method2": ("phi_0", "z_0", "d_F_0", "xi_0", "k0_0", "phi", "z", "d_F", "xi", "k0", "hole_radius_w",
                         "hole_radius_w8"),
}


ROLLING_CASES = {"both": (False, True), "RR": (True,), "noRR": (False,)}
"""The cases a reproduction runs, by whether they have rolling resistance."""

MAX_STAGE_TIME = 1e5
"""The longest preparation stage a reproduction runs, in T0 (200 times the default)."""


@dataclass(frozen=True)
class Reproduction:
    """The settings of one reproduction: ``samples`` of ``particles`` disks for every case, with
    seeds ``first_seed, first_seed + 1, ...``; ``max_time`` (simulated time in ``T0``, the force
    unit being ``F0`` also without cohesion, where ``P = 0.01``) bounds each stage: a sample still
    out of equilibrium then is measured as it is and counted as not equilibrated.
    ``rolling_damping_ratio`` is the damping ratio of a viscous rolling moment in the cases with RR
    (:func:`granlab.engine.protocols.prepare.gilabert_law`). The paper has none; with 0, a disk hanging by
    one contact swings on its rolling spring for ever and the samples never meet the force
    criterion. ``cell_mass_disks``: the cell's generalized mass ``M`` (Eq. 3) is the paper's for a
    sample of that many disks (default 1400, the paper's size; see
    :func:`granlab.engine.protocols.prepare.cell_mass`), so that every size compacts at the paper's rate;
    ``cell_mass`` is the reading of ``M`` (``mass``, 3/10 of the grain mass, or ``per-length``, that
    over the cell size: :data:`granlab.engine.protocols.prepare.CELL_MASS_READINGS`). ``rolling``
    keeps the cases with rolling resistance (``RR``), those without (``noRR``) or ``both``: a sweep of
    the rolling damping needs the RR samples only, and without RR a 1400-disk sample of method 2
    takes three times as long. ``threads_per_sample``: the threads each sample runs on (the local
    cluster then has a worker per that many cores); a sample of 1000 disks or more on two threads
    is another sample than on one (its forces are summed in two parts), so the count is a setting
    of the reproduction, kept in its folder. ``dt_safety``: the time step as a fraction of the
    stability bound (:data:`granlab.engine.protocols.prepare.GILABERT_DT_SAFETY`; folders made
    before it, 27 Nov 2026, ran at 0.3)."""

    name: str
    particles: int = 100
    samples: int = 2
    first_seed: int = 0
    max_time: float = 500.0
    rolling_damping_ratio: float = 0.8
    cell_mass_disks: int = 1400
    cell_mass: str = "mass"
    rolling: str = "both"
    threads_per_sample: int = 1
    dt_safety: float = GILABERT_DT_SAFETY

    def __post_init__(self):
        import numba

        if self.name not in REPRODUCTIONS:
            raise ParameterError("table", self.name, "one of " + ", ".join(REPRODUCTIONS))
        for key, least, most in (("particles", 2, STUDY_LIMITS["particles"]), ("samples", 1, STUDY_LIMITS["samples"]),
                                 ("cell_mass_disks", 1, STUDY_LIMITS["particles"]),
                                 ("threads_per_sample", 1, numba.config.NUMBA_NUM_THREADS)):
            whole(key, getattr(self, key), least, most)
        if not 0 < self.max_time <= MAX_STAGE_TIME:
            raise ParameterError("max_time", self.max_time, f"a duration > 0 and at most {MAX_STAGE_TIME:g} T0 (each "
                                                            f"stage of a sample would otherwise run for days)")
        nonnegative("rolling_damping_ratio", self.rolling_damping_ratio)
        fraction("dt_safety", self.dt_safety, "the stability bound")
        check_cell_mass_reading(self.cell_mass)
        if self.rolling not in ROLLING_CASES:
            raise ParameterError("rolling", self.rolling, "one of " + ", ".join(ROLLING_CASES))

    @property
    def cases(self) -> tuple[Case, ...]:
        return tuple(case for case in REPRODUCTIONS[self.name]() if case.rolling in ROLLING_CASES[self.rolling])


def coordination(snapshot, cohesive: bool, force_scale: float) -> float:
    """Gilabert's ``z`` (see the module docstring)."""
    from .analysis.packing import packing_stats
    from .observables import coordination as observed_coordination

    if not cohesive:
        return packing_stats(snapshot, force_scale).z
    c = snapshot.contacts
    return observed_coordination(c.status, c.i, c.j, snapshot.positions.shape[0], distant=True)


def _fractal(snapshot, prefix: str) -> dict:
    """The fractal analysis of ``snapshot`` under the default conventions (4-connected holes, the periodic
    transform) and the other ones (8-connected holes: ``hole_radius_w8``; a Hann window: I(k) and its
    fit under ``..._hann``), for the docs' comparison of conventions (the paper names none)."""
    from .analysis.fractal import fractal_analysis, small_scale_amplitude

    values = {}
    for tag, connectivity, transform in (("", 4, "periodic"), ("_hann", 8, "hann")):
        try:
            result = fractal_analysis(snapshot.positions, snapshot.radii, snapshot.box_lengths,
                                      connectivity=connectivity, transform=transform)
        except GranLabError as error:  # a grid that cannot be made leaves the other measurements standing
            values.update({f"d_F{tag}{prefix}": None, f"xi{tag}{prefix}": None,
                           f"fractal_error{tag}{prefix}": str(error)})
            continue
        if result.fit_error:
            values.update({f"d_F{tag}{prefix}": None, f"xi{tag}{prefix}": None,
                           f"fractal_error{tag}{prefix}": result.fit_error})
        else:
            values.update({f"d_F{tag}{prefix}": result.d_F, f"xi{tag}{prefix}": result.xi,
                           f"k0{tag}{prefix}": small_scale_amplitude(
                               result.phi, result.xi / (2.0 * float(snapshot.radii.max())), result.d_F)})
        values.update({f"k{tag}{prefix}": result.k.tolist(), f"intensity{tag}{prefix}": result.intensity.tolist(),
                       f"grid_phi{tag}{prefix}": result.phi})
        if prefix == "":  # the holes do not depend on the fit
            name = "hole_radius_w" if connectivity == 4 else "hole_radius_w8"
            values[name] = result.mean_hole_radius_w if math.isfinite(result.mean_hole_radius_w) else None
    return values


def gilabert_sample(reproduction: Reproduction, case: Case, seed: int) -> dict:
    """Prepare and measure one sample on ``reproduction.threads_per_sample`` threads; failures are
    returned, not raised."""
    import numba

    from .analysis.packing import packing_stats
    from .protocols.equilibrium import equilibrium
    from .protocols.prepare import gilabert_law, method1, method2

    start = time.perf_counter()
    row = {"case": case.label, **asdict(case), "seed": seed}
    threads = numba.get_num_threads()
    numba.set_num_threads(reproduction.threads_per_sample)
    try:
        law = gilabert_law(friction=case.friction, kappa=KAPPA, cohesion=case.cohesive, rolling=case.rolling,
                           pressure=P_STAR, rolling_damping_ratio=reproduction.rolling_damping_ratio)
        if reproduction.name == "gilabert-method1":
            prepared = method1(reproduction.particles, PHI_I, P_STAR, law, seed=seed, max_time=reproduction.max_time,
                               cell_mass_disks=reproduction.cell_mass_disks, cell_mass_reading=reproduction.cell_mass,
                               dt_safety=reproduction.dt_safety)
        else:
            def at_zero_pressure(stage, sim):
                if stage == "relaxation":
                    snapshot = sim.snapshot()
                    report = equilibrium(sim, 0.0)
                    row.update(phi_0=packing_stats(snapshot, report.force_scale).phi,
                               z_0=coordination(snapshot, True, report.force_scale),
                               balanced_0=bool(max(report.force, report.moment, report.pressure) < 1.0),
                               **_fractal(snapshot, "_0"))

            prepared = method2(reproduction.particles, PHI_I, P_STAR, law, speed=SPEED * math.sqrt(
                law.cohesion_force * law.cohesion_range), seed=seed, max_strain_rate=MAX_STRAIN_RATE,
                on_stage=at_zero_pressure, max_time=reproduction.max_time, cell_mass_disks=reproduction.cell_mass_disks,
                cell_mass_reading=reproduction.cell_mass, dt_safety=reproduction.dt_safety)
        snapshot = prepared.sim.snapshot()
        stats = packing_stats(snapshot, prepared.report.force_scale)
        row.update(phi=stats.phi, z=coordination(snapshot, case.cohesive, prepared.report.force_scale),
                   z_star=stats.z_star, rattlers=stats.rattlers, equilibrated=prepared.equilibrated,
                   sim_time=prepared.sim_time, error=None)
        if reproduction.name == "gilabert-method2":
            row.update(_fractal(snapshot, ""))
    except Exception as error:  # reported per sample: the others go on
        row.update(error=f"{type(error).__name__}: {error}", traceback=traceback.format_exc(limit=3))
    finally:
        numba.set_num_threads(threads)
    row["wall_time_s"] = time.perf_counter() - start
    return row


def summarize(reproduction: Reproduction, rows: list[dict]) -> dict:
    """Per case and quantity: mean, standard deviation and standard error over the samples that
    gave it, beside the published value."""
    import numpy as np

    cases = []
    for case in reproduction.cases:
        done = sorted((r for r in rows if r["case"] == case.label and r["error"] is None), key=lambda r: r["seed"])
        reference = published(reproduction.name, case)
        quantities = {}
        for quantity in QUANTITIES[reproduction.name]:
            values = np.array([r[quantity] for r in done if r.get(quantity) is not None], dtype=float)
            std = float(values.std(ddof=1)) if values.size > 1 else None
            quantities[quantity] = {
                "mean": float(values.mean()) if values.size else None, "std": std,
                "sem": std / math.sqrt(values.size) if std is not None else None, "n": int(values.size),
                "published": asdict(reference[quantity])}
        cases.append({"case": case.label, **asdict(case), "completed": len(done),
                      "equilibrated": sum(1 for r in done if r["equilibrated"]), "quantities": quantities,
                      "mean_wall_time_s": float(np.mean([r["wall_time_s"] for r in done])) if done else None})
        if reproduction.name == "gilabert-method2":
            cases[-1]["balanced_at_zero_pressure"] = sum(1 for r in done if r.get("balanced_0"))
            cases[-1]["averaged_fit"] = {"at_zero_pressure": averaged_fit(done, "_0"), "under_pressure":
                                         averaged_fit(done, ""),
                                         "at_zero_pressure, Hann window": averaged_fit(done, "_hann_0"),
                                         "under_pressure, Hann window": averaged_fit(done, "_hann")}
    failed = [{"case": r["case"], "seed": r["seed"], "error": r["error"]} for r in rows if r["error"]]
    return {"reproduction": reproduction.name, "settings": asdict(reproduction), "cases": cases,
            "samples": sorted(rows, key=lambda r: (r["case"], r["seed"])), "failed": failed}


def averaged_fit(rows: list[dict], prefix: str) -> dict:
    """Eq. 28 fitted to ``I(k)`` averaged over the samples of ``rows`` (``prefix`` "_0": at
    ``P* = 0``), with the samples' mean grid solid fraction, in units of the diameter ``a = 1``.
    Rows of a series (:func:`summarize_series`) carry their ``particles``: each size is averaged
    on its own bins, the larger boxes alone below the smaller ones' (see
    :func:`granlab.engine.analysis.fractal.average_series_intensity`)."""
    import numpy as np

    from .analysis.fractal import FitError, average_series_intensity, fit_structure, small_scale_amplitude

    have = [r for r in rows if r.get(f"k{prefix}")]
    fit = {"samples": len(have), "d_F": None, "d_F_error": None, "xi": None, "xi_error": None, "k0": None,
           "error": None}
    if not have:
        fit["error"] = "no sample's I(k)"
        return fit
    sizes = sorted({r.get("particles") for r in have}, key=str)
    groups = [[r for r in have if r.get("particles") == size] for size in sizes]
    try:
        k, intensity = average_series_intensity([([r[f"k{prefix}"] for r in group],
                                                  [r[f"intensity{prefix}"] for r in group]) for group in groups])
        phi = float(np.mean([r[f"grid_phi{prefix}"] for r in have]))
        result = fit_structure(k, intensity, phi, diameter=1.0)
    except (FitError, ParameterError) as error:
        fit["error"] = str(error)
        return fit
    fit.update(d_F=result.d_F, d_F_error=result.d_F_error, xi=result.xi, xi_error=result.xi_error,
               k0=small_scale_amplitude(phi, result.xi, result.d_F))
    return fit


SERIES_MAY_DIFFER = ("particles", "samples", "first_seed", "cell_mass_disks")
"""Settings in which the folders of one series may differ: its sizes and seeds."""


def summarize_series(table: str, folders) -> dict:
    """The finished samples of several reproduction folders of ``table``, summarised as one series
    (Gilabert's Table VII: 4 samples of 1400 disks and 2 of 5600 in one fit). Nothing is run. The
    folders may differ only in :data:`SERIES_MAY_DIFFER`."""
    if len({Path(folder).resolve() for folder in folders}) < len(folders):
        raise GranLabError(f"a folder is named twice in --series {' '.join(map(str, folders))}: each once")
    reproductions = [resume_folder(folder) for folder in folders]
    first = reproductions[0]
    rows, series = [], []
    for folder, reproduction in zip(folders, reproductions):
        if reproduction.name != table:
            raise GranLabError(f"{folder} holds {reproduction.name}, not {table}")
        differ = [key for key, value in asdict(reproduction).items()
                  if key not in SERIES_MAY_DIFFER and value != getattr(first, key)]
        if differ:
            raise GranLabError(f"{folder} differs from {folders[0]} in {', '.join(differ)}: a series may differ "
                               f"only in {', '.join(SERIES_MAY_DIFFER)}")
        done = list(finished_samples(folder).values())
        rows += [{**row, "particles": reproduction.particles} for row in done]
        series.append({"folder": str(folder), "particles": reproduction.particles, "samples": len(done)})
    if not rows:
        raise GranLabError(f"no finished sample in {', '.join(map(str, folders))}")
    summary = summarize(first, rows)
    summary["series"] = series
    return summary


def sample_key(case: Case, seed: int) -> str:
    """A sample's name, fit for a file name: ``cohesive-mu0.5-RR-seed3``."""
    return (f"{'cohesive' if case.cohesive else 'cohesionless'}-mu{case.friction:g}-"
            f"{'RR' if case.rolling else 'noRR'}-seed{seed}")


SETTINGS_FILE = "settings.json"
SAMPLES_FOLDER = "samples"


def _write_json(path: Path, data) -> None:
    """Write whole or not at all: an interruption leaves the previous file or none."""
    from .io.jsonsafe import jsonable

    partial = path.with_name(path.name + ".partial")
    partial.write_text(json.dumps(jsonable(data), indent=1))
    os.replace(partial, path)


def start_folder(folder, reproduction: Reproduction) -> Path:
    """A new folder for ``reproduction``'s samples, its settings written in it."""
    folder = Path(folder)
    if (folder / SETTINGS_FILE).exists():
        raise GranLabError(f"{folder} holds a reproduction already: continue it with --resume {folder}, "
                           "or give an empty folder")
    try:
        (folder / SAMPLES_FOLDER).mkdir(parents=True, exist_ok=True)
        _write_json(folder / SETTINGS_FILE, asdict(reproduction))
    except OSError as error:
        raise GranLabError(f"cannot write the reproduction's folder {folder}: {error}") from error
    return folder


def resume_folder(folder) -> Reproduction:
    """The settings of the reproduction in ``folder`` (see :func:`start_folder`)."""
    path = Path(folder) / SETTINGS_FILE
    if not path.is_file():
        raise GranLabError(f"{folder} holds no reproduction ({SETTINGS_FILE} is missing): start one there with "
                           f"--out {folder}")
    try:
        settings = json.loads(path.read_text())
        # folders made before the choice of reading (Nov 2026) used the per-length one, and before
        # the longer step (27 Nov 2026) 0.3 of the bound
        return Reproduction(**{"cell_mass": "per-length", "dt_safety": 0.3, **settings})
    except (OSError, ValueError, TypeError) as error:
        raise GranLabError(f"{path} is not the settings of a reproduction: {error}") from error


def finished_samples(folder) -> dict[str, dict]:
    """The samples of ``folder`` that finished with their measurements, by :func:`sample_key`. A
    failed sample, or a file that cannot be read, is not finished: it is run again."""
    finished = {}
    for path in sorted((Path(folder) / SAMPLES_FOLDER).glob("*.json")):
        try:
            row = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        if isinstance(row, dict) and row.get("error") is None:
            finished[path.stem] = row
    return finished


def _sample_writer(folder, reproduction: Reproduction):
    """``on_result`` of :func:`granlab.engine.studies.run_tasks` writing each sample into ``folder``."""
    samples = Path(folder) / SAMPLES_FOLDER

    def write(key: str, row: dict) -> None:
        _write_json(samples / f"{key.removeprefix(reproduction.name + '-')}.json", row)

    return write


def warm_up(report, threads: int = 1) -> None:
    """Compile (or load from the cache) every kernel a sample on ``threads`` threads needs, before the
    workers start: the time step and the analyses' kernels side by side in processes of their own,
    then a sample of 6 disks; ``report(text)`` says how far the compile is."""
    import io

    from .compilation import compile_sets, describe, step_sets
    from .protocols.prepare import gilabert_law, method1

    compile_sets([*step_sets(["cundall-strack"], threads > 1), "state", "packing", "fractal"], stream=io.StringIO(),
                 on_change=lambda state: report(describe(state)))
    law = gilabert_law(friction=0.5, cohesion=True, rolling=True, pressure=P_STAR)
    _fractal(method1(6, PHI_I, P_STAR, law, max_time=1.0).sim.snapshot(), "")


def run_reproduction(reproduction: Reproduction, scheduler: str | None = None, workers: int | None = None,
                     progress=None, folder=None) -> dict:
    """Every sample of every case on Dask (see :func:`granlab.engine.studies.run_tasks`), summarised.
    The cohesive cases with RR, the slowest, are submitted first. The local cluster has a worker per
    ``threads_per_sample`` cores unless ``workers`` says otherwise. With ``folder`` (made by
    :func:`start_folder`), each sample is written there as it finishes and the samples already
    there are not run again (``resumed`` counts them; ``wall_time_s`` is this call's)."""
    from .studies import run_tasks

    start = time.perf_counter()
    seeds = range(reproduction.first_seed, reproduction.first_seed + reproduction.samples)
    cases = sorted(reproduction.cases, key=lambda c: (not c.cohesive, not c.rolling))
    done = finished_samples(folder) if folder is not None else {}
    rows = [done[sample_key(case, seed)] for case in cases for seed in seeds if sample_key(case, seed) in done]
    tasks = [(reproduction, case, seed) for case in cases for seed in seeds if sample_key(case, seed) not in done]
    resumed = len(rows)
    keys = [f"{reproduction.name}-{sample_key(case, seed)}" for _, case, seed in tasks]
    if workers is None and scheduler is None:
        workers = max(1, (os.cpu_count() or 1) // reproduction.threads_per_sample)
    outcomes = run_tasks(gilabert_sample, tasks, keys, scheduler=scheduler, workers=workers,
                         warm_up=lambda report: warm_up(report, reproduction.threads_per_sample),
                         progress=progress, on_result=None if folder is None else _sample_writer(folder, reproduction)
                         ) if tasks else []
    for (_, case, seed), outcome in zip(tasks, outcomes):
        if isinstance(outcome, Exception):  # a lost worker
            outcome = {"case": case.label, **asdict(case), "seed": seed, "error": f"{type(outcome).__name__}: {outcome}"}
        rows.append(outcome)
    summary = summarize(reproduction, rows)
    summary["wall_time_s"] = time.perf_counter() - start
    summary["sample_wall_time_s"] = float(sum(r.get("wall_time_s", 0.0) for r in rows))
    summary["resumed"] = resumed
    summary["scheduler"] = scheduler or "local"
    summary["folder"] = None if folder is None else str(folder)
    return summary
