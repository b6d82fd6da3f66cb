"""The first compile of the physics kernels (abd_joint_sim/jit/warmup.py, jit/cache.py): a progress
line every PROGRESS_SECONDS, a second process sharing the work on two or more cores, and a
cache index that concurrent writers keep consistent."""
from __future__ import annotations

import os
from pathlib import Path
import subprocess
import sys
import textwrap
import time

import pytest

from conftest import REPO


def test_a_compile_says_how_far_it_is_every_few_seconds(monkeypatch, tmp_path, capsys):
    from abd_joint_sim.jit import cache, warmup
    monkeypatch.setenv('ABD_COMPILE_JOBS', '1')
    monkeypatch.setattr(warmup, 'PROGRESS_SECONDS', 0.2)
    monkeypatch.setattr(warmup, '_run_kernels', lambda: time.sleep(1.1))
    monkeypatch.setattr(warmup, '_done', False)
    monkeypatch.setattr(cache, 'marker', lambda: tmp_path / 'compiled-marker')
    monkeypatch.setattr(cache, 'mark_compiled', lambda: (tmp_path / 'compiled-marker').write_text(''))
    monkeypatch.setattr(cache, 'kernel_count', lambda path=None: 7)
    monkeypatch.setattr(cache, 'previous_kernel_count', lambda: 0)
    assert warmup.ensure_compiled()['compiled']
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith('abd_joint_sim: compiling the physics kernels (first run')
    beats = [line for line in err if line.startswith('abd_joint_sim: compiling the physics '
                                                     f'kernels: 7/{warmup.EXPECTED_KERNELS} stored, ')]
    assert 3 <= len(beats) <= 6, err


def test_the_expected_total_is_the_last_complete_compiles_count(monkeypatch, tmp_path):
    from abd_joint_sim.jit import cache
    monkeypatch.setenv('ABD_KERNEL_CACHE', str(tmp_path))
    cache.directory.cache_clear()
    try:
        here = cache.directory()
        other = here.parent / 'another-version'
        other.mkdir(parents=True)
        (other / 'compiled-another-version').write_text('98 kernel signatures compiled\n')
        assert cache.previous_kernel_count() == 98
        (here / 'terms').mkdir(parents=True)
        for k in range(3):
            (here / 'terms' / f'f-1.py311.{k}.nbc').write_bytes(b'')
        assert cache.kernel_count() == 3
        cache.mark_compiled()
        assert cache.marker().read_text().split()[0] == '3'
    finally:
        cache.directory.cache_clear()


WRITER = textwrap.dedent('''
    import sys, time
    from abd_joint_sim.jit import cache
    from numba.core import caching
    cache.install()
    index = caching.IndexDataCacheFile(sys.argv[1], 'kernel-1.py311', 'stamp')
    time.sleep(max(0.0, float(sys.argv[3]) - time.time()))     # both start together
    for k in range(150):
        key = (sys.argv[2], k)
        index.save(key, {'key': key, 'code': bytes(20000)})
''')


def test_concurrent_writers_keep_the_index_consistent(tmp_path):
    """Two processes storing different signatures of one function at once (warmup's two
    processes; two first runs): every entry survives, each naming its own data file. Without
    cache.py's lock, both number their new files alike and one index names the other's
    machine code."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    start = str(time.time() + 3.0)
    procs = [subprocess.Popen([sys.executable, '-c', WRITER, str(tmp_path), who, start], env=env)
             for who in ('a', 'b')]
    assert [p.wait(timeout=120) for p in procs] == [0, 0]
    from numba.core import caching
    index = caching.IndexDataCacheFile(str(tmp_path), 'kernel-1.py311', 'stamp')
    for who in ('a', 'b'):
        for k in range(150):
            assert index.load((who, k)) == {'key': (who, k), 'code': bytes(20000)}


LISTENER = textwrap.dedent('''
    from numba.core import event
    compiled = []
    class L(event.Listener):
        def on_start(self, ev):
            f = ev.data['dispatcher'].py_func
            if (f.__module__ or '').startswith('abd_joint_sim'):
                compiled.append(f.__module__ + '.' + f.__qualname__)
        def on_end(self, ev):
            pass
    event.register('numba:compile', L())
''')


def _run(code, env, cwd):
    out = subprocess.run([sys.executable, '-c', code], env=env, cwd=cwd, capture_output=True,
                         text=True, timeout=1200)
    assert out.returncode == 0, out.stderr[-3000:]
    return out.stdout


@pytest.mark.slow
def test_the_helpers_kernels_are_the_ones_the_step_loads(tmp_path):
    """What the second process compiles first (`_late_subtrees`, in a cold cache) the main
    sequence then loads instead of compiling: the same signatures (a borrowed struct or a
    non-literal True would be another). After the whole two-process compile, a fresh process
    compiles none of our kernels: nothing is missing."""
    env = dict(os.environ, PYTHONPATH=str(REPO), ABD_KERNEL_CACHE=str(tmp_path / 'kc'),
               ABD_COMPILE_JOBS='1')
    late = ['abd_joint_sim.terms.driving.accumulate', 'abd_joint_sim.terms.limit.accumulate',
            'abd_joint_sim.terms.damping.accumulate', 'abd_joint_sim.solver.linsolve.solve',
            'abd_joint_sim.solver.retraction.retract']
    helper = LISTENER + textwrap.dedent('''
        import sys
        from abd_joint_sim.jit import cache, warmup
        cache.install()
        class Stop(Exception):
            pass
        def stop():
            raise Stop
        try:
            warmup._helper_kernels(stop)
        except Stop:
            pass
        print(sorted(set(compiled)))
    ''')
    stored = _run(helper, env, tmp_path)
    assert all(name in stored for name in late), stored
    main = LISTENER + textwrap.dedent('''
        from abd_joint_sim.jit import warmup
        warmup.ensure_compiled(verbose=False)
        print(sorted(set(compiled)))
    ''')
    compiled = _run(main, env, tmp_path)
    assert 'abd_joint_sim.solver.step.steps' in compiled, compiled
    assert not [name for name in late if f"'{name}'" in compiled], compiled
    # the whole compile with both processes, then a fresh process
    env.update(ABD_KERNEL_CACHE=str(tmp_path / 'kc2'), ABD_COMPILE_JOBS='2')
    proc = subprocess.run([sys.executable, '-m', 'abd_joint_sim.jit.warmup'], env=env, cwd=tmp_path,
                          capture_output=True, text=True, timeout=1200)
    assert proc.returncode == 0 and 'compiled in' in proc.stdout, proc.stderr[-3000:]
    from abd_joint_sim.jit import warmup
    stored = sum(1 for _ in (tmp_path / 'kc2').rglob('*.nbc'))
    assert stored == warmup.EXPECTED_KERNELS, (stored, 'the progress line\'s estimate')
    env['ABD_COMPILE_JOBS'] = '1'
    again = LISTENER + textwrap.dedent('''
        from abd_joint_sim.jit import cache, warmup
        cache.marker().unlink()              # run every entry point again, from the cache
        warmup.ensure_compiled(verbose=False)
        print(sorted(set(compiled)))
    ''')
    assert _run(again, env, tmp_path).strip() == '[]'


def test_the_warm_up_scenes_use_every_term():
    """Every term of terms.TERMS is used by a warm-up scene, so a compile reaches its kernels
    (the terms scene puts each joint term's EXAMPLE on a joint; a joint term added to the list
    without one fails here)."""
    from abd_joint_sim.jit import warmup
    from abd_joint_sim.model import compile_scene
    from abd_joint_sim.terms import TERMS
    models = [compile_scene(s) for s in (warmup._terms_scene(), warmup._loop_scene())]
    unused = [t.__name__ for t in TERMS if not any(t.used(m) for m in models)]
    assert unused == []
