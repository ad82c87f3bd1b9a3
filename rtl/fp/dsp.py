"""An unsigned multiply with its operands and its product registered, for the FP multiplier's
partial products.

On the ECP5 (elaborated with :data:`ECP5` as the platform, as ``saarcor.flows.fpga`` does) it is one
MULT18X18D using its own input and output registers, so no fabric wire lies between a register
and the multiplier array: the path into the block ends at its input registers and the path out
of it starts at its output register. Anywhere else (simulation, other exports) it is the same
registers in logic. Either way: latency 2, throughput 1; ``en`` = 0 holds both registers (the
registers have no reset, like the FP units' data registers).
"""
from __future__ import annotations

from amaranth.hdl import ClockSignal, Const, Instance, Module, Signal
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

__all__ = ["ECP5", "RegMul", "DSP_WIDTH"]

DSP_WIDTH = 18      # operand width of one MULT18X18D


class _ECP5:
    """The platform object for an ECP5 build: units that know the part use its primitives."""
    ecp5_dsp = True

    def __repr__(self):
        return "ECP5"


ECP5 = _ECP5()


class RegMul(wiring.Component):
    """``p = a * b`` (unsigned), two cycles after ``a`` and ``b``: registered operands, then the
    registered product (``en`` = 1 loads both). Operands at most :data:`DSP_WIDTH` bits."""

    def __init__(self, a_width: int, b_width: int):
        if not (1 <= a_width <= DSP_WIDTH and 1 <= b_width <= DSP_WIDTH):
            raise ValueError(f"RegMul: operands of {a_width} and {b_width} bits; a MULT18X18D "
                             f"takes at most {DSP_WIDTH} each")
        self.a_width, self.b_width = a_width, b_width
        super().__init__({"a": In(a_width), "b": In(b_width), "en": In(1, init=1),
                          "p": Out(a_width + b_width)})

    def elaborate(self, platform):
        m = Module()
        if getattr(platform, "ecp5_dsp", False):
            a = [self.a[i] if i < self.a_width else Const(0) for i in range(DSP_WIDTH)]
            b = [self.b[i] if i < self.b_width else Const(0) for i in range(DSP_WIDTH)]
            p = Signal(2 * DSP_WIDTH)
            ports = {f"i_A{i}": a[i] for i in range(DSP_WIDTH)}
            ports.update({f"i_B{i}": b[i] for i in range(DSP_WIDTH)})
            ports.update({f"o_P{i}": p[i] for i in range(2 * DSP_WIDTH)})
            # the C input, the shift chains and the other clocks stay unconnected (as Yosys
            # leaves them when it maps a multiply to the block)
            ports.update(i_CLK0=ClockSignal(), i_CE0=self.en, i_RST0=Const(0))
            m.submodules.dsp = Instance(
                "MULT18X18D",
                p_REG_INPUTA_CLK="CLK0", p_REG_INPUTA_CE="CE0", p_REG_INPUTA_RST="RST0",
                p_REG_INPUTB_CLK="CLK0", p_REG_INPUTB_CE="CE0", p_REG_INPUTB_RST="RST0",
                p_REG_INPUTC_CLK="NONE", p_REG_PIPELINE_CLK="NONE",
                p_REG_OUTPUT_CLK="CLK0", p_REG_OUTPUT_CE="CE0", p_REG_OUTPUT_RST="RST0",
                p_CLK0_DIV="ENABLED", p_CLK1_DIV="ENABLED", p_CLK2_DIV="ENABLED",
                p_CLK3_DIV="ENABLED", p_HIGHSPEED_CLK="NONE", p_GSR="DISABLED",
                p_CAS_MATCH_REG="FALSE", p_SOURCEB_MODE="B_SHIFT", p_MULT_BYPASS="DISABLED",
                p_RESETMODE="SYNC",
                i_SIGNEDA=Const(0), i_SIGNEDB=Const(0), i_SOURCEA=Const(0), i_SOURCEB=Const(0),
                **ports)
            m.d.comb += self.p.eq(p[:len(self.p)])
        else:
            a_q = Signal(self.a_width, name="a_q", reset_less=True)
            b_q = Signal(self.b_width, name="b_q", reset_less=True)
            p_q = Signal(len(self.p), name="p_q", reset_less=True)
            with m.If(self.en):
                m.d.sync += [a_q.eq(self.a), b_q.eq(self.b), p_q.eq(a_q * b_q)]
            m.d.comb += self.p.eq(p_q)
        return m
