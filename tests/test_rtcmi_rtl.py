"""The shared RTC-MI (rtl/rtcmi.py SharedRTCMI): several RTCs' requesters on the three caches
behind their round-robin buses, with the SDRAM model behind them (``tb/units/rtcmi.py``)."""
import numpy as np
import pytest

from model.config import Config
from tb.units.rtcmi import run_shared_rtcmi

# 1 KB word caches (128 words) and a 9 KB triangle cache (256 triangles), 2 ways: the streams
# below both hit and miss, and the RTCs share lines
SMALL = dict(trav_cache_kb=1, list_cache_kb=1, int_cache_kb=9, cache_ways=2, mem_latency=8,
             cache_topology="shared")


def streams(n: int, count: int, seed: int) -> dict:
    """Per cache, per RTC: ``count`` items, half from a region all RTCs read (shared lines),
    half from the RTC's own region."""
    rng = np.random.default_rng(seed)
    def one(r, shared, own):
        common = rng.integers(0, shared, count)
        private = shared + r * own + rng.integers(0, own, count)
        return np.where(rng.random(count) < 0.5, common, private)
    return {"trav": [one(r, 96, 64) for r in range(n)],
            "list": [one(r, 96, 64) for r in range(n)],
            "int": [one(r, 160, 96) for r in range(n)]}


@pytest.mark.parametrize("n, seed", [(1, 1), (4, 2)])
def test_shared_caches_serve_every_rtc(n, seed):
    """Every response reaches the RTC that asked, with its tag and item; each cache's hits and
    misses are the cache model's replay of the order the cache took the RTCs' requests in;
    round robin on each bus; with 4 RTCs several requesters wait on a bus at once."""
    cfg = Config(rtcs=n, **SMALL)
    r = run_shared_rtcmi(cfg, streams(n, 60, seed), seed=seed, idle=0.1, stall=0.3)
    for c in ("trav", "list", "int"):
        assert r.hits[c] > 0 and r.misses[c] > 0, c
        if n == 4:
            assert r.max_waiting[c] >= 3, (c, r.max_waiting)
            assert r.waits[c] > 0 and r.max_wait[c] >= 2, c


def test_bench_catches_an_unfair_bus(monkeypatch):
    """The same run with each cache's bus granting the lowest requesting RTC first: the
    fairness check fails (the bench can fail)."""
    import functools
    import rtl.rtcmi
    monkeypatch.setattr(rtl.rtcmi, "RoundRobinBus",
                        functools.partial(rtl.rtcmi.RoundRobinBus, policy="fixed"))
    cfg = Config(rtcs=4, **SMALL)
    with pytest.raises(AssertionError, match="round robin is unfair"):
        run_shared_rtcmi(cfg, streams(4, 60, 2), seed=2, idle=0.1, stall=0.3)
