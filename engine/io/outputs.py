"""Where results may be written: never over an input, never over an existing file unless the
user says so (``--force``), and checked before any work starts."""

from __future__ import annotations

import os
import re
import secrets
import shutil
import tempfile
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from ..errors import GranLabError, OutputError, WriteFailed


def occupied(path: Path) -> bool:
    """Whether something is at ``path``: a file, a folder, or a link (even one leading nowhere)."""
    return path.exists() or path.is_symlink()


def free_name(path: Path) -> Path:
    """``path`` itself if nothing is there, else the first free ``STEM-2.SUFFIX``, ``STEM-3...``."""
    candidate, number = path, 1
    while occupied(candidate):
        number += 1
        candidate = path.with_name(f"{path.stem}-{number}{path.suffix}")
    return candidate


def check_output(path: str | Path, option: str = "--out", force: bool = False, inputs=(),
                 folder: bool = False) -> Path:
    """``path`` as a file (or with ``folder``, a folder) that may be written.

    Refused, with a message naming ``option``: a file that is one of ``inputs``; an existing
    file unless ``force``; a folder where a file is wanted (or the reverse); a place whose
    nearest existing folder cannot be written."""
    path = Path(path)
    for given in inputs:
        # the same file under any name: a symbolic or a hard link too
        if path.exists() and Path(given).exists() and path.samefile(given):
            raise OutputError(f"{option} {str(path)!r} is the input file: writing it would lose what it holds; "
                              f"give another name ({str(free_name(path))!r} is free)")
    if folder:
        if path.exists() and not path.is_dir():
            raise OutputError(f"{option} {str(path)!r} is a file, not a folder: give a folder for the run files")
    elif path.is_dir():
        raise OutputError(f"{option} {str(path)!r} is a folder: give a file name inside it")
    elif occupied(path) and not force:
        raise OutputError(f"{option} {str(path)!r} exists: give --force to write over it, or another name "
                          f"({str(free_name(path))!r} is free)")
    parent = path if folder else path.parent
    existing = parent.absolute()
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise OutputError(f"{option} {str(path)!r} cannot be written: {str(existing)!r} is a file, not a folder")
    try:  # a probe: permission bits do not tell (root, /proc, read-only mounts)
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as error:
        raise OutputError(f"{option} {str(path)!r} cannot be written: no file can be made in {str(existing)!r} "
                          f"({error.strerror or error})") from None
    return path


def failed_write_reason(error: Exception) -> str | None:
    """The operating system's reason for a failed write (no space, a file size limit, an I/O
    error), from an ``OSError`` or from h5py's ``RuntimeError`` that quotes HDF5's; None for
    another error."""
    if isinstance(error, OSError):
        return error.strerror or str(error)
    found = re.search(r"errno = \d+, error message = '([^']*)'", str(error))
    return found.group(1) if found else None


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process: alive
        pass
    return True


def remove_orphans(home: Path, name: str) -> list[Path]:
    """Remove the hidden ``.NAME.PID-*.part`` folders in ``home`` whose writer (PID) has ended:
    what a command killed outright while writing NAME left. Returns those removed."""
    pattern = re.compile(rf"\.{re.escape(name)}\.(\d+)-[0-9a-f]{{8}}\.part")
    removed = []
    for entry in home.iterdir():
        found = pattern.fullmatch(entry.name)
        if found and not _alive(int(found.group(1))):
            shutil.rmtree(entry, ignore_errors=True)
            removed.append(entry)
    return removed


@contextmanager
def staged(folder: str | Path, last: Sequence[str] = ()) -> Iterator[Path]:
    """A new hidden folder to write a command's files into, moved into ``folder`` (made if
    missing) once the block ends without error: the hidden folder renamed to ``folder`` if that
    did not exist, else file by file, those named in ``last`` last (the file that lists the
    others, the one a reader opens first). On an error, Ctrl-C or SIGTERM (see
    :func:`granlab.app.commands.run_args`) the files are removed; a command killed outright leaves a
    hidden ``.NAME.PID-*.part`` folder (NAME the first of ``last``, else ``folder``'s; PID its
    writer's), removed by the next command that writes NAME there, and nothing under the names it
    was writing."""
    folder = Path(folder).absolute()
    new = not occupied(folder)
    home = folder.parent if new else folder
    home.mkdir(parents=True, exist_ok=True)
    name = last[0] if last else folder.name
    remove_orphans(home, name)
    while True:
        # made here, not by mkdtemp, so that the folder renamed into place has the user's
        # usual permissions (mkdtemp's are 0700)
        stage = home / f".{name}.{os.getpid()}-{secrets.token_hex(4)}.part"
        try:
            stage.mkdir()
            break
        except FileExistsError:
            continue
    try:
        try:
            yield stage
        except (OSError, RuntimeError) as error:
            # a run file's writer says what stays readable of its file: here nothing of it stays
            reason = error.reason if isinstance(error, WriteFailed) else \
                None if isinstance(error, GranLabError) else failed_write_reason(error)  # an input's, not a write's
            if reason is None:
                raise
            raise OutputError(f"writing {str(folder / last[0]) if last else str(folder)!r} failed: {reason}; nothing "
                              f"was written under its name") from None
        if new:
            stage.rename(folder)
        else:
            written = os.listdir(stage)
            names = [name for name in written if name not in last] + [name for name in last if name in written]
            for name in names:
                os.replace(stage / name, folder / name)
            stage.rmdir()
    finally:
        shutil.rmtree(stage, ignore_errors=True)
