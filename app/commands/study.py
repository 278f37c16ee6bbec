"""``granlab study ratchet [options] [--json]``: many samples of cyclic loading on Dask."""

from __future__ import annotations

import math
import os
from pathlib import Path

from granlab.engine import costs
from granlab.engine.errors import GranLabError
from granlab.engine.params import BACKENDS, TANGENTIAL_MODELS

from .options import number, positive_int


def _study(args) -> dict:
    from granlab.engine.studies import RatchetStudy, TextProgress, run_ratchet_study

    if args.batch and args.out:
        raise GranLabError("--batch writes no run files (a batch's work and dissipation are not split by sample): "
                           "leave out --out, or --batch")
    models = TANGENTIAL_MODELS if args.model == "all" else (args.model,)
    sweep = len(args.amplitude) > 1
    results = []
    costs.check_memory(args.particles * min(args.samples, os.cpu_count() or 1), "--particles on every core")
    for amplitude in args.amplitude:
        study = RatchetStudy(particles=args.particles, samples=args.samples, cycles=args.cycles, models=models,
                             amplitude=amplitude, period=args.period,
                             phase=None if args.phase is None else math.radians(args.phase), zero_mean=args.zero_mean,
                             friction=args.mu, dt_factor=args.dt_factor, reference_cycle=args.reference_cycle,
                             gravity=args.gravity, first_seed=args.seed, watch_samples=args.watch,
                             backend=args.backend, batched=args.batch)
        out = str(Path(args.out) / f"amplitude-{amplitude:g}") if sweep and args.out else args.out
        result = run_ratchet_study(study, scheduler=args.scheduler, out_dir=out,
                                   progress=None if args.json else TextProgress(), force=args.force)
        if result["failed"] and not any(model["completed"] for model in result["models"].values()):
            first = result["failed"][0]
            raise GranLabError(f"every sample failed ({len(result['failed'])} of {len(result['failed'])}); seed "
                               f"{first['seed']} ({first['model']}): {first['error']}")
        results.append(result)
    if not sweep:
        return results[0]
    return {"study": "ratchet amplitude sweep", "amplitudes": list(args.amplitude), "results": results,
            "wall_time_s": sum(r["wall_time_s"] for r in results)}


def _print_study(result: dict) -> None:
    if "results" in result:
        for one in result["results"]:
            print(f"amplitude Delta sigma / P0 = {one['settings']['amplitude']:g}:")
            _print_study(one)
        print(f"{'amplitude':>9}  {'model':<16}{'ratcheting':>11} {'(95 %, %)':<10}{'negative':>9} {'(95 %, %)':<10}"
              f"{'without jumps':>13}  |dgamma| geometric mean (range)")
        for one in result["results"]:
            for model, data in one["models"].items():
                spread = "-" if not data["geomean_abs_dgamma"] else (
                    f"{data['geomean_abs_dgamma']:.3g} ({data['range_abs_dgamma'][0]:.3g}..{data['range_abs_dgamma'][1]:.3g})")
                paper = data["rules"][0]
                print(f"{one['settings']['amplitude']:>9g}  {model:<16}{data['ratcheting']:>6}/{data['completed']:<4} "
                      f"{_percent(paper['ratcheting_interval']):<10}{data['negative']:>5}/{data['ratcheting']:<3} "
                      f"{_percent(paper['negative_interval']):<10}"
                      f"{data['ratcheting_without_outliers']:>8}/{data['completed']:<4}  {spread}")
        print(f"total {result['wall_time_s']:.1f} s")
        return
    settings = result["settings"]
    print(f"ratchet study: {settings['samples']} samples of {settings['particles']} disks, {settings['cycles']} cycles, "
          f"{result['wall_time_s']:.1f} s on {result['scheduler']}")
    for model, data in result["models"].items():
        print(f"  {model}: {data['ratcheting']}/{data['completed']} ratcheting", end="")
        if data["geomean_abs_dgamma"]:
            low, high = data["range_abs_dgamma"]
            print(f"; |dgamma| geometric mean {data['geomean_abs_dgamma']:.3g}, range {low:.3g}..{high:.3g}; "
                  f"{data['positive']} positive, {data['negative']} negative", end="")
        print(f"; {data['shakedown']} shakedown, {data['with_outliers']} with outliers "
              f"({data['ratcheting_without_outliers']} ratchet without their jumps)")
        _print_rules(data["rules"])
        for sample in data["samples"]:
            if sample["error"]:
                print(f"    seed {sample['seed']} failed: {sample['error']}")
    for failure in result["failed"]:
        print(f"  failed: seed {failure['seed']} ({failure['model']}): {failure['error']}")


def _percent(interval) -> str:
    return "-" if interval is None else f"{100 * interval[0]:.0f}-{100 * interval[1]:.0f}"


def _print_rules(rules: list[dict]) -> None:
    """The share ratcheting and negative under each verdict rule, with Wilson 95 % intervals."""
    print(f"    {'verdict rule':<48}{'ratcheting':>12} {'(95 %, %)':<10}{'negative':>10} {'(95 %, %)':<10}"
          f"|dgamma| geometric mean (95 %)")
    for rule in rules:
        geomean = "-" if rule["geomean_abs_dgamma"] is None else f"{rule['geomean_abs_dgamma']:.2g}"
        if rule["geomean_interval"] is not None:
            geomean += " ({:.2g} .. {:.2g})".format(*rule["geomean_interval"])
        share, negative = _percent(rule["ratcheting_interval"]), _percent(rule["negative_interval"])
        print(f"    {rule['rule']:<48}{rule['ratcheting']:>6}/{rule['samples']:<5} {share:<10}"
              f"{rule['negative']:>5}/{rule['ratcheting']:<4} {negative:<10}{geomean}")


def add(commands) -> None:
    study = commands.add_parser("study", help="studies of many samples on Dask")
    kinds = study.add_subparsers(dest="kind", required=True)
    ratchet = kinds.add_parser("ratchet", help="cyclic loading of biaxial boxes (ratcheting Sec. IV B)")
    ratchet.add_argument("--particles", type=positive_int, default=16)
    ratchet.add_argument("--samples", type=positive_int, default=10)
    ratchet.add_argument("--cycles", type=positive_int, default=100)
    ratchet.add_argument("--model", default="cundall-strack", choices=TANGENTIAL_MODELS + ("all",))
    ratchet.add_argument("--phase", type=number, help="elliptic loading with this phase (degrees; Eqs. 4-5)")
    ratchet.add_argument("--mu", type=number, default=0.2, help="friction during cycling (inf: no sliding)")
    ratchet.add_argument("--dt-factor", type=number, default=0.2, help="dt = f sqrt(m_min / K_n) (default 0.2)")
    ratchet.add_argument("--amplitude", type=number, nargs="+", default=[0.2], metavar="A",
                         help="Delta sigma in units of P0 (default 0.2); several: a sweep, the same samples at each "
                              "(with --out, a folder amplitude-A for each)")
    ratchet.add_argument("--period", type=number, default=10.0, help="cycle period in tau (default 10)")
    ratchet.add_argument("--reference-cycle", type=int,
                         help="cycle defining L0 (default 30 %% of --cycles, at most cycles - 3: 30 of 100)")
    ratchet.add_argument("--zero-mean", action="store_true",
                         help="cycle the load about P0 (q = -Delta sigma cos wt): its mean isotropic, not Eq. 1's "
                              "P0 + Delta sigma on the top wall")
    ratchet.add_argument("--gravity", type=number, default=0.0, help="weak gravity (Sec. IV B 3)")
    ratchet.add_argument("--seed", type=int, default=0, help="first seed")
    ratchet.add_argument("--watch", type=int, default=0, metavar="K",
                         help="record every contact's (F_n, F_t, status) K times per cycle in the run files")
    ratchet.add_argument("--scheduler", help="address of an existing Dask scheduler (default: local cluster)")
    ratchet.add_argument("--backend", choices=BACKENDS, default="cpu",
                         help="where the cycles run: the CPU's threads (default), or an NVIDIA GPU (numba.cuda)")
    ratchet.add_argument("--batch", action="store_true",
                         help="every sample side by side in one simulation in this process (its threads, or one GPU "
                              "with --backend cuda) instead of one Dask worker a sample; without --out")
    ratchet.add_argument("--out", help="folder for the run files (one per sample and model)")
    ratchet.add_argument("--force", action="store_true", help="write over run files already in --out")
    ratchet.add_argument("--json", action="store_true", help="print one JSON object")
    ratchet.set_defaults(handler=_study, printer=_print_study)
