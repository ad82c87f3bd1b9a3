"""List unit (rtl/list.py) against the golden model: leaf stream in, triangle stream out."""
import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from model.config import Config
from model.list import list_entry, list_words
from tb.harness.common import synth_check
from tb.units.list import golden, leaf_stream, run_list
from rtl.list import ListUnit

from .conftest import ROOT, TIMING, timing_changed

CFG = Config()


@pytest.fixture(scope="module")
def cornell(kd_cache):
    return golden(ROOT / "scenes" / "cornell.toml", 16, 16, CFG, kd_cache)


def test_golden_stream_is_not_trivial(cornell):
    leaves, tris = leaf_stream(cornell)
    assert len(leaves) > 50 and len(tris) > 2 * len(leaves)
    assert any(lf["first"] & 1 for lf in leaves) and any(lf["count"] == 1 for lf in leaves)


def test_list_unit_matches_model_with_bubbles_and_backpressure(cornell):
    r = run_list(cornell, seed=1, idle=0.3, stall=0.3)
    assert r.cycles == TIMING["list/cornell_bubbles"], timing_changed("list/cornell_bubbles",
                                                                      r.cycles)
    assert r.entries == cornell.counters[:, 5].sum()
    assert 0 < r.busy <= r.cycles


def test_list_unit_out_of_order_memory(cornell):
    """SDRAM model: responses of different chips overtake each other; order must still hold."""
    r = run_list(cornell, seed=2, idle=0.1, stall=0.2, sdram=True, latency=6, max_leaves=80)
    tags = r.resp_tags
    assert any((b - a) % 8 != 1 for a, b in zip(tags, tags[1:])), "responses came in order"


def test_list_unit_throughput(cornell):
    """No bubbles, no back-pressure: one entry per cycle once memory latency is hidden."""
    r = run_list(cornell, seed=3, idle=0.0, stall=0.0, latency=20, outstanding=16)
    assert r.cycles < 1.25 * r.entries + 40, (r.cycles, r.entries)
    name = "list/cornell_throughput"
    assert r.cycles == TIMING[name], timing_changed(name, r.cycles)


def test_list_unit_fast_clock(cornell):
    """``fast_clock`` (entries leave through a stream register): the model's stream under
    bubbles and back-pressure; without them, the default timing one cycle later (the
    register's cycle, no throughput lost)."""
    g = dataclasses.replace(cornell, cfg=CFG.replace(fast_clock=True))
    r = run_list(g, seed=1, idle=0.3, stall=0.3)
    assert r.entries == cornell.counters[:, 5].sum()
    r = run_list(g, seed=3, idle=0.0, stall=0.0, latency=20, outstanding=16)
    assert r.cycles == TIMING["list/cornell_throughput"] + 1


def test_list_unit_every_alignment():
    """Synthetic list: every first parity and counts 1..7 (and a huge first index)."""
    rng = np.random.default_rng(5)
    words = rng.integers(0, 2**63, 64, dtype=np.int64).astype(np.uint64) * np.uint64(2)
    words[0] = 0
    base = 9
    data = np.concatenate([np.zeros(base, np.uint64), words])
    leaves, want = [], []
    for first in range(0, 12):
        for count in range(1, 8):
            mask = int(rng.integers(1, 2**63)) | (1 << 63)
            leaves.append({"thread": (first + count) % CFG.threads, "first": first,
                           "count": count, "mask": mask})
            for j in range(count):
                want.append({"thread": (first + count) % CFG.threads,
                             "tri": int(list_entry(data, base, first + j)), "mask": mask,
                             "last": int(j == count - 1)})
    image = SimpleNamespace(data=data, list_base=base)
    g = SimpleNamespace(cfg=CFG, image=image)
    r = run_list(g, seed=4, idle=0.2, stall=0.2, latency=3, outstanding=4,
                 streams=(leaves, want))
    assert r.words == sum(list_words(lf["first"], lf["count"]) for lf in leaves)


def test_list_unit_rejects_bad_outstanding():
    with pytest.raises(ValueError, match="power of two"):
        ListUnit(CFG, outstanding=6)


def test_list_unit_synthesizes():
    stat = synth_check(ListUnit(CFG, addr_width=32, outstanding=8), "list_unit")
    assert "cells" in stat.lower()
