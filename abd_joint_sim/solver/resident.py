"""`Resident`: the World's current state kept in ring buffers between one-step calls
(docs/physics-code.md), instead of a State built per step: per call 2.6 µs against 6.7-6.9
for `Solver.step` on States on one link (`python bench/profiler.py devices`), 11.0-11.3
against 15.6-16.0 µs on the KUKA iiwa; 1.04-1.09x on chains of 100 and 1000 links.

A (4,3,B,12) ring holds (q, v, warm_start) of the current state (slot `cur`), the one before
(q_prev, v_prev, warm_start_prev) and the one before that (warm_start_prev2), modulo 4; a
step writes slot `cur + 1`. A State is built, as copies, only when read; a State set or read
since the last step is the current one, copied into the ring before the next step.
"""
from __future__ import annotations

import numpy as np
from numba.core import types
from numba.experimental import structref

from ..jit import kernel, refcounts
from ..state import State

#: what step.step_resident reads and writes, in one struct (unboxed in about the time of one
#: array); `model`, `work` and the scalars are the Solver's
IO_FIELDS = ('ring', 'angles', 'slots', 'clock', 'torque_value', 'torque_enabled', 'drive_aim',
             'drive_enabled', 'drive_passive', 'skipped', 'outcome', 'model', 'work', 'h', 'bdf2',
             'may_split', 'clean_rotation', 'keep_rotation')


@structref.register
class ResidentIOType(types.StructRef):
    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(t)) for name, t in fields)


class ResidentIO(structref.StructRefProxy):
    """A Resident's ring and clock, a Control's arrays and a Solver's skipped/outcome rows,
    as the compiled one-step call takes them (Solver._step_resident binds it)."""


structref.define_proxy(ResidentIO, ResidentIOType, list(IO_FIELDS))


class Resident:
    """Holds the current state: as a State (`_state`, set or read since the last step: it
    wins), else in the ring. `slots` = (cur, known past warm starts 0-2, step_count), `clock`
    = (time [s], history_dt [s]): arrays, as step.step_resident advances them."""

    __slots__ = ('ring', 'angles', 'slots', 'clock', 'clock_view', '_state', 'io', 'io_key', 'io_call')

    def __init__(self, body_count: int, joint_count: int):
        self.ring = np.zeros((4, 3, body_count, 12))
        self.angles = np.zeros((4, 2, joint_count))
        self.slots = np.zeros(3, dtype=np.int64)
        self.clock = np.zeros(2)
        self.clock_view = memoryview(self.clock)     # clock_view[0]: the time as a Python float
        self._state = None
        self.io = None                  # the ResidentIO last bound, and what it was bound to
        self.io_key = ()
        self.io_call = None             # (function, arguments) of the compiled step on it (Solver)

    cur = property(lambda self: int(self.slots[0]), doc='slot of the current state in the ring')

    def bind(self, key, control, **solver) -> ResidentIO:
        """The ResidentIO of this ring, a Control's and a Solver's arrays (IO_FIELDS from
        `skipped` on), kept with `key` (checked by identity by the caller)."""
        c = control
        values = dict(ring=self.ring, angles=self.angles, slots=self.slots, clock=self.clock,
                      torque_value=c.torque_value, torque_enabled=c.torque_enabled,
                      drive_aim=c.drive_aim, drive_enabled=c.drive_enabled,
                      drive_passive=c.drive_passive, **solver)
        io = ResidentIO(*(values[name] for name in IO_FIELDS))
        io.__dict__.update(values)
        self.io, self.io_key = refcounts.borrow(io), key
        return io

    def set(self, state: State) -> None:
        """Make `state` the current state (copied into the ring at the next `load`)."""
        self._state = state

    def state(self) -> State:
        """The current state as a State (built once per step from three fresh slot copies)."""
        if self._state is None:
            ring = self.ring
            cur, known, step_count = self.slots.tolist()
            time, history_dt = self.clock.tolist()
            prev = (cur + 3) % 4
            now, before, angles = ring[cur].copy(), ring[prev].copy(), self.angles[cur].copy()
            w = now[2]
            p1 = w if known == 0 else before[2]
            p2 = p1 if known <= 1 else ring[(cur + 2) % 4, 2].copy()
            self._state = State(time, now[0], now[1], before[0], before[1], angles[0], angles[1],
                                step_count, history_dt, w, p1, p2)
        return self._state

    def body_q(self, b: int) -> np.ndarray:
        """A copy of body b's current q (12,), without building a State."""
        if self._state is not None:
            return self._state.q[b].copy()
        return self.ring[self.slots[0], 0, b].copy()

    def now(self) -> float:
        """[s] the current state's time (without building a State)."""
        return self._state.time if self._state is not None else float(self.clock[0])

    def joint_values(self, k: int) -> np.ndarray:
        """A copy of the current joint angles (k = 0) or joint velocities (k = 1)."""
        if self._state is not None:
            return (self._state.joint_velocity if k else self._state.joint_angle).copy()
        return self.angles[self.slots[0], k].copy()

    def load(self) -> None:
        """Before a step: copy the current State into the ring if there is one."""
        s = self._state
        if s is None:
            return
        ring, angles = self.ring, self.angles
        arrays = (s.q, s.v, s.warm_start, s.q_prev, s.v_prev, s.warm_start_prev, s.warm_start_prev2,
                  s.joint_angle, s.joint_velocity)
        try:
            done = load_ring(ring, angles, *arrays)
        except Exception:  # noqa: BLE001 - numba cannot type it (not arrays, other dimensions)
            done = False
        if not done:    # another shape or type: numpy's assignment (its casts, its error)
            ring[2, 0], ring[2, 1], ring[2, 2] = s.q, s.v, s.warm_start
            ring[1, 0], ring[1, 1], ring[1, 2] = s.q_prev, s.v_prev, s.warm_start_prev
            ring[0, 2] = s.warm_start_prev2
            angles[2, 0], angles[2, 1] = s.joint_angle, s.joint_velocity
        # (history in slots 1 and 0)
        self.slots[0], self.slots[1], self.slots[2] = 2, s.known_history(), s.step_count
        self.clock[0], self.clock[1] = s.time, s.history_dt


@kernel
def load_ring(ring, angles, q, v, w, q_prev, v_prev, w_prev, w_prev2, joint_angle, joint_velocity):
    """Resident.load's copies in one call (numpy's cost ~2x more) into slots 2, 1 and 0's
    warm start; False, copying nothing, unless every array has the ring's shape."""
    B, J = ring.shape[2], angles.shape[2]
    for x in (q.shape, v.shape, w.shape, q_prev.shape, v_prev.shape, w_prev.shape, w_prev2.shape):
        if x != (B, 12):
            return False
    if joint_angle.shape != (J,) or joint_velocity.shape != (J,):
        return False
    for b in range(B):
        for r in range(12):
            ring[2, 0, b, r] = q[b, r]
            ring[2, 1, b, r] = v[b, r]
            ring[2, 2, b, r] = w[b, r]
            ring[1, 0, b, r] = q_prev[b, r]
            ring[1, 1, b, r] = v_prev[b, r]
            ring[1, 2, b, r] = w_prev[b, r]
            ring[0, 2, b, r] = w_prev2[b, r]
    for j in range(J):
        angles[2, 0, j] = joint_angle[j]
        angles[2, 1, j] = joint_velocity[j]
    return True
