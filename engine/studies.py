"""Studies of many samples on Dask: the ratchet study of McNamara, García-Rojo & Herrmann (Sec. IV B).

Each sample is prepared once (:func:`granlab.engine.protocols.prepare.compress`) and then cycled with
each requested tangential model, writing one run file per model and sample. Samples run in
parallel on a dask.distributed cluster (:func:`run_tasks`, shared with :mod:`granlab.engine.reproduce`): a
local one on all cores (one single-threaded worker process per core), or an existing one given by
its scheduler address.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import signal
import sys
import threading
import time
import traceback
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np

from . import costs, stopping
from .analysis.ratchet import (VERDICT_RULES, RatchetVerdict, deviatoric_strain, judge, ratchet_verdict,
                              share_statistics)
from .batch import Batch
from .cuda import check_backend
from .errors import DivergenceError, GranLabError, ParameterError
from .io.h5md import RunWriter
from .io.outputs import check_output, staged
from .observables import columns, touching
from .params import STUDY_LIMITS, TANGENTIAL_MODELS, finite, friction_coefficient, nonnegative, positive, whole
from .protocols.cyclic import CyclicLoad, run_cycles, wall_loads
from .protocols.prepare import biaxial_law, compress
from .simulation import stability_bound

POLL_SECONDS = 0.2
"""How often a study waiting for its samples looks whether it was asked to stop."""


@dataclass(frozen=True)
class RatchetStudy:
    """The settings of a ratchet study (paper units: box L = 1, pressure p = 1, density 1).

    ``dt_factor`` sets ``dt = dt_factor sqrt(m_min / K_n)`` (ratcheting Fig. 14); ``phase`` turns
    on elliptic loading (Eqs. 4-5); ``zero_mean`` cycles about P0 rather than above it
    (:class:`~granlab.engine.protocols.cyclic.CyclicLoad`); ``gravity`` is the weak gravity of
    Sec. IV B 3. Run files get every cycle's record and a frame every ``frame_every`` cycles (and at
    the reference cycle); with ``watch_samples`` > 0, the (F_n, F_t, status) of every contact present
    when the loading starts, that many times per cycle (the Coulomb-cone paths of ratcheting Figs. 3,
    4 and 6). The cycles run on ``backend`` (:meth:`~granlab.engine.simulation.Simulation.use_backend`; the box is
    prepared on the CPU); ``batched``: every sample side by side in one simulation (:func:`ratchet_batch`).
    """

    particles: int = 16
    samples: int = 10
    cycles: int = 100
    models: tuple[str, ...] = ("cundall-strack",)
    amplitude: float = 0.2
    period: float = 10.0
    phase: float | None = None
    zero_mean: bool = False
    friction: float = 0.2
    dt_factor: float = 0.2
    reference_cycle: int | None = None
    gravity: float = 0.0
    first_seed: int = 0
    normal_model: str = "linear"
    frame_every: int = 10
    watch_samples: int = 0
    backend: str = "cpu"
    batched: bool = False

    def __post_init__(self):
        for name in ("particles", "samples", "cycles"):
            whole(name, getattr(self, name), 1, STUDY_LIMITS[name])
        low, high = STUDY_LIMITS["period"]
        if not low <= self.period <= high:
            raise ParameterError("period", self.period, f"from {low:g} to {high:g} τ (quasi-static loading is slow "
                                                        f"next to τ; longer cycles would run for days)")
        for model in self.models:
            if model not in TANGENTIAL_MODELS:
                raise ParameterError("model", model, "one of " + ", ".join(TANGENTIAL_MODELS) + " or all")
        if self.cycles < 3:
            raise ParameterError("cycles", self.cycles, "at least 3 (the strain per cycle is fitted over 3 cycles "
                                                        "at least)")
        if self.reference_cycle is None:
            object.__setattr__(self, "reference_cycle", default_reference_cycle(self.cycles))
        if not 0 <= self.reference_cycle <= self.cycles - 3:
            raise ParameterError("reference_cycle", self.reference_cycle,
                                 f"a cycle from 0 to cycles - 3 = {self.cycles - 3} (3 cycles at least are fitted)")
        if self.phase is not None:
            finite("phase", self.phase)
        largest = max_dt_factor(self.normal_model)
        if not 0 < positive("dt_factor", self.dt_factor) <= largest:
            raise ParameterError("dt_factor", self.dt_factor,
                                 f"at most {largest:.4g}: above, dt exceeds the stability bound of these disks")
        friction_coefficient("friction", self.friction)
        positive("amplitude", self.amplitude)
        nonnegative("gravity", self.gravity)
        check_backend(self.backend)
        self.load()


    def load(self) -> CyclicLoad:
        """The cyclic load (paper units: P0 = 1)."""
        return CyclicLoad(pressure=1.0, amplitude=self.amplitude, period=self.period, phase=self.phase,
                          zero_mean=self.zero_mean)


def default_reference_cycle(cycles: int) -> int:
    """The paper's choice scaled to the study: L0 at cycle 30 of 100 (ratcheting Sec. IV B 2), so
    that the first 30 % of the cycles, where the packing settles, stay out of the fit."""
    return min(round(0.3 * cycles), cycles - 3)


def max_dt_factor(normal_model: str = "linear") -> float:
    """The largest ``dt_factor`` the biaxial box's law allows: its stability bound in units of
    ``sqrt(m_min / K_n)``, which for uniform discs does not depend on their sizes."""
    law = biaxial_law(normal_model=normal_model)
    return stability_bound(law, np.ones(1), np.ones(1), np.full(1, 0.5)) * math.sqrt(law.normal_stiffness)


def sample_file(out_dir: str, model: str, seed: int) -> Path:
    return Path(out_dir) / f"ratchet_{model}_seed{seed}.h5"


@dataclass(frozen=True)
class RatchetCurve:
    """One sample cycled with one tangential model: ``cycles`` and the box lengths at the start of
    each, ``gamma`` the deviatoric strain from the reference cycle on (ratcheting Eq. 32) and the
    paper's ``verdict`` on it."""

    model: str
    cycles: np.ndarray
    length_x: np.ndarray
    length_y: np.ndarray
    reference_cycle: int
    gamma: np.ndarray
    verdict: RatchetVerdict


def model_sim(base, study: RatchetStudy, model: str):
    """A copy of the prepared biaxial box ``base`` with tangential ``model``, the time step, the gravity and
    the backend of ``study``, ready to cycle."""
    sim = base.clone(tangential_model=model)
    sim.use_backend(study.backend)
    sim.set_dt(study.dt_factor * math.sqrt(float(sim.particles.mass.min()) / sim.law.normal_stiffness))
    if study.gravity:
        sim.set_gravity(0.0, -study.gravity)
    return sim


def cycle_sample(sim, study: RatchetStudy, writer: RunWriter | None = None) -> RatchetCurve:
    """Cycle ``sim`` (from :func:`model_sim`) as ``study`` says (load, cycles; ratcheting Sec. IV B);
    with ``writer``, every cycle's record, a frame every ``frame_every`` cycles and the watched
    contacts go into its run file."""
    load = study.load()

    def on_cycle(cycle, s, lx, ly):
        if writer is not None:
            writer.write_cycle(cycle, s, lx, ly)
            if cycle % study.frame_every == 0 or cycle in (study.reference_cycle, study.cycles):
                writer.write_frame(s)

    series = run_cycles(sim, load, study.cycles, on_cycle=on_cycle,
                        samples_per_cycle=study.watch_samples if writer is not None else 0,
                        on_sample=writer.write_contact_sample if writer is not None else None)
    if writer is not None:
        writer.write_checkpoint(sim)
    return ratchet_curve(study, sim.law.tangential_model, *series.arrays())


def ratchet_curve(study: RatchetStudy, model: str, cycles, lx, ly) -> RatchetCurve:
    """The strain from the reference cycle on (ratcheting Eq. 32) and its verdict, from the box lengths at the
    start of each cycle."""
    ref = study.reference_cycle
    gamma = deviatoric_strain(lx[ref:], ly[ref:], lx[ref], ly[ref])
    return RatchetCurve(model, cycles, lx, ly, ref, gamma, ratchet_verdict(cycles[ref:], gamma))


def ratchet_sample(study: RatchetStudy, seed: int, out_dir: str | None, overwrite: bool = False) -> list[dict]:
    """Prepare sample ``seed``, cycle it with each model; one result (or error) per model."""
    results = []
    try:
        prepared = compress(study.particles, seed=seed, pressure=1.0, friction=study.friction,
                            normal_model=study.normal_model)
    except Exception as error:  # reported per sample: the others go on
        return [_failure(study, seed, model, error) for model in study.models]
    base = prepared.sim
    for model in study.models:
        start = time.perf_counter()
        try:
            sim = model_sim(base, study, model)
            run_file = None
            if out_dir is None:
                curve = cycle_sample(sim, study)
            else:
                run_file = check_output(sample_file(out_dir, model, seed), force=overwrite)
                watch = touching_pairs(sim) if study.watch_samples else []
                # the run file appears once whole: a killed study leaves no sample file it would refuse
                with staged(run_file.parent, last=[run_file.name]) as folder, \
                        RunWriter(folder / run_file.name, sim, watch=watch, protocol={
                            "study": "ratchet", "seed": seed, "model": model, **study.__dict__}) as writer:
                    curve = cycle_sample(sim, study, writer)
                run_file = str(run_file)
            results.append(_result(seed, curve, prepared.equilibrated, run_file, time.perf_counter() - start))
        except Exception as error:  # reported per sample: the others go on
            results.append(_failure(study, seed, model, error))
    return results


def _result(seed: int, curve: RatchetCurve, equilibrated: bool, run_file: str | None, wall_time: float) -> dict:
    verdict = curve.verdict
    return {"seed": seed, "model": curve.model, "dgamma": verdict.dgamma, "ratcheting": verdict.ratcheting,
            "rms_deviation": verdict.rms_deviation, "shakedown": verdict.shakedown,
            "outlier_cycles": verdict.outlier_cycles, "dgamma_without_outliers": verdict.dgamma_without_outliers,
            "ratcheting_without_outliers": verdict.ratcheting_without_outliers, "equilibrated": equilibrated,
            "length_x": curve.length_x.tolist(), "length_y": curve.length_y.tolist(), "run_file": run_file,
            "wall_time_s": wall_time, "error": None}


def ratchet_batch(study: RatchetStudy, seeds, progress=None) -> list[dict]:
    """Every sample of ``seeds`` prepared, then cycled with each model side by side in one
    :class:`~granlab.engine.batch.Batch` on ``study.backend`` (one result or error per sample and model, as
    :func:`ratchet_sample` gives). The batch steps with the smallest of its samples' time steps. A batch
    that diverges is cycled again sample by sample, so that the sample at fault fails alone.
    ``progress(done, total, phase)`` hears of each cycle."""
    results, prepared = [], {}

    def prepare(seed):
        numba.set_num_threads(1)  # this pool thread's own count: a box a core
        try:
            return compress(study.particles, seed=seed, pressure=1.0, friction=study.friction,
                            normal_model=study.normal_model)
        except Exception as error:  # reported per sample: the others go on
            return error

    # the boxes prepared a core each (the kernels release the interpreter): 40 boxes of 16 disks on two
    # cores in 1.0 s instead of 1.7 s
    with ThreadPoolExecutor(os.cpu_count() or 1) as pool:
        for number, (seed, box) in enumerate(zip(seeds, pool.map(prepare, seeds)), start=1):
            if progress is not None:
                progress(0, len(seeds), f"prepared box {number}/{len(seeds)}")
            if isinstance(box, Exception):
                results.extend(_failure(study, seed, model, box) for model in study.models)
            else:
                prepared[seed] = box
    for model in study.models if prepared else ():
        start = time.perf_counter()
        sims = {seed: model_sim(box.sim, study, model) for seed, box in prepared.items()}
        try:
            lengths = _cycle_batch(Batch(list(sims.values())), study, model, progress)
        except DivergenceError:
            for seed, box in prepared.items():
                try:
                    curve = cycle_sample(model_sim(box.sim, study, model), study)
                    results.append(_result(seed, curve, box.equilibrated, None, time.perf_counter() - start))
                except Exception as error:  # reported per sample: the others go on
                    results.append(_failure(study, seed, model, error))
            continue
        cycles = np.arange(study.cycles + 1)
        wall_time = (time.perf_counter() - start) / max(1, len(sims))
        for k, (seed, box) in enumerate(prepared.items()):
            curve = ratchet_curve(study, model, cycles, lengths[:, k, 0], lengths[:, k, 1])
            results.append(_result(seed, curve, box.equilibrated, None, wall_time))
    if progress is not None:
        progress(len(seeds), len(seeds), "done")
    return results


def _cycle_batch(batch: Batch, study: RatchetStudy, model: str, progress) -> np.ndarray:
    """``(cycles + 1, samples, 2)``: each sample's box lengths at the start of every cycle (as
    :func:`~granlab.engine.protocols.cyclic.run_cycles` records them), the batch cycled by ``study``'s load."""
    load = study.load()
    per_cycle = batch.sim.fit_dt(load.period)
    for name, wall_load in wall_loads(load, batch.sim.time).items():
        batch.set_wall_load(name, wall_load)
    lengths = [batch.box_lengths()]
    for cycle in range(1, study.cycles + 1):
        batch.sim.run(per_cycle)
        lengths.append(batch.box_lengths())
        if progress is not None:
            progress(0, batch.count, f"{model}: cycle {cycle}/{study.cycles} of {batch.count} samples side by side")
    return np.array(lengths)


def touching_pairs(sim) -> list[tuple[int, int]]:
    """The (i, j) of every touching contact (j >= N: a wall)."""
    status, i, j, _ = columns(sim)
    rows = touching(status)
    return [(int(a), int(b)) for a, b in zip(i[rows], j[rows])]


def _failure(study, seed, model, error) -> dict:
    return {"seed": seed, "model": model, "dgamma": None, "ratcheting": None, "error": f"{type(error).__name__}: {error}",
            "traceback": "".join(traceback.format_exception(type(error), error, error.__traceback__, limit=3))}


def summarize(study: RatchetStudy, results: list[dict]) -> dict:
    """Per model: fraction ratcheting, geometric mean and range of |dgamma| over the ratcheting
    samples, count of each sign, how many ratchet once a rattler's jumps are taken out of the
    series (:class:`granlab.engine.analysis.ratchet.RatchetVerdict`), and the samples; ``rules``:
    under each verdict rule (:data:`~granlab.engine.analysis.ratchet.VERDICT_RULES`, the paper's
    first), the samples ratcheting and negative with their Wilson 95 % intervals and the geometric
    mean of |dgamma| with its interval."""
    models = {}
    for model in study.models:
        rows = sorted((r for r in results if r["model"] == model), key=lambda r: r["seed"])
        done = [r for r in rows if r["error"] is None]
        ratcheting = [r for r in done if r["ratcheting"]]
        magnitudes = np.array([abs(r["dgamma"]) for r in ratcheting if r["dgamma"] != 0])
        models[model] = {
            "fraction_ratcheting": len(ratcheting) / len(done) if done else None,
            "ratcheting": len(ratcheting),
            "completed": len(done),
            "geomean_abs_dgamma": float(np.exp(np.mean(np.log(magnitudes)))) if magnitudes.size else None,
            "range_abs_dgamma": [float(magnitudes.min()), float(magnitudes.max())] if magnitudes.size else None,
            "positive": sum(1 for r in ratcheting if r["dgamma"] > 0),
            "negative": sum(1 for r in ratcheting if r["dgamma"] < 0),
            "shakedown": sum(1 for r in done if r.get("shakedown")),
            "with_outliers": sum(1 for r in done if r.get("outlier_cycles")),
            "ratcheting_without_outliers": sum(1 for r in done if r.get("ratcheting_without_outliers")),
            "rules": [{"rule": rule.describe(study.cycles, study.reference_cycle), **share_statistics(
                [judge(r["length_x"], r["length_y"], study.reference_cycle, rule) for r in done])}
                for rule in VERDICT_RULES],
            "samples": [{k: r.get(k) for k in ("seed", "dgamma", "ratcheting", "rms_deviation", "shakedown",
                                                "outlier_cycles", "dgamma_without_outliers",
                                                "ratcheting_without_outliers", "run_file", "error")} for r in rows],
        }
    failed = [{"seed": r["seed"], "model": r["model"], "error": r["error"]} for r in results if r["error"]]
    return {"study": "ratchet", "settings": {k: v for k, v in study.__dict__.items()}, "models": models,
            "failed": failed}


def warm_up(models, report) -> None:
    """Compile (or load from the cache) every kernel a sample with ``models`` needs, before the
    workers start: the time steps side by side in processes of their own, then a sample of 4 disks;
    ``report(text)`` says how far the compile is."""
    from .compilation import compile_sets, describe, step_sets

    compile_sets([*step_sets(models), "state", "packing"], stream=io.StringIO(),
                 on_change=lambda state: report(describe(state)))
    ratchet_sample(RatchetStudy(particles=4, samples=1, cycles=3, reference_cycle=0, period=0.5, models=models),
                   0, None)


def run_ratchet_study(study: RatchetStudy, scheduler: str | None = None, out_dir: str | None = None,
                      progress=None, workers: int | None = None, force: bool = False) -> dict:
    """Run every sample on Dask, or in one batch in this process if ``study.batched``, and summarise.
    ``progress(done, total, phase)`` is called as samples finish. Run files already in ``out_dir`` are
    written over only with ``force``."""
    seeds = range(study.first_seed, study.first_seed + study.samples)
    if study.batched:
        if out_dir is not None:
            raise ParameterError("out_dir", out_dir, "none for a batched study: a batch's work and dissipation are "
                                                     "not split by sample, and its run files would lack them")
        start = time.perf_counter()
        summary = summarize(study, ratchet_batch(study, seeds, progress))
        summary["wall_time_s"] = time.perf_counter() - start
        summary["scheduler"] = f"one batch ({study.backend})"
        return summary
    if out_dir is not None:
        check_output(out_dir, folder=True)
        for seed in seeds:
            for model in study.models:
                check_output(sample_file(out_dir, model, seed), force=force)
        files = study.samples * len(study.models)
        costs.check_disk(costs.run_files_bytes(files, study.cycles // study.frame_every + 3, study.particles),
                         Path(out_dir).absolute(), f"--out {out_dir}: {files} run files of {study.particles} disks")
        Path(out_dir).mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    outcomes = run_tasks(ratchet_sample, [(study, seed, out_dir, force) for seed in seeds],
                         [f"ratchet-sample-{seed}" for seed in seeds], scheduler=scheduler, workers=workers,
                         warm_up=lambda report: warm_up(study.models, report), progress=progress)
    results = []
    for seed, outcome in zip(seeds, outcomes):
        if isinstance(outcome, Exception):  # a lost worker: report, go on
            results.extend(_failure(study, seed, model, outcome) for model in study.models)
        else:
            results.extend(outcome)
    summary = summarize(study, results)
    summary["wall_time_s"] = time.perf_counter() - start
    summary["scheduler"] = scheduler or "local"
    return summary


@contextlib.contextmanager
def _workers_leave_interrupts_to_us():
    """Ctrl-C reaches the whole process group: worker processes started in here ignore it and leave
    it to this process, which stops them (else each prints its own KeyboardInterrupt traceback).
    Only the main thread may change a signal's handler; elsewhere nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    interrupt = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, interrupt)


def run_tasks(function, tasks: list[tuple], keys: list[str], scheduler: str | None = None,
              workers: int | None = None, warm_up=None, progress=None, on_result=None) -> list:
    """``function(*task)`` for every task on Dask, in the order of ``tasks``: its result, or the
    exception raised by a task whose worker was lost (the others go on). ``on_result(key, result)``
    is called in this process as each task finishes (not for a lost worker's).

    Without ``scheduler``, ``warm_up(report)`` compiles the kernels first (``report(text)``: how far it
    is, the phase ``progress`` shows) and a local cluster starts with
    ``workers`` (default: all cores) single-threaded worker processes; ``scheduler`` is the address
    of an existing one. ``progress(done, total, phase)`` is called as tasks finish and once a
    second meanwhile (``phase``: what is going on), so that minutes of compiling or of long samples
    are seen to pass."""
    from distributed import Client, LocalCluster, as_completed

    cluster = None
    state = {"done": 0, "phase": "compiling the kernels" if warm_up is not None and not scheduler else "starting"}
    finished = threading.Event()

    def beat():
        while not finished.wait(1.0) and state["done"] < len(tasks):
            progress(state["done"], len(tasks), state["phase"])

    if progress is not None:
        threading.Thread(target=beat, name="progress", daemon=True).start()
    try:
        if scheduler:
            try:
                client = Client(scheduler, timeout="5s")
            except (OSError, TimeoutError) as error:
                raise GranLabError(f"cannot reach the Dask scheduler at {scheduler!r}: {error}") from error
        else:
            if warm_up is not None:
                warm_up(lambda phase: state.update(phase=phase))
            state["phase"] = "starting the workers"
            # the workers' own logs, critical ones only: a worker still running when the scheduler closes
            # (Ctrl-C on a busy machine) logs the lost connection with its traceback; a task's failure
            # comes back here with its future, and a lost worker's as well
            with _workers_leave_interrupts_to_us():
                cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1,
                                       processes=True, dashboard_address=None, silence_logs=50)
            client = Client(cluster)
        with client:
            futures = [client.submit(function, *task, key=key, pure=False) for task, key in zip(tasks, keys)]
            state["phase"] = "running"
            outcomes = {}
            finishing = as_completed(futures)
            while not finishing.is_empty():
                stopping.check()  # a stop asked for ends the study between two samples
                batch = finishing.next_batch(block=False)
                if not batch:
                    time.sleep(POLL_SECONDS)
                for future in batch:
                    try:
                        outcomes[future.key] = future.result()
                    except Exception as error:  # a lost worker: report, go on
                        outcomes[future.key] = error
                    else:
                        if on_result is not None:
                            on_result(future.key, outcomes[future.key])
                    state["done"] += 1
                    if progress is not None:
                        progress(state["done"], len(futures), "running")
    finally:
        finished.set()
        if cluster is not None:
            cluster.close()
    return [outcomes[key] for key in keys]


class TextProgress:
    """A one-line progress bar on the terminal, with the time since it was made and what is going
    on: ``[######      ] 4/20 samples, running, 73 s``."""

    def __init__(self, stream=sys.stderr):
        self.stream, self.start = stream, time.monotonic()

    def __call__(self, done: int, total: int, phase: str = "") -> None:
        width = 30
        filled = int(width * done / total)
        self.stream.write(f"\r[{'#' * filled}{' ' * (width - filled)}] {done}/{total} samples, {phase}, "
                          f"{time.monotonic() - self.start:.0f} s ")
        if done == total:
            self.stream.write("\n")
        self.stream.flush()
