"""Simulation-only top for whole frames through one RTC: ``RTCFrame`` (exported to Verilog and
clocked by ``tb/harness/verilator_main.cpp``, see ``tb/harness/verilator.py``).

The memory contents are not part of the design: a load port writes the memory image, the
rays and a few constants before ``start``, so one compiled simulation per configuration and
memory size serves every scene, resolution (up to ``ray_slots`` rays), seed and bubble rate.
In Verilator the image memories take the image at time 0 instead (``VerilogMemory(preload=
True)``, ``tb/harness/frame_mem.sv``), so only the rays and constants take load cycles.

Load port (one 64-bit word per cycle while ``ld_valid``; ``ld_sel`` picks the target):

=========  ============================================================================
``ld_sel``  target of word ``ld_addr``
=========  ============================================================================
0 (IMAGE)  the memory image: written into all three ``IdealMemory`` s (node, list, tri)
1 (RAYS)   the ray memory: ray slot ``ld_addr >> 3``, 64-bit chunk ``ld_addr & 7`` of the
           ``RayIn`` bits (low chunk first); slot ``r`` feeds the ``r``-th lane transfer
2 (CONST)  constant ``ld_addr`` of :data:`CONSTS` (node_base, list_base, tri_base, root,
           rays, idle and stall in 1/16, the two LFSR seeds, mem_stall in 1/16 and the
           seeds of the node, list and tri memories' hold LFSRs)
=========  ============================================================================

After ``start`` (one cycle) the RTC and its memories leave reset (they are held in reset until
then, so the run is cycle for cycle :class:`tb.units.rtc.RTCSelfTest`'s from reset): the ray memory
feeds ``rays`` lanes in slot order, an LFSR makes input bubbles (``idle``/16 of the cycles
before a transfer) and another result back-pressure (``stall``/16); one LFSR per memory holds
its responses in ``mem_stall``/16 of the cycles (a random, in-order latency). Every result transfer
shows on ``res_valid`` / ``res_data`` (``RayResult`` bits, zero-padded to a multiple of 32);
``finished`` rises in the cycle after the last of ``rays`` results, ``cycles`` counts the
RTC's cycles since start, ``counters`` is the concatenation of :data:`counter_names` (32 bits
each, first name in the low bits), ``results`` counts results out.
"""
from __future__ import annotations

from types import SimpleNamespace

from amaranth.hdl import Cat, ClockSignal, Elaboratable, Instance, Module, ResetInserter, Signal
from amaranth.lib import wiring
from amaranth.lib.memory import Memory
from amaranth.lib.wiring import In, Out
from amaranth.utils import ceil_log2

from model.config import Config
from rtl.common import COUNTER_BITS
from tb.harness.memory import IdealMemory
from rtl.rtc import COUNTERS, RTC, attach_memories, drive_header, tri_reader
from rtl.rtc_streams import RayIn, RayResult

from tb.harness.lfsr import LFSR, feed_from_memory, lfsr_seeds, passes, sink_to

__all__ = ["RTCFrame", "VerilogMemory", "CONSTS", "SEL_IMAGE", "SEL_RAYS", "SEL_CONST", "counter_names",
           "lfsr_seeds", "ray_chunks", "result_bits"]

SEL_IMAGE, SEL_RAYS, SEL_CONST = 0, 1, 2
CONSTS = ("node_base", "list_base", "tri_base", "root", "rays", "idle_q", "stall_q",
          "seed0", "seed1", "mem_stall_q", "seed2", "seed3", "seed4")
MEMS = ("node", "list", "tri")


def counter_names(cfg: Config) -> list[str]:
    """Order of the 32-bit fields of ``RTCFrame.counters`` (low bits first)."""
    return (list(COUNTERS) + [f"sub_busy{j}" for j in range(cfg.trav_subunits)] +
            [f"{m}_mem_reads" for m in MEMS])


def ray_chunks(cfg: Config) -> int:
    """64-bit chunks per ray slot (``RayIn`` bits rounded up)."""
    return -(-RayIn(cfg).size // 64)


def result_bits(cfg: Config, layout=None) -> int:
    """Width of ``res_data``: the result ``layout`` (default ``RayResult``) rounded up to 32
    bits, at least 96 (so that a C++ main reads it as a ``VlWide`` whatever the format)."""
    size = (RayResult(cfg) if layout is None else layout).size
    return max(96, -(-size // 32) * 32)


def frame_signature(cfg: Config, counters: int, result_layout=None, ports: int = 1) -> dict:
    """The ports of a Verilator frame top (:class:`RTCFrame`, ``tb.harness.chip_frame.ChipFrame``):
    what ``tb/harness/verilator_main.cpp`` drives and reads; ``counters`` 32-bit counter fields;
    ``res_data`` holds ``ports`` results side by side (port i's at bit ``i * result_bits``,
    a ``result_layout`` each, default ``RayResult``), ``res_valid`` bit i says port i's is one."""
    return {
        "ld_valid": In(1), "ld_sel": In(2), "ld_addr": In(32), "ld_data": In(64),
        "start": In(1),
        "res_valid": Out(ports), "res_data": Out(ports * result_bits(cfg, result_layout)),
        "finished": Out(1), "running": Out(1),
        "cycles": Out(COUNTER_BITS), "results": Out(COUNTER_BITS),
        "counters": Out(COUNTER_BITS * counters),
        "cap_mem_words": Out(32), "cap_ray_slots": Out(32),
    }


def load_consts_and_start(m: Module, top, consts) -> Signal:
    """In a frame top: constant ``k`` of ``consts`` into ``top.const[name]`` when the load port
    writes address ``k`` with ``ld_sel`` = CONST; returns ``run``, set by ``start``."""
    for k, name in enumerate(consts):
        with m.If(top.ld_valid & (top.ld_sel == SEL_CONST) & (top.ld_addr == k)):
            m.d.sync += top.const[name].eq(top.ld_data)
    run = Signal()
    with m.If(top.start):
        m.d.sync += run.eq(1)
    return run


class VerilogMemory(Elaboratable):
    """A memory of ``depth`` (a power of two) x ``width`` bits held by ``tb/harness/frame_mem.sv``
    (an ``Instance``; Verilator builds only), with ``lib.memory.Memory``'s port methods: one
    ``read_port(domain="sync" | "comb")`` (sync: registered, enable, not transparent) and one
    ``write_port(granularity=None)``. Starts at zero; with ``preload`` it holds the memory
    image (the load file's target-0 blocks) from time 0, before reset (see the .sv file)."""

    def __init__(self, *, width: int, depth: int, preload: bool = False):
        if depth < 2 or depth & (depth - 1):
            raise ValueError(f"VerilogMemory depth={depth} must be a power of two >= 2")
        if preload and width != 64:
            raise ValueError("VerilogMemory preload takes 64-bit words only")
        self.width, self.depth, self.preload = width, depth, preload
        self.abits = ceil_log2(depth)
        self._rd = self._wr = None

    def read_port(self, *, domain: str = "sync"):
        if self._rd is not None:
            raise ValueError("VerilogMemory has one read port")
        self._rd = SimpleNamespace(addr=Signal(self.abits, name="r_addr"),
                                   data=Signal(self.width, name="r_data"),
                                   en=Signal(init=1, name="r_en"), sync=domain != "comb")
        return self._rd

    def write_port(self, *, granularity: int | None = None):
        g = granularity or self.width
        if self._wr is not None or self.width % g:
            raise ValueError("VerilogMemory has one write port; granularity must divide width")
        self._wr = SimpleNamespace(addr=Signal(self.abits, name="w_addr"),
                                   data=Signal(self.width, name="w_data"),
                                   en=Signal(self.width // g, name="w_en"), granularity=g)
        return self._wr

    def elaborate(self, platform):
        m = Module()
        rd, wr = self._rd, self._wr
        if rd is None or wr is None:
            raise ValueError("VerilogMemory needs its read and its write port")
        m.submodules.store = Instance(
            "frame_mem", p_ABITS=self.abits, p_WIDTH=self.width, p_GRAN=wr.granularity,
            p_SYNC_READ=int(rd.sync), p_PRELOAD=int(self.preload), i_clk=ClockSignal(),
            i_r_addr=rd.addr, i_r_en=rd.en, o_r_data=rd.data,
            i_w_addr=wr.addr, i_w_en=wr.en, i_w_data=wr.data)
        return m


class _Run(Elaboratable):
    """The part held in reset until ``start``: RTC, memories' control, feeder, sink."""

    def __init__(self, top: "RTCFrame"):
        self.top = top

    def elaborate(self, platform):
        t = self.top
        m = Module()
        m.submodules.rtc = rtc = t.rtc
        c = t.const
        attach_memories(m, rtc, t.mems, c["tri_base"], t.tri_reader)
        drive_header(m, rtc, c)

        # feeder: ray slot i -> rays, LFSR bubbles (as RTCSelfTest)
        bubbles, backpressure, *holds = (lfsr.value for lfsr in t.lfsr)
        for mem, hold in zip(t.mems.values(), holds):
            m.d.comb += mem.hold.eq(~passes(hold, c["mem_stall_q"]))
        feed_from_memory(m, rtc.rays, t.ray_rd, c["rays"], passes(bubbles, c["idle_q"]))

        # sink: LFSR back-pressure, every transfer on res_valid / res_data
        res = rtc.results
        take = sink_to(m, res, passes(backpressure, c["stall_q"]))
        m.d.comb += [t.res_valid.eq(take), t.res_data.eq(res.payload)]
        with m.If(take):
            m.d.sync += t.results.eq(t.results + 1)
        return m


class RTCFrame(wiring.Component):
    """An RTC on three loadable :class:`~tb.harness.memory.IdealMemory` s with a loadable ray memory
    (simulation only; see the module docstring for the ports).

    The memories are :class:`VerilogMemory` s (the Verilog needs ``tb/harness/frame_mem.sv``), or with
    ``verilog_memories=False`` Amaranth ``Memory`` s (for pysim; small sizes only).

    Parameters: ``cfg``; ``mem_words`` (memory image capacity, rounded up to a power of two);
    ``ray_slots`` (rays per run, rounded up to a power of two); ``mem_latency`` (cycles, >= 2)
    and ``queue`` (requests in flight per memory, default ``mem_latency + 8`` and at least
    ``cfg.threads`` for the node memory, as ``tb.harness.tops.RTCSim``).

    Load: one word per cycle (the image preloaded in Verilator). Run: the RTC's latency and
    throughput, one result per cycle out.
    """

    def __init__(self, cfg: Config, *, mem_words: int, ray_slots: int, mem_latency: int = 20,
                 queue: int | None = None, verilog_memories: bool = True):
        self.cfg = cfg
        self.rtc = rtc = RTC(cfg)
        q = queue if queue is not None else mem_latency + 8
        self.tri_reader = tri_reader(cfg, rtc)
        tags = {"node": cfg.thread_bits, "list": rtc.list.tag_width,
                "tri": len(self.tri_reader.mem.req.payload.tag)}
        # no more words than the chip's addresses reach (cfg.addr_bits)
        self.mem_words = 1 << min(cfg.addr_bits, max(1, ceil_log2(max(1, mem_words))))
        # pysim cannot run the Verilog memories: Amaranth Memory for small runs there
        def store(width, depth, image=False):      # image: preloaded with the memory image
            if verilog_memories:
                return VerilogMemory(width=width, depth=depth, preload=image)
            return Memory(shape=width, depth=depth, init=[])
        self.mems = {name: IdealMemory(None, addr_width=cfg.addr_bits, tag_width=tags[name],
                                       latency=mem_latency, load=True,
                                       store=store(64, self.mem_words, image=True),
                                       queue=max(q, cfg.threads) if name == "node" else q)
                     for name in MEMS}
        self.ray_slots = 1 << max(1, ceil_log2(max(1, ray_slots)))
        self.chunks = ray_chunks(cfg)
        if self.chunks > 8:
            raise ValueError(f"RayIn of {RayIn(cfg).size} bits needs {self.chunks} 64-bit load "
                             "chunks; the ray load address has room for 8")
        self.ray_mem = store(64 * self.chunks, self.ray_slots)
        self.names = counter_names(cfg)
        super().__init__(frame_signature(cfg, len(self.names)))
        # loaded constants: registers that reset does not touch
        self.const = {name: Signal(32, name=f"c_{name}", reset_less=True) for name in CONSTS}
        # bubbles, back-pressure, then the holds of the node, list and tri memories
        self.lfsr = [LFSR(loadable=True) for _ in range(2 + len(MEMS))]

    def elaborate(self, platform):
        m = Module()
        m.submodules.ray_mem = self.ray_mem
        sel, addr, data = self.ld_sel, self.ld_addr, self.ld_data

        for mem in self.mems.values():
            m.d.comb += [mem.ld_en.eq(self.ld_valid & (sel == SEL_IMAGE)),
                         mem.ld_addr.eq(addr), mem.ld_data.eq(data)]
        wr = self.ray_mem.write_port(granularity=64)
        self.ray_rd = self.ray_mem.read_port(domain="comb")    # used by _Run
        m.d.comb += [wr.addr.eq(addr[3:]), wr.data.eq(data.replicate(self.chunks)),
                     wr.en.eq(_chunk_enable(self.ld_valid & (sel == SEL_RAYS), addr[:3],
                                            self.chunks))]
        # start: leave reset; the LFSRs hold their seeds until then
        run = load_consts_and_start(m, self, CONSTS)
        for j, lfsr in enumerate(self.lfsr):
            m.submodules[f"lfsr{j}"] = lfsr
            m.d.comb += [lfsr.en.eq(run), lfsr.seed.eq(self.const[f"seed{j}"])]
        m.submodules.run = ResetInserter({"sync": ~run})(_Run(self))

        rtc = self.rtc
        ctrs = [getattr(rtc, name) for name in COUNTERS] + list(rtc.sub_busy) + \
               [mem.reads for mem in self.mems.values()]
        m.d.comb += [self.counters.eq(Cat(*ctrs)), self.cycles.eq(rtc.cycles),
                     self.running.eq(run),
                     self.finished.eq(run & (self.results == self.const["rays"])),
                     self.cap_mem_words.eq(self.mem_words),
                     self.cap_ray_slots.eq(self.ray_slots)]
        return m


def _chunk_enable(valid, chunk, chunks: int):
    """Write enable of a ``granularity=64`` port: bit ``chunk`` of ``chunks`` when ``valid``."""
    return Cat(*[valid & (chunk == k) for k in range(chunks)])
