"""Testbenches of the intersection unit (``rtl/intersection.py``) against the golden model.

* :func:`run_pipe`: the bare datapath (:class:`~rtl.intersection.IntersectPipe`), one test per
  cycle with random bubbles (``i_valid`` = 0, random operands) and stalls (``en`` = 0), every
  output checked at the exact cycle it must appear (a shift register of the pipeline's latency
  that moves only when ``en`` is 1) against ``model.intersection.intersect``.
* :func:`random_tests` / :func:`golden_tests`: operands for it — random rays and triangles with
  degenerate triangles, exact edge and vertex hits, det = 0 and overflow to infinity; or the
  int-ops (``EV_INT``) of a traced scene.
"""
from __future__ import annotations

import dataclasses

import random
import time
from dataclasses import dataclass, field

import numba
import numpy as np

from amaranth.hdl import Module
from amaranth.lib import wiring
from amaranth.lib.wiring import Out

from model.fp import FPFormat
from model.intersection import intersect
from model.raygen import Rays, setup
from model.events import EV_INT, EV_LEAF, EV_TRI
from model.layout import TRI_WORDS
from model.rtc import C
from rtl.intersection import IntersectionUnit, IntersectPipe
from tb.harness.memory import IdealMemory
from rtl.memport import ItemReader

from tb.harness.common import drain, drive, run, watch


@dataclass
class PipeTests:
    """Operands (float32 format values; ``k`` ints) and the model's results, one row per test."""
    tri: np.ndarray      # (n, 9)
    org: np.ndarray      # (n, 3)
    k: np.ndarray        # (n, 3)
    s: np.ndarray        # (n, 3)
    hit: np.ndarray      # (n,) bool
    t: np.ndarray        # (n,)
    u: np.ndarray
    v: np.ndarray

    def __len__(self):
        return len(self.hit)


@numba.njit(cache=True)
def _intersect_all(tri, org, k, s, E, M, hit, t, u, v):
    for i in range(tri.shape[0]):
        hit[i], t[i], u[i], v[i] = intersect(tri[i], org[i, 0], org[i, 1], org[i, 2],
                                             k[i, 0], k[i, 1], k[i, 2],
                                             s[i, 0], s[i, 1], s[i, 2], E, M)


def model_tests(tri, org, k, s, fmt: FPFormat) -> PipeTests:
    """Run ``model.intersection.intersect`` on every row (operands quantized to ``fmt``)."""
    q = lambda x: np.ascontiguousarray(fmt.quantize(np.asarray(x, np.float64)), np.float32)
    tri, org, s = q(tri), q(org), q(s)
    k = np.ascontiguousarray(k, np.int64)
    n = len(tri)
    hit = np.zeros(n, np.bool_)
    t, u, v = (np.zeros(n, np.float32) for _ in range(3))
    _intersect_all(tri, org, k, s, fmt.exp_bits, fmt.frac_bits, hit, t, u, v)
    return PipeTests(tri, org, k, s, hit, t, u, v)


def random_tests(n: int, fmt: FPFormat, seed: int = 0) -> PipeTests:
    """``n`` random ray/triangle pairs in six families (about n/6 each):

    0. rays aimed at a random point of a random triangle (about half hit);
    1. exact edge and vertex hits: small-integer triangles, axis-aligned rays through a vertex or
       an edge midpoint (edge functions exactly zero);
    2. degenerate triangles (repeated vertex, collinear vertices: det = 0) and rays in the
       triangle's plane;
    3. huge coordinates (products overflow to infinity, inf - inf gives NaN inside);
    4. tiny coordinates near the smallest normal (results flush to zero);
    5. random finite bit patterns for every operand, any kx/ky/kz in 0..3 and random S.
    """
    rng = np.random.default_rng(seed)
    fam = np.arange(n) % 6
    tri = rng.normal(size=(n, 9)) * 4
    org = rng.normal(size=(n, 3)) * 8
    bary = rng.dirichlet([1, 1, 1], size=n) * rng.uniform(0.7, 1.3, (n, 1))
    target = (bary[:, :1] * tri[:, 0:3] + bary[:, 1:2] * tri[:, 3:6] + bary[:, 2:3] * tri[:, 6:9])
    dirn = target - org
    # 1: exact edge/vertex hits on an integer grid
    f = fam == 1
    m = int(f.sum())
    g = rng.integers(-4, 5, size=(m, 9)).astype(np.float64)
    g[:, 2::3] = rng.integers(-2, 3, size=(m, 1))               # triangle in a z plane
    pick = rng.integers(0, 3, m)
    va = g.reshape(m, 3, 3)[np.arange(m), pick]
    vb = g.reshape(m, 3, 3)[np.arange(m), (pick + 1) % 3]
    on = np.where(rng.random((m, 1)) < 0.5, va, (va + vb) / 2)  # a vertex or an edge midpoint
    axis_dir = np.zeros((m, 3))
    axis_dir[:, 2] = np.where(rng.random(m) < 0.5, -1.0, 1.0)
    tri[f], org[f], dirn[f] = g, on - 5 * axis_dir, axis_dir
    # 2: degenerate triangles
    f = fam == 2
    m = int(f.sum())
    d = tri[f].reshape(m, 3, 3)
    kind = rng.integers(0, 3, m)
    d[kind == 0, 1] = d[kind == 0, 0]                              # A == B
    d[kind == 1, 2] = 2 * d[kind == 1, 1] - d[kind == 1, 0]        # C on line AB
    d[kind == 2] = np.round(d[kind == 2])
    tri[f] = d.reshape(m, 9)
    inplane = kind == 2
    dirn[np.flatnonzero(f)[inplane]] = d[inplane, 1] - d[inplane, 0] + 1e-30
    org[np.flatnonzero(f)[inplane]] = d[inplane, 0] - (d[inplane, 1] - d[inplane, 0])
    # 3: huge, 4: tiny
    for fi, scale in ((3, 1e37), (4, fmt.min_normal * 8)):
        f = fam == fi
        tri[f] *= scale * rng.uniform(0.5, 30, (int(f.sum()), 1))
        org[f] *= scale * rng.uniform(0.5, 30, (int(f.sum()), 1))
        dirn[f] = np.where(rng.random((int(f.sum()), 1)) < 0.5, dirn[f],
                           (tri[f, 0:3] - org[f]))
    dirn[np.all(dirn == 0, axis=1)] = (0, 0, 1)
    hi = fmt.max_finite
    tri, org = np.clip(tri, -hi, hi), np.clip(org, -hi, hi)
    rays = Rays(fmt.quantize(org), fmt.quantize(dirn), np.full(n, np.inf, np.float32),
                np.zeros(n, np.uint8), np.zeros(n, np.int32), np.array([0, n], np.int64))
    with np.errstate(all="ignore"):          # huge/tiny families: inf and NaN in the clipping
        rs = setup(rays, np.array([[-1, -1, -1], [1, 1, 1]], np.float32), fmt)
    k, s = rs.k.copy(), rs.s.astype(np.float64)
    # 5: random finite bit patterns, any k, random S
    f = fam == 5
    m = int(f.sum())

    def bits(shape):
        e = rng.integers(0, 255, shape).astype(np.uint32)       # exponent < 255: finite
        x = (rng.integers(0, 2, shape).astype(np.uint32) << 31) | (e << 23) | \
            rng.integers(0, 1 << 23, shape).astype(np.uint32)
        return x.view(np.float32).astype(np.float64)
    tri[f], org[f], s[f] = bits((m, 9)), bits((m, 3)), bits((m, 3))
    k[f] = rng.integers(0, 4, (m, 3))
    return model_tests(np.clip(tri, -hi, hi), np.clip(org, -hi, hi), k,
                       np.clip(s, -hi, hi), fmt)


def golden_tests(g) -> tuple[PipeTests, np.ndarray]:
    """The int-ops of a traced scene (``EV_INT`` in order) as datapath operands, and the
    model's recorded flags/t/u/v bits ``(n, 4)`` (the same tests, as the tracer logged them)."""
    ev = g.events[g.events["kind"] == EV_INT]
    words = g.image.data
    idx = g.image.tri_base + TRI_WORDS * ev["tri"][:, None] + np.arange(TRI_WORDS)
    w = words[idx]                                                  # (n, 5) uint64
    halves = np.stack([w & np.uint64(0xFFFFFFFF), w >> np.uint64(32)], axis=2).reshape(-1, 10)
    tri = halves[:, :9].astype(np.uint32).view(np.float32)
    ray = g.rays.pk_start[ev["packet"]] + ev["lane"]
    t = model_tests(tri, g.rays.org[ray], g.setup.k[ray], g.setup.s[ray], g.cfg.fmt)
    return t, np.stack([ev["flags"], ev["t"], ev["u"], ev["v"]], axis=1).astype(np.int64)


def _pack(fmt: FPFormat, x: np.ndarray) -> list[int]:
    b = fmt.to_bits(x).astype(np.uint64)
    out = np.zeros(len(b), dtype=object)
    for j in range(b.shape[1]):
        out = out + (b[:, j].astype(object) << (fmt.width * j))
    return [int(v) for v in out]


def pipe_ports(tests: PipeTests, fmt: FPFormat, tag_width: int) -> tuple[dict, dict]:
    """The datapath's port values per test (ints; arrays packed as the ports carry them,
    element 0 in the low bits): inputs ``tri``, ``org``, ``k``, ``s``, ``tag`` (the test's index
    modulo ``2**tag_width``) and the model's outputs ``o_tag``, ``hit``, ``t``, ``u``, ``v``."""
    tri, org, s = _pack(fmt, tests.tri), _pack(fmt, tests.org), _pack(fmt, tests.s)
    k = [int(a) | int(b) << 2 | int(c) << 4 for a, b, c in tests.k]
    tag = [i % (1 << tag_width) for i in range(len(tests))]
    hit = tests.hit.astype(int).tolist()
    t, u, v = (fmt.to_bits(x).astype(np.int64).tolist() for x in (tests.t, tests.u, tests.v))
    return ({"tri": tri, "org": org, "k": k, "s": s, "tag": tag},
            {"o_tag": tag, "hit": hit, "t": t, "u": u, "v": v})


@dataclass
class PipeRun:
    tests: int
    cycles: int
    seconds: float
    latency: int
    outputs: int = 0                   # outputs seen (o_valid while enabled)
    mismatches: list = field(default_factory=list)    # each output that differs, in words

    @property
    def cycles_per_s(self) -> float:
        return self.cycles / self.seconds


def run_pipe(tests: PipeTests, fmt: FPFormat, *, seed: int = 0, p_bubble: float = 0.2,
             p_stall: float = 0.2, latencies: dict | None = None) -> PipeRun:
    """Drive ``tests`` through the datapath and compare every output at its exact cycle
    (latency ``L`` enabled cycles after its input) with the model; returns the mismatches."""
    from tb.harness.common import run_fixed_pipe
    n = len(tests)
    dut = IntersectPipe(fmt, tag_width=max(1, n.bit_length()), latencies=latencies)
    ins, outs = pipe_ports(tests, fmt, dut.tag_width)

    def describe(i):
        return (f"tri={tests.tri[i].tolist()} org={tests.org[i].tolist()} "
                f"k={tests.k[i].tolist()} s={tests.s[i].tolist()}")
    t0 = time.perf_counter()
    r = run_fixed_pipe(dut, ins, outs, seed=seed, p_bubble=p_bubble, p_stall=p_stall,
                       describe=describe)
    return PipeRun(n, r.cycles, time.perf_counter() - t0, dut.latency, r.outputs,
                   [f"IntersectPipe: {x}" for x in r.mismatches])


# ---- the whole unit ---------------------------------------------------------------------------

MASK64 = (1 << 64) - 1


class IntBench(wiring.Component):
    """The intersection unit with an ``IdealMemory`` behind an ``ItemReader`` (5 words a
    triangle) on its port; its streams passed through, ``words`` = words read. ``cache``: the
    RTC's int cache (``rtl/rtcmi.py``) instead of the ItemReader, so triangles that hit
    arrive one a cycle."""

    def __init__(self, cfg, image, *, latency: int = 20, tri_slots: int = 4,
                 cache: bool = False):
        addr_width = max(8, int(len(image.data) - 1).bit_length())
        self.unit = IntersectionUnit(cfg, addr_width=addr_width, tri_slots=tri_slots)
        if cache:
            from rtl.cache import Cache
            from rtl.rtcmi import rtcmi_geometries
            geom = rtcmi_geometries(cfg)["int"]
            geom = dataclasses.replace(geom, addr_width=addr_width, mem_addr_width=addr_width)
            self.reader = Cache(geom, tag_width=self.unit.tag_width, fast=cfg.fast_clock)
        else:
            self.reader = ItemReader(item_bits=cfg.int_item_bits, item_words=TRI_WORDS,
                                     addr_width=addr_width, tag_width=self.unit.tag_width,
                                     slots=tri_slots)
        self.memory = IdealMemory(image.data, addr_width=addr_width,
                                  tag_width=len(self.reader.mem.req.payload.tag), latency=latency)
        self.tri_base = image.tri_base
        sig = self.unit.signature.members
        members = {k: sig[k] for k in ("ray_in", "tri_in", "lane_out", "done", "result",
                                       "release", "int_ops", "tris", "busy")}
        members["words"] = Out(32)
        super().__init__(members)

    def elaborate(self, platform):
        m = Module()
        m.submodules.unit, m.submodules.memory = u, mem = self.unit, self.memory
        m.submodules.reader = r = self.reader
        wiring.connect(m, u.mem, r.port)
        wiring.connect(m, r.mem, mem.port)
        for name in ("ray_in", "tri_in", "done"):
            wiring.connect(m, wiring.flipped(getattr(self, name)), getattr(u, name))
        for name in ("lane_out", "result", "release"):
            wiring.connect(m, getattr(u, name), wiring.flipped(getattr(self, name)))
        m.d.comb += [r.base.eq(self.tri_base), self.words.eq(mem.reads)]
        for name in ("int_ops", "tris", "busy"):
            m.d.comb += getattr(self, name).eq(getattr(u, name))
        return m


@dataclass
class UnitStreams:
    """What the unit receives and must produce, from the golden model's event log."""
    rays: list            # RayWrite payloads
    tris: list            # TriRequest payloads
    ints: list            # (thread, lane, hit, t, u, v) per datapath output, in order
    lanes: list           # LaneResult payloads
    done: list            # PacketDone payloads
    results: list         # RayResult payloads
    int_ops: int
    leaves: int


def unit_streams(g, max_leaves: int | None = None) -> UnitStreams:
    """The intersection unit's streams for the first ``max_leaves`` non-empty leaves (all:
    then the final results are the model's ``Hits``, checked against the replay below)."""
    cfg, fmt, ev = g.cfg, g.cfg.fmt, g.events
    T = cfg.threads
    n_packets = g.rays.n_packets
    if n_packets > T:
        raise ValueError(f"{n_packets} packets but {T} threads: the bench loads every packet's "
                         "rays once; use a smaller image")
    bits = lambda x: int(fmt.to_bits(np.float32(x)))
    f32 = lambda b: np.uint32(b).view(np.float32)
    # Config.int_test = "projection": the unit keeps the direction where ``s`` was, k is 0
    proj = cfg.int_test == "projection"
    ray_k = np.zeros_like(g.setup.k) if proj else g.setup.k
    ray_s = g.rays.dir if proj else g.setup.s
    rays = []
    for p in range(n_packets):
        r0, r1 = int(g.rays.pk_start[p]), int(g.rays.pk_start[p + 1])
        for r in range(r0, r1):
            rays.append({"thread": p % T, "ray": {
                "packet": p, "lane": r - r0, "last": int(r == r1 - 1),
                "org": [bits(x) for x in g.rays.org[r]],
                "k": [int(x) for x in ray_k[r]], "s": [bits(x) for x in ray_s[r]],
                "tmax": bits(g.rays.tmax[r]), "anyhit": int(g.rays.anyhit[r])}})
    # replay the model's accept decisions to know every lane's best hit after each leaf
    best = {}
    for p in range(n_packets):
        r0, r1 = int(g.rays.pk_start[p]), int(g.rays.pk_start[p + 1])
        for r in range(r0, r1):
            best[p, r - r0] = [0, bits(g.rays.tmax[r]), 0, 0, -1]   # hit, t, u, v, tri id
    tris, ints, lanes = [], [], []
    leaves, sid, remaining, mask, int_ops = 0, -1, 0, 0, 0
    for row in ev:
        kind, pid = int(row["kind"]), int(row["packet"])
        if kind == EV_LEAF and row["count"] > 0:
            if max_leaves is not None and leaves == max_leaves:
                break
            leaves += 1
            remaining, mask = int(row["count"]), int(row["mask"])
        elif kind == EV_TRI:
            remaining -= 1
            sid = int(row["tri"])          # the unit reports the triangle's index
            tris.append({"thread": pid % T, "tri": int(row["tri"]), "mask": mask,
                         "last": int(remaining == 0)})
        elif kind == EV_INT:
            lane, flags = int(row["lane"]), int(row["flags"])
            t, u, v = (bits(f32(row[x])) for x in "tuv")
            ints.append((pid % T, lane, flags & 1, t, u, v))
            int_ops += 1
            if flags & 2:
                best[pid, lane] = [1, t, u, v, sid]
        if kind == EV_INT and remaining == 0:
            # the leaf's last triangle: this lane's result goes back to traversal
            top = mask.bit_length() - 1
            h = best[pid, lane]
            lanes.append({"thread": pid % T, "lane": lane, "hit": h[0], "t": h[1],
                          "last": int(lane == top)})
    done, results = [], []
    inf = bits(np.float32(np.inf))
    for p in range(n_packets):
        r0, r1 = int(g.rays.pk_start[p]), int(g.rays.pk_start[p + 1])
        done.append({"thread": p % T, "packet": p, "mask": (1 << (r1 - r0)) - 1})
        for r in range(r0, r1):
            h, t, u, v, tri = best[p, r - r0]
            results.append({"packet": p, "lane": r - r0, "last": int(r == r1 - 1),
                            "tri": tri & 0xFFFFFFFF if h else 0xFFFFFFFF,
                            "t": t if h else inf, "u": u if h else 0, "v": v if h else 0})
    if max_leaves is None:       # the replay must agree with the model's own final hits
        hits = g.hits
        index = g.image.tri_index(hits.tri)
        want = [{"tri": int(index[r]) & 0xFFFFFFFF, "t": bits(hits.t[r]),
                 "u": bits(hits.u[r]), "v": bits(hits.v[r])} for r in range(len(hits.t))]
        assert [{k: x[k] for k in ("tri", "t", "u", "v")} for x in results] == want
    return UnitStreams(rays, tris, ints, lanes, done, results, int_ops, leaves)


def unit_counters(s: UnitStreams, g, whole: bool) -> list[tuple[str, int]]:
    """``(counter, expected value)`` of the unit after the streams ``s``: ``int_ops`` (one per
    ``EV_INT``), ``tris`` (one triangle fetched per ``TriRequest``) and, for ``whole`` (every
    leaf of ``g``), the model's own ``int_ops``."""
    want = [("int_ops", s.int_ops), ("tris", len(s.tris))]
    if whole:
        want.append(("int_ops", int(g.counters.sum(axis=0)[C["int_ops"]])))
    return want


@dataclass
class UnitRun:
    int_ops: int
    cycles: int
    seconds: float
    counters: dict
    mismatches: list = field(default_factory=list)    # every difference from the model, in words

    @property
    def cycles_per_s(self) -> float:
        return self.cycles / self.seconds


def run_unit(g, *, max_leaves: int | None = None, seed: int = 0, idle: float = 0.3,
             stall: float = 0.3, latency: int = 20, tri_slots: int = 4,
             cache: bool = False) -> UnitRun:
    """Load the packets' rays, feed the golden TriRequests with random bubbles, drain the
    LaneResults with random back-pressure, then read out every packet's final hits; check the
    datapath outputs (``EV_INT``), the LaneResults, the RayResults and the counters against the
    model; returns every difference in ``mismatches``."""
    s = unit_streams(g, max_leaves)
    dut = IntBench(g.cfg, g.image, latency=latency, tri_slots=tri_slots, cache=cache)
    rng = random.Random(seed)
    pipe = dut.unit.pipe
    ints, lanes, results, released, info = [], [], [], [], {}

    async def source(ctx):
        await drive(ctx, dut.ray_in, s.rays)
        await drive(ctx, dut.tri_in, s.tris, rng=rng, idle=idle, t0=len(s.rays))

    async def sink(ctx):
        await drain(ctx, dut.lane_out, len(s.lanes), rng=rng, stall=stall, out=lanes,
                    timeout=3000)
        await drive(ctx, dut.done, s.done)
        info["cycles"] = lanes[-1][0] if lanes else 0

    async def readout(ctx):
        await drain(ctx, dut.result, len(s.results), rng=rng, stall=stall, out=results,
                    timeout=100_000)
        await ctx.tick().repeat(2)
        info.update({k: ctx.get(getattr(dut, k)) for k in ("int_ops", "tris", "words", "busy")})

    async def monitor(ctx):
        await watch(ctx, pipe.o_valid & pipe.en, pipe.o_tag, pipe.hit, pipe.t, pipe.u, pipe.v,
                    out=ints)

    async def releases(ctx):
        await watch(ctx, dut.release.valid, dut.release.payload, out=released)

    t0 = time.perf_counter()
    run(dut, source, sink, readout, background=[monitor, releases])
    seconds = time.perf_counter() - t0
    meta = dut.unit.pipe_meta
    bad: list = []
    for i, (row, want) in enumerate(zip(ints, s.ints)):
        cycle, tag, *out = row
        tag = meta.from_bits(tag)
        got = (int(tag.thread), int(tag.lane), *out)
        if got != want:
            bad.append(f"datapath output #{i} at cycle {cycle}: (thread, lane, hit, t, u, v) = "
                       f"{got}, model (EV_INT) {want}")
    streams = (("datapath output", ints, s.ints), ("LaneResult", lanes, s.lanes),
               ("RayResult", results, s.results))
    for name, got, want in streams[1:]:
        for i, ((cycle, p), w) in enumerate(zip(got, want)):
            if p != w:
                bad.append(f"{name} #{i} at cycle {cycle}: {p}, model {w}")
    for name, got, want in streams:
        if len(got) != len(want):
            bad.append(f"{name}s: {len(got)}, model {len(want)}")
    # each packet's thread is released in the cycle its last RayResult is taken
    last_cycles = [c for c, p in results if p["last"]]
    want_rel = list(zip(last_cycles, [d["thread"] for d in s.done]))
    if released != want_rel:
        bad.append(f"releases (cycle, thread) {released[:8]}..., want {want_rel[:8]}... "
                   "(the thread of each packet with its last result)")
    want_ctr = unit_counters(s, g, whole=max_leaves is None)
    if not cache:                   # a cache reads a triangle's words only on a miss
        want_ctr.append(("words", 5 * len(s.tris)))
        if max_leaves is None:      # the whole image: the model's own word count too
            want_ctr.append(("words", int(g.counters.sum(axis=0)[C["int_reads"]])))
    for k, w in want_ctr:
        if info[k] != w:
            bad.append(f"counter {k}: {info[k]}, model {w}")
    return UnitRun(s.int_ops, info["cycles"], seconds, info, bad)



if __name__ == "__main__":          # speed figures: python -m tb.units.intersection [width height]
    import sys
    import tempfile
    from model.config import Config
    from tb.units.list import golden
    w, h = (int(x) for x in sys.argv[1:3]) if len(sys.argv) > 2 else (16, 16)
    fmt = FPFormat()
    r = run_pipe(random_tests(600, fmt, seed=1), fmt, seed=1, p_bubble=0.0, p_stall=0.0)
    print(f"IntersectPipe (every stage busy): {r.cycles} cycles in {r.seconds:.1f} s = "
          f"{r.cycles_per_s:.0f} cycles/s")
    g = golden("scenes/cornell.toml", w, h, Config(), tempfile.mkdtemp())
    r = run_unit(g, seed=1, idle=0.2, stall=0.2)
    print(f"IntersectionUnit (cornell {w}x{h}, {r.int_ops} int-ops): {r.cycles} cycles in "
          f"{r.seconds:.1f} s = {r.cycles_per_s:.0f} cycles/s; counters {r.counters}")


def golden_stack(cfg, cache_dir, layers: int = 10, rays_per_packet: int = 1,
                 near_first: bool = False):
    """A stack of ``layers`` parallel quads (two triangles each) facing rays from +z, listed
    far to near, and a few rays per packet: every test of a lane hits and is closer than the
    last, back to back when a packet has one ray (the best-hit read-after-write case).
    ``near_first`` lists them near to far, each layer as two overlapping triangles that
    both cover every ray: every test after the first hits at or beyond the best and must be
    rejected, back to back (a stale best-hit read would accept it)."""
    quads = []
    for i in range(layers):
        z = float(-i)
        if near_first:
            quads += [_cover(z), [(3, 3, z), (-3, 3, z), (0, -4, z)]]
        else:
            quads += [[(-1, -1, z), (1, -1, z), (1, 1, z)], [(-1, -1, z), (1, 1, z), (-1, 1, z)]]
    # reversed: memory (and list) order runs from the farthest layer to the nearest
    return golden_tris(cfg, cache_dir, quads if near_first else quads[::-1], rays_per_packet)


def _cover(z: float) -> list:
    """A triangle in the plane ``z`` that covers every ray of ``golden_tris``."""
    return [(-3, -3, z), (3, -3, z), (0, 4, z)]


def _aside(z: float) -> list:
    """A triangle in the plane ``z`` beside every ray of ``golden_tris`` (a miss)."""
    return [(5, -1, z), (6, -1, z), (5, 1, z)]


def golden_newest_store(cfg, cache_dir):
    """One leaf listing, for every ray: a miss, a hit at t 9, a hit at t 7, a miss, a hit at
    t 8. Back to back (one ray a packet), the last test's candidates for the lane's best are
    the two stores three and two tests before it (t 9, then t 7): the newer, 7, is the best
    and rejects t 8; the older would accept it."""
    # rays start at z = 5 heading -z: t = 5 - z
    tris = [_aside(-4), _cover(-4), _cover(-2), _aside(-2), _cover(-3)]
    return golden_tris(cfg, cache_dir, tris)


def golden_tris(cfg, cache_dir, tris: list, rays_per_packet: int = 1):
    """The golden run of 8 rays from z = 5 heading -z (within x, y in [-1, 1] down to z = -10)
    against ``tris`` (one leaf when they are at most ``cfg.kd_leaf_size``, listed in order),
    ``rays_per_packet`` rays a packet."""
    from model.kdtree import build_kdtree
    from model.layout import build_image
    from tb.units.list import Golden
    tris = cfg.fmt.quantize(np.array(tris, np.float64)).astype(np.float32)
    tree = build_kdtree(tris, cfg, cache_dir=cache_dir)
    image = build_image(tris, tree, cfg)
    rng = np.random.default_rng(3)
    n = 8
    org = np.zeros((n, 3), np.float32)
    org[:, :2] = cfg.fmt.quantize(rng.uniform(-0.9, 0.9, (n, 2)))
    org[:, 2] = 5
    dirn = np.tile(np.array([0, 0, -1], np.float32), (n, 1))
    dirn[:, :2] = cfg.fmt.quantize(rng.uniform(-0.01, 0.01, (n, 2)))
    pk = np.arange(0, n + 1, rays_per_packet).astype(np.int64)
    rays = Rays(org, dirn, np.full(n, np.inf, np.float32), np.zeros(n, np.uint8),
                np.zeros(n, np.int32), pk)
    rs = setup(rays, image.bounds, cfg.fmt)
    from model.rtc import trace
    hits, ctrs, events = trace(image, rays, cfg, ray_setup=rs, record=True)
    return Golden(cfg, image, rays, rs, hits, ctrs, events)
