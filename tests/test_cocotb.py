"""cocotb benches (``tb/harness/cocotb/``) on the exported Verilog of every pipeline (``tb.harness.tops``).

CI (``make test``) runs them under Icarus Verilog: no C++ build, so each bench costs its
simulator start-up (~2-3 s) plus the run; the same benches under Verilator (a 15-60 s C++ build
per top) are marked slow (``make bench``), and so is the whole chip on either simulator
(Icarus runs it at about 200 cycles/s). ``docs/cocotb.md`` has the figures. Deliberately
broken exports (a flipped rounding rule, a dropped ``last`` flag, a stuck result bit of the
chip) must make the benches fail.
"""
from __future__ import annotations

import re
import zlib

import numpy as np
import pytest

from model.config import Config
from tb.harness.cocotb.runner import BenchFailed

from .conftest import ROOT, TIMING, timing_changed
from .test_chip import TINY as CHIP, check_frame

CI_SIM = "icarus"
SIMS = [CI_SIM, pytest.param("verilator", marks=pytest.mark.slow)]
# the RTC units in a small configuration (2 threads, 4x4 packets, 2 traversal sub-units) with
# small caches: small Verilog, misses in every cache
TINY = Config(threads=2, tile_w=4, tile_h=4, trav_subunits=2, trav_cache_kb=1, list_cache_kb=1,
              int_cache_kb=9)


@pytest.fixture(scope="module")
def cornell(kd_cache):
    """Cornell box, 16x16 eye rays in the standard configuration, with the event log."""
    from tb.units.list import golden
    return golden(ROOT / "scenes" / "cornell.toml", 16, 16, Config(), kd_cache)


@pytest.fixture(scope="module")
def cornell_tiny(kd_cache):
    from tb.units.list import golden
    return golden(ROOT / "scenes" / "cornell.toml", 12, 4, TINY, kd_cache)


# ---- FP units: every result at its exact cycle ------------------------------------------------

@pytest.mark.parametrize("sim", SIMS)
@pytest.mark.parametrize("kind", ["add", "mul", "div", "cmp", "min", "conv"])
def test_fp_unit(kind, sim, tmp_path):
    from tb.harness.cocotb.fp import run_fp
    r = run_fp(kind, sim, tmp_path, n=300, seed=zlib.crc32(kind.encode()))
    v = r.values
    assert v["ops"] > 300 and v["cycles"] > v["ops"]       # bubbles and stalls happened


def round_half_up(verilog: str) -> str:
    """Break the RNE rounding: the increment becomes the guard bit alone (ties round away
    from zero instead of to even), as a one-word slip in the Verilog would."""
    return re.sub(r"assign rnd_inc = (\S+ \[\d+\]) &[^;]*;", r"assign rnd_inc = \1;", verilog)


@pytest.mark.parametrize("sim", SIMS)
def test_fp_bench_fails_on_broken_rounding(sim, tmp_path):
    """The multiplier's Verilog with ties rounded away from zero: the bench names the first
    operation whose result differs (a tie), its cycle and both results."""
    from tb.harness.cocotb.fp import run_fp
    with pytest.raises(BenchFailed, match=r"fp_mul: cycle \d+, operation #\d+ \(a=0x[0-9a-f]+, "
                                          r"b=0x[0-9a-f]+\): o=0x[0-9a-f]+, model 0x[0-9a-f]+"):
        run_fp("mul", sim, tmp_path, n=300, seed=1, patch=round_half_up)


# ---- the RTC's units, the cache and the bus: the golden model's streams -----------------------

@pytest.mark.parametrize("sim", SIMS)
def test_list_unit(cornell, sim, tmp_path):
    from tb.harness.cocotb.list import run_list
    r = run_list(cornell, sim, tmp_path, seed=3)
    assert r.values["entries"] > 500


def drop_last_flag(verilog: str) -> str:
    """Break the list unit's output: ``last`` (the TriRequest's top bit) stuck at 0."""
    return re.sub(r"assign tri__payload\[100\] = [^;]+;", "assign tri__payload[100] = 1'h0;",
                  verilog)


def test_list_bench_fails_on_broken_output(cornell, tmp_path):
    from tb.harness.cocotb.list import run_list
    with pytest.raises(BenchFailed, match=r"tri #\d+ at cycle \d+: 0x[0-9a-f]+: "
                                          r"last 0x0 \(model 0x1\)"):
        run_list(cornell, CI_SIM, tmp_path, seed=3, patch=drop_last_flag)


@pytest.mark.parametrize("sim", SIMS)
@pytest.mark.parametrize("unit", ["trav", "list", "int"])
def test_cache(unit, sim, cornell_tiny, tmp_path):
    from tb.harness.cocotb.cache import run_cache
    _, cr = run_cache(unit, cornell_tiny, sim, tmp_path, n=300, seed=len(unit))
    assert cr.hits > 0 and cr.misses > 0


@pytest.mark.parametrize("sim", SIMS)
def test_bus(cornell, sim, tmp_path):
    from tb.harness.cocotb.bus import run_bus
    r = run_bus(cornell, sim, tmp_path, n=200, seed=2)
    assert r.values["counters"]["req_cycles"] == 600


@pytest.mark.parametrize("sim", SIMS)
def test_traversal(sim, kd_cache, tmp_path):
    """3 packets through 2 threads (a thread is released and reused)."""
    from tb.harness.cocotb.traversal import run_traversal
    from tb.units.traversal import small_case
    image, rays = small_case(ROOT / "scenes" / "cornell.toml", 12, 4, TINY, kd_cache)
    r = run_traversal(image, rays, TINY, sim, tmp_path, seed=1)
    assert r.values["leaf_requests"] > 10


@pytest.mark.parametrize("sim", SIMS)
def test_intersect_pipe(sim, tmp_path):
    """The 42-FP-unit datapath on corner-case ray/triangle tests, every output at its exact
    cycle (Icarus runs it at well under 100 cycles/s: CI keeps it short)."""
    from model.fp import BINARY32
    from tb.harness.cocotb.intersection import run_pipe
    from tb.units.intersection import random_tests
    r = run_pipe(random_tests(96, BINARY32, seed=4), sim, tmp_path, seed=4)
    assert r.values["ops"] == 96


@pytest.mark.parametrize("top,sim", [
    ("rtc", CI_SIM), pytest.param("rtc", "verilator", marks=pytest.mark.slow),
    # the bare RTC (three memory ports) is inside the rtc top: CI runs only the top
    *[pytest.param("rtc_core", sim, marks=pytest.mark.slow) for sim in ("icarus", "verilator")]])
def test_rtc(top, sim, kd_cache, tmp_path):
    """One 4x4 packet of Cornell eye rays through the whole RTC (``rtc``: with its RTC-MI caches
    and bus, one memory port): every ray's result and every counter against the model."""
    from tb.harness.cocotb.rtc import run_rtc
    from tb.units.traversal import small_case
    image, rays = small_case(ROOT / "scenes" / "cornell.toml", 4, 4, TINY, kd_cache)
    run, r = run_rtc(image, rays, TINY, sim, tmp_path, top=top, seed=2)
    assert run.mismatches == [] and run.counter_mismatches() == {}
    assert run.rays == 16 and run.counters["int_ops"] > 0


@pytest.mark.parametrize("sim", SIMS)
def test_intersection_unit(sim, kd_cache, tmp_path):
    """Every leaf of two 4x4 Cornell packets; the triangle port answers whole triangles."""
    from tb.harness.cocotb.intersection import run_unit
    from tb.units.list import golden
    g = golden(ROOT / "scenes" / "cornell.toml", 8, 4, TINY, kd_cache)
    r = run_unit(g, sim, tmp_path, seed=1)
    assert r.values["counters"]["int_ops"] > 50


@pytest.mark.parametrize("sim", SIMS)
def test_ray_setup(sim, tmp_path):
    """The edge cases of ray setup (zero and signed-zero components, |d| ties, origins on the
    box's faces, infinities, tiny and huge values) and random rays."""
    from model.fp import BINARY32
    from tb.harness.cocotb.rgs import run_ray_setup
    from tb.units.rgs import AXIS_BOX, edge_rays
    bounds = BINARY32.quantize(AXIS_BOX)
    rays = edge_rays(BINARY32, bounds, n_random=40, seed=3)
    r = run_ray_setup(rays, bounds, Config(), sim, tmp_path, seed=3)
    assert r.values["outputs"] == len(rays)


@pytest.mark.parametrize("sim", SIMS)
def test_eye_rays(sim, tmp_path):
    """Two 8x8 tiles of a 15x12 frame requested out of order with arbitrary ids: the last
    (7x4 pixels, partial) and the first (8x8)."""
    from model.fp import BINARY32
    from tb.harness.cocotb.rgs import run_eye_rays
    from tb.units.rgs import AXIS_BOX, axis_camera
    r = run_eye_rays(axis_camera(), 15, 12, Config(), BINARY32.quantize(AXIS_BOX), sim,
                     tmp_path, tiles=[3, 0], packet_ids=[7, 0xFFFFFFFF], seed=2)
    assert r.values["outputs"] == 7 * 4 + 8 * 8


# ---- the whole chip -----------------------------------------------------------------------------

def test_lfsr_pattern_is_the_hardware_lfsr():
    """The benches' :class:`LFSRPattern` holds a stream in exactly the cycles ``tb/harness/lfsr.py``'s
    LFSR does (what ``ChipFrame`` uses for its result back-pressure), from its seed on."""
    from amaranth.sim import Simulator

    from tb.harness.cocotb.streams import LFSRPattern
    from tb.harness.lfsr import LFSR, lfsr_seeds, passes
    seed, q = lfsr_seeds(3, 3)[1], 4
    dut = LFSR(loadable=True)
    sim = Simulator(dut)
    sim.add_clock(1e-8)
    held = []

    async def bench(ctx):
        ctx.set(dut.seed, seed)
        ctx.set(dut.en, 0)
        await ctx.tick()                       # loads the seed
        ctx.set(dut.en, 1)
        for _ in range(300):
            held.append(not ctx.get(passes(dut.value, q)))
            await ctx.tick()

    sim.add_testbench(bench)
    sim.run()
    pattern = LFSRPattern(q, seed)
    assert [pattern(k) for k in range(300)] == held
    assert 0.15 < sum(held) / 300 < 0.35


@pytest.fixture(scope="module")
def cornell_chip(kd_cache):
    """The Cornell box and its memory image (with the slave records) for the small chip."""
    from model.render import prepare
    from model.scene import load_scene
    scene = load_scene(ROOT / "scenes" / "cornell.toml")
    return scene, prepare(scene, CHIP, cache_dir=kd_cache).image


def run_chip_frame(cornell_chip, sim, tmp_path, *, top="chip", secondary=False, width=4,
                   height=4, **kw):
    """A Cornell frame through the chip's Verilog (25 % result back-pressure, seed 3, as
    ``tests/test_chip.py``'s frames); checked as ``tests/test_chip.py`` checks the Amaranth and
    Verilator frames."""
    from model.raygen import eye_rays
    from tb.harness.cocotb.chip import run_chip
    scene, image = cornell_chip
    run, r = run_chip(CHIP, image, scene.camera, width, height, sim, tmp_path, top=top,
                      scene=scene if secondary else None, stall=0.25, seed=3, **kw)
    check_frame(run, CHIP, image, eye_rays(scene.camera, width, height, CHIP))
    return run, r


@pytest.mark.slow
@pytest.mark.parametrize("sim,secondary", [("icarus", False), ("verilator", False),
                                           ("verilator", True)],
                         ids=["icarus-eye", "verilator-eye", "verilator-secondary"])
def test_chip(sim, secondary, cornell_chip, tmp_path):
    """The chip's Verilog (``make verilog TOP=chip``, 1 RTC) on a 4x4 Cornell frame: the bench
    sets the host registers, starts the frame, serves the memory port from the image (random
    delays and order, request back-pressure) and takes every result; every ray — with the
    scene its shadow and reflection rays too — bit-exact by its id, every ray in and out
    once, the RTC's counters the model's, the caches' grants the words the memory served.
    (Icarus runs the chip at 200-265 cycles/s: slow, ``docs/cocotb.md``.)"""
    run, r = run_chip_frame(cornell_chip, sim, tmp_path, secondary=secondary, mem_stall=0.25)
    assert run.counters["mem_words"] == [run.counters["mem_reads"]] == [r.values["served"]]
    if secondary:
        kinds = np.bincount(run.frame_rays.kind, minlength=3)
        assert kinds[1] > kinds[0] == 16


@pytest.mark.slow
def test_chip_on_sdram_has_the_amaranth_cycles(cornell_chip, tmp_path):
    """The chip on the SDRAM model (``tb/harness/chip_sdram.py``) in Verilator through cocotb, with
    ``ChipFrame``'s result back-pressure: the cycle counts of the Amaranth-simulator runs of
    ``tests/test_chip.py`` (the timing contract), eye rays and with the secondary rays."""
    run, _ = run_chip_frame(cornell_chip, "verilator", tmp_path / "eye", top="chip_sdram",
                            width=8, height=4)
    name = "chip/cornell_8x4_rtcs1"
    assert run.cycles == TIMING[name], timing_changed(name, run.cycles)
    assert len(run.counters["mem_words"]) == CHIP.mem_chips
    run, _ = run_chip_frame(cornell_chip, "verilator", tmp_path / "scene", top="chip_sdram",
                            secondary=True)
    name = "chip/cornell_4x4_scene_rtcs1"
    assert run.cycles == TIMING[name], timing_changed(name, run.cycles)


def stuck_t_lsb(verilog: str) -> str:
    """Break the chip's result output (in module ``chip``, the ``results`` port): bit 0 of
    every result's t stuck at 0."""
    from rtl.rgs import SlaveResult
    lay = SlaveResult(CHIP)
    hi, lo = lay.size - 1, lay["t"].offset
    start = verilog.index("\nmodule chip(")
    end = verilog.index("\nendmodule", start)
    body = verilog[start:end]
    port = f"  output [{hi}:0] results__payload;\n"
    assert body.count(port) == 1 and body.count(".o__payload(results__payload)") == 1
    body = body.replace(".o__payload(results__payload)", ".o__payload(results_raw)")
    body = body.replace(port, port + f"  wire [{hi}:0] results_raw;\n  assign results__payload = "
                        f"{{results_raw[{hi}:{lo + 1}], 1'h0, results_raw[{lo - 1}:0]}};\n")
    return verilog[:start] + body + verilog[end:]


@pytest.mark.slow
def test_chip_bench_fails_on_broken_output(cornell_chip, tmp_path):
    """The chip's Verilog with bit 0 of t stuck at 0: the comparison by ray id names the rays
    whose t is odd, and nothing else."""
    from tb.harness.cocotb.chip import run_chip
    scene, image = cornell_chip
    run, _ = run_chip(CHIP, image, scene.camera, 4, 4, CI_SIM, tmp_path, stall=0.25, seed=3,
                      patch=stuck_t_lsb)
    assert run.mismatches
    assert all(f == "t" and rtl == model & ~1 and model & 1 for _, f, rtl, model
               in run.mismatches)
