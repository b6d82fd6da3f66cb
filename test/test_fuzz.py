"""Seeded random bad input against the public entry points: every mutation must end in one
clear error (SceneError / ValueError / KeyError, or SimulationError once stepping) or in a
run that stays finite; never another exception (a TypeError, OverflowError or RecursionError
out of the validators is a traceback for the user). The tests keep a few hundred mutations
of each kind, so that a new hole shows."""
import copy
import os
import random
import warnings
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from abd_joint_sim import Scene, World
from abd_joint_sim.builders import chain_scene
from abd_joint_sim.errors import SimulationError

from physics_helpers import hinge_dict

CLEAR = (ValueError, KeyError, SimulationError)        # SceneError is a ValueError
VALUES = [None, 'x', '', -1, 0, 1e308, -1e308, float('nan'), float('inf'), [], {}, [1, 2],
          [float('nan')] * 3, True, 10 ** 400, [1e308] * 3, [0, 0, 0], [[1, 2, 3]], 'base', -0.0,
          1e-320, [1, 'a', 3], {'a': 1}]
DELETE = object()


def _paths(d, prefix=()):
    if isinstance(d, dict):
        items = d.items()
    elif isinstance(d, list):
        items = enumerate(d)
    else:
        return
    for k, v in items:
        yield prefix + (k,)
        yield from _paths(v, prefix + (k,))


def _set(d, path, value):
    for k in path[:-1]:
        d = d[k]
    if value is DELETE:
        del d[path[-1]]
    else:
        d[path[-1]] = value


def _outcome(make):
    """'ran', 'refused' or the unexpected exception."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            w = make()
            w.step(3)
        assert np.isfinite(w.joint_angles()).all()
        return 'ran'
    except CLEAR:
        return 'refused'
    except Exception as exc:  # noqa: BLE001 - what the test is looking for
        return exc


@pytest.mark.slow
def test_mutated_scenes_are_refused_with_one_clear_error():
    rng = random.Random(36)
    bases = [chain_scene(3, torque=0.1), hinge_dict()]
    counts = {'ran': 0, 'refused': 0}
    for trial in range(400):
        d = copy.deepcopy(rng.choice(bases))
        mutations = []
        for _ in range(rng.choice([1, 1, 2])):
            path = rng.choice(list(_paths(d)))
            value = rng.choice(VALUES + [DELETE])
            value = value if value is DELETE else copy.deepcopy(value)
            _set(d, path, value)
            mutations.append((path, 'deleted' if value is DELETE else value))
        out = _outcome(lambda: World(Scene.from_dict(d)))
        assert isinstance(out, str), f'trial {trial}, {mutations}: {type(out).__name__}: {out}'
        counts[out] += 1
    assert counts['refused'] > 300 and counts['ran'] > 10, counts     # both kinds exercised


URDF_VALUES = ['', 'x', 'nan', 'inf', '-inf', '1e308', '0', '-1', '1 2', '1 2 3 4', 'nan nan nan',
               '1e-320', '0 0 0', 'prismatic', 'fixed', 'continuous', 'floating', 'base_link', '1,2,3']


@pytest.mark.slow
def test_mutated_urdfs_are_refused_with_one_clear_error():
    pybullet_data = pytest.importorskip('pybullet_data')
    text = open(os.path.join(pybullet_data.getDataPath(), 'kuka_iiwa', 'model.urdf')).read()
    rng = random.Random(36)
    counts = {'ran': 0, 'refused': 0}
    for trial in range(250):
        root = ET.fromstring(text)
        parents = {child: parent for parent in root.iter() for child in parent}
        elements = list(root.iter())
        mutations = []
        for _ in range(rng.choice([1, 1, 2])):
            e = rng.choice(elements)
            r = rng.random()
            if e.attrib and r < 0.7:
                key = rng.choice(sorted(e.attrib))
                e.attrib[key] = rng.choice(URDF_VALUES)
                mutations.append((e.tag, key, e.attrib[key]))
            elif r < 0.85 and e in parents:
                parents[e].remove(e)
                mutations.append((e.tag, 'removed'))
            else:
                key = rng.choice(['xyz', 'rpy', 'value', 'name', 'type', 'link'])
                e.attrib[key] = rng.choice(URDF_VALUES)
                mutations.append((e.tag, key, e.attrib[key]))
        mutated = ET.tostring(root, encoding='unicode')
        out = _outcome(lambda: World(Scene.from_urdf(mutated)))
        assert isinstance(out, str), f'trial {trial}, {mutations}: {type(out).__name__}: {out}'
        counts[out] += 1
    assert counts['refused'] > 50 and counts['ran'] > 50, counts


OPTION_VALUES = [None, 'x', '', -1, 0, 1e308, float('nan'), float('inf'), [], {}, [1, 2], True,
                 10 ** 400, ['lbr_iiwa_joint_1'], {'lbr_iiwa_joint_1': 'x'}, {'nope': 1.0},
                 {'lbr_iiwa_joint_1': {'limit': 'x'}}, ['nope'], 'lbr_iiwa_joint_1', 1e-300,
                 [0, 0, -9.81], {'max_iterations': 0}, 'bdf3', {'lbr_iiwa_joint_1': {'damping': 10 ** 400}}]
OPTIONS = ['dt', 'gravity', 'integrator', 'newton', 'name', 'fixed_base', 'initial_positions', 'lock',
           'actuated', 'joints', 'kappa', 'strength_ratio', 'limits', 'torque_enabled', 'driving', 'bogus']


def test_odd_urdf_options_are_refused_with_one_clear_error():
    pybullet_data = pytest.importorskip('pybullet_data')
    path = os.path.join(pybullet_data.getDataPath(), 'kuka_iiwa', 'model.urdf')
    rng = random.Random(36)
    for trial in range(250):
        opts = {k: copy.deepcopy(rng.choice(OPTION_VALUES)) for k in rng.sample(OPTIONS, rng.choice([1, 2]))}
        out = _outcome(lambda: World(Scene.from_urdf(path, **opts)))
        assert isinstance(out, str), f'trial {trial}, {opts}: {type(out).__name__}: {out}'


def test_odd_world_commands_are_refused_with_one_clear_error():
    w = World(Scene.from_dict(chain_scene(3, torque=0.1)))
    calls = [lambda v: w.set_torque('j1', v), lambda v: w.set_torques(v), lambda v: w.step(v),
             lambda v: w.set_torque_enabled('j2', v), lambda v: w.body_pose(v),
             lambda v: w.set_torque(v, 1.0)]
    values = VALUES + [np.ones(3), np.ones((3, 1)), np.float32(0.5), np.int64(2), '1.5', 1.5, 2.0,
                       2 ** 63, 1e300]
    for call in calls:
        for value in values:
            try:
                call(copy.deepcopy(value))
            except CLEAR:
                pass
            except Exception as exc:  # noqa: BLE001
                pytest.fail(f'{value!r}: {type(exc).__name__}: {exc}')
    assert np.isfinite(w.joint_angles()).all()
