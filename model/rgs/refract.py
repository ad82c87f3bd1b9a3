"""The RGS slave's refracted rays (golden model), as compiled kernels.

A hit on a material that transmits (record constant ``kt`` = transmit > 0) spawns one
refracted ray (:class:`~model.raykind.RayKind` ``REFRACTION``) beside its reflection and
shadow rays. Every operation is one of ``model/fp.py``'s scalar format operations, in this
order (``docs/rgs.md``, "Refraction"); ``d``, ``o``, ``t``, ``n_f`` as in
``model/rgs/secondary.py``, and its results ``p0``, ``g`` (face normal turned toward the ray),
``n`` (unit shading normal on ``g``'s side) and ``r`` (reflected direction):

* ``side``: the ray leaves the mesh if it meets the face from behind, dot(n_f, d) > 0 (the
  ``face`` test of ``secondary``: meshes are closed, their face normals point out); eta =
  ``eta_out`` (= ior) if it leaves, else ``eta_in`` (= 1 / ior), both record constants;
* ``dir_norm``: w = d * (1 / sqrt(dot(d, d))) (as ``secondary``);
* ``cos``: c = -dot(w, n) (n faces the incoming ray, so c >= 0 but for a shading normal
  bent past the ray); ``cos2`` = c*c; ``sin2`` = 1 - cos2; ``eta2`` = eta*eta;
  ``k`` = 1 - eta2*sin2;
* ``tir``: k < 0 is total internal reflection: the ray is the reflection (origin ``p0``,
  direction ``r``), still of kind ``REFRACTION`` and weight;
* else ``root`` = sqrt(k), ``mu`` = eta*c - root, ``tdir[a]`` = eta*w[a] + mu*n[a], origin
  ``pt[a]`` = ((o[a] + t*d[a]) - eps*g[a]) + eps*w[a] (across the surface, on the far side
  from ``p0``, and on along the ray).

Its weight is ``wt * kt`` and it carries ``bg * (wt * kt)`` if it leaves the scene, as a
reflection ray carries ``bg * (wt * kr)`` (``hit_colour``). Refracted rays are made, like
reflection rays, only from rays of depth below ``Config.reflect_depth`` (each adds one).

Driver (compiled, hits in parallel tasks): :func:`refraction_rays`.
"""
from __future__ import annotations

import numba
import numpy as np

from ..fp import fadd, fdiv, fmul, flush_in, fsqrt, fsub
from .common import _ONE, _ZERO, CHUNK
from .secondary import dot3, secondary_at, to_fixed

__all__ = ["refract_one", "refraction_rays"]


@numba.njit(cache=True, error_model="numpy")
def refract_one(o0, o1, o2, d0, d1, d2, t, f0, f1, f2, p00, p01, p02, g0, g1, g2, n0, n1, n2,
                r0, r1, r2, eps, eta_in, eta_out, E, M):
    """The module docstring's steps for one hit, on scalars (``f`` the face normal n_f; ``p0``,
    ``g``, ``n``, ``r`` from ``secondary_one``): the refracted ray's origin and direction
    (6 values) and whether it was totally reflected."""
    # side
    eta = eta_out if dot3(f0, f1, f2, d0, d1, d2, E, M) > _ZERO else eta_in
    # dir_norm
    q = dot3(d0, d1, d2, d0, d1, d2, E, M)
    rl = fdiv(_ONE, fsqrt(q, E, M), E, M)
    w0, w1, w2 = fmul(d0, rl, E, M), fmul(d1, rl, E, M), fmul(d2, rl, E, M)
    # cos, k
    c = -dot3(w0, w1, w2, n0, n1, n2, E, M)
    k = fsub(_ONE, fmul(fmul(eta, eta, E, M), fsub(_ONE, fmul(c, c, E, M), E, M), E, M), E, M)
    if k < _ZERO:                                  # tir
        return p00, p01, p02, r0, r1, r2, True
    mu = fsub(fmul(eta, c, E, M), fsqrt(k, E, M), E, M)
    t0 = fadd(fmul(eta, w0, E, M), fmul(mu, n0, E, M), E, M)
    t1 = fadd(fmul(eta, w1, E, M), fmul(mu, n1, E, M), E, M)
    t2 = fadd(fmul(eta, w2, E, M), fmul(mu, n2, E, M), E, M)
    pt0 = fadd(fsub(fadd(o0, fmul(t, d0, E, M), E, M), fmul(eps, g0, E, M), E, M),
               fmul(eps, w0, E, M), E, M)
    pt1 = fadd(fsub(fadd(o1, fmul(t, d1, E, M), E, M), fmul(eps, g1, E, M), E, M),
               fmul(eps, w1, E, M), E, M)
    pt2 = fadd(fsub(fadd(o2, fmul(t, d2, E, M), E, M), fmul(eps, g2, E, M), E, M),
               fmul(eps, w2, E, M), E, M)
    return pt0, pt1, pt2, t0, t1, t2, False


@numba.njit(cache=True, parallel=True, error_model="numpy")
def refraction_rays(org, dirn, rows, t, u, v, tri, nf, nv, eps, kt, eta_in, eta_out, wt, bg,
                    E, M):
    """The refracted ray of every hit, in parallel: hit i is ray ``rows[i]`` of ``org``,
    ``dirn`` (R, 3) at ``t[i]``, ``u[i]``, ``v[i]`` on triangle row ``tri[i]`` of ``nf``
    (T, 3), ``nv`` (T, 3, 3); its material's ``kt[i]``, ``eta_in[i]``, ``eta_out[i]``, its
    ray's weight ``wt[i]``; ``bg`` (3,) the background. Operands are read as the hardware
    reads format words. Returns the origins and directions (N, 3) float32, ``tir`` (N,) bool,
    the weights ``wt * kt`` (N,) float32 and the fixed-point miss colours (N, 3) int64."""
    N = rows.shape[0]
    ORG = np.empty((N, 3), np.float32)
    DIR = np.empty((N, 3), np.float32)
    TIR = np.empty(N, np.bool_)
    WT = np.empty(N, np.float32)
    MISS = np.empty((N, 3), np.int64)
    e = flush_in(eps, E)
    b0, b1, b2 = flush_in(bg[0], E), flush_in(bg[1], E), flush_in(bg[2], E)
    for ch in numba.prange((N + CHUNK - 1) // CHUNK):
        for i in range(ch * CHUNK, min(N, ch * CHUNK + CHUNK)):
            ray, k = rows[i], tri[i]
            p00, p01, p02, g0, g1, g2, n0, n1, n2, r0, r1, r2 = secondary_at(
                org, dirn, ray, t[i], u[i], v[i], nf, nv, k, e, E, M)
            (ORG[i, 0], ORG[i, 1], ORG[i, 2], DIR[i, 0], DIR[i, 1], DIR[i, 2],
             TIR[i]) = refract_one(
                flush_in(org[ray, 0], E), flush_in(org[ray, 1], E), flush_in(org[ray, 2], E),
                flush_in(dirn[ray, 0], E), flush_in(dirn[ray, 1], E), flush_in(dirn[ray, 2], E),
                flush_in(t[i], E), flush_in(nf[k, 0], E), flush_in(nf[k, 1], E),
                flush_in(nf[k, 2], E), p00, p01, p02, g0, g1, g2, n0, n1, n2, r0, r1, r2, e,
                flush_in(eta_in[i], E), flush_in(eta_out[i], E), E, M)
            w = fmul(flush_in(wt[i], E), flush_in(kt[i], E), E, M)
            WT[i] = w
            MISS[i, 0] = to_fixed(fmul(b0, w, E, M), E)
            MISS[i, 1] = to_fixed(fmul(b1, w, E, M), E)
            MISS[i, 2] = to_fixed(fmul(b2, w, E, M), E)
    return ORG, DIR, TIR, WT, MISS
