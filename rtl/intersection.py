"""Intersection unit: watertight ray-triangle tests, one ray per cycle (``model/intersection.py``).

:class:`IntersectPipe` is the bare datapath: the exact sequence of FP operations of
``model.intersection.intersect``, built from the FP units of ``rtl/fp`` with delay registers
balancing the paths, one test per enabled cycle at a fixed latency.

:class:`IntersectionUnit` wraps it: it keeps the read-only ray data and the best hit per
(thread, lane) in local memories, fetches each requested triangle (5 words through its memory
port, up to ``tri_slots`` triangles ahead of the one being tested), tests every lane of the
request's mask, keeps the closest hit, reports each lane of a leaf to traversal after the leaf's
last triangle and reads out the final hits of a finished packet.
"""
from __future__ import annotations

from amaranth.hdl import Array, C, Cat, Const, Module, Mux, Signal, Value
from amaranth.lib import data, stream, wiring
from amaranth.lib.memory import Memory
from amaranth.lib.wiring import In, Out
from amaranth.utils import ceil_log2

from model.config import Config
from model.fp import FPFormat

from .fp import FPAdd, FPDiv, FPMul
from .fp.common import unpack
from .memport import WORD_BITS, MemReadPort
from .rtc_streams import (PACKET_ID_BITS, TRI_ID_BITS, LaneResult, RayIn, RayResult,
                          TriRequest, lane_bits)

__all__ = ["IntersectPipe", "IntersectionUnit", "RayWrite", "PacketDone", "from_binary32",
           "TRI_WORDS"]

COUNTER_BITS = 32
TRI_WORDS = 5


def RayWrite(cfg: Config) -> data.StructLayout:
    """A ray written into the unit's local store: the RTC's ``RayIn`` and the thread it runs in."""
    return data.StructLayout({"thread": cfg.thread_bits, "ray": RayIn(cfg)})


def PacketDone(cfg: Config) -> data.StructLayout:
    """Read out the final hits of ``thread``'s lanes in ``mask``, labelled with ``packet``."""
    return data.StructLayout({"thread": cfg.thread_bits, "packet": PACKET_ID_BITS,
                              "mask": cfg.packet_size})


def from_binary32(fmt: FPFormat, x: Value) -> Value:
    """A format word from the binary32 pattern of a format value (as memory holds it): the sign,
    the exponent re-biased (0 and all-ones kept) and the top M fraction bits."""
    x = Value.cast(x)
    E, M = fmt.exp_bits, fmt.frac_bits
    if (E, M) == (8, 23):
        return x
    e32 = x[23:31]
    emax = (1 << E) - 1
    e = Mux(e32 == 0, 0, Mux(e32 == 0xFF, emax, (e32 - 127 + fmt.bias)[:E]))
    return Cat(x[23 - M:23], e[:E], x[31])


class _Schedule:
    """Builds a fixed-latency datapath: each value carries the cycle it is ready in; an
    operation waits for its latest operand, the others go through (shared) delay registers."""

    UNITS = {"add": FPAdd, "sub": FPAdd, "mul": FPMul, "div": FPDiv}

    def __init__(self, m: Module, en: Value, fmt: FPFormat, latencies: dict, dry: bool = False):
        self.m, self.en, self.fmt, self.lat, self.dry = m, en, fmt, latencies, dry
        self.taps: dict[int, list[Signal]] = {}
        self.n = 0

    def at(self, value, t0: int, t: int) -> Value:
        """``value`` (ready at cycle ``t0``) as seen at cycle ``t >= t0``."""
        value = Value.cast(value)
        if isinstance(value, Const) or t == t0:
            return value
        chain = self.taps.setdefault(id(value), [value])
        self.taps.setdefault(("keep", id(value)), value)      # keep id() stable
        while len(chain) <= t - t0:
            prev = chain[-1]
            reg = Signal.like(prev, name=f"dly{self.n}", reset_less=True)
            self.n += 1
            with self.m.If(self.en):
                self.m.d.sync += reg.eq(prev)
            chain.append(reg)
        return chain[t - t0]

    def op(self, kind: str, a: tuple, b: tuple, name: str) -> tuple:
        """``(value, ready cycle)`` of ``a kind b``; operands are ``(value, ready cycle)``."""
        t = max(a[1], b[1])
        out = Signal(self.fmt.width, name=name)
        if self.dry:
            return out, t + self.lat[kind]
        unit = self.UNITS[kind](self.fmt, latency=self.lat[kind])
        assert unit.latency == self.lat[kind]
        self.m.submodules[name] = unit
        self.m.d.comb += [unit.a.eq(self.at(a[0], a[1], t)), unit.b.eq(self.at(b[0], b[1], t)),
                          unit.en.eq(self.en)]
        if kind in ("add", "sub"):
            self.m.d.comb += unit.op.eq(kind == "sub")
        self.m.d.comb += out.eq(unit.o)
        return out, t + unit.latency


def _pick(v, k):
    return Mux(k == 0, v[0], Mux(k == 1, v[1], v[2]))


class IntersectPipe(wiring.Component):
    """Bare intersection datapath: ``model.intersection.intersect`` as a pipeline.

    In: ``tri`` (9 format words: A, B, C), ``org`` (3), ``k`` (kx, ky, kz), ``s`` (Sx, Sy, Sz),
    ``tag`` (carried along unchanged), ``i_valid``, ``en``. Out after ``latency`` enabled cycles:
    ``o_valid``, ``hit`` (edge test passed and det != 0), ``t``, ``u``, ``v`` (zero when not
    ``hit``, as the model returns them), ``tag``.

    Operations (all rounded to the format, the model's order): 9 subs (vertices - origin), 9
    muls (Sx, Sy times the z of each vertex; Sz times it), 6 subs (shear), 6 muls + 3 subs (edge
    functions U, V, W), 2 adds (det), 3 muls + 2 adds (T), 1 div (1/det), 3 muls (t, u, v):
    20 add/sub, 21 mul, 1 div. Latency (binary32, default FP latencies 3/3/8): 32 cycles.
    Throughput: one test per cycle in which ``en`` is 1 (``en`` = 0 holds every stage).
    ``latencies``: optional ``{"add": n, "mul": n, "div": n}`` for the FP units.
    """

    def __init__(self, fmt: FPFormat, tag_width: int = 1, latencies: dict | None = None):
        self.fmt = fmt
        self.tag_width = tag_width
        self.latencies = dict(latencies or {})
        for kind in ("add", "mul", "div"):
            if self.latencies.get(kind) is None:
                probe = _Schedule.UNITS[kind](fmt)          # the unit's default latency
                probe._MustUse__silence = True
                self.latencies[kind] = probe.latency
        self.latencies["sub"] = self.latencies["add"]
        w = fmt.width
        super().__init__({
            "tri": In(data.ArrayLayout(w, 9)), "org": In(data.ArrayLayout(w, 3)),
            "k": In(data.ArrayLayout(2, 3)), "s": In(data.ArrayLayout(w, 3)),
            "tag": In(tag_width), "i_valid": In(1), "en": In(1, init=1),
            "o_valid": Out(1), "hit": Out(1), "t": Out(w), "u": Out(w), "v": Out(w),
            "o_tag": Out(tag_width),
        })
        dry = Module()
        dry._MustUse__silence = True
        self.latency = self._build(dry, dry=True)[1]         # the schedule's length

    def _build(self, m, dry=False):
        fmt, w = self.fmt, self.fmt.width
        sch = _Schedule(m, self.en, fmt, self.latencies, dry)
        kx, ky, kz = self.k[0], self.k[1], self.k[2]
        sx, sy, sz = (self.s[0], 0), (self.s[1], 0), (self.s[2], 0)
        # -- vertices relative to the origin, then into the ray's sheared space -------------------
        rel = [sch.op("sub", (self.tri[3 * v + a], 0), (self.org[a], 0), f"rel{v}{a}")
               for v in range(3) for a in range(3)]
        sheared, zs = [], []
        for v, name in enumerate("abc"):
            p = rel[3 * v:3 * v + 3]
            t = p[0][1]
            px, py, pz = ((_pick([q[0] for q in p], sch.at(kk, 0, t)), t) for kk in (kx, ky, kz))
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
        m.d.comb += [
            self.hit.eq(hit),
            self.t.eq(Mux(hit, sch.at(t[0], t[1], L), 0)),
            self.u.eq(Mux(hit, sch.at(u[0], u[1], L), 0)),
            self.v.eq(Mux(hit, sch.at(v[0], v[1], L), 0)),
            self.o_valid.eq(sch.at(self.i_valid, 0, L)),
            self.o_tag.eq(sch.at(self.tag, 0, L)),
        ]
        return m, L

    @staticmethod
    def _wire(m, v, name):
        s = Signal.like(Value.cast(v), name=name)
        m.d.comb += s.eq(v)
        return s

    def elaborate(self, platform):
        return self._build(Module())[0]
