"""Shading (the RGS slave, golden model): Phong-like with one bilinearly filtered texture.

Everything that becomes a ray is the hardware's format arithmetic, in the RTL's order:
``model/rgs/secondary.py``'s :func:`~model.rgs.secondary` makes, from a hit, the secondary rays' origin
``p0 = (p + eps*g) - eps*w`` (g the unit face normal turned toward the incoming ray, w the unit
incoming direction, ``eps = 1e-4 x`` the scene box diagonal: off the surface and back along the
ray, so a secondary ray neither hits its own triangle nor starts on a neighbouring wall at a
corner), the shading normal n (the vertex normals interpolated with u, v, normalized, turned to
g's side) and the reflected direction ``d - 2 (d.n) n``; :func:`~model.rgs.shadow_dir` makes a
shadow ray per light that faces the surface (a light behind the surface, as seen from the ray,
casts no ray: the point is unlit). The unit face normals are computed once on the host (float64,
rounded once per component: ``model.layout.face_normals``), as the memory image's slave
records hold them.

The colour is the slave's format arithmetic too (``model/rgs/secondary.py``'s :func:`~model.rgs.hit_colour`
and :func:`~model.rgs.light_colour`, each contribution then made a 24-bit fixed-point number,
:func:`~model.rgs.to_fixed`): every eye or reflection ray carries a weight (1/oversampling² for
an eye ray, the parent's weight times the material's reflectivity for a reflection ray) and the
colour it adds if it leaves the scene (background times weight); a hit adds its ambient term;
a shadow ray carries the Phong term of its light and adds it if it reaches the light. A pixel is
the integer sum of its contributions, the same in any order. The material constants come from
the slave records (``model.layout.rec_material``: kd and ks already scaled by 1 - reflect). A
texture multiplies kd by its bilinearly filtered texel colour (:func:`~model.rgs.texture_kd`:
the texture coordinate interpolated in the format, wrapped and placed in fixed point, the four
texels filtered in integers, scaled to the format); ``textures=False`` leaves kd as the
record holds it (a chip without a texture unit, ``Config.tex_cache_kb = 0``). The float
``albedo`` (the reference renderer's and the host preview's) filters in float32.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .fp import FPFormat
from .layout import MATERIAL_DTYPE, ShadingData, face_normals, rec_material
from .raygen import Rays
from .raykind import RayKind
from .rgs import refraction_rays, secondary_rays, shade_batch, shadow_rays, texture_kd

AMBIENT = np.float32(0.08)


def shading_data(scene, fmt: FPFormat) -> ShadingData:
    """The scene's materials, per-triangle material ids, vertex normals, texture coordinates
    and textures (RGBA8) as the memory image holds them (``model.layout.ShadingData``)."""
    mats = np.zeros(len(scene.materials), MATERIAL_DTYPE)
    textures = []
    for i, mm in enumerate(scene.materials):
        mats[i]["diffuse"] = mm.diffuse
        mats[i]["specular"] = mm.specular
        mats[i]["shininess"] = mm.shininess
        mats[i]["reflect"] = mm.reflect
        mats[i]["transmit"] = mm.transmit
        mats[i]["ior"] = mm.ior
        mats[i]["texture"] = -1
        if mm.texture is not None:
            t = np.asarray(mm.texture, np.uint8)
            textures.append(np.concatenate([t, np.full(t.shape[:2] + (1,), 255, np.uint8)], 2))
            mats[i]["texture"] = len(textures) - 1
    return ShadingData(mat_id=np.asarray(scene.material), materials=mats,
                       normals=np.asarray(scene.normals), uvs=np.asarray(scene.uv),
                       textures=textures)


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


def frame_colour_registers(scene, fmt: FPFormat, n_samples: int = 1) -> dict:
    """The slave's colour registers for a frame, as format values: ``amb`` (the ambient
    factor), ``bg`` (3: the background), ``w_eye`` (an eye ray's weight, 1 / ``n_samples``),
    ``lights`` ((L, 3): each light's colour), and ``eye_miss`` ((3,) int64: an eye ray's colour
    if it misses, fixed(bg * w_eye) as :func:`~model.rgs.hit_colour` makes a reflection ray's)."""
    from .rgs import to_fixed_array
    bg = fmt.quantize(np.asarray(scene.background, np.float64)).astype(np.float32)
    w_eye = np.float32(fmt.quantize(1.0 / n_samples))
    lights = fmt.quantize(np.array([lt.color for lt in scene.lights], np.float64)
                          .reshape(-1, 3)).astype(np.float32)
    return {"amb": np.float32(fmt.quantize(float(AMBIENT))), "bg": bg, "w_eye": w_eye,
            "lights": lights, "eye_miss": to_fixed_array(fmt.mul(bg, w_eye), fmt.em[0])}


def surface_offset(bounds) -> float:
    """``eps`` of the secondary-ray origin: 1e-4 x the diagonal of the scene box ``bounds``
    ((2, 3): low and high corner; floored at 1e-10)."""
    b = np.asarray(bounds, np.float64)
    return 1e-4 * max(float(np.linalg.norm(b[1] - b[0])), 1e-6)


@dataclass
class Surface:
    """What the slave computes from the hits of ``rays[sel]`` (format values, (n, 3) each):
    ``p0`` the secondary rays' origin, ``g`` the oriented face normal, ``n`` the shading
    normal, ``r`` the reflected direction; ``mat`` material index, ``albedo`` float32 colour
    (diffuse times texture), ``kd`` the slave's diffuse constant (the record's kd, times the
    texture colour in the format where textured and ``textures``)."""
    p0: np.ndarray
    g: np.ndarray
    n: np.ndarray
    r: np.ndarray
    mat: np.ndarray
    albedo: np.ndarray
    kd: np.ndarray


@dataclass
class Shaded:
    """What the slave computes from a set of hits (``Shader.shade``), per hit: ``p0`` the
    secondary rays' origin, ``r`` the reflected direction, ``mat`` the material, ``ambient``
    and ``miss`` (fixed point) and ``wr`` as :func:`~model.rgs.hit_colours` gives them; per
    light and hit: ``shadow_dir``, ``cast`` (a shadow ray is cast) and ``light`` (its fixed-point
    colour if it reaches the light, zero where not cast)."""
    p0: np.ndarray
    r: np.ndarray
    mat: np.ndarray
    ambient: np.ndarray
    wr: np.ndarray
    miss: np.ndarray
    shadow_dir: np.ndarray
    cast: np.ndarray
    light: np.ndarray


class Shader:
    """Surface data of a scene, indexed by the scene-order triangle id the RTC returns."""

    def __init__(self, scene, fmt: FPFormat, eps: float, textures: bool = True):
        self.scene = scene
        self.textures = textures
        self.fmt = fmt
        self.eps = np.float32(fmt.quantize(eps))
        kept = np.full(scene.n_scene_tris, -1, np.int64)
        kept[scene.tri_id] = np.arange(len(scene.tri_id))
        self.kept = kept
        self.face_n = face_normals(fmt.quantize(scene.tris), fmt)
        self.vertex_n = fmt.quantize(scene.normals)
        m = scene.materials
        self.diffuse = np.array([mm.diffuse for mm in m], np.float32).reshape(-1, 3)
        self.specular = np.array([mm.specular for mm in m], np.float32).reshape(-1, 3)
        self.shininess = np.array([mm.shininess for mm in m], np.float32)
        self.reflect = np.array([mm.reflect for mm in m], np.float32)
        self.transmit = np.array([mm.transmit for mm in m], np.float32)
        sd = shading_data(scene, fmt)
        self.rec = rec_material(sd.materials, fmt)
        # the textures as the memory image holds them: RGBA8 words, row by row, one after the
        # other (tex_first: each material's first texel, -1 = none)
        words = [np.ascontiguousarray(t).view("<u4").reshape(-1) for t in sd.textures]
        firsts = np.cumsum([0] + [w.size for w in words])
        self.texels = np.concatenate(words + [np.zeros(1, np.uint32)]).astype(np.uint32)
        ti = sd.materials["texture"]
        self.tex_first = np.where(ti >= 0, firsts[np.maximum(ti, 0)], -1).astype(np.int64)
        sizes = np.array([t.shape[:2] for t in sd.textures] + [(1, 1)], np.int64)
        self.tex_w = sizes[ti, 1]
        self.tex_h = sizes[ti, 0]
        self.uv = fmt.quantize(np.asarray(scene.uv, np.float64)).astype(np.float32)
        self._arrays = None         # shade()'s contiguous tables, made on first use

    def surface(self, rays: Rays, sel: np.ndarray, tri: np.ndarray, t, u, v) -> Surface:
        """The slave's secondary-ray arithmetic (``model.rgs.secondary_rays``) and the
        albedo for the hits ``tri``, ``t``, ``u``, ``v`` of rays ``rays[sel]``."""
        k = self.kept[tri]
        E, M = self.fmt.em
        p0, g, n, r = secondary_rays(
            np.ascontiguousarray(rays.org, np.float32), np.ascontiguousarray(rays.dir, np.float32),
            np.asarray(sel, np.int64), np.asarray(t, np.float32), np.asarray(u, np.float32),
            np.asarray(v, np.float32), k, self.face_n, self.vertex_n, self.eps, E, M)
        mat = self.scene.material[k]
        albedo = self.diffuse[mat].copy()
        kd = self.rec["kd"][mat].copy()
        w = np.stack([1 - u - v, u, v], axis=1).astype(np.float32)
        for mi, mm in enumerate(self.scene.materials):
            if mm.texture is not None:
                on = mat == mi
                if on.any():
                    uv = np.einsum("nk,nkc->nc", w[on], self.scene.uv[k[on]])
                    albedo[on] *= bilinear(mm.texture, uv)
        if self.textures and len(k):
            kd = texture_kd(np.ascontiguousarray(kd, np.float32), np.asarray(u, np.float32),
                            np.asarray(v, np.float32),
                            np.ascontiguousarray(self.uv[k].reshape(-1, 6)),
                            self.tex_first[mat], self.tex_w[mat], self.tex_h[mat],
                            self.texels, E, M)
        return Surface(p0, g, n, r, mat, albedo, kd)

    def shade(self, rays: Rays, sel: np.ndarray, tri: np.ndarray, t, u, v, weight,
              colours: dict, cull_behind: bool = True) -> Shaded:
        """The slave's work on the hits of rays ``sel`` in one compiled pass
        (``model.rgs.shade_batch``): :meth:`surface`'s arithmetic, the hit colours of rays of
        weight ``weight`` and every light's shadow ray and colour, with the frame's colour
        registers ``colours`` (``frame_colour_registers``). ``tri``, ``t``, ``u``, ``v`` and
        ``weight`` are per ray of ``rays`` (only the rows ``sel`` are read)."""
        E, M = self.fmt.em
        if self._arrays is None:
            lights = self.scene.lights
            vecs = [self.light_vector(lt) for lt in lights]
            self._arrays = (
                np.ascontiguousarray(self.scene.material, np.int64),
                np.ascontiguousarray(self.face_n, np.float32),
                np.ascontiguousarray(self.vertex_n, np.float32),
                np.ascontiguousarray(self.uv.reshape(-1, 6), np.float32),
                np.ascontiguousarray(self.rec["kd"], np.float32),
                np.ascontiguousarray(self.rec["ks"], np.float32),
                np.ascontiguousarray(self.rec["shin"], np.int64),
                np.ascontiguousarray(self.rec["kr"], np.float32),
                np.ascontiguousarray(self.tex_first, np.int64),
                np.ascontiguousarray(self.tex_w, np.int64),
                np.ascontiguousarray(self.tex_h, np.int64),
                np.array([v for v, _ in vecs], np.float32).reshape(-1, 3),
                np.array([pt for _, pt in vecs], np.bool_))
        (tri_mat, nf, nv, uv, kd, ks, shin, kr, tex_first, tex_w, tex_h, lvec,
         point) = self._arrays
        lc = np.ascontiguousarray(colours["lights"], np.float32).reshape(-1, 3)
        out = shade_batch(
            np.ascontiguousarray(rays.org, np.float32), np.ascontiguousarray(rays.dir, np.float32),
            np.asarray(sel, np.int64), np.asarray(tri), np.asarray(t, np.float32),
            np.asarray(u, np.float32), np.asarray(v, np.float32),
            np.asarray(weight, np.float32), self.kept, tri_mat, nf, nv, uv, kd, ks, shin, kr,
            tex_first, tex_w, tex_h, self.texels, bool(self.textures), np.float32(colours["amb"]),
            np.asarray(colours["bg"], np.float32), self.eps, lvec, point, lc, bool(cull_behind),
            E, M)
        return Shaded(*out)

    def light_vector(self, light) -> tuple[np.ndarray, bool]:
        """The slave's light register: a point light's position or a parallel light's reversed
        direction, in the format; and whether it is a point light."""
        if light.kind == "point":
            return self.fmt.quantize(light.position), True
        return self.fmt.quantize(-np.asarray(light.direction, np.float64)), False

    def shadow_rays(self, src: Rays, sel, surf: Surface, light, cull_behind: bool = True,
                    light_index: int = 0) -> tuple[Rays, np.ndarray]:
        """One shadow ray per hit whose surface faces ``light`` (light ``light_index`` of the
        scene); packets follow the source packets. Returns the rays and, per ray, the index
        into ``sel`` it came from."""
        vec, point = self.light_vector(light)
        d, facing = shadow_rays(surf.p0, surf.g, vec, point, *self.fmt.em)
        tmax = np.full(len(d), 1.0 if point else np.inf, np.float32)
        if not cull_behind:
            facing = np.ones(len(d), bool)
        return _packetize(src, sel, facing, surf.p0, d, tmax, RayKind.SHADOW, light=light_index)

    def shaded_shadow_rays(self, src: Rays, sel, sh: Shaded, light_index: int
                           ) -> tuple[Rays, np.ndarray]:
        """:meth:`shadow_rays` from :meth:`shade`'s result ``sh`` (the rays ``sel`` of ``src``
        hit) toward light ``light_index``: the rays where ``sh.cast``, and per ray its index
        into ``sel``."""
        point = self.scene.lights[light_index].kind == "point"
        tmax = np.full(len(sel), 1.0 if point else np.inf, np.float32)
        return _packetize(src, sel, sh.cast[light_index], sh.p0, sh.shadow_dir[light_index],
                          tmax, RayKind.SHADOW, light=light_index)

    def reflection_rays(self, src: Rays, sel, surf, cull_matte: bool = True
                        ) -> tuple[Rays, np.ndarray]:
        """One reflection ray per hit on a reflective material (``reflect > 0``); ``surf`` a
        :class:`Surface` or :class:`Shaded` (its ``mat``, ``p0`` and ``r``)."""
        want = self.reflect[surf.mat] > 0 if cull_matte else np.ones(len(surf.r), bool)
        return _packetize(src, sel, want, surf.p0, surf.r,
                          np.full(len(surf.r), np.inf, np.float32), RayKind.REFLECTION)

    def refraction_rays(self, src: Rays, sel, sh: "Shaded", tri, t, u, v, weight,
                        colours: dict) -> tuple[Rays, np.ndarray, np.ndarray, np.ndarray]:
        """One refracted ray per hit on a material that transmits (``transmit > 0``;
        ``model.rgs.refraction_rays``): the rays ``sel`` of ``src`` hit ``tri``, ``t``, ``u``,
        ``v`` (per ray of ``src``), ``sh`` is :meth:`shade`'s result for them, ``weight`` the
        rays' weights (per ray of ``src``). Returns the rays, per ray its index into ``sel``,
        its weight and its fixed-point colour if it misses."""
        sel = np.asarray(sel, np.int64)
        want = self.transmit[sh.mat] > 0
        n = len(sel)
        org = np.zeros((n, 3), np.float32)
        d = np.zeros((n, 3), np.float32)
        wt = np.zeros(n, np.float32)
        miss = np.zeros((n, 3), np.int64)
        idx = np.flatnonzero(want)
        if len(idx):
            E, M = self.fmt.em
            rows = sel[idx]
            mat = sh.mat[idx]
            o, dd, _, w, mc = refraction_rays(
                np.ascontiguousarray(src.org, np.float32),
                np.ascontiguousarray(src.dir, np.float32), rows,
                np.asarray(t, np.float32)[rows], np.asarray(u, np.float32)[rows],
                np.asarray(v, np.float32)[rows], self.kept[np.asarray(tri)[rows]],
                np.ascontiguousarray(self.face_n, np.float32),
                np.ascontiguousarray(self.vertex_n, np.float32), self.eps,
                self.rec["kt"][mat], self.rec["eta_in"][mat], self.rec["eta_out"][mat],
                np.asarray(weight, np.float32)[rows], np.asarray(colours["bg"], np.float32),
                E, M)
            org[idx], d[idx], wt[idx], miss[idx] = o, dd, w, mc
        rays, keep = _packetize(src, sel, want, org, d, np.full(n, np.inf, np.float32),
                                RayKind.REFRACTION)
        return rays, keep, wt[keep], miss[keep]

    def phong(self, d, ns, albedo, mat, light, lit, p):
        """Direct light from one light (zero where unlit/shadowed), in the precision of the
        inputs (the float64 reference and the host's unshadowed preview): the terms of
        ``model.rgs.light_colour`` without the weight and the 1 - reflect factor, with the
        reflected direction made from ``d`` and ``ns``."""
        if light.kind == "point":
            ldir = np.asarray(light.position, p.dtype)[None, :] - p
        else:
            ldir = -np.broadcast_to(np.asarray(light.direction, p.dtype), p.shape)
        ldir = ldir / np.maximum(np.linalg.norm(ldir, axis=1, keepdims=True), 1e-20)
        col = np.asarray(light.color, p.dtype)
        ndl = np.clip(np.sum(ns * ldir, axis=1), 0, None)
        r = d - 2 * np.sum(d * ns, axis=1, keepdims=True) * ns
        r = r / np.maximum(np.linalg.norm(r, axis=1, keepdims=True), 1e-20)
        spec = np.clip(np.sum(r * ldir, axis=1), 0, None) ** self.rec["shin"][mat]
        out = albedo * ndl[:, None] * col + self.specular[mat] * spec[:, None] * col
        return out * lit[:, None]


def _packetize(src: Rays, sel: np.ndarray, want: np.ndarray, org, d, tmax, kind,
               light: int = -1):
    """Keep rays where ``want``; a secondary packet = the wanted rays of one source packet, in
    lane order (the RGS slave packs them the same way). Shadow rays keep their source ray's
    depth, reflection and refracted rays add one; all keep its eye ray and its path, and a
    refracted ray sets the path's bit of its source ray's depth (``Rays.path``)."""
    keep = np.nonzero(want)[0]
    src_packet = np.searchsorted(src.pk_start, sel[keep], side="right") - 1
    counts = np.bincount(src_packet, minlength=src.n_packets)
    pk_start = np.concatenate([[0], np.cumsum(counts[counts > 0])]).astype(np.int64)
    parent = sel[keep]
    depth = src.depth[parent] + (1 if kind in (RayKind.REFLECTION, RayKind.REFRACTION) else 0)
    path = src.path[parent].astype(np.uint16)
    if kind == RayKind.REFRACTION:         # the path's bit of the new depth: a refraction
        path |= (np.uint16(1) << src.depth[parent].astype(np.uint16)).astype(np.uint16)
    rays = Rays(org[keep].astype(np.float32), d[keep].astype(np.float32), tmax[keep],
                np.full(len(keep), kind, np.uint8), src.pixel[parent], pk_start,
                eye=src.eye[parent], depth=depth.astype(np.uint8),
                light=np.full(len(keep), light, np.int16), path=path)
    return rays, keep
