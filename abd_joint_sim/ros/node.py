"""sim_node: steps an abd_joint_sim World and talks ROS 2 (see README "Topics & services").

The node is thin: parameters come from :mod:`.params`, commands are validated, clamped and
buffered by :mod:`.commands`, messages are built by :mod:`.convert`. Callbacks only fill the
pending-command buffer; the step timer applies it at the step boundary, steps, publishes
copies and records. ``rclpy.spin`` runs a single-threaded executor, so callbacks never
overlap with a step and the buffer needs no lock.
"""
from __future__ import annotations

import difflib
import math
import os
import signal
import sys
import time
from typing import Any, Optional

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
import rclpy
from rclpy.clock import Clock as RclpyClock, ClockType
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64, Float64MultiArray
from std_srvs.srv import Trigger

from . import convert
from .commands import Applied, CommandBuffer
from .markers import MarkerBuilder, TOPIC_MARKERS
from .params import (check_live_value, coerce, config_from_values,
                     conflicting_parameter_sources, default_scene_path, NODE_NAME, PARAMS,
                     PARAMS_BY_NAME, undeclared_parameters)
from .recording import (add_node_topics, bag_custom_data, markers_due, parameter_event_msg,
                        PublishSchedule, RECORDED_PARAMETERS, record_applied,
                        TOPIC_CLOCK, TOPIC_DIAGNOSTICS, TOPIC_ENABLE_ALL, TOPIC_ENABLE_JOINT,
                        TOPIC_JOINT_COMMANDS, TOPIC_JOINT_STATES, TOPIC_PARAMETER_EVENTS,
                        TOPIC_TORQUE_ARRAY, TOPIC_TORQUE_JOINT)

JOINT_STATE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.VOLATILE)
CLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                       reliability=ReliabilityPolicy.BEST_EFFORT,
                       durability=DurabilityPolicy.VOLATILE)
COMMAND_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)

DIAGNOSTICS_PERIOD = 1.0      # s of wall time
AFAP_BATCH_WALL = 0.02        # s of stepping between callback rounds when as fast as possible
BATCH_STEPS = 16              # clean steps per compiled call while no command is pending
MAX_LAG_WALL = 0.1            # s; further behind real time than this -> re-anchor and warn
LOG_THROTTLE = 2.0            # s between repeats of a throttled warning


class SimNode(Node):
    """ROS 2 front of an abd_joint_sim ``World``."""

    def __init__(self, **kwargs: Any):
        super().__init__(NODE_NAME, **kwargs)
        # Parameters -> config (read once; live ones re-applied by the post-set callback).
        values = self._declare_parameters()
        self._check_parameter_sources(kwargs)       # before a bad value ends the start
        self.config = config_from_values(values)

        # Scene and world. Imported here so that `--help`-like failures stay cheap.
        from abd_joint_sim import Scene, World
        self.scene = self._load_scene(Scene)
        self.world = World(self.scene, dt=self.config.time_step or None)
        self.joint_names = list(self.world.joint_names)
        self.actuated = list(self.world.actuated_joint_names)
        self.commands = CommandBuffer(self.actuated, self.config.joints,
                                      self.config.effort_limits, self.config.command_timeout,
                                      scene_limits=self._scene_effort_limits(),
                                      driven=[j.name for j in self.scene.joints
                                              if j.driving is not None])
        self.config.joints = list(self.commands.order)

        self.paused = bool(self.config.start_paused)
        self.steps = 0
        self.publish_schedule = PublishSchedule()
        self.fault: Optional[str] = None
        """Why stepping stopped (a failed step, a non-finite state); None while healthy."""
        self.recording_error: Optional[str] = None
        self._anchor_wall = time.monotonic()
        self._anchor_sim = self.world.time
        self._stats_wall = time.monotonic()
        self._stats_steps = 0
        self._not_converged = 0
        self._warned_disabled: set[str] = set()
        self._throttle: dict = {}
        self._closed = False

        # Publishers.
        self.joint_state_pub = self.create_publisher(JointState, TOPIC_JOINT_STATES,
                                                     JOINT_STATE_QOS)
        self.clock_pub = self.create_publisher(Clock, TOPIC_CLOCK, CLOCK_QOS)
        self.clock_encoder = convert.ClockEncoder()      # /clock as checked CDR bytes
        zeros = [0.0] * len(self.joint_names)
        self._joint_state = convert.joint_state_msg(0, self.joint_names, zeros, zeros, zeros)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS, 10)
        # Body markers (ros/markers.py) at marker_rate; built only when someone listens or
        # the run is recorded.
        self.markers = None
        self.marker_pub = None
        self.marker_schedule = PublishSchedule()
        if self.config.marker_rate > 0.0:
            from visualization_msgs.msg import MarkerArray
            self.markers = MarkerBuilder(self.scene, self.config.marker_frame_id,
                                         self.config.marker_joint_axes)
            self.marker_pub = self.create_publisher(MarkerArray, TOPIC_MARKERS, JOINT_STATE_QOS)

        # Subscriptions: only actuated joints get command topics.
        self.command_subs = [
            self.create_subscription(Float64MultiArray, TOPIC_TORQUE_ARRAY,
                                     self._on_torque_array, COMMAND_QOS),
            self.create_subscription(Bool, TOPIC_ENABLE_ALL, self._on_enable_all, COMMAND_QOS),
            self.create_subscription(JointState, TOPIC_JOINT_COMMANDS,
                                     self._on_joint_commands, COMMAND_QOS),
        ]
        for joint in self.actuated:
            self.command_subs.append(self.create_subscription(
                Float64, TOPIC_TORQUE_JOINT.format(joint=joint),
                lambda msg, j=joint: self._on_torque_joint(j, msg), COMMAND_QOS))
            self.command_subs.append(self.create_subscription(
                Bool, TOPIC_ENABLE_JOINT.format(joint=joint),
                lambda msg, j=joint: self._on_enable_joint(j, msg), COMMAND_QOS))

        # Services (std_srvs/Trigger, Gazebo-style pause/unpause pair).
        self.service_handles = [
            self.create_service(Trigger, '~/pause', self._srv_pause),
            self.create_service(Trigger, '~/unpause', self._srv_unpause),
            self.create_service(Trigger, '~/step', self._srv_step),
            self.create_service(Trigger, '~/reset', self._srv_reset),
        ]

        # Recording (optional; failures never stop the simulation).
        self.recorder = None
        if self.config.record:
            self._open_recorder(self.config.record)

        self.add_on_set_parameters_callback(self._vet_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)

        # Timers: stepping (period from dt and the real-time factor) and diagnostics (wall).
        # Both run on the steady clock: on the node's clock they would follow /clock under
        # use_sim_time, which only moves when this node steps, so it would never step.
        self._wall_clock = RclpyClock(clock_type=ClockType.STEADY_TIME)
        self.step_timer = None
        self._make_step_timer()
        self.diagnostics_timer = self.create_timer(DIAGNOSTICS_PERIOD,
                                                   self._on_diagnostics_timer,
                                                   clock=self._wall_clock)
        if self.get_parameter('use_sim_time').value:
            self.get_logger().info(
                'use_sim_time is true: this node is the /clock source, so it ignores '
                'use_sim_time for its own pacing and steps on wall time (steady clock) x '
                'real_time_factor; the stamps it publishes are simulated time as always')

        self._warn_undeclared_parameters()          # all parameters are declared by now
        self._log_start()
        # The initial state, so subscribers see t = 0 even when starting paused.
        self._publish_state(force=True)

    def _load_scene(self, Scene):
        """robot_description (URDF text) if set, else the scene file (.urdf or YAML); URDF
        repairs are logged as warnings, one line each."""
        import warnings
        from abd_joint_sim.urdf import UrdfWarning
        with warnings.catch_warnings():
            warnings.simplefilter('ignore', UrdfWarning)   # logged below instead
            if self.config.robot_description.strip():
                scene = Scene.from_urdf(self.config.robot_description)
                self.config.scene = 'robot_description'
            else:
                scene = Scene.from_file(self.config.scene)
        for text in scene.warnings:
            self.get_logger().warn(text)
        return scene

    def _scene_effort_limits(self) -> dict[str, float]:
        model = getattr(self.world, 'model', None)
        limits = getattr(model, 'torque_effort_limit', None)
        if limits is None:
            return {}
        return {j: float(v) for j, v in zip(self.actuated, limits)}

    # ---------------------------------------------------------------- parameters ----
    def _declare_parameters(self) -> dict[str, Any]:
        values = {}
        for spec in PARAMS:
            default = spec.default
            if spec.name == 'scene':
                default = default_scene_path()
            dynamic = not isinstance(default, (str, bool))
            descriptor = ParameterDescriptor(description=spec.description,
                                             read_only=spec.read_only,
                                             dynamic_typing=dynamic)
            param = self.declare_parameter(spec.name, default, descriptor)
            values[spec.name] = param.value
        return values

    def _warn_undeclared_parameters(self) -> None:
        """Warn about parameters given at start that this node does not have: a typo such
        as real_time_factr would otherwise be ignored without a word (a warning, not a
        refusal: README "Parameters")."""
        overrides = getattr(self, '_parameter_overrides', None) or {}
        names = [n for n in undeclared_parameters(overrides) if not self.has_parameter(n)]
        declared = sorted(getattr(self, '_parameters', None) or PARAMS_BY_NAME)
        for name in names:
            close = difflib.get_close_matches(name, declared, n=1)
            hint = f' (did you mean {close[0]!r}?)' if close else ''
            self.get_logger().warn(
                f'parameter {name!r} is not a parameter of this node and is ignored{hint}; '
                f'its parameters: {", ".join(PARAMS_BY_NAME)} (README "Parameters")')

    def _check_parameter_sources(self, kwargs: dict) -> None:
        """Warn about a parameter given more than once with different values (e.g. `-p
        record:=bag` and a --params-file with `record: ""`: only one of them is in
        effect)."""
        argv = list(kwargs.get('cli_args') or [])
        if kwargs.get('use_global_arguments', True):
            argv = list(sys.argv[1:]) + argv
        for name, sources in conflicting_parameter_sources(argv, self.get_name()).items():
            if name not in PARAMS_BY_NAME:
                continue
            value = self.get_parameter(name).value
            effect = (' -> recording is OFF' if name == 'record' and not value else '')
            self.get_logger().warn(
                f'parameter {name!r} is given more than once with different values: '
                f'{"; ".join(f"{src}: {val!r}" for src, val in sources)}; in effect: '
                f'{value!r}{effect}')

    def _vet_parameters(self, params) -> SetParametersResult:
        for p in params:
            reason = check_live_value(p.name, p.value, len(self.commands.order))
            if reason:
                return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params) -> None:
        for p in params:
            if p.name not in PARAMS_BY_NAME:
                continue
            value = coerce(p.name, p.value)
            setattr(self.config, p.name, value)
            if p.name == 'real_time_factor':
                self._make_step_timer()
            elif p.name == 'publish_rate':
                self.publish_schedule.restart()
            elif p.name == 'command_timeout':
                self.commands.command_timeout = value
            elif p.name == 'effort_limits':
                self.commands.set_effort_limits(value)
            self.get_logger().info(f'parameter {p.name} = {value!r}')
        changes = {p.name: coerce(p.name, p.value) for p in params
                   if p.name in RECORDED_PARAMETERS}
        if changes and self.recorder is not None:
            # Applies from the next step boundary on: log time = the current sim time.
            t_ns = convert.seconds_to_ns(self.world.time)
            self._record(self._abs(TOPIC_PARAMETER_EVENTS), t_ns, parameter_event_msg(
                t_ns, self.get_fully_qualified_name(), changes))

    # ------------------------------------------------------------------- timing ----
    def _make_step_timer(self) -> None:
        if self.step_timer is not None:
            self.destroy_timer(self.step_timer)
        rtf = self.config.real_time_factor
        period = 0.0 if rtf == 0.0 else min(max(self.world.dt / rtf, 0.001), 0.05)
        self._reanchor()
        self.step_timer = self.create_timer(period, self._on_step_timer, clock=self._wall_clock)

    def _reanchor(self) -> None:
        self._anchor_wall = time.monotonic()
        self._anchor_sim = self.world.time

    def _on_step_timer(self) -> None:
        if self.paused:
            return
        rtf = self.config.real_time_factor
        if rtf == 0.0:
            deadline = time.monotonic() + AFAP_BATCH_WALL
            while not self.paused and time.monotonic() < deadline and self.context.ok():
                if not self._step_batch(BATCH_STEPS) and not self._step_once():
                    break
            return
        now = time.monotonic()
        dt = self.world.dt
        if self._anchor_sim + rtf * (now - self._anchor_wall) - self.world.time > \
                MAX_LAG_WALL * rtf + dt:
            self.get_logger().warn(
                f'cannot keep up with real_time_factor {rtf:g} (a step takes longer than '
                f'{dt / rtf:.4g} s of wall time); running as fast as possible instead',
                throttle_duration_sec=10.0)
            self._reanchor()
            self._anchor_wall -= dt / rtf   # allow one step now
        target = self._anchor_sim + rtf * (now - self._anchor_wall)
        # Step while the end of the next step is not ahead of real time x rtf, and give the
        # executor back after AFAP_BATCH_WALL so commands and services are never starved.
        deadline = now + AFAP_BATCH_WALL
        while (not self.paused and self.world.time + dt * (1.0 - 1e-6) <= target
               and time.monotonic() < deadline and self.context.ok()):
            due = int((target - self.world.time) / dt + 1e-6)       # whole steps behind
            if not self._step_batch(min(due, BATCH_STEPS)) and not self._step_once():
                break

    # -------------------------------------------------------------------- steps ----
    def _step_once(self, force_publish: bool = False) -> bool:
        """Apply pending commands at the boundary, take one step, publish. False on failure."""
        applied = self.commands.apply(self.world)
        if applied:
            self._on_applied(applied)
        try:
            report = self.world.step()
        except Exception as exc:  # noqa: BLE001 - keep the node alive, say why, pause
            self._stop_on_fault(
                f'step at t={self.world.time:.6f} s failed: {type(exc).__name__}: {exc}')
            return False
        self.fault = None
        self.steps += 1
        self._stats_steps += 1
        if not report.converged:
            self._not_converged += 1
            self.get_logger().warn(
                f'Newton did not converge at t={self.world.time:.6f} s '
                f'({report.newton_iterations} iterations)', throttle_duration_sec=LOG_THROTTLE)
        for text in report.warnings:
            self.get_logger().warn(f'step: {text}', throttle_duration_sec=LOG_THROTTLE)
        self._publish_state(force=force_publish)
        return True

    def _step_batch(self, max_steps: int) -> int:
        """Up to max_steps steps in one compiled call (World.step_clean) while no command is
        pending: ~30 µs of Python saved per step. Commands are applied at every boundary
        all the same, since none is pending (and the executor only delivers new ones between
        timer rounds). Stops before any step that would sub-step, warn or fail, which
        _step_once then takes. Returns the number of steps taken (0: none)."""
        if self.markers is not None and (self.recorder is not None
                                         or self.marker_pub.get_subscription_count() > 0):
            # End the batch on the step the markers are due at: only then does the world
            # hold the poses they show (not needed while nobody gets markers).
            dt_ns = max(1, convert.seconds_to_ns(self.world.dt))
            ahead = self.marker_schedule.next_ns - convert.seconds_to_ns(self.world.time)
            max_steps = min(max_steps, max(1, -(-ahead // dt_ns)))
        if max_steps < 2 or not self.commands.idle:
            return 0
        count, times, angles, velocities = self.world.step_clean(max_steps)
        if count:
            self.fault = None
            self.steps += count
            self._stats_steps += count
            for t, position, velocity in zip(times, angles, velocities):
                self._publish_state(t=t, position=position, velocity=velocity)
                if self.fault:              # the publish guard stopped it: say so once
                    break
        return count

    def _on_applied(self, applied: Applied) -> None:
        for joint in applied.timed_out:
            self.get_logger().warn(
                f'joint {joint!r}: no torque command for {self.commands.command_timeout:g} s '
                f'(simulated) -> torque set to 0 until the next command')
        for joint, value in applied.torques.items():
            if value != 0.0 and not self.world.torque_enabled(joint):
                if joint not in self._warned_disabled:
                    self._warned_disabled.add(joint)
                    # Throttled too: a sender toggling the enable would re-arm it each time.
                    self._warn_throttled(
                        ('disabled', joint),
                        f'joint {joint!r}: torque {value:g} N m stored but the torque is '
                        f'disabled; publish true on '
                        f'{TOPIC_ENABLE_JOINT.format(joint=joint)} to apply it')
        for joint, flag in applied.enables.items():
            if flag:
                self._warned_disabled.discard(joint)
        if self.recorder is not None:
            record_applied(self._record, self._abs, applied)

    def _stop_on_fault(self, why: str) -> None:
        """Pause, say why on the log and (at once) on /diagnostics, flush the bag."""
        self.fault = why
        self.paused = True
        self.get_logger().error(
            f'{why}; simulation paused, nothing non-finite was published or recorded '
            '(call ~/reset, or ~/unpause to retry)')
        self._publish_diagnostics()
        self._flush_recorder()

    def _publish_state(self, force: bool = False, t: Optional[float] = None,
                       position=None, velocity=None) -> None:
        """/clock after every step, /joint_states when due; never a non-finite value. A
        batch (_step_batch) passes each step's time and joint angles and velocities; by
        default they are the world's current ones."""
        if t is None:
            t = self.world.time
        if not math.isfinite(t):
            self._stop_on_fault(f'non-finite time {t!r} s not published')
            return
        t_ns = convert.seconds_to_ns(t)
        # /clock after every step: 12 bytes of CDR published and recorded as they are
        # (convert.ClockEncoder; a Clock message costs ~10 µs to serialise, twice when
        # recording, against ~40 µs for a whole batched step of the default scene).
        clock = self.clock_encoder.encode(t_ns)
        self.clock_pub.publish(clock)
        if self.recorder is not None:
            self._record(TOPIC_CLOCK, t_ns, clock, serialized=True)
        if self.markers is not None and (position is None or t == self.world.time):
            self._publish_markers(t_ns, force)
        if not self.publish_schedule.due(t_ns, self.config.publish_rate, force):
            return
        w = self.world
        if position is None:
            position, velocity = w.joint_angles(), w.joint_velocities()
        position = np.asarray(position, dtype=float).tolist()
        velocity = np.asarray(velocity, dtype=float).tolist()
        effort = np.asarray(w.applied_torques(), dtype=float).tolist()
        if not all(map(math.isfinite, position + velocity + effort)):
            bad = [f'{name} {arr}' for name, arr in
                   (('position', position), ('velocity', velocity), ('effort', effort))
                   if not all(map(math.isfinite, arr))]
            self._stop_on_fault(f'non-finite state at t={t!r} s ({"; ".join(bad)}) not published')
            return
        msg = self._joint_state
        convert.fill_joint_state(msg, t_ns, position, velocity, effort, self.config.frame_id)
        self.joint_state_pub.publish(msg)
        self._record(self._abs(TOPIC_JOINT_STATES), t_ns, msg)

    def _publish_markers(self, t_ns: int, force: bool) -> None:
        """The body markers when due (markers_due), from the world's current poses."""
        if not markers_due(self.marker_schedule, t_ns, self.config.marker_rate, force):
            return
        if self.recorder is None and self.marker_pub.get_subscription_count() == 0:
            return
        msg = self.markers.build(t_ns, self.world.body_pose)
        if msg is None:       # a non-finite pose: the joint-state guard reports the fault
            return
        self.marker_pub.publish(msg)
        self._record(self._abs(TOPIC_MARKERS), t_ns, msg)

    def _publish_diagnostics(self) -> None:
        now = time.monotonic()
        wall = max(now - self._stats_wall, 1e-9)
        achieved_rtf = self._stats_steps * self.world.dt / wall
        self._stats_wall, self._stats_steps = now, 0
        last = getattr(self.world, 'last_step', None)
        converged = bool(getattr(last, 'converged', True)) if last is not None else True
        values = {
            'sim_time': float(self.world.time),
            'steps': self.steps,
            'paused': self.paused,
            'time_step': float(self.world.dt),
            'real_time_factor_requested': float(self.config.real_time_factor),
            'real_time_factor_achieved': float(achieved_rtf),
            'newton_iterations': getattr(last, 'newton_iterations', 0),
            'line_search_iterations': getattr(last, 'line_search_iterations', 0),
            'converged': converged,
            'not_converged_steps_total': self._not_converged,
            'max_joint_separation': float(getattr(last, 'max_joint_separation', 0.0)),
            'substeps': getattr(last, 'substeps', 1),
            'recording': self.recorder is not None,
            'fault': self.fault or '',
            'recording_error': self.recording_error or '',
        }
        ok = converged and not (getattr(last, 'warnings', None) or [])
        if self.fault:
            level, message = convert.ERROR, f'stopped: {self.fault}'
        else:
            level = convert.OK if ok else convert.WARN
            message = 'paused' if self.paused else ('running' if ok else 'solver warnings')
        t_ns = convert.seconds_to_ns(self.world.time)
        msg = convert.diagnostics_msg(t_ns, f'{self.get_name()}: solver', NODE_NAME, ok,
                                      message, values, level=level)
        self.diagnostics_pub.publish(msg)
        self._record(TOPIC_DIAGNOSTICS, t_ns, msg)

    def _on_diagnostics_timer(self) -> None:
        self._publish_diagnostics()
        # A SIGKILL loses at most the chunk in progress: close it every DIAGNOSTICS_PERIOD.
        self._flush_recorder()

    # ------------------------------------------------------------ subscriptions ----
    def _warn_throttled(self, key, text: str) -> None:
        """Warn at most once per LOG_THROTTLE s per key (rclpy throttles per call site,
        which would hide a second joint's or a second reason's message)."""
        now = time.monotonic()
        last, suppressed = self._throttle.get(key, (-math.inf, 0))
        if now - last < LOG_THROTTLE:
            self._throttle[key] = (last, suppressed + 1)
            return
        if suppressed:
            text += f' ({suppressed} similar message(s) suppressed)'
        self._throttle[key] = (now, 0)
        self.get_logger().warn(text)

    def _report(self, form: str, rejections, clamps) -> None:
        """Throttled per command form (array, joint torque, enable), joint and reason: the
        first rejection of each kind of command shows at once, whatever came before."""
        for r in rejections:
            kind = r.reason.split(' ')[0]
            self._warn_throttled(('reject', form, r.joint, kind), f'{form} command: {r}'
                                 if form == 'array' and r.joint is not None else str(r))
        for c in clamps:
            self._warn_throttled(('clamp', form, c.joint, c.applied > 0), str(c))

    def _on_torque_array(self, msg: Float64MultiArray) -> None:
        self._report('array', *self.commands.command_array(convert.array_values(msg)))

    def _on_torque_joint(self, joint: str, msg: Float64) -> None:
        self._report('joint', *self.commands.command_torque(joint, msg.data))

    def _on_joint_commands(self, msg: JointState) -> None:
        self._report('joint_commands', *self.commands.command_joint_state(
            msg.name, msg.position, msg.velocity, msg.effort))

    def _on_enable_joint(self, joint: str, msg: Bool) -> None:
        self._report('enable', self.commands.command_enable(joint, msg.data), [])

    def _on_enable_all(self, msg: Bool) -> None:
        self.commands.command_enable_all(msg.data)

    # ----------------------------------------------------------------- services ----
    def _srv_pause(self, request, response):
        was = self.paused
        self.paused = True
        self._flush_recorder()
        response.success = True
        response.message = f'paused at t={self.world.time:.6f} s' + (' (already)' if was else '')
        return response

    def _srv_unpause(self, request, response):
        was = self.paused
        self.paused = False
        self._reanchor()
        response.success = True
        response.message = (f'running from t={self.world.time:.6f} s'
                            + ('' if was else ' (was not paused)'))
        return response

    def _srv_step(self, request, response):
        if not self.paused:
            response.success = False
            response.message = 'not paused: call ~/pause first'
            return response
        ok = self._step_once(force_publish=True)
        response.success = ok
        response.message = f't={self.world.time:.6f} s'
        return response

    def _srv_reset(self, request, response):
        self.world.reset()
        self.commands.clear()
        for joint in self.actuated:
            self.world.set_torque(joint, 0.0)
        self._warned_disabled.clear()
        self.publish_schedule.restart()
        self.fault = None
        self._reanchor()
        self._publish_state(force=True)
        self.get_logger().info('reset: initial state, t=0, torque commands cleared')
        response.success = True
        response.message = f'reset to t={self.world.time:.6f} s'
        return response

    # ---------------------------------------------------------------- recording ----
    def _open_recorder(self, path: str) -> None:
        writer = None
        try:
            from abd_joint_sim.record.bag import BagWriter
            custom, attachments = bag_custom_data(
                self.config, self.config.scene, getattr(self.scene, 'source_text', '') or '',
                self.world.dt, self.commands.order,
                urdf_text=getattr(self.scene, 'robot_description', '') or '')
            writer = BagWriter(path, custom_data=custom, attachments=attachments)
            writer.open()
            add_node_topics(writer, self._abs, self.actuated, markers=self.markers is not None)
        except Exception as exc:  # noqa: BLE001 - BagError, ImportError, OSError, ...
            self.get_logger().error(f'recording to {path!r} disabled: {exc}')
            self.recording_error = str(exc)
            self.recorder = None
            self.config.record = ''
            if writer is not None:
                try:
                    writer.close()
                except Exception:  # noqa: BLE001 - already reported above
                    pass
            return
        self.recorder = writer

    def _abs(self, topic: str) -> str:
        """Fully qualified topic name (namespace applied), as it appears on the graph."""
        return self.resolve_topic_name(topic)

    def _record(self, topic: str, stamp_ns: int, msg, serialized: bool = False) -> None:
        if self.recorder is None:
            return
        try:
            if serialized:
                self.recorder.write_serialized(topic, stamp_ns, msg)
            else:
                self.recorder.write(topic, stamp_ns, msg)
        except Exception as exc:  # noqa: BLE001 - keep simulating without the bag
            self._recording_failed(f'writing {topic} failed: {exc}')

    def _recording_failed(self, why: str) -> None:
        self.recording_error = why
        self.get_logger().error(
            f'recording stopped: {why}. The simulation goes on; complete the bag with '
            f'`python -m abd_joint_sim.ros.bag_recover {self.config.record}`')
        self._close_recorder()
        self._publish_diagnostics()

    def _flush_recorder(self) -> None:
        if self.recorder is None:
            return
        try:
            self.recorder.flush()
        except Exception as exc:  # noqa: BLE001
            self._recording_failed(f'flushing failed: {exc}')

    def _close_recorder(self) -> None:
        recorder, self.recorder = self.recorder, None
        if recorder is None:
            return
        try:
            recorder.close()
            self._log_late('INFO', f'bag closed: {self.config.record}')
        except Exception as exc:  # noqa: BLE001
            self._log_late('ERROR', f'closing the bag {self.config.record!r} failed: {exc}')

    def _log_late(self, level: str, text: str) -> None:
        """Log also after Ctrl-C/SIGTERM shut the context down (rosout is gone then)."""
        if self.context.ok():
            getattr(self.get_logger(), level.lower())(text)
        else:
            print(f'[{level}] [{self.get_name()}]: {text}', file=sys.stderr, flush=True)

    # ------------------------------------------------------------------ logging ----
    def _log_start(self) -> None:
        c = self.config
        rtf = 'as fast as possible' if c.real_time_factor == 0 else f'{c.real_time_factor:g}'
        enabled = [j for j in self.actuated if self.world.torque_enabled(j)]
        limits = (', '.join(f'{j}={v:g}' for j, v in self.commands.limits.items())
                  or 'none')
        ns = self.get_namespace().rstrip('/')
        self.get_logger().info(
            f'scene {c.scene} | dt {self.world.dt:g} s | '
            f'joints {self.joint_names} | '
            f'actuated {self.actuated} (torque enabled: {enabled or "none"}) | '
            f'publishing {ns}/{TOPIC_JOINT_STATES} '
            f'({"every step" if c.publish_rate == 0 else f"{c.publish_rate:g} Hz"}), '
            f'{TOPIC_CLOCK}, {TOPIC_DIAGNOSTICS} | commands {ns}/{TOPIC_TORQUE_ARRAY} '
            f'(order {self.commands.order}), {ns}/joint_torque/<joint>, '
            f'{ns}/{TOPIC_ENABLE_ALL}[/<joint>], {ns}/{TOPIC_JOINT_COMMANDS} | services ~/pause ~/unpause ~/step ~/reset | '
            f'real-time factor {rtf} | {"paused" if self.paused else "running"} | '
            f'command timeout {f"{c.command_timeout:g} s" if c.command_timeout else "off"} | '
            f'effort limits {limits} | '
            f'recording {c.record if self.recorder is not None else "off"}')

    # ---------------------------------------------------------------- shutdown ----
    def close(self) -> None:
        """Stop stepping and finalise the bag (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self.paused = True
        self._close_recorder()


def _shutdown_on_signal(signum, frame):
    """SIGINT/SIGTERM: shut the ROS context down; spin() then returns between callbacks.

    Not KeyboardInterrupt (rclpy's own handler chains to Python's, which raises it): Python
    runs a signal handler between any two bytecodes, so an exception could land inside a
    bag write and leave the MCAP writer half updated (e.g. its statistics counting a
    message its chunk never got). Repeated signals while the bag is being closed are
    ignored for the same reason; SIGKILL still ends a hung node.
    """
    rclpy.try_shutdown()


def _robot_description_to_params_file(args: list[str]) -> tuple[list[str], Optional[str]]:
    """Move ``-p robot_description:=<URDF text>`` into a temporary params file.

    rcl parses every ``-p`` value as YAML, and URDF text rarely survives that (``: `` and
    `` #`` in comments or attributes end it), so ``-p robot_description:="$(cat r.urdf)"``, as
    users pass it to robot_state_publisher, would fail before the node starts. The same value,
    quoted by a YAML writer in a params file at the same place in the arguments, is read as
    the string it is. Returns (new args, the file to delete after rclpy.init, or None)."""
    import tempfile
    import yaml
    out: list[str] = []
    path = None
    i = 0
    while i < len(args):
        a = args[i]
        value = None
        if a in ('-p', '--param') and i + 1 < len(args) \
                and args[i + 1].startswith('robot_description:='):
            value, i = args[i + 1][len('robot_description:='):], i + 2
        if value is None:
            out.append(a)
            i += 1
            continue
        with tempfile.NamedTemporaryFile('w', suffix='.yaml', prefix='robot_description_',
                                         delete=False) as f:
            yaml.safe_dump({'/**': {'ros__parameters': {'robot_description': value}}}, f)
            path = f.name
        out += ['--params-file', path]
    return out, path


def main(args: Optional[list[str]] = None) -> int:
    args, tmp_params = _robot_description_to_params_file(list(sys.argv if args is None else args))
    try:
        rclpy.init(args=args)
    except Exception as exc:  # noqa: BLE001 - rcl's argument parser: one line, exit 2
        first = str(exc).split('\n')[0][:300]
        print(f'[FATAL] [{NODE_NAME}]: cannot start: the command-line arguments could not be '
              f'parsed ({first}); -p values are parsed as YAML: give long or structured '
              'values in a --params-file', file=sys.stderr)
        return 2
    finally:
        if tmp_params:
            os.unlink(tmp_params)
    # Ctrl-C and SIGTERM (kill, systemd, launch) end the node cleanly: the bag is finalised.
    signal.signal(signal.SIGINT, _shutdown_on_signal)
    signal.signal(signal.SIGTERM, _shutdown_on_signal)
    node = None
    status = 0
    try:
        node = SimNode()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception as exc:  # noqa: BLE001 - a bad scene/parameter: one clear line, exit 1
        from abd_joint_sim.errors import SceneError
        if not rclpy.ok():
            pass    # SIGINT shut the context down mid-step (or mid-start): a clean stop
        elif isinstance(exc, (SceneError, ValueError, FileNotFoundError, KeyError)):
            rclpy.logging.get_logger(NODE_NAME).fatal(f'cannot start: {exc}')
            status = 1
        else:
            raise
    finally:
        if node is not None:
            node.close()
            node.destroy_node()
        rclpy.try_shutdown()
    return status


if __name__ == '__main__':
    sys.exit(main())
