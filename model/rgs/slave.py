"""The RGS slave's work on a set of hits in one pass (golden model): :func:`shade_batch`, the
render's.

For every hit it does what the RTL slave's shading path does (``rtl/rgs/slave.py``: the
shading record, ``SecondaryPipe``, the texture unit, the light loop, ``LightPipe``), with the
kernels of ``secondary.py`` and ``texture.py``. The slave's control — the ray tree, the
secondary packets per source packet — is ``model/shading.py`` and ``model/render.py``.
"""
from __future__ import annotations

import numba
import numpy as np

from ..fp import flush_in
from ..lanes import borrow
from .common import CHUNK
from .secondary import hit_one, light_one, secondary_at, shadow_one, to_fixed
from .texture import tex_scale, texture_one

__all__ = ["shade_batch"]


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
