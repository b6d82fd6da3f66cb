"""Compile the physics kernels once per install: `python -m abd_joint_sim.jit.warmup`.

Every kernel is `njit(cache=True)`: numba compiles it on first use (about a minute for the
whole step on a small machine) and stores machine code on disk; later processes load it
(about a second). `ensure_compiled()`, called by every Solver, runs a tiny scene through
every kernel signature the simulator uses, printing one line to stderr BEFORE a compile
starts, so a first run never waits in silence. A marker file keyed on the kernel sources
records a completed compile (cache.py says where, and why it is shared between the source
tree and an install).

Exit status of the command: 0 on success, 1 when the kernels fail to compile.
"""
from __future__ import annotations

import argparse
import sys
import time

from . import cache

_done = False


def _tiny_scene():
    from ..scene import Scene
    box = dict(box=[0.2, 0.1, 0.1], density=1000.0)
    return Scene.from_dict(dict(
        dt=0.01, gravity=[0.0, 0.0, -9.81], integrator='bdf2',
        bodies=[dict(name='base', position=[0.0, 0.0, 0.0], fixed=True, **box),
                dict(name='a', position=[0.2, 0.0, 0.0], **box),
                dict(name='b', position=[0.4, 0.0, 0.0], **box)],
        joints=[dict(name='j1', parent='base', child='a', p0=[0.1, 0, -0.05], p1=[0.1, 0, 0.05],
                     external_torque=dict(torque=1.0, enabled=True),
                     driving=dict(aim_angle=0.5, enabled=True),
                     limit=dict(lower=-0.1, upper=0.1)),
                dict(name='j2', parent='a', child='b', p0=[0.3, 0, -0.05], p1=[0.3, 0, 0.05],
                     external_torque=dict(torque=-1.0, enabled=True), damping=0.1)]))


def _loop_scene():
    """Three free bodies in a closed loop: the dense linear solve."""
    box = dict(box=[0.2, 0.1, 0.1], density=1000.0)
    from ..scene import Scene
    bodies = [dict(name='base', position=[0.0, 0.0, 0.0], fixed=True, **box)]
    bodies += [dict(name=n, position=[0.2 * (k + 1), 0.0, 0.0], **box) for k, n in enumerate('abc')]
    pairs = [('base', 'a'), ('a', 'b'), ('b', 'c'), ('c', 'a')]
    joints = [dict(name=f'{p}_{c}', parent=p, child=c, p0=[0.1, 0, -0.05], p1=[0.1, 0, 0.05])
              for p, c in pairs]
    return Scene.from_dict(dict(dt=0.01, bodies=bodies, joints=joints))


def _slide_scene():
    """A prismatic joint with its force, drive and limit beside a revolute one (BDF2)."""
    box = dict(box=[0.2, 0.1, 0.1], density=1000.0)
    from ..scene import Scene
    return Scene.from_dict(dict(
        dt=0.01, integrator='bdf2',
        bodies=[dict(name='base', position=[0.0, 0.0, 0.0], fixed=True, **box),
                dict(name='a', position=[0.2, 0.0, 0.0], **box),
                dict(name='b', position=[0.4, 0.0, 0.0], **box)],
        joints=[dict(name='hinge', parent='base', child='a', p0=[0.1, 0, -0.05], p1=[0.1, 0, 0.05]),
                dict(name='slide', type='prismatic', parent='a', child='b', p0=[0.3, 0, 0],
                     p1=[0.4, 0, 0], external_force=dict(force=1.0, enabled=True),
                     driving=dict(aim_distance=0.01, enabled=True),
                     limit=dict(lower=-0.01, upper=0.01), damping=0.5)]))


def _run_kernels():
    """Call every kernel entry point the simulator calls from Python, on both linear solves."""
    import numpy as np
    from ..model import compile_scene
    from ..solver.resident import Resident
    from ..solver.solver import Solver
    from ..state import Control, State
    from ..terms import driving, limit, ortho, prismatic, prismatic_driving, prismatic_limit, revolute, torque
    for scene in (_tiny_scene(), _loop_scene(), _slide_scene()):
        model = compile_scene(scene)
        solver = Solver(model)
        state, control = State.initial(model), Control.initial(model)
        solver.joint_rates(state)                             # World.reset of moving bodies
        state, _ = solver.step(state, control)                # BDF1 start
        resident = Resident(model.body_count, model.joint_count)
        resident.set(state)
        solver.step_resident(resident, control)              # World.step()
        state, _, _ = solver.advance(state, control, 3)       # batched, BDF2
        solver.clean_steps(state, control, 2)
        limits = np.concatenate([model.torque_effort_limit, model.prismatic_force_effort_limit])
        torque.clamp_commands(control.torque_value.copy(), limits, control.torque_value)
        torque.clamp_command(1.0, 2.0)
        revolute.max_separation(state.q, solver.data)
        prismatic.check_separations(state.q, solver.data)
        ctx = solver.context(state, control, model.dt)
        for term in (ortho, revolute, driving, limit, prismatic, prismatic_driving, prismatic_limit):
            term.energy(state.q, solver.data, ctx)
    # the body markers' poses (ros/markers.py)
    from ..smallmat import frame_poses
    one = np.zeros(1, dtype=np.intp)
    frame_poses(np.zeros((1, 3)), np.eye(3)[None], one, np.zeros((1, 3)), np.eye(3)[None], one,
                np.zeros((1, 3)), np.empty((1, 7)), np.empty((1, 3)))


def ensure_compiled(verbose: bool = True) -> dict:
    """Compile or load the kernels in this process (once). Returns {'seconds', 'compiled'}:
    compiled is False when they came from the on-disk cache."""
    global _done
    t0 = time.perf_counter()
    if _done:
        return {'seconds': 0.0, 'compiled': False}
    cache.install()
    fresh = not cache.marker().exists()
    if fresh and verbose:
        print('abd_joint_sim: compiling the physics kernels (first run on this machine, ~1 min)…',
              file=sys.stderr, flush=True)
    _done = True
    try:
        _run_kernels()
    except BaseException:
        _done = False
        raise
    cache.mark_compiled()
    return {'seconds': time.perf_counter() - t0, 'compiled': fresh}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='python -m abd_joint_sim.jit.warmup', description=__doc__.split('\n\n')[0])
    ap.parse_args(argv)
    try:
        out = ensure_compiled()
    except Exception as exc:  # noqa: BLE001 - one line, then fail
        print(f'abd_joint_sim: the physics kernels failed to compile: {type(exc).__name__}: {exc}',
              file=sys.stderr)
        return 1
    how = 'compiled' if out['compiled'] else 'loaded from the cache'
    print(f'abd_joint_sim: physics kernels {how} in {out["seconds"]:.1f} s ({cache.directory()})')
    return 0


if __name__ == '__main__':
    sys.exit(main())
