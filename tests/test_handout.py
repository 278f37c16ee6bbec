"""`granlab export --format html`: a handout, one page that replays a run in a browser from disk.

The page is read back as a browser would get it (its JSON and base64 arrays) and compared with the
run file frame by frame; then headless Chromium (Debian's package) opens it from file:// and what
a viewer sees is checked: no request leaves the file, no console error, disks on the canvas, a
timeline that moves the scene and the plots' markers, text a projector shows.
"""

import base64
import json
import math
import re
import time

import numpy as np
import pytest

from granlab.engine.errors import ParameterError
from granlab.engine.frames import FrameData, build_frame
from granlab.engine.io import h5md
from granlab.engine.io.export import EXPORT_FORMATS, export_run
from granlab.engine.io.export import html as handout_format

CYCLES = 4
"""Load cycles of the saved ratchet16 run: its strain per cycle is fitted from cycle 2 on, over three cycles."""


@pytest.fixture(scope="module")
def lab_run(tmp_path_factory):
    """A ratchet16 run saved by the lab after CYCLES load cycles (as fast as it runs)."""
    from granlab.app.lab.engine_thread import LabEngine

    folder = tmp_path_factory.mktemp("handout")
    lab = LabEngine(folder, preset="ratchet16", speed=math.inf)
    lab.start()
    try:
        deadline = time.time() + 300
        while lab.status().get("cycle", 0) < CYCLES and time.time() < deadline:
            time.sleep(0.1)
        lab.submit("save", name="ratchet16")
        while "ratchet16.h5" not in lab.saved_files() and time.time() < deadline:
            time.sleep(0.1)
    finally:
        lab.stop()
    return folder / "ratchet16.h5"


@pytest.fixture(scope="module")
def handout(lab_run):
    out = lab_run.with_name("handout.html")
    export_run(lab_run, "html", out)
    return out


def page_data(path) -> tuple[dict, dict]:
    """The page's data as its script reads it, and its arrays decoded."""
    text = path.read_text(encoding="utf-8")
    opening = '<script type="application/json" id="handout-data">'
    start = text.index(opening) + len(opening)
    data = json.loads(text[start:text.index("</script>", start)])
    arrays = {name: np.frombuffer(base64.b64decode(a["b64"]), dtype="<" + a["dtype"])
              for name, a in data["arrays"].items()}
    return data, arrays


def decoded(array: dict) -> np.ndarray:
    return np.frombuffer(base64.b64decode(array["b64"]), dtype="<" + array["dtype"])


def test_the_handout_holds_every_frame_it_claims_and_the_presets_plots(handout, lab_run):
    assert EXPORT_FORMATS["html"].suffix == ".html"
    size = handout.stat().st_size
    assert size < 10 ** 7  # a ratchet16 save mails as one file
    text = handout.read_text(encoding="utf-8")
    # nothing the browser would fetch: no address in a src, href, url() or @import
    assert not re.search(r"""(src|href)\s*=\s*["']?[a-z]*:?//|url\(\s*["']?[a-z]*:?//|@import""", text)
    data, arrays = page_data(handout)
    with h5md.open_run(lab_run) as f:
        count = h5md.frame_count(f)
        params = h5md.parameters(f)
        raws = [h5md.read_frame(f, k) for k in range(count)]
        series = h5md.lab_series(f)
    protocol = json.loads(params["protocol_json"])
    frames = data["frames"]
    assert frames["count"] == count == len(frames["index"]) and frames["index"] == list(range(count))  # none thinned
    n = data["disks"]
    assert n == 16 and not data["radiusPerFrame"]
    offsets = arrays["coff"]
    normals = np.array([w.normal for w in h5md.walls_from_json(params["walls_json"])])
    for k, index in enumerate(frames["index"]):
        raw = raws[index]
        scene = build_frame([(FrameData.from_run_frame(raw, normals), (0.0, 0.0))])
        assert frames["time"][k] == raw["time"] and frames["step"][k] == raw["step"]
        assert frames["phase"][k] == raw["lab_phase"]
        np.testing.assert_array_equal(arrays["pos"][2 * n * k:2 * n * (k + 1)],
                                      raw["position"].astype(np.float32).ravel())
        np.testing.assert_allclose(arrays["angle"][n * k:n * (k + 1)], np.mod(raw["angle"], 2 * np.pi), atol=1e-6)
        np.testing.assert_array_equal(arrays["radius"], raw["radius"].astype(np.float32))
        np.testing.assert_array_equal(arrays["coord"][n * k:n * (k + 1)], scene.coordination)
        rows = slice(offsets[k], offsets[k + 1])
        assert offsets[k + 1] - offsets[k] == len(raw["contacts"]["status"])
        np.testing.assert_array_equal(arrays["seg"][4 * rows.start:4 * rows.stop],
                                      scene.contacts.astype(np.float32).ravel())
        np.testing.assert_array_equal(arrays["kind"][rows], scene.contact_kind)
        walls = arrays["walls"].reshape(-1, 4, 2, 2)[k]  # the box's four walls, each on its line n · x = s
        np.testing.assert_allclose(np.einsum("wd,wed->we", normals, walls), raw["wall_position"][:, None] *
                                   np.ones((1, 2)), atol=1e-5)
        # a watched contact in the frame is marked with its place in the watch list (its colour)
        pairs = [tuple(p) for p in raw["contacts"]["pair"].tolist()]
        for w, pair in enumerate(map(tuple, protocol["watched"])):
            if pair in pairs:
                assert arrays["watch"][offsets[k] + pairs.index(pair)] == w
    settings = dict(data["settings"][frames["settings"][-1]])
    assert settings["friction"] == "friction μ = 0.2"
    assert settings["tangential_model"] == "tangential spring: Cundall–Strack"
    assert data["title"] == "Ratcheting with 16 disks (ratcheting Figs. 1-4)" and data["preset"] == "ratchet16"
    assert data["title"] in text[:2000]  # the page's <title>
    # the preset's key plots first, from its series: γ at each cycle start from the reference cycle, fitted
    assert [p["id"] for p in data["plots"]] == ["strain-per-cycle", "coulomb-cone", "q-gamma", "energy", "coordination"]
    assert data["keyPlots"] == ["strain-per-cycle", "coulomb-cone"]
    strain = data["plots"][0]
    columns, rows = series["cycles"]
    cycle, gamma = rows[:, columns.index("cycle")], rows[:, columns.index("gamma")]
    points = next(layer for layer in strain["layers"] if layer["label"] == "γ at a cycle start")
    np.testing.assert_array_equal(decoded(points["x"]), cycle[cycle >= 2])
    np.testing.assert_allclose(decoded(points["y"]), (gamma - gamma[cycle == 2])[cycle >= 2], rtol=1e-6, atol=1e-12)
    assert strain["title"].startswith("Δγ = ") and "per cycle from cycle 2" in strain["title"]
    cone = data["plots"][1]
    assert {layer["label"] for layer in cone["layers"]} >= set(protocol["watched_labels"][:1])
    for plot in data["plots"]:
        assert plot["xLabel"] and plot["yLabel"] and all(len(decoded(layer["x"])) for layer in plot["layers"])


def test_a_bad_out_suffix_is_refused_before_anything_is_written(lab_run, tmp_path):
    with pytest.raises(ParameterError, match=r"a file name ending in \.html for --format html"):
        export_run(lab_run, "html", tmp_path / "handout.htm")
    assert list(tmp_path.iterdir()) == []


def test_frames_are_thinned_evenly_to_the_budget_and_the_page_says_so(lab_run, tmp_path, monkeypatch):
    monkeypatch.setattr(handout_format, "MAX_BYTES", 120_000)
    out = tmp_path / "small.html"
    export_run(lab_run, "html", out)
    data, arrays = page_data(out)
    index = data["frames"]["index"]
    with h5md.open_run(lab_run) as f:
        count = h5md.frame_count(f)
        last = h5md.read_frame(f, count - 1)
    assert 2 <= len(index) < count and index[0] == 0 and index[-1] == count - 1  # the first and the last kept
    stride = index[1] - index[0]
    assert stride > 1 and all(b - a == stride for a, b in zip(index[:-2], index[1:-1]))
    assert sum(len(a["b64"]) for a in data["arrays"].values()) < 120_000
    assert any(f"holds {len(index)} of the {count} frames" in note for note in data["notes"])
    n = data["disks"]
    np.testing.assert_array_equal(arrays["pos"][-2 * n:], last["position"].astype(np.float32).ravel())


def test_the_colours_are_the_labs():
    from granlab.app.media import drawing

    palettes, colors = handout_format._palettes(), handout_format._colors()
    for name, table in (("rotation", drawing.ROTATION_LUT), ("pressure", drawing.PRESSURE_LUT),
                        ("coordination", drawing.COORDINATION_COLORS), ("sliding", drawing.SLIDING_DISK_COLORS)):
        assert palettes[name] == [drawing.hex_color(c) for c in table], name
    assert colors["kinds"] == [[name, drawing.hex_color(c)] for name, c in drawing.CONTACT_KINDS]
    assert colors["watched"] == [drawing.hex_color(c) for c in drawing.WATCHED_COLORS]
    for name, color in (("spoke", drawing.SPOKE_COLOR), ("wall", drawing.WALL_COLOR), ("cell", drawing.CELL_COLOR)):
        assert colors[name] == drawing.hex_color(color)
    forces = np.array([0.0, 0.1, 0.35, 0.5, 0.99, 1.0, 0.2])
    np.testing.assert_array_equal(handout_format.force_classes(forces), drawing.force_classes(forces))
    assert handout_format.FORCE_CLASSES == drawing.FORCE_CLASSES


def test_the_handout_and_the_viewers_scene_draw_with_one_script(handout):
    """engine/io/export/packing.js draws the packing for both pages: the handout carries it, the lab
    serves it in the viewers' scene, and neither page draws a disk of its own."""
    from granlab.app.lab.server import VIEWER_SCENE

    drawing = handout_format.DRAWING
    assert "function drawPacking(ctx, p)" in drawing and drawing.count("ctx.arc(") == 1
    page = handout.read_text()
    assert drawing in page and page.count("ctx.arc(") == 1 and "drawPacking(ctx, {" in page
    scene = VIEWER_SCENE.read_text()
    assert "<script>%DRAWING%</script>" in scene and "ctx.arc(" not in scene and "drawPacking(ctx, {" in scene


def test_a_run_not_saved_by_the_lab_gets_its_energy_z_phi_and_its_periodic_cell(tmp_path):
    from tests.test_export import FRAMES, compressed_run

    run = compressed_run(tmp_path)
    out = tmp_path / "compressed.html"
    export_run(run, "html", out)
    data, _ = page_data(out)
    assert data["title"] == "Run compressed" and data["preset"] == "" and data["frames"]["count"] == FRAMES
    assert [p["id"] for p in data["plots"]] == ["energy", "coordination", "solid-fraction"]
    with h5md.open_run(run) as f:
        edges = [h5md.read_frame(f, k)["edges"].tolist() for k in range(FRAMES)]
    assert data["frames"]["cell"] == edges and data["walls"] == 0


def canvas_pixels(page) -> tuple[float, int]:
    """The share of the scene's pixels that are not the white background, and a hash of them."""
    return tuple(page.evaluate("""() => {
        const c = document.getElementById("scene"), d = c.getContext("2d").getImageData(0, 0, c.width, c.height).data;
        let drawn = 0, hash = 0;
        for (let i = 0; i < d.length; i += 4) {
            if (d[i] !== 255 || d[i + 1] !== 255 || d[i + 2] !== 255) drawn++;
            hash = (hash * 31 + d[i] + 7 * d[i + 1] + 13 * d[i + 2]) >>> 0;
        }
        return [drawn / (d.length / 4), hash];
    }"""))


def click_timeline(page, fraction: float) -> None:
    box = page.locator("#frame").bounding_box()
    page.mouse.click(box["x"] + fraction * box["width"], box["y"] + box["height"] / 2)


def test_the_handout_replays_from_disk_without_a_request_or_an_error(page, handout):
    outside, errors = [], []
    page.on("request", lambda request: None if request.url.startswith("file://") else outside.append(request.url))
    page.on("console", lambda message: errors.append(message.text) if message.type == "error" else None)
    page.on("pageerror", lambda error: errors.append(str(error)))
    page.goto(handout.as_uri())
    page.wait_for_function("() => window.handout && document.querySelector('[data-plot] svg text')")
    label = page.locator("#frame-label")
    start = label.inner_text()
    assert start.startswith("frame 1 of ")
    drawn, first = canvas_pixels(page)
    assert drawn > 0.2  # the packing fills its box
    click_timeline(page, 0.97)
    page.wait_for_function("() => window.handout.frame() > 0.9 * window.handout.count")
    late = label.inner_text()
    assert late != start and canvas_pixels(page)[1] != first  # the label and the scene follow the timeline
    strain = page.locator("[data-plot=strain-per-cycle]")
    points = strain.locator("path.past").first.get_attribute("d")
    assert points.count("M") >= CYCLES - 1  # the cycles from the reference cycle on, each a dot
    marker = strain.locator("circle.marker").first
    assert marker.get_attribute("visibility") == "visible"
    cone = page.locator("[data-plot=coulomb-cone]")
    assert len(cone.locator("path.past").first.get_attribute("d")) > 20 and "μ = 0.2" in cone.inner_text()
    energy_marker = page.locator("[data-plot=energy] circle.marker").first
    at_end = energy_marker.get_attribute("cx")
    click_timeline(page, 0.3)
    page.wait_for_function(f"() => document.getElementById('frame-label').textContent !== {json.dumps(late)}")
    assert energy_marker.get_attribute("cx") != at_end
    assert len(strain.locator("path.past").first.get_attribute("d") or "") < len(points)
    page.locator("#play").click()
    shown = label.inner_text()
    page.wait_for_function(f"() => document.getElementById('frame-label').textContent !== {json.dumps(shown)}")
    page.locator("#play").click()
    # readable from the back of a room: no text under 13 px
    smallest = page.evaluate("""() => Math.min(...Array.from(document.querySelectorAll("body *"))
        .filter(e => Array.from(e.childNodes).some(n => n.nodeType === 3 && n.textContent.trim()))
        .map(e => parseFloat(getComputedStyle(e).fontSize)))""")
    assert smallest >= 13
    assert outside == [] and errors == []
