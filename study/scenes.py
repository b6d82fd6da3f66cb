"""Scenes with known answers for the studies, and their reference solutions.

Every builder returns a plain scene dict (what `Scene.from_dict` accepts), so the studies do
not depend on the YAML files and each parameter is visible here.

Sign conventions (docs/physics.md "Joint angle", "External joint torque (UID 668)"): the hinge axis is t = (p1 − p0)/|p1 − p0| = +z, and a
positive torque turns the child about +t, i.e. it increases the joint angle θ.

Reference solutions
-------------------
* ``hinge``: fixed cube, free cube, no gravity, constant τ from rest: θ(t) = ½ (τ/I) t².
  I = I_cm,z + m d² is computed from the geometry (the "24.747" of docs/physics.md "Analytic references" is rounded:
  using it leaves a relative error of 1.3e-5 that masks BDF2 below dt ≈ 1e-3).
* ``free_pair``: two identical free cubes, internal torque τ: each turns by φ = θ/2 with
  (I_c + m d² sin²φ) φ̇² = 2τφ (docs/physics.md "Analytic references"). With φ = u² the map t(u) is smooth,
  dt/du = 2 sqrt((I_c + m d² sin² u²)/(2τ)), so we integrate du/dt = 1/that (DOP853,
  rtol 1e-13) and take θ = 2u². Check: θ(1 s) = 11.786632172303 for the default scene.
* ``pendulum``: the hinge scene turned into a pendulum: gravity (0, −g, 0), axis +z, arm COM
  at (d cos θ, d sin θ, 0) so its potential is m g d sin θ and
  I θ'' = τ(t) − m g d cos θ, θ(0) = θ'(0) = 0 (arm horizontal, released from rest), with
  τ(t) = τ0 sin(ω t). Reference: solve_ivp DOP853, rtol = atol = 1e-12, dense output.

Time sampling of the torque: the simulator takes τ once per step (explicit force in the
prediction q̃). The studies call ``set_torque(τ(t_n + h))`` before the step from t_n, i.e.
they sample the end of the step, the time at which both BDF formulas evaluate the force
(implicit Euler: a(t_{n+1}); BDF2: a(t_{n+1}) with weight 4/9 h²). Sampling the start of
the step (a zero-order hold of τ(t_n)) delays the torque by h and is first order for *both*
integrators; the error study measures that variant too (``tau_sample='start'``).
"""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

G = 9.81


# -- scene builders ---------------------------------------------------------------------
def _newton(velocity_tol=0.05, **kw):
    d = {'velocity_tol': float(velocity_tol)}
    d.update(kw)
    return d


def hinge_scene(dt=1e-2, integrator='bdf1', velocity_tol=0.05, tau=100.0, gravity=(0.0, 0.0, 0.0),
                size=0.4, child_box=None, density=1000.0, child_density=None, kappa=1e8,
                strength_ratio=100.0, angular_velocity=0.0, newton=None):
    """Fixed cube at x = −0.6, free cube (or `child_box`) centred at x = +0.6, hinge on z
    through the origin. `angular_velocity` [rad/s] starts the child spinning rigidly about
    the hinge (v = ω ẑ × p), which is a state consistent with the joint."""
    cb = list(child_box) if child_box is not None else [size, size, size]
    w = float(angular_velocity)
    return {
        'name': 'study_hinge', 'dt': float(dt), 'gravity': [float(g) for g in gravity],
        'integrator': integrator, 'newton': newton or _newton(velocity_tol),
        'bodies': [
            {'name': 'base', 'box': [size, size, size], 'density': float(density),
             'kappa': float(kappa), 'position': [-0.6, 0.0, 0.0], 'fixed': True},
            {'name': 'arm', 'box': cb, 'density': float(child_density or density),
             'kappa': float(kappa), 'position': [0.6, 0.0, 0.0],
             'velocity': [0.0, 0.6 * w, 0.0], 'angular_velocity': [0.0, 0.0, w]},
        ],
        'joints': [{'name': 'hinge', 'parent': 'base', 'child': 'arm',
                    'p0': [0.0, 0.0, -0.5], 'p1': [0.0, 0.0, 0.5],
                    'strength_ratio': float(strength_ratio),
                    'external_torque': {'torque': float(tau), 'enabled': True}}],
    }


def slider_scene(dt=1e-2, integrator='bdf1', velocity_tol=0.05, force=10.0, size=0.4, density=1000.0,
                 kappa=1e8, strength_ratio=100.0, velocity=0.0, limit=None, newton=None):
    """Fixed cube at x = −0.6, free cube centred at x = +0.6, a prismatic joint along +x
    through both (UID 20) with the force `force` [N] along it (UID 667); `velocity` [m/s] starts
    the child sliding along the axis; `limit` (lower, upper) [m] adds UID 669."""
    joint = {'name': 'slide', 'type': 'prismatic', 'parent': 'base', 'child': 'arm',
             'p0': [0.0, 0.0, 0.0], 'p1': [1.0, 0.0, 0.0], 'strength_ratio': float(strength_ratio),
             'external_force': {'force': float(force), 'enabled': True}}
    if limit is not None:
        joint['limit'] = {'lower': float(limit[0]), 'upper': float(limit[1])}
    return {
        'name': 'study_slider', 'dt': float(dt), 'gravity': [0.0, 0.0, 0.0],
        'integrator': integrator, 'newton': newton or _newton(velocity_tol),
        'bodies': [
            {'name': 'base', 'box': [size] * 3, 'density': float(density), 'kappa': float(kappa),
             'position': [-0.6, 0.0, 0.0], 'fixed': True},
            {'name': 'arm', 'box': [size] * 3, 'density': float(density), 'kappa': float(kappa),
             'position': [0.6, 0.0, 0.0], 'velocity': [float(velocity), 0.0, 0.0]},
        ],
        'joints': [joint],
    }


def hinge_inertia(size=0.4, density=1000.0, child_box=None, d=0.6):
    """I about the hinge axis (z through the origin) of the child box centred at x = d."""
    a, b, c = child_box if child_box is not None else (size, size, size)
    m = density * a * b * c
    return m * (a * a + b * b) / 12.0 + m * d * d, m


def pendulum_scene(dt=1e-2, integrator='bdf1', velocity_tol=0.05, g=G, **kw):
    """The hinge scene with gravity (0, −g, 0): a compound pendulum released horizontally."""
    return hinge_scene(dt, integrator, velocity_tol, tau=0.0, gravity=(0.0, -g, 0.0), **kw)


def free_pair_scene(dt=1e-3, integrator='bdf1', velocity_tol=0.05, tau=1.0, size=0.2,
                    density=1000.0, parent_density=None, kappa=1e8, strength_ratio=100.0,
                    newton=None):
    """Two free cubes sharing a face, hinge on z through the origin, internal torque τ."""
    return {
        'name': 'study_free_pair', 'dt': float(dt), 'gravity': [0.0, 0.0, 0.0],
        'integrator': integrator, 'newton': newton or _newton(velocity_tol),
        'bodies': [
            {'name': 'left', 'box': [size] * 3, 'density': float(parent_density or density),
             'kappa': float(kappa), 'position': [-size / 2, 0.0, 0.0]},
            {'name': 'right', 'box': [size] * 3, 'density': float(density),
             'kappa': float(kappa), 'position': [size / 2, 0.0, 0.0]},
        ],
        'joints': [{'name': 'hinge', 'parent': 'left', 'child': 'right',
                    'p0': [0.0, 0.0, -size / 2], 'p1': [0.0, 0.0, size / 2],
                    'strength_ratio': float(strength_ratio),
                    'external_torque': {'torque': float(tau), 'enabled': True}}],
    }


def chain_scene(links=20, dt=1e-2, integrator='bdf1', velocity_tol=0.05, length=0.1,
                width=0.02, density=1000.0, gravity=(0.0, -G, 0.0), tau=0.0, kappa=1e8):
    """A fixed base and `links` boxes along +x, each joined to the previous one by a hinge on
    z at their shared face; horizontal under gravity −y at t = 0 (it falls and swings)."""
    bodies = [{'name': 'base', 'box': [length, width, width], 'density': density, 'kappa': kappa,
               'position': [-length / 2, 0.0, 0.0], 'fixed': True}]
    joints = []
    for k in range(links):
        bodies.append({'name': f'l{k}', 'box': [length, width, width], 'density': density,
                       'kappa': kappa, 'position': [length * (k + 0.5), 0.0, 0.0]})
        joints.append({'name': f'j{k}', 'parent': bodies[k]['name'], 'child': f'l{k}',
                       'p0': [length * k, 0.0, -width], 'p1': [length * k, 0.0, width],
                       'external_torque': {'torque': float(tau), 'enabled': tau != 0.0}})
    return {'name': f'chain{links}', 'dt': float(dt), 'gravity': [float(x) for x in gravity],
            'integrator': integrator, 'newton': _newton(velocity_tol),
            'bodies': bodies, 'joints': joints}


# -- references -------------------------------------------------------------------------
def hinge_reference(tau=100.0, **geom):
    I, _ = hinge_inertia(**geom)
    alpha = tau / I
    return lambda t: 0.5 * alpha * np.asarray(t, float) ** 2


@lru_cache(maxsize=8)
def _free_pair_solution(tau, size, density, t_end):
    from scipy.integrate import solve_ivp
    m = density * size ** 3
    Ic = m * (2 * size * size) / 12.0
    d = size / 2

    def dudt(t, u):
        return [1.0 / (2.0 * math.sqrt((Ic + m * d * d * math.sin(u[0] ** 2) ** 2) / (2.0 * tau)))]

    sol = solve_ivp(dudt, (0.0, t_end), [0.0], method='DOP853', rtol=1e-13, atol=1e-15,
                    dense_output=True)
    if not sol.success:
        raise RuntimeError(f'free pair reference failed: {sol.message}')
    return sol


def free_pair_reference(tau=1.0, size=0.2, density=1000.0, t_end=1.0):
    """θ(t) of the symmetric free pair (vectorised)."""
    sol = _free_pair_solution(float(tau), float(size), float(density), float(t_end))
    return lambda t: 2.0 * sol.sol(np.asarray(t, float))[0] ** 2


@lru_cache(maxsize=8)
def _pendulum_solution(tau0, omega, g, t_end, size, density):
    from scipy.integrate import solve_ivp
    I, m = hinge_inertia(size=size, density=density)
    d = 0.6

    def rhs(t, y):
        return [y[1], (tau0 * math.sin(omega * t) - m * g * d * math.cos(y[0])) / I]

    sol = solve_ivp(rhs, (0.0, t_end), [0.0, 0.0], method='DOP853', rtol=1e-12, atol=1e-12,
                    dense_output=True)
    if not sol.success:
        raise RuntimeError(f'pendulum reference failed: {sol.message}')
    return sol


def pendulum_reference(tau0, omega, g=G, t_end=1.0, size=0.4, density=1000.0):
    sol = _pendulum_solution(float(tau0), float(omega), float(g), float(t_end), float(size),
                             float(density))
    return lambda t: sol.sol(np.asarray(t, float))[0]


# -- error-study cases ------------------------------------------------------------------
class Case:
    """One error-study scene: builds worlds, gives the torque schedule and the reference."""

    name = ''
    description = ''
    horizon = 0.5

    def scene(self, dt, integrator, velocity_tol):
        raise NotImplementedError

    def torque(self, t):
        raise NotImplementedError

    def reference(self, t_end):
        raise NotImplementedError


class HingeConstant(Case):
    name = 'hinge_const'
    description = 'fixed cube + free cube, constant tau = 100 N m, no gravity; theta = tau t^2/(2I)'
    tau = 100.0

    def scene(self, dt, integrator, velocity_tol):
        return hinge_scene(dt, integrator, velocity_tol, tau=self.tau)

    def torque(self, t):
        return self.tau

    def reference(self, t_end):
        return hinge_reference(self.tau)


class FreePair(Case):
    name = 'free_pair'
    description = 'two free 0.2 m cubes, internal tau = 1 N m; closed form (docs/physics.md, Analytic references), momentum 0'
    tau = 1.0

    def scene(self, dt, integrator, velocity_tol):
        return free_pair_scene(dt, integrator, velocity_tol, tau=self.tau)

    def torque(self, t):
        return self.tau

    def reference(self, t_end):
        return free_pair_reference(self.tau, t_end=max(t_end, 1.0))


class PendulumSine(Case):
    name = 'pendulum_sine'
    description = ('hinge cube as a pendulum under gravity -y, tau(t) = 200 sin(2 pi t) N m; '
                   'reference DOP853 on I theta\'\' = tau - m g d cos theta')
    tau0 = 200.0
    omega = 2.0 * math.pi

    def scene(self, dt, integrator, velocity_tol):
        return pendulum_scene(dt, integrator, velocity_tol)

    def torque(self, t):
        return self.tau0 * math.sin(self.omega * t)

    def reference(self, t_end):
        return pendulum_reference(self.tau0, self.omega, t_end=max(t_end, 1.0))


class SliderSine(Case):
    name = 'slider_sine'
    description = ('fixed cube + free cube on a prismatic joint, force f(t) = 50 sin(2 pi t) N along '
                   'it, no gravity; d = (f0/m)(t/omega - sin(omega t)/omega^2)')
    f0 = 50.0
    omega = 2.0 * math.pi
    mass = 1000.0 * 0.4 ** 3

    def scene(self, dt, integrator, velocity_tol):
        return slider_scene(dt, integrator, velocity_tol, force=0.0)

    def torque(self, t):
        return self.f0 * math.sin(self.omega * t)

    def reference(self, t_end):
        a, w = self.f0 / self.mass, self.omega
        return lambda t: a * (np.asarray(t, float) / w - np.sin(w * np.asarray(t, float)) / w ** 2)


CASES = {c.name: c for c in (HingeConstant(), FreePair(), PendulumSine(), SliderSine())}
