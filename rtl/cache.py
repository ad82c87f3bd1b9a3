"""Read-only, non-blocking, set-associative cache between an RTC unit and the memory bus.

Geometry and the hit/miss rule are those of ``model/cache.py`` (:class:`CacheGeometry`): the
unit asks for item indices; a miss allocates its line at once (round-robin way per set) and
fetches it word by word from memory, while later requests keep being looked up; a later request
to a line still being fetched is a hit (it waits for the data, costs no memory traffic).

Pipeline::

    port.req -> [tag read] -> S1: compare, allocate on miss -> response queue (in order)
                                    |  miss                       ^ head waits until its
                                    v                             | line's fill is done
                               MSHR + issue FIFO -> mem.req       |
                               mem.resp -> data array (a word at a time) -> [data read] -> port.resp

* Latency: a hit 3 cycles (6 with ``fast``; request accepted in cycle t, response valid in t+3) when nothing older
  waits; a miss ``4 + L + line_words - 1`` behind a memory of latency L delivering a word per cycle
  (``9 + L + line_words - 1`` with ``fast``). Responses come back **in
  request order** (a hit behind a miss waits for it), so tags are returned but never reordered.
* Throughput: one lookup and one response per cycle; ``outstanding`` line fetches in flight;
  ``queue`` requests inside the cache.
* A miss waits (stalling the lookup) while no MSHR is free, or while its victim way is still
  referenced by a queued request or a fill in flight: data is never overwritten under a reader.
* Contents are valid only from reset of the memory contents (``Memory`` init); there is no flush.

Ports: ``port`` (unit side, :class:`MemReadPort` of items), ``mem`` (memory side, 64-bit words,
tag = ``{word index, mshr}``), ``base`` (word address of item 0), counters ``hits``, ``misses``
(``fast``: a cycle after the lookup), ``stalls[i]`` (cycles lost, by the reasons of
:data:`STALLS`), and ``lookup_valid``/``lookup_hit`` (one pulse per
classified request, for testbenches).

Parts (components; ``fast`` takes the ``Fast...`` variant of each stage that has one):

* :class:`TagLookup`: the tag array and the lookup stage S1 (``s1``: the request, its tag row
  and the ways it hits);
* :class:`Decision`: hit, or a miss that allocates its line (``verdict``; ``go``: it leaves the
  lookup this cycle); writes the tag row back;
* :class:`MshrFile`: the lines being fetched (``fills``), the allocation, the free MSHR;
* :class:`Issue`: the misses' line fetches in order, a word request per cycle (``mem.req``);
* :class:`Fill`: each word from ``mem.resp`` into the data array, the line's completion;
* :class:`DataArray`: one memory per word of a line;
* :class:`ResponseQueue`: the requests in order; its ``head`` waits while its line is filled;
* :class:`Output`: the head's item read from the data array (``port.resp``).
"""
from __future__ import annotations

from types import SimpleNamespace

from amaranth.hdl import Array, Cat, Const, Module, Mux, Signal
from amaranth.lib import data, stream, wiring
from amaranth.lib.fifo import SyncFIFO
from amaranth.lib.memory import Memory
from amaranth.lib.wiring import In, Out
from amaranth.utils import ceil_log2

from model.cache import CacheGeometry

from .memport import WORD_BITS, MemReadPort, MemRequest, MemResponse
from .common import COUNTER_BITS, BlockRAM, lowest, registered, times_const

__all__ = ["Cache", "STALLS"]

STALLS = ("queue_full", "no_mshr", "victim_busy", "head_filling", "resp_blocked")
"""Why a cache does not take a request or hand out a response, the cycles of each
(``Cache.stalls[i]``): the lookup holds a request because the response queue is full
(``queue_full``), because it missed and no MSHR is free (``no_mshr``), or because its victim
slot is still referenced by a queued request or a fill (``victim_busy``); the response queue's
oldest request waits for its line's fill, so every request behind it waits too
(``head_filling``); a response is offered and the unit (or the bus's broadcast) does not take
it (``resp_blocked``). A cycle may count under the lookup's reason and a response's at once."""


class Cache(wiring.Component):
    """Non-blocking read-only cache; see the module docstring for latency and throughput.

    Parameters: ``geom`` (:class:`model.cache.CacheGeometry`), ``tag_width`` (unit tags),
    ``fast`` (``Config.fast_clock``: registers for a faster clock, hit latency 6 instead of 3
    (``hit_latency``): ``port.req.ready`` is a register (a skid register takes a request
    while the lookup stalls), the tag row is read a stage before the compare and goes
    straight into a register (the tag and data block RAMs' outputs feed only registers; a
    tag write the read missed is forwarded), the data word is registered before
    ``port.resp``, the line's memory address is formed as the request enters S1 and S2, the
    lowest free MSHR is kept in a register, S1's compare verdict is registered and a stage S2
    decides from registers (S2's tag write applied to the request it takes a cycle later),
    S2 has a skid entry so the stages before it move on a register, each queue entry's
    "line still being filled" and the head's data address are registers, and the memory's
    response is registered before the fill (``fill_delay``: a miss takes a cycle more), as
    is the miss's entry into the issue FIFO (``issue_delay``: another cycle). The hit/miss
    sequence is the same either way.
    """

    def __init__(self, geom: CacheGeometry, *, tag_width: int = 4, fast: bool = False):
        self.geom, self.fast = geom, fast
        self.hit_latency = 6 if fast else 3
        self.fill_delay = 1 if fast else 0      # cycles between mem.resp and the fill
        self.issue_delay = 1 if fast else 0     # cycles between the miss and its issue entry
        g = geom
        self.mshr_bits = max(1, ceil_log2(g.outstanding))
        self.word_bits = max(1, ceil_log2(g.line_words))
        super().__init__({
            "port": In(MemReadPort(addr_width=g.addr_width, data_width=g.item_bits,
                                   tag_width=tag_width)),
            "mem": Out(MemReadPort(addr_width=g.mem_addr_width, data_width=WORD_BITS,
                                   tag_width=self.mshr_bits + self.word_bits)),
            "base": In(g.mem_addr_width),
            "hits": Out(COUNTER_BITS),
            "misses": Out(COUNTER_BITS),
            "stalls": Out(COUNTER_BITS).array(len(STALLS)),
            "lookup_valid": Out(1),
            "lookup_hit": Out(1),
        })

    def elaborate(self, platform):
        m = Module()
        utag_bits = len(self.port.req.payload.tag)
        p = SimpleNamespace(**{name: cls(self.geom, utag_bits)
                               for name, cls in _PARTS[self.fast].items()})
        for name, part in vars(p).items():
            m.submodules[name] = part
        # the lookup: request -> S1 -> decision (-> tag row written back)
        wiring.connect(m, wiring.flipped(self.port.req), p.lookup.req)
        wiring.connect(m, p.lookup.s1, p.decision.s1)
        wiring.connect(m, p.decision.write, p.lookup.write)
        # the verdict: into the response queue (every request) and the MSHRs (a miss)
        wiring.connect(m, p.decision.verdict, p.mshrs.alloc, p.queue.push)
        wiring.connect(m, p.queue.refs, p.decision.queue)
        wiring.connect(m, p.mshrs.fills, p.decision.fills, p.queue.fills, p.fill.fills)
        m.d.comb += [p.decision.q_full.eq(p.queue.full), p.decision.any_free.eq(p.mshrs.any_free),
                     p.queue.kept.eq(p.mshrs.kept), p.fill.spare.eq(p.mshrs.spare),
                     p.mshrs.done.eq(p.fill.done)]
        # the miss path: MSHR -> issue -> memory -> fill -> data array
        wiring.connect(m, p.mshrs.issue, p.issue.mshrs)
        wiring.connect(m, p.issue.req, wiring.flipped(self.mem.req))
        wiring.connect(m, wiring.flipped(self.mem.resp), p.fill.resp)
        wiring.connect(m, p.fill.write, p.data.write)
        # the responses: queue head -> data read -> port.resp
        wiring.connect(m, p.queue.head, p.output.head)
        wiring.connect(m, p.output.read, p.data.read)
        wiring.connect(m, p.output.resp, wiring.flipped(self.port.resp))
        for part in vars(p).values():       # the parts that form memory addresses
            if "base" in part.signature.members:
                m.d.comb += part.base.eq(self.base)
        v = p.decision.verdict
        m.d.comb += [self.hits.eq(p.decision.hits), self.misses.eq(p.decision.misses),
                     self.lookup_valid.eq(v.go), self.lookup_hit.eq(v.hit)]
        resp_blocked = Signal(COUNTER_BITS)
        with m.If(self.port.resp.valid & ~self.port.resp.ready):
            m.d.sync += resp_blocked.eq(resp_blocked + 1)
        for i, c in enumerate([*p.decision.stalls, p.queue.head_waits, resp_blocked]):
            m.d.comb += self.stalls[i].eq(c)
        return m


# --- sizes, layouts and signatures the parts share --------------------------------------------

class _Dims:
    """The sizes the parts derive from the geometry, the unit's tag width and ``fast``."""

    def __init__(self, g: CacheGeometry, utag_bits: int, fast: bool):
        self.g, self.utag, self.fast = g, utag_bits, fast
        self.W, self.S, self.O, self.Q, self.LW = (g.ways, g.sets, g.outstanding, g.queue,
                                                   g.line_words)
        self.ob, self.sb, self.tb = g.offset_bits, g.set_bits, g.tag_bits
        self.wb = ceil_log2(self.W)
        self.entry = 1 + self.tb                    # a way of a tag row: {valid, tag}
        self.row = self.W * self.entry + self.wb    # a set's tag row: the ways, round-robin way
        self.slot = self.wb + self.sb               # a line's place in the data array
        self.mshr_bits = max(1, ceil_log2(self.O))
        self.word_bits = max(1, ceil_log2(self.LW))
        self.maw = g.mem_addr_width
        # an MSHR's line as the issue stage needs it: its index, or (fast) its first word address
        self.line_bits = self.maw if fast else g.addr_width - self.ob
        self.data_bits = g.line_items * g.item_bits

    def lookup(self) -> data.StructLayout:
        """S1's request: its fields, its set's tag row, the ways whose tag it matches in that
        row; ``fast``: the line's first memory word address (``mem``)."""
        return data.StructLayout({"off": self.ob, "set": self.sb, "tag": self.tb,
                                  "utag": self.utag, "row": self.row, "hits": self.W,
                                  **({"mem": self.maw} if self.fast else {})})

    def tag_write(self) -> wiring.Signature:
        return wiring.Signature({"en": Out(1), "set": Out(self.sb), "row": Out(self.row)})

    def verdict(self) -> wiring.Signature:
        """The deciding request (valid while ``go``): hit (``hit_way``) or a miss whose line
        goes to way ``victim``; ``way`` is the one it reads."""
        return wiring.Signature({
            "go": Out(1), "hit": Out(1), "hit_way": Out(self.wb), "way": Out(self.wb),
            "victim": Out(self.wb), "off": Out(self.ob), "set": Out(self.sb),
            "tag": Out(self.tb), "utag": Out(self.utag),
            **({"mem": Out(self.maw)} if self.fast else {})})

    def slot_refs(self, n: int) -> wiring.Signature:
        """``n`` entries that may refer to a data-array slot: ``valid``, ``set`` and ``way``."""
        return wiring.Signature({"valid": Out(n), "set": Out(self.sb).array(n),
                                 "way": Out(self.wb).array(n)})

    def issue(self) -> wiring.Signature:
        """The MSHR allocated this cycle (``en``, ``mshr``) and every MSHR's line."""
        return wiring.Signature({"en": Out(1), "mshr": Out(self.mshr_bits),
                                 "lines": Out(self.line_bits).array(self.O)})

    def fill_write(self) -> wiring.Signature:
        """A memory word of a line into the data array: its slot and word of the line."""
        return wiring.Signature({"en": Out(1), "slot": Out(self.slot),
                                 "word": Out(self.word_bits), "data": Out(WORD_BITS)})

    def data_read(self) -> wiring.Signature:
        return wiring.Signature({"addr": Out(self.slot), "en": Out(1),
                                 "data": In(self.data_bits)})

    def head(self) -> data.StructLayout:
        """The queue's head request: item offset, unit tag, its line's slot."""
        return data.StructLayout({"off": self.ob, "utag": self.utag, "slot": self.slot})


def _way_hits(d: _Dims, row, tag):
    """The ways of tag row ``row`` that hold ``tag`` (valid and equal), one bit per way."""
    e = d.entry
    return Cat(*[row[w * e] & (row[w * e + 1:(w + 1) * e] == tag) for w in range(d.W)])


def _holds(refs, set_, way_, valid=None):
    """One of the entries of ``refs`` (those ``valid`` marks, default ``refs.valid``) refers to
    the slot ``{set_, way_}``."""
    valid = refs.valid if valid is None else valid
    return Cat(*[valid[i] & (refs.set[i] == set_) & (refs.way[i] == way_)
                 for i in range(len(refs.set))]).any()


class _Part(wiring.Component):
    """A part of the cache, built from the cache's geometry and the unit's tag width (its
    ports: :meth:`_ports`); ``fast``: the variant for ``Config.fast_clock``."""

    fast = False

    def __init__(self, geom: CacheGeometry, tag_width: int):
        self._d = _Dims(geom, tag_width, self.fast)
        super().__init__(self._ports(self._d))

    def _ports(self, d: _Dims) -> dict:
        raise NotImplementedError


# --- tag array and lookup stage S1 ------------------------------------------------------------

class TagLookup(_Part):
    """The tag array (a row per set: W x {valid, tag} and the round-robin way) and S1.

    A request is accepted while its set's row is read (transparent for the tag write of that
    cycle) and is in S1 with its row in the next cycle; ``req.ready`` is "S1 empty or moving
    on" (``s1.ready``: the decision's ``go``). Latency 1, throughput 1.
    """

    def _ports(self, d: _Dims) -> dict:
        return {"req": In(stream.Signature(MemRequest(d.g.addr_width, d.utag))),
                "s1": Out(stream.Signature(d.lookup())), "write": In(d.tag_write())}

    def elaborate(self, platform):
        m = Module()
        d, req = self._d, self.req
        ob, sb = d.ob, d.sb
        trp = self._tag_array(m, Memory(shape=d.row, depth=d.S, init=[]), transparent=True)
        a = req.payload.addr
        s1_valid = Signal()
        s1_off, s1_set, s1_tag = Signal(ob), Signal(sb), Signal(d.tb)
        s1_utag = Signal(d.utag)
        m.d.comb += [req.ready.eq(~s1_valid | self.s1.ready), trp.addr.eq(a[ob:ob + sb]),
                     trp.en.eq(req.ready)]
        with m.If(req.ready):
            m.d.sync += [s1_valid.eq(req.valid), s1_off.eq(a[:ob]), s1_set.eq(a[ob:ob + sb]),
                         s1_tag.eq(a[ob + sb:]), s1_utag.eq(req.payload.tag)]
        self._send(m, s1_valid, off=s1_off, set=s1_set, tag=s1_tag, utag=s1_utag, row=trp.data,
                   hits=_way_hits(d, trp.data, s1_tag))
        return m

    def _tag_array(self, m: Module, tags: Memory, transparent: bool):
        """``tags`` written by ``write``; returns its read port."""
        m.submodules.tags = tags
        twp = tags.write_port()
        trp = tags.read_port(transparent_for=(twp,) if transparent else ())
        m.d.comb += [twp.addr.eq(self.write.set), twp.data.eq(self.write.row),
                     twp.en.eq(self.write.en)]
        return trp

    def _send(self, m: Module, valid, **fields):
        """S1's request onto ``s1``."""
        m.d.comb += self.s1.valid.eq(valid)
        m.d.comb += [getattr(self.s1.payload, k).eq(v) for k, v in fields.items()]


class FastTagLookup(TagLookup):
    """``fast`` :class:`TagLookup`: a skid register (``req.ready`` is a register: it takes a
    request while S0 holds), stage S0 that reads the tag row, and S1, whose row is the block
    RAM's output straight into a register, a tag write the read missed forwarded. S1 also
    forms the line's first memory word address (``mem``, from ``base``). Latency 2
    (3 behind a full skid register), throughput 1.
    """

    fast = True

    def _ports(self, d: _Dims) -> dict:
        return {**super()._ports(d), "base": In(d.maw)}

    def elaborate(self, platform):
        m = Module()
        d, w = self._d, self.write
        # not transparent: writes are forwarded below
        trp = self._tag_array(m, BlockRAM(shape=d.row, depth=d.S), transparent=False)
        # the tag write of the cycle before, registered (``wq``): S0's and S1's requests take
        # each write a cycle after it, so the deciding stage's ``go`` (the write enable)
        # reaches these registers, not their rows. A read in the cycle of a write misses it,
        # a read after it sees it. S2 writes only in a cycle it takes a request, which empties
        # the skid entry B: in the next cycle S1 and S0 both move on. So a write is always
        # taken as a request moves (S0 -> S1: into S1's forwarded row; S1 -> S2 or B: at
        # S1's output), never by a request that waits
        wq = SimpleNamespace(en=Signal(name="tw_q_en"), set=Signal(d.sb, name="tw_q_set"),
                             row=Signal(d.row, name="tw_q_row"))
        m.d.sync += [wq.en.eq(w.en), wq.set.eq(w.set), wq.row.eq(w.row)]
        s1_valid = Signal()
        s1_move = Signal()                  # S0 -> S1 this cycle
        m.d.comb += s1_move.eq(~s1_valid | (s1_valid & self.s1.ready))
        s0 = self._s0(m, trp, s1_move)
        self._s1(m, trp, wq, s0, s1_valid, s1_move)
        return m

    def _s0(self, m: Module, trp, s1_move) -> SimpleNamespace:
        """The skid register and S0, the request whose row is being read (the row arrives in
        the next cycle). Returns S0's valid, address and unit tag."""
        d, req = self._d, self.req
        ob, sb = d.ob, d.sb
        a = req.payload.addr
        # skid register: takes a request while S0 holds; ready is its emptiness
        k_valid = Signal()
        k_addr, k_utag = Signal.like(a, name="k_addr"), Signal.like(req.payload.tag, name="k_utag")
        m.d.comb += req.ready.eq(~k_valid)
        s0_valid = Signal()
        s0_addr, s0_utag = Signal.like(a, name="s0_addr"), Signal.like(req.payload.tag, name="s0_utag")
        s0_load = Signal()
        m.d.comb += s0_load.eq(~s0_valid | s1_move)
        in_valid = k_valid | req.valid
        in_addr = Mux(k_valid, k_addr, a)
        in_utag = Mux(k_valid, k_utag, req.payload.tag)
        m.d.comb += [trp.addr.eq(in_addr[ob:ob + sb]), trp.en.eq(s0_load)]
        with m.If(s0_load):
            m.d.sync += [s0_valid.eq(in_valid), s0_addr.eq(in_addr), s0_utag.eq(in_utag),
                         k_valid.eq(0)]
        with m.Elif(req.valid & req.ready):
            m.d.sync += k_valid.eq(1)
        with m.If(~k_valid):                # the fields follow the request while k is empty
            m.d.sync += [k_addr.eq(a), k_utag.eq(req.payload.tag)]
        return SimpleNamespace(valid=s0_valid, addr=s0_addr, utag=s0_utag)

    def _s1(self, m: Module, trp, wq, s0, s1_valid, s1_move):
        """S1: the row as read, or the tag write to the set taken as it came from S0, or the
        last cycle's write (still in ``wq``, chosen at its output); the ways it hits, one
        compare per row it may have (newest write first), then a choice."""
        d = self._d
        ob, sb = d.ob, d.sb
        s1_off, s1_set, s1_tag = Signal(ob), Signal(sb), Signal(d.tb)
        s1_utag = Signal(d.utag)
        s1_raw = Signal(d.row, name="s1_raw_row", reset_less=True)
        s1_fwd, s1_fwd_row = Signal(), Signal(d.row, name="s1_fwd_row")
        # the line's first memory word, formed before an allocation needs it (off the
        # lookup's path): its offset from ``base`` here, S0 -> S1, the sum S1 -> S2 (one
        # carry chain a stage)
        s1_mem = Signal(d.maw, name="s1_mem_off")
        s0_set = s0.addr[ob:ob + sb]
        w_now = wq.en & (wq.set == s0_set)   # the last cycle's write, to S0's set
        with m.If(s1_move):
            m.d.sync += s1_mem.eq(times_const(s0.addr[ob:], d.LW))
        with m.If(s1_move):
            m.d.sync += [s1_valid.eq(s0.valid), s1_off.eq(s0.addr[:ob]), s1_set.eq(s0_set),
                         s1_tag.eq(s0.addr[ob + sb:]), s1_utag.eq(s0.utag),
                         s1_raw.eq(trp.data), s1_fwd.eq(w_now), s1_fwd_row.eq(wq.row)]
        w_s1 = wq.en & (wq.set == s1_set)
        row = Signal(d.row, name="s1_row")
        m.d.comb += row.eq(Mux(w_s1, wq.row, Mux(s1_fwd, s1_fwd_row, s1_raw)))
        hits = Mux(w_s1, _way_hits(d, wq.row, s1_tag),
                   Mux(s1_fwd, _way_hits(d, s1_fwd_row, s1_tag), _way_hits(d, s1_raw, s1_tag)))
        self._send(m, s1_valid, off=s1_off, set=s1_set, tag=s1_tag, utag=s1_utag, row=row,
                   hits=hits, mem=self.base + s1_mem)


# --- the decision: hit, or allocate the miss --------------------------------------------------

class Decision(_Part):
    """The lookup's verdict on S1's request: a hit, or a miss that allocates its line (the
    round-robin way of its set, written into the tag row). ``verdict.go``: the request leaves
    the lookup this cycle, into the response queue: a hit at once, a miss once an MSHR is free
    and its victim slot is referenced neither by a queued request nor by a fill in flight.
    Counts the hits, the misses and the cycles a request waits (``stalls``: queue full, no
    free MSHR, victim busy). Combinational (the verdict in S1's cycle).
    """

    def _ports(self, d: _Dims) -> dict:
        return {"s1": In(stream.Signature(d.lookup())), "write": Out(d.tag_write()),
                "verdict": Out(d.verdict()), "queue": In(d.slot_refs(d.Q)), "q_full": In(1),
                "fills": In(d.slot_refs(d.O)), "any_free": In(1),
                "hits": Out(COUNTER_BITS), "misses": Out(COUNTER_BITS),
                "stalls": Out(COUNTER_BITS).array(3)}

    def elaborate(self, platform):
        m = Module()
        d, v = self._d, self.verdict
        W, e = d.W, d.entry
        go = Signal()
        new_row = Signal(d.row)     # the deciding request's tag row with its miss allocated
        r = self._stage(m, go, new_row)
        hit = Signal()
        hit_way = Signal(d.wb)
        m.d.comb += hit.eq(r.hits.any())
        for w in reversed(range(W)):
            with m.If(r.hits[w]):
                m.d.comb += hit_way.eq(w)
        victim = r.row[W * e:]      # the round-robin way
        way = Signal(d.wb)
        m.d.comb += way.eq(Mux(hit, hit_way, victim))
        busy = self._busy(m, r, go, way, victim)
        m.d.comb += go.eq(r.valid & ~self.q_full & (hit | (self.any_free & ~busy)))
        m.d.comb += [v.go.eq(go), v.hit.eq(hit), v.hit_way.eq(hit_way), v.way.eq(way),
                     v.victim.eq(victim), v.off.eq(r.off), v.set.eq(r.set), v.tag.eq(r.tag),
                     v.utag.eq(r.utag)]
        # miss: allocate the line in the tag row
        m.d.comb += new_row.eq(r.row)
        for w in range(W):
            with m.If(victim == w):
                m.d.comb += new_row[w * e:(w + 1) * e].eq(Cat(Const(1, 1), r.tag))
        if d.wb:
            m.d.comb += new_row[W * e:].eq(victim + 1)
        m.d.comb += [self.write.set.eq(r.set), self.write.row.eq(new_row),
                     self.write.en.eq(go & ~hit)]
        # the cycles the request waits, by reason (STALLS[:3])
        miss_waits = r.valid & ~self.q_full & ~hit
        counts = self._count(m, hit=go & hit, miss=go & ~hit, queue_full=r.valid & self.q_full,
                             no_mshr=miss_waits & ~self.any_free,
                             victim_busy=miss_waits & self.any_free & busy)
        for cond, ctr in zip(counts.values(), [self.hits, self.misses, *self.stalls]):
            with m.If(cond):
                m.d.sync += ctr.eq(ctr + 1)
        return m

    def _stage(self, m: Module, go, new_row) -> SimpleNamespace:
        """The deciding request: S1's (``s1.ready`` is ``go``)."""
        s1 = self.s1
        m.d.comb += s1.ready.eq(go)
        return SimpleNamespace(valid=s1.valid, **{k: getattr(s1.payload, k) for k in
                                                  ("off", "set", "tag", "utag", "row", "hits")})

    def _slot_busy(self, set_, way_):
        """The slot is referenced by a queued request or by a fill in flight."""
        return _holds(self.queue, set_, way_) | _holds(self.fills, set_, way_)

    def _busy(self, m: Module, r, go, way, victim):
        """The victim slot is busy (:meth:`_slot_busy`)."""
        return self._slot_busy(r.set, victim)

    def _count(self, m: Module, **conds) -> dict:
        """The counters' increments."""
        return conds


class FastDecision(Decision):
    """``fast`` :class:`Decision`: in a stage S2 of its own, from registers (S1's compare
    verdict registered), with a skid entry B, so the stall stops at S2 and B and the stages
    before them move on registers; the victim's "busy" is formed a cycle ahead; the counters
    count a cycle later. Latency 1 (2 behind B), throughput 1.
    """

    fast = True

    def _stage(self, m: Module, go, new_row) -> SimpleNamespace:
        """S2: S1's compare verdict in a register, so S2 decides (and the stages before it
        advance) from registers only. S2 has a skid entry B: S1 hands its request on while B
        is empty (a register), to S2 if S2 takes one this cycle, else to B; S2 takes B's
        request first. So the stall (``go``) stops at S2 and B, and the stages before them
        move on registers. S2's tag write of the cycle it takes a request (from S1 or B) is
        applied a cycle later: S2 keeps the request's row and hits as they were and as that
        write leaves them (both formed without ``go``) and a bit saying whether the write was
        to its set. S0 and S1 take the write a cycle later, from a register (a write meets B
        only as B moves on: S2 writes only when it goes)."""
        d, s1, w = self._d, self.s1, self.write
        p = s1.payload
        W = d.W
        s2_valid = Signal()
        s2_off, s2_set, s2_tag = Signal(d.ob), Signal(d.sb), Signal(d.tb)
        s2_utag = Signal(d.utag)
        s2_row_n, s2_row_w = Signal(d.row, name="s2_row"), Signal(d.row, name="s2_row_w")
        s2_hits_n, s2_hits_w = Signal(W, name="s2_hits"), Signal(W, name="s2_hits_w")
        s2_wsel = Signal(name="s2_written")
        s2_mem = Signal(d.maw, name="s2_mem_addr")
        b_valid = Signal(name="s2b_valid")
        b_off, b_set, b_tag = Signal(d.ob, name="s2b_off"), Signal(d.sb, name="s2b_set"), \
            Signal(d.tb, name="s2b_tag")
        b_utag = Signal(d.utag, name="s2b_utag")
        b_row = Signal(d.row, name="s2b_row")
        b_hits = Signal(W, name="s2b_hits")
        b_mem = Signal(d.maw, name="s2b_mem_addr")
        s2_move = Signal()
        m.d.comb += [s2_move.eq(~s2_valid | go), s1.ready.eq(~b_valid)]
        with m.If(s2_move):
            # (a compare per candidate request, B's and S1's, then the choice)
            m.d.sync += [s2_row_w.eq(new_row),
                         s2_hits_w.eq(Mux(b_valid, _way_hits(d, new_row, b_tag),
                                          _way_hits(d, new_row, p.tag))),
                         s2_wsel.eq(w.en & Mux(b_valid, w.set == b_set, w.set == p.set))]
            with m.If(b_valid):
                m.d.sync += [s2_valid.eq(1), s2_off.eq(b_off), s2_set.eq(b_set),
                             s2_tag.eq(b_tag), s2_utag.eq(b_utag), s2_row_n.eq(b_row),
                             s2_hits_n.eq(b_hits), s2_mem.eq(b_mem), b_valid.eq(0)]
            with m.Else():
                m.d.sync += [s2_valid.eq(s1.valid), s2_off.eq(p.off), s2_set.eq(p.set),
                             s2_tag.eq(p.tag), s2_utag.eq(p.utag), s2_row_n.eq(p.row),
                             s2_hits_n.eq(p.hits), s2_mem.eq(p.mem)]
        with m.Elif(s1.valid & s1.ready):   # S2 holds: S1's request into B (no tag write)
            m.d.sync += b_valid.eq(1)
        # B's fields follow S1 while B is empty (they count only once b_valid is set, in
        # the cycle S1 hands over), so their enable is a register, not ``go``
        with m.If(~b_valid):
            m.d.sync += [b_off.eq(p.off), b_set.eq(p.set), b_tag.eq(p.tag), b_utag.eq(p.utag),
                         b_row.eq(p.row), b_hits.eq(p.hits), b_mem.eq(p.mem)]
        d_row, hit_vec = Signal(d.row, name="s2_row_now"), Signal(W, name="s2_hits_now")
        m.d.comb += [d_row.eq(Mux(s2_wsel, s2_row_w, s2_row_n)),
                     hit_vec.eq(Mux(s2_wsel, s2_hits_w, s2_hits_n)),
                     self.verdict.mem.eq(s2_mem)]
        return SimpleNamespace(valid=s2_valid, off=s2_off, set=s2_set, tag=s2_tag, utag=s2_utag,
                               row=d_row, hits=hit_vec, move=s2_move, b_valid=b_valid,
                               b_set=b_set)

    def _busy(self, m: Module, r, go, way, victim):
        """The victim slot's "busy" from registers: per way, computed a cycle ahead for the
        request S2 holds next (B's or S1's if S2 takes one, else its own), plus whether the
        queue entry written in that cycle is in that set; a slot freed meanwhile costs one
        cycle. (One compare per candidate set, B's, S1's and S2's own, each from registers;
        the choice between a new request and S2's own after the registers, by whether S2
        moved: the lookup's verdict ends at one flip-flop, not at the busy bits.)"""
        d, W, s1_set = self._d, self._d.W, self.s1.payload.set

        def busy_ways(set_):
            return Cat(*(self._slot_busy(set_, w) for w in range(W)))
        b_mv, b_hd = Signal(W, name="busy_s2_move"), Signal(W, name="busy_s2_hold")
        moved, lw_go, lw_same, lw_way = (Signal(name="s2_moved"), Signal(name="lw_go"),
                                         Signal(name="lw_same"), Signal(d.wb, name="lw_way"))
        m.d.sync += [b_mv.eq(Mux(r.b_valid, busy_ways(r.b_set), busy_ways(s1_set))),
                     b_hd.eq(busy_ways(r.set)), moved.eq(r.move),
                     # the entry written with `go` is in the next request's set (a `go`
                     # moves S2)
                     lw_go.eq(go), lw_same.eq(Mux(r.b_valid, r.set == r.b_set, r.set == s1_set)),
                     lw_way.eq(way)]
        b = Signal(W, name="busy_s2")
        m.d.comb += b.eq(Mux(moved, b_mv, b_hd))
        last_w = Mux(lw_go & lw_same, Const(1, W) << lw_way, 0)[:W]
        return (b | last_w).bit_select(victim, 1) if W > 1 else b | last_w

    def _count(self, m: Module, **conds) -> dict:
        """The counters count a cycle later, from registers."""
        return registered(m, "count", **conds)


# --- MSHRs ------------------------------------------------------------------------------------

class MshrFile(_Part):
    """The miss status holding registers: per MSHR the slot its line fills (``fills``) and the
    line. The lowest free MSHR is written with the deciding request's fields every cycle
    (``spare``); a miss (``alloc.go & ~alloc.hit``) makes it valid and hands it to the issue
    stage (``issue``); ``done`` (the fill's last word) frees it. ``kept``: the valid bits after
    this cycle's ``done``. ``any_free``: an MSHR is free for a miss this cycle.
    """

    def _ports(self, d: _Dims) -> dict:
        return {"alloc": In(d.verdict()), "done": In(d.O), "fills": Out(d.slot_refs(d.O)),
                "kept": Out(d.O), "spare": Out(d.O), "any_free": Out(1), "issue": Out(d.issue())}

    def elaborate(self, platform):
        m = Module()
        d, a, O = self._d, self.alloc, self._d.O
        mshr_valid = Signal(O)
        mshr_set = [Signal(d.sb, name=f"mshr{i}_set") for i in range(O)]
        mshr_way = [Signal(d.wb, name=f"mshr{i}_way") for i in range(O)]
        mshr_line = [Signal(d.line_bits, name=f"mshr{i}_{self._line_name}") for i in range(O)]
        kept = Signal(O, name="mshr_kept")
        m.d.comb += kept.eq(mshr_valid & ~self.done)
        alloc = a.go & ~a.hit
        any_free, free = self._free(m, mshr_valid, kept, alloc)  # free: the lowest free MSHR
        spare = [(free == i) & ~mshr_valid[i] for i in range(O)]  # written while free
        for i in range(O):
            with m.If(spare[i]):
                m.d.sync += [mshr_set[i].eq(a.set), mshr_way[i].eq(a.victim),
                             mshr_line[i].eq(self._line(a))]
        # valid bits: set on allocation, cleared by the last word of the fill
        set_mask = Signal(O)
        for i in range(O):
            m.d.comb += set_mask[i].eq(alloc & (free == i))
        m.d.sync += mshr_valid.eq((mshr_valid | set_mask) & ~self.done)
        f, s = self.fills, self.issue
        m.d.comb += [f.valid.eq(mshr_valid), self.kept.eq(kept), self.spare.eq(Cat(*spare)),
                     self.any_free.eq(any_free), s.en.eq(alloc), s.mshr.eq(free)]
        for i in range(O):
            m.d.comb += [f.set[i].eq(mshr_set[i]), f.way[i].eq(mshr_way[i]),
                         s.lines[i].eq(mshr_line[i])]
        return m

    _line_name = "line"

    def _line(self, a):
        """An MSHR's line: its index."""
        return Cat(a.set, a.tag)

    def _free(self, m: Module, valid, kept, alloc):
        """(an MSHR is free, the lowest free MSHR), from the valid bits."""
        any_free, free = Signal(), Signal(range(self._d.O))
        m.d.comb += any_free.eq(~valid.all())
        for i in reversed(range(self._d.O)):
            with m.If(~valid[i]):
                m.d.comb += free.eq(i)
        return any_free, free


class FastMshrFile(MshrFile):
    """``fast`` :class:`MshrFile`: an MSHR keeps its line's first memory word address (formed
    in S0 -> S1 -> S2), and the lowest free MSHR is kept in a register."""

    fast = True

    _line_name = "addr"

    def _line(self, a):
        """An MSHR's line: its first memory word address."""
        return a.mem

    def _free(self, m: Module, valid, kept, alloc):
        """``free``/``any_free`` of the next cycle in registers: from the valid bits after
        this cycle's fill completions, without and with this cycle's allocation (which takes
        ``free``), the lookup's verdict only selecting between the two."""
        O = self._d.O
        any_free, free = Signal(init=1), Signal(range(O))   # all free at reset
        k_any, k_idx = lowest(m, ~kept, "mshr_free_keep")
        a_any, a_idx = lowest(m, ~(kept | (Const(1, O) << free)[:O]), "mshr_free_alloc")
        m.d.sync += [any_free.eq(Mux(alloc, a_any, k_any)), free.eq(Mux(alloc, a_idx, k_idx))]
        return any_free, free


# --- issue: the line's words, one request per cycle -------------------------------------------

class Issue(_Part):
    """The allocated MSHRs in a FIFO; the head's line is requested word by word, a word per
    cycle (tag ``{word, mshr}``). Latency 1 (a miss's first word request is valid in the
    cycle after its allocation), throughput one word per cycle."""

    def _ports(self, d: _Dims) -> dict:
        return {"mshrs": In(d.issue()), "base": In(d.maw),
                "req": Out(stream.Signature(MemRequest(d.maw, d.mshr_bits + d.word_bits)))}

    def elaborate(self, platform):
        m = Module()
        d, LW, mreq = self._d, self._d.LW, self.req
        m.submodules.fifo = fifo = SyncFIFO(width=d.mshr_bits, depth=d.O)
        w_en, w_data = self._entry(m)
        m.d.comb += [fifo.w_data.eq(w_data), fifo.w_en.eq(w_en)]
        word = Signal(range(LW))
        head_m = fifo.r_data
        line = Array(self.mshrs.lines)[head_m]
        m.d.comb += [mreq.valid.eq(fifo.r_rdy), mreq.payload.addr.eq(self._addr(line, word)),
                     mreq.payload.tag.eq(Cat(head_m, word)[:len(mreq.payload.tag)])]
        m.d.comb += fifo.r_en.eq(mreq.valid & mreq.ready & (word == LW - 1))
        with m.If(mreq.valid & mreq.ready):
            m.d.sync += word.eq(Mux(word == LW - 1, 0, word + 1))
        return m

    def _entry(self, m: Module):
        """The FIFO's write: the MSHR allocated this cycle."""
        return self.mshrs.en, self.mshrs.mshr

    def _addr(self, line, word):
        """The word's memory address from the line's index."""
        return self.base + times_const(line, self._d.LW) + word


class FastIssue(Issue):
    """``fast`` :class:`Issue`: the miss's MSHR enters the FIFO a cycle later, from
    registers (``issue_delay``), and the word address adds the word to the MSHR's line
    address. Latency 2, throughput one word per cycle."""

    fast = True

    def _ports(self, d: _Dims) -> dict:
        return {k: v for k, v in super()._ports(d).items() if k != "base"}

    def _entry(self, m: Module):
        return registered(m, "issue_w", en_q=self.mshrs.en, data_q=self.mshrs.mshr).values()

    def _addr(self, line, word):
        return line + word


# --- fill: each word goes into the data array as it arrives; the last one completes the line
# (only then may a request read it: the queue's wait bits) -----------------------------------

class Fill(_Part):
    """The memory's responses (always accepted, any order): each word into the data array at
    its MSHR's slot (``write``); per MSHR the words received; ``done``: the MSHRs whose line
    this cycle's word completes. Latency 0 (the word is written in its cycle)."""

    def _ports(self, d: _Dims) -> dict:
        return {"resp": In(stream.Signature(MemResponse(WORD_BITS, d.mshr_bits + d.word_bits))),
                "fills": In(d.slot_refs(d.O)), "spare": In(d.O), "write": Out(d.fill_write()),
                "done": Out(d.O)}

    def elaborate(self, platform):
        m = Module()
        d, O, LW = self._d, self._d.O, self._d.LW
        m.d.comb += self.resp.ready.eq(1)
        mresp = self._response(m)
        f_m = mresp.payload.tag[:d.mshr_bits]
        f_w = mresp.payload.tag[d.mshr_bits:d.mshr_bits + d.word_bits] if LW > 1 \
            else Const(0, 1)
        fire = mresp.valid
        cnt = [Signal(range(LW), name=f"mshr{i}_cnt") for i in range(O)]
        for i in range(O):
            with m.If(self.spare[i]):
                m.d.sync += cnt[i].eq(0)
        for i in range(O):
            with m.If(fire & (f_m == i)):
                m.d.sync += cnt[i].eq(cnt[i] + 1)
        w = self.write
        m.d.comb += [w.en.eq(fire), w.slot.eq(self._slot(m, f_m)), w.word.eq(f_w),
                     w.data.eq(mresp.payload.data)]
        m.d.comb += self.done.eq(self._done(m, fire, f_m, cnt))
        return m

    def _response(self, m: Module):
        """The response the fill takes."""
        return self.resp

    def _slot(self, m: Module, f_m):
        """The word's place: its MSHR's slot."""
        f_slot = Signal(self._d.slot, name="fill_slot")
        m.d.comb += f_slot.eq(Cat(Array(self.fills.way)[f_m], Array(self.fills.set)[f_m]))
        return f_slot

    def _done(self, m: Module, fire, f_m, cnt):
        """The MSHRs whose line this cycle's word completes."""
        clr_mask = Signal(self._d.O)
        last = fire & (Array(cnt)[f_m] == self._d.LW - 1)
        for i in range(self._d.O):
            m.d.comb += clr_mask[i].eq(last & (f_m == i))
        return clr_mask


class FastFill(Fill):
    """``fast`` :class:`Fill`: the memory's response in a register first (it comes from the
    bus; ``fill_delay``), its slot picked as it is registered, and the completion decided as
    it is registered. Latency 1."""

    fast = True

    def _response(self, m: Module):
        """(loaded only with a response: the caches' copies of the bus's shared response stay
        apart, each beside its own fill logic)"""
        mresp = SimpleNamespace(valid=Signal(name="fill_valid"),
                                payload=Signal.like(self.resp.payload, name="fill_resp"))
        m.d.sync += mresp.valid.eq(self.resp.valid)
        with m.If(self.resp.valid):
            m.d.sync += mresp.payload.eq(self.resp.payload)
        return mresp

    def _slot(self, m: Module, f_m):
        """Picked as the response is registered (an MSHR with words in flight keeps its
        fields)."""
        f_slot = Signal(self._d.slot, name="fill_slot")
        r_m = self.resp.payload.tag[:self._d.mshr_bits]
        with m.If(self.resp.valid):
            m.d.sync += f_slot.eq(Cat(Array(self.fills.way)[r_m], Array(self.fills.set)[r_m]))
        return f_slot

    def _done(self, m: Module, fire, f_m, cnt):
        """Per MSHR "the next word completes the line", kept in a register; and which MSHR the
        registered response completes, decided as it is registered (from the raw response's
        tag and the "next word" bits after this cycle), so the fill's completion reaches the
        MSHR valid bits, ``free`` and the queue's waits from a register."""
        O, LW = self._d.O, self._d.LW
        r_m = self.resp.payload.tag[:self._d.mshr_bits]
        nearly = Signal(O, name="mshr_last")
        nearly_next = Signal(O)
        for i in range(O):
            m.d.comb += nearly_next[i].eq(
                Mux(self.spare[i], LW == 1,
                    Mux(fire & (f_m == i), cnt[i] + 1 == LW - 1, nearly[i])))
        m.d.sync += nearly.eq(nearly_next)
        done = Signal(O, name="fill_done")
        for i in range(O):
            m.d.sync += done[i].eq(self.resp.valid & (r_m == i) & nearly_next[i])
        return done


# --- the data array ---------------------------------------------------------------------------

class DataArray(_Part):
    """One memory per word of a line, holding the bits of that word the cache keeps (a line
    is the concatenation of the words' kept bits, item after item), so a fill needs no line
    buffer per MSHR. ``write``: a word (its slot and index in the line); ``read``: a line
    (synchronous: the data in the cycle after ``en``)."""

    def _ports(self, d: _Dims) -> dict:
        return {"write": In(d.fill_write()), "read": In(d.data_read())}

    def elaborate(self, platform):
        m = Module()
        d, w, r = self._d, self.write, self.read
        out = []
        for j, bits in enumerate(d.g.word_kept_bits):
            if bits:
                mem = BlockRAM(shape=sum(hi - lo for lo, hi in bits), depth=d.S * d.W)
                m.submodules[f"data{j}"] = mem
                wp, rp = mem.write_port(), mem.read_port()
                m.d.comb += [wp.addr.eq(w.slot),
                             wp.data.eq(Cat(*(w.data[lo:hi] for lo, hi in bits))),
                             wp.en.eq(w.en & (w.word == j)),
                             rp.addr.eq(r.addr), rp.en.eq(r.en)]
                out.append(rp.data)
        m.d.comb += r.data.eq(Cat(*out))
        return m


# --- response queue (in request order) --------------------------------------------------------

class ResponseQueue(_Part):
    """The requests in order: every verdict with ``go`` takes the entry at the tail (the
    deciding request's fields are written into it every cycle, only the used bit waits for
    ``go``); ``head``: the oldest request once its line is present (no fill in flight to its
    slot), popped by the transfer. ``refs``: the used entries' slots; ``full``;
    ``head_waits``: cycles the oldest request waited for its line."""

    def _ports(self, d: _Dims) -> dict:
        return {"push": In(d.verdict()), "fills": In(d.slot_refs(d.O)), "kept": In(d.O),
                "refs": Out(d.slot_refs(d.Q)), "full": Out(1),
                "head": Out(stream.Signature(d.head())), "head_waits": Out(COUNTER_BITS)}

    def elaborate(self, platform):
        m = Module()
        d, Q, v, head = self._d, self._d.Q, self.push, self.head
        q = SimpleNamespace(
            used=Signal(Q, name="q_used"),
            set=[Signal(d.sb, name=f"q{i}_set") for i in range(Q)],
            way=[Signal(d.wb, name=f"q{i}_way") for i in range(Q)],
            off=[Signal(d.ob, name=f"q{i}_off") for i in range(Q)],
            utag=[Signal(d.utag, name=f"q{i}_utag") for i in range(Q)],
            head=Signal(range(Q), name="q_head"), tail=Signal(range(Q), name="q_tail"))
        q_set_bit, q_clr_bit = Signal(Q), Signal(Q)     # taken at the tail, popped at the head
        q_next = (q.used | q_set_bit) & ~q_clr_bit
        m.d.sync += q.used.eq(q_next)
        m.d.comb += self.full.eq(self._full(m, q.used, q_next))
        # the entry at the tail is not in use, so the deciding request's fields are written
        # into it every cycle, whatever the lookup decides (the verdict drives a few bits, not
        # the entries' enables)
        q.wr = [(q.tail == i) & ~q.used[i] for i in range(Q)]
        for i in range(Q):
            with m.If(q.wr[i]):
                m.d.sync += [q.set[i].eq(v.set), q.way[i].eq(v.way), q.off[i].eq(v.off),
                             q.utag[i].eq(v.utag)]
        with m.If(v.go):
            m.d.comb += q_set_bit.eq(1 << q.tail)
            m.d.sync += q.tail.eq(Mux(q.tail == Q - 1, 0, q.tail + 1))
        # the head: popped by the transfer
        pop = Signal()
        m.d.comb += pop.eq(head.valid & head.ready)
        h_next = Mux(q.head == Q - 1, 0, q.head + 1)[:len(q.head)]
        m.d.comb += q_clr_bit.eq(Mux(pop, 1 << q.head, 0))
        with m.If(pop):
            m.d.sync += q.head.eq(h_next)
        h_pending = self._pending(m, q)
        with m.If(q.used.bit_select(q.head, 1) & h_pending):
            m.d.sync += self.head_waits.eq(self.head_waits + 1)
        m.d.comb += [head.valid.eq(q.used.bit_select(q.head, 1) & ~h_pending),
                     head.payload.off.eq(Array(q.off)[q.head]),
                     head.payload.utag.eq(Array(q.utag)[q.head]),
                     head.payload.slot.eq(self._head_slot(m, q, pop, h_next))]
        m.d.comb += self.refs.valid.eq(q.used)
        for i in range(Q):
            m.d.comb += [self.refs.set[i].eq(q.set[i]), self.refs.way[i].eq(q.way[i])]
        return m

    def _full(self, m: Module, used, used_next):
        return used.all()

    def _pending(self, m: Module, q):
        """The head's line is still being filled."""
        return _holds(self.fills, Array(q.set)[q.head], Array(q.way)[q.head])

    def _head_slot(self, m: Module, q, pop, h_next):
        """The head's slot (the data array is read as the head is popped)."""
        return Cat(Array(q.way)[q.head], Array(q.set)[q.head])


class FastResponseQueue(ResponseQueue):
    """``fast`` :class:`ResponseQueue`: ``full``, each entry's "line still being filled" and
    the head's slot are registers, formed a cycle ahead."""

    fast = True

    def _full(self, m: Module, used, used_next):
        """Kept in a register, from the used bits after this cycle."""
        full = Signal(name="q_full")
        m.d.sync += full.eq(used_next.all())
        return full

    def _pending(self, m: Module, q):
        """Per queue entry, a cycle ahead into a register: the same function of the queue
        entries and the MSHRs after this cycle. A valid MSHR keeps its fields; one allocated
        this cycle matches no used entry (its slot was not busy) but the entry written with
        it; so a used entry waits on the MSHRs still valid after this cycle's fills, and the
        entry written now waits if it is a miss, or a hit on a line still being filled
        (neither needs ``go``: the entry counts only if taken)."""
        v, kept = self.push, self.kept
        wait = Signal(self._d.Q, name="q_wait")
        new_wait = ~v.hit | _holds(self.fills, v.set, v.hit_way, kept)
        for i in range(self._d.Q):
            m.d.sync += wait[i].eq(Mux(q.wr[i], new_wait,
                                       _holds(self.fills, q.set[i], q.way[i], kept)))
        return wait.bit_select(q.head, 1)

    def _head_slot(self, m: Module, q, pop, h_next):
        """From registers, formed a cycle ahead: the slots of the entry at the head and of the
        one after it (the tail entry's write of this cycle bypassed) and whether the head
        moves on. (The data array is read whenever the output stage can take a line, popped or
        not, so the read's enable needs no verdict.)"""
        slot = self._d.slot
        written = Cat(*q.wr)
        q_set_a, q_way_a = Array(q.set), Array(q.way)

        def head_addr(k):
            return Mux(written.bit_select(k, 1), Cat(self.push.way, self.push.set),
                       Cat(q_way_a[k], q_set_a[k]))
        # both candidates registered, the pop registered to choose between them
        stay, moved, popped = Signal(slot, name="h_addr_stay"), \
            Signal(slot, name="h_addr_moved"), Signal(name="h_popped")
        m.d.sync += [stay.eq(head_addr(q.head)), moved.eq(head_addr(h_next)), popped.eq(pop)]
        h_addr = Signal(slot, name="h_addr")
        m.d.comb += h_addr.eq(Mux(popped, moved, stay))
        return h_addr


# --- output: head of the queue once its line is present ---------------------------------------

class Output(_Part):
    """The head's line read from the data array as it is popped (``o``: the block RAM's
    output), its item selected into ``resp``. Latency 1, throughput 1."""

    def _ports(self, d: _Dims) -> dict:
        return {"head": In(stream.Signature(d.head())), "read": Out(d.data_read()),
                "resp": Out(stream.Signature(MemResponse(d.g.item_bits, d.utag)))}

    def elaborate(self, platform):
        m = Module()
        d, head, resp = self._d, self.head, self.resp
        o_valid, o_off, o_utag = Signal(), Signal(d.ob), Signal(d.utag)
        o_move, line, off, out_valid, out_utag = self._final(m, o_valid, o_off, o_utag)
        m.d.comb += head.ready.eq(~o_valid | o_move)
        pop = head.valid & head.ready
        m.d.comb += [self.read.addr.eq(head.payload.slot), self.read.en.eq(self._read_en(pop))]
        with m.If(pop):
            m.d.sync += [o_valid.eq(1), o_off.eq(head.payload.off), o_utag.eq(head.payload.utag)]
        with m.Elif(o_move):
            m.d.sync += o_valid.eq(0)
        m.d.comb += [resp.valid.eq(out_valid),
                     resp.payload.data.eq(line.word_select(off, d.g.item_bits) if d.ob
                                          else line),
                     resp.payload.tag.eq(out_utag)]
        return m

    def _final(self, m: Module, o_valid, o_off, o_utag):
        """(``o`` moves on, the line, offset, valid and unit tag ``resp`` is formed from)."""
        return self.resp.ready, self.read.data, o_off, o_valid, o_utag

    def _read_en(self, pop):
        return pop


class FastOutput(Output):
    """``fast`` :class:`Output`: ``o2``, the line in a register before ``resp`` (the block
    RAM's output feeds only registers); the data array is read whenever ``o`` can take a line.
    Latency 2, throughput 1."""

    fast = True

    def _final(self, m: Module, o_valid, o_off, o_utag):
        d = self._d
        o2_valid, o2_off, o2_utag = Signal(), Signal(d.ob), Signal(d.utag)
        o2_line = Signal(d.data_bits, reset_less=True)
        o_move = Signal()
        m.d.comb += o_move.eq(~o2_valid | self.resp.ready)
        with m.If(o_move):
            m.d.sync += [o2_valid.eq(o_valid), o2_off.eq(o_off), o2_utag.eq(o_utag),
                         o2_line.eq(self.read.data)]
        return o_move, o2_line, o2_off, o2_valid, o2_utag

    def _read_en(self, pop):
        return self.head.ready


_PARTS = {
    False: dict(lookup=TagLookup, decision=Decision, mshrs=MshrFile, queue=ResponseQueue,
                issue=Issue, fill=Fill, data=DataArray, output=Output),
    True: dict(lookup=FastTagLookup, decision=FastDecision, mshrs=FastMshrFile,
               queue=FastResponseQueue, issue=FastIssue, fill=FastFill, data=DataArray,
               output=FastOutput),
}
