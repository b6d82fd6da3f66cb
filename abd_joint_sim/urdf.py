"""URDF import: a robot description -> a normal :class:`~abd_joint_sim.scene.Scene`.

``Scene.from_urdf(source, **options)`` and a scene YAML's ``robot:`` block end here. The URDF
is read with ``xml.etree.ElementTree``, lowered to plain scene data (link frame = body frame;
fixed and locked joints merge the child into its parent; revolute/continuous -> UID 18,
prismatic -> UID 20, ``<limit>`` -> UID 670/669, ``effort`` -> the UID 668/667 effort limit,
``p0`` = joint origin, ``p1 = p0 + axis``) and validated by the scene parser like any scene.
Repairs are warned as :class:`UrdfWarning`. Every mapping rule and why: docs/urdf.md.
"""
from __future__ import annotations

import math
import os
from pathlib import Path
import re
import stat
import warnings
import xml.etree.ElementTree as ET

import numpy as np

from .errors import SceneError
from .geometry import axis_rotation, matrix_rpy, rpy_matrix
from .ranges import RANGES

DEFAULT_DT = 1e-3                      # s, from_urdf / robot: scenes
DEFAULT_GRAVITY = (0.0, 0.0, -9.81)    # m/s^2: a robot description assumes Earth's gravity
FIXED_ROOT_MASS = 1.0                  # kg given to a massless fixed root (it never moves)
FRAME_MARK_RADIUS = 0.02               # m: the sphere drawn for such a root without visuals
WATER_DENSITY = 1000.0                 # kg/m^3: volume (for kappa) and the sphere repair
#: moments below this fraction of a water-density sphere's of the link's mass are a point
#: mass (_check_inertia): a sphere of that mass would be ~1e9 times denser than water
POINT_MASS_RATIO = 1e-6
#: smallest second moment of a link's mass, as a fraction of its largest (_check_inertia):
#: a plate 1 % as thick as it is wide
FLAT_RATIO = 1e-4

ROBOT_OPTIONS = ('fixed_base', 'initial_positions', 'lock', 'actuated', 'joints', 'kappa',
                 'strength_ratio', 'limits', 'torque_enabled', 'driving', 'damping')
"""URDF options of ``from_urdf`` and of a ``robot:`` block (besides ``urdf``)."""
SCENE_OPTIONS = ('dt', 'gravity', 'integrator', 'newton', 'name')
"""Scene options ``from_urdf`` also takes (in a scene YAML they are top-level keys)."""
JOINT_OVERRIDES = ('strength_ratio', 'external_torque', 'external_force', 'driving', 'limit', 'damping')
OVERRIDE_KEYS = {'external_torque': ('torque', 'enabled', 'effort_limit'),
                 'external_force': ('force', 'enabled', 'effort_limit'),
                 'driving': ('strength_ratio', 'aim_angle', 'aim_distance', 'passive', 'enabled'),
                 'limit': ('lower', 'upper', 'strength')}
MOVABLE = ('revolute', 'continuous', 'prismatic')
TURNING = ('revolute', 'continuous')
LIMITED = ('revolute', 'prismatic')     # the types whose <limit lower upper> is a UID 670/669 limit
MAX_URDF_BYTES = 8 << 20
"""Largest URDF read [bytes], as for scene YAML (scene.MAX_YAML_BYTES): the largest robot
of pybullet_data is 0.2 MB, a generated 2000-link arm ~1 MB."""
MAX_URDF_ELEMENTS = 200_000
"""Most XML elements in a URDF (links, joints, visuals, their children)."""
MAX_ECHO = 120
"""Characters of a value from the file quoted in an error (the rest is counted)."""
MAX_INERTIA = RANGES['mass'][1] * RANGES['length'][1] ** 2
"""Largest moment of inertia read [kg m^2]: the largest mass at the largest length."""


_VISUAL_SIZE = {'box': (('size', 3),), 'sphere': (('radius', 1),),
                'cylinder': (('radius', 1), ('length', 1)), 'mesh': (('scale', 3),)}
"""The attributes (and their counts of numbers) that make a visual's size."""


def _clip(value: str) -> str:
    """`value` for an error line: at most MAX_ECHO characters, the rest counted."""
    value = str(value)
    return value if len(value) <= MAX_ECHO else \
        f'{value[:MAX_ECHO]}... ({len(value) - MAX_ECHO} more characters)'


class UrdfWarning(UserWarning):
    """A URDF quirk that was repaired or ignored (one line naming file and link/joint)."""


# -- reading --------------------------------------------------------------------------
class _Link:
    __slots__ = ('name', 'mass', 'com', 'inertia', 'visuals')

    def __init__(self, name):
        self.name, self.mass = name, 0.0
        self.com = np.zeros(3)          # in the link frame
        self.inertia = np.zeros((3, 3))  # about the COM, in the link frame
        self.visuals = []               # (kind, size, uri, T (4x4) in the link frame, rgba)


class _Joint:
    __slots__ = ('name', 'type', 'parent', 'child', 'origin', 'axis', 'lower', 'upper',
                 'effort', 'velocity', 'mimic', 'damping', 'friction')

    def __init__(self, name, jtype, parent, child, origin, axis):
        self.name, self.type, self.parent, self.child = name, jtype, parent, child
        self.origin, self.axis = origin, axis
        self.lower = self.upper = self.effort = self.velocity = self.mimic = None
        self.damping = self.friction = 0.0     # <dynamics>


class _Reader:
    """Reads the elements the simulation needs; errors name the file and the element."""

    def __init__(self, source: str):
        self.source = source

    def fail(self, msg):
        raise SceneError(f'{self.source}: {msg}')

    def floats(self, elem, attr, n, where, default=None):
        raw = elem.get(attr) if elem is not None else None
        if raw is None:
            if default is None:
                self.fail(f'{where}: missing attribute {attr!r}')
            return np.array(default, dtype=float)
        try:
            vals = [float(v) for v in raw.split()]
        except ValueError:
            self.fail(f'{where}: {attr}={_clip(raw)!r} is not {n} number(s)')
        if len(vals) != n or not all(map(math.isfinite, vals)):
            self.fail(f'{where}: {attr}={_clip(raw)!r} must be {n} finite number(s)')
        return np.array(vals)

    def number(self, elem, attr, where, default=None):
        return float(self.floats(elem, attr, 1, where, None if default is None else [default])[0])

    def origin(self, parent, where):
        o, T = parent.find('origin'), np.eye(4)
        T[:3, 3] = self.floats(o, 'xyz', 3, f'{where} <origin>', [0, 0, 0])
        T[:3, :3] = rpy_matrix(self.floats(o, 'rpy', 3, f'{where} <origin>', [0, 0, 0]))
        return T

    def parse(self, text: str):
        # no DTD; trailing NULs and white space before <?xml?> ignored: docs/urdf.md
        if re.search(r'<!\s*(DOCTYPE|ENTITY)', text):
            self.fail('DOCTYPE/ENTITY declarations are not accepted in a URDF (entity '
                      'expansion is refused); remove the <!DOCTYPE ...> block')
        text = text.rstrip('\x00')
        body = text.lstrip()
        skipped_lines = 0
        if body.startswith('<?xml'):
            skipped_lines = text[:len(text) - len(body)].count('\n')
            text = body
        try:
            root = ET.fromstring(text)
        except ET.ParseError as exc:
            line, col = getattr(exc, 'position', (0, 0))
            line += skipped_lines
            what = str(exc).split(':')[0]
            self.fail(f'line {line}, column {col + 1}: not well-formed XML ({what})')
        if root.tag != 'robot':
            self.fail(f'root element is <{_clip(root.tag)}>, expected <robot>')
        count = sum(1 for _ in root.iter())
        if count > MAX_URDF_ELEMENTS:
            self.fail(f'{count} XML elements, more than the {MAX_URDF_ELEMENTS} a URDF may have')
        # (comments are not in the tree: a `${...}` in a comment is fine)
        for el in root.iter():
            if el.tag.startswith('{') and 'xacro' in el.tag:
                self.fail(f'<{el.tag.split("}")[1]}> is a xacro element: expand the file first '
                          '(xacro robot.urdf.xacro > robot.urdf)')
            for attr, value in el.attrib.items():
                if '${' in value or '$(' in value:
                    who = el.get('name')
                    self.fail(f'<{el.tag}{f" name={who!r}" if who else ""}> {attr}={value!r} is an '
                              'unexpanded xacro/launch substitution: expand the file first '
                              '(xacro robot.urdf.xacro > robot.urdf)')
        materials = {}
        for m in root.findall('material'):
            self.material(m, materials, f'<material name={m.get("name")!r}>')
        links, joints = {}, {}
        for tag, found, read, known in (('link', links, self.link, materials),
                                        ('joint', joints, self.joint, links)):
            for el in root.findall(tag):
                item = read(el, known)
                if item.name in found:
                    self.fail(f'{tag} {item.name!r} defined twice')
                found[item.name] = item
        if not links:
            hint = (' (the file declares the xacro namespace: a macro file, which xacro expands '
                    'into the robot that uses it)' if 'xmlns:xacro' in text else '')
            self.fail('no <link> in the robot' + hint)
        return root.get('name', ''), links, joints

    def material(self, m, materials, where):
        """rgba of a <material>: its <color>, else the named one's; remembered by name."""
        c, name = m.find('color'), m.get('name')
        rgba = (tuple(self.floats(c, 'rgba', 4, f'{where} <color>').tolist()) if c is not None
                else materials.get(name))
        if name and rgba is not None:
            materials[name] = rgba
        return rgba

    def link(self, el, materials):
        name = el.get('name')
        if not name:
            self.fail('a <link> without a name')
        link = _Link(name)
        where = f'link {name!r}'
        inertial = el.find('inertial')
        if inertial is not None:
            mass_el = inertial.find('mass')
            link.mass = self.number(mass_el, 'value', f'{where} <mass>') if mass_el is not None else 0.0
            if link.mass < 0.0:
                self.fail(f'{where}: negative mass {link.mass}')
            if link.mass > RANGES['mass'][1]:
                self.fail(f'{where} <mass>: value="{link.mass:g}" is beyond the supported '
                          f'{RANGES["mass"][1]:g} kg')
            T = self.origin(inertial, f'{where} <inertial>')
            link.com = T[:3, 3]
            i = inertial.find('inertia')
            v = {k: self.number(i, k, f'{where} <inertia>', 0.0)
                 for k in ('ixx', 'ixy', 'ixz', 'iyy', 'iyz', 'izz')}
            for k, x in v.items():
                if abs(x) > MAX_INERTIA:
                    self.fail(f'{where} <inertia>: {k}="{x:g}" is beyond the supported '
                              f'{MAX_INERTIA:g} kg m^2')
            I = np.array([[v['ixx'], v['ixy'], v['ixz']], [v['ixy'], v['iyy'], v['iyz']],
                          [v['ixz'], v['iyz'], v['izz']]])
            link.inertia = T[:3, :3] @ I @ T[:3, :3].T    # inertial frame -> link frame
        for vis in el.findall('visual'):
            geom = vis.find('geometry')
            shape = None if geom is None else next(iter(geom), None)
            if shape is None or shape.tag not in _VISUAL_SIZE:
                continue        # (a capsule etc.: no effect on the physics, nothing to draw)
            kind = shape.tag
            w = f'{where} <visual><{kind}>'
            size = tuple(x for attr, n in _VISUAL_SIZE[kind] for x in self.floats(
                shape, attr, n, w, [1, 1, 1] if kind == 'mesh' else None).tolist())
            uri = shape.get('filename', '') if kind == 'mesh' else ''
            mat = vis.find('material')          # colours as urdfdom: docs/urdf.md
            rgba = None if mat is None else (materials.get(mat.get('name')) or
                                             self.material(mat, materials, f'{where} <material>'))
            link.visuals.append((kind, size, uri, self.origin(vis, f'{where} <visual>'), rgba))
        return link

    def joint(self, el, links):
        name, jtype = el.get('name'), el.get('type')
        if not name:
            self.fail('a <joint> without a name')
        where = f'joint {name!r}'
        if not jtype:
            self.fail(f'{where}: missing type="..."')
        # (other types, e.g. PyBullet's 'spherical', are refused later: `lock` can hold them)
        ends = {}
        for key in ('parent', 'child'):
            e = el.find(key)
            if e is None or not e.get('link'):
                self.fail(f'{where}: missing <{key} link="..."/>')
            if e.get('link') not in links:
                self.fail(f'{where}: {key} link {e.get("link")!r} is not defined')
            ends[key] = e.get('link')
        axis = self.floats(el.find('axis'), 'xyz', 3, f'{where} <axis>', [1, 0, 0])
        j = _Joint(name, jtype, ends['parent'], ends['child'], self.origin(el, where), axis)
        if jtype in MOVABLE:
            n = float(np.linalg.norm(axis))
            if n < 1e-12:
                self.fail(f'{where}: <axis xyz="0 0 0"> has no direction')
            j.axis = axis / n
        lim = el.find('limit')
        if lim is not None:
            j.effort = self.number(lim, 'effort', f'{where} <limit>', 0.0)
            if j.effort < 0.0:
                self.fail(f'{where} <limit>: effort="{j.effort:g}" is negative; effort is the '
                          'largest torque (N m) or force (N) magnitude, >= 0 (0 or absent: no effort limit)')
            j.velocity = self.number(lim, 'velocity', f'{where} <limit>', 0.0)
            if jtype in LIMITED and (lim.get('lower') is not None or lim.get('upper') is not None):
                # neither bound written: no limit (docs/decisions.md); one: the other is 0
                j.lower = self.number(lim, 'lower', f'{where} <limit>', 0.0)
                j.upper = self.number(lim, 'upper', f'{where} <limit>', 0.0)
        if el.find('mimic') is not None:
            j.mimic = el.find('mimic').get('joint', '?')
        dyn = el.find('dynamics')
        if dyn is not None:
            j.damping = self.number(dyn, 'damping', f'{where} <dynamics>', 0.0)
            j.friction = self.number(dyn, 'friction', f'{where} <dynamics>', 0.0)
            if j.damping < 0.0:
                self.fail(f'{where} <dynamics>: damping="{j.damping:g}" is negative (a damper '
                          'that drives the joint); damping is >= 0 [N m s/rad]')
            top = RANGES['damping'][1]
            if j.damping > top:
                self.fail(f'{where} <dynamics>: damping="{j.damping:g}" is beyond the supported '
                          f'{top:g} N m s/rad')
        return j


# -- lowering -------------------------------------------------------------------------
def _check_inertia(source, link) -> tuple[np.ndarray, str]:
    """(inertia about the COM, '' or what was repaired) of a link with mass > 0.

    Physical: principal moments > 0 obeying the triangle inequality (S = ½ tr(I) 1 − I
    positive definite). Zero/negative moments -> a solid sphere of water density with the
    link's mass (I = 2/5 m r²); a broken triangle inequality -> MuJoCo's balanceinertia
    (every principal moment = their mean)."""
    I = 0.5 * (link.inertia + link.inertia.T)
    eig = np.linalg.eigvalsh(I)
    scale = max(float(np.abs(eig).max()), 1e-300)
    r = (3.0 * link.mass / WATER_DENSITY / (4.0 * math.pi)) ** (1.0 / 3.0)
    sphere = 0.4 * link.mass * r * r
    negative = eig[0] <= 1e-12 * scale or eig[0] <= 0.0
    if negative or eig[2] < POINT_MASS_RATIO * sphere:         # (or a point mass)
        why = 'are not all > 0' if negative else (f'are negligible for its mass (under '
                                                  f'{POINT_MASS_RATIO:g} of a water-density '
                                                  'sphere\'s)')
        return sphere * np.eye(3), (f'principal moments {_fmt(eig)} {why}: replaced by a solid '
                                    f'sphere of water density ({sphere:.4g} kg m^2 each)')
    if eig[0] + eig[1] <= eig[2] * (1.0 + 1e-9):
        mean = float(eig.mean())
        return mean * np.eye(3), (f'principal moments {_fmt(eig)} break the triangle '
                                  f'inequality: set to their mean {mean:.4g} kg m^2 '
                                  '(MuJoCo balanceinertia)')
    # a flat body (docs/urdf.md): the smallest S_k = ½ tr(I) − I_k raised to FLAT_RATIO of the max
    s = 0.5 * eig.sum() - eig
    floor = FLAT_RATIO * float(s.max())
    if s.min() < floor:
        s_new = np.maximum(s, floor)
        eig_new = s_new.sum() - s_new
        _, V = np.linalg.eigh(I)
        return (V * eig_new) @ V.T, (f'principal moments {_fmt(eig)} make a flat body (its '
                                     f'second moments {_fmt(s)}: the smallest under '
                                     f'{FLAT_RATIO:g} of the largest, which an affine body '
                                     f'needs): the smallest raised to that, moments now '
                                     f'{_fmt(eig_new)} kg m^2')
    return I, ''


def _few(names):
    """The first 8 of `names` joined, and how many more."""
    return ', '.join(names[:8]) + (f' and {len(names) - 8} more' if len(names) > 8 else '')


def _fmt(v):
    return '[' + ', '.join(f'{x:.4g}' for x in v) + ']'


def _plain_list(v):
    return [float(x) for x in np.asarray(v, dtype=float).ravel()]


class _Options:
    def __init__(self, source, opts, joints):
        self.source = source
        self.keys('', opts, ROBOT_OPTIONS, 'option', ROBOT_OPTIONS + SCENE_OPTIONS)
        for key in ('fixed_base', 'limits', 'damping', 'torque_enabled'):
            value = opts.get(key, True)
            if not isinstance(value, bool):
                self.fail(key, 'must be true (the file\'s <dynamics damping>) or false (none), '
                               f'got {value!r}' if key == 'damping' else
                               f'must be true or false, got {value!r}')
            setattr(self, key, value)
        self.kappa = opts.get('kappa')
        self.strength_ratio = opts.get('strength_ratio')
        self.initial = self.mapping('initial_positions', opts.get('initial_positions') or {})
        for name, value in self.initial.items():
            if not isinstance(name, str):
                self.fail('initial_positions', f'keys must be joint names, got {_clip(repr(name))}')
            self.known(f'initial_positions', name, joints)
            if not _finite_number(value):
                self.fail(f'initial_positions.{name}', f'must be a finite number (rad), got {value!r}')
        self.lock = self.names('lock', opts.get('lock') or [], joints)
        actuated = opts.get('actuated')
        self.actuated = None if actuated is None else self.names('actuated', actuated, joints)
        self.overrides = self.mapping('joints', opts.get('joints') or {})
        for name, over in self.overrides.items():
            self.known('joints', name, joints)       # (a str: a list key is no dict key)
            if not isinstance(over, dict):
                self.fail(f'joints.{name}', f'must be a mapping of {", ".join(JOINT_OVERRIDES)}')
            self.keys(f'joints.{name}', over, JOINT_OVERRIDES)
            for key, allowed in OVERRIDE_KEYS.items():
                sub = over.get(key)
                if isinstance(sub, dict):
                    self.keys(f'joints.{name}.{key}', sub, allowed)
                elif key in over and sub is not None and sub is not False:
                    self.fail(f'joints.{name}.{key}', f'must be a mapping (or false to '
                                                      f'remove it), got {sub!r}')
            for key, sub in over.items():
                if isinstance(sub, dict):
                    for k, x in sub.items():
                        if k not in ('enabled', 'passive') and not _finite_number(x):
                            self.fail(f'joints.{name}.{key}.{k}', f'must be a finite number, '
                                                                  f'got {_clip(repr(x))}')
            if 'strength_ratio' in over:
                self.positive(f'joints.{name}.strength_ratio', over['strength_ratio'])
            if over.get('damping') not in (None, False):
                self.positive(f'joints.{name}.damping', over['damping'], strict=False)
        for key in ('kappa', 'strength_ratio'):
            if opts.get(key) is not None:
                self.positive(key, opts[key])
        self.driving = opts.get('driving')
        if self.driving is not None:
            self.keys('driving', self.mapping('driving', self.driving), OVERRIDE_KEYS['driving'])

    def fail(self, field, msg):
        raise SceneError(f'{self.source}: robot{"." + field if field else ""}: {msg}')

    def positive(self, field, value, strict=True):
        if not _finite_number(value) or value < 0 or strict and value == 0:
            self.fail(field, f'must be a finite number {">" if strict else ">="} 0, got {value!r}')

    def keys(self, field, value, allowed, what='key', listed=None):
        bad = [k for k in value if k not in allowed]
        if bad:
            self.fail(field, f'unknown {what}(s) {", ".join(map(repr, bad))}; allowed: '
                             f'{", ".join(listed or allowed)}')

    def mapping(self, field, value):
        if not isinstance(value, dict):
            self.fail(field, f'must be a mapping, got {value!r}')
        return value

    def known(self, field, name, joints):
        if not isinstance(name, str) or name not in joints:
            self.fail(field, f'unknown joint {_clip(repr(name))}; joints: '
                             f'{_clip(", ".join(joints)) or "none"}')

    def names(self, field, value, joints):
        if isinstance(value, str) or not isinstance(value, (list, tuple)):
            self.fail(field, f'must be a list of joint names, got {_clip(repr(value))}')
        for k, name in enumerate(value):
            if not isinstance(name, str):
                self.fail(f'{field}[{k}]', f'must be a joint name (a string), got '
                                           f'{_clip(repr(name))}')
            self.known(field, name, joints)
        return list(value)


def robot_scene_dict(text: str, source: str, options: dict) -> tuple[dict, list[str]]:
    """(scene data without dt/gravity/integrator/newton, warnings) of a URDF text."""
    robot_name, links, joints = _Reader(source).parse(text)
    opt = _Options(source, options, joints)
    notes: list[str] = []

    def warn(msg):
        notes.append(msg)
        warnings.warn(msg, UrdfWarning, stacklevel=5)   # the caller of from_urdf

    # Tree: one root, every link the child of at most one joint.
    child_of: dict[str, _Joint] = {}
    for j in joints.values():
        if j.child in child_of:
            raise SceneError(f'{source}: link {j.child!r} is the child of two joints '
                             f'({child_of[j.child].name!r}, {j.name!r}); a URDF is a tree')
        child_of[j.child] = j
    roots = [n for n in links if n not in child_of]
    if len(roots) != 1:
        raise SceneError(f'{source}: the links must form one tree; roots (links that are no '
                         f'joint\'s child): {roots or "none (a loop)"}')
    children: dict[str, list[_Joint]] = {n: [] for n in links}
    for j in joints.values():
        children[j.parent].append(j)
    order, stack = [], [roots[0]]       # depth first (no link is reached twice)
    while stack:
        order.append(stack.pop())
        stack.extend(j.child for j in reversed(children[order[-1]]))
    if len(order) != len(links):        # a loop beside the tree: name it
        reached = set(order)
        path = [next(n for n in links if n not in reached)]
        while child_of[path[-1]].parent not in path:
            path.append(child_of[path[-1]].parent)
        loop = path[path.index(child_of[path[-1]].parent):][::-1]
        names = [child_of[n].name for n in loop]
        chain = ' -> '.join(_clip(n) for n in loop + [loop[0]])
        raise SceneError(f'{source}: the joints {", ".join(map(repr, names))} form a loop '
                         f'({chain}) not connected to the root link {roots[0]!r}; a URDF is '
                         'a tree')

    # Which joints stay joints.
    for name in opt.lock:
        if joints[name].type == 'fixed':
            raise SceneError(f'{source}: robot.lock: joint {name!r} is fixed already')
    refused = [(j.name, j.type, j.mimic if j.type in MOVABLE else None)   # in one error
               for j in joints.values() if j.name not in opt.lock and j.type != 'fixed'
               and (j.type not in MOVABLE or j.mimic is not None)]
    if len(refused) == 1:
        name, jtype, mimic = refused[0]
        why = (f'is {jtype}: only revolute, continuous and prismatic joints are simulated' if mimic is None
               else f'({jtype}) mimics joint {mimic!r}: mimic joints are not simulated')
        raise SceneError(f'{source}: joint {name!r} {why}; `lock: [{name}]` holds it rigid '
                         '(the child link is merged into its parent)')
    if refused:
        names = ', '.join(name for name, _, _ in refused)
        what = ', '.join(f'{name!r} ({jtype}' + (f', mimics {mimic!r})' if mimic else ')')
                         for name, jtype, mimic in refused)
        raise SceneError(f'{source}: {len(refused)} joints cannot be simulated (only revolute, '
                         f'continuous and prismatic joints are, and no mimic joints): {what}; '
                         f'`lock: [{names}]` holds them rigid (each child link is merged into '
                         'its parent)')

    def moving(j):
        return j.type in MOVABLE and j.name not in opt.lock

    def effective_limit(j):
        """(lower, upper) of the UID 670 limit the joint will get, or None."""
        lim = ({'lower': j.lower, 'upper': j.upper} if opt.limits and j.type in LIMITED
               and j.lower is not None and j.upper >= j.lower else None)
        over = opt.overrides.get(j.name, {})
        if 'limit' in over:
            lim = None if over['limit'] in (None, False) else {**(lim or {}), **over['limit']}
        return (lim['lower'], lim['upper']) if lim and 'lower' in lim and 'upper' in lim else None

    # a limit beyond the positions a scene takes is "no limit" (lower="-1e+16"): docs/urdf.md
    for j in joints.values():
        unit, bound = ('m', RANGES['position'][1]) if j.type == 'prismatic' else ('rad', RANGES['angle'][1])
        if j.type in LIMITED and j.lower is not None and moving(j) \
                and not max(abs(j.lower), abs(j.upper)) <= bound:
            warn(f'{source}: joint {j.name!r}: limit [{j.lower:g}, {j.upper:g}] {unit} is beyond '
                 f'the supported |position| <= {bound:g} {unit}: taken as no limit'
                 + (' (a continuous joint)' if unit == 'rad' else ''))
            j.lower = j.upper = None

    # lower > upper is no limit, lower == upper holds the joint (docs/decisions.md): said once
    def shown(js):
        return _few([f'{j.name!r} [{j.lower:g}, {j.upper:g}]' for j in js])
    ranged = [j for j in joints.values() if j.type in LIMITED and moving(j) and opt.limits
              and j.lower is not None and 'limit' not in opt.overrides.get(j.name, {})]
    odd = [j for j in ranged if j.upper < j.lower]
    held = [j for j in ranged if j.upper == j.lower]
    if odd:
        warn(f'{source}: <limit> with lower > upper taken as no limit (as PyBullet does) '
             f'on {len(odd)} joint(s): {shown(odd)}; `joints: {{name: {{limit: {{lower: a, '
             'upper: b}}}` sets one, `lock: [name]` holds the joint rigid')
        for j in odd:
            j.lower = j.upper = None
    if held:
        warn(f'{source}: <limit> with lower == upper holds the joint at that position (a '
             f'zero-width limit, as in a YAML scene and in PyBullet) on {len(held)} joint(s): '
             f'{shown(held)}; `joints: {{name: {{limit: false}}}}` frees it, `joints: {{name: '
             '{limit: {lower: a, upper: b}}}` sets a range')

    # Coulomb friction and speed limits are not simulated: said once per file, not dropped.
    for names, what in (
            ([j.name for j in joints.values() if moving(j) and j.friction > 0.0],
             '<dynamics friction> is not simulated (no Coulomb friction term): ignored on {} '
             'joint(s): {} (of <dynamics>, only damping is)'),
            ([j.name for j in joints.values() if moving(j) and j.velocity],
             '<limit velocity> is not enforced (joint speeds are not limited): ignored on {} '
             'joint(s): {} (of <limit>, lower, upper and effort are)')):
        if names:
            warn(f'{source}: ' + what.format(len(names), _few(names)))

    # Initial positions: as given, else 0 or the nearest bound of a limit that excludes 0.
    q_init: dict[str, float] = {}
    for j in joints.values():
        q = float(opt.initial.get(j.name, 0.0))
        lim = effective_limit(j) if moving(j) and j.name not in opt.initial else None
        if lim is not None and not lim[0] <= q <= lim[1]:
            q = min(max(q, lim[0]), lim[1])
            warn(f'{source}: joint {j.name!r}: position 0 is outside its limit '
                 f'[{lim[0]:g}, {lim[1]:g}]: it starts at {q:g} '
                 f'{"m" if j.type == "prismatic" else "rad"} (set initial_positions to choose)')
        q_init[j.name] = q

    # Forward kinematics at the initial positions (world = root link frame).
    world_T: dict[str, np.ndarray] = {roots[0]: np.eye(4)}
    joint_frame: dict[str, np.ndarray] = {}
    for name in order:
        for j in children[name]:
            T = world_T[name] @ j.origin
            joint_frame[j.name], q, M = T, q_init[j.name], np.eye(4)
            if j.type in TURNING:
                M[:3, :3] = axis_rotation(j.axis, q)
            elif j.type == 'prismatic':
                M[:3, 3] = j.axis * q
            world_T[j.child] = T @ M
    for name in opt.initial:
        if joints[name].type == 'fixed':
            raise SceneError(f'{source}: robot.initial_positions.{name}: joint {name!r} is fixed')

    # Groups: a link belongs to the body of its nearest ancestor reached by a moving joint.
    group: dict[str, str] = {}
    members: dict[str, list[str]] = {}
    for name in order:
        j = child_of.get(name)
        group[name] = name if j is None or moving(j) else group[j.parent]
        members.setdefault(group[name], []).append(name)

    # Each link's inertia checked (and repaired, one warning per link) once.
    inertia: dict[str, np.ndarray] = {}
    for name in order:
        if links[name].mass > 0.0:
            inertia[name], what = _check_inertia(source, links[name])
            if what:
                warn(f'{source}: link {name!r}: {what}')

    # Lumped mass properties per body, in the body (= top link) frame.
    def lumped(top):
        T0 = world_T[top]
        R0, p0 = T0[:3, :3], T0[:3, 3]
        parts = []
        for name in members[top]:
            link, T = links[name], world_T[name]
            if link.mass > 0.0:
                R = R0.T @ T[:3, :3]
                c = R0.T @ (T[:3, :3] @ link.com + T[:3, 3] - p0)
                parts.append((link.mass, c, R @ inertia[name] @ R.T))
        m = sum(p[0] for p in parts)
        if m <= 0.0:
            return 0.0, np.zeros(3), np.zeros((3, 3))
        c = sum(p[0] * p[1] for p in parts) / m
        I = np.zeros((3, 3))
        for mk, ck, Ik in parts:
            d = ck - c
            I += Ik + mk * (d @ d * np.eye(3) - np.outer(d, d))
        return m, c, I

    # Massless moving bodies: a leaf is held rigid (locked) with a warning, else an error.
    for top in reversed(list(members)):      # leaves first: a chain of them folds up
        j = child_of.get(top)
        if j is None or lumped(top)[0] > 0.0:
            continue
        below = [k.name for n in members[top] for k in children[n] if moving(k)]
        if below:
            raise SceneError(f'{source}: link {top!r} (joint {j.name!r}) has no mass but moves '
                             f'and carries moving joint(s) {below}: an affine body needs mass; '
                             f'give it an <inertial>, or `lock: [{j.name}]`')
        warn(f'{source}: link {top!r} has no mass (nor anything fixed to it): joint '
             f'{j.name!r} is held rigid (merged into {j.parent!r}), it has no dynamics')
        opt.lock.append(j.name)
        for name in members.pop(top):
            members[group[j.parent]].append(name)
            group[name] = group[j.parent]

    props = {top: lumped(top) for top in members}

    bodies = []
    for top in members:
        m, c, I = props[top]
        T = world_T[top]
        rpy = matrix_rpy(T[:3, :3])
        R0 = rpy_matrix(rpy)            # the frame the scene will use, to round-off
        is_root = top == roots[0]
        invented = m <= 0.0
        if invented:
            if not (is_root and opt.fixed_base):
                raise SceneError(f'{source}: link {top!r} has no mass: a free body needs '
                                 'an <inertial> with mass > 0')
            m, c, I = FIXED_ROOT_MASS, np.zeros(3), FIXED_ROOT_MASS * 1e-2 * np.eye(3)
        body = {'name': top,
                'inertial': {'mass': float(m), 'com': _plain_list(c),
                             'inertia': [_plain_list(r) for r in 0.5 * (I + I.T)],
                             'volume': float(m) / WATER_DENSITY},
                'position': _plain_list(T[:3, 3]), 'rpy': [float(a) for a in rpy]}
        if opt.kappa is not None:
            body['kappa'] = opt.kappa
        if is_root and opt.fixed_base:
            body['fixed'] = True
        visuals = []
        for name in members[top]:
            for kind, size, uri, Tv, rgba in links[name].visuals:
                W = world_T[name] @ Tv
                Rv = R0.T @ W[:3, :3]
                v = {'kind': kind, 'size': list(size),
                     'origin_xyz': _plain_list(R0.T @ (W[:3, 3] - T[:3, 3])),
                     'origin_rpy': [float(a) for a in matrix_rpy(Rv)]}
                if uri:
                    v['mesh_uri'] = uri
                if rgba is not None:
                    v['rgba'] = list(rgba)
                visuals.append(v)
        if not visuals and invented:        # (a made-up inertia: mark the frame, docs/urdf.md)
            visuals.append({'kind': 'sphere', 'size': [FRAME_MARK_RADIUS]})
        if visuals:
            body['visuals'] = visuals
        bodies.append(body)

    movable = [j for j in joints.values() if moving(j)]
    actuated = set(opt.actuated if opt.actuated is not None else [j.name for j in movable])
    checks = [(n, 'actuated', '; only moving {} joints can be actuated')
              for n in opt.actuated or ()]          # (the first wrong one as listed)
    for name, field, tail in checks + [(n, f'joints.{n}', ', not a moving {} joint')
                                       for n in opt.overrides]:
        if not moving(joints[name]):
            raise SceneError(f'{source}: robot.{field}: joint {name!r} is '
                             f'{"locked" if name in opt.lock else joints[name].type}'
                             + tail.format('revolute/continuous/prismatic'))
    scene_joints = []
    for j in movable:
        F, q0 = joint_frame[j.name], q_init[j.name]
        p0, axis = F[:3, 3], F[:3, :3] @ j.axis
        sliding = j.type == 'prismatic'
        aim_key, effort_key, value_key = (('aim_distance', 'external_force', 'force') if sliding
                                          else ('aim_angle', 'external_torque', 'torque'))
        d = {'name': j.name, 'type': 'prismatic' if sliding else 'revolute', 'parent': group[j.parent],
             'child': group[j.child], 'p0': _plain_list(p0), 'p1': _plain_list(p0 + axis),
             'init_distance' if sliding else 'init_angle': q0}
        if opt.strength_ratio is not None:
            d['strength_ratio'] = opt.strength_ratio
        if j.name in actuated:
            et = {value_key: 0.0, 'enabled': opt.torque_enabled}
            if j.effort is not None and j.effort > 0.0:
                et['effort_limit'] = j.effort
            d[effort_key] = et
        if opt.limits and j.type in LIMITED and j.lower is not None and j.upper >= j.lower:
            d['limit'] = {'lower': j.lower, 'upper': j.upper}
        if opt.driving is not None:         # UID 19 / 21 on every moving joint, holding its pose
            d['driving'] = {aim_key: q0, **opt.driving}
        if opt.damping and j.damping > 0.0:     # N m s/rad, or N s/m on a prismatic joint
            d['damping'] = j.damping
        over = opt.overrides.get(j.name, {})
        for key in (k for k in JOINT_OVERRIDES if k in over):
            value = over[key]
            if value is False or value is None:
                d.pop(key, None)
            elif key in ('strength_ratio', 'damping'):
                d[key] = value
            else:                           # a mapping, merged into the one the file gives
                d[key] = {**d.get(key, {aim_key: q0} if key == 'driving' else {}), **value}
        lim = effective_limit(j)        # (a zero-width one holds the joint from anywhere)
        if lim and lim[1] > lim[0] and not lim[0] <= q0 <= lim[1]:
            raise SceneError(f'{source}: robot.initial_positions.{j.name}: {q0:g} '
                             f'{"m" if sliding else "rad"} is outside '
                             f'the joint\'s limit [{lim[0]:g}, {lim[1]:g}]; the limit '
                             f'would throw it back at once (widen it with joints: {{{j.name}: '
                             '{limit: ...}}, or limits: false)')
        scene_joints.append(d)
    data = {'name': robot_name, 'bodies': bodies, 'joints': scene_joints}
    return data, notes


def _decode(raw: bytes, name: str) -> str:
    """URDF bytes as text: the encoding its XML declaration names (UTF-8 by default)."""
    head = re.match(rb'\s*<\?xml[^>]*?encoding\s*=\s*["\']([A-Za-z0-9._-]+)["\']',
                    raw.lstrip(b'\xef\xbb\xbf')[:200])
    encoding = head.group(1).decode('ascii') if head else 'utf-8'
    try:
        text = raw.decode(encoding)
    except LookupError:
        raise SceneError(f'{name}: the XML declaration names the unknown encoding '
                         f'{_clip(encoding)!r}') from None
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b'\n') + 1
        raise SceneError(f'{name}: not {encoding} text (byte 0x{raw[exc.start]:02x} at '
                         f'offset {exc.start}, line {line})') from None
    return text.lstrip('\ufeff')


def read_urdf_source(source) -> tuple[str, str]:
    """(text, name for messages) of a path or of URDF XML text (str or bytes): at most
    MAX_URDF_BYTES, a regular file, text in the encoding the XML declaration names (UTF-8
    by default). XML text is what starts with '<' (after white space and a byte-order
    mark); anything else is a path, even one with a '<' in it."""
    big = f'URDF larger than {MAX_URDF_BYTES} bytes'
    irregular = 'not a regular file; a URDF is read from a file'
    is_bytes = isinstance(source, (bytes, bytearray))
    if is_bytes or isinstance(source, str) and \
            source.lstrip().lstrip('\ufeff').lstrip().startswith('<'):
        name = '<robot_description>'
        if len(source) > MAX_URDF_BYTES:
            raise SceneError(f'{name}: {big}; not read')
        return (_decode(bytes(source), name) if is_bytes else source.lstrip('\ufeff')), name
    path = Path(os.path.expanduser(str(source)))
    name = _clip(str(path))
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):     # before open: a FIFO would block
            raise SceneError(f'{name}: {irregular}')
        with open(path, 'rb') as f:
            st = os.fstat(f.fileno())
            if not stat.S_ISREG(st.st_mode):
                raise SceneError(f'{name}: {irregular}')
            if st.st_size > MAX_URDF_BYTES:
                raise SceneError(f'{name}: {big} ({st.st_size}); not read')
            raw = f.read(MAX_URDF_BYTES + 1)
    except OSError as exc:
        raise SceneError(f'{name}: cannot read URDF: {exc.strerror or exc}') from None
    if len(raw) > MAX_URDF_BYTES:
        raise SceneError(f'{name}: {big}; not read')
    return _decode(raw, str(path)), str(path)


def resolve_package_uri(uri: str, base_dir: str) -> str:
    """A ``robot: {urdf: ...}`` path: ``package://pkg/rel`` through the ament index,
    otherwise relative to the scene file's directory."""
    if uri.startswith('package://'):
        pkg, _, rel = uri[len('package://'):].partition('/')
        try:
            from ament_index_python.packages import get_package_share_directory
            share = get_package_share_directory(pkg)
        except Exception:  # noqa: BLE001 - not found / no ament index
            if pkg != 'abd_joint_sim':
                raise SceneError(f'{_clip(uri)}: package {pkg!r} not found in the ament '
                                 'index') from None
            share = os.path.dirname(os.path.abspath(__file__))
        full = os.path.normpath(os.path.join(share, rel))
        if os.path.commonpath([os.path.normpath(share), full]) != os.path.normpath(share):
            raise SceneError(f'{_clip(uri)}: leads outside the package {pkg!r} (a package:// '
                             'path names a file inside the package)')
        return full
    path = os.path.expanduser(uri)
    return path if os.path.isabs(path) else os.path.join(base_dir, path)


def _finite_number(value) -> bool:
    """An int or float (not a bool), finite as a float (10**400 is not: no OverflowError)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:
        return False


def scene_data_from_urdf(source, options: dict) -> tuple[dict, str, str, list[str]]:
    """(full scene data, source name, URDF text, warnings) for ``Scene.from_urdf``."""
    text, name = read_urdf_source(source)
    options = dict(options)
    scene_opts = {k: options.pop(k) for k in SCENE_OPTIONS if k in options}
    data, notes = robot_scene_dict(text, name, options)
    data['dt'] = scene_opts.pop('dt', DEFAULT_DT)
    gravity = scene_opts.pop('gravity', DEFAULT_GRAVITY)
    # a tuple or an array becomes the scene format's list; anything else goes to its check as it is
    data['gravity'] = list(gravity) if isinstance(gravity, (list, tuple, np.ndarray)) else gravity
    name_opt = scene_opts.pop('name', None)
    if name_opt:
        data['name'] = name_opt
    data.update(scene_opts)
    return data, name, text, notes
