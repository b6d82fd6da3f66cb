"""Size and cost of the body markers (docs/bag-format.md "Markers"): bytes per simulated
second of a headless default-scene run (the layout sim_node records) with and without
markers, the CDR size of one MarkerArray and the time to build one.

    python bench/node_load.py markers [--duration 10]
"""
import argparse
import os
from pathlib import Path
import shutil
import sys
import tempfile
import time

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from abd_joint_sim import Scene
from abd_joint_sim.ros.params import config_from_values, resolve_scene
from abd_joint_sim.tools.schedule import parse_schedule
from abd_joint_sim.tools.sim import BagRecorder, HeadlessSim
from abd_joint_sim.ros.markers import MarkerBuilder
from rclpy.serialization import serialize_message


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog='bench/node_load.py markers', description=__doc__.splitlines()[0])
    parser.add_argument('--duration', type=float, default=10.0, help='simulated seconds')
    dur = parser.parse_args(argv).duration
    sched = {'duration': dur, 'events': [{'t': 0.0, 'torque': {'shoulder': 2.0, 'elbow': 1.0}},
                                          {'t': dur / 2, 'torque': {'shoulder': -2.0, 'elbow': -1.0}}]}
    tmp = tempfile.mkdtemp()
    sp = resolve_scene('default'); scene = Scene.from_yaml(sp)
    for label, extra in (('no markers', {'marker_rate': 0.0}), ('markers 30 Hz', {}),
                         ('markers 30 Hz + joint axes', {'marker_joint_axes': True}),
                         ('markers 100 Hz', {'marker_rate': 100.0})):
        sim = HeadlessSim(scene, config_from_values({'scene': 'default', **extra}))
        path = os.path.join(tmp, label.replace(' ', '_').replace('+', ''))
        rec = BagRecorder(path, sim, sp, scene.source_text)
        sim.run(parse_schedule(sched), rec); rec.close()
        size = sum(os.path.getsize(os.path.join(path, f)) for f in os.listdir(path) if f.endswith('.mcap'))
        print(f'{label:28s} {size / dur / 1024:8.1f} KiB per simulated s (zstd chunks), markers {rec.counts.get("/markers", 0)}')
    b = MarkerBuilder(scene)
    sim = HeadlessSim(scene, config_from_values({'scene': 'default'}))
    msg = b.build(0, sim.world.body_pose)
    print('one MarkerArray of the default scene:', len(serialize_message(msg)), 'bytes of CDR')
    n = 2000; t0 = time.perf_counter()
    for i in range(n): b.build(i, sim.world.body_pose)
    print(f'build: {(time.perf_counter() - t0) / n * 1e6:.0f} us per MarkerArray (3 bodies)')
    shutil.rmtree(tmp)

    return 0
