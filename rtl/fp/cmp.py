"""Floating-point compare (lt/le/eq) and min/max, bit-exact with ``FPFormat.lt/le/eq/min/max``."""
from __future__ import annotations

from collections.abc import Sequence
from types import SimpleNamespace

from amaranth.hdl import Cat, Module, Mux, Value
from amaranth.lib import data, wiring
from amaranth.lib.wiring import In, Out

from model.fp import BINARY32, FPFormat
from .common import canonical_nan, special, unpack
from .pipe import Stager, check_regs, placement, unit_ports

__all__ = ["FPCompare", "FPMinMax", "CompareLayout"]

CompareLayout = data.StructLayout({"lt": 1, "le": 1, "equal": 1})


def compare(fmt: FPFormat, a: Value, b: Value) -> SimpleNamespace:
    """IEEE order of two encodings (denormals read as zero): ``-0 == +0``, NaN unordered."""
    ua, ub = unpack(fmt, a), unpack(fmt, b)
    # sign-magnitude order on the magnitudes (exponent:fraction, denormals read as zero): one
    # comparator on the raw bits, started at once; a zero exponent field (zero or denormal)
    # is settled beside it: two such are equal, one is below any other magnitude
    E, M = fmt.exp_bits, fmt.frac_bits
    ra, rb = Value.cast(a)[:E + M], Value.cast(b)[:E + M]
    za, zb = ua.zero, ub.zero
    mlt = Mux(za | zb, za & ~zb, ra < rb)
    meq = Mux(za | zb, za & zb, ra == rb)
    mgt = ~mlt & ~meq
    ordered = ~ua.nan & ~ub.nan
    zeros = ua.zero & ub.zero
    diff = ua.sign ^ ub.sign
    eq = ordered & (zeros | (meq & ~diff))
    lt = ordered & ~zeros & Mux(diff, ua.sign, Mux(ua.sign, mgt, mlt))
    gt = ordered & ~zeros & Mux(diff, ub.sign, Mux(ua.sign, mlt, mgt))
    return SimpleNamespace(lt=lt, eq=eq, le=lt | eq, gt=gt, ua=ua, ub=ub)


def canonical(fmt: FPFormat, u: SimpleNamespace, x: Value) -> Value:
    """An operand as the hardware reads it: NaN canonical, denormal encodings signed zero."""
    return Mux(u.nan, canonical_nan(fmt), Mux(u.zero, special(fmt, u.sign, False), x))


class _Unit(wiring.Component):
    BOUNDARIES = ("input", "output")
    ORDER = (1, 0)

    def __init__(self, fmt, latency, regs, out_shape, extra):
        self.fmt = fmt
        nb = len(self.BOUNDARIES)
        self.regs = (placement(latency, nb, self.ORDER) if regs is None
                     else check_regs(regs, nb, type(self).__name__, self.BOUNDARIES))
        self.latency = sum(self.regs)
        super().__init__(unit_ports(fmt.width, out_shape, b=In(fmt.width), **extra))


class FPCompare(_Unit):
    """``o.lt = a < b``, ``o.le = a <= b``, ``o.equal = a == b`` (IEEE: ``-0 == +0``; every
    comparison with a NaN is false; denormal encodings read as zero).

    Latency: ``latency`` cycles (default 1: registered output; 0 = combinational), registers at
    the input and output boundaries by ``regs``. Throughput: one per cycle in which ``en`` is 1.
    """

    def __init__(self, fmt: FPFormat = BINARY32, latency: int = 1, regs: Sequence[int] | None = None):
        super().__init__(fmt, latency, regs, CompareLayout, {})

    def elaborate(self, platform):
        m = Module()
        st = Stager(m, self.en, self.i_valid, self.regs)
        v = st(a=self.a, b=self.b)
        c = compare(self.fmt, v.a, v.b)
        v = st(o=Cat(c.lt, c.le, c.eq))
        st.finish()
        m.d.comb += [self.o.as_value().eq(v.o), self.o_valid.eq(st.valid)]
        return m


class FPMinMax(_Unit):
    """``o = min(a, b)`` (``op`` = 0) or ``max(a, b)`` (``op`` = 1) by the model's rule:
    ``min = b if b < a or a is NaN else a`` (``max``: ``b > a``), so a NaN is ignored when the
    other operand is a number and of ``+0``/``-0`` the first is returned; NaN out is canonical
    and a denormal operand comes out as signed zero. Beside ``o``: ``lt`` = ``a < b`` and
    ``gt`` = ``a > b`` (:class:`FPCompare`'s order), from the comparator the choice uses, so a
    datapath that needs both a comparison and the min or max of the same operands spends one
    comparator (the traversal's interval clipping).

    Latency: ``latency`` cycles (default 1; 0 = combinational), registers at the input,
    after-compare and output boundaries by ``regs`` or, by default, output first, then input,
    then after the compare (so latencies 1 and 2 place them as before the compare boundary
    existed). Throughput: one per cycle in which ``en`` is 1.
    """

    BOUNDARIES = ("input", "compare", "output")
    ORDER = (2, 0, 1)

    def __init__(self, fmt: FPFormat = BINARY32, latency: int = 1, regs: Sequence[int] | None = None):
        super().__init__(fmt, latency, regs, fmt.width,
                         {"op": In(1), "lt": Out(1), "gt": Out(1)})

    def elaborate(self, platform):
        m = Module()
        st = Stager(m, self.en, self.i_valid, self.regs)
        v = st(a=self.a, b=self.b, op=self.op)
        c = compare(self.fmt, v.a, v.b)
        v = st(take_b=Mux(v.op, c.lt, c.gt) | c.ua.nan,    # max: b > a; min: b < a
               a=canonical(self.fmt, c.ua, v.a), b=canonical(self.fmt, c.ub, v.b),
               lt=c.lt, gt=c.gt)
        v = st(o=Mux(v.take_b, v.b, v.a), lt=v.lt, gt=v.gt)
        st.finish()
        m.d.comb += [self.o.eq(v.o), self.lt.eq(v.lt), self.gt.eq(v.gt),
                     self.o_valid.eq(st.valid)]
        return m

