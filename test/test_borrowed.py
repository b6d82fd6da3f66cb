"""The compiled step's borrowed arrays (abd_joint_sim/jit/refcounts.py): every array field
of a Solver's ModelData and Workspace has a null MemInfo in compiled code (no reference
counting), the same array object comes back when compiled code hands a field to Python,
and building and dropping Worlds leaks no MemInfo."""
from __future__ import annotations

import gc

import numpy as np
import pytest
from numba import njit, types
from numba.core import cgutils
from numba.experimental.structref import _Utils
from numba.extending import intrinsic

from abd_joint_sim import Scene, World

from physics_helpers import chain_dict


@intrinsic
def _owned_array_fields(typingctx, struct_type):
    """How many array fields of the struct have a MemInfo (0 when all are borrowed)."""
    def codegen(context, builder, sig, args):
        data = _Utils(context, builder, struct_type).get_data_struct(args[0])
        count = context.get_constant(types.intp, 0)
        for name, field_type in struct_type.field_dict.items():
            if isinstance(field_type, types.Array):
                array = cgutils.create_struct_proxy(field_type)(context, builder,
                                                                 value=getattr(data, name))
                owned = builder.zext(cgutils.is_not_null(builder, array.meminfo), count.type)
                count = builder.add(count, owned)
        return count
    return types.intp(struct_type), codegen


@njit
def owned_array_fields(struct):
    return _owned_array_fields(struct)


@njit
def body_M(m):
    return m.body_M


@njit
def tree_X(ws):
    return ws.tree_X


def _world():
    w = World(Scene.from_dict(chain_dict(3, torque=0.5, gravity=(0.0, 0.0, -9.81))))
    w.step(3)
    return w


@pytest.mark.slow
def test_model_and_workspace_arrays_are_borrowed():
    w = _world()
    data, work = w.solver.data, w.solver.work
    assert owned_array_fields(data) == 0
    assert owned_array_fields(work) == 0
    # the oracle sees an owned array: a struct built without borrow() has all its MemInfos
    from abd_joint_sim.solver.workspace import FIELDS, Workspace
    plain = Workspace(*(np.zeros(2) for _ in FIELDS))
    assert owned_array_fields(plain) == len(FIELDS)


def test_a_field_handed_to_python_is_the_same_array():
    """A borrowed field keeps its `parent`: boxed, it is the proxy's array itself, not a
    view of memory the proxy owns (which would outlive nothing)."""
    w = _world()
    assert body_M(w.solver.data) is w.solver.data.__dict__['body_M']
    assert tree_X(w.solver.work) is w.solver.work.__dict__['tree_X']


def test_building_and_dropping_worlds_leaks_no_meminfo():
    """borrow() gives up the struct's own reference to each array's MemInfo; without that,
    every array of every Solver would stay allocated. Counted by numba's NRT statistics."""
    from numba.core.runtime import _nrt_python as nrt      # (numba is pinned)
    _world()                                               # compiled, caches warm
    gc.collect()
    was_on = nrt.memsys_stats_enabled()
    nrt.memsys_enable_stats()
    try:
        before = nrt.memsys_get_stats_mi_alloc() - nrt.memsys_get_stats_mi_free()
        allocated = nrt.memsys_get_stats_mi_alloc()
        for _ in range(5):
            w = _world()
            w.step()
            del w
        gc.collect()
        allocated = nrt.memsys_get_stats_mi_alloc() - allocated
        after = nrt.memsys_get_stats_mi_alloc() - nrt.memsys_get_stats_mi_free()
    finally:
        if not was_on:
            nrt.memsys_disable_stats()
    assert allocated > 5 * 40           # the Worlds' arrays were counted (ModelData alone has ~60)
    assert after == before, (before, after)
