"""The projection test (``Config.int_test = "projection"``): its precomputed records and the
golden model against a float64 oracle on the vertices, the memory format, the whole model."""
import numba
import numpy as np
import pytest

from model.config import Config, ConfigError
from model.fp import FPFormat
from model.intersection_projection import intersect_projection, split_k
from model.layout import MemoryImage, projection_records


@numba.njit(cache=True)
def run_projection(rec, k, org, d, E, M):
    n = rec.shape[0]
    out = np.zeros((n, 4), np.float32)
    for i in range(n):
        h, t, u, v = intersect_projection(rec[i], k[i], org[i, 0], org[i, 1], org[i, 2],
                                          d[i, 0], d[i, 1], d[i, 2], E, M)
        out[i] = (np.float32(h), t, u, v)
    return out


def oracle(tris, org, d):
    """float64 on the vertices (Moller-Trumbore): t, and the weights of B (u) and C (v)."""
    t = np.asarray(tris, np.float64).reshape(-1, 3, 3)
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    o, d = np.asarray(org, np.float64), np.asarray(d, np.float64)
    e1, e2 = b - a, c - a
    p = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, p)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1 / det
        s = o - a
        u = np.einsum("ij,ij->i", s, p) * inv
        q = np.cross(s, e1)
        v = np.einsum("ij,ij->i", d, q) * inv
        tt = np.einsum("ij,ij->i", e2, q) * inv
    return tt, u, v


def cases(rng, n, scale=1.0):
    tris = (rng.normal(size=(n, 9)) * scale).astype(np.float32)
    org = (rng.normal(size=(n, 3)) * scale * 3).astype(np.float32)
    centre = tris.reshape(n, 3, 3).mean(axis=1)
    d = (centre - org + rng.normal(size=(n, 3)) * scale * 0.5).astype(np.float32)
    return tris, org, d


def test_records_give_the_barycentric_weights_of_b_and_c():
    """The rounded records, evaluated in float64 at points of the plane, give the weights of
    B and C and the plane equation (relative error ~ binary32 rounding)."""
    rng = np.random.default_rng(1)
    tris = rng.normal(size=(5000, 3, 3)).astype(np.float32)
    rec, k = projection_records(tris, FPFormat())
    r = rec.astype(np.float64)
    w = rng.uniform(-0.5, 1.5, size=(5000, 2))
    t = tris.astype(np.float64)
    p = t[:, 0] + w[:, :1] * (t[:, 1] - t[:, 0]) + w[:, 1:] * (t[:, 2] - t[:, 0])
    i = np.arange(5000)
    pk, pu, pv = p[i, k], p[i, (k + 1) % 3], p[i, (k + 2) % 3]
    lam = pu * r[:, 3] + pv * r[:, 4] + r[:, 5]
    mu = pu * r[:, 6] + pv * r[:, 7] + r[:, 8]
    plane = pk + r[:, 0] * pu + r[:, 1] * pv - r[:, 2]
    nrm = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    # k is the dominant axis of the normal, so |n_u|, |n_v| <= 1
    assert (np.abs(nrm[i, k]) >= np.abs(nrm).max(axis=1)).all()
    assert (np.abs(r[:, :2]) <= 1).all()
    good = np.abs(nrm[i, k]) > 1e-2          # well-conditioned triangles
    assert good.sum() > 4500
    assert np.abs(lam - w[:, 0])[good].max() < 1e-3
    assert np.abs(mu - w[:, 1])[good].max() < 1e-3
    assert np.abs(plane)[good].max() < 1e-4 * (1 + np.abs(p).max())


@pytest.mark.parametrize("fmt", [FPFormat(), FPFormat(8, 16)])
def test_model_agrees_with_float64_oracle(fmt):
    rng = np.random.default_rng(2)
    tris, org, d = cases(rng, 40000)
    tris, org, d = fmt.quantize(tris), fmt.quantize(org), fmt.quantize(d)
    rec, k = projection_records(tris, fmt)
    out = run_projection(rec, k.astype(np.int64), org, d, *fmt.em)
    hit = out[:, 0] > 0
    t, u, v = oracle(tris, org, d)
    ohit = (u >= 0) & (v >= 0) & (u + v <= 1) & np.isfinite(t)
    # away from the edges (in the weights) the verdicts agree
    margin = np.minimum(np.minimum(np.abs(u), np.abs(v)), np.abs(1 - u - v))
    clear = margin > 1e-3 * (1 if fmt.frac_bits == 23 else 2 ** 7)
    assert clear.sum() > 20000 and ohit[clear].sum() > 4000
    assert np.array_equal(hit[clear], ohit[clear])
    # the hits' t, u, v are close to the oracle's
    both = hit & ohit & clear
    tol = 2.0 ** -(fmt.frac_bits - 8)
    assert np.allclose(out[both, 1], t[both], rtol=tol, atol=tol)
    assert np.allclose(out[both, 2], u[both], atol=tol)
    assert np.allclose(out[both, 3], v[both], atol=tol)
    # a miss is (0, 0, 0)
    assert not out[~hit, 1:].any()


def test_edge_cases():
    fmt = FPFormat()
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], np.float32)
    tris = np.repeat(tri, 5, axis=0)
    tris[1] = [[0, 0, 0], [1, 1, 1], [2, 2, 2]]          # degenerate: collinear
    tris[2] = [[1, 2, 3], [1, 2, 3], [1, 2, 3]]          # degenerate: one point
    tris[3] = [[0, 0, 0], [0, 1, 0], [1, 0, 0]]          # the first, wound the other way
    tris[4] = [[0, 0, 0], [0, 0, 1], [0, 1, 0]]          # in the x = 0 plane (k = 0)
    rec, k = projection_records(tris, fmt)
    assert list(k) == [2, 0, 0, 2, 0]
    for i in (1, 2):                                     # the record that never hits
        assert rec[i, 5] == -1 and not np.delete(rec[i], 5).any()
    org = np.array([[0.25, 0.125, 1]] * 5, np.float32)
    org[4] = [1, 0.125, 0.25]
    org[1] = org[2] = [1, 2, 3 + 1]
    d = np.array([[0, 0, -1]] * 5, np.float32)
    d[4] = [-1, 0, 0]
    d[1] = d[2] = [0, 0, -1]                             # through the degenerate ones
    out = run_projection(rec, k.astype(np.int64), org, d, 8, 23)
    assert out[0].tolist() == [1, 1, 0.25, 0.125]        # u weights B = (1, 0, 0)
    assert out[3].tolist() == [1, 1, 0.125, 0.25]        # C = (1, 0, 0) now: v
    assert out[4].tolist() == [1, 1, 0.25, 0.125]        # B = (0, 0, 1): u = z
    assert out[1, 0] == out[2, 0] == 0
    # the edges and vertices of the first triangle are hits (weights exactly 0 or 1)
    for p, uv in (((0, 0), (0, 0)), ((1, 0), (1, 0)), ((0.5, 0), (0.5, 0)),
                  ((0.5, 0.5), (0.5, 0.5))):
        o = np.array([[p[0], p[1], 2]], np.float32)
        r = run_projection(rec[:1], k[:1].astype(np.int64), o, d[:1], 8, 23)[0]
        assert r.tolist() == [1, 2, *uv]
    # parallel to the plane: never a hit
    r = run_projection(rec[:1], k[:1].astype(np.int64), np.array([[0.2, 0.2, 0]], np.float32),
                       np.array([[1, 0, 0]], np.float32), 8, 23)[0]
    assert r[0] == 0


def test_config_rejects_a_bad_int_test():
    assert Config().int_test == "watertight"
    Config(int_test="projection")
    with pytest.raises(ConfigError, match="int_test='woop'.*watertight, projection"):
        Config(int_test="woop")


def test_memory_image_holds_records_k_and_id():
    """The record's 9 words with k in the spare exponent bits of n_u, n_v; the id as ever."""
    from model.kdtree import build_kdtree
    from model.layout import build_image
    rng = np.random.default_rng(3)
    tris = rng.normal(size=(50, 3, 3)).astype(np.float32)
    tris[7, 1] = tris[7, 0]                                       # degenerate
    cfg = Config(int_test="projection")
    ids = (rng.permutation(50) + 1000).astype(np.uint32)
    img = build_image(tris, build_kdtree(tris, cfg, cache_dir=None), cfg, tri_id=ids)
    back = MemoryImage.from_words(img.data)
    assert back.projection and not build_image(
        tris, build_kdtree(tris, Config(), cache_dir=None), Config()).projection
    rec, k = projection_records(tris, cfg.fmt)
    assert set(k.tolist()) == {0, 1, 2}
    words = back.triangles()[0].reshape(50, 9).copy()
    bits = words.view(np.uint32)
    assert np.array_equal((bits[:, 0] >> 30 & 1) | (bits[:, 1] >> 30 & 1) << 1, k)
    for j in range(50):
        assert split_k.py_func(words[j]) == k[j]
    assert np.array_equal(words.view(np.uint32), rec.view(np.uint32))
    assert np.array_equal(back.scene_ids(np.arange(50)), ids)


def test_whole_model_with_projection_agrees_with_embree(kd_cache):
    """The golden model's render (eye, shadow and reflection rays through the RTC model) with
    the projection test against Intel Embree on the vertices."""
    from model.scene import load_scene

    from .conftest import ROOT
    from .test_rtc_model import check_against_embree
    cfg = Config(reflect_depth=2, int_test="projection")
    rep, result = check_against_embree(load_scene(ROOT / "scenes" / "cornell.toml"), cfg,
                                       (48, 36), kd_cache)
    assert rep["both_hit"] > 1000


def test_projection_is_not_watertight_on_shared_edges():
    """Rays through shared edges and vertices of a closed icosphere (the stress bench's case,
    judged by the exact oracle): the watertight test lets none through the surface, the
    projection test some (its rounded records do not describe a shared edge identically);
    each of those hits the far side, so none is a plain leak."""
    from saarcor import stress
    mesh = stress.closed_meshes()["icosphere"]
    far = {}
    for test in ("watertight", "projection"):
        cfg = Config(int_test=test)
        case = stress.watertight_case(mesh, cfg, n_max=1000, exact=True)
        assert case.image.projection == (test == "projection")
        v, _ = stress.model_judge(case, cfg)
        assert v["leaks"] == 0 and v["ghosts"] == 0 and v["rays"] == 1000
        far[test] = v["other_tri_far"]
    assert far["watertight"] == 0 and 10 < far["projection"] < 200
