"""The on-disk kernel cache: a kernel is stamped by every source it is compiled from and no other,
found again by any copy of the same sources, and saved whole by processes saving at once."""

import multiprocessing
import os
import re
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from granlab.engine.kernels import cache, integrate, jit
from granlab.engine.params import TANGENTIAL

KERNEL_DECORATOR = r"(?m)^\s*@(numba\.)?(njit|jit|vectorize|guvectorize|stencil|cfunc)\b"
KERNELS = cache.KERNELS


def names(paths):
    return names_in(paths, KERNELS)


def names_in(paths, folder):
    return {path.relative_to(folder).as_posix() for path in paths}


def test_a_kernel_is_stamped_by_the_modules_it_imports_directly_or_not():
    files, values = cache.closure(KERNELS / "integrate.py")
    # the step driver holds compiled copies of the contact loop, the laws and every tangential model
    assert {"integrate.py", "contacts.py", "laws.py", "pair.py", "neighbours.py", "jit.py",
            "tangential/__init__.py", "tangential/angle.py", "tangential/lammps.py"} <= names(files)
    assert ("params", "TANGENTIAL") in values and ("params", "NORMAL") in values
    locator = integrate.advance._cache._impl.locator
    assert type(locator) is cache.KernelLocator
    assert locator.get_source_stamp() == cache.kernel_stamp(KERNELS / "integrate.py")
    assert Path(locator.get_cache_path()).name == f"stamp-{locator.get_source_stamp()[:16]}"
    # the structure factor's grid and the packing generator import no law: a law's edit leaves them
    assert names(cache.closure(KERNELS / "grid.py")[0]) == {"grid.py", "jit.py"}
    assert names(cache.closure(KERNELS / "packing.py")[0]) == {"packing.py", "jit.py"}
    assert not {"cache.py", "watchers.py"} & names(files)  # where kernels are kept changes no kernel


def test_a_kernel_compiled_for_one_tangential_model_is_stamped_by_that_model_alone():
    stamps = set()
    for model in TANGENTIAL.values():
        files, _ = cache.closure(KERNELS / "integrate.py", model.code)
        models = {name for name in names(files) if name.startswith("tangential/") and name != "tangential/__init__.py"}
        assert f"tangential/{model.key}.py" in models
        # the alpha-corrected spring is Cundall-Strack's, limited alike: it imports its module
        assert models <= {f"tangential/{model.key}.py", "tangential/cundall_strack.py", "tangential/alpha.py"}
        locator = integrate.ADVANCE[model.code]._cache._impl.locator
        assert locator.get_source_stamp() == cache.kernel_stamp(KERNELS / "integrate.py", model.code)
        stamps.add(locator.get_source_stamp())
    assert len(stamps) == len(TANGENTIAL)


@pytest.fixture
def kernels_copy(tmp_path, monkeypatch):
    """The engine's kernels and state in a folder of their own, the stamps computed there; and the
    stamp of the step driver for Cundall-Strack here."""
    here = cache.kernel_stamp(KERNELS / "integrate.py", 0)
    engine = tmp_path / "engine"
    shutil.copytree(KERNELS, engine / "kernels", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(cache.STATE, engine / "state.py")
    monkeypatch.setattr(cache, "ENGINE", engine)
    monkeypatch.setattr(cache, "KERNELS", engine / "kernels")
    monkeypatch.setattr(cache, "STATE", engine / "state.py")

    def stamps():
        cache.imports.cache_clear()
        cache.kernel_stamp.cache_clear()
        return {(name, model): cache.kernel_stamp(engine / "kernels" / name, model)
                for name in ("integrate.py", "grid.py", "laws.py", "energy.py")
                for model in (None, *(m.code for m in TANGENTIAL.values()))}

    yield engine / "kernels", stamps, here
    cache.imports.cache_clear()
    cache.kernel_stamp.cache_clear()


def changed(before, after):
    return {key for key in before if before[key] != after[key]}


def test_editing_a_law_restamps_the_kernels_that_contain_it_and_no_other(kernels_copy):
    folder, stamps, _ = kernels_copy
    before = stamps()
    with open(folder / "tangential" / "angle.py", "a") as module:
        module.write("\n# an edit\n")
    after_angle = stamps()
    angle = TANGENTIAL["angle"].code
    # the step driver for the angle spring, and the generic one (it holds every model), no other
    assert {name for name, model in changed(before, after_angle)} == {"integrate.py"}
    assert changed(before, after_angle) == {("integrate.py", None), ("integrate.py", angle)}
    with open(folder / "laws.py", "a") as module:
        module.write("\n# an edit\n")
    after_laws = stamps()
    assert {name for name, _ in changed(after_angle, after_laws)} == {"integrate.py", "laws.py", "energy.py"}
    with open(folder / "cache.py", "a") as module:
        module.write("\n# an edit\n")
    assert changed(after_laws, stamps()) == set()


def test_imports_are_read_in_every_form_they_take_and_not_from_text(kernels_copy):
    """Imports are read by pattern: across lines with comments, renamed, inside a function; a
    commented-out one is no dependency, a docstring's line that reads as one is (a kernel then
    recompiles more often than it must, never less)."""
    folder, _, _ = kernels_copy
    (folder / "probe.py").write_text(textwrap.dedent('''\
        """Use as ``from .grid import paint_disks``.
        from .energy import energy_terms
        """
        from .laws import (normal_force,  # why
            tangential_force as force)
        # from .packing import random_sequential_addition
        from ..params import TANGENTIAL, NORMAL  # the registries


        def later():
            from .tangential import angle
            return angle
        '''))
    cache.imports.cache_clear()
    files, siblings, values = cache.imports(folder / "probe.py")
    assert names_in(files, folder) == {"energy.py", "laws.py", "tangential/angle.py"}
    assert siblings == () and values == (("params", "TANGENTIAL"), ("params", "NORMAL"))


def test_the_same_sources_elsewhere_have_the_same_stamps(kernels_copy):
    _, stamps, here = kernels_copy
    assert stamps()[("integrate.py", 0)] == here


def _save_entries(folder, first, count, barrier):
    from granlab.engine.kernels.cache import LockedCacheFile

    files = LockedCacheFile(folder, "kernel-1.py311", "stamp")
    barrier.wait()
    for key in range(first, first + count):
        files.save(("signature", key), {"code of": key})


def test_processes_saving_at_once_pair_every_index_entry_with_its_own_data(tmp_path):
    """Numba's own saves, run side by side, lost entries or paired one process's index with the
    other's data file (a kernel loaded so crashed the process). Locked, every entry is its own."""
    context = multiprocessing.get_context("spawn")
    barrier = context.Barrier(4)
    workers = [context.Process(target=_save_entries, args=(str(tmp_path), 100 * w, 40, barrier)) for w in range(4)]
    for worker in workers:
        worker.start()
    for worker in workers:
        worker.join(120)
        assert worker.exitcode == 0
    files = cache.LockedCacheFile(str(tmp_path), "kernel-1.py311", "stamp")
    keys = [("signature", 100 * w + k) for w in range(4) for k in range(40)]
    assert {key: files.load(key) for key in keys} == {key: {"code of": key[1]} for key in keys}
    assert not [path for path in os.listdir(tmp_path) if ".tmp." in path]


def test_stamp_folders_unused_for_two_weeks_go_then_the_least_recently_used_beyond_the_budget(tmp_path,
                                                                                            monkeypatch):
    now = 1_800_000_000
    ages_days = {"stamp-new": 0, "stamp-week": 7, "stamp-month": 30, "stamp-used": 60}
    for name, age in ages_days.items():
        (tmp_path / name).mkdir()
        (tmp_path / name / "kernel.nbc").write_bytes(b"x" * 1000)
        when = now - age * 86400
        os.utime(tmp_path / name, (when, when))
    (tmp_path / "stamp-file").write_bytes(b"not a folder")
    (tmp_path / "other").mkdir()
    monkeypatch.setattr(cache, "_USED", {str(tmp_path / "stamp-used")})

    removed = cache.prune(str(tmp_path), now=now)

    assert sorted(Path(path).name for path in removed) == ["stamp-month"]
    monkeypatch.setattr(cache, "BUDGET_BYTES", 2500)  # three folders of 1000 bytes left
    assert [Path(path).name for path in cache.prune(str(tmp_path), now=now)] == ["stamp-week"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["other", "stamp-file", "stamp-new", "stamp-used"]
    assert cache.prune(str(tmp_path / "missing")) == []


def test_every_numba_kernel_lives_in_the_kernels_package_and_uses_its_cache():
    """A kernel elsewhere (the scene's contact fields were in the lab's package, the fractal grid in
    the analysis) was cached by Numba's own rule and could run stale after a change to a kernel
    it calls or a constant it compiles in."""
    from granlab.engine.kernels import fields, grid

    root = Path(jit.__file__).resolve().parents[2]
    sources = [path for folder in ("app", "engine", "granlab") for path in (root / folder).rglob("*.py")]
    elsewhere = [path.relative_to(root) for path in sources
                 if KERNELS not in path.resolve().parents and re.search(KERNEL_DECORATOR, path.read_text())]
    assert elsewhere == []
    numba_own = [path.relative_to(root) for path in KERNELS.rglob("*.py")
                 if re.search(r"(?m)^from numba import .*\bnjit\b|^\s*@numba\.njit", path.read_text())]
    assert numba_own == []
    for dispatcher in (fields.contact_fields, grid.paint_disks, grid.shell_sums, grid.label_moments):
        assert type(dispatcher._cache) is cache.KernelCache


def test_a_copy_of_the_sources_finds_the_kernels_the_installed_ones_compiled(tmp_path):
    """The cache is keyed by the sources' content, not their place: the wheel's virtual environment, a
    copied source tree and the checkout share one set of compiled kernels."""
    import granlab
    from granlab.engine.protocols.teaching import collision

    collision()  # compiled here, or found
    root = tmp_path / "granlab"
    for name, source in (("", Path(granlab.__file__).parent), ("engine", cache.ENGINE)):
        shutil.copytree(source, root / name, dirs_exist_ok=True, ignore=shutil.ignore_patterns("__pycache__"))
    script = textwrap.dedent(f"""
        import granlab.engine
        assert granlab.engine.__file__.startswith({str(root)!r}), granlab.engine.__file__
        from granlab.engine.kernels import integrate
        from granlab.engine.protocols.teaching import collision
        collision()
        stats = integrate.ADVANCE[0].stats
        assert sum(stats.cache_misses.values()) == 0 and sum(stats.cache_hits.values()) == 1, stats
    """)
    subprocess.run([sys.executable, "-c", script], env={**os.environ, "PYTHONPATH": str(tmp_path)}, check=True,
                   cwd=tmp_path, timeout=120)


def test_a_compile_whose_kernels_cannot_be_kept_says_so_and_exits_2(tmp_path):
    """Into a cache that takes no file of more than 4 KiB (a full disk's refusal, by RLIMIT_FSIZE: Python
    ignores SIGXFSZ, so a write past it fails as ENOSPC would), ``granlab compile`` said "compiled in 3 s
    (kept for the next runs)" and exited 0, and the next run compiled from nothing."""
    import resource

    def limit_files():
        resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))

    env = {**os.environ, "GRANLAB_CACHE_DIR": str(tmp_path / "cache")}
    command = [sys.executable, "-m", "granlab.app.commands", "compile", "--only", "state"]
    full = subprocess.run(command, capture_output=True, text=True, env=env, preexec_fn=limit_files, timeout=300)
    assert full.returncode == 2, full.stderr
    lines = full.stderr.splitlines()
    assert "compiled in" in lines[-2] and "but 1 of 1 sets could not be kept (the kernel cache" in lines[-2]
    assert lines[-1].startswith("granlab compile: error: 1 of 1 kernel sets are not in the kernel cache after "
                                "compiling them (state): the kernel cache ")
    room = subprocess.run(command, capture_output=True, text=True, env=env, timeout=300)
    assert room.returncode == 0 and "compiled in" in room.stderr and "kept for the next runs" in room.stderr
    again = subprocess.run(command, capture_output=True, text=True, env=env, timeout=300)
    assert again.returncode == 0 and again.stdout.startswith("every kernel set was compiled before (1)")
