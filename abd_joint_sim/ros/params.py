"""The parameter table of sim_node and its validation, in plain Python (no DDS).

One row per parameter: name, default, description, read_only, and the function that
validates and normalises a value (numbers are declared with dynamic typing and coerced, so
``-p real_time_factor:=0`` works as well as ``0.0``). The node declares every row with a
``ParameterDescriptor``, reads the values once into a :class:`SimConfig`
(:func:`config_from_values`) and vets live changes with :func:`check_live_value`.
"""
from __future__ import annotations

from dataclasses import field, make_dataclass
import math
import os
from typing import Any, Callable, NamedTuple, Optional, Sequence

NODE_NAME = 'abd_joint_sim'
PACKAGE_NAME = 'abd_joint_sim'


class ParamSpec(NamedTuple):
    name: str
    default: Any
    description: str
    read_only: bool
    coerce: Callable[[str, Any], Any]


def _as_float(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f'parameter {name!r}: expected a number, got {value!r}')
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f'parameter {name!r}: {value} is not finite')
    return value


RANGES = {      # name: (lowest, highest) of a non-zero value (0: off, auto, every step)
    'time_step': (1e-6, 1.0),                  # s, as a scene's dt
    'real_time_factor': (1e-4, 1e4),
    'publish_rate': (1e-6, 1e9),               # Hz of simulated time; 1e9 = every ns
    'command_timeout': (1e-6, 1e6),            # s of simulated time
}
"""Sane ranges of the numeric parameters, refused beyond at start and live: a typo, and the
arithmetic on it (1e9 / publish_rate ns, dt / real_time_factor s) would overflow."""

MAX_EFFORT_LIMIT = 1e9
"""[N m] Largest effort limit (= commands.MAX_ABS_TORQUE, the largest accepted torque)."""


def _as_nonneg(name: str, value: Any) -> float:
    value = _as_float(name, value)
    if value < 0.0:
        raise ValueError(f'parameter {name!r}: {value} is negative (0 means "off"/"auto")')
    lo, hi = RANGES.get(name, (0.0, math.inf))
    if value != 0.0 and not lo <= value <= hi:
        raise ValueError(f'parameter {name!r}: {value!r} is outside the supported range '
                         f'{lo:g} to {hi:g} (or 0)')
    return value


def _as_list(name: str, value: Any, what: str, ok: Callable[[Any], bool]) -> list:
    """A list parameter's items (an empty list is declared as an empty byte array)."""
    if value is None or (isinstance(value, bytes) and not value):
        return []
    if (isinstance(value, (str, bytes)) or not isinstance(value, Sequence)
            or not all(map(ok, value))):
        raise ValueError(f'parameter {name!r}: expected a list of {what}, got {value!r}')
    return list(value)


def _as_float_list(name: str, value: Any) -> list[float]:
    return [_as_float(name, v) for v in
            _as_list(name, value, 'numbers', lambda v: not isinstance(v, bytes))]


def _as_str_list(name: str, value: Any) -> list[str]:
    return [v.strip() for v in _as_list(name, value, 'strings', lambda v: isinstance(v, str))
            if v.strip()]


def _as_str(name: str, value: Any) -> str:
    if value is not None and not isinstance(value, str):
        raise ValueError(f'parameter {name!r}: expected a string, got {value!r}')
    return value or ''


def _as_bool(name: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise ValueError(f'parameter {name!r}: expected true/false, got {value!r}')
    return value


def _as_limits(name: str, value: Any) -> list[float]:
    limits = _as_float_list(name, value)
    for i, lim in enumerate(limits):
        if not lim > 0.0:
            raise ValueError(
                f'parameter \'effort_limits\': entry {i} is {lim}; limits must be > 0 '
                '(use an empty list for no limits)')
        if lim > MAX_EFFORT_LIMIT:
            raise ValueError(
                f'parameter \'effort_limits\': entry {i} is {lim!r}, beyond the largest '
                f'supported torque {MAX_EFFORT_LIMIT:g} N m')
    return limits


def _as_port(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value != int(value):
        raise ValueError(f'parameter {name!r}: expected a whole number 1..65535 (0 = off), '
                         f'got {value!r}')
    if not 0 <= value <= 65535:
        raise ValueError(f'parameter {name!r}: {int(value)} is outside the TCP ports 1..65535 '
                         '(0 = off)')
    return int(value)


def _as_host(name: str, value: Any) -> str:
    return _as_str(name, value).strip() or '127.0.0.1'


def _as_frame(name: str, value: Any) -> str:
    value = _as_str(name, value).strip()
    if not value:
        raise ValueError(f'parameter {name!r}: empty; markers need a frame to be drawn in '
                         "(e.g. 'world')")
    return value


PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec('scene', '',
              'Scene YAML file or URDF file (.urdf). Empty = the packaged default scene (a '
              'fixed base with a two-link arm, joints shoulder and elbow); a bare name such '
              'as "hinge" or "demo_arm" picks a packaged scene or robot.', True, _as_str),
    ParamSpec('robot_description', '',
              'URDF XML text, as robot_state_publisher takes it. Non-empty = this robot is '
              'the scene (default options, docs/urdf.md; a scene YAML with a robot: block '
              'sets options); `scene` is then ignored.', True, _as_str),
    ParamSpec('time_step', 0.0,
              'Time step h [s]. 0 = the scene\'s dt.', True, _as_nonneg),
    ParamSpec('real_time_factor', 1.0,
              'Simulated seconds per wall-clock second. 0 = as fast as possible. Live.',
              False, _as_nonneg),
    ParamSpec('publish_rate', 100.0,
              'Rate of /joint_states [Hz of simulated time]. 0 = after every step. Live.',
              False, _as_nonneg),
    ParamSpec('start_paused', False,
              'Start paused; resume with the ~/unpause service or advance with ~/step.', True,
              _as_bool),
    ParamSpec('command_timeout', 0.0,
              'Simulated seconds after the last torque command of a joint at which its '
              'torque returns to 0 (logged once per joint). 0 = off. Live.', False, _as_nonneg),
    ParamSpec('effort_limits', [],
              'Torque limits [N m], one per joint of `joints`, in that order; commands '
              'beyond are clamped (and a throttled warning says so). Empty = no limits. '
              'Live.', False, _as_limits),
    ParamSpec('joints', [],
              'Joint order of the array command on joint_torque_commands (and of '
              'effort_limits). Empty = all actuated joints in scene order.', True, _as_str_list),
    ParamSpec('record', '',
              'rosbag2 (MCAP) bag directory to record the run into; must not exist yet. '
              'Empty = no recording.', True, _as_str),
    ParamSpec('frame_id', '',
              'header.frame_id of the published joint states.', True, _as_str),
    ParamSpec('marker_rate', 30.0,
              'Rate of the body markers on `markers` (visualization_msgs/MarkerArray) [Hz of '
              'simulated time], never more than one per step; recorded too. 0 = off.', True,
              _as_nonneg),
    ParamSpec('marker_frame_id', 'world',
              'header.frame_id of the markers: the fixed frame to set in RViz.', True, _as_frame),
    ParamSpec('marker_joint_axes', False,
              'Also draw each joint axis as an arrow marker (namespace joint_axes).', True,
              _as_bool),
    ParamSpec('live_port', 0,
              'Port of the live view (Foxglove WebSocket; the browser page on the next port; '
              'docs/live.md), 1..65535. 0 = off. Needs foxglove-sdk (requirements-live.txt).',
              True, _as_port),
    ParamSpec('live_host', '127.0.0.1',
              'Address the live view binds. Anything but loopback lets whoever reaches it '
              'watch and pause the run (a warning says so).', True, _as_host),
)

PARAMS_BY_NAME = {p.name: p for p in PARAMS}

SimConfig = make_dataclass('SimConfig', [('scene', str)] + [
    (p.name, type(p.default), field(default_factory=list) if p.default == []
     else field(default=p.default)) for p in PARAMS[1:]],
    namespace={'as_dict': lambda self: {p.name: getattr(self, p.name) for p in PARAMS}})
SimConfig.__module__ = __name__
SimConfig.__doc__ = """Validated parameter values: a field per row of PARAMS (units there)."""


def world_dt(time_step: float) -> Optional[float]:
    """World's ``dt`` argument for the ``time_step`` parameter: 0 means the scene's dt
    (None); the one place that rule is written."""
    return float(time_step) if time_step else None


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


def _names(folder: str, ext: str) -> list[str]:
    try:
        return sorted(f[:-len(ext)] for f in os.listdir(folder) if f.endswith(ext))
    except OSError:
        return []


def packaged_robots_dir() -> str:
    """Directory of the packaged URDF robots (``robots/`` beside ``scenes/``)."""
    return os.path.join(os.path.dirname(packaged_scenes_dir()), 'robots')


def resolve_scene(value: str) -> str:
    """Scene parameter -> file path ('' = default scene, bare name = packaged scene).

    A bare name that is no packaged scene raises SceneError listing them (and the closest
    name): ``scene:=hinj`` is a typo, and "No such file" would not say of what."""
    value = value.strip()
    if not value:
        return default_scene_path()
    if os.sep not in value and not value.endswith(('.yaml', '.yml', '.urdf')):
        robot = os.path.join(packaged_robots_dir(), value + '.urdf')
        scene = os.path.join(packaged_scenes_dir(), value + '.yaml')
        if os.path.isfile(scene):
            return scene
        if os.path.isfile(robot):
            return robot
        import difflib
        from abd_joint_sim.errors import SceneError
        names = _names(packaged_scenes_dir(), '.yaml') + _names(packaged_robots_dir(), '.urdf')
        close = difflib.get_close_matches(value, names, n=1)
        hint = f'did you mean {close[0]!r}? ' if close else ''
        raise SceneError(
            f'parameter \'scene\': {value!r} is no packaged scene ({hint}packaged: '
            f'{", ".join(names) or "none found"}; or give the path of a .yaml or .urdf file)')
    return os.path.abspath(os.path.expanduser(value))


def coerce(name: str, value: Any) -> Any:
    """Validate and normalise one parameter value; raise ValueError naming it."""
    return PARAMS_BY_NAME[name].coerce(name, value)


def config_from_values(values: dict[str, Any], resolve: bool = True) -> SimConfig:
    """Build the config from raw parameter values (missing names take their defaults).

    `resolve`: turn `scene` into a file path (the node); a replay passes False, since its
    scene comes from the bag and the stored value is only a label (a packaged scene's name, a
    file's base name, or `robot_description`)."""
    kwargs = {p.name: p.coerce(p.name, values.get(p.name, p.default)) for p in PARAMS}
    if resolve:
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


# -- parameters given at start that the node does not use ------------------------------
FOREIGN_PARAMETERS = frozenset({'use_sim_time', 'start_type_description_service'})
"""Parameters rclpy itself declares on every node (not ours, not typos)."""


def undeclared_parameters(overrides: Sequence[str]) -> list[str]:
    """Names among the start-up overrides (``-p``, ``--params-file``, launch) that are no
    parameter of the node (typos such as ``real_time_factr``: the node warns)."""
    return sorted(n for n in overrides if n not in PARAMS_BY_NAME
                  and n not in FOREIGN_PARAMETERS and not n.startswith('qos_overrides.'))


def _ros_args(argv: Sequence[str]) -> list[str]:
    """The arguments inside ``--ros-args ... [--]`` sections of a command line."""
    out, inside = [], False
    for arg in argv:
        if arg == '--ros-args':
            inside = True
        elif arg == '--' and inside:
            inside = False
        elif inside:
            out.append(arg)
    return out


def _file_parameters(path: str, node_name: str) -> dict[str, Any]:
    """Parameters a ROS params file gives `node_name` (sections ``node_name``,
    ``/node_name``, ``/**``, ``**``; nested namespaces by their last name)."""
    from abd_joint_sim.scene import read_yaml_file      # bounded: no alias bomb here either
    try:
        _, data = read_yaml_file(path, ValueError, 'params file')
    except (ValueError, RecursionError):
        return {}           # rcl reports an unreadable file itself
    found: dict[str, Any] = {}

    def walk(d, last):
        if not isinstance(d, dict):
            return
        for key, value in d.items():
            if key == 'ros__parameters' and isinstance(value, dict):
                if last.lstrip('/') in (node_name, '**', '*'):
                    found.update(value)
            else:
                walk(value, str(key).rstrip('/').split('/')[-1] or str(key))
    walk(data, '')
    return found


def conflicting_parameter_sources(argv: Sequence[str], node_name: str = NODE_NAME
                                  ) -> dict[str, list[tuple[str, Any]]]:
    """name -> [(source, value), ...] for every parameter the command line gives more than
    once with different values (``-p name:=v`` and ``--params-file`` files, in order).
    Which one rcl puts in effect is read back from the node; this only finds the clash."""
    import yaml
    given: dict[str, list[tuple[str, Any]]] = {}
    args = iter(_ros_args(argv))
    for arg in args:
        operand = next(args, None) if arg in ('-p', '--param', '--params-file') else None
        if operand is not None and arg == '--params-file':
            for name, value in _file_parameters(operand, node_name).items():
                given.setdefault(name, []).append((f'--params-file {operand}', value))
        elif operand is not None:
            name, sep, text = operand.partition(':=')
            node, colon, pname = name.rpartition(':')
            if sep and (not colon or node.lstrip('/') in (node_name, '**', '*')):
                try:
                    value = yaml.safe_load(text)
                except yaml.YAMLError:
                    value = text
                given.setdefault(pname, []).append((f'-p {operand}', value))
    return {n: s for n, s in given.items()
            if len({repr(v if v is not None else '') for _, v in s}) > 1}
