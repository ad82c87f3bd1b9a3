"""Exact ray-triangle oracle (integer arithmetic) and a plain float32 Möller–Trumbore baseline.

Every float32 value is a dyadic rational, so after scaling all coordinates of a case by one
power of two they are integers, and the triple products that decide whether a ray's line
passes through a triangle are exact Python integers. The oracle answers, for each ray and each
of its candidate triangles, the question the hardware approximates:

* the ray ``o + t*d`` hits the *closed* triangle (edges and vertices included) iff the three
  signed volumes ``d·(a×b)``, ``d·(b×c)``, ``d·(c×a)`` (``a = A-o`` ...) are all >= 0 or all
  <= 0, and their sum ``d·((B-A)×(C-A))`` is not 0 (a ray parallel to the plane, e.g. grazing
  along it, is a miss, as in the watertight test's ``det == 0`` rule);
* ``t = ((B-A)×(C-A))·(A-o) / ((B-A)×(C-A))·d`` exactly, and the hit counts when
  ``0 < t < tmax``.

Work is per (ray, candidate) pair on numpy object arrays of Python ints; it is meant for the
stress cases (up to ~10^5 pairs), not for frames.
"""
from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction

import numpy as np


def _scale_exponent(*arrays) -> int:
    """Smallest power of two that makes every finite value of ``arrays`` an integer."""
    lo = 0
    for a in arrays:
        a = np.asarray(a, np.float64)
        a = a[np.isfinite(a) & (a != 0)]
        if a.size:
            m, e = np.frexp(a)                 # a = m * 2^e, 0.5 <= |m| < 1; 53 mantissa bits
            # lowest set bit of the 53-bit mantissa
            mi = np.abs(np.ldexp(m, 53)).astype(np.int64)
            tz = np.zeros(mi.shape, np.int64)
            x = mi.copy()
            for b in (32, 16, 8, 4, 2, 1):
                low = (x & ((1 << b) - 1)) == 0
                tz += np.where(low, b, 0)
                x = np.where(low, x >> b, x)
            lo = min(lo, int((e - 53 + tz).min()))
    return -lo


def _ints(a, shift: int) -> np.ndarray:
    """float values -> object array of Python ints ``a * 2^shift`` (exact)."""
    a = np.asarray(a, np.float64)
    out = np.empty(a.shape, object)
    flat = out.reshape(-1)
    for i, x in enumerate(a.reshape(-1)):
        n, d = float(x).as_integer_ratio()
        flat[i] = (n << shift) // d
    return out


def _cross(p, q):
    return (p[..., 1] * q[..., 2] - p[..., 2] * q[..., 1],
            p[..., 2] * q[..., 0] - p[..., 0] * q[..., 2],
            p[..., 0] * q[..., 1] - p[..., 1] * q[..., 0])


def _dot(c, q):
    return c[0] * q[..., 0] + c[1] * q[..., 1] + c[2] * q[..., 2]


@dataclass
class ExactHits:
    """Closest exact hit per ray: ``tri`` (scene index or -1), ``t`` (a Fraction or None) and
    ``ties``: every candidate hit at exactly that t (a frozenset; rays through a shared edge or
    vertex, coincident triangles)."""
    tri: np.ndarray
    t: list
    ties: list

    @property
    def hit(self) -> np.ndarray:
        return self.tri >= 0


def exact_pairs(tris, org, dirn, ray, cand, tmax=None):
    """Exact test of the pairs (``ray[k]``, ``cand[k]``).

    Returns ``(hit, num, den)`` per pair: ``hit`` bool, and ``t = num/den`` (den > 0) as
    Python ints (valid where ``hit``)."""
    tris = np.asarray(tris, np.float32)
    org = np.asarray(org, np.float32)
    dirn = np.asarray(dirn, np.float32)
    ray = np.asarray(ray, np.int64)
    cand = np.asarray(cand, np.int64)
    if not (np.isfinite(tris).all() and np.isfinite(org).all() and np.isfinite(dirn).all()):
        raise ValueError("exact oracle: triangles, origins and directions must be finite")
    s = _scale_exponent(tris[cand], org[ray], dirn[ray])
    A, B, C = (_ints(tris[cand, i], s) for i in range(3))
    o = _ints(org[ray], s)
    d = _ints(dirn[ray], s)
    a, b, c = A - o, B - o, C - o
    w_ab = _dot(_cross(a, b), d)
    w_bc = _dot(_cross(b, c), d)
    w_ca = _dot(_cross(c, a), d)
    den = w_ab + w_bc + w_ca                     # = d . ((B-A) x (C-A))
    num = _dot(_cross(B - A, C - A), a)          # t = num / den
    sgn = np.frompyfunc(lambda x: (x > 0) - (x < 0), 1, 1)
    sa, sb, sc, sd = (sgn(x).astype(np.int64) for x in (w_ab, w_bc, w_ca, den))
    sn = sgn(num).astype(np.int64)
    inside = ((sa >= 0) & (sb >= 0) & (sc >= 0)) | ((sa <= 0) & (sb <= 0) & (sc <= 0))
    hit = inside & (sd != 0) & (sn * sd > 0)
    num = np.where(sd < 0, -num, num)
    den = np.where(sd < 0, -den, den)
    if tmax is not None:
        tm = np.asarray(tmax, np.float32)[ray]
        fin = np.isfinite(tm)
        for k in np.flatnonzero(hit & fin):
            n_, d_ = float(tm[k]).as_integer_ratio()
            hit[k] = num[k] * d_ < n_ * den[k]
    return hit, num, den


def exact_closest(tris, org, dirn, candidates=None, tmax=None) -> ExactHits:
    """Closest exact hit of every ray among its candidates.

    ``candidates``: None (every triangle), or a list of index arrays, one per ray."""
    n = len(org)
    if candidates is None:
        candidates = [np.arange(len(tris))] * n
    ray = np.concatenate([np.full(len(c), i, np.int64) for i, c in enumerate(candidates)]
                         + [np.zeros(0, np.int64)])
    cand = np.concatenate([np.asarray(c, np.int64) for c in candidates]
                          + [np.zeros(0, np.int64)])
    hit, num, den = exact_pairs(tris, org, dirn, ray, cand, tmax)
    tri = np.full(n, -1, np.int64)
    t: list = [None] * n
    ties: list = [frozenset()] * n
    for k in np.flatnonzero(hit):
        r = ray[k]
        tk = Fraction(int(num[k]), int(den[k]))
        if t[r] is None or tk < t[r]:
            t[r], tri[r], ties[r] = tk, cand[k], frozenset([int(cand[k])])
        elif tk == t[r]:
            ties[r] = ties[r] | {int(cand[k])}
    return ExactHits(tri, t, ties)


def moller_trumbore32(tris, org, dirn, ray, cand) -> tuple[np.ndarray, np.ndarray]:
    """Plain float32 Möller–Trumbore (no epsilon, IEEE float32 per operation, numpy keeps
    denormals) on the pairs (``ray[k]``, ``cand[k]``): ``(hit, t)``. The baseline a
    non-watertight tracer gets at shared edges and vertices."""
    f = np.float32
    tris = np.asarray(tris, f)
    A, B, C = tris[cand, 0], tris[cand, 1], tris[cand, 2]
    o, d = np.asarray(org, f)[ray], np.asarray(dirn, f)[ray]

    def cross(p, q):
        return np.stack([p[:, 1] * q[:, 2] - p[:, 2] * q[:, 1],
                         p[:, 2] * q[:, 0] - p[:, 0] * q[:, 2],
                         p[:, 0] * q[:, 1] - p[:, 1] * q[:, 0]], axis=1)

    def dot(p, q):
        return (p[:, 0] * q[:, 0] + p[:, 1] * q[:, 1]) + p[:, 2] * q[:, 2]

    with np.errstate(all="ignore"):
        e1, e2 = B - A, C - A
        p = cross(d, e2)
        det = dot(e1, p)
        inv = f(1) / det
        s = o - A
        u = dot(s, p) * inv
        q = cross(s, e1)
        v = dot(d, q) * inv
        t = dot(e2, q) * inv
        hit = (det != 0) & (u >= 0) & (u <= 1) & (v >= 0) & (u + v <= 1) & (t > 0)
    return hit, t


def closest_of_pairs(n_rays: int, ray, cand, hit, t) -> np.ndarray:
    """Per ray, the candidate with the smallest float t among the hit pairs (-1 if none)."""
    best = np.full(n_rays, -1, np.int64)
    hk = np.flatnonzero(hit)
    o = np.lexsort((np.asarray(t, np.float64)[hk], ray[hk]))
    hk = hk[o]
    first = np.ones(len(hk), bool)
    first[1:] = ray[hk][1:] != ray[hk][:-1]
    best[ray[hk][first]] = cand[hk][first]
    return best
