"""The RTC memory interface (RTC-MI): three caches in front of the RTCs' memory ports.

:class:`SharedRTCMI` is the paper's (Sections 4.1.3, 4.2.2): three caches for the whole chip,
each behind a round-robin bus (:class:`~rtl.bus.RoundRobinBus`) of every RTC's port of its kind
that returns data by labeled broadcast (``Config.cache_topology = "shared"``). :class:`RTCMI`
is one RTC's private three caches (``"private"``).

* trav cache: 64-bit kd-node words, addressed by word (``trav_cache_kb``);
* list cache: 64-bit words of the triangle list (two 32-bit entries each), by word
  (``list_cache_kb``);
* int cache: whole triangles (``int_item_bits`` = 288 bits: the 9 vertex floats) by triangle
  index, so the intersection unit gets a triangle in one response (``int_cache_kb``).

Sizes are rounded down to what the geometry allows (a power-of-two number of sets): the
standard 64 / 64 / 144 KB are exact (144 KB = 4 096 triangles of 36 bytes). Each cache's
memory side is a 64-bit word port (``mem_trav``, ``mem_list``, ``mem_int``) for the chip's bus.
The hit/miss sequence of each cache for a given request sequence is
``model.cache.CacheModel``'s (``rtcmi_geometries`` gives the geometries; the request
addresses are ``model.rtc.rtcmi_trace``'s).

Latency and throughput: the cache's (``rtl/cache.py``: a hit answers 3 cycles after the
request, 6 with ``cfg.fast_clock``; one lookup a cycle); shared, one more register each way on
the bus (a hit 5 cycles, 8 with ``fast_clock``), one request and one response a cycle per cache
for all RTCs together.
"""
from __future__ import annotations

from amaranth.hdl import Cat, Module
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from model.cache import CacheGeometry, cache_geometry
from model.config import Config, ConfigError

from .bus import RoundRobinBus
from .cache import STALLS, Cache
from .common import COUNTER_BITS
from .memport import MemReadPort

__all__ = ["RTCMI", "SharedRTCMI", "port_tags", "CACHES", "word_cache_geometry", "rtcmi_geometries"]

CACHES = ("trav", "list", "int")
PORTS = {"trav": "node_mem", "list": "list_mem", "int": "tri_mem"}   # the RTC's port of each


def word_cache_geometry(cfg: Config, kb: int, served: int = 1) -> CacheGeometry:
    """A cache of 64-bit memory words (item = word, item address = word address) of ``kb`` KB
    rounded down to a power of two, with the configuration's ways, line length, outstanding
    misses and queue."""
    if kb < 1:
        raise ConfigError(f"cache of {kb} KB: caches need at least 1 KB")
    size = 1 << ((kb * 1024).bit_length() - 1)
    return CacheGeometry(size_bytes=size, line_items=cfg.cache_line_words, item_bits=64,
                         item_span=64, ways=cfg.cache_ways,
                         outstanding=served * cfg.cache_outstanding,
                         queue=served * cfg.cache_queue, addr_width=cfg.addr_bits,
                         mem_addr_width=cfg.addr_bits)


def _int_geometry(cfg: Config, served: int = 1) -> CacheGeometry:
    """Triangle cache of at most ``int_cache_kb`` KB with a power-of-two number of sets."""
    per_set = cfg.cache_ways * cfg.cache_line_words * cfg.int_item_bits      # bits
    sets = (cfg.int_cache_kb * 1024 * 8) // per_set
    if sets < 1:
        raise ConfigError(f"int_cache_kb={cfg.int_cache_kb}: too small for one set of "
                          f"{cfg.cache_ways} way(s) x {cfg.cache_line_words} triangle(s)")
    sets = 1 << (sets.bit_length() - 1)
    return cache_geometry(cfg, "int", served, size_bytes=sets * per_set // 8)


def rtcmi_geometries(cfg: Config, served: int = 1) -> dict[str, CacheGeometry]:
    """``{"trav", "list", "int"}`` geometries of an RTC-MI's caches serving ``served`` RTCs
    (one RTC's private caches: 1; the shared RTC-MI: ``cfg.rtcs``): ``cache_outstanding``
    misses in flight and ``cache_queue`` requests in each cache per RTC served, so the shared
    caches keep as much in flight as the private caches they replace."""
    return {"trav": word_cache_geometry(cfg, cfg.trav_cache_kb, served),
            "list": word_cache_geometry(cfg, cfg.list_cache_kb, served),
            "int": _int_geometry(cfg, served)}


class _RTCMIBase(wiring.Component):
    """What both RTC-MIs share: the three caches (``self.caches``), their memory ports
    ``mem_trav``, ``mem_list``, ``mem_int``, ``tri_base`` and the counters ``hits[3]``,
    ``misses[3]``; a subclass adds its unit-side ports and connects them."""

    def _members(self, cfg: Config, units: dict) -> dict:
        members = {**units, "tri_base": In(cfg.addr_bits),
                   "hits": Out(COUNTER_BITS).array(3), "misses": Out(COUNTER_BITS).array(3)}
        for name in CACHES:
            members[f"mem_{name}"] = Out(self.caches[name].mem.signature)
        return members

    def mem(self, name: str):
        return getattr(self, f"mem_{name}")

    def _caches(self, m: Module) -> None:
        """The caches as submodules, their memory ports, bases and counters."""
        for i, name in enumerate(CACHES):
            c = self.caches[name]
            m.submodules[f"cache_{name}"] = c
            wiring.connect(m, c.mem, wiring.flipped(self.mem(name)))
            m.d.comb += [self.hits[i].eq(c.hits), self.misses[i].eq(c.misses)]
        m.d.comb += [self.caches["trav"].base.eq(0), self.caches["list"].base.eq(0),
                     self.caches["int"].base.eq(self.tri_base)]


class RTCMI(_RTCMIBase):
    """The three caches of one RTC (see the module docstring).

    Ports: ``node``, ``list``, ``tri`` (servers for the RTC's ``node_mem``, ``list_mem``,
    ``tri_mem``: connect with ``wiring.connect(m, rtc.node_mem, rtcmi.node)``), ``mem_trav``,
    ``mem_list``, ``mem_int`` (each cache's 64-bit word port, tags the cache's; ``mem(name)``), ``tri_base`` (word address of
    triangle 0); counters ``hits[3]``, ``misses[3]``.
    """

    def __init__(self, cfg: Config, rtc):
        self.cfg = cfg
        self.geoms = rtcmi_geometries(cfg)
        self.caches = {}
        for name in CACHES:
            port = getattr(rtc, PORTS[name])
            self.caches[name] = Cache(self.geoms[name], tag_width=len(port.req.payload.tag),
                                      fast=cfg.fast_clock)
        def server(name):
            g, port = self.geoms[name], getattr(rtc, PORTS[name])
            return In(MemReadPort(addr_width=g.addr_width, data_width=g.item_bits,
                                  tag_width=len(port.req.payload.tag)))
        super().__init__(self._members(cfg, {
            "node": server("trav"), "list": server("list"), "tri": server("int")}))

    def elaborate(self, platform):
        m = Module()
        self._caches(m)
        unit_side = {"trav": self.node, "list": self.list, "int": self.tri}
        for name in CACHES:
            wiring.connect(m, wiring.flipped(unit_side[name]), self.caches[name].port)
        return m

def port_tags(rtc) -> dict[str, int]:
    """``{"trav", "list", "int"}``: the tag bits of an RTC's port to each cache."""
    return {name: len(getattr(rtc, PORTS[name]).req.payload.tag) for name in CACHES}


class SharedRTCMI(_RTCMIBase):
    """The paper's RTC-MI: the three caches of the chip, shared by ``n`` RTCs whose ports'
    tags are ``tags[c]`` bits wide (:func:`port_tags`).

    Cache c (trav, list, int) sits behind a :class:`~rtl.bus.RoundRobinBus` whose requesters
    are the RTCs' ports of its kind (RTC r is requester r): one request a cycle is granted
    round-robin and goes to the cache labeled ``{tag, r}``; the cache's response is broadcast
    with its label and RTC r alone takes it. Each RTC keeps its units' requests outstanding as
    with a private cache (the tags are its own).

    Ports: ``node[r]``, ``list[r]``, ``tri[r]`` (servers for RTC r's ``node_mem``, ``list_mem``,
    ``tri_mem``), ``mem_trav``, ``mem_list``, ``mem_int`` (each cache's 64-bit word port;
    ``mem(name)``), ``tri_base``; counters ``hits[3]``, ``misses[3]`` (per cache: every
    request is one lookup, so the bus carried ``hits + misses`` requests), ``waits[3]``
    (cycles in which an RTC's request on the cache's bus waited: another RTC's was granted,
    or the cache took none), ``stalls[len(STALLS) * c + i]`` (cache c's
    :data:`rtl.cache.STALLS` counters: why it took no request or gave no response).
    """

    def __init__(self, cfg: Config, n: int, tags: dict[str, int]):
        self.cfg, self.n = cfg, n
        self.geoms = rtcmi_geometries(cfg, n)
        self.buses, self.caches = {}, {}
        for name in CACHES:
            g = self.geoms[name]
            bus = RoundRobinBus(n, addr_width=g.addr_width, data_width=g.item_bits,
                                tag_width=tags[name])
            self.buses[name] = bus
            self.caches[name] = Cache(g, tag_width=len(bus.mem.req.payload.tag),
                                      fast=cfg.fast_clock)
        units = {key: In(self.buses[name].inputs[0].signature.flip()).array(self.n)
                 for key, name in (("node", "trav"), ("list", "list"), ("tri", "int"))}
        super().__init__({**self._members(cfg, units), "waits": Out(COUNTER_BITS).array(3),
                          "stalls": Out(COUNTER_BITS).array(3 * len(STALLS))})

    def elaborate(self, platform):
        m = Module()
        self._caches(m)
        unit_side = {"trav": self.node, "list": self.list, "int": self.tri}
        for i, name in enumerate(CACHES):
            bus = self.buses[name]
            m.submodules[f"bus_{name}"] = bus
            for r in range(self.n):
                wiring.connect(m, wiring.flipped(unit_side[name][r]), bus.inputs[r])
            wiring.connect(m, bus.mem, self.caches[name].port)
            for j, ctr in enumerate(self.caches[name].stalls):
                m.d.comb += self.stalls[len(STALLS) * i + j].eq(ctr)
            waiting = Cat(*(p.req.valid & ~p.req.ready for p in unit_side[name]))
            with m.If(waiting.any()):
                m.d.sync += self.waits[i].eq(self.waits[i] + 1)
        return m
