"""The simulation ladder: the cycle estimate (``model/timing.py``), the bands of the sampled
RTL (``saarcor/ladder.py``) and ``saarcor sim --fidelity``. Comparisons with the RTL itself
(Verilator builds) are ``slow``."""
from __future__ import annotations

import json

import numpy as np
import pytest

from model.config import Config
from model.raygen import eye_rays
from model.render import prepare
from model.rtc import trace
from model.scene import load_scene
from model.timing import estimate_events, estimate_frame, fps_error, record_work, work_of
from saarcor.ladder import (LADDER_CONFIGS, band_rays, band_registers, choose_bands,
                       ideal_cycles)

SMALL = Config(**LADDER_CONFIGS["1x4"])


@pytest.fixture(scope="module")
def cornell():
    scene = load_scene("scenes/cornell.toml")
    return scene, prepare(scene, SMALL)


def test_estimate_runs_and_respects_the_bounds(cornell):
    """A tiny frame: the estimate is at least what the busiest unit and the result port
    need, and it counts every packet once."""
    scene, prep = cornell
    rays = eye_rays(scene.camera, 16, 16, SMALL)
    est = estimate_frame(SMALL, prep.image, rays)
    _, ctrs = trace(prep.image, rays, SMALL)
    trav, inter = ctrs[:, 2].sum(), ctrs[:, 8].sum()
    assert est["estimate"] is True
    assert est["cycles"] >= ideal_cycles(SMALL, trav, inter)
    assert est["cycles"] >= len(rays)                   # one result a cycle leaves the chip
    assert sum(est["packets_per_rtc"]) == rays.n_packets
    assert est["int_ops"] == inter                      # every lane test replayed
    assert est["fps"] == SMALL.clock_mhz * 1e6 / est["cycles"]


def test_raw_and_decoded_event_logs_give_the_same_work(cornell):
    scene, prep = cornell
    rays = eye_rays(scene.camera, 16, 8, SMALL)
    _, _, events = trace(prep.image, rays, SMALL, record=True)
    a = work_of(events, prep.image, rays.n_packets, np.diff(rays.pk_start))
    b = record_work(prep.image, rays, SMALL)
    for k, v in a.items():
        np.testing.assert_array_equal(v, b[k], err_msg=k)
    assert estimate_events(SMALL, a)["cycles"] == estimate_events(SMALL, b)["cycles"]


def test_estimate_follows_memory_latency_and_threads(cornell):
    """One thread waits for every memory access: a longer latency must cost cycles; more
    threads hide it."""
    scene, prep = cornell
    rays = eye_rays(scene.camera, 16, 16, SMALL)
    one = SMALL.replace(threads=1)
    base = estimate_frame(one, prep.image, rays)["cycles"]
    slow = estimate_frame(one.replace(mem_latency=60), prep.image, rays)["cycles"]
    more = estimate_frame(one.replace(threads=8), prep.image, rays)["cycles"]
    assert slow > base * 1.05
    assert more < base * 0.8


def test_fps_error_scores_a_wrong_estimate_badly(cornell):
    """The error measure: 0 for the same count, the sign says which side; a deliberately
    wrong estimate (no memory latency to wait for, on a one-thread chip) is far off."""
    assert fps_error(1000, 1000) == 0
    assert fps_error(1000, 1250) == 0.25         # estimate too fast by 25 % (exact in binary)
    assert fps_error(1100, 1000) < 0
    with pytest.raises(ValueError):
        fps_error(0, 10)
    scene, prep = cornell
    rays = eye_rays(scene.camera, 16, 16, SMALL)
    one = SMALL.replace(threads=1)
    right = estimate_frame(one, prep.image, rays)["cycles"]
    wrong = estimate_frame(one.replace(mem_latency=2), prep.image, rays)["cycles"]
    assert abs(fps_error(wrong, right)) > 0.05


def test_bands_cover_whole_tile_rows():
    cfg = SMALL
    # (height, fraction, bands asked, bands the frame has room for: one tile row each at least)
    for height, fraction, bands, n in ((96, 0.1, 1, 1), (96, 0.1, 2, 2), (48, 0.5, 3, 3),
                                       (8, 0.1, 2, 2), (4, 0.5, 3, 1)):
        got = choose_bands(cfg, height, fraction, bands=bands)
        assert len(got) == n
        for i, (y0, rows) in enumerate(sorted(got)):        # centred at (i + 0.5) / n
            assert abs(y0 + rows / 2 - (i + 0.5) * height / n) <= cfg.tile_h
        ends = []
        for y0, rows in got:
            assert y0 % cfg.tile_h == 0 and rows % cfg.tile_h == 0 and rows > 0
            assert 0 <= y0 and y0 + rows <= height
            ends.append((y0, y0 + rows))
        ends.sort()
        assert all(a[1] <= b[0] for a, b in zip(ends, ends[1:]))      # no overlap
        share = sum(r for _, r in got) / height
        assert share <= max(fraction * 1.5, cfg.tile_h * bands / height)


def test_band_rays_are_the_frames_rays(cornell):
    """A band from row 0 over the whole height is the frame itself, bit for bit; a band lower
    down (its corner moved, so rounded differently) has the directions of those rows of the
    camera, against the float64 camera within the format's rounding."""
    scene, prep = cornell
    w, h = 16, 16
    full = eye_rays(scene.camera, w, h, SMALL)
    whole = band_rays(SMALL, scene.camera, w, h, 0, h)
    np.testing.assert_array_equal(whole.dir, full.dir)
    np.testing.assert_array_equal(whole.pk_start, full.pk_start)
    y0, rows = 8, 4
    band = band_rays(SMALL, scene.camera, w, h, y0, rows)
    regs = band_registers(SMALL, prep.image, scene.camera, w, h, y0, rows)
    assert regs["n_rays"] == len(band) == w * rows and regs["height"] == rows
    assert regs["reflect_depth"] == 0 and regs["n_lights"] == 0       # eye rays only
    # the float64 camera's directions of those rows (pixel = its index in the band)
    from model.raygen import camera_basis
    cam = scene.camera
    _, corner, dx, dy = camera_basis(cam.position, cam.look_at, cam.up, cam.fov_y, w, h)
    px, py = band.pixel % w + 0.5, band.pixel // w + y0 + 0.5
    ref = corner + px[:, None] * dx + py[:, None] * dy
    # a float64 reference, so a bound: the format's rounding of the camera registers, the
    # band's corner and the two products and sums, a few ulps of the terms' magnitudes (eps =
    # 2**-M; measured 0.4); the format rays are compared exactly above
    eps = 2.0 ** -SMALL.fmt.frac_bits
    mag = np.abs(corner) + px[:, None] * np.abs(dx) + py[:, None] * np.abs(dy)
    assert np.all(np.abs(band.dir - ref) <= 4 * eps * mag)
    assert not np.array_equal(band_rays(SMALL, scene.camera, w, h, 0, rows).dir, band.dir)


def test_sim_fidelity_estimate_writes_marked_stats(tmp_path):
    from saarcor.sim import main
    out = tmp_path / "est"
    assert main(["--fidelity", "estimate", "--scene", "scenes/cornell.toml", "--res", "16x8",
                 "--rtcs", "1", "--threads", "2", "--tile-w", "4", "--tile-h", "4",
                 "--trav-subunits", "2", "--out", str(out), "--quiet"]) == 0
    stats = json.loads((out / "stats.json").read_text())
    assert stats["estimate"] is True and stats["fidelity"] == "estimate"
    assert "cycles" not in stats and stats["cycles_estimated"] > 0
    assert stats["fps_estimated"] == 533e6 / round(stats["cycles_estimated"])
    assert (out / "image.png").exists()


# --- against the RTL (Verilator builds: minutes) -------------------------------------------------

@pytest.mark.slow
@pytest.mark.parametrize("scene_path", ["scenes/cornell.toml", "scenes/office.toml"])
def test_estimate_and_sampled_within_bounds_of_verilator(scene_path):
    """The estimate within 5 % of the RTL's frame rate, the sampled RTL within 5 % too (the
    bounds docs/ladder.md states), on a 1-RTC chip of 4 threads; every ray of the whole frame
    checked."""
    from saarcor.ladder import ladder_point
    p = ladder_point(SMALL, scene_path, 64, 48, fraction=0.25)
    m = p["methods"]
    assert m["rtl"]["mismatches"] == 0
    assert abs(m["estimate"]["fps_error"]) <= 0.05
    assert abs(m["sampled"]["fps_error"]) <= 0.05
    assert abs(m["model"]["fps_error"]) > 0.05           # op counts alone are no timing model
