"""The RGS slave's golden model (``model/rgs/``) against two independent recomputations.

* NumPy-vectorized: the per-operation arrays ``FPFormat.add/mul/div/min/max`` (a different code
  path from the scalar kernels), written here the way ``model/raygen.py`` computed rays before
  the kernels existed, on whole frames and on many random and edge-case rays.
* Exact: ``tests/fp_exact.py``'s ``Fraction`` arithmetic on encodings, step by step in the
  documented order (``docs/rgs.md``), on edge cases.

Plus the sample-coordinate identity (``(2*s + 1) * 2**-1`` rounded once equals
``quantize(s + 0.5)``) over the whole 16-bit coordinate range in every format.
"""
from __future__ import annotations

from fractions import Fraction

import numba
import numpy as np
import pytest

from model.config import Config
from model.fp import FPFormat
from model.raygen import Rays, camera_registers, eye_rays, setup
from model.rgs import sample_coord
from tb.units.rgs import AXIS_BOX, axis_camera, edge_rays, oblique_camera
from tests.fp_exact import INF, NAN, ExactFormat

FORMATS = [FPFormat(8, 23), FPFormat(8, 14), FPFormat(6, 10), FPFormat(5, 10)]


# ----------------------------------------------------------------------------------------------
# the NumPy-vectorized recomputation
# ----------------------------------------------------------------------------------------------

def np_eye_rays(camera, width, height, cfg):
    fmt, n = cfg.fmt, cfg.oversampling
    sw, sh = width * n, height * n
    pos, corner, dx, dy = camera_registers(camera, width, height, cfg)
    tw, th = cfg.tile_w, cfg.tile_h
    ty, tx, ly, lx = np.meshgrid(np.arange(-(-sh // th)), np.arange(-(-sw // tw)),
                                 np.arange(th), np.arange(tw), indexing="ij")
    sx, sy = (tx * tw + lx).ravel(), (ty * th + ly).ravel()
    inside = (sx < sw) & (sy < sh)
    tile = (ty * (-(-sw // tw)) + tx).ravel()[inside]
    sx, sy = sx[inside], sy[inside]
    px, py = fmt.quantize(sx + 0.5), fmt.quantize(sy + 0.5)
    d = np.stack([fmt.add(fmt.add(corner[a], fmt.mul(px, dx[a])), fmt.mul(py, dy[a]))
                  for a in range(3)], axis=1)
    counts = np.bincount(tile, minlength=-(-sw // tw) * -(-sh // th))
    pk_start = np.concatenate([[0], np.cumsum(counts[counts > 0])])
    return d, (sy // n) * width + sx // n, pk_start, pos


@np.errstate(invalid="ignore")
def np_setup(org, dirn, tmax, bounds, fmt):
    """Inputs read as the hardware reads them (denormals flushed), then the steps vectorized."""
    d, o = fmt.flush(dirn), fmt.flush(org)
    tmax = fmt.flush(tmax)
    one = np.float32(1.0)
    inv = np.stack([fmt.div(one, d[:, a]) for a in range(3)], axis=1)
    kz = np.argmax(np.abs(d), axis=1)          # first of the largest; a NaN is the largest
    kx = (kz + 1) % 3
    ky = (kx + 1) % 3
    idx = np.arange(len(d))
    dz = d[idx, kz]
    swap = dz < 0
    kx, ky = np.where(swap, ky, kx), np.where(swap, kx, ky)
    s = np.stack([fmt.div(d[idx, kx], dz), fmt.div(d[idx, ky], dz), fmt.div(one, dz)], axis=1)
    lo, hi = (fmt.flush(np.asarray(b, np.float32)) for b in bounds)
    tnear = np.zeros(len(d), np.float32)
    tfar = tmax.copy()
    for a in range(3):
        t0 = fmt.mul(fmt.sub(lo[a], o[:, a]), inv[:, a])
        t1 = fmt.mul(fmt.sub(hi[a], o[:, a]), inv[:, a])
        flat = np.isnan(t0) | np.isnan(t1)
        t0 = np.where(flat, np.float32(-np.inf), t0)
        t1 = np.where(flat, np.float32(np.inf), t1)
        tnear = fmt.max(tnear, fmt.min(t0, t1))
        tfar = fmt.min(tfar, fmt.max(t0, t1))
    sign = (d.view(np.uint32) >> 31).astype(np.int64)
    octant = sign[:, 0] | sign[:, 1] << 1 | sign[:, 2] << 2
    return inv, np.stack([kx, ky, kz], axis=1), s, tnear, tfar, octant


def same(fmt, a, b) -> bool:
    """Bit-identical as format words (NaN canonical)."""
    return np.array_equal(fmt.to_bits(np.asarray(a, np.float32)),
                          fmt.to_bits(np.asarray(b, np.float32)))


def check_setup(rays, bounds, fmt):
    rs = setup(rays, bounds, fmt)
    inv, k, s, tnear, tfar, octant = np_setup(rays.org, rays.dir, rays.tmax, bounds, fmt)
    assert same(fmt, rs.inv, inv) and same(fmt, rs.s, s)
    assert np.array_equal(rs.k, k) and np.array_equal(rs.octant, octant)
    assert same(fmt, rs.tnear, tnear) and same(fmt, rs.tfar, tfar)
    return rs


@pytest.mark.parametrize("fmt", FORMATS, ids=str)
@pytest.mark.parametrize("n,tile,res", [(1, (8, 8), (15, 12)), (2, (8, 8), (15, 11)),
                                        (3, (4, 4), (7, 5)), (1, (8, 4), (64, 48))])
def test_eye_rays_match_vectorized(fmt, n, tile, res):
    cfg = Config(fmt=fmt, oversampling=n, tile_w=tile[0], tile_h=tile[1], trav_subunits=1)
    for cam in (axis_camera(), oblique_camera()):
        rays = eye_rays(cam, *res, cfg)
        d, pixel, pk_start, pos = np_eye_rays(cam, *res, cfg)
        assert same(fmt, rays.dir, d)
        assert np.array_equal(rays.pixel, pixel) and np.array_equal(rays.pk_start, pk_start)
        assert same(fmt, rays.org, np.broadcast_to(pos, d.shape))
        assert np.all(rays.tmax == np.inf) and not rays.anyhit.any()
        check_setup(rays, fmt.quantize(AXIS_BOX), fmt)


def test_axis_camera_makes_the_edge_cases():
    """The axis camera gives exact zero direction components (infinite reciprocals), ±0
    products, and with :data:`tb.units.rgs.AXIS_BOX` (lo.x on the camera's x) the flat rule: checked
    here, so the tests using them do cover those paths."""
    fmt = FPFormat(8, 23)
    cfg = Config(fmt=fmt)
    rays = eye_rays(axis_camera(), 15, 12, cfg)
    _, _, dx, dy = camera_registers(axis_camera(), 15, 12, cfg)
    assert dx[2] == 0 and dy[2] == 0 and np.signbit(dy[2])       # px*dx_z = +0, py*dy_z = -0
    zero = rays.dir[:, 0] == 0
    assert zero.sum() == 12
    bounds = fmt.quantize(AXIS_BOX)
    rs = setup(rays, bounds, fmt)
    assert np.all(np.isinf(rs.inv[zero, 0]))
    # the x slab of these rays is (lo.x - o.x) * inf = 0 * inf = NaN: the flat rule ignores it,
    # and the interval is the z slab's [2.5, 5] (a NaN let through would make tnear +inf)
    assert np.all(rs.tnear[zero] == 2.5) and np.all(rs.tfar[zero] == 5)


@pytest.mark.parametrize("fmt", FORMATS + [FPFormat(4, 3)], ids=str)
def test_setup_matches_vectorized_on_edge_and_random_rays(fmt):
    rng = np.random.default_rng(7)
    bounds = fmt.quantize(np.array([[-1.5, -1.0, -2.0], [1.0, 2.0, 0.5]]))
    edge = edge_rays(fmt, bounds, n_random=2000, seed=3)
    check_setup(edge, bounds, fmt)
    # NaN and denormal components, NaN and -0 tmax: the axis choice, the swap and the flush
    n = 400
    dirn = rng.normal(size=(n, 3)).astype(np.float32)
    pick = rng.integers(0, 6, size=(n, 3))
    dirn[pick == 0] = np.nan
    dirn[pick == 1] = np.float32(1e-40) * np.sign(rng.normal(size=(pick == 1).sum()))
    dirn[pick == 2] = -0.0
    org = rng.normal(size=(n, 3)).astype(np.float32)
    org[:, 0] = np.where(rng.random(n) < 0.3, bounds[0, 0], org[:, 0])
    tmax = rng.choice(np.array([np.inf, 1.0, -0.0, np.nan, 1e-40], np.float32), n)
    rays = Rays.from_arrays(fmt.quantize(org), np.where(pick == 1, dirn, fmt.quantize(dirn)),
                            tmax)
    check_setup(rays, bounds, fmt)


# ----------------------------------------------------------------------------------------------
# the exact recomputation (Fraction arithmetic on encodings)
# ----------------------------------------------------------------------------------------------

def _mag_key(X, b):
    kind, _, v = X.decode(b)
    return (2, 0) if kind == NAN else (1, 0) if kind == INF else (0, v)


def exact_eye_dir(X, sx, sy, corner, dx, dy):
    px = X.round(0, Fraction(2 * sx + 1, 2))
    py = X.round(0, Fraction(2 * sy + 1, 2))
    return [X.add(X.add(corner[a], X.mul(px, dx[a])), X.mul(py, dy[a])) for a in range(3)]


def exact_setup(X, o, d, tmax, lo, hi):
    """One ray, encodings in and out: inv, k, s, tnear, tfar, octant."""
    one = X.round(0, Fraction(1))
    inv = [X.div(one, d[a]) for a in range(3)]
    keys = [_mag_key(X, x) for x in d]
    kz = max(range(3), key=lambda a: (keys[a], -a))         # first of the largest
    kx, ky = (kz + 1) % 3, (kz + 2) % 3
    if X.lt(d[kz], X.zero(0)):
        kx, ky = ky, kx
    s = [X.div(d[kx], d[kz]), X.div(d[ky], d[kz]), inv[kz]]
    tnear, tfar = X.zero(0), X.canonical(tmax)
    for a in range(3):
        t0 = X.mul(X.sub(lo[a], o[a]), inv[a])
        t1 = X.mul(X.sub(hi[a], o[a]), inv[a])
        if X.decode(t0)[0] == NAN or X.decode(t1)[0] == NAN:
            t0, t1 = X.inf(1), X.inf(0)
        tnear = X.max(tnear, X.min(t0, t1))
        tfar = X.min(tfar, X.max(t0, t1))
    sign = [(x >> (X.E + X.M)) & 1 for x in d]
    return inv, [kx, ky, kz], s, tnear, tfar, sign[0] | sign[1] << 1 | sign[2] << 2


@pytest.mark.parametrize("fmt", [FPFormat(8, 23), FPFormat(6, 10), FPFormat(4, 3)], ids=str)
def test_setup_matches_exact_arithmetic(fmt):
    X = ExactFormat(fmt.exp_bits, fmt.frac_bits)
    bounds = fmt.quantize(np.array([[-1.5, -1.0, -2.0], [1.0, 2.0, 0.5]]))
    rays = edge_rays(fmt, bounds, n_random=100, seed=11)
    rs = setup(rays, bounds, fmt)
    bits = lambda x: [int(v) for v in fmt.to_bits(np.asarray(x, np.float32))]
    lo, hi = bits(bounds[0]), bits(bounds[1])
    for r in range(len(rays)):
        inv, k, s, tnear, tfar, octant = exact_setup(X, bits(rays.org[r]), bits(rays.dir[r]),
                                                     bits([rays.tmax[r]])[0], lo, hi)
        got = (bits(rs.inv[r]), list(rs.k[r]), bits(rs.s[r]), bits([rs.tnear[r]])[0],
               bits([rs.tfar[r]])[0], int(rs.octant[r]))
        assert got == (inv, k, s, tnear, tfar, octant), (r, rays.org[r], rays.dir[r])


@pytest.mark.parametrize("fmt", [FPFormat(8, 23), FPFormat(6, 10), FPFormat(5, 4)], ids=str)
@pytest.mark.parametrize("n", [1, 2])
def test_eye_rays_match_exact_arithmetic(fmt, n):
    X = ExactFormat(fmt.exp_bits, fmt.frac_bits)
    cfg = Config(fmt=fmt, oversampling=n, tile_w=4, tile_h=4, trav_subunits=1)
    for cam in (axis_camera(), oblique_camera()):
        w, h = 15 if n == 1 else 7, 6
        rays = eye_rays(cam, w, h, cfg)
        _, corner, dx, dy = (
            [int(v) for v in fmt.to_bits(x)] for x in camera_registers(cam, w, h, cfg))
        sw, tw, th = w * n, cfg.tile_w, cfg.tile_h
        tiles_x = -(-sw // tw)
        r = 0
        for p in range(rays.n_packets):
            tx, ty = p % tiles_x, p // tiles_x
            for sy in range(ty * th, min(ty * th + th, h * n)):
                for sx in range(tx * tw, min(tx * tw + tw, sw)):
                    want = exact_eye_dir(X, sx, sy, corner, dx, dy)
                    assert [int(v) for v in fmt.to_bits(rays.dir[r])] == want, (sx, sy)
                    assert rays.pixel[r] == (sy // n) * w + sx // n
                    r += 1
        assert r == len(rays)


@numba.njit(cache=True)
def _sample_coords(n, E, M):
    out = np.empty(n, np.float32)
    for s in range(n):
        out[s] = sample_coord(s, E, M)
    return out


def test_sample_coordinate_identity_every_format():
    """``sample``: (2*s + 1) * 2**-1 rounded once (the kernel; ``from_fixed(2*s + 1, 1)``, the
    RTL converter's definition) equals ``quantize(s + 0.5)`` for every 16-bit s in every
    format E2..E8 x M1..M23 (rounding, overflow to inf, and at E2 the flush of 0.5)."""
    s = np.arange(1 << 16)
    for E in range(2, 9):
        for M in range(1, 24):
            fmt = FPFormat(E, M)
            want = fmt.to_bits(fmt.quantize(s + 0.5))
            assert np.array_equal(fmt.to_bits(_sample_coords(s.size, E, M)), want), fmt
            assert np.array_equal(fmt.to_bits(fmt.from_fixed(2 * s + 1, 1)), want), fmt


# ----------------------------------------------------------------------------------------------
# secondary rays against the NumPy-vectorized recomputation and float64
# ----------------------------------------------------------------------------------------------

def np_secondary(h, fmt):
    """The documented steps (``docs/rgs.md``) with ``FPFormat``'s array operations."""
    add, sub, mul, div, sqrt = fmt.add, fmt.sub, fmt.mul, fmt.div, fmt.sqrt

    def dot(a, b):
        return add(add(mul(a[:, 0], b[:, 0]), mul(a[:, 1], b[:, 1])), mul(a[:, 2], b[:, 2]))

    def unit(x):
        q = dot(x, x)
        r = div(np.float32(1), sqrt(q))
        return np.stack([mul(x[:, a], r) for a in range(3)], axis=1), q
    d, o = h.dir, h.org
    g = np.where((dot(h.nf, d) > 0)[:, None], -h.nf, h.nf)
    w, _ = unit(d)
    p = np.stack([add(o[:, a], mul(h.t, d[:, a])) for a in range(3)], axis=1)
    p0 = np.stack([sub(add(p[:, a], mul(h.eps, g[:, a])), mul(h.eps, w[:, a]))
                   for a in range(3)], axis=1)
    b = sub(sub(np.float32(1), h.u), h.v)
    s = np.stack([add(add(mul(b, h.nv[:, 0, a]), mul(h.u, h.nv[:, 1, a])), mul(h.v, h.nv[:, 2, a]))
                  for a in range(3)], axis=1)
    n, q = unit(s)
    n = np.where((q == 0)[:, None], g, n)
    n = np.where((dot(n, g) < 0)[:, None], -n, n)
    k = mul(np.float32(2), dot(d, n))
    r = np.stack([sub(d[:, a], mul(k, n[:, a])) for a in range(3)], axis=1)
    return p0, g, n, r


@pytest.mark.parametrize("fmt", FORMATS, ids=str)
def test_secondary_matches_vectorized(fmt):
    from tb.units.rgs import secondary_cases
    h = secondary_cases(fmt, 3000, seed=11)
    got = h.secondary(fmt)
    for name, a, b in zip(("p0", "g", "n", "r"), got, np_secondary(h, fmt)):
        assert same(fmt, a, b), name


def test_secondary_geometry_float64():
    """What the steps are for, checked in float64 at binary32: the origin lies on g's side of
    the hit point's tangent plane and before it along the ray; the shading normal has unit
    length and lies on g's side; the reflection keeps |d| and mirrors d about n."""
    from tb.units.rgs import secondary_cases
    fmt = FPFormat(8, 23)
    h = secondary_cases(fmt, 2000, seed=12)
    p0, g, n, r = (x.astype(np.float64) for x in h.secondary(fmt))
    d = h.dir.astype(np.float64)
    p = h.org + h.t[:, None].astype(np.float64) * d
    off = p0 - p
    ok = np.linalg.norm(p, axis=1) < 100            # eps = 1e-3 is above the rounding there
    assert np.all(np.sum(off * g, axis=1)[ok] > 0)
    assert np.all(np.sum(off * d, axis=1)[ok] < 0)
    # against float64 geometry, not the RTL (the RTL's secondary rays are compared bit for
    # bit in tests/test_rgs_rtl.py, this model with its vectorized copy above): the bounds are
    # the format's rounding, a few ulps of 1 (eps = 2**-M; measured: 1.2 for |n|, 2.0 for r)
    eps = 2.0 ** -fmt.frac_bits
    assert np.all(np.abs(np.linalg.norm(n, axis=1) - 1) <= 4 * eps)
    assert np.all(np.sum(n * g, axis=1) >= 0)
    want = d - 2 * np.sum(d * n, axis=1, keepdims=True) * n
    scale = np.linalg.norm(d, axis=1, keepdims=True)
    assert np.all(np.abs(r - want) <= 8 * eps * scale)


# ----------------------------------------------------------------------------------------------
# colour
# ----------------------------------------------------------------------------------------------

def np_fixed(x: np.ndarray, fmt: FPFormat) -> np.ndarray:
    """``to_fixed`` in float64 NumPy: floor(x * 2**16) on 0 < x < 256, 0 below (and NaN),
    2**24 - 1 from 256 up."""
    from model.rgs import FIX_BITS, FIX_FRAC
    x = fmt.flush(np.asarray(x, np.float32)).astype(np.float64)
    out = np.floor(np.where(x > 0, x, 0.0) * 2.0 ** FIX_FRAC)
    return np.where(x >= 2.0 ** (FIX_BITS - FIX_FRAC), 2 ** FIX_BITS - 1, out).astype(np.int64)


def np_colour(c, fmt: FPFormat):
    """The colour steps (``model.rgs.light_colour``, ``hit_colour``) with FPFormat's
    array operations: (light (N, 3), ambient (N, 3), wr (N,), miss (N, 3)) as fixed-point."""
    add, mul, div, sqrt, mx = fmt.add, fmt.mul, fmt.div, fmt.sqrt, fmt.max

    def dot(a, b):
        return add(add(mul(a[:, 0], b[:, 0]), mul(a[:, 1], b[:, 1])), mul(a[:, 2], b[:, 2]))
    one = np.ones(len(c), np.float32)
    zero = np.zeros(len(c), np.float32)
    il = div(one, sqrt(dot(c.ld, c.ld)))
    ir = div(one, sqrt(dot(c.r, c.r)))
    ndl = mx(mul(dot(c.n, c.ld), il), zero)
    rdl = mx(mul(mul(dot(c.r, c.ld), il), ir), zero)
    acc, p = one, rdl
    for i in range(10):
        acc = np.where((c.shin >> i) & 1 == 1, mul(acc, p), acc)
        p = mul(p, p)
    light = np.stack([mul(add(mul(c.kd[:, k], ndl), mul(c.ks[:, k], acc)),
                          mul(c.lc[:, k], c.wt)) for k in range(3)], axis=1)
    amb = np.full(len(c), c.amb, np.float32)
    wr = mul(c.wt, c.kr)
    ambient = np.stack([mul(mul(c.kd[:, k], amb), c.wt) for k in range(3)], axis=1)
    miss = np.stack([mul(np.full(len(c), c.bg[k], np.float32), wr) for k in range(3)], axis=1)
    return np_fixed(light, fmt), np_fixed(ambient, fmt), wr, np_fixed(miss, fmt)


@pytest.mark.parametrize("fmt", FORMATS, ids=str)
def test_colour_matches_vectorized(fmt):
    from model.rgs import hit_colours, light_colours
    from tb.units.rgs import colour_cases
    c = colour_cases(fmt, 3000, seed=21)
    E, M = fmt.em
    light = light_colours(c.ld, c.n, c.r, c.kd, c.ks, c.shin, c.lc, c.wt, E, M)
    ambient, wr, miss = hit_colours(c.kd, c.kr, np.float32(c.amb), c.bg, c.wt, E, M)
    w_light, w_amb, w_wr, w_miss = np_colour(c, fmt)
    assert np.array_equal(light, w_light)
    assert np.array_equal(ambient, w_amb)
    assert same(fmt, wr, w_wr)
    assert np.array_equal(miss, w_miss)
    # the cases reach what they are for: saturation, zero light, full and empty highlights
    assert (light == 2 ** 24 - 1).any() and (light == 0).any() and (miss > 0).any()


def test_to_fixed_edges():
    from model.rgs import FIX_MAX, to_fixed_array
    x = np.array([np.nan, -0.0, 0.0, -1.0, 1e-40, 2.0 ** -16, 2.0 ** -17, 1.0,
                  256.0 - 2.0 ** -15, 256.0, np.inf, -np.inf, 3.0 * 2.0 ** -17], np.float32)
    want = [0, 0, 0, 0, 0, 1, 0, 1 << 16, FIX_MAX - 1, FIX_MAX, FIX_MAX, 0, 1]
    assert to_fixed_array(x, 8).tolist() == want


def test_spec_pow_exact_powers():
    """x ** k by squaring on values whose powers are exact: 0.5 ** k = 2 ** -k while it is a
    normal binary32 number (k <= 126), then 0 (flushed); 1 ** k = 1; x ** 0 = 1."""
    from model.rgs import spec_pow
    fn = numba.njit(lambda x, k: spec_pow(x, k, 8, 23))
    for k in (0, 1, 2, 3, 100, 126, 127, 1023):
        assert fn(np.float32(0.5), k) == (np.float32(2.0 ** -k) if k <= 126 else 0.0)
        assert fn(np.float32(1.0), k) == 1.0
    assert fn(np.float32(0.3), 0) == 1.0


def test_render_colour_is_the_sum_of_its_contributions():
    """The render's pixels against a float64 recomputation of the same Phong terms on the same
    rays is the precision study's job; here: textures off changes only textured hits' pixels,
    and the fixed-point sums are what the image shows."""
    from model.render import render
    from model.scene import load_scene
    from pathlib import Path
    scene = load_scene(Path(__file__).resolve().parents[1] / "scenes" / "cornell.toml")
    cfg = Config()
    a = render(scene, cfg, 16, 12)
    b = render(scene, cfg, 16, 12, textures=False)
    assert np.array_equal(a.image.reshape(-1, 3), (a.colour / 2.0 ** 16).astype(np.float32))
    eye = a.rays.kind == 0
    tri = a.hits.tri[eye]
    textured = np.array([scene.materials[scene.material[t]].texture is not None if t >= 0
                         else False for t in tri])
    differ = np.any(a.colour != b.colour, axis=1)
    assert differ.any()
    assert not differ[a.rays.pixel[eye][~textured]].all()


# ----------------------------------------------------------------------------------------------
# texture: model.rgs.texture_kd against FPFormat array operations and exact integers
# ----------------------------------------------------------------------------------------------

def np_texture_kd(c, fmt):
    """The texture steps of ``model.rgs.texture_kd``'s docstring, recomputed with the array
    operations and Python's exact integers and fractions."""
    add, sub, mul = fmt.add, fmt.sub, fmt.mul
    f = fmt.flush
    u, v, uv = f(c.u), f(c.v), f(c.uv)
    b = sub(sub(np.ones_like(u), u), v)

    def coord(k):
        return add(add(mul(b, uv[:, k]), mul(u, uv[:, 2 + k])), mul(v, uv[:, 4 + k]))

    def wrap(s):
        out = []
        for x in s.tolist():
            if x != x or x in (np.inf, -np.inf):
                out.append(0)
            else:
                out.append(int(np.floor(Fraction(x) * 2 ** 24)) % 2 ** 24)
        return out

    def pos(fs, size):
        x = (fs * size) // 2 ** 16 - 128
        i0, w = x // 256, x % 256
        return i0 % size, (i0 + 1) % size, w

    ss, tt = wrap(coord(0)), wrap(coord(1))
    out = c.kd.copy()
    scale = fmt.quantize(256 / 255)
    for i in range(len(c)):
        if c.tex[i] < 0:
            continue
        tw, th = int(c.tw[i]), int(c.th[i])
        x0, x1, wx = pos(ss[i], tw)
        y0, y1, wy = pos(2 ** 24 - tt[i], th)
        at = lambda x, y: int(c.texels[c.tex[i] + y * tw + x])  # noqa: E731
        for ch in range(3):
            g = lambda x, y: (at(x, y) >> (8 * ch)) & 255  # noqa: E731
            val = ((g(x0, y0) * (256 - wx) + g(x1, y0) * wx) * (256 - wy)
                   + (g(x0, y1) * (256 - wx) + g(x1, y1) * wx) * wy)
            tex = mul(fmt.from_fixed(np.array([val]), 24).astype(np.float32),
                      np.array([scale], np.float32))
            out[i, ch] = mul(f(c.kd[i:i + 1, ch]), tex)[0]
    return out


@pytest.mark.parametrize("fmt", FORMATS, ids=str)
def test_texture_matches_vectorized(fmt):
    from model.rgs import texture_kd
    from tb.units.rgs import texture_cases
    c = texture_cases(fmt, 1500, seed=23)
    got = texture_kd(c.kd, c.u, c.v, c.uv, c.tex, c.tw, c.th, c.texels, *fmt.em)
    want = np_texture_kd(c, fmt)
    assert same(fmt, got, want)
    # the cases reach what they are for: black and white texels, untouched kd
    ratio = got[c.tex >= 0] / np.maximum(c.kd[c.tex >= 0], 1e-30)
    assert (got[c.tex >= 0] == 0).any() and (np.abs(ratio - 1) < 1e-2).any()
    assert np.array_equal(got[c.tex < 0], c.kd[c.tex < 0])


def test_texture_filter_is_bilinear():
    """On texel centres the filter returns the texel; halfway between two texels their mean;
    a negative coordinate wraps (-0.25 is 0.75: the last texel's centre) (binary32)."""
    from model.rgs import texture_kd
    fmt = FPFormat(8, 23)
    texels = np.array([[10, 20, 30, 255], [50, 60, 70, 255], [90, 100, 110, 255],
                       [130, 140, 150, 255]], np.uint8).view("<u4").reshape(-1)  # 2 x 2
    # u = v = 0: the coordinate is vertex A's
    s = np.array([0.25, 0.75, 0.5, -0.25, 0.25], np.float32)
    t = np.array([0.75, 0.75, 0.75, 0.75, 0.25], np.float32)  # t = 0.75: the top row
    n = len(s)
    uv = np.zeros((n, 6), np.float32)
    uv[:, 0], uv[:, 1] = s, t
    kd = np.ones((n, 3), np.float32)
    z = np.zeros(n, np.float32)
    got = texture_kd(kd, z, z, uv, np.zeros(n, np.int64), np.full(n, 2), np.full(n, 2),
                     texels, *fmt.em)
    # the filtered channel is the texel (the mean) times 2**16 exactly, then the scale step
    texel = np.array([[10, 20, 30], [50, 60, 70], [30, 40, 50], [50, 60, 70], [90, 100, 110]])
    want = fmt.mul(fmt.from_fixed(texel * 2 ** 16, 24).astype(np.float32),
                   np.float32(fmt.quantize(256 / 255)))
    assert same(fmt, got, want)
