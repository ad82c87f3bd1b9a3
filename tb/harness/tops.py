"""The harness's tops: every unit and top that can be exported as Verilog (:data:`TOPS`,
:func:`build_top`, :func:`export`; the command is ``saarcor verilog``), the one-RTC FPGA top
:class:`RTCTop` and the unit-level simulation top :class:`RTCSim`.

The ``rtc`` top (:class:`RTCTop`) is the synthesizable one-RTC chip: the RTC's three read
ports (node, list, triangle) through its RTC-MI's caches share one :class:`RoundRobinBus` to a
single memory read port ``mem`` (``docs/memory-interface.md``, ``docs/fpga.md``) that an FPGA
memory controller serves. ``rtc_core`` is the bare RTC (three memory ports).
``tb/harness/memory.py``'s memories are simulation models and are not exported.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

from amaranth.back import verilog
from amaranth.hdl import Module
from amaranth.lib import stream, wiring
from amaranth.lib.wiring import In, Out

from model.cache import cache_geometry
from model.config import Config, ConfigError
from rtl.common import COUNTER_BITS
from rtl.memport import connect_tags
from rtl.rtc import RTC, attach_memories, drive_header, tri_reader
from rtl.rtc_streams import RayIn, RayResult
from tb.harness.memory import IdealMemory

__all__ = ["RTCTop", "RTCSim", "TOPS", "build_top", "export"]


class RTCTop(wiring.Component):
    """One RTC with a single memory read port: the synthesizable top for an FPGA.

    The RTC's node, list and triangle ports go through its RTC-MI (``rtl/rtcmi.py``: trav and
    list caches of 64-bit words, the int cache of whole triangles; ``caches=False`` leaves the
    caches out: the triangle port is then served by an :class:`~rtl.memport.ItemReader`, 5
    words a triangle) onto a :class:`~rtl.bus.RoundRobinBus`, whose port is ``mem``:
    ``MemReadPort`` requester, 32-bit word addresses, 64-bit data, tag =
    ``{requester tag, requester id (2 bits: 0 node, 1 list, 2 triangle)}``.

    Ports: ``rays``, ``results``, ``node_base``, ``list_base``, ``tri_base``, ``root`` and the
    counters as :class:`~rtl.rtc.RTC`; ``mem``; ``hits[3]``, ``misses[3]`` (caches) and
    ``mem_reads`` (words read from memory). Latency: the RTC's plus, per memory access, the
    cache's (hit 3 cycles) and one bus register each way; one memory request per cycle.
    """

    def __init__(self, cfg: Config, *, caches: bool = True):
        from rtl.bus import RoundRobinBus
        from rtl.rtc import COUNTERS, RTC, tri_reader
        from rtl.rtcmi import CACHES, RTCMI

        self.cfg, self.with_caches = cfg, caches
        self.rtc = rtc = RTC(cfg)
        if caches:
            self.rtcmi = RTCMI(cfg, rtc)
            ports = [self.rtcmi.mem(name) for name in CACHES]
        else:
            self.reader = tri_reader(cfg, rtc)
            ports = [rtc.node_mem, rtc.list_mem, self.reader.mem]
        self.bus = RoundRobinBus(3, addr_width=cfg.addr_bits,
                                 tag_width=max(len(p.req.payload.tag) for p in ports))
        members = {name: m for name, m in rtc.signature.members.items()
                   if not name.endswith("_mem")}
        members.update({
            "tri_base": In(cfg.addr_bits),
            "mem": Out(self.bus.mem.signature),
            "hits": Out(COUNTER_BITS).array(3), "misses": Out(COUNTER_BITS).array(3),
            "mem_reads": Out(COUNTER_BITS),
        })
        self._counters = list(COUNTERS) + ["cycles"]
        super().__init__(members)

    def elaborate(self, platform):
        from rtl.rtcmi import CACHES
        m = Module()
        m.submodules.rtc = rtc = self.rtc
        m.submodules.bus = bus = self.bus
        wiring.connect(m, bus.mem, wiring.flipped(self.mem))
        if self.with_caches:
            m.submodules.rtcmi = mi = self.rtcmi
            wiring.connect(m, rtc.node_mem, mi.node)
            wiring.connect(m, rtc.list_mem, mi.list)
            wiring.connect(m, rtc.tri_mem, mi.tri)
            m.d.comb += mi.tri_base.eq(self.tri_base)
            for i, name in enumerate(CACHES):
                connect_tags(m, mi.mem(name), bus.inputs[i])
                m.d.comb += [self.hits[i].eq(mi.hits[i]), self.misses[i].eq(mi.misses[i])]
        else:
            m.submodules.tri_reader = r = self.reader
            wiring.connect(m, rtc.tri_mem, r.port)
            m.d.comb += r.base.eq(self.tri_base)
            for i, port in enumerate((rtc.node_mem, rtc.list_mem, r.mem)):
                connect_tags(m, port, bus.inputs[i])
        wiring.connect(m, wiring.flipped(self.rays), rtc.rays)
        wiring.connect(m, rtc.results, wiring.flipped(self.results))
        for name in ("node_base", "list_base", "root"):
            m.d.comb += getattr(rtc, name).eq(getattr(self, name))
        for name in self._counters:
            m.d.comb += getattr(self, name).eq(getattr(rtc, name))
        for j in range(self.cfg.trav_subunits):
            m.d.comb += self.sub_busy[j].eq(rtc.sub_busy[j])
        m.d.comb += self.mem_reads.eq(bus.req_cycles)
        return m


def _fp(kind: str) -> Callable:
    def make(cfg: Config, latency: int | None):
        from rtl import fp
        cls = {"add": fp.FPAdd, "mul": fp.FPMul, "div": fp.FPDiv, "sqrt": fp.FPSqrt,
               "cmp": fp.FPCompare,
               "minmax": fp.FPMinMax, "conv": fp.FPFromInt}[kind]
        kw = {} if latency is None else {"latency": latency}
        return cls(cfg.fmt, **kw)
    return make


def _cache(unit: str) -> Callable:
    def make(cfg: Config, latency):
        from rtl.cache import Cache
        return Cache(cache_geometry(cfg, unit), fast=cfg.fast_clock)
    return make


def _memif(cfg: Config, latency):
    from rtl.bus import MemoryInterface
    return MemoryInterface([cache_geometry(cfg, u) for u in ("trav", "list", "int")],
                           fast=cfg.fast_clock)


def _bus(cfg: Config, latency):
    from rtl.bus import RoundRobinBus
    return RoundRobinBus(3, addr_width=32, tag_width=4)


def _unit(path: str, cls: str) -> Callable:
    def make(cfg: Config, latency):
        import importlib
        return getattr(importlib.import_module(path, "rtl"), cls)(cfg)
    return make


def _pipe(cfg: Config, latency):
    from rtl.intersection import IntersectPipe
    return IntersectPipe(cfg.fmt, latencies=cfg.fp_latencies())


# top name -> (factory(cfg, latency) -> component, description)
TOPS: dict[str, tuple[Callable, str]] = {
    "fp_add": (_fp("add"), "FP adder/subtractor (rtl/fp/add.py)"),
    "fp_mul": (_fp("mul"), "FP multiplier (rtl/fp/mul.py)"),
    "fp_div": (_fp("div"), "FP divider (rtl/fp/div.py)"),
    "fp_sqrt": (_fp("sqrt"), "FP square root (rtl/fp/sqrt.py)"),
    "fp_cmp": (_fp("cmp"), "FP compare (rtl/fp/cmp.py)"),
    "fp_minmax": (_fp("minmax"), "FP min/max (rtl/fp/cmp.py)"),
    "fp_conv": (_fp("conv"), "int -> FP (rtl/fp/conv.py)"),
    "cache_trav": (_cache("trav"), "kd-node cache (rtl/cache.py, trav geometry)"),
    "cache_list": (_cache("list"), "list-entry cache (rtl/cache.py, list geometry)"),
    "cache_int": (_cache("int"), "triangle cache (rtl/cache.py, int geometry)"),
    "bus": (_bus, "round-robin bus, 3 requesters (rtl/bus.py)"),
    "memif": (_memif, "trav+list+int caches on the bus (rtl/bus.py MemoryInterface)"),
    "traversal": (_unit(".traversal", "Traversal"), "traversal unit (rtl/traversal.py)"),
    "list": (_unit(".list", "ListUnit"), "list unit (rtl/list.py)"),
    "intersect_pipe": (_pipe, "intersection datapath (rtl/intersection.py IntersectPipe)"),
    "intersection": (_unit(".intersection", "IntersectionUnit"),
                     "intersection unit (rtl/intersection.py)"),
    "ray_setup": (_unit(".rgs", "RaySetup"), "ray setup, stream in/out (rtl/rgs/eye.py RaySetup)"),
    "rgs_eye": (_unit(".rgs", "EyeRays"),
                "RGS slave eye rays + ray setup, packet requests in (rtl/rgs/eye.py EyeRays)"),
    "rtc_core": (_unit(".rtc", "RTC"), "the RTC, three memory ports (rtl/rtc.py)"),
    "rtc": (lambda cfg, latency: RTCTop(cfg), "one RTC + RTC-MI (3 caches) + bus, one memory port"),
    "chip": (_unit(".chip", "Chip"), "the chip: RGS + cfg.rtcs RTCs with RTC-MIs + bus, one "
             "memory port (rtl/chip.py)"),
    "rtc_nocache": (lambda cfg, latency: RTCTop(cfg, caches=False),
                    "one RTC + bus (no caches), one memory port"),
}


def build_top(top: str, cfg: Config, latency: int | None = None) -> wiring.Component:
    """The component for ``top`` (a key of :data:`TOPS`) built from ``cfg``."""
    if top not in TOPS:
        raise ConfigError(f"unknown top {top!r}; choose one of: {', '.join(TOPS)}")
    if latency is not None and not top.startswith("fp_"):
        raise ConfigError(f"--fp-latency applies to the fp_* tops only, not {top!r}")
    return TOPS[top][0](cfg, latency)


def export(top: str, cfg: Config, out_dir: Path | str = "build/verilog",
           latency: int | None = None, name: str | None = None, ecp5: bool = False) -> Path:
    """Write ``out_dir/<name or top>.v`` (module ``name or top``) and return its path.
    ``ecp5``: elaborate for the ECP5 (:data:`rtl.fp.dsp.ECP5`): the FP multipliers' partial
    products become MULT18X18D blocks with their own registers, as in ``saarcor.flows.fpga``."""
    from rtl.fp.dsp import ECP5
    name = name or top
    text = verilog.convert(build_top(top, cfg, latency), name=name,
                           platform=ECP5 if ecp5 else None)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{name}.v"
    path.write_text(text)
    return path


class RTCSim(wiring.Component):
    """An :class:`~rtl.rtc.RTC` with an :class:`~tb.harness.memory.IdealMemory`
    (``mem_latency`` cycles) holding ``image`` behind each of its three memory ports; image
    constants from the image header.

    Ports: ``rays``, ``results`` as the RTC's; the RTC itself is ``self.rtc`` (its counters
    can be read in simulation).
    """

    def __init__(self, cfg: Config, image, *, mem_latency: int = 20, queue: int | None = None):
        self.cfg, self.image = cfg, image
        self.rtc = RTC(cfg)
        q = queue if queue is not None else mem_latency + 8
        self.tri_reader = tri_reader(cfg, self.rtc)
        self.mems = {
            "node": IdealMemory(image.data, addr_width=cfg.addr_bits, tag_width=cfg.thread_bits,
                                latency=mem_latency, queue=max(q, cfg.threads)),
            "list": IdealMemory(image.data, addr_width=cfg.addr_bits,
                                tag_width=self.rtc.list.tag_width,
                                latency=mem_latency, queue=q),
            "tri": IdealMemory(image.data, addr_width=cfg.addr_bits,
                               tag_width=len(self.tri_reader.mem.req.payload.tag),
                               latency=mem_latency, queue=q),
        }
        super().__init__({
            "rays": In(stream.Signature(RayIn(cfg))),
            "results": Out(stream.Signature(RayResult(cfg))),
        })

    def elaborate(self, platform):
        m = Module()
        m.submodules.rtc = rtc = self.rtc
        attach_memories(m, rtc, self.mems, self.image.tri_base, self.tri_reader)
        drive_header(m, rtc, self.image)
        wiring.connect(m, wiring.flipped(self.rays), rtc.rays)
        wiring.connect(m, rtc.results, wiring.flipped(self.results))
        return m
