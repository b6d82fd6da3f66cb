"""Commands over simulated time: the schedule YAML of ``run_headless`` (format:
docs/replay.md, "Schedule format").

An event takes effect at the first step boundary at or after its ``t`` (as a command sent to
sim_node does); within one event enables act before torques, the array before per-joint
torques (the order sim_node records and a replay applies them). Errors are
:class:`ScheduleError` with one line naming the file and the field.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math
from pathlib import Path
from typing import Any, Optional, Sequence

from abd_joint_sim.ros.convert import NS_PER_S, seconds_to_ns
from abd_joint_sim.ros.params import coerce

SCHEDULE_PARAMETERS = ('time_step', 'publish_rate', 'command_timeout', 'effort_limits',
                       'joints', 'frame_id', 'marker_rate', 'marker_frame_id',
                       'marker_joint_axes')
"""sim_node parameters a schedule may set (the rest do not apply to a headless run)."""

DEFAULT_TAIL = 1.0
"""Seconds simulated after the last event when no duration is given."""

MAX_SCHEDULE_BYTES = 64 << 20
"""Largest schedule file read [bytes] (~1.5 million events of one torque each)."""

MAX_TIME = 1e6
"""[s] Latest event time and longest duration (11.6 simulated days; at the smallest dt
that is 1e12 steps, far beyond any run, and well inside int64 nanoseconds)."""


class ScheduleError(ValueError):
    """A schedule (or a command taken from a bag) that cannot be run; one line."""


@dataclass(frozen=True)
class Command:
    """One command as sim_node receives it on a topic.

    kind: ``'enable'`` (joint, bool), ``'enable_all'`` (bool), ``'array'`` (list of
    floats in `joints` order), ``'torque'`` (joint, float) or ``'joint_state'`` (a
    ``joint_commands`` JointState as {name, position, velocity, effort} lists).
    """

    t_ns: int
    kind: str
    joint: Optional[str]
    value: Any
    where: str = ''

    def describe(self) -> str:
        return self.where or f'{self.kind} {self.joint or ""} at t={self.t_ns / NS_PER_S:g} s'


@dataclass
class Segment:
    """Commands (in application order) from a start (or ~/reset) to ``end_ns``."""

    commands: list[Command] = field(default_factory=list)
    end_ns: int = 0


@dataclass
class Plan:
    """What a headless run does: segments separated by resets, and parameter values."""

    segments: list[Segment]
    parameters: dict[str, Any] = field(default_factory=dict)
    source: str = ''


def _per_joint(t_ns: int, where: str, mapping: dict, kind: str, value) -> list[Command]:
    """The commands of a {joint: value} mapping at `where`, each value read by
    `value(where, v)`."""
    if not mapping:
        raise _fail(where, 'empty mapping')
    return [Command(t_ns, kind, j, value(f'{where}.{j}', v), f'{where}.{j}')
            for j, v in ((_joint_name(where, j), v) for j, v in mapping.items())]


def _fail(where: str, what: str) -> ScheduleError:
    return ScheduleError(f'{where}: {what}')


def _only(where: str, mapping: dict, allowed: tuple[str, ...]) -> None:
    """`where` + ``.key`` of the first key of `mapping` not in `allowed`: unknown."""
    unknown = sorted(set(map(str, mapping)) - set(allowed))
    if unknown:
        raise _fail(f'{where}{unknown[0]}', f'unknown key (allowed: {", ".join(allowed)})')


def _number(where: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _fail(where, f'expected a number, got {value!r}')
    value = float(value)
    if not math.isfinite(value):
        raise _fail(where, f'{value} is not finite')
    return value


def _flag(where: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise _fail(where, f'expected true or false, got {value!r}')
    return value


def _joint_name(where: str, value: Any) -> str:
    if not isinstance(value, str) or not value:
        raise _fail(where, f'joint names are strings, got {value!r}')
    return value


def parse_schedule(data: Any, source: str = '<schedule>') -> Plan:
    """Validate schedule data (already parsed YAML) into a one-segment :class:`Plan`.

    Joint names are checked later, against the scene (:func:`check_plan`).
    """
    if isinstance(data, list):
        data = {'events': data}
    if data is None:
        raise _fail(source, 'empty schedule; expected a mapping with `events` (docs/replay.md)')
    if not isinstance(data, dict):
        raise _fail(source, f'expected a mapping with `events` (or a list of events), got '
                            f'{type(data).__name__}')
    _only(f'{source}: ', data, ('duration', 'parameters', 'events'))
    params: dict[str, Any] = {}
    raw_params = data.get('parameters') or {}
    if not isinstance(raw_params, dict):
        raise _fail(f'{source}: parameters', f'expected a mapping, got {raw_params!r}')
    for name, value in raw_params.items():
        if name not in SCHEDULE_PARAMETERS:
            raise _fail(f'{source}: parameters.{name}',
                        f'not a parameter of a headless run (allowed: '
                        f'{", ".join(SCHEDULE_PARAMETERS)})')
        try:
            params[name] = coerce(name, value)
        except ValueError as exc:
            raise _fail(f'{source}: parameters.{name}', str(exc)) from None
    events = [] if data.get('events') is None else data['events']
    if not isinstance(events, list):
        raise _fail(f'{source}: events', f'expected a list of events, got {events!r}')
    commands: list[Command] = []
    last_t: Optional[float] = None
    for i, event in enumerate(events):
        where = f'{source}: events[{i}]'
        if not isinstance(event, dict):
            raise _fail(where, f'expected a mapping with t and torque/enable, got {event!r}')
        _only(f'{where}.', event, ('t', 'torque', 'enable', 'joint_command'))
        if 't' not in event:
            raise _fail(f'{where}.t', 'missing (the time in seconds)')
        t = _number(f'{where}.t', event['t'])
        if t < 0.0:
            raise _fail(f'{where}.t', f'{t:g} is negative; times start at 0')
        if t > MAX_TIME:
            raise _fail(f'{where}.t', f'{t:g} is beyond the supported {MAX_TIME:g} s')
        if last_t is not None and t <= last_t:
            raise _fail(f'{where}.t', f'{t:g} is not after the previous event\'s t = '
                                      f'{last_t:g}; list events in increasing time, one per time')
        last_t = t
        if not {'torque', 'enable', 'joint_command'} & set(event):
            raise _fail(where, 'has neither torque nor enable (nor joint_command)')
        t_ns = seconds_to_ns(t)
        enable = event.get('enable')
        if 'enable' in event:
            if isinstance(enable, dict):
                commands += _per_joint(t_ns, f'{where}.enable', enable, 'enable', _flag)
            else:
                commands.append(Command(t_ns, 'enable_all', None,
                                        _flag(f'{where}.enable', enable), f'{where}.enable'))
        torque = event.get('torque')
        if 'torque' in event:
            if isinstance(torque, list):
                values = [_number(f'{where}.torque[{k}]', v) for k, v in enumerate(torque)]
                commands.append(Command(t_ns, 'array', None, values, f'{where}.torque'))
            elif isinstance(torque, dict):
                commands += _per_joint(t_ns, f'{where}.torque', torque, 'torque', _number)
            else:
                raise _fail(f'{where}.torque', f'expected {{joint: N m}} or a list in `joints` '
                                               f'order, got {torque!r}')
        if 'joint_command' in event:
            commands.append(_joint_command(f'{where}.joint_command', event['joint_command'],
                                           t_ns))
    # Enables before the array before per-joint torques, within one time (stable sort).
    rank = {'enable_all': 0, 'enable': 1, 'array': 2, 'torque': 3, 'joint_state': 4}
    commands.sort(key=lambda c: (c.t_ns, rank[c.kind]))
    duration = data.get('duration')
    if duration is not None:
        duration = _number(f'{source}: duration', duration)
        if not 0.0 < duration <= MAX_TIME:
            raise _fail(f'{source}: duration', f'{duration:g} must be > 0 and at most '
                                               f'{MAX_TIME:g} s')
        end_ns = seconds_to_ns(duration)
    else:
        end_ns = seconds_to_ns((last_t or 0.0) + DEFAULT_TAIL)
    return Plan([Segment(commands, end_ns)], params, source)


def _joint_command(where: str, value: Any, t_ns: int) -> Command:
    """``joint_command: {effort: {joint: N m}, position: {joint: rad}}`` -> the JointState
    sim_node would receive on ``joint_commands`` (one message; names = the union)."""
    if not isinstance(value, dict) or not value:
        raise _fail(where, f'expected {{effort: {{joint: N m}}, position: {{joint: rad}}}}, '
                           f'got {value!r}')
    _only(f'{where}.', value, ('effort', 'position'))
    parts = {}
    for key in ('effort', 'position'):
        part = value.get(key) or {}
        if not isinstance(part, dict):
            raise _fail(f'{where}.{key}', f'expected {{joint: value}}, got {part!r}')
        parts[key] = {_joint_name(f'{where}.{key}', j): _number(f'{where}.{key}.{j}', v)
                      for j, v in part.items()}
    if parts['effort'] and parts['position'] and set(parts['effort']) != set(parts['position']):
        raise _fail(where, 'effort and position must name the same joints in one message '
                           '(use two events, or one of them)')
    names = list(parts['effort'] or parts['position'])
    return Command(t_ns, 'joint_state', None, {
        'name': names, 'velocity': [],
        'effort': [parts['effort'][n] for n in names] if parts['effort'] else [],
        'position': [parts['position'][n] for n in names] if parts['position'] else []},
        where)


def load_schedule(path: str | Path) -> Plan:
    """Read and validate a schedule YAML file (:class:`ScheduleError` on any problem)."""
    from abd_joint_sim.scene import read_yaml_file   # YAML 1.2 floats (1e3), as scene files
    _, data = read_yaml_file(path, ScheduleError, 'schedule', max_bytes=MAX_SCHEDULE_BYTES)
    return parse_schedule(data, str(path))


def check_plan(plan: Plan, actuated: Sequence[str], order: Sequence[str],
               buffer: Any = None) -> None:
    """Every command is one sim_node would accept: each is handed to `buffer` (a fresh
    CommandBuffer configured as the run's; by default one for `actuated` and `order`), the
    validation the node's subscription callbacks apply (actuated joint, array length,
    finite, within MAX_ABS_TORQUE on a joint without an effort limit, position only on
    joints with driving). ScheduleError names the first refused command."""
    from abd_joint_sim.ros.commands import CommandBuffer
    from abd_joint_sim.ros.loop import queue_command
    if buffer is None:
        buffer = CommandBuffer(actuated, order)
    for seg in plan.segments:
        for cmd in seg.commands:
            if cmd.kind == 'parameter':
                continue
            rejections, _ = queue_command(buffer, cmd.kind, cmd.joint, cmd.value)
            if rejections:
                raise ScheduleError(f'{cmd.describe()}: {rejections[0]}')
    buffer.clear()
