"""LLVM's SLP vectoriser for the physics kernels, which numba keeps off by default.

With SLP on (numba turned it off in 2023, numba#8852), straight-line runs of one operation on
neighbouring elements become one vector operation: linsolve.forward_block12 and
schur_update12 run ~2x faster. In the step (`python bench/profiler.py devices`, two runs,
ratio of an ABD_SLP=0 build's µs per step to this one's, `World.step(n)` / per
`World.step()`): chains of 100 links 1.23 / 1.20 and 1.31 / 1.27, of 1000 links
1.28 / 1.28 and 1.33 / 1.27, the KUKA iiwa 1.19 / 1.14 and 1.15 / 1.16; one link 1.01-1.07.
No result changes (no fast-math; test_solver.py compares with ABD_SLP=0 builds bit for bit).

Every `jit.kernel` compiles inside `enabled()` (numba's global `config.SLP_VECTORIZE`, put
back after). `ABD_SLP=0` compiles everything without it (cache.py keeps such builds apart).
"""
from __future__ import annotations

import contextlib

from numba.core import config

from .cache import switch

#: False with ABD_SLP=0 in the environment: every kernel compiled scalar (the comparison)
ENABLED = switch('ABD_SLP')


@contextlib.contextmanager
def enabled():
    """numba's SLP vectoriser on for the compiles inside (unless ABD_SLP=0), restored after."""
    before = config.SLP_VECTORIZE
    config.SLP_VECTORIZE = 1 if ENABLED else before
    try:
        yield
    finally:
        config.SLP_VECTORIZE = before


def vectorized(dispatcher):
    """Compile `dispatcher`'s overloads inside `enabled()`, wherever the compile is started."""
    compile_ = dispatcher.compile

    def compile(sig):
        with enabled():
            return compile_(sig)
    dispatcher.compile = compile
    return dispatcher
