"""Floating-point divider (correctly rounded), bit-exact with ``FPFormat.div``."""
from __future__ import annotations

from collections.abc import Sequence

from amaranth.hdl import Cat, Module, Mux
from amaranth.lib import wiring
from amaranth.lib.wiring import In

from model.fp import BINARY32, FPFormat
from .common import canonical_nan, pack, round_inc, special, unpack
from .pipe import Stager, digit_regs, unit_ports

__all__ = ["FPDiv"]


class FPDiv(wiring.Component):
    """``o = a / b`` in format ``fmt``, correctly rounded (so ``a = 1`` gives an exact-rounded
    reciprocal; the intersection unit's ``1/det``).

    Steps: unpack (classes, sign, exponent difference), M+3 restoring-division steps of one
    quotient bit each (W = M+1 significand bits: the quotient of two significands lies in
    (1/2, 2), so M+3 bits give W significant bits and a guard bit; the remainder is the sticky
    bit, formed in the last step's stage), then round (a one-bit normalization and the RNE
    increment) and pack (exponent carry, flush/overflow and special-value select).

    Latency: ``latency`` cycles (default ``ceil((M+3)/4) + 1``: four quotient bits per stage
    plus the output register; 0 = combinational). Registers sit at the M+6 step boundaries
    (input, after unpack, after each quotient bit, after round, output), given per boundary by
    ``regs`` or placed by ``latency``: up to the default latency they are spread evenly over
    the boundaries other than "after round" (as before that boundary existed); above it one
    register goes after round and the other ``latency - 1`` are spread that way.
    Throughput: one operation per cycle in which ``en`` is 1.

    Ports: ``a``, ``b``, ``i_valid``, ``en`` in; ``o``, ``o_valid`` out.
    """

    def __init__(self, fmt: FPFormat = BINARY32, latency: int | None = None,
                 regs: Sequence[int] | None = None):
        self.fmt = fmt
        self.qbits = fmt.frac_bits + 3
        self.BOUNDARIES, self.regs = digit_regs("FPDiv", self.qbits, latency, regs)
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
        nan = ua.nan | ub.nan | (ua.zero & ub.zero) | (ua.inf & ub.inf)
        inf = ua.inf | ub.zero
        zero = ua.zero | ub.inf
        # exponent of the quotient's first bit (weight 2**0 of sa/sb); one more step in below
        v = st(r=ua.sig, d=ub.sig, q=Cat(), exp=ua.exp - ub.exp + fmt.bias,
               sign=ua.sign ^ ub.sign, nan=nan, inf=inf, zero=zero)
        # -- restoring division: r < 2d holds throughout; one quotient bit per step -----------
        for i in range(self.qbits):
            r = v.r
            ge = r >= v.d
            q = Cat(ge, v.q)                                  # new bit at the LSB
            if i < self.qbits - 1:
                rem = Mux(ge, r - v.d, r)[:W]                 # < d < 2**W
                v = st(r=Cat(0, rem), d=v.d, q=q, exp=v.exp, sign=v.sign, nan=v.nan,
                       inf=v.inf, zero=v.zero)                # next partial remainder 2*rem
            else:
                # the last step keeps only the sticky bit (final remainder != 0), formed beside
                # the subtract rather than after it: r - d != 0 is r != d
                v = st(r=Mux(ge, r != v.d, r != 0), q=q, exp=v.exp, sign=v.sign, nan=v.nan,
                       inf=v.inf, zero=v.zero)
        # -- normalize, round, pack, specials -------------------------------------------------
        # q = floor(sa/sb * 2**(M+2)), in [2**(M+1), 2**(M+3)): leading bit M+2 or M+1
        top = v.q[self.qbits - 1]
        sig = Mux(top, v.q, v.q << 1)[:self.qbits]
        exp = v.exp - 1 + top
        v = st(**round_inc(m, fmt, exp, sig, sticky=v.r), sign=v.sign, nan=v.nan,
               inf=v.inf, zero=v.zero)
        o = Mux(v.nan, canonical_nan(fmt),
                Mux(v.inf, special(fmt, v.sign, True),
                    Mux(v.zero, special(fmt, v.sign, False), pack(fmt, v.sign, v))))
        v = st(o=o)
        st.finish()
        m.d.comb += [self.o.eq(v.o), self.o_valid.eq(st.valid)]
        return m
