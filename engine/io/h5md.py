"""Run files: HDF5 after H5MD 1.1, appended frame by frame, with checkpoints.

Layout (``docs/run-files.md`` describes every dataset)::

    /h5md                         version = [1, 1]; /author, /creator
    /particles/all/box            dimension = 2, boundary = [x, y]; edges: time-dependent
    /particles/all/{position, velocity, angle, omega, radius, mass}   time-dependent elements
    /particles/all/kind           per-disk kind (0 dynamic, 1 fixed, 2 kinematic)
    /contacts                     the contact table of each frame (GranLab extension)
    /observables/{energy, walls, stress}   time series at the frames
    /observables/cycles           one record per loading cycle
    /observables/contact_paths    (F_n, F_t, status) of watched contacts
    /observables/lab              the lab's time series (one dataset per series) and its settings per frame
    /parameters                   every parameter (attributes, JSON) and the scene text
    /checkpoint                   two slots of the full state; /checkpoint/valid names the good one

A time-dependent element is a group with ``step``, ``time`` and ``value`` datasets whose first
axis is the frame. The file is written in SWMR mode and flushed after every frame, cycle and
checkpoint, so a run killed at any moment leaves a file readable up to its last complete frame.
"""

from __future__ import annotations

import dataclasses
import errno
import fcntl
import functools
import json
import os
import resource
import signal
import struct
import sys
import time
import traceback
import weakref
from pathlib import Path

import h5py
import numpy as np

from .. import __version__, stopping
from ..checkpoint import HUGE, CheckpointError
from ..costs import free_bytes
from ..errors import GranLabError, OutputError, WriteFailed, one_line
from ..params import CELL_CONTROLS, WALL_MODES, ContactLaw, Integration, Load, PeriodicCell, Wall
from ..simulation import Simulation, cell_control_names, fixed_cell_control
from ..state import CELL_NONE, STATUS_NAMES, ParticleState
from . import superblock
from .inputs import require_file
from .outputs import failed_write_reason, occupied

ENERGY_FIELDS = ("kinetic", "stored", "gravity", "dissipated", "work_in", "balance", "dissipated_damping",
                 "dissipated_sliding", "dissipated_rolling", "dissipated_opening", "work_walls", "work_cell",
                 "work_prescribed", "work_external")
CONTACT_FIELDS = (("pair", np.int32, (2,)), ("image", np.int8, (2,)), ("status", np.int8, ()),
                  ("normal_force", np.float64, ()), ("elastic_normal_force", np.float64, ()),
                  ("tangential_force", np.float64, ()),
                  ("surface_gap", np.float64, ()), ("tangential_spring", np.float64, ()),
                  ("rolling_spring", np.float64, ()), ("rolling_distance", np.float64, ()))
CYCLE_FIELDS = ("cycle", "step", "time", "length_x", "length_y")
PARTICLE_ELEMENTS = (("position", (2,)), ("velocity", (2,)), ("angle", ()), ("omega", ()), ("radius", ()),
                     ("mass", ()))


FRAME_OBSERVABLES = (("wall_position", "observables/walls/position"), ("wall_force", "observables/walls/force"),
                     ("wall_mode", "observables/walls/mode"), ("stress", "observables/stress"),
                     ("law_json", "observables/law"), ("lab_settings_json", "observables/lab/settings"),
                     ("lab_phase", "observables/lab/phase"),
                     ("cell_control", "observables/cell/control"),
                     ("cell_target_stress", "observables/cell/target_stress"))
"""Per-frame observables that :func:`read_frame` returns with the particles (key, path)."""


def cell_control_codes(snap) -> list[int]:
    """The cell's control per axis as stored: the index in :data:`CELL_CONTROLS`, -1 where the axis is
    not periodic (a snapshot that names no control has a fixed cell)."""
    names = snap.cell_control or fixed_cell_control(snap.periodic)
    return [CELL_NONE if name == "none" else CELL_CONTROLS.index(name) for name in names]


def cell_control_of(frame: dict, periodic) -> tuple[str, ...]:
    """The cell's control per axis of a frame of :func:`read_frame` (fixed in a run file written before
    the cell's control was stored)."""
    if "cell_control" not in frame:
        return fixed_cell_control(periodic)
    return cell_control_names(frame["cell_control"])


class RunFileError(GranLabError, OSError):
    """A run file that is missing, not HDF5, not H5MD, or lacks what was asked of it."""


CHECKPOINT = "its checkpoint"


class DamagedRunFile(RunFileError):
    """A run file whose frame ``where`` (``frame 12``) is not as GranLab writes it: ``detail`` says how."""

    def __init__(self, path: str, where: str, detail: str):
        self.where, self.detail = where, f"{where}: {detail}"
        super().__init__(f"{str(path)!r} is damaged ({self.detail})")


def _extendable(group, name, shape, dtype, chunk_rows=64):
    """An empty dataset that grows along its first axis (an axis of length 0, e.g. no walls, is
    chunked as if it had length 1)."""
    return group.create_dataset(name, shape=(0,) + tuple(shape), maxshape=(None,) + tuple(d or None for d in shape),
                                dtype=dtype, chunks=(chunk_rows,) + tuple(max(1, d) for d in shape))


def append_row(dataset, value) -> None:
    """Append ``value`` to an extendable dataset along its first axis."""
    n = dataset.shape[0]
    dataset.resize((n + 1,) + dataset.shape[1:])
    dataset[n] = value


CHUNK_BYTES = 2 ** 20
"""A per-disk element's chunk holds up to 16 frames, and no more than this many bytes unless one
frame is larger: HDF5 gives a chunk its whole room at its first frame, and 16 frames of 4 million
disks' positions made a run of two frames take 2.45 GB on disk."""


def frames_per_chunk(frame_bytes: int) -> int:
    return max(1, min(16, CHUNK_BYTES // max(frame_bytes, 1)))


def time_dependent(group, name, shape, dtype=np.float64, chunk_rows=16):
    """An empty H5MD time-dependent element ``name`` (``step``, ``time`` and ``value`` of ``shape``)."""
    element = group.create_group(name)
    _extendable(element, "step", (), np.int64)
    _extendable(element, "time", (), np.float64)
    _extendable(element, "value", shape, dtype, chunk_rows)
    return element


def write_h5md_header(f: h5py.File, author: str = "GranLab user", creator: str = "GranLab") -> None:
    """The ``/h5md`` group of H5MD 1.1: version, author and creator (GranLab's version)."""
    h5md = f.create_group("h5md")
    h5md.attrs["version"] = np.array([1, 1])
    h5md.create_group("author").attrs["name"] = author
    group = h5md.create_group("creator")
    group.attrs["name"] = creator
    group.attrs["version"] = __version__


def to_json(value) -> str:
    """JSON of parameter dataclasses (inf and NaN allowed, as Python's json writes them)."""
    def plain(v):
        if dataclasses.is_dataclass(v):
            return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        if isinstance(v, dict):
            return {k: plain(x) for k, x in v.items()}
        if isinstance(v, np.generic):
            return v.item()
        return v
    return json.dumps(plain(value))


def walls_from_json(text: str) -> tuple[Wall, ...]:
    walls = []
    for item in json.loads(text):
        item = dict(item)
        item["load"] = Load(**item["load"])
        item["normal"] = tuple(item["normal"])
        if item["load_per_length_of"] is not None:
            item["load_per_length_of"] = tuple(item["load_per_length_of"])
        walls.append(Wall(**item))
    return tuple(walls)


def cell_from_json(text: str) -> PeriodicCell | None:
    data = json.loads(text)
    if data is None:
        return None
    return PeriodicCell(**{k: tuple(v) if isinstance(v, list) else v for k, v in data.items()})


def run_file_bytes(sim: Simulation, frames: int) -> int:
    """Bytes of a run file of ``sim`` holding ``frames`` frames (with its contacts of now) and its
    two checkpoint slots, HDF5's metadata included."""
    n = sim.particles.count
    per_disk = sum(8 * int(np.prod(shape)) for _, shape in PARTICLE_ELEMENTS)
    per_contact = sum(np.dtype(dtype).itemsize * int(np.prod(shape)) for _, dtype, shape in CONTACT_FIELDS)
    frame = n * per_disk + sim.contacts.count * per_contact + 2 ** 12
    checkpoint = sum(value.nbytes for value in sim.export_state().values())
    return frames * frame + 2 * checkpoint + 2 ** 20


def _reserve(sim: Simulation) -> int:
    """Bytes a frame and a checkpoint of ``sim`` may take on disk, HDF5's chunks and metadata included."""
    return 2 * sum(value.nbytes for value in sim.export_state().values()) + 2 ** 19


def _write(method):
    """A write of a :class:`RunWriter`: an OS error ends the writer with :class:`WriteFailed`, and
    no later call touches its file; a stop asked for waits until it is whole."""
    @functools.wraps(method)
    def write(self, *args, **kwargs):
        if self.failed is not None:
            raise self.failed
        try:
            short = self._short_of_room()
            if short:
                raise OSError(errno.ENOSPC, short)
            with stopping.shielded():  # a frame or checkpoint is written whole, a late stop or not
                return method(self, *args, **kwargs)
        except (OSError, RuntimeError) as error:
            reason = failed_write_reason(error) or str(error)
            kept = (f"granlab run --resume {str(self.path)!r} goes on from its last checkpoint (step "
                    f"{self.checkpoint_step})" if self.checkpoint_step is not None else "it holds no checkpoint yet")
            step = getattr(args[0], "step", None) if args else None
            at = f" at step {step}" if step is not None else ""
            self.failed = WriteFailed(f"writing {str(self.path)!r} failed{at}: {reason}. What was written before "
                                      f"stays readable; {kept}", reason)
            raise self.failed from error
    return write


class RunWriter:
    """Writes a run file for one simulation.

    ``scene`` is the scene text (TOML), ``protocol`` a JSON-able description of what was run,
    ``watch`` pairs ``(i, j)`` (``j >= N``: a wall) whose (F_n, F_t, status) are recorded by
    :meth:`write_contact_sample`. ``lab_series`` (name -> column names) makes the file a lab run:
    it holds those series (:meth:`write_series`) and the lab's settings at each frame
    (``settings`` of :meth:`write_frame`). An existing ``path`` (a symbolic link too) is
    refused unless ``overwrite``. Use as a context manager.
    """

    def __init__(self, path: str | Path, sim: Simulation, scene: str = "", protocol: dict | None = None,
                 watch: list[tuple[int, int]] | None = None, author: str = "GranLab user",
                 lab_series: dict[str, tuple[str, ...]] | None = None, overwrite: bool = False):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        n = sim.particles.count
        nw = sim.walls.count
        if not overwrite and occupied(self.path):
            raise OutputError(f"run file {str(self.path)!r} exists: it is not written over unless asked")
        # "w-" creates the file exclusively (O_EXCL), so a link put there meanwhile is not followed
        f = h5py.File(self.path, "w" if overwrite else "w-", libver="latest")
        self.file = f
        write_h5md_header(f, author)
        particles = f.create_group("particles/all")
        box = particles.create_group("box")
        box.attrs["dimension"] = 2
        box.attrs["boundary"] = np.array(["periodic" if p else "none" for p in sim.periodic], dtype="S8")
        time_dependent(box, "edges", (2,))
        for name, shape in PARTICLE_ELEMENTS:
            time_dependent(particles, name, (n,) + shape, chunk_rows=frames_per_chunk(n * int(np.prod(shape)) * 8))
        particles.create_dataset("kind", data=sim.particles.kind)
        contacts = f.create_group("contacts")
        contacts.attrs["status_names"] = np.array(STATUS_NAMES, dtype="S12")
        _extendable(contacts, "step", (), np.int64)
        _extendable(contacts, "time", (), np.float64)
        contacts.create_dataset("offset", data=np.zeros(1, dtype=np.int64), maxshape=(None,), chunks=(64,))
        for name, dtype, shape in CONTACT_FIELDS:
            _extendable(contacts, name, shape, dtype, chunk_rows=4096)
        observables = f.create_group("observables")
        energy = time_dependent(observables, "energy", (len(ENERGY_FIELDS),))
        energy.attrs["fields"] = np.array(ENERGY_FIELDS, dtype="S24")
        walls = observables.create_group("walls")
        walls.attrs["names"] = np.array(sim.walls.names, dtype="S32")
        time_dependent(walls, "position", (nw,))
        time_dependent(walls, "force", (nw,))
        time_dependent(walls, "mode", (nw,), np.int8)
        time_dependent(observables, "stress", (2, 2))
        cell = observables.create_group("cell")
        cell.attrs["control_names"] = np.array(CELL_CONTROLS, dtype="S12")
        time_dependent(cell, "control", (2,), np.int8)
        time_dependent(cell, "target_stress", (2,))
        time_dependent(observables, "law", (), h5py.string_dtype())
        _extendable(observables, "notes", (), h5py.string_dtype(), 16)
        cycles = observables.create_group("cycles")
        for name in CYCLE_FIELDS:
            _extendable(cycles, name, (), np.int64 if name in ("cycle", "step") else np.float64)
        _extendable(cycles, "wall_position", (nw,), np.float64)
        paths = observables.create_group("contact_paths")
        paths.create_dataset("pair", data=np.array(watch or [], dtype=np.int64).reshape(-1, 2))
        n_watch = len(watch or [])
        _extendable(paths, "time", (), np.float64, 256)
        for name, dtype in (("normal_force", np.float64), ("elastic_normal_force", np.float64),
                            ("tangential_force", np.float64), ("status", np.int8)):
            paths.create_dataset(name, shape=(0, n_watch), maxshape=(None, None), dtype=dtype,
                                 chunks=(256, max(1, n_watch)))
        if lab_series is not None:
            lab = observables.create_group("lab")
            time_dependent(lab, "settings", (), h5py.string_dtype())
            time_dependent(lab, "phase", (), h5py.string_dtype())
            for name, columns in lab_series.items():
                _extendable(lab, name, (len(columns),), np.float64, 1024).attrs["columns"] = \
                    np.array(columns, dtype="S32")
        self._write_parameters(f.create_group("parameters"), sim, scene, protocol)
        self._create_checkpoint(f.create_group("checkpoint"), sim)
        self.reserve = _reserve(sim)
        f.swmr_mode = True
        self.failed: WriteFailed | None = None
        self.checkpoint_step: int | None = None
        # a lock of our own while writing (SWMR writing drops HDF5's): a reader tells a live writer
        # from a killed one by it
        self._writing = open(self.path, "rb")
        fcntl.fcntl(self._writing, fcntl.F_OFD_SETLK, _FLOCK.pack(fcntl.F_RDLCK, os.SEEK_SET, 0, 0, 0))
        self.watch = list(watch or [])
        self._handles = {}
        self._cycles = []
        self._samples = []

    # ------------------------------------------------------------------ creation
    @staticmethod
    def _write_parameters(group, sim: Simulation, scene: str, protocol: dict | None) -> None:
        for name, value in dataclasses.asdict(sim.law).items():
            group.attrs[f"contact.{name}"] = value
        for name, value in dataclasses.asdict(sim.integration).items():
            group.attrs[f"integration.{name}"] = "none" if value is None else value
        group.attrs["dt"] = sim.dt
        group.attrs["skin"] = sim.skin
        group.attrs["gravity"] = sim.gravity
        group.attrs["law_json"] = to_json(sim.law)
        group.attrs["integration_json"] = to_json(sim.integration)
        group.attrs["walls_json"] = to_json(sim.wall_params)
        group.attrs["cell_json"] = to_json(sim.cell_params)
        group.attrs["protocol_json"] = to_json(protocol or {})
        group.create_dataset("scene", data=scene)

    @staticmethod
    def _create_checkpoint(group, sim: Simulation) -> None:
        state = sim.export_state()
        for slot in ("slot0", "slot1"):
            g = group.create_group(slot)
            for key, value in state.items():
                value = np.asarray(value)
                if key.startswith("contacts/"):
                    g.create_dataset(key, shape=(0,) + value.shape[1:], maxshape=(None,) + value.shape[1:],
                                     dtype=value.dtype, chunks=(4096,) + value.shape[1:])
                else:
                    g.create_dataset(key, shape=value.shape, dtype=value.dtype)
        group.create_dataset("valid", data=np.array([-1, -1], dtype=np.int64))

    # ------------------------------------------------------------------ appending
    def _get(self, path: str):
        handle = self._handles.get(path)
        if handle is None:
            handle = self._handles[path] = self.file[path]
        return handle

    def _element(self, path: str, step: int, time: float, value) -> None:
        append_row(self._get(f"{path}/value"), value)
        append_row(self._get(f"{path}/time"), time)
        append_row(self._get(f"{path}/step"), step)

    @_write
    def write_frame(self, state, settings: str | None = None, phase: str | None = None) -> None:
        """Append a frame (positions, contacts, observables) from a :class:`Simulation` or a
        :class:`Snapshot` taken earlier, and the cycle records waiting in memory; flush.
        ``settings``: the lab's settings at that frame (JSON), ``phase``: where its protocol was
        (``cycle 12 · q = 0.312, rising``), for a lab run."""
        self._write_cycles()
        snap = state.snapshot() if isinstance(state, Simulation) else state
        step, time = snap.step, snap.time
        self._element("particles/all/box/edges", step, time, snap.box_lengths)
        for name, value in (("position", snap.positions), ("velocity", snap.velocities), ("angle", snap.angles),
                            ("omega", snap.omegas), ("radius", snap.radii), ("mass", snap.masses)):
            self._element(f"particles/all/{name}", step, time, value)
        c = snap.contacts
        values = {"pair": np.column_stack([c.i, c.j]), "image": c.image, "status": c.status,
                  "normal_force": c.normal_force, "elastic_normal_force": c.elastic_normal_force,
                  "tangential_force": c.tangential_force,
                  "surface_gap": c.surface_gap, "tangential_spring": c.tangential_spring,
                  "rolling_spring": c.rolling_spring, "rolling_distance": c.rolling_distance}
        offset = self._get("contacts/offset")
        start = int(offset[-1])
        for name, _, _ in CONTACT_FIELDS:
            dataset = self._get(f"contacts/{name}")
            dataset.resize((start + c.count,) + dataset.shape[1:])
            dataset[start:] = values[name]
        append_row(self._get("contacts/time"), time)
        append_row(self._get("contacts/step"), step)
        append_row(offset, start + c.count)
        budget = snap.energy.as_dict()
        self._element("observables/energy", step, time, [budget[k] for k in ENERGY_FIELDS])
        self._element("observables/walls/position", step, time, snap.wall_offsets)
        self._element("observables/walls/force", step, time, snap.wall_forces)
        self._element("observables/walls/mode", step, time, [WALL_MODES.index(m) for m in snap.wall_modes])
        self._element("observables/stress", step, time, snap.stress)
        self._element("observables/cell/control", step, time, cell_control_codes(snap))
        self._element("observables/cell/target_stress", step, time, snap.cell_target_stress)
        self._element("observables/law", step, time, to_json(snap.law))
        if settings is not None:
            self._element("observables/lab/settings", step, time, settings)
        if phase is not None:
            self._element("observables/lab/phase", step, time, phase)
        self.file.flush()

    def write_cycle(self, cycle: int, sim: Simulation, length_x: float, length_y: float) -> None:
        """Record a loading cycle (wall positions at the minimum of the load). Records wait in
        memory and are written with the next frame or checkpoint, on :meth:`close`, or every
        100 records."""
        self.write_cycle_record(cycle, sim.step, sim.time, length_x, length_y, sim.walls.offset)

    @_write
    def write_cycle_record(self, cycle: int, step: int, time: float, length_x: float, length_y: float,
                           wall_position) -> None:
        """Record a loading cycle taken earlier (as :meth:`write_cycle`); ``wall_position`` (W,)."""
        self._cycles.append((cycle, step, time, length_x, length_y, np.array(wall_position, dtype=float)))
        if len(self._cycles) >= 100:
            self._write_cycles()

    @_write
    def write_note(self, text: str) -> None:
        """Append a line to the run's notes (``observables/notes``: what a reader should know of the
        run, such as an energy balance that drifted); flush."""
        append_row(self._get("observables/notes"), text)
        self.file.flush()

    @_write
    def write_series(self, name: str, rows: np.ndarray) -> None:
        """Append rows (R, C) to the lab series ``name``; flush."""
        dataset = self._get(f"observables/lab/{name}")
        rows = np.asarray(rows, dtype=np.float64).reshape(-1, dataset.shape[1])
        n = dataset.shape[0]
        dataset.resize((n + len(rows), dataset.shape[1]))
        dataset[n:] = rows
        self.file.flush()

    def _write_cycles(self) -> None:
        """Write the cycle records and contact samples waiting in memory; flush."""
        for group, names, pending in (
                ("observables/cycles", CYCLE_FIELDS + ("wall_position",), self._cycles),
                ("observables/contact_paths", ("time", "normal_force", "elastic_normal_force", "tangential_force",
                                               "status"), self._samples)):
            if not pending:
                continue
            columns = list(zip(*pending))
            pending.clear()
            for index, name in enumerate(names):
                dataset = self._get(f"{group}/{name}")
                n = dataset.shape[0]
                values = np.array(columns[index])
                dataset.resize((n + len(values),) + dataset.shape[1:])
                dataset[n:] = values
        self.file.flush()

    @_write
    def write_contact_sample(self, sim: Simulation) -> None:
        """Record (F_n, F_t, status) of the watched pairs (zeros and status 0 when not interacting).
        Samples wait in memory like cycle records."""
        fn, elastic, ft, status = watched_contacts(sim, self.watch)
        self._samples.append((sim.time, fn, elastic, ft, status))
        if len(self._samples) >= 1000:
            self._write_cycles()

    @_write
    def write_checkpoint(self, sim: Simulation) -> None:
        """Write the full state into the older slot, then mark it valid; flush."""
        self._write_cycles()
        group = self.file["checkpoint"]
        valid = group["valid"][...]
        slot = 1 - int(valid[0]) if valid[0] >= 0 else 0
        g = group[f"slot{slot}"]
        for key, value in sim.export_state().items():
            dataset = g[key]
            if key.startswith("contacts/"):
                dataset.resize((value.shape[0],) + dataset.shape[1:])
            dataset[...] = value
        self.file.flush()
        group["valid"][...] = [slot, sim.step]
        self.file.flush()
        self.checkpoint_step = sim.step
        self.reserve = _reserve(sim)  # the contacts may have grown

    def _short_of_room(self) -> str | None:
        """Why the next write may not fit, or None: HDF5 fails a write that runs out of room while
        it releases a dataset, where no caller can catch it, and then crashes; so a write is
        started only with room for a whole checkpoint and its frame (``reserve``) to spare."""
        room = free_bytes(self.path.parent)
        if room < self.reserve:
            return f"No space left on device ({room / 2 ** 20:.3g} MiB free, a frame and a checkpoint need " \
                   f"{self.reserve / 2 ** 20:.3g} MiB)"
        limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
        if limit != resource.RLIM_INFINITY and os.path.getsize(self.path) + self.reserve > limit:
            return f"File too large (the file size limit, ulimit -f, is {limit / 2 ** 20:.3g} MiB)"
        return None

    def close(self) -> None:
        with stopping.shielded():  # closed whole, a late stop or not
            if self.failed is None and self.file.id.valid:
                self._write_cycles()
                self.file.close()
            self._writing.close()

    def __enter__(self) -> "RunWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def watched_contacts(sim: Simulation, pairs: list[tuple[int, int]]):
    """(F_n, N^e, F_t, status) of ``sim``'s contacts for ``pairs`` (zeros, status 0 when absent)."""
    snapshot = sim.contact_snapshot()
    lookup = {(int(i), int(j)): k for k, (i, j) in enumerate(zip(snapshot.i, snapshot.j))}
    values = np.zeros((3, len(pairs)))
    status = np.zeros(len(pairs), dtype=np.int8)
    for index, (i, j) in enumerate(pairs):
        k = lookup.get((min(i, j), max(i, j)) if j < sim.particles.count else (i, j))
        if k is not None:
            values[:, index] = (snapshot.normal_force[k], snapshot.elastic_normal_force[k],
                                snapshot.tangential_force[k])
            status[index] = snapshot.status[k]
    return values[0], values[1], values[2], status


# ---------------------------------------------------------------------------------------------- reading
def open_run(path: str | Path) -> h5py.File:
    """Open a run file for reading.

    Without SWMR, which finds a truncated or damaged file at once (HDF5's SWMR reader retries a
    failed read for ever). Only a file being written by a live writer is opened in SWMR mode;
    one still marked as being written by a writer that was killed, or that stopped on a full
    disk, is read as if it had been closed (:class:`granlab.engine.io.superblock.FinishedWriteView`), up to
    the end of what it wrote.
    """
    path = Path(path)
    require_file(path, "run file", RunFileError)
    try:
        return h5py.File(path, "r")
    except OSError as error:
        if "truncated file" in str(error) and not superblock.left_open(path):  # a closed file cut short
            raise _truncated(path) from error
        if "truncated file" not in str(error) and "already open for write" not in str(error):
            raise RunFileError(f"{str(path)!r} is not a readable HDF5 file: {error}") from error
    try:
        if _being_written(path):
            if superblock.stored_eof(path) > path.stat().st_size:
                raise _truncated(path)
            return h5py.File(path, "r", libver="latest", swmr=True)
        view = superblock.FinishedWriteView(path)
        f = h5py.File(view, "r")
    except (OSError, ValueError) as error:
        raise RunFileError(f"{str(path)!r} is not a readable HDF5 file: {error}") from error
    weakref.finalize(f, view.close)
    return f


_FLOCK = struct.Struct("@hhqqi4x")
"""Linux's ``struct flock`` (type, whence, start, length, pid): the record lock a RunWriter holds
on its file. An open-file-description lock: neither HDF5's own locks (flock, which every reader
holds while the file is open) nor another descriptor's close in the writer's process touch it."""


def _being_written(path: Path) -> bool:
    """Whether a live :class:`RunWriter` holds ``path``."""
    with open(path, "rb") as probe:
        answer = fcntl.fcntl(probe, fcntl.F_OFD_GETLK, _FLOCK.pack(fcntl.F_WRLCK, os.SEEK_SET, 0, 0, 0))
    return _FLOCK.unpack(answer)[0] != fcntl.F_UNLCK


def _truncated(path: Path) -> RunFileError:
    stored, size = superblock.stored_eof(path), path.stat().st_size
    of = f" of the {stored} its header records" if stored > size else ""
    return RunFileError(f"run file {str(path)!r} is truncated: {size} bytes{of}, so frames, checkpoint and "
                        f"parameters past the cut are lost (was it cut short while copied or written?)")


def raised_by_damage(error: BaseException) -> bool:
    """Whether ``error`` tells of a damaged file: a read HDF5 could not do (it came out of h5py), or
    text in the file that does not decode."""
    if isinstance(error, (json.JSONDecodeError, UnicodeDecodeError, DamagedRunFile)):
        return True
    return isinstance(error, (OSError, KeyError, ValueError, RuntimeError)) and any(
        "/h5py/" in frame.filename for frame in traceback.extract_tb(error.__traceback__))


PROBE_SECONDS = 10.0
"""How long a file's metadata may take to read in :func:`probe` (a sound file's takes milliseconds)."""


def probe(path: str | Path, seconds: float = PROBE_SECONDS) -> None:
    """Read every object's name and attributes of the HDF5 file ``path`` in a child process first:
    on some damaged metadata HDF5 loops for ever, holding Python's lock, where no thread or signal
    of this process can stop it (a zeroed page of a run file made ``run --resume`` wait for ever on
    its /parameters). A child that does not finish in ``seconds`` is killed and the file named
    damaged. What else is wrong the real read says. For a command's process, before it starts
    threads: a fork copies none of them."""
    if not h5py.is_hdf5(path):
        return
    sys.stdout.flush()
    sys.stderr.flush()
    pid = os.fork()
    if pid == 0:
        try:
            os.dup2(os.open(os.devnull, os.O_WRONLY), 2)
            with open_run(path) as f:
                for look in (lambda: parameters(f), lambda: frame_count(f), lambda: f["checkpoint/valid"][...],
                             lambda: [item.attrs.get(name) for item in [f, *_objects(f)] for name in item.attrs]):
                    try:
                        look()
                    except Exception:  # the real read names it
                        pass
        finally:
            os._exit(0)
    give_up = time.monotonic() + seconds
    while not os.waitpid(pid, os.WNOHANG)[0]:
        if time.monotonic() > give_up:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            raise RunFileError(f"{str(path)!r} is damaged: reading its metadata did not end in {seconds:.0f} s "
                               f"(HDF5 loops for ever on some damaged files)")
        time.sleep(0.005)


def _objects(f: h5py.File) -> list:
    found = []
    f.visititems(lambda name, item: found.append(item))
    return found


DAMAGE_SEARCH_SECONDS = 3.0
"""How long :func:`damaged` looks back through a damaged file's frames for one that reads whole."""


def damaged(path: str | Path, error: BaseException) -> RunFileError:
    """The error that names a damaged file: what went wrong, and for a run file the last frame and
    the checkpoint that can still be read (each found without a hang: see :func:`open_run`)."""
    reason = error.detail if isinstance(error, DamagedRunFile) else \
        f"{type(error).__name__}: {str(error).strip(chr(39) + chr(34))}"
    kept = ""
    try:
        with open_run(path) as f:
            count, last, tried = frame_count(f), None, 0
            give_up = time.monotonic() + DAMAGE_SEARCH_SECONDS
            for index in range(count - 1, -1, -1):
                try:
                    last = read_frame(f, index)
                    break
                except Exception:  # a damaged frame: the one before may be whole
                    tried += 1
                    if time.monotonic() > give_up:
                        break
            try:
                checkpoint = checkpoint_step(f)
            except Exception:
                checkpoint = None
        frames = (f"frame {last['index']} (t = {last['time']:.6g}) is the last that reads whole" if last else
                  "no frame reads whole" if tried == count else f"none of the last {tried} frames reads whole")
        resume = "no other checkpoint" if getattr(error, "where", "") == CHECKPOINT else \
            f"a checkpoint at step {checkpoint}" if checkpoint is not None else "no checkpoint"
        kept = f"; {frames}, {resume}"
    except Exception:  # not even its layout reads
        pass
    return RunFileError(f"{str(path)!r} is damaged ({reason}){kept}")


def is_run_file(f: h5py.File) -> bool:
    """Whether an open H5MD file is a GranLab run file (its contact table and parameters)."""
    return "contacts/offset" in f and "parameters" in f


def require_run_file(f: h5py.File, command: str) -> None:
    """Refuse an H5MD file that is not a GranLab run file, naming what ``command`` takes."""
    if not is_run_file(f):
        raise RunFileError(f"{f.filename!r} is not a GranLab run file (no /contacts or /parameters); {command} "
                           "takes the files of granlab run --out, granlab prepare --out and the lab's Save run")


def frame_count(f: h5py.File) -> int:
    """Complete frames: the fewest frames any time-dependent particle element holds, and in a run
    file those before the first whose step goes back (the rows a writer stopped by a full disk
    had made room for but not written read as zeros)."""
    if "particles/all/position" not in f:
        raise RunFileError(f"{f.filename!r} has no /particles/all/position: not an H5MD particle file")
    counts = []
    particles = f["particles/all"]
    elements = [particles[name] for name in particles] + ([particles["box/edges"]] if "box/edges" in particles else [])
    for element in elements:
        if isinstance(element, h5py.Group) and "value" in element:
            for key in ("step", "time", "value"):
                data = element.get(key)
                numbers = key == "value" or isinstance(data, h5py.Dataset) and data.dtype.kind in "iuf"
                if not isinstance(data, h5py.Dataset) or data.ndim == 0 or not numbers:
                    found = "missing" if data is None else "a group" if isinstance(data, h5py.Group) else \
                        f"{data.dtype} of shape {data.shape}"
                    raise DamagedRunFile(f.filename, element.name, f"{key} is {found}; a row per frame is needed"
                                                                   + ("" if key == "value" else ", a number"))
                counts.append(data.shape[0])
    if "contacts/offset" in f:
        offset = f["contacts/offset"]
        if not isinstance(offset, h5py.Dataset) or offset.ndim != 1:
            raise DamagedRunFile(f.filename, "/contacts/offset", "one whole number per frame is needed")
        counts.append(offset.shape[0] - 1)
    count = min(counts)
    if is_run_file(f) and count > 1:
        back = np.flatnonzero(np.diff(f["particles/all/position/step"][:count]) < 0)
        count = int(back[0]) + 1 if len(back) else count
    return count


def read_frame(f: h5py.File, index: int) -> dict:
    """Positions, velocities, radii, ..., the contact table and the observables of
    :data:`FRAME_OBSERVABLES` of frame ``index`` (negative counts from the end)."""
    count = frame_count(f)
    if count == 0:
        raise RunFileError(f"{f.filename!r} holds no complete frame")
    if not -count <= index < count:
        raise RunFileError(f"frame {index} is out of range: {f.filename!r} holds frames 0..{count - 1}")
    index %= count
    particles = f["particles/all"]
    source = (f.filename, f"frame {index}")
    frame = {"index": index, "step": _number(particles, "position/step", index, source),
             "time": _number(particles, "position/time", index, source)}
    for name in particles:
        element = particles[name]
        if isinstance(element, h5py.Group) and "value" in element:
            frame[name] = element["value"][index]
    if "box/edges" in particles:
        frame["edges"] = particles["box/edges/value"][index]
        boundary = particles["box"].attrs.get("boundary")
        if not isinstance(boundary, np.ndarray) or boundary.shape != (2,) or boundary.dtype.kind not in "SUO":
            raise DamagedRunFile(*source, f"the box's boundary attribute is {boundary!r}; two of 'periodic', 'none' "
                                 f"are needed")
        frame["boundary"] = [b.decode() if isinstance(b, bytes) else str(b) for b in boundary]
    if "contacts/offset" in f:
        frame["contacts"] = _frame_contacts(f, index, source)
    for key, path in FRAME_OBSERVABLES:
        if f"{path}/value" in f and f[f"{path}/value"].shape[0] > index:
            value = f[f"{path}/value"][index]
            frame[key] = value.decode() if isinstance(value, bytes) else value
    if is_run_file(f):
        check_frame(frame, source)
    return frame


def _number(group: h5py.Group, name: str, index: int, source: tuple[str, str]) -> int | float:
    """Frame ``index``'s step or time: a finite number."""
    data = group[name]
    if data.ndim != 1 or data.dtype.kind not in "iuf":
        raise DamagedRunFile(*source, f"{data.name} is {data.dtype} of shape {data.shape}; a number per frame is needed")
    value = data[index]
    if not np.isfinite(value):
        raise DamagedRunFile(*source, f"{data.name} is {value}; a finite number is needed")
    return int(value) if data.dtype.kind in "iu" else float(value)


def _frame_contacts(f: h5py.File, index: int, source: tuple[str, str]) -> dict:
    """The contact table's rows of frame ``index``, between its offsets."""
    offset = f["contacts/offset"]
    if offset.ndim != 1 or offset.dtype.kind not in "iu":
        raise DamagedRunFile(*source, f"/contacts/offset is {offset.dtype} of shape {offset.shape}; one whole "
                             f"number per frame is needed")
    lo, hi = (int(k) for k in offset[index:index + 2])
    contacts = {}
    for name, dtype, shape in CONTACT_FIELDS:
        data = f["contacts"].get(name)
        if not isinstance(data, h5py.Dataset) or data.shape[1:] != shape or data.dtype.kind != np.dtype(dtype).kind \
                or not 0 <= lo <= hi <= data.shape[0]:
            found = "missing" if data is None else f"{data.dtype} of shape {data.shape}"
            raise DamagedRunFile(*source, f"/contacts/{name} is {found}; rows {lo} to {hi} of {np.dtype(dtype)} "
                                 f"{('(rows, ' + str(shape[0]) + ')') if shape else '(rows,)'} are needed")
        contacts[name] = data[lo:hi]
    return contacts


def check_frame(frame: dict, source: tuple[str, str]) -> None:
    """A run file's frame as GranLab writes it: every disk element of one length, numbers, finite;
    contacts between existing disks and walls. A damaged or edited file is refused here, by name,
    before a picture, an export or an analysis is made of it."""
    n = None
    for name, shape in PARTICLE_ELEMENTS:
        value = frame.get(name)
        if value is None:
            raise DamagedRunFile(*source, f"/particles/all/{name} is missing")
        n = value.shape[0] if n is None and value.ndim else n
        if value.shape != (n,) + shape or value.dtype.kind not in "iuf":
            raise DamagedRunFile(*source, f"/particles/all/{name} is {value.dtype} of shape {value.shape}; numbers of "
                                 f"shape {(n,) + shape} are needed")
        bad = ~(np.abs(value) < HUGE) if name != "radius" else ~((value > 0) & (value < HUGE))
        if bad.any():
            disk = int(np.flatnonzero(bad.reshape(n, -1).any(axis=1))[0])
            raise DamagedRunFile(*source, f"/particles/all/{name} of disk {disk} of {n} is {value[disk]}; "
                                 f"{'positive radii' if name == 'radius' else 'finite numbers'} below 1e150 are "
                                 f"needed (a run that diverged writes NaN: an earlier frame may be whole)")
    edges = frame.get("edges")
    if edges is None or "boundary" not in frame:
        raise DamagedRunFile(*source, "/particles/all/box/edges or its boundary attribute is missing")
    if edges.shape != (2,) or edges.dtype.kind not in "iuf" or not np.all((edges > 0) & (edges < HUGE)):
        raise DamagedRunFile(*source, f"the box's edges are {edges.tolist()}; two positive lengths are needed")
    walls = np.shape(frame.get("wall_position", ()))[0] if np.ndim(frame.get("wall_position", ())) else 0
    contacts = frame.get("contacts")
    if contacts is not None and len(contacts["pair"]):
        pair = contacts["pair"]
        if not (0 <= pair[:, 0].min() and pair[:, 0].max() < n and 0 <= pair[:, 1].min()
                and pair[:, 1].max() < n + walls):
            raise DamagedRunFile(*source, f"/contacts/pair joins {pair.min()} to {pair.max()}; disks 0 to {n - 1} and "
                                 f"walls {n} to {n + walls - 1} are allowed")
        status = contacts["status"]
        if not (0 <= status.min() and status.max() < len(STATUS_NAMES)):
            raise DamagedRunFile(*source, f"/contacts/status holds {status.min()} to {status.max()}; codes 0 to "
                                 f"{len(STATUS_NAMES) - 1} are allowed")
        for name, dtype, _ in CONTACT_FIELDS:
            if np.dtype(dtype).kind == "f" and not np.all(np.abs(contacts[name]) < HUGE):
                raise DamagedRunFile(*source, f"/contacts/{name} holds NaN, infinite or huge values; finite numbers "
                                     f"are needed")


def _valid_checkpoint(f: h5py.File) -> tuple[int, int] | None:
    """The slot and step of a run file's last valid checkpoint (``None`` if there is none)."""
    if "checkpoint/valid" not in f:
        return None
    valid = f["checkpoint/valid"]
    if not isinstance(valid, h5py.Dataset) or valid.shape != (2,) or valid.dtype.kind not in "iu":
        raise RunFileError(f"{f.filename!r}: /checkpoint/valid is damaged (two whole numbers, the slot and its step, "
                           f"are needed)")
    slot, step = (int(value) for value in valid[...])
    return None if slot < 0 else (slot, step)


def checkpoint_step(f: h5py.File) -> int | None:
    """The step of a run file's last valid checkpoint, read without reading the checkpoint."""
    found = _valid_checkpoint(f)
    return None if found is None else found[1]


def read_checkpoint(f: h5py.File) -> dict | None:
    """The last valid checkpoint of a run file as a state dict (``None`` if there is none)."""
    found = _valid_checkpoint(f)
    if found is None:
        return None
    slot, _ = found
    if f"checkpoint/slot{slot}" not in f:
        raise RunFileError(f"{f.filename!r}: /checkpoint/valid names slot {slot}, which the file does not hold")
    group, state, limit = f[f"checkpoint/slot{slot}"], {}, _declared_limit(f)

    def read(name, item):
        if isinstance(item, h5py.Dataset):
            if item.size * item.dtype.itemsize > limit:
                raise RunFileError(f"{f.filename!r}: checkpoint {name} declares shape {item.shape}, more than the "
                                   f"file could hold: damaged")
            state[name] = item[()]
    group.visititems(read)
    return state


def _declared_limit(f: h5py.File) -> int:
    """The most bytes a dataset of ``f`` may declare: what its file's size could hold, compressed
    as HDF5 compresses numbers; more is a damaged header, and reading it would exhaust memory."""
    return 64 * os.path.getsize(f.filename) + 2 ** 20


def lab_series(f: h5py.File) -> dict[str, tuple[tuple[str, ...], np.ndarray]]:
    """The lab's time series of a lab run: name -> (column names, rows (R, C)); empty otherwise."""
    if "observables/lab" not in f:
        return {}
    out = {}
    for name, item in f["observables/lab"].items():
        if isinstance(item, h5py.Dataset):
            columns = tuple(c.decode() if isinstance(c, bytes) else str(c) for c in item.attrs["columns"])
            out[name] = (columns, item[()])
    return out


def parameters(f: h5py.File) -> dict:
    group = f["parameters"]
    return {key: (value.decode() if isinstance(value, bytes) else value) for key, value in group.attrs.items()}


def parsed_parameter(f: h5py.File, key: str, parse, text: str | None = None):
    """``parse`` of the JSON parameter ``key`` (``text``: a frame's own, e.g. its law), a damaged
    one named with what is wrong."""
    try:
        return parse(text if text is not None else parameters(f)[key])
    except (GranLabError, KeyError, TypeError, ValueError, AttributeError) as error:
        raise DamagedRunFile(f.filename, f"/parameters {key}", f"{type(error).__name__}: "
                                                               f"{one_line(str(error))}") from None


def _pair(value: np.ndarray) -> tuple[float, float]:
    if value.shape != (2,) or not np.all(np.isfinite(value)):
        raise ValueError(f"{value.tolist()} is not two finite numbers")
    return tuple(value)


def _table(value) -> dict:
    if not isinstance(value, dict):
        raise TypeError(f"a JSON object is needed, not {type(value).__name__}")
    return value


def run_protocol(f: h5py.File) -> dict:
    """What was run (the JSON record of ``protocol_json``), ``{}`` for a file without one."""
    if "protocol_json" not in parameters(f):
        return {}
    return parsed_parameter(f, "protocol_json", lambda value: _table(json.loads(value)))


def energy_series(f: h5py.File) -> dict[str, np.ndarray]:
    """The energy budget of each frame, by name (:data:`ENERGY_FIELDS`); ``{}`` for a file without."""
    if "observables/energy/value" not in f:
        return {}
    fields, values = f["observables/energy"].attrs.get("fields"), f["observables/energy/value"]
    names = [name.decode() if isinstance(name, bytes) else name for name in np.atleast_1d(fields)] \
        if isinstance(fields, np.ndarray) else []
    if names != list(ENERGY_FIELDS) or values.ndim != 2 or values.shape[1] != len(names) or values.dtype.kind != "f":
        raise DamagedRunFile(f.filename, "/observables/energy", f"its fields or values are not those GranLab writes "
                                                                f"({', '.join(ENERGY_FIELDS)})")
    data = values[()]
    return {name: data[:, k] for k, name in enumerate(names)}


def run_walls(f: h5py.File) -> tuple[Wall, ...]:
    return parsed_parameter(f, "walls_json", walls_from_json)


def run_law(f: h5py.File, text: str | None = None) -> ContactLaw:
    """The contact law of a run file, or the one in effect at a frame (its ``law_json``)."""
    return parsed_parameter(f, "law_json", lambda value: ContactLaw(**json.loads(value)), text)


def resume(path: str | Path) -> tuple[Simulation, dict]:
    """A simulation restored from the last checkpoint of a run file, and the file's protocol record;
    a damaged checkpoint or parameters are refused, named (:mod:`granlab.engine.checkpoint`)."""
    with open_run(path) as f:
        state = read_checkpoint(f)
        if state is None:
            raise RunFileError(f"{str(path)!r} holds no checkpoint to resume from")
        law, walls = run_law(f), run_walls(f)
        integration = parsed_parameter(f, "integration_json", lambda value: Integration(**json.loads(value)))
        cell = parsed_parameter(f, "cell_json", cell_from_json)
        gravity = parsed_parameter(f, "gravity", lambda value: _pair(np.asarray(value, dtype=float)))
        record = parsed_parameter(f, "protocol_json", lambda value: _table(json.loads(value)))
        scene = f["parameters/scene"][()] if "parameters/scene" in f else None
        if not isinstance(scene, (bytes, str)):
            raise DamagedRunFile(f.filename, "/parameters/scene", "missing or not text")
    try:
        for key in ("particles/position", "particles/radius", "particles/mass", "particles/inertia", "particles/kind",
                    "dt"):
            if key not in state:
                raise CheckpointError(f"{key} is missing")
        particles = ParticleState(state["particles/position"], state["particles/radius"], mass=state["particles/mass"],
                                  inertia=state["particles/inertia"], kind=state["particles/kind"])
        sim = Simulation(particles, law, integration.replace(dt=float(state["dt"])), walls, cell, gravity,
                         check_initial_overlap=False)
        sim.restore_state(state)
    except (GranLabError, TypeError, ValueError) as error:
        raise DamagedRunFile(path, CHECKPOINT, f"{one_line(str(error))}; an earlier run file or the scene itself "
                                               f"can start again") from None
    record["scene"] = scene.decode() if isinstance(scene, bytes) else scene
    return sim, record


def summary(path: str | Path) -> dict:
    """What ``granlab info`` prints: sizes, frames, times, parameters, last energies, cycles."""
    with open_run(path) as f:
        frames = frame_count(f)
        info = {"run_file": str(path), "frames": frames}
        if "h5md" in f:
            version = f["h5md"].attrs.get("version")
            info["h5md_version"] = version.tolist() if isinstance(version, np.ndarray) and version.dtype.kind in "iu" \
                else None
            info["creator"] = f["h5md/creator"].attrs.get("name", "")
        if frames:
            first, last = read_frame(f, 0), read_frame(f, -1)
            info.update(particles=int(last["position"].shape[0]), first_time=first["time"], last_time=last["time"],
                        last_step=last["step"], contacts_last_frame=int(len(last.get("contacts", {}).get("status", []))))
        if "parameters" in f:
            params = parameters(f)
            info["parameters"] = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in params.items()
                                  if not k.endswith("_json")}
            info["protocol"] = run_protocol(f)
        energy = energy_series(f)
        if energy and len(energy["kinetic"]):
            info["energy_last"] = {name: float(values[-1]) for name, values in energy.items()}
        if "observables/cycles/cycle" in f:
            info["cycles"] = int(f["observables/cycles/cycle"].shape[0])
        if "observables/notes" in f:
            info["notes"] = [note.decode(errors="replace") if isinstance(note, bytes) else str(note)
                             for note in f["observables/notes"][()]]
        info["checkpoint_step"] = checkpoint_step(f)
    return info

