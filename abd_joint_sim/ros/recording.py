"""What sim_node publishes when, and what it records: one set of rules for the node
(``ros/node.py``) and the headless tools (``tools/sim.py``: ``run_headless``,
``replay_check``), so a node bag and a headless bag have the same layout and a replay
re-creates exactly what the node published.

* Topic names are given as the node declares them (``joint_states`` is relative and follows
  the node's namespace; ``/clock`` is absolute). ``resolve`` turns them into the fully
  qualified names that appear on the graph and in the bag: the node passes
  ``Node.resolve_topic_name``, the headless tools :func:`resolve_root` (namespace ``/``).
* :class:`PublishSchedule`: ``/joint_states`` at ``publish_rate`` Hz of simulated time, on
  the grid ``k / publish_rate`` (so a state is published at the first step at or after each
  grid point), after every step for rate 0, and always when forced (start, reset, single
  step).
* :func:`record_applied`: commands as they took effect at a step boundary, in the order a
  replay must apply them (per-joint enables, the array command, then per-joint torques that
  superseded it).
* :func:`parameter_event_msg`: a live parameter change, as an ``rcl_interfaces/msg/
  ParameterEvent`` on ``/parameter_events`` (the topic and type every ROS 2 node publishes
  its changes on), stamped and logged at the simulated time from which it applies, so a
  replay can honour e.g. a live change of ``command_timeout``.
* :func:`bag_custom_data` and :func:`add_node_topics`: the bag's custom data, attachments and
  topic list.
* :func:`markers_due`: the body markers (``ros/markers.py``) at ``marker_rate`` Hz of
  simulated time on their own grid, at most once per step, and at start and reset.

Plain functions over a ``write(topic, stamp_ns, msg)`` callable: the node's writes stop the
recording on failure, the headless recorder's count messages.
"""
from __future__ import annotations

import os
from typing import Any, Callable, Iterable, Mapping, Optional

import yaml

from . import convert
from .commands import Applied
from .markers import TOPIC_MARKERS
from .params import NODE_NAME, packaged_scenes_dir, SimConfig
from .topics import (TOPIC_CLOCK, TOPIC_DIAGNOSTICS, TOPIC_ENABLE_ALL,  # noqa: F401 (re-exported)
                     TOPIC_ENABLE_JOINT, TOPIC_JOINT_COMMANDS, TOPIC_JOINT_STATES,
                     TOPIC_PARAMETER_EVENTS, TOPIC_TORQUE_ARRAY, TOPIC_TORQUE_JOINT, TOPICS)

RECORDED_PARAMETERS = ('real_time_factor', 'publish_rate', 'command_timeout',
                       'effort_limits')
"""Live parameters whose changes are recorded on ``/parameter_events`` (all live ones)."""

Write = Callable[[str, int, Any], None]
Resolve = Callable[[str], str]


def resolve_root(topic: str) -> str:
    """Fully qualified name of `topic` for a node in the root namespace (headless runs)."""
    return topic if topic.startswith('/') else '/' + topic


def portable_scene_path(path: str) -> str:
    """The scene as a bag stores it, free of the recording machine's directories: the bare
    name of a packaged scene (``default``, what the ``scene`` parameter accepts to pick it
    again), else the file's base name. The scene itself is stored whole beside it."""
    if not path:
        return ''
    scenes = os.path.realpath(packaged_scenes_dir())
    full = os.path.realpath(path)
    name = os.path.basename(full)
    if os.path.dirname(full) == scenes and name.endswith('.yaml'):
        return name[:-len('.yaml')]
    return name


def parameters_yaml(config: SimConfig) -> str:
    """The effective parameters as the node stores them (a ros2 params file); the paths
    ``scene`` and ``record`` as base names (:func:`portable_scene_path`)."""
    values = config.as_dict()
    values['scene'] = portable_scene_path(values.get('scene', ''))
    values['record'] = os.path.basename(os.path.normpath(values['record'])) \
        if values.get('record') else ''
    return yaml.safe_dump({NODE_NAME: {'ros__parameters': values}}, sort_keys=False)


def bag_custom_data(config: SimConfig, scene_path: str, scene_text: str, dt: float,
                    joints: Iterable[str], extra: Optional[Mapping[str, str]] = None,
                    urdf_text: str = '') -> tuple[dict[str, str], dict[str, bytes]]:
    """(custom_data, attachments) of a bag: scene, effective parameters, dt, array order;
    for a URDF robot also the URDF (``abd_joint_sim.urdf``, attachment ``robot.urdf``; the
    scene YAML is then the lowered scene the run used, which replays without it)."""
    params_text = parameters_yaml(config)
    custom = {
        'abd_joint_sim.scene_path': portable_scene_path(scene_path),
        'abd_joint_sim.scene_yaml': scene_text,
        'abd_joint_sim.parameters_yaml': params_text,
        'abd_joint_sim.time_step': repr(float(dt)),
        'abd_joint_sim.joints': ','.join(joints),
    }
    custom.update(extra or {})
    attachments = {'scene.yaml': scene_text.encode(), 'parameters.yaml': params_text.encode()}
    if urdf_text:
        custom['abd_joint_sim.urdf'] = urdf_text
        attachments['robot.urdf'] = urdf_text.encode()
    return custom, attachments


def add_node_topics(writer: Any, resolve: Resolve, actuated: Iterable[str],
                    markers: bool = False) -> None:
    """Register every recorded topic of the node's table (``ros/topics.py``) on `writer` (a
    ``BagWriter``), with the QoS the node publishes it with; a ``{joint}`` topic once per
    actuated joint; `markers`: the body markers too (``marker_rate`` > 0)."""
    actuated = list(actuated)
    specs = [t for t in TOPICS if t.recorded and (markers or t.name != TOPIC_MARKERS)]
    for spec in [t for t in specs if '{joint}' not in t.name]:
        if spec.name != TOPIC_MARKERS:
            writer.add_topic(resolve(spec.name), spec.type, qos=spec.reliability,
                             depth=spec.depth)
    per_joint = [t for t in specs if '{joint}' in t.name]
    for joint in actuated:
        for spec in per_joint:
            writer.add_topic(resolve(spec.name.format(joint=joint)), spec.type,
                             qos=spec.reliability, depth=spec.depth)
    for spec in [t for t in specs if t.name == TOPIC_MARKERS]:
        writer.add_topic(resolve(spec.name), spec.type, qos=spec.reliability, depth=spec.depth)


def markers_due(schedule: 'PublishSchedule', t_ns: int, rate: float,
                force: bool = False) -> bool:
    """True if the body markers are due at `t_ns` (``marker_rate`` Hz on the grid
    ``k / rate``, and at start and reset); never for rate 0 (markers off)."""
    return rate > 0.0 and schedule.due(t_ns, rate, force)


def record_applied(write: Write, resolve: Resolve, applied: Applied) -> None:
    """Commands as they took effect (log time = simulated time of the step boundary).

    Same-time messages are written in the order a replay must apply them: per-joint
    enables, then the array command, then per-joint torques that superseded it. Timeouts
    are not written: they follow from ``command_timeout`` (and its recorded changes).
    """
    t_ns = convert.seconds_to_ns(applied.time)
    for joint, flag in applied.enables.items():
        write(resolve(TOPIC_ENABLE_JOINT.format(joint=joint)), t_ns, convert.bool_msg(flag))
    if applied.array is not None:
        write(resolve(TOPIC_TORQUE_ARRAY), t_ns, convert.float64_array_msg(applied.array))
    for joint, value in applied.torques.items():
        if applied.sources.get(joint) == 'joint':
            write(resolve(TOPIC_TORQUE_JOINT.format(joint=joint)), t_ns,
                  convert.float64_msg(value))
    # joint_commands as applied: one message with the efforts (after clamping), one with
    # the driving aims; each joint's final value only, so the order among them is free.
    efforts = {j: v for j, v in applied.torques.items()
               if applied.sources.get(j) == 'joint_state'}
    for kind, values in (('effort', efforts), ('position', applied.aims)):
        if values:
            write(resolve(TOPIC_JOINT_COMMANDS), t_ns,
                  joint_command_msg(t_ns, list(values), **{kind: list(values.values())}))


def joint_command_msg(t_ns: int, names, position=(), effort=()):
    """A sensor_msgs/JointState command (``joint_commands``) as recorded."""
    from sensor_msgs.msg import JointState
    msg = JointState()
    msg.header.stamp = convert.ns_to_time_msg(t_ns)
    msg.name = [str(n) for n in names]
    msg.position = [float(v) for v in position]
    msg.effort = [float(v) for v in effort]
    return msg


class HeldMessages:
    """Serialized messages of one topic held back during a batch of steps and written with
    one ``BagWriter.write_serialized_many`` call (sim_node's and the headless recorder's
    /clock, one per step). The holder flushes before it writes any other message and at the
    batch's end, so the bag gets the order and the bytes of one write per message."""

    __slots__ = ('topic', 'active', '_stamps', '_datas')

    def __init__(self, topic: str) -> None:
        self.topic = topic
        self.active = False         #: in a batch: `hold` rather than write
        self._stamps: list = []
        self._datas: list = []

    def __len__(self) -> int:
        return len(self._stamps)

    def hold(self, stamp_ns: int, data: bytes) -> None:
        self._stamps.append(stamp_ns)
        self._datas.append(data)

    def hold_many(self, stamps_ns: list, datas: list) -> None:
        """`hold` each pair in order."""
        self._stamps += stamps_ns
        self._datas += datas

    def flush(self, writer: Any) -> int:
        """Write what is held into `writer` (None: drop it); returns how many were held."""
        stamps, datas = self._stamps, self._datas
        self._stamps, self._datas = [], []
        if stamps and writer is not None:
            writer.write_serialized_many(self.topic, stamps, datas)
        return len(stamps)


class PublishSchedule:
    """When ``/joint_states`` is due: ``publish_rate`` Hz of simulated time (0 = every step).

    The grid is ``k * period``: after a publish at ``t``, the next one is due at the first
    grid point after ``t``. :meth:`restart` (reset, a change of ``publish_rate``) makes the
    next call due at once.
    """

    def __init__(self) -> None:
        self.next_ns = 0

    def restart(self) -> None:
        self.next_ns = 0

    def due(self, t_ns: int, rate: float, force: bool = False) -> bool:
        """True if a state at `t_ns` is to be published; advances the schedule if so."""
        if not force and rate > 0.0 and t_ns < self.next_ns:
            return False
        if rate > 0.0:
            period_ns = max(1, int(round(1e9 / rate)))
            self.next_ns = (t_ns // period_ns + 1) * period_ns
        return True


def parameter_event_msg(stamp_ns: int, node: str, changes: Mapping[str, Any]):
    """An ``rcl_interfaces/msg/ParameterEvent`` listing `changes` (name -> value) of `node`
    (fully qualified name) as ``changed_parameters``, stamped with simulated time."""
    from rcl_interfaces.msg import ParameterEvent
    from rclpy.parameter import Parameter
    msg = ParameterEvent()
    msg.stamp = convert.ns_to_time_msg(stamp_ns)
    msg.node = node
    msg.changed_parameters = [Parameter(name, value=_ros_value(value)).to_parameter_msg()
                              for name, value in changes.items()]
    return msg


def _ros_value(value: Any) -> Any:
    # rclpy infers the parameter type from the Python type; [] would be a byte array.
    if isinstance(value, list):
        return [float(v) for v in value] if value else []
    return value


def parameter_changes(msg: Any) -> dict[str, Any]:
    """name -> Python value of the new and changed parameters of a ParameterEvent."""
    from rclpy.parameter import parameter_value_to_python
    out: dict[str, Any] = {}
    for p in list(msg.new_parameters) + list(msg.changed_parameters):
        value = parameter_value_to_python(p.value)
        if isinstance(value, (bytes, bytearray)) or (hasattr(value, 'tolist')
                                                     and not isinstance(value, str)):
            value = list(value.tolist() if hasattr(value, 'tolist') else value)
        out[p.name] = value
    return out
