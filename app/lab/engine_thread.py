"""The lab's engine: one simulation per server, advanced by a background thread.

Controls reach it through a command queue, applied between steps. It publishes

- the latest scene frame (a copy, under a lock, with a sequence number),
- time series in ring buffers with sequence numbers, recorded by the preset at its sample
  times in simulated time (each browser tab pulls what it has not seen),
- messages (errors, confirmations), each naming the control that caused it,
- a status dictionary (``GET /status``).

The simulation runs at the speed the user chose, in the preset's clock units (load cycles,
loops, T_0) per second of wall clock, or as fast as it can. The thread runs its kernels on one
numba thread: a single-threaded kernel never asks for the GIL, so the UI's event loops cannot
stall it, and it leaves the other core to them.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import logging
import math
import queue
import re
import threading
import time
from collections import deque
from pathlib import Path

import numba
import numpy as np

from granlab.engine.analysis import ANALYSES
from granlab.engine.analysis.states import PackingState
from granlab.engine.errors import DivergenceError, GranLabError, ParameterError
from granlab.engine.frames import FrameData, SceneFrame, build_frame
from granlab.engine.io.jsonsafe import jsonable
from granlab.engine.io.outputs import free_name, occupied
from granlab.engine.params import positive
from granlab.engine.protocols.presets import (PRESETS, Preset, make_preset, preset_settings, setup_query,
                                              setup_text)
from granlab.engine.protocols.settings import CONTROL_LABELS, RESET_CONTROLS, LabSettings

from .analysis import AnalysisResult, AnalysisRunner
from .buffers import Cursor, MessageLog, SeriesBuffer
from ..media.drawing import COLOR_FIELDS, frame_caption
from .jobs import JobOutcome, Jobs
from .options import HISTORY_MIB
from .replay import Replay, read_replay, read_time_limit, write_handout, write_lab_movie, write_run

LOG = logging.getLogger("granlab.lab")

FILE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,99}$")
CHUNK_SECONDS = 0.02
SERIES_CAPACITY = {"contacts": 1_000_000, "time": 400_000, "block": 400_000, "springs": 400_000, "cycles": 100_000,
                   "replay": 100_000, "collision": 400_000}
"""Rows each series keeps (a tab that falls further behind gets the newest ones), and so a save
holds: the watched paths of ratchet16 (320 samples of 6 contacts a cycle) for its last 520 cycles,
so that a replay draws the cone plot at the frames of those (ratchet16 keeps the frames of 1350
cycles, ratchet those of 90). A buffer's memory is taken when its preset starts (48 MB for the paths; the
ratchet's three series 78 MiB in all) and goes with it."""
MOVIE_SUFFIXES = (".gif", ".mp4")
REPLAY_SUFFIXES = (".h5", ".h5md", ".dump", ".xyz")


def safe_path(data_dir: Path, name: str, suffix: str = ".h5") -> Path:
    """The file ``name`` inside ``data_dir``: a plain name (letters, digits, ``._-``), no folders.

    ``suffix`` is added when there is none. Anything else raises a ParameterError."""
    if not isinstance(name, str) or not FILE_NAME.match(name) or ".." in name:
        raise ParameterError("file name", name, "a plain name of letters, digits, '.', '_' or '-' (no folders, "
                                                "no '..', no absolute path), inside the lab's data folder")
    path = data_dir / name
    if not path.suffix:
        path = path.with_suffix(suffix)
    if path.resolve().parent != data_dir.resolve():
        raise ParameterError("file name", name, "a file inside the lab's data folder")
    return path


def new_file(data_dir: Path, name: str, suffix: str = ".h5") -> Path:
    """:func:`safe_path` for a file to be written: a name already in the data folder is refused
    (the lab never writes over a file), with a free name suggested."""
    path = safe_path(data_dir, name, suffix)
    if occupied(path):
        raise ParameterError("file name", name, f"a name not yet in the data folder ({free_name(path).name} is free)")
    return path


def settings_json(settings: LabSettings) -> str:
    return json.dumps(jsonable(dataclasses.asdict(settings)))


class LabEngine:
    """The simulation of one lab server and the thread that runs it.

    With ``wait_for_tab`` the preset is built and its kernels compiled, but it starts (at t = 0)
    only when the first tab opens (command ``tab_opened``). With ``pause_without_pages`` (seconds),
    a run left with no page open (every tab closed, command ``tab_closed``) pauses after that long and
    goes on when a page opens: a lab forgotten after class takes no core from what follows. The
    frames kept for a save or a movie take at most ``history_mib`` MiB (the oldest go first)."""

    def __init__(self, data_dir: str | Path, preset: str = "ratchet", frame_rate: float = 30.0,
                 wait_for_tab: bool = False, history_mib: float = HISTORY_MIB, pause_without_pages: float = 0.0,
                 **changes):
        self.data_dir = Path(data_dir)
        self.data_dir.mkdir(parents=True, exist_ok=True)
        self.frame_interval = 1.0 / frame_rate
        self.commands: queue.Queue = queue.Queue()
        self.messages = MessageLog()
        self.buffers: dict[str, SeriesBuffer] = {}
        self.run = 0
        """The number of the run shown (a preset, a restart, a replay): the buffers' rows and the status carry it."""
        self._lock = threading.Lock()
        self._frame = None
        self._frame_seq = 0
        self._frame_taken = True
        self._frame_ready = threading.Event()
        self._status: dict = {}
        self.waiting = wait_for_tab
        self.running = not wait_for_tab
        self.error = ""
        self.tabs = 0
        self.pause_without_pages = pause_without_pages
        self._no_page_since: float | None = None
        self.paused_for = ""
        """Why the run paused by itself (no page open), while it stays paused; else empty."""
        self.command_ms = 0.0
        self.scene_fps = lambda: 0.0
        self._stop = threading.Event()
        self._history: deque = deque()
        self._history_bytes = 0
        self.history_limit = int(history_mib * 2 ** 20)
        self._rate: deque = deque()
        self._anchor = (time.perf_counter(), 0.0)
        self._thread = threading.Thread(target=self._loop, name="granlab-engine", daemon=True)
        self.analysis = AnalysisRunner(on_done=self._analysis_done)
        self.jobs = Jobs(on_done=lambda outcome: self.submit("job_done", outcome=outcome))
        self._stepping: float | None = None
        settings = preset_settings(preset, **changes)
        if wait_for_tab:
            self._warm_up(preset, settings)
        self.source: Preset | Replay = make_preset(preset, settings)
        self._switch(self.source)
        self._publish()

    @staticmethod
    def _warm_up(preset: str, settings: LabSettings) -> None:
        """Compile (or load from the cache) the kernels a preset and its frames use, on a copy."""
        warm = make_preset(preset, settings)
        warm.advance(5)
        view = warm.views()[0]
        build_frame([(FrameData.from_simulation(view.sim), view.offset)], [warm.watched()])

    # ------------------------------------------------------------------ for the UI threads
    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self.submit("wake")
        self._thread.join(timeout=10)
        self.analysis.close()
        self.jobs.close()

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def submit(self, command: str, **payload) -> None:
        """Queue a command (``apply``, ``preset``, ``reset``, ``play``, ``pause``, ``step``, ``seek``,
        ``watch``, ``watch_disk``, ``save``, ``load``, ``record``, ``analyze``, ``tab_opened``); it
        never blocks. Its outcome arrives in :attr:`messages`."""
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
        if buffer is None:  # a series this run has not
            return Cursor(run=self.run), True, {}
        return buffer.since(cursor)

    def saved_files(self) -> list[str]:
        """The files of the data folder a replay can show: run files and H5MD files, LAMMPS dumps
        of atoms (not their ``-contacts`` dumps), extended XYZ files; not the hidden files a save
        writes into before it is complete."""
        return sorted(path.name for path in self.data_dir.iterdir() if path.suffix in REPLAY_SUFFIXES
                      and not path.stem.endswith("-contacts") and not path.name.startswith("."))  \
            if self.data_dir.is_dir() else []

    # ------------------------------------------------------------------ the thread
    def _loop(self) -> None:
        numba.set_num_threads(1)
        last_publish = time.perf_counter()
        while not self._stop.is_set():
            if self._stepping is not None:
                wait = self._step_chunk()
            else:
                wait = self._run_chunk() if self.running else 0.05
            self._drain(wait)
            self._pause_if_no_page()
            now = time.perf_counter()
            if now - last_publish >= self.frame_interval:
                last_publish = now
                self._publish(frame=self._frame_taken)

    def _drain(self, wait: float) -> None:
        """Execute the queued commands, waiting up to ``wait`` seconds for the first."""
        try:
            command = self.commands.get(timeout=wait) if wait > 0 else self.commands.get_nowait()
        except queue.Empty:
            return
        while True:
            self._execute(*command)
            try:
                command = self.commands.get_nowait()
            except queue.Empty:
                return

    def _execute(self, command: str, payload: dict, submitted: float) -> None:
        control = {"apply": next(iter(payload.get("changes", {})), ""), "watch": "watch", "watch_disk": "watch",
                   "save": "save", "load": "load", "record": "record", "handout": "handout", "analyze": "analysis",
                   "preset": "preset", "setup": "preset", "seek": "replay",
                   "cancel": payload.get("kind", "run")}.get(command, "run")
        try:
            if command == "apply":
                self._apply(payload["changes"])
            elif command == "preset":
                self._switch(make_preset(payload["name"]))
                self.running = not self.waiting
                self._info(f"preset: {self.source.title}", "preset")
            elif command == "reset":
                name = self.source.of if isinstance(self.source, Replay) and self.source.of else self._preset_name()
                self._switch(make_preset(name, self._settings() if isinstance(self.source, Preset) else None))
                self.running = True
                self._info("preset restarted at t = 0", "run")
            elif command == "defaults":
                preset = self._preset_only("defaults")
                self._switch(make_preset(preset.name))
                self.running = not self.waiting
                self._info(f"the settings of {preset.name} are its own again (restarted at t = 0)", "run")
            elif command == "setup":
                self._setup(payload["name"], payload["changes"])
            elif command == "tab_opened":
                self._no_page_since = None
                if self.waiting:
                    self.waiting, self.running = False, True
                    self._switch(make_preset(self._preset_name(), self._settings()))
                elif self.paused_for:
                    self.running, self.paused_for = True, ""
                    self._reanchor()
                    LOG.info("a page opened: the run goes on")
            elif command == "tab_closed":
                if self.tabs == 0:
                    self._no_page_since = time.monotonic()
            elif command == "play":
                self.running, self.error, self._stepping = True, "", None
                if isinstance(self.source, Replay) and self.source.index == self.source.count - 1:
                    self._seek(0)
                self._reanchor()
            elif command == "pause":
                self.running, self._stepping = False, None
            elif command == "step":
                self.running = False
                self._step_once()
            elif command == "cancel_pending":
                self._info(self._preset_only("controls").cancel_pending(), "pending")
            elif command == "fit_from_now":
                self._info(self._preset_only("fit").fit_from_now(), "fit")
            elif command == "cancel":
                if self.jobs.cancel(payload["kind"]) is None:
                    self._info("nothing to cancel", payload["kind"])
            elif command == "job_done":
                self._job_done(payload["outcome"])
            elif command == "seek":
                self.running = False
                self._seek(int(payload["index"]))
            elif command == "watch":
                self._info(self._preset_only("watch").toggle_watch(tuple(payload["pair"])), "watch")
            elif command == "watch_disk":
                self._info(self._preset_only("watch").watch_disk(int(payload["index"])), "watch")
            elif command == "save":
                self._save(payload["name"])
            elif command == "load":
                self._load(payload["name"])
            elif command == "handout":
                self._handout(payload["name"])
            elif command == "record":
                self._record(payload["name"], float(payload["seconds"]), payload.get("color", "rotation"))
            elif command == "analyze":
                self._analyze(payload["kind"])
            self.command_ms = 1000.0 * (time.perf_counter() - submitted)
        except ParameterError as error:
            key = error.name if error.name in CONTROL_LABELS else control
            label = CONTROL_LABELS.get(error.name, error.name)
            self.messages.add("error", f"{label} = {_shown(error.value)} is not allowed: {error.allowed}", key)
        except (GranLabError, ValueError, OSError) as error:
            self.messages.add("error", str(error), control)
        self._publish()

    def _pause_if_no_page(self) -> None:
        since = self._no_page_since
        if not (self.running and self.pause_without_pages > 0 and self.tabs == 0 and since is not None
                and time.monotonic() - since >= self.pause_without_pages):
            return
        self.running, self._stepping = False, None
        self.paused_for = f"no page open for {self.pause_without_pages:g} s"
        LOG.info("%s: the run is paused; it goes on when a page opens", self.paused_for)

    def _preset_only(self, what: str) -> Preset:
        if not isinstance(self.source, Preset):
            verb = {"save": "Save", "record": "Record", "watch": "Watching a contact",
                    "controls": "Changing a setting", "fit": "Fitting the strain",
                    "defaults": "Resetting the settings"}.get(what, what)
            raise GranLabError(f"{verb} works on a running preset, not on a replay ({self.source.path.name} is "
                               f"already a file): choose a preset first (a movie of a replay: granlab render "
                               f"{self.source.path.name} --out movie.gif)")
        return self.source

    def _preset_name(self) -> str:
        return self.source.name if isinstance(self.source, Preset) else "ratchet"

    def _settings(self) -> LabSettings | None:
        return self.source.settings if isinstance(self.source, Preset) else None

    def _apply(self, changes: dict) -> None:
        if isinstance(self.source, Replay) and set(changes) == {"speed"}:
            self.source.speed = positive("speed", changes["speed"], allow_inf=True)
            self._reanchor()
            self._info(f"replay speed: {_shown(self.source.speed)} {self.source.clock_unit} per second", "speed")
            return
        preset = self._preset_only("controls")
        labels = ", ".join(f"{CONTROL_LABELS.get(k, k)} = {_shown(v)}" for k, v in changes.items())
        key = next(iter(changes), "")
        if any(k in RESET_CONTROLS for k in changes):
            self._switch(make_preset(preset.name, preset.settings.replace(**changes)))
            self.running = not self.waiting
            self._info(f"applied: {labels} (restarted at t = 0)", key)
            return
        notes = preset.apply(**changes)
        self._reanchor()  # a new speed or period changes the pace
        waiting = [k for k in changes if k in preset.pending]
        if waiting:
            self._info(f"from {preset.status().get('pending_from', 'later')}: {labels} (until then the values in "
                       f"effect stay)", key)
            return
        self._info(f"applied: {labels}" + (f" ({'; '.join(notes)})" if notes else ""), key)

    def _setup(self, name: str, changes: dict) -> None:
        """The setup of a link: preset ``name`` with ``changes`` of its own settings, from t = 0
        unless it is the one running (then only its speed may change)."""
        settings = preset_settings(name, **changes)
        source = self.source
        running = isinstance(source, Preset) and source.name == name
        if running and source.settings.replace(speed=settings.speed) == settings:
            if settings.speed != source.settings.speed:
                self._apply({"speed": settings.speed})
            return
        self._switch(make_preset(name, settings))
        self.running = not self.waiting
        self._info(setup_text(name, changes) + " (from t = 0)", "preset")

    def _switch(self, source) -> None:
        """Show ``source`` (a preset from its start, or a replay at its first frame)."""
        self.source = source
        self._stepping = None
        self._history.clear()
        self._history_bytes = 0
        self._rate.clear()
        self.error = ""
        self.run += 1
        self._reset_buffers()
        if isinstance(source, Preset):
            source.on_frame = self._remember
            self._remember()
            self._collect()
        else:
            self._seek(0)
        self._reanchor()

    def _reset_buffers(self) -> None:
        series = dict(self.source.series) if isinstance(self.source, Preset) else \
            {name: columns for name, (columns, _) in self.source.series.items()}
        for name, columns in series.items():
            if name not in self.buffers:
                self.buffers[name] = SeriesBuffer(columns, SERIES_CAPACITY.get(name, 40000))
            self.buffers[name].reset(columns, run=self.run)
        for name in self.buffers.keys() - series.keys():  # its memory goes: a lab runs through every preset
            del self.buffers[name]

    def _reanchor(self) -> None:
        """Pace from now on: simulated time advances at the chosen speed from the current state."""
        self._anchor = (time.perf_counter(), self._time())

    def _time(self) -> float:
        source = self.source
        return float(source.times[source.index]) if isinstance(source, Replay) else source.sim.time

    def _pace(self) -> float:
        """Simulated time per second of wall clock (inf: as fast as possible)."""
        source = self.source
        if isinstance(source, Replay):
            return source.speed * source.cycle_time
        return source.settings.speed * source.cycle_time()

    def _run_chunk(self) -> float:
        """Advance about ``CHUNK_SECONDS`` of work, no further than the paced target time;
        returns how long the loop may wait for commands before the next chunk."""
        pace = self._pace()
        now = time.perf_counter()
        if isinstance(self.source, Replay):
            return self._play_replay(pace, now)
        sim = self.source.sim
        steps = self._chunk_steps()
        if math.isfinite(pace):
            wall0, sim0 = self._anchor
            behind = sim0 + pace * (now - wall0) - sim.time
            if behind <= 0.0:
                return min(CHUNK_SECONDS, -behind / pace)
            if behind > 0.5 * pace:  # cannot keep up: go on at full speed, do not sprint to catch up later
                self._anchor = (now - 0.25, sim.time - 0.25 * pace)
            steps = max(1, min(steps, math.ceil(behind / sim.dt)))
        self._advance(steps)
        return 0.0

    def _chunk_steps(self) -> int:
        seconds = sum(r[3] for r in self._rate)
        if seconds <= 0.0:
            return 10
        return max(1, int(CHUNK_SECONDS * sum(r[2] for r in self._rate) / seconds))

    def _advance(self, steps: int) -> None:
        source = self.source
        start = time.perf_counter()
        try:
            done = source.advance(steps, deadline=start + CHUNK_SECONDS)
        except DivergenceError as error:
            self.running = False
            self._error(f"{error} Paused: change a parameter or restart the preset, then press play.")
            return
        finally:
            self._collect()
        end = time.perf_counter()
        self._rate.append((end, done * sum(v.sim.particles.count for v in source.views()), done, end - start,
                           source.sim.time))
        while self._rate and self._rate[0][0] < end - 2.0:
            self._rate.popleft()

    def _step_once(self) -> None:
        """One sample interval of the preset (a path sample), or the next frame of a replay. The
        preset's interval is run in chunks like a play (:meth:`_step_chunk`): commands are
        answered on the way, and Pause, Play, a new preset or a restart end the step."""
        source = self.source
        if isinstance(source, Replay):
            self._seek(min(source.index + 1, source.count - 1))
            return
        if self._stepping is None:
            self._stepping = source.sim.time + source.steps_to_next_sample() * source.sim.dt
            self._step_from = source.sim.time

    def _step_chunk(self) -> float:
        """A chunk of the step under way; the step ends at its target time."""
        sim = self.source.sim
        remaining = math.ceil((self._stepping - sim.time) / sim.dt - 1e-6)
        if remaining <= 0:
            self._stepping = None
            return 0.05
        self._advance(min(remaining, self._chunk_steps()))
        if self.error:
            self._stepping = None
        return 0.0

    def _collect(self) -> None:
        """Move the rows the preset recorded into the buffers."""
        for name, rows in self.source.rows().items():
            self.buffers[name].extend(rows)

    def _play_replay(self, pace: float, now: float) -> float:
        source = self.source
        wall0, sim0 = self._anchor
        target = sim0 + pace * (now - wall0) if math.isfinite(pace) else math.inf
        index = int(np.searchsorted(source.times, target, side="right")) - 1
        index = min(max(index, source.index), source.count - 1)
        if index == source.count - 1 and source.index == index:
            self.running = False
            return 0.05
        if index > source.index:
            self._seek(index)
        return 0.01

    def _seek(self, index: int) -> None:
        """Show frame ``index`` of the replay, the series up to its time (forward: only the
        rows in between are added)."""
        source = self.source
        if not 0 <= index < source.count:
            raise ParameterError("replay frame", index, f"a frame 0 to {source.count - 1}")
        previous, until = source.times[source.index], source.times[index]
        forward = index > source.index and len(self.buffers["replay"]) > 0
        for name in source.series:
            if not forward:
                self.buffers[name].reset()
            self.buffers[name].extend(source.rows(name, previous if forward else -math.inf, until))
        source.index = index

    def _publish(self, frame: bool = True) -> None:
        """Publish the status and, if ``frame``, a copy of what the scene draws (the arrays of
        :class:`FrameData`; the scene's thread builds the frame from them)."""
        source = self.source
        if isinstance(source, Replay):
            if frame:
                parts = ([(source.data(), (0.0, 0.0))], [source.watched], source.groups)
            status = source.status()
        else:
            views = source.views()
            if frame:
                parts = ([(FrameData.from_simulation(v.sim), v.offset) for v in views],
                         [source.watched()] + [[] for _ in views[1:]], _groups(views))
            sim = views[0].sim
            status = source.status()
            status.update(time=sim.time, step=sim.step, particles=sum(v.sim.particles.count for v in views),
                          dt=sim.dt, watched=[list(p) for p in source.watched()],
                          watched_labels=source.watched_labels(), link=setup_query(source.name, source.settings),
                          speeds=source.speeds)
        seconds = sum(r[3] for r in self._rate)
        span = self._rate[-1][0] - self._rate[0][0] + self._rate[0][3] if self._rate else 0.0
        simulated = self._rate[-1][4] - self._rate[0][4] if len(self._rate) > 1 else 0.0
        if self.running:
            self.paused_for = ""
        state = self._state()
        if self._stepping is not None:
            interval = self._stepping - self._step_from
            status["step_progress"] = (self._time() - self._step_from) / interval if interval > 0 else 1.0
        status.update(state=state, run=self.run, error=self.error, paused_for=self.paused_for,
                      steps_per_s=sum(r[2] for r in self._rate) / seconds if seconds else 0.0,
                      particle_steps_per_s=sum(r[1] for r in self._rate) / seconds if seconds else 0.0,
                      speed_achieved=simulated / span / status["cycle_time"] if span > 0 and self.running else 0.0,
                      presets=list(PRESETS), command_ms=self.command_ms, history_frames=len(self._history),
                      history_mib=self._history_bytes / 2 ** 20, memory=self._memory(),
                      analysis_seq=self.analysis.latest().seq, analysis_busy=self.analysis.busy,
                      jobs=[job.describe() for job in self.jobs.running()],
                      message_seq=self.messages.latest_seq)
        status = jsonable(status)
        with self._lock:
            self._status = status
            if frame:
                self._frame = parts
                self._frame_seq += 1
                self._frame_taken = False
                self._frame_ready.set()

    def _memory(self) -> dict:
        """What the engine holds, in MiB (``/status``'s ``memory``): each series' buffer (taken whole when its
        preset starts) and the share of it rows fill, and the frames kept for saves and movies with their limit."""
        buffers = list(self.buffers.items())
        return {"series_mib": {name: buffer.nbytes / 2 ** 20 for name, buffer in buffers},
                "series_filled": {name: len(buffer) / buffer.capacity for name, buffer in buffers},
                "history_mib": self._history_bytes / 2 ** 20, "history_limit_mib": self.history_limit / 2 ** 20}

    def _state(self) -> str:
        if self.error:
            return "error"
        if self.waiting:
            return "waiting"
        if self.running:
            return "running"
        return "stepping" if self._stepping is not None else "paused"

    def _remember(self) -> None:
        """Keep a frame of the running preset (all its views) with the settings in effect and its phase
        (called by the preset at its frame times), within ``history_limit`` bytes (and at least
        the last two frames)."""
        snap = self.source.snapshot()
        self._history.append((snap, settings_json(self.source.settings), self.source.phase()))
        self._history_bytes += snap.nbytes
        while len(self._history) > 2 and self._history_bytes > self.history_limit:
            self._history_bytes -= self._history.popleft()[0].nbytes

    def _save(self, name: str) -> None:
        """Write the kept frames, the series and a checkpoint into a run file, in a job: the
        simulation goes on meanwhile (what is saved is the run up to now)."""
        preset = self._preset_only("save")
        path = new_file(self.data_dir, name)
        sim = preset.views()[0].sim
        frames = list(self._history)
        if frames[-1][0].step != sim.step:
            frames.append((preset.snapshot(), settings_json(preset.settings), preset.phase()))
        protocol = {"lab_preset": preset.name, "settings": dataclasses.asdict(preset.settings),
                    "clock_unit": preset.clock_unit, "cycle_time": preset.cycle_time(),
                    "watched": [list(pair) for pair in preset.watched()], "changes": preset.changes,
                    "watched_labels": preset.watched_labels(),
                    "views": [list(group) for group in _groups(preset.views())]}
        layout, checkpoint = preset.file_simulation()
        rows = {name_: buffer.array() for name_, buffer in self.buffers.items() if name_ in preset.series}
        cycles = _cycle_records(self.buffers["cycles"], sim) if "cycles" in preset.series else []
        if checkpoint:
            # the preset's own simulation, copied now: the job's thread pickles its arguments while
            # this thread steps the run on
            layout = copy.deepcopy(layout)
        self.jobs.start("save", f"saving {path.name}", write_run,
                        (path, layout, checkpoint, frames, jsonable(protocol), dict(preset.series), rows,
                         cycles))
        self._info(f"saving {len(frames)} frames to {path.name}…", "save")

    def _load(self, name: str) -> None:
        """Read a file of the data folder in a job; it replaces the preset once read."""
        path = safe_path(self.data_dir, name)
        if not path.is_file():
            raise ParameterError("file name", name, "a file of the lab's data folder (" +
                                 (", ".join(self.saved_files()) or "none yet: save a run first") + ")")
        self.jobs.start("load", f"reading {path.name}", read_replay, (path,), time_limit=read_time_limit(path))
        self._info(f"reading {path.name}…", "load")

    def _handout(self, name: str) -> None:
        """Write the handout of a run file of the data folder, ``NAME.html`` beside it (or the first
        free ``NAME-2.html`` ...: the lab never writes over a file), in a job."""
        path = safe_path(self.data_dir, name)
        if path.suffix != ".h5" or not path.is_file():
            raise ParameterError("file name", name, "a GranLab run file (.h5) of the lab's data folder (" +
                                 (", ".join(n for n in self.saved_files() if n.endswith(".h5")) or
                                  "none yet: save a run first") + ")")
        out = free_name(path.with_suffix(".html"))
        self.jobs.start("handout", f"writing {out.name}", write_handout, (path, out))
        self._info(f"writing the handout {out.name}…", "handout")

    def _record(self, name: str, seconds: float, color: str = "rotation") -> None:
        """Render the kept frames of the last ``seconds`` of simulated time into a movie in the
        data folder, disks coloured by ``color``, in a job (the run goes on)."""
        preset = self._preset_only("record")
        if color not in COLOR_FIELDS:
            raise ParameterError("record colouring", color, "one of " + ", ".join(COLOR_FIELDS))
        path = new_file(self.data_dir, name, suffix=".gif")
        if path.suffix not in MOVIE_SUFFIXES:
            raise ParameterError("movie name", name, "a name ending in " + " or ".join(MOVIE_SUFFIXES))
        if not seconds > 0:
            raise ParameterError("record seconds", seconds, "a length of simulated time > 0")
        now = preset.sim.time
        frames = [(FrameData.from_snapshot(snap), frame_caption(snap.time, snap.step, phase))
                  for snap, _, phase in self._history if snap.time >= now - seconds]
        if len(frames) < 2:
            raise ParameterError("record seconds", seconds,
                                 f"a span holding at least 2 kept frames (frames are kept every "
                                 f"{preset.cycle_time() / preset.settings.frames_per_cycle:.3g} of simulated time)")
        self.jobs.start("record", f"recording {path.name}", write_lab_movie,
                        (path, frames, color, preset.watched(), preset.watched_labels(), _groups(preset.views())))
        self._info(f"recording {len(frames)} frames to {path.name}…", "record")

    def _job_done(self, outcome: JobOutcome) -> None:
        """A job ended: a replay read is shown; the others say what they wrote."""
        job = outcome.job
        if outcome.cancelled:
            self._info(f"{job.label}: cancelled (nothing written)" if job.kind != "load" else
                       f"{job.label}: cancelled", job.kind)
        elif outcome.error:
            self.messages.add("error", outcome.error, job.kind)
        elif job.kind == "load":
            replay = outcome.result
            self._switch(replay)
            self.running = True
            self._info(f"replaying {replay.path.name}: {replay.count} frames, {replay.time_label} = "
                       f"{replay.times[0]:.4g} to {replay.times[-1]:.4g}", "load")
        else:
            self._info(outcome.result, job.kind)

    def _analyze(self, kind: str) -> None:
        """Hand the current state to the analysis thread: a snapshot of the running preset (its
        first view), or the replayed frame as its run file holds it."""
        if kind not in ANALYSES:
            raise ParameterError("analysis", kind, f"one of {', '.join(ANALYSES)}")
        if isinstance(self.source, Preset):
            state = PackingState.from_snapshot(self.source.views()[0].sim.snapshot(), source=self.source.title)
        else:
            state = self.source.state  # a run file's frame is read on the analysis thread
        self.analysis.request(state, kind)
        self._info(f"analysis: {kind} of the state at t = {self._time():.4g} started", "analysis")

    def _analysis_done(self, result: AnalysisResult) -> None:
        if result.error:
            self.messages.add("error", f"analysis {result.kind}: {result.error}", "analysis")
        else:
            self._info(f"analysis: {result.kind} done in {result.report.timings['total']:.2f} s", "analysis")

    def _info(self, text: str, control: str = "") -> None:
        self.messages.add("info", text, control)

    def _error(self, text: str) -> None:
        """The run itself failed: the state shows the error until play, a reset or a new preset."""
        self.error = text
        self.messages.add("error", text, "run")


def _groups(views) -> list[tuple[str, int]]:
    """(label, number of disks) of each view of a preset of several, for the labels under them."""
    return [(view.label, view.sim.particles.count) for view in views] if len(views) > 1 else []


def _cycle_records(buffer: SeriesBuffer, sim) -> list[tuple]:
    """The cycle records of ``granlab info`` from the lab's cycle series, as
    :meth:`granlab.engine.io.h5md.RunWriter.write_cycle_record` takes them (wall positions rebuilt from
    the box lengths: the left and bottom walls do not move)."""
    columns = buffer.columns
    names = sim.walls.names
    records = []
    for row in buffer.array():
        record = dict(zip(columns, row))
        walls = np.array(sim.walls.offset, dtype=float)
        if "right" in names and "top" in names:
            walls[names.index("right")] = -record["length_x"] - walls[names.index("left")]
            walls[names.index("top")] = -record["length_y"] - walls[names.index("bottom")]
        records.append((int(record["cycle"]), int(record["step"]), record["t"], record["length_x"],
                        record["length_y"], walls))
    return records


def _shown(value) -> str:
    """A value as the user typed it (no quotes around strings; ∞ for inf)."""
    if isinstance(value, float):
        return "∞" if value == math.inf else f"{value:g}"
    return value if isinstance(value, str) else repr(value)
