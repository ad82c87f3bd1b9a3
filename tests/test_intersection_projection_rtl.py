"""The projection test's pipeline (``rtl/intersection_projection.py``, ``Config.int_test =
"projection"``: the paper's triangle test on precomputed records) and the intersection unit
built with it, bit-exact and cycle-exact with the golden model
(``model/intersection_projection.py``)."""
import numpy as np
import pytest

from model.config import Config
from model.fp import FPFormat

from .test_intersection_rtl import DEEP, FMT

def test_projection_random_tests_cover_the_corner_cases():
    from tb.units.intersection_projection import random_tests as proj_tests
    t = proj_tests(600, FMT, seed=0)
    assert 0.25 < t.hit.mean() < 0.8
    assert t.hit[1::6].mean() > 0.8                                 # exact edge/vertex hits
    assert not t.hit[2::12].any()                                   # degenerate records
    assert (~np.isfinite(t.rec)).sum() == 0 and set(t.k.tolist()) == {0, 1, 2}


@pytest.mark.parametrize("fmt,n", [(FMT, 240), (FPFormat(8, 16), 60), (FPFormat(6, 10), 60)],
                         ids=str)
def test_projection_pipe_exact_cycle(fmt, n):
    from tb.units.intersection_projection import random_tests as proj_tests
    from tb.units.intersection_projection import run_pipe as run_proj
    r = run_proj(proj_tests(n, fmt, seed=1), fmt, seed=1, p_bubble=0.2, p_stall=0.2)
    assert r.mismatches == [] and r.outputs == r.tests == n
    assert r.cycles >= n + r.latency
    if fmt == FMT:
        assert r.latency == 37


def test_projection_pipe_delay_rings_exact_cycle():
    from tb.units.intersection_projection import random_tests as proj_tests
    from tb.units.intersection_projection import run_pipe as run_proj
    fmt = FPFormat(6, 10)
    r = run_proj(proj_tests(60, fmt, seed=5), fmt, seed=5, p_bubble=0.3, p_stall=0.3,
                 latencies={"add": 8, "mul": 5, "div": 29, "delay_ram": 2})
    assert r.mismatches == [] and r.outputs == r.tests == 60


@pytest.mark.slow
def test_projection_pipe_thousands():
    from tb.units.intersection_projection import random_tests as proj_tests
    from tb.units.intersection_projection import run_pipe as run_proj
    r = run_proj(proj_tests(3000, FMT, seed=2), FMT, seed=2, p_bubble=0.1, p_stall=0.1)
    assert r.mismatches[:5] == [] and r.outputs == r.tests == 3000


@pytest.mark.parametrize("deep", [False, True], ids=["default", "deep"])
def test_projection_unit_matches_model_first_leaves(kd_cache, deep):
    """``Config.int_test = "projection"``: the unit reads projection records (k in their spare
    exponent bits) and keeps the rays' directions; the first leaves of 4 Cornell packets,
    every datapath output, LaneResult and final hit against the model."""
    from tb.units.list import golden
    from tb.units.intersection import run_unit
    from .conftest import ROOT
    cfg = Config(int_test="projection", **(DEEP if deep else {}))
    g = golden(ROOT / "scenes" / "cornell.toml", 16, 16, cfg, kd_cache)
    r = run_unit(g, max_leaves=8 if not deep else 6, seed=1, idle=0.3, stall=0.3, latency=20)
    assert r.mismatches[:5] == []
    assert r.int_ops > 50 and r.counters["busy"] > 0
