"""cocotb benches (``tb/cocotb/``) on the exported Verilog of every pipeline (``rtl.export``).

CI (``make test``) runs them under Icarus Verilog: no C++ build, so each bench costs its
simulator start-up (~2-3 s) plus the run; the same benches under Verilator (a 15-60 s C++ build
per top) are marked slow (``make bench``). ``docs/cocotb.md`` has the figures. Deliberately
broken exports (a flipped rounding rule, a dropped ``last`` flag) must make the benches fail.
"""
from __future__ import annotations

import re
import zlib

import pytest

from model.config import Config
from tb.cocotb.runner import BenchFailed

from .conftest import ROOT

CI_SIM = "icarus"
SIMS = [CI_SIM, pytest.param("verilator", marks=pytest.mark.slow)]
# the RTC units in a small configuration (2 threads, 4x4 packets, 2 traversal sub-units) with
# small caches: small Verilog, misses in every cache
TINY = Config(threads=2, tile_w=4, tile_h=4, trav_subunits=2, trav_cache_kb=1, list_cache_kb=1,
              int_cache_kb=9)


@pytest.fixture(scope="module")
def cornell(kd_cache):
    """Cornell box, 16x16 eye rays in the standard configuration, with the event log."""
    from tb.list import golden
    return golden(ROOT / "scenes" / "cornell.toml", 16, 16, Config(), kd_cache)


@pytest.fixture(scope="module")
def cornell_tiny(kd_cache):
    from tb.list import golden
    return golden(ROOT / "scenes" / "cornell.toml", 12, 4, TINY, kd_cache)


# ---- FP units: every result at its exact cycle ------------------------------------------------

@pytest.mark.parametrize("sim", SIMS)
@pytest.mark.parametrize("kind", ["add", "mul", "div", "cmp", "min", "conv"])
def test_fp_unit(kind, sim, tmp_path):
    from tb.cocotb.fp import run_fp
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
    from tb.cocotb.fp import run_fp
    with pytest.raises(BenchFailed, match=r"fp_mul: cycle \d+, operation #\d+ \(a=0x[0-9a-f]+, "
                                          r"b=0x[0-9a-f]+\): o=0x[0-9a-f]+, model 0x[0-9a-f]+"):
        run_fp("mul", sim, tmp_path, n=300, seed=1, patch=round_half_up)


# ---- the RTC's units, the cache and the bus: the golden model's streams -----------------------

@pytest.mark.parametrize("sim", SIMS)
def test_list_unit(cornell, sim, tmp_path):
    from tb.cocotb.list import run_list
    r = run_list(cornell, sim, tmp_path, seed=3)
    assert r.values["entries"] > 500


def drop_last_flag(verilog: str) -> str:
    """Break the list unit's output: ``last`` (the TriRequest's top bit) stuck at 0."""
    return re.sub(r"assign tri__payload\[100\] = [^;]+;", "assign tri__payload[100] = 1'h0;",
                  verilog)


def test_list_bench_fails_on_broken_output(cornell, tmp_path):
    from tb.cocotb.list import run_list
    with pytest.raises(BenchFailed, match=r"tri #\d+ at cycle \d+: 0x[0-9a-f]+: "
                                          r"last 0x0 \(model 0x1\)"):
        run_list(cornell, CI_SIM, tmp_path, seed=3, patch=drop_last_flag)


@pytest.mark.parametrize("sim", SIMS)
@pytest.mark.parametrize("unit", ["trav", "list", "int"])
def test_cache(unit, sim, cornell_tiny, tmp_path):
    from tb.cocotb.cache import run_cache
    _, cr = run_cache(unit, cornell_tiny, sim, tmp_path, n=300, seed=len(unit))
    assert cr.hits > 0 and cr.misses > 0


@pytest.mark.parametrize("sim", SIMS)
def test_bus(cornell, sim, tmp_path):
    from tb.cocotb.bus import run_bus
    r = run_bus(cornell, sim, tmp_path, n=200, seed=2)
    assert r.values["counters"]["req_cycles"] == 600


@pytest.mark.parametrize("sim", SIMS)
def test_traversal(sim, kd_cache, tmp_path):
    """3 packets through 2 threads (a thread is released and reused)."""
    from tb.cocotb.traversal import run_traversal
    from tb.traversal import small_case
    image, rays = small_case(ROOT / "scenes" / "cornell.toml", 12, 4, TINY, kd_cache)
    r = run_traversal(image, rays, TINY, sim, tmp_path, seed=1)
    assert r.values["leaf_requests"] > 10


@pytest.mark.parametrize("sim", SIMS)
def test_intersect_pipe(sim, tmp_path):
    """The 42-FP-unit datapath on corner-case ray/triangle tests, every output at its exact
    cycle (Icarus runs it at well under 100 cycles/s: CI keeps it short)."""
    from model.fp import BINARY32
    from tb.cocotb.intersection import run_pipe
    from tb.intersection import random_tests
    r = run_pipe(random_tests(96, BINARY32, seed=4), sim, tmp_path, seed=4)
    assert r.values["ops"] == 96


@pytest.mark.parametrize("top,sim", [
    ("rtc", CI_SIM), pytest.param("rtc", "verilator", marks=pytest.mark.slow),
    # the bare RTC (three memory ports) is inside the rtc top: CI runs only the top
    *[pytest.param("rtc_core", sim, marks=pytest.mark.slow) for sim in ("icarus", "verilator")]])
def test_rtc(top, sim, kd_cache, tmp_path):
    """One 4x4 packet of Cornell eye rays through the whole RTC (``rtc``: with its RTC-MI caches
    and bus, one memory port): every ray's result and every counter against the model."""
    from tb.cocotb.rtc import run_rtc
    from tb.traversal import small_case
    image, rays = small_case(ROOT / "scenes" / "cornell.toml", 4, 4, TINY, kd_cache)
    run, r = run_rtc(image, rays, TINY, sim, tmp_path, top=top, seed=2)
    assert run.mismatches == [] and run.counter_mismatches() == {}
    assert run.rays == 16 and run.counters["int_ops"] > 0


@pytest.mark.parametrize("sim", SIMS)
def test_intersection_unit(sim, kd_cache, tmp_path):
    """Every leaf of two 4x4 Cornell packets; the triangle port answers whole triangles."""
    from tb.cocotb.intersection import run_unit
    from tb.list import golden
    g = golden(ROOT / "scenes" / "cornell.toml", 8, 4, TINY, kd_cache)
    r = run_unit(g, sim, tmp_path, seed=1)
    assert r.values["counters"]["int_ops"] > 50


@pytest.mark.parametrize("sim", SIMS)
def test_ray_setup(sim, tmp_path):
    """The edge cases of ray setup (zero and signed-zero components, |d| ties, origins on the
    box's faces, infinities, tiny and huge values) and random rays."""
    from model.fp import BINARY32
    from tb.cocotb.rgs import run_ray_setup
    from tb.rgs import AXIS_BOX, edge_rays
    bounds = BINARY32.quantize(AXIS_BOX)
    rays = edge_rays(BINARY32, bounds, n_random=40, seed=3)
    r = run_ray_setup(rays, bounds, Config(), sim, tmp_path, seed=3)
    assert r.values["outputs"] == len(rays)


@pytest.mark.parametrize("sim", SIMS)
def test_eye_rays(sim, tmp_path):
    """Two 8x8 tiles of a 15x12 frame requested out of order with arbitrary ids: the last
    (7x4 pixels, partial) and the first (8x8)."""
    from model.fp import BINARY32
    from tb.cocotb.rgs import run_eye_rays
    from tb.rgs import AXIS_BOX, axis_camera
    r = run_eye_rays(axis_camera(), 15, 12, Config(), BINARY32.quantize(AXIS_BOX), sim,
                     tmp_path, tiles=[3, 0], packet_ids=[7, 0xFFFFFFFF], seed=2)
    assert r.values["outputs"] == 7 * 4 + 8 * 8
