"""Lane masks: a packet's active rays as a 64-bit mask (bit l = lane l); borrowed arrays."""
import numba
import numpy as np
from numba.core import cgutils
from numba.extending import intrinsic

# de Bruijn sequence: index of a mask's lowest set bit in three integer operations
_DEBRUIJN = np.uint64(0x03F79D71B4CB0A89)
_DEBRUIJN_IDX = np.zeros(64, np.int64)
for _i in range(64):
    _DEBRUIJN_IDX[(((1 << _i) * 0x03F79D71B4CB0A89) & (2**64 - 1)) >> 58] = _i


@numba.njit(cache=True, inline="always")
def lowest_lane(m):
    """Index of the lowest set bit of a non-zero lane mask."""
    return _DEBRUIJN_IDX[((m & (~m + np.uint64(1))) * _DEBRUIJN) >> np.uint64(58)]


@numba.njit(cache=True, inline="always")
def popcount(x):
    """Set bits of a 64-bit mask (SWAR, constant time)."""
    x = np.uint64(x)
    x = x - ((x >> np.uint64(1)) & np.uint64(0x5555555555555555))
    x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2)) & np.uint64(0x3333333333333333))
    x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return np.int64((x * np.uint64(0x0101010101010101)) >> np.uint64(56))


@numba.njit(cache=True, inline="always")
def highest_lane(m):
    """Index of the highest set bit of a non-zero lane mask."""
    m = np.uint64(m)
    m |= m >> np.uint64(1)
    m |= m >> np.uint64(2)
    m |= m >> np.uint64(4)
    m |= m >> np.uint64(8)
    m |= m >> np.uint64(16)
    m |= m >> np.uint64(32)
    return lowest_lane(m ^ (m >> np.uint64(1)))


@intrinsic
def borrow(typingctx, arr):
    """A view of array ``arr`` that holds no reference (its memory-info pointer is null, so
    numba's reference counting skips it). Valid while ``arr`` itself is alive: for a kernel's
    per-step loops over arrays its caller owns (the count updates are atomic operations, and
    in a compiled loop that passes arrays on they cost more than the arithmetic)."""
    def codegen(context, builder, sig, args):
        view = cgutils.create_struct_proxy(sig.return_type)(context, builder, value=args[0])
        view.meminfo = cgutils.get_null_value(view.meminfo.type)
        return view._getvalue()
    return arr(arr), codegen
