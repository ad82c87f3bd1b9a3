"""The RGS slave's ray generation (golden model): eye rays and ray setup as compiled kernels.

Every operation is one of ``model/fp.py``'s scalar format operations (rounded to (E, M)), in
the order of the RTL (``rtl/rgs/eye.py``: ``EyeRays``, ``RaySetupPipe``); the step names below
are the RTL's signal names and ``docs/rgs.md``'s. ``model/raygen.py``'s ``eye_rays`` and
``setup`` run these kernels, so the arithmetic is defined here once.

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

Drivers (compiled, rays in parallel tasks; the render and the testbenches call these):
:func:`eye_packets` makes every packet (tile) of a frame in packet order, lanes in order;
:func:`setup_rays` sets up an array of rays. The per-ray arithmetic is written once, on
scalars (``setup_one``); the array functions call it.
"""
from __future__ import annotations

import numba
import numpy as np

from ..fp import fadd, fdiv, fmax, fmin, fmul, flush_in, fsub, round_exact, sign_bit
from .common import _INF, _ONE, _ZERO, CHUNK

__all__ = ["sample_coord", "eye_ray", "setup_one", "ray_setup", "flushed_box", "setup_rays",
           "eye_packets", "packet_count"]


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
