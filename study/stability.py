"""Stability on stiff and extreme cases: one table, pass/fail per case with the reason.

    python -m study.stability --out out/stability [--quick] [--workers N | --address ADDR | --in-process]

The cases run as one sweep through abd_joint_sim/tools/sweep.py (study/sweeps.py): on every
core by default, on a Ray cluster with --address, serially with --in-process; the tables are
written from the sweep's results.csv (--from-sweep DIR: from a sweep run earlier).

Each case runs one or two phases on a small scene (study/scenes.py):
  forced  — from rest with a joint torque; where the answer is known (fixed hinge, constant
            torque: θ = ½ τ/I t²) the angle must track it, which also catches a wrapped or
            aliased angle;
  unforced — no torque (gravity allowed, it is conservative), the child spinning about the
            hinge or the chain falling: the mechanical energy must never grow.
Criteria checked after every step:
  finite      q, v and the joint angles are finite;
  separation  max joint-anchor separation <= 1% of the smallest body's bounding-box diagonal;
  energy      (unforced) E_n <= E_0 + 1e-9 |E_0| + 1e-12 J for every n (roundoff allowance;
              BDF2 is not monotone step to step, so the bound is the initial energy —
              the largest step-to-step rise is reported as energy_max_rise_rel);
  newton      every step converged, or the step reports it (status/warnings);
  continuity  a reported angle never moves more than newton.max_step_rotation per (sub-)step:
              |Δθ| <= max_step_rotation × substeps, and StepReport.max_step_rotation within it;
  reference   where known, |θ − θ_ref| <= rtol |θ_ref| + α h t + velocity_tol t / 0.6 + 1e-9 rad
              (α h t = twice the BDF1 error ½ α h t of docs/physics.md "Analytic references"; the last term is what the
              Newton tolerance on point velocities allows at the 0.6 m lever arm);
  momentum    (free pairs) |P|, |L| <= 1e-3 τ t + 4 eps Σ m (|p| + size) / h + 1e-12 (the
              Newton tolerance limits it; the middle term is the rounding floor of m v when
              v comes from positions known to eps: it matters for an 8e8 kg body).
Verdicts: `pass` (all criteria hold; warnings the simulator gave, e.g. sub-stepping, are
listed), `fail-loud` (a criterion failed, and the simulator said so: SimulationError, a
StepReport warning or an unconverged status — acceptable), `FAIL-SILENT` (a criterion failed
and the simulator said nothing — a bug). `expect`: 'pass' (must pass) or 'loud' (passing or
failing loudly are both right: the case is beyond what the method resolves at that dt).
Cases that expose a known, still open physics-core issue carry `known` (docs/studies.md
section 3); they are reported but do not set the exit status. Exit status 1 when any other
case fails silently or not as expected.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

try:
    from . import common
except ImportError:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import common  # type: ignore

from abd_joint_sim import SimulationError, World  # noqa: E402,F401

try:
    from . import scenes as S
    from . import sweeps as study_sweeps
except ImportError:
    import scenes as S  # type: ignore
    import sweeps as study_sweeps  # type: ignore

SEP_FRAC = 1e-2
MOMENTUM_RTOL = 1e-3                  # of the angular impulse tau*t (Newton-tolerance limited)
ENERGY_RTOL, ENERGY_ATOL = 1e-9, 1e-12


@dataclass
class Phase:
    kind: str                         # 'forced' | 'unforced'
    scene: dict
    steps: int
    torque: float = 0.0               # constant torque on every actuated joint
    reference: object = None          # t -> theta of joint 0
    ref_rtol: float = 0.05
    ref_slack: object = None          # t -> extra allowed |error| (the integrator's own error)
    momentum: bool = False
    prepare: object = None            # callable(world) run before stepping (state hacks)
    expect_warning: str = ''          # substring some StepReport warning must contain


@dataclass
class Case:
    group: str
    name: str
    phases: list
    expect: str = 'pass'              # 'pass' | 'loud' (a loud failure is the right outcome)
    note: str = ''
    known: str = ''                   # a known physics-core issue this case exposes (docs/studies.md)


@dataclass
class PhaseResult:
    steps_done: int = 0
    violations: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    error: str = ''
    unconverged: int = 0
    substep_steps: int = 0
    max_sep_rel: float = 0.0
    max_energy_rise: float = math.nan
    energy_drop: float = math.nan
    ref_err: float = math.nan
    max_momentum: float = math.nan
    wall: float = 0.0
    backend: str = ''


def run_phase(p: Phase) -> PhaseResult:
    r = PhaseResult()
    w = common.make_world(p.scene)
    r.backend = common.BACKEND
    m = w.model
    for j in w.actuated_joint_names:            # (a torque [N m], or a force [N] on a slider)
        w.set_effort_enabled(j, p.torque != 0.0)
        w.set_effort(j, p.torque)
    if p.prepare:
        p.prepare(w)
    size = float(np.min(m.body_size))
    limit = m.newton.max_step_rotation
    turning = np.array([t == 'revolute' for t in w.joint_types])   # (continuity: angles only)
    E0 = E_prev = w.mechanical_energy() if p.kind == 'unforced' else 0.0
    rise, theta_prev = -math.inf, w.joint_angles()
    errs, moms = [], []
    seen_warning = not p.expect_warning
    free = ~m.body_fixed            # rounding floor of the momentum (see the module docstring)
    mom_floor = 4 * np.finfo(float).eps * float(np.sum(
        m.body_mass[free] * (np.linalg.norm(w.state.q[free, :3], axis=1) + m.body_size[free]))) / m.dt
    t0 = time.perf_counter()
    for k in range(p.steps):
        try:
            rep = w.step()
        except SimulationError as exc:
            r.error = str(exc)
            break
        r.steps_done = k + 1
        r.warnings += rep.warnings
        if p.expect_warning and any(p.expect_warning in x for x in rep.warnings):
            seen_warning = True
        r.unconverged += not rep.converged
        r.substep_steps += rep.substeps > 1
        s = w.state
        theta = w.joint_angles()
        if not (np.all(np.isfinite(s.q)) and np.all(np.isfinite(s.v)) and np.all(np.isfinite(theta))):
            r.violations.append(f'non-finite state at step {k + 1}')
            break
        r.max_sep_rel = max(r.max_sep_rel, rep.max_joint_separation / size)
        jump = float(np.max(np.abs(theta - theta_prev)[turning])) if turning.any() else 0.0
        if jump > limit * rep.substeps * (1 + 1e-9) or rep.max_step_rotation > limit * (1 + 1e-9):
            if not any('continuity' in v for v in r.violations):
                r.violations.append(f'continuity: angle moved {jump:.3g} rad in a step with '
                                    f'{rep.substeps} sub-step(s) (limit {limit:.3g} per sub-step)')
        theta_prev = theta
        if p.kind == 'unforced':
            E = w.mechanical_energy()
            rise = max(rise, E - E_prev)
            if E > E0 + ENERGY_RTOL * abs(E0) + ENERGY_ATOL and not any('energy' in v for v in r.violations):
                r.violations.append(f'energy grew to E0 + {E - E0:.3g} J at step {k + 1} (E0 {E0:.4g} J)')
            E_prev = E
        if p.reference is not None:
            ref = float(p.reference(w.time))
            errs.append(abs(theta[0] - ref) / max(abs(ref), 1e-300))
            slack = p.ref_slack(w.time) if p.ref_slack else 0.0
            if abs(theta[0] - ref) > p.ref_rtol * abs(ref) + slack + 1e-9 and not any('reference' in v for v in r.violations):
                r.violations.append(f'reference: theta {theta[0]:.6g} vs {ref:.6g} at t={w.time:.4g}s')
        if p.momentum:
            P, L = w.momentum()
            mom = max(float(np.linalg.norm(P)), float(np.linalg.norm(L)))
            moms.append(mom)
            if mom > MOMENTUM_RTOL * abs(p.torque) * w.time + mom_floor + 1e-12 and not any('momentum' in v for v in r.violations):
                r.violations.append(f'momentum {mom:.3g} at t={w.time:.4g}s')
    r.wall = time.perf_counter() - t0
    if r.max_sep_rel > SEP_FRAC:
        r.violations.append(f'joint separation {r.max_sep_rel:.3g} x body size > {SEP_FRAC}')
    if r.error:
        r.violations.append('SimulationError')
    if not seen_warning and not r.error:
        r.violations.append(f'expected warning containing {p.expect_warning!r} not reported')
    if p.kind == 'unforced' and r.steps_done:
        scale = max(abs(E0), abs(E_prev), 1e-12)      # E0 = 0 for a chain starting at y = 0
        r.max_energy_rise = rise / scale
        r.energy_drop = (E0 - E_prev) / scale
    r.ref_err = float(max(errs)) if errs else math.nan
    r.max_momentum = max(moms) if moms else math.nan
    return r


def run_case(c: Case) -> dict:
    results = [run_phase(p) for p in c.phases]
    viol = [f'{p.kind}: {v}' for p, r in zip(c.phases, results) for v in r.violations]
    warn = [w for r in results for w in r.warnings]
    err = '; '.join(r.error for r in results if r.error)
    unconv = sum(r.unconverged for r in results)
    loud = bool(err or warn or unconv)
    if not viol:
        verdict = 'pass'
    elif loud:
        verdict = 'fail-loud'
    else:
        verdict = 'FAIL-SILENT'
    said = err or (warn[0] if warn else (f'{unconv} unconverged steps' if unconv else ''))
    reason = '; '.join(viol)
    if verdict == 'fail-loud':
        reason += f' — simulator reported: {said[:200]}'
    notes = []
    if warn:
        kinds = sorted({_warning_kind(w) for w in warn})
        notes.append(f'{len(warn)} warnings ({", ".join(kinds)})')
    if unconv:
        notes.append(f'{unconv} unconverged steps (reported)')
    forced = [r for p, r in zip(c.phases, results) if p.kind == 'forced']
    unforced = [r for p, r in zip(c.phases, results) if p.kind == 'unforced']
    ok_expect = verdict == 'pass' if c.expect == 'pass' else verdict in ('pass', 'fail-loud')
    if c.known:
        notes.append(f'KNOWN ISSUE: {c.known}')
    return {
        'group': c.group, 'case': c.name, 'expect': c.expect, 'verdict': verdict, 'known': c.known or '-',
        'as_expected': ok_expect, 'reason': reason or '-', 'notes': '; '.join(notes + ([c.note] if c.note else [])) or '-',
        'steps': sum(r.steps_done for r in results),
        'substep_steps': sum(r.substep_steps for r in results),
        'max_sep_rel': max(r.max_sep_rel for r in results),
        'ref_rel_err': next((r.ref_err for p, r in zip(c.phases, results) if p.reference is not None), math.nan),
        'energy_max_rise_rel': unforced[0].max_energy_rise if unforced else math.nan,
        'energy_drop_rel': unforced[0].energy_drop if unforced else math.nan,
        'max_momentum': max((r.max_momentum for r in results if r.max_momentum == r.max_momentum), default=math.nan),
        'wall_s': sum(r.wall for r in results),
        'backend': '+'.join(sorted({r.backend for r in results})),
    }


def _warning_kind(w):
    for key, label in (('sub-steps of', 'sub-stepping'), ('near-singular', 'near-singular A'),
                       ('damps rotation', 'rotation damping (integrator)'), ('overloaded', 'joint overloaded'),
                       ('Newton stopped', 'Newton stopped'), ('result kept', 'result kept')):
        if key in w:
            return label
    return w.split(':', 1)[-1][:40]


# -- the cases ----------------------------------------------------------------------------
def _hinge_pair(group, name, steps, spin_steps, tau=100.0, dt=1e-2, ref_rtol=0.05, expect='pass',
                note='', known='', **kw):
    """Forced phase (constant τ from rest, analytic reference) + unforced spin (energy)."""
    geom = {k: kw[k] for k in ('child_box', 'density', 'child_density') if k in kw}
    I, _ = S.hinge_inertia(child_box=geom.get('child_box'),
                           density=geom.get('child_density') or geom.get('density', 1000.0))
    phases = [Phase('forced', S.hinge_scene(dt, tau=tau, **kw), steps, torque=tau,
                    reference=lambda t, a=tau / I: 0.5 * a * t * t, ref_rtol=ref_rtol,
                    ref_slack=lambda t, a=tau / I, v=kw.get('velocity_tol', 0.05): a * dt * t + v * t / 0.6)]
    if spin_steps:
        phases.append(Phase('unforced', S.hinge_scene(dt, tau=0.0, angular_velocity=2.0, **kw), spin_steps))
    return Case(group, name, phases, expect, note, known)


def _singular(eps):
    def prepare(w):
        b = w.body_names.index('arm')
        A = w.state.q[b, 3:12].reshape(3, 3).copy()
        A[2] = math.cos(eps) * A[1] + math.sin(eps) * A[2]      # a3 almost parallel to a2
        w.state.q[b, 3:12] = A.ravel()
        w.state.q_prev[b, 3:12] = A.ravel()
    return prepare


# Open physics-core issues as {tag: description} (docs/studies.md section 3 has the
# reproductions); none at present. The failure modes the matrix probes and the core handles
# (docs/studies.md section 3): Newton's stop (decrement criterion), large per-step rotations
# (predicted-rotation sub-stepping, damping warnings for bdf1 and bdf2), a light parent,
# a degenerate torque axis, and stiff kappa (screw steps, abd_joint_sim/solver/retraction.py).
KNOWN_ISSUES: dict[str, str] = {}


def cases(quick=False):
    q = quick
    out = []
    for k in (1e4, 1e6, 1e8, 1e10, 1e11, 1e13):
        c = _hinge_pair('kappa', f'kappa={k:g} Pa', 50, 50 if q else 200, kappa=k)
        if k < 1e6:                       # a soft body deforms: the rigid answer does not apply
            c.phases[0].reference, c.note = None, 'soft body: rigid reference not applied'
        out.append(c)
    out.append(_hinge_pair('kappa', 'kappa=1e13 Pa, velocity_tol=1e-4', 50, 50 if q else 200, kappa=1e13,
                           velocity_tol=1e-4))
    for g in (1.0, 1e2, 1e4, 1e6, 1e8):
        out.append(_hinge_pair('strength_ratio', f'gamma={g:g}', 50, 50 if q else 200, strength_ratio=g))
    for tau in (1e-6, 1e-3, 1.0, 1e3, 1e6):
        out.append(_hinge_pair('torque', f'tau={tau:g} N m', 100, 0, tau=tau, dt=1e-3,
                               expect='loud' if tau >= 1e6 else 'pass'))
    out.append(_hinge_pair('torque', 'tau=1e+06 N m (bdf2)', 100, 0, tau=1e6, dt=1e-3,
                           integrator='bdf2', expect='loud'))
    for r in (1e-8, 1e-4, 1.0, 1e4, 1e8):
        out.append(Case('mass_ratio', f'm_parent/m_child={r:g}',
                        [Phase('forced', S.free_pair_scene(1e-3, parent_density=1000.0 * r), 50 if q else 200,
                               torque=1.0, momentum=True)],
                        expect='loud' if r < 1e-2 else 'pass'))
    for dt in (1e-5, 1e-4, 1e-3, 1e-2, 0.1):
        out.append(_hinge_pair('dt', f'dt={dt:g} s', 50, 50, dt=dt, expect='loud' if dt >= 0.1 else 'pass'))
    out.append(_hinge_pair('dt', 'dt=0.1 s, velocity_tol=1e-4', 50, 50, dt=0.1, velocity_tol=1e-4,
                           expect='loud'))
    for label, box in (('plate 0.4x0.4x4e-4', [0.4, 0.4, 4e-4]), ('rod 0.4x4e-4x4e-4', [0.4, 4e-4, 4e-4])):
        I, _ = S.hinge_inertia(child_box=box)
        out.append(_hinge_pair('thin', f'{label} (aspect 1e-3)', 50, 50 if q else 200, tau=4.0 * I,
                               child_box=box))
    n = 20 if q else 100
    out.append(Case('chain', f'{n}-link chain under gravity', [
        Phase('unforced', S.chain_scene(n, 1e-2), 30 if q else 200),
        Phase('forced', S.chain_scene(n, 1e-2, gravity=(0, 0, 0), tau=0.01), 20 if q else 50, torque=0.01)]))
    nlong = 2000 if q else 100_000
    out.append(Case('long_run', f'{nlong} steps bdf1 spin', [
        Phase('unforced', S.hinge_scene(1e-3, tau=0.0, angular_velocity=2.0), nlong)]))
    nlong2 = 1000 if q else 20_000
    out.append(Case('long_run', f'{nlong2} steps bdf2 spin', [
        Phase('unforced', S.hinge_scene(1e-3, 'bdf2', tau=0.0, angular_velocity=2.0), nlong2)]))
    I, _ = S.hinge_inertia()
    for integ in ('bdf1', 'bdf2'):
        out.append(Case('step_rotation', f'tau=1e5, dt=1e-2 ({integ}): rotation/step -> pi', [
            Phase('forced', S.hinge_scene(1e-2, integ, tau=1e5), 30, torque=1e5,
                  reference=lambda t: 0.5 * 1e5 / I * t * t, ref_rtol=0.1,
                  ref_slack=lambda t: 1e5 / I * 1e-2 * t, expect_warning='sub-steps')],
            expect='loud', note='must sub-step'))
    out.append(Case('step_rotation', 'tau=1e7, dt=1e-2: beyond 2^4 sub-steps', [
        Phase('forced', S.hinge_scene(1e-2, tau=1e7), 10, torque=1e7,
              reference=lambda t: 0.5 * 1e7 / I * t * t, ref_rtol=0.1,
              ref_slack=lambda t: 1e7 / I * 1e-2 * t)], expect='loud',
        note='cannot be resolved at this dt; must be reported'))
    for integ in ('bdf1', 'bdf2'):      # unforced rigid spin at 0.6 rad per step: theta = w t
        out.append(Case('step_rotation', f'spin 60 rad/s, dt=1e-2 ({integ}): 0.6 rad/step', [
            Phase('unforced', S.hinge_scene(1e-2, integ, tau=0.0, angular_velocity=60.0), 50,
                  reference=lambda t: 60.0 * t, ref_rtol=0.1)], expect='loud',
            ))
    # prismatic joints (UID 20 + 667 + 669): d = ½ f/m t² on a fixed base, stiff bodies, large
    # forces, a limit hit at speed (unforced: the energy must not grow)
    m_arm = 1000.0 * 0.4 ** 3
    for k in (1e8, 1e11):
        out.append(Case('prismatic', f'slider, kappa={k:g} Pa', [
            Phase('forced', S.slider_scene(1e-2, kappa=k, force=10.0), 50, torque=10.0,
                  reference=lambda t: 0.5 * 10.0 / m_arm * t * t, ref_rtol=0.02,
                  ref_slack=lambda t: 10.0 / m_arm * 1e-2 * t)]))
    for f in (1e3, 1e6):
        out.append(Case('prismatic', f'slider, f={f:g} N, dt=1e-3', [
            Phase('forced', S.slider_scene(1e-3, force=f), 100, torque=f,
                  reference=lambda t, f=f: 0.5 * f / m_arm * t * t, ref_rtol=0.02,
                  ref_slack=lambda t, f=f: f / m_arm * 1e-3 * t)]))
    for integ in ('bdf1', 'bdf2'):
        out.append(Case('prismatic', f'slider hits its limit at 2 m/s ({integ})', [
            Phase('unforced', S.slider_scene(1e-3, integ, force=0.0, velocity=2.0, limit=(-0.05, 0.05)),
                  200 if q else 1000)]))
    for eps in (1e-7, 0.0):
        out.append(Case('singular_A', f'a3 = cos(e) a2 + sin(e) a3, e={eps:g}', [
            Phase('forced', S.hinge_scene(1e-2, tau=100.0), 20, torque=100.0, prepare=_singular(eps),
                  expect_warning='near-singular')]))
    return out


def _command(argv):
    """The command line a summary names: argv, or a str naming the whole command."""
    return argv if isinstance(argv, str) else ' '.join(['python -m study.stability'] + list(argv))


# -- the study as a sweep (study/sweeps.py) ---------------------------------------------
COLUMNS = ('group', 'case', 'expect', 'verdict', 'known', 'as_expected', 'reason', 'notes', 'steps',
           'substep_steps', 'max_sep_rel', 'ref_rel_err', 'energy_max_rise_rel', 'energy_drop_rel',
           'max_momentum', 'wall_s', 'backend')
SWEEP_TYPES = {'name': str, 'quick': bool, 'group': str, 'expect': str, 'verdict': str, 'known': str,
               'as_expected': bool, 'reason': str, 'notes': str, 'backend': str, 'steps': int,
               'substep_steps': int}


@lru_cache(maxsize=2)
def _by_name(quick):
    return {c.name: c for c in cases(quick)}


def sweep_cases(quick=False, groups=None):
    """The study's cases as sweep cases: axes study, index (the study's order), quick, name;
    `cost` estimates the case's run time [s] (~45 us per step and body) so the longest go first."""
    out = []
    for c in cases(quick):
        if groups and c.group not in groups:
            continue
        cost = 4.5e-5 * sum(p.steps * len(p.scene['bodies']) for p in c.phases)
        out.append({'study': 'stability', 'index': len(out), 'quick': bool(quick), 'name': c.name,
                    'cost': cost})
    return out


def sweep_check(values):
    if values.get('name') not in _by_name(bool(values.get('quick'))):
        raise ValueError(f'stability: no case named {values.get("name")!r}')


def sweep_case(values):
    """One case in a sweep worker: run_case's row, its name in the axis `name` and its
    stepping time as `study_wall_s` (`case` and `wall_s` are the sweep's own columns)."""
    row = run_case(_by_name(bool(values['quick']))[values['name']])
    del row['case']
    row['study_wall_s'] = row.pop('wall_s')
    return row


def from_sweep_row(r):
    """A study row (run_case's columns and order) from a typed sweep row."""
    r = dict(r, case=r['name'], wall_s=r['study_wall_s'])
    return {c: r[c] for c in COLUMNS}


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--out', default='out/stability', type=Path)
    ap.add_argument('--quick', action='store_true')
    ap.add_argument('--group', nargs='*', default=None, help='only these groups')
    study_sweeps.add_arguments(ap)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    status, rows = study_sweeps.run(['stability'], args, {'stability': dict(quick=args.quick, groups=args.group)})
    if status > 1 or not rows.get('stability'):
        return status or 1
    return analyse(rows['stability'], args, argv, t0, status)


def analyse(rows, args, argv, t0, status=0, log=print):
    """The study's outputs (stability.csv, summary.md) from its rows; the exit status."""
    for r in rows:
        log(f'{r["group"]:14s} {r["case"]:44s} {r["verdict"]:11s} sep/size={r["max_sep_rel"]:.1e} '
            f'ref={r["ref_rel_err"]:.1e} dE={r["energy_max_rise_rel"]:.1e} {r["wall_s"]:.1f}s  {r["reason"][:90]}')
    args.out.mkdir(parents=True, exist_ok=True)
    cols = list(rows[0])
    common.write_csv(args.out / 'stability.csv', rows, cols)
    elapsed = time.perf_counter() - t0
    (args.out / 'summary.md').write_text(summary_md(rows, args.quick, elapsed, argv))
    bad = unexpected(rows)
    counts = {v: sum(r['verdict'] == v for r in rows) for v in ('pass', 'fail-loud', 'FAIL-SILENT')}
    print(f'\n{len(rows)} cases: {counts}; wrote {args.out}/stability.csv, summary.md in {elapsed:.0f} s')
    if bad:
        print('UNEXPECTED:\n  ' + '\n  '.join(f'{r["case"]}: {r["verdict"]}: {r["reason"]}' for r in bad),
              file=sys.stderr)
        return 1
    return status


def unexpected(rows):
    """Cases that fail silently or not as expected, other than the known core issues."""
    return [r for r in rows if (r['verdict'] == 'FAIL-SILENT' or not r['as_expected']) and r['known'] == '-']


def run_all(quick=False, groups=None, log=print):
    rows = []
    for c in cases(quick):
        if groups and c.group not in groups:
            continue
        r = run_case(c)
        rows.append(r)
        log(f'{r["group"]:14s} {r["case"]:44s} {r["verdict"]:11s} sep/size={r["max_sep_rel"]:.1e} '
            f'ref={r["ref_rel_err"]:.1e} dE={r["energy_max_rise_rel"]:.1e} {r["wall_s"]:.1f}s  {r["reason"][:90]}')
    return rows


def summary_md(rows, quick, elapsed, argv):
    counts = {v: sum(r['verdict'] == v for r in rows) for v in ('pass', 'fail-loud', 'FAIL-SILENT')}
    lines = ['# Stability on stiff and extreme cases', '',
             f'Command: `{_command(argv)}` ({"quick" if quick else "full"} mode, '
             f'{elapsed:.0f} s). {common.machine()}. '
             f'{common.backend_note()}', '',
             f'{len(rows)} cases: {counts["pass"]} pass, {counts["fail-loud"]} fail loudly (reported by the '
             f'simulator), {counts["FAIL-SILENT"]} fail silently.', '',
             'Criteria (see study/stability.py): finite state; joint separation <= 1% of the smallest body '
             'diagonal (`max_sep_rel`); unforced energy never grows above E0 (allowance 1e-9 |E0|; '
             '`energy_max_rise_rel` is the largest step-to-step change over |E0|, negative = always falling; '
             '`energy_drop_rel` the total loss); Newton converged or reported; angle continuous (at most '
             'max_step_rotation per sub-step); angle within tolerance of the analytic answer where known '
             '(`ref_rel_err`); momentum of free pairs.', '',
             common.md_table(rows, ['group', 'case', 'expect', 'verdict', 'steps', 'substep_steps', 'max_sep_rel',
                                    'ref_rel_err', 'energy_max_rise_rel', 'energy_drop_rel', 'max_momentum',
                                    'wall_s']),
             '', '## Reasons and notes', '',
             common.md_table(rows, ['case', 'expect', 'verdict', 'reason', 'notes']), '',
             '## Known open core issues (tagged cases do not set the exit status)', '']
    for tag, text in KNOWN_ISSUES.items():
        hit = [r['case'] for r in rows if r['known'] == text]
        lines.append(f'- {tag}: {text}. Cases: {", ".join(hit) if hit else "none in this run"}.')
    if not KNOWN_ISSUES:
        lines.append('- none.')
    lines += ['', f'Unexpected results (exit status): {len(unexpected(rows))}.', '']
    return '\n'.join(lines)


if __name__ == '__main__':
    sys.exit(main())
