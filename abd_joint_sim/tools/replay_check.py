"""replay_check: re-simulate a bag's recorded commands and compare the joint states.

    replay_check BAG [--atol-angle 1e-6] [--atol-velocity 1e-5] [--atol-effort 1e-9]
    ros2 run abd_joint_sim replay_check BAG

Exit status: 0 all within tolerance; 1 a deviation beyond tolerance, a recorded state the
re-simulation never reached, or different joint names; 2 unusable input. See docs/replay.md.
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass, field
import math
import sys
import time
from typing import Optional, Sequence

from abd_joint_sim.ros.loop import LoopOutput
from abd_joint_sim.tools import cli

PROG = 'replay_check'

DEFAULT_ATOL = {'position': 1e-6, 'velocity': 1e-5, 'effort': 1e-9}
UNITS = {'position': 'rad', 'velocity': 'rad/s', 'effort': 'N m'}
FIELDS = ('position', 'velocity', 'effort')


@dataclass
class Worst:
    deviation: float = 0.0
    joint: str = ''
    t_ns: int = 0
    recorded: float = 0.0
    replayed: float = 0.0
    beyond: int = 0
    first: Optional[tuple[str, int]] = None


@dataclass
class ReplayResult:
    bag: str
    scene_name: str
    dt: float
    segments: int
    steps: int
    commands: int
    recorded: int
    compared: int = 0
    joints: int = 0
    worst: dict[str, Worst] = field(default_factory=lambda: {f: Worst() for f in FIELDS})
    atol: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_ATOL))
    unmatched: list[tuple[int, int]] = field(default_factory=list)
    """(segment, stamp ns) of recorded states the re-simulation never produced."""
    missing: list[tuple[int, int]] = field(default_factory=list)
    """(segment, stamp ns) of states the node's publish schedule says were published (up to
    the segment's last recorded state) that the bag does not hold: a gap."""
    name_errors: list[str] = field(default_factory=list)
    unapplied: int = 0
    wall: float = 0.0

    @property
    def ok(self) -> bool:
        return (not self.unmatched and not self.missing and not self.name_errors
                and self.compared > 0 and all(self.worst[f].beyond == 0 for f in FIELDS))

    def report(self) -> str:
        s = 's' if self.segments != 1 else ''
        lines = [f'{PROG}: {self.bag}: scene {self.scene_name}, dt {self.dt:g} s, '
                 f'{self.segments} segment{s}, {self.commands} commands replayed, '
                 f'{self.steps} steps in {self.wall:.2f} s wall',
                 f'compared {self.compared} of {self.recorded} recorded joint states '
                 f'({self.joints} joints each)']
        for f in FIELDS:
            w = self.worst[f]
            where = (f' ({w.joint}, t={w.t_ns * 1e-9:.6f} s: recorded {w.recorded:.12g}, '
                     f'replayed {w.replayed:.12g})' if w.deviation > 0.0 else '')
            verdict = 'ok' if w.beyond == 0 else (
                f'FAIL: {w.beyond} value(s) beyond, first {w.first[0]} at '
                f't={w.first[1] * 1e-9:.6f} s')
            lines.append(f'  {f:<8}  worst |diff| {w.deviation:.3g} {UNITS[f]}{where}; '
                         f'atol {self.atol[f]:g}: {verdict}')
        lines += [f'  names: {err}' for err in self.name_errors[:5]]
        if self.unmatched:
            seg, t = self.unmatched[0]
            lines.append(f'  {len(self.unmatched)} recorded state(s) never reached by the '
                         f're-simulation, first t={t * 1e-9:.9f} s (segment {seg})')
        if self.missing:
            seg, t = self.missing[0]
            lines.append(f'  GAP: {len(self.missing)} joint state(s) the publish schedule says '
                         f'were published are not in the bag, first t={t * 1e-9:.9f} s '
                         f'(segment {seg})')
        if self.unapplied:
            lines.append(f'  {self.unapplied} recorded command(s) after the last step, '
                         'not applied')
        if self.ok:
            lines.append('OK: replay reproduces the recorded joint states')
        elif self.compared == 0 and not self.unmatched and not self.name_errors:
            lines.append('MISMATCH: no joint states compared')
        elif self.missing and not any(self.worst[f].beyond for f in FIELDS):
            lines.append('MISMATCH: the bag misses scheduled joint states (see GAP above)')
        else:
            bad = [f for f in FIELDS if self.worst[f].beyond]
            what = ', '.join(f'{f} of joint {self.worst[f].joint!r} (worst at '
                             f't={self.worst[f].t_ns * 1e-9:.6f} s)' for f in bad)
            lines.append('MISMATCH: ' + (what or 'see above'))
        return '\n'.join(lines)


class _Comparer(LoopOutput):
    """Loop output: compares the state after every step with the ones recorded then."""

    every_state = True

    def __init__(self, result: ReplayResult, recorded, sim):
        self.result = result
        self.recorded = recorded          # list per segment: {t_ns: [RecordedState]}
        self.sim = sim
        self.names = list(sim.world.joint_names)
        self.index = {n: i for i, n in enumerate(self.names)}
        self.seen: set[tuple[int, int]] = set()
        self.due: list[tuple[int, int]] = []     # (segment, stamp) the schedule published

    def joint_state(self, t_ns: int, position, velocity, effort) -> None:
        segment = self.sim.segment
        if segment >= len(self.recorded):
            return
        if getattr(self.sim.loop, 'state_due', False):
            self.due.append((segment, t_ns))
        states = self.recorded[segment].get(t_ns)
        if not states:
            return
        self.seen.add((segment, t_ns))
        names, index, res = self.names, self.index, self.result
        values = {'position': position, 'velocity': velocity, 'effort': effort}
        for rec in states:
            res.compared += 1
            res.joints = max(res.joints, len(rec.names))
            if rec.names != names and len(res.name_errors) < 20:
                res.name_errors.append(f't={t_ns * 1e-9:.6f} s: recorded {rec.names}, '
                                       f'scene joints {names}')
            for f in FIELDS:
                arr = getattr(rec, f)
                worst = res.worst[f]
                for k, name in enumerate(rec.names):
                    i = index.get(name)
                    if i is None or k >= len(arr):
                        continue
                    a, b = float(arr[k]), float(values[f][i])
                    d = abs(a - b)
                    if math.isnan(d):       # NaN in both: equal; in one: infinitely apart
                        d = 0.0 if math.isnan(a) and math.isnan(b) else math.inf
                    if d > worst.deviation or (worst.joint == '' and d >= worst.deviation):
                        worst.deviation, worst.joint, worst.t_ns = d, name, t_ns
                        worst.recorded, worst.replayed = a, b
                    if d > res.atol[f]:
                        worst.beyond += 1
                        if worst.first is None:
                            worst.first = (name, t_ns)


def replay(bag: str, atol: Optional[dict[str, float]] = None) -> ReplayResult:
    """Re-simulate `bag` and compare; cli.InputError (exit status 2) if the bag is unusable."""
    from abd_joint_sim.errors import SceneError, SimulationError

    from .bagrun import BagInputError, config_for, load_bag, scene_from_text
    from .schedule import check_plan, ScheduleError
    from .sim import HeadlessSim

    with cli.input_errors(BagInputError):
        run = load_bag(bag)
    with cli.input_errors(SceneError, ValueError, prefix='stored scene/parameters: '):
        scene = scene_from_text(run.scene_text, f'{bag}: scene.yaml')
        config = config_for(run.parameters, scene_path=run.scene_path)
        sim = HeadlessSim(scene, config, clamp=False)
    stored_dt = run.custom.get('abd_joint_sim.time_step')
    if stored_dt:
        try:
            ok = math.isclose(float(stored_dt), sim.world.dt, rel_tol=1e-12, abs_tol=0.0)
        except ValueError:
            ok = False
        if not ok:
            raise cli.InputError(
                f'{bag}: stored time step {stored_dt} differs from the one the stored scene '
                f'and parameters give ({sim.world.dt!r})')
    with cli.input_errors(ScheduleError,
                          prefix=f'{bag}: recorded command does not fit the stored scene: '):
        check_plan(run.plan, sim.actuated, sim.commands.order, sim.fresh_buffer())
    if run.state_count == 0:
        raise cli.InputError(f'{bag}: no /joint_states messages to compare')
    result = ReplayResult(bag=bag, scene_name=scene.name or run.scene_path, dt=sim.world.dt,
                          segments=len(run.plan.segments), steps=0,
                          commands=run.command_count, recorded=run.state_count)
    result.atol.update(atol or {})
    comparer = _Comparer(result, run.states, sim)
    wall0 = time.monotonic()
    try:
        sim.run(run.plan, comparer)
    except SimulationError as exc:
        result.name_errors.append(f'the re-simulation failed at t={sim.world.time:.6f} s: '
                                  f'{exc}')
    result.wall = time.monotonic() - wall0
    result.steps = sim.steps
    result.unapplied = len(sim.unapplied)
    result.unmatched = [(k, t_ns) for k, seg in enumerate(run.states) for t_ns in sorted(seg)
                        if (k, t_ns) not in comparer.seen]
    # A gap: a state due by the publish schedule, before the segment's last recorded one
    # (a recording cut short, e.g. a killed recorder's lost chunk, ends the check there).
    last = [max(seg) if seg else -1 for seg in run.states]
    result.missing = [(k, t) for k, t in comparer.due
                      if k < len(last) and t <= last[k] and t not in run.states[k]]
    return result


def _tolerance(text: str) -> float:
    value = float(text)
    if not (math.isfinite(value) and value >= 0.0):
        raise argparse.ArgumentTypeError(f'{text}: must be a finite number >= 0')
    return value


def build_parser() -> argparse.ArgumentParser:
    p = cli.Parser(prog=PROG, description=(
        'Re-simulate the commands recorded in an abd_joint_sim bag with its stored scene and '
        'parameters and compare every recorded joint state. Exit 0 = reproduced within '
        'tolerance, 1 = not, 2 = unusable input. See docs/replay.md.'))
    p.add_argument('bag', help='bag directory (or its .mcap file)')
    for f, flag, metavar in zip(FIELDS, ('angle', 'velocity', 'effort'), ('RAD', 'RAD/S', 'NM')):
        p.add_argument(f'--atol-{flag}', type=_tolerance, default=DEFAULT_ATOL[f], dest=f,
                       metavar=metavar, help=f'{f} tolerance [{UNITS[f]}] (default %(default)g)')
    return p


def main(argv: Optional[Sequence[str]] = None) -> int:
    return cli.run(PROG, build_parser(), _run, argv)


def _run(args) -> int:
    result = replay(args.bag, {f: getattr(args, f) for f in FIELDS})
    print(result.report())
    return 0 if result.ok else 1


if __name__ == '__main__':
    sys.exit(main())
