"""``granlab serve``: the engine thread, the viser scene and the panel server, together.

Binds 127.0.0.1 unless told otherwise. Routes: ``/`` the dashboard (one per tab), ``/status``
and ``/scene`` JSON for tests and monitoring, ``/lesson`` a lesson sheet to print, and a viewer's
2D scene ``/viewer-scene`` with its websocket ``/viewer-stream`` (:mod:`.stream`). The presenter's
viser client is served by viser on its own port and embedded in the dashboard; only the
dashboard's address is printed. Each scene's websocket admits only its page's own origin (any web
page could otherwise connect to it).

Served on a network (or with ``tokens``), the lab prints two addresses, each with its own random
token: the presenter's, which controls the simulation and its files, and the viewers', which see
everything live and change nothing. Without a valid token neither the dashboard, its websocket,
the scene's websocket, ``/status`` nor ``/scene`` answers. The page's first request sets a cookie
(HttpOnly, SameSite=Strict) that its websocket and later requests carry; the role of a tab is that
of the request its session is made for (:mod:`.access`), and a request by a name the lab did not
start with is refused, tokens or not.
"""

from __future__ import annotations

import contextlib
import ctypes
import gc
import io
import json
import logging
import os
import re
import socket
import subprocess
import sys
import threading
import time
import urllib.parse
import urllib.request
import weakref
from collections import deque
from pathlib import Path

import panel as pn
import tornado.ioloop
import tornado.web
from bokeh.server import urls as bokeh_urls
from bokeh.settings import settings as bokeh_settings
from panel.io.resources import LOCAL_DIST, _env
from websockets.http11 import Request

from granlab.engine import stopping
from granlab.engine.compilation import announced, compile_sets, missing, step_sets
from granlab.engine.errors import GranLabError
from granlab.engine.io.export.html import DRAWING
from granlab.engine.io.jsonsafe import jsonable
from granlab.engine.params import TANGENTIAL
from granlab.engine.protocols.presets import PRESETS, preset_settings

from . import lessons
from .access import Access, TokenAuth, connection_request
from .dashboard import Dashboard
from .engine_thread import LabEngine
from .gate import MAX_VIEWERS, GatedDocHandler, SessionGate, drop_stalled
from .logs import quiet_client_logs
from .options import HISTORY_MIB, LOCAL_HOSTS, PAUSE_WITHOUT_PAGES, check_serve_options, claimed_data_folder
from .scene import SceneView
from .starting import starting_page
from .stream import StreamSocket, ViewerStream

VIEWER_SCENE = Path(__file__).resolve().parents[2] / "static" / "viewer" / "scene.html"

LOG = logging.getLogger("granlab.lab")
# glibc (None elsewhere) keeps what a closed tab's session freed in the arena of the thread that
# freed it, one arena per thread up to 8 per core: a lab opened and closed in many tabs would hold
# it all. Two arenas and a trim after sessions end hand it back.
LIBC = ctypes.CDLL(None)
MALLOC_TRIM = getattr(LIBC, "malloc_trim", None)
MALLOPT = getattr(LIBC, "mallopt", None)
M_ARENA_MAX = -8
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 64 * 1024
"""Bytes from which glibc maps a block of its own, handed back whole when freed. Left to glibc, the threshold
rises to the largest block freed (32 MiB at most), and the columns a page streams (80-320 kB each) then land
in the arenas, where a class's pages fragment them: a quiet lab with ten viewers grew 51 MiB an hour so."""
TRIM_DELAY = 2.0  # seconds after a tab's session ends (later ends within it share one release)
RELEASE_EVERY = 10.0
"""Seconds between two releases at least: a full collection takes the loop for 0.1-0.3 s with forty pages open,
and a class leaving one by one would otherwise pay it every two seconds (12 % of the loop in a storm)."""
UNUSED_SESSION_MS = 5000
"""How long a page's session waits for its websocket before bokeh discards it: at 1 s a loaded server (forty
phones joining) discarded most pages before their websockets came, and built each page a second time as its
websocket opened (a quarter of the loop's time in that storm)."""
STALLED_CHECK_MS = 1000
"""How often the lab looks for pages that stopped reading."""
STARTER_STOP_SECONDS = 2.0
"""How long a stopping lab waits for its compile workers to be killed."""
# a phone lays the page out at its own width (without this, as a 980-pixel desktop page shrunk)
PAGE_TEMPLATE = _env.from_string('{% extends base %}{% block preamble %}{{ super() }}'
                                 '<meta name="viewport" content="width=device-width, initial-scale=1">{% endblock %}')
class PageHandler(tornado.web.RequestHandler):
    """A route of the lab: only to a request ``access`` admits (by one of the lab's names; with
    tokens, a valid one, which the dashboard's cookie carries)."""

    def initialize(self, access: Access):
        self.access = access

    def prepare(self):
        if self.access.admit(self) is None:
            raise tornado.web.HTTPError(403, "a valid token is needed" if self.access.admits_host(self.request.host)
                                        else f"this lab does not answer to {self.request.host!r}")


class JSONHandler(PageHandler):
    """``GET``: the dictionary ``read()`` returns, as JSON (the lab's status, the scene's state)."""

    def initialize(self, access: Access, read):
        super().initialize(access)
        self.read = read

    def get(self):
        self.set_header("Content-Type", "application/json")
        self.set_header("Cache-Control", "no-store")
        self.write(json.dumps(jsonable(self.read())))


class LessonHandler(PageHandler):
    """``GET lesson?preset=NAME``: the preset's lesson sheet as a page to print."""

    def get(self):
        name = self.get_query_argument("preset", "")
        sheet = lessons.lesson(name) if name in PRESETS else None
        if sheet is None:
            raise tornado.web.HTTPError(404, f"no lesson sheet for preset {name!r}: one of {', '.join(PRESETS)}")
        self.set_header("Content-Type", "text/html; charset=utf-8")
        self.write(lessons.lesson_html(sheet, standalone=True))


class ViewerSceneHandler(PageHandler):
    """``GET viewer-scene``: a viewer's scene, drawn in 2D from the viewers' stream."""

    def get(self):
        self.set_header("Content-Type", "text/html; charset=utf-8")
        self.write(VIEWER_SCENE.read_text(encoding="utf-8").replace("%DRAWING%", DRAWING))


def lab_kernel_sets(settings) -> tuple[list[str], list[str]]:
    """The kernel sets a preset with ``settings`` needs to start, and those the lab's other choices need
    (the other tangential models), compiled after it started."""
    first = [*step_sets([settings.tangential_model]), "packing", "state", "frames"]
    return first, [f"step-{model}" for model in TANGENTIAL if f"step-{model}" not in first]


class Lab:
    """Everything one ``granlab serve`` runs: engine, scene, scene thread and panel server.

    The server answers at once; the engine starts once the kernels its first preset needs are
    compiled (on a first run, in worker processes: meanwhile every page shows how far), and the
    kernels of the lab's other choices are compiled next, in a worker process beside it."""

    def __init__(self, host: str = "127.0.0.1", port: int = 5006, data_dir: str | Path = "granlab-data",
                 preset: str = "ratchet", scene_rate: float = 30.0, tokens: bool = False,
                 history_mib: float = HISTORY_MIB, pause_without_pages: float = PAUSE_WITHOUT_PAGES,
                 max_viewers: int = MAX_VIEWERS, **changes):
        self.host = host
        self.gate = SessionGate(max_viewers, UNUSED_SESSION_MS / 1000)
        self.port = port or _free_port(host)
        self.access = Access(host, self.port, tokens)
        settings = preset_settings(preset, **changes)  # a bad setting is refused before anything starts
        kernel_sets = lab_kernel_sets(settings)
        self.compiles = bool(missing(kernel_sets[0]))
        """Whether the engine's start compiles kernels (a first run): else it starts in a second or two."""
        self.engine: LabEngine | None = None
        self.starting = {"state": "compiling" if self.compiles else "starting", "done": 0, "total": 0,
                         "current": "", "seconds": 0.0, "error": ""}
        self._ready = threading.Event()
        self._starter = threading.Thread(target=self._start_engine, name="granlab-starter", daemon=True,
                                         args=(data_dir, preset, history_mib, pause_without_pages, changes,
                                               kernel_sets))
        with contextlib.redirect_stdout(io.StringIO()):  # viser prints its own address: the page embeds it
            self.scene = SceneView(host=host, port=0, admit=self._admit_scene,
                                   may_pick=self._presenter_path if tokens else None)
        self.scene.on_pick(lambda index: self.engine and self.engine.submit("watch_disk", index=index))
        self.scene_interval = 1.0 / scene_rate
        self.stream = ViewerStream()
        self._stop = threading.Event()
        self._release_pending = False
        self._released = -RELEASE_EVERY
        self.releases = 0
        self.pages: weakref.WeakSet[Dashboard] = weakref.WeakSet()
        """The pages open (a page goes with its session's document)."""
        """The memory releases done since the start (``/status``: ``memory_releases``)."""
        self._scene_thread = threading.Thread(target=self._push_scene, name="granlab-scene", daemon=True)
        # the page loads bokeh's and panel's files from this server, whatever BOKEH_RESOURCES the
        # environment holds (cdn would point every stylesheet at cdn.holoviz.org)
        bokeh_settings.resources.set_value("server")
        access = {"access": self.access}
        with gated_pages():
            self.server = pn.serve(
                {"/": self._session}, port=self.port, address=host, websocket_origin=self.access.websocket_origins(),
                auth_provider=TokenAuth(self.access), sign_sessions=True, secret_key=self.access.secret,
                show=False, start=False, title="GranLab", threaded=False, verbose=False,
                extra_patterns=[(r"/status", JSONHandler, {**access, "read": self.status}),
                                (r"/scene", JSONHandler, {**access, "read": self.scene.state}),
                                (r"/lesson", LessonHandler, access),
                                (r"/viewer-scene", ViewerSceneHandler, access),
                                (r"/viewer-stream", StreamSocket, {**access, "stream": self.stream})],
                check_unused_sessions_milliseconds=1000, unused_session_lifetime_milliseconds=UNUSED_SESSION_MS,
                # gzip for a browser that accepts it: a phone on the classroom's Wi-Fi fetches
                # bokeh's and panel's scripts in 0.8 MB rather than 3.0 MB
                compress_response=True)
        self.server._tornado.granlab_gate = self.gate
        self.server._tornado.granlab_prebuild = self._prebuild
        self._stalled = tornado.ioloop.PeriodicCallback(self._drop_stalled, STALLED_CHECK_MS)

    def _drop_stalled(self) -> None:
        """Drop the pages that stopped reading their websockets (:func:`granlab.app.lab.gate.drop_stalled`)."""
        drop_stalled([client._socket for client in self.server._tornado._clients], self.gate)
        drop_stalled(self.stream.sockets, self.gate)

    def _start_engine(self, data_dir, preset: str, history_mib: float, pause_without_pages: float, changes: dict,
                      kernel_sets) -> None:
        first, later = kernel_sets
        try:
            compile_sets(first, on_change=self.starting.update, cancel=self._stop)
            with announced():  # what the preset uses beyond the sets, if anything
                engine = LabEngine(data_dir, preset, wait_for_tab=True, history_mib=history_mib,
                                   pause_without_pages=pause_without_pages, **changes)
        except Exception as error:  # noqa: BLE001 (shown on every page and in the terminal)
            if self._stop.is_set():  # the lab is stopping: its compile was cancelled
                return
            self.starting.update(state="failed", error=f"{type(error).__name__}: {error}")
            print(f"granlab serve: error: the engine did not start: {self.starting['error']}", file=sys.stderr,
                  flush=True)
            return
        engine.scene_fps = self.scene.fps
        engine.start()
        self.engine = engine
        self._ready.set()
        with contextlib.suppress(Exception):  # a choice not compiled here compiles when chosen
            compile_sets(later, workers=1, nice=10, load=False, background=True, cancel=self._stop)

    def wait_ready(self, timeout: float | None = None) -> bool:
        """Whether the engine runs, waiting up to ``timeout`` seconds for it."""
        return self._ready.wait(timeout)

    def status(self) -> dict:
        if self.engine is None:
            return {"state": self.starting["state"], "starting": dict(self.starting), "tabs": 0}
        status = self.engine.status()
        status["threads"] = threading.active_count()
        status["scene_frames"] = self.scene.frames_pushed
        status["stream_messages"] = self.stream.messages
        status["stream_viewers"] = len(self.stream.sockets)
        status["pages"] = self.gate.state()
        status["memory_releases"] = self.releases
        status["memory_release_pending"] = self._release_pending
        status["memory"] = {**status.get("memory", {}), "resident_mib": _resident_mib(),
                            "pages_mib": sum(page.plot_bytes() for page in list(self.pages)) / 2**20}
        return status

    def _session(self):
        # panel points the stylesheets of a document's models at this server only once it renders the
        # document as a page; a browser slower than the 1 s unused-session lifetime to open its websocket
        # finds that session discarded and gets a new document, never rendered, whose every stylesheet
        # would come from cdn.holoviz.org (LOCAL_DIST is relative to "/", where the dashboard is served)
        pn.state.curdoc.template_variables["dist_url"] = LOCAL_DIST
        pn.state.curdoc.template = PAGE_TEMPLATE
        # the role of the request this session is made for, checked again here (bokeh checked it before):
        # never what the session token's payload says, which is the page's and was made by a client
        request = connection_request(pn.state.curdoc.session_context)
        role = self.access.role(request)
        if role is None:
            LOG.warning("refused a session: its connection carries no valid token")
            return pn.pane.HTML(self.access.refusal_page(request))
        if self.engine is None:
            return starting_page(self)
        self.engine.tabs += 1
        self.engine.submit("tab_opened")
        pn.state.on_session_destroyed(self._closed)
        if role == "viewer":
            self.gate.opened(pn.state.curdoc.session_context)
            pn.state.on_session_destroyed(self.gate.closed)
        page = getattr(request, "granlab_page", None)  # made beside the loop as the page's GET had its turn
        request.granlab_page = None
        if page is None or page.viewer != (role == "viewer"):  # a session made as its websocket opened
            page = self._dashboard(pn.state.headers.get("Host") if pn.state.headers else None, role,
                                   pn.state.session_args)
        self.pages.add(page)
        return page.view()

    def _prebuild(self, request, role: str | None) -> Dashboard | None:
        """The page of a GET that the gate let through, made in the gate's thread (None before the engine
        runs, or for a request without a role: the session says why)."""
        if self.engine is None or role is None:
            return None
        return self._dashboard(request.headers.get("Host"), role, request.query_arguments)

    def _dashboard(self, host_header: str | None, role: str, arguments: dict) -> Dashboard:
        """The page of ``role`` asked for as ``host_header`` with the query ``arguments`` (name -> bytes)."""
        host = (host_header or self.host).rsplit(":", 1)[0]
        scene_url = f"http://{host}:{self.scene.port}/"
        token = self.access.token(role)
        viewer = role == "viewer"
        if viewer:  # the viewers' own stream, drawn in 2D: compact, and encoded once for all of them
            scene_url = "/viewer-scene?token=" + urllib.parse.quote(token)
        elif token:  # viser's client drops the page's query; its websocket address may carry a path
            scene_url += "?websocket=" + urllib.parse.quote(f"ws://{host}:{self.scene.port}/{token}", safe="")
        query = {key: values[0].decode(errors="replace") for key, values in arguments.items()
                 if values and isinstance(values[0], bytes)}
        return Dashboard(self.engine, self.scene, scene_url, viewer=viewer, query=query)

    def _presenter_path(self, path: str) -> bool:
        """Whether a scene client connected with the presenter's token (only its clicks watch a disk)."""
        return self.access.roles.get(path.lstrip("/")) == "presenter"

    def _admit_scene(self, request: Request) -> str | None:
        """None if the scene's websocket may open, else why not: asked for by one of the lab's names on
        the scene's port, from the scene's own page (or by a client that is not a browser: it sends no
        Origin); with tokens, a valid token in the path."""
        host, origin = request.headers.get("Host"), request.headers.get("Origin")
        if not self.access.admits_host(host, self.scene.port):
            return f"this lab's scene does not answer to {host!r}"
        if origin is not None and not self.access.admits_host(urllib.parse.urlsplit(origin).netloc, self.scene.port):
            return f"origin {origin} is not the lab's scene page"
        if self.access.roles and request.path.lstrip("/") not in self.access.roles:
            return "a valid token is needed"
        return None

    def _closed(self, session_context) -> None:
        # the release is asked for before the tab is counted out: "no tab and no release pending" in
        # /status then means the last closed tab's memory has been handed back
        if MALLOC_TRIM is not None and not self._release_pending:
            self._release_pending = True
            wait = max(TRIM_DELAY, self._released + RELEASE_EVERY - time.monotonic())
            self.server.io_loop.call_later(wait, self._release_memory)
        self.engine.tabs = max(0, self.engine.tabs - 1)  # only a dashboard's session counts its tab
        self.engine.submit("tab_closed")

    def _release_memory(self) -> None:
        """Collect the closed sessions' documents (reference cycles) and hand the freed heap back."""
        self._release_pending = False
        gc.collect()
        MALLOC_TRIM(0)
        self._released = time.monotonic()
        self.releases += 1

    def _push_scene(self) -> None:
        last = -1
        while not self._ready.wait(0.2):
            if self._stop.is_set():
                return
        while not self._stop.is_set():
            start = time.perf_counter()
            last, frame = self.engine.frame(seen=last, timeout=0.2)
            if frame is not None:
                self.scene.draw(frame)
                if self.stream.sockets:
                    self.stream.publish(frame, self.scene.color_field, self.scene.arrows)
                self._stop.wait(max(0.0, self.scene_interval - (time.perf_counter() - start)))

    @property
    def url(self) -> str:
        """The presenter's address (the only one without tokens)."""
        return self._address("presenter")

    @property
    def viewer_url(self) -> str | None:
        return self._address("viewer") if self.access.roles else None

    def _address(self, role: str) -> str:
        token = self.access.token(role)
        return f"http://{self.host}:{self.port}/" + (f"?token={token}" if token else "")

    def start(self) -> None:
        self.stream.io_loop = self.server.io_loop
        self._stalled.start()
        self._starter.start()
        self._scene_thread.start()
        self.server.start()

    def run_forever(self) -> int:
        """Serve until SIGTERM or Ctrl-C, which stop the server's loop; then stop the engine, the scene and
        any compile in workers. Returns the exit status: 0, or 130 (Ctrl-C) or 143 (SIGTERM)."""
        self.start()
        loop = self.server.io_loop
        with stopping.stop_on_signals(lambda signum: loop.add_callback_from_signal(loop.stop)):
            try:
                loop.start()
            except KeyboardInterrupt:  # a stop raised where the loop was (it did not stop in time)
                pass
            finally:
                self.stop()
            signum = stopping.asked()
        return 128 + signum if signum else 0

    def stop(self) -> None:
        self._stop.set()
        if self._starter.is_alive():  # a compile in workers: they are killed within half a second
            self._starter.join(STARTER_STOP_SECONDS)
        if self.engine is not None:
            self.engine.stop()
        self.scene.close()
        self.server.stop()


@contextlib.contextmanager
def gated_pages():
    """Within this block a bokeh server made builds its pages as :class:`GatedDocHandler` lets it (bokeh
    reads its page routes, ``per_app_patterns``, as a server is made)."""
    patterns = bokeh_urls.per_app_patterns
    saved = list(patterns)
    patterns[:] = [(route, GatedDocHandler if handler.__name__ == "DocHandler" else handler)
                   for route, handler in saved]
    try:
        yield
    finally:
        patterns[:] = saved


def _resident_mib() -> float | None:
    """This process's resident memory in MiB (None where there is no /proc)."""
    try:
        return int(Path("/proc/self/statm").read_text().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2 ** 20
    except OSError:
        return None


def _free_port(host: str) -> int:
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as sock:
        sock.bind((host, 0))
        return sock.getsockname()[1]


def serve(host: str = "127.0.0.1", port: int = 5006, data_dir: str = "granlab-data", preset: str = "ratchet",
          tokens: bool = False, history_mib: float = HISTORY_MIB, pause_without_pages: float = PAUSE_WITHOUT_PAGES,
          max_viewers: int = MAX_VIEWERS, **changes) -> int:
    """Start the lab and serve until stopped (prints the URL, or with tokens the presenter's and
    the viewers' URLs; any host but this machine's loopback serves with tokens); returns the exit
    status (:meth:`Lab.run_forever`). ``changes``: settings of the first preset (e.g. ``particles=5600``)."""
    check_serve_options(host, port, data_dir, history_mib, pause_without_pages, max_viewers)
    with claimed_data_folder(data_dir):  # one lab a folder: its presenter's address is there
        return _serve(host, port, data_dir, preset, tokens, history_mib, pause_without_pages, max_viewers, changes)


def _serve(host, port, data_dir, preset, tokens, history_mib, pause_without_pages, max_viewers, changes) -> int:
    logging.getLogger("granlab.lab").setLevel(logging.INFO)
    logging.getLogger("granlab.lab").addHandler(logging.StreamHandler(sys.stderr))
    tokens = tokens or host not in LOCAL_HOSTS
    if MALLOPT is not None:
        MALLOPT(M_ARENA_MAX, 2)
        MALLOPT(M_MMAP_THRESHOLD, MMAP_THRESHOLD)
    lab = Lab(host=host, port=port, data_dir=data_dir, preset=preset, tokens=tokens, history_mib=history_mib,
              pause_without_pages=pause_without_pages, max_viewers=max_viewers, **changes)
    quiet_client_logs(lab.access.tokens)
    if lab.viewer_url:
        print(f"viewers' address: {lab.viewer_url} (they see the lab live and change nothing; give it to the "
              "class)", flush=True)
        where = write_presenter_address(Path(data_dir), lab.url)
        print(f"GranLab lab ready; the presenter's address is in {where} (not printed: a projector may show this "
              f"terminal; it controls the simulation and writes files). Open it with: python -m webbrowser "
              f"\"$(cat {where})\"", flush=True)
    else:
        print(f"GranLab lab at {lab.url} (open it in a browser; the preset starts when the page opens)", flush=True)
    if lab.compiles:
        print("the first start compiles the simulation's kernels (the page shows how far; `granlab compile` does it "
              "ahead of time)", flush=True)
    status = lab.run_forever()
    if status:
        print(f"granlab serve: stopped by {stopping.SIGNALS.get(status - 128, 'a signal')}", file=sys.stderr, flush=True)
    return status


PRESENTER_FILE = ".presenter-address"
"""The file of the data folder the presenter's address is written to (readable by its owner only)."""


def write_presenter_address(data_dir: Path, url: str) -> Path:
    """Write the presenter's address into the data folder, readable by this user only; its path."""
    path = data_dir / PRESENTER_FILE
    path.unlink(missing_ok=True)  # made anew, so that no one else's file or link is written through
    handle = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(handle, "w") as out:
        out.write(url + "\n")
    return path


SPAWN_OUTPUT_LINES = 200
"""The last lines a spawned lab printed, kept in its process's ``output``."""


def spawn(data_dir: str | Path, *options: str, timeout: float = 900.0,
          program: tuple[str, ...] = (sys.executable, "-m", "granlab.app.commands"), cwd: str | Path | None = None):
    """Start ``granlab serve --port 0 --data-dir data_dir *options`` in a child process (for
    benchmarks and tests; ``program`` the command that is ``granlab``) and wait until its engine has
    started; returns the process (its ``output``: the last lines it printed, read on in a thread),
    the URL it prints once serving
    (with tokens, the presenter's, from its file) and the viewers' URL (None without tokens)."""
    process = subprocess.Popen([*program, "serve", "--port", "0", "--data-dir", str(data_dir), *options],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=cwd)
    deadline = time.time() + timeout
    viewer = None
    while time.time() < deadline:
        line = process.stdout.readline()
        if not line:
            break
        found = re.search(r"viewers' address: (http://\S+)", line)
        viewer = found.group(1) if found else viewer
        found = re.search(r"GranLab lab at (http://\S+)", line)
        if found or "GranLab lab ready" in line:
            # read on: a pipe nobody reads fills up (64 KiB) and then blocks the server's next
            # write, in whichever of its threads makes it
            process.output = deque(maxlen=SPAWN_OUTPUT_LINES)
            threading.Thread(target=process.output.extend, args=(process.stdout,), daemon=True).start()
            url = found.group(1) if found else (Path(data_dir) / PRESENTER_FILE).read_text().strip()
            wait_started(url, process, deadline)
            return process, url, viewer
    process.kill()
    raise GranLabError(f"the lab server did not start within {timeout:.0f} s (run granlab serve to see why)")


def wait_started(url: str, process, deadline: float) -> None:
    """Wait until the lab at ``url`` (served by ``process``) has started its engine."""
    while time.time() < deadline and process.poll() is None:
        with contextlib.suppress(OSError, ValueError):
            state = read_status(url).get("state")
            if state == "failed":
                break
            if state not in ("compiling", "starting"):
                return
        time.sleep(0.2)
    process.kill()
    raise GranLabError(f"the lab's engine did not start within the time given (last lines: "
                       f"{' | '.join(list(getattr(process, 'output', []))[-3:])})")


def endpoint(url: str, name: str) -> str:
    """The address of route ``name`` of the lab at ``url`` (its token kept)."""
    parts = urllib.parse.urlsplit(url)
    return urllib.parse.urlunsplit(parts._replace(path="/" + name))


def read_status(url: str) -> dict:
    """``GET /status`` of the lab at ``url``."""
    with urllib.request.urlopen(endpoint(url, "status"), timeout=10) as response:
        return json.loads(response.read())
