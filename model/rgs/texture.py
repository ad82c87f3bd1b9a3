"""The RGS slave's texture unit (golden model): a textured hit's kd times its bilinearly
filtered texel colour (:func:`texture_kd`, the RTL's ``rtl/rgs/texture.py`` ``Texture``), bit
for bit."""
from __future__ import annotations

import numba
import numpy as np

from ..fp import fadd, fmul, flush_in, fsub, round_exact
from .common import _INF, _ONE

__all__ = ["UV_FRAC", "TEX_FRAC", "TEX_ONE", "TEX_SCALE", "tex_coord", "wrap_coord", "tex_pos",
           "texture_kd", "tex_scale", "texture_one"]

UV_FRAC = 24            # fraction bits of a wrapped texture coordinate
TEX_FRAC = 8            # fraction bits of a bilinear weight
TEX_ONE = 1 << TEX_FRAC
TEX_SCALE = 256.0 / 255.0   # c * 2**-24 * 256/255: a filtered channel 0..255*2**16 as 0..1


@numba.njit(cache=True, error_model="numpy")
def tex_coord(u, v, s0, s1, s2, E, M):
    """``tex_st``: a texture coordinate at the hit, (b*s0 + u*s1) + v*s2 with
    b = (1 - u) - v (the barycentric weights of ``normal``)."""
    b = fsub(fsub(_ONE, u, E, M), v, E, M)
    return fadd(fadd(fmul(b, s0, E, M), fmul(u, s1, E, M), E, M), fmul(v, s2, E, M), E, M)


@numba.njit(cache=True, error_model="numpy")
def wrap_coord(s, E):
    """``wrap``: floor(s * 2**UV_FRAC) mod 2**UV_FRAC, the fraction of s (s - floor(s), the
    texture repeats) in UV_FRAC-bit fixed point; 0 for a NaN, an infinity or a zero
    (denormals read as zero). Exact: every step is exact in float64."""
    s = flush_in(s, E)
    if s != s or s == _INF or s == -_INF:
        return np.int64(0)
    one = np.float64(1 << UV_FRAC)
    f = np.floor(np.float64(s) * one)
    return np.int64(f - np.floor(f / one) * one)


@numba.njit(cache=True)
def tex_pos(fs, size):
    """``pos``: the two texels and the weight of the second along one axis for the wrapped
    coordinate ``fs`` (UV_FRAC bits) on a texture ``size`` texels long: X = fs * size - 1/2 in
    TEX_FRAC-bit fixed point (the product's low bits truncated), i0 = floor(X), i1 = i0 + 1,
    each taken mod ``size`` (i0 >= -1, i1 <= size); weight X - i0. Returns (i0, i1, weight)."""
    x = ((fs * size) >> (UV_FRAC - TEX_FRAC)) - (TEX_ONE >> 1)
    i0 = x >> TEX_FRAC
    f = x & (TEX_ONE - 1)
    i1 = i0 + 1
    if i0 < 0:
        i0 += size
    if i1 >= size:
        i1 -= size
    return i0, i1, f


@numba.njit(cache=True, error_model="numpy")
def texture_kd(kd, u, v, uv, tex, tw, th, texels, E, M):
    """The diffuse constants of textured hits: ``kd`` (N, 3) the records' kd, ``u``, ``v``
    (N,) the hits, ``uv`` (N, 6) the triangles' texture coordinates (s0, t0, s1, t1, s2, t2,
    format values), ``tex`` (N,) the first texel's index in ``texels`` (-1: not textured: kd
    unchanged), ``tw``, ``th`` (N,) the texture's size, ``texels`` the textures' RGBA8 words
    (R in bits 0..7), each texture row by row. Steps (the RTL's ``Texture``):

    * ``tex_st``: s, t = :func:`tex_coord`; ``wrap``: fs = wrap(s), ft = 2**UV_FRAC - wrap(t)
      (image rows run down, t up);
    * ``pos``: (x0, x1, wx) = :func:`tex_pos` (fs, tw), (y0, y1, wy) = tex_pos(ft, th);
    * ``fetch``: the texels T(x, y) = texels[tex + y*tw + x] at (x0, y0), (x1, y0), (x0, y1),
      (x1, y1);
    * ``filter``, per channel c (an exact integer, 0..255 * 2**16):
      ((T00 * (256 - wx) + T10 * wx) * (256 - wy)) + (T01 * (256 - wx) + T11 * wx) * wy;
    * ``scale``: tex = from_fixed(c, 24) * fmt(256/255); ``kd``: kd[c] * tex.

    Returns (N, 3) float32."""
    N = kd.shape[0]
    out = np.empty((N, 3), np.float32)
    scale = tex_scale(E, M)
    for i in range(N):
        out[i, 0], out[i, 1], out[i, 2] = texture_one(
            kd[i, 0], kd[i, 1], kd[i, 2], u[i], v[i], uv, i, tex[i], tw[i], th[i], texels,
            scale, E, M)
    return out


@numba.njit(cache=True, error_model="numpy")
def tex_scale(E, M):
    """``scale``'s constant: 256/255 in the format."""
    return round_exact(np.float64(TEX_SCALE), E, M)


@numba.njit(cache=True, error_model="numpy")
def texture_one(kd0, kd1, kd2, u, v, uv, j, tex, tw, th, texels, scale, E, M):
    """:func:`texture_kd` of one hit (``uv[j]`` its triangle's texture coordinates,
    ``scale`` = :func:`tex_scale`): its 3 channels (``kd`` unchanged if ``tex < 0``)."""
    if tex < 0:
        return kd0, kd1, kd2
    uu = flush_in(u, E)
    vv = flush_in(v, E)
    s = tex_coord(uu, vv, flush_in(uv[j, 0], E), flush_in(uv[j, 2], E),
                  flush_in(uv[j, 4], E), E, M)
    t = tex_coord(uu, vv, flush_in(uv[j, 1], E), flush_in(uv[j, 3], E),
                  flush_in(uv[j, 5], E), E, M)
    x0, x1, wx = tex_pos(wrap_coord(s, E), np.int64(tw))
    y0, y1, wy = tex_pos((1 << UV_FRAC) - wrap_coord(t, E), np.int64(th))
    r0 = tex + y0 * tw
    r1 = tex + y1 * tw
    t00, t10 = np.int64(texels[r0 + x0]), np.int64(texels[r0 + x1])
    t01, t11 = np.int64(texels[r1 + x0]), np.int64(texels[r1 + x1])
    return (_texel_channel(kd0, t00, t10, t01, t11, wx, wy, 0, scale, E, M),
            _texel_channel(kd1, t00, t10, t01, t11, wx, wy, 8, scale, E, M),
            _texel_channel(kd2, t00, t10, t01, t11, wx, wy, 16, scale, E, M))


@numba.njit(cache=True, error_model="numpy")
def _texel_channel(kd, t00, t10, t01, t11, wx, wy, sh, scale, E, M):
    """``filter``, ``scale`` and ``kd`` of one channel (bits ``sh`` .. ``sh + 7`` of a texel)."""
    a00, a10 = (t00 >> sh) & 255, (t10 >> sh) & 255
    a01, a11 = (t01 >> sh) & 255, (t11 >> sh) & 255
    f = ((a00 * (TEX_ONE - wx) + a10 * wx) * (TEX_ONE - wy)
         + (a01 * (TEX_ONE - wx) + a11 * wx) * wy)
    val = fmul(round_exact(np.float64(f) * 2.0 ** -24, E, M), scale, E, M)
    return fmul(flush_in(kd, E), val, E, M)
