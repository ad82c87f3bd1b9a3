"""The SaarCOR chip: ``cfg.rtcs`` ray tracing cores behind the RTC-MI, on one memory bus.

:class:`RTCArray` is the ray-tracing half of the chip (the paper's Figure 2 without the RGS):
``cfg.rtcs`` :class:`~rtl.rtc.RTC` s and ``cfg.rtcmis`` RTC-MIs — one
:class:`~rtl.rtcmi.SharedRTCMI` for all RTCs (``cache_topology = "shared"``, the paper's) or an
:class:`~rtl.rtcmi.RTCMI` per RTC (``"private"``) — whose 3 × ``rtcmis`` caches sit on one
:class:`~rtl.bus.RoundRobinBus` (requester ``3 * k + c``: cache c = trav, list, int of RTC-MI
k) to a single 64-bit memory read port ``mem`` (the memory controller's: in simulation
:class:`~tb.harness.memory.SDRAMMemory`, ``mem_chips`` SDRAM chips with XOR address hashing at the
``mem_clock_ratio`` clock ratio; on an FPGA the board's controller).

Ports: ``rays[r]`` / ``results[r]`` (the RTCs' ``RayIn`` / ``RayResult`` streams), ``mem``,
image constants ``node_base``, ``list_base``, ``tri_base``, ``root``; counters per RTC
(``rtc_counters[r]``: the RTC's ``COUNTERS`` and ``sub_busy`` packed, see
:func:`counter_names`), per cache ``hits[3 * k + c]``, ``misses[3 * k + c]``,
``grants[3 * k + c]`` (memory words the cache read), ``waits[c]`` (shared: cycles in which an
RTC's request waited on cache c's bus; 0 when private), ``cache_stalls[len(STALLS) * c + i]``
(shared: the cycles cache c lost, by the reasons of :data:`rtl.cache.STALLS`; 0 when
private), ``mem_reads``.

Latency and throughput are the RTCs' and caches' (a cache hit 3 cycles; one bus register
each way, one memory request and one response per cycle for the whole chip).
"""
from __future__ import annotations

from amaranth.hdl import Cat, Module, Signal
from amaranth.lib import data, stream, wiring
from amaranth.lib.wiring import In, Out

from model.config import Config
from model.rgs.secondary import FIX_BITS

from .bus import RoundRobinBus
from .cache import STALLS as CACHE_STALLS
from .common import COUNTER_BITS
from .memport import WORD_BITS, MemReadPort, connect_tags
from .rtc import COUNTERS, RTC, STALLS
from .stalls import REASONS, StallCounters
from .rtc_streams import RayIn, RayResult
from .rgs.slave import POOL_COUNTERS, RAY_COUNTERS
from .rtcmi import CACHES, RTCMI, SharedRTCMI, port_tags
from .traversal import NODE_BITS

__all__ = ["RTCArray", "counter_names"]


def counter_names(cfg: Config) -> list[str]:
    """Fields of one ``rtc_counters[r]`` word, 32 bits each, first name in the low bits."""
    return list(COUNTERS) + list(STALLS) + [f"sub_busy{j}" for j in range(cfg.trav_subunits)]


class RTCArray(wiring.Component):
    """``cfg.rtcs`` RTCs with their RTC-MIs on one bus; see the module docstring."""

    def __init__(self, cfg: Config, extra_tag_widths: tuple = ()):
        self.cfg = cfg
        n = cfg.rtcs
        self.rtcs = [RTC(cfg) for _ in range(n)]
        self.shared = cfg.cache_topology == "shared"
        self.mis = ([SharedRTCMI(cfg, n, port_tags(self.rtcs[0]))] if self.shared
                    else [RTCMI(cfg, rtc) for rtc in self.rtcs])
        k = len(self.mis)
        tag = max(len(mi.mem(c).req.payload.tag) for mi in self.mis for c in CACHES)
        tag = max(tag, *extra_tag_widths) if extra_tag_widths else tag
        self.n_extra = len(extra_tag_widths)
        self.bus = RoundRobinBus(3 * k + self.n_extra, addr_width=cfg.addr_bits, tag_width=tag)
        self.names = counter_names(cfg)
        super().__init__({
            "rays": In(stream.Signature(RayIn(cfg))).array(n),
            "results": Out(stream.Signature(RayResult(cfg))).array(n),
            "mem": Out(self.bus.mem.signature),
            "node_base": In(cfg.addr_bits), "list_base": In(cfg.addr_bits),
            "tri_base": In(cfg.addr_bits), "root": In(NODE_BITS),
            "rtc_counters": Out(COUNTER_BITS * len(self.names)).array(n),
            "hits": Out(COUNTER_BITS).array(3 * k), "misses": Out(COUNTER_BITS).array(3 * k),
            "grants": Out(COUNTER_BITS).array(3 * k + self.n_extra),
            "waits": Out(COUNTER_BITS).array(3),
            "cache_stalls": Out(COUNTER_BITS).array(3 * len(CACHE_STALLS)),
            "mem_reads": Out(COUNTER_BITS),
            **({"ext": In(MemReadPort(addr_width=cfg.addr_bits, data_width=WORD_BITS,
                                      tag_width=tag)).array(self.n_extra)}
               if self.n_extra else {}),
        })

    def elaborate(self, platform):
        m = Module()
        m.submodules.bus = bus = self.bus
        wiring.connect(m, bus.mem, wiring.flipped(self.mem))
        m.d.comb += self.mem_reads.eq(bus.req_cycles)
        k = len(self.mis)
        for e in range(self.n_extra):
            wiring.connect(m, bus.inputs[3 * k + e], wiring.flipped(self.ext[e]))
            m.d.comb += self.grants[3 * k + e].eq(bus.grants[3 * k + e])
        for j, mi in enumerate(self.mis):
            m.submodules["rtcmi" if self.shared else f"rtcmi{j}"] = mi
            m.d.comb += mi.tri_base.eq(self.tri_base)
            for c, name in enumerate(CACHES):
                i = 3 * j + c
                connect_tags(m, mi.mem(name), bus.inputs[i])
                m.d.comb += [self.hits[i].eq(mi.hits[c]), self.misses[i].eq(mi.misses[c]),
                             self.grants[i].eq(bus.grants[i])]
        if self.shared:
            for c in range(3):
                m.d.comb += self.waits[c].eq(self.mis[0].waits[c])
            for a, b in zip(self.cache_stalls, self.mis[0].stalls):
                m.d.comb += a.eq(b)
        for r, rtc in enumerate(self.rtcs):
            m.submodules[f"rtc{r}"] = rtc
            mi, p = (self.mis[0], r) if self.shared else (self.mis[r], None)
            for unit, server in (("node_mem", mi.node), ("list_mem", mi.list),
                                 ("tri_mem", mi.tri)):
                wiring.connect(m, getattr(rtc, unit), server if p is None else server[p])
            wiring.connect(m, wiring.flipped(self.rays[r]), rtc.rays)
            wiring.connect(m, rtc.results, wiring.flipped(self.results[r]))
            m.d.comb += [rtc.node_base.eq(self.node_base), rtc.list_base.eq(self.list_base),
                         rtc.root.eq(self.root)]
            values = ([getattr(rtc, k) for k in COUNTERS] + [getattr(rtc, k) for k in STALLS]
                      + list(rtc.sub_busy))
            m.d.comb += self.rtc_counters[r].eq(Cat(*values))
        return m


class Chip(wiring.Component):
    """The SaarCOR chip: RGS master, one RGS slave per RTC (``rtl/rgs/``: eye rays,
    results, secondary rays, colour) with its shading cache and texel cache,
    :class:`RTCArray` (the RTCs, the RTC-MI(s), the bus: requesters ``3 k + c`` the RTC-MI
    caches, ``3 rtcmis + s`` slave s's shading cache, ``3 rtcmis + rtcs + s`` its texel cache), one
    memory port ``mem`` for the memory controller. With ``cfg.secondary_rays`` false (no
    light registers, reflection depth 0) the slaves are eye-ray-only
    (``Slave.elaborate_eye_only``) and there are no shading or texel caches; with
    ``cfg.tex_cache_kb`` 0 the slaves have no texture unit and no texel caches.

    Host side (inputs held for the frame): the image constants ``node_base``, ``list_base``,
    ``tri_base``, ``root``, ``rec_base`` (the slave records), the scene box
    ``box_lo``/``box_hi`` and ``box_cull`` (1, the default: rays that miss the box never
    enter traversal; 0 only to measure what that saves); the camera ``pos``, ``corner``, ``dx``, ``dy`` (format words, as
    ``model.raygen.eye_rays`` quantizes them for the sample image), ``width``/``height``
    (pixels), ``tiles_x``/``tiles_y`` (tiles of the sample image); ``eps``, ``lights``,
    ``light_point``, ``n_lights``, ``reflect_depth`` (the slaves' secondary rays);
    ``light_col``, ``amb``, ``bg``, ``w_eye``, ``eye_miss``, ``colour`` (the slaves' colour,
    ``model.shading.frame_colour_registers``). ``start``
    (one cycle) renders a frame; ``busy`` is high from the cycle after ``start`` until every
    ray the frame spawned has finished and its result has left; ``done`` = not busy.
    ``results[i]`` (``cfg.result_ports`` Out streams of ``SlaveResult``): every ray's id (eye
    packet and lane, depth, sub; path with ``cfg.refraction``), hit and colour contribution, and the ambient records of the
    hits, in any order; slave s's on stream ``s % result_ports`` (a registered round-robin
    over its slaves: one result a cycle each).

    Counters: ``cycles`` (busy cycles of the last frame), ``rays_in`` (rays into the RTCs),
    ``results_out`` (ray results; the ambient records are not counted), ``packets[s]`` (eye
    packets slave s got), per slave ``rays_eye``, ``rays_shadow``, ``rays_reflect``,
    ``rays_refract``, ``sec_busy``, the pool's ``rtl.rgs.POOL_COUNTERS``
    (``slave_counters[s]``), its shading cache's
    ``shade_hits``/``shade_misses`` and its texel cache's ``tex_hits``/``tex_misses`` (0
    where there is none), and :class:`RTCArray`'s (``rtc_counters``, ``hits``,
    ``misses``, ``waits``, ``cache_stalls``, ``grants``, ``mem_reads``).
    """

    SLAVE_COUNTERS = (*RAY_COUNTERS.values(), "sec_busy", *POOL_COUNTERS, *REASONS)
    """Per slave: rays into its RTC by kind, the secondary datapath's busy cycles, and its
    cycles by what it did (``rtl/stalls.py``): work = a ray sent to the RTC or a result taken
    from it, memory = a shading or texel read in flight, blocked = the RTC not taking a ray or
    the chip's output not taking a result, starved = nothing to do."""

    def __init__(self, cfg: Config):
        from model.layout import REC_BITS
        from .cache import Cache
        from .rgs import (COORD_BITS, DEPTH_BITS, RGSMaster, Slave, SlaveResult,
                          shade_cache_geometry, tex_cache_geometry)
        from .rtc_streams import vec3
        self.cfg = cfg
        n = cfg.rtcs
        self.master = RGSMaster(cfg, n)
        self.slaves = [Slave(cfg) for _ in range(n)]
        # eye rays only (no secondary-ray hardware): no shading caches, no bus requesters for
        # them; their counters (shade_hits, shade_misses, grants[3 rtcmis + s]) stay 0 (as the
        # texel caches' where there are none)
        geom = shade_cache_geometry(cfg)
        self.shade_caches = ([Cache(geom, tag_width=1) for _ in range(n)]
                             if cfg.secondary_rays else [])
        # texel caches (bus requesters 3 rtcmis + n + s), where the slaves have a texture unit
        self.tex_caches = ([Cache(tex_cache_geometry(cfg), tag_width=1) for _ in range(n)]
                           if self.slaves[0].tex is not None else [])
        self.array = RTCArray(cfg, tuple(len(c.mem.req.payload.tag)
                                         for c in self.shade_caches + self.tex_caches))
        assert geom.item_bits == REC_BITS
        v3 = vec3(cfg)
        L = max(1, cfg.rgs_lights)
        members = {
            "start": In(1), "busy": Out(1), "done": Out(1),
            "node_base": In(cfg.addr_bits), "list_base": In(cfg.addr_bits),
            "tri_base": In(cfg.addr_bits), "root": In(NODE_BITS), "rec_base": In(cfg.addr_bits),
            "box_lo": In(v3), "box_hi": In(v3), "box_cull": In(1, init=1),
            "pos": In(v3), "corner": In(v3), "dx": In(v3), "dy": In(v3),
            "width": In(COORD_BITS), "height": In(COORD_BITS),
            "tiles_x": In(COORD_BITS), "tiles_y": In(COORD_BITS),
            "eps": In(cfg.fmt.width), "lights": In(v3).array(L), "light_point": In(L),
            "n_lights": In(range(cfg.rgs_lights + 1)), "reflect_depth": In(DEPTH_BITS),
            "light_col": In(v3).array(L), "amb": In(cfg.fmt.width), "bg": In(v3),
            "w_eye": In(cfg.fmt.width), "eye_miss": In(data.ArrayLayout(FIX_BITS, 3)),
            "colour": In(1),
            "results": Out(stream.Signature(SlaveResult(cfg))).array(cfg.result_ports),
            "cycles": Out(COUNTER_BITS), "rays_in": Out(COUNTER_BITS),
            "results_out": Out(COUNTER_BITS),
            "packets": Out(COUNTER_BITS).array(n),
            "slave_counters": Out(COUNTER_BITS * len(self.SLAVE_COUNTERS)).array(n),
            "shade_hits": Out(COUNTER_BITS).array(n), "shade_misses": Out(COUNTER_BITS).array(n),
            "tex_hits": Out(COUNTER_BITS).array(n), "tex_misses": Out(COUNTER_BITS).array(n),
        }
        for name in ("mem", "rtc_counters", "hits", "misses", "waits", "cache_stalls",
                     "mem_reads"):
            members[name] = self.array.signature.members[name]
        members["grants"] = Out(COUNTER_BITS).array(3 * cfg.rtcmis + 2 * n)
        super().__init__(members)

    def _slave_stalls(self, m: Module, s: int, slave) -> StallCounters:
        """Slave ``s``'s cycles by what it did (:data:`SLAVE_COUNTERS`)."""
        mems = [slave.shade] + ([slave.texel] if hasattr(slave, "texel") else [])
        m.submodules[f"stalls_slave{s}"] = st = StallCounters(ports=len(mems))
        act = Signal(COUNTER_BITS, name=f"slave{s}_activity")
        m.d.sync += act.eq(act + (slave.rays.valid & slave.rays.ready)
                           + (slave.results.valid & slave.results.ready))
        m.d.comb += [st.ops.eq(act), st.out_ready.eq(0),
                     st.out_valid.eq((slave.rays.valid & ~slave.rays.ready)
                                     | (slave.out.valid & ~slave.out.ready))]
        for i, p in enumerate(mems):
            m.d.comb += [st.req_valid[i].eq(p.req.valid), st.req_ready[i].eq(p.req.ready),
                         st.resp[i].eq(p.resp.valid & p.resp.ready)]
        return st

    def _result_port(self, m: Module, i: int, res, slaves: list) -> None:
        """Output stream ``res`` (``results[i]``): a round-robin over ``slaves`` into a
        registered output. Latency 1, one result a cycle."""
        from amaranth.hdl import Mux
        from .common import OutputStage, rr_pick
        from .rgs import SlaveResult
        m.submodules[f"res_out{i}" if i else "res_out"] = out = OutputStage(SlaveResult(self.cfg))
        wiring.connect(m, out.o, wiring.flipped(res))
        n = len(slaves)
        p2 = 1 << max(0, (n - 1).bit_length())
        valid = Signal(p2)
        m.d.comb += valid.eq(Cat(*(sl.out.valid for sl in slaves)))
        ptr = Signal(range(p2), name=f"chip_results{i}_ptr" if i else None)
        anyv, pick = rr_pick(m, valid, ptr, f"chip_results{i}" if i else "chip_results")
        m.d.comb += out.i.valid.eq(anyv)
        for s, sl in enumerate(slaves):
            sel = pick == s
            with m.If(sel):
                m.d.comb += out.i.payload.eq(sl.out.payload)
            m.d.comb += sl.out.ready.eq(out.i.ready & sel)
        with m.If(out.i.valid & out.i.ready):
            m.d.sync += ptr.eq(Mux(pick == n - 1, 0, pick + 1))

    def elaborate(self, platform):
        m = Module()
        cfg, n = self.cfg, self.cfg.rtcs
        m.submodules.array = arr = self.array
        m.submodules.master = master = self.master
        wiring.connect(m, arr.mem, wiring.flipped(self.mem))
        for k in ("node_base", "list_base", "tri_base", "root"):
            m.d.comb += getattr(arr, k).eq(getattr(self, k))
        for k in ("rtc_counters", "hits", "misses", "waits", "cache_stalls", "grants"):
            for a, b in zip(getattr(self, k), getattr(arr, k)):
                m.d.comb += a.eq(b)
        m.d.comb += [self.mem_reads.eq(arr.mem_reads), master.start.eq(self.start),
                     master.tiles_x.eq(self.tiles_x), master.tiles_y.eq(self.tiles_y)]
        for s in range(n):
            m.d.comb += self.packets[s].eq(master.packets[s])

        # -- slaves: rays for their RTC, its results back, their shading caches ---------------------
        counts = []
        for s, slave in enumerate(self.slaves):
            m.submodules[f"slave{s}"] = slave
            wiring.connect(m, master.req[s], slave.req)
            if self.shade_caches:
                cache = self.shade_caches[s]
                m.submodules[f"shade_cache{s}"] = cache
                wiring.connect(m, slave.shade, cache.port)
                connect_tags(m, cache.mem, arr.ext[s])
                m.d.comb += [cache.base.eq(self.rec_base), self.shade_hits[s].eq(cache.hits),
                             self.shade_misses[s].eq(cache.misses)]
            if self.tex_caches:
                cache = self.tex_caches[s]
                m.submodules[f"tex_cache{s}"] = cache
                wiring.connect(m, slave.texel, cache.port)
                connect_tags(m, cache.mem, arr.ext[n + s])
                m.d.comb += [cache.base.eq(0), self.tex_hits[s].eq(cache.hits),
                             self.tex_misses[s].eq(cache.misses)]
            for k in ("pos", "corner", "dx", "dy", "width", "height", "box_lo", "box_hi",
                      "box_cull", "eps",
                      "light_point", "n_lights", "reflect_depth", "amb", "bg", "w_eye",
                      "eye_miss", "colour"):
                m.d.comb += getattr(slave, k).eq(getattr(self, k))
            for a, b in zip(slave.lights, self.lights):
                m.d.comb += a.eq(b)
            for a, b in zip(slave.light_col, self.light_col):
                m.d.comb += a.eq(b)
            wiring.connect(m, slave.rays, arr.rays[s])
            wiring.connect(m, arr.results[s], slave.results)
            stalls = self._slave_stalls(m, s, slave)
            m.d.comb += self.slave_counters[s].eq(
                Cat(*(getattr(slave, k) for k in self.SLAVE_COUNTERS[:-len(REASONS)]),
                    *(getattr(stalls, k) for k in REASONS)))
            rays = arr.rays[s]
            counts.append(rays.valid & rays.ready)
        rays_in = Signal(range(n + 1))
        m.d.comb += rays_in.eq(sum(counts[1:], counts[0]))

        # -- results: per output stream, round-robin over its slaves into a registered output --
        k = cfg.result_ports
        for i, res in enumerate(self.results):
            self._result_port(m, i, res, self.slaves[i::k])

        # -- frame control and counters ------------------------------------------------------------
        outs = [res.valid & res.ready & ~res.payload.shade for res in self.results]
        out_now = Signal(range(k + 1))                  # ray results (not ambient) this cycle
        m.d.comb += out_now.eq(sum(outs[1:], outs[0]))
        idle = Signal()
        m.d.comb += idle.eq(master.dispatched & ~master.queued &
                            Cat(*(sl.idle for sl in self.slaves)).all() &
                            ~Cat(*(res.valid for res in self.results)).any())
        m.d.comb += self.done.eq(~self.busy)
        with m.If(self.busy):
            m.d.sync += [self.cycles.eq(self.cycles + 1), self.rays_in.eq(self.rays_in + rays_in),
                         self.results_out.eq(self.results_out + out_now)]
            with m.If(idle):
                m.d.sync += self.busy.eq(0)
        with m.If(self.start):
            m.d.sync += [self.busy.eq(1), self.cycles.eq(0), self.rays_in.eq(0),
                         self.results_out.eq(0)]
        return m
