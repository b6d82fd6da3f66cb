"""World: owns a Model, its State and Control, and the Solver that steps them (one step:
docs/physics.md "Time integration"; recovery and SimulationError: solver/solver.py). Between
one-step calls the state stays in the solver's ring buffers (solver/resident.py) and
`World.state` builds the State when it is read.
"""
from __future__ import annotations

import math
import operator

import numpy as np

from .model import Model, compile_scene
from .scene import EFFORT_UNIT, MAX_ABS_AIM, PRISMATIC, REVOLUTE, Scene
from .solver.report import Status, StepReport
from .solver.resident import Resident
from .solver.solver import Solver
from .state import Control, State
from .terms import ENERGY_TERMS, prismatic, revolute, torque

__all__ = ['World', 'Trajectory', 'StepReport', 'Status']


class World:
    """A running simulation of one scene. See README "Python API" for an example."""

    def __init__(self, scene: Scene | Model, dt: float | None = None):
        """`dt` [s] overrides the scene's step size (checked as the scene's own dt is); a
        compiled Model carries its own and takes no other."""
        if isinstance(scene, Model) and dt is not None and dt != scene.dt:
            raise ValueError(f'World: dt={dt!r} given with a compiled Model of dt {scene.dt}; '
                             'compile the scene with that dt (model.compile_scene(scene, dt)) or '
                             'pass the Scene')
        self.scene = scene if isinstance(scene, Scene) else None
        self.model = scene if isinstance(scene, Model) else compile_scene(scene, dt)
        m = self.model
        from .jit.warmup import ensure_compiled   # (not at import: `python -m abd_joint_sim.jit.warmup`)
        ensure_compiled()                     # says so before a first-time compile
        self.solver = Solver(m)
        self._resident = Resident(m.body_count, m.joint_count)
        self._joint_index = {n: k for k, n in enumerate(m.joint_names)}
        self._torque_slot = {m.joint_names[j]: k for k, j in enumerate(m.torque_joints)}
        # the rows of Control's effort arrays: UID 668 torques, then UID 667 forces
        effort_joints = np.concatenate([m.torque_joints, m.prismatic_force_joints]).astype(np.int64)
        self._effort_joints = effort_joints
        self._effort_slot = {m.joint_names[j]: k for k, j in enumerate(effort_joints)}
        self._actuated = tuple(m.joint_names[j] for j in effort_joints)
        # the effort limits as an array (set_efforts) and as Python floats (set_effort)
        self._effort_limit_array = np.concatenate([m.torque_effort_limit, m.prismatic_force_effort_limit])
        self._effort_limit = self._effort_limit_array.tolist()
        # the rows of Control's drive arrays: UID 19 drives, then UID 21 drives
        self._drive_slot = {m.joint_names[j]: k for k, j in
                            enumerate(np.concatenate([m.drive_joints, m.prismatic_drive_joints]).tolist())}
        self._types = tuple(PRISMATIC if s else REVOLUTE for s in m.joint_slides)
        self.reset()

    # -- introspection ------------------------------------------------------------------
    @property
    def terms(self) -> tuple:
        """Names of the terms this scene uses (energy terms, then forces)."""
        return self.solver.terms

    @property
    def state(self) -> State:
        """The current State (immutable: a step replaces it; built when read)."""
        return self._resident.state()

    @state.setter
    def state(self, state: State) -> None:
        self._resident.set(state)

    @property
    def time(self) -> float:
        return self._resident.now()

    @property
    def dt(self) -> float:
        return self.model.dt

    @property
    def joint_names(self) -> tuple:
        return self.model.joint_names

    @property
    def actuated_joint_names(self) -> tuple:
        """Joints carrying an external effort, in `set_efforts`' order: those with the torque
        (UID 668, revolute) in scene order, then those with the force (UID 667, prismatic)."""
        return self._actuated

    @property
    def effort_limits(self) -> np.ndarray:
        """The effort limit of each actuated joint, in `actuated_joint_names` order: N m on a
        revolute joint, N on a prismatic one (inf: none). A copy."""
        return self._effort_limit_array.copy()

    @property
    def joint_types(self) -> tuple:
        """'revolute' or 'prismatic' per joint, in joint_names order."""
        return self._types

    @property
    def body_names(self) -> tuple:
        return self.model.body_names

    def joint_positions(self) -> np.ndarray:
        """Per joint its position: the multi-turn angle including init_angle [rad] of a
        revolute joint, the distance including init_distance [m] of a prismatic one. (J,)"""
        return self._resident.joint_values(0)

    joint_angles = joint_positions      # (the name from revolute-only scenes)

    def joint_velocities(self) -> np.ndarray:
        """Time derivative of the joint positions. [rad/s | m/s] (J,)"""
        return self._resident.joint_values(1)

    def applied_torques(self) -> np.ndarray:
        """Torque applied at the next step per joint; 0 where disabled or not actuated, and on
        prismatic joints (applied_efforts has their forces). [N m] (J,)"""
        out = self.applied_efforts()
        out[self.model.prismatic_force_joints] = 0.0
        return out

    def applied_efforts(self) -> np.ndarray:
        """Effort applied at the next step per joint: the torque [N m] of a revolute joint, the
        force [N] of a prismatic one; 0 where disabled or not actuated. (J,)"""
        out = np.zeros(self.model.joint_count)
        c = self.control
        out[self._effort_joints] = np.where(c.torque_enabled, c.torque_value, 0.0)
        return out

    def body_pose(self, body: str):
        """(p (3,), A (3,3)) of a body: x = A x̄ + p."""
        try:
            b = self.model.body_names.index(body)
        except ValueError:
            raise KeyError(f'unknown body {body!r}; bodies: {", ".join(self.model.body_names)}') from None
        q = self._resident.body_q(b)        # (a copy, without building a State)
        return q[:3], q[3:12].reshape(3, 3)

    # -- control ------------------------------------------------------------------------
    def _slot(self, table, joint, what):
        if isinstance(joint, str) and joint in table:
            return table[joint]
        if not isinstance(joint, str) or joint not in self._joint_index:     # (a list: unhashable)
            raise KeyError(f'unknown joint {joint!r}; joints: {", ".join(self.model.joint_names)}')
        raise ValueError(f'joint {joint!r} has no {what}')

    def set_effort(self, joint: str, value: float) -> float:
        """Set a joint's effort, applied from the next step: the torque [N m] of a revolute
        joint (UID 668), the force [N] along a prismatic one (UID 667; positive f increases its
        distance). Values beyond the joint's effort_limit are clamped; the applied value is
        returned. A value that is not a number or not finite raises ValueError naming the joint
        and unit, and changes nothing."""
        k = self._slot(self._effort_slot, joint, 'external effort (external_torque or '
                                                 'external_force: not actuated)')
        kind = self._types[self._joint_index[joint]]
        return self._set_effort(k, value, joint, f'effort ({EFFORT_UNIT[kind]})')

    def _set_effort(self, k: int, value, joint: str, what: str) -> float:
        value = torque.clamp_command(_number(value, joint, what), self._effort_limit[k])
        self.control.torque_value[k] = value
        return value

    def set_effort_enabled(self, joint: str, enabled: bool) -> None:
        """Switch a joint's external effort (torque or force) on or off from the next step."""
        k = self._slot(self._effort_slot, joint, 'external effort (not actuated)')
        self.control.torque_enabled[k] = _flag(enabled, joint, 'enabled')

    def effort_enabled(self, joint: str) -> bool:
        return bool(self.control.torque_enabled[self._slot(self._effort_slot, joint, 'external effort')])

    def set_torque(self, joint: str, value: float) -> float:
        """Set the UID 668 torque of a revolute joint, applied from the next step; as
        `set_effort` (a prismatic joint's force), but refuses a prismatic joint."""
        if type(joint) is str and joint in self._effort_slot and joint not in self._torque_slot:
            raise ValueError(f'joint {joint!r} is prismatic: its effort is a force (UID 667, N); '
                             'set it with set_effort')
        k = self._slot(self._torque_slot, joint, 'external_torque (not actuated)')
        return self._set_effort(k, value, joint, 'torque')

    def set_torques(self, values) -> np.ndarray:
        """Set the effort of every actuated joint at once (UID 668 torque [N m], UID 667 force
        [N] on a prismatic joint), in `actuated_joint_names` order, from the next step. Values
        beyond each joint's effort_limit are clamped; returns the applied values (a copy). A
        wrong length or a value that is not a finite number raises ValueError naming it, and
        then no torque is changed."""
        names = self._actuated
        try:
            v = np.asarray(values, dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            raise ValueError(f'set_torques: values must be {len(names)} numbers (one per actuated '
                             f'joint: {", ".join(names)}), got {values!r}') from None
        if v.shape != (len(names),):
            raise ValueError(f'set_torques: {len(names)} values expected (one per actuated joint: '
                             f'{", ".join(names) or "none"}), got shape {v.shape}')
        if not (v.flags.c_contiguous and v.flags.writeable):
            v = v.copy()                # (another layout would be another compiled signature)
        out = self.control.torque_value
        bad = torque.clamp_commands(v, self._effort_limit_array, out)
        if bad >= 0:
            raise ValueError(f'joint {names[bad]!r}: torque {v[bad]} is not finite; rejected (no '
                             'torque changed)')
        return out.copy()

    set_efforts = set_torques           # (the name that says it sets forces too)

    def set_torque_enabled(self, joint: str, enabled: bool) -> None:
        """Switch a joint's UID 668 torque on or off from the next step. `enabled` must be True
        or False (numpy's bool, 0 and 1 too): anything else raises ValueError."""
        k = self._slot(self._torque_slot, joint, 'external_torque (not actuated)')
        self.control.torque_enabled[k] = _flag(enabled, joint, 'enabled')

    def torque_enabled(self, joint: str) -> bool:
        return bool(self.control.torque_enabled[self._slot(self._torque_slot, joint, 'external_torque')])

    def set_drive(self, joint: str, *, aim: float | None = None, enabled: bool | None = None,
                  passive: bool | None = None) -> None:
        """Change a joint's driving aim (absolute: the angle [rad] of a revolute joint's UID 19,
        the distance [m] of a prismatic joint's UID 21), enable or passive flag. All three
        are checked before any is applied: an aim that is not a finite number or a flag that
        is not True or False raises ValueError naming the joint, and changes nothing."""
        k = self._slot(self._drive_slot, joint, 'driving')
        kind = self._types[self._joint_index[joint]]
        what, unit = ('aim distance', 'm') if kind == PRISMATIC else ('aim angle', 'rad')
        aim = None if aim is None else _number(aim, joint, what)
        if aim is not None and abs(aim) > MAX_ABS_AIM:
            raise ValueError(f'joint {joint!r}: {what} {aim} {unit} is outside the supported range '
                             f'|aim| <= {MAX_ABS_AIM:g} {unit}; rejected')
        enabled = None if enabled is None else _flag(enabled, joint, 'enabled')
        passive = None if passive is None else _flag(passive, joint, 'passive')
        c = self.control
        for values, value in ((c.drive_aim, aim), (c.drive_enabled, enabled),
                              (c.drive_passive, passive)):
            if value is not None:
                values[k] = value

    def reset(self) -> None:
        """Back to the initial state and the scene's initial commands; time 0."""
        state = State.initial(self.model)
        if np.any(state.v):                 # bodies given velocities: their joints' rates at t = 0
            state.joint_velocity = self.solver.joint_rates(state)
        self.state = state
        self.control = Control.initial(self.model)
        self.last_step = StepReport(max_joint_separation=self.max_joint_separation())

    # -- diagnostics --------------------------------------------------------------------
    def max_joint_separation(self) -> float:
        """The largest joint separation [m]: the distance between the two bodies' copies of a
        revolute joint's anchor, or of a prismatic joint's axis point from the other body's
        axis."""
        q, data = self.state.q, self.solver.data
        out = float(revolute.max_separation(q, data))
        if len(self.model.prismatic_joints):
            out = max(out, float(prismatic.check_separations(q, data)[0]))
        return out

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
        """Kinetic + gravity + the stored energies of the energy terms [J] (those with STORED:
        shape, joint, driving, limit; the joint, driving and limit energies carry no h² in Π,
        so their physical potentials are E/h²; the shape energy's h² cancels)."""
        m, s = self.model, self.state
        free = ~m.body_fixed
        kin = 0.5 * float(np.einsum('bi,bij,bj->', s.v[free], m.body_M[free], s.v[free]))
        com = s.q[:, :3] + np.einsum('brc,bc->br', s.q[:, 3:12].reshape(-1, 3, 3), m.body_com)
        grav = -float(np.sum(m.body_mass[free] * (com[free] @ m.gravity)))
        ctx = self.solver.context(s, self.control, m.dt)
        data = self.solver.data
        pot = sum(term.energy(s.q, data, ctx) for term in ENERGY_TERMS if term.STORED)
        return kin + grav + pot / m.dt ** 2

    # -- stepping -----------------------------------------------------------------------
    def step(self, n: int = 1, trajectory: Trajectory | None = None) -> StepReport:
        """Advance n steps of size dt; returns (and stores in `last_step`) the last report
        (n = 0: none, the last report again). Raises SimulationError when a step cannot be
        finished even with sub-steps; the state is then that of the last good step (time
        stays a multiple of dt). An n that is not a whole number ≥ 0 raises ValueError.

        With a caller-owned `trajectory` (sim_node's batches): up to n steps that need no
        sub-stepping and give no warning, in one compiled call, each step's rows written to
        it; fewer (possibly 0) when a step is not clean, and the caller takes that one
        without `trajectory` (which sub-steps, warns or raises as usual). State and
        `last_step` are exactly as after `trajectory.count` one-step calls."""
        if n != 1:
            n = _step_count(n)
        if trajectory is not None:
            batch = self.solver.steps(self.state, self.control, n, clean=True) if n else None
            trajectory._fill(batch, self.model)
            if trajectory.count:
                self.state, self.last_step = batch.state, batch.report
            return self.last_step
        if n == 1:                  # (a controller's loop: this call every step)
            self.last_step = report = self.solver._step_resident(self._resident, self.control)
            return report
        while n > 0:
            # the solver never writes a State: on SimulationError self.state is the last good one
            done = self.solver.steps(self.state, self.control, n)
            self.state, self.last_step = done.state, done.report
            n -= done.count
        return self.last_step


class Trajectory:
    """The per-step rows of a `World.step(n, trajectory)` call, owned by the caller and
    rewritten by each call: `count` steps, and after each the time `times` [s] (list), the
    joint positions and velocities (count, J) and the body states `q` (count, B, 12)."""

    count, times, positions, velocities, q = 0, (), None, None, None

    def _fill(self, batch, model) -> None:
        if batch is None:                   # (n = 0)
            self.count, self.times = 0, []
            self.positions = self.velocities = np.empty((0, model.joint_count))
            self.q = np.empty((0, model.body_count, 12))
        else:
            self.count, self.times, self.q = batch.count, batch.times, batch.q
            self.positions, self.velocities = batch.joint_angles, batch.joint_velocities


def _step_count(n) -> int:
    """World.step's n as an int: an integer (numpy's too) or a float with a whole value, ≥ 0;
    ValueError naming n otherwise."""
    try:
        k = operator.index(n)
    except TypeError:
        if not (isinstance(n, (float, np.floating)) and math.isfinite(n) and float(n).is_integer()):
            raise ValueError(f'step: n must be a whole number of steps ≥ 0, got {n!r}') from None
        k = int(n)
    if not 0 <= k < 2 ** 63:                # (the compiled batch counts steps in int64)
        raise ValueError(f'step: n must be a whole number of steps ≥ 0, got {n!r}')
    return k


def _number(value, joint: str, what: str) -> float:
    """A command's value as a finite float; ValueError naming the joint otherwise (None, a
    string, an integer beyond a float's range, NaN, inf)."""
    try:
        value = float(value)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f'joint {joint!r}: {what} {value!r} is not a number; rejected') from None
    if not math.isfinite(value):
        raise ValueError(f'joint {joint!r}: {what} {value} is not finite; rejected')
    return value


def _flag(value, joint: str, what: str) -> bool:
    """A command's on/off flag: True or False (numpy's bool and the integers 0 and 1 too);
    ValueError naming the joint otherwise (bool('no') is True)."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    try:
        k = operator.index(value)
    except TypeError:
        k = None
    if k not in (0, 1):
        raise ValueError(f'joint {joint!r}: {what} must be True or False, got {value!r}; rejected')
    return bool(k)
