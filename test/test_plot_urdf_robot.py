"""study/plot_urdf_robot.py: the KUKA lag study's CSV becomes docs/urdf.md's picture; a CSV
it cannot use is one line and exit status 2."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _module():
    spec = importlib.util.spec_from_file_location('plot_urdf_robot',
                                                  REPO / 'study' / 'plot_urdf_robot.py')
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.slow
def test_picture_from_the_committed_csv(tmp_path, capsys):
    pytest.importorskip('matplotlib', reason='matplotlib not installed (requirements-test.txt)')
    mod = _module()
    out = tmp_path / 'lag.png'
    assert mod.main(['--csv', str(REPO / 'docs/results/urdf_robot.csv'), '--out', str(out)]) == 0
    data = out.read_bytes()
    assert data[:8] == b'\x89PNG\r\n\x1a\n' and len(data) > 20_000
    # what is drawn: BDF1/BDF2 at the default kappa and MuJoCo Euler, 6 dt each
    rows = mod.read_rows(REPO / 'docs/results/urdf_robot.csv')
    curves = mod.series(rows)
    assert sorted(curves) == ['MuJoCo Euler', 'ours bdf1', 'ours bdf2']
    assert all(len(v) == 6 for v in curves.values())
    assert '28 rows' in capsys.readouterr().out
    # both panels say what their y axis is
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig = mod.plot(rows, tmp_path / 'again.png', plt)
    assert [ax.get_ylabel() for ax in fig.axes] == \
        ['largest joint-angle error over 0.2 s [rad]'] * 2


def test_bad_csv_is_one_line(tmp_path, capsys):
    pytest.importorskip('matplotlib', reason='matplotlib not installed (requirements-test.txt)')
    mod = _module()
    bad = tmp_path / 'bad.csv'
    bad.write_text('engine,dt\nours bdf2,0.001\n')
    assert mod.main(['--csv', str(bad), '--out', str(tmp_path / 'x.png')]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'cannot read' in err and 'bad.csv' in err
    assert mod.main(['--csv', str(tmp_path / 'none.csv'), '--out', str(tmp_path / 'x.png')]) == 2
