"""List unit (golden model): turns a leaf's list address into triangle addresses.

List entries are 32-bit triangle indices, two per 64-bit memory word (low half first). One
list-op = one triangle address emitted. Memory reads: every 64-bit word the leaf's entries
touch, once per leaf visit (a word holding two entries is read once).
"""
import numba
import numpy as np


@numba.njit(cache=True, inline="always")
def list_entry(mem, list_base, j):
    w = mem[list_base + (j >> 1)]
    return np.int64((w >> np.uint64(32 * (j & 1))) & np.uint64(0xFFFFFFFF))


@numba.njit(cache=True, inline="always")
def list_words(first, count):
    """64-bit words read to fetch entries [first, first + count)."""
    if count == 0:
        return 0
    return ((first + count - 1) >> 1) - (first >> 1) + 1


@numba.njit(cache=True, inline="always")
def leaf_entries(mem, list_base, first, count, out):
    """The list unit on one leaf: the triangle indices of entries ``[first, first + count)`` in
    entry order into ``out``; returns the 64-bit words it read."""
    for j in range(count):
        out[j] = list_entry(mem, list_base, first + j)
    return list_words(first, count)
