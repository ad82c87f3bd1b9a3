"""Refracted rays (``model/rgs/refract.py``) against independent recomputations.

* NumPy-vectorized: the documented steps (``docs/rgs.md``, "Refraction") with ``FPFormat``'s
  array operations, bit for bit, in several formats.
* float64: Snell's law (the refracted direction has unit length, lies in the plane of the
  incoming direction and the normal, and sin(t) = eta sin(i)), total internal reflection
  where 1 - eta^2 (1 - c^2) < 0, and the origin across the surface.
* A render of ``scenes/glass.toml``: refracted rays are made exactly for the hits on
  transmitting materials below the reflection depth, and they carry colour.
* The RTL: ``SecondaryPipe(refract=True)`` (``rtl/rgs/secondary.py``) bit for bit with the
  model at its exact cycle, with bubbles and stalls (Amaranth simulator).
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from model.config import Config
from model.fp import FPFormat
from model.raykind import RayKind
from model.rgs import refraction_rays
from tb.units.rgs import secondary_cases

ROOT = Path(__file__).resolve().parents[1]
FORMATS = [FPFormat(8, 23), FPFormat(8, 14), FPFormat(6, 10), FPFormat(5, 10)]


def cases(fmt: FPFormat, n: int, seed: int):
    """``tb.units.rgs.secondary_cases`` hits with a random material each: weight, transmit,
    ior in 1 .. 2.5 (the record constants eta_in = 1 / ior, eta_out = ior)."""
    h = secondary_cases(fmt, n, seed=seed)
    rng = np.random.default_rng(seed + 100)
    q = fmt.quantize
    ior = rng.uniform(1.0, 2.5, n)
    mat = {"kt": q(rng.uniform(0.1, 1.0, n)).astype(np.float32),
           "eta_in": q(1.0 / ior).astype(np.float32), "eta_out": q(ior).astype(np.float32),
           "wt": q(rng.uniform(0.0, 1.0, n)).astype(np.float32),
           "bg": q(np.array([0.2, 0.5, 1.5])).astype(np.float32)}
    return h, mat


def run_model(h, mat, fmt):
    i = np.arange(len(h), dtype=np.int64)
    return refraction_rays(h.org, h.dir, i, h.t, h.u, h.v, i, h.nf, h.nv, np.float32(h.eps),
                           mat["kt"], mat["eta_in"], mat["eta_out"], mat["wt"], mat["bg"],
                           *fmt.em)


def np_refract(h, mat, fmt):
    """The documented steps with FPFormat's array operations."""
    add, sub, mul, div, sqrt = fmt.add, fmt.sub, fmt.mul, fmt.div, fmt.sqrt

    def dot(a, b):
        return add(add(mul(a[:, 0], b[:, 0]), mul(a[:, 1], b[:, 1])), mul(a[:, 2], b[:, 2]))
    p0, g, n, r = h.secondary(fmt)
    d, o = h.dir, h.org
    one = np.ones(len(h), np.float32)
    eta = np.where(dot(h.nf, d) > 0, mat["eta_out"], mat["eta_in"])
    rl = div(one, sqrt(dot(d, d)))
    w = np.stack([mul(d[:, a], rl) for a in range(3)], axis=1)
    c = -dot(w, n)
    k = sub(one, mul(mul(eta, eta), sub(one, mul(c, c))))
    tir = k < 0
    mu = sub(mul(eta, c), sqrt(np.where(tir, one, k)))
    t = np.stack([add(mul(eta, w[:, a]), mul(mu, n[:, a])) for a in range(3)], axis=1)
    pt = np.stack([add(sub(add(o[:, a], mul(h.t, d[:, a])), mul(np.float32(h.eps), g[:, a])),
                       mul(np.float32(h.eps), w[:, a])) for a in range(3)], axis=1)
    org = np.where(tir[:, None], p0, pt)
    dirn = np.where(tir[:, None], r, t)
    wt = mul(mat["wt"], mat["kt"])
    miss = np.stack([mul(np.full(len(h), mat["bg"][c_], np.float32), wt) for c_ in range(3)],
                    axis=1)
    return org, dirn, tir, wt, miss


def same(fmt, a, b):
    """Equal encodings (NaN equal to NaN)."""
    return np.array_equal(fmt.to_bits(np.asarray(a, np.float32)),
                          fmt.to_bits(np.asarray(b, np.float32)))


@pytest.mark.parametrize("fmt", FORMATS, ids=str)
def test_refraction_matches_vectorized(fmt):
    from tests.test_rgs_model import np_fixed
    h, mat = cases(fmt, 3000, seed=21)
    org, dirn, tir, wt, miss = run_model(h, mat, fmt)
    w_org, w_dir, w_tir, w_wt, w_miss = np_refract(h, mat, fmt)
    assert np.array_equal(tir, w_tir)
    assert tir.any() and (~tir).any()
    assert same(fmt, org, w_org) and same(fmt, dirn, w_dir) and same(fmt, wt, w_wt)
    assert np.array_equal(miss, np_fixed(w_miss, fmt))


def test_refraction_snell_float64():
    """Against float64 at binary32, from the same unit shading normal n (the secondary
    datapath's, checked in tests/test_rgs_model.py) and face normal: Snell's law and total
    internal reflection."""
    fmt = FPFormat(8, 23)
    h, mat = cases(fmt, 4000, seed=22)
    org, dirn, tir, _, _ = run_model(h, mat, fmt)
    p0, g, n, r = (x.astype(np.float64) for x in h.secondary(fmt))
    d = h.dir.astype(np.float64)
    w = d / np.linalg.norm(d, axis=1, keepdims=True)
    leave = np.sum(h.nf.astype(np.float64) * d, axis=1) > 0
    eta = np.where(leave, mat["eta_out"], mat["eta_in"]).astype(np.float64)
    c = -np.sum(w * n, axis=1)
    k = 1 - eta ** 2 * (1 - c ** 2)
    clear = np.abs(k) > 1e-4                     # away from the critical angle
    assert np.array_equal(tir[clear], (k < 0)[clear])
    assert (k[clear] < 0).sum() > 50 and (k[clear] > 0).sum() > 1000
    # total internal reflection: the mirror ray, bit for bit
    assert np.array_equal(dirn[tir], r[tir].astype(np.float32))
    assert np.array_equal(org[tir], p0[tir].astype(np.float32))
    ok = ~tir & clear
    t = dirn[ok].astype(np.float64)
    want = eta[ok, None] * w[ok] + (eta[ok] * c[ok] - np.sqrt(k[ok]))[:, None] * n[ok]
    # rounding: a few ulps of 1 per step, amplified near the critical angle by 1 / sqrt(k)
    tol = 1e-5 * (1 + 1 / np.sqrt(k[ok]))
    assert np.all(np.linalg.norm(t - want, axis=1) <= tol)
    # Snell: unit length, sin_t = eta sin_i, in the plane of w and n, through the surface
    nn = n[ok]
    assert np.all(np.abs(np.linalg.norm(t, axis=1) - 1) <= tol)
    sin_i = np.linalg.norm(np.cross(w[ok], nn), axis=1)
    sin_t = np.linalg.norm(np.cross(t, nn), axis=1)
    assert np.all(np.abs(sin_t - eta[ok] * sin_i) <= 2 * tol)
    assert np.all(np.abs(np.sum(np.cross(w[ok], nn) * t, axis=1)) <= 2 * tol)
    front = c[ok] > 1e-3
    assert np.all(np.sum(t * nn, axis=1)[front] < 0)
    # the origin lies across the surface (on the far side of the tangent plane from g)
    p = h.org[ok].astype(np.float64) + h.t[ok, None].astype(np.float64) * d[ok]
    near = np.linalg.norm(p, axis=1) < 100      # eps = 1e-3 is above the rounding there
    assert np.all(np.sum((org[ok].astype(np.float64) - p) * g[ok], axis=1)[near] < 0)


def test_refraction_at_normal_incidence_goes_straight():
    """A ray along -n enters undeflected for every ior (t = eta w + (eta - 1) n = w)."""
    fmt = FPFormat(8, 23)
    h, mat = cases(fmt, 8, seed=23)
    n = len(h)
    h.dir[:] = [0.0, 0.0, -2.0]
    h.nf[:] = [0.0, 0.0, 1.0]
    h.nv[:] = [0.0, 0.0, 1.0]
    _, dirn, tir, _, _ = run_model(h, mat, fmt)
    assert not tir.any()
    assert np.array_equal(dirn, np.tile(np.float32([0, 0, -1]), (n, 1)))


def test_glass_render_refracts():
    """scenes/glass.toml at 24x18: every hit of an eye, reflection or refracted ray below the
    reflection depth on a transmitting material spawns exactly one refracted ray (depth + 1),
    and the glass changes the image against the same scene with the glass made opaque."""
    from model.render import render
    from model.scene import load_scene
    scene = load_scene(ROOT / "scenes" / "glass.toml")
    cfg = Config()
    res = render(scene, cfg, 24, 18)
    rays, hits = res.rays, res.hits
    assert res.stats["rays"]["refraction"] > 0
    transmit = np.array([m.transmit for m in scene.materials])
    kept = np.full(scene.n_scene_tris, -1, np.int64)
    kept[scene.tri_id] = np.arange(len(scene.tri_id))
    mat = np.where(hits.tri >= 0, scene.material[kept[np.maximum(hits.tri, 0)]], 0)
    parent = ((rays.kind != RayKind.SHADOW) & (hits.tri >= 0) & (transmit[mat] > 0) &
              (rays.depth < cfg.reflect_depth))
    refr = rays.kind == RayKind.REFRACTION
    assert refr.sum() == parent.sum()
    assert np.all(rays.depth[refr] >= 1) and np.all(rays.depth[refr] <= cfg.reflect_depth)
    # each eye ray's refracted descendants per depth: as many as its parents one level up
    for dep in range(1, cfg.reflect_depth + 1):
        a = np.bincount(rays.eye[refr & (rays.depth == dep)], minlength=len(res.colour) * 4)
        b = np.bincount(rays.eye[parent & (rays.depth == dep - 1)],
                        minlength=len(res.colour) * 4)
        assert np.array_equal(a, b)
    opaque = replace(scene, materials=[replace(m, transmit=0.0) for m in scene.materials])
    res0 = render(opaque, cfg, 24, 18)
    assert (res0.rays.kind == RayKind.REFRACTION).sum() == 0
    assert not np.array_equal(res.colour, res0.colour)


def test_transmit_keys_are_checked(tmp_path):
    from model.scene import load_scene
    from model.scene_toml import SceneError
    text = (ROOT / "scenes" / "glass.toml").read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace("reflect = 0.08", "reflect = 0.5"))
    with pytest.raises(SceneError, match="transmit"):
        load_scene(bad)
    bad.write_text(text.replace("ior = 1.5", "ior = 0.0"))
    with pytest.raises(SceneError, match="ior"):
        load_scene(bad)


@pytest.mark.parametrize("fmt,budget", [(FPFormat(8, 23), None), (FPFormat(5, 10), None),
                                        (FPFormat(8, 23), {"add": 3, "mul": 4})],
                         ids=["E8M23", "E5M10", "E8M23-shared"])
def test_refract_pipe_matches_model(fmt, budget):
    """``SecondaryPipe(refract=True)``: every output of 60 hits (random and edge cases, total
    internal reflection among them) at its exact cycle, bit for bit with the model, with 20 %
    input bubbles and 20 % stalls; alone and on a shared budget."""
    from tb.units.rgs import run_refract
    h, mat = cases(fmt, 60, seed=24)
    _, _, tir, _, _ = run_model(h, mat, fmt)
    assert tir.any() and (~tir).any()
    r = run_refract(h, mat["eta_in"], mat["eta_out"], fmt, budget=budget)
    assert r.mismatches == [], r.mismatches[:5]
    assert r.outputs == len(h)


def test_refract_pipe_latency():
    """The refraction adds 38 cycles after the shading normal at the default latencies
    (docs/rgs.md): 90 against 70, and leaves the datapath without it unchanged."""
    from rtl.rgs import SecondaryPipe
    fmt = FPFormat(8, 23)
    a, b = SecondaryPipe(fmt), SecondaryPipe(fmt, refract=True)
    for p in (a, b):
        p._MustUse__silence = True
    assert (a.latency, b.latency) == (70, 90)
    assert b.counts["mul"] - a.counts["mul"] == 13 and b.counts["add"] - a.counts["add"] == 14
    assert b.counts["sqrt"] - a.counts["sqrt"] == 1 and b.counts["div"] == a.counts["div"]


def test_chip_harness_refuses_transmitting_scenes():
    """The chip's slaves make no refracted rays: the chip harness refuses such a scene
    rather than report a frame that differs from the golden model's; the same scene with the
    glass made opaque is accepted."""
    from model.render import prepare
    from model.scene import load_scene
    from tb.harness.chip import frame_registers
    scene = load_scene(ROOT / "scenes" / "glass.toml")
    cfg = Config()
    prep = prepare(scene, cfg, cache_dir=None)
    with pytest.raises(ValueError, match="refracted"):
        frame_registers(cfg, prep.image, scene.camera, 8, 8, scene=scene)
    opaque = replace(scene, materials=[replace(m, transmit=0.0) for m in scene.materials])
    assert frame_registers(cfg, prep.image, scene.camera, 8, 8, scene=opaque)["n_lights"] == 3


def test_glass_render_against_float64_reference():
    """scenes/glass.toml at 40x29 against the precision study's float64 renderer
    (``model.reference.render64``, refraction in float64): close, and far closer than the
    same model render with the glass made opaque (so a wrong refraction would show)."""
    from model.reference import Reference, render64
    from model.render import render
    from model.scene import load_scene
    from saarcor.precision import image_error
    scene = load_scene(ROOT / "scenes" / "glass.toml")
    img64, _ = render64(Reference(scene), 40, 29)
    good = image_error(render(scene, Config(), 40, 29).image, img64)
    opaque = replace(scene, materials=[replace(m, transmit=0.0) for m in scene.materials])
    bad = image_error(render(opaque, Config(), 40, 29).image, img64)
    # measured: 39.4 dB, 4 of 1160 pixels off by more than one level (silhouettes, where a
    # rounding moves a refracted ray onto another triangle); opaque: 17.4 dB
    assert good["psnr_db"] >= 35 and good["share_off_gt_1_level"] < 0.01
    assert bad["psnr_db"] < good["psnr_db"] - 10
