"""Model: the immutable, compiled form of a Scene (arrays, index maps, term selection).

Conventions (docs/physics.md "Affine body", "Revolute joint (UID 18)", "Joint angle"):
- body state ``q = [p, a1, a2, a3]`` (12,), the a's being the ROWS of A; a rest point x̄ is
  at ``x = A x̄ + p = J(x̄) q`` with ``J(x̄) = [I3 | I3 ⊗ x̄ᵀ]``.
- mass matrix from the dyadic mass (m, m x̄_c, S); gravity in q-space is ``[g, 0...]``.
- every joint stores its anchors in each body's rest frame, in the same order P0, P1 on both
  bodies (§9), and its angle basis (n̄, b̄) per body.
Arrays are made read-only: a Model is shared by worlds, tests and studies.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import SceneError
from .geometry import rpy_matrix, skew
from .scene import PRISMATIC, Scene, check_dt
from .terms import TERMS
from .terms.revolute import stiffness



def mass_properties(body):
    """(mass, com (3,), S (3,3) about the body origin, volume, half extents (3,)) of a BodySpec."""
    s, rho = body.shape, body.density
    com = np.zeros(3)
    if s.kind == 'box':
        a, b, c = s.size
        m = rho * (vol := a * b * c)
        S, half = m * np.diag([a * a, b * b, c * c]) / 12.0, np.array([a, b, c]) / 2
    elif s.kind == 'sphere':
        (R,) = s.size
        m = rho * (vol := 4.0 / 3.0 * math.pi * R ** 3)
        S, half = m * R * R / 5.0 * np.eye(3), np.full(3, R)
    elif s.kind == 'cylinder':             # axis along the body's z, as in URDF
        R, L = s.size
        m = rho * (vol := math.pi * R * R * L)
        S, half = np.diag([m * R * R / 4, m * R * R / 4, m * L * L / 12]), np.array([R, R, L / 2])
    else:                                   # rigid data: inertia about the COM
        m, com = s.mass, np.array(s.com, dtype=float)
        vol = s.volume if s.volume > 0 else m / 1000.0
        I_cm = np.array(s.inertia, dtype=float).reshape(3, 3)
        I_o = I_cm + m * (com @ com * np.eye(3) - np.outer(com, com))
        S_o = 0.5 * np.trace(I_o) * np.eye(3) - I_o      # S = ½ tr(I_o) I − I_o
        # S above is about the origin: it already contains m c cᵀ.
        half = np.sqrt(np.maximum(np.diag(S_o - m * np.outer(com, com)) / m * 3.0, 1e-12))
        return m, com, S_o, vol, half + np.abs(com)
    return m, com, S, vol, half


def mass_matrix(m, com, S) -> np.ndarray:
    """12x12 ABD mass matrix (docs/physics.md "Affine body")."""
    M = np.zeros((12, 12))
    M[0:3, 0:3] = m * np.eye(3)
    for k in range(3):
        M[k, 3 + 3 * k:6 + 3 * k] = m * com
        M[3 + 3 * k:6 + 3 * k, k] = m * com
        M[3 + 3 * k:6 + 3 * k, 3 + 3 * k:6 + 3 * k] = S
    return M


@dataclass(frozen=True, eq=False)
class Model:
    """Compiled scene. Shapes: B bodies, J joints.

    The fields below are the bodies and joints. Each term adds its own, built from the scene
    by its module's `from_scene` (terms/, in terms.TERMS' order): those ending in ``_joints``
    are indices of the joints that carry the term (empty when the scene has none, and then
    the term is not built), e.g. ``torque_joints``, ``drive_joints``, ``limit_lower``.
    """

    dt: float                       #: [s] step size
    gravity: np.ndarray             #: [m/s^2] (3,)
    integrator: str                 #: 'bdf1' | 'bdf2'
    newton: object                  #: NewtonSpec
    body_names: tuple
    body_fixed: np.ndarray          #: (B,) bool
    body_mass: np.ndarray           #: [kg] (B,)
    body_com: np.ndarray            #: [m] (B,3) rest-frame centre of mass
    body_M: np.ndarray              #: (B,12,12) mass matrices
    body_Minv: np.ndarray           #: (B,12,12) their inverses
    body_volume: np.ndarray         #: [m^3] (B,)
    body_kappa: np.ndarray          #: [Pa] (B,)
    body_corners: np.ndarray        #: [m] (B,8,3) rest bounding-box corners (convergence test)
    body_size: np.ndarray           #: [m] (B,) bounding-box diagonal
    body_q0: np.ndarray             #: (B,12) initial state
    body_v0: np.ndarray             #: (B,12) initial velocity
    joint_names: tuple
    joint_parent: np.ndarray        #: (J,) body index i (left)
    joint_child: np.ndarray         #: (J,) body index j (right)
    joint_anchor0: np.ndarray       #: [m] (J,2,3) x̄0 in the parent's, child's rest frame
    joint_anchor1: np.ndarray       #: [m] (J,2,3) x̄1 likewise (same order on both bodies)
    joint_K: np.ndarray             #: [kg] (J,) UID 18 stiffness gamma (m_i + m_j)
    joint_nbar: np.ndarray          #: (J,2,3) n̄ in parent, child frames
    joint_bbar: np.ndarray          #: (J,2,3) b̄ in parent, child frames
    joint_init_angle: np.ndarray    #: [rad | m] (J,) init_angle (revolute) or init_distance (prismatic)
    joint_slides: np.ndarray        #: (J,) bool: a prismatic joint (UID 20), else revolute (UID 18)

    @property
    def body_count(self) -> int:
        return len(self.body_names)

    @property
    def joint_count(self) -> int:
        return len(self.joint_names)

    @property
    def has_gravity(self) -> bool:
        return bool(np.any(self.gravity != 0.0)) and not bool(np.all(self.body_fixed))


def compile_scene(scene: Scene, dt: float | None = None) -> Model:
    """Turn a validated Scene into a Model; `dt` overrides the scene's step size (checked as
    the scene's own: SceneError outside 1e-6 to 1 s, or if not a finite number)."""
    index = {b.name: k for k, b in enumerate(scene.bodies)}
    mass, com, S, vol, half = zip(*map(mass_properties, scene.bodies))
    M = np.array([mass_matrix(*p) for p in zip(mass, com, S)])
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    corners = np.array([c + signs * h for c, h in zip(com, half)])   # com 0 unless 'inertial'
    R0 = [rpy_matrix(b.rpy) for b in scene.bodies]
    q0 = np.array([np.concatenate([b.position, R.ravel()]) for b, R in zip(scene.bodies, R0)])
    # x = A x̄ + p with dA/dt = [ω]x A: a rigid motion with angular velocity ω about p.
    v0 = np.array([np.concatenate([b.velocity, (skew(b.angular_velocity) @ R).ravel()])
                   for b, R in zip(scene.bodies, R0)])
    size = np.linalg.norm(corners.max(axis=1) - corners.min(axis=1), axis=1)

    parent = np.array([index[j.parent] for j in scene.joints], dtype=np.int64)
    child = np.array([index[j.child] for j in scene.joints], dtype=np.int64)
    anchor0, anchor1, nbar, bbar = (np.zeros((len(scene.joints), 2, 3)) for _ in range(4))
    for k, j in enumerate(scene.joints):
        P0, P1 = np.array(j.p0), np.array(j.p1)
        t = (P1 - P0) / np.linalg.norm(P1 - P0)
        # (n, b) orthonormal to the axis t, b = t × n (docs/physics.md "Joint angle")
        n = np.cross(t, np.array([0.0, 1.0, 0.0]) if abs(t[0]) > 0.9 else np.array([1.0, 0.0, 0.0]))
        n /= np.linalg.norm(n)
        bvec = np.cross(t, n)
        bvec /= np.linalg.norm(bvec)
        for side, body in enumerate((parent[k], child[k])):
            R, p = R0[body], q0[body][:3]
            anchor0[k, side] = R.T @ (P0 - p)       # x̄ = T⁻¹ P for a rigid initial pose
            anchor1[k, side] = R.T @ (P1 - p)
            nbar[k, side], bbar[k, side] = R.T @ n, R.T @ bvec
    K = np.array([stiffness(j.strength_ratio, mass[p], mass[c])
                  for j, p, c in zip(scene.joints, parent, child)], float)

    model = Model(
        dt=scene.dt if dt is None else check_dt(dt, 'dt argument'), gravity=np.array(scene.gravity, float),
        integrator=scene.integrator, newton=scene.newton,
        body_names=scene.body_names, body_fixed=np.array([b.fixed for b in scene.bodies], bool),
        body_mass=np.array(mass), body_com=np.array(com), body_M=M,
        body_Minv=np.linalg.inv(M), body_volume=np.array(vol),
        body_kappa=np.array([b.kappa for b in scene.bodies], float), body_corners=corners,
        body_size=size, body_q0=q0, body_v0=v0,
        joint_names=scene.joint_names, joint_parent=parent, joint_child=child,
        joint_anchor0=anchor0, joint_anchor1=anchor1, joint_K=K,
        joint_nbar=nbar, joint_bbar=bbar,
        joint_init_angle=np.array([j.init_position for j in scene.joints], float),
        joint_slides=np.array([j.type == PRISMATIC for j in scene.joints], bool),
    )
    for term in TERMS:                  # each term's own fields, from the scene
        for name, value in term.from_scene(scene, model).items():
            object.__setattr__(model, name, value)
    for value in model.__dict__.values():
        if isinstance(value, np.ndarray):
            value.setflags(write=False)
    return model

