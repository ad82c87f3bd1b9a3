"""The ray tracing core (RTC): traversal -> list -> intersection -> traversal.

:class:`RTC` wires the three units with ``lib.stream`` interfaces (``wiring.connect``) and
exposes their three memory read ports (node and list: 64-bit words; triangle: whole
triangles by index) for the RTC-MI's caches (``rtl/rtcmi.py``); where no int-cache serves the triangle port, an
:class:`~rtl.memport.ItemReader` (:func:`tri_reader`) reads triangles as 5 words each.

Packets: ``rays`` takes ``RayIn`` lanes; a free thread of the traversal unit takes the next
packet (``rays.ready`` is low while every thread is busy). Each lane goes, in the same cycle,
to the traversal unit and, with its thread, to the intersection unit (``RayWrite``). When
traversal finishes a packet it sends ``PacketDone`` to the intersection unit, which reads the
packet's best hits out on ``results`` (``RayResult``); after the packet's last result the
thread is released for the next packet.
"""
from __future__ import annotations

from amaranth.hdl import Cat, Module
from amaranth.lib import stream, wiring
from amaranth.lib.wiring import In, Out

from model.config import Config
from model.layout import TRI_WORDS
from .intersection import IntersectionUnit
from .list import ListUnit
from .memport import WORD_BITS, ItemReader, MemReadPort
from .rtc_streams import RayIn, RayResult
from .traversal import NODE_BITS, Traversal
from .common import COUNTER_BITS
from .stalls import REASONS, StallCounters

__all__ = ["RTC", "COUNTERS", "STALLS", "STALL_UNITS", "HEADER", "drive_header", "attach_memories",
           "tri_reader"]

# the memory image's header constants an RTC top takes as inputs
HEADER = ("node_base", "list_base", "tri_base", "root")


def drive_header(m: Module, top, values) -> None:
    """Drive ``top``'s header inputs (those of ``HEADER`` it has) from ``values``: an object
    with those attributes (a memory image) or a dict (e.g. of loaded constant registers)."""
    for k in HEADER:
        if hasattr(top, k):
            m.d.comb += getattr(top, k).eq(values[k] if isinstance(values, dict)
                                           else getattr(values, k))


def tri_reader(cfg: Config, rtc: "RTC") -> ItemReader:
    """The :class:`ItemReader` that serves the RTC's triangle port from 64-bit words (5 a
    triangle, ``cfg.int_tri_slots`` in flight) where no int-cache does."""
    port = rtc.tri_mem
    return ItemReader(item_bits=cfg.int_item_bits, item_words=TRI_WORDS,
                      addr_width=len(port.req.payload.addr), tag_width=len(port.req.payload.tag),
                      slots=cfg.int_tri_slots)


def attach_memories(m: Module, rtc, mems: dict, tri_base, reader: ItemReader) -> None:
    """Add each memory of ``mems`` (``{"node" | "list" | "tri": memory}`` of 64-bit words) as
    a submodule and connect it to the RTC's port of that name (the triangle port through
    ``reader``, a :func:`tri_reader`, whose ``base`` is ``tri_base``)."""
    m.submodules.tri_reader = reader
    m.d.comb += reader.base.eq(tri_base)
    for name, mem in mems.items():
        m.submodules[f"{name}_mem"] = mem
        port = getattr(rtc, f"{name}_mem")
        if name == "tri":
            wiring.connect(m, port, reader.port)
            port = reader.mem
        wiring.connect(m, port, mem.port)

# counter port -> (unit, port of that unit)
COUNTERS = {
    "trav_busy": ("trav", "busy"), "trav_ctl_busy": ("trav", "ctl_busy"),
    "trav_ops": ("trav", "trav_ops"),
    "trav_steps": ("trav", "trav_steps"), "node_reads": ("trav", "node_reads"),
    "leaf_reqs": ("trav", "leaf_reqs"), "passes": ("trav", "passes"),
    "pushes": ("trav", "pushes"), "packets_done": ("trav", "packets_done"),
    "list_busy": ("list", "busy"), "list_ops": ("list", "list_ops"),
    "list_reads": ("list", "words"),
    "int_busy": ("int", "busy"), "int_ops": ("int", "int_ops"), "int_tris": ("int", "tris"),
}


STALL_UNITS = ("trav", "list", "int")
STALLS = tuple(f"{u}_{r}" for u in STALL_UNITS for r in REASONS)
"""Each unit's cycles by what it did (``rtl/stalls.py``): ``trav_work``, ``trav_memory``,
``trav_blocked``, ``trav_starved``, then list's and int's."""


class RTC(wiring.Component):
    """One ray tracing core.

    Ports: ``rays`` (In stream ``RayIn``), ``results`` (Out stream ``RayResult``), memory
    read ports ``node_mem``, ``list_mem`` (64-bit words at word addresses), ``tri_mem``
    (triangle index -> its ``cfg.int_item_bits`` vertex bits; tags: the units'), memory image
    constants ``node_base``, ``list_base``, ``root`` (In, held).
    Counters (Out, 32 bits): see ``COUNTERS``, ``STALLS`` (each unit's cycles working, waiting
    for memory, blocked, starved), ``sub_busy[k]`` (traversal sub-units) and ``cycles``
    (since reset).

    Latency and throughput are the units' (see their docstrings); up to ``cfg.threads``
    packets are in flight.
    """

    def __init__(self, cfg: Config, *, addr_width: int | None = None):
        self.cfg = cfg
        addr_width = cfg.addr_bits if addr_width is None else addr_width
        self.trav = Traversal(cfg, addr_width=addr_width)
        self.list = ListUnit(cfg, addr_width=addr_width)
        self.int = IntersectionUnit(cfg, addr_width=addr_width)
        ports = {
            "rays": In(stream.Signature(RayIn(cfg))),
            "results": Out(stream.Signature(RayResult(cfg))),
            "node_mem": Out(MemReadPort(addr_width=addr_width, data_width=WORD_BITS,
                                        tag_width=cfg.thread_bits)),
            "list_mem": Out(MemReadPort(addr_width=addr_width, data_width=WORD_BITS,
                                        tag_width=self.list.tag_width)),
            "tri_mem": Out(MemReadPort(addr_width=addr_width, data_width=cfg.int_item_bits,
                                       tag_width=self.int.tag_width)),
            "node_base": In(addr_width), "list_base": In(addr_width), "root": In(NODE_BITS),
            "sub_busy": Out(COUNTER_BITS).array(cfg.trav_subunits),
            "cycles": Out(COUNTER_BITS),
        }
        ports.update({name: Out(COUNTER_BITS) for name in COUNTERS})
        ports.update({name: Out(COUNTER_BITS) for name in STALLS})
        super().__init__(ports)

    def elaborate(self, platform):
        m = Module()
        m.submodules.trav = trav = self.trav
        m.submodules.list = lst = self.list
        m.submodules.int = inter = self.int

        wiring.connect(m, trav.leaf, lst.leaf)
        wiring.connect(m, lst.tri, inter.tri_in)
        wiring.connect(m, inter.lane_out, trav.result)
        wiring.connect(m, trav.done, inter.done)
        wiring.connect(m, inter.result, wiring.flipped(self.results))
        wiring.connect(m, trav.node, wiring.flipped(self.node_mem))
        wiring.connect(m, lst.mem, wiring.flipped(self.list_mem))
        wiring.connect(m, inter.mem, wiring.flipped(self.tri_mem))
        m.d.comb += [trav.node_base.eq(self.node_base), trav.root.eq(self.root),
                     lst.list_base.eq(self.list_base)]

        # a ray lane goes to traversal and (with its thread) to intersection in the same cycle
        rays, ri = self.rays, inter.ray_in
        m.d.comb += [trav.rays.payload.eq(rays.payload),
                     ri.payload.ray.eq(rays.payload), ri.payload.thread.eq(trav.load_thread),
                     trav.rays.valid.eq(rays.valid & ri.ready),
                     ri.valid.eq(rays.valid & trav.rays.ready),
                     rays.ready.eq(trav.rays.ready & ri.ready)]

        # the intersection unit releases a packet's thread with the packet's last result
        wiring.connect(m, inter.release, trav.release)

        units = {"trav": trav, "list": lst, "int": inter}
        for name, (unit, port) in COUNTERS.items():
            m.d.comb += getattr(self, name).eq(getattr(units[unit], port))
        # where each unit's cycles go (rtl/stalls.py): its op counter, memory port and output
        outs = {"trav": [trav.leaf], "list": [lst.tri], "int": [inter.result, inter.lane_out]}
        mems = {"trav": trav.node, "list": lst.mem, "int": inter.mem}
        ops = {"trav": trav.trav_ops, "list": lst.list_ops, "int": inter.int_ops}
        for unit in STALL_UNITS:
            m.submodules[f"stalls_{unit}"] = st = StallCounters()
            mem = mems[unit]
            m.d.comb += [st.ops.eq(ops[unit]), st.req_valid[0].eq(mem.req.valid),
                         st.req_ready[0].eq(mem.req.ready),
                         st.resp[0].eq(mem.resp.valid & mem.resp.ready),
                         st.out_valid.eq(Cat(*(o.valid & ~o.ready for o in outs[unit])).any()),
                         st.out_ready.eq(0)]
            for reason in REASONS:
                m.d.comb += getattr(self, f"{unit}_{reason}").eq(getattr(st, reason))
        for j in range(self.cfg.trav_subunits):
            m.d.comb += self.sub_busy[j].eq(trav.sub_busy[j])
        m.d.sync += self.cycles.eq(self.cycles + 1)
        return m
