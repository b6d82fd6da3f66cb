"""Scene: the editable, named description of a mechanism, loaded from YAML and validated.

A `Scene` is what a user writes; `abd_joint_sim.model.compile_scene` turns it into the
immutable arrays the solver uses (MuJoCo's spec/model split). Every validation error is a
`SceneError` whose message reads ``<source>: <field path>: <what is wrong>``.
The format is documented in README.md ("Scene format").
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from .errors import SceneError

INTEGRATORS = ('bdf1', 'bdf2')


class _Loader(yaml.SafeLoader):
    """SafeLoader that also reads YAML 1.2 floats such as 1e8 and 1.0e8 (YAML 1.1, and so
    plain PyYAML, would read them as strings)."""


_Loader.add_implicit_resolver(
    'tag:yaml.org,2002:float',
    __import__('re').compile(r'''^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
    |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
    |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
    |[-+]?\.(?:inf|Inf|INF)
    |\.(?:nan|NaN|NAN))$''', __import__('re').X),
    list('-+0123456789.'))


def load_yaml(text: str):
    """Parse YAML text the way scene files are parsed."""
    return yaml.load(text, Loader=_Loader)


def read_yaml_file(path, error: type[Exception], what: str):
    """(text, data) of a YAML file; unreadable or invalid YAML raises `error` with a
    one-line message naming the file (and the line and column of a syntax error)."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise error(f'{path}: cannot read {what}: {exc.strerror or exc}') from None
    try:
        return text, load_yaml(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, 'problem_mark', None)
        where = f' (line {mark.line + 1}, column {mark.column + 1})' if mark else ''
        problem = getattr(exc, 'problem', None) or str(exc)
        raise error(f'{path}: not valid YAML{where}: {problem}') from None


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
    """What a body looks like (markers, pictures); no effect on the physics.

    Pose in the body's frame (the frame of `BodySpec.position`/`rpy`; for a URDF robot the
    link frame), as a URDF ``<visual><origin>``.
    """

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
class DrivingSpec:
    strength_ratio: float = 100.0
    aim_angle: float = 0.0
    passive: bool = False
    enabled: bool = False


@dataclass(frozen=True)
class LimitSpec:
    lower: float
    upper: float
    strength: float = 1.0


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
    limit: LimitSpec | None = None


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
    source_text: str = field(default='', repr=False)
    robot_description: str = field(default='', repr=False)  # URDF XML of a robot scene
    warnings: tuple = field(default=(), repr=False)          # URDF quirks repaired on load

    @classmethod
    def from_urdf(cls, source, **options) -> 'Scene':
        """A robot scene from a URDF path or URDF XML text (docs/urdf.md).

        Options: dt (default 1e-3), gravity (default [0, 0, -9.81]), integrator, newton,
        name, fixed_base, initial_positions {joint: rad}, lock [joints], actuated [joints],
        joints {joint: {strength_ratio, external_torque, driving, limit}}, kappa,
        strength_ratio, limits (bool), torque_enabled (bool), driving {...} (all joints).
        Repairs are warned as `abd_joint_sim.urdf.UrdfWarning` and listed in
        `Scene.warnings`.
        """
        from .urdf import scene_data_from_urdf
        data, name, text, notes = scene_data_from_urdf(source, options)
        scene = cls.from_dict(data, source=name)
        return _with_robot(scene, text, notes)

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
            source_text = yaml.safe_dump(data, sort_keys=False) if isinstance(data, dict) else ''
        return _Parser(source).scene(data, source_text)

    def to_dict(self) -> dict:
        # A robot scene's source_text is the lowered scene (bodies, joints), complete in
        # itself: a bag replays it without the URDF file.
        """The scene as plain data (what `from_dict` accepts)."""
        return load_yaml(self.source_text) if self.source_text else {}

    @property
    def body_names(self) -> tuple:
        return tuple(b.name for b in self.bodies)

    @property
    def joint_names(self) -> tuple:
        return tuple(j.name for j in self.joints)


def _with_robot(scene: 'Scene', urdf_text: str, notes) -> 'Scene':
    import dataclasses
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

    def number(self, where, value, *, positive=False, nonneg=False):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(where, f'must be a number, got {value!r}')
        value = float(value)
        if not math.isfinite(value):
            self.fail(where, f'must be finite, got {value!r}')
        if positive and value <= 0.0:
            self.fail(where, f'must be > 0, got {value!r}')
        if nonneg and value < 0.0:
            self.fail(where, f'must be >= 0, got {value!r}')
        return value

    def integer(self, where, value, minimum):
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(where, f'must be an integer, got {value!r}')
        if value < minimum:
            self.fail(where, f'must be >= {minimum}, got {value!r}')
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
        dt = self.number('dt', d['dt'], positive=True)
        gravity = self.vector('gravity', d.get('gravity', [0.0, 0.0, 0.0]))
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
        if robot is not None:       # the lowered scene: replayable without the URDF
            source_text = yaml.safe_dump(data, sort_keys=False)
        return Scene(dt=dt, gravity=gravity, integrator=integrator, newton=newton,
                     bodies=bodies, joints=joints, name=name, source=self.source,
                     source_text=source_text,
                     robot_description=robot[0] if robot else '',
                     warnings=tuple(robot[1]) if robot else ())

    def robot(self, data):
        """A `robot:` block (docs/urdf.md): the URDF lowered to bodies and joints, merged
        with the scene's dt/gravity/integrator/newton (defaults as Scene.from_urdf)."""
        from . import urdf
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
        defaults = NewtonSpec()
        d = self.mapping('newton', value, tuple(NewtonSpec.__dataclass_fields__))
        kw = {}
        for key in ('velocity_tol', 'transrate_tol', 'max_step_rotation'):
            if key in d:
                kw[key] = self.number(f'newton.{key}', d[key], positive=True)
        for key, minimum in (('max_iterations', 1), ('line_search_max', 1), ('max_substep_depth', 0)):
            if key in d:
                kw[key] = self.integer(f'newton.{key}', d[key], minimum)
        spec = NewtonSpec(**{**defaults.__dict__, **kw})
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
        density = 0.0
        if kind == 'inertial':
            shape = self.inertial(w, d[kind])
            if 'density' in d:
                density = self.number(f'{where}.density', d['density'], positive=True)
                if shape.volume == 0.0:
                    shape = ShapeSpec(**{**shape.__dict__, 'volume': shape.mass / density})
        else:
            if 'density' not in d:
                self.fail(where, f'body {name!r} with a {kind} needs a density (kg/m^3)')
            density = self.number(f'{where}.density', d['density'], positive=True)
            if kind == 'box':
                shape = ShapeSpec('box', self.vector(w, d[kind], positive=True))
            elif kind == 'sphere':
                r = d[kind]
                if isinstance(r, dict):
                    r = self.mapping(w, r, ('radius',), ('radius',))['radius']
                shape = ShapeSpec('sphere', (self.number(w, r, positive=True),))
            else:
                c = self.mapping(w, d[kind], ('radius', 'length'), ('radius', 'length'))
                shape = ShapeSpec('cylinder', (self.number(f'{w}.radius', c['radius'], positive=True),
                                               self.number(f'{w}.length', c['length'], positive=True)))
        return BodySpec(
            name=name, shape=shape, density=density,
            kappa=self.number(f'{where}.kappa', d.get('kappa', 1.0e8), positive=True),
            position=self.vector(f'{where}.position', d.get('position', [0, 0, 0])),
            rpy=self.vector(f'{where}.rpy', d.get('rpy', [0, 0, 0])),
            fixed=self.boolean(f'{where}.fixed', d.get('fixed', False)),
            velocity=self.vector(f'{where}.velocity', d.get('velocity', [0, 0, 0])),
            angular_velocity=self.vector(f'{where}.angular_velocity',
                                         d.get('angular_velocity', [0, 0, 0])),
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
            if kind not in sizes:
                self.fail(f'{w}.kind', f'must be one of {", ".join(sizes)}, got {kind!r}')
            size = self.vector(f'{w}.size', v.get('size', [1.0, 1.0, 1.0] if kind == 'mesh'
                                                   else None), sizes[kind])
            uri = v.get('mesh_uri', '')
            if not isinstance(uri, str):
                self.fail(f'{w}.mesh_uri', f'must be a string, got {uri!r}')
            rgba = v.get('rgba')
            out.append(VisualSpec(kind=kind, size=size, mesh_uri=uri,
                                  origin_xyz=self.vector(f'{w}.origin_xyz', v.get('origin_xyz', [0, 0, 0])),
                                  origin_rpy=self.vector(f'{w}.origin_rpy', v.get('origin_rpy', [0, 0, 0])),
                                  rgba=None if rgba is None else self.vector(f'{w}.rgba', rgba, 4)))
        return tuple(out)

    def inertial(self, where, value):
        d = self.mapping(where, value, ('mass', 'com', 'inertia', 'volume'), ('mass', 'inertia'))
        mass = self.number(f'{where}.mass', d['mass'], positive=True)
        com = self.vector(f'{where}.com', d.get('com', [0, 0, 0]))
        raw = d['inertia']
        if isinstance(raw, dict):
            i = self.mapping(f'{where}.inertia', raw, ('ixx', 'ixy', 'ixz', 'iyy', 'iyz', 'izz'),
                             ('ixx', 'iyy', 'izz'))
            v = {k: self.number(f'{where}.inertia.{k}', i.get(k, 0.0)) for k in
                 ('ixx', 'ixy', 'ixz', 'iyy', 'iyz', 'izz')}
            inertia = (v['ixx'], v['ixy'], v['ixz'], v['ixy'], v['iyy'], v['iyz'],
                       v['ixz'], v['iyz'], v['izz'])
        elif isinstance(raw, list) and len(raw) == 3 and all(isinstance(r, list) for r in raw):
            inertia = tuple(self.number(f'{where}.inertia[{r}][{c}]', raw[r][c] if len(raw[r]) == 3
                                        else self.fail(f'{where}.inertia[{r}]', 'must have 3 entries'))
                            for r in range(3) for c in range(3))
        else:
            self.fail(f'{where}.inertia', 'must be {ixx, ixy, ixz, iyy, iyz, izz} or a 3x3 list, '
                                          f'got {raw!r}')
        m = [inertia[0:3], inertia[3:6], inertia[6:9]]
        if any(abs(m[r][c] - m[c][r]) > 1e-12 * (1 + abs(m[r][c])) for r in range(3) for c in range(3)):
            self.fail(f'{where}.inertia', 'must be symmetric')
        # Physical inertia: S = tr(I)/2 - I (about the COM) must be positive definite,
        # i.e. positive principal moments obeying the triangle inequality.
        import numpy as np
        eig = np.linalg.eigvalsh(np.array(m))
        if eig[0] <= 0 or eig[0] + eig[1] <= eig[2] * (1 + 1e-12):
            self.fail(f'{where}.inertia', 'is not a physical inertia: principal moments '
                                          f'{eig.round(12).tolist()} must be > 0 and each <= the sum of the other two')
        volume = self.number(f'{where}.volume', d['volume'], positive=True) if 'volume' in d else 0.0
        return ShapeSpec('inertial', mass=mass, com=com, inertia=inertia, volume=volume)

    def joint(self, where, value, body_names):
        d = self.mapping(where, value, ('name', 'type', 'parent', 'child', 'p0', 'p1', 'strength_ratio',
                                        'init_angle', 'external_torque', 'driving', 'limit'),
                         required=('name', 'parent', 'child', 'p0', 'p1'))
        name = self.name(f'{where}.name', d['name'])
        jtype = d.get('type', 'revolute')
        if jtype != 'revolute':
            if 'external_torque' in d:
                self.fail(f'{where}.external_torque', f'joint {name!r} is {jtype!r}: the external '
                          'torque (UID 668) requires a revolute joint (UID 18)')
            self.fail(f'{where}.type', f'unsupported joint type {jtype!r}; only revolute (UID 18)')
        for key in ('parent', 'child'):
            if d[key] not in body_names:
                self.fail(f'{where}.{key}', f'unknown body {d[key]!r}; bodies: {", ".join(sorted(body_names))}')
        if d['parent'] == d['child']:
            self.fail(f'{where}.child', f'joint {name!r} connects body {d["child"]!r} to itself')
        p0 = self.vector(f'{where}.p0', d['p0'])
        p1 = self.vector(f'{where}.p1', d['p1'])
        if math.dist(p0, p1) < 1e-9:
            self.fail(f'{where}.p1', f'must differ from p0 (the axis is p0 -> p1), both are {list(p0)}')
        torque = driving = limit = None
        if d.get('external_torque') is not None:
            w = f'{where}.external_torque'
            t = self.mapping(w, d['external_torque'], ('torque', 'enabled', 'effort_limit'))
            torque = TorqueSpec(self.number(f'{w}.torque', t.get('torque', 0.0)),
                                self.boolean(f'{w}.enabled', t.get('enabled', False)),
                                self.number(f'{w}.effort_limit', t['effort_limit'], positive=True)
                                if 'effort_limit' in t else math.inf)
            if abs(torque.torque) > torque.effort_limit:
                self.fail(f'{w}.torque', f'|{torque.torque}| exceeds effort_limit {torque.effort_limit}')
        if d.get('driving') is not None:
            w = f'{where}.driving'
            t = self.mapping(w, d['driving'], ('strength_ratio', 'aim_angle', 'passive', 'enabled'))
            driving = DrivingSpec(self.number(f'{w}.strength_ratio', t.get('strength_ratio', 100.0), positive=True),
                                  self.number(f'{w}.aim_angle', t.get('aim_angle', 0.0)),
                                  self.boolean(f'{w}.passive', t.get('passive', False)),
                                  self.boolean(f'{w}.enabled', t.get('enabled', False)))
        if d.get('limit') is not None:
            w = f'{where}.limit'
            t = self.mapping(w, d['limit'], ('lower', 'upper', 'strength'), ('lower', 'upper'))
            limit = LimitSpec(self.number(f'{w}.lower', t['lower']), self.number(f'{w}.upper', t['upper']),
                              self.number(f'{w}.strength', t.get('strength', 1.0), positive=True))
            if limit.lower > limit.upper:
                self.fail(f'{w}', f'lower {limit.lower} > upper {limit.upper}')
        return JointSpec(name=name, parent=d['parent'], child=d['child'], p0=p0, p1=p1,
                         strength_ratio=self.number(f'{where}.strength_ratio', d.get('strength_ratio', 100.0),
                                                    positive=True),
                         init_angle=self.number(f'{where}.init_angle', d.get('init_angle', 0.0)),
                         external_torque=torque, driving=driving, limit=limit)
