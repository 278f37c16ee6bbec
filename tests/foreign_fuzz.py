"""Seeded mutations of valid foreign files (a LAMMPS dump with its ``dump local`` of contacts, an
extended XYZ file, an H5MD file) read by ``granlab analyze`` as a careless or hostile user would
hand them over, each in a child process with a memory limit and a deadline.

``python -m tests.foreign_fuzz FOLDER [--cases N] [--seed S]`` writes the cases into FOLDER and
prints one JSON line per case: its name, exit code, seconds, stderr lines and whether stderr holds
a traceback. The suite's test reads them; run by hand it shows what a change fixed."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import h5py
import numpy as np

from tests import forked

DATA = Path(__file__).parent / "data" / "lammps"
DEADLINE = 20.0

WEIRD_NUMBERS = ("nan", "inf", "-inf", "1e308", "-1", "0", "1e30", "-0", "abc", "")


def _lines(path: Path) -> list[str]:
    return path.read_text().splitlines(keepends=True)


def _mutate_text(lines: list[str], rng: np.random.Generator, kind: str) -> list[str]:
    lines = list(lines)
    k = int(rng.integers(len(lines)))
    if kind == "truncate":
        text = "".join(lines)
        return [text[:int(rng.integers(len(text)))]]
    if kind == "flip":
        text = bytearray("".join(lines).encode())
        for _ in range(int(rng.integers(1, 6))):
            text[int(rng.integers(len(text)))] = int(rng.integers(32, 127))
        return [text.decode()]
    if kind == "delete":
        del lines[k]
    elif kind == "duplicate":
        lines.insert(k, lines[k])
    elif kind == "junk":
        lines.insert(k, rng.choice(["\n", "ITEM: ATOMS\n", "1 2 3\n", "\x00\x01\x02\n", "# comment\n",
                                    "ITEM: NUMBER OF ATOMS\n1000000000000\n"]))
    elif kind == "number":
        words = lines[k].split()
        if words:
            words[int(rng.integers(len(words)))] = str(rng.choice(WEIRD_NUMBERS))
            lines[k] = " ".join(words) + "\n"
    elif kind == "column":
        # a value of every data line of one column made weird at once
        column = int(rng.integers(1, 8))
        value = str(rng.choice(WEIRD_NUMBERS))
        for m, line in enumerate(lines):
            words = line.split()
            if len(words) > column and _numbers(words):
                words[column] = value
                lines[m] = " ".join(words) + "\n"
    return lines


def _numbers(words: list[str]) -> bool:
    try:
        [float(w) for w in words]
    except ValueError:
        return False
    return True


def _dump_header_mutation(lines: list[str], rng: np.random.Generator) -> tuple[str, list[str]]:
    """Mutations a person makes of a dump's header: count, names of columns, their order."""
    lines = list(lines)
    heads = [m for m, line in enumerate(lines) if line.startswith("ITEM: NUMBER OF")]
    atoms = [m for m, line in enumerate(lines) if line.startswith("ITEM: ATOMS") or line.startswith("ITEM: ENTRIES")]
    kind = str(rng.choice(["count", "rename", "swap", "negative-radius", "duplicate-ids", "huge-radius"]))
    if kind == "count" and heads:
        m = heads[int(rng.integers(len(heads)))] + 1
        lines[m] = str(rng.choice(["1000000000000", "0", "-5", "201", "199", "1e3"])) + "\n"
    elif kind == "rename" and atoms:
        m = atoms[0]
        lines[m] = (lines[m].replace("radius", "diameter") if rng.random() < 0.5
                    else lines[m].replace(" x ", " xu ").replace(" y ", " q "))
    elif kind == "swap" and atoms:
        # the values of two columns exchanged under the header (x and radius, say)
        names = lines[atoms[0]].split()[2:]
        a, b = rng.choice(len(names), 2, replace=False)
        for block in atoms:
            m = block + 1
            while m < len(lines) and not lines[m].startswith("ITEM:"):
                words = lines[m].split()
                if len(words) == len(names):
                    words[a], words[b] = words[b], words[a]
                    lines[m] = " ".join(words) + "\n"
                m += 1
    elif kind in ("negative-radius", "huge-radius", "duplicate-ids") and atoms:
        names = lines[atoms[0]].split()[2:]
        column = names.index("radius") if kind != "duplicate-ids" and "radius" in names else 0
        value = {"negative-radius": "-0.5", "huge-radius": "1e30", "duplicate-ids": "7"}[kind]
        m = atoms[0] + 1 + int(rng.integers(5))
        words = lines[m].split()
        if len(words) > column:
            words[column] = value
            lines[m] = " ".join(words) + "\n"
    return kind, lines


def text_cases(folder: Path, rng: np.random.Generator, count: int) -> list[dict]:
    """Cases of the dump (with and without its contacts), the dump local, the XYZ file."""
    dump, local, xyz = _lines(DATA / "packing.dump"), _lines(DATA / "contacts.dump"), _lines(DATA / "packing.xyz")
    kinds = ("truncate", "flip", "delete", "duplicate", "junk", "number", "column", "header")
    cases = []
    for k in range(count):
        target = ("dump", "local", "xyz")[k % 3]
        kind = kinds[int(rng.integers(len(kinds)))]
        lines = {"dump": dump, "local": local, "xyz": xyz}[target]
        if kind == "header" and target != "xyz":
            kind, lines = _dump_header_mutation(lines, rng)
        elif kind == "header":
            lines = list(lines)
            lines[0 if rng.random() < 0.5 else 1] = str(rng.choice(["1000000000000\n", "-3\n", "0\n",
                                                                    'Lattice="0 0 0 0 0 0 0 0 0" pbc="T T F"\n',
                                                                    "Properties=id:I:1\n"]))
        else:
            lines = _mutate_text(lines, rng, kind)
        name = f"{k:03d}-{target}-{kind}"
        path = folder / (name + (".xyz" if target == "xyz" else ".dump"))
        path.write_text("".join(lines))
        if target == "dump":
            args = [str(path), "--contacts", str(DATA / "contacts.dump")]
        elif target == "local":
            args = [str(DATA / "packing.dump"), "--contacts", str(path)]
        else:
            args = [str(path)]
        cases.append({"name": name, "args": args})
    return cases


def _h5md_base(path: Path) -> None:
    """A small H5MD file as other codes write it: positions of the packing in a 3D box."""
    from granlab.engine.analysis.states import read_state
    from granlab.engine.io import h5md

    state = read_state(DATA / "packing.dump")
    n = state.disks
    with h5py.File(path, "w") as f:
        h5md.write_h5md_header(f, creator="fuzz")
        group = f.create_group("particles/all")
        box = group.create_group("box")
        box.attrs["dimension"] = 3
        box.attrs["boundary"] = np.array(["periodic", "periodic", "none"], dtype="S8")
        box.create_dataset("edges", data=np.array([*state.box_lengths, 1.0]))
        position = group.create_group("position")
        value = np.zeros((2, n, 3))
        value[:, :, :2] = state.positions
        position.create_dataset("value", data=value, maxshape=(None, None, 3), chunks=(1, n, 3))
        position.create_dataset("step", data=np.array([0, 1]))
        position.create_dataset("time", data=np.array([0.0, 1.0]))
        group.create_dataset("radius", data=state.radii)


def _retype(position: h5py.Group, rng: np.random.Generator) -> None:
    """One of the position element's datasets replaced by one of another type or rank."""
    name, data = [("value", 3.0), ("value", np.zeros(5)), ("step", np.array([(1, 2.0), (2, 3.0)], dtype="i4,f8")),
                  ("step", np.array([b"a", b"b"])), ("step", np.arange(7)), ("time", np.array([np.nan, 1.0])),
                  ("time", "now")][int(rng.integers(7))]
    del position[name]
    position.create_dataset(name, data=data)


def h5md_cases(folder: Path, rng: np.random.Generator, count: int) -> list[dict]:
    base = folder / "base.h5md"
    _h5md_base(base)
    raw = base.read_bytes()
    kinds = ("truncate", "flip", "page", "shape", "nan", "drop", "radius", "edges", "retype")
    cases = []
    for k in range(count):
        kind = kinds[k % len(kinds)]
        name = f"{k:03d}-h5md-{kind}"
        path = folder / (name + ".h5md")
        if kind in ("truncate", "flip", "page"):
            data = bytearray(raw)
            if kind == "truncate":
                data = data[:int(rng.integers(len(data)))]
            elif kind == "flip":
                for _ in range(int(rng.integers(1, 20))):
                    data[int(rng.integers(len(data)))] ^= 1 << int(rng.integers(8))
            else:
                start = int(rng.integers(len(data) // 4096)) * 4096
                data[start:start + 4096] = bytes(len(data[start:start + 4096]))
            path.write_bytes(bytes(data))
        else:
            path.write_bytes(raw)
            with h5py.File(path, "r+") as f:
                group = f["particles/all"]
                if kind == "shape":
                    group["position/value"].resize((2, int(rng.choice([4 * 10 ** 8, 10 ** 6, 201, 3])), 3))
                elif kind == "nan":
                    value = group["position/value"]
                    value[int(rng.integers(2)), int(rng.integers(200)), int(rng.integers(2))] = \
                        rng.choice([np.nan, np.inf, 1e308])
                elif kind == "retype":
                    _retype(group["position"], rng)
                elif kind == "drop":
                    del group[str(rng.choice(["radius", "box/edges", "position/value", "position"]))]
                elif kind == "radius":
                    radius = group["radius"]
                    radius[int(rng.integers(200))] = rng.choice([-1.0, 0.0, np.nan, 1e30])
                else:
                    f["particles/all/box/edges"][...] = rng.choice([[0.0, 0.0, 1.0], [np.inf, 1.0, 1.0],
                                                                    [-5.0, 13.0, 1.0], [1e-300, 1e-300, 1.0]])
        cases.append({"name": name, "args": [str(path)]})
    return cases


def run_case(case: dict, folder: Path) -> dict:
    """``granlab analyze ARGS packing --json`` in a forked child (:mod:`tests.forked`)."""
    from granlab.app.commands import main

    out, err = folder / (case["name"] + ".out"), folder / (case["name"] + ".err")
    code, seconds = forked.run(main, ["analyze", *case["args"], "packing", "--json"], out, err, DEADLINE)
    stderr = err.read_text(errors="replace")
    result = {"name": case["name"], "code": code, "seconds": seconds,
              "stderr": stderr.splitlines(), "traceback": "Traceback" in stderr}
    if code == 0:
        result["report"] = json.loads(out.read_text())
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("folder", type=Path)
    parser.add_argument("--cases", type=int, default=420)
    parser.add_argument("--seed", type=int, default=28)
    args = parser.parse_args(argv)
    args.folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(args.seed)
    text = args.cases * 3 // 4
    cases = text_cases(args.folder, rng, text) + h5md_cases(args.folder, rng, args.cases - text)
    for case in cases:
        print(json.dumps(run_case(case, args.folder)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
