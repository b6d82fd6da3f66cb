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
    half = (link / 2, link / 4, link / 4)
    body = ''
    for k in range(n_links, 0, -1):        # nest from the tip inwards
        pos = f'{0.5 * link} 0 0' if k == 1 else f'{link} 0 0'
        body = (f'<body name="link{k}" pos="{pos}">'
                f'<joint name="j{k}" type="hinge" axis="0 0 1" pos="0 0 0"/>'
                f'<geom type="box" size="{half[0]} {half[1]} {half[2]}" pos="{0.5 * link} 0 0" '
                f'density="1000" contype="0" conaffinity="0"/>{body}</body>')
    actuators = ''.join(f'<motor joint="j{k}" gear="1"/>' for k in range(1, n_links + 1))
    xml = (f'<mujoco><option timestep="{dt}" integrator="Euler" gravity="0 0 0"/>'
           f'<worldbody><geom type="box" size="{link / 2} {link / 2} {link / 2}" contype="0" '
           f'conaffinity="0"/>{body}</worldbody><actuator>{actuators}</actuator></mujoco>')
    model = mujoco.MjModel.from_xml_string(xml)
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
