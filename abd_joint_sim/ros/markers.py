"""The bodies as ``visualization_msgs/msg/MarkerArray`` for RViz and Foxglove, built alike
by sim_node and the headless recorder (``tools/sim.py``). What is drawn and how it is posed
(URDF visuals, else the scene's shape, else the box of equal inertia; the rotation nearest
to A): docs/viewing.md. Joint axes (optional): one ``ARROW`` per joint from ``p0`` to ``p1``
carried by the parent body; a URDF robot's start at the joint origin, 0.2 x the robot's
extent long (clipped to [0.05, 1] m). Namespaces ``bodies/<body>`` (id = the visual's index)
and ``joint_axes`` (id = the joint's index); every array carries every marker in full
(action ADD), so each message replaces the previous one (docs/bag-format.md).
"""
from __future__ import annotations

from typing import Any, Optional, Sequence

import numpy as np

from abd_joint_sim.geometry import rpy_matrix
from abd_joint_sim.smallmat import frame_poses

# Colours of bodies without an rgba of their own (fixed bodies grey), RGBA in [0, 1].
PALETTE = ((0.20, 0.47, 0.80, 1.0), (0.90, 0.50, 0.10, 1.0), (0.25, 0.65, 0.30, 1.0),
           (0.80, 0.25, 0.30, 1.0), (0.55, 0.40, 0.75, 1.0), (0.55, 0.35, 0.25, 1.0))
FIXED_COLOUR = (0.55, 0.55, 0.55, 1.0)
AXIS_COLOUR = (0.95, 0.85, 0.10, 1.0)


def _scale(M, kind: str, size) -> tuple:
    """(marker type, scale) of a box (sides), mesh (scale), sphere (radius) or cylinder
    (radius, length)."""
    if kind in ('box', 'mesh'):
        return (M.CUBE if kind == 'box' else M.MESH_RESOURCE), tuple(size)
    if kind == 'sphere':
        return M.SPHERE, (2 * size[0],) * 3
    r, length = size
    return M.CYLINDER, (2 * r, 2 * r, length)


def equal_inertia_box(mass: float, inertia: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """(sides (3,), axes (3,3) with det +1) of the box with the inertia `inertia` (3x3 about
    the COM, row-major) and mass `mass`: a_i = sqrt(6 (I_j + I_k - I_i) / m)."""
    I = np.asarray(inertia, dtype=float).reshape(3, 3)
    moments, axes = np.linalg.eigh(0.5 * (I + I.T))
    if np.linalg.det(axes) < 0.0:
        axes[:, 2] = -axes[:, 2]
    total = moments.sum()
    # Physical inertias obey the triangle inequality; clip what rounding leaves below 0.
    sides = np.sqrt(np.maximum(6.0 * (total - 2.0 * moments) / max(mass, 1e-300), 1e-12))
    return sides, axes


def robot_axis_length(scene: Any) -> Optional[float]:
    """Length [m] of a URDF robot's joint-axis arrows (module docstring), None for a scene
    written in YAML (its arrows are p0 -> p1 as given)."""
    if not getattr(scene, 'robot_description', ''):
        return None
    pts = [np.asarray(j.p0, dtype=float) for j in scene.joints] + \
        [np.asarray(b.position, dtype=float) for b in scene.bodies]
    extent = float(np.linalg.norm(np.ptp(np.array(pts), axis=0))) if pts else 0.0
    return min(max(0.2 * extent, 0.05), 1.0)


class _Part:
    """One marker of a body: type, scale, colour, mesh URI, origin in the body frame."""

    def __init__(self, body: str, index: int, kind: int, scale, colour, origin_t, origin_R,
                 mesh_uri: str = ''):
        self.body, self.index, self.kind = body, index, kind
        self.scale = tuple(float(v) for v in scale)
        self.colour = tuple(float(v) for v in colour)
        self.t = np.asarray(origin_t, dtype=float)
        self.R = np.asarray(origin_R, dtype=float)
        self.mesh_uri = mesh_uri


class MarkerBuilder:
    """Builds the MarkerArray of a scene's bodies from their current poses.

    :param scene: the ``Scene`` (bodies, their shapes and visuals, the joints).
    :param frame_id: ``header.frame_id`` of every marker (the frame of the world positions).
    :param joint_axes: also draw each joint's axis as an arrow.
    """

    def __init__(self, scene: Any, frame_id: str = 'world', joint_axes: bool = False):
        from visualization_msgs.msg import Marker
        self.Marker = Marker
        self.frame_id = frame_id
        self.body_names = [b.name for b in scene.bodies]
        self.parts: list[_Part] = []
        for k, body in enumerate(scene.bodies):
            colour = FIXED_COLOUR if body.fixed else PALETTE[k % len(PALETTE)]
            self.parts.extend(self._body_parts(body, colour))
        self.axes: list[tuple[int, str, str, np.ndarray, np.ndarray]] = []
        if joint_axes:
            bodies = {b.name: b for b in scene.bodies}
            length = robot_axis_length(scene)
            for j, joint in enumerate(scene.joints):
                parent = bodies[joint.parent]
                R0 = rpy_matrix(parent.rpy)
                p0 = np.asarray(parent.position, dtype=float)
                q0 = np.asarray(joint.p0, dtype=float)
                q1 = np.asarray(joint.p1, dtype=float)
                if length is not None:
                    q1 = q0 + length * (q1 - q0) / np.linalg.norm(q1 - q0)
                self.axes.append((j, joint.name, joint.parent, R0.T @ (q0 - p0),
                                  R0.T @ (q1 - p0)))
        self._msg: Optional[Any] = None
        self._cdr: Optional[Any] = None    # build_serialized's cdr.Template
        self._packed_ok = False
        # the parts' bodies and origins, the arrows' bodies and ends, as arrays; the outputs
        index = {name: k for k, name in enumerate(self.body_names)}
        ka = np.array([index[parent] for _j, _n, parent, _a, _b in self.axes], dtype=np.intp)
        self._stacked = (
            np.array([index[p.body] for p in self.parts], dtype=np.intp),
            np.array([p.t for p in self.parts], dtype=float).reshape(-1, 3),
            np.array([p.R for p in self.parts], dtype=float).reshape(-1, 3, 3),
            np.repeat(ka, 2),
            np.array([np.concatenate([a, b]) for *_, a, b in self.axes],
                     dtype=float).reshape(-1, 3),
            np.empty((len(self.parts), 7)), np.empty((2 * len(self.axes), 3)))

    def _body_parts(self, body: Any, colour) -> list[_Part]:
        M = self.Marker
        visuals = tuple(getattr(body, 'visuals', ()) or ())
        if visuals:             # (kinds and sizes as Scene validates them)
            return [_Part(body.name, i, *_scale(M, v.kind, v.size),
                          colour if v.rgba is None else v.rgba, v.origin_xyz,
                          rpy_matrix(v.origin_rpy), v.mesh_uri if v.kind == 'mesh' else '')
                    for i, v in enumerate(visuals)]
        s = body.shape
        if s.kind in ('box', 'sphere', 'cylinder'):
            return [_Part(body.name, 0, *_scale(M, s.kind, s.size), colour, (0, 0, 0),
                          np.eye(3))]
        sides, axes = equal_inertia_box(s.mass, s.inertia)
        return [_Part(body.name, 0, M.CUBE, sides, colour, s.com, axes)]

    def _template(self) -> Any:
        """The MarkerArray with every field that does not change (built once: an rclpy
        message costs tens of µs to construct, more than refilling its pose)."""
        from geometry_msgs.msg import Point
        from visualization_msgs.msg import MarkerArray
        out = MarkerArray()
        for part in self.parts:
            m = self._marker(f'bodies/{part.body}', part.index, part.kind)
            m.scale.x, m.scale.y, m.scale.z = part.scale
            m.color.r, m.color.g, m.color.b, m.color.a = part.colour
            if part.mesh_uri:
                m.mesh_resource = part.mesh_uri
            out.markers.append(m)
        for j, _name, _parent, a, b in self.axes:
            m = self._marker('joint_axes', j, self.Marker.ARROW)
            m.pose.orientation.w = 1.0
            m.points = [Point(), Point()]
            length = float(np.linalg.norm(b - a))
            # shaft diameter, head diameter, head length (ARROW given by two points)
            m.scale.x, m.scale.y, m.scale.z = 0.02 * length, 0.05 * length, 0.1 * length
            m.color.r, m.color.g, m.color.b, m.color.a = AXIS_COLOUR
            out.markers.append(m)
        return out

    def build(self, stamp_ns: int, pose) -> Optional[Any]:
        """The MarkerArray at `stamp_ns` with body poses from `pose(name) -> (p, A)`
        (``World.body_pose``), or from the (bodies, 12) states [p, A] of `body_names` in
        that order; None if a pose is not finite. The same message object is refilled by
        every call: publish or serialise it before the next."""
        values = self._values(pose)
        if values is None:
            return None
        poses, points = values
        if self._msg is None:
            self._msg = self._template()
        sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
        markers = self._msg.markers
        for m, (x, y, z, qx, qy, qz, qw) in zip(markers, poses):
            m.header.stamp.sec, m.header.stamp.nanosec = sec, nanosec
            m.pose.position.x, m.pose.position.y, m.pose.position.z = x, y, z
            o = m.pose.orientation
            o.x, o.y, o.z, o.w = qx, qy, qz, qw
        for m, xyz in zip(markers[len(self.parts):], points):
            m.header.stamp.sec, m.header.stamp.nanosec = sec, nanosec
            for point, k in zip(m.points, (0, 3)):
                point.x, point.y, point.z = xyz[k:k + 3]
        return self._msg

    def build_serialized(self, stamp_ns: int, pose) -> Optional[bytes]:
        """:meth:`build` as serialized CDR bytes (what ``serialize_message`` gives for it,
        trimmed as the bag stores it, padding zeroed: ``cdr.without_padding``), for
        ``Publisher.publish(bytes)`` and ``BagWriter.write_serialized``; None if a pose is
        not finite. The array is serialised once and only the stamps, poses and arrow
        points are packed into it (``cdr.Template``); the first call checks the packed bytes
        against ``serialize_message`` of :meth:`build`, and should they differ every call
        serialises :meth:`build` instead."""
        from abd_joint_sim.record import cdr
        if self._cdr is None:
            msg = self.build(stamp_ns, pose)
            if msg is None:
                return None
            n, count = len(self.parts), len(msg.markers)
            self._cdr = cdr.Template(
                msg, [(('markers', i, 'header', 'stamp', 'sec'), 'iI') for i in range(count)]
                + [(('markers', i, 'pose', 'position', 'x'), '7d') for i in range(n)]
                + [(('markers', n + i, 'points', 0, 'x'), '6d') for i in range(len(self.axes))])
            self._packed_ok = self._pack(stamp_ns, self._values(pose)) == self._cdr.data
            return self._cdr.data
        values = self._values(pose)
        if values is None:
            return None
        if not self._packed_ok:
            return cdr.serialized(self.build(stamp_ns, pose))
        return self._pack(stamp_ns, values)

    def _pack(self, stamp_ns: int, values) -> bytes:
        """The template with every marker's stamp, the parts' poses (position x y z,
        orientation x y z w) and the arrows' two points set."""
        poses, points = values
        stamps = [divmod(int(stamp_ns), 1_000_000_000)] * (len(self.parts) + len(self.axes))
        return self._cdr.pack(*stamps, *poses, *points)

    def _values(self, pose) -> Optional[tuple[list, list]]:
        """([(x, y, z, qx, qy, qz, qw) per body part], [(x0, y0, z0, x1, y1, z1) per joint
        arrow]) of the current poses (`pose` as in `build`), plain floats, all parts at once
        (smallmat.frame_poses); None if a pose is not finite."""
        if isinstance(pose, np.ndarray):
            P = np.ascontiguousarray(pose[:, :3], dtype=float)
            A = np.ascontiguousarray(pose[:, 3:12], dtype=float).reshape(-1, 3, 3)
        else:
            poses = [pose(name) for name in self.body_names]
            P = np.asarray([p for p, _ in poses], dtype=float)
            A = np.asarray([a for _, a in poses], dtype=float)
        k, t, Rv, ends_body, ends, poses, points = self._stacked
        if not frame_poses(P, A, k, t, Rv, ends_body, ends, poses, points):
            return None
        return ([tuple(v) for v in poses.tolist()],
                [tuple(v) for v in points.reshape(-1, 6).tolist()])

    def _marker(self, ns: str, mid: int, kind: int):
        m = self.Marker()
        m.header.frame_id = self.frame_id
        m.ns, m.id, m.type, m.action = ns, int(mid), int(kind), self.Marker.ADD
        return m
