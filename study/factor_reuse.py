"""Would reusing Newton's factorised matrix across steps pay? (docs/speed-rounds.md "Reusing the
factorisation: measured, rejected")

A Newton iteration on a matrix H₀ assembled some steps ago instead of the current H converges
like ε = max |λ(H₀⁻¹ H) − 1| per iteration (the chord method). This study steps real scenes,
keeps H₀ of one step and prints ε for the H of each following step, with the largest body
rotation in between:

    python study/factor_reuse.py

ε grows like c·δ with δ the rotation and c ≈ √(stiffness of the shape term / the softest
affine inertia): the shape term (UID 1) is ~10³ stiffer than a body's rotational inertia at
κ = 1e8 Pa, dt = 1 ms, and its stiff directions turn with the body, leaking into the soft
(rigid) ones. The joint blocks (UID 18) are constant, but rotating them with the bodies
(a rotated factorisation) makes it worse, not better, because the bodies turn relative to each
other.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import scipy.linalg as sl

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from abd_joint_sim import Scene, World                      # noqa: E402
from abd_joint_sim.builders import chain_scene              # noqa: E402
from abd_joint_sim.solver import newton                     # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def dense_hessian(w, q):
    """Newton's matrix at q (free bodies, dense), assembled by the step's own `assemble`."""
    m, d = w.model, w.solver.data
    B, J = m.body_count, m.joint_count
    ctx = w.solver.context(w.state, w.control, m.dt, q_tilde=q)
    g, D, P = np.zeros((B, 12)), np.zeros((B, 12, 12)), np.zeros((J, 12, 12))
    P = newton.assemble(np.ascontiguousarray(q), d, ctx, g, D, P)[0]
    H = np.zeros((12 * B, 12 * B))
    for b in range(B):
        H[12 * b:12 * b + 12, 12 * b:12 * b + 12] = D[b]
    for j in range(J):
        i, k = m.joint_parent[j], m.joint_child[j]
        H[12 * i:12 * i + 12, 12 * k:12 * k + 12] += P[j]
        H[12 * k:12 * k + 12, 12 * i:12 * i + 12] += P[j].T
    idx = np.concatenate([np.arange(12 * b, 12 * b + 12) for b in np.flatnonzero(~m.body_fixed)])
    return H[np.ix_(idx, idx)]


def rotation_between(A0, A1):
    """[rad] angle of the rotation nearest to A1 A0⁻¹."""
    U, _, Vt = np.linalg.svd(A1 @ np.linalg.inv(A0))
    R = U @ Vt
    return float(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0)))


def study(name, world, warm_steps, later=(1, 2, 5, 10, 20)):
    world.step(warm_steps)
    free = np.flatnonzero(~world.model.body_fixed)
    q0 = world.state.q.copy()
    H0 = dense_hessian(world, q0)
    rows, done = [], 0
    for k in later:
        world.step(k - done)
        done = k
        q = world.state.q
        H = dense_hessian(world, q)
        eps = float(np.max(np.abs(sl.eigh(H, H0, eigvals_only=True) - 1.0)))
        rot = max(rotation_between(q0[b, 3:].reshape(3, 3), q[b, 3:].reshape(3, 3)) for b in free)
        rows.append((k, rot, eps))
    speed = float(np.abs(world.joint_velocities()).max()) if world.model.joint_count else 0.0
    print(f'\n{name} (largest joint speed {speed:.2f} rad/s)')
    print('| steps since H₀ | largest body rotation [rad] | ε = max |λ(H₀⁻¹H) − 1| | ε / rotation |')
    print('|---|---|---|---|')
    for k, rot, eps in rows:
        print(f'| {k} | {rot:.3g} | {eps:.3g} | {eps / rot if rot else float("nan"):.3g} |')


def main():
    w = World(Scene.from_dict(chain_scene(3)))
    for n in w.actuated_joint_names:
        w.set_torque(n, 1.0)
    study('chain of 3 links, 1 N m on every joint, dt 1 ms', w, 300)
    study('default scene', World(Scene.from_yaml(ROOT / 'abd_joint_sim' / 'scenes' / 'default.yaml')), 300)
    try:
        import pybullet_data
    except ImportError:
        print('\n(pybullet not installed: the KUKA iiwa case is skipped)')
        return
    kuka = Scene.from_urdf(str(Path(pybullet_data.getDataPath()) / 'kuka_iiwa' / 'model.urdf'))
    study('KUKA iiwa URDF, gravity only', World(kuka), 300)


if __name__ == '__main__':
    main()
