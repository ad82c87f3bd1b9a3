"""The FP units of rtl/fp against the golden model, in Amaranth simulation (tb/units/fp.py).

Every test checks every output on the exact cycle it must appear (o_valid on every cycle).
CI runs reduced vector counts; ``-m slow`` (``make bench``) runs the large ones.
"""
from __future__ import annotations

import zlib

import numpy as np
import pytest
from amaranth.sim import Simulator
from hypothesis import given, settings, strategies as st

from model.fp import BINARY32, FPFormat
from rtl.fp import FPAdd, FPDiv, FPFromInt, FPMinMax, FPMul, FPSqrt, placement
from tb.units.fp import make_unit, pair_inputs, run_exhaustive, run_random, simulate

E4M3 = FPFormat(4, 3)
E8M16, E8M10 = FPFormat(8, 16), FPFormat(8, 10)


def full_regs(kind, fmt):
    """A register at every boundary but the input: the fastest to simulate."""
    n = len(make_unit(kind, fmt).BOUNDARIES)
    return (0,) + (1,) * (n - 1)


# -------------------------------------------------------------------------------------------
# exhaustive tiny formats: every operand pair
# -------------------------------------------------------------------------------------------

@pytest.mark.parametrize("kind", ["add", "mul", "div", "sqrt"])
def test_exhaustive_e4m3(kind):
    """Every boundary registered, round and pack cut in two; the multiplier's significands
    (4 bits) split in 2-bit halves so its partial-product boundary is used too."""
    kw = {"dsp_bits": 2} if kind == "mul" else {}
    r = run_exhaustive(kind, E4M3, latency=None, regs=full_regs(kind, E4M3), **kw)
    assert r.ops == 1 << (8 if kind == "sqrt" else 16)


@pytest.mark.parametrize("em,latency", [
    ((5, 10), None),
    pytest.param((6, 9), 3, marks=pytest.mark.slow), pytest.param((3, 12), 0, marks=pytest.mark.slow)])
def test_sqrt_exhaustive_16bit(em, latency):
    """Every encoding of 16-bit formats (even and odd M: the radicand's pairing differs)."""
    assert run_exhaustive("sqrt", FPFormat(*em), latency=latency).ops == 1 << 16


@pytest.mark.slow
@pytest.mark.parametrize("kind,latency", [("add", 6), ("mul", 4), ("mul", 5), ("div", 9)])
def test_exhaustive_e4m3_round_cut(kind, latency):
    """The smallest latencies whose default placement cuts round and pack (and, mul 5, the
    partial products), exhaustively: only the new boundaries plus the defaults' registers."""
    kw = {"dsp_bits": 3} if kind == "mul" else {}
    dut = make_unit(kind, E4M3, latency, **kw)
    assert dut.regs[dut.BOUNDARIES.index("round")] == 1
    assert run_exhaustive(kind, E4M3, latency=latency, **kw).ops == 1 << 16


@pytest.mark.parametrize("kind", ["add", "sub", "mul", "div", "sqrt", "min", "max", "cmp"])
def test_exhaustive_e2m1(kind):
    """E2M1 (4-bit words): all 256 pairs, combinational and pipelined."""
    for latency in (0, 2):
        assert run_exhaustive(kind, FPFormat(2, 1), latency=latency).ops == (
            16 if kind == "sqrt" else 256)


@pytest.mark.slow
@pytest.mark.parametrize("fmt", [E4M3, FPFormat(5, 2), FPFormat(3, 4)], ids=str)
@pytest.mark.parametrize("kind", ["add", "sub", "mul", "div", "min", "max", "cmp"])
def test_exhaustive_8bit_formats(fmt, kind):
    assert run_exhaustive(kind, fmt, latency=None, regs=full_regs(kind, fmt)).ops == 1 << 16


# -------------------------------------------------------------------------------------------
# corner cases and random operands, bubbles and stalls, several latencies and formats
# -------------------------------------------------------------------------------------------

CI_CASES = [
    # (kind, fmt, latency): default latencies at binary32, and the extremes elsewhere
    *[(k, BINARY32, None) for k in ("add", "mul", "div", "cmp", "min", "conv")],
    ("add", E8M10, 0), ("add", E8M16, 5), ("sub", E4M3, 1),
    ("mul", E8M16, 1), ("mul", E8M10, 0), ("div", E8M10, 2), ("div", E4M3, 0),
    ("max", E8M16, 0), ("cmp", E4M3, 2), ("conv", E8M10, 0),
    ("min", BINARY32, 3), ("max", E4M3, 3), ("cmp", BINARY32, 3),   # min/max: compare cut
    ("add", BINARY32, 8), ("sub", E8M10, 8),                         # add: normalize cut
    ("sqrt", BINARY32, None), ("sqrt", E8M16, 3), ("sqrt", E8M10, 0), ("sqrt", BINARY32, 12),
]


@pytest.mark.parametrize("kind,fmt,latency", CI_CASES,
                         ids=[f"{k}-{f}-L{lat}" for k, f, lat in CI_CASES])
def test_random_with_stalls(kind, fmt, latency):
    r = run_random(kind, fmt, 150, latency=latency, seed=zlib.crc32(f"{kind}{fmt}".encode()))
    assert r.ops > 150 and r.cycles > r.ops        # bubbles and stalls really happened


@pytest.mark.slow
@pytest.mark.parametrize("fmt", [BINARY32, E8M16, E8M10, E4M3], ids=str)
@pytest.mark.parametrize("kind", ["add", "sub", "mul", "div", "sqrt", "cmp", "min", "max",
                                  "conv"])
def test_random_with_stalls_long(kind, fmt):
    for latency in (0, 1, None, 7):
        run_random(kind, fmt, 3000, latency=latency, seed=latency or 0)


@pytest.mark.parametrize("kind,regs", [
    ("add", (1, 0, 2, 0, 0, 0, 0, 1)), ("mul", (2, 0, 0, 1, 0, 0, 0)),
    ("div", (0, 1) + (0,) * 12 + (1,) + (0,) * 13 + (0, 2)),
    # round and pack cut; binary32 products from four registered 18-bit partial products
    ("add", (0, 0, 0, 0, 0, 0, 2, 1)), ("add", (0, 0, 0, 1, 2, 0, 0, 1)),
    ("mul", (0, 0, 1, 0, 0, 1, 1)), ("mul", (0, 1, 1, 1, 1, 1, 1)),
    ("div", (0, 1) + (0, 1) * 13 + (1, 0)), ("div", (0, 0) + (1,) * 26 + (1, 1))])
def test_custom_register_placement(kind, regs):
    """Registers may sit anywhere, several at one boundary; latency is their count."""
    r = run_random(kind, BINARY32, 100, regs=regs, seed=3)
    assert make_unit(kind, BINARY32, regs=regs).latency == sum(regs)
    assert r.ops > 100


FAST_CASES = [("add", 6), ("add", 7), ("mul", 4), ("mul", 5), ("mul", 6), ("div", 9),
              ("div", 16)]


@pytest.mark.parametrize("kind,latency", FAST_CASES, ids=[f"{k}-L{n}" for k, n in FAST_CASES])
def test_round_cut_latencies_binary32(kind, latency):
    """The latencies that use the round (and, mul >= 5, partial-product) boundaries, binary32
    corner cases and random operands with bubbles and stalls."""
    assert run_random(kind, BINARY32, 120, latency=latency, seed=latency).ops > 120


def test_default_placements_unchanged():
    """The register placements of the latencies 1-5 (add), 1-3 (mul) and up to the default 8
    (div) are the ones from before the round and partial-product boundaries existed (written
    here as boundary names), so the RTC's cycle timing does not move."""
    def named(unit):
        return [b for b, n in zip(unit.BOUNDARIES, unit.regs) for _ in range(n)]
    assert named(FPAdd(latency=3)) == ["align", "normalize", "output"]
    assert named(FPAdd(latency=5)) == ["unpack", "align", "add", "normalize", "output"]
    assert named(FPMul(latency=3)) == ["unpack", "multiply", "output"]
    assert named(FPMul(latency=2)) == ["multiply", "output"]
    assert named(FPDiv(latency=8)) == ["q2", "q5", "q8", "q12", "q16", "q19", "q22", "output"]
    assert named(FPDiv(latency=4)) == ["q5", "q12", "q19", "output"]
    # above those, round and pack is cut first (mul: before the partial products)
    assert named(FPAdd(latency=6)) == ["unpack", "align", "add", "normalize", "round", "output"]
    assert named(FPMul(latency=4)) == ["unpack", "multiply", "round", "output"]
    assert named(FPMul(latency=5)) == ["unpack", "partial", "multiply", "round", "output"]
    assert "round" in named(FPDiv(latency=9)) and named(FPDiv(latency=9))[-1] == "output"


def test_reciprocal():
    """1/x through the divider (the intersection unit's 1/det): exact-rounded, with 1/±0 = ±inf
    and 1/x flushed for huge x."""
    rng = np.random.default_rng(9)
    b = np.concatenate([rng.standard_normal(200) * 10.0 ** rng.integers(-38, 38, 200),
                        [0.0, -0.0, np.inf, -np.inf, 3.0, 2.0 ** 127, 2.0 ** -126]]).astype(np.float32)
    b = BINARY32.flush(b)
    a = np.ones_like(b)
    ins, exp = pair_inputs("div", BINARY32, a, b, rng)
    simulate(FPDiv(BINARY32), ins, exp, p_bubble=0.2, p_stall=0.2)
    assert exp[-7] == 0x7F800000 and exp[-6] == 0xFF800000 and exp[-2] == 0


# -------------------------------------------------------------------------------------------
# hypothesis: binary32 operand batches through the pipelined units
# -------------------------------------------------------------------------------------------

words = st.integers(0, 0xFFFFFFFF)


@pytest.mark.parametrize("kind", ["add", "mul", "div"])
@settings(max_examples=4, deadline=None)
@given(pairs=st.lists(st.tuples(words, words), min_size=1, max_size=40))
def test_hypothesis_binary32(kind, pairs):
    check_words(kind, pairs)


def check_words(kind, pairs):
    a = np.array([p[0] for p in pairs], dtype=np.uint32)
    b = np.array([p[1] for p in pairs], dtype=np.uint32)
    af, bf = BINARY32.from_bits(a), BINARY32.from_bits(b)
    ins, exp = pair_inputs(kind, BINARY32, af, bf, np.random.default_rng(0))
    ins["a"], ins["b"] = a, b                       # raw words: denormals and NaN payloads too
    simulate(make_unit(kind, BINARY32), ins, exp, p_bubble=0.2, p_stall=0.2)


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["add", "sub", "mul", "div", "min", "cmp"])
@settings(max_examples=60, deadline=None)
@given(pairs=st.lists(st.tuples(words, words), min_size=1, max_size=100))
def test_hypothesis_binary32_long(kind, pairs):
    check_words(kind, pairs)


# -------------------------------------------------------------------------------------------
# interface: latency, stalls, no combinational path, conversion, parameter errors
# -------------------------------------------------------------------------------------------

@pytest.mark.parametrize("cls", [FPAdd, FPMul, FPDiv, FPSqrt, FPMinMax])
def test_no_combinational_path_and_stall_holds(cls):
    """With latency >= 1 changing the inputs never changes the outputs in the same cycle, and
    with en = 0 the outputs hold over clock edges."""
    dut = cls(BINARY32, latency=2)
    seen = []

    async def bench(ctx):
        ctx.set(dut.a, 0x3F800000)
        if hasattr(dut, "b"):
            ctx.set(dut.b, 0x40000000)
        ctx.set(dut.i_valid, 1)
        for _ in range(3):
            await ctx.tick()
        before = (ctx.get(dut.o), ctx.get(dut.o_valid))
        ctx.set(dut.a, 0xC0400000)
        if hasattr(dut, "b"):
            ctx.set(dut.b, 0x7FC00000)
        ctx.set(dut.i_valid, 0)
        seen.append(before == (ctx.get(dut.o), ctx.get(dut.o_valid)))
        ctx.set(dut.en, 0)
        for _ in range(4):
            await ctx.tick()
            seen.append(before == (ctx.get(dut.o), ctx.get(dut.o_valid)))
        ctx.set(dut.en, 1)
        await ctx.tick()
        await ctx.tick()
        seen.append(ctx.get(dut.o_valid) == 0)        # the bubble arrives after 2 enabled cycles
        seen.append(before[1] == 1)

    sim = Simulator(dut)
    sim.add_clock(1e-8)
    sim.add_testbench(bench)
    sim.run()
    assert all(seen) and len(seen) == 7, seen


@pytest.mark.parametrize("width,signed,frac,fmt", [(32, True, 0, BINARY32), (32, True, 1, BINARY32),
                                                   (16, False, 0, E8M10), (12, True, 3, E4M3),
                                                   (8, True, 0, FPFormat(8, 23))])
def test_conversion(width, signed, frac, fmt):
    r = run_random("conv", fmt, 200, int_width=width, signed=signed, frac_bits=frac, seed=width)
    assert r.ops > 200


def test_pixel_centre_conversion_matches_quantize():
    """from_fixed(2*px + 1, 1) is the pixel centre px + 0.5 rounded once (what model/raygen
    computes with quantize), for every 13-bit px, at E8M10 where it rounds."""
    px = np.arange(1 << 13)
    assert np.array_equal(E8M10.to_bits(E8M10.from_fixed(2 * px + 1, 1)),
                          E8M10.to_bits(E8M10.quantize(px + 0.5)))


@pytest.mark.filterwarnings("ignore:.*created but never used")
def test_placement_and_errors():
    assert placement(0, 6, (5, 2)) == (0,) * 6
    assert placement(3, 6, (5, 2, 4)) == (0, 0, 1, 0, 1, 1)
    assert placement(4, 3) == (0, 1, 3)        # more registers than boundaries: extras at output
    assert sum(placement(7, 28)) == 7 and placement(7, 28)[-1] == 1
    assert FPDiv(BINARY32).latency == 8 and FPMul().latency == 3 and FPAdd().latency == 3
    assert FPSqrt(BINARY32).latency == 8 and FPSqrt(FPFormat(5, 10)).latency == 4
    with pytest.raises(ValueError, match="latency"):
        FPMul(BINARY32, latency=-1)
    with pytest.raises(ValueError, match="boundaries"):
        FPAdd(BINARY32, regs=(1, 1))
    with pytest.raises(ValueError, match="boundaries"):
        FPMul(BINARY32, regs=(0, 1, 1, 0, 1))         # the 5-boundary layout of before
    with pytest.raises(ValueError, match="dsp_bits"):
        FPMul(BINARY32, dsp_bits=0)
    with pytest.raises(ValueError, match="int_width"):
        FPFromInt(BINARY32, int_width=1)
    with pytest.raises(TypeError, match="integers"):
        BINARY32.from_fixed(np.array([0.5]))


def test_gt_const_every_value():
    """``gt_const`` (the adder's shift saturation) is ``x > c`` for every x of 1-5 bits and
    every constant from below 0 to above the range."""
    from amaranth.hdl import Module, Signal
    from rtl.fp.common import gt_const
    m = Module()
    cases = []
    for w in range(1, 6):
        x = Signal(w, name=f"x{w}")
        for c in range(-1, (1 << w) + 2):
            o = Signal(name=f"gt{w}_{c + 1}")
            m.d.comb += o.eq(gt_const(x, c))
            cases.append((w, x, c, o))
    wrong = []

    async def bench(ctx):
        for v in range(32):
            for w, x, c, o in cases:
                ctx.set(x, v % (1 << w))
            for w, x, c, o in cases:
                if ctx.get(o) != int(v % (1 << w) > c):
                    wrong.append((w, v % (1 << w), c))
    sim = Simulator(m)
    sim.add_testbench(bench)
    sim.run()
    assert not wrong, wrong[:5]


@pytest.mark.slow
def test_synthesis_no_latches(tmp_path):
    """Each unit (small format) through Yosys synth and synth_ecp5 with the latch assertion;
    the multiplier maps to a DSP block."""
    from saarcor.flows.synth import UNITS, synth_unit
    for name in UNITS:
        r = synth_unit(name, E8M10, tmp_path)
        assert r["generic_ff"] > 0 and r["ecp5"].get("LUT4", 0) > 0, r
        if name == "mul":
            assert r["ecp5"].get("MULT18X18D", 0) >= 1, r


# -------------------------------------------------------------------------------------------
# the multiplier's partial products in the DSP blocks' own registers (rtl/fp/dsp.py)
# -------------------------------------------------------------------------------------------

def test_regmul_latency_two_and_enable_holds():
    """``RegMul`` outside the ECP5: the product of the operands of two enabled cycles before;
    ``en`` = 0 holds both registers."""
    from rtl.fp.dsp import RegMul
    dut = RegMul(18, 6)
    rng = np.random.default_rng(3)
    steps = [(int(rng.integers(1 << 18)), int(rng.integers(1 << 6)), int(rng.random() < 0.7))
             for _ in range(300)]
    got = []

    async def tb(ctx):
        for a, b, en in steps:
            ctx.set(dut.a, a)
            ctx.set(dut.b, b)
            ctx.set(dut.en, en)
            await ctx.tick()
            got.append(ctx.get(dut.p))

    sim = Simulator(dut)
    sim.add_clock(1e-6)
    sim.add_testbench(tb)
    sim.run()
    # reference: operand register, then product register, each loading when en
    a_q = b_q = p_q = 0
    want = []
    for a, b, en in steps:
        if en:
            a_q, b_q, p_q = a, b, a_q * b_q
        want.append(p_q)
    assert got[2:] == want[2:]


def test_mul_partial_products_use_the_dsp_registers_on_ecp5():
    """At a latency with registers after unpack and after the partial products (5, ``make
    fpga``'s), an ECP5 build makes each partial product a MULT18X18D with its input and output
    registers on, in place of the fabric's operand and product registers; other builds keep
    the registers in logic."""
    from amaranth.back import verilog
    from rtl.fp.dsp import ECP5
    dut = FPMul(latency=5)
    assert dut.regs[1] == dut.regs[2] == 1
    text = verilog.convert(dut, name="m", platform=ECP5)
    assert text.count("MULT18X18D ") == 4
    for reg in ("REG_INPUTA_CLK", "REG_INPUTB_CLK", "REG_OUTPUT_CLK"):
        assert text.count(f'.{reg}("CLK0")') == 4, reg
    assert text.count('.REG_PIPELINE_CLK("NONE")') == 4
    assert "p1_0_sa" not in text and "p2_0_ll" not in text
    plain = verilog.convert(FPMul(latency=5), name="m")
    assert "MULT18X18D" not in plain
    # latency 3 has no register after the partial products: the product stays one `*`
    assert "MULT18X18D" not in verilog.convert(FPMul(latency=3), name="m", platform=ECP5)


@pytest.mark.parametrize("latency", [0, 2])
def test_minmax_compare_outputs_are_the_model_order(latency):
    """``FPMinMax.lt``/``gt`` (the traversal's compares, from the comparator its min/max uses):
    ``a < b`` and ``a > b`` by the model's order on every pair of raw 6-bit encodings (signed
    zeros, denormals, infinities, NaN payloads), in the cycle of ``o``."""
    from amaranth.sim import Simulator
    fmt = FPFormat(3, 2)
    n = 1 << fmt.width
    A, B = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    A, B = A.ravel(), B.ravel()
    fa, fb = fmt.from_bits(A), fmt.from_bits(B)
    want = list(zip(fmt.lt(fa, fb).astype(int), fmt.lt(fb, fa).astype(int)))
    assert 0 < sum(x for x, _ in want) < len(want)          # both outcomes occur
    dut = FPMinMax(fmt, latency=latency)
    got = []

    async def bench(ctx):
        for i in range(len(A) + latency):
            if i < len(A):
                ctx.set(dut.a, int(A[i]))
                ctx.set(dut.b, int(B[i]))
                ctx.set(dut.i_valid, 1)
            else:
                ctx.set(dut.i_valid, 0)
            if latency == 0 or i >= latency:
                assert ctx.get(dut.o_valid)
                got.append((ctx.get(dut.lt), ctx.get(dut.gt)))
            await (ctx.tick() if latency else ctx.delay(1e-8))

    sim = Simulator(dut)
    if latency:
        sim.add_clock(1e-8)
    sim.add_testbench(bench)
    sim.run()
    assert got == want
