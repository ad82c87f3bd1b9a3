"""Generic staging for fixed-latency pipelines: the flow control every FP unit shares.

A unit is written as a sequence of arithmetic *steps* (plain functions from Amaranth values to
Amaranth values). Between two steps, and before the first and after the last, lies a
*boundary*; a unit with ``S`` steps has ``S + 1`` boundaries. :class:`Stager` puts zero or
more registers at each boundary, all enabled by one clock enable, and carries the valid bit
alongside the data. The unit's latency is the total number of registers; its throughput is
one operation per enabled cycle. With no register anywhere the unit is combinational.
"""
from __future__ import annotations

from collections.abc import Sequence
from types import SimpleNamespace

from amaranth.hdl import Module, Signal, Value

__all__ = ["Stager", "placement"]


def placement(latency: int, n_boundaries: int, order: Sequence[int] | None = None) -> tuple[int, ...]:
    """Registers per boundary for a total ``latency``.

    ``order`` lists boundaries by priority (the first gets the first register, ...; past the
    end it starts again). Without it the registers are spread evenly, the last one at the
    output boundary.
    """
    if not isinstance(latency, int) or latency < 0:
        raise ValueError(f"latency={latency!r}: must be an integer >= 0 (0 = combinational)")
    counts = [0] * n_boundaries
    if order is None:
        inner = n_boundaries - 1
        for i in range(latency):
            pos = round((i + 1) * inner / latency) if latency <= inner else min(i + 1, inner)
            counts[pos] += 1
    else:
        for i in range(latency):
            counts[order[i % len(order)]] += 1
    return tuple(counts)


def check_regs(regs: Sequence[int], n_boundaries: int, unit: str, names: Sequence[str]) -> tuple[int, ...]:
    """Validate a user-given register placement (one count per boundary)."""
    regs = tuple(regs)
    if len(regs) != n_boundaries or any((not isinstance(r, int)) or r < 0 for r in regs):
        raise ValueError(f"{unit}: regs={regs!r} must give a register count >= 0 for each of the "
                         f"{n_boundaries} boundaries ({', '.join(names)})")
    return regs


def digit_regs(unit: str, qbits: int, latency: int | None, regs: Sequence[int] | None
               ) -> tuple[tuple[str, ...], tuple[int, ...]]:
    """Boundaries and register placement of a digit-recurrence unit (divider, square root):
    boundaries input, unpack, one after each of ``qbits`` result bits, round, output. Default
    latency ``ceil(qbits/4) + 1`` (four result bits a stage plus the output register); up to
    it the registers are spread evenly over every boundary but "round", above it one goes
    after round and the rest are spread that way. ``regs`` (one count per boundary) overrides.
    Returns (boundary names, registers per boundary)."""
    names = ("input", "unpack", *(f"q{i}" for i in range(qbits)), "round", "output")
    nb = len(names)
    if regs is not None:
        return names, check_regs(regs, nb, unit, names)
    default = -(-qbits // 4) + 1
    if latency is None:
        latency = default
    cut = isinstance(latency, int) and latency > default
    spread = placement(latency - cut, nb - 1)             # over every boundary but "round"
    return names, spread[:-1] + ((spread[-1], 1) if cut else (0, spread[-1]))


class Stager:
    """Places registers at a unit's boundaries, in order, as the unit's steps are built.

    ``st = Stager(m, en, i_valid, regs)``; each call ``v = st(name=value, ...)`` crosses the
    next boundary: it returns a namespace with the same names, registered ``regs[k]`` times
    (each register loads when ``en`` is 1 and holds otherwise), and ``st.valid`` is the valid
    bit at that point. Data registers have no reset; valid registers reset to 0. A boundary
    without registers still names its values (combinational wires).
    """

    def __init__(self, m: Module, en: Value, valid: Value, regs: Sequence[int], prefix: str = "p"):
        self.m, self.en, self.regs, self.prefix = m, en, tuple(regs), prefix
        self.valid = valid
        self.k = 0

    def __call__(self, **values) -> SimpleNamespace:
        if self.k >= len(self.regs):
            raise RuntimeError(f"unit crossed more than its {len(self.regs)} boundaries")
        cur = {name: Value.cast(v) for name, v in values.items()}
        valid = self.valid
        if self.regs[self.k] == 0:
            # a named wire: keeps the next step's expressions small (the simulator inlines
            # expressions, so long combinational chains would otherwise grow exponentially)
            wires = {name: Signal.like(v, name=f"{self.prefix}{self.k}_{name}")
                     for name, v in cur.items()}
            self.m.d.comb += [wires[name].eq(cur[name]) for name in cur]
            cur = wires
        for r in range(self.regs[self.k]):
            tag = f"{self.prefix}{self.k}_{r}"
            nxt = {name: Signal.like(v, name=f"{tag}_{name}", reset_less=True)
                   for name, v in cur.items()}
            nvalid = Signal(name=f"{tag}_valid", init=0)
            with self.m.If(self.en):
                self.m.d.sync += [nxt[name].eq(cur[name]) for name in cur]
                self.m.d.sync += nvalid.eq(valid)
            cur, valid = nxt, nvalid
        self.valid = valid
        self.k += 1
        return SimpleNamespace(**cur)

    def finish(self) -> None:
        if self.k != len(self.regs):
            raise RuntimeError(f"unit crossed {self.k} of its {len(self.regs)} boundaries")


def unit_ports(a_width: int, o_shape, **extra) -> dict:
    """The ports every pipelined FP unit has: operand(s), ``i_valid``, ``en`` (stall: 0 holds
    every register; defaults to 1), result ``o`` and ``o_valid``; ``extra`` adds inputs such as
    a second operand ``b`` or an ``op`` select. Pass to ``wiring.Component.__init__``."""
    from amaranth.lib.wiring import In, Out
    return {"a": In(a_width), **extra, "i_valid": In(1), "en": In(1, init=1),
            "o": Out(o_shape), "o_valid": Out(1)}
