"""The headless driver of sim_node's loop (``ros/loop.py``), and the bag recorder.

:class:`HeadlessSim` drives the node's :class:`~abd_joint_sim.ros.loop.SimLoop` from a
:class:`Plan`; :class:`BagRecorder` is the loop output writing sim_node's bag layout.
"""
from __future__ import annotations

from collections import deque
import time
from typing import Any, Optional

from abd_joint_sim.ros import convert
from abd_joint_sim.ros.commands import Applied, CommandBuffer
from abd_joint_sim.ros.loop import LoopOutput, queue_command, SimLoop, steps_until
from abd_joint_sim.ros.params import NODE_NAME, SimConfig
from abd_joint_sim.ros.recording import bag_custom_data, Recording, resolve_root
from abd_joint_sim.ros.topics import TOPIC_DIAGNOSTICS

from .schedule import Command, Plan

NODE_FQN = '/' + NODE_NAME
DIAGNOSTICS_PERIOD_NS = convert.NS_PER_S   # headless: one /diagnostics per simulated second


class _ObserverOutput(LoopOutput):
    """A plain observer as a loop output: called after every step with the world there."""

    world_each_step = True

    def __init__(self, sim: 'HeadlessSim', observer: Any):
        self.sim, self.observer = sim, observer

    def applied(self, applied: Applied) -> None:
        self.observer.on_applied(self.sim, applied)

    def parameters(self, t_ns: int, changes) -> None:
        on_parameters = getattr(self.observer, 'on_parameters', None)
        if on_parameters is not None:
            on_parameters(self.sim, t_ns, dict(changes))

    def stepped(self, t_ns: int, force: bool) -> None:
        self.observer.on_state(self.sim, self.sim.segment, force)


class HeadlessSim:
    """sim_node's loop driven by a :class:`Plan` (no DDS, as fast as possible).

    :param clamp: apply the ``effort_limits`` parameter (True for a schedule; False when the
        commands come from a bag, where they are stored already clamped).
    """

    def __init__(self, scene: Any, config: SimConfig, clamp: bool = True):
        self.loop = SimLoop(scene, config, clamp=clamp, raise_faults=True)
        self.segment = 0
        self.clamps: list[tuple[Command, Any]] = []
        self.unapplied: list[Command] = []

    def __getattr__(self, name: str):
        """The loop's own: world, actuated, commands, steps, time_ns, reset(), ..."""
        if name == 'loop':
            raise AttributeError(name)
        return getattr(self.loop, name)

    def fresh_buffer(self) -> CommandBuffer:
        """A CommandBuffer configured as this run's, for checking a plan before it runs."""
        return CommandBuffer(self.actuated, self.commands.order,
                             self.config.effort_limits if self.clamp else [], 0.0,
                             scene_limits=self.commands.scene_limits, driven=self.commands.driven)

    def _queue(self, cmd: Command) -> None:
        """Hand one command to the loop, as the node's subscription callback would."""
        if cmd.kind == 'parameter':
            try:
                self.loop.set_parameters(cmd.value)
            except (KeyError, ValueError) as exc:
                raise ValueError(f'{cmd.describe()}: parameter: {exc}') from None
            return
        try:
            rejections, clamps = queue_command(self.commands, cmd.kind, cmd.joint, cmd.value)
        except ValueError as exc:
            raise ValueError(f'{cmd.describe()}: {exc}') from None
        if rejections:
            # check_plan() refuses these before the run; here only as a safety net.
            raise ValueError(f'{cmd.describe()}: {rejections[0]}')
        self.clamps.extend((cmd, c) for c in clamps)

    def run(self, plan: Plan, output: Any, pace: Any = None) -> None:
        """Simulate every segment of `plan` into `output` (a :class:`LoopOutput`, or a plain
        observer with ``on_state(sim, segment, force)``, ``on_applied(sim, applied)`` and
        optionally ``on_parameters(sim, t_ns, changes)``, called after every step); raises
        SimulationError if a step fails. `pace(n)`, if given, is called before each advance
        of up to n steps and returns how many to take now (1..n): when, never what."""
        loop = self.loop
        loop.output = output if isinstance(output, LoopOutput) else _ObserverOutput(self, output)
        for k, seg in enumerate(plan.segments):
            self.segment = k
            if k > 0:
                loop.reset()
            else:
                loop.publish_state(force=True)
            pending = deque(seg.commands)
            while loop.time_ns < seg.end_ns:
                now = loop.time_ns
                while pending and pending[0].t_ns <= now:
                    self._queue(pending.popleft())
                until = min(pending[0].t_ns, seg.end_ns) if pending else seg.end_ns
                n = steps_until(until, now, loop.world.dt)
                loop.advance(n if pace is None else pace(n))
            # A live parameter change logged at the segment's last time (set, then ~/reset
            # or the end before another step) took effect in the node at once and stays in
            # force across the reset: apply it here too. Commands cannot be in this
            # position (the node logs them only as a step boundary applies them).
            while pending and pending[0].kind == 'parameter' and pending[0].t_ns <= loop.time_ns:
                self._queue(pending.popleft())
            self.unapplied.extend(pending)


class BagRecorder(LoopOutput):
    """Loop output writing sim_node's bag layout (:class:`~abd_joint_sim.ros.recording.
    Recording`, as the node does), plus ``/diagnostics`` once per simulated second.
    `reproducible`: the same bytes on every run (attachment time 0, the padding of the
    messages it serialises zeroed, no wall-clock value: real_time_factor_achieved 0)."""

    markers_wanted = True
    # /clock, the joint states and the markers as the node records them: the same checked
    # CDR bytes (convert.ClockEncoder, JointStateEncoder, MarkerBuilder.build_serialized).
    markers_serialized = True

    def __init__(self, path: str, sim: HeadlessSim, scene_path: str, scene_text: str,
                 extra_custom: Optional[dict[str, str]] = None, urdf_text: str = '',
                 reproducible: bool = False):
        self.sim, self.reproducible = sim, reproducible
        self._clock = convert.ClockEncoder()
        self._joint_state = convert.JointStateEncoder(sim.loop.joint_names, sim.config.frame_id)
        bag_data = bag_custom_data(sim.config, scene_path, scene_text, sim.world.dt,
                                   sim.commands.order, extra_custom, urdf_text)
        self.recording = Recording.open(path, bag_data, sim.actuated, resolve_root, NODE_FQN,
                                        markers=sim.loop.markers is not None,
                                        attachment_time_ns=0 if reproducible else None,
                                        zero_padding=reproducible)
        self.counts = self.recording.counts
        rec = self.recording        # what the loop hands on unchanged
        self.batch_begin, self.batch_end, self.markers = rec.batch_begin, rec.batch_end, rec.markers
        self.applied, self.restarted, self.parameters = rec.applied, rec.restarted, rec.parameters
        # One /diagnostics per simulated second, on the loop's grid.
        sim.loop.diagnostics_period_ns = DIAGNOSTICS_PERIOD_NS
        sim.loop.next_diagnostics_ns = DIAGNOSTICS_PERIOD_NS
        self._wall0 = time.monotonic()

    def clock(self, t_ns: int) -> None:
        self.recording.clock(t_ns, self._clock.encode(t_ns))

    def clocks(self, stamps_ns: list) -> None:
        self.recording.clocks(stamps_ns, self._clock.encode_many(stamps_ns))

    def joint_state(self, t_ns: int, position, velocity, effort) -> None:
        self.recording.joint_state(t_ns, self._joint_state.encode(t_ns, position, velocity,
                                                                  effort))

    def diagnostics(self, t_ns: int) -> None:
        wall = max(time.monotonic() - self._wall0, 1e-9)
        rtf = 0.0 if self.reproducible else float(self.sim.world.time) / wall
        self.recording.write(TOPIC_DIAGNOSTICS, t_ns, self.sim.loop.diagnostics_msg(
            t_ns, f'{NODE_NAME}: solver', real_time_factor_requested=0.0,
            real_time_factor_achieved=rtf, recording=True))

    def close(self) -> None:
        self.recording.close()
