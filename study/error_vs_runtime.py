"""Error against run time: sweep dt x integrator x Newton tolerance on scenes with known answers.

    python -m study.error_vs_runtime --out out/error_study [--quick] [--img-dir DIR]
        [--workers N | --address ADDR | --in-process]

Every point (ours and MuJoCo's) is a case of one sweep run through
abd_joint_sim/tools/sweep.py (study/sweeps.py); the tables and plots are made from the
sweep's results.csv (--from-sweep DIR: from a sweep run earlier).

Scenes (study/scenes.py): fixed hinge with constant torque (closed form), free pair with
internal torque (closed form for the relative angle; momentum must stay zero), pendulum
under gravity with a sinusoidal torque (DOP853 reference at rtol 1e-12). With MuJoCo
installed (optional), the hinge and the pendulum also run in MuJoCo in the same run
(study/mujoco_peer.py) and the summary gives the run time at equal error, ours/MuJoCo;
without it the study says so and runs the rest. Option: --no-mujoco.
For every point: wall time per simulated second (the step calls only), angle error (max
over the horizon and final), max joint-anchor separation, Newton iterations per step,
max |momentum| (free pair). Writes results.csv, summary.md and, with matplotlib, PNGs.
Results are checked against the references before anything is reported: the exit status
is 1 when a point is clearly wrong (error not falling, wrong order, momentum not
conserved, solver failure), 0 otherwise.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

try:
    from . import common
except ImportError:                      # run as a script
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import common  # type: ignore

from abd_joint_sim import SimulationError  # noqa: E402

try:
    from . import scenes as S
    from . import mujoco_peer as M
    from . import sweeps as study_sweeps
except ImportError:
    import scenes as S  # type: ignore
    import mujoco_peer as M  # type: ignore
    import sweeps as study_sweeps  # type: ignore

# mj_dts: MuJoCo's first-order integrators cost ~3 us per step, so it also gets smaller steps
# (the equal-error ratios need its envelope to reach 1e-5)
FULL = dict(dts=(1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 2e-4, 1e-4), tols=(0.05, 0.005), horizon=0.3,
            fit_min_dt=5e-4, mj_extra_dts=(5e-5, 2e-5, 1e-5))
QUICK = dict(dts=(1e-2, 5e-3, 2e-3, 1e-3), tols=(0.05, 0.005), horizon=0.25, fit_min_dt=1e-3,
             mj_extra_dts=(1e-4,))
INTEGRATORS = ('bdf1', 'bdf2')
EXPECTED_ORDER = {'bdf1': (0.8, 1.3), 'bdf2': (1.7, 2.6)}
COLUMNS = ('engine', 'backend', 'scene', 'integrator', 'velocity_tol', 'tau_sample', 'dt', 'steps', 'sim_time',
           'wall_s', 'wall_per_sim_s', 'ms_per_step', 'err_max', 'err_final', 'theta_final',
           'max_sep', 'newton_per_step', 'line_search_per_step', 'unconverged_steps',
           'substep_steps', 'max_linear_momentum', 'max_angular_momentum', 'warnings', 'error')


def run_point(case, dt, integrator, velocity_tol, horizon, tau_sample='end'):
    """Simulate one point; returns a row dict (see COLUMNS)."""
    w = common.make_world(case.scene(dt, integrator, velocity_tol))
    joint = w.actuated_joint_names[0]       # the hinge's torque [N m], or the slider's force [N]
    w.set_effort_enabled(joint, True)
    n = int(round(horizon / dt))
    times, angles = np.empty(n), np.empty(n)
    its = ls = unconv = subs = 0
    max_sep = max_p = max_l = 0.0
    warnings, error = [], ''
    offset = dt if tau_sample == 'end' else 0.0
    wall = 0.0
    k = 0
    try:
        for k in range(n):
            t0 = time.perf_counter()
            w.set_effort(joint, case.torque(w.time + offset))
            rep = w.step()
            wall += time.perf_counter() - t0
            times[k], angles[k] = w.time, w.joint_angles()[0]
            its += rep.newton_iterations
            ls += rep.line_search_iterations
            unconv += not rep.converged
            subs += rep.substeps > 1
            max_sep = max(max_sep, rep.max_joint_separation)
            if rep.warnings:
                warnings += rep.warnings
            if case.name == 'free_pair':
                P, L = w.momentum()
                max_p, max_l = max(max_p, float(np.linalg.norm(P))), max(max_l, float(np.linalg.norm(L)))
    except SimulationError as exc:
        error = str(exc)
        times, angles = times[:k], angles[:k]
    ref = case.reference(horizon)(times)
    err = np.abs(angles - ref)
    ok = len(err) and np.all(np.isfinite(err))
    return {
        'engine': 'abd', 'backend': common.BACKEND,
        'scene': case.name, 'integrator': integrator, 'velocity_tol': velocity_tol,
        'tau_sample': tau_sample, 'dt': dt, 'steps': len(times),
        'sim_time': float(times[-1]) if len(times) else 0.0, 'wall_s': wall,
        'wall_per_sim_s': wall / (n * dt), 'ms_per_step': 1e3 * wall / max(n, 1),
        'err_max': float(err.max()) if ok else math.nan, 'err_final': float(err[-1]) if ok else math.nan,
        'theta_final': float(angles[-1]) if len(angles) else math.nan, 'max_sep': max_sep,
        'newton_per_step': its / max(n, 1), 'line_search_per_step': ls / max(n, 1),
        'unconverged_steps': unconv, 'substep_steps': subs,
        'max_linear_momentum': max_p, 'max_angular_momentum': max_l,
        'warnings': len(warnings), 'error': error,
    }


def fit_order(dts, errs):
    """Least-squares slope of log(err) against log(dt)."""
    x, y = np.log(np.asarray(dts, float)), np.log(np.asarray(errs, float))
    good = np.isfinite(y)
    if good.sum() < 2:
        return math.nan
    return float(np.polyfit(x[good], y[good], 1)[0])


def groups(rows):
    out = {}
    for r in rows:
        out.setdefault((r['scene'], r['integrator'], r['velocity_tol'], r['tau_sample']), []).append(r)
    for v in out.values():
        v.sort(key=lambda r: -r['dt'])
    return out


def orders(rows, fit_min_dt):
    """One row per (scene, integrator, tol, tau_sample): fitted order over dt >= fit_min_dt
    (err_max and err_final) and the local orders between neighbouring dts."""
    res = []
    for (scene, integ, tol, samp), g in groups(rows).items():
        fit = [r for r in g if r['dt'] >= fit_min_dt * (1 - 1e-9)]
        local = []
        for a, b in zip(g, g[1:]):
            local.append(math.log(a['err_max'] / b['err_max']) / math.log(a['dt'] / b['dt'])
                         if a['err_max'] > 0 and b['err_max'] > 0 else math.nan)
        res.append({'scene': scene, 'integrator': integ, 'velocity_tol': tol, 'tau_sample': samp,
                    'fit_range': f'{min(r["dt"] for r in fit):g} .. {max(r["dt"] for r in fit):g}',
                    'order_err_max': fit_order([r['dt'] for r in fit], [r['err_max'] for r in fit]),
                    'order_err_final': fit_order([r['dt'] for r in fit], [r['err_final'] for r in fit]),
                    'local_orders': ' '.join(f'{x:.2f}' for x in local)})
    return res


def pareto(rows):
    """Per scene, the points no other point beats in both wall time and err_max."""
    out = []
    for scene in dict.fromkeys(r['scene'] for r in rows):
        pts = sorted((r for r in rows if r['scene'] == scene and math.isfinite(r['err_max'])),
                     key=lambda r: (r['wall_per_sim_s'], r['err_max']))
        best = math.inf
        for r in pts:
            if r['err_max'] < best:
                out.append(r)
                best = r['err_max']
    return out


def cost_at_error(rows, target):
    """Wall time per simulated second needed to reach err_max <= target, interpolated in
    log-log along the lower envelope of `rows`; nan if never reached."""
    pts = sorted((r['wall_per_sim_s'], r['err_max']) for r in rows if math.isfinite(r['err_max']))
    env = []                              # Pareto envelope: cost rising, error falling
    for c, e in pts:
        if e > 0 and (not env or e < env[-1][1]):
            env.append((c, e))
    if not env or target < env[-1][1]:
        return math.nan
    if target >= env[0][1]:
        return env[0][0]
    for (c0, e0), (c1, e1) in zip(env, env[1:]):
        if e1 <= target <= e0:
            f = (math.log(target) - math.log(e0)) / (math.log(e1) - math.log(e0))
            return math.exp(math.log(c0) + f * (math.log(c1) - math.log(c0)))
    return math.nan


def equal_error_ratios(rows):
    """Cost of bdf1 / cost of bdf2 (tau sampled at the step end) at a few error levels."""
    out = []
    for scene in dict.fromkeys(r['scene'] for r in rows):
        sel = {i: [r for r in rows if r['scene'] == scene and r['integrator'] == i and
                   r['tau_sample'] == 'end'] for i in INTEGRATORS}
        errs = [r['err_max'] for r in sel['bdf1'] + sel['bdf2'] if math.isfinite(r['err_max'])]
        if not errs:
            continue
        for target in (1e-2, 1e-3, 1e-4):
            c1, c2 = cost_at_error(sel['bdf1'], target), cost_at_error(sel['bdf2'], target)
            out.append({'scene': scene, 'err_target': target, 'bdf1_wall_per_sim_s': c1,
                        'bdf2_wall_per_sim_s': c2,
                        'ratio_bdf1_over_bdf2': c1 / c2 if c1 == c1 and c2 == c2 else math.nan})
    return out


def check(rows, order_rows, cfg):
    """Sanity checks against the references; a list of problems (empty = fine)."""
    problems = []
    for r in rows:
        if r['error']:
            problems.append(f'{r["scene"]} {r["integrator"]} dt={r["dt"]:g}: SimulationError: {r["error"]}')
        if not math.isfinite(r['err_max']):
            problems.append(f'{r["scene"]} {r["integrator"]} dt={r["dt"]:g}: non-finite angle error')
        if r['unconverged_steps']:
            problems.append(f'{r["scene"]} {r["integrator"]} dt={r["dt"]:g} tol={r["velocity_tol"]}: '
                            f'{r["unconverged_steps"]} unconverged steps')
        if r['scene'] == 'free_pair':
            # the torques are exactly antisymmetric and the joint is internal: only the Newton
            # residual can create momentum; allow 1e-6 of the angular impulse tau*T
            lim = 1e-6 * S.CASES['free_pair'].tau * cfg['horizon']
            if r['max_angular_momentum'] > lim or r['max_linear_momentum'] > lim:
                problems.append(f'free_pair {r["integrator"]} dt={r["dt"]:g}: momentum not conserved '
                                f'(|P| {r["max_linear_momentum"]:.2e}, |L| {r["max_angular_momentum"]:.2e})')
    for g in groups(rows).values():
        small = g[-1]
        scale = max(abs(small['theta_final']), 1e-3)
        if small['err_max'] > 2e-2 * scale:
            problems.append(f'{small["scene"]} {small["integrator"]} tol={small["velocity_tol"]}: error '
                            f'{small["err_max"]:.2e} at dt={small["dt"]:g} is > 2% of |theta| {scale:.3g}')
    tight = min(cfg['tols'])
    for o in order_rows:            # looser tolerances are reported, not judged: their error
        if o['tau_sample'] != 'end' or o['velocity_tol'] != tight:   # can be Newton-limited
            continue
        lo, hi = EXPECTED_ORDER[o['integrator']]
        if not lo <= o['order_err_max'] <= hi:
            problems.append(f'{o["scene"]} {o["integrator"]} tol={o["velocity_tol"]}: fitted order '
                            f'{o["order_err_max"]:.2f} outside [{lo}, {hi}]')
    return problems


def sweep(quick=False, cases=None, integrators=INTEGRATORS, log=print, tols=None):
    cfg = dict(QUICK if quick else FULL)
    if tols:
        cfg['tols'] = tuple(tols)
    rows = []
    names = cases or list(S.CASES)
    plan = [(n, i, tol, 'end') for n in names for i in integrators for tol in cfg['tols']]
    if 'pendulum_sine' in names:        # the zero-order-hold sampling of the torque, for contrast
        plan += [('pendulum_sine', i, min(cfg['tols']), 'start') for i in integrators]
    for name, integ, tol, samp in plan:
        for dt in cfg['dts']:
            r = run_point(S.CASES[name], dt, integ, tol, cfg['horizon'], samp)
            rows.append(r)
            log(f'{name:14s} {integ} tol={tol:<6g} tau@{samp:5s} dt={dt:<7g} err_max={r["err_max"]:.3e} '
                f'final={r["err_final"]:.3e} sep={r["max_sep"]:.1e} newton/step={r["newton_per_step"]:.2f} '
                f'{r["ms_per_step"]:.2f} ms/step')
    return rows, cfg


MJ_STYLE = {'mj_euler': ('C2', '^'), 'mj_implicitfast': ('C4', 'v'), 'mj_rk4': ('C1', 'D')}
EXACT = 1e-12               # MuJoCo RK4 is exact on the constant torque (~1e-16)


def plots(rows, img_dir, prefix='', mj_rows=()):
    plt = common.pyplot()
    if plt is None:
        return []
    img_dir.mkdir(parents=True, exist_ok=True)
    scenes_ = list(dict.fromkeys(r['scene'] for r in rows))
    files = []
    style = {('bdf1', 'end'): ('C0', 'o'), ('bdf2', 'end'): ('C3', 's'),
             ('bdf1', 'start'): ('C0', 'x'), ('bdf2', 'start'): ('C3', 'x')}
    # The two tolerance settings drawn apart: the loose one as a wide pale band with open
    # markers, the tight one as a thin line with filled markers on top (where Newton's
    # error is below the time-step error the two coincide, and the band shows both).
    tols = sorted({r['velocity_tol'] for r in rows}, reverse=True)
    loose = tols[0] if len(tols) > 1 else None
    mj_rows = list(mj_rows)
    for kind in ('dt', 'wall'):
        fig, axes = plt.subplots(1, len(scenes_), figsize=(4.6 * len(scenes_) + 2.6, 4.4),
                                 squeeze=False, layout='constrained')
        for ax, scene in zip(axes[0], scenes_):
            for (s, integ, tol, samp), g in groups(rows).items():
                if s != scene:
                    continue
                c, mk = style[(integ, samp)]
                x = [r['dt'] if kind == 'dt' else r['wall_per_sim_s'] for r in g]
                lab = f'ours {integ}, velocity_tol {tol:g}' + (', tau at t_n' if samp == 'start' else '')
                if tol == loose:
                    ax.loglog(x, [r['err_max'] for r in g], '-', color=c, marker=mk, ms=8,
                              mfc='white', lw=5, alpha=0.3, label=lab, zorder=2)
                else:
                    ax.loglog(x, [r['err_max'] for r in g], '-', color=c, marker=mk, ms=4,
                              lw=1.3, label=lab, alpha=0.95 if samp == 'end' else 0.5, zorder=3)
            for (s, integ, tol, samp), g in groups(mj_rows).items():
                if s != scene:
                    continue
                c, mk = MJ_STYLE[integ]
                x = [r['dt'] if kind == 'dt' else r['wall_per_sim_s'] for r in g]
                y = [r['err_max'] for r in g]
                label = f'MuJoCo {integ[3:]}'
                if max(y) < EXACT:         # exact to rounding: drawn at the bottom of the panel
                    bottom = min(r['err_max'] for r in rows + mj_rows
                                 if r['scene'] == scene and r['err_max'] >= EXACT) / 3
                    label += f' ({scene}: exact, err <= {max(y):.0e}, drawn at {bottom:.0e})'
                    y = [bottom] * len(y)
                ax.loglog(x, y, '-.', color=c, marker=mk, ms=5, mfc='none', label=label)
            if kind == 'dt':
                g0 = [r for r in rows if r['scene'] == scene]
                dts = np.array(sorted({r['dt'] for r in g0}))
                e1 = max(r['err_max'] for r in g0 if r['dt'] == dts[-1])
                ax.loglog(dts, e1 * (dts / dts[-1]), 'k:', lw=0.8, label='slope 1')
                ax.loglog(dts, 0.3 * e1 * (dts / dts[-1]) ** 2, 'k--', lw=0.8, label='slope 2')
                ax.set_xlabel('dt [s]')
            else:
                for r in pareto([r for r in rows if r['scene'] == scene]):
                    ax.plot(r['wall_per_sim_s'], r['err_max'], 'o', mfc='none', mec='k', ms=11,
                            label='our Pareto front')
                ax.set_xlabel('wall time per simulated second [s]')
            sliding = scene.startswith('slider')      # a prismatic joint: its distance d
            ax.set_ylabel('max |d - d_ref| [m]' if sliding else 'max |theta - theta_ref| [rad]')
            ax.set_title(scene)
            ax.grid(True, which='both', alpha=0.3)
        # one legend for all panels, beside them: every entry once, none over the data
        handles = {}
        for ax in axes[0]:
            for h, lab in zip(*ax.get_legend_handles_labels()):
                handles.setdefault(lab, h)
        fig.legend(list(handles.values()), list(handles.keys()), loc='outside right center',
                   fontsize=8)
        path = img_dir / f'{prefix}error_vs_{kind}.png'
        fig.savefig(path, dpi=90)
        plt.close(fig)
        files.append(path)
    return files


MJ_TARGETS = (1e-2, 1e-3, 1e-4, 1e-5)


def ours_vs_mujoco(rows, mj_rows):
    """Run time at equal error, ours (best of bdf1/bdf2 and both tolerances, tau@end, the
    compiled step) over each MuJoCo integrator; log-log interpolation on each envelope."""
    out = []
    for scene in dict.fromkeys(r['scene'] for r in mj_rows):
        ours = [r for r in rows if r['scene'] == scene and r['tau_sample'] == 'end']
        for target in MJ_TARGETS:
            c0 = cost_at_error(ours, target)
            row = {'scene': scene, 'err_target': target, 'ours_wall_per_sim_s': c0}
            for integ in MJ_STYLE:
                c = cost_at_error([r for r in mj_rows if r['scene'] == scene and r['integrator'] == integ], target)
                row[f'{integ}_wall_per_sim_s'] = c
                row[f'ratio_ours_over_{integ}'] = c0 / c if c0 == c0 and c == c else math.nan
            out.append(row)
    return out


def summary_md(rows, order_rows, par, ratios, cfg, problems, pngs, quick, mujoco_note, elapsed, argv,
               mj_rows=(), mj_orders=(), mj_ratios=()):
    lines = ['# Error against run time', '',
             f'Command: `{_command(argv)}`'
             f' ({"quick" if quick else "full"} mode, {elapsed:.0f} s). {common.machine()}. '
             f'{common.backend_note()}', '',
             f'Horizon {cfg["horizon"]} s; dt in {", ".join(f"{d:g}" for d in cfg["dts"])}; Newton '
             f'velocity_tol in {", ".join(f"{t:g}" for t in cfg["tols"])} m/s. Torque sampled at the '
             'step end t_n + h (`tau@end`); `tau@start` is the zero-order hold tau(t_n). Wall time '
             'counts the `set_torque` + `step` calls only.', '', '## Scenes', '']
    for c in S.CASES.values():
        if any(r['scene'] == c.name for r in rows):
            lines.append(f'- `{c.name}`: {c.description}')
    lines += ['', '## Checks against the references', '']
    lines += ([f'- FAILED: {p}' for p in problems] if problems else
              ['All points passed: finite, converged, error < 2% of |theta| at the smallest dt, '
               'free-pair momentum < 1e-6 tau T, and the fitted orders at the tightest Newton '
               f'tolerance ({min(cfg["tols"]):g}) within {EXPECTED_ORDER}. Orders at looser '
               'tolerances are reported but not judged: there the Newton stopping error can '
               'dominate the truncation error at large dt.'])
    lines += ['', f'## Measured convergence order (fit of log err_max on log dt, dt >= {cfg["fit_min_dt"]:g})',
              '', common.md_table(list(order_rows) + list(mj_orders),
                                  ['scene', 'integrator', 'velocity_tol', 'tau_sample', 'fit_range',
                                   'order_err_max', 'order_err_final', 'local_orders']),
              '', '## Run time at equal error (bdf1 / bdf2, log-log interpolation)', '',
              common.md_table(ratios, ['scene', 'err_target', 'bdf1_wall_per_sim_s', 'bdf2_wall_per_sim_s',
                                       'ratio_bdf1_over_bdf2']),
              '', '## MuJoCo side by side', '', mujoco_note, '']
    if mj_ratios:
        cols = ['scene', 'err_target', 'ours_wall_per_sim_s'] + \
            [c for i in MJ_STYLE for c in (f'{i}_wall_per_sim_s', f'ratio_ours_over_{i}')]
        lines += ['Run time at equal error, ours (best point of bdf1/bdf2, any tolerance) over MuJoCo '
                  '(wall seconds per simulated second, log-log interpolation along each envelope; '
                  'nan: the target is not reached in the dt range; a target looser than the cheapest '
                  'point costs that point):', '',
                  common.md_table(mj_ratios, cols), '']
    lines += ['## Pareto front (err_max vs wall time per simulated second)', '',
              common.md_table(par, ['scene', 'integrator', 'velocity_tol', 'tau_sample', 'dt', 'wall_per_sim_s',
                                    'err_max', 'newton_per_step']),
              '', '## All points', '',
              common.md_table(list(rows) + list(mj_rows),
                              ['engine', 'scene', 'integrator', 'velocity_tol', 'tau_sample', 'dt', 'wall_per_sim_s',
                               'ms_per_step', 'err_max', 'err_final', 'max_sep', 'newton_per_step',
                               'max_angular_momentum', 'unconverged_steps']),
              '', '## Plots', '']
    lines += [f'![{p.stem}]({p.name if p.parent == Path(".") else p})' for p in pngs] or \
             ['Plots skipped: matplotlib is not installed (`pip install -r requirements-study.txt`).']
    lines += ['']
    return '\n'.join(lines)


def _command(argv):
    """The command line a summary names: argv, or a str naming the whole command."""
    return argv if isinstance(argv, str) else ' '.join(['python -m study.error_vs_runtime'] + list(argv))


# -- the study as a sweep (study/sweeps.py) ---------------------------------------------
AXES = ('engine', 'scene', 'integrator', 'velocity_tol', 'tau_sample', 'dt')
SWEEP_TYPES = {'engine': str, 'backend': str, 'scene': str, 'integrator': str, 'tau_sample': str,
               'error': str, 'steps': int, 'unconverged_steps': int, 'substep_steps': int, 'warnings': int}


def sweep_cases(quick=False, scenes=None, tols=None, mujoco_scenes=()):
    """The study's points as sweep cases (axes study, index, engine, scene, integrator,
    velocity_tol, tau_sample, dt, horizon), ours in sweep()'s order, then MuJoCo's in
    mujoco_peer.sweep()'s; `cost` estimates each point's run time [s]."""
    cfg = dict(QUICK if quick else FULL)
    if tols:
        cfg['tols'] = tuple(tols)
    names = scenes or list(S.CASES)
    plan = [(n, i, tol, 'end') for n in names for i in INTEGRATORS for tol in cfg['tols']]
    if 'pendulum_sine' in names:
        plan += [('pendulum_sine', i, min(cfg['tols']), 'start') for i in INTEGRATORS]
    out = []

    def add(engine, name, integ, tol, samp, dt, cost):
        out.append({'study': 'error_vs_runtime', 'index': len(out), 'engine': engine, 'scene': name,
                    'integrator': integ, 'velocity_tol': tol, 'tau_sample': samp, 'dt': dt,
                    'horizon': cfg['horizon'], 'cost': cost})

    for name, integ, tol, samp in plan:
        for dt in cfg['dts']:
            add('abd', name, integ, tol, samp, dt, 4.5e-5 * cfg['horizon'] / dt)
    for name in mujoco_scenes:                   # median of 3 runs at ~4 us per step
        for integ in M.INTEGRATORS:
            for dt in tuple(cfg['dts']) + tuple(cfg['mj_extra_dts']):
                add('mujoco', name, integ, '-', 'mid', dt, 3 * 4e-6 * cfg['horizon'] / dt)
    return out


def sweep_check(values):
    if values.get('scene') not in S.CASES:
        raise ValueError(f'error_vs_runtime: no scene {values.get("scene")!r}')
    if values.get('integrator') not in INTEGRATORS + tuple(M.INTEGRATORS):
        raise ValueError(f'error_vs_runtime: no integrator {values.get("integrator")!r}')


def sweep_case(values):
    """One point in a sweep worker: run_point's (or MuJoCo's) row without the axes, its
    stepping time as `study_wall_s` (`wall_s` is the sweep's own column)."""
    case = S.CASES[values['scene']]
    if values['engine'] == 'mujoco':
        row = M.run_point(case, values['dt'], values['integrator'], values['horizon'])
    else:
        row = run_point(case, values['dt'], values['integrator'], values['velocity_tol'],
                        values['horizon'], values['tau_sample'])
    row['study_wall_s'] = row.pop('wall_s')
    return {k: v for k, v in row.items() if k not in AXES}


def from_sweep_row(r):
    """A study row (COLUMNS, in order) from a typed sweep row."""
    r = dict(r, wall_s=r['study_wall_s'])
    return {c: r[c] for c in COLUMNS}


def log_row(r, log=print):
    if r['engine'] == 'abd':
        log(f'{r["scene"]:14s} {r["integrator"]} tol={r["velocity_tol"]:<6g} tau@{r["tau_sample"]:5s} '
            f'dt={r["dt"]:<7g} err_max={r["err_max"]:.3e} final={r["err_final"]:.3e} sep={r["max_sep"]:.1e} '
            f'newton/step={r["newton_per_step"]:.2f} {r["ms_per_step"]:.2f} ms/step')
    else:
        log(f'{r["scene"]:14s} {r["integrator"]:15s} tau@mid  dt={r["dt"]:<7g} err_max={r["err_max"]:.3e} '
            f'final={r["err_final"]:.3e} {r["ms_per_step"] * 1e3:.1f} us/step')


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--out', default='out/error_study', type=Path)
    ap.add_argument('--img-dir', type=Path, default=None, help='where the PNGs go (default: --out)')
    ap.add_argument('--quick', action='store_true')
    ap.add_argument('--scenes', nargs='*', default=None, choices=list(S.CASES))
    ap.add_argument('--no-mujoco', action='store_true', help='skip the MuJoCo side-by-side run')
    ap.add_argument('--replot', action='store_true',
                    help='no run: redraw the PNGs from OUT/results.csv (a committed study)')
    study_sweeps.add_arguments(ap)
    args = ap.parse_args(argv)
    if args.replot:
        return replot(args.out, args.img_dir or args.out)
    t0 = time.perf_counter()
    mj_scenes, mujoco_note = mujoco_plan(args.scenes or list(S.CASES), args)
    status, rows = study_sweeps.run(['error_vs_runtime'], args, {'error_vs_runtime': options(args, mj_scenes)})
    if status > 1 or not rows.get('error_vs_runtime'):
        return status or 1
    return analyse(rows['error_vs_runtime'], args, argv, t0, mujoco_note, status)


def options(args, mj_scenes):
    """What sweep_cases takes, from the command line."""
    return dict(quick=args.quick, scenes=args.scenes, mujoco_scenes=mj_scenes)


def analyse(all_rows, args, argv, t0, mujoco_note, status=0, log=print):
    """The study's outputs (results.csv, orders.csv, mujoco_equal_error.csv, summary.md, the
    PNGs) from its rows (ours and MuJoCo's); the exit status."""
    for r in all_rows:
        log_row(r, log)
    cfg = dict(QUICK if args.quick else FULL)
    rows = [r for r in all_rows if r['engine'] == 'abd']
    mj_rows = [r for r in all_rows if r['engine'] != 'abd']
    if not mj_rows and 'ran' in mujoco_note:
        mujoco_note = 'MuJoCo: no MuJoCo point in the sweep\'s results.'
    order_rows = orders(rows, cfg['fit_min_dt'])
    problems = check(rows, order_rows, cfg)
    par, ratios = pareto(rows), equal_error_ratios(rows)
    mj_orders = orders(mj_rows, cfg['fit_min_dt']) if mj_rows else []
    mj_ratios = ours_vs_mujoco(rows, mj_rows) if mj_rows else []
    args.out.mkdir(parents=True, exist_ok=True)
    common.write_csv(args.out / 'results.csv', rows + mj_rows, COLUMNS)
    common.write_csv(args.out / 'orders.csv', order_rows + mj_orders, list(order_rows[0]))
    if mj_ratios:
        common.write_csv(args.out / 'mujoco_equal_error.csv', mj_ratios, list(mj_ratios[0]))
    img_dir = args.img_dir or args.out
    pngs = plots(rows, img_dir, mj_rows=mj_rows)
    rel = [Path(__import__('os').path.relpath(p, args.out)) for p in pngs]
    md = summary_md(rows, order_rows, par, ratios, cfg, problems, rel, args.quick, mujoco_note,
                    time.perf_counter() - t0, argv, mj_rows, mj_orders, mj_ratios)
    (args.out / 'summary.md').write_text(md)
    print()
    for o in order_rows + mj_orders:
        print(f'order {o["scene"]:14s} {o["integrator"]:15s} tol={o["velocity_tol"]:<6} tau@{o["tau_sample"]:5s} '
              f'{o["order_err_max"]:.2f} (final {o["order_err_final"]:.2f})')
    for r in mj_ratios:
        print(f'ours/MuJoCo at err {r["err_target"]:g} {r["scene"]:14s} ' +
              ' '.join(f'{i[3:]}={r[f"ratio_ours_over_{i}"]:.3g}' for i in MJ_STYLE))
    print(mujoco_note)
    print('plots:', ', '.join(map(str, pngs)) if pngs else 'skipped (matplotlib not installed)')
    print(f'wrote {args.out}/results.csv, orders.csv, summary.md in {time.perf_counter() - t0:.0f} s')
    if problems:
        print('CHECK FAILED:\n  ' + '\n  '.join(problems), file=sys.stderr)
        return 1
    return status


def read_results(path):
    """(our rows, MuJoCo rows) of a results.csv, numbers as numbers."""
    import csv
    text = ('engine', 'backend', 'scene', 'integrator', 'tau_sample', 'warnings', 'error')
    rows = []
    with open(path, newline='') as handle:
        for r in csv.DictReader(handle):
            rows.append({k: (v if k in text or v == '-' else float(v) if v != '' else math.nan)
                         for k, v in r.items()})
    return [r for r in rows if r['engine'] == 'abd'], [r for r in rows if r['engine'] != 'abd']


def replot(out, img_dir):
    """The PNGs from a study's results.csv, without running it again."""
    try:
        rows, mj_rows = read_results(out / 'results.csv')
    except (OSError, KeyError, ValueError) as exc:
        print(f'error_vs_runtime: cannot read {out / "results.csv"}: {exc}', file=sys.stderr)
        return 2
    pngs = plots(rows, img_dir, mj_rows=mj_rows)
    print('plots:', ', '.join(map(str, pngs)) if pngs else 'skipped (matplotlib not installed)')
    return 0


def mujoco_run(rows, args, cfg):
    """(MuJoCo rows, a note for the summary); no rows when MuJoCo is missing or skipped."""
    scenes_, note = mujoco_plan([r['scene'] for r in rows], args)
    if not scenes_:
        return [], note
    return M.sweep(tuple(cfg['dts']) + tuple(cfg['mj_extra_dts']), cfg['horizon'], scenes_), note


def mujoco_plan(scene_names, args):
    """(the MuJoCo scenes to run, a note for the summary); none when MuJoCo is missing or
    skipped."""
    cfg = QUICK if getattr(args, 'quick', False) else FULL
    if args.no_mujoco:
        return [], 'MuJoCo side-by-side run skipped (--no-mujoco).'
    mj = M.module()
    if mj is None:
        return [], ('MuJoCo is not installed, so the side-by-side comparison was skipped '
                    '(optional: `pip install -r requirements-bench.txt`).')
    scenes_ = [n for n in M.SCENES if n in scene_names]
    if not scenes_:
        return [], 'MuJoCo: none of its scenes (hinge_const, pendulum_sine) was run.'
    I = M.hinge_inertia_of(S.CASES['hinge_const'])
    return scenes_, (f'MuJoCo {mj.__version__} ran `{"`, `".join(scenes_)}` in the same run (study/mujoco_peer.py): '
                     f'one body on a hinge joint with the same inertia about the hinge (MuJoCo reports '
                     f'{I:.5f} kg m^2), a motor actuator, the same gravity, dt and references; '
                     'integrators Euler (semi-implicit), implicitfast and RK4, dt also down to '
                     f'{min(cfg["mj_extra_dts"]):g}. MuJoCo holds ctrl over a step, '
                     'so it gets the mid-step torque tau(t_n + h/2) (`tau@mid`). Wall time = setting ctrl + '
                     '`mj_step` from Python (median of 3 runs), as ours = `set_torque` + `step`.')


if __name__ == '__main__':
    sys.exit(main())
