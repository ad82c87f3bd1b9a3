"""Compiled drivers of a frame's per-ray work around the trace kernel (the host side of
``model.render``): eye rays, ray setup, secondary rays, colours and the per-pixel sums.

The arithmetic is ``model/rgs.py``'s scalar functions, unchanged; these drivers only run them
over many rays at once (in parallel where rays are independent) and add the fixed-point
contributions into the pixels. Every result is bit for bit the one of ``model/rgs.py``'s
serial drivers (``tests/test_render_kernels.py``).
"""
from __future__ import annotations

import numba
import numpy as np

from .fp import flush_in
from .rgs import (FIX_FRAC, eye_ray, hit_colour, light_colour, ray_setup, secondary, shadow_dir,
                  to_fixed)

CHUNK = 4096           # rows per parallel task (scratch arrays are made once per task)

__all__ = ["eye_packets", "setup_rays", "secondary_rays", "shadow_rays", "light_colours",
           "hit_colours", "add_colours", "colour_image"]


@numba.njit(cache=True, parallel=True, error_model="numpy")
def eye_packets(sw, sh, tw, th, n, width, corner, dx, dy, dirn, pixel, pk_start, E, M):
    """``model.rgs.eye_packets`` (same arguments and outputs), a row of tiles per task: the
    rays above tile row ``ty`` are the ``ty * th * sw`` samples of the rows above it."""
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


@numba.njit(cache=True, parallel=True, error_model="numpy")
def setup_rays(org, dirn, tmax, lo, hi, inv, k, s, tnear, tfar, octant, E, M):
    """``model.rgs.setup_rays`` (same arguments and outputs), rays in parallel, each ray's
    operands read (flushed) into a one-row scratch."""
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


@numba.njit(cache=True, parallel=True, error_model="numpy")
def secondary_rays(org, dirn, rows, t, u, v, tri, nf, nv, eps, E, M):
    """``model.rgs.secondary_rays`` on the rays ``rows`` of ``org``/``dirn`` (hit i is ray
    ``rows[i]`` on triangle ``tri[i]``, a row of the face normals ``nf`` (T, 3) and vertex
    normals ``nv`` (T, 3, 3)), hits in parallel."""
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


@numba.njit(cache=True, parallel=True, error_model="numpy")
def shadow_rays(p0, g, light, point, E, M):
    """``model.rgs.shadow_rays`` (same arguments and outputs), rows in parallel."""
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


@numba.njit(cache=True, parallel=True, error_model="numpy")
def light_colours(ld, n, r, kd, ks, shin, lc, wt, E, M):
    """``model.rgs.light_colours`` with one light colour ``lc`` (3,) for every row, rows in
    parallel: (N, 3) int64 fixed-point contributions."""
    N = ld.shape[0]
    out = np.empty((N, 3), np.int64)
    lf = np.empty(3, np.float32)
    for k in range(3):
        lf[k] = flush_in(lc[k], E)
    for ch in numba.prange((N + CHUNK - 1) // CHUNK):
        a = np.empty(3, np.float32)
        b = np.empty(3, np.float32)
        c3 = np.empty(3, np.float32)
        d = np.empty(3, np.float32)
        e = np.empty(3, np.float32)
        for i in range(ch * CHUNK, min(N, ch * CHUNK + CHUNK)):
            for k in range(3):
                a[k] = flush_in(ld[i, k], E)
                b[k] = flush_in(n[i, k], E)
                c3[k] = flush_in(r[i, k], E)
                d[k] = flush_in(kd[i, k], E)
                e[k] = flush_in(ks[i, k], E)
            col = light_colour(a, b, c3, d, e, shin[i], lf, flush_in(wt[i], E), E, M)
            for k in range(3):
                out[i, k] = to_fixed(col[k], E)
    return out


@numba.njit(cache=True, parallel=True, error_model="numpy")
def hit_colours(kd, kr, amb, bg, wt, E, M):
    """``model.rgs.hit_colours`` (same arguments and outputs), rows in parallel."""
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


@numba.njit(cache=True)
def add_colours(acc, pixel, rows, vals):
    """The per-pixel sums: ``acc[pixel[rows[i]]] += vals[i]`` for every i (``vals`` of one row:
    the same contribution for every i). Integer sums: the order does not matter."""
    one = vals.shape[0] == 1
    for i in range(rows.shape[0]):
        p = pixel[rows[i]]
        j = 0 if one else i
        for c in range(3):
            acc[p, c] += vals[j, c]


@numba.njit(cache=True, parallel=True)
def colour_image(acc):
    """The fixed-point sums as float32 colours: ``float32(acc / 2**FIX_FRAC)``."""
    out = np.empty(acc.shape, np.float32)
    scale = np.float64(1 << FIX_FRAC)
    n = acc.shape[0]
    for ch in numba.prange((n + CHUNK - 1) // CHUNK):
        for i in range(ch * CHUNK, min(n, ch * CHUNK + CHUNK)):
            for c in range(acc.shape[1]):
                out[i, c] = np.float32(np.float64(acc[i, c]) / scale)
    return out
