"""The ``granlab`` command line.

- ``granlab run [SCENE] [--json]``: run a TOML scene (a path or a built-in name; default:
  the built-in ``default`` scene) and print a summary or one JSON object;
- ``granlab experiment NAME [--model M] [--zeta Z] [--mu MU] [--dt DT] [--json]``: a teaching
  experiment (collision, closed-path, block) against its formula;
- ``granlab bench [--steps S] [--json]``: particle-steps per second on the LAMMPS reference system.

Errors print one line naming what is wrong and exit with status 2.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numba
import numpy as np

from .errors import GranLabError


def _float(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number (inf is allowed)") from None


def _clean(value):
    """JSON-safe copy: arrays to lists, inf/NaN to strings."""
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, np.ndarray):
        return _clean(value.tolist())
    if isinstance(value, (np.floating, float)):
        value = float(value)
        return value if math.isfinite(value) else str(value)
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def run_scene(name: str) -> dict:
    """Run a scene to its end; returns the final state, energy budget and recorded series."""
    from .io.scene import load_scene

    scene = load_scene(name)
    if scene.threads:
        numba.set_num_threads(min(scene.threads, numba.config.NUMBA_NUM_THREADS))
    start = time.perf_counter()
    sim = scene.build()
    total = scene.step_count(sim.dt)
    series = {"time": [], "kinetic": [], "stored": [], "dissipated": [], "balance": []}

    def record():
        budget = sim.energy()
        series["time"].append(sim.time)
        for key in ("kinetic", "stored", "dissipated", "balance"):
            series[key].append(getattr(budget, key))

    every = scene.record_every or total
    record()
    done = 0
    while done < total:
        block = min(every, total - done)
        sim.run(block)
        done += block
        record()
    wall = time.perf_counter() - start
    snap = sim.snapshot()
    return {
        "title": scene.title, "particles": sim.particles.count, "steps": sim.step, "time": sim.time, "dt": sim.dt,
        "wall_time_s": wall, "particle_steps_per_s": sim.particles.count * sim.step / wall if wall > 0 else None,
        "positions": snap.positions, "velocities": snap.velocities, "omegas": snap.omegas, "angles": snap.angles,
        "energy": snap.energy.as_dict(), "contacts": snap.contacts.count, "status_counts": sim.status_counts(),
        "wall_names": list(snap.wall_names), "wall_forces": snap.wall_forces, "cell_lengths": snap.cell_lengths,
        "series": series,
    }


def _print_run(result: dict) -> None:
    energy = result["energy"]
    print(result["title"] or "scene")
    print(f"  {result['particles']} disks, {result['steps']} steps of dt = {result['dt']:.4g} "
          f"(t = {result['time']:.4g}) in {result['wall_time_s']:.2f} s "
          f"({result['particle_steps_per_s'] / 1e6:.2f} M particle-steps/s)")
    print(f"  contacts: {result['contacts']}  " + ", ".join(f"{k} {v}" for k, v in result['status_counts'].items()))
    print(f"  energy: kinetic {energy['kinetic']:.6g}, stored {energy['stored']:.6g}, gravity {energy['gravity']:.6g}, "
          f"dissipated {energy['dissipated']:.6g}, work in {energy['work_in']:.6g}")
    first = result["series"]["balance"][0]
    drift = energy["balance"] - first
    scale = max(abs(first), 1e-300)
    print(f"  energy balance: {energy['balance']:.6g} (drift {drift:.3g}, {drift / scale:.2e} relative)")


def _experiment(args) -> dict:
    from .protocols.teaching import EXPERIMENTS

    options = {"model": args.model}
    for key in ("zeta", "mu", "dt"):
        value = getattr(args, key)
        if value is not None:
            options[key] = value
    result = EXPERIMENTS[args.name](**options).as_dict()
    result["experiment"] = args.name
    return result


def _print_experiment(result: dict) -> None:
    name = result["experiment"]
    if name == "collision":
        print(f"collision ({result['model']}, zeta = {result['zeta']}, dt = {result['dt']:.3g})")
        print(f"  restitution {result['restitution']:.6f}  predicted exp(-pi zeta/sqrt(1-zeta^2)) = "
              f"{result['restitution_predicted']:.6f}")
        print(f"  contact duration {result['contact_duration']:.6g}  predicted {result['contact_duration_predicted']:.6g}")
    elif name == "closed-path":
        print(f"closed path of ratcheting Fig. 8 ({result['model']})")
        print(f"  enclosed area a = {result['enclosed_area']:.6g}")
        print(f"  change of D_t = {result['delta_Dt']:.6g}  predicted (Eq. 17) {result['predicted_delta_Dt']:.6g}")
        print(f"  slid: {result['slid']}; the disk came back to within {result['final_position_error']:.2g} of A")
    else:
        print(f"block on a plane (mu = {result['mu']}, normal load {result['normal_load']})")
        print(f"  max |F_t| / (mu F_n) = {result['max_Ft_over_muFn']:.6f} (the Coulomb cone allows at most 1)")
        print(f"  slid from load/mu F_n = {result['slide_start_load_ratio']:.4f} until "
              f"{result['slide_end_load_ratio']:.4f}; stuck again: {result['stuck_again']}")
        print(f"  friction work per slide: {', '.join(f'{w:.4g}' for w in result['friction_work_per_slide'])} "
              f"(positive work: {result['friction_work_positive']})")


def _bench(args) -> dict:
    from . import bench

    if args.steps < 1 or not 2 <= args.side <= 1000:
        raise GranLabError(f"bench takes --steps >= 1 and 2 <= --side <= 1000, not {args.steps} and {args.side}")
    return bench.run(args.steps, args.side)


def _print_bench(result: dict) -> None:
    print(result["system"])
    print(f"  1 thread:  {result['particle_steps_per_s_1thread'] / 1e6:.2f} M particle-steps/s")
    print(f"  {result['threads_all']} threads: {result['particle_steps_per_s_all'] / 1e6:.2f} M particle-steps/s "
          f"(speed-up {result['speedup']:.2f})")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="granlab", description="GranLab: 2D granular mechanics lab")
    commands = parser.add_subparsers(dest="command", required=True)

    run = commands.add_parser("run", help="run a TOML scene (a path or a built-in name)")
    run.add_argument("scene", nargs="?", default="default", help="scene file or built-in name (default: default)")
    run.add_argument("--json", action="store_true", help="print one JSON object")
    run.set_defaults(handler=lambda a: run_scene(a.scene), printer=_print_run)

    experiment = commands.add_parser("experiment", help="a teaching experiment against its formula")
    experiment.add_argument("name", choices=("collision", "closed-path", "block"))
    experiment.add_argument("--model", default="cundall-strack", choices=("cundall-strack", "alpha", "angle"),
                            help="tangential spring model")
    experiment.add_argument("--zeta", type=_float, help="normal damping ratio zeta in [0, 1)")
    experiment.add_argument("--mu", type=_float, help="friction coefficient (inf: no sliding)")
    experiment.add_argument("--dt", type=_float, help="time step (default: from the stability bound)")
    experiment.add_argument("--json", action="store_true", help="print one JSON object")
    experiment.set_defaults(handler=_experiment, printer=_print_experiment)

    bench = commands.add_parser("bench", help="particle-steps per second on the LAMMPS reference system")
    bench.add_argument("--steps", type=int, default=5000, help="timed steps (default 5000)")
    bench.add_argument("--side", type=int, default=100, help="disks per side of the lattice (default 100: 10 000)")
    bench.add_argument("--json", action="store_true", help="print one JSON object")
    bench.set_defaults(handler=_bench, printer=_print_bench)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        result = args.handler(args)
    except GranLabError as error:
        print(f"granlab {args.command}: error: {error}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(_clean(result)))
    else:
        args.printer(result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
