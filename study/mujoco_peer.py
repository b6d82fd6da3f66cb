"""The error study's scenes in MuJoCo (optional: `pip install -r requirements-bench.txt`).

Same model as study/scenes.py, reduced to what a revolute joint leaves: one body on a hinge
about +z through the origin, its centre of mass at (0.6, 0, 0), mass m = 64 kg and central
inertia m (a² + a²)/12 = 1.70667 kg m² (the 0.4 m cube), so I about the hinge is the same
24.74667 kg m² the references use; a motor actuator (gear 1, no control limit) applies the
joint torque; gravity (0, −g, 0) for the pendulum, none for the constant-torque hinge; no
contacts, damping or armature. The joint angle is qpos[0] (positive about +z, as ours).

Torque sampling: MuJoCo holds ctrl constant over a step, for every integrator, so the best a
held control can do is the mid-step value τ(t_n + h/2) (`tau@mid`); ours is sampled where
the BDF formulas evaluate the force (`tau@end`). With the sine torque this caps RK4 at order 2.
Wall time counts the same work as ours: setting the control and stepping, from Python.
The free pair (two free bodies) is not built here: its MuJoCo model would need a free joint
and is not what the comparison is about.
"""
from __future__ import annotations

import math
import time

import numpy as np

try:
    from . import scenes as S
except ImportError:
    import scenes as S  # type: ignore

INTEGRATORS = {'mj_euler': 'Euler', 'mj_implicitfast': 'implicitfast', 'mj_rk4': 'RK4'}
SCENES = ('hinge_const', 'pendulum_sine')


def module():
    """The mujoco module, or None when it is not installed."""
    try:
        import mujoco
    except ImportError:
        return None
    return mujoco


def model_xml(case, dt, integrator):
    I, m = S.hinge_inertia()
    a = 0.4
    ic = m * (a * a + a * a) / 12.0
    gravity = f'0 {-S.G!r} 0' if case.name == 'pendulum_sine' else '0 0 0'
    return (f'<mujoco model="{case.name}"><option timestep="{dt!r}" integrator="{INTEGRATORS[integrator]}" '
            f'gravity="{gravity}"/><worldbody><body name="arm">'
            '<joint name="hinge" type="hinge" axis="0 0 1" pos="0 0 0"/>'
            f'<inertial pos="0.6 0 0" mass="{m!r}" diaginertia="{ic!r} {ic!r} {ic!r}"/>'
            '</body></worldbody><actuator><motor joint="hinge" gear="1" ctrllimited="false"/>'
            '</actuator></mujoco>')


def hinge_inertia_of(case):
    """I about the hinge as MuJoCo computes it (a check that the model is the same)."""
    mj = module()
    mdl = mj.MjModel.from_xml_string(model_xml(case, 1e-3, 'mj_euler'))
    mass, ic = float(mdl.body_mass[1]), float(mdl.body_inertia[1][2])
    return ic + mass * float(np.sum(mdl.body_ipos[1][:2] ** 2))


def run_point(case, dt, integrator, horizon, repeats=3):
    """One MuJoCo point; returns a row with the error study's columns (median wall time of
    `repeats` identical runs: a MuJoCo run at dt = 1e-2 takes ~0.1 ms)."""
    mj = module()
    mdl = mj.MjModel.from_xml_string(model_xml(case, dt, integrator))
    n = int(round(horizon / dt))
    walls = []
    for _ in range(repeats):
        d = mj.MjData(mdl)
        times, angles = np.empty(n), np.empty(n)
        t0 = time.perf_counter()
        for k in range(n):
            d.ctrl[0] = case.torque(d.time + 0.5 * dt)
            mj.mj_step(mdl, d)
            times[k], angles[k] = d.time, d.qpos[0]
        walls.append(time.perf_counter() - t0)
    wall = float(np.median(walls))
    err = np.abs(angles - case.reference(horizon)(times))
    ok = bool(np.all(np.isfinite(err)))
    return {
        'engine': 'mujoco', 'backend': f'mujoco {mj.__version__}', 'scene': case.name,
        'integrator': integrator, 'velocity_tol': '-', 'tau_sample': 'mid', 'dt': dt, 'steps': n,
        'sim_time': float(times[-1]), 'wall_s': wall, 'wall_per_sim_s': wall / (n * dt),
        'ms_per_step': 1e3 * wall / n,
        'err_max': float(err.max()) if ok else math.nan, 'err_final': float(err[-1]) if ok else math.nan,
        'theta_final': float(angles[-1]), 'max_sep': 0.0, 'newton_per_step': math.nan,
        'line_search_per_step': math.nan, 'unconverged_steps': 0, 'substep_steps': 0,
        'max_linear_momentum': 0.0, 'max_angular_momentum': 0.0, 'warnings': 0, 'error': '',
    }


def sweep(dts, horizon, scenes=SCENES, log=print):
    rows = []
    for name in scenes:
        for integ in INTEGRATORS:
            for dt in dts:
                r = run_point(S.CASES[name], dt, integ, horizon)
                rows.append(r)
                log(f'{name:14s} {integ:15s} tau@mid  dt={dt:<7g} err_max={r["err_max"]:.3e} '
                    f'final={r["err_final"]:.3e} {r["ms_per_step"] * 1e3:.1f} us/step')
    return rows
