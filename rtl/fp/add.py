"""Floating-point adder/subtractor, bit-exact with ``FPFormat.add`` / ``FPFormat.sub``."""
from __future__ import annotations

from collections.abc import Sequence

from amaranth.hdl import C, Cat, Module, Mux
from amaranth.lib import wiring
from amaranth.lib.wiring import In

from model.fp import BINARY32, FPFormat
from .common import bits_for, canonical_nan, gt_const, lzc, pack, round_inc, special, unpack
from .pipe import Stager, check_regs, placement, unit_ports

__all__ = ["FPAdd"]

GUARD = 3          # guard, round and sticky bits kept below the aligned significands


class FPAdd(wiring.Component):
    """``o = a + b`` (``op`` = 0) or ``o = a - b`` (``op`` = 1) in format ``fmt``.

    Steps: unpack (order the operands by exponent), align (shift the smaller right by the
    exponent difference, keeping guard/round/sticky bits), add or subtract the significands
    (on an exponent tie the difference's sign picks which way round), count the leading zeros,
    normalize (leading-zero count and left shift), round (the RNE increment), pack (exponent
    carry, flush/overflow and special-value select).

    Latency: ``latency`` cycles (default 3; 0 = combinational), registers placed at the 8 step
    boundaries (input, after unpack, after align, after add, after the leading-zero count,
    after normalize, after round, output) by ``regs`` or, by default, output first, then after
    align, after normalize, after unpack, after add, after round, input, after the count (so
    latencies 1-5 place them as before the round boundary existed; 6 is the first to cut
    round and pack, 8 the first to cut normalize in two). Throughput: one operation per
    cycle in which ``en`` is 1; with ``en`` = 0 every register holds (``o``/``o_valid`` too).

    Ports: ``a``, ``b``, ``op``, ``i_valid``, ``en`` in; ``o``, ``o_valid`` out.
    """

    BOUNDARIES = ("input", "unpack", "align", "add", "count", "normalize", "round", "output")
    ORDER = (7, 2, 5, 1, 3, 6, 0, 4)

    def __init__(self, fmt: FPFormat = BINARY32, latency: int = 3, regs: Sequence[int] | None = None):
        self.fmt = fmt
        nb = len(self.BOUNDARIES)
        self.regs = (placement(latency, nb, self.ORDER) if regs is None
                     else check_regs(regs, nb, "FPAdd", self.BOUNDARIES))
        self.latency = sum(self.regs)
        super().__init__(unit_ports(fmt.width, fmt.width, b=In(fmt.width), op=In(1)))

    def elaborate(self, platform):
        m = Module()
        fmt = self.fmt
        M = fmt.frac_bits
        W = M + 1
        n = W + GUARD                                        # aligned significand width
        st = Stager(m, self.en, self.i_valid, self.regs)

        v = st(a=self.a, b=self.b, op=self.op)
        # -- unpack: big = operand of larger exponent (a on a tie) ----------------------------
        # ordering by the exponents alone keeps this step short (an E-bit compare drives the
        # swap muxes, not an (E+M)-bit one); on a tie the add step resolves the order
        ua, ub = unpack(fmt, v.a), unpack(fmt, v.b)
        sb = ub.sign ^ v.op                                  # sign of the addend b
        # shift distance, saturated at n: both differences at once, the swap is a - b's sign,
        # the saturation plain logic on a difference's bits (not a second carry chain)
        E = fmt.exp_bits
        dab, dba = ua.exp - ub.exp, ub.exp - ua.exp
        swap = dab[E]                                        # ub.exp > ua.exp
        eff_sub = ua.sign ^ sb
        nan = ua.nan | ub.nan | (ua.inf & ub.inf & eff_sub)
        inf = ua.inf | ub.inf
        sh = bits_for(n)
        d = Mux(swap, Mux(gt_const(dba[:E], n), n, dba[:sh]),
                Mux(gt_const(dab[:E], n), n, dab[:sh]))[:sh]
        v = st(big_sig=Mux(swap, ub.sig, ua.sig), small_sig=Mux(swap, ua.sig, ub.sig),
               big_exp=Mux(swap, ub.exp, ua.exp), d=d,
               sign=Mux(swap, sb, ua.sign), small_sign=Mux(swap, ua.sign, sb),
               zero_sign=ua.sign & sb, eff_sub=eff_sub,
               nan=nan, inf=inf, inf_sign=Mux(ua.inf, ua.sign, sb))
        # -- align: small >> d, bits shifted out OR into a sticky LSB ---------------------------
        wide = Cat(C(0, n + GUARD), v.small_sig) >> v.d  # 2n bits: aligned | shifted out
        small = wide[n:] | (wide[:n] != 0)
        v = st(big=Cat(C(0, GUARD), v.big_sig), small=small, exp=v.big_exp, sign=v.sign,
               small_sign=v.small_sign, zero_sign=v.zero_sign, eff_sub=v.eff_sub, nan=v.nan,
               inf=v.inf, inf_sign=v.inf_sign)
        # -- add / subtract: the magnitude of the difference, whose sign is the larger operand's
        # (small > big only on an exponent tie: then nothing was shifted and small - big is exact)
        diff = (v.big - v.small).as_unsigned()[:n + 1]       # n+1 bits: the top bit is a borrow
        neg = v.eff_sub & diff[n]
        s = Mux(v.eff_sub, Mux(diff[n], (v.small - v.big).as_unsigned()[:n + 1], diff),
                v.big + v.small)
        v = st(s=s, exp=v.exp, sign=Mux(neg, v.small_sign, v.sign), zero_sign=v.zero_sign,
               nan=v.nan, inf=v.inf, inf_sign=v.inf_sign)
        # -- count the leading zeros ---------------------------------------------------------
        v = st(s=v.s, lz=lzc(m, v.s), exp=v.exp, sign=v.sign, zero_sign=v.zero_sign,
               nan=v.nan, inf=v.inf, inf_sign=v.inf_sign)
        # -- normalize: leading one to the MSB; the sum's bit n is one binade above big's ----
        # hidden bit (bit n-1, exponent big_exp)
        lz = v.lz
        norm = (v.s << lz)[:n + 1]
        exp = v.exp + 1 - lz                                  # signed, wide enough
        sign = Mux(v.s == 0, v.zero_sign, v.sign)             # exact zero: -0 only for -0 + -0
        v = st(sig=norm, exp=exp, sign=sign, nan=v.nan, inf=v.inf, inf_sign=v.inf_sign)
        # -- round: RNE increment, flags for both outcomes of its carry -----------------------
        v = st(**round_inc(m, fmt, v.exp, v.sig), sign=v.sign, nan=v.nan, inf=v.inf,
               inf_sign=v.inf_sign)
        # -- pack, specials ------------------------------------------------------------------
        o = Mux(v.nan, canonical_nan(fmt),
                Mux(v.inf, special(fmt, v.inf_sign, True), pack(fmt, v.sign, v)))
        v = st(o=o)
        st.finish()
        m.d.comb += [self.o.eq(v.o), self.o_valid.eq(st.valid)]
        return m
