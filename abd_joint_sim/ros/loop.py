"""The simulation loop of sim_node and of the headless tools (run_headless, replay_check).

:class:`SimLoop` owns the ``World``, the :class:`~.commands.CommandBuffer`, the publishing
and marker schedules, the fault state and the diagnostics values. Commands take effect at a
step boundary; the command timeout acts at the first boundary at or after it expires; after
every step go ``/clock``, the markers and the joint state when due; a failed step or a
non-finite state stops the loop (a fault) before anything non-finite is published. Clean
steps go in batches (``World.step(n, trajectory)``) up to the next boundary that needs the
world (a command timeout, headless diagnostics), bit-identical to single steps
(docs/decisions.md). Where messages go is the :class:`LoopOutput`'s business. No rclpy here.
"""
from __future__ import annotations

import bisect
import math
from typing import Any, Mapping, Optional

import numpy as np

from . import convert
from .commands import Applied, CommandBuffer
from .markers import MarkerBuilder
from .params import coerce, NODE_NAME, SimConfig, world_dt
from .recording import PublishSchedule, RECORDED_PARAMETERS
from .topics import TOPIC_ENABLE_JOINT

DIAGNOSTIC_KEYS = (
    'sim_time', 'steps', 'paused', 'time_step', 'real_time_factor_requested',
    'real_time_factor_achieved', 'newton_iterations', 'line_search_iterations', 'converged',
    'not_converged_steps_total', 'max_joint_separation', 'substeps', 'recording', 'fault',
    'recording_error')
"""The values of the node's ``/diagnostics`` status, in order (docs/topics.md)."""

MAX_BATCH = 256
"""Most clean steps per batch (bounds the arrays of its Trajectory)."""


class LoopOutput:
    """Where the loop's results go (the node's publishers and recorder, a headless bag, the
    replay checker). Every method is a no-op here; override what you need."""

    markers_wanted = False
    """Build the body markers (someone subscribes, or the run is recorded)."""
    every_state = False
    """Hand over the joint state after every step, not only when ``publish_rate`` says."""
    world_each_step = False
    """`stepped` reads the world itself after every step: no batching."""
    markers_serialized = False
    """`markers` gets CDR bytes (``MarkerBuilder.build_serialized``), not a message."""

    def clock(self, t_ns: int) -> None:
        """After every step (and at start, reset and a forced publish)."""

    def clocks(self, stamps_ns: list) -> None:
        """`clock` for each of a run of a batch's steps that publish nothing else."""
        for t_ns in stamps_ns:
            self.clock(t_ns)

    def joint_state(self, t_ns: int, position: list, velocity: list, effort: list) -> None:
        """The joint state at `t_ns` when due (finite, plain floats)."""

    def markers(self, t_ns: int, msg: Any) -> None:
        """The body markers when due (only while `markers_wanted`): a MarkerArray, or its
        CDR bytes with `markers_serialized`."""

    def applied(self, applied: Applied) -> None:
        """Commands as they took effect at a step boundary."""

    def restarted(self) -> None:
        """Simulated time restarts at 0 (reset), before the reset's state is published."""

    def parameters(self, t_ns: int, changes: Mapping[str, Any]) -> None:
        """Live parameter changes (recorded ones) in force from `t_ns` on."""

    def diagnostics(self, t_ns: int) -> None:
        """Simulated-time diagnostics are due (only with ``diagnostics_period_ns``)."""

    def stepped(self, t_ns: int, force: bool) -> None:
        """After the above, once per step or forced publish."""

    def batch_begin(self) -> None:
        """Before a batch's outputs (its /clock may be held back until anything else or
        `batch_end`)."""

    def batch_end(self) -> None:
        """After a batch's outputs, also when one of them raised."""

    def log(self, level: str, text: str, key: Any = None) -> None:
        """A message for a person; `key` set: throttle repeats of this kind."""

    def faulted(self, why: str) -> None:
        """The loop stopped on a fault (already paused and logged)."""


class SimLoop:
    """A World stepped with sim_node's rules; see the module docstring.

    :param clamp: apply the ``effort_limits`` parameter (False when the commands come from a
        bag, stored already clamped).
    :param raise_faults: re-raise a failed step (headless tools) instead of pausing (node).
    :param diagnostics_period_ns: > 0: diagnostics are due on this grid of simulated time
        (headless runs); 0: the caller times them.
    """

    def __init__(self, scene: Any, config: SimConfig, output: Optional[LoopOutput] = None,
                 clamp: bool = True, raise_faults: bool = False, paused: bool = False,
                 diagnostics_period_ns: int = 0):
        from abd_joint_sim.world import Trajectory, World
        self.scene = scene
        self.config = config
        self.output = output if output is not None else LoopOutput()
        self.world = World(scene, dt=world_dt(config.time_step))
        self.joint_names = list(self.world.joint_names)
        self.actuated = list(self.world.actuated_joint_names)
        self.clamp = clamp
        self.commands = CommandBuffer(
            self.actuated, config.joints, config.effort_limits if clamp else [],
            config.command_timeout,
            scene_limits=dict(zip(self.actuated, self.world.effort_limits.tolist())),
            driven=[j.name for j in getattr(scene, 'joints', ())
                    if getattr(j, 'driving', None) is not None])
        config.joints = list(self.commands.order)
        self.markers = (MarkerBuilder(scene, config.marker_frame_id, config.marker_joint_axes)
                        if config.marker_rate > 0.0 else None)
        # the marker bodies' rows in a batch's Trajectory.q: a batch need not end at a marker
        self._marker_rows = (None if self.markers is None else np.array(
            [self.world.model.body_names.index(n) for n in self.markers.body_names],
            dtype=np.intp))
        self.publish_schedule = PublishSchedule()
        self.marker_schedule = PublishSchedule()
        self.raise_faults = raise_faults
        self.diagnostics_period_ns = int(diagnostics_period_ns)
        self.next_diagnostics_ns = self.diagnostics_period_ns
        self.paused = bool(paused)
        self.fault: Optional[str] = None
        """Why stepping stopped (a failed step, a non-finite state); None while healthy."""
        self.steps = 0
        self.not_converged = 0
        self._trajectory = Trajectory()     # the rows of each batch (World.step)
        self._warned_disabled: set[str] = set()

    @property
    def time_ns(self) -> int:
        return convert.seconds_to_ns(self.world.time)

    # ------------------------------------------------------------------- stepping ----
    def advance(self, n: int, force_publish: bool = False) -> int:
        """Up to `n` steps: pending commands at each boundary that can have any, clean steps
        in batches, the rest one at a time. Stops early on a pause or a fault. Returns the
        number of steps taken."""
        taken = 0
        while taken < n and not self.paused:
            self.apply_commands()
            limit = self._batch_limit(n - taken) if not force_publish else 1
            if limit >= 2:
                self.world.step(limit, self._trajectory)
                count = self._trajectory.count
                if count:
                    self._after_batch(self._trajectory)
                    taken += count
                    if count == limit or self.paused:
                        continue
                    self.apply_commands()       # (nothing can be pending: cheap)
                # The step that was not clean: sub-steps, warnings or a failure.
            if not self._step_single(force_publish):
                break
            taken += 1
        return taken

    def _batch_limit(self, remaining: int) -> int:
        """Steps the next batch may take: up to the next command timeout or diagnostics."""
        if remaining < 2 or self.output.world_each_step:
            return 1
        limit = min(remaining, MAX_BATCH)
        dt = self.world.dt
        now = self.world.time
        expiry = self.commands.next_timeout()
        if expiry < math.inf:
            # Boundaries strictly inside the batch are skipped: all before the expiry
            # (one step to spare against rounding of the accumulated time).
            limit = min(limit, max(1, int((expiry - now) / dt - 1e-6)))
        dt_ns = max(1, convert.seconds_to_ns(dt))
        now_ns = convert.seconds_to_ns(now)
        if self.diagnostics_period_ns:
            ahead = self.next_diagnostics_ns - now_ns
            limit = min(limit, max(1, -(-ahead // dt_ns)))
        return limit

    def apply_commands(self) -> Applied:
        """Apply pending commands (and the command timeout) at this step boundary."""
        applied = self.commands.apply(self.world)
        if applied:
            self._on_applied(applied)
        return applied

    def step_once(self, force_publish: bool = False) -> bool:
        """Apply pending commands, take one step, publish. False on a fault."""
        self.apply_commands()
        return self._step_single(force_publish)

    def _step_single(self, force_publish: bool) -> bool:
        try:
            report = self.world.step()
        except Exception as exc:  # noqa: BLE001 - keep the node alive, say why, pause
            if self.raise_faults:
                raise
            self.stop_on_fault(
                f'step at t={self.world.time:.6f} s failed: {type(exc).__name__}: {exc}')
            return False
        self.fault = None
        self.steps += 1
        if not report.converged:
            self.not_converged += 1
            self.output.log('warn', f'Newton did not converge at t={self.world.time:.6f} s '
                            f'({report.newton_iterations} iterations)', key='not converged')
        for text in report.warnings:
            self.output.log('warn', f'step: {text}', key='step warning')
        self.publish_state(force=force_publish)
        return self.fault is None

    def _after_batch(self, batch) -> None:
        count, times = batch.count, batch.times
        angles, velocities, states = batch.positions, batch.velocities, batch.q
        self.fault = None
        self.steps += count
        last = count - 1
        out = self.output
        stamps = self._batch_stamps(times)
        # the efforts of every joint state in the batch: no command changes inside it
        effort = np.asarray(self.world.applied_efforts(), dtype=float).tolist()
        out.batch_begin()
        try:
            i = 0
            while i < count:
                # steps that publish only /clock: one `clocks` call
                k = self._next_busy_step(stamps, i) if stamps is not None else i
                if k > i:
                    out.clocks(stamps[i:k])
                    i = k
                    if i == count:
                        break
                self.publish_state(t=times[i], position=angles[i], velocity=velocities[i],
                                   current=i == last, states=states[i], effort=effort)
                if self.fault:              # the publish guard stopped it: say so once
                    break
                i += 1
        finally:
            out.batch_end()

    def _batch_stamps(self, times: list) -> Optional[list]:
        """The batch's stamps [ns] as `publish_state` rounds them, or None when every step
        goes through `publish_state` anyway (a joint state after every step, an output that
        reads the world after every step, a non-finite time for its guard to report)."""
        out = self.output
        if (out.every_state or self.config.publish_rate <= 0.0
                or type(out).stepped is not LoopOutput.stepped):
            return None
        stamps = np.rint(np.asarray(times, dtype=float) * convert.NS_PER_S)
        if not np.isfinite(stamps).all():
            return None
        return stamps.astype(np.int64).tolist()     # = round(t * NS_PER_S) of each

    def _next_busy_step(self, stamps: list, i: int) -> int:
        """The first step from `i` on at which `publish_state` publishes more than /clock
        (a joint state, markers or diagnostics due); len(stamps) if none."""
        k = bisect.bisect_left(stamps, self.publish_schedule.next_ns, i)
        if self.markers is not None:
            k = min(k, bisect.bisect_left(stamps, self.marker_schedule.next_ns, i))
        if self.diagnostics_period_ns:
            k = min(k, bisect.bisect_left(stamps, self.next_diagnostics_ns, i))
        return k

    def _on_applied(self, applied: Applied) -> None:
        for joint in applied.timed_out:
            self.output.log('warn', f'joint {joint!r}: no torque command for '
                            f'{self.commands.command_timeout:g} s (simulated) -> torque set '
                            'to 0 until the next command')
        for joint, value in applied.torques.items():
            if value != 0.0 and not self.world.effort_enabled(joint) \
                    and joint not in self._warned_disabled:
                self._warned_disabled.add(joint)
                sliding = self.world.joint_types[self.joint_names.index(joint)] == 'prismatic'
                what, unit = ('force', 'N') if sliding else ('torque', 'N m')
                # Throttled too: a sender toggling the enable would re-arm it each time.
                self.output.log(
                    'warn', f'joint {joint!r}: {what} {value:g} {unit} stored but the {what} is '
                    f'disabled; publish true on {TOPIC_ENABLE_JOINT.format(joint=joint)} to '
                    'apply it', key=('disabled', joint))
        for joint, flag in applied.enables.items():
            if flag:
                self._warned_disabled.discard(joint)
        self.output.applied(applied)

    def stop_on_fault(self, why: str) -> None:
        """Pause and say why (the output publishes diagnostics and flushes the bag)."""
        self.fault = why
        self.paused = True
        if self.raise_faults:
            from abd_joint_sim.errors import SimulationError
            raise SimulationError(why)
        self.output.log('error', f'{why}; simulation paused, nothing non-finite was published '
                        'or recorded (call ~/reset, or ~/unpause to retry)')
        self.output.faulted(why)

    # ------------------------------------------------------------------ publishing ----
    def publish_state(self, force: bool = False, t: Optional[float] = None,
                      position=None, velocity=None, current: Optional[bool] = None,
                      states=None, effort: Optional[list] = None) -> None:
        """/clock after every step, markers and the joint state when due; never a non-finite
        value. A batch passes each step's time, joint positions and velocities, whether it
        is the world's current step, its body states (B, 12) and the efforts (a list, the
        same for the whole batch)."""
        out = self.output
        if t is None:
            t = self.world.time
        if not math.isfinite(t):
            self.stop_on_fault(f'non-finite time {t!r} s not published')
            return
        t_ns = int(round(float(t) * convert.NS_PER_S))       # convert.seconds_to_ns
        if current is None:
            current = position is None or t == self.world.time
        out.clock(t_ns)
        if self.markers is not None and (current or states is not None) and (
                force or t_ns >= self.marker_schedule.next_ns):   # (the schedule's own test)
            self._markers(t_ns, force, states)
        schedule = self.publish_schedule
        # (PublishSchedule.due's own test first: most steps publish no joint state)
        if (force or t_ns >= schedule.next_ns or out.every_state
                or self.config.publish_rate <= 0.0):
            self._joint_state(t, t_ns, force, position, velocity, effort)
        if self.diagnostics_period_ns:
            if force:               # start or reset: the diagnostics grid restarts too
                self.next_diagnostics_ns = t_ns + self.diagnostics_period_ns
            elif t_ns >= self.next_diagnostics_ns:
                self.next_diagnostics_ns = t_ns + self.diagnostics_period_ns
                out.diagnostics(t_ns)
        if type(out).stepped is not LoopOutput.stepped:     # (most outputs have none)
            out.stepped(t_ns, force)

    def _joint_state(self, t: float, t_ns: int, force: bool, position, velocity,
                     effort: Optional[list] = None) -> None:
        out = self.output
        due = self.publish_schedule.due(t_ns, self.config.publish_rate, force)
        self.state_due = due        # (replay_check: a due state missing from a bag is a gap)
        if not (due or out.every_state):
            return
        w = self.world
        if position is None:
            position, velocity = w.joint_angles(), w.joint_velocities()
        position = np.asarray(position, dtype=float).tolist()
        velocity = np.asarray(velocity, dtype=float).tolist()
        if effort is None:
            effort = np.asarray(w.applied_efforts(), dtype=float).tolist()
        if not all(map(math.isfinite, position + velocity + effort)):
            bad = [f'{name} {arr}' for name, arr in
                   (('position', position), ('velocity', velocity), ('effort', effort))
                   if not all(map(math.isfinite, arr))]
            self.stop_on_fault(f'non-finite state at t={t!r} s ({"; ".join(bad)}) not '
                               'published')
            return
        out.joint_state(t_ns, position, velocity, effort)

    def _markers(self, t_ns: int, force: bool, states=None) -> None:
        rate = self.config.marker_rate      # (0: markers off; due at start and reset)
        if not (rate > 0.0 and self.marker_schedule.due(t_ns, rate, force)
                and self.output.markers_wanted):
            return
        build = (self.markers.build_serialized if self.output.markers_serialized
                 else self.markers.build)
        msg = build(t_ns, self.world.body_pose if states is None
                    else states[self._marker_rows])
        if msg is not None:     # a non-finite pose: the joint-state guard reports the fault
            self.output.markers(t_ns, msg)

    # --------------------------------------------------------- reset and parameters ----
    def reset(self, publish: bool = True) -> None:
        """As ``~/reset``: initial state, t = 0, torque commands cleared to 0, pending ones
        dropped, the fault cleared; the pause state is kept. Publishes the state at once."""
        self.output.restarted()
        self.world.reset()
        self.commands.clear()
        for joint in self.actuated:
            self.world.set_effort(joint, 0.0)
        self._warned_disabled.clear()
        self.publish_schedule.restart()
        self.fault = None
        if publish:
            self.publish_state(force=True)

    def set_parameters(self, changes: Mapping[str, Any]) -> dict[str, Any]:
        """Live parameter changes (name -> value), in force from the next step boundary: the
        post-set callback of the node. Values are coerced (ValueError/KeyError naming the
        parameter); the recorded ones go to the output. Returns the coerced values."""
        values = {name: coerce(name, value) for name, value in changes.items()}
        for name, value in values.items():
            if name == 'command_timeout':
                self.commands.command_timeout = value
            elif name == 'publish_rate':
                self.publish_schedule.restart()
            elif name == 'effort_limits' and self.clamp:
                self.commands.set_effort_limits(value)
            if hasattr(self.config, name):
                setattr(self.config, name, value)
        recorded = {n: v for n, v in values.items() if n in RECORDED_PARAMETERS}
        if recorded:
            self.output.parameters(self.time_ns, recorded)
        return values

    # ---------------------------------------------------------------- diagnostics ----
    def diagnostics_msg(self, t_ns: int, name: str, real_time_factor_requested: float,
                        real_time_factor_achieved: float, recording: bool,
                        recording_error: str = '') -> Any:
        """A ``DiagnosticArray`` for status `name` with the values (:data:`DIAGNOSTIC_KEYS`)
        of the last step: ERROR after a fault, WARN on solver warnings, else OK."""
        last = self.world.last_step
        values = dict(zip(DIAGNOSTIC_KEYS, (
            float(self.world.time), self.steps, self.paused, float(self.world.dt),
            float(real_time_factor_requested), float(real_time_factor_achieved),
            last.newton_iterations, last.line_search_iterations, bool(last.converged),
            self.not_converged, float(last.max_joint_separation), last.substeps,
            bool(recording), self.fault or '', recording_error or ''), strict=True))
        ok = values['converged'] and not last.warnings
        if self.fault:
            level, message = convert.ERROR, f'stopped: {self.fault}'
        else:
            level = convert.OK if ok else convert.WARN
            message = 'paused' if self.paused else ('running' if ok else 'solver warnings')
        return convert.diagnostics_msg(t_ns, name, NODE_NAME, ok, message, values, level=level)


def queue_command(buffer: CommandBuffer, kind: str, joint: Optional[str], value: Any):
    """Hand one command to `buffer` as the node's subscription callback for its topic does;
    returns (rejections, clamps). `kind`: 'torque', 'array', 'enable', 'enable_all',
    'joint_state' (value: dict with name and position/velocity/effort lists)."""
    if kind == 'enable':
        return buffer.command_enable(joint, value), []
    if kind == 'enable_all':
        buffer.command_enable_all(value)
        return [], []
    if kind == 'array':
        return buffer.command_array(value)
    if kind == 'torque':
        return buffer.command_torque(joint, value)
    if kind == 'joint_state':
        return buffer.command_joint_state(value['name'], value.get('position', []),
                                          value.get('velocity', []), value.get('effort', []))
    raise ValueError(f'unknown command kind {kind!r}')


def steps_until(t_ns: int, now_ns: int, dt: float) -> int:
    """Whole steps from `now_ns` that stay before `t_ns` (at least 1): the most a caller can
    advance without passing a boundary at or after `t_ns`."""
    dt_ns = max(1, convert.seconds_to_ns(dt))
    return max(1, (t_ns - now_ns) // dt_ns)
