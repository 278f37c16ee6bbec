"""What an input path is, when it is not a regular file to read: said as what it is (a folder,
a named pipe, a device, a socket, a link to nowhere), never as "does not exist" when it does."""

from __future__ import annotations

import os
import stat
from pathlib import Path

from ..errors import GranLabError


def not_a_file(path: str | Path) -> str | None:
    """None for a regular file (or a link to one); else what ``path`` is, as the end of a sentence."""
    path = Path(path)
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return "is a link to nowhere" if path.is_symlink() else "does not exist"
    except OSError as error:
        return f"cannot be looked at ({error.strerror or error})"
    if stat.S_ISREG(mode):
        return None
    target = f" ({os.path.realpath(path)})" if path.is_symlink() else ""
    if stat.S_ISDIR(mode):
        return f"is a folder{target}, not a file"
    if stat.S_ISFIFO(mode):
        return f"is a named pipe (FIFO){target}, not a file"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return f"is a device{target}, not a file"
    if stat.S_ISSOCK(mode):
        return f"is a socket{target}, not a file"
    return "is not a regular file"


def require_file(path: str | Path, what: str, error: type[GranLabError], hint: str = "") -> Path:
    """``path`` if it is a regular file; else ``error`` saying ``what`` it was to be and what it is."""
    reason = not_a_file(path)
    if reason is not None:
        raise error(f"{what} {str(path)!r} {reason}{hint}")
    return Path(path)
