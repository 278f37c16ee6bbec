"""330 seeded mutations of GranLab's own run files (a finished run and one interrupted half-way:
flipped bits, zeroed pages, truncations; frame and checkpoint datasets deleted, swapped, retyped or
reshaped, a declared shape of 10^9 rows among them; NaN, inf, 1e300, -1 and 0 written into frames and
into each of the checkpoint's datasets; attributes deleted or retyped, JSON parameters broken, the
stored scene and the checkpoint's valid record damaged) read by ``granlab run --resume``, ``info``,
``analyze``, ``export`` and ``render`` (:mod:`tests.run_fuzz`).

Each must end within its deadline, under its memory limit, with exit status 0 or 2 and no traceback;
a refusal (status 2) is exactly one line on standard error, ``granlab COMMAND: error: ...``; a resume
that succeeds wrote only finite positions and velocities (it did not step on from NaN, inf or 1e300);
and no command leaves a hidden ``.part`` file behind."""

import json
import subprocess
import sys
from pathlib import Path

from tests import run_fuzz

PROGRESS = ("exporting frame ", "rendering frame ", "running: step ")


def test_mutated_run_files_end_in_one_line_or_a_sound_result(tmp_path):
    process = subprocess.run([sys.executable, "-m", "tests.run_fuzz", str(tmp_path), "--cases", str(run_fuzz.CASES)],
                             capture_output=True, text=True, timeout=600, cwd=Path(__file__).parent.parent)
    assert process.returncode == 0, process.stderr
    results = [json.loads(line) for line in process.stdout.splitlines()]
    assert len(results) == run_fuzz.CASES >= 200

    def said(r):  # standard error but for the progress lines printed before the damage was met
        return [line for line in r["stderr"] if not line.startswith(PROGRESS)]

    def brief(r):
        return r["name"], r["what"], r["code"], r["stderr"][-3:]

    assert not [brief(r) for r in results if r["traceback"]]
    assert not [brief(r) for r in results if r["hang"]]
    assert not [brief(r) for r in results if r["memory"]]
    assert not [brief(r) for r in results if r["code"] not in (0, 2)]
    # the command's name as the user typed it: a resume is ``granlab run``
    wrong = [brief(r) for r in results if r["code"] == 2 and (len(said(r)) != 1 or not said(r)[0].startswith(
        f"granlab {'run' if r['command'] == 'resume' else r['command']}: error: "))]
    assert not wrong
    assert not [brief(r) for r in results if r.get("sound") is False]  # a resume from NaN, inf or 1e300
    assert not [(r["name"], r["parts"]) for r in results if r["parts"]]
