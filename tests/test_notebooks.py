"""The notebooks of docs/notebooks run top to bottom in a fresh kernel (nbclient), and show what
their text says."""

import json
import shutil
from pathlib import Path

import pytest

nbclient = pytest.importorskip("nbclient")
nbformat = pytest.importorskip("nbformat")

NOTEBOOKS = Path(__file__).resolve().parents[1] / "docs" / "notebooks"


def execute(name: str, folder: Path):
    """Run a copy of notebook ``name`` in ``folder`` (its data folder goes there); the executed notebook."""
    shutil.copy(NOTEBOOKS / name, folder / name)
    notebook = nbformat.read(folder / name, as_version=4)
    nbclient.NotebookClient(notebook, timeout=600, kernel_name="python3",
                            resources={"metadata": {"path": str(folder)}}).execute()
    return notebook


def text_of(cell) -> str:
    return "".join(output.get("text", "") + "".join(output.get("data", {}).get("text/html", ""))
                   for output in cell.get("outputs", []))


def test_ratcheting_in_30_lines_shows_the_three_springs_and_the_live_lab(tmp_path):
    notebook = execute("ratcheting-in-30-lines.ipynb", tmp_path)
    code = [cell for cell in notebook.cells if cell.cell_type == "code"]
    assert sum(len(cell.source.splitlines()) for cell in code) <= 30
    printed = text_of(code[0])
    assert "cundall-strack: strain per cycle +5.11e-08" in printed and "ratcheting: True" in printed
    assert printed.splitlines()[2].strip().startswith("angle") and printed.splitlines()[2].endswith("ratcheting: False")
    assert any("application/vnd.bokehjs_exec.v0+json" in output.get("data", {}) for output in code[1].outputs)
    assert "<iframe src=\"http://127.0.0.1:" in text_of(code[2])
    assert text_of(code[3]).startswith("waiting at http://127.0.0.1:")  # the lab waits for its page to open


def test_analyse_a_lammps_packing_reads_lammps_forces_and_runs_every_analysis(tmp_path):
    notebook = execute("analyse-a-lammps-packing.ipynb", tmp_path)
    outputs = "".join(text_of(cell) for cell in notebook.cells if cell.cell_type == "code")
    assert "200 disks, 413 contacts, periodic (True, True)" in outputs
    for label in ("Solid fraction Φ", "Null modes of k", "Critical contacts M_c", "Degree of hyperstaticity H"):
        assert label in outputs
    figure = json.dumps(notebook.cells[-1].outputs)  # the bokeh document goes in the cell's script
    assert "LAMMPS's force network" in figure and "non-sliding contact" in figure
