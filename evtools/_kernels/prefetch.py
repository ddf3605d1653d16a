"""A software prefetch for numba kernels whose events hit random pixels of a large state array.

``prefetch(array, index)`` asks the CPU to bring ``array[index]`` into the cache without waiting for it (LLVM's
``llvm.prefetch``, read, high locality): issued a few events ahead, the miss overlaps the work on the current
event. Unlike a plain load ahead, it never stalls the pipeline when the data arrives late, and the compiler cannot
drop it. It changes no result, only timing.
"""

from __future__ import annotations

from evtools._kernels.jit import deferred


def _prefetch(typingctx, array, index):
    """Prefetch the element ``index`` of the 1-D array ``array`` (no bounds check: any index is harmless)."""
    from llvmlite import ir
    from numba import types

    if not isinstance(array, types.Array) or array.ndim != 1 or not isinstance(index, types.Integer):
        return None

    def codegen(context, builder, signature, args):
        array_value, index_value = args
        data = context.make_array(signature.args[0])(context, builder, array_value).data
        address = builder.gep(data, [index_value])
        byte_pointer = ir.IntType(8).as_pointer()
        function = builder.module.declare_intrinsic(
            "llvm.prefetch", fnty=ir.FunctionType(ir.VoidType(), [byte_pointer] + [ir.IntType(32)] * 3)
        )
        constant = ir.IntType(32)
        # address, read (0), high temporal locality (3), data cache (1)
        builder.call(function, [builder.bitcast(address, byte_pointer), constant(0), constant(3), constant(1)])
        return context.get_dummy_value()

    return types.void(array, index), codegen



def _build():
    from numba.extending import intrinsic

    return intrinsic(_prefetch)


prefetch = deferred(_build)
