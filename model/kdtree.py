"""Binned-SAH kd-tree builder (the paper's "BSP") for the SaarCOR traversal unit.

The whole build runs in one numba function with an explicit work stack (no Python recursion):

* node 0 is the root; an inner node's children are allocated together as an adjacent pair
  (left = ``child``, right = ``child + 1``), so one index per inner node suffices;
* every candidate plane is rounded to the hardware format ``cfg.fmt`` *before* triangles are
  counted or classified, so the stored split is exactly the plane the builder used;
* triangles are classified against that stored split conservatively by a box per reference:
  left if ``min[axis] <= split``, right if ``max[axis] >= split`` (both when straddling or lying
  in the plane). The box starts as the triangle's bounding box; with split clipping (default)
  a straddling reference's box is shrunk to the bounds of the triangle clipped to the child's
  box (float64 Sutherland-Hodgman, rounded outward by at least one float32 ulp). Every box
  contains the part of its triangle inside the node, so a point of a triangle inside a node's
  box lies in the box of a child that lists it: no ray can miss a triangle because of the tree;
* SAH with ``kd_bins`` candidate planes per axis at the (quantized) bin boundaries; the counts
  per candidate are exact (computed against the quantized planes), so the cost that chose a
  split is the cost of the split stored. A node becomes a leaf when it holds at most
  ``kd_leaf_size`` triangles, sits at depth ``kd_max_depth``, or no split is cheaper than
  ``kd_cost_int * n`` (intersecting everything). Empty leaves arise from the SAH naturally.

Built trees are cached on disk (``$SAARCOR_CACHE/kdtree/`` or ``~/.cache/saarcor/kdtree/``),
keyed by a sha256 over the triangle bytes, the format, every kd parameter, the clipping flag
and :data:`BUILDER_VERSION`.

Speed (this machine, one core, after compilation): ~1 M triangles (10 dragons) in ~8 s.
"""
from __future__ import annotations

import hashlib
import os
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np

from .config import Config
from .fp import round_exact
from .layout import LEAF, image_size_words

BUILDER_VERSION = 2
"""Bump whenever the builder's output for a given input changes (invalidates the disk cache)."""

"""``axis`` value of a leaf node (0/1/2 = split axis of an inner node)."""


class KdTreeError(ValueError):
    """The triangles cannot be turned into a kd-tree; the message says why and how to fix it."""


@dataclass
class KdTree:
    axis: np.ndarray      # (n_nodes,) uint8: 0/1/2 = split axis of an inner node, 3 = leaf
    split: np.ndarray     # (n_nodes,) float32: split position (inner nodes), a value of cfg.fmt
    child: np.ndarray     # (n_nodes,) int32: inner: index of the left child; right = left + 1
    first: np.ndarray     # (n_nodes,) int32: leaf: index of its first entry in tri_list
    count: np.ndarray     # (n_nodes,) int32: leaf: number of triangles
    tri_list: np.ndarray  # (n_entries,) int32: triangle indices (into the tris array given)
    bounds: np.ndarray    # (2, 3) float32: scene box (min, max), format values
    depth: int            # max depth reached (root = 0); <= cfg.kd_max_depth
    build_seconds: float = 0.0
    from_cache: bool = False

    @property
    def n_nodes(self) -> int:
        return int(self.axis.shape[0])

    @property
    def n_entries(self) -> int:
        return int(self.tri_list.shape[0])


# ---------------------------------------------------------------------------------------------
# the compiled builder
# ---------------------------------------------------------------------------------------------

@numba.njit(cache=True)
def _grow_i32(a, need):
    if need <= a.shape[0]:
        return a
    cap = max(need, 2 * a.shape[0])
    b = np.empty(cap, np.int32)
    b[:a.shape[0]] = a
    return b


@numba.njit(cache=True)
def _area(lo, hi):
    dx = hi[0] - lo[0]
    dy = hi[1] - lo[1]
    dz = hi[2] - lo[2]
    return 2.0 * (dx * dy + dy * dz + dz * dx)


@numba.njit(cache=True)
def _f32_down(x):
    """Largest float32 strictly below float64 ``x`` (a safe lower bound)."""
    f = np.float32(x)
    if np.float64(f) >= x:
        f = np.float32(np.nextafter(f, np.float32(-np.inf)))
    return f


@numba.njit(cache=True)
def _f32_up(x):
    f = np.float32(x)
    if np.float64(f) <= x:
        f = np.float32(np.nextafter(f, np.float32(np.inf)))
    return f


@numba.njit(cache=True)
def _clip_bounds(v, lo, hi, P, Q, omin, omax):
    """Shrink box ``omin``/``omax`` to the bounds of triangle ``v`` clipped to box [lo, hi].

    Sutherland-Hodgman in float64, result rounded outward to float32 with a margin of at least
    one float32 ulp, so the shrunk box still contains every point of the triangle in [lo, hi].
    Leaves the box unchanged when clipping leaves nothing (numerically): conservative."""
    for i in range(3):
        for j in range(3):
            P[i, j] = np.float64(v[i, j])
    n = 3
    for k in range(3):
        for side in range(2):
            c = np.float64(lo[k]) if side == 0 else np.float64(hi[k])
            m = 0
            for i in range(n):
                i2 = i + 1 if i + 1 < n else 0
                pk = P[i, k]
                qk = P[i2, k]
                pin = pk >= c if side == 0 else pk <= c
                qin = qk >= c if side == 0 else qk <= c
                if pin:
                    for j in range(3):
                        Q[m, j] = P[i, j]
                    m += 1
                if pin != qin:
                    t = (c - pk) / (qk - pk)
                    for j in range(3):
                        Q[m, j] = P[i, j] + t * (P[i2, j] - P[i, j])
                    Q[m, k] = c
                    m += 1
            if m == 0:
                return
            for i in range(m):
                for j in range(3):
                    P[i, j] = Q[i, j]
            n = m
    for j in range(3):
        mn = P[0, j]
        mx = P[0, j]
        for i in range(1, n):
            mn = min(mn, P[i, j])
            mx = max(mx, P[i, j])
        a = max(omin[j], _f32_down(mn))
        b = min(omax[j], _f32_up(mx))
        if not (a <= b):
            return
        Q[0, j] = a
        Q[1, j] = b
    for j in range(3):
        omin[j] = np.float32(Q[0, j])
        omax[j] = np.float32(Q[1, j])


@numba.njit(cache=True)
def _build(tris, tmin, tmax, root_lo, root_hi, E, M, max_depth, leaf_size, bins, cost_trav,
           cost_int, clip):
    """Build the tree over triangles ``tris`` with boxes ``tmin``/``tmax`` ((N, 3) float32).

    Each reference carries its own box (the triangle's box, cut to the node's box, and with
    ``clip`` shrunk to the part of the triangle inside the node). Returns (axis, split, child,
    first, count, tri_list, depth), arrays trimmed to size."""
    n = tmin.shape[0]
    B = bins

    cap = max(16, 2 * n + 1)
    axis = np.empty(cap, np.uint8)
    split = np.zeros(cap, np.float32)
    child = np.zeros(cap, np.int32)
    first = np.zeros(cap, np.int32)
    count = np.zeros(cap, np.int32)
    lst = np.empty(max(16, 2 * n), np.int32)
    n_lst = 0

    # Work buffer: the triangle ids of the pending nodes, stacked; the node being processed is
    # always the topmost segment, so its split can use the space above it as scratch.
    buf = np.empty(max(16, 3 * n), np.int32)
    rmin = np.empty((buf.shape[0], 3), np.float32)
    rmax = np.empty((buf.shape[0], 3), np.float32)
    for i in range(n):
        buf[i] = i
        rmin[i, :] = tmin[i, :]
        rmax[i, :] = tmax[i, :]
    P = np.empty((16, 3), np.float64)
    Q = np.empty((16, 3), np.float64)
    clo = np.empty(3, np.float32)
    chi = np.empty(3, np.float32)

    # Work stack: one pending right sibling per level at most.
    sk = np.empty((max_depth + 2, 4), np.int64)      # node, depth, start, count
    skb = np.empty((max_depth + 2, 2, 3), np.float32)  # node box
    sp = 0
    sk[0, 0] = 0
    sk[0, 1] = 0
    sk[0, 2] = 0
    sk[0, 3] = n
    skb[0, 0, :] = root_lo
    skb[0, 1, :] = root_hi
    sp = 1
    n_nodes = 1
    max_d = 0

    q = np.empty(B + 1, np.float32)       # quantized candidate planes q[1..B-1]
    hmin = np.zeros(B + 1, np.int64)
    hmax = np.zeros(B + 1, np.int64)
    lo = np.empty(3, np.float32)
    hi = np.empty(3, np.float32)
    blo = np.empty(3, np.float64)
    bhi = np.empty(3, np.float64)

    while sp > 0:
        sp -= 1
        node = sk[sp, 0]
        d = sk[sp, 1]
        s = sk[sp, 2]
        c = sk[sp, 3]
        for k in range(3):
            lo[k] = skb[sp, 0, k]
            hi[k] = skb[sp, 1, k]
        if d > max_d:
            max_d = d

        best_axis = -1
        best_split = np.float32(0.0)
        if c > leaf_size and d < max_depth:
            for k in range(3):
                blo[k] = lo[k]
                bhi[k] = hi[k]
            sa = _area(blo, bhi)
            best_cost = cost_int * c             # cost of a leaf
            if sa > 0.0:
                for a in range(3):
                    l64 = np.float64(lo[a])
                    h64 = np.float64(hi[a])
                    if not (h64 > l64):
                        continue
                    for k in range(1, B):
                        q[k] = round_exact(l64 + (h64 - l64) * k / B, E, M)
                    inv_w = B / (h64 - l64)
                    for k in range(B + 1):
                        hmin[k] = 0
                        hmax[k] = 0
                    for t in range(s, s + c):
                        # a = smallest k in 1..B with q[k] >= m (q[B] = +inf)
                        m = rmin[t, a]
                        g = (np.float64(m) - l64) * inv_w
                        g = min(max(g, 0.0), np.float64(B))
                        j = min(max(int(g) + 1, 1), B)
                        while j > 1 and q[j - 1] >= m:
                            j -= 1
                        while j < B and q[j] < m:
                            j += 1
                        hmin[j] += 1
                        # b = largest k in 0..B-1 with q[k] <= x (q[0] = -inf)
                        x = rmax[t, a]
                        g = (np.float64(x) - l64) * inv_w
                        g = min(max(g, 0.0), np.float64(B))
                        j = min(max(int(g), 0), B - 1)
                        while j < B - 1 and q[j + 1] <= x:
                            j += 1
                        while j > 0 and q[j] > x:
                            j -= 1
                        hmax[j] += 1
                    n_left = hmin[0]
                    n_right = c - hmax[0]
                    for k in range(1, B):
                        n_left += hmin[k]          # tris with min <= q[k]
                        if k > 1:
                            n_right -= hmax[k - 1]  # tris with max >= q[k]
                        qk = q[k]
                        if not (qk > lo[a] and qk < hi[a]):
                            continue
                        if k > 1 and q[k - 1] == qk:
                            continue
                        save = bhi[a]
                        bhi[a] = np.float64(qk)
                        sa_l = _area(blo, bhi)
                        bhi[a] = save
                        save = blo[a]
                        blo[a] = np.float64(qk)
                        sa_r = _area(blo, bhi)
                        blo[a] = save
                        cost = cost_trav + cost_int * (sa_l * n_left + sa_r * n_right) / sa
                        if cost < best_cost:
                            best_cost = cost
                            best_axis = a
                            best_split = qk

        if best_axis < 0:
            # leaf: append the node's triangles (ascending: partitions keep the order)
            lst = _grow_i32(lst, n_lst + c)
            for t in range(c):
                lst[n_lst + t] = buf[s + t]
            axis[node] = LEAF
            first[node] = n_lst
            count[node] = c
            n_lst += c
            continue

        # inner node: partition into scratch above the segment, then move down as
        # [right | left] so that left (processed next) is the topmost segment
        a = best_axis
        sv = best_split
        if s + 3 * c > buf.shape[0]:
            cap2 = max(s + 3 * c, 2 * buf.shape[0])
            buf = _grow_i32(buf, cap2)
            rmin2 = np.empty((cap2, 3), np.float32)
            rmin2[:s + c] = rmin[:s + c]
            rmin = rmin2
            rmax2 = np.empty((cap2, 3), np.float32)
            rmax2[:s + c] = rmax[:s + c]
            rmax = rmax2
        nl = 0
        nr = 0
        for side in range(2):                  # 0: left (min <= split), 1: right (max >= split)
            for k in range(3):
                clo[k] = lo[k]
                chi[k] = hi[k]
            if side == 0:
                chi[a] = sv
            else:
                clo[a] = sv
            o = s + c + nl if side == 1 else s + c
            nout = 0
            for t in range(s, s + c):
                if side == 0:
                    keep = rmin[t, a] <= sv
                else:
                    keep = rmax[t, a] >= sv
                if not keep:
                    continue
                buf[o + nout] = buf[t]
                for k in range(3):             # cut the box to the child's box
                    rmin[o + nout, k] = max(rmin[t, k], clo[k])
                    rmax[o + nout, k] = min(rmax[t, k], chi[k])
                if clip and rmin[t, a] < sv and rmax[t, a] > sv:
                    _clip_bounds(tris[buf[t]], clo, chi, P, Q, rmin[o + nout], rmax[o + nout])
                nout += 1
            if side == 0:
                nl = nout
            else:
                nr = nout
        # move down as [right | left]
        for t in range(nr):
            buf[s + t] = buf[s + c + nl + t]
            rmin[s + t, :] = rmin[s + c + nl + t, :]
            rmax[s + t, :] = rmax[s + c + nl + t, :]
        for t in range(nl):
            buf[s + nr + t] = buf[s + c + t]
            rmin[s + nr + t, :] = rmin[s + c + t, :]
            rmax[s + nr + t, :] = rmax[s + c + t, :]

        if n_nodes + 2 > axis.shape[0]:
            new_cap = 2 * axis.shape[0]
            axis2 = np.empty(new_cap, np.uint8)
            axis2[:n_nodes] = axis[:n_nodes]
            axis = axis2
            split2 = np.zeros(new_cap, np.float32)
            split2[:n_nodes] = split[:n_nodes]
            split = split2
            child = _grow_i32(child, new_cap)
            first = _grow_i32(first, new_cap)
            count = _grow_i32(count, new_cap)
        left = n_nodes
        n_nodes += 2
        axis[node] = a
        split[node] = sv
        child[node] = left
        first[node] = 0
        count[node] = 0

        # push right, then left (popped first)
        sk[sp, 0] = left + 1
        sk[sp, 1] = d + 1
        sk[sp, 2] = s
        sk[sp, 3] = nr
        for k in range(3):
            skb[sp, 0, k] = lo[k]
            skb[sp, 1, k] = hi[k]
        skb[sp, 0, a] = sv
        sp += 1
        sk[sp, 0] = left
        sk[sp, 1] = d + 1
        sk[sp, 2] = s + nr
        sk[sp, 3] = nl
        for k in range(3):
            skb[sp, 0, k] = lo[k]
            skb[sp, 1, k] = hi[k]
        skb[sp, 1, a] = sv
        sp += 1

    return (axis[:n_nodes].copy(), split[:n_nodes].copy(), child[:n_nodes].copy(),
            first[:n_nodes].copy(), count[:n_nodes].copy(), lst[:n_lst].copy(), max_d)


@numba.njit(cache=True)
def _node_boxes(axis, split, child, lo, hi):
    """Box of every node (children are allocated after their parent: one forward pass)."""
    n = axis.shape[0]
    box = np.empty((n, 2, 3), np.float32)
    box[0, 0, :] = lo
    box[0, 1, :] = hi
    for i in range(n):
        a = axis[i]
        if a == LEAF:
            continue
        l = child[i]
        box[l, :, :] = box[i, :, :]
        box[l + 1, :, :] = box[i, :, :]
        box[l, 1, a] = split[i]
        box[l + 1, 0, a] = split[i]
    return box


def node_boxes(tree: KdTree) -> np.ndarray:
    """(n_nodes, 2, 3) float32: the box (min, max) of every node, format values."""
    return _node_boxes(tree.axis, tree.split, tree.child,
                       np.ascontiguousarray(tree.bounds[0]), np.ascontiguousarray(tree.bounds[1]))


# ---------------------------------------------------------------------------------------------
# Python front end: checks, cache
# ---------------------------------------------------------------------------------------------

def default_cache_dir() -> Path:
    root = os.environ.get("SAARCOR_CACHE")
    if root:
        return Path(root) / "kdtree"
    return Path.home() / ".cache" / "saarcor" / "kdtree"


def _check_tris(tris: np.ndarray, cfg: Config) -> np.ndarray:
    tris = np.asarray(tris)
    if tris.ndim != 3 or tris.shape[1:] != (3, 3):
        raise KdTreeError(f"tris has shape {tris.shape}; expected (N, 3, 3) "
                          "(N triangles x 3 vertices x xyz)")
    if tris.dtype != np.float32:
        raise KdTreeError(f"tris has dtype {tris.dtype}; expected float32 values of {cfg.fmt} "
                          "(quantize first: cfg.fmt.quantize(tris))")
    tris = np.ascontiguousarray(tris)
    bad = ~np.isfinite(tris).all(axis=(1, 2))
    if bad.any():
        raise KdTreeError(f"{int(bad.sum())} triangles have NaN or infinite vertices "
                          f"(first: triangle {int(np.argmax(bad))}); remove them before building")
    q = cfg.fmt.quantize(tris)
    off = (q.view(np.uint32) != tris.view(np.uint32)).any(axis=(1, 2))
    if off.any():
        raise KdTreeError(f"{int(off.sum())} triangles have vertices that are not values of "
                          f"{cfg.fmt} (first: triangle {int(np.argmax(off))}); "
                          "quantize with cfg.fmt.quantize(tris) before building")
    return tris


def cache_key(tris: np.ndarray, cfg: Config, clip: bool = True) -> str:
    h = hashlib.sha256()
    h.update(f"kdtree v{BUILDER_VERSION} clip={bool(clip)} {cfg.fmt} d={cfg.kd_max_depth} "
             f"leaf={cfg.kd_leaf_size} "
             f"bins={cfg.kd_bins} ct={cfg.kd_cost_trav!r} ci={cfg.kd_cost_int!r} "
             f"shape={tris.shape}".encode())
    h.update(np.ascontiguousarray(tris).tobytes())
    return h.hexdigest()


_FIELDS = ("axis", "split", "child", "first", "count", "tri_list", "bounds")
_DTYPES = dict(axis=np.uint8, split=np.float32, child=np.int32, first=np.int32, count=np.int32,
               tri_list=np.int32, bounds=np.float32)


def _load_cached(path: Path, key: str) -> KdTree | None:
    try:
        with np.load(path, allow_pickle=False) as z:
            if str(z["key"]) != key:
                return None
            arrs = {f: np.asarray(z[f]) for f in _FIELDS}
            depth = int(z["depth"])
        n = arrs["axis"].shape[0]
        for f in _FIELDS:
            if arrs[f].dtype != _DTYPES[f]:
                return None
        if n == 0 or any(arrs[f].shape != (n,) for f in ("split", "child", "first", "count")):
            return None
        if arrs["bounds"].shape != (2, 3):
            return None
        return KdTree(**arrs, depth=depth, from_cache=True)
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile):
        return None


def _store_cached(path: Path, key: str, tree: KdTree) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.stem}.{os.getpid()}.tmp.npz")
    np.savez(tmp, key=np.array(key), depth=np.array(tree.depth),
             **{f: getattr(tree, f) for f in _FIELDS})
    os.replace(tmp, path)


_DEFAULT = "default"


def build_kdtree(tris: np.ndarray, cfg: Config, cache_dir: Path | str | None = _DEFAULT,
                 clip: bool = True) -> KdTree:
    """Build (or load from the disk cache) the kd-tree over ``tris``.

    ``tris``: (N, 3, 3) float32, values of ``cfg.fmt``. ``cache_dir``: directory for cached
    trees; the default is :func:`default_cache_dir`; ``None`` disables the cache. ``clip``:
    split clipping (a straddling triangle's box is shrunk to its part inside each child;
    fewer list entries); without it a leaf lists exactly the triangles whose bounding box
    overlaps the leaf's closed box."""
    t0 = time.perf_counter()
    tris = _check_tris(tris, cfg)
    path = None
    if cache_dir is not None:
        key = cache_key(tris, cfg, clip)
        path = Path(default_cache_dir() if cache_dir == _DEFAULT else cache_dir) / f"{key}.npz"
        if path.exists():
            tree = _load_cached(path, key)
            if tree is not None:
                tree.build_seconds = time.perf_counter() - t0
                return tree

    n = tris.shape[0]
    if n:
        tmin = np.ascontiguousarray(tris.min(axis=1))
        tmax = np.ascontiguousarray(tris.max(axis=1))
        bounds = np.stack([tmin.min(axis=0), tmax.max(axis=0)]).astype(np.float32)
    else:
        tmin = tmax = np.zeros((0, 3), np.float32)
        bounds = np.zeros((2, 3), np.float32)
    E, M = cfg.fmt.em
    axis, split, child, first, count, tri_list, depth = _build(
        tris, tmin, tmax, bounds[0].copy(), bounds[1].copy(), E, M, cfg.kd_max_depth,
        cfg.kd_leaf_size, cfg.kd_bins, float(cfg.kd_cost_trav), float(cfg.kd_cost_int),
        bool(clip))
    tree = KdTree(axis=axis, split=split, child=child, first=first, count=count,
                  tri_list=tri_list, bounds=bounds, depth=int(depth))
    if path is not None:
        _store_cached(path, key, tree)
    tree.build_seconds = time.perf_counter() - t0
    return tree


def sah_cost(tree: KdTree, cfg: Config) -> float:
    """Expected SAH cost of the tree relative to the root box's area (a single leaf: ci * N)."""
    box = node_boxes(tree).astype(np.float64)
    ext = box[:, 1] - box[:, 0]
    area = 2 * (ext[:, 0] * ext[:, 1] + ext[:, 1] * ext[:, 2] + ext[:, 2] * ext[:, 0])
    if area[0] <= 0:
        return float(cfg.kd_cost_int * tree.count[0]) if tree.axis[0] == LEAF else float("nan")
    leaf = tree.axis == LEAF
    cost = np.where(leaf, cfg.kd_cost_int * tree.count, cfg.kd_cost_trav)
    return float((cost * area).sum() / area[0])


def kdtree_stats(tree: KdTree, n_tris: int | None = None) -> dict:
    """Node/leaf/list figures and the size of the memory image (without shading data).

    ``n_tris``: triangles in the scene (default: the largest listed index + 1)."""
    leaf = tree.axis == LEAF
    counts = tree.count[leaf]
    if n_tris is None:
        n_tris = int(tree.tri_list.max()) + 1 if tree.tri_list.size else 0
    return {
        "nodes": tree.n_nodes,
        "inner": int((~leaf).sum()),
        "leaves": int(leaf.sum()),
        "empty_leaves": int((counts == 0).sum()),
        "depth": tree.depth,
        "mean_leaf_size": float(counts.mean()) if counts.size else 0.0,
        "mean_nonempty_leaf_size": float(counts[counts > 0].mean()) if (counts > 0).any() else 0.0,
        "max_leaf_size": int(counts.max()) if counts.size else 0,
        "entries": tree.n_entries,
        "image_bytes": 8 * image_size_words(tree.n_nodes, tree.n_entries, n_tris),
        "build_seconds": tree.build_seconds,
        "from_cache": tree.from_cache,
    }
