"""sim_node's topic table: every topic's name, type, QoS and direction, for the node, the
recorder (``recording.add_node_topics``) and docs/topics.md (test_docs_tables.py), without
rclpy. Names are as the node declares them: relative ones (``joint_states``) follow the
node's namespace, absolute ones (``/clock``) do not; ``{joint}`` stands for each actuated
joint's name."""
from __future__ import annotations

import re
from typing import NamedTuple

RELIABLE = 'reliable'
BEST_EFFORT = 'best_effort'


class TopicSpec(NamedTuple):
    name: str
    type: str
    description: str
    direction: str = 'in'
    """'out': the node publishes it; 'in': the node subscribes to it."""
    reliability: str = RELIABLE
    """RELIABLE or BEST_EFFORT; durability is volatile and history keep-last throughout."""
    depth: int = 10
    recorded: bool = True
    """Stored in the bag (commands as applied, the rest as published)."""


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
    TopicSpec(TOPIC_JOINT_STATES, 'sensor_msgs/msg/JointState',
              'all joints: angle, velocity, applied torque; at publish_rate', 'out'),
    TopicSpec(TOPIC_CLOCK, 'rosgraph_msgs/msg/Clock', 'simulation time after every step', 'out',
              BEST_EFFORT, 1),
    TopicSpec(TOPIC_DIAGNOSTICS, 'diagnostic_msgs/msg/DiagnosticArray',
              'solver status, 1 Hz of wall time (DIAGNOSTIC_KEYS in ros/loop.py)', 'out'),
    TopicSpec(TOPIC_PARAMETER_EVENTS, 'rcl_interfaces/msg/ParameterEvent',
              'live parameter changes (published by rclpy for every node)', 'out', depth=1000),
    TopicSpec(TOPIC_TORQUE_ARRAY, 'std_msgs/msg/Float64MultiArray',
              'one torque per joint of `joints`'),
    TopicSpec(TOPIC_ENABLE_ALL, 'std_msgs/msg/Bool', 'enable/disable all actuated joints'),
    TopicSpec(TOPIC_JOINT_COMMANDS, 'sensor_msgs/msg/JointState',
              'name-matched effort and driving-aim commands'),
    TopicSpec(TOPIC_TORQUE_JOINT, 'std_msgs/msg/Float64', 'torque of one actuated joint'),
    TopicSpec(TOPIC_ENABLE_JOINT, 'std_msgs/msg/Bool', 'enable/disable one joint\'s torque'),
    TopicSpec(TOPIC_MARKERS, 'visualization_msgs/msg/MarkerArray',
              'one marker per body at marker_rate (recorded unless marker_rate is 0)', 'out'),
)
"""In the order the bag registers them (per-joint ones once per actuated joint)."""

TOPICS_BY_NAME = {t.name: t for t in TOPICS}


def pattern(name: str) -> 're.Pattern[str]':
    """A regex matching the topic `name` as recorded under any namespace (``/arm/joint_states``
    for ``joint_states``); a ``{joint}`` part is captured as group 1."""
    body = re.escape(name.lstrip('/')).replace(re.escape('{joint}'), '([^/]+)')
    return re.compile(r'(?:^|/)' + body + '$')
