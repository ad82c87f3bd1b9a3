"""The chip on the SDRAM model with the chip's own host ports outside: :class:`ChipOnSDRAM`,
the simulation top of the cocotb chip bench (``tb/harness/cocotb/chip.py``, top ``chip_sdram``).

``tb/harness/chip_frame.py``'s ``ChipFrame`` puts the same memory behind the chip but loads the
host registers as constants and makes its own back-pressure (what a C++ main needs); here a
testbench drives every register, ``start`` and the result stream's ``ready`` itself. The
memory image is read at time 0 from a hex file (``tb/harness/image_mem.v``, plusarg ``+image=``):
loading it through a port would cost a clock cycle a word (78 768 for Cornell).
"""
from __future__ import annotations

from amaranth.hdl import Instance, Module
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from model.config import Config
from rtl.chip import Chip
from rtl.common import COUNTER_BITS
from tb.harness.memory import SDRAMMemory

from tb.harness.frame import VerilogMemory

__all__ = ["ChipOnSDRAM", "ImageMemory", "MEM_WORDS", "VERILOG_SOURCES", "write_image"]

# words the memory holds (1 MB: Cornell with its slave records is 78 768 words)
MEM_WORDS = 1 << 17
# the Verilog the export needs beside its own (the memory: no initial contents in the Verilog)
VERILOG_SOURCES = ("image_mem.v",)


def write_image(words, path) -> None:
    """The memory image as ``tb/harness/image_mem.v`` reads it (``$readmemh``: a word a line)."""
    from pathlib import Path
    Path(path).write_text("".join(f"{int(w):016x}\n" for w in words))


class ImageMemory(VerilogMemory):
    """A memory of ``depth`` x ``width`` bits held by ``tb/harness/image_mem.v`` (an ``Instance``),
    filled at time 0 from the file of the plusarg ``+image=`` (:func:`write_image`): one
    ``read_port(domain="comb")``; its write port (the SDRAM model's load port) is not
    connected."""

    def elaborate(self, platform):
        m = Module()
        rd = self._rd
        if rd is None or rd.sync:
            raise ValueError("ImageMemory has one combinational read port")
        m.submodules.store = Instance("image_mem", p_ABITS=self.abits, p_WIDTH=self.width,
                                      i_r_addr=rd.addr, o_r_data=rd.data)
        return m


class ChipOnSDRAM(wiring.Component):
    """The chip (:class:`rtl.chip.Chip`) with :class:`tb.harness.memory.SDRAMMemory` behind its memory
    port (``cfg.mem_chips`` chips at the configuration's clock ratio and latency), as in
    ``ChipFrame`` (simulation only).

    Ports: every port of :class:`~rtl.chip.Chip` but ``mem`` (host registers, ``start``,
    ``busy``/``done``, ``results``, counters); ``mem_hold`` (while high the SDRAM model holds
    its responses: random memory latency); ``mem_words[k]``, ``mem_busy[k]`` (the SDRAM chips'
    counters). The memory (:class:`ImageMemory`) holds ``mem_words`` words, the image from the
    ``+image=`` file.

    A run as ``ChipFrame``'s: ``start`` in the first cycle after reset, so that the chip and
    the SDRAM model leave reset in the cycle of ``start``; with the same result back-pressure
    the chip counts the same ``cycles``.
    """

    def __init__(self, cfg: Config, *, mem_words: int = MEM_WORDS):
        self.cfg = cfg
        self.chip = Chip(cfg)
        self.mem_depth = mem_words
        self.memory = SDRAMMemory(None, addr_width=cfg.addr_bits,
                                  tag_width=len(self.chip.mem.req.payload.tag),
                                  chips=cfg.mem_chips, chip_bits=cfg.mem_chip_bits,
                                  clock_ratio=cfg.mem_clock_ratio, latency=cfg.mem_latency,
                                  chip_queue=cfg.mem_chip_queue, load=True,
                                  store=ImageMemory(width=64, depth=mem_words))
        members = {k: v for k, v in self.chip.signature.members.items() if k != "mem"}
        members.update({"mem_hold": In(1),
                        "mem_words": Out(COUNTER_BITS).array(cfg.mem_chips),
                        "mem_busy": Out(COUNTER_BITS).array(cfg.mem_chips)})
        super().__init__(members)

    def elaborate(self, platform):
        m = Module()
        m.submodules.chip = chip = self.chip
        m.submodules.memory = mem = self.memory
        wiring.connect(m, chip.mem, mem.port)
        outer = {path: value for path, _, value in self.signature.flatten(self)}
        for path, member, value in chip.signature.flatten(chip):
            if path[0] == "mem":
                continue
            if member.flow == In:
                m.d.comb += value.eq(outer[path])
            else:
                m.d.comb += outer[path].eq(value)
        m.d.comb += [mem.ld_en.eq(0), mem.hold.eq(self.mem_hold)]
        for k in range(self.cfg.mem_chips):
            m.d.comb += [self.mem_words[k].eq(mem.words[k]), self.mem_busy[k].eq(mem.busy[k])]
        return m
