"""Arrays a numba kernel reads without counting references to them.

numba counts the references to every array it passes: each array handed to an inlined helper, unpacked from a
tuple or passed into a call costs an atomic increment and decrement, which its reference pruning removes only in
simple control flow. In the echo stage's per-beam path, whose helpers take the batch's tuples of arrays (the
volume tables, the output buffers), that was a third of the time (``perf``: the two atomic instructions of
NRT_incref / NRT_decref). :func:`borrow` gives a kernel views of arrays its caller owns for the whole call, without
the count: the same memory, read and written as before, never freed through the view.

Only for arrays that outlive the kernel's use of the view (a kernel's own arguments, which its caller holds) and
views that never leave the kernel (not returned, not stored).
"""

from __future__ import annotations

from numba import types
from numba.extending import intrinsic


def _without_count(context, builder, typ, value):
    """``value`` of numba type ``typ`` with every array in it (itself, or a tuple's members) uncounted."""
    if isinstance(typ, types.Array):
        view = context.make_array(typ)(context, builder, value=value)
        view.meminfo = context.get_constant_null(types.MemInfoPointer(typ.dtype))
        view.parent = context.get_constant_null(types.pyobject)
        return view._getvalue()
    if isinstance(typ, types.BaseTuple):
        for i, member in enumerate(typ.types):
            item = builder.extract_value(value, i)
            value = builder.insert_value(value, _without_count(context, builder, member, item), i)
    return value


@intrinsic
def borrow(typingctx, value):
    """``value`` (an array, or a tuple / named tuple of arrays and scalars) with its arrays borrowed: views of the
    same memory without a reference count (module doc)."""
    if not isinstance(value, (types.Array, types.BaseTuple)):
        return None

    def codegen(context, builder, signature, args):
        return _without_count(context, builder, signature.args[0], args[0])

    return value(value), codegen



