"""Intersection unit (golden model): watertight ray-triangle test of Woop, Benthin, Wald (2013).

One int-op = one active ray against one triangle (288 bits = 9 binary32 from memory). The
order of operations below is the hardware's; every operation is rounded to the format (E, M).
No double-precision fallback: a zero edge function counts as "on the edge", so rays through
shared edges and vertices hit at least one triangle (watertight) and may hit both.

Hardware: one ray per cycle, fully pipelined; the triangle is fetched once per packet.
"""
import numba
import numpy as np

from .events import EV_INT, record
from .fp import fadd, fdiv, fmul, fsub
from .intersection_projection import intersect_projection
from .lanes import highest_lane, lowest_lane, popcount
from .layout import TRI_WORDS

_ONE = np.float32(1.0)
_ZERO = np.float32(0.0)


@numba.njit(cache=True, inline="always")
def pick(v0, v1, v2, k):
    if k == 0:
        return v0
    if k == 1:
        return v1
    return v2


@numba.njit(cache=True, inline="always")
def shear(p0, p1, p2, kx, ky, kz, sx, sy, E, M):
    """Vertex (relative to the origin) into the ray's sheared space: (x, y, z_unscaled)."""
    px = pick(p0, p1, p2, kx)
    py = pick(p0, p1, p2, ky)
    pz = pick(p0, p1, p2, kz)
    return fsub(px, fmul(sx, pz, E, M), E, M), fsub(py, fmul(sy, pz, E, M), E, M), pz


@numba.njit(cache=True, inline="always")
def intersect(tri, ox, oy, oz, kx, ky, kz, sx, sy, sz, E, M):
    """Test one ray against one triangle.

    tri: 9 float32 (A, B, C); (ox, oy, oz): origin; (kx, ky, kz), (sx, sy, sz): the ray's shear
    constants. Returns (hit, t, u, v); hit means the edge test passed and det != 0 (the caller
    applies the t-range test ``0 < t < t_best``).
    """
    ax, ay, az = shear(fsub(tri[0], ox, E, M), fsub(tri[1], oy, E, M),
                       fsub(tri[2], oz, E, M), kx, ky, kz, sx, sy, E, M)
    bx, by, bz = shear(fsub(tri[3], ox, E, M), fsub(tri[4], oy, E, M),
                       fsub(tri[5], oz, E, M), kx, ky, kz, sx, sy, E, M)
    cx, cy, cz = shear(fsub(tri[6], ox, E, M), fsub(tri[7], oy, E, M),
                       fsub(tri[8], oz, E, M), kx, ky, kz, sx, sy, E, M)
    eu = fsub(fmul(cx, by, E, M), fmul(cy, bx, E, M), E, M)
    ev = fsub(fmul(ax, cy, E, M), fmul(ay, cx, E, M), E, M)
    ew = fsub(fmul(bx, ay, E, M), fmul(by, ax, E, M), E, M)
    if (eu < _ZERO or ev < _ZERO or ew < _ZERO) and (eu > _ZERO or ev > _ZERO or ew > _ZERO):
        return False, _ZERO, _ZERO, _ZERO
    det = fadd(fadd(eu, ev, E, M), ew, E, M)
    if det == _ZERO:
        return False, _ZERO, _ZERO, _ZERO
    tz = fadd(fadd(fmul(eu, fmul(sz, az, E, M), E, M), fmul(ev, fmul(sz, bz, E, M), E, M), E, M),
              fmul(ew, fmul(sz, cz, E, M), E, M), E, M)
    rcp = fdiv(_ONE, det, E, M)
    return True, fmul(tz, rcp, E, M), fmul(ev, rcp, E, M), fmul(ew, rcp, E, M)


_FLT_MIN = np.float32(2.0 ** -126)
VECTOR_LANES = 8        # test_triangle tests the lanes together from this many active lanes


@numba.njit(cache=True, inline="always")
def _tiny(r):
    """A binary32 result IEEE may have got wrong for the hardware: denormal or exactly the
    smallest normal (the band where flush-after-rounding and gradual underflow differ)."""
    return (r != _ZERO) & (abs(r) <= _FLT_MIN)


@numba.njit(cache=True, error_model="numpy")
def _intersect_exact32(tri, ox, oy, oz, kx, ky, kz, sx, sy, sz):
    return intersect(tri, ox, oy, oz, kx, ky, kz, sx, sy, sz, 8, 23)


@numba.njit(cache=True, inline="always", error_model="numpy")
def _edges32(A0, A1, A2, B0, B1, B2, C0, C1, C2, ox, oy, oz, kx, ky, kz, sx, sy):
    """The edge functions of :func:`intersect` in plain IEEE float32: ``az``, ``bz``, ``cz``,
    ``eu``, ``ev``, ``ew`` and ``bad`` (a value lies where IEEE and the hardware can differ,
    see ``_tiny``)."""
    a0 = A0 - ox
    a1 = A1 - oy
    a2 = A2 - oz
    b0 = B0 - ox
    b1 = B1 - oy
    b2 = B2 - oz
    c0 = C0 - ox
    c1 = C1 - oy
    c2 = C2 - oz
    return _sheared_edges32(pick(a0, a1, a2, kx), pick(a0, a1, a2, ky), pick(a0, a1, a2, kz),
                            pick(b0, b1, b2, kx), pick(b0, b1, b2, ky), pick(b0, b1, b2, kz),
                            pick(c0, c1, c2, kx), pick(c0, c1, c2, ky), pick(c0, c1, c2, kz),
                            sx, sy)


@numba.njit(cache=True, inline="always", error_model="numpy")
def _sheared_edges32(a0, a1, az, b0, b1, bz, c0, c1, cz, sx, sy):
    """:func:`_edges32` from the vertices' differences to the origin already in the ray's
    axes (x, y, z = kx, ky, kz); ``bad`` covers all nine differences, so it does not matter
    in which order they were picked."""
    pax = sx * az
    pay = sy * az
    pbx = sx * bz
    pby = sy * bz
    pcx = sx * cz
    pcy = sy * cz
    ax = a0 - pax
    ay = a1 - pay
    bx = b0 - pbx
    by = b1 - pby
    cx = c0 - pcx
    cy = c1 - pcy
    p0 = cx * by
    p1 = cy * bx
    p2 = ax * cy
    p3 = ay * cx
    p4 = bx * ay
    p5 = by * ax
    eu = p0 - p1
    ev = p2 - p3
    ew = p4 - p5
    bad = (_tiny(a0) | _tiny(a1) | _tiny(az) | _tiny(b0) | _tiny(b1) | _tiny(bz) | _tiny(c0)
           | _tiny(c1) | _tiny(cz) | _tiny(pax) | _tiny(pay) | _tiny(pbx) | _tiny(pby)
           | _tiny(pcx) | _tiny(pcy) | _tiny(ax) | _tiny(ay) | _tiny(bx) | _tiny(by) | _tiny(cx)
           | _tiny(cy) | _tiny(p0) | _tiny(p1) | _tiny(p2) | _tiny(p3) | _tiny(p4) | _tiny(p5)
           | _tiny(eu) | _tiny(ev) | _tiny(ew))
    return az, bz, cz, eu, ev, ew, bad


@numba.njit(cache=True, inline="always", error_model="numpy")
def _hit32(az, bz, cz, eu, ev, ew, sz):
    """The rest of :func:`intersect` in plain IEEE float32: ``s0``, ``det``, ``t``, ``u``,
    ``v`` and ``bad`` (as :func:`_edges32`; meaningless where ``det`` is 0)."""
    s0 = eu + ev
    det = s0 + ew
    qa = sz * az
    qb = sz * bz
    qc = sz * cz
    ta = eu * qa
    tb = ev * qb
    tc = ew * qc
    t0 = ta + tb
    tz = t0 + tc
    rcp = _ONE / det
    t = tz * rcp
    u = ev * rcp
    v = ew * rcp
    bad = (_tiny(s0) | _tiny(det) | _tiny(qa) | _tiny(qb) | _tiny(qc) | _tiny(ta) | _tiny(tb)
           | _tiny(tc) | _tiny(t0) | _tiny(tz) | _tiny(rcp) | _tiny(t) | _tiny(u) | _tiny(v))
    return s0, det, t, u, v, bad


@numba.njit(cache=True, inline="always", error_model="numpy")
def intersect32(tri, ox, oy, oz, kx, ky, kz, sx, sy, sz):
    """:func:`intersect` for binary32, faster: the same operations in plain IEEE float32 with
    no per-operation check; if any result lies where IEEE and the hardware can differ (see
    ``_tiny``) the test is redone with the exact operations. Bit-identical to ``intersect``
    (tests compare the two)."""
    az, bz, cz, eu, ev, ew, bad = _edges32(tri[0], tri[1], tri[2], tri[3], tri[4], tri[5],
                                           tri[6], tri[7], tri[8], ox, oy, oz, kx, ky, kz,
                                           sx, sy)
    if bad:
        return _intersect_exact32(tri, ox, oy, oz, kx, ky, kz, sx, sy, sz)
    if (eu < _ZERO or ev < _ZERO or ew < _ZERO) and (eu > _ZERO or ev > _ZERO or ew > _ZERO):
        return False, _ZERO, _ZERO, _ZERO
    s0, det, t, u, v, bad = _hit32(az, bz, cz, eu, ev, ew, sz)
    if det == _ZERO:
        if _tiny(s0):
            return _intersect_exact32(tri, ox, oy, oz, kx, ky, kz, sx, sy, sz)
        return False, _ZERO, _ZERO, _ZERO
    if bad:
        return _intersect_exact32(tri, ox, oy, oz, kx, ky, kz, sx, sy, sz)
    return True, t, u, v


@numba.njit(cache=True, inline="always", error_model="numpy")
def intersect32_lanes(tri, l0, l1, kx, ky, kz, o_t, s_t, st, ht, hu, hv):
    """:func:`intersect32` for lanes ``l0 .. l1-1`` that share the shear axes ``kx``, ``ky``,
    ``kz``, at once, in a loop the compiler turns into vector instructions (every lane computes
    every step; a lane's outcome is selected at the end). ``o_t``, ``s_t``: the packet's
    origins and shear constants by component, (3, lanes). With the axes fixed the vertices'
    components are picked once: ``A[kx] - o[kx]`` is :func:`intersect32`'s ``pick(a0, a1, a2,
    kx)``, the same values (and the same underflow checks on all nine differences). Writes per
    lane ``st`` = 0 (no hit), 1 (hit at ``ht``, ``hu``, ``hv``) or 2 (a value in the band where
    IEEE and the hardware can differ: redo the lane with the exact operations) -- the outcomes
    of :func:`intersect32`'s branches."""
    Ax, Ay, Az = tri[kx], tri[ky], tri[kz]
    Bx, By, Bz = tri[3 + kx], tri[3 + ky], tri[3 + kz]
    Cx, Cy, Cz = tri[6 + kx], tri[6 + ky], tri[6 + kz]
    ox, oy, oz = o_t[kx], o_t[ky], o_t[kz]
    sxs, sys_, szs = s_t[0], s_t[1], s_t[2]
    for l in range(l0, l1):
        az, bz, cz, eu, ev, ew, bad = _sheared_edges32(
            Ax - ox[l], Ay - oy[l], Az - oz[l], Bx - ox[l], By - oy[l], Bz - oz[l],
            Cx - ox[l], Cy - oy[l], Cz - oz[l], sxs[l], sys_[l])
        edge_miss = (((eu < _ZERO) | (ev < _ZERO) | (ew < _ZERO))
                     & ((eu > _ZERO) | (ev > _ZERO) | (ew > _ZERO)))
        s0, det, t, u, v, bad2 = _hit32(az, bz, cz, eu, ev, ew, szs[l])
        r = np.int8(2) if bad2 else np.int8(1)
        r = (np.int8(2) if _tiny(s0) else np.int8(0)) if det == _ZERO else r
        r = np.int8(0) if edge_miss else r
        st[l] = np.int8(2) if bad else r
        ht[l] = t
        hu[l] = u
        hv[l] = v


@numba.njit(cache=True, inline="always")
def shared_axes(mask, lk):
    """The shear axes every lane of ``mask`` shares, as ``kx | ky << 2 | kz << 4``, or -1 when
    they differ (``lk``: the packet's shear axes per lane, (lanes, 3))."""
    code = np.int64(-1)
    m = mask
    while m:
        l = lowest_lane(m)
        m &= m - np.uint64(1)
        c = lk[l, 0] | (lk[l, 1] << 2) | (lk[l, 2] << 4)
        if code < 0:
            code = c
        elif c != code:
            return np.int64(-1)
    return code


@numba.njit(cache=True, inline="always")
def fetch_triangle(mem, tri_base, i, out):
    """Read triangle ``i`` (5 words) into ``out`` (9 float32); returns its scene-order id."""
    base = tri_base + TRI_WORDS * i
    for w in range(TRI_WORDS):
        word = mem[base + w]
        lo = np.uint32(word & np.uint64(0xFFFFFFFF))
        hi = np.uint32(word >> np.uint64(32))
        out[2 * w] = np.uint32(lo).view(np.float32)
        if w < 4:
            out[2 * w + 1] = np.uint32(hi).view(np.float32)
        else:
            return np.int64(hi)
    return np.int64(-1)


@numba.njit(cache=True, inline="always", error_model="numpy")
def test_triangle(tri, sid, ti, mask, lo, lk, ls, best, b_tri, b_u, b_v, E, M, rec, rec_n, pid,
                  n, lanes, axes, tk=-1):
    """The intersection unit on one triangle: test every lane of ``mask`` in lane order (the
    issue stage), and keep the closest hit (best-hit update): a hit is accepted when
    ``0 < t < best``. ``lo``/``lk``/``ls`` are the packet's ray store (origin, shear axes and
    constants), ``best``/``b_tri``/``b_u``/``b_v`` its best-hit store (the triangle's index
    in memory, as the hardware knows it; ``sid``, the scene-order id, is only recorded).
    ``lanes``: the packet's ``n`` lanes' store by component and per-lane outcome arrays
    (:func:`intersect32_lanes`); ``axes``: the shear axes the mask's lanes share
    (:func:`shared_axes`) or -1. At binary32, with shared axes, at least ``VECTOR_LANES``
    lanes in the mask and no event log, the lanes are tested together first (the same
    results). ``tk`` >= 0 (``Config.int_test = "projection"``): ``tri`` is a projection record
    with axis ``tk`` and ``ls`` holds the lanes' directions
    (:func:`model.intersection_projection.intersect_projection`). Returns the int-ops done."""
    if (tk < 0 and E == 8 and M == 23 and rec.shape[0] == 0 and axes >= 0
            and popcount(mask) >= VECTOR_LANES):
        o_t, s_t, st, ht, hu, hv = lanes
        l0 = lowest_lane(mask)
        l1 = min(n, (highest_lane(mask) + 16) & ~15)
        intersect32_lanes(tri, l0 & ~15, l1, axes & 3, (axes >> 2) & 3, axes >> 4, o_t, s_t,
                          st, ht, hu, hv)
        ops = 0
        m = mask
        while m:
            l = lowest_lane(m)
            m &= m - np.uint64(1)
            ops += 1
            if st[l] == 2:
                hit, t, u, v = _intersect_exact32(tri, lo[l, 0], lo[l, 1], lo[l, 2], lk[l, 0],
                                                  lk[l, 1], lk[l, 2], ls[l, 0], ls[l, 1],
                                                  ls[l, 2])
            else:
                hit, t, u, v = st[l] == 1, ht[l], hu[l], hv[l]
            if hit and t > _ZERO and t < best[l]:
                best[l] = t
                b_tri[l] = ti
                b_u[l] = u
                b_v[l] = v
        return ops
    ops = 0
    m = mask
    while m:
        l = lowest_lane(m)
        m &= m - np.uint64(1)
        ops += 1
        if tk >= 0:
            hit, t, u, v = intersect_projection(tri, tk, lo[l, 0], lo[l, 1], lo[l, 2], ls[l, 0],
                                                ls[l, 1], ls[l, 2], E, M)
        elif E == 8 and M == 23:
            hit, t, u, v = intersect32(tri, lo[l, 0], lo[l, 1], lo[l, 2], lk[l, 0], lk[l, 1],
                                       lk[l, 2], ls[l, 0], ls[l, 1], ls[l, 2])
        else:
            hit, t, u, v = intersect(tri, lo[l, 0], lo[l, 1], lo[l, 2], lk[l, 0], lk[l, 1],
                                     lk[l, 2], ls[l, 0], ls[l, 1], ls[l, 2], E, M)
        accept = hit and t > _ZERO and t < best[l]
        if rec.shape[0]:
            record(rec, rec_n, EV_INT, pid, l, ti, np.int64(hit) | (np.int64(accept) << 1),
                   _bits(t), _bits(u), _bits(v))
        if accept:
            best[l] = t
            b_tri[l] = ti
            b_u[l] = u
            b_v[l] = v
    return ops


@numba.njit(cache=True, inline="always")
def _bits(x):
    return np.int64(np.float32(x).view(np.uint32))

