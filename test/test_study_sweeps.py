"""The studies as sweeps (study/sweeps.py) and the sweep features they stand on: a spec's
`runner:` (a function in place of sim_node's loop) and its listed `cases:`.

* A subset of both studies runs through the sweep engine on a local Ray with 2 workers; the
  rows the analysis reads back from results.csv equal the serial computation (run_case,
  run_point) in every column but the measured times, in the studies' order, and the
  analysis writes the same table rows (25–35 s on the loaded 2-core machine, most of it Ray
  starting).
* A runner spec in process: listed cases, a runner's error as a row, bad runner specs as one
  line with nothing run.
"""
from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path
import sys
import textwrap

import pytest

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from abd_joint_sim.tools import sweep  # noqa: E402
from study import common  # noqa: E402
from study import error_vs_runtime as E  # noqa: E402
from study import scenes as S  # noqa: E402
from study import stability as ST  # noqa: E402
from study import sweeps  # noqa: E402

STABILITY_GROUPS = ('singular_A', 'step_rotation')
ERROR_SCENES = ['hinge_const', 'free_pair']
ERROR_TOLS = (0.005,)
TIMES = {'wall_s', 'wall_per_sim_s', 'ms_per_step'}       # measured, not computed


def _read_csv(path) -> list[dict]:
    """results.csv back as dicts (numbers as floats where they parse)."""
    rows = []
    with open(path, newline='') as f:
        for row in csv.DictReader(f):
            out = {}
            for k, v in row.items():
                try:
                    out[k] = float(v) if v not in ('', 'ok') else v
                except ValueError:
                    out[k] = v
            rows.append(out)
    return rows


def _same(a, b):
    """Equal, NaN equal to NaN."""
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b and type(a) is type(b)


def _differences(got, want):
    assert len(got) == len(want)
    return [(k, key, g[key], w[key]) for k, (g, w) in enumerate(zip(got, want))
            for key in w if key not in TIMES and not _same(g[key], w[key])]


def _args(tmp_path, **kw):
    base = dict(workers=None, address=None, in_process=False, sweep_dir=tmp_path / 'sweep',
                resume=False, from_sweep=None)
    base.update(kw)
    return argparse.Namespace(**base)


@pytest.fixture(scope='module')
def ray_run(tmp_path_factory):
    pytest.importorskip('ray', reason='the sweep engine (requirements-sweep.txt) is not installed')
    tmp = tmp_path_factory.mktemp('study_sweep')
    options = {'stability': dict(quick=True, groups=STABILITY_GROUPS),
               'error_vs_runtime': dict(quick=True, scenes=ERROR_SCENES, tols=ERROR_TOLS)}
    status, rows = sweeps.run(['stability', 'error_vs_runtime'], _args(tmp, workers=2), options)
    return tmp, status, rows


def test_a_study_subset_on_two_ray_workers_equals_the_serial_run(ray_run):
    tmp, status, rows = ray_run
    assert status == 0
    summary = (tmp / 'sweep' / 'summary.md').read_text()
    assert 'Ray ' in summary and '2 worker(s)' in summary, summary[:400]
    # stability: the cases of the subset, serially, as `python study/stability.py` runs them
    serial = [ST.run_case(c) for c in ST.cases(quick=True) if c.group in STABILITY_GROUPS]
    assert [r['case'] for r in rows['stability']] == [r['case'] for r in serial]
    assert list(rows['stability'][0]) == list(serial[0])
    assert _differences(rows['stability'], serial) == []
    # error study: its points serially, in sweep()'s order
    serial_e, cfg = E.sweep(quick=True, cases=ERROR_SCENES, tols=ERROR_TOLS, log=lambda *a: None)
    assert len(rows['error_vs_runtime']) == len(serial_e) == 2 * 2 * len(cfg['dts'])
    assert list(rows['error_vs_runtime'][0]) == list(E.COLUMNS)
    assert _differences(rows['error_vs_runtime'], serial_e) == []
    assert E.orders(rows['error_vs_runtime'], cfg['fit_min_dt']) == E.orders(serial_e, cfg['fit_min_dt'])


def test_the_analysis_writes_the_serial_tables(ray_run, tmp_path):
    _, _, rows = ray_run
    args = argparse.Namespace(out=tmp_path / 'st', quick=True)
    assert ST.analyse(rows['stability'], args, [], 0.0, log=lambda *a: None) == 0
    serial = [ST.run_case(c) for c in ST.cases(quick=True) if c.group in STABILITY_GROUPS]
    common.write_csv(tmp_path / 'serial.csv', serial, list(serial[0]))

    def table(path):
        with open(path, newline='') as f:
            return [{k: v for k, v in r.items() if k not in TIMES} for r in csv.DictReader(f)]
    assert table(tmp_path / 'st' / 'stability.csv') == table(tmp_path / 'serial.csv')
    md = (tmp_path / 'st' / 'summary.md').read_text()
    assert '| singular_A | a3 = cos(e) a2 + sin(e) a3, e=0 | pass | pass | 20 |' in md
    args = argparse.Namespace(out=tmp_path / 'er', img_dir=tmp_path / 'img', quick=True,
                              no_mujoco=True, scenes=ERROR_SCENES)
    E.analyse(rows['error_vs_runtime'], args, [], 0.0, 'no MuJoCo', log=lambda *a: None)
    with open(tmp_path / 'er' / 'orders.csv', newline='') as f:
        got = list(csv.DictReader(f))
    assert {(o['scene'], o['integrator']) for o in got} == {(s, i) for s in ERROR_SCENES
                                                            for i in E.INTEGRATORS}


def test_the_study_command_writes_its_tables_from_a_sweep_directory(ray_run, tmp_path, capsys):
    tmp, _, rows = ray_run
    out = tmp_path / 'st'
    assert ST.main(['--quick', '--from-sweep', str(tmp / 'sweep'), '--out', str(out)]) == 0
    with open(out / 'stability.csv', newline='') as f:
        assert [r['case'] for r in csv.DictReader(f)] == [r['case'] for r in rows['stability']]
    assert ST.main(['--from-sweep', str(tmp_path / 'nothing'), '--out', str(out)]) == 2
    assert 'cannot read' in capsys.readouterr().err


def test_cases_go_longest_first_and_come_back_in_the_study_order():
    cases = ST.sweep_cases(quick=False)
    ordered = sweeps._cost_order(cases)
    assert ordered[0]['name'] == '100000 steps bdf1 spin' and 'cost' not in ordered[0]
    assert sorted(c['index'] for c in ordered) == list(range(len(cases)))


# ------------------------------------------------------------ runner specs in process ----
RUNNER_MODULE = '''
def run(values):
    if values['x'] < 0:
        raise ValueError('x must not be negative')
    return {'square': values['x'] ** 2, 'label': f"x={values['x']}"}

def check(values):
    if 'x' not in values:
        raise ValueError('no x')

run.check = check

def wall(values):
    return {'wall_s': 1.0}
'''


@pytest.fixture
def runner_module(tmp_path, monkeypatch):
    (tmp_path / 'tiny_runner.py').write_text(RUNNER_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    return 'tiny_runner'


def _write(tmp_path, text):
    path = tmp_path / 'spec.yaml'
    path.write_text(textwrap.dedent(text))
    return path


def test_a_runner_spec_runs_listed_cases_and_a_failing_case_is_a_row(runner_module, tmp_path):
    spec = _write(tmp_path, f"""\
        runner: {runner_module}:run
        cases:
          - {{x: 3}}
          - {{x: -1}}
          - {{x: 0.5}}
        """)
    assert sweep.main([str(spec), '--out', str(tmp_path / 'o'), '--in-process', '-q']) == 1
    rows = _read_csv(tmp_path / 'o' / 'results.csv')
    with open(tmp_path / 'o' / 'results.csv') as f:
        header = f.readline().strip().split(',')
    assert header == ['case', 'x', 'status', 'message', 'square', 'label', 'wall_s']
    assert [r['status'] for r in rows] == ['ok', 'error', 'ok']
    assert rows[0]['square'] == 9.0 and rows[2]['label'] == 'x=0.5'
    assert 'x must not be negative' in rows[1]['message']


def test_the_python_api_runs_a_spec_given_as_data(runner_module, tmp_path):
    data = {'runner': f'{runner_module}:run', 'grid': {'x': [1.0, 2.0]}}
    assert sweep.run_spec(data, tmp_path / 'o', in_process=True, quiet=True, name='api') == 0
    assert [r['square'] for r in _read_csv(tmp_path / 'o' / 'results.csv')] == [1.0, 4.0]


@pytest.mark.parametrize('text,message', [
    ('runner: no_such_module_here:run\ncases: [{x: 1}]\n', 'runner: no_such_module_here:run: ModuleNotFoundError'),
    ('runner: RUNNER:nothing\ncases: [{x: 1}]\n', "has no attribute 'nothing'"),
    ('runner: just_a_name\ncases: [{x: 1}]\n', 'expected module:function'),
    ('runner: RUNNER:run\nscene: hinge\ncases: [{x: 1}]\n', 'builds its cases itself'),
    ('runner: RUNNER:run\ncases: [{y: 1}]\n', 'case 0 (y = 1): no x'),
    ('runner: RUNNER:run\ncases: [{wall_s: 1}]\n', "axis 'wall_s' is a result column"),
    ('runner: RUNNER:run\ngrid: {x: [1]}\ncases: [{y: 1}]\n', 'a listed case names their axes'),
    ('runner: RUNNER:run\ncases: []\n', 'expected a non-empty list'),
])
def test_a_bad_runner_spec_is_one_line(runner_module, tmp_path, capsys, text, message):
    spec = _write(tmp_path, text.replace('RUNNER', runner_module))
    assert sweep.main([str(spec), '--out', str(tmp_path / 'o'), '--in-process']) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err
    assert not (tmp_path / 'o').exists()


def test_a_runner_may_not_return_a_reserved_column(runner_module, tmp_path):
    spec = _write(tmp_path, f'runner: {runner_module}:wall\ncases: [{{x: 1}}]\n')
    assert sweep.main([str(spec), '--out', str(tmp_path / 'o'), '--in-process', '-q']) == 1
    (row,) = _read_csv(tmp_path / 'o' / 'results.csv')
    assert row['status'] == 'error' and "column 'wall_s'" in row['message']


def test_a_study_case_unknown_to_the_study_is_refused(tmp_path, capsys):
    data = {'runner': sweeps.RUNNER, 'cases': [{'study': 'stability', 'index': 0, 'quick': True,
                                                'name': 'no such case'}]}
    assert sweep.run_spec(data, tmp_path / 'o', in_process=True, name='bad') == 2
    assert "no case named 'no such case'" in capsys.readouterr().err
    assert S.CASES                                      # (the study modules imported)
