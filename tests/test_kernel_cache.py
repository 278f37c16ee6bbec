"""The on-disk kernel cache is invalidated by a change to any kernel source, not only the kernel's own."""

from pathlib import Path

from granlab.engine.kernels import integrate, jit


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


def test_functions_outside_the_kernels_keep_numba_s_own_locator():
    from granlab.engine.analysis import fractal

    dispatcher = next(value for value in vars(fractal).values() if hasattr(value, "_cache") and value._cache)
    assert not type(dispatcher._cache._impl.locator).__name__.startswith("Kernels")
