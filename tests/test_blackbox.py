"""``tb/harness/blackbox.py``: a deduplicated export behaves as the flat one, cycle for cycle.

A small design holds two copies of an accumulator behind a ``ResetInserter`` (as the frame
tops hold the chip in reset until ``start``). Exported flat and deduplicated (the copies
``Instance``s of one exported module), both run side by side in Icarus Verilog on the same
random inputs, with the inserted reset raised and dropped during the run: every output must
agree on every cycle. The whole chip's deduplicated build is checked against Amaranth's
simulator by ``tests/test_chip.py`` (same results, same cycle count).
"""
from __future__ import annotations

import shutil
import subprocess

import pytest
from amaranth.back import verilog
from amaranth.hdl import Module, ResetInserter, Signal
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from tb.harness.blackbox import Blackbox, deduplicate, export_units, module_ports, port_names


class Acc(wiring.Component):
    """Adds ``a`` into ``total`` and counts the additions, when ``en``."""

    def __init__(self):
        super().__init__({"a": In(8), "en": In(1), "total": Out(16, init=5), "count": Out(4)})

    def elaborate(self, platform):
        m = Module()
        with m.If(self.en):
            m.d.sync += [self.total.eq(self.total + self.a), self.count.eq(self.count + 1)]
        return m

    def doubled(self):
        return self.total + self.total


class _Held(wiring.Component):
    def __init__(self, top):
        self.top = top
        super().__init__({})

    def elaborate(self, platform):
        m, t = Module(), self.top
        for i, acc in enumerate(t.accs):
            m.submodules[f"acc{i}"] = acc
            m.d.comb += [acc.a.eq(t.a[i]), acc.en.eq(t.en[i]), t.total[i].eq(acc.total),
                         t.count[i].eq(acc.count)]
        return m


class Pair(wiring.Component):
    """Two accumulators, held in reset while ``hold`` (a ``ResetInserter``)."""

    def __init__(self, dedup: bool):
        super().__init__({"a": In(8).array(2), "en": In(1).array(2), "hold": In(1),
                          "total": Out(16).array(2), "count": Out(4).array(2)})
        self.accs = [Acc(), Acc()]
        self.held = Signal()
        self.units = []
        if dedup:
            self.units = [("acc", deduplicate(self.accs, "acc", self.held), self.accs)]

    def elaborate(self, platform):
        m = Module()
        m.submodules.run = ResetInserter({"sync": self.hold})(_Held(self))
        m.d.comb += self.held.eq(self.hold)
        return m


TB = """
module tb;
  reg clk = 0, rst = 1;
  reg [7:0] a0, a1; reg en0, en1, hold;
  wire [15:0] ft0, ft1, dt0, dt1; wire [3:0] fc0, fc1, dc0, dc1;
  flat  f(.clk(clk), .rst(rst), .a__0(a0), .a__1(a1), .en__0(en0), .en__1(en1), .hold(hold),
          .total__0(ft0), .total__1(ft1), .count__0(fc0), .count__1(fc1));
  dedup d(.clk(clk), .rst(rst), .a__0(a0), .a__1(a1), .en__0(en0), .en__1(en1), .hold(hold),
          .total__0(dt0), .total__1(dt1), .count__0(dc0), .count__1(dc1));
  integer i, bad = 0, held = 0;
  initial begin
    a0 = 0; a1 = 0; en0 = 0; en1 = 0; hold = 0;
    #1 clk = 1; #1 clk = 0; rst = 0;
    for (i = 0; i < 400; i = i + 1) begin
      a0 = $random; a1 = $random; en0 = $random; en1 = $random;
      hold = (i % 97) > 90;
      held = held + hold;
      #1 clk = 1; #1 clk = 0;
      if ({ft0, ft1, fc0, fc1} !== {dt0, dt1, dc0, dc1}) begin
        bad = bad + 1;
        if (bad < 4) $display("MISMATCH cycle %0d: flat %h %h dedup %h %h", i, ft0, ft1, dt0, dt1);
      end
    end
    $display("DONE bad=%0d held=%0d total=%h", bad, held, ft0);
    $finish;
  end
endmodule
"""


def _export(tmp_path, dedup: bool) -> list:
    top = Pair(dedup)
    files = []
    for module, text, _ in export_units(top.units):
        (tmp_path / f"{module}.v").write_text(text)
        files.append(tmp_path / f"{module}.v")
    name = "dedup" if dedup else "flat"
    (tmp_path / f"{name}.v").write_text(verilog.convert(top, name=name))
    return files + [tmp_path / f"{name}.v"]


def test_deduplicated_export_runs_as_the_flat_one(tmp_path):
    if shutil.which("iverilog") is None:
        pytest.fail("iverilog missing: run make setup (scripts/setup.sh installs it)")
    files = _export(tmp_path, False) + _export(tmp_path, True)
    # the deduplicated top holds no accumulator logic of its own: two instances of "acc"
    dedup = (tmp_path / "dedup.v").read_text()
    assert dedup.count("  acc ") == 2 and "module acc" not in dedup
    (tmp_path / "tb.v").write_text(TB)
    subprocess.run(["iverilog", "-g2012", "-o", str(tmp_path / "sim"), str(tmp_path / "tb.v"),
                    *map(str, files)], check=True, capture_output=True, text=True)
    out = subprocess.run(["vvp", str(tmp_path / "sim")], capture_output=True, text=True,
                         check=True).stdout
    assert "DONE bad=0" in out, out
    held = int(out.split("held=")[1].split()[0])
    assert held > 10                      # the inserted reset was exercised


def test_a_stand_in_without_the_hold_would_differ(tmp_path):
    """The check above can fail: the same design with the stand-ins ignoring the inserted
    reset (no ``hold``) runs differently."""
    class NoHold(Pair):
        def __init__(self, dedup):
            super().__init__(dedup)
            if dedup:
                for bb in self.accs:
                    bb._hold = None
    files = _export(tmp_path, False)
    top = NoHold(True)
    for module, text, _ in export_units(top.units):
        (tmp_path / f"{module}.v").write_text(text)
        files.append(tmp_path / f"{module}.v")
    (tmp_path / "dedup.v").write_text(verilog.convert(top, name="dedup"))
    (tmp_path / "tb.v").write_text(TB)
    subprocess.run(["iverilog", "-g2012", "-o", str(tmp_path / "sim"), str(tmp_path / "tb.v"),
                    *map(str, files), str(tmp_path / "dedup.v")], check=True)
    out = subprocess.run(["vvp", str(tmp_path / "sim")], capture_output=True, text=True).stdout
    assert "MISMATCH" in out and "DONE bad=0" not in out, out


def test_stand_ins_keep_ports_and_methods():
    a, b = Acc(), Acc()
    slots = [a, b]
    first = deduplicate(slots, "acc")
    assert first is a and all(isinstance(s, Blackbox) for s in slots)
    assert port_names(slots[1]).keys() == port_names(a).keys() == {"a", "en", "total", "count"}
    assert slots[1].total is not a.total
    # a method of the unit's class acts on the stand-in's own ports
    assert repr(slots[1].doubled()) == repr(slots[1].total + slots[1].total)
    text = verilog.convert(first, name="acc")
    assert module_ports(text, "acc") == {"clk", "rst", "a", "en", "total", "count"}


def test_units_that_differ_are_refused():
    class Other(Acc):
        pass
    with pytest.raises(ValueError, match="the units differ"):
        deduplicate([Acc(), Other()], "acc")
