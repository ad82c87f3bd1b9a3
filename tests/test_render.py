"""The render's compiled pieces: ``model.rgs.secondary_rays``' indexed reads, the per-pixel
colour sums against NumPy, the binary32 classify against the exact one; the bench's
whole-render measurement runs."""
import numpy as np
import pytest

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
def test_secondary_rays_reads_hits_by_index(fmt):
    """``model.rgs.secondary_rays`` reads hit i from ray ``rows[i]`` and triangle ``tri[i]``:
    the same bits as on arrays gathered beforehand (hit i = ray i, triangle i), over several
    parallel tasks and with NaN, infinite, zero and tiny operands. (Its arithmetic against an
    independent recomputation: ``tests/test_rgs_model.py``.)"""
    E, M = fmt.em
    rng = np.random.default_rng(2)
    N, H = 6000, 4500
    org, dirn = odd_values(rng, (N, 3), fmt), odd_values(rng, (N, 3), fmt)
    rows = np.sort(rng.choice(N, H, replace=False)).astype(np.int64)
    t, u, v = (np.abs(odd_values(rng, H, fmt)) for _ in range(3))
    nf, nv = odd_values(rng, (H, 3), fmt), odd_values(rng, (H, 3, 3), fmt)
    eps = np.float32(fmt.quantize(1e-3))
    i = np.arange(H, dtype=np.int64)
    want = rgs.secondary_rays(org[rows], dirn[rows], i, t, u, v, i, nf, nv, eps, E, M)
    tri = rng.permutation(H).astype(np.int64)
    inv = np.argsort(tri)
    got = rgs.secondary_rays(org, dirn, rows, t, u, v, tri, nf[inv], nv[inv], eps, E, M)
    assert all(same(a, b) for a, b in zip(want, got))


def test_colour_sums_match_numpy():
    from model.render import add_colours, colour_image
    rng = np.random.default_rng(3)
    acc = rng.integers(0, 1 << 30, (500, 3)).astype(np.int64)
    pixel = rng.integers(0, 500, 4000).astype(np.int32)
    rows = rng.choice(4000, 3000).astype(np.int64)
    vals = rng.integers(0, 1 << 24, (3000, 3)).astype(np.int64)
    want = acc.copy()
    np.add.at(want, pixel[rows], vals)
    got = acc.copy()
    add_colours(got, pixel, rows, vals)
    assert same(want, got)
    np.add.at(want, pixel[rows], vals[:1])
    add_colours(got, pixel, rows, vals[:1])
    assert same(want, got)
    assert same(colour_image(got), (got / float(1 << rgs.FIX_FRAC)).astype(np.float32))


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
    from saarcor.bench.model import render_speed
    from model.scene import load_scene
    r = render_speed(load_scene(ROOT / "scenes/cornell.toml"), (32, 24), 1, None)
    assert r["rays"] == 32 * 24 and r["rays_per_second"] > 0 and r["threads"] >= 1
    assert set(r["phase_seconds"]) == {"raygen", "setup", "trace", "shading"}
