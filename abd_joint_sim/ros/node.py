"""sim_node: runs the simulation loop (:mod:`.loop`) and talks ROS 2 (docs/topics.md).

ROS plumbing only: parameters from :mod:`.params`, topics and QoS from :mod:`.topics`;
callbacks hand commands to the loop's :class:`~.commands.CommandBuffer`; services call the
loop; ``loop.advance(n)`` steps and hands its outputs to :class:`_NodeOutput`, which
publishes and records them. In real time `main` steps in a thread of its own
(:meth:`SimNode.start_stepping_thread`, docs/decisions.md), as fast as possible the step
timer steps in 20 ms rounds; the thread and every callback hold ``SimNode._lock`` while they
touch the loop, so a callback never overlaps a step.
"""
from __future__ import annotations

import difflib
import functools
import math
import os
import signal
import sys
import threading
import time
from typing import Any, Optional

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
import rclpy
from rclpy.clock import Clock as RclpyClock, ClockType
from rclpy.exceptions import InvalidParameterTypeException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64, Float64MultiArray
from std_srvs.srv import Trigger

from . import convert
from .loop import LoopOutput, queue_command, SimLoop
from .params import (check_live_value, config_from_values, conflicting_parameter_sources,
                     default_scene_path, NODE_NAME, PARAMS, PARAMS_BY_NAME,
                     undeclared_parameters)
from .recording import bag_custom_data, Recording
from .topics import (BEST_EFFORT, TOPIC_CLOCK, TOPIC_DIAGNOSTICS, TOPIC_ENABLE_ALL,
                     TOPIC_ENABLE_JOINT, TOPIC_JOINT_COMMANDS, TOPIC_JOINT_STATES,
                     TOPIC_MARKERS, TOPIC_TORQUE_ARRAY, TOPIC_TORQUE_JOINT, TOPICS_BY_NAME,
                     TopicSpec)


def _qos(spec: TopicSpec) -> QoSProfile:
    """The rclpy QoS of a topic-table row (keep-last, volatile)."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=spec.depth,
                      reliability=(ReliabilityPolicy.BEST_EFFORT if spec.reliability ==
                                   BEST_EFFORT else ReliabilityPolicy.RELIABLE),
                      durability=DurabilityPolicy.VOLATILE)


DIAGNOSTICS_PERIOD = 1.0      # s of wall time
AFAP_BATCH_WALL = 0.02        # s of stepping between callback rounds when as fast as possible
BATCH_STEPS = 16              # most steps per timer round between wall-clock checks
AFAP_BATCH_STEPS = 256        # most steps per `_advance` as fast as possible (_afap_steps)
MAX_LAG_WALL = 0.1            # s; further behind real time than this -> re-anchor and warn
LOG_THROTTLE = 2.0            # s between repeats of a throttled warning
MAX_LOG_LINE = 500            # characters of a logged warning (the rest is counted)
THREAD_IDLE = 0.05            # s the stepping thread sleeps while idle (a change wakes it)
COMMAND_FORMS = {'array': 'array', 'torque': 'joint', 'joint_state': 'joint_commands',
                 'enable': 'enable', 'enable_all': 'enable'}
"""queue_command kind -> the command form its warnings name and throttle by."""


def _locked(method):
    """Run `method` holding the node's lock (executor callbacks: see the module docstring)."""
    def locked(self, *args, **kwargs):
        with self._lock:
            return method(self, *args, **kwargs)
    locked.__name__, locked.__doc__ = method.__name__, method.__doc__
    return locked


class SimNode(Node):
    """ROS 2 front of an abd_joint_sim ``World``."""

    def __init__(self, **kwargs: Any):
        super().__init__(NODE_NAME, **kwargs)
        self._lock = threading.RLock()      # the loop: stepping thread and callbacks
        self._stepper: Optional[threading.Thread] = None
        self._stepper_quit = threading.Event()
        self._stepper_wake = threading.Event()
        self.stepper_error: Optional[BaseException] = None
        values = self._declare_parameters()
        self._check_parameter_sources(kwargs)       # before a bad value ends the start
        self.config = config_from_values(values)

        from abd_joint_sim.scene import Scene     # (here: `--help`-like failures stay cheap)
        self.scene = self._load_scene(Scene)
        self._output = _NodeOutput(self)
        self.loop = SimLoop(self.scene, self.config, output=self._output, clamp=True,
                            paused=bool(self.config.start_paused))
        self.world = self.loop.world
        self.commands = self.loop.commands
        self.joint_names = list(self.loop.joint_names)
        self.actuated = list(self.loop.actuated)
        self.live = self._start_live()      # the live view (docs/live.md), live_port > 0

        self.recording_error: Optional[str] = None
        self._reanchor()
        self._stats_wall = time.monotonic()
        self._stats_steps = 0
        self._throttle: dict = {}
        self._wall_per_step = 0.0           # measured as fast as possible (_afap_steps)
        self._closed = False

        # Publishers (topic table: ros/topics.py).
        self.joint_state_pub = self._publisher(JointState, TOPIC_JOINT_STATES)
        self.clock_pub = self._publisher(Clock, TOPIC_CLOCK)
        self.clock_encoder = convert.ClockEncoder()      # /clock as checked CDR bytes
        # publish(bytes) without its per-call type dispatch and handle guard (the publisher
        # lives as long as the node)
        self.clock_publish_raw = self.clock_pub.handle.publish_raw
        self.joint_state_encoder = convert.JointStateEncoder(self.joint_names,
                                                             self.config.frame_id)
        self.joint_state_publish_raw = self.joint_state_pub.handle.publish_raw   # (as /clock)
        self.diagnostics_pub = self._publisher(DiagnosticArray, TOPIC_DIAGNOSTICS)
        from visualization_msgs.msg import MarkerArray
        self.marker_pub = (None if self.loop.markers is None
                           else self._publisher(MarkerArray, TOPIC_MARKERS))

        # Subscriptions (queue_command kinds): only actuated joints get command topics.
        self.command_subs = [
            self._subscription(Float64MultiArray, TOPIC_TORQUE_ARRAY, 'array'),
            self._subscription(Bool, TOPIC_ENABLE_ALL, 'enable_all'),
            self._subscription(JointState, TOPIC_JOINT_COMMANDS, 'joint_state')]
        for joint in self.actuated:
            self.command_subs += [self._subscription(Float64, TOPIC_TORQUE_JOINT, 'torque', joint),
                                  self._subscription(Bool, TOPIC_ENABLE_JOINT, 'enable', joint)]

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

        # Timers on the steady clock: under use_sim_time the node's clock follows /clock,
        # which only moves when this node steps.
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
        self.loop.publish_state(force=True)

    # The loop's state as attributes of the node.
    paused = property(lambda self: self.loop.paused,
                      lambda self, value: setattr(self.loop, 'paused', bool(value)))
    fault = property(lambda self: self.loop.fault)
    steps = property(lambda self: self.loop.steps)

    def _publisher(self, msg_type, name: str):
        """A publisher for a row of the topic table (its QoS from there)."""
        return self.create_publisher(msg_type, name, _qos(TOPICS_BY_NAME[name]))

    def _subscription(self, msg_type, name: str, kind: str, joint: Optional[str] = None):
        """A subscription for a row of the topic table (`joint` fills ``{joint}``) whose
        messages are commands of `kind` (:func:`.loop.queue_command`)."""
        from rclpy.exceptions import InvalidTopicNameException
        try:
            return self.create_subscription(msg_type, name.format(joint=joint),
                                            lambda msg: self._on_command(kind, joint, msg),
                                            _qos(TOPICS_BY_NAME[name]))
        except InvalidTopicNameException:     # (only a joint's name can make one invalid)
            shown = joint if len(joint) <= 80 else f'{joint[:80]}... ({len(joint)} characters)'
            raise ValueError(
                f'joint {shown!r} cannot name its command topic {name!r}: a ROS topic name '
                "has only letters, digits and '_' between its slashes, no part starting with "
                'a digit, at most 255 characters in all; rename the joint, or leave it out of '
                '`actuated`') from None

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

    # ---------------------------------------------------------------- parameters ----
    def _declare_parameters(self) -> dict[str, Any]:
        values = {}
        for spec in PARAMS:
            default = default_scene_path() if spec.name == 'scene' else spec.default
            descriptor = ParameterDescriptor(description=spec.description,
                                             read_only=spec.read_only,
                                             dynamic_typing=not isinstance(default, (str, bool)))
            try:
                param = self.declare_parameter(spec.name, default, descriptor)
            except InvalidParameterTypeException:
                # (a string or bool parameter given another YAML type: one line, no traceback)
                given = (getattr(self, '_parameter_overrides', None) or {}).get(spec.name)
                given = getattr(given, 'value', given)
                kind = 'true or false' if isinstance(default, bool) else 'a string'
                hint = (f' (-p values are parsed as YAML: quote a string that looks like a number '
                        f'or a boolean, -p {spec.name}:="\'{given}\'")' if kind == 'a string' else '')
                raise ValueError(f'parameter {spec.name!r}: expected {kind}, got {given!r}{hint}') from None
            values[spec.name] = param.value
        return values

    def _warn_undeclared_parameters(self) -> None:
        """Warn about parameters given at start that this node does not have (typos)."""
        overrides = getattr(self, '_parameter_overrides', None) or {}
        names = [n for n in undeclared_parameters(overrides) if not self.has_parameter(n)]
        declared = sorted(getattr(self, '_parameters', None) or PARAMS_BY_NAME)
        for name in names:
            close = difflib.get_close_matches(name, declared, n=1)
            hint = f' (did you mean {close[0]!r}?)' if close else ''
            self.get_logger().warn(
                f'parameter {name!r} is not a parameter of this node and is ignored{hint}; '
                f'its parameters: {", ".join(PARAMS_BY_NAME)} (docs/parameters.md)')

    def _check_parameter_sources(self, kwargs: dict) -> None:
        """Warn about a parameter given more than once with different values (`-p
        record:=bag` and a --params-file with `record: ""`)."""
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
            if p.type_ == Parameter.Type.NOT_SET and p.name in PARAMS_BY_NAME:
                return SetParametersResult(successful=False, reason=(
                    f'parameter {p.name!r} cannot be deleted: the node always needs its value '
                    '(set another value instead)'))
            reason = check_live_value(p.name, p.value, len(self.commands.order))
            if reason:
                return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    @_locked
    def _apply_parameters(self, params) -> None:
        values = self.loop.set_parameters({p.name: p.value for p in params
                                           if p.name in PARAMS_BY_NAME})
        for name, value in values.items():
            if name == 'real_time_factor':
                self._make_step_timer()
            self.get_logger().info(f'parameter {name} = {value!r}')

    # ------------------------------------------------------------------- timing ----
    def _make_step_timer(self) -> None:
        """The step timer at the period `real_time_factor` asks for; while the stepping thread
        steps (real_time_factor > 0), a slow one that only notices a SIGINT/SIGTERM."""
        if self.step_timer is not None:
            self.destroy_timer(self.step_timer)
        rtf = self.config.real_time_factor
        period = 0.0 if rtf == 0.0 else min(max(self.world.dt / rtf, 0.001), 0.05)
        self._reanchor()
        if self._stepper is not None and rtf > 0.0:
            self.step_timer = self.create_timer(THREAD_IDLE, self._on_housekeeping,
                                                clock=self._wall_clock)
            self._stepper_wake.set()
            return
        self.step_timer = self.create_timer(period, self._on_step_timer, clock=self._wall_clock)

    def start_stepping_thread(self) -> None:
        """Step in a thread of its own from now on (`main` does; see the module docstring).
        Idempotent. `close` stops it."""
        with self._lock:
            if self._stepper is not None or self._closed:
                return
            self._stepper = threading.Thread(target=self._stepper_main, name='sim_stepper',
                                             daemon=True)
            self._make_step_timer()
        self._stepper.start()

    @_locked
    def _on_housekeeping(self) -> None:
        """The step timer while the thread steps: notice a SIGINT/SIGTERM (the lock held, so
        the context never shuts down in the middle of the thread's round)."""
        self._stop_requested()
        self._live_refresh()

    def _stepper_main(self) -> None:
        try:
            while not self._stepper_quit.is_set():
                with self._lock:
                    delay = self._pace()
                if delay > 0.0:
                    self._stepper_wake.wait(delay)
                    self._stepper_wake.clear()
                else:
                    time.sleep(0)           # the GIL, and so the lock, to a waiting callback
        except BaseException as exc:  # noqa: BLE001 - said, then the node shuts down
            if _STOP_SIGNAL['received'] or not self.context.ok():
                return                      # shutting down anyway: not a failure
            self.stepper_error = exc
            self._log_late('FATAL', f'the stepping thread failed: {type(exc).__name__}: {exc}')
            rclpy.try_shutdown(context=self.context)

    def _pace(self) -> float:
        """One round of real-time stepping (the thread's, or the step timer's without it; the
        lock held): the steps due now in real time x real_time_factor, at most BATCH_STEPS;
        returns the wall seconds until the next step is due (0: look again at once). Idle
        while paused and as fast as possible."""
        rtf = self.config.real_time_factor
        if (self._closed or self.paused or rtf == 0.0 or _STOP_SIGNAL['received']
                or not self.context.ok()):
            return THREAD_IDLE
        now = time.monotonic()
        dt = self.world.dt
        if self._anchor_sim + rtf * (now - self._anchor_wall) - self.world.time > \
                MAX_LAG_WALL * rtf + dt:    # lagging: say so (every 10 s at most), re-anchor
            self.get_logger().warn(
                f'cannot keep up with real_time_factor {rtf:g} (a step takes longer than '
                f'{dt / rtf:.4g} s of wall time); running as fast as possible instead',
                throttle_duration_sec=10.0)
            self._reanchor()
            self._anchor_wall -= dt / rtf   # allow one step now
        # whole steps to real time x rtf (1e-6 of a step to spare)
        due = int((self._anchor_sim + rtf * (now - self._anchor_wall) - self.world.time) / dt
                  + 1e-6)
        if due >= 1:
            self._advance(min(due, BATCH_STEPS))
            return 0.0
        # the next step ends at world.time + dt: due when real time x rtf reaches it
        due_wall = self._anchor_wall + (self.world.time + dt * (1.0 - 1e-6)
                                        - self._anchor_sim) / rtf
        return max(due_wall - now, 0.0)

    def _stop_stepping_thread(self) -> None:
        stepper = self._stepper
        if stepper is None or stepper is threading.current_thread():
            return
        self._stepper_quit.set()
        self._stepper_wake.set()
        stepper.join(timeout=10.0)

    def _reanchor(self) -> None:
        self._anchor_wall = time.monotonic()
        self._anchor_sim = self.world.time

    def _stop_requested(self) -> bool:
        """A SIGINT/SIGTERM was noted (`_shutdown_on_signal`): shut the context down from
        here, in a callback, where no rclpy lock is held; spin() then returns."""
        if _STOP_SIGNAL['received']:
            rclpy.try_shutdown()
            return True
        return False

    @_locked
    def _on_step_timer(self) -> None:
        if self._stop_requested() or self.paused:
            return
        rtf = self.config.real_time_factor
        if rtf == 0.0:
            now = time.monotonic()
            deadline = now + AFAP_BATCH_WALL
            while (not self.paused and now < deadline
                   and not _STOP_SIGNAL['received'] and self.context.ok()):
                taken = self._advance(self._afap_steps())
                if not taken:
                    break
                now, before = time.monotonic(), now
                self._wall_per_step = (now - before) / taken
            return
        # the stepping thread's rounds, until none is due or after AFAP_BATCH_WALL (the
        # executor's turn: commands and services are never starved)
        deadline = time.monotonic() + AFAP_BATCH_WALL
        while self._pace() == 0.0 and time.monotonic() < deadline:
            pass

    # -------------------------------------------------------------------- steps ----
    def _afap_steps(self) -> int:
        """Steps per `_advance` as fast as possible: a quarter of AFAP_BATCH_WALL at the wall
        time per step measured so far, 1 to AFAP_BATCH_STEPS (a small scene takes its steps
        in few compiled calls, a large one still hands the executor back in time)."""
        per = self._wall_per_step
        if not per > 0.0:
            return 1
        return max(1, min(AFAP_BATCH_STEPS, int(0.25 * AFAP_BATCH_WALL / per)))

    def _advance(self, n: int) -> int:
        """Up to n steps of the loop (batched; commands at their step boundaries)."""
        taken = self.loop.advance(n)
        self._stats_steps += taken
        if self.live is not None:
            self.live.publish_loop(self.loop)
        return taken

    def _step_once(self, force_publish: bool = False) -> bool:
        """Apply pending commands at the boundary, take one step, publish. False on failure."""
        ok = self.loop.step_once(force_publish=force_publish)
        if ok:
            self._stats_steps += 1
        if self.live is not None:
            self.live.publish_loop(self.loop, force=force_publish)
        return ok

    def _publish_diagnostics(self) -> None:
        now = time.monotonic()
        wall = max(now - self._stats_wall, 1e-9)
        achieved_rtf = self._stats_steps * self.world.dt / wall
        self._stats_wall, self._stats_steps = now, 0
        t_ns = convert.seconds_to_ns(self.world.time)
        msg = self.loop.diagnostics_msg(
            t_ns, f'{self.get_name()}: solver',
            real_time_factor_requested=self.config.real_time_factor,
            real_time_factor_achieved=achieved_rtf, recording=self.recorder is not None,
            recording_error=self.recording_error or '')
        self.diagnostics_pub.publish(msg)
        if self.recorder is not None:
            self.recorder.write(TOPIC_DIAGNOSTICS, t_ns, msg)

    @_locked
    def _on_diagnostics_timer(self) -> None:
        if self._stop_requested():
            return
        self._publish_diagnostics()
        # A SIGKILL loses at most the chunk in progress: close it every DIAGNOSTICS_PERIOD.
        self._flush_recorder()
        self._live_refresh()

    # ------------------------------------------------------------ subscriptions ----
    def _warn_throttled(self, key, text: str) -> None:
        """Warn at most once per LOG_THROTTLE s per key (rclpy's throttle is per call site)."""
        now = time.monotonic()
        last, suppressed = self._throttle.get(key, (-math.inf, 0))
        if now - last < LOG_THROTTLE:
            self._throttle[key] = (last, suppressed + 1)
            return
        if len(text) > MAX_LOG_LINE:
            text = f'{text[:MAX_LOG_LINE]}... ({len(text) - MAX_LOG_LINE} more characters)'
        if suppressed:
            text += f' ({suppressed} similar message(s) suppressed)'
        self._throttle[key] = (now, 0)
        self.get_logger().warn(text)

    def _report(self, form: str, rejections, clamps) -> None:
        """Warn of rejections and clamps, throttled per command form, joint and reason;
        entries naming joints the scene does not have are one line per message and reason."""
        unknown: dict[str, list] = {}
        for r in rejections:
            kind = r.reason.split(' ')[0]
            if r.joint is not None and r.joint not in self.joint_names:
                unknown.setdefault(kind, []).append(r)
                continue
            self._warn_throttled(('reject', form, r.joint, kind), f'{form} command: {r}'
                                 if form == 'array' and r.joint is not None else str(r))
        for kind, rs in unknown.items():
            names = ', '.join(repr(r.joint if len(r.joint) <= 40 else r.joint[:40] + '...')
                              for r in rs[:5])
            more = f' and {len(rs) - 5} more' if len(rs) > 5 else ''
            reason = rs[0].reason.replace(f'{rs[0].joint!r}', 'the joint')
            self._warn_throttled(('reject', form, None, 'unknown', kind),
                                 str(rs[0]) if len(rs) == 1 else
                                 f'{form} command: {len(rs)} entries rejected, joints {names}'
                                 f'{more}: {reason}')
        for c in clamps:
            self._warn_throttled(('clamp', form, c.joint, c.applied > 0), str(c))

    @_locked
    def _on_command(self, kind: str, joint: Optional[str], msg) -> None:
        """Queue a command message of `kind` for its step boundary; warn of what it lost."""
        if kind == 'array':
            value = convert.array_values(msg)
        elif kind == 'joint_state':
            value = {'name': msg.name, 'position': msg.position, 'velocity': msg.velocity,
                     'effort': msg.effort}
        else:
            value = msg.data
        self._report(COMMAND_FORMS[kind], *queue_command(self.commands, kind, joint, value))

    # ----------------------------------------------------------------- services ----
    @staticmethod
    def _answer(response, success: bool, message: str):
        response.success, response.message = success, message
        return response

    @_locked
    def _srv_pause(self, request, response):
        was = self.paused
        self.paused = True
        self._flush_recorder()
        return self._answer(response, True, f'paused at t={self.world.time:.6f} s'
                            + (' (already)' if was else ''))

    @_locked
    def _srv_unpause(self, request, response):
        was = self.paused
        self.paused = False
        self._reanchor()
        self._stepper_wake.set()
        return self._answer(response, True, f'running from t={self.world.time:.6f} s'
                            + ('' if was else ' (was not paused)'))

    @_locked
    def _srv_step(self, request, response):
        if not self.paused:
            return self._answer(response, False, 'not paused: call ~/pause first')
        ok = self._step_once(force_publish=True)
        return self._answer(response, ok, f't={self.world.time:.6f} s')

    @_locked
    def _srv_reset(self, request, response):
        self.loop.reset()
        self._reanchor()
        self._stepper_wake.set()
        self._live_refresh(force=True)
        self.get_logger().info('reset: initial state, t=0, torque commands cleared')
        return self._answer(response, True, f'reset to t={self.world.time:.6f} s')

    # ---------------------------------------------------------------- live view ----
    def _start_live(self):
        """The live view (abd_joint_sim/live, docs/live.md) when live_port is set, with
        ~/pause, ~/unpause, ~/step, ~/reset as its services; if it cannot start (port taken,
        no foxglove-sdk) one error line says why and the node runs without it."""
        if not self.config.live_port:
            return None
        from abd_joint_sim.live import LiveError, LiveServer

        def trigger(service):
            def call():
                response = service(Trigger.Request(), Trigger.Response())
                return response.success, response.message
            return call
        try:
            live = LiveServer(
                self.scene, self.joint_names, self.config.live_port, self.config.live_host,
                world_frame=self.config.marker_frame_id, name=self.get_fully_qualified_name(),
                services={name: trigger(getattr(self, f'_srv_{name}'))
                          for name in ('pause', 'unpause', 'step', 'reset')},
                log=lambda level, text: getattr(self.get_logger(), level)(text)).start()
        except LiveError as exc:
            self.get_logger().error(f'{exc}; the simulation runs without the live view')
            return None
        self.get_logger().info(live.describe())
        return live

    def _live_refresh(self, force: bool = False) -> None:
        """Publish the current state to the live view after a reset (`force`) or for a
        client that subscribed (also while paused); the lock is held."""
        if self.live is not None and (force or self.live.refresh_due):
            self.live.publish_loop(self.loop, force=True)

    # ---------------------------------------------------------------- recording ----
    def _open_recorder(self, path: str) -> None:
        try:
            bag_data = bag_custom_data(
                self.config, self.config.scene, getattr(self.scene, 'source_text', '') or '',
                self.world.dt, self.commands.order,
                urdf_text=getattr(self.scene, 'robot_description', '') or '')
            self.recorder = Recording.open(
                path, bag_data, self.actuated, self.resolve_topic_name,
                self.get_fully_qualified_name(),
                markers=self.loop.markers is not None, on_error=self._recording_failed)
        except Exception as exc:  # noqa: BLE001 - BagError, ImportError, OSError, ...
            self.get_logger().error(f'recording to {path!r} disabled: {exc}')
            self.recording_error = str(exc)
            self.recorder = None
            self.config.record = ''

    def _recording_failed(self, why: str) -> None:
        self.recording_error = why
        self.get_logger().error(
            f'recording stopped: {why}. The simulation goes on; complete the bag with '
            f'`python -m abd_joint_sim.tools.bag_recover {self.config.record}`')
        self._close_recorder()
        self._publish_diagnostics()

    def _flush_recorder(self) -> None:
        if self.recorder is not None:
            self.recorder.flush()           # a failure: _recording_failed

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
        enabled = [j for j in self.actuated if self.world.effort_enabled(j)]
        limits = (', '.join(f'{j}={v:g}' for j, v in self.commands.limits.items())
                  or 'none')
        ns = self.get_namespace().rstrip('/')
        g = self.world.model.gravity
        gravity = (f'gravity ({g[0]:g}, {g[1]:g}, {g[2]:g}) m/s²' if any(g != 0.0)
                   else 'no gravity')
        self.get_logger().info(
            f'scene {c.scene} | dt {self.world.dt:g} s | {gravity} | '
            'not simulated: contact and collision (bodies pass through each other) | '
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
        """Stop stepping (the stepping thread ends its round first) and finalise the bag
        (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._stop_stepping_thread()
        with self._lock:
            self.paused = True
            self._close_recorder()
        if self.live is not None:
            self.live.close()


class _NodeOutput(LoopOutput):
    """The loop's output in the node: publishers, the recorder and the log. /clock and
    /joint_states are serialised once (convert.ClockEncoder, JointStateEncoder), published
    and recorded as the same bytes; in a batch the recording holds /clock back and writes it
    in one call (Recording.clock)."""

    markers_serialized = True       # MarkerBuilder.build_serialized: bytes, as above

    def __init__(self, node: SimNode):
        self.node = node
        self._clock_subscribed = True

    def _record(self, what: str, *args) -> None:
        if self.node.recorder is not None:
            getattr(self.node.recorder, what)(*args)

    @property
    def markers_wanted(self) -> bool:
        node = self.node
        return node.marker_pub is not None and (
            node.recorder is not None or node.marker_pub.get_subscription_count() > 0)

    def clock(self, t_ns: int) -> None:
        self.clocks([t_ns])

    def clocks(self, stamps_ns: list) -> None:
        node = self.node
        if not self._clock_subscribed and node.recorder is None:
            return                          # nobody receives them, nothing records them
        datas = node.clock_encoder.encode_many(stamps_ns)
        if self._clock_subscribed:
            publish = node.clock_publish_raw
            for data in datas:
                publish(data)
        self._record('clocks', stamps_ns, datas)

    def batch_begin(self) -> None:
        self._record('batch_begin')
        # /clock is best effort with depth 1 (as Gazebo's): a batch's /clock is published
        # only when a subscriber is matched as the batch begins (asked once per batch); one
        # matched during a batch gets /clock from the next, as if discovery took longer.
        self._clock_subscribed = self.node.clock_pub.get_subscription_count() > 0

    def batch_end(self) -> None:
        self._clock_subscribed = True
        self._record('batch_end')

    def joint_state(self, t_ns: int, position, velocity, effort) -> None:
        data = self.node.joint_state_encoder.encode(t_ns, position, velocity, effort)
        self.node.joint_state_publish_raw(data)
        self._record('joint_state', t_ns, data)

    def markers(self, t_ns: int, data) -> None:
        self.node.marker_pub.publish(data)
        self._record('markers', t_ns, data)

    applied = functools.partialmethod(_record, 'applied')
    restarted = functools.partialmethod(_record, 'restarted')
    parameters = functools.partialmethod(_record, 'parameters')

    def log(self, level: str, text: str, key=None) -> None:
        if key is not None and level == 'warn':
            self.node._warn_throttled(key, text)
        else:
            getattr(self.node.get_logger(), level)(text)

    def faulted(self, why: str) -> None:
        self.node._publish_diagnostics()
        self.node._flush_recorder()


_STOP_SIGNAL = {'received': False}


def _shutdown_on_signal(signum, frame):
    """SIGINT/SIGTERM: only note it; the node's timers shut the ROS context down at their next
    call (`SimNode._stop_requested`), and spin() returns between callbacks (docs/decisions.md:
    neither KeyboardInterrupt nor rclpy.try_shutdown() here)."""
    _STOP_SIGNAL['received'] = True


def _robot_description_to_params_file(args: list[str]) -> tuple[list[str], Optional[str]]:
    """Move ``-p robot_description:=<URDF text>`` into a temporary params file at the same
    place in the arguments (rcl parses ``-p`` values as YAML, which URDF text rarely survives;
    a YAML writer quotes it). Returns (new args, the file to delete after rclpy.init, or
    None)."""
    import tempfile
    import yaml
    key = 'robot_description:='
    out: list[str] = []
    path = None
    for arg in args:
        if arg.startswith(key) and out[-1:] in (['-p'], ['--param']):
            with tempfile.NamedTemporaryFile('w', suffix='.yaml', prefix='robot_description_',
                                             delete=False) as f:
                yaml.safe_dump({'/**': {'ros__parameters': {
                    'robot_description': arg[len(key):]}}}, f)
            path = f.name
            out[-1:] = ['--params-file', path]
        else:
            out.append(arg)
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
        node.start_stepping_thread()
        rclpy.spin(node)
        if node.stepper_error is not None:      # said already; the node shut itself down
            status = 1
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
