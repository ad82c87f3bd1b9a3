"""Simulation memories (tb/harness/memory.py): data, tags, exact latency, SDRAM bandwidth per chip."""
import numpy as np
import pytest

from model.config import Config
from tb.harness.memory import IdealMemory, SDRAMMemory, chip_of
from tb.units.memory import run_memory, sdram_bandwidth

RNG = np.random.default_rng(5)
IMAGE = RNG.integers(0, 1 << 63, 256, dtype=np.uint64) | np.uint64(1 << 63)


@pytest.mark.parametrize("latency", [2, 3, 7, 20])
def test_ideal_memory_exact_latency_and_full_throughput(latency):
    addrs = RNG.integers(0, 256, 60)
    r = run_memory(IdealMemory(IMAGE, addr_width=8, tag_width=6, latency=latency), addrs)
    assert [p["data"] for _, p in r.responses] == [int(IMAGE[a]) for a in addrs]
    assert [p["tag"] for _, p in r.responses] == list(range(60))
    # no back-pressure: every response exactly `latency` cycles after its request,
    # and one request per cycle (queue defaults to latency + 1)
    assert [c for c, _ in r.responses] == [s + latency for s in r.sent]
    assert r.sent == list(range(60))
    assert r.counters["reads"] == 60


def test_ideal_memory_back_pressure_loses_nothing():
    addrs = RNG.integers(0, 256, 150)
    dut = IdealMemory(IMAGE, addr_width=8, tag_width=4, latency=5, queue=3)
    r = run_memory(dut, addrs, seed=3, idle=0.3, stall=0.5)
    assert [p["data"] for _, p in r.responses] == [int(IMAGE[a]) for a in addrs]
    assert [p["tag"] for _, p in r.responses] == [i % 16 for i in range(150)]
    assert all(c >= s + 5 for c, s in zip((c for c, _ in r.responses), r.sent))


def test_sdram_random_reads_with_back_pressure():
    addrs = RNG.integers(0, 256, 120)
    dut = SDRAMMemory(IMAGE, addr_width=8, tag_width=7, chips=4, latency=6)
    r = run_memory(dut, addrs, seed=1, idle=0.2, stall=0.4)
    tags = sorted(p["tag"] for _, p in r.responses)
    assert tags == list(range(120)), "every request answered exactly once"
    for _, p in r.responses:
        assert p["data"] == int(IMAGE[addrs[p["tag"]]])
    want = np.bincount(chip_of(addrs, 4), minlength=4).tolist()
    assert r.counters["words"] == want


def test_chip_hash_spreads_sequential_and_strided_addresses():
    a = np.arange(4096)
    for chips in (1, 2, 4, 8):
        assert (np.bincount(chip_of(a, chips), minlength=chips) == 4096 // chips).all()
    for stride in (4, 8, 64, 512):   # power-of-two strides still reach every chip
        assert set(chip_of(a * stride, 4).tolist()) == {0, 1, 2, 3}
    assert [chip_of(x, 4) for x in (0, 1, 2, 3, 4, 5)] == [0, 1, 2, 3, 1, 0]


@pytest.mark.parametrize("chips", [1, 2, 4])
def test_sdram_bandwidth_per_chip_and_scaling(chips):
    cfg = Config()
    r = sdram_bandwidth(chips, 64 * chips, latency=cfg.mem_latency,
                        chip_bits=cfg.mem_chip_bits, clock_ratio=cfg.mem_clock_ratio)
    ideal = cfg.mem_chip_bits / cfg.mem_clock_ratio          # 16 bit x clock / 4 per chip
    for bw in r["bits_per_cycle_per_chip"]:
        assert abs(bw - ideal) <= 0.05 * ideal
    assert abs(r["bits_per_cycle"] - chips * ideal) <= 0.05 * chips * ideal
    assert r["words_per_chip"] == [64] * chips
    # the data bus of a chip is busy 16 chip cycles per 64-bit word
    assert r["busy_per_chip"] == [64 * 16] * chips


def test_sdram_hot_spot_gets_one_chip_of_bandwidth():
    r = sdram_bandwidth(4, 48, pattern="hot")
    assert abs(r["bits_per_cycle"] - 4.0) <= 0.2
    assert r["words_per_chip"] == [48, 0, 0, 0]


@pytest.mark.filterwarnings("ignore:.*created but never used")
def test_memory_errors_say_what_to_fix():
    with pytest.raises(ValueError, match="latency=1"):
        IdealMemory(IMAGE, addr_width=8, tag_width=1, latency=1)
    with pytest.raises(TypeError, match="uint64"):
        IdealMemory(IMAGE.astype(np.int64), addr_width=8, tag_width=1, latency=4)
    with pytest.raises(ValueError, match="addr_width=4"):
        IdealMemory(IMAGE, addr_width=4, tag_width=1, latency=4)
    with pytest.raises(ValueError, match="power of two"):
        SDRAMMemory(IMAGE, addr_width=8, tag_width=1, chips=3)


@pytest.mark.parametrize("slots,seed", [(1, 1), (4, 2)])
def test_item_reader_assembles_items_in_order_from_out_of_order_words(slots, seed):
    """5-word items (a triangle's span) of which the low 288 bits are answered, from a word
    memory answering in random order after random delays, under input bubbles and output
    back-pressure: every item in request order with its tag, its words read once each."""
    import random

    from rtl.memport import ItemReader
    from tb.harness.common import drain, drive, run
    from tb.units.memory import random_memory
    base, n_items = 16, (256 - 16) // 5
    items = RNG.integers(0, n_items, 40)
    dut = ItemReader(item_bits=288, item_words=5, addr_width=8, tag_width=3, slots=slots)
    rng = random.Random(seed)
    got, log = [], []

    async def source(ctx):
        ctx.set(dut.base, base)
        await drive(ctx, dut.port.req, [{"addr": int(a), "tag": i % 8}
                                        for i, a in enumerate(items)], rng=rng, idle=0.3)

    async def sink(ctx):
        await drain(ctx, dut.port.resp, len(items), rng=rng, stall=0.4, out=got, timeout=3000)

    async def memory(ctx):
        await random_memory(ctx, dut.mem, IMAGE, rng, max_delay=12, log=log)

    run(dut, source, sink, background=[memory])
    want = []
    for a in items:
        w = IMAGE[base + 5 * int(a):base + 5 * int(a) + 5]
        want.append(sum(int(x) << (64 * j) for j, x in enumerate(w)) & ((1 << 288) - 1))
    assert [p["data"] for _, p in got] == want
    assert [p["tag"] for _, p in got] == [i % 8 for i in range(len(items))]
    assert sorted(log) == sorted(base + 5 * int(a) + j for a in items for j in range(5))
