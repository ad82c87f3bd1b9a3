"""The timing contract: cycle counts of small reference runs, recorded in ``tests/timing.json``.

The values are a recorded contract, measured in the simulators, not expected values derived from
the code: a test that makes one of these runs compares its cycle count with the file exactly
(``assert cycles == TIMING[name], timing_changed(name, cycles)``). The unit and RTC runs are the
ones the unit tests already make (``tests/test_{traversal,list,intersection,rtc}_rtl.py``,
``tests/test_verilator.py``); the threads sweep is checked here: one RTC of 1 and of 16 threads (4x4 packets, 2
traversal sub-units, 20-cycle memories, the configuration of ``make bench``'s sweep, so the
Verilator binaries are shared with it) on a Cornell 32x32 frame in Verilator.
"""
import re

import pytest

from model.config import Config
from tb.units.traversal import small_case

from .conftest import ROOT, TIMING, timing_changed


def test_every_recorded_run_is_checked():
    """Each entry of timing.json is compared by some test (no stale entry goes unchecked)."""
    sources = "".join(p.read_text() for p in (ROOT / "tests").glob("test_*.py"))
    named = set(re.findall(r'"([a-z_]+/[a-z0-9_]+)"', sources))
    named |= {f"verilator/threads_{t}_cornell_32x32" for t in SWEEP}
    assert set(TIMING) <= named, sorted(set(TIMING) - named)


SWEEP = (1, 16)


@pytest.mark.parametrize("threads", SWEEP)
def test_threads_sweep_cycles(threads, kd_cache):
    from tb.harness.verilator import run_frame
    cfg = Config(tile_w=4, tile_h=4, trav_subunits=2, threads=threads)
    image, rays = small_case(ROOT / "scenes/cornell.toml", 32, 32, cfg, kd_cache)
    r = run_frame(image, rays, cfg, mem_latency=20, progress=False)
    assert r.mismatches == [] and r.counter_mismatches() == {}
    assert r.counters["packets_done"] == rays.n_packets == 64
    name = f"verilator/threads_{threads}_cornell_32x32"
    assert r.cycles == TIMING[name], timing_changed(name, r.cycles)
