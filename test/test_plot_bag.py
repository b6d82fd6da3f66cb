"""plot_bag: a fresh bag becomes PNGs (joints.png, poses.png) that show the motion; clear
one-line errors without matplotlib and for a bag it cannot read."""
from __future__ import annotations

import sys

import numpy as np
import pytest

from abd_joint_sim import Scene
from abd_joint_sim.ros.params import config_from_values, resolve_scene
from abd_joint_sim.tools import plot_bag
from abd_joint_sim.tools.schedule import parse_schedule
from abd_joint_sim.tools.sim import BagRecorder, HeadlessSim

SCHEDULE = {'duration': 1.2, 'events': [
    {'t': 0.0, 'torque': {'shoulder': 3.0, 'elbow': 1.0}},
    {'t': 0.6, 'torque': {'shoulder': -3.0, 'elbow': -1.0}}]}


def _bag(path, **params):
    scene_path = resolve_scene('default')
    scene = Scene.from_yaml(scene_path)
    sim = HeadlessSim(scene, config_from_values({'scene': 'default', **params}))
    rec = BagRecorder(str(path), sim, scene_path, scene.source_text)
    try:
        sim.run(parse_schedule(SCHEDULE), rec)
    finally:
        rec.close()
    return path


def _png_size(path):
    data = path.read_bytes()
    assert data[:8] == b'\x89PNG\r\n\x1a\n', f'{path} is not a PNG'
    return int.from_bytes(data[16:20], 'big'), int.from_bytes(data[20:24], 'big')


@pytest.mark.slow
def test_fresh_bag_to_pngs(tmp_path, capsys):
    bag = _bag(tmp_path / 'run', marker_joint_axes=True)
    out = tmp_path / 'png'
    assert plot_bag.main([str(bag), '--out', str(out), '--times', '0,0.4,0.8,1.2']) == 0
    line = capsys.readouterr().out
    assert 'poses at t = 0.000, 0.400, 0.800, 1.200 s (xy view)' in line, line
    for name in ('joints.png', 'poses.png'):
        w, h = _png_size(out / name)
        assert w > 600 and h > 300 and (out / name).stat().st_size > 20_000
    # What the pictures are drawn from: the commands where they took effect, and markers
    # that moved (the forearm's marker moves between the first and the last panel).
    run = plot_bag.read_run(bag)
    assert sorted({round(t, 6) for t, _ in run.commands}) == [0.0, 0.6]
    assert run.joint_names == ['shoulder', 'elbow'] and len(run.t) == 121
    first, last = run.markers[0][1], run.markers[-1][1]
    moved = [np.hypot(a.pose.position.x - b.pose.position.x,
                      a.pose.position.y - b.pose.position.y)
             for a, b in zip(first.markers, last.markers) if a.ns == 'bodies/forearm']
    assert moved and moved[0] > 0.05
    # The image itself differs between panels: the strip is not four copies of t = 0.
    import matplotlib.image as mpimg
    img = mpimg.imread(out / 'poses.png')
    quarter = img.shape[1] // 4
    assert np.abs(img[:, :quarter] - img[:, -quarter:]).mean() > 1e-3


def test_each_body_its_own_colour_fixed_ones_grey_and_the_title_names_the_scene(tmp_path):
    """body_styles: a distinct colour per moving body (never the fixed bodies' grey), grey
    for the fixed ones, from the stored scene or, without one, the bodies that never moved;
    the default title names the scene (a URDF robot: its <robot name>)."""
    run = plot_bag.read_run(_bag(tmp_path / 'b'))
    styles = plot_bag.body_styles(run)
    assert styles == {'pedestal': (plot_bag.FIXED_COLOUR, True),
                      'upper_arm': (plot_bag.BODY_COLOURS[0], False),
                      'forearm': (plot_bag.BODY_COLOURS[1], False)}
    run.fixed_bodies = None                 # a bag without a readable scene
    assert plot_bag.body_styles(run) == styles
    assert run.scene_name == 'default'
    assert plot_bag.scene_name({'abd_joint_sim.urdf': '<robot name="demo_arm">',
                                'abd_joint_sim.scene_path': 'demo_arm.urdf'}) == 'demo_arm'
    assert len(set(plot_bag.BODY_COLOURS)) == len(plot_bag.BODY_COLOURS)
    assert plot_bag.FIXED_COLOUR not in plot_bag.BODY_COLOURS


def test_grid_fits_the_poses_and_trails_are_bounded(tmp_path):
    assert [plot_bag.grid_shape(n) for n in (1, 4, 5, 6, 8, 9)] == \
        [(1, 1), (1, 4), (1, 5), (2, 3), (2, 4), (2, 5)]
    run = plot_bag.read_run(_bag(tmp_path / 'b'))
    k = len(run.markers) - 1                # t = 1.2 s, markers at 30 Hz
    t = run.markers[k][0]
    paths = plot_bag.trails(run, k)
    assert paths and all(t - plot_bag.TRAIL_SECONDS - 1e-9 <= te <= t
                         for path in paths.values() for te, _ in path)
    assert max(len(path) for path in paths.values()) == 16      # 0.5 s at 30 Hz, both ends


def test_command_note_only_when_there_were_commands(tmp_path):
    run = plot_bag.read_run(_bag(tmp_path / 'b'))
    assert plot_bag.joints_notes(run) == 'dotted: a command took effect'
    run.commands = []
    assert plot_bag.joints_notes(run) == ''
    run.resets = [0.5]
    assert plot_bag.joints_notes(run) == 'dashed: reset'


def test_view_follows_the_motion_plane(tmp_path):
    run = plot_bag.read_run(_bag(tmp_path / 'b'))
    assert plot_bag.choose_view(run) == 'xy'       # the SCARA arm moves horizontally


def test_no_markers_gives_joints_only(tmp_path, capsys):
    bag = _bag(tmp_path / 'plain', marker_rate=0.0)
    assert plot_bag.main([str(bag), '--out', str(tmp_path / 'o')]) == 0
    assert (tmp_path / 'o' / 'joints.png').is_file()
    assert not (tmp_path / 'o' / 'poses.png').exists()
    assert 'no markers in the bag' in capsys.readouterr().out


def test_without_matplotlib_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, 'matplotlib', None)     # import fails
    assert plot_bag.main([str(tmp_path / 'any'), '--out', str(tmp_path / 'o')]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'matplotlib is not installed' in err[0] and \
        'requirements-study.txt' in err[0]


def test_unreadable_bag_one_line(tmp_path, capsys):
    assert plot_bag.main([str(tmp_path / 'missing'), '--out', str(tmp_path / 'o')]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith('plot_bag: ') and 'missing' in err[0]


def test_bad_times_are_refused(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        plot_bag.main([str(tmp_path), '--out', str(tmp_path / 'o'), '--times', '0,abc'])
    assert exc.value.code == 2
    assert "'0,abc' is not a comma-separated list" in capsys.readouterr().err


def test_reset_starts_a_new_segment(tmp_path):
    """A ~/reset (simulated time back to 0) is drawn after the first segment, not over it."""
    from abd_joint_sim.tools.schedule import Plan
    plan = parse_schedule(SCHEDULE)
    first = plan.segments[0]
    second = parse_schedule({'duration': 0.5, 'events': [
        {'t': 0.1, 'torque': {'shoulder': -1.0}}]}).segments[0]
    scene_path = resolve_scene('default')
    scene = Scene.from_yaml(scene_path)
    sim = HeadlessSim(scene, config_from_values({'scene': 'default'}))
    rec = BagRecorder(str(tmp_path / 'reset'), sim, scene_path, scene.source_text)
    try:
        sim.run(Plan([first, second]), rec)
    finally:
        rec.close()
    run = plot_bag.read_run(tmp_path / 'reset')
    assert run.resets == [pytest.approx(1.2)]
    assert run.t == sorted(run.t) and run.t[-1] == pytest.approx(1.7)
    assert sorted({round(t, 6) for t, _ in run.commands}) == [0.0, 0.6, 1.3]
    assert plot_bag.main([str(tmp_path / 'reset'), '--out', str(tmp_path / 'o'), '-q']) == 0
