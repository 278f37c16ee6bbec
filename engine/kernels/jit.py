"""Shared JIT flags, and the freshness stamp of the on-disk kernel cache.

``nogil`` lets the lab's event loops run while a kernel computes; ``cache``
keeps compiled kernels on disk; ``error_model="numpy"`` turns a division by
zero into inf/NaN (caught by the divergence checks) instead of a branch per
division. The thread-safe layer (OpenMP or TBB) lets parallel kernels be
launched from several Python threads at once.

Numba judges a cached kernel fresh when its own source file is unchanged, but a
kernel carries compiled copies of the functions it calls from other files (the
step kernel of ``integrate.py`` holds the contact loop and the laws). A kernel
of this package is therefore cached under a stamp of all of its sources, of
``engine/state.py`` and of ``engine/params.py`` (whose constants, the status and
tangential model codes, are compiled in): changing the contact law recompiles
every kernel that calls it.
"""

import functools
import hashlib
import os
import shutil
from pathlib import Path

import numba
from numba.core.caching import CacheImpl, InTreeCacheLocator, UserProvidedCacheLocator, UserWideCacheLocator

numba.config.THREADING_LAYER = "threadsafe"

JIT = dict(nogil=True, cache=True, error_model="numpy")
PARALLEL = dict(JIT, parallel=True)
#: for kernels that never allocate: no reference counting. Numba otherwise wraps every array
#: taken from a named tuple in atomic increments and decrements, some 60 per call of the
#: contact loop, which cost 4.5 us per call on these machines (more than all the work of a
#: 16-disk step). Numba refuses to compile an allocation in such a kernel. One of LLVM's
#: fast-math liberties, and only that one: ``x / y`` as ``x * (1 / y)`` (``arcp``, within an ulp).
#: Not fused multiply-adds (``contract``): which product LLVM fuses into an addition depends on
#: the code around it, so the gathered contact pass (vector code) and the direct one (scalar)
#: rounded the same row differently; unfused, they agree bit for bit, and a run gives the same
#: numbers on a processor without fused multiply-adds. None that assumes finite values (the
#: divergence checks test for NaN and inf) or reorders sums (the energy tallies, and the
#: bit-for-bit resumption, depend on their order).
KERNEL = dict(JIT, _nrt=False, fastmath={"arcp"})

KERNELS = Path(__file__).resolve().parent
SOURCES = tuple(sorted(KERNELS.rglob("*.py"))) + (KERNELS.parent / "state.py", KERNELS.parent / "params.py")


def sources_stamp(paths) -> str:
    """SHA-256 over the names and contents of ``paths``."""
    digest = hashlib.sha256()
    for path in paths:
        digest.update(Path(path).name.encode())
        digest.update(Path(path).read_bytes())
    return digest.hexdigest()


@functools.lru_cache(maxsize=1)
def package_stamp() -> str:
    return sources_stamp(SOURCES)


#: stamp folders kept beside the one in use, the most recently used first: a checkout moved back a
#: commit or two (or a lab still running the code before an edit) finds its kernels compiled.
KEPT_STAMPS = 2


@functools.lru_cache(maxsize=None)
def prune_stamps(folder: str, current: str) -> None:
    """Mark ``folder/current`` used now and remove the stamp folders beside it but the
    :data:`KEPT_STAMPS` most recently used: each edit of a kernel source compiles a new stamp
    (about 30 MB), which nothing else would remove. Once per folder and process; a folder that
    cannot be read or written is left as it is (Numba then caches elsewhere or not at all), and
    a process that finds its stamp removed compiles again."""
    try:
        with os.scandir(folder) as entries:
            others = [entry for entry in entries if entry.name.startswith("stamp-") and entry.name != current
                      and entry.is_dir(follow_symlinks=False)]
        if os.path.isdir(os.path.join(folder, current)):
            os.utime(os.path.join(folder, current))
        others.sort(key=lambda entry: entry.stat().st_mtime, reverse=True)
    except OSError:
        return
    for entry in others[KEPT_STAMPS:]:
        shutil.rmtree(entry.path, ignore_errors=True)


class _PackageStamped:
    """A Numba cache locator for the kernels of this package, stamped by :func:`package_stamp`.

    Each stamp has a folder of its own: Numba unpickles an index before it compares stamps, so an
    index written by other sources can name modules that no longer exist (the kernels' types were
    ``engine.state``'s before the package was ``granlab.engine``) and stop every run with
    ``ModuleNotFoundError`` instead of recompiling."""

    def get_source_stamp(self):
        return package_stamp()

    def get_cache_path(self):
        folder = super().get_cache_path()
        current = f"stamp-{package_stamp()[:16]}"
        prune_stamps(folder, current)
        return str(Path(folder) / current)

    @classmethod
    def from_function(cls, py_func, py_file):
        if KERNELS not in Path(py_file).resolve().parents:
            return None
        return super().from_function(py_func, py_file)


CacheImpl._locator_classes[:0] = [type(f"Kernels{base.__name__}", (_PackageStamped, base), {})
                                    for base in (UserProvidedCacheLocator, InTreeCacheLocator, UserWideCacheLocator)]
