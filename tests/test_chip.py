"""The whole chip (rtl/chip.py): RGS master and slaves, RTCs behind their RTC-MIs, one bus to
the SDRAM model; every ray — eye rays, and with a scene its shadow and reflection rays made by
the slaves — bit-exact with the golden model in both simulators."""
import io
from types import SimpleNamespace

import numpy as np
import pytest

from model.cache import CacheModel
from model.config import Config
from model.events import EV_LEAF, EV_NODE, EV_TRI
from model.raygen import eye_rays
from model.raykind import RayKind
from model.layout import REC_WORDS
from model.render import prepare
from model.rtc import trace
from model.scene import load_scene
from rtl.rgs.slave import slave_buffers as rtl_slave_buffers
from rtl.rtcmi import rtcmi_geometries
from tb.harness.compare import COMPARED

from .conftest import ROOT, TIMING, timing_changed

# small caches so that a tiny frame both hits and misses; SDRAM as configured (4 chips, 4:1)
TINY = Config(rtcs=1, threads=2, tile_w=4, tile_h=4, trav_subunits=2, trav_cache_kb=1, list_cache_kb=1,
              int_cache_kb=9, mem_latency=8)


@pytest.fixture(scope="module")
def cornell(kd_cache):
    scene = load_scene(ROOT / "scenes/cornell.toml")
    return scene, prepare(scene, TINY, cache_dir=kd_cache).image


def check_frame(r, cfg, image, rays):
    """Every ray bit-exact (and, where the chip makes colour, every pixel's colour); every ray
    in and out once; the RTCs' counters add up to the model's; the caches' and the memory's counters agree with each other. ``rays``: the eye
    rays (the frame's other rays are ``r.frame_rays``, the model's)."""
    from rtl.rgs import RAY_COUNTERS
    c = r.counters
    every = r.frame_rays
    assert r.mismatches == []
    assert c["rays_in"] == c["results_out"] == len(every) == r.rays
    assert sum(c["packets"]) == rays.n_packets
    assert sum(x["packets_done"] for x in c["rtc"]) == every.n_packets
    for kind, name in RAY_COUNTERS.items():
        assert sum(x[name] for x in c["slave"]) == int((every.kind == kind).sum()), name
    for rtc_name, model_name in COMPARED.items():
        assert sum(x[rtc_name] for x in c["rtc"]) == r.model[model_name], rtc_name
    reads = {"trav": "node_reads", "list": "list_reads", "int": "int_tris"}
    words = {"trav": 1, "list": 1, "int": 5}             # memory words a miss reads
    for x, h, mi, g in zip(c["rtc"], c["hits"], c["misses"], c["grants"]):
        if cfg.cache_topology == "private":              # each RTC's own caches
            for k, n in reads.items():
                assert h[k] + mi[k] == x[n], k
                assert g[k] == words[k] * mi[k], k
        assert g["shade"] == REC_WORDS * mi["shade"]
        assert g["tex"] == mi["tex"]                     # a texel word a miss
    for k, n in reads.items():                           # the RTC-MI: every request one lookup
        x = c["rtcmi"][k]
        assert x["hits"] + x["misses"] == sum(y[n] for y in c["rtc"]), k
        assert x["grants"] == words[k] * x["misses"], k
    # every unit's cycles: working, waiting for memory, blocked, starved, one each
    # (rtl/stalls.py; the frame's last cycle is counted the cycle after, and the RTCs leave
    # reset with the frame's first cycle)
    from rtl.rtc import STALL_UNITS
    from rtl.stalls import REASONS
    for x in c["rtc"]:
        for u in STALL_UNITS:
            got = {rs: x[f"{u}_{rs}"] for rs in REASONS}
            assert r.cycles - 2 <= sum(got.values()) <= r.cycles, (u, got, r.cycles)
        assert x["trav_work"] <= x["trav_ops"] and x["int_work"] == x["int_ops"]
        assert x["list_work"] <= x["list_ops"]
    for x in c["slave"]:                                 # the RGS slaves', the same way
        got = {rs: x[rs] for rs in REASONS}
        assert r.cycles - 2 <= sum(got.values()) <= r.cycles, ("slave", got, r.cycles)
        assert (x["work"] > 0) == (x["rays_eye"] > 0)     # an idle slave (no packet) never works
    if cfg.cache_topology == "shared":                   # why a shared cache lost cycles
        from rtl.cache import STALLS
        for k, x in c["rtcmi"].items():
            s = x["stalls"]
            assert set(s) == set(STALLS), k
            # a cycle's lookup takes a request or holds one for one reason at most
            assert x["hits"] + x["misses"] + s["queue_full"] + s["no_mshr"] + \
                s["victim_busy"] <= r.cycles, (k, s)
            assert s["head_filling"] <= r.cycles and s["resp_blocked"] <= r.cycles, (k, s)
            if x["misses"]:                              # a miss's line is filled before
                assert s["head_filling"] > 0, (k, s)     # its request leaves the queue
    slave_words = sum(g["shade"] + g["tex"] for g in c["grants"])
    assert sum(c["mem_words"]) == c["mem_reads"] == slave_words + sum(
        x["grants"] for x in c["rtcmi"].values())


FRAMES_8X4 = {(1, "shared"): "chip/cornell_8x4_rtcs1", (2, "shared"): "chip/cornell_8x4_rtcs2",
              (2, "private"): "chip/cornell_8x4_rtcs2_private"}


@pytest.mark.parametrize("rtcs, topology", [
    (1, "shared"), pytest.param(2, "shared", marks=pytest.mark.slow),
    pytest.param(2, "private", marks=pytest.mark.slow)])
def test_chip_frame_in_amaranth_sim(rtcs, topology, cornell):
    """An 8x4 Cornell frame (2 packets): eye rays made by the RGS slaves in FP hardware,
    traced by 1 or 2 RTCs through the RTC-MI's caches (shared by the RTCs, or each RTC's own)
    and the SDRAM model, under result back-pressure; with 2 RTCs the master gives each a
    packet. The 2-RTC runs (about 150 s of Amaranth's simulator each) are slow tests: their
    timing entries are checked on every run by ``test_chip_verilator_same_cycles_as_amaranth_sim``
    (the same frames in Verilator)."""
    from tb.harness.chip import run_chip
    scene, image = cornell
    cfg = TINY.replace(rtcs=rtcs, cache_topology=topology)
    rays = eye_rays(scene.camera, 8, 4, cfg)
    r = run_chip(cfg, image, scene.camera, 8, 4, stall=0.25, seed=3)
    check_frame(r, cfg, image, rays)
    if rtcs == 2:
        assert r.counters["packets"] == [1, 1]
    name = FRAMES_8X4[rtcs, topology]
    assert r.cycles == TIMING[name], timing_changed(name, r.cycles)


@pytest.mark.slow
def test_cache_hits_are_the_cache_models(cornell):
    """One RTC of one thread traces packet after packet in the model's event order, so each
    of its private caches sees the model's request sequence: ``model.cache.CacheModel``
    predicts its hits. (Shared caches see the RTCs' requests interleaved: their replay is
    ``tests/test_rtcmi_rtl.py``'s, in CI. Slow: two minutes of Amaranth's simulator for the
    private topology.)"""
    from tb.harness.chip import run_chip
    scene, image = cornell
    cfg = TINY.replace(threads=1, cache_topology="private")
    rays = eye_rays(scene.camera, 8, 4, cfg)
    r = run_chip(cfg, image, scene.camera, 8, 4)
    check_frame(r, cfg, image, rays)
    _, _, ev = trace(image, rays, cfg, record=True)
    kind = ev["kind"]
    leaf = ev[(kind == EV_LEAF) & (ev["count"] > 0)]
    words = [np.arange(f >> 1, ((f + n - 1) >> 1) + 1) for f, n in zip(leaf["first"],
                                                                         leaf["count"])]
    streams = {"trav": image.node_base + ev["node"][(kind == EV_NODE) | (kind == EV_LEAF)],
               "list": image.list_base + np.concatenate(words),
               "int": ev["tri"][kind == EV_TRI]}
    geoms = rtcmi_geometries(cfg)
    for name, addrs in streams.items():
        model = CacheModel(geoms[name])
        model.access(addrs.astype(np.int64))
        assert (r.counters["hits"][0][name], r.counters["misses"][0][name]) == \
            (model.hits, model.misses), name
        assert model.hits > 0 and model.misses > 0, name


@pytest.mark.slow
def test_chip_verilator_same_cycles_as_amaranth_sim(cornell):
    """The same frame, stall pattern and seed in Verilator: the same results, counters and
    cycle count as in Amaranth's simulator (the timing contract). Slow (a Verilator build of
    its own): in CI the timing contract is pinned in Amaranth's simulator on one RTC
    (``test_chip_frame_in_amaranth_sim``) and in Verilator on four
    (``test_chip_verilator_cornell_16x16``)."""
    from tb.harness.chip import run_chip_frame
    scene, image = cornell
    cfg = TINY.replace(rtcs=2)
    rays = eye_rays(scene.camera, 8, 4, cfg)
    r = run_chip_frame(cfg, image, scene.camera, 8, 4, stall=0.25, seed=3, progress=False)
    check_frame(r, cfg, image, rays)
    name = FRAMES_8X4[2, cfg.cache_topology]
    assert r.cycles == TIMING[name], timing_changed(name, r.cycles)


@pytest.mark.slow
def test_chip_verilator_private_caches_same_cycles_as_amaranth_sim(cornell):
    """The private topology's 8x4 frame in Verilator: the cycles of its Amaranth run."""
    from tb.harness.chip import run_chip_frame
    scene, image = cornell
    cfg = TINY.replace(rtcs=2, cache_topology="private")
    rays = eye_rays(scene.camera, 8, 4, cfg)
    r = run_chip_frame(cfg, image, scene.camera, 8, 4, stall=0.25, seed=3, progress=False)
    check_frame(r, cfg, image, rays)
    name = FRAMES_8X4[2, "private"]
    assert r.cycles == TIMING[name], timing_changed(name, r.cycles)


@pytest.mark.slow
def test_chip_two_result_ports_verilator(cornell):
    """``result_ports=2``: each of two RGS slaves hands its results out on a stream of its own.
    Every ray bit-exact and once, and the frame takes no more cycles than on one shared
    stream (the same frame as ``test_chip_verilator_same_cycles_as_amaranth_sim``). (Slow: a
    build of its own; in CI ``test_chip_shade_pool_verilator`` runs two streams.)"""
    from tb.harness.chip import run_chip_frame
    scene, image = cornell
    cfg = TINY.replace(rtcs=2, result_ports=2)
    rays = eye_rays(scene.camera, 8, 4, cfg)
    r = run_chip_frame(cfg, image, scene.camera, 8, 4, stall=0.25, seed=3, progress=False)
    check_frame(r, cfg, image, rays)
    assert r.cycles <= TIMING[FRAMES_8X4[2, "shared"]]


@pytest.mark.slow
def test_chip_two_result_ports_same_cycles_as_amaranth_sim(cornell):
    """The two-stream frame in Amaranth's simulator: the Verilator frame's cycles and rays."""
    from tb.harness.chip import run_chip, run_chip_frame
    scene, image = cornell
    cfg = TINY.replace(rtcs=2, result_ports=2)
    rays = eye_rays(scene.camera, 8, 4, cfg)
    r = run_chip(cfg, image, scene.camera, 8, 4, stall=0.25, seed=3)
    check_frame(r, cfg, image, rays)
    v = run_chip_frame(cfg, image, scene.camera, 8, 4, stall=0.25, seed=3, progress=False)
    assert r.cycles == v.cycles


def test_chip_verilator_cornell_16x16(cornell):
    """A 16x16 Cornell frame (16 packets) on 4 RTCs sharing the RTC-MI's caches, in Verilator
    with result back-pressure and random memory latency (the SDRAM model holds its responses
    in half the cycles): every ray bit-exact, the packets spread over the RTCs by the master,
    four requesters on each cache's bus (the timing contract's run with several waiting)."""
    from tb.harness.chip import run_chip_frame
    scene, image = cornell
    cfg = TINY.replace(rtcs=4)
    rays = eye_rays(scene.camera, 16, 16, cfg)
    r = run_chip_frame(cfg, image, scene.camera, 16, 16, stall=0.25, mem_stall=0.5, seed=5,
                       progress=False)
    check_frame(r, cfg, image, rays)
    assert min(r.counters["packets"]) >= 2
    assert all(x["waits"] > 0 for x in r.counters["rtcmi"].values())   # the RTCs contend
    assert r.cycles == TIMING["chip/cornell_16x16_rtcs4"], timing_changed(
        "chip/cornell_16x16_rtcs4", r.cycles)
    fixed = run_chip_frame(cfg, image, scene.camera, 16, 16, stall=0.25, seed=5,
                           progress=False)
    check_frame(fixed, cfg, image, rays)
    assert r.cycles > fixed.cycles        # the holds do act


@pytest.mark.slow
@pytest.mark.parametrize("buffers", [0, 13])
def test_chip_secondary_rays_in_amaranth_sim(cornell, buffers):
    """A 4x4 Cornell frame with its shadow rays (3 point lights) and reflections (the mirror
    sphere): the slaves make every secondary ray in FP hardware from the RTCs' results, and
    every ray of the frame's ray tree is bit-exact with ``model.render``'s, found by its id;
    every pixel's colour, summed from the slaves' records, equals the model's. (Slow: 5-10
    minutes; ``test_chip_secondary_rays_verilator`` checks the same frame's cycles in CI.)
    ``buffers`` 13: one pending buffer more than the default (``rgs_buffers``)."""
    from tb.harness.chip import run_chip
    scene, image = cornell
    cfg = TINY.replace(rtcs=2, rgs_buffers=buffers)
    rays = eye_rays(scene.camera, 4, 4, cfg)
    r = run_chip(cfg, image, scene.camera, 4, 4, stall=0.25, seed=3, scene=scene)
    check_frame(r, cfg, image, rays)
    assert r.color is not None                      # and every pixel's colour (check_frame)
    kinds = np.bincount(r.frame_rays.kind, minlength=3)
    assert kinds[1] > kinds[0] > 0                  # shadow rays toward every light
    if not buffers:
        name = "chip/cornell_4x4_scene_rtcs2"
        assert r.cycles == TIMING[name], timing_changed(name, r.cycles)


def textured_hits(r, scene) -> int:
    """Hits of eye and reflection rays on textured triangles in the chip's frame ``r``: each
    reads its four texels through its slave's texel cache."""
    rays, tri = r.frame_rays, np.asarray(r.frame_hits.tri)
    kept = np.full(scene.n_scene_tris, -1, np.int64)
    kept[scene.tri_id] = np.arange(len(scene.tri_id))
    textured = np.array([m.texture is not None for m in scene.materials], bool)
    on = (rays.kind != RayKind.SHADOW) & (tri >= 0)
    return int(textured[scene.material[kept[tri[on]]]].sum())


def test_chip_secondary_rays_verilator(cornell):
    """The same 4x4 frame with secondary rays in Verilator: the same cycle count as in
    Amaranth's simulator; then 16x16 (shadows, a reflective sphere, the textured floor) under
    back-pressure and random memory latency: every ray bit-exact, reflections included."""
    from tb.harness.chip import run_chip_frame
    scene, image = cornell
    cfg = TINY.replace(rtcs=2)
    log = io.StringIO()
    r = run_chip_frame(cfg, image, scene.camera, 4, 4, stall=0.25, seed=3, scene=scene,
                       progress=True, log=log)
    check_frame(r, cfg, image, eye_rays(scene.camera, 4, 4, cfg))
    # the progress bar counts the rays (not the pixels' colour records) against all of them
    n = len(r.frame_rays)
    assert n > 16 and f" {n}/{n} " in log.getvalue(), log.getvalue()[-300:]
    name = "chip/cornell_4x4_scene_rtcs2"
    assert r.cycles == TIMING[name], timing_changed(name, r.cycles)
    r = run_chip_frame(cfg, image, scene.camera, 16, 16, stall=0.25, mem_stall=0.5, seed=5,
                       scene=scene, progress=False, max_cycles=2_000_000)
    check_frame(r, cfg, image, eye_rays(scene.camera, 16, 16, cfg))
    assert r.color is not None and r.color.max() > 0
    tex = sum(h["tex"] + mi["tex"] for h, mi in zip(r.counters["hits"], r.counters["misses"]))
    assert tex == 4 * textured_hits(r, scene) > 0                # the checkered floor
    rays = r.frame_rays
    assert (rays.kind == RayKind.REFLECTION).any()
    # shadow rays at reflection hits
    assert ((rays.kind == RayKind.SHADOW) & (rays.depth == 1)).any()


def test_chip_reflections_of_reflections_verilator(kd_cache):
    """Office (3 lights, a mirror) on the same binary, 16x16 under back-pressure: reflections of
    reflections and many reflection packets waiting for their reservations. (The standard chip
    hung on office while the slave's sender tried only the lowest ready buffer: a reflection
    packet waiting for its reservation blocked the shadow packets that return it.)"""
    from tb.harness.chip import run_chip_frame
    cfg = TINY.replace(rtcs=2)
    scene = load_scene(ROOT / "scenes/office.toml")
    image = prepare(scene, cfg, cache_dir=kd_cache).image
    r = run_chip_frame(cfg, image, scene.camera, 16, 16, stall=0.25, seed=3, scene=scene,
                       progress=False, max_cycles=1_000_000)
    check_frame(r, cfg, image, eye_rays(scene.camera, 16, 16, cfg))
    rays = r.frame_rays
    assert (rays.depth == 2).any() and (rays.kind == RayKind.REFLECTION).sum() > 10


def test_a_stuck_frame_names_its_packets_and_rtcs():
    """When a frame hits the cycle limit, the message names the packets whose results are
    missing and, per RTC, packets given against packets finished."""
    from tb.harness.chip import stuck
    cfg = TINY.replace(rtcs=2)
    rays = eye_rays(load_scene(ROOT / "scenes/cornell.toml").camera, 8, 8, cfg)   # 4 packets
    records = {"packet": np.array([0] * 16 + [1] * 16 + [3] * 10)}
    c = {"packets0": 2, "packets1": 2, "rtc0_packets_done": 2, "rtc1_packets_done": 0,
         "rays_in": 64}
    text = stuck(cfg, rays, records, c, 1000)
    assert "packets never finished: [2, 3]" in text
    assert "RTC 0: 2 packets in, 2 done" in text and "RTC 1: 2 packets in, 0 done" in text
    assert "42 of 64 results" in text
    # with secondary rays a tile has finished when the rays it spawned have: tile 0's eye rays
    # 3 and 5 spawned two more
    every = SimpleNamespace(eye=np.concatenate([np.arange(64), [3, 5]]))
    text = stuck(cfg, rays, records, c, 1000, every)
    assert "packets never finished: [0, 2, 3]" in text and "42 of 66 results" in text


def test_stall_bench_passes_and_can_fail(cornell, tmp_path):
    """``saarcor.bench.chip --seeds``: a few seeds of back-pressure and memory-latency jitter on the
    small chip finish bit-exact; with a cycle limit no frame can meet, every seed is reported
    as a failure naming the unfinished packets (a later part of the seeds: ``first_seed``)."""
    import json

    from saarcor.bench.chip import stall_bench
    scene, image = cornell
    cfg = TINY.replace(rtcs=2)
    path = tmp_path / "stalls.json"
    assert stall_bench(cfg, image, scene.camera, 8, 8, 3, path) == 0
    res = json.loads(path.read_text())
    assert res["runs"] == 3 and res["failures"] == []
    assert len({r["cycles"] for r in res["per_run"]}) > 1          # the seeds differ
    assert stall_bench(cfg, image, scene.camera, 8, 8, 2, path, max_cycles=200,
                       first_seed=500) == 1
    res = json.loads(path.read_text())
    assert [f["seed"] for f in res["failures"]] == [500, 501]
    assert "packets never finished" in res["failures"][0]["what"]


def test_colour_check_finds_a_wrong_pixel():
    """The chip's colour records summed per pixel against the model's sums: equal sums give
    no mismatch, whatever the records' order; one channel off by one unit is named."""
    from model.render import render
    from tb.harness.chip import colour_mismatches
    cfg = TINY
    scene = load_scene(ROOT / "scenes/cornell.toml")
    res = render(scene, cfg, 8, 4, textures=False)
    eye = eye_rays(scene.camera, 8, 4, cfg)
    # records: one per pixel channel sum, split in two halves, shuffled
    pk = np.searchsorted(eye.pk_start, np.arange(len(eye)), side="right") - 1
    lane = np.arange(len(eye)) - eye.pk_start[pk]
    half = res.colour[eye.pixel] // 2
    rest = res.colour[eye.pixel] - half
    recs = {"packet": np.concatenate([pk, pk]), "lane": np.concatenate([lane, lane])}
    for c in range(3):
        recs[f"col{c}"] = np.concatenate([half[:, c], rest[:, c]])
    order = np.random.default_rng(1).permutation(2 * len(eye))
    recs = {k: v[order] for k, v in recs.items()}
    bad, img = colour_mismatches(recs, eye, res.colour)
    assert bad == [] and np.array_equal(img, res.image.reshape(-1, 3))
    recs["col1"][5] += 1
    bad, _ = colour_mismatches(recs, eye, res.colour)
    p = int(eye.pixel[eye.pk_start[recs["packet"][5]] + recs["lane"][5]])
    assert [(b[0], b[1]) for b in bad] == [(p, "colour")]
    assert bad[0][2] - bad[0][3] == 1 << 24


@pytest.mark.slow
def test_chip_shared_fp_units_verilator(cornell):
    """The slaves with the paper's budget of FP units per datapath (3 adders, 4 multipliers,
    shared in time: ``Config.rgs_fp_adders``, ``rgs_fp_muls``): Cornell 16x16 with its
    shadows, the mirror sphere and the textured floor, under back-pressure and random memory
    latency: every ray and every pixel bit-exact; the slaves take a ray every ``ii`` cycles,
    so the frame takes more cycles than with a unit per operation. (Slow: a chip build of its
    own; in CI the pool below runs the slaves at ``ii`` > 1 in the chip, and
    ``tests/test_rgs_rtl.py`` checks each shared datapath bit for bit.)"""
    from rtl.rgs import Slave
    from tb.harness.chip import run_chip_frame
    scene, image = cornell
    cfg = TINY.replace(rtcs=2, rgs_fp_adders=3, rgs_fp_muls=4)
    slave = Slave(cfg)
    slave._MustUse__silence = True
    assert slave.shd.ii > 1 and slave.shd.units["mul"] <= 4 and slave.sec.units["add"] <= 3
    r = run_chip_frame(cfg, image, scene.camera, 16, 16, stall=0.25, mem_stall=0.5, seed=5,
                       scene=scene, progress=False, max_cycles=2_000_000)
    check_frame(r, cfg, image, eye_rays(scene.camera, 16, 16, cfg))
    assert r.color is not None and r.color.max() > 0
    assert (r.frame_rays.kind == RayKind.REFLECTION).any()
    full = run_chip_frame(cfg.replace(rgs_fp_adders=0, rgs_fp_muls=0), image, scene.camera, 16,
                          16, stall=0.25, mem_stall=0.5, seed=5, scene=scene, progress=False,
                          max_cycles=2_000_000)
    assert full.mismatches == [] and full.rays == r.rays
    assert r.cycles > full.cycles


@pytest.mark.slow
def test_chip_shade_pool_verilator(cornell):
    """The slaves' ray datapaths on one pool of the paper's 3 adders and 4 multipliers
    (``Config.rgs_fp_pool``: the eye rays, the secondary rays' ray setup (an entry per light
    and one for the reflection), SecondaryPipe, a LightPipe entry per light register and the
    texture unit's two pipes in one modulo schedule, ``rtl.rgs.SlavePool``): Cornell 16x16 with its shadows, the mirror sphere
    and the textured floor, under back-pressure and random memory latency: every ray and every
    pixel bit-exact. The chip hands its results (rays and ambient records) out on two streams
    (``result_ports``), one a slave. (Slow: in CI ``test_chip_paper_preset_refraction_verilator``
    runs the pool with refraction.)"""
    from rtl.rgs import Slave
    from tb.harness.chip import run_chip_frame
    scene, image = cornell
    cfg = TINY.replace(rtcs=2, rgs_fp_adders=3, rgs_fp_muls=4, rgs_fp_pool=True,
                       result_ports=2)
    slave = Slave(cfg)
    slave._MustUse__silence = True
    pool = slave.pool
    assert pool.units["add"] <= 3 and pool.units["mul"] <= 4 and pool.copies == cfg.rgs_lights
    assert (slave.sec.ii == slave.shd.ii == slave.eye.gen.ii == slave.eye.setup.ii
            == slave.setup.pipe.ii == slave.tex.coord.ii == slave.tex.filter.ii == pool.ii)
    assert slave.setup.pipe.per_ii == cfg.rgs_lights + 1 and slave.eye.gen.per_ii == 1
    r = run_chip_frame(cfg, image, scene.camera, 16, 16, stall=0.25, mem_stall=0.5, seed=5,
                       scene=scene, progress=False, max_cycles=2_000_000)
    check_frame(r, cfg, image, eye_rays(scene.camera, 16, 16, cfg))
    assert r.color is not None and r.color.max() > 0
    kinds = r.frame_rays.kind
    assert (kinds == RayKind.REFLECTION).any() and (kinds == RayKind.SHADOW).any()


@pytest.mark.slow
def test_chip_shared_slots_that_never_meet_verilator(cornell):
    """One adder and two multipliers per datapath: SecondaryPipe's interval (30) and the
    texture unit's (6) share a factor, so in a given phase offset their slots never meet in
    one cycle; a hit must go into both at once, so before the texture's input queue the slave
    waited forever (the first packets' shading never started). Cornell 16x16, every ray and
    pixel bit-exact."""
    from math import gcd
    from rtl.rgs import Slave
    from tb.harness.chip import run_chip_frame
    scene, image = cornell
    cfg = TINY.replace(rtcs=2, rgs_fp_adders=1, rgs_fp_muls=2)
    slave = Slave(cfg)
    slave._MustUse__silence = True
    assert gcd(slave.sec.ii, slave.tex.coord.ii) > 1
    r = run_chip_frame(cfg, image, scene.camera, 16, 16, stall=0.25, mem_stall=0.5, seed=5,
                       scene=scene, progress=False, max_cycles=3_000_000)
    check_frame(r, cfg, image, eye_rays(scene.camera, 16, 16, cfg))
    assert r.color is not None and r.color.max() > 0


@pytest.mark.slow
def test_chip_waveform_holds_the_units_signals(cornell, tmp_path):
    """A waveform of the chip (``--trace``): the binary is a flat model of the deduplicated
    export, so the VCD holds the signals inside the units (a slave's, an RTC's), and the frame
    is bit-exact with the cycles of the build without a waveform."""
    from tb.harness.chip import run_chip_frame
    scene, image = cornell
    cfg = TINY.replace(rtcs=2)
    rays = eye_rays(scene.camera, 8, 4, cfg)
    vcd = tmp_path / "chip.vcd"
    r = run_chip_frame(cfg, image, scene.camera, 8, 4, stall=0.25, seed=3, progress=False,
                       trace_file=vcd)
    check_frame(r, cfg, image, rays)
    assert r.cycles == TIMING["chip/cornell_8x4_rtcs2"], timing_changed(
        "chip/cornell_8x4_rtcs2", r.cycles)
    text = vcd.read_text()
    scopes = {line.split()[2] for line in text.splitlines()
              if line.lstrip().startswith("$scope")}
    assert {"slave0", "slave1", "rtc0", "rtc1"} <= scopes, (sorted(scopes)[:40], text[:600])
    assert "packets_done" in text and "rays_eye" in text


@pytest.mark.slow
def test_chip_frame_projection_test_in_amaranth_sim(kd_cache):
    """``Config.int_test = "projection"`` (the paper's triangle test on precomputed records):
    the 8x4 Cornell frame on one RTC, every ray bit-exact with the golden model's (slow:
    about 100 s, most of it building the chip)."""
    from tb.harness.chip import run_chip
    cfg = TINY.replace(int_test="projection")
    scene = load_scene(ROOT / "scenes/cornell.toml")
    image = prepare(scene, cfg, cache_dir=kd_cache).image
    assert image.projection
    rays = eye_rays(scene.camera, 8, 4, cfg)
    r = run_chip(cfg, image, scene.camera, 8, 4, stall=0.25, seed=3)
    check_frame(r, cfg, image, rays)
    # the watertight test's triangles, but where its hit lies on an edge (the frame's corner
    # lines pass exactly through edges: there the projection test may pick the neighbour, or
    # let the ray through)
    hits = np.asarray(r.frame_hits.tri)
    wt, _ = trace(prepare(scene, TINY, cache_dir=kd_cache).image, rays, TINY)
    assert r.rays == 32 and (hits >= 0).sum() >= 8
    differ = hits != np.asarray(wt.tri)
    u, v = np.asarray(wt.u, np.float64), np.asarray(wt.v, np.float64)
    assert (np.minimum(np.minimum(u, v), 1 - u - v)[differ] < 1e-6).all()
    assert differ.sum() < 8


@pytest.mark.slow
def test_chip_projection_secondary_rays_verilator(kd_cache):
    """``Config.int_test = "projection"`` with shadow and reflection rays made by the slaves
    (their ray setup sends the direction to the RTCs), an 8x8 Cornell frame on 2 RTCs in
    Verilator: every ray and every pixel's colour bit-exact with the golden model's (slow:
    a Verilator build of its own, about 4 minutes)."""
    from tb.harness.chip import run_chip_frame
    cfg = TINY.replace(rtcs=2, int_test="projection")
    scene = load_scene(ROOT / "scenes/cornell.toml")
    image = prepare(scene, cfg, cache_dir=kd_cache).image
    r = run_chip_frame(cfg, image, scene.camera, 8, 8, stall=0.25, seed=3, scene=scene,
                       progress=False)
    check_frame(r, cfg, image, eye_rays(scene.camera, 8, 8, cfg))
    kinds = np.bincount(r.frame_rays.kind, minlength=3)
    assert r.color is not None and kinds[1] > kinds[0] > 0 and kinds[2] > 0


# refracted rays (Config.refraction): the glass scene, reflections and refractions to depth 2
GLASS = TINY.replace(refraction=True, reflect_depth=2)


@pytest.fixture(scope="module")
def glass(kd_cache):
    """scenes/glass.toml, and the same scene seen from close to its glass block (every eye ray
    of a 4x4 frame hits the block: a frame short enough for Amaranth's simulator)."""
    import dataclasses

    from model.scene_data import Camera
    scene = load_scene(ROOT / "scenes/glass.toml")
    block = dataclasses.replace(scene, camera=Camera(
        np.array([1.6, 1.2, 7.0]), np.array([1.6, 1.2, 2.4]), np.array([0.0, 1.0, 0.0]), 12.0))
    return scene, block, prepare(scene, GLASS, cache_dir=kd_cache).image


def check_refraction(r, cfg, image, scene, width, height):
    """:func:`check_frame`, and the frame's refracted rays: every kind, and rays of one eye
    ray and depth told apart by their path (a reflection's refraction, a refraction's
    reflection), refracted rays of refracted rays among them."""
    check_frame(r, cfg, image, eye_rays(scene.camera, width, height, cfg))
    rays = r.frame_rays
    assert r.color is not None
    kinds = np.bincount(rays.kind, minlength=4)
    assert (kinds > 0).all(), kinds
    assert sum(x["rays_refract"] for x in r.counters["slave"]) == kinds[RayKind.REFRACTION]
    refracted_twice = (rays.kind == RayKind.REFRACTION) & (rays.path == 3)
    reflected_after = (rays.kind == RayKind.REFLECTION) & (rays.path == 1) & (rays.depth == 2)
    assert refracted_twice.any() and reflected_after.any()


@pytest.mark.slow
def test_chip_refraction_in_amaranth_sim(glass):
    """The slaves make refracted rays (``Config.refraction``): the glass block 4x4 (3 point
    lights, reflections and refractions to depth 2), every ray of the frame's ray tree
    bit-exact with ``model.render``'s, found by its id (eye ray, depth, light, path), every
    pixel's colour too, under result back-pressure. (Slow: about 3 minutes of Amaranth's
    simulator; ``test_chip_refraction_verilator`` runs it in Verilator to the same cycle.)"""
    from tb.harness.chip import run_chip
    _, block, image = glass
    r = run_chip(GLASS, image, block.camera, 4, 4, stall=0.25, seed=3, scene=block,
                 max_cycles=100_000)
    check_refraction(r, GLASS, image, block, 4, 4)
    name = "chip/glass_block_4x4_refraction"
    assert r.cycles == TIMING[name], timing_changed(name, r.cycles)


@pytest.mark.slow
def test_chip_refraction_verilator(glass):
    """The same frame in Verilator to the same cycle; then scenes/glass.toml 8x8 (the glass
    sphere and block among the Cornell walls) under back-pressure and random memory latency:
    every ray and pixel bit-exact, the slaves' refracted-ray counters the model's count."""
    from tb.harness.chip import run_chip_frame
    scene, block, image = glass
    r = run_chip_frame(GLASS, image, block.camera, 4, 4, stall=0.25, seed=3, scene=block,
                       progress=False)
    check_refraction(r, GLASS, image, block, 4, 4)
    name = "chip/glass_block_4x4_refraction"
    assert r.cycles == TIMING[name], timing_changed(name, r.cycles)
    r = run_chip_frame(GLASS, image, scene.camera, 8, 8, stall=0.25, mem_stall=0.5, seed=5,
                       scene=scene, progress=False, max_cycles=2_000_000)
    check_refraction(r, GLASS, image, scene, 8, 8)


def test_chip_paper_preset_refraction_verilator(glass, kd_cache):
    """The paper preset (``--preset paper``: the projection triangle test, every slave
    datapath on one pool of 3 adders and 4 multipliers, ``rtl.rgs.SlavePool``) with
    refraction: scenes/glass.toml 8x8 (its glass sphere and block, 3 point lights, the
    checkered floor through the texture unit, reflections and refractions to depth 2) under
    back-pressure and random memory latency, the results on two streams
    (``result_ports``): every ray of the ray tree and every pixel bit-exact with the model,
    the slaves' refracted-ray counters its count."""
    from model.config import PRESETS
    from rtl.rgs import Slave
    from tb.harness.chip import run_chip_frame
    scene, _, _ = glass
    cfg = GLASS.replace(**PRESETS["paper"], rtcs=2, result_ports=2)
    image = prepare(scene, cfg, cache_dir=kd_cache).image
    slave = Slave(cfg)
    slave._MustUse__silence = True
    assert slave.sec.refract and slave.tex is not None and slave.tex.coord.ii == slave.pool.ii
    assert slave.pool.units["mul"] <= 4 and slave.pool.units["add"] <= 3
    assert slave.setup.pipe.per_ii == cfg.rgs_lights + 2
    r = run_chip_frame(cfg, image, scene.camera, 8, 8, stall=0.25, mem_stall=0.5, seed=5,
                       scene=scene, progress=False, max_cycles=3_000_000)
    check_refraction(r, cfg, image, scene, 8, 8)
    name = "chip/glass_8x8_paper_rtcs2"
    assert r.cycles == TIMING[name], timing_changed(name, r.cycles)
    # the pool's counters (rtl.rgs.POOL_COUNTERS): SecondaryPipe took every eye, reflection
    # and refracted result, and so did both texture pipes (textured or not), the eye-ray
    # datapath every eye ray, the ray setup every secondary ray; an interval every ii cycles
    c, rays = r.counters["slave"], r.frame_rays
    total = {k: sum(x[k] for x in c) for k in c[0]}
    assert total["pool_sec"] == int((rays.kind != RayKind.SHADOW).sum())
    assert total["pool_eye"] == int((rays.kind == RayKind.EYE).sum())
    assert total["pool_setup"] == int((rays.kind != RayKind.EYE).sum())
    assert total["pool_tex_coord"] == total["pool_tex_filter"] == total["pool_sec"]
    assert total["pool_light"] >= total["pool_sec"]
    for x in c:
        assert abs(x["pool_intervals"] - r.cycles / slave.pool.ii) <= 2


@pytest.mark.slow
def test_chip_paper_preset_keeps_its_pool_busy(kd_cache):
    """The paper preset on one RTC, office 128x96 with all its rays: SecondaryPipe takes a hit
    in at least 70 % of the pool's intervals and the eye-ray datapath makes its rays in the
    same intervals (the two fills add up to more than one). With only SecondaryPipe's own
    hits in the shading path (the light loop waiting for the texture unit's kd) it took one
    in 45 %, and the eye rays waited for admission (43 %). Every ray bit-exact."""
    from model.config import PRESETS
    from tb.harness.chip import run_chip_frame
    scene = load_scene(ROOT / "scenes/office.toml")
    cfg = Config(**PRESETS["paper"], rtcs=1)
    image = prepare(scene, cfg, cache_dir=kd_cache).image
    r = run_chip_frame(cfg, image, scene.camera, 128, 96, scene=scene, progress=False)
    check_frame(r, cfg, image, eye_rays(scene.camera, 128, 96, cfg))
    c = r.counters["slave"][0]
    sec, eye = (c[k] / c["pool_intervals"] for k in ("pool_sec", "pool_eye"))
    assert sec >= 0.7 and sec + eye > 1.0, (sec, eye)


@pytest.mark.slow
def test_chip_paper_preset_refraction_both_simulators(glass, kd_cache):
    """The paper preset with refraction on the glass block 4x4 in Amaranth's simulator and in
    Verilator: every ray and pixel bit-exact in both, to the same cycle. (Slow: minutes of
    Amaranth's simulator.)"""
    from model.config import PRESETS
    from tb.harness.chip import run_chip, run_chip_frame
    scene, block, _ = glass
    cfg = GLASS.replace(**PRESETS["paper"])
    image = prepare(scene, cfg, cache_dir=kd_cache).image
    a = run_chip(cfg, image, block.camera, 4, 4, stall=0.25, seed=3, scene=block,
                 max_cycles=400_000)
    check_refraction(a, cfg, image, block, 4, 4)
    v = run_chip_frame(cfg, image, block.camera, 4, 4, stall=0.25, seed=3, scene=block,
                       progress=False)
    check_refraction(v, cfg, image, block, 4, 4)
    assert a.cycles == v.cycles


def test_chip_refuses_refraction_it_cannot_make(glass):
    """A scene whose materials transmit needs ``refraction=True``; refraction needs enough
    pending buffers for its depth."""
    from model.config import ConfigError
    from tb.harness.chip import frame_registers
    scene, _, image = glass
    with pytest.raises(ValueError, match="refraction=True"):
        frame_registers(TINY, image, scene.camera, 4, 4, scene)
    with pytest.raises(ConfigError, match="refraction=True"):
        TINY.check_scene(scene, image, 4, 4)
    assert GLASS.for_scene(scene, image, 4, 4).refraction
    with pytest.raises(ConfigError, match="reflect_depth"):
        GLASS.replace(rgs_lights=1, reflect_depth=9, rgs_buffers=10)
    assert GLASS.replace(rgs_lights=1, reflect_depth=9).min_rgs_buffers == 3 + 9 + 1
    assert GLASS.hardware_dict() != GLASS.replace(reflect_depth=3).hardware_dict()
    assert TINY.hardware_dict() == TINY.replace(reflect_depth=2).hardware_dict()


MIRROR_BOX = """
name = "mirror box"
background = [0.1, 0.2, 0.3]
[camera]
position = [0.3, 0.2, 0.5]
look_at = [0.0, 0.0, -2.0]
up = [0.0, 1.0, 0.0]
fov = 60.0
[[material]]
name = "mirror"
diffuse = [0.1, 0.1, 0.1]
reflect = 0.8
[[object]]
name = "box"
box = { size = [4.0, 3.0, 5.0] }
material = "mirror"
"""


def test_chip_reflections_without_lights_in_amaranth_sim(tmp_path, kd_cache):
    """A frame without lights (K = 1: a packet reserves one buffer, for its reflections)
    inside a mirrored box, every ray reflected to depth 2, more RTC slots than pending
    buffers (4 threads: 8 slots; 4 buffers, the fewest) and 8 packets of 2x2 rays: every eye
    packet commits with a waiting reflection packet that may spawn. Without the branching
    bound the waiting packets hold every buffer and the slave deadlocks
    (``tests/test_rgs_slave_reservations.py``); with it the frame finishes, every ray and
    pixel bit-exact."""
    from tb.harness.chip import run_chip
    path = tmp_path / "mirror_box.toml"
    path.write_text(MIRROR_BOX)
    scene = load_scene(path)
    assert len(scene.lights) == 0
    cfg = TINY.replace(threads=4, rgs_lights=0, reflect_depth=2, rgs_buffers=4, tile_w=2,
                       tile_h=2)
    assert rtl_slave_buffers(cfg) == cfg.min_rgs_buffers == 4
    image = prepare(scene, cfg, cache_dir=kd_cache).image
    r = run_chip(cfg, image, scene.camera, 8, 4, stall=0.25, seed=3, scene=scene,
                 max_cycles=100_000)
    check_frame(r, cfg, image, eye_rays(scene.camera, 8, 4, cfg))
    rays = r.frame_rays
    assert ((rays.kind == RayKind.REFLECTION) & (rays.depth == 2)).sum() == 32
