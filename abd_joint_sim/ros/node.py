"""sim_node: steps an abd_joint_sim World and talks ROS 2 (see README "Topics & services").

The node is thin: parameters come from :mod:`.params`, commands are validated, clamped and
buffered by :mod:`.commands`, messages are built by :mod:`.convert`. Callbacks only fill the
pending-command buffer; the step timer applies it at the step boundary, steps, publishes
copies and records. ``rclpy.spin`` runs a single-threaded executor, so callbacks never
overlap with a step and the buffer needs no lock.
"""
from __future__ import annotations

import math
import signal
import sys
import time
from typing import Any, Optional

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64, Float64MultiArray
from std_srvs.srv import Trigger

from . import convert
from .commands import Applied, CommandBuffer
from .params import (check_live_value, coerce, config_from_values, default_scene_path,
                     NODE_NAME, PARAMS, PARAMS_BY_NAME)
from .recording import (add_node_topics, bag_custom_data, parameter_event_msg,
                        PublishSchedule, RECORDED_PARAMETERS, record_applied,
                        TOPIC_CLOCK, TOPIC_DIAGNOSTICS, TOPIC_ENABLE_ALL, TOPIC_ENABLE_JOINT,
                        TOPIC_JOINT_STATES, TOPIC_PARAMETER_EVENTS, TOPIC_TORQUE_ARRAY,
                        TOPIC_TORQUE_JOINT)

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
        self.config = config_from_values(self._declare_parameters())

        # Scene and world. Imported here so that `--help`-like failures stay cheap.
        from abd_joint_sim import Scene, World
        self.scene = Scene.from_yaml(self.config.scene)
        self.world = World(self.scene, dt=self.config.time_step or None)
        self.joint_names = list(self.world.joint_names)
        self.actuated = list(self.world.actuated_joint_names)
        self.commands = CommandBuffer(self.actuated, self.config.joints,
                                      self.config.effort_limits, self.config.command_timeout,
                                      scene_limits=self._scene_effort_limits())
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

        # Subscriptions: only actuated joints get command topics.
        self.command_subs = [
            self.create_subscription(Float64MultiArray, TOPIC_TORQUE_ARRAY,
                                     self._on_torque_array, COMMAND_QOS),
            self.create_subscription(Bool, TOPIC_ENABLE_ALL, self._on_enable_all, COMMAND_QOS),
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
        self.step_timer = None
        self._make_step_timer()
        self.diagnostics_timer = self.create_timer(DIAGNOSTICS_PERIOD,
                                                   self._on_diagnostics_timer)

        self._log_start()
        # The initial state, so subscribers see t = 0 even when starting paused.
        self._publish_state(force=True)

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
        self.step_timer = self.create_timer(period, self._on_step_timer)

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
                    self.get_logger().warn(
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

    def _report(self, rejections, clamps) -> None:
        for r in rejections:
            kind = r.reason.split(' ')[0]
            self._warn_throttled(('reject', r.joint, kind), str(r))
        for c in clamps:
            self._warn_throttled(('clamp', c.joint, c.applied > 0), str(c))

    def _on_torque_array(self, msg: Float64MultiArray) -> None:
        self._report(*self.commands.command_array(convert.array_values(msg)))

    def _on_torque_joint(self, joint: str, msg: Float64) -> None:
        self._report(*self.commands.command_torque(joint, msg.data))

    def _on_enable_joint(self, joint: str, msg: Bool) -> None:
        self._report(self.commands.command_enable(joint, msg.data), [])

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
                self.world.dt, self.commands.order)
            writer = BagWriter(path, custom_data=custom, attachments=attachments)
            writer.open()
            add_node_topics(writer, self._abs, self.actuated)
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
            f'{ns}/{TOPIC_ENABLE_ALL}[/<joint>] | services ~/pause ~/unpause ~/step ~/reset | '
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


def _raise_keyboard_interrupt(signum, frame):
    raise KeyboardInterrupt


def main(args: Optional[list[str]] = None) -> int:
    rclpy.init(args=args)
    # SIGTERM (kill, systemd, launch) ends the node like Ctrl-C, so the bag is finalised.
    signal.signal(signal.SIGTERM, _raise_keyboard_interrupt)
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
