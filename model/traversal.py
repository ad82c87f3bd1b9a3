"""Traversal unit (golden model): one packet step at a kd-tree node.

A trav-op is one active ray at one inner node: ``dist = (split - o[axis]) * inv[axis]`` (one FP
sub, one FP mul), then two compares decide which children the ray needs and a min/max clips its
interval. The node (64 bits) is fetched once per packet. The hardware splits the packet's lanes
statically over ``trav_subunits`` sub-units; the model computes the same per-ray values.

Node word (see ``docs/memory-format.md``): bits [1:0] axis (3 = leaf); inner: [31:2] left child
(right = left + 1), [63:32] split (binary32 bits); leaf: [31:2] triangle count, [63:32] first
list entry.
"""
import numba
import numpy as np

from .fp import fmax, fmin, fmul, fsub

LEAF = 3

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
def decode_node(w):
    """(kind, field, hi): kind 0/1/2 = split axis, 3 = leaf; field = child or count; hi = bits."""
    w = np.uint64(w)
    return (np.int64(w & np.uint64(3)), np.int64((w >> np.uint64(2)) & np.uint64(0x3FFFFFFF)),
            np.uint32(w >> np.uint64(32)))


@numba.njit(cache=True, inline="always")
def bits_to_f32(b):
    return np.uint32(b).view(np.float32)  # noqa


@numba.njit(cache=True, error_model="numpy")
def classify(split, axis, mask, n, org, inv, tnear, tfar, dist, E, M):
    """Per active lane: dist to the split plane, and which children the ray needs.

    ``org``/``inv`` are the packet's per-lane copies. Returns (near_mask, far_mask). ``need_near = not (dist < tnear)``, ``need_far = not
    (dist > tfar)`` (a NaN dist, a ray lying in the plane, needs both)."""
    mnear = np.uint64(0)
    mfar = np.uint64(0)
    m = mask
    while m:
        l = lowest_lane(m)
        bit = m & (~m + np.uint64(1))
        m ^= bit
        d = fmul(fsub(split, org[l, axis], E, M), inv[l, axis], E, M)
        dist[l] = d
        if not (d < tnear[l]):
            mnear |= bit
        if not (d > tfar[l]):
            mfar |= bit
    return mnear, mfar


@numba.njit(cache=True, error_model="numpy")
def clip_near(mask, dist, tfar, n):
    """Rays descending into the near child: tfar = min(tfar, dist)."""
    m = mask
    while m:
        l = lowest_lane(m)
        m &= m - np.uint64(1)
        tfar[l] = fmin(tfar[l], dist[l])


@numba.njit(cache=True, error_model="numpy")
def clip_far(mask, dist, tnear, n):
    """Rays descending into the far child: tnear = max(tnear, dist)."""
    m = mask
    while m:
        l = lowest_lane(m)
        m &= m - np.uint64(1)
        tnear[l] = fmax(tnear[l], dist[l])


@numba.njit(cache=True, error_model="numpy")
def push(sp, node, mask, dist, tnear, tfar, s_node, s_mask, s_near, s_far, n):
    """Push the far child: its mask and, per ray, the far interval [max(tnear, dist), tfar]."""
    s_node[sp] = node
    s_mask[sp] = mask
    m = mask
    while m:
        l = lowest_lane(m)
        m &= m - np.uint64(1)
        s_near[sp, l] = fmax(tnear[l], dist[l])
        s_far[sp, l] = tfar[l]
    return sp + 1


@numba.njit(cache=True, error_model="numpy")
def pop(sp, terminated, tnear, tfar, s_node, s_mask, s_near, s_far, n):
    """Pop entries until one has a live ray. Returns (sp, node, mask); mask 0 = packet done."""
    while sp > 0:
        sp -= 1
        mask = s_mask[sp] & ~terminated
        if mask:
            m = mask
            while m:
                l = lowest_lane(m)
                m &= m - np.uint64(1)
                tnear[l] = s_near[sp, l]
                tfar[l] = s_far[sp, l]
            return sp, s_node[sp], mask
    return 0, np.int64(0), np.uint64(0)
