"""Caches: the hit/miss model (model/cache.py) and the RTL cache (rtl/cache.py) against it."""
from collections import deque

import numpy as np
import pytest

from model.cache import CacheGeometry, CacheModel, cache_geometry, item_values, synthetic_traces
from model.config import Config
from rtl.cache import Cache
from tb.units.cache import CacheRun, check_cache_run, run_cache

IMAGE = np.random.default_rng(11).integers(0, 1 << 64, 4096, dtype=np.uint64)


def geom(item="node", ways=1, sets=16, line_items=1, **kw):
    bits, span = {"node": (64, 64), "entry": (32, 32), "tri": (288, 320),
                  "tri320": (320, 320)}[item]
    return CacheGeometry(size_bytes=sets * ways * line_items * bits // 8, ways=ways,
                         line_items=line_items, item_bits=bits, item_span=span, **kw)


# --- the model --------------------------------------------------------------------------------

def test_model_direct_mapped_by_hand():
    g = geom(sets=4)                       # item a -> set a % 4
    hits = CacheModel(g).access([0, 4, 0, 1, 5, 1, 1, 2])
    assert hits.tolist() == [False, False, False, False, False, False, True, False]


def test_model_two_way_round_robin_not_lru():
    g = geom(ways=2, sets=2)               # set = a % 2
    m = CacheModel(g)
    # 0 -> way 0, 2 -> way 1, 0 hits, 4 replaces way 0 (round robin; LRU would evict 2),
    # so 0 misses again and replaces way 1 (the 2), and 4 still hits
    assert m.access([0, 2, 0, 4, 0, 4, 2]).tolist() == \
        [False, False, True, False, False, True, False]
    assert (m.hits, m.misses) == (2, 5)


def test_model_lines_of_several_items():
    g = geom(item="entry", sets=4, line_items=4)   # 4 entries per line, line -> set line % 4
    hits = CacheModel(g).access([0, 1, 3, 4, 7, 16, 2, 17])
    assert hits.tolist() == [False, True, True, False, True, False, False, False]
    assert CacheModel(g).geom.line_words == 2


def _reference(g, addrs):
    """Plain-Python cache: per set a FIFO of resident lines (oldest evicted first)."""
    sets = [deque() for _ in range(g.sets)]
    out = []
    for a in addrs:
        line = a // g.line_items
        s = sets[line % g.sets]
        if line in s:
            out.append(True)
        else:
            out.append(False)
            if len(s) == g.ways:
                s.popleft()
            s.append(line)
    return out


@pytest.mark.parametrize("ways,sets,line_items", [(1, 8, 1), (2, 4, 2), (4, 2, 4), (4, 64, 1)])
def test_model_matches_reference_on_random_streams(ways, sets, line_items):
    g = geom(ways=ways, sets=sets, line_items=line_items)
    rng = np.random.default_rng(ways * 100 + sets)
    addrs = rng.integers(0, 4 * sets * ways * line_items, 5000)
    m = CacheModel(g)
    got = np.concatenate([m.access(addrs[:1234]), m.access(addrs[1234:])])  # state persists
    assert got.tolist() == _reference(g, addrs.tolist())
    assert m.hits + m.misses == 5000 and m.words_read == m.misses * g.line_words


def test_standard_geometries_from_config():
    cfg = Config()
    t, lst, i = (cache_geometry(cfg, u) for u in ("trav", "list", "int"))
    assert (t.sets, t.line_words) == (64 * 1024 // 8, 1)          # 8192 nodes
    assert (lst.sets, lst.line_items, lst.line_words) == (8192, 2, 1)  # 16384 entries
    assert (i.sets, i.line_words, i.item_bits) == (4096, 5, 288)  # 144 KB = 4096 triangles
    assert cache_geometry(cfg, "int", ways=4).sets == 1024
    with pytest.raises(ValueError, match="power of two"):
        cache_geometry(cfg.replace(int_cache_kb=100), "int")
    with pytest.raises(ValueError, match="must be one of"):
        cache_geometry(cfg, "shade")


def test_item_values_slice_memory_like_the_layout():
    words = IMAGE[:64]
    halves = words.view(np.uint32)                        # little-endian: low half first
    g = geom(item="entry", sets=4, line_items=2)
    assert item_values(words, g, [0, 1, 5], base=0) == [int(halves[k]) for k in (0, 1, 5)]
    assert item_values(words, g, [3], base=8) == [int(halves[16 + 3])]
    g = geom(item="tri")                                  # triangle t: words 5t..5t+4, 288 bits
    u = words.view(np.uint32)
    tri = item_values(words, g, [2], base=1)[0]
    assert tri == sum(int(u[2 * (1 + 10) + k]) << (32 * k) for k in range(9))


# --- the RTL cache ----------------------------------------------------------------------------

@pytest.mark.parametrize("item,line_items", [("node", 1), ("node", 4), ("entry", 2), ("entry", 8),
                                             ("tri", 1), ("tri", 2), ("tri320", 2)])
def test_rtl_cache_data_array_words_hold_the_line(item, line_items):
    """The RTL's data array is one memory per word of a line
    (``CacheGeometry.word_kept_bits``): the words' kept bits, concatenated, are the line's
    items in order (what the model reads from memory for each item)."""
    g = geom(item, sets=4, line_items=line_items)
    words = g.word_kept_bits
    assert len(words) == g.line_words
    assert sum(hi - lo for w in words for lo, hi in w) == g.line_items * g.item_bits
    line = IMAGE[5 * g.line_words:6 * g.line_words]
    row, at = 0, 0
    for j, w in enumerate(words):
        for lo, hi in w:
            row |= ((int(line[j]) >> lo) & ((1 << (hi - lo)) - 1)) << at
            at += hi - lo
    items = item_values(IMAGE, g, range(5 * g.line_items, 6 * g.line_items))
    assert row == sum(v << (i * g.item_bits) for i, v in enumerate(items))


CASES = {
    # name: (geometry, memory, idle, stall)
    "node-dm-ideal": (geom(sets=16, outstanding=4, queue=8), "ideal", 0.0, 0.0),
    "node-2way-random": (geom(ways=2, sets=8, outstanding=3, queue=6), "random", 0.2, 0.3),
    "entry-4way-line4-random": (geom("entry", ways=4, sets=4, line_items=4, outstanding=2,
                                     queue=5), "random", 0.1, 0.4),
    "tri-2way-sdram": (geom("tri", ways=2, sets=8, outstanding=4, queue=8), "sdram", 0.0, 0.2),
    "tri320-line2-random": (geom("tri320", ways=1, sets=8, line_items=2, outstanding=1,
                                 queue=3), "random", 0.3, 0.3),
}


@pytest.mark.parametrize("fast", [False, True], ids=["default", "fast"])
@pytest.mark.parametrize("name", list(CASES))
def test_rtl_cache_random_stream(name, fast):
    g, memory, idle, stall = CASES[name]
    rng = np.random.default_rng(len(name))
    span_items = 3 * g.sets * g.ways * g.line_items          # enough to thrash and to hit
    addrs = rng.integers(0, span_items, 250)
    base = 8
    assert (base * 64 + span_items * g.item_span) // 64 < len(IMAGE)
    r = run_cache(g, IMAGE, addrs, base=base, memory=memory, idle=idle, stall=stall,
                  seed=len(name), latency=6, fast=fast)
    assert 0 < r.hits < len(addrs)                         # the stream exercises both


@pytest.mark.parametrize("unit", ["trav", "list", "int"])
def test_rtl_cache_kdtree_like_stream(unit):
    tr = synthetic_traces(30, depth=10, seed=4)[unit][:300]
    g = {"trav": geom(ways=2, sets=32), "list": geom("entry", ways=1, sets=32, line_items=2),
         "int": geom("tri", ways=4, sets=8)}[unit]
    span = int(tr.max() + 1) * g.item_span // 64
    image = np.random.default_rng(1).integers(0, 1 << 64, span + 8, dtype=np.uint64)
    r = run_cache(g, image, tr, memory="random", idle=0.1, stall=0.2, seed=7)
    assert r.hits > 0 and r.misses > 0
    if unit == "trav":
        assert r.hits > r.misses                           # hot top nodes


@pytest.mark.parametrize("fast", [False, True], ids=["default", "fast"])
def test_rtl_cache_hit_latency_and_throughput(fast):
    g = geom(sets=16, outstanding=4, queue=8)
    addrs = [3] * 20                       # one miss; once it is done, 19 hits back to back
    r = run_cache(g, IMAGE, addrs, memory="ideal", latency=4, gaps=[0, 30] + [0] * 18,
                  fast=fast)
    lat = [c - s for (c, _), s in zip(r.responses, r.sent)]
    hit = 6 if fast else 3
    cache = Cache(g, fast=fast)
    cache._MustUse__silence = True           # not elaborated: only its documented latency
    assert cache.hit_latency == hit
    assert lat[1:] == [hit] * 19, f"hit latencies {lat[1:]}, documented {hit}"
    assert r.sent[1:] == list(range(r.sent[1], r.sent[1] + 19)), "one request per cycle"
    # a miss: hit path + issue FIFO (1) + memory latency (4) + the response's register and
    # the issue entry's register (fast)
    assert cache.fill_delay == cache.issue_delay == (1 if fast else 0)
    assert lat[0] == hit + 1 + 4 + (2 if fast else 0)


def test_rtl_cache_fast_forwards_tag_writes():
    """``fast``: back-to-back misses and hits on one set (each lookup reads its row before
    the previous one's tag write lands): the hit/miss sequence is still the model's."""
    g = geom(ways=2, sets=2, outstanding=4, queue=8)
    addrs = [0, 2, 0, 4, 0, 2, 2, 6, 4, 0, 8, 10, 8, 10, 1, 3, 1, 5, 1]
    for memory, stall in (("ideal", 0.0), ("random", 0.3)):
        r = run_cache(g, IMAGE, addrs, memory=memory, latency=3, stall=stall, fast=True)
        assert r.misses > 0 and r.hits > 0


@pytest.mark.parametrize("fast", [False, True], ids=["default", "fast"])
def test_response_queue_head_waits_for_its_line(fast):
    """The response queue alone: a hit, a miss and a hit on the miss's line, pushed in three
    cycles while the miss's fill is in flight (cycles 2 to 7, done in 7), leave in request
    order, each with its slot; the two behind the fill only once it is done (both variants:
    ``fast`` forms the wait bits a cycle ahead from ``kept``)."""
    from amaranth.sim import Simulator
    from rtl.cache import FastResponseQueue, ResponseQueue
    q = (FastResponseQueue if fast else ResponseQueue)(geom(ways=2, sets=4, outstanding=2,
                                                            queue=4), tag_width=3)
    pushes = {0: dict(hit=1, hit_way=0, way=0, set=1, utag=5),
              1: dict(hit=0, victim=1, way=1, set=2, utag=6),
              2: dict(hit=1, hit_way=1, way=1, set=2, utag=7)}
    pops = []

    async def bench(ctx):
        ctx.set(q.head.ready, 1)
        ctx.set(q.fills.set[0], 2)
        ctx.set(q.fills.way[0], 1)
        for cycle in range(12):
            for k, v in pushes.get(cycle, {}).items():
                ctx.set(getattr(q.push, k), v)
            ctx.set(q.push.go, cycle in pushes)
            ctx.set(q.fills.valid, 2 <= cycle <= 7)         # MSHR 0 fills set 2, way 1
            ctx.set(q.kept, 2 <= cycle <= 6)                # ... and is done in cycle 7
            assert not ctx.get(q.full)
            if ctx.get(q.head.valid):
                h = ctx.get(q.head.payload)
                pops.append((cycle, h.utag, h.slot))
            await ctx.tick()

    sim = Simulator(q)
    sim.add_clock(1e-6)
    sim.add_testbench(bench)
    sim.run()
    slot = lambda way, set_: way | set_ << 1                # noqa: E731  {way, set}
    assert pops == [(1, 5, slot(0, 1)), (8, 6, slot(1, 2)), (9, 7, slot(1, 2))]


def test_rtl_cache_outstanding_misses_overlap():
    """With 4 MSHRs, 8 misses to distinct lines take far less than 8 memory round trips."""
    g = geom(sets=16, outstanding=4, queue=16)
    r = run_cache(g, IMAGE, list(range(8)), memory="ideal", latency=20)
    assert r.misses == 8
    assert r.cycles < 8 * 20 // 2


def test_checker_catches_wrong_data_order_and_hits():
    g = geom(ways=2, sets=4)
    addrs = np.array([1, 9, 1, 17, 9, 1])
    reqs = [{"addr": int(a), "tag": i % 16} for i, a in enumerate(addrs)]
    vals = item_values(IMAGE, g, addrs)
    hits = CacheModel(g).access(addrs)
    good = CacheRun(responses=[(i, {"data": v, "tag": i}) for i, v in enumerate(vals)],
                    sent=list(range(6)), lookups=[(i, bool(h)) for i, h in enumerate(hits)],
                    hits=int(hits.sum()), misses=int((~hits).sum()),
                    words_fetched=int((~hits).sum()), cycles=10)
    check_cache_run(good, g, IMAGE, addrs, reqs, 0)
    bad = [
        dict(responses=good.responses[:2] + [(2, {"data": vals[2] ^ 1, "tag": 2})] +
             good.responses[3:]),
        dict(responses=[good.responses[1], good.responses[0]] + good.responses[2:]),
        dict(responses=good.responses[:-1]),
        dict(lookups=[(0, True)] + good.lookups[1:], hits=good.hits + 1,
             misses=good.misses - 1),
        dict(words_fetched=good.words_fetched + 1),
    ]
    for change in bad:
        with pytest.raises(AssertionError):
            check_cache_run(CacheRun(**{**good.__dict__, **change}), g, IMAGE, addrs, reqs, 0)


def test_cache_synthesizes_without_latches():
    from tb.harness.common import synth_check
    stat = synth_check(Cache(geom("tri", ways=2, sets=2, outstanding=2, queue=3,
                                  addr_width=12, mem_addr_width=14), tag_width=2), "cache")
    assert "DFF" in stat


def test_bench_memory_writes_hit_rates(tmp_path):
    from saarcor.bench.memory import main
    tr = tmp_path / "trav.npy"
    np.save(tr, np.arange(100_000) % 5000)          # 5000 nodes fit the 64 KB trav cache
    res = main(["--out", str(tmp_path), "--packets", "200", "--depth", "12", "--no-bandwidth",
                "--addr-trace", f"trav={tr}"])
    assert (tmp_path / "memory.json").exists()
    t = res["hit_rates"]["trav"]
    assert t["1-way"]["misses"] == 5000 and t["4-way"]["misses"] == 5000   # compulsory only
    assert set(res["hit_rates"]) == {"trav", "list", "int"}


@pytest.mark.slow
@pytest.mark.parametrize("fast", [False, True], ids=["default", "fast"])
@pytest.mark.parametrize("unit", ["trav", "list", "int"])
@pytest.mark.parametrize("ways", [1, 4])
def test_rtl_cache_standard_size_long_stream(unit, ways, fast):
    """Standard-size caches (64/64/144 KB) on 3000 accesses of a kd-tree-like stream, with
    and without the ``fast`` registers."""
    g = cache_geometry(Config(), unit, ways=ways)
    tr = synthetic_traces(400, depth=14, seed=ways)[unit][:3000]
    span = int(tr.max() + 1) * g.item_span // 64 + 1
    image = np.random.default_rng(2).integers(0, 1 << 64, span, dtype=np.uint64)
    run_cache(g, image, tr, memory="sdram", latency=Config().mem_latency, idle=0.05,
              stall=0.05, seed=3, fast=fast)
