"""Pieces every unit uses, defined once: counter width, priority encoder, round-robin pick,
the registered stream output and stream register, and the memory's binary32 words as format
words."""
from __future__ import annotations

import os
from collections.abc import Callable
from types import SimpleNamespace

from amaranth.hdl import Array, C, Cat, Const, Elaboratable, Module, Mux, Signal, Value
from amaranth.lib import data, stream, wiring
from amaranth.lib.memory import Memory
from amaranth.lib.wiring import In, Out
from amaranth.utils import ceil_log2

from model.fp import FPFormat

__all__ = ["COUNTER_BITS", "popcount", "sum_tree", "times_const", "lowest", "rr_pick",
           "OutputStage", "SkidBuffer", "BlockRAM", "ram_poison", "from_binary32"]

COUNTER_BITS = 32      # every statistics counter the hardware reports


def sum_tree(terms) -> Value:
    """The sum of ``terms`` as a balanced tree of adds (depth log2 of their number)."""
    terms = [Value.cast(t) for t in terms]
    if not terms:
        return C(0, 1)
    while len(terms) > 1:
        terms = [terms[k] + terms[k + 1] if k + 1 < len(terms) else terms[k]
                 for k in range(0, len(terms), 2)]
    return terms[0]


def times_const(v: Value, k: int) -> Value:
    """``v * k`` for a constant ``k >= 0`` as shifts and adds (one shifted copy of ``v`` per set
    bit of ``k``, summed as a tree): Yosys maps a ``*`` by a constant to a DSP block, whose
    delay and the wires to and from it made the int cache's line address (``k`` = 5 words a
    triangle) the routed critical path of the one-RTC FPGA design."""
    if k < 0:
        raise ValueError(f"times_const: k={k} must be >= 0")
    v = Value.cast(v)
    return sum_tree([v << i for i in range(k.bit_length()) if k >> i & 1])


def popcount(v: Value) -> Value:
    """The number of ones in ``v`` (a balanced tree of adds)."""
    return sum_tree(list(Value.cast(v)))


def lowest(m: Module, bits: Value, name: str) -> tuple[Signal, Signal]:
    """(any, index of the lowest set bit) of ``bits``: a priority encoder, built as a tree of
    2:1 muxes (log2 of the width deep, not a chain of one mux per bit); index 0 if none."""
    bits = Value.cast(bits)
    n = len(bits)
    idx = Signal(range(max(2, n)), name=f"{name}_idx")

    def tree(lo, hi):
        """(any, index within the part) of bits[lo:hi]; the left part is the largest power
        of two 2**k below the width, so an index is k bits plus one that says which part."""
        if hi - lo == 1:
            return bits[lo], Cat()
        k = (hi - lo - 1).bit_length() - 1
        mid = lo + (1 << k)
        a_l, i_l = tree(lo, mid)
        a_h, i_h = tree(mid, hi)
        pad = lambda i: Cat(i, C(0, k - len(i))) if len(i) < k else i
        return a_l | a_h, Mux(a_l | ~a_h, Cat(pad(i_l), C(0, 1)), Cat(pad(i_h), C(1, 1)))

    _, off = tree(0, n)
    m.d.comb += idx.eq(off)
    anyb = Signal(name=f"{name}_any")
    m.d.comb += anyb.eq(bits.any())
    return anyb, idx


def lowest_onehot(bits: Value) -> Value:
    """The lowest set bit of ``bits`` alone (0 if none): bit t is ``bits[t]`` and no lower bit."""
    bits = Value.cast(bits)
    return Cat(*(bits[t] & ~bits[:t].any() if t else bits[0] for t in range(len(bits))))


def _at_or_after(ptr: Value, n: int) -> Value:
    """One bit per request index t < n: ``t >= ptr`` (a constant 1 where no ``ptr`` exceeds t)."""
    top = (1 << len(Value.cast(ptr))) - 1
    return Cat(*(Const(1) if t >= top else ptr <= t for t in range(n)))


def rr_pick(m: Module, req: Value, ptr: Value, name: str) -> tuple[Signal, Signal]:
    """Round-robin: (any, first set bit of ``req`` at or after ``ptr``, wrapping around): the
    lowest request at or after ``ptr`` if there is one, else the lowest request (two priority
    encoders and a 2:1 mux; no rotation and no add)."""
    n = len(req)
    if n == 1:
        return lowest(m, req, name)
    req = Value.cast(req)
    ge = _at_or_after(ptr, n)                       # the requests at or after ptr
    hi_any, hi_idx = lowest(m, req & ge, f"{name}_hi")
    lo_any, lo_idx = lowest(m, req, name)
    idx = Signal(range(n), name=f"{name}_pick")
    m.d.comb += idx.eq(Mux(hi_any, hi_idx, lo_idx))
    return lo_any, idx


def rr_pick_onehot(req: Value, ptr: Value) -> Value:
    """:func:`rr_pick`'s pick as a one-hot vector (0 if no request)."""
    n = len(req)
    req = Value.cast(req)
    hi = req & _at_or_after(ptr, n)
    return Mux(hi.any(), lowest_onehot(hi), lowest_onehot(req))


def element(arr, idx: Value) -> Value:
    """The element ``idx`` of an ``Array``, or the bit ``idx`` of a ``Value``."""
    return arr.bit_select(idx, 1) if isinstance(arr, Value) else arr[idx]


def registered(m: Module, prefix: str, **values) -> dict:
    """Each value a cycle later, from a register named ``{prefix}_{name}`` (in ``values``'
    order)."""
    regs = {k: Signal.like(Value.cast(v), name=f"{prefix}_{k}") for k, v in values.items()}
    m.d.sync += [regs[k].eq(v) for k, v in values.items()]
    return regs


def rr_pick_next(m: Module, req: Value, ptr: Value, drop: Value, name: str,
                 taken: Value | None = None, copies: int = 1) -> tuple[Value, Value, Value,
                                                                     Callable]:
    """The next cycle's :func:`rr_pick` of ``req`` from registers, less the request ``taken``
    (one-hot; default: this pick itself) when ``drop``: both picks (with and without it), their
    one-hot forms and ``drop`` go into registers, and the pick is a 2:1 mux of them, so a late
    ``drop`` (a handshake, a busy flag) runs into one register instead of through the pick.
    Returns (any, index, one-hot, select) for the next cycle; ``select(array)`` is the picked
    element of an ``Array`` (or the bit of a ``Value``) read with both registered indices and
    then chosen by ``drop``'s register, so the 2:1 index mux does not come before the wide
    select. ``copies`` (1 or 2): the registered indices and ``drop`` are kept twice,
    ``select(array, copy)`` reads with copy 0 or 1, so each copy drives half of a wide select's
    multiplexers. The second copy resets to other values (a different cell, which synthesis
    does not merge with the first); the indices are only read while a pick is valid, which
    no reset value is."""
    if copies not in (1, 2):
        raise ValueError(f"rr_pick_next copies={copies}: 1 or 2")
    n = len(req)
    oh = Signal(n, name=f"{name}_onehot")
    less = (Value.cast(req) & ~(oh if taken is None else taken))[:n]
    l_any, l_idx = rr_pick(m, less, ptr, f"{name}_less")
    k_any, k_idx = rr_pick(m, req, ptr, name)
    vals = (l_any, l_idx, rr_pick_onehot(less, ptr), k_any, k_idx, rr_pick_onehot(req, ptr), drop)
    regs = [Signal(name=f"{name}_less_any_q"), Signal.like(l_idx, name=f"{name}_less_pick_q"),
            Signal(n, name=f"{name}_less_onehot_q"), Signal(name=f"{name}_any_q"),
            Signal.like(k_idx, name=f"{name}_pick_q"), Signal(n, name=f"{name}_onehot_q"),
            Signal(name=f"{name}_drop_q")]
    m.d.sync += [r.eq(v) for r, v in zip(regs, vals)]
    lq_any, lq_idx, lq_oh, kq_any, kq_idx, kq_oh, drop_q = regs
    m.d.comb += oh.eq(Mux(drop_q, lq_oh, kq_oh))
    sels = [(drop_q, lq_idx, kq_idx)]
    if copies == 2 and len(k_idx):
        dup = (Signal(name=f"{name}_drop_q1", init=1),
               Signal.like(l_idx, name=f"{name}_less_pick_q1", init=1),
               Signal.like(k_idx, name=f"{name}_pick_q1", init=1))
        m.d.sync += [r.eq(v) for r, v in zip(dup, (drop, l_idx, k_idx))]
        sels.append(dup)
    else:
        sels.append(sels[0])

    def select(arr, copy: int = 0):
        d, lq, kq = sels[copy]
        return Mux(d, element(arr, lq), element(arr, kq))
    return Mux(drop_q, lq_any, kq_any), Mux(drop_q, lq_idx, kq_idx), oh, select


class OutputStage(wiring.Component):
    """A registered stream output: ``o.valid`` and ``o.payload`` are flip-flops.

    ``i.ready`` is combinational: the register is empty or its transfer happens this cycle, so a
    producer can hand over one payload per cycle with no bubble. Latency 1, throughput 1.
    """

    def __init__(self, layout):
        super().__init__({"i": In(stream.Signature(layout)), "o": Out(stream.Signature(layout))})

    def elaborate(self, platform):
        m = Module()
        i, o = self.i, self.o
        m.d.comb += i.ready.eq(~o.valid | o.ready)
        with m.If(i.valid & i.ready):
            m.d.sync += [o.valid.eq(1), o.payload.eq(i.payload)]
        with m.Elif(o.ready):
            m.d.sync += o.valid.eq(0)
        return m


class SkidBuffer(wiring.Component):
    """A stream register that cuts both directions: ``o.valid``, ``o.payload`` and ``i.ready``
    are flip-flops, so no path runs from the producer to the consumer or back.

    ``i.ready`` is "the skid register is empty": the transfer offered in a cycle where the
    output holds goes into the skid register and leaves from it first. Latency 1 (a payload
    taken in cycle t is on ``o`` in t + 1), throughput 1 (no bubble while ``o.ready`` is high).
    """

    def __init__(self, layout):
        self._layout = layout
        super().__init__({"i": In(stream.Signature(layout)), "o": Out(stream.Signature(layout))})

    def elaborate(self, platform):
        m = Module()
        i, o = self.i, self.o
        k_valid = Signal()
        k_payload = Signal(self._layout)
        m.d.comb += i.ready.eq(~k_valid)
        with m.If(~o.valid | o.ready):
            with m.If(k_valid):
                m.d.sync += [o.valid.eq(1), o.payload.eq(k_payload), k_valid.eq(0)]
            with m.Else():
                m.d.sync += [o.valid.eq(i.valid), o.payload.eq(i.payload)]
        with m.Elif(i.valid & i.ready):
            m.d.sync += [k_valid.eq(1), k_payload.eq(i.payload)]
        return m


POISON_ENV = "SAARCOR_RAM_POISON"


def ram_poison() -> bool:
    """``SAARCOR_RAM_POISON`` is set (not empty, not 0): :class:`BlockRAM` poisons colliding
    reads in the designs elaborated now."""
    return os.environ.get(POISON_ENV, "0") not in ("", "0")


class BlockRAM(Memory):
    """A :class:`Memory` with synchronous, non-transparent read ports whose reads of a row
    written in the same cycle (by a port of the same domain) are left undefined: Yosys's
    ``no_rw_check`` attribute. ECP5 block RAM leaves such a read undefined, so for a plain
    ``Memory`` Yosys emulates the old-data read with a 2:1 mux after the RAM (select: the
    registered address match) and every read crosses a LUT on its way out; with
    ``no_rw_check`` the RAM's output is a register's input. For a unit whose colliding reads
    are never used (overridden by forwarding logic or ignored), which the simulations check:
    with the environment variable ``SAARCOR_RAM_POISON=1`` at elaboration, every colliding read
    returns its row with all bits inverted, so a use of it changes the results.
    Simulation without it returns the row before the write (as ``Memory`` does)."""

    def __init__(self, *, shape, depth: int, init=(), attrs=None, src_loc_at: int = 0):
        super().__init__(shape=shape, depth=depth, init=list(init),
                         attrs={**(attrs or {}), "no_rw_check": 1}, src_loc_at=src_loc_at + 1)

    def elaborate(self, platform):
        for r in self.read_ports:
            if r.domain == "comb" or r.transparent_for:
                raise ValueError("BlockRAM: read ports must be synchronous and not transparent "
                                 "(use Memory for a comb or transparent read)")
        if not ram_poison():
            return super().elaborate(platform)
        m = Module()
        m.submodules.inner = inner = Memory(shape=self.shape, depth=self.depth, init=self.init)
        for w in self.write_ports:
            iw = inner.write_port(domain=w.domain, granularity=w.signature.granularity)
            m.d.comb += [iw.addr.eq(w.addr), iw.data.eq(w.data), iw.en.eq(w.en)]
        for r in self.read_ports:
            ir = inner.read_port(domain=r.domain)
            m.d.comb += [ir.addr.eq(r.addr), ir.en.eq(r.en)]
            hit = Signal(name="collision")
            with m.If(r.en):
                m.d[r.domain] += hit.eq(0)
                for w in self.write_ports:
                    if w.domain == r.domain:
                        with m.If(w.en.any() & (w.addr == r.addr)):
                            m.d[r.domain] += hit.eq(1)
            raw = Value.cast(ir.data)
            m.d.comb += Value.cast(r.data).eq(raw ^ Mux(hit, ~C(0, len(raw)), 0))
        return m


class TwoWriteMemory(Elaboratable):
    """A memory with two write ports and one synchronous read port (not transparent: a read
    returns the word before that cycle's writes), built so that it maps to block RAM: two
    memories of one write port each (``bank0`` written by ``w[0]``, ``bank1`` by ``w[1]``) and
    a live-value table that says which bank to read. Yosys cannot map a memory with two write
    ports and a read port to ECP5 block RAM and builds it of flip-flops. Twice the memory bits.

    The table holds one bit per block of ``block`` words (aligned; a power of two): the port
    that last wrote a word of the block. So a read returns the newest word as long as every
    word read was written since the block's last writer took it (the slave's ray store and
    pending buffers: a block is one packet's lanes, written by one source while the packet
    holds it and read after). A table bit per word would be general; for the slave's 2 048
    words it is 2 048 flip-flops with a decoder per port, and as one wide signal Yosys runs out
    of memory expanding its write.

    Ports: ``w[i]`` (``addr``, ``data``, ``en``: the banks' write ports), ``r`` (``addr``,
    ``en``, ``data``: a view of ``shape``)."""

    def __init__(self, shape, depth: int, block: int):
        if block < 1 or block & (block - 1) or depth % block:
            raise ValueError(f"TwoWriteMemory: block={block} must be a power of two that "
                             f"divides depth={depth}")
        self.depth, self.block = depth, block
        self._banks = [Memory(shape=shape, depth=depth, init=[]) for _ in range(2)]
        self.w = [b.write_port() for b in self._banks]
        self._r = [b.read_port() for b in self._banks]
        self._sel = Signal()
        self.r = _ReadPort(self._r[0].addr.shape(), shape, self._r, self._sel)

    def elaborate(self, platform):
        m = Module()
        m.submodules.bank0, m.submodules.bank1 = self._banks
        sh = ceil_log2(self.block)
        live = Signal(self.depth // self.block)     # 1: bank1 holds the block's words
        for i, w in enumerate(self.w):       # port 1's update last: it wins
            with m.If(w.en):
                m.d.sync += live.bit_select(w.addr[sh:], 1).eq(i)
        for r in self._r:
            m.d.comb += [r.addr.eq(self.r.addr), r.en.eq(self.r.en)]
        with m.If(self.r.en):
            m.d.sync += self._sel.eq(live.bit_select(self.r.addr[sh:], 1))
        return m


class PacketMemory(Elaboratable):
    """:class:`TwoWriteMemory`'s ports on a memory of ``depth / block`` banks of ``block``
    words (aligned; a power of two), one memory of one write port each: a bank is written by
    the port whose address lies in it, so the two ports must never write one bank in the same
    cycle (the slave's ray store and pending buffers: a bank is one packet's lanes, written by
    one source while the packet holds it; port 1 wins if they do). The bits of one memory
    (:class:`TwoWriteMemory`: twice), as many small memories (LUT RAM on an FPGA, register
    files on a chip), a write-port multiplexer per bank and a ``depth / block``-way read
    multiplexer. Synchronous read, not transparent. Ports: ``w[i]`` (``addr``, ``data``,
    ``en``), ``r`` (``addr``, ``en``, ``data``: a view of ``shape``)."""

    def __init__(self, shape, depth: int, block: int):
        if block < 1 or block & (block - 1) or depth % block:
            raise ValueError(f"PacketMemory: block={block} must be a power of two that "
                             f"divides depth={depth}")
        self.depth, self.block, self.shape = depth, block, shape
        self._banks = [Memory(shape=shape, depth=block, init=[])
                       for _ in range(depth // block)]
        self._wp = [b.write_port() for b in self._banks]
        self._rp = [b.read_port() for b in self._banks]
        self.w = [SimpleNamespace(addr=Signal(range(depth), name=f"w{i}_addr"),
                                  data=Signal(shape, name=f"w{i}_data"),
                                  en=Signal(name=f"w{i}_en")) for i in range(2)]
        self._sel = Signal(range(len(self._banks)))
        datas = [p.data.as_value() if isinstance(p.data, data.View) else p.data
                 for p in self._rp]
        word = Array(datas)[self._sel] if len(datas) > 1 else datas[0]
        self.r = SimpleNamespace(addr=Signal(range(depth), name="r_addr"),
                                 en=Signal(init=1, name="r_en"),
                                 data=data.View(data.Layout.cast(shape), word)
                                 if isinstance(shape, data.Layout) else word)

    def elaborate(self, platform):
        m = Module()
        sh = ceil_log2(self.block)
        w0, w1 = self.w
        for b, (mem, wp, rp) in enumerate(zip(self._banks, self._wp, self._rp)):
            m.submodules[f"bank{b}"] = mem
            hit0 = w0.en & (w0.addr[sh:] == b) if len(self._banks) > 1 else w0.en
            hit1 = w1.en & (w1.addr[sh:] == b) if len(self._banks) > 1 else w1.en
            m.d.comb += [wp.en.eq(hit0 | hit1),
                         wp.addr.eq(Mux(hit1, w1.addr[:sh], w0.addr[:sh])),
                         wp.data.eq(Mux(hit1, Value.cast(w1.data), Value.cast(w0.data))),
                         rp.addr.eq(self.r.addr[:sh]), rp.en.eq(self.r.en)]
        if len(self._banks) > 1:
            with m.If(self.r.en):
                m.d.sync += self._sel.eq(self.r.addr[sh:])
        return m


class _ReadPort:
    """:class:`TwoWriteMemory`'s read port: ``addr``, ``en`` (default 1) and ``data``, the word
    of the bank the live-value table named when the address was read."""

    def __init__(self, addr_shape, shape, banks, sel):
        self.addr = Signal(addr_shape)
        self.en = Signal(init=1)
        self.data = data.View(data.Layout.cast(shape), Mux(sel, banks[1].data.as_value(),
                                                            banks[0].data.as_value())) \
            if isinstance(shape, data.Layout) else Mux(sel, banks[1].data, banks[0].data)


def from_binary32(fmt: FPFormat, x: Value) -> Value:
    """A format word from the binary32 pattern of a format value (as memory holds it): the sign,
    the exponent re-biased (0 and all-ones kept) and the top M fraction bits."""
    x = Value.cast(x)
    E, M = fmt.exp_bits, fmt.frac_bits
    if (E, M) == (8, 23):
        return x[:32]
    e32 = x[23:31]
    emax = (1 << E) - 1
    e = Mux(e32 == 0, 0, Mux(e32 == 0xFF, emax, (e32 - 127 + fmt.bias)[:E]))
    return Cat(x[23 - M:23], e[:E], x[31])
