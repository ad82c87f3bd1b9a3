"""TOML scene descriptions -> :class:`model.scene.Scene` (format: ``docs/scenes.md``).

Every key is checked where it is read: unknown keys are reported by name with the allowed
ones, values by type and range, each error prefixed with the file and the table it is in
(``scenes/x.toml: object 3 'chair' > part 2: ...``).
"""
from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np

from . import scene_geometry as geo
from .scene_data import (DEFAULT_BACKGROUND, Camera, Light, Material, Scene, SceneError,
                         auto_camera, finish_pieces, grey_material, load_mesh_file)

TOP_KEYS = ("name", "background", "camera", "light", "material", "object", "base")
# what a scene with ``base = "other.toml"`` may set itself: the view and the lighting
VIEW_KEYS = ("name", "background", "camera", "light", "base")
CAMERA_KEYS = ("position", "look_at", "up", "fov")
LIGHT_KEYS = {"point": ("kind", "position", "color", "intensity"),
              "parallel": ("kind", "direction", "color", "intensity")}
MATERIAL_KEYS = ("name", "diffuse", "specular", "shininess", "reflect", "transmit", "ior",
                 "texture", "checker")
TRANSFORM_KEYS = ("translate", "rotate", "scale")
SHAPES = {  # primitive -> allowed keys of its table
    "box": ("size", "inward"),
    "sphere": ("radius", "subdivisions", "inward"),
    "plane": ("size", "segments"),
    "quad": ("size", "segments"),
    "cylinder": ("radius", "height", "sections"),
    "terrain": ("size", "resolution", "height", "seed", "octaves", "features", "flatten"),
    "wall": ("size", "thickness", "windows", "window_size"),
}
GEOMETRY_KEYS = ("mesh", *SHAPES, "part")
OBJECT_KEYS = ("name", "material", "transform", "instances", *GEOMETRY_KEYS)
MAX_PART_DEPTH = 8


# ---------------------------------------------------------------------------------------------
# typed access with located errors
# ---------------------------------------------------------------------------------------------

class _Reader:
    """Reads one TOML table; ``where`` says where it is for error messages."""

    def __init__(self, tbl, where: str, allowed, kind: str = "table"):
        if not isinstance(tbl, dict):
            raise SceneError(f"{where}: expected a {kind} (key = value pairs), got "
                             f"{type(tbl).__name__} {tbl!r}")
        unknown = [k for k in tbl if k not in allowed]
        if unknown:
            raise SceneError(f"{where}: unknown key{'s' if len(unknown) > 1 else ''} "
                             f"{', '.join(repr(k) for k in unknown)}; allowed keys: "
                             f"{', '.join(allowed)}")
        self.tbl, self.where = tbl, where

    def has(self, key: str) -> bool:
        return key in self.tbl

    def err(self, key: str, msg: str) -> SceneError:
        return SceneError(f"{self.where}: '{key}' {msg}")

    def num(self, key, default=None, lo=None, hi=None, lo_open=False, hi_open=False) -> float:
        if key not in self.tbl:
            if default is None:
                raise self.err(key, "is missing; add it (a number)")
            return float(default)
        v = self.tbl[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise self.err(key, f"must be a finite number, got {v!r}")
        v = float(v)
        if lo is not None and (v < lo or (lo_open and v == lo)):
            raise self.err(key, f"must be {'>' if lo_open else '>='} {lo:g}, got {v:g}")
        if hi is not None and (v > hi or (hi_open and v == hi)):
            raise self.err(key, f"must be {'<' if hi_open else '<='} {hi:g}, got {v:g}")
        return v

    def int(self, key, default=None, lo=None, hi=None) -> int:
        if key not in self.tbl:
            if default is None:
                raise self.err(key, "is missing; add it (an integer)")
            return int(default)
        v = self.tbl[key]
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.err(key, f"must be an integer, got {v!r}")
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            raise self.err(key, f"must be in {lo}..{hi}, got {v}")
        return v

    def vec(self, key, n=3, default=None, lo=None, positive=False, allow_scalar=False):
        if key not in self.tbl:
            if default is None:
                raise self.err(key, f"is missing; add it (a list of {n} numbers)")
            return np.array(default, dtype=np.float64)
        v = self.tbl[key]
        if allow_scalar and isinstance(v, (int, float)) and not isinstance(v, bool):
            v = [v] * n
        if (not isinstance(v, list) or len(v) != n
                or any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in v)
                or not all(math.isfinite(x) for x in v)):
            extra = " (or one number)" if allow_scalar else ""
            raise self.err(key, f"must be a list of {n} finite numbers{extra}, got {v!r}")
        a = np.array(v, dtype=np.float64)
        if positive and (a <= 0).any():
            raise self.err(key, f"must be > 0 (negative or zero sizes/scales are not allowed: "
                                f"rotate instead of mirroring), got {v!r}")
        if lo is not None and (a < lo).any():
            raise self.err(key, f"must be >= {lo:g} in every component, got {v!r}")
        return a

    def ivec(self, key, n, default, lo=1, hi=4096, allow_scalar=True) -> tuple[int, ...]:
        v = self.tbl.get(key, default)
        if allow_scalar and isinstance(v, int) and not isinstance(v, bool):
            v = [v] * n
        if (not isinstance(v, list) or len(v) != n
                or any(isinstance(x, bool) or not isinstance(x, int) for x in v)
                or any(x < lo or x > hi for x in v)):
            raise self.err(key, f"must be {n} integers in {lo}..{hi} (or one), got {v!r}")
        return tuple(v)

    def str(self, key, default=None) -> str:
        if key not in self.tbl:
            if default is None:
                raise self.err(key, "is missing; add it (a string)")
            return default
        v = self.tbl[key]
        if not isinstance(v, str) or not v:
            raise self.err(key, f"must be a non-empty string, got {v!r}")
        return v

    def bool(self, key, default=False) -> bool:
        v = self.tbl.get(key, default)
        if not isinstance(v, bool):
            raise self.err(key, f"must be true or false, got {v!r}")
        return v

    def list_of_tables(self, key) -> list:
        v = self.tbl.get(key, [])
        if isinstance(v, dict):
            v = [v]
        if not isinstance(v, list):
            raise self.err(key, f"must be a list of tables ([[{key}]] or [{{...}}, ...]), "
                                f"got {v!r}")
        return v


# ---------------------------------------------------------------------------------------------
# sections
# ---------------------------------------------------------------------------------------------

def _camera(tbl, where: str) -> Camera:
    r = _Reader(tbl, where, CAMERA_KEYS)
    pos, look = r.vec("position"), r.vec("look_at")
    up = r.vec("up", default=(0.0, 1.0, 0.0))
    fov = r.num("fov", default=45.0, lo=0.0, hi=180.0, lo_open=True, hi_open=True)
    view = look - pos
    if not np.linalg.norm(view) > 0:
        raise SceneError(f"{where}: look_at equals position {pos.tolist()}; the camera must "
                         "look somewhere else")
    if not np.linalg.norm(up) > 0:
        raise SceneError(f"{where}: 'up' is the zero vector; use e.g. [0, 1, 0]")
    s = np.linalg.norm(np.cross(view / np.linalg.norm(view), up / np.linalg.norm(up)))
    if s < 1e-6:
        raise SceneError(f"{where}: 'up' {up.tolist()} is parallel to the view direction "
                         f"{view.tolist()}; choose an up vector across the view (e.g. "
                         "[0, 1, 0] unless looking straight up or down)")
    return Camera(pos, look, up, fov)


def _light(tbl, where: str) -> Light:
    if not isinstance(tbl, dict):
        raise SceneError(f"{where}: expected a table, got {tbl!r}")
    kind = tbl.get("kind")
    if kind not in LIGHT_KEYS:
        raise SceneError(f"{where}: 'kind' must be \"point\" or \"parallel\", got {kind!r}")
    r = _Reader(tbl, where, LIGHT_KEYS[kind])
    color = r.vec("color", default=(1.0, 1.0, 1.0), lo=0.0) * r.num("intensity", 1.0, lo=0.0)
    if kind == "point":
        return Light("point", r.vec("position"), None, color)
    d = r.vec("direction")
    if not np.linalg.norm(d) > 0:
        raise SceneError(f"{where}: 'direction' is the zero vector; give the direction the "
                         "light travels in, e.g. [-1, -2, -1] for a sun high in the sky")
    return Light("parallel", None, d / np.linalg.norm(d), color)


def _checker(spec, r: _Reader) -> np.ndarray:
    if (not isinstance(spec, list) or len(spec) != 3 or isinstance(spec[0], bool)
            or not isinstance(spec[0], int) or not 1 <= spec[0] <= 256):
        raise r.err("checker", f"must be [n, color1, color2] with n an integer in 1..256 "
                               f"checks per side, got {spec!r}")
    cols = []
    for c in spec[1:]:
        cr = _Reader({"color": c}, r.where, ("color",))
        cols.append(cr.vec("color", lo=0.0))
    n = spec[0]
    px = max(2, 256 // n)
    idx = (np.arange(n * px) // px)
    parity = (idx[:, None] + idx[None, :]) % 2
    pal = np.round(np.clip(np.stack(cols), 0.0, 1.0) * 255).astype(np.uint8)
    return pal[parity]


def _material(tbl, where: str, base: Path) -> Material:
    r = _Reader(tbl, where, MATERIAL_KEYS)
    name = r.str("name")
    tex = None
    if r.has("texture") and r.has("checker"):
        raise SceneError(f"{where}: give either 'texture' or 'checker', not both")
    if r.has("texture"):
        tpath = base / r.str("texture")
        from PIL import Image
        try:
            with Image.open(tpath) as im:
                tex = np.asarray(im.convert("RGB"), dtype=np.uint8).copy()
        except FileNotFoundError:
            raise SceneError(f"{where}: texture '{tpath}' does not exist; paths are relative "
                             "to the .toml file") from None
        except Exception as e:
            raise SceneError(f"{where}: cannot read texture '{tpath}': {e}; use a PNG or JPEG "
                             "image") from e
    elif r.has("checker"):
        tex = _checker(r.tbl["checker"], r)
    reflect = r.num("reflect", 0.0, lo=0.0, hi=1.0)
    transmit = r.num("transmit", 0.0, lo=0.0, hi=1.0 - reflect)
    ior = r.num("ior", 1.0, lo=0.25, hi=4.0)
    return Material(r.vec("diffuse", default=(0.8, 0.8, 0.8), lo=0.0),
                    r.vec("specular", default=(0.0, 0.0, 0.0), lo=0.0),
                    r.num("shininess", 32.0, lo=0.0), reflect, tex, name, transmit, ior)


def _transform(tbl, where: str) -> np.ndarray:
    r = _Reader(tbl, where, TRANSFORM_KEYS)
    return geo.trs(r.vec("translate", default=(0, 0, 0)), r.vec("rotate", default=(0, 0, 0)),
                   r.vec("scale", default=(1, 1, 1), positive=True, allow_scalar=True))


def _shape(kind: str, tbl, where: str) -> geo.Piece:
    r = _Reader(tbl, f"{where} > {kind}", SHAPES[kind])
    if kind == "box":
        return geo.box(r.vec("size", default=(1, 1, 1), positive=True, allow_scalar=True),
                       r.bool("inward"))
    if kind == "sphere":
        return geo.sphere(r.num("radius", 1.0, lo=0.0, lo_open=True),
                          r.int("subdivisions", 2, lo=0, hi=6), r.bool("inward"))
    if kind in ("plane", "quad"):
        return geo.plane(r.vec("size", 2, default=(1, 1), positive=True),
                         r.ivec("segments", 2, 1))
    if kind == "cylinder":
        return geo.cylinder(r.num("radius", 0.5, lo=0.0, lo_open=True),
                            r.num("height", 1.0, lo=0.0, lo_open=True),
                            r.int("sections", 16, lo=3, hi=1024))
    if kind == "terrain":
        flatten = r.vec("flatten", 3) if r.has("flatten") else None
        if flatten is not None and flatten[2] <= 0:
            raise r.err("flatten", f"radius (third value) must be > 0, got {flatten[2]:g}")
        return geo.terrain(r.vec("size", 2, default=(100, 100), positive=True),
                           r.ivec("resolution", 2, 64, hi=2048),
                           r.num("height", 10.0, lo=0.0), r.int("seed", 0, lo=0, hi=2**31),
                           r.int("octaves", 5, lo=1, hi=12),
                           r.num("features", 4.0, lo=0.0, lo_open=True), flatten)
    # wall
    size = r.vec("size", 2, positive=True)
    windows = r.ivec("windows", 2, 0, lo=0)
    wsize = r.vec("window_size", 2, default=(1, 1), positive=True)
    if windows[0] and windows[1]:
        cw, ch = size[0] / windows[0], size[1] / windows[1]
        if wsize[0] >= cw or wsize[1] >= ch:
            raise r.err("window_size", f"{wsize.tolist()} does not fit {windows[0]}x"
                                       f"{windows[1]} windows in a {size.tolist()} wall (each "
                                       f"cell is {cw:g} x {ch:g}); use smaller windows or fewer")
    return geo.wall(size, r.num("thickness", 0.2, lo=0.0, lo_open=True), windows, wsize)


class _Builder:
    def __init__(self, path: Path, materials: list[Material]):
        self.path, self.base = path, path.parent
        self.materials = materials
        self.index = {m.name: i for i, m in enumerate(materials)}
        self.pieces: list[tuple[geo.Piece, int, str]] = []

    def material_index(self, name: str, where: str) -> int:
        if name not in self.index:
            have = ", ".join(repr(k) for k in self.index if k != "default") or "none defined"
            raise SceneError(f"{where}: unknown material {name!r}; define it in a [[material]] "
                             f"table (materials: {have})")
        return self.index[name]

    def default_material(self) -> int:
        if "default" not in self.index:
            self.index["default"] = len(self.materials)
            self.materials.append(grey_material())
        return self.index["default"]

    def object(self, tbl, where: str, parent: np.ndarray, mat: int | None, depth: int) -> None:
        r = _Reader(tbl, where, OBJECT_KEYS)
        if r.has("name"):
            where = f"{where} '{r.str('name')}'"
        geoms = [k for k in GEOMETRY_KEYS if r.has(k)]
        if len(geoms) != 1:
            raise SceneError(f"{where}: needs exactly one geometry key (one of "
                             f"{', '.join(GEOMETRY_KEYS)}), got "
                             f"{', '.join(geoms) if geoms else 'none'}")
        if r.has("material"):
            mat = self.material_index(r.str("material"), where)
        local = _transform(r.tbl["transform"], f"{where} > transform") \
            if r.has("transform") else np.eye(4)
        if r.has("instances"):
            insts = r.list_of_tables("instances")
            if not insts:
                raise r.err("instances", "is an empty list; remove it or give transforms")
            mats = [_transform(t, f"{where} > instance {i}") for i, t in enumerate(insts)]
        else:
            mats = [np.eye(4)]
        kind = geoms[0]
        piece = None
        if kind == "mesh":
            piece = load_mesh_file(self.base / r.str("mesh"), where)
        elif kind != "part":
            piece = _shape(kind, r.tbl[kind], where)
        else:
            if depth >= MAX_PART_DEPTH:
                raise SceneError(f"{where}: parts nested deeper than {MAX_PART_DEPTH}")
            parts = r.list_of_tables("part")
            if not parts:
                raise r.err("part", "is empty; give at least one [[object.part]]")
        for k, inst in enumerate(mats):
            world = parent @ inst @ local
            label = where if len(mats) == 1 else f"{where} > instance {k}"
            if piece is not None:
                m = mat if mat is not None else self.default_material()
                self.pieces.append((geo.transform(piece, world), m, label))
            else:
                for i, p in enumerate(parts):
                    self.object(p, f"{label} > part {i}", world, mat, depth + 1)


def _read_doc(path: Path) -> dict:
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except tomllib.TOMLDecodeError as e:
        raise SceneError(f"{path}: TOML syntax error: {e}; fix the syntax there") from None
    except OSError as e:
        raise SceneError(f"{path}: cannot read the file: {e}") from e


def _with_base(doc: dict, path: Path) -> tuple[dict, Path]:
    """A view of another scene: ``base = "other.toml"`` takes that file's materials and
    objects (their paths relative to it); this file's name, background, camera and lights
    replace the base's. Returns the merged document and the file its geometry comes from."""
    r = _Reader(doc, str(path), VIEW_KEYS)       # materials or objects here: an error
    base = path.parent / r.str("base")
    if base.suffix.lower() != ".toml":
        raise r.err("base", f"must name a TOML scene, got {base.name!r}")
    if not base.is_file():
        raise r.err("base", f"file {base} does not exist; check the path")
    bdoc = _read_doc(base)
    if "base" in bdoc:
        raise SceneError(f"{base}: a base scene may not have a base itself (used by {path})")
    merged = {k: v for k, v in bdoc.items() if k != "name"}
    merged.update({k: v for k, v in doc.items() if k != "base"})
    return merged, base


def load_toml(path: Path) -> Scene:
    """Parse and validate a TOML scene; see ``docs/scenes.md``."""
    doc = _read_doc(path)
    geo_path = path
    if isinstance(doc, dict) and "base" in doc:
        doc, geo_path = _with_base(doc, path)
    top = _Reader(doc, str(path), TOP_KEYS)
    name = top.str("name", default=path.stem)
    background = top.vec("background", default=DEFAULT_BACKGROUND, lo=0.0)

    materials: list[Material] = []
    for i, m in enumerate(top.list_of_tables("material")):
        mat = _material(m, f"{geo_path}: material {i}", geo_path.parent)
        if any(x.name == mat.name for x in materials):
            raise SceneError(f"{path}: material {i}: name {mat.name!r} is defined twice; "
                             "material names must be unique")
        materials.append(mat)
    lights = [_light(t, f"{path}: light {i}") for i, t in enumerate(top.list_of_tables("light"))]

    camera = _camera(doc["camera"], f"{path}: [camera]") if top.has("camera") else None

    b = _Builder(geo_path, materials)
    objects = top.list_of_tables("object")
    if not objects:
        raise SceneError(f"{path}: the scene has no [[object]] tables; add at least one")
    for i, o in enumerate(objects):
        b.object(o, f"{geo_path}: object {i}", np.eye(4), None, 0)
    if not b.pieces:
        raise SceneError(f"{path}: the scene has no triangles; add objects")
    tris, ids, n, mat, uv, normals, ndeg = finish_pieces(b.pieces)
    if len(tris) == 0:
        raise SceneError(f"{path}: no triangles left after dropping {ndeg} degenerate ones "
                         "(zero area or repeated vertices); the scene is empty")
    if camera is None:
        camera = auto_camera(tris)
    return Scene(name, tris, ids, n, mat, uv, normals, b.materials, lights, camera,
                 background, {"degenerate": ndeg, "nonfinite": 0}, str(path))
