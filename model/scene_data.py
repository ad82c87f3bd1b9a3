"""The scene's data (:class:`Scene`, cameras, lights, materials) and the steps every scene
loader shares: a mesh file as a piece, pieces into scene-order triangles, the automatic
camera and the default material. ``model.scene`` and ``model.scene_toml`` both build on it."""
from __future__ import annotations

import io
import logging
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import scene_geometry as geo

MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf", ".off")
DEFAULT_BACKGROUND = (0.1, 0.1, 0.1)


class SceneError(ValueError):
    """Bad scene input; the message names the problem, where it is, and how to fix it."""


class SceneWarning(UserWarning):
    """A scene that loads but probably does not show what was meant (a light on a surface, a
    camera inside a closed mesh); the message says what and how to fix it. The checks are in
    ``model.scene_checks``, the rules in ``docs/scenes.md`` ("Checks on load")."""


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
    transmit: float = 0.0         # 0..1 - reflect: the share the refracted ray carries
    ior: float = 1.0              # index of refraction (inside / outside the closed mesh)


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
        v = self.tris.reshape(-1, 3)            # one column at a time: ~20x faster than axis=0
        return (np.array([v[:, a].min() for a in range(3)], v.dtype),
                np.array([v[:, a].max() for a in range(3)], v.dtype))


# ---------------------------------------------------------------------------------------------
# mesh files
# ---------------------------------------------------------------------------------------------

def _utf8(data: bytes) -> bytes:
    """``data`` if it is valid UTF-8, else read as Latin-1 and encoded as UTF-8."""
    try:
        data.decode("utf-8")
        return data
    except UnicodeDecodeError:
        return data.decode("latin-1").encode("utf-8")


def _text_bytes(path: Path) -> bytes | None:
    """The file's bytes made valid UTF-8 where trimesh would decode them as text, or None when
    they are already (or the file is binary).

    Why not trimesh's own fallback: on a byte that is not UTF-8 it imports the optional
    ``charset_normalizer`` (not installed: the file is reported corrupt), which *guesses* an
    encoding from the first 1000 bytes and then decodes with ``errors="ignore"`` (a wrong
    guess drops or mangles bytes, silently); and a PLY header is decoded as strict UTF-8
    without any fallback. The syntax of these formats is ASCII: other bytes can only be in
    comments and names. Reading them as Latin-1 maps every byte to one character and keeps
    every ASCII byte as it is, so it cannot fail and cannot change the geometry:
    deterministic, whatever the file's real encoding, and without another dependency."""
    suffix = path.suffix.lower()
    if suffix not in (".obj", ".off", ".stl", ".ply"):
        return None                                 # glTF/GLB: JSON, UTF-8 by definition
    if suffix == ".stl":
        with open(path, "rb") as f:
            head = f.read(84)
        if len(head) == 84 and \
                path.stat().st_size == 84 + 50 * int.from_bytes(head[80:], "little"):
            return None                             # binary STL (its header is not text)
    data = path.read_bytes()
    if suffix == ".ply":
        end = data.find(b"end_header")
        if end < 0:
            return None                             # not a PLY: let trimesh report it
        end = data.find(b"\n", end)
        end = len(data) if end < 0 else end + 1
        head = data[:end]
        fixed = _utf8(head)                         # a binary body stays as it is
        return None if fixed is head else fixed + data[end:]
    fixed = _utf8(data)
    return None if fixed is data else fixed


def _obj_index_error(data: bytes, who: str, path: Path) -> SceneError | None:
    """The first face (or line) of an OBJ naming a vertex, texture coordinate or normal the
    file does not have, as a SceneError; None if every index is in range. OBJ indices count
    from 1 in file order; negative ones count back from the last element defined so far."""
    counts = {"v": 0, "vt": 0, "vn": 0}
    total = {k: len(re.findall(rb"^[ \t]*" + k.encode() + rb"[ \t]", data, re.M)) for k in counts}
    names = {"v": ("vertex", "vertices", "'v'"),
             "vt": ("texture coordinate", "texture coordinates", "'vt'"),
             "vn": ("normal", "normals", "'vn'")}
    for ln, raw in enumerate(data.decode("latin-1").split("\n"), 1):
        tok = raw.split("#", 1)[0].split()
        if not tok:
            continue
        if tok[0] in counts:
            counts[tok[0]] += 1
            continue
        if tok[0] not in ("f", "l", "p"):
            continue
        for ref in tok[1:]:
            for kind, part in zip(("v", "vt", "vn"), ref.split("/")):
                if not part:
                    continue
                try:
                    idx = int(part)
                except ValueError:
                    break                           # not a number: trimesh's own error
                n = total[kind] if idx > 0 else counts[kind]
                pos = idx if idx > 0 else n + 1 + idx
                if idx == 0 or not 1 <= pos <= n:
                    one, many, key = names[kind]
                    have = (f"has {total[kind]} {many} ({key} lines, numbered from 1)"
                            if idx > 0 else
                            f"has {counts[kind]} {many} before that line (negative indices "
                            "count back from the last one defined)")
                    if idx == 0:
                        have = f"numbers {many} from 1, not 0"
                    return SceneError(
                        f"{who}: mesh '{path}' line {ln}: '{raw.strip()}' names {one} {idx}, "
                        f"which does not exist: the file {have}; fix the index or add the "
                        f"missing {many}")
    return None


class _TextResolver:
    """trimesh's file resolver for the OBJ's neighbours (``mtllib``, textures); material
    libraries are made valid UTF-8 as the OBJ itself (:func:`_text_bytes`)."""

    def __init__(self, path: Path):
        import trimesh
        self._inner = trimesh.resolvers.FilePathResolver(str(path))

    def __getattr__(self, name):
        return getattr(self._inner, name)

    def get(self, name: str):
        data = self._inner.get(name)
        return _utf8(data) if str(name).lower().endswith(".mtl") else data


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
    text = None
    try:
        text = _text_bytes(path)
        if text is None:
            loaded = trimesh.load_scene(str(path), process=False)
        else:
            loaded = trimesh.load_scene(io.BytesIO(text), file_type=path.suffix.lower()[1:],
                                        resolver=_TextResolver(path), process=False)
        mesh = loaded.to_mesh()
    except Exception as e:  # trimesh raises many types for corrupt files
        if isinstance(e, IndexError) and path.suffix.lower() == ".obj":
            bad = _obj_index_error(text if text is not None else path.read_bytes(), who, path)
            if bad is not None:
                raise bad from None
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
    radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-300)   # > 0 (a floor of 1e-6 put the
    # camera of a mesh smaller than that so far away that the mesh was not even one pixel)
    d = np.array([0.6, 0.45, 1.0])
    d /= np.linalg.norm(d)
    dist = radius / math.sin(math.radians(fov) / 2) * 1.05
    return Camera(centre + d * dist, centre, np.array([0.0, 1.0, 0.0]), fov)


def grey_material() -> Material:
    return Material(np.array([0.7, 0.7, 0.7]), np.array([0.2, 0.2, 0.2]), 32.0, 0.0, None,
                    "default")
