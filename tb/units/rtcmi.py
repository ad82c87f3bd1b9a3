"""Testbench for ``rtl/rtcmi.py``'s :class:`SharedRTCMI`: ``cfg.rtcs`` RTCs' worth of random
requesters on the three shared caches, the SDRAM model behind them (one round-robin bus for the
three caches' misses, as on the chip), random request gaps and response back-pressure.

Checks, every cycle and at the end:

* every requester gets exactly its responses, in its request order, each with its tag and the
  memory's item (nothing lost, duplicated or delivered to another RTC);
* each cache's hit/miss sequence is :class:`model.cache.CacheModel`'s replay of the requests in
  the order the cache took them (recorded at the cache's port: the RTL's own interleaving);
* each cache's bus grants at most one request a cycle, round robin (:class:`GrantCheck`);
* the counters: ``hits``/``misses`` the model's, ``waits`` the cycles in which a requester
  waited, memory words the misses' lines.
"""
from __future__ import annotations

import random
from dataclasses import dataclass

import numpy as np
from amaranth.hdl import Elaboratable, Module
from amaranth.lib import wiring

from model.cache import CacheModel, item_values
from model.config import Config
from rtl.bus import RoundRobinBus
from rtl.memport import connect_tags
from rtl.rtcmi import CACHES, SharedRTCMI
from tb.harness.common import drain, drive, run, watch
from tb.harness.memory import SDRAMMemory
from tb.units.bus import GrantCheck

__all__ = ["RTCMIRun", "run_shared_rtcmi"]


@dataclass
class RTCMIRun:
    cycles: int
    hits: dict            # per cache: the hardware counters
    misses: dict
    waits: dict
    max_waiting: dict     # per cache: the most requesters waiting on its bus in one cycle
    max_wait: dict        # per cache: the most grants to others while one requester waited


def run_shared_rtcmi(cfg: Config, streams: dict[str, list], *, tag_width: int = 3,
                     seed: int = 0, idle: float = 0.2, stall: float = 0.2) -> RTCMIRun:
    """Simulate the shared RTC-MI of ``cfg`` (``cfg.rtcs`` requesters per cache); requester r of
    cache c reads the items ``streams[c][r]`` (node and list words, triangle indices) with
    tags ``0, 1, 2, ...`` modulo ``2**tag_width``. Raises AssertionError on any broken check."""
    n = cfg.rtcs
    rng = random.Random(seed)
    mi = SharedRTCMI(cfg, n, {c: tag_width for c in CACHES})
    words = max(int(np.max(s)) + 1 for c in ("trav", "list") for s in streams[c])
    tri_base = words
    span = tri_base + 5 * (max(int(np.max(s)) for s in streams["int"]) + 1) + 8
    image = np.random.default_rng(seed).integers(0, 1 << 64, span, dtype=np.uint64)
    bus = RoundRobinBus(3, addr_width=cfg.addr_bits,
                        tag_width=max(len(mi.mem(c).req.payload.tag) for c in CACHES))
    mem = SDRAMMemory(image, addr_width=cfg.addr_bits, tag_width=len(bus.mem.req.payload.tag),
                      chips=cfg.mem_chips, latency=cfg.mem_latency)

    class Top(Elaboratable):
        def elaborate(self, platform):
            m = Module()
            m.submodules.mi, m.submodules.bus, m.submodules.mem = mi, bus, mem
            for i, c in enumerate(CACHES):
                connect_tags(m, mi.mem(c), bus.inputs[i])
            wiring.connect(m, bus.mem, mem.port)
            m.d.comb += mi.tri_base.eq(tri_base)
            return m

    side = {"trav": mi.node, "list": mi.list, "int": mi.tri}
    reqs = {c: [[{"addr": int(a), "tag": j % (1 << tag_width)} for j, a in enumerate(s)]
                for s in streams[c]] for c in CACHES}
    got = {c: [[] for _ in range(n)] for c in CACHES}
    order = {c: [] for c in CACHES}        # (cycle, addr) of each request the cache took
    lookups = {c: [] for c in CACHES}      # (cycle, hit) of each lookup
    checks = {c: GrantCheck(n) for c in CACHES}
    waiting = {c: 0 for c in CACHES}
    waited_cycles = {c: 0 for c in CACHES}
    state, left = {}, [3 * n]

    def requester(c, r):
        port = side[c][r]

        async def source(ctx):
            await drive(ctx, port.req, reqs[c][r], rng=rng, idle=idle)

        async def sink(ctx):
            await drain(ctx, port.resp, len(reqs[c][r]), rng=rng, stall=stall,
                        out=got[c][r], timeout=20_000)
            left[0] -= 1
            if not left[0]:
                state.update({k: {c: ctx.get(getattr(mi, k)[i]) for i, c in enumerate(CACHES)}
                              for k in ("hits", "misses", "waits")},
                             grants=[ctx.get(g) for g in bus.grants], cycles=ctx.get(mem.cycles))
        return source, sink

    def monitor(c):
        ports = side[c]

        async def step(ctx):
            sig = [s for p in ports for s in (p.req.valid, p.req.ready)]
            cycle = 0
            async for _, _, *vals in ctx.tick().sample(*sig):
                valid, ready = vals[0::2], vals[1::2]
                checks[c].step(cycle, valid, ready)
                w = sum(1 for v, r in zip(valid, ready) if v and not r)
                waiting[c] = max(waiting[c], w)
                waited_cycles[c] += w > 0
                cycle += 1
        return step

    def recorders(c):
        cache = mi.caches[c]
        p = cache.port.req
        return [lambda ctx: watch(ctx, p.valid & p.ready, p.payload.addr, out=order[c]),
                lambda ctx: watch(ctx, cache.lookup_valid, cache.lookup_hit, out=lookups[c])]

    run(Top(), *[tb for c in CACHES for r in range(n) for tb in requester(c, r)],
        background=[monitor(c) for c in CACHES] + [x for c in CACHES for x in recorders(c)])

    for c in CACHES:
        geom = mi.geoms[c]
        base = tri_base if c == "int" else 0
        assert not checks[c].violations, f"{c} bus: " + "; ".join(checks[c].violations[:3])
        for r in range(n):                 # each requester: its items, its tags, in its order
            want = item_values(image, geom, np.asarray(streams[c][r], np.int64), base)
            assert len(got[c][r]) == len(reqs[c][r]), (
                f"{c} cache, RTC {r}: {len(got[c][r])} responses for {len(reqs[c][r])} requests")
            for i, ((cycle, p), q, w) in enumerate(zip(got[c][r], reqs[c][r], want)):
                assert p["tag"] == q["tag"] and p["data"] == w, (
                    f"{c} cache, RTC {r}, response {i} (cycle {cycle}): tag {p['tag']} data "
                    f"{p['data']:#x}, expected tag {q['tag']} data {int(w):#x} (item "
                    f"{q['addr']}): lost, duplicated, reordered or another RTC's")
        addrs = np.array([a for _, a in order[c]], np.int64)
        assert len(addrs) == sum(len(s) for s in streams[c]), f"{c}: {len(addrs)} lookups"
        model = CacheModel(geom)
        want_hits = model.access(addrs)
        got_hits = np.array([bool(h) for _, h in lookups[c]])
        bad = np.flatnonzero(got_hits != want_hits)
        assert bad.size == 0, (f"{c} cache: hit/miss differs from the model's replay of the "
                               f"taken order at {bad.size} requests, first #{bad[:1]}")
        assert (state["hits"][c], state["misses"][c]) == (model.hits, model.misses), c
        assert state["waits"][c] == waited_cycles[c], (
            f"{c}: waits counter {state['waits'][c]}, cycles seen waiting {waited_cycles[c]}")
    assert state["grants"] == [state["misses"][c] * mi.geoms[c].line_words
                               for c in CACHES], state["grants"]   # memory words: whole lines
    return RTCMIRun(cycles=state["cycles"], hits=state["hits"], misses=state["misses"],
                    waits=state["waits"], max_waiting=waiting,
                    max_wait={c: checks[c].max_wait for c in CACHES})
