"""Scene builders and helpers shared by the physics tests (no rclpy)."""
from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
from numba import njit

from abd_joint_sim import Scene, World
from abd_joint_sim.builders import chain_scene
from abd_joint_sim.jit import subnormals
from abd_joint_sim.scene import load_yaml
from abd_joint_sim.smallmat import nearest_rotation_in, quaternion_in
from abd_joint_sim.terms import angle, prismatic, prismatic_force, torque

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
    n = generalized_force(np.ascontiguousarray(q, dtype=float), world.solver.data, taus, on, F, skipped)
    return F, skipped[:n].tolist()


def torque_axis(world, q, k=0):
    """ê_j (3,) of the k-th actuated joint (the child's axis; the parent's is −ê_j)."""
    from abd_joint_sim.terms import torque
    e = np.zeros(3)
    torque.axis(np.ascontiguousarray(q, dtype=float), world.solver.data, int(world.model.torque_joints[k]), e)
    return e


def nearest_rotation(A: np.ndarray) -> np.ndarray:
    """The rotation nearest to A (Frobenius norm), det +1: U diag(1, 1, det(U Vᵀ)) Vᵀ from
    the SVD A = U S Vᵀ (smallmat.nearest_rotation_in, as the markers pose bodies)."""
    return nearest_rotations(np.asarray(A, dtype=float)[None])[0]


def nearest_rotations(A: np.ndarray) -> np.ndarray:
    """:func:`nearest_rotation` of each of a stack of matrices (B, 3, 3)."""
    A = np.ascontiguousarray(A, dtype=float)
    R = np.empty_like(A)
    work = np.empty((5, 3, 3))
    for k in range(A.shape[0]):
        nearest_rotation_in(A[k], R[k], work)
    return R


def quaternion(R: np.ndarray) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation matrix, w >= 0 (Shepperd's method: the largest of
    w, x, y, z is computed first, so no division by a small number; smallmat.quaternion_in,
    as the markers do)."""
    out = np.empty(4)
    quaternion_in(np.ascontiguousarray(R, dtype=float), out)
    return tuple(out.tolist())


# -- test-side kernels over the compiled terms' pieces ---------------------------------------
@njit
def mxcsr():
    """The SSE control and status register (x86-64: jit/subnormals.py sets its FTZ and DAZ)."""
    return subnormals._read_mxcsr()


@njit
def generalized_force(q, m, torque_value, torque_enabled, F, skipped):
    """Adds F_k of every enabled joint to F (B,12). Bodies skipped by the singular guard are
    written to `skipped` (parent side of every joint first, then child side); returns their
    count."""
    if not torque._any_active(torque_value, torque_enabled, m.torque_joints.size):
        return 0
    tj, parent, child = m.torque_joints, m.joint_parent, m.joint_child
    e = np.empty((tj.size + 2, 3))
    torque._axes(q, tj, parent, child, m.joint_x_bar, torque_value, torque_enabled, e)
    bodies, ptr, entries = m.torque_bodies, m.torque_body_ptr, m.torque_body_entries
    any_skipped = False
    for t in range(bodies.size):
        b = bodies[t]
        f = torque._body_force(q, b, ptr[t], ptr[t + 1], entries, e, torque_value, torque_enabled)
        if f[0] == 0:
            any_skipped = True
        elif f[0] == 1:
            F[b, 3] += f[1]
            F[b, 4] += f[2]
            F[b, 5] += f[3]
            F[b, 6] += f[4]
            F[b, 7] += f[5]
            F[b, 8] += f[6]
            F[b, 9] += f[7]
            F[b, 10] += f[8]
            F[b, 11] += f[9]
    if not any_skipped:
        return 0
    return torque._list_skipped(q, tj, parent, child, torque_value, torque_enabled, skipped)


@njit
def prismatic_generalized_force(q, m, effort_value, effort_enabled, F):
    """Adds F_k of every enabled UID 667 joint to F (B,12), from prismatic_force's pieces."""
    T = m.torque_joints.size
    joints, parent, child, fr, slot = (m.prismatic_force_joints, m.joint_parent, m.joint_child,
                                       m.prismatic_frame, m.prismatic_slot)
    for k in range(joints.size):
        f = effort_value[T + k] if effort_enabled[T + k] else 0.0
        if f == 0.0:
            continue
        j = joints[k]
        e = prismatic_force.axis(q, m, j)
        for side in range(2):
            b = parent[j] if side == 0 else child[j]
            for c in range(12):
                F[b, c] += prismatic_force._body_force(f, e, fr, slot[j], side, c)


@njit
def theta_derivatives(q, m, j, grad, hess, want_hess):
    """angle.theta_derivatives_at on the compiled model m."""
    return angle.theta_derivatives_at(q, m.joint_parent, m.joint_child, m.joint_nbar, m.joint_bbar, j,
                                      grad, hess, want_hess, np.empty(angle.WORK_SHAPE))


@njit
def theta_and_slope_at(q, d_plus, d_minus, parent, child, nbar, bbar, j):
    """(wrapped θ, ∇θ(q)·d) of joint j along the direction d = d_plus − d_minus in q[3:12]."""
    c, s, slope = angle.cos_sin_slope_at(q, d_plus, d_minus, parent, child, nbar, bbar, j)
    return math.atan2(s, c), slope


@njit
def forward_block(L, inv_d, X, ncol):
    """X[:, :ncol] = L⁻¹ X[:, :ncol] (L the 12x12 lower factor): the loop form
    linsolve.forward_vector12 and forward_block12 are compared with, bit for bit."""
    for i in range(12):
        for k in range(i):
            lik = L[i, k]
            for c in range(ncol):
                X[i, c] -= lik * X[k, c]
        di = inv_d[i]
        for c in range(ncol):
            X[i, c] *= di


@njit
def prismatic_distance(q, m, j):
    """d(q) of joint j (a prismatic joint), relative to its creation. [m]"""
    return prismatic.distance_at(q, m.joint_parent[j], m.joint_child[j], m.prismatic_frame, m.prismatic_slot[j])
