"""Verilog export of the chip's units and of the one-RTC top (``make verilog``).

Run: ``.venv/bin/python -m rtl.export --top <top> [configuration options] [--out DIR]``; writes
``DIR/<top>.v`` (default ``build/verilog``). ``--list`` names the tops. Every field of
:class:`model.config.Config` is an option (``--threads 2 --trav-subunits 1 --trav-cache-kb 4``),
``--fmt E8M16`` sets the FP format, ``--latency N`` the pipeline latency of an ``fp_*`` top.

The ``rtc`` top (:class:`RTCTop`) is the synthesizable one-RTC chip: the RTC's three read
ports (node, list, triangle) through its RTC-MI's caches share one :class:`RoundRobinBus` to a
single memory read port ``mem`` (``docs/memory-interface.md``, ``docs/fpga.md``) that an FPGA
memory controller serves. ``rtc_core`` is the bare RTC (three memory ports).
``rtl/memory.py``'s memories are simulation models and are not exported.
"""
from __future__ import annotations

import argparse
import dataclasses
import re
from pathlib import Path
from typing import Callable

from amaranth.back import verilog
from amaranth.hdl import Module
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from model.cache import cache_geometry
from model.config import Config, ConfigError, field_help
from model.fp import FPFormat
from .common import COUNTER_BITS
from .memport import connect_tags

__all__ = ["RTCTop", "TOPS", "build_top", "export", "main"]


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
        from .bus import RoundRobinBus
        from .rtc import COUNTERS, RTC, tri_reader
        from .rtcmi import CACHES, RTCMI

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
        from .rtcmi import CACHES
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
        from . import fp
        cls = {"add": fp.FPAdd, "mul": fp.FPMul, "div": fp.FPDiv, "sqrt": fp.FPSqrt,
               "cmp": fp.FPCompare,
               "minmax": fp.FPMinMax, "conv": fp.FPFromInt}[kind]
        kw = {} if latency is None else {"latency": latency}
        return cls(cfg.fmt, **kw)
    return make


def _cache(unit: str) -> Callable:
    def make(cfg: Config, latency):
        from .cache import Cache
        return Cache(cache_geometry(cfg, unit), fast=cfg.fast_clock)
    return make


def _memif(cfg: Config, latency):
    from .bus import MemoryInterface
    return MemoryInterface([cache_geometry(cfg, u) for u in ("trav", "list", "int")],
                           fast=cfg.fast_clock)


def _bus(cfg: Config, latency):
    from .bus import RoundRobinBus
    return RoundRobinBus(3, addr_width=32, tag_width=4)


def _unit(path: str, cls: str) -> Callable:
    def make(cfg: Config, latency):
        import importlib
        return getattr(importlib.import_module(path, __package__), cls)(cfg)
    return make


def _pipe(cfg: Config, latency):
    from .intersection import IntersectPipe
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


def parse_fmt(text: str) -> FPFormat:
    m = re.fullmatch(r"E(\d+)M(\d+)", text)
    if not m:
        raise ConfigError(f"--fmt {text!r}: write the format as E<exp>M<frac>, e.g. E8M23")
    return FPFormat(int(m[1]), int(m[2]))


def build_top(top: str, cfg: Config, latency: int | None = None) -> wiring.Component:
    """The component for ``top`` (a key of :data:`TOPS`) built from ``cfg``."""
    if top not in TOPS:
        raise ConfigError(f"unknown top {top!r}; choose one of: {', '.join(TOPS)}")
    if latency is not None and not top.startswith("fp_"):
        raise ConfigError(f"--latency applies to the fp_* tops only, not {top!r}")
    return TOPS[top][0](cfg, latency)


def export(top: str, cfg: Config, out_dir: Path | str = "build/verilog",
           latency: int | None = None, name: str | None = None, ecp5: bool = False) -> Path:
    """Write ``out_dir/<name or top>.v`` (module ``name or top``) and return its path.
    ``ecp5``: elaborate for the ECP5 (:data:`rtl.fp.dsp.ECP5`): the FP multipliers' partial
    products become MULT18X18D blocks with their own registers, as in ``rtl.fpga``."""
    from rtl.fp.dsp import ECP5
    name = name or top
    text = verilog.convert(build_top(top, cfg, latency), name=name,
                           platform=ECP5 if ecp5 else None)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{name}.v"
    path.write_text(text)
    return path


def add_config_args(ap: argparse.ArgumentParser) -> None:
    """One option per :class:`Config` field (``--trav-cache-kb``), plus ``--fmt``."""
    g = ap.add_argument_group("configuration (model/config.py Config; defaults are Config's)")
    g.add_argument("--fmt", help="FP format E<exp>M<frac> (default E8M23, binary32)")
    text = field_help()
    for f in dataclasses.fields(Config):
        if f.name == "fmt":
            continue
        default = getattr(Config(), f.name)
        typ = {bool: lambda s: s.lower() in ("1", "true", "yes", "on")}.get(type(default),
                                                                            type(default))
        g.add_argument("--" + f.name.replace("_", "-"), dest=f.name, type=typ, default=None,
                       metavar=type(default).__name__.upper(),
                       help=(text[f.name] + f" (default {default})" if f.name in text
                             else f"default {default}").replace("%", "%%"))


def config_from_args(args: argparse.Namespace) -> Config:
    changes = {f.name: getattr(args, f.name) for f in dataclasses.fields(Config)
               if f.name != "fmt" and getattr(args, f.name, None) is not None}
    if args.fmt:
        changes["fmt"] = parse_fmt(args.fmt)
    return Config(**changes)


def config_and_res(args: argparse.Namespace, prog: str) -> tuple[Config, int, int]:
    """The :class:`Config` (:func:`config_from_args`) and the ``--res`` width and height of a
    command line; a bad value exits naming it (``prog: ...``)."""
    from model.cli import parse_res
    try:
        return (config_from_args(args), *parse_res(args.res))
    except (ConfigError, argparse.ArgumentTypeError) as e:
        raise SystemExit(f"{prog}: {e}")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(prog="saarcor verilog",
                                 description="Write the Verilog of a unit or of the one-RTC top.")
    ap.add_argument("--top", default="rtc", help="what to export (default rtc; --list names all)")
    ap.add_argument("--list", action="store_true", help="list the tops and exit")
    ap.add_argument("--out", default="build/verilog", help="output directory (build/verilog)")
    ap.add_argument("--name", help="Verilog module and file name (default: the top's name)")
    ap.add_argument("--latency", type=int, help="pipeline latency of an fp_* top")
    ap.add_argument("--ecp5", action="store_true",
                    help="for a Lattice ECP5 flow: the FP multipliers' partial products as "
                         "MULT18X18D instances using their own input and output registers "
                         "(at FP multiply latencies with those registers, e.g. 5); the "
                         "default is portable Verilog with the registers in logic")
    add_config_args(ap)
    args = ap.parse_args(argv)
    if args.list:
        for k, (_, desc) in TOPS.items():
            print(f"{k:15s} {desc}")
        return
    try:
        path = export(args.top, config_from_args(args), args.out, args.latency, args.name,
                      ecp5=args.ecp5)
    except (ConfigError, ValueError) as e:
        raise SystemExit(f"rtl.export: {e}")
    print(f"rtl.export: wrote {path} ({path.stat().st_size // 1024} KB)")


if __name__ == "__main__":
    main()
