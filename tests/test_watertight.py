"""Watertightness: rays aimed exactly at shared edges and vertices of closed meshes.

Each ray comes from outside, along the surface normal at its target (tilted at random), and
passes through a mesh vertex or a point of a shared edge. A closed mesh has no gaps, so every
such ray must hit some triangle; a miss means the ray slipped between two triangles.
"""
import numpy as np
import pytest
import trimesh

from model.config import Config
from model.fp import FPFormat
from model.kdtree import build_kdtree
from model.layout import build_image
from model.rtc import trace

from .conftest import SHARED_MESHES, needs_shared_meshes
from .test_rtc_model import rays_from


def targets(mesh: trimesh.Trimesh, fmt, rng):
    """Vertices and points on shared edges (rounded to the format), each with the unit normals
    of the faces around it."""
    v = fmt.quantize(mesh.vertices)
    faces = mesh.faces
    fn = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    # faces around each vertex / each edge, as a padded (K, max) table (-1 = none)
    flat = faces.ravel()
    order = np.argsort(flat, kind="stable")
    deg = np.bincount(flat, minlength=len(v))
    start = np.concatenate([[0], np.cumsum(deg)[:-1]])
    rank = np.arange(len(flat)) - start[flat[order]]
    vf = np.full((len(v), deg.max()), -1)
    vf[flat[order], rank] = order // 3
    edges = mesh.edges_unique
    ef = np.full((len(edges), 2), -1)
    inv = np.asarray(mesh.edges_unique_inverse).reshape(-1, 3)
    slot = np.zeros(len(edges), int)
    for k in range(3):
        e = inv[:, k]
        order = np.argsort(e, kind="stable")
        for f_i in order:                                  # at most 2 faces per edge
            ef[e[f_i], min(slot[e[f_i]], 1)] = f_i
            slot[e[f_i]] += 1
    f = rng.random((len(edges), 1))
    on_edge = fmt.quantize(v[edges[:, 0]] * (1 - f) + v[edges[:, 1]] * f)
    mid = fmt.quantize(0.5 * (v[edges[:, 0]] + v[edges[:, 1]]))
    pts = np.concatenate([v, on_edge, mid])
    w = max(vf.shape[1], 2)
    around = np.full((len(pts), w), -1)
    around[:len(v), :vf.shape[1]] = vf
    around[len(v):len(v) + len(edges), :2] = ef
    around[len(v) + len(edges):, :2] = ef
    return pts, around, fn


def shoot(mesh, fmt, n_max=20000, seed=0, tilt=0.5):
    """Rays from outside through vertices / edge points, each entering the surface there:
    its direction is against the normal of every face around its target (targets where a
    random tilted direction can't satisfy that, e.g. saddle vertices, are drawn again)."""
    rng = np.random.default_rng(seed)
    cfg = Config(fmt=fmt)
    tris = fmt.quantize(mesh.vertices[mesh.faces]).astype(np.float32)
    image = build_image(tris, build_kdtree(tris, cfg, cache_dir=None), cfg)
    pts, around, fn = targets(mesh, fmt, rng)
    valid = around >= 0
    nsum = np.where(valid[:, :, None], fn[np.maximum(around, 0)], 0).sum(axis=1)
    nsum /= np.linalg.norm(nsum, axis=1, keepdims=True)
    chosen, dirs = [], []
    for _ in range(8):
        w = nsum + tilt * rng.normal(size=nsum.shape)
        w /= np.linalg.norm(w, axis=1, keepdims=True)
        cos = np.einsum("kj,kmj->km", w, fn[np.maximum(around, 0)])
        enters = np.all(~valid | (cos > 0.05), axis=1)
        chosen.append(np.nonzero(enters)[0])
        dirs.append(w[enters])
    idx = np.concatenate(chosen)
    w = np.concatenate(dirs)
    idx, first = np.unique(idx, return_index=True)
    w = w[first]
    pick = rng.choice(len(idx), size=min(n_max, len(idx)), replace=False)
    target, w = pts[idx[pick]], w[pick]
    size = np.ptp(mesh.vertices, axis=0).max()
    org = fmt.quantize(target + 0.5 * size * w)
    dirn = np.stack([fmt.sub(target[:, a], org[:, a]) for a in range(3)], axis=1)
    hits, _ = trace(image, rays_from(org, dirn), cfg)
    return hits, len(org)


CLOSED = {
    "icosphere": lambda: trimesh.creation.icosphere(subdivisions=4, radius=2.0),
    "uv_sphere": lambda: trimesh.creation.uv_sphere(radius=1.5, count=[24, 24]),
    "box": lambda: trimesh.creation.box(extents=(2.0, 3.0, 1.0)).subdivide().subdivide(),
    "cylinder": lambda: trimesh.creation.cylinder(radius=1.0, height=3.0, sections=40),
}


@pytest.mark.parametrize("fmt", [FPFormat(8, 23), FPFormat(8, 12)], ids=str)
@pytest.mark.parametrize("name", sorted(CLOSED))
def test_no_ray_passes_through_closed_primitives(name, fmt):
    mesh = CLOSED[name]()
    assert mesh.is_watertight
    hits, n = shoot(mesh, fmt, n_max=6000)
    assert n >= min(6000, len(mesh.vertices))
    # the rounded direction passes the target within a few ulps of the format
    through = (hits.tri < 0) | (hits.t > 1 + 2.0 ** (6 - fmt.frac_bits))
    assert through.sum() == 0, f"{through.sum()} of {n} rays passed through"


@needs_shared_meshes
@pytest.mark.parametrize("name", ["dragon", "nefertiti"])
def test_no_ray_passes_through_real_closed_meshes(name):
    mesh = trimesh.load(SHARED_MESHES / f"{name}.obj", force="mesh", process=False)
    hits, n = shoot(mesh, FPFormat(8, 23), n_max=30000)
    assert n == 30000
    through = (hits.tri < 0) | (hits.t > 1 + 1e-4)
    assert through.sum() == 0, f"{through.sum()} of {n} rays passed through"


SIMPLE_DIRS = np.array([d for d in np.ndindex(3, 3, 3) if d != (1, 1, 1)], np.float64) - 1


@pytest.mark.parametrize("name", ["icosphere", "box", "cylinder"])
def test_exact_hits_on_edges_and_vertices(name):
    """Vertices snapped to a grid and rays with simple directions (components in {-1, 0, 1}):
    the ray passes *exactly* through its target vertex or edge midpoint, so edge functions
    are exactly zero on the shared edge — the case a non-watertight test gets wrong."""
    fmt = FPFormat(8, 23)
    cfg = Config(fmt=fmt)
    mesh = CLOSED[name]()
    mesh.vertices = np.round(mesh.vertices * 64) / 64          # on a 2^-6 grid
    mesh.merge_vertices()
    mesh.update_faces(mesh.nondegenerate_faces())
    rng = np.random.default_rng(1)
    pts, around, fn = targets(mesh, fmt, rng)
    n_v = len(mesh.vertices)
    n_e = len(mesh.edges_unique)
    keep = np.r_[np.arange(n_v), n_v + n_e + np.arange(n_e)]     # vertices and exact midpoints
    pts, around = pts[keep], around[keep]
    valid = around >= 0
    units = SIMPLE_DIRS / np.linalg.norm(SIMPLE_DIRS, axis=1, keepdims=True)
    cos = np.einsum("dj,kmj->kdm", units, fn[np.maximum(around, 0)])   # (K, dirs, faces)
    enters = np.all(~valid[:, None, :] | (cos > 0.05), axis=2)
    ok = np.nonzero(enters.any(axis=1))[0]
    choice = np.array([rng.choice(np.nonzero(enters[k])[0]) for k in ok])
    w = SIMPLE_DIRS[choice]
    target = pts[ok]
    org = target + 8.0 * w                                        # exact on the grid
    dirn = -w
    assert np.array_equal(fmt.quantize(org), org)
    tris = fmt.quantize(mesh.vertices[mesh.faces]).astype(np.float32)
    image = build_image(tris, build_kdtree(tris, cfg, cache_dir=None), cfg)
    hits, _ = trace(image, rays_from(org, dirn), cfg)
    assert len(ok) > 100
    through = (hits.tri < 0) | (hits.t > 8)                      # the target is at t = 8 exactly
    assert through.sum() == 0, f"{through.sum()} of {len(ok)} rays passed through"
