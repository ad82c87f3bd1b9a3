"""Floating-point multiplier, bit-exact with ``FPFormat.mul``."""
from __future__ import annotations

from collections.abc import Sequence

from amaranth.hdl import Module, Mux
from amaranth.lib import wiring
from amaranth.lib.wiring import In

from model.fp import BINARY32, FPFormat
from .common import canonical_nan, round_pack, special, unpack
from .pipe import Stager, check_regs, placement, unit_ports

__all__ = ["FPMul"]


class FPMul(wiring.Component):
    """``o = a * b`` in format ``fmt``.

    Steps: unpack (classes, sign, exponent sum), multiply the (M+1)-bit significands,
    normalize (the product is in [1, 4): at most a one-bit shift), round and pack.

    Latency: ``latency`` cycles (default 3; 0 = combinational), registers placed at the 5 step
    boundaries (input, after unpack, after multiply, after normalize, output) by ``regs`` or,
    by default, output first, then after multiply, after unpack, after normalize, input.
    Throughput: one operation per cycle in which ``en`` is 1; ``en`` = 0 holds every register.

    Ports: ``a``, ``b``, ``i_valid``, ``en`` in; ``o``, ``o_valid`` out.
    """

    BOUNDARIES = ("input", "unpack", "multiply", "normalize", "output")
    ORDER = (4, 2, 1, 3, 0)

    def __init__(self, fmt: FPFormat = BINARY32, latency: int = 3, regs: Sequence[int] | None = None):
        self.fmt = fmt
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
        v = st(sa=ua.sig, sb=ub.sig, exp=ua.exp + ub.exp - fmt.bias, sign=ua.sign ^ ub.sign,
               nan=ua.nan | ub.nan | (zero & inf), inf=inf, zero=zero)
        # -- multiply: 2W-bit product in [2**(2W-2), 2**(2W)) -------------------------------
        v = st(p=v.sa * v.sb, exp=v.exp, sign=v.sign, nan=v.nan, inf=v.inf, zero=v.zero)
        # -- normalize: the MSB has exponent exp + 1 ------------------------------------------
        top = v.p[2 * W - 1]
        v = st(sig=Mux(top, v.p, v.p << 1)[:2 * W], exp=v.exp + top, sign=v.sign,
               nan=v.nan, inf=v.inf, zero=v.zero)
        # -- round, pack, specials -----------------------------------------------------------
        o = Mux(v.nan, canonical_nan(fmt),
                Mux(v.inf, special(fmt, v.sign, True),
                    Mux(v.zero, special(fmt, v.sign, False),
                        round_pack(m, fmt, v.sign, v.exp, v.sig))))
        v = st(o=o)
        st.finish()
        m.d.comb += [self.o.eq(v.o), self.o_valid.eq(st.valid)]
        return m
