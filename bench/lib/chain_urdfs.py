"""Writes URDF chains nobody tuned the simulator for, for `bench/peers.py sweep`: 2 to 50
links, boxes or cylinders of 10 or 40 cm along z, masses drawn at random (seeded) around a
density of ~1000 kg/m³, hinge axes y or x (alternating where the draw says), with and
without joint limits (±2 rad), the COM at mid-link. 48 files. The sweep then loads each in
ours and in MuJoCo (gravity, the bench's torques on every joint, dt 1 ms) and prints the
ratio per step.

    python bench/peers.py chain-urdfs /tmp/chains && python bench/peers.py sweep /tmp/chains
"""
from __future__ import annotations

import argparse
import os

import numpy as np

LINKS = (2, 3, 6, 10, 20, 50)
SHAPES = ('box', 'cyl')
LENGTHS = (0.1, 0.4)            # [m]


def inertia(shape, dims, mass):
    """Principal moments about the COM of a box (x, y, z) or a cylinder (r, l) along z."""
    if shape == 'box':
        x, y, z = dims
        return mass / 12 * np.array([y * y + z * z, x * x + z * z, x * x + y * y])
    r, l = dims
    side = mass * (3 * r * r + l * l) / 12
    return np.array([side, side, mass * r * r / 2])


def chain(name, shape, length, masses, axes, limits):
    """URDF text of a chain on a fixed `base` link."""
    out = [f'<robot name="{name}">', '<link name="base"/>']
    for i, (mass, axis) in enumerate(zip(masses, axes)):
        dims = (length * 0.3, length * 0.3, length) if shape == 'box' else (length * 0.15, length)
        ixx, iyy, izz = inertia(shape, dims, mass)
        geometry = (f'<box size="{dims[0]} {dims[1]} {dims[2]}"/>' if shape == 'box'
                    else f'<cylinder radius="{dims[0]}" length="{dims[1]}"/>')
        out.append(f'<link name="l{i}"><inertial><origin xyz="0 0 {length / 2}"/>'
                   f'<mass value="{mass}"/><inertia ixx="{ixx}" iyy="{iyy}" izz="{izz}" ixy="0" '
                   f'ixz="0" iyz="0"/></inertial><visual><origin xyz="0 0 {length / 2}"/>'
                   f'<geometry>{geometry}</geometry></visual></link>')
        parent = 'base' if i == 0 else f'l{i - 1}'
        kind = 'revolute' if limits else 'continuous'
        limit = '<limit lower="-2.0" upper="2.0" effort="100" velocity="10"/>' if limits else ''
        out.append(f'<joint name="j{i}" type="{kind}"><parent link="{parent}"/><child link="l{i}"/>'
                   f'<origin xyz="0 0 {0.0 if i == 0 else length}"/><axis xyz="{axis}"/>{limit}</joint>')
    out.append('</robot>')
    return '\n'.join(out) + '\n'


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='bench/peers.py chain-urdfs', description=__doc__.split('\n')[0])
    ap.add_argument('out', help='directory to write the URDFs to')
    args = ap.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    rng = np.random.default_rng(7)
    for n in LINKS:
        for shape in SHAPES:
            for length in LENGTHS:
                for limits in (False, True):
                    masses = rng.uniform(0.3, 3.0, n) * (length / 0.4) ** 2
                    axes = ['0 1 0' if (i % 2 == 0 or rng.random() < 0.5) else '1 0 0' for i in range(n)]
                    name = f'c{n:02d}_{shape}_{int(round(length * 100))}cm_{"lim" if limits else "free"}'
                    with open(os.path.join(args.out, name + '.urdf'), 'w') as f:
                        f.write(chain(name, shape, length, masses, axes, limits))
    print(f'{len(LINKS) * len(SHAPES) * len(LENGTHS) * 2} URDFs in {args.out}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
