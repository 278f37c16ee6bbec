"""What each command compiles on a first run: its wall time with an empty kernel cache and with the
cache it left, and the kernels' signatures it compiled (the table of docs/performance.md's "The
first run").

    python docs/compile_census.py [--repository PATH] [COMMAND ...]

Each command (default: the list below) runs twice in processes of their own, the first with an
empty cache folder; the signatures are the entries of the Numba indexes it left there (whichever
process compiled them). ``--repository`` runs another checkout's ``granlab`` (e.g. a worktree of
an older commit), for a before-and-after table in one sitting.
"""

from __future__ import annotations

import argparse
import os
import pickle
import subprocess
import sys
import tempfile
import time
from pathlib import Path

COMMANDS = (
    "experiment collision",
    "experiment closed-path --model all",
    "experiment block",
    "run",
    "prepare --method compress",
    "study ratchet --particles 16 --samples 1 --cycles 2 --workers 1",
    "bench --steps 100 --side 40",
)

def signatures(folder: Path) -> tuple[int, int]:
    """Signatures and kernels in the kernel cache ``folder``: the entries of every Numba index there
    (each compiled signature is saved, whichever process compiled it)."""
    entries = kernels = 0
    for index in folder.rglob("*.nbi"):
        with open(index, "rb") as handle:
            pickle.load(handle)  # Numba's version
            _, overloads = pickle.loads(handle.read())
        entries += len(overloads)
        kernels += bool(overloads)
    return entries, kernels


def importable(repository: Path, folder: Path) -> Path:
    """A folder from which ``import granlab`` imports ``repository``'s sources, laid out as installed."""
    package = folder / "granlab"
    package.mkdir()
    for source in (repository / "granlab").iterdir():
        (package / source.name).symlink_to(source.resolve())
    for name in ("engine", "app", "static"):
        (package / name).symlink_to((repository / name).resolve())
    return folder


def census(command: str, repository: Path | None) -> dict:
    with tempfile.TemporaryDirectory() as folder, tempfile.TemporaryDirectory() as sources:
        env = {**os.environ, "NUMBA_CACHE_DIR": folder, "GRANLAB_CACHE_DIR": folder}
        if repository is not None:
            env["PYTHONPATH"] = str(importable(repository, Path(sources)))
        walls = []
        for _ in range(2):  # the first run with an empty cache, the second with what it left
            start = time.perf_counter()
            done = subprocess.run([sys.executable, "-m", "granlab.app.commands", *command.split()], env=env, cwd=folder,
                                  capture_output=True, text=True)
            walls.append(time.perf_counter() - start)
            if done.returncode != 0:
                raise SystemExit(f"{command}: exit {done.returncode}:\n{done.stderr[-2000:]}")
        entries, kernels = signatures(Path(folder))
    return {"command": command, "first_s": walls[0], "next_s": walls[1], "signatures": entries, "kernels": kernels}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("commands", nargs="*", default=COMMANDS)
    parser.add_argument("--repository", type=Path, help="a checkout whose granlab to run (default: the installed one)")
    args = parser.parse_args()
    print("| command | first run, empty cache (s) | next run (s) | signatures compiled | kernels |")
    print("|---|---|---|---|---|")
    for command in args.commands:
        row = census(command, args.repository)
        print(f"| `granlab {row['command']}` | {row['first_s']:.0f} | {row['next_s']:.1f} | {row['signatures']} | "
              f"{row['kernels']} |", flush=True)


if __name__ == "__main__":
    main()
