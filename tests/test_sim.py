"""``make sim`` (``saarcor/sim.py``): a frame through the chip in Verilator, its outputs and errors.

Uses the small 2-RTC chip configuration of ``tests/test_chip.py`` (its Verilator binary is
shared with those tests)."""
import json

import numpy as np
import pytest
from PIL import Image

from model.raygen import eye_rays
from model.render import prepare
from model.scene import load_scene

from .conftest import ROOT

TINY_ARGS = ["--rtcs", "2", "--threads", "2", "--tile-w", "4", "--tile-h", "4",
             "--trav-subunits", "2", "--trav-cache-kb", "1", "--list-cache-kb", "1",
             "--int-cache-kb", "9", "--mem-latency", "8"]


def test_sim_writes_image_stats_usage_and_the_chips_hits(tmp_path, kd_cache):
    from model.config import Config
    from saarcor.sim import main
    out = tmp_path / "sim"
    rc = main(["--scene", str(ROOT / "scenes/cornell.toml"), "--res", "16x12", "--out",
               str(out), "--kd-cache", str(kd_cache), "--quiet", "--sample-every", "100",
               *TINY_ARGS])
    assert rc == 0
    stats = json.loads((out / "stats.json").read_text())
    c = stats["config"]
    assert (c["rtcs"], c["threads"], c["trav_cache_kb"]) == (2, 2, 1)
    cfg = Config(rtcs=2, threads=2, tile_w=4, tile_h=4, trav_subunits=2, trav_cache_kb=1,
                 list_cache_kb=1, int_cache_kb=9, mem_latency=8)
    assert cfg.to_dict() == c
    assert stats["mismatches"] == 0 and stats["backend"] == "verilator"
    kinds = stats["rays"]
    assert kinds["eye"] == 16 * 12 and kinds["shadow"] > kinds["eye"]
    assert stats["rays_total"] == sum(kinds.values())
    # the figures are the counters' own: op counts, the paper's ideal and relative performance
    ctr = stats["counters"]
    assert stats["trav_ops"] == sum(x["trav_ops"] for x in ctr["rtc"]) > 0
    # the same float expressions as the paper's definition: equal, not close (JSON keeps them)
    ideal = max(stats["trav_ops"] / (2 * 2), stats["int_ops"] / 2)
    assert stats["relative_performance"] == ideal / stats["cycles"]
    assert stats["fps"] == cfg.clock_mhz * 1e6 / stats["cycles"]
    assert stats["cache_topology"] == "shared"
    for k in ("trav", "list", "int"):
        c = stats["cache"][k]
        assert 0 < c["hit_rate"] < 1 and c["hits"] + c["misses"] > 0
        # the shared cache's bus: one request a cycle, each request one lookup
        assert c["bus"]["busy"] == (c["hits"] + c["misses"]) / stats["cycles"]
        assert 0 < c["bus"]["busy"] < 1 and 0 <= c["bus"]["wait"] < 1
    mem = stats["memory"]
    assert mem["bytes"] == 8 * mem["words"] == 8 * sum(p["words"] for p in mem["per_chip"])
    assert [p["share"] for p in mem["per_chip"]] == [p["words"] / mem["words"]
                                                     for p in mem["per_chip"]]
    assert 0 < stats["units"]["int"] <= 1 and 0 < stats["bus"]["words_per_cycle"] <= 1
    # the rays and hits are the chip's: equal to the golden model's render of the frame, and
    # the image is the chip's colour, equal to that render's (textured: the slaves' texture
    # units)
    from model.render import render, to_srgb8
    scene = load_scene(ROOT / "scenes/cornell.toml")
    prep = prepare(scene, cfg, cache_dir=kd_cache)
    want = render(scene, cfg, 16, 12, prepared=prep)
    hits = np.load(out / "hits.npz")
    assert np.array_equal(hits["tri"], want.hits.tri)
    for f in ("t", "u", "v"):
        assert np.array_equal(hits[f].view(np.uint32), getattr(want.hits, f).view(np.uint32)), f
    assert (hits["tri"] >= 0).any()
    img = np.asarray(Image.open(out / "image.png"))
    assert img.shape == (12, 16, 3) and img.std() > 5
    assert np.array_equal(img, to_srgb8(want.image))
    assert Image.open(out / "usage.png").size[0] > 500
    assert len(np.load(out / "rays.npz")["pixel"]) == stats["rays_total"]
    # where the cycles went: each unit's four shares add up to the frame (one cycle short
    # at most), and the limiter names a reason with its figure
    for u in ("trav", "list", "int"):
        total = sum(stats["stalls"][u].values())
        assert 1 - 2 / stats["cycles"] <= total <= 1 + 1e-12, (u, stats["stalls"][u])
    assert stats["limiter"]["limit"] in ("trav-bound", "list-bound", "int-bound",
                                         "memory-bandwidth-bound", "bus-bound",
                                         "memory-latency-bound", "back-pressure", "starved",
                                         "output-bound", "slave-pool-bound")
    assert "%" in stats["limiter"]["why"]
    assert 0 <= stats["memory"]["saturated_share"] <= 1


def _stats(work, memory=0.0, blocked=0.0, starved=0.0, *, unit="trav", sdram=0.2, wait=0.0,
           sat=0.0, output=0.3, slave_blocked=0.2, pool=None):
    other = {"work": 0.1, "memory": 0.1, "blocked": 0.0, "starved": 0.8}
    st = {u: dict(other) for u in ("trav", "list", "int")}
    st["slave"] = {"work": 0.2, "memory": 0.0, "blocked": slave_blocked,
                   "starved": 0.8 - slave_blocked}
    st[unit] = {"work": work, "memory": memory, "blocked": blocked, "starved": starved}
    cache = {k: {"hit_rate": 0.9, "bus": {"busy": 0.3, "wait": wait}}
             for k in ("trav", "list", "int")}
    return {"stalls": st, "cache": cache,
            "config": {"rtcs": 4, "threads": 16, "rgs_fp_adders": 3, "rgs_fp_muls": 4},
            "slaves": {"pool": pool} if pool else {},
            "memory": {"per_chip": [{"busy": sdram}, {"busy": sdram / 2}],
                       "saturated_share": sat},
            "packets_per_rtc": [12, 12, 12, 12], "output": {"ports": 1, "busy": output}}


@pytest.mark.parametrize("stats,limit,words", [
    (_stats(0.9, 0.05, 0.0, 0.05), "trav-bound", "traversal works 90 %"),
    (_stats(0.6, 0.3, 0.05, 0.05, sdram=0.8), "memory-bandwidth-bound", "busy 80 %"),
    (_stats(0.6, 0.3, 0.05, 0.05, sdram=0.6, sat=0.62), "memory-bandwidth-bound",
     "at least 80 % in 62 % of it"),
    (_stats(0.6, 0.3, 0.05, 0.05, wait=0.5), "bus-bound", "trav cache's bus 50 %"),
    (_stats(0.4, 0.35, 0.0, 0.25, wait=0.5, output=0.85, slave_blocked=0.9), "output-bound",
     "record 85 % of the cycles and the RGS slaves are blocked 90 %"),
    (_stats(0.4, 0.35, 0.0, 0.25, wait=0.5, output=0.85, slave_blocked=0.3), "bus-bound",
     "trav cache's bus 50 %"),
    (_stats(0.6, 0.3, 0.05, 0.05), "memory-latency-bound", "cache hits 90.0 %"),
    (_stats(0.5, 0.1, 0.3, 0.1, unit="int"), "back-pressure", "RGS slave"),
    (_stats(0.3, 0.1, 0.0, 0.6), "starved", "48 packets for 4 RTCs x 16 threads"),
    (_stats(0.5, 0.1, 0.3, 0.1, unit="int", pool={"sec": 0.95, "light": 0.7}),
     "slave-pool-bound", "3 adders and 4 multipliers sets the pace: its secondary-ray "
     "datapath takes an input in 95 % of its slots"),
    (_stats(0.3, 0.1, 0.0, 0.6, pool={"sec": 0.5, "light": 0.9}), "slave-pool-bound",
     "light datapath takes an input in 90 %"),
    (_stats(0.3, 0.1, 0.0, 0.6, pool={"sec": 0.5, "light": 0.8, "eye": 0.3}), "starved",
     "48 packets"),
    (_stats(0.2, 0.02, 0.77, 0.01, unit="int", pool={"sec": 0.49, "eye": 0.47, "light": 0.37}),
     "back-pressure", "RGS slave"),
    (_stats(0.6, 0.3, 0.05, 0.05, pool={"sec": 0.9}), "memory-latency-bound", "hits 90.0"),
])
def test_limiter_rule(stats, limit, words):
    from saarcor.sim import limiter
    got = limiter(stats)
    assert got["limit"] == limit and words in got["why"], got


def test_sim_errors_name_the_problem(tmp_path):
    from saarcor.sim import main
    with pytest.raises(SystemExit, match="--res '0x4'"):
        main(["--res", "0x4", "--out", str(tmp_path)])
    with pytest.raises(SystemExit, match="scene 'nope.toml' not found"):
        main(["--scene", "nope.toml", "--out", str(tmp_path)])
    with pytest.raises(SystemExit, match="rtcs"):
        main(["--rtcs", "0", "--out", str(tmp_path)])
    with pytest.raises(SystemExit, match="VCD"):
        main(["--backend", "amaranth", "--trace", "x.fst", "--out", str(tmp_path)])
    with pytest.raises(SystemExit, match="--fmt or --narrowest-fmt"):
        main(["--fmt", "E8M16", "--narrowest-fmt", "--out", str(tmp_path)])


def test_sim_narrowest_format_for_the_scene(tmp_path, kd_cache):
    """--narrowest-fmt --for-scene: the chip's configuration in stats.json has the chosen
    format (below binary32 on Cornell) and the scene's light and reflection needs."""
    from saarcor.sim import main
    out = tmp_path / "sim"
    rc = main(["--scene", str(ROOT / "scenes/cornell.toml"), "--res", "16x12", "--out",
               str(out), "--kd-cache", str(kd_cache), "--quiet", "--fidelity", "estimate",
               "--narrowest-fmt", "--for-scene", "--rgs-lights", "8", *TINY_ARGS])
    assert rc == 0
    stats = json.loads((out / "stats.json").read_text())
    chosen = stats["narrowest_fmt"]
    assert chosen["resolution"] == [128, 97]
    assert chosen["formats"][chosen["fmt"]]["ok"] and chosen["fmt"] != "E8M23"
    m = int(chosen["fmt"].split("M")[1])
    assert stats["config"]["fmt"] == {"exp_bits": 8, "frac_bits": m}
    scene = load_scene(ROOT / "scenes/cornell.toml")
    assert stats["config"]["rgs_lights"] == len(scene.lights) < 8


def test_a_mismatch_names_the_rays_pixel_kind_and_packet():
    """The text a mismatching run prints: ray id, pixel, kind, packet and lane, both values."""
    from model.config import Config
    from tb.harness.compare import describe
    rays = eye_rays(load_scene(ROOT / "scenes/cornell.toml").camera, 16, 8,
                    Config(tile_w=4, tile_h=4))
    text = describe([(37, "t", 0x3f800000, 0x3f800001)], rays=rays)
    # 4x4 packets over a 16-pixel row: ray 37 = packet 2 (tiles x = 8..11), lane 5 (x + 1, y + 1)
    assert "ray 37 (pixel 25, eye, packet 2 lane 5): t RTL 0x3f800000, model 0x3f800001" in text
