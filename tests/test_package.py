"""GranLab installs as one import name, ``granlab``, and its wheel works without the checkout."""

import email
import json
import os
import re
import subprocess
import sys
import urllib.request
import zipfile
from pathlib import Path

import pytest
from packaging.specifiers import SpecifierSet

import granlab
import granlab.api
from granlab.app.lab.server import endpoint, spawn

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("panel", "bokeh", "matplotlib", "viser", "tornado")
SCENE = """title = "A wheel's first run"
[simulation]
steps = 400
record_every = 100
[contact]
normal_stiffness = 1.0e3
friction = 0.3
[cell]
lengths = [12.0, 12.0]
[[particles.gas]]
count = 30
radius = 0.8
velocity_spread = 1.0
seed = 1
"""


def loaded(statement: str, cwd: Path) -> set[str]:
    """The top-level modules a fresh interpreter holds after ``statement``."""
    code = f"{statement}\nimport sys, json\nprint(json.dumps(sorted({{m.split('.')[0] for m in sys.modules}})))"
    process = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=cwd, check=True)
    return set(json.loads(process.stdout))


def test_installed_under_one_name_and_lab_libraries_loaded_only_when_used(tmp_path):
    """``engine`` and ``app`` are not names in site-packages; ``import granlab`` and the engine
    bring none of the lab's or the figures' libraries (they took 3.6-4.6 s of import before)."""
    outside = loaded("import granlab", tmp_path)
    assert "granlab" in outside and not outside & {"engine", "app", "numba", *HEAVY}
    engine = loaded("import granlab.engine, granlab.engine.analysis.report", tmp_path)
    assert not engine & set(HEAVY), engine & set(HEAVY)
    commands = loaded("import granlab.app.commands", tmp_path)  # the parser: every command's options
    assert not commands & {"numba", *HEAVY}, commands & {"numba", *HEAVY}
    for name in ("engine", "app"):
        probe = subprocess.run([sys.executable, "-c", f"import {name}"], capture_output=True, text=True, cwd=tmp_path)
        assert probe.returncode == 1 and f"No module named '{name}'" in probe.stderr
    assert "panel" in loaded("import granlab\ngranlab.lab", tmp_path)


def test_every_public_name_resolves_from_where_it_is_listed():
    assert set(granlab.api.__all__) <= set(granlab.__all__)
    assert set(granlab.__all__) - set(granlab.api.__all__) == {
        "EXPORT_FORMATS", "NotebookLab", "analysis_figure", "force_network_figure", "lab", "show", "strain_figure"}
    for name in granlab.__all__:
        assert getattr(granlab, name) is not None, name
    assert set(granlab.__all__) <= set(dir(granlab))


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    """The wheel built from the checkout (with its sdist)."""
    dist = tmp_path_factory.mktemp("dist")
    subprocess.run([sys.executable, "-m", "build", "--outdir", str(dist), str(ROOT)], check=True,
                   capture_output=True, timeout=900)
    wheels = sorted(dist.glob("granlab-*.whl"))
    assert len(wheels) == 1 and len(sorted(dist.glob("granlab-*.tar.gz"))) == 1
    return wheels[0]


def test_the_wheel_says_its_license_its_types_and_the_pythons_it_runs_on(wheel):
    with zipfile.ZipFile(wheel) as archive:
        files = set(archive.namelist())
        metadata = email.message_from_bytes(archive.read(next(name for name in files if name.endswith("/METADATA"))))
    assert "granlab/py.typed" in files and any(name.endswith("licenses/LICENSE") for name in files)
    assert metadata["License-Expression"] == "MIT"
    admitted = SpecifierSet(metadata["Requires-Python"])
    assert all(version in admitted for version in ("3.11", "3.12", "3.13", "3.14"))


@pytest.mark.parametrize("python", ["3.12", "3.13"])
def test_pip_resolves_the_wheel_and_every_dependency_as_built_wheels_for_newer_pythons(wheel, python, tmp_path):
    """What these machines cannot run is checked with pip's resolver: each dependency of the wheel
    exists as a binary wheel for that Python (nothing to compile on a newcomer's machine)."""
    report = tmp_path / "report.json"
    subprocess.run([sys.executable, "-m", "pip", "install", "--dry-run", "--quiet", "--ignore-installed",
                    "--only-binary=:all:", "--python-version", python, "--target", str(tmp_path / "target"),
                    "--report", str(report), str(wheel)], check=True, capture_output=True, timeout=600)
    installed = {item["metadata"]["name"].lower(): item for item in json.loads(report.read_text())["install"]}
    assert {"granlab", "numba", "llvmlite", "numpy", "scipy", "h5py", "panel", "bokeh", "viser"} <= set(installed)
    tag = f"cp{python.replace('.', '')}"
    assert tag in installed["numba"]["download_info"]["url"], installed["numba"]["download_info"]["url"]


def test_the_wheel_installed_in_a_clean_environment_runs_serves_exports_and_analyses(wheel, tmp_path, monkeypatch):
    """The wheel installed in a virtual environment of its own and used from a folder outside the
    checkout: nothing may come from the repository."""
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    bin_dir = venv / "bin"
    # --no-compile: pip would byte-compile every module of every dependency (35-45 s of the install's
    # 75-90 s here); Python compiles those it imports, once
    subprocess.run([bin_dir / "python", "-m", "pip", "install", "--quiet", "--no-compile", wheel], check=True,
                   capture_output=True, timeout=1800)
    work = tmp_path / "work"
    work.mkdir()
    # as on a newcomer's machine: the modules imported are byte-compiled once, then read compiled
    monkeypatch.delenv("PYTHONDONTWRITEBYTECODE", raising=False)
    env = {**os.environ, "PYTHONPATH": ""}

    def granlab_cli(*args: str) -> subprocess.CompletedProcess:
        process = subprocess.run([bin_dir / "granlab", *args], capture_output=True, text=True, cwd=work, env=env,
                                 timeout=900)
        assert process.returncode == 0, (args, process.stderr)
        return process

    assert granlab_cli("--version").stdout.strip() == f"granlab {granlab.__version__}"
    where = subprocess.run([bin_dir / "python", "-c", "import granlab.engine; print(granlab.engine.__file__)"],
                           capture_output=True, text=True, cwd=work, env=env, check=True).stdout
    assert Path(where).is_relative_to(venv)
    (work / "gas.toml").write_text(SCENE)
    run = json.loads(granlab_cli("run", "gas.toml", "--out", "gas.h5", "--json").stdout)
    assert run["steps"] == 400
    granlab_cli("export", "gas.h5", "--format", "xyz", "--out", "gas.xyz")
    assert (work / "gas.xyz").read_text().count("Lattice=") == 5
    packing = json.loads(granlab_cli("analyze", "gas.h5", "packing", "--json").stdout)
    assert packing["analysis"] == "packing" and packing["particles"] == 30
    teaching = subprocess.run([bin_dir / "python", "-c", "from granlab.app.lab.dashboard import STATIC, teaching_text\n"
                               "print(STATIC.resolve(), teaching_text('ratchet16'), sep='\\n')"],
                              capture_output=True, text=True, cwd=work, env=env, check=True).stdout
    static, text = teaching.split("\n", 1)
    assert Path(static).is_relative_to(venv)
    assert text.strip() == (ROOT / "static" / "teaching" / "ratchet16.md").read_text().strip()
    process, url, _ = spawn(work / "data", timeout=900, program=(str(bin_dir / "granlab"),), cwd=work)
    try:
        with urllib.request.urlopen(url, timeout=60) as response:
            page = response.read().decode()
        files = re.findall(r'(?:src|href)="(static/[^"?]+)', page)
        assert len(files) >= 5, page
        for file in files:  # the page's scripts and stylesheets, from the installed package
            with urllib.request.urlopen(endpoint(url, file), timeout=60) as response:
                assert response.status == 200 and response.read(), file
        with urllib.request.urlopen(endpoint(url, "scene"), timeout=60) as response:
            scene = json.loads(response.read())
        assert scene["disks"] > 0 and scene["frames"] >= 1
    finally:
        process.kill()
        process.wait()
