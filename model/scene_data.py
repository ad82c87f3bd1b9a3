"""The scene's data (:class:`Scene`, cameras, lights, materials) and the steps every scene
loader shares: a mesh file as a piece, pieces into scene-order triangles, the automatic
camera and the default material. ``model.scene`` and ``model.scene_toml`` both build on it."""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import scene_geometry as geo

MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf", ".off")
DEFAULT_BACKGROUND = (0.1, 0.1, 0.1)


class SceneError(ValueError):
    """Bad scene input; the message names the problem, where it is, and how to fix it."""


@dataclass(frozen=True)
class Camera:
    position: np.ndarray          # (3,) float64
    look_at: np.ndarray           # (3,)
    up: np.ndarray                # (3,)
    fov_y: float                  # vertical field of view, degrees, in (0, 180)


@dataclass(frozen=True)
class Light:
    kind: str                     # "point" | "parallel"
    position: np.ndarray | None   # (3,) for point lights
    direction: np.ndarray | None  # (3,) unit vector pointing FROM the light, parallel lights
    color: np.ndarray             # (3,) linear RGB, intensity folded in


@dataclass(frozen=True)
class Material:
    diffuse: np.ndarray           # (3,)
    specular: np.ndarray          # (3,)
    shininess: float
    reflect: float                # 0..1
    texture: np.ndarray | None    # (H, W, 3) uint8, row 0 = top of the image; uv (0,0) = bottom-left
    name: str = ""


@dataclass
class Scene:
    name: str
    tris: np.ndarray              # (N, 3, 3) float32 world-space vertices A, B, C
    tri_id: np.ndarray            # (N,) int32 index in scene order (before dropping)
    n_scene_tris: int             # triangles in scene order, including dropped ones
    material: np.ndarray          # (N,) int32 index into materials
    uv: np.ndarray                # (N, 3, 2) float32
    normals: np.ndarray           # (N, 3, 3) float32 unit shading normals per vertex
    materials: list[Material]
    lights: list[Light]
    camera: Camera
    background: np.ndarray        # (3,) float64
    dropped: dict[str, int]       # {"degenerate": n, "nonfinite": 0}
    source: str

    def __len__(self) -> int:
        return len(self.tris)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounding box (lo, hi) of all kept triangles."""
        v = self.tris.reshape(-1, 3)
        return v.min(axis=0), v.max(axis=0)


# ---------------------------------------------------------------------------------------------
# mesh files
# ---------------------------------------------------------------------------------------------

def load_mesh_file(path: Path, who: str) -> geo.Piece:
    """Read a mesh with trimesh in file order; ``who`` names it in errors."""
    import trimesh
    if not path.is_file():
        raise SceneError(f"{who}: mesh file '{path}' does not exist; check the path "
                         "(TOML mesh paths are relative to the .toml file)")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise SceneError(f"{who}: '{path}' has an unsupported extension '{path.suffix}'; "
                         f"use one of {', '.join(MESH_SUFFIXES)}")
    logging.getLogger("trimesh").setLevel(logging.ERROR)
    try:
        loaded = trimesh.load_scene(str(path), process=False)
        mesh = loaded.to_mesh()
    except Exception as e:  # trimesh raises many types for corrupt files
        raise SceneError(f"{who}: cannot read mesh '{path}': {type(e).__name__}: {e}; "
                         "the file is corrupt or not a valid "
                         f"{path.suffix.lstrip('.').upper()} mesh") from e
    faces = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))), dtype=np.int64)
    verts = np.asarray(getattr(mesh, "vertices", np.zeros((0, 3))), dtype=np.float64)
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise SceneError(f"{who}: mesh '{path}' contains no triangles (empty, a point cloud or "
                         "unreadable); export it with faces")
    tris = verts[faces]
    bad = ~np.isfinite(tris).all(axis=(1, 2))
    if bad.any():
        raise SceneError(f"{who}: mesh '{path}' has {int(bad.sum())} triangles with NaN/inf "
                         f"vertices (first: face {int(np.argmax(bad))}); fix or remove them")
    uv = np.zeros((len(faces), 3, 2))
    tuv = getattr(mesh.visual, "uv", None)
    if tuv is not None and len(tuv) == len(verts):
        uv = np.nan_to_num(np.asarray(tuv, dtype=np.float64)[faces][..., :2])
    normals = None
    # trimesh keeps a file's vertex normals only on the un-concatenated geometry
    geoms = list(getattr(loaded, "geometry", {}).values())
    if len(geoms) == 1 and len(getattr(geoms[0], "vertices", ())) == len(verts):
        node = loaded.graph.nodes_geometry[0]
        if np.allclose(loaded.graph[node][0], np.eye(4)):
            vn = getattr(getattr(geoms[0], "_cache", None), "cache", {}).get("vertex_normals")
            if vn is not None and np.shape(vn) == verts.shape:
                normals = np.asarray(vn, dtype=np.float64)[faces]
    return geo.Piece(tris, uv, normals)


# ---------------------------------------------------------------------------------------------
# assembling triangles into a Scene
# ---------------------------------------------------------------------------------------------

def finish_pieces(pieces: list[tuple[geo.Piece, int, str]]) -> tuple:
    """Concatenate world-space pieces (piece, material index, label for errors), round to
    float32, check finiteness, fill missing shading normals with face normals and drop
    degenerate triangles. Returns (tris, tri_id, n_scene, material, uv, normals, n_dropped)."""
    tris64 = np.concatenate([p.tris for p, _, _ in pieces])
    with np.errstate(over="ignore", invalid="ignore"):
        tris = tris64.astype(np.float32)
    bad = ~np.isfinite(tris).all(axis=(1, 2))
    if bad.any():
        first = int(np.argmax(bad))
        starts = np.cumsum([0] + [len(p) for p, _, _ in pieces])
        k = int(np.searchsorted(starts, first, side="right")) - 1
        raise SceneError(f"{pieces[k][2]}: {int(bad.sum())} triangles with NaN/inf vertices "
                         f"(first: face {first - starts[k]}); keep coordinates finite and within "
                         "about +-1000 (check scale and translate)")
    n = len(tris)
    mat = np.concatenate([np.full(len(p), m, np.int32) for p, m, _ in pieces])
    uv = np.concatenate([p.uv for p, _, _ in pieces]).astype(np.float32)
    fn = geo.face_normals(tris)
    normals = np.concatenate([p.normals if p.normals is not None
                              else np.full((len(p), 3, 3), np.nan) for p, _, _ in pieces])
    with np.errstate(invalid="ignore", divide="ignore"):
        ln = np.linalg.norm(normals, axis=2, keepdims=True)
        ok = np.isfinite(ln) & (ln > 1e-12)
        normals = np.where(ok, normals / np.where(ok, ln, 1.0), fn[:, None, :])
    t = tris.astype(np.float64)
    repeated = ((tris[:, 0] == tris[:, 1]).all(1) | (tris[:, 1] == tris[:, 2]).all(1)
                | (tris[:, 0] == tris[:, 2]).all(1))
    zero_area = ~np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]).any(axis=1)
    keep = ~(repeated | zero_area)
    ids = np.arange(n, dtype=np.int32)[keep]
    return (tris[keep], ids, n, mat[keep], uv[keep], normals[keep].astype(np.float32),
            int((~keep).sum()))


def auto_camera(tris: np.ndarray, fov: float = 45.0) -> Camera:
    """Look at the box centre from a 3/4 view, far enough that the bounding sphere fits."""
    v = tris.reshape(-1, 3).astype(np.float64)
    lo, hi = v.min(0), v.max(0)
    centre = (lo + hi) / 2
    radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-6)
    d = np.array([0.6, 0.45, 1.0])
    d /= np.linalg.norm(d)
    dist = radius / math.sin(math.radians(fov) / 2) * 1.05
    return Camera(centre + d * dist, centre, np.array([0.0, 1.0, 0.0]), fov)


def grey_material() -> Material:
    return Material(np.array([0.7, 0.7, 0.7]), np.array([0.2, 0.2, 0.2]), 32.0, 0.0, None,
                    "default")
