"""A recorded bag as what is needed to run it again: scene, parameters, commands, states.

Messages are read in *file* order (the node's step order). A segment starts at the first
message and wherever the stamp of ``/clock`` or ``/joint_states`` does not advance (a
``~/reset``); a command's time in its segment is its log time minus the segment's offset
(log time minus the stamp of its first ``/clock`` or ``/joint_states``; docs/replay.md).
Topics are recognised by their last components, so a namespaced node's bag works.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import os
from pathlib import Path
from typing import Any, Optional

import yaml

from abd_joint_sim.ros import convert
from abd_joint_sim.ros.params import NODE_NAME
from abd_joint_sim.ros.topics import (pattern, TOPIC_CLOCK, TOPIC_ENABLE_ALL, TOPIC_ENABLE_JOINT,
                                      TOPIC_JOINT_COMMANDS, TOPIC_JOINT_STATES,
                                      TOPIC_PARAMETER_EVENTS, TOPIC_TORQUE_ARRAY,
                                      TOPIC_TORQUE_JOINT)

from .schedule import Command, Plan, Segment

_STATES = pattern(TOPIC_JOINT_STATES)
_CLOCK = pattern(TOPIC_CLOCK)


def _parameters(msg) -> Optional[dict]:
    from abd_joint_sim.ros.recording import parameter_changes
    return parameter_changes(msg) or None if hasattr(msg, 'changed_parameters') else None


def _joint_state(msg) -> Optional[dict]:
    return {'name': list(msg.name), 'position': list(msg.position), 'velocity':
            list(msg.velocity), 'effort': list(msg.effort)} if hasattr(msg, 'effort') else None


_COMMANDS = ((pattern(TOPIC_TORQUE_ARRAY), 'array', convert.array_values),
             (pattern(TOPIC_TORQUE_JOINT), 'torque', lambda msg: float(msg.data)),
             (pattern(TOPIC_ENABLE_JOINT), 'enable', lambda msg: bool(msg.data)),
             (pattern(TOPIC_PARAMETER_EVENTS), 'parameter', _parameters),
             (pattern(TOPIC_JOINT_COMMANDS), 'joint_state', _joint_state),
             (pattern(TOPIC_ENABLE_ALL), 'enable_all', lambda msg: bool(msg.data)))
"""(recorded topic under any namespace, command kind, its value from the message or None)"""


class BagInputError(RuntimeError):
    """The bag cannot be used (unreadable, no scene, ...); one line."""


@dataclass
class RecordedState:
    t_ns: int
    names: list[str]
    position: list[float]
    velocity: list[float]
    effort: list[float]


@dataclass
class RecordedRun:
    path: str
    custom: dict[str, str]
    scene_text: str
    scene_path: str
    parameters: dict[str, Any]
    plan: Plan
    states: list[dict[int, list[RecordedState]]] = field(default_factory=list)
    """Per segment: stamp [ns] -> recorded joint states with that header stamp."""
    counts: dict[str, int] = field(default_factory=dict)
    """Messages per topic."""

    @property
    def state_count(self) -> int:
        return sum(len(v) for seg in self.states for v in seg.values())

    @property
    def command_count(self) -> int:
        return sum(len(seg.commands) for seg in self.plan.segments)


def _iter_file_order(path: str | os.PathLike[str], topics: Optional[list[str]] = None):
    """(topic, type, log_time, message) in the order the recorder wrote them (only
    `topics`, when given); a bag that cannot be read: BagInputError."""
    from abd_joint_sim.record import BagError, read_messages
    try:
        yield from read_messages(path, topics, log_time_order=False)
    except BagError as exc:
        raise BagInputError(str(exc)) from None


def _stored_text(custom: dict[str, str], attachments: dict[str, bytes], key: str,
                 attachment: str) -> str:
    return custom.get(key) or attachments.get(attachment, b'').decode('utf-8', 'replace')


def load_bag(path: str | os.PathLike[str]) -> RecordedRun:
    """Read a bag recorded by sim_node or run_headless (:class:`BagInputError` if unusable)."""
    from abd_joint_sim.record import BagError, read_attachments, read_custom_data
    path = str(path)
    if not Path(path).exists():
        raise BagInputError(f'bag {path!r} does not exist')
    try:
        custom = read_custom_data(path)
        attachments = read_attachments(path)
    except BagError as exc:
        raise BagInputError(str(exc)) from None
    scene_text = _stored_text(custom, attachments, 'abd_joint_sim.scene_yaml', 'scene.yaml')
    if not scene_text.strip():
        raise BagInputError(f'bag {path!r} stores no scene (no custom_data '
                            '`abd_joint_sim.scene_yaml`, no attachment scene.yaml); '
                            'was it recorded by sim_node or run_headless?')
    params_text = _stored_text(custom, attachments, 'abd_joint_sim.parameters_yaml',
                               'parameters.yaml')
    parameters: dict[str, Any] = {}
    if params_text.strip():
        try:
            loaded = yaml.safe_load(params_text) or {}
            parameters = dict(loaded[NODE_NAME]['ros__parameters'])
        except (yaml.YAMLError, KeyError, TypeError, ValueError) as exc:
            raise BagInputError(f'bag {path!r}: stored parameters are unreadable: '
                                f'{type(exc).__name__}: {exc}') from None
    joints_text = custom.get('abd_joint_sim.joints')
    if joints_text and not parameters.get('joints'):
        parameters['joints'] = [j for j in joints_text.split(',') if j]

    segments: list[Segment] = [Segment()]
    states: list[dict[int, list[RecordedState]]] = [{}]
    counts: dict[str, int] = {}
    last: dict[str, int] = {}
    ends: list[int] = [0]
    offset = [0]            # log time - simulated time in the current segment

    def step_marker(kind: str, t_ns: int, log_ns: int) -> None:
        if kind in last and t_ns <= last[kind]:     # a new segment
            segments.append(Segment())
            states.append({})
            ends.append(0)
            last.clear()
        if not last:        # the segment's first step: its log-time offset
            offset[0] = log_ns - t_ns
        last[kind] = t_ns
        ends[-1] = max(ends[-1], t_ns)

    for topic, _type, log_ns, msg in _iter_file_order(path):
        counts[topic] = counts.get(topic, 0) + 1
        if _CLOCK.search(topic) and hasattr(msg, 'clock'):
            step_marker('clock', convert.time_msg_to_ns(msg.clock), log_ns)
            continue
        if _STATES.search(topic) and hasattr(msg, 'position'):
            t_ns = convert.time_msg_to_ns(msg.header.stamp)
            step_marker('states', t_ns, log_ns)
            states[-1].setdefault(t_ns, []).append(RecordedState(
                t_ns, list(msg.name), list(msg.position), list(msg.velocity),
                list(msg.effort)))
            continue
        log_ns -= offset[0]         # the command's time in its segment
        for regex, kind, value_of in _COMMANDS:
            if (m := regex.search(topic)) is not None:
                if (value := value_of(msg)) is not None:
                    segments[-1].commands.append(Command(
                        log_ns, kind, m.group(1) if regex.groups else None, value,
                        f'{topic} at t={log_ns / convert.NS_PER_S:.9g} s'))
                break
    for seg, end in zip(segments, ends):
        seg.end_ns = end
    plan = Plan(segments, {}, source=path)
    return RecordedRun(path, custom, scene_text,
                       custom.get('abd_joint_sim.scene_path', '') or 'scene.yaml',
                       parameters, plan, states, counts)


def scene_from_text(text: str, source: str):
    """Parse stored scene YAML like ``Scene.from_yaml`` (SceneError names `source`)."""
    from abd_joint_sim.errors import SceneError
    from abd_joint_sim.scene import load_yaml, Scene
    try:
        data = load_yaml(text)
    except yaml.YAMLError as exc:
        raise SceneError(f'{source}: not valid YAML: {getattr(exc, "problem", exc)}') from None
    except (RecursionError, ValueError) as exc:     # as read_yaml_file: one line, not a trace
        raise SceneError(f'{source}: not valid YAML: {exc or "nested too deeply"}') from None
    return Scene.from_dict(data, source=source, source_text=text)


def config_for(run_parameters: dict[str, Any], overrides: Optional[dict[str, Any]] = None,
               scene_path: str = ''):
    """SimConfig from stored parameters (unknown or live-only ones ignored) + overrides."""
    from abd_joint_sim.ros.params import config_from_values, PARAMS_BY_NAME
    values = {k: v for k, v in run_parameters.items() if k in PARAMS_BY_NAME}
    values.update(overrides or {})
    values['scene'] = scene_path or values.get('scene') or ''
    values['record'] = ''
    values['real_time_factor'] = 0.0
    values['start_paused'] = False
    return config_from_values(values, resolve=False)   # the scene comes from the bag or the caller
