"""The one configuration object: every parameter of the chip and the golden model.

The CLI, the golden model, the RTL and the statistics all take a :class:`Config`; derived
sizes (stack depth, address widths, cache geometry) are computed here and nowhere else.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from .fp import FPFormat


CACHE_TOPOLOGIES = ("shared", "private")   # Config.cache_topology
INT_TESTS = ("watertight", "projection")   # Config.int_test
RGS_STORES = ("two_banks", "per_packet")    # Config.rgs_store
TRAV_STACKS = ("two_values", "one_value")   # Config.trav_stack


_TYPE_WORDS = {bool: "true or false (a bool)", int: "an integer", float: "a finite number",
               str: "a string"}


class ConfigError(ValueError):
    """An impossible or inconsistent configuration; the message names the parameter."""


def _pow2(x: int) -> bool:
    return x > 0 and (x & (x - 1)) == 0


@dataclass(frozen=True)
class Config:
    # --- arithmetic ---------------------------------------------------------------------------
    fmt: FPFormat = field(default_factory=FPFormat)

    # --- ray tracing core (RTC) -------------------------------------------------------------
    rtcs: int = 4                  # ray tracing cores on the chip
    threads: int = 16              # packets in flight per RTC
    trav_subunits: int = 4         # traversal sub-units per RTC (a packet is split statically)
    trav_sync: bool = True         # sub-units run synchronously (False: asynchronously)
    int_test: str = "watertight"   # the intersection unit's ray-triangle test: "watertight"
                                   # (Woop, Benthin, Wald 2013, on the vertices) or
                                   # "projection" (the paper's: Wald et al. 2001, on
                                   # precomputed triangle records; docs/memory-format.md)
    # the traversal stack's word a lane and level: "two_values" (the far interval, tnear and
    # tfar: a pop copies nothing) or "one_value" (one value and a bit, the paper's 34.5 bits:
    # a pop after a leaf first writes the lanes' intervals back; docs/architecture.md)
    trav_stack: str = "two_values"
    int_tri_slots: int = 8         # triangles the intersection unit holds (fetched ahead + tested)
    list_outstanding: int = 8      # list-word reads the list unit keeps in flight
    # pipeline stages of the RTL's FP units (0: the unit's default: add 3, mul 3, divider
    # ceil((M+3)/4)+1 = 8 at binary32, square root ceil((M+2)/4)+1 = 8); more stages trade
    # latency for clock rate (docs/fpga.md)
    fp_add_latency: int = 0
    fp_mul_latency: int = 0
    fp_div_latency: int = 0
    fp_sqrt_latency: int = 0
    fp_cmp_latency: int = 0        # compare and min/max units (0: the default 1; 2 registers
                                   # their inputs too)
    # extra registers for a faster clock (docs/fpga.md): block-RAM reads registered before
    # they feed arithmetic or control, the per-thread selects of the traversal control cut in
    # two, the caches' lookup in two stages. False keeps every unit's cycle timing as it was.
    fast_clock: bool = False
    # delays of at least this many cycles in the fixed-latency datapaths (intersection test,
    # ray setup, eye rays, shading) are ring buffers in small memories (LUT-RAM on an FPGA)
    # instead of flip-flop chains; the same cycles. 0: flip-flops only (docs/fpga.md)
    delay_ram: int = 0
    tile_w: int = 8                # a packet is a tile_w x tile_h tile of eye rays
    tile_h: int = 8                # (tile_w x tile_h = packet_size rays)

    # --- kd-tree (the paper's BSP) -----------------------------------------------------------
    kd_max_depth: int = 24         # d: maximum number of scene subdivisions (sizes the stack)
    kd_leaf_size: int = 4          # stop splitting at or below this many triangles
    kd_bins: int = 32              # SAH bins per axis
    kd_cost_trav: float = 1.0      # SAH cost of one traversal step
    kd_cost_int: float = 1.5       # SAH cost of one triangle test

    # --- shading (RGS) -------------------------------------------------------------------------
    reflect_depth: int = 3         # maximum reflection bounces
    oversampling: int = 1          # rays per pixel side: n x n rays on a regular sub-pixel grid
    shadows: bool = True           # every light casts shadows
    rgs_lights: int = 4            # light registers per RGS slave (the most lights a scene has)
    # the RGS slaves make refracted rays (a material with transmit > 0; docs/rgs.md,
    # "Refraction"): the refraction datapath beside the secondary rays' and one more pending
    # buffer reserved per packet that may spawn rays
    refraction: bool = False
    # pending secondary packets per RGS slave (packet_size rays each); 0: enough to keep every
    # RTC thread busy, threads + rgs_lights + 1 (at least 2 (rgs_lights + 1) + 2, the fewest
    # that cannot deadlock: docs/chip.md)
    rgs_buffers: int = 0
    shade_cache_kb: int = 28       # each RGS slave's cache of shading records (face and vertex
                                   # normals, flags, colour constants, texture coordinates and
                                   # texture: 112 bytes a triangle; 28 KB = 256 records)
    # FP units of each RGS slave datapath (eye rays, ray setup, secondary rays, light and
    # colour): 0 = one pipelined unit per operation (a ray a cycle); n = at most n adders
    # (multipliers), shared in a modulo schedule: the datapath takes a ray every ii cycles,
    # ii = ceil(operations / n) (docs/rgs.md). The paper's slave has 3 adders, 4 multipliers.
    rgs_fp_adders: int = 0
    rgs_fp_muls: int = 0
    # every slave datapath (eye rays, ray setup, secondary rays, light and colour, texture)
    # shares one pool of those units instead of a budget each (docs/rgs.md, "One pool for
    # the slave"); needs a budget
    rgs_fp_pool: bool = False
    # how an RGS slave builds its ray store and pending buffers, memories with two write
    # ports: "two_banks" (a bank per write port and a live-value table: block RAM on an FPGA,
    # twice the bits) or "per_packet" (a memory per packet of rays, written by one port at a
    # time: the bits once, small memories; docs/chip.md)
    rgs_store: str = "two_banks"
    # ray results the chip hands out a cycle: one output stream each, slave s on stream
    # s mod result_ports (round-robin among its slaves); the stand-in for the frame buffer's
    # writes, whose one result a cycle caps 16 RTCs (docs/memory-interface.md)
    result_ports: int = 1
    tex_cache_kb: int = 4          # each RGS slave's texel cache (64-bit words, two RGBA8
                                   # texels each); 0: no texture unit (a textured surface shows
                                   # its material's colour)

    # --- memory interface (RTC-MI) -------------------------------------------------------------
    clock_mhz: float = 533.0       # chip clock
    mem_clock_ratio: int = 4       # chip cycles per SDRAM cycle
    mem_chips: int = 4             # 16-bit SDRAM chips
    mem_chip_bits: int = 16        # data bits per SDRAM chip
    mem_latency: int = 20          # chip cycles from request to first data (ideal memory/SDRAM)
    cache_topology: str = "shared"  # "shared": the paper's RTC-MI, three caches shared by all
                                   # RTCs behind round-robin buses with labeled broadcast;
                                   # "private": three caches per RTC
    trav_cache_kb: int = 64        # the kd-node cache (RTC-MI; one per RTC when private)
    list_cache_kb: int = 64        # the list-entry cache (one per RTC when private)
    int_cache_kb: int = 144        # the triangle cache (144 KB = 4 096 triangles; one per RTC
                                   # when private)
    cache_ways: int = 1            # 1 (direct-mapped), 2 or 4
    cache_line_words: int = 1      # 64-bit words per cache line (triangles: 5 words per item)
    cache_outstanding: int = 4     # outstanding misses of a cache per RTC it serves (a shared
                                   # RTC-MI cache: rtcs times this; a slave's cache: this)
    cache_queue: int = 16          # requests in flight inside a cache (in-order response
                                   # queue) per RTC it serves, as cache_outstanding
    int_item_bits: int = 288       # bits of a triangle the int-cache keeps (288: 9 floats; 320: +id)
    mem_chip_queue: int = 4        # requests queued per SDRAM chip in the memory controller
    addr_bits: int = 32            # memory word address bits of every memory port, cache tag,
                                   # bus and base register (2**addr_bits words of 8 bytes);
                                   # for_scene narrows it to the scene's memory image

    def __post_init__(self) -> None:
        self._check_types()
        for name in ("rtcs", "threads", "trav_subunits", "tile_w", "tile_h", "kd_max_depth",
                     "kd_leaf_size", "kd_bins", "mem_chips", "mem_clock_ratio",
                     "cache_outstanding", "cache_line_words", "mem_chip_bits",
                     "trav_cache_kb", "list_cache_kb", "int_cache_kb"):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name}={getattr(self, name)} must be >= 1")
        if self.clock_mhz <= 0:
            raise ConfigError(f"clock_mhz={self.clock_mhz} must be > 0 (the chip clock in MHz; "
                              "the paper's 533)")
        if self.mem_latency < 0:
            raise ConfigError(f"mem_latency={self.mem_latency} must be >= 0 (chip cycles from a "
                              "memory request to its first data)")
        for name in ("fp_add_latency", "fp_mul_latency", "fp_div_latency", "fp_sqrt_latency",
                     "fp_cmp_latency"):
            if not 0 <= getattr(self, name) <= 64:
                raise ConfigError(f"{name}={getattr(self, name)} must be in 0..64 (pipeline "
                                  "stages of that FP unit; 0 = the unit's default)")
        if self.delay_ram == 1 or self.delay_ram < 0:
            raise ConfigError(f"delay_ram={self.delay_ram} must be 0 (flip-flop delays) or "
                              ">= 2 (the shortest delay kept in a ring buffer)")
        if self.int_tri_slots < 2 or not _pow2(self.int_tri_slots):
            raise ConfigError(f"int_tri_slots={self.int_tri_slots} must be a power of two >= 2 "
                              "(one triangle is tested while the next ones are fetched)")
        if self.list_outstanding < 2 or not _pow2(self.list_outstanding):
            raise ConfigError(f"list_outstanding={self.list_outstanding} must be a power of two "
                              ">= 2")
        if not 0 <= self.reflect_depth <= 15:
            raise ConfigError(f"reflect_depth={self.reflect_depth} must be in 0..15 (the "
                              "slave's 4-bit ray depth)")
        if not 0 <= self.rgs_lights <= 14:
            raise ConfigError(f"rgs_lights={self.rgs_lights} must be in 0..14 (light "
                              "registers per RGS slave)")
        if self.shade_cache_kb < 1:
            raise ConfigError(f"shade_cache_kb={self.shade_cache_kb} must be >= 1")
        if self.rgs_buffers and self.rgs_buffers < self.min_rgs_buffers:
            need = ("2 (rgs_lights + 2) + 2 and rgs_lights + 2 + reflect_depth + 1 "
                    "(refraction)" if self.refraction else
                    "2 (rgs_lights + 1) + 2 and reflect_depth + 2 (a frame without lights)")
            raise ConfigError(f"rgs_buffers={self.rgs_buffers} is too few for rgs_lights="
                              f"{self.rgs_lights}: a slave needs at least {need} = "
                              f"{self.min_rgs_buffers} pending buffers (or 0: the default) so "
                              "that a reflection packet always finds its reservation")
        if self.refraction and not self.secondary_rays:
            raise ConfigError("refraction=True but the RGS slaves make no secondary rays "
                              "(rgs_lights=0 and reflect_depth=0): give reflect_depth >= 1 "
                              "(refracted rays count as a reflection level), or set "
                              "refraction=False")
        if self.rgs_fp_adders < 0 or self.rgs_fp_muls < 0:
            raise ConfigError(f"rgs_fp_adders={self.rgs_fp_adders}, rgs_fp_muls="
                              f"{self.rgs_fp_muls} must be >= 0 (0: a unit per operation)")
        if self.rgs_fp_pool and not (self.rgs_fp_adders or self.rgs_fp_muls):
            raise ConfigError("rgs_fp_pool=True shares a budget of FP units among the slave's "
                              "datapaths: give rgs_fp_adders and/or rgs_fp_muls (the paper's "
                              "slave: 3 and 4)")
        if self.tex_cache_kb < 0:
            raise ConfigError(f"tex_cache_kb={self.tex_cache_kb} must be >= 0 (0: no texture "
                              "unit)")
        if self.oversampling < 1:
            raise ConfigError(f"oversampling={self.oversampling} must be >= 1")
        if self.packet_size > 64:
            raise ConfigError(f"packet of tile_w x tile_h = {self.tile_w}x{self.tile_h} = "
                              f"{self.packet_size} rays: "
                              "at most 64 rays per packet (the active mask is 64 bits)")
        if self.packet_size % self.trav_subunits:
            raise ConfigError(f"packet size tile_w x tile_h = {self.packet_size} is not "
                              "divisible by "
                              f"trav_subunits={self.trav_subunits}")
        if self.kd_max_depth > 62:
            raise ConfigError(f"kd_max_depth={self.kd_max_depth} must be <= 62")
        if not 1 <= self.result_ports <= self.rtcs:
            raise ConfigError(f"result_ports={self.result_ports} must be in 1..rtcs={self.rtcs} "
                              "(each output stream serves at least one RGS slave)")
        if self.cache_topology not in CACHE_TOPOLOGIES:
            raise ConfigError(f"cache_topology={self.cache_topology!r} must be one of "
                              f"{', '.join(CACHE_TOPOLOGIES)} (shared: three caches for the "
                              "chip; private: three caches per RTC)")
        if self.int_test not in INT_TESTS:
            raise ConfigError(f"int_test={self.int_test!r} must be one of "
                              f"{', '.join(INT_TESTS)} (watertight: the test on the triangle's "
                              "vertices; projection: the paper's test on precomputed records)")
        if self.rgs_store not in RGS_STORES:
            raise ConfigError(f"rgs_store={self.rgs_store!r} must be one of "
                              f"{', '.join(RGS_STORES)} (two_banks: a bank per write port and a "
                              "live-value table; per_packet: a memory per packet)")
        if self.trav_stack not in TRAV_STACKS:
            raise ConfigError(f"trav_stack={self.trav_stack!r} must be one of "
                              f"{', '.join(TRAV_STACKS)} (two_values: the far interval a lane "
                              "and level; one_value: one value and a bit)")
        if self.trav_stack == "one_value" and self.fast_clock:
            raise ConfigError("trav_stack='one_value' is built for the default clock only: "
                              "set fast_clock=False, or trav_stack='two_values'")
        if self.cache_ways not in (1, 2, 4):
            raise ConfigError(f"cache_ways={self.cache_ways} must be 1, 2 or 4")
        if not _pow2(self.threads):
            raise ConfigError(f"threads={self.threads} must be a power of two")
        if self.kd_cost_trav <= 0 or self.kd_cost_int <= 0:
            raise ConfigError("kd_cost_trav and kd_cost_int must be > 0")
        if self.cache_queue < 1 or self.mem_chip_queue < 1:
            raise ConfigError(f"cache_queue={self.cache_queue} and mem_chip_queue="
                              f"{self.mem_chip_queue} must be >= 1")
        if self.int_item_bits not in (288, 320):
            raise ConfigError(f"int_item_bits={self.int_item_bits} must be 288 (the 9 vertex "
                              "floats) or 320 (the whole 5-word triangle, id included)")
        if not self.min_addr_bits <= self.addr_bits <= 32:
            raise ConfigError(f"addr_bits={self.addr_bits} must be in {self.min_addr_bits}..32 "
                              "(at least the index bits of the largest cache: "
                              f"{self.min_addr_bits} here)")
        if self.mem_chips & (self.mem_chips - 1):
            raise ConfigError(f"mem_chips={self.mem_chips} must be a power of two (1, 2, 4, 8): "
                              "the controller hashes addresses over chips by XOR-folding")

    def _check_types(self) -> None:
        """Every field has its default's type: an int field an int (not a bool or a float), a
        float field a finite number, a bool field a bool, a str field a str; the message names
        the field. (A Config from Python code can hold anything; the command line parses
        strictly, ``saarcor.args``.)"""
        import math
        import numbers
        if not isinstance(self.fmt, FPFormat):
            raise ConfigError(f"fmt={self.fmt!r} must be an FPFormat (e.g. FPFormat(8, 23))")
        for f in dataclasses.fields(self):
            if f.name == "fmt":
                continue
            v, want = getattr(self, f.name), type(f.default)
            if want is bool:
                ok = isinstance(v, bool)
            elif want is int:
                ok = isinstance(v, numbers.Integral) and not isinstance(v, bool)
                if ok and not isinstance(v, int):
                    object.__setattr__(self, f.name, int(v))     # numpy integers
            elif want is float:
                ok = isinstance(v, numbers.Real) and not isinstance(v, bool)
                if ok and not math.isfinite(v):
                    raise ConfigError(f"{f.name}={v} must be a finite number")
                if ok and not isinstance(v, float):
                    object.__setattr__(self, f.name, float(v))
            else:
                ok = isinstance(v, want)
            if not ok:
                raise ConfigError(f"{f.name}={v!r} must be {_TYPE_WORDS[want]}, not "
                                  f"{type(v).__name__}")

    # --- derived sizes (the only place they are computed) -----------------------------------
    @property
    def packet_size(self) -> int:
        return self.tile_w * self.tile_h

    @property
    def rays_per_subunit(self) -> int:
        return self.packet_size // self.trav_subunits

    @property
    def stack_depth(self) -> int:
        """Entries of the per-packet traversal stack: one per kd-tree level."""
        return self.kd_max_depth

    @property
    def secondary_rays(self) -> bool:
        """Do the RGS slaves have the secondary-ray hardware (ray setup, the secondary and
        shadow datapaths, pending buffers, shading caches)? Not when they hold no light and
        make no reflection (``rgs_lights == 0 and reflect_depth == 0``): eye rays only."""
        return self.rgs_lights > 0 or self.reflect_depth > 0

    @property
    def min_rgs_buffers(self) -> int:
        """The fewest pending buffers a slave can hold without deadlock: ``2 *``
        :attr:`rgs_reserve` ``+ 2``, and at least K ``+ reflect_depth + 1`` for the K under
        the branching bound (``rtl/rgs/slave.py``, ``docs/chip.md``): :attr:`rgs_reserve` with
        :attr:`refraction`, else 1 (a frame without lights)."""
        k = self.rgs_reserve if self.refraction else 1
        return max(2 * self.rgs_reserve + 2, k + self.reflect_depth + 1)

    @property
    def rgs_reserve(self) -> int:
        """The most pending buffers a packet that may spawn rays reserves: one per light, one
        for its reflections and, with :attr:`refraction`, one for its refracted rays."""
        return self.rgs_lights + 1 + int(self.refraction)

    @property
    def min_addr_bits(self) -> int:
        """The narrowest memory address this configuration's caches can index: enough bits
        to number every 32-bit item of the largest cache (a cache's set and line-offset
        bits come out of the address; the rest is its tag)."""
        kb = max(self.trav_cache_kb, self.list_cache_kb, self.int_cache_kb,
                 self.shade_cache_kb, self.tex_cache_kb)
        return max(1, (kb * 1024 * 8 // 32 - 1).bit_length())

    @property
    def thread_bits(self) -> int:
        return max(1, (self.threads - 1).bit_length())

    @property
    def mem_bytes_per_s(self) -> float:
        return self.mem_chips * self.mem_chip_bits / 8 * self.clock_mhz * 1e6 / self.mem_clock_ratio

    def fp_latencies(self) -> dict:
        """``{"add": n, "mul": n, "div": n, "sqrt": n, "cmp": n}`` for the RTL's FP units
        (``cmp``: compare and min/max of the traversal and intersection units); None = the
        unit's default; ``delay_ram``: :attr:`delay_ram` for the datapaths' delays."""
        return {"add": self.fp_add_latency or None, "mul": self.fp_mul_latency or None,
                "div": self.fp_div_latency or None, "sqrt": self.fp_sqrt_latency or None,
                "cmp": self.fp_cmp_latency or None, "delay_ram": self.delay_ram}

    def rgs_budget(self) -> dict | None:
        """The RGS slave datapaths' FP unit budget (``rtl.rgs``): ``{"add": n, "mul": n}`` of
        :attr:`rgs_fp_adders`, :attr:`rgs_fp_muls` (the nonzero ones), or None: a unit per
        operation."""
        b = {k: n for k, n in (("add", self.rgs_fp_adders), ("mul", self.rgs_fp_muls)) if n}
        return b or None

    def for_scene(self, scene, image, width: int, height: int) -> "Config":
        """The smallest chip of this configuration that renders ``scene`` at ``width x
        height`` the same: the traversal stack as deep as the scene's kd-tree (``image``, its
        memory image, built with this configuration: ``model.render.prepare``), as many light
        registers as the scene casts shadows from, no reflections if no triangle reflects (so
        for a scene without lights and mirrors no secondary-ray hardware:
        :attr:`secondary_rays`), no texture unit if no triangle is textured, no refraction
        if no triangle transmits. Rebuilding the
        tree with the derived ``kd_max_depth`` gives the same tree (the limit was not
        reached below it). Memory addresses get as many bits as the image's words need (at
        least :attr:`min_addr_bits`). Raises :class:`ConfigError` if the scene needs more than this
        configuration provides (:meth:`check_scene`)."""
        self.check_scene(scene, image, width, height)
        need = scene_needs(scene, image, self)
        return self.replace(kd_max_depth=max(1, need["stack_depth"]),
                            rgs_lights=need["lights"], reflect_depth=need["reflect_depth"],
                            refraction=need["refraction"],
                            tex_cache_kb=need["tex_cache_kb"],
                            addr_bits=max(self.min_addr_bits, need["addr_bits"]))

    def check_scene(self, scene, image, width: int, height: int) -> None:
        """Raise :class:`ConfigError` naming what ``scene`` (with its memory ``image``) at
        ``width x height`` needs beyond this configuration."""
        need = scene_needs(scene, image, self)
        if need["stack_depth"] > self.stack_depth:
            raise ConfigError(f"the scene's kd-tree is {need['stack_depth']} levels deep, the "
                              f"traversal stack holds {self.stack_depth} (kd_max_depth="
                              f"{self.kd_max_depth}): build the tree with this configuration "
                              "or raise kd_max_depth")
        if need["lights"] > self.rgs_lights:
            raise ConfigError(f"the scene casts shadows from {need['lights']} lights, the RGS "
                              f"slaves hold rgs_lights={self.rgs_lights}: raise rgs_lights "
                              "(or turn shadows off)")
        if need["refracts"] and not self.refraction:
            raise ConfigError("the scene has a material that transmits (refracted rays), the "
                              "RGS slaves make none (refraction=False): set refraction=True")
        if need["addr_bits"] > self.addr_bits:
            raise ConfigError(f"the scene's memory image is {len(image.data)} words, the chip "
                              f"addresses 2**{self.addr_bits} (addr_bits={self.addr_bits}): "
                              f"raise addr_bits to {need['addr_bits']}")
        for name, n in (("width", width), ("height", height)):
            if not 1 <= n * self.oversampling < 1 << COORD_BITS:
                raise ConfigError(f"{name}={n} x oversampling {self.oversampling}: the RGS "
                                  f"counts samples in {COORD_BITS} bits (1 .. "
                                  f"{(1 << COORD_BITS) - 1})")

    def replace(self, **changes) -> "Config":
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["fmt"] = {"exp_bits": self.fmt.exp_bits, "frac_bits": self.fmt.frac_bits}
        return d

    @property
    def rtcmis(self) -> int:
        """RTC-MIs on the chip, each with a trav, list and int cache: one shared by every RTC
        (``cache_topology = "shared"``), or one per RTC (``"private"``)."""
        return 1 if self.cache_topology == "shared" else self.rtcs

    def hardware_dict(self) -> dict:
        """:meth:`to_dict` without :data:`HOST_FIELDS`: what the elaborated hardware depends on
        (a Verilator binary's cache key; one binary serves every value of the others).
        ``reflect_depth`` enters only as :attr:`secondary_rays` (the RTL reads it through that
        property alone; the depth itself is a register loaded per frame), so a chip with light
        registers is one binary for every reflection depth (but with :attr:`refraction`, whose
        fewest pending buffers grow with the depth, and without it the fewest buffers,
        :attr:`min_rgs_buffers`, which grow with a deep enough depth)."""
        d = {k: v for k, v in self.to_dict().items() if k not in HOST_FIELDS}
        if not self.refraction:
            del d["reflect_depth"]
            d["min_rgs_buffers"] = self.min_rgs_buffers
        d["secondary_rays"] = self.secondary_rays
        return d



def field_help() -> dict[str, str]:
    """Each :class:`Config` field's comment in this file, for command-line help: its trailing
    comment with the indented comment lines under it, or else the comment block above it (a
    block serves every field after it up to the next commented one). Fields without one are
    left out."""
    import inspect
    import re
    out: dict[str, str] = {}
    block: list[str] = []
    fresh = True                                  # the next block comment starts a new block
    last = None                                   # the field whose trailing comment continues
    try:
        source = inspect.getsource(Config)
    except (OSError, TypeError):                  # no source at hand: no comments to show
        return {}
    for line in source.splitlines():
        text, indent = line.strip(), len(line) - len(line.lstrip())
        if text.startswith("#"):
            words = text.lstrip("#").strip()
            if indent > 4 and last is not None:
                out[last] += " " + words          # a trailing comment's next line
            elif not words.startswith("---"):
                block = [words] if fresh else block + [words]
                fresh, last = False, None
            continue
        last = None
        m = re.match(r"(\w+)\s*:[^=#]+=[^#]*(?:#\s*(.*))?$", text)
        if not text or not m:
            block, fresh = [], True
            continue
        name, trailing = m.group(1), m.group(2)
        fresh = True
        if trailing:
            out[name], last, block = trailing.strip(), name, []
        elif block:
            out[name] = " ".join(block)
    return {k: v for k, v in out.items() if k in Config.__dataclass_fields__}

# Fields the RTL never reads: how the host builds the kd-tree, whether a frame asks for shadow
# rays (the slaves' n_lights register, loaded per frame) and the clock the figures are quoted
# at. (reflect_depth is loaded per frame too, but reflect_depth = 0 with rgs_lights = 0 builds
# the eye-ray-only slave: hardware_dict keeps it as secondary_rays.)
HOST_FIELDS = ("kd_leaf_size", "kd_bins", "kd_cost_trav", "kd_cost_int", "shadows",
               "clock_mhz")


COORD_BITS = 16        # sample coordinates (and image sizes in samples) below 2**16


def scene_needs(scene, image, cfg: Config) -> dict:
    """What rendering ``scene`` (``image``: its memory image) with ``cfg`` uses of the chip:
    ``stack_depth`` (the kd-tree's depth), ``lights`` (shadow-casting lights: 0 without
    ``cfg.shadows``), ``reflect_depth`` (``cfg.reflect_depth``, 0 if no triangle's material
    reflects or transmits), ``tex_cache_kb`` (``cfg.tex_cache_kb``, 0 if no triangle's
    material has a texture), ``refracts`` (a triangle's material transmits, at a
    ``cfg.reflect_depth`` above 0), ``refraction`` (``cfg.refraction`` and ``refracts``),
    ``addr_bits`` (memory word address bits the image's words need)."""
    import numpy as np
    reflect = np.array([m.reflect + m.transmit for m in scene.materials], np.float64)
    reflective = bool(len(scene.material) and (reflect[scene.material] > 0).any())
    transmit = np.array([m.transmit for m in scene.materials], np.float64)
    refracts = bool(len(scene.material) and (transmit[scene.material] > 0).any()
                    and cfg.reflect_depth > 0)
    tex = np.array([m.texture is not None for m in scene.materials], bool)
    textured = bool(len(scene.material) and tex[scene.material].any())
    return {"stack_depth": int(image.depth),
            "lights": len(scene.lights) if cfg.shadows else 0,
            "reflect_depth": cfg.reflect_depth if reflective else 0,
            "tex_cache_kb": cfg.tex_cache_kb if textured else 0,
            "refracts": refracts, "refraction": cfg.refraction and refracts,
            "addr_bits": max(1, (len(image.data) - 1).bit_length())}


DEFAULT = Config()

PRESETS: dict[str, dict] = {
    # Config's defaults: the standard chip (4 RTCs of 16 threads and 4 traversal sub-units, the
    # shared 64 / 64 / 144 KB caches, 4 SDRAM chips), every RGS datapath with a unit per operation
    "standard": {},
    # the standard chip at the paper's cost (Section 5: 192 FP units): the paper's triangle
    # test (projection on precomputed records), every RGS slave datapath on one pool of 3
    # adders and 4 multipliers, the slaves' ray stores and pending buffers a memory per
    # packet (their bits once), the traversal stack one value and a bit a lane and level
    "paper": {"int_test": "projection", "rgs_fp_adders": 3, "rgs_fp_muls": 4,
              "rgs_fp_pool": True, "rgs_store": "per_packet", "trav_stack": "one_value"},
}
"""Named configurations (``--preset``): the fields each changes from :class:`Config`'s
defaults."""


def preset(name: str, **changes) -> Config:
    """The :data:`PRESETS` configuration ``name``, with ``changes`` on top."""
    if name not in PRESETS:
        raise ConfigError(f"preset {name!r}: choose one of {', '.join(PRESETS)}")
    return Config(**{**PRESETS[name], **changes})
