"""The render's compiled drivers (``model/render_kernels.py``) and the binary32 classify give
the bits of the serial reference functions; the bench's whole-render measurement runs."""
import numpy as np
import pytest

from model import render_kernels as rk
from model import rgs
from model.fp import FPFormat
from model.traversal import classify, classify32

from .conftest import ROOT

FORMATS = [FPFormat(8, 23), FPFormat(5, 10)]


def odd_values(rng, shape, fmt):
    """Format values with zeros of both signs, infinities, NaNs and tiny magnitudes mixed in."""
    x = rng.normal(size=shape) * 2.0 ** rng.integers(-8, 8, size=shape)
    flat = x.reshape(-1)
    pick = rng.random(flat.size)
    flat[pick < 0.02] = 0.0
    flat[(pick >= 0.02) & (pick < 0.03)] = -0.0
    flat[(pick >= 0.03) & (pick < 0.035)] = np.inf
    flat[(pick >= 0.035) & (pick < 0.04)] = np.nan
    tiny = (pick >= 0.04) & (pick < 0.06)
    flat[tiny] *= 2.0 ** (fmt.em[0] == 8 and -120 or -12)
    return fmt.quantize(x).astype(np.float32)


def same(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.mark.parametrize("fmt", FORMATS, ids=str)
def test_eye_packets_and_setup_match_serial(fmt):
    E, M = fmt.em
    sw, sh, tw, th, n, width = 2 * 37, 2 * 21, 8, 4, 2, 37
    corner, dx, dy = (fmt.quantize(np.array(v)).astype(np.float32)
                      for v in ([-0.7, 0.4, -1.0], [0.013, 0.0, 0.001], [0.0, -0.019, 0.0005]))
    total = sw * sh
    outs = []
    for f in (rgs.eye_packets, rk.eye_packets):
        d = np.empty((total, 3), np.float32)
        pixel = np.empty(total, np.int32)
        pk = np.empty(rgs.packet_count(sw, sh, tw, th) + 1, np.int64)
        f(sw, sh, tw, th, n, width, corner, dx, dy, d, pixel, pk, E, M)
        outs.append((d, pixel, pk))
    assert all(same(a, b) for a, b in zip(*outs))

    rng = np.random.default_rng(1)
    N = 5000
    org, dirn = odd_values(rng, (N, 3), fmt), odd_values(rng, (N, 3), fmt)
    tmax = np.abs(odd_values(rng, N, fmt))
    lo = fmt.quantize(np.array([-1.5, -2.0, -0.5])).astype(np.float32)
    hi = fmt.quantize(np.array([1.0, 0.5, 2.5])).astype(np.float32)
    outs = []
    for f in (rgs.setup_rays, rk.setup_rays):
        o = (np.empty((N, 3), np.float32), np.empty((N, 3), np.int64),
             np.empty((N, 3), np.float32), np.empty(N, np.float32), np.empty(N, np.float32),
             np.empty(N, np.int64))
        f(org, dirn, tmax, lo, hi, *o, E, M)
        outs.append(o)
    assert all(same(a, b) for a, b in zip(*outs))


@pytest.mark.parametrize("fmt", FORMATS, ids=str)
def test_shading_drivers_match_serial(fmt):
    E, M = fmt.em
    rng = np.random.default_rng(2)
    N, H = 6000, 4500
    org, dirn = odd_values(rng, (N, 3), fmt), odd_values(rng, (N, 3), fmt)
    rows = np.sort(rng.choice(N, H, replace=False)).astype(np.int64)
    t, u, v = (np.abs(odd_values(rng, H, fmt)) for _ in range(3))
    nf, nv = odd_values(rng, (H, 3), fmt), odd_values(rng, (H, 3, 3), fmt)
    eps = np.float32(fmt.quantize(1e-3))
    want = rgs.secondary_rays(org[rows], dirn[rows], t, u, v, nf, nv, eps, E, M)
    tri = rng.permutation(H).astype(np.int64)
    inv = np.argsort(tri)
    got = rk.secondary_rays(org, dirn, rows, t, u, v, tri, nf[inv], nv[inv], eps, E, M)
    assert all(same(a, b) for a, b in zip(want, got))

    p0, g = want[0], want[1]
    light = fmt.quantize(np.array([0.3, 5.0, -1.0])).astype(np.float32)
    for point in (True, False):
        assert all(same(a, b) for a, b in zip(rgs.shadow_rays(p0, g, light, point, E, M),
                                              rk.shadow_rays(p0, g, light, point, E, M)))

    kd, ks = np.abs(odd_values(rng, (H, 3), fmt)), np.abs(odd_values(rng, (H, 3), fmt))
    shin = rng.integers(0, 1024, H).astype(np.int64)
    wt = np.abs(odd_values(rng, H, fmt))
    lc = fmt.quantize(np.array([0.9, 0.7, 0.2])).astype(np.float32)
    ld = odd_values(rng, (H, 3), fmt)
    assert same(rgs.light_colours(ld, want[2], want[3], kd, ks, shin, np.tile(lc, (H, 1)), wt,
                                  E, M),
                rk.light_colours(ld, want[2], want[3], kd, ks, shin, lc, wt, E, M))
    kr = np.abs(odd_values(rng, H, fmt))
    amb, bg = np.float32(fmt.quantize(0.08)), lc
    assert all(same(a, b) for a, b in zip(rgs.hit_colours(kd, kr, amb, bg, wt, E, M),
                                          rk.hit_colours(kd, kr, amb, bg, wt, E, M)))


def test_colour_sums_match_numpy():
    rng = np.random.default_rng(3)
    acc = rng.integers(0, 1 << 30, (500, 3)).astype(np.int64)
    pixel = rng.integers(0, 500, 4000).astype(np.int32)
    rows = rng.choice(4000, 3000).astype(np.int64)
    vals = rng.integers(0, 1 << 24, (3000, 3)).astype(np.int64)
    want = acc.copy()
    np.add.at(want, pixel[rows], vals)
    got = acc.copy()
    rk.add_colours(got, pixel, rows, vals)
    assert same(want, got)
    np.add.at(want, pixel[rows], vals[:1])
    rk.add_colours(got, pixel, rows, vals[:1])
    assert same(want, got)
    assert same(rk.colour_image(got), (got / float(1 << rgs.FIX_FRAC)).astype(np.float32))


def test_binary32_classify_matches_exact():
    """Random lanes at scales down to the underflow band, and lanes lying in the plane."""
    rng = np.random.default_rng(4)
    for trial in range(300):
        n = int(rng.integers(1, 65))
        scale = 2.0 ** float(rng.choice([0, -60, -120, -126, -130, 40]))
        fmt = FPFormat(8, 23)
        org = fmt.quantize(rng.normal(size=(n, 3)) * scale).astype(np.float32)
        inv = fmt.quantize(rng.normal(size=(n, 3)) * 2.0 ** rng.integers(-30, 30)).astype(
            np.float32)
        axis = int(rng.integers(0, 3))
        split = np.float32(org[rng.integers(0, n), axis] if trial % 3 == 0
                           else fmt.quantize(rng.normal() * scale))
        tnear = np.abs(fmt.quantize(rng.normal(size=n))).astype(np.float32)
        tfar = (tnear + np.abs(fmt.quantize(rng.normal(size=n)))).astype(np.float32)
        mask = np.uint64((int(rng.integers(0, 1 << 62)) | 1) & ((1 << n) - 1))
        d0, d1 = np.full(n, 7, np.float32), np.full(n, 7, np.float32)
        want = classify(split, axis, mask, n, org, inv, tnear, tfar, d0, 8, 23)
        got = classify32(split, axis, mask, n, np.ascontiguousarray(org.T),
                         np.ascontiguousarray(inv.T), tnear, tfar, d1, org, inv)
        on = [(int(mask) >> i) & 1 == 1 for i in range(n)]
        assert want == got
        assert same(d0[on], d1[on])


def test_bench_render_speed_runs(tmp_path):
    from model.bench import render_speed
    from model.scene import load_scene
    r = render_speed(load_scene(ROOT / "scenes/cornell.toml"), (32, 24), 1, None)
    assert r["rays"] == 32 * 24 and r["rays_per_second"] > 0 and r["threads"] >= 1
    assert set(r["phase_seconds"]) == {"raygen", "setup", "trace", "shading"}
