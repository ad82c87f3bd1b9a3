"""The Verilator frame path (``tb/harness/frame.py``, ``tb/harness/verilator.py``, ``tb/harness/verilator_main.cpp``):
an RTC on a real image in Verilator against the golden model, cycle for cycle against the
Amaranth simulator, the binary cache, and the errors users see.

One small configuration (2 threads, 2 sub-units, 4x4 packets) is built once (~1-2 minutes on
the shared 2-core machine, cached in build/verilator/ between sessions); every test reuses it.
"""
import dataclasses
import random
import struct
import subprocess

import numpy as np
import pytest

from model.config import Config
from tb.harness.memory import IdealMemory
from tb.harness.common import drain, drive, run
from tb.units.traversal import small_case

from .conftest import ROOT, TIMING, timing_changed

import tb.harness.verilator as vl           # verilator missing: the tests fail saying `make setup`

TINY = Config(threads=2, tile_w=4, tile_h=4, trav_subunits=2)
LATENCY = 4


def case(scene, w, h, kd_cache):
    return small_case(ROOT / f"scenes/{scene}.toml", w, h, TINY, kd_cache)


def frame(image, rays, **kw):
    kw = {"mem_latency": LATENCY, "progress": False, **kw}
    return vl.run_frame(image, rays, TINY, **kw)


def check(r, rays):
    assert r.rays == len(rays)
    assert r.mismatches == []
    assert r.counter_mismatches() == {}
    assert r.counters["packets_done"] == rays.n_packets
    assert r.counters["int_ops"] > 0 and r.cycles > 0


def test_cornell_frame_matches_model(kd_cache):
    """Cornell 16x16 (16 packets through 2 threads) with LFSR bubbles and back-pressure:
    every ray's triangle, t, u, v bits and the counters equal the model's."""
    image, rays = case("cornell", 16, 16, kd_cache)
    r = frame(image, rays, idle=0.25, stall=0.3, seed=1)
    check(r, rays)
    name = "verilator/cornell_16x16_tiny"
    assert r.cycles == TIMING[name], timing_changed(name, r.cycles)
    assert r.counters["node_mem_reads"] == r.model["node_reads"]
    assert r.counters["tri_mem_reads"] == r.model["int_reads"]
    # the image is preloaded at time 0; only the rays and the constants take load cycles
    assert 8 * len(rays) <= r.load_cycles < 8 * len(rays) + 256


# the FPGA build's configuration (make fpga): 8 threads, deep FP pipelines, fast_clock,
# asynchronous sub-units
FPGA = Config(threads=8, tile_w=4, tile_h=4, trav_subunits=2, trav_sync=False,
              fp_add_latency=8, fp_mul_latency=6, fp_div_latency=29, fp_cmp_latency=3,
              fast_clock=True, delay_ram=4)


def test_fpga_configuration_frame_with_poisoned_collisions(kd_cache, monkeypatch):
    """Office 32x24 (48 packets through 8 threads: rays load while other threads test) in the
    FPGA build's configuration, every block-RAM read of a row written in its cycle returning
    its row inverted (``SAARCOR_RAM_POISON``): every ray and counter equals the model's."""
    monkeypatch.setenv(vl.POISON_ENV, "1")
    image, rays = small_case(ROOT / "scenes/office.toml", 32, 24, FPGA, kd_cache)
    r = vl.run_frame(image, rays, FPGA, mem_latency=LATENCY, progress=False,
                     idle=0.1, stall=0.1, seed=3)
    check(r, rays)


def test_same_cycles_as_pysim(kd_cache):
    """The same RTC, rays, seed and bubbles in Amaranth's simulator (``run_rtc_free``): the
    same counters, busy cycles included, and the same cycle count (pysim samples ``finished``
    one clock edge later, so it reports one cycle more)."""
    from tb.units.rtc import run_rtc_free
    image, rays = case("cornell", 4, 4, kd_cache)
    r = frame(image, rays, idle=0.25, stall=0.25, seed=7)
    p = run_rtc_free(image, rays, TINY, mem_latency=LATENCY, idle=0.25, stall=0.25, seed=7)
    check(r, rays)
    assert p.mismatches == []
    assert {k: r.counters[k] for k in p.counters} == p.counters
    assert "trav_busy" in p.counters and "sub_busy" in p.counters
    assert r.cycles == p.cycles - 1
    name = "verilator/cornell_4x4_seed7"
    assert r.cycles == TIMING[name], timing_changed(name, r.cycles)
    assert p.cycles == TIMING["rtc/cornell_4x4_seed7"], timing_changed("rtc/cornell_4x4_seed7",
                                                                       p.cycles)


def test_memory_jitter_same_as_pysim(kd_cache):
    """``mem_stall``: each memory holds its responses in a random half of the cycles (in-order,
    random latency, as behind a cache). The same bits, and the same cycles in both simulators;
    slower than with fixed latency, so the holds do act."""
    from tb.units.rtc import run_rtc_free
    image, rays = case("cornell", 12, 4, kd_cache)
    kw = {"idle": 0.25, "stall": 0.3, "seed": 5}
    r = frame(image, rays, mem_stall=0.5, **kw)
    p = run_rtc_free(image, rays, TINY, mem_latency=LATENCY, mem_stall=0.5, **kw)
    check(r, rays)
    assert p.mismatches == []
    assert r.cycles == p.cycles - 1
    fixed = frame(image, rays, **kw)
    assert r.cycles > fixed.cycles * 1.05, (r.cycles, fixed.cycles)


@pytest.mark.slow
def test_standard_rtc_survives_memory_jitter(kd_cache):
    """The standard RTC (16 threads, 64-ray packets) with random memory latency, input
    bubbles and result back-pressure: every packet finishes. (Seed 3 hung here while the RTC
    released a thread by the packet *last accepted* for readout rather than the packet whose
    last result left: a stalled last result and a waiting ``done`` freed the wrong thread.)"""
    cfg = Config()
    image, rays = small_case(ROOT / "scenes/office.toml", 64, 48, cfg, kd_cache)
    for seed in (3, 4, 10):
        r = vl.run_frame(image, rays, cfg, mem_latency=20, idle=0.2, stall=0.3,
                         mem_stall=0.8, seed=seed, max_cycles=2_000_000, progress=False)
        check(r, rays)


@pytest.mark.slow
def test_waveform_window(kd_cache, tmp_path):
    """``trace_from``: the VCD starts at that run cycle (the load and the first cycles are not
    in it) and holds the RTC's signals."""
    image, rays = case("cornell", 4, 4, kd_cache)
    vcd = tmp_path / "w.vcd"
    r = frame(image, rays, trace_file=vcd, trace_from=200)
    check(r, rays)
    text = vcd.read_text()
    stamps = [int(line[1:]) for line in text.splitlines() if line.startswith("#")]
    load = r.load_cycles
    assert stamps and min(stamps) >= 2 * (load + 200), (min(stamps), load)
    assert max(stamps) <= 2 * (load + r.cycles + 10)
    assert "packets_done" in text


def test_second_scene_reuses_the_binary(kd_cache):
    """Office (a 272 k-word image) runs on the binary Cornell built: loaded, not rebuilt."""
    image, rays = case("cornell", 4, 4, kd_cache)
    first = frame(image, rays)
    image, rays = case("office", 8, 8, kd_cache)
    r = frame(image, rays, stall=0.5, seed=3)
    check(r, rays)
    assert not r.build.built and r.build.binary == first.build.binary
    assert r.build.binary.exists()


def test_build_key_follows_configuration_and_sources(tmp_path, monkeypatch):
    kw = {"mem_words": 1 << 17, "ray_slots": 1 << 16, "mem_latency": 4}
    k = vl.build_key(TINY, **kw)
    assert k == vl.build_key(TINY, **kw)
    assert k != vl.build_key(TINY.replace(threads=4), **kw)
    assert k != vl.build_key(TINY, **{**kw, "mem_latency": 5})
    assert k != vl.build_key(TINY, **{**kw, "mem_words": 1 << 18})
    # shadow rays or not, the kd-tree build and the quoted clock share one binary
    assert k == vl.build_key(TINY.replace(shadows=False, kd_leaf_size=8, clock_mhz=100.0), **kw)
    assert k != vl.build_key(TINY.replace(rgs_lights=0, reflect_depth=0), **kw)   # eye-ray slave
    assert any(p.name == "traversal.py" for p in vl._sources())
    # the C++ optimisation level: its own binary; a level the compiler does not have is named
    monkeypatch.setenv(vl.CXX_OPT_ENV, "-O1")
    assert vl.build_key(TINY, **kw) != k
    monkeypatch.setenv(vl.CXX_OPT_ENV, "-O9")
    with pytest.raises(vl.ConfigError, match=r"SAARCOR_VERILATOR_OPT='-O9': one of -O0"):
        vl.build_key(TINY, **kw)
    monkeypatch.delenv(vl.CXX_OPT_ENV)
    assert vl.cxx_opt() == ""
    # the block-RAM collision poison (SAARCOR_RAM_POISON) builds its own binary
    plain = vl.build_key(TINY, **kw)
    monkeypatch.setenv(vl.POISON_ENV, "1")
    assert vl.build_key(TINY, **kw) != plain
    monkeypatch.setenv(vl.POISON_ENV, "0")
    assert vl.build_key(TINY, **kw) == plain
    src = tmp_path / "unit.py"
    src.write_text("a = 1\n")
    monkeypatch.setattr(vl, "ROOT", tmp_path)
    monkeypatch.setattr(vl, "_sources", lambda: [src])
    before = vl.build_key(TINY, **kw)
    src.write_text("a = 2\n")
    assert vl.build_key(TINY, **kw) != before


def test_bad_inputs_say_what_is_wrong(kd_cache, tmp_path):
    image, rays = case("cornell", 4, 4, kd_cache)
    with pytest.raises(vl.FrameError, match=r"max_cycles=300 .*raise"):
        frame(image, rays, max_cycles=300)
    huge = dataclasses.replace(image, data=np.zeros((1 << 19) + 1, np.uint64))
    with pytest.raises(ValueError, match=r"524289 words, the simulation holds 524288 .*"
                                         r"pass mem_words >= 524289"):
        frame(huge, rays, mem_words=1000)
    with pytest.raises(ValueError, match=r"idle=1.0.*\[0, 15/16\]"):
        vl.write_input(tmp_path / "x.bin", image, rays, TINY, idle=1.0)
    # the binary itself: a truncated input file, a block beyond the memory
    b = vl.build(TINY, mem_latency=LATENCY)
    good = tmp_path / "in.bin"
    vl.write_input(good, image, rays, TINY)
    bad = tmp_path / "bad.bin"
    bad.write_bytes(good.read_bytes()[:1000])
    p = subprocess.run([str(b.binary), str(bad), str(tmp_path / "o.bin")],
                                     capture_output=True, text=True)
    assert p.returncode == 1 and "truncated input file" in p.stderr
    big = tmp_path / "big.bin"
    big.write_bytes(vl.IN_MAGIC + struct.pack("<QIIQ", 1, 0, b.mem_words - 1, 2) +
                    bytes(16))
    p = subprocess.run([str(b.binary), str(big), str(tmp_path / "o.bin")],
                                     capture_output=True, text=True)
    assert p.returncode == 1 and f"the design has {b.mem_words}" in p.stderr


def test_ideal_memory_load_port():
    """``IdealMemory(load=True)``: words written through the load port are read back, in
    request order with their tags."""
    dut = IdealMemory(None, addr_width=6, tag_width=4, latency=3, load=True, depth=40)
    assert dut.depth == 64
    words = [random.Random(1).getrandbits(64) for _ in range(64)]
    addrs = [5, 63, 0, 17, 17, 40]
    got = []

    async def load_then_read(ctx):
        ctx.set(dut.ld_en, 1)
        for a, w in enumerate(words):
            ctx.set(dut.ld_addr, a)
            ctx.set(dut.ld_data, w)
            await ctx.tick()
        ctx.set(dut.ld_en, 0)
        await drive(ctx, dut.port.req, [{"addr": a, "tag": i} for i, a in enumerate(addrs)])

    async def sink(ctx):
        await drain(ctx, dut.port.resp, len(addrs), out=got)

    run(dut, load_then_read, sink)
    assert [p["data"] for _, p in got] == [words[a] for a in addrs]
    assert [p["tag"] for _, p in got] == list(range(len(addrs)))


def test_prune_builds_keeps_the_recent_and_the_busy(tmp_path):
    """The binaries' cache stays under its limit: the builds used least recently go first; a
    build another process holds (its lock taken), the one being made and unfinished folders
    stay."""
    import fcntl
    import io
    import os
    root = tmp_path / "verilator"
    for i, name in enumerate(["a", "b", "c", "d"]):           # a oldest ... d newest, 1 MB each
        d = root / name / "obj_dir"
        d.mkdir(parents=True)
        (d / "Vframe").write_bytes(b"x" * 2 ** 20)
        stamp = root / name / "build.json"
        stamp.write_text("{}")
        os.utime(stamp, (1000 + i, 1000 + i))
    (root / "half").mkdir()                                   # an interrupted build
    (root / "half" / "frame.v").write_bytes(b"x" * 2 ** 20)
    with open(root / "b.lock", "w") as busy:                  # another process builds/uses b
        fcntl.flock(busy, fcntl.LOCK_EX)
        log = io.StringIO()
        gone = vl.prune_builds(root, limit_gb=1.5 / 1024, keep=root / "c", log=log)
    assert sorted(p.name for p in gone) == ["a", "d"]
    assert sorted(p.name for p in root.iterdir() if p.is_dir()) == ["b", "c", "half"]
    assert "removed 2 binaries" in log.getvalue()
    assert vl.prune_builds(root, limit_gb=1.0) == []
