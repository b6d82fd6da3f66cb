"""Subnormal numbers flushed to zero for the duration of a step, or of a batch of steps
(docs/decisions.md "Subnormals flushed to zero inside the step").

The step sets the core's flush-to-zero (FTZ) and denormals-are-zero (DAZ) flags on entry
and puts the caller's back on exit (x86-64; elsewhere `enter` and `leave` do nothing). A
scene without subnormals (all but long chains) steps bit-identically either way.

Pays on the 1000-link chain under 1 N m per joint (`python bench/profiler.py devices`, two
runs; 1623 subnormal entries without the flags): 1.39 and 1.54 times the cost without them
in `World.step(n)` (1.51 against 2.09 ms), 1.47 and 1.49 per `World.step()`. Chains of 1 and
100 links and the KUKA iiwa hold no subnormals: 0.94-1.09, noise.

`ABD_FLUSH_SUBNORMALS=0` in the environment makes `enter` and `leave` do nothing (the
comparison; cache.py keeps that build apart).
"""
from __future__ import annotations

import platform

import llvmlite.ir as ir
from numba import types
from . import kernel
from .cache import switch
from numba.core import cgutils
from numba.extending import intrinsic

X86 = platform.machine().lower() in ('x86_64', 'amd64')
#: False with ABD_FLUSH_SUBNORMALS=0 in the environment: the step keeps subnormals (the comparison)
ENABLED = switch('ABD_FLUSH_SUBNORMALS')
#: MXCSR bits: FTZ (flush to zero, bit 15) and DAZ (denormals are zero, bit 6)
FTZ_DAZ = 0x8040


def _mxcsr_call(builder, name, ptr):
    fnty = ir.FunctionType(ir.VoidType(), [ptr.type])
    builder.call(cgutils.get_or_insert_function(builder.module, fnty, name), [ptr])


@intrinsic
def _read_mxcsr(typingctx):
    """The SSE control and status register (llvm.x86.sse.stmxcsr)."""
    def codegen(context, builder, signature, args):
        ptr = cgutils.alloca_once(builder, ir.IntType(32))
        _mxcsr_call(builder, 'llvm.x86.sse.stmxcsr', ptr)
        return builder.load(ptr)
    return types.uint32(), codegen


@intrinsic
def _write_mxcsr(typingctx, value):
    """Load `value` into the SSE control and status register (llvm.x86.sse.ldmxcsr)."""
    def codegen(context, builder, signature, args):
        ptr = cgutils.alloca_once(builder, ir.IntType(32))
        builder.store(args[0], ptr)
        _mxcsr_call(builder, 'llvm.x86.sse.ldmxcsr', ptr)
        return context.get_dummy_value()
    return types.none(types.uint32), codegen


if X86:
    @kernel
    def enter():
        """Set FTZ and DAZ; returns the flags to give `leave`."""
        if not ENABLED:
            return types.uint32(0)
        saved = _read_mxcsr()
        _write_mxcsr(saved | types.uint32(FTZ_DAZ))
        return saved

    @kernel
    def leave(saved):
        """Put back the caller's FTZ and DAZ as `enter` found them; the exception flags the step
        raised stay raised, as they would without `enter`."""
        mask = types.uint32(FTZ_DAZ)
        _write_mxcsr((_read_mxcsr() & ~mask) | (types.uint32(saved) & mask))
else:                                                       # pragma: no cover (x86-64 here)
    @kernel
    def enter():
        return types.uint32(0)

    @kernel
    def leave(saved):
        pass
