"""Fixed-latency datapaths built from the FP units: :class:`Schedule`.

A datapath (the intersection test, ray setup, eye-ray generation) is written as a sequence of
FP operations on ``(value, ready cycle)`` pairs; :class:`Schedule` instantiates one pipelined FP
unit per operation, starts it in the cycle its latest operand is ready and brings the other
operands to that cycle through delay registers (shared: a value delayed to cycle t is one
register chain however many operations read it). Every register loads when ``en`` is 1 and
holds otherwise, so the whole datapath stalls as one.
"""
from __future__ import annotations

from amaranth.hdl import Const, Module, Signal, Value

from model.fp import FPFormat

from .add import FPAdd
from .cmp import FPMinMax
from .div import FPDiv
from .mul import FPMul
from .sqrt import FPSqrt

__all__ = ["Schedule"]


class Schedule:
    """Builds a fixed-latency datapath: each value carries the cycle it is ready in; an
    operation waits for its latest operand, the others go through (shared) delay registers.

    ``latencies``: ``{kind: cycles}`` for the kinds used (:meth:`default_latencies` fills in
    the units' defaults). ``dry=True`` instantiates nothing and only computes ready cycles (to
    learn a datapath's latency before building it)."""

    UNITS = {"add": FPAdd, "sub": FPAdd, "mul": FPMul, "div": FPDiv, "sqrt": FPSqrt,
             "min": FPMinMax, "max": FPMinMax}

    def __init__(self, m: Module, en: Value, fmt: FPFormat, latencies: dict, dry: bool = False):
        self.m, self.en, self.fmt, self.lat, self.dry = m, en, fmt, latencies, dry
        self.taps: dict[int, list[Signal]] = {}
        self.n = 0

    @classmethod
    def default_latencies(cls, fmt: FPFormat, latencies: dict | None = None) -> dict:
        """``latencies`` (``{"add": n, "mul": n, "div": n, "sqrt": n, "minmax": n}``, any missing
        or None)
        completed with each unit's default latency, as ``{kind: n}`` for every kind of
        :attr:`UNITS` (sub = add, min = max = minmax)."""
        given = dict(latencies or {})
        out = {}
        for kind, unit in (("add", FPAdd), ("mul", FPMul), ("div", FPDiv), ("sqrt", FPSqrt),
                           ("minmax", FPMinMax)):
            if given.get(kind) is None:
                probe = unit(fmt)                           # the unit's default latency
                probe._MustUse__silence = True
                out[kind] = probe.latency
            else:
                out[kind] = given[kind]
        out["sub"] = out["add"]
        out["min"] = out["max"] = out.pop("minmax")
        return out

    def at(self, value, t0: int, t: int) -> Value:
        """``value`` (ready at cycle ``t0``) as seen at cycle ``t >= t0``."""
        value = Value.cast(value)
        if isinstance(value, Const) or t == t0:
            return value
        assert t > t0, f"value ready at cycle {t0} read at cycle {t}"
        chain = self.taps.setdefault(id(value), [value])     # chain[0] keeps id() unique
        while len(chain) <= t - t0:
            prev = chain[-1]
            reg = Signal.like(prev, name=f"dly{self.n}", reset_less=True)
            self.n += 1
            with self.m.If(self.en):
                self.m.d.sync += reg.eq(prev)
            chain.append(reg)
        return chain[t - t0]

    def op(self, kind: str, a: tuple, b: tuple | None, name: str) -> tuple:
        """``(value, ready cycle)`` of ``a kind b`` (``sqrt``: of ``a``, ``b`` is None);
        operands are ``(value, ready cycle)``."""
        t = a[1] if b is None else max(a[1], b[1])
        out = Signal(self.fmt.width, name=name)
        if self.dry:
            return out, t + self.lat[kind]
        unit = self.UNITS[kind](self.fmt, latency=self.lat[kind])
        assert unit.latency == self.lat[kind]
        self.m.submodules[name] = unit
        self.m.d.comb += [unit.a.eq(self.at(a[0], a[1], t)), unit.en.eq(self.en)]
        if b is not None:
            self.m.d.comb += unit.b.eq(self.at(b[0], b[1], t))
        if kind in ("add", "sub"):
            self.m.d.comb += unit.op.eq(kind == "sub")
        elif kind in ("min", "max"):
            self.m.d.comb += unit.op.eq(kind == "max")
        self.m.d.comb += out.eq(unit.o)
        return out, t + unit.latency
