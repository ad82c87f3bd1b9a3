"""The RGS slave's secondary rays and colour (golden model), as compiled kernels.

Every operation is one of ``model/fp.py``'s scalar format operations, in the order of the RTL
(``rtl/rgs/secondary.py``: ``SecondaryPipe``, ``LightPipe``); the step names are the RTL's
signal names and ``docs/rgs.md``'s. ``model/shading.py`` runs these kernels.

The per-hit functions here (and in ``refract.py`` and ``texture.py``) are compiled on their own
and called, not inlined into the parallel kernels at numba's IR level as ``model/fp.py``'s
operations are: inlined, the refraction kernel alone took 258 s to compile (7 s now) at the
same run time. The trace kernels keep their IR inlining, which is 1.7x faster there.

Secondary rays from a hit (:func:`secondary`, the RTL's ``SecondaryPipe``): the ray's origin o
and direction d, the hit's t, u, v, the triangle's unit face normal n_f and vertex normals
n_A, n_B, n_C (memory image), ``eps`` (a register):

* ``hit``: p[a] = o[a] + t*d[a];
* ``face``: g = -n_f if dot(n_f, d) > 0 else n_f (the face normal turned toward the ray);
* ``dir_norm``: w = d * (1 / sqrt(dot(d, d))) (the unit incoming direction);
* ``offset``: p0[a] = (p[a] + eps*g[a]) - eps*w[a] (every secondary ray's origin: off the
  surface and back along the ray);
* ``normal``: b = (1 - u) - v; s[a] = (b*n_A[a] + u*n_B[a]) + v*n_C[a];
  n = s * (1 / sqrt(dot(s, s))), or g where dot(s, s) = 0; turned to g's side:
  n = -n if dot(n, g) < 0;
* ``reflect``: k = 2 * dot(d, n); r[a] = d[a] - k*n[a];

with dot(a, b) = (a0*b0 + a1*b1) + a2*b2. Negation flips the sign bit (a NaN stays NaN).
Shadow ray toward one light (:func:`shadow_dir`): direction l - p0 (point light at l, tmax 1)
or the light's reversed direction (parallel light, tmax inf; the host negates it); it is cast
only if ``dot(g, direction) > 0`` (the light faces the surface).

Colour (:func:`light_colour`, :func:`hit_colour`, the RTL's ``LightPipe``): a hit of an eye or
reflection ray of weight wt adds its ambient term (kd * amb) * wt; its reflection ray gets the
weight wr = wt * kr and carries bg * wr, added if it leaves the scene; its shadow ray toward
light l carries the Phong term ((kd * ndl) + (ks * rdl ** shin)) * (lc * wt), with ndl and rdl
the cosines of the light direction with the shading normal and with the reflected direction
(each clamped at +0), added if it reaches the light. Each contribution becomes a 24-bit
fixed-point number (:func:`to_fixed`: floor(x * 2**16), saturating); a pixel is their
integer sum, the same in any order.

Drivers (compiled, hits in parallel tasks): :func:`secondary_rays` and :func:`shadow_rays`
make the secondary rays of an array of hits; :func:`light_colours` and :func:`hit_colours`
their colour contributions. The per-hit arithmetic is written once, on scalars
(``secondary_one``, ``shadow_one``, ``light_one``, ``hit_one``); the array functions and
``slave.shade_batch`` call it.
"""
from __future__ import annotations

import numba
import numpy as np

from ..fp import fadd, fdiv, fmax, fmul, flush_in, fsqrt, fsub
from .common import _ONE, _ZERO, CHUNK

__all__ = ["dot3", "secondary_one", "secondary", "secondary_at", "secondary_rays",
           "shadow_one", "shadow_dir", "shadow_rays", "FIX_FRAC", "FIX_BITS", "FIX_MAX",
           "to_fixed", "spec_pow", "light_one", "light_colour", "hit_one", "hit_colour",
           "light_colours", "hit_colours", "to_fixed_array"]

_TWO = np.float32(2.0)


@numba.njit(cache=True, error_model="numpy")
def dot3(a0, a1, a2, b0, b1, b2, E, M):
    """``dot``: (a0*b0 + a1*b1) + a2*b2, every operation rounded."""
    return fadd(fadd(fmul(a0, b0, E, M), fmul(a1, b1, E, M), E, M), fmul(a2, b2, E, M), E, M)


@numba.njit(cache=True, error_model="numpy")
def _unit(x0, x1, x2, E, M):
    """x * (1 / sqrt(dot(x, x))) per component, and dot(x, x)."""
    q = dot3(x0, x1, x2, x0, x1, x2, E, M)
    r = fdiv(_ONE, fsqrt(q, E, M), E, M)
    return fmul(x0, r, E, M), fmul(x1, r, E, M), fmul(x2, r, E, M), q


@numba.njit(cache=True, error_model="numpy")
def secondary_one(o0, o1, o2, d0, d1, d2, t, u, v, f0, f1, f2, a0, a1, a2, b0, b1, b2,
                  c0, c1, c2, eps, E, M):
    """The module docstring's steps for one hit, on scalars: origin ``o``, direction ``d``,
    face normal ``f``, vertex normals ``a`` (A), ``b`` (B), ``c`` (C). Returns the 12 values
    ``p0``, ``g``, ``n``, ``r`` (3 each, in that order)."""
    # face
    flip = dot3(f0, f1, f2, d0, d1, d2, E, M) > _ZERO
    g0 = -f0 if flip else f0
    g1 = -f1 if flip else f1
    g2 = -f2 if flip else f2
    # dir_norm
    w0, w1, w2, _ = _unit(d0, d1, d2, E, M)
    # hit, offset
    p00 = fsub(fadd(fadd(o0, fmul(t, d0, E, M), E, M), fmul(eps, g0, E, M), E, M),
               fmul(eps, w0, E, M), E, M)
    p01 = fsub(fadd(fadd(o1, fmul(t, d1, E, M), E, M), fmul(eps, g1, E, M), E, M),
               fmul(eps, w1, E, M), E, M)
    p02 = fsub(fadd(fadd(o2, fmul(t, d2, E, M), E, M), fmul(eps, g2, E, M), E, M),
               fmul(eps, w2, E, M), E, M)
    # normal
    bb = fsub(fsub(_ONE, u, E, M), v, E, M)
    s0 = fadd(fadd(fmul(bb, a0, E, M), fmul(u, b0, E, M), E, M), fmul(v, c0, E, M), E, M)
    s1 = fadd(fadd(fmul(bb, a1, E, M), fmul(u, b1, E, M), E, M), fmul(v, c1, E, M), E, M)
    s2 = fadd(fadd(fmul(bb, a2, E, M), fmul(u, b2, E, M), E, M), fmul(v, c2, E, M), E, M)
    n0, n1, n2, q = _unit(s0, s1, s2, E, M)
    if q == _ZERO:
        n0, n1, n2 = g0, g1, g2
    if dot3(n0, n1, n2, g0, g1, g2, E, M) < _ZERO:
        n0, n1, n2 = -n0, -n1, -n2
    # reflect
    k = fmul(_TWO, dot3(d0, d1, d2, n0, n1, n2, E, M), E, M)
    r0 = fsub(d0, fmul(k, n0, E, M), E, M)
    r1 = fsub(d1, fmul(k, n1, E, M), E, M)
    r2 = fsub(d2, fmul(k, n2, E, M), E, M)
    return p00, p01, p02, g0, g1, g2, n0, n1, n2, r0, r1, r2


@numba.njit(cache=True, error_model="numpy")
def secondary(o, d, t, u, v, nf, nv, eps, E, M):
    """The module docstring's steps for one hit: ``o``, ``d``, ``nf`` (3,), ``nv`` (3, 3) vertex
    normals A, B, C. Returns (p0, g, n, r), each a (3,) float32 array."""
    x = secondary_one(o[0], o[1], o[2], d[0], d[1], d[2], t, u, v, nf[0], nf[1], nf[2],
                      nv[0, 0], nv[0, 1], nv[0, 2], nv[1, 0], nv[1, 1], nv[1, 2],
                      nv[2, 0], nv[2, 1], nv[2, 2], eps, E, M)
    p0 = np.empty(3, np.float32)
    g = np.empty(3, np.float32)
    n = np.empty(3, np.float32)
    r = np.empty(3, np.float32)
    p0[0], p0[1], p0[2], g[0], g[1], g[2], n[0], n[1], n[2], r[0], r[1], r[2] = x
    return p0, g, n, r


@numba.njit(cache=True, error_model="numpy")
def secondary_at(org, dirn, ray, t, u, v, nf, nv, k, eps, E, M):
    """:func:`secondary_one` of ray ``ray`` of ``org``/``dirn`` on triangle row ``k`` of
    ``nf``/``nv``, every operand read as the hardware reads format words (``eps`` already)."""
    return secondary_one(
        flush_in(org[ray, 0], E), flush_in(org[ray, 1], E), flush_in(org[ray, 2], E),
        flush_in(dirn[ray, 0], E), flush_in(dirn[ray, 1], E), flush_in(dirn[ray, 2], E),
        flush_in(t, E), flush_in(u, E), flush_in(v, E),
        flush_in(nf[k, 0], E), flush_in(nf[k, 1], E), flush_in(nf[k, 2], E),
        flush_in(nv[k, 0, 0], E), flush_in(nv[k, 0, 1], E), flush_in(nv[k, 0, 2], E),
        flush_in(nv[k, 1, 0], E), flush_in(nv[k, 1, 1], E), flush_in(nv[k, 1, 2], E),
        flush_in(nv[k, 2, 0], E), flush_in(nv[k, 2, 1], E), flush_in(nv[k, 2, 2], E),
        eps, E, M)


@numba.njit(cache=True, parallel=True, error_model="numpy")
def secondary_rays(org, dirn, rows, t, u, v, tri, nf, nv, eps, E, M):
    """:func:`secondary` for every hit, in parallel: hit i is ray ``rows[i]`` of ``org``,
    ``dirn`` (R, 3) at ``t[i]``, ``u[i]``, ``v[i]`` on triangle ``tri[i]``, a row of the face
    normals ``nf`` (T, 3) and vertex normals ``nv`` (T, 3, 3); operands read as the hardware
    reads format words. Returns ``p0``, ``g``, ``n``, ``r``, each (N, 3)."""
    N = rows.shape[0]
    P0 = np.empty((N, 3), np.float32)
    G = np.empty((N, 3), np.float32)
    NS = np.empty((N, 3), np.float32)
    R = np.empty((N, 3), np.float32)
    e = flush_in(eps, E)
    for ch in numba.prange((N + CHUNK - 1) // CHUNK):
        for i in range(ch * CHUNK, min(N, ch * CHUNK + CHUNK)):
            (P0[i, 0], P0[i, 1], P0[i, 2], G[i, 0], G[i, 1], G[i, 2], NS[i, 0], NS[i, 1],
             NS[i, 2], R[i, 0], R[i, 1], R[i, 2]) = secondary_at(org, dirn, rows[i], t[i], u[i],
                                                                 v[i], nf, nv, tri[i], e, E, M)
    return P0, G, NS, R


@numba.njit(cache=True, error_model="numpy")
def shadow_one(p0, p1, p2, g0, g1, g2, l0, l1, l2, point, E, M):
    """:func:`shadow_dir` on scalars: (d0, d1, d2, cast)."""
    if point:
        d0 = fsub(l0, p0, E, M)
        d1 = fsub(l1, p1, E, M)
        d2 = fsub(l2, p2, E, M)
    else:
        d0, d1, d2 = l0, l1, l2
    return d0, d1, d2, dot3(g0, g1, g2, d0, d1, d2, E, M) > _ZERO


@numba.njit(cache=True, error_model="numpy")
def shadow_dir(p0, g, light, point, E, M):
    """The shadow ray toward one light from origin ``p0`` with oriented face normal ``g``:
    (direction (3,), cast). ``light``: the point light's position (``point``) or the parallel
    light's reversed direction."""
    ds = np.empty(3, np.float32)
    ds[0], ds[1], ds[2], cast = shadow_one(p0[0], p0[1], p0[2], g[0], g[1], g[2], light[0],
                                           light[1], light[2], point, E, M)
    return ds, cast


@numba.njit(cache=True, parallel=True, error_model="numpy")
def shadow_rays(p0, g, light, point, E, M):
    """:func:`shadow_dir` for every row of ``p0``, ``g`` (N, 3), in parallel: directions
    (N, 3) and the facing test (N,) bool."""
    N = p0.shape[0]
    D = np.empty((N, 3), np.float32)
    cast = np.empty(N, np.bool_)
    lf = np.empty(3, np.float32)
    for a in range(3):
        lf[a] = flush_in(light[a], E)
    for ch in numba.prange((N + CHUNK - 1) // CHUNK):
        for i in range(ch * CHUNK, min(N, ch * CHUNK + CHUNK)):
            D[i, 0], D[i, 1], D[i, 2], cast[i] = shadow_one(
                p0[i, 0], p0[i, 1], p0[i, 2], g[i, 0], g[i, 1], g[i, 2], lf[0], lf[1], lf[2],
                point, E, M)
    return D, cast


# ---------------------------------------------------------------------------------------------
# colour
# ---------------------------------------------------------------------------------------------

FIX_FRAC = 16            # a colour contribution as an unsigned fixed-point number: 16 fraction
FIX_BITS = 24            # bits, 24 bits in all (0 .. 256 - 2**-16)
FIX_MAX = (1 << FIX_BITS) - 1


@numba.njit(cache=True, error_model="numpy")
def to_fixed(x, E):
    """``fixed``: a format value as a colour contribution: floor(x * 2**FIX_FRAC), 0 for a
    NaN, a zero (denormals read as zero) or a negative value, FIX_MAX from 2**8 up (+inf)."""
    x = flush_in(x, E)
    if not x > _ZERO:
        return np.int64(0)
    v = np.float64(x) * np.float64(1 << FIX_FRAC)
    if v >= np.float64(FIX_MAX + 1):
        return np.int64(FIX_MAX)
    return np.int64(np.floor(v))


@numba.njit(cache=True, error_model="numpy")
def spec_pow(x, k, E, M):
    """``spec``: x ** k for the 10-bit exponent k, by squaring: acc = 1, p = x; for bit
    i = 0..9: acc = acc * p if bit i of k is set; p = p * p (before bit i + 1)."""
    acc = _ONE
    p = x
    for i in range(10):
        if (k >> i) & 1:
            acc = fmul(acc, p, E, M)
        if i < 9:
            p = fmul(p, p, E, M)
    return acc


@numba.njit(cache=True, error_model="numpy")
def light_one(l0, l1, l2, n0, n1, n2, r0, r1, r2, kd0, kd1, kd2, ks0, ks1, ks2, shin,
              lc0, lc1, lc2, wt, E, M):
    """:func:`light_colour` on scalars (``l`` the shadow ray's direction): its 3 channels."""
    il = fdiv(_ONE, fsqrt(dot3(l0, l1, l2, l0, l1, l2, E, M), E, M), E, M)
    ir = fdiv(_ONE, fsqrt(dot3(r0, r1, r2, r0, r1, r2, E, M), E, M), E, M)
    ndl = fmax(fmul(dot3(n0, n1, n2, l0, l1, l2, E, M), il, E, M), _ZERO)
    rdl = fmax(fmul(fmul(dot3(r0, r1, r2, l0, l1, l2, E, M), il, E, M), ir, E, M), _ZERO)
    spec = spec_pow(rdl, shin, E, M)
    c0 = fmul(fadd(fmul(kd0, ndl, E, M), fmul(ks0, spec, E, M), E, M), fmul(lc0, wt, E, M),
              E, M)
    c1 = fmul(fadd(fmul(kd1, ndl, E, M), fmul(ks1, spec, E, M), E, M), fmul(lc1, wt, E, M),
              E, M)
    c2 = fmul(fadd(fmul(kd2, ndl, E, M), fmul(ks2, spec, E, M), E, M), fmul(lc2, wt, E, M),
              E, M)
    return c0, c1, c2


@numba.njit(cache=True, error_model="numpy")
def light_colour(ld, n, r, kd, ks, shin, lc, wt, E, M):
    """The light one shadow ray brings if it reaches its light (Phong): ``ld`` the shadow
    ray's direction (not unit for a point light), ``n`` the unit shading normal, ``r`` the
    reflected direction, ``kd``, ``ks``, ``shin`` the material's record constants, ``lc`` the
    light's colour, ``wt`` the hit ray's weight. Steps (the RTL's ``LightPipe``):

    * ``il`` = 1 / sqrt(dot(ld, ld)), ``ir`` = 1 / sqrt(dot(r, r));
    * ``ndl`` = max(dot(n, ld) * il, +0); ``rdl`` = max((dot(r, ld) * il) * ir, +0)
      (max with +0 turns a NaN into +0);
    * ``spec`` = :func:`spec_pow` (rdl, shin);
    * per channel c: ((kd[c] * ndl) + (ks[c] * spec)) * (lc[c] * wt).

    Returns (3,) float32."""
    out = np.empty(3, np.float32)
    out[0], out[1], out[2] = light_one(ld[0], ld[1], ld[2], n[0], n[1], n[2], r[0], r[1], r[2],
                                       kd[0], kd[1], kd[2], ks[0], ks[1], ks[2], shin,
                                       lc[0], lc[1], lc[2], wt, E, M)
    return out


@numba.njit(cache=True, error_model="numpy")
def hit_one(kd0, kd1, kd2, kr, amb, bg0, bg1, bg2, wt, E, M):
    """:func:`hit_colour` on scalars: (ambient 3 channels, wr, miss 3 channels)."""
    wr = fmul(wt, kr, E, M)
    return (fmul(fmul(kd0, amb, E, M), wt, E, M), fmul(fmul(kd1, amb, E, M), wt, E, M),
            fmul(fmul(kd2, amb, E, M), wt, E, M), wr, fmul(bg0, wr, E, M),
            fmul(bg1, wr, E, M), fmul(bg2, wr, E, M))


@numba.njit(cache=True, error_model="numpy")
def hit_colour(kd, kr, amb, bg, wt, E, M):
    """What a hit of an eye or reflection ray of weight ``wt`` adds by itself, and what its
    reflection ray carries: ``ambient`` (kd[c] * amb) * wt; ``wr`` = wt * kr (the reflection
    ray's weight); ``miss`` = bg[c] * wr (its colour if it leaves the scene). Returns
    (ambient (3,), wr, miss (3,))."""
    amb_c = np.empty(3, np.float32)
    miss = np.empty(3, np.float32)
    amb_c[0], amb_c[1], amb_c[2], wr, miss[0], miss[1], miss[2] = hit_one(
        kd[0], kd[1], kd[2], kr, amb, bg[0], bg[1], bg[2], wt, E, M)
    return amb_c, wr, miss


@numba.njit(cache=True, parallel=True, error_model="numpy")
def light_colours(ld, n, r, kd, ks, shin, lc, wt, E, M):
    """:func:`light_colour` then :func:`to_fixed` for every row (``ld``, ``n``, ``r``, ``kd``,
    ``ks`` (N, 3), ``shin``, ``wt`` (N,); ``lc`` (N, 3) the light colour of each row), in
    parallel: (N, 3) int64 contributions."""
    N = ld.shape[0]
    out = np.empty((N, 3), np.int64)
    for ch in numba.prange((N + CHUNK - 1) // CHUNK):
        for i in range(ch * CHUNK, min(N, ch * CHUNK + CHUNK)):
            c0, c1, c2 = light_one(
                flush_in(ld[i, 0], E), flush_in(ld[i, 1], E), flush_in(ld[i, 2], E),
                flush_in(n[i, 0], E), flush_in(n[i, 1], E), flush_in(n[i, 2], E),
                flush_in(r[i, 0], E), flush_in(r[i, 1], E), flush_in(r[i, 2], E),
                flush_in(kd[i, 0], E), flush_in(kd[i, 1], E), flush_in(kd[i, 2], E),
                flush_in(ks[i, 0], E), flush_in(ks[i, 1], E), flush_in(ks[i, 2], E), shin[i],
                flush_in(lc[i, 0], E), flush_in(lc[i, 1], E), flush_in(lc[i, 2], E),
                flush_in(wt[i], E), E, M)
            out[i, 0] = to_fixed(c0, E)
            out[i, 1] = to_fixed(c1, E)
            out[i, 2] = to_fixed(c2, E)
    return out


@numba.njit(cache=True, parallel=True, error_model="numpy")
def hit_colours(kd, kr, amb, bg, wt, E, M):
    """:func:`hit_colour` for every row (``kd`` (N, 3), ``kr``, ``wt`` (N,); ``amb`` a format
    value, ``bg`` (3,)), in parallel: ambient (N, 3) int64 (fixed point), wr (N,) float32,
    miss (N, 3) int64 (fixed point)."""
    N = kd.shape[0]
    amb_o = np.empty((N, 3), np.int64)
    miss_o = np.empty((N, 3), np.int64)
    wr_o = np.empty(N, np.float32)
    b0, b1, b2 = flush_in(bg[0], E), flush_in(bg[1], E), flush_in(bg[2], E)
    am = flush_in(amb, E)
    for ch in numba.prange((N + CHUNK - 1) // CHUNK):
        for i in range(ch * CHUNK, min(N, ch * CHUNK + CHUNK)):
            a0, a1, a2, wr, m0, m1, m2 = hit_one(
                flush_in(kd[i, 0], E), flush_in(kd[i, 1], E), flush_in(kd[i, 2], E),
                flush_in(kr[i], E), am, b0, b1, b2, flush_in(wt[i], E), E, M)
            wr_o[i] = wr
            amb_o[i, 0] = to_fixed(a0, E)
            amb_o[i, 1] = to_fixed(a1, E)
            amb_o[i, 2] = to_fixed(a2, E)
            miss_o[i, 0] = to_fixed(m0, E)
            miss_o[i, 1] = to_fixed(m1, E)
            miss_o[i, 2] = to_fixed(m2, E)
    return amb_o, wr_o, miss_o


@numba.njit(cache=True, error_model="numpy")
def to_fixed_array(x, E):
    """:func:`to_fixed` of every element of the 1-D float32 array ``x`` (int64)."""
    out = np.empty(x.shape[0], np.int64)
    for i in range(x.shape[0]):
        out[i] = to_fixed(x[i], E)
    return out
