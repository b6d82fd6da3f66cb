"""JSON schemas of the live channels (``jsonschema`` encoding, messages in JSON).

``foxglove.SceneUpdate`` and ``foxglove.FrameTransforms`` are Foxglove's well-known schemas
(the 3D panel recognises them by name); written out here for the fields the server fills
(the SDK ships them only as protobuf descriptors, and a browser page reads JSON without a
protobuf library). The joint states and the solver status are this package's own.
"""
from __future__ import annotations

import json

_NUM = {'type': 'number'}
_STR = {'type': 'string'}
_TIME = {'type': 'object', 'properties': {'sec': {'type': 'integer'},
                                          'nsec': {'type': 'integer'}}}
_VEC = {'type': 'object', 'properties': {k: _NUM for k in 'xyz'}}
_QUAT = {'type': 'object', 'properties': {k: _NUM for k in 'xyzw'}}
_POSE = {'type': 'object', 'properties': {'position': _VEC, 'orientation': _QUAT}}
_COLOUR = {'type': 'object', 'properties': {k: _NUM for k in 'rgba'}}


def _array(item):
    return {'type': 'array', 'items': item}


def _object(title, **props):
    return {'title': title, 'type': 'object', 'properties': props}


_PRIMITIVE = {'type': 'object', 'properties': {'pose': _POSE, 'size': _VEC, 'color': _COLOUR}}
_CYLINDER = {'type': 'object', 'properties': {'pose': _POSE, 'size': _VEC, 'color': _COLOUR,
                                              'bottom_scale': _NUM, 'top_scale': _NUM}}
_MODEL = {'type': 'object', 'properties': {
    'pose': _POSE, 'scale': _VEC, 'color': _COLOUR, 'override_color': {'type': 'boolean'},
    'url': _STR, 'media_type': _STR, 'data': {'type': 'string', 'contentEncoding': 'base64'}}}
_ENTITY = {'type': 'object', 'properties': {
    'timestamp': _TIME, 'frame_id': _STR, 'id': _STR, 'lifetime': _TIME,
    'frame_locked': {'type': 'boolean'},
    'metadata': _array({'type': 'object', 'properties': {'key': _STR, 'value': _STR}}),
    'arrows': _array({'type': 'object'}), 'cubes': _array(_PRIMITIVE),
    'spheres': _array(_PRIMITIVE), 'cylinders': _array(_CYLINDER),
    'lines': _array({'type': 'object'}), 'triangles': _array({'type': 'object'}),
    'texts': _array({'type': 'object'}), 'models': _array(_MODEL)}}

SCENE_UPDATE = _object(
    'foxglove.SceneUpdate',
    deletions=_array({'type': 'object', 'properties': {'timestamp': _TIME,
                                                       'type': {'type': 'integer'},
                                                       'id': _STR}}),
    entities=_array(_ENTITY))

FRAME_TRANSFORMS = _object(
    'foxglove.FrameTransforms',
    transforms=_array({'type': 'object', 'properties': {
        'timestamp': _TIME, 'parent_frame_id': _STR, 'child_frame_id': _STR,
        'translation': _VEC, 'rotation': _QUAT}}))

JOINT_STATES = _object(
    'abd_joint_sim.JointStates', timestamp=_TIME, name=_array(_STR), position=_array(_NUM),
    velocity=_array(_NUM), effort=_array(_NUM))

STATUS = _object(
    'abd_joint_sim.Status', timestamp=_TIME, sim_time=_NUM, steps={'type': 'integer'},
    paused={'type': 'boolean'}, time_step=_NUM, real_time_factor=_NUM,
    newton_iterations={'type': 'integer'}, converged={'type': 'boolean'},
    max_joint_separation=_NUM, fault=_STR, source=_STR,
    wall_time=_NUM)     # the publisher's clock [s since the epoch]: the page's latency

TRIGGER_REQUEST = _object('std_srvs/Trigger_Request')
TRIGGER_RESPONSE = _object('std_srvs/Trigger_Response', success={'type': 'boolean'},
                           message=_STR)


def text(schema: dict) -> bytes:
    return json.dumps(schema, separators=(',', ':')).encode()
