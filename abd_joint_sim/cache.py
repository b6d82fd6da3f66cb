"""Where numba keeps the compiled physics kernels, so they compile once per install.

numba's default cache sits beside each source file (`__pycache__`), keyed on the file's
directory: the source tree (tests) and a colcon install space (sim_node) are two copies of
the same files, so each compiled the kernels again. Here the kernels of this package are
cached in one directory per user, numba version and Python version
(`$ABD_KERNEL_CACHE`, else `$XDG_CACHE_HOME/abd_joint_sim/…` or `~/.cache/abd_joint_sim/…`),
in a subdirectory named by a hash of ALL kernel sources: any edit to any kernel file
gives a new directory (numba alone would not notice an edit in a callee that lives in
another file). Why a directory per hash rather than one directory with stamped entries:
numba unpickles an index's signatures before it compares the stamp, so another version's
index naming a type this version lacks was an ImportError out of the first kernel call
(switching checkouts or versions), and two versions used alternately recompiled over each
other. Only the KEEP most recently used directories are kept. A directory that cannot be
written leaves numba's own locators in charge.
"""
from __future__ import annotations

import functools
import hashlib
import os
import platform
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent
#: where the compiled kernels live; the files among them that define any (`njit(`) make the
#: cache stamp, so editing pure-Python modules there does not force a recompile
KERNEL_SOURCES = ('smallmat.py', 'angles.py', 'terms', 'solver')


@functools.lru_cache(maxsize=None)
def sources_hash() -> str:
    h = hashlib.sha256()
    for entry in KERNEL_SOURCES:
        path = PACKAGE / entry
        files = sorted(path.glob('*.py')) if path.is_dir() else [path]
        for f in files:
            text = f.read_bytes()
            if b'njit(' in text:
                h.update(f.relative_to(PACKAGE).as_posix().encode())
                h.update(text)
    from .solver import vectorize        # a build without the SLP vectoriser is another build
    h.update(b'slp' if vectorize.ENABLED else b'no-slp')
    return h.hexdigest()[:20]


@functools.lru_cache(maxsize=None)
def directory() -> Path:
    import numba
    root = os.environ.get('ABD_KERNEL_CACHE')
    if not root:
        base = os.environ.get('XDG_CACHE_HOME') or os.path.join(os.path.expanduser('~'), '.cache')
        root = os.path.join(base, 'abd_joint_sim')
    tag = f'numba{numba.__version__}-py{sys.version_info[0]}{sys.version_info[1]}-{platform.machine()}'
    return Path(root) / tag / sources_hash()


#: kernel directories (source versions) kept per user, numba and Python version
KEEP = 4


def prune() -> None:
    """Remove all but the KEEP most recently compiled source versions' directories, and
    anything else there (an unfinished compile, the layout before per-version directories)
    untouched for a day. Best effort."""
    import shutil
    import time
    here = directory()
    try:
        parent = here.parent
        versions = [d for d in parent.iterdir() if d != here]
        day_ago = time.time() - 86400
        old = [d for d in versions if not (d.is_dir() and any(d.glob('compiled-*')))
               and d.stat().st_mtime < day_ago]
        versions = [d for d in versions if d.is_dir() and any(d.glob('compiled-*'))]
        done = sorted(versions, key=lambda d: d.stat().st_mtime)
        for d in old + done[:max(0, len(done) - (KEEP - 1))]:
            shutil.rmtree(d, ignore_errors=True) if d.is_dir() else d.unlink()
    except OSError:
        pass


def marker() -> Path:
    """Exists once every kernel has been compiled for these sources."""
    return directory() / f'compiled-{sources_hash()}'


def kernel_count(path: Path | None = None) -> int:
    """Kernel signatures stored under `path` (default: this version's directory)."""
    try:
        return sum(1 for _ in (path or directory()).rglob('*.nbc'))
    except OSError:
        return 0


def previous_kernel_count() -> int:
    """The count the most recent complete compile of another source version stored (0 if
    none): a compile's expected total."""
    try:
        marks = sorted(directory().parent.glob('*/compiled-*'), key=lambda p: p.stat().st_mtime)
        for mark in reversed(marks):
            text = mark.read_text().split()
            if text and text[0].isdigit():
                return int(text[0])
    except OSError:
        pass
    return 0


def mark_compiled() -> None:
    try:
        marker().write_text(f'{kernel_count()} kernel signatures compiled for these sources\n')
    except OSError:
        return
    prune()


def _writable(path: Path) -> bool:
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / f'.probe-{os.getpid()}'
        probe.write_text('')
        probe.unlink()
        return True
    except OSError:
        return False


_installed = False


def install() -> None:
    """Put the package locator first in numba's list (idempotent)."""
    global _installed
    if _installed:
        return
    from numba.core import caching

    class PackageCacheLocator(caching._SourceFileBackedLocatorMixin, caching._CacheLocator):
        def __init__(self, py_func, py_file):
            self._py_file = py_file
            self._lineno = py_func.__code__.co_firstlineno
            rel = Path(py_file).resolve().parent.relative_to(PACKAGE)
            self._cache_path = str(directory() / rel)

        def get_cache_path(self):
            return self._cache_path

        def get_source_stamp(self):
            return sources_hash()

        @classmethod
        def from_function(cls, py_func, py_file):
            try:
                Path(py_file).resolve().relative_to(PACKAGE)
            except (ValueError, OSError):
                return None
            return cls(py_func, py_file) if _writable(directory()) else None

    caching.CacheImpl._locator_classes.insert(0, PackageCacheLocator)

    # A cache that cannot be written (full disk, quota, a file-size limit) costs a compile
    # next time, never the run: numba would raise the OSError out of the first call.
    save = caching.Cache.save_overload

    def save_overload(self, sig, data):
        try:
            save(self, sig, data)
        except OSError as exc:
            if not str(getattr(self, '_cache_path', '')).startswith(str(directory())):
                raise
            if not _save_failed:
                _save_failed.append(exc)
                print(f'abd_joint_sim: could not store the compiled physics kernels in '
                      f'{directory()} ({exc.strerror or exc}); running on, they will be '
                      'compiled again next time', file=sys.stderr, flush=True)

    caching.Cache.save_overload = save_overload

    # An index that cannot be read (truncated by a full disk or a killed process, written by
    # another numba) is a stale cache, compiled over, not an exception out of the first call.
    load_index = caching.IndexDataCacheFile._load_index

    def _load_index(self):
        try:
            return load_index(self)
        except Exception:                           # noqa: BLE001 - any unreadable index
            return {}

    caching.IndexDataCacheFile._load_index = _load_index

    # Two processes compiling at once (warmup's helper; two first runs) each read an index,
    # number a new data file and write the index back: unserialised, both could take the same
    # number and one's index name the other's machine code. An exclusive lock per cache
    # directory around numba's read-number-write makes each save see the last.
    index_save = caching.IndexDataCacheFile.save

    def save_locked(self, key, data):
        import fcntl
        try:
            lock = open(os.path.join(self._cache_path, '.lock'), 'a')
        except OSError:
            return index_save(self, key, data)
        with lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            return index_save(self, key, data)

    caching.IndexDataCacheFile.save = save_locked
    _installed = True


_save_failed: list = []


install()
