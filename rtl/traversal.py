"""Traversal unit of the RTC: up to ``cfg.threads`` packets walk the kd-tree, bit-exact with
``model.rtc.trace_packet`` / ``model.traversal``.

Per thread (packet in flight) the unit keeps: the read-only ray data of its lanes (org, inv,
any-hit) and the per-lane interval ``[tnear, tfar]`` in the sub-units' local memories; the
active mask, current node, octant pass, stack pointer and terminated mask in registers; a stack
of ``cfg.stack_depth`` entries (node, mask) in an on-chip ``Memory`` and, per entry and lane,
the far interval in the sub-units' stack memories.

Interval storage: a thread's current intervals live either in its *near* slot ``N`` or in its
stack slot ``S[sp]`` (flag ``cur``). A step at an inner node writes, for every active lane,
the near interval ``[tnear, min(tfar, dist)]`` to ``N`` and the far interval
``[max(tnear, dist), tfar]`` to ``S[sp]`` (each lane reads its own word before it overwrites
it, so doing this in place is safe). Then: both children needed -> push entry ``sp`` (its
intervals are already in ``S[sp]``), descend near (``cur = N``); near only -> ``cur = N``; far
only -> ``cur = S``. A pop of entry ``i`` sets ``sp = i``, ``cur = S``: no interval is copied.

``cfg.trav_stack = "one_value"``: ``S[sp]`` keeps one value and a keep bit a lane
(``model.traversal.push_one``), ``N`` the interval each lane goes on with, so a step leaves
``cur = N``; a popped lane's interval is ``[value, N.tfar]`` or ``[N.tfar, value]``. A pop that
follows a leaf reached by a pop first folds those intervals into ``N`` (a ``fold`` step through
the sub-units, ``_ControlEngine.pop``).

Engines (each a small state machine; threads are picked round-robin among those waiting):

* loader (``_Loader``): takes ``RayIn`` packets into a free thread (``load_thread`` says
  which), one lane per cycle;
* fetcher: one 64-bit node read per packet visit (``node`` port, tag = thread);
* control engine (``_ControlEngine``): decodes the node (2 cycles per event); at an inner
  node it queues the step in every sub-unit (``StepDispatch``: lane ``l`` -> sub-unit
  ``l // (lanes/k)``) and moves on to the next thread; at a non-empty leaf it emits a
  ``LeafRequest`` and parks the thread; empty leaves and finished leaves pop the stack (one
  entry per 2 cycles); an exhausted stack starts the next octant pass or finishes the packet;
* sub-units: one lane per cycle through ``sub -> mul -> compare with min/max``, steps of different
  threads back to back; synchronous mode (``cfg.trav_sync``): all sub-units start a step
  together; asynchronous: each starts its next step as soon as it has issued its lanes of the
  previous one (an idle group costs one cycle);
* decide engine (``StepDecide``): when every sub-unit's verdict on the oldest outstanding
  step is in, combines them and goes near / far / both (push) / ends the pass, in one cycle;
* result engine: one ``LaneResult`` per cycle; terminates lanes with
  ``hit & (anyhit | t <= tfar)``; the leaf's ``last`` result makes the thread pop;
* done engine: emits ``PacketDone``; the thread is free again on ``release``.

Counters (ports, 32 bit): ``busy`` (cycles the control engine, a sub-unit or the decide
engine works), ``ctl_busy`` (cycles the control engine works), ``sub_busy[k]`` (cycles a
sub-unit has a lane in flight), ``trav_ops`` (active lanes classified), ``trav_steps`` (inner
node steps), ``node_reads``, ``leaf_reqs``, ``passes``, ``pushes``, ``packets_done``.
"""
from __future__ import annotations

from amaranth.hdl import Array, Cat, Const, Module, Mux, Signal, Value
from amaranth.lib import data, enum, stream, wiring
from amaranth.lib.fifo import SyncFIFO
from amaranth.lib.wiring import In, Out
from amaranth.utils import ceil_log2

from model.config import Config
from model.layout import LEAF, NODE_INDEX_BITS, node_layout
from .common import (COUNTER_BITS, BlockRAM, OutputStage, element, from_binary32, lowest,
                     lowest_onehot, registered, rr_pick, rr_pick_next)
from .fp import FPAdd, FPMinMax, FPMul
from .fp.cmp import compare
from .memport import WORD_BITS, MemReadPort, MemRequest
from .rtc_streams import LaneResult, LeafRequest, PacketDone, RayIn, lane_bits

__all__ = ["Traversal", "TravSubunit", "StepIssue", "StepDispatch", "StepDecide", "ThreadState"]

NODE_BITS = NODE_INDEX_BITS


class ThreadState(enum.Enum, shape=4):
    """Where a thread (a packet in flight) is."""
    FREE = 0          # no packet: the loader may take it
    LOAD = 1          # the loader is writing its rays
    NEXTPASS = 2      # start the next octant pass (or finish)
    FETCH = 3         # its node is to be read
    WAIT_MEM = 4      # node read in flight
    HAVE_NODE = 5     # node word here, waiting for the control engine
    WAIT_LEAF = 6     # leaf sent to the list unit, waiting for the leaf's results
    POP = 7           # pop the stack
    DONE = 8          # every pass ended: report the packet
    DRAIN = 9         # reported: its results are being read out
    STEP = 10         # an inner-node step is in the sub-units


def stack_bits(cfg: Config) -> int:
    """Bits of a stack pointer (an entry's index)."""
    return max(1, ceil_log2(cfg.stack_depth))


def stack_entry(cfg: Config, thread: Value, sp: Value) -> Value:
    """The row of ``thread``'s stack entry ``sp`` in a stack memory of ``threads x
    stack_depth`` rows: ``thread * stack_depth + sp``, so a depth that is not a power of two
    pads nothing (24 levels: 3/4 of the 32-level memory). Entries written are below the
    depth: a step at an inner node of depth k writes entry sp <= k <= stack_depth - 1."""
    D = cfg.stack_depth
    if D == 1:
        return thread
    if D & (D - 1) == 0:
        return Cat(sp[:stack_bits(cfg)], thread)
    return (thread * D + sp)[:ceil_log2(cfg.threads * D)]


def step_layout(cfg: Config) -> data.StructLayout:
    """A step for one sub-unit: its lanes of the active mask and the node's split plane;
    ``fold`` (``trav_stack = "one_value"``): no step but a fold, the lanes' intervals written
    back (:class:`TravSubunit`)."""
    return data.StructLayout({
        "mask": cfg.rays_per_subunit, "thread": cfg.thread_bits, "axis": 2,
        "split": cfg.fmt.width, "sp": stack_bits(cfg), "cur": 1, "fold": 1})


def step_result_layout(cfg: Config) -> data.StructLayout:
    """A sub-unit's verdict on a step: lanes that need the near / the far child."""
    return data.StructLayout({"near": cfg.rays_per_subunit, "far": cfg.rays_per_subunit})


class StepIssue(wiring.Component):
    """A sub-unit's step queue (``queue`` entries) and issue stage: the lanes of the current
    step's mask, lowest first, one per cycle; a step with no lane of this sub-unit takes one
    cycle. The next step is taken when ``go`` is 1 and the stage is free or frees in this cycle
    (``can_start``), so steps issue back to back.

    Outputs per cycle: ``active`` (a step is issuing), ``cur`` (that step), ``has_lane``,
    ``lane`` (the lane issued now), ``last`` (the step's last cycle); ``queued`` (a step waits).
    """

    def __init__(self, cfg: Config, *, queue: int):
        self.cfg, self.queue = cfg, queue
        R = cfg.rays_per_subunit
        super().__init__({
            "step": In(stream.Signature(step_layout(cfg))),
            "go": In(1, init=1), "can_start": Out(1), "queued": Out(1),
            "active": Out(1), "cur": Out(step_layout(cfg)), "has_lane": Out(1),
            "lane": Out(max(1, ceil_log2(R))), "last": Out(1),
        })

    def elaborate(self, platform):
        m = Module()
        R, slay = self.cfg.rays_per_subunit, step_layout(self.cfg)
        # each queued step carries its mask without the lowest lane, "at most one lane", and
        # its lowest lane (any, index), formed as it is queued
        without_lowest = lambda x: (x & (x - 1))[:R]
        mask_rest = without_lowest(self.step.payload.mask)
        in_has, in_lane = lowest(m, self.step.payload.mask, "queued")
        lb = len(self.lane)
        m.submodules.queue = q = SyncFIFO(width=slay.size + R + 2 + lb, depth=self.queue)
        m.d.comb += [q.w_data.eq(Cat(self.step.payload, mask_rest, mask_rest == 0, in_has,
                                     in_lane[:lb])),
                     q.w_en.eq(self.step.valid),
                     self.step.ready.eq(q.w_rdy), self.queued.eq(q.r_rdy)]
        head = slay(q.r_data[:slay.size])
        head_rest, head_one = q.r_data[slay.size:slay.size + R], q.r_data[slay.size + R]
        head_has, head_lane = q.r_data[slay.size + R + 1], q.r_data[slay.size + R + 2:]
        act, d = self.active, self.cur
        rest = Signal(R)                    # the current step's lanes not issued yet, less
        #                                     the lowest one (issued now)
        # ``has_lane``, ``lane`` and ``last`` (at most one lane left) are registers, computed
        # when a step is taken or loses its lowest lane: the issue decision and the ray
        # read's address do not wait for a priority encoder
        has, lane0, last = Signal(name="issue_has"), Signal(lb, name="issue_lane"), self.last
        _, r_lane = lowest(m, rest, "issue_rest")
        m.d.comb += [self.has_lane.eq(has), self.lane.eq(lane0)]
        take = Signal()
        m.d.comb += [self.can_start.eq(q.r_rdy & (~act | last)),
                     take.eq(self.can_start & self.go), q.r_en.eq(take)]
        # the step's fields are loaded whenever the stage is free or frees, taken or not (they
        # count only while ``active``), so only ``active`` and the queue's read wait for
        # ``go`` (with synchronous sub-units, an AND over all of them)
        m.d.sync += act.eq(take | (act & ~last))
        with m.If(~act | last):
            m.d.sync += [d.eq(head), rest.eq(head_rest), last.eq(head_one),
                         has.eq(head_has), lane0.eq(head_lane)]
        with m.Else():
            rest_rest = without_lowest(rest)
            # (rest is not empty here: last is 0)
            m.d.sync += [rest.eq(rest_rest), last.eq(rest_rest == 0), has.eq(1),
                         lane0.eq(r_lane[:lb])]
        return m


class TravSubunit(wiring.Component):
    """One traversal sub-unit: its static share of ``R = lanes / k`` lanes of every thread.

    Memories (per sub-unit): ray data ``org, inv`` (T x R), ``anyhit`` (T x R), near slot
    intervals ``N`` (T x R) and stack slot intervals ``S`` (T x depth x R), each interval word
    ``tnear | tfar << w`` (``cfg.trav_stack = "one_value"``: an ``S`` word is ``value | keep <<
    w``, and a ``fold`` step writes the lanes' popped intervals to ``N``: no trav-op, no ``S``
    write, its verdict ignored).

    Steps arrive on ``step`` (a queue of ``queue`` entries); one is taken when the issue stage
    is free (or frees in this cycle) and ``go`` is 1 (synchronous mode: the traversal raises
    ``go`` only when every sub-unit ``can_start``). A step issues its active lanes lowest first,
    one per cycle (a step with no lane of this sub-unit takes one cycle), back to back with the
    next step, whatever its thread: thread, sp, cur, axis and split travel with each lane.
    Per lane: ray read (1), register (1), ``split - org[axis]`` (FPAdd), ``* inv[axis]``
    (FPMul), interval read timed to meet ``dist``, two compares, each with its min/max (1),
    write of both intervals: ``LAT`` cycles from issue to write. After a step's last lane the verdict
    (``near`` = not (dist < tnear), ``far`` = not (dist > tfar) per lane) goes to ``res`` (a
    queue of ``cfg.threads`` entries: at most one step per thread is ever outstanding, so it
    never overflows). ``a`` active lanes: the verdict is valid ``a + STEP_LAT`` cycles after the
    step's transfer on an idle sub-unit; throughput one lane per cycle.

    ``ld_*``: write one lane's ray data and initial interval (the loader); ``ld_block`` says the
    datapath writes ``N`` this cycle (the loader must wait), ``ld_block_next`` that it will in
    the next cycle, ``ld_block_next2`` in the cycle after (the pipeline never stalls).
    ``cfg.fast_clock``: the ``ld_*`` write lands a cycle later, from registers beside the
    memories (the loader registers ``ld_block_next2``, so it checks the cycle the write
    lands). ``rq_*``: read a lane's ``tfar`` (current slot) and ``anyhit``;
    ``rq_tfar``/``rq_anyhit`` are valid ``RQ_LAT`` cycles later (1; 3 with
    ``cfg.fast_clock``: the block-RAM outputs are registered beside the RAMs, then again), as
    are both slots' ``tfar`` (``rq_s_tfar``, ``rq_n_tfar``) and which is current
    (``rq_slot``).

    Block-RAM outputs feed only registers: the ray read is registered before the axis pick,
    the interval read is issued two stages before ``dist`` is valid and registered once
    (``cfg.fast_clock``: three stages, registered twice, the slot mux between the two).
    ``cfg.fp_cmp_latency`` (default 1) sets the compare and min/max units' latency.
    """

    def __init__(self, cfg: Config, *, queue: int = 4):
        self.cfg = cfg
        fmt = cfg.fmt
        w = fmt.width
        self.R = R = cfg.rays_per_subunit
        self.rbits = max(1, ceil_log2(R))
        self.tbits = cfg.thread_bits
        self.dbits = stack_bits(cfg)
        self.queue = queue
        lat = cfg.fp_latencies()
        self.add = FPAdd(fmt) if lat["add"] is None else FPAdd(fmt, latency=lat["add"])
        self.mul = FPMul(fmt) if lat["mul"] is None else FPMul(fmt, latency=lat["mul"])
        self.cmp_lat = lat["cmp"] or 1     # compare and min/max units
        self.LAT = 2 + self.add.latency + self.mul.latency + self.cmp_lat  # issue -> write stage
        self.STEP_LAT = self.LAT + 2      # step transfer -> verdict valid, minus active lanes
        self.RQ_LAT = 3 if cfg.fast_clock else 1    # rq_* address -> rq_tfar, rq_anyhit
        self.one = cfg.trav_stack == "one_value"
        self.s_width = w + 1 if self.one else 2 * w     # a stack slot's word
        super().__init__({
            "step": In(stream.Signature(step_layout(cfg))),
            "go": In(1, init=1), "can_start": Out(1),
            "res": Out(stream.Signature(step_result_layout(cfg))),
            "idle": Out(1), "issue": Out(1),
            "ld_en": In(1), "ld_thread": In(self.tbits), "ld_lane": In(self.rbits),
            "ld_org": In(data.ArrayLayout(w, 3)), "ld_inv": In(data.ArrayLayout(w, 3)),
            "ld_tnear": In(w), "ld_tfar": In(w), "ld_anyhit": In(1), "ld_block": Out(1),
            "ld_block_next": Out(1), "ld_block_next2": Out(1),
            "rq_thread": In(self.tbits), "rq_lane": In(self.rbits), "rq_sp": In(self.dbits),
            "rq_cur": In(1), "rq_tfar": Out(w), "rq_anyhit": Out(1),
            "rq_s_tfar": Out(w), "rq_n_tfar": Out(w), "rq_slot": Out(1),
        })

    def elaborate(self, platform):
        m = Module()
        w, T, rb = self.cfg.fmt.width, self.cfg.threads, self.rbits
        m.submodules.ray = ray = BlockRAM(shape=6 * w, depth=T << rb)
        m.submodules.anyhit = ah = BlockRAM(shape=1, depth=T << rb)
        m.submodules.nmem = nmem = BlockRAM(shape=2 * w, depth=T << rb)
        m.submodules.smem = smem = BlockRAM(shape=self.s_width,
                                            depth=(T * self.cfg.stack_depth) << rb)
        ray_r, ray_w = ray.read_port(), ray.write_port()
        ah_r, ah_w = ah.read_port(), ah.write_port()
        n_r, n_rq, n_w = nmem.read_port(), nmem.read_port(), nmem.write_port()
        s_r, s_rq, s_w = smem.read_port(), smem.read_port(), smem.write_port()
        m.submodules.add, m.submodules.mul = self.add, self.mul
        st, d = self._issue(m)
        dist, kd = self._distance(m, st, d, ray_r)
        n_word, s_word = self._classify(m, st, dist, self._interval(m, st, kd, n_r, s_r))
        # ---- k=K: write the far interval (one_value: its word) to S[sp] (N: _write_n)
        sw = st[self.LAT]
        m.d.comb += [s_w.addr.eq(Cat(sw.lane, stack_entry(self.cfg, sw.thread, sw.sp))),
                     s_w.data.eq(s_word),
                     s_w.en.eq(sw.v & ~sw.fold)]
        self._write_n(m, st, n_word, n_w, ray_w, ah_w)
        self._request(m, n_rq, s_rq, ah_r)
        return m

    def _issue(self, m: Module):
        """The step queue and issue stage, and the pipeline behind it: per stage ``k`` (0: the
        issue, ``LAT``: the write) a slot (e), a lane in it (v) and its step's tag. Returns
        (the stages' tags, the issuing step)."""
        m.submodules.issue = iss = StepIssue(self.cfg, queue=self.queue)
        wiring.connect(m, wiring.flipped(self.step), iss.step)
        m.d.comb += [iss.go.eq(self.go), self.can_start.eq(iss.can_start)]
        act, has, d = iss.active, iss.has_lane, iss.cur
        tag = data.StructLayout({"e": 1, "v": 1, "last": 1, "lane": self.rbits,
                                 "thread": self.tbits, "sp": self.dbits, "cur": 1, "fold": 1})
        st = [Signal(tag, name=f"s{k}") for k in range(self.LAT + 1)]
        m.d.comb += [st[0].e.eq(act), st[0].v.eq(act & has), st[0].last.eq(iss.last),
                     st[0].lane.eq(iss.lane), st[0].thread.eq(d.thread), st[0].sp.eq(d.sp),
                     st[0].cur.eq(d.cur), st[0].fold.eq(d.fold),
                     self.issue.eq(act & has & ~d.fold)]
        for k in range(1, self.LAT + 1):
            m.d.sync += st[k].eq(st[k - 1])
        m.d.comb += self.idle.eq(~act & ~iss.queued & ~Cat(*(s.e for s in st[1:])).any())
        return st, d

    def _distance(self, m: Module, st, d, ray_r):
        """k=0: ray read; k=1: register; k=2: ``split - org[axis]`` (FPAdd); then ``*
        inv[axis]`` (FPMul). Returns (dist, the stage ``kd`` where it is valid)."""
        w, add, mul = self.cfg.fmt.width, self.add, self.mul
        m.d.comb += ray_r.addr.eq(Cat(st[0].lane, st[0].thread))
        axis1, split1, axis2, split2 = Signal(2), Signal(w), Signal(2), Signal(w)
        ray2 = Signal(6 * w, reset_less=True)   # a block-RAM read: no reset (saarcor/flows/fpga/outreg.py)
        m.d.sync += [axis1.eq(d.axis), split1.eq(d.split), axis2.eq(axis1), split2.eq(split1),
                     ray2.eq(ray_r.data)]
        org = [ray2[i * w:(i + 1) * w] for i in range(3)]
        inv = [ray2[(3 + i) * w:(4 + i) * w] for i in range(3)]
        m.d.comb += [add.a.eq(split2), add.b.eq(Array(org)[axis2]), add.op.eq(1),
                     add.i_valid.eq(st[2].v)]
        inv_d = Array(inv)[axis2]
        for i in range(add.latency):
            nxt = Signal(w, name=f"inv_d{i}")
            m.d.sync += nxt.eq(inv_d)
            inv_d = nxt
        m.d.comb += [mul.a.eq(add.o), mul.b.eq(inv_d), mul.i_valid.eq(add.o_valid)]
        kd = 2 + add.latency + mul.latency          # stage where dist is valid
        assert kd == self.LAT - self.cmp_lat
        return mul.o, kd

    def _interval(self, m: Module, st, kd: int, n_r, s_r) -> Signal:
        """The lane's current interval (``tnear | tfar << w``), registered at stage ``kd``.
        Read two stages earlier and registered once, so it meets dist (the block RAM's output
        feeds only the slot mux and that register; no step of the same thread is in the
        pipeline, so reading earlier sees the same words). ``cfg.fast_clock``: four stages
        earlier (three, two when the pipeline has fewer), the block RAMs' outputs through two
        registers (the first has no other load, so it sits beside the RAM), then the slot mux
        into the interval register."""
        w = self.cfg.fmt.width
        rd = max(2, min(4, kd)) if self.cfg.fast_clock else 2
        m.d.comb += [n_r.addr.eq(Cat(st[kd - rd].lane, st[kd - rd].thread)),
                     s_r.addr.eq(Cat(st[kd - rd].lane,
                                     stack_entry(self.cfg, st[kd - rd].thread, st[kd - rd].sp)))]
        iv = Signal(2 * w)
        s_d, n_d = s_r.data, n_r.data
        for i in range(rd - 2):
            s_q, n_q = (Signal(self.s_width, name=f"s_d{i}", reset_less=True),
                        Signal(2 * w, name=f"n_d{i}", reset_less=True))
            m.d.sync += [s_q.eq(s_d), n_q.eq(n_d)]
            s_d, n_d = s_q, n_q
        m.d.sync += iv.eq(Mux(st[kd - 1].cur, self._popped(s_d, n_d), n_d))
        return iv

    def _popped(self, s_word, n_word) -> Value:
        """A popped lane's interval from its stack word and its ``N`` word: the far interval
        (two_values); one_value: ``[value, tfar]`` if the word's keep bit is 1, else ``[tfar,
        value]`` (``tfar``: N's, as the near subtree left it; ``model.traversal.popped``)."""
        if not self.one:
            return s_word
        w = self.cfg.fmt.width
        val, keep, tfar = s_word[:w], s_word[w], n_word[w:]
        return Mux(keep, Cat(val, tfar), Cat(tfar, val))

    def _classify(self, m: Module, st, dist, iv):
        """Stage ``kd``: ``max(tnear, dist)`` with ``dist < tnear`` (as ``tnear > dist``) and
        ``min(tfar, dist)`` with ``dist > tfar`` (as ``tfar < dist``): two comparators, each
        with the min or max it selects (:class:`~rtl.fp.FPMinMax`; ``cmp_lat`` cycles), so a
        trav-op costs an add, a multiply and two compares, the paper's 3 adds and 1 multiply
        with a compare counted as an add. At the write stage each lane's verdict joins its
        step's, which goes to the ``res`` queue with the step's last lane. Returns the words to
        write to ``N`` and ``S[sp]`` (two_values: the near and the far interval)."""
        fmt, R, c = self.cfg.fmt, self.R, self.cmp_lat
        w, kd = fmt.width, self.LAT - c
        m.submodules.vmin = vmin = FPMinMax(fmt, latency=c)
        m.submodules.vmax = vmax = FPMinMax(fmt, latency=c)
        tnear, tfar = iv[:w], iv[w:]
        m.d.comb += [vmin.a.eq(tfar), vmin.b.eq(dist), vmin.op.eq(0), vmin.i_valid.eq(st[kd].v),
                     vmax.a.eq(tnear), vmax.b.eq(dist), vmax.op.eq(1), vmax.i_valid.eq(st[kd].v)]
        tnear_d, tfar_d = tnear, tfar               # the interval, delayed to the write stage
        for i in range(c):
            tn, tf = Signal(w, name=f"tnear_d{i}"), Signal(w, name=f"tfar_d{i}")
            m.d.sync += [tn.eq(tnear_d), tf.eq(tfar_d)]
            tnear_d, tfar_d = tn, tf
        sw = st[self.LAT]
        near, far = Signal(R), Signal(R)            # this step's lanes so far
        near_n, far_n = Signal(R), Signal(R)
        bit = Mux(sw.v, Const(1, R) << sw.lane, 0)
        m.d.comb += [near_n.eq(near | Mux(~vmax.gt, bit, 0)),     # not (dist < tnear)
                     far_n.eq(far | Mux(~vmin.lt, bit, 0))]       # not (dist > tfar)
        m.submodules.results = rq = SyncFIFO(width=2 * R, depth=self.cfg.threads)
        m.d.comb += [rq.w_data.eq(Cat(near_n, far_n)), rq.w_en.eq(sw.e & sw.last),
                     self.res.payload.eq(rq.r_data), self.res.valid.eq(rq.r_rdy),
                     rq.r_en.eq(self.res.ready)]
        with m.If(sw.e):
            m.d.sync += [near.eq(Mux(sw.last, 0, near_n)), far.eq(Mux(sw.last, 0, far_n))]
        near_iv, far_iv = Cat(tnear_d, vmin.o), Cat(vmax.o, tfar_d)
        if not self.one:
            return near_iv, far_iv
        # one_value (model.traversal.push_one): a lane that needs the near child and whose
        # tfar the clip changes (dist < tfar) keeps tfar, any other max(tnear, dist) and the
        # keep bit; N gets the interval the lane goes on with (a fold: its interval as read)
        need_near, changed = ~vmax.gt, ~vmax.gt & vmin.gt
        s_word = Cat(Mux(changed, tfar_d, vmax.o), ~changed)
        n_word = Mux(sw.fold, Cat(tnear_d, tfar_d), Mux(need_near, near_iv, far_iv))
        return n_word, s_word

    def _write_n(self, m: Module, st, near_iv, n_w, ray_w, ah_w) -> None:
        """The write stage's near interval to ``N``, else the loader's lane (its interval to
        ``N``, its ray data and any-hit flag), which waits for ``ld_block``. ``cfg.fast_clock``:
        the loader's write a cycle later, from registers beside the memories (the loader's
        handshake, far away, ends at a register; it checked that the datapath does not write
        N in the cycle the write lands)."""
        K = self.LAT
        sw = st[K]
        m.d.comb += [self.ld_block.eq(sw.v), self.ld_block_next.eq(st[K - 1].v),
                     self.ld_block_next2.eq(st[K - 2].v)]
        ld = dict(en=self.ld_en, thread=self.ld_thread, lane=self.ld_lane,
                  org=self.ld_org.as_value(), inv=self.ld_inv.as_value(),
                  tnear=self.ld_tnear, tfar=self.ld_tfar, anyhit=self.ld_anyhit)
        if self.cfg.fast_clock:
            ld = registered(m, "ld_q", **ld)
        ld_addr = Cat(ld["lane"], ld["thread"])
        with m.If(sw.v):
            m.d.comb += [n_w.addr.eq(Cat(sw.lane, sw.thread)), n_w.data.eq(near_iv),
                         n_w.en.eq(1)]
        with m.Else():
            m.d.comb += [n_w.addr.eq(ld_addr), n_w.data.eq(Cat(ld["tnear"], ld["tfar"])),
                         n_w.en.eq(ld["en"])]
        m.d.comb += [ray_w.addr.eq(ld_addr), ray_w.data.eq(Cat(ld["org"], ld["inv"])),
                     ray_w.en.eq(ld["en"] & ~sw.v),
                     ah_w.addr.eq(ld_addr), ah_w.data.eq(ld["anyhit"]),
                     ah_w.en.eq(ld["en"] & ~sw.v)]

    def _request(self, m: Module, n_rq, s_rq, ah_r) -> None:
        """The result side's read: both slots' ``tfar`` and ``anyhit``, ``RQ_LAT`` cycles
        later (the block RAMs' outputs straight into registers when more than 1)."""
        w = self.cfg.fmt.width
        m.d.comb += [n_rq.addr.eq(Cat(self.rq_lane, self.rq_thread)),
                     s_rq.addr.eq(Cat(self.rq_lane,
                                      stack_entry(self.cfg, self.rq_thread, self.rq_sp))),
                     ah_r.addr.eq(Cat(self.rq_lane, self.rq_thread))]
        cur_d = Signal()
        m.d.sync += cur_d.eq(self.rq_cur)
        s_tfar, n_tfar, anyhit = self._popped(s_rq.data, n_rq.data)[w:], n_rq.data[w:], ah_r.data
        for i in range(self.RQ_LAT - 1):
            regs = (Signal(w, name=f"rq{i}_s_tfar", reset_less=True),
                    Signal(w, name=f"rq{i}_n_tfar", reset_less=True), Signal(name=f"rq{i}_ah"))
            cur_dd = Signal(name=f"rq{i}_cur")
            m.d.sync += [regs[0].eq(s_tfar), regs[1].eq(n_tfar), regs[2].eq(anyhit),
                         cur_dd.eq(cur_d)]
            (s_tfar, n_tfar, anyhit), cur_d = regs, cur_dd
        m.d.comb += [self.rq_tfar.eq(Mux(cur_d, s_tfar, n_tfar)), self.rq_anyhit.eq(anyhit),
                     self.rq_s_tfar.eq(s_tfar), self.rq_n_tfar.eq(n_tfar),
                     self.rq_slot.eq(cur_d)]


class _Threads:
    """The per-thread registers every engine of :class:`Traversal` reads and writes: one
    register per thread for each field (threads are indexed by a thread id)."""

    def __init__(self, cfg: Config, packet_bits: int):
        T, L = cfg.threads, cfg.packet_size
        db = stack_bits(cfg)
        self.fast, self.tbits, self.writes = cfg.fast_clock, cfg.thread_bits, {}
        self.shadows = []                     # (states, per-thread flags): in_states_q

        def per_thread(shape, name, init=0):
            return Array(Value.cast(Signal(shape, name=f"{name}{t}", init=init))
                         for t in range(T))
        self.T = T
        self.state = per_thread(ThreadState, "state", ThreadState.FREE)
        self.node = per_thread(NODE_BITS, "node")         # node to fetch / being worked on
        self.word = per_thread(WORD_BITS, "word")         # its 64-bit word
        self.mask = per_thread(L, "mask")                 # active lanes
        self.term = per_thread(L, "term")                 # terminated lanes
        self.sp = per_thread(db, "sp")                    # stack pointer
        self.cur = per_thread(1, "cur")                   # intervals in N (0) or S[sp] (1)
        self.octant = per_thread(3, "oct")                # the pass's octant
        self.todo = per_thread(8, "todo")                 # octant passes still to run
        self.packet = per_thread(packet_bits, "packet")
        self.lanes = per_thread(L, "lanes")               # lanes the packet has (readout)

    def in_state(self, s: ThreadState) -> Value:
        """One bit per thread: the thread is in state ``s``."""
        return Cat(*(self.state[t] == s for t in range(self.T)))

    def in_states_q(self, *states: ThreadState) -> Value:
        """One bit per thread: the thread is in one of ``states``, from a register per thread
        kept beside the state (``fast`` only; written by :meth:`finish` with the state, so it
        always equals the decode of the state register, without the decode's LUT level)."""
        assert self.fast
        names = "_".join(s.name.lower() for s in states)
        flags = [Signal(name=f"state{t}_{names}", init=int(ThreadState.FREE in states))
                 for t in range(self.T)]
        self.shadows.append((states, flags))
        return Cat(*flags)

    def set(self, m: Module, field: str, thread: Value, value, onehot: Value | None = None) -> None:
        """``field[thread] = value`` at the next clock edge, in the caller's ``If`` context.

        Each engine moves only the threads in the states it owns, so no two engines write one
        thread's field in one cycle; with ``fast`` the writes are therefore combined as an
        AND-OR per thread (:meth:`finish`) instead of a chain of one priority mux per writer.
        ``onehot`` (``fast`` only; called outside any ``If``): the writer's per-thread write
        enables, e.g. a register set a cycle ahead, instead of the ``If`` context and
        ``thread``.
        """
        reg = getattr(self, field)
        if not self.fast:
            m.d.sync += reg[thread].eq(value)
            return
        writes = self.writes.setdefault(field, [])
        i = len(writes)
        val = Signal.like(reg[0], name=f"{field}_w{i}_value")
        m.d.comb += val.eq(value)
        if onehot is not None:
            writes.append((None, None, val, onehot))
            return
        req = Signal(name=f"{field}_w{i}")
        tgt = Signal(self.tbits, name=f"{field}_w{i}_thread")
        m.d.comb += [req.eq(1), tgt.eq(thread)]
        writes.append((req, tgt, val, None))

    def set_state(self, m: Module, thread: Value, value) -> None:
        self.set(m, "state", thread, value)

    def finish(self, m: Module) -> None:
        """The combined writes (``fast``; nothing to do otherwise)."""
        if not self.fast:
            return
        for field, writes in self.writes.items():
            reg = getattr(self, field)
            for t in range(self.T):
                hit = [Signal(name=f"{field}{t}_w{i}") for i in range(len(writes))]
                m.d.comb += [h.eq(req & (tgt == t) if onehot is None else onehot[t])
                             for h, (req, tgt, _, onehot) in zip(hit, writes)]
                nxt = 0
                for h, (_, _, val, _) in zip(hit, writes):
                    nxt = nxt | Mux(h, Value.cast(val), 0)
                with m.If(Cat(*hit).any()):
                    m.d.sync += reg[t].eq(nxt)
                    if field == "state":        # one writer at a time: OR of its verdicts
                        for states, flags in self.shadows:
                            m.d.sync += flags[t].eq(Cat(*(
                                h & _among(val, states)
                                for h, (_, _, val, _) in zip(hit, writes))).any())


def _among(value: Value, states) -> Value:
    """``value`` is one of ``states``."""
    return Cat(*(Value.cast(value) == Value.cast(st) for st in states)).any()


def packet_step_layout(cfg: Config) -> data.StructLayout:
    """An inner-node step as the control engine dispatches it: the thread, its node word, its
    active lanes, stack pointer and interval slot (``cur``), and the near child's side
    (``neg``: the pass's octant bit on the node's axis); ``fold``: a fold, not a step."""
    return data.StructLayout({"thread": cfg.thread_bits, "word": node_layout(),
                              "mask": cfg.packet_size, "sp": stack_bits(cfg), "cur": 1,
                              "neg": 1, "fold": 1})


def order_layout(cfg: Config) -> data.StructLayout:
    """An outstanding step as the decide engine needs it: the thread, the node's near and far
    children and the stack pointer (none of them changes while the step is out)."""
    return data.StructLayout({"thread": cfg.thread_bits, "near": NODE_BITS, "far": NODE_BITS,
                              "sp": stack_bits(cfg), "fold": 1})


def decision_layout(cfg: Config) -> data.StructLayout:
    """A decided step: the thread's next stack pointer, node, active lanes, slot and state."""
    return data.StructLayout({"thread": cfg.thread_bits, "sp": stack_bits(cfg),
                              "node": NODE_BITS, "mask": cfg.packet_size, "cur": 1,
                              "state": ThreadState})


def push_layout(cfg: Config) -> data.StructLayout:
    """A stack entry to write at (thread, sp): the far child and the lanes that need it."""
    return data.StructLayout({"sp": stack_bits(cfg), "thread": cfg.thread_bits,
                              "node": NODE_BITS, "mask": cfg.packet_size})


class StepDispatch(wiring.Component):
    """The control engine's steps to the sub-units. A step taken on ``i`` goes in the same
    cycle to every sub-unit's step queue (``sub[j]``: lanes ``j R .. j R + R - 1`` of the
    mask, the split plane in the unit's format) and, with the node's near and far children,
    to ``order`` (the decide engine's queue of outstanding steps, as deep as the threads: never
    full, its ready is not read). Room (``i.ready``): always with queues (``queue`` entries) as deep as the
    threads; synchronous sub-units take each step together, so their queues hold the same
    steps and the first one's room is every one's (no path across them); asynchronous ones:
    every queue's room. Combinational: latency 0, one step per cycle."""

    def __init__(self, cfg: Config, *, queue: int):
        self.cfg, self.queue = cfg, queue
        super().__init__({
            "i": In(stream.Signature(packet_step_layout(cfg))),
            "sub": Out(stream.Signature(step_layout(cfg))).array(cfg.trav_subunits),
            "order": Out(stream.Signature(order_layout(cfg))),
        })

    def elaborate(self, platform):
        m = Module()
        cfg, R, p = self.cfg, self.cfg.rays_per_subunit, self.i.payload
        if self.queue >= cfg.threads:
            room = Const(1)
        elif cfg.trav_sync:
            room = self.sub[0].ready
        else:
            room = Cat(*(s.ready for s in self.sub)).all()
        disp = Signal()                              # push a step to every sub-unit
        m.d.comb += [self.i.ready.eq(room), disp.eq(self.i.valid & room)]
        o = self.order.payload
        m.d.comb += [o.thread.eq(p.thread), o.near.eq((p.word.index + p.neg)[:NODE_BITS]),
                     o.far.eq((p.word.index + 1 - p.neg)[:NODE_BITS]), o.sp.eq(p.sp),
                     o.fold.eq(p.fold), self.order.valid.eq(disp)]
        for j, s in enumerate(self.sub):
            m.d.comb += [s.payload.mask.eq(p.mask[j * R:(j + 1) * R]),
                         s.payload.thread.eq(p.thread), s.payload.axis.eq(p.word.axis),
                         s.payload.split.eq(from_binary32(cfg.fmt, p.word.value)),
                         s.payload.sp.eq(p.sp), s.payload.cur.eq(p.cur),
                         s.payload.fold.eq(p.fold), s.valid.eq(disp)]
        return m


class StepDecide(wiring.Component):
    """The decide engine: the oldest outstanding step (the head of ``order``, a queue of
    ``cfg.threads`` entries), once every sub-unit's verdict (``res[j]``) is in: both children
    -> push the far one (``push``: the entry at the thread's sp) and go near; near only; far
    only; none ends the pass (NEXTPASS), as ``model.traversal.decide``; a fold (``trav_stack =
    "one_value"``) returns its thread to POP. ``wr``: the thread's next fields, one write
    each; ``pushes`` counts the pushes.

    Latency: ``wr`` and ``push`` in the cycle the last verdict is at the queues' heads (a
    cycle later with ``cfg.fast_clock``: the heads and the thread's next fields go through
    registers; no other engine touches a thread in STEP, so its stack pointer, read a cycle
    before, is still its own). Throughput: one step per cycle."""

    def __init__(self, cfg: Config):
        self.cfg = cfg
        super().__init__({
            "order": In(stream.Signature(order_layout(cfg))),
            "res": In(stream.Signature(step_result_layout(cfg))).array(cfg.trav_subunits),
            "wr": Out(stream.Signature(decision_layout(cfg), always_ready=True)),
            "push": Out(stream.Signature(push_layout(cfg), always_ready=True)),
            "pushes": Out(COUNTER_BITS),
        })

    def elaborate(self, platform):
        m = Module()
        olay = order_layout(self.cfg)
        m.submodules.order = order = SyncFIFO(width=olay.size, depth=self.cfg.threads)
        m.d.comb += [order.w_data.eq(self.order.payload), order.w_en.eq(self.order.valid),
                     self.order.ready.eq(order.w_rdy)]
        head = olay(order.r_data)
        dec = Signal()
        m.d.comb += dec.eq(order.r_rdy & Cat(*(r.valid for r in self.res)).all())
        m.d.comb += [order.r_en.eq(dec)] + [r.ready.eq(dec) for r in self.res]
        mn = Cat(*(r.payload.near for r in self.res))
        mf = Cat(*(r.payload.far for r in self.res))
        n_any, f_any = mn.any(), mf.any()
        both, d_sp = n_any & f_any, head.sp
        new = dict(sp=Mux(both, d_sp + 1, d_sp)[:len(d_sp)],
                   node=Mux(n_any, head.near, head.far), mask=Mux(n_any, mn, mf), cur=~n_any,
                   state=Mux(n_any | f_any, ThreadState.FETCH, ThreadState.NEXTPASS))
        if self.cfg.trav_stack == "one_value":
            # every lane's next interval is in N; a fold (its verdicts mean nothing) returns
            # the thread to POP with its intervals in N
            fold = head.fold
            both = both & ~fold
            new = dict(sp=Mux(both, d_sp + 1, d_sp)[:len(d_sp)], node=new["node"],
                       mask=Mux(fold, 0, new["mask"]), cur=Const(0),
                       state=Mux(fold, ThreadState.POP, new["state"]))
        v = dict(v=dec, thread=head.thread, both=both, far_node=head.far, far=mf, sp=d_sp,
                 **{f"new_{k}": x for k, x in new.items()})
        if self.cfg.fast_clock:
            v = registered(m, "dec", **v)
        w, p = self.wr.payload, self.push.payload
        m.d.comb += [self.wr.valid.eq(v["v"]), w.thread.eq(v["thread"]),
                     *(w[k].eq(v[f"new_{k}"]) for k in new)]
        with m.If(v["v"] & v["both"]):
            m.d.comb += [self.push.valid.eq(1), p.sp.eq(v["sp"]), p.thread.eq(v["thread"]),
                         p.node.eq(v["far_node"]), p.mask.eq(v["far"])]
            m.d.sync += self.pushes.eq(self.pushes + 1)
        return m


WAIT_STATES = (ThreadState.HAVE_NODE, ThreadState.POP, ThreadState.NEXTPASS)


class _ControlEngine:
    """The control engine (default clock). IDLE: picks a thread waiting in HAVE_NODE, POP or
    NEXTPASS (round-robin) and loads its fields into the engine's registers (``e_*``).
    DISPATCH: an inner node's step goes to ``step`` once the sub-units have room (STEP); a
    non-empty leaf to LEAF (a ``LeafRequest`` on ``leaf``, then WAIT_LEAF); an empty leaf or a
    finished one to POP; NEXTPASS to PASS. POP: one stack entry per 2 cycles until one has a
    live lane (FETCH its node; intervals in ``S[sp]``) or the stack is empty (PASS). PASS:
    the lowest octant left starts a pass from the root (FETCH) or, none left, DONE. 2 cycles
    per event; the thread is written (state, fields) in the cycle the engine leaves it.

    Not a component: it reads the picked thread's fields from, and writes them back into, the
    per-thread registers every engine shares (:class:`_Threads`), in the unit's module.
    :class:`_FastControlEngine` overrides the stages that ``cfg.fast_clock`` changes."""

    def __init__(self, trav: Traversal, m: Module, th: _Threads, step, leaf, st_r, pm_r):
        cfg = trav.cfg
        self.trav, self.m, self.th, self.cfg = trav, m, th, cfg
        self.step, self.leaf, self.st_r, self.pm_r = step, leaf, st_r, pm_r
        L, tb = cfg.packet_size, cfg.thread_bits
        self.ptr, self.t = Signal(tb, name="e_ptr"), Signal(tb, name="e_t")
        self.busy = Signal(name="ctl_busy")          # the engine works on thread e_t
        self.pick_any, self.pick_idx, self.read = self.pick()
        self.kind = Signal(ThreadState, name="e_kind")
        self.word = Signal(node_layout(), name="e_word")
        self.mask, self.sp = Signal(L, name="e_mask"), Signal(stack_bits(cfg), name="e_sp")
        self.cur, self.neg = Signal(name="e_cur"), Signal(name="e_neg")
        self.oct = Signal(3, name="e_oct")           # the octant a new pass starts
        self.todo, self.term = self.thread_masks()   # octants to do, terminated lanes
        self.oct_any, self.oct_next = lowest(m, self.todo, "pass")
        self.st_data, self.pm_data = self.late(st_r.data, "st_q"), self.late(pm_r.data, "pm_q")
        self.popped = self.st_data[NODE_BITS:] & ~self.term   # the entry's live lanes
        # what the engine writes into thread e_t, set in the FSM
        self.w_state, self.w_state_we = Signal(ThreadState, name="ctl_state"), Signal()
        self.w_fields = {f: Signal.like(getattr(th, f)[0], name=f"ctl_{f}")
                         for f in ("node", "mask", "sp", "cur")}
        self.w_fields_we = Signal()
        s, lf = step.payload, leaf.payload
        self.fold = Signal(name="e_fold")            # POP offers a fold (one_value)
        m.d.comb += [s.thread.eq(self.t), s.word.eq(self.word), s.mask.eq(self.mask),
                     s.sp.eq(self.sp), s.cur.eq(self.cur), s.neg.eq(self.neg),
                     s.fold.eq(self.fold),
                     lf.thread.eq(self.t), lf.first.eq(self.word.value),
                     lf.count.eq(self.word.index), lf.mask.eq(self.mask)]

    # ---- the stages that cfg.fast_clock changes (see _FastControlEngine)
    def pick(self):
        """(any, index, read) of the round-robin pick among the waiting threads; ``read(arr,
        copy)`` is the picked thread's element of a per-thread ``Array`` (or bit)."""
        th = self.th
        waiting = Cat(*(_among(th.state[t], WAIT_STATES) for t in range(th.T)))
        e_any, e_idx = rr_pick(self.m, waiting, self.ptr, "step")
        return e_any, e_idx, lambda arr, copy=0: element(arr, e_idx)

    def thread_masks(self):
        """The thread's octants to do and its terminated lanes, read where they are."""
        return self.th.todo[self.t], self.th.term[self.t]

    def late(self, value, name: str):
        """A block RAM's output as the engine uses it: straight, a cycle after the read."""
        return value

    def goto(self, state: str) -> None:
        self.m.next = state

    def offer_step(self) -> None:
        """In DISPATCH at an inner node: the step is offered to the sub-units."""
        self.m.d.comb += self.step.valid.eq(1)

    def pop_read(self, node, mask, live):
        """The state that uses the popped entry (node, live lanes, any live): POP2, as read."""
        return "POP2", node, mask, live

    def write_todo(self, todo) -> None:
        """PASS: the thread's octants left."""
        self.m.d.sync += self.th.todo[self.t].eq(todo)

    def pass_read(self) -> str:
        """The state that uses the pass masks read in PASS: PASS2."""
        return "PASS2"

    def write_back(self) -> None:
        """The writes of thread e_t the FSM asked for: one write per field."""
        m, th = self.m, self.th
        with m.If(self.w_state_we):
            th.set_state(m, self.t, self.w_state)
        with m.If(self.w_fields_we):
            for f, v in self.w_fields.items():
                th.set(m, f, self.t, v)

    def count_busy(self, busy):
        """The ``busy`` counter's enable."""
        return busy

    # ---- the state machine
    def set_state(self, v) -> None:
        self.m.d.comb += [self.w_state_we.eq(1), self.w_state.eq(v)]

    def set_fields(self, **values) -> None:
        self.m.d.comb += [self.w_fields_we.eq(1),
                          *(self.w_fields[f].eq(v) for f, v in values.items())]

    def load(self) -> None:
        """IDLE with a pick: the thread's fields into the engine's registers. The node word's
        low 48 bits are read with the pick's copy 0, the rest with copy 1 (fast_clock: two
        copies of the registered pick, each drives half of the multiplexers)."""
        th, read, idx = self.th, self.read, self.pick_idx
        # the near child's side per thread (its octant's bit on its node's axis), taken at the
        # pick with the node word, so the children's sums (StepDispatch) start at registers
        is_neg = Cat(*(th.octant[t].bit_select(data.View(node_layout(), th.word[t]).axis, 1)
                       for t in range(th.T)))
        word = Cat(read(th.word, 0)[:48], read(th.word, 1)[48:])
        self.m.d.sync += [self.t.eq(idx), self.kind.eq(read(th.state, 1)),
                          self.word.eq(word), self.mask.eq(read(th.mask, 1)),
                          self.neg.eq(read(is_neg, 1)), self.sp.eq(read(th.sp, 1)),
                          self.cur.eq(read(th.cur, 1)), self.ptr.eq(idx + 1)]

    def fsm(self) -> None:
        m = self.m
        m.d.comb += self.busy.eq(1)
        with m.FSM(name="step") as self.states:
            with m.State("IDLE"):
                m.d.comb += self.busy.eq(0)
                with m.If(self.pick_any):
                    self.load()
                    self.goto("DISPATCH")
            with m.State("DISPATCH"):
                self.dispatch()
            with m.State("LEAF"):
                m.d.comb += self.leaf.valid.eq(1)
                with m.If(self.leaf.ready):
                    self.set_state(ThreadState.WAIT_LEAF)
                    self.goto("IDLE")
            self.pop()
            self.next_pass()

    def dispatch(self) -> None:
        m, trav = self.m, self.trav
        with m.If(self.kind == ThreadState.HAVE_NODE):
            with m.If(self.word.axis != LEAF):
                self.offer_step()
                with m.If(self.step.ready):
                    m.d.sync += trav.trav_steps.eq(trav.trav_steps + 1)
                    self.set_state(ThreadState.STEP)
                    self.goto("IDLE")
            with m.Elif(self.word.index != 0):
                self.goto("LEAF")
            with m.Else():
                self.goto("POP")
        with m.Elif(self.kind == ThreadState.POP):
            self.goto("POP")
        with m.Else():
            self.goto("PASS")

    def pop(self) -> None:
        """POP reads entry sp - 1 (none: PASS); the state ``pop_read`` names uses it.

        ``trav_stack = "one_value"``: a thread whose intervals are a popped entry's (``cur``,
        its node was a leaf) and whose stack is not empty first folds them into ``N`` (a step
        with ``fold``: STEP, then the decide engine returns it to POP), as the next pop's
        lanes take their ``tnear`` from the ``tfar`` the entry gave them."""
        m, db = self.m, stack_bits(self.cfg)
        with m.State("POP"):
            fold = (self.cur & (self.sp != 0)) if self.cfg.trav_stack == "one_value" else 0
            with m.If(fold):
                m.d.comb += [self.fold.eq(1), self.step.valid.eq(1)]
                with m.If(self.step.ready):
                    self.set_state(ThreadState.STEP)
                    self.goto("IDLE")
            with m.Elif(self.sp == 0):
                self.goto("PASS")
            with m.Else():
                m.d.comb += self.st_r.addr.eq(stack_entry(self.cfg, self.t, (self.sp - 1)[:db]))
                m.d.sync += self.sp.eq(self.sp - 1)
                self.goto("POP2")
        state, node, mask, live = self.pop_read(self.st_data[:NODE_BITS], self.popped,
                                                self.popped.any())
        with m.State(state):
            with m.If(live):
                self.set_fields(node=node, mask=mask, sp=self.sp, cur=1)
                self.set_state(ThreadState.FETCH)
                self.goto("IDLE")
            with m.Else():
                self.goto("POP")

    def next_pass(self) -> None:
        """PASS takes the lowest octant left and reads the pass masks; the state
        ``pass_read`` names starts the pass from the root with that octant's lanes."""
        m, th, trav, L = self.m, self.th, self.trav, self.cfg.packet_size
        with m.State("PASS"):
            with m.If(~self.oct_any):
                self.set_state(ThreadState.DONE)
                self.goto("IDLE")
            with m.Else():
                m.d.comb += self.pm_r.addr.eq(self.t)
                m.d.sync += self.oct.eq(self.oct_next)
                self.write_todo(self.todo & ~(Const(1, 8) << self.oct_next))
                self.goto("PASS2")
        with m.State(self.pass_read()):
            m.d.sync += [th.octant[self.t].eq(self.oct), trav.passes.eq(trav.passes + 1)]
            self.set_fields(mask=self.pm_data.word_select(self.oct, L), node=trav.root, sp=0,
                            cur=0)
            self.set_state(ThreadState.FETCH)
            self.goto("IDLE")


class _FastControlEngine(_ControlEngine):
    """The control engine with ``cfg.fast_clock``: the same events, and a pop and a pass take
    a cycle more each. Per stage:

    * pick: made a cycle ahead into registers from the registered state flags, with and
      without the thread being worked on (only this engine moves a thread out of the waiting
      states); ``ctl_busy``, registered, chooses; the picked thread's fields (about 100 bits)
      are read with two copies of the registered pick;
    * the thread's octants to do are copied at the pick (only this engine changes them), its
      terminated lanes in every cycle from e_t (they hold while the thread is the engine's; the
      first use, POP3, comes three cycles after the pick);
    * the stack entry and the pass masks: the block RAMs' outputs straight into registers
      (POP2 -> POP3, PASS2 -> PASS3); POP3 registers the entry's live lanes, POP4 uses them;
    * the thread's writes: from registered one-hot state flags (one per writing state, set with
      each transition) and e_t's one-hot register, not from the FSM's state decode; the
      fields' per-thread enables from a register set a cycle ahead (POP4 and PASS3 are
      entered unconditionally from POP3 and PASS2); the octants left from a register in PASS3;
    * the ``busy`` counter counts a cycle later, from a register (its 32 enables do not hang on
      the verdict queues' handshake; the total is the same once the unit is idle)."""

    def __init__(self, *args):
        super().__init__(*args)
        T = self.cfg.threads
        self.flags = {k: Signal(name=f"step_in_{k.lower()}")
                      for k in ("DISPATCH", "LEAF", "POP4", "PASS", "PASS3")}
        # DISPATCH's "a step" (an inner node) taken at the pick from a per-thread form; PASS's
        # "no octant left" a cycle after it (PASS comes two cycles after the pick at the
        # earliest; e_todo holds from the pick on); the octants left, written in PASS3
        self.is_step = Signal(name="e_step")
        self.todo_none, self.todo_left = Signal(name="e_todo_none"), Signal(8, name="e_todo_left")
        self.hits = Signal(T, name="ctl_fields_hit")

    def pick(self):
        self.taken = Signal(self.th.T, name="e_taken")     # e_t one-hot
        waiting = self.th.in_states_q(*WAIT_STATES)
        e_any, e_idx, self.pick_oh, read = rr_pick_next(self.m, waiting, self.ptr, self.busy,
                                                        "step", taken=self.taken, copies=2)
        return e_any, e_idx, read

    def thread_masks(self):
        todo, term = Signal(8, name="e_todo"), Signal(self.cfg.packet_size, name="e_term")
        self.m.d.sync += term.eq(self.th.term[self.t])
        return todo, term

    def late(self, value, name: str):
        """The block RAM's output registered (no reset), used a cycle later."""
        q = Signal.like(value, name=name, reset_less=True)
        self.m.d.sync += q.eq(value)
        return q

    def goto(self, state: str) -> None:
        super().goto(state)
        self.m.d.sync += [f.eq(int(k == state)) for k, f in self.flags.items()]

    def offer_step(self) -> None:
        pass                            # from the flags (write_back)

    def load(self) -> None:
        super().load()
        th, read = self.th, self.read
        is_step = Cat(*((th.state[t] == ThreadState.HAVE_NODE) &
                        (data.View(node_layout(), th.word[t]).axis != LEAF)
                        for t in range(th.T)))
        self.m.d.sync += [self.todo.eq(read(th.todo, 1)), self.taken.eq(self.pick_oh),
                          self.is_step.eq(read(is_step, 1))]

    def pop_read(self, node, mask, live):
        """POP2: the entry is read; POP3: its live lanes, registered; POP4 uses them."""
        m = self.m
        with m.State("POP2"):
            self.goto("POP3")
        regs = (Signal(NODE_BITS, name="pop_node"), Signal(len(mask), name="pop_mask"),
                Signal(name="pop_any"))
        with m.State("POP3"):
            m.d.sync += [r.eq(v) for r, v in zip(regs, (node, mask, live))]
            self.goto("POP4")
        self.pop_any = regs[2]
        return ("POP4", *regs)

    def write_todo(self, todo) -> None:
        self.m.d.sync += self.todo_left.eq(todo)

    def pass_read(self) -> str:
        with self.m.State("PASS2"):
            self.goto("PASS3")
        return "PASS3"

    def write_back(self) -> None:
        """The writes from the flags and registers only; the per-thread enables: e_t's one-hot
        register. STEP and WAIT_LEAF are written in every cycle of DISPATCH (a step) and LEAF,
        also while they wait for the sub-units' room or the leaf output: the same value, and
        nothing reads a thread's STEP or WAIT_LEAF before its step or leaf request is out (the
        engine's own next pick leaves out the thread it works on)."""
        m, th, flags, T = self.m, self.th, self.flags, self.cfg.threads
        m.d.comb += self.step.valid.eq(flags["DISPATCH"] & self.is_step)
        we = ((flags["DISPATCH"] & self.is_step) | flags["LEAF"] |
              (flags["POP4"] & self.pop_any) | (flags["PASS"] & self.todo_none) |
              flags["PASS3"])
        val = Mux(flags["DISPATCH"], ThreadState.STEP,
                  Mux(flags["LEAF"], ThreadState.WAIT_LEAF,
                      Mux(flags["PASS"], ThreadState.DONE, ThreadState.FETCH)))
        th.set(m, "state", None, val, onehot=Mux(we, self.taken, 0))
        we_next = (self.states.ongoing("POP3") & self.popped.any()) | \
            self.states.ongoing("PASS2")
        m.d.sync += self.hits.eq(Mux(we_next, Const(1, T) << self.t, 0)[:T])
        for f, v in self.w_fields.items():
            th.set(m, f, self.t, v, onehot=self.hits)
        for t in range(T):
            with m.If(flags["PASS3"] & self.taken[t]):
                m.d.sync += th.todo[t].eq(self.todo_left)
        m.d.sync += self.todo_none.eq(self.todo == 0)

    def count_busy(self, busy):
        return registered(self.m, "busy", inc=busy)["inc"]



class _Loader:
    """The loader (default clock): takes the lowest free thread (LOAD) and writes ``RayIn``
    lanes into it, one per cycle (``load_thread`` says which thread): each lane's ray data
    and interval into its sub-unit (held while the sub-unit's datapath writes ``N``:
    ``ld_block``), its octant into the thread's pass masks (live rays only: tnear <= tfar).
    With the packet's last lane the pass masks go to ``pm_w`` and the thread to NEXTPASS, with
    its packet, lanes and the passes to run (``todo``).

    Not a component: it writes the per-thread registers every engine shares
    (:class:`_Threads`), in the unit's module. :class:`_FastLoader` overrides the stages
    ``cfg.fast_clock`` changes."""

    def __init__(self, trav: Traversal, m: Module, th: _Threads, pm_w):
        self.trav, self.m, self.th, self.cfg, self.pm_w = trav, m, th, trav.cfg, pm_w
        self.active = Signal(name="ld_active")
        self.thread = Signal(trav.cfg.thread_bits, name="ld_thread")
        self.live_in = compare(trav.cfg.fmt, trav.rays.payload.tnear, trav.rays.payload.tfar).le

    def build(self) -> None:
        m, trav, L, pm_w = self.m, self.trav, self.cfg.packet_size, self.pm_w
        self.claim()
        valid, p, live, lane_one, oct_one = self.lane_in()
        lane_sub, lane_loc = trav._split_lane(m, p.lane, "ld")
        blocked = self.blocked(p, lane_sub)
        ready = Signal()                    # the loader writes the lane this cycle if valid
        m.d.comb += [ready.eq(self.active & ~blocked), trav.load_thread.eq(self.thread)]
        take = valid & ready
        self.accept(ready, take)
        # per octant: its lanes so far (acc) and whether it has any (acc_any)
        acc = [Signal(L, name=f"acc{o}") for o in range(8)]
        acc_lanes, acc_any = Signal(L, name="acc_lanes"), Signal(8, name="acc_any")
        acc_new = [Signal(L, name=f"acc_new{o}") for o in range(8)]
        for o in range(8):
            m.d.comb += acc_new[o].eq(acc[o] | Mux(oct_one[o] & live, lane_one, 0))
        acc_any_new = acc_any | Mux(live, oct_one, 0)
        for j, s in enumerate(trav.subunits):
            m.d.comb += [s.ld_en.eq(take & (lane_sub == j)), s.ld_thread.eq(self.thread),
                         s.ld_lane.eq(lane_loc), s.ld_org.eq(p.org), s.ld_inv.eq(p.inv),
                         s.ld_tnear.eq(p.tnear), s.ld_tfar.eq(p.tfar), s.ld_anyhit.eq(p.anyhit)]
        m.d.comb += [pm_w.addr.eq(self.thread), pm_w.data.eq(Cat(*acc_new))]
        with m.If(take):
            m.d.sync += [acc_lanes.eq(acc_lanes | lane_one), acc_any.eq(acc_any_new)]
            m.d.sync += [acc[o].eq(acc_new[o]) for o in range(8)]
            with m.If(p.last):
                m.d.comb += pm_w.en.eq(1)
                m.d.sync += [self.active.eq(0), acc_lanes.eq(0), acc_any.eq(0)]
                m.d.sync += [acc[o].eq(0) for o in range(8)]
        self.loaded(take, p, acc_lanes | lane_one, acc_any_new)

    # ---- the stages that cfg.fast_clock changes (see _FastLoader)
    def claim(self) -> None:
        """The lowest free thread, when the loader has none, turns LOAD."""
        m, th = self.m, self.th
        free_any, free_idx = lowest(m, th.in_state(ThreadState.FREE), "free")
        with m.If(~self.active & free_any):
            m.d.sync += [self.active.eq(1), self.thread.eq(free_idx)]
            th.set_state(m, free_idx, ThreadState.LOAD)

    def lane_in(self):
        """(valid, payload, live, lane one-hot, octant one-hot) of the lane offered now."""
        rays, L = self.trav.rays, self.cfg.packet_size
        lane_one, oct_one = Signal(L, name="lane_one"), Signal(8, name="oct_one")
        self.m.d.comb += [lane_one.eq(Const(1, L) << rays.payload.lane),
                          oct_one.eq(Const(1, 8) << rays.payload.octant)]
        return rays.valid, rays.payload, self.live_in, lane_one, oct_one

    def blocked(self, p, lane_sub) -> Value:
        """The lane's sub-unit writes ``N`` in this cycle."""
        subs = self.trav.subunits
        return Array(s.ld_block for s in subs)[lane_sub] if len(subs) > 1 else subs[0].ld_block

    def accept(self, ready, take) -> None:
        """``rays.ready``: the lane is written in this cycle."""
        self.m.d.comb += self.trav.rays.ready.eq(ready)

    def loaded(self, take, p, lanes, todo) -> None:
        """The thread's fields: its packet with each lane; with the last lane its lanes, the
        passes to run, no lane terminated, NEXTPASS."""
        m, th, t = self.m, self.th, self.thread
        with m.If(take):
            m.d.sync += th.packet[t].eq(p.packet)
            with m.If(p.last):
                th.set_state(m, t, ThreadState.NEXTPASS)
                m.d.sync += [th.lanes[t].eq(lanes), th.todo[t].eq(todo), th.term[t].eq(0)]


class _FastLoader(_Loader):
    """The loader with ``cfg.fast_clock``. Per stage:

    * claim: the free threads from the registered flags beside the states (no decode); the
      state write's per-thread enables: the lowest free thread, one-hot;
    * lane in: the lane waits in an input register with its live bit, its lane and octant
      one-hot precomputed; a packet's lanes are taken while the loader has its thread (no lane
      of the next packet before this one's last lane is written);
    * blocked: the input lane's sub-unit's block in the cycle after (when its write lands,
      from the sub-unit's registers), registered a cycle ahead: the sub-units' pipelines never
      stall, and the lane in the input register next cycle is known now;
    * loaded: the thread's fields are written a cycle after its last lane, from registers and
      by the thread's one-hot (the thread stays LOAD until then: no engine reads it)."""

    def claim(self) -> None:
        m, th = self.m, self.th
        free = th.in_states_q(ThreadState.FREE)
        free_any, free_idx = lowest(m, free, "free")
        self.onehot = Signal(th.T, name="ld_onehot")      # ld_thread one-hot
        with m.If(~self.active & free_any):
            m.d.sync += [self.active.eq(1), self.thread.eq(free_idx),
                         self.onehot.eq(lowest_onehot(free))]
        th.set(m, "state", None, ThreadState.LOAD,
               onehot=Mux(~self.active, lowest_onehot(free), 0))

    def lane_in(self):
        L = self.cfg.packet_size
        self.valid, self.got_last = Signal(name="ld_in_valid"), Signal(name="ld_got_last")
        self.p = Signal.like(self.trav.rays.payload, name="ld_in")
        self.live = Signal(name="ld_in_live")
        self.lane_one = Signal(L, name="ld_in_lane_one")
        self.oct_one = Signal(8, name="ld_in_oct_one")
        return self.valid, self.p, self.live, self.lane_one, self.oct_one

    def blocked(self, p, lane_sub) -> Value:
        m, rays, subs = self.m, self.trav.rays, self.trav.subunits
        blocked = Signal(name="ld_blocked")
        nxt_lane = Mux(rays.ready, rays.payload.lane, p.lane)
        nxt_sub, _ = self.trav._split_lane(m, nxt_lane, "ld_next")
        m.d.sync += blocked.eq(Array(s.ld_block_next2 for s in subs)[nxt_sub] if len(subs) > 1
                               else subs[0].ld_block_next2)
        return blocked

    def accept(self, ready, take) -> None:
        """The input register loads whenever the loader is ready, valid or not (only ``valid``
        follows the handshake): its wide enable is the loader's own, not the input's valid,
        which the intersection unit's ready gates."""
        m, rays, L, p, valid = self.m, self.trav.rays, self.cfg.packet_size, self.p, self.valid
        m.d.comb += rays.ready.eq(self.active & ~self.got_last & (~valid | ready))
        with m.If(rays.ready):
            m.d.sync += [p.eq(rays.payload), self.live.eq(self.live_in),
                         self.lane_one.eq(Const(1, L) << rays.payload.lane),
                         self.oct_one.eq(Const(1, 8) << rays.payload.octant)]
        with m.If(rays.valid & rays.ready):
            m.d.sync += [valid.eq(1), self.got_last.eq(rays.payload.last)]
        with m.Elif(take):
            m.d.sync += valid.eq(0)
        with m.If(take & p.last):
            m.d.sync += self.got_last.eq(0)

    def loaded(self, take, p, lanes, todo) -> None:
        m, th, L = self.m, self.th, self.cfg.packet_size
        fin = Signal(name="ld_fin")
        fin_oh = Signal(th.T, name="ld_fin_onehot")
        fin_packet = Signal.like(p.packet, name="ld_fin_packet")
        fin_lanes, fin_todo = Signal(L, name="ld_fin_lanes"), Signal(8, name="ld_fin_todo")
        m.d.sync += [fin.eq(take & p.last), fin_oh.eq(self.onehot), fin_packet.eq(p.packet),
                     fin_lanes.eq(lanes), fin_todo.eq(todo)]
        th.set(m, "state", None, ThreadState.NEXTPASS, onehot=Mux(fin, fin_oh, 0))
        for t in range(th.T):
            with m.If(fin & fin_oh[t]):
                m.d.sync += [th.packet[t].eq(fin_packet), th.lanes[t].eq(fin_lanes),
                             th.todo[t].eq(fin_todo), th.term[t].eq(0)]


class Traversal(wiring.Component):
    """The traversal unit: ``cfg.threads`` packets in flight, ``cfg.trav_subunits`` sub-units.

    Ports: ``rays`` (``RayIn`` in; ``load_thread`` = the thread a transfer goes to), ``node``
    (memory read port, 64-bit words, tag = thread), ``leaf`` (``LeafRequest`` out), ``result``
    (``LaneResult`` in, always ready), ``done`` (``PacketDone`` out), ``release`` (thread id in,
    always ready: the thread's results were read out, it may take a new packet), ``node_base``
    and ``root`` (memory image constants, held). Counters: see the module docstring.

    Latency of one inner-node step of a packet with ``a`` active lanes in its busiest sub-unit
    (idle unit): 2 (pick, dispatch) + ``a`` + ``TravSubunit.STEP_LAT`` + 1 (decide); node
    fetch: memory latency + 2. Throughput: the sub-units issue steps of different threads back
    to back, one lane per cycle each; the control engine takes 2 cycles per step.

    ``elaborate`` builds the engines: the loader (:class:`_Loader`), the fetcher, result and
    done engines (a method each), the control engine (:class:`_ControlEngine`) with its step
    fan-out (:class:`StepDispatch`) and the decide engine (:class:`StepDecide`). The engines
    that move threads are built into this module, as they share the per-thread registers
    (:class:`_Threads`); a stage that ``cfg.fast_clock`` changes has its variant in one place
    (:class:`_FastLoader`, :class:`_FastControlEngine`, ``_fetch_pick_fast``, ``_kill_fast``,
    ``_done_out_fast``).
    """

    def __init__(self, cfg: Config, *, addr_width: int = 32):
        self.cfg = cfg
        # fast_clock: a step queue per sub-unit as deep as the threads: each thread has at most
        # one step outstanding, so a queue is never full and the dispatch needs no room (no
        # path from the sub-units' queue levels into the control engine)
        self.step_queue = max(4, cfg.threads) if cfg.fast_clock else 4
        self.subunits = [TravSubunit(cfg, queue=self.step_queue)
                         for _ in range(cfg.trav_subunits)]
        tb = cfg.thread_bits
        counters = {name: Out(COUNTER_BITS) for name in (
            "busy", "ctl_busy", "trav_ops", "trav_steps", "node_reads", "leaf_reqs", "passes", "pushes",
            "packets_done")}
        super().__init__({
            "rays": In(stream.Signature(RayIn(cfg))),
            "load_thread": Out(tb),
            "node": Out(MemReadPort(addr_width=addr_width, data_width=WORD_BITS, tag_width=tb)),
            "leaf": Out(stream.Signature(LeafRequest(cfg))),
            "result": In(stream.Signature(LaneResult(cfg))),
            "done": Out(stream.Signature(PacketDone(cfg))),
            "release": In(stream.Signature(tb)),
            "node_base": In(addr_width), "root": In(NODE_BITS),
            "sub_busy": Out(COUNTER_BITS).array(cfg.trav_subunits),
            **counters,
        })

    def _split_lane(self, m: Module, lane: Value, name: str) -> tuple[Signal, Signal]:
        """(sub-unit, lane within it) of a packet lane: lane l -> (l // R, l % R)."""
        R, k = self.cfg.rays_per_subunit, self.cfg.trav_subunits
        sub = Signal(range(max(2, k)), name=f"{name}_sub")
        loc = Signal(max(1, ceil_log2(R)), name=f"{name}_loc")
        m.d.comb += [sub.eq(sum(lane >= j * R for j in range(1, k))) if k > 1 else sub.eq(0)]
        m.d.comb += loc.eq(lane - sub * R)
        return sub, loc

    def elaborate(self, platform):
        m = Module()
        for j, s in enumerate(self.subunits):
            m.submodules[f"sub{j}"] = s
        th = _Threads(self.cfg, len(self.rays.payload.packet))
        m.submodules.stack = stack = BlockRAM(shape=NODE_BITS + self.cfg.packet_size,
                                              depth=self.cfg.threads * self.cfg.stack_depth)
        m.submodules.passmask = pmem = BlockRAM(shape=8 * self.cfg.packet_size,
                                                depth=self.cfg.threads)
        pm_r = pmem.read_port()
        (_FastLoader if th.fast else _Loader)(self, m, th, pmem.write_port()).build()
        self._fetcher(m, th)
        self._result_engine(m, th)
        self._done_engine(m, th)
        self._control(m, th, stack.read_port(), stack.write_port(), pm_r)
        th.finish(m)
        return m

    def _fetcher(self, m: Module, th: _Threads) -> None:
        """One 64-bit node read per packet visit, round-robin over threads in ``FETCH``; the
        word's arrival turns the thread to ``HAVE_NODE``."""
        req = self.node.req
        m.submodules.fetch_out = out = OutputStage(MemRequest(len(req.payload.addr),
                                                              len(req.payload.tag)))
        wiring.connect(m, out.o, wiring.flipped(req))
        f_ptr = Signal(self.cfg.thread_bits)
        sent = out.i.valid & out.i.ready
        pick = self._fetch_pick_fast if self.cfg.fast_clock else self._fetch_pick
        f_any, f_idx, f_node = pick(m, th, f_ptr, sent)
        m.d.comb += [out.i.valid.eq(f_any), out.i.payload.tag.eq(f_idx),
                     out.i.payload.addr.eq(self.node_base + f_node)]
        with m.If(sent):
            m.d.sync += f_ptr.eq(f_idx + 1)
        with m.If(req.valid & req.ready):
            m.d.sync += self.node_reads.eq(self.node_reads + 1)
        resp = self.node.resp
        m.d.comb += resp.ready.eq(1)
        with m.If(resp.valid):
            m.d.sync += th.word[resp.payload.tag].eq(resp.payload.data)
            th.set_state(m, resp.payload.tag, ThreadState.HAVE_NODE)

    def _fetch_pick(self, m: Module, th: _Threads, ptr, sent):
        """(any, thread, its node) of the fetcher's round-robin pick; the thread turns
        ``WAIT_MEM`` when its request is ``sent``."""
        f_any, f_idx = rr_pick(m, th.in_state(ThreadState.FETCH), ptr, "fetch")
        with m.If(sent):
            th.set_state(m, f_idx, ThreadState.WAIT_MEM)
        return f_any, f_idx, element(th.node, f_idx)

    def _fetch_pick_fast(self, m: Module, th: _Threads, ptr, sent):
        """:meth:`_fetch_pick` made a cycle ahead into registers, from the registered state
        flags, with and without the thread whose request goes out then (only this engine
        moves a thread out of FETCH); ``sent``, registered, chooses. The state write's
        per-thread enables: the pick's one-hot form."""
        f_any, f_idx = Signal(name="fetch_any"), Signal(self.cfg.thread_bits, name="fetch_pick")
        p_any, p_idx, f_oh, f_sel = rr_pick_next(m, th.in_states_q(ThreadState.FETCH), ptr,
                                                 sent, "fetch")
        m.d.comb += [f_any.eq(p_any), f_idx.eq(p_idx)]
        th.set(m, "state", None, ThreadState.WAIT_MEM, onehot=Mux(sent, f_oh, 0))
        return f_any, f_idx, f_sel(th.node)

    def _result_engine(self, m: Module, th: _Threads) -> None:
        """One ``LaneResult`` per cycle: the lane ends if it hit and is an any-hit ray or its
        hit lies in the cell (``t <= tfar``, tfar read from its sub-unit); the leaf's ``last``
        result makes the thread pop. Applied 1 + ``RQ_LAT`` cycles after the result arrives
        (``cfg.fast_clock``: 3 + ``RQ_LAT``, the result and its thread's sp/cur registered
        before the read, each sub-unit's verdict registered after it)."""
        cfg, k, subs = self.cfg, self.cfg.trav_subunits, self.subunits
        rs = self.result.payload
        m.d.comb += self.result.ready.eq(1)
        r = dict(v=self.result.valid, thread=rs.thread, lane=rs.lane, hit=rs.hit, t=rs.t,
                 last=rs.last, sp=th.sp[rs.thread], cur=th.cur[rs.thread])
        if cfg.fast_clock:
            # the result and its thread's stack pointer and slot flag in registers first, so
            # the sub-units' stack reads are addressed from registers here (the thread waits
            # for its leaf, so its sp and cur hold)
            r = registered(m, "rin", **r)
        r_sub, r_loc = self._split_lane(m, r["lane"], "rq")
        for s in subs:
            m.d.comb += [s.rq_thread.eq(r["thread"]), s.rq_lane.eq(r_loc),
                         s.rq_sp.eq(r["sp"]), s.rq_cur.eq(r["cur"])]
        # the result waits in registers for the sub-units' read (RQ_LAT cycles)
        r = dict(v=r["v"], thread=r["thread"], lane=r["lane"], hit=r["hit"], t=r["t"],
                 last=r["last"], sub=r_sub)
        shapes = dict(v=1, thread=cfg.thread_bits, lane=lane_bits(cfg), hit=1,
                      t=cfg.fmt.width, last=1, sub=range(max(2, k)))
        for i in range(subs[0].RQ_LAT):
            regs = {f: Signal(shapes[f], name=f"r{i}_{f}") for f in r}
            m.d.sync += [regs[f].eq(r[f]) for f in r]
            r = regs
        kill, r = (self._kill_fast if cfg.fast_clock else self._kill)(m, r)
        with m.If(r["v"]):
            with m.If(kill):
                m.d.sync += th.term[r["thread"]].eq(th.term[r["thread"]] |
                                                    (Const(1, cfg.packet_size) << r["lane"]))
            with m.If(r["last"]):
                th.set_state(m, r["thread"], ThreadState.POP)

    def _kill(self, m: Module, r: dict) -> tuple[Value, dict]:
        """(the result ends its lane, the result): a hit, and an any-hit ray or ``t <= tfar``
        (the result's sub-unit's read)."""
        subs = self.subunits
        anyhit = Array(s.rq_anyhit for s in subs)[r["sub"]]
        le = compare(self.cfg.fmt, r["t"], Array(s.rq_tfar for s in subs)[r["sub"]]).le
        return r["hit"] & (anyhit | le), r

    def _kill_fast(self, m: Module, r: dict) -> tuple[Value, dict]:
        """:meth:`_kill` a cycle later (with the result, registered): t against every sub-unit's
        tfar of both slots at once; each sub-unit's verdict (its lane already hit, or t <=
        tfar) is registered, and the result's sub-unit and hit choose among the registers (the
        slot and sub-unit selects leave the compare's path)."""
        fmt = self.cfg.fmt
        kills = Cat(*(s.rq_anyhit | Mux(s.rq_slot, compare(fmt, r["t"], s.rq_s_tfar).le,
                                        compare(fmt, r["t"], s.rq_n_tfar).le)
                      for s in self.subunits))
        q = registered(m, "rk", v=r["v"], kills=kills, hit=r["hit"], sub=r["sub"],
                       thread=r["thread"], lane=r["lane"], last=r["last"])
        return q["hit"] & q["kills"].bit_select(q["sub"], 1), q

    def _done_engine(self, m: Module, th: _Threads) -> None:
        """``PacketDone`` for a thread whose passes all ended (it turns ``DRAIN``);
        ``release`` frees the thread."""
        dn = self.done
        (self._done_out_fast if th.fast else self._done_out)(m, th)
        with m.If(dn.valid & dn.ready):
            m.d.sync += self.packets_done.eq(self.packets_done + 1)
        m.d.comb += self.release.ready.eq(1)
        with m.If(self.release.valid):
            th.set_state(m, self.release.payload, ThreadState.FREE)

    def _done_out(self, m: Module, th: _Threads) -> None:
        """``done`` leaves from a register (:class:`OutputStage`): the lowest thread in
        ``DONE``, which turns ``DRAIN`` as it goes in."""
        m.submodules.done_out = out = OutputStage(PacketDone(self.cfg))
        wiring.connect(m, out.o, wiring.flipped(self.done))
        d_any, d_idx = lowest(m, th.in_state(ThreadState.DONE), "done")
        m.d.comb += [out.i.valid.eq(d_any), out.i.payload.thread.eq(d_idx),
                     out.i.payload.packet.eq(th.packet[d_idx]),
                     out.i.payload.mask.eq(th.lanes[d_idx])]
        with m.If(out.i.valid & out.i.ready):
            th.set_state(m, d_idx, ThreadState.DRAIN)

    def _done_out_fast(self, m: Module, th: _Threads) -> None:
        """:meth:`_done_out` with the register holding the thread's id and its one-hot: the
        thread stays ``DONE`` until ``done`` is taken, so the state write starts at registers,
        not at the pick over every thread's state (the same cycles: the one-hot leaves the
        thread just taken out of the next pick and writes its DRAIN, with no decoder on the
        loop)."""
        dn = self.done
        o_thread = Signal(self.cfg.thread_bits, name="done_thread")
        o_oh = Signal(th.T, name="done_onehot")
        cand = th.in_states_q(ThreadState.DONE) & ~Mux(dn.valid, o_oh, 0)
        d_any, d_idx = lowest(m, cand, "done")
        with m.If(~dn.valid | dn.ready):
            m.d.sync += [dn.valid.eq(d_any), o_thread.eq(d_idx), o_oh.eq(lowest_onehot(cand))]
        m.d.comb += [dn.payload.thread.eq(o_thread), dn.payload.packet.eq(th.packet[o_thread]),
                     dn.payload.mask.eq(th.lanes[o_thread])]
        th.set(m, "state", None, ThreadState.DRAIN, onehot=Mux(dn.valid & dn.ready, o_oh, 0))

    def _control(self, m: Module, th: _Threads, st_r, st_w, pm_r) -> None:
        """The control engine (:class:`_ControlEngine`: pick a thread, dispatch its step /
        leaf / pop / pass) and the decide engine (:class:`StepDecide`), joined by the
        sub-units' step queues (fed by :class:`StepDispatch`) and verdict queues."""
        cfg, subs = self.cfg, self.subunits
        m.submodules.dispatch = dsp = StepDispatch(cfg, queue=self.step_queue)
        m.submodules.decide = dcd = StepDecide(cfg)
        for j, s in enumerate(subs):
            wiring.connect(m, dsp.sub[j], s.step)
            wiring.connect(m, s.res, dcd.res[j])
        wiring.connect(m, dsp.order, dcd.order)
        # synchronous sub-units start each step together; asynchronous ones start when free
        go = Cat(*(s.can_start for s in subs)).all() if cfg.trav_sync else Const(1)
        m.d.comb += [s.go.eq(go) for s in subs]
        m.submodules.leaf_out = lf = OutputStage(LeafRequest(cfg))
        wiring.connect(m, lf.o, wiring.flipped(self.leaf))
        engine = _FastControlEngine if cfg.fast_clock else _ControlEngine
        ctl = engine(self, m, th, dsp.i, lf.i, st_r, pm_r)
        # the decisions: the thread's next fields (one write each), the far child pushed
        w, p = dcd.wr.payload, dcd.push.payload
        with m.If(dcd.wr.valid):
            for f in ("sp", "node", "mask", "cur", "state"):
                th.set(m, f, w.thread, w[f])
        m.d.comb += [st_w.addr.eq(stack_entry(self.cfg, p.thread, p.sp)),
                     st_w.data.eq(Cat(p.node, p.mask)),
                     st_w.en.eq(dcd.push.valid), self.pushes.eq(dcd.pushes)]
        ctl.fsm()
        ctl.write_back()
        self._control_counters(m, ctl, dcd)

    def _control_counters(self, m: Module, ctl: _ControlEngine, dcd: StepDecide) -> None:
        """``leaf_reqs``, ``trav_ops``, ``sub_busy``, ``busy`` and ``ctl_busy``."""
        subs = self.subunits
        with m.If(self.leaf.valid & self.leaf.ready):
            m.d.sync += self.leaf_reqs.eq(self.leaf_reqs + 1)
        m.d.sync += self.trav_ops.eq(self.trav_ops + sum(s.issue for s in subs))
        for j, s in enumerate(subs):
            with m.If(~s.idle):
                m.d.sync += self.sub_busy[j].eq(self.sub_busy[j] + 1)
        busy = ctl.count_busy(ctl.busy | dcd.wr.valid | ~Cat(*(s.idle for s in subs)).all())
        with m.If(busy):
            m.d.sync += self.busy.eq(self.busy + 1)
        with m.If(ctl.busy):
            m.d.sync += self.ctl_busy.eq(self.ctl_busy + 1)
