"""`granlab export`: a run file's frames for ParaView (vtk), OVITO (xyz, lammps) and MDAnalysis
(h5md), read back by those tools' own readers (VTK's XML reader, OVITO's importer, MDAnalysis's
H5MD reader) and by GranLab's, and compared with the run file."""

import functools
import json
import pkgutil
import signal
import subprocess
import sys
import xml.etree.ElementTree as ElementTree

import numpy as np
import pytest

import granlab.engine.io.export as export_package
from granlab.app.commands import build_parser
from granlab.engine import ContactLaw, Integration, ParticleState, PeriodicCell, Simulation
from granlab.engine.analysis import stiffness as st
from granlab.engine.analysis.packing import packing_stats
from granlab.engine.analysis.rigidity import rigidity
from granlab.engine.analysis.states import read_state
from granlab.engine.errors import ParameterError
from granlab.engine.frames import FrameData, build_frame
from granlab.engine.generate import radii, random_gas
from granlab.engine.io import h5md
from granlab.engine.io.export import EXPORT_FORMATS, contacts_dump_name, export_run

FRAMES = 3


def granlab(*args, check=True):
    """The ``granlab`` command (with the lab's commands) in a process of its own."""
    process = subprocess.run([sys.executable, "-m", "granlab.app.commands", *args], capture_output=True, text=True,
                             timeout=600)
    if check and process.returncode != 0:
        raise AssertionError(process.stderr)
    return process


@functools.cache
def compressed_run(folder):
    """A periodic cell of 80 frictional disks compressed at a constant strain rate into a contact
    network with sticking and sliding contacts (no damping: F_n is the elastic force), 3 frames."""
    r = radii(80, radius_min=0.4, radius_max=0.6, distribution="uniform", seed=3)
    positions = random_gas(r, (0, 12.0, 0, 12.0), periodic=(True, True), seed=3)
    law = ContactLaw(normal_stiffness=1e3, tangential_stiffness=800.0, friction=0.3)
    sim = Simulation(ParticleState(positions, r), law, Integration(dt_safety=0.2),
                     cell=PeriodicCell((12.0, 12.0), control=("strain-rate", "strain-rate"), strain_rate=(0.02, 0.02)))
    sim.run(8500)
    path = folder / "compressed.h5"
    with h5md.RunWriter(path, sim) as writer:
        for _ in range(FRAMES):
            sim.run(300)
            writer.write_frame(sim)
    return path


@pytest.fixture(scope="module")
def run_file(tmp_path_factory):
    return compressed_run(tmp_path_factory.mktemp("export"))


def frames_of(path):
    with h5md.open_run(path) as f:
        return [h5md.read_frame(f, k) for k in range(h5md.frame_count(f))]


def vtu_arrays(path):
    """Points, cell point ids and every named array of a .vtu, read by VTK's own XML reader."""
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkIOXML import vtkXMLUnstructuredGridReader

    reader = vtkXMLUnstructuredGridReader()
    reader.SetFileName(str(path))
    reader.Update()
    assert reader.GetErrorCode() == 0
    grid = reader.GetOutput()
    arrays = {"points": vtk_to_numpy(grid.GetPoints().GetData()) if grid.GetNumberOfPoints() else np.zeros((0, 3)),
              "cells": [[grid.GetCell(c).GetPointId(k) for k in range(grid.GetCell(c).GetNumberOfPoints())]
                        for c in range(grid.GetNumberOfCells())],
              "types": [grid.GetCellType(c) for c in range(grid.GetNumberOfCells())]}
    for data in (grid.GetPointData(), grid.GetCellData(), grid.GetFieldData()):
        for k in range(data.GetNumberOfArrays()):
            arrays[data.GetArrayName(k)] = vtk_to_numpy(data.GetAbstractArray(k))
    return arrays


def test_vtk_export_is_a_pvd_time_series_of_disks_force_network_and_cell(run_file, tmp_path):
    out = tmp_path / "paraview"
    process = granlab("export", str(run_file), "--format", "vtk", "--out", str(out), "--json")
    result = json.loads(process.stdout)
    assert result["frames"] == FRAMES and len(result["files"]) == 1 + 3 * FRAMES
    # progress on standard error, a line a second at most and the last: the --json output stays one object
    assert process.stderr.splitlines() == ["exporting frame 0 of 3", "exporting frame 3 of 3"]
    collection = ElementTree.parse(out / "compressed.pvd").getroot()
    assert collection.get("type") == "Collection"
    entries = collection.findall("Collection/DataSet")
    assert len(entries) == 3 * FRAMES
    for raw in frames_of(run_file):
        parts = {int(e.get("part")): out / e.get("file") for e in entries if float(e.get("timestep")) == raw["time"]}
        assert sorted(parts) == [0, 1, 2]
        scene = build_frame([(FrameData.from_run_frame(raw, np.zeros((0, 2))), (0.0, 0.0))])
        disks = vtu_arrays(parts[0])
        n = raw["position"].shape[0]
        np.testing.assert_array_equal(disks["points"][:, :2], raw["position"])
        np.testing.assert_array_equal(disks["points"][:, 2], 0.0)
        assert set(disks["types"]) == {1} and len(disks["types"]) == n  # one vertex per disk
        for name in ("radius", "omega", "angle", "mass", "coordination", "pressure"):
            np.testing.assert_array_equal(disks[name], raw[name] if name in raw else getattr(scene, name))
        np.testing.assert_array_equal(disks["velocity"][:, :2], raw["velocity"])
        np.testing.assert_array_equal(disks["sliding"], scene.sliding)
        assert disks["TimeValue"][0] == raw["time"] and disks["step"][0] == raw["step"]
        network = vtu_arrays(parts[1])
        c = raw["contacts"]
        assert len(network["types"]) == c["status"].size > 100 and set(network["types"]) == {3}  # lines
        for name in ("normal_force", "tangential_force", "status", "tangential_spring", "surface_gap"):
            np.testing.assert_array_equal(network[name], c[name])
        np.testing.assert_array_equal(network["i"], c["pair"][:, 0])
        ends = network["points"][np.array(network["cells"])]
        np.testing.assert_array_equal(ends[:, 0, :2], raw["position"][c["pair"][:, 0]])
        length = np.hypot(*(ends[:, 0, :2] - ends[:, 1, :2]).T)  # to j's nearest image, not across the cell
        assert np.all(length <= 1.0001 * (raw["radius"][c["pair"][:, 0]] + raw["radius"][c["pair"][:, 1]]))
        assert {2, 3} & set(c["status"]) and 1 in c["status"]  # sliding and sticking contacts are in the file
        cell = vtu_arrays(parts[2])
        assert len(cell["types"]) == 4 and set(cell["kind"]) == {1}
        np.testing.assert_allclose(cell["points"][:, :2].max(axis=0), raw["edges"])


def test_xyz_export_is_read_by_ase_and_by_ovito_with_radii_and_the_periodic_cell(run_file, tmp_path):
    out = tmp_path / "run.xyz"
    granlab("export", str(run_file), "--format", "xyz", "--out", str(out))
    raws = frames_of(run_file)
    for k, raw in enumerate(raws):
        state = read_state(out, frame=k)
        np.testing.assert_array_equal(state.radii, raw["radius"])
        np.testing.assert_allclose(state.positions, raw["position"], rtol=0, atol=1e-12)
        np.testing.assert_array_equal(state.box_lengths, raw["edges"])
        assert state.periodic == (True, True) and state.time == raw["time"] and state.step == raw["step"]
    ovito_io = pytest.importorskip("ovito.io")
    pipeline = ovito_io.import_file(str(out))
    assert pipeline.source.num_frames == FRAMES
    data = pipeline.compute(FRAMES - 1)
    np.testing.assert_allclose(np.asarray(data.particles["Radius"]), raws[-1]["radius"], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(data.particles["Position"])[:, :2], raws[-1]["position"], rtol=1e-12)
    np.testing.assert_allclose(np.asarray(data.particles["Velocity"])[:, :2], raws[-1]["velocity"], rtol=1e-12)
    np.testing.assert_allclose(np.diag(np.asarray(data.cell)[:2, :2]), raws[-1]["edges"], rtol=1e-12)
    assert tuple(data.cell.pbc) == (True, True, False)


def test_lammps_export_reads_back_with_its_contacts_as_the_run_file_does(run_file, tmp_path):
    """The dump and its dump local give `granlab analyze` the same packing as the run file: the same
    contacts with the same forces, statuses and springs, z, Phi and rigidity counts."""
    out = tmp_path / "run.dump"
    granlab("export", str(run_file), "--format", "lammps", "--out", str(out))
    law = {"friction": 0.3, "normal_stiffness": 1e3, "tangential_stiffness": 800.0}
    for frame in range(FRAMES):
        original = read_state(run_file, frame=frame)
        exported = read_state(out, frame=frame, law=law, contacts=contacts_dump_name(out))
        assert exported.forces_known and exported.step == original.step
        np.testing.assert_allclose(exported.positions, original.positions, rtol=0, atol=1e-12)
        a, b = original.contacts, exported.contacts
        order_a, order_b = np.lexsort((a.j, a.i)), np.lexsort((b.j, b.i))
        for name in ("i", "j", "image", "status"):
            np.testing.assert_array_equal(getattr(b, name)[order_b], getattr(a, name)[order_a], err_msg=name)
        for name in ("normal_force", "tangential_force", "tangential_spring", "surface_gap"):
            np.testing.assert_allclose(getattr(b, name)[order_b], getattr(a, name)[order_a], rtol=1e-9, atol=1e-12,
                                       err_msg=name)
        ours, theirs = packing_stats(original), packing_stats(exported)
        assert (theirs.z, theirs.phi, theirs.rattlers) == (ours.z, ours.phi, ours.rattlers)
        raw = frames_of(run_file)[frame]
        kinetic = np.diag(np.sum(raw["mass"][:, None] * raw["velocity"] ** 2, axis=0)) / np.prod(raw["edges"])
        np.testing.assert_allclose(exported.stress + kinetic, original.stress, rtol=1e-9)  # contacts + kinetic
        counts = [rigidity(st.network(s)) for s in (original, exported)]
        assert counts[0] == counts[1]
    ovito_io = pytest.importorskip("ovito.io")
    data = ovito_io.import_file(str(out)).compute(FRAMES - 1)
    raw = frames_of(run_file)[-1]
    np.testing.assert_allclose(np.asarray(data.particles["Radius"]), raw["radius"], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(data.particles["Angular Velocity"])[:, 2], raw["omega"], rtol=1e-12)


def test_h5md_export_is_read_by_mdanalysis_in_a_3d_box(run_file, tmp_path):
    mda = pytest.importorskip("MDAnalysis")
    out = tmp_path / "run.h5md"
    granlab("export", str(run_file), "--format", "h5md", "--out", str(out))
    raws = frames_of(run_file)
    universe = mda.Universe(str(out), n_atoms=raws[0]["position"].shape[0], convert_units=False)
    assert universe.trajectory.n_frames == FRAMES
    for ts, raw in zip(universe.trajectory, raws):
        np.testing.assert_allclose(universe.atoms.positions[:, :2], raw["position"], rtol=1e-6, atol=1e-5)
        np.testing.assert_array_equal(universe.atoms.positions[:, 2], 0.0)
        np.testing.assert_allclose(universe.atoms.velocities[:, :2], raw["velocity"], rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(ts.dimensions, [*raw["edges"], 2 * raw["radius"].max(), 90, 90, 90], rtol=1e-6)
        assert ts.time == pytest.approx(raw["time"])
    state = read_state(out)
    np.testing.assert_array_equal(state.positions, raws[-1]["position"])
    assert state.periodic == (True, True) and packing_stats(state).z == packing_stats(read_state(run_file)).z


def test_the_format_registry_is_the_one_list_of_formats(tmp_path, capsys):
    """Every format is one module of the export package and one entry of EXPORT_FORMATS, from which the
    command's --format choices, the --out suffix checks and the errors naming the formats are read."""
    modules = {f"{export_package.__name__}.{module.name}" for module in pkgutil.iter_modules(export_package.__path__)
               if module.name != "writing"}  # the work every format shares
    assert {fmt.module for fmt in EXPORT_FORMATS.values()} == modules
    for name, fmt in EXPORT_FORMATS.items():
        writer = fmt.writer()
        assert fmt.name == name and fmt.title and callable(writer.files) and callable(writer.write), name
        if fmt.suffix:
            with pytest.raises(ParameterError, match=f"a file name ending in {fmt.suffix} for --format {name}"):
                export_run(tmp_path / "run.h5", name, tmp_path / "frames.wrong")
    commands = next(action for action in build_parser()._actions if action.dest == "command")
    option = next(action for action in commands.choices["export"]._actions if action.dest == "format")
    assert list(option.choices) == list(EXPORT_FORMATS)
    assert all(f"{name} ({fmt.title})" in option.help for name, fmt in EXPORT_FORMATS.items())
    with pytest.raises(ParameterError) as refused:
        export_run(tmp_path / "run.h5", "pdb", tmp_path / "frames.pdb")
    assert str(refused.value).endswith("one of " + ", ".join(EXPORT_FORMATS))
    with pytest.raises(SystemExit):
        build_parser().parse_args(["export", "run.h5", "--format", "pdb", "--out", "frames.pdb"])
    assert "(choose from " + ", ".join(map(repr, EXPORT_FORMATS)) + ")" in capsys.readouterr().err


def test_bad_exports_get_one_line_and_exit_2(run_file, tmp_path):
    (tmp_path / "taken.xyz").write_text("mine")
    cases = [(("--format", "pdb", "--out", str(tmp_path / "x.pdb")), "--format: invalid choice: 'pdb'"),
             (("--format", "xyz", "--out", str(tmp_path / "x.dump")), "a file name ending in .xyz"),
             (("--format", "vtk", "--out", str(tmp_path / "x.pvd")), "a folder (a name without a suffix) for --format"),
             (("--format", "xyz", "--out", str(tmp_path / "taken.xyz")), "exists: give --force"),
             (("--format", "xyz", "--out", str(tmp_path / "x.xyz"), "--frames", "7"), "--frames = '7' is not allowed")]
    for args, message in cases:
        process = granlab("export", str(run_file), *args, check=False)
        assert process.returncode == 2 and message in process.stderr, (args, process.stderr)
        assert process.stderr.count("\n") == 1, process.stderr
    assert (tmp_path / "taken.xyz").read_text() == "mine"
    lammps_dump = tmp_path / "other.dump"
    lammps_dump.write_text("ITEM: TIMESTEP\n0\n")
    process = granlab("export", str(lammps_dump), "--format", "xyz", "--out", str(tmp_path / "y.xyz"), check=False)
    assert process.returncode == 2 and "is not a readable HDF5 file" in process.stderr


STALLED = """
import sys, time
from granlab.engine.io import h5md
read = h5md.read_frame
def stalled(f, index):
    if index > 0:
        print("stalled", flush=True)
        time.sleep(600)
    return read(f, index)
h5md.read_frame = stalled
from granlab.app.commands import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.parametrize("command, out, written", [
    (("export", "--format", "vtk"), "paraview", ["paraview"]),
    (("export", "--format", "xyz"), "frames.xyz", ["frames.xyz"]),
    (("export", "--format", "lammps"), "frames.dump", ["frames.dump", "frames-contacts.dump"]),
    (("export", "--format", "h5md"), "frames.h5md", ["frames.h5md"]),
    (("render",), "movie.gif", ["movie.gif"]),
    (("render",), "still.png", ["still_00000.png", "still_00001.png", "still_00002.png"]),
])
def test_a_killed_export_or_render_leaves_nothing_under_its_names_and_its_rerun_is_not_refused(
        run_file, tmp_path, command, out, written):
    args = [command[0], str(run_file), *command[1:], "--out", str(tmp_path / out), "--frames", ":"]
    process = subprocess.Popen([sys.executable, "-c", STALLED, *args], stdout=subprocess.PIPE, text=True)
    try:
        assert process.stdout.readline() == "stalled\n"  # its first frame written, the second never comes
        process.kill()
        process.wait(timeout=30)
    finally:
        process.kill()
    assert not any((tmp_path / name).exists() for name in written)
    assert len(list(tmp_path.glob(".*.part"))) <= 1  # what the killed command was writing, if it had begun
    granlab(*args)
    assert all((tmp_path / name).exists() for name in written)
    assert not list(tmp_path.glob(".*.part"))  # its writer dead, the rerun removed it
    if command[0] == "export" and command[-1] == "vtk":
        assert len(list((tmp_path / "paraview").iterdir())) == 1 + 3 * FRAMES


@pytest.mark.parametrize("stop, code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
@pytest.mark.parametrize("command, out", [(("export", "--format", "vtk"), "paraview"), (("export", "--format", "xyz"),
                                                                                       "frames.xyz")])
def test_a_command_stopped_by_sigterm_or_ctrl_c_removes_its_part_files_at_once_and_says_so(
        run_file, tmp_path, command, out, stop, code):
    """Before: SIGTERM left the hidden ``.NAME.*.part`` folder, which later exports never removed."""
    args = [command[0], str(run_file), *command[1:], "--out", str(tmp_path / out), "--frames", ":"]
    process = subprocess.Popen([sys.executable, "-c", STALLED, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True)
    try:
        assert process.stdout.readline() == "stalled\n"
        process.send_signal(stop)
        _, stderr = process.communicate(timeout=30)
    finally:
        process.kill()
    assert process.returncode == code
    assert stderr.splitlines()[-1] == f"granlab {command[0]}: stopped by {'SIGTERM' if code == 143 else 'Ctrl-C'}"
    assert "Traceback" not in stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def _small_file_limit():
    import resource

    resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))


@pytest.mark.parametrize("command, out", [
    (("export", "--format", "vtk"), "paraview"), (("export", "--format", "xyz"), "frames.xyz"),
    (("export", "--format", "lammps"), "frames.dump"), (("export", "--format", "h5md"), "frames.h5md"),
    (("render",), "movie.gif"), (("render",), "movie.mp4"), (("render",), "still.png")])
def test_an_export_or_render_that_runs_out_of_room_says_so_in_one_line_and_leaves_nothing(
        run_file, tmp_path, command, out):
    """Under a file size limit as on a full disk (a real full tmpfs gave tracebacks, exit 1; the
    h5md export a segfault after 265 KB of them; the mp4 a broken file and exit 0)."""
    process = subprocess.run([sys.executable, "-m", "granlab.app.commands", command[0], str(run_file), *command[1:], "--out",
                              str(tmp_path / out), "--frames", ":"], capture_output=True, text=True, timeout=600,
                             preexec_fn=_small_file_limit)
    lines = [line for line in process.stderr.splitlines() if not line.startswith(("rendering frame", "exporting frame"))]
    assert process.returncode == 2 and len(lines) == 1, process.stderr
    assert "File too large" in lines[0] or "ulimit -f" in lines[0] or "is the disk full" in lines[0], lines
    assert sorted(p.name for p in tmp_path.iterdir()) == []
