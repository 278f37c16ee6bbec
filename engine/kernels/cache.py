"""The on-disk kernel cache: a folder per stamp of the sources a kernel is compiled from, shared by
every copy of those sources, written under a lock.

- **Stamps.** Numba judges a cached kernel fresh by its own source file, but a kernel carries
  compiled copies of the functions it calls from other files (the step driver holds the contact
  loop and the laws). A kernel's stamp is the SHA-256 of the kernel modules its module imports,
  directly or through others (read from their import statements; a package's ``__init__`` imports
  every module beside it), of ``engine/state.py`` (the array sets and codes) and of the values it
  imports from ``engine/params.py`` (the registries): editing a law recompiles the kernels whose
  modules import it and no other. A kernel compiled for one tangential model
  (:func:`for_model`) is stamped by that model's module and registry entry alone.
- **Place.** The folder is named by the stamp, under :func:`cache_root`: the same sources find the
  same kernels whether they run from a checkout, an installed wheel or a copy.
- **Writes.** Numba saves an entry as an index (signature to data file) and a data file; two
  processes saving at once could pair one's index with the other's data, and a kernel loaded so
  crashed the process. Saves hold an exclusive lock on the folder, reread the index under it and
  write the data before the index that names it.
- **Pruning.** A process marks the folders it uses; once a process, folders unused for
  :data:`UNUSED_DAYS` go, then the least recently used until the cache holds :data:`BUDGET_BYTES`.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib
import itertools
import os
import re
import shutil
import tempfile
import time
from pathlib import Path

from numba.core.caching import CompileResultCacheImpl, FunctionCache, IndexDataCacheFile, _CacheLocator

try:
    import fcntl
except ImportError:  # Windows: saves are not locked
    fcntl = None

THIS = Path(__file__).resolve()
KERNELS = THIS.parent
UNCOMPILED = ("cache.py", "watchers.py")
"""Modules of the kernels' package that compile nothing: this one and who is told of compiles."""
ENGINE = KERNELS.parent
STATE = ENGINE / "state.py"
PACKAGE = "granlab.engine"

UNUSED_DAYS = 14
BUDGET_BYTES = 1 << 30
MODEL_ATTRIBUTE = "granlab_tangential_model"
"""Set on a kernel's Python function: the tangential model code it is compiled for."""


def cache_root() -> Path:
    """Where the stamp folders are: ``$GRANLAB_CACHE_DIR``, else ``$NUMBA_CACHE_DIR/granlab``, else
    ``$XDG_CACHE_HOME/granlab`` (``~/.cache/granlab``); the first that can be written, else a folder
    in the temporary directory."""
    candidates = [os.environ.get("GRANLAB_CACHE_DIR")]
    if os.environ.get("NUMBA_CACHE_DIR"):
        candidates.append(os.path.join(os.environ["NUMBA_CACHE_DIR"], "granlab"))
    candidates.append(os.path.join(os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "granlab"))
    candidates.append(os.path.join(tempfile.gettempdir(), f"granlab-{os.getuid() if hasattr(os, 'getuid') else 0}"))
    for candidate in filter(None, candidates):
        if _writable(candidate):
            return Path(candidate)
    return Path(candidates[-1])


@functools.lru_cache(maxsize=None)
def _writable(folder: str) -> bool:
    try:
        os.makedirs(folder, exist_ok=True)
        tempfile.TemporaryFile(dir=folder).close()
    except OSError:
        return False
    return True


# ---------------------------------------------------------------------------------------- stamps
def _module_file(name: str) -> Path | None:
    """The file of module ``granlab.engine.<name>`` (dotted), if it is one of the kernels'."""
    path = ENGINE.joinpath(*name.split("."))
    path = path / "__init__.py" if path.is_dir() else path.with_suffix(".py")
    return path if KERNELS in path.parents and path.is_file() else None


_RELATIVE_IMPORT = re.compile(r"^[ \t]*from[ \t]+(\.+)([\w.]*)[ \t]+import[ \t]+(\([^)]*\)|[^\n#]*)", re.M)
_IMPORT_BY_NAME = re.compile(r"\.import_module\(")


@functools.lru_cache(maxsize=None)
def imports(path: Path) -> tuple[tuple[Path, ...], tuple[Path, ...], tuple[tuple[str, str], ...]]:
    """What the kernel module at ``path`` imports: the kernel modules it names, those it imports by
    name at run time (a package whose ``__init__`` calls ``importlib.import_module``: every module
    beside it) and the ``(module, name)`` of the values it takes from the rest of the engine. Read
    from its relative ``from`` imports by pattern, not by parsing: parsing the twenty modules took
    0.18 s of every command's start."""
    package = path.parent.relative_to(ENGINE).parts
    text = path.read_text()
    files, values = [], []
    for dots, named, names in _RELATIVE_IMPORT.findall(text):
        base = package[:len(package) - len(dots) + 1]
        module = ".".join((*base, *(named.split(".") if named else ())))
        for alias in re.sub(r"#[^\n]*", "", names).strip("() \t").split(","):
            if not alias.split():
                continue
            name = alias.split()[0]  # ``name as other``
            submodule = _module_file(f"{module}.{name}" if module else name)
            if submodule is not None:
                files.append(submodule)
            elif _module_file(module) is not None:
                files.append(_module_file(module))
            elif not module.startswith("kernels"):
                values.append((module, name))
    dynamic = _IMPORT_BY_NAME.search(text) is not None
    siblings = sorted(p for p in path.parent.glob("*.py") if p != path) if dynamic else []
    # a change to a module that compiles nothing recompiles nothing
    files = [file for file in dict.fromkeys(files) if not _uncompiled(file)]
    return tuple(files), tuple(file for file in siblings if not _uncompiled(file)), tuple(dict.fromkeys(values))


def _uncompiled(path: Path) -> bool:
    return path.parent == KERNELS and path.name in UNCOMPILED


def _model_file(code: int) -> Path:
    from ..params import TANGENTIAL

    model = next(model for model in TANGENTIAL.values() if model.code == code)
    return KERNELS / "tangential" / f"{model.key}.py"


def closure(path: Path, model: int | None = None) -> tuple[tuple[Path, ...], tuple[tuple[str, str], ...]]:
    """The kernel modules ``path`` depends on (itself included) and the engine values they import.
    With ``model``, a package importing the tangential models at run time brings that model's
    module only."""
    seen, values, todo = set(), set(), [path]
    while todo:
        current = todo.pop()
        if current in seen:
            continue
        seen.add(current)
        files, siblings, imported = imports(current)
        todo.extend(files)
        if siblings and model is not None and current.parent == KERNELS / "tangential":
            siblings = (_model_file(model),)
        todo.extend(siblings)
        values.update(imported)
    return tuple(sorted(seen)), tuple(sorted(values))


def _value_text(module: str, name: str, model: int | None) -> str:
    value = getattr(importlib.import_module(f"{PACKAGE}.{module}"), name)
    if model is not None and module == "params" and name == "TANGENTIAL":
        value = [entry for entry in value.values() if entry.code == model]
    return f"{module}.{name}={value!r}"


@functools.lru_cache(maxsize=None)
def kernel_stamp(path: Path, model: int | None = None) -> str:
    """SHA-256 of what a kernel of the module at ``path`` is compiled from (the module docstring)."""
    files, values = closure(path, model)
    digest = hashlib.sha256()
    for file in (STATE, *files):
        digest.update(file.relative_to(ENGINE).as_posix().encode())
        digest.update(file.read_bytes())
    for module, name in values:
        digest.update(_value_text(module, name, model).encode())
    return digest.hexdigest()


def for_model(function, tangential_model: int):
    """Mark ``function`` (to be compiled) as compiled for one tangential model: its stamp leaves out
    the other models' modules and registry entries."""
    setattr(function, MODEL_ATTRIBUTE, tangential_model)
    return function


# --------------------------------------------------------------------------------- locks, pruning
@contextlib.contextmanager
def folder_lock(folder: str):
    """An exclusive lock on ``folder`` (its ``.lock`` file), between processes."""
    if fcntl is None:
        yield
        return
    with open(os.path.join(folder, ".lock"), "a+b") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


_USED: set[str] = set()


def mark_used(folder: str) -> None:
    """Mark ``folder`` used now (once a process; this process's folders are never pruned) and prune
    its cache root (once a process)."""
    if folder in _USED:
        return
    _USED.add(folder)
    with contextlib.suppress(OSError):
        os.utime(folder)
    _prune_once(os.path.dirname(folder))


@functools.lru_cache(maxsize=None)
def _prune_once(root: str) -> None:
    prune(root)


def _size(folder: str) -> int:
    total = 0
    with contextlib.suppress(OSError), os.scandir(folder) as entries:
        for entry in entries:
            with contextlib.suppress(OSError):
                total += entry.stat(follow_symlinks=False).st_size
    return total


def prune(root: str, now: float | None = None) -> list[str]:
    """Remove the stamp folders of ``root`` unused for :data:`UNUSED_DAYS`, then the least recently
    used until the rest holds :data:`BUDGET_BYTES`; never a folder this process uses, a symlink or
    what cannot be read. Returns the folders removed."""
    now = time.time() if now is None else now
    try:
        with os.scandir(root) as entries:
            folders = [(entry.stat().st_mtime, entry.path) for entry in entries
                       if entry.name.startswith("stamp-") and entry.is_dir(follow_symlinks=False)]
    except OSError:
        return []
    sizes = {path: _size(path) for _, path in folders}
    total, removed = sum(sizes.values()), []
    for used, path in sorted(folders):
        if path in _USED:
            continue
        if now - used > UNUSED_DAYS * 86400 or total > BUDGET_BYTES:
            shutil.rmtree(path, ignore_errors=True)
            total -= sizes[path]
            removed.append(path)
    return removed


# --------------------------------------------------------------------------------- numba's classes
class KernelLocator(_CacheLocator):
    """A kernel's folder, ``<cache root>/stamp-<its stamp's first 16 hex digits>``."""

    def __init__(self, py_func, py_file):
        self._lineno = py_func.__code__.co_firstlineno
        self._stamp = kernel_stamp(Path(py_file).resolve(), getattr(py_func, MODEL_ATTRIBUTE, None))
        self._path = str(cache_root() / f"stamp-{self._stamp[:16]}")

    def get_cache_path(self):
        return self._path

    def get_source_stamp(self):
        return self._stamp

    def get_disambiguator(self):
        return str(self._lineno)

    @classmethod
    def from_function(cls, py_func, py_file):
        if KERNELS not in Path(py_file).resolve().parents:
            return None
        return cls(py_func, py_file)


class KernelCacheImpl(CompileResultCacheImpl):
    _locator_classes = [KernelLocator]


class LockedCacheFile(IndexDataCacheFile):
    """Numba's index and data files, saved under :func:`folder_lock`, the data first."""

    def save(self, key, data):
        with folder_lock(self._cache_path):
            overloads = self._load_index()
            data_name = overloads.get(key)
            if data_name is None:
                existing = set(overloads.values())
                data_name = next(name for name in map(self._data_name, itertools.count(1)) if name not in existing)
            self._save_data(data_name, data)
            if overloads.get(key) != data_name:
                overloads[key] = data_name
                self._save_index(overloads)


class KernelCache(FunctionCache):
    """Numba's cache of a kernel of this package, located, stamped and locked as the module says;
    its folder found when the kernel is first called, not when it is defined."""

    _impl_class = KernelCacheImpl

    def __init__(self, py_func):
        self._name = repr(py_func)
        self._py_func = py_func
        self.enable()

    @functools.cached_property
    def _impl(self):
        return self._impl_class(self._py_func)

    @functools.cached_property
    def _cache_path(self):
        return self._impl.locator.get_cache_path()

    @functools.cached_property
    def _cache_file(self):
        mark_used(self._cache_path)
        return LockedCacheFile(cache_path=self._cache_path, filename_base=self._impl.filename_base,
                               source_stamp=self._impl.locator.get_source_stamp())

    def load_overload(self, sig, target_context):
        if not os.path.isdir(self._cache_path):
            return None
        return super().load_overload(sig, target_context)

    def save_overload(self, sig, data):
        """Save, or leave unsaved where the folder cannot be written (the kernel then compiles again
        in the next process)."""
        with contextlib.suppress(OSError):
            super().save_overload(sig, data)
