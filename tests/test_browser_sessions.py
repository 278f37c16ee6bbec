"""The lab's sessions in a real browser (headless Chromium driven by playwright, as in test_browser.py):
the presenter's and a viewer's pages with tokens, tabs opened and closed all lesson, a lab left with no
page, a notebook cell's frame, a first start that compiles, and a phone's scripts."""

import gzip
import os
import re
import shutil
import subprocess
import sys
import time
import urllib.request

import pytest
from playwright.sync_api import expect

from granlab.app.lab.bench import resident_mib
from granlab.app.lab.server import read_status, spawn
from tests.test_browser import (dashboard_handshake, handshake, scene_socket, status, wait_model,
                                wait_status)


@pytest.fixture(scope="module")
def token_lab(tmp_path_factory):
    data = tmp_path_factory.mktemp("token-lab-data")
    process, url, viewer = spawn(data, "--tokens", "--preset", "ratchet16")
    yield {"url": url, "viewer": viewer, "process": process, "data": data}
    process.terminate()
    process.wait(timeout=30)


def lab_only(page, lab) -> None:
    """Refuse the scene's page in this tab: its address is in the iframe, which is all the test
    needs, and rendering it in software would slow every other action in the tab."""
    bare = lab["url"].split("?")[0]
    page.route("**/*", lambda route: route.continue_() if route.request.url.startswith(bare) else route.abort())


def test_with_tokens_the_presenter_controls_and_a_viewer_only_watches(browser, token_lab):
    presenter = browser.new_page(viewport={"width": 1366, "height": 768})
    lab_only(presenter, token_lab)
    presenter.goto(token_lab["url"])
    expect(presenter.locator(".play-button button")).to_be_enabled(timeout=60000)
    expect(presenter.locator(".save-button button")).to_be_visible()
    wait_status(token_lab, lambda s: s["state"] == "running")
    viewer = browser.new_page(viewport={"width": 1366, "height": 768})
    lab_only(viewer, token_lab)
    viewer.goto(token_lab["viewer"])
    expect(viewer.locator(".viewer-badge")).to_contain_text("viewer", timeout=60000)
    wait_status(token_lab, lambda s: s["tabs"] >= 2)
    for control in (".play-button button", ".reset-button button", ".preset-select select", ".color-select select",
                    ".amplitude-input input", ".watch-button button"):
        expect(viewer.locator(control)).to_be_disabled()
    expect(viewer.locator(".save-button button")).to_be_hidden()
    # the speed in effect as text (ratchet16 runs at 0.5 cycles a second), no slider to reach for
    expect(viewer.locator(".speed-text")).to_have_text("Speed (load cycles per second): 0.5")
    expect(viewer.locator(".speed-slider").first).to_be_hidden()
    expect(viewer.locator(".load-button button")).to_be_hidden()
    # a page that enables its own Pause button and presses it: the server ignores a viewer's commands
    viewer.evaluate("() => { for (const m of Bokeh.documents[0].all_models)"
                    " if ((m.css_classes || []).includes('play-button')) m.disabled = false; }")
    viewer.locator(".play-button button").click()
    viewer.wait_for_timeout(1500)
    assert status(token_lab)["state"] == "running"
    presenter.locator(".play-button button").click()
    wait_status(token_lab, lambda s: s["state"] == "paused")
    # the dashboard's websocket, with the presenter's token: from another site's page, refused
    dashboard_socket = token_lab["url"].replace("http://", "ws://").replace("/?", "/ws?")
    assert dashboard_handshake(dashboard_socket, "http://evil.example") == 403
    assert dashboard_handshake(dashboard_socket, token_lab["url"].split("/?")[0]) != 403
    # the presenter's 3D scene: its token opens the websocket, from the scene page's own origin only
    # (a viewer's scene is the viewers' stream: test_browser_classroom.py)
    address, port = scene_socket(presenter)
    assert handshake(address, f"http://127.0.0.1:{port}") == 101
    assert handshake(address, "http://evil.example") == 403
    assert handshake(address.rsplit("/", 1)[0] + "/", f"http://127.0.0.1:{port}") == 403
    assert handshake(address.rsplit("/", 1)[0] + "/wrong", f"http://127.0.0.1:{port}") == 403
    presenter.close()
    viewer.close()


@pytest.fixture(scope="module")
def small_history_lab(tmp_path_factory):
    """A lab whose frames kept for saves may take 1 MiB: what remains of its memory is the tabs'; left
    with no page open, it pauses after 4 s."""
    data = tmp_path_factory.mktemp("small-history-lab-data")
    process, url, _ = spawn(data, "--history-mib", "1", "--pause-without-pages", "4")
    yield {"url": url, "process": process, "data": data}
    process.terminate()
    process.wait(timeout=30)


def test_tabs_opened_and_closed_leave_the_server_memory_where_it_was(browser, small_history_lab):
    """A class opens and closes tabs all lesson: each tab's session (its document and the series it
    pulled) must go when it closes, so that two rounds of 8 tabs do not each grow the server. The scene's
    page is left out to keep the test short."""
    lab = small_history_lab

    def churn(tabs: int) -> float:
        for _ in range(tabs):
            page = browser.new_page()
            lab_only(page, lab)
            page.goto(lab["url"])
            page.wait_for_function("() => window.Bokeh && Bokeh.documents.length > 0", polling=200, timeout=60000)
            wait_model(page, "q-gamma-path", "m.data.x0.length > 0")  # the tab pulled the series
            page.close()
        # the closed tabs' memory handed back (a release asked for by an earlier tab may be the one that
        # covers the last: it can come before the last tab is counted out, so no count of releases is waited for)
        wait_status(lab, lambda s: s["tabs"] == 0 and not s["memory_release_pending"])
        time.sleep(1.0)
        return resident_mib(lab["process"].pid)

    before = churn(4)  # the first tabs fill caches that later ones reuse
    middle = churn(8)
    after = churn(8)
    assert status(lab)["history_mib"] <= 1.0
    # a leak grows the server by each round of tabs; an allocator's arena or a cache taken once grows it by one
    # round (once in five fresh runs, 13.5 MiB for 8 tabs): the smaller round is the leak's. A busy machine's
    # fresh run grew each round by 7.4-7.8 MiB, a quiet one's 100 tabs by 9.3 MiB in all (docs/performance.md).
    assert min(middle - before, after - middle) < 10.0, \
        f"8 tabs and 8 more took the server from {before:.1f} to {middle:.1f} and {after:.1f} MiB"


def test_a_lab_left_with_no_page_pauses_says_why_and_goes_on_when_a_page_opens(browser, small_history_lab):
    lab = small_history_lab

    def open_tab():
        page = browser.new_page()
        lab_only(page, lab)
        page.goto(lab["url"])
        return page

    page = open_tab()
    running = wait_status(lab, lambda s: s["tabs"] == 1 and s["state"] == "running" and s["time"] > 0, timeout=60)
    page.close()
    paused = wait_status(lab, lambda s: s["state"] == "paused", timeout=30)
    assert paused["tabs"] == 0 and paused["paused_for"] == "no page open for 4 s" and paused["time"] > running["time"]
    assert any("no page open for 4 s: the run is paused; it goes on when a page opens" in line
               for line in lab["process"].output)
    time.sleep(1.0)
    assert status(lab)["time"] == paused["time"]
    page = open_tab()
    wait_status(lab, lambda s: s["state"] == "running" and s["time"] > paused["time"] and s["paused_for"] == "")
    assert any("a page opened: the run goes on" in line for line in lab["process"].output)
    page.close()


def test_the_lab_of_a_notebook_cell_runs_in_its_frame(page, tmp_path):
    """``gl.lab`` in a notebook: the cell's HTML, in a page served from another origin (as
    Jupyter's is), opens the lab in its frame: the preset starts for that tab and its plots fill in."""
    import functools
    import http.server
    import threading

    from granlab.app.notebook import NotebookLab

    live = NotebookLab("ratchet16", data_dir=tmp_path / "data")
    (tmp_path / "cell.html").write_text(f"<html><body><h3>In [1]: live</h3>{live._repr_html_()}</body></html>")
    notebook = http.server.ThreadingHTTPServer(
        ("127.0.0.1", 0), functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(tmp_path)))
    threading.Thread(target=notebook.serve_forever, daemon=True).start()
    origin = f"http://127.0.0.1:{notebook.server_address[1]}/"
    try:
        assert live.status()["state"] == "waiting"
        # the 3D scene's own requests are refused, as in open_dashboard: software WebGL slows the tab
        page.route("**/*", lambda route: route.continue_() if route.request.url.startswith((origin, live.url))
                   else route.abort())
        page.goto(origin + "cell.html")
        frame = page.frame_locator("iframe")
        expect(frame.locator(".preset-select select")).to_be_visible(timeout=60000)
        state = wait_status(live, lambda s: s["state"] == "running" and s["tabs"] == 1 and s["time"] > 0,
                            timeout=60, read=lambda lab: lab.status())
        assert state["preset"] == "ratchet16"
        inner = next(f for f in page.frames if f.url.startswith(live.url))
        inner.wait_for_function("() => window.Bokeh && Bokeh.documents.length > 0 && Bokeh.documents[0]"
                                ".get_model_by_name('coulomb-cone-paths') !== null && Bokeh.documents[0]"
                                ".get_model_by_name('coulomb-cone-paths').data.x0.length > 10", polling=200,
                                timeout=60000)
    finally:
        notebook.shutdown()
        live.stop()
    assert not live._thread.is_alive()


def test_a_first_start_serves_at_once_shows_the_compile_on_the_page_then_the_preset(page, tmp_path):
    """A lab whose kernels are not compiled (here: the step's neighbour search and first kick, taken
    out of a copy of the suite's kernel cache) prints its address at once; a page opened then shows
    how far the compile is, and reloads into the dashboard with the preset running once it is done."""
    from granlab.engine.kernels.cache import cache_root

    cache = tmp_path / "cache"
    shutil.copytree(cache_root(), cache, ignore=shutil.ignore_patterns("integrate.rebuild-*", "integrate._start-*"))
    process = subprocess.Popen([sys.executable, "-m", "granlab.app.commands", "serve", "--port", "0", "--data-dir",
                                str(tmp_path / "data")], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                               env={**os.environ, "GRANLAB_CACHE_DIR": str(cache)})
    try:
        started = time.time()
        lines = []
        while not any("GranLab lab at" in line for line in lines):
            lines.append(process.stdout.readline())
            assert time.time() - started < 60, lines
        url = re.search(r"GranLab lab at (http://\S+)", lines[-1]).group(1)
        assert "compiles the simulation's kernels" in process.stdout.readline()
        page.goto(url)
        message = page.locator(".starting-text")
        expect(message).to_contain_text("Compiling the simulation's kernels, first run only (later starts take "
                                         "seconds): 1 of 1 (the neighbour search and the first kick)", timeout=60000)
        expect(message).to_have_text(re.compile(r".*first kick\), \d+ s\s*$"))  # and the seconds so far
        assert page.locator(".starting-progress progress").get_attribute("max") == "1"
        assert read_status(url)["state"] == "compiling"
        page.wait_for_selector(".preset-select select", timeout=120000)  # reloaded into the dashboard
        assert page.locator(".starting-text").count() == 0
        wait_status({"url": url}, lambda s: s["state"] == "running" and s["step"] > 0)
    finally:
        process.terminate()
        process.wait(timeout=30)


def test_a_viewers_phone_fetches_the_pages_scripts_gzipped_in_under_a_megabyte(token_lab):
    """The scripts of a viewer's page as a phone's browser asks for them (gzip accepted): 3.0 MB
    uncompressed, about 0.8 MB on the wire."""
    page = urllib.request.urlopen(urllib.request.Request(token_lab["viewer"], headers={"Accept-Encoding": "gzip"}),
                                  timeout=30)
    html = gzip.decompress(page.read()).decode() if page.headers.get("Content-Encoding") == "gzip" else ""
    assert "bokeh" in html, "the page itself is not gzipped"
    base = token_lab["viewer"].split("?")[0].rstrip("/") + "/"
    files = re.findall(r'src="(static/[^"]+\.js[^"]*)"', html)
    assert any("bokeh.min.js" in name for name in files) and any("panel.min.js" in name for name in files)
    wire = raw = 0
    for name in files:
        request = urllib.request.Request(base + name.replace("&amp;", "&"), headers={"Accept-Encoding": "gzip"})
        with urllib.request.urlopen(request, timeout=30) as response:
            body = response.read()
            assert response.headers.get("Content-Encoding") == "gzip", name
        wire += len(body)
        raw += len(gzip.decompress(body))
    assert raw > 2_500_000 and wire < 1_000_000, (raw, wire)
