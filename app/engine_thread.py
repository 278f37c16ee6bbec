"""The lab's engine: one simulation per server, advanced by a background thread.

Controls reach it through a command queue, applied between steps. It publishes

- the latest scene frame (a copy, under a lock, with a sequence number),
- time series in ring buffers with sequence numbers (each browser tab pulls what it has
  not seen),
- messages (errors, confirmations) in a buffer of their own,
- a status dictionary (``GET /status``).

The thread runs its kernels on one numba thread: a single-threaded kernel never asks for the
GIL, so the UI's event loops cannot stall it, and it leaves the other core to them.
"""

from __future__ import annotations

import dataclasses
import queue
import re
import threading
import time
from collections import deque
from pathlib import Path

import numba
import numpy as np

from engine.analysis.report import ANALYSES
from engine.analysis.states import PackingState, read_state
from engine.errors import DivergenceError, GranLabError, ParameterError
from engine.io import h5md
from engine.io.jsonsafe import jsonable
from engine.protocols.presets import PRESETS, RESET_CONTROLS, LabSettings, Preset, make_preset, preset_settings

from .analysis import AnalysisResult, AnalysisRunner
from .buffers import Cursor, SeriesBuffer
from .frames import FrameData, build_frame
from .drawing import SceneFrame

FILE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,99}$")
HISTORY_BYTES = 64 * 2 ** 20
CHUNK_SECONDS = 0.02


def safe_path(data_dir: Path, name: str) -> Path:
    """The file ``name`` inside ``data_dir``: a plain name (letters, digits, ``._-``), no folders.

    ``.h5`` is added when there is no suffix. Anything else raises a ParameterError."""
    if not isinstance(name, str) or not FILE_NAME.match(name) or ".." in name:
        raise ParameterError("file name", name, "a plain name of letters, digits, '.', '_' or '-' (no folders, "
                                                "no '..', no absolute path), inside the lab's data folder")
    path = data_dir / name
    if not path.suffix:
        path = path.with_suffix(".h5")
    if path.resolve().parent != data_dir.resolve():
        raise ParameterError("file name", name, "a file inside the lab's data folder")
    return path


class Replay:
    """Frames of a run file played back in a loop, with the series it recorded."""

    title = "Replay"
    controls: tuple[str, ...] = ()

    def __init__(self, path: Path):
        self.path = path
        self.name = f"replay:{path.name}"
        with h5md.open_run(path) as f:
            self.count = h5md.frame_count(f)
            if self.count == 0:
                raise h5md.RunFileError(f"{path.name} holds no complete frame to replay")
            params = h5md.parameters(f)
            walls = h5md.walls_from_json(params["walls_json"])
            self.normals = np.array([w.normal for w in walls], dtype=float).reshape(-1, 2)
            self.frames = [h5md.read_frame(f, k) for k in range(self.count)]
            fields = [x.decode() for x in f["observables/energy"].attrs["fields"]]
            energy = f["observables/energy/value"][: self.count]
        self.series = {"replay": ("t", "step") + tuple(fields)}
        self.rows_ready = [(frame["time"], frame["step"], *map(float, energy[k])) for k, frame in enumerate(self.frames)]
        self.index = 0
        self.stage = f"frame 1 of {self.count}"

    def data(self) -> FrameData:
        return FrameData.from_run_frame(self.frames[self.index], self.normals)

    def advance(self) -> None:
        self.index = (self.index + 1) % self.count
        self.stage = f"frame {self.index + 1} of {self.count}"

    def status(self) -> dict:
        frame = self.frames[self.index]
        return {"preset": self.name, "title": f"Replay of {self.path.name}", "stage": self.stage,
                "time": frame["time"], "step": frame["step"], "particles": int(frame["position"].shape[0])}


class LabEngine:
    """The simulation of one lab server and the thread that runs it."""

    def __init__(self, data_dir: str | Path, preset: str = "ratchet", frame_rate: float = 30.0,
                 sample_rate: float = 20.0, **changes):
        self.data_dir = Path(data_dir)
        self.data_dir.mkdir(parents=True, exist_ok=True)
        self.frame_interval = 1.0 / frame_rate
        self.sample_interval = 1.0 / sample_rate
        self.commands: queue.Queue = queue.Queue()
        self.messages = SeriesBuffer(("level", "text"), capacity=200)
        self.buffers: dict[str, SeriesBuffer] = {}
        self._lock = threading.Lock()
        self._frame = None
        self._frame_seq = 0
        self._frame_taken = True
        self._frame_ready = threading.Event()
        self._status: dict = {}
        self.running = True
        self.error = ""
        self.tabs = 0
        self.command_ms = 0.0
        self.scene_fps = lambda: 0.0
        self._stop = threading.Event()
        self._history: deque = deque()
        self._rate = deque()
        self._thread = threading.Thread(target=self._loop, name="granlab-engine", daemon=True)
        self.analysis = AnalysisRunner(on_done=self._analysis_done)
        self.source: Preset | Replay = make_preset(preset, preset_settings(preset, **changes))
        self._reset_buffers()
        self._publish()

    # ------------------------------------------------------------------ for the UI threads
    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self.submit("wake")
        self._thread.join(timeout=10)
        self.analysis.close()

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def submit(self, command: str, **payload) -> None:
        """Queue a command (``apply``, ``preset``, ``reset``, ``play``, ``pause``, ``step``, ``watch``,
        ``watch_disk``, ``save``, ``load``, ``analyze``); it never blocks. Its outcome arrives in :attr:`messages`."""
        self.commands.put((command, payload, time.perf_counter()))

    def frame(self, seen: int = -1, timeout: float = 0.0) -> tuple[int, SceneFrame | None]:
        """The latest scene frame if its sequence number is not ``seen`` (else None), waiting up
        to ``timeout`` seconds for one. The engine thread publishes the arrays; the frame is
        built here, on the caller's thread, and the engine copies the next arrays only once
        these were taken (a slow scene costs the engine nothing)."""
        self._frame_ready.wait(timeout)
        with self._lock:
            seq, parts = self._frame_seq, self._frame
            if seq == seen or parts is None:
                return seq, None
            self._frame_taken = True
            self._frame_ready.clear()
        return seq, build_frame(*parts)

    def status(self) -> dict:
        with self._lock:
            status = dict(self._status)
        status["tabs"] = self.tabs
        status["scene_fps"] = self.scene_fps()
        return status

    def series(self, name: str, cursor: Cursor):
        buffer = self.buffers.get(name)
        if buffer is None:
            return cursor, True, {}
        return buffer.since(cursor)

    def saved_files(self) -> list[str]:
        return sorted(path.name for path in self.data_dir.glob("*.h5"))

    # ------------------------------------------------------------------ the thread
    def _loop(self) -> None:
        numba.set_num_threads(1)
        last_frame = last_sample = last_history = time.perf_counter()
        while not self._stop.is_set():
            self._drain(block=not self.running)
            if self.running:
                self._step_once(chunked=True)
            now = time.perf_counter()
            if now - last_sample >= self.sample_interval:
                last_sample = now
                self._sample()
            if now - last_frame >= self.frame_interval:
                last_frame = now
                self._publish(frame=self._frame_taken)
            if now - last_history >= 1.0 and isinstance(self.source, Preset) and self.running:
                last_history = now
                self._remember()

    def _drain(self, block: bool) -> None:
        try:
            command = self.commands.get(timeout=0.05) if block else self.commands.get_nowait()
        except queue.Empty:
            return
        while True:
            self._execute(*command)
            try:
                command = self.commands.get_nowait()
            except queue.Empty:
                return

    def _execute(self, command: str, payload: dict, submitted: float) -> None:
        try:
            if command == "apply":
                self._apply(payload["changes"])
            elif command == "preset":
                self._switch(make_preset(payload["name"]))
                self._info(f"preset: {self.source.title}")
            elif command == "reset":
                self._switch(make_preset(self._preset_name(), self._settings()))
                self._info("reset")
            elif command == "play":
                self.running = True
                self.error = ""
            elif command == "pause":
                self.running = False
            elif command == "step":
                self.running = False
                self._step_once()
                self._sample()
            elif command == "watch":
                if isinstance(self.source, Preset):
                    self.source.toggle_watch(tuple(payload["pair"]))
            elif command == "watch_disk":
                if isinstance(self.source, Preset):
                    self.source.watch_disk(int(payload["index"]))
            elif command == "save":
                self._save(payload["name"])
            elif command == "load":
                self._load(payload["name"])
            elif command == "analyze":
                self._analyze(payload["kind"])
            self.command_ms = 1000.0 * (time.perf_counter() - submitted)
            self._publish()
        except (GranLabError, ValueError, OSError) as error:
            self.messages.extend([("error", str(error))])

    def _preset_name(self) -> str:
        return self.source.name if isinstance(self.source, Preset) else "ratchet"

    def _settings(self) -> LabSettings | None:
        return self.source.settings if isinstance(self.source, Preset) else None

    def _apply(self, changes: dict) -> None:
        if not isinstance(self.source, Preset):
            raise ParameterError("controls", sorted(changes), "a running preset (not a replay)")
        if any(key in RESET_CONTROLS for key in changes):
            settings = self.source.settings.replace(**changes)
            self._switch(make_preset(self.source.name, settings))
            self._info("applied: " + ", ".join(f"{k} = {v}" for k, v in changes.items()) + " (reset)")
            return
        self.source.apply(**changes)
        self._info("applied: " + ", ".join(f"{k} = {v}" for k, v in changes.items()))

    def _switch(self, source) -> None:
        self.source = source
        self._history.clear()
        self.error = ""
        self._reset_buffers()

    def _reset_buffers(self) -> None:
        series = self.source.series
        for name, columns in series.items():
            if name in self.buffers:
                self.buffers[name].reset(columns)
            else:
                self.buffers[name] = SeriesBuffer(columns)
        for name in list(self.buffers):
            if name not in series:
                self.buffers[name].reset()
        if isinstance(self.source, Replay):
            self.buffers["replay"].extend(self.source.rows_ready)

    def _step_once(self, chunked: bool = False) -> None:
        """Advance ``steps_per_frame`` steps; while running (``chunked``) at most what takes
        ``CHUNK_SECONDS`` at the measured rate, so that controls wait little and frames come
        often however large the system."""
        source = self.source
        if isinstance(source, Replay):
            source.advance()
            time.sleep(0.1)
            return
        steps = source.settings.steps_per_frame
        seconds = sum(r[3] for r in self._rate)
        if chunked and seconds > 0.0:
            steps = max(1, min(steps, int(CHUNK_SECONDS * sum(r[2] for r in self._rate) / seconds)))
        start = time.perf_counter()
        try:
            source.advance(steps)
        except DivergenceError as error:
            self.running = False
            self._error(f"{error} Paused: change a parameter or reset, then press play.")
            return
        self._rate.append((time.perf_counter(), steps * sum(v.sim.particles.count for v in source.views()),
                           steps, time.perf_counter() - start))
        while self._rate and self._rate[0][0] < time.perf_counter() - 2.0:
            self._rate.popleft()

    def _sample(self) -> None:
        if isinstance(self.source, Preset):
            self.source.sample()
            for name, rows in self.source.rows().items():
                self.buffers[name].extend(rows)

    def _publish(self, frame: bool = True) -> None:
        """Publish the status and, if ``frame``, a copy of what the scene draws (the arrays of
        :class:`FrameData`; the scene's thread builds the frame from them)."""
        source = self.source
        if isinstance(source, Replay):
            if frame:
                parts = ([(source.data(), (0.0, 0.0))], None)
            status = source.status()
        else:
            views = source.views()
            if frame:
                parts = ([(FrameData.from_simulation(v.sim), v.offset) for v in views],
                         [source.watched()] + [[] for _ in views[1:]])
            sim = views[0].sim
            status = source.status()
            status.update(time=sim.time, step=sim.step, particles=sum(v.sim.particles.count for v in views),
                          dt=sim.dt, watched=[list(p) for p in source.watched()])
        seconds = sum(r[3] for r in self._rate)
        status.update(state="error" if self.error else ("running" if self.running else "paused"), error=self.error,
                      steps_per_s=sum(r[2] for r in self._rate) / seconds if seconds else 0.0,
                      particle_steps_per_s=sum(r[1] for r in self._rate) / seconds if seconds else 0.0,
                      presets=list(PRESETS), command_ms=self.command_ms, history_frames=len(self._history),
                      analysis_seq=self.analysis.latest().seq, analysis_busy=self.analysis.busy)
        status = jsonable(status)
        with self._lock:
            self._status = status
            if frame:
                self._frame = parts
                self._frame_seq += 1
                self._frame_taken = False
                self._frame_ready.set()

    def _remember(self) -> None:
        snap = self.source.views()[0].sim.snapshot()
        size = snap.positions.nbytes * 4 + snap.contacts.i.nbytes * 16
        self._history.append(snap)
        while len(self._history) > max(2, HISTORY_BYTES // max(1, size)):
            self._history.popleft()

    def _save(self, name: str) -> None:
        if not isinstance(self.source, Preset):
            raise ParameterError("save", self.source.name, "a running preset (a replay is already a file)")
        path = safe_path(self.data_dir, name)
        sim = self.source.views()[0].sim
        snapshots = list(self._history) + [sim.snapshot()]
        partial = path.with_name(path.name + ".part")
        with h5md.RunWriter(partial, sim, protocol={"lab_preset": self.source.name,
                                                     "settings": dataclasses.asdict(self.source.settings)}) as writer:
            for snap in snapshots:
                writer.write_frame(snap)
            writer.write_checkpoint(sim)
        partial.replace(path)  # a file appears in the list only once complete
        self._info(f"saved {len(snapshots)} frames to {path.name}")

    def _load(self, name: str) -> None:
        path = safe_path(self.data_dir, name)
        self._switch(Replay(path))
        self.running = True
        self._info(f"replaying {path.name} ({self.source.count} frames)")

    def _analyze(self, kind: str) -> None:
        """Hand the current state to the analysis thread: a snapshot of the running preset (its
        first view), or the replayed frame as its run file holds it."""
        if kind not in ANALYSES:
            raise ParameterError("analysis", kind, f"one of {', '.join(ANALYSES)}")
        if isinstance(self.source, Preset):
            state = PackingState.from_snapshot(self.source.views()[0].sim.snapshot(), source=self.source.title)
        else:
            state = read_state(self.source.path, self.source.index)
        self.analysis.request(state, kind)
        self._info(f"analysis: {kind} of the state at t = {state.time:.4g} started")

    def _analysis_done(self, result: AnalysisResult) -> None:
        if result.error:
            self.messages.extend([("error", f"analysis {result.kind}: {result.error}")])
        else:
            self._info(f"analysis: {result.kind} done in {result.report.timings['total']:.2f} s")

    def _info(self, text: str) -> None:
        self.messages.extend([("info", text)])

    def _error(self, text: str) -> None:
        """The run itself failed: the state shows the error until play, a reset or a new preset."""
        self.error = text
        self.messages.extend([("error", text)])

