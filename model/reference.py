"""Float64 reference of the golden model's algorithm (for the precision study).

The same steps as :mod:`model.rtc` and :mod:`model.render` — kd-tree traversal with a stack and
``[tnear, tfar]`` clipping, the watertight shear test of Woop, Benthin and Wald (same order of
operations, reciprocal then multiply), the same camera, hit-point offset, shadow and reflection
rays and shading — but every geometric operation in IEEE float64 on the scene's own triangles
(the binary32 values the scene file gave), traced one ray at a time (packets do not change
results). The kd-tree is the one built at binary32 (its leaves hold every triangle that touches
them); traversal widens each split by ``pad`` in t so that float64 rounding of the split
distance cannot skip a leaf.

Colour arithmetic (shading normals, textures, Phong) is the model's own float32 code.
"""
from __future__ import annotations

from types import SimpleNamespace

import numba
import numpy as np

from .config import Config
from .fp import BINARY32, fmax, fmin
from .intersection import pick
from .raygen import eye_rays
from .render import prepare
from .shading import AMBIENT, Shader, surface_offset


@numba.njit(cache=True)
def intersect64(tri, o, kx, ky, kz, sx, sy, sz):
    """Float64 watertight test of one ray against one triangle (9 float64): (hit, t, u, v)."""
    a0, a1, a2 = tri[0] - o[0], tri[1] - o[1], tri[2] - o[2]
    b0, b1, b2 = tri[3] - o[0], tri[4] - o[1], tri[5] - o[2]
    c0, c1, c2 = tri[6] - o[0], tri[7] - o[1], tri[8] - o[2]
    az, bz, cz = pick(a0, a1, a2, kz), pick(b0, b1, b2, kz), pick(c0, c1, c2, kz)
    ax = pick(a0, a1, a2, kx) - sx * az
    ay = pick(a0, a1, a2, ky) - sy * az
    bx = pick(b0, b1, b2, kx) - sx * bz
    by = pick(b0, b1, b2, ky) - sy * bz
    cx = pick(c0, c1, c2, kx) - sx * cz
    cy = pick(c0, c1, c2, ky) - sy * cz
    eu = cx * by - cy * bx
    ev = ax * cy - ay * cx
    ew = bx * ay - by * ax
    if (eu < 0 or ev < 0 or ew < 0) and (eu > 0 or ev > 0 or ew > 0):
        return False, 0.0, 0.0, 0.0
    det = (eu + ev) + ew
    if det == 0:
        return False, 0.0, 0.0, 0.0
    tz = (eu * (sz * az) + ev * (sz * bz)) + ew * (sz * cz)
    rcp = 1.0 / det
    return True, tz * rcp, ev * rcp, ew * rcp


@numba.njit(cache=True, inline="always")
def shear_axes(d):
    """The watertight test's axes and shear constants of direction ``d`` (float64):
    kz = the dominant axis, kx/ky the others (swapped when d[kz] < 0)."""
    kz = 0
    for a in (1, 2):
        if abs(d[a]) > abs(d[kz]):
            kz = a
    kx = (kz + 1) % 3
    ky = (kx + 1) % 3
    if d[kz] < 0:
        kx, ky = ky, kx
    return kx, ky, kz, d[kx] / d[kz], d[ky] / d[kz], 1.0 / d[kz]


@numba.njit(cache=True)
def _trace_one(axis, split, child, first, count, tri_list, tris, ids, lo, hi, o, d, tmax,
               anyhit, pad, stack_node, stack_near, stack_far):
    inv = np.empty(3)
    neg = np.empty(3, np.int64)
    for a in range(3):
        inv[a] = 1.0 / d[a] if d[a] != 0 else (np.inf if np.copysign(1.0, d[a]) > 0 else -np.inf)
        neg[a] = 1 if np.copysign(1.0, d[a]) < 0 else 0
    kx, ky, kz, sx, sy, sz = shear_axes(d)
    tnear, tfar = 0.0, tmax
    for a in range(3):
        t0 = (lo[a] - o[a]) * inv[a]
        t1 = (hi[a] - o[a]) * inv[a]
        tnear = fmax(tnear, fmin(t0, t1) - pad)
        tfar = fmin(tfar, fmax(t0, t1) + pad)
    best, btri, bu, bv = tmax, -1, 0.0, 0.0
    if not (tnear <= tfar):
        return btri, np.inf, bu, bv
    node, sp = 0, 0
    while True:
        if axis[node] != 3:
            a = axis[node]
            dist = (split[node] - o[a]) * inv[a]
            near = child[node] + neg[a]
            far = child[node] + 1 - neg[a]
            need_near = not (dist + pad < tnear)
            need_far = not (dist - pad > tfar)
            if need_near and need_far:
                stack_node[sp] = far
                stack_near[sp] = fmax(tnear, dist - pad)
                stack_far[sp] = tfar
                sp += 1
                tfar = fmin(tfar, dist + pad)
                node = near
            elif need_near:
                tfar = fmin(tfar, dist + pad)
                node = near
            else:
                tnear = fmax(tnear, dist - pad)
                node = far
            continue
        for j in range(count[node]):
            ti = tri_list[first[node] + j]
            hit, t, u, v = intersect64(tris[ti], o, kx, ky, kz, sx, sy, sz)
            if hit and t > 0 and t < best:
                best, btri, bu, bv = t, ids[ti], u, v
        if btri >= 0 and (anyhit or best <= tfar):
            break
        if sp == 0:
            break
        sp -= 1
        node, tnear, tfar = stack_node[sp], stack_near[sp], stack_far[sp]
    return btri, (best if btri >= 0 else np.inf), bu, bv


@numba.njit(cache=True, parallel=True)
def _trace_all(axis, split, child, first, count, tri_list, tris, ids, lo, hi, org, dirn, tmax,
               anyhit, pad, depth, out_tri, out_t, out_u, out_v):
    for r in numba.prange(org.shape[0]):
        sn = np.empty(depth + 2, np.int64)
        s0 = np.empty(depth + 2)
        s1 = np.empty(depth + 2)
        tri, t, u, v = _trace_one(axis, split, child, first, count, tri_list, tris, ids, lo, hi,
                                  org[r], dirn[r], tmax[r], anyhit[r], pad[r], sn, s0, s1)
        out_tri[r], out_t[r], out_u[r], out_v[r] = tri, t, u, v


class Reference:
    """A scene ready for float64 tracing: its binary32 kd-tree and float64 triangles."""

    def __init__(self, scene, cfg: Config | None = None):
        cfg = (cfg or Config()).replace(fmt=BINARY32)
        self.scene = scene
        self.cfg = cfg
        self.prep = prepare(scene, cfg)
        tree = self.prep.tree
        if not np.array_equal(self.prep.tris, np.asarray(scene.tris, np.float32)):
            raise ValueError("reference: the scene's triangles are not binary32 values")
        self.tree = tree
        self.tris = np.ascontiguousarray(np.asarray(scene.tris, np.float64).reshape(-1, 9))
        self.ids = np.asarray(scene.tri_id, np.int64)
        self.bounds = tree.bounds.astype(np.float64)
        self.scale = float(np.abs(self.bounds).max())

    def trace(self, org, dirn, tmax=None, anyhit=None, pad_rel: float = 1e-9):
        """Closest (or, where ``anyhit``, any) hit per ray in float64: (tri id or -1, t, u, v)."""
        org = np.ascontiguousarray(org, np.float64)
        dirn = np.ascontiguousarray(dirn, np.float64)
        n = len(org)
        tmax = np.full(n, np.inf) if tmax is None else np.asarray(tmax, np.float64)
        anyhit = np.zeros(n, bool) if anyhit is None else np.asarray(anyhit, bool)
        pad = pad_rel * self.scale / np.maximum(np.linalg.norm(dirn, axis=1), 1e-300)
        out = (np.empty(n, np.int64), np.empty(n), np.empty(n), np.empty(n))
        t = self.tree
        if n:
            _trace_all(t.axis.astype(np.int64), t.split.astype(np.float64),
                       t.child.astype(np.int64), t.first.astype(np.int64),
                       t.count.astype(np.int64), t.tri_list.astype(np.int64), self.tris,
                       self.ids, self.bounds[0], self.bounds[1], org, dirn, tmax, anyhit, pad,
                       int(t.depth), *out)
        return out


def render64(ref: Reference, width: int, height: int, reflect_depth: int = 3,
             shadows: bool = True) -> tuple[np.ndarray, tuple]:
    """Float64 render with :func:`model.render.render`'s steps (oversampling 1), refracted
    rays included.

    Returns the (H, W, 3) float32 linear image and the eye rays' hits (in the model's eye-ray
    order: tri, t, u, v)."""
    from .raygen import camera_basis
    scene = ref.scene
    cam = scene.camera
    pos, corner, dx, dy = camera_basis(cam.position, cam.look_at, cam.up, cam.fov_y, width,
                                       height)
    pixel = eye_rays(cam, width, height, ref.cfg).pixel
    sx, sy = pixel % width + 0.5, pixel // width + 0.5
    d = (corner[None] + sx[:, None] * dx[None]) + sy[:, None] * dy[None]
    org = np.broadcast_to(pos, d.shape).copy()
    eps = surface_offset(ref.bounds)
    shader = Shader(scene, BINARY32, eps=eps)
    tri64 = ref.tris.reshape(-1, 3, 3)
    fn = np.cross(tri64[:, 1] - tri64[:, 0], tri64[:, 2] - tri64[:, 0])
    fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
    color = np.zeros((width * height, 3), np.float64)
    weight = np.ones(len(d))
    bg = np.asarray(scene.background, np.float64)
    eye_hits = None
    for depth in range(reflect_depth + 1):
        if len(d) == 0:
            break
        tri, t, u, v = ref.trace(org, d)
        if eye_hits is None:
            eye_hits = (tri, t, u, v)
        hit = np.nonzero(tri >= 0)[0]
        miss = np.nonzero(tri < 0)[0]
        np.add.at(color, pixel[miss], bg * weight[miss, None])
        if hit.size == 0:
            break

        # Shader.surface's shading normal, material and albedo (its ray origins are discarded)
        d32 = d.astype(np.float32)
        rays32 = SimpleNamespace(dir=d32, org=np.zeros_like(d32))
        surf = shader.surface(rays32, hit, tri[hit], t[hit].astype(np.float32),
                              u[hit].astype(np.float32), v[hit].astype(np.float32))
        ns, mat, albedo = surf.n, surf.mat, surf.albedo
        dh = d[hit]
        p = org[hit] + t[hit, None] * dh
        ng = fn[shader.kept[tri[hit]]]
        ng = np.where((np.sum(ng * dh, axis=1) > 0)[:, None], -ng, ng)
        w = dh / np.linalg.norm(dh, axis=1, keepdims=True)
        p0 = (p + eps * ng) - eps * w
        local = (AMBIENT * albedo).astype(np.float64)
        for light in scene.lights:
            if light.kind == "point":
                ld = np.asarray(light.position, np.float64)[None] - p0
                tmax = np.ones(len(ld))
            else:
                ld = np.broadcast_to(-np.asarray(light.direction, np.float64), p0.shape).copy()
                tmax = np.full(len(ld), np.inf)
            keep = np.sum(ng * ld, axis=1) > 0
            lit = np.zeros(hit.size)
            if shadows and keep.any():
                st = ref.trace(p0[keep], ld[keep], tmax[keep], np.ones(keep.sum(), bool))[0]
                lit[keep] = st < 0
            else:
                lit[keep] = 1.0
            local += shader.phong(dh, ns, albedo, mat, light, lit, p)
        refl = shader.reflect[mat]
        trans = shader.transmit[mat]
        local *= (1 - refl - trans)[:, None]
        np.add.at(color, pixel[hit], local * weight[hit, None])
        if depth == reflect_depth:
            break
        nsd = ns.astype(np.float64)
        r = dh - (2 * np.sum(dh * nsd, axis=1))[:, None] * nsd
        want = refl > 0
        tw = trans > 0
        # refraction (model/rgs/refract.py's steps in float64): entering where the ray meets
        # the face from the front, total internal reflection as the mirror ray
        ior = np.array([m.ior for m in scene.materials], np.float64)[mat[tw]]
        leave = np.sum(fn[shader.kept[tri[hit[tw]]]] * dh[tw], axis=1) > 0
        eta = np.where(leave, ior, 1 / ior)[:, None]
        c = -np.sum(w[tw] * nsd[tw], axis=1, keepdims=True)
        k = 1 - eta ** 2 * (1 - c ** 2)
        tir = k < 0
        tdir = np.where(tir, r[tw], eta * w[tw] + (eta * c - np.sqrt(np.maximum(k, 0))) * nsd[tw])
        torg = np.where(tir, p0[tw], (p[tw] - eps * ng[tw]) + eps * w[tw])
        org, d = np.concatenate([p0[want], torg]), np.concatenate([r[want], tdir])
        pixel = np.concatenate([pixel[hit[want]], pixel[hit[tw]]])
        weight = np.concatenate([weight[hit[want]] * refl[want], weight[hit[tw]] * trans[tw]])
    return color.reshape(height, width, 3).astype(np.float32), eye_hits


@numba.njit(cache=True, parallel=True)
def crossings64(tris, org, dirn, tlim):
    """Per ray, the number of triangles (9 float64 each) the float64 test hits with
    0 < t <= tlim (every triangle tested; for a few rays)."""
    out = np.zeros(org.shape[0], np.int64)
    for r in numba.prange(org.shape[0]):
        d = dirn[r]
        kx, ky, kz, sx, sy, sz = shear_axes(d)
        for i in range(tris.shape[0]):
            hit, t, u, v = intersect64(tris[i], org[r], kx, ky, kz, sx, sy, sz)
            if hit and t > 0 and t <= tlim[r]:
                out[r] += 1
    return out
