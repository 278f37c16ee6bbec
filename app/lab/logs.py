"""What the lab writes to its terminal, which is often projected: no token, and one line for each
thing a client did that the lab refused (a traceback is for the lab's own faults, never for what
a page or a client sent)."""

from __future__ import annotations

import collections
import logging
import os
import traceback
from pathlib import Path

import tornado.websocket
from bokeh.protocol.exceptions import ProtocolError
from tornado.iostream import StreamClosedError

CLIENT_LOGGERS = ("bokeh.server.views.ws", "bokeh.server.protocol_handler", "panel.reactive", "tornado.application")
"""Where bokeh, panel and tornado log what they failed to do with a client's message: where no frame
of the lab's own code failed, the message's fault, said in a line."""

OWN_CODE = tuple(str(Path(__file__).resolve().parents[2] / part) + os.sep for part in ("app", "engine", "granlab"))
"""The folders of the lab's own code (in a clone and installed alike): a failure in it keeps its traceback."""

REPEATS = ("had invalid signature", "server failed to parse a message", "server failed to handle a message")
"""Bokeh's lines that repeat a line already written of the same refusal."""

MESSAGE_CHARS = 160
"""A refused message is quoted up to this many characters."""


class ClosedTabFilter(logging.Filter):
    """Drops the warnings and tracebacks of a message sent to a tab that just closed: a closed
    tab is normal in a classroom, and the terminal the lab runs in should stay readable."""

    def filter(self, record: logging.LogRecord) -> bool:
        closed = (tornado.websocket.WebSocketClosedError, StreamClosedError)
        if record.exc_info and isinstance(record.exc_info[1], closed):
            return False
        message = record.getMessage()
        return "connection was closed" not in message and "WebSocketClosedError" not in message


class RepeatFilter(logging.Filter):
    """Drops a refusal's second line: one of an error already written (panel logs a widget's failed
    change, then raises it to tornado, which logs it again), bokeh's that repeat one (REPEATS), and
    tornado's access line of a websocket refused (the refusal's own line says why)."""

    def filter(self, record: logging.LogRecord) -> bool:
        if getattr(record, "repeat", False):
            return False
        message = record.getMessage()
        if record.name == "tornado.access":
            return not message.startswith("403 GET /ws")
        return not any(text in message for text in REPEATS)


def own_fault(error: BaseException) -> bool:
    """Whether a frame of the lab's own code is in ``error``'s traceback."""
    return any(frame.filename.startswith(OWN_CODE) for frame in traceback.extract_tb(error.__traceback__))


def one_line(record: logging.LogRecord) -> str | None:
    """The line a client's refused request or message is written as (None: not one)."""
    error = record.exc_info[1] if record.exc_info else None
    first = record.getMessage().splitlines()[0] if record.getMessage() else ""
    if isinstance(error, ProtocolError):
        return f"refused a websocket that does not speak bokeh's protocol ({error}): " \
               f"{first.removeprefix('Uncaught exception ')}"
    if error is not None and record.name in CLIENT_LOGGERS and not own_fault(error):
        return f"refused a page's message ({type(error).__name__}: {str(error)[:MESSAGE_CHARS]})"
    if first.startswith("Refusing websocket connection from Origin"):
        return f"refused a websocket from {first.split(';')[0].removeprefix('Refusing websocket connection from ')}" \
               " (not a page of this lab)"
    return None


def lab_log_records(tokens) -> None:
    """From now on every log record writes the lab's ``tokens`` as ``…`` and a client's refused
    request or message as one line (:func:`one_line`)."""
    make_record = logging.getLogRecordFactory()
    written = collections.deque(maxlen=8)  # the errors last written as a line

    def lab_record(*args, **kwargs) -> logging.LogRecord:
        record = make_record(*args, **kwargs)
        line = one_line(record)
        if line is None and not tokens:
            return record
        message = record.getMessage() if line is None else line
        if line is not None and record.exc_info:
            error = record.exc_info[1]
            record.repeat = any(error is seen for seen in written)
            written.append(error)
            record.exc_info = record.exc_text = None
        for token in tokens:
            message = message.replace(token, "…")
        record.msg, record.args = message, ()
        return record

    logging.setLogRecordFactory(lab_record)


def quiet_client_logs(tokens) -> None:
    """The lab's terminal as this module says: tokens masked, a refusal a line, closed tabs silent."""
    for name in ("asyncio", "bokeh.server.views.ws", "panel.io.document"):
        logging.getLogger(name).addFilter(ClosedTabFilter())
    for name in (*CLIENT_LOGGERS, "tornado.access"):  # a logger's filters see only its own records
        logging.getLogger(name).addFilter(RepeatFilter())
    lab_log_records(tokens)
