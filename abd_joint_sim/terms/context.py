"""What the energy terms read besides q and the model: fixed for the duration of one step.

A numba structref, passed by reference (a namedtuple of six arrays would be copied onto the
stack, ~300 bytes, at each of a dozen term calls per Newton iteration). The step uses its
Workspace's context, setting h, scale and drive_on in place (solver/step.py).

Fields:
- h [s] step size; scale s of the inertia term (1 BDF1, 9/4 BDF2);
- q_tilde (B,12) the prediction q̃;
- angle_start [rad] (J,) unwrapped joint angle minus init_angle at the start of the step;
- drive_target [rad] (D,) UID 19 target relative to init_angle (the aim, or angle_start
  when passive); drive_on (D,) bool;
- angle_work: scratch of angle.ANGLE_WORK_SHAPE the drives and limits work in;
- angle_ref (terms.reference_shape): rows each term of terms.REFERENCE_TERMS writes once per
  step (solver/newton.py `references`): the L limits' first, then the P dampers', then the
  prismatic dampers'.
"""
from __future__ import annotations

import numpy as np
from numba import types
from numba.experimental import structref

from ..jit import kernel

@structref.register
class StepContextType(types.StructRef):
    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(t)) for name, t in fields)


#: the one numba type of a context: C-contiguous arrays, so Python-made contexts and the
#: Workspace's compile to the same kernels
CONTEXT_TYPE = StepContextType([
    ('h', types.float64), ('scale', types.float64),
    ('q_tilde', types.float64[:, ::1]), ('angle_start', types.float64[::1]),
    ('drive_target', types.float64[::1]), ('drive_on', types.boolean[::1]),
    ('angle_work', types.float64[:, ::1]), ('angle_ref', types.float64[:, ::1])])
FIELDS = tuple(CONTEXT_TYPE.field_dict)     #: the field names, in the constructor's order


@kernel
def _new(h, scale, q_tilde, angle_start, drive_target, drive_on, angle_work, angle_ref):
    ctx = structref.new(CONTEXT_TYPE)
    ctx.h = h
    ctx.scale = scale
    ctx.q_tilde = q_tilde
    ctx.angle_start = angle_start
    ctx.drive_target = drive_target
    ctx.drive_on = drive_on
    ctx.angle_work = angle_work
    ctx.angle_ref = angle_ref
    return ctx


def _compiled(x, dtype):
    """x itself if it has the layout of CONTEXT_TYPE's arrays (C-contiguous, writable, of
    dtype), else such a copy (a read-only array is another numba type)."""
    a = np.ascontiguousarray(x, dtype=dtype)
    return a if a.flags.writeable else a.copy()


class StepContext(structref.StructRefProxy):
    """A step's context, made in Python (the Workspace's own, World.mechanical_energy, the
    tests). The arrays are taken as they are when they already have the compiled layout
    (C-contiguous and writable, float64, bool for drive_on; q_tilde, angle_work and
    angle_ref 2-D), else copied into it. Python reads the fields from the instance's
    __dict__ (the same arrays the struct refers to), as for ModelData; h and scale there are
    those it was made with (the step sets them in the Workspace's context in compiled code)."""

    def __new__(cls, h, scale, q_tilde, angle_start, drive_target, drive_on, angle_work, angle_ref):
        values = dict(h=float(h), scale=float(scale), q_tilde=_compiled(q_tilde, np.float64),
                      angle_start=_compiled(angle_start, np.float64),
                      drive_target=_compiled(drive_target, np.float64),
                      drive_on=_compiled(drive_on, np.bool_), angle_work=_compiled(angle_work, np.float64),
                      angle_ref=_compiled(angle_ref, np.float64))
        ctx = _new(*(values[name] for name in FIELDS))
        ctx.__dict__.update(values)
        return ctx

    def replace(self, **changes) -> StepContext:
        """A new context with the given fields changed (its other arrays shared)."""
        values = {name: self.__dict__[name] for name in FIELDS}
        values.update(changes)
        return StepContext(*(values[name] for name in FIELDS))


structref.define_boxing(StepContextType, StepContext)
