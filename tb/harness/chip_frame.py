"""Simulation-only top for whole frames through the chip: :class:`ChipFrame` (exported to
Verilog and clocked by ``tb/harness/verilator_main.cpp`` like ``tb/harness/frame.py``'s one-RTC frame; the
host side is ``tb/harness/chip.py``). The Verilator binary depends on this file, not on the host code.
"""
from __future__ import annotations

from amaranth.hdl import Module
from amaranth.lib import wiring

from model.config import Config
from rtl.chip import Chip, counter_names
from tb.harness.memory import SDRAMMemory
from rtl.cache import STALLS as CACHE_STALLS
from rtl.rtcmi import CACHES

__all__ = ["ChipFrame", "chip_consts", "chip_counter_names", "REGISTERS"]


def chip_consts(cfg: Config) -> list[str]:
    """The constants :class:`ChipFrame` loads (``ld_sel`` = CONST, address = position): the
    chip's registers (three words for a vector: ``pos_0``, ``pos_1``, ``pos_2``; light l's
    vector ``light{l}_0`` ..., its colour ``lcol{l}_0`` ...), then the result back-pressure (``stall_q``, sixteenths) and its
    LFSR seed, then the fraction of cycles the SDRAM model holds its responses
    (``mem_stall_q``) and that LFSR's seed."""
    names = []
    for k, v in REGISTERS.items():
        names += [f"{k}_{i}" for i in range(3)] if v else [k]
    for li in range(max(1, cfg.rgs_lights)):
        names += [f"light{li}_{i}" for i in range(3)]
    for li in range(max(1, cfg.rgs_lights)):
        names += [f"lcol{li}_{i}" for i in range(3)]
    return names + ["stall_q", "seed", "mem_stall_q", "mem_seed"]


REGISTERS = {"node_base": 0, "list_base": 0, "tri_base": 0, "root": 0, "rec_base": 0,
             "box_lo": 1, "box_hi": 1, "pos": 1, "corner": 1, "dx": 1, "dy": 1, "width": 0,
             "height": 0, "tiles_x": 0, "tiles_y": 0, "eps": 0, "light_point": 0,
             "n_lights": 0, "reflect_depth": 0, "amb": 0, "bg": 1, "w_eye": 0,
             "eye_miss": 1, "colour": 0, "box_cull": 0}   # 1: a vector of 3 words


def chip_counter_names(cfg: Config) -> list[str]:
    """Order of the 32-bit fields of ``ChipFrame.counters`` (low bits first)."""
    names = ["rays_in", "results_out", "mem_reads"]
    names += [f"packets{s}" for s in range(cfg.rtcs)]
    shared = cfg.cache_topology == "shared"
    for r in range(cfg.rtcs):
        names += [f"rtc{r}_{k}" for k in counter_names(cfg)]
        if not shared:                      # each RTC's own caches
            names += [f"rtc{r}_{c}_{k}" for c in CACHES for k in ("hits", "misses", "grants")]
        names += [f"slave{r}_{k}" for k in Chip.SLAVE_COUNTERS]
        names += [f"slave{r}_shade_{k}" for k in ("hits", "misses", "grants")]
        names += [f"slave{r}_tex_{k}" for k in ("hits", "misses", "grants")]
    if shared:                              # the RTC-MI's caches, shared by the RTCs
        names += [f"rtcmi_{c}_{k}" for c in CACHES
                  for k in ("hits", "misses", "grants", "waits", *CACHE_STALLS)]
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
        from tb.harness.lfsr import passes, sink_to
        t, m = self.top, Module()
        m.submodules.chip = chip = t.chip
        m.submodules.memory = mem = t.memory
        wiring.connect(m, chip.mem, mem.port)
        c = t.const
        for k, vec in REGISTERS.items():
            port = getattr(chip, k)
            if vec:
                for i in range(3):
                    m.d.comb += port[i].eq(c[f"{k}_{i}"])
            else:
                m.d.comb += port.eq(c[k])
        for li, port in enumerate(chip.lights):
            for i in range(3):
                m.d.comb += port[i].eq(c[f"light{li}_{i}"])
        for li, port in enumerate(chip.light_col):
            for i in range(3):
                m.d.comb += port[i].eq(c[f"lcol{li}_{i}"])
        going = Signal()
        m.d.sync += going.eq(1)
        m.d.comb += [chip.start.eq(~going), t.finished_run.eq(going & chip.done)]
        # every result stream takes in the same cycles (one back-pressure pattern)
        ready = passes(t.lfsr.value, c["stall_q"])
        wd = len(t.res_data) // len(chip.results)
        for i, res in enumerate(chip.results):
            m.d.comb += [t.res_valid[i].eq(sink_to(m, res, ready)),
                         t.res_data[i * wd:(i + 1) * wd].eq(res.payload)]
        m.d.comb += mem.hold.eq(~passes(t.mem_lfsr.value, c["mem_stall_q"]))
        return m


class ChipFrame(wiring.Component):
    """The chip on a loadable SDRAM model, for whole frames in Verilator (simulation only):
    the same outside as :class:`tb.harness.frame.RTCFrame` (``tb/harness/verilator_main.cpp`` drives both).

    Load (``ld_sel``): 0 the memory image into the SDRAM model's words (in Verilator the
    model's memory takes them at time 0 instead: ``VerilogMemory(preload=True)``); 2 constant
    ``ld_addr``
    of :func:`chip_consts` (the chip's registers, result back-pressure and its LFSR seed). No
    ray memory: the chip makes its rays (``cap_ray_slots`` = 0). After ``start`` the chip and
    the memory model leave reset and the chip renders the frame; every result transfer shows on
    ``res_valid`` / ``res_data`` (``cfg.result_ports`` side by side); ``finished`` once the
    chip is done; ``cycles`` = the chip's busy cycles; ``counters`` = :func:`chip_counter_names` (32 bits each, first in the low bits).

    ``preload`` (Amaranth simulation, ``verilog_memories=False``): ``{"image": words,
    "consts": {name: value}}`` as initial contents, so no load cycles are needed; the run is
    cycle for cycle the loaded one's.
    """

    def __init__(self, cfg: Config, *, mem_words: int, verilog_memories: bool = True,
                 preload: dict | None = None, dedup: bool = False):
        from amaranth.hdl import Signal
        from amaranth.lib.memory import Memory
        from amaranth.utils import ceil_log2

        from tb.harness.frame import VerilogMemory, frame_signature
        from tb.harness.lfsr import LFSR
        self.cfg = cfg
        self.chip = Chip(cfg)
        # dedup (Verilator builds): each kind of repeated unit exported once as its own module,
        # its copies Instances of it (tb/harness/blackbox.py); ``units``: (module name, the unit to
        # export, its stand-ins)
        self.hold = Signal()
        self.units = []
        if dedup:
            from tb.harness.blackbox import deduplicate
            c = self.chip
            for slots, name in ((c.slaves, "slave"), (c.array.rtcs, "rtc"),
                                (c.array.mis, "rtcmi"), (c.shade_caches, "shade_cache"),
                                (c.tex_caches, "tex_cache")):
                unit = deduplicate(slots, name, self.hold)
                if unit is not None:
                    self.units.append((name, unit, slots))
        # no more words than the chip's addresses reach (cfg.addr_bits)
        self.mem_words = 1 << min(cfg.addr_bits, max(1, ceil_log2(max(1, mem_words))))
        init = [] if preload is None else [int(w) for w in preload["image"]]
        if len(init) > self.mem_words:
            raise ValueError(f"memory image of {len(init)} words > mem_words={mem_words}")
        store = (VerilogMemory(width=64, depth=self.mem_words, preload=True)
                 if verilog_memories else Memory(shape=64, depth=self.mem_words, init=init))
        self.memory = SDRAMMemory(None, addr_width=cfg.addr_bits,
                                  tag_width=len(self.chip.mem.req.payload.tag),
                                  chips=cfg.mem_chips, chip_bits=cfg.mem_chip_bits,
                                  clock_ratio=cfg.mem_clock_ratio, latency=cfg.mem_latency,
                                  chip_queue=cfg.mem_chip_queue, load=True, store=store)
        self.consts = chip_consts(cfg)
        self.names = chip_counter_names(cfg)
        from rtl.rgs import SlaveResult
        super().__init__(frame_signature(cfg, len(self.names), SlaveResult(cfg),
                                         ports=cfg.result_ports))
        values = {} if preload is None else preload["consts"]
        self.const = {name: Signal(32, name=f"c_{name}", reset_less=True,
                                   init=int(values.get(name, 0))) for name in self.consts}
        self.lfsr = LFSR(loadable=True)           # result back-pressure
        self.mem_lfsr = LFSR(loadable=True)       # memory response holds
        self.finished_run = Signal()

    def elaborate(self, platform):
        from amaranth.hdl import ResetInserter
        from tb.harness.frame import SEL_IMAGE, load_consts_and_start
        m = Module()
        mem = self.memory
        m.d.comb += [mem.ld_en.eq(self.ld_valid & (self.ld_sel == SEL_IMAGE)),
                     mem.ld_addr.eq(self.ld_addr), mem.ld_data.eq(self.ld_data)]
        run = load_consts_and_start(m, self, self.consts)
        m.submodules.lfsr, m.submodules.mem_lfsr = self.lfsr, self.mem_lfsr
        m.d.comb += [self.lfsr.en.eq(run), self.lfsr.seed.eq(self.const["seed"]),
                     self.mem_lfsr.en.eq(run), self.mem_lfsr.seed.eq(self.const["mem_seed"])]
        m.submodules.run = ResetInserter({"sync": ~run})(_ChipRun(self))
        m.d.comb += self.hold.eq(~run)
        taken = [self.res_valid[i] for i in range(len(self.res_valid))]
        m.d.sync += self.results.eq(self.results + sum(taken[1:], taken[0]))
        chip = self.chip
        values = [chip.rays_in, chip.results_out, chip.mem_reads, *chip.packets]
        names = counter_names(self.cfg)
        n, k = self.cfg.rtcs, self.cfg.rtcmis
        shared = self.cfg.cache_topology == "shared"
        for r in range(n):
            word = chip.rtc_counters[r]
            values += [word[32 * i:32 * i + 32] for i in range(len(names))]
            if not shared:
                for c in range(3):
                    values += [chip.hits[3 * r + c], chip.misses[3 * r + c],
                               chip.grants[3 * r + c]]
            word = chip.slave_counters[r]
            values += [word[32 * i:32 * i + 32] for i in range(len(Chip.SLAVE_COUNTERS))]
            values += [chip.shade_hits[r], chip.shade_misses[r], chip.grants[3 * k + r]]
            values += [chip.tex_hits[r], chip.tex_misses[r], chip.grants[3 * k + n + r]]
        if shared:
            for c in range(3):
                values += [chip.hits[c], chip.misses[c], chip.grants[c], chip.waits[c]]
                values += [chip.cache_stalls[len(CACHE_STALLS) * c + i]
                           for i in range(len(CACHE_STALLS))]
        values += list(mem.words) + list(mem.busy)
        from amaranth.hdl import Cat
        m.d.comb += [self.counters.eq(Cat(*values)), self.cycles.eq(chip.cycles),
                     self.running.eq(run), self.finished.eq(run & self.finished_run),
                     self.cap_mem_words.eq(self.mem_words), self.cap_ray_slots.eq(0)]
        return m
