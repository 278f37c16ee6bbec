"""The host's side of a run on the device: a call of the step driver, as the CPU's.

:class:`DeviceRun` is called as :data:`granlab.engine.kernels.integrate.ADVANCE` is, with the host's
arrays: it copies the state to the device, launches the steps in batches (one read of the call's
state a batch, none a step; a small system's batch in one launch, :data:`ONE_BLOCK_ROWS`; a batch of boxes
a block a box, :data:`SAMPLES_IN_BLOCKS`), and copies the state back when the call ends. The contact table is
rebuilt on the device (:class:`granlab.engine.cuda.neighbours.DeviceTable`), the CPU engine's table row for row,
the state staying there.
A :class:`granlab.engine.simulation.Simulation` calls it once a checkpoint block (2000 steps at most).
"""

from __future__ import annotations

import math

import numpy as np

from . import numba_cuda, simulated
from .neighbours import DeviceTable
from .layout import R_ROWS, RUN_CODE, RUN_SIZE, RUN_STEP, RUN_STOP, START, STEP, THREADS, Device, Samples
from .samples import SPLIT, batch_ranges, compact, join, rows_needed, segment_capacity, segmented, split
from ..kernels.contacts import TALLY_SIZE
from ..kernels.integrate import (CODE_OK, CODE_OVERFLOW, CODE_REBUILD, CODE_TUNNEL, FLAG_PHASE, FLAG_REBUILD,
                                 GATHER_SIZE, PHASE_ON_STEP)
from ..kernels.laws import D0
from ..state import CellArrays, ContactArrays

BATCH = 32
"""Steps launched between two reads of the call's state."""

SAMPLES_IN_BLOCKS = True
"""Whether a batch's samples (:func:`granlab.engine.cuda.samples.batch_ranges`) are stepped a block each, every
block its own steps and rebuilds, rather than as one system."""

ONE_BLOCK_ROWS = 16 * THREADS
"""A contact table of at most this many rows is stepped by one block, ``BATCH`` steps a launch
(``steps_in_a_block``): a box of a few dozen disks would otherwise be four launches a step, each costing
more than its work. Larger tables take the four launches, their rows and disks over many blocks."""

_DEVICE_ONLY = ("force_buffer", "touched", "wall_buffer", "tally_buffer", "partial_gather", "row_columns")
"""The workspace's buffers the device keeps in its own shapes (one chunk) and never sends back."""

_KERNELS: dict[int, tuple] = {}


def kernels(model: int) -> tuple:
    """The kernels of tangential model ``model`` (built once a process; compiled at their first launch)."""
    if model not in _KERNELS:
        from .kernels import build  # numba.cuda takes 0.7 s to import: only for a run on the device

        _KERNELS[model] = build(model)
    return _KERNELS[model]


def _to_device(array: np.ndarray):
    """A copy of ``array`` on the device (the simulator's device is this memory: a copy of its own)."""
    array = np.ascontiguousarray(array)
    return array.copy() if simulated() else numba_cuda().to_device(array)


def _to_host(device, host: np.ndarray) -> None:
    host[...] = device if simulated() else device.copy_to_host()


def _blocks(count: int) -> int:
    return max(1, math.ceil(count / THREADS))


class DeviceRun:
    """Runs the steps of tangential model ``model`` on the device; called as the CPU's driver."""

    def __init__(self, model: int):
        self.model = model

    def __call__(self, p, w, cell, ct, spare, ws, law, run, parallel=None) -> tuple[int, int]:
        """Up to ``run.n_steps`` steps; returns ``(steps_done, code)``, the state back in the host's arrays."""
        if run.n_steps == 0:
            return 0, CODE_OK
        ranges = batch_ranges(w, cell, ct, p.position.shape[0]) if SAMPLES_IN_BLOCKS else None
        if ranges is not None:
            outcome = self._samples(p, w, cell, ct, ws, law, run, ranges)
            if outcome is not None:
                return outcome
        return self._whole(p, w, cell, ct, ws, law, run)

    def _started(self, p, w, cell, ct, ws, law, run):
        """The state on the device, the run's numbers, and the call's first half kick and drift if it starts on a
        whole step: ``(state, dev, code)``, ``code`` None unless that ended the call."""
        _, _, start, disks, after_disks, _, _ = kernels(self.model)
        disk_blocks = _blocks(p.position.shape[0])
        dev = Device(law=_to_device(law), gravity=_to_device(np.asarray(run.gravity, np.float64)),
                     numbers=_to_device(np.array([run.dt, run.time_origin, run.skin, run.max_overlap])),
                     counts=_to_device(np.array([run.normal_model, run.has_loads, run.step_offset, run.n_steps],
                                                np.int64)),
                     run=_to_device(np.zeros(RUN_SIZE, np.int64)), block_tallies=_to_device(np.zeros((1, TALLY_SIZE))),
                     block_gather=_to_device(np.zeros((disk_blocks, GATHER_SIZE))))
        state = _State(p, w, cell, ct, ws)
        if ws.flags[FLAG_PHASE] == PHASE_ON_STEP:
            start[1, 1](state.w, state.cell, state.ws, dev)
            disks[disk_blocks, THREADS](state.p, state.ws, dev, START)
            after_disks[1, THREADS](state.w, state.cell, state.ws, dev, disk_blocks, START)
            _, code, stopped = _read(dev)
            if stopped:
                state.download()
                return state, dev, code
        return state, dev, None

    def _samples(self, p, w, cell, ct, ws, law, run, ranges) -> tuple[int, int] | None:
        """The steps of a batch, a block a sample (``samples_in_blocks``), each sample's rows in a segment of the
        table. ``None`` where the call must run again as one system, the host's arrays as they were: a segment
        filled, a disk moving far enough to pass another (the CPU's driver decides that on the whole system),
        more rows than the host's table holds."""
        samples_in_blocks = kernels(self.model)[6]
        capacity = segment_capacity(ranges)
        if np.any(ranges[:, R_ROWS + 1] - ranges[:, R_ROWS] > capacity):
            return None
        state, dev, code = self._started(p, w, cell, ct, ws, law, run)
        if code is not None:
            return 0, code
        table, segment_ranges = segmented(ct, ranges, capacity)
        rows = ContactArrays(*(_to_device(a) for a in table))
        spare_rows = ContactArrays(*(_to_device(np.zeros_like(a)) for a in table))
        own = split(segment_ranges, w.length_ref, {name: _on_host(getattr(state.ws, name)) for name in SPLIT},
                    {name: _on_host(getattr(state.cell, name)) for name in CellArrays._fields})
        own_device = _moved(own, _to_device)
        count = segment_ranges.shape[0]
        while True:
            samples_in_blocks[count, THREADS](state.p, state.w, rows, spare_rows, state.ws, dev, own_device, BATCH)
            runs = _on_host(own_device.run)
            if runs[:, RUN_STOP].all():
                break
        codes = runs[:, RUN_CODE]
        own = _moved(own_device, _on_host)
        if np.any((codes == CODE_TUNNEL) | (codes == CODE_OVERFLOW)) or rows_needed(own.ranges) > ct.particle_i.shape[0]:
            return None
        failing = np.flatnonzero(codes != CODE_OK)
        failed = int(failing[0]) if failing.size else None
        state.download()
        workspace, cell_arrays = join(own, failed)
        for name, value in workspace.items():
            getattr(ws, name)[...] = value
        for name, value in cell_arrays.items():
            getattr(cell, name)[...] = value
        compact(ContactArrays(*(_on_host(a) for a in rows)), own.ranges, ct)
        if failed is None:
            return run.n_steps, CODE_OK
        return int(runs[failed, RUN_STEP]), int(codes[failed])

    def _whole(self, p, w, cell, ct, ws, law, run) -> tuple[int, int]:
        """The steps of the whole system: one block a batch of steps for a small table, else four launches a
        step."""
        contacts, after_contacts, _, disks, after_disks, steps_in_a_block, _ = kernels(self.model)
        disk_blocks = _blocks(p.position.shape[0])
        state, dev, code = self._started(p, w, cell, ct, ws, law, run)
        if code is not None:
            return 0, code
        done = 0
        rows = int(ct.count[0])
        table = None
        while True:
            flags = np.zeros_like(ws.flags)
            _to_host(state.ws.flags, flags)
            if flags[FLAG_REBUILD]:
                table = table or DeviceTable(state, p.radius, law[D0] + run.skin)
                code, rows = table.rebuild(state)
                if code != CODE_OK:
                    state.download()
                    return done, code
            row_blocks = _blocks(rows)
            if dev.block_tallies.shape[0] < row_blocks:
                dev = dev._replace(block_tallies=_to_device(np.zeros((row_blocks, TALLY_SIZE))))
            sums = (state.ws.force_buffer, state.ws.wall_buffer)
            one_block = rows <= ONE_BLOCK_ROWS
            stopped = False
            while not stopped:
                steps = min(BATCH, run.n_steps - done)
                if one_block:
                    steps_in_a_block[1, THREADS](state.p, state.w, state.cell, state.ct, state.ws, dev, steps)
                for _ in range(0 if one_block else steps):
                    contacts[row_blocks, THREADS](state.p, state.w, state.cell, state.ct, sums, dev)
                    after_contacts[1, THREADS](state.w, state.cell, state.ws, dev, row_blocks)
                    disks[disk_blocks, THREADS](state.p, state.ws, dev, STEP)
                    after_disks[1, THREADS](state.w, state.cell, state.ws, dev, disk_blocks, STEP)
                done, code, stopped = _read(dev)
            if code != CODE_REBUILD:
                state.download()
                return done, code
            dev = dev._replace(run=_to_device(np.array([0, 0, done], np.int64)))  # RUN_STOP, RUN_CODE, RUN_STEP


def _moved(own: Samples, move) -> Samples:
    """``own`` with ``move`` applied to each of its arrays (its cell's too): to the device or back."""
    return Samples(**{name: CellArrays(*(move(a) for a in own.cell)) if name == "cell" else move(getattr(own, name))
                      for name in Samples._fields})


def _on_host(device) -> np.ndarray:
    """A host copy of a device array."""
    return np.array(device) if simulated() else device.copy_to_host()


def _read(dev) -> tuple[int, int, bool]:
    """The call's state: steps done, its code, whether it stopped."""
    run = np.zeros(RUN_SIZE, np.int64)
    _to_host(dev.run, run)
    return int(run[RUN_STEP]), int(run[RUN_CODE]), bool(run[RUN_STOP])


class _State:
    """The state's arrays on the device (the host's named tuples, each array copied), and the way back."""

    def __init__(self, p, w, cell, ct, ws):
        self.host = (p, w, cell, ct, ws)
        self.p, self.w, self.cell, self.ct = (type(t)(*(_to_device(a) for a in t)) for t in (p, w, cell, ct))
        n, walls = p.position.shape[0], w.offset.shape[0]
        mine = dict(force_buffer=np.zeros((1, n, 3)), touched=np.array([[0, max(n, 1) - 1]], np.uint64),
                    wall_buffer=np.zeros((1, walls)),
                    tally_buffer=np.zeros((1, TALLY_SIZE)), partial_gather=np.zeros((1, GATHER_SIZE)),
                    row_columns=np.zeros((1, 1)))
        self.ws = type(ws)(**{name: _to_device(mine.get(name, getattr(ws, name))) for name in ws._fields})

    def download(self) -> None:
        for device, host in zip((self.p, self.w, self.cell, self.ct, self.ws), self.host):
            for name in host._fields:
                if name not in _DEVICE_ONLY:
                    _to_host(getattr(device, name), getattr(host, name))
