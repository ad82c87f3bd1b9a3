"""What the intersection unit's triangle-test pipelines share: :class:`TrianglePipe`, the base
of ``IntersectPipe`` (the watertight test, ``rtl/intersection.py``) and ``ProjectionPipe`` (the
paper's projection test, ``rtl/intersection_projection.py``): the FP latencies, the ports
(each test's inputs, the same outputs), the schedule's length, and the outputs at its last
stage."""
from __future__ import annotations

from amaranth.hdl import Module, Mux, Signal, Value
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from model.fp import FPFormat

from .fp.schedule import Schedule

__all__ = ["TrianglePipe", "pick"]


def pick(v, k):
    """Word ``k`` (0, 1 or 2) of the three words ``v``."""
    return Mux(k == 0, v[0], Mux(k == 1, v[1], v[2]))


class TrianglePipe(wiring.Component):
    """A triangle test as a pipeline of FP units (:class:`~rtl.fp.schedule.Schedule`).

    Ports: the test's ``inputs`` and ``tag``, ``i_valid``, ``en``; out after ``latency``
    enabled cycles ``o_valid``, ``hit``, ``t``, ``u``, ``v`` (zero when not ``hit``), ``o_tag``,
    ``pre_tag`` and ``pre2_tag`` (the tag one and two stages earlier, for a read that must land
    together with the result). ``latencies``: optional ``{"add": n, "mul": n, "div": n}``
    (default: each unit's). A subclass builds its datapath in ``_build(m, dry)`` and ends it
    with :meth:`_outputs`.
    """

    def __init__(self, fmt: FPFormat, tag_width: int, latencies: dict | None, inputs: dict):
        self.fmt = fmt
        self.tag_width = tag_width
        self.latencies = dict(latencies or {})
        for kind in ("add", "mul", "div"):
            if self.latencies.get(kind) is None:
                probe = Schedule.UNITS[kind](fmt)           # the unit's default latency
                probe._MustUse__silence = True
                self.latencies[kind] = probe.latency
        self.latencies["sub"] = self.latencies["add"]
        w = fmt.width
        super().__init__({
            **inputs, "tag": In(tag_width), "i_valid": In(1), "en": In(1, init=1),
            "o_valid": Out(1), "hit": Out(1), "t": Out(w), "u": Out(w), "v": Out(w),
            "o_tag": Out(tag_width), "pre_tag": Out(tag_width), "pre2_tag": Out(tag_width),
        })
        dry = Module()
        dry._MustUse__silence = True
        self.latency = self._build(dry, dry=True)[1]         # the schedule's length

    def _build(self, m: Module, dry: bool = False):
        raise NotImplementedError

    def _outputs(self, m: Module, sch, hit, t, u, v, L: int, dry: bool):
        """The outputs at stage ``L``: ``hit``, and ``t``, ``u``, ``v`` (each a (value, stage)
        pair) where it hits, zero else; the tags. Returns ``(m, L)``."""
        m.d.comb += [
            self.hit.eq(hit),
            self.t.eq(Mux(hit, sch.at(t[0], t[1], L), 0)),
            self.u.eq(Mux(hit, sch.at(u[0], u[1], L), 0)),
            self.v.eq(Mux(hit, sch.at(v[0], v[1], L), 0)),
            self.o_valid.eq(sch.at(self.i_valid, 0, L)),
            self.o_tag.eq(sch.at(self.tag, 0, L)),
            self.pre_tag.eq(sch.at(self.tag, 0, L - 1)),
            self.pre2_tag.eq(sch.at(self.tag, 0, L - 2)),
        ]
        if not dry:     # the delay storage built (``Config.delay_ram``): flip-flop, ring bits
            self.delay_bits = (sch.reg_bits, sch.ring_bits)
        return m, L

    @staticmethod
    def _wire(m: Module, v, name: str):
        s = Signal.like(Value.cast(v), name=name)
        m.d.comb += s.eq(v)
        return s

    def elaborate(self, platform):
        return self._build(Module())[0]
