"""The parameter table of sim_node and its validation, in plain Python.

One row per parameter: name, default, description, read_only. The node declares every row
with a ``ParameterDescriptor`` (so ``ros2 param describe`` explains it), reads the values
once into a :class:`SimConfig` through :func:`config_from_values`, and vets live changes
with :func:`check_live_value`. Nothing here needs DDS.

Numeric parameters are declared with dynamic typing and coerced here, so ``-p
real_time_factor:=0`` (an integer on the command line) works as well as ``0.0``; any other
type is refused with a message naming the parameter.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math
import os
from typing import Any, NamedTuple, Optional, Sequence

NODE_NAME = 'abd_joint_sim'
PACKAGE_NAME = 'abd_joint_sim'


class ParamSpec(NamedTuple):
    name: str
    default: Any
    description: str
    read_only: bool


PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec('scene', '',
              'Scene YAML file. Empty = the packaged default scene (a fixed base with a '
              'two-link arm, joints shoulder and elbow); a bare name such as "hinge" picks '
              'a packaged scene.', True),
    ParamSpec('time_step', 0.0,
              'Time step h [s]. 0 = the scene\'s dt.', True),
    ParamSpec('real_time_factor', 1.0,
              'Simulated seconds per wall-clock second. 0 = as fast as possible. Live.',
              False),
    ParamSpec('publish_rate', 100.0,
              'Rate of /joint_states [Hz of simulated time]. 0 = after every step. Live.',
              False),
    ParamSpec('start_paused', False,
              'Start paused; resume with the ~/unpause service or advance with ~/step.', True),
    ParamSpec('command_timeout', 0.0,
              'Simulated seconds after the last torque command of a joint at which its '
              'torque returns to 0 (logged once per joint). 0 = off. Live.', False),
    ParamSpec('effort_limits', [],
              'Torque limits [N m], one per joint of `joints`, in that order; commands '
              'beyond are clamped (and a throttled warning says so). Empty = no limits. '
              'Live.', False),
    ParamSpec('joints', [],
              'Joint order of the array command on joint_torque_commands (and of '
              'effort_limits). Empty = all actuated joints in scene order.', True),
    ParamSpec('record', '',
              'rosbag2 (MCAP) bag directory to record the run into; must not exist yet. '
              'Empty = no recording.', True),
    ParamSpec('frame_id', '',
              'header.frame_id of the published joint states.', True),
)

PARAMS_BY_NAME = {p.name: p for p in PARAMS}

# Live parameters the node applies while running (the rest are read once at start).
LIVE = frozenset(p.name for p in PARAMS if not p.read_only)


@dataclass
class SimConfig:
    """Validated parameter values (units as in :data:`PARAMS`)."""

    scene: str
    time_step: float = 0.0
    real_time_factor: float = 1.0
    publish_rate: float = 100.0
    start_paused: bool = False
    command_timeout: float = 0.0
    effort_limits: list[float] = field(default_factory=list)
    joints: list[str] = field(default_factory=list)
    record: str = ''
    frame_id: str = ''

    def as_dict(self) -> dict[str, Any]:
        return {p.name: getattr(self, p.name) for p in PARAMS}


def packaged_scenes_dir() -> str:
    """Directory of the packaged scenes: beside the Python package, else the ament share."""
    here = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), 'scenes')
    if os.path.isdir(here):
        return here
    try:
        from ament_index_python.packages import get_package_share_directory
        return os.path.join(get_package_share_directory(PACKAGE_NAME), 'scenes')
    except Exception:  # noqa: BLE001 - not installed through ament: keep the package path
        return here


def default_scene_path() -> str:
    return os.path.join(packaged_scenes_dir(), 'default.yaml')


def resolve_scene(value: str) -> str:
    """Scene parameter -> file path ('' = default scene, bare name = packaged scene)."""
    value = value.strip()
    if not value:
        return default_scene_path()
    if os.sep not in value and not value.endswith(('.yaml', '.yml')):
        return os.path.join(packaged_scenes_dir(), value + '.yaml')
    return os.path.abspath(os.path.expanduser(value))


def _as_float(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f'parameter {name!r}: expected a number, got {value!r}')
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f'parameter {name!r}: {value} is not finite')
    return value


def _as_nonneg(name: str, value: Any) -> float:
    value = _as_float(name, value)
    if value < 0.0:
        raise ValueError(f'parameter {name!r}: {value} is negative (0 means "off"/"auto")')
    return value


def _as_float_list(name: str, value: Any) -> list[float]:
    if value is None:
        return []
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
        # A byte array is what an empty list is declared as: accept it only when empty.
        if isinstance(value, bytes) and not value:
            return []
        raise ValueError(f'parameter {name!r}: expected a list of numbers, got {value!r}')
    out = []
    for v in value:
        if isinstance(v, bytes):
            raise ValueError(f'parameter {name!r}: expected a list of numbers, got {value!r}')
        out.append(_as_float(name, v))
    return out


def _as_str_list(name: str, value: Any) -> list[str]:
    if value is None:
        return []
    if isinstance(value, str) or not isinstance(value, Sequence):
        raise ValueError(f'parameter {name!r}: expected a list of strings, got {value!r}')
    out = []
    for v in value:
        if not isinstance(v, str):
            if isinstance(v, bytes) and not value:
                continue
            raise ValueError(f'parameter {name!r}: expected a list of strings, got {value!r}')
        if v.strip():
            out.append(v.strip())
    return out


def _as_str(name: str, value: Any) -> str:
    if value is None:
        return ''
    if not isinstance(value, str):
        raise ValueError(f'parameter {name!r}: expected a string, got {value!r}')
    return value


def _as_bool(name: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise ValueError(f'parameter {name!r}: expected true/false, got {value!r}')
    return value


def _check_limits(limits: list[float]) -> list[float]:
    for i, lim in enumerate(limits):
        if not lim > 0.0:
            raise ValueError(
                f'parameter \'effort_limits\': entry {i} is {lim}; limits must be > 0 '
                '(use an empty list for no limits)')
    return limits


_COERCE = {
    'scene': _as_str,
    'time_step': _as_nonneg,
    'real_time_factor': _as_nonneg,
    'publish_rate': _as_nonneg,
    'start_paused': _as_bool,
    'command_timeout': _as_nonneg,
    'effort_limits': lambda n, v: _check_limits(_as_float_list(n, v)),
    'joints': _as_str_list,
    'record': _as_str,
    'frame_id': _as_str,
}


def coerce(name: str, value: Any) -> Any:
    """Validate and normalise one parameter value; raise ValueError naming it."""
    return _COERCE[name](name, value)


def config_from_values(values: dict[str, Any]) -> SimConfig:
    """Build the config from raw parameter values (missing names take their defaults)."""
    kwargs = {}
    for spec in PARAMS:
        kwargs[spec.name] = coerce(spec.name, values.get(spec.name, spec.default))
    kwargs['scene'] = resolve_scene(kwargs['scene'])
    return SimConfig(**kwargs)


def check_live_value(name: str, value: Any, n_joints: Optional[int] = None) -> Optional[str]:
    """Reason to refuse a live change of `name` to `value`, or None if acceptable."""
    spec = PARAMS_BY_NAME.get(name)
    if spec is None:
        return None  # not ours (e.g. use_sim_time): let rclpy handle it
    if spec.read_only:
        return f'parameter {name!r} is read-only (set it at start)'
    try:
        value = coerce(name, value)
    except ValueError as exc:
        return str(exc)
    if name == 'effort_limits' and n_joints is not None and value and len(value) != n_joints:
        return (f'effort_limits needs {n_joints} values (one per joint of `joints`) or none, '
                f'got {len(value)}')
    return None
