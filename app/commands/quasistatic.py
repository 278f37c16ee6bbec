"""``granlab quasistatic SCENE --wall NAME=LOAD | --force I=FX,FY [--steps S] [--compare T...]``: follow a
slowly changing load with the stiffness matrix (:mod:`granlab.engine.protocols.quasistatic`)."""

from __future__ import annotations

import math
from pathlib import Path

from granlab.engine.errors import ParameterError

from .options import number, positive_int


def add(commands) -> None:
    quasistatic = commands.add_parser("quasistatic", help="follow a slowly changing load with the stiffness matrix "
                                                          "and the consistent contact status")
    quasistatic.add_argument("start", metavar="START",
                             help="a run file with a checkpoint (granlab prepare ... --out FILE), or a scene (a TOML "
                                  "file or a built-in name, e.g. block) run for its duration first")
    quasistatic.add_argument("--wall", action="append", default=[], metavar="NAME=LOAD",
                             help="the final load of a force-controlled wall (its base: a pressure for a wall loaded "
                                  "per length); repeat for several walls")
    quasistatic.add_argument("--force", action="append", default=[], metavar="I=FX,FY",
                             help="the final external force on disk I; repeat for several disks")
    quasistatic.add_argument("--steps", type=positive_int, default=100, help="load steps (default 100)")
    quasistatic.add_argument("--compare", type=number, nargs="+", default=[], metavar="T",
                             help="ramp the same load in the dynamics over each duration T and report how far each "
                                  "end is from the quasi-static one")
    quasistatic.add_argument("--check-unique", action="store_true",
                             help="enumerate every state of up to 10 critical contacts at each step and count the "
                                  "consistent ones (the principle of minimum sliding says one)")
    quasistatic.add_argument("--json", action="store_true", help="print one JSON object")
    quasistatic.set_defaults(handler=_quasistatic, printer=_print_quasistatic)


def _quasistatic_targets(args):
    from granlab.engine.protocols.quasistatic import Targets

    walls, forces = {}, {}
    for text in args.wall:
        name, _, value = text.partition("=")
        try:
            walls[name] = float(value)
        except ValueError:
            raise ParameterError("--wall", text, "NAME=LOAD with LOAD a number, e.g. top=1.1") from None
    for text in args.force:
        index, _, value = text.partition("=")
        try:
            fx, fy = (float(v) for v in value.split(","))
            forces[int(index)] = (fx, fy)
        except ValueError:
            raise ParameterError("--force", text, "I=FX,FY with I a disk index and FX, FY numbers, e.g. 0=0.75,0") \
                from None
    if not walls and not forces:
        raise ParameterError("load", "none given", "at least one --wall NAME=LOAD or --force I=FX,FY")
    named = [*((f"wall {n}", (v,)) for n, v in walls.items()), *((f"disk {i}", v) for i, v in forces.items())]
    for name, values in named:
        if not all(math.isfinite(v) for v in values):
            raise ParameterError(f"load of {name}", values, "finite numbers")
    return Targets(walls, forces)


def _quasistatic_start(start: str):
    import h5py

    from granlab.engine.io import h5md
    from granlab.engine.io.scene import load_scene

    if Path(start).is_file() and h5py.is_hdf5(start):
        return h5md.resume(start)[0]
    scene = load_scene(start)
    sim = scene.build()
    sim.run(scene.step_count(sim.dt))
    return sim


def _quasistatic(args) -> dict:
    import numpy as np

    from granlab.engine.protocols.quasistatic import STOP_REASONS, compare

    targets = _quasistatic_targets(args)
    for duration in args.compare:
        if not (duration > 0 and math.isfinite(duration)):
            raise ParameterError("--compare", duration, "durations > 0")
    sim = _quasistatic_start(args.start)
    result = compare(sim, targets, args.steps, args.compare, args.check_unique)
    path = result["path"]
    mobile = result["mobile"]
    names = [name for name, m in zip(path.wall_names, mobile) if m]
    rows = [{"load": float(path.load[k]),
             "walls_moved": {name: float(path.wall_offsets[k][m] - path.wall_offsets[0][m])
                             for m, name in enumerate(path.wall_names) if mobile[m]},
             "largest_disk_move": float(np.abs(path.positions[k] - path.positions[0]).max()),
             "sliding": int(path.sliding[k]), "critical": int(path.critical[k]), "flips": int(path.flips[k]),
             "iterations": int(path.iterations[k]), "consistent_states": int(path.consistent_states[k])}
            for k in range(len(path.load))]
    return {"start": args.start, "disks": result["disks"], "contacts": result["contacts"],
            "start_imbalance": result["start_imbalance"],
            "loads": {name: [float(result["start_loads"][m]), float(result["target_loads"][m])]
                      for m, name in enumerate(path.wall_names) if name in names},
            "forces": {str(i): list(v) for i, v in targets.forces.items()},
            "steps": args.steps, "reached": path.reached, "stop": path.stop, "stop_reason": STOP_REASONS[path.stop],
            "stop_detail": path.stop_detail, "halvings": path.halvings, "solves": path.solves,
            "wall_time_s": path.wall_time_s,
            "events": [{"load": float(lam), "event": kind, "contact": name} for lam, kind, name in path.events],
            "path": rows, "comparisons": result["comparisons"]}


def _print_quasistatic(result: dict) -> None:
    loads = [f"wall '{name}' {a:g} -> {b:g}" for name, (a, b) in result["loads"].items() if a != b]
    loads += [f"disk {i} force -> ({v[0]:g}, {v[1]:g})" for i, v in result["forces"].items()]
    print(f"quasistatic {result['start']}: {result['disks']} disks, {result['contacts']} contacts; "
          f"{', '.join(loads)} in {result['steps']} steps")
    print(f"  stopped at load fraction {result['reached']:.6g}: {result['stop_reason']}"
          + ("" if result["stop"] == "target" else f", {result['stop_detail']}"))
    print(f"  {result['solves']} linear solves, {result['halvings']} halvings, {result['wall_time_s']:.2f} s")
    walls = list(next(iter(result["path"]))["walls_moved"])
    print("    " + "load".ljust(10) + "".join(f"{name + ' moved':>14}" for name in walls)
          + f"{'disk moved':>14}{'sliding':>9}{'critical':>9}{'flips':>7}{'Newton':>8}"
          + (f"{'consistent':>12}" if any(r["consistent_states"] >= 0 for r in result["path"]) else ""))
    rows = result["path"]
    shown = sorted(set(range(0, len(rows), max(1, len(rows) // 10))) | {len(rows) - 1})
    for k in shown:
        r = rows[k]
        print(f"    {r['load']:<10.6g}" + "".join(f"{r['walls_moved'][name]:>14.4g}" for name in walls)
              + f"{r['largest_disk_move']:>14.4g}{r['sliding']:>9}{r['critical']:>9}{r['flips']:>7}"
              f"{r['iterations']:>8}" + (f"{r['consistent_states']:>12}" if r["consistent_states"] >= 0 else ""))
    for event in result["events"]:
        print(f"  contact {event['contact']} {event['event']} at load fraction {event['load']:.4g}")
    if result["comparisons"]:
        print("  the dynamics ramping the same load (RMS difference from the quasi-static end over its displacement):")
        print(f"    {'duration':>10}{'steps':>12}{'wall time':>11}{'disks':>12}{'walls':>12}")
        for c in result["comparisons"]:
            walls_text = "-" if c["walls"] is None else f"{c['walls']:.3g}"
            print(f"    {c['duration']:>10g}{c['steps']:>12}{c['wall_time_s']:>10.2f}s{c['disks']:>12.3g}"
                  f"{walls_text:>12}")
