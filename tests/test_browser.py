"""The lab in a real browser: headless Chromium (Debian's package) driven by playwright.

The tests look at what a viewer sees: the plots' samples per load cycle, the range of the
strain plot, a refused value going back in its box, the scene holding every preset's disks,
the legends, the replay's timeline, and no request leaving 127.0.0.1. Under CI=true these tests
run; elsewhere they skip when no Chromium is installed.
"""

import json
import math
import os
import shutil
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path
from urllib.parse import parse_qs, urlparse

import pytest
from playwright.sync_api import expect

from granlab.app.lab.pace import DRAW_WAIT_SECONDS
from granlab.app.lab.server import read_status, spawn
from granlab.engine.protocols.presets import PRESETS

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
if CHROMIUM is None:
    if os.environ.get("CI") == "true":
        raise RuntimeError("CI=true but no chromium on PATH: .ci/run installs Debian's chromium package")
    pytest.skip("no chromium on PATH", allow_module_level=True)


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    data = tmp_path_factory.mktemp("lab-data")
    process, url, _ = spawn(data)
    lab = {"url": url, "process": process, "data": data}
    yield lab
    process.terminate()
    process.wait(timeout=30)


def status(lab) -> dict:
    return read_status(lab["url"])


def scene(lab) -> dict:
    with urllib.request.urlopen(lab["url"] + "scene", timeout=10) as response:
        return json.loads(response.read())


def wait_status(lab, predicate, timeout=30.0, read=status):
    deadline = time.time() + timeout
    last = None
    while time.time() < deadline:
        last = read(lab)
        if predicate(last):
            return last
        time.sleep(0.2)
    raise AssertionError(f"never matched; last: {last}")


def open_dashboard(page, lab, preset="ratchet", scene=False):
    """Open a tab on ``preset`` (chosen in the page if the lab shows another one); returns the
    console errors and the requests to hosts other than 127.0.0.1 (refused and counted). Without
    ``scene`` the 3D scene's own requests are refused too: headless Chromium renders it in
    software on the tab's main thread, which slows every other action in the tab."""
    errors, outside = [], []

    def handle(route):
        url = route.request.url
        if urlparse(url).hostname not in ("127.0.0.1", None):
            outside.append(url)
            route.abort()
        elif not scene and not url.startswith(lab["url"]):
            route.abort()
        else:
            route.continue_()

    page.route("**/*", handle)
    page.on("console", lambda message: errors.append(message.text) if message.type == "error" else None)
    page.on("pageerror", lambda error: errors.append(str(error)))
    page.goto(lab["url"])
    page.wait_for_selector(".preset-select select", timeout=60000)
    page.wait_for_function("() => window.Bokeh && Bokeh.documents.length > 0", polling=200, timeout=60000)
    if status(lab)["preset"] != preset:
        choose_preset(page, lab, preset)
    return errors, outside


def model(page, name: str, expression: str):
    """``expression`` of the bokeh model ``name`` (bound to ``m``; None while it is not in the page)."""
    return page.evaluate(f"() => {{ const m = Bokeh.documents[0].get_model_by_name({name!r});"
                         f" return m === null ? null : ({expression}); }}")


def wait_model(page, name: str, condition: str, timeout=60000):
    page.wait_for_function(f"() => {{ const m = Bokeh.documents[0].get_model_by_name({name!r});"
                           f" return m !== null && ({condition}); }}", polling=200, timeout=timeout)


PAGE_REFRESH = ("[...Bokeh.documents[0].all_models].find(m => m.sent !== undefined && m.drawn !== undefined)"
                ".drawn")
"""The number of the last refresh the page drew (app/lab/pace.py)."""


def page_caught_up(page) -> None:
    """Wait until the page has drawn a refresh made after this call: the refresh after the next one
    (the next may have been made before, and be on its way)."""
    after = page.evaluate(f"() => {PAGE_REFRESH}") + 2
    page.wait_for_function(f"() => {PAGE_REFRESH} >= {after}", polling=100, timeout=60000)


def choose_preset(page, lab, name: str):
    """Choose ``name`` in the page and wait until the page shows it (its plots, text and panes)."""
    page.select_option(".preset-select select", label=PRESETS[name].menu_name)
    wait_status(lab, lambda s: s["preset"] == name)
    page_caught_up(page)


def set_speed(page, lab, label: str):
    """Press the speed slider's keys until it shows ``label`` (a value of app.dashboard.SPEEDS)."""
    from granlab.app.lab.dashboard import SPEEDS

    handle = page.locator(".speed-slider .noUi-handle")
    target = list(SPEEDS).index(label)
    deadline = time.time() + 60
    while time.time() < deadline:
        current = list(SPEEDS).index(next(k for k, v in SPEEDS.items() if v == speed_in(status(lab))))
        if current == target:
            return
        if float(handle.get_attribute("aria-valuenow")) == current:  # the last key is in effect: the next one
            handle.focus()
            page.keyboard.press("ArrowRight" if current < target else "ArrowLeft")
        time.sleep(0.2)
    raise AssertionError(f"the speed never reached {label}")


def speed_in(s: dict) -> float:
    speed = s["settings"]["speed"]
    return float("inf") if speed == "inf" else float(speed)


def test_the_lab_waits_for_its_first_tab_and_starts_the_preset_at_t0(page, lab):
    s = status(lab)
    assert s["state"] == "waiting" and s["step"] == 0 and s["preset"] == "ratchet"
    open_dashboard(page, lab)
    s = wait_status(lab, lambda s: s["state"] == "running" and s["step"] > 0)
    assert s["tabs"] >= 1 and s["time"] < 30.0
    # the key plots are empty while the box is compressed: the page says what they wait for
    try:
        expect(page.locator(".plots-waiting")).to_contain_text("the load–strain loop starts with cycling. Now: "
                                                               "compressing", timeout=15000)
    except AssertionError:
        assert status(lab)["stage"] != "compressing"  # (only if the compression ended first)


def test_the_page_asks_nothing_of_other_hosts_and_logs_no_error_with_the_scene_on(page, lab):
    errors, outside = open_dashboard(page, lab, scene=True)
    page.wait_for_selector("iframe")
    frames = []
    for _ in range(300):  # the iframe is about:blank until its page starts loading
        frames = [f for f in page.frames if f.url.startswith("http") and f != page.main_frame]
        if frames:
            break
        page.wait_for_timeout(200)
    frame = frames[0]
    frame.wait_for_function("() => window.__viserTestpoints && window.__viserTestpoints.rendererInfo"
                            " && window.__viserTestpoints.rendererInfo.render.frame > 5", polling=200, timeout=90000)
    count = frame.evaluate("() => window.__viserTestpoints.rendererInfo.render.frame")
    frame.wait_for_function(f"() => window.__viserTestpoints.rendererInfo.render.frame > {count}", polling=200,
                            timeout=30000)
    page.locator(".pane-choice button", has_text="About").click()
    page.locator(".pane-choice button", has_text="Analysis").click()
    page.wait_for_timeout(2000)
    assert outside == [] and errors == []


def test_every_preset_draws_its_disks_and_boundary_inside_the_view(page, lab):
    open_dashboard(page, lab)
    for name, cls in PRESETS.items():
        if status(lab)["preset"] != name:
            choose_preset(page, lab, name)
        s = wait_status(lab, lambda s: s["preset"] == name and s["time"] > 0.0)
        view = wait_status(lab, lambda v: v["disks"] == s["particles"] and v["frames"] > 0, read=scene)
        # the scene's camera is framed on what it draws: every disk of the preset in view
        view = wait_status(lab, lambda v: v["disks_in_view"] == v["disks"], read=scene)
        if name in ("aggregation", "compression"):
            assert view["cell"] is not None and view["walls"] == 0
        elif name not in ("closed-path", "collision"):  # pairs of disks in free space
            assert view["walls"] >= 1
        legend = page.locator(".legend")
        expect(legend).to_contain_text("force network", timeout=10000)
        expect(legend).to_contain_text("walls" if view["walls"] else "disk colour", timeout=10000)


def test_plots_hold_200_samples_a_load_cycle_at_the_default_speed_and_at_the_highest(page, lab):
    open_dashboard(page, lab, "ratchet16")
    for speed in ("0.5", "max"):
        set_speed(page, lab, speed)
        s = wait_status(lab, lambda s: s["stage"] == "cycling" and s["cycle"] >= 2, timeout=120)
        cycle = s["cycle"] + 1
        wait_status(lab, lambda s: s["cycle"] > cycle, timeout=120)  # one whole cycle drawn at this speed
        page.locator(".pane-choice button", has_text="Key plots").click()
        wait_model(page, "coulomb-cone-paths", "m.data.t.length > 0")
        # the watched contact drawn most in the last period of simulated time
        t = model(page, "coulomb-cone-paths", "Array.from(m.data.t)")
        labels = model(page, "coulomb-cone-paths", "Array.from(m.data.label)")
        recent = [label for label, ti in zip(labels, t) if ti > max(t) - 10.0]
        assert max(recent.count(label) for label in set(recent)) >= 100
        page.locator(".pane-choice button", has_text="More plots").click()
        wait_model(page, "q-gamma-path", f"m.data.cycle.includes({cycle})")
        assert model(page, "q-gamma-path", f"m.data.cycle.filter(c => c == {cycle}).length") >= 200
    set_speed(page, lab, "0.5")


def test_the_strain_plot_shows_the_drift_from_the_reference_cycle(page, lab):
    open_dashboard(page, lab, "ratchet16")
    wait_model(page, "strain-cycles", "m.data.cycle.length >= 4", timeout=120000)
    cycles = model(page, "strain-cycles", "Array.from(m.data.cycle)")
    strain = model(page, "strain-cycles", "Array.from(m.data.strain)")
    low, high = model(page, "figure-strain-per-cycle", "[m.y_range.start, m.y_range.end]")
    assert min(cycles) == PRESETS["ratchet16"].reference_cycle and strain[0] == 0.0
    # the range holds the points and is fitted to them (drift ~ 5e-8 a cycle: not hidden by cycle 0)
    assert low <= min(strain) and max(strain) <= high
    assert high - low < 1.5 * (max(strain) - min(strain))


def test_friction_slider_changes_mu_in_status(page, lab):
    open_dashboard(page, lab)
    handle = page.locator(".friction-slider .noUi-handle")
    box = handle.bounding_box()
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.down()
    page.mouse.move(box["x"] + box["width"] / 2 + 60, box["y"] + box["height"] / 2, steps=5)
    page.mouse.up()
    s = wait_status(lab, lambda s: s["settings"]["friction"] != 0.2)
    assert 0.2 < s["settings"]["friction"] <= 1.0


def test_a_refused_value_goes_back_to_the_value_in_effect_with_a_message_beside_it(page, lab):
    open_dashboard(page, lab, "ratchet16")
    before = status(lab)["settings"]["amplitude"]
    box = page.locator(".amplitude-input input")
    box.fill("-0.5")
    page.keyboard.press("Enter")
    note = page.locator(".note-amplitude")
    expect(note).to_contain_text("Amplitude Δσ = -0.5 is not allowed: an amplitude from 0 to 2 P0", timeout=30000)
    expect(box).to_have_value(str(before), timeout=30000)
    s = status(lab)
    assert s["settings"]["amplitude"] == before and s["state"] == "running"
    step = s["step"]
    wait_status(lab, lambda s: s["step"] > step)


def test_a_number_of_disks_typed_stays_in_its_box_while_other_settings_change_until_applied(page, lab):
    """N and the seed wait for their Apply button: a page refresh that shows another setting's new
    value (here the damping, typed after N) leaves the N typed in its box, and Apply restarts with it."""
    open_dashboard(page, lab, "ratchet16")
    type_into(page, ".particles-input", "20")
    damping = status(lab)["settings"]["damping_ratio"]
    page.locator(".damping-slider .noUi-handle").focus()
    page.keyboard.press("ArrowRight")
    wait_status(lab, lambda s: s["settings"]["damping_ratio"] > damping)
    expect(page.locator(".damping-slider").first).to_contain_text(f"{damping + 0.05:.2f}")  # that refresh drawn
    expect(page.locator(".particles-input input")).to_have_value("20")
    page.click(".apply-reset-button button")
    wait_status(lab, lambda s: s["settings"]["particles"] == 20 and s["particles"] == 20)
    page.click(".defaults-button button")
    wait_status(lab, lambda s: s["settings"]["particles"] == 16 and s["settings"]["damping_ratio"] == damping)
    expect(page.locator(".particles-input input")).to_have_value("16")


def test_at_1366_by_768_the_controls_column_says_it_scrolls_and_no_control_is_cut(page, lab):
    """A laptop's screen is too short for the whole column: a line at its foot says more lies below
    (gone at the end); each control, scrolled to, lies whole inside the column."""
    page.set_viewport_size({"width": 1366, "height": 768})
    open_dashboard(page, lab, "ratchet16")
    column = page.locator(".controls")
    assert column.evaluate("e => e.scrollHeight > e.clientHeight + 50")
    cue = page.locator(".more-below")
    expect(cue).to_contain_text("more controls below")
    box, shown = column.bounding_box(), cue.bounding_box()
    assert box["y"] + box["height"] - 40 <= shown["y"] and shown["y"] + shown["height"] <= box["y"] + box["height"] + 1
    assert cue.evaluate("e => getComputedStyle(e).opacity") == "1"
    controls = column.locator("input:visible, select:visible, button:visible, .noUi-handle:visible")
    assert controls.count() >= 20
    for k in range(controls.count()):
        control = controls.nth(k)
        control.scroll_into_view_if_needed()
        where = control.bounding_box()
        assert box["x"] <= where["x"] and where["x"] + where["width"] <= box["x"] + box["width"], control
        assert box["y"] <= where["y"] and where["y"] + where["height"] <= box["y"] + box["height"] + 1, control
    assert cue.evaluate("e => getComputedStyle(e).opacity") == "0"  # the end of the column: nothing more below


def type_into(page, css: str, text: str) -> None:
    box = page.locator(f"{css} input")
    box.fill(text)
    page.keyboard.press("Enter")


def answers_within(lab, predicate, seconds: float) -> float:
    """How long until ``/status`` matches ``predicate`` (it must within ``seconds``)."""
    start = time.perf_counter()
    wait_status(lab, predicate, timeout=seconds)
    return time.perf_counter() - start


def test_a_typo_in_the_period_never_freezes_the_lab(page, lab):
    """Period T = 10000000 typed, then 10 back, Step, Pause: the typo is refused with both bounds,
    the period acts at once, and the lab answers every command within half a second."""
    open_dashboard(page, lab, "ratchet16")
    choose_preset(page, lab, "ratchet16")  # from t = 0 with the preset's own settings
    wait_status(lab, lambda s: s.get("cycle", 0) >= 1, timeout=120)
    type_into(page, ".period-input", "10000000")
    expect(page.locator(".note-period")).to_contain_text("Period T = 10000000 is not allowed: a period from 100 time "
                                                        "steps", timeout=10000)
    expect(page.locator(".note-period")).to_contain_text("<= T <= 7702")
    expect(page.locator(".period-input input")).to_have_value("10", timeout=10000)
    type_into(page, ".period-input", "20")
    s = wait_status(lab, lambda s: s["settings"]["period"] == 20.0, timeout=5)
    assert s["cycle_time"] == 20.0 and not s["pending"]  # at once, at the same fraction of the cycle
    type_into(page, ".period-input", "10")
    wait_status(lab, lambda s: s["cycle_time"] == 10.0, timeout=5)
    play = page.locator(".play-button button")
    page.click(".step-button button")
    assert answers_within(lab, lambda s: s["state"] in ("stepping", "paused"), 0.5 + 0.4) < 0.9
    wait_status(lab, lambda s: s["state"] == "paused", timeout=10)
    expect(play).to_have_text("Play", timeout=5000)  # the button follows the state (every 0.2 s)
    play.click()
    step = wait_status(lab, lambda s: s["state"] == "running", timeout=2)["step"]
    expect(play).to_have_text("Pause", timeout=5000)
    play.click()
    assert answers_within(lab, lambda s: s["state"] == "paused", 1.0) < 0.5 + 0.4  # /status is read every 0.2 s
    paused = status(lab)["step"]
    time.sleep(0.5)
    assert status(lab)["step"] == paused >= step
    expect(play).to_have_text("Play", timeout=5000)
    play.click()
    wait_status(lab, lambda s: s["state"] == "running", timeout=2)


def test_a_hostile_file_and_a_save_never_stop_the_simulation(page, lab):
    """An extended XYZ file whose last count line says 10^12 atoms is refused by name, beside the
    Load button, while the run goes on; a save is written while the simulation keeps stepping,
    its progress shown beside the Save button."""
    open_dashboard(page, lab, "ratchet16")
    packing = (Path(__file__).parent / "data" / "lammps" / "packing.xyz").read_text()
    (lab["data"] / "bad.xyz").write_text(packing + "1000000000000\ncomment\n1 2 3\n")
    expect(page.locator(".load-select option", has_text="bad.xyz")).to_have_count(1, timeout=30000)
    page.select_option(".load-select select", value="bad.xyz")
    step = status(lab)["step"]
    page.click(".load-button button")
    expect(page.locator(".note-load")).to_contain_text("bad.xyz, frame 1: the count line says 1000000000000 particles",
                                                       timeout=60000)
    s = status(lab)
    assert s["preset"] == "ratchet16" and s["state"] == "running" and s["step"] > step
    wait_status(lab, lambda s: s["time"] > 5.0, timeout=120)
    type_into(page, ".save-name", "busy.h5")
    page.click(".save-button button")
    # while the save runs (its own process, a second or more): the engine steps on, and the page says so
    first = wait_status(lab, lambda s: s["jobs"], timeout=30)
    steps, shown = [first["step"]], set()
    while (s := status(lab))["jobs"]:
        steps.append(s["step"])
        shown |= {css for css in (".job-save", ".readout") if page.locator(css, has_text="saving busy.h5…").count()}
    assert steps[-1] > steps[0] + 500, steps
    assert shown == {".job-save", ".readout"}
    expect(page.locator(".note-save")).to_contain_text("saved", timeout=60000)
    expect(page.locator(".job-save")).to_be_hidden()
    assert (lab["data"] / "busy.h5").exists()


def test_a_loading_change_shows_the_value_in_effect_until_the_next_cycle(page, lab):
    """Δσ typed while cycling waits for the next cycle: the box keeps the value in effect, the line
    beside it says what comes and when (counted down at 0.05 cycles per second), Cancel drops it;
    a change of μ is marked on the strain plot and the fit starts two whole cycles after it."""
    open_dashboard(page, lab, "ratchet16")
    choose_preset(page, lab, "ratchet16")
    wait_status(lab, lambda s: s.get("cycle", 0) >= 1, timeout=120)
    expect(page.locator(".play-button button")).to_have_text("Pause", timeout=5000)
    page.click(".play-button button")  # paused: a waiting change waits for the run to go on
    wait_status(lab, lambda s: s["state"] == "paused", timeout=5)
    type_into(page, ".amplitude-input", "0.25")
    s = wait_status(lab, lambda s: s["pending"] == {"amplitude": 0.25}, timeout=5)
    assert s["settings"]["amplitude"] == 0.2
    expect(page.locator(".note-amplitude")).to_contain_text("from the next cycle: Amplitude Δσ = 0.25 (when the run "
                                                            "goes on)", timeout=5000)
    expect(page.locator(".amplitude-input input")).to_have_value("0.2", timeout=5000)
    page.click(".cancel-pending-button button")
    wait_status(lab, lambda s: not s["pending"] and s["settings"]["amplitude"] == 0.2, timeout=5)
    expect(page.locator(".note-pending")).to_contain_text("cancelled: Δσ = 0.25 (the values in effect stay)")
    expect(page.locator(".note-amplitude")).to_be_hidden(timeout=5000)
    set_speed(page, lab, "0.05")  # a cycle lasts 20 s
    type_into(page, ".amplitude-input", "0.25")
    cycle = wait_status(lab, lambda s: s["pending"] == {"amplitude": 0.25}, timeout=5)["cycle"]
    expect(page.locator(".play-button button")).to_have_text("Play", timeout=5000)
    page.click(".play-button button")
    expect(page.locator(".note-amplitude")).to_contain_text("from the next cycle: Amplitude Δσ = 0.25 (in ",
                                                            timeout=10000)
    set_speed(page, lab, "max")
    s = wait_status(lab, lambda s: s["cycle"] > cycle, timeout=60)
    assert s["settings"]["amplitude"] == 0.25 and not s["pending"]
    expect(page.locator(".amplitude-input input")).to_have_value("0.25", timeout=5000)
    expect(page.locator(".note-amplitude")).to_be_hidden(timeout=5000)
    page.check(".friction-infinite input")
    s = wait_status(lab, lambda s: s["settings"]["friction"] == "inf", timeout=5)
    change = s["changes"][-1]
    assert change["text"] == "μ 0.2 → ∞" and s["fit_from"] == {"cycle": math.ceil(change["cycle"]) + 2,
                                                               "after": "after μ 0.2 → ∞"}
    wait_model(page, "strain-per-cycle-changes", "m.data.text.includes('μ 0.2 → ∞')")
    wait_model(page, "strain-per-cycle-changes", "m.data.text.some(t => t.startsWith('Δσ 0.2 → 0.25'))")
    expect(page.locator(".note-friction")).to_contain_text("applied", timeout=5000)
    expect(page.locator(".friction-slider")).to_contain_text("not in effect: μ = ∞")


LAYOUT = r"""() => {
  const ctx = document.createElement("canvas").getContext("2d");
  const width = (text, size, style, family) => {
    ctx.font = `${style || "normal"} ${size} ${family || "helvetica"}`;
    return Math.max(...String(text).split("\n").map(line => ctx.measureText(line).width));
  };
  const views = [];
  const walk = (view) => {
    if (view.model.type === "Figure" && view.model.name && view.model.name.startsWith("figure-")) views.push(view);
    for (const c of (view.child_views ?? [])) walk(c);
  };
  for (const r of Bokeh.index.roots) walk(r);
  const out = [];
  const shown = new Map();  // figure name -> its largest view shown (a pane shown before may leave one behind)
  for (const v of views) {
    const rect = v.el.getBoundingClientRect();
    if (rect.width === 0 || rect.height === 0 || v.el.offsetParent === null) continue;   // not shown
    const other = shown.get(v.model.name);
    if (!other || rect.width * rect.height > other.area) shown.set(v.model.name, {view: v, area: rect.width * rect.height});
  }
  for (const {view: v} of shown.values()) {
    const m = v.model, f = v.frame.bbox, c = v.bbox;
    const problems = [];
    const title = m.title;
    if (title && title.text) {
      const w = width(title.text, title.text_font_size, title.text_font_style, title.text_font);
      const left = f.left + (title.offset || 0);
      if (left + w > c.width + 1) problems.push(`title runs ${Math.round(left + w - c.width)} px off the right`);
    }
    for (const axis of [...m.below, ...m.left]) {
      if (!axis.axis_label) continue;
      const w = width(axis.axis_label, axis.axis_label_text_font_size, axis.axis_label_text_font_style, axis.axis_label_text_font);
      const vertical = m.left.includes(axis);
      const span = vertical ? c.height : c.width;
      const centre = vertical ? f.top + f.height / 2 : f.left + f.width / 2;
      if (centre - w / 2 < -1 || centre + w / 2 > span + 1) problems.push(`${vertical ? "y" : "x"} label cut (${Math.round(w)} px on ${Math.round(span)})`);
    }
    for (const rv of v.renderer_views.values()) {
      if (rv.model.type !== "Legend" || !rv.bbox || !(rv.bbox.width > 0)) continue;
      const b = rv.bbox;
      if (b.left < -1 || b.top < -1 || b.right > c.width + 1 || b.bottom > c.height + 1) problems.push("legend outside its figure");
      const overlap = !(b.right <= f.left + 1 || b.left >= f.right - 1 || b.bottom <= f.top + 1 || b.top >= f.bottom - 1);
      if (overlap) problems.push("legend covers the plot");
    }
    if (f.height < 250) problems.push(`plot area ${Math.round(f.height)} px high`);
    out.push({name: m.name, frame: Math.round(f.height), width: Math.round(f.width), problems});
  }
  return out;
}"""
"""Each bokeh figure shown in the page, measured as a viewer would look at it: its name, the height of
its drawing area, and what is wrong (a title running off its figure, an axis label cut, a legend
outside its figure or over the plot, a drawing area under 250 px)."""


PROJECTOR_SIZES = ((1366, 768), (1920, 1080))


def test_every_plot_of_every_preset_is_readable_on_a_projector(browser, lab):
    """Each preset once, its plots measured at both screen sizes (one preset switch serves the two)."""
    page = browser.new_page(viewport={"width": PROJECTOR_SIZES[0][0], "height": PROJECTOR_SIZES[0][1]})
    try:
        seen = []
        open_dashboard(page, lab, "ratchet16")
        for name, cls in PRESETS.items():
            choose_preset(page, lab, name)
            if name == "ratchet16":  # its watched contacts fill the cone plot's legend
                wait_status(lab, lambda s: s.get("cycle", 0) >= 1, timeout=120)
            time.sleep(1.0)
            for size in PROJECTOR_SIZES:
                page.set_viewport_size({"width": size[0], "height": size[1]})
                seen += measure_every_figure(page, name, cls, size)
        assert len(seen) == len(PROJECTOR_SIZES) * sum(len(cls.plots) for cls in PRESETS.values())
    finally:
        page.close()


def measure_every_figure(page, name, cls, size) -> list:
    """The preset ``name``'s selector and figures, shown in both panes at ``size``: what was measured."""
    seen = []
    box = page.locator(".preset-select select").bounding_box()
    width = page.locator(".preset-select select").evaluate(
        "s => { const c = document.createElement('canvas').getContext('2d'); c.font = getComputedStyle(s).font; "
        "return c.measureText(s.selectedOptions[0].text).width; }")
    assert width + 24 <= box["width"], f"{size} {name}: the preset selector cuts {cls.menu_name!r}"
    for pane, plots in (("Key plots", cls.key_plots), ("More plots", set(cls.plots) - set(cls.key_plots))):
        page.locator(".pane-choice button", has_text=pane).click()
        expected = {f"figure-{plot}" for plot in plots}
        deadline = time.time() + 20.0
        shown = None  # "More plots" of a preset that has none shows no figure: wait for that too
        while shown != expected:
            assert time.time() < deadline, f"{name}, {pane}: {shown}, not {expected}"
            time.sleep(0.2)
            shown = {figure["name"] for figure in page.evaluate(LAYOUT)}
        time.sleep(0.5)  # the last layout pass
        for figure in page.evaluate(LAYOUT):
            seen.append((name, pane, figure["name"]))
            assert not figure["problems"], f"{size} {name}, {pane}, {figure['name']}: {figure['problems']}"
            assert figure["frame"] >= 250
    return seen


def test_preset_switch_builds_its_plots_and_its_text(page, lab):
    open_dashboard(page, lab, "ratchet")
    choose_preset(page, lab, "block")
    wait_model(page, "series-block-load", "m.data.t.length > 3")
    wait_model(page, "block-cone-paths", "m.data.x0.length > 3")
    page.locator(".pane-choice button", has_text="About").click()
    expect(page.locator(".teaching h1")).to_contain_text("minimum sliding", timeout=10000)


SWITCHES = ("elliptic", "block", "collision", "closed-path", "compression", "aggregation", "ratchet", "ratchet16",
            "block", "elliptic", "compression", "closed-path", "collision", "ratchet", "aggregation", "ratchet16")
"""From ratchet16, each preset entered from two others."""
FIRST_SAMPLE = {"collision": 0.05}
"""The latest a preset's first plotted sample may come, where it is not t = 0: the collision's
contact samples start when the disks first touch, at t = 0.025."""
PAGE_PLOTS = """() => {
  const out = {plots: {}}
  for (const m of Bokeh.documents[0].all_models) {
    if (m.type !== "Figure" || !(m.name || "").startsWith("figure-") || !m.document) continue
    const plot = out.plots[m.name.slice(7)] = {title: m.title.text, rows: 0, t0: null, labels: []}
    for (const r of m.renderers) {
      const source = r.data_source
      if (!source || !source.name) continue  // the legend's placeholders
      const data = source.data, n = (data[Object.keys(data)[0]] || []).length
      plot.rows += n
      if (source.name.startsWith("series-") && data.t && n) plot.t0 = data.t[0]
      if (data.label) plot.labels = [...new Set(data.label)]
    }
  }
  return out
}"""


def test_a_preset_switch_is_a_clean_slate_on_a_busy_machine(page, lab):
    """Every preset entered from two others, with two busy processes beside the lab: from the first
    refresh made after the switch, its key plots' time series start at t = 0, and a cone plot names
    only the contacts the preset watches and the μ in effect."""
    open_dashboard(page, lab, "ratchet16")
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    try:
        for name in SWITCHES:
            choose_preset(page, lab, name)  # returns once the page drew a refresh made after the switch
            deadline = time.time() + 3
            while time.time() < deadline:  # each refresh from then on shows the new preset only
                shown = page.evaluate(PAGE_PLOTS)
                s = status(lab)
                friction = s["settings"].get("friction")
                mu = "∞" if friction == "inf" else f"{friction:g}"
                for plot in PRESETS[name].key_plots:  # the plots the page shows after a switch
                    drawn = shown["plots"][plot]
                    where = f"{name}, plot {plot}: {drawn}"
                    assert drawn["t0"] is None or 0 <= drawn["t0"] <= FIRST_SAMPLE.get(name, 0), where
                    if plot.endswith("cone"):
                        assert f"μ = {mu}" in drawn["title"], where
                        assert set(drawn["labels"]) <= set(s["watched_labels"]), f"{where}; {s['watched_labels']}"
    finally:
        for process in busy:
            process.kill()


def test_save_then_replay_with_a_timeline(page, lab):
    open_dashboard(page, lab, "ratchet16")
    wait_status(lab, lambda s: s["preset"] == "ratchet16" and s["cycle"] >= 2, timeout=90)  # contacts watched
    page.fill(".save-name input", "roundtrip.h5")
    page.keyboard.press("Enter")
    page.click(".save-button button")
    expect(page.locator(".note-save")).to_contain_text("saved", timeout=30000)
    assert (lab["data"] / "roundtrip.h5").exists()
    expect(page.locator(".load-select option", has_text="roundtrip.h5")).to_have_count(1, timeout=30000)
    page.select_option(".load-select select", value="roundtrip.h5")
    page.click(".load-button button")
    s = wait_status(lab, lambda s: s["preset"] == "replay:roundtrip.h5")
    assert s["particles"] == 16 and s["replay"]["of"] == "ratchet16" and s["replay"]["frames"] >= 30
    # the replay plays at the lab's speed to its last frame and stops there
    s = wait_status(lab, lambda s: s["state"] == "paused", timeout=60)
    assert s["replay"]["frame"] == s["replay"]["frames"] - 1
    expect(page.locator(".timeline")).to_be_visible(timeout=30000)
    drawn = scene(lab)["frames"]
    track = page.locator(".replay-slider .noUi-base").bounding_box()
    page.mouse.click(track["x"] + 0.1 * track["width"], track["y"] + track["height"] / 2)
    s = wait_status(lab, lambda s: s["replay"]["frame"] <= 0.3 * s["replay"]["frames"])
    wait_status(lab, lambda v: v["frames"] > drawn, read=scene)  # the scene draws the frame scrubbed to
    page.click(".step-button button")  # the next frame
    wait_status(lab, lambda t: t["replay"]["frame"] == s["replay"]["frame"] + 1)
    # the plots show the saved series up to the frame: at the end, the strain per cycle and the cone paths
    handle = page.locator(".replay-slider .noUi-handle")
    expect(handle).to_have_attribute("aria-valuenow", f"{s['replay']['frame'] + 2}.0", timeout=30000)  # from 1
    track = page.locator(".replay-slider .noUi-base").bounding_box()
    page.mouse.click(track["x"] + 0.97 * track["width"], track["y"] + track["height"] / 2)
    wait_status(lab, lambda s: s["replay"]["frame"] >= 0.9 * (s["replay"]["frames"] - 1))
    wait_model(page, "coulomb-cone-paths", "m.data.x0.length > 10")
    # each watched contact keeps its own colour and its name (a wall by name) as in the run
    replayed = status(lab)
    assert replayed["watched_labels"] and len(replayed["watched_labels"]) == len(replayed["watched"])
    wait_model(page, "coulomb-cone-paths", "new Set(m.data.color).size >= 2")
    colors = model(page, "coulomb-cone-paths", "[...new Set(m.data.color)]")
    labels = model(page, "coulomb-cone-paths", "[...new Set(m.data.label)]")
    assert len(colors) == len(labels) and set(labels) <= set(replayed["watched_labels"])
    expect(page.locator(".amplitude-input input")).to_be_disabled()


def test_two_tabs_both_update(browser, lab):
    pages = [browser.new_page(), browser.new_page()]
    for page in pages:
        open_dashboard(page, lab, "ratchet16")
    wait_status(lab, lambda s: s["tabs"] >= 2)
    for page in pages:
        wait_model(page, "coulomb-cone-paths", "true")
    lengths = [model(page, "coulomb-cone-paths", "m.data.x0.length") for page in pages]
    for page, length in zip(pages, lengths):
        wait_model(page, "coulomb-cone-paths", f"m.data.x0.length > {length}")
    for page in pages:
        page.close()


RECORD_REFRESHES = """
window.refreshes = []
const Native = window.WebSocket
window.WebSocket = class extends Native {
  constructor(...args) {
    super(...args)
    this.addEventListener("message", (event) => {  // before bokeh reads it: what the page had drawn then
      if (typeof event.data !== "string" || !event.data.includes('"sent"')) return
      for (const change of JSON.parse(event.data).events || []) {
        if (change.attr !== "sent") continue
        const pacer = Bokeh.documents[0].get_model_by_id(change.model.id)
        window.refreshes.push({sent: change.new, drawn: pacer.drawn, t: performance.now()})
      }
    })
  }
}
"""


def test_a_page_that_draws_slowly_is_sent_a_refresh_only_once_it_drew_the_last(browser, lab):
    """A browser slowed eightfold (a phone, a busy laptop) never has refreshes queued: each arrives
    after the page drew the one before (or after the server waited DRAW_WAIT_SECONDS), so a click
    waits behind one refresh at most."""
    page = browser.new_page(viewport={"width": 1366, "height": 768})
    page.add_init_script(RECORD_REFRESHES)
    open_dashboard(page, lab, "ratchet16")
    slow = page.context.new_cdp_session(page)
    slow.send("Emulation.setCPUThrottlingRate", {"rate": 8})
    page.wait_for_timeout(15000)
    slow.send("Emulation.setCPUThrottlingRate", {"rate": 1})
    arrived = page.evaluate("() => window.refreshes")
    assert len(arrived) >= 5
    queued = [later for earlier, later in zip(arrived, arrived[1:])
              if later["drawn"] < later["sent"] - 1 and later["t"] - earlier["t"] < 1000 * DRAW_WAIT_SECONDS]
    assert not queued, arrived
    page.close()


def test_analysis_tab_shows_the_force_network_and_only_the_figures_the_analysis_has(page, lab):
    open_dashboard(page, lab, "ratchet16")
    before = wait_status(lab, lambda s: s["stage"] == "cycling")["analysis_seq"]  # compressed: the disks touch
    page.locator(".pane-choice button", has_text="Analysis").click()
    # no empty frame before an analysis has run
    expect(page.locator(".analysis-button button")).to_be_visible()
    assert model(page, "figure-analysis-network", "m.visible") is (before > 0)
    page.select_option(".analysis-select select", value="status")
    page.click(".analysis-button button")
    s = wait_status(lab, lambda s: s["analysis_seq"] > before, timeout=60)
    expect(page.locator(".analysis-summary")).to_contain_text("Critical contacts M_c", timeout=30000)
    wait_model(page, "analysis-segments", "m.data.x0.length > 0")
    assert model(page, "analysis-segments", "m.data.x0.length") >= s["particles"]  # a packed box
    assert page.locator(".analysis-summary").inner_text().count("nan") == 0
    assert model(page, "figure-analysis-network", "m.visible") is True
    assert model(page, "figure-analysis-forces", "m.visible") is False


def scene_socket(page) -> tuple[str, int]:
    """The scene's websocket address as the tab's iframe gives it (viser's page port, and the
    token's path with tokens), and the port of viser's page."""
    src = urlparse(page.locator("iframe").get_attribute("src"))
    given = parse_qs(src.query).get("websocket")
    return (given[0] if given else f"ws://{src.netloc}/"), src.port


def handshake(address: str, origin: str | None) -> int:
    """The HTTP status the scene's websocket answers: 101 if it opens."""
    import viser
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    try:
        with connect(address, origin=origin, subprotocols=[f"viser-v{viser.__version__}"], open_timeout=10):
            return 101
    except InvalidStatus as error:
        return error.response.status_code


def dashboard_handshake(address: str, origin: str) -> int:
    """The HTTP status the dashboard's (bokeh's) websocket answers: 101 if it opens."""
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    try:
        with connect(address, origin=origin, subprotocols=["bokeh"], open_timeout=10):
            return 101
    except InvalidStatus as error:
        return error.response.status_code


def test_the_scene_websocket_admits_only_the_scene_page_origin(page, lab):
    open_dashboard(page, lab)
    address, port = scene_socket(page)
    assert handshake(address, "http://evil.example") == 403
    assert handshake(address, f"http://localhost:{port + 1 if port < 65535 else port - 1}") == 403
    assert handshake(address, f"http://127.0.0.1:{port}") == 101

