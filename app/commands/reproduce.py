"""``granlab reproduce {gilabert-method1,gilabert-method2} [options] [--json]``: Gilabert's preparation tables
measured on Dask beside the published values, each sample written to ``--out`` as it finishes."""

from __future__ import annotations

import os
import sys
from pathlib import Path

from granlab.engine import costs
from granlab.engine.errors import GranLabError, ParameterError
from granlab.engine.params import CELL_MASS_READINGS, GILABERT_DT_SAFETY
from granlab.engine.reproduce import REPRODUCTIONS, ROLLING_CASES

from .options import ROLLING_DAMPING_HELP, number, positive_int


_REPRODUCTION_OPTIONS = {"particles": "--particles", "samples": "--samples", "first_seed": "--seed",
                         "max_time": "--max-time", "rolling_damping_ratio": "--rolling-damping",
                         "cell_mass_disks": "--cell-mass-disks", "cell_mass": "--cell-mass",
                         "rolling": "--rolling", "threads_per_sample": "--threads-per-sample",
                         "dt_safety": "--dt-safety"}


def _reproduce(args) -> dict:
    from granlab.engine.reproduce import (PAPER_SIZE, Reproduction, finished_samples, resume_folder, run_reproduction,
                            start_folder, summarize_series)
    from granlab.engine.studies import STUDY_LIMITS, TextProgress

    given = {key: getattr(args, option[2:].replace("-", "_")) for key, option in _REPRODUCTION_OPTIONS.items()}
    given = {key: value for key, value in given.items() if value is not None}
    if args.series:
        options = [_REPRODUCTION_OPTIONS[key] for key in given] + (["--paper-size"] if args.paper_size else []) + \
            [f"--{name}" for name in ("workers", "scheduler") if getattr(args, name) is not None]
        if options:
            raise GranLabError(f"--series summarises the folders' samples as they are and runs nothing: "
                               f"drop {', '.join(options)}")
        return summarize_series(args.table, args.series)
    if args.workers is not None and args.workers > STUDY_LIMITS["workers"]:
        raise ParameterError("--workers", args.workers, f"from 1 to {STUDY_LIMITS['workers']} (a worker is a process "
                                                        f"of its own; this machine has {os.cpu_count()} cores)")
    if args.resume:
        reproduction = resume_folder(args.resume)
        if reproduction.name != args.table:
            raise GranLabError(f"{args.resume} holds {reproduction.name}, not {args.table}")
        if given or args.paper_size:
            options = [_REPRODUCTION_OPTIONS[key] for key in given] + (["--paper-size"] if args.paper_size else [])
            raise GranLabError(f"--resume {args.resume} continues with the settings it was started with: "
                               f"drop {', '.join(options)}")
        folder = Path(args.resume)
    else:
        if args.paper_size:
            particles, samples = PAPER_SIZE[args.table]
            given = {"particles": particles, "samples": samples, **given}
        reproduction = Reproduction(args.table, **given)
        costs.check_memory(reproduction.particles * (args.workers or os.cpu_count() or 1), "--particles on every worker")
        folder = None if args.out is None else start_folder(args.out, reproduction)
    try:
        result = run_reproduction(reproduction, scheduler=args.scheduler, workers=args.workers,
                                  progress=None if args.json else TextProgress(), folder=folder)
    except KeyboardInterrupt as stop:
        if folder is None:
            raise
        total = reproduction.samples * len(reproduction.cases)
        print(f"\ninterrupted: {len(finished_samples(folder))} of {total} samples are in {folder}; go on with "
              f"granlab reproduce {args.table} --resume {folder}", file=sys.stderr)
        raise SystemExit(getattr(stop, "exit_status", 130)) from None
    if result["failed"] and len(result["failed"]) == len(result["samples"]):
        first = result["failed"][0]
        raise GranLabError(f"every sample failed ({len(result['failed'])} of {len(result['failed'])}); seed "
                           f"{first['seed']} ({first['case']}): {first['error']}")
    return result


def _print_reproduce(result: dict) -> None:
    settings = result["settings"]
    if "series" in result:
        print(f"{result['reproduction']}, one series of "
              + " + ".join(f"{s['folder']} ({s['samples']} samples of {s['particles']} disks in all cases)"
                         for s in result["series"])
              + f", cell mass M: {settings['cell_mass']} reading")
    else:
        print(f"{result['reproduction']}: {settings['samples']} samples of {settings['particles']} disks per case "
              f"(cell mass M: {settings['cell_mass']} reading, of {settings['cell_mass_disks']} disks), "
              f"{result['wall_time_s']:.1f} s on {result['scheduler']} (samples' own times: "
              f"{result['sample_wall_time_s']:.1f} s)")
    if result.get("folder"):
        print(f"  samples in {result['folder']}" + (f", {result['resumed']} of them from before"
                                                    if result["resumed"] else ""))
    print(f"    {'quantity':<20}{'measured (mean ± s.e.)':<26}{'published':<24}source")
    for case in result["cases"]:
        zero = case.get("balanced_at_zero_pressure")
        print(f"  {case['case']}: {case['equilibrated']}/{case['completed']} samples in equilibrium"
              + ("" if zero is None else f" ({zero} balanced at P* = 0)"))
        for name, q in case["quantities"].items():
            digits = 4 if name.startswith("phi") else 3
            measured = "-" if q["mean"] is None else f"{q['mean']:.{digits}f}" + \
                ("" if q["sem"] is None else f" ± {q['sem']:.{digits}f}") + f" (n = {q['n']})"
            ref = q["published"]
            print(f"    {name:<20}{measured:<26}{ref['value']:g} ± {ref['error']:g}".ljust(74) + ref["source"])
        for stage, fit in case.get("averaged_fit", {}).items():
            suffix = "_0" if stage.startswith("at_zero_pressure") else ""
            window = " Hann" if stage.endswith("Hann window") else ""
            if fit["error"]:
                print(f"    d_F{suffix}, xi{suffix} of I(k){window} averaged over {fit['samples']} samples: "
                      f"{fit['error']}")
                continue
            for name, digits in (("d_F", 3), ("xi", 2), ("k0", 2)):
                ref = case["quantities"][name + suffix]["published"]
                error = f" ± {fit[name + '_error']:.{digits}f}" if name + "_error" in fit else ""
                measured = f"{fit[name]:.{digits}f}{error} (n = {fit['samples']})"
                print(f"    {name + suffix + ' <I(k)>' + window:<20}{measured:<25} {ref['value']:g} ± "
                      f"{ref['error']:g}".ljust(74) + ref["source"])
    for failure in result["failed"]:
        print(f"  failed: {failure['case']}, seed {failure['seed']}: {failure['error']}")


def add(commands) -> None:
    reproduce = commands.add_parser("reproduce", help="reproduce a paper's table on Dask, beside the published values")
    reproduce.add_argument("table", choices=tuple(REPRODUCTIONS),
                           help="Gilabert et al. method 1 (Tables II, III) or method 2 (Tables IV, V, VII)")
    reproduce.add_argument("--paper-size", action="store_true",
                           help="the paper's size: 1400 disks, 4 samples per case (--particles and --samples "
                                "still override: --particles 5600 --samples 3 is method 2's larger series)")
    reproduce.add_argument("--samples", type=positive_int, help="samples per case (default 2)")
    reproduce.add_argument("--particles", type=positive_int, help="disks per sample (default 100)")
    reproduce.add_argument("--max-time", type=number,
                           help="simulated-time limit of each preparation stage, in T0 (default 500)")
    reproduce.add_argument("--rolling-damping", type=number, metavar="ZETA_R", help=ROLLING_DAMPING_HELP)
    reproduce.add_argument("--cell-mass-disks", type=positive_int, metavar="N",
                           help="the cell's generalized mass M (Eq. 3) is the paper's for N disks (default 1400, "
                                "the paper's size: every sample size then compacts at the paper's rate)")
    reproduce.add_argument("--cell-mass", choices=CELL_MASS_READINGS,
                           help="reading of M: 'mass', 3/10 of the grain mass (default: a mass, as Eq. 3 needs "
                                "in 2D; reproduces Table III), or 'per-length', that over the cell size L (the "
                                "paper's words; compacts faster, looser and less coordinated)")
    reproduce.add_argument("--rolling", choices=tuple(ROLLING_CASES),
                           help="run the cases with rolling resistance (RR), those without (noRR) or both "
                                "(default both)")
    reproduce.add_argument("--seed", type=int, help="first seed (default 0)")
    reproduce.add_argument("--threads-per-sample", type=positive_int, metavar="T",
                           help="threads each sample runs on (default 1; the local cluster then has a worker per T "
                                "cores): for fewer samples than cores; from 1000 disks on, a sample on T threads "
                                "is another sample than on one")
    reproduce.add_argument("--dt-safety", type=number, metavar="F",
                           help=f"the time step as a fraction F of the stability bound, in (0, 1] (default "
                                f"{GILABERT_DT_SAFETY}; 0.3 until 27 Nov 2026: the same tables, twice the time)")
    folder = reproduce.add_mutually_exclusive_group()
    folder.add_argument("--out", metavar="DIR", help="write the settings and each sample to DIR as it finishes")
    folder.add_argument("--resume", metavar="DIR",
                        help="continue the reproduction in DIR (made by --out): run only the samples not there yet, "
                             "with DIR's settings")
    folder.add_argument("--series", metavar="DIR", nargs="+",
                        help="summarise the samples of these folders (made by --out, e.g. one of 1400 disks and one "
                             "of 5600) as one series, I(k) averaged over all of them before the fit; runs nothing")
    reproduce.add_argument("--workers", type=positive_int, help="local Dask workers (default: one per core)")
    reproduce.add_argument("--scheduler", help="address of an existing Dask scheduler (default: local cluster)")
    reproduce.add_argument("--json", action="store_true", help="print one JSON object")
    reproduce.set_defaults(handler=_reproduce, printer=_print_reproduce)
