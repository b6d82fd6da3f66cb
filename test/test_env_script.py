"""scripts/env.sh, against a stand-in venv whose `python` records
how it was called and exits as told: no real installation, so it runs in milliseconds."""
from __future__ import annotations

import os
from pathlib import Path
import subprocess

from conftest import REPO

STUB = """#!/bin/sh
echo "STUB $*" >> "$ABD_STUB_LOG"
echo "pip output: Collecting ..."
exit ${ABD_STUB_STATUS:-0}
"""


def _venv(tmp_path: Path) -> Path:
    venv = tmp_path / 'venv'
    (venv / 'bin').mkdir(parents=True)
    python = venv / 'bin' / 'python'
    python.write_text(STUB)
    python.chmod(0o755)
    return venv


def _source(tmp_path: Path, venv: Path, script: str, status: int = 0):
    env = dict(os.environ, ABD_VENV=str(venv), ABD_STUB_LOG=str(tmp_path / 'calls'),
               ABD_STUB_STATUS=str(status))
    env.pop('ABD_REQUIREMENTS', None)
    return subprocess.run(['bash', '-c', script], cwd=REPO, env=env, capture_output=True,
                          text=True, timeout=60)


def _calls(tmp_path: Path) -> list[str]:
    log = tmp_path / 'calls'
    return log.read_text().splitlines() if log.exists() else []


def test_says_what_it_installs_first_and_ignores_the_callers_arguments(tmp_path):
    venv = _venv(tmp_path)
    # A script run as `script.sh -k foo` that sources env.sh without arguments.
    res = _source(tmp_path, venv, 'set -- -k foo; source scripts/env.sh; echo "rc=$?"')
    assert 'rc=0' in res.stdout, res.stderr
    calls = _calls(tmp_path)
    assert calls == [f'STUB -m pip install --disable-pip-version-check -r '
                     f'{REPO}/requirements-test.txt'], calls
    err = res.stderr
    assert err.index('[env] installing the pinned wheels of requirements-test.txt') < \
        err.index('pip output: Collecting'), err
    assert list(venv.glob('.req-*'))
    # Up to date now: silent, no pip.
    res = _source(tmp_path, venv, 'source scripts/env.sh; echo "rc=$?"')
    assert 'rc=0' in res.stdout and res.stderr == '' and len(_calls(tmp_path)) == 1


def test_failed_pip_is_not_marked_up_to_date_and_returns_nonzero(tmp_path):
    venv = _venv(tmp_path)
    script = 'source scripts/env.sh requirements-test.txt; echo "rc=$?"'
    res = _source(tmp_path, venv, script, status=1)
    assert 'rc=1' in res.stdout and 'failed' in res.stderr, (res.stdout, res.stderr)
    assert not list(venv.glob('.req-*'))
    res = _source(tmp_path, venv, script, status=0)         # tries again, succeeds
    assert 'rc=0' in res.stdout and len(_calls(tmp_path)) == 2
    assert list(venv.glob('.req-*'))


def test_callers_shell_options_and_environment(tmp_path):
    venv = _venv(tmp_path)
    res = _source(tmp_path, venv, 'unset AMENT_PREFIX_PATH; set -euo pipefail; '
                                  'source scripts/env.sh; echo "opts=$-"; '
                                  'echo "range=$ROS_AUTOMATIC_DISCOVERY_RANGE"; '
                                  'source scripts/env.sh; echo "$PATH" | tr ":" "\\n" | '
                                  f'grep -c "^{venv}/bin$"')
    out = res.stdout.splitlines()
    assert {'e', 'u'} <= set(out[0].split('=')[1]), (out, res.stderr)   # options kept
    assert out[1] == 'range=LOCALHOST' and out[2] == '1', out   # PATH entry added once
    res = _source(tmp_path, venv, 'source scripts/env.sh requirements-nope.txt; echo "rc=$?"')
    assert 'rc=0' in res.stdout      # not an existing file: the default is used


def test_the_node_installs_only_its_own_requirements(tmp_path):
    """run_default.sh sources env.sh with requirements.txt: pip installs the node's wheels
    alone, not the tests' (SciPy, matplotlib, MuJoCo, PyBullet); a venv the tests set up
    (requirements-test.txt includes requirements.txt) serves the node without pip."""
    script = 'source scripts/env.sh requirements.txt; echo "rc=$?"'
    assert 'run_default' not in script and \
        'source scripts/env.sh "$ROOT/requirements.txt"' in (REPO / 'scripts' / 'run_default.sh').read_text()
    venv = _venv(tmp_path)
    res = _source(tmp_path, venv, script)
    assert 'rc=0' in res.stdout, res.stderr
    assert _calls(tmp_path) == ['STUB -m pip install --disable-pip-version-check -r '
                                'requirements.txt']
    assert '[env] installing the pinned wheels of requirements.txt' in res.stderr
    node_reqs = (REPO / 'requirements.txt').read_text()
    assert not any(name in node_reqs for name in ('scipy', 'matplotlib', 'mujoco', 'pybullet'))
    # a test venv: no pip for the node
    tmp2 = tmp_path / 'test-venv'
    tmp2.mkdir()
    venv2 = _venv(tmp2)
    _source(tmp2, venv2, 'source scripts/env.sh requirements-test.txt')
    res = _source(tmp2, venv2, script)
    assert 'rc=0' in res.stdout and res.stderr == '' and len(_calls(tmp2)) == 1


def test_heartbeat_speaks_while_the_command_is_silent(tmp_path):
    """scripts/heartbeat.py (env.sh runs venv and pip through it, 8 s): the command's output
    passes through, a line whenever it has been silent for the interval, its exit status."""
    res = subprocess.run(['python3', str(REPO / 'scripts' / 'heartbeat.py'), '[env] pip', '0.5',
                          '--', 'sh', '-c', 'echo first; sleep 1.8; echo second; exit 3'],
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 3
    lines = res.stderr.splitlines()
    assert lines[0] == 'first' and lines[-1] == 'second', lines
    beats = [line for line in lines if line.startswith('[env] pip: still running (')]
    assert 2 <= len(beats) <= 4, lines
