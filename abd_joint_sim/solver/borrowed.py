"""Structref fields as borrowed arrays: no reference counting in the compiled step.

numba counts references to every array it reads out of a structref (an atomic increment
and decrement of the array's MemInfo), and LLVM's reference-count pruning removes those
counts only in functions that call no other compiled function (docs/speed.md, "The tenth
round"). A step reads ~100 fields per link, and an atomic add costs ~20 cycles here.

`borrow(struct)` sets every array field's MemInfo to null. numba's incref and decref of a
null MemInfo return at once, so reading such a field, or a view of it, counts nothing. The
arrays stay alive because the Python proxy keeps them in its `__dict__` (`model_data.build`,
`workspace.build` put them there), and the struct lives no longer than its proxy: nothing
compiled returns or stores the struct. Each field keeps its `parent` pointer, the numpy
array itself, so a field boxed back to Python (`ModelData`'s `__dict__` is what Python
reads anyway) is that same array.
"""
from __future__ import annotations

from numba import njit
from numba.core import cgutils, types
from numba.core.datamodel import models
from numba.experimental.structref import _Utils, define_attributes
from numba.extending import intrinsic, register_model


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

    def codegen(context, builder, sig, args):
        out = cgutils.create_struct_proxy(array_type)(context, builder, value=args[0])
        out.meminfo = cgutils.get_null_value(out.meminfo.type)
        return out._getvalue()
    return array_type(array_type), codegen


@njit(cache=True)
def _borrow(struct):
    _null_array_meminfos(struct)


def borrow(proxy):
    """Make `proxy`'s array fields borrowed in compiled code (see the module docstring);
    every array field must also be in `proxy.__dict__`. Returns proxy."""
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
    return Struct(struct_type)(struct_type), lambda context, builder, sig, args: args[0]
