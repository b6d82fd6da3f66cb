"""The compiled-kernel cache loads only what this user compiled, and survives damage.

A cache entry is a pickle: loading one runs whatever it says. Each test runs a small
kernel (``smallmat.svd3_in``, a few seconds to compile) in a fresh process with its own
``ABD_KERNEL_CACHE``; a planted entry would create a marker directory when unpickled.
"""

from __future__ import annotations

import os
from pathlib import Path
import pickle
import shutil
import stat
import subprocess
import sys

REPO = Path(__file__).resolve().parents[1]
CODE = ('import numpy as np; from abd_joint_sim import smallmat, cache; '
        'U, S, V = np.zeros((3, 3)), np.zeros(3), np.zeros((3, 3)); '
        'smallmat.svd3_in(np.diag([2.0, 3.0, 1.0]), U, S, V, np.zeros((2, 3, 3))); '
        'print(S.tolist()); '
        'print(cache.directory())')


def run(env_extra: dict) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(REPO), **env_extra)
    env.pop('ABD_KERNEL_CACHE', None) if 'ABD_KERNEL_CACHE' not in env_extra else None
    return subprocess.run([sys.executable, '-c', CODE], capture_output=True, text=True,
                          timeout=600, env=env, cwd=str(REPO))


class _Planted:
    """Unpickling this makes the directory `marker` (os.mkdir): code run from the cache."""

    def __init__(self, marker: str) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.mkdir, (self.marker,))


def compiled_cache(tmp_path: Path) -> tuple[Path, str]:
    """A cache with svd3_in compiled into it, and the first run's output."""
    cache = tmp_path / 'good'
    first = run({'ABD_KERNEL_CACHE': str(cache)})
    assert first.returncode == 0 and first.stderr == '', first.stderr[-2000:]
    return cache, first.stdout.splitlines()[0]


def plant(cache: Path, marker: Path) -> list[Path]:
    """Replace every compiled svd3_in data file of `cache` by the planted pickle."""
    files = list(cache.rglob('smallmat.svd3_in-*.nbc'))
    assert files
    for f in files:
        f.write_bytes(pickle.dumps(_Planted(str(marker))))
    return files


def test_a_cache_writable_by_others_is_refused(tmp_path):
    good, expected = compiled_cache(tmp_path)
    shared = tmp_path / 'shared'
    shutil.copytree(good, shared)
    marker = tmp_path / 'PLANTED-CODE-RAN'
    plant(shared, marker)
    for d in [shared, *[p for p in shared.rglob('*') if p.is_dir()]]:
        d.chmod(0o777)
    out = run({'ABD_KERNEL_CACHE': str(shared)})
    print(out.stderr)
    assert out.returncode == 0, out.stderr[-2000:]
    assert not marker.exists(), 'a pickle from a cache others can write was loaded'
    assert out.stdout.splitlines()[0] == expected
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and f'refusing the kernel cache {shared}' in lines[0], out.stderr
    assert 'writable by group or others (mode 0777)' in lines[0]
    used = Path(out.stdout.splitlines()[1])
    assert shared not in used.parents and not used.exists(), 'the private cache is removed'


def test_a_cache_file_writable_by_others_is_not_loaded(tmp_path):
    good, expected = compiled_cache(tmp_path)
    marker = tmp_path / 'PLANTED-CODE-RAN'
    files = plant(good, marker)
    for f in files:
        f.chmod(0o666)
    out = run({'ABD_KERNEL_CACHE': str(good)})
    assert out.returncode == 0, out.stderr[-2000:]
    assert not marker.exists(), 'a cache file others can write was loaded'
    assert out.stdout.splitlines()[0] == expected
    assert f'not loading the compiled kernel file {files[0]}' in out.stderr, out.stderr
    assert 'writable by group or others (mode 0666)' in out.stderr
    assert 'Traceback' not in out.stderr


def test_the_default_cache_is_created_private(tmp_path):
    home = tmp_path / 'home'
    home.mkdir()
    code = 'from abd_joint_sim.jit import cache; print(cache.directory())'
    env = dict(os.environ, PYTHONPATH=str(REPO), HOME=str(home))
    env.pop('ABD_KERNEL_CACHE', None)
    env.pop('XDG_CACHE_HOME', None)
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=120, env=env, cwd=str(REPO))
    assert out.returncode == 0, out.stderr[-2000:]
    here = Path(out.stdout.strip())
    root = home / '.cache' / 'abd_joint_sim'
    assert root in here.parents
    for d in (root, here.parent, here):
        assert stat.S_IMODE(d.stat().st_mode) == 0o700, (d, oct(d.stat().st_mode))


def test_a_truncated_cache_entry_is_discarded_and_compiled_again(tmp_path):
    good, expected = compiled_cache(tmp_path)
    files = list(good.rglob('smallmat.svd3_in-*.nbc'))
    assert files
    for f in files:
        f.write_bytes(f.read_bytes()[:len(f.read_bytes()) // 2])
    out = run({'ABD_KERNEL_CACHE': str(good)})
    print(out.stderr)
    assert out.returncode == 0 and 'Traceback' not in out.stderr, out.stderr[-2000:]
    assert out.stdout.splitlines()[0] == expected
    lines = out.stderr.strip().splitlines()
    assert len(lines) == len(files), out.stderr
    assert all('discarding the damaged compiled kernel file' in ln for ln in lines)
    assert str(files[0]) in out.stderr
    again = run({'ABD_KERNEL_CACHE': str(good)})
    assert again.returncode == 0 and again.stderr == '', 'compiled again and stored'


def test_a_second_copy_of_the_package_does_not_lock_the_cache_twice(tmp_path):
    """bench/ab.py imports another checkout's package beside this one: both install the
    cache's save lock, and a second lock on the same file would wait for the first forever.
    Installing again (as the second copy does) keeps one lock, and a save returns."""
    code = ('from numba.core import caching; from abd_joint_sim.jit import cache; '
            'cache.install(); cache._installed = False; cache.install(); '
            f'f = caching.IndexDataCacheFile({str(tmp_path)!r}, "probe", ("stamp", 1)); '
            'f.save(("key",), b"data"); print(f.load(("key",)))')
    env = dict(os.environ, PYTHONPATH=str(REPO), ABD_KERNEL_CACHE=str(tmp_path / 'kc'))
    try:
        out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                             timeout=60, env=env, cwd=str(REPO))
    except subprocess.TimeoutExpired:
        raise AssertionError('a save waited on its own cache lock') from None
    assert out.returncode == 0 and out.stdout.strip() == "b'data'", out.stderr[-2000:]
