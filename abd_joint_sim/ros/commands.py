"""Torque and enable commands between ROS callbacks and the simulation step, in plain Python.

:class:`CommandBuffer` validates incoming values (finite, right length, known actuated joint),
clamps torques to the effort limits and keeps the latest per joint pending; at the next step
boundary :meth:`CommandBuffer.apply` writes them into the world and runs the command timeout
(simulated time: the torque goes to 0 at the first boundary with ``t - t_cmd >= timeout``).
A joint without an effort limit rejects values beyond :data:`MAX_ABS_TORQUE`
(docs/robustness.md).
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
import math
from typing import Any, Iterable, Mapping, Optional, Sequence

from ..scene import MAX_ABS_AIM

MAX_ABS_TORQUE = 1e9
"""[N m] Largest torque magnitude accepted on a joint without an effort limit."""


@dataclass(frozen=True)
class Rejection:
    """A refused command: which joint (or None for a whole array), the value, the reason."""

    joint: Optional[str]
    value: object
    reason: str
    topic: str = ''
    """Set for a whole-message rejection on a topic other than the array command."""

    def __str__(self) -> str:
        who = (f'joint {self.joint!r}' if self.joint is not None
               else f'{self.topic} command' if self.topic else 'array command')
        value = self.value
        if isinstance(value, (list, tuple)) and len(value) > 8:    # a long array: its head
            shown = f'{repr(list(value[:8]))[:-1]}, ... ({len(value)} values)]'
        else:
            shown = repr(value)
        return f'{who}: {shown} rejected: {self.reason}'


@dataclass(frozen=True)
class Clamp:
    joint: str
    requested: float
    applied: float
    limit: float

    def __str__(self) -> str:
        return (f'joint {self.joint!r}: torque {self.requested:g} N m clamped to '
                f'{self.applied:g} (effort limit {self.limit:g})')


@dataclass
class Applied:
    """What took effect at one step boundary (all lists empty when nothing did)."""

    time: float
    torques: dict[str, float] = field(default_factory=dict)
    """joint -> torque [N m] written into the world (after clamping)."""
    enables: dict[str, bool] = field(default_factory=dict)
    timed_out: list[str] = field(default_factory=list)
    """Joints whose torque was set to 0 by the command timeout at this boundary."""
    array: Optional[list[float]] = None
    """The array command that took effect (clamped), in `joints` order, if any."""
    enable_all: Optional[bool] = None
    """The all-joints enable command that took effect, if any."""
    sources: dict[str, str] = field(default_factory=dict)
    """joint -> 'array', 'joint' or 'joint_state': which topic its torque came from."""
    aims: dict[str, float] = field(default_factory=dict)
    """joint -> UID 19 driving aim [rad] set from a joint_commands position."""

    def __bool__(self) -> bool:
        return bool(self.torques or self.enables or self.timed_out or self.aims)


NOTHING_APPLIED = Applied(time=math.nan)
"""What `CommandBuffer.apply` returns at most boundaries (nothing pending, no timeout: an
Applied costs ~1.5 µs); falsy and shared, so never modify it."""


class CommandBuffer:
    """Pending torque/enable commands, effort limits and the command timeout.

    :param actuated: the joints that accept commands (the world's actuated joints).
    :param order: joint order of the array command (a subset or permutation of `actuated`).
    :param effort_limits: one positive limit [N m] per joint of `order`, or empty for none.
    :param command_timeout: simulated seconds [s]; 0 = off.
    :param scene_limits: joint -> the scene's own effort limit [N m] (inf = none); the
        tighter limit applies, so every clamp is reported here.
    :param driven: joints with driving (UID 19 / 21), which take position commands.
    """

    def __init__(self, actuated: Sequence[str], order: Sequence[str],
                 effort_limits: Sequence[float] = (), command_timeout: float = 0.0,
                 scene_limits: Optional[Mapping[str, float]] = None,
                 driven: Sequence[str] = ()):
        self.actuated = list(actuated)
        self.driven = list(driven)
        self._actuated_set = set(self.actuated)
        self.order = list(order) if order else list(self.actuated)
        bad = [j for j in self.order if j not in self._actuated_set]
        if bad:
            raise ValueError(
                f'parameter \'joints\': {bad} not actuated joints of the scene '
                f'(actuated: {self.actuated})')
        if len(set(self.order)) != len(self.order):
            raise ValueError(f'parameter \'joints\': duplicate names in {self.order}')
        self.scene_limits = {j: float(v) for j, v in (scene_limits or {}).items()
                             if math.isfinite(v) and v > 0.0}
        self.set_effort_limits(effort_limits)
        self.command_timeout = float(command_timeout)
        self.clear()

    def _drop_pending(self) -> None:
        self._pending_torque: dict[str, tuple[float, str]] = {}
        self._pending_enable: dict[str, bool] = {}
        self._pending_array: Optional[list[float]] = None
        self._pending_enable_all: Optional[bool] = None
        self._pending_aim: dict[str, float] = {}

    # -- configuration -----------------------------------------------------------------
    def set_effort_limits(self, limits: Sequence[float]) -> None:
        limits = list(limits)
        if limits and len(limits) != len(self.order):
            raise ValueError(
                f'parameter \'effort_limits\': {len(limits)} values for {len(self.order)} '
                f'joints {self.order}; give one per joint (in `joints` order) or none')
        for j, lim in zip(self.order, limits):
            if not (lim > 0.0):
                raise ValueError(f'parameter \'effort_limits\': {lim} for joint {j!r} not > 0')
        self.param_limits = dict(zip(self.order, (float(x) for x in limits)))
        self.limits = dict(self.scene_limits)
        for j, lim in self.param_limits.items():
            self.limits[j] = min(lim, self.limits.get(j, math.inf))

    # -- from subscription callbacks ---------------------------------------------------
    def _queue(self, joint: str, value: float, source: str, clamps: list) -> float:
        """Queue a valid torque, clamped to the joint's limit (a Clamp appended to `clamps`)."""
        lim = self.limits.get(joint)
        if lim is not None and abs(value) > lim:
            clamps.append(Clamp(joint, value, math.copysign(lim, value), lim))
            value = math.copysign(lim, value)
        self._pending_torque[joint] = (value, source)
        return value

    def _check_joint(self, joint: str) -> Optional[str]:
        if joint not in self._actuated_set:
            return f'not an actuated joint (actuated: {self.actuated})'
        return None

    def _check_value(self, joint: str, value: float) -> Optional[str]:
        if not math.isfinite(value):
            return 'torque must be finite'
        if joint not in self.limits and abs(value) > MAX_ABS_TORQUE:
            return (f'|torque| beyond {MAX_ABS_TORQUE:g} N m on a joint without an effort '
                    'limit (set effort_limits to clamp instead)')
        return None

    def command_torque(self, joint: str, value: float) -> tuple[list[Rejection], list[Clamp]]:
        """Queue one joint's torque [N m]. Returns (rejections, clamps)."""
        reason = self._check_joint(joint)
        if reason is None:
            try:
                value = float(value)
            except (TypeError, ValueError):
                reason = 'torque must be a number'
            else:
                reason = self._check_value(joint, value)
        if reason is not None:
            return [Rejection(joint, value, reason)], []
        clamps: list[Clamp] = []
        self._queue(joint, value, 'joint', clamps)
        return [], clamps

    def command_array(self, values: Iterable[float]) -> tuple[list[Rejection], list[Clamp]]:
        """Queue torques for all joints of `order`; a wrong length or a non-finite entry
        rejects the whole array (nothing is queued)."""
        values = [float(v) for v in values]
        if len(values) != len(self.order):
            return [Rejection(None, values,
                              f'expected {len(self.order)} values (joints {self.order}), '
                              f'got {len(values)}')], []
        bad = [Rejection(j, v, f'{reason}; whole array ignored')
               for j, v in zip(self.order, values)
               if (reason := self._check_value(j, v)) is not None]
        if bad:
            return bad, []
        clamps: list[Clamp] = []
        self._pending_array = [self._queue(j, v, 'array', clamps)
                               for j, v in zip(self.order, values)]
        return [], clamps

    def command_enable(self, joint: str, flag: bool) -> list[Rejection]:
        reason = self._check_joint(joint)
        if reason is not None:
            return [Rejection(joint, flag, reason)]
        self._pending_enable[joint] = bool(flag)
        return []

    def command_enable_all(self, flag: bool) -> None:
        # Later per-joint enables override; an all-joints command overrides earlier ones.
        for j in self.actuated:
            self._pending_enable[j] = bool(flag)
        self._pending_enable_all = bool(flag)

    def command_joint_state(self, names: Sequence[str], position: Sequence[float],
                            velocity: Sequence[float], effort: Sequence[float]
                            ) -> tuple[list[Rejection], list[Clamp]]:
        """A sensor_msgs/JointState on ``joint_commands`` (what topic-based ros2_control
        hardware interfaces publish): name-matched, any subset of joints; ``effort`` ->
        torque (validated and clamped like the other torque commands), ``position`` -> the
        driving (UID 19) aim. A length mismatch or a non-finite value rejects the message;
        ``velocity``, unknown joints, efforts on unactuated joints and positions on joints
        without driving are refused entry by entry (the rest applies)."""
        def whole(value, reason):       # a rejection of the message, not of one joint
            return Rejection(None, value, reason, 'joint_commands')
        names = [str(n) for n in names]
        position, velocity, effort = list(position), list(velocity), list(effort)
        for field_name, values in (('position', position), ('velocity', velocity),
                                   ('effort', effort)):
            if values and len(values) != len(names):
                return [whole(values, f'{len(values)} {field_name} values for {len(names)} '
                              'names; give one per name or none')], []
        for field_name, values in (('position', position), ('effort', effort)):
            bad = [(n, v) for n, v in zip(names, values) if not math.isfinite(float(v))]
            if bad:
                return [Rejection(bad[0][0], bad[0][1], f'{field_name} must be finite; '
                                  'whole joint_commands message ignored')], []
        if len(set(names)) != len(names):
            twice = sorted(n for n, count in Counter(names).items() if count > 1)[:5]
            return [whole(twice, 'joint name(s) given more than once; whole joint_commands '
                          'message ignored (which value would apply is not said by a '
                          'JointState)')], []
        rejections = [whole(velocity, 'velocity commands are not supported (use position '
                            'with driving, or effort); ignored')] if velocity else []
        if not position and not effort:
            rejections.append(whole(names, 'neither position nor effort given'))
        clamps: list[Clamp] = []
        for k, joint in enumerate(names):
            if effort:
                value = float(effort[k])
                reason = self._check_joint(joint) or self._check_value(joint, value)
                if reason is not None:
                    rejections.append(Rejection(joint, value, f'effort: {reason}'))
                else:
                    self._queue(joint, value, 'joint_state', clamps)
            if position:
                if joint not in self.driven:
                    rejections.append(Rejection(joint, position[k], 'position: joint has no '
                                      f'driving (UID 19, or UID 21 on a sliding joint); joints with driving: '
                                      f'{self.driven or "none"}'))
                elif abs(float(position[k])) > MAX_ABS_AIM:
                    rejections.append(Rejection(joint, position[k], f'position: |aim| beyond '
                                      f'{MAX_ABS_AIM:g} rad, the supported range'))
                else:
                    self._pending_aim[joint] = float(position[k])
        return rejections, clamps

    def clear(self) -> None:
        """Drop pending commands and forget command times (used on reset)."""
        self._drop_pending()
        self._last_command_time: dict[str, float] = {}     # joint -> time [s]
        self._last_value: dict[str, float] = {}
        self._timed_out: set[str] = set()

    # -- at the step boundary ----------------------------------------------------------
    @property
    def idle(self) -> bool:
        """Nothing pending and no command timeout to run: `apply` would change nothing."""
        return not (self._pending_torque or self._pending_enable or self.command_timeout > 0.0
                    or self._pending_aim
                    or self._pending_array is not None or self._pending_enable_all is not None)

    def apply(self, world: Any) -> Applied:
        """Write pending commands into `world`, then apply the command timeout."""
        if self.idle:
            return NOTHING_APPLIED          # the common boundary: nothing to do
        now = float(world.time)
        out = Applied(time=now, array=self._pending_array, enable_all=self._pending_enable_all)
        for joint, flag in self._pending_enable.items():
            world.set_effort_enabled(joint, flag)
            out.enables[joint] = flag
        for joint, (value, source) in self._pending_torque.items():
            result = world.set_effort(joint, value)   # N m (revolute) or N (prismatic)
            if isinstance(result, float):   # the world's own clamp, if any
                value = result
            out.torques[joint] = value
            out.sources[joint] = source
            self._last_command_time[joint] = now
            self._last_value[joint] = value
            self._timed_out.discard(joint)
        for joint, aim in self._pending_aim.items():
            world.set_drive(joint, aim=aim)
            out.aims[joint] = aim
        self._drop_pending()
        if self.command_timeout > 0.0:
            for joint, t_cmd in self._last_command_time.items():
                if joint in self._timed_out:
                    continue
                if now - t_cmd >= self.command_timeout - 1e-9:
                    self._timed_out.add(joint)
                    if self._last_value.get(joint, 0.0) != 0.0:
                        world.set_effort(joint, 0.0)
                        out.timed_out.append(joint)
        return out

    def next_timeout(self) -> float:
        """Earliest simulated time [s] at which `apply` would time a joint out (inf: none
        while nothing new arrives). Boundaries before it change nothing, so a caller may
        step past them in one batch."""
        if self.command_timeout <= 0.0:
            return math.inf
        times = [t for j, t in self._last_command_time.items() if j not in self._timed_out]
        return min(times) + self.command_timeout - 1e-9 if times else math.inf
