"""Independent oracle: Intel Embree (through ``embreex``) on the same triangles and rays.

Used by the differential tests and the benchmark only (embreex is a test/bench dependency).
Embree traces in IEEE float32 with its own algorithm; agreement is checked with a tolerance and
every disagreement is explained (see :func:`explain`), never by bit equality.
"""
from __future__ import annotations

import numpy as np


class Embree:
    def __init__(self, tris: np.ndarray, tri_id: np.ndarray | None = None):
        import embreex.rtcore_scene as rtcs
        from embreex.mesh_construction import TriangleMesh
        self.tris = np.ascontiguousarray(tris, np.float32)
        self.tri_id = np.arange(len(tris)) if tri_id is None else np.asarray(tri_id)
        self.scene = rtcs.EmbreeScene()
        TriangleMesh(self.scene, self.tris)

    def _run(self, org, dirn, tmax):
        org = np.ascontiguousarray(org, np.float32)
        dirn = np.ascontiguousarray(dirn, np.float32)
        if tmax is None:
            res = self.scene.run(org, dirn, output=1)
        else:  # run() overwrites dists with the hit distance: pass a copy
            res = self.scene.run(org, dirn, dists=np.array(tmax, np.float32), output=1)
        prim = res["primID"].astype(np.int64)
        hit = (res["geomID"] >= 0) & (prim >= 0)
        tri = np.where(hit, self.tri_id[np.where(hit, prim, 0)], -1).astype(np.int32)
        t = np.where(hit, res["tfar"], np.inf).astype(np.float32)
        return tri, t, res["u"].astype(np.float32), res["v"].astype(np.float32)

    def intersect(self, org, dirn, tmax=None, nudge=1e-6):
        """Closest hit per ray: (tri scene id or -1, t, u, v), with SaarCOR's ``t > 0`` rule.

        Embree accepts hits at t = 0 (a ray starting on a triangle); SaarCOR requires t > 0.
        Rays Embree reports at exactly t = 0 are traced again from ``o + nudge*d`` (and their
        t shifted back), which emulates an open interval at 0."""
        tri, t, u, v = self._run(org, dirn, tmax)
        again = np.nonzero((tri >= 0) & (t == 0))[0]
        if again.size:
            o2 = (org[again].astype(np.float64) + nudge * dirn[again]).astype(np.float32)
            tm = None if tmax is None else np.asarray(tmax, np.float32)[again] - np.float32(nudge)
            tri2, t2, u2, v2 = self._run(o2, dirn[again], tm)
            tri[again], t[again] = tri2, t2 + np.float32(nudge)
            u[again], v[again] = u2, v2
        return tri, t, u, v


def edge_distance(tris: np.ndarray, org, dirn, t) -> np.ndarray:
    """For rays hitting triangles ``tris`` (K,3,3) at parameter t: the smallest barycentric
    coordinate of the hit point (float64), i.e. how close to an edge or vertex the ray passes
    (0 = on an edge; negative = just outside)."""
    p = org.astype(np.float64) + t[:, None].astype(np.float64) * dirn.astype(np.float64)
    a, b, c = (tris[:, i].astype(np.float64) for i in range(3))
    n = np.cross(b - a, c - a)
    area = np.einsum("ij,ij->i", n, n)
    wa = np.einsum("ij,ij->i", np.cross(c - b, p - b), n) / area
    wb = np.einsum("ij,ij->i", np.cross(a - c, p - c), n) / area
    return np.minimum(np.minimum(wa, wb), 1 - wa - wb)


def compare(model_hits, embree_hits, rays_org, rays_dir, tris_by_id, closest=None,
            t_rel=1e-5, edge_eps=1e-4, t_start=1e-5) -> dict:
    """Compare the golden model's hits with Embree's; explain every disagreement.

    ``closest``: per ray, whether the closest hit is wanted (False for any-hit shadow rays:
    only hit/miss is compared). A hit/miss disagreement is *explained* when the ray passes
    within ``edge_eps`` (barycentric) of an edge or vertex of the triangle the other side hit
    ("edge"), or when that hit lies at ``t <= t_start`` (in units of the ray's direction
    length), i.e. the ray starts on a surface and the two treat its start differently
    ("origin").
    """
    m_tri, m_t = model_hits[0], model_hits[1]
    e_tri, e_t = embree_hits[0], embree_hits[1]
    n = len(m_tri)
    closest = np.ones(n, bool) if closest is None else closest
    mh, eh = m_tri >= 0, e_tri >= 0
    disagree = np.nonzero(mh != eh)[0]
    explained = np.zeros(len(disagree), bool)
    reason = [""] * len(disagree)
    margin = np.full(len(disagree), np.nan)
    for j, r in enumerate(disagree):
        tri_id, t = (m_tri[r], m_t[r]) if mh[r] else (e_tri[r], e_t[r])
        tri = tris_by_id[tri_id][None]
        margin[j] = edge_distance(tri, rays_org[r:r + 1], rays_dir[r:r + 1], np.array([t]))[0]
        if abs(margin[j]) <= edge_eps:
            reason[j] = "edge"
        elif t <= t_start:
            reason[j] = "origin"
        explained[j] = bool(reason[j])
    both = np.nonzero(mh & eh & closest)[0]
    rel = np.abs(m_t[both].astype(np.float64) - e_t[both]) / np.abs(e_t[both].astype(np.float64))
    t_far = both[rel > t_rel]
    # |t - t_embree| > t_rel * t happens for hits very close to the origin, where float32's
    # absolute error (an ulp of the coordinates) dominates; such a t is explained when the
    # model is as close to the exact (float64) plane distance as Embree is, or within 4 ulps
    # of the coordinates' magnitude.
    t_ok = np.zeros(len(t_far), bool)
    for j, r in enumerate(t_far):
        tri = tris_by_id[m_tri[r]].astype(np.float64)
        o, d = rays_org[r].astype(np.float64), rays_dir[r].astype(np.float64)
        nrm = np.cross(tri[1] - tri[0], tri[2] - tri[0])
        t64 = np.dot(nrm, tri[0] - o) / np.dot(nrm, d)
        scale = max(np.abs(tri).max(), np.abs(o).max())
        bound = max(abs(float(e_t[r]) - t64), 4 * np.spacing(np.float32(scale)) / np.linalg.norm(d))
        t_ok[j] = abs(float(m_t[r]) - t64) <= bound
    t_bad = t_far[~t_ok]
    return {
        "rays": int(n),
        "hit_agreement": float(1 - len(disagree) / max(n, 1)),
        "disagreements": int(len(disagree)),
        "disagreements_explained": int(explained.sum()),
        "unexplained_rays": disagree[~explained].tolist(),
        "explanations": {k: reason.count(k) for k in ("edge", "origin") if k in reason},
        "disagreement_margins": margin.tolist(),
        "both_hit": int(len(both)),
        "t_max_rel_error": float(rel.max()) if len(rel) else 0.0,
        "t_beyond_rel_tolerance": int(len(t_far)),
        "t_beyond_explained": int(t_ok.sum()),
        "t_errors": t_bad.tolist(),
        "same_triangle": float((m_tri[both] == e_tri[both]).mean()) if len(both) else 1.0,
    }
