"""The bench entry points (bench/*.py): each answers --help, lists its commands, refuses an
unknown command or a bad argument with one line and exit 2, and every command's module loads
and answers its own --help. Two commands run in a tiny mode, so that a bench that no longer
matches the package fails here rather than in a user's hands."""
from __future__ import annotations

import os
from pathlib import Path
import subprocess
import sys

import pytest

REPO = Path(__file__).resolve().parents[1]
ENTRIES = {'peers.py': ['chains', 'robots', 'sliding', 'sweep', 'chain-urdfs', 'regimes', 'sweeps'],
           'profiler.py': ['step', 'calls', 'perf', 'devices'],
           'node_load.py': ['rtf', 'flood', 'soak', 'markers', 'live']}


def _run(*args, timeout=300):
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    return subprocess.run([sys.executable, *map(str, args)], capture_output=True, text=True,
                          cwd=REPO, env=env, timeout=timeout)


def test_at_most_five_entry_points_each_with_help():
    entries = sorted(p.name for p in (REPO / 'bench').glob('*.py'))
    assert entries == sorted([*ENTRIES, 'ab.py'])
    for entry in entries:
        out = _run(REPO / 'bench' / entry, '--help')
        assert out.returncode == 0, out.stderr
        assert 'usage' in out.stdout.lower() or 'commands:' in out.stdout


@pytest.mark.parametrize('entry', sorted(ENTRIES))
def test_each_command_loads_and_answers_help(entry):
    listing = _run(REPO / 'bench' / entry, '--help').stdout
    for command in ENTRIES[entry]:
        assert f'  {command} ' in listing, (entry, command)
        out = _run(REPO / 'bench' / entry, command, '--help')
        assert out.returncode == 0, (command, out.stderr[-2000:])
        assert f'bench/{entry} {command}' in out.stdout, out.stdout[:300]


@pytest.mark.parametrize('args, words', [
    (['peers.py', 'nonsense'], "unknown command 'nonsense'"),
    (['peers.py'], 'commands:'),
    (['ab.py', '--other', '/nonexistent/checkout'], 'no abd_joint_sim package there'),
    (['ab.py', '--other', '.', 'chain7x'], 'unknown scene(s) chain7x'),
    (['ab.py', '--other', '.', '--rounds', '0'], '--rounds must be at least 1'),
    (['node_load.py', 'rtf', '--other', '/nonexistent/checkout'], 'no abd_joint_sim package there'),
    (['profiler.py', 'devices', 'chain7'], 'unknown scene(s) chain7'),
    (['profiler.py', 'devices', '--devices', 'slp,turbo'], 'unknown device(s) turbo'),
])
def test_bad_arguments_are_one_line_and_exit_2(args, words):
    out = _run(REPO / 'bench' / args[0], *args[1:])
    assert out.returncode == 2
    text = out.stdout + out.stderr
    assert words in text, text
    assert 'Traceback' not in text


def test_regimes_runs_in_a_tiny_mode():
    """`peers.py regimes` on a 2-link chain for 20 steps: the table has a row per case."""
    out = _run(REPO / 'bench' / 'peers.py', 'regimes', '--steps', '20', '--links', '2')
    assert out.returncode == 0, out.stderr[-2000:]
    rows = [ln for ln in out.stdout.splitlines() if ln.startswith('| ') and not ln.startswith('| link')]
    assert len(rows) >= 4, out.stdout


def test_step_profile_runs_in_a_tiny_mode():
    """`profiler.py step` on one link without the KUKA: both tables have a row of figures."""
    out = _run(REPO / 'bench' / 'profiler.py', 'step', '--links', '1', '--no-kuka')
    assert out.returncode == 0, out.stderr[-2000:]
    rows = [ln for ln in out.stdout.splitlines() if ln.startswith('| 1 |')]
    assert len(rows) == 2, out.stdout
    for row in rows:
        cells = [c.strip() for c in row.strip().strip('|').split('|')]
        assert all(float(c) == float(c) for c in cells), row       # every cell a number


def test_sliding_runs_in_a_tiny_mode():
    """`peers.py sliding` for 20 steps, one round: a row per robot with the sliding Panda's
    one prismatic joint (none on its hinge variant), and its per-body ratio to each revolute
    robot."""
    pytest.importorskip('pybullet_data')
    out = _run(REPO / 'bench' / 'peers.py', 'sliding', '--steps', '20', '--rounds', '1')
    assert out.returncode == 0, out.stderr[-2000:]
    rows = {ln.split('|')[1].strip(): [c.strip() for c in ln.strip().strip('|').split('|')]
            for ln in out.stdout.splitlines() if ln.startswith('| Panda') or ln.startswith('| KUKA')}
    assert sorted(rows) == ['KUKA iiwa', 'Panda, finger a hinge', 'Panda, finger sliding',
                            'Panda, fingers locked'], out.stdout
    assert rows['Panda, finger sliding'][1:3] == ['9', '1'] and rows['Panda, finger a hinge'][1:3] == ['9', '0']
    assert rows['Panda, fingers locked'][1:3] == ['8', '0']
    assert out.stdout.count('ours per body:') == 3, out.stdout
