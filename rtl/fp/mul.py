"""Floating-point multiplier, bit-exact with ``FPFormat.mul``."""
from __future__ import annotations

from collections.abc import Sequence

from amaranth.hdl import C, Cat, Module, Mux
from amaranth.lib import wiring
from amaranth.lib.wiring import In

from model.fp import BINARY32, FPFormat
from .common import canonical_nan, exp_flags, pack, round_sig, special, unpack
from .dsp import DSP_WIDTH, RegMul
from .pipe import Stager, check_regs, placement, unit_ports

__all__ = ["FPMul"]

DSP_BITS = 18      # operand width of one ECP5 MULT18X18D


def _carry_save_partials(ll, lh, hl, hh, h: int, width: int):
    """``ll + ((lh + hl) << h) + (hh << 2h)`` in ``width`` bits, in carry-save form: ``(low,
    s, c)`` with the sum ``Cat(low, s + c)`` (:func:`_add_carry_save`).

    ``ll`` < 2**2h, so ``ll + (hh << 2h)`` is their concatenation; its bits from ``h`` up and
    the two middle products are three addends, reduced to two by one level of full adders
    (sum and carry bits, a LUT each) before the one carry-propagate add. The path out of the
    multipliers' output registers (a long wire from the DSP row) then meets one LUT and one
    carry chain, not three chains in a row.
    """
    x = Cat(ll, hh)[h:width]
    n = width - h
    s_bits, c_bits = [], []
    for i in range(n):
        yi = lh[i] if i < len(lh) else C(0, 1)
        zi = hl[i] if i < len(hl) else C(0, 1)
        s_bits.append(x[i] ^ yi ^ zi)
        c_bits.append((x[i] & yi) | (x[i] & zi) | (yi & zi))
    return ll[:h], Cat(*s_bits), Cat(C(0, 1), *c_bits[:-1])


def _add_carry_save(low, s, c):
    """The sum of :func:`_carry_save_partials`' form: one carry-propagate add."""
    return Cat(low, (s + c)[:len(s)])


class FPMul(wiring.Component):
    """``o = a * b`` in format ``fmt``.

    Steps: unpack (classes, sign, exponent sum), partial products (significands split at
    ``dsp_bits`` = 18 bits, one ECP5 MULT18X18D each), their sum (the (M+1)×(M+1)-bit
    product), normalize (the product is in [1, 4): at most a one-bit shift), round (the RNE
    increment), pack (exponent carry, flush/overflow and special-value select). Without a
    register after the partial products the product is one ``*`` (Yosys splits it the same way).

    Latency: ``latency`` cycles (default 3; 0 = combinational), registers placed at the 7 step
    boundaries (input, after unpack, after the partial products, after multiply, after
    normalize, after round, output) by ``regs`` or, by default, output first, then after
    multiply, after unpack, after round, after the partial products, after normalize, input
    (latencies 1-3 place them as before the round and partial boundaries existed). With the
    partial products in DSP registers and the normalize boundary registered (latency 6 and up
    by default), the multiply register holds the product's sum in carry-save form and its
    carry-propagate add joins the normalize stage.
    Throughput: one operation per cycle in which ``en`` is 1; ``en`` = 0 holds every register.

    Ports: ``a``, ``b``, ``i_valid``, ``en`` in; ``o``, ``o_valid`` out.
    """

    BOUNDARIES = ("input", "unpack", "partial", "multiply", "normalize", "round", "output")
    ORDER = (6, 3, 1, 5, 2, 4, 0)

    def __init__(self, fmt: FPFormat = BINARY32, latency: int = 3, regs: Sequence[int] | None = None,
                 dsp_bits: int = DSP_BITS):
        if not isinstance(dsp_bits, int) or dsp_bits < 1:
            raise ValueError(f"FPMul: dsp_bits={dsp_bits!r} must be an integer >= 1 (18 for "
                             "the ECP5's MULT18X18D)")
        self.fmt, self.dsp_bits = fmt, dsp_bits
        nb = len(self.BOUNDARIES)
        self.regs = (placement(latency, nb, self.ORDER) if regs is None
                     else check_regs(regs, nb, "FPMul", self.BOUNDARIES))
        self.latency = sum(self.regs)
        super().__init__(unit_ports(fmt.width, fmt.width, b=In(fmt.width)))

    def elaborate(self, platform):
        m = Module()
        fmt = self.fmt
        W = fmt.frac_bits + 1
        st = Stager(m, self.en, self.i_valid, self.regs)

        v = st(a=self.a, b=self.b)
        # -- unpack --------------------------------------------------------------------------
        ua, ub = unpack(fmt, v.a), unpack(fmt, v.b)
        zero = ua.zero | ub.zero
        inf = ua.inf | ub.inf
        H = self.dsp_bits
        # one register after unpack and one after the partial products: those registers are
        # the partial multipliers' own (RegMul: a MULT18X18D's input and output registers on
        # the ECP5), so no fabric wire lies between a register and a multiplier array
        in_dsp = (self.regs[1] == 1 and self.regs[2] == 1 and H < W <= 2 * H
                  and H <= DSP_WIDTH)
        flags = dict(exp=ua.exp + ub.exp - fmt.bias, sign=ua.sign ^ ub.sign,
                     nan=ua.nan | ub.nan | (zero & inf), inf=inf, zero=zero)
        # the significands with their hidden bit, not cleared for a zero (or flushed denormal)
        # operand: that product is never used (the zero flag selects the result), and no
        # clear stands between the operand and the multiplier's input register
        sa, sb = Cat(ua.frac, C(1, 1)), Cat(ub.frac, C(1, 1))
        if in_dsp:
            # the classes go into the unpack register in pieces (exponent all ones or zero,
            # fraction not zero, per operand) and are combined after it, beside the
            # multipliers: one operand may feed many units, and its wires are long
            v = st(exp=flags["exp"], sign=flags["sign"],
                   **{f"{n}_{k}": x for n, u in (("a", ua), ("b", ub)) for k, x in
                      (("top", u.exp == (1 << fmt.exp_bits) - 1), ("zero", u.zero),
                       ("fnz", u.frac != 0))})
            zero, top_a, top_b = v.a_zero | v.b_zero, v.a_top, v.b_top
            inf = (top_a & ~v.a_fnz) | (top_b & ~v.b_fnz)
            v.nan = (top_a & v.a_fnz) | (top_b & v.b_fnz) | (zero & inf)
            v.inf, v.zero = inf, zero
        else:
            v = st(sa=sa, sb=sb, **flags)
        # -- multiply: 2W-bit product in [2**(2W-2), 2**(2W)) -------------------------------
        flags = dict(sign=v.sign, nan=v.nan, inf=v.inf, zero=v.zero)
        if in_dsp:
            parts = {}
            for name, (x, y) in dict(ll=(sa[:H], sb[:H]), lh=(sa[:H], sb[H:]),
                                     hl=(sa[H:], sb[:H]), hh=(sa[H:], sb[H:])).items():
                mul = m.submodules[f"dsp_{name}"] = RegMul(len(x), len(y))
                m.d.comb += [mul.a.eq(x), mul.b.eq(y), mul.en.eq(self.en)]
                parts[name] = mul.p
            v = st(exp=v.exp, **flags)
            csa = _carry_save_partials(parts["ll"], parts["lh"], parts["hl"], parts["hh"], H,
                                       2 * W)
            p = _add_carry_save(*csa)
        elif self.regs[2] and W > H:       # partial products registered, summed next stage
            al, ah, bl, bh = v.sa[:H], v.sa[H:], v.sb[:H], v.sb[H:]
            v = st(ll=al * bl, lh=al * bh, hl=ah * bl, hh=ah * bh, exp=v.exp, **flags)
            p = v.ll + ((v.lh + v.hl) << H) + (v.hh << (2 * H))
        else:
            v = st(p=v.sa * v.sb, exp=v.exp, **flags)
            p = v.p
        # the rounding's exponent flags for both normalizations (exp, exp + 1), formed here
        # beside the product's sum, so the round stage only selects them
        ef = exp_flags(fmt, v.exp)
        fl = dict(sign=v.sign, nan=v.nan, inf=v.inf, zero=v.zero,
                  **{f"n0_{k}": x for k, x in ef.items()},
                  **{f"n1_{k}": x for k, x in exp_flags(fmt, v.exp + 1).items()})
        if in_dsp and self.regs[4]:
            # the normalize boundary registered too: the multiply register holds the sum in
            # carry-save form (the DSP outputs meet one LUT level), the carry-propagate add
            # runs in the normalize stage
            v = st(lo=csa[0], s=csa[1], c=csa[2], **fl)
            p = _add_carry_save(v.lo, v.s, v.c)
        else:
            v = st(p=p[:2 * W], **fl)
            p = v.p
        # -- normalize: the MSB has exponent exp + 1 ------------------------------------------
        # the normalized product's top W + 1 bits (the kept significand and the guard bit) and
        # whether any bit below them is set (its low bits leave the sum's carry chain first),
        # so the round stage is the increment alone
        top = p[2 * W - 1]
        sig = Mux(top, p, p << 1)[:2 * W]
        v = st(sig=sig[W - 1:], rest=Mux(top, p[:W - 1] != 0, p[:W - 2] != 0),
               sign=v.sign, nan=v.nan, inf=v.inf, zero=v.zero,
               **{k: Mux(top, getattr(v, f"n1_{k}"), getattr(v, f"n0_{k}")) for k in ef})
        # -- round: RNE increment (round_inc's significand half; its exponent half above) -----
        v = st(**round_sig(m, fmt, v.sig, sticky=v.rest), **{k: getattr(v, k) for k in ef},
               sign=v.sign, nan=v.nan, inf=v.inf, zero=v.zero)
        # -- pack, specials ------------------------------------------------------------------
        o = Mux(v.nan, canonical_nan(fmt),
                Mux(v.inf, special(fmt, v.sign, True),
                    Mux(v.zero, special(fmt, v.sign, False), pack(fmt, v.sign, v))))
        v = st(o=o)
        st.finish()
        m.d.comb += [self.o.eq(v.o), self.o_valid.eq(st.valid)]
        return m
