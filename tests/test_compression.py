"""The biaxial box's compression (ratcheting Sec. IV B 1) presses the lattice without hitting it,
and `granlab prepare` says how it is getting on."""

import json
import re
import subprocess
import sys

import pytest

from granlab.engine.protocols import prepare
from granlab.engine.protocols.equilibrium import measured_pressure

STRICT_OVERLAP = 0.15
"""Twice the largest overlap of a compressed box at rest (0.077 of a radius with 64 disks)."""


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_compression_overlaps_no_disk_much_deeper_than_at_rest(monkeypatch, capfd, seed):
    # walls as heavy as the packing pushed at P0 at once overlapped 64 disks by 0.27 of a radius
    # (5600 disks: by half a radius, a divergence); a run is stopped above STRICT_OVERLAP
    build = prepare.biaxial_box

    def strict_box(*args, **kwargs):
        sim = build(*args, **kwargs)
        sim.integration = sim.integration.replace(max_overlap=STRICT_OVERLAP)
        return sim

    monkeypatch.setattr(prepare, "biaxial_box", strict_box)
    prepared = prepare.compress(64, seed=seed)
    assert prepared.equilibrated
    assert measured_pressure(prepared.sim) == pytest.approx(1.0, abs=1e-4)
    assert capfd.readouterr() == ("", "")  # a library call reports nothing unless asked


def test_prepare_reports_progress_on_stderr_and_keeps_stdout_for_the_result(tmp_path):
    out = tmp_path / "box.h5"
    process = subprocess.run([sys.executable, "-m", "granlab.app.commands", "prepare", "--method", "compress",
                              "--particles", "400", "--out", str(out), "--json"], capture_output=True, text=True,
                             timeout=600)
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
