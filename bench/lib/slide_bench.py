"""What a sliding joint costs per body: the Franka Panda of pybullet_data with its first finger
sliding (a prismatic joint; the second finger mimics it and is locked), the same Panda with
that finger turned into a hinge (a revolute robot of the same bodies), with both fingers
locked, and a revolute arm (the KUKA iiwa), ours and MuJoCo side by side in one process, the
engines and robots taking turns round after round.

    python bench/peers.py sliding [--steps 2000] [--rounds 5] [--finger-force F]

Conditions as `bench/peers.py robots`: dt 1 ms, gravity, a fixed base, `robot_bench.torques`
on every actuated joint (on the finger that rule's value is a force in N: −0.6 N, which holds
it in its lower limit), contacts off in MuJoCo, which gets the file without the meshes it
cannot open and with the same joints locked. `steps` steps in one call on both sides
(`World.step(n)`, `mj_step(m, d, n)`), CPU time of this process, the median over the rounds.
The hinge variant is the file with the finger's `type="prismatic"` made `revolute` (its
limit, 0–0.04, then in rad, and −0.6 N m from the torque rule).
The per-body figure divides a step's time by the robot's bodies; the last lines give the
sliding Panda's per-body cost over each revolute robot's, per step and per Newton iteration
(a step of ours costs about its Newton iterations; MuJoCo's none), and MuJoCo's per-body
ratio beside it, so that a burst of load, which falls on both engines alike, shows.
"""
from __future__ import annotations

import argparse
import math
import os
import shutil
import statistics
import sys
import tempfile
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))     # this checkout's package
sys.path.insert(0, str(Path(__file__).resolve().parent))

from robot_bench import DT, mujoco_model, torques  # noqa: E402

PANDA, KUKA = 'franka_panda/panda.urdf', 'kuka_iiwa/model.urdf'
FINGERS = ['panda_finger_joint1', 'panda_finger_joint2']
#: (label, file in pybullet_data, joints held rigid on both sides, whether the sliding finger
#: is made a hinge); the first is the sliding robot, the others the revolute references
CASES = (('Panda, finger sliding', PANDA, FINGERS[1:], False),
         ('Panda, finger a hinge', PANDA, FINGERS[1:], True),
         ('Panda, fingers locked', PANDA, FINGERS, False),
         ('KUKA iiwa', KUKA, [], False))


def as_hinge(path, workdir):
    """A copy of the Panda URDF at `path` in `workdir` with panda_finger_joint1 revolute."""
    text = open(path).read()
    old = f'<joint name="{FINGERS[0]}" type="prismatic">'
    if old not in text:
        raise ValueError(f'{path}: no {old}')
    out = os.path.join(workdir, 'panda_finger_hinge.urdf')
    with open(out, 'w') as fh:
        fh.write(text.replace(old, f'<joint name="{FINGERS[0]}" type="revolute">'))
    return out


class _Ours:
    def __init__(self, path, lock, finger_force):
        from abd_joint_sim import Scene, World
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')             # the importer's repairs (docs/urdf.md)
            self.world = World(Scene.from_urdf(path, dt=DT, lock=list(lock)))
        names = self.world.actuated_joint_names
        efforts = torques(len(names))
        for k, name in enumerate(names):
            if name == FINGERS[0] and finger_force is not None:
                efforts[k] = finger_force
        self.efforts = efforts
        self.world.set_efforts(efforts)
        self.world.step(3)
        self.iterations = sum(self.world.step().newton_iterations for _ in range(200)) / 200
        self.bodies = self.world.model.body_count
        self.sliding = sum(t == 'prismatic' for t in self.world.joint_types)

    def run(self, steps):
        t0 = time.process_time()
        self.world.step(steps)
        return (time.process_time() - t0) / steps


class _MuJoCo:
    def __init__(self, path, lock, efforts):
        import mujoco as mj
        self.mj = mj
        self.model, self.note = mujoco_model(path, lock)
        self.model.opt.timestep = DT
        self.model.opt.disableflags |= mj.mjtDisableBit.mjDSBL_CONTACT
        self.data = mj.MjData(self.model)
        if self.model.nv != len(efforts):
            raise ValueError(f'MuJoCo has {self.model.nv} degrees of freedom, ours {len(efforts)} joints')
        self.data.qfrc_applied[:] = efforts
        mj.mj_step(self.model, self.data, 3)

    def run(self, steps):
        t0 = time.process_time()
        self.mj.mj_step(self.model, self.data, steps)
        return (time.process_time() - t0) / steps


def measure(steps, rounds, finger_force=None, peers=True, out=print):
    """Rows (dicts: label, bodies, sliding joints, Newton iterations per step, ours and MuJoCo
    s/step, the medians over `rounds`) of CASES, printed as a table with the ratios below;
    None without pybullet_data."""
    try:
        import pybullet_data
    except ImportError:
        out('sliding: skipped (pybullet_data not installed: requirements-bench.txt)')
        return None
    try:
        import mujoco  # noqa: F401
    except ImportError:
        peers = False
    engines = []
    workdir = tempfile.mkdtemp(prefix='slide_bench_')
    for label, name, lock, hinge in CASES:
        path = os.path.join(pybullet_data.getDataPath(), name)
        if hinge:
            path = as_hinge(path, workdir)
        ours = _Ours(path, lock, finger_force)
        mj = _MuJoCo(path, lock, ours.efforts) if peers else None
        engines.append((label, ours, mj))
    shutil.rmtree(workdir, ignore_errors=True)          # (both engines have read the file)
    times = {label: ([], []) for label, _, _ in engines}
    for _ in range(rounds):
        for label, ours, mj in engines:
            times[label][0].append(ours.run(steps))
            if mj:
                times[label][1].append(mj.run(steps))
    rows = []
    for label, ours, mj in engines:
        t, t_mj = times[label]
        rows.append(dict(label=label, bodies=ours.bodies, sliding=ours.sliding, its=ours.iterations,
                         ours=statistics.median(t), mujoco=statistics.median(t_mj) if t_mj else None,
                         note=mj.note if mj else ''))
    _print(rows, steps, rounds, finger_force, out)
    return rows


def _print(rows, steps, rounds, finger_force, out):
    force = '−0.6 N (the torque rule)' if finger_force is None else f'{finger_force:g} N'
    out(f'\nSliding against revolute joints (dt 1 ms, gravity, torque on every joint, finger force '
        f'{force}, {steps} steps in one call on both sides, median of {rounds} rounds, CPU time):')
    out('| robot | bodies | sliding joints | Newton it/step | ours µs/step | ours µs/body | '
        'MuJoCo µs/step | MuJoCo µs/body | ours/MuJoCo |')
    out('|' + '---|' * 9)
    for r in rows:
        mj = r['mujoco']
        cells = ('–', '–', '–') if mj is None else (f'{mj * 1e6:.1f}', f'{mj * 1e6 / r["bodies"]:.2f}',
                                                   f'{r["ours"] / mj:.2f}')
        out(f'| {r["label"]} | {r["bodies"]} | {r["sliding"]} | {r["its"]:.2f} | {r["ours"] * 1e6:.1f} | '
            f'{r["ours"] * 1e6 / r["bodies"]:.2f} | {cells[0]} | {cells[1]} | {cells[2]} |')
    notes = sorted({r['note'] for r in rows if r['note']})
    if notes:
        out(f'(MuJoCo: {"; ".join(notes)})')
    slide = rows[0]
    for ref in rows[1:]:
        per_body = (slide['ours'] / slide['bodies']) / (ref['ours'] / ref['bodies'])
        per_it = per_body * ref['its'] / slide['its']
        line = (f'{slide["label"]} / {ref["label"]}, ours per body: {per_body:.2f} per step, '
                f'{per_it:.2f} per Newton iteration')
        if slide['mujoco'] and ref['mujoco']:
            line += (f'; MuJoCo per body {(slide["mujoco"] / slide["bodies"]) / (ref["mujoco"] / ref["bodies"]):.2f}')
        out(line)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='bench/peers.py sliding', description=__doc__.split('\n\n')[0])
    ap.add_argument('--steps', type=int, default=2000, help='steps per timed call (default 2000)')
    ap.add_argument('--rounds', type=int, default=5, help='rounds of turns; the median is shown (default 5)')
    ap.add_argument('--finger-force', type=float, default=None,
                    help='the finger\'s force in N (on the hinge variant its torque in N m) instead '
                         'of the torque rule\'s (0: the finger moves only with the arm)')
    ap.add_argument('--no-peers', action='store_true', help='ours only')
    args = ap.parse_args(argv)
    if args.steps < 1 or args.rounds < 1:
        ap.error('--steps and --rounds must be at least 1')
    if args.finger_force is not None and not math.isfinite(args.finger_force):
        ap.error(f'--finger-force must be a finite number, got {args.finger_force}')
    measure(args.steps, args.rounds, args.finger_force, peers=not args.no_peers)
    return 0
