"""Extended XYZ files: read with ASE's parser, written here with full precision.

A frame is a count line, a comment line of ``key=value`` pairs and one line per particle::

    200
    Lattice="14.2 0 0 0 14.2 0 0 0 1" Origin="0 0 -0.5" pbc="T T F" Properties=id:I:1:pos:R:3:radius:R:1 Time=2.5
    1 0.55 3.2 0 0.47
    ...

``Lattice`` holds the three cell vectors (rows), ``Origin`` (OVITO writes it) the corner of the cell,
``pbc`` its periodicity and ``Properties`` the columns, each ``name:type:count``. OVITO, ASE and
many codes write it; OVITO shows the particles with the ``radius`` column's size in the cell.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .h5md import RunFileError
from .inputs import require_file

RADIUS_NAMES = ("radius", "radii")
DIAMETER_NAMES = ("diameter", "diameters")


@dataclass(frozen=True)
class XYZFrame:
    """One frame: ``positions`` (N, 3) relative to the ``origin`` of the cell, ``cell`` (3, 3)
    its vectors as rows, ``pbc`` its periodicity, ``arrays`` every per-particle column by its
    name (lower case), ``info`` the other keys of the comment line."""

    index: int
    count: int
    positions: np.ndarray
    cell: np.ndarray
    origin: np.ndarray
    pbc: tuple[bool, bool, bool]
    arrays: dict[str, np.ndarray]
    info: dict = field(default_factory=dict)


def read_xyz_frames(path: str | Path) -> list[XYZFrame]:
    """Every frame of an extended XYZ file."""
    import ase.io

    path = Path(path)
    require_file(path, "extended XYZ file", RunFileError)
    check_counts(path)
    try:
        frames = ase.io.read(path, index=":", format="extxyz")
    except Exception as error:  # ASE raises many kinds (XYZError, ValueError, IndexError, KeyError)
        raise RunFileError(f"{path} is not a readable extended XYZ file: {error or type(error).__name__}") from None
    if not frames:
        raise RunFileError(f"{path} holds no frame")
    return [_frame(path, index, atoms, len(frames)) for index, atoms in enumerate(frames)]


def check_counts(path: Path) -> None:
    """Check each frame's count line against what is left of the file before any parser reads it:
    a count of 10¹² particles in a file of kilobytes would have a parser read past its end for
    minutes. Each particle's line takes at least two bytes (a value and its line end)."""
    size = path.stat().st_size
    with path.open("rb") as f:
        index = 0
        while True:
            line = f.readline()
            if not line.strip():
                if not line or not f.read(1 << 16).strip():  # the end, or only blank lines to it
                    return
                raise RunFileError(f"{path}, frame {index}: a blank line where a count line (the number of "
                                   f"particles) should be")
            try:
                count = int(line)
            except ValueError:
                raise RunFileError(f"{path}, frame {index}: the count line reads {line[:40].decode(errors='replace')!r}"
                                   f"; it should be the number of particles") from None
            left = size - f.tell()
            if count < 0 or 2 * count > left:
                raise RunFileError(f"{path}, frame {index}: the count line says {count} particles, but only "
                                   f"{left} bytes follow it (each particle needs a line of its own)")
            for _ in range(count + 1):  # the comment line, then the particles
                if not f.readline():
                    raise RunFileError(f"{path}, frame {index}: the file ends inside the frame (its count line "
                                       f"says {count} particles)")
            index += 1


def _frame(path: Path, index: int, atoms, count: int) -> XYZFrame:
    info = dict(atoms.info)
    origin = np.asarray(info.pop("Origin", np.zeros(3)), dtype=float).reshape(-1)
    if origin.shape != (3,):
        raise RunFileError(f"{path}, frame {index}: Origin holds {origin.size} numbers; 3 are needed")
    arrays = {name.lower(): np.asarray(value) for name, value in atoms.arrays.items() if name != "numbers"}
    positions = arrays.pop("positions") - origin
    return XYZFrame(index, count, positions, np.asarray(atoms.cell[:], dtype=float), origin,
                    tuple(bool(p) for p in atoms.pbc), arrays, info)


def write_xyz(f, positions: np.ndarray, lengths: np.ndarray, periodic, columns: dict[str, np.ndarray],
              info: dict[str, float | int], lower=(0.0, 0.0)) -> None:
    """Append one frame of 2D disks to an open text file: ``positions`` (N, 2) in the cell of
    ``lengths`` whose lower corner is ``lower``, written in the plane z = 0 of a cell of thickness 1
    (``pbc`` false along z, ``Origin`` at z = -0.5); ``columns`` name -> (N,) or (N, k) per-disk
    values, integers kept as such, floats with 17 significant digits."""
    n = positions.shape[0]
    lattice = f"{lengths[0]:.17g} 0 0 0 {lengths[1]:.17g} 0 0 0 1"
    pbc = " ".join("T" if p else "F" for p in periodic) + " F"
    table = [np.column_stack([positions, np.zeros(n)])]
    properties = ["pos:R:3"]
    formats = ["%.17g"] * 3
    for name, values in columns.items():
        values = np.asarray(values).reshape(n, -1)
        integer = np.issubdtype(values.dtype, np.integer)
        properties.append(f"{name}:{'I' if integer else 'R'}:{values.shape[1]}")
        formats += ["%d" if integer else "%.17g"] * values.shape[1]
        table.append(values)
    extra = " ".join(f"{key}={value}" for key, value in info.items())
    origin = f"{lower[0]:.17g} {lower[1]:.17g} -0.5"
    f.write(f'{n}\nLattice="{lattice}" Origin="{origin}" pbc="{pbc}" Properties={":".join(properties)} {extra}\n')
    np.savetxt(f, np.column_stack(table) if n else np.zeros((0, len(formats))), fmt=formats)
