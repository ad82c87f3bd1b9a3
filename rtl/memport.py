"""The memory read port every unit uses: a tagged request stream and a tagged response stream.

Seen from the requester (a cache, a bus input, a unit reading through a cache)::

    req  : Out(stream)  payload {addr: addr_width, tag: tag_width}
    resp : In(stream)   payload {data: data_width, tag: tag_width}

The server (memory, bus output, cache input) uses ``MemReadPort(...).flip()``.

Protocol (see ``docs/memory-interface.md`` for the timing diagram):

* Both streams follow ``amaranth.lib.stream`` rules: a transfer happens in a cycle where
  ``valid & ready``; once ``valid`` is high, it and the payload stay unchanged until the transfer.
* Every accepted request gets exactly one response carrying the request's ``tag``, after at least
  one cycle. Responses may come back in any order; the tag says which request a response answers.
  A requester that needs to tell responses apart must not reuse a tag before its response arrived.
* ``addr`` counts items of the port's data width as seen by the server: 64-bit words on a memory
  port (word address = byte address // 8), items (node, list entry, triangle) on a cache's unit port.
"""
from __future__ import annotations

from amaranth.hdl import Module
from amaranth.lib import data, stream, wiring
from amaranth.lib.wiring import In, Out

from .common import times_const

__all__ = ["MemRequest", "MemResponse", "MemReadPort", "WORD_BITS", "connect_tags", "ItemReader"]

WORD_BITS = 64  # one memory access: a 64-bit word


def MemRequest(addr_width: int, tag_width: int) -> data.StructLayout:
    """Layout of a read request: item address and the requester's tag."""
    return data.StructLayout({"addr": addr_width, "tag": tag_width})


def MemResponse(data_width: int, tag_width: int) -> data.StructLayout:
    """Layout of a read response: the item and the tag of the request it answers."""
    return data.StructLayout({"data": data_width, "tag": tag_width})


class MemReadPort(wiring.Signature):
    """Signature of a tagged read port, from the requester's side.

    Parameters
    ----------
    addr_width : int
        Address bits (items of ``data_width`` bits).
    data_width : int
        Bits per response: 64 for a memory word; a cache's unit port returns whole items.
    tag_width : int
        Bits of the tag a request carries back in its response (>= 1).
    """

    def __init__(self, *, addr_width: int, data_width: int, tag_width: int):
        for name, value in (("addr_width", addr_width), ("data_width", data_width),
                            ("tag_width", tag_width)):
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"MemReadPort: {name}={value!r} must be an int >= 1")
        self.addr_width = addr_width
        self.data_width = data_width
        self.tag_width = tag_width
        super().__init__({
            "req": Out(stream.Signature(MemRequest(addr_width, tag_width))),
            "resp": In(stream.Signature(MemResponse(data_width, tag_width))),
        })

    def __eq__(self, other):
        return (isinstance(other, MemReadPort) and self.addr_width == other.addr_width and
                self.data_width == other.data_width and self.tag_width == other.tag_width)

    def __repr__(self):
        return (f"MemReadPort(addr_width={self.addr_width}, data_width={self.data_width}, "
                f"tag_width={self.tag_width})")


def connect_tags(m: Module, requester, server) -> None:
    """Connect a requester's port to a server port whose tag is at least as wide (a bus input
    shared by requesters with different tags): the tag is zero-extended on the way in and
    truncated back on the way out. Address and data widths must match."""
    w = len(requester.req.payload.tag)
    if (len(server.req.payload.addr), len(server.resp.payload.data)) != (
            len(requester.req.payload.addr), len(requester.resp.payload.data)):
        raise ValueError("connect_tags: the ports' address or data widths differ")
    if len(server.req.payload.tag) < w:
        raise ValueError(f"connect_tags: the server's tag ({len(server.req.payload.tag)} bits) "
                         f"is narrower than the requester's ({w} bits)")
    m.d.comb += [
        server.req.valid.eq(requester.req.valid), requester.req.ready.eq(server.req.ready),
        server.req.payload.addr.eq(requester.req.payload.addr),
        server.req.payload.tag.eq(requester.req.payload.tag),
        requester.resp.valid.eq(server.resp.valid), server.resp.ready.eq(requester.resp.ready),
        requester.resp.payload.data.eq(server.resp.payload.data),
        requester.resp.payload.tag.eq(server.resp.payload.tag[:w]),
    ]


class ItemReader(wiring.Component):
    """Serves a port of wide items (a triangle) from a port of 64-bit memory words.

    Item ``i`` is the ``item_words`` words from ``base + i * item_words``; the response holds
    their low ``item_bits`` bits (first word in the low bits). Up to ``slots`` items are in
    flight; the words of one item are requested on consecutive cycles (one word request per
    cycle), responses may come back in any order (tag = ``{word, slot}``), and items are answered
    in request order as soon as their last word is in.

    Latency: a request accepted in cycle t sends its first word request in t+1; the item is
    offered one cycle after its last word arrived. Throughput: one item per ``item_words``
    cycles (the word port's rate). Counter: ``words`` (words received).

    Ports: ``port`` (``MemReadPort`` server: item index, ``item_bits`` data, ``tag_width``),
    ``mem`` (``MemReadPort`` requester of 64-bit words), ``base`` (word address of item 0).
    """

    def __init__(self, *, item_bits: int, item_words: int, addr_width: int, tag_width: int,
                 slots: int = 4):
        if not 0 < item_bits <= item_words * WORD_BITS:
            raise ValueError(f"ItemReader: item_bits={item_bits} must be in 1..{item_words * 64}")
        if slots < 1 or slots & (slots - 1):
            raise ValueError(f"ItemReader: slots={slots} must be a power of two")
        self.item_bits, self.item_words, self.slots = item_bits, item_words, slots
        self.slot_bits = max(1, (slots - 1).bit_length())
        self.word_bits = max(1, (item_words - 1).bit_length())
        super().__init__({
            "port": In(MemReadPort(addr_width=addr_width, data_width=item_bits,
                                   tag_width=tag_width)),
            "mem": Out(MemReadPort(addr_width=addr_width, data_width=WORD_BITS,
                                   tag_width=self.slot_bits + self.word_bits)),
            "base": In(addr_width),
            "words": Out(32),
        })

    def elaborate(self, platform):
        from amaranth.hdl import Array, Cat, Mux, Signal
        m = Module()
        n, k = self.slots, self.item_words
        req, resp, mreq, mresp = self.port.req, self.port.resp, self.mem.req, self.mem.resp
        tag_w = len(req.payload.tag)
        buf = Array(Signal(k * WORD_BITS, name=f"slot{i}_data") for i in range(n))
        got = Array(Signal(k, name=f"slot{i}_got") for i in range(n))
        tag = Array(Signal(tag_w, name=f"slot{i}_tag") for i in range(n))
        used = Signal(n)
        used_set, used_clr = Signal(n), Signal(n)
        m.d.sync += used.eq((used | used_set) & ~used_clr)

        # -- requests: the item's words, one a cycle, from the slot being issued --------------
        head, tail = Signal(self.slot_bits), Signal(self.slot_bits)    # answer / allocate
        issuing = Signal()
        word = Signal(range(k))
        addr = Signal(len(mreq.payload.addr))
        i_slot = Signal(self.slot_bits)
        m.d.comb += [mreq.valid.eq(issuing), mreq.payload.addr.eq(addr + word),
                     mreq.payload.tag.eq(Cat(word[:self.word_bits], i_slot))]
        last_word = mreq.valid & mreq.ready & (word == k - 1)
        with m.If(mreq.valid & mreq.ready):
            m.d.sync += word.eq(Mux(word == k - 1, 0, word + 1))
        with m.If(last_word):
            m.d.sync += issuing.eq(0)
        m.d.comb += req.ready.eq((~issuing | last_word) & ~used.bit_select(tail, 1))
        with m.If(req.valid & req.ready):
            m.d.comb += used_set.eq(1 << tail)
            m.d.sync += [issuing.eq(1), word.eq(0), i_slot.eq(tail), tail.eq(Mux(tail == n - 1, 0, tail + 1)),
                         addr.eq(self.base + times_const(req.payload.addr, k)),
                         tag[tail].eq(req.payload.tag), got[tail].eq(0)]

        # -- word responses fill their slot ---------------------------------------------------
        r_slot = mresp.payload.tag[self.word_bits:]
        r_word = mresp.payload.tag[:self.word_bits]
        m.d.comb += mresp.ready.eq(1)
        with m.If(mresp.valid):
            m.d.sync += [buf[r_slot].word_select(r_word, WORD_BITS).eq(mresp.payload.data),
                         got[r_slot].eq(got[r_slot] | (1 << r_word)),
                         self.words.eq(self.words + 1)]

        # -- answers, in request order, from a registered output -----------------------------
        full = Signal()
        m.d.comb += full.eq(used.bit_select(head, 1) & (got[head] == (1 << k) - 1))
        take = Signal()
        m.d.comb += take.eq(full & (~resp.valid | resp.ready))
        with m.If(take):
            m.d.comb += used_clr.eq(1 << head)
            m.d.sync += [resp.valid.eq(1), resp.payload.data.eq(buf[head][:self.item_bits]),
                         resp.payload.tag.eq(tag[head]),
                         head.eq(Mux(head == n - 1, 0, head + 1))]
        with m.Elif(resp.ready):
            m.d.sync += resp.valid.eq(0)
        return m
