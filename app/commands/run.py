"""``granlab run [SCENE] [--json]``: run a TOML scene (a path or a built-in name; default: the built-in
``default`` scene), or resume a run file, and print a summary or one JSON object."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from granlab.engine import costs
from granlab.engine.errors import DivergenceError
from granlab.engine.params import BACKENDS, TANGENTIAL

from .options import number, positive_int


def run_scene(name: str | None, out: str | None = None, frame_every: int | None = None,
              resume: str | None = None, force: bool = False, checkpoint_frames: int = 10,
              checkpoint_seconds: float = 60.0, progress=None, backend: str = "cpu") -> dict:
    """Run a scene to its end (or continue a run file from its checkpoint); returns the final
    state, energy budget and recorded series.

    With ``out`` a run file gets a frame every ``frame_every`` steps (default: the scene's
    ``record_every``; a resumed run keeps its file's) and a checkpoint with the frame every
    ``checkpoint_frames`` frames or once ``checkpoint_seconds`` of wall time have passed since
    the last, and at the end: a killed run resumes from the last one, bit for bit. A diverging
    run writes its restored last good state as the last checkpoint. ``out`` is never the resumed
    file, and an existing ``out`` is written over only with ``force``. ``progress(done, total,
    sim)`` is called about four times a second of wall time (the steps run in slices that long;
    a run split so continues bit for bit), not after the last slice: the result follows. ``backend``: where
    the steps run (:attr:`granlab.engine.simulation.Simulation.backend`)."""
    import numba

    from granlab.engine.compilation import compile_sets, step_sets
    from granlab.engine.cuda import check_backend
    from granlab.engine.io import h5md
    from granlab.engine.io.outputs import check_output
    from granlab.engine.io.scene import load_scene, parse_scene
    from granlab.engine.params import positive
    from granlab.engine.simulation import PARALLEL_MIN_DISKS, UNBOOKED_SHARE

    positive("--checkpoint-seconds", checkpoint_seconds, allow_inf=True)
    check_backend(backend)
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
    sim.use_backend(backend)
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

    start_energy = sim.energy()
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
        unbooked = sim.energy().unbooked_share(start_energy)
        if abs(unbooked) > UNBOOKED_SHARE:
            note = (f"the energy balance drifted by {100 * unbooked:+.3g} % of the energy the run turned over, more "
                    f"than {100 * UNBOOKED_SHARE:g} %: the time step is too large for this run (a smaller "
                    f"simulation.dt_safety or dt)")
            print(f"granlab run: warning: {note}", file=sys.stderr, flush=True)
            if writer is not None:
                writer.write_note(note)
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
    from granlab.engine.io import h5md

    need = h5md.run_file_bytes(sim, frames)
    costs.check_disk(need, Path(out).absolute().parent, f"--out {out!r}: {frames} frames of {sim.particles.count} disks",
                     fewer="fewer frames (--frame-every, simulation.record_every)")
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


def add(commands) -> None:
    run = commands.add_parser("run", help="run a TOML scene (a path or a built-in name)")
    run.add_argument("scene", nargs="?", default="default", help="scene file or built-in name (default: default)")
    run.add_argument("--out", help="write a run file (HDF5, H5MD)")
    run.add_argument("--frame-every", type=positive_int, help="steps between frames (default: record_every)")
    run.add_argument("--resume", metavar="RUNFILE", help="continue a run file from its checkpoint to the end of its scene "
                                                         "(into --out, default RUNFILE-resumed.h5; never RUNFILE itself)")
    run.add_argument("--force", action="store_true", help="write over an existing --out file")
    run.add_argument("--checkpoint-every", type=positive_int, default=10, metavar="K",
                     help="a checkpoint every K frames (default 10), so a killed run resumes from it")
    run.add_argument("--checkpoint-seconds", type=number, default=60.0, metavar="S",
                     help="... or once S seconds of wall time have passed since the last (default 60)")
    run.add_argument("--backend", choices=BACKENDS, default="cpu",
                     help="where the steps run: the CPU's threads (default), or an NVIDIA GPU (numba.cuda)")
    run.add_argument("--json", action="store_true", help="print one JSON object")
    run.set_defaults(handler=lambda a: run_scene(None if a.resume else a.scene, a.out, a.frame_every, a.resume, a.force,
                                                 a.checkpoint_every, a.checkpoint_seconds, _run_progress(),
                                                 a.backend),
                     printer=_print_run)
