"""Shading (the RGS slave, golden model): Phong-like with one bilinearly filtered texture.

Colour arithmetic is plain float32 NumPy (it only makes the picture). Everything that becomes a
ray — hit points, shadow and reflection rays — is computed with the hardware format's
operations, so the RTL traces exactly the rays the model traces.

Secondary rays leave the surface from ``p' = (p + eps*n) - eps*w`` (n the geometric normal
turned to the side the ray came from, w the unit incoming direction, ``eps = 1e-4 x`` the scene
box diagonal): away from the surface and back along the incoming ray, so they neither hit their
own triangle nor start on a neighbouring wall at a corner. A light behind the surface (as seen from the ray) casts no ray: the point is unlit.
"""
from __future__ import annotations

import numpy as np

from .fp import FPFormat
from .raygen import REFLECTION, SHADOW, Rays

AMBIENT = np.float32(0.08)


def dot3(fmt: FPFormat, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(a.x*b.x + a.y*b.y) + a.z*b.z in the format."""
    return fmt.add(fmt.add(fmt.mul(a[:, 0], b[:, 0]), fmt.mul(a[:, 1], b[:, 1])),
                   fmt.mul(a[:, 2], b[:, 2]))


def axpy(fmt: FPFormat, s: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """y + s*x per component in the format (s per ray)."""
    return np.stack([fmt.add(y[:, a], fmt.mul(s, x[:, a])) for a in range(3)], axis=1)


def bilinear(tex: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinearly filtered, wrapping texture lookup; tex (H, W, 3) uint8 -> (N, 3) float32 0..1."""
    h, w = tex.shape[:2]
    x = (uv[:, 0] % 1.0) * w - 0.5
    y = (1.0 - uv[:, 1] % 1.0) * h - 0.5
    x0 = np.floor(x).astype(np.int64)
    y0 = np.floor(y).astype(np.int64)
    fx = (x - x0)[:, None].astype(np.float32)
    fy = (y - y0)[:, None].astype(np.float32)
    t = tex.astype(np.float32) / 255.0

    def at(yy, xx):
        return t[yy % h, xx % w]
    return ((at(y0, x0) * (1 - fx) + at(y0, x0 + 1) * fx) * (1 - fy)
            + (at(y0 + 1, x0) * (1 - fx) + at(y0 + 1, x0 + 1) * fx) * fy)


def surface_offset(bounds) -> float:
    """``eps`` of the secondary-ray origin: 1e-4 x the diagonal of the scene box ``bounds``
    ((2, 3): low and high corner; floored at 1e-10)."""
    b = np.asarray(bounds, np.float64)
    return 1e-4 * max(float(np.linalg.norm(b[1] - b[0])), 1e-6)


class Shader:
    """Surface data of a scene, indexed by the scene-order triangle id the RTC returns."""

    def __init__(self, scene, fmt: FPFormat, eps: float):
        self.scene = scene
        self.fmt = fmt
        self.eps = np.float32(fmt.quantize(eps))
        kept = np.full(scene.n_scene_tris, -1, np.int64)
        kept[scene.tri_id] = np.arange(len(scene.tri_id))
        self.kept = kept
        tris = fmt.quantize(scene.tris)
        e1 = tris[:, 1] - tris[:, 0]
        e2 = tris[:, 2] - tris[:, 0]
        n = np.cross(e1.astype(np.float64), e2.astype(np.float64))
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        self.face_n = fmt.quantize(n)
        m = scene.materials
        self.diffuse = np.array([mm.diffuse for mm in m], np.float32).reshape(-1, 3)
        self.specular = np.array([mm.specular for mm in m], np.float32).reshape(-1, 3)
        self.shininess = np.array([mm.shininess for mm in m], np.float32)
        self.reflect = np.array([mm.reflect for mm in m], np.float32)

    def surface(self, rays: Rays, sel: np.ndarray, tri: np.ndarray, t, u, v):
        """Hit point (format), oriented geometric normal (format), shading normal, albedo."""
        fmt = self.fmt
        k = self.kept[tri]
        d = rays.dir[sel]
        p = axpy(fmt, t, d, rays.org[sel])
        ng = self.face_n[k]
        flip = dot3(fmt, ng, d) > 0
        ng = np.where(flip[:, None], -ng, ng).astype(np.float32)
        w = np.stack([1 - u - v, u, v], axis=1).astype(np.float32)
        ns = np.einsum("nk,nkc->nc", w, self.scene.normals[k]).astype(np.float32)
        ns /= np.maximum(np.linalg.norm(ns, axis=1, keepdims=True), 1e-20)
        ns = np.where((np.sum(ns * ng, axis=1) < 0)[:, None], -ns, ns)
        mat = self.scene.material[k]
        albedo = self.diffuse[mat].copy()
        for mi, mm in enumerate(self.scene.materials):
            if mm.texture is not None:
                on = mat == mi
                if on.any():
                    uv = np.einsum("nk,nkc->nc", w[on], self.scene.uv[k[on]])
                    albedo[on] *= bilinear(mm.texture, uv)
        return p, ng, ns, mat, albedo

    def offset(self, p, ng, d):
        """Origin of a secondary ray: (p + eps*n) - eps*w (format arithmetic)."""
        fmt = self.fmt
        w = d.astype(np.float64)
        w = fmt.quantize(w / np.maximum(np.linalg.norm(w, axis=1, keepdims=True), 1e-300))
        return np.stack([fmt.sub(fmt.add(p[:, a], fmt.mul(self.eps, ng[:, a])),
                                 fmt.mul(self.eps, w[:, a])) for a in range(3)], axis=1)

    def shadow_rays(self, src: Rays, sel, p0, ng, light,
                    cull_behind: bool = True) -> tuple[Rays, np.ndarray]:
        """One shadow ray per lit-side hit; packets follow the source packets.
        Returns the rays and, per ray, the index into ``sel`` it came from."""
        fmt = self.fmt
        if light.kind == "point":
            lp = fmt.quantize(light.position)
            d = np.stack([fmt.sub(lp[a], p0[:, a]) for a in range(3)], axis=1)
            tmax = np.ones(len(d), np.float32)
        else:
            d = np.broadcast_to(fmt.quantize(-np.asarray(light.direction, np.float64)),
                                p0.shape).astype(np.float32)
            tmax = np.full(len(d), np.inf, np.float32)
        facing = dot3(fmt, ng, d) > 0
        if not cull_behind:
            facing = np.ones(len(d), bool)
        return _packetize(src, sel, facing, p0, d, tmax, SHADOW)

    def reflection_rays(self, src: Rays, sel, p0, ns, mat,
                        cull_matte: bool = True) -> tuple[Rays, np.ndarray]:
        fmt = self.fmt
        d = src.dir[sel]
        ns = fmt.quantize(ns)
        two_dn = fmt.mul(np.float32(2.0), dot3(fmt, d, ns))
        r = np.stack([fmt.sub(d[:, a], fmt.mul(two_dn, ns[:, a])) for a in range(3)], axis=1)
        want = self.reflect[mat] > 0 if cull_matte else np.ones(len(r), bool)
        return _packetize(src, sel, want, p0, r, np.full(len(r), np.inf, np.float32), REFLECTION)

    def phong(self, d, ns, albedo, mat, light, lit, p):
        """Direct light from one light (zero where unlit/shadowed)."""
        if light.kind == "point":
            ldir = np.asarray(light.position, np.float32)[None, :] - p
        else:
            ldir = -np.broadcast_to(np.asarray(light.direction, np.float32), p.shape)
        ldir = ldir / np.maximum(np.linalg.norm(ldir, axis=1, keepdims=True), 1e-20)
        col = np.asarray(light.color, np.float32)
        ndl = np.clip(np.sum(ns * ldir, axis=1), 0, None)
        view = -d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-20)
        h = ldir + view
        h /= np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-20)
        spec = np.clip(np.sum(ns * h, axis=1), 0, None) ** self.shininess[mat]
        out = albedo * ndl[:, None] * col + self.specular[mat] * spec[:, None] * col
        return out * lit[:, None]


def _packetize(src: Rays, sel: np.ndarray, want: np.ndarray, org, d, tmax, kind):
    """Keep rays where ``want``; a secondary packet = the wanted rays of one source packet."""
    keep = np.nonzero(want)[0]
    src_packet = np.searchsorted(src.pk_start, sel[keep], side="right") - 1
    counts = np.bincount(src_packet, minlength=src.n_packets)
    pk_start = np.concatenate([[0], np.cumsum(counts[counts > 0])]).astype(np.int64)
    rays = Rays(org[keep].astype(np.float32), d[keep].astype(np.float32), tmax[keep],
                np.full(len(keep), kind, np.uint8), src.pixel[sel[keep]], pk_start)
    return rays, keep
