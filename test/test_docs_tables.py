"""The reference pages cannot drift from the code they describe.

* docs/parameters.md against `ros/params.py` PARAMS: names, defaults, live or not;
* docs/topics.md against `ros/topics.py` TOPICS (name, type, reliability, depth, direction,
  recorded) and its services against those `ros/node.py` creates;
* docs/scene-format.md against the scene parser: the keys each section accepts (asked of the
  parser itself, through the "allowed:" list of its unknown-key error) and the defaults of
  the specs it builds; docs/urdf.md "Options" against `urdf.ROBOT_OPTIONS`/`SCENE_OPTIONS`;
* every relative link in README.md and docs/*.md resolves, and none points outside the
  repository.

Each checker returns a list of problems; the tests run it on the real pages (no problem) and
on a doctored copy (a row dropped, a default or flag changed, a link broken), where it must
name what is wrong.
"""
from __future__ import annotations

import copy
import dataclasses
import math
from pathlib import Path
import re

import pytest

from abd_joint_sim import urdf
from abd_joint_sim.errors import SceneError
from abd_joint_sim.ros.params import PARAMS
from abd_joint_sim.ros.topics import BEST_EFFORT, RELIABLE, TOPICS
from abd_joint_sim.scene import (DrivingSpec, JointSpec, LimitSpec, NewtonSpec, Scene,
                                 TorqueSpec, VisualSpec, load_yaml)

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / 'docs'
REQUIRED = '—'


# ------------------------------------------------------------------ markdown tables ----
def section(text: str, heading: str) -> str:
    """The text under `heading` (a line such as '## `newton`') up to the next heading of the
    same or a higher level."""
    level = len(heading) - len(heading.lstrip('#'))
    lines = text.splitlines()
    try:
        start = lines.index(heading)
    except ValueError:
        return ''
    out = []
    for line in lines[start + 1:]:
        m = re.match(r'(#+) ', line)
        if m and len(m.group(1)) <= level:
            break
        out.append(line)
    return '\n'.join(out)


def table(text: str) -> list[list[str]]:
    """Rows (cells stripped) of the first Markdown table in `text`, header and rule left out."""
    rows, started = [], False
    for line in text.splitlines():
        if line.startswith('|'):
            cells = [c.strip() for c in re.split(r'(?<!\\)\|', line.strip())[1:-1]]
            if started and not set(''.join(cells)) <= set('-: '):
                rows.append(cells)
            started = True
        elif started:
            break
    return rows


def code(cell: str) -> str:
    """The text inside a cell's first pair of backticks (the whole cell if none)."""
    m = re.match(r'`([^`]*)`', cell)
    return m.group(1) if m else cell


def same(doc_value, code_value) -> bool:
    if isinstance(code_value, (tuple, list)) and isinstance(doc_value, (tuple, list)):
        return len(doc_value) == len(code_value) and all(
            same(a, b) for a, b in zip(doc_value, code_value))
    if isinstance(code_value, bool) or isinstance(doc_value, bool):
        return doc_value is code_value
    if isinstance(code_value, (int, float)) and isinstance(doc_value, (int, float)):
        return (math.isinf(code_value) and doc_value == code_value) or \
            math.isclose(doc_value, code_value, rel_tol=1e-4, abs_tol=0.0)
    return doc_value == code_value


# ------------------------------------------------------------------------ parameters ----
def parameter_problems(text: str) -> list[str]:
    rows = {code(r[0]): r for r in table(text)}
    problems = []
    for p in PARAMS:
        if p.name not in rows:
            problems.append(f'parameter {p.name!r} missing from the page')
            continue
        r = rows.pop(p.name)
        if not same(load_yaml(code(r[1])), p.default):
            problems.append(f'parameter {p.name!r}: default {r[1]} on the page, {p.default!r} in PARAMS')
        if r[2] != ('no' if p.read_only else 'yes'):
            problems.append(f'parameter {p.name!r}: live {r[2]!r} on the page, read_only={p.read_only}')
    problems += [f'parameter {name!r} on the page is not in PARAMS' for name in rows]
    return problems


def test_parameter_page_matches_params():
    assert parameter_problems((DOCS / 'parameters.md').read_text()) == []


def test_parameter_check_can_fail():
    text = (DOCS / 'parameters.md').read_text()
    dropped = '\n'.join(ln for ln in text.splitlines() if not ln.startswith('| `publish_rate`'))
    assert parameter_problems(dropped) == ["parameter 'publish_rate' missing from the page"]
    wrong = text.replace('| `marker_rate` | `30.0` |', '| `marker_rate` | `20.0` |')
    assert any("'marker_rate': default" in p for p in parameter_problems(wrong))
    flipped = text.replace('| `real_time_factor` | `1.0` | yes |', '| `real_time_factor` | `1.0` | no |')
    assert any("'real_time_factor': live" in p for p in parameter_problems(flipped))
    extra = text.replace('| `frame_id` |', '| `frame_idd` | `x` | no | typo |\n| `frame_id` |')
    assert parameter_problems(extra) == ["parameter 'frame_idd' on the page is not in PARAMS"]


# ---------------------------------------------------------------- topics and services ----
def topic_problems(text: str) -> list[str]:
    rows = {code(r[0]).replace('<joint>', '{joint}'): r for r in table(text)}
    problems = []
    for t in TOPICS:
        if t.name not in rows:
            problems.append(f'topic {t.name!r} missing from the page')
            continue
        r = rows.pop(t.name)
        qos = r[2]
        page = (code(r[1]), BEST_EFFORT if 'best effort' in qos else RELIABLE,
                int(re.search(r'depth (\d+)', qos).group(1)) if 'depth' in qos else None,
                r[3], r[4] == 'yes')
        ours = (t.type, t.reliability, t.depth, t.direction, t.recorded)
        if page != ours:
            problems.append(f'topic {t.name!r}: {page} on the page, {ours} in TOPICS')
    problems += [f'topic {name!r} on the page is not in TOPICS' for name in rows]
    return problems


def service_problems(text: str) -> list[str]:
    page = {code(r[0]) for r in table(section(text, '## Services'))}
    node = set(re.findall(r"create_service\(\s*\w+,\s*'([^']+)'",
                          (ROOT / 'abd_joint_sim' / 'ros' / 'node.py').read_text()))
    assert node, 'no create_service call found in ros/node.py'
    return ([f'service {s!r} missing from the page' for s in sorted(node - page)]
            + [f'service {s!r} on the page is not created by the node' for s in sorted(page - node)])


def test_topic_page_matches_topics():
    text = (DOCS / 'topics.md').read_text()
    assert topic_problems(text) == []
    assert service_problems(text) == []


def test_topic_check_can_fail():
    text = (DOCS / 'topics.md').read_text()
    wrong = text.replace('| `/clock` | `rosgraph_msgs/msg/Clock` | best effort, depth 1 |',
                         '| `/clock` | `rosgraph_msgs/msg/Clock` | reliable, depth 1 |')
    assert [p.split(':')[0] for p in topic_problems(wrong)] == ["topic '/clock'"]
    dropped = '\n'.join(ln for ln in text.splitlines() if not ln.startswith('| `joint_commands`'))
    assert topic_problems(dropped) == ["topic 'joint_commands' missing from the page"]
    no_step = '\n'.join(ln for ln in text.splitlines() if not ln.startswith('| `~/step`'))
    assert service_problems(no_step) == ["service '~/step' missing from the page"]


# ---------------------------------------------------------------------- scene format ----
_BODY = {'name': 'b', 'box': [1.0, 1.0, 1.0], 'density': 1000.0, 'position': [1.0, 0.0, 0.0]}
_BASE = {'dt': 0.01,
         'bodies': [{'name': 'a', 'box': [1.0, 1.0, 1.0], 'density': 1000.0, 'fixed': True}, _BODY],
         'joints': [{'name': 'j', 'parent': 'a', 'child': 'b', 'p0': [0.5, 0, 0],
                     'p1': [0.5, 0, 1]}]}
_CYLINDER = dict(_BODY, box=None, cylinder={'radius': 0.1, 'length': 1.0})
_INERTIAL = {'name': 'b', 'inertial': {'mass': 1.0, 'inertia': {'ixx': 1, 'iyy': 1, 'izz': 1}}}
# page heading -> (a scene in which that section is present, the path to the section)
SECTIONS = {
    '## Top level': (_BASE, ()),
    '## `newton`': (dict(_BASE, newton={}), ('newton',)),
    '## `bodies[]`': (_BASE, ('bodies', 1)),
    '### `cylinder`': (dict(_BASE, bodies=[_BASE['bodies'][0], {k: v for k, v in _CYLINDER.items()
                                                                 if v is not None}]),
                       ('bodies', 1, 'cylinder')),
    '### `inertial`': (dict(_BASE, bodies=[_BASE['bodies'][0], _INERTIAL]), ('bodies', 1, 'inertial')),
    '### `inertial.inertia`': (dict(_BASE, bodies=[_BASE['bodies'][0], _INERTIAL]),
                               ('bodies', 1, 'inertial', 'inertia')),
    '### `visuals[]`': (dict(_BASE, bodies=[_BASE['bodies'][0], dict(
        _BODY, visuals=[{'kind': 'box', 'size': [1, 1, 1]}])]), ('bodies', 1, 'visuals', 0)),
    '## `joints[]`': (_BASE, ('joints', 0)),
    '### `external_torque`': (dict(_BASE, joints=[dict(_BASE['joints'][0], external_torque={})]),
                              ('joints', 0, 'external_torque')),
    '### `driving`': (dict(_BASE, joints=[dict(_BASE['joints'][0], driving={})]),
                      ('joints', 0, 'driving')),
    '### `limit`': (dict(_BASE, joints=[dict(_BASE['joints'][0], limit={'lower': -1, 'upper': 1})]),
                    ('joints', 0, 'limit')),
}


def parser_keys(scene: dict, path: tuple) -> list[str]:
    """The keys the parser accepts at `path` of `scene`: its unknown-key error lists them."""
    d = copy.deepcopy(scene)
    node = d
    for k in path:
        node = node[k]
    node['zz_not_a_key'] = 1
    with pytest.raises(SceneError) as err:
        Scene.from_dict(d)
    m = re.search(r'allowed: (.*)$', str(err.value))
    assert m, str(err.value)
    return [k.strip() for k in m.group(1).split(',')]


def code_defaults() -> dict[str, dict]:
    """Defaults of each section as the parser fills them in (from a scene that omits them)."""
    def fields(spec):
        return {f.name: f.default for f in dataclasses.fields(spec)
                if f.default is not dataclasses.MISSING}
    s = Scene.from_dict(dict(_BASE, bodies=[_BASE['bodies'][0], dict(_BODY, visuals=[
        {'kind': 'box', 'size': [1, 1, 1]}])]))
    inertial = Scene.from_dict(dict(_BASE, bodies=[_BASE['bodies'][0], _INERTIAL])).bodies[1].shape
    body = s.bodies[1]
    visual = fields(VisualSpec)
    visual.pop('rgba')                          # None: no default colour
    visual.pop('size')                          # required, except a mesh's (scale 1)
    inertia = inertial.inertia
    return {
        '## Top level': {'gravity': s.gravity, 'integrator': s.integrator, 'name': s.name,
                         'joints': []},
        '## `newton`': fields(NewtonSpec),
        '## `bodies[]`': {'kappa': body.kappa, 'position': (0.0, 0.0, 0.0), 'rpy': body.rpy,
                          'fixed': body.fixed, 'velocity': body.velocity,
                          'angular_velocity': body.angular_velocity,
                          'visuals': list(Scene.from_dict(_BASE).bodies[1].visuals)},
        '### `cylinder`': {},
        '### `inertial`': {'com': inertial.com, 'volume': 0.0},
        '### `inertial.inertia`': {'ixy': inertia[1], 'ixz': inertia[2], 'iyz': inertia[5]},
        '### `visuals[]`': visual,
        '## `joints[]`': dict(fields(JointSpec), type='revolute'),
        '### `external_torque`': fields(TorqueSpec),
        '### `driving`': fields(DrivingSpec),
        '### `limit`': fields(LimitSpec),
    }


def scene_format_problems(text: str) -> list[str]:
    problems = []
    defaults = code_defaults()
    for heading, (scene, path) in SECTIONS.items():
        rows = {code(r[0]): r[1] for r in table(section(text, heading))}
        if not rows:
            problems.append(f'{heading}: no table on the page')
            continue
        accepted = parser_keys(scene, path)
        problems += [f'{heading}: key {k!r} accepted by the parser, missing from the page'
                     for k in accepted if k not in rows]
        problems += [f'{heading}: key {k!r} on the page, refused by the parser'
                     for k in rows if k not in accepted]
        for key, value in defaults[heading].items():
            if key not in rows:
                continue
            if value is None:                       # no default: the section is absent
                if rows[key] != REQUIRED:
                    problems.append(f'{heading}: {key!r} default {rows[key]} on the page, none in the code')
            elif rows[key] == REQUIRED or not same(load_yaml(code(rows[key])), value):
                problems.append(f'{heading}: {key!r} default {rows[key]} on the page, {value!r} in the code')
    return problems


def test_scene_format_page_matches_the_parser():
    assert scene_format_problems((DOCS / 'scene-format.md').read_text()) == []


def test_scene_format_check_can_fail():
    text = (DOCS / 'scene-format.md').read_text()
    wrong = text.replace('| `max_iterations` | `64` |', '| `max_iterations` | `50` |')
    assert scene_format_problems(wrong) == [
        "## `newton`: 'max_iterations' default `50` on the page, 64 in the code"]
    dropped = '\n'.join(ln for ln in text.splitlines() if not ln.startswith('| `damping` | `0.0`'))
    assert scene_format_problems(dropped) == [
        "## `joints[]`: key 'damping' accepted by the parser, missing from the page"]
    extra = text.replace('| `strength` | `1.0` |', '| `stiffness` | `1.0` | x |\n| `strength` | `1.0` |')
    assert scene_format_problems(extra) == [
        "### `limit`: key 'stiffness' on the page, refused by the parser"]


def urdf_option_problems(text: str) -> list[str]:
    listed = set()
    for r in table(section(text, '## Options')):
        listed |= set(re.findall(r'`([a-z_]+)`', r[0]))
    return [f'URDF option {o!r} missing from docs/urdf.md "Options"'
            for o in urdf.ROBOT_OPTIONS + urdf.SCENE_OPTIONS if o not in listed]


def test_urdf_options_are_documented():
    text = (DOCS / 'urdf.md').read_text()
    assert urdf_option_problems(text) == []
    dropped = '\n'.join(ln for ln in text.splitlines() if not ln.startswith('| `lock`'))
    assert urdf_option_problems(dropped) == ['URDF option \'lock\' missing from docs/urdf.md "Options"']


# ---------------------------------------------------------------------------- links ----
LINK = re.compile(r'(?<!!)\[[^\]]*\]\(([^)\s]+)\)|!\[[^\]]*\]\(([^)\s]+)\)')


def link_problems(page: Path, text: str) -> list[str]:
    """Relative links (and images) of `page` that do not resolve inside the repository."""
    problems = []
    for m in LINK.finditer(text):
        target = (m.group(1) or m.group(2)).split('#', 1)[0]
        if not target or re.match(r'[a-z]+:', target):
            continue                                # a URL or an anchor in the page
        path = (page.parent / target).resolve()
        if ROOT not in path.parents and path != ROOT:
            problems.append(f'{page.name}: {target} points outside the repository')
        elif not path.exists():
            problems.append(f'{page.name}: {target} does not exist')
    return problems


def pages() -> list[Path]:
    return [ROOT / 'README.md'] + sorted(DOCS.glob('*.md'))


def test_every_relative_link_resolves():
    problems = [p for page in pages() for p in link_problems(page, page.read_text())]
    assert problems == []
    assert not any('../shared' in page.read_text() for page in pages())


def test_link_check_can_fail():
    readme = ROOT / 'README.md'
    assert link_problems(readme, 'see [x](docs/nope.md) and ![p](docs/img/nope.png)') == [
        'README.md: docs/nope.md does not exist', 'README.md: docs/img/nope.png does not exist']
    assert link_problems(readme, '[s](../shared/spec/a.md)') == [
        'README.md: ../shared/spec/a.md points outside the repository']
    assert link_problems(readme, '[ok](docs/speed.md#floor) [web](https://x.org/y)') == []
