"""Procedural primitives, transforms and per-corner attributes for the scene loader.

Every builder returns a :class:`Piece`: triangles as per-corner arrays (no shared vertices), so
texture coordinates and shading normals can differ per corner. Conventions: y is up, every
primitive is centred on the origin in x and z, triangles are counter-clockwise seen from
outside (face normal ``(B - A) x (C - A)`` points out). Pure NumPy (float64), deterministic:
the terrain noise is an integer hash, not a random generator, so it never changes with the
NumPy version.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh


@dataclass
class Piece:
    """Triangles of one primitive in its local frame (float64, per corner)."""
    tris: np.ndarray                 # (n, 3, 3)
    uv: np.ndarray                   # (n, 3, 2)
    normals: np.ndarray | None       # (n, 3, 3) shading normals, or None: use face normals

    def __len__(self) -> int:
        return len(self.tris)


def face_normals(tris: np.ndarray) -> np.ndarray:
    """Unit face normals (B - A) x (C - A) in float64; zero vectors for degenerate triangles."""
    t = tris.astype(np.float64)
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    ln = np.linalg.norm(n, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(ln > 0, n / np.where(ln > 0, ln, 1.0), 0.0)


def _box_uv(tris: np.ndarray) -> np.ndarray:
    """Planar UVs per triangle, projected along the dominant axis of its face normal and
    scaled to the piece's bounding box (0..1 on every face of a box)."""
    lo = tris.reshape(-1, 3).min(axis=0)
    ext = tris.reshape(-1, 3).max(axis=0) - lo
    ext = np.where(ext > 0, ext, 1.0)
    rel = (tris - lo) / ext                                       # (n, 3, 3) in 0..1
    axis = np.abs(face_normals(tris)).argmax(axis=1)              # projection axis per face
    u_ax = np.array([2, 0, 0])[axis]                              # x-faces: (z, y); y: (x, z)
    v_ax = np.array([1, 2, 1])[axis]                              # z-faces: (x, y)
    idx = np.arange(len(tris))[:, None]
    return np.stack([rel[idx, np.arange(3)[None, :], u_ax[:, None]],
                     rel[idx, np.arange(3)[None, :], v_ax[:, None]]], axis=-1)


def _flip(piece: Piece) -> Piece:
    """Reverse winding (inside-out) and shading normals."""
    tris = piece.tris[:, ::-1].copy()
    uv = piece.uv[:, ::-1].copy()
    normals = None if piece.normals is None else -piece.normals[:, ::-1]
    return Piece(tris, uv, normals)


def box(size, inward: bool = False) -> Piece:
    """Axis-aligned box of extents ``size`` (12 triangles), flat normals, per-face planar UVs.
    ``inward``: faces point into the box (a room seen from inside)."""
    m = trimesh.creation.box(extents=np.asarray(size, dtype=np.float64))
    tris = np.asarray(m.vertices, dtype=np.float64)[np.asarray(m.faces)]
    p = Piece(tris, _box_uv(tris), None)
    return _flip(p) if inward else p


def sphere(radius: float, subdivisions: int, inward: bool = False) -> Piece:
    """Icosphere (20 * 4**subdivisions triangles), smooth normals, spherical UVs."""
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    unit = np.asarray(m.vertices, dtype=np.float64)
    unit /= np.linalg.norm(unit, axis=1, keepdims=True)
    corners = unit[np.asarray(m.faces)]                            # (n, 3, 3)
    u = 0.5 + np.arctan2(corners[..., 2], corners[..., 0]) / (2 * np.pi)
    v = 0.5 + np.arcsin(np.clip(corners[..., 1], -1.0, 1.0)) / np.pi
    p = Piece(corners * radius, np.stack([u, v], axis=-1), corners.copy())
    return _flip(p) if inward else p


def _grid(nx: int, nz: int, x: np.ndarray, y: np.ndarray, z: np.ndarray,
          normals: np.ndarray | None) -> Piece:
    """Triangulate a (nz+1, nx+1) vertex grid (two triangles per cell, facing +y when y is
    flat); UVs are planar: u along x, v along z, 0..1 over the grid."""
    P = np.stack([x, y, z], axis=-1)                               # (nz+1, nx+1, 3)
    U, V = np.meshgrid(np.linspace(0, 1, nx + 1), np.linspace(0, 1, nz + 1))
    UV = np.stack([U, V], axis=-1)
    j, i = np.meshgrid(np.arange(nz), np.arange(nx), indexing="ij")
    j, i = j.ravel(), i.ravel()
    # cell corners: (j, i) -> (j+1, i) -> (j, i+1) and (j, i+1) -> (j+1, i) -> (j+1, i+1)
    cj = np.stack([np.stack([j, j + 1, j], 1), np.stack([j, j + 1, j + 1], 1)], 1).reshape(-1, 3)
    ci = np.stack([np.stack([i, i, i + 1], 1), np.stack([i + 1, i, i + 1], 1)], 1).reshape(-1, 3)
    return Piece(P[cj, ci], UV[cj, ci], None if normals is None else normals[cj, ci])


def plane(size, segments) -> Piece:
    """Flat rectangle in the xz plane (y = 0) facing +y, ``size = (w, d)``, split into
    ``segments = (nx, nz)`` cells of two triangles; planar UVs."""
    w, d = size
    nx, nz = segments
    X, Z = np.meshgrid(np.linspace(-w / 2, w / 2, nx + 1), np.linspace(-d / 2, d / 2, nz + 1))
    return _grid(nx, nz, X, np.zeros_like(X), Z, None)


def cylinder(radius: float, height: float, sections: int) -> Piece:
    """Capped cylinder along y (4 * sections triangles), smooth sides, flat caps, box UVs."""
    m = trimesh.creation.cylinder(radius=radius, height=height, sections=sections)
    v = np.asarray(m.vertices, dtype=np.float64)
    v = np.stack([v[:, 0], v[:, 2], -v[:, 1]], axis=1)             # z axis -> y axis (rotation)
    tris = v[np.asarray(m.faces)]
    fn = face_normals(tris)
    radial = tris.copy()
    radial[..., 1] = 0.0
    ln = np.linalg.norm(radial, axis=-1, keepdims=True)
    radial = np.where(ln > 0, radial / np.where(ln > 0, ln, 1.0), 0.0)
    cap = np.abs(fn[:, 1]) > 0.5
    normals = np.where(cap[:, None, None], fn[:, None, :], radial)
    return Piece(tris, _box_uv(tris), normals)


def _hash01(ix: np.ndarray, iz: np.ndarray, seed: int) -> np.ndarray:
    """Deterministic lattice hash -> [0, 1) (splitmix64-style finaliser)."""
    h = (ix.astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)
         ^ iz.astype(np.uint64) * np.uint64(0xC2B2AE3D27D4EB4F)
         ^ np.full(ix.shape, (seed * 0x165667B19E3779F9) & 0xFFFFFFFFFFFFFFFF, np.uint64))
    h ^= h >> np.uint64(33)
    h *= np.uint64(0xFF51AFD7ED558CCD)
    h ^= h >> np.uint64(33)
    h *= np.uint64(0xC4CEB9FE1A85EC53)
    h ^= h >> np.uint64(33)
    return (h >> np.uint64(11)).astype(np.float64) * 2.0 ** -53


def fbm(x: np.ndarray, z: np.ndarray, seed: int, octaves: int) -> np.ndarray:
    """Fractal value noise in [0, 1]: ``octaves`` layers of smoothstep-interpolated lattice
    noise, each at twice the frequency and half the amplitude of the last. x, z >= 0."""
    total = np.zeros_like(x)
    norm = 0.0
    for o in range(octaves):
        f, a = 2.0 ** o, 0.5 ** o
        fx, fz = x * f, z * f
        ix, iz = np.floor(fx).astype(np.int64), np.floor(fz).astype(np.int64)
        tx, tz = fx - ix, fz - iz
        tx, tz = tx * tx * (3 - 2 * tx), tz * tz * (3 - 2 * tz)
        s = seed + 7919 * o
        n00, n10 = _hash01(ix, iz, s), _hash01(ix + 1, iz, s)
        n01, n11 = _hash01(ix, iz + 1, s), _hash01(ix + 1, iz + 1, s)
        total += a * ((n00 * (1 - tx) + n10 * tx) * (1 - tz) + (n01 * (1 - tx) + n11 * tx) * tz)
        norm += a
    return total / norm


def terrain(size, resolution, height: float, seed: int, octaves: int, features: float,
            flatten) -> Piece:
    """Height field over ``size = (w, d)`` centred on the origin, ``resolution = (nx, nz)`` cells
    (2 * nx * nz triangles), heights ``height * fbm`` in [0, height] with ``features`` base
    noise cells across the terrain; smooth normals from central differences, planar UVs.
    ``flatten = (cx, cz, r)`` levels a disc of radius r (blending out to 2r) to the height at
    its centre and shifts the whole terrain so that disc lies at y = 0 (a building site);
    ``None`` leaves the terrain as it is."""
    w, d = size
    nx, nz = resolution
    xs, zs = np.linspace(-w / 2, w / 2, nx + 1), np.linspace(-d / 2, d / 2, nz + 1)
    X, Z = np.meshgrid(xs, zs)
    scale = features / max(w, d)
    def hfield(x, z):
        return height * fbm((x + w / 2) * scale + 0.5, (z + d / 2) * scale + 0.5, seed, octaves)
    H = hfield(X, Z)
    if flatten is not None:
        cx, cz, r = flatten
        h0 = hfield(np.array([cx]), np.array([cz]))[0]
        dist = np.hypot(X - cx, Z - cz)
        t = np.clip((dist - r) / r, 0.0, 1.0)
        t = t * t * (3 - 2 * t)
        H = h0 * (1 - t) + H * t - h0
    dhdx = np.gradient(H, xs, axis=1)
    dhdz = np.gradient(H, zs, axis=0)
    N = np.stack([-dhdx, np.ones_like(H), -dhdz], axis=-1)
    N /= np.linalg.norm(N, axis=-1, keepdims=True)
    return _grid(nx, nz, X, H, Z, N)


def wall(size, thickness: float, windows, window_size) -> Piece:
    """Wall slab in the xy plane from y = 0 to h, x centred, z from -t/2 to t/2, with a grid of
    ``windows = (cols, rows)`` rectangular holes of ``window_size = (ww, wh)``, each centred in
    its cell; built from boxes (12 triangles each)."""
    w, h = size
    cols, rows = windows
    ww, wh = window_size
    boxes = []                                                      # (x0, x1, y0, y1)
    if cols == 0 or rows == 0:
        boxes.append((-w / 2, w / 2, 0.0, h))
    else:
        cw, ch = w / cols, h / rows
        ys = [0.0]
        for r in range(rows):
            yc = (r + 0.5) * ch
            ys += [yc - wh / 2, yc + wh / 2]
        ys.append(h)
        for k in range(0, len(ys), 2):                              # horizontal bands
            boxes.append((-w / 2, w / 2, ys[k], ys[k + 1]))
        for r in range(rows):                                       # piers between windows
            y0, y1 = ys[2 * r + 1], ys[2 * r + 2]
            xs = [-w / 2]
            for c in range(cols):
                xc = -w / 2 + (c + 0.5) * cw
                xs += [xc - ww / 2, xc + ww / 2]
            xs.append(w / 2)
            for k in range(0, len(xs), 2):
                boxes.append((xs[k], xs[k + 1], y0, y1))
    parts = []
    for x0, x1, y0, y1 in boxes:
        if x1 - x0 <= 0 or y1 - y0 <= 0:
            continue
        p = box((x1 - x0, y1 - y0, thickness))
        p.tris += np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
        parts.append(p)
    tris = np.concatenate([p.tris for p in parts])
    return Piece(tris, _box_uv(tris), None)


# ---------------------------------------------------------------------------------------------
# transforms
# ---------------------------------------------------------------------------------------------

def trs(translate=(0.0, 0.0, 0.0), rotate=(0.0, 0.0, 0.0), scale=(1.0, 1.0, 1.0)) -> np.ndarray:
    """4x4 matrix T * Rz * Ry * Rx * S: scale first, then rotate about x, then y, then z (degrees,
    right-handed), then translate."""
    ax, ay, az = np.radians(np.asarray(rotate, dtype=np.float64))
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    M = np.eye(4)
    M[:3, :3] = Rz @ Ry @ Rx @ np.diag(np.asarray(scale, dtype=np.float64))
    M[:3, 3] = translate
    return M


def transform(piece: Piece, M: np.ndarray) -> Piece:
    """Apply a 4x4 affine matrix (positive scales only) to vertices and shading normals."""
    L, t = M[:3, :3], M[:3, 3]
    tris = piece.tris @ L.T + t
    normals = None
    if piece.normals is not None:
        n = piece.normals @ np.linalg.inv(L)                        # inverse transpose
        ln = np.linalg.norm(n, axis=-1, keepdims=True)
        normals = np.where(ln > 0, n / np.where(ln > 0, ln, 1.0), 0.0)
    return Piece(tris, piece.uv, normals)
