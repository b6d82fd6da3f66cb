"""The benchmark chain (abd_joint_sim.builders.chain_scene) in MuJoCo and PyBullet.

Same geometry and inertia: fixed base cube of side L at the origin; link k a box
(L, L/2, L/2) of density 1000 centred at (kL, 0, 0), hinged about +z at x = (k − ½)L; no
gravity; torque tau on every joint; dt = 1 ms; MuJoCo with its Euler integrator, PyBullet
with its default solver. Each `make_*` returns (step(), angles()) closures, or None when
the engine is not installed; MuJoCo's step also has `step.many(n)`, n steps in one call.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np


def make_mujoco(n_links, *, tau=1.0, dt=1e-3, link=0.2):
    try:
        import mujoco
    except ImportError:
        return None
    # Built with MjSpec, not MJCF text: a 1000-deep body nesting exceeds the XML parser's
    # element depth limit.
    spec = mujoco.MjSpec()
    spec.option.timestep = dt
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_EULER
    spec.option.gravity = [0.0, 0.0, 0.0]
    box = mujoco.mjtGeom.mjGEOM_BOX
    spec.worldbody.add_geom(type=box, size=[link / 2] * 3, contype=0, conaffinity=0)
    parent = spec.worldbody
    for k in range(1, n_links + 1):
        body = parent.add_body(name=f'link{k}', pos=[0.5 * link if k == 1 else link, 0, 0])
        body.add_joint(name=f'j{k}', type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 0, 1])
        body.add_geom(type=box, size=[link / 2, link / 4, link / 4], pos=[0.5 * link, 0, 0],
                      density=1000.0, contype=0, conaffinity=0)
        spec.add_actuator(name=f'm{k}', target=f'j{k}', trntype=mujoco.mjtTrn.mjTRN_JOINT)
        parent = body
    model = spec.compile()
    data = mujoco.MjData(model)
    data.ctrl[:] = tau

    def step():
        mujoco.mj_step(model, data)

    def many(n):    # n steps in one call (MuJoCo's nstep), as World.step(n)
        mujoco.mj_step(model, data, n)
    step.many = many
    step.data = data        # (regimes.py reads its warning counters)

    def angles():
        return np.array(data.qpos)

    return step, angles


def chain_urdf(n_links, link=0.2, density=1000.0) -> str:
    """The benchmark chain as URDF (inertias written out: PyBullet must not guess them)."""
    L = link
    m = density * L * (L / 2) ** 2
    ixx = m * (2 * (L / 2) ** 2) / 12           # box (L, L/2, L/2) about its centre
    iyy = izz = m * (L ** 2 + (L / 2) ** 2) / 12
    parts = ['<?xml version="1.0"?>', '<robot name="chain">',
             f'<link name="base"><inertial><mass value="0"/><inertia ixx="0" ixy="0" ixz="0" '
             'iyy="0" iyz="0" izz="0"/></inertial><collision><geometry>'
             f'<box size="{L} {L} {L}"/></geometry></collision></link>']
    for k in range(1, n_links + 1):
        parts.append(
            f'<link name="link{k}"><inertial><origin xyz="{L / 2} 0 0"/><mass value="{m}"/>'
            f'<inertia ixx="{ixx}" ixy="0" ixz="0" iyy="{iyy}" iyz="0" izz="{izz}"/></inertial>'
            f'<collision><origin xyz="{L / 2} 0 0"/><geometry><box size="{L} {L / 2} {L / 2}"/>'
            '</geometry></collision></link>\n'
            f'<joint name="j{k}" type="continuous"><parent link="{"base" if k == 1 else f"link{k - 1}"}"/>'
            f'<child link="link{k}"/><origin xyz="{L / 2 if k == 1 else L} 0 0"/>'
            '<axis xyz="0 0 1"/></joint>')
    parts.append('</robot>')
    return '\n'.join(parts)          # one element per line: TinyXML chokes on very long lines


def make_pybullet(n_links, *, tau=1.0, dt=1e-3, link=0.2):
    try:
        import pybullet as p
    except ImportError:
        return None
    import tempfile
    cid = p.connect(p.DIRECT)
    p.setGravity(0, 0, 0, physicsClientId=cid)
    p.setPhysicsEngineParameter(fixedTimeStep=dt, physicsClientId=cid)
    # URDF, not createMultiBody: the latter silently stops at 127 links.
    with tempfile.NamedTemporaryFile('w', suffix='.urdf', delete=False) as f:
        f.write(chain_urdf(n_links, link))
    body = p.loadURDF(f.name, useFixedBase=True, flags=p.URDF_USE_INERTIA_FROM_FILE,
                      physicsClientId=cid)
    Path(f.name).unlink()
    assert p.getNumJoints(body, physicsClientId=cid) == n_links
    joints = list(range(n_links))
    for k in range(-1, n_links):           # no collisions: only the joints, as in the others
        p.setCollisionFilterGroupMask(body, k, 0, 0, physicsClientId=cid)
    p.setJointMotorControlArray(body, joints, p.VELOCITY_CONTROL, forces=[0.0] * n_links,
                                physicsClientId=cid)
    for k in joints:                       # PyBullet damps links by default; the others don't
        p.changeDynamics(body, k, linearDamping=0.0, angularDamping=0.0, physicsClientId=cid)
    torques = [tau] * n_links

    def step():
        # torque commands last one step in PyBullet: re-sent every step, as a controller would
        p.setJointMotorControlArray(body, joints, p.TORQUE_CONTROL, forces=torques,
                                    physicsClientId=cid)
        p.stepSimulation(physicsClientId=cid)

    def angles():
        return np.array([s[0] for s in p.getJointStates(body, joints, physicsClientId=cid)])

    return step, angles
