"""The package's floors: every import in abd_joint_sim/ (at the top of a module or inside a
function) goes down the layer order below or stays on its floor, no modules import each other
in a circle, no module imports the package's facade (its ``__init__``), and the physics core
never imports rclpy.

Imports are read from the source (ast), so an import hidden in a function counts as much as
one at the top. A package's ``__init__`` counts only where it is named
(``from abd_joint_sim import World``), not as the parent that Python runs first.
"""
from __future__ import annotations

import ast
from pathlib import Path
import subprocess
import sys

import pytest

PACKAGE = 'abd_joint_sim'
ROOT = Path(__file__).resolve().parents[1] / PACKAGE

#: The floors, lowest first: a module may import from its own floor and the floors below.
#: A module belongs to the floor of the longest prefix that names it.
LAYERS = (
    ('foundation', ('errors', 'ranges', 'geometry', 'builders', 'smallmat', 'jit')),
    ('terms', ('terms',)),             # the constitutions: compiled kernels over given arrays
    ('urdf', ('urdf',)),               # the URDF reader: below the scene, which calls it
    ('scene', ('scene',)),
    ('model', ('model',)),
    ('state', ('state',)),
    ('solver', ('solver', 'jit.warmup')),   # the warm-up runs the solver's kernels
    ('world', ('world', '')),          # '': the package's __init__, which re-exports World
    ('record', ('record',)),
    ('ros', ('ros', 'runtime', 'live')),   # live: the live view, served by the node and the tools
    ('tools', ('tools',)),
)

#: The physics core: these floors never import ROS (:func:`is_ros`).
CORE = ('foundation', 'terms', 'urdf', 'scene', 'model', 'state', 'solver', 'world')
ROS_PACKAGES = ('rclpy', 'rosidl_runtime_py', 'rosidl_parser', 'builtin_interfaces',
                'rcl_interfaces')


def is_ros(module: str) -> bool:
    """rclpy, the rosidl tools or a message/service package (``*_msgs``, ``*_srvs``)."""
    top = module.split('.')[0]
    return top in ROS_PACKAGES or top.endswith(('_msgs', '_srvs'))


def modules() -> dict[str, Path]:
    found = {}
    for path in sorted(ROOT.rglob('*.py')):
        parts = list(path.relative_to(ROOT.parent).with_suffix('').parts)
        if parts[-1] == '__init__':
            parts.pop()
        found['.'.join(parts)] = path
    return found


def imports(name: str, path: Path, known) -> list[tuple[str, int]]:
    """(imported module, line) of every import statement in the file, nested ones included:
    ``from a import b`` names the module a.b when that is a module, else a."""
    package = name.split('.') if path.name == '__init__.py' else name.split('.')[:-1]
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(alias.name, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = '.'.join(package[:len(package) - node.level + 1]
                                + ([node.module] if node.module else []))
            else:
                base = node.module
            for alias in node.names:
                sub = f'{base}.{alias.name}'
                found.append((sub if sub in known else base, node.lineno))
    return found


def layer_of(module: str) -> str:
    rel = module[len(PACKAGE) + 1:] if module != PACKAGE else ''
    best, floor = -1, None
    for layer, prefixes in LAYERS:
        for prefix in prefixes:
            if (rel == prefix or rel.startswith(prefix + '.') or prefix == '') \
                    and len(prefix) > best:
                best, floor = len(prefix), layer
    return floor


ORDER = {layer: k for k, (layer, _) in enumerate(LAYERS)}


def graph() -> dict[str, list[tuple[str, int]]]:
    known = modules()
    return {name: [(m, line) for m, line in imports(name, path, known)
                   if m == PACKAGE or m.startswith(PACKAGE + '.')]
            for name, path in known.items()}


def cycles(edges: dict[str, list[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module, or a module importing
    itself (Tarjan)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in edges.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1 or v in edges.get(v, ()):
                found.append(sorted(component))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return found


def test_every_module_has_a_floor():
    assert [m for m in modules() if layer_of(m) is None] == []


def test_no_import_cycle():
    edges = {name: sorted({m for m, _ in found}) for name, found in graph().items()}
    assert cycles(edges) == []


def test_imports_go_down_the_layers():
    upward = [f'{name} ({layer_of(name)}) line {line} imports {m} ({layer_of(m)})'
              for name, found in graph().items() for m, line in found
              if ORDER[layer_of(m)] > ORDER[layer_of(name)]]
    assert upward == []


def test_modules_import_the_module_that_defines_a_name_not_the_facade():
    """``abd_joint_sim/__init__.py`` re-exports the public names for users; inside the
    package, ``from abd_joint_sim.world import World``, so the imports show the floors."""
    facade = [f'{name} line {line}' for name, found in graph().items() if name != PACKAGE
              for m, line in found if m == PACKAGE]
    assert facade == []


def test_core_never_imports_rclpy():
    known = modules()
    ros = [f'{name} line {line} imports {m}'
           for name, path in known.items() if layer_of(name) in CORE
           for m, line in imports(name, path, known) if is_ros(m)]
    assert ros == []
    code = ('import sys; import abd_joint_sim; from abd_joint_sim.world import World; '
            'print(sorted({m.split(".")[0] for m in sys.modules}))')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=300, cwd=ROOT.parent)
    assert out.returncode == 0, out.stderr
    loaded = ast.literal_eval(out.stdout.strip())
    assert [m for m in loaded if is_ros(m)] == []


@pytest.mark.parametrize('edges, expected', [
    ({'a': ['b'], 'b': ['c'], 'c': ['a']}, [['a', 'b', 'c']]),
    ({'a': ['a']}, [['a']]),
    ({'a': ['b'], 'b': ['c'], 'c': []}, []),
])
def test_the_cycle_finder_finds_circles(edges, expected):
    assert cycles(edges) == expected


def test_a_function_level_import_counts(tmp_path):
    source = tmp_path / 'inner.py'
    source.write_text('def f():\n    from . import scene\n')
    assert imports(f'{PACKAGE}.inner', source, {f'{PACKAGE}.scene'}) == [(f'{PACKAGE}.scene', 2)]
    assert layer_of(f'{PACKAGE}.jit.flat') == 'foundation'
    assert layer_of(PACKAGE) == 'world'
    assert ORDER[layer_of(f'{PACKAGE}.scene')] > ORDER[layer_of(f'{PACKAGE}.urdf')]
