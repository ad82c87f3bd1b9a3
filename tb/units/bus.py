"""Testbench for ``rtl/bus.py``: N random requesters, a random-order memory, random back-pressure.

Checks, every cycle and at the end:

* every response reaches the requester that asked, exactly once, with the right data (each
  requester reads its own address range, so a misdelivered word cannot match);
* at most one request is granted per cycle;
* fairness: while a requester keeps ``valid`` high, at most N-1 grants go to others;
* the hardware counters (grants per requester, request/response cycles) match what was seen.
"""
from __future__ import annotations

import random
from dataclasses import dataclass

import numpy as np

from rtl.bus import RoundRobinBus

from tb.harness.common import as_dict, run
from tb.units.memory import random_memory

__all__ = ["GrantCheck", "Outstanding", "BusRun", "run_bus", "SystemRun", "run_system"]


class GrantCheck:
    """The bus's grant rules, cycle by cycle (:meth:`step` with every input's request
    ``valid`` and ``ready``): at most one grant per cycle, and round robin: while a requester
    keeps ``valid`` high, at most N-1 grants go to others. Breaks are collected in
    ``violations`` (raise them after the run: an exception inside a simulation leaves the other
    testbenches dangling); ``grants`` counts the grants per requester, ``max_wait`` the most
    grants to others while one requester waited."""

    def __init__(self, n: int):
        self.n = n
        self.waited = [0] * n
        self.grants = [0] * n
        self.max_wait = 0
        self.violations: list[str] = []

    def step(self, cycle: int, valid, ready) -> None:
        n = self.n
        granted = [k for k in range(n) if valid[k] and ready[k]]
        if len(granted) > 1:
            self.violations.append(f"cycle {cycle}: {len(granted)} grants in one cycle {granted}")
        for k in range(n):
            if k in granted:
                self.waited[k] = 0
                self.grants[k] += 1
            elif valid[k]:
                self.waited[k] += len(granted)
                self.max_wait = max(self.max_wait, self.waited[k])
                if self.waited[k] == n:
                    self.violations.append(f"cycle {cycle}: requester {k} waited "
                                           f"{self.waited[k]} grants (> N-1 = {n - 1}): round "
                                           "robin is unfair")
            else:
                self.waited[k] = 0


class Outstanding:
    """Requester ``i``'s reads in flight (tag -> word address): every response must answer one
    of them, with the word at its address in ``image``."""

    def __init__(self, i: int, image):
        self.i, self.image, self.tags = i, image, {}

    def free(self, tag: int) -> bool:
        return tag not in self.tags

    def sent(self, tag: int, addr: int) -> None:
        self.tags[tag] = addr

    def received(self, tag: int, data: int) -> None:
        i = self.i
        assert tag in self.tags, (
            f"requester {i} got a response with tag {tag} it is not waiting for "
            f"(outstanding {sorted(self.tags)}): misrouted or duplicated")
        addr = self.tags.pop(tag)
        assert data == int(self.image[addr]), (
            f"requester {i}, tag {tag}: data {data:#x} is not word {addr} "
            f"({int(self.image[addr]):#x})")


@dataclass
class BusRun:
    per_requester: list   # responses received per requester
    max_wait: int         # most grants to others while one requester waited
    grants: list          # hardware grant counters
    cycles: int


def run_bus(n: int, n_reqs: int, *, tag_width: int = 2, seed: int = 0, idle: float = 0.3,
            stall: float = 0.3, mem_stall: float = 0.2, max_delay: int = 20,
            words_per_requester: int = 64, policy: str = "round_robin") -> BusRun:
    """Simulate ``n`` requesters sending ``n_reqs`` reads each through the bus."""
    rng = random.Random(seed)
    image = np.random.default_rng(seed).integers(0, 1 << 63, n * words_per_requester,
                                                 dtype=np.uint64)
    addr_width = max(1, (len(image) - 1).bit_length())
    dut = RoundRobinBus(n, addr_width=addr_width, tag_width=tag_width, policy=policy)
    outstanding = [Outstanding(i, image) for i in range(n)]
    received = [0] * n
    check = GrantCheck(n)
    counters = {}
    done = [False] * n

    def requester(i):
        port = dut.inputs[i]

        async def source(ctx):
            sent = 0
            while sent < n_reqs:
                free = [t for t in range(1 << tag_width) if outstanding[i].free(t)]
                if not free or rng.random() < idle:
                    ctx.set(port.req.valid, 0)
                    await ctx.tick()
                    continue
                tag = rng.choice(free)
                addr = i * words_per_requester + rng.randrange(words_per_requester)
                ctx.set(port.req.payload, {"addr": addr, "tag": tag})
                ctx.set(port.req.valid, 1)
                await ctx.tick().until(port.req.ready)
                outstanding[i].sent(tag, addr)
                sent += 1
            ctx.set(port.req.valid, 0)

        async def sink(ctx):
            while received[i] < n_reqs:
                ready = rng.random() >= stall
                ctx.set(port.resp.ready, int(ready))
                _, _, v, p = await ctx.tick().sample(port.resp.valid, port.resp.payload)
                if v and ready:
                    p = as_dict(p)
                    outstanding[i].received(p["tag"], p["data"])
                    received[i] += 1
            ctx.set(port.resp.ready, 0)
            done[i] = True
            if all(done):
                counters["grants"] = [ctx.get(g) for g in dut.grants]
                counters["req_cycles"] = ctx.get(dut.req_cycles)
                counters["resp_cycles"] = ctx.get(dut.resp_cycles)
                counters["cycles"] = ctx.get(dut.cycles)
        return source, sink

    async def monitor(ctx):
        sig = [s for p in dut.inputs for s in (p.req.valid, p.req.ready)]
        cycle = 0
        async for _, _, *vals in ctx.tick().sample(*sig):
            check.step(cycle, vals[0::2], vals[1::2])
            cycle += 1

    tbs = [tb for i in range(n) for tb in requester(i)]
    run(dut, *tbs, background=[
        monitor,
        lambda ctx: random_memory(ctx, dut.mem, image, rng, max_delay=max_delay,
                                  stall=mem_stall)])
    assert not check.violations, "; ".join(check.violations[:5])
    assert received == [n_reqs] * n, f"responses received per requester: {received}"
    assert all(not o.tags for o in outstanding), "requests left without a response"
    assert counters["grants"] == [n_reqs] * n, f"grant counters {counters['grants']}"
    assert check.grants == [n_reqs] * n, f"grants seen {check.grants}"
    assert counters["req_cycles"] == counters["resp_cycles"] == n * n_reqs, counters
    return BusRun(per_requester=received, max_wait=check.max_wait, grants=counters["grants"],
                  cycles=counters["cycles"])


@dataclass
class SystemRun:
    hits: list            # per cache, hardware counters
    misses: list
    grants: list          # memory words read per cache (bus grant counters)
    words_per_chip: list  # SDRAM counters
    bus_busy: int         # cycles a request went to memory
    cycles: int


def run_system(geoms, streams, *, bases=None, chips: int = 4, latency: int = 20,
               tag_width: int = 4, seed: int = 0, idle: float = 0.1,
               stall: float = 0.1) -> SystemRun:
    """Caches (``geoms``) + bus + SDRAM model, each cache fed its item stream; checks every
    cache's responses and hit/miss sequence as :func:`tb.units.cache.run_cache` does."""
    from amaranth.hdl import Elaboratable, Module
    from amaranth.lib import wiring

    from rtl.bus import MemoryInterface
    from tb.harness.memory import SDRAMMemory

    from tb.units.cache import CacheRun, check_cache_run
    from tb.harness.common import drain, drive, watch

    rng = random.Random(seed)
    bases = [0] * len(geoms) if bases is None else bases
    span = max(b + (int(np.max(s)) + 1) * g.item_span // 64 + 1
               for g, s, b in zip(geoms, streams, bases))
    image = np.random.default_rng(seed).integers(0, 1 << 64, span, dtype=np.uint64)
    mi = MemoryInterface(geoms, tag_width=tag_width)
    mem = SDRAMMemory(image, addr_width=geoms[0].mem_addr_width, tag_width=len(mi.mem.req.payload.tag),
                      chips=chips, latency=latency)

    class Top(Elaboratable):
        def elaborate(self, platform):
            m = Module()
            m.submodules.mi, m.submodules.mem = mi, mem
            wiring.connect(m, mi.mem, mem.port)
            return m

    k = len(geoms)
    reqs = [[{"addr": int(a), "tag": j % (1 << tag_width)} for j, a in enumerate(s)]
            for s in streams]
    sent, got, lookups = [[] for _ in range(k)], [[] for _ in range(k)], [[] for _ in range(k)]
    done, state = [False] * k, {}

    def unit(i):
        port = getattr(mi, f"unit{i}")

        async def source(ctx):
            ctx.set(mi.bases[i], bases[i])
            sent[i].extend(await drive(ctx, port.req, reqs[i], rng=rng, idle=idle))

        async def sink(ctx):
            await drain(ctx, port.resp, len(reqs[i]), rng=rng, stall=stall, out=got[i],
                        timeout=20_000)
            done[i] = True
            if all(done):
                state.update(hits=[ctx.get(x) for x in mi.hits],
                             misses=[ctx.get(x) for x in mi.misses],
                             grants=[ctx.get(x) for x in mi.grants],
                             words=[ctx.get(x) for x in mem.words],
                             busy=ctx.get(mi.req_cycles), cycles=ctx.get(mem.cycles))
        return source, sink

    def watcher(i):
        c = mi.caches[i]
        return lambda ctx: watch(ctx, c.lookup_valid, c.lookup_hit, out=lookups[i])

    run(Top(), *[tb for i in range(k) for tb in unit(i)],
        background=[watcher(i) for i in range(k)])
    for i, g in enumerate(geoms):
        r = CacheRun(responses=got[i], sent=sent[i], lookups=[(c, bool(h)) for c, h in lookups[i]],
                     hits=state["hits"][i], misses=state["misses"][i],
                     words_fetched=state["grants"][i], cycles=state["cycles"])
        check_cache_run(r, g, image, np.asarray(streams[i]), reqs[i], bases[i])
    return SystemRun(hits=state["hits"], misses=state["misses"], grants=state["grants"],
                     words_per_chip=state["words"], bus_busy=state["busy"],
                     cycles=state["cycles"])
