"""The lab as a teacher's instrument, in headless Chromium: links that carry a setup, the preset's
own settings back in one press, named speeds. What is checked is what a teacher would check: the
values in effect (the lab's ``/status``) and the widgets showing them."""

import json
import math
import re
from urllib.parse import parse_qs, urlparse

import pytest
from playwright.sync_api import expect

from granlab.app.lab import lessons
from granlab.app.lab.dashboard import SPEEDS
from granlab.app.lab.server import spawn
from granlab.engine.protocols.presets import PRESETS, preset_settings
from tests.test_browser import PAGE_REFRESH, open_dashboard, scene, status, wait_model, wait_status
from tests.test_browser_sessions import lab_only
from tests.test_lab_access import status_of


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    data = tmp_path_factory.mktemp("classroom-lab-data")
    process, url, _ = spawn(data)
    yield {"url": url, "process": process, "data": data}
    process.terminate()
    process.wait(timeout=30)


def settings_in_effect(lab) -> dict:
    settings = status(lab)["settings"]
    return {key: math.inf if value == "inf" else value for key, value in settings.items()}


def test_a_link_sets_up_the_lab_exactly_and_copy_link_gives_it_back(browser, lab):
    context = browser.new_context(viewport={"width": 1366, "height": 768},
                                  permissions=["clipboard-read", "clipboard-write"])
    page = context.new_page()
    lab_only(page, lab)
    page.goto(lab["url"] + "?preset=ratchet16&friction=0.45&tangential_model=angle&damping_ratio=0.55&speed=fast")
    wait_status(lab, lambda s: s["preset"] == "ratchet16" and s["settings"]["friction"] == 0.45)
    expected = preset_settings("ratchet16", friction=0.45, tangential_model="angle", damping_ratio=0.55,
                               speed=PRESETS["ratchet16"].speeds["fast"])
    assert settings_in_effect(lab) == expected.__dict__
    # the widgets show the values in effect
    expect(page.locator(".friction-slider").first).to_contain_text("0.45")
    expect(page.locator(".damping-slider").first).to_contain_text("0.55")
    expect(page.locator(".model-select select")).to_have_value("angle")
    expect(page.locator(".speed-fast button")).to_have_class("bk-btn bk-btn-primary")
    expect(page.locator(".speed-slow button")).to_have_class("bk-btn bk-btn-default")
    left_at = wait_status(lab, lambda s: s["time"] > 40.0, timeout=60)["time"]
    # a named speed pressed is the speed in effect
    page.locator(".speed-slow button").click()
    wait_status(lab, lambda s: s["settings"]["speed"] == PRESETS["ratchet16"].speeds["slow"])
    expect(page.locator(".speed-slow button")).to_have_class("bk-btn bk-btn-primary")

    page.locator(".copy-link-button button").click()
    expect(page.locator(".note-preset")).to_contain_text("link copied", timeout=10000)
    expect(page.locator(".note-preset")).to_be_visible()
    link = page.evaluate("() => navigator.clipboard.readText()")
    query = {key: values[0] for key, values in parse_qs(urlparse(link).query).items()}
    assert link.startswith(lab["url"].split("?")[0])
    assert query == {"preset": "ratchet16", "friction": "0.45", "tangential_model": "angle", "damping_ratio": "0.55",
                     "speed": "slow"}

    # the lab moves on to something else; the copied link brings the setup back in a new tab
    page.select_option(".preset-select select", label=PRESETS["block"].menu_name)
    wait_status(lab, lambda s: s["preset"] == "block")
    again = context.new_page()
    lab_only(again, lab)
    again.goto(link)
    s = wait_status(lab, lambda s: s["preset"] == "ratchet16")
    assert settings_in_effect(lab) == expected.__dict__ | {"speed": PRESETS["ratchet16"].speeds["slow"]}
    assert s["time"] < left_at  # from t = 0, at the slow speed: 40 takes it more than 10 s
    expect(again.locator(".note-preset")).to_be_visible(timeout=10000)
    expect(again.locator(".note-preset")).to_contain_text("the link's setup: Ratcheting with 16 disks")
    context.close()


def test_a_link_with_a_value_the_lab_does_not_allow_changes_nothing_and_says_why(page, lab):
    open_dashboard(page, lab, "ratchet16")
    before = status(lab)
    page.goto(lab["url"] + "?preset=block&friction=lots&speed=normal")
    note = page.locator(".note-preset")
    expect(note).to_contain_text("this link's setup was not used", timeout=60000)
    expect(note).to_contain_text("friction = 'lots' is not allowed: a number, or inf")
    expect(note).to_be_visible()
    after = status(lab)
    assert after["preset"] == "ratchet16" and after["settings"] == before["settings"]
    assert after["time"] >= before["time"]


def test_reset_settings_brings_back_the_presets_own_values_and_restart_keeps_them(page, lab):
    open_dashboard(page, lab, "ratchet16")
    page.locator(".model-select select").select_option("angle")
    page.locator(".amplitude-input input").fill("0.3")
    page.keyboard.press("Enter")
    wait_status(lab, lambda s: s["settings"]["tangential_model"] == "angle" and s["pending"] == {}
                and s["settings"]["amplitude"] == 0.3, timeout=60)
    page.locator(".reset-button button").click()  # Restart: the same settings from t = 0
    s = wait_status(lab, lambda s: s["time"] < 5.0)
    assert s["settings"]["tangential_model"] == "angle" and s["settings"]["amplitude"] == 0.3
    wait_status(lab, lambda s: s["time"] > 5.0)
    page.locator(".defaults-button button").click()
    s = wait_status(lab, lambda s: s["settings"]["tangential_model"] == "cundall-strack")
    assert settings_in_effect(lab) == preset_settings("ratchet16").__dict__ and s["time"] < 5.0
    expect(page.locator(".model-select select")).to_have_value("cundall-strack")
    expect(page.locator(".amplitude-input input")).to_have_value("0.2")
    expect(page.locator(".note-run")).to_contain_text("its own again")
    expect(page.locator(".note-run")).to_be_visible()
    expect(page.locator(".link-query input")).to_have_value(json.dumps({"preset": "ratchet16", "speed": "normal"}))


def test_the_lesson_pane_shows_the_presets_sheet_and_its_page_to_print(page, lab):
    open_dashboard(page, lab, "block")
    page.locator(".pane-choice button", has_text="Lesson").click()
    sheet = lessons.lesson("block")
    first = page.locator(".lesson h2").first
    expect(first).to_be_visible(timeout=10000)
    expect(first).to_contain_text(sheet.steps[0].title.split("*")[0][:20])
    assert page.locator(".lesson h2").count() == len(sheet.steps)
    with page.context.expect_page() as opened:
        page.locator(".lesson a", has_text="Print this sheet").click()
    printable = opened.value
    printable.wait_for_load_state()
    assert urlparse(printable.url).path == "/lesson" and printable.locator("section.lesson-step").count() == len(
        sheet.steps)
    printable.close()
    assert status_of(lab["url"] + "lesson?preset=nowhere") == 404


HEADER = ("preset-select", "play-button", "step-button", "reset-button", "defaults-button", "speed-slider",
          "speed-slow", "speed-normal", "speed-fast", "copy-link-button", "keys", "preferences")
SIDEBAR = (("phase", "phase-slider"), ("amplitude", "amplitude-input"), ("pressure", "pressure-input"),
           ("period", "period-input"), ("fit", "fit-now-button"), ("friction", "friction-slider"),
           ("friction", "friction-infinite"), ("tangential_model", "model-select"), ("damping_ratio", "damping-slider"),
           ("rolling_friction", "rolling-friction-input"), ("rolling_stiffness", "rolling-stiffness-input"),
           ("cohesion_force", "cohesion-force-input"), ("cohesion_range", "cohesion-range-input"),
           ("particles", "particles-input"), ("seed", "seed-input"), ("particles", "apply-reset-button"))
FILES = ("color-select", "watch-input", "watch-button", "frames-input", "save-name", "save-button",
         "load-select", "load-button", "handout-button", "record-name", "record-seconds", "record-button", "pane-choice")
KNOWN = set(HEADER) | {css for _, css in SIDEBAR} | set(FILES)
FOCUSED = """() => {
  let el = document.activeElement
  const classes = [...(el.classList || [])]
  while (el && el.shadowRoot && el.shadowRoot.activeElement) {
    el = el.shadowRoot.activeElement
    classes.push(...(el.classList || []))
  }
  const style = getComputedStyle(el)
  return {classes, ring: style.outlineStyle !== "none" && parseFloat(style.outlineWidth) >= 3}
}"""


def designed_order(name: str) -> list[str]:
    cls = PRESETS[name]
    shown = [css for key, css in SIDEBAR if key in cls.controls or (key == "fit" and "strain-per-cycle" in cls.plots)]
    return [*HEADER, *shown, *FILES]


def wait_named_speed(page, lab, name: str) -> None:
    """The page shows the new preset's speed in effect on its named speed buttons. Until then a
    button whose type is about to change would be drawn anew under the keyboard's focus and drop it
    (the walk then starts again from the top: a failure seen once in a fresh clone's CI)."""
    speed = status(lab)["settings"]["speed"]
    speed = math.inf if speed == "inf" else speed
    for label, value in PRESETS[name].speeds.items():
        kind = "primary" if value == speed else "default"
        expect(page.locator(f".speed-{label} button")).to_have_class(f"bk-btn bk-btn-{kind}")


def test_tab_reaches_every_control_of_every_preset_in_the_designed_order_with_a_visible_ring(page, lab):
    open_dashboard(page, lab, "ratchet16")
    for name in PRESETS:
        page.select_option(".preset-select select", label=PRESETS[name].menu_name)
        wait_status(lab, lambda s: s["preset"] == name)
        wait_named_speed(page, lab, name)
        order = designed_order(name)
        for css in order:  # the page shows the preset's controls, and only those
            expect(page.locator(f".{css}").first).to_be_visible()
        for css in {css for _, css in SIDEBAR} - set(order):
            expect(page.locator(f".{css}").first).to_be_hidden()
        page.locator(".preset-select select").focus()  # the first control of the page
        stops = []
        for _ in range(120):
            focused = page.evaluate(FOCUSED)
            known = [css for css in focused["classes"] if css in KNOWN]
            if known:
                assert focused["ring"], f"{name}: no visible focus ring on {known[0]}"
                if not stops or stops[-1] != known[0]:
                    stops.append(known[0])
            if stops and stops[-1] == "pane-choice":
                break
            page.keyboard.press("Tab")
        assert stops == order, name


def test_the_shortcuts_play_pause_step_restart_reset_and_list_the_keys(page, lab):
    open_dashboard(page, lab, "ratchet16")
    wait_status(lab, lambda s: s["state"] == "running")
    page.locator(".readout").click()  # focus on no control: the page's own keys
    page.keyboard.press("Space")
    wait_status(lab, lambda s: s["state"] == "paused")
    before = status(lab)["time"]
    page.keyboard.press("ArrowRight")
    s = wait_status(lab, lambda s: s["time"] > before and s["state"] == "paused")
    page.keyboard.press("Space")
    wait_status(lab, lambda s: s["state"] == "running")
    page.locator(".amplitude-input input").fill("0.3")
    page.keyboard.press("Enter")
    wait_status(lab, lambda s: s["settings"]["amplitude"] == 0.3 and s["time"] > 20.0, timeout=60)
    page.locator(".readout").click()
    page.keyboard.press("Alt+r")
    s = wait_status(lab, lambda s: s["time"] < 10.0)
    assert s["settings"]["amplitude"] == 0.3
    page.keyboard.press("Alt+Shift+R")
    wait_status(lab, lambda s: s["settings"]["amplitude"] == 0.2)
    # in a text box the keys are the box's: a space typed is a space, not a pause
    page.locator(".watch-input input").focus()
    page.keyboard.type("3 7")
    assert page.locator(".watch-input input").input_value() == "3 7" and status(lab)["state"] == "running"
    page.locator(".readout").click()
    page.keyboard.press("?")
    dialog = page.locator(".keys-dialog")
    expect(dialog).to_be_visible()
    for key in ("Space", "Alt+R", "Alt+Shift+R", "PageUp/PageDown"):
        expect(dialog).to_contain_text(key)
    page.keyboard.press("Escape")
    expect(dialog).to_be_hidden()


def focus(page, css: str):
    page.locator(css).first.focus()


def test_each_control_works_from_the_keyboard(browser, lab):
    context = browser.new_context(viewport={"width": 1366, "height": 768},
                                  permissions=["clipboard-read", "clipboard-write"])
    page = context.new_page()
    open_dashboard(page, lab, "ratchet16")
    press = page.keyboard.press

    def type_in(css: str, text: str):
        focus(page, f"{css} input")
        page.keyboard.press("Control+a")
        page.keyboard.type(text)
        press("Enter")

    # the header
    focus(page, ".play-button button")
    press("Enter")
    wait_status(lab, lambda s: s["state"] == "paused")
    press("Space")
    wait_status(lab, lambda s: s["state"] == "running")
    focus(page, ".step-button button")
    press("Enter")
    wait_status(lab, lambda s: s["state"] == "paused")  # the step done (Play while it goes would stop it)
    focus(page, ".play-button button")
    press("Enter")
    for name in ("fast", "slow", "normal"):
        focus(page, f".speed-{name} button")
        press("Enter")
        wait_status(lab, lambda s: speed(s) == PRESETS["ratchet16"].speeds[name])
    # the slider shows the named speed at the page's next refresh: an arrow before it would move from the last one
    normal = str(float(list(SPEEDS).index("0.5")))  # the slider's value is the speed's place in SPEEDS
    expect(page.locator(".speed-slider .noUi-handle")).to_have_attribute("aria-valuenow", normal)
    focus(page, ".speed-slider .noUi-handle")
    press("ArrowRight")
    wait_status(lab, lambda s: speed(s) == 1.0)
    press("End")
    wait_status(lab, lambda s: speed(s) == math.inf)
    focus(page, ".speed-normal button")
    press("Enter")
    focus(page, ".copy-link-button button")
    press("Enter")
    expect(page.locator(".note-preset")).to_contain_text("link copied")
    focus(page, ".keys button")
    press("Enter")
    expect(page.locator(".keys-dialog")).to_be_visible()
    press("Escape")

    # the loading: a slider and boxes (they wait for the next cycle while the box is cycled)
    wait_status(lab, lambda s: s["stage"] == "cycling", timeout=60)
    focus(page, ".phase-slider .noUi-handle")
    press("ArrowRight")
    wait_status(lab, lambda s: s["settings"]["phase"] == 5.0 or s["pending"].get("phase") == 5.0)
    type_in(".amplitude-input", "0.25")
    type_in(".pressure-input", "1.2")
    type_in(".period-input", "12")
    wait_status(lab, lambda s: s["settings"]["amplitude"] == 0.25 and s["settings"]["pressure"] == 1.2
                and s["settings"]["period"] == 12.0, timeout=60)
    focus(page, ".fit-now-button button")
    press("Enter")
    expect(page.locator(".note-fit")).to_be_visible()

    # the contacts
    focus(page, ".friction-slider .noUi-handle")
    press("ArrowRight")
    wait_status(lab, lambda s: s["settings"]["friction"] == 0.25)
    press("Shift+ArrowLeft")
    wait_status(lab, lambda s: s["settings"]["friction"] == 0.24)
    press("PageUp")
    wait_status(lab, lambda s: s["settings"]["friction"] == 0.44)
    focus(page, ".friction-infinite input")
    press("Space")
    wait_status(lab, lambda s: s["settings"]["friction"] == "inf")
    press("Space")
    wait_status(lab, lambda s: s["settings"]["friction"] == 0.44)
    focus(page, ".model-select select")
    press("ArrowDown")
    wait_status(lab, lambda s: s["settings"]["tangential_model"] != "cundall-strack")
    focus(page, ".damping-slider .noUi-handle")
    press("ArrowRight")
    wait_status(lab, lambda s: s["settings"]["damping_ratio"] == 0.35)
    type_in(".rolling-stiffness-input", "0.5")
    type_in(".rolling-friction-input", "0.01")
    type_in(".cohesion-range-input", "0.001")
    type_in(".cohesion-force-input", "0.1")
    wait_status(lab, lambda s: s["settings"]["rolling_friction"] == 0.01 and s["settings"]["cohesion_force"] == 0.1)

    # the sample: N and seed apply with a restart
    type_in(".particles-input", "20")
    type_in(".seed-input", "2")
    focus(page, ".apply-reset-button button")
    press("Enter")
    wait_status(lab, lambda s: s["settings"]["particles"] == 20 and s["settings"]["seed"] == 2 and s["time"] < 10)

    # the view
    focus(page, ".color-select select")
    press("ArrowDown")
    expect(page.locator(".legend")).not_to_contain_text("rotation angle")
    type_in(".watch-input", "0 1")
    focus(page, ".watch-button button")
    press("Enter")
    expect(page.locator(".note-watch")).to_be_visible()

    # the files: save, then replay it, record a movie
    type_in(".frames-input", "20")
    wait_status(lab, lambda s: s["settings"]["frames_per_cycle"] == 20.0)
    type_in(".save-name", "keys.h5")
    focus(page, ".save-button button")
    press("Enter")
    wait_status(lab, lambda s: (lab["data"] / "keys.h5").exists() and not s["jobs"], timeout=60)
    type_in(".record-name", "keys.gif")
    type_in(".record-seconds", "5")
    focus(page, ".record-button button")
    press("Enter")
    wait_status(lab, lambda s: (lab["data"] / "keys.gif").exists() and not s["jobs"], timeout=120)
    expect(page.locator(".load-select select option", has_text="keys.h5")).to_have_count(1)  # the list refreshed
    focus(page, ".load-select select")
    press("ArrowDown")
    focus(page, ".handout-button button")
    press("Enter")
    wait_status(lab, lambda s: (lab["data"] / "keys.html").exists() and not s["jobs"], timeout=120)
    expect(page.locator(".note-handout")).to_contain_text("wrote keys.html")
    focus(page, ".load-button button")
    press("Enter")
    wait_status(lab, lambda s: s.get("replay") is not None, timeout=60)
    expect(page.locator(".preset-select select")).to_have_value("Replay of keys.h5")  # the page shows the replay before a key
    focus(page, ".preset-select select")
    press("ArrowUp")
    wait_status(lab, lambda s: s.get("replay") is None)

    # the panes on the right, and back to the preset's own settings
    focus(page, ".pane-choice button")
    press("Tab")
    press("Tab")
    press("Tab")
    press("Enter")
    expect(page.locator(".lesson h2").first).to_be_visible()
    context.close()


def speed(s: dict) -> float:
    value = s["settings"]["speed"]
    return math.inf if value == "inf" else value


def test_the_live_text_says_the_state_every_few_seconds_and_alerts_a_restart(page, lab):
    open_dashboard(page, lab, "ratchet16")
    wait_status(lab, lambda s: s["stage"] == "cycling" and s["cycle"] >= 5, timeout=90)
    polite = page.locator(".live-text [role=status]")
    assert polite.get_attribute("aria-live") == "polite"
    expect(polite).to_contain_text("Ratcheting with 16 disks (ratcheting Figs. 1-4): cycling", timeout=10000)
    s = status(lab)
    for words in ("strain change per cycle", "3.00 contacts per disk", "sliding",
                  f"The scene shows {s['particles']} disks between 4 walls, each coloured by its"):
        expect(polite).to_contain_text(words)  # the colouring is the scene's, which another tab may change
    said_phi = float(re.search(r"packing fraction (0\.\d{3});", polite.text_content()).group(1))
    assert abs(said_phi - status(lab)["readout"]["phi"]) < 0.01  # the text is at most 5 s old; Φ moves less
    # said again within a few seconds: the cycle it names moves on
    said = re.search(r"cycle \d+;", polite.text_content()).group(0)
    expect(polite).not_to_contain_text(said, timeout=15000)
    page.locator(".reset-button button").click()
    expect(page.locator(".live-text [role=alert]")).to_contain_text("starts from t = 0", timeout=10000)


def test_the_projector_profile_from_the_address_or_the_preferences_makes_text_large_and_lines_thick(page, lab):
    open_dashboard(page, lab, "ratchet16")
    page.goto(lab["url"] + "?preset=ratchet16&profile=projector")
    toggle = page.locator(".prefs-projector")
    expect(toggle).to_be_checked(timeout=60000)
    # each figure's change may come in a message of its own: every one is waited for, none read once
    wait_model(page, "figure-strain-per-cycle", "m.title.text_font_size == '17px'")
    wait_model(page, "figure-coulomb-cone", "m.below[0].axis_label_text_font_size == '17px'")
    widths = ("JSON.stringify(m.renderers.map(r => r.glyph.line_width)"
              ".map(w => typeof w == 'number' ? w : w && w.value).filter(w => typeof w == 'number'))")
    # the cone's dashed line, the contacts' paths and the three markers' outlines (plots.py), twice as thick
    thin, thick = f"{widths} == '[1.5,2,1,1,1]'", f"{widths} == '[3,4,2,2,2]'"
    wait_model(page, "figure-coulomb-cone", thick)
    expect(page.locator(".link-query input")).to_have_value(re.compile('"profile": "projector"'))  # next refresh
    page.locator(".prefs-button").focus()
    page.keyboard.press("Enter")  # the dialog opens on its first choice: projector mode
    expect(page.get_by_role("dialog", name="Preferences")).to_be_visible()
    expect(toggle).to_be_focused()
    page.keyboard.press("Space")  # off, from the keyboard
    wait_model(page, "figure-strain-per-cycle", "m.title.text_font_size == '14px'")
    wait_model(page, "figure-coulomb-cone", thin)
    expect(page.locator(".link-query input")).not_to_have_value(re.compile("profile"))
    page.keyboard.press("Space")  # on again
    wait_model(page, "figure-coulomb-cone", thick)
    wait_model(page, "figure-strain-per-cycle", "m.title.text_font_size == '17px'")
    page.keyboard.press("Escape")
    expect(page.get_by_role("dialog", name="Preferences")).to_be_hidden()
    expect(page.locator(".prefs-button")).to_be_focused()  # back where the keyboard was


def tab_to(page, css: str, presses: int = 40) -> None:
    """Press Tab until the control of class ``css`` has the keyboard (fails after ``presses``)."""
    for _ in range(presses):
        page.keyboard.press("Tab")
        if css in page.evaluate(FOCUSED)["classes"]:
            return
    raise AssertionError(f"{presses} presses of Tab did not reach .{css}")


KEYBOARD_MODEL = "[...Bokeh.documents[0].all_models].find(m => m.single_keys !== undefined && m.enabled !== undefined)"


def test_keyboard_help_and_preferences_are_buttons_that_tab_and_screen_readers_reach(browser, lab):
    """A screen reader takes the ? key for itself: the keys' list is a button named "keyboard help",
    reached by Tab; the Preferences dialog turns the one-key shortcuts off (Space then pauses
    nothing; the controls still act)."""
    page = browser.new_page(viewport={"width": 1366, "height": 768})
    open_dashboard(page, lab, "ratchet16")
    wait_status(lab, lambda s: s["state"] == "running")
    help_button = page.get_by_role("button", name=re.compile("keyboard help"))
    expect(help_button).to_have_count(1)
    expect(page.get_by_role("button", name="Preferences")).to_have_count(1)
    page.evaluate("() => document.activeElement.blur()")  # the keyboard at the top of the page
    tab_to(page, "keys-button", presses=len(HEADER))
    page.keyboard.press("Enter")
    keys = page.get_by_role("dialog", name="Keys")
    expect(keys).to_be_visible()
    expect(keys).to_contain_text("one-key shortcuts off")
    page.keyboard.press("Escape")
    expect(keys).to_be_hidden()
    expect(help_button).to_be_focused()
    page.keyboard.press("Tab")
    assert "prefs-button" in page.evaluate(FOCUSED)["classes"]
    page.keyboard.press("Enter")
    expect(page.get_by_role("dialog", name="Preferences")).to_be_visible()
    tab_to(page, "prefs-single_keys", presses=3)
    page.keyboard.press("Space")
    expect(page.locator(".prefs-single_keys")).not_to_be_checked()
    page.keyboard.press("Escape")
    page.wait_for_function(f"() => {KEYBOARD_MODEL}.single_keys === false", polling=100, timeout=30000)
    page.locator(".readout").click()
    page.keyboard.press("Space")  # nothing; the box's value after it arrives after it
    page.locator(".amplitude-input input").fill("0.25")
    page.keyboard.press("Enter")
    s = wait_status(lab, lambda s: 0.25 in (s["settings"]["amplitude"], s["pending"].get("amplitude")), timeout=60)
    assert s["state"] == "running"
    page.locator(".readout").click()
    page.keyboard.press("?")
    expect(keys).to_be_hidden()
    page.close()


def refreshes_in(page, seconds: float, count: str) -> int:
    before = page.evaluate(f"() => {count}")
    page.wait_for_timeout(seconds * 1000)
    return page.evaluate(f"() => {count}") - before


def test_reduced_motion_follows_the_system_and_redraws_every_two_seconds(browser, lab):
    """With the system's reduced motion, the Preferences start with it on: the plots and readout
    redraw every 2 s (still sampled in simulated time), and a viewer's 2D scene too."""
    context = browser.new_context(viewport={"width": 1366, "height": 768}, reduced_motion="reduce")
    page = context.new_page()
    open_dashboard(page, lab, "ratchet16")
    expect(page.locator(".prefs-reduced_motion")).to_be_checked(timeout=30000)
    wait_status(lab, lambda s: s["state"] == "running")
    page.wait_for_timeout(2500)  # a refresh that was on its way when the period changed
    drawn = refreshes_in(page, 8.0, PAGE_REFRESH)
    assert 2 <= drawn <= 5, drawn
    scene_page = context.new_page()
    lab_only(scene_page, lab)
    scene_page.goto(lab["url"].split("?")[0] + "viewer-scene")
    scene_page.wait_for_function("() => window.granlabScene && granlabScene.drawn > 0", polling=200, timeout=60000)
    assert 2 <= refreshes_in(scene_page, 8.0, "granlabScene.drawn") <= 5
    context.close()


MECHANISM_PIXELS = """() => { const c = document.querySelector("canvas"), d = c.getContext("2d").getImageData(0, 0,
  c.width, c.height).data, [r, g, b] = [1, 3, 5].map(k => parseInt(granlabScene.style.mechanism.slice(k, k + 2), 16));
  let k = 0;
  for (let i = 0; i < d.length; i += 4) {
    if (Math.abs(d[i] - r) + Math.abs(d[i + 1] - g) + Math.abs(d[i + 2] - b) < 12) k++ }
  return k }"""
"""Pixels of a viewer's 2D scene in the colour of a mechanism's arrows."""


def test_a_viewers_scene_draws_the_mechanism_the_presenters_analysis_found(browser, lab):
    """The block preset's one mechanism (the block sliding along its wall): the presenter pauses and
    runs the stiffness analysis, which draws it as an arrow over the 3D scene; a viewer's 2D scene
    draws the same arrow (a paused run's frames still come), and loses it with the next analysis."""
    presenter = browser.new_page(viewport={"width": 1366, "height": 768})
    open_dashboard(presenter, lab, "block")
    wait_status(lab, lambda s: s["state"] == "running")
    viewer = browser.new_page(viewport={"width": 1366, "height": 768})
    lab_only(viewer, lab)
    viewer.goto(lab["url"].split("?")[0] + "viewer-scene")
    viewer.wait_for_function("() => window.granlabScene && granlabScene.drawn > 0", polling=200, timeout=60000)
    presenter.click(".play-button button")
    wait_status(lab, lambda s: s["state"] == "paused")
    before = status(lab)["analysis_seq"]
    presenter.locator(".pane-choice button", has_text="Analysis").click()
    presenter.select_option(".analysis-select select", value="stiffness")
    presenter.click(".analysis-button button")
    wait_status(lab, lambda s: s["analysis_seq"] > before, timeout=60)
    wait_status(lab, lambda s: s["mechanism"], timeout=30, read=scene)
    viewer.wait_for_function("() => granlabScene.arrows.length > 0", polling=200, timeout=30000)
    assert len(viewer.evaluate("() => Array.from(granlabScene.arrows)")) % 12 == 0  # shaft and head: x0 y0 x1 y1
    viewer.wait_for_function(f"() => ({MECHANISM_PIXELS})() > 100", polling=200, timeout=30000)  # drawn, on top
    presenter.select_option(".analysis-select select", value="packing")  # another analysis takes it away
    presenter.click(".analysis-button button")
    viewer.wait_for_function("() => granlabScene.arrows.length === 0", polling=200, timeout=60000)
    viewer.wait_for_function(f"() => ({MECHANISM_PIXELS})() === 0", polling=200, timeout=30000)
    presenter.click(".play-button button")
    wait_status(lab, lambda s: s["state"] == "running")
    viewer.close()
    presenter.close()


@pytest.fixture(scope="module")
def token_lab(tmp_path_factory):
    process, url, viewer = spawn(tmp_path_factory.mktemp("classroom-token-lab"), "--tokens", "--preset", "ratchet16")
    yield {"url": url, "viewer": viewer, "process": process}
    process.terminate()
    process.wait(timeout=30)


BOXES = """() => {
  const find = (root, css) => { for (const el of root.querySelectorAll("*")) {
      if (el.classList && el.classList.contains(css)) return el
      if (el.shadowRoot) { const found = find(el.shadowRoot, css); if (found) return found } } return null }
  const box = (css) => { const el = find(document, css); if (el == null) return null
      const r = el.getBoundingClientRect(); return {left: r.left, right: r.right, top: r.top + scrollY,
      bottom: r.bottom + scrollY, width: r.width, height: r.height} }
  const figure = (name) => { const m = Bokeh.documents[0].get_model_by_name(name)
      const view = Bokeh.index.query_one((v) => v.model === m); const r = view.el.getBoundingClientRect()
      return {left: r.left, right: r.right, top: r.top + scrollY, width: r.width, height: r.height} }
  return {page: document.documentElement.scrollWidth, scene: box("scene"), legend: box("legend"),
          readout: box("readout"), panes: box("pane-choice"), plot: figure("figure-strain-per-cycle"),
          controls: box("controls")}
}"""


@pytest.mark.parametrize("screen, width, height", [("tablet", 1024, 768), ("phone", 390, 844)])
def test_a_viewers_tablet_or_phone_shows_the_scene_above_the_key_plots_within_the_screen(browser, token_lab, screen,
                                                                                        width, height):
    context = browser.new_context(viewport={"width": width, "height": height}, has_touch=True,
                                  is_mobile=screen == "phone")
    page = context.new_page()
    lab_only(page, token_lab)
    page.goto(token_lab["viewer"])
    expect(page.locator(".viewer-badge")).to_contain_text("viewer", timeout=60000)
    wait_model(page, "strain-cycles", "m.data.cycle.length >= 1", timeout=120000)
    boxes = page.evaluate(BOXES)
    assert boxes["page"] <= width, boxes  # nothing to scroll sideways
    for name in ("scene", "legend", "readout", "panes", "plot"):
        assert 0 <= boxes[name]["left"] and boxes[name]["right"] <= width + 0.5, (name, boxes[name])
    assert boxes["controls"] is None or boxes["controls"]["width"] == 0  # a viewer's disabled controls go
    assert boxes["scene"]["height"] >= 0.4 * height and boxes["scene"]["width"] >= 0.9 * width - 20
    assert boxes["scene"]["top"] < boxes["legend"]["top"] < boxes["panes"]["top"] < boxes["plot"]["top"]
    assert boxes["plot"]["width"] >= 0.9 * width - 20 and boxes["plot"]["height"] >= 250
    expect(page.locator(".speed-text")).to_be_visible()
    canvas = viewer_scene(page).evaluate("() => document.querySelector('canvas').getBoundingClientRect().width")
    assert canvas >= boxes["scene"]["width"] - 20  # the 2D scene fills its place
    context.close()


def viewer_scene(page):
    """The frame of a viewer's 2D scene, once it has drawn a frame of the viewers' stream."""
    for _ in range(240):
        frame = next((f for f in page.frames if "/viewer-scene" in f.url), None)
        if frame is not None:
            break
        page.wait_for_timeout(500)
    else:
        raise AssertionError(f"no viewer's scene among the page's frames {[f.url for f in page.frames]}")
    frame.wait_for_function("() => window.granlabScene && window.granlabScene.drawn > 0", polling=200, timeout=60000)
    return frame


PAINTED = """() => { const c = document.querySelector("canvas"), d = c.getContext("2d").getImageData(0, 0, c.width,
  c.height).data; let k = 0;
  for (let i = 0; i < d.length; i += 4) if (d[i] < 240 || d[i + 1] < 240 || d[i + 2] < 240) k++;
  return k / (d.length / 4) }"""
"""The share of a viewer's 2D scene that is not white."""


def stream_handshake(url: str, origin: str) -> int:
    """The HTTP status the viewers' stream answers at ``url`` (ws://): 101 if it opens."""
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    try:
        with connect(url, origin=origin, open_timeout=10):
            return 101
    except InvalidStatus as error:
        return error.response.status_code


def test_a_viewers_scene_is_the_lab_s_packing_drawn_from_the_viewers_stream(browser, token_lab):
    page = browser.new_page(viewport={"width": 1366, "height": 768})
    lab_only(page, token_lab)
    page.goto(token_lab["viewer"])
    frame = viewer_scene(page)
    seq = frame.evaluate("() => granlabScene.seq")
    frame.wait_for_function(f"() => granlabScene.seq >= {seq + 10}", polling=200, timeout=30000)  # it follows the run
    shown = frame.evaluate("() => ({n: granlabScene.header.n, contacts: granlabScene.ci.length,"
                           " palette: granlabScene.palette.length, field: granlabScene.header.field})")
    s = status(token_lab)
    assert shown["n"] == s["particles"] == 16 and shown["field"] == "rotation" and shown["palette"] == 256
    assert shown["contacts"] >= 16  # a box of 16 disks at z = 3, and its walls
    assert frame.evaluate(PAINTED) > 0.2  # disks, force lines and walls
    # the stream's socket: a valid token, from the lab's own origin
    bare = urlparse(token_lab["viewer"])
    address, origin = f"ws://{bare.netloc}/viewer-stream", f"http://{bare.netloc}"
    assert stream_handshake(f"{address}?{bare.query}", origin) == 101
    assert stream_handshake(f"{address}?{bare.query}", "http://evil.example") == 403
    assert stream_handshake(f"{address}?token=wrong", origin) == 403
    assert stream_handshake(address, origin) == 403
    page.close()
