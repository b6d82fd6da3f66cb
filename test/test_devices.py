"""The compiler devices' switches (jit/cache.py SWITCHES): NAME=0 in the environment compiles
a device out, into a build the kernel cache keeps apart, and such a build steps to the same
bits as the default one (`python bench/profiler.py devices` times them side by side)."""
from __future__ import annotations

import os
from pathlib import Path
import subprocess
import sys

import pytest

from test_solver import _SLP_PROBE

REPO = Path(__file__).resolve().parents[1]
NEW = ('ABD_REFCOUNTS', 'ABD_FLAT', 'ABD_FLUSH_SUBNORMALS')

_READ = r'''
from abd_joint_sim.jit import cache, flat, refcounts, slp, subnormals
print(cache.sources_hash(), refcounts.ENABLED, flat.ENABLED, slp.ENABLED, subnormals.ENABLED)
'''


def _python(code, env, timeout=900):
    out = subprocess.run([sys.executable, '-c', code], env=dict(os.environ, **env),
                         capture_output=True, text=True, timeout=timeout, cwd=str(REPO))
    assert out.returncode == 0, out.stderr[-3000:]
    return [line for line in out.stdout.splitlines() if line.strip()]


def test_each_switch_turns_its_device_off_in_a_build_of_its_own():
    """Each switch, read when the package is imported, turns off its own device only and
    gives the kernel cache another directory (a build without a device never loads the
    default build's machine code, nor the other way round)."""
    from abd_joint_sim.jit import cache
    assert set(NEW) < set(cache.SWITCHES)
    clear = {s: '1' for s in cache.SWITCHES}
    default = _python(_READ, clear)[0].split()
    assert default[1:] == ['True'] * 4
    hashes = {default[0]}
    for k, name in enumerate(('ABD_REFCOUNTS', 'ABD_FLAT', 'ABD_SLP', 'ABD_FLUSH_SUBNORMALS')):
        got = _python(_READ, dict(clear, **{name: '0'}))[0].split()
        assert got[1:] == ['False' if i == k else 'True' for i in range(4)], (name, got)
        hashes.add(got[0])
    assert len(hashes) == 5


_OFF_PROBE = r'''
from numba import njit, typeof
from abd_joint_sim import Scene, World
from abd_joint_sim.builders import chain_scene
from abd_joint_sim.jit import refcounts, subnormals
w = World(Scene.from_dict(chain_scene(2)))
w.step(2)

@njit
def read(m):
    return refcounts.struct(m).joint_K.size
read.compile((typeof(w.solver.data),))
types = [t for cres in read.overloads.values() for t in cres.type_annotation.typemap.values()]
borrowed = any('Borrowed' in str(t) for t in types)

@njit
def flags():
    return subnormals._read_mxcsr()
before = flags()
saved = subnormals.enter()
flushing = bool(flags() & subnormals.FTZ_DAZ) and not before & subnormals.FTZ_DAZ
subnormals.leave(saved)
print('borrowed' if borrowed else 'counted', 'flushing' if flushing else 'not-flushing')
'''


@pytest.mark.slow
def test_a_build_without_the_devices_steps_bit_identically(tmp_path):
    """One build with ABD_REFCOUNTS=0, ABD_FLAT=0 and ABD_FLUSH_SUBNORMALS=0 (compiled
    afresh into its own cache: numba counts every reference, copies with its n-d
    assignment, never flushes subnormals) steps the four scenes of the ABD_SLP=0 check to
    the default build's bits (none of them makes a subnormal)."""
    off = {s: '0' for s in NEW}
    off['ABD_KERNEL_CACHE'] = str(tmp_path / 'cache')
    assert _python(_OFF_PROBE, {s: '1' for s in NEW}) == ['borrowed flushing']
    assert _python(_OFF_PROBE, off) == ['counted not-flushing']
    assert any((tmp_path / 'cache').rglob('*.nbi'))          # it did compile its own build
    default = _python(_SLP_PROBE, {s: '1' for s in NEW})
    assert len(default) == 4
    assert _python(_SLP_PROBE, off) == default
