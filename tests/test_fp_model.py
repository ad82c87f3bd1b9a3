"""Tests of the golden model's hardware arithmetic (model/fp.py).

Oracles: an exact ``Fraction`` reference (tests/fp_exact.py, written from the rules, not from
the model) for exhaustive tiny formats and the hard cases of binary32/E8M16/E8M10; numpy
float32 for binary32 in the normal range (hypothesis).
"""
from __future__ import annotations

import numba
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from model.fp import (FPFormat, BINARY32, fadd, fsub, fmul, fdiv, fsqrt, flt, fle, feq, fmin,
                      fmax)
from tb.units.fp_vectors import corner_pairs, special_values
from tests.fp_exact import ExactFormat

OPS = ("add", "sub", "mul", "div")


def all_pairs(fmt: FPFormat):
    n = 1 << fmt.width
    A, B = np.meshgrid(np.arange(n, dtype=np.uint32), np.arange(n, dtype=np.uint32), indexing="ij")
    return A.ravel(), B.ravel()


def check_against_exact(fmt: FPFormat, ops, a_bits, b_bits):
    """Run the model on encodings and compare each op with the exact reference; return a dict
    of mismatch lists (empty when all agree)."""
    ex = ExactFormat(*fmt.em)
    a, b = fmt.from_bits(a_bits), fmt.from_bits(b_bits)
    bad = {}
    for op in ops:
        got = fmt.to_bits(getattr(fmt, op)(a, b))
        ref_op = getattr(ex, op)
        want = np.array([ref_op(int(x), int(y)) for x, y in zip(a_bits, b_bits)], dtype=np.uint32)
        idx = np.flatnonzero(got != want)
        bad[op] = [(hex(a_bits[i]), hex(b_bits[i]), hex(got[i]), hex(want[i])) for i in idx[:10]]
        assert idx.size == 0, f"{fmt} {op}: {idx.size} mismatches (a, b, model, exact): {bad[op]}"


# -------------------------------------------------------------------------------------------
# exhaustive tiny formats
# -------------------------------------------------------------------------------------------

@pytest.mark.parametrize("op", OPS)
def test_e4m3_exhaustive_arith(op):
    fmt = FPFormat(4, 3)
    check_against_exact(fmt, [op], *all_pairs(fmt))


@pytest.mark.slow
@pytest.mark.parametrize("em", [(5, 4), (3, 6), (2, 1)])
@pytest.mark.parametrize("op", OPS)
def test_small_formats_exhaustive_arith(em, op):
    fmt = FPFormat(*em)
    check_against_exact(fmt, [op], *all_pairs(fmt))


@pytest.mark.parametrize("em", [(4, 3), (2, 1), (5, 4), (6, 5), (5, 10)])
def test_sqrt_exhaustive(em):
    """Every encoding of small formats (NaN payloads, denormals, -0, negatives, inf) against
    the exact reference."""
    fmt = FPFormat(*em)
    ex = ExactFormat(*em)
    bits = np.arange(1 << fmt.width, dtype=np.uint32)
    got = fmt.to_bits(fmt.sqrt(fmt.from_bits(bits)))
    want = np.array([ex.sqrt(int(b)) for b in bits], dtype=np.uint32)
    idx = np.flatnonzero(got != want)
    assert idx.size == 0, f"{fmt} sqrt: {idx.size} mismatches, first (a, model, exact): " \
        f"{[(hex(bits[i]), hex(got[i]), hex(want[i])) for i in idx[:5]]}"


@pytest.mark.parametrize("fmt", [BINARY32, FPFormat(8, 16), FPFormat(8, 10)], ids=str)
def test_sqrt_exact_wide(fmt):
    """Wide formats: every significand pattern near a rounding tie and random values of every
    binade, against the exact reference (and numpy's float32 sqrt for binary32)."""
    rng = np.random.default_rng(5)
    ex = ExactFormat(*fmt.em)
    a, _ = corner_pairs(fmt, 3000, rng)
    M = fmt.frac_bits
    k = rng.integers(1 << M, 1 << (M + 1), 2000).astype(np.float64)
    e = rng.integers(-20, 20, k.size)
    near_tie = fmt.quantize((k + 0.5) ** 2 * np.exp2(2.0 * (e - M)) * rng.choice([1, 2], k.size))
    bits = fmt.to_bits(np.concatenate([a, special_values(fmt), near_tie,
                                       np.nextafter(near_tie, np.float32(0))]))
    got = fmt.to_bits(fmt.sqrt(fmt.from_bits(bits)))
    want = np.array([ex.sqrt(int(b)) for b in bits], dtype=np.uint32)
    assert np.array_equal(got, want), np.flatnonzero(got != want)[:5]
    if fmt == BINARY32:
        x = fmt.from_bits(bits)
        with np.errstate(invalid="ignore"):
            assert np.array_equal(fmt.to_bits(np.sqrt(x)), got)


@pytest.mark.parametrize("em", [(4, 3), (2, 1)])
def test_tiny_exhaustive_compare_minmax(em):
    fmt = FPFormat(*em)
    ex = ExactFormat(*em)
    A, B = all_pairs(fmt)
    a, b = fmt.from_bits(A), fmt.from_bits(B)
    for op in ("lt", "le", "eq"):
        got = getattr(fmt, op)(a, b)
        want = np.array([getattr(ex, op)(int(x), int(y)) for x, y in zip(A, B)])
        assert got.dtype == bool
        assert np.array_equal(got, want), f"{fmt} {op}: {np.count_nonzero(got != want)} mismatches"
    for op in ("min", "max"):
        got = fmt.to_bits(getattr(fmt, op)(a, b))
        want = np.array([getattr(ex, op)(int(x), int(y)) for x, y in zip(A, B)], dtype=np.uint32)
        idx = np.flatnonzero(got != want)
        assert idx.size == 0, (f"{fmt} {op}: {idx.size} mismatches, first a={A[idx[0]]:#x} "
                               f"b={B[idx[0]]:#x} model={got[idx[0]]:#x} exact={want[idx[0]]:#x}")


def test_minmax_zero_and_nan_rules():
    """The documented choices, spelled out: first operand of two equal zeros, NaN ignored."""
    fmt = BINARY32
    pz, nz, nan = np.float32(0.0), np.float32(-0.0), np.float32(np.nan)
    assert fmt.to_bits(fmt.min(pz, nz)) == 0x00000000
    assert fmt.to_bits(fmt.min(nz, pz)) == 0x80000000
    assert fmt.to_bits(fmt.max(nz, pz)) == 0x80000000
    assert fmt.min(nan, np.float32(2)) == 2 and fmt.min(np.float32(2), nan) == 2
    assert fmt.max(nan, np.float32(-2)) == -2 and fmt.max(np.float32(-2), nan) == -2
    assert np.isnan(fmt.max(nan, nan))
    assert not fmt.lt(nan, nan) and not fmt.le(nan, np.float32(1)) and not fmt.eq(nan, nan)
    assert fmt.eq(pz, nz) and fmt.le(nz, pz) and not fmt.lt(nz, pz)


# -------------------------------------------------------------------------------------------
# binary32 against numpy float32 (independent oracle) in the normal range
# -------------------------------------------------------------------------------------------

FLT_MIN = np.float32(2.0 ** -126)
normal_bits = st.integers(0x00800000, 0x7F7FFFFF).flatmap(
    lambda m: st.sampled_from([m, m | 0x80000000]))


def _normal(x) -> bool:
    return bool(np.isfinite(x) and abs(x) >= FLT_MIN)


@settings(max_examples=3000, deadline=None)
@given(normal_bits, normal_bits)
def test_binary32_matches_numpy(ab, bb):
    a = np.array([ab], dtype=np.uint32).view(np.float32)
    b = np.array([bb], dtype=np.uint32).view(np.float32)
    with np.errstate(all="ignore"):
        for op, ref in (("add", np.add), ("sub", np.subtract), ("mul", np.multiply),
                        ("div", np.divide)):
            want = ref(a, b)
            if not _normal(want[0]):
                continue
            got = getattr(BINARY32, op)(a, b)
            assert got.view(np.uint32)[0] == want.view(np.uint32)[0], (op, hex(ab), hex(bb))


def test_binary32_matches_numpy_bulk():
    """2 x 10^5 random normal pairs per op, moderate and full exponent ranges."""
    rng = np.random.default_rng(3)
    n = 100_000
    mags = [rng.integers(0x00800000, 0x7F800000, n, dtype=np.uint32),
            (rng.integers(-20, 21, n) + 127).astype(np.uint32) << 23
            | rng.integers(0, 1 << 23, n, dtype=np.uint32)]
    for m in mags:
        s = rng.integers(0, 2, (2, n), dtype=np.uint32) << 31
        a = (m | s[0]).view(np.float32)
        b = (rng.permutation(m) | s[1]).view(np.float32)
        with np.errstate(all="ignore"):
            for op, ref in (("add", np.add), ("sub", np.subtract), ("mul", np.multiply),
                            ("div", np.divide)):
                want = ref(a, b)
                keep = np.isfinite(want) & (np.abs(want) >= FLT_MIN)
                got = getattr(BINARY32, op)(a, b)
                assert np.array_equal(got.view(np.uint32)[keep], want.view(np.uint32)[keep]), op


# -------------------------------------------------------------------------------------------
# hard cases of E8M23, E8M16, E8M10 against the exact reference
# -------------------------------------------------------------------------------------------

WIDE = [FPFormat(8, 23), FPFormat(8, 16), FPFormat(8, 10)]


def bits(fmt, *vals):
    return fmt.to_bits(np.array(vals, dtype=np.float64).astype(np.float32))


@pytest.mark.parametrize("fmt", WIDE, ids=str)
def test_band_cases(fmt):
    """Named flush-after-rounding band cases, generalized to M, each checked by the reference
    (and the expected outcome class asserted so the reference itself is checked too)."""
    ex = ExactFormat(*fmt.em)
    M = fmt.frac_bits
    mn, mx = fmt.min_normal, fmt.max_finite
    u = 2.0 ** -M
    below1, below1b = 1 - u / 2, 1 - u                 # 0x3f7fffff, 0x3f7ffffe for binary32
    cases = [
        ("mul", below1, mn, "zero"),                   # exact < min normal, no rounding up
        ("mul", below1b, mn * (1 + u), "min"),         # 1 - 2^-2M rounds up to min normal
        ("mul", -below1, mn, "-zero"),
        ("div", mn, 2.0, "zero"),
        ("div", mn * (2 - u), 2.0, "zero"),            # (1 - 2^-(M+1)) * mn: a tie? no, exact
        ("div", mn * (2 - u), 2.0 - u, "min"),
        ("add", 1.0, u / 2, "one"),                    # tie, to even (down)
        ("add", 1.0 + u, u / 2, "even_up"),            # tie, to even (up)
        ("add", mx, mx, "inf"),
        ("add", mx, 2.0 ** (fmt.bias - M - 1), "inf"),  # max + half ulp: tie rounds to even=inf
        ("add", mx, 2.0 ** (fmt.bias - M - 2), "max"),
        ("mul", mx, 1 + u, "inf"),
        ("mul", -mx, 2.0, "-inf"),
        ("add", 2.0 - u, u / 2, "two"),                # rounds up into the next binade
        ("mul", 2.0 - u, 1 + u, "two"),
        ("sub", 1.0 + u, 1.0, "ulp"),                  # cancellation, exact
        ("sub", mn * (1 + u), mn, "zero"),             # cancellation below min normal: flushed
        ("sub", -mn * (1 + u), -mn, "-zero"),
        ("sub", 1.0, 1.0, "zero"),
        ("add", -0.0, -0.0, "-zero"),
        ("add", 1.0, 2.0 ** -(M + 3), "one"),          # exponent gap beyond the fraction
        ("sub", 1.0, 2.0 ** -(M + 3), "one"),
        ("sub", 1.0, 3 * 2.0 ** -(M + 3), "below1"),    # 1 - 3/4 ulp(below 1) -> 1 - ulp
        ("div", 1.0, 3.0, None),
        ("div", 1.0, mx, "zero"),                      # 1/x of a large x flushes
        ("div", 1.0, mn, None),
        ("div", 1.0, 1.0 + u, "below1b"),              # 1/(1+u) = 1 - u + u^2 - ...
    ]
    expect_value = {"zero": 0.0, "-zero": -0.0, "min": mn, "one": 1.0, "two": 2.0,
                    "even_up": 1 + 2 * u, "inf": np.inf, "-inf": -np.inf, "max": mx,
                    "ulp": u, "below1": 1 - u / 2, "below1b": 1 - u}
    for op, x, y, kind in cases:
        a, b = bits(fmt, x, y)
        want = getattr(ex, op)(int(a), int(b))
        got = int(fmt.to_bits(getattr(fmt, op)(fmt.from_bits(a), fmt.from_bits(b))))
        assert got == want, f"{fmt} {op}({x!r}, {y!r}): model {got:#x}, exact {want:#x}"
        if kind is not None and kind in expect_value:
            assert want == int(bits(fmt, expect_value[kind])[0]), (op, x, y, kind, hex(want))
    if fmt == BINARY32:        # the literal encodings of the band cases
        assert fmt.to_bits(fmt.mul(np.uint32(0x3F7FFFFF).view(np.float32),
                                   np.uint32(0x00800000).view(np.float32))) == 0
        assert fmt.to_bits(fmt.mul(np.uint32(0x3F7FFFFE).view(np.float32),
                                   np.uint32(0x00800001).view(np.float32))) == 0x00800000


@pytest.mark.parametrize("fmt", WIDE, ids=str)
def test_corner_families_exact(fmt):
    """~4000 generated corner pairs (tb/fp_vectors.corner_pairs) per format, every op."""
    a, b = corner_pairs(fmt, 2000, np.random.default_rng(7))
    check_against_exact(fmt, OPS, fmt.to_bits(a), fmt.to_bits(b))


def test_corner_band_outcomes_occur():
    """The corner generator really reaches the band: some products flush, some round up to the
    smallest normal, some overflow (so the test above is not vacuous)."""
    fmt = FPFormat(8, 16)
    a, b = corner_pairs(fmt, 2000, np.random.default_rng(7))
    p = fmt.mul(a, b)
    exact = a.astype(np.float64) * b.astype(np.float64)
    fin = np.isfinite(exact) & (exact != 0)
    assert np.count_nonzero(fin & (p == 0)) > 20
    assert np.count_nonzero(fin & (np.abs(exact) < fmt.min_normal) & (np.abs(p) == fmt.min_normal)) > 5
    assert np.count_nonzero(fin & np.isinf(p)) > 20


def test_denormal_carriers_read_as_zero():
    """float32 denormal carriers given to the vectorized ops read as signed zero."""
    fmt = BINARY32
    d = np.array([1e-40, -1e-40, 1e-45], dtype=np.float32)
    one = np.float32(1)
    assert np.array_equal(fmt.to_bits(fmt.mul(d, np.float32(2.0 ** 100))), [0, 0x80000000, 0])
    assert np.array_equal(fmt.to_bits(fmt.add(d, d)), [0, 0x80000000, 0])
    assert np.all(np.isinf(fmt.div(one, d)))
    assert np.array_equal(fmt.to_bits(fmt.div(one, d)), [0x7F800000, 0xFF800000, 0x7F800000])
    assert not fmt.lt(np.float32(0), d[0]) and fmt.eq(d[1], np.float32(0))
    assert np.array_equal(fmt.to_bits(d), [0, 0x80000000, 0])


# -------------------------------------------------------------------------------------------
# encodings, quantize, scalar kernels
# -------------------------------------------------------------------------------------------

@pytest.mark.parametrize("em", [(8, 23), (8, 16), (8, 10), (5, 10), (4, 3), (2, 1)])
def test_bits_round_trip(em):
    fmt = FPFormat(*em)
    E, M = em
    rng = np.random.default_rng(1)
    n = 1 << fmt.width
    enc = np.arange(n, dtype=np.uint64) if n <= 1 << 16 else rng.integers(0, n, 200_000, dtype=np.uint64)
    exp = (enc >> M) & ((1 << E) - 1)
    frac = enc & ((1 << M) - 1)
    sign = enc >> (E + M)
    vals = fmt.from_bits(enc)
    back = fmt.to_bits(vals).astype(np.uint64)
    normal_or_inf = (exp != 0) & ~((exp == (1 << E) - 1) & (frac != 0))
    assert np.array_equal(back[normal_or_inf], enc[normal_or_inf])
    nan = (exp == (1 << E) - 1) & (frac != 0)
    assert np.all(np.isnan(vals[nan]))
    assert np.all(back[nan] == ((1 << E) - 1) << M | 1 << (M - 1))
    zero = exp == 0                                   # denormal encodings read as signed zero
    assert np.all(vals[zero] == 0) and np.array_equal(back[zero], sign[zero] << (E + M))
    # decoded values are exact: sig * 2^(e - bias - M)
    ok = normal_or_inf & (exp != (1 << E) - 1)
    want = np.ldexp((frac[ok] | (1 << M)).astype(np.float64),
                    exp[ok].astype(np.int64) - fmt.bias - M) * np.where(sign[ok] != 0, -1, 1)
    assert np.array_equal(vals[ok].astype(np.float64), want)


@pytest.mark.parametrize("fmt", [BINARY32, FPFormat(8, 10), FPFormat(4, 3)], ids=str)
def test_quantize_exact(fmt):
    ex = ExactFormat(*fmt.em)
    from fractions import Fraction
    rng = np.random.default_rng(5)
    x = np.concatenate([rng.standard_normal(3000) * 10.0 ** rng.integers(-40, 40, 3000),
                        special_values(fmt).astype(np.float64),
                        np.array([fmt.min_normal * (1 - 2.0 ** -(fmt.frac_bits + 1)),
                                  fmt.min_normal * (1 - 2.0 ** -(fmt.frac_bits + 2)),
                                  fmt.max_finite * (1 + 2.0 ** -(fmt.frac_bits + 1))])])
    got = fmt.to_bits(fmt.quantize(x))
    for xi, g in zip(x, got):
        if np.isnan(xi):
            assert g == ex.nan_bits
            continue
        if np.isinf(xi):
            want = ex.inf(int(xi < 0))
        else:
            want = ex.round(int(np.signbit(xi)), abs(Fraction(float(xi))))
        assert g == want, (xi, hex(g), hex(want))


@numba.njit
def _scalar_loop(a, b, E, M):
    n = a.size
    out = np.empty((6, n), np.float32)
    cmp = np.empty((3, n), np.bool_)
    for i in range(n):
        out[0, i] = fadd(a[i], b[i], E, M)
        out[1, i] = fsub(a[i], b[i], E, M)
        out[2, i] = fmul(a[i], b[i], E, M)
        out[3, i] = fdiv(a[i], b[i], E, M)
        out[4, i] = fmin(a[i], b[i]) if i % 2 else fmax(a[i], b[i])
        out[5, i] = fsqrt(a[i], E, M)
        cmp[0, i] = flt(a[i], b[i])
        cmp[1, i] = fle(a[i], b[i])
        cmp[2, i] = feq(a[i], b[i])
    return out, cmp


@pytest.mark.parametrize("fmt", [BINARY32, FPFormat(8, 16), FPFormat(5, 7), FPFormat(4, 3)], ids=str)
def test_scalar_kernels_equal_vectorized(fmt):
    a, b = corner_pairs(fmt, 3000, np.random.default_rng(11))
    out, cmp = _scalar_loop(a, b, *fmt.em)
    mm = np.where(np.arange(a.size) % 2 == 1, fmt.to_bits(fmt.min(a, b)), fmt.to_bits(fmt.max(a, b)))
    for row, op in zip(out[:4], OPS):
        assert np.array_equal(fmt.to_bits(row), fmt.to_bits(getattr(fmt, op)(a, b))), op
    assert np.array_equal(fmt.to_bits(out[4]), mm)
    assert np.array_equal(fmt.to_bits(out[5]), fmt.to_bits(fmt.sqrt(a)))
    for row, op in zip(cmp, ("lt", "le", "eq")):
        assert np.array_equal(row, getattr(fmt, op)(a, b)), op


def test_format_rejects_unsupported_widths():
    with pytest.raises(ValueError, match="exp_bits"):
        FPFormat(9, 23)
    with pytest.raises(ValueError, match="frac_bits"):
        FPFormat(8, 24)
