"""Messages <-> plain values for sim_node (no DDS needed; only message classes)."""
from __future__ import annotations

import math
from typing import Iterable, Mapping, Optional, Sequence

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64, Float64MultiArray, MultiArrayDimension

NS_PER_S = 1_000_000_000
OK = DiagnosticStatus.OK
WARN = DiagnosticStatus.WARN
ERROR = DiagnosticStatus.ERROR


def seconds_to_ns(t: float) -> int:
    """Simulation time [s] -> integer nanoseconds (rounded to the nearest ns)."""
    return int(round(float(t) * NS_PER_S))


def ns_to_time_msg(ns: int) -> Time:
    sec, nanosec = divmod(int(ns), NS_PER_S)
    return Time(sec=sec, nanosec=nanosec)


def time_msg_to_ns(stamp: Time) -> int:
    return stamp.sec * NS_PER_S + stamp.nanosec


def check_lengths(n: int, position, velocity, effort) -> None:
    """ValueError unless a joint state's three arrays hold one value per each of its `n`
    names."""
    if not (len(position) == len(velocity) == len(effort) == n):
        raise ValueError(
            f'joint state arrays differ in length: name {n}, position {len(position)}, '
            f'velocity {len(velocity)}, effort {len(effort)}')


def joint_state_msg(stamp_ns: int, names: Sequence[str], position: Iterable[float],
                    velocity: Iterable[float], effort: Iterable[float],
                    frame_id: str = '') -> JointState:
    """A JointState with all four arrays filled (copied) and of equal length."""
    msg = JointState()
    msg.header.stamp = ns_to_time_msg(stamp_ns)
    msg.header.frame_id = frame_id
    msg.name = list(names)
    msg.position, msg.velocity, msg.effort = (np.asarray(a, dtype=float).ravel().tolist()
                                              for a in (position, velocity, effort))
    check_lengths(len(msg.name), msg.position, msg.velocity, msg.effort)
    return msg


def fill_joint_state(msg: JointState, stamp_ns: int, position: list[float], velocity: list[float],
                     effort: list[float], frame_id: str) -> None:
    """Refill a JointState made by `joint_state_msg` (same names) for a new state: sim_node
    reuses one message, as building one costs ~25 µs."""
    check_lengths(len(msg.name), position, velocity, effort)
    stamp = msg.header.stamp
    stamp.sec, stamp.nanosec = divmod(int(stamp_ns), NS_PER_S)
    msg.header.frame_id = frame_id
    msg.position, msg.velocity, msg.effort = position, velocity, effort


def clock_msg(stamp_ns: int) -> Clock:
    return Clock(clock=ns_to_time_msg(stamp_ns))


class ClockEncoder:
    """/clock as serialized CDR, for ``Publisher.publish(bytes)`` and the bag: 12 bytes packed
    by ``cdr.Template`` (a Clock through rclpy costs ~10 µs, a tenth of a step of the default
    scene), checked against ``serialize_message``; if the check fails, ``encode`` serialises
    through rclpy instead."""

    def __init__(self) -> None:
        from abd_joint_sim.record import cdr
        self._template = cdr.Template(clock_msg(0), [(('clock', 'sec'), 'iI')])
        self.checked = self._template.matches(
            ((divmod(ns, NS_PER_S),), clock_msg(ns))
            for ns in (0, 1, NS_PER_S - 1, 1_234_567_891_011, (2 ** 31 - 1) * NS_PER_S + NS_PER_S - 1))

    def encode(self, stamp_ns: int) -> bytes:
        if self.checked:
            return self._template.pack(divmod(stamp_ns, NS_PER_S))
        from abd_joint_sim.record import cdr
        return cdr.serialized(clock_msg(stamp_ns))

    def encode_many(self, stamps_ns: Sequence[int]) -> list[bytes]:
        """``[encode(t) for t in stamps_ns]`` (a run of a batch's steps)."""
        return [self.encode(t) for t in stamps_ns]


class JointStateEncoder:
    """/joint_states as serialized CDR, for ``Publisher.publish(bytes)`` and the bag: with
    fixed names and frame only the stamp and the three float64 arrays change, packed into the
    message's template by ``cdr.Template`` and checked here against ``serialize_message`` on
    several states; if the check fails, ``encode`` serialises through rclpy instead."""

    def __init__(self, names: Sequence[str], frame_id: str = '') -> None:
        from abd_joint_sim.record import cdr
        self.names = list(names)
        self.frame_id = frame_id
        n = len(self.names)
        self._n = n
        self._msg = joint_state_msg(0, self.names, [0.0] * n, [0.0] * n, [0.0] * n, frame_id)
        fields = [(('header', 'stamp', 'sec'), 'iI')]
        if n:
            fields += [((attr,), f'{n}d') for attr in ('position', 'velocity', 'effort')]
        self._template = cdr.Template(self._msg, fields)
        rng = np.random.default_rng(15)
        self.checked = all(
            self._pack(ns, *vals) == self._serialize(ns, *vals)
            for ns, vals in ((0, ([0.0] * n,) * 3), (1_234_567_891_011, tuple(
                rng.normal(size=(3, n)).tolist())), ((2 ** 31 - 1) * NS_PER_S + 7, tuple(
                    (rng.normal(size=(3, n)) * 1e300).tolist()))))

    def _serialize(self, stamp_ns: int, position, velocity, effort) -> bytes:
        from abd_joint_sim.record import cdr
        fill_joint_state(self._msg, stamp_ns, list(position), list(velocity), list(effort),
                         self.frame_id)
        return cdr.serialized(self._msg)

    def _pack(self, stamp_ns: int, position, velocity, effort) -> bytes:
        stamp = divmod(int(stamp_ns), NS_PER_S)
        if self._n:
            return self._template.pack(stamp, position, velocity, effort)
        return self._template.pack(stamp)           # no joints: the stamp alone changes

    def encode(self, stamp_ns: int, position: Sequence[float], velocity: Sequence[float],
               effort: Sequence[float]) -> bytes:
        """The CDR bytes of the JointState at `stamp_ns` (plain float lists, one per joint)."""
        check_lengths(self._n, position, velocity, effort)
        if self.checked:
            return self._pack(stamp_ns, position, velocity, effort)
        return self._serialize(stamp_ns, position, velocity, effort)


def float64_msg(value: float) -> Float64:
    return Float64(data=float(value))


def bool_msg(flag: bool) -> Bool:
    return Bool(data=bool(flag))


def float64_array_msg(values: Iterable[float], label: str = 'joints') -> Float64MultiArray:
    data = [float(v) for v in values]
    msg = Float64MultiArray(data=data)
    msg.layout.dim = [MultiArrayDimension(label=label, size=len(data), stride=len(data))]
    return msg


def array_values(msg: Float64MultiArray) -> list[float]:
    """The values of an array command (`data`, honouring `layout.data_offset`)."""
    return [float(v) for v in msg.data[msg.layout.data_offset:]]


def _kv(key: str, value: object) -> KeyValue:
    if isinstance(value, float):
        return KeyValue(key=key, value='nan' if math.isnan(value) else f'{value:.6g}')
    return KeyValue(key=key, value=str(value))


def diagnostics_msg(stamp_ns: int, name: str, hardware_id: str, level_ok: bool,
                    message: str, values: Mapping[str, object],
                    level: Optional[int] = None) -> DiagnosticArray:
    """One DiagnosticStatus in a DiagnosticArray stamped with sim time: OK or WARN after
    `level_ok`, unless `level` (OK, WARN, ERROR) is given."""
    status = DiagnosticStatus(level=(OK if level_ok else WARN) if level is None else level,
                              name=name, hardware_id=hardware_id, message=message,
                              values=[_kv(k, v) for k, v in values.items()])
    msg = DiagnosticArray(status=[status])
    msg.header.stamp = ns_to_time_msg(stamp_ns)
    return msg
