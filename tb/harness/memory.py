"""Simulation-only memories serving a :class:`~rtl.memport.MemReadPort` from a memory image.

Both are plain Amaranth hardware (contents in ``lib.memory.Memory``, initialised from the golden
model's ``uint64`` image), so they run unchanged under pysim and Verilator with no Python in the
per-cycle loop. They would synthesize, but they are not part of the chip (an FPGA memory
controller serves the chip's memory port instead, see ``docs/memory-interface.md``).

* :class:`IdealMemory`: a fixed latency and a request queue; one word per cycle.
* :class:`SDRAMMemory`: a memory controller with ``m`` 16-bit SDRAM chips at a ``k:1`` clock ratio
  and XOR-fold address hashing over the chips; each chip delivers one 64-bit word per
  ``64 / chip_bits * k`` chip cycles.
"""
from __future__ import annotations

import numpy as np
from amaranth.hdl import Array, Cat, Module, Mux, Signal
from amaranth.lib import wiring
from amaranth.lib.fifo import SyncFIFO
from amaranth.lib.memory import Memory
from amaranth.lib.wiring import In, Out
from amaranth.utils import ceil_log2

from rtl.memport import WORD_BITS, MemReadPort
from rtl.common import COUNTER_BITS

__all__ = ["IdealMemory", "SDRAMMemory", "chip_of", "image_memory"]


def image_memory(image, addr_width: int) -> Memory:
    """A ``Memory`` of 64-bit words holding ``image``, sized to a power of two (addresses wrap)."""
    image = np.asarray(image)
    if image.dtype != np.uint64 or image.ndim != 1:
        raise TypeError(f"memory image must be a 1-D numpy uint64 array of 64-bit words, got "
                        f"{image.dtype} with shape {image.shape}; build it with model.layout")
    depth = 1 << max(1, ceil_log2(max(1, len(image))))
    if depth > (1 << addr_width):
        raise ValueError(f"memory image of {len(image)} words needs {ceil_log2(depth)} address "
                         f"bits, but the port has addr_width={addr_width}; widen the port")
    return Memory(shape=WORD_BITS, depth=depth, init=[int(w) for w in image])


def chip_of(addr, chips: int):
    """Chip serving a word address: XOR-fold of the address in log2(chips)-bit groups.

    Works on Python ints and numpy integer arrays; the RTL in :class:`SDRAMMemory` is the same.
    Consecutive words go to consecutive chips; power-of-two strides are spread as well.
    """
    bits = chips.bit_length() - 1
    if bits == 0:
        return addr * 0
    out = addr * 0
    mask = chips - 1
    for shift in range(0, 64, bits):
        out = out ^ ((addr >> shift) & mask)
    return out


def _storage(image, addr_width: int, *, load: bool, depth: int | None, store, who: str):
    """The words a simulation memory holds: ``store`` (an object with ``Memory``'s ``depth``,
    ``read_port()`` and ``write_port()``, filled through the load port), an empty ``Memory``
    of ``depth`` words (``image=None``, filled through the load port) or a ``Memory``
    initialised with ``image``."""
    if store is not None:
        if image is not None or not load:
            raise ValueError(f"{who} store=...: pass image=None and load=True (the store "
                             "starts empty and is filled through the load port)")
        if store.depth > (1 << addr_width):
            raise ValueError(f"{who} store of {store.depth} words needs more than "
                             f"addr_width={addr_width} address bits; widen the port")
        return store
    if image is None:
        if depth is None or depth < 1:
            raise ValueError(f"{who} without an image needs depth=<words> (>= 1)")
        depth = 1 << max(1, ceil_log2(depth))
        if depth > (1 << addr_width):
            raise ValueError(f"{who} depth={depth} words needs more than "
                             f"addr_width={addr_width} address bits; widen the port")
        return Memory(shape=WORD_BITS, depth=depth, init=[])
    return image_memory(image, addr_width)


def _load_port(m: Module, top, mem) -> None:
    """``top``'s load port (``ld_en``, ``ld_addr``, ``ld_data``) writes ``mem``."""
    wr = mem.write_port()
    m.d.comb += [wr.addr.eq(top.ld_addr), wr.data.eq(top.ld_data), wr.en.eq(top.ld_en)]


class IdealMemory(wiring.Component):
    """Memory with a fixed latency and a request queue.

    A request accepted in cycle ``t`` is answered (``resp.valid``) in cycle ``t + latency`` unless
    the response stream is back-pressured; responses come in request order. Throughput: one word
    per cycle while fewer than ``queue`` requests are in flight (``queue > latency`` sustains it).

    Parameters: ``image`` (uint64 words), ``addr_width``, ``tag_width``, ``latency`` (>= 2 cycles),
    ``queue`` (requests in flight, default ``latency + 1``).
    Counters: ``reads`` (words delivered).

    ``hold`` (input, default 0): while high the memory answers nothing (the head response
    waits), so a testbench driving it from an LFSR turns the fixed latency into a random one,
    order kept; requests back up into the queue and then stall at the port.

    With ``load=True`` the memory also has a write port for filling it before use (one word per
    cycle: ``ld_en``, ``ld_addr``, ``ld_data``; word written at the clock edge, not affected by
    reset); ``image`` may then be ``None`` with ``depth`` words (rounded up to a power of two,
    contents zero) so that one compiled simulation serves every scene (``tb/harness/frame.py``), or
    ``store``: an object with ``Memory``'s ``depth``, ``read_port()`` and ``write_port()`` to
    hold the words instead (``tb.harness.frame.VerilogMemory``: Amaranth writes a ``Memory``'s whole
    initial contents into the Verilog, which is slow for millions of words).
    """

    def __init__(self, image, *, addr_width: int, tag_width: int, latency: int,
                 queue: int | None = None, load: bool = False, depth: int | None = None,
                 store=None):
        if latency < 2:
            raise ValueError(f"IdealMemory latency={latency}: must be >= 2 cycles "
                             "(one for the request register, one for the memory read)")
        self.latency = latency
        self.queue = latency + 1 if queue is None else queue
        if self.queue < 1:
            raise ValueError(f"IdealMemory queue={queue} must be >= 1")
        self._mem = _storage(image, addr_width, load=load, depth=depth, store=store,
                             who="IdealMemory")
        self.depth = self._mem.depth
        self.load = load
        ports = {
            "port": In(MemReadPort(addr_width=addr_width, data_width=WORD_BITS,
                                   tag_width=tag_width)),
            "reads": Out(COUNTER_BITS),
            "hold": In(1),
        }
        if load:
            ports.update({"ld_en": In(1), "ld_addr": In(addr_width), "ld_data": In(WORD_BITS)})
        super().__init__(ports)

    def elaborate(self, platform):
        m = Module()
        m.submodules.mem = mem = self._mem
        rd = mem.read_port()
        req, resp = self.port.req, self.port.resp
        tag_width = len(req.payload.tag)
        if self.load:
            _load_port(m, self, mem)

        inflight = Signal(range(self.queue + 1))
        accept = req.valid & req.ready
        deliver = resp.valid & resp.ready
        m.d.comb += req.ready.eq(inflight < self.queue)
        m.d.sync += inflight.eq(inflight + accept - deliver)

        # delay line: latency - 2 register stages in front of the (1-cycle) memory read
        v, a, t = accept, req.payload.addr, req.payload.tag
        for i in range(self.latency - 2):
            nv, na, nt = Signal(name=f"d{i}_valid"), Signal.like(a, name=f"d{i}_addr"), \
                Signal(tag_width, name=f"d{i}_tag")
            m.d.sync += [nv.eq(v), na.eq(a), nt.eq(t)]
            v, a, t = nv, na, nt
        rd_valid, rd_tag = Signal(), Signal(tag_width)
        m.d.comb += [rd.addr.eq(a), rd.en.eq(1)]
        m.d.sync += [rd_valid.eq(v), rd_tag.eq(t)]

        m.submodules.fifo = fifo = SyncFIFO(width=WORD_BITS + tag_width, depth=self.queue)
        m.d.comb += [
            fifo.w_en.eq(rd_valid),
            fifo.w_data.eq(Cat(rd.data, rd_tag)),
            resp.valid.eq(fifo.r_rdy & ~self.hold),
            resp.payload.data.eq(fifo.r_data[:WORD_BITS]),
            resp.payload.tag.eq(fifo.r_data[WORD_BITS:]),
            fifo.r_en.eq(resp.ready & ~self.hold),
        ]
        with m.If(deliver):
            m.d.sync += self.reads.eq(self.reads + 1)
        return m


class SDRAMMemory(wiring.Component):
    """Memory controller with ``chips`` SDRAM chips (simulation model of their timing).

    Request ``addr`` (a word address) goes to chip :func:`chip_of`; each chip has a request queue
    (``chip_queue`` entries; a request for a full chip's queue waits at the port, blocking those
    behind it). A chip starts an access on an SDRAM clock edge (every ``clock_ratio`` chip cycles)
    when its data bus is free; one 64-bit word occupies the chip's data bus for
    ``burst = 64 / chip_bits * clock_ratio`` chip cycles (16 for 16-bit chips at 4:1), so a chip
    sustains ``chip_bits`` bits per SDRAM cycle. The word is answered ``latency + burst`` chip
    cycles after the access starts (``latency``: cycles to the first data beat). Responses of
    different chips may overtake each other (the tag identifies them); one response per cycle,
    round-robin over the chips with a due word. Rows, banks and refresh are not modelled.

    Counters (per chip, ``Out`` arrays): ``words`` (words read), ``busy`` (cycles the data bus is
    occupied); ``cycles`` (cycles since reset).

    ``hold`` (input, default 0): while high no response leaves (due words wait, chips stop
    starting accesses once their in-flight queues fill): a testbench driving it from an LFSR
    adds random latency to every word, the order among chips changing with it.

    The words are read when they are answered (one read port, combinational: the model needs
    no more than one read a cycle). ``load``, ``depth`` and ``store`` as for
    :class:`IdealMemory` (a load port ``ld_en``, ``ld_addr``, ``ld_data``).
    """

    def __init__(self, image, *, addr_width: int, tag_width: int, chips: int = 4,
                 chip_bits: int = 16, clock_ratio: int = 4, latency: int = 20,
                 chip_queue: int = 4, load: bool = False, depth: int | None = None,
                 store=None):
        if chips < 1 or chips & (chips - 1):
            raise ValueError(f"SDRAMMemory chips={chips}: must be a power of two (1, 2, 4, 8) "
                             "for the XOR-fold address hash")
        if WORD_BITS % chip_bits:
            raise ValueError(f"SDRAMMemory chip_bits={chip_bits} must divide {WORD_BITS}")
        if clock_ratio < 1 or latency < 0 or chip_queue < 1:
            raise ValueError("SDRAMMemory needs clock_ratio >= 1, latency >= 0, chip_queue >= 1")
        self.chips, self.chip_bits, self.clock_ratio = chips, chip_bits, clock_ratio
        self.latency, self.chip_queue = latency, chip_queue
        self.burst = WORD_BITS // chip_bits * clock_ratio
        # words in flight per chip: enough to cover latency + burst at one start per burst
        self.inflight = -(-(latency + self.burst) // self.burst) + 1
        self._mem = _storage(image, addr_width, load=load, depth=depth, store=store,
                             who="SDRAMMemory")
        self.depth, self.load = self._mem.depth, load
        ports = {
            "port": In(MemReadPort(addr_width=addr_width, data_width=WORD_BITS,
                                   tag_width=tag_width)),
            "words": Out(COUNTER_BITS).array(chips),
            "busy": Out(COUNTER_BITS).array(chips),
            "cycles": Out(COUNTER_BITS),
            "hold": In(1),
        }
        if load:
            ports.update({"ld_en": In(1), "ld_addr": In(addr_width), "ld_data": In(WORD_BITS)})
        super().__init__(ports)

    def elaborate(self, platform):
        m = Module()
        m.submodules.mem = mem = self._mem
        req, resp = self.port.req, self.port.resp
        tag_width = len(req.payload.tag)
        n, bits = self.chips, self.chips.bit_length() - 1
        rd = mem.read_port(domain="comb")
        if self.load:
            _load_port(m, self, mem)

        now = Signal(COUNTER_BITS)
        phase = Signal(range(self.clock_ratio))
        m.d.sync += [now.eq(now + 1), self.cycles.eq(self.cycles + 1),
                     phase.eq(Mux(phase == self.clock_ratio - 1, 0, phase + 1))]

        addr = req.payload.addr
        chip = Signal(range(n))
        if bits:
            groups = [addr[i:i + bits] for i in range(0, len(addr), bits)]
            fold = groups[0]
            for g in groups[1:]:
                fold = fold ^ g
            m.d.comb += chip.eq(fold)

        aw = len(addr)
        entry_bits = aw + tag_width + COUNTER_BITS
        due_heads, due_tags, due_addr, pops = [], [], [], []
        queue_ready = []
        for c in range(n):
            q = SyncFIFO(width=len(addr) + tag_width, depth=self.chip_queue)
            f = SyncFIFO(width=entry_bits, depth=self.inflight)
            m.submodules[f"queue{c}"], m.submodules[f"flight{c}"] = q, f
            queue_ready.append(q.w_rdy)
            m.d.comb += [q.w_data.eq(Cat(addr, req.payload.tag)),
                         q.w_en.eq(req.valid & (chip == c))]

            busy = Signal(range(self.burst), name=f"busy{c}")
            count = Signal(range(self.inflight + 1), name=f"count{c}")  # started, not answered
            start = Signal(name=f"start{c}")
            pop = Signal(name=f"pop{c}")
            m.d.comb += start.eq(q.r_rdy & (busy == 0) & (phase == 0) & (count < self.inflight))
            m.d.comb += q.r_en.eq(start)
            with m.If(start):
                m.d.sync += [busy.eq(self.burst - 1), self.words[c].eq(self.words[c] + 1)]
            with m.Elif(busy != 0):
                m.d.sync += busy.eq(busy - 1)
            with m.If(start | (busy != 0)):
                m.d.sync += self.busy[c].eq(self.busy[c] + 1)
            m.d.sync += count.eq(count + start - pop)

            # the access, with its due time, goes in flight one cycle later
            s_valid, s_addr, s_tag = Signal(), Signal(aw), Signal(tag_width)
            s_due = Signal(COUNTER_BITS)
            m.d.sync += [s_valid.eq(start), s_addr.eq(q.r_data[:aw]), s_tag.eq(q.r_data[aw:]),
                         s_due.eq(now + self.latency + self.burst)]
            m.d.comb += [f.w_en.eq(s_valid), f.w_data.eq(Cat(s_addr, s_tag, s_due))]

            head_due = f.r_data[aw + tag_width:]
            due = Signal(name=f"due{c}")
            m.d.comb += due.eq(f.r_rdy & ((now - head_due)[COUNTER_BITS - 1] == 0))
            m.d.comb += f.r_en.eq(pop)
            due_heads.append(due)
            due_addr.append(f.r_data[:aw])
            due_tags.append(f.r_data[aw:aw + tag_width])
            pops.append(pop)

        m.d.comb += req.ready.eq(Array(queue_ready)[chip])

        # round-robin over chips with a due word: the first due chip at or after `prio`
        prio = Signal(range(n))
        sel = Signal(range(n))
        any_due = Signal()
        # priority search: scan the chips in the order prio, prio+1, ...
        with m.Switch(prio):
            for p in range(n):
                with m.Case(p):
                    order = [(p + i) % n for i in range(n)]
                    with m.If(due_heads[order[0]]):
                        m.d.comb += sel.eq(order[0])
                    for c in order[1:]:
                        with m.Elif(due_heads[c]):
                            m.d.comb += sel.eq(c)
        m.d.comb += any_due.eq(Cat(*due_heads).any())
        m.d.comb += [resp.valid.eq(any_due & ~self.hold), rd.addr.eq(Array(due_addr)[sel]),
                     resp.payload.data.eq(rd.data),
                     resp.payload.tag.eq(Array(due_tags)[sel])]
        for c in range(n):
            m.d.comb += pops[c].eq(resp.valid & resp.ready & (sel == c))
        with m.If(resp.valid & resp.ready):
            m.d.sync += prio.eq(Mux(sel == n - 1, 0, sel + 1))
        return m
