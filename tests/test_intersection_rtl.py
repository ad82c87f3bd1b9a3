"""Intersection unit (rtl/intersection.py) against the golden model (model/intersection.py).

Amaranth's simulator runs the 42-FP-unit datapath at only ~40-60 cycles/s when every unit
toggles, so CI checks a few hundred tests; the thousands run under ``-m slow``."""
import numpy as np
import pytest

from model.config import Config
from model.fp import FPFormat
from model.rtc import C
from tb.units.intersection import random_tests, run_pipe

from .conftest import TIMING, timing_changed

FMT = FPFormat()


def test_random_tests_cover_the_corner_cases():
    t = random_tests(600, FMT, seed=0)
    assert 0.3 < t.hit.mean() < 0.8
    assert np.isnan(t.t).any() and t.hit[np.isnan(t.t)].all()      # NaN t on a "hit" (inf-inf)
    assert not t.hit[2::6].any()                                    # degenerate: det = 0
    assert t.hit[1::6].mean() > 0.8                                 # exact edge/vertex hits


def test_pipe_random_binary32_exact_cycle():
    r = run_pipe(random_tests(240, FMT, seed=1), FMT, seed=1, p_bubble=0.2, p_stall=0.2)
    assert r.mismatches == [] and r.outputs == r.tests == 240
    assert r.latency == 33 and r.cycles >= 240 + 33
    assert r.cycles == TIMING["intersection/pipe_240"], timing_changed("intersection/pipe_240",
                                                                       r.cycles)


@pytest.mark.slow
def test_pipe_random_binary32_thousands():
    r = run_pipe(random_tests(3000, FMT, seed=2), FMT, seed=2, p_bubble=0.1, p_stall=0.1)
    assert r.mismatches[:5] == [] and r.outputs == r.tests == 3000
    print(f"IntersectPipe: {r.cycles} cycles in {r.seconds:.1f} s = {r.cycles_per_s:.0f} cycles/s")


@pytest.fixture(scope="module")
def cornell(kd_cache):
    from tb.units.list import golden
    from .conftest import ROOT
    return golden(ROOT / "scenes" / "cornell.toml", 16, 16, Config(), kd_cache)


def test_unit_matches_model_first_leaves(cornell):
    """The first leaves of 4 Cornell packets: every datapath output against EV_INT in order,
    every LaneResult against the model's best hit after the leaf, every lane's final hit."""
    from tb.units.intersection import run_unit
    r = run_unit(cornell, max_leaves=8, seed=1, idle=0.3, stall=0.3, latency=20)
    assert r.mismatches[:5] == []
    assert r.int_ops > 100 and r.counters["busy"] > 0
    name = "intersection/unit_first_leaves"
    assert r.cycles == TIMING[name], timing_changed(name, r.cycles)


def test_unit_deep_settings_first_leaves(kd_cache):
    """The deep settings on the first leaves of 4 Cornell packets, bubbles and back-pressure."""
    from tb.units.list import golden
    from tb.units.intersection import run_unit
    from .conftest import ROOT
    g = golden(ROOT / "scenes" / "cornell.toml", 16, 16, Config(**DEEP), kd_cache)
    r = run_unit(g, max_leaves=6, seed=3, idle=0.3, stall=0.3, latency=20)
    assert r.mismatches[:5] == [] and r.int_ops > 50


@pytest.mark.slow
def test_unit_matches_model_whole_image(cornell):
    from tb.units.intersection import run_unit
    r = run_unit(cornell, seed=2, idle=0.2, stall=0.2, latency=20)
    assert r.mismatches[:5] == []
    assert r.counters["int_ops"] == cornell.counters.sum(axis=0)[C["int_ops"]]
    print(f"IntersectionUnit: {r.cycles} cycles in {r.seconds:.1f} s = "
          f"{r.cycles_per_s:.0f} cycles/s")


# the deep settings of the FPGA build (docs/fpga.md): deeper FP units, block-RAM reads
# registered with the best hit's stores forwarded, a registered readout (fast_clock)
DEEP = dict(fast_clock=True, fp_add_latency=6, fp_mul_latency=5, fp_div_latency=29)


@pytest.mark.parametrize("deep", [False, True], ids=["default", "deep"])
def test_unit_every_test_accepts_small_slots_fast_memory(kd_cache, deep):
    """One-ray packets against a stack of quads listed far to near (every layer's hit
    replaces the previous best) and near to far (every later hit is rejected): back-to-back
    tests of one lane after a stall, each needing the previous one's store (with the deep
    settings: a store the best-hit read missed, forwarded); two triangle slots and a 2-cycle
    memory; LaneResults back-pressured."""
    from tb.units.intersection import golden_stack, run_unit
    from model.events import EV_INT
    cfg = Config(kd_leaf_size=32, **(DEEP if deep else {}))
    for near_first in (False, True):
        g = golden_stack(cfg, kd_cache, layers=6, near_first=near_first)
        ints = g.events[g.events["kind"] == EV_INT]
        accepts = ((ints["flags"] & 2) != 0).sum()
        # near first: the nearest layer's two triangles only (rounding may favour either)
        assert 8 <= accepts <= 16 if near_first else accepts >= 6 * 8
        r = run_unit(g, seed=5, idle=0.0, stall=0.4, latency=2, tri_slots=2)
        assert r.mismatches[:5] == []
        assert r.counters["tris"] == len(ints) and r.int_ops == len(ints)  # one ray a packet
    # through the int cache: the triangles of every packet after the first hit and arrive
    # one a cycle, so one lane's tests follow each other back to back
    g = golden_stack(cfg.replace(int_cache_kb=1), kd_cache, layers=6, near_first=True)
    r = run_unit(g, seed=6, idle=0.0, stall=0.0, latency=4, tri_slots=8, cache=True)
    assert r.mismatches[:5] == []


@pytest.mark.parametrize("deep", [False, True], ids=["default", "deep"])
def test_unit_newest_forwarded_store_wins(kd_cache, deep):
    """Per ray: a miss, hits at t 9 and t 7, a miss, a hit at t 8, back to back through the
    int cache (one ray a packet). With the deep settings the t 8 test's best-hit read misses
    the two stores before it, both of the lane: the newer (t 7) must reject it."""
    from model.events import EV_INT
    from tb.units.intersection import golden_newest_store, run_unit
    cfg = Config(kd_leaf_size=32, int_cache_kb=1, **(DEEP if deep else {}))
    g = golden_newest_store(cfg, kd_cache)
    tri = np.asarray(g.hits.tri)
    assert (tri == 2).all()                                    # the t 7 triangle, every ray
    # the model's tests, per ray in list order: miss, hit, hit, miss, hit; the two hits
    # accepted, the last hit between them (t as binary32 bits: exact comparisons)
    ints = g.events[g.events["kind"] == EV_INT].reshape(len(tri), 5)
    assert (ints["flags"] & 1 == [0, 1, 1, 0, 1]).all()
    assert ((ints["flags"] >> 1) & 1 == [0, 1, 1, 0, 0]).all()
    t = ints["t"].view(np.float32)
    assert ((t[:, 2] < t[:, 4]) & (t[:, 4] < t[:, 1])).all()
    r = run_unit(g, seed=6, idle=0.0, stall=0.0, latency=4, tri_slots=8, cache=True)
    assert r.mismatches[:5] == []
    assert r.int_ops == 5 * len(tri)


@pytest.mark.slow
def test_unit_synthesizes_small_config():
    """Yosys, generic synth (about 5 minutes): 2 threads of 2x2 rays (the ray and best-hit
    memories become flip-flops in the generic flow, so keep them small); no latches."""
    from rtl.intersection import IntersectionUnit
    from tb.harness.common import synth_check
    stat = synth_check(IntersectionUnit(Config(threads=2, tile_w=2, tile_h=2)), "intersection")
    assert "cells" in stat          # synth_check raises on a latch or a failed `check`


@pytest.mark.parametrize("fmt", [FPFormat(8, 16), FPFormat(6, 10)], ids=str)
def test_pipe_reduced_formats_exact_cycle(fmt):
    r = run_pipe(random_tests(60, fmt, seed=4), fmt, seed=4)
    assert r.mismatches == [] and r.outputs == r.tests == 60


@pytest.mark.parametrize("lat", [{}, {"add": 8, "mul": 5, "div": 29}], ids=["default", "deep"])
def test_pipe_delay_rings_exact_cycle(lat):
    """``Config.delay_ram``: the datapath's delays as ring buffers give every output at its
    exact cycle under random bubbles and stalls (the pointers advance only when enabled),
    including delays longer than one ring (the deep divider's 29 cycles)."""
    from amaranth.hdl import Fragment
    from rtl.intersection import IntersectPipe
    fmt = FPFormat(6, 10)
    on = dict(lat, delay_ram=2)
    r = run_pipe(random_tests(60, fmt, seed=5), fmt, seed=5, p_bubble=0.3, p_stall=0.3,
                 latencies=on)
    assert r.mismatches == [] and r.outputs == r.tests == 60
    bits = {}
    for k in (0, 2, 4):
        pipe = IntersectPipe(fmt, tag_width=8, latencies=dict(lat, delay_ram=k))
        Fragment.get(pipe, None)
        bits[k] = pipe.delay_bits
    # fewer flip-flops the lower the threshold (a ring's one output register each), and the
    # rings hold at least the delay the flip-flops no longer do
    assert bits[0][1] == 0 and bits[2][0] < bits[4][0] < bits[0][0]
    assert bits[4][0] + bits[4][1] >= bits[0][0]
    assert bits[2][1] > 0 and bits[4][1] > 0


@pytest.mark.slow
def test_unit_reduced_format(kd_cache):
    """E8M16: triangles come from memory as binary32 patterns and are sliced to the format."""
    from tb.units.list import golden
    from tb.units.intersection import run_unit
    from .conftest import ROOT
    g = golden(ROOT / "scenes" / "cornell.toml", 16, 16, Config(fmt=FPFormat(8, 16)), kd_cache)
    r = run_unit(g, max_leaves=20, seed=1)
    assert r.mismatches[:5] == [] and r.int_ops > 0
