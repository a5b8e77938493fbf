"""Two things numba's Python subset cannot say, for the compiled kernels (composite_cpu.py): scratch arrays on
the stack, and cache prefetches. Kept apart from kernels.py, which the PyTorch path imports too, so that
only the compiled kernels import numba."""

from __future__ import annotations

from numba.core import cgutils, types
from numba.extending import intrinsic

ir = cgutils.ir  # llvmlite's IR builder, as numba's own code generation uses it (llvmlite comes with numba)


def stack_array(size: int):
    """A compiled function returning a pointer to ``size`` float64 in its caller's stack frame (numba
    inlines it; the kernels wrap it with numba.carray).

    Why: LLVM keeps a kernel's scratch values in registers, and vectorises loops over them (composite_cpu.py's
    tile rows), only where it can prove that the arrays it loads and stores do not overlap. Stack memory it
    can; np.empty's heap arrays it cannot. Each kernel thread has its own stack: parallel loops share
    nothing."""

    @intrinsic
    def pointer(typingctx):
        def codegen(context, builder, signature, args):
            return cgutils.alloca_once(builder, context.get_value_type(types.float64), size=size)

        return types.CPointer(types.float64)(), codegen

    return pointer


@intrinsic
def prefetch(typingctx, array, row):
    """Start loading row ``row`` of a C-contiguous 2D array into the cache (LLVM's prefetch: a hint, with no
    effect on any result). Why: the compositor reads its Gaussians' records scattered in memory, one per
    pair, and a pair's walk is too long for the CPU to run ahead to the next record by itself."""

    def codegen(context, builder, signature, args):
        arr = context.make_array(signature.args[0])(context, builder, args[0])
        offset = builder.mul(args[1], builder.extract_value(arr.shape, 1))
        byte_ptr = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        fn = builder.module.declare_intrinsic(
            "llvm.prefetch", fnty=ir.FunctionType(ir.VoidType(), [byte_ptr, i32, i32, i32])
        )
        # read, high temporal locality, data cache
        address = builder.bitcast(builder.gep(arr.data, [offset]), byte_ptr)
        builder.call(fn, [address, ir.Constant(i32, 0), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return types.void(array, row), codegen
