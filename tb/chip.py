"""The whole chip (``rtl/chip.py``) on a frame, against the golden model.

* :func:`frame_registers`: what the host writes into the chip's registers for a frame: image
  constants, scene box, the camera as ``model.raygen.eye_rays`` quantizes it, image and tile
  counts, the number of rays.
* :class:`ChipFrame`: the chip with :class:`~rtl.memory.SDRAMMemory` (``cfg.mem_chips`` chips,
  the configuration's clock ratio and latency) behind its port, loadable (Verilator: one
  binary per configuration serves every scene and camera) or preloaded (Amaranth simulation);
  LFSR back-pressure on the results.
* :func:`run_chip` (Amaranth's simulator) and :func:`run_chip_frame` (Verilator): one frame;
  every ray's result against ``model.rtc.trace`` of the model's eye rays (``tb/compare.py``),
  and the chip's counters; the two give the same cycle count.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from amaranth.hdl import Module
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from model.config import Config
from model.raygen import camera_registers, eye_rays
from model.rtc import counter_totals, trace
from rtl.chip import Chip, counter_names
from rtl.memory import SDRAMMemory
from rtl.rtcmi import CACHES

from . import compare

__all__ = ["frame_registers", "ChipFrame", "ChipRun", "run_chip", "run_chip_frame",
           "chip_consts", "chip_counter_names", "const_values", "chip_blocks"]


def frame_registers(cfg: Config, image, camera, width: int, height: int) -> dict:
    """The chip's host registers for a ``width x height`` frame of ``camera`` (values as the
    chip's ports take them: format words as their bit patterns)."""
    fmt, n = cfg.fmt, cfg.oversampling
    sw, sh = width * n, height * n
    pos, corner, dx, dy = camera_registers(camera, width, height, cfg)
    bits = lambda v: [int(b) for b in fmt.to_bits(np.asarray(v, np.float32))]  # noqa: E731
    return {
        "node_base": image.node_base, "list_base": image.list_base,
        "tri_base": image.tri_base, "root": image.root,
        "box_lo": bits(image.bounds[0]), "box_hi": bits(image.bounds[1]),
        "pos": bits(pos), "corner": bits(corner), "dx": bits(dx), "dy": bits(dy),
        "width": width, "height": height,
        "tiles_x": -(-sw // cfg.tile_w), "tiles_y": -(-sh // cfg.tile_h), "n_rays": sw * sh,
    }


@dataclass
class ChipRun:
    cycles: int
    seconds: float
    rays: int
    counters: dict                 # the chip's counters (per RTC, caches, memory)
    model: dict                    # the model's counter totals
    mismatches: list = field(default_factory=list)


# --- the chip frame for Verilator ---------------------------------------------------------------

def chip_consts(cfg: Config) -> list[str]:
    """The constants :class:`ChipFrame` loads (``ld_sel`` = CONST, address = position): the
    chip's registers (three words for a vector: ``pos_0``, ``pos_1``, ``pos_2``), then the
    result back-pressure (``stall_q``, sixteenths) and its LFSR seed."""
    names = []
    for k, v in _REGISTERS.items():
        names += [f"{k}_{i}" for i in range(3)] if v else [k]
    return names + ["stall_q", "seed"]


_REGISTERS = {"node_base": 0, "list_base": 0, "tri_base": 0, "root": 0, "box_lo": 1, "box_hi": 1,
              "pos": 1, "corner": 1, "dx": 1, "dy": 1, "width": 0, "height": 0, "tiles_x": 0,
              "tiles_y": 0, "n_rays": 0}                     # 1: a vector of 3 format words


def chip_counter_names(cfg: Config) -> list[str]:
    """Order of the 32-bit fields of ``ChipFrame.counters`` (low bits first)."""
    names = ["rays_in", "results_out", "mem_reads"]
    names += [f"packets{s}" for s in range(cfg.rtcs)]
    for r in range(cfg.rtcs):
        names += [f"rtc{r}_{k}" for k in counter_names(cfg)]
        names += [f"rtc{r}_{c}_{k}" for c in CACHES for k in ("hits", "misses", "grants")]
    names += [f"chip{c}_{k}" for k in ("words", "busy") for c in range(cfg.mem_chips)]
    return names


class _ChipRun(wiring.Component):
    """The part of :class:`ChipFrame` held in reset until ``start``: the chip, the SDRAM
    model's control, the result sink. The chip's ``start`` is its first cycle out of reset."""

    def __init__(self, top: "ChipFrame"):
        self.top = top
        super().__init__({})

    def elaborate(self, platform):
        from amaranth.hdl import Signal
        from .lfsr import passes, sink_to
        t, m = self.top, Module()
        m.submodules.chip = chip = t.chip
        m.submodules.memory = mem = t.memory
        wiring.connect(m, chip.mem, mem.port)
        c = t.const
        for k, vec in _REGISTERS.items():
            port = getattr(chip, k)
            if vec:
                for i in range(3):
                    m.d.comb += port[i].eq(c[f"{k}_{i}"])
            else:
                m.d.comb += port.eq(c[k])
        going = Signal()
        m.d.sync += going.eq(1)
        m.d.comb += [chip.start.eq(~going), t.finished_run.eq(going & chip.done)]
        take = sink_to(m, chip.results, passes(t.lfsr.value, c["stall_q"]))
        m.d.comb += [t.res_valid.eq(take), t.res_data.eq(chip.results.payload)]
        return m


class ChipFrame(wiring.Component):
    """The chip on a loadable SDRAM model, for whole frames in Verilator (simulation only):
    the same outside as :class:`tb.frame.RTCFrame` (``tb/verilator_main.cpp`` drives both).

    Load (``ld_sel``): 0 the memory image into the SDRAM model's words; 2 constant ``ld_addr``
    of :func:`chip_consts` (the chip's registers, result back-pressure and its LFSR seed). No
    ray memory: the chip makes its rays (``cap_ray_slots`` = 0). After ``start`` the chip and
    the memory model leave reset and the chip renders the frame; every result transfer shows on
    ``res_valid`` / ``res_data``; ``finished`` once the chip is done; ``cycles`` = the chip's
    busy cycles; ``counters`` = :func:`chip_counter_names` (32 bits each, first in the low bits).

    ``preload`` (Amaranth simulation, ``verilog_memories=False``): ``{"image": words,
    "consts": {name: value}}`` as initial contents, so no load cycles are needed; the run is
    cycle for cycle the loaded one's.
    """

    def __init__(self, cfg: Config, *, mem_words: int, verilog_memories: bool = True,
                 preload: dict | None = None):
        from amaranth.hdl import Signal
        from amaranth.lib.memory import Memory
        from amaranth.utils import ceil_log2

        from .frame import VerilogMemory, result_bits
        from .lfsr import LFSR
        self.cfg = cfg
        self.chip = Chip(cfg)
        self.mem_words = 1 << max(1, ceil_log2(max(1, mem_words)))
        init = [] if preload is None else [int(w) for w in preload["image"]]
        if len(init) > self.mem_words:
            raise ValueError(f"memory image of {len(init)} words > mem_words={mem_words}")
        store = (VerilogMemory(width=64, depth=self.mem_words) if verilog_memories else
                 Memory(shape=64, depth=self.mem_words, init=init))
        self.memory = SDRAMMemory(None, addr_width=32,
                                  tag_width=len(self.chip.mem.req.payload.tag),
                                  chips=cfg.mem_chips, chip_bits=cfg.mem_chip_bits,
                                  clock_ratio=cfg.mem_clock_ratio, latency=cfg.mem_latency,
                                  chip_queue=cfg.mem_chip_queue, load=True, store=store)
        self.consts = chip_consts(cfg)
        self.names = chip_counter_names(cfg)
        super().__init__({
            "ld_valid": In(1), "ld_sel": In(2), "ld_addr": In(32), "ld_data": In(64),
            "start": In(1),
            "res_valid": Out(1), "res_data": Out(result_bits(cfg)),
            "finished": Out(1), "running": Out(1),
            "cycles": Out(32), "results": Out(32),
            "counters": Out(32 * len(self.names)),
            "cap_mem_words": Out(32), "cap_ray_slots": Out(32),
        })
        values = {} if preload is None else preload["consts"]
        self.const = {name: Signal(32, name=f"c_{name}", reset_less=True,
                                   init=int(values.get(name, 0))) for name in self.consts}
        self.lfsr = LFSR(loadable=True)
        self.finished_run = Signal()

    def elaborate(self, platform):
        from amaranth.hdl import ResetInserter, Signal
        from .frame import SEL_CONST, SEL_IMAGE
        m = Module()
        sel, addr, data = self.ld_sel, self.ld_addr, self.ld_data
        mem = self.memory
        m.d.comb += [mem.ld_en.eq(self.ld_valid & (sel == SEL_IMAGE)), mem.ld_addr.eq(addr),
                     mem.ld_data.eq(data)]
        for k, name in enumerate(self.consts):
            with m.If(self.ld_valid & (sel == SEL_CONST) & (addr == k)):
                m.d.sync += self.const[name].eq(data)
        run = Signal()
        with m.If(self.start):
            m.d.sync += run.eq(1)
        m.submodules.lfsr = self.lfsr
        m.d.comb += [self.lfsr.en.eq(run), self.lfsr.seed.eq(self.const["seed"])]
        m.submodules.run = ResetInserter({"sync": ~run})(_ChipRun(self))
        with m.If(self.res_valid):
            m.d.sync += self.results.eq(self.results + 1)
        chip = self.chip
        values = [chip.rays_in, chip.results_out, chip.mem_reads, *chip.packets]
        names = counter_names(self.cfg)
        for r in range(self.cfg.rtcs):
            word = chip.rtc_counters[r]
            values += [word[32 * i:32 * i + 32] for i in range(len(names))]
            for c in range(3):
                values += [chip.hits[3 * r + c], chip.misses[3 * r + c], chip.grants[3 * r + c]]
        values += list(mem.words) + list(mem.busy)
        from amaranth.hdl import Cat
        m.d.comb += [self.counters.eq(Cat(*values)), self.cycles.eq(chip.cycles),
                     self.running.eq(run), self.finished.eq(run & self.finished_run),
                     self.cap_mem_words.eq(self.mem_words), self.cap_ray_slots.eq(0)]
        return m


def const_values(cfg: Config, regs: dict, *, stall: float = 0.0, seed: int = 1) -> dict:
    """``{name: value}`` of :func:`chip_consts` for a frame's registers ``regs``."""
    from .lfsr import lfsr_seeds, sixteenths
    vals = {"stall_q": sixteenths(stall, "stall"), "seed": lfsr_seeds(seed)[1]}
    for k, vec in _REGISTERS.items():
        if vec:
            vals.update({f"{k}_{i}": regs[k][i] for i in range(3)})
        else:
            vals[k] = regs[k]
    return vals


def chip_blocks(cfg: Config, image, regs: dict, *, stall: float = 0.0, seed: int = 1) -> list:
    """The load blocks of a frame for :class:`ChipFrame`: the memory image and the
    constants (:func:`chip_consts` order)."""
    from .frame import SEL_CONST, SEL_IMAGE
    vals = const_values(cfg, regs, stall=stall, seed=seed)
    consts = np.array([vals[n] for n in chip_consts(cfg)], np.uint64)
    return [(SEL_IMAGE, 0, np.asarray(image.data, np.uint64)), (SEL_CONST, 0, consts)]


def run_chip_frame(cfg: Config, image, camera, width: int, height: int, *, stall: float = 0.0,
                   seed: int = 1, max_cycles: int = 100_000_000, trace_file=None,
                   progress: bool = True, mem_words: int | None = None, build_root=None,
                   log=None) -> ChipRun:
    """One frame through :class:`ChipFrame` in Verilator (built once per configuration),
    every ray compared with the golden model as :func:`run_chip` does in pysim."""
    import sys

    from rtl.rtc_streams import RayResult

    from .verilator import (BUILD_ROOT, MIN_MEM_WORDS, _field, _pow2, _trace_kind, build,
                            run_binary, write_blocks)
    log = sys.stderr if log is None else log
    regs = frame_registers(cfg, image, camera, width, height)
    rays = eye_rays(camera, width, height, cfg)
    words = len(image.data)
    mw = _pow2(words if mem_words is None else mem_words, MIN_MEM_WORDS)
    if words > mw:
        raise ValueError(f"the memory image has {words} words, the simulation holds {mw}")
    b = build(cfg, mem_words=mw, ray_slots=0, mem_latency=cfg.mem_latency,
              trace=_trace_kind(trace_file), root=build_root or BUILD_ROOT, log=log, top="chip")
    names = chip_counter_names(cfg)
    out = run_binary(b, lambda f: write_blocks(f, chip_blocks(cfg, image, regs, stall=stall,
                                                              seed=seed)),
                     cfg, len(rays), max_cycles=max_cycles, trace_file=trace_file,
                     progress=progress, log=log, desc="chip (Verilator)", names=names)
    lay = RayResult(cfg)
    records = {name: _field(out.results, fld.offset, fld.width) for name, fld in lay}
    run = _finish(cfg, image, rays, records, out.cycles, out.seconds, out.counters)
    run.build = b
    return run


def _finish(cfg: Config, image, rays, records: dict, cycles: int, seconds: float,
            c: dict) -> ChipRun:
    """Compare result ``records`` with the model; counters ``c`` by :func:`chip_counter_names`."""
    hits, ctrs = trace(image, rays, cfg)
    by_ray = compare.results_by_ray(records, rays)
    counters = {"cycles": cycles, "rays_in": c["rays_in"], "results_out": c["results_out"],
                "mem_reads": c["mem_reads"],
                "packets": [c[f"packets{s}"] for s in range(cfg.rtcs)],
                "mem_words": [c[f"chip{k}_words"] for k in range(cfg.mem_chips)],
                "mem_busy": [c[f"chip{k}_busy"] for k in range(cfg.mem_chips)],
                "rtc": [{k: c[f"rtc{r}_{k}"] for k in counter_names(cfg)}
                        for r in range(cfg.rtcs)]}
    for k in ("hits", "misses", "grants"):
        counters[k] = [{cc: c[f"rtc{r}_{cc}_{k}"] for cc in CACHES} for r in range(cfg.rtcs)]
    return ChipRun(cycles, seconds, len(rays), counters, counter_totals(ctrs),
                   compare.result_mismatches(by_ray, compare.expected(hits, cfg, image)))


def run_chip(cfg: Config, image, camera, width: int, height: int, *, stall: float = 0.0,
             seed: int = 1, max_cycles: int = 1_000_000) -> ChipRun:
    """One frame through :class:`ChipFrame` in Amaranth's simulator (memory image and
    registers preloaded), every ray compared with the golden model; the same cycles as
    :func:`run_chip_frame` in Verilator for the same ``stall`` and ``seed``."""
    from amaranth.sim import Simulator

    from rtl.rtc_streams import RayResult
    regs = frame_registers(cfg, image, camera, width, height)
    rays = eye_rays(camera, width, height, cfg)
    top = ChipFrame(cfg, mem_words=len(image.data), verilog_memories=False,
                    preload={"image": image.data,
                             "consts": const_values(cfg, regs, stall=stall, seed=seed)})
    sim = Simulator(top)
    sim.add_clock(1e-8)
    got, info = [], {}

    async def bench(ctx):
        ctx.set(top.start, 1)
        await ctx.tick()
        ctx.set(top.start, 0)
        t0 = time.process_time()
        cycles = 0
        while cycles < max_cycles:
            _, _, fin, valid, data, ctrs, cyc = await ctx.tick().sample(
                top.finished, top.res_valid, top.res_data, top.counters, top.cycles)
            if valid:
                got.append(int(data))
            if fin:
                break
            cycles += 1
        info.update(seconds=time.process_time() - t0, finished=bool(fin), cycles=int(cyc),
                    counters=int(ctrs))

    sim.add_testbench(bench)
    sim.run()
    if not info["finished"]:
        raise AssertionError(f"chip frame: {len(got)} of {len(rays)} results after "
                             f"{max_cycles} cycles (deadlock?)")
    lay = RayResult(cfg)
    records = {name: np.array([(v >> fld.offset) & ((1 << fld.width) - 1) for v in got],
                              np.int64) for name, fld in lay}
    names = chip_counter_names(cfg)
    c = {k: (info["counters"] >> (32 * i)) & 0xFFFFFFFF for i, k in enumerate(names)}
    return _finish(cfg, image, rays, records, info["cycles"], info["seconds"], c)
