"""How many pages the lab holds and builds at once, and the clients it lets go.

A page's bokeh session is built on the server's one loop and takes it for about half a second (a
viewer's page of the 256-disk ratchet on two cores: 0.46–0.82 s, three quarters of it making bokeh's
models). Forty phones joining at once queued forty builds behind each other: ``GET /`` timed out at
20 s, ``/status`` waited 5–8 s, and every client that left before its page came had its page built
anyway. So:

- pages are built one at a time (:meth:`SessionGate.admit`), the loop answering everything else
  between two builds; the presenter's page goes before any viewer's waiting; a client that left
  while it waited has no page built; a page's widgets are made in a thread beside the loop, which
  is left only bokeh's own models to make;
- at most ``max_viewers`` viewers' pages are open or waiting: one more is told the class is full (a
  small page, 503, that tries again by itself) without a session being built;
- a client that stops reading is dropped once what waits to be sent to it passes
  :data:`MAX_BACKLOG_BYTES` (:func:`drop_stalled`): its messages were kept for it without bound.
"""

from __future__ import annotations

import asyncio
import collections
import logging
import time
from concurrent.futures import ThreadPoolExecutor

from panel.io.server import DocHandler

from .options import MAX_VIEWERS

LOG = logging.getLogger("granlab.lab")

MAX_BACKLOG_BYTES = 8 * 2 ** 20
"""What may wait to be sent to one client before it is dropped (a page keeps up with a few hundred kB)."""

FULL_PAGE = ("<!doctype html><title>GranLab: the class is full</title><meta http-equiv='refresh' content='{retry}'>"
             "<body style='font:20px sans-serif;margin:3em'><h1>GranLab</h1><p>The class is full: this lab holds "
             "{limit} viewers' pages and all are open. This page tries again by itself every {retry} s; ask the "
             "presenter to raise <code>--max-viewers</code> if the class is larger.</p>")
RETRY_SECONDS = 10
TURN_SECONDS = 0.005
"""The pause between two builds, in which the loop answers everything that came during the first."""


class SessionGate:
    """One page built at a time, the presenter's first, and at most ``max_viewers`` viewers' pages."""

    def __init__(self, max_viewers: int = MAX_VIEWERS, pending_seconds: float = 5.0):
        self.max_viewers = max_viewers
        self.pending_seconds = pending_seconds
        """How long a page built waits for its websocket before its session is discarded."""
        self._viewers: dict = {}  # a viewer's session context -> [built at, whether its websocket came]
        self.full = 0
        """Viewers told the class was full, since the start."""
        self.gone = 0
        """Clients that left while their page waited to be built, since the start."""
        self.dropped = 0
        """Clients dropped for not reading, since the start."""
        self.made_beside = 0
        """Pages whose widgets were made in the gate's thread, beside the loop, since the start."""
        self._building = False
        self._waiting = {"presenter": collections.deque(), "viewer": collections.deque()}

    @property
    def waiting(self) -> int:
        return sum(len(queue) for queue in self._waiting.values())

    def opened(self, context) -> None:
        """A viewer's page was built (``context``: its bokeh session's)."""
        self._viewers[context] = [time.monotonic(), False]

    def closed(self, context) -> None:
        """A viewer's session ended."""
        self._viewers.pop(context, None)

    @property
    def viewers(self) -> int:
        """Viewers' pages open: connected, or built and waiting for their websocket (a page whose client
        left holds no place while its session waits to be discarded)."""
        now = time.monotonic()
        count = 0
        for context, seen in self._viewers.items():
            session = context._session
            connected = session is not None and session.connection_count > 0
            seen[1] = seen[1] or connected
            count += connected or (not seen[1] and now - seen[0] < self.pending_seconds)
        return count

    def state(self) -> dict:
        """What ``/status`` says of the gate."""
        return {"viewers": self.viewers, "max_viewers": self.max_viewers, "waiting": self.waiting,
                "refused_full": self.full, "left_waiting": self.gone, "dropped_not_reading": self.dropped,
                "made_beside_the_loop": self.made_beside}

    async def admit(self, handler, role: str) -> bool:
        """Wait until this page may be built; False where it is not (the class is full, said on the
        page, or the client left meanwhile)."""
        if role == "viewer" and self.viewers + len(self._waiting["viewer"]) >= self.max_viewers:
            self.full += 1
            handler.set_status(503)
            handler.set_header("Retry-After", str(RETRY_SECONDS))
            handler.finish(FULL_PAGE.format(limit=self.max_viewers, retry=RETRY_SECONDS))
            return False
        if self._building:
            turn = asyncio.get_running_loop().create_future()
            self._waiting[role if role in self._waiting else "viewer"].append(turn)
            await turn
        self._building = True
        if handler.request.connection.stream.closed():
            self.gone += 1
            self.built()
            return False
        return True

    def built(self) -> None:
        """The page being built is done (or given up): the next may start, the presenter's first, once the
        loop has answered what came meanwhile (a build is one long step of the loop: woken at once, the next
        would be the loop's next step too, ahead of the requests that were waiting for a turn)."""
        asyncio.get_running_loop().call_later(TURN_SECONDS, self._next)

    def _next(self) -> None:
        for queue in (self._waiting["presenter"], self._waiting["viewer"]):
            if queue:
                queue.popleft().set_result(None)
                return
        self._building = False


BUILDER = ThreadPoolExecutor(1, thread_name_prefix="granlab-page")
"""Where a page's Python objects are made, beside the loop (one at a time, as the gate lets them)."""


class GatedDocHandler(DocHandler):
    """Panel's page handler, its session built only once :class:`SessionGate` lets it (the gate and the
    request's role are the lab's ``application.granlab_gate`` and ``current_user``). Where the lab gives
    ``application.granlab_prebuild(request, role)``, what it returns is made in :data:`BUILDER`'s thread
    and left on the request as ``granlab_page`` for the session to take: half a page's build is making its
    widgets, and made on the loop it kept ``/status`` waiting."""

    _holds = False

    async def prepare(self):
        await super().prepare()
        if self._finished or self.current_user is None:
            return
        gate: SessionGate = self.application.granlab_gate
        if not await gate.admit(self, self.current_user):
            if not self._finished:
                self.finish()
            return
        self._holds = True
        prebuild = getattr(self.application, "granlab_prebuild", None)
        if prebuild is not None:
            self.request.granlab_page = await asyncio.get_running_loop().run_in_executor(
                BUILDER, prebuild, self.request, self.current_user)
            gate.made_beside += self.request.granlab_page is not None

    def on_finish(self):
        self._release()
        super().on_finish()

    def on_connection_close(self):
        self._release()
        super().on_connection_close()

    def _release(self) -> None:
        if self._holds:
            self._holds = False
            self.application.granlab_gate.built()


def backlog(stream) -> int:
    """Bytes written to a tornado stream and not yet handed to the network."""
    return stream._total_write_index - stream._total_write_done_index


def drop_stalled(sockets, gate: SessionGate) -> int:
    """Close the websockets of ``sockets`` (tornado handlers) whose backlog passed MAX_BACKLOG_BYTES; how
    many were."""
    dropped = 0
    for socket in list(sockets):
        connection = getattr(socket, "ws_connection", None)
        stream = getattr(connection, "stream", None)
        if stream is None or stream.closed() or backlog(stream) <= MAX_BACKLOG_BYTES:
            continue
        LOG.warning("dropped a page that stopped reading (%.0f MB waited to be sent to %s)", backlog(stream) / 1e6,
                    socket.request.remote_ip)
        stream.close()
        dropped += 1
    gate.dropped += dropped
    return dropped

