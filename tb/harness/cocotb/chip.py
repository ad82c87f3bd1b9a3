"""cocotb bench of the whole chip's exported Verilog: ``chip`` (``rtl/chip.py``, what ``make
verilog TOP=chip`` writes: one memory port for the board's memory controller) or
``chip_sdram`` (the chip on the SDRAM model, ``tb/harness/chip_sdram.py``: the memory side of
``tb/harness/chip_frame.py``'s ``ChipFrame``, the image read from a file at time 0).

Pytest side, :func:`run_chip`: the host registers of a frame (``tb.harness.chip.frame_registers``:
scene, camera, image size, lights, reflection depth) as port values; the scene's memory image
(``chip``: served by the bench; ``chip_sdram``: the SDRAM model's, ``+image=image.hex``).
Every result is compared by its ray id with the golden model and the counters are collected by
``tb.harness.chip``'s own code (``golden_frame``, ``tb.harness.compare.results_by_id``): a ``tb.harness.chip.ChipRun``
as the Amaranth and Verilator frames return it.

Simulator side, :func:`chip`: the registers set, ``start`` in the first cycle after reset, the
results taken under the back-pressure of ``ChipFrame``'s LFSR (:class:`LFSRPattern`: the same
cycles as ``tb.harness.chip.run_chip`` for the same seed), until ``done``. ``chip``'s memory port is
answered from the image after random delays, in random order, with request back-pressure;
``chip_sdram``'s SDRAM model holds its responses in the cycles of ``ChipFrame``'s memory LFSR.
"""
from __future__ import annotations

import re
import time
from pathlib import Path

import numpy as np

import cocotb

from tb.harness.cocotb.streams import (LFSRPattern, Memory, Pattern, Sink, _Port, from_ints, load, read,
                      read_ports, run, save, start)

TOPS = ("chip", "chip_sdram")


def run_chip(cfg, image, camera, width: int, height: int, sim: str, run_dir, *,
             top: str = "chip", scene=None, stall: float = 0.0, mem_stall: float = 0.0,
             seed: int = 1, max_delay: int = 20, max_cycles: int = 1_000_000, **build_kw):
    """A ``width x height`` frame of ``camera`` (with ``scene``: its shadow and reflection
    rays) through the exported ``top`` of ``cfg``; returns ``(tb.harness.chip.ChipRun, runner
    Result)``. ``stall``: result back-pressure (a fraction of cycles, from the LFSR seeded by
    ``seed`` as in ``tb.harness.chip.run_chip``); ``mem_stall``: memory holds (``chip_sdram``: the
    SDRAM model's, from ``run_chip``'s memory LFSR; ``chip``: request back-pressure), and
    ``chip``'s responses come 1 to ``max_delay`` cycles after their requests. The caller
    checks ``mismatches`` (empty when the Verilog agrees with the model) and the counters."""
    from rtl.rgs import SlaveResult
    from tb.harness.chip import _finish, frame_registers, golden_frame
    from tb.harness.compare import record_fields
    from tb.harness.chip_sdram import write_image
    from tb.harness.lfsr import lfsr_seeds, sixteenths

    from tb.harness.cocotb.runner import build, interface, run as run_bench
    if top not in TOPS:
        raise ValueError(f"top {top!r}: one of {', '.join(TOPS)}")
    dut = interface(top, cfg)
    words = np.asarray(image.data, np.uint64)
    if top == "chip_sdram" and len(words) > dut.mem_depth:
        raise ValueError(f"the memory image has {len(words)} words; chip_sdram holds "
                         f"{dut.mem_depth} (tb.harness.chip_sdram.MEM_WORDS)")
    seeds = lfsr_seeds(seed, 3)
    lay = SlaveResult(cfg)
    params = {"top": top, "result_bits": lay.size, "result_ports": cfg.result_ports, "counters": counter_ports(cfg, top),
              "consts": register_ports(dut, frame_registers(cfg, image, camera, width, height,
                                                            scene)),
              "stall_q": sixteenths(stall, "stall"), "stall_seed": seeds[1],
              "mem_stall_q": sixteenths(mem_stall, "mem_stall"), "mem_seed": seeds[2],
              "seed": seed, "max_delay": max_delay, "max_cycles": max_cycles}
    b = build(top, cfg, sim, **build_kw)
    if top == "chip":                   # the bench serves the memory port
        params["mem"] = {"addr_bits": len(dut.mem.req.payload.addr),
                         "data_bits": len(dut.mem.resp.payload.data)}
        arrays, plusargs = {"image": words}, []
    else:                               # the SDRAM model reads the image at time 0
        image_file = Path(run_dir) / "image.hex"
        image_file.parent.mkdir(parents=True, exist_ok=True)
        write_image(words, image_file)
        arrays, plusargs = {}, [f"+image={image_file.resolve()}"]
    r = run_bench("chip", b, run_dir, params=params, arrays=arrays, plusargs=plusargs)
    got = [int.from_bytes(row.tobytes(), "little") for row in r.arrays["results"]]
    records = {k: np.array([(v >> off) & ((1 << wd) - 1) for v in got], np.int64)
               for k, off, wd in record_fields(lay)}
    v = r.values["counters"]
    run = _finish(cfg, image, records, v["cycles"], r.values["seconds"], counters(cfg, v),
                  golden_frame(cfg, image, camera, width, height, scene))
    if top == "chip":        # the bench's memory: one port, every word it served
        run.counters["mem_words"] = [r.values["served"]]
    return run, r


def register_ports(dut, regs: dict) -> dict[str, int]:
    """The host registers ``regs`` (``tb.harness.chip.frame_registers``) as port values of ``dut``'s
    Verilog: a vector through its port's layout (three format words, the first in the low
    bits); light l's vector is port ``lights__l``, its colour ``light_col__l``."""
    out = {}
    for name, value in regs.items():
        light = re.fullmatch(r"(light|lcol)(\d+)", name)
        if light:
            array = "lights" if light[1] == "light" else "light_col"
            port = getattr(dut, array)[int(light[2])]
            name = f"{array}__{light[2]}"
        else:
            port = getattr(dut, name)
        out[name] = (port.shape().const(value).as_value().value if isinstance(value, list)
                     else int(value))
    return out


def counter_ports(cfg, top: str) -> list[str]:
    """The counter ports of ``top``'s Verilog the bench reads at the end of the frame."""
    n = cfg.rtcs
    names = ["cycles", "rays_in", "results_out", "mem_reads"]
    names += [f"{k}__{s}" for k in ("packets", "rtc_counters", "slave_counters", "shade_hits",
                                    "shade_misses", "tex_hits", "tex_misses") for s in range(n)]
    names += [f"{k}__{i}" for k in ("hits", "misses") for i in range(3 * cfg.rtcmis)]
    names += [f"waits__{c}" for c in range(3)]
    names += [f"grants__{i}" for i in range(3 * cfg.rtcmis + 2 * n)]
    if top == "chip_sdram":
        names += [f"mem_{k}__{c}" for k in ("words", "busy") for c in range(cfg.mem_chips)]
    return names


def counters(cfg, ports: dict[str, int]) -> dict[str, int]:
    """The counter ports' values as ``tb.harness.chip_frame.chip_counter_names`` names them (what
    ``tb.harness.chip`` reads from ``ChipFrame``); the SDRAM chips' only if ``ports`` has them."""
    from rtl.chip import Chip, counter_names
    from rtl.rtcmi import CACHES
    n, k3, v = cfg.rtcs, 3 * cfg.rtcmis, ports
    shared = cfg.cache_topology == "shared"
    c = {k: v[k] for k in ("rays_in", "results_out", "mem_reads")}
    for s in range(n):
        c[f"packets{s}"] = v[f"packets__{s}"]
        c.update(_split(v[f"rtc_counters__{s}"], [f"rtc{s}_{k}" for k in counter_names(cfg)]))
        c.update(_split(v[f"slave_counters__{s}"],
                        [f"slave{s}_{k}" for k in Chip.SLAVE_COUNTERS]))
        for ci, cache in enumerate(CACHES if not shared else ()):
            for k in ("hits", "misses", "grants"):
                c[f"rtc{s}_{cache}_{k}"] = v[f"{k}__{3 * s + ci}"]
        c[f"slave{s}_shade_hits"] = v[f"shade_hits__{s}"]
        c[f"slave{s}_shade_misses"] = v[f"shade_misses__{s}"]
        c[f"slave{s}_shade_grants"] = v[f"grants__{k3 + s}"]
        c[f"slave{s}_tex_hits"] = v[f"tex_hits__{s}"]
        c[f"slave{s}_tex_misses"] = v[f"tex_misses__{s}"]
        c[f"slave{s}_tex_grants"] = v[f"grants__{k3 + n + s}"]
    for ci, cache in enumerate(CACHES if shared else ()):
        for k in ("hits", "misses", "grants", "waits"):
            c[f"rtcmi_{cache}_{k}"] = v[f"{k}__{ci}"]
    for k in range(cfg.mem_chips):
        if f"mem_words__{k}" in v:
            c[f"chip{k}_words"], c[f"chip{k}_busy"] = v[f"mem_words__{k}"], v[f"mem_busy__{k}"]
    return c


def _split(word: int, names: list[str]) -> dict[str, int]:
    """A packed counter word (32 bits a name, first in the low bits) as ``{name: value}``."""
    return {k: (word >> (32 * i)) & 0xFFFFFFFF for i, k in enumerate(names)}


class Frame:
    """``start`` in cycle 0 (the first after reset), ``done`` watched from cycle 1 on;
    ``mem_hold`` (``chip_sdram``) from ``hold``."""

    def __init__(self, dut, hold=None):
        self.start_port = _Port(dut.start)
        self.done_port = dut.done
        self.hold = hold
        self.hold_port = _Port(dut.mem_hold) if hold is not None else None
        self.done = False

    def drive(self, cycle: int) -> None:
        self.start_port.set(int(cycle == 0))
        if self.hold is not None:
            self.hold_port.set(int(self.hold(cycle)))

    def sample(self, cycle: int) -> bool:
        if cycle >= 1 and read(self.done_port, "done"):
            self.done = True
        return False

    def __str__(self):
        return f"frame: {'done' if self.done else 'busy'}"


@cocotb.test()
async def chip(dut):
    """A frame: registers, start, every result out; memory from the scene's image."""
    p, a = load()
    sdram = p["top"] == "chip_sdram"
    # one sink per result stream, each held by a copy of the frame's one back-pressure pattern
    sinks = [Sink(dut, f"results__{i}", hold=LFSRPattern(p["stall_q"], p["stall_seed"]))
             for i in range(p["result_ports"])]
    frame = Frame(dut, LFSRPattern(p["mem_stall_q"], p["mem_seed"]) if sdram else None)
    agents = [frame, *sinks]
    mem = None
    if not sdram:
        m, image = p["mem"], a["image"]
        mem = Memory(dut, "mem", lambda addr: int(image[addr]), addr_bits=m["addr_bits"],
                     data_bits=m["data_bits"], rng=np.random.default_rng(p["seed"] + 10),
                     max_delay=p["max_delay"],
                     hold=Pattern(p["mem_stall_q"] / 16, p["seed"] + 20))
        agents.append(mem)

    if sdram:
        dut.mem_hold.value = 0
    await start(dut, p["consts"], reset_cycles=1)
    t0 = time.perf_counter()
    # no stream moves while the first rays are traced: the cycle limit is the only timeout
    cycles = await run(dut, agents, lambda: frame.done, max_cycles=p["max_cycles"],
                       quiet=p["max_cycles"])
    seconds = time.perf_counter() - t0
    counters = await read_ports(dut, p["counters"])
    got = [r for sink in sinks for r in sink.got]
    save({"results": from_ints(got, p["result_bits"])}, cycles=cycles,
         seconds=seconds, counters=counters, served=len(mem.addrs) if mem else None)
