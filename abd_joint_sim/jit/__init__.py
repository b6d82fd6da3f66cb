"""How the physics kernels are compiled (docs/physics-code.md "Layout"): `kernel`, the one
decorator of every kernel, and the compiler devices beside it (cache.py, warmup.py,
refcounts.py, flat.py, slp.py, subnormals.py)."""
from __future__ import annotations

from numba import njit

from . import slp

#: the compile options every kernel shares
OPTIONS = dict(cache=True, error_model='numpy')


def kernel(function=None, **options):
    """`@kernel` or `@kernel(inline='always')`: `function` compiled by numba with OPTIONS (the
    on-disk cache, numpy's division semantics: inf or NaN, no check per division) plus
    `options`, its compiles run with LLVM's SLP vectoriser on (slp.vectorized)."""
    def compile_(f):
        return slp.vectorized(njit(f, **OPTIONS, **options))
    return compile_ if function is None else compile_(function)
