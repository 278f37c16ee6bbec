"""The ``granlab`` command line.

- ``granlab run [SCENE] [--json]``: run a TOML scene (a path or a built-in name; default:
  the built-in ``default`` scene) and print a summary or one JSON object;
- ``granlab experiment NAME [--model M] [--zeta Z] [--mu MU] [--dt DT] [--json]``: a teaching
  experiment (collision, closed-path, block) against its formula;
- ``granlab bench [--steps S] [--json]``: particle-steps per second on the LAMMPS reference system
  (``--analysis PACKING.h5``: the wall time of every analysis instead);
- ``granlab prepare --method {compress,1,2} [options] [--json]``: a packing in equilibrium;
- ``granlab study ratchet [options] [--json]``: many samples of cyclic loading on Dask;
- ``granlab reproduce {gilabert-method1,gilabert-method2} [--paper-size] [--samples S] [--particles N] [--rolling {both,RR,noRR}]
  [--threads-per-sample T] [--dt-safety F] [--out DIR | --resume DIR | --series DIR...] [--json]``: Gilabert's
  preparation tables measured on Dask beside the published values, each sample written to DIR as it finishes;
- ``granlab analyze RUNFILE {stiffness,status,rigidity,packing,fractal} [--frame K] [--json]``:
  quasi-static and structural analysis of one frame (:mod:`granlab.engine.analysis.report`);
- ``granlab info RUNFILE [--json]``: what a run file holds.

Errors print one line naming what is wrong and exit with status 2.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import threading
import time
from importlib.metadata import version
from pathlib import Path

from . import costs
from .analysis import ANALYSES, LOADS
from .errors import DivergenceError, GranLabError, ParameterError, RegistryError, WriteFailed, one_line
from .params import CELL_MASS_READINGS, GILABERT_DT_SAFETY, TANGENTIAL, TANGENTIAL_MODELS
from .reproduce import REPRODUCTIONS, ROLLING_CASES


def _float(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number (inf is allowed)") from None


def run_scene(name: str | None, out: str | None = None, frame_every: int | None = None,
              resume: str | None = None, force: bool = False, checkpoint_frames: int = 10,
              checkpoint_seconds: float = 60.0, progress=None) -> dict:
    """Run a scene to its end (or continue a run file from its checkpoint); returns the final
    state, energy budget and recorded series.

    With ``out`` a run file gets a frame every ``frame_every`` steps (default: the scene's
    ``record_every``; a resumed run keeps its file's) and a checkpoint with the frame every
    ``checkpoint_frames`` frames or once ``checkpoint_seconds`` of wall time have passed since
    the last, and at the end: a killed run resumes from the last one, bit for bit. A diverging
    run writes its restored last good state as the last checkpoint. ``out`` is never the resumed
    file, and an existing ``out`` is written over only with ``force``. ``progress(done, total,
    sim)`` is called about four times a second of wall time (the steps run in slices that long;
    a run split so continues bit for bit), not after the last slice: the result follows."""
    import numba

    from .compilation import compile_sets, step_sets
    from .io import h5md
    from .io.outputs import check_output
    from .io.scene import load_scene, parse_scene
    from .params import positive
    from .simulation import PARALLEL_MIN_DISKS

    positive("--checkpoint-seconds", checkpoint_seconds, allow_inf=True)
    start = time.perf_counter()
    if resume is not None and out is None:
        out = str(Path(resume).with_name(Path(resume).stem + "-resumed.h5"))
    if out is not None:
        check_output(out, force=force, inputs=[resume] if resume else [])
    if resume is not None:
        sim, record = h5md.resume(resume)
        scene = parse_scene(record["scene"], origin=f"scene stored in {resume}")
        total = max(0, scene.step_count(sim.dt) - sim.step)
        frame_every = frame_every or record.get("frame_every")
    else:
        scene = load_scene(name)
        memory = costs.simulation_memory(scene.particles.count)
        if memory >= costs.ANNOUNCE_BYTES:
            print(f"building {scene.particles.count} disks (up to {costs.size(memory)} of memory)", file=sys.stderr,
                  flush=True)
        if scene.threads:
            numba.set_num_threads(scene.threads)
        threaded = numba.get_num_threads() > 1 and scene.particles.count >= PARALLEL_MIN_DISKS
        compile_sets(step_sets([scene.law.tangential_model], threaded) + ["state", "packing"])
        sim = scene.build()
        total = scene.step_count(sim.dt)
    series = {"time": [], "kinetic": [], "stored": [], "dissipated": [], "balance": []}
    every = frame_every or scene.record_every or total or 1
    if out is not None:
        _check_run_file_room(sim, out, 1 + -(-total // every))
    writer = h5md.RunWriter(out, sim, scene=scene.source, overwrite=force,
                            protocol={"command": "run", "scene": scene.title, "frame_every": every}) if out else None
    last_checkpoint = {"frames": 0, "time": time.perf_counter()}

    def record():
        budget = sim.energy()
        series["time"].append(sim.time)
        for key in ("kinetic", "stored", "dissipated", "balance"):
            series[key].append(getattr(budget, key))
        if writer is not None:
            writer.write_frame(sim)
            last_checkpoint["frames"] += 1
            if (last_checkpoint["frames"] >= checkpoint_frames
                    or time.perf_counter() - last_checkpoint["time"] >= checkpoint_seconds):
                writer.write_checkpoint(sim)
                last_checkpoint.update(frames=0, time=time.perf_counter())

    try:
        record()
        done = 0
        slice_steps = 100
        while done < total:
            block = min(every, total - done)
            while block > 0:
                steps = min(block, slice_steps)
                began = time.perf_counter()
                try:
                    sim.run(steps)
                except DivergenceError as error:
                    if writer is not None:
                        writer.write_checkpoint(sim)
                        error.args = (f"{error} It is the last checkpoint of {out}.",)
                    raise
                done += steps
                block -= steps
                slice_steps = max(1, int(steps * 0.25 / max(time.perf_counter() - began, 1e-6)))
                if progress is not None and done < total:
                    progress(done, total, sim)
            record()
        if writer is not None:
            writer.write_checkpoint(sim)
    finally:
        if writer is not None:
            writer.close()
    wall = time.perf_counter() - start
    snap = sim.snapshot()
    return {
        "title": scene.title, "particles": sim.particles.count, "steps": sim.step, "time": sim.time, "dt": sim.dt,
        "wall_time_s": wall, "particle_steps_per_s": sim.particles.count * done / wall if wall > 0 else None,
        "positions": snap.positions, "velocities": snap.velocities, "omegas": snap.omegas, "angles": snap.angles,
        "energy": snap.energy.as_dict(), "contacts": snap.contacts.count, "status_counts": sim.status_counts(),
        "wall_names": list(snap.wall_names), "wall_forces": snap.wall_forces, "cell_lengths": snap.cell_lengths,
        "series": series, "run_file": out,
        "first_order": bool(snap.energy.dissipated_damping) and not TANGENTIAL[sim.law.tangential_model].whole_step_dashpots,
    }


def _check_run_file_room(sim, out: str, frames: int) -> None:
    """Refuse a run file the disk cannot hold; say what a large one will take before it is begun."""
    from .io import h5md
    from .io.outputs import room_for_one_file

    need, room = h5md.run_file_bytes(sim, frames), room_for_one_file(Path(out).absolute().parent)
    if need > room:
        raise costs.CostError(f"--out {out!r}: {frames} frames of {sim.particles.count} disks need up to "
                              f"{costs.size(need)}; {costs.size(room)} free there: fewer frames (--frame-every, "
                              f"simulation.record_every), or another disk")
    if need >= costs.ANNOUNCE_BYTES:
        print(f"writing {frames} frames to {out} (up to {costs.size(need)})", file=sys.stderr, flush=True)


def _run_progress():
    """A line on standard error once a second of stepping, from the first second on (a short run
    prints none; the clock starts with the first steps, after the imports and the kernels' loading):
    ``running: step 12000 of 80000 (15 %), t = 3.2, 4 s, about 23 s left``."""
    clock = {}

    def report(done: int, total: int, sim) -> None:
        now = time.monotonic()
        start = clock.setdefault("start", now)
        if now - clock.setdefault("shown", now) >= 1.0:
            clock["shown"] = now
            left = (total - done) * (now - start) / done
            print(f"running: step {done} of {total} ({100 * done / total:.0f} %), t = {sim.time:.4g}, "
                  f"{now - start:.0f} s, about {costs.duration(left)} left", file=sys.stderr, flush=True)
    return report


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
    order = ("falls as dt: LAMMPS's half-step dashpots" if result["first_order"]
             else "falls faster than dt: as dt^1.5 to dt^3 in oblique collisions")
    print(f"  energy balance: {energy['balance']:.6g} (drift {drift:.3g}, {drift / scale:.2e} relative; {order})")
    if result["run_file"]:
        print(f"  run file: {result['run_file']}")


def _experiment(args) -> dict:
    from .compilation import compile_sets, step_sets
    from .protocols.teaching import EXPERIMENTS

    options = {key: getattr(args, key) for key in ("zeta", "mu", "dt") if getattr(args, key) is not None}
    models = TANGENTIAL_MODELS if args.model == "all" else (args.model,)
    compile_sets(step_sets(models))
    results = [dict(EXPERIMENTS[args.name](model=model, **options).as_dict(), experiment=args.name)
               for model in models]
    return {"experiment": args.name, "models": results} if args.model == "all" else results[0]


def _print_experiment(result: dict) -> None:
    for one in result.get("models", [result]):
        _print_one_experiment(one)


def _print_one_experiment(result: dict) -> None:
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
    import numba

    from . import bench

    if args.beside_engine and not args.analysis:
        raise GranLabError("--beside-engine times the analyses of --analysis PACKING.h5: give that too")
    if args.analysis:
        if args.beside_engine:
            return bench.analysis_beside_engine(args.analysis, args.particles or bench.ANALYSIS_PARTICLES)
        return bench.analysis(args.analysis, args.particles or bench.ANALYSIS_PARTICLES)
    steps = args.steps or (bench.SCALING_STEPS if args.scaling else bench.TIMED_STEPS)
    if steps < 1 or not 2 <= args.side <= 1000:
        raise GranLabError(f"bench takes --steps >= 1 and 2 <= --side <= 1000, not {steps} and {args.side}")
    if args.scaling:
        return bench.scaling(steps=steps)
    if args.profile:
        return bench.profile(args.side, args.steps or 1000)
    from .compilation import compile_sets, step_sets

    compile_sets(step_sets([args.model]) + step_sets([args.model], threads=numba.config.NUMBA_NUM_THREADS > 1))
    return bench.run(steps, args.side, args.model)


def _print_bench(result: dict) -> None:
    if "contact_pass_ns_per_row" in result:
        step = result["ns_per_particle_step"]
        print(result["system"])
        print(f"  a particle-step: {step:.1f} ns ({1e3 / step:.1f} M particle-steps/s)")
        print(f"  contact pass:    {result['contact_pass_ns_per_disk']:.1f} ns per disk "
              f"({result['rows_per_disk']:.2f} rows per disk, {result['contact_pass_ns_per_row']:.1f} ns per row), "
              f"{100 * result['contact_pass_ns_per_disk'] / step:.0f} %; every row directly: "
              f"{result['direct_contact_pass_ns_per_row']:.1f} ns per row")
        print(f"  particle pass:   {result['particle_pass_ns_per_disk']:.1f} ns per disk, "
              f"{100 * result['particle_pass_ns_per_disk'] / step:.0f} %")
        if result["other_ns_per_disk"] > 0:
            print(f"  the rest:        {result['other_ns_per_disk']:.1f} ns per disk (walls, cell, tallies, checks), "
                  f"{100 * result['other_ns_per_disk'] / step:.0f} %")
        else:
            print("  the rest:        below the noise (the two passes timed apart take longer than in a step)")
        print(f"  one rebuild of the contact table: {result['rebuild_in_steps']:.1f} steps")
        return
    if "sizes" in result:
        print(result["system"])
        print(f"  {'disks':>9} {'steps':>6} {'M particle-steps/s':>19} {'ns/particle-step':>17} {'bytes/disk':>11} "
              f"{'a rebuild, in steps':>20} {'rebuilds':>9} {'rebuild share':>14}")
        for row in result["sizes"]:
            print(f"  {row['particles']:>9} {row['steps']:>6} {row['particle_steps_per_s'] / 1e6:>19.2f} "
                  f"{row['ns_per_particle_step']:>17.1f} {row['bytes_per_disk']:>11.0f} {row['rebuild_in_steps']:>20.1f} "
                  f"{row['rebuilds']:>9} {100 * row['rebuild_share']:>13.1f}%")
        print(f"  slowest size over fastest, per particle-step: {result['worst_over_best']:.2f}")
        return
    if "beside_engine" in result:
        print(f"analyses of {result['packing']} ({result['particles']} disks) beside a simulation of it on one "
              f"thread ({result['engine_steps_per_s_alone']:.0f} steps/s alone; {result['cores']} cores, "
              f"{result['free_threads']} free)")
        print(f"  {'analysis':<10}{'alone':>9}{'beside, every core':>26}{'beside, free cores':>26}")
        for kind, row in result["beside_engine"].items():
            print(f"  {kind:<10}{row['alone_s']:>8.3f}s"
                  + "".join(f"{row[name + '_s']:>12.3f}s, engine "
                          + ("    -" if row[name + "_engine_share"] is None else f"{row[name + '_engine_share']:>5.2f}")
                          for name in ("every_core", "free_cores")))
        return
    if "fractal_s" in result:
        print(f"analysis of {result['packing']}: {result['particles']} disks, {result['contacts']} contacts"
              + (f" (prepared in {result['preparation_s']:.0f} s)" if result["preparation_s"] else ""))
        for kind, values in result["values"].items():
            if "error" in values:
                print(f"  {kind}: error: {values['error']}")
                continue
            timing = result["timings_s"][kind]
            stages = ", ".join(f"{k} {v:.3f}" for k, v in timing.items() if k != "total")
            print(f"  {kind}: {timing['total']:.3f} s ({stages})")
        return
    print(result["system"])
    print(f"  1 thread:  {result['particle_steps_per_s_1thread'] / 1e6:.2f} M particle-steps/s")
    print(f"  {result['threads_all']} threads: {result['particle_steps_per_s_all'] / 1e6:.2f} M particle-steps/s "
          f"(speed-up {result['speedup']:.2f})")


def _progress_line(line: str) -> None:
    """A preparation's progress, once a second, on standard error: standard output keeps the result."""
    print(line, file=sys.stderr, flush=True)


def _prepare(args) -> dict:
    import numba

    from .analysis.packing import packing_stats
    from .compilation import compile_sets, step_sets
    from .io.h5md import RunWriter
    from .io.outputs import check_output
    from .protocols import prepare
    from .simulation import PARALLEL_MIN_DISKS

    if args.out:
        check_output(args.out, force=args.force)
    costs.check_memory(args.particles, "--particles")
    if args.method == "compress" and args.dt_safety is not None:
        raise ParameterError("--dt-safety", args.dt_safety, "an option of --method 1 and 2 only")
    threaded = numba.get_num_threads() > 1 and args.particles >= PARALLEL_MIN_DISKS
    compile_sets(step_sets(["cundall-strack"], threaded) + ["state", "packing"])
    if args.method == "compress":
        prepared = prepare.compress(args.particles, seed=args.seed, pressure=args.pressure,
                                    friction=0.2 if args.mu is None else args.mu, max_time=args.max_time or 400.0,
                                    progress=_progress_line)
    else:
        law = prepare.gilabert_law(friction=0.15 if args.mu is None else args.mu, kappa=args.kappa,
                                   cohesion=args.method == "2" or args.cohesive, rolling=args.rolling,
                                   pressure=args.pressure, rolling_damping_ratio=args.rolling_damping)
        args.dt_safety = GILABERT_DT_SAFETY if args.dt_safety is None else args.dt_safety  # the run file keeps it
        common = dict(count=args.particles, solid_fraction=args.solid_fraction, pressure=args.pressure, law=law,
                      seed=args.seed, progress=_progress_line, dt_safety=args.dt_safety)
        if args.method == "1":
            prepared = prepare.method1(max_time=args.max_time or 2000.0, **common)
        else:
            prepared = prepare.method2(speed=args.speed, accelerated=args.accelerated,
                                       max_time=args.max_time or 4000.0, **common)
    sim = prepared.sim
    stats = packing_stats(sim.snapshot(), prepared.report.force_scale)
    run_file = args.out
    if run_file:
        with RunWriter(run_file, sim, protocol={"command": "prepare", **{k: v for k, v in vars(args).items()
                                                                          if k not in ("handler", "printer")}},
                       overwrite=args.force) as w:
            w.write_frame(sim)
            w.write_checkpoint(sim)
    return {"method": args.method, "particles": sim.particles.count, "phi": stats.phi, "z": stats.z,
            "z_star": stats.z_star, "rattlers": stats.rattlers, "equilibrated": prepared.equilibrated,
            "sim_time": prepared.sim_time, "wall_time_s": prepared.wall_time_s, "run_file": run_file,
            "pressure": prepared.pressure, "measured_pressure": prepared.report.measured_pressure,
            "equilibrium": prepared.report.as_dict()}


def _print_prepare(result: dict) -> None:
    state = "in equilibrium" if result["equilibrated"] else "NOT in equilibrium (time limit reached)"
    print(f"method {result['method']}: {result['particles']} disks {state} after t = {result['sim_time']:.4g} "
          f"({result['wall_time_s']:.2f} s)")
    print(f"  solid fraction {result['phi']:.4f}, coordination z = {result['z']:.3f} (z* = {result['z_star']:.3f}), "
          f"{result['rattlers']} rattlers; pressure {result['measured_pressure']:.6g} (imposed {result['pressure']:.6g})")
    if result["run_file"]:
        print(f"  run file: {result['run_file']}")


def _study(args) -> dict:
    from .studies import RatchetStudy, TextProgress, run_ratchet_study

    models = TANGENTIAL_MODELS if args.model == "all" else (args.model,)
    sweep = len(args.amplitude) > 1
    results = []
    costs.check_memory(args.particles * min(args.samples, os.cpu_count() or 1), "--particles on every core")
    for amplitude in args.amplitude:
        study = RatchetStudy(particles=args.particles, samples=args.samples, cycles=args.cycles, models=models,
                             amplitude=amplitude, period=args.period,
                             phase=None if args.phase is None else math.radians(args.phase), zero_mean=args.zero_mean,
                             friction=args.mu, dt_factor=args.dt_factor, reference_cycle=args.reference_cycle,
                             gravity=args.gravity, first_seed=args.seed, watch_samples=args.watch)
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


_REPRODUCTION_OPTIONS = {"particles": "--particles", "samples": "--samples", "first_seed": "--seed",
                         "max_time": "--max-time", "rolling_damping_ratio": "--rolling-damping",
                         "cell_mass_disks": "--cell-mass-disks", "cell_mass": "--cell-mass",
                         "rolling": "--rolling", "threads_per_sample": "--threads-per-sample",
                         "dt_safety": "--dt-safety"}


def _reproduce(args) -> dict:
    from .reproduce import (PAPER_SIZE, Reproduction, finished_samples, resume_folder, run_reproduction,
                            start_folder, summarize_series)
    from .studies import STUDY_LIMITS, TextProgress

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
    except KeyboardInterrupt:
        if folder is None:
            raise
        total = reproduction.samples * len(reproduction.cases)
        print(f"\ninterrupted: {len(finished_samples(folder))} of {total} samples are in {folder}; go on with "
              f"granlab reproduce {args.table} --resume {folder}", file=sys.stderr)
        raise SystemExit(130) from None
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


def _info(args) -> dict:
    from .io.h5md import summary

    return summary(args.runfile)


def _print_info(result: dict) -> None:
    print(f"{result['run_file']}: H5MD {'.'.join(map(str, result.get('h5md_version') or ['?']))} "
          f"by {result.get('creator', '?')}")
    print(f"  {result.get('particles', '?')} disks, {result['frames']} complete frames"
          + (f", t = {result['first_time']:.6g} .. {result['last_time']:.6g} (step {result['last_step']})"
             if result["frames"] else ""))
    if "cycles" in result:
        print(f"  {result['cycles']} cycle records")
    print(f"  checkpoint: {'step ' + str(result['checkpoint_step']) if result['checkpoint_step'] is not None else 'none'}")
    if "energy_last" in result:
        e = result["energy_last"]
        print(f"  last energies: kinetic {e['kinetic']:.6g}, stored {e['stored']:.6g}, balance {e['balance']:.6g}")
    if result.get("protocol"):
        from .io.jsonsafe import jsonable

        print(f"  protocol: {json.dumps(jsonable(result['protocol']))}")


LAW_OPTIONS = {"friction": ("--mu", "mu"), "normal_stiffness": ("--kn", "K_n"),
               "tangential_stiffness": ("--kt", "K_t")}
"""The contact law's values ``analyze`` takes from its options when a file carries none: option, symbol."""


def _analyze(args) -> dict:
    from .analysis.plausibility import implausible
    from .analysis.report import analyze
    from .analysis.states import read_state

    given = {key: getattr(args, option[2:]) for key, (option, _) in LAW_OPTIONS.items()
             if getattr(args, option[2:]) is not None}
    columns = tuple(args.contact_columns.replace(",", " ").split()) if args.contact_columns else None
    state = read_state(args.runfile, args.frame, law=given, contacts=args.contacts, contact_columns=columns)
    warnings = implausible(state)
    for warning in warnings:  # before the work: a wrong reading is told at once
        print(f"granlab analyze: warning: {warning}", file=sys.stderr, flush=True)
    result = analyze(state, args.analysis, load=args.load, seed=args.seed).as_dict()
    result.update(run_file=args.runfile, source=state.source, particles=state.disks, forces_known=state.forces_known,
                  law={"friction": state.law.friction, "normal_stiffness": state.law.normal_stiffness,
                       "tangential_stiffness": state.law.tangential_stiffness,
                       "assumed": [] if state.law_given else [key for key in LAW_OPTIONS if key not in given]},
                  warnings=warnings)
    return result


def _print_analysis(result) -> None:
    """The rows of the report (:meth:`granlab.engine.analysis.report.AnalysisReport.rows`) that ``result``
    (a :class:`granlab.engine.analysis.report.ReportDict`) keeps: "label: text  (note)", the texts aligned."""
    print(f"{result['analysis']} of {result['source']} ({result['particles']} disks"
          + ("" if result["forces_known"] else "; contacts from the geometry, no forces") + ")")
    law = result["law"]
    if law["assumed"]:
        values = {key: f"{LAW_OPTIONS[key][1]} = {law[key]:g}" for key in LAW_OPTIONS}
        given = [values[key] for key in LAW_OPTIONS if key not in law["assumed"]]
        print("  contact law assumed, the file carries none: "
              + ", ".join(f"{values[key]} ({LAW_OPTIONS[key][0]})" for key in law["assumed"])
              + (f"; given: {', '.join(given)}" if given else ""))
    rows = result.report.rows()
    width = max((len(row.label) for row in rows), default=0) + 1
    for row in rows:
        print(f"  {row.label + ':':<{width}} {row.text}" + (f"  ({row.note})" if row.note else ""))
    print("  time: " + ", ".join(f"{k} {v:.3g} s" for k, v in result["timings_s"].items()))


ROLLING_DAMPING_HELP = ("damping ratio of a viscous rolling moment with --rolling (default 0.8; 0 is Gilabert's "
                        "undamped rolling spring, with which a disk held by one contact never stops swinging)")


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"{value} is not allowed: a whole number > 0")
    return value


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose errors are one line, as every other error of the command: the
    usage block argparse prints first would bury the line that says what is wrong."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="granlab", description="GranLab: 2D granular mechanics lab")
    parser.add_argument("--version", action="version", version=f"%(prog)s {version('granlab')}")
    commands = parser.add_subparsers(dest="command", required=True)
    for add in (_add_run, _add_experiment, _add_bench, _add_prepare, _add_study, _add_reproduce, _add_analyze,
                _add_quasistatic, _add_info, _add_compile):
        add(commands)
    return parser


def _add_run(commands) -> None:
    run = commands.add_parser("run", help="run a TOML scene (a path or a built-in name)")
    run.add_argument("scene", nargs="?", default="default", help="scene file or built-in name (default: default)")
    run.add_argument("--out", help="write a run file (HDF5, H5MD)")
    run.add_argument("--frame-every", type=_positive_int, help="steps between frames (default: record_every)")
    run.add_argument("--resume", metavar="RUNFILE", help="continue a run file from its checkpoint to the end of its scene "
                                                         "(into --out, default RUNFILE-resumed.h5; never RUNFILE itself)")
    run.add_argument("--force", action="store_true", help="write over an existing --out file")
    run.add_argument("--checkpoint-every", type=_positive_int, default=10, metavar="K",
                     help="a checkpoint every K frames (default 10), so a killed run resumes from it")
    run.add_argument("--checkpoint-seconds", type=_float, default=60.0, metavar="S",
                     help="... or once S seconds of wall time have passed since the last (default 60)")
    run.add_argument("--json", action="store_true", help="print one JSON object")
    run.set_defaults(handler=lambda a: run_scene(None if a.resume else a.scene, a.out, a.frame_every, a.resume, a.force,
                                                 a.checkpoint_every, a.checkpoint_seconds, _run_progress()),
                     printer=_print_run)


def _add_experiment(commands) -> None:
    experiment = commands.add_parser("experiment", help="a teaching experiment against its formula")
    experiment.add_argument("name", choices=("collision", "closed-path", "block"))
    experiment.add_argument("--model", default="cundall-strack", choices=TANGENTIAL_MODELS + ("all",),
                            help="tangential spring model (all: each registered model in turn)")
    experiment.add_argument("--zeta", type=_float, help="normal damping ratio zeta in [0, 1)")
    experiment.add_argument("--mu", type=_float, help="friction coefficient (inf: no sliding)")
    experiment.add_argument("--dt", type=_float, help="time step (default: from the stability bound)")
    experiment.add_argument("--json", action="store_true", help="print one JSON object")
    experiment.set_defaults(handler=_experiment, printer=_print_experiment)


def _add_bench(commands) -> None:
    bench = commands.add_parser("bench", help="particle-steps per second on the LAMMPS reference system")
    bench.add_argument("--steps", type=int, help="timed steps (default 5000; with --scaling 1000 at each size)")
    bench.add_argument("--scaling", action="store_true",
                       help="the reference system at 10^3, 10^4, 10^5 and 10^6 disks on one thread: particle-steps "
                            "per second, bytes per disk and the share of rebuilds at each size (a minute or two)")
    bench.add_argument("--model", default="cundall-strack", choices=TANGENTIAL_MODELS,
                       help="tangential model (lammps: integrated as LAMMPS does it)")
    bench.add_argument("--profile", action="store_true",
                       help="where a particle-step goes on one thread: contact pass per row, pass over the disks, "
                            "the rest, a rebuild")
    bench.add_argument("--side", type=int, default=100, help="disks per side of the lattice (default 100: 10 000)")
    bench.add_argument("--analysis", metavar="PACKING.h5",
                       help="time every analysis of 'granlab analyze' on this packing instead (prepared there by "
                            "method 1 if missing)")
    bench.add_argument("--beside-engine", action="store_true",
                       help="with --analysis: run each analysis beside a simulation of the packing on one thread, "
                            "with every core and with the cores it leaves free, as in the lab")
    bench.add_argument("--particles", type=_positive_int, help="disks of a prepared packing or of the lab (default 5600)")
    bench.add_argument("--json", action="store_true", help="print one JSON object")
    bench.set_defaults(handler=_bench, printer=_print_bench)


def _add_prepare(commands) -> None:
    prepare = commands.add_parser("prepare", help="prepare a packing in equilibrium")
    prepare.add_argument("--method", required=True, choices=("compress", "1", "2"),
                         help="compress: ratcheting biaxial box; 1, 2: Gilabert's methods")
    prepare.add_argument("--particles", type=_positive_int, default=None, help="number of disks")
    prepare.add_argument("--seed", type=int, default=0)
    prepare.add_argument("--pressure", type=_float, default=None,
                         help="P (compress: P0 = 1 in paper units; Gilabert: P* a F0 or P with kappa = K_N/P)")
    prepare.add_argument("--mu", type=_float, help="friction (compress: switched on after compression, 0.2)")
    prepare.add_argument("--solid-fraction", type=_float, default=0.36, help="initial gas fraction Phi_I (1, 2)")
    prepare.add_argument("--kappa", type=_float, default=1e5, help="stiffness parameter kappa (1, 2)")
    prepare.add_argument("--cohesive", action="store_true", help="method 1 with cohesion (method 2 always is)")
    prepare.add_argument("--rolling", action="store_true", help="rolling resistance (Gilabert Table I)")
    prepare.add_argument("--rolling-damping", type=_float, default=0.8, metavar="ZETA_R",
                         help=ROLLING_DAMPING_HELP)
    prepare.add_argument("--speed", type=_float, help="V0 of method 2 (default V* = sqrt(F0 D0))")
    prepare.add_argument("--accelerated", action="store_true", help="method 2 series B: soft, then stiffened")
    prepare.add_argument("--max-time", type=_float, help="simulated-time limit of each stage")
    prepare.add_argument("--dt-safety", type=_float, metavar="F",
                         help=f"methods 1 and 2: the time step as a fraction F of the stability bound, in (0, 1] "
                              f"(default {GILABERT_DT_SAFETY}; 0.3 until 27 Nov 2026)")
    prepare.add_argument("--out", help="write the packing to a run file")
    prepare.add_argument("--force", action="store_true", help="write over an existing --out file")
    prepare.add_argument("--json", action="store_true", help="print one JSON object")
    prepare.set_defaults(handler=_prepare_with_defaults, printer=_print_prepare)


def _add_study(commands) -> None:
    study = commands.add_parser("study", help="studies of many samples on Dask")
    kinds = study.add_subparsers(dest="kind", required=True)
    ratchet = kinds.add_parser("ratchet", help="cyclic loading of biaxial boxes (ratcheting Sec. IV B)")
    ratchet.add_argument("--particles", type=_positive_int, default=16)
    ratchet.add_argument("--samples", type=_positive_int, default=10)
    ratchet.add_argument("--cycles", type=_positive_int, default=100)
    ratchet.add_argument("--model", default="cundall-strack", choices=TANGENTIAL_MODELS + ("all",))
    ratchet.add_argument("--phase", type=_float, help="elliptic loading with this phase (degrees; Eqs. 4-5)")
    ratchet.add_argument("--mu", type=_float, default=0.2, help="friction during cycling (inf: no sliding)")
    ratchet.add_argument("--dt-factor", type=_float, default=0.2, help="dt = f sqrt(m_min / K_n) (default 0.2)")
    ratchet.add_argument("--amplitude", type=_float, nargs="+", default=[0.2], metavar="A",
                         help="Delta sigma in units of P0 (default 0.2); several: a sweep, the same samples at each "
                              "(with --out, a folder amplitude-A for each)")
    ratchet.add_argument("--period", type=_float, default=10.0, help="cycle period in tau (default 10)")
    ratchet.add_argument("--reference-cycle", type=int,
                         help="cycle defining L0 (default 30 %% of --cycles, at most cycles - 3: 30 of 100)")
    ratchet.add_argument("--zero-mean", action="store_true",
                         help="cycle the load about P0 (q = -Delta sigma cos wt): its mean isotropic, not Eq. 1's "
                              "P0 + Delta sigma on the top wall")
    ratchet.add_argument("--gravity", type=_float, default=0.0, help="weak gravity (Sec. IV B 3)")
    ratchet.add_argument("--seed", type=int, default=0, help="first seed")
    ratchet.add_argument("--watch", type=int, default=0, metavar="K",
                         help="record every contact's (F_n, F_t, status) K times per cycle in the run files")
    ratchet.add_argument("--scheduler", help="address of an existing Dask scheduler (default: local cluster)")
    ratchet.add_argument("--out", help="folder for the run files (one per sample and model)")
    ratchet.add_argument("--force", action="store_true", help="write over run files already in --out")
    ratchet.add_argument("--json", action="store_true", help="print one JSON object")
    ratchet.set_defaults(handler=_study, printer=_print_study)


def _add_reproduce(commands) -> None:
    reproduce = commands.add_parser("reproduce", help="reproduce a paper's table on Dask, beside the published values")
    reproduce.add_argument("table", choices=tuple(REPRODUCTIONS),
                           help="Gilabert et al. method 1 (Tables II, III) or method 2 (Tables IV, V, VII)")
    reproduce.add_argument("--paper-size", action="store_true",
                           help="the paper's size: 1400 disks, 4 samples per case (--particles and --samples "
                                "still override: --particles 5600 --samples 3 is method 2's larger series)")
    reproduce.add_argument("--samples", type=_positive_int, help="samples per case (default 2)")
    reproduce.add_argument("--particles", type=_positive_int, help="disks per sample (default 100)")
    reproduce.add_argument("--max-time", type=_float,
                           help="simulated-time limit of each preparation stage, in T0 (default 500)")
    reproduce.add_argument("--rolling-damping", type=_float, metavar="ZETA_R", help=ROLLING_DAMPING_HELP)
    reproduce.add_argument("--cell-mass-disks", type=_positive_int, metavar="N",
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
    reproduce.add_argument("--threads-per-sample", type=_positive_int, metavar="T",
                           help="threads each sample runs on (default 1; the local cluster then has a worker per T "
                                "cores): for fewer samples than cores; from 1000 disks on, a sample on T threads "
                                "is another sample than on one")
    reproduce.add_argument("--dt-safety", type=_float, metavar="F",
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
    reproduce.add_argument("--workers", type=_positive_int, help="local Dask workers (default: one per core)")
    reproduce.add_argument("--scheduler", help="address of an existing Dask scheduler (default: local cluster)")
    reproduce.add_argument("--json", action="store_true", help="print one JSON object")
    reproduce.set_defaults(handler=_reproduce, printer=_print_reproduce)


def _add_analyze(commands) -> None:
    analyze = commands.add_parser("analyze", help="quasi-static and structural analysis of one frame of a run file, "
                                                  "an H5MD file, a LAMMPS dump or an extended XYZ file")
    analyze.add_argument("runfile", metavar="FILE",
                         help="a GranLab run file, an H5MD file with positions, radii and a 2D box, a LAMMPS dump "
                              "custom (id x y radius|diameter) or an extended XYZ file (radius, Lattice, pbc)")
    analyze.add_argument("analysis", choices=ANALYSES,
                         help="; ".join(f"{name}: {analysis.title}" for name, analysis in ANALYSES.items()))
    analyze.add_argument("--frame", type=int, default=-1, help="frame index (negative counts from the end; default -1)")
    analyze.add_argument("--load", choices=LOADS, default="auto",
                         help="load increment of stiffness and status (default auto: the walls' loads, else random; "
                              "cell: the target stress of a cell under stress control)")
    analyze.add_argument("--seed", type=int, default=0, help="seed of the random load increment")
    analyze.add_argument("--mu", type=_float,
                         help="friction coefficient to assume (default: the run's; other codes' files: 0.5)")
    analyze.add_argument("--kn", type=_float, help="normal stiffness K_n to assume (default: the run's; else 1000)")
    analyze.add_argument("--kt", type=_float, help="tangential stiffness K_t to assume (default: the run's; else 1000)")
    analyze.add_argument("--contacts", metavar="FILE",
                         help="a LAMMPS dump local of the contacts (compute pair/local) at the dump's timesteps")
    analyze.add_argument("--contact-columns", metavar="NAMES",
                         help="what each column of --contacts holds, in order: id1 id2 fx fy [ftx fty], - for a "
                              "column to leave out (default: the names in its header)")
    analyze.add_argument("--json", action="store_true", help="print one JSON object")
    analyze.set_defaults(handler=_analyze, printer=_print_analysis)


def _add_quasistatic(commands) -> None:
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
    quasistatic.add_argument("--steps", type=_positive_int, default=100, help="load steps (default 100)")
    quasistatic.add_argument("--compare", type=_float, nargs="+", default=[], metavar="T",
                             help="ramp the same load in the dynamics over each duration T and report how far each "
                                  "end is from the quasi-static one")
    quasistatic.add_argument("--check-unique", action="store_true",
                             help="enumerate every state of up to 10 critical contacts at each step and count the "
                                  "consistent ones (the principle of minimum sliding says one)")
    quasistatic.add_argument("--json", action="store_true", help="print one JSON object")
    quasistatic.set_defaults(handler=_quasistatic, printer=_print_quasistatic)


def _quasistatic_targets(args):
    from .protocols.quasistatic import Targets

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

    from .io import h5md
    from .io.scene import load_scene

    if Path(start).is_file() and h5py.is_hdf5(start):
        return h5md.resume(start)[0]
    scene = load_scene(start)
    sim = scene.build()
    sim.run(scene.step_count(sim.dt))
    return sim


def _quasistatic(args) -> dict:
    import numpy as np

    from .protocols.quasistatic import STOP_REASONS, compare

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


def _add_info(commands) -> None:
    info = commands.add_parser("info", help="summarise a run file")
    info.add_argument("runfile")
    info.add_argument("--json", action="store_true", help="print one JSON object")
    info.set_defaults(handler=_info, printer=_print_info)


def _add_compile(commands) -> None:
    from .compilation import KERNEL_SETS

    compile_ = commands.add_parser("compile", help="compile every kernel now (a first run then starts at once): the "
                                                   "night before a class, or after an upgrade")
    compile_.add_argument("--only", nargs="+", choices=tuple(KERNEL_SETS), metavar="SET",
                          help="these kernel sets only: " + ", ".join(KERNEL_SETS))
    compile_.add_argument("--workers", type=_positive_int, help="processes compiling side by side (default: one a "
                                                                "core)")
    compile_.add_argument("--json", action="store_true", help="print one JSON object")
    compile_.set_defaults(handler=_compile, printer=_print_compile)


def _compile(args) -> dict:
    import numba

    from .compilation import KERNEL_SETS, compile_sets
    from .kernels.cache import cache_root

    start = time.perf_counter()
    names = args.only or tuple(KERNEL_SETS)
    if numba.config.NUMBA_NUM_THREADS < 2:  # one core: nothing runs the several-thread code
        names = [name for name in names if not name.endswith("-threads")]
    compiled = compile_sets(names, workers=args.workers)
    return {"compiled": compiled, "already": [name for name in names if name not in compiled],
            "seconds": time.perf_counter() - start, "cache": str(cache_root())}


def _print_compile(result: dict) -> None:
    if result["compiled"]:
        print(f"compiled {len(result['compiled'])} kernel sets in {result['seconds']:.0f} s "
              f"({len(result['already'])} were compiled before), kept in {result['cache']}")
    else:
        print(f"every kernel set was compiled before ({len(result['already'])}), kept in {result['cache']}")


def _prepare_with_defaults(args) -> dict:
    defaults = {"compress": (16, 1.0), "1": (200, 1e-2), "2": (200, 1e-2)}[args.method]
    if args.particles is None:
        args.particles = defaults[0]
    if args.pressure is None:
        args.pressure = defaults[1]
    return _prepare(args)


def main(argv: list[str] | None = None) -> int:
    return run_args(build_parser().parse_args(argv))


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised as Ctrl-C's KeyboardInterrupt is, so that a command stopped either way
    unwinds: its hidden part files are removed and its run file closed whole."""


def _terminate(signum, frame):
    raise Terminated()


def run_args(args) -> int:
    """Run a parsed command: print its result (or one JSON object); errors exit with status 2,
    Ctrl-C with 130 and SIGTERM with 143, each after one line on standard error."""
    main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _terminate) if main_thread else None
    try:
        result = _handle(args)
    except KeyboardInterrupt as stop:
        terminated = isinstance(stop, Terminated)
        print(f"granlab {args.command}: stopped by {'SIGTERM' if terminated else 'Ctrl-C'}", file=sys.stderr)
        return 143 if terminated else 130
    finally:
        if main_thread:
            signal.signal(signal.SIGTERM, previous)
    if isinstance(result, GranLabError):
        print(f"granlab {args.command}: error: {one_line(str(result))}", file=sys.stderr)
        return 2
    return _print_result(args, result)


def _handle(args):
    """The command's result, or the GranLabError that tells why there is none."""
    from .compilation import announced

    source = next((getattr(args, name) for name in ("runfile", "resume") if getattr(args, name, None)), None)
    try:
        if source is not None and Path(source).is_file():
            from .io import h5md

            h5md.probe(source)
        with announced():
            return args.handler(args)
    except RegistryError as error:  # the engine does not import: a run file cannot be judged with it
        return error
    except WriteFailed as error:
        print(f"granlab {args.command}: error: {one_line(str(error))}", file=sys.stderr, flush=True)
        sys.stdout.flush()
        os._exit(2)  # see WriteFailed: an exit that closes the file would crash the process
    except Exception as error:
        from .io import h5md

        if isinstance(error, GranLabError) and not (source and isinstance(error, h5md.DamagedRunFile)):
            return error
        if source is None or not h5md.raised_by_damage(error):
            raise
        return h5md.damaged(source, error)


def _print_result(args, result) -> int:
    from .io.jsonsafe import jsonable

    try:
        if args.json:
            print(json.dumps(jsonable(result)))
        else:
            args.printer(result)
        sys.stdout.flush()
    except BrokenPipeError:
        # a reader that stopped early (granlab ... | head) had what it wanted; Python's own flush
        # at exit must not fail again
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
