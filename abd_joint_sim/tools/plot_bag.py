"""plot_bag: pictures of a recorded run (PNG), for people to look at (docs/viewing.md).

    python -m abd_joint_sim.tools.plot_bag BAG --out DIR [--times 0,0.5,1] [--view xy]

writes ``DIR/joints.png`` (joint angle, velocity and effort against simulated time; dotted
lines where a recorded command took effect, dashed ones at resets, after which the next
segment is drawn on) and, when the bag has markers, ``DIR/poses.png`` (the bodies at chosen
times projected on the plane they move in, with each moving body's path over the last
TRAIL_SECONDS; a body with mesh visuals is drawn, hatched, as its box of equal inertia from
the scene stored in the bag, or as a cross without one). matplotlib is optional
(requirements-study.txt); without it, as for a bag it cannot read: one line, exit status 2.
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass, field
import math
import os
from pathlib import Path
import sys
from typing import Any, Optional, Sequence

import numpy as np

from abd_joint_sim.tools import cli

PROG = 'plot_bag'
#: [s] each body's path drawn in a pose panel: the last this many seconds before it
TRAIL_SECONDS = 0.5
#: moving bodies' colours (matplotlib's tab20 without its greys, dark shades first): grey
#: is kept for fixed bodies
BODY_COLOURS = ('#1f77b4', '#ff7f0e', '#2ca02c', '#d62728', '#9467bd', '#8c564b', '#e377c2',
                '#bcbd22', '#17becf', '#aec7e8', '#ffbb78', '#98df8a', '#ff9896', '#c5b0d5',
                '#c49c94', '#f7b6d2', '#dbdb8d', '#9edae5')
FIXED_COLOUR = '0.78'
_COMMAND_TYPES = ('std_msgs/msg/Float64', 'std_msgs/msg/Float64MultiArray',
                  'std_msgs/msg/Bool')
_CORNERS = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)])


class PlotError(RuntimeError):
    """The bag cannot be plotted; the message says why (one line)."""


@dataclass
class Run:
    """What the pictures need from a bag, in simulated time (segments laid end to end)."""

    joint_names: list[str] = field(default_factory=list)
    t: list[float] = field(default_factory=list)            # s, continuous across resets
    position: list[list[float]] = field(default_factory=list)
    velocity: list[list[float]] = field(default_factory=list)
    effort: list[list[float]] = field(default_factory=list)
    commands: list[tuple[float, str]] = field(default_factory=list)     # (t, topic)
    resets: list[float] = field(default_factory=list)
    reset_index: list[int] = field(default_factory=list)    # index in t of a reset's first
    markers: list[tuple[float, Any]] = field(default_factory=list)      # (t, MarkerArray)
    marker_segment: list[int] = field(default_factory=list)     # segment (0, 1, ...) of each
    mesh_boxes: dict[str, tuple] = field(default_factory=dict)  # see mesh_boxes()
    fixed_bodies: Optional[set[str]] = None     # from the stored scene; None: unknown
    scene_name: str = ''        # the robot's name, else the scene file's stem


def _stored_scene(bag: str | os.PathLike[str]):
    """(the scene stored in the bag or None, its custom data {})."""
    from abd_joint_sim.record import read_custom_data
    from abd_joint_sim.tools.bagrun import scene_from_text
    try:
        custom = read_custom_data(bag)
    except Exception:  # noqa: BLE001 - optional: the pictures do without it
        return None, {}
    try:
        text = custom.get('abd_joint_sim.scene_yaml', '')
        return (scene_from_text(text, 'scene.yaml') if text else None), custom
    except Exception:  # noqa: BLE001
        return None, custom


def scene_name(custom: dict) -> str:
    """The robot's name (a URDF robot's <robot name>), else the scene file's stem."""
    import re
    found = re.search(r'<robot\b[^>]*\bname\s*=\s*["\']([^"\']+)', custom.get('abd_joint_sim.urdf', ''))
    if found:
        return found.group(1)
    path = custom.get('abd_joint_sim.scene_path', '')
    return Path(path).stem if path else ''


def mesh_boxes(scene: Any) -> dict[str, tuple]:
    """{body with mesh visuals: (visual origins {index: (t, R_v)}, box sides, centre, axes in
    the body frame)}: the box of equal inertia drawn for its mesh visuals, from `scene` (the
    bag's stored scene); {} when it is None (then meshes are crosses)."""
    from abd_joint_sim.geometry import rpy_matrix
    from abd_joint_sim.ros.markers import equal_inertia_box
    out = {}
    for body in scene.bodies if scene is not None else ():
        visuals = getattr(body, 'visuals', ()) or ()
        if not any(v.kind == 'mesh' for v in visuals) or body.shape.kind != 'inertial':
            continue
        sides, axes = equal_inertia_box(body.shape.mass, body.shape.inertia)
        origins = {i: (np.asarray(v.origin_xyz, dtype=float), rpy_matrix(v.origin_rpy))
                   for i, v in enumerate(visuals)}
        out[body.name] = (origins, sides, np.asarray(body.shape.com, dtype=float), axes)
    return out


def _wanted_topics(bag: str | os.PathLike[str]) -> Optional[list[str]]:
    """Topics worth deserialising (joint states, markers, commands), from the MCAP summary:
    /clock alone is a message per step. None = all (no summary to tell)."""
    from mcap.reader import make_reader
    from abd_joint_sim.record.read import mcap_file
    try:
        with open(mcap_file(bag), 'rb') as handle:
            summary = make_reader(handle).get_summary()
    except Exception:  # noqa: BLE001 - read_messages below reports what is wrong
        return None
    if summary is None:
        return None
    wanted = []
    for channel in summary.channels.values():
        schema = summary.schemas.get(channel.schema_id)
        name = schema.name if schema is not None else ''
        if name in ('sensor_msgs/msg/JointState', 'visualization_msgs/msg/MarkerArray') or \
                (name in _COMMAND_TYPES and 'joint_torque' in channel.topic):
            wanted.append(channel.topic)
    return wanted


def read_run(bag: str | os.PathLike[str]) -> Run:
    """Read joint states, commands and markers of `bag` (raises PlotError), in the order
    they were written. Log time is simulated time since the recording began (it runs on
    across a reset); a reset is where the simulation's own stamps (joint states, markers)
    go back. (Bags whose log times restart at 0 at a reset are laid end to end.)"""
    from abd_joint_sim.ros.convert import time_msg_to_ns
    from abd_joint_sim.tools.bagrun import _iter_file_order, _STATES, BagInputError
    run = Run()
    offset = 0.0          # simulated time of earlier segments (log times restarting at 0)
    last = -1
    stamps: dict[str, int] = {}     # kind -> the last stamp of the current segment
    try:
        for topic, msg_type, log_ns, msg in _iter_file_order(bag, _wanted_topics(bag)):
            is_state = msg_type == 'sensor_msgs/msg/JointState' and _STATES.search(topic)
            kind = 'states' if is_state else (
                'markers' if msg_type == 'visualization_msgs/msg/MarkerArray' else '')
            # simulated time: the stamp of a JointState or of a MarkerArray's first marker
            header = msg.header if is_state else \
                msg.markers[0].header if kind and msg.markers else None
            stamp = None if header is None else time_msg_to_ns(header.stamp)
            restarted = log_ns < last       # log time restarted from 0 at a reset
            if restarted:
                offset += last * 1e-9
            if restarted or (stamp is not None and kind in stamps and stamp <= stamps[kind]):
                run.resets.append(offset if restarted else offset + log_ns * 1e-9)
                run.reset_index.append(len(run.t))
                stamps.clear()
            if stamp is not None:
                stamps[kind] = stamp
            last = log_ns
            t = offset + log_ns * 1e-9
            if is_state:
                if not run.joint_names:
                    run.joint_names = list(msg.name)
                if list(msg.name) != run.joint_names:
                    raise PlotError(f'{bag}: {topic} changes its joint names at t = {t:g} s')
                run.t.append(t)
                run.position.append(list(msg.position))
                run.velocity.append(list(msg.velocity))
                run.effort.append(list(msg.effort))
            elif msg_type == 'visualization_msgs/msg/MarkerArray':
                run.markers.append((t, msg))
                run.marker_segment.append(len(run.resets))
            elif (msg_type in _COMMAND_TYPES and 'joint_torque' in topic) or (
                    msg_type == 'sensor_msgs/msg/JointState'):    # joint_commands
                run.commands.append((t, topic))
    except BagInputError as exc:
        raise PlotError(str(exc)) from None
    if not run.t:
        raise PlotError(f'{bag}: no sensor_msgs/msg/JointState messages to plot')
    scene, custom = _stored_scene(bag)
    run.scene_name = scene_name(custom)
    if scene is not None:
        run.fixed_bodies = {b.name for b in scene.bodies if b.fixed}
    if run.markers:
        run.mesh_boxes = mesh_boxes(scene)
    return run


def _position(marker) -> list[float]:
    p = marker.pose.position
    return [p.x, p.y, p.z]


def body_styles(run: Run) -> dict[str, tuple[Any, bool]]:
    """{body: (colour, fixed)} in the order the bodies' markers first appear: a colour of
    its own for each moving body, FIXED_COLOUR for the fixed ones (from the stored scene; a
    bag without one: the bodies whose markers never moved)."""
    where: dict[str, list] = {}
    for _, arr in run.markers:
        for m in arr.markers:
            if m.ns.startswith('bodies/'):
                where.setdefault(m.ns.split('/', 1)[1], []).append(_position(m))
    out = {}
    for name, points in where.items():
        fixed = name in run.fixed_bodies if run.fixed_bodies is not None else \
            float(np.ptp(np.array(points), axis=0).max()) < 1e-9
        moving = sum(not f for _, f in out.values())
        out[name] = (FIXED_COLOUR, True) if fixed else \
            (BODY_COLOURS[moving % len(BODY_COLOURS)], False)
    return out


def trails(run: Run, k: int) -> dict[tuple[str, int], list[tuple[float, list[float]]]]:
    """{(marker ns, id): [(t, position)]} of the bodies' markers over the TRAIL_SECONDS up
    to run.markers[k], in its segment: the paths a pose panel draws."""
    t = run.markers[k][0]
    out: dict = {}
    segment = run.marker_segment[k]
    for (te, earlier), seg in zip(run.markers[:k + 1], run.marker_segment):
        if seg != segment or te < t - TRAIL_SECONDS - 1e-9:
            continue
        for m in earlier.markers:
            if m.ns.startswith('bodies/'):
                out.setdefault((m.ns, m.id), []).append((te, _position(m)))
    return out


def grid_shape(n: int) -> tuple[int, int]:
    """(rows, cols) of n panels: rows of at most 5, as even as they come (5: one row of
    5; 6: 2 x 3; 8: 2 x 4), so at most rows - 1 panels are empty."""
    rows = max(1, -(-n // 5))
    return rows, max(1, -(-n // rows))


def joints_notes(run: Run) -> str:
    """What the vertical lines of joints.png mean, for the lines there are."""
    notes = (['dotted: a command took effect'] if run.commands else []) + \
        (['dashed: reset'] if run.resets else [])
    return '; '.join(notes)


def plot_joints(plt, run: Run, path: Path, title: str) -> None:
    # A NaN row before each reset breaks the lines there instead of joining the segments.
    cut = run.reset_index
    t = np.insert(np.array(run.t), cut, np.nan)
    rows = (('angle [rad]', run.position), ('velocity [rad/s]', run.velocity),
            ('effort [N m]', run.effort))
    fig, axes = plt.subplots(3, 1, figsize=(9, 7.5), sharex=True, constrained_layout=True)
    for ax, (label, values) in zip(axes, rows):
        data = np.array(values, dtype=float).reshape(len(run.t), -1)
        data = np.insert(data, cut, np.nan, axis=0)
        for k, name in enumerate(run.joint_names):
            if k < data.shape[1]:
                ax.plot(t, data[:, k], lw=1.6, label=name)
        for tc in sorted({round(tc, 9) for tc, _ in run.commands}):
            ax.axvline(tc, color='0.45', ls=':', lw=1.0)
        for tr in run.resets:
            ax.axvline(tr, color='k', ls='--', lw=1.2)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(loc='best', fontsize=9, ncol=max(1, len(run.joint_names) // 4 + 1))
    axes[-1].set_xlabel('simulated time [s]')
    notes = joints_notes(run)
    axes[0].set_title(f'{title}\n{notes}' if notes else title, fontsize=11)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _quat_matrix(o) -> np.ndarray:
    x, y, z, w = o.x, o.y, o.z, o.w
    n = math.sqrt(x * x + y * y + z * z + w * w) or 1.0
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _outline(marker) -> Optional[np.ndarray]:
    """Points (N,3) in the marker frame whose projection's convex hull is its silhouette."""
    from visualization_msgs.msg import Marker
    s = np.array([marker.scale.x, marker.scale.y, marker.scale.z]) / 2.0
    if marker.type == Marker.CUBE:
        local = _CORNERS * s
    elif marker.type == Marker.CYLINDER:
        a = np.linspace(0.0, 2 * math.pi, 24, endpoint=False)
        ring = np.stack([np.cos(a) * s[0], np.sin(a) * s[1], np.zeros_like(a)], axis=1)
        local = np.concatenate([ring + [0, 0, s[2]], ring - [0, 0, s[2]]])
    else:
        return None
    return local @ _quat_matrix(marker.pose.orientation).T + _position(marker)


def _hull(points: np.ndarray) -> np.ndarray:
    """Convex hull (Andrew's monotone chain) of 2-D points, counter-clockwise."""
    pts = sorted(set(map(tuple, np.round(points, 12))))
    if len(pts) < 3:
        return np.array(pts)

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    def chain(ordered) -> list:     # the lower (upper) half, without its last point
        out: list = []
        for p in ordered:
            while len(out) >= 2 and cross(out[-2], out[-1], p) <= 0:
                out.pop()
            out.append(p)
        return out[:-1]
    return np.array(chain(pts) + chain(reversed(pts)))


def _mesh_box_points(run: Run, marker) -> Optional[np.ndarray]:
    """Corners (8, 3) in the world of the equal-inertia box standing in for the body of a
    mesh marker, or None (no scene in the bag, or not a body's visual)."""
    body = marker.ns.split('/', 1)[-1] if marker.ns.startswith('bodies/') else ''
    entry = run.mesh_boxes.get(body)
    if entry is None or marker.id not in entry[0]:
        return None
    origins, sides, com, axes = entry
    t_v, R_v = origins[marker.id]
    R_b = _quat_matrix(marker.pose.orientation) @ R_v.T
    p_b = np.array(_position(marker)) - R_b @ t_v
    local = _CORNERS * (sides / 2.0)
    return (local @ axes.T + com) @ R_b.T + p_b


def choose_view(run: Run) -> str:
    """The plane ('xy', 'xz', 'yz') normal to the axis the marker positions vary least
    along: the plane the bodies move in."""
    pos = np.array([_position(m) for _, arr in run.markers for m in arr.markers
                    if m.ns.startswith('bodies/')])
    if len(pos) == 0:
        return 'xy'
    spread = pos.max(axis=0) - pos.min(axis=0)
    # Ties (e.g. nothing moved) prefer the top view.
    drop = int(np.argmin(spread + np.array([2e-9, 1e-9, 0.0])))
    return {0: 'yz', 1: 'xz', 2: 'xy'}[drop]


def pick_times(run: Run, times: Optional[Sequence[float]], count: int = 5) -> list[int]:
    """Indices into run.markers nearest to `times` (default: `count` evenly spaced)."""
    stamps = np.array([t for t, _ in run.markers])
    if times is None:
        times = np.linspace(stamps[0], stamps[-1], min(count, len(stamps)))
    out = []
    for t in times:
        k = int(np.argmin(np.abs(stamps - t)))
        if k not in out:
            out.append(k)
    return sorted(out)


def plot_poses(plt, run: Run, path: Path, title: str, view: str,
               times: Optional[Sequence[float]]) -> list[float]:
    """The strip of body poses; returns the times drawn."""
    from matplotlib.patches import Circle, Polygon
    from visualization_msgs.msg import Marker
    i, j = 'xyz'.index(view[0]), 'xyz'.index(view[1])
    chosen = pick_times(run, times)
    all_pts = []
    for _, arr in run.markers:
        for m in arr.markers:
            pts = _outline(m)
            if pts is None and m.type == Marker.MESH_RESOURCE:
                pts = _mesh_box_points(run, m)
            if pts is not None:
                all_pts.append(pts[:, [i, j]])
            all_pts.append(np.array([_position(m)])[:, [i, j]])
    all_pts = np.concatenate(all_pts)
    lo, hi = all_pts.min(axis=0), all_pts.max(axis=0)
    pad = 0.05 * max(hi - lo) + 1e-3
    n = len(chosen)
    rows, cols = grid_shape(n)
    styles = body_styles(run)
    aspect = (hi[1] - lo[1] + 2 * pad) / (hi[0] - lo[0] + 2 * pad)
    panel = 3.6
    # (the legend beside the grid narrows the panels: 0.85 of their width)
    fig, axes = plt.subplots(rows, cols, figsize=(panel * cols + 1.6, (min(
        0.85 * panel * aspect, 2 * panel) + 0.9) * rows + 0.7),
                             squeeze=False, constrained_layout=True)
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    drawn, labelled, boxed = [], set(), set()
    for ax, k in zip(axes.ravel(), chosen):
        t, arr = run.markers[k]
        drawn.append(t)
        # each moving body's trail (see trails()) as a thin line in its colour
        for (ns, _), path_pts in trails(run, k).items():
            xy = np.array([p for _, p in path_pts])[:, [i, j]]
            colour, fixed = styles.get(ns.split('/', 1)[1], ('0.35', False))
            if not fixed and np.ptp(xy, axis=0).max() > 1e-6:
                ax.plot(xy[:, 0], xy[:, 1], color=colour, lw=1.0, alpha=0.7)
        for m in arr.markers:
            name = m.ns.split('/', 1)[1] if m.ns.startswith('bodies/') else ''
            colour, fixed = styles.get(name, ('k', False))
            label = None if not name or name in labelled else \
                (f'{name} (fixed)' if fixed else name)
            p = _position(m)
            if m.type == Marker.ARROW and len(m.points) == 2:
                a, b = ([q.x, q.y, q.z] for q in m.points)
                ax.annotate('', xy=(b[i], b[j]), xytext=(a[i], a[j]),
                            arrowprops=dict(arrowstyle='->', color='k', lw=1.5))
                continue
            style = dict(facecolor=colour, edgecolor='k', lw=0.6, alpha=0.85, label=label)
            if m.type == Marker.SPHERE:
                ax.add_patch(Circle((p[i], p[j]), m.scale.x / 2, **style))
            elif m.type == Marker.MESH_RESOURCE:
                pts = _mesh_box_points(run, m)
                if pts is None:
                    ax.plot(p[i], p[j], 'x', color=colour, ms=8, mew=2, label=label)
                elif (t, name) not in boxed:        # one stand-in per body
                    boxed.add((t, name))
                    ax.add_patch(Polygon(_hull(pts[:, [i, j]]), closed=True,
                                         **dict(style, alpha=0.6, hatch='//')))
                else:
                    continue
            else:
                pts = _outline(m)
                if pts is None:
                    continue
                ax.add_patch(Polygon(_hull(pts[:, [i, j]]), closed=True, **style))
            if name:
                labelled.add(name)
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)
        ax.set_aspect('equal')
        ax.grid(alpha=0.3)
        ax.set_title(f't = {t:.3f} s', fontsize=11)
        ax.set_xlabel(f'{view[0]} [m]')
    for row in axes:
        row[0].set_ylabel(f'{view[1]} [m]')
    if labelled:        # one entry per body, beside the grid (never over a panel)
        handles = {}
        for ax in axes.ravel():
            for h, lab in zip(*ax.get_legend_handles_labels()):
                handles.setdefault(lab, h)
        fig.legend(list(handles.values()), list(handles.keys()), loc='outside right upper',
                   fontsize=9)
    notes = [f'thin lines: each body\'s path over the last {TRAIL_SECONDS:g} s']
    if boxed:
        notes.append('hatched: a mesh visual, drawn as the box of equal inertia of its body')
    fig.suptitle(f'{title}: bodies seen along {"xyz"[3 - i - j]} (from the recorded '
                 f'markers)\n{"; ".join(notes)}', fontsize=11)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return drawn


def _times(text: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(',') if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f'{text!r} is not a comma-separated list of seconds') \
            from None
    if not values or not all(math.isfinite(v) and v >= 0 for v in values):
        raise argparse.ArgumentTypeError(f'{text!r}: give times >= 0 in seconds, e.g. 0,0.5,1')
    return values


def main(argv: Optional[list[str]] = None) -> int:
    parser = cli.Parser(
        prog=PROG, description='Turn a recorded abd_joint_sim bag into PNG pictures: joint '
        'angles, velocities and efforts against simulated time (joints.png) and a strip of '
        'the bodies at chosen times from the recorded markers (poses.png).')
    parser.add_argument('bag', help='bag directory (or its .mcap file)')
    parser.add_argument('--out', required=True, help='directory to write the PNGs into')
    parser.add_argument('--times', type=_times, default=None,
                        help='simulated times [s] of the pose strip, comma-separated '
                        '(default: 5 evenly spaced; the nearest recorded markers are drawn)')
    parser.add_argument('--view', choices=('xy', 'xz', 'yz'), default=None,
                        help='projection plane of the pose strip (default: the plane the '
                        'bodies move in)')
    parser.add_argument('--title', default=None,
                        help='title (default: the scene or robot name and the bag name)')
    parser.add_argument('-q', '--quiet', action='store_true', help='no summary line')
    args = parser.parse_args(cli.own_args(argv))

    def fail(text: str) -> int:
        print(f'{PROG}: {text}', file=sys.stderr)
        return 2
    try:
        import matplotlib
    except ImportError:
        return fail('matplotlib is not installed (it is optional); install it with '
                    '`python -m pip install -r requirements-study.txt`')
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    try:
        run = read_run(args.bag)
    except PlotError as exc:
        return fail(str(exc))
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        return fail(f'cannot create {out}: {exc.strerror or exc}')
    bag_name = Path(os.path.normpath(args.bag)).name
    title = args.title or (f'{run.scene_name} (bag {bag_name})' if run.scene_name else bag_name)
    written = [out / 'joints.png']
    plot_joints(plt, run, written[0], title)
    note = 'no markers in the bag (marker_rate 0): no poses.png'
    if run.markers:
        view = args.view or choose_view(run)
        drawn = plot_poses(plt, run, out / 'poses.png', title, view, args.times)
        written.append(out / 'poses.png')
        note = f'poses at t = {", ".join(f"{t:.3f}" for t in drawn)} s ({view} view)'
    if not args.quiet:
        print(f'{PROG}: {len(run.t)} joint states, {len(run.commands)} commands, '
              f'{len(run.markers)} marker arrays -> {", ".join(map(str, written))}; {note}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
