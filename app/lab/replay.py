"""Files of the lab's data folder, read and written beside the simulation (:mod:`granlab.app.lab.jobs`).

:class:`Replay` plays a file back on a timeline. :func:`read_replay`, :func:`write_run` and
:func:`write_lab_movie` are the functions the lab's file jobs run in a process of their own: each
takes a ``report(fraction)`` callback first, and writes a file whole or not at all (into a hidden
file beside it, renamed at the end).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from granlab.engine import costs
from granlab.engine.costs import room_for_one_file
from granlab.engine.analysis.packing import packing_stats
from granlab.engine.analysis.ratchet import strain_fit
from granlab.engine.analysis.states import PackingState, StateReader, detect_format, read_state
from granlab.engine.errors import GranLabError
from granlab.engine.frames import FrameData, build_frame
from granlab.engine.io import h5md
from granlab.engine.io.outputs import staged
from granlab.engine.protocols.presets import PRESETS


MAX_REPLAY_BYTES = 2 * 2 ** 30
"""The largest file the lab replays: it holds every frame in memory (``granlab render`` and
``granlab analyze`` read larger files frame by frame)."""
REPLAY_MEMORY_PER_BYTE = 3
"""A replay holds every frame read (the file's bytes) and the frames drawn from them."""
READ_SECONDS_PER_GIB = 120.0
"""How long reading a file may take, beyond a first minute: a reader that takes longer is given up."""


def read_time_limit(path: Path) -> float:
    """Seconds the reading of ``path`` may take before the lab gives up on it."""
    return 60.0 + READ_SECONDS_PER_GIB * path.stat().st_size / 2 ** 30


def read_replay(report, path: Path) -> "Replay":
    """A file of the data folder ready to replay (the job of "Load and replay")."""
    size = path.stat().st_size
    if size > MAX_REPLAY_BYTES:
        raise GranLabError(f"{path.name} is {size / 2 ** 30:.1f} GiB: the lab replays files up to "
                           f"{MAX_REPLAY_BYTES / 2 ** 30:.0f} GiB (it holds every frame in memory); granlab render and "
                           f"granlab analyze read larger ones frame by frame")
    need, room = REPLAY_MEMORY_PER_BYTE * size, costs.memory_room()
    if need > room:
        raise GranLabError(f"{path.name} ({costs.size(size)}) needs about {costs.size(need)} of memory to replay; "
                           f"{costs.size(max(room, 0))} is free: close other programs, or render it (granlab render)")
    return Replay(path, report)


class Replay:
    """A file played back on a timeline: its frames, and the series up to the frame shown.

    A GranLab run file gives its energy (and a lab run the lab's series, with the settings of
    each frame). Another code's packing (a LAMMPS dump, with the contacts of ``STEM-contacts.dump``
    beside it when there is one; an extended XYZ file; any H5MD file) gives the coordination z and
    the solid fraction Φ of each frame; its frames are timed by the file's times, else its
    timesteps, else their order."""

    title = "Replay"
    controls: tuple[str, ...] = ()

    def __init__(self, path: Path, report=lambda fraction: None):
        self.path = path
        self.name = f"replay:{path.name}"
        self.states: list[PackingState] = []
        if detect_format(path) == "h5md" and _is_run_file(path):
            self._read_run(path, report)
        else:
            self._read_packing(path, report)
        self._fit: tuple[int, dict | None] = (-1, None)
        self.index = 0

    def _read_run(self, path: Path, report) -> None:
        with h5md.open_run(path) as f:
            self.count = h5md.frame_count(f)
            if self.count == 0:
                raise h5md.RunFileError(f"{path.name} holds no complete frame to replay")
            walls, protocol = h5md.run_walls(f), h5md.run_protocol(f)
            self.normals = np.array([w.normal for w in walls], dtype=float).reshape(-1, 2)
            self.frames = []
            for k in range(self.count):
                self.frames.append(h5md.read_frame(f, k))
                report((k + 1) / self.count)
            energy = {name: values[: self.count] for name, values in h5md.energy_series(f).items()}
            lab = h5md.lab_series(f)
        self.times = np.array([frame["time"] for frame in self.frames])
        self.of = protocol.get("lab_preset") if protocol.get("lab_preset") in PRESETS and lab else None
        span = float(self.times[-1] - self.times[0])
        self.clock_unit = protocol.get("clock_unit", "tens of frames")
        self.cycle_time = float(protocol.get("cycle_time", 10.0 * span / max(1, self.count - 1) or 1.0))
        settings = self.settings(0) or {}
        self.speed = float(settings.get("speed", 1.0)) if isinstance(settings.get("speed"), (int, float)) else 1.0
        steps = np.array([frame["step"] for frame in self.frames], dtype=float)
        self.series: dict[str, tuple[tuple[str, ...], np.ndarray]] = {
            "replay": (("t", "step") + tuple(energy), np.column_stack([self.times, steps, *energy.values()]))}
        self.series.update(lab)
        self.plot = "replay-energy"
        self.time_label = "t"
        self.readouts = None
        self.watched = [tuple(pair) for pair in protocol.get("watched", [])]
        self.watched_labels = list(protocol.get("watched_labels", []))
        self.groups = [tuple(group) for group in protocol.get("views", [])]
        self.changes = list(protocol.get("changes", []))

    def _read_packing(self, path: Path, report) -> None:
        contacts = path.with_name(f"{path.stem}-contacts{path.suffix}")
        if detect_format(path) != "lammps" or not contacts.is_file():
            contacts = None
        reader = StateReader(path, contacts=contacts)
        states = self.states
        for k in range(reader.count):
            states.append(reader.read(k))
            report((k + 1) / reader.count)
        self.count = len(states)
        self.normals = np.zeros((0, 2))
        self.frames = [_packing_frame(k, state) for k, state in enumerate(states)]
        times = np.array([state.time for state in states], dtype=float)
        steps = np.array([state.step for state in states], dtype=float)
        frames = np.arange(1, self.count + 1, dtype=float)
        increasing = [bool(self.count == 1 or np.all(np.diff(t) > 0)) for t in (times, steps)]
        self.time_label = "t" if increasing[0] and times.any() else ("timestep" if increasing[1] else "frame")
        self.times = {"t": times, "timestep": steps, "frame": frames}[self.time_label]
        self.of = None
        self.clock_unit = "tens of frames"
        span = float(self.times[-1] - self.times[0])
        self.cycle_time = 10.0 * span / max(1, self.count - 1) or 1.0
        self.speed = 1.0
        stats = [packing_stats(state) for state in states]
        self.readouts = [{"phi": s.phi, "z": s.z} for s in stats]
        self.series = {"replay": (("t", "step", "frame", "z", "phi"),
                                  np.column_stack([self.times, steps, frames, [s.z for s in stats],
                                                   [s.phi for s in stats]]))}
        self.plot = "replay-structure"
        self.watched, self.watched_labels, self.groups = [], [], []
        self.changes = []

    def _strain_fit(self, until: float) -> dict | None:
        """The strain fit of the cycles recorded up to ``until``, as the preset showed it."""
        if "cycles" not in self.series or self.of is None:
            return None
        columns, rows = self.series["cycles"]
        count = int(np.count_nonzero(rows[:, columns.index("t")] <= until))
        if self._fit[0] != count:  # status is read at every frame shown; the fit changes only with a cycle
            pairs = list(zip(rows[:count, columns.index("cycle")].astype(int), rows[:count, columns.index("gamma")]))
            self._fit = (count, strain_fit(pairs, self._fit_from(until)))
        return self._fit[1]

    def _fit_from(self, until: float) -> int:
        """The cycle the preset fitted from at time ``until``: the second whole cycle after the
        last change of the physics (the first cycles settle the packing)."""
        settle = getattr(PRESETS[self.of], "reference_cycle", 0)
        cycles = [c["cycle"] for c in self.changes if c["t"] <= until and c.get("cycle") is not None]
        return math.ceil(cycles[-1] - 1e-9) + settle if cycles else settle

    def state(self) -> PackingState:
        """The frame shown, as the analyses take it (another code's packing is held in memory; a run
        file's frame is read again, as its file holds it)."""
        return self.states[self.index] if self.states else read_state(self.path, self.index)

    def settings(self, index: int) -> dict | None:
        text = self.frames[index].get("lab_settings_json")
        return json.loads(text) if text else None

    def data(self) -> FrameData:
        return FrameData.from_run_frame(self.frames[self.index], self.normals)

    def rows(self, name: str, after: float, until: float) -> np.ndarray:
        """Rows of series ``name`` with ``after < t <= until``."""
        columns, rows = self.series[name]
        t = rows[:, columns.index("t")]
        return rows[(t > after) & (t <= until)]

    def status(self) -> dict:
        frame = self.frames[self.index]
        status = {"preset": self.name, "title": f"Replay of {self.path.name}",
                  "stage": f"frame {self.index + 1} of {self.count}", "time": float(self.times[self.index]),
                  "time_label": self.time_label, "step": frame["step"],
                  "particles": int(frame["position"].shape[0]), "settings": self.settings(self.index),
                  "clock_unit": self.clock_unit, "cycle_time": self.cycle_time, "speed": self.speed, "window": 0.0,
                  "watched": [list(pair) for pair in self.watched], "watched_labels": self.watched_labels,
                  "strain": self._strain_fit(frame["time"]),
                  "changes": [change for change in self.changes if change["t"] <= frame["time"]],
                  "replay": {"of": self.of, "frame": self.index, "frames": self.count, "plot": self.plot,
                             "start": float(self.times[0]), "end": float(self.times[-1])}}
        if self.readouts is not None:
            status["readout"] = self.readouts[self.index]
        return status


def _is_run_file(path: Path) -> bool:
    with h5md.open_run(path) as f:
        return h5md.is_run_file(f)


def _packing_frame(index: int, state: PackingState) -> dict:
    """A frame of another code's packing as :meth:`FrameData.from_run_frame` reads it (no walls;
    the disks do not turn)."""
    c = state.contacts
    return {"index": index, "time": state.time, "step": state.step, "position": state.positions,
            "radius": state.radii, "angle": np.zeros(state.disks), "edges": state.box_lengths,
            "boundary": ["periodic" if p else "none" for p in state.periodic],
            "contacts": {"pair": np.column_stack([c.i, c.j]), "image": c.image, "status": c.status,
                         "normal_force": c.normal_force, "tangential_force": c.tangential_force,
                         "surface_gap": c.surface_gap}}


def write_run(report, path: Path, sim, checkpoint: bool, frames: list, protocol: dict, series: dict, rows: dict,
              cycles: list) -> str:
    """Write a lab run file to ``path`` (the job of "Save run"): ``sim`` (a copy of the simulation:
    its parameters, and its checkpoint if ``checkpoint``), ``frames`` (snapshot, settings JSON,
    phase) triples, the lab's ``series`` (name -> columns) with their ``rows``, and the ``cycles``
    records of ``granlab info`` as (cycle, step, t, L_x, L_y, wall positions). Returns what was
    written, for the user."""
    need, room = h5md.run_file_bytes(sim, len(frames)), room_for_one_file(path.parent)
    if need > room:
        raise GranLabError(f"saving {path.name}: {len(frames)} frames of {sim.particles.count} disks need up to "
                           f"{costs.size(need)}; {costs.size(room)} free in the data folder")
    with staged(path.parent, last=[path.name]) as folder:  # a file appears in the list only once complete
        with h5md.RunWriter(folder / path.name, sim, protocol=protocol, lab_series=series, overwrite=True) as writer:
            for k, (snap, settings, phase) in enumerate(frames):
                writer.write_frame(snap, settings, phase)
                report(0.95 * (k + 1) / len(frames))
            for name, values in rows.items():
                writer.write_series(name, values)
            for record in cycles:
                writer.write_cycle_record(*record)
            if checkpoint:
                writer.write_checkpoint(sim)
    return f"saved {len(frames)} frames (t = {frames[0][0].time:.4g} to {frames[-1][0].time:.4g}) to {path.name}"


def write_handout(report, run: Path, out: Path) -> str:
    """The handout of the run file ``run`` (the job of "Handout"): one HTML page ``out`` that replays it
    from disk, without a server (:mod:`granlab.engine.io.export.html`)."""
    from granlab.engine.io.export import export_run

    result = export_run(run, "html", out, progress=lambda done, total: report(done / max(total, 1)))
    return (f"wrote {out.name}: {len(result['indices'])} frames, {out.stat().st_size / 1e6:.1f} MB, one page that "
            f"opens from disk in any browser")


def write_lab_movie(report, path: Path, frames: list, color: str, watched: list, labels: list[str],
                    groups: list) -> str:
    """Render (FrameData, caption) pairs into the movie ``path`` (the job of "Record movie"),
    the ``watched`` pairs drawn in their colours and named by ``labels`` in the legend, the
    ``groups`` of disks named under them (:func:`granlab.engine.frames.group_labels`)."""
    from ..media.render import union_bounds, write_movie  # matplotlib takes a second to load: only when a movie is made

    scenes = [(build_frame([(data, (0.0, 0.0))], [watched], groups), caption) for data, caption in frames]
    bounds = union_bounds(scene for scene, _ in scenes)

    def rendered():
        for k, pair in enumerate(scenes):
            yield pair
            report((k + 1) / len(scenes))

    with staged(path.parent, last=[path.name]) as folder:
        count = write_movie(rendered(), folder / path.name, color_field=color, bounds=bounds, watched_labels=labels)
    return f"recorded {count} frames to {path.name}"
