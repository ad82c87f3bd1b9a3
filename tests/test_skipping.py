"""Skipping what a scene doesn't need: the box cull and empty tiles at run time
(``model.render.Skip``), and the chip built for the scene (``Config.for_scene``: stack depth,
light registers, no secondary-ray hardware). The measurements are ``saarcor bench skipping``."""
import dataclasses

import numpy as np
import pytest

from model.config import Config, ConfigError
from model.raygen import box_misses, eye_rays, live_packets, setup
from model.render import Skip, prepare, render
from model.rtc import counter_totals, trace
from model.scene import load_scene

from .conftest import ROOT, TIMING, timing_changed

TINY = Config(rtcs=1, threads=2, tile_w=4, tile_h=4, trav_subunits=2, trav_cache_kb=1,
              list_cache_kb=1, int_cache_kb=9, mem_latency=8)


@pytest.fixture(scope="module")
def cornell(kd_cache):
    scene = load_scene(ROOT / "scenes/cornell.toml")
    return scene, prepare(scene, TINY, cache_dir=kd_cache)


def test_box_cull_keeps_missing_rays_out_of_traversal(cornell):
    """Cornell's camera sees past the open box: the rays that miss the box do no traversal
    step with the cull and do work without it; every hit is the same either way."""
    scene, prep = cornell
    rays = eye_rays(scene.camera, 32, 24, TINY)
    rs = setup(rays, prep.image.bounds, TINY.fmt)
    miss = box_misses(rs.tnear, rs.tfar)
    assert 0 < miss.sum() < len(rays)
    on, c_on = trace(prep.image, rays, TINY)
    off, c_off = trace(prep.image, rays, TINY, box_cull=False)
    for f in ("tri", "t", "u", "v"):
        assert np.array_equal(getattr(on, f), getattr(off, f)), f
    on, off = counter_totals(c_on), counter_totals(c_off)
    assert off["trav_ops"] > on["trav_ops"] and off["int_ops"] > on["int_ops"]
    # the missing rays alone, in packets of their own: nothing with the cull
    from model.raygen import Rays
    lost = Rays.from_arrays(rays.org[miss], rays.dir[miss], packet=16)
    _, c = trace(prep.image, lost, TINY)
    assert counter_totals(c)["trav_ops"] == counter_totals(c)["passes"] == 0
    _, c = trace(prep.image, lost, TINY, box_cull=False)
    assert counter_totals(c)["trav_ops"] > 0


def test_empty_tiles_are_not_traced_and_change_nothing(cornell):
    scene, prep = cornell
    cfg = TINY.replace(reflect_depth=1)
    base = render(scene, cfg, 32, 24, prepared=prep)
    skip = render(scene, cfg, 32, 24, prepared=prep, skip=Skip(empty_tiles=True))
    eye = eye_rays(scene.camera, 32, 24, cfg)
    empty = int((~live_packets(eye, setup(eye, prep.image.bounds, cfg.fmt))).sum())
    assert empty > 0
    assert skip.stats["packets_skipped"] == empty        # secondary packets all meet the box
    assert base.stats["packets_skipped"] == 0
    assert np.array_equal(base.image, skip.image)
    assert np.array_equal(base.hits.tri, skip.hits.tri)
    assert base.counters == skip.counters


def _no_lights_no_mirrors(scene):
    mats = [dataclasses.replace(m, reflect=0.0) for m in scene.materials]
    return dataclasses.replace(scene, lights=[], materials=mats)


def _first(scene, n):
    return dataclasses.replace(scene, tris=scene.tris[:n], tri_id=np.arange(n, dtype=np.int32),
                               n_scene_tris=n, material=scene.material[:n], uv=scene.uv[:n],
                               normals=scene.normals[:n])


def test_for_scene_derives_what_the_scene_needs(cornell, kd_cache):
    scene, prep = cornell
    cfg = TINY.for_scene(scene, prep.image, 32, 24)
    # the builder splits Cornell down to the depth limit: the stack stays as configured
    assert (cfg.kd_max_depth, cfg.rgs_lights, cfg.reflect_depth) == (TINY.kd_max_depth, 3, 3)
    assert cfg.secondary_rays
    bare = TINY.for_scene(_no_lights_no_mirrors(scene), prep.image, 32, 24)
    assert (bare.rgs_lights, bare.reflect_depth, bare.secondary_rays) == (0, 0, False)
    dark = TINY.replace(shadows=False).for_scene(scene, prep.image, 32, 24)
    assert (dark.rgs_lights, dark.reflect_depth, dark.secondary_rays) == (0, 3, True)
    # the checkered floor keeps the texture unit; without textures there is none
    assert cfg.tex_cache_kb == TINY.tex_cache_kb > 0
    plain = dataclasses.replace(scene, materials=[dataclasses.replace(m, texture=None)
                                                  for m in scene.materials])
    assert TINY.for_scene(plain, prep.image, 32, 24).tex_cache_kb == 0
    # four triangles (kd_leaf_size): the root is a leaf, one stack entry is enough, and the
    # tree built with that limit is the same
    few = _first(scene, TINY.kd_leaf_size)
    small = prepare(few, TINY, cache_dir=kd_cache)
    assert small.image.depth == 0
    fit = TINY.for_scene(few, small.image, 32, 24)
    assert fit.kd_max_depth == fit.stack_depth == 1
    assert np.array_equal(prepare(few, fit, cache_dir=kd_cache).image.data, small.image.data)


def test_for_scene_names_what_the_configuration_lacks(cornell):
    scene, prep = cornell
    with pytest.raises(ConfigError, match="3 lights.*rgs_lights=2"):
        TINY.replace(rgs_lights=2).for_scene(scene, prep.image, 32, 24)
    with pytest.raises(ConfigError, match=f"{prep.image.depth} levels deep.*holds 3"):
        TINY.replace(kd_max_depth=3).check_scene(scene, prep.image, 32, 24)
    with pytest.raises(ConfigError, match="width=70000"):
        TINY.check_scene(scene, prep.image, 70000, 24)


def test_for_scene_narrows_addresses_to_the_image(cornell):
    """Memory addresses get the bits the image's words need; a narrower address than the
    image needs, or than the caches index, is refused naming addr_bits."""
    scene, prep = cornell
    words = len(prep.image.data)
    fit = TINY.for_scene(scene, prep.image, 32, 24)
    assert TINY.addr_bits == 32 and TINY.min_addr_bits == 13
    assert fit.addr_bits == (words - 1).bit_length() < 32
    assert fit.addr_bits >= fit.min_addr_bits        # still indexes every cache
    fit.check_scene(scene, prep.image, 32, 24)          # the narrowest that holds the image
    with pytest.raises(ConfigError, match=f"{words} words.*addr_bits={fit.addr_bits - 1}"):
        TINY.replace(addr_bits=fit.addr_bits - 1).check_scene(scene, prep.image, 32, 24)
    with pytest.raises(ConfigError, match="addr_bits=12 must be in 13..32"):
        TINY.replace(addr_bits=12)
    with pytest.raises(ConfigError, match="addr_bits=33"):
        TINY.replace(addr_bits=33)


@pytest.mark.filterwarnings("ignore:.*created but never used")
def test_narrow_addresses_shrink_the_cache_tags():
    """Each line's tag loses the address bits the chip no longer has: 32 - addr_bits bits a
    line of tag memory, on every cache of the RTC-MI and the slaves."""
    from rtl.cache import Cache
    from rtl.rgs import shade_cache_geometry
    from rtl.rtcmi import rtcmi_geometries
    from saarcor.bench.resources import resources
    for a in (32, 18):
        assert all(g.mem_addr_width == g.addr_width == a for g in
                   [*rtcmi_geometries(TINY.replace(addr_bits=a)).values(),
                    shade_cache_geometry(TINY.replace(addr_bits=a))])
    wide, narrow = (rtcmi_geometries(TINY.replace(addr_bits=a))["int"] for a in (32, 18))
    assert wide.tag_bits - narrow.tag_bits == 14
    bits = [resources(lambda: Cache(g, tag_width=2))["totals"] for g in (wide, narrow)]
    assert bits[0]["memory_bits"] - bits[1]["memory_bits"] == wide.sets * wide.ways * 14
    assert bits[1]["flipflop_bits"] < bits[0]["flipflop_bits"]


@pytest.mark.filterwarnings("ignore:.*created but never used")
def test_eye_only_slave_has_no_secondary_ray_units():
    """Without lights and reflections the slave drops the ray setup (3 + 2 div, 6 sub, 6
    mul, 12 min/max: docs/rgs.md), the secondary datapath (43 mul, 30 add, 2 sqrt, 2 div),
    the light datapath (LightPipe: 59 mul, 16 add, 2 sqrt, 2 div), the texture unit
    (12 mul, 6 add, 3 int -> FP), and its ray store and pending buffers."""
    from rtl.rgs import Slave
    from saarcor.bench.resources import resources
    full = resources(lambda: Slave(TINY))
    eye = resources(lambda: Slave(TINY.replace(rgs_lights=0, reflect_depth=0)))
    diff = {k: full["fp_units"].get(k, 0) - eye["fp_units"].get(k, 0)
            for k in full["fp_units"]}
    assert {k: v for k, v in diff.items() if v} == {"div": 9, "add": 58, "mul": 120,
                                                   "minmax": 12, "sqrt": 4, "int_to_fp": 3}
    assert eye["totals"]["memory_bits"] < full["totals"]["memory_bits"] / 10


def test_eye_only_chip_same_frame_same_cycles(cornell):
    """The chip without secondary-ray hardware and with addresses as narrow as the image
    renders an eye-ray frame bit-exact, in the same cycles as the whole chip
    (``tests/test_chip.py``, same frame, stall and seed)."""
    from rtl.chip import Chip
    from tb.harness.chip import run_chip

    from .test_chip import check_frame
    scene, prep = cornell
    cfg = TINY.replace(rgs_lights=0, reflect_depth=0,
                       addr_bits=(len(prep.image.data) - 1).bit_length())
    assert not cfg.secondary_rays and cfg.addr_bits < 32
    assert len(Chip(cfg).mem.req.payload.addr) == cfg.addr_bits
    r = run_chip(cfg, prep.image, scene.camera, 8, 4, stall=0.25, seed=3)
    check_frame(r, cfg, prep.image, eye_rays(scene.camera, 8, 4, cfg))
    name = "chip/cornell_8x4_rtcs1"
    assert r.cycles == TIMING[name], timing_changed(name, r.cycles)


@pytest.mark.slow
def test_chip_box_cull_off_traverses_the_missing_rays(cornell):
    """With the slaves' box cull turned off (the ``box_cull`` register at 0) the 16 of Cornell
    8x4's 32 eye rays that miss the box are traversed with ``[0, +inf]``: every ray bit-exact
    with the model's frame without the cull and the RTC's counters equal to its counters,
    which have more traversal work than the culled frame's (same hits)."""
    from tb.harness.chip import golden_frame, run_chip

    from .test_chip import check_frame
    scene, prep = cornell
    cfg = TINY.replace(rgs_lights=0, reflect_depth=0)
    eye = eye_rays(scene.camera, 8, 4, cfg)
    rs = setup(eye, prep.image.bounds, cfg.fmt)
    assert box_misses(rs.tnear, rs.tfar).sum() == 16
    r = run_chip(cfg, prep.image, scene.camera, 8, 4, box_cull=False)
    check_frame(r, cfg, prep.image, eye)
    _, _, hits_on, on, _ = golden_frame(cfg, prep.image, scene.camera, 8, 4)
    _, _, hits_off, off, _ = golden_frame(cfg, prep.image, scene.camera, 8, 4, box_cull=False)
    assert r.model == off and off["trav_ops"] > on["trav_ops"]
    assert np.array_equal(hits_off.tri, hits_on.tri)
