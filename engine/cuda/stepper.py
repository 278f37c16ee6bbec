"""The host's side of a run on the device: a call of the step driver, as the CPU's.

:class:`DeviceRun` is called as :data:`granlab.engine.kernels.integrate.ADVANCE` is, with the host's
arrays: it copies the state to the device (of the contact table, the rows in use), launches the steps in
batches (one read of the call's state a batch, none a step; a small system's batch in one launch,
:data:`ONE_BLOCK_ROWS`; a batch of boxes a block a box, :data:`SAMPLES_IN_BLOCKS`), and copies the state back
when the call ends. The contact table is rebuilt on the device (:class:`granlab.engine.cuda.neighbours.
DeviceTable`), the CPU engine's table row for row, the state staying there. A
:class:`granlab.engine.simulation.Simulation` calls it once a checkpoint block (2000 steps at most), with the
state staying on the device from one block to the next of a run (``resident``) and the blocks' checkpoints
copies on the device: a run sends the state once and brings it back once."""

from __future__ import annotations

import numpy as np

from .layout import R_ROWS, RUN_CODE, RUN_SIZE, RUN_STEP, RUN_STOP, START, STEP, THREADS, Device, Samples, blocks
from .neighbours import DeviceTable
from .samples import SPLIT, batch_ranges, compact, join, rows_needed, segment_capacity, segmented, split
from .transfer import copied, on_host, rows_to_device, to_device, to_host
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



class DeviceRun:
    """Runs the steps of tangential model ``model`` on the device; called as the CPU's driver.

    ``resident``: after a call that ends well the state stays on the device (:attr:`state`), ahead of the host's
    arrays, and the next call goes on from it; :meth:`release` brings it back. So a run of many checkpoint
    blocks sends the state once and brings it back once. Otherwise each call sends it and brings it back."""

    def __init__(self, model: int, resident: bool = False):
        self.model = model
        self.resident = resident
        self.state: DeviceState | None = None

    def release(self) -> None:
        """The state back in the host's arrays, if the device holds it."""
        if self.state is not None:
            self.state.download()
            self.state = None

    def __call__(self, p, w, cell, ct, spare, ws, law, run, parallel=None) -> tuple[int, int]:
        """Up to ``run.n_steps`` steps; returns ``(steps_done, code)``, the state back in the host's arrays
        unless it stays on the device."""
        if run.n_steps == 0:
            return 0, CODE_OK
        ranges = batch_ranges(w, cell, ct, p.position.shape[0]) if SAMPLES_IN_BLOCKS and self.state is None else None
        if ranges is not None:
            outcome = self._samples(p, w, cell, ct, ws, law, run, ranges)
            if outcome is not None:
                return outcome
        return self._whole(p, w, cell, ct, ws, law, run)

    def _ended(self, state: DeviceState, code: int) -> None:
        """The call ended with ``code``: the state stays on the device if the call ended well and the run is
        resident, else it comes back."""
        if code == CODE_OK and self.resident:
            self.state = state
        else:
            state.download()
            self.state = None

    def _started(self, p, w, cell, ct, ws, law, run):
        """The state on the device (sent, or the one it holds), the run's numbers, and the call's first half kick
        and drift if it starts on a whole step: ``(state, dev, code)``, ``code`` None unless that ended the
        call (the state then back on the host)."""
        _, _, start, disks, after_disks, _, _ = kernels(self.model)
        disk_blocks = blocks(p.position.shape[0])
        dev = Device(law=to_device(law), gravity=to_device(np.asarray(run.gravity, np.float64)),
                     numbers=to_device(np.array([run.dt, run.time_origin, run.skin, run.max_overlap])),
                     counts=to_device(np.array([run.normal_model, run.has_loads, run.step_offset, run.n_steps],
                                                np.int64)),
                     run=to_device(np.zeros(RUN_SIZE, np.int64)), block_tallies=to_device(np.zeros((1, TALLY_SIZE))),
                     block_gather=to_device(np.zeros((disk_blocks, GATHER_SIZE))))
        state = self.state or DeviceState(p, w, cell, ct, ws)
        self.state = None
        phase = np.zeros_like(ws.flags)
        to_host(state.ws.flags, phase)
        if phase[FLAG_PHASE] == PHASE_ON_STEP:
            start[1, 1](state.w, state.cell, state.ws, dev)
            disks[disk_blocks, THREADS](state.p, state.ws, dev, START)
            after_disks[1, THREADS](state.w, state.cell, state.ws, dev, disk_blocks, START)
            _, code, stopped = _read(dev)
            if stopped:
                self._ended(state, code)
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
        rows = ContactArrays(*(to_device(a) for a in table))
        spare_rows = ContactArrays(*(to_device(np.zeros_like(a)) for a in table))
        own = split(segment_ranges, w.length_ref, {name: on_host(getattr(state.ws, name)) for name in SPLIT},
                    {name: on_host(getattr(state.cell, name)) for name in CellArrays._fields})
        own_device = _moved(own, to_device)
        count = segment_ranges.shape[0]
        while True:
            samples_in_blocks[count, THREADS](state.p, state.w, rows, spare_rows, state.ws, dev, own_device, BATCH)
            runs = on_host(own_device.run)
            if runs[:, RUN_STOP].all():
                break
        codes = runs[:, RUN_CODE]
        own = _moved(own_device, on_host)
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
        compact(ContactArrays(*(on_host(a) for a in rows)), own.ranges, ct)
        if failed is None:
            return run.n_steps, CODE_OK
        return int(runs[failed, RUN_STEP]), int(codes[failed])

    def _whole(self, p, w, cell, ct, ws, law, run) -> tuple[int, int]:
        """The steps of the whole system: one block a batch of steps for a small table, else four launches a
        step."""
        contacts, after_contacts, _, disks, after_disks, steps_in_a_block, _ = kernels(self.model)
        disk_blocks = blocks(p.position.shape[0])
        state, dev, code = self._started(p, w, cell, ct, ws, law, run)
        if code is not None:
            return 0, code
        done = 0
        rows = _read_count(state.ct)
        while True:
            flags = np.zeros_like(ws.flags)
            to_host(state.ws.flags, flags)
            if flags[FLAG_REBUILD]:
                state.table = state.table or DeviceTable(state, p.radius, law[D0] + run.skin)
                code, rows = state.table.rebuild(state)
                if code != CODE_OK:
                    self._ended(state, code)
                    return done, code
            row_blocks = blocks(rows)
            if dev.block_tallies.shape[0] < row_blocks:
                dev = dev._replace(block_tallies=to_device(np.zeros((row_blocks, TALLY_SIZE))))
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
                self._ended(state, code)
                return done, code
            dev = dev._replace(run=to_device(np.array([0, 0, done], np.int64)))  # RUN_STOP, RUN_CODE, RUN_STEP


def _moved(own: Samples, move) -> Samples:
    """``own`` with ``move`` applied to each of its arrays (its cell's too): to the device or back."""
    return Samples(**{name: CellArrays(*(move(a) for a in own.cell)) if name == "cell" else move(getattr(own, name))
                      for name in Samples._fields})


def _read_count(table) -> int:
    """The rows in use of a contact table on the device."""
    count = np.zeros(1, np.int64)
    to_host(table.count, count)
    return int(count[0])


def _read(dev) -> tuple[int, int, bool]:
    """The call's state: steps done, its code, whether it stopped."""
    run = np.zeros(RUN_SIZE, np.int64)
    to_host(dev.run, run)
    return int(run[RUN_STEP]), int(run[RUN_CODE]), bool(run[RUN_STOP])


class DeviceState:
    """The state's arrays on the device (the host's named tuples, each array copied; of the contact table the
    rows in use), and the way back: into the host's arrays it came from, or others of the same shapes."""

    def __init__(self, p, w, cell, ct, ws, copy_of: DeviceState | None = None):
        self.host = (p, w, cell, ct, ws)
        self.table: DeviceTable | None = None
        """What rebuilds this state's contact table on the device, made at its first rebuild."""
        if copy_of is not None:  # a copy made on the device: nothing crosses to the host
            self.p, self.w, self.cell, self.ct, self.ws = (type(t)(*(copied(a) for a in t)) for t in (
                copy_of.p, copy_of.w, copy_of.cell, copy_of.ct, copy_of.ws))
            return
        self.p, self.w, self.cell = (type(t)(*(to_device(a) for a in t)) for t in (p, w, cell))
        rows = int(ct.count[0])
        self.ct = type(ct)(*(to_device(a) if name == "count" else rows_to_device(a, rows)
                             for name, a in zip(ct._fields, ct)))
        n, walls = p.position.shape[0], w.offset.shape[0]
        mine = {"force_buffer": np.zeros((1, n, 3)), "touched": np.array([[0, max(n, 1) - 1]], np.uint64),
                "wall_buffer": np.zeros((1, walls)), "tally_buffer": np.zeros((1, TALLY_SIZE)),
                "partial_gather": np.zeros((1, GATHER_SIZE)), "row_columns": np.zeros((1, 1))}
        self.ws = type(ws)(**{name: to_device(mine.get(name, getattr(ws, name))) for name in ws._fields})

    def copy(self) -> DeviceState:
        """A copy of the state on the device, which :meth:`download` brings back later."""
        return DeviceState(*self.host, copy_of=self)

    def download(self, host=None) -> None:
        """The state into the host's arrays it came from (``host``: into these instead, of the same shapes but
        maybe a larger contact table); of the table, the rows in use."""
        host = self.host if host is None else host
        rows = _read_count(self.ct)
        for part, (device, arrays) in enumerate(zip((self.p, self.w, self.cell, self.ct, self.ws), host)):
            for name in arrays._fields:
                if name in _DEVICE_ONLY:
                    continue
                if part == 3 and name != "count":
                    if rows:
                        to_host(getattr(device, name)[:rows], getattr(arrays, name)[:rows])
                else:
                    to_host(getattr(device, name), getattr(arrays, name))
