"""Reduced versions of the studies (study/): convergence orders and stability criteria.

Budget: ~5 s once the physics kernels are compiled (`python -m abd_joint_sim.jit.warmup`)
on 2 shared cores. The full studies run from the command line (docs/studies.md).
Open physics-core issues would be strict xfails here (docs/studies.md section 3); there are
none at present: the last one (stiff-kappa drift) is test_stiff_kappa_does_not_drift.
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
    # docs/physics.md "Analytic references" closed forms
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


QUICK_GROUPS = ('kappa', 'strength_ratio', 'torque', 'dt', 'thin', 'singular_A', 'step_rotation', 'chain',
                'prismatic')


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


def test_prismatic_cases_pass(stability_rows):
    """Sliders: stiff bodies, large forces (d = ½ f/m t²), a limit hit at speed (energy never
    above the start's)."""
    rows = [r for r in stability_rows if r['group'] == 'prismatic']
    assert len(rows) == 6
    for r in rows:
        assert r['verdict'] == 'pass' and r['max_sep_rel'] < ST.SEP_FRAC, r
    hits = [r for r in rows if 'hits its limit' in r['case']]
    assert all(r['energy_drop_rel'] > 0.0 for r in hits)


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


def _case(name):
    (c,) = [c for c in ST.cases(quick=True) if c.name == name]
    return c


def test_large_rotation_sub_steps_and_says_so(stability_rows):
    # a torque whose step would turn the joint ~6 rad is refused on the predicted rotation
    # and sub-stepped, and the inaccuracy left at that dt is reported (fail-loud), never
    # silent
    by = {r['case']: r for r in stability_rows}
    for name in ('tau=1e5, dt=1e-2 (bdf1): rotation/step -> pi', 'tau=1e5, dt=1e-2 (bdf2): rotation/step -> pi',
                 'tau=1e7, dt=1e-2: beyond 2^4 sub-steps', 'tau=1e+06 N m'):
        r = by[name]
        assert r['verdict'] in ('pass', 'fail-loud') and r['as_expected'], r
    assert by['tau=1e5, dt=1e-2 (bdf1): rotation/step -> pi']['substep_steps'] > 0
    assert 'sub-stepping' in by['tau=1e5, dt=1e-2 (bdf1): rotation/step -> pi']['notes']
    w = ST.common.make_world(S.hinge_scene(1e-2, tau=1e5))
    w.set_torque_enabled('hinge', True)
    w.set_torque('hinge', 1e5)
    rep = w.step()
    assert rep.substeps >= 2 and any('predicted to turn' in x for x in rep.warnings), rep


def test_large_dt_converges_to_the_minimiser_and_warns():
    # at dt = 0.1 a loose tolerance stays within velocity_tol*h (at the 0.6 m lever arm) of a
    # tight solve (BDF1 answer 0.1210 rad after 2 steps), and the BDF1 damping of the fast
    # rotation is reported
    def run(tol, steps):
        w = ST.common.make_world(S.hinge_scene(0.1, tau=100.0, velocity_tol=tol))
        w.set_torque_enabled('hinge', True)
        w.set_torque('hinge', 100.0)
        thetas, warnings = [], []
        for _ in range(steps):
            rep = w.step()
            assert rep.converged
            thetas.append(float(w.joint_angles()[0]))
            warnings += rep.warnings
        return thetas, warnings

    tight, _ = run(1e-7, 2)
    loose, warnings = run(0.05, 5)
    assert tight[1] == pytest.approx(0.1210, abs=2e-4)
    for a, b in zip(loose, tight):
        assert abs(a - b) <= 0.05 * 0.1 / 0.6
    assert any('damps rotation' in x for x in warnings), warnings
    r = ST.run_case(_case('dt=0.1 s'))
    assert r['verdict'] == 'fail-loud' and r['as_expected'] and 'damps rotation' in r['reason'], r


def test_momentum_criterion_has_a_rounding_floor():
    # an 8e8 kg parent: m v carries ~1e-5 kg m/s of rounding, which is not a failure
    r = ST.run_case(_case('m_parent/m_child=1e+08'))
    assert r['verdict'] == 'pass', r
    r = ST.run_case(_case('m_parent/m_child=0.0001'))     # the light parent is reported
    assert r['verdict'] == 'fail-loud' and r['as_expected'], r


def test_stiff_kappa_does_not_drift(stability_rows):
    # at kappa >= 1e11 and the default velocity_tol a linear Newton step would stretch the
    # turning body and stop biased; the screw steps (solver/retraction.py) keep both on the
    # BDF1 answer 0.514 rad after 50 steps
    by = {r['case']: r for r in stability_rows}
    for name in ('kappa=1e+11 Pa', 'kappa=1e+13 Pa'):
        assert by[name]['verdict'] == 'pass' and by[name]['known'] == '-', by[name]
    for kappa in (1e11, 1e13):
        w = ST.common.make_world(S.hinge_scene(1e-2, tau=100.0, kappa=kappa))
        w.set_torque_enabled('hinge', True)
        w.set_torque('hinge', 100.0)
        rep = [w.step() for _ in range(50)]
        assert all(r.converged and not r.warnings for r in rep)
        assert max(r.newton_iterations for r in rep) <= 8
        assert float(w.joint_angles()[0]) == pytest.approx(0.51414, abs=2e-4)


def test_bdf2_fast_rotation_is_reported(stability_rows):
    # bdf2 damps rotation at 0.3-0.6 rad per step; World.step reports it (threshold
    # 0.3 rad/step), so the cases fail loudly
    by = {r['case']: r for r in stability_rows}
    for name in ('tau=1e+06 N m (bdf2)', 'spin 60 rad/s, dt=1e-2 (bdf2): 0.6 rad/step'):
        assert by[name]['verdict'] == 'fail-loud' and by[name]['as_expected'], by[name]


def test_mujoco_peer_matches_the_scene():
    pytest.importorskip('mujoco')
    from study import mujoco_peer as M
    I, _ = S.hinge_inertia()
    assert M.hinge_inertia_of(S.CASES['hinge_const']) == pytest.approx(I, rel=1e-12)
    # semi-implicit Euler on a constant torque: error 1/2 alpha h t exactly; RK4 exact
    r = M.run_point(S.CASES['hinge_const'], 1e-2, 'mj_euler', 0.3, repeats=1)
    assert r['err_final'] == pytest.approx(0.5 * 100.0 / I * 1e-2 * 0.3, rel=1e-6)
    assert M.run_point(S.CASES['hinge_const'], 1e-2, 'mj_rk4', 0.3, repeats=1)['err_max'] < 1e-12
    r = M.run_point(S.CASES['pendulum_sine'], 1e-3, 'mj_rk4', 0.3, repeats=1)
    assert r['err_max'] < 1e-5


def test_error_study_runs_without_mujoco(monkeypatch):
    monkeypatch.setattr(E.M, 'module', lambda: None)
    rows, note = E.mujoco_run([{'scene': 'hinge_const'}], type('A', (), {'no_mujoco': False})(), {})
    assert rows == [] and 'not installed' in note
