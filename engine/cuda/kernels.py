"""The device's kernels, one set per tangential model (its code a constant, as on the CPU).

A step is four launches, none of which waits for the host:

1. :func:`contacts`, one thread a row of the contact table: the row's geometry and laws
   (:data:`granlab.engine.kernels.contacts.SINGLE_ROW`), its force added to the disks' sums with atomic
   additions, its tallies summed within the block;
2. ``after_contacts``, one block: the blocks' tallies summed, the walls' reactions and the energy
   tallies (:func:`granlab.engine.kernels.integrate.contact_totals`), then the walls' and the cell's kick and
   drift;
3. ``disks``, one thread a disk: its forces gathered, its kicks and drift
   (:func:`granlab.engine.kernels.integrate.particle_range`), the pass's sums within the block;
4. ``after_disks``, one block: the blocks' sums, the cell's stress (:func:`~granlab.engine.kernels.integrate.
   pass_totals`) and the checks that end a call (:func:`~granlab.engine.kernels.integrate.step_end`).

A small system (a contact table of at most :data:`granlab.engine.cuda.stepper.ONE_BLOCK_ROWS` rows) takes
``steps_in_a_block`` instead: one block runs a batch of steps, the four launches its phases between the
block's barriers (each thread a stride of the rows, then a run of the disks), so that a box of 16 disks is
one launch for 32 steps, not 128. Its parameters take 4.5 KB, which a launch takes from CUDA 12.1 on (ptxas
12.9 assembles it for sm_90: 128 registers, 23.5 KB of shared memory); the four kernels stay under 4 KB.

A batch of boxes (:class:`granlab.engine.batch.Batch`, :mod:`granlab.engine.cuda.samples`) takes
``samples_in_blocks``: a block a box, each the same phases on its box's rows, disks and walls, with the
box's own sums, flags and clock, and each rebuilding its box's rows in its own segment of the table when
they are due (``sample_rebuild``: every pair of its disks tested, on one thread). The blocks share nothing
and never wait for one another, so a launch steps every box 32 steps however many boxes there are (6.4 KB
of parameters; ptxas: 164 registers).

A call's state (``RUN_STOP``, ``RUN_CODE``, ``RUN_STEP``) lives on the device: once a step ends the call
(its last, a divergence, a rebuild due), the steps launched after it do nothing, so the host launches
steps in batches and reads the state once a batch. Sums over blocks are taken in block order, but a disk's
forces, added atomically, meet in the order the threads happen to run: two runs on the device may part by
rounding, as a run on the device and one on the CPU do. A rebuild due, the host rebuilds the table on the
device (:mod:`granlab.engine.cuda.neighbours`) and launches on.
"""

from __future__ import annotations

import sys

from numba import float64

from . import numba_cuda, simulated
from ..kernels.contacts import SINGLE_ROW, TALLY_MAX_OVERLAP, TALLY_SIZE
from ..kernels.integrate import (CODE_GO_ON, CODE_LOST_CONTACT, CODE_OK, CODE_OVERFLOW, CODE_REBUILD, FLAG_PHASE,
                                 FLAG_REBUILD, G_DISPLACEMENT, G_MOVER, G_STEP_MOVE, GATHER_SIZE, INFO_LOST,
                                 INFO_NEEDED, INFO_REBUILDS, PHASE_ON_STEP, cell_step, contact_totals, particle_range, pass_totals,
                                 start_boundaries, start_end, step_end, walls_step)
from ..kernels.laws import D0, root_reduced_mass, touching
from ..kernels.neighbours import carry_history, copy_row, no_history
from ..state import CellArrays, WallArrays, Workspace
from .layout import (C_HAS_LOADS, C_N_STEPS, C_NORMAL_MODEL, C_STEP_OFFSET, N_DT, N_MAX_OVERLAP, N_SKIN,
                     N_TIME_ORIGIN, R_DISKS, R_ROWS, R_SEGMENT, R_WALLS, RUN_CODE, RUN_STEP, RUN_STOP, START, STEP,
                     THREADS)

cuda = numba_cuda()  # a global: the simulator finds the module in the kernels' globals and stands in for it


def _simulator_fixes() -> None:
    """Numba's simulator runs a Python thread for each of a block's threads. Its own thread polls them while it
    holds the interpreter: handed over every 20 µs instead of 5 ms, a step takes a third of the time. And the
    threads of a block that first reach a ``cuda.shared.array`` line each look for the block's array and, finding
    none, may each make one (numba 0.68's ``FakeCUDAShared.array``): they then share nothing, and a block's sum
    reads memory never written (a run diverged on it once in about ten). Made under a lock here, the array is
    the block's one."""
    import threading

    import numpy as np
    from numba.cuda.simulator import kernelapi
    from numba.np import numpy_support

    sys.setswitchinterval(min(sys.getswitchinterval(), 2e-5))
    lock = threading.Lock()

    def array(self, shape, dtype):
        caller = sys._getframe(1)
        where = (caller.f_code.co_filename, caller.f_lineno)  # the simulator's key: one array a line and block
        with lock:
            if where not in self._allocations:
                self._allocations[where] = np.zeros(shape, numpy_support.as_dtype(dtype))
            return self._allocations[where]

    kernelapi.FakeCUDAShared.array = array


if simulated():
    _simulator_fixes()


TALLIES, GATHER = 0, 1
"""What a block sums: the contact pass's tallies (``TALLY_*``), or the disks' pass's sums (``G_*``)."""


def build(model: int):
    """The kernels of tangential model ``model``: ``(contacts, after_contacts, start, disks, after_disks,
    steps_in_a_block, samples_in_blocks)``."""
    contact_row = SINGLE_ROW[model]

    @cuda.jit(device=True)
    def add_tallies(into, a, b):
        for s in range(TALLY_SIZE):
            if s == TALLY_MAX_OVERLAP:
                into[s, a] = max(into[s, a], into[s, b])
            else:
                into[s, a] += into[s, b]

    @cuda.jit(device=True)
    def add_gather(into, a, b):
        for s in range(G_STEP_MOVE):
            if s == G_DISPLACEMENT:
                into[s, a] = max(into[s, a], into[s, b])
            else:
                into[s, a] += into[s, b]
        # the fastest disk, the first of equals (as the CPU's pass)
        if into[G_STEP_MOVE, b] > into[G_STEP_MOVE, a] or (
                into[G_STEP_MOVE, b] == into[G_STEP_MOVE, a] and into[G_MOVER, b] < into[G_MOVER, a]):
            into[G_STEP_MOVE, a] = into[G_STEP_MOVE, b]
            into[G_MOVER, a] = into[G_MOVER, b]

    @cuda.jit(device=True)
    def reduce_block(shared, tid, kind):
        """Sum the block's columns of ``shared`` into column 0, in a fixed order."""
        stride = THREADS // 2
        while stride > 0:
            cuda.syncthreads()
            if tid < stride:
                if kind == TALLIES:
                    add_tallies(shared, tid, tid + stride)
                else:
                    add_gather(shared, tid, tid + stride)
            stride //= 2
        cuda.syncthreads()

    @cuda.jit(device=True)
    def sum_block(shared, tid, kind, width, blocks):
        """The block's columns of ``shared`` summed (:func:`reduce_block`) into its row of ``blocks``."""
        reduce_block(shared, tid, kind)
        if tid == 0:
            for s in range(width):
                blocks[cuda.blockIdx.x, s] = shared[s, 0]

    @cuda.jit(device=True)
    def reduce_blocks(shared, blocks, count, width, tid, kind):
        """Column 0 of ``shared`` = the sum of the ``count`` rows of ``blocks`` (each thread a stride of them,
        in order, then :func:`reduce_block`)."""
        for s in range(width):
            shared[s, tid] = blocks[tid, s] if tid < count else 0.0
        if kind == GATHER and tid >= count:
            shared[G_MOVER, tid] = 1e300
        b = tid + THREADS
        while b < count:
            for s in range(width):
                value = blocks[b, s]
                if kind == TALLIES:
                    if s == TALLY_MAX_OVERLAP:
                        shared[s, tid] = max(shared[s, tid], value)
                    else:
                        shared[s, tid] += value
                elif s == G_DISPLACEMENT:
                    shared[s, tid] = max(shared[s, tid], value)
                elif s < G_STEP_MOVE:
                    shared[s, tid] += value
            if kind == GATHER and blocks[b, G_STEP_MOVE] > shared[G_STEP_MOVE, tid]:
                shared[G_STEP_MOVE, tid] = blocks[b, G_STEP_MOVE]
                shared[G_MOVER, tid] = blocks[b, G_MOVER]
            b += THREADS
        reduce_block(shared, tid, kind)

    @cuda.jit(device=True)
    def row_forces(p, w, cell, ct, dev, k, force_buffer, wall_buffer, store, shared, tid):
        """Row ``k``'s geometry and laws, its force added to the disks' sums (atomic additions), its tallies
        folded into column ``tid`` of ``shared``."""
        acts, is_wall, i, j, fx, fy, torque_i, torque_j, push, tallies = contact_row(
            p, w, cell, ct, dev.law, k, dev.numbers[N_DT], dev.numbers[N_MAX_OVERLAP], dev.counts[C_NORMAL_MODEL],
            store)
        if acts:
            cuda.atomic.add(force_buffer, (0, i, 0), fx)
            cuda.atomic.add(force_buffer, (0, i, 1), fy)
            cuda.atomic.add(force_buffer, (0, i, 2), torque_i)
            if is_wall:
                cuda.atomic.add(wall_buffer, (0, j), -push)
            else:
                cuda.atomic.add(force_buffer, (0, j, 0), -fx)
                cuda.atomic.add(force_buffer, (0, j, 1), -fy)
                cuda.atomic.add(force_buffer, (0, j, 2), torque_j)
        for s in range(TALLY_SIZE):
            if s == TALLY_MAX_OVERLAP:
                shared[s, tid] = max(shared[s, tid], tallies[s])
            else:
                shared[s, tid] += tallies[s]

    @cuda.jit(device=True)
    def rows_done(w, cell, ws, dev, run, shared):
        """One thread, after the rows: their tallies (column 0 of ``shared``), the walls' reactions and the energy
        tallies, then the walls' and the cell's kick and drift (``run``: the call's state)."""
        for s in range(TALLY_SIZE):
            ws.tally_buffer[0, s] = shared[s, 0]
        contact_totals(w, ws, 1)
        for m in range(ws.wall_buffer.shape[1]):
            ws.wall_buffer[0, m] = 0.0
        dt = dev.numbers[N_DT]
        step = run[RUN_STEP]
        last = step + 1 == dev.counts[C_N_STEPS]
        t = dev.numbers[N_TIME_ORIGIN] + (dev.counts[C_STEP_OFFSET] + step + 1) * dt
        kicks = 1 if last else 2
        drift = 0.0 if last else dt
        walls_step(w, t, 0.5 * dt, kicks, drift)
        cell_step(cell, cell.virial, cell.kinetic, 0.5 * dt, kicks, drift, ws.scale)

    @cuda.jit(device=True)
    def disks_range(p, ws, dev, run, mode, first, stop, out):
        """The pass over disks ``[first, stop)`` into ``out`` (nothing but the sums' neutral values when empty)."""
        for s in range(GATHER_SIZE):
            out[s] = 0.0
        out[G_MOVER] = 1e300
        if first < stop:
            dt = dev.numbers[N_DT]
            last = mode == STEP and run[RUN_STEP] + 1 == dev.counts[C_N_STEPS]
            kicks = 1 if mode == START or last else 2
            particle_range(p, ws.force_buffer, ws.touched, 1, dev.gravity, dev.counts[C_HAS_LOADS] != 0, mode == STEP,
                           last, 0.5 * dt, kicks, 0.0 if last else dt, ws.scale[0], ws.scale[1], ws.reference, first,
                           stop, out)

    @cuda.jit(device=True)
    def disks_done(w, cell, ws, dev, run, shared, mode, rebuilds_here):
        """One thread, after the disks: their sums (column 0 of ``shared``), the cell's stress and the checks that
        end a call (``run``: its state)."""
        for s in range(GATHER_SIZE):
            ws.gather[s] = shared[s, 0]
        max_overlap = dev.numbers[N_MAX_OVERLAP]
        if mode == START:
            code = start_end(w, cell, ws, dev.numbers[N_SKIN], max_overlap)
        else:
            pass_totals(cell, ws, ws.scale)
            last = run[RUN_STEP] + 1 == dev.counts[C_N_STEPS]
            if last:
                ws.flags[FLAG_PHASE] = PHASE_ON_STEP
            run[RUN_STEP] += 1
            code = step_end(w, cell, ws, last, dev.numbers[N_SKIN], max_overlap)
        # a rebuild flagged (ws.flags) and done by the block itself, where it may: no stop
        if code != CODE_GO_ON and not (rebuilds_here and code == CODE_REBUILD):
            run[RUN_CODE] = code
            run[RUN_STOP] = 1

    @cuda.jit
    def contacts(p, w, cell, ct, sums, dev):
        # sums: the workspace's force and wall buffers alone, so that the kernel's parameters stay under the
        # 4 KB a launch takes before CUDA 12.1 (the whole workspace with them: 4.4 KB)
        if dev.run[RUN_STOP] != 0:
            return
        force_buffer, wall_buffer = sums
        k = cuda.grid(1)
        tid = cuda.threadIdx.x
        shared = cuda.shared.array((TALLY_SIZE, THREADS), float64)
        for s in range(TALLY_SIZE):
            shared[s, tid] = 0.0
        if k < ct.count[0]:
            row_forces(p, w, cell, ct, dev, k, force_buffer, wall_buffer, dev.run[RUN_STEP] + 1 == dev.counts[C_N_STEPS],
                       shared, tid)
        sum_block(shared, tid, TALLIES, TALLY_SIZE, dev.block_tallies)

    @cuda.jit
    def after_contacts(w, cell, ws, dev, blocks):
        if dev.run[RUN_STOP] != 0:
            return
        tid = cuda.threadIdx.x
        shared = cuda.shared.array((TALLY_SIZE, THREADS), float64)
        reduce_blocks(shared, dev.block_tallies, blocks, TALLY_SIZE, tid, TALLIES)
        if tid == 0:
            rows_done(w, cell, ws, dev, dev.run, shared)

    @cuda.jit
    def start(w, cell, ws, dev):
        dt = dev.numbers[N_DT]
        start_boundaries(w, cell, ws, dev.numbers[N_TIME_ORIGIN] + dev.counts[C_STEP_OFFSET] * dt, 0.5 * dt, dt,
                         ws.scale)

    @cuda.jit
    def disks(p, ws, dev, mode):
        if dev.run[RUN_STOP] != 0:
            return
        i = cuda.grid(1)
        tid = cuda.threadIdx.x
        shared = cuda.shared.array((GATHER_SIZE, THREADS), float64)
        out = cuda.local.array(GATHER_SIZE, float64)
        disks_range(p, ws, dev, dev.run, mode, i, min(i + 1, p.position.shape[0]), out)
        for s in range(GATHER_SIZE):
            shared[s, tid] = out[s]
        sum_block(shared, tid, GATHER, GATHER_SIZE, dev.block_gather)

    @cuda.jit
    def after_disks(w, cell, ws, dev, blocks, mode):
        if dev.run[RUN_STOP] != 0:
            return
        tid = cuda.threadIdx.x
        shared = cuda.shared.array((GATHER_SIZE, THREADS), float64)
        reduce_blocks(shared, dev.block_gather, blocks, GATHER_SIZE, tid, GATHER)
        if tid == 0:
            disks_done(w, cell, ws, dev, dev.run, shared, mode, False)

    @cuda.jit
    def steps_in_a_block(p, w, cell, ct, ws, dev, steps):
        """Up to ``steps`` steps of a small system in one block, the four launches of a step its phases between
        the block's barriers: each thread a stride of the rows, then a run of the disks."""
        tid = cuda.threadIdx.x
        tallies = cuda.shared.array((TALLY_SIZE, THREADS), float64)
        gather = cuda.shared.array((GATHER_SIZE, THREADS), float64)
        out = cuda.local.array(GATHER_SIZE, float64)
        n = p.position.shape[0]
        for _ in range(steps):
            if dev.run[RUN_STOP] != 0:  # written by thread 0 before the last barrier: every thread reads the same
                return
            store = dev.run[RUN_STEP] + 1 == dev.counts[C_N_STEPS]
            for s in range(TALLY_SIZE):
                tallies[s, tid] = 0.0
            k = tid
            while k < ct.count[0]:
                row_forces(p, w, cell, ct, dev, k, ws.force_buffer, ws.wall_buffer, store, tallies, tid)
                k += THREADS
            reduce_block(tallies, tid, TALLIES)
            if tid == 0:
                rows_done(w, cell, ws, dev, dev.run, tallies)
            cuda.syncthreads()
            disks_range(p, ws, dev, dev.run, STEP, tid * n // THREADS, (tid + 1) * n // THREADS, out)
            for s in range(GATHER_SIZE):
                gather[s, tid] = out[s]
            reduce_block(gather, tid, GATHER)
            if tid == 0:
                disks_done(w, cell, ws, dev, dev.run, gather, STEP, False)
            cuda.syncthreads()

    @cuda.jit(device=True)
    def sample_views(w, ws, own, b):
        """Sample ``b``'s walls, cell and workspace: views of the whole system's wall and disk arrays, its own
        sums, flags and cell (``own``: :class:`~granlab.engine.cuda.layout.Samples`)."""
        lo = own.ranges[b, R_WALLS]
        hi = own.ranges[b, R_WALLS + 1]
        walls = WallArrays(w.normal[lo:hi], w.offset[lo:hi], w.velocity[lo:hi], w.tangential_velocity[lo:hi],
                           w.tangential_position[lo:hi], w.mode[lo:hi], w.inv_mass[lo:hi], w.load[lo:hi],
                           own.length_ref[lo:hi], w.particle_force[lo:hi], w.reach[lo:hi])
        c = own.cell
        cell = CellArrays(c.length[b], c.rate[b], c.control[b], c.target_stress[b], c.strain_rate[b],
                          c.reference_length[b], c.mass[b], c.max_strain_rate[b], c.virial[b], c.kinetic[b])
        work = Workspace(ws.force_buffer, ws.touched, ws.wall_buffer[:, lo:hi], own.tally_buffer[b],
                         own.virial_correction[b], own.lagged_virial[b], own.lagged_kinetic[b], ws.wrapped, ws.wraps,
                         ws.reference, ws.wall_reference[lo:hi], own.length_reference[b], own.scale[b], own.gather[b],
                         ws.partial_gather, own.flags[b], own.energy[b], own.info[b], ws.row_columns)
        return walls, cell, work

    @cuda.jit(device=True)
    def sample_rebuild(p, w, ct, spare, own, b, work, extra):
        """Sample ``b``'s rows rebuilt within its segment (one thread): every pair of its disks and every disk and
        wall of it closer than ``extra``, in the CPU's order within a disk (disks, then walls), the history of
        the rows that were there already carried over; returns a code (``CODE_OVERFLOW``: the segment is full,
        ``CODE_LOST_CONTACT``: a touching contact found no row)."""
        first_row = own.ranges[b, R_ROWS]
        old_stop = own.ranges[b, R_ROWS + 1]
        capacity = own.ranges[b, R_SEGMENT]
        d0 = own.ranges[b, R_DISKS]
        d1 = own.ranges[b, R_DISKS + 1]
        w0 = own.ranges[b, R_WALLS]
        w1 = own.ranges[b, R_WALLS + 1]
        n = p.position.shape[0]
        count = 0
        for i in range(d0, d1):
            for j in range(i + 1, d1 + w1 - w0):
                if j < d1:
                    dx = p.position[i, 0] - p.position[j, 0]
                    dy = p.position[i, 1] - p.position[j, 1]
                    reach = p.radius[i] + p.radius[j] + extra
                    near = dx * dx + dy * dy < reach * reach
                    other = j
                    inv_mass_j = p.inv_mass[j]
                else:
                    m = w0 + j - d1
                    near = w.normal[m, 0] * p.position[i, 0] + w.normal[m, 1] * p.position[i, 1] - w.offset[m] \
                        - p.radius[i] < extra
                    other = n + m
                    inv_mass_j = 0.0
                if near:
                    if count < capacity:
                        k = first_row + count
                        spare.particle_i[k] = i
                        spare.particle_j[k] = other
                        spare.image[k, 0] = 0
                        spare.image[k, 1] = 0
                        spare.root_reduced_mass[k] = root_reduced_mass(p.inv_mass[i], inv_mass_j)
                    count += 1
        if count > capacity:
            work.info[INFO_NEEDED] = count
            return CODE_OVERFLOW
        matched = 0
        active = 0
        for k in range(first_row, old_stop):
            if touching(ct.status[k]):
                active += 1
        for k in range(first_row, first_row + count):
            found = -1
            for q in range(first_row, old_stop):
                if ct.particle_i[q] == spare.particle_i[k] and ct.particle_j[q] == spare.particle_j[k]:
                    found = q
                    break
            if found < 0:
                no_history(spare, k)
                continue
            if touching(ct.status[found]):
                matched += 1
            carry_history(ct, found, spare, k)
        if active > matched:
            work.info[INFO_LOST] = active - matched
            return CODE_LOST_CONTACT
        for k in range(first_row, first_row + count):
            copy_row(spare, k, ct, k)
        own.ranges[b, R_ROWS + 1] = first_row + count
        for i in range(d0, d1):
            work.reference[i, 0] = p.position[i, 0]
            work.reference[i, 1] = p.position[i, 1]
        for m in range(w1 - w0):
            work.wall_reference[m] = w.offset[w0 + m]
        work.flags[FLAG_REBUILD] = 0
        work.info[INFO_REBUILDS] += 1
        return CODE_OK

    @cuda.jit
    def samples_in_blocks(p, w, ct, spare, ws, dev, own, steps):
        """Up to ``steps`` steps of each sample of a batch (``own``: :class:`~granlab.engine.cuda.layout.Samples`)
        in a block of its own, the four launches of a step its phases between the block's barriers: each thread
        a stride of the sample's rows, then a run of its disks. A sample's rows lie in a segment of their own of
        the table ``ct`` and the block rebuilds them there when they are due (``sample_rebuild``): the blocks
        share no disk, wall or row and never wait for one another; each keeps its own step count."""
        b = cuda.blockIdx.x
        tid = cuda.threadIdx.x
        tallies = cuda.shared.array((TALLY_SIZE, THREADS), float64)
        gather = cuda.shared.array((GATHER_SIZE, THREADS), float64)
        out = cuda.local.array(GATHER_SIZE, float64)
        walls, cell, work = sample_views(w, ws, own, b)
        run = own.run[b]
        first_disk = own.ranges[b, R_DISKS]
        n = own.ranges[b, R_DISKS + 1] - first_disk
        for _ in range(steps):
            if run[RUN_STOP] != 0:  # written by thread 0 before the last barrier: every thread reads the same
                return
            if tid == 0 and work.flags[FLAG_REBUILD] != 0:
                code = sample_rebuild(p, w, ct, spare, own, b, work, dev.law[D0] + dev.numbers[N_SKIN])
                if code != CODE_OK:
                    run[RUN_CODE] = code
                    run[RUN_STOP] = 1
            cuda.syncthreads()  # every thread past the rebuild, and reading the same stop
            if run[RUN_STOP] != 0:
                return
            store = run[RUN_STEP] + 1 == dev.counts[C_N_STEPS]
            for s in range(TALLY_SIZE):
                tallies[s, tid] = 0.0
            k = own.ranges[b, R_ROWS] + tid
            while k < own.ranges[b, R_ROWS + 1]:
                row_forces(p, w, cell, ct, dev, k, ws.force_buffer, ws.wall_buffer, store, tallies, tid)
                k += THREADS
            reduce_block(tallies, tid, TALLIES)
            if tid == 0:
                rows_done(walls, cell, work, dev, run, tallies)
            cuda.syncthreads()
            disks_range(p, work, dev, run, STEP, first_disk + tid * n // THREADS, first_disk + (tid + 1) * n // THREADS,
                        out)
            for s in range(GATHER_SIZE):
                gather[s, tid] = out[s]
            reduce_block(gather, tid, GATHER)
            if tid == 0:
                disks_done(walls, cell, work, dev, run, gather, STEP, True)
            cuda.syncthreads()

    return contacts, after_contacts, start, disks, after_disks, steps_in_a_block, samples_in_blocks
