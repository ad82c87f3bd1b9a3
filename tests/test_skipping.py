"""Skipping what a scene doesn't need: the box cull and empty tiles at run time
(``model.render.Skip``). The measurements are ``python -m tb.skipping``."""
import numpy as np
import pytest

from model.config import Config
from model.raygen import box_misses, eye_rays, live_packets, setup
from model.render import Skip, prepare, render
from model.rtc import counter_totals, trace
from model.scene import load_scene

from .conftest import ROOT

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
