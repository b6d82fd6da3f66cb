"""The compiled step without numba's reference counts (docs/decisions.md).

numba counts a reference (an atomic add and subtract, ~20 cycles each) for every array read
from a structref, array argument, view and structref passed on: ~270 per step on a chain,
~470 on a 7-joint arm in its limits. The step's arrays have an owner outside compiled code:

- `borrow(proxy)` nulls the MemInfo of every array field of a ModelData or Workspace, once
  (the arrays stay alive in the proxy's `__dict__`; each keeps its `parent`, the array);
- `array(a)` nulls an argument's MemInfo for the call (its views inherit the null);
- `struct(s)` retypes a structref argument as `Struct`, whose data model has no MemInfo.

Pays (`python bench/profiler.py devices`, two runs, ratio of the µs per step without it to
with it): one link 1.20 and 1.26 in `World.step(n)` (1.65 against 2.02 µs), 1.19 and 1.18 one
`World.step()` per call; the KUKA iiwa 1.12 and 1.08 (n), 1.08 and 1.10 (per call); chains of
100 and 1000 links 1.00-1.11.

`ABD_REFCOUNTS=0` in the environment makes `array`, `struct` and `borrow` identities: numba
counts every reference (the comparison; cache.py keeps that build apart).
"""
from __future__ import annotations

from . import kernel
from .cache import switch
from numba.core import cgutils, types
from numba.core.imputils import impl_ret_borrowed
from numba.core.datamodel import models
from numba.experimental.structref import _Utils, define_attributes
from numba.extending import intrinsic, register_model

#: False with ABD_REFCOUNTS=0 in the environment: no reference is borrowed (the comparison)
ENABLED = switch('ABD_REFCOUNTS')


def _same(context, builder, sig, args):       # the identity, as a counted new reference
    return impl_ret_borrowed(context, builder, sig.return_type, args[0])


@intrinsic
def _null_array_meminfos(typingctx, struct_type):
    def codegen(context, builder, sig, args):
        [instance] = args
        data = _Utils(context, builder, struct_type).get_data_struct(instance)
        for name, field_type in struct_type.field_dict.items():
            if not isinstance(field_type, types.Array):
                continue
            value = getattr(data, name)
            # the field's own reference goes: the proxy's __dict__ holds the array
            context.nrt.decref(builder, field_type, value)
            array = cgutils.create_struct_proxy(field_type)(context, builder, value=value)
            array.meminfo = cgutils.get_null_value(array.meminfo.type)
            setattr(data, name, array._getvalue())
        return context.get_dummy_value()
    return types.none(struct_type), codegen


@intrinsic
def array(typingctx, array_type):
    """`array(a)`: a with a null MemInfo, for the duration of a call that received a from
    its caller (who keeps it alive): no reference counting of a or of any view of it."""
    if not isinstance(array_type, types.Array):
        return None
    if not ENABLED:
        return array_type(array_type), _same

    def codegen(context, builder, sig, args):
        out = cgutils.create_struct_proxy(array_type)(context, builder, value=args[0])
        out.meminfo = cgutils.get_null_value(out.meminfo.type)
        return out._getvalue()
    return array_type(array_type), codegen


@kernel
def _borrow(struct):
    _null_array_meminfos(struct)


def borrow(proxy):
    """Make `proxy`'s array fields borrowed in compiled code (see the module docstring);
    every array field must also be in `proxy.__dict__`. Returns proxy."""
    if ENABLED:
        _borrow(proxy)
    return proxy


class Struct(types.StructRef):
    """A structref read without reference counting: `struct(s)` inside a compiled call that
    received s from its caller. Same fields and layout as the original type."""

    def __init__(self, original):
        self.original = original
        self._fields = original._fields
        self._typename = f'Borrowed[{type(original).__qualname__}]'
        types.Type.__init__(self, name=f'numba.{self._typename}{self._fields}')

    def __reduce__(self):           # the kernel cache pickles signatures
        return (Struct, (self.original,))


@register_model(Struct)
class _StructModel(models.StructRefModel):
    # the same value as a structref (a MemInfo pointer) that numba neither increfs nor decrefs
    def has_nrt_meminfo(self):
        return False

    def traverse(self, builder):
        return []


define_attributes(Struct)


@intrinsic
def struct(typingctx, struct_type):
    """`struct(s)`: the structref s as a `Struct`, for the duration of a call that received s
    from its caller (who keeps it alive): no reference counting of s in the functions it is
    passed to."""
    if isinstance(struct_type, Struct):
        return struct_type(struct_type), lambda context, builder, sig, args: args[0]
    if not isinstance(struct_type, types.StructRef):
        return None
    if not ENABLED:
        return struct_type(struct_type), _same
    return Struct(struct_type)(struct_type), lambda context, builder, sig, args: args[0]
