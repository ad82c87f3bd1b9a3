"""Shared combinational pieces of the FP units: unpack, leading-zero count, round and pack.

The rules are those of ``model/fp.py``: denormal encodings read as signed zero, round to
nearest even to M+1 significant bits with an unbounded exponent, then flush (biased exponent
< 1 -> signed zero) or overflow (biased exponent >= all-ones -> signed infinity), NaN out is
the canonical encoding of ``FPFormat.to_bits`` (sign 0, exponent all ones, fraction MSB only).
"""
from __future__ import annotations

from types import SimpleNamespace

from amaranth.hdl import C, Cat, Const, Module, Mux, Signal, Value

from model.fp import FPFormat

__all__ = ["wire", "unpack", "lzc", "round_pack", "round_inc", "pack", "special", "canonical_nan", "bits_for"]


def bits_for(n: int) -> int:
    """Bits of an unsigned number that holds 0..n."""
    return max(1, int(n).bit_length())


def gt_const(x: Value, c: int) -> Value:
    """``x > c`` for a constant ``c`` as and/or terms (a LUT or two), not a compare that
    synthesis would map to a carry chain: some bit where ``c`` has a 0 is set in ``x`` with
    every higher bit where ``c`` has a 1 (a higher 0 of ``c`` set in ``x`` is a term itself)."""
    x = Value.cast(x)
    w = len(x)
    if c < 0 or c >= 1 << w:
        return C(int(c < 0), 1)
    terms = [x[i] & Cat(*(x[j] for j in range(i + 1, w) if c >> j & 1), C(1, 1)).all()
             for i in range(w) if not c >> i & 1]
    return Cat(*terms).any() if terms else C(0, 1)


def unpack(fmt: FPFormat, x: Value) -> SimpleNamespace:
    """Split an encoding: sign, biased exponent, significand with its hidden bit (0 for zero and
    denormal encodings), and the class flags zero / inf / nan."""
    E, M = fmt.exp_bits, fmt.frac_bits
    x = Value.cast(x)
    sign, exp, frac = x[E + M], x[M:M + E], x[:M]
    emax = (1 << E) - 1
    zero = exp == 0
    top = exp == emax
    return SimpleNamespace(
        sign=sign, exp=exp, frac=frac, zero=zero,
        inf=top & (frac == 0), nan=top & (frac != 0),
        sig=Mux(zero, 0, Cat(frac, C(1, 1))),
        # magnitude order key: denormals read as zero, so their fraction is cleared
        key=Cat(Mux(zero, 0, frac), exp))


def wire(m: Module, v, name: str) -> Signal:
    """``v`` through a named combinational signal (readable Verilog; small simulator
    expressions)."""
    s = Signal.like(Value.cast(v), name=name)
    m.d.comb += s.eq(v)
    return s


def lzc(m: Module, v: Value, name: str = "lzc") -> Value:
    """Leading zeros of ``v`` (``len(v)`` when ``v`` is 0), as an unsigned value; a log-depth
    tree of 2:1 muxes."""
    v = Value.cast(v)
    n = len(v)
    p = 1
    while p < n:
        p *= 2
    if p == 1:
        return ~v[0]
    # pad below with ones: the count of a nonzero v is unchanged, a zero v counts n
    w = Cat(Const((1 << (p - n)) - 1, p - n), v) if p > n else v

    def tree(x, path):
        if len(x) == 2:
            return ~x[1], ~x[1] & ~x[0]
        h = len(x) // 2
        ch, zh = tree(x[h:], path + "h")
        cl, zl = tree(x[:h], path + "l")
        return Mux(zh, Cat(cl, C(1, 1)), Cat(ch, C(0, 1))), zh & zl

    cnt, _ = tree(w, "")
    return cnt


def canonical_nan(fmt: FPFormat) -> Const:
    E, M = fmt.exp_bits, fmt.frac_bits
    return Const((((1 << E) - 1) << M) | (1 << (M - 1)), fmt.width)


def special(fmt: FPFormat, sign: Value, inf: bool) -> Value:
    """Signed infinity (``inf``) or signed zero."""
    E, M = fmt.exp_bits, fmt.frac_bits
    return Cat(C(0, M), C((1 << E) - 1 if inf else 0, E), sign)


def exp_flags(fmt: FPFormat, exp: Value) -> dict:
    """The exponent half of :func:`round_inc`: the exponent and the flush/overflow flags for
    both outcomes of the increment's carry (``exp`` and ``exp + 1``)."""
    exp = Value.cast(exp)
    E = fmt.exp_bits
    emax = (1 << E) - 1
    e1 = exp + 1                                     # the exponent if the increment carries
    return dict(rnd_e0=exp[:E], rnd_e1=e1[:E], rnd_flush0=exp < 1, rnd_flush1=e1 < 1,
                rnd_over0=exp >= emax, rnd_over1=e1 >= emax)


def round_sig(m: Module, fmt: FPFormat, sig: Value, sticky: Value = C(0, 1)) -> dict:
    """The significand half of :func:`round_inc`: the round-to-nearest-even increment of a
    normalized significand (``rnd_sig``, W+1 bits, == 2**W on a carry) and ``rnd_zero`` (the
    value is zero: the significand and the sticky bit)."""
    M = fmt.frac_bits
    W = M + 1
    sig = Value.cast(sig)
    n = len(sig)
    assert n >= W, f"round_pack: significand of {n} bits < M+1={W}"
    keep = sig[n - W:]
    guard = sig[n - W - 1] if n > W else C(0, 1)
    rest = (sig[:n - W - 1] != 0) if n > W + 1 else C(0, 1)
    inc = wire(m, guard & (rest | sticky | keep[0]), "rnd_inc")
    return dict(rnd_sig=keep + inc, rnd_zero=(sig == 0) & ~sticky)


def round_inc(m: Module, fmt: FPFormat, exp: Value, sig: Value,
              sticky: Value = C(0, 1)) -> dict:
    """First half of :func:`round_pack`: the round-to-nearest-even increment of a normalized
    significand, and the flush/overflow flags for both outcomes of its carry (so the second
    half only selects). Returns the values to carry to :func:`pack` (a dict: pass it through a
    pipeline boundary, e.g. ``st(**rounded, sign=...)``, to cut round and pack in two).
    :func:`round_sig` and :func:`exp_flags` are its two halves, for a unit that forms the
    exponent's half earlier (the multiplier)."""
    return {**round_sig(m, fmt, sig, sticky), **exp_flags(fmt, exp)}


def pack(fmt: FPFormat, sign: Value, r) -> Value:
    """Second half of :func:`round_pack`: the encoding from :func:`round_inc`'s values ``r``
    (a dict or a namespace with the same names): flush to signed zero or overflow to signed
    infinity after rounding, else sign, exponent (one binade up if the increment carried) and
    fraction."""
    M = fmt.frac_bits
    r = r if isinstance(r, dict) else vars(r)
    carry = r["rnd_sig"][M + 1]
    flush = r["rnd_zero"] | Mux(carry, r["rnd_flush1"], r["rnd_flush0"])
    over = Mux(carry, r["rnd_over1"], r["rnd_over0"])
    return Mux(flush, special(fmt, sign, False),
               Mux(over, special(fmt, sign, True),
                   Cat(r["rnd_sig"][:M], Mux(carry, r["rnd_e1"], r["rnd_e0"]), sign)))


def round_pack(m: Module, fmt: FPFormat, sign: Value, exp: Value, sig: Value,
               sticky: Value = C(0, 1)) -> Value:
    """Round a normalized significand and pack it, flushing and overflowing after rounding
    (:func:`round_inc` then :func:`pack`, in one cycle).

    ``sig`` (n >= M+1 bits) has its leading one at the MSB (or is all zero: a zero result);
    its value is ``sig / 2**(n-1) * 2**(exp - bias)`` plus, if ``sticky``, something nonzero
    below the LSB. ``exp`` is a signed biased exponent wide enough for any intermediate value.
    """
    return pack(fmt, sign, round_inc(m, fmt, exp, sig, sticky))
