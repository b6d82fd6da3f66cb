"""Shared fixtures for the tests, and helpers for the real-DDS tests (sim_node in its own
process, a probe node in the test process).

DDS rules (shared/spec/ROS.md): every ROS process runs with
ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, each test gets its own ROS_DOMAIN_ID, and nothing
is published before discovery has matched. Every wait is bounded, so a hung node fails the
test instead of hanging the suite (there is no pytest-timeout here).
"""
from __future__ import annotations

import itertools
import os
from pathlib import Path
import signal
import subprocess
import sys
import time
from typing import Callable, Optional

import pytest

# Before anything can import rclpy: no DDS traffic may leave loopback.
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')

REPO = Path(__file__).resolve().parents[1]
SCENES = REPO / 'abd_joint_sim' / 'scenes'

_domain_counter = itertools.count()
_probe_counter = itertools.count()


def next_domain_id() -> int:
    """A ROS_DOMAIN_ID in 1..100 for one test, different for consecutive tests of a run and
    (by the pid) unlikely to collide with a concurrent run on the same machine."""
    return (os.getpid() * 13 + next(_domain_counter) * 37) % 100 + 1


def ros_env(domain_id: int, log_dir: Path, extra_pythonpath: Optional[str] = None) -> dict:
    env = dict(os.environ)
    env['ROS_DOMAIN_ID'] = str(domain_id)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env['ROS_LOG_DIR'] = str(log_dir)
    env['PYTHONUNBUFFERED'] = '1'
    env['RCUTILS_LOGGING_BUFFERED_STREAM'] = '0'
    env['RCUTILS_COLORIZED_OUTPUT'] = '0'
    paths = [p for p in (extra_pythonpath, str(REPO), env.get('PYTHONPATH')) if p]
    env['PYTHONPATH'] = os.pathsep.join(paths)
    return env


class NodeProcess:
    """sim_node (or any command) in its own process; output goes to a log file."""

    def __init__(self, cmd: list[str], env: dict, log_path: Path, cwd: Path = REPO):
        self.cmd = cmd
        self.log_path = log_path
        self._log = open(log_path, 'wb')
        self.proc = subprocess.Popen(cmd, env=env, cwd=str(cwd), stdout=self._log,
                                     stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)

    @classmethod
    def sim_node(cls, tmp_path: Path, domain_id: int, params: dict, name: str = 'node'):
        args = [sys.executable, '-m', 'abd_joint_sim.ros.node', '--ros-args']
        for key, value in params.items():
            args += ['-p', f'{key}:={_param_text(value)}']
        log_dir = tmp_path / f'{name}_ros_log'
        log_dir.mkdir(exist_ok=True)
        return cls(args, ros_env(domain_id, log_dir), tmp_path / f'{name}.log')

    def output(self) -> str:
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text(errors='replace')

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self, sig: int = signal.SIGINT, timeout: float = 15.0) -> int:
        """Signal the process (by PID) and wait; SIGKILL if it does not end in time."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
                self._log.close()
                raise AssertionError(
                    f'{self.cmd[:3]} did not stop within {timeout} s of signal {sig}:\n'
                    + self.output()[-3000:])
        self._log.close()
        return self.proc.returncode


def _param_text(value) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (list, tuple)):
        return '[' + ', '.join(_param_text(v) for v in value) + ']'
    if isinstance(value, str):
        return value if value else "''"
    return repr(value)


class Probe:
    """A node in the test process, in its own rclpy context on the test's domain."""

    def __init__(self, domain_id: int, name: Optional[str] = None):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        self.rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        name = name or f'probe_{os.getpid()}_{next(_probe_counter)}'
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._answered: set[int] = set()

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=min(0.05, max(end - time.monotonic(), 0.0)))

    def wait_for(self, predicate: Callable[[], bool], timeout: float, what: str,
                 log: Optional[NodeProcess] = None):
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            value = predicate()
            if value:
                return value
            self.executor.spin_once(timeout_sec=0.05)
        value = predicate()
        if value:
            return value
        tail = ('\n--- node output ---\n' + log.output()[-4000:]) if log else ''
        raise AssertionError(f'timed out after {timeout} s waiting for {what}{tail}')

    def wait_matched_subscriber(self, publisher, timeout: float = 20.0, log=None) -> None:
        self.wait_for(lambda: publisher.get_subscription_count() > 0, timeout,
                      f'a subscriber on {publisher.topic_name}', log)

    def call(self, client, request, timeout: float = 10.0, log=None,
             idempotent: Optional[bool] = None):
        """The answer of one service call.

        DDS discovery is asymmetric: the client can see the service before the service
        sees the client's answer reader, and Fast DDS then drops the answer ("failed to
        send response (timeout): client will not receive response"). A client's first
        call therefore waits a moment after the service is ready, and a call whose repeat
        changes nothing is sent again when its answer does not come. The node's ~/step is
        the one service whose repeat is not harmless (idempotent=False by default for it).
        """
        if idempotent is None:
            idempotent = not client.srv_name.endswith('/step')
        self.wait_for(lambda: client.service_is_ready(), 20.0,
                      f'service {client.srv_name}', log)
        if id(client) not in self._answered:
            self.spin_for(0.5)
        end = time.monotonic() + timeout
        sent = 0
        while time.monotonic() < end:
            future = client.call_async(request)
            sent += 1
            resend = time.monotonic() + 2.0 if idempotent else end
            while not future.done() and time.monotonic() < min(resend, end):
                self.executor.spin_once(timeout_sec=0.05)
            if future.done():
                self._answered.add(id(client))
                return future.result()
            client.remove_pending_request(future)
        tail = ('\n--- node output ---\n' + log.output()[-4000:]) if log else ''
        raise AssertionError(f'no answer of {client.srv_name} within {timeout} s '
                             f'(sent {sent} times){tail}')

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.context)


@pytest.fixture
def domain_id() -> int:
    return next_domain_id()


# ------------------------------------------------------------------ MCAP validation ----
# Every MCAP file the tests leave under pytest's temporary directory is checked by the
# official MCAP reader (@mcap/core, TypeScript; test/mcap_validator/validate.mjs): framing,
# chunk, attachment, summary and data-section CRCs, indexes against the data. The pinned
# package is installed from its package-lock.json by `npm ci` the first time it is needed.
# Tests that leave a deliberately unfinished bag (a simulated crash or full disk) say so
# with @pytest.mark.broken_bags; their files are exempt. Opt out (e.g. no node.js on a
# development machine) with ABD_SKIP_MCAP_VALIDATION=1; CI never sets it.
MCAP_VALIDATOR = REPO / 'test' / 'mcap_validator'
_MCAP_MAGIC = b'\x89MCAP0\r\n'
_checked: dict[Path, tuple[int, int]] = {}
_exempt: set[Path] = set()


def pytest_configure(config):
    config.addinivalue_line(
        'markers', 'broken_bags: the test leaves unfinished or damaged MCAP files on purpose '
        '(they are not validated)')


def _install_validator() -> str:
    """Path of node.js, with the validator's pinned packages installed (npm ci)."""
    import shutil
    node, npm = shutil.which('node'), shutil.which('npm')
    if node is None or npm is None:
        raise RuntimeError('node.js/npm not found: the MCAP validator (test/mcap_validator) '
                           'needs them (or set ABD_SKIP_MCAP_VALIDATION=1 to skip it)')
    lock = MCAP_VALIDATOR / 'package-lock.json'
    installed = MCAP_VALIDATOR / 'node_modules' / '.package-lock.json'
    if not installed.is_file() or installed.stat().st_mtime < lock.stat().st_mtime:
        # --ignore-scripts: no package install script is needed to read MCAP.
        result = subprocess.run([npm, 'ci', '--no-audit', '--no-fund', '--ignore-scripts'],
                                cwd=MCAP_VALIDATOR, capture_output=True, text=True,
                                timeout=600, stdin=subprocess.DEVNULL)
        if result.returncode != 0:
            raise RuntimeError(f'npm ci in {MCAP_VALIDATOR} failed:\n{result.stderr[-2000:]}')
    return node


_node_path: list[str] = []


def validate_mcap(files) -> list[dict]:
    """Run the @mcap/core validator on `files`; one result dict per file
    ({'file', 'ok', 'errors', 'messages', ...})."""
    import json
    files = [str(f) for f in files]
    if not files:
        return []
    if not _node_path:
        _node_path.append(_install_validator())
    result = subprocess.run([_node_path[0], str(MCAP_VALIDATOR / 'validate.mjs'), *files],
                            capture_output=True, text=True, timeout=300,
                            stdin=subprocess.DEVNULL)
    out = [json.loads(line) for line in result.stdout.splitlines() if line.startswith('{')]
    if len(out) != len(files):
        raise RuntimeError(f'MCAP validator gave {len(out)} results for {len(files)} files:\n'
                           f'{result.stdout[-2000:]}\n{result.stderr[-2000:]}')
    return out


def _unchecked_bags(root: Path, finished_only: bool) -> list[Path]:
    found = []
    for path in sorted(root.rglob('*.mcap')):
        if path in _exempt or any(parent in _exempt for parent in path.parents):
            continue
        stat = path.stat()
        key = (stat.st_size, stat.st_mtime_ns)
        if _checked.get(path) == key:
            continue
        if finished_only:   # a node of a module fixture may still be recording into it
            with open(path, 'rb') as handle:
                handle.seek(max(stat.st_size - len(_MCAP_MAGIC), 0))
                if handle.read() != _MCAP_MAGIC:
                    continue
        found.append(path)
    return found


def _check_bags(root: Path, finished_only: bool) -> None:
    files = _unchecked_bags(root, finished_only)
    bad = []
    for result in validate_mcap(files):
        path = Path(result['file'])
        stat = path.stat()
        _checked[path] = (stat.st_size, stat.st_mtime_ns)
        if not result['ok']:
            bad.append(f"{path}: {'; '.join(result['errors'])}")
    if bad:
        pytest.fail('MCAP validator (@mcap/core) rejects:\n' + '\n'.join(bad), pytrace=False)


@pytest.fixture(scope='session')
def _bag_root(tmp_path_factory):
    root = tmp_path_factory.getbasetemp()
    yield root
    if os.environ.get('ABD_SKIP_MCAP_VALIDATION') != '1':
        _check_bags(root, finished_only=False)     # also bags no test saw finished


@pytest.fixture(autouse=True)
def _validate_bags(request, _bag_root):
    """After each test: every finished MCAP file not checked yet passes @mcap/core."""
    if request.node.get_closest_marker('broken_bags') and 'tmp_path' in request.fixturenames:
        _exempt.add(Path(request.getfixturevalue('tmp_path')))
    yield
    if os.environ.get('ABD_SKIP_MCAP_VALIDATION') != '1':
        _check_bags(_bag_root, finished_only=True)
