"""The light clients of ``granlab bench --lab --viewers N``: a presenter's page and N viewers' pages
of a lab served with tokens, opened as a browser opens them but drawing nothing, in a process of
their own (``python -m granlab.app.lab.classroom SPEC.json``; the result is written to SPEC's "out").

A session, as the page's scripts do it: GET the page (it sets the token's cookie and carries
bokeh's session token), bokeh's websocket (``/ws``, subprotocols ``["bokeh", token]``, the
document pulled as bokeh's client pulls it), the scene's address from the iframe in that
document, and the scene's websocket: a viewer's, the viewers' stream of the dashboard's server
(app/lab/stream.py); the presenter's, viser's (its subprotocol, the page's origin) with one camera
report (viser counts a client as connected from its first one; a browser sends it once it draws).
Each page says it drew each refresh as soon as it arrives (app/lab/pace.py), as a page that draws at
once would.

Counted per socket from outside the server: websocket messages and bytes received (neither
server compresses its websocket: these are the bytes on the wire, less the frames' few bytes of
header), and on the scene's socket the frames, a frame being a message of the viewers' stream or
one of viser's that moves the disks (viser sends nothing for an unchanged value). The presenter
changes the load's period through its own bokeh websocket, as its page's input box does, and the
latency runs from that message to the value in ``/status``. Only this module's imports are loaded:
the clients' process stays small.
"""

from __future__ import annotations

import asyncio
import contextlib
import html
import importlib.metadata
import json
import os
import re
import statistics
import sys
import time
import urllib.error
import urllib.parse
import urllib.request
import zlib
from collections import Counter
from pathlib import Path

import msgspec
import zstandard
from websockets.asyncio.client import connect

BOKEH_TOKEN = re.compile(r'"token"\s*:\s*"([^"]+)"')
IFRAME = re.compile(r'<iframe src="([^"]+)"')
OPEN_TIMEOUT = 120.0  # a page of a 5600-disk lab on two busy cores
LOST_AFTER = 30.0


def get_json(url: str) -> dict:
    with urllib.request.urlopen(url, timeout=30) as response:
        return json.loads(response.read())


def endpoint(url: str, name: str) -> str:
    """Route ``name`` of the lab at ``url``, its token kept (server.endpoint, without loading the server)."""
    return urllib.parse.urlunsplit(urllib.parse.urlsplit(url)._replace(path="/" + name))


def cpu_seconds(pid: int) -> float:
    """User and system CPU time of process ``pid`` (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _size(message: str | bytes) -> int:
    """Bytes of a websocket message on the wire (a text message is sent as UTF-8)."""
    return len(message.encode()) if isinstance(message, str) else len(message)


def _page(url: str, timeout: float = OPEN_TIMEOUT) -> tuple[str, str, str]:
    """The page at ``url``: bokeh's session token, the cookie it sets and its origin."""
    with urllib.request.urlopen(url, timeout=timeout) as response:
        text = response.read().decode()
        cookie = "; ".join(c.split(";")[0] for c in response.headers.get_all("Set-Cookie") or [])
    found = BOKEH_TOKEN.search(text)
    if found is None:
        raise RuntimeError(f"no bokeh session token in the page at {url.split('?')[0]}")
    parts = urllib.parse.urlsplit(url)
    return found.group(1), cookie, f"{parts.scheme}://{parts.netloc}"


def _models(document: object, names: dict[str, str]) -> None:
    """Fill ``names`` (model id -> 'Type[first css class]') from a bokeh document or event."""
    if isinstance(document, dict):
        if document.get("type") == "object" and "id" in document:
            classes = (document.get("attributes") or {}).get("css_classes") or []
            kind = document.get("name", "?").rsplit(".", 1)[-1]
            names[document["id"]] = f"{kind}[{classes[0]}]" if classes and isinstance(classes[0], str) else kind
        for value in document.values():
            _models(value, names)
    elif isinstance(document, list):
        for value in document:
            _models(value, names)


def _find_model(document: object, css_class: str) -> str | None:
    """The id of the first model of ``document`` with ``css_class``."""
    if isinstance(document, dict):
        if document.get("type") == "object" and css_class in ((document.get("attributes") or {}).get("css_classes")
                                                              or []):
            return document["id"]
        document = list(document.values())
    for value in document if isinstance(document, list) else ():
        found = _find_model(value, css_class)
        if found:
            return found
    return None


class Socket:
    """What one websocket received: messages and bytes (and frames, for the scene), and with
    ``anatomy`` where the bytes went (a Counter of bytes by what carried them)."""

    def __init__(self, anatomy: bool):
        self.messages = self.bytes = self.frames = 0
        self.anatomy: Counter | None = Counter() if anatomy else None

    def snapshot(self) -> dict:
        return {"messages": self.messages, "bytes": self.bytes, "frames": self.frames,
                "anatomy": Counter(self.anatomy) if self.anatomy is not None else None}


class Session:
    """One page's two websockets; ``anatomy``: sort the bytes received by what carried them."""

    def __init__(self, url: str, anatomy: bool = False, page_timeout: float = OPEN_TIMEOUT):
        self.url = url
        self.page_timeout = page_timeout
        self.bokeh = Socket(anatomy)
        self.scene = Socket(anatomy)
        self.names: dict[str, str] = {}  # bokeh model id -> its type and first css class
        self.document: dict = {}
        self.tasks: list[asyncio.Task] = []
        self.sockets = []
        self._pending: list = []  # the websocket messages of the bokeh message being received
        self._header: dict = {}  # and its header
        self._scene_decoder = zstandard.ZstdDecompressor()
        self._acks: set[asyncio.Task] = set()
        self._sending = asyncio.Lock()  # a bokeh message is three websocket messages: never two interleaved

    async def open(self, reads: bool = True) -> None:
        """Open the page and its websockets; one that does not ``reads`` pulls the document and reads nothing
        after (its websockets queue one message, then leave the rest to the network)."""
        token, cookie, origin = await asyncio.to_thread(_page, self.url, self.page_timeout)
        address = urllib.parse.urlsplit(self.url)
        queue = {} if reads else {"max_queue": 1}
        bokeh = await connect(f"ws://{address.netloc}/ws", subprotocols=["bokeh", token], origin=origin,
                              additional_headers={"Cookie": cookie}, max_size=None, compression=None,
                              open_timeout=OPEN_TIMEOUT, **queue)
        self.sockets.append(bokeh)
        # bokeh's client pulls the document once the server has acknowledged the connection: the
        # server reads nothing before (its receiver is made when it sends the ACK)
        while self._bokeh_received(await asyncio.wait_for(bokeh.recv(), OPEN_TIMEOUT)) != "ACK":
            pass
        await bokeh.send(json.dumps({"msgid": "pull", "msgtype": "PULL-DOC-REQ"}))
        await bokeh.send("{}")
        await bokeh.send("{}")
        while not self.document:  # the server's patches may come before the reply; they count too
            self._bokeh_received(await asyncio.wait_for(bokeh.recv(), OPEN_TIMEOUT))
        if reads:
            self.tasks.append(asyncio.create_task(self._read(bokeh, self._bokeh_received)))
        found = IFRAME.search(html.unescape(json.dumps(self.document)))
        if found is None:
            raise RuntimeError("no scene iframe in the dashboard's document")
        page = urllib.parse.urlsplit(html.unescape(found.group(1)))
        if page.path == "/viewer-scene":  # a viewer's scene: the viewers' stream, from the dashboard's server
            scene = await connect(f"ws://{address.netloc}/viewer-stream?{page.query}", origin=origin,
                                  additional_headers={"Cookie": cookie}, max_size=None, compression=None,
                                  open_timeout=OPEN_TIMEOUT, **queue)
            self.sockets.append(scene)
            if reads:
                self.tasks.append(asyncio.create_task(self._read(scene, self._stream_received)))
            return
        given = urllib.parse.parse_qs(page.query).get("websocket")
        scene = await connect(given[0] if given else f"ws://{page.netloc}/", origin=f"http://{page.netloc}",
                              subprotocols=[f"viser-v{importlib.metadata.version('viser')}"], max_size=None,
                              compression=None, open_timeout=OPEN_TIMEOUT)
        self.sockets.append(scene)
        # a browser's client reports its camera once it draws: from then on viser counts it as a client
        await scene.send(msgspec.msgpack.encode({
            "type": "ViewerCameraMessage", "wxyz": [1.0, 0.0, 0.0, 0.0], "position": [0.0, 0.0, 100.0],
            "fov": 0.5, "near": 0.01, "far": 1000.0, "image_height": 900, "image_width": 900,
            "look_at": [0.0, 0.0, 0.0], "up_direction": [0.0, 1.0, 0.0]}))
        self.tasks.append(asyncio.create_task(self._read(scene, self._scene_received)))

    async def _read(self, socket, received) -> None:
        async for message in socket:
            received(message)

    def _bokeh_received(self, message: str | bytes) -> str | None:
        """Count a websocket message of bokeh's protocol: a message is a header, metadata and content
        (text), then a buffer header (text) and payload (binary) per buffer. The type of the bokeh
        message it completes, if it does."""
        self.bokeh.messages += 1
        self.bokeh.bytes += _size(message)
        self._pending.append(message)
        if len(self._pending) == 1:
            self._header = json.loads(message)
        if len(self._pending) < 3 + 2 * self._header.get("num_buffers", 0):
            return None
        parts, self._pending = self._pending, []
        kind = self._header["msgtype"]
        if kind == "PULL-DOC-REPLY":
            self.document = json.loads(parts[2])["doc"]
            _models(self.document, self.names)
        if kind == "PATCH-DOC" and '"sent"' in parts[2]:  # a page that draws each refresh at once says so
            for event in json.loads(parts[2]).get("events", []):
                if event.get("attr") == "sent":
                    ack = asyncio.create_task(self.command(event["model"]["id"], "drawn", event["new"]))
                    self._acks.add(ack)
                    ack.add_done_callback(self._acks.discard)
        anatomy = self.bokeh.anatomy
        if anatomy is None:
            return kind
        if kind != "PATCH-DOC":
            anatomy[kind] += sum(map(_size, parts))
            return kind
        anatomy["PATCH-DOC header and metadata"] += _size(parts[0]) + _size(parts[1])
        buffers = {json.loads(parts[k]).get("id"): _size(parts[k]) + _size(parts[k + 1])
                   for k in range(3, len(parts), 2)}
        events = json.loads(parts[2]).get("events", [])
        texts = [json.dumps(event) for event in events]
        share = _size(parts[2]) / max(1, sum(map(len, texts)))  # the content's bytes, shared by the events
        for event, text in zip(events, texts):
            _models(event, self.names)
            model = self.names.get((event.get("model") or {}).get("id"), "?")
            key = f"{event.get('kind')} {model}" + (f".{event['attr']}" if event.get("attr") else "")
            anatomy[key] += share * len(text) + sum(size for ident, size in buffers.items() if ident and ident in text)
        return kind

    def _scene_received(self, message: bytes) -> None:
        """Count a message of viser's wire format: 8 bytes the msgpack's size, 8 its zstd size, the
        compressed msgpack of the messages (arrays as placeholders), then the arrays, raw."""
        self.scene.messages += 1
        self.scene.bytes += _size(message)
        packed = int.from_bytes(message[8:16], "little")
        inner = msgspec.msgpack.decode(self._scene_decoder.decompress(
            message[16:16 + packed], max_output_size=int.from_bytes(message[:8], "little")))
        messages = inner["messages"]
        if any(m["type"] == "SceneNodeUpdateMessage" and m.get("name") == "/granlab/disks"
               and "batched_positions" in (m.get("updates") or {}) for m in messages):
            self.scene.frames += 1
        anatomy = self.scene.anatomy
        if anatomy is None:
            return
        sizes = inner["binaryBufferLengths"]
        carried = 0
        for m in messages:
            fields = m.get("updates") if m["type"] == "SceneNodeUpdateMessage" else m.get("props", m)
            if not isinstance(fields, dict):
                continue
            for field, value in fields.items():
                if isinstance(value, dict) and "__binary_index" in value:
                    size = sizes[value["__binary_index"]]
                    carried += size
                    anatomy[f"{m['type']} {m.get('name') or ''}.{field}".replace(" .", " ")] += size
        anatomy["sizes, zstd msgpack of the messages, padding"] += len(message) - carried

    def _stream_received(self, message: bytes) -> None:
        """Count a message of the viewers' stream (app/lab/stream.py): each one is a frame, a key frame
        (every array whole) or a frame's change."""
        self.scene.messages += 1
        self.scene.frames += 1
        self.scene.bytes += _size(message)
        if self.scene.anatomy is not None:
            data = zlib.decompress(message)
            header = json.loads(data[4:4 + int.from_bytes(data[:4], "little")])
            self.scene.anatomy["viewers' stream, " + ("key frames" if header["key"] else "changes")] += _size(message)

    async def command(self, model: str, attr: str, value) -> None:
        """Send a change of ``model``'s ``attr`` as the page does when a widget changes."""
        bokeh = self.sockets[0]
        async with self._sending:
            await bokeh.send(json.dumps({"msgid": f"c{time.monotonic_ns()}", "msgtype": "PATCH-DOC"}))
            await bokeh.send("{}")
            await bokeh.send(json.dumps({"events": [{"kind": "ModelChanged", "model": {"id": model}, "attr": attr,
                                                     "new": value}]}))

    def snapshot(self) -> dict:
        return {"bokeh": self.bokeh.snapshot(), "scene": self.scene.snapshot()}

    def failed(self) -> BaseException | None:
        return next((task.exception() for task in self.tasks if task.done() and not task.cancelled()
                     and task.exception() is not None), None)

    async def close(self) -> None:
        for socket in self.sockets:
            await socket.close()
        for task in self.tasks:
            task.cancel()
        await asyncio.gather(*self.tasks, return_exceptions=True)


async def _latencies(presenter: Session, status_url: str, count: int, spacing: float) -> dict:
    """Changes of the load's period sent by the presenter's page (a control that acts at once in
    both stages): milliseconds from the message to the value in ``/status``, and ``command_ms``
    (the server receiving it to the engine taking it). Sent one after another while every page is
    open, from the start of the count (on a loaded server they go on past its end). A change not
    in ``/status`` within LOST_AFTER seconds is counted as lost: an amplitude typed as the
    dashboard wrote the value in effect into its widget was seen lost so on a loaded server."""
    model = _find_model(presenter.document, "period-input")
    if model is None:
        raise RuntimeError("no period input in the presenter's document")
    end_to_end, server, lost = [], [], 0
    for k in range(count):
        await asyncio.sleep(spacing)
        value = round(10.0 + 0.1 * (k + 1), 1)
        start = time.perf_counter()
        await presenter.command(model, "value", value)
        while (status := await asyncio.to_thread(get_json, status_url))["settings"]["period"] != value:
            if time.perf_counter() - start > LOST_AFTER:
                lost += 1
                break
            await asyncio.sleep(0.01)
        else:
            end_to_end.append(1000.0 * (time.perf_counter() - start))
            server.append(status["command_ms"])
    return {"latency_ms": end_to_end, "command_ms": server, "commands_sent": count, "commands_lost": lost}


def _difference(after: dict, before: dict, seconds: float) -> dict:
    """Per second between two snapshots of a socket."""
    out = {key: (after[key] - before[key]) / seconds for key in ("messages", "bytes", "frames")}
    if after["anatomy"] is not None:
        out["anatomy"] = {key: value / seconds for key, value in (after["anatomy"] - before["anatomy"]).most_common()}
    return out


async def classroom(spec: dict) -> dict:
    """Open the presenter's and ``spec["viewers"]`` viewers' sessions, let them settle for
    ``spec["warmup"]`` s, count ``spec["seconds"]`` s while the presenter sends its commands."""
    status_url = endpoint(spec["presenter"], "status")
    presenter = Session(spec["presenter"])
    opening = time.perf_counter()
    await presenter.open()
    viewers = []
    for k in range(spec["viewers"]):
        viewers.append(Session(spec["viewer"], anatomy=k == 0))
        await viewers[-1].open()
    opened = time.perf_counter() - opening
    sessions = [presenter, *viewers]
    try:
        await asyncio.sleep(spec["warmup"])
        count = min(10, max(1, int(spec["seconds"])))
        first, before = await asyncio.to_thread(get_json, status_url), [s.snapshot() for s in sessions]
        start, cpu, server_cpu = time.perf_counter(), time.process_time(), cpu_seconds(spec["server_pid"])
        commands = asyncio.create_task(_latencies(presenter, status_url, count, spec["seconds"] / (count + 1)))
        await asyncio.sleep(spec["seconds"])
        after, last = [s.snapshot() for s in sessions], await asyncio.to_thread(get_json, status_url)
        elapsed = time.perf_counter() - start
        cpu, server_cpu = time.process_time() - cpu, cpu_seconds(spec["server_pid"]) - server_cpu
        latencies = await commands
        failed = next((error for error in map(Session.failed, sessions) if error is not None), None)
        if failed is not None:
            raise RuntimeError(f"a session's websocket failed: {failed!r}")
    finally:
        for session in sessions:
            await session.close()
    per_session = [{socket: _difference(a[socket], b[socket], elapsed) for socket in ("bokeh", "scene")}
                   for a, b in zip(after, before)]
    return {"seconds": elapsed, "sessions_opened_s": opened, "time_from": first["time"], "time_to": last["time"],
            "stage_from": first["stage"], "stage": last["stage"], "tabs": last["tabs"], "threads": last["threads"],
            "particles": last["particles"],
            "particle_steps_per_s": (last["step"] - first["step"]) * last["particles"] / elapsed,
            "status_particle_steps_per_s": last["particle_steps_per_s"],
            "scene_pushed_fps": (last["scene_frames"] - first["scene_frames"]) / elapsed,
            "server_cpu_cores": server_cpu / elapsed, "client_cpu_cores": cpu / elapsed,
            "presenter": per_session[0], "viewers": per_session[1:], **latencies,
            "latency_ms_median": statistics.median(latencies["latency_ms"]) if latencies["latency_ms"] else None,
            "command_ms_median": statistics.median(latencies["command_ms"]) if latencies["command_ms"] else None}


STORM_PAGE_TIMEOUT = 25.0
"""A client of the storm that waits longer for its page gives up (and closes its connection), as a phone would."""


async def _storm_client(viewer: str, deadline: float, rng, counts: dict, reads: bool) -> None:
    """A viewer that joins (the page, its two websockets), stays 1 to 5 s reading them, leaves and joins
    again until ``deadline``; one that does not ``reads`` joins once and never reads its websockets (its
    queue of one message full, it leaves the server's data in the network and then in the server)."""
    while time.monotonic() < deadline:
        session = Session(viewer, page_timeout=STORM_PAGE_TIMEOUT)
        began = time.monotonic()
        try:
            await asyncio.wait_for(session.open(reads), STORM_PAGE_TIMEOUT)
            counts["pages"] += 1
            counts["page_seconds"].append(time.monotonic() - began)
            await asyncio.sleep(rng.uniform(1.0, 5.0) if reads else max(0.0, deadline - time.monotonic()))
        except urllib.error.HTTPError as error:
            counts["full" if error.code == 503 else "failed"] += 1
            await asyncio.sleep(rng.uniform(0.5, 2.0))
        except (OSError, RuntimeError, asyncio.TimeoutError, ValueError) as error:  # the lab too busy to answer
            counts["failed"] += 1
            counts["errors"][type(error).__name__] += 1
        finally:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(session.close(), 5.0)


async def storm(spec: dict) -> dict:
    """``spec["clients"]`` viewers joining and leaving at once for ``spec["seconds"]`` s and
    ``spec["stuck"]`` that join once and never read (:func:`_storm_client`); what they got."""
    import concurrent.futures
    import random

    asyncio.get_running_loop().set_default_executor(concurrent.futures.ThreadPoolExecutor(spec["clients"] + 8))
    counts = {"pages": 0, "full": 0, "failed": 0, "page_seconds": [], "errors": Counter()}
    deadline = time.monotonic() + spec["seconds"]
    clients = [_storm_client(spec["viewer"], deadline, random.Random(k), counts, True) for k in range(spec["clients"])]
    clients += [_storm_client(spec["viewer"], deadline, random.Random(-k), counts, False) for k in range(spec["stuck"])]
    await asyncio.gather(*clients)
    seconds = counts.pop("page_seconds")
    return {**counts, "errors": dict(counts["errors"]),
            "page_seconds": {"median": statistics.median(seconds), "max": max(seconds)} if seconds else None}


async def soak(spec: dict) -> dict:
    """The presenter's and ``spec["viewers"]`` viewers' sessions open, reading, for ``spec["seconds"]`` s; what
    they received."""
    sessions = [Session(spec["presenter"]), *(Session(spec["viewer"]) for _ in range(spec["viewers"]))]
    for session in sessions:
        await session.open()
    Path(spec["opened"]).touch()
    try:
        deadline = time.monotonic() + spec["seconds"]
        while time.monotonic() < deadline:
            await asyncio.sleep(min(5.0, max(0.0, deadline - time.monotonic())))
            failed = next((error for error in map(Session.failed, sessions) if error is not None), None)
            if failed is not None:
                raise RuntimeError(f"a session's websocket failed: {failed!r}")
        received = [session.snapshot() for session in sessions]
    finally:
        for session in sessions:
            await session.close()
    return {"bokeh_mb": sum(r["bokeh"]["bytes"] for r in received) / 1e6,
            "scene_frames": sum(r["scene"]["frames"] for r in received)}


def main(argv: list[str]) -> int:
    spec = json.loads(Path(argv[0]).read_text())
    try:
        result = asyncio.run(storm(spec) if spec.get("storm") else soak(spec) if spec.get("soak") else classroom(spec))
    except Exception as error:  # one line for the bench to show: the clients' process has no terminal
        print(f"{type(error).__name__}: {error}", file=sys.stderr)
        return 1
    Path(spec["out"]).write_text(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
