"""Rotated and offset <inertial> frames: the lowered inertia is R I Rᵀ, and the motion agrees
with PyBullet and MuJoCo loading the same file.

The robot is written by this test (no file of pybullet_data has a rotated inertial frame
on a moving link): a base and three links on revolute joints about x, y and z, each link's
<inertial> offset from its frame and turned by an rpy far from 0, with clearly unequal
principal moments, so an inertia left unrotated moves the arm differently by far more than
the engines' 1 % agreement.
"""
import os

import numpy as np
import pytest

from abd_joint_sim import Scene

pytest.importorskip('pybullet', reason='pybullet not installed (requirements-test.txt)')
pytest.importorskip('pybullet_data', reason='pybullet_data not installed')
from test_urdf_engines import run_mujoco, run_ours, run_pybullet   # noqa: E402

# link: (mass, principal moments ixx iyy izz (a valid triangle), inertial xyz, inertial rpy)
LINKS = {
    'l1': (1.2, (0.020, 0.012, 0.028), (0.05, 0.02, 0.15), (0.7, -0.4, 1.1)),
    'l2': (0.9, (0.006, 0.015, 0.012), (0.10, -0.03, 0.05), (-1.2, 0.5, 0.3)),
    'l3': (0.6, (0.008, 0.003, 0.007), (-0.02, 0.08, 0.04), (0.4, 1.0, -0.8)),
}
JOINTS = [  # name, parent, child, origin xyz, axis
    ('j1', 'base', 'l1', (0.0, 0.0, 0.1), (1, 0, 0)),
    ('j2', 'l1', 'l2', (0.0, 0.05, 0.3), (0, 1, 0)),
    ('j3', 'l2', 'l3', (0.2, 0.0, 0.05), (0, 0, 1)),
]


def rpy_to_matrix(rpy) -> np.ndarray:
    """URDF rpy: fixed-axis x, then y, then z: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = rpy
    cx, sx, cy, sy, cz, sz = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


def write_robot(path) -> None:
    links = ['<link name="base"><inertial><mass value="5"/><inertia ixx="0.1" iyy="0.1" '
             'izz="0.1" ixy="0" ixz="0" iyz="0"/></inertial></link>']
    for name, (mass, (ixx, iyy, izz), xyz, rpy) in LINKS.items():
        links.append(
            f'<link name="{name}"><inertial><origin xyz="{" ".join(map(str, xyz))}" '
            f'rpy="{" ".join(map(str, rpy))}"/><mass value="{mass}"/><inertia ixx="{ixx}" '
            f'iyy="{iyy}" izz="{izz}" ixy="0" ixz="0" iyz="0"/></inertial></link>')
    joints = [f'<joint name="{n}" type="revolute"><parent link="{p}"/><child link="{c}"/>'
              f'<origin xyz="{" ".join(map(str, o))}" rpy="0 0 0"/>'
              f'<axis xyz="{" ".join(map(str, a))}"/>'
              '<limit lower="-3" upper="3" effort="100" velocity="10"/></joint>'
              for n, p, c, o, a in JOINTS]
    path.write_text('<?xml version="1.0"?>\n<robot name="turned_inertials">'
                    + ''.join(links + joints) + '</robot>\n')


@pytest.fixture
def robot(tmp_path):
    path = tmp_path / 'turned_inertials.urdf'
    write_robot(path)
    return str(path)


def test_the_lowered_inertia_is_the_rotated_one(robot):
    scene = Scene.from_urdf(robot)
    shapes = {b.name: b.shape for b in scene.bodies}
    for name, (mass, moments, xyz, rpy) in LINKS.items():
        R = rpy_to_matrix(rpy)
        expected = R @ np.diag(moments) @ R.T
        shape = shapes[name]
        assert shape.kind == 'inertial' and shape.mass == pytest.approx(mass)
        assert np.allclose(shape.com, xyz, atol=1e-12)
        got = np.asarray(shape.inertia, dtype=float).reshape(3, 3)
        assert np.allclose(got, expected, atol=1e-12), (name, got, expected)
        # and not the unrotated one: the check can fail
        assert np.abs(got - np.diag(moments)).max() > 1e-3


@pytest.mark.parametrize('engine', ['pybullet', 'mujoco'])
def test_motion_with_turned_inertials_agrees_with_other_engines(robot, engine):
    q0 = {'j1': 0.3, 'j2': -0.5, 'j3': 0.8}
    world, names, torques = run_ours(robot, q0)
    run = run_pybullet if engine == 'pybullet' else run_mujoco
    q_ref, v_ref = run(robot, names, torques, q0)
    start = np.array([q0[n] for n in names])
    dv = np.linalg.norm(world.joint_velocities() - v_ref) / np.linalg.norm(v_ref)
    dq = np.linalg.norm(world.joint_angles() - q_ref) / np.linalg.norm(q_ref - start)
    print(f'turned inertials vs {engine}: velocity {dv:.2e}, angle {dq:.2e} (relative)')
    assert dv < 0.01 and dq < 0.01
