"""Stack scratch for the compiled kernels (composite_cpu.py, project_cpu.py): kept apart from kernels.py,
which the PyTorch path imports too, so that only the compiled kernels import numba."""

from __future__ import annotations

from numba.core import cgutils, types
from numba.extending import intrinsic


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
