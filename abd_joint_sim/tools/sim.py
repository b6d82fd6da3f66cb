"""The headless stepping loop and the recorder, mirroring sim_node without DDS.

:class:`HeadlessSim` owns a ``World`` and the node's :class:`~abd_joint_sim.ros.commands.
CommandBuffer`. For every step it hands the commands due at that step boundary to the buffer
(as the node's subscription callbacks do), applies them (``CommandBuffer.apply``: same
validation, clamping, command timeout), steps, and tells an observer. Between segments of a
plan it resets like the node's ``~/reset`` service.

:class:`BagRecorder` is the observer ``run_headless`` uses: it writes sim_node's bag layout
(topics, types, QoS, custom data, attachments; messages built by ``ros.convert``) with the
node's publishing rules: ``/clock`` after every step, ``/joint_states`` at ``publish_rate``
(and the initial/reset state always), commands as applied at their step boundary, live
parameter changes on ``/parameter_events``. Those rules live in :mod:`abd_joint_sim.ros.
recording`, shared with the node; only the stepping loop is re-stated here.
"""
from __future__ import annotations

from collections import deque
import time
from typing import Any, Optional, Protocol

from abd_joint_sim.ros import convert
from abd_joint_sim.ros.commands import Applied, CommandBuffer
from abd_joint_sim.ros.params import coerce, NODE_NAME, SimConfig
from abd_joint_sim.ros.markers import MarkerBuilder, TOPIC_MARKERS
from abd_joint_sim.ros.recording import (add_node_topics, bag_custom_data, markers_due,
                                         parameter_event_msg,
                                         PublishSchedule, record_applied, resolve_root,
                                         TOPIC_CLOCK, TOPIC_DIAGNOSTICS, TOPIC_JOINT_STATES,
                                         TOPIC_PARAMETER_EVENTS)

from .schedule import Command, Plan

NODE_FQN = '/' + NODE_NAME
DIAGNOSTICS_PERIOD_NS = convert.NS_PER_S   # headless: one /diagnostics per simulated second


class Observer(Protocol):
    def on_state(self, sim: 'HeadlessSim', segment: int, force: bool) -> None: ...

    def on_applied(self, sim: 'HeadlessSim', applied: Applied) -> None: ...

    # Optional: def on_parameters(self, sim, t_ns: int, changes: dict) -> None



class HeadlessSim:
    """A World driven by a :class:`Plan`, with sim_node's command semantics.

    :param clamp: apply the ``effort_limits`` parameter (True for a schedule; False when the
        commands come from a bag, where they are stored already clamped, so that a live
        change of the limits during the recorded run cannot clamp them a second time).
    """

    def __init__(self, scene: Any, config: SimConfig, clamp: bool = True):
        from abd_joint_sim import World
        self.scene = scene
        self.config = config
        self.world = World(scene, dt=config.time_step or None)
        self.actuated = list(self.world.actuated_joint_names)
        limits = getattr(self.world.model, 'torque_effort_limit', None)
        scene_limits = ({} if limits is None else
                        {j: float(v) for j, v in zip(self.actuated, limits)})
        self.commands = CommandBuffer(self.actuated, config.joints,
                                      config.effort_limits if clamp else [],
                                      config.command_timeout, scene_limits=scene_limits,
                                      driven=[j.name for j in getattr(scene, 'joints', ())
                                              if getattr(j, 'driving', None) is not None])
        config.joints = list(self.commands.order)
        self.steps = 0
        self.not_converged = 0
        self.clamp = clamp
        self.publish_schedule = PublishSchedule()
        self.clamps: list[tuple[Command, Any]] = []
        self.unapplied: list[Command] = []
        self.observer: Optional[Observer] = None

    def fresh_buffer(self) -> CommandBuffer:
        """A CommandBuffer configured as this run's, for checking a plan before it runs."""
        return CommandBuffer(self.actuated, self.commands.order,
                             self.config.effort_limits if self.clamp else [], 0.0,
                             scene_limits=self.commands.scene_limits)

    @property
    def time_ns(self) -> int:
        return convert.seconds_to_ns(self.world.time)

    def reset(self) -> None:
        """As sim_node's ``~/reset``: initial state, t = 0, torque commands cleared to 0."""
        self.world.reset()
        self.commands.clear()
        for joint in self.actuated:
            self.world.set_torque(joint, 0.0)

    def _queue(self, cmd: Command) -> None:
        """Hand one command to the buffer, as the node's subscription callback would."""
        if cmd.kind == 'parameter':
            self._set_parameters(cmd)
            return
        if cmd.kind == 'enable':
            rejections, clamps = self.commands.command_enable(cmd.joint, cmd.value), []
        elif cmd.kind == 'enable_all':
            self.commands.command_enable_all(cmd.value)
            rejections, clamps = [], []
        elif cmd.kind == 'array':
            rejections, clamps = self.commands.command_array(cmd.value)
        elif cmd.kind == 'torque':
            rejections, clamps = self.commands.command_torque(cmd.joint, cmd.value)
        elif cmd.kind == 'joint_state':
            v = cmd.value
            rejections, clamps = self.commands.command_joint_state(
                v['name'], v.get('position', []), v.get('velocity', []), v.get('effort', []))
        else:
            raise ValueError(f'{cmd.describe()}: unknown command kind {cmd.kind!r}')
        if rejections:
            # check_plan() refuses these before the run; here only as a safety net.
            raise ValueError(f'{cmd.describe()}: {rejections[0]}')
        self.clamps.extend((cmd, c) for c in clamps)

    def _set_parameters(self, cmd: Command) -> None:
        """A live parameter change, as sim_node's post-set callback applies it."""
        changes = {}
        for name, value in cmd.value.items():
            try:
                value = coerce(name, value)
            except (KeyError, ValueError) as exc:
                raise ValueError(f'{cmd.describe()}: parameter {name}: {exc}') from None
            changes[name] = value
            if name == 'command_timeout':
                self.commands.command_timeout = value
            elif name == 'publish_rate':
                self.config.publish_rate = value
                self.publish_schedule.restart()
            elif name == 'effort_limits' and self.clamp:
                self.commands.set_effort_limits(value)
            if hasattr(self.config, name):
                setattr(self.config, name, value)
        on_parameters = getattr(self.observer, 'on_parameters', None)
        if on_parameters is not None and changes:
            on_parameters(self, self.time_ns, changes)

    def run(self, plan: Plan, observer: Observer) -> None:
        """Simulate every segment of `plan`; raises SimulationError if a step fails."""
        self.observer = observer
        for k, seg in enumerate(plan.segments):
            if k > 0:
                self.reset()
            observer.on_state(self, k, True)
            pending = deque(seg.commands)
            while self.time_ns < seg.end_ns:
                now = self.time_ns
                while pending and pending[0].t_ns <= now:
                    self._queue(pending.popleft())
                applied = self.commands.apply(self.world)
                if applied:
                    observer.on_applied(self, applied)
                report = self.world.step()
                self.steps += 1
                if not getattr(report, 'converged', True):
                    self.not_converged += 1
                observer.on_state(self, k, False)
            # A live parameter change logged at the segment's last time (set, then ~/reset
            # or the end before another step) took effect in the node at once and stays in
            # force across the reset: apply it here too. Commands cannot be in this
            # position (the node logs them only as a step boundary applies them).
            while pending and pending[0].kind == 'parameter' and pending[0].t_ns <= self.time_ns:
                self._queue(pending.popleft())
            self.unapplied.extend(pending)


class BagRecorder:
    """Observer writing sim_node's bag layout through ``abd_joint_sim.record.BagWriter``."""

    def __init__(self, path: str, sim: HeadlessSim, scene_path: str, scene_text: str,
                 extra_custom: Optional[dict[str, str]] = None, urdf_text: str = ''):
        from abd_joint_sim.record import BagWriter
        self.sim = sim
        custom, attachments = bag_custom_data(sim.config, scene_path, scene_text, sim.world.dt,
                                              sim.commands.order, extra_custom, urdf_text)
        self.writer = BagWriter(path, custom_data=custom, attachments=attachments)
        self.writer.open()
        self.markers = None
        self.marker_schedule = PublishSchedule()
        try:
            if sim.config.marker_rate > 0.0:
                self.markers = MarkerBuilder(sim.scene, sim.config.marker_frame_id,
                                             sim.config.marker_joint_axes)
            add_node_topics(self.writer, resolve_root, sim.actuated,
                            markers=self.markers is not None)
        except BaseException:
            self.writer.close()
            raise
        self.joint_names = list(sim.world.joint_names)
        self._next_diag_ns = DIAGNOSTICS_PERIOD_NS
        self._wall0 = time.monotonic()
        self.counts: dict[str, int] = {}

    def _write(self, topic: str, t_ns: int, msg: Any) -> None:
        self.writer.write(topic, t_ns, msg)
        self.counts[topic] = self.counts.get(topic, 0) + 1

    # -- Observer -------------------------------------------------------------------------
    def on_state(self, sim: HeadlessSim, segment: int, force: bool) -> None:
        """sim_node's ``_publish_state``: /clock always, /joint_states when due."""
        world = sim.world
        t_ns = sim.time_ns
        self._write(TOPIC_CLOCK, t_ns, convert.clock_msg(t_ns))
        if force:           # start or reset: the node's diagnostics restart too
            self._next_diag_ns = t_ns + DIAGNOSTICS_PERIOD_NS
        # As sim_node: markers (when due), then /joint_states (when due).
        if self.markers is not None and markers_due(self.marker_schedule, t_ns,
                                                    sim.config.marker_rate, force):
            markers = self.markers.build(t_ns, world.body_pose)
            if markers is not None:
                self._write(resolve_root(TOPIC_MARKERS), t_ns, markers)
        if sim.publish_schedule.due(t_ns, sim.config.publish_rate, force):
            self._write(resolve_root(TOPIC_JOINT_STATES), t_ns, convert.joint_state_msg(
                t_ns, self.joint_names, world.joint_angles(), world.joint_velocities(),
                world.applied_torques(), sim.config.frame_id))
        if not force and t_ns >= self._next_diag_ns:
            self._next_diag_ns = t_ns + DIAGNOSTICS_PERIOD_NS
            self._write(TOPIC_DIAGNOSTICS, t_ns, self._diagnostics(sim, t_ns))

    def on_applied(self, sim: HeadlessSim, applied: Applied) -> None:
        """sim_node's commands as applied (``recording.record_applied``)."""
        record_applied(self._write, resolve_root, applied)

    def on_parameters(self, sim: HeadlessSim, t_ns: int, changes: dict) -> None:
        """sim_node's record of a live parameter change."""
        self._write(TOPIC_PARAMETER_EVENTS, t_ns, parameter_event_msg(t_ns, NODE_FQN, changes))

    def _diagnostics(self, sim: HeadlessSim, t_ns: int):
        last = getattr(sim.world, 'last_step', None)
        converged = bool(getattr(last, 'converged', True))
        wall = max(time.monotonic() - self._wall0, 1e-9)
        values = {
            'sim_time': float(sim.world.time),
            'steps': sim.steps,
            'paused': False,
            'time_step': float(sim.world.dt),
            'real_time_factor_requested': 0.0,
            'real_time_factor_achieved': float(sim.world.time) / wall,
            'newton_iterations': getattr(last, 'newton_iterations', 0),
            'line_search_iterations': getattr(last, 'line_search_iterations', 0),
            'converged': converged,
            'not_converged_steps_total': sim.not_converged,
            'max_joint_separation': float(getattr(last, 'max_joint_separation', 0.0)),
            'substeps': getattr(last, 'substeps', 1),
            'recording': True,
        }
        ok = converged and not (getattr(last, 'warnings', None) or [])
        return convert.diagnostics_msg(t_ns, f'{NODE_NAME}: solver', NODE_NAME, ok,
                                       'running' if ok else 'solver warnings', values)

    def close(self) -> None:
        self.writer.close()
