"""``granlab export``: frames of a GranLab run file for the tools people already use.

One module of this package per format (its files and its writer; what the files hold is in its
docstring) and one entry of :data:`EXPORT_FORMATS`, which the command's ``--format``, the checks
of ``--out`` and ``granlab.export`` all read: adding a format is a module, an entry and its docs.
GranLab's units are the user's, so no file claims a unit.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType


@dataclass(frozen=True)
class ExportFormat:
    """A format of ``granlab export``: its ``--format`` name; the module writing it, loaded on first
    use (so that listing the formats costs nothing), which defines ``files(out, stem, indices)``
    (what it writes) and ``write(frames, out, stem, indices)`` (the frames as :class:`.writing._Frame`), and
    may define ``check_room(run, out, indices)`` (called before anything is written) and
    ``read_run(run, indices)`` (what it needs of the run file beyond its frames, given to ``write``
    as ``run=``); what it is, in a line; the suffix of its ``--out`` file, "" for a folder."""

    name: str
    module: str
    title: str
    suffix: str

    def writer(self) -> ModuleType:
        return importlib.import_module(self.module)


EXPORT_FORMATS = {fmt.name: fmt for fmt in (
    ExportFormat("vtk", f"{__name__}.vtk", "ParaView: a folder of .pvd and .vtu files", ""),
    ExportFormat("xyz", f"{__name__}.xyz", "OVITO, ASE: extended XYZ", ".xyz"),
    ExportFormat("lammps", f"{__name__}.lammps", "LAMMPS, OVITO: a dump custom and a dump local of the contacts",
                 ".dump"),
    ExportFormat("h5md", f"{__name__}.h5md", "MDAnalysis: H5MD in a 3D box", ".h5md"),
    ExportFormat("html", f"{__name__}.html", "a handout: one page replaying the run in a browser, offline", ".html"),
)}
"""Every format of ``granlab export`` by name (iterating gives the names)."""


def contacts_dump_name(out: Path) -> Path:
    """The ``dump local`` of the contacts written beside a LAMMPS dump ``out``."""
    return out.with_name(f"{out.stem}-contacts{out.suffix}")


def print_summary(result: dict) -> None:
    """What ``granlab export`` prints without ``--json``."""
    files = result["files"]
    first, last = result["indices"]
    frames = f"frame {first}" if result["frames"] == 1 else f"{result['frames']} frames ({first}..{last})"
    where = result["out"] if len(files) <= 2 else f"{result['out']} ({len(files)} files)"
    print(f"wrote {where}: {frames} of {result['run_file']} as {result['format']} in {result['seconds']:.2f} s")
    if result["format"] == "lammps":
        print(f"  contacts: {files[1]} (granlab analyze {files[0]} --contacts {files[1]})")


def __getattr__(name: str):
    """``export_run`` (:mod:`.writing`), imported on first use: listing the formats (the command
    line's ``--help``) reads no run file and draws nothing."""
    if name != "export_run":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from .writing import export_run

    return export_run
