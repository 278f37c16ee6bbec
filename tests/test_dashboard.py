"""A tab's dashboard driven without a browser: which values its widgets show, refresh by refresh."""

import contextlib
import io

import param
import pytest

from granlab.app.lab.dashboard import Dashboard
from granlab.app.lab.engine_thread import LabEngine
from granlab.app.lab.plots import VIEWER_SHARE
from granlab.app.lab.scene import SceneView

from .test_lab_engine import wait


@pytest.fixture
def dashboard(tmp_path):
    engine = LabEngine(tmp_path, preset="ratchet16")
    engine.start()
    wait(lambda: engine.status()["step"] > 0)
    with contextlib.redirect_stdout(io.StringIO()):  # viser prints its address
        scene = SceneView()
    yield Dashboard(engine, scene, "http://127.0.0.1/")
    scene.close()
    engine.stop()


def test_defaults_shown_after_the_page_changed_settings_between_two_refreshes(dashboard):
    """A page whose refreshes are late (a busy machine, a slow browser) types N, moves the damping,
    applies N and presses Defaults, all between two refreshes: the engine is back at the very settings the
    page last showed, and the next refresh must still put them in every widget (N was left at 20)."""
    page, engine = dashboard, dashboard.engine
    page._update()
    defaults = engine.status()["settings"]
    assert page.particles.value == defaults["particles"] == 16
    page.particles.value = 20  # typed: it waits for Apply
    with param.edit_constant(page.damping):  # a slider let go: its value and its throttled value
        page.damping.value_throttled = page.damping.value = defaults["damping_ratio"] + 0.05
    page.apply_reset.clicks += 1
    wait(lambda: engine.status()["particles"] == 20)
    page.defaults.clicks += 1
    wait(lambda: engine.status()["settings"] == defaults and engine.status()["particles"] == 16)
    page._update()
    assert (page.particles.value, page.damping.value) == (16, defaults["damping_ratio"])


def test_a_viewers_page_keeps_its_share_of_the_rows_and_says_what_its_plots_hold(dashboard):
    """A viewer's plots keep VIEWER_SHARE of each rollover (the server holds a copy of every page's);
    what they hold is counted in bytes for /status."""
    engine = dashboard.engine
    viewer = Dashboard(engine, dashboard.scene, "/viewer-scene", viewer=True)
    for page in (dashboard, viewer):
        page._update()
    wait(lambda: viewer._update() or viewer.plot_bytes() > 0)
    assert {plot.share for plot in viewer.shown} == {VIEWER_SHARE}
    assert {plot.share for plot in dashboard.shown} == {1.0}
