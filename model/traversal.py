"""Traversal unit (golden model): a packet's walk through the kd-tree, step by step.

The steps have the names of the RTL's engines (``rtl/traversal.py``): :func:`start_packet`
(loader) and :func:`pass_mask` (one pass per direction octant present in the packet),
:func:`decode_node` (control engine), :func:`classify` (the sub-units), :func:`decide` (near /
far / push), :func:`terminate` (result engine) and :func:`pop`. ``model.rtc.trace_packet``
runs them in the order the RTC does.

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

from .fp import fmax, fmin, fmul, fsub, sign_bit
from .lanes import lowest_lane


@numba.njit(cache=True, inline="always")
def decode_node(w):
    """(kind, field, hi): kind 0/1/2 = split axis, 3 = leaf; field = child or count; hi = bits."""
    w = np.uint64(w)
    return (np.int64(w & np.uint64(3)), np.int64((w >> np.uint64(2)) & np.uint64(0x3FFFFFFF)),
            np.uint32(w >> np.uint64(32)))


@numba.njit(cache=True, inline="always")
def bits_to_f32(b):
    return np.uint32(b).view(np.float32)  # noqa


@numba.njit(cache=True, inline="always", error_model="numpy")
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


@numba.njit(cache=True, inline="always")
def lane_on(mask, l):
    """Is lane ``l`` in ``mask``?"""
    return (mask >> np.uint64(l)) & np.uint64(1) != np.uint64(0)


# The per-lane updates below visit every lane and select by the mask (a lane outside it keeps
# its value): the same result as visiting only the mask's lanes, in loops the compiler turns
# into vector instructions.

_FLT_MIN = np.float32(2.0 ** -126)


@numba.njit(cache=True, inline="always", error_model="numpy")
def classify32(split, axis, mask, n, org_t, inv_t, tnear, tfar, dist, org, inv):
    """:func:`classify` for binary32, faster: every lane in plain IEEE float32 (``org_t``,
    ``inv_t``: the packet's origins and inverse directions by axis, (3, n)); if an active
    lane's difference or product lies where IEEE and the hardware can differ (at or below the
    smallest normal, ``model.fp.fadd``'s fast path), the step is redone by :func:`classify`.
    Bit-identical to it."""
    o = org_t[axis]
    iv = inv_t[axis]
    mnear = np.uint64(0)
    mfar = np.uint64(0)
    tiny = np.uint64(0)
    for l in range(n):
        a = split - o[l]
        d = a * iv[l]
        dist[l] = d
        bit = np.uint64(1) << np.uint64(l)
        tiny |= bit if (abs(a) <= _FLT_MIN) | (abs(d) <= _FLT_MIN) else np.uint64(0)
        mnear |= np.uint64(0) if d < tnear[l] else bit
        mfar |= np.uint64(0) if d > tfar[l] else bit
    if tiny & mask:
        return classify(split, axis, mask, n, org, inv, tnear, tfar, dist, 8, 23)
    return mnear & mask, mfar & mask


@numba.njit(cache=True, inline="always", error_model="numpy")
def clip_near(mask, dist, tfar, n):
    """Rays descending into the near child: tfar = min(tfar, dist)."""
    for l in range(n):
        v = fmin(tfar[l], dist[l])
        tfar[l] = v if lane_on(mask, l) else tfar[l]


@numba.njit(cache=True, inline="always", error_model="numpy")
def clip_far(mask, dist, tnear, n):
    """Rays descending into the far child: tnear = max(tnear, dist)."""
    for l in range(n):
        v = fmax(tnear[l], dist[l])
        tnear[l] = v if lane_on(mask, l) else tnear[l]


@numba.njit(cache=True, inline="always", error_model="numpy")
def push(sp, node, mask, dist, tnear, tfar, s_node, s_mask, s_near, s_far, n):
    """Push the far child: its mask and, per ray, the far interval [max(tnear, dist), tfar]
    (written for every lane; only the mask's lanes are ever read back)."""
    s_node[sp] = node
    s_mask[sp] = mask
    for l in range(n):
        s_near[sp, l] = fmax(tnear[l], dist[l])
        s_far[sp, l] = tfar[l]
    return sp + 1


@numba.njit(cache=True, inline="always", error_model="numpy")
def push_one(sp, node, mask, mnear, dist, tnear, tfar, s_node, s_mask, s_val, s_keep, n):
    """:func:`push` with one value a lane (``Config.trav_stack = "one_value"``): a lane that
    needs the near child too and whose ``tfar`` the near clip changes (``dist < tfar``: the
    interval is never NaN, a live ray's ``tnear <= tfar``) stores ``tfar`` (``keep`` 0: at the pop its ``tnear`` is its
    ``tfar`` then, which is ``min(tfar, dist)`` again); every other lane stores ``max(tnear,
    dist)`` (``keep`` 1: its ``tfar`` then is this one). The caller clips the far-only lanes'
    ``tnear`` now, so their registers hold the far interval until the pop."""
    s_node[sp] = node
    s_mask[sp] = mask
    for l in range(n):
        changed = lane_on(mnear, l) and dist[l] < tfar[l]
        s_val[sp, l] = tfar[l] if changed else fmax(tnear[l], dist[l])
        s_keep[sp, l] = np.float32(0) if changed else np.float32(1)
    return sp + 1


@numba.njit(cache=True, inline="always")
def popped(one, first, second, tfar):
    """A popped lane's interval ``(tnear, tfar)`` from its stack words: the far interval
    ``[first, second]`` (two values); ``one``: :func:`push_one`'s value ``first`` and keep flag
    ``second``, ``[value, tfar]`` if it keeps, else ``[tfar, value]`` (``tfar``: the lane's, as
    the near subtree left it). The RTL's ``TravSubunit._popped``."""
    if not one:
        return first, second
    if second != np.float32(0):
        return first, tfar
    return tfar, first


@numba.njit(cache=True, inline="always", error_model="numpy")
def pop(sp, terminated, tnear, tfar, s_node, s_mask, s_near, s_far, n, one):
    """Pop entries until one has a live ray; its lanes take their :func:`popped` intervals.
    Returns (sp, node, mask); mask 0 = packet done."""
    while sp > 0:
        sp -= 1
        mask = s_mask[sp] & ~terminated
        if mask:
            for l in range(n):
                lo, hi = popped(one, s_near[sp, l], s_far[sp, l], tfar[l])
                on = lane_on(mask, l)
                tnear[l] = lo if on else tnear[l]
                tfar[l] = hi if on else tfar[l]
            return sp, s_node[sp], mask
    return 0, np.int64(0), np.uint64(0)


# ---- the traversal unit's control: passes, the decide step, termination -----------------------

@numba.njit(cache=True, inline="always", error_model="numpy")
def start_packet(dirn, r0, n, tnear, tfar, octant):
    """Load a packet: per lane its direction octant (sign bits x | y << 1 | z << 2) into
    ``octant``; returns the live mask (rays whose clipped interval is non-empty)."""
    live = np.uint64(0)
    for l in range(n):
        octant[l] = (sign_bit(dirn[r0 + l, 0]) | (sign_bit(dirn[r0 + l, 1]) << 1) |
                     (sign_bit(dirn[r0 + l, 2]) << 2))
        if tnear[l] <= tfar[l]:
            live |= np.uint64(1) << np.uint64(l)
    return live


@numba.njit(cache=True, inline="always")
def pass_mask(oc, octant, live, n):
    """The lanes of an octant pass: live rays whose direction lies in octant ``oc``."""
    mask = np.uint64(0)
    for l in range(n):
        if octant[l] == oc and (live & (np.uint64(1) << np.uint64(l))):
            mask |= np.uint64(1) << np.uint64(l)
    return mask


@numba.njit(cache=True, inline="always")
def pass_masks(octant, live, n, masks):
    """:func:`pass_mask` of every octant at once into ``masks`` (8,)."""
    for oc in range(8):
        masks[oc] = np.uint64(0)
    for l in range(n):
        bit = np.uint64(1) << np.uint64(l)
        if live & bit:
            masks[octant[l]] |= bit


@numba.njit(cache=True, inline="always", error_model="numpy")
def decide(oc, axis, child, mnear, mfar, sp, dist, tnear, tfar, s_node, s_mask, s_near, s_far,
           n, one):
    """The decide engine, after every sub-unit classified its lanes at an inner node.

    The near child is ``child + neg`` (``neg``: the pass's direction sign on ``axis``), the
    far child the other one. Both needed: push the far child (rays of ``mfar``) and go near;
    near only: go near; else go far (an empty ``mfar`` ends the pass). ``one``: the stack
    keeps one value a lane (:func:`push_one`; the stack's arrays ``s_near``, ``s_far`` hold
    the values and the keep flags). Returns ``(node, mask, sp, pushed)``."""
    neg = (oc >> axis) & 1
    near = child + neg
    far = child + 1 - neg
    if mnear and mfar:
        if one:
            sp = push_one(sp, far, mfar, mnear, dist, tnear, tfar, s_node, s_mask, s_near,
                          s_far, n)
            clip_far(mfar & ~mnear, dist, tnear, n)
        else:
            sp = push(sp, far, mfar, dist, tnear, tfar, s_node, s_mask, s_near, s_far, n)
        clip_near(mnear, dist, tfar, n)
        return near, mnear, sp, True
    if mnear:
        clip_near(mnear, dist, tfar, n)
        return near, mnear, sp, False
    clip_far(mfar, dist, tnear, n)
    return far, mfar, sp, False


@numba.njit(cache=True, inline="always", error_model="numpy")
def terminate(mask, terminated, b_tri, anyhit, r0, best, tfar):
    """The result engine, after a leaf's triangles: a lane of ``mask`` ends if it has a hit
    and either is an any-hit (shadow) ray or its closest hit lies in this cell
    (``t <= tfar``). Returns the new terminated mask."""
    m = mask
    while m:
        l = lowest_lane(m)
        m &= m - np.uint64(1)
        if b_tri[l] >= 0 and (anyhit[r0 + l] or best[l] <= tfar[l]):
            terminated |= np.uint64(1) << np.uint64(l)
    return terminated
