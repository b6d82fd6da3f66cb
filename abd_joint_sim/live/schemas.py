"""JSON schemas of the live channels (``jsonschema`` encoding, messages in JSON): Foxglove's
well-known ``foxglove.SceneUpdate`` and ``foxglove.FrameTransforms`` for the fields the server
fills (the SDK ships them only as protobuf descriptors), and this package's own."""
from __future__ import annotations

import json

_NUM, _STR, _INT, _BOOL = ({'type': t} for t in ('number', 'string', 'integer', 'boolean'))
_ANY = {'type': 'object'}


def _array(item):
    return {'type': 'array', 'items': item}


def _obj(**props):
    return {'type': 'object', 'properties': props}


def _object(title, **props):
    return {'title': title, **_obj(**props)}


_TIME = _obj(sec=_INT, nsec=_INT)
_VEC, _QUAT, _COLOUR = (_obj(**{k: _NUM for k in keys}) for keys in ('xyz', 'xyzw', 'rgba'))
_POSE = _obj(position=_VEC, orientation=_QUAT)
_PRIMITIVE = _obj(pose=_POSE, size=_VEC, color=_COLOUR)
_CYLINDER = _obj(pose=_POSE, size=_VEC, color=_COLOUR, bottom_scale=_NUM, top_scale=_NUM)
_MODEL = _obj(pose=_POSE, scale=_VEC, color=_COLOUR, override_color=_BOOL, url=_STR,
              media_type=_STR, data={'type': 'string', 'contentEncoding': 'base64'})
_ENTITY = _obj(
    timestamp=_TIME, frame_id=_STR, id=_STR, lifetime=_TIME, frame_locked=_BOOL,
    metadata=_array(_obj(key=_STR, value=_STR)), arrows=_array(_ANY),
    cubes=_array(_PRIMITIVE), spheres=_array(_PRIMITIVE), cylinders=_array(_CYLINDER),
    lines=_array(_ANY), triangles=_array(_ANY), texts=_array(_ANY), models=_array(_MODEL))

SCENE_UPDATE = _object('foxglove.SceneUpdate',
                       deletions=_array(_obj(timestamp=_TIME, type=_INT, id=_STR)),
                       entities=_array(_ENTITY))
FRAME_TRANSFORMS = _object('foxglove.FrameTransforms', transforms=_array(_obj(
    timestamp=_TIME, parent_frame_id=_STR, child_frame_id=_STR, translation=_VEC,
    rotation=_QUAT)))
JOINT_STATES = _object(
    'abd_joint_sim.JointStates', timestamp=_TIME, name=_array(_STR), position=_array(_NUM),
    velocity=_array(_NUM), effort=_array(_NUM))
STATUS = _object(
    'abd_joint_sim.Status', timestamp=_TIME, sim_time=_NUM, steps=_INT, paused=_BOOL,
    time_step=_NUM, real_time_factor=_NUM, newton_iterations=_INT, converged=_BOOL,
    max_joint_separation=_NUM, fault=_STR, source=_STR,
    wall_time=_NUM)     # the publisher's clock [s since the epoch]: the page's latency
TRIGGER_REQUEST = _object('std_srvs/Trigger_Request')
TRIGGER_RESPONSE = _object('std_srvs/Trigger_Response', success=_BOOL, message=_STR)


def text(schema: dict) -> bytes:
    return json.dumps(schema, separators=(',', ':')).encode()
