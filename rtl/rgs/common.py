"""What the RGS slave's datapaths share (``eye.py``, ``secondary.py``, ``texture.py``).

* :class:`_Datapath`: a bare fixed-latency datapath of FP units on a ``Schedule`` (optionally
  shared in a modulo schedule within an FP unit budget), the base of every ``*Pipe``.
* :func:`_fp_const`: the format's constants (1, +-inf, +0); :func:`_valid_chain`: a valid bit
  through the pipeline's registers.
"""
from __future__ import annotations

from amaranth.hdl import Const, Module, Signal, Value
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from model.fp import FPFormat

from ..fp.schedule import Schedule, Share


def _fp_const(fmt: FPFormat, value: str) -> Const:
    E, M = fmt.exp_bits, fmt.frac_bits
    emax = (1 << E) - 1
    bits = {"one": fmt.bias << M, "+inf": emax << M, "-inf": (1 << (E + M)) | (emax << M),
            "+0": 0}[value]
    return Const(bits, fmt.width)



def _valid_chain(m: Module, en: Value, valid: Value, n: int, name: str) -> Value:
    """``valid`` through ``n`` registers (reset to 0) that load when ``en`` is 1."""
    for i in range(n):
        reg = Signal(name=f"{name}{i}")
        with m.If(en):
            m.d.sync += reg.eq(valid)
        valid = reg
    return valid


def _latencies(fmt: FPFormat, latencies: dict | None) -> dict:
    lat = Schedule.default_latencies(fmt, latencies)
    conv = (latencies or {}).get("conv")
    lat["conv"] = 2 if conv is None else conv          # FPFromInt's default
    return lat


class _Datapath(wiring.Component):
    """A bare fixed-latency datapath of FP units (``Schedule``): ``inputs`` and ``outputs``
    ports plus ``tag`` (carried along), ``i_valid``, ``en`` (0 holds every stage),
    ``i_slot`` (1 in the cycles in which an input is taken), ``o_valid`` and ``o_tag``. A
    subclass writes ``_build(m, dry)``, which returns the latency; ``latency`` comes from a
    dry build (ready cycles only, no units).

    ``budget`` (``{"add": n, "mul": n}``, optional; :meth:`Config.rgs_budget`): at most n FP
    adders and n multipliers, shared in a modulo schedule (:class:`~rtl.fp.schedule.Share`):
    the datapath then takes an input every ``ii`` enabled cycles (``i_slot``; an ``i_valid``
    outside its slot is ignored) and ``units`` gives the units of each class. Two more keys:
    ``"ii"``, the least interval (to run in step with another datapath), and ``"offset"``:
    the first slot comes ``offset`` enabled cycles after reset (the latency of a datapath of
    the same interval that feeds this one, so that its outputs meet this one's slots).
    Without a budget, ``ii`` is 1 and every operation has its own unit."""

    def __init__(self, fmt: FPFormat, tag_width: int, latencies: dict | None,
                 inputs: dict, outputs: dict, budget: dict | None = None):
        self.fmt, self.tag_width = fmt, tag_width
        self.latencies = _latencies(fmt, latencies)
        super().__init__({**inputs, "tag": In(tag_width), "i_valid": In(1), "en": In(1, init=1),
                          "i_slot": Out(1), "o_valid": Out(1), **outputs,
                          "o_tag": Out(tag_width)})
        self.share = None
        self.latency = self._build(self._dry(), dry=True)
        self.counts = dict(self._sch.counts)            # operations per FP unit class
        budget = dict(budget or {})
        min_ii, offset = budget.pop("ii", 1), budget.pop("offset", 0)
        if budget or min_ii > 1:
            self.share = Share.for_budget(self.counts, budget, min_ii, offset)
            if self.share.ii > 1:
                self.latency = self._build(self._dry(), dry=True)
            else:
                self.share = None
        self.ii = 1 if self.share is None else self.share.ii
        self.units = dict(self.counts if self.share is None else self.share.units)
        self.per_ii = 1             # inputs taken per interval (ShadePool's LightPipe copies)

    @property
    def in_flight(self) -> int:
        """The most inputs inside the datapath at once, the one held at its output included
        (``per_ii`` inputs every ``ii`` enabled cycles, each leaving after ``latency``):
        ``(latency // ii + 1) * per_ii``."""
        return (self.latency // self.ii + 1) * self.per_ii

    @staticmethod
    def _dry() -> Module:
        m = Module()
        m._MustUse__silence = True
        return m

    def _schedule(self, m: Module, dry: bool) -> Schedule:
        self._sch = Schedule(m, self.en, self.fmt, self.latencies, dry, self.share)
        return self._sch

    def _emit(self, m: Module, sch: Schedule, dry: bool, en: Value | None = None) -> int:
        """The ``_build`` of a datapath written as ``_graph(m, sch, t0, dry)`` (its operations
        from inputs ready at cycle ``t0``, returning the outputs' cycle and values): one copy
        from cycle 0, its outputs on the ports, the valid along (loading when ``en``, default
        the ``en`` port)."""
        L, outs = self._graph(m, sch, 0, dry)
        if not dry:
            en = self.en if en is None else en
            m.d.comb += self.o_valid.eq(_valid_chain(m, en, sch.start(self.i_valid), L,
                                                     "valid"))
            m.d.comb += [getattr(self, k).eq(v) for k, v in outs.items()]
        return L

    def _build(self, m: Module, dry: bool = False) -> int:
        raise TypeError(f"{type(self).__name__}: a datapath defines _build(m, dry) (its "
                        "stages; returns the latency)")

    def elaborate(self, platform):
        m = Module()
        self._build(m)
        m.d.comb += self.i_slot.eq(self._sch.slot)
        return m
