"""Seeded mutations of GranLab's own run files (``granlab run SCENE --out FILE.h5``) handed to every
command that reads one: ``run --resume``, ``info``, ``analyze``, ``export`` and ``render``, each in a
child process with a memory limit and a deadline, as :mod:`tests.foreign_fuzz` does for other codes'
files.

Two small runs are the base: one run to its end, one interrupted half-way (its resume steps on).
A case flips bits, zeroes a page or cuts the file short; deletes, swaps, retypes or reshapes a
dataset of the frames or of the checkpoint; writes NaN, inf, 1e300, -1 or 0 into them; deletes or
retypes an attribute; damages the stored scene or the checkpoint's ``valid`` record.

``python -m tests.run_fuzz FOLDER [--cases N] [--seed S]`` writes each case into a folder of its own
and prints one JSON line per case: its name, kind, command, what was mutated, exit code, seconds,
stderr lines, whether stderr holds a traceback, whether it ran out of memory, for a resume that
exited 0 whether every position and velocity it wrote is finite, and the hidden ``.part`` files
left in its folder."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import h5py
import numpy as np

from tests import forked

DEADLINE = 20.0

SCENE = """title = "fuzz: 30 disks settle in a box"
simulation = {steps = 600, dt_safety = 0.3, gravity = [0.0, -1.0], record_every = 50}
contact = {normal_stiffness = 1.0e3, tangential_stiffness = 1.0e3, friction = 0.5, damping_ratio = 0.5}
box = {x = [0.0, 6.0], y = [0.0, 6.0]}
particles = {gas = [{count = 30, radius_min = 0.35, radius_max = 0.5, velocity_spread = 0.5, seed = 1}]}
"""

WEIRD = (np.nan, np.inf, -np.inf, 1e300, -1.0, 0.0)
P = "particles/all"
FRAME_DATASETS = (f"{P}/position/value", f"{P}/position/step", f"{P}/position/time", f"{P}/velocity/value",
                  f"{P}/radius/value", f"{P}/box/edges/value", f"{P}/mass/value", f"{P}/kind", "contacts/offset",
                  "contacts/pair", "parameters/scene")
DROPPED = FRAME_DATASETS + (f"{P}/position", f"{P}/box/edges", f"{P}/box", "checkpoint/valid", "checkpoint")
VALUED = (f"{P}/position/value", f"{P}/velocity/value", f"{P}/radius/value", f"{P}/box/edges/value")
# "@" stands for the checkpoint's valid slot
SWAPS = ((f"{P}/position/value", f"{P}/velocity/value"), (f"{P}/position/value", f"{P}/radius/value"),
         (f"{P}/position/step", f"{P}/position/time"), (f"{P}/box/edges/value", f"{P}/position/value"),
         ("contacts/offset", "contacts/pair"), ("@particles/position", "@particles/radius"),
         ("@particles/position", "@particles/velocity"), ("@contacts/particle_i", "@contacts/particle_j"),
         ("@particles/mass", "@particles/inv_mass"), ("@step", "@dt"), ("@particles/kind", "@contacts/status"),
         ("@walls/normal", "@walls/offset"), ("checkpoint/slot0", "checkpoint/slot1"))
ATTRIBUTES = (("h5md", "version"), ("h5md/creator", "version"), (f"{P}/box", "boundary"), (f"{P}/box", "dimension"),
              ("observables/energy", "fields"), ("contacts", "status_names"),
              *(("parameters", name) for name in ("law_json", "integration_json", "walls_json", "cell_json",
                                                   "protocol_json", "gravity", "dt", "skin")))
SCENES = ("", "[[[ not toml", SCENE.replace("steps = 600", "steps = -1"), SCENE.replace("steps = 600", 'steps = "many"'),
          SCENE.replace("record_every = 50", "record_every = 0"), SCENE.replace("count = 30", "count = 5"),
          SCENE.replace("dt_safety = 0.3", "dt_safety = nan"), SCENE.replace("steps = 600", "steps = 100"),
          b"\xff\xfe title", 7, "attribute")
VALID = ([-1, -1], [2, 600], [-7, 0], [0, 0], [1, -1], [1, 10 ** 12], [b"1", b"600"], 1, [0, 600, 1], [0.5, 600.0])

FILE_COMMANDS = ("resume", "info", "analyze", "resume", "export", "render")
CHECKPOINT_COMMANDS = ("resume", "resume", "info")
KINDS = {"flip": FILE_COMMANDS, "page": FILE_COMMANDS, "truncate": FILE_COMMANDS, "drop": FILE_COMMANDS,
         "swap": FILE_COMMANDS, "retype": FILE_COMMANDS, "shape": FILE_COMMANDS, "value": FILE_COMMANDS,
         "attribute": FILE_COMMANDS, "scene": CHECKPOINT_COMMANDS, "valid": CHECKPOINT_COMMANDS,
         "checkpoint-retype": CHECKPOINT_COMMANDS, "checkpoint-shape": CHECKPOINT_COMMANDS,
         "checkpoint-drop": ("resume",), "checkpoint-value": ("resume",)}
SCHEDULE = (*KINDS, *["checkpoint-drop", "checkpoint-value"] * 3)
"""The kind of case k is SCHEDULE[k % len]: deleting one of the checkpoint's 60 datasets, and
writing a weird value into one, come round often enough to take each in turn within 330 cases
(the first 220 reach those of its cell, contacts and particles)."""
CASES = 330


def make_bases(folder: Path) -> dict[str, Path]:
    """The run to its end and the run interrupted at half its steps, a frame and a checkpoint
    every 50 steps (this loads the kernels every case then finds loaded)."""
    from granlab.app.commands.run import run_scene

    scene = folder / "scene.toml"
    scene.write_text(SCENE)
    bases = {"done": folder / "done.h5", "cut": folder / "cut.h5"}
    run_scene(str(scene), out=str(bases["done"]), frame_every=50, checkpoint_frames=1)

    def interrupt(done, total, sim):
        if done >= total // 2:
            raise KeyboardInterrupt

    try:
        run_scene(str(scene), out=str(bases["cut"]), frame_every=50, checkpoint_frames=1, progress=interrupt)
    except KeyboardInterrupt:
        pass
    return bases


def _slot(f, name: str) -> str:
    """A path, "@" standing for the checkpoint's valid slot."""
    return name.replace("@", f"checkpoint/slot{int(f['checkpoint/valid'][0])}/")


def checkpoint_names(path: Path) -> list[str]:
    names = []
    with h5py.File(path, "r") as f:
        f[_slot(f, "@")].visititems(lambda name, item: names.append("@" + name) if isinstance(item, h5py.Dataset)
                                    else None)
    return sorted(names)


def _pick(rng, items):
    return items[int(rng.integers(len(items)))]


def _replace(f, path: str, data) -> None:
    del f[path]
    f.create_dataset(path, data=data)


def _drop(f, path: str, rng) -> str:
    del f[path]
    return f"deleted {path}"


def _write_weird(f, path: str, rng) -> str:
    """A weird value into one element, into one frame (of a frame's dataset; the last one half the
    time) or everywhere."""
    data = np.array(f[path][()])
    value = _pick(rng, WEIRD) if data.dtype.kind == "f" else \
        int(_pick(rng, [-1, 0, np.iinfo(data.dtype).max, np.iinfo(data.dtype).min]))
    where = _pick(rng, ["element", "all" if path.startswith("checkpoint") else "frame", "all"]) if data.ndim else "all"
    if where == "element":
        data[tuple(int(rng.integers(n)) for n in data.shape)] = value
    elif where == "frame":
        data[-1 if rng.random() < 0.5 else int(rng.integers(len(data)))] = value
    else:
        data[...] = value
    f[path][...] = data
    return f"{value} into {where} of {path}"


def _retype(f, path: str, rng) -> str:
    data = np.asarray(f[path][()])
    how = _pick(rng, ["number", "string", "compound", "scalar", "rank"])
    new = {"number": lambda: data.astype(np.int64) if data.dtype.kind == "f" else np.full(data.shape, 0.5),
           "string": lambda: np.full(data.shape, b"abc", dtype="S8"),
           "compound": lambda: np.zeros(data.shape, dtype=[("x", "f8"), ("n", "i4")]),
           "scalar": lambda: np.float64(1.0),
           "rank": lambda: data[..., None] if data.ndim < 2 else data.reshape(-1)}[how]()
    _replace(f, path, new)
    return f"{path} as {how} {new.dtype}{new.shape}"


def _reshape(f, path: str, rng) -> str:
    data = np.asarray(f[path][()])
    data = np.stack([data, data]) if data.ndim == 0 else data
    how = _pick(rng, ["extra row", "missing row", "last dimension", "huge"])
    if how == "huge":  # a declared shape of 10^9 rows: nothing of it is stored
        del f[path]
        f.create_dataset(path, data=data, maxshape=(None,) + data.shape[1:], chunks=True).resize(10 ** 9, axis=0)
        return f"{path} declared {(10 ** 9,) + data.shape[1:]}"
    new = {"extra row": lambda: np.concatenate([data, data[-1:]]), "missing row": lambda: data[:-1],
           "last dimension": lambda: np.concatenate([data, data[..., -1:]], axis=-1) if data.ndim > 1
           else np.stack([data] * 3, axis=-1)}[how]()
    _replace(f, path, new)
    return f"{path} {how}: {new.shape}"


OPERATIONS = {"drop": (_drop, DROPPED), "retype": (_retype, FRAME_DATASETS),
              "shape": (_reshape, FRAME_DATASETS[:-1]), "value": (_write_weird, VALUED)}
"""What each kind does, and to which of the frames' datasets (a checkpoint-KIND to the checkpoint's)."""


def _json_mutation(text: str, rng) -> str:
    """One value of a JSON record made weird (a frame_every of -1, say), or JSON that is not one."""
    value = json.loads(text)
    record = value[0] if isinstance(value, list) and value else value
    if not isinstance(record, dict) or not record or rng.random() < 0.3:
        return _pick(rng, ["", "{", "null", "[]", "{}"])
    record[_pick(rng, sorted(record))] = _pick(rng, [-1, "ten", None, 1e300, [], 0])
    return json.dumps(value)


def _attribute(f, rng) -> str:
    path, name = _pick(rng, ATTRIBUTES)
    attrs = f[path].attrs
    how = _pick(rng, ["delete", "number", "negative", "string", "json" if name.endswith("_json") else "nan"])
    if how == "delete":
        del attrs[name]
    elif how == "json":
        attrs[name] = _json_mutation(attrs[name], rng)
    else:
        attrs[name] = {"number": 7, "negative": -1, "string": "abc", "nan": np.array([np.nan, np.inf])}[how]
    return f"{path}.attrs[{name}] {how}: {attrs.get(name)!r}"[:200]


def _mutate(f, kind: str, rng, turn: int, checkpoint: list[str]) -> str:
    """Mutate the open file ``f`` by ``kind``; ``turn`` counts the cases of that kind, so that each
    of the checkpoint's datasets is deleted, and written into, in turn."""
    if kind == "swap":
        a, b = (_slot(f, name) for name in _pick(rng, SWAPS))
        f.move(a, a + "~")
        f.move(b, a)
        f.move(a + "~", b)
        return f"swapped {a} and {b}"
    if kind == "attribute":
        return _attribute(f, rng)
    if kind == "scene":
        text = _pick(rng, SCENES)
        if text == "attribute":  # the scene text as an attribute rather than a dataset
            del f["parameters/scene"]
            f["parameters"].attrs["scene"] = SCENE
        else:
            _replace(f, "parameters/scene", text)
        return f"scene {text!r}"[:120]
    if kind == "valid":
        valid = _pick(rng, VALID)
        _replace(f, "checkpoint/valid", np.asarray(valid))
        return f"checkpoint/valid {valid!r}"
    operation, targets = OPERATIONS[kind.removeprefix("checkpoint-")]
    if kind in ("checkpoint-drop", "checkpoint-value"):
        return operation(f, _slot(f, checkpoint[turn % len(checkpoint)]), rng)
    if kind.startswith("checkpoint"):
        return operation(f, _slot(f, _pick(rng, checkpoint)), rng)
    return operation(f, _pick(rng, targets), rng)


def _mutate_bytes(raw: bytes, kind: str, rng) -> tuple[bytes, str]:
    """Flipped bits and zeroed pages where the file holds something (most of it is empty room)."""
    data = bytearray(raw)
    if kind == "truncate":
        size = int(rng.integers(len(data)))
        return bytes(data[:size]), f"cut at {size} of {len(data)} bytes"
    written = np.flatnonzero(np.frombuffer(raw, dtype=np.uint8))
    if kind == "flip":
        offsets = sorted(int(_pick(rng, written)) for _ in range(int(rng.integers(1, 20))))
        for offset in offsets:
            data[offset] ^= 1 << int(rng.integers(8))
        return bytes(data), f"bits flipped at {offsets}"
    start = int(_pick(rng, written)) // 4096 * 4096
    data[start:start + 4096] = bytes(len(data[start:start + 4096]))
    return bytes(data), f"page at {start} zeroed"


def make_cases(folder: Path, rng, count: int) -> list[dict]:
    from granlab.engine.io.export import EXPORT_FORMATS

    bases = make_bases(folder)
    raw = {name: path.read_bytes() for name, path in bases.items()}
    checkpoint = checkpoint_names(bases["done"])
    turns = dict.fromkeys(KINDS, 0)
    cases = []
    for k in range(count):
        kind = SCHEDULE[k % len(SCHEDULE)]
        turn = turns[kind]
        turns[kind] += 1
        command = KINDS[kind][turn % len(KINDS[kind])]
        base = _pick(rng, ("cut", "done"))
        name = f"{k:03d}-{kind}-{command}"
        home = folder / name
        home.mkdir()
        path = home / "run.h5"
        if kind in ("flip", "page", "truncate"):
            data, what = _mutate_bytes(raw[base], kind, rng)
            path.write_bytes(data)
        else:
            path.write_bytes(raw[base])
            with h5py.File(path, "r+") as f:
                what = _mutate(f, kind, rng, turn, checkpoint)
        fmt = EXPORT_FORMATS[list(EXPORT_FORMATS)[turn % len(EXPORT_FORMATS)]]
        args = {"resume": ["run", "--resume", str(path), "--out", str(home / "out.h5")], "info": ["info", str(path)],
                "analyze": ["analyze", str(path), "packing", "--json"],
                "export": ["export", str(path), "--format", fmt.name, "--out", str(home / f"export{fmt.suffix}")],
                "render": ["render", str(path), "--out", str(home / "picture.png"), "--size", "480x270"]}[command]
        cases.append({"name": name, "kind": kind, "command": command, "base": base, "what": what, "args": args})
    return cases


def _sound(path: Path) -> bool:
    """Whether every position and velocity of a resumed run's frames is finite."""
    try:
        with h5py.File(path, "r") as f:
            return all(np.isfinite(f[f"{P}/{name}/value"][()]).all() for name in ("position", "velocity"))
    except (OSError, KeyError):
        return False


def run_case(case: dict, folder: Path) -> dict:
    """``granlab ARGS`` in a forked child (:mod:`tests.forked`)."""
    from granlab.app.commands import main

    home = folder / case["name"]
    out, err = home / "stdout", home / "stderr"
    code, seconds = forked.run(main, case["args"], out, err, DEADLINE)
    stderr = err.read_text(errors="replace")
    result = {key: case[key] for key in ("name", "kind", "command", "base", "what")}
    result.update(code=code, seconds=seconds, stderr=stderr.splitlines(),
                  traceback="Traceback" in stderr, hang=code is None,
                  memory=any(word in stderr for word in ("MemoryError", "Unable to allocate", "bad_alloc")),
                  parts=sorted(str(p.relative_to(home)) for p in home.rglob(".*") if ".part" in p.name))
    if code == 0 and case["command"] == "resume":
        result["sound"] = _sound(home / "out.h5")
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("folder", type=Path)
    parser.add_argument("--cases", type=int, default=CASES)
    parser.add_argument("--seed", type=int, default=29)
    args = parser.parse_args(argv)
    args.folder.mkdir(parents=True, exist_ok=True)
    # what the commands import, imported once here rather than in every child
    import granlab.app.media.render  # noqa: F401
    import granlab.engine.analysis.report  # noqa: F401
    from granlab.engine.io.export import EXPORT_FORMATS

    for fmt in EXPORT_FORMATS.values():
        fmt.writer()
    for case in make_cases(args.folder, np.random.default_rng(args.seed), args.cases):
        print(json.dumps(run_case(case, args.folder)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
