"""A monotonic clock the planning kernels read without leaving compiled code.

The kernels check their deadline (`time.perf_counter() + seconds`, from Python) every few
hundred iterations. numba's object mode could call `time.perf_counter`, but an object-mode
block needs an environment that only the JIT builds: an ahead-of-time build (`build/aot.py`)
cannot hold one. So the kernels call the C library's `clock_gettime(CLOCK_MONOTONIC)`, the
clock behind `time.perf_counter` on Linux, directly.
"""
from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.extending import intrinsic

CLOCK_MONOTONIC = 1     # <time.h> on Linux


@intrinsic
def monotonic(typingctx):
    """Seconds of CLOCK_MONOTONIC, as `time.perf_counter()` gives them. Written in llvmlite's IR
    alone: numba's public `intrinsic` is all it takes of numba (no helper of its internals)."""
    def codegen(context, builder, signature, args):
        i64, i32, f64 = ir.IntType(64), ir.IntType(32), ir.DoubleType()
        timespec = ir.LiteralStructType([i64, i64])
        module = builder.module
        fnty = ir.FunctionType(i32, [i32, timespec.as_pointer()])
        clock_gettime = module.globals.get("clock_gettime") or ir.Function(module, fnty, "clock_gettime")
        # In the entry block, as LLVM wants its allocas: a loop calling the clock does not grow the stack.
        with builder.goto_entry_block():
            ts = builder.alloca(timespec)
        builder.call(clock_gettime, [ir.Constant(i32, CLOCK_MONOTONIC), ts])
        zero = ir.Constant(i32, 0)
        sec = builder.sitofp(builder.load(builder.gep(ts, [zero, zero], inbounds=True)), f64)
        nsec = builder.sitofp(builder.load(builder.gep(ts, [zero, ir.Constant(i32, 1)], inbounds=True)), f64)
        return builder.fadd(sec, builder.fmul(nsec, ir.Constant(f64, 1e-9)))
    return types.float64(), codegen
