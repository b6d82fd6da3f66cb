"""The studies as sweeps: their cases run through `sweep`'s engine (abd_joint_sim/tools/sweep.py).

Each study lists its cases as sweep cases (`study/stability.py: sweep_cases`,
`study/error_vs_runtime.py: sweep_cases`): mappings of axis values with the axes `study`
(which study) and `index` (the case's place in the study's own order). The spec handed to
the sweep's Python API has `runner: study.sweeps:run_case`, which runs one case in a worker
as the study runs it (the study's per-step checks, references and timing), so `--workers`,
`--address` and `--in-process` mean what they mean to `sweep`. The cases go to the workers
longest first (an estimate of each case's cost), so the long runs do not finish last; the
analysis puts the rows back in the study's order (`index`) and writes the study's tables
and plots from the sweep's `results.csv` only.

    python -m study --workers 2                    # both studies in one sweep (one Ray start)
    python -m study.stability --workers 2          # one study
    python -m study.stability --from-sweep DIR     # the tables from a sweep run elsewhere
"""
from __future__ import annotations

import csv
from pathlib import Path
import shutil
import sys

STUDIES = ('stability', 'error_vs_runtime')
RUNNER = 'study.sweeps:run_case'
BASE_TYPES = {'case': str, 'status': str, 'message': str, 'study': str, 'index': int}


def _module(name):
    import importlib
    if name not in STUDIES:
        raise ValueError(f'study {name!r}: unknown (have: {", ".join(STUDIES)})')
    return importlib.import_module(f'study.{name}')


def run_case(values: dict) -> dict:
    """The sweep runner: one case of the study its `study` axis names (in a worker)."""
    return _module(values['study']).sweep_case(values)


def _check(values: dict) -> None:
    if 'study' not in values:
        raise ValueError('no study axis')
    _module(values['study']).sweep_check(values)


run_case.check = _check


def add_arguments(ap) -> None:
    """The sweep options every study command takes."""
    g = ap.add_argument_group('sweep (the cases run through abd_joint_sim/tools/sweep.py)')
    g.add_argument('--workers', type=int, metavar='N',
                   help='parallel workers (default: every core, or the cluster\'s CPUs)')
    g.add_argument('--address', metavar='ADDR',
                   help='a running Ray cluster (auto, HOST:PORT or ray://HOST:10001)')
    g.add_argument('--in-process', action='store_true',
                   help='run the cases one after another in this process (no Ray)')
    g.add_argument('--sweep-dir', type=Path, metavar='DIR',
                   help='where the sweep writes results.csv (default: out/sweep_<study>; '
                        'replaced on each run unless --resume)')
    g.add_argument('--resume', action='store_true',
                   help='keep the cases an interrupted run of the same sweep finished')
    g.add_argument('--from-sweep', type=Path, metavar='DIR',
                   help='run nothing: the tables from DIR/results.csv of this study\'s sweep')


def _cost_order(cases: list) -> list:
    """The cases longest first (their `cost` estimate, then the study's order); `cost` is
    dropped (it is no axis)."""
    order = sorted(range(len(cases)), key=lambda k: -cases[k]['cost'])
    return [{k: v for k, v in cases[i].items() if k != 'cost'} for i in order]


def run(names, args, options) -> tuple[int, dict]:
    """Run the cases of the studies `names` as one sweep; (status, {study: rows in the
    study's order}). `options[name]` is what that study's `sweep_cases` takes."""
    from abd_joint_sim.tools import sweep
    if args.from_sweep:
        return read_results(args.from_sweep / 'results.csv', names)
    cases = []
    for name in names:
        cases += _module(name).sweep_cases(**options[name])
    out = args.sweep_dir or Path('out') / ('sweep_' + '_'.join(names))
    if out.exists() and not args.resume:
        if not (out / 'sweep.json').is_file():
            print(f'study: --sweep-dir {out}: exists and holds no sweep; use a new directory',
                  file=sys.stderr)
            return 2, {}
        shutil.rmtree(out)
    data = {'runner': RUNNER, 'cases': _cost_order(cases), 'max_cases': max(len(cases), 1)}
    status = sweep.run_spec(data, out, workers=args.workers, address=args.address,
                            in_process=args.in_process, name=f'study {"+".join(names)}')
    if status not in (0, 1):
        return status, {}
    return read_results(out / 'results.csv', names)


def read_results(path: Path, names) -> tuple[int, dict]:
    """The rows of a study sweep's results.csv, typed by each study's columns, in each
    study's order: (0, {study: rows}), or (1, ...) with the cases that did not finish named."""
    try:
        with open(path, newline='') as f:
            raw = list(csv.DictReader(f))
    except OSError as exc:
        print(f'study: cannot read {path}: {exc.strerror or exc}', file=sys.stderr)
        return 2, {}
    out, status = {}, 0
    for name in names:
        mod = _module(name)
        mine = [r for r in raw if r.get('study') == name]
        bad = [r for r in mine if r.get('status') != 'ok']
        for r in bad:
            print(f'study: {name} {r.get("case")}: {r.get("status")}: {r.get("message")}',
                  file=sys.stderr)
        if bad or not mine:
            status = 1
            if not mine:
                print(f'study: {path}: no case of the {name} study', file=sys.stderr)
        types = {**BASE_TYPES, **mod.SWEEP_TYPES}
        rows = [_typed(r, types) for r in mine if r.get('status') == 'ok']
        rows.sort(key=lambda r: r['index'])
        out[name] = [mod.from_sweep_row(r) for r in rows]
    return status, out


def _typed(row: dict, types: dict) -> dict:
    """A results.csv row with the study's types: str, int, bool; other columns are floats
    written with repr (exact), or a string where the cell is no number ('-')."""
    out = {}
    for key, cell in row.items():
        kind = types.get(key)
        if kind is str:
            out[key] = cell
        elif kind is int:
            out[key] = int(cell) if cell != '' else None
        elif kind is bool:
            out[key] = cell == 'True'
        elif cell == '':
            continue                        # a column of another study's rows
        else:
            try:
                out[key] = float(cell)
            except ValueError:
                out[key] = cell
    return out
