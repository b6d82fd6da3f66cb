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
from .scene import PRISMATIC, REVOLUTE, Scene, check_dt
from .terms.revolute import stiffness

#: largest h d / I of a damped joint (I: the lighter body's moment about the axis): beyond it
#: the damper outweighs the body's inertia by more than double precision resolves in Newton's
#: matrix (measured: steps fail from ~4e19), and the joint is locked for all purposes
DAMPING_RATIO_MAX = 1e15
#: a Model's per-term arrays: (field prefix, joint type, JointSpec attribute, the spec's
#: attributes, their field suffixes); bool arrays for `enabled`/`passive`, else float
_EFFORT, _DRIVE = ('value0', 'enabled0', 'effort_limit'), ('aim0', 'passive0', 'enabled0')
_LIMIT = ('lower', 'upper', 'strength')
_TERMS = (('torque', REVOLUTE, 'external_torque', ('torque', 'enabled', 'effort_limit'), _EFFORT),
          ('drive', REVOLUTE, 'driving', ('aim_angle', 'passive', 'enabled'), _DRIVE),
          ('limit', REVOLUTE, 'limit', _LIMIT, _LIMIT),
          ('prismatic_force', PRISMATIC, 'external_force', ('force', 'enabled', 'effort_limit'),
           _EFFORT),
          ('prismatic_drive', PRISMATIC, 'driving', ('aim_distance', 'passive', 'enabled'), _DRIVE),
          ('prismatic_limit', PRISMATIC, 'limit', _LIMIT, _LIMIT))


def mass_properties(body):
    """(mass, com (3,), S (3,3) about the body origin, volume, half extents (3,)) of a BodySpec."""
    s, rho = body.shape, body.density
    com = np.zeros(3)
    if s.kind == 'box':
        a, b, c = s.size
        vol = a * b * c
        m = rho * vol
        S = m * np.diag([a * a, b * b, c * c]) / 12.0
        half = np.array([a, b, c]) / 2
    elif s.kind == 'sphere':
        (R,) = s.size
        vol = 4.0 / 3.0 * math.pi * R ** 3
        m = rho * vol
        S = m * R * R / 5.0 * np.eye(3)
        half = np.full(3, R)
    elif s.kind == 'cylinder':             # axis along the body's z, as in URDF
        R, L = s.size
        vol = math.pi * R * R * L
        m = rho * vol
        S = np.diag([m * R * R / 4, m * R * R / 4, m * L * L / 12])
        half = np.array([R, R, L / 2])
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


def joint_basis(t):
    """(n, b) orthonormal to the unit axis t, with b = t × n (docs/physics.md "Joint angle")."""
    test = np.array([0.0, 1.0, 0.0]) if abs(t[0]) > 0.9 else np.array([1.0, 0.0, 0.0])
    n = np.cross(t, test)
    n /= np.linalg.norm(n)
    b = np.cross(t, n)
    b /= np.linalg.norm(b)
    return n, b


@dataclass(frozen=True, eq=False)
class Model:
    """Compiled scene. Shapes: B bodies, J joints; per-term index arrays select joints.

    Attributes ending in ``_joints`` are indices into the joint arrays of the joints that
    carry that term (empty when the scene has none, and then the term is not built).
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
    torque_joints: np.ndarray       #: (T,) joints with UID 668
    torque_value0: np.ndarray       #: [N m] (T,)
    torque_enabled0: np.ndarray     #: (T,) bool
    torque_effort_limit: np.ndarray  #: [N m] (T,) inf = none
    drive_joints: np.ndarray        #: (D,) joints with UID 19
    drive_K: np.ndarray             #: [kg] (D,) UID 19 stiffness gamma (m_i + m_j)
    drive_aim0: np.ndarray          #: [rad] (D,)
    drive_passive0: np.ndarray      #: (D,) bool
    drive_enabled0: np.ndarray      #: (D,) bool
    limit_joints: np.ndarray        #: (L,) joints with UID 670
    limit_lower: np.ndarray         #: [rad] (L,)
    limit_upper: np.ndarray         #: [rad] (L,)
    limit_strength: np.ndarray      #: (L,)
    damping_joints: np.ndarray      #: (P,) joints with viscous damping (terms/damping.py)
    damping_coeff: np.ndarray       #: [N m s/rad] (P,) their damping coefficients d > 0
    joint_slides: np.ndarray        #: (J,) bool: a prismatic joint (UID 20), else revolute (UID 18)
    revolute_joints: np.ndarray     #: (R,) the revolute joints (UID 18)
    prismatic_joints: np.ndarray    #: (S,) the prismatic joints (UID 20)
    prismatic_K: np.ndarray         #: [kg] (S,) UID 20 stiffness gamma (m_i + m_j)
    prismatic_force_joints: np.ndarray      #: (F,) joints with UID 667
    prismatic_force_value0: np.ndarray      #: [N] (F,)
    prismatic_force_enabled0: np.ndarray    #: (F,) bool
    prismatic_force_effort_limit: np.ndarray  #: [N] (F,) inf = none
    prismatic_drive_joints: np.ndarray      #: (Ds,) joints with UID 21
    prismatic_drive_K: np.ndarray           #: [kg] (Ds,) UID 21 stiffness gamma (m_i + m_j)
    prismatic_drive_aim0: np.ndarray        #: [m] (Ds,) absolute aim distance
    prismatic_drive_passive0: np.ndarray    #: (Ds,) bool
    prismatic_drive_enabled0: np.ndarray    #: (Ds,) bool
    prismatic_limit_joints: np.ndarray      #: (Ls,) joints with UID 669
    prismatic_limit_lower: np.ndarray       #: [m] (Ls,)
    prismatic_limit_upper: np.ndarray       #: [m] (Ls,)
    prismatic_limit_strength: np.ndarray    #: (Ls,)
    prismatic_damping_joints: np.ndarray    #: (Ps,) prismatic joints with viscous damping
    prismatic_damping_coeff: np.ndarray     #: [N s/m] (Ps,) their damping coefficients c > 0

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
    mass, com, M, Minv, vol, corners, q0, v0, R0 = [], [], [], [], [], [], [], [], []
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    for b in scene.bodies:
        m, c, S, v, half = mass_properties(b)
        Mb = mass_matrix(m, c, S)
        R = rpy_matrix(b.rpy)
        mass.append(m), com.append(c), M.append(Mb), Minv.append(np.linalg.inv(Mb)), vol.append(v)
        centre = c if b.shape.kind == 'inertial' else np.zeros(3)
        corners.append(centre + signs * half)
        q0.append(np.concatenate([b.position, R.ravel()]))
        # x = A x̄ + p with dA/dt = [ω]x A: a rigid motion with angular velocity ω about p.
        v0.append(np.concatenate([b.velocity, (skew(b.angular_velocity) @ R).ravel()]))
        R0.append(R)
    corners = np.array(corners)
    size = np.linalg.norm(corners.max(axis=1) - corners.min(axis=1), axis=1)

    J = len(scene.joints)
    parent = np.array([index[j.parent] for j in scene.joints], dtype=np.int64)
    child = np.array([index[j.child] for j in scene.joints], dtype=np.int64)
    anchor0, anchor1 = np.zeros((J, 2, 3)), np.zeros((J, 2, 3))
    nbar, bbar = np.zeros((J, 2, 3)), np.zeros((J, 2, 3))
    K = np.zeros(J)
    for k, j in enumerate(scene.joints):
        P0, P1 = np.array(j.p0), np.array(j.p1)
        t = (P1 - P0) / np.linalg.norm(P1 - P0)
        n, bvec = joint_basis(t)
        for side, body in enumerate((parent[k], child[k])):
            R, p = R0[body], q0[body][:3]
            anchor0[k, side] = R.T @ (P0 - p)       # x̄ = T⁻¹ P for a rigid initial pose
            anchor1[k, side] = R.T @ (P1 - p)
            nbar[k, side], bbar[k, side] = R.T @ n, R.T @ bvec
        K[k] = stiffness(j.strength_ratio, mass[parent[k]], mass[child[k]])

    def sel(kind, pred=lambda j: True):
        return np.array([k for k, j in enumerate(scene.joints) if j.type == kind and pred(j)],
                        dtype=np.int64)

    terms = {}
    for prefix, kind, spec, attrs, suffixes in _TERMS:
        ks = terms[f'{prefix}_joints'] = sel(kind, lambda j: getattr(j, spec) is not None)
        js = [getattr(scene.joints[k], spec) for k in ks]
        for attr, suffix in zip(attrs, suffixes):
            dtype = bool if attr in ('enabled', 'passive') else float
            terms[f'{prefix}_{suffix}'] = np.array([getattr(x, attr) for x in js], dtype)
        if spec == 'driving':
            terms[f'{prefix}_K'] = np.array([stiffness(scene.joints[k].driving.strength_ratio,
                                                       mass[parent[k]], mass[child[k]])
                                             for k in ks], float)
    for prefix, kind in (('damping', REVOLUTE), ('prismatic_damping', PRISMATIC)):
        ks = terms[f'{prefix}_joints'] = sel(kind, lambda j: j.damping > 0.0)
        terms[f'{prefix}_coeff'] = np.array([scene.joints[k].damping for k in ks], float)
    sj = sel(PRISMATIC)
    model = Model(
        dt=scene.dt if dt is None else check_dt(dt, 'dt argument'), gravity=np.array(scene.gravity, float),
        integrator=scene.integrator, newton=scene.newton,
        body_names=scene.body_names, body_fixed=np.array([b.fixed for b in scene.bodies], bool),
        body_mass=np.array(mass), body_com=np.array(com), body_M=np.array(M),
        body_Minv=np.array(Minv), body_volume=np.array(vol),
        body_kappa=np.array([b.kappa for b in scene.bodies], float), body_corners=corners,
        body_size=size, body_q0=np.array(q0), body_v0=np.array(v0),
        joint_names=scene.joint_names, joint_parent=parent, joint_child=child,
        joint_anchor0=anchor0, joint_anchor1=anchor1, joint_K=K,
        joint_nbar=nbar, joint_bbar=bbar,
        joint_init_angle=np.array([j.init_position for j in scene.joints], float),
        joint_slides=np.array([j.type == PRISMATIC for j in scene.joints], bool),
        revolute_joints=sel(REVOLUTE), prismatic_joints=sj,
        prismatic_K=np.array([K[k] for k in sj], float), **terms)
    for value in model.__dict__.values():
        if isinstance(value, np.ndarray):
            value.setflags(write=False)
    def lighter_mass(m, j):
        return min([float(m.body_mass[b]) for b in (m.joint_parent[j], m.joint_child[j])
                    if not m.body_fixed[b]], default=math.inf)

    for joints, coeff, of, unit, what, xunit, formula in (
            (model.damping_joints, model.damping_coeff, axis_inertia, 'N m s/rad',
             'moment of its lighter body about the axis', 'kg m^2', 'dt d / I'),
            (model.prismatic_damping_joints, model.prismatic_damping_coeff, lighter_mass, 'N s/m',
             'mass of its lighter body', 'kg', 'dt c / m')):
        for j, c in zip(joints, coeff):
            x = of(model, j)
            if model.dt * c > DAMPING_RATIO_MAX * x:
                raise SceneError(
                    f'{scene.source}: joint {model.joint_names[j]!r}: damping {c:g} {unit} is '
                    f'{model.dt * c / x:.1e} times the {what} ({x:.2e} {xunit}) per step of '
                    f'{model.dt:g} s ({formula}), beyond the {DAMPING_RATIO_MAX:g} a step can '
                    'resolve: a joint damped this hard does not move; lock it, or lower the '
                    'damping')
    return model


def axis_inertia(model: Model, j: int) -> float:
    """[kg m²] The lighter of joint j's two bodies' moment of inertia about the joint's axis
    (inf for a fixed body): ½ q̇ᵀ M q̇ = ½ I for a unit turn about the axis, q̇ =
    (−a × x̄0, [a]ₓ) in the body's rest frame (x = t + A x̄, A's rows in q). The same on any
    pose: the axis turns with the body."""
    m = model
    out = math.inf
    for side, b in enumerate((int(m.joint_parent[j]), int(m.joint_child[j]))):
        if m.body_fixed[b]:
            continue
        x0, x1 = m.joint_anchor0[j, side], m.joint_anchor1[j, side]
        a = (x1 - x0) / np.linalg.norm(x1 - x0)
        qdot = np.concatenate([-np.cross(a, x0), skew(a).ravel()])
        out = min(out, float(qdot @ m.body_M[b] @ qdot))
    return out
