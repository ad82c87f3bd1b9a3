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
(``fast``: a cycle after the lookup), and ``lookup_valid``/``lookup_hit`` (one pulse per
classified request, for testbenches).
"""
from __future__ import annotations

from types import SimpleNamespace

from amaranth.hdl import Array, Cat, Const, Module, Mux, Signal
from amaranth.lib import wiring
from amaranth.lib.fifo import SyncFIFO
from amaranth.lib.memory import Memory
from amaranth.lib.wiring import In, Out
from amaranth.utils import ceil_log2

from model.cache import CacheGeometry

from .memport import WORD_BITS, MemReadPort
from .common import COUNTER_BITS, BlockRAM, lowest, registered, times_const

__all__ = ["Cache"]


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
            "lookup_valid": Out(1),
            "lookup_hit": Out(1),
        })

    def elaborate(self, platform):
        m = Module()
        g = self.geom
        W, S, O, Q, LW = g.ways, g.sets, g.outstanding, g.queue, g.line_words
        ob, sb, tb = g.offset_bits, g.set_bits, g.tag_bits
        wb = ceil_log2(W)
        req, resp = self.port.req, self.port.resp
        utag_bits = len(req.payload.tag)

        # --- tag array: one row per set = W x {valid, tag} + round-robin pointer -----------
        entry = 1 + tb
        tags = (BlockRAM if self.fast else Memory)(shape=W * entry + wb, depth=S, init=[])
        m.submodules.tags = tags
        twp = tags.write_port()
        a = req.payload.addr

        # --- lookup stage S1: valid, the request's fields, its tag row; ``s1_go`` = it
        # finishes this cycle -----------------------------------------------------------------
        s1_valid = Signal()
        s1_off, s1_set, s1_tag = Signal(ob), Signal(sb), Signal(tb)
        s1_utag = Signal(utag_bits)
        s1_go = Signal()
        accept = Signal()
        m.d.comb += accept.eq(req.valid & req.ready)
        if not self.fast:
            # the request is accepted while its row is read (transparent for the tag write)
            trp = tags.read_port(transparent_for=(twp,))
            m.d.comb += [req.ready.eq(~s1_valid | s1_go), trp.addr.eq(a[ob:ob + sb]),
                         trp.en.eq(req.ready)]
            with m.If(req.ready):
                m.d.sync += [s1_valid.eq(req.valid), s1_off.eq(a[:ob]), s1_set.eq(a[ob:ob + sb]),
                             s1_tag.eq(a[ob + sb:]), s1_utag.eq(req.payload.tag)]
            row = trp.data
        else:
            row = self._fast_front(m, tags, twp, s1_valid, s1_go,
                                   (s1_off, s1_set, s1_tag, s1_utag))

        def hits(r, tag):
            return Cat(*[r[w * entry] & (r[w * entry + 1:(w + 1) * entry] == tag)
                         for w in range(W)])
        # --- the decision (S1, or S2 with ``fast``): hit, or allocate the miss; ``go`` = it
        # finishes this cycle; ``new_row`` = its tag row with the miss allocated
        go = Signal()
        new_row = Signal(len(row))
        if self.fast:
            # S2: S1's compare verdict in a register, so S2 decides (and the stages before it
            # advance) from registers only. S2 has a skid entry B: S1 hands its request on
            # while B is empty (a register), to S2 if S2 takes one this cycle, else to B; S2
            # takes B's request first. So the stall (``go``) stops at S2 and B, and the stages
            # before them move on registers. S2's tag write of the cycle it takes a request
            # (from S1 or B) is applied a cycle later: S2 keeps the request's row and hits as
            # they were and as that write leaves them (both formed without ``go``) and a bit
            # saying whether the write was to its set. S0 and S1 take the write a cycle later,
            # from a register (a write meets B only as B moves on: S2 writes only when it goes)
            s2_valid = Signal()
            s2_off, s2_set, s2_tag = Signal(ob), Signal(sb), Signal(tb)
            s2_utag = Signal(utag_bits)
            s2_row_n, s2_row_w = Signal(len(row), name="s2_row"), Signal(len(row), name="s2_row_w")
            s2_hits_n, s2_hits_w = Signal(W, name="s2_hits"), Signal(W, name="s2_hits_w")
            s2_wsel = Signal(name="s2_written")
            s2_mem = Signal(g.mem_addr_width, name="s2_mem_addr")
            b_valid = Signal(name="s2b_valid")
            b_off, b_set, b_tag = Signal(ob, name="s2b_off"), Signal(sb, name="s2b_set"), \
                Signal(tb, name="s2b_tag")
            b_utag = Signal(utag_bits, name="s2b_utag")
            b_row = Signal(len(row), name="s2b_row")
            b_hits = Signal(W, name="s2b_hits")
            b_mem = Signal(g.mem_addr_width, name="s2b_mem_addr")
            s2_move = Signal()
            m.d.comb += [s2_move.eq(~s2_valid | go), s1_go.eq(s1_valid & ~b_valid)]
            # S1's hits: one compare per row it may have (newest write first), then a choice
            (w_s1, wq_row), (s1_fwd, s1_fwd_row), (_, s1_raw) = self._s1_rows
            s1_hits = Mux(w_s1, hits(wq_row, s1_tag),
                          Mux(s1_fwd, hits(s1_fwd_row, s1_tag), hits(s1_raw, s1_tag)))
            s1_mem = self.base + self._s1_mem
            with m.If(s2_move):
                # (a compare per candidate request, B's and S1's, then the choice)
                m.d.sync += [s2_row_w.eq(new_row),
                             s2_hits_w.eq(Mux(b_valid, hits(new_row, b_tag),
                                              hits(new_row, s1_tag))),
                             s2_wsel.eq(twp.en & Mux(b_valid, twp.addr == b_set,
                                                     twp.addr == s1_set))]
                with m.If(b_valid):
                    m.d.sync += [s2_valid.eq(1), s2_off.eq(b_off), s2_set.eq(b_set),
                                 s2_tag.eq(b_tag), s2_utag.eq(b_utag), s2_row_n.eq(b_row),
                                 s2_hits_n.eq(b_hits), s2_mem.eq(b_mem), b_valid.eq(0)]
                with m.Else():
                    m.d.sync += [s2_valid.eq(s1_valid), s2_off.eq(s1_off), s2_set.eq(s1_set),
                                 s2_tag.eq(s1_tag), s2_utag.eq(s1_utag), s2_row_n.eq(row),
                                 s2_hits_n.eq(s1_hits), s2_mem.eq(s1_mem)]
            with m.Elif(s1_go):     # S2 holds: S1's request into B (no tag write this cycle)
                m.d.sync += b_valid.eq(1)
            # B's fields follow S1 while B is empty (they count only once b_valid is set, in
            # the cycle S1 hands over), so their enable is a register, not ``go``
            with m.If(~b_valid):
                m.d.sync += [b_off.eq(s1_off), b_set.eq(s1_set), b_tag.eq(s1_tag),
                             b_utag.eq(s1_utag), b_row.eq(row), b_hits.eq(s1_hits),
                             b_mem.eq(s1_mem)]
            d_valid, d_off, d_set, d_tag, d_utag = s2_valid, s2_off, s2_set, s2_tag, s2_utag
            d_row, hit_vec = Signal(len(row), name="s2_row_now"), Signal(W, name="s2_hits_now")
            m.d.comb += [d_row.eq(Mux(s2_wsel, s2_row_w, s2_row_n)),
                         hit_vec.eq(Mux(s2_wsel, s2_hits_w, s2_hits_n))]
        else:
            m.d.comb += s1_go.eq(go)
            d_valid, d_off, d_set, d_tag, d_utag = s1_valid, s1_off, s1_set, s1_tag, s1_utag
            d_row, hit_vec = row, hits(row, s1_tag)
        rr = d_row[W * entry:]
        hit = Signal()
        hit_way = Signal(wb)
        m.d.comb += hit.eq(hit_vec.any())
        for w in reversed(range(W)):
            with m.If(hit_vec[w]):
                m.d.comb += hit_way.eq(w)
        victim = rr
        way = Signal(wb)
        m.d.comb += way.eq(Mux(hit, hit_way, victim))

        # --- MSHRs ------------------------------------------------------------------------
        mshr_valid = Signal(O)
        mshr_set = [Signal(sb, name=f"mshr{i}_set") for i in range(O)]
        mshr_way = [Signal(wb, name=f"mshr{i}_way") for i in range(O)]
        mshr_line = [Signal(g.addr_width - ob, name=f"mshr{i}_line") for i in range(O)]
        mshr_addr = [Signal(g.mem_addr_width, name=f"mshr{i}_addr") for i in range(O)]
        mshr_cnt = [Signal(range(LW), name=f"mshr{i}_cnt") for i in range(O)]
        free = Signal(range(O))                 # the lowest free MSHR
        any_free = Signal(init=int(self.fast))  # fast: a register (all free at reset)
        if not self.fast:
            m.d.comb += any_free.eq(~mshr_valid.all())
            for i in reversed(range(O)):
                with m.If(~mshr_valid[i]):
                    m.d.comb += free.eq(i)

        # --- response queue (in request order) ------------------------------------------------
        q_used = Signal(Q)
        q_set = [Signal(sb, name=f"q{i}_set") for i in range(Q)]
        q_way = [Signal(wb, name=f"q{i}_way") for i in range(Q)]
        q_off = [Signal(ob, name=f"q{i}_off") for i in range(Q)]
        q_utag = [Signal(utag_bits, name=f"q{i}_utag") for i in range(Q)]
        q_head, q_tail = Signal(range(Q)), Signal(range(Q))
        q_full = Signal()
        q_set_bit, q_clr_bit = Signal(Q), Signal(Q)     # taken at the tail, popped at the head
        q_next = (q_used | q_set_bit) & ~q_clr_bit
        m.d.sync += q_used.eq(q_next)
        if self.fast:       # kept in a register, from the used bits after this cycle
            m.d.sync += q_full.eq(q_next.all())
        else:
            m.d.comb += q_full.eq(q_used.all())

        def filling(set_, way_, valid=mshr_valid):
            """The slot is the target of a fill in flight (of the MSHRs ``valid`` marks)."""
            return Cat(*[valid[i] & (mshr_set[i] == set_) & (mshr_way[i] == way_)
                         for i in range(O)]).any()

        def slot_busy(set_, way_):
            """The slot is referenced by a queued request or by a fill in flight."""
            in_q = Cat(*[q_used[i] & (q_set[i] == set_) & (q_way[i] == way_) for i in range(Q)])
            return in_q.any() | filling(set_, way_)

        if self.fast:
            # the victim slot's "busy" from registers: per way, computed a cycle ahead for the
            # request S2 holds next (B's or S1's if S2 takes one, else its own), plus whether the
            # queue entry written in that cycle is in that set; a slot freed meanwhile costs
            # one cycle
            def busy_ways(set_):
                return Cat(*(slot_busy(set_, w) for w in range(W)))
            # (one compare per candidate set, B's, S1's and S2's own, each from registers; the
            # choice between a new request and S2's own after the registers, by whether S2
            # moved: the lookup's verdict ends at one flip-flop, not at the busy bits)
            b_mv, b_hd = Signal(W, name="busy_s2_move"), Signal(W, name="busy_s2_hold")
            moved, lw_go, lw_same, lw_way = (Signal(name="s2_moved"), Signal(name="lw_go"),
                                             Signal(name="lw_same"), Signal(wb))
            m.d.sync += [b_mv.eq(Mux(b_valid, busy_ways(b_set), busy_ways(s1_set))),
                         b_hd.eq(busy_ways(d_set)), moved.eq(s2_move),
                         # the entry written with `go` is in the next request's set (a `go`
                         # moves S2)
                         lw_go.eq(go), lw_same.eq(Mux(b_valid, d_set == b_set, d_set == s1_set)),
                         lw_way.eq(way)]
            b = Signal(W, name="busy_s2")
            m.d.comb += b.eq(Mux(moved, b_mv, b_hd))
            last_w = Mux(lw_go & lw_same, Const(1, W) << lw_way, 0)[:W]
            busy = (b | last_w).bit_select(victim, 1) if W > 1 else b | last_w
        else:
            busy = slot_busy(d_set, victim)
        m.d.comb += go.eq(d_valid & ~q_full & (hit | (any_free & ~busy)))
        m.d.comb += [self.lookup_valid.eq(go), self.lookup_hit.eq(hit)]

        issue = SyncFIFO(width=self.mshr_bits, depth=O)
        m.submodules.issue = issue
        # the queue entry at the tail and the lowest free MSHR are not in use, so S1's fields
        # are written into them every cycle, whatever the lookup decides; only the used and
        # valid bits wait for ``go`` (the lookup's verdict drives a few bits, not the
        # entries' enables)
        q_wr = [(q_tail == i) & ~q_used[i] for i in range(Q)]     # the entry at the tail
        for i in range(Q):
            with m.If(q_wr[i]):
                m.d.sync += [q_set[i].eq(d_set), q_way[i].eq(way), q_off[i].eq(d_off),
                             q_utag[i].eq(d_utag)]
        with m.If(go):
            m.d.comb += q_set_bit.eq(1 << q_tail)
            m.d.sync += q_tail.eq(Mux(q_tail == Q - 1, 0, q_tail + 1))
        count_hit, count_miss = go & hit, go & ~hit
        if self.fast:       # the counters count a cycle later, from registers
            count_hit, count_miss = registered(m, "count", hit=count_hit,
                                               miss=count_miss).values()
        with m.If(count_hit):
            m.d.sync += self.hits.eq(self.hits + 1)
        with m.If(count_miss):
            m.d.sync += self.misses.eq(self.misses + 1)
        # miss: allocate the line in the tag row, an MSHR, and queue its fetch
        m.d.comb += new_row.eq(d_row)
        for w in range(W):
            with m.If(victim == w):
                m.d.comb += new_row[w * entry:(w + 1) * entry].eq(Cat(Const(1, 1), d_tag))
        if wb:
            m.d.comb += new_row[W * entry:].eq(victim + 1)
        m.d.comb += [twp.addr.eq(d_set), twp.data.eq(new_row), twp.en.eq(go & ~hit)]
        iw_en, iw_data = go & ~hit, free
        if self.fast:   # the miss's MSHR enters the issue FIFO a cycle later, from registers
            iw_en, iw_data = registered(m, "issue_w", en_q=iw_en, data_q=iw_data).values()
        m.d.comb += [issue.w_data.eq(iw_data), issue.w_en.eq(iw_en)]
        spare = [(free == i) & ~mshr_valid[i] for i in range(O)]    # written while free
        for i in range(O):
            with m.If(spare[i]):
                m.d.sync += [mshr_set[i].eq(d_set), mshr_way[i].eq(victim),
                             mshr_line[i].eq(Cat(d_set, d_tag)), mshr_cnt[i].eq(0)]
                if self.fast:       # the line's first word address, formed in S0 -> S1
                    m.d.sync += mshr_addr[i].eq(s2_mem)

        # --- issue: the line's words, one request per cycle -----------------------------------
        word = Signal(range(LW))
        head_m = issue.r_data
        mreq = self.mem.req
        line = Array(mshr_line)[head_m]
        m.d.comb += [mreq.valid.eq(issue.r_rdy),
                     mreq.payload.addr.eq(Array(mshr_addr)[head_m] + word if self.fast
                                          else self.base + times_const(line, LW) + word),
                     mreq.payload.tag.eq(Cat(head_m, word)[:len(mreq.payload.tag)])]
        m.d.comb += issue.r_en.eq(mreq.valid & mreq.ready & (word == LW - 1))
        with m.If(mreq.valid & mreq.ready):
            m.d.sync += word.eq(Mux(word == LW - 1, 0, word + 1))

        # --- fill: each word goes into the data array as it arrives; the last one completes
        # the line (only then may a request read it: the queue's wait bits) -----------------
        # the data array: one memory per word of a line, holding the bits of that word the
        # cache keeps (a line is the concatenation of the words' kept bits, item after item),
        # so a fill needs no line buffer per MSHR
        data = []
        for j, bits in enumerate(g.word_kept_bits):
            if bits:
                mem = BlockRAM(shape=sum(hi - lo for lo, hi in bits), depth=S * W)
                m.submodules[f"data{j}"] = mem
                data.append((j, bits, mem.write_port(), mem.read_port()))
        drp = SimpleNamespace(addr=Signal(wb + sb, name="data_raddr"),
                              en=Signal(name="data_ren"),
                              data=Cat(*(rp.data for _, _, _, rp in data)))
        for _, _, _, rp in data:
            m.d.comb += [rp.addr.eq(drp.addr), rp.en.eq(drp.en)]
        mresp = self.mem.resp
        if self.fast:       # the memory's response in a register first (it comes from the bus)
            # (loaded only with a response: the caches' copies of the bus's shared response
            # stay apart, each beside its own fill logic)
            mresp = SimpleNamespace(valid=Signal(name="fill_valid"),
                                    payload=Signal.like(self.mem.resp.payload, name="fill"))
            m.d.sync += mresp.valid.eq(self.mem.resp.valid)
            with m.If(self.mem.resp.valid):
                m.d.sync += mresp.payload.eq(self.mem.resp.payload)
        m.d.comb += self.mem.resp.ready.eq(1)
        f_m = mresp.payload.tag[:self.mshr_bits]
        f_w = mresp.payload.tag[self.mshr_bits:self.mshr_bits + self.word_bits] if LW > 1 \
            else Const(0, 1)
        fire = mresp.valid
        for i in range(O):
            with m.If(fire & (f_m == i)):
                m.d.sync += mshr_cnt[i].eq(mshr_cnt[i] + 1)
        # the word's place: its MSHR's slot (fast: picked as the response is registered; an
        # MSHR with words in flight keeps its fields)
        f_slot = Signal(wb + sb, name="fill_slot")
        if self.fast:
            r_m = self.mem.resp.payload.tag[:self.mshr_bits]
            with m.If(self.mem.resp.valid):
                m.d.sync += f_slot.eq(Cat(Array(mshr_way)[r_m], Array(mshr_set)[r_m]))
        else:
            m.d.comb += f_slot.eq(Cat(Array(mshr_way)[f_m], Array(mshr_set)[f_m]))
        for j, bits, wp, _ in data:
            m.d.comb += [wp.addr.eq(f_slot),
                         wp.data.eq(Cat(*(mresp.payload.data[lo:hi] for lo, hi in bits))),
                         wp.en.eq(fire & (f_w == j))]
        clr_mask = Signal(O)        # the MSHRs whose line this cycle's fill completes
        if self.fast:
            # per MSHR "the next word completes the line", kept in a register; and which MSHR
            # the registered response completes, decided as it is registered (from the raw
            # response's tag and the "next word" bits after this cycle), so the fill's
            # completion reaches the MSHR valid bits, ``free`` and the queue's waits from a
            # register
            nearly = Signal(O, name="mshr_last")
            nearly_next = Signal(O)
            for i in range(O):
                m.d.comb += nearly_next[i].eq(
                    Mux(spare[i], LW == 1,
                        Mux(fire & (f_m == i), mshr_cnt[i] + 1 == LW - 1, nearly[i])))
            m.d.sync += nearly.eq(nearly_next)
            done = Signal(O, name="fill_done")
            for i in range(O):
                m.d.sync += done[i].eq(self.mem.resp.valid & (r_m == i) & nearly_next[i])
            m.d.comb += clr_mask.eq(done)
        else:
            last = fire & (Array(mshr_cnt)[f_m] == LW - 1)
            for i in range(O):
                m.d.comb += clr_mask[i].eq(last & (f_m == i))
        # MSHR valid bits: set on allocation, cleared by the last word of the fill
        set_mask = Signal(O)
        for i in range(O):
            m.d.comb += set_mask[i].eq(go & ~hit & (free == i))
        m.d.sync += mshr_valid.eq((mshr_valid | set_mask) & ~clr_mask)
        if self.fast:
            # ``free``/``any_free`` of the next cycle in registers: from the valid bits after
            # this cycle's fill completions, without and with this cycle's allocation (which
            # takes ``free``), the lookup's verdict only selecting between the two
            kept = Signal(O, name="mshr_kept")
            m.d.comb += kept.eq(mshr_valid & ~clr_mask)
            k_any, k_idx = lowest(m, ~kept, "mshr_free_keep")
            a_any, a_idx = lowest(m, ~(kept | (Const(1, O) << free)[:O]), "mshr_free_alloc")
            alloc = go & ~hit
            m.d.sync += [any_free.eq(Mux(alloc, a_any, k_any)), free.eq(Mux(alloc, a_idx, k_idx))]

        # --- output: head of the queue once its line is present -----------------------------
        q_set_a, q_way_a = Array(q_set), Array(q_way)
        h_set, h_way = q_set_a[q_head], q_way_a[q_head]
        h_ready = Signal()
        if self.fast:
            # per queue entry, a cycle ahead into a register: the same function of the queue
            # entries and the MSHRs after this cycle. A valid MSHR keeps its fields; one
            # allocated this cycle matches no used entry (its slot was not busy) but the entry
            # written with it; so a used entry waits on the MSHRs still valid after this
            # cycle's fills, and the entry written now waits if it is a miss, or a hit on a
            # line still being filled (neither needs ``go``: the entry counts only if taken)
            wait = Signal(Q, name="q_wait")
            new_wait = ~hit | filling(d_set, hit_way, kept)
            for i in range(Q):
                m.d.sync += wait[i].eq(Mux(q_wr[i], new_wait, filling(q_set[i], q_way[i], kept)))
            h_pending = wait.bit_select(q_head, 1)
        else:
            h_pending = filling(h_set, h_way)
        m.d.comb += h_ready.eq(q_used.bit_select(q_head, 1) & ~h_pending)
        # o: the data read (the block RAM's output); fast: o2, that line in a register
        o_valid, o_off, o_utag = Signal(), Signal(ob), Signal(utag_bits)
        if self.fast:
            o2_valid, o2_off, o2_utag = Signal(), Signal(ob), Signal(utag_bits)
            o2_line = Signal(len(drp.data), reset_less=True)
            o_move = Signal()
            m.d.comb += o_move.eq(~o2_valid | resp.ready)
            with m.If(o_move):
                m.d.sync += [o2_valid.eq(o_valid), o2_off.eq(o_off), o2_utag.eq(o_utag),
                             o2_line.eq(drp.data)]
            line, off, out_valid, out_utag = o2_line, o2_off, o2_valid, o2_utag
        else:
            o_move = resp.ready
            line, off, out_valid, out_utag = drp.data, o_off, o_valid, o_utag
        pop = Signal()
        m.d.comb += pop.eq(h_ready & (~o_valid | o_move))
        h_next = Mux(q_head == Q - 1, 0, q_head + 1)[:len(q_head)]
        if self.fast:
            # the head entry's data address from registers, formed a cycle ahead: the
            # addresses of the entry at the head and of the one after it (the tail entry's
            # write of this cycle bypassed) and whether the head moves on. The data array is
            # read whenever the output stage can take a line, popped or not (o_valid says
            # whether it is the head's), so the read's enable needs no verdict
            h_addr = Signal(wb + sb, name="h_addr")
            written = Cat(*q_wr)

            def head_addr(k):
                return Mux(written.bit_select(k, 1), Cat(way, d_set), Cat(q_way_a[k], q_set_a[k]))
            # both candidates registered, the pop registered to choose between them
            stay, moved, popped = Signal(wb + sb, name="h_addr_stay"), \
                Signal(wb + sb, name="h_addr_moved"), Signal(name="h_popped")
            m.d.sync += [stay.eq(head_addr(q_head)), moved.eq(head_addr(h_next)),
                         popped.eq(pop)]
            m.d.comb += [h_addr.eq(Mux(popped, moved, stay)),
                         drp.addr.eq(h_addr), drp.en.eq(~o_valid | o_move)]
        else:
            m.d.comb += [drp.addr.eq(Cat(h_way, h_set)), drp.en.eq(pop)]
        m.d.comb += q_clr_bit.eq(Mux(pop, 1 << q_head, 0))
        with m.If(pop):
            m.d.sync += [o_valid.eq(1), o_off.eq(Array(q_off)[q_head]),
                         o_utag.eq(Array(q_utag)[q_head]),
                         q_head.eq(h_next)]
        with m.Elif(o_move):
            m.d.sync += o_valid.eq(0)
        m.d.comb += [resp.valid.eq(out_valid),
                     resp.payload.data.eq(line.word_select(off, g.item_bits) if ob else line),
                     resp.payload.tag.eq(out_utag)]
        return m

    def _fast_front(self, m: Module, tags, twp, s1_valid, s1_go, s1_fields) -> Signal:
        """``fast``: request register (registered ``ready``, a skid register), stage S0 that
        reads the tag row, and S1's tag row (the block RAM's output straight into a register,
        a tag write the read missed forwarded). Returns S1's tag row."""
        g, req = self.geom, self.port.req
        ob, sb = g.offset_bits, g.set_bits
        a = req.payload.addr
        trp = tags.read_port()              # not transparent: writes are forwarded below
        # skid register: takes a request while S0 holds; ready is its emptiness
        k_valid = Signal()
        k_addr, k_utag = Signal.like(a, name="k_addr"), Signal.like(req.payload.tag, name="k_utag")
        m.d.comb += req.ready.eq(~k_valid)
        # S0: the request whose row is being read; the row arrives in the next cycle
        s0_valid = Signal()
        s0_addr, s0_utag = Signal.like(a, name="s0_addr"), Signal.like(req.payload.tag, name="s0_utag")
        s1_move = Signal()                  # S0 -> S1 this cycle
        s0_load = Signal()
        m.d.comb += [s1_move.eq(~s1_valid | s1_go), s0_load.eq(~s0_valid | s1_move)]
        in_valid = k_valid | req.valid
        in_addr = Mux(k_valid, k_addr, a)
        in_utag = Mux(k_valid, k_utag, req.payload.tag)
        in_set = in_addr[ob:ob + sb]
        m.d.comb += [trp.addr.eq(in_set), trp.en.eq(s0_load)]
        # the tag write of the cycle before, registered (``wq``): S0's and S1's requests take
        # each write a cycle after it, so the deciding stage's ``go`` (the write enable)
        # reaches these registers, not their rows. A read in the cycle of a write misses it,
        # a read after it sees it. S2 writes only in a cycle it takes a request, which empties
        # the skid entry B: in the next cycle S1 and S0 both move on. So a write is always
        # taken as a request moves (S0 -> S1: into S1's forwarded row; S1 -> S2 or B: at
        # S1's output), never by a request that waits
        wq_en, wq_set = Signal(name="tw_q_en"), Signal(sb, name="tw_q_set")
        wq_row = Signal(len(trp.data), name="tw_q_row")
        m.d.sync += [wq_en.eq(twp.en), wq_set.eq(twp.addr), wq_row.eq(twp.data)]
        with m.If(s0_load):
            m.d.sync += [s0_valid.eq(in_valid), s0_addr.eq(in_addr), s0_utag.eq(in_utag),
                         k_valid.eq(0)]
        with m.Elif(req.valid & req.ready):
            m.d.sync += k_valid.eq(1)
        s0_set = s0_addr[ob:ob + sb]
        w_now = wq_en & (wq_set == s0_set)   # the last cycle's write, to S0's set
        with m.If(~k_valid):                # the fields follow the request while k is empty
            m.d.sync += [k_addr.eq(a), k_utag.eq(req.payload.tag)]
        # S1: the row as read, or the tag write to the set taken as it came from S0, or the
        # last cycle's write (still in ``wq``, chosen at its output)
        s1_off, s1_set, s1_tag, s1_utag = s1_fields
        s1_raw = Signal(len(trp.data), name="s1_raw_row", reset_less=True)
        s1_fwd, s1_fwd_row = Signal(), Signal(len(trp.data), name="s1_fwd_row")
        # the line's first memory word, formed before an allocation needs it (off the
        # lookup's path): its offset from ``base`` here, S0 -> S1, the sum S1 -> S2 (one
        # carry chain a stage)
        s1_mem = Signal(g.mem_addr_width, name="s1_mem_off")
        with m.If(s1_move):
            m.d.sync += s1_mem.eq(times_const(s0_addr[ob:], g.line_words))
        self._s1_mem = s1_mem
        with m.If(s1_move):
            m.d.sync += [s1_valid.eq(s0_valid), s1_off.eq(s0_addr[:ob]), s1_set.eq(s0_set),
                         s1_tag.eq(s0_addr[ob + sb:]), s1_utag.eq(s0_utag),
                         s1_raw.eq(trp.data), s1_fwd.eq(w_now), s1_fwd_row.eq(wq_row)]
        w_s1 = wq_en & (wq_set == s1_set)
        row = Signal(len(trp.data), name="s1_row")
        m.d.comb += row.eq(Mux(w_s1, wq_row, Mux(s1_fwd, s1_fwd_row, s1_raw)))
        self._s1_rows = ((w_s1, wq_row), (s1_fwd, s1_fwd_row), (None, s1_raw))
        return row

