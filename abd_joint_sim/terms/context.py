"""What the energy terms read besides q and the model: fixed for the duration of one step."""
from __future__ import annotations

from collections import namedtuple

#: h [s] step size; scale s of the inertia term (1 BDF1, 9/4 BDF2); q_tilde (B,12) the
#: prediction q̃; angle_start [rad] (J,) unwrapped joint angle minus init_angle at the
#: start of the step; drive_target [rad] (D,) UID 19 target relative to init_angle (the
#: aim, or angle_start when passive); drive_on (D,) bool; angle_work: scratch of
#: angles.ANGLE_WORK_SHAPE the drives and limits work in (no allocation in the step);
#: angle_ref (L + P, ≥ 3) the angle terms' references for the step: row k < L what
#: limit.inside reads for limit k (limit.references, from angle_start), row L + k damper k's
#: stiffness and angle linearised at Newton's start (damping.references). One array, not
#: two: every term call takes the context, and each array in it costs every such call.
StepContext = namedtuple('StepContext', ['h', 'scale', 'q_tilde', 'angle_start', 'drive_target', 'drive_on',
                                         'angle_work', 'angle_ref'])
