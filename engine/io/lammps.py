"""LAMMPS text dumps: ``dump custom`` of the atoms and ``dump local`` of the contacts.

A dump is a sequence of frames, each a header and rows::

    ITEM: TIMESTEP                 (ITEM: UNITS and ITEM: TIME may come first: dump_modify units/time yes)
    1000
    ITEM: NUMBER OF ATOMS          (NUMBER OF ENTRIES in a local dump)
    200
    ITEM: BOX BOUNDS pp pp pp      (p periodic; f, s, m not; "xy xz yz" first: a triclinic box)
    0 14.2
    0 14.2
    -0.5 0.5
    ITEM: ATOMS id type x y z radius vx vy vz omegaz     (ITEM: ENTRIES c_1[1] c_1[2] ... in a local dump)
    ... one row of numbers per atom (entry) ...

The parser here is strict (every header item, every row's width, the count of rows, a last line
cut short) and reads only the frame asked for after one quick pass that indexes the frames.
Libraries that read dumps do not fit: ASE's reader converts the values to its own units and
keeps no ``radius`` nor ``omegaz`` column, MDAnalysis's drops the boundary flags.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .h5md import RunFileError
from .inputs import require_file

ATOM_ITEM = "ATOMS"
LOCAL_ITEM = "ENTRIES"
_CHUNK = 1 << 20


class DumpError(RunFileError):
    """A LAMMPS dump that cannot be read: names the file, the frame and what is wrong."""


@dataclass(frozen=True)
class DumpFrame:
    """One frame of a dump: ``bounds`` (3, 2) lower and upper box bounds, ``boundary`` the three
    flags of the header (``"pp"``: periodic), ``rows`` (N, C) with the ``columns`` of the header."""

    index: int
    timestep: int
    time: float | None
    bounds: np.ndarray
    boundary: tuple[str, ...]
    columns: tuple[str, ...]
    rows: np.ndarray

    @property
    def periodic(self) -> tuple[bool, ...]:
        return tuple(flag == "pp" for flag in self.boundary)

    def column(self, name: str) -> np.ndarray:
        return self.rows[:, self.columns.index(name)]


@dataclass(frozen=True)
class _Header:
    timestep: int
    time: float | None
    bounds: np.ndarray
    boundary: tuple[str, ...]
    columns: tuple[str, ...]
    count: int
    offset: int
    line: int


class Dump:
    """A LAMMPS text dump, its frames indexed (``timesteps``); :meth:`frame` reads one.
    ``item`` is :data:`ATOM_ITEM` for ``dump custom``/``atom``, :data:`LOCAL_ITEM` for ``dump local``."""

    def __init__(self, path: str | Path, item: str = ATOM_ITEM):
        self.path = Path(path)
        self.item = item
        self.what = "atom" if item == ATOM_ITEM else "entry"
        require_file(self.path, "dump", DumpError)
        self._headers = self._index()

    @property
    def timesteps(self) -> list[int]:
        return [h.timestep for h in self._headers]

    def __len__(self) -> int:
        return len(self._headers)

    def _fail(self, line: int, message: str) -> DumpError:
        return DumpError(f"{self.path}, line {line}: {message}")

    def _index(self) -> list[_Header]:
        headers = []
        with open(self.path, "rb") as f:
            size = self.path.stat().st_size
            if size == 0:
                raise DumpError(f"{self.path} is empty: not a LAMMPS dump")
            f.seek(size - 1)
            if f.read(1) != b"\n":
                raise DumpError(f"{self.path} is truncated: its last line is cut short (was it copied or written "
                                f"to the end?)")
            f.seek(0)
            line = 0
            while True:
                header, line = self._read_header(f, line, len(headers))
                if header is None:
                    break
                skipped = _skip_lines(f, header.count)
                if skipped < header.count:
                    raise DumpError(f"{self.path} is truncated: frame {len(headers)} (timestep {header.timestep}) has "
                                    f"{skipped} of the {header.count} {self.what} rows its header announces")
                line += header.count
                headers.append(header)
        if not headers:
            raise DumpError(f"{self.path} holds no frame: not a LAMMPS dump")
        return headers

    def _read_header(self, f, line: int, frame: int) -> tuple[_Header | None, int]:
        timestep = count = None
        time = None
        bounds = boundary = None
        expected = "ITEM: TIMESTEP"
        while True:
            raw = f.readline()
            line += 1
            if not raw:
                if timestep is None and count is None:
                    return None, line
                raise DumpError(f"{self.path} is truncated: frame {frame} stops in its header (line {line})")
            text = raw.decode("utf-8", "replace").strip()
            if not text.startswith("ITEM:"):
                if frame == 0 and line == 1:
                    raise self._fail(line, f"{text[:40]!r} where a LAMMPS dump starts with 'ITEM: TIMESTEP'")
                raise self._fail(line, f"{text[:40]!r} where '{expected}' was expected")
            item = text[5:].strip()
            if item == "UNITS":
                f.readline()
                line += 1
            elif item == "TIME":
                time, line = self._number(f, line, item, float), line + 1
            elif item == "TIMESTEP":
                timestep, line = self._number(f, line, item, int), line + 1
            elif item in ("NUMBER OF ATOMS", "NUMBER OF ENTRIES"):
                wanted = f"NUMBER OF {self.item}"
                if item != wanted:
                    other = "a dump local of entries" if item.endswith("ENTRIES") else "a dump of atoms"
                    raise self._fail(line, f"'ITEM: {item}': this is {other}, where {self._kind()} is needed")
                count, line = self._number(f, line, item, int), line + 1
                if count < 0:
                    raise self._fail(line, f"{count} {self.what} rows: a count >= 0 is needed")
            elif item.startswith("BOX BOUNDS"):
                flags = item.split()[2:]
                if flags[:3] == ["xy", "xz", "yz"]:
                    raise self._fail(line, "a triclinic box (BOX BOUNDS xy xz yz): only rectangular boxes can be "
                                           "analysed")
                if len(flags) != 3 or any(len(flag) != 2 or set(flag) - set("pfsm") for flag in flags):
                    raise self._fail(line, f"'ITEM: {item}': three boundary flags such as 'pp pp pp' are needed")
                bounds = np.zeros((3, 2))
                for axis in range(3):
                    raw = f.readline()
                    line += 1
                    try:
                        lo, hi = (float(v) for v in raw.split())
                    except ValueError:
                        raise self._fail(line, f"{raw.decode('utf-8', 'replace').strip()!r}: the box's lower and upper "
                                               f"bound along {'xyz'[axis]} are needed") from None
                    bounds[axis] = lo, hi
                boundary = tuple(flags)
            elif item.split()[0] == self.item or item.split()[0] in (ATOM_ITEM, LOCAL_ITEM):
                if item.split()[0] != self.item:
                    raise self._fail(line, f"'ITEM: {item.split()[0]}': this is not {self._kind()}")
                missing = [name for name, value in (("TIMESTEP", timestep), (f"NUMBER OF {self.item}", count),
                                                    ("BOX BOUNDS", bounds)) if value is None]
                if missing:
                    raise self._fail(line, f"frame {frame} has no {' or '.join(missing)} item before its rows")
                columns = tuple(item.split()[1:])
                if not columns:
                    raise self._fail(line, f"'ITEM: {self.item}' names no column")
                return _Header(timestep, time, bounds, boundary, columns, count, f.tell(), line), line
            else:
                raise self._fail(line, f"'ITEM: {item}' is not an item of a LAMMPS dump")
            expected = f"ITEM: {self.item}"

    def _number(self, f, line: int, item: str, kind: type):
        text = f.readline().decode("utf-8", "replace").strip()
        try:
            return kind(text)
        except ValueError:
            what = "a whole number" if kind is int else "a number"
            raise self._fail(line + 1, f"{text[:40]!r} after 'ITEM: {item}', where {what} is needed") from None

    def _kind(self) -> str:
        return "a dump of atoms (dump custom)" if self.item == ATOM_ITEM else "a dump local of contacts"

    def find(self, frame: int) -> int:
        """The index of frame ``frame`` (negative counts from the end), checked."""
        count = len(self._headers)
        if not -count <= frame < count:
            raise DumpError(f"frame {frame} is out of range: {self.path} holds frames 0..{count - 1} "
                            f"(timesteps {_listed(self.timesteps)})")
        return frame % count

    def frame(self, frame: int) -> DumpFrame:
        """Frame ``frame`` (negative counts from the end) with its rows."""
        index = self.find(frame)
        header = self._headers[index]
        width = len(header.columns)
        with open(self.path, "rb") as f:
            f.seek(header.offset)
            lines = [f.readline() for _ in range(header.count)]
        try:
            rows = np.loadtxt(lines, dtype=float, ndmin=2, comments=None).reshape(header.count, width)
        except ValueError:
            for k, raw in enumerate(lines):
                values = raw.split()
                if len(values) != width:
                    raise self._fail(header.line + k + 1, f"{len(values)} values in a row of frame {index} (timestep "
                                                          f"{header.timestep}), whose header names {width} columns")
                try:
                    [float(v) for v in values]
                except ValueError:
                    raise self._fail(header.line + k + 1, f"{raw.decode('utf-8', 'replace').strip()[:60]!r} is not a "
                                                          "row of numbers") from None
            raise
        return DumpFrame(index, header.timestep, header.time, header.bounds, header.boundary, header.columns, rows)


def _skip_lines(f, count: int) -> int:
    """Move ``f`` past ``count`` lines; the number of lines there were (fewer at the end of the file)."""
    skipped = 0
    while skipped < count:
        start = f.tell()
        chunk = f.read(_CHUNK)
        if not chunk:
            break
        ends = np.flatnonzero(np.frombuffer(chunk, dtype=np.uint8) == 10)
        if skipped + ends.size >= count:
            f.seek(start + int(ends[count - skipped - 1]) + 1)
            return count
        skipped += ends.size
    return skipped


def _listed(values: list[int]) -> str:
    shown = ", ".join(str(v) for v in values[:6])
    return shown + (f", ... {values[-1]}" if len(values) > 6 else "")


def write_dump(f, timestep: int, time: float, lower: np.ndarray, upper: np.ndarray, periodic, columns: tuple[str, ...],
               rows: np.ndarray, item: str = ATOM_ITEM, formats: tuple[str, ...] | None = None) -> None:
    """Append one frame to an open text file: a 2D box (``lower``, ``upper`` of x and y; z from
    -0.5 to 0.5, periodic as LAMMPS writes a 2D box), the columns and rows. Floats are written
    with 17 significant digits, so a frame read back holds the same numbers."""
    flags = " ".join("pp" if p else "ff" for p in periodic) + " pp"
    f.write(f"ITEM: TIME\n{time:.17g}\nITEM: TIMESTEP\n{timestep}\nITEM: NUMBER OF {item}\n{len(rows)}\n"
            f"ITEM: BOX BOUNDS {flags}\n")
    for lo, hi in zip(lower, upper):
        f.write(f"{lo:.17g} {hi:.17g}\n")
    f.write("-0.5 0.5\n")
    f.write(f"ITEM: {item} {' '.join(columns)}\n")
    fmt = " ".join(formats or ("%.17g",) * len(columns))
    np.savetxt(f, rows, fmt=fmt)
