"""Operand generators for the FP tests: corner cases and random format values.

Every value returned is a float32 carrier of a value of the format (or a NaN), so the same
arrays drive the golden model (``fmt.add(a, b)`` ...) and the RTL (``fmt.to_bits(a)``).
The corner cases are the ones issue 3 lists: signed zeros, infinities, NaN, largest and
smallest normal, results that round up into the next binade, ties to even, overflow,
results near the smallest normal (flushed, or rounded up to it), catastrophic cancellation,
exponent differences larger than the fraction.
"""
from __future__ import annotations

import numpy as np

from model.fp import FPFormat


def make(fmt: FPFormat, sign, exp, sig) -> np.ndarray:
    """Values ``(-1)**sign * sig * 2**(exp - M)`` with ``sig`` an (M+1)-bit significand."""
    sign = np.asarray(sign, dtype=np.int64)
    v = np.ldexp(np.asarray(sig, dtype=np.float64), np.asarray(exp, dtype=np.int64) - fmt.frac_bits)
    return np.where(sign != 0, -v, v).astype(np.float32)


def round_sig(fmt: FPFormat, x) -> np.ndarray:
    """Round float64 ``x`` to M+1 significant bits (unbounded exponent; a generator, not the
    reference: the tests check results against the exact ``Fraction`` rounding)."""
    m, e = np.frexp(np.asarray(x, dtype=np.float64))
    return np.ldexp(np.round(np.ldexp(m, fmt.frac_bits + 1)), e - fmt.frac_bits - 1)


def special_values(fmt: FPFormat) -> np.ndarray:
    """Signed zeros, infinities, NaN, extreme normals and neighbours of 1, as float32."""
    M = fmt.frac_bits
    mn, mx = fmt.min_normal, fmt.max_finite
    ulp1 = 2.0 ** -M
    pos = [0.0, np.inf, mn, mn * (1 + ulp1), mn * 2, mx, mx - 2.0 ** (fmt.bias - M), 1.0,
           1.0 - ulp1 / 2, 1.0 + ulp1, 2.0 - ulp1, 2.0, 0.5, 3.0]
    pos = [p for p in pos if p == 0 or p == np.inf or mn <= p <= mx]
    vals = np.array(pos + [-p for p in pos] + [np.nan], dtype=np.float64)
    return vals.astype(np.float32)


def random_values(fmt: FPFormat, n: int, rng: np.random.Generator, spread: int | None = None) -> np.ndarray:
    """Random normal values; exponents uniform over the format, or within ``±spread`` of 0."""
    M = fmt.frac_bits
    emin, emax = 1 - fmt.bias, fmt.bias
    if spread is None:
        e = rng.integers(emin, emax + 1, n)
    else:
        e = rng.integers(max(emin, -spread), min(emax, spread) + 1, n)
    sig = rng.integers(1 << M, 1 << (M + 1), n)
    return make(fmt, rng.integers(0, 2, n), e, sig)


def random_encodings(fmt: FPFormat, n: int, rng: np.random.Generator) -> np.ndarray:
    """Values of uniformly random encodings (denormal encodings read as zero, NaNs included)."""
    bits = rng.integers(0, 1 << fmt.width, n, dtype=np.uint64)
    return fmt.from_bits(bits)


def corner_pairs(fmt: FPFormat, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """About ``n`` operand pairs (float32 arrays), mixed from the corner-case families."""
    M = fmt.frac_bits
    mn, mx = fmt.min_normal, fmt.max_finite
    k = max(1, n // 10)
    A, B = [], []

    def add(a, b):
        A.append(np.asarray(a, np.float32))
        B.append(np.asarray(b, np.float32))

    sp = special_values(fmt)
    # specials against specials and against random values
    ga, gb = np.meshgrid(sp, sp)
    add(ga.ravel(), gb.ravel())
    r = random_values(fmt, k, rng, spread=4)
    add(rng.choice(sp, k), r)
    add(r, rng.choice(sp, k))
    # uniformly random encodings and moderate random values
    add(random_encodings(fmt, k, rng), random_encodings(fmt, k, rng))
    add(random_values(fmt, k, rng, spread=3), random_values(fmt, k, rng, spread=3))
    # cancellation: b within a few ulps of ±a
    a = random_values(fmt, k, rng)
    sig = np.abs(a).astype(np.float64)
    m, e = np.frexp(sig)
    d = rng.integers(-3, 4, k)
    b = np.ldexp(np.ldexp(m, M + 1) + d, e - M - 1)
    b = np.where((b >= mn) & (b <= mx), b, sig)
    add(a, np.where(rng.integers(0, 2, k) != 0, -b, b))
    # exponent differences from 0 to beyond the fraction width, ties (b = half ulps of a)
    a = random_values(fmt, k, rng, spread=2)
    gap = rng.integers(0, M + 6, k)
    b = np.ldexp(np.abs(random_values(fmt, k, rng, spread=0)).astype(np.float64), -gap)
    b = np.where(rng.integers(0, 4, k) == 0, np.ldexp(1.0, -gap), b)
    b = np.where(rng.integers(0, 2, k) != 0, -b, b)
    add(a, np.where(b == 0, 1.0, b))
    # results that round up into the next binade: significands all ones
    a = make(fmt, rng.integers(0, 2, k), rng.integers(-2, 3, k), np.full(k, (1 << (M + 1)) - 1))
    b = make(fmt, 0, rng.integers(-M - 2, 1, k), rng.integers(1 << M, 1 << (M + 1), k))
    add(a, b)
    # products and quotients near the smallest normal (flushed, or rounded up to it)
    a = np.abs(random_values(fmt, k, rng, spread=0)).astype(np.float64) * 0.5    # [0.5, 1)
    b = round_sig(fmt, mn / a) + np.ldexp(rng.integers(-2, 3, k).astype(np.float64),
                                          int(np.log2(mn)) - M)
    b = np.clip(b, mn, mx)
    add(a, b)
    add(make(fmt, rng.integers(0, 2, k), 1 - fmt.bias, rng.integers(1 << M, 1 << (M + 1), k)),
        np.abs(random_values(fmt, k, rng, spread=0)))                           # [1, 2)
    add(make(fmt, rng.integers(0, 2, k), 1 - fmt.bias + rng.integers(0, 2, k),
             rng.integers(1 << M, 1 << (M + 1), k)),
        np.ldexp(1.0, rng.integers(0, 3, k)))
    # products near overflow
    a = np.abs(random_values(fmt, k, rng, spread=0)).astype(np.float64)          # [1, 2)
    b = np.clip(round_sig(fmt, mx / a), mn, mx)
    add(a, b)
    return _sanitize(fmt, np.concatenate(A)), _sanitize(fmt, np.concatenate(B))


def _sanitize(fmt: FPFormat, x: np.ndarray) -> np.ndarray:
    """Make every finite entry a format value: M+1 significant bits, clamped to max_finite,
    below-normal magnitudes flushed."""
    x = x.astype(np.float64)
    fin = np.isfinite(x)
    r = np.where(fin, round_sig(fmt, np.where(fin, x, 0.0)), x)
    r = np.where(fin & (np.abs(r) > fmt.max_finite), np.copysign(fmt.max_finite, r), r)
    return fmt.flush(r.astype(np.float32))
