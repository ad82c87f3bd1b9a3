"""The golden model's binary32 fast intersection equals the exact-operation reference."""
import numba
import numpy as np

from model.intersection import intersect, intersect32


@numba.njit(cache=True)
def run_both(tris, org, k, s):
    n = tris.shape[0]
    out = np.zeros((n, 2, 4), np.float32)
    for i in range(n):
        h, t, u, v = intersect(tris[i], org[i, 0], org[i, 1], org[i, 2], k[i, 0], k[i, 1],
                               k[i, 2], s[i, 0], s[i, 1], s[i, 2], 8, 23)
        out[i, 0] = (np.float32(h), t, u, v)
        h, t, u, v = intersect32(tris[i], org[i, 0], org[i, 1], org[i, 2], k[i, 0], k[i, 1],
                                 k[i, 2], s[i, 0], s[i, 1], s[i, 2])
        out[i, 1] = (np.float32(h), t, u, v)
    return out


def cases(rng, n, scale_exp):
    """Random rays/triangles at scale 2^scale_exp (tiny scales reach the underflow band)."""
    scale = 2.0 ** scale_exp
    tris = (rng.normal(size=(n, 9)) * scale).astype(np.float32)
    org = (rng.normal(size=(n, 3)) * scale).astype(np.float32)
    centre = tris.reshape(n, 3, 3).mean(axis=1)
    d = (centre - org + rng.normal(size=(n, 3)) * scale * 0.3).astype(np.float64)
    kz = np.argmax(np.abs(d), axis=1)
    kx = (kz + 1) % 3
    ky = (kx + 1) % 3
    dz = d[np.arange(n), kz]
    kx, ky = np.where(dz < 0, ky, kx), np.where(dz < 0, kx, ky)
    k = np.stack([kx, ky, kz], axis=1).astype(np.int64)
    s = np.stack([d[np.arange(n), kx] / dz, d[np.arange(n), ky] / dz, 1 / dz], axis=1)
    flush = lambda x: np.where(np.abs(x) < 2.0 ** -126, 0, x).astype(np.float32)  # noqa: E731
    return flush(tris), flush(org), k, flush(s)


def test_fast_binary32_intersection_is_bit_identical():
    rng = np.random.default_rng(5)
    total_hits = 0
    for scale_exp in (0, 10, -20, -40, -60, -63, -64, -66, 40, 60):
        tris, org, k, s = cases(rng, 40000, scale_exp)
        # some exact edge hits: the origin on the plane of an axis through a vertex
        tris[:500, 0] = org[:500, 0]
        out = run_both(tris, org, k, s)
        ref, fast = out[:, 0], out[:, 1]
        assert np.array_equal(ref.view(np.uint32), fast.view(np.uint32)), scale_exp
        total_hits += int(ref[:, 0].sum())
    assert total_hits > 10000
