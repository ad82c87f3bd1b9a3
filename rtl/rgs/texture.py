"""RGS slave: the texture unit, a textured hit's kd times its bilinearly filtered texels.

The golden model is ``model/rgs/texture.py`` (``texture_kd``: ``tex_st``, ``wrap``, ``pos``,
``fetch``, ``filter``, ``scale``, ``kd``), bit for bit (``docs/rgs.md``).

* :class:`TexCoordPipe`: a hit's texel indices and bilinear weights; :func:`wrap_coord`,
  :func:`tex_pos` (combinational).
* :class:`TexFilterPipe`: four texels and the weights -> kd times the filtered colour.
* :class:`Texture`: both as a stream unit with the texel reads between them.
"""
from __future__ import annotations

from amaranth.hdl import Array, Cat, Const, Module, Mux, Signal, Value
from amaranth.lib import data, stream, wiring
from amaranth.lib.wiring import In, Out

from model.config import Config
from model.fp import FPFormat
from model.rgs.texture import TEX_FRAC, TEX_ONE, TEX_SCALE, UV_FRAC

from ..fp.common import bits_for, unpack, wire
from ..fp.conv import FPFromInt
from ..memport import WORD_BITS, MemReadPort
from ..rtc_streams import vec3
from ..fp.schedule import Schedule
from .common import _Datapath, _fp_const

__all__ = ["TEX_SIZE_BITS", "TEX_INDEX_BITS", "wrap_coord", "tex_pos", "TexCoordPipe",
           "TexFilterPipe", "TexIn", "TexOut", "Texture"]

TEX_SIZE_BITS = 16     # texture width and height: 1 .. 65535 texels (model.layout)
TEX_INDEX_BITS = 32    # a texel's index in its texture, y * width + x


def wrap_coord(fmt: FPFormat, x: Value) -> Value:
    """``model.rgs.wrap_coord`` (combinational): floor(x * 2**UV_FRAC) mod 2**UV_FRAC, 0 for a
    NaN, an infinity or a zero. With the significand ``sig`` (hidden bit included) padded
    with UV_FRAC - 1 zeros, x * 2**UV_FRAC is that padding shifted right by
    ``s = bias + M - 1 - exp``; from exp = bias + M up every bit lies at 2**UV_FRAC or above
    (0); a negative x is -(magnitude + 1 if bits were shifted out), kept mod 2**UV_FRAC."""
    u = unpack(fmt, x)
    M = fmt.frac_bits
    pad = UV_FRAC - 1
    wide = Cat(Const(0, pad), u.sig)
    W = len(wide)
    s_top = fmt.bias + M - 1
    big = (u.exp >= fmt.bias + M) | u.inf | u.nan
    raw = Const(s_top, bits_for(s_top + 1)) - u.exp
    s = Mux(raw > W, W, raw[:bits_for(W)])
    mag = (wide >> s)[:UV_FRAC]
    mask = ((Const(1, W + 1) << s) - 1)[:W]
    sticky = (wide & mask) != 0
    neg = (-(mag + sticky))[:UV_FRAC]
    return Mux(big, 0, Mux(u.sign, neg, mag))


def tex_pos(m: Module, fs: Value, size: Value, name: str) -> tuple:
    """``model.rgs.tex_pos`` (combinational): (i0, i1, weight) along one axis for the wrapped
    coordinate ``fs`` (UV_FRAC bits, up to 2**UV_FRAC inclusive) on a texture ``size`` texels
    long: X = ((fs * size) >> (UV_FRAC - TEX_FRAC)) - 2**(TEX_FRAC - 1); i0 = X >> TEX_FRAC
    (-1 wraps to size - 1), i1 = i0 + 1 (size wraps to 0), weight = X mod 2**TEX_FRAC."""
    prod = wire(m, (fs * size)[UV_FRAC - TEX_FRAC:], f"{name}_prod")
    x = wire(m, prod.as_signed() - (1 << (TEX_FRAC - 1)), f"{name}_x")
    i0 = x[TEX_FRAC:].as_signed()
    i1 = wire(m, (i0 + 1)[:TEX_SIZE_BITS + 1], f"{name}_i1")
    return (wire(m, Mux(i0 < 0, size - 1, i0[:TEX_SIZE_BITS])[:TEX_SIZE_BITS], f"{name}_i0"),
            wire(m, Mux(i1 == size, 0, i1)[:TEX_SIZE_BITS], f"{name}_i1w"),
            wire(m, x[:TEX_FRAC], f"{name}_w"))


class TexCoordPipe(_Datapath):
    """Bare texture-coordinate datapath: a hit's texel indices and bilinear weights
    (``model.rgs.texture_kd``'s ``tex_st``, ``wrap``, ``pos`` and the row products).

    In: ``u``, ``v`` (the hit), ``uv`` (the triangle's s0, t0, s1, t1, s2, t2), ``tw``,
    ``th`` (the texture's size), ``tag``, ``i_valid``, ``en``. Out after ``latency`` enabled
    cycles: ``j`` (the texel indices y*tw + x of (x0, y0), (x1, y0), (x0, y1), (x1, y1)),
    ``wx``, ``wy`` (the weights of x1 and y1, TEX_FRAC bits), ``o_tag``.

    Operations: b = (1 - u) - v (2 sub), s and t (6 mul, 4 add); then a register after the
    wrap and the positions (two UV_FRAC x 16-bit products) and one after the row products
    (two 16 x 16). Latency 2 add + mul + 2 add + 2 (17 at the binary32 defaults).
    Throughput: one hit per enabled cycle.
    """

    def __init__(self, fmt: FPFormat, tag_width: int = 1, latencies: dict | None = None,
                 budget: dict | None = None):
        w = fmt.width
        super().__init__(fmt, tag_width, latencies,
                         {"u": In(w), "v": In(w), "uv": In(data.ArrayLayout(w, 6)),
                          "tw": In(TEX_SIZE_BITS), "th": In(TEX_SIZE_BITS)},
                         {"j": Out(data.ArrayLayout(TEX_INDEX_BITS, 4)), "wx": Out(TEX_FRAC),
                          "wy": Out(TEX_FRAC)}, budget)

    def _build(self, m: Module, dry: bool = False) -> int:
        return self._emit(m, self._schedule(m, dry), dry)

    def _graph(self, m: Module, sch: Schedule, t0: int, dry: bool) -> tuple:
        """The operations, inputs ready at cycle ``t0``: ``(L, outputs)``, the cycle the
        outputs are ready in and ``{port name: value}`` (None when ``dry``)."""
        fmt = self.fmt
        at = sch.at
        u, v = (wire(m, self.u, "u"), t0), (wire(m, self.v, "v"), t0)
        uv = [(wire(m, self.uv[k], f"uv{k}"), t0) for k in range(6)]
        one = (_fp_const(fmt, "one"), t0)
        b = sch.op("sub", sch.op("sub", one, u, "tex_1u"), v, "tex_b")
        st = [sch.op("add", sch.op("add", sch.op("mul", b, uv[k], f"tex_b{k}"),
                                   sch.op("mul", u, uv[2 + k], f"tex_u{k}"), f"tex_a{k}"),
                     sch.op("mul", v, uv[4 + k], f"tex_v{k}"), f"tex_st{k}") for k in range(2)]
        T = max(x[1] for x in st)
        L = T + 2
        if dry:
            return L, None

        def reg(value, name):            # one register that loads with en
            r = Signal.like(Value.cast(value), name=name)
            with m.If(self.en):
                m.d.sync += r.eq(value)
            return r
        tw, th = at(self.tw, t0, T), at(self.th, t0, T)
        fs = wire(m, wrap_coord(fmt, at(st[0][0], st[0][1], T)), "tex_fs")
        ft = wire(m, (1 << UV_FRAC) - wrap_coord(fmt, at(st[1][0], st[1][1], T)), "tex_ft")
        x0, x1, wx = tex_pos(m, fs, tw, "tex_x")
        y0, y1, wy = tex_pos(m, ft[:UV_FRAC + 1], th, "tex_y")
        r = {k: reg(val, f"tex_{k}") for k, val in
             (("x0", x0), ("x1", x1), ("wx", wx), ("y0", y0), ("y1", y1), ("wy", wy))}
        tw1 = at(self.tw, t0, T + 1)
        row0 = reg(r["y0"] * tw1, "tex_row0")
        row1 = reg(r["y1"] * tw1, "tex_row1")
        x0d, x1d = reg(r["x0"], "tex_x0d"), reg(r["x1"], "tex_x1d")
        j = [(row + x)[:TEX_INDEX_BITS] for row in (row0, row1) for x in (x0d, x1d)]
        return L, {"j": Cat(*j), "wx": reg(r["wx"], "tex_wxd"), "wy": reg(r["wy"], "tex_wyd"),
                   "o_tag": at(self.tag, t0, L)}


class TexFilterPipe(_Datapath):
    """Bare texture filter: four RGBA8 texels and the weights -> kd times the filtered
    colour (``model.rgs.texture_kd``'s ``filter``, ``scale``, ``kd``).

    In: ``t`` (texels (x0, y0), (x1, y0), (x0, y1), (x1, y1), 32 bits each, R in bits 0..7),
    ``wx``, ``wy``, ``kd`` (3 format words), ``on`` (0: kd passes unchanged), ``tag``,
    ``i_valid``, ``en``. Out after ``latency`` enabled cycles: ``kd_o``, ``o_tag``.

    Per channel: the two row blends (4 products of 8 x 9 bits) registered, the column blend
    (2 products of 17 x 9 bits) registered, an int -> FP conversion of the 24-bit sum with 24
    fraction bits, a multiplication by fmt(256/255) and one by kd. Latency 2 + conv + 2 mul
    (10 at the binary32 defaults). Throughput: one hit per enabled cycle.
    """

    def __init__(self, fmt: FPFormat, tag_width: int = 1, latencies: dict | None = None,
                 budget: dict | None = None):
        v3 = data.ArrayLayout(fmt.width, 3)
        super().__init__(fmt, tag_width, latencies,
                         {"t": In(data.ArrayLayout(32, 4)), "wx": In(TEX_FRAC),
                          "wy": In(TEX_FRAC), "kd": In(v3), "on": In(1)},
                         {"kd_o": Out(v3)}, budget)

    def _build(self, m: Module, dry: bool = False) -> int:
        return self._emit(m, self._schedule(m, dry), dry)

    def _graph(self, m: Module, sch: Schedule, t0: int, dry: bool) -> tuple:
        """The operations, inputs ready at cycle ``t0``: ``(L, outputs)``, the cycle the
        outputs are ready in and ``{port name: value}`` (None when ``dry``)."""
        fmt = self.fmt
        at = sch.at
        scale = (Const(fmt.to_bits(fmt.quantize(TEX_SCALE)).item(), fmt.width), t0)
        if not dry:                      # the blends' weights: 256 - w and w
            nx = wire(m, TEX_ONE - self.wx, "tex_nx")
            ny = at(wire(m, TEX_ONE - self.wy, "tex_ny"), t0, t0 + 1)
            wy = at(self.wy, t0, t0 + 1)
        out = []
        for c in range(3):
            conv = FPFromInt(fmt, int_width=UV_FRAC, signed=False, frac_bits=UV_FRAC,
                             latency=self.latencies["conv"])
            tex = (wire(m, conv.o, f"tex_f{c}"), t0 + 2 + conv.latency)
            kd = (wire(m, self.kd[c], f"kd{c}"), t0)
            out.append(sch.op("mul", kd, sch.op("mul", tex, scale, f"tex_s{c}"), f"tex_kd{c}"))
            if dry:
                conv._MustUse__silence = True
                continue
            m.submodules[f"tex_conv{c}"] = conv
            a = [self.t[k][8 * c:8 * c + 8] for k in range(4)]
            r0 = Signal(2 * TEX_FRAC + 1, name=f"tex_r0_{c}")      # row y0's blend
            r1 = Signal(2 * TEX_FRAC + 1, name=f"tex_r1_{c}")      # row y1's
            col = Signal(UV_FRAC, name=f"tex_c{c}")
            with m.If(self.en):
                m.d.sync += [r0.eq(a[0] * nx + a[1] * self.wx), r1.eq(a[2] * nx + a[3] * self.wx),
                             col.eq(r0 * ny + r1 * wy)]
            m.d.comb += [conv.a.eq(col), conv.en.eq(self.en)]
        L = max(x[1] for x in out)
        if dry:
            return L, None
        on = at(self.on, t0, L)
        return L, {"kd_o": Cat(*(Mux(on, at(*x, L), at(self.kd[c], t0, L))
                                 for c, x in enumerate(out))),
                   "o_tag": at(self.tag, t0, L)}


def TexIn(cfg: Config, tag_width: int = 1) -> data.StructLayout:
    """A hit into :class:`Texture`: ``u``, ``v``, the triangle's texture coordinates ``uv``
    (s0, t0, s1, t1, s2, t2), its texture's first texel word ``addr`` and size ``tw``,
    ``th``, ``on`` (0: not textured, kd passes), the record's ``kd``, a ``tag``."""
    w = cfg.fmt.width
    return data.StructLayout({"u": w, "v": w, "uv": data.ArrayLayout(w, 6), "addr": 32,
                              "tw": TEX_SIZE_BITS, "th": TEX_SIZE_BITS, "on": 1,
                              "kd": vec3(cfg), "tag": tag_width})


def TexOut(cfg: Config, tag_width: int = 1) -> data.StructLayout:
    """A hit out of :class:`Texture`: its diffuse constant (kd times the filtered texel colour
    where textured) and its tag."""
    return data.StructLayout({"kd": vec3(cfg), "tag": tag_width})


class Texture(wiring.Component):
    """The slave's texture unit: a textured hit's kd times its bilinearly filtered texel
    colour (``model.rgs.texture_kd``), every hit in order.

    Ports: ``i`` (In stream :func:`TexIn`), ``o`` (Out stream :func:`TexOut`), ``mem``
    (:class:`~rtl.memport.MemReadPort` of 64-bit texel words; it must answer in request
    order, as ``rtl.cache.Cache`` does: the slave's texel cache).

    Stages: :class:`TexCoordPipe` (the texel indices and weights), an issue stage that sends
    a textured hit's four word requests (word = addr + index // 2; the texel is the word's
    low half for an even index), one a cycle, and queues the hit (``queue`` entries, from its
    first request on); a collector that takes the four responses in order; then
    :class:`TexFilterPipe` and an output queue of ``out_depth`` hits (the pipes stall as one
    while it is full). An untextured hit requests nothing and passes in order.
    Latency: TexCoordPipe + 1 + TexFilterPipe + 1 (29 at the binary32 defaults) for an
    untextured hit; a textured one adds the memory's latency and 3 cycles.
    Throughput: one untextured hit a cycle, one textured hit per 4 cycles (4 words); with
    :meth:`Config.rgs_budget` (shared FP units) at most one hit per ``ii`` cycles of either
    pipe.
    """

    def __init__(self, cfg: Config, tag_width: int = 1, latencies: dict | None = None,
                 queue: int = 8, out_depth: int = 4, pooled: bool = False):
        self.cfg, self.queue, self.out_depth, self.pooled = cfg, queue, out_depth, pooled
        fmt = cfg.fmt
        lat = cfg.fp_latencies() if latencies is None else latencies
        budget = None if pooled else cfg.rgs_budget()
        self.carry = data.StructLayout({"addr": 32, "on": 1, "kd": vec3(cfg), "tag": tag_width})
        self.coord = TexCoordPipe(fmt, self.carry.size, lat, budget)
        self.wait = data.StructLayout({"kd": vec3(cfg), "tag": tag_width, "on": 1, "half": 4,
                                       "wx": TEX_FRAC, "wy": TEX_FRAC})
        self.filter = TexFilterPipe(fmt, tag_width, lat, budget)
        if pooled:                       # ports only: the pool builds both
            self.coord._MustUse__silence = self.filter._MustUse__silence = True
        super().__init__({
            "i": In(stream.Signature(TexIn(cfg, tag_width))),
            "o": Out(stream.Signature(TexOut(cfg, tag_width))),
            "mem": Out(MemReadPort(addr_width=cfg.addr_bits, data_width=WORD_BITS,
                                   tag_width=1)),
        })

    @property
    def latency(self) -> int:
        return self.coord.latency + 1 + self.filter.latency + 1

    def elaborate(self, platform):
        from amaranth.lib.fifo import SyncFIFO
        m = Module()
        cp, fp = self.coord, self.filter
        out_depth = self.out_depth
        if self.pooled:
            out_depth = max(out_depth, fp.in_flight + 1)
        else:
            m.submodules.coord, m.submodules.filter = cp, fp
        m.submodules.waitq = waitq = SyncFIFO(width=self.wait.size, depth=self.queue)
        m.submodules.outq = outq = SyncFIFO(width=len(self.o.payload.as_value()),
                                            depth=out_depth)
        p = self.i.payload
        # -- TexCoordPipe: held while its output hit is not yet queued (on the pool: its
        #    outputs queued, a hit taken only while there is room) ------------------------------
        ci = data.View(self.carry, cp.tag)
        m.d.comb += [cp.u.eq(p.u), cp.v.eq(p.v), cp.uv.eq(p.uv), cp.tw.eq(p.tw), cp.th.eq(p.th),
                     ci.addr.eq(p.addr), ci.on.eq(p.on), ci.kd.eq(p.kd), ci.tag.eq(p.tag)]
        done = Signal()                  # the issue stage is done with the coordinates' hit
        if self.pooled:
            lay = data.StructLayout({"tag": self.carry, "j": data.ArrayLayout(TEX_INDEX_BITS, 4),
                                     "wx": TEX_FRAC, "wy": TEX_FRAC})
            depth = cp.in_flight + 1
            m.submodules.coordq = cq = SyncFIFO(width=lay.size, depth=depth)
            held = Signal(range(depth + 1))
            credit = Signal()
            fed = cp.i_valid & cp.i_slot
            m.d.comb += [credit.eq(held < depth), cp.en.eq(1),
                         cp.i_valid.eq(self.i.valid & credit),
                         self.i.ready.eq(credit & cp.i_slot),
                         cq.w_en.eq(cp.o_valid),
                         cq.w_data.eq(Cat(cp.o_tag, cp.j.as_value(), cp.wx, cp.wy)),
                         cq.r_en.eq(cq.r_rdy & done)]
            m.d.sync += held.eq(held + fed - (cq.r_rdy & done))
            head = data.View(lay, cq.r_data)
            c_valid, c_tag, c_j, c_wx, c_wy = cq.r_rdy, head.tag.as_value(), head.j, head.wx, head.wy
        else:
            en_a = Signal()
            m.d.comb += [cp.en.eq(en_a), cp.i_valid.eq(self.i.valid),
                         self.i.ready.eq(en_a & cp.i_slot), en_a.eq(~cp.o_valid | done)]
            c_valid, c_tag, c_j, c_wx, c_wy = cp.o_valid, cp.o_tag, cp.j, cp.wx, cp.wy
        # -- issue: a textured hit's four requests, the hit queued with the first ---------------
        co = data.View(self.carry, c_tag)
        cnt = Signal(2)
        req = self.mem.req
        first = cnt == 0
        m.d.comb += [req.valid.eq(c_valid & co.on & (~first | waitq.w_rdy)),
                     req.payload.addr.eq(co.addr + (Array(c_j)[cnt] >> 1)),
                     req.payload.tag.eq(0)]
        sent = req.valid & req.ready
        with m.If(sent):
            m.d.sync += cnt.eq(cnt + 1)
        push = c_valid & Mux(co.on, sent & first, waitq.w_rdy)
        m.d.comb += done.eq(c_valid & Mux(co.on, sent & (cnt == 3), waitq.w_rdy))
        w_in = Signal(self.wait)
        m.d.comb += [w_in.kd.eq(co.kd), w_in.tag.eq(co.tag), w_in.on.eq(co.on),
                     w_in.half.eq(Cat(*(c_j[k][0] for k in range(4)))),
                     w_in.wx.eq(c_wx), w_in.wy.eq(c_wy),
                     waitq.w_data.eq(w_in), waitq.w_en.eq(push)]
        # -- collector: the head's four texels in order, then the filter ------------------------
        head = data.View(self.wait, waitq.r_data)
        resp = self.mem.resp
        got = Signal(2)
        held = [Signal(32, name=f"texel{k}") for k in range(3)]
        texel = Mux(head.half.bit_select(got, 1), resp.payload.data[32:], resp.payload.data[:32])
        en_f = Signal()                  # the filter may take a hit
        if self.pooled:                  # room for every hit in it and the output queue
            n_f = Signal(range(out_depth + 1))
            m.d.comb += [en_f.eq(n_f < out_depth), fp.en.eq(1)]
        else:
            m.d.comb += [en_f.eq(~fp.o_valid | outq.w_rdy), fp.en.eq(en_f)]
        last = got == 3
        go_f = en_f & fp.i_slot          # the filter takes a hit (its slot, with shared units)
        m.d.comb += resp.ready.eq(waitq.r_rdy & head.on & (~last | go_f))
        take = resp.valid & resp.ready
        with m.If(take):
            m.d.sync += got.eq(got + 1)
            for k in range(3):
                with m.If(got == k):
                    m.d.sync += held[k].eq(texel)
        feed = waitq.r_rdy & go_f & Mux(head.on, resp.valid & last, 1)
        m.d.comb += [waitq.r_en.eq(feed), fp.i_valid.eq(feed),
                     fp.t.eq(Cat(*held, texel)), fp.wx.eq(head.wx), fp.wy.eq(head.wy),
                     fp.kd.eq(head.kd), fp.on.eq(head.on), fp.tag.eq(head.tag)]
        if self.pooled:
            m.d.sync += n_f.eq(n_f + feed - (self.o.valid & self.o.ready))
        # -- output queue ----------------------------------------------------------------------
        out = Signal(self.o.payload.shape())
        m.d.comb += [out.kd.eq(fp.kd_o), out.tag.eq(fp.o_tag),
                     outq.w_data.eq(out), outq.w_en.eq(fp.o_valid & outq.w_rdy),
                     self.o.valid.eq(outq.r_rdy), self.o.payload.eq(outq.r_data),
                     outq.r_en.eq(self.o.ready)]
        return m
