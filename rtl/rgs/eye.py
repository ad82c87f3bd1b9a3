"""RGS slave: eye rays from camera registers and ray setup, in FP hardware.

The golden model is ``model/rgs/eye.py`` (``eye_ray``, ``ray_setup``); every FP operation here
is one of its steps, in its order, so the rays come out bit for bit as
``model.raygen.eye_rays`` + ``setup`` make them (``docs/rgs.md``).

* :class:`RaySetupPipe`: the bare ray-setup datapath (``inv``, ``axes``, ``shear``, ``slab``,
  ``flat``, ``order``, ``clip``, ``octant``), fixed latency, one ray per enabled cycle.
* :class:`RaySetup`: the datapath as a stream unit: (org, dir, tmax, anyhit, packet, lane, last)
  in, ``RayIn`` out, back-pressure (the slave's secondary rays).
* :class:`EyeRayPipe`: the bare eye-ray datapath: sample (sx, sy) -> direction (``sample``,
  ``mul_x``, ``mul_y``, ``add_x``, ``add_y``) and the pixel index.
* :class:`EyeRays`: the slave's ray generator: packet requests in, each tile's rays in lane
  order through :class:`EyeRayPipe` and :class:`RaySetupPipe`, ``RayIn`` (+ pixel index) out.

Flow control of the stream units: one clock enable stalls the whole pipeline while its last
stage holds a ray the consumer does not take (``en = ~o.valid | o.ready``; ``i.ready = en``),
so rays leave in order, one per cycle at full rate, at exactly ``latency`` cycles after they
entered when the output is never stalled.
"""
from __future__ import annotations

from types import SimpleNamespace

from amaranth.hdl import C, Cat, Module, Mux, Signal, Value
from amaranth.lib import data, stream, wiring
from amaranth.lib.fifo import SyncFIFO
from amaranth.lib.wiring import In, Out
from amaranth.utils import ceil_log2

from model.config import COORD_BITS, Config
from model.fp import FPFormat

from ..fp.common import unpack, wire
from ..fp.conv import FPFromInt
from ..fp.schedule import Schedule
from ..rtc_streams import PACKET_ID_BITS, RayIn, lane_bits, vec3
from .common import _Datapath, _fp_const

__all__ = ["COORD_BITS", "PIXEL_BITS", "RaySetupIn", "EyeRequest", "EyeRay", "RaySetupPipe",
           "RaySetup", "EyeRayPipe", "EyeRays", "div_const", "div_const_params",
           "sample_converter"]

PIXEL_BITS = 32        # pixel index y * width + x
# COORD_BITS (model.config): sample coordinates (and image sizes in samples) below 2**16


def RaySetupIn(cfg: Config) -> data.StructLayout:
    """A ray into :class:`RaySetup`: its place in a packet and what ray setup needs."""
    w = cfg.fmt.width
    return data.StructLayout({
        "packet": PACKET_ID_BITS, "lane": lane_bits(cfg), "last": 1,
        "org": vec3(cfg), "dir": vec3(cfg), "tmax": w, "anyhit": 1,
    })


def EyeRequest(cfg: Config) -> data.StructLayout:
    """A packet request to :class:`EyeRays`: tile (``tile_x``, ``tile_y``) of the sample image
    (tile coordinates, so no division by the tiles per row is needed), labelled ``packet``."""
    return data.StructLayout({"tile_x": COORD_BITS, "tile_y": COORD_BITS,
                              "packet": PACKET_ID_BITS})


def EyeRay(cfg: Config) -> data.StructLayout:
    """An eye ray out of :class:`EyeRays`: the ``RayIn`` for the RTC, the index
    ``y * width + x`` of the pixel the sample belongs to and the ray's direction (which the
    slave keeps for the ray's secondary rays)."""
    return data.StructLayout({"ray": RayIn(cfg), "pixel": PIXEL_BITS, "dir": vec3(cfg)})


def div_const_params(n: int, bits: int) -> tuple[int, int]:
    """``(m, k)`` with ``v // n == (v * m) >> k`` for every ``0 <= v < 2**bits``:
    ``k = bits + ceil(log2 n)``, ``m = ceil(2**k / n)``. (With v = q*n + r, v*m/2**k =
    v/n + v*e/(n*2**k), e = m*n - 2**k < n, and v*e < 2**bits * n <= 2**k: the excess is below
    1/n, too little to carry r/n <= (n-1)/n over the next integer.)"""
    if n < 1:
        raise ValueError(f"div_const: n={n} must be >= 1")
    k = bits + ceil_log2(n)
    return -(-(1 << k) // n), k


def div_const(v: Value, n: int) -> Value:
    """``v // n`` for an unsigned ``v`` and a constant ``n``: a shift for a power of two,
    else a multiplication by :func:`div_const_params`'s reciprocal."""
    v = Value.cast(v)
    if n & (n - 1) == 0:
        return v >> ceil_log2(n)
    mult, k = div_const_params(n, len(v))
    return (v * mult)[k:k + len(v)]


def sample_converter(fmt: FPFormat, coord_bits: int = COORD_BITS, latency: int = 2) -> FPFromInt:
    """The ``sample`` step's converter: the ``coord_bits + 1``-bit unsigned integer 2*s + 1 with
    one fraction bit, i.e. s + 0.5 rounded once to ``fmt`` (= ``fmt.quantize(s + 0.5)`` for
    every s < 2**coord_bits: ``tests/test_rgs.py`` checks the whole range)."""
    return FPFromInt(fmt, int_width=coord_bits + 1, signed=False, frac_bits=1, latency=latency)




def _pick(v, k):
    return Mux(k == 0, v[0], Mux(k == 1, v[1], v[2]))




class RaySetupPipe(_Datapath):
    """Bare ray-setup datapath: ``model.rgs.ray_setup`` as a pipeline.

    In: ``org``, ``dir`` (3 format words each), ``tmax``, ``tag`` (carried along unchanged),
    ``i_valid``, ``en``; ``lo``, ``hi``: the scene box (held constant while rays are in
    flight). Out after ``latency`` enabled cycles: ``o_valid``, ``o_org``, ``o_dir``, ``inv``,
    ``octant``,
    ``k`` (kx, ky, kz), ``s`` (Sx, Sy, Sz), ``tnear``, ``tfar``, ``o_tmax``, ``o_tag`` (every
    output comes from registers that hold while ``en`` is 0; a ``static`` input is passed
    straight through).

    Operations (the model's steps): 3 divs (``inv``), the axis choice (magnitude compares of the
    direction's exponent:fraction keys, cycle 0, registered), 2 divs (``shear``; Sz is inv[kz],
    no divider), 6 subs and 6 muls (``slab``), the NaN rule (``flat``: a mux), 3 min + 3 max
    (``order``), 3 max + 3 min in two chains (``clip``): 5 div, 6 sub, 6 mul, 12 min/max.
    Latency: ``latency`` = max(add, div) + mul + 4 min/max (the ``clip`` chains end the
    longest path; the shear divisions, started one cycle late, end at 1 + div; at least 1):
    binary32 with the default FP latencies add 3, mul 3, div 8, min/max 1 gives 8 + 3 + 4 =
    15 cycles. Throughput: one ray per cycle in which ``en`` is 1 (``en`` = 0 holds every
    stage).
    ``latencies``: optional ``{"add": n, "mul": n, "div": n, "minmax": n}``. ``static``: names
    of inputs (``"org"``, ``"tmax"``) that are constant while rays are in flight (the eye rays'
    camera position and +inf): they skip the delay registers and go straight to the output.
    """

    STATIC = ("org", "tmax")

    def __init__(self, fmt: FPFormat, tag_width: int = 1, latencies: dict | None = None,
                 static: tuple = (), budget: dict | None = None):
        if set(static) - set(self.STATIC):
            raise ValueError(f"RaySetupPipe static={static!r}: only {self.STATIC} may be static")
        self.static = tuple(static)
        v3 = data.ArrayLayout(fmt.width, 3)
        w = fmt.width
        super().__init__(fmt, tag_width, latencies,
                         {"org": In(v3), "dir": In(v3), "tmax": In(w), "lo": In(v3),
                          "hi": In(v3)},
                         {"o_org": Out(v3), "o_dir": Out(v3), "inv": Out(v3), "octant": Out(3),
                          "k": Out(data.ArrayLayout(2, 3)), "s": Out(v3), "tnear": Out(w),
                          "tfar": Out(w), "o_tmax": Out(w)}, budget)

    def _build(self, m: Module, dry: bool = False) -> int:
        return self._emit(m, self._schedule(m, dry), dry)

    def _graph(self, m: Module, sch: Schedule, t0: int, dry: bool) -> tuple:
        """The operations, inputs ready at cycle ``t0``: ``(L, outputs)``, the cycle the
        outputs are ready in and ``{port name: value}`` (None when ``dry``)."""
        fmt = self.fmt
        d = [wire(m, self.dir[a], f"d{a}") for a in range(3)]
        org = [wire(m, self.org[a], f"o{a}") for a in range(3)]
        tmax = wire(m, self.tmax, "tmax")
        # -- inv: 1 / d per axis ------------------------------------------------------------------
        one = (_fp_const(fmt, "one"), t0)
        inv = [sch.op("div", one, (d[a], t0), f"inv{a}") for a in range(3)]
        # -- axes: kz = first axis of largest |d| (NaN key is the largest), swap if dz < 0 -------
        u = [unpack(fmt, x) for x in d]
        gt1 = u[1].key > u[0].key
        best = Mux(gt1, u[1].key, u[0].key)
        kz = wire(m, Mux(u[2].key > best, 2, Mux(gt1, 1, 0)), "axes_kz")
        neg = wire(m, _pick([x.sign & ~x.zero & ~x.nan for x in u], kz), "axes_swap")
        kx0 = Mux(kz == 2, 0, kz + 1)                     # (kz + 1) % 3
        ky0 = Mux(kz == 0, 2, kz - 1)                     # (kx + 1) % 3
        kx = wire(m, Mux(neg, ky0, kx0)[:2], "axes_kx")
        ky = wire(m, Mux(neg, kx0, ky0)[:2], "axes_ky")
        # -- shear: d[kx] / dz, d[ky] / dz (operands picked from the registered axes), inv[kz] ----
        t1 = t0 + 1
        d1 = [sch.at(x, t0, t1) for x in d]
        dz = (wire(m, _pick(d1, sch.at(kz, t0, t1)), "shear_dz"), t1)
        dkx = (wire(m, _pick(d1, sch.at(kx, t0, t1)), "shear_dkx"), t1)
        dky = (wire(m, _pick(d1, sch.at(ky, t0, t1)), "shear_dky"), t1)
        s_x = sch.op("div", dkx, dz, "shear_sx")
        s_y = sch.op("div", dky, dz, "shear_sy")
        ti = max(x[1] for x in inv)       # (one cycle unless the dividers are shared)
        s_z = (wire(m, _pick([sch.at(*x, ti) for x in inv], sch.at(kz, t0, ti)), "shear_sz"), ti)
        # -- slab, flat, order per axis -----------------------------------------------------------
        near, far = [], []
        for a in range(3):
            lo = wire(m, self.lo[a], f"lo{a}")
            hi = wire(m, self.hi[a], f"hi{a}")
            ta = sch.op("mul", sch.op("sub", (lo, t0), (org[a], t0), f"slab_lo{a}"), inv[a],
                        f"slab_t0_{a}")
            tb = sch.op("mul", sch.op("sub", (hi, t0), (org[a], t0), f"slab_hi{a}"), inv[a],
                        f"slab_t1_{a}")
            tt = max(ta[1], tb[1])
            v0, v1 = sch.at(ta[0], ta[1], tt), sch.at(tb[0], tb[1], tt)
            flat = wire(m, unpack(fmt, v0).nan | unpack(fmt, v1).nan, f"flat{a}")
            f0 = (wire(m, Mux(flat, _fp_const(fmt, "-inf"), v0), f"flat_t0_{a}"), tt)
            f1 = (wire(m, Mux(flat, _fp_const(fmt, "+inf"), v1), f"flat_t1_{a}"), tt)
            near.append(sch.op("min", f0, f1, f"order_near{a}"))
            far.append(sch.op("max", f0, f1, f"order_far{a}"))
        # -- clip: two chains in axis order -------------------------------------------------------
        tnear = (_fp_const(fmt, "+0"), t0)
        tfar = (tmax, far[0][1] if "tmax" in self.static else t0)
        for a in range(3):
            tnear = sch.op("max", tnear, near[a], f"clip_near{a}")
            tfar = sch.op("min", tfar, far[a], f"clip_far{a}")
        octant = wire(m, Cat(*(x[-1] for x in d)), "octant")
        L = max(tnear[1], tfar[1], s_x[1], s_y[1], s_z[1], t0 + 1)
        if dry:
            return L, None
        at = lambda x: sch.at(x[0], x[1], L)  # noqa: E731
        keep = lambda x, name: x if name in self.static else sch.at(x, t0, L)  # noqa: E731
        return L, {
            "o_org": Cat(*(keep(x, "org") for x in org)),
            "o_dir": Cat(*(sch.at(x, t0, L) for x in d)),
            "inv": Cat(*(at(x) for x in inv)),
            "octant": sch.at(octant, t0, L),
            "k": Cat(sch.at(kx, t0, L), sch.at(ky, t0, L), sch.at(kz, t0, L)),
            "s": Cat(at(s_x), at(s_y), at(s_z)),
            "tnear": at(tnear), "tfar": at(tfar),
            "o_tmax": keep(tmax, "tmax"),
            "o_tag": sch.at(self.tag, t0, L),
        }


def _stall(m: Module, o) -> Signal:
    """The pipeline enable of a stream unit whose last stage is its output ``o``: advance
    unless that stage holds a ray the consumer does not take."""
    en = Signal(name="en")
    m.d.comb += en.eq(~o.valid | o.ready)
    return en


def _credit_out(m: Module, pipe, lay, value: Value, o, name: str, ahead: int = 0) -> Value:
    """The output of a datapath on a pool of FP units (which never stalls) through a queue as
    deep as the inputs the datapath holds at once + 1 + ``ahead``: ``value`` (``lay``) goes in
    when ``pipe.o_valid``, ``o`` (a stream of ``lay``) takes it out. Returns the credit: 1
    while the datapath and the queue together hold fewer inputs than the queue takes, so an
    input entering now always finds room when it comes out (and the datapath runs up to
    ``ahead`` outputs ahead of a consumer that takes none)."""
    depth = pipe.in_flight + 1 + ahead
    q = SyncFIFO(width=lay.size, depth=depth)
    m.submodules[f"{name}_q"] = q
    held = Signal(range(depth + 1), name=f"{name}_held")
    fed = pipe.i_valid & pipe.i_slot
    credit = Signal(name=f"{name}_credit")
    m.d.comb += [credit.eq(held < depth), q.w_en.eq(pipe.o_valid), q.w_data.eq(value),
                 o.valid.eq(q.r_rdy), o.payload.eq(q.r_data), q.r_en.eq(o.ready)]
    m.d.sync += held.eq(held + fed - (o.valid & o.ready))
    return credit


def _ray_out(m: Module, pipe: RaySetupPipe, ray, packet, lane, last, anyhit,
             box_cull: Value, projection: bool = False) -> list:
    """Assignments of a ``RayIn`` view ``ray`` from the setup pipe's outputs. With
    ``box_cull`` = 0 a ray whose clipped interval is empty (``not tnear <= tfar``, the
    traversal's test) gets ``[+0, tmax]`` instead and is traversed like any other
    (``model.raygen.setup(box_cull=False)``: only to measure what the cull saves); a
    combinational compare and two muxes on the output registers, no cycle. ``projection``
    (``Config.int_test``): the intersection unit's ``s`` is the direction, ``k`` is 0."""
    from ..fp.cmp import compare
    keep = Signal(name="box_keep")
    m.d.comb += keep.eq(box_cull | compare(pipe.fmt, pipe.tnear, pipe.tfar).le)
    return [ray.packet.eq(packet), ray.lane.eq(lane), ray.last.eq(last),
            ray.org.eq(pipe.o_org), ray.inv.eq(pipe.inv), ray.octant.eq(pipe.octant),
            ray.tnear.eq(Mux(keep, pipe.tnear, _fp_const(pipe.fmt, "+0"))),
            ray.tfar.eq(Mux(keep, pipe.tfar, pipe.o_tmax)),
            ray.k.eq(0 if projection else pipe.k),
            ray.s.eq(pipe.o_dir if projection else pipe.s), ray.tmax.eq(pipe.o_tmax),
            ray.anyhit.eq(anyhit)]


class RaySetup(wiring.Component):
    """Ray setup as a stream unit: :class:`RaySetupPipe` with back-pressure.

    Ports: ``i`` (In stream, :func:`RaySetupIn`): org, dir, tmax, anyhit, packet, lane, last;
    ``box_lo``, ``box_hi`` (In, 3 format words each: the scene box, constant while rays are in
    flight); ``box_cull`` (In, 1 by default: 0 turns the box cull off, see :func:`_ray_out`);
    ``o`` (Out stream, ``RayIn``).
    Latency: ``latency`` cycles (= ``RaySetupPipe.latency``, 15 for binary32 with the default
    FP latencies) from a ray's input transfer to its ``o.valid``, when ``o`` is not stalled.
    Throughput: one ray per cycle; ``i.ready = ~o.valid | o.ready`` (the whole pipeline holds
    while the output ray waits). With :meth:`Config.rgs_budget` (shared FP units) one ray
    every ``pipe.ii`` cycles: ``i.ready`` also waits for the pipe's input slot.
    """

    def __init__(self, cfg: Config, latencies: dict | None = None, pooled: bool = False):
        self.cfg, self.pooled = cfg, pooled
        self.tag = data.StructLayout({"packet": PACKET_ID_BITS, "lane": lane_bits(cfg),
                                      "last": 1, "anyhit": 1})
        self.pipe = RaySetupPipe(cfg.fmt, self.tag.size,
                                 cfg.fp_latencies() if latencies is None else latencies,
                                 budget=None if pooled else cfg.rgs_budget())
        if pooled:
            self.pipe._MustUse__silence = True          # ports only: the pool builds it
        super().__init__({
            "i": In(stream.Signature(RaySetupIn(cfg))),
            "box_lo": In(vec3(cfg)), "box_hi": In(vec3(cfg)), "box_cull": In(1, init=1),
            "o": Out(stream.Signature(RayIn(cfg))),
        })

    @property
    def latency(self) -> int:
        return self.pipe.latency

    def elaborate(self, platform):
        m = Module()
        pipe = self.pipe
        p = self.i.payload
        tag_in = data.View(self.tag, pipe.tag)
        if self.pooled:
            o = stream.Signature(RayIn(self.cfg)).create(path=("setup_o",))
            en = _credit_out(m, pipe, RayIn(self.cfg), o.payload.as_value(), self.o, "setup")
            m.d.comb += pipe.en.eq(1)
            out = o.payload
        else:
            m.submodules.pipe = pipe
            en = _stall(m, self.o)
            m.d.comb += pipe.en.eq(en)
            out = self.o.payload
        m.d.comb += [
            self.i.ready.eq(en & pipe.i_slot), pipe.i_valid.eq(self.i.valid & en),
            pipe.org.eq(p.org), pipe.dir.eq(p.dir), pipe.tmax.eq(p.tmax),
            pipe.lo.eq(self.box_lo), pipe.hi.eq(self.box_hi),
            tag_in.packet.eq(p.packet), tag_in.lane.eq(p.lane), tag_in.last.eq(p.last),
            tag_in.anyhit.eq(p.anyhit),
        ]
        tag = data.View(self.tag, pipe.o_tag)
        if not self.pooled:
            m.d.comb += self.o.valid.eq(pipe.o_valid)
        m.d.comb += _ray_out(m, pipe, out, tag.packet, tag.lane, tag.last,
                             tag.anyhit, self.box_cull, self.cfg.int_test == "projection")
        return m


class EyeRayPipe(_Datapath):
    """Bare eye-ray datapath: ``model.rgs.eye_ray`` and the pixel index as a pipeline.

    In: ``sx``, ``sy`` (sample coordinates, ``coord_bits`` each), ``tag``, ``i_valid``, ``en``;
    the camera ``corner``, ``dx``, ``dy`` (3 format words each) and the image ``width`` in
    pixels (held constant while rays are in flight). Out after ``latency`` enabled cycles:
    ``o_valid``, ``dir`` (3 format words), ``pixel`` = (sy // n) * width + sx // n (n =
    ``oversampling``; a constant division: a shift or a reciprocal multiplication), ``o_tag``.

    Operations (the model's steps): 2 int -> FP conversions of 2*s + 1 with one fraction bit
    (``sample``: s + 0.5 rounded once), 6 muls (``mul_x``, ``mul_y``), 6 adds (``add_x``,
    ``add_y``). Latency: ``latency`` = max(conv + mul + 2 add, 2) (binary32 defaults:
    2 + 3 + 3 + 3 = 11 cycles; the pixel index takes 2).
    Throughput: one sample per cycle in which ``en`` is 1.
    """

    def __init__(self, fmt: FPFormat, oversampling: int = 1, tag_width: int = 1,
                 latencies: dict | None = None, coord_bits: int = COORD_BITS,
                 budget: dict | None = None):
        self.n, self.coord_bits = oversampling, coord_bits
        v3 = data.ArrayLayout(fmt.width, 3)
        super().__init__(fmt, tag_width, latencies,
                         {"sx": In(coord_bits), "sy": In(coord_bits), "corner": In(v3),
                          "dx": In(v3), "dy": In(v3), "width": In(coord_bits)},
                         {"dir": Out(v3), "pixel": Out(PIXEL_BITS)}, budget)

    def _build(self, m: Module, dry: bool = False) -> int:
        return self._emit(m, self._schedule(m, dry), dry)

    def _graph(self, m: Module, sch: Schedule, t0: int, dry: bool) -> tuple:
        """The operations, inputs ready at cycle ``t0``: ``(L, outputs)``, the cycle the
        outputs are ready in and ``{port name: value}`` (None when ``dry``)."""
        fmt = self.fmt
        # -- sample: (2*s + 1) * 2**-1 rounded once -----------------------------------------------
        pts = []
        for name, s in (("x", self.sx), ("y", self.sy)):
            conv = sample_converter(fmt, self.coord_bits, self.latencies["conv"])
            if not dry:
                m.submodules[f"sample_{name}"] = conv
                m.d.comb += [conv.a.eq(Cat(C(1, 1), s)), conv.en.eq(self.en)]
            else:
                conv._MustUse__silence = True
            pts.append((wire(m, conv.o, f"sample_p{name}"), t0 + conv.latency))
        px, py = pts
        # -- mul_x, mul_y, add_x, add_y (camera registers are static: ready whenever read) --------
        d = []
        for a in range(3):
            mx = sch.op("mul", px, (self.dx[a], px[1]), f"mul_x{a}")
            my = sch.op("mul", py, (self.dy[a], py[1]), f"mul_y{a}")
            ax = sch.op("add", (self.corner[a], mx[1]), mx, f"add_x{a}")
            d.append(sch.op("add", ax, my, f"add_y{a}"))
        # -- pixel index: quotients registered, then the row product registered -------------------
        n = self.n
        qx = wire(m, div_const(self.sx, n), "pixel_qx")
        qy = wire(m, div_const(self.sy, n), "pixel_qy")
        pixel = wire(m, (sch.at(qy, t0, t0 + 1) * self.width
                         + sch.at(qx, t0, t0 + 1))[:PIXEL_BITS], "pixel_index")
        L = max(max(x[1] for x in d), t0 + 2)
        if dry:
            return L, None
        return L, {"dir": Cat(*(sch.at(x[0], x[1], L) for x in d)),
                   "pixel": sch.at(pixel, t0 + 1, L), "o_tag": sch.at(self.tag, t0, L)}


class EyeRays(wiring.Component):
    """The RGS slave's eye-ray generator: packet requests in, ``RayIn`` s (+ pixel index) out.

    Ports
    -----
    ``req`` (In stream, :func:`EyeRequest`): tile (``tile_x``, ``tile_y``) and packet id. The
        tile must lie in the image (tile_x < ceil(width*n / tile_w), likewise y).
    ``o`` (Out stream, :func:`EyeRay`): the tile's rays in lane order (row-major over the tile's
        samples inside the image: a tile at the right/bottom edge gives a smaller packet),
        ``ray.last`` on its final lane, ``ray.packet`` the request's id, ``pixel`` = y * width
        + x of the sample's pixel. ``ray.tmax`` = +inf, ``ray.anyhit`` = 0.
    ``pos``, ``corner``, ``dx``, ``dy`` (In, 3 format words each): the camera as
        ``model.raygen.eye_rays`` quantizes it (``camera_basis`` of the sample image); ``pos``
        is every ray's origin.
    ``width``, ``height`` (In, ``coord_bits``): the image in pixels; the sample image is
        ``width*n x height*n`` (n = ``cfg.oversampling``), below 2**``coord_bits`` each.
    ``box_lo``, ``box_hi`` (In, 3 format words each): the scene box of ray setup;
    ``box_cull`` (In, 1 by default; 0: no box cull, :func:`_ray_out`).
    The camera, image size and box are registers of the slave: hold them while rays are in
    flight.

    Pipeline: the sequencer issues one sample per cycle (x fastest) into :class:`EyeRayPipe`,
    whose directions go straight into :class:`RaySetupPipe`; one enable stalls all three while
    the output ray is not taken. Latency: ``latency`` = 1 (the request is registered) +
    ``EyeRayPipe.latency`` + ``RaySetupPipe.latency`` cycles from a request's transfer to its
    first ray's ``o.valid`` (binary32 with the default FP latencies: 1 + 11 + 15 = 27), when
    the sequencer is idle and ``o`` not stalled. Throughput: one ray per cycle,
    including from one packet to the next (the next request is taken in the cycle its
    predecessor's last lane issues). With :meth:`Config.rgs_budget` (shared FP units) both
    datapaths run at one interval ``ii`` (the larger of the two the budget gives), the
    sequencer issues in the eye-ray datapath's slots and ray setup's slots are offset by the
    eye-ray datapath's latency, so each direction meets a slot: one ray every ``ii`` cycles;
    the first ray waits up to ``ii - 1`` more cycles for a slot.

    ``pooled`` (the slave's pool of FP units builds both datapaths; they never stall): the
    rays go out through a queue, as deep as the rays in the datapaths + 1 + ``ahead``, and a
    sample issues only while it will find room there, so the datapaths run up to ``ahead``
    rays ahead of a consumer that takes none (the slave: one packet, made while it waits for
    its RTC slot). ``idle``: no tile's samples left to issue and no ray in the datapaths or
    the queue.
    """

    def __init__(self, cfg: Config, latencies: dict | None = None,
                 coord_bits: int = COORD_BITS, pooled: bool = False, ahead: int = 0):
        if ahead and not pooled:
            raise ValueError("EyeRays: ahead needs pooled (its output queue)")
        self.cfg, self.coord_bits, self.pooled, self.ahead = cfg, coord_bits, pooled, ahead
        lat = cfg.fp_latencies() if latencies is None else latencies
        self.lane_bits = lane_bits(cfg)
        self.tag = data.StructLayout({"packet": PACKET_ID_BITS, "lane": self.lane_bits,
                                      "last": 1})
        self.setup_tag = data.StructLayout({"packet": PACKET_ID_BITS, "lane": self.lane_bits,
                                            "last": 1, "pixel": PIXEL_BITS})
        budget = None if pooled else cfg.rgs_budget()
        self.gen = EyeRayPipe(cfg.fmt, cfg.oversampling, self.tag.size, lat, coord_bits, budget)
        self.setup = RaySetupPipe(cfg.fmt, self.setup_tag.size, lat, static=("org", "tmax"),
                                  budget=budget)
        ii = max(self.gen.ii, self.setup.ii)
        if pooled:                     # ports only: the pool builds both
            self.gen._MustUse__silence = self.setup._MustUse__silence = True
        elif ii > 1:                   # one interval; setup's slots meet gen's outputs
            self.gen._MustUse__silence = self.setup._MustUse__silence = True
            self.gen = EyeRayPipe(cfg.fmt, cfg.oversampling, self.tag.size, lat, coord_bits,
                                  {**budget, "ii": ii})
            self.setup = RaySetupPipe(cfg.fmt, self.setup_tag.size, lat, static=("org", "tmax"),
                                      budget={**budget, "ii": ii, "offset": self.gen.latency})
        v3 = vec3(cfg)
        super().__init__({
            "req": In(stream.Signature(EyeRequest(cfg))),
            "o": Out(stream.Signature(EyeRay(cfg))),
            "pos": In(v3), "corner": In(v3), "dx": In(v3), "dy": In(v3),
            "width": In(coord_bits), "height": In(coord_bits),
            "box_lo": In(v3), "box_hi": In(v3), "box_cull": In(1, init=1),
            "idle": Out(1),
        })

    @property
    def latency(self) -> int:
        return 1 + self.gen.latency + self.setup.latency

    @property
    def in_flight(self) -> int:
        """The most samples in the two datapaths at once (on a pool: one chain)."""
        return (self.gen.latency + self.setup.latency) // self.gen.ii + 1

    def elaborate(self, platform):
        m = Module()
        cfg, cb = self.cfg, self.coord_bits
        gen, setup = self.gen, self.setup
        if self.pooled:
            o = stream.Signature(EyeRay(cfg)).create(path=("eye_o",))
            chain = SimpleNamespace(in_flight=self.in_flight, i_valid=gen.i_valid,
                                    i_slot=gen.i_slot, o_valid=setup.o_valid)
            en = _credit_out(m, chain, EyeRay(cfg), o.payload.as_value(), self.o, "eye",
                             self.ahead)
            m.d.comb += [gen.en.eq(1), setup.en.eq(1)]
            out = o.payload
        else:
            m.submodules.gen, m.submodules.setup = gen, setup
            en = _stall(m, self.o)
            m.d.comb += [gen.en.eq(en), setup.en.eq(en)]
            out = self.o.payload

        # -- sequencer: the current tile's lanes, x fastest ---------------------------------------
        tw, th, n = cfg.tile_w, cfg.tile_h, cfg.oversampling
        busy = Signal()
        packet = Signal(PACKET_ID_BITS)
        x0, y0 = Signal(cb), Signal(cb)
        wt, ht = Signal(range(tw + 1)), Signal(range(th + 1))     # the tile's size in the image
        lx, ly = Signal(range(max(2, tw))), Signal(range(max(2, th)))
        lane = Signal(self.lane_bits)
        end_x = wire(m, lx == wt - 1, "seq_end_x")
        last = wire(m, end_x & (ly == ht - 1), "seq_last")
        issue = wire(m, busy & en & gen.i_slot, "seq_issue")
        held = Signal(range(self.in_flight + self.ahead + 3))    # issued, not yet taken
        m.d.sync += held.eq(held + issue - (self.o.valid & self.o.ready))
        m.d.comb += self.idle.eq(~busy & (held == 0))
        with m.If(issue):
            m.d.sync += [lx.eq(Mux(end_x, 0, lx + 1)), lane.eq(lane + 1)]
            with m.If(end_x):
                m.d.sync += ly.eq(ly + 1)
            with m.If(last):
                m.d.sync += busy.eq(0)
        req = self.req
        m.d.comb += req.ready.eq(~busy | (issue & last))
        with m.If(req.valid & req.ready):
            rx = wire(m, req.payload.tile_x * tw, "req_x0")
            ry = wire(m, req.payload.tile_y * th, "req_y0")
            sw = wire(m, self.width * n, "sample_w")
            sh = wire(m, self.height * n, "sample_h")
            rem_x, rem_y = sw - rx, sh - ry
            m.d.sync += [
                busy.eq(1), packet.eq(req.payload.packet), x0.eq(rx), y0.eq(ry),
                wt.eq(Mux(rem_x < tw, rem_x, tw)), ht.eq(Mux(rem_y < th, rem_y, th)),
                lx.eq(0), ly.eq(0), lane.eq(0),
            ]

        # -- eye rays, then ray setup -------------------------------------------------------------
        tag = data.View(self.tag, gen.tag)
        m.d.comb += [
            gen.i_valid.eq(busy & en),
            gen.sx.eq(x0 + lx), gen.sy.eq(y0 + ly),
            tag.packet.eq(packet), tag.lane.eq(lane), tag.last.eq(last),
            gen.corner.eq(self.corner), gen.dx.eq(self.dx), gen.dy.eq(self.dy),
            gen.width.eq(self.width),
        ]
        g = data.View(self.tag, gen.o_tag)
        st = data.View(self.setup_tag, setup.tag)
        inf = _fp_const(cfg.fmt, "+inf")
        m.d.comb += [
            setup.i_valid.eq(gen.o_valid),
            setup.org.eq(self.pos), setup.dir.eq(gen.dir), setup.tmax.eq(inf),
            setup.lo.eq(self.box_lo), setup.hi.eq(self.box_hi),
            st.packet.eq(g.packet), st.lane.eq(g.lane), st.last.eq(g.last),
            st.pixel.eq(gen.pixel),
        ]
        t = data.View(self.setup_tag, setup.o_tag)
        if not self.pooled:
            m.d.comb += self.o.valid.eq(setup.o_valid)
        m.d.comb += [out.pixel.eq(t.pixel), out.dir.eq(setup.o_dir)]
        m.d.comb += _ray_out(m, setup, out.ray, t.packet, t.lane, t.last, 0,
                             self.box_cull, self.cfg.int_test == "projection")
        return m
