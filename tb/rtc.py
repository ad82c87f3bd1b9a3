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
    seconds: float               # wall time of the simulation (after compiling the design)
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
    tri = np.where(hits.tri < 0, MISS, hits.tri).astype(np.int64)
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
        info["t0"] = time.perf_counter()
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
        info["seconds"] = time.perf_counter() - info["t0"]
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
