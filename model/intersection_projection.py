"""Intersection unit (golden model), ``Config.int_test = "projection"``: the paper's test.

The projection test of Wald, Benthin, Wagner, Slusallek (2001) on the precomputed triangle
record of ``model.layout.projection_records``: k (the dominant axis of the normal) and 9
format words n_u, n_v, n_d, b_nu, b_nv, b_d, c_nu, c_nv, c_d; u = (k+1) % 3, v = (k+2) % 3.
Per ray (origin o, direction d), in the hardware's order, every operation rounded to (E, M)::

    nd  = (d[k] + n_u*d[u]) + n_v*d[v]                      2 mul, 2 add
    f   = (((n_d - o[k]) - n_u*o[u]) - n_v*o[v]) / nd       2 mul, 3 sub, 1 div
    h_u = o[u] + f*d[u];  h_v = o[v] + f*d[v]               2 mul, 2 add
    lam = (h_u*b_nu + h_v*b_nv) + b_d                       2 mul, 2 add
    mu  = (h_u*c_nu + h_v*c_nv) + c_d                       2 mul, 2 add
    hit = lam >= 0 and mu >= 0 and lam + mu <= 1           1 add, 3 compares

12 add/sub, 10 mul, 1 div (the paper's "12 FP adds and 13 FP multiplications", a division
counted as three). ``lam`` and ``mu`` are the hit's weights of vertices B and C, the
watertight test's u and v. The caller applies the t-range test ``0 < t < t_best``.

Hardware: one ray per cycle, fully pipelined (``rtl/intersection_projection.py``).
"""
import numba
import numpy as np

from .fp import fadd, fdiv, fmul, fsub
from .layout import PROJ_K_BIT

_ONE = np.float32(1.0)
_ZERO = np.float32(0.0)
_K_BIT = np.uint32(1 << PROJ_K_BIT)


@numba.njit(cache=True, inline="always")
def pick(v0, v1, v2, k):
    if k == 0:
        return v0
    if k == 1:
        return v1
    return v2


@numba.njit(cache=True, inline="always")
def split_k(rec):
    """The record's axis k, from the spare exponent bits of n_u and n_v (bit 0, bit 1), which
    are cleared in ``rec`` (9 float32 as read from memory), leaving the values."""
    b0 = np.float32(rec[0]).view(np.uint32)
    b1 = np.float32(rec[1]).view(np.uint32)
    rec[0] = np.uint32(b0 & ~_K_BIT).view(np.float32)
    rec[1] = np.uint32(b1 & ~_K_BIT).view(np.float32)
    return np.int64((b0 & _K_BIT) != 0) | (np.int64((b1 & _K_BIT) != 0) << 1)


@numba.njit(cache=True, inline="always")
def intersect_projection(rec, k, ox, oy, oz, dx, dy, dz, E, M):
    """Test one ray against one projection record.

    rec: 9 float32 (n_u, n_v, n_d, b_nu, b_nv, b_d, c_nu, c_nv, c_d); k: 0..2; (ox, oy, oz),
    (dx, dy, dz): the ray. Returns (hit, t, u, v), (False, 0, 0, 0) on a miss."""
    ku = (k + 1) % 3
    kv = (k + 2) % 3
    ok, ou, ov = pick(ox, oy, oz, k), pick(ox, oy, oz, ku), pick(ox, oy, oz, kv)
    dk, du, dv = pick(dx, dy, dz, k), pick(dx, dy, dz, ku), pick(dx, dy, dz, kv)
    n_u, n_v, n_d = rec[0], rec[1], rec[2]
    nd = fadd(fadd(dk, fmul(n_u, du, E, M), E, M), fmul(n_v, dv, E, M), E, M)
    num = fsub(fsub(fsub(n_d, ok, E, M), fmul(n_u, ou, E, M), E, M), fmul(n_v, ov, E, M), E, M)
    f = fdiv(num, nd, E, M)
    hu = fadd(ou, fmul(f, du, E, M), E, M)
    hv = fadd(ov, fmul(f, dv, E, M), E, M)
    lam = fadd(fadd(fmul(hu, rec[3], E, M), fmul(hv, rec[4], E, M), E, M), rec[5], E, M)
    mu = fadd(fadd(fmul(hu, rec[6], E, M), fmul(hv, rec[7], E, M), E, M), rec[8], E, M)
    s = fadd(lam, mu, E, M)
    if lam >= _ZERO and mu >= _ZERO and s <= _ONE:
        return True, f, lam, mu
    return False, _ZERO, _ZERO, _ZERO
