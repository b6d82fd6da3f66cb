"""Both studies in one sweep (one Ray start, the cases of both on every worker):

    python -m study --workers 2 [--address ADDR] [--quick]

writes docs/results/stability, docs/results/error_study and the error study's PNGs in
docs/img, as `python -m study.stability --out docs/results/stability` and `python -m
study.error_vs_runtime --out docs/results/error_study --img-dir docs/img` do one at a time.
"""
from __future__ import annotations

import argparse
from pathlib import Path
import sys
import time

from study import error_vs_runtime as E
from study import stability as ST
from study import sweeps


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    ap = argparse.ArgumentParser(prog='python -m study', description=__doc__.split('\n')[0])
    ap.add_argument('--stability-out', type=Path, default=Path('docs/results/stability'))
    ap.add_argument('--error-out', type=Path, default=Path('docs/results/error_study'))
    ap.add_argument('--img-dir', type=Path, default=Path('docs/img'))
    ap.add_argument('--quick', action='store_true')
    ap.add_argument('--no-mujoco', action='store_true', help='skip the MuJoCo side-by-side points')
    sweeps.add_arguments(ap)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    mj_scenes, note = E.mujoco_plan(list(E.S.CASES), args)
    names = ['stability', 'error_vs_runtime']
    status, rows = sweeps.run(names, args, {'stability': dict(quick=args.quick),
                                            'error_vs_runtime': dict(quick=args.quick,
                                                                     mujoco_scenes=mj_scenes)})
    if status > 1 or not all(rows.get(n) for n in names):
        return status or 1
    st_args = argparse.Namespace(out=args.stability_out, quick=args.quick)
    er_args = argparse.Namespace(out=args.error_out, img_dir=args.img_dir, quick=args.quick,
                                 no_mujoco=args.no_mujoco, scenes=None)
    command = ' '.join(['python -m study'] + argv)
    a = ST.analyse(rows['stability'], st_args, command, t0, status)
    b = E.analyse(rows['error_vs_runtime'], er_args, command, t0, note, status)
    return max(a, b)


if __name__ == '__main__':
    sys.exit(main())
