"""Compiling the kernels before their first use, and saying so.

A first run compiles the numba kernels it uses and keeps them in the kernel cache
(:mod:`granlab.engine.kernels.cache`); later runs load them in a fraction of a second. The kernels
come in :data:`KERNEL_SETS`, each what one kind of work needs (the time step with one tangential
model, on one thread or several; the energy budget and snapshots; the lab's frames; random
packings; the structure factor), compiled by running that work on a few disks.

- :func:`compile_sets` compiles the sets of a list the cache does not hold, several at once in
  worker processes where the machine has the cores, and reports ``compiling kernels, first run
  only: 2 of 5 (the time step, alpha), 38 s`` as it goes.
- :func:`announced` says so on standard error within a second of any compile it did not plan (a
  command's first run): which kernel, for how long so far.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import multiprocessing
import os
import shutil
import sys
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from . import stopping
from .errors import GranLabError
from .params import TANGENTIAL


@dataclass(frozen=True)
class KernelSet:
    """Kernels compiled together: the ``name`` (``granlab compile --only``), what they are for in
    words, and ``exercise``, the name of this module's function that runs them on a few disks (with
    ``argument``)."""

    name: str
    title: str
    exercise: str
    argument: str = ""


def _sets() -> dict[str, KernelSet]:
    sets = [KernelSet("step-pieces", "the neighbour search and the first kick", "_step_pieces")]
    sets += [KernelSet(f"step-{model.name}", f"the time step, {model.label}", "_step", model.name)
             for model in TANGENTIAL.values()]
    sets += [KernelSet("state", "energies and snapshots", "_state"),
             KernelSet("frames", "frames of the lab and of exports", "_frames"),
             KernelSet("packing", "random packings", "_packing"),
             KernelSet("fractal", "the structure factor", "_fractal")]
    sets += [KernelSet("step-pieces-threads", "the neighbour search and the first kick on several threads",
                       "_step_pieces", "threads")]
    sets += [KernelSet(f"step-{model.name}-threads", f"the time step on several threads, {model.label}", "_step",
                       f"{model.name}:threads") for model in TANGENTIAL.values()]
    return {kernel_set.name: kernel_set for kernel_set in sets}


KERNEL_SETS = _sets()
"""Every kernel set, in the order ``granlab compile`` compiles them (one thread before several).

The time step of a model (``step-MODEL``) holds the pieces every model shares (``step-pieces``):
compiled apart, each in a worker, the two take less time than the step alone (the step then
loads the pieces compiled beside it); a step compiled alone compiles its pieces too."""


def step_sets(models, threads: bool = False) -> list[str]:
    """The sets of the time step with ``models`` (names), on one thread or on several."""
    tail = "-threads" if threads else ""
    return [f"step-pieces{tail}", *(f"step-{model}{tail}" for model in models)]

PARALLEL_THREADS = 2
"""Threads the several-thread time step is compiled with (any number above one runs its code)."""


# ------------------------------------------------------------------------------------ exercises
def _tiny_simulation(model: str = "cundall-strack", disks: int = 2, started: bool = True):
    """``disks`` touching disks on a square lattice in a periodic cell, with tangential model ``model``
    (not ``started``: :meth:`~granlab.engine.simulation.Simulation.unstarted`)."""
    import numpy as np

    from .params import ContactLaw, Integration, PeriodicCell
    from .simulation import Simulation
    from .state import ParticleState

    side = int(np.ceil(np.sqrt(disks)))
    x, y = np.meshgrid(np.arange(side), np.arange(side))
    positions = np.column_stack([x.ravel(), y.ravel()])[:disks] * 0.99 + 0.5
    velocity = np.zeros((disks, 2))
    velocity[0] = 0.01, 0.005
    particles = ParticleState(positions, np.full(disks, 0.5), velocity=velocity)
    law = ContactLaw(normal_stiffness=1e3, tangential_stiffness=1e3, friction=0.5, tangential_model=model)
    build = Simulation if started else Simulation.unstarted
    return build(particles, law, Integration(), cell=PeriodicCell((side * 0.99, side * 0.99 + 1.0)))


def _signature(*arguments):
    """The Numba types of ``arguments`` (a Numba type stands for itself)."""
    from numba import typeof
    from numba.core.types import Type

    return tuple(argument if isinstance(argument, Type) else typeof(argument) for argument in arguments)


def _pieces(threads: bool):
    """The arrays of a few disks not yet started, and the ``parallel`` type of the step."""
    from numba import types

    sim = _tiny_simulation(started=False)
    arrays = (sim.particles.arrays(), sim.walls.arrays(), sim.cell.arrays(), sim.contacts.arrays(),
              sim._spare.arrays(), sim.workspace, sim._law_vector, sim.run_options(sim.dt, 1))
    return sim, arrays, types.boolean if threads else types.none


def _step_pieces(argument: str) -> None:
    """The neighbour search and the first kick of a call of the time step (its ``_start``): no
    tangential model's code is in them."""
    from .kernels import integrate

    sim, (p, w, cell, ct, spare, ws, law, run), parallel = _pieces(argument == "threads")
    integrate.rebuild.compile(_signature(p, w, cell, ct, spare, ws, law, sim.skin))
    integrate._start.compile(_signature(p, w, cell, ws, run, ws.scale, parallel))


def _step(argument: str) -> None:
    """The steps of a model (``_steps``, with the contact loop), then the time step around them."""
    import numba
    from numba import types

    from .kernels import integrate
    from .simulation import PARALLEL_MIN_DISKS

    model, _, threads = argument.partition(":")
    _, (p, w, cell, ct, _spare, ws, law, run), parallel = _pieces(bool(threads))
    integrate._steps.compile(_signature(p, w, cell, ct, ws, law, run, types.int64, ws.scale,
                                        types.literal(TANGENTIAL[model].code), parallel))
    if threads:
        previous = numba.get_num_threads()
        numba.set_num_threads(PARALLEL_THREADS)
        try:
            _tiny_simulation(model, PARALLEL_MIN_DISKS).run(2)
        finally:
            numba.set_num_threads(previous)
    else:
        _tiny_simulation(model).run(2)


def _state(_argument="") -> None:
    sim = _tiny_simulation(started=False)  # its arrays' types are a running one's: no time step compiled
    sim.energy()
    sim.snapshot()


def _frames(_argument="") -> None:
    from .frames import FrameData, build_frame

    sim = _tiny_simulation(started=False)
    build_frame([(FrameData.from_simulation(sim), (0.0, 0.0))], [[(0, 1)]])


def _packing(_argument="") -> None:
    from .generate import radii, random_gas

    random_gas(radii(4, radius_min=0.4, radius_max=0.6, distribution="uniform", seed=0), (0.0, 10.0, 0.0, 10.0),
               periodic=(True, True), seed=0)


def _fractal(_argument="") -> None:
    from .analysis.fractal import fractal_analysis

    sim = _tiny_simulation(disks=16, started=False)
    fractal_analysis(sim.particles.position, sim.particles.radius, sim.cell.length)


# ------------------------------------------------------------------------------------ the cache
def _entry_points(kernel_set: KernelSet) -> list[tuple[object, Callable]]:
    """The kernels Python calls for a set, each with a test of a cached signature."""
    from numba import types

    from .kernels import energy, fields, grid, integrate, packing

    if kernel_set.exercise == "_step":
        model, _, threads = str(kernel_set.argument).partition(":")
        kind = types.boolean if threads else types.none
        return [(integrate.ADVANCE[TANGENTIAL[model].code], lambda signature: signature[-1] == kind)]
    if kernel_set.exercise == "_step_pieces":
        kind = types.boolean if kernel_set.argument == "threads" else types.none
        return [(integrate.rebuild, lambda signature: True), (integrate._start, lambda signature: signature[-1] == kind)]
    dispatchers = {"_state": (energy.energy_terms, energy.rolling_distance, energy.elastic_normal_forces),
                   "_frames": (fields.contact_fields,), "_packing": (packing.random_sequential_addition,),
                   "_fractal": (grid.paint_disks, grid.shell_sums, grid.label_moments)}[kernel_set.exercise]
    return [(dispatcher, lambda signature: True) for dispatcher in dispatchers]


def cached(kernel_set: KernelSet, loaded: bool = True) -> bool:
    """Whether the kernel cache holds the set, compiled from these sources for this processor (with
    ``loaded``, a set this process has compiled or loaded counts as held)."""
    for dispatcher, wanted in _entry_points(kernel_set):
        if loaded and any(wanted(signature) for signature in dispatcher.signatures):
            continue
        cache = dispatcher._cache
        codegen = dispatcher.targetctx.codegen()
        try:
            keys = cache._cache_file._load_index()
        except Exception:  # an unreadable index is a missing one: Numba then compiles
            return False
        if not any(wanted(key[0]) and cache._index_key(key[0], codegen) == key for key in keys):
            return False
    return True


def missing(names: Iterable[str], loaded: bool = True) -> list[KernelSet]:
    """The sets of ``names`` (known to :data:`KERNEL_SETS`) the cache does not hold (``loaded``: as
    :func:`cached`)."""
    return [KERNEL_SETS[name] for name in dict.fromkeys(names) if not cached(KERNEL_SETS[name], loaded)]


def exercise(name: str) -> float:
    """Run set ``name``'s work (compiling what the cache lacks); its seconds."""
    start = time.perf_counter()
    kernel_set = KERNEL_SETS[name]
    with _quiet():
        globals()[kernel_set.exercise](kernel_set.argument)
    return time.perf_counter() - start


# ------------------------------------------------------------------------------------ progress
class Progress:
    """``compiling kernels, first run only: 2 of 5 (the time step, alpha), 38 s`` on standard error
    (without the count where ``total`` is not known beforehand): rewritten in place on a terminal,
    else a line when a set starts or ends and every :attr:`every` seconds between; in the
    ``background`` (other work goes on meanwhile, writing to the same terminal) the first line and
    the last only."""

    every = 10.0

    def __init__(self, total: int | None, stream=None, on_change: Callable[[dict], None] | None = None,
                 background: bool = False):
        self.stream = stream or sys.stderr
        self.background = background
        self.total, self.done, self.current = total, 0, ""
        self.start = time.monotonic()
        self.on_change = on_change
        self._printed = -float("inf")
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._ticker = threading.Thread(target=self._tick, daemon=True, name="granlab-compile-progress")

    def state(self) -> dict:
        return {"done": self.done, "total": self.total, "current": self.current,
                "seconds": time.monotonic() - self.start}

    def text(self) -> str:
        where = " in the background (the rest goes on meanwhile)" if self.background else ""
        return describe(self.state()).replace("compiling kernels", f"compiling kernels{where}", 1)

    def show(self, force: bool = False) -> None:
        with self._lock:
            now = time.monotonic()
            if self.background and self._printed > -float("inf"):
                pass  # work goes on beside it: its first line and its last only
            elif self.stream.isatty() and not self.background:
                print(f"\r\033[K{self.text()}", end="", file=self.stream, flush=True)
            elif force or now - self._printed >= self.every:
                print(self.text(), file=self.stream, flush=True)
            else:
                return
            self._printed = now
        if self.on_change is not None:
            self.on_change(self.state())

    def begin(self, title: str) -> None:
        """Now compiling ``title``: shown at once, then every second (on a terminal) or
        :attr:`every` seconds until :meth:`close`."""
        self.current = title
        if self._ticker.ident is None:
            self._ticker.start()
        self.show(force=True)

    def finished(self, count: int = 1) -> None:
        self.done += count
        self.show(force=True)

    def close(self, unkept: int = 0, stopped: bool = False) -> None:
        """The last line: how long it took, and whether the kernels were kept (``unkept``: sets that
        could not be; ``stopped``: the compile was stopped before its end)."""
        self._stop.set()
        with self._lock:
            seconds = time.monotonic() - self.start
            end = "\r\033[K" if self.stream.isatty() and not self.background else ""
            kept = f"but {unkept} of {self.total} sets could not be kept ({not_kept()}): the next run compiles them " \
                   "again" if unkept else "kept for the next runs"
            done = f"compile stopped after {seconds:.0f} s" if stopped else f"compiled in {seconds:.0f} s ({kept})"
            print(f"{end}{done}", file=self.stream, flush=True)
        if self.on_change is not None:
            self.on_change({**self.state(), "done": self.total, "current": ""})

    def _tick(self) -> None:
        while not self._stop.wait(1.0):
            self.show()


def describe(state: dict) -> str:
    """``compiling kernels, first run only: 2 of 5 (the time step, alpha), 38 s`` of a
    :meth:`Progress.state`."""
    doing = f" ({state['current']})" if state["current"] else ""
    count = f": {min(state['done'] + 1, state['total'])} of {state['total']}" if state["total"] else ""
    return f"compiling kernels, first run only{count}{doing}, {state['seconds']:.0f} s"


def workers_for(count: int) -> int:
    """Worker processes for ``count`` sets: one a core this process may use, at most ``count``."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(count, cores))


def compile_sets(names: Iterable[str], workers: int | None = None, stream=None,
                 on_change: Callable[[dict], None] | None = None, nice: int = 0, load: bool = True,
                 background: bool = False, cancel: threading.Event | None = None) -> list[str]:
    """Compile the sets of ``names`` the cache does not hold, in their order, and report it on
    ``stream`` (standard error) and to ``on_change(state)``: in ``workers`` processes side by side
    (default: one set here, more in one process a core; 0: here), raised in ``nice`` (so that a
    process going on beside them keeps its cores); with ``load``, the sets are then loaded here (a
    fraction of a second each); ``background``: a line when it starts and one when it ends, for
    work that goes on meanwhile. ``cancel`` set stops a compile in workers (they are killed:
    :class:`CompileCancelled`). Returns the names compiled."""
    todo = missing(names)
    if not todo:
        return []
    progress = Progress(len(todo), stream, on_change, background)
    if workers is None:
        workers = 0 if len(todo) == 1 else workers_for(len(todo))
    try:
        if workers == 0:
            for kernel_set in todo:
                progress.begin(kernel_set.title)
                exercise(kernel_set.name)
                progress.finished()
        else:
            _compile_in_workers(todo, min(workers, len(todo)), progress, nice, cancel)
            for kernel_set in todo if load else ():
                exercise(kernel_set.name)
    except BaseException:
        progress.close(stopped=True)
        raise
    progress.close(len(missing((kernel_set.name for kernel_set in todo), loaded=False)))
    return [kernel_set.name for kernel_set in todo]


class CompileCancelled(GranLabError):
    """A compile in workers stopped by its ``cancel`` event (:func:`compile_sets`)."""


def not_kept() -> str:
    """Why compiled kernels may not have been kept, in words: where the cache is and what room its disk has."""
    from .kernels.cache import cache_root

    root = cache_root()
    try:
        free = f"{shutil.disk_usage(root).free / 2 ** 20:.0f} MiB free on its disk"
    except OSError as error:
        free = error.strerror
    return f"the kernel cache {root} could not be written: {free}"


def _compile_in_workers(todo: list[KernelSet], workers: int, progress: Progress, nice: int,
                        cancel: threading.Event | None) -> None:
    """Each set in a worker process, in the order of ``todo``. The workers end with this process, however
    it ends, and at once when this one is asked to stop (:mod:`granlab.engine.stopping`), ``cancel`` is set
    or a set fails."""
    pending, running = list(todo), {}
    context = multiprocessing.get_context("spawn")
    pool = concurrent.futures.ProcessPoolExecutor(workers, mp_context=context, initializer=_worker_start,
                                                  initargs=(os.getpid(), nice))
    try:
        while pending or running:
            while pending and len(running) < workers:
                kernel_set = pending.pop(0)
                running[pool.submit(exercise, kernel_set.name)] = kernel_set
            progress.begin(", ".join(kernel_set.title for kernel_set in running.values()))
            finished = ()
            while not finished:
                stopping.check()
                if cancel is not None and cancel.is_set():
                    raise CompileCancelled("the compile was cancelled")
                finished, _ = concurrent.futures.wait(running, timeout=0.5,
                                                      return_when=concurrent.futures.FIRST_COMPLETED)
            for future in finished:
                future.result()
                running.pop(future)
                progress.done += 1
    except BaseException:
        for process in list(getattr(pool, "_processes", {}).values()):  # ProcessPoolExecutor keeps them so
            process.kill()
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown()


def _worker_start(parent: int, nice: int) -> None:
    """A compile worker's start: it ends with process ``parent``, and yields its cores by ``nice``."""
    stopping.die_with_parent(parent)
    os.nice(nice)


# ------------------------------------------------------------------------------------ announcing
_PLANNED = threading.local()


@contextlib.contextmanager
def _quiet():
    """A planned compile: :func:`announced` stays silent (the planner reports)."""
    _PLANNED.active = getattr(_PLANNED, "active", 0) + 1
    try:
        yield
    finally:
        _PLANNED.active -= 1


@contextlib.contextmanager
def announced(stream=None):
    """Within this block, a compile of a GranLab kernel that nothing planned is announced on
    ``stream`` (standard error) as it starts, with its seconds so far every few seconds and its
    total at the end. Loads nothing: a command that compiles nothing pays nothing."""
    from .kernels.watchers import WATCHERS

    watcher = _Announcer(stream or sys.stderr)
    WATCHERS.append(watcher)
    try:
        yield
    finally:
        WATCHERS.remove(watcher)
        watcher.stop()


class _Announcer:
    """Reports the compiles :func:`announced` watches, but the planned ones (:func:`compile_sets`)."""

    def __init__(self, stream):
        self.stream, self.progress = stream, None

    def started(self, name: str) -> None:
        if not getattr(_PLANNED, "active", 0):
            self.progress = Progress(None, self.stream)
            self.progress.begin(name)

    def ended(self) -> None:
        if self.progress is not None:
            self.progress.close()
            self.progress = None

    def stop(self) -> None:
        self.ended()
