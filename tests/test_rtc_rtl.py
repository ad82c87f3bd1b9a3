"""The whole RTC in Amaranth (``rtl/rtc.py``) against the golden model (``tb/units/rtc.py``): every
ray's result (triangle, t, u, v bits) and the trav-op / list-op / int-op counters."""
import pytest

from model.config import Config
from rtl.common import POISON_ENV
from rtl.rtc import RTC
from tb.harness.common import synth_check
from tb.units.rtc import run_rtc, run_rtc_free
from tb.units.traversal import small_case

from .conftest import ROOT, TIMING, timing_changed

# CI size: the whole RTC runs at a few hundred cycles/s in pysim, so packets of 4x4 rays,
# 2 packets per scene, through 2 threads and 2 traversal sub-units
TINY = Config(threads=2, tile_w=4, tile_h=4, trav_subunits=2)


def check(r, rays):
    assert r.rays == len(rays)
    assert r.mismatches == []
    assert r.counter_mismatches() == {}
    assert r.counters["packets_done"] == rays.n_packets
    assert r.counters["int_ops"] > 0


@pytest.mark.parametrize("scene,res,seed", [("cornell", (12, 4), 1), ("office", (4, 4), 2),
                                            ("conference", (4, 4), 3)])
def test_rtc_matches_model(scene, res, seed, kd_cache):
    """1-3 packets per scene (Cornell: 3 packets through 2 threads, so a thread is reused);
    LFSR-driven input bubbles and result back-pressure (in hardware: no Python per cycle)."""
    image, rays = small_case(ROOT / f"scenes/{scene}.toml", *res, TINY, kd_cache)
    assert rays.n_packets == res[0] * res[1] // 16
    r = run_rtc_free(image, rays, TINY, mem_latency=4, idle=0.25, stall=0.3, seed=seed)
    check(r, rays)
    if scene == "cornell":
        assert r.cycles == TIMING["rtc/cornell_12x4"], timing_changed("rtc/cornell_12x4", r.cycles)


def test_rtc_matches_model_with_deep_fp_pipelines_and_async_subunits(kd_cache, monkeypatch):
    """The FPGA timing configuration (add 6, mul 5, div 20 stages) with asynchronous sub-units:
    the same bits and counters (the units re-time themselves from the FP latencies). Every
    block-RAM read of a row written in its cycle returns garbage (``SAARCOR_RAM_POISON``):
    no such read is used."""
    monkeypatch.setenv(POISON_ENV, "1")
    cfg = TINY.replace(fp_add_latency=6, fp_mul_latency=5, fp_div_latency=20, trav_sync=False)
    image, rays = small_case(ROOT / "scenes/office.toml", 4, 4, cfg, kd_cache)
    r = run_rtc_free(image, rays, cfg, mem_latency=4, idle=0.25, stall=0.3, seed=4)
    check(r, rays)


# the FPGA build's settings (docs/fpga.md, make fpga): deeper FP units and compare units,
# block-RAM reads registered and the other registers of Config.fast_clock
DEEP = dict(fast_clock=True, fp_add_latency=8, fp_mul_latency=5, fp_div_latency=29,
            fp_cmp_latency=3)


def test_rtc_matches_model_fast_clock(kd_cache, monkeypatch):
    """The FPGA build's settings, 3 packets through 2 threads (a thread is reused), bubbles
    and back-pressure: the same bits and counters as the model, with every block-RAM read of
    a row written in its cycle returning garbage (``SAARCOR_RAM_POISON``)."""
    monkeypatch.setenv(POISON_ENV, "1")
    cfg = TINY.replace(**DEEP)
    image, rays = small_case(ROOT / "scenes/cornell.toml", 12, 4, cfg, kd_cache)
    r = run_rtc_free(image, rays, cfg, mem_latency=4, idle=0.25, stall=0.3, seed=5)
    check(r, rays)


@pytest.mark.slow
def test_rtc_python_testbench_standard(kd_cache):
    """Standard configuration, 2 packets of 64 rays, Python-driven random bubbles and stalls."""
    cfg = Config()
    image, rays = small_case(ROOT / "scenes/conference.toml", 16, 8, cfg, kd_cache)
    check(run_rtc(image, rays, cfg, mem_latency=20, idle=0.2, stall=0.3), rays)


@pytest.mark.slow
@pytest.mark.parametrize("scene", ["cornell", "office", "terrain"])
def test_rtc_matches_model_standard(scene, kd_cache):
    """The standard configuration (16 threads, 4 sub-units, 64-ray packets), 64x48 eye rays.
    (Terrain's 1.9 M-word image takes minutes to load into the simulator's memories.)"""
    cfg = Config()
    image, rays = small_case(ROOT / f"scenes/{scene}.toml", 64, 48, cfg, kd_cache)
    check(run_rtc_free(image, rays, cfg, mem_latency=20, stall=0.25), rays)


@pytest.mark.slow
def test_rtc_synthesizes_without_latches():
    cfg = Config(threads=2, tile_w=2, tile_h=2, trav_subunits=2, kd_max_depth=2)
    assert "cells" in synth_check(RTC(cfg), "rtc")


@pytest.mark.slow
def test_threads_sweep_writes_bench():
    """``make bench``: the threads sweep (``saarcor.bench.threads``) -> build/bench/threads.json;
    every run is checked against the model, and more threads must not be slower."""
    from saarcor.bench.threads import main
    res = main(["--out", str(ROOT / "build" / "bench")])
    cycles = [r["cycles"] for r in res["runs"]]
    assert all(b <= a for a, b in zip(cycles, cycles[1:])), cycles
    assert res["runs"][1]["speedup"] > 1.5          # 2 threads hide most of one's latency
