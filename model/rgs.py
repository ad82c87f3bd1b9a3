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
their colour contributions.
"""
from __future__ import annotations

import numba
import numpy as np

from .fp import fadd, fdiv, fmax, fmin, fmul, flush_in, fsqrt, fsub, round_exact, sign_bit

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


@numba.njit(cache=True, inline="always", error_model="numpy")
def ray_setup(org, dirn, tmax, lo, hi, r, inv, k, s, tnear, tfar, octant, E, M):
    """Set up ray ``r`` (row ``r`` of ``org``/``dirn``, ``tmax[r]``) against the box
    ``[lo, hi]``: writes ``inv[r]``, ``k[r]`` (kx, ky, kz), ``s[r]``, ``tnear[r]``, ``tfar[r]``,
    ``octant[r]`` (the module docstring's steps, in order)."""
    d0, d1, d2 = dirn[r, 0], dirn[r, 1], dirn[r, 2]
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
    s[r, 0] = fdiv(_pick(d0, d1, d2, kx), dz, E, M)
    s[r, 1] = fdiv(_pick(d0, d1, d2, ky), dz, E, M)
    s[r, 2] = _pick(i0, i1, i2, kz)
    # slab, flat, order
    n0, f0 = _slab(lo[0], hi[0], org[r, 0], i0, E, M)
    n1, f1 = _slab(lo[1], hi[1], org[r, 1], i1, E, M)
    n2, f2 = _slab(lo[2], hi[2], org[r, 2], i2, E, M)
    # clip
    tnear[r] = fmax(fmax(fmax(_ZERO, n0), n1), n2)
    tfar[r] = fmin(fmin(fmin(tmax[r], f0), f1), f2)
    inv[r, 0] = i0
    inv[r, 1] = i1
    inv[r, 2] = i2
    k[r, 0] = kx
    k[r, 1] = ky
    k[r, 2] = kz
    octant[r] = sign_bit(d0) | (sign_bit(d1) << 1) | (sign_bit(d2) << 2)


@numba.njit(cache=True, parallel=True, error_model="numpy")
def setup_rays(org, dirn, tmax, lo, hi, inv, k, s, tnear, tfar, octant, E, M):
    """:func:`ray_setup` for every ray, in parallel tasks of ``CHUNK`` rays. The operands are
    first read as the hardware reads format words (denormal encodings as signed zeros; the
    vectorized ``FPFormat`` operations do the same), so any float32 input gives the hardware's
    answer."""
    n = org.shape[0]
    lo_f = np.empty(3, np.float32)
    hi_f = np.empty(3, np.float32)
    for a in range(3):
        lo_f[a] = flush_in(lo[a], E)
        hi_f[a] = flush_in(hi[a], E)
    for ch in numba.prange((n + CHUNK - 1) // CHUNK):
        o = np.empty((1, 3), np.float32)
        d = np.empty((1, 3), np.float32)
        t = np.empty(1, np.float32)
        for r in range(ch * CHUNK, min(n, ch * CHUNK + CHUNK)):
            for a in range(3):
                o[0, a] = flush_in(org[r, a], E)
                d[0, a] = flush_in(dirn[r, a], E)
            t[0] = flush_in(tmax[r], E)
            ray_setup(o, d, t, lo_f, hi_f, 0, inv[r:r + 1], k[r:r + 1], s[r:r + 1],
                      tnear[r:r + 1], tfar[r:r + 1], octant[r:r + 1], E, M)


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


@numba.njit(cache=True, error_model="numpy")
def secondary(o, d, t, u, v, nf, nv, eps, E, M):
    """The module docstring's steps for one hit: ``o``, ``d``, ``nf`` (3,), ``nv`` (3, 3) vertex
    normals A, B, C. Returns (p0, g, n, r), each a (3,) float32 array."""
    p0 = np.empty(3, np.float32)
    g = np.empty(3, np.float32)
    n = np.empty(3, np.float32)
    r = np.empty(3, np.float32)
    # face
    flip = dot3(nf[0], nf[1], nf[2], d[0], d[1], d[2], E, M) > _ZERO
    for a in range(3):
        g[a] = -nf[a] if flip else nf[a]
    # dir_norm
    w0, w1, w2, _ = _unit(d[0], d[1], d[2], E, M)
    # hit, offset
    w = (w0, w1, w2)
    for a in range(3):
        p = fadd(o[a], fmul(t, d[a], E, M), E, M)
        p0[a] = fsub(fadd(p, fmul(eps, g[a], E, M), E, M), fmul(eps, w[a], E, M), E, M)
    # normal
    b = fsub(fsub(_ONE, u, E, M), v, E, M)
    s = np.empty(3, np.float32)
    for a in range(3):
        s[a] = fadd(fadd(fmul(b, nv[0, a], E, M), fmul(u, nv[1, a], E, M), E, M),
                    fmul(v, nv[2, a], E, M), E, M)
    n0, n1, n2, q = _unit(s[0], s[1], s[2], E, M)
    if q == _ZERO:
        n0, n1, n2 = g[0], g[1], g[2]
    if dot3(n0, n1, n2, g[0], g[1], g[2], E, M) < _ZERO:
        n0, n1, n2 = -n0, -n1, -n2
    n[0], n[1], n[2] = n0, n1, n2
    # reflect
    k = fmul(_TWO, dot3(d[0], d[1], d[2], n0, n1, n2, E, M), E, M)
    for a in range(3):
        r[a] = fsub(d[a], fmul(k, n[a], E, M), E, M)
    return p0, g, n, r


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
        o = np.empty(3, np.float32)
        d = np.empty(3, np.float32)
        f = np.empty(3, np.float32)
        nn = np.empty((3, 3), np.float32)
        for i in range(ch * CHUNK, min(N, ch * CHUNK + CHUNK)):
            ray = rows[i]
            k = tri[i]
            for a in range(3):
                o[a] = flush_in(org[ray, a], E)
                d[a] = flush_in(dirn[ray, a], E)
                f[a] = flush_in(nf[k, a], E)
                for c in range(3):
                    nn[c, a] = flush_in(nv[k, c, a], E)
            p0, g, n, r = secondary(o, d, flush_in(t[i], E), flush_in(u[i], E),
                                    flush_in(v[i], E), f, nn, e, E, M)
            for a in range(3):
                P0[i, a] = p0[a]
                G[i, a] = g[a]
                NS[i, a] = n[a]
                R[i, a] = r[a]
    return P0, G, NS, R


@numba.njit(cache=True, inline="always", error_model="numpy")
def shadow_dir(p0, g, light, point, E, M):
    """The shadow ray toward one light from origin ``p0`` with oriented face normal ``g``:
    (direction (3,), cast). ``light``: the point light's position (``point``) or the parallel
    light's reversed direction."""
    ds = np.empty(3, np.float32)
    for a in range(3):
        ds[a] = fsub(light[a], p0[a], E, M) if point else light[a]
    return ds, dot3(g[0], g[1], g[2], ds[0], ds[1], ds[2], E, M) > _ZERO


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
            ds, c = shadow_dir(p0[i], g[i], lf, point, E, M)
            for a in range(3):
                D[i, a] = ds[a]
            cast[i] = c
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
    il = fdiv(_ONE, fsqrt(dot3(ld[0], ld[1], ld[2], ld[0], ld[1], ld[2], E, M), E, M), E, M)
    ir = fdiv(_ONE, fsqrt(dot3(r[0], r[1], r[2], r[0], r[1], r[2], E, M), E, M), E, M)
    ndl = fmax(fmul(dot3(n[0], n[1], n[2], ld[0], ld[1], ld[2], E, M), il, E, M), _ZERO)
    rdl = fmax(fmul(fmul(dot3(r[0], r[1], r[2], ld[0], ld[1], ld[2], E, M), il, E, M),
                    ir, E, M), _ZERO)
    spec = spec_pow(rdl, shin, E, M)
    for c in range(3):
        out[c] = fmul(fadd(fmul(kd[c], ndl, E, M), fmul(ks[c], spec, E, M), E, M),
                      fmul(lc[c], wt, E, M), E, M)
    return out


@numba.njit(cache=True, error_model="numpy")
def hit_colour(kd, kr, amb, bg, wt, E, M):
    """What a hit of an eye or reflection ray of weight ``wt`` adds by itself, and what its
    reflection ray carries: ``ambient`` (kd[c] * amb) * wt; ``wr`` = wt * kr (the reflection
    ray's weight); ``miss`` = bg[c] * wr (its colour if it leaves the scene). Returns
    (ambient (3,), wr, miss (3,))."""
    amb_c = np.empty(3, np.float32)
    miss = np.empty(3, np.float32)
    wr = fmul(wt, kr, E, M)
    for c in range(3):
        amb_c[c] = fmul(fmul(kd[c], amb, E, M), wt, E, M)
        miss[c] = fmul(bg[c], wr, E, M)
    return amb_c, wr, miss


@numba.njit(cache=True, parallel=True, error_model="numpy")
def light_colours(ld, n, r, kd, ks, shin, lc, wt, E, M):
    """:func:`light_colour` then :func:`to_fixed` for every row (``ld``, ``n``, ``r``, ``kd``,
    ``ks`` (N, 3), ``shin``, ``wt`` (N,); ``lc`` (N, 3) the light colour of each row), in
    parallel: (N, 3) int64 contributions."""
    N = ld.shape[0]
    out = np.empty((N, 3), np.int64)
    for ch in numba.prange((N + CHUNK - 1) // CHUNK):
        a = np.empty(3, np.float32)
        b = np.empty(3, np.float32)
        c3 = np.empty(3, np.float32)
        d = np.empty(3, np.float32)
        e = np.empty(3, np.float32)
        lf = np.empty(3, np.float32)
        for i in range(ch * CHUNK, min(N, ch * CHUNK + CHUNK)):
            for k in range(3):
                a[k] = flush_in(ld[i, k], E)
                b[k] = flush_in(n[i, k], E)
                c3[k] = flush_in(r[i, k], E)
                d[k] = flush_in(kd[i, k], E)
                e[k] = flush_in(ks[i, k], E)
                lf[k] = flush_in(lc[i, k], E)
            col = light_colour(a, b, c3, d, e, shin[i], lf, flush_in(wt[i], E), E, M)
            for k in range(3):
                out[i, k] = to_fixed(col[k], E)
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
    bf = np.empty(3, np.float32)
    for k in range(3):
        bf[k] = flush_in(bg[k], E)
    am = flush_in(amb, E)
    for ch in numba.prange((N + CHUNK - 1) // CHUNK):
        k3 = np.empty(3, np.float32)
        for i in range(ch * CHUNK, min(N, ch * CHUNK + CHUNK)):
            for k in range(3):
                k3[k] = flush_in(kd[i, k], E)
            a, wr, ms = hit_colour(k3, flush_in(kr[i], E), am, bf, flush_in(wt[i], E), E, M)
            wr_o[i] = wr
            for k in range(3):
                amb_o[i, k] = to_fixed(a[k], E)
                miss_o[i, k] = to_fixed(ms[k], E)
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
    scale = round_exact(np.float64(TEX_SCALE), E, M)
    for i in range(N):
        for c in range(3):
            out[i, c] = kd[i, c]
        if tex[i] < 0:
            continue
        uu = flush_in(u[i], E)
        vv = flush_in(v[i], E)
        s = tex_coord(uu, vv, flush_in(uv[i, 0], E), flush_in(uv[i, 2], E),
                      flush_in(uv[i, 4], E), E, M)
        t = tex_coord(uu, vv, flush_in(uv[i, 1], E), flush_in(uv[i, 3], E),
                      flush_in(uv[i, 5], E), E, M)
        x0, x1, wx = tex_pos(wrap_coord(s, E), np.int64(tw[i]))
        y0, y1, wy = tex_pos((1 << UV_FRAC) - wrap_coord(t, E), np.int64(th[i]))
        r0 = tex[i] + y0 * tw[i]
        r1 = tex[i] + y1 * tw[i]
        t00, t10 = np.int64(texels[r0 + x0]), np.int64(texels[r0 + x1])
        t01, t11 = np.int64(texels[r1 + x0]), np.int64(texels[r1 + x1])
        for c in range(3):
            sh = 8 * c
            a00, a10 = (t00 >> sh) & 255, (t10 >> sh) & 255
            a01, a11 = (t01 >> sh) & 255, (t11 >> sh) & 255
            f = ((a00 * (TEX_ONE - wx) + a10 * wx) * (TEX_ONE - wy)
                 + (a01 * (TEX_ONE - wx) + a11 * wx) * wy)
            val = fmul(round_exact(np.float64(f) * 2.0 ** -24, E, M), scale, E, M)
            out[i, c] = fmul(flush_in(kd[i, c], E), val, E, M)
    return out
