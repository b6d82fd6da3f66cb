"""Scene dicts for generated mechanisms (chains, trees), shared by tests, benchmarks and
users: `Scene.from_dict(chain_scene(100))`.

Chain geometry (also built identically in bench/lib/engines.py for MuJoCo and PyBullet): a fixed
cube of side `link` at the origin, then `n` boxes (link, link/2, link/2) centred at
(k·link, 0, 0), joined by hinges about +z through x = (k − ½)·link; every joint actuated.
"""
from __future__ import annotations


def box_body(name, position, size, *, fixed=False, density=1000.0, **extra):
    return dict(name=name, box=[float(s) for s in size], density=density,
                position=[float(p) for p in position], fixed=fixed, **extra)


def chain_scene(n_links: int, *, dt: float = 0.001, torque: float = 1.0, link: float = 0.2,
                gravity=(0.0, 0.0, 0.0), integrator: str = 'bdf1') -> dict:
    """A fixed base plus n free links along +x, vertical hinges, torque on every joint."""
    bodies = [box_body('base', (0.0, 0.0, 0.0), (link, link, link), fixed=True)]
    joints = []
    for k in range(1, n_links + 1):
        bodies.append(box_body(f'link{k}', (k * link, 0.0, 0.0), (link, 0.5 * link, 0.5 * link)))
        x = (k - 0.5) * link
        joints.append(dict(name=f'j{k}', parent=bodies[k - 1]['name'], child=f'link{k}',
                           p0=[x, 0.0, -0.5 * link], p1=[x, 0.0, 0.5 * link],
                           external_torque=dict(torque=torque, enabled=True)))
    return dict(name=f'chain{n_links}', dt=dt, gravity=list(gravity), integrator=integrator,
                bodies=bodies, joints=joints)


def tree_scene(depth: int = 3, branching: int = 2, *, dt: float = 0.001, torque: float = 0.1,
               link: float = 0.2) -> dict:
    """A fixed base with a binary (or k-ary) tree of links fanning out in the xy-plane."""
    bodies = [box_body('base', (0.0, 0.0, 0.0), (link, link, link), fixed=True)]
    joints = []
    frontier = [('base', 0.0, 0.0)]
    for level in range(1, depth + 1):
        new = []
        for parent, x, y in frontier:
            for b in range(branching):
                name = f'{parent}_{b}' if parent != 'base' else f'n{b}'
                cy = y + (b - (branching - 1) / 2) * link * 2.0 ** (depth - level)
                cx = x + link
                bodies.append(box_body(name, (cx, cy, 0.0), (0.5 * link, 0.25 * link, 0.25 * link)))
                jx, jy = cx - 0.25 * link, cy
                joints.append(dict(name=f'j_{name}', parent=parent, child=name,
                                   p0=[jx, jy, -0.5 * link], p1=[jx, jy, 0.5 * link],
                                   external_torque=dict(torque=torque, enabled=True)))
                new.append((name, cx, cy))
        frontier = new
    return dict(name=f'tree{depth}x{branching}', dt=dt, gravity=[0.0, 0.0, 0.0], bodies=bodies,
                joints=joints)
