"""The benchmark chain (abd_joint_sim.builders.chain_scene) in MuJoCo and PyBullet.

Same geometry and inertia: fixed base cube of side L at the origin; link k a box
(L, L/2, L/2) of density 1000 centred at (kL, 0, 0), hinged about +z at x = (k − ½)L; no
gravity; torque tau on every joint; dt = 1 ms; MuJoCo with its Euler integrator, PyBullet
with its default solver. Each `make_*` returns (step(), angles()) closures, or None when
the engine is not installed.
"""
from __future__ import annotations

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

    def angles():
        return np.array(data.qpos)

    return step, angles


def make_pybullet(n_links, *, tau=1.0, dt=1e-3, link=0.2):
    try:
        import pybullet as p
    except ImportError:
        return None
    cid = p.connect(p.DIRECT)
    p.setGravity(0, 0, 0, physicsClientId=cid)
    p.setPhysicsEngineParameter(fixedTimeStep=dt, physicsClientId=cid)
    base = p.createCollisionShape(p.GEOM_BOX, halfExtents=[link / 2] * 3, physicsClientId=cid)
    shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=[link / 2, link / 4, link / 4],
                                   physicsClientId=cid)
    mass = 1000.0 * link * (link / 2) ** 2
    # link frame = joint frame at the hinge; the centre of mass sits L/2 further along x.
    # linkPositions are relative to the parent's link frame (URDF joint origins).
    body = p.createMultiBody(
        baseMass=0.0, baseCollisionShapeIndex=base,
        linkMasses=[mass] * n_links, linkCollisionShapeIndices=[shape] * n_links,
        linkVisualShapeIndices=[-1] * n_links,
        linkPositions=[[0.5 * link, 0, 0]] + [[link, 0, 0]] * (n_links - 1),
        linkOrientations=[[0, 0, 0, 1]] * n_links,
        linkInertialFramePositions=[[0.5 * link, 0, 0]] * n_links,
        linkInertialFrameOrientations=[[0, 0, 0, 1]] * n_links,
        linkParentIndices=list(range(n_links)), linkJointTypes=[p.JOINT_REVOLUTE] * n_links,
        linkJointAxis=[[0, 0, 1]] * n_links, physicsClientId=cid)
    for k in range(n_links):               # no collisions: only the joints, as in the others
        p.setCollisionFilterGroupMask(body, k, 0, 0, physicsClientId=cid)
    p.setCollisionFilterGroupMask(body, -1, 0, 0, physicsClientId=cid)
    joints = list(range(n_links))
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
