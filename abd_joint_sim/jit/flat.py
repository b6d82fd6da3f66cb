"""Whole-array copies and fills as one flat loop.

numba compiles `dst[:] = src` on a 2-d or 3-d array through its n-d iterator; a flat loop
becomes vector moves (2-core VM, loaded: thirteen 12x12 blocks copy in 0.17 µs against 0.67,
a 1000-link chain's q in 1.8 µs against 4.5). `a.flat[i]`, not a reshape (a C helper call,
~20 ns). `array` makes the copies the kernels are compiled for.

In the step (`python bench/profiler.py devices`, two runs, µs per step with numba's
assignments / with these loops, `World.step(n)`; per `World.step()`): one link 1.09, 1.11;
1.02, 1.08; 100 links 1.04, 1.14; 1.02, 1.09; the KUKA iiwa 1.05-1.06; 1.02-1.04; 1000 links
0.97-1.07: about the noise of this loaded machine. `ABD_FLAT=0` compiles them as numpy's
`dst[:] = src` (the comparison; cache.py keeps that build apart).
"""
from __future__ import annotations

import numpy as np

from . import kernel
from .cache import switch

#: False with ABD_FLAT=0 in the environment: numba's n-d assignments (the comparison)
ENABLED = switch('ABD_FLAT')


@kernel
def copy(dst, src):
    """dst[...] = src (the same size and C order)."""
    if not ENABLED:
        dst[:] = src
        return
    d, s = dst.flat, src.flat
    for i in range(src.size):
        d[i] = s[i]


@kernel
def fill(dst, value):
    """dst[...] = value."""
    if not ENABLED:
        dst[:] = value
        return
    d = dst.flat
    for i in range(dst.size):
        d[i] = value


def array(x, dtype):
    """A writable C-contiguous copy of x: the layout the kernels are compiled for (a read-only
    or strided array is another numba type, and would compile them again)."""
    return np.ascontiguousarray(np.array(x, dtype=dtype, copy=True))
