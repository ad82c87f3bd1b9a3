"""Testbench for ``rtl/cache.py``: drive an item-address stream, check data, order and hits.

The cache is checked against two references: every response must equal the item in the memory
image (``model.cache.item_values``), in request order with the request's tag; the per-request
hit/miss sequence (``lookup_valid``/``lookup_hit``) and the counters must equal
``model.cache.CacheModel`` on the same stream. Memory behind the cache is one of:

* ``"ideal"``: :class:`tb.harness.memory.IdealMemory` (fixed latency, in order);
* ``"sdram"``: :class:`tb.harness.memory.SDRAMMemory` (responses of different chips overtake);
* ``"random"``: a testbench responder answering in random order after random delays, with
  random back-pressure on requests (stresses the fill logic beyond what the models produce).
"""
from __future__ import annotations

import random
from dataclasses import dataclass

import numpy as np
from amaranth.hdl import Elaboratable, Module
from amaranth.lib import wiring

from model.cache import CacheGeometry, CacheModel, item_values
from rtl.cache import Cache
from tb.harness.memory import IdealMemory, SDRAMMemory

from tb.harness.common import drain, drive, run, watch
from tb.units.memory import random_memory

__all__ = ["CacheRun", "run_cache", "check_cache_run"]


class _System(Elaboratable):
    def __init__(self, cache, memory):
        self.cache, self.memory = cache, memory

    def elaborate(self, platform):
        m = Module()
        m.submodules.cache, m.submodules.memory = self.cache, self.memory
        wiring.connect(m, self.cache.mem, self.memory.port)
        return m


@dataclass
class CacheRun:
    responses: list      # (cycle, {"data", "tag"}) in arrival order
    sent: list           # cycle of each accepted request
    lookups: list        # (cycle, hit) per classified request
    hits: int            # hardware counters at the end
    misses: int
    words_fetched: int   # memory words the cache asked for
    cycles: int


def run_cache(geom: CacheGeometry, image: np.ndarray, addrs, *, base: int = 0,
              tag_width: int = 4, memory: str = "ideal", latency: int = 8, seed: int = 0,
              idle: float = 0.0, stall: float = 0.0, gaps=None, check: bool = True,
              fast: bool = False) -> CacheRun:
    """Simulate the cache on ``addrs`` (item indices) and, with ``check``, assert it is right.

    ``idle``/``stall``: probabilities of a request bubble / of response back-pressure per cycle;
    ``gaps``: idle cycles before each request (instead of random bubbles); ``fast``: the
    cache's ``fast`` registers (``Config.fast_clock``).
    """
    rng = random.Random(seed)
    addrs = np.asarray(addrs, dtype=np.int64)
    cache = Cache(geom, tag_width=tag_width, fast=fast)
    fetched = []
    if memory == "ideal":
        mem = IdealMemory(image, addr_width=geom.mem_addr_width, tag_width=len(cache.mem.req.payload.tag),
                          latency=latency)
        dut = _System(cache, mem)
    elif memory == "sdram":
        mem = SDRAMMemory(image, addr_width=geom.mem_addr_width,
                          tag_width=len(cache.mem.req.payload.tag), latency=latency)
        dut = _System(cache, mem)
    elif memory == "random":
        mem, dut = None, cache
    else:
        raise ValueError(f"memory={memory!r}: use 'ideal', 'sdram' or 'random'")

    reqs = [{"addr": int(a), "tag": i % (1 << tag_width)} for i, a in enumerate(addrs)]
    sent, got, lookups, state = [], [], [], {}

    async def source(ctx):
        ctx.set(cache.base, base)
        sent.extend(await drive(ctx, cache.port.req, reqs, rng=rng, idle=idle, gaps=gaps))

    async def sink(ctx):
        await drain(ctx, cache.port.resp, len(reqs), rng=rng, stall=stall, out=got,
                    timeout=20_000)
        state.update(hits=ctx.get(cache.hits), misses=ctx.get(cache.misses),
                     cycles=got[-1][0] + 1 if got else 0)
        if mem is not None:
            state["words"] = ctx.get(mem.reads) if memory == "ideal" else \
                sum(ctx.get(w) for w in mem.words)

    background = [lambda ctx: watch(ctx, cache.lookup_valid, cache.lookup_hit, out=lookups)]
    if mem is None:
        background.append(lambda ctx: random_memory(ctx, cache.mem, image, rng, log=fetched))
    run(dut, source, sink, background=background)

    result = CacheRun(responses=got, sent=sent, lookups=[(c, bool(h)) for c, h in lookups],
                      hits=state["hits"], misses=state["misses"],
                      words_fetched=state.get("words", len(fetched)), cycles=state["cycles"])
    if check:
        check_cache_run(result, geom, image, addrs, reqs, base)
    return result


def check_cache_run(r: CacheRun, geom, image, addrs, reqs, base) -> None:
    """Compare a run with the memory image and the hit/miss model (AssertionError on mismatch)."""
    expect = item_values(image, geom, addrs, base)
    assert len(r.responses) == len(reqs), f"{len(r.responses)} responses for {len(reqs)} requests"
    for i, ((cycle, p), want, req) in enumerate(zip(r.responses, expect, reqs)):
        assert p["tag"] == req["tag"], (f"response {i} (cycle {cycle}) has tag {p['tag']}, "
                                        f"expected {req['tag']}: lost, duplicated or reordered")
        assert p["data"] == want, (f"response {i} (item {req['addr']}, cycle {cycle}): "
                                   f"data {p['data']:#x} != memory {want:#x}")
    model = CacheModel(geom)
    want_hits = model.access(addrs)
    got_hits = np.array([h for _, h in r.lookups], bool)
    assert len(got_hits) == len(addrs), f"{len(got_hits)} lookups for {len(addrs)} requests"
    bad = np.flatnonzero(got_hits != want_hits)
    assert bad.size == 0, (f"hit/miss differs from the model at {bad.size} requests, first #"
                           f"{bad[:1]} (item {addrs[bad[0]] if bad.size else None}): RTL "
                           f"{got_hits[bad[:5]]}, model {want_hits[bad[:5]]}")
    assert (r.hits, r.misses) == (model.hits, model.misses), \
        f"counters hits={r.hits} misses={r.misses}, model {model.hits}/{model.misses}"
    assert r.words_fetched == model.misses * geom.line_words, \
        f"{r.words_fetched} words fetched for {model.misses} misses of {geom.line_words} words"
