"""Compile the physics kernels once per install: `python -m abd_joint_sim.jit.warmup`.

Kernels are cached on disk (cache.py): a compile takes about a minute of CPU, a load a few
seconds. `ensure_compiled()`, called by every Solver, runs tiny scenes through every kernel
signature the simulator uses, printing one line to stderr before a compile starts and a
progress line every PROGRESS_SECONDS (kernels stored / expected); a marker file records a
completed compile. With two or more cores a second process compiles the kernels the main
sequence reaches last (`_helper_kernels`), each loading what the other stored.
ABD_COMPILE_JOBS=1 compiles in this process alone.

Exit status of the command: 0 on success, 1 when the kernels fail to compile.
"""
from __future__ import annotations

import argparse
import contextlib
import os
import subprocess
import sys
import threading
import time

from . import cache

_done = False
#: seconds between two progress lines of a compile
PROGRESS_SECONDS = 5.0
#: kernel signatures a complete compile stores (cache.kernel_count(); test_warmup checks it):
#: the progress line's total when no earlier compile on this machine recorded its own count
EXPECTED_KERNELS = 141
#: the second compiling process, while it runs (`_helper_kernels`)
_helper = None


def _scene(names, joints, **settings):
    """A fixed box 'base' at the origin and free boxes `names` 0.2 m apart along x."""
    from ..scene import Scene
    box = dict(box=[0.2, 0.1, 0.1], density=1000.0)
    bodies = [dict(name='base', position=[0.0, 0.0, 0.0], fixed=True, **box)]
    bodies += [dict(name=n, position=[0.2 * (k + 1), 0.0, 0.0], **box) for k, n in enumerate(names)]
    return Scene.from_dict(dict(dt=0.01, bodies=bodies, joints=joints, **settings))


def _terms_scene():
    """A joint per term of terms.TERMS that has an EXAMPLE, in a chain from the base, with the
    term's keys (a hinge about z, or a slide along x), gravity and BDF2: every term is used."""
    from ..terms import TERMS
    terms = [t for t in TERMS if hasattr(t, 'EXAMPLE')]
    names = ['base'] + [f'b{k}' for k in range(len(terms))]
    joints = []
    for k, term in enumerate(terms):
        x = 0.2 * k + 0.1
        ends = ([x, 0, 0], [x + 0.1, 0, 0]) if term.EXAMPLE.get('type') == 'prismatic' else \
            ([x, 0, -0.05], [x, 0, 0.05])
        joints.append(dict(name=term.__name__.rsplit('.', 1)[1], parent=names[k],
                           child=names[k + 1], p0=ends[0], p1=ends[1], **term.EXAMPLE))
    return _scene(names[1:], joints, gravity=[0.0, 0.0, -9.81], integrator='bdf2')


def _loop_scene():
    """Three free bodies in a closed loop: the dense linear solve."""
    return _scene('abc', [dict(name=f'{p}_{c}', parent=p, child=c, p0=[0.1, 0, -0.05],
                               p1=[0.1, 0, 0.05])
                          for p, c in [('base', 'a'), ('a', 'b'), ('b', 'c'), ('c', 'a')]])


def _run_kernels():
    """Call every kernel entry point the simulator calls from Python, on both linear solves."""
    import numpy as np
    from ..model import compile_scene
    from ..solver.resident import Resident
    from ..solver.solver import Solver
    from ..state import Control, State
    from ..terms import ENERGY_TERMS, prismatic, revolute, torque
    for scene in (_terms_scene(), _loop_scene()):
        model = compile_scene(scene)
        solver = Solver(model)
        state, control = State.initial(model), Control.initial(model)
        solver.joint_rates(state)                             # World.reset of moving bodies
        state, _ = solver.step(state, control)                # step.steps, one BDF1 step
        _helper_go()                                          # its step_resident may start
        state = solver.steps(state, control, 3).state         # step.steps, BDF2
        limits = np.concatenate([model.torque_effort_limit, model.prismatic_force_effort_limit])
        torque.clamp_commands(control.torque_value.copy(), limits, control.torque_value)
        torque.clamp_command(1.0, 2.0)
        revolute.max_separation(state.q, solver.data)
        prismatic.check_separations(state.q, solver.data)
        ctx = solver.context(state, control, model.dt)
        for term in ENERGY_TERMS:                            # World.mechanical_energy
            if term.STORED:
                term.energy(state.q, solver.data, ctx)
        _helper_wait()
        resident = Resident(model.body_count, model.joint_count)
        resident.set(state)
        solver._step_resident(resident, control)              # step.step_resident: World.step()
    # the body markers' poses (ros/markers.py)
    from ..smallmat import frame_poses
    one = np.zeros(1, dtype=np.intp)
    frame_poses(np.zeros((1, 3)), np.eye(3)[None], one, np.zeros((1, 3)), np.eye(3)[None], one,
                np.zeros((1, 3)), np.empty((1, 7)), np.empty((1, 3)))


def _late_subtrees():
    """A compiled function (not cached, never run) whose compile compiles the subtrees
    `newton.minimize` reaches last, with its argument types (borrowed structs, literal True)."""
    from numba import njit
    from ..solver import linsolve, retraction
    from ..terms import damping, driving, limit
    from . import refcounts

    @njit
    def late_subtrees(q, m, ws):
        m, ws = refcounts.struct(m), refcounts.struct(ws)
        ctx = refcounts.struct(ws.ctx)
        driving.accumulate(q, m, ctx, ws.grad, ws.diag, ws.pair, True)
        limit.accumulate(q, m, ctx, ws.grad, ws.diag, ws.pair, True)
        damping.accumulate(q, m, ctx, ws.grad, ws.diag, ws.pair, True)
        linsolve.solve(m, ws.diag, ws.pair, ws.grad, ws.dq, ws)
        retraction.retract(q, ws.dq, 1.0, m, ws, ws.trial)
    return late_subtrees


def _helper_kernels(go) -> None:
    """The second process's share: the subtrees the main sequence (`_run_kernels`) reaches
    last, then, once `go` returns (`step.one_step` is stored), `step.step_resident`."""
    from numba import typeof
    from ..model import compile_scene
    from ..solver.resident import Resident
    from ..solver.solver import Solver
    from ..state import Control, State
    model = compile_scene(_terms_scene())
    solver = Solver(model)
    state, control = State.initial(model), Control.initial(model)
    _late_subtrees().compile((typeof(state.q), typeof(solver.data), typeof(solver.work)))
    go()
    resident = Resident(model.body_count, model.joint_count)
    resident.set(state)
    solver._step_resident(resident, control)


def _jobs() -> int:
    try:
        return max(1, int(os.environ.get('ABD_COMPILE_JOBS', '') or len(os.sched_getaffinity(0))))
    except (ValueError, AttributeError):
        return 1


def _start_helper():
    """`python -m abd_joint_sim.jit.warmup --helper` on this copy of the package, or None."""
    global _helper
    if _jobs() < 2:
        return None
    env = dict(os.environ, ABD_COMPILE_JOBS='1')
    root = str(cache.PACKAGE.parent)
    env['PYTHONPATH'] = root + (os.pathsep + env['PYTHONPATH'] if env.get('PYTHONPATH') else '')
    try:
        _helper = subprocess.Popen([sys.executable, '-m', 'abd_joint_sim.jit.warmup', '--helper'],
                                   stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                                   stderr=subprocess.DEVNULL, env=env, cwd=root)
    except OSError:
        _helper = None
    return _helper


def _helper_go() -> None:
    """Let the helper start step_resident (the main process has stored `step.one_step`)."""
    if _helper is not None and _helper.stdin is not None and not _helper.stdin.closed:
        try:
            _helper.stdin.write(b'go\n')
            _helper.stdin.close()
        except OSError:
            pass


def _helper_wait() -> None:
    """Wait for the helper (whatever it failed to store, this process compiles next)."""
    global _helper
    if _helper is None:
        return
    _helper_go()
    try:
        _helper.wait(timeout=600)
    except subprocess.TimeoutExpired:
        _helper.kill()
        _helper.wait()
    _helper = None


@contextlib.contextmanager
def _progress(verbose: bool):
    """A line to stderr every PROGRESS_SECONDS while the kernels compile: kernels stored in
    the cache (by either process) / the count a complete compile stores."""
    total = cache.previous_kernel_count() or EXPECTED_KERNELS
    stop, t0 = threading.Event(), time.perf_counter()

    def run():
        while not stop.wait(PROGRESS_SECONDS):
            done = cache.kernel_count()
            print(f'abd_joint_sim: compiling the physics kernels: {done}/{max(done, total)} '
                  f'stored, {time.perf_counter() - t0:.0f} s', file=sys.stderr, flush=True)
    thread = threading.Thread(target=run, daemon=True)
    if verbose:
        thread.start()
    try:
        yield
    finally:
        stop.set()
        if thread.is_alive():
            thread.join()


def ensure_compiled(verbose: bool = True) -> dict:
    """Compile or load the kernels in this process (once). Returns {'seconds', 'compiled'}:
    compiled is False when they came from the on-disk cache."""
    global _done
    t0 = time.perf_counter()
    if _done:
        return {'seconds': 0.0, 'compiled': False}
    cache.install()
    fresh = not cache.marker().exists()
    jobs = min(_jobs(), 2) if fresh else 1
    if fresh and verbose:
        print('abd_joint_sim: compiling the physics kernels (first run on this machine: about '
              f'1 min on 2 idle cores, longer on a busy machine; {jobs} process'
              f'{"es" if jobs > 1 else ""}, a line every {PROGRESS_SECONDS:.0f} s)…',
              file=sys.stderr, flush=True)
    _done = True
    try:
        with _progress(verbose and fresh):
            if jobs > 1:
                _start_helper()
            _run_kernels()
    except BaseException:
        _done = False
        if _helper is not None:
            _helper.kill()
            _helper_wait()
        raise
    cache.mark_compiled()
    return {'seconds': time.perf_counter() - t0, 'compiled': fresh}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='python -m abd_joint_sim.jit.warmup', description=__doc__.split('\n\n')[0])
    ap.add_argument('--helper', action='store_true', help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.helper:                        # the second compiling process (_start_helper)
        cache.install()
        _helper_kernels(lambda: sys.stdin.readline())
        return 0
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
