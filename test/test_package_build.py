"""colcon builds the package into a temporary install space; sim_node is resolved through
the ament index exactly as ``ros2 run abd_joint_sim sim_node`` does, started with the
installed config file (as ``ros2 launch abd_joint_sim sim.launch.py`` passes it), seen on
/joint_states over DDS, and stopped by PID with SIGINT."""
from __future__ import annotations

import os
from pathlib import Path
import py_compile
import signal
import subprocess
import sys

import pytest
import yaml

from conftest import NodeProcess, Probe, REPO, next_domain_id, ros_env

PKG = 'abd_joint_sim'


@pytest.fixture(scope='module')
def install(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp('colcon')
    cmd = ['colcon', '--log-base', str(tmp / 'log'), 'build', '--base-paths', str(REPO),
           '--build-base', str(tmp / 'build'), '--install-base', str(tmp / 'install'),
           '--event-handlers', 'console_cohesion-', 'status-', 'terminal_title-']
    proc = subprocess.run(cmd, cwd=str(tmp), capture_output=True, text=True, timeout=300,
                          stdin=subprocess.DEVNULL)
    assert proc.returncode == 0, f'colcon build failed:\n{proc.stdout}\n{proc.stderr}'
    return tmp / 'install'


def _site_packages(prefix: Path) -> Path:
    return prefix / 'lib' / f'python{sys.version_info[0]}.{sys.version_info[1]}' / 'site-packages'


def test_install_layout(install):
    prefix = install / PKG
    share = prefix / 'share' / PKG
    assert (prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' / PKG).is_file()
    for rel in ('package.xml', 'launch/sim.launch.py', 'config/sim.yaml',
                'scenes/default.yaml', 'scenes/hinge.yaml'):
        assert (share / rel).is_file(), rel
    assert os.access(prefix / 'lib' / PKG / 'sim_node', os.X_OK)
    assert os.access(prefix / 'lib' / PKG / 'plot_bag', os.X_OK)
    assert (_site_packages(prefix) / PKG / 'scenes' / 'default.yaml').is_file()
    assert (_site_packages(prefix) / PKG / 'ros' / 'node.py').is_file()
    py_compile.compile(str(share / 'launch' / 'sim.launch.py'), doraise=True)
    # The config file names only declared parameters, under the node's name.
    from abd_joint_sim.ros.params import PARAMS
    config = yaml.safe_load((share / 'config' / 'sim.yaml').read_text())
    params = config[PKG]['ros__parameters']
    assert set(params) <= {p.name for p in PARAMS}, set(params) - {p.name for p in PARAMS}


@pytest.mark.slow
def test_ros2_run_resolution_and_joint_states(install, tmp_path):
    prefix = install / PKG
    domain = next_domain_id()
    env = ros_env(domain, tmp_path, extra_pythonpath=str(_site_packages(prefix)))
    # Only the install space, not the source tree, provides the package.
    env['PYTHONPATH'] = os.pathsep.join(
        p for p in env['PYTHONPATH'].split(os.pathsep) if Path(p).resolve() != REPO)
    env['AMENT_PREFIX_PATH'] = os.pathsep.join(
        [str(prefix)] + [p for p in env.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p])
    # What `ros2 run` does: get_package_prefix(pkg) / lib / pkg / executable.
    lookup = subprocess.run(
        [sys.executable, '-c',
         'from ament_index_python.packages import get_package_prefix, '
         'get_package_share_directory as s; '
         f'print(get_package_prefix("{PKG}")); print(s("{PKG}"))'],
        env=env, capture_output=True, text=True, timeout=60, cwd=str(tmp_path))
    assert lookup.returncode == 0, lookup.stderr
    found_prefix, share = lookup.stdout.split()
    assert Path(found_prefix) == prefix
    exe = Path(found_prefix) / 'lib' / PKG / 'sim_node'
    config = Path(share) / 'config' / 'sim.yaml'
    node = NodeProcess([str(exe), '--ros-args', '--params-file', str(config),
                        '-p', 'real_time_factor:=0'], env, tmp_path / 'node.log', cwd=tmp_path)
    probe = Probe(domain)
    try:
        from sensor_msgs.msg import JointState
        states = []
        probe.node.create_subscription(JointState, '/joint_states', states.append, 10)
        probe.wait_for(lambda: len(states) >= 3, 60.0, '3 messages on /joint_states', node)
        assert list(states[-1].name) == ['shoulder', 'elbow']
        out = node.output()
        # The installed copy ran, with the scene from the install space.
        assert str(_site_packages(prefix) / PKG / 'scenes' / 'default.yaml') in out, out[-2000:]
        rc = node.stop(signal.SIGINT)
        assert rc == 0, f'exit status {rc} after SIGINT:\n{node.output()[-3000:]}'
    finally:
        probe.close()
        if node.alive():
            node.stop(signal.SIGKILL)


def test_bad_scene_fails_with_one_clear_line(install, tmp_path):
    exe = install / PKG / 'lib' / PKG / 'sim_node'
    env = ros_env(next_domain_id(), tmp_path, extra_pythonpath=str(_site_packages(install / PKG)))
    proc = subprocess.run([str(exe), '--ros-args', '-p', f'scene:={tmp_path}/missing.yaml'],
                          env=env, capture_output=True, text=True, timeout=60,
                          stdin=subprocess.DEVNULL, cwd=str(tmp_path))
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert 'cannot start' in proc.stderr and 'missing.yaml' in proc.stderr
    assert 'Traceback' not in proc.stderr


def _run_default(args, ws: Path, tmp_path: Path, name: str) -> str:
    """scripts/run_default.sh ARGS with its build under ws; its output once the node's
    start-up line is there (then the node is stopped with SIGINT, by PID)."""
    import time
    env = ros_env(next_domain_id(), tmp_path)
    env['ABD_BUILD_ROOT'] = str(ws)
    env['ABD_VENV'] = sys.prefix                 # the venv these tests run in
    node = NodeProcess(['bash', str(REPO / 'scripts' / 'run_default.sh'), *args], env,
                       tmp_path / f'{name}.log', cwd=tmp_path)
    try:
        deadline = time.monotonic() + 240
        while 'not simulated: contact' not in node.output():
            assert node.alive(), node.output()[-3000:]
            assert time.monotonic() < deadline, node.output()[-3000:]
            time.sleep(0.2)
        rc = node.stop(signal.SIGINT)
        assert rc == 0, f'exit status {rc} after SIGINT:\n{node.output()[-3000:]}'
    finally:
        if node.alive():
            node.stop(signal.SIGKILL)
    return node.output()


@pytest.mark.slow
def test_run_default_builds_only_when_needed_and_records_only_when_asked(tmp_path):
    """The README's first command: colcon builds the install space the first time and not
    again while nothing changed; `--no-record` runs without a bag, `-p record:=DIR` records
    there; neither makes the node warn that `record` was given twice."""
    ws = tmp_path / 'ws'
    out = _run_default(['--no-record', '--ros-args', '-p', 'real_time_factor:=0'], ws,
                       tmp_path, 'first')
    assert '[run_default] colcon build ->' in out and 'recording off' in out, out[-3000:]
    assert 'more than once' not in out and not (ws / 'bags').exists()
    bag = tmp_path / 'my_bag'
    out = _run_default(['--ros-args', '-p', f'record:={bag}', '-p', 'real_time_factor:=0'], ws,
                       tmp_path, 'second')
    assert 'install space up to date' in out and 'colcon build ->' not in out, out[-3000:]
    assert f'recording {bag}' in out and 'more than once' not in out, out[-3000:]
    assert (bag / 'metadata.yaml').is_file()
    # an edited package file: built again
    (ws / 'install' / '.abd-built').write_text('another tree\n')
    out = _run_default(['--ros-args', '-p', 'real_time_factor:=0'], ws, tmp_path, 'third')
    assert '[run_default] colcon build ->' in out and 'recording ' + str(ws / 'bags') in out
