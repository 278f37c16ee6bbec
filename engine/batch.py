"""Samples side by side in one simulation: a study's small boxes stepped as one set of arrays.

A ratchet study (ratcheting Sec. IV B) cycles many boxes of a few dozen disks with one law and one load.
Stepped alone, a box of 16 disks costs about 1.2 µs a step, most of it the fixed work of a step (the
parallel regions, the walls, the tests) that does not grow with the disks; stepped together, the
samples share that work. :class:`Batch` lays the samples on a square lattice, each shifted by whole
multiples of a pitch twice the largest sample's span (so that no disk of one reaches another's), and
makes every wall meet its own sample's disks alone (:attr:`granlab.engine.params.Wall.disks`). The
batch is one :class:`~granlab.engine.simulation.Simulation` (any backend); :meth:`Batch.sample` brings
one sample back as a simulation of its own, in the batch's state.

The batch steps with the smallest of its samples' time steps. Shifting a position rounds it to the
precision of the shifted coordinate: a sample in a batch follows the same sample stepped alone
within rounding (relative 1e-12 over a few hundred steps, tests/test_batch.py), and, granular
packings being chaotic, apart from it over many cycles, as two runs on different thread counts do.
The batch's energy tallies (work, dissipation) are its samples' together: they are not split by
sample, and :meth:`Batch.sample` leaves each sample's tallies as they were when the batch was made.
"""

from __future__ import annotations

import math

import numpy as np

from .errors import ParameterError
from .kernels import integrate as k_integrate
from .params import Load
from .simulation import Simulation
from .state import ParticleState

SUMMED = {"cell/virial", "cell/kinetic", "workspace/energy", "workspace/virial_correction",
          "workspace/lagged_virial", "workspace/lagged_kinetic"}
"""State arrays of a batch that are its samples' summed (the others of the cell and the workspace are
the first sample's, or joined disk by disk and wall by wall)."""


class Batch:
    """``samples`` (simulations with the same law, walls and gravity, no periodic axis) side by side in
    one simulation, :attr:`sim`. ``samples`` are left as they are until :meth:`sample` brings one up
    to the batch's state."""

    def __init__(self, samples: list[Simulation]):
        if not samples:
            raise ParameterError("samples", 0, "at least one simulation")
        first = samples[0]
        for k, sample in enumerate(samples):
            if sample.cell_params is not None and any(sample.periodic):
                raise ParameterError(f"samples[{k}]", "a periodic cell", "walled samples: a periodic cell has "
                                                                        "no side to put another beside")
            for name, mine, theirs in (("law", sample.law, first.law),
                                       ("wall names", sample.walls.names, first.walls.names),
                                       ("gravity", tuple(sample.gravity), tuple(first.gravity)),
                                       ("backend", sample.backend, first.backend)):
                if mine != theirs:
                    raise ParameterError(f"samples[{k}] {name}", mine, f"the first sample's: {theirs}")
        self.samples = list(samples)
        self.disk_starts = np.cumsum([0] + [s.particles.count for s in samples])
        self.wall_starts = np.cumsum([0] + [s.walls.count for s in samples])
        self.shifts = lattice_shifts(samples)
        self._steps_at_start = [s.step for s in samples]
        self._times_at_start = [s.time for s in samples]
        self.sim = self._joined()

    def _joined(self) -> Simulation:
        """The batch's simulation: the samples' disks, walls and contacts numbered on and shifted."""
        first = self.samples[0]
        p = [s.particles for s in self.samples]
        particles = ParticleState(np.concatenate([q.position + shift for q, shift in zip(p, self.shifts)]),
                                  np.concatenate([q.radius for q in p]), mass=np.concatenate([q.mass for q in p]),
                                  inertia=np.concatenate([q.inertia for q in p]),
                                  kind=np.concatenate([q.kind for q in p]))
        walls = []
        for k, sample in enumerate(self.samples):
            disks = (int(self.disk_starts[k]), int(self.disk_starts[k + 1]))
            for wall, offset in zip(sample.wall_params, sample.walls.offset):
                per_length = wall.load_per_length_of
                walls.append(wall.replace(
                    name=batched_name(wall.name, k), position=offset + float(np.dot(wall.normal, self.shifts[k])),
                    load_per_length_of=None if per_length is None else tuple(batched_name(n, k) for n in per_length),
                    disks=disks))
        dt = min(s.dt for s in self.samples)
        sim = Simulation(particles, first.law, first.integration.replace(dt=dt), tuple(walls), None,
                         tuple(first.gravity), check_initial_overlap=False)
        sim.use_backend(first.backend)
        sim.restore_state(self._joined_state(dt))
        return sim

    def _joined_state(self, dt: float) -> dict:
        states = [s.export_state() for s in self.samples]
        joined = {}
        for key in states[0]:
            group = key.split("/")[0]
            if key in SUMMED:
                joined[key] = sum(state[key] for state in states)
            elif group in ("particles", "walls", "contacts") or key == "workspace/reference" \
                    or key == "workspace/wall_reference":
                joined[key] = np.concatenate([state[key] for state in states])
            else:
                joined[key] = states[0][key]
        joined["particles/position"] = np.concatenate(
            [state["particles/position"] + shift for state, shift in zip(states, self.shifts)])
        joined["workspace/reference"] = np.concatenate(
            [state["workspace/reference"] + shift for state, shift in zip(states, self.shifts)])
        for name in ("walls/offset", "workspace/wall_reference"):
            joined[name] = np.concatenate([state[name] + state["walls/normal"] @ shift
                                           for state, shift in zip(states, self.shifts)])
        loads = []
        for state, start in zip(states, self._times_at_start):
            load = state["walls/load"].copy()
            load[:, 3] += load[:, 2] * start  # each sample's load on the batch's clock, 0 at the sample's start
            loads.append(load)
        joined["walls/load"] = np.concatenate(loads)
        joined["walls/length_ref"] = np.concatenate(
            [np.where(state["walls/length_ref"] >= 0, state["walls/length_ref"] + start, -1)
             for state, start in zip(states, self.wall_starts)])
        self._join_contacts(states, joined)
        flags = np.zeros(k_integrate.FLAG_SIZE, dtype=np.int64)
        flags[k_integrate.FLAG_REBUILD] = max(state["workspace/flags"][k_integrate.FLAG_REBUILD] for state in states)
        joined["workspace/flags"] = flags
        joined["workspace/info"] = np.zeros_like(states[0]["workspace/info"])
        joined.update(step=np.int64(0), step_origin=np.int64(0), time_origin=np.float64(0.0), dt=np.float64(dt))
        return joined

    def _join_contacts(self, states, joined) -> None:
        """Rows numbered on: a disk by its sample's first disk, a wall by its sample's first wall after every
        disk; a wall's anchor (a coordinate along it) moves with the shift."""
        total = int(self.disk_starts[-1])
        columns_j, anchors = [], []
        for k, state in enumerate(states):
            n = self.samples[k].particles.count
            j = state["contacts/particle_j"]
            wall = j >= n
            columns_j.append(np.where(wall, total + self.wall_starts[k] + j - n, j + self.disk_starts[k]))
            normal = state["walls/normal"][np.where(wall, j - n, 0)]
            along = -normal[:, 1] * self.shifts[k][0] + normal[:, 0] * self.shifts[k][1]
            anchors.append(state["contacts/anchor_angle_j"] + np.where(wall, along, 0.0))
        joined["contacts/particle_i"] = np.concatenate(
            [state["contacts/particle_i"] + start for state, start in zip(states, self.disk_starts)])
        joined["contacts/particle_j"] = np.concatenate(columns_j)
        joined["contacts/anchor_angle_j"] = np.concatenate(anchors)

    # ------------------------------------------------------------------ the samples' loads and lengths
    @property
    def count(self) -> int:
        return len(self.samples)

    def wall_index(self, k: int, name: str) -> int:
        """Index in the batch of sample ``k``'s wall ``name``."""
        return self.sim.wall_index(batched_name(name, k))

    def set_wall_load(self, name: str, load: Load) -> None:
        """Load wall ``name`` of every sample."""
        for k in range(self.count):
            self.sim.set_wall_load(batched_name(name, k), load)

    def box_lengths(self) -> np.ndarray:
        """``(samples, 2)``: each sample's box lengths (the distance between its walls named left and right,
        bottom and top)."""
        offset = self.sim.walls.offset
        lengths = np.empty((self.count, 2))
        for k in range(self.count):
            for axis, (low, high) in enumerate((("left", "right"), ("bottom", "top"))):
                lengths[k, axis] = -(offset[self.wall_index(k, low)] + offset[self.wall_index(k, high)])
        return lengths

    # ------------------------------------------------------------------ one sample back
    def sample(self, k: int) -> Simulation:
        """Sample ``k`` (the simulation given) brought to the batch's state, unshifted, its clock on by the
        batch's steps and time; its energy tallies are those it had when the batch was made."""
        sample = self.samples[k]
        state = sample.export_state()
        whole = self.sim.export_state()
        disks = slice(self.disk_starts[k], self.disk_starts[k + 1])
        walls = slice(self.wall_starts[k], self.wall_starts[k + 1])
        for key in state:
            group, _, name = key.partition("/")
            if group == "particles" or key == "workspace/reference":
                state[key] = whole[key][disks]
            elif group == "walls":
                state[key] = whole[key][walls]
        state["particles/position"] = state["particles/position"] - self.shifts[k]
        state["workspace/reference"] = state["workspace/reference"] - self.shifts[k]
        for name in ("walls/offset", "workspace/wall_reference"):
            state[name] = whole[name][walls] - state["walls/normal"] @ self.shifts[k]
        state["walls/length_ref"] = sample.walls.length_ref.copy()
        # a load's phase is counted on the batch's clock, which started at 0 where the sample's stood at its start
        state["walls/load"][:, 3] -= state["walls/load"][:, 2] * self._times_at_start[k]
        state.update(self._sample_contacts(k, whole))
        state["workspace/flags"] = whole["workspace/flags"].copy()
        dt = float(whole["dt"])
        state["step"] = np.int64(self._steps_at_start[k] + int(whole["step"]))
        state["step_origin"] = state["step"]
        state["time_origin"] = np.float64(self._times_at_start[k] + self.sim.time)
        state["dt"] = np.float64(dt)
        sample.restore_state(state)
        return sample

    def _sample_contacts(self, k: int, whole: dict) -> dict:
        total = int(self.disk_starts[-1])
        n = self.samples[k].particles.count
        i = whole["contacts/particle_i"]
        rows = (i >= self.disk_starts[k]) & (i < self.disk_starts[k + 1])
        contacts = {key: value[rows] for key, value in whole.items() if key.startswith("contacts/")}
        j = contacts["contacts/particle_j"]
        wall = j >= total
        contacts["contacts/particle_i"] = contacts["contacts/particle_i"] - self.disk_starts[k]
        contacts["contacts/particle_j"] = np.where(wall, n + j - total - self.wall_starts[k], j - self.disk_starts[k])
        normal = self.sim.walls.normal[np.where(wall, j - total, 0)]
        along = -normal[:, 1] * self.shifts[k][0] + normal[:, 0] * self.shifts[k][1]
        contacts["contacts/anchor_angle_j"] = contacts["contacts/anchor_angle_j"] - np.where(wall, along, 0.0)
        return contacts


def batched_name(name: str, k: int) -> str:
    """The name in a batch of sample ``k``'s wall ``name``."""
    return f"{name}#{k}"


def lattice_shifts(samples: list[Simulation]) -> np.ndarray:
    """``(samples, 2)``: the shift of each sample, a square lattice (row by row) whose pitch is twice the
    largest extent of any sample's disks and walls, so that samples a cell apart stay a span apart."""
    lows, highs = [], []
    for sample in samples:
        p = sample.particles
        lows.append((p.position - p.radius[:, None]).min(axis=0))
        highs.append((p.position + p.radius[:, None]).max(axis=0))
    span = float((np.max(highs, axis=0) - np.min(lows, axis=0)).max())
    pitch = 2.0 * span
    columns = math.ceil(math.sqrt(len(samples)))
    return np.array([(pitch * (k % columns), pitch * (k // columns)) for k in range(len(samples))], dtype=float)
