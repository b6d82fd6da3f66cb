"""LLVM's SLP vectoriser for the physics kernels, which numba keeps off by default.

numba turned the SLP ("superword-level parallelism") vectoriser off in 2023 (numba#8852)
after miscompilations in the LLVM of the time; its loop vectoriser stays on, but it rarely
acts here because the compiler first unrolls the many loops of 3, 4, 9 or 12. With SLP on,
straight-line runs of the same operation on neighbouring elements become one vector
operation: the 12x12 block kernels written out for it (linsolve.forward_block12,
schur_update12) run ~2x faster. In the step (`python bench/profiler.py devices`, two runs,
ratio of the µs per step of an ABD_SLP=0 build to this one's, `World.step(n)` / one
`World.step()` per call): chains of 100 links 1.23 / 1.20 and 1.31 / 1.27, of 1000 links
1.28 / 1.28 and 1.33 / 1.27, the KUKA iiwa 1.19 / 1.14 and 1.15 / 1.16; one link 1.01-1.07.

It changes no result: numba compiles without fast-math, so nothing is reassociated or
contracted, and a vector operation rounds each element as the scalar one does. That is
checked, since a miscompilation is the risk (test_solver.py): the vectorised block kernels
against builds without it, and four scenes stepped by a build with ABD_SLP=0 (everything
scalar, its own cache) against this one, bit for bit.

The switch is numba's global `config.SLP_VECTORIZE`, read when a function is optimised: every
`jit.kernel` compiles inside `enabled()` (`vectorized` wraps its dispatcher's compile), which
puts it back after, so a user's numba code in the same process compiles as numba decides.
`ABD_SLP=0` in the environment compiles everything without it (cache.py keeps such builds
apart).
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
