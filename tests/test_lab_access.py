"""Who may open what in a lab served with tokens, probed as a hostile client would, without a browser:
forged session tokens, a viewer's cookie behind a presenter's page, foreign Host and Origin headers, a
removed lock file, malformed messages. What a viewer could do once in is in test_browser_sessions.py."""

import asyncio
import concurrent.futures
import html
import http.client
import json
import logging
import re
import subprocess
import sys
import threading
import time
import types
import urllib.error
import urllib.parse
import urllib.request

import pytest
import tornado.httputil
from bokeh.protocol.exceptions import ProtocolError
from bokeh.util.token import generate_jwt_token, generate_session_id
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed, InvalidStatus

from granlab.app.lab.access import COOKIE, Access, served_names
from granlab.app.lab.logs import quiet_client_logs
from granlab.app.lab.server import UNUSED_SESSION_MS, endpoint, spawn

BOKEH_TOKEN = '"token":"'


@pytest.fixture(scope="module")
def token_lab(tmp_path_factory):
    data = tmp_path_factory.mktemp("access-lab-data")
    process, url, viewer = spawn(data, "--tokens", "--preset", "ratchet16")
    lab = {"url": url, "viewer": viewer, "process": process, "data": data,
           "netloc": urllib.parse.urlsplit(url).netloc,
           "presenter_token": urllib.parse.parse_qs(urllib.parse.urlsplit(url).query)["token"][0],
           "viewer_token": urllib.parse.parse_qs(urllib.parse.urlsplit(viewer).query)["token"][0]}
    yield lab
    process.terminate()
    process.wait(timeout=30)


def request(uri: str, host: str = "127.0.0.1:5006", cookie: str | None = None):
    headers = tornado.httputil.HTTPHeaders({"Host": host})
    if cookie is not None:
        headers["Cookie"] = f"{COOKIE}={cookie}"
    return tornado.httputil.HTTPServerRequest(start_line=tornado.httputil.RequestStartLine("GET", uri, "HTTP/1.1"),
                                              headers=headers)


def test_a_request_s_role_is_that_of_its_own_token_by_one_of_the_lab_s_names():
    access = Access("127.0.0.1", 5006, tokens=True)
    presenter, viewer = access.token("presenter"), access.token("viewer")
    assert access.role(request(f"/?token={presenter}")) == "presenter"
    assert access.role(request(f"/?token={viewer}")) == "viewer"
    assert access.role(request("/", cookie=viewer)) == "viewer"
    assert access.role(request(f"/?token={viewer}", cookie=presenter)) == "viewer"  # the address first
    assert access.role(request("/?token=junk", cookie=viewer)) == "viewer"
    for refused in (request("/"), request("/?token=junk"), request("/", cookie="junk"), request("/?token="),
                    request(f"/?token={presenter}", host="evil.example:5006"),
                    request(f"/?token={presenter}", host="127.0.0.1:5007"),
                    request(f"/?token={presenter}", host="127.0.0.1:99999"), request(f"/?token={presenter}", host="")):
        assert access.role(refused) is None, refused
    # without tokens every page of the lab's names is the presenter's, and no other
    local = Access("127.0.0.1", 5006, tokens=False)
    assert local.role(request("/", host="localhost:5006")) == "presenter"
    assert local.role(request("/", host="evil.example:5006")) is None
    assert local.websocket_origins() == ["127.0.0.1:5006", "localhost:5006"]


def test_a_lab_on_every_network_answers_to_this_machine_s_names_and_addresses_only():
    names = served_names("0.0.0.0")
    assert {"127.0.0.1", "localhost", "0.0.0.0"} <= names and "evil.example" not in names
    import psutil
    import socket
    addresses = {a.address for found in psutil.net_if_addrs().values() for a in found if a.family == socket.AF_INET}
    assert addresses <= names
    assert served_names("127.0.0.1") == frozenset({"127.0.0.1", "localhost", "[::1]"})


def bokeh_page(url: str, cookie: str | None = None) -> str:
    """The session token of the dashboard's page at ``url``."""
    headers = {"Cookie": f"{COOKIE}={cookie}"} if cookie else {}
    with urllib.request.urlopen(urllib.request.Request(url, headers=headers), timeout=120) as response:
        text = response.read().decode()
    start = text.index(BOKEH_TOKEN) + len(BOKEH_TOKEN)
    return text[start:text.index('"', start)]


async def _document(netloc: str, token: str, cookie: str) -> str:
    """The dashboard's document (JSON) as its websocket sends it, or "closed" or "refused STATUS"."""
    try:
        socket = await connect(f"ws://{netloc}/ws", subprotocols=["bokeh", token], origin=f"http://{netloc}",
                               additional_headers={"Cookie": f"{COOKIE}={cookie}"}, max_size=None, open_timeout=60)
    except InvalidStatus as error:
        return f"refused {error.response.status_code}"

    async def message() -> tuple[dict, str]:
        header = json.loads(await asyncio.wait_for(socket.recv(), 60))
        await socket.recv()
        content = await socket.recv()
        for _ in range(2 * header.get("num_buffers", 0)):
            await socket.recv()
        return header, content

    try:
        header, _ = await message()
        assert header["msgtype"] == "ACK"
        await socket.send(json.dumps({"msgid": "pull", "msgtype": "PULL-DOC-REQ"}))
        await socket.send("{}")
        await socket.send("{}")
        while (found := await message())[0]["msgtype"] != "PULL-DOC-REPLY":
            pass
        return found[1]
    except ConnectionClosed:
        return "closed"
    finally:
        await socket.close()


def run_async(coroutine):
    """``asyncio.run(coroutine)`` in a thread of its own: a browser test before this one in the same process
    may have left its event loop running in this thread."""
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        return pool.submit(asyncio.run, coroutine).result()


def pulled(lab, token: str, cookie: str) -> str:
    """The page the dashboard's websocket builds for a session ``token``, asked with a ``cookie``:
    "presenter", "viewer", "neither", "closed" or "refused STATUS"."""
    content = run_async(_document(lab["netloc"], token, cookie))
    if content == "closed" or content.startswith("refused"):
        return content
    return "viewer" if "viewer-badge" in content else "presenter" if "save-button" in content else "neither"


def forged(payload: dict) -> str:
    """A session token a client made itself, with its own id and ``payload`` (unsigned)."""
    return generate_jwt_token(generate_session_id(signed=False), signed=False, extra_payload=payload)


def test_a_viewer_s_cookie_never_opens_the_presenter_s_page(token_lab):
    viewer = token_lab["viewer_token"]
    for payload in ({"arguments": {}, "cookies": {}, "headers": {}},
                    {"arguments": {}, "cookies": {COOKIE: "junk"}, "headers": {}},
                    {"arguments": {"token": [viewer]}, "cookies": {}, "headers": {}},
                    {"arguments": {"token": []}, "cookies": {}, "headers": {}},
                    {"arguments": {"token": [123]}, "cookies": {}, "headers": {}}):
        assert pulled(token_lab, forged(payload), viewer) == "closed", payload  # bokeh: invalid signature
    assert pulled(token_lab, forged({}), "junk") == "refused 403"
    # a page's own (signed) session, discarded unused and made again as its websocket opens: its role is
    # the websocket's cookie's, never the page's address's
    unused_past = UNUSED_SESSION_MS / 1000 + 1.5  # the unused sessions' lifetime, looked for every second
    presenter_page = bokeh_page(token_lab["url"])
    time.sleep(unused_past)
    assert pulled(token_lab, presenter_page, viewer) == "viewer"
    presenter_page = bokeh_page(token_lab["url"])
    time.sleep(unused_past)
    assert pulled(token_lab, presenter_page, token_lab["presenter_token"]) == "presenter"
    assert pulled(token_lab, bokeh_page(token_lab["viewer"]), viewer) == "viewer"
    # the presenter's page opened again in a browser whose cookie a viewer's page set is the presenter's
    assert pulled(token_lab, bokeh_page(token_lab["url"], cookie=viewer), viewer) == "presenter"
    deadline = time.time() + 10  # the lab's output is read on in a thread
    while "".join(token_lab["process"].output).count("Invalid token signature") < 5 and time.time() < deadline:
        time.sleep(0.1)
    output = "".join(token_lab["process"].output)
    assert output.count("Invalid token signature") == 5 and "Traceback" not in output


class _NoRedirect(urllib.request.HTTPRedirectHandler):
    def redirect_request(self, *args, **kwargs):
        return None


def status_of(url: str, headers: dict | None = None, body: list | None = None) -> int:
    """The status of a GET of ``url`` itself (a redirect is its 3xx, not followed); its text added
    to ``body``."""
    try:
        with urllib.request.build_opener(_NoRedirect).open(urllib.request.Request(url, headers=headers or {}),
                                                           timeout=30) as response:
            status, text = response.status, response.read()
    except urllib.error.HTTPError as error:
        status, text = error.code, error.read()
    if body is not None:
        body.append(text.decode(errors="replace"))
    return status


def test_with_tokens_nothing_answers_without_a_valid_one(token_lab):
    bare = token_lab["url"].split("?")[0]
    assert token_lab["viewer"].split("?")[0] == bare and token_lab["viewer"] != token_lab["url"]
    for url in (bare, bare + "?token=wrong", bare + "status", bare + "scene", bare + "status?token=wrong",
                bare + "lesson?preset=block", bare + "viewer-scene", bare + "viewer-scene?token=wrong"):
        assert status_of(url) == 403, url
    for url in (bare, bare + "?token=wrong"):
        body = []
        assert status_of(url, body=body) == 403, url  # the page itself, no redirect to it
        assert "open the full address the presenter gave" in body[0], url
    assert status_of(endpoint(token_lab["viewer"], "status")) == 200
    # the presenter's address is not printed (a projector may show the terminal) but kept for its owner
    kept = token_lab["data"] / ".presenter-address"
    assert kept.stat().st_mode & 0o777 == 0o600 and kept.read_text().strip() == token_lab["url"]
    # a second lab on the same folder would have written its own presenter's address over this one
    second = subprocess.run([sys.executable, "-m", "granlab.app.commands", "serve", "--port", "0", "--tokens",
                             "--data-dir", str(token_lab["data"])], capture_output=True, text=True, timeout=120)
    assert second.returncode == 2 and second.stderr.count("\n") == 1, second.stderr
    assert second.stderr.startswith(f"granlab serve: error: --data-dir {str(token_lab['data'])!r} is in use by "
                                    f"another lab (process {token_lab['process'].pid}): give each lab a folder")
    assert kept.read_text().strip() == token_lab["url"]


def upgrade(netloc: str, path: str, headers: dict) -> int:
    """The HTTP status a websocket upgrade of ``path`` at ``netloc`` with ``headers`` is answered."""
    connection = http.client.HTTPConnection(netloc, timeout=30)
    connection.request("GET", path, headers={"Upgrade": "websocket", "Connection": "Upgrade",
                                             "Sec-WebSocket-Key": "dGhlIHNhbXBsZSBub25jZQ==",
                                             "Sec-WebSocket-Version": "13", **headers})
    status = connection.getresponse().status
    connection.close()
    return status


def scene_port(lab) -> int:
    """The port of the presenter's 3D scene, from the iframe of the presenter's page."""
    document = run_async(_document(lab["netloc"], bokeh_page(lab["url"]), lab["presenter_token"]))
    return int(re.search(r"ws://127\.0\.0\.1:(\d+)/", html.unescape(urllib.parse.unquote(document))).group(1))


def test_no_request_widens_the_origins_and_every_foreign_name_is_refused_403(token_lab):
    netloc, viewer, presenter = token_lab["netloc"], token_lab["viewer_token"], token_lab["presenter_token"]
    # a viewer's page asked for by another site's name (what widened the origins for good before)
    assert status_of(token_lab["viewer"], {"Host": "evil.example"}) == 403
    assert status_of(endpoint(token_lab["viewer"], "status"), {"Host": "evil.example"}) == 403
    cookie = {"Cookie": f"{COOKIE}={viewer}"}
    assert upgrade(netloc, "/ws", {**cookie, "Origin": "http://evil.example"}) == 403
    assert upgrade(netloc, "/ws", {**cookie, "Origin": "http://evil.example", "Host": "evil.example"}) == 403
    assert upgrade(netloc, "/viewer-stream", {**cookie, "Origin": "http://evil.example",
                                              "Host": "evil.example"}) == 403
    assert upgrade(netloc, "/viewer-stream", {**cookie, "Origin": "http://evil.example"}) == 403
    assert upgrade(netloc, "/viewer-stream", {**cookie, "Origin": f"http://{netloc}"}) == 101
    # the presenter's 3D scene: a foreign Host and Origin together were answered 500
    port = scene_port(token_lab)
    scene = f"127.0.0.1:{port}"
    subprotocol = {"Sec-WebSocket-Protocol": f"viser-v{__import__('viser').__version__}"}
    for headers in ({"Host": "evil.example", "Origin": "http://evil.example"},
                    {"Host": f"evil.example:{port}", "Origin": f"http://evil.example:{port}"},
                    {"Origin": "http://evil.example"}, {"Origin": f"http://{scene}"}):
        path = f"/{presenter}" if "Host" in headers else "/"
        assert upgrade(scene, path, {**subprotocol, **headers}) == 403, headers
    assert upgrade(scene, f"/{presenter}", {**subprotocol, "Origin": f"http://{scene}"}) == 101


def test_removing_the_lock_file_frees_no_folder_a_lab_holds(token_lab):
    (token_lab["data"] / ".lab-lock").unlink()
    second = subprocess.run([sys.executable, "-m", "granlab.app.commands", "serve", "--port", "0", "--tokens",
                             "--data-dir", str(token_lab["data"])], capture_output=True, text=True, timeout=120)
    assert second.returncode == 2 and second.stderr.count("\n") == 1, second.stderr
    assert second.stderr.startswith(f"granlab serve: error: --data-dir {str(token_lab['data'])!r} is in use by "
                                    "another lab: give each lab a folder")
    assert (token_lab["data"] / ".presenter-address").read_text().strip() == token_lab["url"]


class Kept(logging.Handler):
    def __init__(self):
        super().__init__()
        self.records = []

    def emit(self, record):
        self.records.append(record)


def test_a_client_s_refused_messages_are_one_line_each_and_the_lab_s_own_faults_keep_their_traceback():
    """What a page sends that bokeh or panel cannot take is one line (bokeh logged each with a traceback),
    and so is an upgrade without bokeh's protocol; a failure inside the lab's own code keeps its traceback;
    the terminal of a lab is often projected: every line writes the tokens as '…'."""
    factory = logging.getLogRecordFactory()
    loggers = {name: logging.getLogger(name) for name in ("panel.reactive", "tornado.application", "tornado.access",
                                                          "bokeh.server.protocol_handler", "bokeh.server.views.ws",
                                                          "asyncio", "panel.io.document")}
    filters = {name: list(logger.filters) for name, logger in loggers.items()}
    levels = {name: logger.level for name, logger in loggers.items()}
    kept = Kept()
    for logger in loggers.values():  # panel's loggers do not propagate to the root's
        logger.addHandler(kept)
        logger.setLevel(logging.DEBUG)  # distributed, once imported in this process, sets tornado's to CRITICAL
    try:
        quiet_client_logs(("presenterSECRET",))
        try:
            ["a", "b"].index(None)
        except ValueError as error:  # panel's failure to take a select's value, then tornado's of the same
            loggers["panel.reactive"].error("Callback failed for object named 'Normal spring'", exc_info=True)
            loggers["tornado.application"].error("Exception in callback %r", "partial(...)", exc_info=error)
        try:
            {}["name"]
        except KeyError:
            loggers["bokeh.server.protocol_handler"].error("error handling message\n message: %r", "x", exc_info=True)
        try:
            Access("127.0.0.1", 5006, tokens=True).role(None)  # a fault of the lab's own code
        except AttributeError:
            loggers["tornado.application"].error("Uncaught exception GET /status?token=presenterSECRET",
                                                 exc_info=True)
        try:
            raise ProtocolError("Subprotocol header is not 'bokeh'")
        except ProtocolError:
            loggers["tornado.application"].error(
                "Uncaught exception GET /ws?token=presenterSECRET (127.0.0.1)\nHTTPServerRequest(uri='/ws?token="
                "presenterSECRET')", exc_info=True)
        loggers["tornado.access"].warning("%d %s %.2fms", 404, "GET /nothing?token=presenterSECRET (127.0.0.1)", 1.0)
        loggers["tornado.access"].warning("%d %s %.2fms", 403, "GET /ws (127.0.0.1)", 1.0)
        loggers["bokeh.server.views.ws"].error("Refusing websocket connection from Origin '%s'; use "
                                               "--allow-websocket-origin=%s", "http://evil.example", "evil.example")
    finally:
        logging.setLogRecordFactory(factory)
        for name, logger in loggers.items():
            logger.filters[:] = filters[name]
            logger.setLevel(levels[name])
            logger.removeHandler(kept)
    lines = [record.getMessage() for record in kept.records]
    assert lines[:2] == ["refused a page's message (ValueError: None is not in list)",
                         "refused a page's message (KeyError: 'name')"]
    assert lines[2] == "Uncaught exception GET /status?token=…" and kept.records[2].exc_info is not None
    assert lines[3:] == ["refused a websocket that does not speak bokeh's protocol (Subprotocol header is not 'bokeh'): "
                         "GET /ws?token=… (127.0.0.1)", "404 GET /nothing?token=… (127.0.0.1) 1.00ms",
                         "refused a websocket from Origin 'http://evil.example' (not a page of this lab)"]
    assert not any("SECRET" in line for line in lines)


@pytest.fixture(scope="module")
def small_class_lab(tmp_path_factory):
    data = tmp_path_factory.mktemp("small-class-lab-data")
    process, url, viewer = spawn(data, "--tokens", "--preset", "ratchet16", "--max-viewers", "2")
    yield {"url": url, "viewer": viewer, "process": process}
    process.terminate()
    process.wait(timeout=30)


class Loop:
    """An event loop in a thread of its own, for clients that stay open while the test goes on."""

    def __init__(self):
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()

    def run(self, coroutine, timeout=120):
        return asyncio.run_coroutine_threadsafe(coroutine, self.loop).result(timeout)

    def close(self):
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)


def pages(lab) -> dict:
    with urllib.request.urlopen(endpoint(lab["url"], "status"), timeout=30) as response:
        return json.loads(response.read())["pages"]


def test_a_class_larger_than_the_lab_holds_is_told_so_and_the_presenter_always_gets_in(small_class_lab):
    """Forty clients joining at once had every page built however many came, behind each other; now a
    lab holds ``--max-viewers`` viewers' pages (60 by default) and tells one more, in a small page that
    tries again by itself, without building a session for it."""
    from granlab.app.lab.classroom import Session

    loop = Loop()
    try:
        viewers = [Session(small_class_lab["viewer"]) for _ in range(2)]
        for session in viewers:
            loop.run(session.open())
        opened = pages(small_class_lab)
        assert opened["viewers"] == 2
        assert opened["made_beside_the_loop"] >= 2  # the widgets of each page made beside the server's loop
        body = []
        assert status_of(small_class_lab["viewer"], body=body) == 503
        assert "The class is full: this lab holds 2 viewers' pages" in body[0] and "refresh" in body[0]
        assert pages(small_class_lab)["refused_full"] == 1
        assert status_of(small_class_lab["url"]) == 200  # the presenter's page is never refused
        loop.run(viewers[0].close())
        deadline = time.monotonic() + 20
        while pages(small_class_lab)["viewers"] > 1 and time.monotonic() < deadline:
            time.sleep(0.2)
        assert status_of(small_class_lab["viewer"]) == 200  # a place came free
    finally:
        for session in viewers[1:]:
            loop.run(session.close())
        loop.close()


class FakeStream:
    def __init__(self, waiting: int):
        self._total_write_index, self._total_write_done_index = waiting, 0
        self.was_closed = False

    def closed(self):
        return self.was_closed

    def close(self):
        self.was_closed = True


class FakeClient:
    def __init__(self, waiting: int = 0, role: str = "viewer"):
        self.stream = FakeStream(waiting)
        self.ws_connection = types.SimpleNamespace(stream=self.stream)
        self.request = types.SimpleNamespace(remote_ip="10.0.0.7", connection=types.SimpleNamespace(stream=self.stream))
        self.role = role
        self.finished = None

    def set_status(self, status):
        self.status = status

    def set_header(self, name, value):
        pass

    def finish(self, text=""):
        self.finished = text


def test_pages_are_built_one_at_a_time_the_presenter_first_and_a_client_that_stops_reading_goes():
    from granlab.app.lab.gate import MAX_BACKLOG_BYTES, SessionGate, drop_stalled

    async def scenario():
        gate = SessionGate(max_viewers=2)
        order = []

        async def page(client):
            if await gate.admit(client, client.role):
                order.append(client.role)
                await asyncio.sleep(0.01)  # its build
                gate.built()

        first = FakeClient()
        await gate.admit(first, "viewer")  # being built
        waiting = [asyncio.create_task(page(FakeClient(role=role))) for role in ("viewer", "viewer", "presenter")]
        await asyncio.sleep(0.01)
        assert gate.waiting == 3
        full = FakeClient()
        assert not await gate.admit(full, "viewer") and full.status == 503 and "class is full" in full.finished
        gone = FakeClient(role="presenter")  # a presenter's reload that left before its turn
        gone.stream.was_closed = True
        waiting.append(asyncio.create_task(page(gone)))
        gate.built()
        await asyncio.gather(*waiting)
        return order, gate

    order, gate = run_async(scenario())
    assert order == ["presenter", "viewer", "viewer"] and gate.gone == 1 and gate.full == 1 and gate.waiting == 0
    clients = [FakeClient(waiting=MAX_BACKLOG_BYTES + 1), FakeClient(waiting=MAX_BACKLOG_BYTES)]
    assert drop_stalled(clients, gate) == 1 and clients[0].stream.was_closed and not clients[1].stream.was_closed
    assert gate.state()["dropped_not_reading"] == 1
