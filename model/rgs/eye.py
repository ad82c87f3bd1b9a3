"""The RGS slave's ray generation (golden model): eye rays and ray setup as compiled kernels.

Every operation is one of ``model/fp.py``'s scalar format operations (rounded to (E, M)), in
the order of the RTL (``rtl/rgs.py``: ``EyeRays``, ``RaySetupPipe``); the step names below are
the RTL's signal names and ``docs/rgs.md``'s. ``model/raygen.py``'s ``eye_rays`` and ``setup``
run these kernels, so the arithmetic is defined here once.

Eye ray of sample (sx, sy) (:func:`eye_ray`):

* ``sample``: px = (2*sx + 1) * 2**-1 rounded once to the format (= ``fmt.quantize(sx + 0.5)``,
  the RTL's ``FPFromInt(frac_bits=1)``), py likewise;
* ``mul_x``: px * dx[a]; ``mul_y``: py * dy[a];
* ``add_x``: corner[a] + px*dx[a]; ``add_y``: (corner[a] + px*dx[a]) + py*dy[a] = d[a].

Ray setup of one ray (:func:`ray_setup`; operands are read as the hardware reads them:
denormal encodings are signed zeros, see :func:`setup_rays`):

* ``inv``: inv[a] = 1 / d[a] (x / ±0 = ±inf);
* ``axes``: kz = the first axis of largest |d| (a NaN counts as largest; the RTL compares the
  exponent:fraction keys), kx = (kz + 1) % 3, ky = (kx + 1) % 3, swapped when d[kz] < 0;
* ``shear``: s = (d[kx] / d[kz], d[ky] / d[kz], inv[kz]) (Sz = 1/dz *is* inv[kz]: one divider);
* ``slab``: t0[a] = (lo[a] - o[a]) * inv[a], t1[a] = (hi[a] - o[a]) * inv[a];
* ``flat``: if t0[a] or t1[a] is NaN (0 * inf: d[a] = ±0 and the origin on a face plane of the
  box; the ray lies in that plane, inside the closed slab), t0[a] = -inf, t1[a] = +inf;
* ``order``: near[a] = min(t0[a], t1[a]), far[a] = max(t0[a], t1[a]);
* ``clip``: tnear = max(max(max(+0, near[0]), near[1]), near[2]),
  tfar = min(min(min(tmax, far[0]), far[1]), far[2]);
* ``octant``: the sign bits of d, x | y << 1 | z << 2 (-0 counts as negative, as the
  traversal's ``sign_bit``).

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

Drivers (compiled, rays in parallel tasks; the render and the testbenches call these):
:func:`eye_packets` makes every packet (tile) of a frame in packet order, lanes in order;
:func:`setup_rays` sets up an array of rays; :func:`secondary_rays` and :func:`shadow_rays`
make the secondary rays of an array of hits; :func:`light_colours` and :func:`hit_colours`
their colour contributions; :func:`shade_batch` does all of that for a set of hits in one
pass (the render's). The per-ray arithmetic is written once, on scalars (``setup_one``,
``secondary_one``, ``shadow_one``, ``light_one``, ``hit_one``, ``texture_one``); the array
functions call it.
"""
from __future__ import annotations

import numba
import numpy as np

from ..fp import fadd, fdiv, fmax, fmin, fmul, flush_in, fsqrt, fsub, round_exact, sign_bit
from ..lanes import borrow

__all__ = ["sample_coord", "eye_ray", "ray_setup", "eye_packets", "packet_count", "setup_rays",
           "dot3", "secondary", "secondary_rays", "shadow_dir", "shadow_rays", "FIX_FRAC",
           "FIX_BITS", "to_fixed", "spec_pow", "light_colour", "hit_colour", "light_colours",
           "hit_colours", "to_fixed_array", "UV_FRAC", "TEX_FRAC", "tex_coord",
           "wrap_coord", "tex_pos", "texture_kd"]

CHUNK = 4096           # rows per parallel task of the drivers (scratch arrays made once per task)

_ONE = np.float32(1.0)
_ZERO = np.float32(0.0)
_INF = np.float32(np.inf)


@numba.njit(cache=True, inline="always")
def sample_coord(s, E, M):
    """``sample``: the integer sample coordinate ``s`` to its centre ``s + 0.5`` in the format,
    one rounding of ``(2*s + 1) * 2**-1`` (exact in float64 for ``s < 2**52``)."""
    return round_exact(np.float64(2 * s + 1) * 0.5, E, M)


@numba.njit(cache=True, inline="always")
def eye_ray(sx, sy, corner, dx, dy, E, M):
    """The direction ``(d0, d1, d2)`` of the eye ray through sample (sx, sy):
    ``d[a] = (corner[a] + px*dx[a]) + py*dy[a]``, every operation rounded."""
    px = sample_coord(sx, E, M)
    py = sample_coord(sy, E, M)
    d0 = fadd(fadd(corner[0], fmul(px, dx[0], E, M), E, M), fmul(py, dy[0], E, M), E, M)
    d1 = fadd(fadd(corner[1], fmul(px, dx[1], E, M), E, M), fmul(py, dy[1], E, M), E, M)
    d2 = fadd(fadd(corner[2], fmul(px, dx[2], E, M), E, M), fmul(py, dy[2], E, M), E, M)
    return d0, d1, d2


@numba.njit(cache=True, inline="always")
def _larger(a, b):
    """|d| order of the axis choice: ``a`` beats the current best ``b`` (ties keep ``b``; a NaN
    is larger than every number, the first NaN stays)."""
    return a > b or (a != a and b == b)


@numba.njit(cache=True, inline="always")
def _pick(v0, v1, v2, k):
    if k == 0:
        return v0
    if k == 1:
        return v1
    return v2


@numba.njit(cache=True, inline="always", error_model="numpy")
def _slab(lo, hi, o, inv, E, M):
    """``slab``, ``flat`` and ``order`` of one axis: (near, far)."""
    t0 = fmul(fsub(lo, o, E, M), inv, E, M)
    t1 = fmul(fsub(hi, o, E, M), inv, E, M)
    if t0 != t0 or t1 != t1:
        t0 = -_INF
        t1 = _INF
    return fmin(t0, t1), fmax(t0, t1)


@numba.njit(cache=True, error_model="numpy")
def setup_one(o0, o1, o2, d0, d1, d2, tmax, lo0, lo1, lo2, hi0, hi1, hi2, E, M):
    """Set up one ray (origin ``o``, direction ``d``, ``tmax``) against the box ``[lo, hi]``
    (the module docstring's steps, in order). Returns ``(i0, i1, i2, kx, ky, kz, s0, s1, s2,
    tnear, tfar, octant)``."""
    # inv
    i0 = fdiv(_ONE, d0, E, M)
    i1 = fdiv(_ONE, d1, E, M)
    i2 = fdiv(_ONE, d2, E, M)
    # axes
    kz = 0
    best = abs(d0)
    if _larger(abs(d1), best):
        kz = 1
        best = abs(d1)
    if _larger(abs(d2), best):
        kz = 2
    kx = (kz + 1) % 3
    ky = (kx + 1) % 3
    dz = _pick(d0, d1, d2, kz)
    if dz < _ZERO:
        kx, ky = ky, kx
    # shear
    s0 = fdiv(_pick(d0, d1, d2, kx), dz, E, M)
    s1 = fdiv(_pick(d0, d1, d2, ky), dz, E, M)
    s2 = _pick(i0, i1, i2, kz)
    # slab, flat, order
    n0, f0 = _slab(lo0, hi0, o0, i0, E, M)
    n1, f1 = _slab(lo1, hi1, o1, i1, E, M)
    n2, f2 = _slab(lo2, hi2, o2, i2, E, M)
    # clip
    tnear = fmax(fmax(fmax(_ZERO, n0), n1), n2)
    tfar = fmin(fmin(fmin(tmax, f0), f1), f2)
    octant = sign_bit(d0) | (sign_bit(d1) << 1) | (sign_bit(d2) << 2)
    return i0, i1, i2, kx, ky, kz, s0, s1, s2, tnear, tfar, octant


@numba.njit(cache=True, inline="always", error_model="numpy")
def ray_setup(org, dirn, tmax, lo, hi, r, inv, k, s, tnear, tfar, octant, E, M):
    """Set up ray ``r`` (row ``r`` of ``org``/``dirn``, ``tmax[r]``) against the box
    ``[lo, hi]``: writes ``inv[r]``, ``k[r]`` (kx, ky, kz), ``s[r]``, ``tnear[r]``, ``tfar[r]``,
    ``octant[r]`` (:func:`setup_one`)."""
    (inv[r, 0], inv[r, 1], inv[r, 2], k[r, 0], k[r, 1], k[r, 2], s[r, 0], s[r, 1], s[r, 2],
     tnear[r], tfar[r], octant[r]) = setup_one(org[r, 0], org[r, 1], org[r, 2], dirn[r, 0],
                                               dirn[r, 1], dirn[r, 2], tmax[r], lo[0], lo[1], lo[2],
                                               hi[0], hi[1], hi[2], E, M)


@numba.njit(cache=True, inline="always", error_model="numpy")
def setup_flushed(org, dirn, tmax, lo_f, hi_f, r, inv, k, s, tnear, tfar, octant, E, M):
    """:func:`ray_setup` of ray ``r`` with its operands first read as the hardware reads
    format words (denormal encodings as signed zeros); ``lo_f``/``hi_f`` already read so."""
    (inv[r, 0], inv[r, 1], inv[r, 2], k[r, 0], k[r, 1], k[r, 2], s[r, 0], s[r, 1], s[r, 2],
     tnear[r], tfar[r], octant[r]) = setup_one(
        flush_in(org[r, 0], E), flush_in(org[r, 1], E), flush_in(org[r, 2], E),
        flush_in(dirn[r, 0], E), flush_in(dirn[r, 1], E), flush_in(dirn[r, 2], E),
        flush_in(tmax[r], E), lo_f[0], lo_f[1], lo_f[2], hi_f[0], hi_f[1], hi_f[2], E, M)


@numba.njit(cache=True, error_model="numpy")
def flushed_box(lo, hi, E):
    """The box corners read as the hardware reads format words: (lo, hi), each (3,)."""
    lo_f = np.empty(3, np.float32)
    hi_f = np.empty(3, np.float32)
    for a in range(3):
        lo_f[a] = flush_in(lo[a], E)
        hi_f[a] = flush_in(hi[a], E)
    return lo_f, hi_f


@numba.njit(cache=True, parallel=True, error_model="numpy")
def setup_rays(org, dirn, tmax, lo, hi, inv, k, s, tnear, tfar, octant, E, M):
    """:func:`ray_setup` for every ray, in parallel tasks of ``CHUNK`` rays. The operands are
    first read as the hardware reads format words (denormal encodings as signed zeros; the
    vectorized ``FPFormat`` operations do the same), so any float32 input gives the hardware's
    answer."""
    n = org.shape[0]
    lo_f, hi_f = flushed_box(lo, hi, E)
    for ch in numba.prange((n + CHUNK - 1) // CHUNK):
        for r in range(ch * CHUNK, min(n, ch * CHUNK + CHUNK)):
            setup_flushed(org, dirn, tmax, lo_f, hi_f, r, inv, k, s, tnear, tfar, octant, E, M)


@numba.njit(cache=True)
def packet_count(sw, sh, tw, th):
    """Packets (tiles) of a ``sw x sh`` sample image in ``tw x th`` tiles."""
    return ((sw + tw - 1) // tw) * ((sh + th - 1) // th)


@numba.njit(cache=True, parallel=True, error_model="numpy")
def eye_packets(sw, sh, tw, th, n, width, corner, dx, dy, dirn, pixel, pk_start, E, M):
    """Every eye ray of a ``sw x sh`` sample image (``n x n`` samples per pixel of a
    ``width``-pixel-wide image) in packet order: tiles of ``tw x th`` samples row-major, lanes
    row-major inside a tile; a tile at the right/bottom edge holds only the samples inside the
    image. Writes ``dirn`` (N, 3), ``pixel`` (N,: y * width + x of the sample's pixel) and
    ``pk_start`` (P + 1,). The RTL's ``EyeRays`` makes one packet per request in this lane
    order. A row of tiles per parallel task (the rays above tile row ``ty`` are the
    ``ty * th * sw`` samples of the rows above it)."""
    tiles_x = (sw + tw - 1) // tw
    tiles_y = (sh + th - 1) // th
    for ty in numba.prange(tiles_y):
        y0 = ty * th
        ht = min(th, sh - y0)
        r = y0 * sw
        for tx in range(tiles_x):
            x0 = tx * tw
            wt = min(tw, sw - x0)
            pk_start[ty * tiles_x + tx] = r
            for ly in range(ht):
                sy = y0 + ly
                row = (sy // n) * width
                for lx in range(wt):
                    sx = x0 + lx
                    d0, d1, d2 = eye_ray(sx, sy, corner, dx, dy, E, M)
                    dirn[r, 0] = d0
                    dirn[r, 1] = d1
                    dirn[r, 2] = d2
                    pixel[r] = row + sx // n
                    r += 1
    pk_start[tiles_x * tiles_y] = sw * sh


# ---------------------------------------------------------------------------------------------
# secondary rays
# ---------------------------------------------------------------------------------------------

_TWO = np.float32(2.0)


@numba.njit(cache=True, inline="always", error_model="numpy")
def dot3(a0, a1, a2, b0, b1, b2, E, M):
    """``dot``: (a0*b0 + a1*b1) + a2*b2, every operation rounded."""
    return fadd(fadd(fmul(a0, b0, E, M), fmul(a1, b1, E, M), E, M), fmul(a2, b2, E, M), E, M)


@numba.njit(cache=True, inline="always", error_model="numpy")
def _unit(x0, x1, x2, E, M):
    """x * (1 / sqrt(dot(x, x))) per component, and dot(x, x)."""
    q = dot3(x0, x1, x2, x0, x1, x2, E, M)
    r = fdiv(_ONE, fsqrt(q, E, M), E, M)
    return fmul(x0, r, E, M), fmul(x1, r, E, M), fmul(x2, r, E, M), q


@numba.njit(cache=True, inline="always", error_model="numpy")
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


@numba.njit(cache=True, inline="always", error_model="numpy")
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


@numba.njit(cache=True, inline="always", error_model="numpy")
def shadow_one(p0, p1, p2, g0, g1, g2, l0, l1, l2, point, E, M):
    """:func:`shadow_dir` on scalars: (d0, d1, d2, cast)."""
    if point:
        d0 = fsub(l0, p0, E, M)
        d1 = fsub(l1, p1, E, M)
        d2 = fsub(l2, p2, E, M)
    else:
        d0, d1, d2 = l0, l1, l2
    return d0, d1, d2, dot3(g0, g1, g2, d0, d1, d2, E, M) > _ZERO


@numba.njit(cache=True, inline="always", error_model="numpy")
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


@numba.njit(cache=True, inline="always", error_model="numpy")
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


@numba.njit(cache=True, inline="always", error_model="numpy")
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


@numba.njit(cache=True, inline="always", error_model="numpy")
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


@numba.njit(cache=True, inline="always", error_model="numpy")
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


# ---------------------------------------------------------------------------------------------
# texture (the RTL's Texture unit)
# ---------------------------------------------------------------------------------------------

UV_FRAC = 24            # fraction bits of a wrapped texture coordinate
TEX_FRAC = 8            # fraction bits of a bilinear weight
TEX_ONE = 1 << TEX_FRAC
TEX_SCALE = 256.0 / 255.0   # c * 2**-24 * 256/255: a filtered channel 0..255*2**16 as 0..1


@numba.njit(cache=True, inline="always", error_model="numpy")
def tex_coord(u, v, s0, s1, s2, E, M):
    """``tex_st``: a texture coordinate at the hit, (b*s0 + u*s1) + v*s2 with
    b = (1 - u) - v (the barycentric weights of ``normal``)."""
    b = fsub(fsub(_ONE, u, E, M), v, E, M)
    return fadd(fadd(fmul(b, s0, E, M), fmul(u, s1, E, M), E, M), fmul(v, s2, E, M), E, M)


@numba.njit(cache=True, inline="always", error_model="numpy")
def wrap_coord(s, E):
    """``wrap``: floor(s * 2**UV_FRAC) mod 2**UV_FRAC, the fraction of s (s - floor(s), the
    texture repeats) in UV_FRAC-bit fixed point; 0 for a NaN, an infinity or a zero
    (denormals read as zero). Exact: every step is exact in float64."""
    s = flush_in(s, E)
    if s != s or s == _INF or s == -_INF:
        return np.int64(0)
    one = np.float64(1 << UV_FRAC)
    f = np.floor(np.float64(s) * one)
    return np.int64(f - np.floor(f / one) * one)


@numba.njit(cache=True, inline="always")
def tex_pos(fs, size):
    """``pos``: the two texels and the weight of the second along one axis for the wrapped
    coordinate ``fs`` (UV_FRAC bits) on a texture ``size`` texels long: X = fs * size - 1/2 in
    TEX_FRAC-bit fixed point (the product's low bits truncated), i0 = floor(X), i1 = i0 + 1,
    each taken mod ``size`` (i0 >= -1, i1 <= size); weight X - i0. Returns (i0, i1, weight)."""
    x = ((fs * size) >> (UV_FRAC - TEX_FRAC)) - (TEX_ONE >> 1)
    i0 = x >> TEX_FRAC
    f = x & (TEX_ONE - 1)
    i1 = i0 + 1
    if i0 < 0:
        i0 += size
    if i1 >= size:
        i1 -= size
    return i0, i1, f


@numba.njit(cache=True, error_model="numpy")
def texture_kd(kd, u, v, uv, tex, tw, th, texels, E, M):
    """The diffuse constants of textured hits: ``kd`` (N, 3) the records' kd, ``u``, ``v``
    (N,) the hits, ``uv`` (N, 6) the triangles' texture coordinates (s0, t0, s1, t1, s2, t2,
    format values), ``tex`` (N,) the first texel's index in ``texels`` (-1: not textured: kd
    unchanged), ``tw``, ``th`` (N,) the texture's size, ``texels`` the textures' RGBA8 words
    (R in bits 0..7), each texture row by row. Steps (the RTL's ``Texture``):

    * ``tex_st``: s, t = :func:`tex_coord`; ``wrap``: fs = wrap(s), ft = 2**UV_FRAC - wrap(t)
      (image rows run down, t up);
    * ``pos``: (x0, x1, wx) = :func:`tex_pos` (fs, tw), (y0, y1, wy) = tex_pos(ft, th);
    * ``fetch``: the texels T(x, y) = texels[tex + y*tw + x] at (x0, y0), (x1, y0), (x0, y1),
      (x1, y1);
    * ``filter``, per channel c (an exact integer, 0..255 * 2**16):
      ((T00 * (256 - wx) + T10 * wx) * (256 - wy)) + (T01 * (256 - wx) + T11 * wx) * wy;
    * ``scale``: tex = from_fixed(c, 24) * fmt(256/255); ``kd``: kd[c] * tex.

    Returns (N, 3) float32."""
    N = kd.shape[0]
    out = np.empty((N, 3), np.float32)
    scale = tex_scale(E, M)
    for i in range(N):
        out[i, 0], out[i, 1], out[i, 2] = texture_one(
            kd[i, 0], kd[i, 1], kd[i, 2], u[i], v[i], uv, i, tex[i], tw[i], th[i], texels,
            scale, E, M)
    return out


@numba.njit(cache=True, inline="always", error_model="numpy")
def tex_scale(E, M):
    """``scale``'s constant: 256/255 in the format."""
    return round_exact(np.float64(TEX_SCALE), E, M)


@numba.njit(cache=True, inline="always", error_model="numpy")
def texture_one(kd0, kd1, kd2, u, v, uv, j, tex, tw, th, texels, scale, E, M):
    """:func:`texture_kd` of one hit (``uv[j]`` its triangle's texture coordinates,
    ``scale`` = :func:`tex_scale`): its 3 channels (``kd`` unchanged if ``tex < 0``)."""
    if tex < 0:
        return kd0, kd1, kd2
    uu = flush_in(u, E)
    vv = flush_in(v, E)
    s = tex_coord(uu, vv, flush_in(uv[j, 0], E), flush_in(uv[j, 2], E),
                  flush_in(uv[j, 4], E), E, M)
    t = tex_coord(uu, vv, flush_in(uv[j, 1], E), flush_in(uv[j, 3], E),
                  flush_in(uv[j, 5], E), E, M)
    x0, x1, wx = tex_pos(wrap_coord(s, E), np.int64(tw))
    y0, y1, wy = tex_pos((1 << UV_FRAC) - wrap_coord(t, E), np.int64(th))
    r0 = tex + y0 * tw
    r1 = tex + y1 * tw
    t00, t10 = np.int64(texels[r0 + x0]), np.int64(texels[r0 + x1])
    t01, t11 = np.int64(texels[r1 + x0]), np.int64(texels[r1 + x1])
    return (_texel_channel(kd0, t00, t10, t01, t11, wx, wy, 0, scale, E, M),
            _texel_channel(kd1, t00, t10, t01, t11, wx, wy, 8, scale, E, M),
            _texel_channel(kd2, t00, t10, t01, t11, wx, wy, 16, scale, E, M))


@numba.njit(cache=True, inline="always", error_model="numpy")
def _texel_channel(kd, t00, t10, t01, t11, wx, wy, sh, scale, E, M):
    """``filter``, ``scale`` and ``kd`` of one channel (bits ``sh`` .. ``sh + 7`` of a texel)."""
    a00, a10 = (t00 >> sh) & 255, (t10 >> sh) & 255
    a01, a11 = (t01 >> sh) & 255, (t11 >> sh) & 255
    f = ((a00 * (TEX_ONE - wx) + a10 * wx) * (TEX_ONE - wy)
         + (a01 * (TEX_ONE - wx) + a11 * wx) * wy)
    val = fmul(round_exact(np.float64(f) * 2.0 ** -24, E, M), scale, E, M)
    return fmul(flush_in(kd, E), val, E, M)


# ---------------------------------------------------------------------------------------------
# the slave's work on a set of hits, in one pass
# ---------------------------------------------------------------------------------------------

@numba.njit(cache=True, parallel=True, error_model="numpy")
def shade_batch(org, dirn, rows, tri, t, u, v, weight, kept, tri_mat, nf, nv, uv, rec_kd,
               rec_ks, rec_shin, rec_kr, tex_first, tex_w, tex_h, texels, textures, amb, bg,
               eps, lights, point, light_col, cull_behind, E, M):
    """Everything the slave computes from the hits of rays ``rows`` (ray i of ``org``,
    ``dirn``, ``tri`` (scene-order ids), ``t``, ``u``, ``v``, ``weight``, all indexed by ray),
    in parallel, with the arithmetic of :func:`secondary_rays`, :func:`texture_kd` (if
    ``textures``), :func:`hit_colours`, :func:`shadow_rays` and :func:`light_colours`: hit i's
    triangle row is ``kept[tri[rows[i]]]`` (of ``tri_mat``, ``nf``, ``nv``, ``uv``), its
    material that row's ``tri_mat`` (a row of the ``rec_*`` constants and ``tex_*``).
    Light j: ``lights[j]`` (position or reversed direction), ``point[j]``, ``light_col[j]``.

    Returns ``p0``, ``r`` (N, 3) float32, ``mat`` (N,) int64, the fixed-point ``ambient``
    (N, 3), ``wr`` (N,) float32, the fixed-point ``miss`` (N, 3), and per light the shadow
    directions (L, N, 3) float32, ``cast`` (L, N) bool (the light faces the surface, or
    always without ``cull_behind``) and the fixed-point light colours (L, N, 3), zero where
    not ``cast``."""
    N = rows.shape[0]
    L = lights.shape[0]
    P0 = np.empty((N, 3), np.float32)
    R = np.empty((N, 3), np.float32)
    MAT = np.empty(N, np.int64)
    AMB = np.empty((N, 3), np.int64)
    WR = np.empty(N, np.float32)
    MISS = np.empty((N, 3), np.int64)
    SD = np.empty((L, N, 3), np.float32)
    CAST = np.empty((L, N), np.bool_)
    LC = np.empty((L, N, 3), np.int64)
    e = flush_in(eps, E)
    am = flush_in(amb, E)
    b0, b1, b2 = flush_in(bg[0], E), flush_in(bg[1], E), flush_in(bg[2], E)
    lf = np.empty((L, 3), np.float32)
    lcf = np.empty((L, 3), np.float32)
    for j in range(L):
        for a in range(3):
            lf[j, a] = flush_in(lights[j, a], E)
            lcf[j, a] = flush_in(light_col[j, a], E)
    scale = tex_scale(E, M)
    for ch in numba.prange((N + CHUNK - 1) // CHUNK):
        _shade_rows(ch * CHUNK, min(N, ch * CHUNK + CHUNK), org, dirn, rows, tri, t, u, v,
                    weight, kept, tri_mat, nf, nv, uv, rec_kd, rec_ks, rec_shin, rec_kr,
                    tex_first, tex_w, tex_h, texels, textures, am, b0, b1, b2, e, lf, point,
                    lcf, cull_behind, scale, P0, R, MAT, AMB, WR, MISS, SD, CAST, LC, E, M)
    return P0, R, MAT, AMB, WR, MISS, SD, CAST, LC


@numba.njit(cache=True, error_model="numpy")
def _shade_rows(i0, i1, org, dirn, rows, tri, t, u, v, weight, kept, tri_mat, nf, nv, uv,
                rec_kd, rec_ks, rec_shin, rec_kr, tex_first, tex_w, tex_h, texels, textures, am,
                b0, b1, b2, e, lf, point, lcf, cull_behind, scale, P0, R, MAT, AMB, WR, MISS,
                SD, CAST, LC, E, M):
    """:func:`shade_batch`' work on hits ``i0 .. i1-1`` (one task's; a function of its own, so
    the parallel loop stays small for the compiler)."""
    org, dirn, rows, tri, t, u, v, weight = (borrow(org), borrow(dirn), borrow(rows), borrow(tri),
                                             borrow(t), borrow(u), borrow(v), borrow(weight))
    kept, tri_mat, nf, nv, uv, rec_kd, rec_ks = (borrow(kept), borrow(tri_mat), borrow(nf),
                                                 borrow(nv), borrow(uv), borrow(rec_kd),
                                                 borrow(rec_ks))
    rec_shin, rec_kr, tex_first, tex_w, tex_h, texels = (borrow(rec_shin), borrow(rec_kr),
                                                         borrow(tex_first), borrow(tex_w),
                                                         borrow(tex_h), borrow(texels))
    lf, point, lcf, P0, R, MAT, AMB, WR, MISS = (borrow(lf), borrow(point), borrow(lcf),
                                                 borrow(P0), borrow(R), borrow(MAT), borrow(AMB),
                                                 borrow(WR), borrow(MISS))
    SD, CAST, LC = borrow(SD), borrow(CAST), borrow(LC)
    for i in range(i0, i1):
        ray = rows[i]
        k = kept[tri[ray]]
        m = tri_mat[k]
        MAT[i] = m
        p00, p01, p02, g0, g1, g2, n0, n1, n2, r0, r1, r2 = secondary_at(
            org, dirn, ray, t[ray], u[ray], v[ray], nf, nv, k, e, E, M)
        P0[i, 0], P0[i, 1], P0[i, 2] = p00, p01, p02
        R[i, 0], R[i, 1], R[i, 2] = r0, r1, r2
        kd0, kd1, kd2 = rec_kd[m, 0], rec_kd[m, 1], rec_kd[m, 2]
        if textures:
            kd0, kd1, kd2 = texture_one(kd0, kd1, kd2, u[ray], v[ray], uv, k, tex_first[m],
                                        tex_w[m], tex_h[m], texels, scale, E, M)
        kd0, kd1, kd2 = flush_in(kd0, E), flush_in(kd1, E), flush_in(kd2, E)
        wt = flush_in(weight[ray], E)
        a0, a1, a2, wr, m0, m1, m2 = hit_one(kd0, kd1, kd2, flush_in(rec_kr[m], E), am, b0, b1, b2,
                                             wt, E, M)
        WR[i] = wr
        AMB[i, 0], AMB[i, 1], AMB[i, 2] = to_fixed(a0, E), to_fixed(a1, E), to_fixed(a2, E)
        MISS[i, 0], MISS[i, 1], MISS[i, 2] = to_fixed(m0, E), to_fixed(m1, E), to_fixed(m2, E)
        ks0, ks1, ks2 = (flush_in(rec_ks[m, 0], E), flush_in(rec_ks[m, 1], E),
                         flush_in(rec_ks[m, 2], E))
        for j in range(lf.shape[0]):
            d0, d1, d2, c = shadow_one(p00, p01, p02, g0, g1, g2, lf[j, 0], lf[j, 1], lf[j, 2],
                                       point[j], E, M)
            c = c or not cull_behind
            SD[j, i, 0], SD[j, i, 1], SD[j, i, 2] = d0, d1, d2
            CAST[j, i] = c
            if c:
                c0, c1, c2 = light_one(d0, d1, d2, n0, n1, n2, r0, r1, r2, kd0, kd1, kd2, ks0, ks1,
                                       ks2, rec_shin[m], lcf[j, 0], lcf[j, 1], lcf[j, 2], wt, E, M)
                LC[j, i, 0], LC[j, i, 1], LC[j, i, 2] = (to_fixed(c0, E), to_fixed(c1, E),
                                                         to_fixed(c2, E))
            else:
                LC[j, i, 0], LC[j, i, 1], LC[j, i, 2] = 0, 0, 0
