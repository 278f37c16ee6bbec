"""Shared helpers: small packings built from the engine's own generators, and the browser every
browser test drives (Debian's Chromium at 1366×768, the smaller projector screen)."""

import os
import shutil

import numpy as np
import pytest

from granlab.engine import ContactLaw, Integration, ParticleState, PeriodicCell, Simulation
from granlab.engine.compilation import KERNEL_SETS, compile_sets
from granlab.engine.generate import radii, random_gas

SUITE_KERNEL_SETS = [name for name in KERNEL_SETS if not name.endswith("-threads")] + \
    ["step-pieces-threads", "step-cundall-strack-threads"]
"""What the suite runs: every set on one thread, and Cundall-Strack's step on several (the other
models' several-thread steps compile in the tests that use them)."""


def pytest_sessionstart(session):
    """The kernels the suite runs, compiled at its start side by side (a worker a core) into the kernel
    cache that every test, every subprocess and the wheel's virtual environment then load them from;
    with pytest-xdist, once, before its workers start."""
    if not hasattr(session.config, "workerinput") and not session.config.option.collectonly:
        compile_sets(SUITE_KERNEL_SETS)


FILE_SECONDS = {
    "test_browser.py": 400, "test_browser_sessions.py": 230, "test_browser_classroom.py": 220, "test_cuda.py": 110,
    "test_reproduce.py": 75, "test_package.py": 70, "test_export.py": 60, "test_run_fuzz.py": 55,
    "test_h5md.py": 50, "test_signals.py": 50, "test_cli.py": 50, "test_lab_access.py": 45,
    "test_foreign_fuzz.py": 45, "test_study.py": 42, "test_lab_engine.py": 38, "test_registries.py": 38,
    "test_lessons.py": 35, "test_foreign_files.py": 30, "test_scene_fuzz.py": 20, "test_lab_bench.py": 18}
"""What each of the slowest files takes in a fresh clone's CI (7 Dec 2026, 2 cores, seconds, rounded)."""


def pytest_collection_modifyitems(items):
    """The slowest files first (the rest in their order), run under ``--dist loadfile --no-loadscope-reorder``:
    each test process takes the next file as it finishes one, so that no long file starts last and holds
    one process while the other has nothing left (xdist's own order, by the number of tests in a file, started
    the six-test, four-minute sessions file near the end: 1027 s, where the code before the split took 978)."""
    items.sort(key=lambda item: -FILE_SECONDS.get(item.path.name, 0))


def periodic_gas(count=120, length=20.0, seed=1, speed=1.0, law=None, dt_safety=0.1, skin=None, radius_range=(0.4, 0.6)):
    """A polydisperse gas of ``count`` disks in a periodic square cell, random velocities and spins."""
    rng = np.random.default_rng(seed)
    r = radii(count, radius_min=radius_range[0], radius_max=radius_range[1], distribution="uniform", seed=seed)
    positions = random_gas(r, (0.0, length, 0.0, length), periodic=(True, True), seed=seed)
    velocity = rng.normal(0.0, speed, (count, 2))
    omega = rng.normal(0.0, speed, count)
    law = law or ContactLaw(normal_stiffness=1e3, tangential_stiffness=1e3, friction=0.0)
    return Simulation(ParticleState(positions, r, velocity=velocity, omega=omega), law,
                      Integration(dt_safety=dt_safety, skin=skin), cell=PeriodicCell((length, length)))


@pytest.fixture
def gas_factory():
    return periodic_gas


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.fixture(scope="session")
def browser_type_launch_args(browser_type_launch_args):
    """Debian's Chromium for playwright's ``browser`` and ``page`` (its own download is not
    installed); without it a browser test skips, except under CI=true, where it is an error."""
    if CHROMIUM is None:
        if os.environ.get("CI") == "true":
            raise RuntimeError("CI=true but no chromium on PATH: .ci/run installs Debian's chromium package")
        pytest.skip("no chromium on PATH")
    return {**browser_type_launch_args, "executable_path": CHROMIUM,
            "args": ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
                     "--disable-sync", "--no-first-run"]}


@pytest.fixture(scope="session")
def browser_context_args(browser_context_args):
    """Every page at 1366×768; what a test expects a page to show, waited for 15 s: this Chromium draws with
    software WebGL on 2 cores, and a busy lab page's frames stop for up to 5.6 s after it loads (measured: 11–17
    frames a second at the ratchet's speeds), so a 5 s wait fails a page that only drew late."""
    from playwright.sync_api import expect

    expect.set_options(timeout=15_000)
    return {**browser_context_args, "viewport": {"width": 1366, "height": 768}}  # the smaller projector screen
