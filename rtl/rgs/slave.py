"""The RGS slave: one per RTC; eye rays, the results of every ray, secondary rays and colour.

A slave takes packet requests (tiles) from the RGS master, makes their eye rays
(:class:`~rtl.rgs.EyeRays`) and feeds them to its RTC; it takes every result back, reports it
to the host, and for every hit of an eye or reflection ray makes the secondary rays in FP
hardware (:class:`~rtl.rgs.SecondaryPipe`, :class:`~rtl.rgs.LightPipe`): one shadow ray per
light that faces the surface (any-hit, tmax 1 for a point light), a reflection ray where the
material reflects and the depth allows; with ``cfg.refraction`` also a refracted ray where
the material transmits and the depth allows (``SecondaryPipe(refract=True)``, its weight and
miss colour from LightPipe on one more token of the hit). The secondary rays of one source
packet are packed into packets exactly as ``model.shading`` packs them (per light, the
reflections and the refracted rays: the wanted hits of the source packet in lane order) and
set up (:class:`~rtl.rgs.RaySetup`) for the same RTC. It computes the colour too
(``model.shading``): every ray carries its weight and the contribution it makes if it misses
(the background for an eye, reflection or refracted ray, its light's Phong term for a shadow
ray, computed by ``LightPipe`` when the ray is made); a hit adds its ambient term as a record
of its own. The host sums the contributions per pixel (in fixed point: the same in any
order).

Data paths::

    master ─req─► admit ─► EyeRays ──────────────┐              ┌─► host records (out)
                                                  ├─ RTC arbiter ─► RTC ─results─► store lookup
    pending buffers ─► sender ─► RaySetup ────────┘   (per packet)                      │
          ▲                                                                              ▼
          └── builders ◄── LightPipe ◄── light loop ◄── SecondaryPipe ◄── shading cache (hits)
                              └─► ambient records ─► host records

The RTC arbiter is :class:`RTCInput` and the sender :class:`Sender` (stream components); the
other pieces share state (the slot table, the pending buffers and their credits) and are
:class:`Slave`'s helpers, one per box above, composed by ``Slave.elaborate``.

* **Ray store**: per RTC packet slot (``2 * threads`` slots; the slot is the packet id the RTC
  sees) and lane, the ray's origin, direction and lane in its eye packet; per slot the eye
  packet (tile), the depth, the kind (``sub``: 0 eye, reflection or refracted ray, 1 + l
  shadow ray of light l) and, with refraction, the path (bit i: the packet's ancestor of
  depth i + 1 is a refracted packet).
* **Host record** (:func:`SlaveResult`) of every ray: eye packet and lane, depth, sub (and
  path) — the ray's id — its hit (triangle, t, u, v) and its colour if it missed; and of
  every hit of an eye, reflection or refracted ray, its ambient term.
* **Shading records** (``REC_BITS``: unit face normal, vertex normals, flags, the material's
  colour constants; for a material that transmits, kt, eta_in and eta_out in the texture
  coordinates' slots, ``model.layout.REC_KT``) come through the slave's shading cache (a
  ``rtl.cache.Cache`` on the chip's bus), addressed by triangle.
* **Pending buffers** (``buffers`` of ``packet_size`` rays: origin, direction, eye lane):
  secondary packets waiting for the RTC.
* **Texture unit** (:class:`~rtl.rgs.Texture`, with ``cfg.tex_cache_kb > 0``): beside
  SecondaryPipe, in step with it (its output queue holds as many hits as SecondaryPipe can),
  a textured hit's kd times its filtered texels, read through the ``texel`` port (the chip's
  texel cache); the light loop waits for it.

Nothing is dropped and nothing deadlocks (``docs/chip.md``): a packet whose hits may spawn
rays (an eye, reflection or refracted packet, when there are lights or its depth is below
``reflect_depth``) enters the RTC only after it has *reserved* K = ``lights + 1``
pending buffers (one per light, one for the reflections; ``lights + 2`` with
``cfg.refraction``, one more for the refracted rays: a source packet's spawned rays fill at
most one buffer per builder), so the results of every packet in the RTC can always be
processed and the RTC always frees its threads; eye packets are admitted only while no
secondary packet waits, and there are ``buffers >= 2 * K + 2`` (``Config.min_rgs_buffers``),
so a waiting reflection packet always finds its own reservation once the packets ahead of it
have finished. With refraction a source packet may leave two waiting packets that need a
reservation (its reflection and refracted packets), and with K = 1 (no light in use) its one
waiting packet takes the buffer it reserved and gives none back; there that count no longer
holds, and two more rules bound the waiting packets (:meth:`Slave._branch_gate`,
:meth:`Slave._send`): with refraction a packet that may spawn starts only while no deeper one that may spawn waits, and
(with refraction, or K = 1) a *branching* packet
(one that may spawn, below ``reflect_depth``) only while fewer than ``B = (buffers - K) //
(reflect_depth + 1)`` are in flight. At most ``B * (reflect_depth + 1)`` packets then wait,
and ``buffers >= K + reflect_depth + 1`` leaves K free for the deepest
(``tests/test_rgs_slave_reservations.py`` searches every state of an abstract slave).

Every result of an eye, reflection or refracted ray goes through the shading path (context
queue, SecondaryPipe, light loop, LightPipe), hit or miss, so that its packet's last token commits
the packet's secondary packets; the ambient records are reserved at the light loop (a queue
as deep as the tokens LightPipe holds at once + 7, rounded up to a power of two), so LightPipe
never stalls.

On the slave's pool of FP units (``cfg.rgs_fp_pool``: one eye ray and one hit an interval)
a tile's eye rays are made before its admission, into a queue of one packet
(:meth:`Slave._admission_ahead`), and the shading path holds hits enough to cover the
texture unit's latency (:meth:`Slave._texture_hits`), so the pool makes eye rays, shades
hits and sets up secondary rays in the same intervals.

Throughput: one ray into the RTC per cycle; one result per cycle; a hit takes
``max(1, lights)`` cycles of the light loop (one more where it spawns a refracted ray).
Latency of a hit's secondary rays: the shading cache, :class:`~rtl.rgs.SecondaryPipe` (70
cycles at binary32 defaults, 90 with refraction), the light loop, :class:`~rtl.rgs.LightPipe`
(75), then the whole source packet must be done before its
secondary packets go (they are complete only then).
"""
from __future__ import annotations

from math import gcd
from types import SimpleNamespace

from amaranth.hdl import Array, Cat, Const, Module, Mux, Signal, Value
from amaranth.lib import data, stream, wiring
from amaranth.lib.fifo import SyncFIFO
from amaranth.lib.wiring import In, Out
from amaranth.utils import ceil_log2

from model.cache import CacheGeometry
from model.config import Config, ConfigError
from model.layout import (REC_BITS, REC_FLAGS, REC_KD, REC_KR, REC_KS, REC_KT, REC_NF, REC_NV,
                          REC_REFLECTIVE, REC_SHIN_SHIFT, REC_TEX_ADDR, REC_TEX_SIZE, REC_TEXTURED,
                          REC_TRANSMITS, REC_UV, REC_WORDS, SHIN_BITS)
from model.raykind import RayKind
from model.rgs.secondary import FIX_BITS

from ..common import (COUNTER_BITS, OutputStage, PacketMemory, TwoWriteMemory, from_binary32,
                      lowest)
from ..memport import WORD_BITS, MemReadPort
from ..rtc_streams import PACKET_ID_BITS, TRI_ID_BITS, RayIn, RayResult, lane_bits, vec3
from .common import _fp_const
from .eye import COORD_BITS, EyeRay, EyeRays, EyeRequest, RaySetup, RaySetupIn
from .secondary import LightPipe, SecondaryPipe, SlavePool
from .texture import Texture

__all__ = ["Slave", "SlaveResult", "DEPTH_BITS", "SUB_BITS", "PATH_BITS", "RAY_COUNTERS",
           "POOL_COUNTERS", "pool_entries",
           "slave_buffers",
           "shade_cache_geometry", "tex_cache_geometry"]

DEPTH_BITS = 4          # reflection depth of a ray (0: eye ray)
SUB_BITS = 4            # 0: eye, reflection or refracted ray, 1 + l: shadow ray toward light l
PATH_BITS = 15          # (Config.refraction) bit i: the ray's ancestor of depth i + 1 refracted
# the slave's counters of rays into the RTC, by kind (rays_refract stays 0 without
# Config.refraction)
RAY_COUNTERS = {RayKind.EYE: "rays_eye", RayKind.SHADOW: "rays_shadow",
                RayKind.REFLECTION: "rays_reflect", RayKind.REFRACTION: "rays_refract"}

#: the slave's pool of FP units (``Config.rgs_fp_pool``): ``pool_intervals`` (its intervals of
#: ``ii`` cycles) and per datapath the inputs it took (0 without the pool): each takes at most
#: :func:`pool_entries` inputs an interval, so ``pool_x / (entries * pool_intervals)`` is how
#: full its slots were
POOL_COUNTERS = ("pool_intervals", "pool_sec", "pool_light", "pool_eye", "pool_setup",
                 "pool_tex_coord", "pool_tex_filter")


def pool_entries(cfg: Config) -> dict:
    """The inputs each datapath on the slave's pool takes an interval (``SlavePool``): one hit
    (SecondaryPipe), a (hit, light) token per light register (LightPipe), one eye sample, a
    ray per builder (ray setup: lights + 1, + 1 with refraction) and, with a texture unit,
    one hit in each texture pipe (every hit passes it, textured or not)."""
    L = cfg.rgs_lights
    tex = {"tex_coord": 1, "tex_filter": 1} if cfg.tex_cache_kb > 0 else {}
    return {"sec": 1, "light": max(1, L), "eye": 1, "setup": L + 1 + int(cfg.refraction),
            **tex}


def slave_buffers(cfg: Config) -> int:
    """Pending secondary packets a slave holds: ``cfg.rgs_buffers``, or by default
    ``threads + rgs_reserve`` (``rgs_lights + 1``, + 1 with refraction), at least
    ``2 * rgs_reserve + 2``.

    The fewest that cannot deadlock is ``cfg.min_rgs_buffers`` (the module docstring), but
    then only ``buffers // (lights + 1)`` eye packets (3 with 12 buffers and 3 lights) hold a
    reservation at a time, and with their shadow packets they leave some of the RTC's threads
    idle. ``threads + rgs_lights + 1`` lets ``threads / (lights + 1)`` eye packets and their
    ``lights`` shadow packets each fill every thread (office 1024x768 with all its rays on the
    standard chip: 8 118 838 cycles against 8 747 633 with 12 buffers, ``docs/chip.md``)."""
    return cfg.rgs_buffers or max(cfg.min_rgs_buffers, cfg.threads + cfg.rgs_reserve)


def _slave_cache(cfg: Config, kb: int, name: str, item_bits: int, words: int) -> CacheGeometry:
    """A slave cache of ``kb`` KB (``name``: its Config field) holding items of ``item_bits``
    bits that span ``words`` memory words, rounded down to a power-of-two number of sets."""
    per_set = cfg.cache_ways * item_bits
    sets = (kb * 1024 * 8) // per_set
    if sets < 1:
        raise ConfigError(f"{name}={kb}: too small for one set of {cfg.cache_ways} item(s) of "
                          f"{item_bits // 8} bytes")
    sets = 1 << (sets.bit_length() - 1)
    return CacheGeometry(size_bytes=sets * per_set // 8, ways=cfg.cache_ways, line_items=1,
                         item_bits=item_bits, item_span=64 * words,
                         outstanding=cfg.cache_outstanding, queue=cfg.cache_queue,
                         addr_width=cfg.addr_bits, mem_addr_width=cfg.addr_bits)


def shade_cache_geometry(cfg: Config) -> CacheGeometry:
    """The slave's shading cache: records of ``REC_BITS`` bits (``REC_WORDS`` memory words),
    ``shade_cache_kb`` KB."""
    return _slave_cache(cfg, cfg.shade_cache_kb, "shade_cache_kb", REC_BITS, REC_WORDS)


def tex_cache_geometry(cfg: Config) -> CacheGeometry:
    """The slave's texel cache: 64-bit memory words (two RGBA8 texels each), ``tex_cache_kb``
    KB."""
    return _slave_cache(cfg, cfg.tex_cache_kb, "tex_cache_kb", 64, 1)


def _regs(n: int, shape, name: str) -> Array:
    """``n`` registers as an ``Array``, padded to a power of two (an index never falls outside
    it, so a read mux has no uncovered case: no latch)."""
    return Array(Signal(shape, name=f"{name}{i}") for i in range(1 << ceil_log2(max(2, n))))


def SlaveResult(cfg: Config) -> data.StructLayout:
    """A record the chip reports: with ``shade`` 0 a ray's result — the ray's id (``packet``
    and ``lane`` of its eye ray: the tile and the lane in it; ``depth``: reflections before it;
    ``sub``: 0 eye or reflection ray, 1 + l shadow ray toward light l), its hit (``tri`` all
    ones on a miss, t, u, v) and ``col``, what it adds to its pixel (3 fixed-point channels,
    ``model.rgs.to_fixed``: its colour if it misses — the background for an eye or reflection
    ray, its light's Phong term for a shadow ray — else 0); with ``shade`` 1 the ambient term
    of the hit of the eye or reflection ray (``packet``, ``lane``, ``depth``) in ``col`` (the
    other fields 0). A pixel is the sum of the ``col`` of every record of its eye rays.
    With ``cfg.refraction`` the id has ``path`` too (bit i: the ray's ancestor of depth
    i + 1, or the ray itself, is a refracted ray, not a reflection; ``sub`` 0 is then an eye,
    reflection or refracted ray)."""
    w = cfg.fmt.width
    path = {"path": PATH_BITS} if cfg.refraction else {}
    return data.StructLayout({"packet": PACKET_ID_BITS, "lane": lane_bits(cfg),
                              "depth": DEPTH_BITS, "sub": SUB_BITS, **path, "tri": TRI_ID_BITS,
                              "t": w, "u": w, "v": w,
                              "col": data.ArrayLayout(FIX_BITS, 3), "shade": 1})


def RayEntry(cfg: Config) -> data.StructLayout:
    """A ray as the ray store and the pending buffers hold it: origin, direction, its lane in
    its eye packet, its weight (eye and reflection rays) and its contribution if it misses."""
    return data.StructLayout({"org": vec3(cfg), "dir": vec3(cfg), "lane": lane_bits(cfg),
                              "wt": cfg.fmt.width, "col": data.ArrayLayout(FIX_BITS, 3)})


class _Record:
    """A shading record (``REC_BITS``, as the shading cache returns it): ``field(i)``, its
    32-bit word i; ``word(i)``, that word as a format value (memory holds binary32);
    ``vec(i, n)``, n such words from word i."""

    def __init__(self, fmt, bits: Value):
        self.fmt, self.bits = fmt, Value.cast(bits)

    def field(self, i: int) -> Value:
        return self.bits[32 * i:32 * i + 32]

    def word(self, i: int) -> Value:
        return from_binary32(self.fmt, self.field(i))

    def vec(self, i: int, n: int) -> Value:
        return Cat(*(self.word(i + k) for k in range(n)))


class RTCInput(wiring.Component):
    """The slave's RTC input: eye rays (``eye``) or set-up secondary rays (``sec``) to the RTC
    (``o``, all three In/Out streams of ``RayIn``), a whole packet at a time: a packet that
    started holds the input until its ``last`` ray; between packets a waiting secondary ray
    goes first. Combinational (no latency), one ray per cycle."""

    def __init__(self, cfg: Config):
        ray = stream.Signature(RayIn(cfg))
        super().__init__({"eye": In(ray), "sec": In(ray), "o": Out(ray)})

    def elaborate(self, platform):
        m = Module()
        lock = Signal(2)                     # 0 none, 1 eye, 2 secondary
        use_sec = Mux(lock == 0, self.sec.valid, lock == 2)
        m.d.comb += [
            self.o.valid.eq(Mux(use_sec, self.sec.valid, self.eye.valid)),
            self.o.payload.eq(Mux(use_sec, self.sec.payload.as_value(),
                                  self.eye.payload.as_value())),
            self.sec.ready.eq(use_sec & self.o.ready),
            self.eye.ready.eq(~use_sec & self.o.ready)]
        with m.If(self.o.valid & self.o.ready):
            m.d.sync += lock.eq(Mux(self.o.payload.last, 0, Mux(use_sec, 2, 1)))
        return m


class Sender(wiring.Component):
    """The slave's sender: a ready pending buffer's rays, in lane order, into ray setup.

    Ports: ``start`` (In stream: ``buf``, the RTC packet ``slot`` it goes to, ``count`` rays;
    taken while the sender is idle), ``o`` (Out stream :func:`~rtl.rgs.eye.RaySetupIn`: each
    ray with packet = the slot, any-hit and tmax by the slot's kind); the buffer memory's read
    port ``rd_addr``, ``rd_en``, ``rd_data`` (:func:`RayEntry`, one cycle after the read);
    ``sub`` (In: the sending slot's kind, 0 reflection rays, 1 + l shadow rays of light l:
    tmax 1 toward a point light, +inf otherwise), ``light_point``; ``kind`` (the rays'
    :class:`~model.raykind.RayKind`), ``busy``, ``done`` (the last ray goes this cycle),
    ``buf`` and ``slot`` (the packet being sent).
    Latency: the first ray 2 cycles after ``start``; throughput one ray per cycle (the next
    lane is read while a ray goes)."""

    def __init__(self, cfg: Config, buffers: int, slots: int):
        self.cfg = cfg
        P, bb = cfg.packet_size, max(1, ceil_log2(buffers))
        start = data.StructLayout({"buf": bb, "slot": range(slots), "count": range(P + 1)})
        super().__init__({
            "start": In(stream.Signature(start)),
            "o": Out(stream.Signature(RaySetupIn(cfg))),
            "rd_addr": Out(range(buffers * P)), "rd_en": Out(1), "rd_data": In(RayEntry(cfg)),
            "sub": In(SUB_BITS), "light_point": In(max(1, cfg.rgs_lights)),
            "kind": Out(RayKind), "busy": Out(1), "done": Out(1), "buf": Out(bb),
            "slot": Out(range(slots)),
        })

    def elaborate(self, platform):
        m = Module()
        cfg, P, L = self.cfg, self.cfg.packet_size, self.cfg.rgs_lights
        busy, st, o = self.busy, self.start, self.o
        count = Signal(range(P + 1))
        nxt = Signal(range(P + 1))           # lanes read so far
        rd_valid = Signal()
        rd_lane = Signal(lane_bits(cfg))
        m.d.comb += st.ready.eq(~busy)
        with m.If(st.valid & st.ready):
            m.d.sync += [busy.eq(1), self.buf.eq(st.payload.buf), self.slot.eq(st.payload.slot),
                         count.eq(st.payload.count), nxt.eq(0), rd_valid.eq(0)]
        xfer = o.valid & o.ready
        load = busy & (nxt < count) & (~rd_valid | xfer)
        m.d.comb += [self.rd_addr.eq(self.buf * P + nxt), self.rd_en.eq(load)]
        with m.If(load):
            m.d.sync += [nxt.eq(nxt + 1), rd_lane.eq(nxt)]
        with m.If(xfer & ~load):
            m.d.sync += rd_valid.eq(0)
        with m.Elif(load):
            m.d.sync += rd_valid.eq(1)
        e = self.rd_data
        light_idx = (self.sub - 1)[:max(1, ceil_log2(max(2, L)))]
        is_shadow = self.sub != 0
        point = Mux(is_shadow, self.light_point.bit_select(light_idx, 1), 0)
        last_lane = rd_lane == count - 1
        m.d.comb += [
            o.valid.eq(busy & rd_valid),
            o.payload.packet.eq(self.slot), o.payload.lane.eq(rd_lane),
            o.payload.last.eq(last_lane), o.payload.org.eq(e.org), o.payload.dir.eq(e.dir),
            o.payload.tmax.eq(Mux(point, _fp_const(cfg.fmt, "one"),
                                  _fp_const(cfg.fmt, "+inf"))),
            o.payload.anyhit.eq(is_shadow),
            self.kind.eq(Mux(is_shadow, RayKind.SHADOW, RayKind.REFLECTION)),
            self.done.eq(xfer & last_lane),
        ]
        with m.If(self.done):
            m.d.sync += busy.eq(0)
        return m


class Slave(wiring.Component):
    """One RGS slave (see the module docstring).

    Ports: ``req`` (In stream ``EyeRequest``: tiles from the master), ``rays`` (Out stream
    ``RayIn`` to the RTC), ``results`` (In stream ``RayResult`` from the RTC), ``out`` (Out
    stream :func:`SlaveResult`: every ray's result), ``shade`` (read port of shading records by
    triangle, ``REC_BITS`` wide: the shading cache). Registers (held for the frame): the
    camera ``pos``, ``corner``, ``dx``, ``dy``, ``width``, ``height``, the scene box
    ``box_lo``, ``box_hi``, ``eps`` (secondary origins' offset), ``lights`` (``rgs_lights`` ×
    3 format words: a point light's position or a parallel light's reversed direction),
    ``light_point`` (bit l: light l is a point light), ``n_lights`` (lights in use),
    ``reflect_depth``; the colour registers ``light_col`` (each light's colour), ``amb`` (the
    ambient factor), ``bg`` (the background), ``w_eye`` (an eye ray's weight), ``eye_miss``
    (an eye ray's contribution if it misses: fixed(bg * w_eye), 3 fixed-point channels) —
    ``model.shading.frame_colour_registers`` — and ``colour`` (1: the frame is shaded; 0: no
    ambient records, and only packets that spawn rays take the shading path, as for a frame
    of bare eye rays). ``idle``: nothing in flight. Counters: ``rays_eye``, ``rays_shadow``,
    ``rays_reflect``, ``rays_refract`` (rays into the RTC by kind: :data:`RAY_COUNTERS`;
    ``cfg.refraction``: refracted rays), ``sec_busy`` (cycles
    the light loop held a
    hit), :data:`POOL_COUNTERS` (with ``cfg.rgs_fp_pool``).
    """

    def __init__(self, cfg: Config):
        self.cfg = cfg
        self.pool = None                 # SlavePool (Config.rgs_fp_pool)
        L = cfg.rgs_lights
        if L < 0 or L + 1 >= 1 << SUB_BITS:
            raise ConfigError(f"rgs_lights={L} must be in 0..{(1 << SUB_BITS) - 2}")
        lat = cfg.fp_latencies()
        pooled = cfg.rgs_fp_pool and cfg.secondary_rays
        # on the pool the eye rays run a packet ahead of admission (Slave._admission_ahead)
        self.eye = EyeRays(cfg, lat, pooled=pooled, ahead=cfg.packet_size if pooled else 0)
        self.slots = 2 * cfg.threads
        if cfg.secondary_rays:
            self.setup = RaySetup(cfg, lat, pooled=pooled)
            # refraction: the material transmits (trans), the ray's path; rtok: the hit's
            # refraction token (after its lights' tokens)
            refr = {"trans": 1, "path": PATH_BITS} if cfg.refraction else {}
            self.sec_tag = data.StructLayout({
                "lane": lane_bits(cfg), "hit": 1, "refl": 1, "last": 1,
                "packet": PACKET_ID_BITS, "depth": DEPTH_BITS, **refr})
            # hit: a shadow ray is wanted (a hit, lights); rhit: the ray hit; first: the hit's
            # first token; tlast: its last; last: the packet's last token; spawn: the packet
            # reserved pending buffers
            self.shd_tag = data.StructLayout({
                "lane": lane_bits(cfg), "light": range(max(2, L)), "hit": 1, "rhit": 1,
                "refl": 1, "first": 1, "tlast": 1, "last": 1, "spawn": 1,
                "packet": PACKET_ID_BITS, "depth": DEPTH_BITS,
                **({"rtok": 1, "path": PATH_BITS} if cfg.refraction else {})})
            self.tex = Texture(cfg, 1, lat, pooled=pooled) if cfg.tex_cache_kb > 0 else None
            if pooled:                   # one pool of units for all, a LightPipe entry per light
                self.pool = SlavePool(cfg.fmt, self.sec_tag.size, self.shd_tag.size, lat,
                                      cfg.rgs_budget(), max(1, L), self.eye, self.setup,
                                      L + 1 + cfg.refraction,
                                      self.tex, cfg.refraction)
                self.sec, self.shd = self.pool.sec, self.pool.shd
            else:
                self.sec = SecondaryPipe(cfg.fmt, self.sec_tag.size, lat, cfg.rgs_budget(),
                                         refract=cfg.refraction)
                self.shd = LightPipe(cfg.fmt, self.shd_tag.size, lat, cfg.rgs_budget())
            self.buffers = slave_buffers(cfg)
            self.shade_hits = self.sec.in_flight + 1 + self._texture_hits(cfg)
            if self.tex is not None:     # in step with SecondaryPipe: as deep a queue as it holds
                self.tex.out_depth = self.shade_hits
        else:
            self.buffers = 0
            self.tex = None
        v3 = vec3(cfg)
        w = cfg.fmt.width
        super().__init__({
            "req": In(stream.Signature(EyeRequest(cfg))),
            "rays": Out(stream.Signature(RayIn(cfg))),
            "results": In(stream.Signature(RayResult(cfg))),
            "out": Out(stream.Signature(SlaveResult(cfg))),
            "shade": Out(MemReadPort(addr_width=cfg.addr_bits, data_width=REC_BITS, tag_width=1)),
            **({"texel": Out(MemReadPort(addr_width=cfg.addr_bits, data_width=WORD_BITS, tag_width=1))}
               if self.tex is not None else {}),
            "pos": In(v3), "corner": In(v3), "dx": In(v3), "dy": In(v3),
            "width": In(COORD_BITS), "height": In(COORD_BITS),
            "box_lo": In(v3), "box_hi": In(v3), "box_cull": In(1, init=1), "eps": In(w),
            "lights": In(v3).array(max(1, L)), "light_point": In(max(1, L)),
            "n_lights": In(range(L + 1)), "reflect_depth": In(DEPTH_BITS),
            "light_col": In(v3).array(max(1, L)), "amb": In(w), "bg": In(v3), "w_eye": In(w),
            "eye_miss": In(data.ArrayLayout(FIX_BITS, 3)), "colour": In(1),
            "idle": Out(1),
            **{name: Out(COUNTER_BITS) for name in RAY_COUNTERS.values()},
            "sec_busy": Out(COUNTER_BITS),
            **{name: Out(COUNTER_BITS) for name in POOL_COUNTERS},
        })

    def _texture_hits(self, cfg: Config) -> int:
        """On the pool with a texture unit, the hits the shading path holds beyond
        SecondaryPipe's: the light loop takes a hit only with its kd from the texture unit,
        whose latency on the pool is its two pipes, up to an interval's wait for each one's
        slot and a texel read from SDRAM (``mem_latency`` memory cycles). Hits enough to
        cover it keep SecondaryPipe taking one an interval (with SecondaryPipe's alone the
        office at 128x96 took 1.75x the cycles: ``docs/rgs.md``). Else 0."""
        if self.pool is None or self.tex is None:
            return 0
        tex, ii = self.tex, self.pool.ii
        wait = (tex.coord.latency + tex.filter.latency + 2 * ii
                + cfg.mem_latency * cfg.mem_clock_ratio)
        return -(-wait // ii)

    # -- pieces both slaves are built from -------------------------------------------------------
    def _eye(self, m: Module) -> EyeRays:
        """The eye-ray generator, on the camera and scene-box registers."""
        m.submodules.eye = eye = self.eye
        for k in ("pos", "corner", "dx", "dy", "width", "height", "box_lo", "box_hi",
                  "box_cull"):
            m.d.comb += getattr(eye, k).eq(getattr(self, k))
        return eye

    def _sec_out(self, m: Module, sec, sec_en: Signal) -> SimpleNamespace:
        """SecondaryPipe's output as the light loop sees it: ``valid``, ``tag``, ``p0``,
        ``g``, ``n``, ``r``; the loop sets ``take`` when it is done with it. ``sec_en`` is set
        to 1 when the pipe may take a hit. Alone the pipe holds its output: its ``en`` stalls
        it until taken. On the shading pool it never stalls: its outputs go into a queue as
        deep as the hits it can hold, and a hit enters only while the pipe and the queue
        together hold fewer."""
        v3 = vec3(self.cfg)
        take = Signal()
        if self.pool is None:
            m.d.comb += [sec_en.eq(~sec.o_valid | take), sec.en.eq(sec_en)]
            return SimpleNamespace(valid=sec.o_valid, tag=sec.o_tag, p0=sec.p0, g=sec.g,
                                   n=sec.n, r=sec.r, take=take,
                                   **({"tp0": sec.tp0, "tdir": sec.tdir} if sec.refract else {}))
        rf = ("tp0", "tdir") if sec.refract else ()
        lay = data.StructLayout({"p0": v3, "g": v3, "n": v3, "r": v3, "tag": self.sec_tag,
                                 **{k: v3 for k in rf}})
        depth = self.shade_hits
        m.submodules.secq = q = SyncFIFO(width=lay.size, depth=depth)
        held = Signal(range(depth + 1))           # hits in the pipe and the queue
        fed = sec.i_valid & sec.i_slot
        m.d.comb += [sec_en.eq(held < depth),
                     q.w_en.eq(sec.o_valid),
                     q.w_data.eq(Cat(sec.p0.as_value(), sec.g.as_value(), sec.n.as_value(),
                                     sec.r.as_value(), sec.o_tag,
                                     *(getattr(sec, k).as_value() for k in rf))),
                     q.r_en.eq(take)]
        m.d.sync += held.eq(held + fed - (take & q.r_rdy))
        h = data.View(lay, q.r_data)
        return SimpleNamespace(valid=q.r_rdy, tag=h.tag.as_value(), p0=h.p0, g=h.g, n=h.n,
                               r=h.r, take=take, **{k: getattr(h, k) for k in rf})

    def _slots(self, m: Module) -> SimpleNamespace:
        """The RTC packet slots: ``free`` (mask), ``any``/``new`` (the lowest free one),
        ``packet`` (each slot's eye packet id); ``take`` allocates ``new`` and ``release``
        frees ``rel`` this cycle."""
        NS = self.slots
        s = SimpleNamespace(free=Signal(NS, init=(1 << NS) - 1), take=Signal(),
                            release=Signal(), rel=Signal(range(NS)),
                            packet=_regs(NS, PACKET_ID_BITS, "slot_packet"))
        s.any, s.new = lowest(m, s.free, "slot")
        m.d.sync += s.free.eq((s.free & ~Mux(s.take, 1 << s.new, 0))
                              | Mux(s.release, 1 << s.rel, 0))
        return s

    def _admission(self, m: Module, eye: EyeRays, slot: Value, can_admit: Value) -> Signal:
        """A tile from the master starts its eye rays as RTC packet ``slot`` while
        ``can_admit``; returns the cycle's ``admit``."""
        admit = Signal()
        m.d.comb += [
            eye.req.valid.eq(self.req.valid & can_admit),
            self.req.ready.eq(eye.req.ready & can_admit),
            eye.req.payload.tile_x.eq(self.req.payload.tile_x),
            eye.req.payload.tile_y.eq(self.req.payload.tile_y),
            eye.req.payload.packet.eq(slot),
            admit.eq(self.req.valid & self.req.ready),
        ]
        return admit

    def _result_stage(self, m: Module) -> SimpleNamespace:
        """Stage B: the RTC's result registered (``valid``, ``res``); it moves on in a cycle
        with ``adv``, which the caller drives."""
        res = self.results
        b = SimpleNamespace(valid=Signal(), res=Signal(RayResult(self.cfg)), adv=Signal())
        m.d.comb += res.ready.eq(~b.valid | b.adv)
        with m.If(res.ready):
            m.d.sync += [b.valid.eq(res.valid), b.res.eq(res.payload)]
        return b

    def _count_rays(self, m: Module, en: Value, kind, kinds: tuple = ()):
        """``en``: a ray of ``kind`` goes into the RTC; its counter (:data:`RAY_COUNTERS`)
        counts it. ``kind``: a :class:`~model.raykind.RayKind`, or a signal of that shape
        holding one of ``kinds``."""
        for k in kinds or (kind,):
            counter = getattr(self, RAY_COUNTERS[k])
            with m.If(en & (kind == k) if kinds else en):
                m.d.sync += counter.eq(counter + 1)

    def _host_out(self, m: Module, other: SyncFIFO | None = None) -> SyncFIFO:
        """The host records: a 4-entry queue (the caller writes it) and the registered
        ``out`` stream; with ``other`` (a second queue of records) the two take turns."""
        m.submodules.outq = outq = SyncFIFO(width=SlaveResult(self.cfg).size, depth=4)
        m.submodules.out_stage = ost = OutputStage(SlaveResult(self.cfg))
        if other is None:
            m.d.comb += [ost.i.valid.eq(outq.r_rdy), ost.i.payload.eq(outq.r_data),
                         outq.r_en.eq(ost.i.ready)]
        else:
            turn = Signal()                  # 1: ``other`` goes first
            use = other.r_rdy & (~outq.r_rdy | turn)
            m.d.comb += [ost.i.valid.eq(outq.r_rdy | other.r_rdy),
                         ost.i.payload.eq(Mux(use, other.r_data, outq.r_data)),
                         outq.r_en.eq(ost.i.ready & ~use), other.r_en.eq(ost.i.ready & use)]
            with m.If(ost.i.valid & ost.i.ready):
                m.d.sync += turn.eq(~use)
        wiring.connect(m, ost.o, wiring.flipped(self.out))
        return outq

    def elaborate_eye_only(self, m: Module) -> Module:
        """The slave without secondary-ray hardware (``cfg.secondary_rays`` false): tiles in,
        eye rays to the RTC, every result to the host. The same cycles as the whole slave on
        a frame with no lights and no reflections: admission, the RTC input and the result
        path (a registered stage, the output queue and stage) are the same pieces; an eye
        ray's lane in its tile is its lane in the RTC packet, so no ray store is needed."""
        sb = ceil_log2(self.slots)
        eye = self._eye(m)
        slot = self._slots(m)
        admit = self._admission(m, eye, slot.new, slot.any)
        m.d.comb += slot.take.eq(admit)
        with m.If(admit):
            m.d.sync += slot.packet[slot.new].eq(self.req.payload.packet)
        m.d.comb += [self.rays.valid.eq(eye.o.valid),
                     self.rays.payload.eq(eye.o.payload.ray.as_value()),
                     eye.o.ready.eq(self.rays.ready)]
        self._count_rays(m, eye.o.valid & eye.o.ready, RayKind.EYE)
        b = self._result_stage(m)
        outq = self._host_out(m)
        bslot = b.res.packet[:sb]
        rec = Signal(SlaveResult(self.cfg))
        m.d.comb += [b.adv.eq(b.valid & outq.w_rdy),
                     rec.packet.eq(slot.packet[bslot]), rec.lane.eq(b.res.lane),
                     rec.tri.eq(b.res.tri), rec.t.eq(b.res.t), rec.u.eq(b.res.u),
                     rec.v.eq(b.res.v), outq.w_data.eq(rec), outq.w_en.eq(b.adv),
                     slot.rel.eq(bslot), slot.release.eq(b.adv & b.res.last)]
        m.d.comb += self.idle.eq((slot.free == (1 << self.slots) - 1) & ~b.valid &
                                 ~outq.r_rdy & ~self.out.valid)
        return m

    def elaborate(self, platform):
        m = Module()
        if not self.cfg.secondary_rays:
            return self.elaborate_eye_only(m)
        L = self.cfg.rgs_lights
        eye = self._eye(m)
        setup = self._datapaths(m)
        # K: the pending buffers a packet that may spawn rays reserves (one per light in use,
        # one for its reflections, one for its refracted rays with cfg.refraction)
        R = int(self.cfg.refraction)
        K = Signal(range(L + 2 + R))
        m.d.comb += K.eq(self.n_lights + 1 + R)
        slot = self._slot_table(m)
        pb = self._pending(m)
        self._branch_gate(m, pb, K)
        m.submodules.store = store = self._two_write(self.slots * self.cfg.packet_size)
        m.submodules.sender = snd = Sender(self.cfg, self.buffers, self.slots)
        eye_o = self._admit(m, eye, slot, pb, K, snd.busy)
        start = self._send(m, snd, setup, slot, pb, K, store)
        self._rtc_input(m, eye_o, setup, store)
        res = self._results(m, slot, store)
        fed = self._shade_feed(m, res)
        loop = self._light_loop(m, fed, res)
        bld = self._builders(m, pb, loop, K)
        # a branching packet's commit (its last token left LightPipe)
        ot = loop.ot
        m.d.comb += pb.br_dec.eq(self.shd.o_valid & ot.last & ot.spawn &
                                 (ot.depth < self.reflect_depth))
        m.d.sync += pb.branching.eq(pb.branching + pb.br_eye + pb.br_send - pb.br_dec)
        self._ambient(m, res, loop)
        m.d.sync += pb.ready.eq((pb.ready | bld.committed) &
                                ~Mux(start.go, 1 << start.buf, 0))
        m.d.sync += pb.free.eq((pb.free & ~bld.taken) | Mux(snd.done, 1 << snd.buf, 0))
        m.d.comb += pb.back.eq(bld.unused + snd.done)
        m.d.sync += pb.credits.eq(pb.credits + pb.back - pb.take)
        # -- idle: results in the shading path (context queue, SecondaryPipe, light loop,
        # LightPipe) counted
        NS, shd = self.slots, self.shd
        shading = Signal(range(NS * self.cfg.packet_size + 1))
        m.d.sync += shading.eq(shading + (res.adv & res.need_ctx) -
                               (shd.o_valid & loop.ot.tlast))
        m.d.comb += self.idle.eq((slot.free == (1 << NS) - 1) & (pb.credits == self.buffers) &
                                 eye.idle & ~res.valid & ~res.outq.r_rdy & ~self.out.valid &
                                 ~snd.busy & (shading == 0) & (loop.amb_cnt == 0))
        return m

    # -- the whole slave's pieces, in the order elaborate builds them -------------------------
    def _two_write(self, depth: int):
        """The ray store or the pending buffers (``depth`` rays of :func:`RayEntry`): a memory
        with two write ports, built as ``cfg.rgs_store`` says (``rtl.common.TwoWriteMemory``:
        two banks and a live-value table, so that both map to block RAM; ``PacketMemory``: a
        memory per block, the bits once). The block is the largest power of two that divides
        the packet size, so a block lies within one packet, and a buffer holds shadow or
        reflection rays, a slot an eye or a secondary packet: one writer at a time."""
        P = self.cfg.packet_size
        kind = PacketMemory if self.cfg.rgs_store == "per_packet" else TwoWriteMemory
        return kind(RayEntry(self.cfg), depth, P & -P)

    def _spawns(self, depth: Value) -> Value:
        """May a packet (eye or reflection) of this depth spawn rays?"""
        return (self.n_lights != 0) | (depth < self.reflect_depth)

    def _datapaths(self, m: Module) -> RaySetup:
        """Ray setup and the shading datapaths (alone or on their pool) as submodules."""
        m.submodules.setup = setup = self.setup
        if self.pool is None:
            m.submodules.sec, m.submodules.shd = self.sec, self.shd
        else:
            m.submodules.shading = self.pool
            self._pool_counters(m)
        m.d.comb += [setup.box_lo.eq(self.box_lo), setup.box_hi.eq(self.box_hi),
                     setup.box_cull.eq(self.box_cull)]
        return setup

    def _pool_counters(self, m: Module):
        """:data:`POOL_COUNTERS`: the pool's intervals (SecondaryPipe's slot, phase 0) and the
        inputs each datapath on it took (its first pipe valid in one of its slots)."""
        firsts = {"sec": self.sec, "light": self.shd, "eye": self.eye.gen,
                  "setup": self.setup.pipe}
        if self.tex is not None:
            firsts.update(tex_coord=self.tex.coord, tex_filter=self.tex.filter)
        m.d.sync += self.pool_intervals.eq(self.pool_intervals + self.sec.i_slot)
        for name, pipe in firsts.items():
            counter = getattr(self, f"pool_{name}")
            m.d.sync += counter.eq(counter + (pipe.i_valid & pipe.i_slot))

    def _slot_table(self, m: Module) -> SimpleNamespace:
        """The RTC packet slots (:meth:`_slots`) with per slot the packet's reflection
        ``depth`` and kind ``sub`` (0 eye or reflection rays, 1 + l shadow rays of light l)."""
        slot = self._slots(m)
        slot.depth = _regs(self.slots, DEPTH_BITS, "slot_depth")
        slot.sub = _regs(self.slots, SUB_BITS, "slot_sub")
        if self.cfg.refraction:          # the packet's path (SlaveResult)
            slot.path = _regs(self.slots, PATH_BITS, "slot_path")
        return slot

    def _pending(self, m: Module) -> SimpleNamespace:
        """The pending buffers: ``free`` and ``ready`` (masks), per buffer its packet's
        ``count`` (rays), ``sub``, ``depth`` and eye ``packet``; ``credits`` (buffers not
        reserved; ``take`` and ``back``, this cycle's reservations and returns) and ``mem``,
        the rays (:func:`RayEntry`; write ports ``w[0]`` shadow, ``w[1]`` reflection rays,
        from LightPipe, and refracted rays through ``w[0]``; read port ``r``, the sender's;
        with ``cfg.refraction`` per buffer its packet's ``path``)."""
        NB, P = self.buffers, self.cfg.packet_size
        pb = SimpleNamespace(
            free=Signal(NB, init=(1 << NB) - 1, name="buf_free"),
            ready=Signal(NB, name="buf_ready"),
            count=_regs(NB, range(P + 1), "buf_count"), sub=_regs(NB, SUB_BITS, "buf_sub"),
            depth=_regs(NB, DEPTH_BITS, "buf_depth"),
            packet=_regs(NB, PACKET_ID_BITS, "buf_packet"),
            path=_regs(NB, PATH_BITS, "buf_path") if self.cfg.refraction else None,
            credits=Signal(range(NB + 1), init=NB, name="credits"),
            take=Signal(range(self.cfg.rgs_reserve + 1), name="credit_take"),
            back=Signal(range(NB + 1), name="credit_back"))
        m.submodules.pend = pb.mem = self._two_write(NB * P)
        return pb

    def _branch_gate(self, m: Module, pb, K: Value):
        """The branching packets (those that may spawn, of depth below ``reflect_depth``:
        their hits may spawn a reflection and, with ``cfg.refraction``, a refracted packet that
        spawn in turn) in flight, ``pb.branching`` (``br_eye``, ``br_send``, ``br_dec``: this
        cycle's admitted eye packet, started secondary packet, commit), and ``pb.branch_ok``:
        fewer than ``B`` = (buffers - K) // (reflect_depth + 1) (at least 1) are, so one more
        may start (the module docstring). ``pb.gated``: the rules apply, with
        ``cfg.refraction`` always, else while K = 1 (no light in use: a commit's one waiting
        reflection packet takes the buffer its parent reserved and gives none back, so
        without the bound the waiting packets can hold every buffer)."""
        NB, D = self.buffers, self.reflect_depth
        pb.gated = Const(1) if self.cfg.refraction else (self.n_lights == 0)
        pb.branching = Signal(range(self.slots + 1), name="branching")
        pb.br_eye, pb.br_send = Signal(name="branch_eye"), Signal(name="branch_send")
        pb.br_dec = Signal(name="branch_commit")
        bmax = Signal(range(NB + 1), name="branch_max")
        m.d.comb += bmax.eq(sum((K + i * (D + 1) <= NB).as_unsigned()
                                for i in range(1, NB + 1)))
        pb.branch_ok = pb.branching < Mux(bmax == 0, 1, bmax)

    def _admit(self, m: Module, eye: EyeRays, slot, pb, K: Value, sender_busy: Value):
        """Admission of eye packets: a tile takes the lowest free RTC slot and, if its hits may
        spawn rays, reserves K pending buffers; only while no secondary packet waits (no
        ready buffer, the sender idle), and where the branching bound applies
        (``pb.gated``) only while one more branching packet may start
        (:meth:`_branch_gate`). Returns the admitted packets' eye rays (a stream of
        ``EyeRay``, ``ray.packet`` their slot): alone the tile is admitted before its rays
        are made (:meth:`_admission`), on the pool once they are
        (:meth:`_admission_ahead`)."""
        eye_spawns = self._spawns(0)
        can_admit = (slot.any & (~eye_spawns | (pb.credits >= K)) & (pb.ready == 0) &
                     ~sender_busy)
        eye_branches = self.reflect_depth != 0
        can_admit &= ~pb.gated | ~eye_branches | pb.branch_ok
        if self.pool is None:
            admit = self._admission(m, eye, slot.new, can_admit)
            packet, eye_o = self.req.payload.packet, eye.o
        else:
            admit, packet, eye_o = self._admission_ahead(m, eye, slot.new, can_admit)
        m.d.comb += pb.br_eye.eq(admit & eye_branches)
        with m.If(admit):
            m.d.comb += [slot.take.eq(1), pb.take.eq(Mux(eye_spawns, K, 0))]
            m.d.sync += [slot.packet[slot.new].eq(packet),
                         slot.depth[slot.new].eq(0), slot.sub[slot.new].eq(0)]
            if self.cfg.refraction:
                m.d.sync += slot.path[slot.new].eq(0)
        return eye_o

    def _admission_ahead(self, m: Module, eye: EyeRays, slot: Value, can_admit: Value):
        """Admission on the pool, where a slave makes one eye ray an interval: the tiles go
        straight into :class:`EyeRays`, which makes the next packet's rays into its queue
        (``ahead``: one packet) while the packet waits; it is admitted once its first ray is
        at the queue's head and ``can_admit``, and its rays leave from the next cycle with
        ``slot`` as their packet id. So the eye rays are made while the pool shades hits
        and sets up secondary rays, not only in turns with them. Returns ``admit``, the
        admitted tile's packet id and the rays out."""
        wiring.connect(m, wiring.flipped(self.req), eye.req)
        admit, is_open = Signal(name="eye_admit"), Signal(name="eye_open")
        eslot = Signal(PACKET_ID_BITS, name="eye_slot")
        o = stream.Signature(EyeRay(self.cfg)).create(path=("eye_admitted",))
        m.d.comb += [admit.eq(eye.o.valid & ~is_open & can_admit),
                     o.valid.eq(eye.o.valid & is_open), o.payload.eq(eye.o.payload),
                     o.payload.ray.packet.eq(eslot), eye.o.ready.eq(o.ready & is_open)]
        with m.If(admit):
            m.d.sync += [is_open.eq(1), eslot.eq(slot)]
        with m.If(o.valid & o.ready & o.payload.ray.last):
            m.d.sync += is_open.eq(0)
        return admit, eye.o.payload.ray.packet, o

    def _send(self, m: Module, snd: "Sender", setup: RaySetup, slot, pb, K: Value,
              store: "TwoWriteMemory | PacketMemory") -> SimpleNamespace:
        """The :class:`Sender` started on a ready buffer, into ray setup, each ray also into
        the ray store. A ready reflection packet that may spawn waits for its reservation;
        the others (shadow packets, reflections that spawn nothing) may start: the lowest
        ready buffer that can start goes, so a waiting reflection packet never blocks the
        shadow packets whose buffers give the credits back. Where the rules apply
        (``pb.gated``: with ``cfg.refraction``, or K = 1) a branching packet waits while no
        more may start (:meth:`_branch_gate`), and with ``cfg.refraction`` a packet that may
        spawn waits also while a deeper one that may spawn is ready. Returns ``go`` (a
        packet starts) and ``buf`` (its buffer)."""
        NB, P = self.buffers, self.cfg.packet_size
        startable = Signal(NB)
        sp = [(pb.sub[i] == 0) & self._spawns(pb.depth[i]) for i in range(NB)]
        # branching ones while they may (where the rules apply); with refraction (two waiting
        # packets a commit) the deepest first
        wait = [(pb.credits < K) |
                (pb.gated & (pb.depth[i] < self.reflect_depth) & ~pb.branch_ok)
                for i in range(NB)]
        if self.cfg.refraction:
            wait = [w | Cat(*(pb.ready[j] & sp[j] & (pb.depth[j] > pb.depth[i])
                              for j in range(NB) if j != i)).any()
                    for i, w in enumerate(wait)]
        m.d.comb += startable.eq(Cat(*(pb.ready[i] & ~(sp[i] & wait[i]) for i in range(NB))))
        any_ready, rb = lowest(m, startable, "ready")
        # a reflection packet that may spawn
        spawning = (pb.sub[rb] == 0) & self._spawns(pb.depth[rb])
        go = Signal(name="start_send")
        m.d.comb += [snd.start.valid.eq(any_ready & slot.any), snd.start.payload.buf.eq(rb),
                     snd.start.payload.slot.eq(slot.new),
                     snd.start.payload.count.eq(pb.count[rb]),
                     go.eq(snd.start.valid & snd.start.ready)]
        m.d.comb += pb.br_send.eq(go & spawning & (pb.depth[rb] < self.reflect_depth))
        with m.If(go):
            m.d.comb += slot.take.eq(1)
            with m.If(spawning):
                m.d.comb += pb.take.eq(K)
            m.d.sync += [slot.packet[slot.new].eq(pb.packet[rb]),
                         slot.depth[slot.new].eq(pb.depth[rb]),
                         slot.sub[slot.new].eq(pb.sub[rb])]
            if self.cfg.refraction:
                m.d.sync += slot.path[slot.new].eq(pb.path[rb])
        rd = pb.mem.r
        m.d.comb += [rd.addr.eq(snd.rd_addr), rd.en.eq(snd.rd_en), snd.rd_data.eq(rd.data),
                     snd.sub.eq(slot.sub[snd.slot]), snd.light_point.eq(self.light_point)]
        wiring.connect(m, snd.o, setup.i)
        xfer = snd.o.valid & snd.o.ready
        w = store.w[1]
        m.d.comb += [w.addr.eq(snd.slot * P + snd.o.payload.lane), w.data.eq(rd.data),
                     w.en.eq(xfer)]
        if self.cfg.refraction:          # a refracted packet: its path's bit of its depth
            kind = Signal(RayKind, name="send_kind")
            sd = slot.depth[snd.slot]
            refracted = slot.path[snd.slot].bit_select((sd - 1)[:DEPTH_BITS], 1)
            m.d.comb += kind.eq(Mux((snd.kind == RayKind.REFLECTION) & refracted,
                                    RayKind.REFRACTION, snd.kind))
            self._count_rays(m, xfer, kind,
                             (RayKind.SHADOW, RayKind.REFLECTION, RayKind.REFRACTION))
        else:
            self._count_rays(m, xfer, snd.kind, (RayKind.SHADOW, RayKind.REFLECTION))
        return SimpleNamespace(go=go, buf=rb)

    def _rtc_input(self, m: Module, eye_o, setup: RaySetup, store: "TwoWriteMemory | PacketMemory"):
        """:class:`RTCInput`: eye rays (``eye_o``, the admitted packets') or set-up secondary
        rays to the RTC; each eye ray into the ray store (origin, direction, lane, weight and
        its contribution if it misses)."""
        m.submodules.rtc_in = rin = RTCInput(self.cfg)
        wiring.connect(m, setup.o, rin.sec)
        m.d.comb += [rin.eye.valid.eq(eye_o.valid), rin.eye.payload.eq(eye_o.payload.ray),
                     eye_o.ready.eq(rin.eye.ready)]
        wiring.connect(m, rin.o, wiring.flipped(self.rays))
        eo, w = eye_o.payload, store.w[0]
        m.d.comb += [
            w.addr.eq(eo.ray.packet[:ceil_log2(self.slots)] * self.cfg.packet_size +
                      eo.ray.lane),
            w.data.eq(Cat(self.pos.as_value(), eo.dir.as_value(), eo.ray.lane,
                          self.w_eye, self.eye_miss.as_value())),
            w.en.eq(eye_o.valid & eye_o.ready),
        ]
        self._count_rays(m, eye_o.valid & eye_o.ready, RayKind.EYE)

    def _results(self, m: Module, slot, store: "TwoWriteMemory | PacketMemory") -> SimpleNamespace:
        """Every result: the ray store read with it (stage B, :meth:`_result_stage`), its host
        record (:meth:`_host_out`, taking turns with the ambient records), and for a result of
        an eye or reflection ray its shading context (the ``ctx`` queue) and, for a hit, its
        shading record's request; the slot is released with its packet's last result."""
        cfg, w, P = self.cfg, self.cfg.fmt.width, self.cfg.packet_size
        sb = ceil_log2(self.slots)
        res = self.results
        b = self._result_stage(m)
        m.d.comb += [store.r.addr.eq(res.payload.packet[:sb] * P + res.payload.lane),
                     store.r.en.eq(res.ready)]
        bslot = b.res.packet[:sb]
        sub, depth = slot.sub[bslot], slot.depth[bslot]
        hit = b.res.tri != (1 << TRI_ID_BITS) - 1
        shade_pkt = (sub == 0) & (self._spawns(depth) | self.colour)   # eye and reflection rays
        spawn_pkt = shade_pkt & self._spawns(depth)
        want_rec = shade_pkt & hit
        stored = data.View(RayEntry(cfg), store.r.data)
        b.ctx_lay = data.StructLayout({"org": vec3(cfg), "dir": vec3(cfg),
                                       "lane": lane_bits(cfg), "hit": 1, "last": 1,
                                       "packet": PACKET_ID_BITS, "depth": DEPTH_BITS, "t": w,
                                       "u": w, "v": w, "wt": w, "spawn": 1,
                                       **({"path": PATH_BITS} if cfg.refraction else {})})
        m.submodules.ctx = b.ctxq = ctxq = SyncFIFO(width=b.ctx_lay.size,
                                                    depth=4 + cfg.cache_queue)
        # ambient records: as many as LightPipe can hold in flight, reserved at the light loop
        b.amb_depth = 1 << ceil_log2(self.shd.in_flight + 7)
        m.submodules.ambq = b.ambq = SyncFIFO(width=SlaveResult(cfg).size, depth=b.amb_depth)
        b.outq = outq = self._host_out(m, b.ambq)
        rq = self.shade.req
        b.need_ctx = b.valid & shade_pkt
        ok = (outq.w_rdy & (~shade_pkt | (ctxq.w_rdy & (~want_rec | rq.ready))))
        m.d.comb += b.adv.eq(b.valid & ok)
        rec = Signal(SlaveResult(cfg))
        m.d.comb += [rec.packet.eq(slot.packet[bslot]), rec.lane.eq(stored.lane),
                     rec.depth.eq(depth), rec.sub.eq(sub), rec.tri.eq(b.res.tri),
                     rec.t.eq(b.res.t), rec.u.eq(b.res.u), rec.v.eq(b.res.v),
                     rec.col.eq(Mux(hit, 0, stored.col.as_value()))]
        if cfg.refraction:
            m.d.comb += rec.path.eq(slot.path[bslot])
        ctx = Signal(b.ctx_lay)
        m.d.comb += [ctx.org.eq(stored.org), ctx.dir.eq(stored.dir), ctx.lane.eq(stored.lane),
                     ctx.hit.eq(hit), ctx.last.eq(b.res.last),
                     ctx.packet.eq(slot.packet[bslot]), ctx.depth.eq(depth), ctx.t.eq(b.res.t),
                     ctx.u.eq(b.res.u), ctx.v.eq(b.res.v), ctx.wt.eq(stored.wt),
                     ctx.spawn.eq(spawn_pkt)]
        if cfg.refraction:
            m.d.comb += ctx.path.eq(slot.path[bslot])
        m.d.comb += [outq.w_data.eq(rec), outq.w_en.eq(b.adv),
                     ctxq.w_data.eq(ctx), ctxq.w_en.eq(b.adv & b.need_ctx),
                     rq.valid.eq(b.valid & want_rec & outq.w_rdy & ctxq.w_rdy),
                     rq.payload.addr.eq(b.res.tri), rq.payload.tag.eq(0)]
        m.d.comb += [slot.rel.eq(bslot), slot.release.eq(b.adv & b.res.last)]
        return b

    def _shade_feed(self, m: Module, res) -> SimpleNamespace:
        """SecondaryPipe's input: the head context (with its shading record, for a hit), one
        per enabled cycle in the pipe's slot; beside it (in order, at most the pipe's
        ``in_flight``) the hit's colour inputs in the ``matq`` queue: the record's material
        constants, the ray's weight, the packet's reservation, and kd through the texture unit
        where there is one (:meth:`_texture_feed`). Returns what the light loop reads:
        ``out`` (:meth:`_sec_out`), ``mat`` (the queue's head), ``kd``, ``ok`` (kd is there),
        ``matq``."""
        cfg, fmt, w, sec = self.cfg, self.cfg.fmt, self.cfg.fmt.width, self.sec
        ctxq = res.ctxq
        head = data.View(res.ctx_lay, ctxq.r_data)
        resp = self.shade.resp
        feed_ok = ctxq.r_rdy & (~head.hit | resp.valid)
        sec_en = Signal()                  # SecondaryPipe may take a hit (its output has room)
        f = SimpleNamespace(out=self._sec_out(m, sec, sec_en))
        feed = Signal()
        m.d.comb += [ctxq.r_en.eq(feed), resp.ready.eq(feed & head.hit)]
        rec = _Record(fmt, resp.payload.data)
        flags = rec.field(REC_FLAGS)
        tex = self.tex
        mat_lay = data.StructLayout({**({} if tex else {"kd": vec3(cfg)}), "ks": vec3(cfg),
                                     "kr": w, "shin": SHIN_BITS, "wt": w, "spawn": 1,
                                     **({"kt": w} if cfg.refraction else {})})
        m.submodules.matq = f.matq = matq = SyncFIFO(width=mat_lay.size,
                                                     depth=self.shade_hits)
        if tex is not None:
            f.kd, f.ok = self._texture_feed(m, head, rec, feed, feed_ok & sec_en & sec.i_slot)
        else:
            m.d.comb += feed.eq(feed_ok & sec_en & sec.i_slot)
            f.ok = 1
        mat_in = Signal(mat_lay)
        m.d.comb += [mat_in.ks.eq(rec.vec(REC_KS, 3)), mat_in.kr.eq(rec.word(REC_KR)),
                     mat_in.shin.eq(flags[REC_SHIN_SHIFT:REC_SHIN_SHIFT + SHIN_BITS]),
                     mat_in.wt.eq(head.wt), mat_in.spawn.eq(head.spawn),
                     matq.w_data.eq(mat_in), matq.w_en.eq(feed)]
        f.mat = data.View(mat_lay, matq.r_data)
        if tex is None:
            m.d.comb += mat_in.kd.eq(rec.vec(REC_KD, 3))
            f.kd = f.mat.kd
        st = data.View(self.sec_tag, sec.tag)
        m.d.comb += [sec.i_valid.eq(feed), sec.org.eq(head.org), sec.dir.eq(head.dir),
                     sec.t.eq(head.t), sec.u.eq(head.u), sec.v.eq(head.v), sec.eps.eq(self.eps),
                     sec.nf.eq(rec.vec(REC_NF, 3)),
                     sec.nv.eq(rec.vec(REC_NV, 9)),
                     st.lane.eq(head.lane), st.hit.eq(head.hit), st.last.eq(head.last),
                     st.refl.eq((flags & REC_REFLECTIVE) != 0), st.packet.eq(head.packet),
                     st.depth.eq(head.depth)]
        if cfg.refraction:               # the refraction's record constants, its tag
            m.d.comb += [sec.eta_in.eq(rec.word(REC_KT + 1)), sec.eta_out.eq(rec.word(REC_KT + 2)),
                         mat_in.kt.eq(rec.word(REC_KT)),
                         st.trans.eq((flags & REC_TRANSMITS) != 0), st.path.eq(head.path)]
        return f

    def _texture_feed(self, m: Module, head, rec: "_Record", feed: Signal, go: Value) -> tuple:
        """The texture unit beside SecondaryPipe: it takes the hit in the cycle SecondaryPipe
        does (``go``: the pipe takes it now; sets ``feed``), or, where the two pipes' slots
        (each with its own phase) may never meet in one cycle, through a queue as deep as the
        hits SecondaryPipe holds. Returns (kd, kd is there) at the unit's output."""
        tex, sec = self.tex, self.sec
        m.submodules.tex = tex
        wiring.connect(m, tex.mem, wiring.flipped(self.texel))
        ti = Signal(tex.i.payload.shape())
        if gcd(sec.ii, tex.coord.ii) > 1:
            m.submodules.texq = texq = SyncFIFO(width=len(ti.as_value()),
                                                depth=self.shade_hits)
            m.d.comb += [texq.w_en.eq(feed), texq.w_data.eq(ti),
                         feed.eq(go & texq.w_rdy),
                         tex.i.valid.eq(texq.r_rdy), tex.i.payload.eq(texq.r_data),
                         texq.r_en.eq(tex.i.ready)]
        else:           # coprime intervals (or none): both slots meet every lcm cycles
            m.d.comb += [tex.i.valid.eq(go), tex.i.payload.eq(ti),
                         feed.eq(go & tex.i.ready)]
        size = rec.field(REC_TEX_SIZE)
        m.d.comb += [
            ti.u.eq(head.u), ti.v.eq(head.v),
            ti.uv.eq(rec.vec(REC_UV, 6)),
            ti.addr.eq(rec.field(REC_TEX_ADDR)), ti.tw.eq(size[:16]), ti.th.eq(size[16:]),
            ti.on.eq(head.hit & ((rec.field(REC_FLAGS) & REC_TEXTURED) != 0) & self.colour),
            ti.kd.eq(rec.vec(REC_KD, 3))]
        return tex.o.payload.kd, tex.o.valid

    def _light_loop(self, m: Module, f, res) -> SimpleNamespace:
        """The light loop: each SecondaryPipe output to LightPipe once per light in use (once
        if no hit, or no light), in LightPipe's slots; a hit's first token reserves its
        ambient record (``amb_cnt``, at most the ambient queue's depth); after a packet's last
        token no new token until that token leaves LightPipe (``commit_wait``, which the
        builders clear). With ``cfg.refraction`` a hit on a material that transmits, below
        ``reflect_depth``, takes one more token, its refraction token (``rtok``): LightPipe
        carries the refracted ray's origin and direction (in place of ``p0`` and ``r``) and
        makes its weight and miss colour (``kr`` = kt: wt * kt, bg * (wt * kt)); it casts no
        shadow ray. Returns ``ot`` (LightPipe's output tag), ``commit_wait``, ``amb_cnt``."""
        L, shd, out, mat = self.cfg.rgs_lights, self.shd, f.out, f.mat
        R = self.cfg.refraction
        so = data.View(self.sec_tag, out.tag)
        li = Signal(range(max(2, L + R)))
        lp = SimpleNamespace(commit_wait=Signal(name="commit_wait"),  # a packet's last token
                             amb_cnt=Signal(range(res.amb_depth + 1), name="amb_cnt"),  # in
                             ot=data.View(self.shd_tag, shd.o_tag))                      # shd
        tokens_last = Mux(so.hit & (self.n_lights != 0), li == self.n_lights - 1, 1)
        rtok, lsel = Const(0, 1), li        # the refraction token; the light register index
        if R:
            ltoks = Mux(so.hit & (self.n_lights != 0), self.n_lights, 1)   # the lights' tokens
            refr = so.hit & so.trans & (so.depth < self.reflect_depth)
            rtok = Signal(name="rtok")
            m.d.comb += rtok.eq(refr & (li == ltoks))
            tokens_last = Mux(refr, rtok, tokens_last)
            lsel = Mux(rtok, 0, li)
        amb_tok = so.hit & (li == 0) & self.colour   # the token makes the hit's ambient record
        loop_go = (out.valid & f.ok & ~lp.commit_wait &
                   (~amb_tok | (lp.amb_cnt < res.amb_depth)) & shd.i_slot)
        take = loop_go & tokens_last
        m.d.comb += [out.take.eq(take), f.matq.r_en.eq(take)]
        if self.tex is not None:
            m.d.comb += self.tex.o.ready.eq(take)
        with m.If(loop_go):
            m.d.sync += li.eq(Mux(tokens_last, 0, li + 1))
            m.d.sync += self.sec_busy.eq(self.sec_busy + 1)
        with m.If(take & so.last):
            m.d.sync += lp.commit_wait.eq(1)
        tt = data.View(self.shd_tag, shd.tag)

        def per_light(regs):                # light li's register (a complete read mux)
            return Array([x.as_value() for x in regs] + [regs[0].as_value()] *
                         ((1 << ceil_log2(max(2, L))) - L))[lsel] if L else 0

        def on_rtok(refracted, value):     # the refraction token's input, else value's
            return Mux(rtok, Value.cast(refracted), Value.cast(value)) if R else value
        m.d.comb += [shd.en.eq(1), shd.i_valid.eq(loop_go),
                     shd.p0.eq(on_rtok(getattr(out, "tp0", None), out.p0)),
                     shd.g.eq(out.g),
                     shd.light.eq(per_light(self.lights)),
                     shd.point.eq(self.light_point.bit_select(lsel, 1) if L else 0),
                     shd.n.eq(out.n), shd.r.eq(on_rtok(getattr(out, "tdir", None), out.r)),
                     shd.kd.eq(f.kd), shd.ks.eq(mat.ks),
                     shd.kr.eq(on_rtok(getattr(mat, "kt", None), mat.kr)),
                     shd.shin.eq(mat.shin), shd.wt.eq(mat.wt),
                     shd.lc.eq(per_light(self.light_col)), shd.amb.eq(self.amb),
                     shd.bg.eq(self.bg),
                     tt.lane.eq(so.lane), tt.light.eq(lsel),
                     tt.hit.eq(so.hit & (self.n_lights != 0) & ~rtok), tt.rhit.eq(so.hit),
                     tt.refl.eq(so.refl), tt.first.eq(li == 0), tt.tlast.eq(tokens_last),
                     tt.last.eq(take & so.last), tt.spawn.eq(mat.spawn),
                     tt.packet.eq(so.packet), tt.depth.eq(so.depth)]
        if R:
            m.d.comb += [tt.rtok.eq(rtok), tt.path.eq(so.path)]
        ambq = res.ambq
        m.d.sync += lp.amb_cnt.eq(lp.amb_cnt + (loop_go & amb_tok) - (ambq.r_rdy & ambq.r_en))
        return lp

    def _builders(self, m: Module, pb, lp, K: Value) -> SimpleNamespace:
        """The builders: the L shadow packets and the reflection packet of the current source
        packet (and its refracted packet, builder L + 1, with ``cfg.refraction``), written
        from LightPipe's output into pending buffers (up to two new buffers a cycle for
        builders without one); at the source packet's commit (its last token left LightPipe)
        each built packet's buffer becomes ready with its metadata, and the reservations it
        did not use return. A refracted ray is written on its hit's refraction token, through
        the shadow rays' write port (the token casts no shadow ray, and no reflection ray is
        written then). Returns ``taken`` (buffers allocated), ``committed`` (buffers made
        ready), ``unused`` (credits returned) this cycle."""
        L, P, NB = self.cfg.rgs_lights, self.cfg.packet_size, self.buffers
        shd, ot = self.shd, lp.ot
        w = self.cfg.fmt.width
        R = self.cfg.refraction
        T = L + 1                     # the refracted packet's builder
        nbld = L + 1 + R
        has = Signal(nbld)
        bbuf = _regs(nbld, max(1, ceil_log2(NB)), "bld_buf")
        bcnt = _regs(nbld, range(P + 1), "bld_count")
        # reflection write (LightPipe output, first token of a hit on a reflective surface)
        rf_w = shd.o_valid & ot.first & ot.rhit & ot.refl & (ot.depth < self.reflect_depth)
        # shadow write (LightPipe output)
        sh_w = shd.o_valid & ot.hit & shd.cast
        sh_b = ot.light               # the light's builder (as wide as the light index: the
                                      # register arrays' read muxes stay complete)
        # buffers for builders without one: up to two new ones a cycle
        a1, f1 = lowest(m, pb.free, "alloc1")
        a2, f2 = lowest(m, pb.free & ~(1 << f1), "alloc2")
        # refraction write (LightPipe output, the hit's refraction token)
        rt_w = shd.o_valid & ot.rtok if R else Const(0, 1)
        need_rf = rf_w & ~has[L]
        need_sh = sh_w & ~has.bit_select(sh_b, 1)
        rf_buf = Mux(has[L], bbuf[L], f1)
        sh_buf = Mux(has.bit_select(sh_b, 1), bbuf[sh_b], Mux(need_rf, f2, f1))
        bld = SimpleNamespace(taken=Signal(NB, name="taken"),
                              committed=Signal(NB, name="committed"),
                              unused=Signal(range(nbld + 1), name="unused"))
        need_rt = (rt_w & ~has[T]) if R else Const(0, 1)
        m.d.comb += bld.taken.eq(Mux(need_rf, 1 << f1, 0) |
                                 Mux(need_sh, Mux(need_rf, 1 << f2, 1 << f1), 0) |
                                 Mux(need_rt, 1 << f1, 0))
        w_sh, w_rf = pb.mem.w
        # a reflection or refracted ray: origin, direction (LightPipe's o_r), weight, miss
        bounce = Cat(shd.o_p0.as_value(), shd.o_r.as_value(), ot.lane, shd.wr,
                     shd.rmiss.as_value())
        sh_addr = sh_buf * P + bcnt[sh_b]
        sh_data = Cat(shd.o_p0.as_value(), shd.dir.as_value(), ot.lane, Const(0, w),
                      shd.col.as_value())
        if R:
            rt_buf = Mux(has[T], bbuf[T], f1)
            sh_addr = Mux(rt_w, rt_buf * P + bcnt[T], sh_addr)
            sh_data = Mux(rt_w, bounce, sh_data)
        m.d.comb += [
            w_rf.addr.eq(rf_buf * P + bcnt[L]), w_rf.en.eq(rf_w), w_rf.data.eq(bounce),
            w_sh.addr.eq(sh_addr), w_sh.en.eq(sh_w | rt_w), w_sh.data.eq(sh_data),
        ]
        # commit: the source packet's last token left LightPipe
        commit = shd.o_valid & ot.last
        new_has = Signal(nbld)
        m.d.comb += new_has.eq(has | Mux(rf_w, 1 << L, 0) | Mux(sh_w, 1 << sh_b, 0) |
                               Mux(rt_w, 1 << T, 0))
        with m.If(rf_w):
            m.d.sync += [bcnt[L].eq(bcnt[L] + 1)]
            with m.If(~has[L]):
                m.d.sync += bbuf[L].eq(f1)
        with m.If(sh_w):
            m.d.sync += bcnt[sh_b].eq(bcnt[sh_b] + 1)
            with m.If(~has.bit_select(sh_b, 1)):
                m.d.sync += bbuf[sh_b].eq(Mux(need_rf, f2, f1))
        if R:
            with m.If(rt_w):
                m.d.sync += bcnt[T].eq(bcnt[T] + 1)
                with m.If(~has[T]):
                    m.d.sync += bbuf[T].eq(f1)

        def fresh(i):                # the buffer builder i is given this cycle
            return f1 if i in (L, T) else Mux(need_rf, f2, f1)
        with m.If(commit):
            m.d.sync += has.eq(0)
            for i in range(nbld):
                cnt = (bcnt[i] + Mux(sh_w & (sh_b == i), 1, 0) + (rf_w if i == L else 0) +
                       (rt_w if i == T else 0))
                b = Mux(has[i], bbuf[i], fresh(i))
                m.d.sync += bcnt[i].eq(0)
                with m.If(new_has[i]):
                    m.d.sync += [pb.count[b].eq(cnt),
                                 pb.sub[b].eq(0 if i in (L, T) else i + 1),
                                 pb.depth[b].eq(ot.depth + (1 if i in (L, T) else 0)),
                                 pb.packet[b].eq(ot.packet)]
                    if R:                # a refracted packet: its path's bit of the new depth
                        m.d.sync += pb.path[b].eq(
                            ot.path | (Const(1, PATH_BITS) << ot.depth)[:PATH_BITS]
                            if i == T else ot.path)
            m.d.comb += bld.unused.eq(Mux(ot.spawn, K - sum(new_has[i] for i in range(nbld)),
                                          0))
            m.d.comb += bld.committed.eq(Cat(*(
                sum((new_has[i] & (Mux(has[i], bbuf[i], fresh(i)) == b)) for i in range(nbld))
                != 0 for b in range(NB))))
            m.d.sync += lp.commit_wait.eq(0)
        with m.Else():
            m.d.sync += has.eq(new_has)
        return bld

    def _ambient(self, m: Module, res, lp):
        """A hit's ambient record (LightPipe's output, the hit's first token) into the
        ambient queue, which :meth:`_host_out` empties in turn with the ray records."""
        shd, ot = self.shd, lp.ot
        amb_rec = Signal(SlaveResult(self.cfg))
        amb_w = shd.o_valid & ot.first & ot.rhit & self.colour
        m.d.comb += [amb_rec.packet.eq(ot.packet), amb_rec.lane.eq(ot.lane),
                     amb_rec.depth.eq(ot.depth), amb_rec.col.eq(shd.amb_col),
                     *([amb_rec.path.eq(ot.path)] if self.cfg.refraction else []),
                     amb_rec.shade.eq(1), res.ambq.w_data.eq(amb_rec), res.ambq.w_en.eq(amb_w)]
