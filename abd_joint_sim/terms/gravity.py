"""Uniform gravity (docs/physics.md "Forces"): a force without energy in Π, entering the
prediction q̃ only. In q-space its acceleration M⁻¹F is exactly [g, 0, ..., 0] on every free
body (the generalized force of ρg over the body is M [g, 0...])."""
from __future__ import annotations

import numpy as np

from ..jit import flat, kernel

NAME = 'gravity'            #: in Solver.terms
FIELDS = (
    ('gravity', '[m/s²] (3,)'),
    ('has_gravity', 'bool'),
)


def used(model) -> bool:
    return model.has_gravity


def from_scene(scene, model) -> dict:
    """No Model fields of its own: it reads the scene's gravity (Model.gravity)."""
    return {}


def build(model, data) -> dict:
    return dict(gravity=flat.array(model.gravity, np.float64), has_gravity=bool(model.has_gravity))


@kernel
def add_acceleration(q, m, acc):
    if not m.has_gravity:
        return
    g = m.gravity
    for b in m.free_bodies:
        for r in range(3):
            acc[b, r] += g[r]
