"""saarcor.flows.fpga.outreg: the flip-flops after block-RAM reads move into the RAMs' output registers."""
from __future__ import annotations

import copy
import json

import pytest

from saarcor.flows.fpga.outreg import absorb_output_registers

CLK, CE, RST = 7, 8, 9


def _ff(di, q, *, ce=None, clk=CLK, lsr="0", cemux=None):
    return {"type": "TRELLIS_FF",
            "parameters": {"CEMUX": cemux or ("CE" if ce is not None else "1 "),
                           "CLKMUX": "CLK", "GSR": "DISABLED", "LSRMUX": "LSR",
                           "REGSET": "RESET"},
            "port_directions": {"CLK": "input", "CE": "input", "LSR": "input", "DI": "input",
                                "Q": "output"},
            "connections": {"CLK": [clk], "LSR": [lsr], "DI": [di], "Q": [q],
                            **({"CE": [ce]} if ce is not None else {})}}


def _netlist(width: int, outs: list[str], ffs: dict, extra_sinks=()) -> dict:
    """fpga_top: one DP16KD of ``width`` whose output pins ``outs`` drive nets 100.., and
    ``ffs`` (name -> cell); a LUT4 reads each flip-flop's Q (nets 200..)."""
    ram = {"type": "DP16KD",
           "parameters": {"DATA_WIDTH_A": format(width, "032b"),
                          "DATA_WIDTH_B": format(width, "032b"), "REGMODE_A": "NOREG",
                          "REGMODE_B": "NOREG", "CLKAMUX": "CLKA", "CLKBMUX": "CLKB"},
           "port_directions": {**{p: "output" for p in outs},
                               **{p: "input" for p in ("CLKA", "CLKB", "CEB", "OCEA", "OCEB",
                                                       "RSTA", "RSTB")}},
           "connections": {**{p: [100 + i] for i, p in enumerate(outs)},
                           "CLKA": [CLK], "CLKB": [CLK], "CEB": [5], "OCEA": ["0"],
                           "OCEB": ["1"], "RSTA": ["0"], "RSTB": ["0"]}}
    cells = {"ram": ram, **ffs}
    for i, f in enumerate(ffs.values()):
        q = f["connections"]["Q"][0]
        cells[f"lut{i}"] = {"type": "LUT4", "port_directions": {"A": "input", "Z": "output"},
                            "connections": {"A": [q], "Z": [300 + i]}}
    for i, b in enumerate(extra_sinks):
        cells[f"extra{i}"] = {"type": "LUT4", "port_directions": {"A": "input", "Z": "output"},
                              "connections": {"A": [b], "Z": [400 + i]}}
    names = {f"ram_do{i}": {"bits": [100 + i]} for i in range(len(outs))}
    return {"modules": {"fpga_top": {"attributes": {"top": 1}, "ports": {}, "cells": cells,
                                     "netnames": names}}}


def test_registers_move_into_the_read_port():
    """9-bit RAM read on port B: the two flip-flops (one enable) become the output register;
    each output pin drives its flip-flop's net, and the old net's name joins it."""
    ffs = {"f0": _ff(100, 200, ce=CE), "f1": _ff(101, 201, ce=CE)}
    net = _netlist(9, ["DOB0", "DOB1"], ffs)
    res = absorb_output_registers(net)
    assert res == {"ports": 1, "bits": 2, "skipped": {}}
    cells = net["modules"]["fpga_top"]["cells"]
    assert "f0" not in cells and "f1" not in cells
    ram = cells["ram"]
    assert ram["connections"]["DOB0"] == [200] and ram["connections"]["DOB1"] == [201]
    assert ram["parameters"]["REGMODE_B"] == "OUTREG"
    assert ram["parameters"]["REGMODE_A"] == "NOREG"
    assert ram["connections"]["OCEB"] == [CE]
    assert cells["lut0"]["connections"]["A"] == [200]        # the reader is untouched
    assert net["modules"]["fpga_top"]["netnames"]["ram_do1"]["bits"] == [201]


def test_a_second_pass_changes_nothing():
    """The moved register's net may feed one more flip-flop (a read registered twice): a
    second pass must not take that one into the RAM too (a cycle less)."""
    ffs = {"f0": _ff(100, 200), "g0": _ff(200, 210)}
    net = _netlist(9, ["DOB0"], ffs)
    net["modules"]["fpga_top"]["cells"].pop("lut0")   # f0's Q feeds g0 alone; a LUT reads g0's
    assert absorb_output_registers(net)["bits"] == 1
    once = copy.deepcopy(net)
    assert absorb_output_registers(net) == {"ports": 0, "bits": 0,
                                            "skipped": {"output register in use": 1}}
    assert net == once


def test_only_the_selected_rams_move():
    """``only``: a RAM whose cell name the expression does not match keeps its flip-flops,
    counted as "not selected"; one it matches moves as without ``only``."""
    ffs = {"f0": _ff(100, 200, ce=CE)}
    net = _netlist(9, ["DOB0"], ffs)
    before = copy.deepcopy(net)
    assert absorb_output_registers(net, only="stack") == {
        "ports": 0, "bits": 0, "skipped": {"not selected": 1}}
    assert net == before
    assert absorb_output_registers(net, only="^ra") == {"ports": 1, "bits": 1, "skipped": {}}
    assert "f0" not in net["modules"]["fpga_top"]["cells"]


def test_pseudo_dual_port_enables_both_halves():
    """36-bit mode reads on B with data on both halves: both output registers, both enables
    (always on here)."""
    ffs = {"f0": _ff(100, 200), "f1": _ff(101, 201)}
    net = _netlist(36, ["DOA3", "DOB0"], ffs)
    assert absorb_output_registers(net)["bits"] == 2
    ram = net["modules"]["fpga_top"]["cells"]["ram"]
    assert ram["parameters"]["REGMODE_A"] == ram["parameters"]["REGMODE_B"] == "OUTREG"
    assert ram["connections"]["OCEA"] == ram["connections"]["OCEB"] == ["1"]


@pytest.mark.parametrize("why, ffs, extra", [
    ("flip-flop with set/reset", {"f0": _ff(100, 200), "f1": _ff(101, 201, lsr=RST)}, ()),
    ("output not only a flip-flop's D", {"f0": _ff(100, 200), "f1": _ff(101, 201)}, (101,)),
    ("flip-flops with different enables", {"f0": _ff(100, 200, ce=CE), "f1": _ff(101, 201)}, ()),
    ("flip-flop on another clock", {"f0": _ff(100, 200), "f1": _ff(101, 201, clk=6)}, ()),
    ("inverted clock enable", {"f0": _ff(100, 200, ce=CE, cemux="INV"),
                               "f1": _ff(101, 201, ce=CE, cemux="INV")}, ()),
])
def test_a_port_that_cannot_move_is_left_whole(why, ffs, extra):
    """One flip-flop that does not fit leaves the whole read port as it was."""
    net = _netlist(9, ["DOB0", "DOB1"], ffs, extra)
    before = copy.deepcopy(net)
    assert absorb_output_registers(net) == {"ports": 0, "bits": 0, "skipped": {why: 1}}
    assert net == before


def test_yosys_netlist_of_a_registered_block_ram_read():
    """A BlockRAM read straight into a register (no reset), through Yosys's synth_ecp5: every
    output bit's flip-flop moves into the RAM; the register's enable becomes the RAM's."""
    from amaranth.hdl import Module, Signal
    from amaranth.lib import wiring
    from amaranth.lib.wiring import In, Out
    from rtl.common import BlockRAM
    from tb.harness.common import synth_ecp5_json

    class Top(wiring.Component):
        def __init__(self):
            super().__init__({"wa": In(9), "wd": In(36), "we": In(1), "ra": In(9),
                              "re": In(1), "take": In(1), "q": Out(36)})

        def elaborate(self, platform):
            m = Module()
            m.submodules.mem = mem = BlockRAM(shape=36, depth=512)
            w, r = mem.write_port(), mem.read_port()
            reg = Signal(36, reset_less=True)
            m.d.comb += [w.addr.eq(self.wa), w.data.eq(self.wd), w.en.eq(self.we),
                         r.addr.eq(self.ra), r.en.eq(self.re), self.q.eq(reg)]
            with m.If(self.take):
                m.d.sync += reg.eq(r.data)
            return m

    net = synth_ecp5_json(Top())
    cells = net["modules"]["top"]["cells"]
    n_ff = sum(c["type"] == "TRELLIS_FF" for c in cells.values())
    res = absorb_output_registers(net, "top")
    assert res["ports"] == 1 and res["bits"] == 36 and res["skipped"] == {}
    rams = [c for c in cells.values() if c["type"] == "DP16KD"]
    assert len(rams) == 1 and rams[0]["parameters"]["REGMODE_B"] == "OUTREG"
    assert sum(c["type"] == "TRELLIS_FF" for c in cells.values()) == n_ff - 36
    # the output pins now drive the nets the top's q port reads
    q_bits = set(net["modules"]["top"]["ports"]["q"]["bits"])
    outs = {b for p, bits in rams[0]["connections"].items() if p.startswith("DO")
            for b in bits if isinstance(b, int)}
    assert q_bits <= outs
    assert rams[0]["connections"]["OCEB"] == net["modules"]["top"]["ports"]["take"]["bits"]


def test_path_estimate_starts_at_the_output_register(tmp_path):
    """``--estimate``: a read through the RAM's output register leaves it 0.9 ns after the
    clock (the plain RAM's 5.8 ns went into the flip-flop the pass removed), so the design's
    worst path, the RAM into that flip-flop, is gone."""
    from saarcor.flows.fpga.paths import BRAM_CQ, BRAM_OUTREG_CQ, FF_CQ, SETUP, estimate
    ffs = {"f0": _ff(100, 200)}
    net = _netlist(9, ["DOB0"], ffs)
    net["modules"]["fpga_top"]["cells"]["g"] = _ff(300, 301)     # the LUT's output, registered
    ends = {}
    for moved in (False, True):
        n = copy.deepcopy(net)
        if moved:
            assert absorb_output_registers(n)["bits"] == 1
        (tmp_path / "n.json").write_text(json.dumps(n))
        ends[moved] = {e["end"]: e for e in estimate(tmp_path / "n.json", route=1.0)}
    assert ends[False]["f0"]["ns"] == round(BRAM_CQ + 1.0 + SETUP, 2)
    assert ends[False]["g"]["path"][0] == "f0" and "f0" not in ends[True]
    assert ends[True]["g"]["path"][0] == "ram"
    assert ends[True]["g"]["ns"] == round(ends[False]["g"]["ns"] - FF_CQ + BRAM_OUTREG_CQ, 2)
    assert max(e["ns"] for e in ends[True].values()) < ends[False]["f0"]["ns"] - 3
