"""Subnormal numbers flushed to zero for the duration of a step, or of a batch of steps
(docs/decisions.md "Subnormals flushed to zero inside the step").

Why: a disturbance travels along a long chain through the linear solve decaying by ~10^0.7
per link, so a few steps after a torque starts, the affine entries that were exactly 0 in the
bodies ~450 links or more away hold values below 2.2e-308, the subnormal range. x86 cores handle each arithmetic operation on a
subnormal in microcode, ~100× slower than on a normal number; on a 1000-link chain under
torque ~10 % of the state was subnormal and every term touching it was 4–10× dearer per body
than at 100 links. Values below 2.2e-308 m or rad mean nothing to
the physics, so the step sets the core's flush-to-zero (FTZ: a subnormal result becomes 0)
and denormals-are-zero (DAZ: a subnormal input is read as 0) flags on entry and puts the
caller's flags back on exit: no other code in the process sees them.

Pays on the 1000-link chain under 1 N m per joint (`python bench/profiler.py devices`, two
runs; 10 steps after the torque starts, 1623 entries of its state are subnormal without the
flags): the step costs 1.39 and 1.54 times as much without them in `World.step(n)` (1.51
against 2.09 ms), 1.47 and 1.49 one `World.step()` per call. Chains of 1 and 100 links and
the KUKA iiwa hold no subnormals: 0.94-1.09, noise.

A scene without subnormals (every scene but long chains) steps bit-identically either way.
On a CPU other than x86-64 `enter` and `leave` do nothing (the step is then only slower on
such a chain, not different in any digit that means something).

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

    @kernel
    def flags():
        """The current MXCSR (for the tests)."""
        return _read_mxcsr()
else:                                                       # pragma: no cover (x86-64 here)
    @kernel
    def enter():
        return types.uint32(0)

    @kernel
    def leave(saved):
        pass

    @kernel
    def flags():
        return types.uint32(0)
