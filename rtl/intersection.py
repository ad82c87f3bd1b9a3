"""Intersection unit: watertight ray-triangle tests, one ray per cycle (``model/intersection.py``).

:class:`IntersectPipe` is the bare datapath: the exact sequence of FP operations of
``model.intersection.intersect``, built from the FP units of ``rtl/fp`` with delay registers
balancing the paths, one test per enabled cycle at a fixed latency.

:class:`IntersectionUnit` wraps it: it keeps the read-only ray data and the best hit per
(thread, lane) in local memories, fetches each requested triangle (one read of the whole
triangle through its memory port, the int-cache's, up to ``tri_slots`` triangles ahead of the
one being tested), tests every lane of the
request's mask, keeps the closest hit, reports each lane of a leaf to traversal after the leaf's
last triangle and reads out the final hits of a finished packet.
"""
from __future__ import annotations

from types import SimpleNamespace

from amaranth.hdl import Array, Cat, Const, Module, Mux, Signal, Value
from amaranth.lib import data, stream, wiring
from amaranth.lib.memory import Memory
from amaranth.lib.wiring import In, Out
from amaranth.utils import ceil_log2

from model.config import Config
from model.fp import FPFormat

from .common import (COUNTER_BITS, BlockRAM, OutputStage, SkidBuffer, from_binary32, lowest,
                     popcount, registered, sum_tree)
from .fp.cmp import compare
from .fp.common import unpack
from .fp.schedule import Schedule as _Schedule
from .intersection_projection import PROJ_K_BIT, ProjectionPipe
from .memport import MemReadPort
from .triangle_pipe import TrianglePipe, pick
from .rtc_streams import (PACKET_ID_BITS, TRI_ID_BITS, LaneResult, PacketDone, RayIn,
                          RayResult, TriRequest, lane_bits)

__all__ = ["IntersectPipe", "IntersectionUnit", "RayWrite"]


def RayWrite(cfg: Config) -> data.StructLayout:
    """A ray written into the unit's local store: the RTC's ``RayIn`` and the thread it runs in."""
    return data.StructLayout({"thread": cfg.thread_bits, "ray": RayIn(cfg)})



class IntersectPipe(TrianglePipe):
    """Bare intersection datapath: ``model.intersection.intersect`` as a pipeline.

    In: ``tri`` (9 format words: A, B, C), ``org`` (3), ``k`` (kx, ky, kz), ``s`` (Sx, Sy, Sz),
    ``tag`` (carried along unchanged), ``i_valid``, ``en``. Out after ``latency`` enabled cycles:
    ``o_valid``, ``hit`` (edge test passed and det != 0), ``t``, ``u``, ``v`` (zero when not
    ``hit``, as the model returns them), ``o_tag``; ``pre_tag`` and ``pre2_tag`` are the tag
    one and two stages earlier (for a read that must land together with the result).

    Operations (all rounded to the format, the model's order): 9 subs (vertices - origin), 9
    muls (Sx, Sy times the z of each vertex; Sz times it), 6 subs (shear), 6 muls + 3 subs (edge
    functions U, V, W), 2 adds (det), 3 muls + 2 adds (T), 1 div (1/det), 3 muls (t, u, v):
    22 add/sub, 21 mul, 1 div. The operands are registered first (they come from block RAM).
    Latency (binary32, default FP latencies 3/3/8): 33 cycles.
    Throughput: one test per cycle in which ``en`` is 1 (``en`` = 0 holds every stage).
    ``latencies``: optional ``{"add": n, "mul": n, "div": n}`` for the FP units.
    """

    def __init__(self, fmt: FPFormat, tag_width: int = 1, latencies: dict | None = None):
        w = fmt.width
        super().__init__(fmt, tag_width, latencies, {
            "tri": In(data.ArrayLayout(w, 9)), "org": In(data.ArrayLayout(w, 3)),
            "k": In(data.ArrayLayout(2, 3)), "s": In(data.ArrayLayout(w, 3))})

    def _build(self, m, dry=False):
        fmt, w = self.fmt, self.fmt.width
        sch = _Schedule(m, self.en, fmt, self.latencies, dry)
        # the operands are registered first (they come straight from block RAM in the unit)
        t0 = 1
        kx, ky, kz = (sch.at(self.k[i], 0, t0) for i in range(3))
        sx, sy, sz = ((sch.at(self.s[i], 0, t0), t0) for i in range(3))
        tri = [sch.at(self.tri[i], 0, t0) for i in range(9)]
        org = [sch.at(self.org[i], 0, t0) for i in range(3)]
        # -- vertices relative to the origin, then into the ray's sheared space -------------------
        rel = [sch.op("sub", (tri[3 * v + a], t0), (org[a], t0), f"rel{v}{a}")
               for v in range(3) for a in range(3)]
        sheared, zs = [], []
        for v, name in enumerate("abc"):
            p = rel[3 * v:3 * v + 3]
            t = p[0][1]
            px, py, pz = ((pick([q[0] for q in p], sch.at(kk, t0, t)), t) for kk in (kx, ky, kz))
            # name the picks: one mux each, shared by every use
            px, py, pz = [(self._wire(m, q[0], f"{name}{c}_pick"), q[1])
                          for q, c in ((px, "x"), (py, "y"), (pz, "z"))]
            x = sch.op("sub", px, sch.op("mul", sx, pz, f"{name}_sxz"), f"{name}x")
            y = sch.op("sub", py, sch.op("mul", sy, pz, f"{name}_syz"), f"{name}y")
            sheared.append((x, y))
            zs.append(pz)
        (ax, ay), (bx, by), (cx, cy) = sheared
        # -- edge functions ------------------------------------------------------------------------
        eu = sch.op("sub", sch.op("mul", cx, by, "cxby"), sch.op("mul", cy, bx, "cybx"), "eu")
        ev = sch.op("sub", sch.op("mul", ax, cy, "axcy"), sch.op("mul", ay, cx, "aycx"), "ev")
        ew = sch.op("sub", sch.op("mul", bx, ay, "bxay"), sch.op("mul", by, ax, "byax"), "ew")
        te = max(eu[1], ev[1], ew[1])
        E = [unpack(fmt, sch.at(e[0], e[1], te)) for e in (eu, ev, ew)]
        neg = [u.sign & ~u.zero & ~u.nan for u in E]
        pos = [~u.sign & ~u.zero & ~u.nan for u in E]
        edge_ok = (self._wire(m, ~((neg[0] | neg[1] | neg[2]) & (pos[0] | pos[1] | pos[2])),
                              "edge_ok"), te)
        # -- determinant, scaled distance, reciprocal ----------------------------------------------
        det = sch.op("add", sch.op("add", eu, ev, "det_uv"), ew, "det")
        det_ok = (self._wire(m, ~unpack(fmt, det[0]).zero, "det_nonzero"), det[1])
        az, bz, cz = (sch.op("mul", sz, z, f"{n}_szz") for z, n in zip(zs, "abc"))
        tz = sch.op("add", sch.op("add", sch.op("mul", eu, az, "u_az"),
                                  sch.op("mul", ev, bz, "v_bz"), "tz_uv"),
                    sch.op("mul", ew, cz, "w_cz"), "tz")
        one = (Const(((fmt.bias) << fmt.frac_bits), w), 0)
        rcp = sch.op("div", one, det, "rcp")
        t = sch.op("mul", tz, rcp, "t")
        u = sch.op("mul", ev, rcp, "u")
        v = sch.op("mul", ew, rcp, "v")
        L = max(t[1], u[1], v[1])
        hit = sch.at(edge_ok[0], edge_ok[1], L) & sch.at(det_ok[0], det_ok[1], L)
        return self._outputs(m, sch, hit, t, u, v, L, dry)


class IntersectionUnit(wiring.Component):
    """The RTC's intersection unit: triangle fetch, per-lane tests, closest hit, results.

    Ports
    -----
    ``ray_in`` (In stream, :func:`RayWrite`): the RTC writes each ray of a packet (thread, lane)
        before the packet's first leaf; the unit keeps org, k, s and resets the lane's best hit
        to (t = tmax, none). ``ready`` is low only in a cycle where a hit is being stored.
    ``tri_in`` (In stream, ``TriRequest``): a triangle for the lanes in ``mask`` (nonzero);
        ``last`` marks the leaf's final triangle.
    ``mem`` (``MemReadPort`` requester, tag = slot): one read per triangle, address = the
        triangle's index, answered with its 9 binary32 vertex words (``cfg.int_item_bits``
        bits, vertex 0's x in the low bits: an int-cache item, ``rtl/cache.py``); with
        ``cfg.int_test = "projection"`` the 9 words of its projection record, k in them.
    ``lane_out`` (Out stream, ``LaneResult``): for a leaf's last triangle, one result per lane
        of the mask in lane order (``last`` on the highest lane): has-hit and best t.
    ``done`` (In stream, ``PacketDone``) / ``result`` (Out stream, ``RayResult``): read out
        the final hit of every lane of ``mask`` in lane order, labelled with ``packet``
        (tri = all ones and t = +inf on a miss). Send ``done`` only after the packet's last
        ``LaneResult`` was taken. ``done`` is taken as soon as the previous packet's last
        result is in the output register, so the next packet's readout follows without a gap.
    ``release`` (Out stream, thread id): the thread of a packet whose last ``RayResult`` was
        taken in this cycle (valid for that one cycle: the consumer must always be ready); its
        rays and best hits may be overwritten from the next cycle on.
    Counters (Out, 32 bits): ``int_ops`` (rays tested), ``tris`` (triangles fetched),
    ``busy`` (cycles with a triangle held or a test in flight).

    Timing: up to ``tri_slots`` triangles are fetched ahead of the one being tested (a request
    leaves one cycle after its ``TriRequest`` was taken, one triangle a cycle); tests issue one
    lane per cycle with no gap between triangles. A test's result is stored 2 + ``IntersectPipe.latency`` cycles after its issue
    (34 for binary32; ``ProjectionPipe.latency`` with ``cfg.int_test = "projection"``: 38); the LaneResult leaves one cycle later. The whole pipeline stalls only while
    ``lane_out`` is full and not taken (``cfg.fast_clock``: while a second LaneResult waits
    behind the full output, in a skid register, so the stall starts a cycle later and comes
    from a flip-flop).
    """

    def __init__(self, cfg: Config, *, addr_width: int = 32, tri_slots: int | None = None,
                 latencies: dict | None = None):
        if tri_slots is None:
            tri_slots = cfg.int_tri_slots
        if tri_slots < 2 or tri_slots & (tri_slots - 1):
            self._MustUse__silence = True        # never elaborated: no warning
            raise ValueError(f"IntersectionUnit tri_slots={tri_slots}: must be a power of two "
                             ">= 2 (one triangle tested while the next is fetched)")
        self.cfg, self.fmt, self.tri_slots = cfg, cfg.fmt, tri_slots
        self.slot_bits = ceil_log2(tri_slots)
        self.tag_width = self.slot_bits
        self.lanes = cfg.packet_size
        self.lane_bits = lane_bits(cfg)
        self.pipe_meta = data.StructLayout({
            "thread": cfg.thread_bits, "lane": self.lane_bits, "id": TRI_ID_BITS,
            "tri_last": 1, "lane_last": 1})
        if latencies is None:
            latencies = cfg.fp_latencies()
        # the test (Config.int_test): the watertight one on the vertices, or the paper's on
        # precomputed records (the ray store then keeps the direction where ``s`` was)
        self.projection = cfg.int_test == "projection"
        pipe = ProjectionPipe if self.projection else IntersectPipe
        self.pipe = pipe(cfg.fmt, tag_width=self.pipe_meta.size, latencies=latencies)
        super().__init__({
            "ray_in": In(stream.Signature(RayWrite(cfg))),
            "tri_in": In(stream.Signature(TriRequest(cfg))),
            "mem": Out(MemReadPort(addr_width=addr_width, data_width=cfg.int_item_bits,
                                   tag_width=self.tag_width)),
            "lane_out": Out(stream.Signature(LaneResult(cfg))),
            "done": In(stream.Signature(PacketDone(cfg))),
            "result": Out(stream.Signature(RayResult(cfg))),
            "release": Out(stream.Signature(cfg.thread_bits)),
            "int_ops": Out(COUNTER_BITS), "tris": Out(COUNTER_BITS),
            "busy": Out(COUNTER_BITS),
        })

    def elaborate(self, platform):
        m = Module()
        m.submodules.pipe = self.pipe
        # the test pipeline advances unless a LaneResult waits in a full output register
        # (fast_clock: unless one waits in the skid register behind it, so the enable of the
        # issue, the datapath and the closest-hit stages is a flip-flop, not the consumer's
        # ready)
        stage = SkidBuffer if self.cfg.fast_clock else OutputStage
        m.submodules.lane_stage = self._lane_stage = stage(LaneResult(self.cfg))
        wiring.connect(m, self._lane_stage.o, wiring.flipped(self.lane_out))
        en = self._lane_stage.i.ready
        w = self.fmt.width
        ray_l = data.StructLayout(
            {"org": data.ArrayLayout(w, 3), "dir": data.ArrayLayout(w, 3)} if self.projection
            else {"org": data.ArrayLayout(w, 3), "k": data.ArrayLayout(2, 3),
                  "s": data.ArrayLayout(w, 3)})
        best_l = data.StructLayout({"t": w, "u": w, "v": w, "tri": TRI_ID_BITS, "hit": 1})
        depth = 1 << (self.cfg.thread_bits + self.lane_bits)
        # local ray store (read-only data) and best-hit store, one word per (thread, lane)
        m.submodules.rays = rays = BlockRAM(shape=ray_l, depth=depth)
        m.submodules.best = best = (BlockRAM if self.cfg.fast_clock else Memory)(
            shape=best_l, depth=depth, init=[])
        ray_w, best_w = rays.write_port(), best.write_port()
        ray_r = rays.read_port()
        # fast_clock: the best-hit read goes straight into a register, the stores it missed
        # are forwarded (_best_hit); else the read port is transparent to the store
        best_r = best.read_port() if self.cfg.fast_clock else \
            best.read_port(transparent_for=(best_w,))
        out_r = best.read_port()
        slots = self._fetch(m)
        issued = self._issue(m, en, slots, ray_r)
        self._best_hit(m, en, best_r, best_w, ray_w)
        self._readout(m, out_r)
        self._counters(m, en, slots, issued)
        return m

    def _addr(self, thread, lane):
        """Address of (thread, lane) in the ray and best-hit stores."""
        return Cat(lane[:self.lane_bits], thread[:self.cfg.thread_bits])

    def _fetch(self, m: Module) -> SimpleNamespace:
        """Triangle fetch: a request is taken into the next free of ``tri_slots`` slots and
        its read (triangle index, tag = slot) leaves from a register in the next cycle, one per
        cycle; each response is the whole triangle and lands in its slot, in any order."""
        n_slots, lanes = self.tri_slots, self.lanes
        s = SimpleNamespace()
        # the slots' triangles: a memory written by the responses and read without a clock
        # (LUT-RAM on an FPGA: the issue stage's pick by its slot pointer is the RAM's read
        # address, not a mux tree over tri_slots x 288 flip-flops)
        m.submodules.tri_store = store = Memory(shape=self.cfg.int_item_bits, depth=n_slots,
                                                init=[])
        s.item_w, s.item_r = store.write_port(), store.read_port(domain="comb")
        s.got = Signal(n_slots)
        s.mask = Array(Signal(lanes, name=f"s{i}_mask") for i in range(n_slots))
        s.thread = Array(Signal(self.cfg.thread_bits, name=f"s{i}_thread")
                         for i in range(n_slots))
        s.index = Array(Signal(TRI_ID_BITS, name=f"s{i}_index") for i in range(n_slots))
        s.last = Signal(n_slots)
        s.count = Array(Signal(range(lanes + 1), name=f"s{i}_count") for i in range(n_slots))
        s.alloc = alloc = Signal(n_slots)
        alloc_set, s.alloc_clr = Signal(n_slots), Signal(n_slots)
        m.d.sync += alloc.eq((alloc | alloc_set) & ~s.alloc_clr)

        nxt = Signal(self.slot_bits)       # the slot the next request goes to
        req, tri_in = self.mem.req, self.tri_in
        fast = self.cfg.fast_clock
        if fast:
            # nxt one-hot, and "slot nxt is allocated" a cycle ahead, in registers (from the
            # allocations after this cycle's releases, for nxt or, with a transfer, the slot
            # after it), so the request's ready and the slot writes start at registers
            nxt_oh = Signal(n_slots, init=1, name="nxt_onehot")
            nxt_busy = Signal(name="nxt_busy")
            kept = alloc & ~s.alloc_clr
            rot = Cat(nxt_oh[-1], nxt_oh[:-1])          # the slot after nxt
            xfer = tri_in.valid & tri_in.ready
            m.d.sync += nxt_busy.eq(Mux(xfer, (kept & rot).any(), (kept & nxt_oh).any()))
            with m.If(xfer):
                m.d.sync += nxt_oh.eq(rot)
            slot_free, nxt_sel = ~nxt_busy, nxt_oh
        else:
            slot_free, nxt_sel = ~alloc.bit_select(nxt, 1), (Const(1, n_slots) << nxt)[:n_slots]
        m.d.comb += tri_in.ready.eq((~req.valid | req.ready) & slot_free)
        with m.If(req.valid & req.ready):
            m.d.sync += req.valid.eq(0)
        got_set, got_clr = Signal(n_slots), Signal(n_slots)
        p = tri_in.payload
        with m.If(tri_in.valid & tri_in.ready):
            m.d.comb += [alloc_set.eq(nxt_sel), got_clr.eq(nxt_sel)]
            m.d.sync += [
                req.valid.eq(1), req.payload.addr.eq(p.tri), req.payload.tag.eq(nxt),
                nxt.eq(nxt + 1),
            ]
            for k in range(n_slots):        # the slot's fields, by its one-hot
                with m.If(nxt_sel[k]):
                    m.d.sync += [s.mask[k].eq(p.mask), s.thread[k].eq(p.thread),
                                 s.index[k].eq(p.tri), s.last[k].eq(p.last)]
        s.counted = alloc
        if fast:
            # the mask's lane count (for the issue stage) in two cycles after the request:
            # counts of 8-lane groups from a register of the mask, then their sum; the slot
            # counts as allocated for the issue stage once its count is written (its triangle
            # comes from memory later than that anyway)
            c_v, c_slot, c_mask = Signal(), Signal(self.slot_bits), Signal(lanes, name="c_mask")
            groups = [c_mask[k:k + 8] for k in range(0, lanes, 8)]
            c2_v, c2_slot = Signal(), Signal(self.slot_bits)
            c2_part = [Signal(4, name=f"c2_part{k}") for k in range(len(groups))]
            m.d.sync += [c_v.eq(tri_in.valid & tri_in.ready), c2_v.eq(c_v), c2_slot.eq(c_slot)]
            m.d.sync += [c2_part[k].eq(popcount(g)) for k, g in enumerate(groups)]
            with m.If(tri_in.valid & tri_in.ready):
                m.d.sync += [c_slot.eq(nxt), c_mask.eq(tri_in.payload.mask)]
            # with "one lane" beside the count, so the issue stage's N takes it from a register
            s.one = Signal(n_slots, name="s_one")
            c2_sum = Signal(range(lanes + 1), name="c2_sum")
            m.d.comb += c2_sum.eq(sum_tree(c2_part))
            with m.If(c2_v):
                m.d.sync += [s.count[c2_slot].eq(c2_sum),
                             s.one.bit_select(c2_slot, 1).eq(c2_sum == 1)]
            s.counted = Signal(n_slots)
            m.d.comb += s.counted.eq(alloc & ~Mux(c_v, 1 << c_slot, 0)[:n_slots]
                                     & ~Mux(c2_v, 1 << c2_slot, 0)[:n_slots])
        resp = self.mem.resp
        m.d.comb += resp.ready.eq(1)
        r_valid, r_tag, r_data = resp.valid, resp.payload.tag[:self.slot_bits], resp.payload.data
        if fast:
            # a response lands in registers beside the unit first, a cycle later (the
            # cache's output register sits elsewhere on the die: h7_s1's critical path was
            # its valid's 4.8 ns wire into got_cur)
            r = registered(m, "resp_q", valid=r_valid, tag=r_tag)
            q_data = Signal.like(Value.cast(r_data), name="resp_q_data", reset_less=True)
            m.d.sync += q_data.eq(r_data)
            r_valid, r_tag, r_data = r["valid"], r["tag"], q_data
        with m.If(r_valid):
            m.d.comb += got_set.eq(1 << r_tag)
        m.d.comb += [s.item_w.addr.eq(r_tag), s.item_w.data.eq(r_data),
                     s.item_w.en.eq(r_valid)]
        s.got_in = Signal(n_slots)                   # s.got with this cycle's arrivals
        m.d.comb += s.got_in.eq(s.got | got_set)
        m.d.sync += s.got.eq(s.got_in & ~got_clr)
        return s

    def _issue(self, m: Module, en: Value, s: SimpleNamespace, ray_r) -> Value:
        """Test issue: the lanes of the oldest slot's mask, lowest first, one per cycle, no gap
        between triangles; stage 1 registers the triangle (format words) and the lane, while
        the ray store is read. Returns the condition that a test issues this cycle."""
        fmt, lanes, pipe = self.fmt, self.lanes, self.pipe
        t_slot = Signal(self.slot_bits)
        rem = Signal(lanes)
        go = Signal()
        issue = Signal()                   # a lane's test issues this cycle
        rest = Signal(lanes)
        if self.cfg.fast_clock:
            # Two register sets, so that the issue decision and every load read only
            # registers: the head H (rem: the current slot's lanes still to test, valid
            # rem_v; ``left`` their number, ``last`` whether one is left; the slot's thread,
            # triangle index and last flag) and the next N (the same fields of the slot
            # that H takes next: n_slot, the slot after H's, or H's own slot while H is
            # empty). N samples its slot every cycle (a pick by a register index), H takes
            # N as H's last lane issues or while H is empty, so triangles follow each other
            # without a gap. H takes a new slot two cycles after its count is written, and
            # its triangle comes from memory later than that.
            rem_v, last = Signal(), Signal()
            left = Signal(range(lanes + 1))     # lanes in rem
            slot = SimpleNamespace(thread=Signal(self.cfg.thread_bits, name="slot_thread"),
                                   index=Signal(TRI_ID_BITS, name="slot_index"),
                                   last=Signal(name="slot_last"))
            n = SimpleNamespace(v=Signal(name="n_v"), mask=Signal(lanes, name="n_mask"),
                                count=Signal(range(lanes + 1), name="n_count"),
                                one=Signal(name="n_one"),
                                thread=Signal(self.cfg.thread_bits, name="n_thread"),
                                index=Signal(TRI_ID_BITS, name="n_index"),
                                last=Signal(name="n_last"))
            # N samples slot n_slot, or n_slot + 1 when H takes N now (n_after, always
            # n_slot + 1, is kept in its own register: both picks are by register indices)
            n_slot = Signal(self.slot_bits)
            n_after = Signal(self.slot_bits, init=1)
            take = Signal()
            # got_cur: the current slot's triangle is in (a register, from the slot current in
            # the next cycle and the got bits with this cycle's arrivals; a slot allocated in
            # this cycle, whose got bit is cleared, is not taken by H for cycles, while
            # got_cur follows it every cycle)
            got_cur = Signal()
            adv = go & last
            after = (t_slot + 1)[:self.slot_bits]
            m.d.sync += got_cur.eq(Mux(adv, s.got_in.bit_select(after, 1),
                                       s.got_in.bit_select(t_slot, 1)))
            m.d.comb += [go.eq(en & rem_v & got_cur), issue.eq(go),
                         rest.eq(rem & (rem - 1)),
                         take.eq(n.v & (~rem_v | adv))]
            # the lowest lane of rem, kept in a register for the rem after each cycle (the
            # ray store's read address starts at registers): N's lowest lane when H takes N,
            # the lowest lane above this one when a lane issues, else the same
            lane = Signal(range(max(2, lanes)), name="issue_lane")
            _, n_lane = lowest(m, n.mask, "issue_next")
            above = Cat(Const(0, 1), *(lane < k for k in range(1, lanes)))
            _, up_lane = lowest(m, rem & above, "issue_up")
            m.d.sync += lane.eq(Mux(take, n_lane, Mux(go & ~last, up_lane, lane)))

            def sample(k):
                return dict(v=s.counted.bit_select(k, 1), mask=s.mask[k], count=s.count[k],
                            one=s.one.bit_select(k, 1), thread=s.thread[k], index=s.index[k],
                            last=s.last.bit_select(k, 1))
            at_slot, at_after = sample(n_slot), sample(n_after)
            m.d.sync += [getattr(n, f).eq(Mux(take, at_after[f], at_slot[f])) for f in at_slot]
            with m.If(take):
                m.d.sync += [n_slot.eq(n_after), n_after.eq(n_after + 1),
                             rem_v.eq(1), rem.eq(n.mask), left.eq(n.count), last.eq(n.one),
                             slot.thread.eq(n.thread), slot.index.eq(n.index),
                             slot.last.eq(n.last)]
            with m.If(go):
                with m.If(last):
                    m.d.comb += s.alloc_clr.eq(1 << t_slot)
                    m.d.sync += t_slot.eq(t_slot + 1)
                    with m.If(~n.v):
                        m.d.sync += rem_v.eq(0)
                with m.Else():
                    m.d.sync += [rem.eq(rest), left.eq(left - 1), last.eq(left == 2)]
            lane_last = last
            thread, index, tri_last = slot.thread, slot.index, slot.last
        else:
            testing = Signal()             # part of t_slot's mask is already issued
            ready_slot = s.alloc.bit_select(t_slot, 1) & s.got.bit_select(t_slot, 1)
            cur = Signal(lanes)
            m.d.comb += cur.eq(Mux(testing, rem, s.mask[t_slot]))
            m.d.comb += [go.eq(en & ready_slot), issue.eq(go & (cur != 0))]
            _, lane = lowest(m, cur, "issue")
            m.d.comb += rest.eq(cur & (cur - 1))
            with m.If(go):
                m.d.sync += rem.eq(rest)
                with m.If(rest == 0):
                    m.d.comb += s.alloc_clr.eq(1 << t_slot)
                    m.d.sync += [testing.eq(0), t_slot.eq(t_slot + 1)]
                with m.Else():
                    m.d.sync += testing.eq(1)
            lane_last = rest == 0
            thread, index, tri_last = s.thread[t_slot], s.index[t_slot], \
                s.last.bit_select(t_slot, 1)

        m.d.comb += s.item_r.addr.eq(t_slot)
        tri = data.View(data.ArrayLayout(32, 9), s.item_r.data[:9 * 32])
        s1_valid = Signal()
        s1_tri = Signal(data.ArrayLayout(fmt.width, 9))
        s1_meta = Signal(self.pipe_meta)
        words = [tri[j] for j in range(9)]
        if self.projection:
            # a record keeps its axis k in the spare exponent bits of n_u and n_v
            s1_k = Signal(2)
            kb = [words[j][PROJ_K_BIT] for j in (0, 1)]
            clear = Const(0xFFFFFFFF ^ (1 << PROJ_K_BIT), 32)
            words[0], words[1] = (w_ & clear for w_ in words[:2])
            with m.If(en):
                m.d.sync += s1_k.eq(Cat(*kb))
        m.d.comb += [ray_r.addr.eq(self._addr(thread, lane)), ray_r.en.eq(en)]
        with m.If(en):
            m.d.sync += [
                s1_valid.eq(issue),
                s1_tri.eq(Cat(*(from_binary32(fmt, x) for x in words))),
                s1_meta.thread.eq(thread), s1_meta.lane.eq(lane),
                s1_meta.id.eq(index), s1_meta.tri_last.eq(tri_last),
                s1_meta.lane_last.eq(lane_last),
            ]
        ray = ray_r.data
        m.d.comb += [
            pipe.tri.eq(s1_tri), pipe.org.eq(ray.org),
            pipe.tag.eq(s1_meta), pipe.i_valid.eq(s1_valid), pipe.en.eq(en),
        ]
        if self.projection:
            m.d.comb += [pipe.tri_k.eq(s1_k), pipe.dir.eq(ray.dir)]
        else:
            m.d.comb += [pipe.k.eq(ray.k), pipe.s.eq(ray.s)]
        return issue

    def _best_hit(self, m: Module, en: Value, best_r, best_w, ray_w) -> None:
        """Closest-hit update at the end of the pipeline (accept ``0 < t < best``), the ray
        store's writes, and the ``LaneResult`` after a leaf's last triangle. The best-hit read
        is presented one stage before the datapath's output; the read port is transparent to
        the update's write, so back-to-back tests of one lane see each other
        (``cfg.fast_clock``: :meth:`_best_hit_fast`)."""
        fmt, w, pipe = self.fmt, self.fmt.width, self.pipe
        fast = self.cfg.fast_clock
        pre = data.View(self.pipe_meta, pipe.pre2_tag if fast else pipe.pre_tag)
        m.d.comb += [best_r.addr.eq(self._addr(pre.thread, pre.lane)), best_r.en.eq(en)]
        if fast:
            self._best_hit_fast(m, en, best_r, best_w, ray_w)
            return
        o_meta = data.View(self.pipe_meta, pipe.o_tag)
        old = best_r.data
        accept, store = Signal(), Signal()
        m.d.comb += [accept.eq(pipe.o_valid & pipe.hit & compare(fmt, Const(0, w), pipe.t).lt &
                               compare(fmt, pipe.t, old.t).lt),
                     store.eq(en & accept), self.ray_in.ready.eq(~store)]
        self._ray_store_writes(m, store, store, pipe.o_valid, pipe.t, pipe.u, pipe.v, o_meta,
                               accept, old.t, old.hit, best_w, ray_w)

    def _ray_store_writes(self, m, store, upd, valid, t, u, v, meta, accept, old_t, old_hit,
                          best_w, ray_w) -> None:
        """The ray store's writes, the best-hit store's write (while ``upd``: the update's
        address and data, written if ``store``; else a new ray's initial best) and the
        LaneResult, from the deciding stage's values."""
        ray_in = self.ray_in
        rp = ray_in.payload
        # (projection: RayIn's ``s`` carries the direction, rtl/rtc_streams.py)
        ray = dict(addr=self._addr(rp.thread, rp.ray.lane),
                   data=(Cat(rp.ray.org, rp.ray.s) if self.projection
                         else Cat(rp.ray.org, rp.ray.k, rp.ray.s)),
                   en=ray_in.valid & ray_in.ready)
        # (the initial best's write is used only while no update holds the port, when the
        # ray input is ready: its enable is the handshake, as the ray store's)
        init = dict(addr=ray["addr"], tmax=rp.ray.tmax, en=ray["en"])
        if self.cfg.fast_clock:
            # the ray store's write and the initial best a cycle later, from registers (a
            # lane's first read comes after its thread's traversal reaches a leaf): the
            # handshake, which the traversal unit's loader drives, ends at registers, not at
            # the block RAMs' write pins (the ray input waits while stage B will hold a hit
            # in the next cycle, so the initial best has the write port then)
            ray = registered(m, "ray_w", **ray)
            init = registered(m, "best_init", **init)
        m.d.comb += [ray_w.addr.eq(ray["addr"]), ray_w.data.as_value().eq(ray["data"]),
                     ray_w.en.eq(ray["en"])]
        with m.If(upd):
            m.d.comb += [
                best_w.addr.eq(self._addr(meta.thread, meta.lane)), best_w.en.eq(store),
                best_w.data.t.eq(t), best_w.data.u.eq(u), best_w.data.v.eq(v),
                best_w.data.tri.eq(meta.id), best_w.data.hit.eq(1),
            ]
        with m.Else():
            m.d.comb += [
                best_w.addr.eq(init["addr"]), best_w.en.eq(init["en"]),
                best_w.data.t.eq(init["tmax"]), best_w.data.hit.eq(0),
            ]
        lo = self._lane_stage.i
        m.d.comb += [
            lo.valid.eq(valid & meta.tri_last),
            lo.payload.thread.eq(meta.thread), lo.payload.lane.eq(meta.lane),
            lo.payload.hit.eq(accept | old_hit),
            lo.payload.t.eq(Mux(accept, t, old_t)),
            lo.payload.last.eq(meta.lane_last),
        ]

    def _best_hit_fast(self, m: Module, en: Value, best_r, best_w, ray_w) -> None:
        """``cfg.fast_clock``: the closest-hit decision in two stages. Stage A (the datapath's
        output) compares t with each candidate for the lane's best so far: the best-hit read
        (issued two stages earlier, registered: it misses the last three stores) and those
        three stores (the one being decided in stage B now, and the two before, in
        registers). Stage B (a register stage) knows which of them stored, picks the newest
        matching one's verdict, accepts and stores. Only whether B's predecessor stored is
        new in B: the older candidates' t and hit (the two older stores and the read) are
        chosen in A, by the address matches alone, and registered; their verdicts are
        chosen in B from registers, beside the predecessor's. The LaneResult leaves a cycle
        later than without ``fast_clock``; a new ray waits while stage B will hold a hit in
        the next cycle (its initial best is written then)."""
        fmt, w, pipe = self.fmt, self.fmt.width, self.pipe
        a_meta = data.View(self.pipe_meta, pipe.o_tag)
        a_addr = self._addr(a_meta.thread, a_meta.lane)
        # the best-hit read, registered (no reset: a block-RAM read, saarcor/flows/fpga/outreg.py)
        q_t = Signal(w, name="best_q_t", reset_less=True)
        q_hit = Signal(name="best_q_hit", reset_less=True)
        # stage B registers
        b_valid, b_hit = Signal(name="b_valid"), Signal(name="b_hit")
        b_t, b_u, b_v = (Signal(w, name=f"b_{n}") for n in "tuv")
        b_meta = Signal(self.pipe_meta, name="b_meta")
        b_addr = Signal(len(a_addr), name="b_addr")
        # the older candidates' choice, made in A: the newest matching of st1, st2 (as they
        # are in A) and the read, its t and whether it is a hit
        r_t, r_hit = Signal(w, name="b_rest_t"), Signal(name="b_rest_hit")
        b_ok = Signal(name="b_ok")          # B holds a hit with t > 0
        # the last two stores before B's: (valid, address, t), newest first
        st = [(Signal(name=f"st{i}_v"), Signal(len(a_addr), name=f"st{i}_addr"),
               Signal(w, name=f"st{i}_t")) for i in (1, 2)]
        # stage A: one compare per candidate (B's op, st1, st2 as they are now; the read)
        cands = [(Const(1), b_addr, b_t), st[0], st[1]]
        lt_a = [compare(fmt, pipe.t, c[2]).lt for c in cands] + [compare(fmt, pipe.t, q_t).lt]
        match_a = [c[0] & (c[1] == a_addr) for c in cands]
        lt_q, match_q = Signal(4, name="b_lt"), Signal(3, name="b_match")
        store = Signal()
        gt0 = compare(fmt, Const(0, w), pipe.t).lt
        with m.If(en):
            m.d.sync += [q_t.eq(best_r.data.t), q_hit.eq(best_r.data.hit),
                         b_valid.eq(pipe.o_valid), b_hit.eq(pipe.hit),
                         b_ok.eq(pipe.o_valid & pipe.hit & gt0),
                         b_t.eq(pipe.t), b_u.eq(pipe.u), b_v.eq(pipe.v), b_meta.eq(pipe.o_tag),
                         b_addr.eq(a_addr), lt_q.eq(Cat(*lt_a)), match_q.eq(Cat(*match_a)),
                         r_t.eq(Mux(match_a[1], st[0][2], Mux(match_a[2], st[1][2], q_t))),
                         r_hit.eq(match_a[1] | match_a[2] | q_hit)]
            m.d.sync += [st[0][0].eq(store), st[0][1].eq(b_addr), st[0][2].eq(b_t)]
            m.d.sync += [a.eq(b) for a, b in zip(st[1], st[0])]
        # stage B: B's predecessor (st1 now) matched in A and stored, else the older choice
        mt0 = match_q[0] & st[0][0]
        r_lt = Mux(match_q[1], lt_q[1], Mux(match_q[2], lt_q[2], lt_q[3]))
        old_t = Mux(mt0, st[0][2], r_t)
        old_hit = mt0 | r_hit
        accept = Signal()
        # the ray input waits while B holds a hit in the next cycle (the update has the
        # best-hit write port then; a new ray's initial best is written a cycle after it
        # enters)
        b_hit_next = Mux(en, pipe.o_valid & pipe.hit, b_valid & b_hit)
        m.d.comb += [accept.eq(b_ok & Mux(mt0, lt_q[0], r_lt)), store.eq(en & accept),
                     self.ray_in.ready.eq(~b_hit_next)]
        # the best-hit write's address and data are the update's while B holds a hit (from
        # registers; a new ray's initial best waits then), so only its enable follows the
        # verdict
        self._ray_store_writes(m, store, b_valid & b_hit, b_valid, b_t, b_u, b_v, b_meta,
                               accept, old_t, old_hit, best_w, ray_w)

    def _readout(self, m: Module, out_r) -> None:
        """Final results of a finished packet: one ``RayResult`` per lane of the ``done``
        mask, in lane order, read from the best-hit store (the read port is the output
        register: it advances when the output is empty or taken; ``cfg.fast_clock``: the read
        is registered once more before the output)."""
        fmt, w, lanes = self.fmt, self.fmt.width, self.lanes
        done, res = self.done, self.result
        d_active = Signal()
        d_rem = Signal(lanes)
        d_thread = Signal(self.cfg.thread_bits)
        d_packet = Signal(PACKET_ID_BITS)
        _, d_lane = lowest(m, d_rem, "readout")
        adv = Signal()
        hb = out_r.data
        if self.cfg.fast_clock:
            # the read lands in a register stage (r_*, the block RAM's output straight into
            # hb_q) before the output
            r_valid = Signal()
            hb_q = Signal.like(out_r.data, name="readout_hb_q", reset_less=True)
            o_lane, o_last, o_packet = (Signal(self.lane_bits), Signal(),
                                        Signal(PACKET_ID_BITS))
            move = ~res.valid | res.ready
            m.d.comb += [adv.eq(~r_valid | move), done.ready.eq(~d_active)]
        else:
            m.d.comb += [adv.eq(~res.valid | res.ready), done.ready.eq(~d_active)]
            r_valid = res.valid
        # fast_clock: a packet has at least one lane (its last), so a done packet always has
        # results to read out (with none its thread would never be released)
        d_any = Const(1) if self.cfg.fast_clock else done.payload.mask != 0
        with m.If(done.valid & done.ready):
            m.d.sync += [d_active.eq(d_any), d_rem.eq(done.payload.mask),
                         d_thread.eq(done.payload.thread), d_packet.eq(done.payload.packet)]
        m.d.comb += [out_r.addr.eq(self._addr(d_thread, d_lane)), out_r.en.eq(adv)]
        r_lane = Signal(self.lane_bits)
        r_last = Signal()
        r_packet = Signal(PACKET_ID_BITS)
        r_thread = Signal(self.cfg.thread_bits)
        with m.If(adv):
            m.d.sync += [r_valid.eq(d_active), r_lane.eq(d_lane), r_packet.eq(d_packet),
                         r_thread.eq(d_thread), r_last.eq((d_rem & (d_rem - 1)) == 0)]
            with m.If(d_active):
                m.d.sync += d_rem.eq(d_rem & (d_rem - 1))
                with m.If((d_rem & (d_rem - 1)) == 0):
                    m.d.sync += d_active.eq(0)
        if self.cfg.fast_clock:
            o_thread = Signal(self.cfg.thread_bits)
            with m.If(move):
                m.d.sync += [res.valid.eq(r_valid), o_lane.eq(r_lane), o_last.eq(r_last),
                             o_packet.eq(r_packet), o_thread.eq(r_thread), hb_q.eq(out_r.data)]
            hb, r_lane, r_last, r_packet, r_thread = hb_q, o_lane, o_last, o_packet, o_thread
        # the thread goes with its last result: by then `done` may hold the next packet
        m.d.comb += [self.release.valid.eq(res.valid & res.ready & r_last),
                     self.release.payload.eq(r_thread)]
        inf = Const(((1 << fmt.exp_bits) - 1) << fmt.frac_bits, w)
        m.d.comb += [
            res.payload.packet.eq(r_packet), res.payload.lane.eq(r_lane),
            res.payload.last.eq(r_last),
            res.payload.tri.eq(Mux(hb.hit, hb.tri, (1 << TRI_ID_BITS) - 1)),
            res.payload.t.eq(Mux(hb.hit, hb.t, inf)),
            res.payload.u.eq(Mux(hb.hit, hb.u, 0)), res.payload.v.eq(Mux(hb.hit, hb.v, 0)),
        ]

    def _counters(self, m: Module, en: Value, s: SimpleNamespace, issued: Value) -> None:
        pipe = self.pipe
        with m.If(issued):
            m.d.sync += self.int_ops.eq(self.int_ops + 1)
        with m.If(self.tri_in.valid & self.tri_in.ready):
            m.d.sync += self.tris.eq(self.tris + 1)
        inflight = Signal(range(pipe.latency + 3))
        m.d.sync += inflight.eq(inflight + issued - (en & pipe.o_valid))
        with m.If((s.alloc != 0) | (inflight != 0) | self.lane_out.valid):
            m.d.sync += self.busy.eq(self.busy + 1)
