"""What the live server sends, as plain JSON-ready dicts (Foxglove's JSON encoding of its
``foxglove.SceneUpdate`` and ``foxglove.FrameTransforms`` schemas), built from a scene.

Each body has a frame named as the body, posed in the world frame by its position p and the
rotation nearest to its affine A; a URDF link merged into a body gets a frame of its own,
the child of its body's frame. One ``SceneUpdate`` entity per body, frame-locked in the
body's frame, holds exactly the parts the markers draw (``MarkerBuilder``'s parts).
"""
from __future__ import annotations

import json
from typing import Any, Optional

import numpy as np

from abd_joint_sim.ros.markers import MarkerBuilder
from abd_joint_sim.smallmat import quaternion_in

NS_PER_S = 1_000_000_000


def stamp(t_ns: int) -> dict:
    sec, nsec = divmod(int(t_ns), NS_PER_S)
    return {'sec': sec, 'nsec': nsec}


def _vec(v) -> dict:
    return {'x': float(v[0]), 'y': float(v[1]), 'z': float(v[2])}


def _pose(t, R) -> dict:
    out = np.empty(4)
    quaternion_in(np.ascontiguousarray(R, dtype=float), out)     # (x, y, z, w), w >= 0
    x, y, z, w = out.tolist()
    return {'position': _vec(t), 'orientation': {'x': x, 'y': y, 'z': z, 'w': w}}


def scene_entities(scene: Any, builder: Optional[MarkerBuilder] = None) -> list[dict]:
    """One ``foxglove.SceneEntity`` (JSON) per body of `scene`, in the body's frame, without
    a timestamp (``scene_update`` adds it). Geometry from `builder` (a MarkerBuilder of the
    scene: the markers' own parts)."""
    M = __import__('visualization_msgs.msg', fromlist=['Marker']).Marker
    builder = builder or MarkerBuilder(scene)
    entities = {name: {'frame_id': name, 'id': f'bodies/{name}',
                       'lifetime': {'sec': 0, 'nsec': 0}, 'frame_locked': True,
                       'metadata': [{'key': 'body', 'value': name}], 'arrows': [],
                       'cubes': [], 'spheres': [], 'cylinders': [], 'lines': [],
                       'triangles': [], 'texts': [], 'models': []}
                for name in builder.body_names}
    for part in builder.parts:
        e = entities[part.body]
        pose = _pose(part.t, part.R)
        colour = dict(zip('rgba', part.colour))
        size = {'x': part.scale[0], 'y': part.scale[1], 'z': part.scale[2]}
        if part.kind in (M.CUBE, M.SPHERE):
            e['cubes' if part.kind == M.CUBE else 'spheres'].append(
                {'pose': pose, 'size': size, 'color': colour})
        elif part.kind == M.CYLINDER:
            e['cylinders'].append({'pose': pose, 'size': size, 'bottom_scale': 1.0,
                                   'top_scale': 1.0, 'color': colour})
        elif part.kind == M.MESH_RESOURCE:
            e['models'].append({'pose': pose, 'scale': size, 'color': colour,
                                'override_color': False, 'url': part.mesh_uri,
                                'media_type': '', 'data': ''})
    return list(entities.values())


def scene_update_bytes(entities: list[dict], t_ns: int) -> bytes:
    """The ``SceneUpdate`` JSON of `entities` stamped `t_ns`."""
    ts = stamp(t_ns)
    return json.dumps({'deletions': [], 'entities': [dict(e, timestamp=ts) for e in entities]},
                      separators=(',', ':')).encode()


def urdf_link_frames(scene: Any) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
    """(body, link, translation (3,), rotation (3,3)) of each URDF link that is no body of
    `scene` (merged into one by a fixed or locked joint): its frame in its body's frame.
    Empty for a scene without ``robot_description``."""
    text = getattr(scene, 'robot_description', '') or ''
    if not text:
        return []
    from abd_joint_sim.urdf import _Reader
    _name, links, joints = _Reader('robot_description').parse(text)
    bodies = {b.name for b in scene.bodies}
    parent_joint = {j.child: j for j in joints.values()}
    out = []
    for link in links:
        if link in bodies:
            continue
        T = np.eye(4)
        name = link
        while name not in bodies and name in parent_joint:
            j = parent_joint[name]
            T = j.origin @ T
            name = j.parent
        if name in bodies:
            out.append((name, link, T[:3, 3].copy(), T[:3, :3].copy()))
    return out


class FrameBuilder:
    """``FrameTransforms`` (JSON) of the body frames (in `world_frame`) and of the URDF links
    merged into bodies (in their body's frame), from the bodies' states."""

    def __init__(self, scene: Any, world_frame: str = 'world'):
        self.world_frame = world_frame
        self.body_names = [b.name for b in scene.bodies]
        self.links = urdf_link_frames(scene)
        self._static = [{'parent_frame_id': body, 'child_frame_id': link,
                         'translation': _vec(t), 'rotation': _pose(t, R)['orientation']}
                        for body, link, t, R in self.links]
        B = len(self.body_names)
        self._k = np.arange(B, dtype=np.intp)
        self._t = np.zeros((B, 3))
        self._Rv = np.repeat(np.eye(3)[None], B, axis=0)
        self._none_i = np.zeros(0, dtype=np.intp)
        self._none_p = np.zeros((0, 3))
        self._poses = np.empty((B, 7))
        self._points = np.empty((0, 3))

    def body_poses(self, body_pose) -> Optional[np.ndarray]:
        """(B, 7) = (x, y, z, qx, qy, qz, qw) of each body frame: p and the rotation nearest
        A, from ``World.body_pose`` (name -> (p, A)). None if not finite."""
        from abd_joint_sim.smallmat import frame_poses
        pa = [body_pose(n) for n in self.body_names]
        P = np.array([p for p, _ in pa], dtype=float)
        A = np.array([a for _, a in pa], dtype=float)
        if not frame_poses(P, A, self._k, self._t, self._Rv, self._none_i, self._none_p,
                           self._poses, self._points):
            return None
        return self._poses

    def transforms(self, t_ns: int, poses: np.ndarray) -> dict:
        ts = stamp(t_ns)
        out = [{'timestamp': ts, 'parent_frame_id': self.world_frame, 'child_frame_id': name,
                'translation': {'x': x, 'y': y, 'z': z},
                'rotation': {'x': qx, 'y': qy, 'z': qz, 'w': qw}}
               for name, (x, y, z, qx, qy, qz, qw) in zip(self.body_names, poses.tolist())]
        out.extend(dict(s, timestamp=ts) for s in self._static)
        return {'transforms': out}
