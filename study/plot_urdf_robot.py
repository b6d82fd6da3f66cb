"""Picture of the KUKA lag study (study/urdf_robot.py) from its CSV, no re-run:
the largest joint-angle error against dt and against wall time per simulated second, for
ours (BDF1, BDF2 at the default κ = 1e8; BDF2 at κ 1e5..1e10 and the finest dt) and
MuJoCo's semi-implicit Euler. MuJoCo RK4 is the reference's own method (errors < 2e-6 rad,
in the CSV and docs/urdf.md's table): not drawn, it would only stretch the error axis.

    python study/plot_urdf_robot.py [--csv docs/results/urdf_robot.csv] [--out docs/img/urdf_robot_lag.png]

Needs matplotlib (requirements-study.txt); without it, one line and exit status 2.
"""
from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path
import sys

REPO = Path(__file__).resolve().parents[1]

KAPPA_DEFAULT = 1e8
STYLE = {'ours bdf1': dict(color='tab:orange', marker='s'),
         'ours bdf2': dict(color='tab:blue', marker='o'),
         'MuJoCo Euler': dict(color='tab:green', marker='^', ls='--')}


def read_rows(path: Path) -> list[dict]:
    with open(path, newline='') as handle:
        rows = list(csv.DictReader(handle))
    for r in rows:
        for key in ('dt', 'kappa', 'error', 'wall'):
            r[key] = float(r[key])
    return rows


def series(rows: list[dict]) -> dict[str, list[dict]]:
    """Curves: per engine at the default κ (MuJoCo has none), sorted by dt."""
    out: dict[str, list[dict]] = {}
    for r in rows:
        if r['engine'] not in STYLE or (r['engine'].startswith('ours') and
                                        r['kappa'] != KAPPA_DEFAULT):
            continue
        out.setdefault(r['engine'], []).append(r)
    for v in out.values():
        v.sort(key=lambda r: r['dt'])
    return out


def plot(rows: list[dict], out: Path, plt):
    """Draw and save the picture; returns the (closed) figure."""
    curves = series(rows)
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.6), constrained_layout=True)
    for name, pts in curves.items():
        err = [r['error'] for r in pts]
        label = name + (' (κ = 1e8)' if name.startswith('ours') else '')
        a.loglog([r['dt'] for r in pts], err, label=label, **STYLE[name])
        b.loglog([r['wall'] for r in pts], err, label=label, **STYLE[name])
    soft = sorted((r for r in rows if r['engine'] == 'ours bdf2' and
                   r['kappa'] != KAPPA_DEFAULT), key=lambda r: r['kappa'])
    for r in soft:
        a.loglog(r['dt'], r['error'], 'o', mfc='none', color='tab:red')
        a.annotate(f'κ = 1e{round(math.log10(r["kappa"]))}', (r['dt'], r['error']),
                   textcoords='offset points', xytext=(-8, 0), ha='right', va='center',
                   fontsize=8, color='tab:red')
    if soft:
        a.plot([], [], 'o', mfc='none', color='tab:red', label='ours bdf2, other κ')
    first = curves.get('ours bdf2', [])
    if len(first) >= 2:       # slope-2 guide through the finest BDF2 point
        r0 = first[0]
        xs = [r0['dt'], first[-1]['dt']]
        a.loglog(xs, [r0['error'] * (x / r0['dt']) ** 2 for x in xs], ':', color='0.4',
                 label='slope 2 (second order)')
    a.set_xlabel('time step dt [s]')
    for ax in (a, b):
        ax.set_ylabel('largest joint-angle error over 0.2 s [rad]')
    b.set_xlabel('wall time per simulated second [s] (2-core VM, ±30 %)')
    dts = sorted({r['dt'] for r in rows if r['engine'] in STYLE})
    a.set_xticks(dts, [f'{d:g}' for d in dts], minor=False)
    a.set_xticks([], minor=True)
    a.set_xlim(dts[0] / 4, dts[-1] * 1.5)
    for ax in (a, b):
        ax.grid(alpha=0.3, which='both')
    a.tick_params(axis='x', labelsize=8)
    a.legend(fontsize=8, loc='lower right')
    fig.suptitle('KUKA iiwa (pybullet_data) lagging a rigid reference (MuJoCo RK4, dt 1e-5): '
                 'torque step and gravity, 0.2 s', fontsize=11)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return fig


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--csv', default=str(REPO / 'docs/results/urdf_robot.csv'))
    parser.add_argument('--out', default=str(REPO / 'docs/img/urdf_robot_lag.png'))
    args = parser.parse_args(argv)
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        print('plot_urdf_robot: matplotlib is not installed (it is optional); '
              '`python -m pip install -r requirements-study.txt`', file=sys.stderr)
        return 2
    try:
        rows = read_rows(Path(args.csv))
    except (OSError, KeyError, ValueError) as exc:
        print(f'plot_urdf_robot: cannot read {args.csv}: {exc}', file=sys.stderr)
        return 2
    if not any(r['engine'] in STYLE for r in rows) or \
            not all(math.isfinite(r['error']) for r in rows):
        print(f'plot_urdf_robot: {args.csv}: no rows, or a non-finite error', file=sys.stderr)
        return 2
    plot(rows, Path(args.out), plt)
    print(f'plot_urdf_robot: {len(rows)} rows -> {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
