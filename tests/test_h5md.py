"""Run files: H5MD layout, an independent reader, crashes, bit-identical resume, bad input."""

import json
import re
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from granlab.engine.io import h5md
from granlab.engine.io.scene import parse_scene

SCENE = """
title = "loaded box"
[simulation]
steps = 4000
gravity = [0.0, -1.0]
[contact]
normal_stiffness = 2e4
tangential_stiffness = 1.5e4
friction = 0.4
damping_ratio = 0.3
cohesion_force = 0.3
cohesion_range = 0.02
rolling_stiffness = 5.0
rolling_friction = 0.02
[box]
x = [0.0, 10.0]
y = [0.0, 25.0]
wall_mass = 4.0
[box.loads.top]
base = 2.0
amplitude = 1.0
period = 3.0
[[particles.gas]]
count = 60
radius_min = 0.35
radius_max = 0.5
region = [0.0, 10.0, 0.0, 20.0]
seed = 2
"""


def _sim():
    return parse_scene(SCENE).build()


def test_layout_follows_h5md_and_a_plain_h5py_reader_rebuilds_the_state(tmp_path):
    sim = _sim()
    path = tmp_path / "run.h5"
    with h5md.RunWriter(path, sim, scene=SCENE, protocol={"test": True}, watch=[(0, 1)]) as writer:
        for _ in range(3):
            sim.run(500)
            writer.write_frame(sim)
            writer.write_contact_sample(sim)
        writer.write_checkpoint(sim)
    snap = sim.snapshot()
    # an independent reader: only h5py and the documented layout
    with h5py.File(path, "r", libver="latest", swmr=True) as f:
        assert list(f["h5md"].attrs["version"]) == [1, 1]
        assert f["h5md/creator"].attrs["name"] == "GranLab"
        assert "name" in f["h5md/author"].attrs
        box = f["particles/all/box"]
        assert box.attrs["dimension"] == 2
        assert [b.decode() for b in box.attrs["boundary"]] == ["none", "none"]
        for name in ("position", "velocity", "angle", "omega", "radius", "mass", "box/edges"):
            element = f["particles/all"][name]
            assert set(element) == {"step", "time", "value"}
            assert element["value"].shape[0] == element["step"].shape[0] == element["time"].shape[0] == 3
        assert f["particles/all/position/step"][-1] == sim.step
        np.testing.assert_array_equal(f["particles/all/position/value"][-1], snap.positions)
        np.testing.assert_array_equal(f["particles/all/velocity/value"][-1], snap.velocities)
        np.testing.assert_array_equal(f["particles/all/radius/value"][-1], snap.radii)
        np.testing.assert_array_equal(f["particles/all/omega/value"][-1], snap.omegas)
        lo, hi = f["contacts/offset"][-2:]
        pairs = f["contacts/pair"][lo:hi]
        np.testing.assert_array_equal(pairs[:, 0], snap.contacts.i)
        np.testing.assert_array_equal(f["contacts/normal_force"][lo:hi], snap.contacts.normal_force)
        fields = [x.decode() for x in f["observables/energy"].attrs["fields"]]
        energy = dict(zip(fields, f["observables/energy/value"][-1]))
        assert energy["balance"] == pytest.approx(snap.energy.balance)
        walls = [x.decode() for x in f["observables/walls"].attrs["names"]]
        assert walls == ["left", "right", "bottom", "top"]
        assert f["observables/contact_paths/normal_force"].shape == (3, 1)
        assert f["parameters"].attrs["contact.friction"] == 0.4
        assert "loaded box" in f["parameters/scene"][()].decode()
        assert f["checkpoint/valid"][1] == sim.step


WRITER = textwrap.dedent("""
    import sys
    from granlab.engine.io import h5md
    from granlab.engine.io.scene import parse_scene
    sys.path.insert(0, {tests!r})
    from test_h5md import SCENE
    sim = parse_scene(SCENE).build()
    writer = h5md.RunWriter({path!r}, sim, scene=SCENE)
    print("ready", flush=True)
    while True:
        sim.run(5)
        writer.write_frame(sim)
        writer.write_checkpoint(sim)
""")


@pytest.fixture(scope="module")
def killed_run(tmp_path_factory):
    """A run file whose writer was killed (still marked as being written), with frames and checkpoints."""
    path = tmp_path_factory.mktemp("killed") / "killed.h5"
    script = WRITER.format(tests=str(Path(__file__).parent), path=str(path))
    process = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    assert process.stdout.readline().strip() == "ready"
    time.sleep(2.0)
    process.send_signal(signal.SIGKILL)
    process.wait()
    return path


def test_a_writer_killed_mid_run_leaves_a_readable_file(killed_run, tmp_path):
    path = killed_run
    with h5md.open_run(path) as f:
        frames = h5md.frame_count(f)
        assert frames >= 2
        last = h5md.read_frame(f, -1)
        assert np.all(np.isfinite(last["position"]))
        assert last["step"] == 5 * frames
        state = h5md.read_checkpoint(f)
        assert state is not None and state["step"] >= 5 * (frames - 1)
    resumed, _ = h5md.resume(path)
    resumed.run(10)


def _damage(data: bytes, how: str) -> bytes:
    data = bytearray(data)
    if how == "flipped":
        for at in range(4096, len(data), 997):
            data[at] ^= 0x55
    elif how == "page":
        at = len(data) // 2 // 4096 * 4096
        data[at:at + 4096] = bytes(4096)
    elif how == "tail":
        data[-len(data) // 3:] = bytes(len(data) // 3)
    elif how == "cut":
        del data[len(data) // 2:]
    return bytes(data)


@pytest.mark.parametrize("how", ["whole", "flipped", "page", "tail", "cut"])
def test_a_damaged_file_of_a_killed_writer_is_named_in_one_line_and_never_waited_on(killed_run, tmp_path, how):
    """HDF5's SWMR reader, the only one that opens a file still marked as being written, retries a
    damaged read for ever: such a file is read as a closed one, and the damage named at once."""
    path = tmp_path / f"{how}.h5"
    path.write_bytes(_damage(killed_run.read_bytes(), how))
    for command in (["info", str(path)], ["analyze", str(path), "packing"]):
        start = time.perf_counter()
        process = subprocess.run([sys.executable, "-m", "granlab.app.commands", *command], capture_output=True, text=True,
                                 timeout=60)
        assert time.perf_counter() - start < 20.0
        if how == "whole":
            assert process.returncode == 0, process.stderr
            continue
        # read up to the damage, or named in one line (damaged, or truncated)
        assert process.returncode in (0, 2) and "Traceback" not in process.stderr, process.stderr
        if process.returncode == 2:
            assert process.stderr.count("\n") == 1 and f"{str(path)!r} is " in process.stderr, process.stderr


READERS = textwrap.dedent("""
    import sys
    from granlab.engine.analysis.states import read_state
    from granlab.engine.io import h5md
    for reader in (h5md.summary, read_state, h5md.resume):
        try:
            reader(sys.argv[1])
            print("read")
        except h5md.RunFileError as error:
            print(error)
""")


@pytest.mark.parametrize("cut", [100, 2000, 100_000, 0.5, -1000])
def test_a_truncated_run_file_is_named_at_once_by_every_reader(tmp_path, cut):
    """HDF5's SWMR reader waits for ever for the missing bytes; every reader (info, analyze,
    resume) must say at once that the file is cut short."""
    sim = _sim()
    whole = tmp_path / "whole.h5"
    with h5md.RunWriter(whole, sim, scene=SCENE) as writer:
        for _ in range(6):
            sim.run(200)
            writer.write_frame(sim)
        writer.write_checkpoint(sim)
    data = whole.read_bytes()
    size = int(len(data) * cut) if isinstance(cut, float) else cut % len(data)
    path = tmp_path / "cut.h5"
    path.write_bytes(data[:size])
    process = subprocess.run([sys.executable, "-c", READERS, str(path)], capture_output=True, text=True, timeout=60)
    lines = process.stdout.splitlines()
    assert len(lines) == 3, process.stderr
    assert all(line == f"run file {str(path)!r} is truncated: {size} bytes of the {len(data)} its header records, "
               "so frames, checkpoint and parameters past the cut are lost (was it cut short while copied or "
               "written?)" for line in lines)


def test_resume_matches_an_uninterrupted_run_bit_for_bit(tmp_path):
    whole = _sim()
    whole.run(4000)
    part = _sim()
    part.run(1700)
    with h5md.RunWriter(tmp_path / "half.h5", part, scene=SCENE) as writer:
        writer.write_frame(part)
        writer.write_checkpoint(part)
    resumed, record = h5md.resume(tmp_path / "half.h5")
    assert "loaded box" in record["scene"]
    resumed.run(2300)
    np.testing.assert_array_equal(resumed.particles.position, whole.particles.position)
    np.testing.assert_array_equal(resumed.particles.omega, whole.particles.omega)
    np.testing.assert_array_equal(resumed.walls.offset, whole.walls.offset)
    assert resumed.time == whole.time
    assert resumed.energy().balance == whole.energy().balance


def test_cli_resume_continues_to_the_end_of_the_scene(tmp_path):
    scene_file = tmp_path / "box.toml"
    scene_file.write_text(SCENE)

    def cli(*args):
        process = subprocess.run([sys.executable, "-m", "granlab.app.commands", *args], capture_output=True, text=True,
                                 timeout=600)
        assert process.returncode == 0, process.stderr
        return json.loads(process.stdout)

    whole = cli("run", str(scene_file), "--json", "--out", str(tmp_path / "whole.h5"))
    part = _sim()
    part.run(2500)
    with h5md.RunWriter(tmp_path / "part.h5", part, scene=SCENE) as writer:
        writer.write_checkpoint(part)
    resumed = cli("run", "--resume", str(tmp_path / "part.h5"), "--json")
    assert resumed["steps"] == whole["steps"] == 4000
    assert resumed["positions"] == whole["positions"]
    assert resumed["run_file"].endswith("part-resumed.h5")
    info = cli("info", str(tmp_path / "whole.h5"), "--json")
    assert info["frames"] == 2 and info["particles"] == 60 and info["checkpoint_step"] == 4000


FULL_DISK = """
import os, sys
from granlab.app.commands import main
real = os.statvfs
CAPACITY = int(sys.argv[1])


class Disk:
    # a disk of CAPACITY bytes holding only the run file, once another program has filled the rest
    # (the run's look before it starts finds room)
    looks = 0

    def __init__(self, path):
        Disk.looks += 1
        self.f_frsize, out = 1, sys.argv[-1]
        self.f_bavail = 10 ** 12 if Disk.looks == 1 else \
            max(CAPACITY - (os.path.getsize(out) if os.path.exists(out) else 0), 0)


os.statvfs = Disk
sys.exit(main(sys.argv[2:]))
"""


def test_a_run_whose_file_the_disk_cannot_hold_is_refused_before_it_starts(tmp_path):
    """Under a file size limit of 1.14 MiB, 81 frames of 60 disks (up to 1.8 MB): refused in one line
    with the figures, nothing written (before: the run stopped when the file reached the limit)."""
    import resource

    scene_file = tmp_path / "box.toml"
    scene_file.write_text(SCENE.replace("steps = 4000", "steps = 4000\nrecord_every = 50"))

    def small_file_limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (1_200_000, 1_200_000))

    out = tmp_path / "full.h5"
    process = subprocess.run([sys.executable, "-m", "granlab.app.commands", "run", str(scene_file), "--out", str(out)],
                             capture_output=True, text=True, timeout=600, preexec_fn=small_file_limit)
    assert process.returncode == 2 and process.stderr == (
        f"granlab run: error: --out {str(out)!r}: 81 frames of 60 disks need up to 1.8 MB; 1.2 MB free there: fewer "
        "frames (--frame-every, simulation.record_every), or another disk\n")
    assert not out.exists()


def test_a_run_stopped_by_a_full_disk_says_so_in_one_line_and_its_file_resumes(tmp_path):
    """A disk filled by another program stops the writer mid-run: one line, exit 2, no crash (a
    real 700 KB tmpfs crashed HDF5 as it released a dataset, exit 139); the frames written before
    read back in order and --resume goes on from the last checkpoint to the scene's end, as the
    uninterrupted run does."""
    scene_file = tmp_path / "box.toml"
    scene_file.write_text(SCENE.replace("steps = 4000", "steps = 4000\nrecord_every = 50"))
    limit = 1_200_000
    out = tmp_path / "full.h5"
    process = subprocess.run([sys.executable, "-c", FULL_DISK, str(limit), "run", str(scene_file), "--out", str(out)],
                             capture_output=True, text=True, timeout=600)
    assert process.returncode == 2 and process.stderr.count("\n") == 1, process.stderr
    cause = r"No space left on device \([0-9.]+ MiB free, a frame and a checkpoint need [0-9.]+ MiB\)"
    found = re.search(r"writing '.*full.h5' failed at step (\d+): " + cause + r"\. What was written before stays "
                      r"readable; granlab run --resume '.*full.h5' goes on from its last checkpoint \(step (\d+)\)",
                      process.stderr)
    assert found and out.stat().st_size <= limit, process.stderr
    failed_at, checkpoint = int(found.group(1)), int(found.group(2))
    with h5md.open_run(out) as f:
        steps = f["particles/all/position/step"][:h5md.frame_count(f)]
        assert steps[0] == 0 and np.all(np.diff(steps) == 50) and checkpoint <= steps[-1] < failed_at
        assert h5md.read_checkpoint(f)["step"] == checkpoint
    resumed = subprocess.run([sys.executable, "-m", "granlab.app.commands", "run", "--resume", str(out), "--json"],
                             capture_output=True, text=True, timeout=600)
    assert resumed.returncode == 0, resumed.stderr
    assert json.loads(resumed.stdout)["steps"] == 4000


def test_bad_run_files_give_clear_errors(tmp_path):
    with pytest.raises(h5md.RunFileError, match="does not exist"):
        h5md.open_run(tmp_path / "missing.h5")
    text = tmp_path / "notes.h5"
    text.write_text("not an HDF5 file")
    with pytest.raises(h5md.RunFileError, match="is not a readable HDF5 file"):
        h5md.open_run(text)
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f.create_dataset("x", data=[1, 2, 3])
    with h5md.open_run(other) as f:
        with pytest.raises(h5md.RunFileError, match="not an H5MD particle file"):
            h5md.frame_count(f)
    with pytest.raises(h5md.RunFileError, match="holds no checkpoint"):
        sim = _sim()
        with h5md.RunWriter(tmp_path / "nockpt.h5", sim) as writer:
            writer.write_frame(sim)
        h5md.resume(tmp_path / "nockpt.h5")
    with h5md.open_run(tmp_path / "nockpt.h5") as f:
        with pytest.raises(h5md.RunFileError, match=r"frame 5 is out of range: .* holds frames 0..0"):
            h5md.read_frame(f, 5)
    process = subprocess.run([sys.executable, "-m", "granlab.app.commands", "info", str(text)], capture_output=True,
                             text=True)
    assert process.returncode == 2 and "is not a readable HDF5 file" in process.stderr


def test_a_killed_cli_run_resumes_from_its_last_periodic_checkpoint_bit_for_bit(tmp_path):
    scene_file = tmp_path / "long.toml"
    scene_file.write_text(SCENE.replace("steps = 4000", "steps = 400000\nrecord_every = 4000"))
    crash = tmp_path / "crash.h5"
    command = [sys.executable, "-m", "granlab.app.commands", "run", str(scene_file), "--json"]
    process = subprocess.Popen(command + ["--out", str(crash), "--checkpoint-every", "2"], stdout=subprocess.DEVNULL)
    deadline = time.monotonic() + 120.0
    step = 0
    while step < 20000 and time.monotonic() < deadline:  # killed after its third checkpoint (4000, 12000, 20000)
        time.sleep(0.02)
        if crash.exists():
            try:
                step = h5md.summary(crash)["checkpoint_step"] or 0
            except (h5md.RunFileError, OSError, KeyError):
                pass
    process.send_signal(signal.SIGKILL)
    process.wait()
    assert 20000 <= step < 400000 and step % 4000 == 0
    resumed = json.loads(subprocess.run(command[:4] + ["--resume", str(crash), "--json"], capture_output=True,
                                        text=True, timeout=600, check=True).stdout)
    whole = json.loads(subprocess.run(command, capture_output=True, text=True, timeout=600, check=True).stdout)
    assert resumed["steps"] == whole["steps"] == 400000
    assert resumed["positions"] == whole["positions"] and resumed["omegas"] == whole["omegas"]
    with h5md.open_run(tmp_path / "crash-resumed.h5") as f:
        assert f["particles/all/position/step"][0] >= step and f["particles/all/position/step"][1] % 4000 == 0


def test_a_diverging_cli_run_writes_its_restored_last_good_state_as_the_last_checkpoint(tmp_path):
    scene_file = tmp_path / "heavy.toml"
    scene_file.write_text(SCENE.replace("gravity = [0.0, -1.0]", "gravity = [0.0, -3e3]"))
    out = tmp_path / "heavy.h5"
    process = subprocess.run([sys.executable, "-m", "granlab.app.commands", "run", str(scene_file), "--out", str(out),
                              "--frame-every", "10", "--checkpoint-every", "4"], capture_output=True, text=True,
                             timeout=600)
    assert process.returncode == 2
    with h5md.open_run(out) as f:
        dt = h5md.parameters(f)["dt"]
    assert process.stderr.strip().endswith(f"above max_overlap = 0.5 (time step too large or stiffness too low). "
                                           f"The simulation was restored to its last good state (t = {90 * dt:.6g}). "
                                           f"It is the last checkpoint of {out}.")
    info = h5md.summary(out)
    assert info["checkpoint_step"] == info["last_step"] == 90  # periodic checkpoints were at steps 30 and 70


def test_a_file_whose_metadata_hdf5_reads_for_ever_is_named_damaged_after_ten_seconds(tmp_path):
    """A page zeroed at 4096 bytes of a run file: HDF5 looped for ever reading its /parameters,
    holding Python's lock, so that neither a thread nor SIGTERM could stop `run --resume`."""
    from tests import run_fuzz

    done = run_fuzz.make_bases(tmp_path)["done"]
    data = bytearray(done.read_bytes())
    data[4096:8192] = bytes(4096)
    damaged = tmp_path / "damaged.h5"
    damaged.write_bytes(bytes(data))
    start = time.perf_counter()
    process = subprocess.run([sys.executable, "-m", "granlab.app.commands", "run", "--resume", str(damaged)],
                             capture_output=True, text=True, timeout=120)
    assert time.perf_counter() - start < 30
    assert process.returncode == 2 and process.stderr.count("\n") == 1, process.stderr
    # where HDF5 loops, that is what is said; elsewhere the damage is named
    assert process.stderr.startswith(f"granlab run: error: {str(damaged)!r} is damaged"), process.stderr
