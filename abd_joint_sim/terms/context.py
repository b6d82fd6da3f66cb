"""What the energy terms read besides q and the model: fixed for the duration of one step."""
from __future__ import annotations

from collections import namedtuple

#: h [s] step size; scale s of the inertia term (1 BDF1, 9/4 BDF2); q_tilde (B,12) the
#: prediction q̃; angle_start [rad] (J,) unwrapped joint angle minus init_angle at the
#: start of the step; drive_target [rad] (D,) UID 19 target relative to init_angle (the
#: aim, or angle_start when passive); drive_on (D,) bool; angle_work: scratch of
#: angles.ANGLE_WORK_SHAPE the drives and limits work in (no allocation in the step);
#: limit_ref (L,3) what limit.inside reads, made by limit.references from angle_start;
#: damping (P,21) the dampers' stiffness and angle linearised at Newton's start
#: (damping.references).
StepContext = namedtuple('StepContext', ['h', 'scale', 'q_tilde', 'angle_start', 'drive_target', 'drive_on',
                                         'angle_work', 'limit_ref', 'damping'])
