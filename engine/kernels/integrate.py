"""Velocity-Verlet time stepping of disks, walls and the periodic cell.

:func:`advance` runs ``n_steps`` steps without returning to Python. One step:

1. half kick ``v += dt/2 f/m``, ``w += dt/2 tau/I`` of disks, force-controlled walls and
   a stress-controlled cell (Gilabert Eq. 3); drift of walls, cell lengths (applied
   affinely to positions), positions and angles by ``dt``;
2. if some disk, wall or cell length moved so far since the last rebuild that a pair could
   have come within range unseen, rebuild the contact table at the current positions
   (history carried over);
3. contact forces at the new positions (half-step velocities in the viscous terms);
4. gravity and applied loads, second half kick; energy tallies; divergence checks.

Inside one call the second half kick of a step and the first half kick and drift of the
next are one pass over the disks (leapfrog form). Between calls the state is always at a
whole step, except when the contact table overflows: the call then returns in the middle
of a step (``FLAG_PHASE`` = drifted) and the next call, with a larger table, resumes it.

Numba types a constant argument as a literal and compiles the kernel it is passed to once for
each value. Flags, counts and chunk numbers that differ between call sites (or between the one-
and the several-thread step, whose contact loop is then compiled once for both) are passed as
``np.bool_`` and ``np.int64`` values, but where a constant makes the loop over the disks leaner:
the pass of every step but a call's last gets its flags, and a one-thread pass its one chunk, as
constants (a compile of their own; measured: 20 % less time in the pass over the disks).
"""

import math

import numpy as np
from numba import prange, uint64

from ..state import CELL_NONE, CELL_STRAIN_RATE, CELL_STRESS, WALL_FIXED, WALL_FORCE
from .contacts import (TALLY_DAMPING, TALLY_MAX_OVERLAP, TALLY_OPENING, TALLY_OVERLAPPING, TALLY_ROLLING,
                       TALLY_SLIDING, TALLY_VXX, TALLY_WALL_WORK, contact_chunk, contact_chunks_parallel)
from .cache import for_model
from .jit import JIT, KERNEL, PARALLEL, njit
from .laws import D0
from .neighbours import build_table, copy_table
from .tangential import MODELS, model_key

CODE_OK, CODE_OVERFLOW, CODE_LOST_CONTACT, CODE_NAN, CODE_OVERLAP, CODE_REBUILD, CODE_TUNNEL = range(7)
CODE_GO_ON = -1

# energy tallies accumulated over the run (work done on the disks is positive)
(E_DAMPING, E_SLIDING, E_ROLLING, E_OPENING, E_WALL_WORK, E_CELL_WORK, E_PRESCRIBED_WORK,
 E_EXTERNAL_WORK) = range(8)
ENERGY_TALLY_SIZE = 8

# results of a particle pass
G_KINETIC_X, G_KINETIC_Y, G_PRESCRIBED, G_EXTERNAL, G_DISPLACEMENT, G_BAD = range(6)
G_VXX, G_VXY, G_VYX, G_VYY = 6, 7, 8, 9
G_STEP_MOVE, G_MOVER = 10, 11
GATHER_SIZE = 12

# flags
FLAG_REBUILD, FLAG_PHASE = 0, 1
FLAG_SIZE = 2
PHASE_ON_STEP, PHASE_DRIFTED = 0, 1

# info written by advance
INFO_NEEDED, INFO_LOST, INFO_OVERLAPPING, INFO_MAX_OVERLAP, INFO_REBUILDS, INFO_MOVER = range(6)
INFO_SIZE = 6


@njit(**KERNEL)
def particle_pass(p, force_buffer, touched, n_chunks, gravity, has_loads, gather, store, half, kicks, drift, scale_x,
                  scale_y, reference, partial, out, parallel):
    """One pass over the disks: gather forces, kick, drift.

    - ``gather``: sum the chunk buffers (zeroing them) into the contact force and torque, each
      chunk's only for the disks its rows touched (``touched (T, 2)``: the lowest and highest);
      tally their virial ``sum F_i ⊗ x_i``; add gravity and, if ``has_loads``, the applied
      loads; tally, with the whole-step velocity ``v + half f/m``, the kinetic stress
      ``sum m v_a²`` and the work of loads over ``2 half``;
    - tally the work of prescribed motions by the trapezoid rule, each drift's half with the
      force at its start (the stored force without ``gather``) and half with the force at its
      end, the drift's velocity being the ``predicted_motion`` a prescribed disk keeps (a force
      at one end alone, as before, was first order in dt: 1 % of the spring's energy a side of the
      closed path, the sides' errors of one sign);
      ``store``: keep the totals in ``force``/``torque`` (else they stay those of the last
      store: a call of :func:`advance` stores on its last pass only);
    - ``kicks`` half kicks ``v += half f/m``, ``w += half tau/I`` (dynamic disks only; without
      ``gather`` with the stored forces): the second half kick of a step and the first of the
      next are two additions, exactly as when a run stops and resumes between them;
    - drift ``x = x scale + drift v``, ``theta += drift w`` (every disk);
    - the velocities predicted at the next whole step, ``v + half f/m`` after the kicks, for the
      dashpots of the next contact pass (prescribed velocities as they are).

    Fills ``out``: kinetic stress (x, y), prescribed and external work, the largest squared
    distance of a disk from its neighbour-list ``reference``, the number of non-finite disks,
    the virial sums, and the largest drift of a disk in radii, with that disk. With ``parallel`` None
    (:func:`advance`) the disks are one chunk, here; with ``parallel`` True they are split among ``n_chunks``
    threads, each filling a row of ``partial (T, GATHER_SIZE)``.
    """
    n = p.position.shape[0]
    if parallel is None:
        particle_range(p, force_buffer, touched, 1, gravity, has_loads, gather, store, half, kicks, drift, scale_x,
                       scale_y, reference, 0, n, out)
        return
    _particle_ranges_parallel(p, force_buffer, touched, n_chunks, gravity, has_loads, gather, store, half, kicks, drift,
                              scale_x, scale_y, reference, partial)
    for k in range(GATHER_SIZE):
        out[k] = 0.0
    for c in range(n_chunks):
        for k in range(G_STEP_MOVE):
            if k == G_DISPLACEMENT:
                out[k] = max(out[k], partial[c, k])
            else:
                out[k] += partial[c, k]
        if partial[c, G_STEP_MOVE] > out[G_STEP_MOVE]:
            out[G_STEP_MOVE] = partial[c, G_STEP_MOVE]
            out[G_MOVER] = partial[c, G_MOVER]


@njit(**PARALLEL)
def _particle_ranges_parallel(p, force_buffer, touched, n_chunks, gravity, has_loads, gather, store, half, kicks, drift,
                              scale_x, scale_y, reference, partial):
    n = p.position.shape[0]
    for c in prange(n_chunks):
        particle_range(p, force_buffer, touched, n_chunks, gravity, has_loads, gather, store, half, kicks, drift, scale_x,
                       scale_y, reference, c * n // n_chunks, (c + 1) * n // n_chunks, partial[c])


@njit(**KERNEL)
def particle_range(p, force_buffer, touched, n_chunks, gravity, has_loads, gather, store, half, kicks, drift, scale_x,
                   scale_y, reference, lo, hi, out):
    """:func:`particle_pass` for disks ``[lo, hi)``."""
    position = p.position
    velocity = p.velocity
    angle = p.angle
    omega = p.omega
    mass = p.mass
    inv_mass = p.inv_mass
    inv_inertia = p.inv_inertia
    force = p.force
    torque = p.torque
    external_force = p.external_force
    external_torque = p.external_torque
    predicted = p.predicted_motion
    gx = gravity[0]
    gy = gravity[1]
    work_dt = 2.0 * half
    kinetic_x = 0.0
    kinetic_y = 0.0
    prescribed = 0.0
    external = 0.0
    displacement = 0.0
    mover_move2 = 0.0  # the largest drift² / radius² so far, as a fraction: no division per disk
    mover_r2 = 1.0
    mover = 0
    vxx = 0.0
    vxy = 0.0
    vyx = 0.0
    vyy = 0.0
    bad = 0
    for i in range(uint64(lo), uint64(hi)):
        x = position[i, 0]
        y = position[i, 1]
        vx = velocity[i, 0]
        vy = velocity[i, 1]
        w = omega[i]
        im = inv_mass[i]
        if gather:
            fx = 0.0
            fy = 0.0
            tq = 0.0
            for c in range(n_chunks):
                if touched[c, 0] <= i <= touched[c, 1]:  # a chunk's buffer is zero outside the disks its rows touch
                    fx += force_buffer[c, i, 0]
                    fy += force_buffer[c, i, 1]
                    tq += force_buffer[c, i, 2]
                    force_buffer[c, i, 0] = 0.0
                    force_buffer[c, i, 1] = 0.0
                    force_buffer[c, i, 2] = 0.0
            vxx += fx * x
            vxy += fx * y
            vyx += fy * x
            vyy += fy * y
            if im > 0.0:
                m = mass[i]
                fx += m * gx
                fy += m * gy
                if has_loads:
                    efx = external_force[i, 0]
                    efy = external_force[i, 1]
                    etq = external_torque[i]
                    fx += efx
                    fy += efy
                    tq += etq
                    external += (efx * (vx + half * fx * im) + efy * (vy + half * fy * im)
                                 + etq * (w + half * tq * inv_inertia[i])) * work_dt
                vx_step = vx + half * fx * im
                vy_step = vy + half * fy * im
                kinetic_x += m * vx_step * vx_step
                kinetic_y += m * vy_step * vy_step
            else:  # the drift that brought a prescribed disk here: its force at the end, half the trapezoid
                prescribed -= (fx * predicted[i, 0] + fy * predicted[i, 1] + tq * predicted[i, 2]) * half
            if store:
                force[i, 0] = fx
                force[i, 1] = fy
                torque[i] = tq
        else:
            fx = force[i, 0]
            fy = force[i, 1]
            tq = torque[i]
        if im > 0.0:
            ii = inv_inertia[i]
            for _ in range(kicks):
                vx += half * fx * im
                vy += half * fy * im
                w += half * tq * ii
            velocity[i, 0] = vx
            velocity[i, 1] = vy
            omega[i] = w
            predicted[i, 0] = vx + half * fx * im
            predicted[i, 1] = vy + half * fy * im
            predicted[i, 2] = w + half * tq * ii
        else:  # the drift ahead, its force at the start: the other half of its trapezoid
            prescribed -= (fx * vx + fy * vy + tq * w) * 0.5 * drift
            predicted[i, 0] = vx
            predicted[i, 1] = vy
            predicted[i, 2] = w
        x = x * scale_x + drift * vx
        y = y * scale_y + drift * vy
        position[i, 0] = x
        position[i, 1] = y
        angle[i] += drift * w
        dx = x - reference[i, 0]
        dy = y - reference[i, 1]
        displacement = max(displacement, dx * dx + dy * dy)
        r = p.radius[i]
        move2 = drift * drift * (vx * vx + vy * vy)
        if move2 * mover_r2 > mover_move2 * (r * r):
            mover_move2 = move2
            mover_r2 = r * r
            mover = i
        if not math.isfinite(vx + vy + w + x + y):
            bad += 1
    out[G_KINETIC_X] = kinetic_x
    out[G_KINETIC_Y] = kinetic_y
    out[G_PRESCRIBED] = prescribed
    out[G_EXTERNAL] = external
    out[G_DISPLACEMENT] = displacement
    out[G_BAD] = bad
    out[G_VXX] = vxx
    out[G_VXY] = vxy
    out[G_VYX] = vyx
    out[G_VYY] = vyy
    out[G_STEP_MOVE] = math.sqrt(mover_move2 / mover_r2)
    out[G_MOVER] = mover


@njit(**KERNEL)
def wall_load(w, m, t):
    """Applied force on wall ``m`` at time ``t``: ``sigma(t)`` times the box length it spans."""
    base = w.load[m, 0]
    amplitude = w.load[m, 1]
    sigma = base + amplitude * (1.0 - math.cos(w.load[m, 2] * t + w.load[m, 3]))
    a = w.length_ref[m, 0]
    if a < 0:
        return sigma
    b = w.length_ref[m, 1]
    return sigma * -(w.offset[a] + w.offset[b])


@njit(**KERNEL)
def walls_step(w, t, half, kicks, drift):
    """``kicks`` half kicks of force-controlled walls with the load at ``t`` and the disks' push;
    drift of moving walls."""
    for m in range(w.offset.shape[0]):
        if w.mode[m] == WALL_FORCE:
            acceleration = (wall_load(w, m, t) + w.particle_force[m]) * w.inv_mass[m]
            for _ in range(kicks):
                w.velocity[m] += half * acceleration
    for m in range(w.offset.shape[0]):
        if w.mode[m] != WALL_FIXED:
            w.offset[m] += drift * w.velocity[m]
        w.tangential_position[m] += drift * w.tangential_velocity[m]


@njit(**KERNEL)
def measured_stress(cell, virial, kinetic, axis):
    """Gilabert's sigma^M_aa = (sum m v_a² + sum f_a r_a) / A (compression positive)."""
    return (kinetic[axis] + virial[axis, axis]) / (cell.length[0] * cell.length[1])


@njit(**KERNEL)
def cell_step(cell, virial, kinetic, half, kicks, drift, scale):
    """``kicks`` half kicks of a stress-controlled length (d²L/dt² = L0 (sigma^M - sigma^I) / M,
    Gilabert Eq. 3, with |dL/dt| <= max_strain_rate L0), then the drift of the lengths;
    ``scale`` gets the affine factors of the drift. The measured stress comes from ``virial``
    and ``kinetic``: those of the previous step (the virial of a step's forces is summed by
    the same pass that drifts the disks).
    """
    for a in range(2):
        scale[a] = 1.0
        if cell.control[a] == CELL_STRESS:
            mismatch = measured_stress(cell, virial, kinetic, a) - cell.target_stress[a]
            cap = cell.max_strain_rate[0] * cell.reference_length[a]
            for _ in range(kicks):
                cell.rate[a] += half * cell.reference_length[a] * mismatch / cell.mass[0]
                cell.rate[a] = min(cap, max(-cap, cell.rate[a]))
        if cell.control[a] == CELL_STRESS or cell.control[a] == CELL_STRAIN_RATE:
            new_length = cell.length[a] + drift * cell.rate[a]
            scale[a] = new_length / cell.length[a]
            cell.length[a] = new_length


@njit(**KERNEL)
def contact_totals(w, ws, n_chunks):
    """After the contact pass: the walls' reactions, the virial corrections and the energy tallies,
    summed over the chunk buffers."""
    for m in range(w.offset.shape[0]):
        total = 0.0
        for c in range(n_chunks):
            total += ws.wall_buffer[c, m]
        w.particle_force[m] = total
    tallies = ws.tally_buffer
    for a in range(2):
        for b in range(2):
            total = 0.0
            for c in range(n_chunks):
                total += tallies[c, TALLY_VXX + 2 * a + b]
            ws.virial_correction[a, b] = total
    worst = 0.0
    overlapping = 0.0
    for c in range(n_chunks):
        ws.energy[E_DAMPING] += tallies[c, TALLY_DAMPING]
        ws.energy[E_SLIDING] += tallies[c, TALLY_SLIDING]
        ws.energy[E_ROLLING] += tallies[c, TALLY_ROLLING]
        ws.energy[E_OPENING] += tallies[c, TALLY_OPENING]
        ws.energy[E_WALL_WORK] += tallies[c, TALLY_WALL_WORK]
        overlapping += tallies[c, TALLY_OVERLAPPING]
        worst = max(worst, tallies[c, TALLY_MAX_OVERLAP])
    ws.info[INFO_OVERLAPPING] = overlapping
    ws.info[INFO_MAX_OVERLAP] = worst


@njit(**JIT)
def rebuild(p, w, cell, ct, spare, ws, law, skin):
    """Rebuild the contact table into ``spare``, then commit it to ``ct``. Returns a code."""
    periodic = (cell.control[0] != CELL_NONE, cell.control[1] != CELL_NONE)
    needed, lost = build_table(p.position, p.radius, p.inv_mass, cell.length, periodic, w.normal, w.offset,
                               w.reach, law[D0] + skin, ct, spare, ws.wrapped, ws.wraps)
    if needed > spare.particle_i.shape[0]:
        ws.info[INFO_NEEDED] = needed
        return CODE_OVERFLOW
    if lost > 0:
        ws.info[INFO_LOST] = lost
        return CODE_LOST_CONTACT
    copy_table(spare, ct)
    rebuilt_disks(p, ws, 0, p.position.shape[0])
    rebuilt_boundaries(w, cell, ws)
    return CODE_OK


@njit(**KERNEL)
def rebuilt_disks(p, ws, first, stop):
    """Disks ``[first, stop)`` after a rebuild: at their wrapped positions, their references for the next."""
    for i in range(first, stop):
        for a in range(2):
            p.position[i, a] = ws.wrapped[i, a]
            ws.reference[i, a] = ws.wrapped[i, a]


@njit(**KERNEL)
def rebuilt_boundaries(w, cell, ws):
    """After a rebuild: the walls' and the cell's references for the next, the rebuild done and counted."""
    for m in range(w.offset.shape[0]):
        ws.wall_reference[m] = w.offset[m]
    for a in range(2):
        ws.length_reference[a] = cell.length[a]
    ws.flags[FLAG_REBUILD] = 0
    ws.info[INFO_REBUILDS] += 1


@njit(**KERNEL)
def _needs_rebuild(w, cell, ws, skin):
    """Whether a pair distance may have changed by the skin since the last rebuild."""
    moved = math.sqrt(ws.gather[G_DISPLACEMENT])
    wall_move = 0.0
    for m in range(w.offset.shape[0]):
        wall_move = max(wall_move, abs(w.offset[m] - ws.wall_reference[m]))
    cell_move = 0.0
    for a in range(2):
        if cell.control[a] != CELL_NONE:
            cell_move += 2.0 * abs(cell.length[a] - ws.length_reference[a])
    return moved + max(moved, wall_move) + cell_move >= skin


@njit(**KERNEL)
def _pass(p, cell, ws, gravity, has_loads, n_chunks, gather, store, half, kicks, drift, scale, parallel):
    """Particle pass, then, on ``gather``, :func:`pass_totals`."""
    if parallel is None:  # particle_pass's one chunk, a call less deep to compile
        particle_range(p, ws.force_buffer, ws.touched, 1, gravity, has_loads, gather, store, half, kicks, drift, scale[0],
                       scale[1], ws.reference, 0, p.position.shape[0], ws.gather)
    else:
        particle_pass(p, ws.force_buffer, ws.touched, n_chunks, gravity, has_loads, gather, store, half, kicks, drift,
                      scale[0], scale[1], ws.reference, ws.partial_gather, ws.gather, parallel)
    if gather:
        pass_totals(cell, ws, scale)


@njit(**KERNEL)
def pass_totals(cell, ws, scale):
    """After a pass that gathered the forces: the cell's new virial and kinetic stress (the previous
    ones kept for the barostat), the work of loads, of prescribed motions and of the cell's affine drift."""
    for a in range(2):
        ws.lagged_kinetic[a] = cell.kinetic[a]
        for b in range(2):
            ws.lagged_virial[a, b] = cell.virial[a, b]
            cell.virial[a, b] = ws.gather[G_VXX + 2 * a + b] + ws.virial_correction[a, b]
        ws.energy[E_CELL_WORK] -= (scale[a] - 1.0) * cell.virial[a, a]
    cell.kinetic[0] = ws.gather[G_KINETIC_X]
    cell.kinetic[1] = ws.gather[G_KINETIC_Y]
    ws.energy[E_PRESCRIBED_WORK] += ws.gather[G_PRESCRIBED]
    ws.energy[E_EXTERNAL_WORK] += ws.gather[G_EXTERNAL]


@njit(**JIT, inline="always")
def advance(p, w, cell, ct, spare, ws, law, run, tangential_model, parallel):
    """Run up to ``run.n_steps`` velocity-Verlet steps (``run``: :class:`granlab.engine.state.RunOptions`)
    with the laws of tangential model ``tangential_model`` (its code); returns ``(steps_done, code)``.

    One machine code is compiled for each model and for each kind of ``parallel``, when first
    used: ``None``, one thread (nothing parallel is compiled); ``True``, ``run.n_chunks`` threads.
    Python calls it through :data:`ADVANCE`, into whose kernels it is inlined.

    Step ``k`` of this call ends at ``time_origin + (step_offset + k + 1) dt``. ``dt = 0`` with
    ``n_steps = 1`` only evaluates the forces of the current state. This outer loop rebuilds
    the contact table (which allocates); the steps run in :func:`_steps`, which never
    allocates and so needs no reference counting. A run split into several calls does the
    same arithmetic as one call: it continues bit for bit.
    """
    if run.n_steps == 0:
        return 0, CODE_OK
    scale = ws.scale
    if ws.flags[FLAG_PHASE] == PHASE_ON_STEP:
        code = _start(p, w, cell, ws, run, scale, parallel)
        if code != CODE_GO_ON:
            return 0, code
    step = np.int64(0)
    while True:
        if ws.flags[FLAG_REBUILD]:
            code = rebuild(p, w, cell, ct, spare, ws, law, run.skin)
            if code != CODE_OK:
                return step, code
        chunk_reach(ct, p.position.shape[0], run.n_chunks, ws.touched)
        step, code = _steps(p, w, cell, ct, ws, law, run, step, scale, tangential_model, parallel)
        if code != CODE_REBUILD:
            return step, code


@njit(**KERNEL)
def chunk_reach(ct, n, n_chunks, touched):
    """``touched[c]``: the lowest and highest disk the rows of chunk ``c`` of the contact table touch (a wall
    is no disk), outside which its force buffer stays zero: the pass over the disks reads and zeroes each
    chunk's buffer between the two only (on the reference system at 10⁵ disks, 2.1 buffers a disk
    instead of one for each of 16 chunks). Rows change only at a rebuild: computed once a call and after
    each rebuild, not in the contact pass (there, 2 ns a row)."""
    count = ct.count[0]
    for c in range(n_chunks):
        first = uint64(n)
        last = uint64(0)
        for k in range(c * count // n_chunks, (c + 1) * count // n_chunks):
            i = uint64(ct.particle_i[k])
            j = uint64(ct.particle_j[k])
            first = min(first, i)
            last = max(last, i if j >= n else max(i, j))
        touched[c, 0] = first
        touched[c, 1] = last


def _advance_for(tangential_model: int):
    """:func:`advance` with the code of a tangential model as a constant. Numba compiles ``advance``
    for the code as a literal; called from Python with the code as an argument, it would try the
    code as a plain integer first and fail, at every call (some 20 ms)."""

    def advance_model(p, w, cell, ct, spare, ws, law, run, parallel):
        return advance(p, w, cell, ct, spare, ws, law, run, tangential_model, parallel)

    advance_model.__qualname__ = advance_model.__name__ = f"advance_{model_key(tangential_model)}"
    return njit(**JIT)(for_model(advance_model, tangential_model))


ADVANCE = {code: _advance_for(code) for code in MODELS}
"""The step driver by tangential model code: ``ADVANCE[code](p, w, cell, ct, spare, ws, law, run, parallel)``."""


@njit(**KERNEL)
def _tunnels(ws, max_overlap):
    """Whether the last drift moved a disk further than ``max_overlap / 2`` of its radius: it
    could then meet a neighbour head-on at an overlap above ``max_overlap``, or pass through it
    between two steps. Records the disk in ``ws.info``."""
    if not ws.gather[G_STEP_MOVE] > 0.5 * max_overlap:
        return False
    ws.info[INFO_MOVER] = ws.gather[G_MOVER]
    return True


@njit(**KERNEL)
def _start(p, w, cell, ws, run, scale, parallel):
    """First half kick and drift of a call that starts on a whole step; returns :func:`start_end`'s code."""
    dt = run.dt
    half = 0.5 * dt
    kicks, no = np.int64(1), np.bool_(False)
    start_boundaries(w, cell, ws, run.time_origin + run.step_offset * dt, half, dt, scale)
    _pass(p, cell, ws, run.gravity, run.has_loads, run.n_chunks, no, no, half, kicks, dt, scale, parallel)
    return start_end(w, cell, ws, run.skin, run.max_overlap)


@njit(**KERNEL)
def start_end(w, cell, ws, skin, max_overlap):
    """After a call's first half kick and drift: its phase, a rebuild flagged if due, and the code the call
    ends with at once (a divergence), or ``CODE_GO_ON``."""
    ws.flags[FLAG_PHASE] = PHASE_DRIFTED
    ws.energy[E_PRESCRIBED_WORK] += ws.gather[G_PRESCRIBED]
    if _needs_rebuild(w, cell, ws, skin):
        ws.flags[FLAG_REBUILD] = 1
    if ws.gather[G_BAD] > 0:
        return CODE_NAN
    if _tunnels(ws, max_overlap):
        return CODE_TUNNEL
    return CODE_GO_ON


@njit(**KERNEL)
def start_boundaries(w, cell, ws, t, half, dt, scale):
    """The first half kick and drift of the walls (their load at ``t``) and of the cell, in a call that
    starts on a whole step; the work of the cell's affine drift."""
    kicks = np.int64(1)
    walls_step(w, t, half, kicks, dt)
    cell_step(cell, ws.lagged_virial, ws.lagged_kinetic, half, kicks, dt, scale)
    for a in range(2):
        ws.energy[E_CELL_WORK] -= (scale[a] - 1.0) * cell.virial[a, a]


@njit(**KERNEL)
def step_end(w, cell, ws, last, skin, max_overlap):
    """After a step's pass over the disks: the code it ends the call with (a divergence, the call's
    last step, a rebuild due, which it flags), or ``CODE_GO_ON``."""
    if ws.gather[G_BAD] > 0:
        return CODE_NAN
    if ws.info[INFO_OVERLAPPING] > 0:
        return CODE_OVERLAP
    if _tunnels(ws, max_overlap):
        return CODE_TUNNEL
    if last:
        return CODE_OK
    if _needs_rebuild(w, cell, ws, skin):
        ws.flags[FLAG_REBUILD] = 1
        return CODE_REBUILD
    return CODE_GO_ON


@njit(**KERNEL)
def _steps(p, w, cell, ct, ws, law, run, step, scale, tangential_model, parallel):
    """Steps from a drifted state until the end, an error, or a rebuild is due (``CODE_REBUILD``).
    The last step kicks once and does not drift: the state ends on a whole step."""
    gravity, has_loads = run.gravity, run.has_loads
    dt, time_origin, step_offset, n_steps = run.dt, run.time_origin, run.step_offset, run.n_steps
    skin, max_overlap, n_chunks = run.skin, run.max_overlap, run.n_chunks
    half = 0.5 * dt
    gather = np.bool_(True)
    while True:
        last = step + 1 == n_steps
        if parallel is None:  # the contact pass (contacts.contact_forces), a call less deep to compile
            contact_chunk(p, w, cell, ct, ws, law, run, tangential_model, last, np.int64(0))
        else:
            contact_chunks_parallel(p, w, cell, ct, ws, law, run, tangential_model, last)
        contact_totals(w, ws, n_chunks)
        t = time_origin + (step_offset + step + 1) * dt
        kicks = np.int64(1) if last else np.int64(2)
        drift = 0.0 if last else dt
        walls_step(w, t, half, kicks, drift)
        cell_step(cell, cell.virial, cell.kinetic, half, kicks, drift, scale)
        if last:  # a second half kick alone: the pass that starts a call does the same with one drift
            _pass(p, cell, ws, gravity, has_loads, n_chunks, gather, last, half, kicks, drift, scale, parallel)
            ws.flags[FLAG_PHASE] = PHASE_ON_STEP
        else:  # every other step: the pass compiled for these flags as constants, its loop the leanest
            _pass(p, cell, ws, gravity, has_loads, n_chunks, True, False, half, 2, dt, scale, parallel)
        step += 1
        code = step_end(w, cell, ws, last, skin, max_overlap)
        if code != CODE_GO_ON:
            return step, code
