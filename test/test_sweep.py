"""The sweep command (abd_joint_sim/tools/sweep.py) on a real Ray: a local Ray of its own, and
a two-node cluster on loopback started here with `ray start` (one module-scoped cluster for
the tests of this file: a Ray node takes ~10 s to start on this machine). Every Ray process
this file starts lives under its own --temp-dir and is stopped by PID at the end (other Ray
instances on the machine are never touched). Bad specs: one line each, nothing started."""
from __future__ import annotations

import csv
import json
import os
from pathlib import Path
import signal
import socket
import subprocess
import sys
import tempfile
import time

import pytest

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from abd_joint_sim.tools import sweep  # noqa: E402

pytest.importorskip('ray', reason='the sweep engine (requirements-sweep.txt) is not installed')

# Ray's CLI replaces a node address of 127.0.0.1 by the machine's routable address (its
# servers then listen on every interface); this runs the same CLI with the loopback address
# kept, so the test cluster's servers listen on 127.0.0.1 only.
RAY_CLI = ('import sys; import ray._private.services as s; import ray.scripts.scripts as c; '
           's.resolve_ip_for_localhost = lambda host: host; sys.argv[0] = "ray"; '
           'sys.exit(c.main())')

SPEC = """\
scene: default
duration: 0.05
grid:
  dt: [0.002, 0.001]
  joints.shoulder.external_torque.torque: [0.5, 2.0]
random:
  n: 2
  seed: 11
  uniform: {bodies.forearm.density: [800.0, 1500.0]}
  choice: {joints.elbow.external_torque.torque: [-1.0, 1.0]}
"""

# A joint 1e8 times weaker than the default, its arm flung at 1e4 m/s: it comes apart
# (SimulationError) within a few steps; the default strength holds it.
FAULT_SPEC = """\
scene: hinge
duration: 0.1
grid:
  joints.hinge.strength_ratio: [100.0, 1.0e-6, 50.0]
  bodies.arm.velocity: [[10000.0, 0.0, 0.0]]
"""

LONG_SPEC = """\
scene: default
duration: 4.0
schedule:
  events:
    - {t: 0.0, torque: {shoulder: 1.0, elbow: -0.5}}
    - {t: 0.5, torque: {shoulder: -1.0}}
grid:
  bodies.forearm.density: [1000.0, 1500.0, 2000.0, 2500.0, 3000.0, 3500.0, 4000.0, 4500.0]
"""


def _env(**extra) -> dict:
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(p for p in (str(REPO), env.get('PYTHONPATH')) if p)
    env['RAY_USAGE_STATS_ENABLED'] = '0'
    env['RAY_AUTH_MODE'] = 'disabled'       # a loopback-only test cluster: no token file
    # a worker node joins only where Ray's cluster switch is on (its default on Linux)
    env.pop('RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER', None)
    env['PYTHONUNBUFFERED'] = '1'
    env.update(extra)
    return env


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def _pids_under(temp_dir: str) -> list[int]:
    """PIDs of the processes of the Ray whose --temp-dir is `temp_dir`, and their children."""
    procs = {}
    for entry in Path('/proc').iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmd = (entry / 'cmdline').read_bytes().replace(b'\0', b' ').decode(errors='replace')
            ppid = int((entry / 'stat').read_text().rsplit(')', 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            continue
        procs[int(entry.name)] = (ppid, cmd)
    ours = {pid for pid, (_, cmd) in procs.items() if temp_dir in cmd}
    grew = True
    while grew:
        kids = {pid for pid, (ppid, _) in procs.items() if ppid in ours} - ours
        grew = bool(kids)
        ours |= kids
    return sorted(ours)


def _stop(temp_dir: str) -> None:
    """Stop this Ray's processes by PID: SIGTERM, then SIGKILL what is left after 5 s."""
    for sig, wait in ((signal.SIGTERM, 5.0), (signal.SIGKILL, 2.0)):
        pids = _pids_under(temp_dir)
        for pid in pids:
            try:
                os.kill(pid, sig)
            except ProcessLookupError:
                pass
        deadline = time.monotonic() + wait
        while _pids_under(temp_dir) and time.monotonic() < deadline:
            time.sleep(0.2)


def _ray_start(args: list, env: dict, log: Path) -> None:
    with open(log, 'ab') as f:
        proc = subprocess.run([sys.executable, '-c', RAY_CLI, 'start', *args], env=env,
                              stdout=f, stderr=subprocess.STDOUT, timeout=180, cwd=REPO)
    assert proc.returncode == 0, log.read_text()[-2000:]


@pytest.fixture(scope='module')
def cluster(tmp_path_factory):
    """A two-node Ray cluster on 127.0.0.1, one CPU per node: `ray start --head`, then a
    second `ray start --address` worker node. Yields the address."""
    temp_dir = tempfile.mkdtemp(prefix='rs-')      # short: Ray's socket paths must fit
    logs = tmp_path_factory.mktemp('ray-logs')
    port = _free_port()
    env = _env()
    try:
        _ray_start(['--head', '--node-ip-address=127.0.0.1', f'--port={port}', '--num-cpus=1',
                    '--include-dashboard=false', f'--dashboard-port={_free_port()}',
                    f'--temp-dir={temp_dir}', '--disable-usage-stats'], env, logs / 'head.log')
        _ray_start([f'--address=127.0.0.1:{port}', '--node-ip-address=127.0.0.1',
                    '--num-cpus=1', f'--temp-dir={temp_dir}', '--disable-usage-stats'],
                   env, logs / 'worker.log')
        yield f'127.0.0.1:{port}'
    finally:
        _stop(temp_dir)
        assert not _pids_under(temp_dir), 'Ray processes of the test cluster still running'
        subprocess.run(['rm', '-rf', temp_dir])


def _sweep(spec: Path, out: Path, *args, timeout: float = 300.0, **popen):
    return subprocess.run([sys.executable, '-m', 'abd_joint_sim.tools.sweep', str(spec),
                           '--out', str(out), *args], env=_env(), cwd=REPO,
                          capture_output=True, text=True, timeout=timeout, **popen)


def _rows(out: Path) -> list[dict]:
    with open(out / 'results.csv', newline='') as f:
        return list(csv.DictReader(f))


def _without_wall(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k != 'wall_s'} for r in rows]


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _bag_bytes(out: Path) -> dict:
    return {p.relative_to(out): p.read_bytes() for p in sorted((out / 'bags').rglob('*'))
            if p.is_file()}


# ------------------------------------------------------------------ on Ray ----
@pytest.fixture(scope='module')
def reference(tmp_path_factory):
    """The small sweep serially in-process, with bags: the rows and bags every engine and
    worker count must reproduce."""
    tmp = tmp_path_factory.mktemp('reference')
    spec = _write(tmp, 'spec.yaml', SPEC)
    proc = _sweep(spec, tmp / 'out', '--in-process', '--bags')
    assert proc.returncode == 0, proc.stderr
    return spec, tmp / 'out'


@pytest.mark.slow
def test_grid_and_random_sweep_gives_one_row_per_case(reference):
    spec, out = reference
    rows = _rows(out)
    assert len(rows) == 2 * 2 * 2                      # grid 2 x 2, crossed with n = 2
    assert [r['case'] for r in rows] == [f'case_{k:04d}' for k in range(8)]
    assert all(r['status'] == 'ok' for r in rows), rows
    for column in ('dt', 'joints.shoulder.external_torque.torque', 'bodies.forearm.density',
                   'joints.elbow.external_torque.torque', 'angle.shoulder', 'velocity.elbow',
                   'energy_drift', 'max_joint_separation', 'newton_mean', 'newton_max',
                   'substep_steps', 'wall_s'):
        assert column in rows[0]
    # the grid is crossed, the random samples repeat (seeded) in every grid cell
    assert [float(r['dt']) for r in rows] == [0.002] * 4 + [0.001] * 4
    densities = [r['bodies.forearm.density'] for r in rows]
    assert densities[:2] == densities[2:4] == densities[4:6] and densities[0] != densities[1]
    assert all(800.0 <= float(d) <= 1500.0 for d in densities)
    assert int(rows[0]['steps']) == 25 and int(rows[4]['steps']) == 50
    # the torque axis reaches the physics: the shoulder turns further with 2 N m than 0.5
    assert float(rows[2]['angle.shoulder']) > float(rows[0]['angle.shoulder']) + 1e-3
    summary = (out / 'summary.md').read_text()
    assert '8 of 8 cases: 8 ok' in summary and (out / 'figure.png').stat().st_size > 1000


@pytest.mark.slow
def test_rows_and_bags_are_identical_on_1_and_2_workers_and_on_local_ray(reference, cluster,
                                                                          tmp_path):
    spec, ref = reference
    expected, bags = _without_wall(_rows(ref)), _bag_bytes(ref)
    one = _sweep(spec, tmp_path / 'one', '--address', cluster, '--workers', '1', '--bags')
    assert one.returncode == 0, one.stderr
    assert '1 worker(s) on 2 node(s)' in one.stdout
    local = _sweep(spec, tmp_path / 'local', '--workers', '2', '--bags')
    assert local.returncode == 0, local.stderr
    assert '2 worker(s) on 1 node(s) (local)' in local.stdout
    for out in (tmp_path / 'one', tmp_path / 'local'):
        assert _without_wall(_rows(out)) == expected
        assert _bag_bytes(out) == bags                 # bit-identical, metadata.yaml included
    # the local Ray of the sweep is gone with it
    assert not [p for p in _pids_under(tempfile.gettempdir() + '/ray-sweep-')]


@pytest.mark.slow
def test_two_node_cluster_runs_a_case_on_each_node(reference, cluster, tmp_path):
    """One CPU per node and two workers of one CPU each: one worker on each node."""
    spec, ref = reference
    proc = _sweep(spec, tmp_path / 'two', '--address', cluster, '--workers', '2')
    assert proc.returncode == 0, proc.stderr
    assert '2 worker(s) on 2 node(s)' in proc.stdout
    assert _without_wall(_rows(tmp_path / 'two')) == _without_wall(_rows(ref))


@pytest.mark.slow
def test_bags_of_a_sweep_replay(reference):
    from abd_joint_sim.tools.replay_check import replay
    _, out = reference
    bags = sorted(p for p in (out / 'bags').iterdir() if p.is_dir())
    assert len(bags) == 8 and not list((out / 'bags').glob('*.incomplete'))
    for bag in (bags[0], bags[-1]):
        result = replay(str(bag))
        assert result.ok, (bag, result)


@pytest.mark.slow
def test_a_faulting_case_is_a_row_and_the_others_finish(cluster, tmp_path):
    spec = _write(tmp_path, 'fault.yaml', FAULT_SPEC)
    proc = _sweep(spec, tmp_path / 'out', '--address', cluster, '--bags')
    assert proc.returncode == 0, proc.stderr             # a fault is a result
    rows = _rows(tmp_path / 'out')
    assert [r['status'] for r in rows] == ['ok', 'fault', 'ok']
    assert "joint 'hinge' came apart" in rows[1]['message']
    assert float(rows[1]['sim_time']) < 0.1 and float(rows[0]['sim_time']) == pytest.approx(0.1)
    assert '2 ok, 1 fault' in (tmp_path / 'out' / 'summary.md').read_text().replace(
        '3 of 3 cases: ', '')
    # the faulted case's bag is closed and readable up to the fault
    from abd_joint_sim.tools.replay_check import replay
    assert replay(str(tmp_path / 'out' / 'bags' / 'case_0001')).ok


@pytest.mark.slow
def test_ctrl_c_keeps_finished_cases_and_a_rerun_resumes(cluster, tmp_path):
    spec = _write(tmp_path, 'long.yaml', LONG_SPEC)
    out = tmp_path / 'out'
    proc = subprocess.Popen([sys.executable, '-m', 'abd_joint_sim.tools.sweep', str(spec),
                             '--out', str(out), '--address', cluster, '--workers', '1',
                             '--bags'], env=_env(), cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and proc.poll() is None:
            rows = out / 'rows.jsonl'
            if rows.exists() and len(rows.read_text().splitlines()) >= 2:
                break
            time.sleep(0.1)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    assert 'interrupted' in err and 'run the same command again to resume' in err
    done = len((out / 'rows.jsonl').read_text().splitlines())
    assert 2 <= done < 8
    assert len(_rows(out)) == done                       # results.csv has the finished rows
    # no half-written bag without its marker: a bag without one is complete (a case that
    # finished as the sweep stopped may have a complete bag and no row: it runs again)
    from abd_joint_sim.tools.replay_check import replay
    for bag in (p for p in (out / 'bags').iterdir() if p.is_dir()):
        if not Path(str(bag) + '.incomplete').exists():
            assert replay(str(bag)).ok, bag

    again = _sweep(spec, out, '--address', cluster, '--workers', '1', '--bags')
    assert again.returncode == 0, again.stderr
    assert f'resuming: {done} of 8 cases done already' in again.stderr
    rows = _rows(out)
    assert len(rows) == 8 and all(r['status'] == 'ok' for r in rows)
    # finished cases were not run again: one line each in rows.jsonl
    lines = [json.loads(x)['case'] for x in (out / 'rows.jsonl').read_text().splitlines()]
    assert sorted(lines) == [f'case_{k:04d}' for k in range(8)]
    assert not list((out / 'bags').glob('*.incomplete'))
    assert replay(str(out / 'bags' / f'case_{done:04d}')).ok   # the one re-run from scratch


@pytest.mark.slow
def test_a_worker_that_dies_is_replaced_and_its_case_retried(cluster, tmp_path):
    spec = _write(tmp_path, 'long.yaml', LONG_SPEC)
    out = tmp_path / 'out'
    proc = subprocess.Popen([sys.executable, '-m', 'abd_joint_sim.tools.sweep', str(spec),
                             '--out', str(out), '--address', cluster, '--workers', '2'],
                            env=_env(), cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    killed = None
    try:
        deadline = time.monotonic() + 240
        while killed is None and time.monotonic() < deadline and proc.poll() is None:
            for entry in Path('/proc').iterdir():
                try:
                    cmd = (entry / 'cmdline').read_bytes()
                except OSError:
                    continue
                if cmd.startswith(b'ray::CaseWorker.run'):
                    os.kill(int(entry.name), signal.SIGKILL)
                    killed = int(entry.name)
                    break
            time.sleep(0.05)
        out_text, err = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert killed is not None, 'no running case found to kill'
    assert proc.returncode == 0, err
    rows = _rows(out)
    assert len(rows) == 8 and all(r['status'] == 'ok' for r in rows), rows


# ------------------------------------------------------------- bad specs ----
BAD = {
    'unknown_joint': ('grid:\n  joints.wrist.external_torque.torque: [1.0]\n',
                      "case 0 (joints.wrist.external_torque.torque = 1.0): "
                      "joints.wrist.external_torque.torque: unknown path: no item named 'wrist'"),
    'unknown_field': ('grid:\n  bodies.forearm.colour: [1.0]\n',
                      "case 0 (bodies.forearm.colour = 1.0): ", "unknown key(s) 'colour'"),
    'empty_axis': ('grid:\n  dt: []\n', 'grid.dt: empty list'),
    'out_of_range': ('grid:\n  dt: [0.001, 5.0]\n',
                     'case 1 (dt = 5.0): ', 'dt: 5.0 is outside the supported range'),
    'wrong_value': ('grid: {integrator: [bdf1, rk4]}\n',
                    "case 1 (integrator = 'rk4'): ", "integrator: must be one of"),
    'schedule_joint': ('schedule:\n  events:\n    - {t: 0.0, torque: {wrist: 1.0}}\n',
                       'case 0: ', 'wrist'),
    'too_many': ('grid:\n  joints.shoulder.external_torque.torque: [%s]\n'
                 '  joints.elbow.external_torque.torque: [%s]\n'
                 % (', '.join(str(k / 1e3) for k in range(1000)),
                    ', '.join(str(k / 1e3) for k in range(1000))),
                 '1000000 cases asked, more than the cap of 10000'),
    'unseeded': ('random: {n: 3, uniform: {dt: [0.001, 0.002]}}\n', 'random.seed'),
    'unknown_key': ('grids: {dt: [0.001]}\n', 'grids: unknown key'),
    'through_a_value': ('grid:\n  dt.x: [1.0]\n', 'dt.x: unknown path: dt is a value'),
    'robot_on_a_yaml': ('grid:\n  robot.fixed_base: [true]\n',
                        'robot.fixed_base: unknown path: the scene has no robot: block'),
}


@pytest.mark.parametrize('name', sorted(BAD))
def test_a_bad_spec_is_one_line_and_nothing_runs(name, tmp_path, capsys):
    body, *wanted = BAD[name]
    spec = _write(tmp_path, 'spec.yaml', 'scene: default\nduration: 0.1\n' + body)
    out = tmp_path / 'out'
    assert sweep.main([str(spec), '--out', str(out), '--in-process']) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('sweep: error: '), captured.err
    for text in wanted:
        assert text in lines[0], lines[0]
    assert not out.exists() and not captured.out


def test_a_urdf_that_does_not_load_is_one_line(tmp_path, capsys):
    _write(tmp_path, 'broken.urdf', '<robot name="x"><link name="a"></robot')
    spec = _write(tmp_path, 'spec.yaml', 'scene: broken.urdf\nduration: 0.1\n'
                                         'grid: {dt: [0.001]}\n')
    assert sweep.main([str(spec), '--out', str(tmp_path / 'out'), '--in-process']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'broken.urdf' in err[0] and 'case 0 (dt = 0.001)' in err[0], err
    assert not (tmp_path / 'out').exists()


def test_the_cap_is_configurable(tmp_path, capsys):
    spec = _write(tmp_path, 'spec.yaml', 'scene: hinge\nduration: 0.02\n'
                                         'grid: {dt: [0.01, 0.005, 0.002]}\n')
    assert sweep.main([str(spec), '--out', str(tmp_path / 'a'), '--in-process',
                       '--max-cases', '2']) == 2
    assert '3 cases asked, more than the cap of 2' in capsys.readouterr().err
    assert sweep.main([str(spec), '--out', str(tmp_path / 'b'), '--in-process', '-q',
                       '--max-cases', '3']) == 0
    assert len(_rows(tmp_path / 'b')) == 3


def test_the_duration_defaults_to_the_schedules(tmp_path, capsys):
    """No `duration:` in the spec: the schedule's `duration` (inline or a file) is the
    case's; a schedule without one is one line naming the missing duration."""
    schedule = "{duration: 0.03, events: [{t: 0.0, torque: {hinge: 1.0}}]}"
    _write(tmp_path, 'cmds.yaml', schedule + '\n')
    for name, value in (('inline', schedule), ('file', 'cmds.yaml')):
        spec = _write(tmp_path, f'{name}.yaml', f'scene: hinge\nschedule: {value}\n'
                                                'grid: {dt: [0.01]}\n')
        assert sweep.main([str(spec), '--out', str(tmp_path / name), '--in-process', '-q']) == 0
        (row,) = _rows(tmp_path / name)
        assert row['status'] == 'ok' and float(row['sim_time']) == pytest.approx(0.03)
    spec = _write(tmp_path, 'none.yaml', 'scene: hinge\nschedule: {events: []}\n')
    assert sweep.main([str(spec), '--out', str(tmp_path / 'none'), '--in-process']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'duration: missing' in err[0], err


def test_urdf_scene_paths_robot_options_and_joints(tmp_path):
    """A URDF base scene: `robot.initial_positions.<joint>` (a URDF option) and
    `joints.<joint>.external_torque.torque` (the lowered scene) both reach the run."""
    spec = _write(tmp_path, 'spec.yaml', f"""\
scene: {REPO}/abd_joint_sim/robots/demo_arm.urdf
urdf_options: {{gravity: [0.0, 0.0, 0.0]}}
duration: 0.01
grid:
  robot.initial_positions.elbow: [0.0, 0.4]
  joints.shoulder_pan.external_torque.torque: [0.0, 0.5]
""")
    assert sweep.main([str(spec), '--out', str(tmp_path / 'out'), '--in-process', '-q']) == 0
    rows = _rows(tmp_path / 'out')
    assert [r['status'] for r in rows] == ['ok'] * 4
    assert float(rows[0]['angle.elbow']) == pytest.approx(0.0, abs=1e-6)
    assert float(rows[2]['angle.elbow']) == pytest.approx(0.4, abs=1e-3)
    assert float(rows[0]['angle.shoulder_pan']) == pytest.approx(0.0, abs=1e-9)
    assert float(rows[1]['angle.shoulder_pan']) > 1e-6


def test_without_ray_the_command_says_how_to_install_it(tmp_path):
    stub = tmp_path / 'stub' / 'ray'
    stub.mkdir(parents=True)
    (stub / '__init__.py').write_text('raise ImportError("No module named ray")\n')
    spec = _write(tmp_path, 'spec.yaml', 'scene: hinge\nduration: 0.02\n')
    proc = subprocess.run([sys.executable, '-m', 'abd_joint_sim.tools.sweep', str(spec),
                           '--out', str(tmp_path / 'out')], cwd=REPO, capture_output=True,
                          text=True, timeout=120,
                          env=_env(PYTHONPATH=os.pathsep.join([str(tmp_path / 'stub'),
                                                               str(REPO)])))
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and 'pip install -r requirements-sweep.txt' in lines[0], proc.stderr
    assert not (tmp_path / 'out').exists()


def test_help():
    proc = subprocess.run([sys.executable, '-m', 'abd_joint_sim.tools.sweep', '--help'],
                          cwd=REPO, capture_output=True, text=True, timeout=60, env=_env())
    assert proc.returncode == 0 and '--workers' in proc.stdout and '--address' in proc.stdout


def test_progress_is_one_line_per_tenth_off_a_terminal():
    import io
    stream = io.StringIO()
    progress = sweep.Progress(40, 0, stream=stream)
    for k in range(40):
        progress.update({'status': 'ok' if k != 3 else 'fault'})
    lines = stream.getvalue().splitlines()
    assert len(lines) == 10 and lines[0].startswith('sweep: 10% 4/40 cases, 1 failed')
    assert lines[-1].startswith('sweep: 100% 40/40 cases, 1 failed')


def test_figure_of_list_valued_and_chosen_axes(tmp_path):
    """A list-valued axis (a velocity) is no series; `plot:` picks the axes and the column;
    a `plot:` naming no axis is refused before anything runs."""
    spec = _write(tmp_path, 'spec.yaml', """\
scene: hinge
duration: 0.02
grid:
  bodies.arm.velocity: [[0.0, 0.0, 0.0], [0.0, 0.1, 0.0]]
  joints.hinge.external_torque.torque: [0.5, 1.0]
plot: {x: joints.hinge.external_torque.torque, y: energy_drift}
""")
    assert sweep.main([str(spec), '--out', str(tmp_path / 'out'), '--in-process', '-q']) == 0
    assert (tmp_path / 'out' / 'figure.png').stat().st_size > 1000
    assert '![figure.png](figure.png)' in (tmp_path / 'out' / 'summary.md').read_text()
    bad = _write(tmp_path, 'bad.yaml', spec.read_text().replace('y: energy_drift',
                                                                'y: energy'))
    assert sweep.main([str(bad), '--out', str(tmp_path / 'bad'), '--in-process']) == 2
    assert not (tmp_path / 'bad').exists()


def test_two_runs_write_the_same_bag_bytes(tmp_path):
    """The bag of a case does not depend on when it is written (attachment time, wall-clock
    diagnostics): two runs a moment apart give the same files."""
    spec = _write(tmp_path, 'spec.yaml', 'scene: hinge\nduration: 1.2\n'
                                         'grid: {joints.hinge.external_torque.torque: [0.5]}\n')
    for name in ('a', 'b'):
        assert sweep.main([str(spec), '--out', str(tmp_path / name), '--in-process', '-q',
                           '--bags']) == 0
        time.sleep(0.01)
    a, b = _bag_bytes(tmp_path / 'a'), _bag_bytes(tmp_path / 'b')
    assert a and a == b


@pytest.mark.slow
def test_an_address_with_no_ray_is_one_line_at_once(tmp_path):
    spec = _write(tmp_path, 'spec.yaml', 'scene: hinge\nduration: 0.02\n')
    t0 = time.monotonic()
    proc = _sweep(spec, tmp_path / 'out', '--address', f'127.0.0.1:{_free_port()}',
                  timeout=120)
    assert proc.returncode == 2 and time.monotonic() - t0 < 60
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and 'no Ray there' in lines[0], proc.stderr
    assert not (tmp_path / 'out').exists()
