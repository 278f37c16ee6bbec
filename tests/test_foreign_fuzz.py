"""420 seeded mutations of valid foreign files (LAMMPS dump, its dump local, extended XYZ, H5MD:
truncations, flipped bytes, zeroed pages, deleted or repeated lines, swapped or renamed columns,
huge counts and shapes, datasets of another type or rank (a scalar position, a compound step), NaN, inf and huge values, negative radii, duplicate ids, junk) read by
``granlab analyze`` (:mod:`tests.foreign_fuzz`): each ends within its deadline in a one-line error
(exit 2) or a result, never in a traceback, a hang or a memory limit, and a result that is not a
packing is said not to be one (:mod:`granlab.engine.analysis.plausibility`). Before this check 31 of the
420 ended in a traceback (4 of them allocating 8.9 GiB for a declared shape) or printed warnings
before their message."""

import json
import subprocess
import sys
from pathlib import Path

from tests import foreign_fuzz


def test_mutated_foreign_files_end_in_one_line_or_a_result(tmp_path):
    process = subprocess.run([sys.executable, "-m", "tests.foreign_fuzz", str(tmp_path), "--cases", "420"],
                             capture_output=True, text=True, timeout=900, cwd=Path(__file__).parent.parent)
    assert process.returncode == 0, process.stderr
    results = [json.loads(line) for line in process.stdout.splitlines()]
    assert len(results) == 420
    failures = [(r["name"], r["code"], r["stderr"][-3:]) for r in results
                if r["code"] not in (0, 2) or r["traceback"] or (r["code"] == 2 and len(r["stderr"]) != 1)]
    assert not failures, failures
    assert max(r["seconds"] for r in results) < foreign_fuzz.DEADLINE / 4
    errors = [r for r in results if r["code"] == 2]
    assert all(line.startswith("granlab analyze: error: ") for r in errors for line in r["stderr"])
    assert 100 < len(errors) < 400  # the corpus both breaks files and leaves some readable
    read = [r for r in results if r["code"] == 0]
    assert all(line.startswith("granlab analyze: warning: ") for r in read for line in r["stderr"])
    # what reads is the packing (phi 0.841, z 3.6 in the unmutated files) or is said not to be one:
    # phi = 1.7e58 from a radius of 1e30, z = 28 from a zeroed page were shown without a word
    silent = [(r["name"], r["report"]["phi"], r["report"]["z"]) for r in read if not r["report"]["warnings"]
              and not (0.80 < r["report"]["phi"] < 0.87 and 3.0 < r["report"]["z"] < 4.5)]
    assert not silent, silent
    assert sum(bool(r["report"]["warnings"]) for r in read) >= 10
