"""sim_node's topic table: the one place that names every topic, its type, QoS and direction.

The node creates its publishers and subscriptions from it, the recorder registers the bag's
topics from it (``recording.add_node_topics``), and test/test_docs_tables.py compares
docs/topics.md with it. Plain Python (QoS as reliability + depth), so the headless tools
read it without rclpy.

Names are given as the node declares them: relative ones (``joint_states``) follow the
node's namespace, absolute ones (``/clock``) do not; ``{joint}`` stands for each actuated
joint's name.
"""
from __future__ import annotations

import re
from typing import NamedTuple

RELIABLE = 'reliable'
BEST_EFFORT = 'best_effort'


class TopicSpec(NamedTuple):
    name: str
    type: str
    direction: str
    """'out': the node publishes it; 'in': the node subscribes to it."""
    reliability: str
    """RELIABLE or BEST_EFFORT; durability is volatile and history keep-last throughout."""
    depth: int
    recorded: bool
    """Stored in the bag (commands as applied, the rest as published)."""
    description: str


TOPIC_JOINT_STATES = 'joint_states'
TOPIC_CLOCK = '/clock'
TOPIC_DIAGNOSTICS = '/diagnostics'
TOPIC_PARAMETER_EVENTS = '/parameter_events'
TOPIC_TORQUE_ARRAY = 'joint_torque_commands'
TOPIC_TORQUE_JOINT = 'joint_torque/{joint}'
TOPIC_ENABLE_ALL = 'joint_torque_enable'
TOPIC_ENABLE_JOINT = 'joint_torque_enable/{joint}'
TOPIC_JOINT_COMMANDS = 'joint_commands'
TOPIC_MARKERS = 'markers'

TOPICS: tuple[TopicSpec, ...] = (
    TopicSpec(TOPIC_JOINT_STATES, 'sensor_msgs/msg/JointState', 'out', RELIABLE, 10, True,
              'all joints: angle, velocity, applied torque; at publish_rate'),
    TopicSpec(TOPIC_CLOCK, 'rosgraph_msgs/msg/Clock', 'out', BEST_EFFORT, 1, True,
              'simulation time after every step'),
    TopicSpec(TOPIC_DIAGNOSTICS, 'diagnostic_msgs/msg/DiagnosticArray', 'out', RELIABLE, 10,
              True, 'solver status, 1 Hz of wall time (DIAGNOSTIC_KEYS in ros/loop.py)'),
    TopicSpec(TOPIC_PARAMETER_EVENTS, 'rcl_interfaces/msg/ParameterEvent', 'out', RELIABLE,
              1000, True, 'live parameter changes (published by rclpy for every node)'),
    TopicSpec(TOPIC_TORQUE_ARRAY, 'std_msgs/msg/Float64MultiArray', 'in', RELIABLE, 10, True,
              'one torque per joint of `joints`'),
    TopicSpec(TOPIC_ENABLE_ALL, 'std_msgs/msg/Bool', 'in', RELIABLE, 10, True,
              'enable/disable all actuated joints'),
    TopicSpec(TOPIC_JOINT_COMMANDS, 'sensor_msgs/msg/JointState', 'in', RELIABLE, 10, True,
              'name-matched effort and driving-aim commands'),
    TopicSpec(TOPIC_TORQUE_JOINT, 'std_msgs/msg/Float64', 'in', RELIABLE, 10, True,
              'torque of one actuated joint'),
    TopicSpec(TOPIC_ENABLE_JOINT, 'std_msgs/msg/Bool', 'in', RELIABLE, 10, True,
              'enable/disable one joint\'s torque'),
    TopicSpec(TOPIC_MARKERS, 'visualization_msgs/msg/MarkerArray', 'out', RELIABLE, 10, True,
              'one marker per body at marker_rate (recorded unless marker_rate is 0)'),
)
"""In the order the bag registers them (per-joint ones once per actuated joint)."""

TOPICS_BY_NAME = {t.name: t for t in TOPICS}


def expand(spec: TopicSpec, joints) -> list[str]:
    """The concrete names of `spec`: one per joint for a ``{joint}`` topic."""
    if '{joint}' in spec.name:
        return [spec.name.format(joint=j) for j in joints]
    return [spec.name]


def pattern(name: str) -> 're.Pattern[str]':
    """A regex matching the topic `name` as recorded under any namespace (``/arm/joint_states``
    for ``joint_states``); a ``{joint}`` part is captured as group 1."""
    body = re.escape(name.lstrip('/')).replace(re.escape('{joint}'), '([^/]+)')
    return re.compile(r'(?:^|/)' + body + '$')
