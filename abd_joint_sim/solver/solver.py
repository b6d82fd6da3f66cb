"""`Solver`: built once per Model, steps a State under a Control (docs/physics.md).

`Solver.step(state, control)` returns the new State (the one passed in is never written) and
a StepReport. A step whose Newton solve fails, whose state is not finite, in which a joint
turns more than `max_step_rotation` (or is predicted to) or comes apart, is retried as two
half steps, recursively up to 2**max_substep_depth sub-steps; if that still leaves a
non-finite state or a joint apart, `SimulationError` is raised (the caller keeps its State);
an unconverged result is kept and reported. `Solver.steps(state, control, n)` takes up to n
steps in one compiled call (`step.steps`), bit-identical; clean=True also stops before any
warning (sim_node). `World.step()` runs `step.step_resident` through `_step_resident`.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import SimulationError
from ..state import Control, State
from ..terms import TERMS, angle, prismatic, reference_shape
from ..terms.damping import axis_inertia
from ..terms.context import StepContext
from ..terms.revolute import SEPARATION_FAULT, SEPARATION_WARN, joint_separation
from ..terms.torque import SINGULAR_RATIO
from . import model_data, newton, step as compiled, workspace
from .report import STATUS_BY_CODE, Status, StepReport
from .resident import Resident

# Rotation per step above which the integrator's numerical damping of it is reported
# (measured on the free-spinning reference hinge, loss of angular speed per step).
ACCURACY_ROTATION = {'bdf1': 0.1, 'bdf2': 0.3}
ACCURACY_NOTE = {
    'bdf1': 'implicit Euler (bdf1) damps rotation this fast (measured: ~0.9 % of the speed per '
            'step at 0.1 rad/step, ~5 % at 0.3): reduce dt or use bdf2 for accuracy',
    'bdf2': 'bdf2 damps rotation this fast (measured: ~0.1 % of the speed per step at 0.3 '
            'rad/step, ~1 % at 0.6): reduce dt for accuracy'}


#: [bytes] the states of one compiled batch (Solver.steps): within a core's L2 cache
BATCH_BYTES = 1 << 20
_CONVERGED, _new_tuple = Status.CONVERGED, tuple.__new__
_OUT_ROTATION, _OUT_SEPARATION = compiled.OUT_ROTATION, compiled.OUT_SEPARATION
_KEPT_WITH_WARNINGS = compiled.KEPT_WITH_WARNINGS
_NONFINITE = {compiled.FAIL_NEWTON_NONFINITE: 'Newton produced a non-finite state',
              compiled.FAIL_STEP_NONFINITE: 'step produced a non-finite state'}

#: dtypes of Control's arrays as the compiled entries are called with them
CONTROL_DTYPES = (np.dtype(np.float64), np.dtype(np.bool_), np.dtype(np.float64), np.dtype(np.bool_),
                  np.dtype(np.bool_))


def _compiled_layout(arrays) -> bool:
    """Whether Control's arrays are C-contiguous, aligned, writable, 1-d, CONTROL_DTYPES."""
    return all(type(a) is np.ndarray and a.flags.c_contiguous and a.flags.aligned and a.flags.writeable
               and a.ndim == 1 and a.dtype == d for a, d in zip(arrays, CONTROL_DTYPES))


def _entry_point(dispatcher, args):
    """The compiled entry point of `dispatcher` for the types of `args`, or None."""
    try:
        return dispatcher.overloads[tuple(dispatcher.typeof_pyval(a) for a in args)].entry_point
    except (AttributeError, KeyError, TypeError):
        return None


@dataclass(frozen=True)
class Steps:
    """Result of `Solver.steps`."""

    count: int
    state: State                #: after the last step (the input state if count is 0)
    report: StepReport | None   #: of the last step (None if count is 0)
    times: list                 #: [s] (count,) time after each step
    joint_angles: np.ndarray    #: [rad] (count, J)
    joint_velocities: np.ndarray  #: [rad/s] (count, J)
    q: np.ndarray               #: (count, B, 12) body states after each step (read only)


@dataclass(slots=True)
class _Tally:
    """A StepReport being filled over the sub-steps of one step."""

    status: Status = Status.CONVERGED
    converged: bool = True
    newton_iterations: int = 0
    line_search_iterations: int = 0
    substeps: int = 1
    max_joint_separation: float = 0.0
    max_step_rotation: float = 0.0
    warnings: list = field(default_factory=list)
    overloaded: bool = False        #: a joint beyond its warning separation

    def freeze(self, time) -> StepReport:
        return StepReport(time, self.status, self.converged, self.newton_iterations,
                          self.line_search_iterations, self.substeps, self.max_joint_separation,
                          self.max_step_rotation, tuple(self.warnings))


def _history(s: State, h: float, new_warm_start):
    """(warm_start_prev, warm_start_prev2) after a step of size h from s with correction
    new_warm_start: s's own, where s came from a step of size h; an unknown one is the same
    array as the newer one (as `step.steps` does)."""
    if s.history_dt != h:
        return new_warm_start, new_warm_start
    if s.warm_start_prev is s.warm_start:
        return s.warm_start, s.warm_start
    return s.warm_start, s.warm_start_prev


def _clean_report_of(time, newton_iterations, halvings, separation, rotation) -> StepReport:
    """The StepReport of a clean step, built with tuple.__new__ (the NamedTuple's __new__
    costs ~0.4 µs more per one-step call)."""
    return _new_tuple(StepReport, (time, _CONVERGED, True, newton_iterations, halvings, 1, separation,
                                   rotation if rotation > 0.0 else 0.0, ()))


class Solver:
    """The compiled step of one Model."""

    def __init__(self, model, force_dense: bool = False):
        """`force_dense`: solve Newton's system densely whatever its structure (for tests)."""
        self.model = model
        self.data = model_data.build(model, force_dense)    # ValueError for an unsupported loop
        self.work = workspace.build(model, self.data)
        B, J = model.body_count, model.joint_count
        self._skipped = np.zeros(max(2 * len(model.torque_joints), 1), dtype=np.int64)
        self._outcomes = np.zeros((1, compiled.OUT_COLUMNS))  # a step's outcome row (_compute)
        self._outcome = self._outcomes[0]                   # (and step_resident's)
        self._outcome_view = memoryview(self._outcome)      # (step_resident's report)
        self._clean_rotation = min(model.newton.max_step_rotation, ACCURACY_ROTATION[model.integrator])
        self._keep_rotation = float(model.newton.max_step_rotation)     # (step.kept)
        self._shape = (B, J)
        #: steps per compiled batch in `steps`: their states fill about BATCH_BYTES
        self.batch_limit = max(2, BATCH_BYTES // (8 * (3 * B * 12 + 2 * J + compiled.OUT_COLUMNS)))
        self._resident_entry = None     # step_resident's compiled entry point (_bind)
        self._entry = None              # and steps' (_run), the arrays the last call made
        self._made = (None,) * 8
        self._control = (None,) * 5     # and Control arrays checked for it
        self._bdf2 = model.integrator == 'bdf2'
        self._dt = model.dt
        self._may_split = model.newton.max_substep_depth > 0
        # the terms this model uses (energy terms, then forces), named as in World.terms
        self.terms = tuple(term.NAME for term in TERMS if term.NAME and term.used(model))

    def context(self, state: State, control: Control, h: float, q_tilde=None) -> StepContext:
        """The BDF1 StepContext of a step from `state` (q̃ = state.q unless given) for the
        energy functions called from Python (World.mechanical_energy, tests)."""
        m = self.model
        start = state.joint_angle - m.joint_init_angle
        drives = np.concatenate([m.drive_joints, m.prismatic_drive_joints])     # UID 19, then UID 21
        init = m.joint_init_angle[drives]
        target = np.where(control.drive_passive, start[drives], control.drive_aim - init)
        return StepContext(float(h), 1.0, state.q if q_tilde is None else q_tilde, start,
                           np.ascontiguousarray(target, dtype=float),
                           np.ascontiguousarray(control.drive_enabled, dtype=bool),
                           np.empty(angle.ANGLE_WORK_SHAPE),
                           self._angle_ref(state, start, h))

    def _angle_ref(self, state: State, start, h):
        """StepContext.angle_ref of a BDF1 step from `state` (the dampers linearised there)."""
        return newton.references(self.data, state.q, state.q_prev, start, float(h), False,
                                 np.empty(angle.ANGLE_WORK_SHAPE),
                                 np.empty(reference_shape(self.model)))

    # -- one step, with recovery ---------------------------------------------------------
    def step(self, state: State, control: Control) -> tuple[State, StepReport]:
        """One step of dt; raises SimulationError when even sub-steps cannot finish it."""
        h = self.model.dt
        computed = self._compute(state, control, h, self._may_split)
        clean = self._clean_report(computed[2], state.time + h)      # (a few µs less)
        if clean is not None:
            return self._state(state, h, computed[0], computed[1]), clean
        return self._recovered(state, control, computed)

    def _step_resident(self, r: Resident, control: Control) -> StepReport:
        """`step` on the state a Resident holds (World.step()), the same bits: a clean step
        of `step.step_resident` only turns r's ring slots; any other goes through `step`'s
        recovery and sets its State on r. On SimulationError r keeps the last good state."""
        if r._state is not None:            # (load's own test, without the call)
            r.load()
        c = control
        k = r.io_key
        if not (k and k[0] is self and k[1] is c.torque_value and k[2] is c.torque_enabled
                and k[3] is c.drive_aim and k[4] is c.drive_enabled and k[5] is c.drive_passive):
            self._bind(r, c)
        call, args = r.io_call
        code = call(*args)
        if code:                            # clean or kept (step.kept): the Resident has advanced
            r._state = None
            if code == _KEPT_WITH_WARNINGS:
                return self._kept_report(self._outcome, r.clock.item(0), r.ring[r.cur, 0])
            if code < 0:                    # (line-search halvings: read from the row)
                return self._report(self._outcome, r.clock.item(0))
            o = self._outcome_view          # (code: Newton iterations; a memoryview: ~0.2 µs less)
            return _clean_report_of(r.clock_view[0], code, 0, o[_OUT_SEPARATION], o[_OUT_ROTATION])
        state, k = r.state(), (r.cur + 1) % 4
        computed = ((r.ring[k, 0].copy(), r.ring[k, 1].copy(), r.ring[k, 2].copy()),
                    (r.angles[k, 0].copy(), r.angles[k, 1].copy()), self._outcome)
        new, report = self._recovered(state, control, computed)
        r.set(new)
        return report

    def _bind(self, r: Resident, c: Control) -> None:
        """Bind r to c's arrays and this Solver's rows (Resident.bind), and to step_resident's
        entry point (no typing: ~0.65 µs less per structref) when c's arrays have the compiled
        layout (the key's last item); others go through the dispatcher."""
        arrays = (c.torque_value, c.torque_enabled, c.drive_aim, c.drive_enabled, c.drive_passive)
        standard = _compiled_layout(arrays)
        io = r.bind((self,) + arrays + (standard,), c, skipped=self._skipped, outcome=self._outcome,
                    model=self.data, work=self.work, h=float(self._dt), bdf2=bool(self._bdf2),
                    may_split=bool(self._may_split), clean_rotation=float(self._clean_rotation),
                    keep_rotation=self._keep_rotation)
        if standard and self._resident_entry is None:
            self._resident_entry = _entry_point(compiled.step_resident, (io,))
        call = self._resident_entry if standard and self._resident_entry is not None else compiled.step_resident
        r.io_call = (call, (io,))

    def _clean_report(self, out, time):
        """The StepReport of a step whose outcome row `out` is clean (`step.clean`), else None."""
        return self._report(out, time) if compiled.clean(out, self._clean_rotation) else None

    @staticmethod
    def _report(out, time):
        """The StepReport of a clean step from its outcome row."""
        _, newton_its, halvings, rotation, _, _, separation, _, _ = out.tolist()
        return _clean_report_of(time, int(newton_its), int(halvings), separation, rotation)

    def _recovered(self, state, control, computed) -> tuple[State, StepReport]:
        """(the State, the report) of a step of dt from `state` whose first try is `computed`
        (`_compute`), with sub-steps where it needs them, and its end warnings."""
        tally = _Tally()
        new = self._recover(state, control, self._dt, 0, tally, computed)
        tally.warnings += self._end_warnings(new.q, new.time, tally.overloaded, tally.max_step_rotation)
        return new, tally.freeze(new.time)

    def _recover(self, state, control, h, depth, tally, computed=None):
        max_depth = self.model.newton.max_substep_depth
        if computed is None:
            computed = self._compute(state, control, h, depth < max_depth)
        new_state, failure = self._decode(state, h, *computed, tally)
        if failure is None:
            return new_state
        if depth < max_depth:
            tally.status, tally.converged = Status.CONVERGED, True
            tally.warnings.append(f't={state.time:.6g}s: {failure}; retrying as 2 sub-steps of {h / 2:.3g}s')
            tally.substeps += 1
            half = self._recover(state, control, h / 2, depth + 1, tally)
            return self._recover(half, control, h / 2, depth + 1, tally)
        if new_state is None:       # not finite, or a joint came apart: nothing to keep
            raise SimulationError(f't={state.time:.6g}s: {failure} even with {2 ** depth} sub-steps of '
                                  f'{h:.3g}s; state kept at the last good step{self._drive_hint(state, control)}'
                                  f'{self._torque_hint(control)}')
        tally.warnings.append(f't={state.time:.6g}s: {failure} with {2 ** depth} sub-steps; result kept')
        return new_state

    def _drive_hint(self, state, control) -> str:
        """Why a failed step may be a drive's doing: an active drive whose aim is more than
        max_step_rotation from its joint's angle (UID 19 pulls onto the aim within a step,
        sub-steps do not help)."""
        m = self.model
        limit = m.newton.max_step_rotation
        far = []
        for k, j in enumerate(m.drive_joints):
            if control.drive_enabled[k] and not control.drive_passive[k]:
                gap = float(control.drive_aim[k] - state.joint_angle[j])
                if not abs(gap) <= limit:
                    far.append(f'{m.joint_names[j]!r} (aim {control.drive_aim[k]:.3g} rad, '
                               f'angle {state.joint_angle[j]:.3g} rad)')
        if not far:
            return ''
        return (f'. The drive of joint(s) {", ".join(far)} asks for more than max_step_rotation = '
                f'{limit:.3g} rad in one step: a drive reaches its aim within a step or two, so move '
                'the aim in smaller increments over several steps')

    def joint_rates(self, state: State) -> np.ndarray:
        """[rad/s] (J,) θ̇ = ∇θ(q)·v of a state's bodies (step.joint_rates), as a step does."""
        m = self.model
        out = np.empty((2, m.joint_count))
        compiled.joint_rates(self.data, state.q, state.v, self.work.zero,
                             state.joint_angle - m.joint_init_angle, m.dt, out, self.work.angle_work)
        return out[1].copy()

    def axis_inertia(self, j: int) -> float:
        """[kg m²] terms/damping.py axis_inertia of joint j."""
        return axis_inertia(self.model, j)

    def _torque_hint(self, control) -> str:
        """Why a failed step may be a torque's doing: the joint whose torque turns its lighter
        body the most in one step from rest, ½ (τ/I) dt² (an upper bound), above the accuracy
        threshold."""
        m = self.model
        worst, who = 0.0, None
        for k, j in enumerate(m.torque_joints):
            tau = abs(float(control.torque_value[k])) if control.torque_enabled[k] else 0.0
            if tau > 0.0:
                turn = 0.5 * tau / self.axis_inertia(int(j)) * m.dt ** 2
                if turn > worst:
                    worst, who = turn, (int(j), tau)
        if who is None or not worst > ACCURACY_ROTATION[m.integrator]:
            return ''
        j, tau = who
        return (f'. The torque of joint {m.joint_names[j]!r} ({tau:.3g} N m on a body of '
                f'{self.axis_inertia(j):.3g} kg m^2 about the axis) alone turns it {worst:.3g} rad '
                f'in one step of {m.dt:.3g} s from rest: lower the torque or dt')

    def _compute(self, s, c, h, may_split):
        """One compiled (sub-)step of size h from s: ((q, v, warm_start) (B,12) each, (angle,
        velocity) (J,) each, outcome row)."""
        _, _, aw = self._run(s, c, h, 1, may_split, self._keep_rotation, self._outcomes)
        made = self._made                   # (the same view objects: _run's check is by identity)
        return (made[0], made[1], made[4]), (made[5], aw[0, 1]), self._outcome

    def _run(self, s, c, h, n, may_split, keep_rotation, out):
        """`step.steps` from s under c: (count, qvw (n,3,B,12), aw (n,2,J)), outcome rows in
        out. Where s's arrays are those the last call made (`_made`) and c's are checked, the
        entry point is called without the dispatcher's typing of 28 arguments (`Solver.step`,
        one link: 6.8 µs per call, 9.4 through the dispatcher; KUKA iiwa 15.2 and 17.7; 2-core
        VM, loaded, side by side); it would misread another layout, so others go through it."""
        B, J = self._shape
        qvw, aw = np.empty((n, 3, B, 12)), np.empty((n, 2, J))
        uniform = s.history_dt == h
        args = (self.data, s.q, s.v, s.q_prev, s.v_prev, s.warm_start, s.warm_start_prev, s.warm_start_prev2,
                s.joint_angle, c.torque_value, c.torque_enabled, c.drive_aim, c.drive_enabled,
                c.drive_passive, h, self._bdf2 and uniform, self._bdf2, uniform, s.extrapolation_order(h),
                may_split, n, self._clean_rotation, keep_rotation, self.work, qvw, aw, self._skipped, out)
        k = self._made
        w, p1, p2 = s.warm_start, s.warm_start_prev, s.warm_start_prev2
        if (s.q is k[0] and s.v is k[1] and s.q_prev is k[2] and s.v_prev is k[3]
                and w is k[4] and (p1 is k[4] or p1 is k[6])
                and (p2 is k[4] or p2 is k[6] or p2 is k[7])
                and s.joint_angle is k[5] and self._control_checked(c)):
            if self._entry is None:
                self._entry = _entry_point(compiled.steps, args)
            count = (self._entry or compiled.steps)(*args)
        else:
            count = compiled.steps(*args)
        # the arrays of the state after the first step (or, as history, of the steps before);
        # indexed once: each qvw[0, 0] is a new view object, and the check is by identity
        self._made = (qvw[0, 0], qvw[0, 1], s.q if s.q is k[0] else None, s.v if s.v is k[1] else None,
                      qvw[0, 2], aw[0, 0], w if w is k[4] else None,
                      p1 if (p1 is k[4] or p1 is k[6]) else None)
        return count, qvw, aw

    def _control_checked(self, c) -> bool:
        """Whether c's arrays have the compiled layout (checked again when one is replaced)."""
        arrays = (c.torque_value, c.torque_enabled, c.drive_aim, c.drive_enabled, c.drive_passive)
        known = self._control
        if (arrays[0] is known[0] and arrays[1] is known[1] and arrays[2] is known[2]
                and arrays[3] is known[3] and arrays[4] is known[4]):
            return True
        self._control = arrays if _compiled_layout(arrays) else (None,) * 5
        return self._control is arrays

    def _state(self, s, h, qvw, aw):
        """The State after a step from s."""
        return State(s.time + h, qvw[0], qvw[1], s.q, s.v, aw[0],
                     aw[1] if self._shape[1] else s.joint_velocity, s.step_count + 1, h, qvw[2],
                     *_history(s, h, qvw[2]))

    def _decode(self, s, h, qvw, aw, out, tally):
        """(the new State or None, None or why the step needs sub-steps), counted into tally."""
        m = self.model
        skipped = int(out[compiled.OUT_SKIPPED])
        if skipped:
            tally.warnings += self._skipped_warnings(skipped)
        failure = int(out[compiled.OUT_FAILURE])
        rotation, limit = float(out[compiled.OUT_ROTATION]), m.newton.max_step_rotation
        if failure == compiled.FAIL_PREDICTED_ROTATION:
            return None, (f'a joint is predicted to turn {rotation:.3g} rad in one step '
                          f'(limit {limit:.3g})')
        tally.newton_iterations += int(out[compiled.OUT_NEWTON])
        tally.line_search_iterations += int(out[compiled.OUT_LINE_SEARCH])
        if failure in _NONFINITE:
            return None, _NONFINITE[failure]
        if failure == compiled.FAIL_JOINT_APART:
            j = int(out[compiled.OUT_APART_JOINT])
            apart = self.joint_separation(qvw[0], j)[0]
            return None, (f'joint {m.joint_names[j]!r} came apart: anchors {apart:.3g} m apart '
                          f"(> {SEPARATION_FAULT:g} x the bodies' size)")
        tally.max_step_rotation = max(tally.max_step_rotation, rotation)
        tally.max_joint_separation = float(out[compiled.OUT_SEPARATION])
        tally.overloaded = bool(out[compiled.OUT_OVERLOADED])
        new = self._state(s, h, qvw, aw)
        if rotation > limit:
            return new, f'a joint turned {rotation:.3g} rad in one step (limit {limit:.3g})'
        status = STATUS_BY_CODE[int(out[compiled.OUT_STATUS])]
        if status is not Status.CONVERGED:
            tally.status, tally.converged = status, False
            return new, f'Newton stopped: {status.value} after {int(out[compiled.OUT_NEWTON])} iterations'
        return new, None

    def joint_separation(self, q, j) -> tuple:
        """(separation [m], its warning threshold [m]) of joint j at body states q: UID 18's
        anchor distance, or UID 20's axis offset (terms/prismatic.py)."""
        k = int(self.data.prismatic_slot[j])
        if k >= 0:
            return float(prismatic.joint_separation(q, self.data, j)), float(self.data.prismatic_warn_separation[k])
        return float(joint_separation(q, self.data, j)), float(self.data.joint_warn_separation[j])

    def _skipped_warnings(self, count) -> list:
        """The warnings of a step whose torque skipped `count` bodies (listed in _skipped)."""
        names = self.model.body_names
        return [f'body {names[b]!r}: affine matrix near-singular (|det A|/(|a1||a2||a3|) < '
                f'{SINGULAR_RATIO}); joint torque not applied' for b in self._skipped[:count].tolist()]

    def _end_warnings(self, q, time, overloaded, rotation) -> list:
        """The overloaded-joint and accuracy warnings of a step ending at `time` with q."""
        m, out = self.model, []
        if overloaded:
            for j in range(m.joint_count):
                sep, warn = self.joint_separation(q, j)
                if sep > warn:
                    out.append(f't={time:.6g}s: joint {m.joint_names[j]!r} anchors {sep:.3g} m apart '
                               f'(> {SEPARATION_WARN:.0%} of the smaller body): the joint is overloaded; '
                               'lower the torque or dt, or raise strength_ratio')
        if rotation > ACCURACY_ROTATION[m.integrator]:
            out.append(f't={time:.6g}s: a joint turned {rotation:.3g} rad in one step; '
                       f'{ACCURACY_NOTE[m.integrator]}')
        return out

    def _kept_report(self, out, time, q) -> StepReport:
        """The report of a step kept with warnings (step.kept): `_decode` and `_recovered`'s."""
        _, its, halvings, rotation, _, skipped, separation, overloaded, _ = out.tolist()
        rotation = rotation if rotation > 0.0 else 0.0
        warnings = self._skipped_warnings(int(skipped)) if skipped else []
        warnings += self._end_warnings(q, time, overloaded, rotation)
        return _new_tuple(StepReport, (time, _CONVERGED, True, int(its), int(halvings), 1, separation,
                                       rotation, tuple(warnings)))

    # -- several steps -------------------------------------------------------------------
    def steps(self, state: State, control: Control, n: int, clean: bool = False) -> Steps:
        """Up to n steps in one compiled call, bit-identical to `count` calls of `step`. By
        default at least one and at most `batch_limit` (every state is written): steps that
        only warn stay in (only the last report is returned); one that needs sub-steps ends
        the batch, or goes through `step` if first (which may raise SimulationError).
        clean=True (sim_node): stops before any step that would sub-step, warn or fail."""
        if not clean:
            n = min(n, self.batch_limit)
            if n <= 1:
                return self._one(state, control)
        out = np.empty((n, compiled.OUT_COLUMNS))
        count, qvw, aw = self._run(state, control, self._dt, int(n), self._may_split,
                                   -1.0 if clean else self._keep_rotation, out)
        if count == 0 and not clean:
            return self._one(state, control)
        if count == 0:
            return Steps(0, state, None, [], aw[:0, 0], aw[:0, 1], qvw[:0, 0])
        s, h = state, self._dt
        acc = np.full(count + 1, h)     # t + h + h ... in order: `step`'s bits, 1/6 of a loop
        acc[0] = s.time
        np.add.accumulate(acc, out=acc)
        times = acc[1:].tolist()
        t = times[-1]
        k = count - 1
        J = self.model.joint_count
        w = qvw[k, 2]
        if k == 0:
            prev, prev2 = _history(s, h, w)
        else:                       # the state before it is this batch's
            prev = qvw[k - 1, 2]        # two back: that state's own warm_start_prev
            prev2 = qvw[k - 2, 2] if k >= 2 else _history(s, h, prev)[0]
        state = State(time=t, q=qvw[k, 0], v=qvw[k, 1],
                      q_prev=qvw[k - 1, 0] if k else s.q, v_prev=qvw[k - 1, 1] if k else s.v,
                      joint_angle=aw[k, 0], joint_velocity=aw[k, 1] if J else s.joint_velocity,
                      step_count=s.step_count + count, history_dt=h, warm_start=w,
                      warm_start_prev=prev, warm_start_prev2=prev2)
        o = out[k]
        report = self._clean_report(o, t)
        if report is None:          # (kept: it only warns)
            report = self._kept_report(o, t, state.q)
        return Steps(count, state, report, times, aw[:count, 0], aw[:count, 1], qvw[:count, 0])

    def _one(self, state, control) -> Steps:
        new, report = self.step(state, control)
        return Steps(1, new, report, [new.time], new.joint_angle[None], new.joint_velocity[None], new.q[None])
