"""Ray generation and ray setup (the RGS side), in the hardware format.

Eye rays: a pinhole camera; the host computes the camera's corner direction and per-pixel
steps once (float64, then quantized to the format, as a driver would upload them); the
hardware makes each ray with format arithmetic:
``d = (corner + px*dx) + py*dy`` per component, px = x + 0.5 (converted to the format).
Directions are not normalized (the traversal and the intersection test don't need it).

Packets: the image (times the oversampling factor) is cut into ``tile_w x tile_h`` tiles; a
tile's rays are one packet (partial tiles at the right/bottom edge give smaller packets).
Ray setup computes the read-only per-ray data the RTC units keep: ``inv``, the shear constants
``k``/``s`` of the watertight test, and the interval ``[tnear, tfar]`` clipped to the scene box.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .config import Config
from .fp import FPFormat

EYE, SHADOW, REFLECTION, REFRACTION = 0, 1, 2, 3


@dataclass
class Rays:
    """Rays in packet order: packet p holds rays ``pk_start[p]:pk_start[p+1]`` (lanes 0..n-1)."""
    org: np.ndarray              # (N, 3) float32 format values
    dir: np.ndarray              # (N, 3) float32 format values
    tmax: np.ndarray             # (N,) float32 (inf for eye rays)
    kind: np.ndarray             # (N,) uint8: 0 eye, 1 shadow, 2 reflection, 3 refraction
    pixel: np.ndarray            # (N,) int32: y * width + x of the pixel the ray contributes to
    pk_start: np.ndarray         # (P + 1,) int64
    anyhit: np.ndarray = field(default=None)   # (N,) bool: any hit ends the ray (shadow rays)

    def __post_init__(self):
        if self.anyhit is None:
            self.anyhit = self.kind == SHADOW

    def __len__(self) -> int:
        return self.org.shape[0]

    @property
    def n_packets(self) -> int:
        return self.pk_start.shape[0] - 1

    @staticmethod
    def from_arrays(org, dirn, tmax=None, *, packet: int = 64, kind: int = 0,
                    anyhit=None) -> "Rays":
        """Rays from (N, 3) origins and directions, in packets of ``packet`` consecutive rays
        (pixel = ray index; tmax default inf; any-hit default: shadow rays)."""
        org = np.ascontiguousarray(org, np.float32)
        dirn = np.ascontiguousarray(dirn, np.float32)
        n = len(dirn)
        if org.shape != (n, 3) or dirn.shape != (n, 3):
            raise ValueError(f"origins {org.shape} and directions {dirn.shape} must both be "
                             "(N, 3)")
        if not 1 <= packet <= 64:
            raise ValueError(f"packet={packet}: a packet holds 1 to 64 rays")
        tmax = np.full(n, np.inf, np.float32) if tmax is None else np.asarray(tmax, np.float32)
        pk = np.unique(np.r_[np.arange(0, n, packet), n]).astype(np.int64)
        return Rays(org, dirn, tmax, np.full(n, kind, np.uint8), np.arange(n, dtype=np.int32),
                    pk, None if anyhit is None else np.asarray(anyhit, bool))

    @staticmethod
    def concat(parts: list["Rays"]) -> "Rays":
        parts = [p for p in parts if len(p)]
        if not parts:
            return empty_rays()
        starts, off = [np.zeros(1, np.int64)], 0
        for p in parts:
            starts.append(p.pk_start[1:] + off)
            off += len(p)
        return Rays(np.concatenate([p.org for p in parts]), np.concatenate([p.dir for p in parts]),
                    np.concatenate([p.tmax for p in parts]), np.concatenate([p.kind for p in parts]),
                    np.concatenate([p.pixel for p in parts]), np.concatenate(starts),
                    np.concatenate([p.anyhit for p in parts]))


def empty_rays() -> Rays:
    z3 = np.zeros((0, 3), np.float32)
    return Rays(z3, z3.copy(), np.zeros(0, np.float32), np.zeros(0, np.uint8),
                np.zeros(0, np.int32), np.zeros(1, np.int64), np.zeros(0, bool))


def camera_basis(position, look_at, up, fov_y: float, width: int, height: int):
    """Host side: corner direction and per-pixel steps (float64)."""
    pos = np.asarray(position, np.float64)
    fwd = np.asarray(look_at, np.float64) - pos
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, np.asarray(up, np.float64))
    right /= np.linalg.norm(right)
    upv = np.cross(right, fwd)
    half_h = np.tan(np.radians(fov_y) / 2)
    half_w = half_h * width / height
    corner = fwd - half_w * right + half_h * upv
    dx = right * (2 * half_w / width)
    dy = -upv * (2 * half_h / height)
    return pos, corner, dx, dy


def eye_rays(camera, width: int, height: int, cfg: Config) -> Rays:
    """Eye rays for a ``width x height`` image with ``cfg.oversampling``² rays per pixel."""
    fmt = cfg.fmt
    n = cfg.oversampling
    sw, sh = width * n, height * n
    pos, corner, dx, dy = camera_basis(camera.position, camera.look_at, camera.up, camera.fov_y,
                                       sw, sh)
    pos, corner, dx, dy = (fmt.quantize(v) for v in (pos, corner, dx, dy))
    tw, th = cfg.tile_w, cfg.tile_h
    # sample coordinates in packet order: tiles row-major, lanes row-major inside a tile
    ty, tx, ly, lx = np.meshgrid(np.arange(-(-sh // th)), np.arange(-(-sw // tw)),
                                 np.arange(th), np.arange(tw), indexing="ij")
    sx = (tx * tw + lx).ravel()
    sy = (ty * th + ly).ravel()
    inside = (sx < sw) & (sy < sh)
    tile = (ty * (-(-sw // tw)) + tx).ravel()[inside]
    sx, sy = sx[inside], sy[inside]
    px = fmt.quantize(sx + 0.5)
    py = fmt.quantize(sy + 0.5)
    d = np.empty((sx.size, 3), np.float32)
    for a in range(3):
        d[:, a] = fmt.add(fmt.add(corner[a], fmt.mul(px, dx[a])), fmt.mul(py, dy[a]))
    org = np.broadcast_to(pos, d.shape).astype(np.float32)
    counts = np.bincount(tile, minlength=-(-sw // tw) * -(-sh // th))
    pk_start = np.concatenate([[0], np.cumsum(counts[counts > 0])]).astype(np.int64)
    pixel = ((sy // n) * width + (sx // n)).astype(np.int32)
    return Rays(org, d, np.full(sx.size, np.inf, np.float32), np.zeros(sx.size, np.uint8),
                pixel, pk_start)


@dataclass
class RaySetup:
    """Read-only per-ray data broadcast to the RTC units, and the initial interval."""
    inv: np.ndarray      # (N, 3) float32: 1 / dir
    k: np.ndarray        # (N, 3) int64: kx, ky, kz
    s: np.ndarray        # (N, 3) float32: Sx, Sy, Sz
    tnear: np.ndarray    # (N,) float32
    tfar: np.ndarray     # (N,) float32


def setup(rays: Rays, bounds: np.ndarray, fmt: FPFormat) -> RaySetup:
    """Ray setup in the format's arithmetic (vectorized over rays)."""
    d, o = rays.dir, rays.org
    one = np.float32(1.0)
    inv = np.stack([fmt.div(one, d[:, a]) for a in range(3)], axis=1)
    kz = np.argmax(np.abs(d), axis=1)          # first axis of largest |d| (ties: lowest axis)
    kx = (kz + 1) % 3
    ky = (kx + 1) % 3
    dz = d[np.arange(len(d)), kz]
    swap = dz < 0
    kx, ky = np.where(swap, ky, kx), np.where(swap, kx, ky)
    idx = np.arange(len(d))
    s = np.stack([fmt.div(d[idx, kx], dz), fmt.div(d[idx, ky], dz), fmt.div(one, dz)], axis=1)
    lo = bounds[0].astype(np.float32)
    hi = bounds[1].astype(np.float32)
    tnear = np.zeros(len(d), np.float32)
    tfar = rays.tmax.astype(np.float32).copy()
    for a in range(3):
        with np.errstate(invalid="ignore"):
            t0 = fmt.mul(fmt.sub(lo[a], o[:, a]), inv[:, a])
            t1 = fmt.mul(fmt.sub(hi[a], o[:, a]), inv[:, a])
        # 0 * inf = NaN: d[a] = ±0 and the origin on a face plane of the box; the ray lies in
        # that plane, inside the closed slab, so this axis does not clip it
        flat = np.isnan(t0) | np.isnan(t1)
        t0 = np.where(flat, np.float32(-np.inf), t0)
        t1 = np.where(flat, np.float32(np.inf), t1)
        tnear = fmt.max(tnear, fmt.min(t0, t1))
        tfar = fmt.min(tfar, fmt.max(t0, t1))
    return RaySetup(inv, np.stack([kx, ky, kz], axis=1).astype(np.int64), s, tnear, tfar)
