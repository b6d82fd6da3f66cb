"""What it costs to hand the model to a compiled function, per call (docs/physics-code.md):
a namedtuple of N arrays (numba unboxes every field on every call) against a structref of
the same N arrays (one pointer) and a call with 2 plain arrays.

    python bench/unboxing.py [--fields 30] [--calls 100000]
"""
from __future__ import annotations

import argparse
import time
from collections import namedtuple

import numpy as np
from numba import njit, types
from numba.experimental import structref


@structref.register
class _Type(types.StructRef):
    def preprocess_fields(self, fields):
        return tuple((n, types.unliteral(t)) for n, t in fields)


class _Proxy(structref.StructRefProxy):
    pass


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--fields', type=int, default=30)
    ap.add_argument('--calls', type=int, default=100000)
    args = ap.parse_args(argv)
    names = [f'a{i}' for i in range(args.fields)]
    arrays = [np.zeros(i + 3) for i in range(args.fields)]
    NT = namedtuple('NT', names)
    structref.define_proxy(_Proxy, _Type, names)
    nt, sr = NT(*arrays), _Proxy(*arrays)

    @njit
    def first_last(m):
        return m.a0[0]

    @njit
    def two(x, y):
        return x[0] + y[0]

    for label, fn, call_args in (('namedtuple', first_last, (nt,)), ('structref', first_last, (sr,)),
                                 ('2 arrays', two, (arrays[0], arrays[1]))):
        fn(*call_args)
        t0 = time.perf_counter()
        for _ in range(args.calls):
            fn(*call_args)
        print(f'{label:24s} {(time.perf_counter() - t0) / args.calls * 1e6:.2f} µs per call')


if __name__ == '__main__':
    main()
