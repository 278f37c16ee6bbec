"""The on-disk kernel cache is invalidated by a change to any kernel source, not only the kernel's own."""

import os
import re
from pathlib import Path

from granlab.engine.kernels import integrate, jit

KERNEL_DECORATOR = r"(?m)^\s*@(numba\.)?(njit|jit|vectorize|guvectorize|stencil|cfunc)\b"


def test_a_kernel_is_cached_under_the_stamp_of_every_kernel_source():
    # advance() holds compiled copies of the contact loop (contacts.py) and the laws (laws.py)
    locator = integrate.advance._cache._impl.locator
    assert type(locator).__name__.startswith("Kernels")
    assert locator.get_source_stamp() == jit.sources_stamp(jit.SOURCES)
    assert {"contacts.py", "laws.py", "integrate.py", "neighbours.py", "state.py", "params.py"} <= \
        {p.name for p in jit.SOURCES}
    # each stamp in a folder of its own: Numba unpickles an index before comparing its stamp, and an
    # index of other sources (naming the modules ``engine.*`` of before) stopped every run
    index = Path(integrate.advance._cache._cache_file._index_path)
    assert index.parent.name == f"stamp-{jit.package_stamp()[:16]}"


def test_the_stamp_changes_with_the_content_of_any_source(tmp_path):
    laws, contacts = tmp_path / "laws.py", tmp_path / "contacts.py"
    laws.write_text("GAMMA = 0\n")
    contacts.write_text("from .laws import GAMMA\n")
    before = jit.sources_stamp([laws, contacts])
    laws.write_text("GAMMA = 1\n")
    assert jit.sources_stamp([laws, contacts]) != before
    laws.write_text("GAMMA = 0\n")
    assert jit.sources_stamp([laws, contacts]) == before


def test_every_numba_kernel_lives_in_the_kernels_package_under_its_stamp():
    """A kernel elsewhere (the scene's contact fields were in the lab's package, the fractal grid in
    the analysis) was cached by Numba's own rule and could run stale after a change to a kernel
    it calls or a constant it compiles in."""
    from granlab.engine.kernels import fields, grid

    root = Path(jit.__file__).resolve().parents[2]
    sources = [path for folder in ("app", "engine", "granlab") for path in (root / folder).rglob("*.py")]
    elsewhere = [path.relative_to(root) for path in sources
                 if jit.KERNELS not in path.resolve().parents and re.search(KERNEL_DECORATOR, path.read_text())]
    assert elsewhere == []
    for dispatcher in (fields.contact_fields, grid.paint_disks, grid.shell_sums, grid.label_moments):
        assert type(dispatcher._cache._impl.locator).__name__.startswith("Kernels")


def test_stamps_of_earlier_sources_are_removed_but_the_most_recently_used(tmp_path):
    """Each edit of a kernel source compiles a stamp of about 30 MB: a checkout followed for a
    month kept gigabytes. The stamp in use and the two used last before it stay."""
    ages = {"stamp-current": 50, "stamp-a": 10, "stamp-b": 40, "stamp-c": 30, "stamp-d": 20}
    for name, age in ages.items():
        (tmp_path / name).mkdir()
        (tmp_path / name / "kernel.nbi").write_bytes(b"index")
        when = 1_700_000_000 - age * 3600
        os.utime(tmp_path / name, (when, when))
    (tmp_path / "jit.cpython-311.pyc").write_bytes(b"bytecode")
    (tmp_path / "stamp-file").write_bytes(b"not a folder")

    jit.prune_stamps(str(tmp_path), "stamp-current")

    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "jit.cpython-311.pyc", "stamp-a", "stamp-current", "stamp-d", "stamp-file"]
    assert (tmp_path / "stamp-current").stat().st_mtime > 1_700_000_000  # marked used now


def test_a_folder_that_cannot_be_read_is_left_as_it_is(tmp_path):
    jit.prune_stamps(str(tmp_path / "missing"), "stamp-current")
    assert not (tmp_path / "missing").exists()
