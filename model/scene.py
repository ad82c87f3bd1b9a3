"""Scene loader: a TOML scene description or a bare mesh file -> :class:`Scene`.

``load_scene(path)`` reads ``.toml`` scenes (format: ``docs/scenes.md``) and bare meshes
(``.obj .ply .stl .glb .gltf .off`` through trimesh, ``process=False`` so faces keep the file's
order). The result holds world-space float32 triangles in *scene order* (TOML: objects in file
order, each object's instances in order, each instance's faces in load order), with
``tri_id`` giving each kept triangle's index in that order. Degenerate triangles (a repeated
vertex or exactly zero area after rounding to float32) are dropped and counted; every other
bad input raises :class:`SceneError` with a message naming the problem and how to fix it. A scene
that loads but probably does not show what was meant (a point light on a surface, a camera
inside a closed mesh) gives a :class:`SceneWarning` (``model.scene_checks``; the rules:
``docs/scenes.md``, "Checks on load").

``saarcor scene --scene PATH`` prints a summary of each scene.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .scene_checks import warn_scene
from .scene_data import (DEFAULT_BACKGROUND, MESH_SUFFIXES, Camera, Light, Material, Scene,
                         SceneError, SceneWarning, auto_camera, finish_pieces, grey_material,
                         load_mesh_file)
from .scene_toml import load_toml

__all__ = ["load_scene", "Scene", "SceneError", "SceneWarning", "Camera", "Light", "Material",
           "DEFAULT_BACKGROUND", "MESH_SUFFIXES"]


def _load_bare_mesh(path: Path) -> Scene:
    piece = load_mesh_file(path, f"{path}")
    tris, ids, n, mat, uv, normals, ndeg = finish_pieces([(piece, 0, f"{path}")])
    if len(tris) == 0:
        raise SceneError(f"{path}: no triangles left after dropping {ndeg} degenerate ones; "
                         "the mesh is empty")
    cam = auto_camera(tris)
    fwd = cam.look_at - cam.position
    right = np.cross(fwd, cam.up)
    right /= np.linalg.norm(right)
    dist = float(np.linalg.norm(fwd))
    light = Light("point", cam.position + 0.2 * dist * (right + cam.up), None,
                  np.array([1.0, 1.0, 1.0]))
    return Scene(path.stem, tris, ids, n, mat, uv, normals, [grey_material()], [light], cam,
                 np.array(DEFAULT_BACKGROUND), {"degenerate": ndeg, "nonfinite": 0}, str(path))


def load_scene(path: str | Path) -> Scene:
    """Load a ``.toml`` scene or a bare mesh file (see the module docstring); warns
    (:class:`SceneWarning`) about a light on a surface or a camera inside a closed mesh."""
    scene = _load(Path(path))
    warn_scene(scene, stacklevel=3)
    return scene


def _load(path: Path) -> Scene:
    if not path.exists():
        raise SceneError(f"scene file '{path}' does not exist; check the path "
                         "(shipped scenes are in scenes/, e.g. scenes/cornell.toml)")
    if path.is_dir():
        raise SceneError(f"'{path}' is a directory; give a .toml scene or a mesh file")
    suffix = path.suffix.lower()
    if suffix == ".toml":
        return load_toml(path)
    if suffix in MESH_SUFFIXES:
        return _load_bare_mesh(path)
    raise SceneError(f"'{path}': unknown scene type '{path.suffix}'; use a .toml scene or a "
                     f"mesh file ({', '.join(MESH_SUFFIXES)})")
