"""State (what changes per step) and Control (the inputs written between steps).

`State` is exactly the integration state (MuJoCo's sense): two worlds with equal Model and
State step identically. `Control` holds the per-term inputs, prefixed by their term.
"""
from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np


@dataclass(slots=True)
class State:
    time: float                 #: [s]
    q: np.ndarray               #: (B,12) body states [p, a1, a2, a3]
    v: np.ndarray               #: (B,12) dq/dt
    q_prev: np.ndarray          #: (B,12) q one step back (BDF2 history; = q at start)
    v_prev: np.ndarray          #: (B,12) v one step back
    #: [rad | m] (J,) multi-turn angle including init_angle (a revolute joint), or distance
    #: including init_distance (a prismatic joint)
    joint_angle: np.ndarray
    joint_velocity: np.ndarray  #: [rad/s | m/s] (J,)
    step_count: int = 0
    history_dt: float = 0.0     #: [s] step size q_prev/v_prev belong to; 0 = no history (BDF2 restarts)
    #: (B,12) Newton's last correction (q − q̃)/(c h²), c = 1 (BDF1) or 4/9 (BDF2), which the
    #: next step extrapolates over the last three steps (solver/step.py). None = zeros.
    warm_start: np.ndarray | None = None
    #: (B,12) the warm starts one and two steps (of history_dt) before; an unknown one is the
    #: same array as the newer one (None = that)
    warm_start_prev: np.ndarray | None = None
    warm_start_prev2: np.ndarray | None = None

    def __post_init__(self):
        if self.warm_start is None:
            self.warm_start = np.zeros_like(self.q)
        if self.warm_start_prev is None:
            self.warm_start_prev = self.warm_start
        if self.warm_start_prev2 is None:
            self.warm_start_prev2 = self.warm_start_prev

    def known_history(self) -> int:
        """How many past warm starts are known (0, 1 or 2; unknown ones by identity)."""
        if self.warm_start_prev is self.warm_start:
            return 0
        return 1 if self.warm_start_prev2 is self.warm_start_prev else 2

    def extrapolation_order(self, h: float) -> int:
        """Past warm starts a step of size h extrapolates over: 0, 1 (linear), 2 (quadratic)."""
        return self.known_history() if self.history_dt == h else 0

    @classmethod
    def initial(cls, model) -> 'State':
        q, v = model.body_q0.copy(), model.body_v0.copy()
        v[model.body_fixed] = 0.0
        return cls(0.0, q, v, q.copy(), v.copy(), model.joint_init_angle.copy(),
                   np.zeros(model.joint_count))

    def copy(self) -> 'State':
        """A deep copy; the warm starts that are the same array stay one array."""
        w = self.warm_start.copy()
        p1 = w if self.warm_start_prev is self.warm_start else self.warm_start_prev.copy()
        p2 = p1 if self.warm_start_prev2 is self.warm_start_prev else self.warm_start_prev2.copy()
        return State(self.time, self.q.copy(), self.v.copy(), self.q_prev.copy(), self.v_prev.copy(),
                     self.joint_angle.copy(), self.joint_velocity.copy(), self.step_count,
                     self.history_dt, w, p1, p2)


@dataclass
class Control:
    #: [N m | N] (T + F,) the joints' efforts: per UID 668 joint (model.torque_joints order)
    #: its torque [N m], then per UID 667 joint (model.prismatic_force_joints) its force [N]
    torque_value: np.ndarray
    torque_enabled: np.ndarray  #: (T + F,) bool, likewise
    #: [rad | m] (D + Ds,) absolute aims (including init_angle / init_distance): per UID 19
    #: drive (model.drive_joints) an angle, then per UID 21 drive (model.prismatic_drive_joints)
    #: a distance
    drive_aim: np.ndarray
    drive_enabled: np.ndarray   #: (D + Ds,) bool, likewise
    drive_passive: np.ndarray   #: (D + Ds,) bool, likewise

    @classmethod
    def initial(cls, model) -> 'Control':
        m = model
        return cls(np.concatenate([m.torque_value0, m.prismatic_force_value0]),
                   np.concatenate([m.torque_enabled0, m.prismatic_force_enabled0]),
                   np.concatenate([m.drive_aim0, m.prismatic_drive_aim0]),
                   np.concatenate([m.drive_enabled0, m.prismatic_drive_enabled0]),
                   np.concatenate([m.drive_passive0, m.prismatic_drive_passive0]))

    def copy(self) -> 'Control':
        return Control(*(getattr(self, f.name).copy() for f in fields(self)))
