"""kd-tree builder: structure, format-exact splits, conservative classification (every triangle
reachable from every point on it), SAH, limits, disk cache."""
import time

import numpy as np
import pytest

from model.config import Config
from model.fp import FPFormat
from model.kdtree import KdTreeError, build_kdtree, kdtree_stats
from model.layout import build_image

from .conftest import SHARED_MESHES, needs_shared_meshes

LEAF = 3


# ---------------------------------------------------------------------------------------------
# scenes
# ---------------------------------------------------------------------------------------------

def soup(n, seed, size=0.3, extent=10.0, fmt=FPFormat()):
    rng = np.random.default_rng(seed)
    c = rng.random((n, 1, 3)) * extent
    return fmt.quantize(c + rng.normal(size=(n, 3, 3)) * size)


def sphere(fmt=FPFormat(), subdivisions=3):
    import trimesh
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=3.0)
    return fmt.quantize(m.vertices[m.faces] + np.array([1.0, -2.0, 0.5]))


def grid_scene(fmt=FPFormat()):
    """Axis-aligned quads on an integer grid: many vertices lie exactly on candidate planes."""
    tris = []
    for i in range(8):
        for j in range(8):
            a, b, c, d = [(i, j, 0), (i + 1, j, 0), (i + 1, j + 1, 0), (i, j + 1, 0)]
            tris += [(a, b, c), (a, c, d), ((i, 0, j), (i + 1, 0, j), (i, 0, j + 1))]
    return fmt.quantize(np.array(tris, np.float64))


def lattice(n=1200, seed=11, fmt=FPFormat()):
    """Vertices on a 1/4 lattice inside the box [0, 8]^3: bin boundaries (multiples of 8/32 and
    finer at depth) coincide with triangle bounds all the time, so the <= / >= rule matters."""
    rng = np.random.default_rng(seed)
    c = rng.integers(0, 33, size=(n, 1, 3))
    v = np.clip(c + rng.integers(-3, 4, size=(n, 3, 3)), 0, 32) / 4.0
    v[0] = [[0, 0, 0], [8, 0, 0], [0, 8, 8]]          # pin the scene box to [0, 8]^3
    return fmt.quantize(v)


def cfg_for(fmt=FPFormat(), **kw):
    return Config(fmt=fmt, **kw)


# ---------------------------------------------------------------------------------------------
# independent readers (bit operations written here, not the code under test)
# ---------------------------------------------------------------------------------------------

def walk(tree):
    """(node, depth, lo, hi) for every node reachable from the root, via an explicit stack."""
    out = []
    stack = [(0, 0, tree.bounds[0].astype(np.float64), tree.bounds[1].astype(np.float64))]
    while stack:
        i, d, lo, hi = stack.pop()
        out.append((i, d, lo, hi))
        a = int(tree.axis[i])
        if a != LEAF:
            s = float(tree.split[i])
            l = int(tree.child[i])
            hl, lr = hi.copy(), lo.copy()
            hl[a] = s
            lr[a] = s
            stack += [(l, d + 1, lo, hl), (l + 1, d + 1, lr, hi)]
    return out


def leaves_containing(words, node_base, list_base, p):
    """Triangle lists of every leaf whose closed box contains point p, read from image words."""
    found = []
    stack = [0]
    while stack:
        w = int(words[node_base + stack.pop()])
        kind, idx, top = w & 3, (w >> 2) & (2**30 - 1), w >> 32
        if kind == LEAF:
            ents = []
            for j in range(top, top + idx):
                lw = int(words[list_base + j // 2])
                ents.append((lw >> (32 * (j % 2))) & 0xFFFFFFFF)
            found.append(set(ents))
            continue
        s = float(np.array([top], np.uint32).view(np.float32)[0])
        if p[kind] <= s:
            stack.append(idx)
        if p[kind] >= s:
            stack.append(idx + 1)
    return found


def sah(tree, ct, ci):
    total = 0.0
    area = lambda lo, hi: 2 * ((hi - lo)[0] * (hi - lo)[1] + (hi - lo)[1] * (hi - lo)[2]  # noqa
                               + (hi - lo)[2] * (hi - lo)[0])
    root = area(tree.bounds[0].astype(np.float64), tree.bounds[1].astype(np.float64))
    for i, d, lo, hi in walk(tree):
        total += (ci * tree.count[i] if tree.axis[i] == LEAF else ct) * area(lo, hi) / root
    return total


# ---------------------------------------------------------------------------------------------
# tests
# ---------------------------------------------------------------------------------------------

SCENES = {
    "soup": lambda fmt: soup(1500, 1, fmt=fmt),
    "soup_big_tris": lambda fmt: soup(400, 2, size=2.0, fmt=fmt),
    "sphere": lambda fmt: sphere(fmt),
    "grid": lambda fmt: grid_scene(fmt),
    "lattice": lambda fmt: lattice(fmt=fmt),
}
FMTS = [FPFormat(8, 23), FPFormat(8, 16), FPFormat(8, 10)]


@pytest.mark.parametrize("fmt", FMTS, ids=str)
@pytest.mark.parametrize("name", SCENES)
def test_structure_and_format_splits(name, fmt):
    tris = SCENES[name](fmt)
    cfg = cfg_for(fmt, kd_max_depth=16)
    tree = build_kdtree(tris, cfg, cache_dir=None)
    nodes = walk(tree)
    # every node reached exactly once (children pairs are adjacent and disjoint)
    idx = sorted(i for i, *_ in nodes)
    assert idx == list(range(tree.n_nodes))
    depths = [d for _, d, _, _ in nodes]
    assert max(depths) == tree.depth <= cfg.kd_max_depth
    # scene box: format values containing every vertex, tight
    assert (fmt.quantize(tree.bounds) == tree.bounds).all()
    assert (tris.min(axis=(0, 1)) == tree.bounds[0]).all()
    assert (tris.max(axis=(0, 1)) == tree.bounds[1]).all()
    inner = tree.axis != LEAF
    assert inner.any()
    sp = tree.split[inner]
    assert (fmt.quantize(sp).view(np.uint32) == sp.view(np.uint32)).all(), "split not a format value"
    for i, d, lo, hi in nodes:
        if tree.axis[i] != LEAF:
            a = tree.axis[i]
            assert lo[a] < tree.split[i] < hi[a], "split outside the node's box"
        else:
            assert 0 <= tree.first[i] and tree.first[i] + tree.count[i] <= tree.n_entries
            ents = tree.tri_list[tree.first[i]:tree.first[i] + tree.count[i]]
            assert (np.diff(ents) > 0).all(), "leaf entries must be ascending and distinct"
    assert tree.count[inner].sum() == 0
    assert tree.count[~inner].sum() == tree.n_entries
    # every triangle is listed somewhere
    assert set(tree.tri_list.tolist()) == set(range(len(tris)))


@pytest.mark.parametrize("clip", [True, False], ids=["clip", "noclip"])
@pytest.mark.parametrize("fmt", [FPFormat(8, 23), FPFormat(8, 16), FPFormat(8, 10)], ids=str)
@pytest.mark.parametrize("name", SCENES)
def test_points_on_triangles_reach_their_triangle(name, fmt, clip):
    """For points on each triangle (its vertices, edge midpoints, random interior points, all
    in float64), every leaf whose closed box contains the point lists the triangle."""
    tris = SCENES[name](fmt)
    cfg = cfg_for(fmt, kd_max_depth=16, kd_leaf_size=2)
    tree = build_kdtree(tris, cfg, cache_dir=None, clip=clip)
    img = build_image(tris, tree, cfg)
    rng = np.random.default_rng(7)
    t64 = tris.astype(np.float64)
    bary = [np.eye(3)[k] for k in range(3)] + [np.array([0.5, 0.5, 0.0]),
                                               np.array([0.0, 0.5, 0.5])]
    checked = 0
    for t in range(0, len(tris), max(1, len(tris) // 300)):
        pts = [b @ t64[t] for b in bary]
        w = rng.dirichlet([1, 1, 1], size=3)
        pts += list(w @ t64[t])
        for p in pts:
            lists = leaves_containing(img.data, img.node_base, img.list_base, p)
            assert lists, f"point {p} of triangle {t} is in no leaf"
            for ents in lists:
                assert t in ents, f"triangle {t} missing from a leaf containing its point {p}"
            checked += 1
    assert checked > 500


@pytest.mark.parametrize("name", SCENES)
def test_leaf_lists_are_exactly_the_overlapping_triangles(name):
    """Conservative classification without clipping: a leaf lists triangle t if and only if
    t's bounding box overlaps the leaf's closed box (min <= split goes left, max >= split right).
    With clipping a leaf lists a subset of those, and fewer entries in total."""
    fmt = FPFormat(8, 16)
    tris = SCENES[name](fmt)
    cfg = cfg_for(fmt, kd_max_depth=14, kd_leaf_size=2)
    tree = build_kdtree(tris, cfg, cache_dir=None, clip=False)
    tmin, tmax = tris.min(axis=1), tris.max(axis=1)
    on_plane = 0
    for i, d, lo, hi in walk(tree):
        if tree.axis[i] == LEAF:
            want = np.flatnonzero(((tmin <= hi) & (tmax >= lo)).all(axis=1))
            got = np.sort(tree.tri_list[tree.first[i]:tree.first[i] + tree.count[i]])
            assert np.array_equal(got, want), (name, i, d)
        else:
            a, s = tree.axis[i], tree.split[i]
            on_plane += int(((tmin[:, a] == s) | (tmax[:, a] == s)).sum())
    if name == "lattice":
        assert on_plane > 0, "scene meant to put triangle bounds on split planes did not"
    clipped = build_kdtree(tris, cfg, cache_dir=None, clip=True)
    for i, d, lo, hi in walk(clipped):
        if clipped.axis[i] == LEAF:
            got = clipped.tri_list[clipped.first[i]:clipped.first[i] + clipped.count[i]]
            assert ((tmin[got] <= hi) & (tmax[got] >= lo)).all(), (name, i, d)
    if name != "grid":
        assert clipped.n_entries < tree.n_entries


def exact_clip_bounds(tri, lo, hi):
    """Bounds of triangle ∩ box in exact rational arithmetic (None if empty)."""
    from fractions import Fraction as F
    poly = [[F(float(x)) for x in v] for v in tri]
    for k in range(3):
        for c, keep in ((F(float(lo[k])), lambda x, c: x >= c), (F(float(hi[k])), lambda x, c: x <= c)):
            out = []
            for i, p in enumerate(poly):
                q = poly[(i + 1) % len(poly)]
                if keep(p[k], c):
                    out.append(p)
                if keep(p[k], c) != keep(q[k], c):
                    t = (c - p[k]) / (q[k] - p[k])
                    out.append([p[j] + t * (q[j] - p[j]) for j in range(3)])
            poly = out
            if not poly:
                return None
    return [min(p[j] for p in poly) for j in range(3)], [max(p[j] for p in poly) for j in range(3)]


def test_clip_bounds_contain_exact_clipped_triangle():
    """Split clipping's float64 bounds, rounded outward to float32, contain the exact bounds of
    the triangle clipped to the box (rational arithmetic) for random triangles and boxes."""
    from fractions import Fraction as F
    from model.kdtree import _clip_bounds
    rng = np.random.default_rng(12)
    P, Q = np.empty((16, 3)), np.empty((16, 3))
    n_clipped = 0
    for _ in range(300):
        tri = (rng.random((3, 3)) * 4 - 2).astype(np.float32)
        lo = (rng.random(3) * 2 - 1.5).astype(np.float32)
        hi = (lo + rng.random(3) * 2 + 0.1).astype(np.float32)
        omin = np.maximum(tri.min(axis=0), lo)
        omax = np.minimum(tri.max(axis=0), hi)
        if not (omin <= omax).all():
            continue
        ex = exact_clip_bounds(tri, lo, hi)
        _clip_bounds(tri, lo, hi, P, Q, omin, omax)
        if ex is None:
            continue
        for j in range(3):
            assert F(float(omin[j])) <= ex[0][j] and F(float(omax[j])) >= ex[1][j]
        n_clipped += 1
        # and it does shrink: within a few float32 ulps of the exact bounds
        assert all(abs(float(omin[j]) - float(ex[0][j])) <= 1e-5 for j in range(3))
    assert n_clipped > 50


def test_leaf_size_respected_unless_depth_limited():
    # tiny, well separated triangles and expensive intersections: the SAH always splits
    tris = soup(3000, 3, size=1e-3, extent=100.0)
    cfg = Config(kd_max_depth=12, kd_leaf_size=3, kd_cost_int=100.0)
    tree = build_kdtree(tris, cfg, cache_dir=None)
    for i, d, lo, hi in walk(tree):
        if tree.axis[i] == LEAF and tree.count[i] > cfg.kd_leaf_size:
            assert d == cfg.kd_max_depth, (i, d, tree.count[i])
    assert tree.depth == cfg.kd_max_depth    # 3000 tris in leaves of 3 need > 2^10 leaves
    cfg2 = cfg.replace(kd_max_depth=24)
    tree2 = build_kdtree(tris, cfg2, cache_dir=None)
    assert tree2.count[tree2.axis == LEAF].max() <= cfg2.kd_leaf_size


def test_oversized_leaves_are_sah_terminated():
    """A leaf above leaf_size and above max depth exists only when no candidate plane (checked
    here with numpy over the same quantized bin boundaries) is cheaper than the leaf."""
    fmt = FPFormat(8, 16)
    tris = soup(800, 4, size=1.5, fmt=fmt)
    cfg = Config(fmt=fmt, kd_max_depth=20, kd_leaf_size=2, kd_bins=16)
    tree = build_kdtree(tris, cfg, cache_dir=None, clip=False)   # boxes = triangle boxes
    tmin, tmax = tris.min(axis=1), tris.max(axis=1)
    n_checked = 0
    for i, d, lo, hi in walk(tree):
        c = tree.count[i]
        if tree.axis[i] != LEAF or c <= cfg.kd_leaf_size or d == cfg.kd_max_depth:
            continue
        ids = tree.tri_list[tree.first[i]:tree.first[i] + c]
        ext = hi - lo
        sa = 2 * (ext[0] * ext[1] + ext[1] * ext[2] + ext[2] * ext[0])
        if sa <= 0:
            continue
        for a in range(3):
            if hi[a] <= lo[a]:
                continue
            k = np.arange(1, cfg.kd_bins)
            q = fmt.quantize(lo[a] + (hi[a] - lo[a]) * k / cfg.kd_bins).astype(np.float64)
            q = q[(q > lo[a]) & (q < hi[a])]
            nl = (tmin[ids, a][None, :] <= q[:, None]).sum(1)
            nr = (tmax[ids, a][None, :] >= q[:, None]).sum(1)
            o = [b for b in range(3) if b != a]
            cross = ext[o[0]] * ext[o[1]]
            per = ext[o[0]] + ext[o[1]]
            sal = 2 * (cross + (q - lo[a]) * per)
            sar = 2 * (cross + (hi[a] - q) * per)
            cost = cfg.kd_cost_trav + cfg.kd_cost_int * (sal * nl + sar * nr) / sa
            assert (cost >= cfg.kd_cost_int * c * (1 - 1e-9)).all(), (i, a, cost.min(), c)
        n_checked += 1
    assert n_checked > 0, "scene should have SAH-terminated leaves"


def test_sah_beats_single_leaf_and_cuts_empty_space():
    # two clusters with empty space between them
    a = soup(1000, 5, size=0.05, extent=1.0)
    b = soup(1000, 6, size=0.05, extent=1.0) + np.float32(20.0)
    tris = FPFormat().quantize(np.concatenate([a, b]))
    cfg = Config()
    tree = build_kdtree(tris, cfg, cache_dir=None)
    cost = sah(tree, cfg.kd_cost_trav, cfg.kd_cost_int)
    leaf_cost = cfg.kd_cost_int * len(tris)
    assert cost < 0.05 * leaf_cost, (cost, leaf_cost)
    st = kdtree_stats(tree, len(tris))
    counts = tree.count[tree.axis == LEAF]
    assert st["nodes"] == tree.n_nodes and st["leaves"] == len(counts)
    assert st["empty_leaves"] == int((counts == 0).sum()) > 0
    assert st["entries"] == counts.sum() and st["max_leaf_size"] == counts.max()
    assert st["image_bytes"] == 8 * len(build_image(tris, tree, cfg).data)


def test_degenerate_inputs():
    cfg = Config(kd_max_depth=8)
    one = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], np.float32)
    t = build_kdtree(one, cfg, cache_dir=None)
    assert t.n_nodes == 1 and t.axis[0] == LEAF and t.tri_list.tolist() == [0]
    same = np.repeat(one, 50, axis=0)      # cannot be separated: depth limit or SAH stops it
    t = build_kdtree(same, cfg, cache_dir=None)
    assert t.depth <= 8 and set(t.tri_list.tolist()) == set(range(50))
    flat = soup(300, 8)
    flat[:, :, 2] = 0.0                     # flat box along z
    t = build_kdtree(flat, cfg, cache_dir=None)
    assert t.n_nodes > 1 and (t.axis != 2).all()
    empty = np.zeros((0, 3, 3), np.float32)
    t = build_kdtree(empty, cfg, cache_dir=None)
    assert t.n_nodes == 1 and t.count[0] == 0


def test_bad_input_errors():
    cfg = Config(fmt=FPFormat(8, 10))
    with pytest.raises(KdTreeError, match="quantize"):
        build_kdtree(np.full((1, 3, 3), 0.1, np.float32), cfg, cache_dir=None)
    bad = np.zeros((2, 3, 3), np.float32)
    bad[1, 0, 0] = np.nan
    with pytest.raises(KdTreeError, match="NaN"):
        build_kdtree(bad, cfg, cache_dir=None)
    with pytest.raises(KdTreeError, match="shape"):
        build_kdtree(np.zeros((2, 9), np.float32), cfg, cache_dir=None)
    with pytest.raises(KdTreeError, match="float32"):
        build_kdtree(np.zeros((2, 3, 3)), cfg, cache_dir=None)


def test_deterministic_and_cached(tmp_path):
    tris = soup(2000, 9)
    cfg = Config()
    t1 = build_kdtree(tris, cfg, cache_dir=tmp_path)
    assert not t1.from_cache
    files = list(tmp_path.glob("*.npz"))
    assert len(files) == 1
    t2 = build_kdtree(tris, cfg, cache_dir=tmp_path)
    assert t2.from_cache and t2.build_seconds < 1.0
    t3 = build_kdtree(tris, cfg, cache_dir=None)
    for f in ("axis", "split", "child", "first", "count", "tri_list", "bounds"):
        assert np.array_equal(getattr(t1, f), getattr(t2, f)), f
        assert np.array_equal(getattr(t1, f), getattr(t3, f)), f
    assert t1.depth == t2.depth == t3.depth
    # another parameter is another key
    t4 = build_kdtree(tris, cfg.replace(kd_bins=16), cache_dir=tmp_path)
    assert not t4.from_cache and len(list(tmp_path.glob("*.npz"))) == 2
    # a corrupt cache file is rebuilt (and replaced)
    files[0].write_bytes(b"garbage")
    t5 = build_kdtree(tris, cfg, cache_dir=tmp_path)
    assert not t5.from_cache and np.array_equal(t5.split, t1.split)
    assert build_kdtree(tris, cfg, cache_dir=tmp_path).from_cache


def test_cache_env(tmp_path, monkeypatch):
    monkeypatch.setenv("SAARCOR_CACHE", str(tmp_path))
    tris = soup(100, 10)
    assert not build_kdtree(tris, Config()).from_cache
    assert build_kdtree(tris, Config()).from_cache
    assert len(list((tmp_path / "kdtree").glob("*.npz"))) == 1


@pytest.mark.slow
@needs_shared_meshes
def test_build_1m_triangles():
    """10 copies of the dragon (~1M triangles) offset in space: build time after compilation."""
    import trimesh
    m = trimesh.load(SHARED_MESHES / "dragon.obj", force="mesh")
    base = m.vertices[m.faces]
    ext = base.max(axis=(0, 1)) - base.min(axis=(0, 1))
    copies = [base + np.array([1.1 * ext[0] * (k % 5), 1.1 * ext[1] * (k // 5), 0.0])
              for k in range(10)]
    tris = FPFormat().quantize(np.concatenate(copies))
    cfg = Config()
    build_kdtree(tris[:1000], cfg, cache_dir=None)          # compile outside the timing
    t0 = time.perf_counter()
    tree = build_kdtree(tris, cfg, cache_dir=None)
    dt = time.perf_counter() - t0
    st = kdtree_stats(tree, len(tris))
    print(f"\n1M-triangle build: {len(tris)} tris in {dt:.2f} s; {st}")
    assert dt < 60
    assert tree.depth <= cfg.kd_max_depth
