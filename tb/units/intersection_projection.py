"""Testbench of the projection-test datapath (``rtl/intersection_projection.py``) against the
golden model (``model.intersection_projection.intersect_projection``).

* :func:`random_tests`: records (from random triangles by ``model.layout.projection_records``,
  or random bit patterns) and rays, with exact edge and vertex hits, degenerate triangles, rays
  parallel to the plane, overflow to infinity and results that flush to zero.
* :func:`run_pipe`: one test per cycle with random bubbles and stalls, every output checked at
  the exact cycle it must appear (``tb.harness.common.run_fixed_pipe``).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numba
import numpy as np

from model.fp import FPFormat
from model.intersection_projection import intersect_projection
from model.layout import projection_records
from rtl.intersection_projection import ProjectionPipe

from .intersection import PipeRun, _pack


@dataclass
class ProjectionTests:
    """Operands (float32 format values; ``k`` ints) and the model's results, one row per test."""
    rec: np.ndarray      # (n, 9)
    k: np.ndarray        # (n,)
    org: np.ndarray      # (n, 3)
    dir: np.ndarray      # (n, 3)
    hit: np.ndarray      # (n,) bool
    t: np.ndarray        # (n,)
    u: np.ndarray
    v: np.ndarray

    def __len__(self):
        return len(self.hit)


@numba.njit(cache=True)
def _intersect_all(rec, k, org, d, E, M, hit, t, u, v):
    for i in range(rec.shape[0]):
        hit[i], t[i], u[i], v[i] = intersect_projection(rec[i], k[i], org[i, 0], org[i, 1],
                                                        org[i, 2], d[i, 0], d[i, 1], d[i, 2],
                                                        E, M)


def model_tests(rec, k, org, dirn, fmt: FPFormat) -> ProjectionTests:
    """Run the model on every row (operands quantized to ``fmt``)."""
    q = lambda x: np.ascontiguousarray(fmt.quantize(np.asarray(x, np.float64)), np.float32)
    rec, org, dirn = q(rec), q(org), q(dirn)
    k = np.ascontiguousarray(k, np.int64)
    n = len(rec)
    hit = np.zeros(n, np.bool_)
    t, u, v = (np.zeros(n, np.float32) for _ in range(3))
    _intersect_all(rec, k, org, dirn, fmt.exp_bits, fmt.frac_bits, hit, t, u, v)
    return ProjectionTests(rec, k, org, dirn, hit, t, u, v)


def random_tests(n: int, fmt: FPFormat, seed: int = 0) -> ProjectionTests:
    """``n`` random ray/record pairs in six families (about n/6 each): 0. rays aimed at a
    random point near a random triangle (about half hit); 1. exact edge and vertex hits
    (small-integer triangles, axis-aligned rays through a vertex or an edge midpoint);
    2. degenerate triangles (the never-hit record) and rays parallel to the plane (t infinite
    or NaN); 3. huge coordinates (overflow); 4. tiny ones (flush to zero); 5. random finite bit
    patterns for every operand, k in 0..2."""
    rng = np.random.default_rng(seed)
    fam = np.arange(n) % 6
    tri = rng.normal(size=(n, 3, 3)) * 4
    org = rng.normal(size=(n, 3)) * 8
    bary = rng.dirichlet([1, 1, 1], size=n) * rng.uniform(0.7, 1.3, (n, 1))
    dirn = np.einsum("ij,ijk->ik", bary, tri) - org
    f = fam == 1
    m = int(f.sum())
    g = rng.integers(-4, 5, size=(m, 3, 3)).astype(np.float64)
    g[:, :, 2] = rng.integers(-2, 3, size=(m, 1))                # triangle in a z plane
    pick = rng.integers(0, 3, m)
    va, vb = g[np.arange(m), pick], g[np.arange(m), (pick + 1) % 3]
    on = np.where(rng.random((m, 1)) < 0.5, va, (va + vb) / 2)
    axis_dir = np.zeros((m, 3))
    axis_dir[:, 2] = np.where(rng.random(m) < 0.5, -1.0, 1.0)
    tri[f], org[f], dirn[f] = g, on - 5 * axis_dir, axis_dir
    f = np.flatnonzero(fam == 2)
    half = f[::2]
    tri[half, 1] = tri[half, 0]                                   # A == B: degenerate
    rest = f[1::2]                                                # a ray in the plane
    dirn[rest] = tri[rest, 1] - tri[rest, 0]
    org[rest] = tri[rest, 0] - dirn[rest]
    for fi, scale in ((3, 1e37), (4, fmt.min_normal * 8)):
        f = fam == fi
        s = scale * rng.uniform(0.5, 30, (int(f.sum()), 1))
        tri[f] *= s[:, :, None]
        org[f] *= s
        dirn[f] = np.where(rng.random((int(f.sum()), 1)) < 0.5, dirn[f], tri[f, 0] - org[f])
    hi = fmt.max_finite
    tri, org, dirn = (np.clip(np.nan_to_num(x), -hi, hi) for x in (tri, org, dirn))
    with np.errstate(all="ignore"):
        rec, k = projection_records(fmt.quantize(tri), fmt)
    rec, k = rec.astype(np.float64), k.astype(np.int64)
    f = fam == 5
    m = int(f.sum())

    def bits(shape):
        e = rng.integers(0, 255, shape).astype(np.uint32)       # exponent < 255: finite
        x = (rng.integers(0, 2, shape).astype(np.uint32) << 31) | (e << 23) | \
            rng.integers(0, 1 << 23, shape).astype(np.uint32)
        return x.view(np.float32).astype(np.float64)
    rec[f], org[f], dirn[f] = bits((m, 9)), bits((m, 3)), bits((m, 3))
    k[f] = rng.integers(0, 3, m)
    return model_tests(np.clip(rec, -hi, hi), k, np.clip(org, -hi, hi), np.clip(dirn, -hi, hi),
                       fmt)


def pipe_ports(tests: ProjectionTests, fmt: FPFormat, tag_width: int) -> tuple[dict, dict]:
    """The datapath's port values per test (ints, arrays packed element 0 lowest): inputs and
    the model's outputs."""
    tag = [i % (1 << tag_width) for i in range(len(tests))]
    t, u, v = (fmt.to_bits(x).astype(np.int64).tolist() for x in (tests.t, tests.u, tests.v))
    return ({"tri": _pack(fmt, tests.rec), "tri_k": [int(x) for x in tests.k],
             "org": _pack(fmt, tests.org), "dir": _pack(fmt, tests.dir), "tag": tag},
            {"o_tag": tag, "hit": tests.hit.astype(int).tolist(), "t": t, "u": u, "v": v})


def run_pipe(tests: ProjectionTests, fmt: FPFormat, *, seed: int = 0, p_bubble: float = 0.2,
             p_stall: float = 0.2, latencies: dict | None = None) -> PipeRun:
    """Drive ``tests`` through :class:`ProjectionPipe` and compare every output at its exact
    cycle with the model; returns the mismatches."""
    from tb.harness.common import run_fixed_pipe
    n = len(tests)
    dut = ProjectionPipe(fmt, tag_width=max(1, n.bit_length()), latencies=latencies)
    ins, outs = pipe_ports(tests, fmt, dut.tag_width)

    def describe(i):
        return (f"rec={tests.rec[i].tolist()} k={int(tests.k[i])} org={tests.org[i].tolist()} "
                f"dir={tests.dir[i].tolist()}")
    t0 = time.perf_counter()
    r = run_fixed_pipe(dut, ins, outs, seed=seed, p_bubble=p_bubble, p_stall=p_stall,
                       describe=describe)
    return PipeRun(n, r.cycles, time.perf_counter() - t0, dut.latency, r.outputs,
                   [f"ProjectionPipe: {x}" for x in r.mismatches])
