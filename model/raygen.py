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

The per-ray arithmetic of both is ``model/rgs/eye.py``'s kernels (the RTL's operation order,
``docs/rgs.md``); this module is the host side around them (camera, packets, arrays).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .config import Config
from .fp import FPFormat
from .raykind import RayKind
from .rgs import eye_packets, packet_count, setup_rays


@dataclass
class Rays:
    """Rays in packet order: packet p holds rays ``pk_start[p]:pk_start[p+1]`` (lanes 0..n-1)."""
    org: np.ndarray              # (N, 3) float32 format values
    dir: np.ndarray              # (N, 3) float32 format values
    tmax: np.ndarray             # (N,) float32 (inf for eye rays)
    kind: np.ndarray             # (N,) uint8: the ray's RayKind
    pixel: np.ndarray            # (N,) int32: y * width + x of the pixel the ray contributes to
    pk_start: np.ndarray         # (P + 1,) int64
    anyhit: np.ndarray = field(default=None)   # (N,) bool: any hit ends the ray (shadow rays)
    # the ray's id in its frame (what the chip reports): the eye ray it descends from (index in
    # eye-ray order), its depth (reflections before it), for a shadow ray its light and its
    # path: bit i set where the ray's ancestor (or itself) of depth i + 1 is a refracted ray
    # (not a reflection), so that rays of one eye ray and depth differ
    eye: np.ndarray = field(default=None)      # (N,) int64; default: the ray's own index
    depth: np.ndarray = field(default=None)    # (N,) uint8; default 0
    light: np.ndarray = field(default=None)    # (N,) int16: light index, -1 for no shadow ray
    path: np.ndarray = field(default=None)     # (N,) uint16; default 0

    def __post_init__(self):
        n = self.org.shape[0]
        if self.anyhit is None:
            self.anyhit = self.kind == RayKind.SHADOW
        if self.eye is None:
            self.eye = np.arange(n, dtype=np.int64)
        if self.depth is None:
            self.depth = np.zeros(n, np.uint8)
        if self.light is None:
            self.light = np.full(n, -1, np.int16)
        if self.path is None:
            self.path = np.zeros(n, np.uint16)

    def __len__(self) -> int:
        return self.org.shape[0]

    @property
    def n_packets(self) -> int:
        return self.pk_start.shape[0] - 1

    @staticmethod
    def from_arrays(org, dirn, tmax=None, *, packet: int = 64, kind: int = RayKind.EYE,
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
                    np.concatenate([p.anyhit for p in parts]),
                    np.concatenate([p.eye for p in parts]),
                    np.concatenate([p.depth for p in parts]),
                    np.concatenate([p.light for p in parts]),
                    np.concatenate([p.path for p in parts]))


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


def camera_registers(camera, width: int, height: int, cfg: Config):
    """Host side: the camera registers of the RGS slave (``rtl/rgs/eye.py`` ``EyeRays``) for a
    ``width x height`` image: ``pos``, ``corner``, ``dx``, ``dy`` (float32 format values),
    :func:`camera_basis` of the sample image (``cfg.oversampling`` times the size) quantized."""
    n = cfg.oversampling
    basis = camera_basis(camera.position, camera.look_at, camera.up, camera.fov_y,
                         width * n, height * n)
    return tuple(cfg.fmt.quantize(v) for v in basis)


def eye_rays(camera, width: int, height: int, cfg: Config) -> Rays:
    """Eye rays for a ``width x height`` image with ``cfg.oversampling``² rays per pixel, made
    by ``model.rgs.eye_packets`` (the RTL's ``EyeRays``) from :func:`camera_registers`."""
    fmt = cfg.fmt
    n = cfg.oversampling
    sw, sh = width * n, height * n
    pos, corner, dx, dy = camera_registers(camera, width, height, cfg)
    tw, th = cfg.tile_w, cfg.tile_h
    total = sw * sh
    d = np.empty((total, 3), np.float32)
    pixel = np.empty(total, np.int32)
    pk_start = np.empty(packet_count(sw, sh, tw, th) + 1, np.int64)
    eye_packets(sw, sh, tw, th, n, width, corner, dx, dy, d, pixel, pk_start, *fmt.em)
    org = np.empty((total, 3), np.float32)
    for a in range(3):                  # by column: a few times faster than broadcasting a row
        org[:, a] = pos[a]
    return Rays(org, d, np.full(total, np.inf, np.float32), np.zeros(total, np.uint8),
                pixel, pk_start)


@dataclass
class RaySetup:
    """Read-only per-ray data broadcast to the RTC units, and the initial interval."""
    inv: np.ndarray      # (N, 3) float32: 1 / dir
    k: np.ndarray        # (N, 3) int64: kx, ky, kz
    s: np.ndarray        # (N, 3) float32: Sx, Sy, Sz
    tnear: np.ndarray    # (N,) float32
    tfar: np.ndarray     # (N,) float32
    octant: np.ndarray = None   # (N,) int64: direction sign bits x | y << 1 | z << 2


def setup(rays: Rays, bounds: np.ndarray, fmt: FPFormat, box_cull: bool = True) -> RaySetup:
    """Ray setup in the format's arithmetic: ``model.rgs.ray_setup`` on every ray (the RTL's
    ``RaySetupPipe``; steps in ``model/rgs/eye.py`` and ``docs/rgs.md``).

    A ray whose interval clipped to the scene box is empty (``not tnear <= tfar``) starts
    inactive: it never enters traversal (the box cull). ``box_cull=False`` is the setup without
    the cull, only to measure what it saves: such a ray gets its unclipped interval
    ``[0, tmax]`` and goes through traversal like any other; the rays that meet the box keep
    their clipped interval (the RTL: the slaves' ``box_cull`` register, ``rtl.rgs.eye._ray_out``)."""
    n = len(rays)
    inv = np.empty((n, 3), np.float32)
    s = np.empty((n, 3), np.float32)
    k = np.empty((n, 3), np.int64)
    tnear = np.empty(n, np.float32)
    tfar = np.empty(n, np.float32)
    octant = np.empty(n, np.int64)
    b = np.asarray(bounds, np.float32)
    setup_rays(np.ascontiguousarray(rays.org, np.float32),
               np.ascontiguousarray(rays.dir, np.float32),
               np.ascontiguousarray(rays.tmax, np.float32), b[0].copy(), b[1].copy(),
               inv, k, s, tnear, tfar, octant, *fmt.em)
    if not box_cull:
        miss = box_misses(tnear, tfar)
        tnear[miss] = 0.0
        tfar[miss] = fmt.quantize(rays.tmax[miss].astype(np.float64))
    return RaySetup(inv, k, s, tnear, tfar, octant)


def box_misses(tnear: np.ndarray, tfar: np.ndarray) -> np.ndarray:
    """The rays the box cull stops: an empty (or NaN) clipped interval, the traversal's
    ``not tnear <= tfar`` (``model.traversal.start_packet``)."""
    return ~(tnear <= tfar)


def live_packets(rays: Rays, rs: RaySetup) -> np.ndarray:
    """Per packet: does any of its rays meet the scene box? A packet with none does no
    traversal step; an RGS that skips empty tiles need not send it at all."""
    live = (~box_misses(rs.tnear, rs.tfar)).astype(np.int64)
    counts = np.add.reduceat(live, rays.pk_start[:-1]) if len(rays) else np.zeros(0, np.int64)
    return (counts > 0) & (np.diff(rays.pk_start) > 0)


def select_packets(rays: Rays, keep: np.ndarray) -> tuple[Rays, np.ndarray]:
    """The packets ``keep`` (bool per packet) of ``rays``, in order; also the indices of their
    rays in ``rays``."""
    keep = np.asarray(keep, bool)
    sizes = np.diff(rays.pk_start)
    idx = np.flatnonzero(np.repeat(keep, sizes))
    pk = np.r_[0, np.cumsum(sizes[keep])].astype(np.int64)
    sub = Rays(rays.org[idx], rays.dir[idx], rays.tmax[idx], rays.kind[idx], rays.pixel[idx],
               pk, rays.anyhit[idx], rays.eye[idx], rays.depth[idx], rays.light[idx],
               rays.path[idx])
    return sub, idx
