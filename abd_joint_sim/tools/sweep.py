"""sweep: run many variants of one scene (a grid and seeded random samples) on Ray.

    sweep SPEC.yaml --out DIR [--workers N] [--address auto|ray://host:10001] [--bags]
    sweep SPEC.yaml --out DIR --in-process        # serially in this process, no Ray

The spec (docs/sweeps.md) names a base scene, a duration, an optional schedule and the axes
(scene fields by dotted path): a grid, seeded random samples, listed cases; or a `runner:`
in place of sim_node's loop. Every case is checked before anything runs. Each case runs
through the loop as ``run_headless`` runs it and gives one row of ``DIR/results.csv``
(also ``summary.md``, ``figure.png``; ``rows.jsonl`` and ``sweep.json`` let a re-run
resume). Exit status: 0 every case ran (faulted cases are results); 1 a case raised an
exception or lost its worker twice; 2 bad input; 130 interrupted (re-run to resume).
"""
from __future__ import annotations

import argparse
import copy
from dataclasses import dataclass, field
import hashlib
import itertools
import json
import math
import os
from pathlib import Path
import shutil
import sys
import time
from typing import Any, Callable, Optional, Sequence

from abd_joint_sim.tools import cli

PROG = 'sweep'
DEFAULT_MAX_CASES = 10_000
SPEC_KEYS = ('scene', 'urdf_options', 'duration', 'schedule', 'grid', 'random', 'cases',
             'runner', 'max_cases', 'plot')
RUNNER_EXCLUDES = ('scene', 'urdf_options', 'duration', 'schedule')   # a runner builds these
RESERVED_COLUMNS = ('case', 'status', 'message', 'wall_s')
RANDOM_KINDS = ('uniform', 'normal', 'choice')
STATUSES = ('ok', 'fault', 'error', 'died')
INSTALL_HINT = ("Ray is not installed: pip install -r requirements-sweep.txt (or "
                "pip install 'abd_joint_sim[sweep]'), or run serially with --in-process")


class SpecError(cli.InputError):
    """A spec that cannot run; one line."""


def build_parser() -> argparse.ArgumentParser:
    p = cli.Parser(prog=PROG, description=(
        'Run a sweep over an abd_joint_sim scene: a grid and seeded random samples of scene '
        'fields, each case through the run_headless loop, on Ray (local cores or a cluster). '
        'Writes DIR/results.csv, summary.md and figure.png; re-running resumes. '
        'Spec format: docs/sweeps.md.'))
    p.add_argument('spec', metavar='SPEC.yaml', help='the sweep spec')
    p.add_argument('--out', required=True, metavar='DIR',
                   help='results directory (created; an existing one of the same spec resumes)')
    p.add_argument('--workers', type=int, metavar='N',
                   help='parallel workers (default: every core of this machine, or every '
                        'CPU of the cluster with --address)')
    p.add_argument('--address', metavar='ADDR',
                   help="a running Ray cluster: 'auto' (started here with `ray start`), host:"
                        'port or ray://host:10001; default: a Ray of its own on this machine')
    p.add_argument('--bags', action='store_true',
                   help='record each case\'s bag (as run_headless) in DIR/bags/CASE')
    p.add_argument('--in-process', action='store_true',
                   help='run the cases one after another in this process (no Ray)')
    p.add_argument('--max-cases', type=int, metavar='N',
                   help=f'refuse a spec of more cases (default: the spec\'s max_cases, else '
                        f'{DEFAULT_MAX_CASES})')
    p.add_argument('--temp-dir', metavar='DIR',
                   help='Ray\'s session directory for a local Ray (default: a new one under '
                        'the system temp directory, removed afterwards)')
    p.add_argument('-q', '--quiet', action='store_true', help='no progress, no summary line')
    return p


@dataclass
class Setup:
    """What every case shares: the base scene data, the schedule, the duration."""

    base: dict                      # scene data (a URDF robot as a `robot:` block)
    source: str                     # the base scene's path (relative URDF paths resolve there)
    scene_path: str                 # what a bag stores as the scene ('' = spec-made scene)
    plan: Any                       # schedule.Plan (one segment)
    parameters: dict                # the schedule's sim_node parameters
    duration_ns: int
    axes: list                      # dotted paths, grid axes first
    runner: str = ''                # 'module:function' running a case instead of the loop


@dataclass
class Job:
    """One case for a worker."""

    index: int
    case: str                       # 'case_0003'
    values: dict                    # path -> value
    bag: str = ''                   # bag directory to write, '' = none


@dataclass
class Spec:
    setup: Setup
    cases: list                     # [{path: value}], in case order
    digest: str
    plot: dict = field(default_factory=dict)


def _fail(where: str, what: str) -> SpecError:
    return SpecError(f'{where}: {what}')


def _finite(where: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(float(value)):
        raise _fail(where, f'expected a finite number, got {value!r}')
    return float(value)


def _integer(where: str, value: Any, low: int, expected: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise _fail(where, f'{expected}, got {value!r}')
    return value


def _check_path(where: str, path: Any) -> str:
    if not isinstance(path, str) or not path or any(not s for s in path.split('.')):
        raise _fail(where, f'{path!r} is not a dotted path into the scene '
                           '(e.g. joints.elbow.external_torque.torque)')
    return path


def load_spec(path: str | Path, max_cases: Optional[int] = None) -> Spec:
    """Read, expand and check a spec; SpecError (one line) on the first problem."""
    from abd_joint_sim.scene import read_yaml_file
    path = Path(path)
    _, data = read_yaml_file(path, SpecError, 'sweep spec')
    return spec_from_data(data, str(path), path.resolve().parent, max_cases)


def spec_from_data(data: Any, src: str, here: Path, max_cases: Optional[int] = None) -> Spec:
    """Expand and check a spec given as data (what the YAML holds): `src` names it in
    messages, `here` is where its relative paths start. SpecError (one line) on a problem."""
    if not isinstance(data, dict):
        raise _fail(src, 'expected a mapping with scene, duration, grid and/or random '
                         '(docs/sweeps.md)')
    unknown = [k for k in data if k not in SPEC_KEYS]
    if unknown:
        raise _fail(f'{src}: {unknown[0]}', f'unknown key (allowed: {", ".join(SPEC_KEYS)})')
    runner = data.get('runner')
    if runner is not None:
        _load_runner(f'{src}: runner', runner)
        extra = [k for k in RUNNER_EXCLUDES if k in data]
        if extra:
            raise _fail(f'{src}: {extra[0]}', 'a spec with a runner: builds its cases itself '
                                              f'(leave out {", ".join(RUNNER_EXCLUDES)})')
        setup = Setup({}, src, '', None, {}, 0, [], runner)
    else:
        setup = _loop_setup(src, here, data)
    grid = _grid(src, data.get('grid'))
    rnd = _random(src, data.get('random'))
    axes = list(grid) + list(rnd['axes'])
    listed = _listed(src, data.get('cases'), axes)
    dup = [a for a in axes if axes.count(a) > 1]
    if dup:
        raise _fail(src, f'axis {dup[0]} is given twice')
    for values in listed:
        axes += [a for a in values if a not in axes]
    setup.axes = axes
    bad = [a for a in axes if a in RESERVED_COLUMNS]
    if setup.runner and bad:
        raise _fail(src, f'axis {bad[0]!r} is a result column of every sweep (reserved: '
                         f'{", ".join(RESERVED_COLUMNS)})')
    cap = max_cases if max_cases is not None else data.get('max_cases', DEFAULT_MAX_CASES)
    _integer(f'{src}: max_cases', cap, 1, 'expected an integer >= 1')
    crossed = grid or data.get('random') is not None or not listed
    count = (math.prod(len(v) for v in grid.values()) * rnd['n'] if crossed else 0) + len(listed)
    if count > cap:
        raise _fail(src, f'{count} cases asked, more than the cap of {cap} (raise it with '
                         f'max_cases: in the spec or --max-cases)')
    samples = _samples(rnd)
    cases = [{**dict(zip(grid, combo)), **sample}
             for combo in itertools.product(*grid.values()) for sample in samples] \
        if crossed else []
    cases += listed
    for k, values in enumerate(cases):
        check_case(setup, k, values)
    plot = data.get('plot') or {}
    if not isinstance(plot, dict) or set(plot) - {'x', 'y', 'series'}:
        raise _fail(f'{src}: plot', f'expected {{x: axis, y: column, series: axis}}, got {plot!r}')
    for key in ('x', 'series'):
        if key in plot and plot[key] not in axes:
            raise _fail(f'{src}: plot.{key}', f'{plot[key]!r} is not an axis of the spec '
                                              f'(axes: {", ".join(axes) or "none"})')
    if 'y' in plot and not setup.runner and plot['y'] not in FIXED_COLUMNS \
            and not str(plot['y']).startswith(('angle.', 'velocity.')):
        raise _fail(f'{src}: plot.y', f'{plot["y"]!r} is not a result column (angle.<joint>, '
                                      f'velocity.<joint>, {", ".join(FIXED_COLUMNS[2:])})')
    digest = hashlib.sha256(json.dumps(
        {'base': setup.base, 'source': setup.source, 'duration_ns': setup.duration_ns,
         'parameters': setup.parameters, 'runner': setup.runner, 'cases': cases,
         'plan': repr(setup.plan.segments) if setup.plan is not None else ''},
        sort_keys=True, default=repr).encode()).hexdigest()[:16]
    return Spec(setup, cases, digest, plot)


def _loop_setup(src: str, here: Path, data: dict) -> Setup:
    """The Setup of a spec without a runner (but its axes)."""
    from abd_joint_sim.errors import SceneError
    from abd_joint_sim.ros.convert import seconds_to_ns
    from abd_joint_sim.scene import read_yaml_file
    from .schedule import MAX_SCHEDULE_BYTES, MAX_TIME, parse_schedule, ScheduleError
    try:
        base, source = _base_scene(here, data.get('scene', 'default'), data.get('urdf_options'))
    except SceneError as exc:
        raise _fail(f'{src}: scene', str(exc)) from None
    schedule, where = data.get('schedule'), f'{src}: schedule'
    try:
        if schedule is None:
            schedule, where = {'events': []}, f'{src}: (no schedule)'
        elif isinstance(schedule, str):         # a file, read as schedule.load_schedule reads it
            where = str(here / os.path.expanduser(schedule))
            _, schedule = read_yaml_file(where, ScheduleError, 'schedule',
                                         max_bytes=MAX_SCHEDULE_BYTES)
        plan = parse_schedule(schedule, where)
    except ScheduleError as exc:
        raise SpecError(str(exc)) from None
    duration = data.get('duration')
    given = isinstance(schedule, dict) and schedule.get('duration') is not None
    if duration is None and not given:             # (the schedule's duration is the default)
        raise _fail(f'{src}: duration', 'missing (simulated seconds per case)')
    if duration is not None:
        duration = _finite(f'{src}: duration', duration)
        if not 0.0 < duration <= MAX_TIME:
            raise _fail(f'{src}: duration', f'{duration:g} must be > 0 and at most {MAX_TIME:g} s')
        plan.segments[-1].end_ns = seconds_to_ns(duration)
    return Setup(base, source, source, plan, dict(plan.parameters), plan.segments[-1].end_ns, [])


def _listed(src: str, listed: Any, crossed_axes: list) -> list:
    """The spec's `cases:`: a list of {axis: value}, run after the grid x random cases."""
    if listed is None:
        return []
    where = f'{src}: cases'
    if not isinstance(listed, list) or not listed:
        raise _fail(where, f'expected a non-empty list of {{axis: value}}, got {listed!r}')
    for k, values in enumerate(listed):
        if not isinstance(values, dict) or not values:
            raise _fail(f'{where}[{k}]', f'expected a mapping {{axis: value}}, got {values!r}')
        for path in values:
            _check_path(f'{where}[{k}]', path)
        if crossed_axes and set(values) != set(crossed_axes):
            raise _fail(f'{where}[{k}]', f'names {", ".join(sorted(values))}; beside grid/random '
                                         f'a listed case names their axes ({", ".join(crossed_axes)})')
    return [dict(values) for values in listed]


def _load_runner(where: str, runner: Any) -> Callable:
    """The callable a `runner: module:function` names (SpecError when it does not import)."""
    import importlib
    if not isinstance(runner, str) or runner.count(':') != 1 or not all(runner.split(':')):
        raise _fail(where, f'expected module:function, got {runner!r}')
    module, name = runner.split(':')
    try:
        fn = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError) as exc:
        raise _fail(where, f'{runner}: {type(exc).__name__}: {exc}') from None
    if not callable(fn):
        raise _fail(where, f'{runner} is not callable')
    return fn


def _base_scene(here: Path, scene: Any, urdf_options: Any) -> tuple[dict, str]:
    """(scene data, its path) of the spec's `scene`; SceneError on a problem."""
    from abd_joint_sim import urdf
    from abd_joint_sim.errors import SceneError
    from abd_joint_sim.ros.params import resolve_scene
    from abd_joint_sim.scene import read_yaml_file
    if not isinstance(scene, str) or not scene.strip():
        raise SceneError('expected a packaged scene name or the path of a .yaml or .urdf file, '
                         f'got {scene!r}')
    if os.sep in scene or scene.endswith(('.yaml', '.yml', '.urdf')):
        scene = str((here / os.path.expanduser(scene)).resolve())
    scene_path = resolve_scene(scene)
    if not os.path.isfile(scene_path):
        raise SceneError(f'{scene_path}: no such file')
    if not scene_path.lower().endswith('.urdf'):
        if urdf_options is not None:
            raise SceneError('urdf_options apply to a .urdf scene only (a scene YAML has a '
                             'robot: block for that)')
        _, data = read_yaml_file(scene_path, SceneError, 'scene file')
        if not isinstance(data, dict):
            raise SceneError(f'{scene_path}: expected a scene mapping')
        return data, scene_path
    options = urdf_options or {}
    if not isinstance(options, dict):
        raise SceneError(f'urdf_options: expected a mapping, got {options!r}')
    allowed = urdf.ROBOT_OPTIONS + urdf.SCENE_OPTIONS
    bad = [k for k in options if k not in allowed]
    if bad:
        raise SceneError(f'urdf_options.{bad[0]}: unknown option (allowed: {", ".join(allowed)})')
    data = {k: v for k, v in options.items() if k in urdf.SCENE_OPTIONS}
    data.setdefault('dt', urdf.DEFAULT_DT)
    data.setdefault('gravity', list(urdf.DEFAULT_GRAVITY))
    data['robot'] = {'urdf': scene_path,
                     **{k: v for k, v in options.items() if k in urdf.ROBOT_OPTIONS}}
    return data, scene_path


def _grid(src: str, grid: Any) -> dict:
    if grid is None:
        return {}
    if not isinstance(grid, dict):
        raise _fail(f'{src}: grid', f'expected {{path: [values]}}, got {grid!r}')
    for path, values in grid.items():
        _check_path(f'{src}: grid', path)
        if not isinstance(values, list):
            raise _fail(f'{src}: grid.{path}', f'expected a list of values, got {values!r}')
        if not values:
            raise _fail(f'{src}: grid.{path}', 'empty list: an axis needs at least one value')
    return dict(grid)


def _random(src: str, rnd: Any) -> dict:
    if rnd is None:
        return {'n': 1, 'seed': 0, 'axes': {}}
    where = f'{src}: random'
    if not isinstance(rnd, dict):
        raise _fail(where, f'expected a mapping with n, seed and uniform/normal/choice, got {rnd!r}')
    bad = [k for k in rnd if k not in ('n', 'seed') + RANDOM_KINDS]
    if bad:
        raise _fail(f'{where}.{bad[0]}', f'unknown key (allowed: n, seed, {", ".join(RANDOM_KINDS)})')
    n = _integer(f'{where}.n', rnd.get('n'), 1, 'expected the number of samples, an integer >= 1')
    seed = _integer(f'{where}.seed', rnd.get('seed'), 0,
                    'expected an integer >= 0 (samples are seeded)')
    axes: dict = {}
    for kind in (k for k in RANDOM_KINDS if rnd.get(k) is not None):
        block = rnd[kind]
        if not isinstance(block, dict) or not block:
            raise _fail(f'{where}.{kind}', f'expected {{path: ...}}, got {block!r}')
        for path, arg in block.items():
            w = f'{where}.{kind}.{_check_path(f"{where}.{kind}", path)}'
            if path in axes:
                raise _fail(w, 'axis given twice')
            if kind == 'choice' and (not isinstance(arg, list) or not arg):
                raise _fail(w, f'expected a non-empty list of values, got {arg!r}')
            if kind != 'choice':
                if not isinstance(arg, list) or len(arg) != 2:
                    want = '[low, high]' if kind == 'uniform' else '[mean, std]'
                    raise _fail(w, f'expected {want}, got {arg!r}')
                arg = [_finite(w, v) for v in arg]
                if kind == 'uniform' and not arg[0] <= arg[1]:
                    raise _fail(w, f'low {arg[0]:g} is above high {arg[1]:g}')
                if kind == 'normal' and arg[1] < 0.0:
                    raise _fail(w, f'std {arg[1]:g} is negative')
            axes[path] = (kind, arg)
    if not axes:
        raise _fail(where, 'no axis: give uniform, normal or choice')
    return {'n': n, 'seed': seed, 'axes': axes}


def _samples(rnd: dict) -> list[dict]:
    """n samples {path: value}: one seeded generator, axes drawn in spec order, n at a time."""
    import numpy as np
    n, gen = rnd['n'], np.random.default_rng(rnd['seed'])
    columns = {path: [arg[int(k)] for k in gen.integers(0, len(arg), n)] if kind == 'choice'
               else [float(x) for x in getattr(gen, kind)(arg[0], arg[1], n)]
               for path, (kind, arg) in rnd['axes'].items()}
    return [{p: c[i] for p, c in columns.items()} for i in range(n)]


def case_name(index: int, total: int) -> str:
    return f'case_{index:0{max(4, len(str(total - 1)))}d}'


def _set_path(data: dict, path: str, value: Any) -> None:
    """data[path] = value: mapping keys by name, list items (bodies, joints) by their name.
    Missing mapping keys are created (the scene format decides whether they are allowed)."""
    from abd_joint_sim.errors import SceneError
    parts = path.split('.')
    cur: Any = data
    for k, part in enumerate(parts):
        last = k == len(parts) - 1
        if isinstance(cur, list):
            items = [x for x in cur if isinstance(x, dict) and x.get('name') == part]
            if not items:
                names = [x.get('name') for x in cur if isinstance(x, dict)]
                raise SceneError(f'{path}: unknown path: no item named {part!r} in '
                                 f'{".".join(parts[:k])} (have: {", ".join(map(str, names))})')
            if last:
                raise SceneError(f'{path}: names a whole item; name one of its fields')
            cur = items[0]
        elif isinstance(cur, dict) and last:
            cur[part] = copy.deepcopy(value)
        elif isinstance(cur, dict):
            if cur.get(part) is None:
                cur[part] = {}
            cur = cur[part]
        else:
            raise SceneError(f'{path}: unknown path: {".".join(parts[:k])} is a value '
                             f'({cur!r}), not a mapping or list')


_TOP_SCENE_KEYS = ('name', 'description', 'dt', 'gravity', 'integrator', 'newton')


def case_scene(setup: Setup, values: dict):
    """The Scene of one case (SceneError naming the path on a refused value). With a URDF
    robot, `robot.*` and the top-level keys are set before the URDF is lowered."""
    from abd_joint_sim.errors import SceneError
    from abd_joint_sim.scene import Scene, _Parser, _with_robot
    data = copy.deepcopy(setup.base)
    robot = None
    rest = dict(values)
    if 'robot' in data:
        for path in [p for p in values if p.split('.')[0] in ('robot',) + _TOP_SCENE_KEYS]:
            _set_path(data, path, rest.pop(path))
        try:
            data, robot = _Parser(setup.source).robot(data)
        except SceneError as exc:
            raise SceneError(f'robot: {exc}') from None
    for path, value in rest.items():
        if path.split('.')[0] == 'robot':
            raise SceneError(f'{path}: unknown path: the scene has no robot: block')
        _set_path(data, path, value)
    scene = Scene.from_dict(data, source=setup.source)
    return scene if robot is None else _with_robot(scene, *robot)


def check_case(setup: Setup, index: int, values: dict) -> None:
    """Build the case's scene and check the schedule against it (SpecError naming the case).
    With a runner: the runner's own `check(values)`, when it has one."""
    try:
        if setup.runner:
            check = getattr(_load_runner('runner', setup.runner), 'check', None)
            if check is not None:
                check(dict(values))
            return
        from abd_joint_sim.ros.commands import CommandBuffer
        from .bagrun import config_for
        from .schedule import check_plan
        scene = case_scene(setup, values)
        config = config_for(setup.parameters, scene_path=setup.scene_path)
        torqued = [j for j in scene.joints if j.external_torque is not None]
        actuated = [j.name for j in torqued]
        buffer = CommandBuffer(actuated, config.joints, config.effort_limits, 0.0,
                               scene_limits={j.name: j.external_torque.effort_limit
                                             for j in torqued},
                               driven=[j.name for j in scene.joints if j.driving is not None])
        check_plan(setup.plan, actuated, buffer.order, buffer)
    except ((ValueError, KeyError, TypeError) if setup.runner else ValueError) as exc:
        shown = ', '.join(f'{p} = {v!r}' for p, v in values.items())   # (SceneError too)
        raise SpecError(f'case {index}' + (f' ({shown})' if shown else '') + f': {exc}') from None


def _outputs():
    """The loop outputs of a case, defined when used (they import the ROS messages)."""
    from abd_joint_sim.ros.loop import LoopOutput
    from .sim import BagRecorder

    class Metrics(LoopOutput):
        """Per-step solver statistics of a case (reads the world after every step)."""

        world_each_step = True

        def __init__(self, sim):
            self.sim = sim
            self.steps = self.newton_sum = self.newton_max = 0
            self.substep_steps = self.substeps_max = 0
            self.max_sep = 0.0

        def stepped(self, t_ns: int, force: bool) -> None:
            rep = self.sim.world.last_step
            self.max_sep = max(self.max_sep, float(rep.max_joint_separation))
            if force:               # the initial state, not a step
                return
            self.steps += 1
            self.newton_sum += rep.newton_iterations
            self.newton_max = max(self.newton_max, rep.newton_iterations)
            self.substep_steps += rep.substeps > 1
            self.substeps_max = max(self.substeps_max, rep.substeps)

        def close(self) -> None:
            pass

    class CaseBag(BagRecorder, Metrics):
        """run_headless's bag with the statistics, the same bytes on every worker and run."""

        def __init__(self, path, sim, scene_path, scene_text, extra_custom, urdf_text):
            Metrics.__init__(self, sim)
            BagRecorder.__init__(self, path, sim, scene_path, scene_text, extra_custom,
                                 urdf_text=urdf_text, reproducible=True)

    return Metrics, CaseBag


def incomplete_marker(bag: str) -> Path:
    """The file beside a bag that says it is not finished (removed once it is)."""
    return Path(bag + '.incomplete')


def _plain(value: Any) -> Any:
    """A numpy scalar as the Python number it holds (the table writes Python's repr)."""
    item = getattr(value, 'item', None)
    return item() if item is not None and type(value).__module__ == 'numpy' else value


def run_case(setup: Setup, job: Job) -> dict:
    """Run one case; always returns its row (a failure is a status and a message)."""
    wall0 = time.perf_counter()
    row: dict = {'case': job.case, **job.values}
    try:
        message = (_runner_case if setup.runner else _loop_case)(setup, job, row)
        status = 'fault' if message else 'ok'
    except Exception as exc:  # noqa: BLE001 - a case's failure is its row, not the sweep's
        status, message = 'error', f'{type(exc).__name__}: {exc}'
    row.update(status=status, message=message.replace('\n', ' '),
               wall_s=time.perf_counter() - wall0)
    return row


def _runner_case(setup: Setup, job: Job, row: dict) -> str:
    """A case of a spec with a runner: its columns are what the runner returns."""
    result = _load_runner('runner', setup.runner)(dict(job.values))
    if not isinstance(result, dict):
        raise TypeError(f'the runner returned {type(result).__name__}, not a mapping of columns')
    clash = [k for k in result if k in RESERVED_COLUMNS or k in setup.axes]
    if clash:
        raise KeyError(f'the runner returned column {clash[0]!r}, a reserved column or an axis')
    row.update({str(k): _plain(v) for k, v in result.items()})
    return ''


def _loop_case(setup: Setup, job: Job, row: dict) -> str:
    """A case through sim_node's loop: adds its columns to `row`, returns the fault ('' none)."""
    from abd_joint_sim.errors import SimulationError
    from .bagrun import config_for
    from .sim import HeadlessSim
    scene = case_scene(setup, job.values)
    config = config_for(setup.parameters, scene_path=setup.scene_path)
    sim = HeadlessSim(scene, config, clamp=True)
    world, fault = sim.world, ''
    energy0 = world.mechanical_energy()
    Metrics, CaseBag = _outputs()
    if job.bag:
        marker = incomplete_marker(job.bag)
        marker.parent.mkdir(parents=True, exist_ok=True)
        marker.write_text('this bag is being written; a bag beside this file is partial\n')
        if os.path.isdir(job.bag):
            shutil.rmtree(job.bag)          # a partial bag of an interrupted run
        config.record = job.bag
        out = CaseBag(job.bag, sim, setup.scene_path, getattr(scene, 'source_text', ''),
                      {'abd_joint_sim.recorded_by': f'sweep ({job.case})',
                       'abd_joint_sim.sweep_case': json.dumps(job.values, sort_keys=True)},
                      getattr(scene, 'robot_description', '') or '')
    else:
        out = Metrics(sim)
    try:
        sim.run(copy.deepcopy(setup.plan), out)
    except (SimulationError, ArithmeticError, ValueError) as exc:
        what = str(exc) if isinstance(exc, SimulationError) else f'{type(exc).__name__}: {exc}'
        fault = f'step at t={world.time:.6f} s failed: {what}'
    finally:
        out.close()         # on an error the marker stays: the bag is partial
    if job.bag:
        incomplete_marker(job.bag).unlink()
    for name, a, v in zip(world.joint_names, world.joint_angles().tolist(),
                          world.joint_velocities().tolist()):
        row[f'angle.{name}'] = a
        row[f'velocity.{name}'] = v
    row.update({
        'sim_time': float(world.time), 'steps': out.steps,
        'energy_drift': float(world.mechanical_energy() - energy0),
        'max_joint_separation': out.max_sep,
        'newton_mean': out.newton_sum / out.steps if out.steps else 0.0,
        'newton_max': out.newton_max, 'substep_steps': out.substep_steps,
        'substeps_max': out.substeps_max, 'not_converged': sim.not_converged})
    return fault


def warm_kernels() -> None:
    """Load (or compile) the compiled step, and import what a case uses, once in this
    process: a short case of the packaged hinge scene runs through the loop."""
    spec = spec_from_data({'scene': 'hinge', 'duration': 0.05, 'schedule': {
        'events': [{'t': 0.0, 'torque': {'hinge': 1.0}}]}}, '<warm-up>', Path('.'))
    row = run_case(spec.setup, Job(0, 'warm-up', {}))
    if row['status'] != 'ok':
        raise RuntimeError(f'the warm-up case failed: {row["message"]}')


class CaseWorker:
    """A worker process's state: the shared set-up and the warm kernels (a Ray actor)."""

    def __init__(self, setup: Setup):
        self.setup = setup
        warm = getattr(_load_runner('runner', setup.runner), 'warm', None) if setup.runner \
            else warm_kernels
        if warm is not None:            # a runner's own warm-up, when it has one
            warm()

    def run(self, job: Job) -> dict:
        return run_case(self.setup, job)


def run_in_process(setup: Setup, jobs: list, on_row: Callable[[dict], None]) -> None:
    worker = CaseWorker(setup)
    for job in jobs:
        on_row(worker.run(job))


class RayEngine:
    """The cases on Ray actors (one per worker, each with warm kernels); a case whose
    worker dies is retried once on a new worker, then recorded as 'died'."""

    def __init__(self, workers: Optional[int], address: Optional[str],
                 temp_dir: Optional[str] = None):
        import ray
        self.ray, self.own_temp = ray, None
        kwargs: dict = dict(log_to_driver=False, logging_level='ERROR', configure_logging=True)
        if address:
            ray.init(address=address, **kwargs)
            self.workers = workers or int(ray.cluster_resources().get('CPU', 1))
        else:
            import tempfile
            self.workers = workers or os.cpu_count() or 1
            if temp_dir is None:
                temp_dir = self.own_temp = tempfile.mkdtemp(prefix='ray-sweep-')
            ray.init(num_cpus=self.workers, _temp_dir=os.path.abspath(temp_dir),
                     include_dashboard=False, **kwargs)
        self.nodes = sum(1 for n in ray.nodes() if n.get('Alive'))
        self.setup: Optional[Setup] = None
        self.setup_ref, self.actors = None, []
        self.remote = ray.remote(num_cpus=1, max_restarts=0)(CaseWorker)

    def run(self, setup: Setup, jobs: list, on_row: Callable[[dict], None]) -> None:
        """Run `jobs`, each row to `on_row` as it comes; the workers stay up (warm) between
        calls of the same set-up."""
        ray = self.ray
        from ray.exceptions import RayActorError, WorkerCrashedError
        if self.setup is not setup:             # workers of another set-up: new ones
            for actor in self.actors:
                ray.kill(actor, no_restart=True)
            self.setup, self.setup_ref, self.actors = setup, ray.put(setup), []
        queue = [(job, 0) for job in reversed(jobs)]    # pop() takes the next in case order
        actors = self.actors
        while len(actors) < min(self.workers, len(jobs)):
            actors.append(self.remote.remote(self.setup_ref))
        pending: dict = {}

        def submit(slot: int) -> None:
            if queue:
                job, attempt = queue.pop()
                pending[actors[slot].run.remote(job)] = (slot, job, attempt)

        for slot in range(len(actors)):
            submit(slot)
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                slot, job, attempt = pending.pop(ref)
                try:
                    row = ray.get(ref)
                except (RayActorError, WorkerCrashedError) as exc:
                    ray.kill(actors[slot], no_restart=True)
                    actors[slot] = self.remote.remote(self.setup_ref)
                    if attempt == 0:
                        queue.append((job, 1))
                        submit(slot)
                        continue
                    why = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
                    row = {'case': job.case, **job.values, 'status': 'died',
                           'message': f'worker process died twice: {why}', 'wall_s': 0.0}
                on_row(row)
                submit(slot)

    def close(self) -> None:
        for actor in self.actors:
            try:
                self.ray.kill(actor, no_restart=True)
            except Exception:  # noqa: BLE001 - shutting down anyway
                pass
        self.ray.shutdown()
        if self.own_temp:
            shutil.rmtree(self.own_temp, ignore_errors=True)


class Progress:
    """Cases done / failed / ETA: a bar on a terminal, else a line per 10 %."""

    def __init__(self, total: int, done: int, stream=None, quiet: bool = False):
        self.total, self.done, self.start_done, self.failed = total, done, done, 0
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, 'isatty') and self.stream.isatty()
        self.quiet = quiet
        self.t0 = time.monotonic()
        self.next_tenth = (10 * done // max(total, 1)) + 1

    def update(self, row: dict) -> None:
        self.done += 1
        self.failed += row.get('status') != 'ok'
        if self.quiet or not self.total:
            return
        ran = self.done - self.start_done
        elapsed = time.monotonic() - self.t0
        eta = elapsed / ran * (self.total - self.done) if ran else math.nan
        text = f'{self.done}/{self.total} cases, {self.failed} failed, ' + (
            f'ETA {eta:.0f} s' if self.done < self.total else f'{elapsed:.1f} s')
        if self.tty:
            filled = int(30 * self.done / self.total)
            self.stream.write(f'\r{PROG}: [{"#" * filled}{"." * (30 - filled)}] {text}  ')
            if self.done == self.total:
                self.stream.write('\n')
            self.stream.flush()
        elif 10 * self.done // self.total >= self.next_tenth:
            self.next_tenth = 10 * self.done // self.total + 1
            print(f'{PROG}: {100 * self.done // self.total}% {text}', file=self.stream,
                  flush=True)

    def end_line(self) -> None:
        if self.tty and not self.quiet and self.done < self.total:
            self.stream.write('\n')
            self.stream.flush()


FIXED_COLUMNS = ('status', 'message', 'sim_time', 'steps', 'energy_drift',
                 'max_joint_separation', 'newton_mean', 'newton_max', 'substep_steps',
                 'substeps_max', 'not_converged', 'wall_s')


def columns_of(rows: list, axes: list, runner: bool = False) -> list:
    seen = dict.fromkeys(k for row in rows for k in row)        # in the order first given
    if runner:                  # the runner's columns
        middle, end = [k for k in seen if k not in RESERVED_COLUMNS and k not in axes], []
    else:                       # the joints' angles, then their velocities
        middle = sorted((k for k in seen if k.startswith(('angle.', 'velocity.'))),
                        key=lambda k: k.startswith('velocity.'))
        end = list(FIXED_COLUMNS[2:-1])
    return ['case'] + list(axes) + ['status', 'message'] + middle + end + ['wall_s']


def _cell(value: Any) -> str:
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, (dict, list)):
        return json.dumps(value)
    return '' if value is None else str(value)


def write_csv(path: Path, rows: list, columns: list) -> None:
    import csv
    tmp = path.with_suffix('.csv.tmp')
    with open(tmp, 'w', newline='') as f:
        w = csv.writer(f)
        w.writerow(columns)
        w.writerows([_cell(row.get(c)) for c in columns] for row in rows)
    os.replace(tmp, path)


def _fmt(v: Any) -> str:
    return f'{v:.4g}' if isinstance(v, float) else str(v).replace('|', '/')


def _counts(rows: list) -> dict:
    return {s: sum(r.get('status') == s for r in rows) for s in STATUSES}


def summary_md(spec_path: str, rows: list, columns: list, total: int, wall: float,
               engine: str, figure: str, argv: Sequence[str]) -> str:
    counts = _counts(rows)
    case_wall = sum(float(r.get('wall_s') or 0.0) for r in rows)
    lines = [f'# Sweep {Path(spec_path).name}', '',
             f'Command: `sweep {" ".join(argv)}`; engine: {engine}.', '',
             f'{len(rows)} of {total} cases: ' + ', '.join(f'{counts[s]} {s}' for s in STATUSES)
             + f'. Wall time of this run {wall:.1f} s; the cases\' own wall time sums to '
             f'{case_wall:.1f} s.', '']
    if figure:
        lines += [f'![{figure}]({figure})', '']
    failed = [r for r in rows if r.get('status') != 'ok']
    if failed:
        lines += ['## Cases that did not finish', '',
                  '| case | status | message |', '|---|---|---|']
        lines += [f'| {r["case"]} | {r["status"]} | {_fmt(r.get("message", ""))[:300]} |'
                  for r in failed[:100]] + ['']
    shown = [c for c in columns if c != 'message']
    lines += ['## Results', '', '| ' + ' | '.join(shown) + ' |', '|' + '---|' * len(shown)]
    lines += ['| ' + ' | '.join(_fmt(r.get(c, '')) for c in shown) + ' |' for r in rows[:200]]
    if len(rows) > 200:
        lines.append(f'\n{len(rows) - 200} more rows in results.csv.')
    return '\n'.join(lines) + '\n'


def write_figure(path: Path, rows: list, axes: list, plot: dict) -> str:
    """A metric against one axis (coloured by a second): matplotlib as plot_bag uses it.
    Returns the file name, or '' (with the reason on stderr) when there is nothing to plot."""
    try:
        import matplotlib
    except ImportError:
        print(f'{PROG}: note: matplotlib is not installed; figure skipped '
              '(pip install -r requirements-study.txt)', file=sys.stderr)
        return ''
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    ok = [r for r in rows if r.get('status') == 'ok']

    def all_of(axis, types) -> bool:
        return all(isinstance(r.get(axis), types) and not isinstance(r.get(axis), bool)
                   for r in ok)
    numeric = [a for a in axes if all_of(a, (int, float))]
    scalar = [a for a in axes if all_of(a, (int, float, str))]    # (a list value is no series)
    x = plot.get('x') or (numeric[0] if numeric else None)
    y = plot.get('y') or next((c for r in ok[:1] for c in r if c.startswith('angle.')),
                              'newton_mean')
    series = plot.get('series') or next((a for a in scalar if a != x), None)
    if not ok or x is None or x not in numeric or series not in scalar + [None] \
            or not all_of(y, (int, float)):
        print(f'{PROG}: note: no figure: ' + (
            'no case finished' if not ok else f'needs a numeric axis for x and a numeric '
            f'column for y (x {x!r}, y {y!r}, series {series!r})'), file=sys.stderr)
        return ''
    fig, ax = plt.subplots(figsize=(7, 4.5), constrained_layout=True)
    groups: dict = {}
    for r in ok:
        groups.setdefault(r.get(series) if series else None, []).append(r)
    for key, members in sorted(groups.items(), key=lambda kv: str(kv[0])):
        members = sorted(members, key=lambda r: float(r[x]))     # (x is numeric in each)
        label = f'{series} = {key:.4g}' if isinstance(key, float) else (
            f'{series} = {key}' if series else None)
        xs = [r.get(x) for r in members]
        # a line only where it is one: one point per x (other axes vary otherwise)
        style = 'o-' if len(groups) <= 12 and len(set(xs)) == len(xs) else 'o'
        ax.plot(xs, [r.get(y) for r in members], style, ms=4, alpha=0.8, label=label)
    ax.set(xlabel=x, ylabel=y, title=f'{y} against {x} ({len(ok)} cases)')
    ax.grid(True, alpha=0.3)
    if series and len(groups) <= 12:
        ax.legend(fontsize=8)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path.name


def main(argv: Optional[Sequence[str]] = None) -> int:
    argv = cli.own_args(argv)
    return cli.run(PROG, build_parser(), lambda args: _run(args, argv), argv)


def run_spec(data: dict, out: str | Path, *, workers: Optional[int] = None,
             address: Optional[str] = None, in_process: bool = False, quiet: bool = False,
             temp_dir: Optional[str] = None, name: str = '<spec>',
             here: str | Path = '.') -> int:
    """The Python API: run a spec given as data (what a spec YAML holds) into `out`, as
    `sweep` runs a file (same engine, resume, results.csv). `name` labels it in messages and
    summary.md. Returns the exit status; a spec error is printed as one line (status 2)."""
    args = argparse.Namespace(spec=name, out=str(out), workers=workers, address=address,
                              in_process=in_process, quiet=quiet, temp_dir=temp_dir,
                              max_cases=None, bags=False)
    argv = [name, '--out', str(out)] + (['--workers', str(workers)] if workers else []) + \
        (['--address', address] if address else []) + (['--in-process'] if in_process else [])
    saved = dict(os.environ)                # Ray's switches set for the run, not the caller
    try:
        return _run(args, argv, lambda: spec_from_data(data, name, Path(here)))
    except SpecError as exc:
        print(f'{PROG}: error: {exc}', file=sys.stderr)
        return 2
    finally:
        os.environ.clear()
        os.environ.update(saved)


def _run(args, argv, make_spec: Optional[Callable[[], Spec]] = None) -> int:
    for flag, value in (('--workers', args.workers), ('--max-cases', args.max_cases)):
        if value is not None and value < 1:
            raise SpecError(f'{flag} {value}: must be >= 1')
    if args.in_process and args.address:
        raise SpecError('--in-process and --address exclude each other')
    if not args.in_process:
        _ray_environment(args.address)
        try:
            import ray  # noqa: F401
        except ImportError:
            raise SpecError(INSTALL_HINT) from None
    spec = make_spec() if make_spec else load_spec(args.spec, args.max_cases)
    out = Path(args.out)
    done = _earlier_rows(out, spec)
    total = len(spec.cases)
    jobs, rows = [], {}
    for k, values in enumerate(spec.cases):
        name = case_name(k, total)
        bag = str((out / 'bags' / name).resolve()) if args.bags else ''
        row = done.get(name)
        if row is not None and row.get('status') != 'died' and (
                not bag or (os.path.isdir(bag) and not incomplete_marker(bag).exists())):
            rows[name] = row
        else:
            jobs.append(Job(k, name, values, bag))
    engine, engine_name = None, 'in-process (serial)'
    if jobs and not args.in_process:            # connect before anything is written
        _export_pythonpath()
        _probe_address(args.address)
        try:
            engine = RayEngine(args.workers, args.address, args.temp_dir)
        except KeyboardInterrupt:
            print(f'{PROG}: interrupted while starting Ray; nothing ran', file=sys.stderr)
            return 130
        except Exception as exc:  # noqa: BLE001 - Ray's errors have no common base
            first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            where = f'--address {args.address}' if args.address else 'a local Ray'
            raise SpecError(f'{where}: Ray did not start or connect: {first[:300]}') from None
        engine_name = (f'Ray {engine.ray.__version__}, {engine.workers} worker(s) on '
                       f'{engine.nodes} node(s)'
                       + (f' of {args.address}' if args.address else ' (local)'))
    out.mkdir(parents=True, exist_ok=True)
    (out / 'sweep.json').write_text(json.dumps(
        {'spec': args.spec if make_spec else os.path.abspath(args.spec),
         'digest': spec.digest, 'cases': total}) + '\n')
    progress = Progress(total, len(rows), quiet=args.quiet)
    if not args.quiet and rows:
        print(f'{PROG}: resuming: {len(rows)} of {total} cases done already', file=sys.stderr)
    rows_file = open(out / 'rows.jsonl', 'a')
    if rows_file.tell() and not (out / 'rows.jsonl').read_bytes().endswith(b'\n'):
        rows_file.write('\n')                   # a torn last line ends before new rows

    def on_row(row: dict) -> None:
        rows[row['case']] = row
        rows_file.write(json.dumps(row, sort_keys=True) + '\n')
        rows_file.flush()
        progress.update(row)

    wall0 = time.monotonic()
    interrupted = False
    try:
        if jobs:
            (engine.run if engine else run_in_process)(spec.setup, jobs, on_row)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        progress.end_line()
        rows_file.close()
        if engine is not None:
            try:
                engine.close()
            except KeyboardInterrupt:
                interrupted = True
    wall = time.monotonic() - wall0
    ordered = [rows[n] for n in (case_name(k, total) for k in range(total)) if n in rows]
    columns = columns_of(ordered, spec.setup.axes, bool(spec.setup.runner))
    write_csv(out / 'results.csv', ordered, columns)
    figure = write_figure(out / 'figure.png', ordered, spec.setup.axes, spec.plot) \
        if ordered and (spec.plot or not spec.setup.runner) else ''
    (out / 'summary.md').write_text(summary_md(args.spec, ordered, columns, total, wall,
                                               engine_name, figure, argv))
    counts = _counts(ordered)
    if interrupted:
        print(f'{PROG}: interrupted: {len(ordered)} of {total} cases done, kept in {out}; '
              'run the same command again to resume', file=sys.stderr)
        return 130
    if not args.quiet:
        print(f'{PROG}: {total} cases ({", ".join(f"{n} {s}" for s, n in counts.items() if n)}) '
              f'in {wall:.1f} s on {engine_name} -> {out}/results.csv')
    return 1 if counts['error'] or counts['died'] else 0


def _earlier_rows(out: Path, spec: Spec) -> dict:
    """The finished rows of an earlier run of `spec` in `out` (a torn last line is ignored:
    it is re-run); SpecError when `out` holds something else."""
    if out.exists() and not out.is_dir():
        raise SpecError(f'--out {out}: exists and is not a directory')
    state_path = out / 'sweep.json'
    if not state_path.exists():
        if out.exists() and any(out.iterdir()):
            raise SpecError(f'--out {out}: exists and holds no sweep; use a new or empty '
                            'directory')
        return {}
    try:
        state = json.loads(state_path.read_text())
    except (OSError, ValueError) as exc:
        raise SpecError(f'{state_path}: unreadable ({exc}); use a new --out') from None
    if state.get('digest') != spec.digest:
        raise SpecError(f'--out {out}: holds the results of a different sweep (spec '
                        f'{state.get("spec")}); use a new --out')
    rows: dict = {}
    if (out / 'rows.jsonl').exists():
        for line in (out / 'rows.jsonl').read_text().split('\n'):
            try:
                row = json.loads(line)
            except ValueError:
                continue
            if isinstance(row, dict) and 'case' in row:
                rows[row['case']] = row
    return rows


def _ray_environment(address: Optional[str]) -> None:
    """Before Ray is imported: usage statistics off (unless the user chose), and a Ray on
    this machine (or a cluster addressed on loopback) kept on 127.0.0.1 with Ray's
    single-machine switch (docs/decisions.md "Sweeps")."""
    os.environ.setdefault('RAY_USAGE_STATS_ENABLED', '0')
    host = (address or '').split('://')[-1].rsplit(':', 1)[0]
    if not address or host in ('127.0.0.1', 'localhost'):
        os.environ.setdefault('RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER', '0')


PROBE_TIMEOUT = 5.0
"""[s] How long a cluster's address may take to accept a connection (Ray itself retries for
minutes, logging each attempt)."""


def _probe_address(address: Optional[str]) -> None:
    """A HOST:PORT or ray://HOST:PORT address must accept a TCP connection: SpecError (one
    line) at once otherwise. 'auto' and a local Ray are Ray's to find."""
    import socket
    if not address or address == 'auto':
        return
    host, sep, port = address.split('://', 1)[-1].rpartition(':')
    if not sep or not port.isdigit() or not host:
        raise SpecError(f'--address {address}: expected auto, HOST:PORT or ray://HOST:PORT')
    try:
        socket.create_connection((host.strip('[]'), int(port)), timeout=PROBE_TIMEOUT).close()
    except OSError as exc:
        raise SpecError(f'--address {address}: no Ray there ({exc.strerror or exc}); start '
                        'one with `ray start --head`, or leave --address out for a local '
                        'Ray') from None


def _export_pythonpath() -> None:
    """A local Ray's workers import abd_joint_sim as this process does (they inherit the
    environment of the Ray this process starts)."""
    root = str(Path(__file__).resolve().parents[2])
    paths = os.environ.get('PYTHONPATH', '').split(os.pathsep)
    if root not in paths:
        os.environ['PYTHONPATH'] = os.pathsep.join([root] + [p for p in paths if p])


if __name__ == '__main__':
    sys.exit(main())
