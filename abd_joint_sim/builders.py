"""Scene dicts for generated mechanisms (chains), shared by tests, benchmarks and
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

