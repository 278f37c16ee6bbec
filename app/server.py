"""``granlab serve``: the engine thread, the viser scene and the panel server, together.

Binds 127.0.0.1 unless told otherwise (the lab has no authentication). Routes: ``/`` the
dashboard (one per tab), ``/status`` and ``/scene`` JSON for tests and monitoring. The viser
client is served by viser on its own port and embedded in the dashboard; only the dashboard's
address is printed.
"""

from __future__ import annotations

import contextlib
import errno
import io
import json
import logging
import re
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import panel as pn
import tornado.web
import tornado.websocket
from tornado.iostream import StreamClosedError
from bokeh.settings import settings as bokeh_settings

from engine.errors import GranLabError
from engine.io.jsonsafe import jsonable
from engine.io.outputs import check_output

from .dashboard import Dashboard
from .engine_thread import LabEngine
from .scene import SceneView

LOCAL_HOSTS = ("127.0.0.1", "localhost", "::1")


class JSONHandler(tornado.web.RequestHandler):
    """``GET``: the dictionary ``read()`` returns, as JSON (the lab's status, the scene's state)."""

    def initialize(self, read):
        self.read = read

    def get(self):
        self.set_header("Content-Type", "application/json")
        self.set_header("Cache-Control", "no-store")
        self.write(json.dumps(jsonable(self.read())))


class Lab:
    """Everything one ``granlab serve`` runs: engine, scene, scene thread and panel server."""

    def __init__(self, host: str = "127.0.0.1", port: int = 5006, data_dir: str | Path = "granlab-data",
                 preset: str = "ratchet", scene_rate: float = 30.0, **changes):
        self.host = host
        self.engine = LabEngine(data_dir, preset, wait_for_tab=True, **changes)
        with contextlib.redirect_stdout(io.StringIO()):  # viser prints its own address: the page embeds it
            self.scene = SceneView(host=host, port=0)
        self.scene.on_pick(lambda index: self.engine.submit("watch_disk", index=index))
        self.engine.scene_fps = self.scene.fps
        self.scene_interval = 1.0 / scene_rate
        self._stop = threading.Event()
        self._scene_thread = threading.Thread(target=self._push_scene, name="granlab-scene", daemon=True)
        self.port = port or _free_port(host)
        # the page loads bokeh's and panel's files from this server, whatever BOKEH_RESOURCES the
        # environment holds (cdn would point every stylesheet at cdn.holoviz.org)
        bokeh_settings.resources.set_value("server")
        origins = sorted({f"{name}:{self.port}" for name in (host, "127.0.0.1", "localhost")})
        self.server = pn.serve({"/": self._session}, port=self.port, address=host, websocket_origin=origins,
                               show=False, start=False, title="GranLab", threaded=False, verbose=False,
                               extra_patterns=[(r"/status", JSONHandler, {"read": self.status}),
                                               (r"/scene", JSONHandler, {"read": self.scene.state})],
                               check_unused_sessions_milliseconds=1000, unused_session_lifetime_milliseconds=1000)

    def status(self) -> dict:
        status = self.engine.status()
        status["threads"] = threading.active_count()
        status["scene_frames"] = self.scene.frames_pushed
        return status

    def _session(self):
        self.engine.tabs += 1
        self.engine.submit("tab_opened")
        pn.state.on_session_destroyed(self._closed)
        host = (pn.state.headers.get("Host") or self.host).rsplit(":", 1)[0] if pn.state.headers else self.host
        return Dashboard(self.engine, self.scene, f"http://{host}:{self.scene.port}/").view()

    def _closed(self, session_context) -> None:
        self.engine.tabs = max(0, self.engine.tabs - 1)

    def _push_scene(self) -> None:
        last = -1
        while not self._stop.is_set():
            start = time.perf_counter()
            last, frame = self.engine.frame(seen=last, timeout=0.2)
            if frame is not None:
                self.scene.draw(frame)
                self._stop.wait(max(0.0, self.scene_interval - (time.perf_counter() - start)))

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}/"

    def start(self) -> None:
        self.engine.start()
        self._scene_thread.start()
        self.server.start()

    def run_forever(self) -> None:
        self.start()
        try:
            self.server.io_loop.start()
        except KeyboardInterrupt:
            pass
        finally:
            self.stop()

    def stop(self) -> None:
        self._stop.set()
        self.engine.stop()
        self.scene.close()
        self.server.stop()


def _free_port(host: str) -> int:
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as sock:
        sock.bind((host, 0))
        return sock.getsockname()[1]


def check_address(host: str, port: int) -> None:
    """Refuse, before the engine starts, an address the lab could not serve on: a port out of range,
    a host name that does not resolve or is not this machine's, a port another program holds."""
    if not 0 <= port <= 65535:
        raise GranLabError(f"--port {port} is not allowed: a port from 1 to 65535, or 0 for any free port")
    try:
        family = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0][0]
    except (socket.gaierror, UnicodeError) as error:
        raise GranLabError(f"--host {host!r} is not an address of this machine: {error} (127.0.0.1 serves this "
                           "machine only, 0.0.0.0 every network it is on)") from error
    with socket.socket(family) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((host, port))
        except OSError as error:
            taken = error.errno == errno.EADDRINUSE
            raise GranLabError(f"--port {port} is in use by another program: give another port, or --port 0 for "
                               "any free one" if taken else f"--host {host!r} cannot be served: {error.strerror} "
                               "(127.0.0.1 serves this machine only, 0.0.0.0 every network it is on)") from error


class ClosedTabFilter(logging.Filter):
    """Drops the warnings and tracebacks of a message sent to a tab that just closed: a closed
    tab is normal in a classroom, and the terminal the lab runs in should stay readable."""

    def filter(self, record: logging.LogRecord) -> bool:
        closed = (tornado.websocket.WebSocketClosedError, StreamClosedError)
        if record.exc_info and isinstance(record.exc_info[1], closed):
            return False
        message = record.getMessage()
        return "connection was closed" not in message and "WebSocketClosedError" not in message


def serve(host: str = "127.0.0.1", port: int = 5006, data_dir: str = "granlab-data", preset: str = "ratchet",
          **changes) -> None:
    """Start the lab and serve until interrupted (prints the URL). ``changes``: settings of the
    first preset (e.g. ``particles=5600``)."""
    check_address(host, port)
    check_output(data_dir, "--data-dir", folder=True)
    if host not in LOCAL_HOSTS:
        print(f"warning: serving on {host}: the lab has no authentication; anyone who can reach this address "
              "can control the simulation and write files in its data folder", file=sys.stderr)
    for name in ("asyncio", "bokeh.server.views.ws", "panel.io.document"):
        logging.getLogger(name).addFilter(ClosedTabFilter())
    print("starting the engine (the first start compiles the numba kernels: a minute or two)...", flush=True)
    lab = Lab(host=host, port=port, data_dir=data_dir, preset=preset, **changes)
    print(f"GranLab lab at {lab.url} (open it in a browser; the preset starts when the page opens)", flush=True)
    lab.run_forever()


def spawn(data_dir: str | Path, *options: str, timeout: float = 900.0):
    """Start ``granlab serve --port 0 --data-dir data_dir *options`` in a child process (for
    benchmarks and tests); returns the process and the URL it prints once serving."""
    process = subprocess.Popen([sys.executable, "-m", "app.cli", "serve", "--port", "0", "--data-dir", str(data_dir),
                                *options], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    deadline = time.time() + timeout
    while time.time() < deadline:
        line = process.stdout.readline()
        if not line:
            break
        found = re.search(r"GranLab lab at (http://\S+/)", line)
        if found:
            return process, found.group(1)
    process.kill()
    raise GranLabError(f"the lab server did not start within {timeout:.0f} s (run granlab serve to see why)")


def read_status(url: str) -> dict:
    """``GET /status`` of the lab at ``url``."""
    with urllib.request.urlopen(url + "status", timeout=10) as response:
        return json.loads(response.read())
