"""What sim_node publishes when and records how: one set of rules for the node and the
headless tools (``tools/sim.py``), so their bags share one layout and a replay re-creates what
the node published. Topic names are as the node declares them; ``resolve`` qualifies them
(``Node.resolve_topic_name``, or :func:`resolve_root` headless). :class:`Recording` is the
one bag writer: a failed write stops the node's recording (``on_error``) and ends a headless
run (raised)."""
from __future__ import annotations

import os
from typing import Any, Callable, Iterable, Mapping, Optional

import yaml

from . import convert
from .commands import Applied
from .params import NODE_NAME, packaged_scenes_dir, SimConfig
from .topics import (TOPIC_CLOCK, TOPIC_ENABLE_JOINT, TOPIC_JOINT_COMMANDS, TOPIC_JOINT_STATES,
                     TOPIC_MARKERS, TOPIC_PARAMETER_EVENTS, TOPIC_TORQUE_ARRAY,
                     TOPIC_TORQUE_JOINT, TOPICS)

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
    specs = [t for t in TOPICS if t.recorded and (markers or t.name != TOPIC_MARKERS)]
    names = [(t, t.name) for t in specs if '{joint}' not in t.name and t.name != TOPIC_MARKERS]
    names += [(t, t.name.format(joint=j)) for j in actuated for t in specs if '{joint}' in t.name]
    names += [(t, t.name) for t in specs if t.name == TOPIC_MARKERS]
    for spec, name in names:
        writer.add_topic(resolve(name), spec.type, qos=spec.reliability, depth=spec.depth)


def record_applied(write: Write, resolve: Resolve, applied: Applied) -> None:
    """Commands as they took effect (log time = simulated time of the step boundary), in the
    order a replay must apply them: per-joint enables, the array command, per-joint torques
    that superseded it, joint_commands. Timeouts follow from ``command_timeout``."""
    t_ns = convert.seconds_to_ns(applied.time)
    for joint, flag in applied.enables.items():
        write(resolve(TOPIC_ENABLE_JOINT.format(joint=joint)), t_ns, convert.bool_msg(flag))
    if applied.array is not None:
        write(resolve(TOPIC_TORQUE_ARRAY), t_ns, convert.float64_array_msg(applied.array))
    for joint, value in applied.torques.items():
        if applied.sources.get(joint) == 'joint':
            write(resolve(TOPIC_TORQUE_JOINT.format(joint=joint)), t_ns,
                  convert.float64_msg(value))
    # joint_commands: one message with the efforts (clamped), one with the driving aims
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


class Recording:
    """The bag of a run in sim_node's layout, written through one ``BagWriter`` (open one
    with :meth:`open`). In a batch ``/clock`` is held back and written in one call before any
    other message and at the batch's end: the same order and bytes as one write per message.
    `counts`: messages per topic. A failed write closes the bag and calls ``on_error(why)``,
    or raises when there is none."""

    def __init__(self, writer: Any, resolve: Resolve, node_fqn: str,
                 on_error: Optional[Callable[[str], None]] = None,
                 zero_padding: bool = False) -> None:
        self.writer = writer            #: an open BagWriter with the node's topics; None: closed
        #: zero the alignment padding of messages serialised here (cdr.without_padding), for
        #: bags that must compare equal byte for byte (sweep cases)
        self.zero_padding = zero_padding
        self.resolve = resolve
        self.node_fqn = node_fqn
        self.on_error = on_error
        self.counts: dict[str, int] = {}
        self._clock = resolve(TOPIC_CLOCK)
        self._joint_states = resolve(TOPIC_JOINT_STATES)
        self._markers = resolve(TOPIC_MARKERS)
        self._batching = False          # in a batch: /clock held back
        self._held_stamps: list = []
        self._held_datas: list = []

    @classmethod
    def open(cls, path: str, bag_data: tuple[dict[str, str], dict[str, bytes]],
             actuated: Iterable[str], resolve: Resolve, node_fqn: str, markers: bool,
             on_error: Optional[Callable[[str], None]] = None,
             attachment_time_ns: Optional[int] = None,
             zero_padding: bool = False) -> 'Recording':
        """A new bag at `path` with `bag_data` (custom data and attachments:
        :func:`bag_custom_data`) and the node's topics (:func:`add_node_topics`); the writer
        is closed again if registering them fails. `attachment_time_ns`: as BagWriter's."""
        from abd_joint_sim.record.bag import BagWriter
        custom, attachments = bag_data
        writer = BagWriter(path, custom_data=custom, attachments=attachments,
                           attachment_time_ns=attachment_time_ns)
        writer.open()
        try:
            add_node_topics(writer, resolve, actuated, markers=markers)
        except BaseException:
            writer.close()
            raise
        return cls(writer, resolve, node_fqn, on_error, zero_padding)

    def write(self, topic: str, stamp_ns: int, msg: Any, serialized: bool = False) -> None:
        """One message (`serialized`: its CDR bytes) on the resolved `topic`."""
        if self._held_stamps:
            self._write_held()              # first: the bag keeps the order of the steps
        if self.writer is not None and self._try(f'writing {topic}', self._write, topic,
                                                 stamp_ns, msg, serialized):
            self.counts[topic] = self.counts.get(topic, 0) + 1

    def _write(self, topic: str, stamp_ns: int, msg: Any, serialized: bool) -> None:
        if not serialized and self.zero_padding:
            from rclpy.serialization import serialize_message
            from abd_joint_sim.record.cdr import without_padding
            msg, serialized = without_padding(serialize_message(msg), msg), True
        if serialized:
            self.writer.write_serialized(topic, stamp_ns, msg)
        else:
            self.writer.write(topic, stamp_ns, msg)

    def _write_held(self) -> None:
        """The /clock messages a batch held back, in one call (dropped once the bag failed)."""
        stamps, datas = self._held_stamps, self._held_datas
        self._held_stamps, self._held_datas = [], []
        if stamps and self.writer is not None and self._try(
                f'writing {self._clock}', self.writer.write_serialized_many, self._clock,
                stamps, datas):
            self.counts[self._clock] = self.counts.get(self._clock, 0) + len(stamps)

    def _try(self, what: str, call: Callable, *args) -> bool:
        """`call(*args)`; False if it failed: ``on_error(f'{what} failed: {exc}')``, or the
        exception raised again when there is no on_error."""
        try:
            call(*args)
        except Exception as exc:  # noqa: BLE001 - BagError, OSError, ...
            if self.on_error is None:
                raise
            self.on_error(f'{what} failed: {exc}')
            return False
        return True

    # -- what the loop hands over -----------------------------------------------------
    def clock(self, t_ns: int, data: bytes) -> None:
        """/clock as CDR bytes; held back in a batch."""
        self.clocks([t_ns], [data])

    def clocks(self, stamps_ns: list, datas: list) -> None:
        """`clock` for each pair, in order."""
        if self._batching:
            self._held_stamps += stamps_ns
            self._held_datas += datas
        else:
            for t_ns, data in zip(stamps_ns, datas):
                self.write(self._clock, t_ns, data, serialized=True)

    def batch_begin(self) -> None:
        self._batching = True

    def batch_end(self) -> None:
        try:
            self._write_held()
        finally:
            self._batching = False

    def joint_state(self, t_ns: int, data: bytes) -> None:
        self.write(self._joint_states, t_ns, data, serialized=True)

    def markers(self, t_ns: int, data: bytes) -> None:
        self.write(self._markers, t_ns, data, serialized=True)

    def applied(self, applied: Applied) -> None:
        record_applied(self.write, self.resolve, applied)

    def restarted(self) -> None:
        """Simulated time restarts at 0 (reset): the held /clock first, then log times go on
        increasing from the last one written (``BagWriter.restart_time``)."""
        if self._held_stamps:
            self._write_held()
        if self.writer is not None:
            self._try('restarting the log time', self.writer.restart_time)

    def parameters(self, t_ns: int, changes: Mapping[str, Any]) -> None:
        """Live changes, in force from `t_ns` (the current simulated time) on."""
        self.write(self.resolve(TOPIC_PARAMETER_EVENTS), t_ns,
                   parameter_event_msg(t_ns, self.node_fqn, changes))

    def flush(self) -> None:
        """Close the chunk in progress (a SIGKILL then loses at most the next one)."""
        if self.writer is not None:
            self._try('flushing', self.writer.flush)

    def close(self) -> None:
        """Finalise the bag (idempotent); held messages are dropped once the bag failed."""
        writer, self.writer = self.writer, None
        if writer is not None:
            writer.close()


class PublishSchedule:
    """When ``/joint_states`` (or the markers) are due: ``rate`` Hz of simulated time on the
    grid ``k * period`` (0 = every step), and always when forced (start, reset, single step);
    after :meth:`restart` the next call is due at once."""

    next_ns = 0
    """[ns] The earliest time a state is due again (0: at once)."""

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
        if isinstance(value, (bytes, bytearray)) or hasattr(value, 'tolist'):
            value = list(value.tolist() if hasattr(value, 'tolist') else value)
        out[p.name] = value
    return out
