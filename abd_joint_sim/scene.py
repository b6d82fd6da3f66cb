"""Scene: the editable, named description of a mechanism, loaded from YAML and validated.

A `Scene` is what a user writes; `abd_joint_sim.model.compile_scene` turns it into the
immutable arrays the solver uses (MuJoCo's spec/model split). Every validation error is a
`SceneError` whose message reads ``<source>: <field path>: <what is wrong>``.
The format: docs/scene-format.md (test/test_docs_tables.py checks it against this parser).
"""
from __future__ import annotations

import dataclasses
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from . import urdf
from .errors import SceneError
from .ranges import RANGES

INTEGRATORS = ('bdf1', 'bdf2')


_DUMPER = getattr(yaml, 'CSafeDumper', yaml.SafeDumper)     # safe_dump's, libyaml's if present
MAX_YAML_BYTES = 8 << 20
"""Largest scene file read [bytes] (the packaged scenes are ~2 KB; a generated scene of
20 000 bodies and joints ~7 MB). Schedules pass their own bound (tools/schedule.py)."""
MAX_YAML_NODES = 100_000
ALIAS_EXPANSION = 10
"""A document may hold at most max(MAX_YAML_NODES, ALIAS_EXPANSION x its own nodes) values
once every alias is expanded: reuse through aliases is fine, a billion-laughs file (~1 KB
of text, ~100 nodes, 1e9 or more expanded) is refused before anything walks it."""
MAX_YAML_DEPTH = 64                 # deepest nesting of lists/mappings (a scene needs 4-5)


class SceneText:
    """A scene's YAML text, written from its data (the scene's own copy) the first time it is
    asked for: docs/decisions.md says why."""

    __slots__ = ('_data', '_text')

    def __init__(self, data):
        self._data, self._text = data, None

    @property
    def written(self) -> bool:
        return self._text is not None

    @property
    def text(self) -> str:
        if self._text is None:
            self._text = yaml.dump(self._data, Dumper=_DUMPER, sort_keys=False)
            self._data = None
        return self._text

    def __eq__(self, other):
        other = other.text if isinstance(other, SceneText) else other
        return self.text == other if isinstance(other, str) else NotImplemented

    def __hash__(self):
        return hash(self.text)


class YAMLLimitError(yaml.YAMLError):
    """A YAML document too large once aliases are expanded, nested deeper than
    MAX_YAML_DEPTH, or with a recursive alias."""

    def __init__(self, problem: str, mark=None):
        super().__init__(problem)
        self.problem, self.problem_mark = problem, mark


class _Loader(yaml.SafeLoader):
    """SafeLoader with YAML 1.2 core-schema scalars (decimal numbers, booleans true/false
    only) and bounded documents: a duplicate key, nesting deeper than MAX_YAML_DEPTH, more
    values with aliases expanded than `_expanded_size` allows and an alias inside its own
    anchor are errors, raised before the data is constructed (docs/robustness.md §6)."""

    yaml_implicit_resolvers: dict = {}

    def __init__(self, stream):
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent, index):
        self._depth += 1
        try:
            if self._depth > MAX_YAML_DEPTH:
                raise YAMLLimitError(f'nested deeper than {MAX_YAML_DEPTH} levels',
                                     self.peek_event().start_mark)
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def get_single_node(self):
        node = super().get_single_node()
        if node is not None:
            _expanded_size(node)
        return node

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen = {}
            for key_node, _ in node.value:
                if key_node.tag == 'tag:yaml.org,2002:merge' or \
                        not isinstance(key_node, yaml.ScalarNode):
                    continue
                key = self.construct_object(key_node)
                if key in seen:
                    raise yaml.constructor.ConstructorError(
                        None, None, f'duplicate key {key!r} (first at line '
                        f'{seen[key].line + 1}); each key may appear once',
                        key_node.start_mark)
                seen[key] = key_node.start_mark
        return super().construct_mapping(node, deep=deep)


def _expanded_size(root) -> None:
    """YAMLLimitError if the document, every alias expanded (memoised over the shared nodes),
    holds more nodes than ALIAS_EXPANSION allows, or if a node contains itself."""
    sizes: dict[int, tuple] = {}            # id -> (expanded size, node), in post-order
    active: set[int] = set()
    stack = [(root, False)]                 # iterative: keep Python's stack out
    while stack:
        node, done = stack.pop()
        key = id(node)
        children = []
        if isinstance(node, yaml.SequenceNode):
            children = node.value
        elif isinstance(node, yaml.MappingNode):
            children = [n for pair in node.value for n in pair]
        if done:
            active.discard(key)
            sizes[key] = (1 + sum(sizes[id(c)][0] for c in children), node)
        elif key not in sizes:
            if key in active:
                raise YAMLLimitError('an alias (*name) refers to a node that contains it',
                                     node.start_mark)
            active.add(key)
            stack.append((node, True))
            stack.extend((c, False) for c in children if id(c) not in sizes)
    limit = max(MAX_YAML_NODES, ALIAS_EXPANSION * len(sizes))
    for size, node in sizes.values():
        if size > limit:
            raise YAMLLimitError(
                f'more than {limit} values once aliases (*name) are expanded, from '
                f'{len(sizes)} in the text (an alias bomb?)', node.start_mark)


for _tag, _regexp, _first in (
        ('tag:yaml.org,2002:null', r'^(?:~|null|Null|NULL|)$', ['~', 'n', 'N', '']),
        ('tag:yaml.org,2002:bool', r'^(?:true|True|TRUE|false|False|FALSE)$', list('tTfF')),
        ('tag:yaml.org,2002:int', r'^[-+]?[0-9]+$', list('-+0123456789')),
        ('tag:yaml.org,2002:float',
         r'''^(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?
         |[-+]?\.(?:inf|Inf|INF)
         |\.(?:nan|NaN|NAN))$''', list('-+0123456789.')),
        ('tag:yaml.org,2002:merge', r'^(?:<<)$', ['<']),
):
    _Loader.add_implicit_resolver(_tag, re.compile(_regexp, re.X), _first)
# Decimal, as YAML 1.2 (PyYAML's constructor reads a leading 0 as octal: 010 -> 8).
_Loader.add_constructor('tag:yaml.org,2002:int',
                        lambda loader, node: int(loader.construct_scalar(node), 10))


def load_yaml(text: str):
    """Parse YAML text the way scene files are parsed (see `_Loader`)."""
    return yaml.load(text, Loader=_Loader)


def read_yaml_file(path, error: type[Exception], what: str, max_bytes: int = MAX_YAML_BYTES):
    """(text, data) of a YAML file; unreadable, too large, not UTF-8 or invalid YAML
    (including `_Loader`'s limits) raises `error` with a one-line message naming the file
    (and the line and column where that is known)."""
    path = Path(path)
    try:
        with open(path, 'rb') as f:
            # Ask for no more than the file holds: read(n) allocates n bytes up front.
            size = os.fstat(f.fileno()).st_size
            raw = f.read((min(size, max_bytes) if size else max_bytes) + 1)
    except OSError as exc:
        raise error(f'{path}: cannot read {what}: {exc.strerror or exc}') from None
    if len(raw) > max_bytes:
        raise error(f'{path}: {what} larger than {max_bytes} bytes; not read')
    try:
        text = raw.decode('utf-8')
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b'\n') + 1
        raise error(f'{path}: {what} is not UTF-8 text (byte 0x{raw[exc.start]:02x} at '
                    f'offset {exc.start}, line {line})') from None
    try:
        return text, load_yaml(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, 'problem_mark', None)
        where = f' (line {mark.line + 1}, column {mark.column + 1})' if mark else ''
        problem = getattr(exc, 'problem', None) or str(exc)
        raise error(f'{path}: not valid YAML{where}: {problem}') from None
    except ValueError as exc:     # e.g. an integer of more than 4300 digits
        raise error(f'{path}: not valid YAML: {exc}') from None


MAX_ABS_AIM = RANGES['angle'][1]
"""[rad] Largest |aim angle| of a drive, in a scene and at run time (World.set_drive, the
node's joint_commands): beyond it the drive's (θ − aim)² loses θ to rounding (an aim of 1e300
held the joint still)."""

MAX_SUBSTEP_DEPTH = 10      # a failed step is retried as up to 2**depth sub-steps (1024 here)

MAX_ITERATIONS = 10_000


@dataclass(frozen=True)
class NewtonSpec:
    velocity_tol: float = 0.05      # m/s: points of every body move < velocity_tol*h per iteration
    transrate_tol: float = 0.1      # 1/s: max |dq[3:12]| <= transrate_tol*h
    max_iterations: int = 64
    line_search_max: int = 32       # halvings of the step before giving up
    max_substep_depth: int = 4      # a failed step is retried as 2, 4, ... 2**depth sub-steps
    max_step_rotation: float = 0.5 * math.pi  # rad per (sub-)step; above it the step is split


@dataclass(frozen=True)
class ShapeSpec:
    kind: str                       # 'box' | 'sphere' | 'cylinder' | 'inertial'
    size: tuple = ()                # box: (a, b, c); sphere: (R,); cylinder: (radius, length)
    mass: float = 0.0               # inertial only
    com: tuple = (0.0, 0.0, 0.0)    # inertial only, in the body frame
    inertia: tuple = ()             # inertial only: 3x3 about the COM, row-major (9,)
    volume: float = 0.0             # inertial only (0 = mass / 1000 kg/m^3)


@dataclass(frozen=True)
class VisualSpec:
    """What a body looks like (markers, pictures; no effect on the physics), posed in the body's
    frame (of `BodySpec.position`/`rpy`; a URDF robot's link frame) as a ``<visual><origin>``."""

    kind: str                               # 'box' | 'sphere' | 'cylinder' | 'mesh'
    size: tuple = ()                        # box: (a, b, c); sphere: (R,); cylinder: (radius, length); mesh: scale (sx, sy, sz)
    mesh_uri: str = ''                      # mesh only: e.g. package://pkg/meshes/link.stl
    origin_xyz: tuple = (0.0, 0.0, 0.0)     # [m] in the body frame
    origin_rpy: tuple = (0.0, 0.0, 0.0)     # [rad] URDF convention
    rgba: tuple | None = None               # colour, None = the viewer's default


@dataclass(frozen=True)
class BodySpec:
    name: str
    shape: ShapeSpec
    density: float
    kappa: float
    position: tuple
    rpy: tuple
    fixed: bool
    velocity: tuple
    angular_velocity: tuple
    visuals: tuple = ()                     # VisualSpec, ...; () = draw the shape (or a fallback)


@dataclass(frozen=True)
class TorqueSpec:
    torque: float = 0.0
    enabled: bool = False
    effort_limit: float = math.inf


@dataclass(frozen=True)
class ForceSpec:
    """UID 667, the external force along a prismatic joint's axis [N]."""

    force: float = 0.0
    enabled: bool = False
    effort_limit: float = math.inf


@dataclass(frozen=True)
class DrivingSpec:
    strength_ratio: float = 100.0
    aim_angle: float = 0.0                  # [rad] UID 19 (revolute)
    passive: bool = False
    enabled: bool = False
    aim_distance: float = 0.0               # [m] UID 21 (prismatic)


@dataclass(frozen=True)
class LimitSpec:
    lower: float
    upper: float
    strength: float = 1.0


REVOLUTE, PRISMATIC = 'revolute', 'prismatic'
JOINT_TYPES = (REVOLUTE, PRISMATIC)
#: the unit of a joint's position (angle, distance) and of its effort, per joint type
POSITION_UNIT = {REVOLUTE: 'rad', PRISMATIC: 'm'}
EFFORT_UNIT = {REVOLUTE: 'N m', PRISMATIC: 'N'}


@dataclass(frozen=True)
class JointSpec:
    name: str
    parent: str
    child: str
    p0: tuple
    p1: tuple
    strength_ratio: float = 100.0
    init_angle: float = 0.0
    external_torque: TorqueSpec | None = None
    driving: DrivingSpec | None = None
    limit: LimitSpec | None = None          # [rad] revolute, [m] prismatic
    damping: float = 0.0                    # viscous joint damping [N m s/rad] or [N s/m]; 0 = none
    type: str = REVOLUTE                    # REVOLUTE (UID 18) or PRISMATIC (UID 20)
    init_distance: float = 0.0              # [m] prismatic: the reported distance at creation
    external_force: ForceSpec | None = None  # UID 667 (prismatic)

    @property
    def init_position(self) -> float:
        """init_angle [rad] of a revolute joint, init_distance [m] of a prismatic one."""
        return self.init_distance if self.type == PRISMATIC else self.init_angle


@dataclass(frozen=True)
class Scene:
    """A validated scene. Build with `Scene.from_yaml` or `Scene.from_dict`."""

    dt: float
    gravity: tuple
    integrator: str
    newton: NewtonSpec
    bodies: tuple
    joints: tuple
    name: str = ''
    source: str = '<dict>'
    _text: Any = field(default='', repr=False)   # str, or SceneText (written when asked)
    robot_description: str = field(default='', repr=False)  # URDF XML of a robot scene
    warnings: tuple = field(default=(), repr=False)          # URDF quirks repaired on load

    @classmethod
    def from_urdf(cls, source, **options) -> 'Scene':
        """A robot scene from a URDF path or URDF XML text; `options`: urdf.ROBOT_OPTIONS and
        urdf.SCENE_OPTIONS (docs/urdf.md). Repairs are warned as `urdf.UrdfWarning` and
        listed in `Scene.warnings`."""
        data, name, text, notes = urdf.scene_data_from_urdf(source, options)
        return _with_robot(cls.from_dict(data, source=name), text, notes)

    @classmethod
    def from_file(cls, path: str | Path) -> 'Scene':
        """`from_urdf` for a .urdf file, else `from_yaml`."""
        if str(path).lower().endswith('.urdf'):
            return cls.from_urdf(str(path))
        return cls.from_yaml(path)

    @classmethod
    def from_yaml(cls, path: str | Path) -> 'Scene':
        text, data = read_yaml_file(path, SceneError, 'scene file')
        return cls.from_dict(data, source=str(path), source_text=text)

    @classmethod
    def from_dict(cls, data: Any, *, source: str = '<dict>', source_text: str | None = None) -> 'Scene':
        data = _plain(data)
        if source_text is None:
            source_text = SceneText(data) if isinstance(data, dict) else ''
        return _Parser(source).scene(data, source_text)

    def to_dict(self) -> dict:
        """The scene as plain data (what `from_dict` accepts; a robot scene's is the lowered
        scene, complete without the URDF file)."""
        return load_yaml(self.source_text) if self.source_text else {}

    @property
    def source_text(self) -> str:
        """The scene as YAML: the file's own text, else the data written as YAML (a robot
        scene: the lowered scene), written the first time it is asked for."""
        return self._text if isinstance(self._text, str) else self._text.text

    @property
    def body_names(self) -> tuple:
        return tuple(b.name for b in self.bodies)

    @property
    def joint_names(self) -> tuple:
        return tuple(j.name for j in self.joints)


def check_dt(value, source: str = 'dt') -> float:
    """A step size given outside a scene (World's `dt` argument) checked as a scene's `dt` is:
    a finite number in the supported range, else SceneError naming `source` and the value."""
    if getattr(value, 'shape', None) == () and hasattr(value, 'item'):
        value = value.item()                # a numpy scalar: its Python number
    return _Parser(source).number('', value, positive=True, bound='dt')


def _with_robot(scene: 'Scene', urdf_text: str, notes) -> 'Scene':
    return dataclasses.replace(scene, robot_description=urdf_text, warnings=tuple(notes))


def _plain(data):
    """Plain Python containers and scalars (numpy scalars and arrays converted)."""
    if isinstance(data, dict):
        return {k: _plain(v) for k, v in data.items()}
    if isinstance(data, (list, tuple)):
        return [_plain(v) for v in data]
    if hasattr(data, 'tolist') and not isinstance(data, (str, bytes)):   # numpy scalar/array
        return _plain(data.tolist())
    return data


class _Parser:
    """Validates plain data field by field; `where` is the dotted path of the current field."""

    def __init__(self, source: str):
        self.source = source

    def fail(self, where: str, msg: str):
        raise SceneError(f'{self.source}: {where}: {msg}' if where else f'{self.source}: {msg}')

    # -- primitives ---------------------------------------------------------------------
    def mapping(self, where, value, allowed, required=()):
        if not isinstance(value, dict):
            self.fail(where, f'must be a mapping, got {type(value).__name__}')
        unknown = [k for k in value if k not in allowed]
        if unknown:
            self.fail(where, f'unknown key(s) {", ".join(map(repr, unknown))}; '
                             f'allowed: {", ".join(allowed)}')
        for key in required:
            if key not in value:
                self.fail(where, f'missing required key {key!r}')
        return value

    def number(self, where, value, *, positive=False, nonneg=False, bound=None):
        """A finite float; `bound` names a row of RANGES (the sane magnitude range)."""
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(where, f'must be a number, got {value!r}')
        try:
            value = float(value)
        except OverflowError:
            self.fail(where, f'must be finite, got an integer of {len(str(abs(value)))} digits')
        if not math.isfinite(value):
            self.fail(where, f'must be finite, got {value!r}')
        if positive and value <= 0.0:
            self.fail(where, f'must be > 0, got {value!r}')
        if nonneg and value < 0.0:
            self.fail(where, f'must be >= 0, got {value!r}')
        if bound is not None:
            lo, hi, unit = RANGES[bound]
            unit = f' {unit}' if unit else ''
            if positive and not lo <= value <= hi:
                self.fail(where, f'{value!r} is outside the supported range '
                                 f'{lo:g} to {hi:g}{unit}')
            if not positive and abs(value) > hi:
                self.fail(where, f'{value!r} is outside the supported range: '
                                 f'|value| <= {hi:g}{unit}')
        return value

    def integer(self, where, value, minimum, maximum=None):
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(where, f'must be an integer, got {value!r}')
        if value < minimum:
            self.fail(where, f'must be >= {minimum}, got {value!r}')
        if maximum is not None and value > maximum:
            self.fail(where, f'must be <= {maximum}, got {value!r}')
        return value

    def boolean(self, where, value):
        if not isinstance(value, bool):
            self.fail(where, f'must be true or false, got {value!r}')
        return value

    def vector(self, where, value, n=3, **kw):
        if not isinstance(value, (list, tuple)) or len(value) != n:
            self.fail(where, f'must be a list of {n} numbers, got {value!r}')
        return tuple(self.number(f'{where}[{i}]', v, **kw) for i, v in enumerate(value))

    def name(self, where, value):
        if not isinstance(value, str) or not value.strip():
            self.fail(where, f'must be a non-empty string, got {value!r}')
        return value

    # -- sections -----------------------------------------------------------------------
    def scene(self, data, source_text):
        if data is None:
            self.fail('', 'empty scene')
        robot = None
        if isinstance(data, dict) and 'robot' in data:
            data, robot = self.robot(data)
        d = self.mapping('', data, ('name', 'description', 'dt', 'gravity', 'integrator',
                                    'newton', 'bodies', 'joints'), required=('dt', 'bodies'))
        dt = self.number('dt', d['dt'], positive=True, bound='dt')
        gravity = self.vector('gravity', d.get('gravity', [0.0, 0.0, 0.0]), bound='gravity')
        integrator = d.get('integrator', 'bdf1')
        if integrator not in INTEGRATORS:
            self.fail('integrator', f'must be one of {", ".join(INTEGRATORS)}, got {integrator!r}')
        newton = self.newton(d.get('newton', {}))
        raw_bodies = d['bodies']
        if not isinstance(raw_bodies, list) or not raw_bodies:
            self.fail('bodies', 'must be a non-empty list')
        bodies = tuple(self.body(f'bodies[{k}]', b) for k, b in enumerate(raw_bodies))
        self.unique('bodies', [b.name for b in bodies])
        raw_joints = d.get('joints', []) or []
        if not isinstance(raw_joints, list):
            self.fail('joints', 'must be a list')
        names = {b.name for b in bodies}
        joints = tuple(self.joint(f'joints[{k}]', j, names) for k, j in enumerate(raw_joints))
        self.unique('joints', [j.name for j in joints])
        name = d.get('name', '')
        if not isinstance(name, str):
            self.fail('name', f'must be a string, got {name!r}')
        urdf_text, notes = robot or (None, ())
        return Scene(dt=dt, gravity=gravity, integrator=integrator, newton=newton, bodies=bodies,
                     joints=joints, name=name, source=self.source, warnings=tuple(notes),
                     robot_description=urdf_text or '',   # a robot's _text: the lowered scene
                     _text=source_text if urdf_text is None else SceneText(data))

    def robot(self, data):
        """A `robot:` block (docs/urdf.md): the URDF lowered to bodies and joints, merged
        with the scene's dt/gravity/integrator/newton (defaults as Scene.from_urdf)."""
        if 'bodies' in data or 'joints' in data:
            self.fail('robot', 'a scene with a robot: block takes its bodies and joints from '
                               'the URDF; remove bodies:/joints:')
        block = self.mapping('robot', data['robot'], ('urdf',) + urdf.ROBOT_OPTIONS, ('urdf',))
        options = {k: v for k, v in block.items() if k != 'urdf'}
        ref = block['urdf']
        if not isinstance(ref, str) or not ref.strip():
            self.fail('robot.urdf', f'must be a path (or package://pkg/path), got {ref!r}')
        base = (os.path.dirname(os.path.abspath(self.source))
                if self.source and not self.source.startswith('<') else os.getcwd())
        try:
            path = urdf.resolve_package_uri(ref, base)
            text, name = urdf.read_urdf_source(path)
            lowered, notes = urdf.robot_scene_dict(text, name, options)
        except SceneError as exc:
            raise SceneError(f'{self.source}: robot: {exc}') from None
        out = {k: v for k, v in data.items() if k != 'robot'}
        out.setdefault('dt', urdf.DEFAULT_DT)
        out.setdefault('gravity', list(urdf.DEFAULT_GRAVITY))
        if not out.get('name'):
            out['name'] = lowered['name']
        out['bodies'], out['joints'] = lowered['bodies'], lowered['joints']
        return out, (text, notes)

    def unique(self, where, names):
        seen = set()
        for k, n in enumerate(names):
            if n in seen:
                self.fail(f'{where}[{k}].name', f'duplicate name {n!r}')
            seen.add(n)

    def newton(self, value):
        d = self.mapping('newton', value, tuple(NewtonSpec.__dataclass_fields__))
        kw = {}
        for key in ('velocity_tol', 'transrate_tol', 'max_step_rotation'):
            if key in d:
                kw[key] = self.number(f'newton.{key}', d[key], positive=True,
                                      bound=None if key == 'max_step_rotation' else 'tolerance')
        for key, minimum, maximum in (('max_iterations', 1, MAX_ITERATIONS),
                                      ('line_search_max', 1, 64),
                                      ('max_substep_depth', 0, MAX_SUBSTEP_DEPTH)):
            if key in d:
                kw[key] = self.integer(f'newton.{key}', d[key], minimum, maximum)
        spec = NewtonSpec(**kw)
        if spec.max_step_rotation >= math.pi:
            self.fail('newton.max_step_rotation', 'must be < pi: the multi-turn angle is only '
                                                  f'exact below pi per step, got {spec.max_step_rotation}')
        return spec

    def body(self, where, value):
        d = self.mapping(where, value, ('name', 'box', 'sphere', 'cylinder', 'inertial', 'density',
                                        'kappa', 'position', 'rpy', 'fixed', 'velocity',
                                        'angular_velocity', 'visuals'), required=('name',))
        name = self.name(f'{where}.name', d['name'])
        shapes = [k for k in ('box', 'sphere', 'cylinder', 'inertial') if k in d]
        if len(shapes) != 1:
            self.fail(where, f'body {name!r} needs exactly one of box, sphere, cylinder, inertial'
                             f' (got {shapes or "none"})')
        kind = shapes[0]
        w = f'{where}.{kind}'
        if kind != 'inertial' and 'density' not in d:
            self.fail(where, f'body {name!r} with a {kind} needs a density (kg/m^3)')
        shape = self.inertial(w, d[kind]) if kind == 'inertial' else None
        density = (self.number(f'{where}.density', d['density'], positive=True, bound='density')
                   if 'density' in d else 0.0)
        if kind == 'box':
            shape = ShapeSpec('box', self.vector(w, d[kind], positive=True, bound='length'))
        elif kind == 'sphere':
            r = (self.mapping(w, d[kind], ('radius',), ('radius',))['radius']
                 if isinstance(d[kind], dict) else d[kind])
            shape = ShapeSpec('sphere', (self.number(w, r, positive=True, bound='length'),))
        elif kind == 'cylinder':
            c = self.mapping(w, d[kind], ('radius', 'length'), ('radius', 'length'))
            shape = ShapeSpec('cylinder', (
                self.number(f'{w}.radius', c['radius'], positive=True, bound='length'),
                self.number(f'{w}.length', c['length'], positive=True, bound='length')))
        elif density and shape.volume == 0.0:           # inertial
            shape = dataclasses.replace(shape, volume=shape.mass / density)
        return BodySpec(
            name=name, shape=shape, density=density,
            kappa=self.number(f'{where}.kappa', d.get('kappa', 1.0e8), positive=True, bound='kappa'),
            position=self.vector(f'{where}.position', d.get('position', [0, 0, 0]), bound='position'),
            rpy=self.vector(f'{where}.rpy', d.get('rpy', [0, 0, 0]), bound='angle'),
            fixed=self.boolean(f'{where}.fixed', d.get('fixed', False)),
            velocity=self.vector(f'{where}.velocity', d.get('velocity', [0, 0, 0]), bound='speed'),
            angular_velocity=self.vector(f'{where}.angular_velocity',
                                         d.get('angular_velocity', [0, 0, 0]), bound='angular_speed'),
            visuals=self.visuals(f'{where}.visuals', d.get('visuals') or []))

    def visuals(self, where, value):
        """`visuals:` list of a body: VisualSpec fields (how it looks; no physics)."""
        if not isinstance(value, list):
            self.fail(where, f'must be a list, got {value!r}')
        out = []
        sizes = {'box': 3, 'sphere': 1, 'cylinder': 2, 'mesh': 3}
        for k, v in enumerate(value):
            w = f'{where}[{k}]'
            v = self.mapping(w, v, tuple(VisualSpec.__dataclass_fields__), ('kind',))
            kind = v['kind']
            if not isinstance(kind, str) or kind not in sizes:
                self.fail(f'{w}.kind', f'must be one of {", ".join(sizes)}, got {kind!r}')
            size = self.vector(f'{w}.size', v.get('size', [1.0, 1.0, 1.0] if kind == 'mesh'
                                                   else None), sizes[kind])
            uri = v.get('mesh_uri', '')
            if not isinstance(uri, str):
                self.fail(f'{w}.mesh_uri', f'must be a string, got {uri!r}')
            out.append(VisualSpec(
                kind=kind, size=size, mesh_uri=uri,
                origin_xyz=self.vector(f'{w}.origin_xyz', v.get('origin_xyz', [0, 0, 0])),
                origin_rpy=self.vector(f'{w}.origin_rpy', v.get('origin_rpy', [0, 0, 0])),
                rgba=None if v.get('rgba') is None else self.vector(f'{w}.rgba', v['rgba'], 4)))
        return tuple(out)

    def inertial(self, where, value):
        d = self.mapping(where, value, ('mass', 'com', 'inertia', 'volume'), ('mass', 'inertia'))
        mass = self.number(f'{where}.mass', d['mass'], positive=True, bound='mass')
        com = self.vector(f'{where}.com', d.get('com', [0, 0, 0]), bound='position')
        raw = d['inertia']
        if isinstance(raw, dict):
            i = self.mapping(f'{where}.inertia', raw, ('ixx', 'ixy', 'ixz', 'iyy', 'iyz', 'izz'),
                             ('ixx', 'iyy', 'izz'))
            v = {k: self.number(f'{where}.inertia.{k}', i.get(k, 0.0), bound='inertia') for k in
                 ('ixx', 'ixy', 'ixz', 'iyy', 'iyz', 'izz')}
            inertia = (v['ixx'], v['ixy'], v['ixz'], v['ixy'], v['iyy'], v['iyz'],
                       v['ixz'], v['iyz'], v['izz'])
        elif isinstance(raw, list) and len(raw) == 3 and all(isinstance(r, list) for r in raw):
            inertia = tuple(self.number(f'{where}.inertia[{r}][{c}]', raw[r][c] if len(raw[r]) == 3
                                        else self.fail(f'{where}.inertia[{r}]', 'must have 3 entries'),
                                        bound='inertia')
                            for r in range(3) for c in range(3))
        else:
            self.fail(f'{where}.inertia', 'must be {ixx, ixy, ixz, iyy, iyz, izz} or a 3x3 list, '
                                          f'got {raw!r}')
        m = [inertia[0:3], inertia[3:6], inertia[6:9]]
        if any(abs(m[r][c] - m[c][r]) > 1e-12 * (1 + abs(m[r][c])) for r in range(3) for c in range(3)):
            self.fail(f'{where}.inertia', 'must be symmetric')
        # physical: S = tr(I)/2 - I positive definite (moments > 0, triangle inequality)
        import numpy as np
        eig = np.linalg.eigvalsh(np.array(m))
        if eig[0] <= 0 or eig[0] + eig[1] <= eig[2] * (1 + 1e-12):
            self.fail(f'{where}.inertia', 'is not a physical inertia: principal moments '
                                          f'{eig.round(12).tolist()} must be > 0 and each <= the sum of the other two')
        volume = (self.number(f'{where}.volume', d['volume'], positive=True, bound='volume')
                  if 'volume' in d else 0.0)
        return ShapeSpec('inertial', mass=mass, com=com, inertia=inertia, volume=volume)

    def joint(self, where, value, body_names):
        d = self.mapping(where, value, ('name', 'type', 'parent', 'child', 'p0', 'p1', 'strength_ratio',
                                        'init_angle', 'init_distance', 'external_torque',
                                        'external_force', 'driving', 'limit', 'damping'),
                         required=('name', 'parent', 'child', 'p0', 'p1'))
        name = self.name(f'{where}.name', d['name'])
        jtype = d.get('type', REVOLUTE)
        if jtype not in JOINT_TYPES:
            if 'external_torque' in d:
                self.fail(f'{where}.external_torque', f'joint {name!r} is {jtype!r}: the external '
                          'torque (UID 668) requires a revolute joint (UID 18)')
            self.fail(f'{where}.type', f'unsupported joint type {jtype!r}; one of revolute (UID 18), '
                                       'prismatic (UID 20)')
        sliding = jtype == PRISMATIC
        # the fields of the other joint type, named with the ones to use instead
        wrong = {'init_distance': 'the revolute joint takes init_angle (rad)',
                 'external_force': 'the external force (UID 667) requires a prismatic joint (UID 20); '
                                   'a revolute joint takes external_torque (UID 668, N m)'} \
            if not sliding else {'init_angle': 'the prismatic joint takes init_distance (m)',
                                 'external_torque': 'the external torque (UID 668) requires a revolute '
                                                    'joint (UID 18); a sliding joint takes '
                                                    'external_force (UID 667, N)'}
        for key, why in wrong.items():
            if key in d:
                self.fail(f'{where}.{key}', f'joint {name!r} is {jtype}: {why}')
        for key in ('parent', 'child'):
            if self.name(f'{where}.{key}', d[key]) not in body_names:
                self.fail(f'{where}.{key}', f'unknown body {d[key]!r}; bodies: {", ".join(sorted(body_names))}')
        if d['parent'] == d['child']:
            self.fail(f'{where}.child', f'joint {name!r} connects body {d["child"]!r} to itself')
        p0, p1 = (self.vector(f'{where}.{k}', d[k], bound='position') for k in ('p0', 'p1'))
        if math.dist(p0, p1) < 1e-9:
            self.fail(f'{where}.p1', f'must differ from p0 (the axis is p0 -> p1), both are {list(p0)}')
        unit = POSITION_UNIT[jtype]
        position = 'position' if sliding else 'angle'       # RANGES row of positions and aims
        init_key, aim_key, other = (('init_distance', 'aim_distance', 'aim_angle') if sliding
                                    else ('init_angle', 'aim_angle', 'aim_distance'))
        effort_key, value_key = (('external_force', 'force') if sliding
                                 else ('external_torque', 'torque'))
        effort = driving = limit = None
        if d.get(effort_key) is not None:
            w, u = f'{where}.{effort_key}', ' N' if sliding else ''
            t = self.mapping(w, d[effort_key], (value_key, 'enabled', 'effort_limit'))
            effort = (ForceSpec if sliding else TorqueSpec)(
                self.number(f'{w}.{value_key}', t.get(value_key, 0.0), bound=value_key),
                self.boolean(f'{w}.enabled', t.get('enabled', False)),
                self.number(f'{w}.effort_limit', t['effort_limit'], positive=True,
                            bound='force_limit' if sliding else 'effort_limit')
                if 'effort_limit' in t else math.inf)
            value, top = getattr(effort, value_key), effort.effort_limit
            if abs(value) > top:
                self.fail(f'{w}.{value_key}', f'|{value}|{u} exceeds effort_limit {top}{u}')
        if d.get('driving') is not None:
            w = f'{where}.driving'
            t = self.mapping(w, d['driving'], ('strength_ratio', aim_key, 'passive', 'enabled', other))
            if other in t:
                self.fail(f'{w}.{other}', f'joint {name!r} is {jtype}: its drive takes {aim_key} ({unit})')
            aim = self.number(f'{w}.{aim_key}', t.get(aim_key, 0.0), bound=position)
            driving = DrivingSpec(self.number(f'{w}.strength_ratio', t.get('strength_ratio', 100.0),
                                              positive=True, bound='strength'),
                                  passive=self.boolean(f'{w}.passive', t.get('passive', False)),
                                  enabled=self.boolean(f'{w}.enabled', t.get('enabled', False)),
                                  **{aim_key: aim})
        if d.get('limit') is not None:
            w = f'{where}.limit'
            t = self.mapping(w, d['limit'], ('lower', 'upper', 'strength'), ('lower', 'upper'))
            limit = LimitSpec(self.number(f'{w}.lower', t['lower'], bound=position),
                              self.number(f'{w}.upper', t['upper'], bound=position),
                              self.number(f'{w}.strength', t.get('strength', 1.0), positive=True,
                                          bound='strength'))
            if limit.lower > limit.upper:
                self.fail(f'{w}', f'lower {limit.lower} > upper {limit.upper} ({unit})')
            init = d.get(init_key, 0.0)
            # (a start outside a limit is refused; a zero-width limit is a lock: robustness.md)
            if isinstance(init, (int, float)) and not isinstance(init, bool) and \
                    limit.upper > limit.lower and not limit.lower <= init <= limit.upper:
                self.fail(f'{where}.{init_key}', f'{init!r} {unit} is outside the joint\'s limit '
                                                 f'[{limit.lower:g}, {limit.upper:g}] {unit}; start inside it')
        init_value = self.number(f'{where}.{init_key}', d.get(init_key, 0.0), bound=position)
        damping = self.number(f'{where}.damping', d.get('damping', 0.0), nonneg=True,
                              bound='slide_damping' if sliding else 'damping')
        return JointSpec(name=name, parent=d['parent'], child=d['child'], p0=p0, p1=p1,
                         strength_ratio=self.number(f'{where}.strength_ratio', d.get('strength_ratio', 100.0),
                                                    positive=True, bound='strength'),
                         driving=driving, limit=limit, damping=damping, type=jtype,
                         **{init_key: init_value, effort_key: effort})
