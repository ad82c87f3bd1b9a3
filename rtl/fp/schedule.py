"""Fixed-latency datapaths built from the FP units: :class:`Schedule`.

A datapath (the intersection test, ray setup, eye-ray generation) is written as a sequence of
FP operations on ``(value, ready cycle)`` pairs; :class:`Schedule` instantiates one pipelined FP
unit per operation, starts it in the cycle its latest operand is ready and brings the other
operands to that cycle through delay registers (shared: a value delayed to cycle t is one
register chain however many operations read it). Every register loads when ``en`` is 1 and
holds otherwise, so the whole datapath stalls as one.

With ``latencies["delay_ram"] = n`` (``Config.delay_ram``, n >= 2) a delay of n or more cycles
is a ring buffer instead: a small memory written and read at one pointer that advances when
``en`` is 1, followed by one register (the ring holds n - 1 cycles, at most :data:`RING_MAX`
words; longer delays are rings in series), so the memory's read feeds only a flip-flop. It
gives every value in the same cycle as the register chain; on an FPGA the memory is LUT-RAM
(ECP5: ``TRELLIS_DPR16X4``, 16 x 4 bits) where the chain was ``n`` flip-flops per bit.

**Shared units** (``share``: :class:`Share`, an initiation interval ``ii`` and a unit count per
class): the datapath takes a new input only every ``ii``-th enabled cycle (a phase counter
advances with ``en``; inputs enter at phase 0, :meth:`Schedule.start`), and each FP unit
serves up to ``ii`` operations, one per phase (a modulo schedule). An operation starts at the
first cycle, from its latest operand's, at which some unit of its class has that cycle's phase
free; the unit's operands are multiplexed by the phase. Delays become strided: a value ready
at cycle t and read at t + d is held in ``ceil(d / ii)`` registers that all load at t's phase
(each holds a value for ``ii`` cycles), not in ``d``. The arithmetic and every result are the
same as with one unit per operation; the latency may grow where operations wait for a unit.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from math import ceil

from amaranth.hdl import Const, Module, Mux, Signal, Value
from amaranth.lib.memory import Memory

from model.fp import FPFormat

from .add import FPAdd
from .cmp import FPMinMax
from .div import FPDiv
from .mul import FPMul
from .sqrt import FPSqrt

__all__ = ["Schedule", "Share", "RING_MAX"]

RING_MAX = 16          # the deepest ring buffer (the depth of one LUT-RAM cell on the ECP5)

CLASS = {"add": "add", "sub": "add", "mul": "mul", "div": "div", "sqrt": "sqrt",
         "min": "minmax", "max": "minmax"}     # the unit class that performs each operation


@dataclass(frozen=True)
class Share:
    """Resource sharing of a :class:`Schedule`: a new input every ``ii`` enabled cycles,
    ``units[cls]`` FP units of each class (``add`` also subtracts, ``minmax`` takes min and
    max)."""
    ii: int
    units: dict = field(default_factory=dict)
    offset: int = 0        # phase 0 comes this many enabled cycles after reset's (mod ii)

    @classmethod
    def for_budget(cls, counts: dict, budget: dict, min_ii: int = 1,
                   offset: int = 0) -> "Share":
        """The smallest interval (at least ``min_ii``) at which a datapath with
        ``counts[cls]`` operations per class fits ``budget[cls]`` units of each budgeted class
        (the other classes get as many units as the interval needs): ``ii =
        max(ceil(counts / budget))``, ``units = ceil(counts / ii)``."""
        for c, n in budget.items():
            if c not in counts or n < 1:
                raise ValueError(f"FP unit budget {budget!r}: {c!r} must be one of "
                                 f"{sorted(counts)} with at least one unit")
        ii = max([min_ii] + [ceil(counts[c] / n) for c, n in budget.items() if counts[c]])
        return cls(ii, {c: ceil(n / ii) for c, n in counts.items() if n}, offset)


class Schedule:
    """Builds a fixed-latency datapath: each value carries the cycle it is ready in; an
    operation waits for its latest operand, the others go through (shared) delay registers.

    ``latencies``: ``{kind: cycles}`` for the kinds used (:meth:`default_latencies` fills in
    the units' defaults). ``dry=True`` instantiates nothing and only computes ready cycles (to
    learn a datapath's latency before building it). ``latencies["delay_ram"]`` (optional, 0:
    off): delays at least this long are ring buffers (module docstring)."""

    UNITS = {"add": FPAdd, "sub": FPAdd, "mul": FPMul, "div": FPDiv, "sqrt": FPSqrt,
             "min": FPMinMax, "max": FPMinMax}

    def __init__(self, m: Module, en: Value, fmt: FPFormat, latencies: dict, dry: bool = False,
                 share: Share | None = None):
        self.m, self.en, self.fmt, self.lat, self.dry = m, en, fmt, latencies, dry
        self.share = share if share is not None and share.ii > 1 else None
        self.counts = dict.fromkeys(CLASS.values(), 0)   # operations per unit class
        self.taps: dict[int, dict[int, Value]] = {}
        self.ptrs: dict[int, Signal] = {}        # one write/read pointer per ring depth
        self.ram_min = int(latencies.get("delay_ram") or 0)
        assert self.ram_min == 0 or self.ram_min >= 2, self.ram_min
        self.n = 0
        self.reg_bits = self.ring_bits = 0       # delay storage: flip-flops, ring memory bits
        if self.share is not None:
            ii = self.share.ii
            self.slots = {c: [set() for _ in range(n)] for c, n in self.share.units.items()}
            self.units: dict[tuple, object] = {}     # (class, index) -> the unit
            self.phase = Signal(range(ii), name="phase", init=-self.share.offset % ii)
            if not dry:
                with m.If(en):
                    m.d.sync += self.phase.eq(Mux(self.phase == ii - 1, 0, self.phase + 1))

    def start(self, valid: Value) -> Value:
        """``valid`` gated to the cycles in which the datapath takes an input (every cycle, or
        phase 0 with shared units)."""
        return valid if self.share is None else valid & self.slot

    def slot_at(self, t0: int) -> Value:
        """1 in the cycles in which a datapath whose inputs are ready at cycle ``t0`` takes an
        input. Several datapaths (or copies of one) built on one shared schedule, each from
        its own ``t0``, share its units: an operation of each is placed at the absolute cycle
        its operands are ready in, so the phases never collide."""
        return Const(1, 1) if self.share is None else self.phase == t0 % self.share.ii

    @property
    def slot(self) -> Value:
        """1 in the cycles in which the datapath takes an input."""
        return self.slot_at(0)

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
        out["delay_ram"] = given.get("delay_ram") or 0
        return out

    def at(self, value, t0: int, t: int) -> Value:
        """``value`` (ready at cycle ``t0``) as seen at cycle ``t >= t0``."""
        value = Value.cast(value)
        if isinstance(value, Const) or t == t0:
            return value
        assert t > t0, f"value ready at cycle {t0} read at cycle {t}"
        if self.share is not None:
            return self._strided(value, t0, t)
        taps = self.taps.setdefault(id(value), {0: value})  # taps[0] keeps id() unique
        d = t - t0
        while d not in taps:                  # extend from the longest delay made so far
            e = max(k for k in taps if k < d)
            if self.ram_min and d - e >= self.ram_min:
                # a ring of n - 1 words, then a register: the memory's read feeds only a
                # flip-flop, never the logic of the operation that reads the value
                n = min(d - e, RING_MAX + 1)
                taps[e + n] = self._reg(self._ring(taps[e], n - 1))
            else:
                taps[e + 1] = self._reg(taps[e])
        return taps[d]

    def _reg(self, value: Value) -> Signal:
        """``value`` a cycle later: a register that loads when ``en`` is 1."""
        reg = Signal.like(value, name=f"dly{self.n}", reset_less=True)
        self.n += 1
        with self.m.If(self.en):
            self.m.d.sync += reg.eq(value)
        self.reg_bits += len(reg)
        return reg

    def _strided(self, value: Value, t0: int, t: int) -> Value:
        """With shared units: ``value`` (ready at ``t0``) at ``t`` from a chain of registers that
        all load in ``t0``'s phase; the k-th holds it for cycles ``t0 + (k-1)*ii + 1 ..
        t0 + k*ii``."""
        ii = self.share.ii
        chain = self.taps.setdefault((id(value), t0 % ii), [value])
        k = -(-(t - t0) // ii)
        while len(chain) <= k:
            reg = Signal.like(chain[0], name=f"dly{self.n}", reset_less=True)
            self.n += 1
            if not self.dry:
                with self.m.If(self.en & (self.phase == t0 % ii)):
                    self.m.d.sync += reg.eq(chain[-1])
            chain.append(reg)
            self.reg_bits += len(reg)
        return chain[k]

    def _ring(self, value: Value, n: int) -> Signal:
        """``value`` delayed by ``n`` enabled cycles in a ring buffer of ``n`` words: each
        enabled cycle reads the word written ``n`` enabled cycles ago and writes ``value``
        in its place (the read is combinational, before the write)."""
        if self.dry:                          # ready cycles only: no memory to elaborate
            return Signal.like(value)
        ptr = self.ptrs.get(n)
        if ptr is None:
            ptr = self.ptrs[n] = Signal(range(n), name=f"ring{n}_ptr")
            with self.m.If(self.en):
                self.m.d.sync += ptr.eq(Mux(ptr == n - 1, 0, ptr + 1))
        mem = Memory(shape=len(value), depth=n, init=[])
        self.m.submodules[f"ring{self.n}"] = mem
        wr, rd = mem.write_port(), mem.read_port(domain="comb")
        out = Signal.like(value, name=f"dly{self.n}")
        self.n += 1
        self.ring_bits += n * len(value)
        self.m.d.comb += [wr.addr.eq(ptr), wr.data.eq(value), wr.en.eq(self.en),
                          rd.addr.eq(ptr), out.eq(rd.data)]
        return out

    def op(self, kind: str, a: tuple, b: tuple | None, name: str) -> tuple:
        """``(value, ready cycle)`` of ``a kind b`` (``sqrt``: of ``a``, ``b`` is None);
        operands are ``(value, ready cycle)``."""
        t = a[1] if b is None else max(a[1], b[1])
        self.counts[CLASS[kind]] += 1
        if self.share is not None:
            return self._shared_op(kind, a, b, t)
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

    def _shared_op(self, kind: str, a: tuple, b: tuple | None, t: int) -> tuple:
        """``op`` on a shared unit: the first cycle from ``t`` at which a unit of the class has
        the cycle's phase free; the unit's operands are multiplexed by the phase."""
        ii, cls = self.share.ii, CLASS[kind]
        if self.lat[kind] < 1:
            raise ValueError(f"shared schedule: a shared {cls} unit needs a latency of at "
                             "least 1 (its output would feed its own multiplexer)")
        if cls not in self.slots:
            raise ValueError(f"shared schedule: no {cls} unit for {kind} ({self.share!r})")
        for s in range(t, t + ii):
            free = [i for i, busy in enumerate(self.slots[cls]) if s % ii not in busy]
            if free:
                break
        else:
            raise ValueError(f"shared schedule: more {cls} operations than "
                             f"{len(self.slots[cls])} units x interval {ii} can take")
        i = free[0]
        self.slots[cls][i].add(s % ii)
        unit = self.units.get((cls, i))
        if unit is None:
            lat = self.lat[kind]
            unit = self.UNITS[kind](self.fmt, latency=lat) if not self.dry else None
            o = Signal(self.fmt.width, name=f"{cls}{i}_o")
            if unit is not None:
                self.m.submodules[f"{cls}{i}"] = unit
                self.m.d.comb += [unit.en.eq(self.en), o.eq(unit.o)]
            unit = self.units[cls, i] = (unit, o)
        unit, o = unit
        va = self.at(a[0], a[1], s)                # the delays first: not under the phase's If
        vb = None if b is None else self.at(b[0], b[1], s)
        if unit is not None:
            with self.m.If(self.phase == s % ii):
                self.m.d.comb += unit.a.eq(va)
                if vb is not None:
                    self.m.d.comb += unit.b.eq(vb)
                if kind in ("add", "sub", "min", "max"):
                    self.m.d.comb += unit.op.eq(kind in ("sub", "max"))
        return o, s + self.lat[kind]
