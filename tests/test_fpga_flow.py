"""saarcor.flows.fpga.flow helpers that need no Yosys or nextpnr run: log parsing, --reuse checks."""
from __future__ import annotations

import json
import shutil
import time

import pytest

from model.config import Config
from saarcor.flows.fpga.flow import placement_fmax, pnr_times, run

LOG = """Info: HeAP Placer Time: 668.70s
Info:   of which solving equations: 419.13s
Info: Max frequency for clock '$glbnet$clk$TRELLIS_IO_IN': 12.00 MHz (FAIL at 100.00 MHz)
Info: Running simulated annealing placer for refinement.
Info: SA placement time 1299.70s

Info: Max frequency for clock '$glbnet$clk$TRELLIS_IO_IN': 26.54 MHz (FAIL at 100.00 MHz)
Info: Routing..
Info: Router2 time 301.25s
Info: Routing complete.
Info: Router1 time 10.53s
Info: Max frequency for clock '$glbnet$clk$TRELLIS_IO_IN': 31.02 MHz (FAIL at 100.00 MHz)
"""


def test_pnr_times_and_placement_estimate():
    assert pnr_times(LOG) == {"heap_place": 668.7, "sa_place": 1299.7, "router2": 301.25,
                              "router1": 10.53}
    assert placement_fmax(LOG) == 26.54           # after refinement, not the earlier line
    r1 = "Info: SA placement time 5.67s\nInfo: Routing complete.\nInfo: Router1 time 10.41s\n"
    assert pnr_times(r1) == {"sa_place": 5.67, "router1": 10.41}
    assert placement_fmax("Info: HeAP Placer Time: 1.0s\n") is None   # placement unfinished


def test_reuse_checks(tmp_path):
    cfg = Config()
    with pytest.raises(SystemExit, match="no such run"):
        run("fp_add", cfg, out=tmp_path, reuse="nothing", pnr=False)
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "fpga_top.json").write_text("{}")
    (tmp_path / "old" / "fpga_top.stat").write_text("")
    old = {"top": "fp_mul", "config": cfg.to_dict(), "latency": 3}
    (tmp_path / "report.json").write_text(json.dumps({"runs": {"old": old}}))
    with pytest.raises(SystemExit, match="another top or configuration"):
        run("fp_add", cfg, out=tmp_path, reuse="old", pnr=False)
    with pytest.raises(SystemExit, match="another top or configuration"):
        run("fp_mul", cfg.replace(fp_mul_latency=5), out=tmp_path, reuse="old", pnr=False)


def test_set_router_rewrites_the_stored_setting(tmp_path):
    from saarcor.flows.fpga.flow import _set_router
    placed = tmp_path / "placed.json"
    text = '{"modules": {"top": {"settings": {"placer": "heap", "router": "router1"}}}}'
    placed.write_text(text)
    _set_router(placed, "router2")
    assert json.loads(placed.read_text())["modules"]["top"]["settings"]["router"] == "router2"
    _set_router(placed, "router2")                    # already so: unchanged
    assert placed.read_text() == text.replace("router1", "router2")


def test_native_yosys_is_named_when_missing(monkeypatch):
    from tb.harness.tools import ToolMissing, tool
    monkeypatch.setenv("PATH", "")
    with pytest.raises(ToolMissing, match="apt-get install yosys"):
        tool("yosys")


@pytest.mark.skipif(shutil.which("yosys") is None, reason="no native Yosys on PATH")
def test_native_yosys_synthesizes(tmp_path):
    """``--yosys yosys`` (the native build the whole chip needs) maps a unit to ECP5 cells."""
    e = run("fp_add", Config(), out=tmp_path, pnr=False, yosys="yosys")
    assert e["yosys"] == "yosys" and e["status"] == "synthesized"
    assert e["resources"]["lut4"] > 100 and e["resources"]["ff"] > 50


def test_speed_grade_checked_and_shown(tmp_path):
    from saarcor.flows.fpga.flow import _fmax_text
    with pytest.raises(SystemExit, match="grades 6, 7, 8"):
        run("fp_add", Config(), out=tmp_path, pnr=False, speed=5)
    fmax = {"achieved_mhz": 84.2}
    assert _fmax_text({"speed": 8}, fmax) == "84.2 (speed 8)"
    assert _fmax_text({}, fmax) == "84.2"               # runs before --speed: grade 6


STAT = """
=== fpga_top ===
   Number of cells:                 12
     LUT4                           10
     TRELLIS_FF                      2
     fpga_top.dut                    1

=== fpga_top.dut ===
   Number of cells:                  3
     LUT4                            3

=== fpga_top.dut.array.rtc0 ===
   Number of cells:                 20
     LUT4                           15
     MULT18X18D                      4
     CCU2C                           1

=== fpga_top.dut.array.rtc0.int.pipe ===
   Number of cells:                  5
     TRELLIS_FF                      5

=== fpga_top.dut.array.bus ===
   Number of cells:                  7
     LUT4                            7

=== fpga_top.dut.slave0 ===
   Number of cells:                 30
     DP16KD                          2
     TRELLIS_DPR16X4                 1

=== design hierarchy ===

   fpga_top                          1
     fpga_top.dut                    1

   Number of cells:                 77
     LUT4                           35
"""


def test_unit_resources_and_chip_estimate():
    from saarcor.flows.fpga.flow import chip_estimate, chip_unit, stat_sections, unit_resources
    assert chip_unit("\\\\fpga_top.dut.array.rtcmi0.cache_int") == "rtcmi0"
    assert chip_unit("fpga_top.dut.master.queue0") == "master"
    assert stat_sections(STAT)["fpga_top.dut.array.bus"].count("LUT4") == 1
    u = unit_resources(STAT)
    assert set(u) == {"wrapper", "glue", "rtc0", "bus", "slave0"}
    assert (u["rtc0"]["lut4"], u["rtc0"]["ff"], u["rtc0"]["dsp"], u["rtc0"]["carry"]) == \
        (15, 5, 4, 1)                                  # the unit's modules summed
    assert u["wrapper"]["lut4"] == 10 and u["glue"]["lut4"] == 3
    est = chip_estimate(u, 4)
    assert sorted(est["per_rtc_units"]) == ["rtc0", "slave0"]
    assert est["resources"]["lut4"] == 3 + 7 + 4 * 15           # glue + bus + 4 RTCs
    assert est["resources"]["bram"] == 4 * 2 and est["resources"]["lutram"] == 4
    u["rtc1"] = u["rtc0"]
    with pytest.raises(ValueError, match="one RTC"):
        chip_estimate(u, 4)


@pytest.mark.skipif(shutil.which("yosys") is None, reason="no native Yosys on PATH")
def test_hierarchy_units_add_up(tmp_path):
    """``--hierarchy``: each unit's cells, summed, are the whole design's."""
    cfg = Config(trav_cache_kb=4, list_cache_kb=4, int_cache_kb=9)
    e = run("memif", cfg, out=tmp_path, yosys="yosys", hierarchy=True)
    assert e["status"] == "synthesized" and {"bus", "cache0", "cache2"} <= set(e["units"])
    for k, n in e["resources"].items():
        assert sum(u[k] for u in e["units"].values()) == n, k
    assert e["units"]["cache2"]["bram"] > 0 and e["units"]["bus"]["ff"] > 0


def test_pnr_args_reach_nextpnr_and_the_report(tmp_path, monkeypatch):
    """``--pnr-arg`` words go to nextpnr as they are and are recorded with the run."""
    import subprocess
    import types

    import saarcor.flows.fpga.flow as flow
    cfg = Config()
    (tmp_path / "old").mkdir()
    for f in ("fpga_top.json", "fpga_top.stat"):
        (tmp_path / "old" / f).write_text("")
    res = dict.fromkeys(("lut4", "ff", "dsp", "bram", "carry", "pfumx", "l6mux", "lutram",
                         "alu54"), 0)
    old = {"top": "fp_add", "config": cfg.to_dict(), "fmt": "E8M23", "latency": None,
           "wrapper": {"ff": 0}, "resources": res}
    (tmp_path / "report.json").write_text(json.dumps({"runs": {"old": old}}))
    calls = []

    def fake_run(cmd, **kw):
        calls.append(cmd)
        return types.SimpleNamespace(returncode=1, stderr="stopped", stdout="")
    monkeypatch.setattr(subprocess, "run", fake_run)
    monkeypatch.setattr(flow, "tool", lambda name: name)
    with pytest.raises(SystemExit, match="nextpnr failed"):
        run("fp_add", cfg, out=tmp_path, reuse="old", label="beta",
            pnr_args=("--placer-heap-beta", "0.7"))
    assert len(calls) == 1
    cmd = calls[0]
    i = cmd.index("--placer-heap-beta")
    assert cmd[i + 1] == "0.7" and cmd[0:3] == ["nice", "-n", "10"]
    assert cmd.count("--detailed-timing-report") == 1       # for --estimate --routed
    entry = json.loads((tmp_path / "report.json").read_text())["runs"]["beta"]
    assert entry["pnr_args"] == ["--placer-heap-beta", "0.7"]
    assert entry["status"].startswith("place and route failed")
    # the stall watchdog reads router1's table: with router2 it is refused, not ignored
    with pytest.raises(SystemExit, match="--stall-s watches router1"):
        run("fp_add", cfg, out=tmp_path, reuse="old", label="r2", router="router2", stall_s=60)
    assert len(calls) == 1
    with pytest.raises(SystemExit, match="nextpnr failed"):     # given: not passed twice
        run("fp_add", cfg, out=tmp_path, reuse="old", label="d",
            pnr_args=("--detailed-timing-report",))
    assert calls[-1].count("--detailed-timing-report") == 1


def test_outreg_only_on_a_reused_netlist(tmp_path):
    """``bram_outreg_only`` rewrites the reused netlist's copy (the original stays), records
    the result and takes the moved flip-flops off ``resources``; a netlist that has output
    registers already is refused."""
    from tests.test_fpga_outreg import CE, _ff, _netlist
    cfg = Config()
    (tmp_path / "old").mkdir()
    net = _netlist(9, ["DOB0", "DOB1"], {"f0": _ff(100, 200, ce=CE), "f1": _ff(101, 201, ce=CE)})
    (tmp_path / "old" / "fpga_top.json").write_text(json.dumps(net))
    (tmp_path / "old" / "fpga_top.stat").write_text(
        "   Number of cells:                  3\n     DP16KD                          1\n"
        "     TRELLIS_FF                      2\n")
    old = {"top": "fp_add", "config": cfg.to_dict(), "fmt": "E8M23", "latency": None,
           "wrapper": {"ff": 0},
           "resources": dict.fromkeys(("lut4", "ff", "dsp", "bram", "carry", "pfumx", "l6mux",
                                       "lutram", "alu54"), 0)}
    (tmp_path / "report.json").write_text(json.dumps({"runs": {"old": old}}))
    e = run("fp_add", cfg, out=tmp_path, reuse="old", label="o", pnr=False,
            bram_outreg_only="^ra")
    assert e["bram_outreg"] == {"ports": 1, "bits": 2, "skipped": {}, "only": "^ra"}
    assert e["cells"]["TRELLIS_FF"] == 0 and e["cells"]["DP16KD"] == 1
    ram = json.loads((tmp_path / "o" / "fpga_top.json").read_text())[
        "modules"]["fpga_top"]["cells"]["ram"]
    assert ram["parameters"]["REGMODE_B"] == "OUTREG"
    assert json.loads((tmp_path / "old" / "fpga_top.json").read_text()) == net
    e = run("fp_add", cfg, out=tmp_path, reuse="old", label="n", pnr=False,
            bram_outreg_only="stack")
    assert e["bram_outreg"]["skipped"] == {"not selected": 1}
    assert e["cells"]["TRELLIS_FF"] == 2
    with pytest.raises(SystemExit, match="output registers already"):
        run("fp_add", cfg, out=tmp_path, reuse="o", label="twice", pnr=False,
            bram_outreg_only="^ra")


def test_congestion_units_and_shares(tmp_path):
    """Cells are mapped to the unit path in their names, each tile's overuse is split between
    the units by their cells there, the quietest iteration is chosen, and the map is drawn."""
    from saarcor.flows.fpga.congestion import attribute, read_heatmap, report, tile_units, unit_of
    from saarcor.flows.fpga.flow import main
    assert unit_of("dut.rtcmi.cache_int.queue.q_wait_TRELLIS_FF_Q") == "rtcmi.cache_int"
    assert unit_of("dut.rtc.int.pipe.add3.s2_TRELLIS_FF_Q") == "rtc.int.pipe"
    assert unit_of("dut.rtc.int.n_mask_LUT4_Z") == "rtc.int"
    assert unit_of("dut.pipe.a_sxz$619.$42_MULT18X18D_P9") == "pipe"
    assert unit_of("dut.done__valid_LUT4_Z") == "top"
    assert unit_of("$1_TRELLIS_FF_Q") == "other"
    # the CSVs hold a row per tile column x: iteration 1 has 6 in tile (x=1, y=0) and 2 in
    # (0, 1); iteration 2 less
    (tmp_path / "heatmap_congestion_by_coordinate_1.csv").write_text("0,2,\n6,0,\n")
    (tmp_path / "heatmap_congestion_by_coordinate_2.csv").write_text("0,1,\n3,0,\n")
    (tmp_path / "heatmap_congestion_by_net_2.csv").write_text(
        "dut.rtc.trav.x_LUT4_Z,5\ndut.rtcmi.cache_int.y$3.z,1\n$PACKER_GND_NET,2\n")
    assert read_heatmap(tmp_path / "heatmap_congestion_by_coordinate_1.csv").tolist() == \
        [[0, 6], [2, 0]]
    cells = {
        "dut.rtc.trav.a_TRELLIS_FF_Q": ("TRELLIS_FF", "X1/Y0/SLICEA"),
        "dut.rtc.trav.b_LUT4_Z": ("TRELLIS_COMB", "X1/Y0/SLICEB"),
        "dut.rtcmi.cache_int.c_LUT4_Z": ("TRELLIS_COMB", "X1/Y0/SLICEC"),
        "dut.rtcmi.cache_int.d_LUT4_Z": ("TRELLIS_COMB", "X0/Y1/SLICEA"),
        "dut.rtc.trav.e_TRELLIS_FF_Q": ("TRELLIS_FF", "X0/Y0/SLICEA"),
        "dut.rtc.trav.port": ("TRELLIS_IO", "X0/Y0/PIOA"),          # not a logic site
    }
    placed = {"modules": {"top": {"cells": {
        n: {"type": t, "attributes": {"NEXTPNR_BEL": b}} for n, (t, b) in cells.items()}}}}
    tiles = tile_units(placed)
    assert tiles[(1, 0)] == {"rtc.trav": 2, "rtcmi.cache_int": 1}
    assert sum(map(sum, (t.values() for t in tiles.values()))) == 5
    shares = attribute(read_heatmap(tmp_path / "heatmap_congestion_by_coordinate_1.csv"), tiles)
    # tile (1, 0): 6 wires, 2/3 to the traversal; tile (0, 1): 2 wires, all to the cache
    # (each value is a product and a division of small integers: exact, or rounded once as
    # the literal is)
    assert shares["rtc.trav"]["overuse"] == 4.0
    assert shares["rtcmi.cache_int"]["overuse"] == 4.0
    assert shares["rtc.trav"]["share"] == 0.5 and shares["rtc.trav"]["cell_share"] == 0.6
    with pytest.raises(SystemExit, match="placed.json"):
        report(tmp_path)
    (tmp_path / "placed.json").write_text(json.dumps(placed))
    res = report(tmp_path)
    assert res["iteration"] == 2 and res["overuse_by_iteration"] == {1: 8, 2: 4}
    assert res["units"]["rtc.trav"]["overuse"] == 2.0           # 3 * 2/3
    assert res["units"]["rtcmi.cache_int"]["overuse"] == 2.0    # 3/3 + 1
    assert res["units"]["rtc.trav"]["net_excess"] == 5 and res["units"]["other"]["net_excess"] == 2
    assert res["units"]["rtcmi.cache_int"]["net_share"] == 0.125
    assert (tmp_path / "congestion.png").stat().st_size > 1000
    assert json.loads((tmp_path / "congestion.json").read_text())["iteration"] == 2
    with pytest.raises(SystemExit, match="iteration 7"):
        report(tmp_path, iteration=7)
    with pytest.raises(SystemExit, match="no router2 heatmaps"):
        main(["--congestion", "nothing", "--out", str(tmp_path)])


def _router1_log(rows) -> str:
    """A nextpnr log with router1's progress table: (seconds, arcs left) rows."""
    head = ("Info: Routing 227694 arcs.\n"
            "Info:            |   (re-)routed arcs  |   delta    | remaining|       time spent     |\n"
            "Info:    IterCnt |  w/ripup   wo/ripup |  w/r  wo/r |      arcs| batch(sec) total(sec)|\n")
    return head + "".join(f"Info: {1000 * (i + 1):10d} | {300 * i:8d} {700 * i:10d} | "
                          f"{300:4d} {700:5d} | {n:9d}| {1.5:10.2f} {t:10.2f}|\n"
                          for i, (t, n) in enumerate(rows))


def test_router1_stall_rule():
    """Stalled: the fewest arcs left have not fallen 2 % in the last window of routing time;
    steady progress, a log shorter than the window, or no router1 table: not stalled."""
    from saarcor.flows.fpga.flow import router1_progress, router1_stalled
    steady = [(10.0 * i, 200_000 - 300 * i) for i in range(100)]          # 990 s
    assert router1_progress(_router1_log(steady[:2])) == [(0.0, 200_000), (10.0, 199_700)]
    assert not router1_stalled(_router1_log(steady), 300)
    stuck = steady[:40] + [(400.0 + 10 * i, 188_000 + 50 * (i % 3)) for i in range(60)]
    assert router1_stalled(_router1_log(stuck), 300)       # 600 s without a new low
    assert not router1_stalled(_router1_log(stuck[:45]), 300)   # 3 % gained in the window
    slow = [(10.0 * i, 200_000 - 20 * i) for i in range(100)]    # 0.3 % per 300 s
    assert router1_stalled(_router1_log(slow), 300)
    assert not router1_stalled(_router1_log(steady[:20]), 300)
    assert not router1_stalled("Info: Router2 time 301.25s\n", 300)


def test_router1_watch_stops_a_batch_longer_than_the_window():
    """The watch: router1's rule over the log, and a log whose last row is older than the
    window in wall time; before routing starts (no rows) nothing is stalled."""
    from saarcor.flows.fpga.flow import Router1Watch
    steady = [(10.0 * i, 200_000 - 300 * i) for i in range(20)]
    w = Router1Watch(300)
    assert not w.stalled("Info: HeAP placer\n", 0.0)
    assert not w.stalled("Info: HeAP placer\n", 1000.0)       # placing: no rows yet
    assert not w.stalled(_router1_log(steady[:10]), 1000.0)
    assert not w.stalled(_router1_log(steady[:10]), 1299.0)    # the last row 299 s ago
    assert not w.stalled(_router1_log(steady[:11]), 1299.5)    # a new row: the clock restarts
    assert w.stalled(_router1_log(steady[:11]), 1600.0)        # 300.5 s without a row
    stuck = steady + [(200.0 + 10 * i, 194_000) for i in range(40)]
    assert Router1Watch(300).stalled(_router1_log(stuck), 0.0)  # the table's own rule


def test_watched_nextpnr_is_stopped_when_router1_stalls(tmp_path, monkeypatch):
    """``_nextpnr`` with a stall window stops a process whose log shows router1 stalled, and
    lets one that finishes run to its end."""
    import sys

    import saarcor.flows.fpga.flow as flow
    monkeypatch.setattr(flow, "POLL_S", 0.05)
    stuck = [(10.0 * i, 100_000) for i in range(40)]
    log = tmp_path / "place.log"
    script = (f"import pathlib, sys, time; pathlib.Path({str(log)!r}).write_text({_router1_log(stuck)!r}); "
              "print('routing', file=sys.stderr, flush=True); time.sleep(60)")
    t0 = time.time()
    rc, err, stalled = flow._nextpnr([sys.executable, "-c", script], tmp_path, log, 300)
    assert stalled and rc != 0 and "routing" in err and time.time() - t0 < 30
    rc, err, stalled = flow._nextpnr([sys.executable, "-c", "print('done')"], tmp_path,
                                     tmp_path / "none.log", 300)
    assert (rc, stalled) == (0, False)


def test_seeds_tried_in_turn_until_one_routes(tmp_path, monkeypatch):
    """``--seed 1 2 3``: a stalled seed moves on to the next, which places the first run's
    netlist again under LABEL_sN; the first that routes ends the loop; none: an error."""
    import saarcor.flows.fpga.flow as flow
    calls = []

    def fake_run(top, cfg, **kw):
        calls.append((kw["seed"], kw["label"], kw["reuse"], kw["stall_s"]))
        if kw["seed"] in routed:
            return {"label": kw["label"], "fmax": {"clk": 70.0}}
        raise flow.RouteStalled(f"{kw['label']} stalled")
    monkeypatch.setattr(flow, "run", fake_run)
    routed = {2}
    flow.main(["--top", "fp_add", "--label", "x", "--seed", "1", "2", "3", "--stall-s", "600",
               "--out", str(tmp_path)])
    assert calls == [(1, "x", None, 600.0), (2, "x_s2", "x", 600.0)]
    calls.clear()
    routed = set()
    with pytest.raises(SystemExit, match=r"no seed of \[1, 2\] routed x"):
        flow.main(["--top", "fp_add", "--label", "x", "--seed", "1", "2", "--stall-s", "60",
                   "--out", str(tmp_path)])
    assert [c[0] for c in calls] == [1, 2]
    with pytest.raises(SystemExit, match="several --seed values"):
        flow.main(["--top", "fp_add", "--seed", "1", "2", "--synth-only"])


def _dsp_netlist(path, registered):
    """fpga_top: flip-flop q -> MULT18X18D (A0) -> flip-flop r (from P0)."""
    reg = "CLK0" if registered else "NONE"
    cells = {
        "q": {"type": "TRELLIS_FF", "port_directions": {"DI": "input", "Q": "output"},
              "connections": {"DI": [10], "Q": [2]}},
        "dsp": {"type": "MULT18X18D", "parameters": {"REG_INPUTA_CLK": reg,
                                                    "REG_INPUTB_CLK": reg,
                                                    "REG_OUTPUT_CLK": reg},
                "port_directions": {"A0": "input", "P0": "output"},
                "connections": {"A0": [2], "P0": [3]}},
        "r": {"type": "TRELLIS_FF", "port_directions": {"DI": "input", "Q": "output"},
              "connections": {"DI": [3], "Q": [11]}},
    }
    path.write_text(json.dumps({"modules": {"fpga_top": {"cells": cells}}}))
    return path


def test_path_estimate_knows_the_dsp_registers(tmp_path):
    """``--estimate``: a MULT18X18D without its own registers is a 4.5 ns step between two
    flip-flops; with them, the path into it ends at its inputs and the path out of it starts
    at its output register."""
    from saarcor.flows.fpga.paths import DSP, DSP_CQ, FF_CQ, SETUP, estimate
    plain = {e["end"]: e for e in estimate(_dsp_netlist(tmp_path / "a.json", False), route=1.0)}
    assert plain["r"]["path"] == ["q", "dsp", "r"]
    assert plain["r"]["ns"] == round(FF_CQ + 1.0 + DSP + 1.0 + SETUP, 2)
    assert "dsp" not in plain
    reg = {e["end"]: e for e in estimate(_dsp_netlist(tmp_path / "b.json", True), route=1.0)}
    assert reg["dsp"]["path"] == ["q", "dsp"] and reg["r"]["path"] == ["dsp", "r"]
    assert reg["r"]["ns"] == round(DSP_CQ + 1.0 + SETUP, 2)


def test_routed_estimate_ranks_endpoints_by_nextpnr_arrivals(tmp_path):
    """``--estimate LABEL --routed``: each endpoint's time is its latest routed arrival from
    nextpnr's detailed net timings (the worst over its inputs), its path named from the
    estimate; endpoints nextpnr does not list are left out; a report without the detailed
    timings is refused with the option that writes them."""
    from saarcor.flows.fpga.paths import estimate, report, routed_arrivals
    net = _dsp_netlist(tmp_path / "n.json", False)
    rep = tmp_path / "report.json"
    rep.write_text(json.dumps({"detailed_net_timings": [
        {"net": "a", "driver": "q", "port": "Q", "endpoints": [
            {"cell": "r", "port": "DI", "delay": [1.0, 11.5]},
            {"cell": "x", "port": "DI", "delay": [0.5, 3.0]}]},
        {"net": "b", "driver": "q", "port": "Q", "endpoints": [
            {"cell": "r", "port": "CE", "delay": [0.5, 12.25]}]}]}))
    routed = routed_arrivals(rep)
    assert routed == {"r": 12.25, "x": 3.0}
    guess = {e["end"]: e for e in estimate(net, route=1.0)}
    ends = estimate(net, route=1.0, routed=routed)
    assert [e["end"] for e in ends] == ["r"]          # q is not in the report
    assert ends[0]["ns"] == 12.25 and ends[0]["est"] == guess["r"]["ns"]
    assert ends[0]["path"] == ["q", "dsp", "r"]
    text = report(net, period=10.0, routed=routed)
    assert text.startswith("1 of 1 endpoints routed over 10.0 ns") and "12.25 ns" in text
    rep.write_text(json.dumps({"critical_paths": []}))
    with pytest.raises(ValueError, match="--detailed-timing-report"):
        routed_arrivals(rep)
