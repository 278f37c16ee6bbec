"""Screenshots of the lab, one per preset, at 1920×1080 and 1366×768 (docs/lab.md shows them).

    python docs/screenshots.py [--out docs/images] [--sizes 1920x1080,1366x768] [--presets a,b]

Starts ``granlab serve`` on a free port, opens it in headless Chromium (Debian's ``chromium``;
the 3D scene renders in software, so a shot takes a while), runs each preset at full speed until
it shows what its text promises, sets its own speed back and saves ``lab-PRESET-WIDTH.png``
(quantised to 256 colours, a few hundred kB each). Needs the test extra (playwright).
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

from PIL import Image
from playwright.sync_api import sync_playwright

from granlab.app.lab.dashboard import SPEEDS
from granlab.app.lab.server import read_status, spawn
from granlab.engine.protocols.presets import PRESETS

READY = {
    "ratchet": lambda s: s.get("cycle", 0) >= 4,
    "ratchet16": lambda s: s.get("cycle", 0) >= 8,
    "elliptic": lambda s: s.get("cycle", 0) >= 8,
    "closed-path": lambda s: s.get("loops", 0) >= 8,
    "block": lambda s: s["time"] >= 100.0,
    "collision": lambda s: (s.get("readout") or {}).get("collisions", 0) >= 4,
    "aggregation": lambda s: s["time"] >= 300.0,
    "compression": lambda s: s["stage"] == "equilibrated" or s["time"] >= 200.0,
}
"""When a preset shows what its text is about (a few cycles of ratcheting, a staircase of D_t,
one cluster forming, a packing in equilibrium)."""


def set_speed(page, url: str, value: float) -> None:
    """Press the speed slider's arrow keys until the lab runs at ``value``."""
    labels = list(SPEEDS)
    page.locator(".speed-slider .noUi-handle").focus()
    for _ in range(2 * len(labels)):
        speed = read_status(url)["settings"]["speed"]
        current = labels.index(next(k for k, v in SPEEDS.items() if v == (float("inf") if speed == "inf" else speed)))
        target = labels.index(next(k for k, v in SPEEDS.items() if v == value))
        if current == target:
            return
        page.keyboard.press("ArrowRight" if current < target else "ArrowLeft")
        time.sleep(0.5)


def dismiss_software_notice(page) -> None:
    """Close viser's notice that WebGL runs in software (headless Chromium has no GPU; a
    classroom's machine does not show it), so that it hides no disks in the picture."""
    for frame in page.frames:
        if frame != page.main_frame:
            for button in frame.locator(".mantine-Notification-closeButton").all():
                button.dispatch_event("click")  # a click waits for a still page, which software WebGL rarely gives
    page.wait_for_timeout(500)


def shoot(url: str, out: Path, sizes: list[tuple[int, int]], presets: list[str]) -> list[Path]:
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        sys.exit("screenshots need Chromium on PATH (Debian: apt-get install chromium)")
    written = []
    with sync_playwright() as playwright:
        for width, height in sizes:  # a browser each: software WebGL leaves a browser slow for a while
            browser = playwright.chromium.launch(executable_path=chromium, args=["--no-sandbox", "--disable-gpu"])
            page = browser.new_page(viewport={"width": width, "height": height})
            page.goto(url, timeout=120000, wait_until="domcontentloaded")
            page.wait_for_selector(".preset-select select", timeout=120000)
            for name in presets:
                page.select_option(".preset-select select", label=PRESETS[name].menu_name)
                while read_status(url)["preset"] != name:
                    time.sleep(0.2)
                default = PRESETS[name].defaults.get("speed", 1.0)
                set_speed(page, url, float("inf"))
                while not READY[name](read_status(url)):
                    time.sleep(0.5)
                set_speed(page, url, default)
                page.wait_for_timeout(8000)  # the scene draws in software: let it catch up
                dismiss_software_notice(page)
                path = out / f"lab-{name}-{width}.png"
                page.screenshot(path=str(path))
                Image.open(path).convert("RGB").quantize(256).save(path, optimize=True)
                written.append(path)
                print(f"{path} ({path.stat().st_size // 1024} kB)", flush=True)
            browser.close()
    return written


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(Path(__file__).resolve().parent / "images"))
    parser.add_argument("--sizes", default="1920x1080,1366x768")
    parser.add_argument("--presets", default=",".join(PRESETS))
    args = parser.parse_args()
    sizes = [tuple(int(v) for v in size.split("x")) for size in args.sizes.split(",")]
    presets = args.presets.split(",")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as data:
        process, url, _ = spawn(data)
        try:
            shoot(url, out, sizes, presets)
        finally:
            process.terminate()
            process.wait(timeout=30)


if __name__ == "__main__":
    main()
