"""Round-robin memory bus: N requesters share one memory port; responses return by labeled broadcast.

Requests: each cycle the output register can take a request, the first requester with a valid
request at or after the round-robin pointer is granted (at most one grant per cycle) and the
pointer moves just past it, so a requester that keeps asking waits for at most N-1 other grants.
The request goes to memory with the label ``{tag, requester id}`` as its tag.

Responses: the memory's response is registered and broadcast to all requesters with its label;
only the requester whose id it carries sees ``valid`` and takes it (its ``ready`` back-pressures
the broadcast). Requesters keep any number of requests outstanding (tags are theirs to manage).

Latency: one register each way (request: accepted in cycle t, offered to memory in t+1;
response: accepted from memory in t, offered to the requester in t+1). Throughput: one request
and one response per cycle.

Counters: ``grants[i]`` per requester, ``req_cycles`` (cycles a request went to memory),
``resp_cycles`` (cycles a response was delivered), ``cycles`` (since reset).
"""
from __future__ import annotations

from amaranth.hdl import Array, Cat, Module, Mux, Signal
from amaranth.lib import data, wiring
from amaranth.lib.wiring import In, Out
from amaranth.utils import ceil_log2

from .memport import WORD_BITS, MemReadPort, connect_tags
from .common import COUNTER_BITS, OutputStage

__all__ = ["RoundRobinBus"]


class RoundRobinBus(wiring.Component):
    """``n`` word read ports (``inputs[i]``, tags of ``tag_width``) onto one port ``mem`` whose
    tags are ``tag_width + ceil_log2(n)`` bits (requester id in the top bits).

    ``policy="fixed"`` grants the lowest requesting id instead (unfair; a baseline for
    comparisons and for checking that the fairness check in ``tb/units/bus.py`` can fail).
    """

    def __init__(self, n: int, *, addr_width: int, tag_width: int, data_width: int = WORD_BITS,
                 policy: str = "round_robin"):
        if n < 1:
            raise ValueError(f"RoundRobinBus n={n}: need at least one requester")
        if policy not in ("round_robin", "fixed"):
            raise ValueError(f"RoundRobinBus policy={policy!r}: use 'round_robin' or 'fixed'")
        self.n, self.policy = n, policy
        self.id_bits = max(1, ceil_log2(n))
        port = MemReadPort(addr_width=addr_width, data_width=data_width, tag_width=tag_width)
        super().__init__({
            "inputs": In(port).array(n),
            "mem": Out(MemReadPort(addr_width=addr_width, data_width=data_width,
                                   tag_width=tag_width + self.id_bits)),
            "grants": Out(COUNTER_BITS).array(n),
            "req_cycles": Out(COUNTER_BITS),
            "resp_cycles": Out(COUNTER_BITS),
            "cycles": Out(COUNTER_BITS),
        })

    def elaborate(self, platform):
        m = Module()
        n, ins = self.n, self.inputs
        tag_width = len(ins[0].req.payload.tag)
        m.d.sync += self.cycles.eq(self.cycles + 1)

        # --- requests: round-robin grant into the output register -------------------------
        out = self.mem.req
        prio = Signal(range(n))
        grant = Signal(range(n))
        any_req = Signal()
        m.d.comb += any_req.eq(Cat(*[p.req.valid for p in ins]).any())
        with m.Switch(prio):
            for p in range(n):
                with m.Case(p):
                    order = [(p + i) % n for i in range(n)]
                    with m.If(ins[order[0]].req.valid):
                        m.d.comb += grant.eq(order[0])
                    for c in order[1:]:
                        with m.Elif(ins[c].req.valid):
                            m.d.comb += grant.eq(c)
        m.submodules.req_out = stage = OutputStage(out.payload.shape())
        wiring.connect(m, stage.o, wiring.flipped(out))
        m.d.comb += [stage.i.valid.eq(any_req),
                     stage.i.payload.addr.eq(Array(p.req.payload.addr for p in ins)[grant]),
                     stage.i.payload.tag.eq(Cat(Array(p.req.payload.tag for p in ins)[grant],
                                                grant))]
        load = Signal()
        m.d.comb += load.eq(stage.i.valid & stage.i.ready)
        for i in range(n):
            m.d.comb += ins[i].req.ready.eq(load & (grant == i))
            with m.If(load & (grant == i)):
                m.d.sync += self.grants[i].eq(self.grants[i] + 1)
        with m.If(load):
            m.d.sync += prio.eq(Mux(grant == n - 1, 0, grant + 1) if self.policy ==
                                "round_robin" else 0)
        with m.If(out.valid & out.ready):
            m.d.sync += self.req_cycles.eq(self.req_cycles + 1)

        # --- responses: labeled broadcast -------------------------------------------------
        src = self.mem.resp
        m.submodules.resp_out = bc = OutputStage(data.StructLayout({
            "data": len(src.payload.data), "tag": tag_width, "id": self.id_bits}))
        b_valid, b_data = bc.o.valid, bc.o.payload.data
        b_tag, b_id = bc.o.payload.tag, bc.o.payload.id
        m.d.comb += [bc.i.valid.eq(src.valid), src.ready.eq(bc.i.ready),
                     bc.i.payload.data.eq(src.payload.data),
                     bc.i.payload.tag.eq(src.payload.tag[:tag_width]),
                     bc.i.payload.id.eq(src.payload.tag[tag_width:]),
                     bc.o.ready.eq(Array(p.resp.ready for p in ins)[b_id] if n > 1
                                   else ins[0].resp.ready)]
        for i in range(n):
            m.d.comb += [ins[i].resp.valid.eq(b_valid & (b_id == i)),
                         ins[i].resp.payload.data.eq(b_data),
                         ins[i].resp.payload.tag.eq(b_tag)]
        with m.If(b_valid & bc.o.ready):
            m.d.sync += self.resp_cycles.eq(self.resp_cycles + 1)
        return m


class MemoryInterface(wiring.Component):
    """The RTC memory interface: one :class:`~rtl.cache.Cache` per geometry in ``geoms`` (e.g.
    trav, list and int cache of each RTC), all on one :class:`RoundRobinBus` to ``mem``.

    Ports: ``unit{i}`` (the unit side of cache i), ``bases[i]`` (word address of cache i's item
    0), ``mem`` (words; tag = ``{cache's tag, requester id}``); counters ``hits[i]``,
    ``misses[i]``, ``grants[i]`` (memory words cache i read) and ``req_cycles`` (bus busy
    cycles). Latency and throughput: those of the cache plus one cycle each way on the bus.
    ``fast``: the caches' ``fast`` registers (``Config.fast_clock``).
    """

    def __init__(self, geoms, *, tag_width: int = 4, policy: str = "round_robin",
                 fast: bool = False):
        from .cache import Cache   # the cache imports model/, keep the bare bus import-light

        if not geoms:
            raise ValueError("MemoryInterface needs at least one cache geometry")
        widths = {g.mem_addr_width for g in geoms}
        if len(widths) != 1:
            raise ValueError(f"all caches must use one memory address width, got {widths}")
        self.caches = [Cache(g, tag_width=tag_width, fast=fast) for g in geoms]
        addr_width = widths.pop()
        bus_tag = max(len(c.mem.req.payload.tag) for c in self.caches)
        self.bus = RoundRobinBus(len(geoms), addr_width=addr_width, tag_width=bus_tag,
                                 policy=policy)
        k = len(geoms)
        members = {f"unit{i}": In(c.port.signature.flip()) for i, c in enumerate(self.caches)}
        members.update({
            "bases": In(addr_width).array(k),
            "mem": Out(self.bus.mem.signature),
            "hits": Out(COUNTER_BITS).array(k),
            "misses": Out(COUNTER_BITS).array(k),
            "grants": Out(COUNTER_BITS).array(k),
            "req_cycles": Out(COUNTER_BITS),
        })
        super().__init__(members)

    def elaborate(self, platform):
        m = Module()
        m.submodules.bus = bus = self.bus
        wiring.connect(m, bus.mem, wiring.flipped(self.mem))
        m.d.comb += self.req_cycles.eq(bus.req_cycles)
        for i, c in enumerate(self.caches):
            m.submodules[f"cache{i}"] = c
            wiring.connect(m, wiring.flipped(getattr(self, f"unit{i}")), c.port)
            connect_tags(m, c.mem, bus.inputs[i])
            m.d.comb += [
                c.base.eq(self.bases[i]),
                self.hits[i].eq(c.hits), self.misses[i].eq(c.misses),
                self.grants[i].eq(bus.grants[i]),
            ]
        return m
