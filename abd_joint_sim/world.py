"""World: model + state + control + terms + solver, with the public stepping API.

One step of size h (PHYSICS.md §2), run by `World.step`:
  1. forces (gravity, UID 668 torque) give the q-space acceleration a = g_q + M⁻¹F at qⁿ;
  2. prediction q̃ (BDF1: qⁿ + h vⁿ + h² a; BDF2: see `_predict`), q̃ = qⁿ on fixed bodies;
  3. Newton minimises Π (solver/newton.py) over the free bodies;
  4. velocities, then the multi-turn joint angles (angles.py) are updated.
Recovery: a step whose Newton solve fails, turns out non-finite, or turns a joint by more
than `newton.max_step_rotation` (the unwrapped angle is only exact below π per step) is
undone and retried as two half steps, recursively up to 2**max_substep_depth sub-steps.
If even that yields a non-finite state, `SimulationError` is raised and the state stays at
the last good step; a merely unconverged result is kept and reported (never hidden).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from . import fast
from .angles import joint_theta_derivatives, unwrap
from .errors import SimulationError
from .model import Model, compile_scene
from .scene import Scene
from .solver.linsolve import LinearSystem
from .solver.newton import NewtonSolver, Status
from .state import Control, State
from .terms.angle_terms import Driving, Limit
from .terms.base import StepContext
from .terms.forces import ExternalTorque, Gravity
from .terms.ortho import OrthoPotential
from .terms.revolute import RevoluteJoint, joint_separation

BETA_BDF2 = 4.0 / 9.0
SEPARATION_WARN = 0.01      # joint anchors further apart than this x body size: warn
# Rotation per step above which the integrator's numerical damping of it is reported
# (measured on the free-spinning reference hinge, loss of angular speed per step).
ACCURACY_ROTATION = {'bdf1': 0.1, 'bdf2': 0.3}
ACCURACY_NOTE = {
    'bdf1': 'implicit Euler (bdf1) damps rotation this fast (measured: ~0.9 % of the speed per '
            'step at 0.1 rad/step, ~5 % at 0.3): reduce dt or use bdf2 for accuracy',
    'bdf2': 'bdf2 damps rotation this fast (measured: ~0.1 % of the speed per step at 0.3 '
            'rad/step, ~1 % at 0.6): reduce dt for accuracy'}
ENERGY_TERMS = (OrthoPotential, RevoluteJoint, Driving, Limit)
FORCES = (Gravity, ExternalTorque)


@dataclass(slots=True)
class StepReport:
    """What one call of `World.step` did (the last step when several were taken)."""

    time: float = 0.0                   #: [s] simulation time after the step
    status: str = 'converged'           #: worst Newton status over the sub-steps
    converged: bool = True
    newton_iterations: int = 0          #: summed over sub-steps
    line_search_iterations: int = 0
    substeps: int = 1
    max_joint_separation: float = 0.0   #: [m] after the step
    max_step_rotation: float = 0.0      #: [rad] largest joint rotation of a (sub-)step
    warnings: list = field(default_factory=list)


class World:
    """A running simulation of one scene. See README "Python API" for an example."""

    def __init__(self, scene: Scene | Model, dt: float | None = None, backend: str = 'auto'):
        self.scene = scene if isinstance(scene, Scene) else None
        self.model = scene if isinstance(scene, Model) else compile_scene(scene, dt)
        m = self.model
        # 'numpy' (this file: the reference) or 'numba' (fast/, same step compiled); 'auto'
        # = ABD_BACKEND if set, else numba when importable (docs/fast-backend.md)
        self.backend = fast.resolve(backend, m)
        # the compiled step (fast/step.py `single`), bound once: importing it per step costs
        # ~1 µs, and only a numba World may import numba
        self._fast_single = None
        if self.backend == 'numba':
            from .fast.step import single as fast_single
            self._fast_single = fast_single
        self.energy_terms = [t for t in (c.build(m) for c in ENERGY_TERMS) if t is not None]
        self.forces = [f for f in (c.build(m) for c in FORCES) if f is not None]
        self.solver = NewtonSolver(m, self.energy_terms, LinearSystem(m))
        self._joint_index = {n: k for k, n in enumerate(m.joint_names)}
        self._torque_slot = {m.joint_names[j]: k for k, j in enumerate(m.torque_joints)}
        self._drive_slot = {m.joint_names[j]: k for k, j in enumerate(m.drive_joints)}
        self._all_joints = np.arange(m.joint_count)
        size = m.body_size
        self._joint_separation_limit = SEPARATION_WARN * np.minimum(size[m.joint_parent], size[m.joint_child])
        self._separation_warn = float(self._joint_separation_limit.min()) if m.joint_count else np.inf
        self.reset()

    # -- introspection ------------------------------------------------------------------
    @property
    def terms(self) -> tuple:
        """Names of the terms this scene instantiated (energy terms, then forces)."""
        return tuple(t.name for t in self.energy_terms) + tuple(f.name for f in self.forces)

    @property
    def time(self) -> float:
        return self.state.time

    @property
    def dt(self) -> float:
        return self.model.dt

    @property
    def joint_names(self) -> tuple:
        return self.model.joint_names

    @property
    def actuated_joint_names(self) -> tuple:
        """Joints carrying the external torque (UID 668), in scene order."""
        return tuple(self.model.joint_names[j] for j in self.model.torque_joints)

    @property
    def body_names(self) -> tuple:
        return self.model.body_names

    def joint_angles(self) -> np.ndarray:
        """Multi-turn angles including init_angle. [rad] (J,)"""
        return self.state.joint_angle.copy()

    def joint_velocities(self) -> np.ndarray:
        """Time derivative of the joint angles. [rad/s] (J,)"""
        return self.state.joint_velocity.copy()

    def applied_torques(self) -> np.ndarray:
        """Torque applied at the next step per joint; 0 where disabled or not actuated. [N m] (J,)"""
        out = np.zeros(self.model.joint_count)
        c = self.control
        out[self.model.torque_joints] = np.where(c.torque_enabled, c.torque_value, 0.0)
        return out

    def body_pose(self, body: str):
        """(p (3,), A (3,3)) of a body: x = A x̄ + p."""
        try:
            b = self.model.body_names.index(body)
        except ValueError:
            raise KeyError(f'unknown body {body!r}; bodies: {", ".join(self.model.body_names)}') from None
        q = self.state.q[b]
        return q[:3].copy(), q[3:12].reshape(3, 3).copy()

    # -- control ------------------------------------------------------------------------
    def _slot(self, table, joint, what):
        if joint in table:
            return table[joint]
        if joint not in self._joint_index:
            raise KeyError(f'unknown joint {joint!r}; joints: {", ".join(self.model.joint_names)}')
        raise ValueError(f'joint {joint!r} has no {what}')

    def set_torque(self, joint: str, value: float) -> float:
        """Set the UID 668 torque of a joint, applied from the next step. Values beyond the
        joint's effort_limit are clamped; the applied value is returned."""
        k = self._slot(self._torque_slot, joint, 'external_torque (not actuated)')
        value = float(value)
        if not math.isfinite(value):
            raise ValueError(f'joint {joint!r}: torque {value} is not finite; rejected')
        limit = self.model.torque_effort_limit[k]
        self.control.torque_value[k] = min(max(value, -limit), limit)
        return float(self.control.torque_value[k])

    def set_torque_enabled(self, joint: str, enabled: bool) -> None:
        k = self._slot(self._torque_slot, joint, 'external_torque (not actuated)')
        self.control.torque_enabled[k] = bool(enabled)

    def torque_enabled(self, joint: str) -> bool:
        return bool(self.control.torque_enabled[self._slot(self._torque_slot, joint, 'external_torque')])

    def set_drive(self, joint: str, *, aim: float | None = None, enabled: bool | None = None,
                  passive: bool | None = None) -> None:
        """Change a joint's driving (UID 19) aim angle [rad, absolute], enable or passive flag."""
        k = self._slot(self._drive_slot, joint, 'driving')
        if aim is not None:
            if not math.isfinite(aim):
                raise ValueError(f'joint {joint!r}: aim angle {aim} is not finite; rejected')
            self.control.drive_aim[k] = aim
        if enabled is not None:
            self.control.drive_enabled[k] = bool(enabled)
        if passive is not None:
            self.control.drive_passive[k] = bool(passive)

    def reset(self) -> None:
        """Back to the initial state and the scene's initial commands; time 0."""
        self.state = State.initial(self.model)
        self.control = Control.initial(self.model)
        self.last_step = StepReport(max_joint_separation=self.max_joint_separation())

    # -- diagnostics --------------------------------------------------------------------
    def max_joint_separation(self) -> float:
        if self.backend == 'numba':
            from .fast.step import max_joint_separation
            return max_joint_separation(self)
        sep = joint_separation(self.model, self.state.q)
        return float(sep.max()) if len(sep) else 0.0

    def momentum(self):
        """(linear (3,), angular about the world origin (3,)) of the free bodies."""
        m = self.model
        free = ~m.body_fixed
        q, v = self.state.q[free], self.state.v[free]
        mass, mc = m.body_mass[free], m.body_mass[free, None] * m.body_com[free]
        S = m.body_M[free, 3:6, 3:6]
        p, pd = q[:, :3], v[:, :3]
        A, Ad = q[:, 3:12].reshape(-1, 3, 3), v[:, 3:12].reshape(-1, 3, 3)
        Amc, Admc = np.einsum('brc,bc->br', A, mc), np.einsum('brc,bc->br', Ad, mc)
        linear = (mass[:, None] * pd + Admc).sum(axis=0)
        # ∫ρ x × ẋ with x = A x̄ + p: the affine part is the axial vector of A S Ȧᵀ − Ȧ S Aᵀ
        W = A @ S @ Ad.transpose(0, 2, 1)
        W = W - W.transpose(0, 2, 1)
        spin = np.stack([W[:, 1, 2], W[:, 2, 0], W[:, 0, 1]], axis=1)
        angular = (mass[:, None] * np.cross(p, pd) + np.cross(p, Admc) + np.cross(Amc, pd)
                   + spin).sum(axis=0)
        return linear, angular

    def mechanical_energy(self) -> float:
        """Kinetic + gravity + shape + joint energies [J] (the joint, driving and limit energies
        carry no h² in Π, so their physical potentials are E/h²)."""
        m = self.model
        q, v = self.state.q, self.state.v
        free = ~m.body_fixed
        kin = 0.5 * float(np.einsum('bi,bij,bj->', v[free], m.body_M[free], v[free]))
        com = q[:, :3] + np.einsum('brc,bc->br', q[:, 3:12].reshape(-1, 3, 3), m.body_com)
        grav = -float(np.sum(m.body_mass[free] * (com[free] @ m.gravity)))
        ctx = self._context(m.dt)
        pot = 0.0
        for t in self.energy_terms:
            e = t.energy(q, ctx)
            pot += e / m.dt ** 2
        return kin + grav + pot

    # -- stepping -----------------------------------------------------------------------
    def step(self, n: int = 1) -> StepReport:
        """Advance n steps of size dt; returns (and stores in `last_step`) the last report."""
        for _ in range(int(n)):
            report = StepReport()
            # A step replaces the State object and never writes into the old one, so keeping
            # a reference is enough to undo it.
            start = self.state
            try:
                if self._fast_single is not None:     # no numpy arithmetic in the step;
                    self._advance(self.model.dt, 0, report)     # fast/step.py sets the separation
                else:
                    # overflow in a failing step is caught by the finite checks, reported once
                    with np.errstate(over='ignore', invalid='ignore', divide='ignore'):
                        self._advance(self.model.dt, 0, report)
                    report.max_joint_separation = self.max_joint_separation()
            except SimulationError:
                self.state = start          # whole step undone: time stays a multiple of dt
                raise
            report.time = self.state.time
            if report.max_joint_separation > self._separation_warn:
                self._warn_separation(report)
            x = report.max_step_rotation
            if x > ACCURACY_ROTATION[self.model.integrator]:
                report.warnings.append(
                    f't={self.state.time:.6g}s: a joint turned {x:.3g} rad in one step; '
                    f'{ACCURACY_NOTE[self.model.integrator]}')
            self.last_step = report
        return self.last_step

    def step_clean(self, n: int):
        """Up to n steps that need no sub-stepping and give no warning, in one compiled call
        (numba backend; ~30 µs of Python per step saved, for sim_node's batches). Returns
        (count, times, joint angles (count,J), joint velocities (count,J)); state and
        `last_step` are exactly as after `count` calls of `step`. Fewer than n (possibly 0)
        when a step is not clean, and always 0 on the numpy backend: the caller then takes
        that step with `step`, which sub-steps, warns or raises as usual."""
        if self._fast_single is None or n <= 0:
            return 0, [], np.empty((0, self.model.joint_count)), np.empty((0, self.model.joint_count))
        from .fast.step import clean_steps
        return clean_steps(self, int(n))

    def _warn_separation(self, report):
        sep = joint_separation(self.model, self.state.q)
        for j in np.flatnonzero(sep > self._joint_separation_limit):
            report.warnings.append(
                f't={self.state.time:.6g}s: joint {self.model.joint_names[j]!r} anchors '
                f'{sep[j]:.3g} m apart (> {SEPARATION_WARN:.0%} of the smaller body): the joint '
                'is overloaded; lower the torque or dt, or raise strength_ratio')

    def _context(self, h) -> StepContext:
        m, c = self.model, self.control
        rel = self.state.joint_angle - m.joint_init_angle
        target = np.where(c.drive_passive, rel[m.drive_joints], c.drive_aim - m.joint_init_angle[m.drive_joints])
        return StepContext(h=h, joint_rel_start=rel, drive_target=target, drive_active=c.drive_enabled.copy())

    def _advance(self, h, depth, report):
        saved = self.state
        failure = self._single(h, report, depth < self.model.newton.max_substep_depth)
        if failure is None:
            return
        if depth < self.model.newton.max_substep_depth:
            self.state = saved
            report.status, report.converged = 'converged', True
            report.warnings.append(f't={saved.time:.6g}s: {failure}; retrying as 2 sub-steps of {h / 2:.3g}s')
            report.substeps += 1
            self._advance(h / 2, depth + 1, report)
            self._advance(h / 2, depth + 1, report)
            return
        if 'non-finite' in failure:
            self.state = saved
            raise SimulationError(f't={saved.time:.6g}s: {failure} even with {2 ** depth} sub-steps of '
                                  f'{h:.3g}s; state kept at the last good step')
        report.warnings.append(f't={saved.time:.6g}s: {failure} with {2 ** depth} sub-steps; result kept')

    def _single(self, h, report, may_split=False):
        """One (sub-)step; returns None or a failure description (state then invalid).
        `may_split`: a step predicted to turn a joint too far is refused before solving."""
        if self._fast_single is not None:      # same contract, compiled (fast/step.py)
            return self._fast_single(self, h, report, may_split)
        m, s = self.model, self.state
        free = ~m.body_fixed
        # BDF2 needs one step of history at this h. Without it (first step, after a reset,
        # a dt change or sub-stepping) the step is taken with BDF1: the reference's start
        # q₋₁ = q₀, v₋₁ = v₀ leaves a velocity deficit of h·a/3 that BDF2 never damps, which
        # makes it first order globally (docs/decisions.md).
        bdf2 = m.integrator == 'bdf2' and s.history_dt == h
        # Forces are explicit. The torque's generalized force turns with A, so evaluating it
        # at qⁿ lags by O(h): fine for BDF1, but BDF2 takes them at the extrapolation
        # 2qⁿ − qⁿ⁻¹ = q(t+h) + O(h²) to stay second order.
        q_force = 2 * s.q - s.q_prev if bdf2 else s.q
        acc = np.zeros((m.body_count, 12))
        for f in self.forces:
            f.acceleration(q_force, self.control, acc, report.warnings)
        if bdf2:
            q_tilde = (4 * s.q - s.q_prev) / 3 + 2.0 / 9.0 * h * (4 * s.v - s.v_prev) + BETA_BDF2 * h * h * acc
            scale = 1.0 / BETA_BDF2
        else:
            q_tilde = s.q + h * s.v + h * h * acc
            scale = 1.0
        q_tilde[~free] = s.q[~free]
        if may_split and m.joint_count:
            # BDF1 damps fast rotation: the solved angle change saturates below the limit
            # and would never trigger a split. The linearised prediction ∇θ·(q̃ − qⁿ) does not.
            _, dth0, _ = joint_theta_derivatives(m, s.q, self._all_joints, hessian=False)
            dq = q_tilde - s.q
            predicted = float(np.max(np.abs(np.einsum(
                'ja,ja->j', dth0, np.concatenate([dq[m.joint_parent, 3:12], dq[m.joint_child, 3:12]], axis=1)))))
            if predicted > m.newton.max_step_rotation:
                return (f'a joint is predicted to turn {predicted:.3g} rad in one step (limit '
                        f'{m.newton.max_step_rotation:.3g})')
        ctx = self._context(h)
        # Start from the prediction plus the last step's correction (State.warm_start): with
        # no contact to guard, q̃ is a good guess, but the joints correct the free-body
        # prediction by about the same amount every step (a couple on a link spins it about
        # its own centre; the hinge makes it turn about the joint), so q̃ alone costs one
        # Newton iteration more (docs/decisions.md).
        cw = h * h / scale
        result = self.solver.minimize(q_tilde + cw * s.warm_start, q_tilde, scale, ctx, q_other=q_tilde)
        report.newton_iterations += result.iterations
        report.line_search_iterations += result.line_search_iterations
        q = result.q
        if result.status is Status.NONFINITE or not np.all(np.isfinite(q)):
            return 'Newton produced a non-finite state'
        if bdf2:
            v = (3 * q - 4 * s.q + s.q_prev) / (2 * h)
        else:
            v = (q - s.q) / h
        v[~free] = 0.0
        rel_prev = s.joint_angle - m.joint_init_angle
        if m.joint_count:
            theta, dth, _ = joint_theta_derivatives(m, q, self._all_joints, hessian=False)
            rel = unwrap(theta, rel_prev)
            vp, vc = v[m.joint_parent, 3:12], v[m.joint_child, 3:12]
            omega = np.einsum('ja,ja->j', dth, np.concatenate([vp, vc], axis=1))
            rotation = float(np.max(np.maximum(np.abs(rel - rel_prev), np.abs(omega) * h)))
        else:
            rel, omega, rotation = rel_prev, s.joint_velocity, 0.0
        if not (np.all(np.isfinite(rel)) and np.all(np.isfinite(v))):
            return 'step produced a non-finite state'
        report.max_step_rotation = max(report.max_step_rotation, rotation)
        warm = (q - q_tilde) / cw
        self.state = State(time=s.time + h, q=q, v=v, q_prev=s.q, v_prev=s.v, warm_start=warm,
                           joint_angle=rel + m.joint_init_angle, joint_velocity=omega,
                           step_count=s.step_count + 1, history_dt=h)
        if rotation > m.newton.max_step_rotation:
            return (f'a joint turned {rotation:.3g} rad in one step (limit '
                    f'{m.newton.max_step_rotation:.3g})')
        if result.status is not Status.CONVERGED:
            report.status, report.converged = result.status.value, False
            return f'Newton stopped: {result.status.value} after {result.iterations} iterations'
        return None
