"""run_headless: run a scene with a torque/enable schedule, no DDS, and record sim_node's bag.

    run_headless --schedule sched.yaml [--scene default] --out bags/run1 [--duration 2]
    run_headless --from-bag bags/recorded --out bags/again
    ros2 run abd_joint_sim run_headless ...

Steps as fast as possible with sim_node's loop and records sim_node's bag. Input errors:
one line on stderr, exit status 2. A failed step: exit 1 (the bag is closed and readable).
See docs/replay.md.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from typing import Optional, Sequence

from abd_joint_sim.tools import cli

PROG = 'run_headless'
MAX_WARNINGS = 10     # clamp warnings listed one by one; the rest are counted
STORED = ('time_step', 'publish_rate', 'command_timeout', 'effort_limits', 'joints', 'frame_id')
"""The parameters of a bag that ``--from-bag`` (and replay_bag) take."""


def build_parser() -> argparse.ArgumentParser:
    p = cli.Parser(prog=PROG, description=(
        'Run an abd_joint_sim scene headless (no DDS, as fast as possible) with a torque/'
        'enable schedule and record the same rosbag2 (MCAP) bag sim_node records. '
        'Schedule format: docs/replay.md.'))
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument('--schedule', metavar='YAML', help='torque/enable schedule file')
    src.add_argument('--from-bag', metavar='BAG',
                     help='take the commands (and, unless --scene is given, the scene and '
                          'parameters) from a recorded bag')
    p.add_argument('--out', required=True, metavar='BAGDIR',
                   help='bag directory to write (must not exist)')
    p.add_argument('--scene', metavar='YAML|NAME',
                   help="scene file or packaged scene name ('default', 'hinge', ...); "
                        'default: the packaged default scene, or the bag\'s stored scene')
    p.add_argument('--duration', type=float, metavar='S',
                   help='simulated seconds (default: the schedule\'s `duration`, else last '
                        'event + 1 s; with --from-bag the recorded run\'s end)')
    p.add_argument('--dt', type=float, metavar='S',
                   help='time step [s] (the time_step parameter; default: schedule/bag '
                        'parameter, else the scene\'s dt)')
    rate = p.add_mutually_exclusive_group()
    rate.add_argument('--publish-every', type=int, metavar='N',
                      help='record /joint_states every N steps (1 = every step)')
    rate.add_argument('--publish-rate', type=float, metavar='HZ',
                      help='record /joint_states at HZ of simulated time (0 = every step; '
                           'default 100, as sim_node)')
    p.add_argument('--live', type=int, metavar='PORT',
                   help='watch the run live (Foxglove WebSocket on PORT, the page on PORT+1; '
                        'docs/live.md): the run is paced at real time and can be paused and '
                        'stepped; its results are unchanged')
    p.add_argument('--live-host', default='127.0.0.1', metavar='ADDR',
                   help='address the live view binds (default 127.0.0.1)')
    p.add_argument('-q', '--quiet', action='store_true', help='no summary line')
    return p


def main(argv: Optional[Sequence[str]] = None) -> int:
    return cli.run(PROG, build_parser(), _run, argv)


def _run(args) -> int:
    from abd_joint_sim.scene import Scene
    from abd_joint_sim.errors import SceneError, SimulationError
    from abd_joint_sim.record import BagError
    from abd_joint_sim.ros.convert import NS_PER_S, seconds_to_ns
    from abd_joint_sim.ros.params import resolve_scene, world_dt

    from .bagrun import BagInputError, config_for, load_bag, scene_from_text
    from .schedule import check_plan, load_schedule, MAX_TIME, ScheduleError
    from .sim import BagRecorder, HeadlessSim

    # -- what to run ---------------------------------------------------------------------
    with cli.input_errors(ScheduleError, BagInputError):
        if args.schedule:
            plan = load_schedule(args.schedule)
            overrides = dict(plan.parameters)
            provenance = f'schedule {args.schedule}'
        else:
            run = load_bag(args.from_bag)
            plan = run.plan
            overrides = {k: v for k, v in run.parameters.items() if k in STORED}
            provenance = f'commands of bag {args.from_bag}'
    for name, value in (('--dt', args.dt), ('--duration', args.duration),
                        ('--publish-rate', args.publish_rate)):
        if value is not None and (not math.isfinite(value) or value < 0.0
                                  or (value == 0.0 and name != '--publish-rate')):
            raise cli.InputError(f'{name} {value}: must be a finite number > 0'
                                 + (' (or 0)' if name == '--publish-rate' else ''))
    if args.duration is not None and args.duration > MAX_TIME:
        raise cli.InputError(f'--duration {args.duration:g}: beyond the supported {MAX_TIME:g} s')
    if args.live is not None:
        from abd_joint_sim.live import check_port
        with cli.input_errors(ValueError):
            check_port(args.live, '--live')
    if args.publish_every is not None and args.publish_every < 1:
        raise cli.InputError(f'--publish-every {args.publish_every}: must be >= 1')
    if args.dt is not None:
        overrides['time_step'] = args.dt
    if args.publish_rate is not None:
        overrides['publish_rate'] = args.publish_rate

    # -- scene and parameters (the same validation as sim_node's) ----------------------------
    urdf_text = ''
    with cli.input_errors(SceneError):
        if args.scene is not None or args.schedule:
            scene_path = resolve_scene(args.scene or '')
            scene = Scene.from_file(scene_path)      # .urdf: a robot with default options
        else:
            scene_path = run.scene_path
            scene = scene_from_text(run.scene_text, f'{args.from_bag}: scene.yaml')
            urdf_text = run.custom.get('abd_joint_sim.urdf', '')    # kept in the new bag
    with cli.input_errors(ValueError, SceneError):
        config = config_for(overrides, scene_path=scene_path)
        if args.publish_every is not None:
            dt = world_dt(config.time_step) or float(scene.dt)
            config.publish_rate = 0.0 if args.publish_every == 1 else \
                1.0 / (args.publish_every * dt)
        sim = HeadlessSim(scene, config, clamp=bool(args.schedule))
    config.record = args.out
    if args.duration is not None:
        plan.segments[-1].end_ns = seconds_to_ns(args.duration)
    with cli.input_errors(ScheduleError):
        check_plan(plan, sim.actuated, sim.commands.order, sim.fresh_buffer())
    late = [(cmd, seg) for seg in plan.segments for cmd in seg.commands if cmd.t_ns >= seg.end_ns]
    if late:
        cmd, seg = late[0]
        more = f' (and {len(late) - 1} later command(s))' if len(late) > 1 else ''
        print(f'{PROG}: warning: {cmd.describe()}{more}: at or after the end of the run '
              f'(t = {seg.end_ns / NS_PER_S:g} s), never takes effect', file=sys.stderr)

    # -- run and record --------------------------------------------------------------------
    live = pace = None
    if args.live is not None:       # a port in use: exit 2 before anything is recorded
        from abd_joint_sim.live import LiveError
        from abd_joint_sim.live.headless import RealTimePacer, start_live
        pace = RealTimePacer(sim.loop)
        with cli.input_errors(LiveError):
            live = start_live(PROG, scene, pace, args.live, args.live_host, PROG)
        print(f'{PROG}: {live.describe()}', file=sys.stderr, flush=True)
    try:
        recorder = BagRecorder(args.out, sim, scene_path, scene.source_text or '', extra_custom={
            'abd_joint_sim.recorded_by': f'run_headless ({provenance})'},
            urdf_text=getattr(scene, 'robot_description', '') or urdf_text)
    except BagError as exc:
        if live is not None:
            live.close()
        raise cli.InputError(str(exc)) from None
    wall0 = time.monotonic()
    status = 0
    try:
        sim.run(plan, recorder, pace=pace)
    except (SimulationError, ArithmeticError, ValueError) as exc:
        # a solver failure the world did not wrap (LinAlgError is a ValueError): one line
        what = str(exc) if isinstance(exc, SimulationError) else f'{type(exc).__name__}: {exc}'
        print(f'{PROG}: error: step at t={sim.world.time:.6f} s failed: {what}; the bag '
              f'ends there', file=sys.stderr)
        status = 1
    except KeyboardInterrupt:
        print(f'{PROG}: interrupted at t={sim.world.time:.6f} s; the bag ends there',
              file=sys.stderr)
        status = 130
    finally:
        recorder.close()
        if live is not None:
            live.close()
    wall = time.monotonic() - wall0
    for cmd, clamp in sim.clamps[:MAX_WARNINGS]:
        print(f'{PROG}: warning: {cmd.describe()}: {clamp}', file=sys.stderr)
    if len(sim.clamps) > MAX_WARNINGS:
        print(f'{PROG}: warning: {len(sim.clamps) - MAX_WARNINGS} more command(s) clamped',
              file=sys.stderr)
    if not args.quiet:
        c = recorder.counts
        print(f'{PROG}: {scene.name or scene_path}, dt {sim.world.dt:g} s, {sim.steps} steps to '
              f't = {sim.world.time:.6g} s in {wall:.2f} s wall; recorded '
              f'{c.get("/joint_states", 0)} joint states, '
              f'{sum(v for k, v in c.items() if "joint_torque" in k or k.endswith("joint_commands"))} '
              f'commands -> {args.out}'
              + (f'; {sim.not_converged} steps not converged' if sim.not_converged else ''))
    return status


if __name__ == '__main__':
    sys.exit(main())
