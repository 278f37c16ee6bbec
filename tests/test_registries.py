"""A registry is the one place a new part is named: an analysis registered at run time, and a
tangential model or a normal law added to a copy of the source as its module and one registry line,
are picked up by the command line (its choices, its text and ``--json``), the Python API, the
analyses and the lab."""

import json
import math
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import granlab
from granlab.app import commands as cli
from granlab.engine.analysis import ANALYSES, Analysis, register
from granlab.engine.io.h5md import RunWriter

from .conftest import periodic_gas
from .test_lab_engine import wait

LARGEST_DISK = '''
"""A test's analysis: the largest disk."""
from dataclasses import dataclass

import numpy as np

from granlab.engine.analysis.report import AnalysisReport

LABELS = {"disks": "Disks N", "largest_radius": "Radius of the largest disk [length]"}


@dataclass(frozen=True)
class Largest:
    index: int
    radius: float


def run(state, clock, load, seed):
    index = int(np.argmax(state.radii))
    clock.lap("largest")
    return AnalysisReport("largest", {"disks": state.disks, "largest_radius": float(state.radii[index])},
                          Largest(index, float(state.radii[index])))
'''


@pytest.fixture
def largest(tmp_path, monkeypatch):
    (tmp_path / "largest_disk.py").write_text(LARGEST_DISK)
    monkeypatch.syspath_prepend(str(tmp_path))
    register(Analysis("largest", "largest_disk", "the largest disk"))
    yield
    del ANALYSES["largest"]


def test_a_registered_analysis_reaches_the_command_line_its_json_the_api_and_the_lab(largest, tmp_path, capsys):
    from granlab.app.lab.analysis import summary
    from granlab.app.lab.engine_thread import LabEngine

    sim = periodic_gas(count=30, length=12.0)
    path = tmp_path / "gas.h5"
    with RunWriter(path, sim) as writer:
        writer.write_frame(sim)
    biggest = float(sim.particles.radius.max())
    assert "largest" in granlab.ANALYSES
    report = granlab.analyze(granlab.read(str(path)), "largest")
    assert report.result.radius == biggest and report.result.index == int(np.argmax(sim.particles.radius))

    assert cli.main(["analyze", str(path), "largest"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert any(line.startswith("  Radius of the largest disk [length]:") and f"{biggest:.4g}" in line
               for line in lines)
    assert cli.main(["analyze", str(path), "largest", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["analysis"] == "largest" and result["largest_radius"] == biggest and result["disks"] == 30
    assert set(result["timings_s"]) == {"largest", "total"}
    with pytest.raises(SystemExit):
        cli.main(["analyze", "--help"])
    assert "largest: the largest disk" in " ".join(capsys.readouterr().out.split())

    lab = LabEngine(tmp_path / "lab", preset="ratchet16", speed=math.inf)
    lab.start()
    try:
        wait(lambda: lab.status()["step"] > 0)
        lab.submit("analyze", kind="largest")
        found = wait(lambda: lab.analysis.latest() if lab.analysis.latest().seq == 1 else None)
    finally:
        lab.stop()
    assert found.error == "" and found.report.values["disks"] == 16
    assert "Radius of the largest disk [length]" in summary(found)


ONE_MORE_MODEL = ('    TangentialModel("twin", 4, "Cundall–Strack\'s twin (a test\'s)", "twin", False, True),\n')


def test_a_tangential_model_is_one_module_and_one_registry_line(tmp_path):
    """A copy of the installed source with one more model (its kernels a copy of Cundall–Strack's
    module, its line in ``params.TANGENTIAL``): the contact loop's list of models, the contact law,
    the lab's settings, its menu and legend colours, and the command line's choices take it."""
    import granlab.app
    import granlab.engine

    root = tmp_path / "granlab"
    app = Path(granlab.app.__file__).parent
    for name, source in (("", Path(granlab.__file__).parent), ("engine", Path(granlab.engine.__file__).parent),
                         ("app", app), ("static", app.parent / "static")):
        shutil.copytree(source, root / name, dirs_exist_ok=True, ignore=shutil.ignore_patterns("__pycache__"))
    kernels = root / "engine" / "kernels" / "tangential"
    shutil.copy(kernels / "cundall_strack.py", kernels / "twin.py")
    params = root / "engine" / "params.py"
    text = params.read_text()
    opening = "TANGENTIAL = {model.name: model for model in (\n"
    assert opening in text
    params.write_text(text.replace(opening, opening + ONE_MORE_MODEL))
    script = textwrap.dedent(f"""
        import granlab.engine
        assert granlab.engine.__file__.startswith({str(root)!r}), granlab.engine.__file__
        from granlab.engine import ContactLaw
        from granlab.engine.kernels.tangential import CODES
        from granlab.engine.params import TANGENTIAL_MODELS
        from granlab.engine.protocols.settings import LabSettings
        from granlab.app.lab import dashboard
        from granlab.app.lab.plots import MODEL_STYLES
        assert "twin" in TANGENTIAL_MODELS and CODES[-1] == 4
        assert ContactLaw(tangential_model="twin").tangential_model == "twin"
        assert LabSettings(tangential_model="twin").tangential_model == "twin"
        assert "twin" in dashboard.TANGENTIAL_MODELS and len(set(MODEL_STYLES.values())) == len(TANGENTIAL_MODELS)
    """)
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    subprocess.run([sys.executable, "-c", script], env=env, check=True, cwd=tmp_path, timeout=300)
    for command in (["experiment"], ["bench"], ["study", "ratchet"]):
        help_text = subprocess.run([sys.executable, "-m", "granlab.app.commands", *command, "--help"], env=env,
                                   cwd=tmp_path, capture_output=True, text=True, check=True, timeout=300).stdout
        assert "twin" in help_text.split("--model")[1], command


POWER_LAW = '''"""A test's normal law: N^e = K_n δ^(3/2) / √l, l = r_i + r_j (2 r_i for a wall)."""

import math

from ..jit import KERNEL, njit


@njit(**KERNEL)
def _length(ri, rj, is_wall):
    return 2.0 * ri if is_wall else ri + rj


@njit(**KERNEL)
def force(kn, overlap, ri, rj, is_wall):
    return kn * overlap * math.sqrt(overlap / _length(ri, rj, is_wall))


@njit(**KERNEL)
def energy(kn, overlap, ri, rj, is_wall):
    return 0.4 * overlap * force(kn, overlap, ri, rj, is_wall)


@njit(**KERNEL)
def stiffness(kn, overlap, ri, rj, is_wall):
    return 1.5 * kn * math.sqrt(overlap / _length(ri, rj, is_wall))
'''
ONE_MORE_LAW = '    NormalModel("power", 2, "N^e = K_n δ^(3/2) / √l (a test\'s)", "power 3/2"),\n'


def _copy_of_the_source(tmp_path) -> Path:
    import granlab.app
    import granlab.engine

    root = tmp_path / "granlab"
    app = Path(granlab.app.__file__).parent
    for name, source in (("", Path(granlab.__file__).parent), ("engine", Path(granlab.engine.__file__).parent),
                         ("app", app), ("static", app.parent / "static")):
        shutil.copytree(source, root / name, dirs_exist_ok=True, ignore=shutil.ignore_patterns("__pycache__"))
    return root


def test_a_normal_law_is_one_module_and_one_registry_line(tmp_path):
    """A copy of the source with one more normal law, N^e = K_n δ^(3/2)/√l (its module and its line
    in ``params.NORMAL``): the block of quasi-rigidity Fig. 2 settles on the overlap that law gives
    its weight and stores the law's energy; the stiffness matrix takes the law's tangent stiffness;
    the quasi-static stepper, lifting half the weight, ends on the law's overlap; the command line
    runs a scene of that law and names it among those allowed; the lab's settings and menu take it.
    Without its stiffness, the law does not register: the engine does not import, in one line."""
    root = _copy_of_the_source(tmp_path)
    (root / "engine" / "kernels" / "normal" / "power.py").write_text(POWER_LAW)
    params = root / "engine" / "params.py"
    opening = "NORMAL = {model.name: model for model in (\n"
    assert opening in params.read_text()
    params.write_text(params.read_text().replace(opening, opening + ONE_MORE_LAW))
    scene = tmp_path / "block_power.toml"
    block = (root / "engine" / "io" / "scenes" / "block.toml").read_text()
    scene.write_text(block.replace("[contact]\n", '[contact]\nnormal_model = "power"\n'))
    script = textwrap.dedent(f"""
        import math
        import granlab.engine
        assert granlab.engine.__file__.startswith({str(root)!r}), granlab.engine.__file__
        from granlab.engine.analysis import stiffness
        from granlab.engine.io.scene import load_scene
        from granlab.engine.params import NORMAL_MODELS
        from granlab.engine.protocols.quasistatic import Targets, follow
        from granlab.engine.protocols.settings import LabSettings
        from granlab.app.lab import dashboard

        kn, weight, r = 1.0e3, 1.0, 0.5
        def overlap(load):  # K_n δ^(3/2) / √(2r) = load
            return (load * math.sqrt(2 * r) / kn) ** (2 / 3)

        scene = load_scene({str(scene)!r})
        sim = scene.build()
        sim.run(scene.step_count(sim.dt))
        settled = overlap(weight)
        assert abs(r - sim.particles.position[0, 1] - settled) < 1e-6 * settled, sim.particles.position[0]
        snapshot = sim.snapshot()
        energy = sim.energy().normal_elastic
        assert abs(energy - 0.4 * settled * weight) < 1e-5 * energy, energy
        net = stiffness.network(snapshot)
        tangent = 1.5 * kn * math.sqrt((r - sim.particles.position[0, 1]) / (2 * r))
        assert abs(net.kn[0] - tangent) < 1e-9 * tangent, (net.kn, tangent)
        path = follow(sim, Targets(forces={{0: (0.0, 0.5 * weight)}}), steps=10)
        assert path.stop == "target", path.stop_detail
        lifted = r - path.positions[-1, 0, 1]
        assert abs(lifted - overlap(0.5 * weight)) < 1e-9 * lifted, (lifted, overlap(0.5 * weight))
        assert "power" in NORMAL_MODELS and "power" in dashboard.NORMAL_MODELS
        from granlab.engine.protocols.presets import make_preset, preset_settings
        preset = make_preset("ratchet16", preset_settings("ratchet16", normal_model="power"))
        preset.advance(200)
        assert preset.sim.law.normal_model == "power" and preset.sim.time > 0.0
        preset.apply(normal_model="linear")
        assert preset.sim.law.normal_model == "linear" and LabSettings(normal_model="power").normal_model == "power"
    """)
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    subprocess.run([sys.executable, "-c", script], env=env, check=True, cwd=tmp_path, timeout=300)
    run = subprocess.run([sys.executable, "-m", "granlab.app.commands", "quasistatic", str(scene), "--force", "0=0,0.5",
                          "--steps", "5"], env=env, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0 and "the target load is reached" in run.stdout, run.stdout + run.stderr
    scene.write_text(block.replace("[contact]\n", '[contact]\nnormal_model = "hooke"\n'))
    run = subprocess.run([sys.executable, "-m", "granlab.app.commands", "run", str(scene)], env=env, cwd=tmp_path,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 2 and "'linear', 'area', 'power'" in run.stderr.replace("'power', 'linear', 'area'",
                                                                                    "'linear', 'area', 'power'"), \
        run.stderr
    law = root / "engine" / "kernels" / "normal" / "power.py"
    law.write_text(law.read_text().split("@njit(**KERNEL)\ndef stiffness")[0])
    run = subprocess.run([sys.executable, "-m", "granlab.app.commands", "info", str(scene)], env=env, cwd=tmp_path,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 2 and len(run.stderr.strip().splitlines()) == 1, run.stderr
    assert "normal law 'power' does not register" in run.stderr and "has no stiffness" in run.stderr, run.stderr
