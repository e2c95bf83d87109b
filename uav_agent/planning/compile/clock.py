"""A monotonic clock the planning kernels read without leaving compiled code.

The kernels check their deadline (`time.perf_counter() + seconds`, from Python) every few
hundred iterations. numba's object mode could call `time.perf_counter`, but an object-mode
block needs an environment that only the JIT builds: an ahead-of-time build (`build/aot.py`)
cannot hold one. So the kernels call the C library's `clock_gettime(CLOCK_MONOTONIC)`, the
clock behind `time.perf_counter` on Linux, directly.
"""
from __future__ import annotations

from llvmlite import ir
from numba.core import cgutils, types
from numba.extending import intrinsic

CLOCK_MONOTONIC = 1     # <time.h> on Linux


@intrinsic
def monotonic(typingctx):
    """Seconds of CLOCK_MONOTONIC, as `time.perf_counter()` gives them."""
    def codegen(context, builder, signature, args):
        i64, i32, f64 = ir.IntType(64), ir.IntType(32), ir.DoubleType()
        timespec = ir.LiteralStructType([i64, i64])
        clock_gettime = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(i32, [i32, timespec.as_pointer()]), "clock_gettime")
        ts = cgutils.alloca_once(builder, timespec)
        builder.call(clock_gettime, [ir.Constant(i32, CLOCK_MONOTONIC), ts])
        sec = builder.sitofp(builder.load(cgutils.gep_inbounds(builder, ts, 0, 0)), f64)
        nsec = builder.sitofp(builder.load(cgutils.gep_inbounds(builder, ts, 0, 1)), f64)
        return builder.fadd(sec, builder.fmul(nsec, ir.Constant(f64, 1e-9)))
    return types.float64(), codegen
