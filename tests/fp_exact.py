"""Exact reference for the hardware float format, written with ``fractions.Fraction``.

Independent of ``model/fp.py``: operands are decoded from their encodings by hand, the
operation is done exactly, the result is rounded to nearest-even to M+1 significant bits with
an unbounded exponent, then flushed (below the smallest normal -> signed zero) or overflowed
(above the largest finite -> signed infinity), and encoded by hand. Slow (pure Python): for
exhaustive tiny formats and a few thousand chosen cases.
"""
from __future__ import annotations

from fractions import Fraction

NAN, INF, FIN = 0, 1, 2


class ExactFormat:
    def __init__(self, E: int, M: int):
        self.E, self.M = E, M
        self.bias = (1 << (E - 1)) - 1
        self.emax = (1 << E) - 1
        self.nan_bits = (self.emax << M) | (1 << (M - 1))

    # -- encodings ---------------------------------------------------------------------------
    def decode(self, bits: int):
        """(kind, sign, magnitude) with magnitude a Fraction (denormal encodings read as 0)."""
        E, M = self.E, self.M
        s = (bits >> (E + M)) & 1
        e = (bits >> M) & self.emax
        f = bits & ((1 << M) - 1)
        if e == self.emax:
            return (NAN, 0, None) if f else (INF, s, None)
        if e == 0:
            return (FIN, s, Fraction(0))
        return (FIN, s, Fraction((1 << M) | f) * Fraction(2) ** (e - self.bias - M))

    def zero(self, s: int) -> int:
        return s << (self.E + self.M)

    def inf(self, s: int) -> int:
        return (s << (self.E + self.M)) | (self.emax << self.M)

    def round(self, s: int, q: Fraction) -> int:
        """Encode sign ``s`` and exact magnitude ``q >= 0``: RNE, then flush/overflow."""
        if q == 0:
            return self.zero(s)
        M = self.M
        n, d = q.numerator, q.denominator
        e = n.bit_length() - d.bit_length()          # 2**e <= q < 2**(e+1) after the fix-up
        if (n << max(0, -e)) < (d << max(0, e)):
            e -= 1
        num = n << max(0, M - e)
        den = d << max(0, e - M)
        k, r = divmod(num, den)                       # k in [2**M, 2**(M+1))
        return self.encode(s, e, k + (2 * r > den or (2 * r == den and k & 1)))

    def encode(self, s: int, e: int, k: int) -> int:
        """Sign ``s`` and the rounded value ``k * 2**(e - M)`` (``k`` in [2**M, 2**(M+1)], the
        top end from a rounding carry): renormalise, then flush to zero or overflow to inf."""
        M = self.M
        if k == 1 << (M + 1):
            k >>= 1
            e += 1
        be = e + self.bias
        if be < 1:
            return self.zero(s)
        if be > self.emax - 1:
            return self.inf(s)
        return (s << (self.E + M)) | (be << M) | (k - (1 << M))

    # -- operations on encodings ---------------------------------------------------------------
    def add(self, a: int, b: int, negate_b: bool = False) -> int:
        ka, sa, va = self.decode(a)
        kb, sb, vb = self.decode(b)
        if negate_b and kb != NAN:
            sb ^= 1
        if ka == NAN or kb == NAN:
            return self.nan_bits
        if ka == INF and kb == INF:
            return self.inf(sa) if sa == sb else self.nan_bits
        if ka == INF:
            return self.inf(sa)
        if kb == INF:
            return self.inf(sb)
        x = (-va if sa else va) + (-vb if sb else vb)
        if x == 0:                                    # IEEE: -0 only for (-0) + (-0)
            return self.zero(sa & sb)
        return self.round(int(x < 0), abs(x))

    def sub(self, a: int, b: int) -> int:
        return self.add(a, b, negate_b=True)

    def mul(self, a: int, b: int) -> int:
        ka, sa, va = self.decode(a)
        kb, sb, vb = self.decode(b)
        s = sa ^ sb
        if ka == NAN or kb == NAN:
            return self.nan_bits
        if ka == INF or kb == INF:
            if (ka == FIN and va == 0) or (kb == FIN and vb == 0):
                return self.nan_bits
            return self.inf(s)
        return self.round(s, va * vb)

    def div(self, a: int, b: int) -> int:
        ka, sa, va = self.decode(a)
        kb, sb, vb = self.decode(b)
        s = sa ^ sb
        if ka == NAN or kb == NAN:
            return self.nan_bits
        if ka == INF:
            return self.nan_bits if kb == INF else self.inf(s)
        if kb == INF:
            return self.zero(s)
        if vb == 0:
            return self.nan_bits if va == 0 else self.inf(s)
        return self.round(s, va / vb)

    def sqrt(self, a: int) -> int:
        """Square root, correctly rounded: the integer square root gives the truncated
        significand, and comparing 4*X with (2k+1)**2 (exact integers) decides the rounding."""
        from math import isqrt
        ka, sa, va = self.decode(a)
        if ka == NAN or (sa and not (ka == FIN and va == 0)):
            return self.nan_bits                      # NaN, or below zero (-inf included)
        if ka == INF:
            return self.inf(0)
        if va == 0:
            return self.zero(sa)
        M = self.M
        ev = va.numerator.bit_length() - va.denominator.bit_length()
        if va < Fraction(2) ** ev:
            ev -= 1                                   # 2**ev <= va < 2**(ev+1)
        e = ev // 2                                   # 2**e <= sqrt(va) < 2**(e+1)
        x = va * Fraction(4) ** (M - e)               # sqrt(x) in [2**M, 2**(M+1))
        k = isqrt(x.numerator // x.denominator)
        four_x, mid = 4 * x, (2 * k + 1) ** 2
        return self.encode(0, e, k + (four_x > mid or (four_x == mid and k & 1)))

    # -- compare, min, max (documented rules of model/fp.py) -----------------------------------
    def value(self, bits: int) -> float:
        """Exact value as a Python float (every E<=8, M<=23 value is a float64); NaN for NaN."""
        k, s, v = self.decode(bits)
        if k == NAN:
            return float("nan")
        x = float("inf") if k == INF else float(v)
        return -x if s else x

    def canonical(self, bits: int) -> int:
        """The operand as the hardware reads it: NaN canonical, denormal encodings signed zero."""
        k, s, v = self.decode(bits)
        if k == NAN:
            return self.nan_bits
        if k == FIN and v == 0:
            return self.zero(s)
        return bits

    def lt(self, a: int, b: int) -> bool:
        return self.value(a) < self.value(b)         # Python floats: NaN false, -0 == +0

    def le(self, a: int, b: int) -> bool:
        return self.value(a) <= self.value(b)

    def eq(self, a: int, b: int) -> bool:
        return self.value(a) == self.value(b)

    def min(self, a: int, b: int) -> int:
        x, y = self.value(a), self.value(b)
        return self.canonical(b if (y < x or x != x) else a)

    def max(self, a: int, b: int) -> int:
        x, y = self.value(a), self.value(b)
        return self.canonical(b if (y > x or x != x) else a)
