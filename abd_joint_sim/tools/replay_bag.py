"""replay_bag: watch a recorded bag live, at real time, in the browser or Foxglove.

    replay_bag BAG --live PORT [--speed 1] [--live-host 127.0.0.1]
    ros2 run abd_joint_sim replay_bag BAG --live 8765

The run is simulated again from the bag (as ``run_headless --from-bag``) and served by the
live server at real time x `--speed` (docs/live.md). Nothing is recorded. Input errors: one
line on stderr, exit 2.
"""
from __future__ import annotations

import argparse
import math
import sys
from typing import Optional, Sequence

from abd_joint_sim.tools import cli

PROG = 'replay_bag'


def build_parser() -> argparse.ArgumentParser:
    p = cli.Parser(prog=PROG, description=(
        'Replay a recorded abd_joint_sim bag at real time into the live view (a page in the '
        'browser, or Foxglove with its playback bar). docs/live.md.'))
    p.add_argument('bag', metavar='BAG', help='bag directory (or .mcap file) to replay')
    p.add_argument('--live', type=int, required=True, metavar='PORT',
                   help='Foxglove WebSocket port (the page is on PORT+1)')
    p.add_argument('--live-host', default='127.0.0.1', metavar='ADDR',
                   help='address to bind (default 127.0.0.1)')
    p.add_argument('--speed', type=float, default=1.0, metavar='X',
                   help='simulated seconds per wall second (default 1)')
    return p


def main(argv: Optional[Sequence[str]] = None) -> int:
    return cli.run(PROG, build_parser(), _run, argv)


def _run(args) -> int:
    from abd_joint_sim.errors import SceneError, SimulationError
    from abd_joint_sim.live import check_port, LiveError
    from abd_joint_sim.live.headless import RealTimePacer, Restart, start_live
    from abd_joint_sim.ros.loop import LoopOutput

    from .bagrun import BagInputError, config_for, load_bag, scene_from_text
    from .run_headless import STORED
    from .sim import HeadlessSim

    with cli.input_errors(ValueError):
        check_port(args.live, '--live')
    if not (math.isfinite(args.speed) and 0.0 < args.speed <= 1e3):
        raise cli.InputError(f'--speed {args.speed}: must be a number in (0, 1000]')
    with cli.input_errors(BagInputError, SceneError, ValueError):
        run = load_bag(args.bag)
        scene = scene_from_text(run.scene_text, f'{args.bag}: scene.yaml')
        config = config_for({k: v for k, v in run.parameters.items() if k in STORED},
                            scene_path=run.scene_path)
        sim = HeadlessSim(scene, config, clamp=False)
    plan = run.plan
    end_ns = max(seg.end_ns for seg in plan.segments)
    pacer = RealTimePacer(sim.loop, speed=args.speed, end_ns=end_ns)
    with cli.input_errors(LiveError):
        live = start_live(PROG, scene, pacer, args.live, args.live_host, f'{PROG} {args.bag}',
                          playback=pacer, playback_end_ns=end_ns)
    print(f'{PROG}: {args.bag}: {end_ns / 1e9:g} s of simulated time; {live.describe()}; '
          'Ctrl-C ends', file=sys.stderr, flush=True)
    status = 0
    try:
        while True:
            try:
                sim.run(plan, LoopOutput(), pace=pacer)
                pacer.wait_at_end()
            except Restart:
                pass
            sim = HeadlessSim(scene, config, clamp=False)
            pacer.replace_loop(sim.loop)
    except KeyboardInterrupt:
        pass
    except (SimulationError, ArithmeticError) as exc:
        print(f'{PROG}: error: step at t={sim.world.time:.6f} s failed: {exc}', file=sys.stderr)
        status = 1
    finally:
        live.close()
    return status


if __name__ == '__main__':
    sys.exit(main())
