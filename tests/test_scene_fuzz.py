"""Scene files with every key of every section set to NaN, -1, 0, 1e308, inf, a string, a boolean,
an empty array or a table, and scenes of absurd size (10¹² disks, 10⁹ gas disks, 10¹⁸ steps, a
time step that underflows), nested thousands deep, with duplicate keys or bytes that are not
UTF-8, and files that are empty, a folder, a FIFO or a link to /dev/zero, run by ``granlab run
SCENE --out RUN.h5`` (:mod:`tests.scene_fuzz`). Each ends within its deadline, under its memory
limit, without a traceback, in exit 0 or 2. A refusal (2) is one line, ``granlab run: error: ``
naming the key at fault (or the file), said before any work; a run that ends (0) says nothing of
nan, inf or 0 steps and writes finite positions."""

import json
import subprocess
import sys
from pathlib import Path


def test_abused_scene_files_end_in_one_line_naming_the_key_or_a_sound_run(tmp_path):
    process = subprocess.run([sys.executable, "-m", "tests.scene_fuzz", str(tmp_path)],
                             capture_output=True, text=True, timeout=900, cwd=Path(__file__).parent.parent)
    assert process.returncode == 0, process.stderr
    results = [json.loads(line) for line in process.stdout.splitlines()]
    assert len(results) >= 150
    broken = [(r["name"], r["code"], r["stderr"][-3:]) for r in results if r["traceback"] or r["code"] not in (0, 2)]
    assert not broken, broken
    hangs = [(r["name"], r["stderr"][-1:]) for r in results if r["hang"]]
    assert not hangs, hangs
    memory = [(r["name"], r["peak_mib"], r["stderr"][-1:]) for r in results if r["memory"]]
    assert not memory, memory
    refusals = [r for r in results if r["code"] == 2]
    unnamed = [(r["name"], r["stderr"]) for r in refusals
               if not (r["named"] and r["stderr"][0].startswith("granlab run: error: "))]
    assert not unnamed, unnamed
    nonsense = [(r["name"], r["stderr"][-2:]) for r in results if r["code"] == 0 and r["nonsense"]]
    assert not nonsense, nonsense
