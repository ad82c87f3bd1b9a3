"""Numerical stress cases for the golden model and the RTC, judged by the exact oracle.

Each case is a small scene plus a ray set built so that one numerical corner happens for
sure (a hit at exactly a leaf's far distance, a ray through a shared edge, a zero direction
component, ...). The expected answer is :mod:`tb.exact`'s integer arithmetic on the case's
triangles, never another float tracer. ``python -m tb.stress`` runs the big versions and writes
``build/bench/stability.json``; ``tests/test_stress.py`` runs the small ones, on the model and
(through Verilator) on the RTC.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from model.config import Config
from model.kdtree import LEAF, KdTree, build_kdtree
from model.layout import build_image
from model.raygen import Rays, setup
from model.rtc import counter_totals, trace

from .exact import ExactHits, exact_closest

ROOT = Path(__file__).resolve().parent.parent


# --- building blocks ----------------------------------------------------------------------------

def make_rays(org, dirn, tmax=None, packet: int = 64, anyhit=None, kind: int = 0) -> Rays:
    """Rays in packets of ``packet`` consecutive rays."""
    org = np.ascontiguousarray(org, np.float32)
    dirn = np.ascontiguousarray(dirn, np.float32)
    n = len(dirn)
    if org.shape != (n, 3) or dirn.shape != (n, 3):
        raise ValueError(f"origins {org.shape} and directions {dirn.shape} must both be (N, 3)")
    tmax = np.full(n, np.inf, np.float32) if tmax is None else np.asarray(tmax, np.float32)
    pk = np.unique(np.r_[np.arange(0, n, packet), n]).astype(np.int64)
    r = Rays(org, dirn, tmax, np.full(n, kind, np.uint8), np.arange(n, dtype=np.int32), pk)
    if anyhit is not None:
        r.anyhit = np.asarray(anyhit, bool)
    return r


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
    hits, _ = trace(img, make_rays(org, dirn), cfg)
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
        rays = make_rays(org, dirn)
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
    rays = make_rays(org, dirn, packet=packet)
    return Case("tie_t_eq_tfar", tris, image, rays, exact_closest(tris, org, dirn))
