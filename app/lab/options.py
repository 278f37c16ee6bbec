"""What ``granlab serve`` is given, checked before anything heavy is imported or started: a bad
address, folder or limit is refused in a fraction of a second, not after the seconds that panel,
bokeh, viser and numba take to import."""

from __future__ import annotations

import contextlib
import errno
import os
import socket
from pathlib import Path

try:
    import fcntl
except ImportError:  # Windows: a folder is not claimed
    fcntl = None

from granlab.engine.errors import GranLabError
from granlab.engine.io.outputs import check_output

LOCAL_HOSTS = ("127.0.0.1", "localhost", "::1")
CLAIM_FILE = ".lab-lock"
"""The file of the data folder the lab holding it writes its process id into."""
HISTORY_MIB = 64.0
MAX_HISTORY_MIB = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2 ** 21
PAUSE_WITHOUT_PAGES = 60.0
"""Seconds a run goes on with no page open before it pauses (``--pause-without-pages``)."""
MAX_PAUSE_WITHOUT_PAGES = 86400.0
MAX_VIEWERS = 60
"""Viewers' pages a lab holds by default (``--max-viewers``): a class of forty and a margin."""
MAX_MAX_VIEWERS = 1000


def check_serve_options(host: str, port: int, data_dir, history_mib: float, pause_without_pages: float,
                        max_viewers: int = MAX_VIEWERS) -> None:
    """Refuse, before the lab starts, what it could not serve with (each in one line naming what is
    allowed)."""
    if not 1 <= max_viewers <= MAX_MAX_VIEWERS:
        raise GranLabError(f"--max-viewers {max_viewers} is not allowed: from 1 to {MAX_MAX_VIEWERS} (each viewer's "
                           "page is a session of its own on this machine)")
    check_address(host, port)
    check_output(data_dir, "--data-dir", folder=True)
    if not 0 < history_mib <= MAX_HISTORY_MIB:  # NaN fails too
        raise GranLabError(f"--history-mib {history_mib:g} is not allowed: more than 0 and at most "
                           f"{MAX_HISTORY_MIB:.0f} (half this machine's memory)")
    if not 0 <= pause_without_pages <= MAX_PAUSE_WITHOUT_PAGES:
        raise GranLabError(f"--pause-without-pages {pause_without_pages:g} is not allowed: seconds from 0 (never "
                           f"pause) to {MAX_PAUSE_WITHOUT_PAGES:g} (a day)")


def check_address(host: str, port: int) -> None:
    """Refuse an address the lab could not serve on: a port out of range, a host name that does not
    resolve or is not this machine's, a port another program holds."""
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


@contextlib.contextmanager
def claimed_data_folder(data_dir):
    """The data folder locked for this lab while in the block; refused if another lab holds it: its
    presenter's address, its saves and its movies are there. The lock is the folder's own (an OS lock
    on the folder, which ends with the process holding it), so that removing a file frees nothing;
    the lab's process id is written into the folder's CLAIM_FILE for the refusal to name."""
    folder = Path(data_dir)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        handle = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError as error:
        raise GranLabError(f"--data-dir {str(data_dir)!r} cannot be used: {error.strerror}") from error
    try:
        if fcntl is not None:
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                raise GranLabError(f"--data-dir {str(data_dir)!r} is in use by another lab{_claimant(folder)}: "
                                   "give each lab a folder of its own") from None
            with contextlib.suppress(OSError):  # the lock holds without it
                (folder / CLAIM_FILE).write_text(str(os.getpid()))
        yield
    finally:
        os.close(handle)


def _claimant(folder: Path) -> str:
    """" (process ID)" of the lab holding ``folder``, from its CLAIM_FILE ("" if that cannot be read)."""
    try:
        pid = (folder / CLAIM_FILE).read_text().strip()
    except (OSError, UnicodeDecodeError):
        return ""
    return f" (process {pid})" if pid.isdigit() else ""
