"""Speed on a machine with many cores (and a GPU): the reference system's particle-steps per second
by disks and threads, what a rebuild of the contact table costs, a ratchet study of 100 samples side by
side in one batch against its samples one by one, and, where numba finds a GPU, the CUDA backend: every
law beside the CPU engine, its contact table rebuilt beside the CPU engine's (row for row, and a rebuild's
time at each size), small systems stepped by one block against four launches a step, its speed at
10⁴-10⁶ disks and the batched study on it. One call, under four minutes on 16 cores; writes JSON.

    python docs/device.py --out device.json [--threads 1,2,4,8,16] [--quick] [--breakdown]

On a machine without a registry (the lent GPU machines), install the checkout first with
``docs/device.sh``, which runs this too.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

SIZES = ((100, 2000), (316, 1000), (1000, 200))
"""Lattice sides (10⁴, 10⁵, 10⁶ disks) and the steps timed at each: about a second and a half on one
thread at each size; the two smaller ones see the table rebuilt as often as ``granlab bench``'s
run does."""


def processor() -> dict:
    """What the figures were measured on: model, logical cores, vector extensions."""
    model, flags = platform.processor(), ""
    try:
        with open("/proc/cpuinfo") as info:
            for line in info:
                if line.startswith("model name") and not model:
                    model = line.split(":", 1)[1].strip()
                if line.startswith("flags") and not flags:
                    flags = line
    except OSError:
        pass
    vectors = [name for name in ("avx2", "avx512f", "fma") if f" {name}" in flags]
    return {"model": model, "cores": os.cpu_count(), "vectors": vectors}


def thread_table(threads: list[int], sizes=SIZES) -> list[dict]:
    """Particle-steps per second of the reference system at each size and thread count (the same
    simulation carried on from one count to the next), with the rebuilds in the timed steps and the
    time of one rebuild (serial) at each size."""
    import numba

    from granlab.engine import bench
    from granlab.engine.kernels.integrate import INFO_REBUILDS

    rows = []
    for side, steps in sizes:
        numba.set_num_threads(max(threads))
        built = time.perf_counter()
        sim = bench.reference_system(side)
        sim.run(20)
        built = time.perf_counter() - built
        rebuild = bench.rebuild_seconds(sim, repeats=3)
        for count in threads:
            numba.set_num_threads(count)
            sim.run(10)
            rebuilds = sim.workspace.info[INFO_REBUILDS]
            start = time.perf_counter()
            sim.run(steps)
            elapsed = time.perf_counter() - start
            rebuilds = int(sim.workspace.info[INFO_REBUILDS] - rebuilds)
            n = sim.particles.count
            rows.append({"particles": n, "threads": count, "steps": steps, "seconds": elapsed,
                         "particle_steps_per_s": n * steps / elapsed, "rebuilds": rebuilds,
                         "rebuild_seconds": rebuild, "rebuild_share": min(1.0, rebuilds * rebuild / elapsed),
                         "setup_seconds": built})
            print(f"{n:>8} disks {count:>2} threads: {n * steps / elapsed / 1e6:8.1f} M particle-steps/s, "
                  f"{rebuilds} rebuilds ({rebuild * 1e3:.1f} ms each)", flush=True)
    return rows


def breakdown(side: int, threads: int, steps: int = 200) -> dict:
    """Where a step of the reference system goes on ``threads`` threads: the whole step, its two parallel
    regions (the contact pass over the table's rows, the pass over the disks that gathers the chunk
    buffers, kicks and drifts) timed alone, what lies outside them, a rebuild of the table (serial) and
    how many steps lie between two, and the chunk buffers the disks' pass reads and zeroes a disk (their
    bytes: each 24 read and 24 written)."""
    import numba
    import numpy as np

    from granlab.engine import bench
    from granlab.engine.kernels import contacts, integrate
    from granlab.engine.kernels.integrate import INFO_REBUILDS

    numba.set_num_threads(threads)
    sim = bench.reference_system(side)
    sim.run(20)
    rebuilds = sim.workspace.info[INFO_REBUILDS]
    start = time.perf_counter()
    sim.run(steps)
    step = (time.perf_counter() - start) / steps
    rebuilds = int(sim.workspace.info[INFO_REBUILDS] - rebuilds)
    p, w, cell, ct, ws = sim.particles.arrays(), sim.walls.arrays(), sim.cell.arrays(), sim.contacts.arrays(), \
        sim.workspace
    run = sim.run_options(sim.dt, 1)
    parallel = None if run.n_chunks == 1 else True
    forces = contacts.CONTACT_FORCES[sim.tangential_model_code]
    repeats = max(1, steps // 4)
    contact = bench._best_seconds(lambda: forces(p, w, cell, ct, ws, sim._law_vector, run, False, parallel), repeats)
    disks = bench._best_seconds(lambda: integrate.particle_pass(
        p, ws.force_buffer, ws.touched, run.n_chunks, np.zeros(2), False, True, False, 0.0, 2, 0.0, 1.0, 1.0,
        ws.reference, ws.partial_gather, ws.gather, parallel), repeats)
    rebuild = bench.rebuild_seconds(sim, repeats=3)
    n = sim.particles.count
    reach = ws.touched[:run.n_chunks].astype(np.int64)
    buffers = float(np.maximum(reach[:, 1] - reach[:, 0] + 1, 0).sum()) / n  # each read and zeroed
    return {"particles": n, "threads": threads, "chunks": int(run.n_chunks), "step_s": step,
            "contact_pass_s": contact, "disk_pass_s": disks, "outside_s": step - contact - disks,
            "rebuild_s": rebuild, "steps_between_rebuilds": steps / rebuilds if rebuilds else None,
            "buffers_per_disk": buffers, "buffer_bytes_per_disk": buffers * 2 * ws.force_buffer.shape[2] * 8}


def cuda_probe() -> dict:
    """Whether numba's CUDA target compiles and runs a kernel with float64 atomics here, and what a
    launch costs. numba-cuda may still name ``numpy.row_stack`` (gone in numpy 2.5): aliased first."""
    import numpy as np

    if not hasattr(np, "row_stack"):
        np.row_stack = np.vstack
    try:
        from numba import cuda

        if not cuda.is_available():
            return {"available": False}

        @cuda.jit
        def scatter(values, index, total):
            k = cuda.grid(1)
            if k < values.shape[0]:
                cuda.atomic.add(total, index[k], values[k])

        n = 1 << 20
        values = cuda.to_device(np.ones(n))
        index = cuda.to_device((np.arange(n) % 1024).astype(np.int64))
        total = cuda.to_device(np.zeros(1024))
        scatter[(n + 255) // 256, 256](values, index, total)
        cuda.synchronize()
        launches = 200
        start = time.perf_counter()
        for _ in range(launches):
            scatter[(n + 255) // 256, 256](values, index, total)
        cuda.synchronize()
        elapsed = (time.perf_counter() - start) / launches
        sums = total.copy_to_host()
        device = cuda.get_current_device()
        return {"available": True, "device": device.name.decode() if isinstance(device.name, bytes) else device.name,
                "compute_capability": list(device.compute_capability), "atomics_correct": bool(
                    np.all(sums == (launches + 1) * n / 1024)), "seconds_per_launch_1M_atomics": elapsed}
    except Exception as error:  # the probe reports what failed; the table above stands
        return {"available": False, "error": f"{type(error).__name__}: {error}"}


CUDA_SIZES = ((100, 2000), (316, 2000), (1000, 1000))
"""Lattice sides and steps of the device's speed table (10⁴, 10⁵, 10⁶ disks)."""


ONE_BLOCK_SIDES = (4, 10, 23, 32)
"""Lattice sides (16 to 1024 disks, 32 to 2048 rows) timed in one block and in four launches a step."""


def one_block_table(steps: int = 3000) -> list[dict]:
    """The reference system's small sizes stepped by one block, 32 steps a launch, and by four launches a
    step: where the one block stops paying is where ``stepper.ONE_BLOCK_ROWS`` belongs."""
    from granlab.engine import bench
    from granlab.engine.cuda import stepper

    rows = []
    threshold = stepper.ONE_BLOCK_ROWS
    for side in ONE_BLOCK_SIDES:
        row = {"particles": side * side}
        for name, limit in (("one_block", threshold), ("four_launches", 0)):
            stepper.ONE_BLOCK_ROWS = limit
            try:
                row[name] = bench.device(steps, side)["particle_steps_per_s"]
            except Exception as error:  # each figure stands or fails alone
                row[name] = f"{type(error).__name__}: {error}"
        stepper.ONE_BLOCK_ROWS = threshold
        rows.append(row)
        print(f"{side * side:>8} disks on the device: one block {row['one_block']}, four launches "
              f"{row['four_launches']} particle-steps/s", flush=True)
    return rows


def rebuild_table(sides) -> list[dict]:
    """A rebuild of the reference system's contact table on the device, and on one CPU thread (the CPU engine's,
    which a run on the device took before, the state brought back and sent again besides), at each size."""
    from granlab.engine import bench

    rows = []
    for side in sides:
        sim = bench.reference_system(side)
        row = {"particles": side * side, "cpu_seconds": bench.rebuild_seconds(sim, repeats=3)}
        try:
            row["device_seconds"] = bench.device_rebuild_seconds(sim, repeats=3)
        except Exception as error:  # each figure stands or fails alone
            row["device_error"] = f"{type(error).__name__}: {error}"
        rows.append(row)
        print(f"{side * side:>8} disks, a rebuild: device {row.get('device_seconds')} s, CPU {row['cpu_seconds']:.4f} s",
              flush=True)
    return rows


def cuda_table(quick: bool) -> dict:
    """The CUDA backend: every law beside the CPU engine (tests/cuda_cases.py, on the GPU itself), the
    reference system's check after 200 steps, and its particle-steps per second at each size."""
    import subprocess
    import sys

    from granlab.engine import bench

    result: dict = {"cases": [], "checks": [], "speed": []}
    cases = subprocess.run([sys.executable, os.path.join(os.path.dirname(__file__), "..", "tests", "cuda_cases.py")],
                           capture_output=True, text=True, timeout=300)
    result["cases"] = [json.loads(line) for line in cases.stdout.splitlines() if line.startswith("{")]
    if cases.returncode:
        result["cases_error"] = cases.stderr[-2000:]
    rebuilt = subprocess.run([sys.executable, os.path.join(os.path.dirname(__file__), "..", "tests", "cuda_rebuild.py")],
                             capture_output=True, text=True, timeout=300)
    result["rebuild_cases"] = [json.loads(line) for line in rebuilt.stdout.splitlines() if line.startswith("{")]
    if rebuilt.returncode:
        result["rebuild_cases_error"] = rebuilt.stderr[-2000:]
    result["rebuild"] = rebuild_table([side for side, _ in (CUDA_SIZES[:2] if quick else CUDA_SIZES)])
    for model in ("cundall-strack", "lammps"):
        try:
            result["checks"].append(bench.device_check(200, side=32, model=model))
        except Exception as error:  # each figure stands or fails alone
            result["checks"].append({"model": model, "error": f"{type(error).__name__}: {error}"})
    result["one_block"] = one_block_table()
    try:
        result["batch"] = bench.batch_study(100, "cuda", alone_samples=3)
    except Exception as error:
        result["batch"] = {"error": f"{type(error).__name__}: {error}"}
    for side, steps in CUDA_SIZES[:2] if quick else CUDA_SIZES:
        try:
            row = bench.device(steps, side)
        except Exception as error:
            row = {"particles": side * side, "error": f"{type(error).__name__}: {error}"}
        result["speed"].append(row)
        print(f"{side * side:>8} disks on the device: {row.get('particle_steps_per_s', 0) / 1e6:8.1f} M particle-steps/s "
              f"{row.get('error', '')}", flush=True)
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="device.json")
    parser.add_argument("--threads", default="1,2,4,8,16")
    parser.add_argument("--quick", action="store_true", help="10⁴ and 10⁵ disks only (a check of the script)")
    parser.add_argument("--breakdown", action="store_true", help="where a step goes, at each size and thread count")
    args = parser.parse_args()
    import numba

    threads = [t for t in map(int, args.threads.split(",")) if t <= numba.config.NUMBA_NUM_THREADS]
    began = time.perf_counter()
    result = {"processor": processor(), "numba": numba.__version__, "cuda": cuda_probe()}
    if result["cuda"].get("available"):
        result["cuda_backend"] = cuda_table(args.quick)
    result["table"] = thread_table(threads, SIZES[:2] if args.quick else SIZES)
    from granlab.engine import bench

    result["batch_cpu"] = bench.batch_study(100, "cpu")
    if args.breakdown:
        result["breakdown"] = [breakdown(side, count) for side, _ in (SIZES[:2] if args.quick else SIZES)
                               for count in threads]
    result["seconds"] = time.perf_counter() - began
    with open(args.out, "w") as out:
        json.dump(result, out, indent=1)
    print(json.dumps(result["cuda"]), f"{result['seconds']:.0f} s", flush=True)


if __name__ == "__main__":
    main()
