"""Who may open what in a lab: the roles' tokens, the names its pages may be opened by, and the
checks every route, websocket and session makes with them.

Everything here is fixed when the lab starts and read from the request at hand, never widened by
one: a page opened by a name the lab did not start with is refused (another site's page whose
name points at this machine would otherwise read it), and a session's role is that of the
connection it is made for (its ``?token=`` or its cookie), never of what a client wrote into a
session token. Bokeh's session tokens are signed with a secret made at start, so that one made
by a client is refused before any session is built from it.
"""

from __future__ import annotations

import logging
import secrets
import socket
import urllib.parse

import psutil
import tornado.httputil
import tornado.web
import tornado.websocket
from bokeh.server.auth_provider import AuthProvider


LOG = logging.getLogger("granlab.lab")
COOKIE = "granlab-token"
ROLES = ("presenter", "viewer")
EVERY_NETWORK = ("0.0.0.0", "::", "")
LOCKED_PAGE = ("<!doctype html><title>GranLab</title><body style='font:20px sans-serif;margin:3em'>"
               "<h1>GranLab</h1><p>This lab is served with tokens: open the full address the presenter gave, "
               "with its <code>?token=…</code>.</p>")
FOREIGN_PAGE = ("<!doctype html><title>GranLab</title><body style='font:20px sans-serif;margin:3em'>"
                "<h1>GranLab</h1><p>This lab does not answer to this address: open it by the one it printed.</p>")


def served_names(host: str) -> frozenset[str]:
    """The names (lower case, IPv6 in brackets) a page of a lab bound to ``host`` may be opened by:
    this machine's loopback names and ``host``; bound to every network (0.0.0.0, ::), also this
    machine's names and every address of its network interfaces, as they are at start."""
    names = {"127.0.0.1", "localhost", "[::1]", _bracketed(host.lower())}
    if host in EVERY_NETWORK:
        hostname = socket.gethostname().lower()
        names |= {hostname, f"{hostname}.local", socket.getfqdn().lower()}
        for addresses in psutil.net_if_addrs().values():
            names |= {_bracketed(a.address.split("%")[0].lower()) for a in addresses
                      if a.family in (socket.AF_INET, socket.AF_INET6)}
    return frozenset(names - {"", "[]"})


def _bracketed(address: str) -> str:
    return f"[{address}]" if ":" in address else address


def _name_of(netloc: str) -> tuple[str, int | None]:
    """The name (lower case, IPv6 in brackets) and the port of ``host[:port]``."""
    parts = urllib.parse.urlsplit("//" + netloc)
    try:
        port = parts.port
    except ValueError:  # a port out of range or not a number
        return "", None
    return _bracketed((parts.hostname or "").lower()), port


class Access:
    """A lab's roles (with ``tokens``, a random token each; without, every page of this machine is the
    presenter's) and the names its pages may be opened by on ``port``."""

    def __init__(self, host: str, port: int, tokens: bool):
        self.port = port
        self.names = served_names(host)
        self.roles: dict[str, str] = {secrets.token_urlsafe(16): role for role in ROLES} if tokens else {}
        self.secret = secrets.token_bytes(32)
        """Bokeh signs its session ids and tokens with this: a session token made by a client is refused."""

    @property
    def tokens(self) -> tuple[str, ...]:
        return tuple(self.roles)

    def token(self, role: str) -> str:
        """The token of ``role`` ("" without tokens)."""
        return next((token for token, given in self.roles.items() if given == role), "")

    def websocket_origins(self) -> list[str]:
        """The origins (``name:port``) the dashboard's websocket admits: its pages' own (bokeh's list
        cannot hold an IPv6 address: a page opened by one is refused its websocket)."""
        return sorted(f"{name}:{self.port}" for name in self.names if not name.startswith("["))

    def admits_host(self, netloc: str | None, port: int | None = None) -> bool:
        """Whether ``netloc`` (a Host header, an Origin's ``host:port``) names this lab on ``port`` (the
        dashboard's by default); a Host without a port is port 80."""
        if not netloc:
            return False
        name, given = _name_of(netloc)
        return name in self.names and (given or 80) == (port or self.port)

    def role(self, request: tornado.httputil.HTTPServerRequest) -> str | None:
        """The role of ``request`` itself: None if it names another host, else that of the token in its
        query, else in its cookie (the presenter's without tokens); None without a valid token."""
        if not self.admits_host(request.host):
            return None
        if not self.roles:
            return "presenter"
        return self.roles.get(self.given_token(request))

    def given_token(self, request: tornado.httputil.HTTPServerRequest) -> str:
        """The token ``request`` carries: in its query if valid there, else in its cookie ("" if none)."""
        for value in request.query_arguments.get("token", []):
            text = value.decode(errors="replace")
            if text in self.roles:
                return text
        cookie = request.cookies.get(COOKIE)
        return cookie.value if cookie is not None and cookie.value in self.roles else ""

    def admit(self, handler: tornado.web.RequestHandler) -> str | None:
        """The role of ``handler``'s request, its token set in the page's cookie (HttpOnly,
        SameSite=Strict) when it came in the address; None if refused."""
        role = self.role(handler.request)
        if role is not None and self.roles and not isinstance(handler, tornado.websocket.WebSocketHandler):
            token = self.given_token(handler.request)
            if handler.get_cookie(COOKIE) != token:
                handler.set_cookie(COOKIE, token, httponly=True, samesite="Strict")
        return role

    def refusal(self, request: tornado.httputil.HTTPServerRequest) -> str:
        """Why ``request`` is refused, in a few words (its summary as tornado logs it)."""
        why = "no valid token" if self.admits_host(request.host) else f"asked for by {request.host!r}, not this lab's"
        return f"{why}: {request.method} {request.path} ({request.remote_ip})"

    def refusal_page(self, request: tornado.httputil.HTTPServerRequest) -> str:
        return LOCKED_PAGE if self.admits_host(request.host) else FOREIGN_PAGE


class TokenAuth(AuthProvider):
    """Bokeh's check of the dashboard's page, websocket and files: a request by one of the lab's names
    with a valid role (a page refused is a 403 that says what to open; bokeh would redirect it)."""

    def __init__(self, access: Access):
        self.access = access
        super().__init__()

    @property
    def get_user(self):
        return self._role

    def _role(self, handler: tornado.web.RequestHandler) -> str | None:
        role = self.access.admit(handler)
        if role is None and isinstance(handler, tornado.websocket.WebSocketHandler):  # panel answers it 403
            LOG.warning("refused a websocket: %s", self.access.refusal(handler.request))
        elif role is None:
            handler.set_status(403)
            handler.finish(self.access.refusal_page(handler.request))
            raise tornado.web.Finish()
        return role

    @property
    def login_url(self) -> str:
        return "/locked"

    @property
    def login_handler(self):
        return LockedHandler


class LockedHandler(tornado.web.RequestHandler):
    """Where bokeh would send a request without a valid token: a 403 that says what to open."""

    def get(self):
        self.set_status(403)
        self.write(LOCKED_PAGE)


def connection_request(session_context) -> tornado.httputil.HTTPServerRequest:
    """The request a bokeh session is being made for: the page's own GET, or the websocket's
    upgrade when a page's session is made as its websocket opens. (Bokeh's request proxy answers
    ``arguments``, ``cookies`` and ``headers`` from the session token's payload; the connection's
    own request is behind it.)"""
    return session_context.request._request

