"""`Resident`: the World's current state kept in ring buffers between one-step calls.

A `State` is immutable and every step returns a new one. Building it, with fresh arrays
for q, v and the warm start, and handing its ten arrays to the compiled step, costs about as
much as the step itself on a small robot (docs/speed.md, "The eighth round"). So `World.step()`
keeps the state here instead. Slots of one (4,3,B,12) ring hold (q, v, warm_start) for the
current state (slot `cur`), the state before it (`cur − 1`: q_prev, v_prev, warm_start_prev)
and the one before that (`cur − 2`: warm_start_prev2), modulo 4; a step writes slot
`cur + 1`, which then becomes the current one (`Solver.step_resident`). The `State` is built only when it is read (`state()`), as copies,
so a State a caller holds never changes. Whenever a State has been set or read since the
last step it is the current state, and the next step copies it into the ring first (so a
caller that changed its arrays in place, as tests and studies do to perturb a state, is
obeyed as before).

Which past warm starts are known is kept as a count (`known`: 0, 1 or 2), where a State marks
the unknown ones by identity (`State.known_history`).
"""
from __future__ import annotations

import numpy as np

from ..state import State


class Resident:
    """Holds the current state: as a State (`_state`, when set or read since the last
    step; it then wins), else in the ring."""

    __slots__ = ('ring', 'angles', 'cur', 'time', 'step_count', 'history_dt', 'known', '_state')

    def __init__(self, body_count: int, joint_count: int):
        self.ring = np.zeros((4, 3, body_count, 12))
        self.angles = np.zeros((4, 2, joint_count))
        self.cur = 0
        self.time = 0.0
        self.step_count = 0
        self.history_dt = 0.0
        self.known = 0
        self._state = None

    def set(self, state: State) -> None:
        """Make `state` the current state (copied into the ring at the next `load`)."""
        self._state = state

    def state(self) -> State:
        """The current state as a State (built from the ring once per step, then kept)."""
        if self._state is None:
            ring, angles = self.ring, self.angles
            cur, prev, prev2 = self.cur, (self.cur + 3) % 4, (self.cur + 2) % 4
            w = ring[cur, 2].copy()
            p1 = w if self.known == 0 else ring[prev, 2].copy()
            p2 = p1 if self.known <= 1 else ring[prev2, 2].copy()
            self._state = State(self.time, ring[cur, 0].copy(), ring[cur, 1].copy(),
                                ring[prev, 0].copy(), ring[prev, 1].copy(),
                                angles[cur, 0].copy(), angles[cur, 1].copy(),
                                self.step_count, self.history_dt, w, p1, p2)
        return self._state

    def now(self) -> float:
        """[s] the current state's time (without building a State)."""
        return self._state.time if self._state is not None else self.time

    def joint_values(self, k: int) -> np.ndarray:
        """A copy of the current joint angles (k = 0) or joint velocities (k = 1)."""
        if self._state is not None:
            return (self._state.joint_velocity if k else self._state.joint_angle).copy()
        return self.angles[self.cur, k].copy()

    def load(self) -> None:
        """Before a step: copy the current State into the ring if there is one."""
        s = self._state
        if s is None:
            return
        self.cur = 2                        # (history in slots 1 and 0)
        ring, angles = self.ring, self.angles
        ring[2, 0], ring[2, 1], ring[2, 2] = s.q, s.v, s.warm_start
        ring[1, 0], ring[1, 1], ring[1, 2] = s.q_prev, s.v_prev, s.warm_start_prev
        ring[0, 2] = s.warm_start_prev2
        angles[2, 0], angles[2, 1] = s.joint_angle, s.joint_velocity
        self.time, self.step_count, self.history_dt = s.time, s.step_count, s.history_dt
        self.known = s.known_history()

    def advance(self, h: float) -> None:
        """After a step of size h into slot cur + 1: that slot is the current state (the rule
        of solver._history: the past warm starts count only across steps of one size)."""
        self.known = min(self.known + 1, 2) if self.history_dt == h else 0
        self.cur = (self.cur + 1) % 4
        self.time += h
        self.step_count += 1
        self.history_dt = h
        self._state = None
