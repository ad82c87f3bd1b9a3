"""List unit: expands a leaf's triangle list into triangle addresses (``model/list.py``).

A ``LeafRequest`` names list entries ``[first, first + count)``; entries are 32-bit triangle
indices, two per 64-bit word (low half first) at word ``list_base + (entry >> 1)``. The unit
reads every word the leaf touches once (``model.list.list_words``), keeps up to ``outstanding``
reads in flight (the tag is the slot of a small reorder buffer), and emits one ``TriRequest``
per entry in entry order, ``last`` on the leaf's final entry.
"""
from __future__ import annotations

from amaranth.hdl import Module, Mux, Signal
from amaranth.lib import data, stream, wiring
from amaranth.lib.fifo import SyncFIFO
from amaranth.lib.memory import Memory
from amaranth.lib.wiring import In, Out
from amaranth.utils import ceil_log2

from model.config import Config
from model.layout import list_word_layout

from .memport import WORD_BITS, MemReadPort
from .rtc_streams import COUNT_BITS, LeafRequest, TriRequest
from .common import COUNTER_BITS, SkidBuffer

__all__ = ["ListUnit"]


class ListUnit(wiring.Component):
    """Leaf list -> triangle addresses.

    Ports: ``leaf`` (In stream, ``LeafRequest``), ``tri`` (Out stream, ``TriRequest``), ``mem``
    (``MemReadPort`` requester: 64-bit words, ``addr_width`` bits, tag = reorder slot),
    ``list_base`` (In: word address of the list section, from the image header). Counters
    (Out, 32 bits): ``list_ops`` (entries emitted), ``words`` (words read), ``busy`` (cycles with
    a leaf in progress or a word not yet emitted).

    Timing: a leaf is accepted in the cycle its last word request is issued (or when idle);
    one word request per cycle, at most ``outstanding`` words between request and emission;
    one ``TriRequest`` per cycle. Latency leaf -> first entry: 1 cycle + memory latency
    (``cfg.fast_clock``: + 1, ``tri`` leaves from a :class:`~rtl.common.SkidBuffer`, so the
    metadata FIFO's read and the consumer's ready meet only registers).
    Throughput: one entry per cycle when memory keeps up (a word serves two entries).
    """

    def __init__(self, cfg: Config, *, addr_width: int = 32, outstanding: int | None = None):
        if outstanding is None:
            outstanding = cfg.list_outstanding
        if outstanding < 2 or outstanding & (outstanding - 1):
            self._MustUse__silence = True        # never elaborated: no warning
            raise ValueError(f"ListUnit outstanding={outstanding}: must be a power of two >= 2 "
                             "(it is the tag space of the memory port)")
        self.cfg = cfg
        self.outstanding = outstanding
        self.tag_width = max(1, ceil_log2(outstanding))
        super().__init__({
            "leaf": In(stream.Signature(LeafRequest(cfg))),
            "tri": Out(stream.Signature(TriRequest(cfg))),
            "mem": Out(MemReadPort(addr_width=addr_width, data_width=WORD_BITS,
                                   tag_width=self.tag_width)),
            "list_base": In(addr_width),
            "list_ops": Out(COUNTER_BITS),
            "words": Out(COUNTER_BITS),
            "busy": Out(COUNTER_BITS),
        })

    def elaborate(self, platform):
        m = Module()
        cfg, n = self.cfg, self.outstanding
        leaf, tri, req, resp = self.leaf, self.tri, self.mem.req, self.mem.resp
        if cfg.fast_clock:                 # entries leave through a stream register
            m.submodules.tri_out = out = SkidBuffer(TriRequest(cfg))
            wiring.connect(m, out.o, wiring.flipped(self.tri))
            tri = out.i

        # ---- issue: walk the current leaf's words, one request per cycle -----------------------
        active = Signal()
        thread = Signal(cfg.thread_bits)
        mask = Signal(cfg.packet_size)
        word = Signal(32)                  # current word index (entry >> 1)
        # where the walk is, from counts and flags rather than compares of 32-bit indices
        # (set when a leaf or a word is taken): the words after this one, this is the leaf's
        # last word, its first word, and whether the first / last entry is odd
        left = Signal(COUNT_BITS, name="words_left")
        at_last = Signal()
        at_first = Signal()
        first_odd, last_odd = Signal(), Signal()

        meta = data.StructLayout({"thread": cfg.thread_bits, "mask": cfg.packet_size,
                                  "lo": 1, "hi": 1, "last": 1})
        m.submodules.meta = fifo = SyncFIFO(width=meta.size, depth=n)
        wr_tag = Signal(self.tag_width)
        inflight = Signal(range(n + 1))    # words requested and not yet emitted

        issue = Signal()
        done_word = Signal()               # the head word's entries have all been emitted
        m.d.comb += [
            req.valid.eq(active & (inflight < n)),
            req.payload.addr.eq(self.list_base + word),
            req.payload.tag.eq(wr_tag),
            issue.eq(req.valid & req.ready),
        ]
        w_meta = data.View(meta, fifo.w_data)
        m.d.comb += [
            fifo.w_en.eq(issue),
            w_meta.thread.eq(thread), w_meta.mask.eq(mask),
            w_meta.lo.eq(~(at_first & first_odd)),             # entry 2w is in the leaf
            w_meta.hi.eq(~at_last | last_odd),                 # entry 2w+1 is in the leaf
            w_meta.last.eq(at_last),
        ]
        final = issue & at_last
        m.d.comb += leaf.ready.eq(~active | final)
        with m.If(issue):
            m.d.sync += [word.eq(word + 1), wr_tag.eq(wr_tag + 1),
                         left.eq(left - 1), at_last.eq(left == 1), at_first.eq(0)]
        with m.If(final):
            m.d.sync += active.eq(0)
        with m.If(leaf.valid & leaf.ready):
            p = leaf.payload
            odd = p.first[0]
            # entries [first, first + count) span (count - 1 + first's parity) / 2 words
            # after the first; one word if count is 1, or 2 from an even first
            m.d.sync += [
                active.eq(p.count != 0),
                thread.eq(p.thread), mask.eq(p.mask),
                word.eq(p.first >> 1),
                left.eq((p.count - 1 + odd) >> 1),
                at_last.eq((p.count == 1) | ((p.count == 2) & ~odd)),
                at_first.eq(1), first_odd.eq(odd), last_odd.eq(odd ^ p.count[0] ^ 1),
            ]
        m.d.sync += inflight.eq(inflight + issue - done_word)

        # ---- responses land in their slot (any order) -------------------------------------------
        # the slots' words: a memory written by the responses and read without a clock by
        # ``rd_tag`` (LUT-RAM on an FPGA, whose read is one LUT deep, not a mux tree over
        # ``outstanding`` x 64 flip-flops)
        m.submodules.slots = slots = Memory(shape=WORD_BITS, depth=n, init=[])
        slot_w, slot_r = slots.write_port(), slots.read_port(domain="comb")
        slot_full = Signal(n)
        m.d.comb += resp.ready.eq(1)
        rd_tag = Signal(self.tag_width)
        got = resp.valid & resp.ready
        set_bits = Mux(got, 1 << resp.payload.tag, 0)
        clr_bits = Mux(done_word, 1 << rd_tag, 0)
        m.d.sync += slot_full.eq((slot_full | set_bits) & ~clr_bits)
        m.d.comb += [slot_w.addr.eq(resp.payload.tag), slot_w.data.eq(resp.payload.data),
                     slot_w.en.eq(got), slot_r.addr.eq(rd_tag)]

        # ---- emit the head word's entries in order ---------------------------------------------
        h = data.View(meta, fifo.r_data)
        h_full, h_lo, h_hi, h_last = slot_full.bit_select(rd_tag, 1), h.lo, h.hi, h.last
        if cfg.fast_clock:
            h_full, h_lo, h_hi, h_last = self._head_registers(
                m, n, slot_full, got, wr_tag, issue, w_meta, rd_tag, done_word)
        upper = Signal()                   # the head word's low entry is already out
        take_hi = Signal()
        head = Signal(list_word_layout())     # two 32-bit entries, low first
        m.d.comb += [
            head.eq(slot_r.data),
            take_hi.eq(upper | ~h_lo),
            # fast_clock: a tag's word arrives after its metadata is queued and leaves the
            # slot when the metadata is read, so "the head word is in" implies "the queue is
            # not empty" and the valid comes from the register alone (not from the queue's
            # level)
            tri.valid.eq(h_full if cfg.fast_clock else fifo.r_rdy & h_full),
            tri.payload.thread.eq(h.thread),
            tri.payload.mask.eq(h.mask),
            tri.payload.tri.eq(Mux(take_hi, head[1], head[0])),
            tri.payload.last.eq(h_last & (take_hi | ~h_hi)),
        ]
        emit = tri.valid & tri.ready
        m.d.comb += [done_word.eq(emit & (take_hi | ~h_hi)), fifo.r_en.eq(done_word)]
        with m.If(emit):
            m.d.sync += upper.eq(~done_word)
        with m.If(done_word):
            m.d.sync += rd_tag.eq(rd_tag + 1)

        # ---- counters --------------------------------------------------------------------------
        with m.If(emit):
            m.d.sync += self.list_ops.eq(self.list_ops + 1)
        with m.If(got):
            m.d.sync += self.words.eq(self.words + 1)
        working = active | (inflight != 0)
        if cfg.fast_clock:                 # an entry still in the output register
            working = working | self.tri.valid
        with m.If(working):
            m.d.sync += self.busy.eq(self.busy + 1)
        return m

    def _head_registers(self, m, n, slot_full, got, wr_tag, issue, w_meta, rd_tag, done_word):
        """``fast_clock``: the head word's "arrived" bit and its ``lo``/``hi``/``last`` flags in
        registers, so the emit decision starts at registers, not at a mux of the slots by
        ``rd_tag`` and the metadata FIFO's read. The flags are also kept per tag (a tag's
        are written as its word is requested and stay until it is emitted: at most ``n``
        words in flight). Each cycle the registers take the values of the head after it:
        the next tag's if the head word is done, else the same tag's, with this cycle's
        response (``got``) to it. A tag's flags written this cycle are in its registers a
        cycle later, before its word can arrive (a response comes a cycle after its request
        at the earliest), so they need no such forwarding."""
        nt = (rd_tag + 1)[:len(rd_tag)]
        resp_tag = self.mem.resp.payload.tag
        flags = {k: Signal(n, name=f"slot_{k}") for k in ("lo", "hi", "last")}
        for i in range(n):
            with m.If(issue & (wr_tag == i)):
                m.d.sync += [f[i].eq(getattr(w_meta, k)) for k, f in flags.items()]
        h_full = Signal(name="head_full")
        regs = {k: Signal(name=f"head_{k}") for k in flags}

        def at(tag):        # a tag's flags after this cycle
            return ((slot_full.bit_select(tag, 1) | (got & (resp_tag == tag))),
                    {k: f.bit_select(tag, 1) for k, f in flags.items()})
        full0, f0 = at(rd_tag)
        full1, f1 = at(nt)
        m.d.sync += [h_full.eq(Mux(done_word, full1, full0)),
                     *(r.eq(Mux(done_word, f1[k], f0[k])) for k, r in regs.items())]
        return h_full, regs["lo"], regs["hi"], regs["last"]
