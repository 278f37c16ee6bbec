"""The lab as a teacher's instrument, in headless Chromium: links that carry a setup, the preset's
own settings back in one press, named speeds. What is checked is what a teacher would check: the
values in effect (the lab's ``/status``) and the widgets showing them."""

import json
import math
from urllib.parse import parse_qs, urlparse

import pytest
from playwright.sync_api import expect

from granlab.app.lab import lessons
from granlab.app.lab.server import spawn
from granlab.engine.protocols.presets import PRESETS, preset_settings
from tests.test_browser import browser_context_args, browser_type_launch_args  # noqa: F401 (Debian's Chromium)
from tests.test_browser import http_status, lab_only, open_dashboard, status, wait_status


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    process, url, _ = spawn(tmp_path_factory.mktemp("classroom-lab-data"))
    yield {"url": url, "process": process}
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
    assert json.loads(page.locator(".link-query input").input_value()) == {"preset": "ratchet16", "speed": "normal"}


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
    assert http_status(lab["url"] + "lesson?preset=nowhere") == 404
