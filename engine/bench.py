"""``granlab bench``: the standard system of ``shared/bench/lammps_reference.in``.

10 000 disks of diameter 1.02 on a unit square lattice in a periodic 100 × 100
box, unit mass, disc inertia, ``K_n = 1000``, ``K_t = 2 K_n / 7``, normal damping
``gamma_n = 50`` in LAMMPS's mass-velocity form (``eta = m_eff gamma_n``, so
``zeta = m_eff gamma_n / (2 sqrt(K_n m_eff))``), no tangential damping (the input's
``dampflag = 0``), ``mu = 0.5``, ``dt = 0.001``, random velocities of temperature 0.01;
every disk touches its 4 neighbours (2 contacts per disk). GranLab's Cundall-Strack law by
default; ``model="lammps"`` integrates it as LAMMPS does (half-step dashpots, Coulomb on F_n).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numba
import numpy as np

from .errors import GranLabError
from .params import ContactLaw, Integration, PeriodicCell
from .simulation import Simulation
from .state import ParticleState

WARMUP_STEPS = 100
TIMED_STEPS = 5000


def reference_system(side: int = 100, seed: int = 4928459, model: str = "cundall-strack") -> Simulation:
    """The LAMMPS reference system with ``side²`` disks (``side = 100``: 10 000), tangential ``model``."""
    grid = np.arange(side, dtype=np.float64)
    x, y = np.meshgrid(grid, grid, indexing="xy")
    positions = np.column_stack([x.ravel(), y.ravel()])
    n = positions.shape[0]
    rng = np.random.default_rng(seed)
    velocities = rng.normal(0.0, math.sqrt(0.01), size=(n, 2))
    velocities -= velocities.mean(axis=0)
    particles = ParticleState(positions, np.full(n, 0.51), velocity=velocities, mass=np.ones(n))
    m_eff = 0.5
    gamma_n = 50.0
    kn = 1000.0
    law = ContactLaw(normal_stiffness=kn, tangential_stiffness=2.0 * kn / 7.0, friction=0.5,
                     damping_ratio=m_eff * gamma_n / (2.0 * math.sqrt(kn * m_eff)), tangential_model=model)
    integration = Integration(dt=0.001, skin=0.1)
    return Simulation(particles, law, integration, cell=PeriodicCell(lengths=(float(side), float(side))))


def measure(threads: int, steps: int = TIMED_STEPS, side: int = 100, model: str = "cundall-strack") -> dict:
    """Particle-steps per second of the reference system on ``threads`` threads."""
    previous = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        sim = reference_system(side, model=model)
        sim.run(WARMUP_STEPS)
        start = time.perf_counter()
        sim.run(steps)
        elapsed = time.perf_counter() - start
    finally:
        numba.set_num_threads(previous)
    n = sim.particles.count
    return {"threads": threads, "particles": n, "steps": steps, "seconds": elapsed,
            "particle_steps_per_s": n * steps / elapsed,
            "contacts_per_disk": sim.contact_snapshot().count / n}


def run(steps: int = TIMED_STEPS, side: int = 100, model: str = "cundall-strack") -> dict:
    """Measure on one thread and on all threads (``side`` < 100: a smaller system, for tests)."""
    one = measure(1, steps, side, model)
    every = numba.config.NUMBA_NUM_THREADS
    allt = measure(every, steps, side, model)
    return {
        "system": f"lammps_reference.in: {side * side} disks, periodic {side}x{side}, {model}, dt=0.001",
        "particle_steps_per_s_1thread": one["particle_steps_per_s"],
        "particle_steps_per_s_all": allt["particle_steps_per_s"],
        "threads_all": every,
        "speedup": allt["particle_steps_per_s"] / one["particle_steps_per_s"],
        "contacts_per_disk": one["contacts_per_disk"],
        "particles": one["particles"],
        "steps": steps,
    }


def device(steps: int = TIMED_STEPS, side: int = 100, model: str = "cundall-strack") -> dict:
    """Particle-steps per second of the reference system on the CUDA backend (its state sent to the device and
    brought back once, as every run on it: those copies are timed too)."""
    from .cuda.transfer import CROSSED

    sim = reference_system(side, model=model)
    sim.use_backend("cuda")
    sim.run(WARMUP_STEPS)  # the kernels compile at their first launch
    crossed = sum(CROSSED.values())
    start = time.perf_counter()
    sim.run(steps)
    elapsed = time.perf_counter() - start
    n = sim.particles.count
    return {"system": f"lammps_reference.in: {n} disks, periodic {side}x{side}, {model}, dt=0.001, CUDA backend",
            "backend": "cuda", "particles": n, "steps": steps, "seconds": elapsed,
            "particle_steps_per_s": n * steps / elapsed, "bytes_crossed": sum(CROSSED.values()) - crossed}


def device_check(steps: int, side: int = 100, model: str = "cundall-strack") -> dict:
    """The reference system after ``steps`` steps on the device beside the CPU engine
    (:func:`granlab.engine.cuda.check.compare`)."""
    from .cuda.check import compare

    result = compare(lambda: reference_system(side, model=model), steps)
    return {"system": f"lammps_reference.in: {side * side} disks, periodic {side}x{side}, {model}, dt=0.001",
            "backend": "cuda", "check": result, "exit_status": int(not result["worst"] <= result["tolerance"])}


BATCH_CYCLES = 3
"""Cycles of ``bench --batch``: the ratchet study's default period, about 3300 steps a cycle."""


def batch_study(samples: int = 100, backend: str = "cpu", alone_samples: int = 10, rounds: int = 3) -> dict:
    """A ratchet study's cycles (16 disks a sample, the study's defaults) two ways, alternated ``rounds``
    times, medians: ``samples`` prepared boxes side by side in one :class:`~granlab.engine.batch.Batch` on
    ``backend``, and ``alone_samples`` of them cycled one after another on one thread, each its own
    simulation on ``backend`` (as one Dask worker runs them). The preparation, the same for both, is left
    out; each time is for :data:`BATCH_CYCLES` cycles, and the ratio is per sample."""
    from .analysis.report import analysis_threads
    from .batch import Batch
    from .protocols.cyclic import run_cycles
    from .protocols.prepare import compress
    from .studies import RatchetStudy, _cycle_batch, model_sim

    study = RatchetStudy(particles=16, samples=samples, cycles=BATCH_CYCLES, backend=backend)
    boxes = [model_sim(compress(16, seed=seed, pressure=1.0, friction=study.friction).sim, study, "cundall-strack")
             for seed in range(samples)]
    alone = boxes[:alone_samples]

    def batched() -> float:
        start = time.perf_counter()
        _cycle_batch(Batch([box.clone() for box in boxes]), study, "cundall-strack", None)
        return time.perf_counter() - start

    def one_by_one() -> float:
        copies = [box.clone() for box in alone]
        start = time.perf_counter()
        with analysis_threads(1):
            for copy in copies:
                run_cycles(copy, study.load(), study.cycles)
        return time.perf_counter() - start

    batched(), one_by_one()  # compile, warm the caches
    batch_times, alone_times = [], []
    for _ in range(rounds):
        batch_times.append(batched())
        alone_times.append(one_by_one())
    batch_s, alone_s = float(np.median(batch_times)), float(np.median(alone_times))
    threads = numba.get_num_threads() if backend == "cpu" else None
    return {"system": f"ratchet study: {samples} samples of 16 disks, {BATCH_CYCLES} cycles of period "
                      f"{study.period:g}, Cundall-Strack, {backend}" + (f", {threads} threads" if threads else ""),
            "backend": backend, "samples": samples, "cycles": BATCH_CYCLES, "batch_s": batch_s,
            "alone_samples": len(alone), "alone_s": alone_s, "alone_per_sample_s": alone_s / len(alone),
            "batch_per_sample_s": batch_s / samples, "speedup_per_sample": alone_s / len(alone) / (batch_s / samples),
            "batch_times_s": batch_times, "alone_times_s": alone_times}


SCALING_SIDES = (32, 100, 316, 1000)
"""Sides of the lattices of ``bench --scaling``: about 10³, 10⁴, 10⁵ and 10⁶ disks."""
SCALING_STEPS = 1000
"""Steps timed at each size: the same simulated time everywhere, so that every size rebuilds its
table as often (the lattice's thermal motion uses up the skin every few hundred steps)."""


def state_bytes(sim: Simulation) -> int:
    """Bytes of the arrays a simulation steps with: disks, walls, cell, the contact table and its
    spare, the workspace."""
    parts = (sim.particles.arrays(), sim.walls.arrays(), sim.cell.arrays(), sim.contacts.arrays(),
             sim._spare.arrays(), sim.workspace)
    return sum(value.nbytes for part in parts for value in part if hasattr(value, "nbytes"))


def rebuild_seconds(sim: Simulation, repeats: int = 5) -> float:
    """Median wall time of one rebuild of the contact table of ``sim`` as it stands (what a step
    that needs one pays on top of its forces)."""
    from .kernels import integrate

    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        integrate.rebuild(sim.particles.arrays(), sim.walls.arrays(), sim.cell.arrays(), sim.contacts.arrays(),
                          sim._spare.arrays(), sim.workspace, sim._law_vector, sim.skin)
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def device_rebuild_seconds(sim: Simulation, repeats: int = 5) -> float:
    """Median wall time of one rebuild of the contact table of ``sim`` on the device
    (:class:`~granlab.engine.cuda.neighbours.DeviceTable`, its state there; the first, which compiles, not
    counted): what a run on the device pays for a rebuild, the state staying there."""
    from .cuda.neighbours import DeviceTable
    from .cuda.stepper import DeviceState
    from .kernels.laws import D0

    state = DeviceState(sim.particles.arrays(), sim.walls.arrays(), sim.cell.arrays(), sim.contacts.arrays(), sim.workspace)
    table = DeviceTable(state, sim.particles.radius, sim._law_vector[D0] + sim.skin)
    times = []
    for _ in range(repeats + 1):
        start = time.perf_counter()
        table.rebuild(state)  # reads its code back: the device is done when it returns
        times.append(time.perf_counter() - start)
    return float(np.median(times[1:]))


def scaling(sides=SCALING_SIDES, steps: int = SCALING_STEPS) -> dict:
    """The reference system at each of ``sides`` (N = side² disks), on one thread: particle-steps
    per second, nanoseconds per particle-step, bytes of state per disk, the cost of one rebuild of
    the contact table in steps (the median of five rebuilds timed apart) and the share of the time
    spent rebuilding (the rebuilds counted over the timed steps)."""
    from .kernels.integrate import INFO_REBUILDS

    previous = numba.get_num_threads()
    numba.set_num_threads(1)
    rows = []
    try:
        for side in sides:
            sim = reference_system(side)
            n = sim.particles.count
            sim.run(WARMUP_STEPS)
            rebuilds = sim.workspace.info[INFO_REBUILDS]
            start = time.perf_counter()
            sim.run(steps)
            elapsed = time.perf_counter() - start
            rebuilds = int(sim.workspace.info[INFO_REBUILDS] - rebuilds)
            one_rebuild = rebuild_seconds(sim)
            rows.append({"side": side, "particles": n, "steps": steps, "seconds": elapsed,
                         "particle_steps_per_s": n * steps / elapsed, "ns_per_particle_step": 1e9 * elapsed / (n * steps),
                         "bytes_per_disk": state_bytes(sim) / n, "rebuilds": rebuilds,
                         "rebuild_in_steps": one_rebuild / (elapsed / steps),
                         "rebuild_share": min(1.0, rebuilds * one_rebuild / elapsed)})
    finally:
        numba.set_num_threads(previous)
    best = min(row["ns_per_particle_step"] for row in rows)
    return {"system": "lammps_reference.in at each size, Cundall-Strack, dt=0.001, 1 thread", "sizes": rows,
            "worst_over_best": max(row["ns_per_particle_step"] for row in rows) / best}


def _best_seconds(call, repeats: int) -> float:
    """The fastest of five timings of ``repeats`` calls of ``call``, per call."""
    call()
    runs = []
    for _ in range(5):
        start = time.perf_counter()
        for _ in range(repeats):
            call()
        runs.append((time.perf_counter() - start) / repeats)
    return min(runs)


def profile(side: int = 100, steps: int = 1000) -> dict:
    """Where a particle-step of the reference system goes, on one thread: the whole step (``steps``
    steps in one call), the contact pass alone (per row of the contact table; also with every row
    computed directly, not over gathered blocks) and the pass over
    the disks alone (per disk, gathering the force buffers, two kicks and a drift of zero length,
    so the state does not change), the rest (walls, cell, tallies, checks) by difference, and one
    rebuild of the contact table (in steps)."""
    from .kernels import contacts, integrate

    previous = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        sim = reference_system(side)
        sim.run(WARMUP_STEPS)
        step = _best_seconds(lambda: sim.run(steps), 1) / steps
        p, w, cell, ct, ws = (sim.particles.arrays(), sim.walls.arrays(), sim.cell.arrays(), sim.contacts.arrays(),
                              sim.workspace)
        repeats = max(1, steps // 10)
        run = sim.run_options(sim.dt, 1)
        contact_forces = contacts.CONTACT_FORCES[sim.tangential_model_code]
        contact_pass = _best_seconds(lambda: contact_forces(p, w, cell, ct, ws, sim._law_vector, run, False, None),
                                     repeats)
        direct = run._replace(gathered=False)
        direct_pass = _best_seconds(lambda: contact_forces(p, w, cell, ct, ws, sim._law_vector, direct, False, None),
                                    repeats)
        particle_pass = _best_seconds(lambda: integrate.particle_pass(
            p, ws.force_buffer, ws.touched, 1, np.zeros(2), False, True, False, 0.0, 2, 0.0, 1.0, 1.0, ws.reference,
            ws.partial_gather, ws.gather, None), repeats)
        one_rebuild = rebuild_seconds(sim)
    finally:
        numba.set_num_threads(previous)
    n, rows = sim.particles.count, sim.contacts.count
    ns = 1e9 / n
    return {"system": f"lammps_reference.in: {n} disks, Cundall-Strack, dt=0.001, 1 thread", "particles": n,
            "rows": rows, "rows_per_disk": rows / n, "ns_per_particle_step": step * ns,
            "contact_pass_ns_per_disk": contact_pass * ns, "contact_pass_ns_per_row": contact_pass * 1e9 / rows,
            "direct_contact_pass_ns_per_row": direct_pass * 1e9 / rows,
            "particle_pass_ns_per_disk": particle_pass * ns,
            "other_ns_per_disk": (step - contact_pass - particle_pass) * ns,
            "rebuild_in_steps": one_rebuild / step}


ANALYSIS_PARTICLES = 5600


def prepared_packing(path: str | Path, particles: int = ANALYSIS_PARTICLES, seed: int = 1) -> float | None:
    """Make sure ``path`` holds a packing to analyse: if it does not exist, prepare one by
    Gilabert's method 1 (cohesionless, mu = 0.5, P/K_N = 1e-5, Phi_I = 0.36) and write it there.
    Returns the preparation's wall time (None if the file was there)."""
    from .io.h5md import RunWriter
    from .protocols.prepare import gilabert_law, method1

    path = Path(path)
    if path.exists():
        return None
    law = gilabert_law(friction=0.5, cohesion=False, pressure=1e-2)
    # the per-length cell mass made the packings docs/performance.md's analysis figures were measured on
    prepared = method1(count=particles, pressure=1e-2, law=law, seed=seed, cell_mass_reading="per-length")
    with RunWriter(path, prepared.sim, protocol={"command": "bench --analysis", "method": "1", "seed": seed,
                                                 "equilibrated": prepared.equilibrated}) as writer:
        writer.write_frame(prepared.sim)
        writer.write_checkpoint(prepared.sim)
    return prepared.wall_time_s


def analysis(path: str | Path, particles: int = ANALYSIS_PARTICLES, repeats: int = 2) -> dict:
    """Wall time of every analysis of ``granlab analyze`` on the packing in ``path`` (prepared
    there first if missing), each run ``repeats`` times (the first compiles or loads kernels);
    the figures are the fastest run."""
    from .analysis import ANALYSES
    from .analysis.report import analyze
    from .analysis.states import read_state

    preparation = prepared_packing(path, particles)
    state = read_state(path)
    timings, values = {}, {}
    for kind in ANALYSES:
        try:
            runs = [analyze(state, kind) for _ in range(repeats)]
        except GranLabError as error:  # e.g. a box too small for the fractal fit: report it, go on
            values[kind] = {"error": str(error)}
            continue
        best = min(runs, key=lambda report: report.timings["total"])
        timings[kind] = best.timings
        values[kind] = {k: v for k, v in best.values.items() if not isinstance(v, (list, tuple, dict))}

    def total(*kinds):
        return sum(timings[k]["total"] for k in kinds) if all(k in timings for k in kinds) else None

    return {"packing": str(path), "particles": state.disks, "contacts": int(state.contacts.count),
            "preparation_s": preparation, "timings_s": timings, "values": values,
            "stiffness_mechanisms_status_s": total("stiffness", "status"), "fractal_s": total("fractal")}


LAB_CHUNK_SECONDS = 0.02
"""The work the lab's engine thread does between two looks at its commands (it takes the GIL then)."""


def analysis_beside_engine(path: str | Path, particles: int = ANALYSIS_PARTICLES, engine_seconds: float = 3.0,
                           repeats: int = 3) -> dict:
    """The lab's case: a simulation of the packing in ``path`` steps on its own thread (one numba
    thread, as the lab's engine) while each analysis runs on the calling thread, first with every
    core (BLAS, FFT, numba) and then with the cores the engine leaves free
    (:data:`granlab.app.lab.analysis.ANALYSIS_THREADS`'s rule). Reports the engine's rate alone and
    during each analysis, and each analysis's time alone and beside the engine: medians of
    ``repeats`` runs, the two thread counts alternated. The engine's rate is counted at the end of
    its chunks of work (:data:`LAB_CHUNK_SECONDS`): an analysis shorter than five chunks has none."""
    import os
    import threading

    from .analysis import ANALYSES
    from .analysis.report import analyze
    from .analysis.states import read_state
    from .io.h5md import resume

    preparation = prepared_packing(path, particles)
    state = read_state(path)
    sim = resume(path)[0]
    free = max(1, (os.cpu_count() or 1) - 1)
    counter = {"steps": 0}
    stop, go = threading.Event(), threading.Event()

    def engine() -> None:
        numba.set_num_threads(1)
        start = time.perf_counter()
        sim.run(100)
        chunk = max(1, int(LAB_CHUNK_SECONDS * 100 / (time.perf_counter() - start)))
        while not stop.is_set():
            go.wait()
            if stop.is_set():
                return
            sim.run(chunk)
            counter["steps"] += chunk

    def engine_rate(seconds: float) -> float:
        start, steps = time.perf_counter(), counter["steps"]
        time.sleep(seconds)
        return (counter["steps"] - steps) / (time.perf_counter() - start)

    for kind in ANALYSES:  # compile or load every kernel first
        analyze(state, kind)
    alone = {kind: float(np.median([analyze(state, kind).timings["total"] for _ in range(repeats)]))
             for kind in ANALYSES}
    thread = threading.Thread(target=engine, daemon=True)
    thread.start()
    go.set()
    rate_alone = engine_rate(engine_seconds)
    rows = {}
    for kind in ANALYSES:
        runs = {"every_core": [], "free_cores": []}
        for _ in range(repeats):
            for name, threads in (("every_core", None), ("free_cores", free)):
                start, steps = time.perf_counter(), counter["steps"]
                report = analyze(state, kind, threads=threads)
                elapsed = time.perf_counter() - start
                share = (counter["steps"] - steps) / elapsed / rate_alone if elapsed >= 5 * LAB_CHUNK_SECONDS else None
                runs[name].append((report.timings["total"], share))
        row = {"alone_s": alone[kind]}
        for name, pairs in runs.items():
            row[f"{name}_s"] = float(np.median([t for t, _ in pairs]))
            shares = [share for _, share in pairs if share is not None]
            row[f"{name}_engine_share"] = float(np.median(shares)) if shares else None
        rows[kind] = row
    stop.set()
    go.set()
    thread.join()
    return {"packing": str(path), "particles": state.disks, "contacts": int(state.contacts.count),
            "preparation_s": preparation, "cores": os.cpu_count(), "free_threads": free,
            "engine_steps_per_s_alone": rate_alone, "beside_engine": rows}
