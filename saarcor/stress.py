"""Numerical stress cases for the golden model and the RTC, judged by the exact oracle.

Each case is a small scene plus a ray set built so that one numerical corner happens for
sure (a hit at exactly a leaf's far distance, a ray through a shared edge, a zero direction
component, ...). The expected answer is :mod:`saarcor.exact`'s integer arithmetic on the case's
triangles, never another float tracer. ``saarcor bench stress`` runs the big versions and writes
``build/bench/stability.json``; ``tests/test_stress.py`` runs the small ones, on the model and
(through Verilator) on the RTC.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

import numpy as np

from model.config import Config
from model.kdtree import KdTree, build_kdtree
from model.layout import LEAF
from model.layout import build_image
from model.raygen import Rays, setup
from model.rtc import counter_totals, trace

from saarcor.exact import ExactHits, exact_closest, exact_pairs, moller_trumbore32
from saarcor.outputs import write_atomic

ROOT = Path(__file__).resolve().parent.parent


# --- building blocks ----------------------------------------------------------------------------

def tree_from_leaves(tris: np.ndarray, nodes: list) -> KdTree:
    """A kd-tree given node by node: ``("split", axis, value, left_child)`` or
    ``("leaf", [triangle indices])``, node 0 the root, children adjacent (right = left + 1).

    Checks the builder's placement rule (``docs/architecture.md``; ``model/kdtree.py``): a
    triangle is listed in every leaf whose closed box its bounding box touches (a triangle in a
    split plane is on both sides), so the tree is one the builder could produce."""
    n = len(nodes)
    axis = np.full(n, LEAF, np.uint8)
    split = np.zeros(n, np.float32)
    child = np.zeros(n, np.int32)
    first = np.zeros(n, np.int32)
    count = np.zeros(n, np.int32)
    lists = []
    for i, nd in enumerate(nodes):
        if nd[0] == "split":
            axis[i], split[i], child[i] = nd[1], nd[2], nd[3]
        else:
            first[i], count[i] = sum(len(x) for x in lists), len(nd[1])
            lists.append(list(nd[1]))
    lo = tris.min(axis=(0, 1)).astype(np.float32)
    hi = tris.max(axis=(0, 1)).astype(np.float32)
    tmin, tmax = tris.min(axis=1), tris.max(axis=1)

    def check(i, blo, bhi, depth):
        if axis[i] == LEAF:
            listed = set(int(x) for x in nodes[i][1])
            touch = set(np.flatnonzero(np.all((tmin <= bhi) & (tmax >= blo), axis=1)).tolist())
            if listed != touch:
                raise ValueError(f"leaf {i} lists {sorted(listed)}, the placement rule gives "
                                 f"{sorted(touch)}")
            return depth
        a, s, c = axis[i], split[i], child[i]
        lhi, rlo = bhi.copy(), blo.copy()
        lhi[a], rlo[a] = s, s
        return max(check(c, blo, lhi, depth + 1), check(c + 1, rlo, bhi, depth + 1))

    depth = check(0, lo, hi, 0)
    tri_list = np.array([x for xs in lists for x in xs], np.int32)
    return KdTree(axis=axis, split=split, child=child, first=first, count=count,
                  tri_list=tri_list, bounds=np.stack([lo, hi]), depth=depth)


def image_of(tris, cfg: Config, tree: KdTree | None = None):
    """(quantized tris, memory image) with the builder's tree unless ``tree`` is given."""
    tris = cfg.fmt.quantize(np.asarray(tris, np.float64)).astype(np.float32)
    if tree is None:
        tree = build_kdtree(tris, cfg, cache_dir=None)
    return tris, build_image(tris, tree, cfg)


def single_t(tri, org, dirn, cfg: Config) -> np.ndarray:
    """The model's t for each ray against one triangle alone (inf: no hit)."""
    _, img = image_of(np.asarray(tri)[None], cfg, tree_from_leaves(
        cfg.fmt.quantize(np.asarray(tri, np.float64)[None]).astype(np.float32), [("leaf", [0])]))
    hits, _ = trace(img, Rays.from_arrays(org, dirn), cfg)
    return hits.t


# --- the tie case: a hit at exactly the leaf's far distance ------------------------------------

@dataclass
class Case:
    """A scene (tris, image) and rays, with what the exact oracle says about them."""
    name: str
    tris: np.ndarray
    image: object
    rays: Rays
    exact: ExactHits | None = None
    info: dict = field(default_factory=dict)


TIE_SPLIT_Z = 0.0


def tie_scene(frac_bits: int = 23) -> tuple[np.ndarray, list]:
    """Four triangles and a one-split tree (z = 0, as the builder's rule places them):

    * P in the plane z = 0 (listed in both leaves),
    * Q just below it, tilted, entirely in z < 0 (only in the lower leaf),
    * G a ground triangle at z = -8 and R a triangle at z = 8 off to the side (they give the
      scene box room in z; R is away from every ray).

    Rays come from z = 4 downwards: the upper leaf (z >= 0) is the near one. A ray hitting P at
    exactly the split distance must end in the near leaf (``t <= tfar``); a traversal that uses
    ``t < tfar`` goes on into the lower leaf, where Q's rounded t can be below P's (its exact t
    is larger), and reports Q."""
    P = [[-4.0, -4.0, 0.0], [4.0, -3.5, 0.0], [-0.5, 4.0, 0.0]]
    e = 2.0 ** -frac_bits                   # Q's depth scales with the format's resolution
    Q = [[-4.0, -4.0, -2 * e], [4.0, -3.5, -e], [-0.5, 4.0, -3 * e]]
    G = [[-16.0, -16.0, -8.0], [16.0, -16.0, -8.0], [0.0, 16.0, -8.0]]
    R = [[12.0, 12.0, 8.0], [13.0, 12.0, 8.0], [12.0, 13.0, 8.0]]
    tris = np.array([P, Q, G, R], np.float64)
    nodes = [("split", 2, TIE_SPLIT_Z, 1), ("leaf", [0, 1, 2]), ("leaf", [0, 3])]
    return tris, nodes


def tie_case(cfg: Config, n: int = 16, seed: int = 0, packet: int = 16) -> Case:
    """``n`` rays for which the model's t on P equals the near leaf's tfar bit for bit and Q's
    rounded t is smaller than P's (found by a seeded search)."""
    fmt = cfg.fmt
    raw, nodes = tie_scene(fmt.frac_bits)
    tris = fmt.quantize(raw).astype(np.float32)
    tree = tree_from_leaves(tris, nodes)
    _, image = image_of(tris, cfg, tree)
    rng = np.random.default_rng(seed)
    got_o, got_d = [], []
    for _ in range(50):
        m = 20000
        org = fmt.quantize(np.c_[rng.uniform(-1.5, 1.5, (m, 2)), np.full(m, 4.0)])
        dirn = fmt.quantize(np.c_[rng.uniform(-0.3, 0.3, (m, 2)), -rng.uniform(0.5, 2.0, m)])
        rays = Rays.from_arrays(org, dirn)
        rs = setup(rays, image.bounds, fmt)
        dist = fmt.mul(fmt.sub(np.float32(TIE_SPLIT_Z), org[:, 2]), rs.inv[:, 2])
        tp = single_t(tris[0], org, dirn, cfg)
        tq = single_t(tris[1], org, dirn, cfg)
        ok = np.isfinite(tp) & (tp == dist) & (tq < tp)
        got_o.append(org[ok])
        got_d.append(dirn[ok])
        if sum(len(x) for x in got_o) >= n:
            break
    org, dirn = np.concatenate(got_o)[:n], np.concatenate(got_d)[:n]
    if len(org) < n:
        raise RuntimeError(f"tie search found {len(org)} of {n} rays in format {fmt}")
    rays = Rays.from_arrays(org, dirn, packet=packet)
    return Case("tie_t_eq_tfar", tris, image, rays, exact_closest(tris, org, dirn))


# --- judging a tracer's hits against the exact oracle ------------------------------------------

def judge(tris, org, dirn, tri, t, candidates, tmax=None, rel_tol: float = 2.0 ** -20) -> dict:
    """Compare per-ray hits ``tri`` / ``t`` (any tracer) with the exact closest hit among each
    ray's ``candidates`` (the tracer's own triangle is added to them).

    * ``leaks``: the exact answer is a hit, the tracer reports none;
    * ``ghosts``: the tracer reports a hit, exactly the ray hits none of the candidates;
    * ``other_tri``: both hit, the tracer's triangle is not among the exactly closest ones
      (a neighbour across an edge the ray passes within an ulp of, or a near tie);
      ``other_tri_far``: of those, the ones whose plane the ray meets more than ``rel_tol``
      (relative) away from the exact closest t (the tracer went through or stopped short);
    * ``t_rel_max``: largest |t - t_exact| / t_exact where both agree on the triangle."""
    tri = np.asarray(tri, np.int64)
    cands = [np.unique(np.r_[np.asarray(c, np.int64), [tri[i]] if tri[i] >= 0 else []]).astype(
        np.int64) for i, c in enumerate(candidates)]
    ex = exact_closest(tris, org, dirn, cands, tmax)
    got = tri >= 0
    leaks = ex.hit & ~got
    ghosts = ~ex.hit & got
    both = np.flatnonzero(ex.hit & got)
    other = [i for i in both if int(tri[i]) not in ex.ties[i]]
    far = []
    if other:
        # the tracer's triangle, exactly: where its plane meets the ray (inside the triangle
        # or, for a near-edge choice, just beside it)
        _, num, den = exact_pairs(tris, org, dirn, np.array(other), tri[other], None)
        for j, i in enumerate(other):
            if den[j] == 0:
                far.append(i)
                continue
            te = Fraction(int(num[j]), int(den[j]))
            if abs(te - ex.t[i]) > ex.t[i] * Fraction(rel_tol):
                far.append(i)
    same = [i for i in both if int(tri[i]) in ex.ties[i]]
    rel = [abs(Fraction(float(t[i])) - ex.t[i]) / ex.t[i] for i in same]
    return {"rays": int(len(tri)), "exact_hits": int(ex.hit.sum()), "leaks": int(leaks.sum()),
            "ghosts": int(ghosts.sum()), "other_tri": len(other), "other_tri_far": len(far),
            "t_rel_max": float(max(rel)) if rel else 0.0,
            "leak_rays": np.flatnonzero(leaks)[:8].tolist(),
            "ghost_rays": np.flatnonzero(ghosts)[:8].tolist(), "far_rays": far[:8]}


def model_judge(case: Case, cfg: Config, candidates=None) -> tuple[dict, dict]:
    """Trace the case on the golden model and judge it (near ties within 8 ulps of the format);
    returns (verdict, counter totals)."""
    hits, ctrs = trace(case.image, case.rays, cfg)
    n = len(case.rays)
    cands = candidates if candidates is not None else case.info.get(
        "candidates", [np.arange(len(case.tris))] * n)
    v = judge(case.tris, case.rays.org, case.rays.dir, hits.tri, hits.t, cands, case.rays.tmax,
              rel_tol=2.0 ** (3 - cfg.fmt.frac_bits))
    return v, counter_totals(ctrs)


# --- closed meshes and rays exactly through their edges and vertices ---------------------------

def closed_meshes() -> dict:
    """Closed procedural meshes (trimesh), vertices snapped to a 2^-6 grid."""
    import trimesh
    out = {}
    for name, make in {
        "icosphere": lambda: trimesh.creation.icosphere(subdivisions=3, radius=2.0),
        "box": lambda: trimesh.creation.box(extents=(2.0, 3.0, 1.0)).subdivide().subdivide(),
        "cylinder": lambda: trimesh.creation.cylinder(radius=1.0, height=3.0, sections=40),
    }.items():
        m = make()
        m.vertices = np.round(m.vertices * 64) / 64
        m.merge_vertices()
        m.update_faces(m.nondegenerate_faces())
        assert m.is_watertight, name
        out[name] = m
    return out


def _stars(faces: np.ndarray, n_vertices: int) -> list:
    """Faces around each vertex."""
    star = [[] for _ in range(n_vertices)]
    for f, tri in enumerate(faces):
        for v in tri:
            star[v].append(f)
    return [np.array(s, np.int64) for s in star]


def watertight_case(mesh, cfg: Config, n_max: int = 2000, seed: int = 0, scale: float = 1.0,
                    offset: float = 0.0, packet: int = 64, name: str = "watertight",
                    exact: bool = True) -> Case:
    """Rays from outside through mesh vertices and exact edge midpoints, each entering the
    surface there (against the normal of every face around its target), with directions on a
    2^-5 grid so that, at scale 1 and offset 0, the ray passes *exactly* through its target at
    t = 8. With ``scale``/``offset`` the mesh is moved (x' = x*scale + offset, then rounded to
    the format); targets, origins and directions are rounded too, so rays pass within an ulp of
    their targets. ``exact=False``: edge targets at random points of the edges and unit
    directions, all rounded (the rays pass within an ulp of the edge, on either side: the case
    that breaks a non-watertight test). ``info["candidates"]``: per ray the faces around its target's neighbourhood
    (every face a ray through that point can enter by)."""
    fmt = cfg.fmt
    rng = np.random.default_rng(seed)
    v = fmt.quantize(mesh.vertices * scale + offset)
    faces = np.asarray(mesh.faces)
    tris = fmt.quantize(v[faces]).astype(np.float32)
    fn = np.cross(mesh.vertices[faces[:, 1]] - mesh.vertices[faces[:, 0]],
                  mesh.vertices[faces[:, 2]] - mesh.vertices[faces[:, 0]])
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    star = _stars(faces, len(v))
    edges = np.asarray(mesh.edges_unique)
    # targets: vertices, then exact midpoints (in unscaled coordinates)
    f = 0.5 if exact else rng.uniform(0.05, 0.95, (len(edges), 1))
    pts0 = np.concatenate([mesh.vertices, (1 - f) * mesh.vertices[edges[:, 0]] +
                           f * mesh.vertices[edges[:, 1]]])
    around = star + [np.intersect1d(star[a], star[b]) for a, b in edges]
    hood = [np.unique(np.concatenate([star[x] for x in faces[s].ravel()])) for s in around]
    org, dirn, cands = [], [], []
    for k in rng.permutation(len(pts0)):
        nsum = fn[around[k]].sum(axis=0)
        for _ in range(8):
            w = nsum / np.linalg.norm(nsum) + 0.5 * rng.normal(size=3)
            if exact:
                w = np.round(w / np.abs(w).max() * 32) / 32      # a 2^-5 grid, |w|_inf = 1
            if np.all(fn[around[k]] @ w > 0.05 * np.linalg.norm(w)):
                break
        else:
            continue
        target = pts0[k] * scale + offset
        o = fmt.quantize(target + 8 * w * scale)
        if exact and scale == 1.0 and offset == 0.0:
            d = -w                                                 # exact: o + 8 d = target
        else:
            d = fmt.quantize(fmt.quantize(target) - o)
        org.append(o)
        dirn.append(d)
        cands.append(hood[k])
        if len(org) == n_max:
            break
    org = fmt.quantize(np.array(org))
    dirn = fmt.quantize(np.array(dirn))
    _, image = image_of(tris, cfg)
    rays = Rays.from_arrays(org, dirn, packet=packet)
    return Case(name, tris, image, rays, info={"candidates": cands})


def mt_leaks(case: Case) -> dict:
    """The plain float32 Möller–Trumbore baseline on a watertight case's rays: a leak is a ray
    that hits none of the faces around its target (it slips between them)."""
    cands = case.info["candidates"]
    ray = np.concatenate([np.full(len(c), i) for i, c in enumerate(cands)])
    cand = np.concatenate(cands)
    hit, _ = moller_trumbore32(case.tris, case.rays.org, case.rays.dir, ray, cand)
    any_hit = np.bincount(ray[hit], minlength=len(cands)) > 0
    return {"rays": len(cands), "leaks": int((~any_hit).sum())}


# --- special rays on an axis-aligned box -----------------------------------------------------

def _signed_zero(rng, n):
    return np.where(rng.random(n) < 0.5, -0.0, 0.0)


def special_rays_case(cfg: Config, n_each: int = 64, seed: int = 0, packet: int = 64) -> Case:
    """The box [-1, 1]^3 (each face 4x4 quads, vertices on a 0.5 grid) and four groups of rays
    (``info["groups"]`` names each ray's group):

    * ``axis``: directions along an axis, the other components +0 or -0 at random (infinite
      reciprocals of both signs), aimed at 0.25-grid points: many pass exactly through edges
      and vertices;
    * ``split_plane``: origins in a split plane of the builder's kd-tree, direction component
      along that axis +0 or -0 (the ray lies in the plane: both children are needed);
    * ``grazing``: origins in the plane of a box face, direction inside that plane (det = 0 for
      that face's triangles; the ray meets the side faces exactly on their edge);
    * ``on_surface``: origins exactly on the surface (faces, edges, vertices), half pointing
      out (exactly: no hit, t = 0 is not a hit), half pointing in (the opposite side)."""
    import trimesh
    fmt = cfg.fmt
    rng = np.random.default_rng(seed)
    m = trimesh.creation.box(extents=(2.0, 2.0, 2.0)).subdivide().subdivide()
    tris = fmt.quantize(m.vertices[m.faces]).astype(np.float32)
    _, image = image_of(tris, cfg)
    from model.kdtree import build_kdtree as _bk
    tree = _bk(tris, cfg, cache_dir=None)
    grid = lambda k, step, lim: np.round(rng.uniform(-lim, lim, k) / step) * step  # noqa: E731
    org, dirn, group = [], [], []
    # axis-parallel
    for _ in range(n_each):
        a = rng.integers(3)
        sgn = rng.choice([-1.0, 1.0])
        o = grid(3, 0.25, 1.25)
        o[a] = -3 * sgn
        d = _signed_zero(rng, 3)
        d[a] = sgn * rng.choice([1.0, 0.5, 3.0])
        org.append(o), dirn.append(d), group.append("axis")
    # in a split plane
    inner = np.flatnonzero(tree.axis != LEAF)
    for _ in range(n_each):
        nd = rng.choice(inner) if inner.size else 0
        a, sv = int(tree.axis[nd]) % 3, float(tree.split[nd])
        o = grid(3, 0.125, 1.5)
        o[a] = sv
        d = grid(3, 0.125, 1.0)
        d[a] = _signed_zero(rng, 1)[0]
        if not d.any():
            d[(a + 1) % 3] = 1.0
        org.append(o), dirn.append(d), group.append("split_plane")
    # grazing along a face's plane
    for _ in range(n_each):
        a = rng.integers(3)
        o = grid(3, 0.25, 2.5)
        o[a] = rng.choice([-1.0, 1.0])
        d = grid(3, 0.125, 1.0)
        d[a] = _signed_zero(rng, 1)[0]
        if not d.any():
            d[(a + 1) % 3] = -1.0
        org.append(o), dirn.append(d), group.append("grazing")
    # starting on the surface
    for i in range(n_each):
        a = rng.integers(3)
        o = grid(3, 0.25, 1.0)
        side = rng.choice([-1.0, 1.0])
        o[a] = side
        d = grid(3, 0.125, 1.0)
        d[a] = side * (0.5 + rng.integers(4) / 4) * (1 if i % 2 else -1)
        org.append(o), dirn.append(d), group.append("on_surface")
    org = fmt.quantize(np.array(org))
    dirn = fmt.quantize(np.array(dirn))
    rays = Rays.from_arrays(org, dirn, packet=packet)
    return Case("special_rays", tris, image, rays,
                info={"groups": np.array(group), "tree_depth": tree.depth})


# --- slivers, degenerate, coincident and overlapping triangles ---------------------------------

DEGENERATE_GROUPS = ("sliver", "near_degenerate", "zero_area", "repeated_vertex", "duplicate",
                     "rotated", "reversed", "overlap")


def degenerate_case(cfg: Config, n_each: int = 48, seed: int = 0, packet: int = 64) -> Case:
    """One group of triangles per kind, 4 apart in x (``info["tri_group"]``), rays from above
    aimed at random points of each group's bounding box, slightly tilted:

    sliver (aspect ratio 1e6), near_degenerate (apex 2^-30 off the base), zero_area (collinear
    vertices), repeated_vertex (A == B), duplicate (the same triangle twice, bit for bit),
    rotated (the same triangle with its vertices rotated), reversed (opposite winding),
    overlap (two coplanar triangles overlapping in part)."""
    fmt = cfg.fmt
    rng = np.random.default_rng(seed)
    base = np.array([[0.0, 0.0, 0.0], [2.0, 0.25, 0.0], [0.5, 2.0, 0.0]])
    groups = {
        "sliver": [[[0, 0, 0], [2, 0, 0], [1, 2e-6, 0]]],
        "near_degenerate": [[[0, 0, 0], [2, 0, 0], [1, 2.0 ** -30, 0]]],
        "zero_area": [[[0, 0, 0], [1, 0.5, 0], [2, 1, 0]]],
        "repeated_vertex": [[[0, 0, 0], [0, 0, 0], [1, 2, 0]]],
        "duplicate": [base, base],
        "rotated": [base, base[[1, 2, 0]]],
        "reversed": [base, base[[0, 2, 1]]],
        "overlap": [base, base * 0.75 + [0.5, 0.25, 0]],
    }
    tris, tri_group, org, dirn, ray_group = [], [], [], [], []
    for g, name in enumerate(DEGENERATE_GROUPS):
        shift = np.array([4.0 * g, 0.0, 0.3 * g])        # the planes differ in height too
        ts = np.asarray(groups[name], np.float64) + shift
        tris += list(ts)
        tri_group += [name] * len(ts)
        lo, hi = ts.min(axis=(0, 1)), ts.max(axis=(0, 1))
        if name in ("sliver", "near_degenerate"):        # aim at the sliver itself
            f = rng.random((n_each, 1))
            p = ts[0, 0] * (1 - f) + ts[0, 1] * f + [0, 1e-6, 0] * rng.random((n_each, 1))
        else:
            p = lo + (hi - lo) * rng.random((n_each, 3))
        d = np.c_[rng.normal(0, 0.05, (n_each, 2)), -np.ones(n_each)]
        org += list(p - 3 * d)
        dirn += list(d)
        ray_group += [name] * n_each
    tris = fmt.quantize(np.array(tris)).astype(np.float32)
    _, image = image_of(tris, cfg)
    rays = Rays.from_arrays(fmt.quantize(np.array(org)), fmt.quantize(np.array(dirn)), packet=packet)
    return Case("degenerate", tris, image, rays,
                info={"tri_group": np.array(tri_group), "groups": np.array(ray_group)})


# --- secondary rays off a convex mesh ----------------------------------------------------------

def self_intersection(mesh, cfg: Config, n: int = 4000, seed: int = 0, scale: float = 1.0,
                      offset: float = 0.0, eps_rel: float = 0.0) -> dict:
    """Eye rays onto a convex closed mesh, then from each hit point ``p = o + t*d`` (format
    arithmetic) a shadow ray toward a light on the lit side of the hit triangle and a mirror
    reflection. On a convex mesh both must miss: every hit is false (self-intersection).
    ``eps_rel``: the origin is moved off the surface by eps_rel x the box diagonal along the
    normal (0: the raw hit point)."""
    fmt = cfg.fmt
    rng = np.random.default_rng(seed)
    v = fmt.quantize(mesh.vertices * scale + offset)
    tris = fmt.quantize(v[np.asarray(mesh.faces)]).astype(np.float32)
    _, image = image_of(tris, cfg)
    c = tris.reshape(-1, 3).mean(axis=0)
    r = np.ptp(tris.reshape(-1, 3), axis=0).max()
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    org = fmt.quantize(c + 3 * r * u)
    aim = c + 0.45 * r * rng.uniform(-1, 1, (n, 3))
    dirn = fmt.quantize(aim - org)
    hits, _ = trace(image, Rays.from_arrays(org, dirn), cfg)
    h = np.flatnonzero(hits.tri >= 0)
    t = hits.t[h]
    p = np.stack([fmt.add(org[h, a], fmt.mul(t, dirn[h, a])) for a in range(3)], axis=1)
    tri = tris[hits.tri[h]].astype(np.float64)
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    nrm = np.where((np.sum(nrm * dirn[h], axis=1) > 0)[:, None], -nrm, nrm)
    if eps_rel:
        p = fmt.quantize(p + eps_rel * np.sqrt(3) * r * nrm)
    # light: beyond the surface along the normal, tilted (always on the lit side)
    lp = fmt.quantize(p + 2 * r * (nrm + 0.5 * rng.normal(size=nrm.shape) / 3))
    ld = np.stack([fmt.sub(lp[:, a], p[:, a]) for a in range(3)], axis=1)
    lit = np.sum(ld * nrm, axis=1) > 0
    sh, _ = trace(image, Rays.from_arrays(p[lit], ld[lit], tmax=np.ones(lit.sum()), kind=1), cfg)
    dn = np.sum(dirn[h] * nrm, axis=1, keepdims=True)
    rd = fmt.quantize(dirn[h] - 2 * dn * nrm)
    rf, _ = trace(image, Rays.from_arrays(p, rd, kind=2), cfg)
    own = rf.tri == hits.tri[h]
    return {"hit_points": int(len(h)), "shadow_rays": int(lit.sum()),
            "false_shadow_hits": int((sh.tri >= 0).sum()), "reflection_rays": int(len(h)),
            "reflection_hits": int((rf.tri >= 0).sum()), "reflection_own_triangle": int(own.sum())}


# --- bench ---------------------------------------------------------------------------------------

FORMATS = ((8, 23), (8, 16), (8, 12))


def bench(n_max: int, formats, meshes: dict, log=None, int_test: str = "watertight") -> dict:
    """Every case per format; ``int_test``: the triangle test (``Config.int_test``)."""
    log = sys.stderr if log is None else log
    from model.fp import FPFormat
    out: dict = {"formats": [f"E{e}M{m}" for e, m in formats], "int_test": int_test}
    t0 = time.perf_counter()
    wt = {"rays": 0, "leaks": 0, "mt_leaks": 0, "other_tri_far": 0, "cases": []}
    for e, m in formats:
        cfg = Config(fmt=FPFormat(e, m), int_test=int_test)
        for name, mesh in meshes.items():
            for exact in (True, False):
                case = watertight_case(mesh, cfg, n_max=n_max, exact=exact)
                v, _ = model_judge(case, cfg)
                mt = mt_leaks(case)
                row = {"mesh": name, "format": f"E{e}M{m}", "exact_targets": exact,
                       "rays": v["rays"], "leaks": v["leaks"], "ghosts": v["ghosts"],
                       "other_tri": v["other_tri"], "other_tri_far": v["other_tri_far"],
                       "t_rel_max": v["t_rel_max"], "mt_leaks": mt["leaks"]}
                wt["cases"].append(row)
                for k, k2 in (("rays", "rays"), ("leaks", "leaks"), ("mt_leaks", "mt_leaks"),
                              ("other_tri_far", "other_tri_far")):
                    wt[k] += row[k2]
                print(f"watertight {name} E{e}M{m} exact={exact}: {row}", file=log)
    out["watertight"] = wt
    out["special_rays"], out["degenerate"], out["tie_t_eq_tfar"] = {}, {}, {}
    for e, m in formats:
        cfg = Config(fmt=FPFormat(e, m), int_test=int_test)
        key = f"E{e}M{m}"
        case = special_rays_case(cfg, n_each=256)
        out["special_rays"][key] = model_judge(case, cfg)[0]
        case = degenerate_case(cfg, n_each=256)
        v, _ = model_judge(case, cfg)
        g = case.info["groups"]
        hits, _ = trace(case.image, case.rays, cfg)
        per = {}
        for name in DEGENERATE_GROUPS:
            s = np.flatnonzero(g == name)
            per[name] = judge(case.tris, case.rays.org[s], case.rays.dir[s], hits.tri[s],
                              hits.t[s], [np.arange(len(case.tris))] * len(s))
        out["degenerate"][key] = per
        try:
            case = tie_case(cfg, n=64, packet=64)
        except RuntimeError as e:      # the search is tuned to the watertight test's rounding
            out["tie_t_eq_tfar"][key] = {"not_found": str(e)}
        else:
            v, ctr = model_judge(case, cfg)
            out["tie_t_eq_tfar"][key] = {**v, "leaf_visits": ctr["leaf_visits"],
                                         "passes": ctr["passes"]}
        print(f"special/degenerate/tie {key} done", file=log)
    # translated and scaled scenes
    ico = meshes.get("icosphere", next(iter(meshes.values())))
    tr = []
    for e, m in formats:
        cfg = Config(fmt=FPFormat(e, m), int_test=int_test)
        for kind, values in (("offset", (0.0, 1e5, 1e6, 1e7)),
                             ("scale", (1e-6, 1e-3, 1e3, 1e6))):
            for val in values:
                kw = {"offset": val} if kind == "offset" else {"scale": val}
                case = watertight_case(ico, cfg, n_max=min(n_max, 2000), exact=False, **kw)
                v, _ = model_judge(case, cfg)
                tq = case.tris.astype(np.float64)
                area2 = np.linalg.norm(np.cross(tq[:, 1] - tq[:, 0], tq[:, 2] - tq[:, 0]), axis=1)
                row = {"format": f"E{e}M{m}", kind: val, "rays": v["rays"],
                       "leaks": v["leaks"], "ghosts": v["ghosts"], "other_tri": v["other_tri"],
                       "other_tri_far": v["other_tri_far"], "t_rel_max": v["t_rel_max"],
                       "zero_area_tris": int((area2 == 0).sum()), "tris": len(tq),
                       "mt_leaks": mt_leaks(case)["leaks"],
                       "self_raw": self_intersection(ico, cfg, n=1000, **kw),
                       "self_eps1e-4": self_intersection(ico, cfg, n=1000, eps_rel=1e-4, **kw)}
                tr.append(row)
                print(f"transform {row}", file=log)
    out["transform"] = tr
    out["seconds"] = time.perf_counter() - t0
    return out


def main(argv=None) -> int:
    from model.config import ConfigError
    from saarcor.args import add_formats_arg, add_out_arg, add_scene_arg, parse_formats
    ap = argparse.ArgumentParser(
        prog="saarcor bench stress",
        description="Numerical stress bench of the golden model against the exact oracle "
                    "(saarcor/exact.py): rays through shared edges and vertices of closed meshes "
                    "(leaks, and the leaks of a float32 Möller–Trumbore baseline on the same "
                    "rays), axis-parallel / split-plane / grazing / on-surface rays, slivers and "
                    "degenerate / coincident triangles, the t == tfar tie, translated and scaled "
                    "scenes and secondary-ray self-intersection, per FP format. Writes "
                    "OUT/stability.json (one entry per case).")
    add_out_arg(ap)
    ap.add_argument("--rays", type=int, default=20000,
                    help="at most this many rays per closed mesh and format (default 20000)")
    add_formats_arg(ap, ",".join(f"E{e}M{m}" for e, m in FORMATS))
    from model.config import INT_TESTS
    ap.add_argument("--int-test", default="watertight", choices=INT_TESTS,
                    help="the triangle test (Config.int_test; default watertight)")
    add_scene_arg(ap, None, repeat=True,
                  help="an extra closed mesh file (OBJ/PLY/STL) for the watertightness cases; "
                       "it must be watertight")
    args = ap.parse_args(argv)
    try:
        formats = [(f.exp_bits, f.frac_bits) for f in parse_formats(args.formats)]
    except (ConfigError, ValueError) as e:
        ap.error(str(e))
    if args.rays < 1:
        ap.error("--rays must be >= 1")
    meshes = closed_meshes()
    for path in args.scene:
        import trimesh
        m = trimesh.load(path, force="mesh", process=True)
        if not m.is_watertight:
            ap.error(f"--scene {path}: the mesh is not watertight (closed); leaks would mean "
                     "nothing on it")
        meshes[Path(path).stem] = m
    res = bench(args.rays, formats, meshes, int_test=args.int_test)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_atomic(out / "stability.json", json.dumps(res, indent=1, default=float))
    w = res["watertight"]
    print(f"watertight: {w['rays']} rays, {w['leaks']} leaks (float32 Möller–Trumbore: "
          f"{w['mt_leaks']}); {out / 'stability.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
