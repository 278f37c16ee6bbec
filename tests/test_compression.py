"""`granlab prepare` says how its compression is getting on."""

import json
import re
import subprocess
import sys


def test_prepare_reports_progress_on_stderr_and_keeps_stdout_for_the_result(tmp_path):
    out = tmp_path / "box.h5"
    process = subprocess.run([sys.executable, "-m", "engine.cli", "prepare", "--method", "compress", "--particles",
                              "256", "--out", str(out), "--json"], capture_output=True, text=True, timeout=600)
    assert process.returncode == 0, process.stderr
    result = json.loads(process.stdout)
    assert result["equilibrated"] and result["wall_time_s"] > 2.0
    line = re.compile(r"compressing: t = ([\d.]+), pressure [\d.]+ of P0, kinetic energy \S+, "
                      r"(force|moment|pressure|kinetic) \S+x its equilibrium tolerance, (\d+) s")
    reports = [line.fullmatch(text) for text in process.stderr.splitlines()]
    assert reports and all(reports), process.stderr
    times = [float(report[1]) for report in reports]
    assert times == sorted(times) and times[-1] <= result["sim_time"]
    assert len(reports) <= result["wall_time_s"] + 1  # about once a second, not more
