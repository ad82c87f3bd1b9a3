"""RGS slave RTL (``rtl/rgs/``): ``EyeRays`` and ``RaySetup`` bit for bit against the golden
model (``model.raygen.eye_rays`` + ``setup``, i.e. ``model/rgs/``), with random request
bubbles and output back-pressure; exact latency and one-ray-per-cycle throughput; the sample
conversion over its whole range; the pixel index's constant division; the secondary-ray
datapaths (``SecondaryPipe``, ``LightPipe``) against ``model.rgs.secondary_rays`` /
``shadow_rays`` / ``light_colours`` / ``hit_colours`` at their exact cycles."""
from __future__ import annotations

import numpy as np
import pytest
from amaranth.sim import Simulator

from model.config import Config
from model.fp import FPFormat
from model.raygen import eye_rays
from rtl.rgs import (COORD_BITS, EyeRays, LightPipe, RaySetup, RaySetupPipe, SecondaryPipe,
                     div_const_params, sample_converter)
from tb.units.rgs import (AXIS_BOX, axis_camera, edge_rays, oblique_camera, run_eye_rays,
                    run_ray_setup, run_secondary, run_shadow, secondary_cases, tile_grid)

B32 = FPFormat(8, 23)
OBLIQUE_BOX = np.array([[-1.5, -1.0, -2.0], [1.0, 2.0, 0.5]])


def check(r):
    assert r.mismatches == [], r.describe()
    assert len(r.out_cycles) == r.rays


# ----------------------------------------------------------------------------------------------
# EyeRays
# ----------------------------------------------------------------------------------------------

@pytest.mark.parametrize("fmt", [B32, FPFormat(6, 10)], ids=str)
def test_eye_rays_axis_camera(fmt):
    """15 x 12 pixels in 8 x 8 tiles (partial tiles right and bottom), every tile requested in
    a shuffled order with arbitrary packet ids; the camera looks down -z, so the middle column
    has d.x = 0 (inv.x = inf) on the box's lo.x face plane (the flat rule), and the z sums add
    ±0 products. Random request bubbles and output back-pressure."""
    cfg = Config(fmt=fmt)
    cam, bounds = axis_camera(), fmt.quantize(AXIS_BOX)
    rays = eye_rays(cam, 15, 12, cfg)
    assert (rays.dir[:, 0] == 0).sum() == 12 and sorted(np.diff(rays.pk_start)) == [28, 32, 56, 64]
    rng = np.random.default_rng(1)
    tiles = list(rng.permutation(4))
    r = run_eye_rays(cam, 15, 12, cfg, bounds, tiles=tiles, packet_ids=[7, 0xFFFFFFFF, 3, 42],
                     idle=0.3, stall=0.3, seed=2)
    check(r)
    assert r.rays == 180


@pytest.mark.parametrize("fmt,n,res,tile,tiles", [
    (FPFormat(8, 14), 2, (15, 11), (8, 8), [0, 3, 11, 7]),     # 30 x 22 samples; 4 x 3 tiles
    (FPFormat(8, 16), 3, (5, 4), (4, 4), None),                # 15 x 12: pixel = s // 3
    (B32, 1, (16, 12), (8, 8), [1, 2]),
], ids=["E8M14-n2", "E8M16-n3", "E8M23-n1"])
def test_eye_rays_oversampling(fmt, n, res, tile, tiles):
    """Oversampled frames (n x n samples per pixel; the pixel index divides by n), the oblique
    camera, a small format."""
    cfg = Config(fmt=fmt, oversampling=n, tile_w=tile[0], tile_h=tile[1], trav_subunits=1)
    r = run_eye_rays(oblique_camera(), *res, cfg, fmt.quantize(OBLIQUE_BOX), tiles=tiles,
                     idle=0.2, stall=0.4, seed=5)
    check(r)


def test_eye_rays_latency_and_throughput():
    """Without bubbles or back-pressure: the first ray leaves ``latency`` cycles after the first
    request (27 for binary32 with the default FP latencies) and then one ray per cycle,
    packets back to back, partial tiles included."""
    cfg = Config()
    r = run_eye_rays(oblique_camera(), 15, 12, cfg, OBLIQUE_BOX)
    check(r)
    assert r.latency == 27
    assert r.out_cycles[0] == r.in_cycles[0] + r.latency
    assert r.out_cycles == list(range(r.out_cycles[0], r.out_cycles[0] + r.rays))


def test_eye_rays_latency_follows_fp_latencies():
    cfg = Config(fp_add_latency=2, fp_mul_latency=1, fp_div_latency=5)
    dut = EyeRays(cfg)
    for unit in (dut, dut.gen, dut.setup):
        unit._MustUse__silence = True
    # 1 + (conv 2 + mul 1 + 2 adds) + (div 5 + mul 1 + 4 min/max)
    assert (dut.gen.latency, dut.setup.latency, dut.latency) == (7, 10, 18)
    r = run_eye_rays(oblique_camera(), 9, 8, cfg.replace(tile_w=4, tile_h=4, trav_subunits=1),
                     OBLIQUE_BOX)
    check(r)
    assert r.out_cycles[0] == r.in_cycles[0] + r.latency


# ----------------------------------------------------------------------------------------------
# RaySetup
# ----------------------------------------------------------------------------------------------

@pytest.mark.parametrize("fmt", [B32, FPFormat(8, 14), FPFormat(6, 10)], ids=str)
def test_ray_setup_edge_and_random_rays(fmt):
    """Zero and signed-zero components, |d| ties, negative dominant axes, origins on every face
    plane (in-plane and leaving), infinite, tiny and huge components, finite tmax, any-hit."""
    cfg = Config(fmt=fmt, tile_w=4, tile_h=4, trav_subunits=1)
    bounds = fmt.quantize(OBLIQUE_BOX)
    r = run_ray_setup(edge_rays(fmt, bounds, n_random=60, seed=4), bounds, cfg, idle=0.25,
                      stall=0.35, seed=9)
    check(r)


def test_ray_setup_exact_latency():
    """Every ray leaves exactly ``latency`` cycles after it entered (no back-pressure; input
    bubbles), one per cycle when they come one per cycle; 15 cycles for binary32."""
    cfg = Config(tile_w=4, tile_h=4, trav_subunits=1)
    bounds = OBLIQUE_BOX.astype(np.float32)
    rays = edge_rays(B32, bounds, n_random=20, seed=6)
    r = run_ray_setup(rays, bounds, cfg, idle=0.3, seed=3)
    check(r)
    assert r.latency == 15
    assert [o - i for i, o in zip(r.in_cycles, r.out_cycles)] == [r.latency] * r.rays
    r = run_ray_setup(rays, bounds, cfg)
    assert r.out_cycles == [c + r.latency for c in r.in_cycles]
    assert r.in_cycles == list(range(r.in_cycles[0], r.in_cycles[0] + r.rays))


def test_ray_setup_latency_parameters():
    fmt = FPFormat(8, 10)
    for lat, want in (({"add": 1, "mul": 2, "div": 3, "minmax": 0}, 3 + 2 + 0),
                      ({"add": 1, "mul": 0, "div": 3, "minmax": 0}, 1 + 3),  # shear ends last
                      ({"add": 4, "mul": 1, "div": 2, "minmax": 2}, 4 + 1 + 4 * 2)):
        pipe = RaySetupPipe(fmt, latencies=lat)
        pipe._MustUse__silence = True
        assert pipe.latency == want, lat
    cfg = Config(fmt=fmt, tile_w=4, tile_h=4, trav_subunits=1)
    bounds = fmt.quantize(OBLIQUE_BOX)
    r = run_ray_setup(edge_rays(fmt, bounds, n_random=10, seed=2), bounds, cfg, latencies=lat,
                      stall=0.3, seed=1)
    check(r)


# ----------------------------------------------------------------------------------------------
# pieces: the sample conversion, the pixel index's division
# ----------------------------------------------------------------------------------------------

@pytest.mark.parametrize("fmt", [
    FPFormat(5, 10),                   # rounds above s = 2**10, overflows to inf above 65504
    FPFormat(2, 1),                    # 0.5 flushes to zero, 4 and up overflow
    *(pytest.param(f, marks=pytest.mark.slow)
      for f in (B32, FPFormat(8, 14), FPFormat(6, 10), FPFormat(4, 3)))], ids=str)
def test_sample_conversion_whole_range(fmt):
    """The RTL's ``sample`` step (int -> FP of 2*s + 1 with one fraction bit, the converter
    ``EyeRayPipe`` instantiates) equals ``fmt.quantize(s + 0.5)`` for every s < 2**16 (the
    model's side of the identity is checked in every format in
    ``tests/test_rgs_model.py``). ~15 s per format in the Amaranth simulator."""
    dut = sample_converter(fmt, COORD_BITS, latency=0)
    n = 1 << COORD_BITS
    got = np.empty(n, np.int64)

    async def bench(ctx):
        for s in range(n):
            ctx.set(dut.a, 2 * s + 1)
            got[s] = ctx.get(dut.o)

    sim = Simulator(dut)
    sim.add_testbench(bench)
    sim.run()
    want = fmt.to_bits(fmt.quantize(np.arange(n) + 0.5)).astype(np.int64)
    bad = np.flatnonzero(got != want)
    assert bad.size == 0, f"{fmt}: s = {bad[:5]}: RTL {got[bad[:5]]}, model {want[bad[:5]]}"


def test_div_const_exact():
    """The pixel index's ``v // n`` by reciprocal multiplication is exact for every 16-bit v."""
    v = np.arange(1 << COORD_BITS, dtype=np.int64)
    for n in range(1, 17):
        mult, k = div_const_params(n, COORD_BITS)
        assert np.array_equal((v * mult) >> k, v // n), n


def test_tile_grid():
    assert tile_grid(15, 11, Config(oversampling=2)) == (4, 3)


# ----------------------------------------------------------------------------------------------
# secondary rays: SecondaryPipe, LightPipe
# ----------------------------------------------------------------------------------------------

LIGHTS = np.array([[1.0, 2.0, 3.0], [0.3, -0.5, 0.8], [-4.0, 5.0, 1.0]])
POINT = np.array([1, 0, 1])


@pytest.mark.parametrize("fmt,latencies", [
    (B32, None), (FPFormat(8, 12), {"add": 1, "mul": 2, "div": 3, "sqrt": 2}),
    (FPFormat(6, 10), {"add": 5, "mul": 4, "div": 12, "sqrt": 11}),
    (FPFormat(6, 10), {"add": 5, "mul": 4, "div": 12, "sqrt": 11, "delay_ram": 3})], ids=str)
def test_secondary_pipe(fmt, latencies):
    """Every output of every hit (random and edge cases) at its exact cycle, bit for bit with
    ``model.rgs.secondary_rays``, with 20 % input bubbles and 20 % stalls."""
    hits = secondary_cases(fmt, 80, seed=fmt.frac_bits)
    r = run_secondary(hits, fmt, latencies=latencies)
    assert r.mismatches == [], r.mismatches[:5]
    assert r.outputs == len(hits) and r.cycles > len(hits)


def test_secondary_cases_reach_every_branch():
    """The edge cases make each of the datapath's selects go both ways in the model."""
    fmt = B32
    h = secondary_cases(fmt, 200, seed=3)
    p0, g, n, r = h.secondary(fmt)
    flipped = np.all(g == -h.nf, axis=1) & np.any(h.nf != 0, axis=1)
    assert 0 < flipped.sum() < len(h)                          # face: both orientations
    assert np.all(np.sum(g.astype(np.float64) * h.dir, axis=1) <= 0)
    zero_sum = np.all(n == g, axis=1)
    assert zero_sum.any()                                      # normal: the zero-sum rule
    assert np.all(np.sum(n.astype(np.float64) * g, axis=1) >= 0)   # n on g's side
    assert np.any(h.dir == 0) and np.any(np.signbit(h.dir) & (h.dir == 0))


def test_secondary_pipe_latency_formula():
    """Latency = 11 add + 7 mul + sqrt + div (the shading normal's path through the
    reflection), and LightPipe's 4 add + 15 mul + sqrt + div + 2, for two sets of FP
    latencies."""
    for lat in ({"add": 3, "mul": 3, "div": 8, "sqrt": 8}, {"add": 2, "mul": 5, "div": 9, "sqrt": 4}):
        p = SecondaryPipe(B32, latencies=lat)
        assert p.latency == 11 * lat["add"] + 7 * lat["mul"] + lat["sqrt"] + lat["div"]
        s = LightPipe(B32, latencies=lat)
        # the light vector (add), the dot product ld.ld (mul, 2 add), its square root and
        # reciprocal, r.ld * il * ir (2 mul), the clamp (min/max, 1), the power (10 mul),
        # ks * spec (mul), the sum (add), the product with lc * wt (mul), fixed point (1)
        assert s.latency == 4 * lat["add"] + 15 * lat["mul"] + lat["sqrt"] + lat["div"] + 2
    assert SecondaryPipe(B32).latency == 70 and LightPipe(B32).latency == 75


@pytest.mark.parametrize("fmt", [B32, FPFormat(8, 12)], ids=str)
def test_shadow_pipe(fmt):
    """Point and parallel lights: LightPipe's direction, tmax and facing test of every (hit,
    light) pair bit for bit with ``model.rgs.shadow_rays``."""
    hits = secondary_cases(fmt, 50, seed=7)
    r = run_shadow(hits, LIGHTS, POINT, fmt)
    assert r.mismatches == [], r.mismatches[:5]
    assert r.outputs == 3 * len(hits) and r.cycles > 3 * len(hits)


@pytest.mark.parametrize("fmt,latencies", [
    (B32, None), (FPFormat(8, 12), {"add": 1, "mul": 2, "div": 3, "sqrt": 2}),
    (FPFormat(6, 10), {"add": 2, "mul": 1, "div": 5, "sqrt": 4}),
    (FPFormat(6, 10), {"add": 2, "mul": 1, "div": 5, "sqrt": 4, "delay_ram": 2})], ids=str)
def test_light_pipe(fmt, latencies):
    """The shadow ray and every colour output of every (hit, light) pair (random and edge
    cases, point and parallel lights) at its exact cycle, bit for bit with the model
    (``model.rgs.shadow_rays``, ``light_colours``, ``hit_colours``), with 20 % bubbles and
    20 % stalls."""
    from tb.units.rgs import colour_cases, run_light
    c = colour_cases(fmt, 90, seed=fmt.frac_bits)
    r = run_light(c, LIGHTS, POINT, fmt, latencies=latencies)
    assert r.mismatches == [], r.mismatches[:5]
    assert r.outputs == len(c) and r.cycles > len(c)


def test_light_pipe_cases_reach_every_branch():
    """The colour cases make the model saturate and zero contributions, clamp n.l and r.l,
    and use exponents 0 and 1023, so the pipe test covers them."""
    from model.rgs import FIX_MAX
    from tb.units.rgs import colour_cases, light_ports
    fmt = B32
    c = colour_cases(fmt, 90, seed=fmt.frac_bits)
    _, outs = light_ports(c, LIGHTS, POINT, fmt, 8)
    col = np.array([[(v >> (24 * k)) & FIX_MAX for k in range(3)] for v in outs["col"]])
    assert (col == FIX_MAX).any() and (col == 0).all(axis=1).any()
    assert 0 < np.count_nonzero(outs["cast"]) < len(c)
    assert {0, 1023} <= set(c.shin.tolist())


def comb_on_codes(fn, fmt: FPFormat, codes, width: int) -> tuple[list, np.ndarray]:
    """The combinational RTL function ``fn(fmt, x)`` (``width`` bits out) on every encoding in
    ``codes``, in Amaranth's simulator: its outputs and the encodings' values (float32)."""
    from amaranth.hdl import Module, Signal
    from amaranth.sim import Simulator
    m = Module()
    x, y = Signal(fmt.width), Signal(width)
    m.d.comb += y.eq(fn(fmt, x))
    got = []

    async def bench(ctx):
        for code in codes:
            ctx.set(x, int(code))
            got.append(ctx.get(y))
    sim = Simulator(m)
    sim.add_testbench(bench)
    sim.run()
    return got, fmt.from_bits(np.asarray(codes).astype(np.uint64)).astype(np.float32)


def test_to_fixed_rtl_exhaustive_small_format():
    """``rtl.rgs.to_fixed`` against ``model.rgs.to_fixed`` on every encoding of E5M6 and of
    E8M23's values around the fixed-point range's ends."""
    from model.rgs import to_fixed_array
    from rtl.rgs import to_fixed
    for fmt, codes in ((FPFormat(5, 6), np.arange(1 << 12)),
                       (B32, np.concatenate([
                           np.arange(0x3F7FFF00, 0x3F800100), np.arange(0x437FFF00, 0x43800100),
                           np.arange(0x37800000 - 256, 0x37800000 + 256), [0x7F800000,
                                                                           0x7FC00000,
                                                                           0xFF800000]]))):
        got, vals = comb_on_codes(to_fixed, fmt, codes, 24)
        assert got == to_fixed_array(vals, fmt.exp_bits).tolist(), fmt


def test_wrap_coord_rtl_exhaustive_small_format():
    """``rtl.rgs.wrap_coord`` against ``model.rgs.wrap_coord`` on every encoding of E5M6 and
    of binary32 around 0, 1, 2**24 (where the last fraction bit leaves the window) and the
    special values."""
    import numba

    from model.rgs import UV_FRAC, wrap_coord as model_wrap
    from rtl.rgs import wrap_coord

    @numba.njit
    def wraps(x, E):
        out = np.empty(x.shape[0], np.int64)
        for i in range(x.shape[0]):
            out[i] = model_wrap(x[i], E)
        return out
    for fmt, codes in ((FPFormat(5, 6), np.arange(1 << 12)),
                       (B32, np.concatenate([
                           np.arange(0, 0x200), np.arange(0x80000000, 0x80000200),
                           np.arange(0x33000000 - 256, 0x33000000 + 256),    # 2**-25
                           np.arange(0xB3800000 - 256, 0xB3800000 + 256),    # -2**-24
                           np.arange(0x3F7FFF00, 0x3F800100), np.arange(0xBF7FFF00, 0xBF800100),
                           np.arange(0x4B7FFF00, 0x4B800100), np.arange(0xCB7FFF00, 0xCB800100),
                           [0x7F800000, 0x7FC00000, 0xFF800000, 0x7F7FFFFF, 0xFF7FFFFF]]))):
        got, vals = comb_on_codes(wrap_coord, fmt, codes, UV_FRAC)
        want = wraps(vals, fmt.exp_bits)
        assert got == want.tolist(), fmt
        assert (want == 0).any() and (want > 1 << (UV_FRAC - 1)).any()   # zero, negatives
    assert want.tolist().count((1 << UV_FRAC) - 1) > 0                  # -2**-25 etc.


@pytest.mark.parametrize("fmt,seed", [(B32, 4), (FPFormat(5, 6), 5)], ids=str)
def test_texture(fmt, seed):
    """``rtl.rgs.Texture`` on a 256-byte texel cache (misses and evictions) and a memory that
    holds its answers 30 % of the cycles, with input gaps and output back-pressure: every
    hit's kd bit-exact with ``model.rgs.texture_kd``, in order."""
    from tb.units.rgs import run_texture, texture_cases
    cfg = Config(fmt=fmt)
    c = texture_cases(fmt, 120, seed=seed)
    bad, cycles = run_texture(c, cfg, seed=seed)
    assert bad == []
    assert (c.tex < 0).any() and (c.tex >= 0).sum() > 80


# ----------------------------------------------------------------------------------------------
# shared FP units (Config.rgs_fp_adders, rgs_fp_muls)
# ----------------------------------------------------------------------------------------------

SHARED = [(B32, None, {"add": 3, "mul": 4}),
          (FPFormat(6, 10), {"add": 5, "mul": 4, "div": 12, "sqrt": 11}, {"add": 1, "mul": 2}),
          (FPFormat(8, 12), {"add": 1, "mul": 2, "div": 3, "sqrt": 2}, {"mul": 7})]


@pytest.mark.parametrize("fmt,latencies,budget", SHARED, ids=str)
def test_shared_secondary_and_light_pipes(fmt, latencies, budget):
    """With an FP unit budget, SecondaryPipe and LightPipe take a hit every ``ii`` cycles and
    every output of every hit still comes at its exact cycle, bit for bit with the model,
    under 20 % bubbles and 20 % stalls (an input offered outside its slot waits)."""
    from tb.units.rgs import colour_cases, run_light
    hits = secondary_cases(fmt, 30, seed=fmt.frac_bits)
    r = run_secondary(hits, fmt, latencies=latencies, budget=budget)
    assert r.mismatches == [], r.mismatches[:5]
    assert r.outputs == len(hits)
    c = colour_cases(fmt, 30, seed=fmt.frac_bits)
    r = run_light(c, LIGHTS, POINT, fmt, latencies=latencies, budget=budget)
    assert r.mismatches == [], r.mismatches[:5]
    assert r.outputs == len(c)


def test_shared_texture():
    """The texture unit with shared units (both pipes at ``ii`` 2 or more): every hit's kd
    bit-exact, in order, with misses, memory holds, gaps and back-pressure."""
    from tb.units.rgs import run_texture, texture_cases
    from rtl.rgs import Texture
    cfg = Config(rgs_fp_adders=1, rgs_fp_muls=2)
    tex = Texture(cfg)
    tex._MustUse__silence = True
    assert tex.coord.ii > 1 and tex.filter.ii > 1
    c = texture_cases(B32, 60, seed=6)
    bad, cycles = run_texture(c, cfg, seed=6)
    assert bad == []
    assert (c.tex < 0).any() and (c.tex >= 0).sum() > 40


@pytest.mark.parametrize("cls", [SecondaryPipe, LightPipe, RaySetupPipe], ids=lambda c: c.__name__)
def test_shared_units_fit_the_budget(cls):
    """The interval is the least at which the budget's units take every operation
    (ceil(operations / units)); no class has more units than its operations need at that
    interval; sharing lengthens the latency by no more than the waits for a unit (at most
    ii - 1 per operation on the longest path, so well below ii times the operations)."""
    free = cls(B32)
    for budget in ({"add": 3, "mul": 4}, {"add": 1, "mul": 1}, {"mul": 2}):
        p = cls(B32, budget=budget)
        want = max([1] + [-(-free.counts[k] // n) for k, n in budget.items() if free.counts[k]])
        assert p.ii == want, (budget, p.ii)
        for k, n in free.counts.items():
            if n:
                assert p.units[k] == -(-n // p.ii), (budget, k)
                if k in budget:
                    assert p.units[k] <= budget[k]
        assert p.counts == free.counts
        assert free.latency <= p.latency < free.latency + p.ii * sum(free.counts.values())
    assert SecondaryPipe(B32, budget={"add": 3, "mul": 4}).units["mul"] == 4


def test_shared_budget_errors():
    with pytest.raises(ValueError, match="at least one unit"):
        SecondaryPipe(B32, budget={"add": 0})
    with pytest.raises(ValueError, match="latency of at"):
        RaySetupPipe(FPFormat(8, 10), latencies={"add": 1, "mul": 2, "div": 3, "minmax": 0},
                     budget={"add": 1})
    from model.config import ConfigError
    with pytest.raises(ConfigError, match="rgs_fp_adders"):
        Config(rgs_fp_adders=-1)


@pytest.mark.parametrize("adders,muls", [(3, 4), (1, 1)])
def test_shared_eye_rays(adders, muls):
    """Eye rays with shared units: both datapaths at one interval, ray setup's slots offset by
    the eye-ray datapath's latency; every ray bit for bit under bubbles and back-pressure,
    and without them one ray every ``ii`` cycles (the first one after up to ``ii - 1`` cycles
    waiting for a slot)."""
    cfg = Config(rgs_fp_adders=adders, rgs_fp_muls=muls, tile_w=4, tile_h=4, trav_subunits=1)
    dut = EyeRays(cfg)
    for unit in (dut, dut.gen, dut.setup):
        unit._MustUse__silence = True
    ii = dut.gen.ii
    assert ii == dut.setup.ii > 1
    r = run_eye_rays(oblique_camera(), 9, 7, cfg, OBLIQUE_BOX, idle=0.3, stall=0.3, seed=4)
    check(r)
    r = run_eye_rays(oblique_camera(), 9, 7, cfg, OBLIQUE_BOX)
    check(r)
    assert r.latency <= r.out_cycles[0] - r.in_cycles[0] < r.latency + ii   # waits for a slot
    assert np.all(np.diff(r.out_cycles) == ii)


def test_shared_ray_setup():
    """RaySetup with shared units: every ray bit for bit under bubbles and stalls; without
    them one ray every ``ii`` cycles, each ``latency`` cycles after it entered."""
    fmt = FPFormat(8, 14)
    cfg = Config(fmt=fmt, rgs_fp_adders=1, rgs_fp_muls=2, tile_w=4, tile_h=4, trav_subunits=1)
    bounds = fmt.quantize(OBLIQUE_BOX)
    rays = edge_rays(fmt, bounds, n_random=30, seed=8)
    r = run_ray_setup(rays, bounds, cfg, idle=0.25, stall=0.35, seed=2)
    check(r)
    r = run_ray_setup(rays, bounds, cfg)
    check(r)
    ii = RaySetup(cfg).pipe.ii
    assert ii > 1
    assert np.all(np.diff(r.in_cycles) == ii)
    assert r.out_cycles == [c + r.latency for c in r.in_cycles]


# ----------------------------------------------------------------------------------------------
# one pool for the shading (ShadePool)
# ----------------------------------------------------------------------------------------------

@pytest.mark.parametrize("fmt,latencies,budget,copies", [
    (B32, None, {"add": 3, "mul": 4}, 3),
    (FPFormat(6, 10), {"add": 2, "mul": 1, "div": 5, "sqrt": 4}, {"add": 1, "mul": 2}, 1),
    (FPFormat(8, 12), {"add": 1, "mul": 2, "div": 3, "sqrt": 2, "delay_ram": 2},
     {"add": 3, "mul": 4}, 4)], ids=str)
def test_shade_pool(fmt, latencies, budget, copies):
    """SecondaryPipe and ``copies`` LightPipe graphs on one pool of units: hits and (hit,
    light) tokens offered together with 20 % bubbles, each taken in its datapath's slots, every
    output at its exact cycle bit for bit with the model."""
    from tb.units.rgs import colour_cases, run_pool
    hits = secondary_cases(fmt, 16, seed=fmt.frac_bits)
    c = colour_cases(fmt, 30, seed=fmt.frac_bits)
    pool, cycles, bad = run_pool(hits, c, LIGHTS, POINT, fmt, budget=budget, copies=copies,
                                 latencies=latencies, seed=copies)
    assert bad == [], bad[:5]
    assert len(set(pool.t0)) == copies and cycles > len(c) * pool.ii // copies


def test_shade_pool_units_fit_the_budget():
    """The pool's interval is the least at which the budget takes SecondaryPipe's operations
    and ``copies`` times LightPipe's; no class has more units than that needs; each datapath
    reports the interval, its inputs per interval and its in-flight bound."""
    from rtl.rgs import ShadePool
    sec, shd = SecondaryPipe(B32), LightPipe(B32)
    for budget, copies in (({"add": 3, "mul": 4}, 3), ({"add": 1, "mul": 1}, 1),
                           ({"mul": 4}, 4)):
        p = ShadePool(B32, 4, 4, None, budget, copies)
        counts = {k: sec.counts[k] + copies * shd.counts[k] for k in sec.counts}
        want = max([copies, 2] + [-(-counts[k] // n) for k, n in budget.items()])
        assert p.ii == want, (budget, copies)
        for k, n in counts.items():
            if n:
                assert p.units[k] == -(-n // p.ii)
                assert k not in budget or p.units[k] <= budget[k]
        assert p.shd.per_ii == copies and p.shd.in_flight == (p.shd.latency // p.ii + 1) * copies
        assert p.sec.latency >= sec.latency and p.shd.latency >= shd.latency
    with pytest.raises(ValueError, match="copies"):
        ShadePool(B32, 4, 4, None, {"add": 3}, 0)
    with pytest.raises(ValueError, match="budget"):
        ShadePool(B32, 4, 4, None, {}, 2)
    from model.config import ConfigError
    with pytest.raises(ConfigError, match="rgs_fp_pool"):
        Config(rgs_fp_pool=True)                      # a pool needs a budget of units


def test_slave_pool_units_fit_the_budget():
    """Every ray datapath of the slave on one pool (``rtl.rgs.SlavePool``, what
    ``Config.rgs_fp_pool`` builds): the interval is the least at which the budget takes
    SecondaryPipe's operations, a LightPipe entry per light, the eye-ray chain (EyeRayPipe
    then RaySetupPipe), a ray-setup entry per light and one for the reflection, and the
    texture unit's two pipes; every datapath runs at that interval, and no class has more
    units than the interval needs."""
    from rtl.rgs import EyeRayPipe, RaySetupPipe, Slave, TexCoordPipe, TexFilterPipe
    for lights, budget in ((1, {"add": 3, "mul": 4}), (3, {"add": 3, "mul": 4}),
                           (2, {"add": 1, "mul": 2})):
        cfg = Config(rgs_lights=lights, reflect_depth=1, rgs_fp_adders=budget["add"],
                     rgs_fp_muls=budget["mul"], rgs_fp_pool=True)
        s = Slave(cfg)
        s._MustUse__silence = True
        p = s.pool
        parts = [(SecondaryPipe(B32), 1), (LightPipe(B32), lights), (EyeRayPipe(B32), 1),
                 (RaySetupPipe(B32), 1), (RaySetupPipe(B32), lights + 1),
                 (TexCoordPipe(B32), 1), (TexFilterPipe(B32), 1)]
        assert cfg.tex_cache_kb > 0
        counts = {k: sum(n * d.counts[k] for d, n in parts) for k in parts[0][0].counts}
        for d, _ in parts:
            d._MustUse__silence = True
        want = max([lights, 2] + [-(-counts[k] // n) for k, n in budget.items()])
        assert p.ii == want, (lights, budget)
        for k, n in counts.items():
            if n:
                assert p.units[k] == -(-n // p.ii), k
                assert k not in budget or p.units[k] <= budget[k]
        pipes = (s.sec, s.shd, s.eye.gen, s.eye.setup, s.setup.pipe, s.tex.coord, s.tex.filter)
        assert {d.ii for d in pipes} == {p.ii}
        assert [d.per_ii for d in pipes] == [1, lights, 1, 1, lights + 1, 1, 1]
        assert s.setup.pipe.in_flight == (s.setup.pipe.latency // p.ii + 1) * (lights + 1)
        assert s.eye.in_flight == (s.eye.gen.latency + s.eye.setup.latency) // p.ii + 1
