"""How the physics kernels are compiled, in one place.

- `kernel`: the one decorator of every physics kernel: numba's `njit` with the on-disk cache
  (cache.py), numpy's error model (a division by zero gives inf or NaN, as numpy does: no
  check and no exception per division) and LLVM's SLP vectoriser on while it compiles
  (slp.py);
- cache.py: where the compiled kernels are stored (one directory per source version);
- warmup.py: compiles every kernel once per install (`python -m abd_joint_sim.jit.warmup`);
- refcounts.py: the step's arrays and structs read without numba's reference counts;
- flat.py: whole-array copies and fills as one flat loop;
- subnormals.py: subnormal numbers flushed to zero while a step runs.
"""
from __future__ import annotations

from numba import njit

from . import slp

#: the compile options every kernel shares
OPTIONS = dict(cache=True, error_model='numpy')


def kernel(function=None, **options):
    """`@kernel` or `@kernel(inline='always')`: `function` compiled by numba with OPTIONS
    (plus `options`), its compiles run with the SLP vectoriser on (slp.vectorized)."""
    def compile_(f):
        return slp.vectorized(njit(f, **OPTIONS, **options))
    return compile_ if function is None else compile_(function)
