"""The render's one-pass kernels against the staged ones, bit for bit: ``Shader.shade``
(``model.rgs.shade_batch``) against ``Shader.surface``, ``hit_colours``, ``shadow_rays`` and
``light_colours``; the trace kernel with the ray setup inside (``trace_all_setup``) against
``setup`` then ``trace``; the borrowed array views."""
import numpy as np
import pytest

from model.config import Config
from model.fp import FPFormat
from model.raygen import eye_rays, setup
from model.render import _shader, prepare
from model.rgs import hit_colours, light_colours
from model.rtc import trace
from model.scene import load_scene
from model.shading import frame_colour_registers

from .conftest import ROOT

CASES = [("office", FPFormat(8, 23), True), ("office", FPFormat(5, 10), True),
         ("office", FPFormat(8, 16), False), ("cornell", FPFormat(8, 23), True),
         ("game", FPFormat(6, 12), True)]


def same(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.fixture(scope="module", params=CASES, ids=lambda c: f"{c[0]}-{c[1]}-tex{int(c[2])}")
def frame(request):
    name, fmt, textures = request.param
    scene = load_scene(ROOT / "scenes" / f"{name}.toml")
    cfg = Config(fmt=fmt)
    prep = prepare(scene, cfg, cache_dir=None)
    rays = eye_rays(scene.camera, 48, 36, cfg)
    return scene, cfg, prep, rays, textures


def test_trace_with_setup_inside_matches_staged(frame):
    scene, cfg, prep, rays, _ = frame
    fused, c1 = trace(prep.image, rays, cfg)
    staged, c2 = trace(prep.image, rays, cfg, setup(rays, prep.image.bounds, cfg.fmt))
    assert (fused.tri >= 0).any()
    for f in ("tri", "t", "u", "v"):
        assert same(getattr(fused, f), getattr(staged, f)), f
    assert same(c1, c2)


@pytest.mark.parametrize("cull", [True, False])
def test_shade_matches_staged_shading(frame, cull):
    scene, cfg, prep, rays, textures = frame
    fmt = cfg.fmt
    E, M = fmt.em
    hits, _ = trace(prep.image, rays, cfg)
    hit = np.flatnonzero(hits.tri >= 0)
    shader = _shader(prep, scene, fmt, textures)
    col = frame_colour_registers(scene, fmt, 1)
    # weights of every kind a ray carries, zero and tiny ones among them
    weight = fmt.quantize(np.random.default_rng(1).choice(
        [1.0, 0.5, 0.3, 0.0, 2.0 ** -130, 0.9], len(rays))).astype(np.float32)
    sh = shader.shade(rays, hit, hits.tri, hits.t, hits.u, hits.v, weight, col,
                      cull_behind=cull)
    surf = shader.surface(rays, hit, hits.tri[hit], hits.t[hit], hits.u[hit], hits.v[hit])
    rec = shader.rec
    assert same(sh.p0, surf.p0) and same(sh.r, surf.r)
    assert np.array_equal(sh.mat, surf.mat)
    amb, wr, miss = hit_colours(surf.kd, rec["kr"][surf.mat], col["amb"], col["bg"],
                                weight[hit], E, M)
    assert same(sh.ambient, amb) and same(sh.wr, wr) and same(sh.miss, miss)
    for li, light in enumerate(scene.lights):
        srays, keep = shader.shadow_rays(rays, hit, surf, light, cull_behind=cull,
                                         light_index=li)
        s2, keep2 = shader.shaded_shadow_rays(rays, hit, sh, li)
        assert same(keep, keep2)
        for f in ("org", "dir", "tmax", "kind", "pixel", "pk_start", "anyhit", "eye", "depth",
                  "light"):
            assert same(getattr(srays, f), getattr(s2, f)), f
        lc = light_colours(srays.dir, surf.n[keep], surf.r[keep], surf.kd[keep],
                           rec["ks"][surf.mat[keep]], rec["shin"][surf.mat[keep]],
                           np.broadcast_to(col["lights"][li], (len(srays), 3)),
                           weight[hit[keep]], E, M)
        assert same(sh.light[li][keep], lc)
        assert not sh.light[li][~sh.cast[li]].any()


def test_borrowed_view_reads_and_writes_the_array():
    import numba

    from model.lanes import borrow

    @numba.njit
    def twice(a):
        b = borrow(a)
        for i in range(b.shape[0]):
            b[i] *= 2
        return b.sum()

    a = np.arange(10, dtype=np.float64)
    assert twice(a) == 90 and a[3] == 6


def test_lanes_intersection_matches_exact():
    """``model.intersection.intersect32_lanes`` (the lanes that share shear axes at once)
    resolved as ``test_triangle`` resolves it gives, lane by lane, the exact-operation
    ``intersect``'s outcome, at scales down to the underflow band; ``shared_axes`` finds the
    axes a mask's lanes share."""
    import numba

    from model.intersection import _intersect_exact32, intersect, intersect32_lanes, shared_axes

    from .test_intersection_model import cases

    @numba.njit(error_model="numpy")
    def run(tris, org, k, s):
        n = org.shape[0]
        out = np.zeros((tris.shape[0], n, 2, 4), np.float32)
        o_t = np.ascontiguousarray(org.T)
        s_t = np.ascontiguousarray(s.T)
        st = np.empty(n, np.int8)
        ht = np.empty(n, np.float32)
        hu = np.empty(n, np.float32)
        hv = np.empty(n, np.float32)
        for i in range(tris.shape[0]):
            g0 = 0
            while g0 < n:                   # each run of lanes with the same axes at once
                g1 = g0 + 1
                while g1 < n and (k[g1, 0] == k[g0, 0] and k[g1, 1] == k[g0, 1]
                                  and k[g1, 2] == k[g0, 2]):
                    g1 += 1
                intersect32_lanes(tris[i], g0, g1, k[g0, 0], k[g0, 1], k[g0, 2], o_t, s_t, st,
                                  ht, hu, hv)
                g0 = g1
            for l in range(n):
                h, t, u, v = intersect(tris[i], org[l, 0], org[l, 1], org[l, 2], k[l, 0],
                                       k[l, 1], k[l, 2], s[l, 0], s[l, 1], s[l, 2], 8, 23)
                out[i, l, 0] = (np.float32(h), t, u, v)
                if st[l] == 2:
                    h, t, u, v = _intersect_exact32(tris[i], org[l, 0], org[l, 1], org[l, 2],
                                                    k[l, 0], k[l, 1], k[l, 2], s[l, 0],
                                                    s[l, 1], s[l, 2])
                else:
                    h, t, u, v = st[l] == 1, ht[l], hu[l], hv[l]
                out[i, l, 1] = (np.float32(h), t, u, v)
        return out

    axes = numba.njit(lambda mask, lk: shared_axes(mask, lk))
    rng = np.random.default_rng(7)
    for scale_exp in (0, -40, -60, -62, -64, -70, 20):
        tris, org, k, s = cases(rng, 64 * 8, scale_exp)
        code = k[:, 0] | k[:, 1] << 2 | k[:, 2] << 4
        order = np.argsort(code[:64], kind="stable")        # lanes grouped by their axes
        org, k, s, code = org[:64][order], k[:64][order], s[:64][order], code[:64][order]
        assert len(set(code)) > 1
        first = np.uint64((1 << int((code == code[0]).sum())) - 1)
        assert axes(first, k) == code[0] and axes(np.uint64(2 ** 64 - 1), k) == -1
        out = run(tris[:8], org, k, s)
        hit = out[..., 0] == 1
        want, got = out[:, :, 0], out[:, :, 1]
        assert same(want[..., 0], got[..., 0])
        assert same(want[..., 1:][hit[..., 0]], got[..., 1:][hit[..., 0]])
