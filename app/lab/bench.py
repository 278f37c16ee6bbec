"""``granlab bench --lab``: the lab under load, measured from outside as a user sees it.

A ``granlab serve`` process runs the ratchet preset with ``particles`` disks (Gilabert's larger
samples have 5600) and one headless Chromium tab watches it. Measured:

- the engine's throughput in the lab (wall-clock particle-steps per second from ``/status``)
  against ``granlab bench`` on one thread (the lab's engine thread runs on one) and against
  the same preset run headless in this process over the same simulated interval, with the tab
  rendering the scene and again with a tab whose scene is blocked (what the engine gets when
  Chromium's software WebGL does not share the two cores);
- scene frames pushed per second to the viser client (and frames the tab rendered);
- the latency of a control: from the key press to the value in ``/status``, in a tab whose
  3D scene is blocked (in headless Chromium the scene's software WebGL shares the tab's main
  thread and the two cores with the server) and in the tab that renders the scene; and from
  the server receiving it to the engine applying it;
- the server's resident memory and thread count before and after ``tabs`` tabs are opened
  (dashboard loaded) and closed.
"""

from __future__ import annotations

import shutil
import statistics
import tempfile
import time
from pathlib import Path

import numba

from granlab.engine import bench as engine_bench
from granlab.engine.errors import GranLabError
from granlab.engine.protocols.presets import make_preset, preset_settings

from .server import read_status as _status
from .server import spawn

TARGETS = {"engine_fraction": 0.5, "scene_fps": 20.0, "latency_ms": 200.0}


def handler(args) -> dict:
    if args.particles is None:
        args.particles = 5600
    if args.particles < 1 or args.seconds <= 0 or args.tabs < 0:
        raise GranLabError(f"bench --lab takes --particles >= 1, --seconds > 0 and --tabs >= 0, not "
                           f"{args.particles}, {args.seconds} and {args.tabs}")
    return run(args.particles, args.seconds, args.tabs)


def headless_rate(particles: int, start: float, end: float) -> float:
    """Particle-steps per second of the ratchet preset advanced in a loop on one numba thread,
    timed from simulated time ``start`` to ``end`` (the lab's interval: the cost per step grows
    as the box is compressed)."""
    previous = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        preset = make_preset("ratchet", preset_settings("ratchet", particles=particles))
        steps = 50
        while preset.sim.time < start:
            preset.advance(steps)
        began, step0 = time.perf_counter(), preset.sim.step
        while preset.sim.time < end:
            preset.advance(steps)
        return (preset.sim.step - step0) * particles / (time.perf_counter() - began)
    finally:
        numba.set_num_threads(previous)


def resident_mib(pid: int) -> float:
    """Resident memory of process ``pid`` in MiB (Linux /proc)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    raise GranLabError(f"no VmRSS for process {pid}")


def _open(page, url: str) -> None:
    page.goto(url, timeout=120000)
    page.wait_for_selector(".preset-select select", timeout=60000)


def _rates(url: str, seconds: float) -> dict:
    first, start = _status(url), time.perf_counter()
    time.sleep(seconds)
    last, elapsed = _status(url), time.perf_counter() - start
    return {"particle_steps_per_s": (last["step"] - first["step"]) * last["particles"] / elapsed,
            "time_from": first["time"], "time_to": last["time"],
            "scene_fps": (last["scene_frames"] - first["scene_frames"]) / elapsed,
            "stage": last["stage"]}


def _latencies(page, url: str, count: int = 10, timeout: float = 30.0) -> tuple[list[float], list[float]]:
    """Per amplitude change: milliseconds from the key press in the tab to the new value in
    ``/status``, and from the server receiving it to the engine applying it."""
    end_to_end, server = [], []
    for k in range(count):
        value = round(0.21 + 0.01 * k, 2)
        page.fill(".amplitude-input input", str(value), timeout=1000.0 * timeout)
        start = time.perf_counter()
        page.keyboard.press("Enter")
        while (status := _status(url))["settings"]["amplitude"] != value:
            if time.perf_counter() - start > timeout:
                raise GranLabError(f"amplitude {value} never reached the engine")
            time.sleep(0.01)
        end_to_end.append(1000.0 * (time.perf_counter() - start))
        server.append(status["command_ms"])
    return end_to_end, server


def _scene_tab_latency(page, url: str) -> dict:
    """Key press to ``/status`` in the tab that renders the scene; None if the tab is too busy
    to take a key within two minutes (software WebGL on a small machine)."""
    from playwright.sync_api import TimeoutError as PlaywrightTimeout

    try:
        end_to_end, _ = _latencies(page, url, count=3, timeout=120.0)
    except (PlaywrightTimeout, GranLabError):
        return {"scene_tab_latency_ms_median": None}
    return {"scene_tab_latency_ms_median": statistics.median(end_to_end)}


def run(particles: int = 5600, seconds: float = 20.0, tabs: int = 100) -> dict:
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        raise GranLabError("bench --lab drives a browser with playwright: python -m pip install -e \".[test]\"") from None
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        raise GranLabError("bench --lab needs Chromium on PATH (Debian: apt-get install chromium)")
    reference = engine_bench.measure(1)["particle_steps_per_s"]
    result = {"particles": particles, "bench_1_thread": reference}
    with tempfile.TemporaryDirectory() as data, sync_playwright() as playwright:
        process, url, _ = spawn(data, "--particles", str(particles))
        try:
            browser = playwright.chromium.launch(executable_path=chromium, args=["--no-sandbox", "--disable-gpu"])
            page = browser.new_page()
            _open(page, url)
            time.sleep(5.0)
            rendered = _render_count(page)
            result.update(_rates(url, seconds))
            result["tab_fps"] = (_render_count(page) - rendered) / seconds if rendered is not None else None
            result.update(_scene_tab_latency(page, url))
            page.close()
            page = browser.new_page()
            page.route(lambda address: not address.startswith(url), lambda route: route.abort())
            _open(page, url)
            time.sleep(5.0)
            hidden = _rates(url, seconds)
            result.update(hidden_particle_steps_per_s=hidden["particle_steps_per_s"], hidden_time_from=hidden["time_from"],
                          hidden_time_to=hidden["time_to"])
            end_to_end, server = _latencies(page, url)
            page.close()
            result.update(latency_ms_median=statistics.median(end_to_end), latency_ms_max=max(end_to_end),
                          server_latency_ms_median=statistics.median(server), server_latency_ms_max=max(server))
            result.update(_churn(browser, url, process.pid, tabs))
            browser.close()
        finally:
            process.terminate()
            process.wait(timeout=30)
    result["engine_fraction"] = result["particle_steps_per_s"] / reference
    result["hidden_engine_fraction"] = result["hidden_particle_steps_per_s"] / reference
    result["headless_same_interval"] = headless_rate(particles, result["time_from"], result["time_to"])
    result["hidden_headless_same_interval"] = headless_rate(particles, result["hidden_time_from"],
                                                            result["hidden_time_to"])
    result["pass"] = {"engine": result["engine_fraction"] >= TARGETS["engine_fraction"],
                      "scene": result["scene_fps"] >= TARGETS["scene_fps"],
                      "latency": result["latency_ms_max"] < TARGETS["latency_ms"],
                      "tabs": result["threads_after"] <= result["threads_before"]
                      and result["memory_growth_mib"] < 0.1 * result["memory_before_mib"]}
    return result


def _render_count(page):
    """Frames the tab's viser client has rendered (None before its canvas is up)."""
    frames = [f for f in page.frames if f != page.main_frame and f.url.startswith("http")]
    if not frames:
        return None
    return frames[0].evaluate("() => window.__viserTestpoints && window.__viserTestpoints.rendererInfo ?"
                              " window.__viserTestpoints.rendererInfo.render.frame : null")


def _settle(url: str, tabs: int) -> dict:
    """Wait until the server counts ``tabs`` tabs (closed sessions are reaped within seconds)."""
    deadline = time.time() + 60
    while _status(url)["tabs"] != tabs and time.time() < deadline:
        time.sleep(0.5)
    time.sleep(3.0)
    return _status(url)


def _churn(browser, url: str, pid: int, tabs: int) -> dict:
    for _ in range(5):  # warm-up: first sessions fill caches that later ones reuse
        page = browser.new_page()
        _open(page, url)
        page.close()
    before = _settle(url, 0)
    memory_before = resident_mib(pid)
    start = time.perf_counter()
    for _ in range(tabs):
        page = browser.new_page()
        _open(page, url)
        page.close()
    elapsed = time.perf_counter() - start
    after = _settle(url, 0)
    memory_after = resident_mib(pid)
    return {"tabs_opened": tabs, "tab_seconds": elapsed / max(1, tabs), "threads_before": before["threads"],
            "threads_after": after["threads"], "memory_before_mib": memory_before, "memory_after_mib": memory_after,
            "memory_growth_mib": memory_after - memory_before}


def print_result(r: dict) -> None:
    mark = {True: "ok", False: "BELOW TARGET"}
    print(f"lab benchmark, ratchet preset, {r['particles']} disks, one tab")
    print(f"  granlab bench (1 thread):  {r['bench_1_thread'] / 1e6:.2f} M particle-steps/s")
    print(f"  engine in the lab:          {r['particle_steps_per_s'] / 1e6:.2f} M particle-steps/s = "
          f"{r['engine_fraction']:.2f} of bench [{mark[r['pass']['engine']]}] (stage: {r['stage']})")
    tab = f"; the tab rendered {r['tab_fps']:.1f} frames/s" if r.get("tab_fps") is not None else ""
    print(f"  scene pushed:               {r['scene_fps']:.1f} frames/s [{mark[r['pass']['scene']]}]{tab}")
    print(f"  preset headless over the same simulated interval (t = {r['time_from']:.2f} to {r['time_to']:.2f}): "
          f"{r['headless_same_interval'] / 1e6:.2f} M; the lab ran at "
          f"{r['particle_steps_per_s'] / r['headless_same_interval']:.2f} of it")
    print(f"  engine, the tab's scene blocked: {r['hidden_particle_steps_per_s'] / 1e6:.2f} M particle-steps/s = "
          f"{r['hidden_engine_fraction']:.2f} of bench; {r['hidden_particle_steps_per_s'] / r['hidden_headless_same_interval']:.2f}"
          f" of the preset headless over its interval (t = {r['hidden_time_from']:.2f} to {r['hidden_time_to']:.2f})")
    print(f"  control, key press to /status (a tab without the scene): median {r['latency_ms_median']:.0f} ms, "
          f"max {r['latency_ms_max']:.0f} ms [{mark[r['pass']['latency']]}]")
    print(f"  control, server to engine:  median {r['server_latency_ms_median']:.0f} ms, "
          f"max {r['server_latency_ms_max']:.0f} ms")
    scene_tab = r["scene_tab_latency_ms_median"]
    print("  control, key press to /status in the tab rendering the scene: " +
          (f"median {scene_tab:.0f} ms" if scene_tab is not None else "no answer within 120 s"))
    print(f"  {r['tabs_opened']} tabs opened and closed ({r['tab_seconds']:.2f} s each): threads "
          f"{r['threads_before']} -> {r['threads_after']}, memory {r['memory_before_mib']:.0f} -> "
          f"{r['memory_after_mib']:.0f} MiB [{mark[r['pass']['tabs']]}]")
