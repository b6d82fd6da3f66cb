"""Scene builders and helpers shared by the physics tests (no rclpy)."""
from __future__ import annotations

import copy
from pathlib import Path

import numpy as np

from abd_joint_sim import Scene, World
from abd_joint_sim.builders import chain_scene
from abd_joint_sim.scene import load_yaml

SCENES = Path(__file__).resolve().parents[1] / 'abd_joint_sim' / 'scenes'


def scene_dict(name: str) -> dict:
    return load_yaml((SCENES / f'{name}.yaml').read_text())


def world_from(d: dict, **overrides) -> World:
    d = copy.deepcopy(d)
    d.update(overrides)
    return World(Scene.from_dict(d))


def box(name, pos, size=(0.4, 0.4, 0.4), fixed=False, **kw):
    return dict(name=name, box=list(size), density=1000.0, position=list(pos), fixed=fixed, **kw)


def hinge_dict(**kw):
    """Reference scene of docs/physics.md "Analytic references" (I_axis = 24.747)."""
    d = scene_dict('hinge')
    d.update(kw)
    return d


def random_rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    return q


def rotation_about(axis, phi):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(phi) * K + (1 - np.cos(phi)) * K @ K


def chain_dict(n_links, *, dt=0.001, torque=1.0, gravity=(0.0, 0.0, 0.0), link=0.2):
    """A fixed base plus n free links along +x joined by vertical hinges, all actuated."""
    return chain_scene(n_links, dt=dt, torque=torque, gravity=gravity, link=link)


# -- calling the compiled terms from a test -----------------------------------------------
def theta(world, q, joint=0) -> float:
    """Wrapped joint angle θ of `joint` at q (abd_joint_sim/terms/angle.py)."""
    from abd_joint_sim.terms import angle as angles
    return float(angles.theta(np.ascontiguousarray(q, dtype=float), world.solver.data, joint))


def torque_force(world, q, taus, enabled=None):
    """(F (B,12), skipped bodies) of the UID 668 torques `taus` (one per actuated joint)."""
    from abd_joint_sim.terms import torque
    taus = np.asarray(taus, dtype=float)
    on = np.ones(len(taus), bool) if enabled is None else np.asarray(enabled, bool)
    F = np.zeros((world.model.body_count, 12))
    skipped = np.zeros(2 * len(taus) + 1, dtype=np.int64)
    n = torque.generalized_force(np.ascontiguousarray(q, dtype=float), world.solver.data, taus, on, F, skipped)
    return F, skipped[:n].tolist()


def torque_axis(world, q, k=0):
    """ê_j (3,) of the k-th actuated joint (the child's axis; the parent's is −ê_j)."""
    from abd_joint_sim.terms import torque
    e = np.zeros(3)
    torque.axis(np.ascontiguousarray(q, dtype=float), world.solver.data, int(world.model.torque_joints[k]), e)
    return e
