"""Integer (fixed-point) to floating-point conversion, bit-exact with ``FPFormat.from_fixed``."""
from __future__ import annotations

from collections.abc import Sequence

from amaranth.hdl import C, Cat, Module, Mux
from amaranth.lib import wiring

from model.fp import BINARY32, FPFormat
from .common import lzc, round_pack
from .pipe import Stager, check_regs, placement, unit_ports

__all__ = ["FPFromInt"]


class FPFromInt(wiring.Component):
    """``o = a * 2**-frac_bits`` rounded once to ``fmt``, for an ``int_width``-bit integer ``a``
    (two's complement if ``signed``). Ray generation uses it for pixel coordinates: with
    ``frac_bits=1`` the input ``2*px + 1`` gives the pixel centre ``px + 0.5`` in one rounding.
    Zero gives +0; magnitudes beyond the format's range give signed infinity.

    Steps: sign and magnitude, normalize (leading-zero count and left shift), round and pack.
    Latency: ``latency`` cycles (default 2; 0 = combinational), registers at the 4 boundaries
    (input, after magnitude, after normalize, output) by ``regs`` or, by default, output first,
    then after magnitude, after normalize, input. Throughput: one per cycle in which ``en`` is 1.

    Ports: ``a``, ``i_valid``, ``en`` in; ``o``, ``o_valid`` out.
    """

    BOUNDARIES = ("input", "magnitude", "normalize", "output")
    ORDER = (3, 1, 2, 0)

    def __init__(self, fmt: FPFormat = BINARY32, int_width: int = 32, signed: bool = True,
                 frac_bits: int = 0, latency: int = 2, regs: Sequence[int] | None = None):
        if int_width < 2:
            raise ValueError(f"FPFromInt: int_width={int_width} must be >= 2")
        if not 0 <= frac_bits < 64:
            raise ValueError(f"FPFromInt: frac_bits={frac_bits} must be in 0..63")
        self.fmt, self.int_width, self.signed, self.frac_bits = fmt, int_width, signed, frac_bits
        nb = len(self.BOUNDARIES)
        self.regs = (placement(latency, nb, self.ORDER) if regs is None
                     else check_regs(regs, nb, "FPFromInt", self.BOUNDARIES))
        self.latency = sum(self.regs)
        super().__init__(unit_ports(int_width, fmt.width))

    def elaborate(self, platform):
        m = Module()
        fmt, w = self.fmt, self.int_width
        W = fmt.frac_bits + 1
        st = Stager(m, self.en, self.i_valid, self.regs)

        v = st(a=self.a)
        if self.signed:
            neg = v.a[w - 1]
            mag = Mux(neg, -v.a.as_signed(), v.a.as_signed()).as_unsigned()[:w]
        else:
            neg, mag = C(0, 1), v.a
        v = st(mag=mag, sign=neg)
        lz = lzc(m, v.mag)
        norm = (v.mag << lz)[:w]
        # the MSB of norm has weight 2**(w - 1 - frac_bits - lz)
        exp = fmt.bias + w - 1 - self.frac_bits - lz
        v = st(sig=norm, exp=exp, sign=v.sign)
        sig = Cat(C(0, W + 1 - w), v.sig) if w < W + 1 else v.sig
        v = st(o=round_pack(m, fmt, v.sign, v.exp, sig))
        st.finish()
        m.d.comb += [self.o.eq(v.o), self.o_valid.eq(st.valid)]
        return m
