"""Reduced versions of the studies (study/): convergence orders and stability criteria.

Budget: about 40-60 s on 2 cores. The full studies run from the command line
(docs/studies.md).
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from study import error_vs_runtime as E
from study import scenes as S
from study import stability as ST


def test_references():
    # PHYSICS.md §7 closed forms
    assert S.free_pair_reference()(1.0) == pytest.approx(11.786632172303, rel=1e-11)
    I, m = S.hinge_inertia()
    assert m == pytest.approx(64.0) and I == pytest.approx(24.7467, abs=1e-4)
    # pendulum sign: released from horizontal it falls (theta decreases), like the simulator
    assert S.pendulum_reference(0.0, 1.0)(0.1) < 0


@pytest.fixture(scope='module')
def sweep():
    rows, cfg = E.sweep(quick=True, tols=(0.005,), log=lambda *a: None)
    return rows, cfg, E.orders(rows, cfg['fit_min_dt'])


@pytest.mark.parametrize('scene', list(S.CASES))
@pytest.mark.parametrize('integrator,lo,hi', [('bdf1', 0.8, 1.3), ('bdf2', 1.7, 2.6)])
def test_convergence_order(sweep, scene, integrator, lo, hi):
    rows, cfg, orders = sweep
    (o,) = [o for o in orders if o['scene'] == scene and o['integrator'] == integrator
            and o['tau_sample'] == 'end']
    assert lo <= o['order_err_max'] <= hi, o


def test_zero_order_hold_torque_is_first_order(sweep):
    # sampling tau at the step start delays it by h: first order for both integrators
    rows, cfg, orders = sweep
    for o in orders:
        if o['tau_sample'] == 'start':
            assert 0.8 <= o['order_err_max'] <= 1.3, o


def test_error_study_checks(sweep):
    rows, cfg, orders = sweep
    assert E.check(rows, orders, cfg) == []
    fp = [r for r in rows if r['scene'] == 'free_pair']
    assert max(r['max_angular_momentum'] for r in fp) < 1e-6 * cfg['horizon']
    # bdf2 beats bdf1 at the same dt on every scene
    for r2 in (r for r in rows if r['integrator'] == 'bdf2' and r['tau_sample'] == 'end'):
        (r1,) = [r for r in rows if r['integrator'] == 'bdf1' and r['tau_sample'] == 'end'
                 and r['scene'] == r2['scene'] and r['dt'] == r2['dt']]
        assert r2['err_max'] < r1['err_max']
    assert E.pareto(rows)


def test_checks_can_fail():
    # a wrong reference must be caught by the study's own check
    rows = [dict(scene='hinge_const', integrator='bdf1', velocity_tol=0.005, tau_sample='end', dt=dt,
                 err_max=0.1, err_final=0.1, theta_final=0.5, error='', unconverged_steps=0,
                 max_angular_momentum=0.0, max_linear_momentum=0.0) for dt in (1e-2, 1e-3)]
    cfg = dict(E.QUICK, tols=(0.005,))
    problems = E.check(rows, E.orders(rows, 1e-3), cfg)
    assert any('order' in p for p in problems) and any('2%' in p for p in problems)


QUICK_GROUPS = ('kappa', 'strength_ratio', 'torque', 'dt', 'thin', 'singular_A', 'step_rotation', 'chain')


@pytest.fixture(scope='module')
def stability_rows():
    cs = [c for c in ST.cases(quick=True) if c.group in QUICK_GROUPS]
    # keep it short: fewer steps in the chain
    return [ST.run_case(c) for c in cs]


def test_no_unexpected_silent_failure(stability_rows):
    bad = ST.unexpected(stability_rows)
    assert not bad, [(r['case'], r['verdict'], r['reason']) for r in bad]


def test_stability_core_cases_pass(stability_rows):
    by = {r['case']: r for r in stability_rows}
    for name in ('kappa=1e+08 Pa', 'kappa=1e13 Pa, velocity_tol=1e-4', 'gamma=1', 'gamma=1e+08',
                 'tau=1e-06 N m', 'tau=1000 N m', 'dt=1e-05 s', 'dt=0.01 s',
                 'plate 0.4x0.4x4e-4 (aspect 1e-3)', 'rod 0.4x4e-4x4e-4 (aspect 1e-3)',
                 '20-link chain under gravity'):
        r = by[name]
        assert r['verdict'] == 'pass', r
        assert r['max_sep_rel'] < ST.SEP_FRAC
        if not math.isnan(r['energy_max_rise_rel']):
            assert r['energy_drop_rel'] >= 0


def test_singular_affine_state_is_reported(stability_rows):
    rows = [r for r in stability_rows if r['group'] == 'singular_A']
    assert len(rows) == 2
    for r in rows:
        assert r['verdict'] == 'pass' and 'near-singular A' in r['notes'], r


def test_stability_criteria_can_fail():
    # energy injected by hand must be caught: a spinning hinge whose velocity is doubled
    c = ST._hinge_pair('x', 'x', 5, 5)
    ph = c.phases[1]

    orig = ST.World.step
    calls = {'n': 0}

    def step(self, n=1):
        rep = orig(self, n)
        calls['n'] += 1
        if calls['n'] == 2:
            self.state.v *= 1.5
        return rep
    ST.World.step = step
    try:
        r = ST.run_phase(ph)
    finally:
        ST.World.step = orig
    assert any('energy' in v for v in r.violations)


@pytest.mark.xfail(reason='known core issue (docs/studies.md): large per-step rotations lag and '
                          'do not trigger sub-stepping', strict=False)
def test_known_rotation_lag():
    (c,) = [c for c in ST.cases(quick=True) if c.name.startswith('tau=1e5, dt=1e-2 (bdf1)')]
    assert ST.run_case(c)['verdict'] == 'pass'


@pytest.mark.xfail(reason='known core issue (docs/studies.md): Newton step-size stop accepts a '
                          'non-minimiser at dt=0.1', strict=False)
def test_known_newton_stop():
    (c,) = [c for c in ST.cases(quick=True) if c.name == 'dt=0.1 s']
    assert ST.run_case(c)['verdict'] == 'pass'
