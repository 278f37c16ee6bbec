"""granlab render: pictures and movies of run files, checked on their pixels, and clear errors."""

import re
from concurrent.futures import ThreadPoolExecutor

import h5py
import imageio.v2 as iio2
import imageio.v3 as iio
import numpy as np
import pytest

from granlab.app.commands import main
from granlab.app.media.drawing import (CELL_COLOR, COMPRESSIVE_COLOR, COORDINATION_COLORS, ROTATION_LUT, WALL_COLOR,
                                 WATCHED_COLORS, disk_colors)
from granlab.app.media.render import default_movie_frames, render_image, run_frames, write_movie
from granlab.engine.frames import SceneFrame
from granlab.engine.io import h5md
from granlab.engine.io.scene import parse_scene

PILE = """
title = "a cohesive pile settling between two walls"
walls = [{ name = "floor", normal = [0.0, 1.0], position = 0.0 },
         { name = "left", normal = [1.0, 0.0], position = 0.0 },
         { name = "right", normal = [-1.0, 0.0], position = -10.0 }]
[simulation]
steps = 2000
gravity = [0.0, -30.0]
[contact]  # stiff enough for this gravity, damped, frictional and cohesive
normal_stiffness = 2e4
damping_ratio = 0.3
friction = 0.3
cohesion_force = 2.0
cohesion_range = 0.05
[particles]
gas = [{ count = 80, radius_min = 0.35, radius_max = 0.5, region = [0.0, 10.0, 0.0, 20.0], seed = 2 }]
"""

CELL = """
title = "a gas in a periodic cell"
[simulation]
steps = 200
[contact]
normal_stiffness = 1e3
tangential_stiffness = 1e3
[cell]
lengths = [12.0, 12.0]
[[particles.gas]]
count = 50
radius_min = 0.4
radius_max = 0.6
seed = 1
velocity_spread = 1.0
"""

FRAMES = 5


def _write_run(path, scene, frames, steps):
    sim = parse_scene(scene).build()
    with h5md.RunWriter(path, sim, scene=scene, protocol={"test": True}) as writer:
        writer.write_frame(sim)
        for _ in range(frames - 1):
            sim.run(steps)
            writer.write_frame(sim)
    return path


@pytest.fixture(scope="module")
def pile(tmp_path_factory):
    """Five frames, 500 steps apart, of 80 disks falling onto a floor between two walls: the
    last frames have compressive, tensile and sliding contacts."""
    return _write_run(tmp_path_factory.mktemp("pile") / "pile.h5", PILE, FRAMES, 500)


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    return _write_run(tmp_path_factory.mktemp("cell") / "cell.h5", CELL, 2, 100)


def _frame(path, index):
    with h5md.open_run(path) as f:
        return next(run_frames(f, [index]))


def _packed(colors):
    """sRGB triples (..., 3) as integers 0xRRGGBB."""
    colors = np.asarray(colors, dtype=np.int64)
    return (colors[..., 0] << 16) | (colors[..., 1] << 8) | colors[..., 2]


def _count(image, colors):
    """Pixels of ``image`` of exactly each colour of ``colors`` (K, 3), or of the one colour (3,)."""
    values, counts = np.unique(_packed(image), return_counts=True)
    wanted = _packed(colors)
    where = np.clip(np.searchsorted(values, wanted), 0, len(values) - 1)
    found = np.where(values[where] == wanted, counts[where], 0)
    return found if found.ndim else int(found)


def _render(*args):
    return main(["render", *map(str, args)])


def test_png_has_the_size_asked_and_the_disks_in_their_palette_colours(pile, tmp_path):
    out = tmp_path / "last.png"
    assert _render(pile, "--out", out, "--size", "1000x700") == 0
    image = iio.imread(out)
    assert image.shape == (700, 1000, 3)
    assert 0.3 < np.mean(np.all(image == 255, axis=-1)) < 0.9  # white background, not a blank picture
    frame, caption = _frame(pile, -1)
    assert re.fullmatch(r"t = 0\.\d{4}, step 2000", caption)
    colors = np.unique(disk_colors(frame, "rotation"), axis=0)
    # every colour a disk has is on the picture, each disk being 23-33 px across
    assert _count(image, colors).min() > 20 and len(colors) > 10
    # the legend's colour bar shows the whole cyclic scale: 169 px (9 em of 18.75 px) for 256 entries
    assert np.count_nonzero(_count(image, ROTATION_LUT)) > 120
    assert _count(image, WALL_COLOR) > 2000


def test_gif_and_mp4_have_the_frames_and_size_asked(pile, tmp_path):
    gif = tmp_path / "pile.gif"
    assert _render(pile, "--out", gif, "--size", "640x360") == 0  # a movie: its last 100 frames by default
    frames = iio.imread(gif, index=None)
    assert frames.shape == (FRAMES, 360, 640, 3)
    mp4 = tmp_path / "pile.mp4"
    assert _render(pile, "--out", mp4, "--size", "480x270", "--frames", "1::2", "--fps", "4") == 0
    reader = iio2.get_reader(mp4, format="FFMPEG")
    assert reader.get_meta_data()["fps"] == 4.0
    images = [reader.get_data(k) for k in range(reader.count_frames())]
    assert [image.shape for image in images] == [(270, 480, 3)] * 2  # frames 1 and 3


def test_a_movie_is_the_last_ten_cycles_by_default_and_shows_its_progress(tmp_path, capsys):
    """A run that names its cycle (the lab's cycle_time): its last 10 cycles; without one, the last
    100 frames. ``granlab render`` says how far it got on standard error."""
    sim = parse_scene(CELL).build()
    path = tmp_path / "cycled.h5"
    with h5md.RunWriter(path, sim, scene=CELL, protocol={"cycle_time": 20 * sim.dt}) as writer:
        for _ in range(30):  # a frame every 10 steps: two frames a cycle
            writer.write_frame(sim)
            sim.run(10)
    with h5md.open_run(path) as f:
        assert default_movie_frames(f, 30) == list(range(9, 30))  # from t_last - 10 cycles: 21 frames
        assert default_movie_frames(f, 2) == [0, 1]
    assert _render(path, "--out", tmp_path / "last.gif", "--size", "480x270") == 0
    assert len(iio.imread(tmp_path / "last.gif", index=None)) == 21
    err = capsys.readouterr().err.splitlines()
    assert err[0] == "rendering frame 0 of 21" and err[-1] == "rendering frame 21 of 21" and len(err) <= 12


def test_a_movie_keeps_its_framing_while_the_pile_settles(pile, tmp_path):
    """One picture per frame (STEM_00002.png: the frame's index) with the walls at the same
    pixels in each; the last frame alone, its disks lower, is drawn larger."""
    out = tmp_path / "pile.png"
    assert _render(pile, "--out", out, "--frames", "2:5", "--size", "800x600") == 0
    assert not out.exists()

    def floor_and_sides(image):
        walls = np.all(np.abs(image.astype(int) - WALL_COLOR) <= 2, axis=-1)
        rows, columns = walls.sum(axis=1), walls.sum(axis=0)
        return int(np.argmax(rows)), tuple(np.flatnonzero(columns > 0.5 * columns.max())[[0, -1]])

    placed = [floor_and_sides(iio.imread(tmp_path / f"pile_{k:05d}.png")) for k in (2, 3, 4)]
    assert placed[0] == placed[1] == placed[2]
    (tmp_path / "pile_00002.png").unlink()
    kept = (tmp_path / "pile_00003.png").read_bytes()
    assert _render(pile, "--out", out, "--frames", "2:5", "--size", "640x480") == 2  # pile_00003.png is there
    assert (tmp_path / "pile_00003.png").read_bytes() == kept and not (tmp_path / "pile_00002.png").exists()
    assert _render(pile, "--out", out, "--frames", "2:5", "--size", "640x480", "--force") == 0
    assert iio.imread(tmp_path / "pile_00003.png").shape == (480, 640, 3)
    alone = floor_and_sides(render_image(_frame(pile, 4)[0], size=(800, 600)))
    assert alone[1][1] - alone[1][0] > placed[0][1][1] - placed[0][1][0] + 20


def test_no_forces_and_coordination_change_the_picture(pile, tmp_path):
    pictures = {}
    for name, options in {"forces": [], "bare": ["--no-forces"], "coordination": ["--color", "coordination"]}.items():
        out = tmp_path / f"{name}.png"
        assert _render(pile, "--out", out, *options) == 0
        pictures[name] = iio.imread(out)
    assert _count(pictures["forces"], COMPRESSIVE_COLOR) > 500
    assert _count(pictures["bare"], COMPRESSIVE_COLOR) == 0
    frame, _ = _frame(pile, -1)
    present = np.unique(np.minimum(frame.coordination, 6))
    assert len(present) >= 3
    for z in present:  # the disks of z contacts: in the coordination picture, not in the rotation one
        disks = _count(pictures["coordination"], COORDINATION_COLORS[z])
        assert disks > 200 and _count(pictures["forces"], COORDINATION_COLORS[z]) < disks / 10


def test_periodic_cell_is_outlined(cell, tmp_path):
    out = tmp_path / "cell.png"
    assert _render(cell, "--out", out) == 0
    image = iio.imread(out)
    assert _count(image, CELL_COLOR) > 1000
    assert _count(image, WALL_COLOR) < 100  # dark text edges; a wall would be thousands


def test_a_lab_runs_movie_shows_its_watched_contacts_and_its_phase(pile, tmp_path):
    """A lab run names its watched contacts and the phase of each frame: the picture draws each
    watched contact in its colour (packing and legend) and the caption names the phase."""
    sim = parse_scene(PILE).build()
    sim.run(2000)
    snap = sim.contact_snapshot()
    watched = [(int(i), int(j)) for i, j in zip(snap.i, snap.j) if j < sim.particles.count][:2]
    path = tmp_path / "lab.h5"
    protocol = {"watched": [list(p) for p in watched], "watched_labels": [f"{i}–{j}" for i, j in watched]}
    with h5md.RunWriter(path, sim, protocol=protocol, lab_series={}) as writer:
        writer.write_frame(sim, "{}", "cycle 3 · q = 0.100, rising")
    frame, caption = _frame(path, 0)
    assert caption.splitlines()[0] == "cycle 3 · q = 0.100, rising" and caption.splitlines()[1].startswith("t = ")
    assert frame.watched.shape == (2, 2, 2)
    out = tmp_path / "lab.png"
    assert _render(path, "--out", out) == 0
    image = iio.imread(out)
    packing, legend = image[:, :640], image[:, 640:]
    for color in WATCHED_COLORS[:2]:
        assert _count(packing, color) > 100 and _count(legend, color) > 100
    assert _count(image, WATCHED_COLORS[2]) == 0


def test_disks_show_through_a_force_network_of_equal_forces(tmp_path):
    """16 disks in a square, every force equal (all in the top class, as in a small box under
    load): more than half of each disk still shows its colour."""
    centres = np.array([(2.0 * x, 2.0 * y) for y in range(4) for x in range(4)])
    pairs = [(k, k + 1) for k in range(16) if k % 4 < 3] + [(k, k + 4) for k in range(12)]
    frame = SceneFrame(positions=centres, radii=np.ones(16), angles=np.zeros(16), coordination=np.zeros(16, int),
                       pressure=np.zeros(16), sliding=np.zeros(16, bool),
                       contacts=np.array([[centres[i], centres[j]] for i, j in pairs]), contact_force=np.ones(24),
                       contact_kind=np.zeros(24, np.int8), walls=np.zeros((0, 2, 2)), cell=None,
                       watched=np.zeros((0, 2, 2)))
    disk = ROTATION_LUT[0]
    bare = _count(render_image(frame, forces=False), disk)
    assert _count(render_image(frame), disk) > 0.5 * bare
def test_write_movie_takes_frames_in_memory(pile, tmp_path):
    """The lab's recorder: (SceneFrame, caption) pairs straight to a GIF."""
    frames = [_frame(pile, k) for k in range(FRAMES)]
    assert write_movie(frames, tmp_path / "lab.gif", size=(480, 270), color_field="sliding") == FRAMES
    assert iio.imread(tmp_path / "lab.gif", index=None).shape == (FRAMES, 270, 480, 3)


@pytest.mark.parametrize("options, message", [
    (["--out", "{tmp}/a.jpg"], "--out suffix = '.jpg' is not allowed: .png, .gif, .mp4"),
    (["--out", "{tmp}/none/a.png"], "a file in an existing folder"),
    (["--out", "{tmp}/a.png", "--frames", "3:3"], "a range selecting at least one of the file's frames 0..4"),
    (["--out", "{tmp}/a.png", "--frames", "2:9"], "--frames = '2:9' is not allowed: a frame K or a range A:B:S"),
    (["--out", "{tmp}/a.png", "--frames", "5"], "within the file's frames 0..4"),
    (["--out", "{tmp}/a.png", "--frames", "::0"], "(S > 0)"),
    (["--out", "{tmp}/a.png", "--size", "1280by720"], "--size = '1280by720' is not allowed: WIDTHxHEIGHT in pixels"),
    (["--out", "{tmp}/a.png", "--size", "100x100"], "width 480..7680 and height 270..4320"),
    (["--out", "{tmp}/a.mp4", "--size", "641x360"], "an even width and height for .mp4"),
    (["--out", "{tmp}/a.png", "--color", "speed"], "one of rotation, coordination, pressure, sliding"),
    (["--out", "{tmp}/a.gif", "--fps", "0"], "--fps = '0' is not allowed: frames per second"),
])
def test_bad_options_exit_2_with_one_line_naming_what_is_allowed(pile, tmp_path, capsys, options, message):
    assert _render(pile, *[option.format(tmp=tmp_path) for option in options]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and error.startswith("granlab render: error: ") and message in error
    assert list(tmp_path.iterdir()) == []


def test_files_that_are_not_run_files_exit_2_with_one_line(tmp_path, capsys):
    scene = tmp_path / "scene.toml"
    scene.write_text(PILE)
    generic = tmp_path / "generic.h5"
    with h5py.File(generic, "w") as f:  # H5MD particles, but no GranLab contacts or parameters
        position = f.create_group("particles/all/position")
        position["step"], position["time"], position["value"] = [0], [0.0], np.zeros((1, 3, 2))
    for path, message in [(tmp_path / "none.h5", "does not exist"), (scene, "is not a readable HDF5 file"),
                          (generic, "is not a GranLab run file")]:
        assert _render(path, "--out", tmp_path / "a.png") == 2
        error = capsys.readouterr().err
        assert error.count("\n") == 1 and message in error


def test_pictures_rendered_on_threads_match_one_rendered_alone(pile):
    """The lab's recorder renders on a background thread while the lab draws: no shared state."""
    frames = [_frame(pile, k) for k in (1, FRAMES - 1)]
    alone = [render_image(frame, size=(640, 360), caption=caption) for frame, caption in frames]
    with ThreadPoolExecutor(4) as pool:
        threaded = list(pool.map(lambda pair: render_image(pair[0], size=(640, 360), caption=pair[1]), frames * 4))
    for k, image in enumerate(threaded):
        np.testing.assert_array_equal(image, alone[k % 2])
