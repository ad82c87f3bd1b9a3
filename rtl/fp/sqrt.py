"""Floating-point square root (correctly rounded), bit-exact with ``FPFormat.sqrt``."""
from __future__ import annotations

from collections.abc import Sequence

from amaranth.hdl import C, Cat, Module, Mux
from amaranth.lib import wiring

from model.fp import BINARY32, FPFormat
from .common import canonical_nan, pack, round_inc, special, unpack
from .pipe import Stager, digit_regs, unit_ports

__all__ = ["FPSqrt"]


class FPSqrt(wiring.Component):
    """``o = sqrt(a)`` in format ``fmt``, correctly rounded (the RGS slave's vector lengths).

    Steps: unpack (classes; an odd exponent shifts the significand one bit left, so the root's
    exponent is half an even one), M+2 restoring square-root steps of one root bit each (the
    radicand's significand lies in [1, 4), its root in [1, 2): M+2 bits give the M+1
    significant bits and a guard bit, the remainder is the sticky bit; no normalization), then
    round (the RNE increment) and pack. NaN for a NaN or a number below zero (-inf too), ±0
    for ±0 (a denormal encoding reads as a signed zero), +inf for +inf; the exponent halves,
    so nothing flushes or overflows.

    Latency: ``latency`` cycles (default ``ceil((M+2)/4) + 1``: four root bits per stage plus
    the output register, 8 at binary32; 0 = combinational). Registers sit at the M+5 step
    boundaries (input, after unpack, after each root bit, after round, output), given per
    boundary by ``regs`` or placed by ``latency`` as ``FPDiv`` places them.
    Throughput: one operation per cycle in which ``en`` is 1.

    Ports: ``a``, ``i_valid``, ``en`` in; ``o``, ``o_valid`` out.
    """

    def __init__(self, fmt: FPFormat = BINARY32, latency: int | None = None,
                 regs: Sequence[int] | None = None):
        self.fmt = fmt
        self.qbits = fmt.frac_bits + 2
        self.BOUNDARIES, self.regs = digit_regs("FPSqrt", self.qbits, latency, regs)
        self.latency = sum(self.regs)
        super().__init__(unit_ports(fmt.width, fmt.width))

    def elaborate(self, platform):
        m = Module()
        fmt = self.fmt
        M = fmt.frac_bits
        st = Stager(m, self.en, self.i_valid, self.regs)

        v = st(a=self.a)
        # -- unpack ----------------------------------------------------------------------------
        u = unpack(fmt, v.a)
        nan = u.nan | (u.sign & ~u.zero)
        # the bias 2**(E-1) - 1 is odd: the unbiased exponent is odd when the biased one is even
        odd = ~u.exp[0]
        rad = Mux(odd, u.sig << 1, u.sig)[:M + 2]          # significand in [1, 4) * 2**M
        XW = M + 2 + (M % 2)                                # radicand bits, consumed two a step
        RW = M + 5                                          # remainder <= 2 * root < 2**(M+3)
        # exponent of the root: (exp - bias - odd) / 2 + bias = (exp + bias - odd) / 2
        rexp = (u.exp + (fmt.bias - 1) + ~odd)[1:]
        v = st(x=Cat(C(0, XW - (M + 2)), rad), r=C(0, RW), q=Cat(), exp=rexp, sign=u.sign,
               nan=nan, inf=u.inf & ~u.sign, zero=u.zero)
        # -- restoring square root: one root bit per step ----------------------------------------
        for _ in range(self.qbits):
            rem = Cat(v.x[XW - 2:XW], v.r)[:RW]             # 4 * r + the next two radicand bits
            trial = Cat(C(1, 2), v.q)                       # 4 * q + 1
            ge = rem >= trial
            v = st(x=(v.x << 2)[:XW], r=Mux(ge, rem - trial, rem)[:RW], q=Cat(ge, v.q),
                   exp=v.exp, sign=v.sign, nan=v.nan, inf=v.inf, zero=v.zero)
        # -- round, pack, specials ---------------------------------------------------------------
        v = st(**round_inc(m, fmt, v.exp, v.q, sticky=v.r != 0), sign=v.sign, nan=v.nan,
               inf=v.inf, zero=v.zero)
        o = Mux(v.nan, canonical_nan(fmt),
                Mux(v.inf, special(fmt, C(0, 1), True),
                    Mux(v.zero, special(fmt, v.sign, False), pack(fmt, C(0, 1), v))))
        v = st(o=o)
        st.finish()
        m.d.comb += [self.o.eq(v.o), self.o_valid.eq(st.valid)]
        return m
