"""Scene files as a careless or hostile user writes them, each run by ``granlab run SCENE --out
RUN.h5`` in a child process with a memory limit and a deadline.

Three small valid scenes (three disks; a 3 × 3 lattice in a box with a loaded lid and a loaded
piston; a gas of 20 disks in a periodic cell) have every key of every section, sections included,
replaced in turn by NaN, -1, 0, 1e308, inf, a string, a boolean, an empty array and a table. To
them come absurd sizes (lattices of 2000 × 2000 and 10⁶ × 10⁶ disks, 10⁹ gas disks, 10¹⁸ steps, a
frame a step of 10⁴ disks, stiffnesses that make the time step underflow or overflow), arrays and
tables nested thousands deep, duplicate keys, bytes that are not UTF-8, and files that are empty,
a folder, a FIFO or links to /dev/zero and to nothing.

``python -m tests.scene_fuzz FOLDER`` writes the cases into FOLDER and prints one JSON line per
case: its name, class, key and value; exit code (None: killed at the deadline), seconds, stderr
lines, peak memory; whether stderr holds a traceback or a memory error; for a refusal whether it
names the key, for a finished run whether what it printed or wrote is nonsense (nan, inf, 0 steps,
positions that are not finite)."""

from __future__ import annotations

import argparse
import copy
import json
import math
import os
import re
import sys
import time
from pathlib import Path

from tests import forked

DEADLINE = 20.0
"""A small scene runs in a fraction of a second; an absurd one should be refused before any work."""
WORKERS = 2
"""Cases run two at a time: on two cores the whole takes half as long."""

VALUES = {"nan": math.nan, "-1": -1, "0": 0, "1e308": 1e308, "inf": math.inf, "text": "abc", "bool": True,
          "empty-array": [], "table": {"a": 1}}
EXCLUSIVE = {"duration": ("steps",), "steps": ("duration",), "mass": ("density",), "density": ("mass",),
             "radius": ("radius_min", "radius_max"), "radius_min": ("radius",), "radius_max": ("radius",),
             "count": ("solid_fraction",), "solid_fraction": ("count",)}
"""Keys a key replaces, so that a case tests its value and not the clash of the two."""
PARTNERS = {"radius_min": ("radius_max", 0.45), "radius_max": ("radius_min", 0.3)}

SIMULATION = {"steps": 50, "dt_safety": 0.2, "skin": 0.1, "max_overlap": 0.5, "initial_overlap": 0.1,
              "gravity": [0.0, -1.0], "record_every": 10, "threads": 1}
"""One thread: the children are forked, and a pool of threads does not survive a fork."""
CONTACT = {"normal_stiffness": 1e3, "tangential_stiffness": 1e3, "friction": 0.5, "damping_ratio": 0.3,
           "tangential_damping": 0.0, "normal_model": "linear", "tangential_model": "cundall-strack",
           "cohesion_force": 0.0, "cohesion_range": 0.0, "rolling_stiffness": 0.0, "rolling_friction": 0.0,
           "rolling_damping_ratio": 0.0}
GROUP = {"seed": 1, "density": 1.0, "kind": "dynamic", "velocity": [0.0, 0.0]}
LOAD = {"base": 0.1, "amplitude": 0.05, "period": 1.0, "phase": 0.0}
BASES = {
    "disks": {"title": "fuzz: three disks", "simulation": SIMULATION, "contact": CONTACT, "particles": {
        "density": 1.0, "disk": [{"x": 0.0, "y": 0.5, "r": 0.5, "vx": 1.0, "vy": 0.0, "omega": 0.0, "angle": 0.0,
                                  "density": 1.0, "kind": "dynamic"},
                                 {"x": 1.2, "y": 0.5, "r": 0.5}, {"x": 2.4, "y": 0.5, "r": 0.5, "kind": "fixed"}]}},
    "box": {"simulation": SIMULATION, "contact": CONTACT,
            "box": {"x": [0.0, 5.0], "y": [0.0, 10.0], "wall_mass": 1.0, "loads": {"top": LOAD}},
            "walls": [{"name": "piston", "normal": [0.0, -1.0], "position": -8.0, "mode": "force", "velocity": 0.0,
                       "tangential_velocity": 0.0, "mass": 1.0, "load": LOAD, "load_per_length_of": ["left", "right"]}],
            "particles": {"lattice": [{"pattern": "square", "rows": 3, "columns": 3, "spacing": 1.0,
                                       "origin": [1.0, 1.0], "radius": 0.45, "velocity_spread": 0.0, **GROUP}]}},
    "cell": {"simulation": SIMULATION, "contact": CONTACT,
             "cell": {"lengths": [10.0, 10.0], "periodic": [True, True], "control": ["stress", "fixed"],
                      "stress": [0.1, 0.0], "strain_rate": [0.0, 0.0], "mass": 1.0, "max_strain_rate": 0.01},
             "particles": {"gas": [{"count": 20, "radius_min": 0.3, "radius_max": 0.5, "velocity_spread": 0.1,
                                    **GROUP}]}},
}


class Raw(str):
    """TOML text written as it is: nestings thousands deep, cheaper to spell than to build."""


def _value(v) -> str:
    if isinstance(v, Raw):
        return v
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float) and not math.isfinite(v):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(map(_value, v)) + "]"
    return "{" + ", ".join(f"{k} = {_value(x)}" for k, x in v.items()) + "}"


def toml(table: dict, prefix: str = "") -> str:
    """A scene as people write it: its values, then its tables as [sections] and arrays of
    tables as [[sections]] (their own tables inline)."""
    def section(v):
        return isinstance(v, dict) or (isinstance(v, list) and v and all(isinstance(e, dict) for e in v))

    lines = [f"{k} = {_value(v)}" for k, v in table.items() if not section(v)]
    for k, v in table.items():
        if isinstance(v, dict):
            lines += [f"\n[{prefix}{k}]", toml(v, f"{prefix}{k}.")]
        elif section(v):
            for entry in v:
                lines += [f"\n[[{prefix}{k}]]", *(f"{key} = {_value(x)}" for key, x in entry.items())]
    return "\n".join(lines)


def _where(path: tuple) -> str:
    """``("particles", "disk", 0)`` as the scene's messages write it: ``particles.disk[0]``."""
    text = ""
    for part in path:
        text += f"[{part}]" if isinstance(part, int) else (f".{part}" if text else part)
    return text


def _scene_with(base: str, path: tuple, key: str, value) -> dict:
    scene = copy.deepcopy(BASES[base])
    table = scene
    for part in path:
        table = table[part]
    for other in EXCLUSIVE.get(key, ()):
        table.pop(other, None)
    if key in PARTNERS:
        table.setdefault(*PARTNERS[key])
    table[key] = value
    return scene


def key_cases() -> list[dict]:
    """Every key of scene.py's sets (docs/scenes.md documents the same), each given each of VALUES."""
    from granlab.engine.io import scene

    targets = [("disks", (), scene.TOP_KEYS), ("disks", ("simulation",), scene.SIMULATION_KEYS),
               ("disks", ("contact",), scene.CONTACT_KEYS),
               ("disks", ("particles",), {"density", "disk", "lattice", "gas"}),
               ("disks", ("particles", "disk", 0), scene.DISK_KEYS), ("box", ("box",), scene.BOX_KEYS),
               ("box", ("box", "loads"), {"left", "right", "bottom", "top"}),
               ("box", ("box", "loads", "top"), scene.LOAD_KEYS), ("box", ("walls", 0), scene.WALL_KEYS),
               ("box", ("particles", "lattice", 0), scene.LATTICE_KEYS), ("cell", ("cell",), scene.CELL_KEYS),
               ("cell", ("particles", "gas", 0), scene.GAS_KEYS)]
    cases = []
    for base, path, keys in targets:
        for key in sorted(keys):
            where = f"{_where(path)}.{key}" if path else key
            for label, value in VALUES.items():
                cases.append({"name": f"{base}-{where}={label}", "class": "key", "keys": [where], "value": label,
                              "text": toml(_scene_with(base, path, key, value))})
    return cases


def special_cases(folder: Path) -> list[dict]:
    """Absurd sizes, deep nestings, broken bytes and files that are not files."""
    def case(kind, name, keys, value, base=None, path=(), key=None, text=None, label=None):
        if base is not None:
            scene = _scene_with(base, path, key, value) if key else BASES[base]
            text = toml(scene) if text is None else text(toml(scene))
        return {"name": f"{kind}-{name}", "class": kind, "keys": keys, "value": label or str(value), "text": text}

    sim, gas = ("simulation",), ("particles", "gas", 0)
    lattice = [case("size", f"lattice-{n}x{n}", ["particles.lattice[0]"], n, "box", text=_square(n))
               for n in (2000, 10 ** 6)]
    cases = lattice + [case("size", f"gas-count-{n}", ["particles.gas[0].count"], n, "cell", gas, "count")
                       for n in (10 ** 6, 10 ** 9)]
    cases += [case("size", "gas-fraction-0.9", ["particles.gas[0].solid_fraction"], 0.9, "cell", gas, "solid_fraction"),
              case("size", "steps-1e18", ["simulation.steps"], 10 ** 18, "disks", sim, "steps"),
              case("size", "duration-1e12", ["simulation.duration"], 1e12, "disks", sim, "duration"),
              case("size", "record_every-1e18", ["simulation.record_every"], 10 ** 18, "disks", sim, "record_every"),
              case("size", "frame-a-step-100x100", ["simulation.steps", "simulation.record_every"], 10 ** 6, "box", sim,
                   "steps", lambda t: _square(100)(t).replace("record_every = 10", "record_every = 1"))]
    # stiffnesses whose time step underflows (10^154 steps in one unit of time, or none) or overflows
    one = _edit(("steps = 50", "duration = 1.0"))
    for key, value in (("normal_stiffness", 1e308), ("normal_stiffness", 1e-308), ("tangential_stiffness", 1e308),
                       ("tangential_damping", 1e308), ("rolling_stiffness", 1e308)):
        cases.append(case("size", f"duration-1-{key}={value:g}", [f"contact.{key}", "simulation.duration"], value,
                          "disks", ("contact",), key, one))
    cases.append(case("size", "duration-1-dt=1e-300", ["simulation.dt", "simulation.duration"], 1e-300, "disks", sim,
                      "dt", one))
    grid = [{"x": 1.1 * (k % 150), "y": 1.1 * (k // 150), "r": 0.5} for k in range(20000)]
    cases += [case("size", "disks-20000", ["particles.disk"], grid, "disks", ("particles",), "disk",
                   _edit(("steps = 50", "steps = 5")), "20000 [[particles.disk]]"),
              case("size", "disks-2000-on-one-point", ["particles.disk", "particles"],
                   [{"x": 0.0, "y": 0.0, "r": 0.5}] * 2000, "disks", ("particles",), "disk",
                   label="2000 [[particles.disk]] at (0, 0)")]

    gravity = "gravity = [0.0, -1.0]"  # the disks scene's, replaced in its text
    for depth in (100, 5000):
        for name, value in (("array", "[" * depth + "]" * depth),
                            ("inline-table", "{a = " * depth + "1" + "}" * depth)):
            cases.append(case("nesting", f"{name}-{depth}", ["simulation.gravity"], None, "disks", text=_edit(
                (gravity, f"gravity = {value}")), label=f"{name} {depth} deep"))
    cases.append(case("nesting", "dotted-key-5000", ["simulation.gravity"], None, "disks",
                      text=_edit((gravity, "gravity" + ".a" * 5000 + " = 1")), label="gravity.a.a... 5000 deep"))

    text = toml(BASES["disks"])
    cases += [case("file", "duplicate-key", ["contact.normal_stiffness"], "twice",
                   text=text.replace("[contact]\n", "[contact]\nnormal_stiffness = 5.0\n")),
              case("file", "duplicate-table", ["simulation"], "twice", text=text + "\n[simulation]\nsteps = 10\n")]
    for name, data in (("non-utf8-title", text.encode().replace(b'title = "', b'title = "\xff\xfe')),
                       ("latin1-comment", b"# caf\xe9\n" + text.encode()), ("nul-byte", b"\x00" + text.encode()),
                       ("empty", b""), ("comment-only", b"# nothing here\n")):
        cases.append(case("file", name, None, name, text=data))
    for name, make in (("folder", lambda p: p.mkdir()), ("fifo", os.mkfifo),
                       ("dev-zero", lambda p: p.symlink_to("/dev/zero")),
                       ("dangling-link", lambda p: p.symlink_to(folder / "nowhere.toml"))):
        path = folder / f"file-{name}.toml"
        try:
            make(path)
        except OSError:
            continue  # a file system without FIFOs or links: that kind is skipped
        cases.append({"name": f"file-{name}", "class": "file", "keys": [str(path)], "value": name, "path": path})
    for c in cases:
        c["keys"] = c["keys"] or [str(folder / (c["name"] + ".toml"))]  # a file's refusal names the file
    return cases


def _edit(*pairs):
    """A scene's text with each ``(old, new)`` replaced: what a dict cannot hold, or a scene resized."""
    def edit(text: str) -> str:
        for old, new in pairs:
            assert old in text, old  # an edit that misses would test the unedited scene
            text = text.replace(old, new)
        return text
    return edit


def _square(n: int):
    """The box scene's lattice made n × n, its box and piston moved out of its way."""
    return _edit(("rows = 3", f"rows = {n}"), ("columns = 3", f"columns = {n}"),
                 ("x = [0.0, 5.0]", f"x = [0.0, {n + 2}.0]"), ("y = [0.0, 10.0]", f"y = [0.0, {2 * n}.0]"),
                 ("position = -8.0", f"position = -{1.5 * n}"))


def named(line: str, keys: list[str], name: str) -> bool:
    """A refusal names a key as scene.py writes it: by its dotted path (``simulation.duration =
    -1``), or by its section in brackets and its name (``[contact] friction = -0.3``). The case's
    own file name, which holds key and value, does not count unless the key is that file."""
    for key in keys:
        text = line if name in key else line.replace(name, "")
        section, _, leaf = key.rpartition(".")
        if key in text or (section and f"[{section}]" in text and re.search(rf"\b{re.escape(leaf)}\b", text)):
            return True
    return False


def _start(case: dict, folder: Path) -> int:
    """``granlab run SCENE --out RUN.h5`` in a forked child (:mod:`tests.forked`)."""
    from granlab.app.commands import main

    run = folder / (case["name"] + ".h5")
    run.unlink(missing_ok=True)
    return forked.start(main, ["run", str(case["path"]), "--out", str(run)], folder / (case["name"] + ".out"),
                        folder / (case["name"] + ".err"))


def _result(case: dict, folder: Path, code, seconds: float, usage) -> dict:
    # the case's name is in the paths a run prints (and holds "=inf"): it is not what the run says
    out = (folder / (case["name"] + ".out")).read_text(errors="replace").replace(case["name"], "")
    stderr = (folder / (case["name"] + ".err")).read_text(errors="replace")
    result = {key: case[key] for key in ("name", "class", "keys", "value")}
    result.update(code=code, seconds=round(seconds, 3), stderr=stderr.splitlines(), traceback="Traceback" in stderr,
                  hang=code is None, peak_mib=round(usage.ru_maxrss / 1024),
                  memory=bool(re.search(r"MemoryError|Unable to allocate|bad_alloc|Cannot allocate memory", stderr)))
    if code == 2:
        # a run that starts and diverges stops on the engine's own check, which names what happened
        result["named"] = len(result["stderr"]) == 1 and (named(result["stderr"][0], case["keys"], case["name"])
                                                          or DIVERGED.match(result["stderr"][0]) is not None)
    if code == 0:
        said = out + stderr.replace(case["name"], "")
        no_steps = case["keys"][0] in ("simulation.steps", "simulation.duration") and case["value"] == "0"
        result["nonsense"] = bool(re.search(r"\b(nan|inf)\b" + ("" if no_steps else r"|\b0 steps\b"), said,
                                            re.IGNORECASE)) or not _finite_run_file(folder / (case["name"] + ".h5"))
    return result


DIVERGED = re.compile(r"granlab run: error: run diverged at step \d+: ")


def _finite_run_file(path: Path) -> bool:
    import h5py
    import numpy as np

    with h5py.File(path, "r") as f:
        return bool(np.isfinite(f["particles/all/position/value"][...]).all())


def _warm(folder: Path) -> None:
    """Each base scene run here once: the kernels it loads, every child inherits."""
    from granlab.app.commands.run import run_scene

    for name, scene in BASES.items():
        path = folder / f"base-{name}.toml"
        path.write_text(toml(scene))
        (folder / f"base-{name}.h5").unlink(missing_ok=True)
        run_scene(str(path), str(folder / f"base-{name}.h5"))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("folder", type=Path)
    args = parser.parse_args(argv)
    args.folder.mkdir(parents=True, exist_ok=True)
    for stale in args.folder.glob("file-*.toml"):  # the special files of an earlier run
        if stale.is_dir() and not stale.is_symlink():
            stale.rmdir()
        else:
            stale.unlink()
    _warm(args.folder)
    cases = key_cases() + special_cases(args.folder)
    for case in cases:
        if "path" not in case:
            case["path"] = args.folder / (case["name"] + ".toml")
            data = case["text"]
            case["path"].write_bytes(data if isinstance(data, bytes) else data.encode())
    running = {}
    while cases or running:
        while cases and len(running) < WORKERS:
            case = cases.pop(0)
            running[_start(case, args.folder)] = (case, time.perf_counter())
        for pid, (case, start) in list(running.items()):
            done, code, usage = forked.ended(pid, start, DEADLINE)
            if done:
                del running[pid]
                print(json.dumps(_result(case, args.folder, code, time.perf_counter() - start, usage)), flush=True)
        time.sleep(0.005)
    return 0


if __name__ == "__main__":
    sys.exit(main())
