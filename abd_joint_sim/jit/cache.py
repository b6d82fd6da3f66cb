"""Where numba keeps the compiled physics kernels, so they compile once per install.

One directory per user, numba and Python version (`$ABD_KERNEL_CACHE`, else
`$XDG_CACHE_HOME/abd_joint_sim/…` or `~/.cache/abd_joint_sim/…`), shared by the source tree
and an install, with a subdirectory per hash of ALL kernel sources (an edit in any kernel
file gives a new one; a directory per hash, as numba unpickles an index before comparing
its stamp). The KEEP most recently used are kept. A directory that cannot be written leaves
numba's own locators in charge.

Unpickling runs code: each directory of the path is created mode 0700 and must be owned by
the current user and not writable by group or others, and each file the same. A directory
that fails is refused with one line on stderr (the kernels then go to a private temporary
cache, removed at exit); a file that fails is not loaded (one line) and is compiled over,
as is a damaged entry (one line naming it).
"""
from __future__ import annotations

import functools
import hashlib
import os
import platform
import stat
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1]
#: where the compiled kernels live; the files among them that define any (`@kernel`) and the
#: packages' __init__ (terms/__init__.py lists the terms jit/unroll.py writes out) make the
#: cache stamp, so editing pure-Python modules there does not force a recompile
KERNEL_SOURCES = ('smallmat.py', 'terms', 'solver', 'jit')
#: the compiler devices' switches: NAME=0 in the environment compiles that device out (for
#: measuring what it pays: `python bench/profiler.py devices`); such a build is another build
SWITCHES = ('ABD_SLP', 'ABD_REFCOUNTS', 'ABD_FLAT', 'ABD_FLUSH_SUBNORMALS')


def switch(name: str) -> bool:
    """Whether the device of switch `name` (one of SWITCHES) is compiled in: unless NAME=0."""
    return os.environ.get(name, '1').strip() != '0'


@functools.lru_cache(maxsize=None)
def sources_hash() -> str:
    h = hashlib.sha256()
    for entry in KERNEL_SOURCES:
        path = PACKAGE / entry
        files = sorted(path.glob('*.py')) if path.is_dir() else [path]
        for f in files:
            text = f.read_bytes()
            if b'@kernel' in text or f.name == '__init__.py':
                h.update(f.relative_to(PACKAGE).as_posix().encode())
                h.update(text)
    h.update(' '.join(f'{name}=0' for name in SWITCHES if not switch(name)).encode())
    return h.hexdigest()[:20]


@functools.lru_cache(maxsize=None)
def directory() -> Path:
    import numba
    root = os.environ.get('ABD_KERNEL_CACHE')
    if not root:
        base = os.environ.get('XDG_CACHE_HOME') or os.path.join(os.path.expanduser('~'), '.cache')
        root = os.path.join(base, 'abd_joint_sim')
    tag = f'numba{numba.__version__}-py{sys.version_info[0]}{sys.version_info[1]}-{platform.machine()}'
    levels = [Path(root), Path(root) / tag, Path(root) / tag / sources_hash()]
    for level in levels:
        why = _untrusted(level, create=True)
        if why is None:
            return levels[-1]          # cannot be created: numba's own locators take over
        if why:
            return _private_fallback(level, why, tag)
    return levels[-1]


def _untrusted(path: Path, create: bool = False) -> str | None:
    """'' if `path` (a directory, or a file with `create` False) may be trusted: owned by
    the current user, not writable by group or others; else why not; None if a missing
    directory could not be created. `create`: make a missing directory, mode 0700."""
    if create:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)     # (~/.cache: the user's)
            path.mkdir(mode=0o700)
        except FileExistsError:
            pass
        except OSError:
            return None
    try:
        st = path.stat()
    except OSError as exc:
        return None if create else f'cannot be checked ({exc.strerror or exc})'
    if create and not stat.S_ISDIR(st.st_mode):
        return 'not a directory'
    if st.st_uid != os.geteuid():
        return f'owned by uid {st.st_uid}, not by the current user (uid {os.geteuid()})'
    if st.st_mode & 0o022:
        return f'writable by group or others (mode {stat.S_IMODE(st.st_mode):04o})'
    return ''


def _private_fallback(refused: Path, why: str, tag: str) -> Path:
    """A fresh private cache (mkdtemp: mode 0700, this user's), removed at exit."""
    import atexit
    import shutil
    import tempfile
    private = Path(tempfile.mkdtemp(prefix='abd_joint_sim-kernels-'))
    atexit.register(shutil.rmtree, private, True)
    (private / tag).mkdir(mode=0o700)
    here = private / tag / sources_hash()
    here.mkdir(mode=0o700)
    print(f'abd_joint_sim: refusing the kernel cache {refused}: {why}; compiling the physics '
          f'kernels into the private cache {private} instead', file=sys.stderr, flush=True)
    return here


#: kernel directories (source versions) kept per user, numba and Python version
KEEP = 4


def prune() -> None:
    """Remove all but the KEEP most recently compiled versions' directories, and anything
    else there untouched for a day (an unfinished compile). Best effort."""
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

    # Only this user's files are unpickled; an unreadable index or data file (truncated,
    # another numba's) is discarded and compiled over, with one line naming it.
    load_index = caching.IndexDataCacheFile._load_index
    load_data = caching.IndexDataCacheFile._load_data

    def _ours(path: str) -> bool:
        return path.startswith(str(directory()) + os.sep)

    def _trusted(path: str) -> bool:
        if not _ours(path) or not os.path.exists(path):
            return True
        why = _untrusted(Path(path))
        if why:
            _say(f'not loading the compiled kernel file {path}: {why}; compiling it again')
        return not why

    def _load_index(self):
        if not _trusted(self._index_path):
            return {}
        try:
            return load_index(self)
        except Exception as exc:                    # noqa: BLE001 - any unreadable index
            if _ours(self._index_path):
                _discard(self._index_path, exc)
            return {}

    def _load_data(self, name):
        path = self._data_path(name)
        if not _trusted(path):
            return None
        try:
            return load_data(self, name)
        except OSError:
            raise                                   # (numba: removed meanwhile -> a miss)
        except Exception as exc:                    # noqa: BLE001 - truncated, damaged
            if not _ours(path):
                raise
            _discard(path, exc)
            return None

    caching.IndexDataCacheFile._load_index = _load_index
    caching.IndexDataCacheFile._load_data = _load_data

    # An exclusive lock per cache directory around numba's read-number-write of an index, so
    # two compiling processes never take the same data file number. Installed once per
    # process: a second copy of the package (bench/ab.py's) would wait on the first's lock.
    index_save = caching.IndexDataCacheFile.save
    if getattr(index_save, 'locks_cache_directory', False):
        _installed = True
        return

    def save_locked(self, key, data):
        import fcntl
        try:
            lock = open(os.path.join(self._cache_path, '.lock'), 'a')
        except OSError:
            return index_save(self, key, data)
        with lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            return index_save(self, key, data)

    save_locked.locks_cache_directory = True
    caching.IndexDataCacheFile.save = save_locked
    _installed = True


_save_failed: list = []
_said: set = set()


def _say(line: str) -> None:
    if line not in _said:
        _said.add(line)
        print(f'abd_joint_sim: {line}', file=sys.stderr, flush=True)


def _discard(path: str, exc: BaseException) -> None:
    """Remove a damaged cache file (one line naming it); it is compiled again."""
    try:
        os.unlink(path)
    except OSError:
        pass
    what = f'{type(exc).__name__}: {exc}'.strip().rstrip(':')
    _say(f'discarding the damaged compiled kernel file {path} ({what}); compiling it again')


install()
