"""`python -m abd_joint_sim.fast --warm-up`: compile (or load from numba's cache) the fast
backend's kernels for this install, so that backend 'auto' uses them. Exit 0 on success,
1 when numba is not importable or the kernels fail to compile."""
import argparse
import sys

from . import compiled, warm_up


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='python -m abd_joint_sim.fast', description=__doc__.split('\n\n')[0])
    ap.add_argument('--warm-up', action='store_true', help='compile / load the kernels now')
    args = ap.parse_args(argv)
    if not args.warm_up:
        print('compiled' if compiled() else 'not compiled')
        return 0
    try:
        out = warm_up()
    except Exception as exc:  # noqa: BLE001 - report and fail, the numpy backend still works
        print(f'fast backend unavailable: {type(exc).__name__}: {exc}', file=sys.stderr)
        return 1
    how = 'loaded from cache' if out['cache_hits'] else 'compiled'
    print(f'fast backend {how} in {out["seconds"]:.1f} s')
    return 0


if __name__ == '__main__':
    sys.exit(main())
