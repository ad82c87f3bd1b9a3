"""Hardware floating-point arithmetic, emulated bit for bit.

The format has ``exp_bits`` (E) exponent bits and ``frac_bits`` (M) fraction bits, IEEE-like
layout (sign, biased exponent, fraction; exponent all-ones is inf/NaN). The hardware rules:

* round to nearest, ties to even;
* denormal inputs read as signed zero (they never occur inside the chip: every value is the
  output of a rounding below, or was quantized when the memory image was built);
* results are rounded to M+1 significant bits **as if the exponent were unbounded**, then a
  rounded magnitude below the smallest normal gives a signed zero and one above the largest
  finite gives a signed infinity (flush/overflow *after* rounding);
* NaN: any NaN operand, inf-inf, 0*inf, 0/0, inf/inf and the square root of a number below
  zero give NaN (encoded canonically, see
  :meth:`FPFormat.to_bits`); x/0 gives a signed infinity; zero signs follow IEEE 754.
* compare: IEEE (``-0 == +0``; every comparison with NaN is false);
* ``min(a, b) = b if b < a or a is NaN else a`` and ``max(a, b) = b if b > a or a is NaN else a``:
  a NaN is ignored when the other operand is a number, and of two equal operands (``+0``/``-0``)
  the first is returned.

Values are carried in NumPy/numba as ``float32`` (every format with E <= 8, M <= 23 embeds
exactly in binary32). An operation converts its operands exactly to float64, computes there and
rounds **once** to (E, M). One rounding from float64 is exact for M <= 23: float64 holds
53 >= 2(M+1)+2 significant bits, so rounding the float64 result again cannot double-round
(checked exhaustively for small formats and on adversarial operands in ``tests/test_fp_model.py``). For binary32 a fast path uses the float32 result directly and falls back to
the exact rounding only when that result is at or below the smallest normal (the one band where
IEEE gradual underflow and flush-after-rounding disagree).

Two APIs over the same code:
* scalar ``@njit`` functions ``fadd(a, b, E, M)``, ``fsqrt(a, E, M)`` ... for the compiled per-packet kernels;
* :class:`FPFormat` methods ``fmt.add(a, b)`` ... vectorized over NumPy arrays (flush inputs).
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

_SIGN64 = np.uint64(1 << 63)
_EXPMASK64 = np.uint64(0x7FF << 52)
_FLT_MIN = np.float32(2.0 ** -126)


# ---------------------------------------------------------------------------------------------
# scalar kernels (compiled); E and M are runtime integers so one compilation serves every format
# ---------------------------------------------------------------------------------------------

@numba.njit(cache=True, inline="always")
def min_normal_bits64(E):
    """float64 bit pattern of the smallest normal of an E-bit exponent format."""
    bias = (1 << (E - 1)) - 1
    return np.uint64(1023 + 1 - bias) << np.uint64(52)


@numba.njit(cache=True, inline="always")
def max_finite_bits64(E, M):
    """float64 bit pattern of the largest finite value of format (E, M)."""
    bias = (1 << (E - 1)) - 1
    return (np.uint64(1023 + bias) << np.uint64(52)) | (
        np.uint64((1 << M) - 1) << np.uint64(52 - M))


@numba.njit(cache=True, error_model="numpy")
def round_exact(x, E, M):
    """Round float64 ``x`` once to (E, M): RNE with unbounded exponent, then flush/overflow."""
    b = np.float64(x).view(np.uint64)
    sign = b & _SIGN64
    mag = b ^ sign
    if mag >= _EXPMASK64:                      # inf or NaN pass through
        return np.float32(x)
    sh = np.uint64(52 - M)
    lsb = (mag >> sh) & np.uint64(1)
    half_m1 = (np.uint64(1) << (sh - np.uint64(1))) - np.uint64(1)
    mag = (mag + half_m1 + lsb) & ~((np.uint64(1) << sh) - np.uint64(1))
    if mag < min_normal_bits64(E):
        mag = np.uint64(0)
    elif mag > max_finite_bits64(E, M):
        mag = _EXPMASK64
    return np.float32(np.uint64(mag | sign).view(np.float64))


@numba.njit(cache=True, inline="always")
def rnd(x, E, M):
    """Round a float64 exact-or-once-rounded result to the hardware format."""
    if E == 8 and M == 23:
        r = np.float32(x)
        if not (abs(r) <= _FLT_MIN):          # normal, inf or NaN: IEEE == hardware
            return r
    return round_exact(x, E, M)


# Binary32 fast path: IEEE float32 arithmetic equals the hardware's whenever the result is
# normal, inf or NaN (operands are always format values, never denormal); a result at or below
# the smallest normal is recomputed exactly (the flush-after-rounding band).

@numba.njit(cache=True, inline="always", error_model="numpy")
def fadd(a, b, E, M):
    if E == 8 and M == 23:
        r = np.float32(a) + np.float32(b)
        if not (abs(r) <= _FLT_MIN):
            return r
    return round_exact(np.float64(a) + np.float64(b), E, M)


@numba.njit(cache=True, inline="always", error_model="numpy")
def fsub(a, b, E, M):
    if E == 8 and M == 23:
        r = np.float32(a) - np.float32(b)
        if not (abs(r) <= _FLT_MIN):
            return r
    return round_exact(np.float64(a) - np.float64(b), E, M)


@numba.njit(cache=True, inline="always", error_model="numpy")
def fmul(a, b, E, M):
    if E == 8 and M == 23:
        r = np.float32(a) * np.float32(b)
        if not (abs(r) <= _FLT_MIN):
            return r
    return round_exact(np.float64(a) * np.float64(b), E, M)


@numba.njit(cache=True, inline="always", error_model="numpy")
def fdiv(a, b, E, M):
    """a / b; x/0 is ±inf and 0/0 NaN, as IEEE and the hardware.

    The zero divisor is handled explicitly: this function is inlined into its caller, and a
    caller compiled with numba's default ``error_model='python'`` would raise
    ZeroDivisionError on ``a / 0``."""
    if b == 0:
        if a != a or a == 0:
            return np.float32(np.nan)
        neg = (np.float64(a).view(np.uint64) ^ np.float64(b).view(np.uint64)) & _SIGN64
        return np.float32(np.inf) if neg == 0 else np.float32(-np.inf)
    if E == 8 and M == 23:
        r = np.float32(a) / np.float32(b)
        if not (abs(r) <= _FLT_MIN):
            return r
    return round_exact(np.float64(a) / np.float64(b), E, M)


@numba.njit(cache=True, inline="always", error_model="numpy")
def fsqrt(a, E, M):
    """sqrt(a): NaN for a NaN or a number below zero (-inf too), ±0 for ±0 (the sign kept, as
    IEEE), +inf for +inf; otherwise correctly rounded (float64's sqrt is correctly rounded and
    53 >= 2(M+1)+2, so rounding it once more to (E, M) is exact). Never flushes or overflows:
    the exponent halves."""
    if a != a or a < 0:
        return np.float32(np.nan)
    if a == 0:
        return np.float32(a)
    if E == 8 and M == 23:
        return np.float32(np.sqrt(np.float32(a)))
    return round_exact(np.sqrt(np.float64(a)), E, M)


@numba.njit(cache=True, inline="always")
def flt(a, b):
    return a < b


@numba.njit(cache=True, inline="always")
def fle(a, b):
    return a <= b


@numba.njit(cache=True, inline="always")
def feq(a, b):
    return a == b


@numba.njit(cache=True, inline="always")
def fmin(a, b):
    return b if (b < a or a != a) else a


@numba.njit(cache=True, inline="always")
def fmax(a, b):
    return b if (b > a or a != a) else a


@numba.njit(cache=True, inline="always")
def flush_in(x, E):
    """Denormal (below smallest normal) operands read as signed zero."""
    b = np.float64(x).view(np.uint64)
    if (b & ~_SIGN64) < min_normal_bits64(E):
        return np.float32(np.uint64(b & _SIGN64).view(np.float64))
    return np.float32(x)


# ---------------------------------------------------------------------------------------------
# vectorized API
# ---------------------------------------------------------------------------------------------

_SIG2 = ["float32(float32, float32, int64, int64)"]


@numba.vectorize(_SIG2, cache=True)
def _vadd(a, b, E, M):
    return fadd(flush_in(a, E), flush_in(b, E), E, M)


@numba.vectorize(_SIG2, cache=True)
def _vsub(a, b, E, M):
    return fsub(flush_in(a, E), flush_in(b, E), E, M)


@numba.vectorize(_SIG2, cache=True)
def _vmul(a, b, E, M):
    return fmul(flush_in(a, E), flush_in(b, E), E, M)


@numba.vectorize(_SIG2, cache=True)
def _vdiv(a, b, E, M):
    return fdiv(flush_in(a, E), flush_in(b, E), E, M)


@numba.vectorize(["float32(float32, int64, int64)"], cache=True)
def _vsqrt(a, E, M):
    return fsqrt(flush_in(a, E), E, M)


@numba.vectorize(_SIG2, cache=True)
def _vmin(a, b, E, M):
    return fmin(flush_in(a, E), flush_in(b, E))


@numba.vectorize(_SIG2, cache=True)
def _vmax(a, b, E, M):
    return fmax(flush_in(a, E), flush_in(b, E))


@numba.vectorize(["float32(float64, int64, int64)"], cache=True)
def _vquant(x, E, M):
    return round_exact(x, E, M)


@numba.vectorize(["float32(float32, int64)"], cache=True)
def _vflush(x, E):
    return flush_in(x, E)


@dataclass(frozen=True)
class FPFormat:
    """A hardware float format: ``exp_bits`` exponent bits, ``frac_bits`` fraction bits."""

    exp_bits: int = 8
    frac_bits: int = 23

    def __post_init__(self) -> None:
        if not 2 <= self.exp_bits <= 8:
            raise ValueError(f"FPFormat: exp_bits={self.exp_bits} must be in 2..8 "
                             "(values are carried as float32)")
        if not 1 <= self.frac_bits <= 23:
            raise ValueError(f"FPFormat: frac_bits={self.frac_bits} must be in 1..23 "
                             "(values are carried as float32)")

    # -- derived sizes ---------------------------------------------------------------------
    @property
    def width(self) -> int:
        return 1 + self.exp_bits + self.frac_bits

    @property
    def bias(self) -> int:
        return (1 << (self.exp_bits - 1)) - 1

    @property
    def min_normal(self) -> float:
        return 2.0 ** (1 - self.bias)

    @property
    def max_finite(self) -> float:
        return (2.0 - 2.0 ** -self.frac_bits) * 2.0 ** self.bias

    @property
    def em(self) -> tuple[int, int]:
        """(E, M) as the compiled kernels take them."""
        return self.exp_bits, self.frac_bits

    def __str__(self) -> str:
        return f"E{self.exp_bits}M{self.frac_bits}"

    # -- conversions -------------------------------------------------------------------------
    def quantize(self, x) -> np.ndarray:
        """Round any real array (float64/float32) once to this format, as float32."""
        return _vquant(np.asarray(x, dtype=np.float64), self.exp_bits, self.frac_bits)

    def from_fixed(self, x, frac_bits: int = 0) -> np.ndarray:
        """Integers ``x`` read as fixed point with ``frac_bits`` fraction bits (the value
        ``x * 2**-frac_bits``), rounded once to this format: the int -> float conversion of the
        ray generation (e.g. ``from_fixed(2*px + 1, 1)`` is the pixel centre ``px + 0.5``)."""
        x = np.asarray(x)
        if x.dtype.kind not in "iub":
            raise TypeError(f"from_fixed: x has dtype {x.dtype}; pass integers "
                            "(use quantize() for real values)")
        x = x.astype(np.int64)
        if x.size and int(np.abs(x).max()) >= 1 << 53:
            raise ValueError("from_fixed: |x| >= 2**53 is not exact in float64; "
                             "split the integer or narrow it")
        return self.quantize(np.ldexp(x.astype(np.float64), -frac_bits))

    def flush(self, x) -> np.ndarray:
        """Denormal inputs read as zero."""
        return _vflush(np.asarray(x, dtype=np.float32), self.exp_bits)

    def to_bits(self, x) -> np.ndarray:
        """Encode format values (float32 carriers) as ``width``-bit integers (uint32).

        Below-normal magnitudes encode as signed zero; NaN encodes canonically as exponent
        all-ones with only the fraction's MSB set, sign 0."""
        x = self.flush(x)
        b = x.view(np.uint32).astype(np.uint64)
        sign = (b >> 31) & 1
        e32 = (b >> 23) & 0xFF
        f32 = b & 0x7FFFFF
        E, M = self.exp_bits, self.frac_bits
        emax = (1 << E) - 1
        e = np.where(e32 == 0, 0, np.where(e32 == 0xFF, emax, e32.astype(np.int64) - 127 + self.bias))
        f = f32 >> (23 - M)
        nan = np.isnan(x)
        e = np.where(nan, emax, e).astype(np.uint64)
        f = np.where(nan, 1 << (M - 1), f).astype(np.uint64)
        sign = np.where(nan, 0, sign).astype(np.uint64)
        return ((sign << (E + M)) | (e << M) | f).astype(np.uint32)

    def from_bits(self, bits) -> np.ndarray:
        """Decode ``width``-bit integers to float32 carriers (denormal encodings read as zero)."""
        b = np.asarray(bits).astype(np.uint64)
        E, M = self.exp_bits, self.frac_bits
        sign = (b >> (E + M)) & 1
        e = ((b >> M) & ((1 << E) - 1)).astype(np.int64)
        f = b & ((1 << M) - 1)
        emax = (1 << E) - 1
        e32 = np.where(e == 0, 0, np.where(e == emax, 0xFF, e - self.bias + 127))
        f32 = np.where(e == 0, 0, f << (23 - M))
        f32 = np.where((e == emax) & (f != 0), 1 << 22, f32)
        out = (sign << 31) | (e32.astype(np.uint64) << 23) | f32.astype(np.uint64)
        return out.astype(np.uint32).view(np.float32)

    # -- operations (vectorized, operands are flushed first) ---------------------------------
    def _f(self, x) -> np.ndarray:
        return np.asarray(x, dtype=np.float32)

    def add(self, a, b):
        return _vadd(self._f(a), self._f(b), *self.em)

    def sub(self, a, b):
        return _vsub(self._f(a), self._f(b), *self.em)

    def mul(self, a, b):
        return _vmul(self._f(a), self._f(b), *self.em)

    def div(self, a, b):
        with np.errstate(divide="ignore", invalid="ignore"):   # x/0 = ±inf is defined
            return _vdiv(self._f(a), self._f(b), *self.em)

    def sqrt(self, a):
        return _vsqrt(self._f(a), *self.em)

    def min(self, a, b):
        return _vmin(self._f(a), self._f(b), *self.em)

    def max(self, a, b):
        return _vmax(self._f(a), self._f(b), *self.em)

    def lt(self, a, b):
        return self.flush(a) < self.flush(b)

    def le(self, a, b):
        return self.flush(a) <= self.flush(b)

    def eq(self, a, b):
        return self.flush(a) == self.flush(b)


BINARY32 = FPFormat(8, 23)


@numba.njit(cache=True, inline="always")
def sign_bit(x):
    """The sign bit of a format value (1 for -0.0 and negative numbers)."""
    return np.int64(np.float32(x).view(np.uint32) >> np.uint32(31))
