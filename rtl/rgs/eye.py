"""RGS slave, part one: eye rays from camera registers and ray setup, in FP hardware.

The golden model is ``model/rgs.py`` (``eye_ray``, ``ray_setup``); every FP operation here is
one of its steps, in its order, so the rays come out bit for bit as
``model.raygen.eye_rays`` + ``setup`` make them (``docs/rgs.md``).

* :class:`RaySetupPipe`: the bare ray-setup datapath (``inv``, ``axes``, ``shear``, ``slab``,
  ``flat``, ``order``, ``clip``, ``octant``), fixed latency, one ray per enabled cycle.
* :class:`RaySetup`: the datapath as a stream unit: (org, dir, tmax, anyhit, packet, lane, last)
  in, ``RayIn`` out, back-pressure.
* :class:`EyeRayPipe`: the bare eye-ray datapath: sample (sx, sy) -> direction (``sample``,
  ``mul_x``, ``mul_y``, ``add_x``, ``add_y``) and the pixel index.
* :class:`EyeRays`: the slave's ray generator: packet requests in, each tile's rays in lane
  order through :class:`EyeRayPipe` and :class:`RaySetupPipe`, ``RayIn`` (+ pixel index) out.
* :class:`SecondaryPipe`: a hit -> the secondary rays' origin, the oriented face and shading
  normals and the reflected direction (``hit``, ``face``, ``dir_norm``, ``offset``,
  ``normal``, ``reflect``); :class:`LightPipe`: (origin, normals, light, material) -> the
  shadow ray's direction, tmax and whether it is cast, and the colour contributions.

Flow control of the stream units: one clock enable stalls the whole pipeline while its last
stage holds a ray the consumer does not take (``en = ~o.valid | o.ready``; ``i.ready = en``),
so rays leave in order, one per cycle at full rate, at exactly ``latency`` cycles after they
entered when the output is never stalled.
"""
from __future__ import annotations

from amaranth.hdl import C, Array, Cat, Const, Elaboratable, Module, Mux, Signal, Value
from amaranth.lib import data, stream, wiring
from amaranth.lib.wiring import In, Out
from amaranth.utils import ceil_log2

from model.config import COORD_BITS, Config
from model.fp import FPFormat
from model.layout import SHIN_BITS
from model.rgs import FIX_BITS, FIX_FRAC, FIX_MAX, TEX_FRAC, TEX_ONE, TEX_SCALE, UV_FRAC

from ..fp.common import bits_for, unpack, wire
from ..fp.conv import FPFromInt
from ..fp.schedule import Schedule, Share
from ..memport import WORD_BITS, MemReadPort
from ..rtc_streams import PACKET_ID_BITS, RayIn, lane_bits, vec3

__all__ = ["COORD_BITS", "PIXEL_BITS", "RaySetupIn", "EyeRequest", "EyeRay", "RaySetupPipe",
           "RaySetup", "EyeRayPipe", "EyeRays", "SecondaryPipe", "div_const",
           "div_const_params", "sample_converter", "LightPipe", "to_fixed", "wrap_coord",
           "tex_pos", "ShadePool", "TexCoordPipe", "TexFilterPipe", "TexIn", "TexOut", "Texture"]

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


def _fp_const(fmt: FPFormat, value: str) -> Const:
    E, M = fmt.exp_bits, fmt.frac_bits
    emax = (1 << E) - 1
    bits = {"one": fmt.bias << M, "+inf": emax << M, "-inf": (1 << (E + M)) | (emax << M),
            "+0": 0}[value]
    return Const(bits, fmt.width)


def _pick(v, k):
    return Mux(k == 0, v[0], Mux(k == 1, v[1], v[2]))


def _valid_chain(m: Module, en: Value, valid: Value, n: int, name: str) -> Value:
    """``valid`` through ``n`` registers (reset to 0) that load when ``en`` is 1."""
    for i in range(n):
        reg = Signal(name=f"{name}{i}")
        with m.If(en):
            m.d.sync += reg.eq(valid)
        valid = reg
    return valid


def _latencies(fmt: FPFormat, latencies: dict | None) -> dict:
    lat = Schedule.default_latencies(fmt, latencies)
    conv = (latencies or {}).get("conv")
    lat["conv"] = 2 if conv is None else conv          # FPFromInt's default
    return lat


class _Datapath(wiring.Component):
    """A bare fixed-latency datapath of FP units (``Schedule``): ``inputs`` and ``outputs``
    ports plus ``tag`` (carried along), ``i_valid``, ``en`` (0 holds every stage),
    ``i_slot`` (1 in the cycles in which an input is taken), ``o_valid`` and ``o_tag``. A
    subclass writes ``_build(m, dry)``, which returns the latency; ``latency`` comes from a
    dry build (ready cycles only, no units).

    ``budget`` (``{"add": n, "mul": n}``, optional; :meth:`Config.rgs_budget`): at most n FP
    adders and n multipliers, shared in a modulo schedule (:class:`~rtl.fp.schedule.Share`):
    the datapath then takes an input every ``ii`` enabled cycles (``i_slot``; an ``i_valid``
    outside its slot is ignored) and ``units`` gives the units of each class. Two more keys:
    ``"ii"``, the least interval (to run in step with another datapath), and ``"offset"``:
    the first slot comes ``offset`` enabled cycles after reset (the latency of a datapath of
    the same interval that feeds this one, so that its outputs meet this one's slots).
    Without a budget, ``ii`` is 1 and every operation has its own unit."""

    def __init__(self, fmt: FPFormat, tag_width: int, latencies: dict | None,
                 inputs: dict, outputs: dict, budget: dict | None = None):
        self.fmt, self.tag_width = fmt, tag_width
        self.latencies = _latencies(fmt, latencies)
        super().__init__({**inputs, "tag": In(tag_width), "i_valid": In(1), "en": In(1, init=1),
                          "i_slot": Out(1), "o_valid": Out(1), **outputs,
                          "o_tag": Out(tag_width)})
        self.share = None
        self.latency = self._build(self._dry(), dry=True)
        self.counts = dict(self._sch.counts)            # operations per FP unit class
        budget = dict(budget or {})
        min_ii, offset = budget.pop("ii", 1), budget.pop("offset", 0)
        if budget or min_ii > 1:
            self.share = Share.for_budget(self.counts, budget, min_ii, offset)
            if self.share.ii > 1:
                self.latency = self._build(self._dry(), dry=True)
            else:
                self.share = None
        self.ii = 1 if self.share is None else self.share.ii
        self.units = dict(self.counts if self.share is None else self.share.units)
        self.per_ii = 1             # inputs taken per interval (ShadePool's LightPipe copies)

    @property
    def in_flight(self) -> int:
        """The most inputs inside the datapath at once, the one held at its output included
        (``per_ii`` inputs every ``ii`` enabled cycles, each leaving after ``latency``):
        ``(latency // ii + 1) * per_ii``."""
        return (self.latency // self.ii + 1) * self.per_ii

    @staticmethod
    def _dry() -> Module:
        m = Module()
        m._MustUse__silence = True
        return m

    def _schedule(self, m: Module, dry: bool) -> Schedule:
        self._sch = Schedule(m, self.en, self.fmt, self.latencies, dry, self.share)
        return self._sch

    def _emit(self, m: Module, sch: Schedule, dry: bool, en: Value | None = None) -> int:
        """The ``_build`` of a datapath written as ``_graph(m, sch, t0, dry)`` (its operations
        from inputs ready at cycle ``t0``, returning the outputs' cycle and values): one copy
        from cycle 0, its outputs on the ports, the valid along (loading when ``en``, default
        the ``en`` port)."""
        L, outs = self._graph(m, sch, 0, dry)
        if not dry:
            en = self.en if en is None else en
            m.d.comb += self.o_valid.eq(_valid_chain(m, en, sch.start(self.i_valid), L,
                                                     "valid"))
            m.d.comb += [getattr(self, k).eq(v) for k, v in outs.items()]
        return L

    def _build(self, m: Module, dry: bool = False) -> int:
        raise TypeError(f"{type(self).__name__}: a datapath defines _build(m, dry) (its "
                        "stages; returns the latency)")

    def elaborate(self, platform):
        m = Module()
        self._build(m)
        m.d.comb += self.i_slot.eq(self._sch.slot)
        return m


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
        fmt = self.fmt
        sch = self._schedule(m, dry)
        d = [wire(m, self.dir[a], f"d{a}") for a in range(3)]
        org = [wire(m, self.org[a], f"o{a}") for a in range(3)]
        tmax = wire(m, self.tmax, "tmax")
        # -- inv: 1 / d per axis ------------------------------------------------------------------
        one = (_fp_const(fmt, "one"), 0)
        inv = [sch.op("div", one, (d[a], 0), f"inv{a}") for a in range(3)]
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
        t1 = 1
        d1 = [sch.at(x, 0, t1) for x in d]
        dz = (wire(m, _pick(d1, sch.at(kz, 0, t1)), "shear_dz"), t1)
        dkx = (wire(m, _pick(d1, sch.at(kx, 0, t1)), "shear_dkx"), t1)
        dky = (wire(m, _pick(d1, sch.at(ky, 0, t1)), "shear_dky"), t1)
        s_x = sch.op("div", dkx, dz, "shear_sx")
        s_y = sch.op("div", dky, dz, "shear_sy")
        ti = max(x[1] for x in inv)       # (one cycle unless the dividers are shared)
        s_z = (wire(m, _pick([sch.at(*x, ti) for x in inv], sch.at(kz, 0, ti)), "shear_sz"), ti)
        # -- slab, flat, order per axis -----------------------------------------------------------
        near, far = [], []
        for a in range(3):
            lo = wire(m, self.lo[a], f"lo{a}")
            hi = wire(m, self.hi[a], f"hi{a}")
            t0 = sch.op("mul", sch.op("sub", (lo, 0), (org[a], 0), f"slab_lo{a}"), inv[a],
                        f"slab_t0_{a}")
            t1_ = sch.op("mul", sch.op("sub", (hi, 0), (org[a], 0), f"slab_hi{a}"), inv[a],
                         f"slab_t1_{a}")
            tt = max(t0[1], t1_[1])
            v0, v1 = sch.at(t0[0], t0[1], tt), sch.at(t1_[0], t1_[1], tt)
            flat = wire(m, unpack(fmt, v0).nan | unpack(fmt, v1).nan, f"flat{a}")
            f0 = (wire(m, Mux(flat, _fp_const(fmt, "-inf"), v0), f"flat_t0_{a}"), tt)
            f1 = (wire(m, Mux(flat, _fp_const(fmt, "+inf"), v1), f"flat_t1_{a}"), tt)
            near.append(sch.op("min", f0, f1, f"order_near{a}"))
            far.append(sch.op("max", f0, f1, f"order_far{a}"))
        # -- clip: two chains in axis order -------------------------------------------------------
        tnear = (_fp_const(fmt, "+0"), 0)
        tfar = (tmax, far[0][1] if "tmax" in self.static else 0)
        for a in range(3):
            tnear = sch.op("max", tnear, near[a], f"clip_near{a}")
            tfar = sch.op("min", tfar, far[a], f"clip_far{a}")
        octant = wire(m, Cat(*(x[-1] for x in d)), "octant")
        L = max(tnear[1], tfar[1], s_x[1], s_y[1], s_z[1], 1)
        if dry:
            return L
        at = lambda x: sch.at(x[0], x[1], L)
        keep = lambda x, name: x if name in self.static else sch.at(x, 0, L)
        m.d.comb += [
            self.o_valid.eq(_valid_chain(m, self.en, sch.start(self.i_valid), L, "valid")),
            self.o_org.eq(Cat(*(keep(x, "org") for x in org))),
            self.o_dir.eq(Cat(*(sch.at(x, 0, L) for x in d))),
            self.inv.eq(Cat(*(at(x) for x in inv))),
            self.octant.eq(sch.at(octant, 0, L)),
            self.k.eq(Cat(sch.at(kx, 0, L), sch.at(ky, 0, L), sch.at(kz, 0, L))),
            self.s.eq(Cat(at(s_x), at(s_y), at(s_z))),
            self.tnear.eq(at(tnear)), self.tfar.eq(at(tfar)),
            self.o_tmax.eq(keep(tmax, "tmax")),
            self.o_tag.eq(sch.at(self.tag, 0, L)),
        ]
        return L


def _stall(m: Module, o) -> Signal:
    """The pipeline enable of a stream unit whose last stage is its output ``o``: advance
    unless that stage holds a ray the consumer does not take."""
    en = Signal(name="en")
    m.d.comb += en.eq(~o.valid | o.ready)
    return en


def _ray_out(m: Module, pipe: RaySetupPipe, ray, packet, lane, last, anyhit,
             box_cull: Value) -> list:
    """Assignments of a ``RayIn`` view ``ray`` from the setup pipe's outputs. With
    ``box_cull`` = 0 a ray whose clipped interval is empty (``not tnear <= tfar``, the
    traversal's test) gets ``[+0, tmax]`` instead and is traversed like any other
    (``model.raygen.setup(box_cull=False)``: only to measure what the cull saves); a
    combinational compare and two muxes on the output registers, no cycle."""
    from ..fp.cmp import compare
    keep = Signal(name="box_keep")
    m.d.comb += keep.eq(box_cull | compare(pipe.fmt, pipe.tnear, pipe.tfar).le)
    return [ray.packet.eq(packet), ray.lane.eq(lane), ray.last.eq(last),
            ray.org.eq(pipe.o_org), ray.inv.eq(pipe.inv), ray.octant.eq(pipe.octant),
            ray.tnear.eq(Mux(keep, pipe.tnear, _fp_const(pipe.fmt, "+0"))),
            ray.tfar.eq(Mux(keep, pipe.tfar, pipe.o_tmax)), ray.k.eq(pipe.k),
            ray.s.eq(pipe.s), ray.tmax.eq(pipe.o_tmax), ray.anyhit.eq(anyhit)]


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

    def __init__(self, cfg: Config, latencies: dict | None = None):
        self.cfg = cfg
        self.tag = data.StructLayout({"packet": PACKET_ID_BITS, "lane": lane_bits(cfg),
                                      "last": 1, "anyhit": 1})
        self.pipe = RaySetupPipe(cfg.fmt, self.tag.size,
                                 cfg.fp_latencies() if latencies is None else latencies,
                                 budget=cfg.rgs_budget())
        self.latency = self.pipe.latency
        super().__init__({
            "i": In(stream.Signature(RaySetupIn(cfg))),
            "box_lo": In(vec3(cfg)), "box_hi": In(vec3(cfg)), "box_cull": In(1, init=1),
            "o": Out(stream.Signature(RayIn(cfg))),
        })

    def elaborate(self, platform):
        m = Module()
        m.submodules.pipe = pipe = self.pipe
        en = _stall(m, self.o)
        p = self.i.payload
        tag_in = data.View(self.tag, pipe.tag)
        m.d.comb += [
            self.i.ready.eq(en & pipe.i_slot), pipe.en.eq(en), pipe.i_valid.eq(self.i.valid),
            pipe.org.eq(p.org), pipe.dir.eq(p.dir), pipe.tmax.eq(p.tmax),
            pipe.lo.eq(self.box_lo), pipe.hi.eq(self.box_hi),
            tag_in.packet.eq(p.packet), tag_in.lane.eq(p.lane), tag_in.last.eq(p.last),
            tag_in.anyhit.eq(p.anyhit),
        ]
        tag = data.View(self.tag, pipe.o_tag)
        m.d.comb += self.o.valid.eq(pipe.o_valid)
        m.d.comb += _ray_out(m, pipe, self.o.payload, tag.packet, tag.lane, tag.last,
                             tag.anyhit, self.box_cull)
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
        fmt = self.fmt
        sch = self._schedule(m, dry)
        # -- sample: (2*s + 1) * 2**-1 rounded once -----------------------------------------------
        pts = []
        for name, s in (("x", self.sx), ("y", self.sy)):
            conv = sample_converter(fmt, self.coord_bits, self.latencies["conv"])
            if not dry:
                m.submodules[f"sample_{name}"] = conv
                m.d.comb += [conv.a.eq(Cat(C(1, 1), s)), conv.en.eq(self.en)]
            else:
                conv._MustUse__silence = True
            pts.append((wire(m, conv.o, f"sample_p{name}"), conv.latency))
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
        pixel = wire(m, (sch.at(qy, 0, 1) * self.width + sch.at(qx, 0, 1))[:PIXEL_BITS],
                     "pixel_index")
        L = max(max(x[1] for x in d), 2)
        if dry:
            return L
        m.d.comb += [
            self.o_valid.eq(_valid_chain(m, self.en, sch.start(self.i_valid), L, "valid")),
            self.dir.eq(Cat(*(sch.at(x[0], x[1], L) for x in d))),
            self.pixel.eq(sch.at(pixel, 1, L)),
            self.o_tag.eq(sch.at(self.tag, 0, L)),
        ]
        return L


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
    """

    def __init__(self, cfg: Config, latencies: dict | None = None,
                 coord_bits: int = COORD_BITS):
        self.cfg, self.coord_bits = cfg, coord_bits
        lat = cfg.fp_latencies() if latencies is None else latencies
        self.lane_bits = lane_bits(cfg)
        self.tag = data.StructLayout({"packet": PACKET_ID_BITS, "lane": self.lane_bits,
                                      "last": 1})
        self.setup_tag = data.StructLayout({"packet": PACKET_ID_BITS, "lane": self.lane_bits,
                                            "last": 1, "pixel": PIXEL_BITS})
        budget = cfg.rgs_budget()
        self.gen = EyeRayPipe(cfg.fmt, cfg.oversampling, self.tag.size, lat, coord_bits, budget)
        self.setup = RaySetupPipe(cfg.fmt, self.setup_tag.size, lat, static=("org", "tmax"),
                                  budget=budget)
        ii = max(self.gen.ii, self.setup.ii)
        if ii > 1:                     # one interval; setup's slots meet gen's outputs
            self.gen._MustUse__silence = self.setup._MustUse__silence = True
            self.gen = EyeRayPipe(cfg.fmt, cfg.oversampling, self.tag.size, lat, coord_bits,
                                  {**budget, "ii": ii})
            self.setup = RaySetupPipe(cfg.fmt, self.setup_tag.size, lat, static=("org", "tmax"),
                                      budget={**budget, "ii": ii, "offset": self.gen.latency})
        self.latency = 1 + self.gen.latency + self.setup.latency
        v3 = vec3(cfg)
        super().__init__({
            "req": In(stream.Signature(EyeRequest(cfg))),
            "o": Out(stream.Signature(EyeRay(cfg))),
            "pos": In(v3), "corner": In(v3), "dx": In(v3), "dy": In(v3),
            "width": In(coord_bits), "height": In(coord_bits),
            "box_lo": In(v3), "box_hi": In(v3), "box_cull": In(1, init=1),
        })

    def elaborate(self, platform):
        m = Module()
        cfg, cb = self.cfg, self.coord_bits
        m.submodules.gen = gen = self.gen
        m.submodules.setup = setup = self.setup
        en = _stall(m, self.o)

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
            gen.en.eq(en), gen.i_valid.eq(busy),
            gen.sx.eq(x0 + lx), gen.sy.eq(y0 + ly),
            tag.packet.eq(packet), tag.lane.eq(lane), tag.last.eq(last),
            gen.corner.eq(self.corner), gen.dx.eq(self.dx), gen.dy.eq(self.dy),
            gen.width.eq(self.width),
        ]
        g = data.View(self.tag, gen.o_tag)
        st = data.View(self.setup_tag, setup.tag)
        inf = _fp_const(cfg.fmt, "+inf")
        m.d.comb += [
            setup.en.eq(en), setup.i_valid.eq(gen.o_valid),
            setup.org.eq(self.pos), setup.dir.eq(gen.dir), setup.tmax.eq(inf),
            setup.lo.eq(self.box_lo), setup.hi.eq(self.box_hi),
            st.packet.eq(g.packet), st.lane.eq(g.lane), st.last.eq(g.last),
            st.pixel.eq(gen.pixel),
        ]
        out = data.View(self.setup_tag, setup.o_tag)
        m.d.comb += [self.o.valid.eq(setup.o_valid), self.o.payload.pixel.eq(out.pixel),
                     self.o.payload.dir.eq(setup.o_dir)]
        m.d.comb += _ray_out(m, setup, self.o.payload.ray, out.packet, out.lane, out.last, 0,
                             self.box_cull)
        return m


# ---------------------------------------------------------------------------------------------
# secondary rays
# ---------------------------------------------------------------------------------------------

def _dot(sch: Schedule, a: list, b: list, name: str) -> tuple:
    """``dot``: (a0*b0 + a1*b1) + a2*b2 on scheduled values."""
    p = [sch.op("mul", a[i], b[i], f"{name}_m{i}") for i in range(3)]
    return sch.op("add", sch.op("add", p[0], p[1], f"{name}_a0"), p[2], f"{name}_a1")


def _positive(fmt: FPFormat, x: Value) -> Value:
    """x > 0 (a NaN is not; a denormal encoding reads as zero)."""
    u = unpack(fmt, x)
    return ~u.sign & ~u.zero & ~u.nan


def _negative(fmt: FPFormat, x: Value) -> Value:
    """x < 0 (-0 and NaN are not)."""
    u = unpack(fmt, x)
    return u.sign & ~u.zero & ~u.nan


def _neg_if(fmt: FPFormat, x: Value, cond: Value) -> Value:
    """-x where ``cond`` (the sign bit flipped; a NaN stays the canonical NaN), else x."""
    sign = Const(1 << (fmt.width - 1), fmt.width)
    return Mux(cond & ~unpack(fmt, x).nan, x ^ sign, x)


class SecondaryPipe(_Datapath):
    """Bare secondary-ray datapath: ``model.rgs.secondary`` as a pipeline.

    In: ``org``, ``dir`` (the ray, 3 format words each), ``t``, ``u``, ``v`` (its hit), ``nf``
    (the triangle's unit face normal), ``nv`` (vertex normals A, B, C: 3 x 3 words), ``tag``
    (carried along), ``i_valid``, ``en``; ``eps`` (the offset register, constant while rays are
    in flight). Out after ``latency`` enabled cycles: ``o_valid``, ``p0`` (the secondary rays'
    origin), ``g`` (face normal turned toward the ray), ``n`` (shading normal), ``r`` (reflected
    direction), ``o_tag``.

    Operations (the model's steps, ``docs/rgs.md``): ``hit`` 3 mul + 3 add, ``face`` a dot
    product (3 mul, 2 add) and a sign flip, ``dir_norm`` a dot product, a square root, a
    reciprocal (div) and 3 mul, ``offset`` 6 mul + 3 add + 3 sub, ``normal`` 2 sub, 9 mul,
    6 add, a dot product, a square root, a reciprocal, 3 mul, a zero test and mux and a dot
    product for the side, ``reflect`` a dot product, 1 mul by 2, 3 mul, 3 sub: 43 mul, 30
    add/sub, 2 sqrt, 2 div in all. Latency ``latency`` (binary32 with the default FP latencies:
    add 3, mul 3, div 8, sqrt 8 gives 70: ``normal``'s chain of two dot products, square
    root, reciprocal and the reflection ends the longest path). Throughput: one hit per cycle
    in which ``en`` is 1.
    ``latencies``: optional ``{"add": n, "mul": n, "div": n, "sqrt": n}``.
    """

    def __init__(self, fmt: FPFormat, tag_width: int = 1, latencies: dict | None = None,
                 budget: dict | None = None):
        w = fmt.width
        v3 = data.ArrayLayout(w, 3)
        super().__init__(fmt, tag_width, latencies,
                         {"org": In(v3), "dir": In(v3), "t": In(w), "u": In(w), "v": In(w),
                          "nf": In(v3), "nv": In(data.ArrayLayout(v3, 3)), "eps": In(w)},
                         {"p0": Out(v3), "g": Out(v3), "n": Out(v3), "r": Out(v3)}, budget)

    def _build(self, m: Module, dry: bool = False) -> int:
        return self._emit(m, self._schedule(m, dry), dry)

    def _graph(self, m: Module, sch: Schedule, t0: int, dry: bool) -> tuple:
        """The operations, inputs ready at cycle ``t0``: ``(L, outputs)``, the cycle the
        outputs are ready in and ``{port name: value}`` (None when ``dry``)."""
        fmt = self.fmt
        at = sch.at
        vec = lambda port, name: [(wire(m, port[a], f"{name}{a}"), t0) for a in range(3)]  # noqa: E731
        d, o, nf = vec(self.dir, "d"), vec(self.org, "o"), vec(self.nf, "nf")
        nv = [vec(self.nv[c], f"nv{c}_") for c in range(3)]
        t, u, v, eps = ((wire(m, x, name), t0) for x, name in
                        ((self.t, "t"), (self.u, "u"), (self.v, "v"), (self.eps, "eps")))
        one = (_fp_const(fmt, "one"), t0)
        # -- face: g = -nf if dot(nf, d) > 0 -------------------------------------------------
        dn = _dot(sch, nf, d, "face_dot")
        flip = wire(m, _positive(fmt, dn[0]), "face_flip")
        g = [(wire(m, _neg_if(fmt, at(nf[a][0], t0, dn[1]), flip), f"g{a}"), dn[1])
             for a in range(3)]
        # -- dir_norm: w = d * (1 / sqrt(dot(d, d))) -----------------------------------------
        rl = sch.op("div", one, sch.op("sqrt", _dot(sch, d, d, "dir_dot"), None, "dir_len"),
                    "dir_rcp")
        w_ = [sch.op("mul", d[a], rl, f"w{a}") for a in range(3)]
        # -- hit, offset: p0 = (o + t*d + eps*g) - eps*w --------------------------------------
        p = [sch.op("add", o[a], sch.op("mul", t, d[a], f"hit_m{a}"), f"hit{a}") for a in range(3)]
        p0 = [sch.op("sub", sch.op("add", p[a], sch.op("mul", eps, g[a], f"off_g{a}"),
                                   f"off_a{a}"),
                     sch.op("mul", eps, w_[a], f"off_w{a}"), f"p0_{a}") for a in range(3)]
        # -- normal: interpolate, normalize (g where the sum is zero), turn to g's side --------
        b = sch.op("sub", sch.op("sub", one, u, "bary_1u"), v, "bary_b")
        s = [sch.op("add", sch.op("add", sch.op("mul", b, nv[0][a], f"nrm_b{a}"),
                                  sch.op("mul", u, nv[1][a], f"nrm_u{a}"), f"nrm_a{a}"),
                    sch.op("mul", v, nv[2][a], f"nrm_v{a}"), f"nrm_s{a}") for a in range(3)]
        q = _dot(sch, s, s, "nrm_dot")
        rn = sch.op("div", one, sch.op("sqrt", q, None, "nrm_len"), "nrm_rcp")
        s1 = [sch.op("mul", s[a], rn, f"nrm_n{a}") for a in range(3)]
        tn = max(x[1] for x in s1)
        zero = wire(m, unpack(fmt, at(q[0], q[1], tn)).zero, "nrm_zero")
        n1 = [(wire(m, Mux(zero, at(g[a][0], g[a][1], tn), at(*s1[a], tn)), f"nrm_sel{a}"), tn)
              for a in range(3)]
        side = _dot(sch, n1, g, "side_dot")
        back = wire(m, _negative(fmt, side[0]), "side_flip")
        n = [(wire(m, _neg_if(fmt, at(n1[a][0], tn, side[1]), back), f"n{a}"), side[1])
             for a in range(3)]
        # -- reflect: r = d - (2 * dot(d, n)) * n ---------------------------------------------
        two = (Const(fmt.to_bits(2.0).item(), fmt.width), t0)
        k = sch.op("mul", two, _dot(sch, d, n, "refl_dot"), "refl_k")
        r = [sch.op("sub", d[a], sch.op("mul", k, n[a], f"refl_m{a}"), f"r{a}") for a in range(3)]
        L = max(x[1] for x in (*p0, *g, *n, *r))
        if dry:
            return L, None
        out = lambda xs: Cat(*(at(x[0], x[1], L) for x in xs))  # noqa: E731
        return L, {"p0": out(p0), "g": out(g), "n": out(n), "r": out(r),
                   "o_tag": at(self.tag, t0, L)}


# ---------------------------------------------------------------------------------------------
# colour
# ---------------------------------------------------------------------------------------------

def to_fixed(fmt: FPFormat, x: Value) -> Value:
    """``model.rgs.to_fixed`` (combinational): floor(x * 2**FIX_FRAC) as FIX_BITS bits; 0 for a
    NaN, a zero or a negative x, all ones from 2**(FIX_BITS - FIX_FRAC) up. For
    0 < x < 2**8, x * 2**FIX_FRAC = sig * 2**(exp - bias - M + FIX_FRAC) with the significand
    ``sig`` (hidden bit included): ``sig`` padded with ``pad`` zeros and shifted right by
    ``c - exp`` (never negative there)."""
    u = unpack(fmt, x)
    M = fmt.frac_bits
    pad = max(0, (FIX_BITS - FIX_FRAC - 1) + FIX_FRAC - M)     # the largest left shift
    c = pad + fmt.bias + M - FIX_FRAC
    big = u.exp >= fmt.bias + (FIX_BITS - FIX_FRAC)
    shifted = (Cat(Const(0, pad), u.sig) >> (c - u.exp)[:bits_for(c)])[:FIX_BITS]
    return Mux(u.sign | u.zero | u.nan, 0, Mux(big, FIX_MAX, shifted))


class LightPipe(_Datapath):
    """The shadow ray of a (hit, light) pair and its colour: the shadow ray
    (``model.rgs.shadow_dir``), the Phong term the ray brings if it reaches its light
    (``model.rgs.light_colour``) and the hit's own terms (``model.rgs.hit_colour``), each made
    a fixed-point contribution (``model.rgs.to_fixed``), as a pipeline.

    In: ``p0``, ``g`` (the hit's secondary origin and oriented face normal, from
    :class:`SecondaryPipe`), ``light`` (3 format words: a point light's position, or a
    parallel light's reversed direction), ``point`` (1: point light); ``n``, ``r`` (the hit's
    shading normal and reflected direction, from :class:`SecondaryPipe`); ``kd``, ``ks``,
    ``kr``, ``shin`` (the material's record constants); ``lc`` (the light's colour), ``wt``
    (the hit ray's weight); registers ``amb``, ``bg``; ``tag``, ``i_valid``, ``en``. Out after
    ``latency`` enabled cycles: ``o_p0``, ``o_r`` (carried along), ``dir`` (light - p0, or the
    light vector itself for a parallel light), ``tmax`` (1 for a point light, +inf for a
    parallel one), ``cast`` (dot(g, dir) > 0: the light faces the surface; no ray otherwise),
    ``col`` (the light's contribution, 3 x ``FIX_BITS``), ``amb_col``
    (the ambient contribution), ``wr`` (the reflection ray's weight), ``rmiss`` (the reflection
    ray's contribution if it misses), ``o_tag``.

    Operations: the shadow ray's 3 sub, 3 mul, 2 add; four dot products (ld.ld, r.r, n.ld,
    r.ld: 12 mul, 8 add), 2 sqrt, 2 div (reciprocals), 3 mul, 2 clamps at +0 (a mux each, in
    a min/max unit's latency), the power by squaring (19 mul, 10 muxes), per channel 4 mul and
    an add; the hit's terms 10 mul: 59 mul, 16 add/sub, 2 sqrt, 2 div in all. Latency: the power's chain of 10 multiplications
    after the two reciprocals, then a fixed-point conversion (75 at the binary32 defaults).
    Throughput: one pair per enabled cycle.
    """

    def __init__(self, fmt: FPFormat, tag_width: int = 1, latencies: dict | None = None,
                 budget: dict | None = None):
        w = fmt.width
        v3 = data.ArrayLayout(w, 3)
        f3 = data.ArrayLayout(FIX_BITS, 3)
        super().__init__(fmt, tag_width, latencies,
                         {"p0": In(v3), "g": In(v3), "light": In(v3), "point": In(1),
                          "n": In(v3), "r": In(v3), "kd": In(v3), "ks": In(v3), "kr": In(w),
                          "shin": In(SHIN_BITS), "lc": In(v3), "wt": In(w), "amb": In(w),
                          "bg": In(v3)},
                         {"o_p0": Out(v3), "o_r": Out(v3), "dir": Out(v3), "tmax": Out(w),
                          "cast": Out(1), "col": Out(f3), "amb_col": Out(f3), "wr": Out(w),
                          "rmiss": Out(f3)}, budget)

    def _build(self, m: Module, dry: bool = False) -> int:
        return self._emit(m, self._schedule(m, dry), dry)

    def _graph(self, m: Module, sch: Schedule, t0: int, dry: bool) -> tuple:
        """The operations, inputs ready at cycle ``t0``: ``(L, outputs)``, the cycle the
        outputs are ready in and ``{port name: value}`` (None when ``dry``)."""
        fmt = self.fmt
        at = sch.at
        # -- the shadow ray (model.rgs.shadow_dir) ----------------------------------------------
        point = wire(m, self.point, "point")
        sub = [sch.op("sub", (self.light[a], t0), (self.p0[a], t0), f"ldir{a}")
               for a in range(3)]
        ts = max(x[1] for x in sub)
        ds = [(wire(m, Mux(at(point, t0, ts), at(*sub[a], ts), at(self.light[a], t0, ts)),
                    f"dir{a}"),
               ts) for a in range(3)]
        face = _dot(sch, [(self.g[a], t0) for a in range(3)], ds, "face_dot")
        vec = lambda port, name: [(wire(m, port[a], f"{name}{a}"), t0) for a in range(3)]  # noqa: E731
        n, r, kd, ks = vec(self.n, "n"), vec(self.r, "r"), vec(self.kd, "kd"), vec(self.ks, "ks")
        lc, bg = vec(self.lc, "lc"), vec(self.bg, "bg")
        wt, kr, amb = ((wire(m, x, name), t0) for x, name in
                       ((self.wt, "wt"), (self.kr, "kr"), (self.amb, "amb")))
        shin = wire(m, self.shin, "shin")
        one = (_fp_const(fmt, "one"), t0)
        # -- light: il = 1 / |ld|, ir = 1 / |r|; ndl, rdl clamped at +0 -----------------------
        il = sch.op("div", one, sch.op("sqrt", _dot(sch, ds, ds, "ll_dot"), None, "ll_len"),
                    "ll_rcp")
        ir = sch.op("div", one, sch.op("sqrt", _dot(sch, r, r, "rr_dot"), None, "rr_len"),
                    "rr_rcp")
        def clamp0(x, name):             # max(x, +0) as FPMinMax gives it, in its latency:
            u = unpack(fmt, x[0])        # +0 for a NaN or a value below zero (-0 stays)
            v = wire(m, Mux(u.nan | (u.sign & ~u.zero), 0, x[0]), name)
            t = x[1] + self.latencies["max"]
            return at(v, x[1], t), t
        ndl = clamp0(sch.op("mul", _dot(sch, n, ds, "nl_dot"), il, "ndl_m"), "ndl")
        rdl = clamp0(sch.op("mul", sch.op("mul", _dot(sch, r, ds, "rl_dot"), il, "rdl_m0"),
                            ir, "rdl_m1"), "rdl")
        # -- spec = rdl ** shin, by squaring ---------------------------------------------------
        acc, p = one, rdl
        for i in range(SHIN_BITS):
            prod = sch.op("mul", acc, p, f"pow_acc{i}")
            t = prod[1]
            bit = at(shin[i], t0, t)
            acc = (wire(m, Mux(bit, prod[0], at(acc[0], acc[1], t)), f"pow_sel{i}"), t)
            if i < SHIN_BITS - 1:
                p = sch.op("mul", p, p, f"pow_sq{i}")
        # -- per channel: ((kd * ndl) + (ks * spec)) * (lc * wt) -------------------------------
        col = [sch.op("mul", sch.op("add", sch.op("mul", kd[c], ndl, f"dif{c}"),
                                    sch.op("mul", ks[c], acc, f"spc{c}"), f"sum{c}"),
                      sch.op("mul", lc[c], wt, f"lw{c}"), f"col{c}") for c in range(3)]
        # -- the hit's own terms ---------------------------------------------------------------
        wr = sch.op("mul", wt, kr, "wr")
        amb_c = [sch.op("mul", sch.op("mul", kd[c], amb, f"ka{c}"), wt, f"amb{c}")
                 for c in range(3)]
        rmiss = [sch.op("mul", bg[c], wr, f"rmiss{c}") for c in range(3)]
        F = max(x[1] for x in (*col, *amb_c, *rmiss))      # the fixed-point conversions' cycle
        L = F + 1
        if dry:
            return L, None
        fixed = lambda xs, name: Cat(*(at(wire(m, to_fixed(fmt, at(x[0], x[1], F)),  # noqa: E731
                                               f"{name}{c}"), F, L)
                                       for c, x in enumerate(xs)))
        return L, {
            "o_p0": Cat(*(at(self.p0[a], t0, L) for a in range(3))),
            "o_r": Cat(*(at(x[0], x[1], L) for x in r)),
            "dir": Cat(*(at(x[0], x[1], L) for x in ds)),
            "tmax": Mux(at(point, t0, L), _fp_const(fmt, "one"), _fp_const(fmt, "+inf")),
            "cast": at(_positive(fmt, face[0]), face[1], L),
            "col": fixed(col, "fix_col"), "amb_col": fixed(amb_c, "fix_amb"),
            "wr": at(wr[0], wr[1], L), "rmiss": fixed(rmiss, "fix_rmiss"),
            "o_tag": at(self.tag, t0, L)}


class ShadePool(Elaboratable):
    """The shading datapaths on one pool of FP units: :class:`SecondaryPipe` and ``copies``
    copies of :class:`LightPipe`'s operation graph in one modulo schedule over ``budget``
    (``{"add": n, "mul": n}``, the paper's 3 and 4 for the shading), so the units serve
    whichever datapath has an operation in a phase.

    ``sec`` and ``shd`` are the two datapaths' components: their ports are the pool's (the
    pool drives their outputs; their own ``elaborate`` is not used, and ``en`` is not: the
    pool never stalls, so its consumers must take every output). In each interval of ``ii``
    cycles ``sec`` takes a hit in phase 0 (``sec.i_slot``) and ``shd`` a (hit, light) token
    in each of the phases ``t0`` (``shd.i_slot``; ``copies`` of them, spread over the
    interval): ``ii`` is the least interval at which the budget takes ``SecondaryPipe``'s
    operations and ``copies`` times ``LightPipe``'s. Every copy's outputs are delayed to one
    latency (``shd.latency``), so tokens leave in the order they entered, in distinct
    cycles, and ``shd`` looks like one pipe taking ``copies`` inputs per interval."""

    def __init__(self, fmt: FPFormat, sec_tag_width: int, shd_tag_width: int,
                 latencies: dict | None, budget: dict, copies: int):
        if copies < 1:
            raise ValueError(f"ShadePool: copies={copies}; LightPipe needs at least one")
        if not budget:
            raise ValueError("ShadePool: an FP unit budget ({'add': n, 'mul': n}) is needed")
        self.fmt, self.copies = fmt, copies
        self.sec = SecondaryPipe(fmt, sec_tag_width, latencies)
        self.shd = LightPipe(fmt, shd_tag_width, latencies)
        self.sec._MustUse__silence = self.shd._MustUse__silence = True   # ports only
        self.counts = {c: self.sec.counts[c] + copies * self.shd.counts[c]
                       for c in self.sec.counts}
        self.share = Share.for_budget(self.counts, dict(budget), min_ii=max(2, copies))
        self.ii = ii = self.share.ii
        self.units = dict(self.share.units)
        self.t0 = [j * ii // copies for j in range(copies)]
        sec_l, shd_l = self._build(_Datapath._dry(), dry=True)
        for pipe, lat, per in ((self.sec, sec_l, 1), (self.shd, shd_l, copies)):
            pipe.latency, pipe.ii, pipe.per_ii = lat, ii, per
            pipe.share, pipe.units = self.share, self.units
        self.latency = max(sec_l, shd_l)

    def _build(self, m: Module, dry: bool = False) -> tuple:
        """Both graphs on one schedule: ``(sec latency, shd latency)``."""
        sec, shd = self.sec, self.shd
        sch = Schedule(m, Const(1, 1), self.fmt, sec.latencies, dry, self.share)
        ls = sec._emit(m, sch, dry, en=Const(1, 1))        # as alone, on the pool's schedule
        graphs = [shd._graph(m, sch, t, dry) for t in self.t0]
        lmax = max(L - t for (L, _), t in zip(graphs, self.t0))
        if dry:
            return ls, lmax
        m.d.comb += sec.i_slot.eq(sch.slot)
        valids, outs = [], {}
        for j, ((L, o), t) in enumerate(zip(graphs, self.t0)):
            v = _valid_chain(m, Const(1, 1), shd.i_valid & sch.slot_at(t), lmax, f"shd{j}_valid")
            for k, x in o.items():
                x = sch.at(x, L, t + lmax)
                outs[k] = x if j == 0 else Mux(v, x, outs[k])
            valids.append(v)
        m.d.comb += [shd.i_slot.eq(Cat(*(sch.slot_at(t) for t in self.t0)).any()),
                     shd.o_valid.eq(Cat(*valids).any())]
        m.d.comb += [getattr(shd, k).eq(v) for k, v in outs.items()]
        return ls, lmax

    def elaborate(self, platform):
        m = Module()
        self._build(m)
        return m


# ---------------------------------------------------------------------------------------------
# texture
# ---------------------------------------------------------------------------------------------

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
        fmt = self.fmt
        sch = self._schedule(m, dry)
        at = sch.at
        u, v = (wire(m, self.u, "u"), 0), (wire(m, self.v, "v"), 0)
        uv = [(wire(m, self.uv[k], f"uv{k}"), 0) for k in range(6)]
        one = (_fp_const(fmt, "one"), 0)
        b = sch.op("sub", sch.op("sub", one, u, "tex_1u"), v, "tex_b")
        st = [sch.op("add", sch.op("add", sch.op("mul", b, uv[k], f"tex_b{k}"),
                                   sch.op("mul", u, uv[2 + k], f"tex_u{k}"), f"tex_a{k}"),
                     sch.op("mul", v, uv[4 + k], f"tex_v{k}"), f"tex_st{k}") for k in range(2)]
        T = max(x[1] for x in st)
        L = T + 2
        if dry:
            return L

        def reg(value, name):            # one register that loads with en
            r = Signal.like(Value.cast(value), name=name)
            with m.If(self.en):
                m.d.sync += r.eq(value)
            return r
        tw, th = at(self.tw, 0, T), at(self.th, 0, T)
        fs = wire(m, wrap_coord(fmt, at(st[0][0], st[0][1], T)), "tex_fs")
        ft = wire(m, (1 << UV_FRAC) - wrap_coord(fmt, at(st[1][0], st[1][1], T)), "tex_ft")
        x0, x1, wx = tex_pos(m, fs, tw, "tex_x")
        y0, y1, wy = tex_pos(m, ft[:UV_FRAC + 1], th, "tex_y")
        r = {k: reg(val, f"tex_{k}") for k, val in
             (("x0", x0), ("x1", x1), ("wx", wx), ("y0", y0), ("y1", y1), ("wy", wy))}
        tw1 = at(self.tw, 0, T + 1)
        row0 = reg(r["y0"] * tw1, "tex_row0")
        row1 = reg(r["y1"] * tw1, "tex_row1")
        x0d, x1d = reg(r["x0"], "tex_x0d"), reg(r["x1"], "tex_x1d")
        j = [(row + x)[:TEX_INDEX_BITS] for row in (row0, row1) for x in (x0d, x1d)]
        m.d.comb += [
            self.o_valid.eq(_valid_chain(m, self.en, sch.start(self.i_valid), L, "valid")),
            self.j.eq(Cat(*j)), self.wx.eq(reg(r["wx"], "tex_wxd")),
            self.wy.eq(reg(r["wy"], "tex_wyd")), self.o_tag.eq(at(self.tag, 0, L)),
        ]
        return L


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
        fmt = self.fmt
        sch = self._schedule(m, dry)
        at = sch.at
        scale = (Const(fmt.to_bits(fmt.quantize(TEX_SCALE)).item(), fmt.width), 0)
        if not dry:                      # the blends' weights: 256 - w and w
            nx = wire(m, TEX_ONE - self.wx, "tex_nx")
            ny, wy = at(wire(m, TEX_ONE - self.wy, "tex_ny"), 0, 1), at(self.wy, 0, 1)
        out = []
        for c in range(3):
            conv = FPFromInt(fmt, int_width=UV_FRAC, signed=False, frac_bits=UV_FRAC,
                             latency=self.latencies["conv"])
            tex = (wire(m, conv.o, f"tex_f{c}"), 2 + conv.latency)
            kd = (wire(m, self.kd[c], f"kd{c}"), 0)
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
            return L
        on = at(self.on, 0, L)
        m.d.comb += [
            self.o_valid.eq(_valid_chain(m, self.en, sch.start(self.i_valid), L, "valid")),
            self.kd_o.eq(Cat(*(Mux(on, at(*x, L), at(self.kd[c], 0, L))
                               for c, x in enumerate(out)))),
            self.o_tag.eq(at(self.tag, 0, L)),
        ]
        return L


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
                 queue: int = 8, out_depth: int = 4):
        self.cfg, self.queue, self.out_depth = cfg, queue, out_depth
        fmt = cfg.fmt
        lat = cfg.fp_latencies() if latencies is None else latencies
        self.carry = data.StructLayout({"addr": 32, "on": 1, "kd": vec3(cfg), "tag": tag_width})
        self.coord = TexCoordPipe(fmt, self.carry.size, lat, cfg.rgs_budget())
        self.wait = data.StructLayout({"kd": vec3(cfg), "tag": tag_width, "on": 1, "half": 4,
                                       "wx": TEX_FRAC, "wy": TEX_FRAC})
        self.filter = TexFilterPipe(fmt, tag_width, lat, cfg.rgs_budget())
        self.latency = self.coord.latency + 1 + self.filter.latency + 1
        super().__init__({
            "i": In(stream.Signature(TexIn(cfg, tag_width))),
            "o": Out(stream.Signature(TexOut(cfg, tag_width))),
            "mem": Out(MemReadPort(addr_width=cfg.addr_bits, data_width=WORD_BITS,
                                   tag_width=1)),
        })

    def elaborate(self, platform):
        from amaranth.lib.fifo import SyncFIFO
        m = Module()
        m.submodules.coord = cp = self.coord
        m.submodules.filter = fp = self.filter
        m.submodules.waitq = waitq = SyncFIFO(width=self.wait.size, depth=self.queue)
        m.submodules.outq = outq = SyncFIFO(width=len(self.o.payload.as_value()),
                                            depth=self.out_depth)
        p = self.i.payload
        # -- TexCoordPipe: held while its output hit is not yet queued ---------------------------
        en_a = Signal()
        ci = data.View(self.carry, cp.tag)
        m.d.comb += [cp.en.eq(en_a), cp.i_valid.eq(self.i.valid),
                     self.i.ready.eq(en_a & cp.i_slot),
                     cp.u.eq(p.u), cp.v.eq(p.v), cp.uv.eq(p.uv), cp.tw.eq(p.tw), cp.th.eq(p.th),
                     ci.addr.eq(p.addr), ci.on.eq(p.on), ci.kd.eq(p.kd), ci.tag.eq(p.tag)]
        # -- issue: a textured hit's four requests, the hit queued with the first ---------------
        co = data.View(self.carry, cp.o_tag)
        cnt = Signal(2)
        req = self.mem.req
        first = cnt == 0
        m.d.comb += [req.valid.eq(cp.o_valid & co.on & (~first | waitq.w_rdy)),
                     req.payload.addr.eq(co.addr + (Array(cp.j)[cnt] >> 1)),
                     req.payload.tag.eq(0)]
        sent = req.valid & req.ready
        with m.If(sent):
            m.d.sync += cnt.eq(cnt + 1)
        push = cp.o_valid & Mux(co.on, sent & first, waitq.w_rdy)
        m.d.comb += en_a.eq(~cp.o_valid | Mux(co.on, sent & (cnt == 3), waitq.w_rdy))
        w_in = Signal(self.wait)
        m.d.comb += [w_in.kd.eq(co.kd), w_in.tag.eq(co.tag), w_in.on.eq(co.on),
                     w_in.half.eq(Cat(*(cp.j[k][0] for k in range(4)))),
                     w_in.wx.eq(cp.wx), w_in.wy.eq(cp.wy),
                     waitq.w_data.eq(w_in), waitq.w_en.eq(push)]
        # -- collector: the head's four texels in order, then the filter ------------------------
        head = data.View(self.wait, waitq.r_data)
        resp = self.mem.resp
        got = Signal(2)
        held = [Signal(32, name=f"texel{k}") for k in range(3)]
        texel = Mux(head.half.bit_select(got, 1), resp.payload.data[32:], resp.payload.data[:32])
        en_f = Signal()
        m.d.comb += en_f.eq(~fp.o_valid | outq.w_rdy)
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
        m.d.comb += [waitq.r_en.eq(feed), fp.en.eq(en_f), fp.i_valid.eq(feed),
                     fp.t.eq(Cat(*held, texel)), fp.wx.eq(head.wx), fp.wy.eq(head.wy),
                     fp.kd.eq(head.kd), fp.on.eq(head.on), fp.tag.eq(head.tag)]
        # -- output queue ----------------------------------------------------------------------
        out = Signal(self.o.payload.shape())
        m.d.comb += [out.kd.eq(fp.kd_o), out.tag.eq(fp.o_tag),
                     outq.w_data.eq(out), outq.w_en.eq(fp.o_valid & outq.w_rdy),
                     self.o.valid.eq(outq.r_rdy), self.o.payload.eq(outq.r_data),
                     outq.r_en.eq(self.o.ready)]
        return m
