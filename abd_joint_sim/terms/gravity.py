"""Uniform gravity (docs/physics.md "Forces"): a force without energy in Π, entering the
prediction q̃ only. In q-space its acceleration M⁻¹F is exactly [g, 0, ..., 0] on every free
body (the generalized force of ρg over the body is M [g, 0...])."""
from __future__ import annotations

from numba import njit


@njit(cache=True, error_model='numpy')
def add_acceleration(q, m, acc):
    if not m.has_gravity:
        return
    g = m.gravity
    for b in m.free_bodies:
        for r in range(3):
            acc[b, r] += g[r]
