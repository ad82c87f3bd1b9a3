"""Scene loader: shipped scenes, mesh files, primitives/transforms, and every bad-input case."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from model.scene import Camera, Light, Material, Scene, SceneError, load_scene

from .conftest import SHARED_MESHES, needs_shared_meshes

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"
TEAPOT = SHARED_MESHES / "teapot.obj"

# (file, min triangles, max triangles, number of lights, light kinds)
SHIPPED = [
    ("cornell.toml", 1_000, 5_000, 3, {"point"}),
    ("glass.toml", 5_000, 6_000, 3, {"point"}),
    ("conference.toml", 20_000, 300_000, 2, {"point"}),
    ("terrain.toml", 50_000, 200_000, 1, {"parallel"}),
    ("office.toml", 2_000, 60_000, 3, {"point"}),
    # the paper's classes at its sizes (Table 1: 34 772, 33 952, ... triangles), within 10 %
    ("game.toml", 31_300, 38_250, 0, set()),
    ("office_large.toml", 30_550, 37_350, 3, {"point"}),
    ("conference_large.toml", 253_800, 310_200, 2, {"point"}),
    ("building.toml", 1_359_000, 1_661_000, 0, set()),
    ("outdoor.toml", 1_920_000, 2_347_000, 1, {"parallel"}),
    ("outdoor_above.toml", 1_920_000, 2_347_000, 1, {"parallel"}),
    ("ship.toml", 3_273_000, 4_001_000, 0, set()),
    ("ship_lit.toml", 3_273_000, 4_001_000, 2, {"parallel", "point"}),
]
# loading one of these takes 10-20 s: with the slow tests
LARGE = {"conference_large.toml", "building.toml", "outdoor.toml", "outdoor_above.toml",
         "ship.toml", "ship_lit.toml"}


def write(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def toml_scene(tmp_path: Path, body: str, camera: str | None = None) -> Path:
    """A scene of `body` followed by a camera (a default one unless given)."""
    cam = camera if camera is not None else (
        "[camera]\nposition = [0.0, 0.0, 5.0]\nlook_at = [0.0, 0.0, 0.0]\n")
    return write(tmp_path, "s.toml", body + "\n" + cam)


BOX = '[[object]]\nbox = { size = 1.0 }\n'


def check_invariants(s: Scene) -> None:
    n = len(s.tris)
    assert n > 0
    assert s.tris.dtype == np.float32 and s.tris.shape == (n, 3, 3)
    assert s.tri_id.dtype == np.int32 and s.tri_id.shape == (n,)
    assert np.all(np.diff(s.tri_id) > 0) and s.tri_id[-1] < s.n_scene_tris
    assert s.n_scene_tris == n + sum(s.dropped.values())
    assert s.material.dtype == np.int32 and s.material.min() >= 0
    assert s.material.max() < len(s.materials)
    assert s.uv.dtype == np.float32 and s.uv.shape == (n, 3, 2)
    assert s.normals.dtype == np.float32 and s.normals.shape == (n, 3, 3)
    assert np.allclose(np.linalg.norm(s.normals, axis=2), 1.0, atol=1e-5)
    assert np.isfinite(s.tris).all() and np.isfinite(s.uv).all()
    t = s.tris.astype(np.float64)
    assert np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]).any(axis=1).all()
    c = s.camera
    assert 0 < c.fov_y < 180 and np.linalg.norm(c.look_at - c.position) > 0
    assert s.background.shape == (3,)


# ------------------------------------------------------------------------------------------
# shipped scenes
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("fname,lo,hi,nlights,kinds", [
    pytest.param(*x, marks=[pytest.mark.slow] if x[0] in LARGE else [], id=x[0]) for x in SHIPPED])
def test_shipped_scene_loads(fname, lo, hi, nlights, kinds):
    s = load_scene(SCENES / fname)
    check_invariants(s)
    assert lo <= len(s) <= hi, len(s)
    assert len(s.lights) == nlights and {l.kind for l in s.lights} == kinds
    for l in s.lights:
        assert (l.color > 0).any()
        if l.kind == "parallel":
            assert math.isclose(np.linalg.norm(l.direction), 1.0) and l.direction[1] < 0
    assert np.abs(s.tris).max() <= 1000.0          # keeps rendering cost reasonable
    lo_b, hi_b = s.bounds()
    assert np.all((lo_b <= s.camera.look_at) & (s.camera.look_at <= hi_b))  # looks at the scene
    assert s.dropped == {"degenerate": 0, "nonfinite": 0}


def test_every_shipped_scene_is_tested():
    assert sorted(p.name for p in SCENES.glob("*.toml")) == sorted(f for f, *_ in SHIPPED)


def test_cornell_contents():
    s = load_scene(SCENES / "cornell.toml")
    # 5 walls of 4x4 cells (32 tris), icosphere subdiv 3 (20 * 4**3), two boxes (12 each)
    assert len(s) == 5 * 32 + 20 * 64 + 12 + 12
    by_name = {m.name: m for m in s.materials}
    floor = by_name["floor"]
    assert floor.texture is not None and floor.texture.dtype == np.uint8
    assert floor.texture.ndim == 3 and floor.texture.shape[2] == 3
    assert len(np.unique(floor.texture.reshape(-1, 3), axis=0)) == 2    # two checker colours
    assert by_name["mirror"].reflect > 0.5
    assert {tuple(by_name[n].diffuse) for n in ("red", "green")} != {tuple(by_name["white"].diffuse)}
    # the camera looks into the open side of the box from outside
    assert s.camera.position[2] > 5.0


def test_make_sim_default_scene_is_cornell():
    assert "SCENE ?= scenes/cornell.toml" in (ROOT / "Makefile").read_text()


# ------------------------------------------------------------------------------------------
# bare mesh files
# ------------------------------------------------------------------------------------------

TWO_TRIS = "v 0 0 0\nv 2 0 0\nv 0 1 0\nv 2 1 1\nf 1 2 3\nf 2 4 3\n"


def test_tiny_obj(tmp_path):
    s = load_scene(write(tmp_path, "t.obj", TWO_TRIS))
    check_invariants(s)
    assert s.name == "t" and s.source.endswith("t.obj")
    expect = np.array([[[0, 0, 0], [2, 0, 0], [0, 1, 0]], [[2, 0, 0], [2, 1, 1], [0, 1, 0]]])
    assert np.array_equal(s.tris, expect.astype(np.float32))
    assert s.tri_id.tolist() == [0, 1] and s.n_scene_tris == 2
    # no normals in the file: face normals; the first triangle faces +z
    assert np.allclose(s.normals[0], [0, 0, 1])
    assert len(s.materials) == 1 and np.allclose(s.materials[0].diffuse, s.materials[0].diffuse[0])
    assert len(s.lights) == 1 and s.lights[0].kind == "point"
    # auto camera: looks at the box centre, every vertex inside the vertical and horizontal fov
    c = s.camera
    assert np.allclose(c.look_at, [1.0, 0.5, 0.5])
    f = (c.look_at - c.position) / np.linalg.norm(c.look_at - c.position)
    v = s.tris.reshape(-1, 3) - c.position
    cosang = (v @ f) / np.linalg.norm(v, axis=1)
    assert np.all(np.degrees(np.arccos(cosang)) < c.fov_y / 2)
    # 3/4 view: not along an axis
    assert np.count_nonzero(np.abs(f) > 0.2) == 3
    # light near the camera
    assert np.linalg.norm(s.lights[0].position - c.position) < np.linalg.norm(c.look_at - c.position)


def test_obj_with_missing_material_library_uv_and_normals(tmp_path):
    text = ("mtllib nothere.mtl\nusemtl foo\nv 0 0 0\nv 1 0 0\nv 0 1 0\n"
            "vt 0.1 0.2\nvt 0.9 0.2\nvt 0.1 0.8\nvn 0 1 0\nf 1/1/1 2/2/1 3/3/1\n")
    s = load_scene(write(tmp_path, "m.obj", text))
    assert len(s) == 1
    assert np.allclose(s.uv[0], [[0.1, 0.2], [0.9, 0.2], [0.1, 0.8]])
    assert np.allclose(s.normals[0], [[0, 1, 0]] * 3)         # the file's normals, not the face's


@needs_shared_meshes
def test_teapot():
    s = load_scene(TEAPOT)
    check_invariants(s)
    assert s.n_scene_tris == 2464
    assert len(s) + s.dropped["degenerate"] == 2464
    assert np.abs(s.tris).max() < 2.0


# ------------------------------------------------------------------------------------------
# primitives, transforms, instances, materials
# ------------------------------------------------------------------------------------------

def test_transform_and_instances(tmp_path):
    body = ('[[object]]\nbox = { size = [2.0, 4.0, 6.0] }\n'
            'transform = { translate = [10.0, 0.0, 0.0], rotate = [0.0, 90.0, 0.0], scale = 0.5 }\n'
            'instances = [{ translate = [0.0, 100.0, 0.0] }, { translate = [0.0, -100.0, 0.0] }]\n')
    s = load_scene(toml_scene(tmp_path, body))
    assert len(s) == 24 and s.tri_id.tolist() == list(range(24))
    a, b = s.tris[:12].reshape(-1, 3), s.tris[12:].reshape(-1, 3)
    # scale 0.5 -> 1 x 2 x 3, rotate 90 about y swaps x and z extents, then translate
    assert np.allclose(a.min(0), [10 - 1.5, 100 - 1, -0.5], atol=1e-5)
    assert np.allclose(a.max(0), [10 + 1.5, 100 + 1, 0.5], atol=1e-5)
    assert np.allclose(b - a, [0, -200, 0], atol=1e-4)
    # box face normals point outwards
    fn = np.cross(s.tris[:12, 1] - s.tris[:12, 0], s.tris[:12, 2] - s.tris[:12, 0])
    assert np.all(np.einsum("ij,ij->i", fn, s.tris[:12].mean(1) - [10, 100, 0]) > 0)


def test_primitive_triangle_counts_and_parts(tmp_path):
    body = ('[[material]]\nname = "a"\n[[material]]\nname = "b"\n'
            '[[object]]\nsphere = { radius = 2.0, subdivisions = 2 }\nmaterial = "a"\n'
            '[[object]]\ncylinder = { sections = 10 }\n'
            '[[object]]\nplane = { size = [4.0, 2.0], segments = [3, 2] }\nmaterial = "b"\n'
            '[[object]]\nterrain = { size = [10.0, 10.0], resolution = [5, 4], height = 2.0 }\n'
            '[[object]]\nwall = { size = [10.0, 3.0], windows = [2, 1], window_size = [2.0, 1.0] }\n'
            '[[object]]\nmaterial = "a"\ninstances = [{}, { translate = [5.0, 0.0, 0.0] }]\n'
            '  [[object.part]]\n  box = { size = 1.0 }\n'
            '  [[object.part]]\n  quad = {}\n  material = "b"\n')
    s = load_scene(toml_scene(tmp_path, body))
    counts = [20 * 16, 4 * 10, 2 * 6, 2 * 20, 12 * (2 + 3), 2 * (12 + 2)]
    assert len(s) == sum(counts)
    names = [m.name for m in s.materials]
    assert names == ["a", "b", "default"]                      # default added on demand
    starts = np.cumsum([0] + counts)
    mat = s.material
    assert set(mat[starts[0]:starts[1]]) == {0} and set(mat[starts[1]:starts[2]]) == {2}
    assert set(mat[starts[2]:starts[3]]) == {1}
    assert mat[starts[5]:].tolist() == ([0] * 12 + [1] * 2) * 2     # part materials inherit/override
    sph = s.tris[:320].reshape(-1, 3)
    assert np.allclose(np.linalg.norm(sph, axis=1), 2.0, atol=1e-5)
    # sphere shading normals are radial
    assert np.allclose(s.normals[:320], s.tris[:320] / 2.0, atol=1e-5)
    # plane and terrain face +y with planar UVs in 0..1
    pl = slice(starts[2], starts[3])
    assert np.allclose(s.tris[pl][..., 1], 0) and np.allclose(s.normals[pl], [0, 1, 0])
    assert s.uv[pl].min() == 0 and s.uv[pl].max() == 1
    tr = slice(starts[3], starts[4])
    assert (s.normals[tr][..., 1] > 0).all() and 0 <= s.tris[tr][..., 1].min()
    assert s.tris[tr][..., 1].max() <= 2.0


def test_wall_has_window_holes(tmp_path):
    body = '[[object]]\nwall = { size = [10.0, 3.0], windows = [2, 1], window_size = [2.0, 1.0] }\n'
    s = load_scene(toml_scene(tmp_path, body))
    # window centres (-2.5, 1.5) and (2.5, 1.5): no triangle covers them in the wall plane
    for cx in (-2.5, 2.5):
        lo, hi = s.tris.min(1), s.tris.max(1)
        inside = (lo[:, 0] < cx) & (hi[:, 0] > cx) & (lo[:, 1] < 1.5) & (hi[:, 1] > 1.5)
        assert not inside.any()
    assert np.allclose(s.tris.reshape(-1, 3).min(0), [-5, 0, -0.1])


def test_terrain_is_deterministic_and_seeded(tmp_path):
    def load(seed):
        body = f'[[object]]\nterrain = {{ size = [50.0, 50.0], resolution = 8, seed = {seed} }}\n'
        return load_scene(toml_scene(tmp_path, body)).tris
    assert np.array_equal(load(3), load(3))
    assert not np.array_equal(load(3), load(4))


def test_textures_and_checker(tmp_path):
    img = np.zeros((4, 6, 3), np.uint8)
    img[0, 0] = [255, 0, 0]
    Image.fromarray(img).save(tmp_path / "tex.png")
    body = ('[[material]]\nname = "t"\ntexture = "tex.png"\n'
            '[[material]]\nname = "c"\nchecker = [4, [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]\n'
            '[[material]]\nname = "shiny"\nspecular = [0.5, 0.5, 0.5]\nshininess = 7.0\n'
            'reflect = 0.25\n' + BOX + 'material = "t"\n')
    s = load_scene(toml_scene(tmp_path, body))
    t, c, sh = s.materials
    assert t.texture.shape == (4, 6, 3) and t.texture[0, 0].tolist() == [255, 0, 0]
    h = c.texture.shape[0]
    assert c.texture.shape == (h, h, 3) and h % 4 == 0
    assert c.texture[0, 0].tolist() == [255, 0, 0]
    assert c.texture[0, h // 4].tolist() == [0, 0, 255]
    assert c.texture[h // 4, h // 4].tolist() == [255, 0, 0]
    assert sh.shininess == 7.0 and sh.reflect == 0.25 and sh.texture is None
    assert s.material.tolist() == [0] * 12


def test_lights_and_camera(tmp_path):
    body = ('[[light]]\nkind = "point"\nposition = [1.0, 2.0, 3.0]\ncolor = [1.0, 0.5, 0.0]\n'
            'intensity = 2.0\n[[light]]\nkind = "parallel"\ndirection = [0.0, -3.0, 0.0]\n'
            + BOX)
    cam = "[camera]\nposition = [0.0, 0.0, 5.0]\nlook_at = [0.0, 0.0, 0.0]\nfov = 30.0\n"
    s = load_scene(toml_scene(tmp_path, body, cam))
    p, d = s.lights
    assert p.kind == "point" and np.allclose(p.position, [1, 2, 3])
    assert np.allclose(p.color, [2.0, 1.0, 0.0])                 # intensity folded in
    assert d.kind == "parallel" and np.allclose(d.direction, [0, -1, 0])
    assert np.allclose(d.color, [1, 1, 1])
    assert s.camera.fov_y == 30.0 and np.allclose(s.camera.up, [0, 1, 0])


def test_toml_without_camera_gets_automatic_one(tmp_path):
    s = load_scene(toml_scene(tmp_path, BOX, camera=""))
    assert np.allclose(s.camera.look_at, 0.0, atol=1e-6)


# ------------------------------------------------------------------------------------------
# degenerate triangles
# ------------------------------------------------------------------------------------------

DEGEN_OBJ = ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nv 1 1 0\n"
             "f 1 2 3\n"       # 0 ok
             "f 1 1 3\n"       # 1 repeated vertex
             "f 1 2 4\n"       # 2 collinear: zero area
             "f 2 5 3\n"       # 3 ok
             "f 3 3 3\n")      # 4 all the same


def test_degenerate_triangles_dropped_and_counted(tmp_path):
    s = load_scene(write(tmp_path, "d.obj", DEGEN_OBJ))
    assert s.dropped["degenerate"] == 3 and s.n_scene_tris == 5
    assert s.tri_id.tolist() == [0, 3]
    assert np.allclose(s.tris[1], [[1, 0, 0], [1, 1, 0], [0, 1, 0]])


def test_degenerate_in_toml_keeps_scene_order(tmp_path):
    write(tmp_path, "d.obj", DEGEN_OBJ)
    body = BOX + '[[object]]\nmesh = "d.obj"\ninstances = [{}, { translate = [5.0, 0.0, 0.0] }]\n'
    s = load_scene(toml_scene(tmp_path, body))
    assert s.n_scene_tris == 12 + 2 * 5 and s.dropped["degenerate"] == 6
    assert s.tri_id.tolist() == list(range(12)) + [12, 15, 17, 20]
    assert np.allclose(s.tris[14] - s.tris[12], [5, 0, 0])


def test_all_degenerate_is_an_error(tmp_path):
    p = write(tmp_path, "z.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\nf 1 1 2\n")
    with pytest.raises(SceneError, match=r"no triangles left after dropping 2 degenerate"):
        load_scene(p)


# ------------------------------------------------------------------------------------------
# bad input
# ------------------------------------------------------------------------------------------

def test_missing_file(tmp_path):
    with pytest.raises(SceneError, match=r"nothere\.toml' does not exist"):
        load_scene(tmp_path / "nothere.toml")
    with pytest.raises(SceneError, match=r"mesh file .*gone\.obj' does not exist"):
        load_scene(toml_scene(tmp_path, '[[object]]\nmesh = "gone.obj"\n'))


def test_unknown_extension_and_directory(tmp_path):
    with pytest.raises(SceneError, match=r"unknown scene type '\.xyz'"):
        load_scene(write(tmp_path, "a.xyz", "x"))
    with pytest.raises(SceneError, match="is a directory"):
        load_scene(tmp_path)


@pytest.mark.parametrize("name,content,pattern", [
    ("c.obj", "v 1 2\nf 1 2 zz\n", r"cannot read mesh .*c\.obj"),
    ("e.ply", "ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n",
     r"cannot read mesh .*e\.ply.*corrupt"),
    ("b.stl", "garbage\x00\x01\x02", r"b\.stl' contains no triangles"),
    ("empty.obj", "", r"empty\.obj' contains no triangles"),
])
def test_corrupt_mesh(tmp_path, name, content, pattern):
    with pytest.raises(SceneError, match=pattern):
        load_scene(write(tmp_path, name, content))


def test_nan_vertices(tmp_path):
    text = ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv nan 0 0\nv 0 inf 0\n"
            "f 1 2 3\nf 1 2 3\nf 1 4 3\nf 2 3 5\nf 4 5 1\n")
    p = write(tmp_path, "n.obj", text)
    with pytest.raises(SceneError, match=r"n\.obj' has 3 triangles with NaN/inf vertices "
                                         r"\(first: face 2\)"):
        load_scene(p)
    # the same mesh inside a TOML scene names the object too
    with pytest.raises(SceneError, match=r"object 1 'bad'.*3 triangles with NaN/inf"):
        load_scene(toml_scene(tmp_path, BOX + '[[object]]\nname = "bad"\nmesh = "n.obj"\n'))


def test_overflow_after_transform(tmp_path):
    body = BOX + '[[object]]\nname = "huge"\nbox = { size = 1.0 }\ntransform = { scale = 1e39 }\n'
    with pytest.raises(SceneError, match=r"object 1 'huge': 12 triangles with NaN/inf.*face 0"):
        load_scene(toml_scene(tmp_path, body))


def test_toml_syntax_error_reports_line(tmp_path):
    p = write(tmp_path, "s.toml", "[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0 0]\n")
    with pytest.raises(SceneError, match=r"TOML syntax error.*line 3"):
        load_scene(p)


@pytest.mark.parametrize("camera,pattern", [
    ("[camera]\nposition = [1.0, 2.0, 3.0]\nlook_at = [1.0, 2.0, 3.0]\n",
     r"look_at equals position"),
    ("[camera]\nposition = [0.0, 0.0, 0.0]\nlook_at = [0.0, 5.0, 0.0]\n",
     r"'up' \[0.0, 1.0, 0.0\] is parallel to the view direction"),
    ("[camera]\nposition = [0.0, 0.0, 0.0]\nlook_at = [0.0, 0.0, 1.0]\nup = [0.0, 0.0, -2.0]\n",
     r"parallel to the view direction"),
    ("[camera]\nposition = [0.0, 0.0, 5.0]\nlook_at = [0.0, 0.0, 0.0]\nfov = 180.0\n",
     r"\[camera\]: 'fov' must be < 180"),
    ("[camera]\nposition = [0.0, 0.0, 5.0]\nlook_at = [0.0, 0.0, 0.0]\nfov = 0\n",
     r"'fov' must be > 0"),
    ("[camera]\nposition = [0.0, 0.0, 5.0]\nlook_at = [0.0, 0.0, 0.0]\nfov = -10.0\n",
     r"'fov' must be > 0"),
    ("[camera]\nposition = [0.0, 0.0, 5.0]\nlook_at = [0.0, 0.0, 0.0]\nfov = true\n",
     r"'fov' must be a finite number"),
    ("[camera]\nposition = [0.0, 0.0]\nlook_at = [0.0, 0.0, 0.0]\n",
     r"'position' must be a list of 3 finite numbers"),
    ("[camera]\nposition = [0.0, 0.0, 5.0]\n", r"'look_at' is missing"),
    ("[camera]\nposition = [0.0, 0.0, 5.0]\nlook_at = [0.0, 0.0, 0.0]\nfocus = 3.0\n",
     r"\[camera\]: unknown key 'focus'; allowed keys: position, look_at, up, fov"),
])
def test_bad_camera(tmp_path, camera, pattern):
    with pytest.raises(SceneError, match=pattern):
        load_scene(toml_scene(tmp_path, BOX, camera))


@pytest.mark.parametrize("body,pattern", [
    ('colour = 1\n' + BOX, r"s\.toml: unknown key 'colour'; allowed keys: name, background"),
    ('[[object]]\nbox = { size = 1.0 }\ncolor = "red"\n',
     r"object 0: unknown key 'color'; allowed keys: name, material, transform"),
    ('[[object]]\nbox = { sise = 1.0 }\n', r"object 0 > box: unknown key 'sise'; allowed keys: "
                                          r"size, inward"),
    ('[[object]]\nbox = { size = 1.0 }\ntransform = { scale = [1.0, -1.0, 1.0] }\n',
     r"object 0 > transform: 'scale' must be > 0"),
    ('[[object]]\nbox = { size = 1.0 }\ntransform = { scale = -2 }\n', r"'scale' must be > 0"),
    ('[[object]]\nbox = { size = 1.0 }\ntransform = { spin = 2 }\n',
     r"unknown key 'spin'; allowed keys: translate, rotate, scale"),
    ('[[object]]\nbox = { size = 1.0 }\ninstances = [{ translate = [1.0, 2.0] }]\n',
     r"object 0 > instance 0: 'translate' must be a list of 3"),
    ('[[object]]\nbox = { size = 1.0 }\nmaterial = "gold"\n',
     r"object 0: unknown material 'gold'; define it in a \[\[material\]\]"),
    ('[[material]]\nname = "m"\nreflect = 1.5\n' + BOX, r"material 0: 'reflect' must be <= 1"),
    ('[[material]]\nname = "m"\nglossy = 1\n' + BOX, r"material 0: unknown key 'glossy'"),
    ('[[material]]\ndiffuse = [1.0, 1.0, 1.0]\n' + BOX, r"material 0: 'name' is missing"),
    ('[[material]]\nname = "m"\n[[material]]\nname = "m"\n' + BOX, r"'m' is defined twice"),
    ('[[material]]\nname = "m"\ntexture = "no.png"\n' + BOX, r"texture .*no\.png' does not exist"),
    ('[[material]]\nname = "m"\ntexture = "s.toml"\n' + BOX, r"cannot read texture"),
    ('[[material]]\nname = "m"\nchecker = [0, [1, 1, 1], [0, 0, 0]]\n' + BOX,
     r"'checker' must be \[n, color1, color2\]"),
    ('[[material]]\nname = "m"\nchecker = [2, [1, 1, 1], [0, 0, 0]]\ntexture = "x.png"\n' + BOX,
     r"either 'texture' or 'checker'"),
    ('[[material]]\nname = "m"\ndiffuse = "white"\n' + BOX, r"'diffuse' must be a list of 3"),
    ('[[object]]\nsphere = { radius = "big" }\n', r"object 0 > sphere: 'radius' must be a finite"),
    ('[[object]]\nsphere = { subdivisions = 2.5 }\n', r"'subdivisions' must be an integer"),
    ('[[object]]\nsphere = { subdivisions = 9 }\n', r"'subdivisions' must be in 0\.\.6"),
    ('[[object]]\nsphere = { radius = -1.0 }\n', r"'radius' must be > 0"),
    ('[[object]]\nbox = [1, 2, 3]\n', r"object 0 > box: expected a table"),
    ('[[object]]\nname = "x"\n', r"object 0 'x': needs exactly one geometry key .* got none"),
    ('[[object]]\nbox = {}\nsphere = {}\n', r"needs exactly one geometry key .* got box, sphere"),
    ('[[object]]\nwall = { size = [4.0, 3.0], windows = [2, 1], window_size = [3.0, 1.0] }\n',
     r"'window_size' \[3.0, 1.0\] does not fit 2x1 windows"),
    ('[[object]]\nterrain = { resolution = 0 }\n', r"'resolution' must be 2 integers"),
    ('[[light]]\nkind = "spot"\nposition = [0.0, 1.0, 0.0]\n' + BOX,
     r"light 0: 'kind' must be \"point\" or \"parallel\", got 'spot'"),
    ('[[light]]\nkind = "point"\ndirection = [0.0, 1.0, 0.0]\n' + BOX,
     r"light 0: unknown key 'direction'; allowed keys: kind, position, color, intensity"),
    ('[[light]]\nkind = "parallel"\ndirection = [0.0, 0.0, 0.0]\n' + BOX,
     r"'direction' is the zero vector"),
    ('[[light]]\nkind = "point"\nposition = [0.0, 1.0, 0.0]\nintensity = -1.0\n' + BOX,
     r"'intensity' must be >= 0"),
    ('background = [0.1, 0.1]\n' + BOX, r"'background' must be a list of 3"),
    ('name = 3\n' + BOX, r"'name' must be a non-empty string"),
    ('object = 3\n', r"'object' must be a list of tables"),
    ('', r"no \[\[object\]\] tables"),
])
def test_bad_scene_parameters(tmp_path, body, pattern):
    with pytest.raises(SceneError, match=pattern):
        load_scene(toml_scene(tmp_path, body))


def test_scene_error_is_value_error():
    assert issubclass(SceneError, ValueError)
    # the public dataclasses exist with the documented fields
    assert {"position", "look_at", "up", "fov_y"} <= set(Camera.__dataclass_fields__)
    assert {"kind", "position", "direction", "color"} <= set(Light.__dataclass_fields__)
    assert {"diffuse", "specular", "shininess", "reflect", "texture"} <= set(
        Material.__dataclass_fields__)


# ------------------------------------------------------------------------------------------
# a view of another scene (base = "other.toml")
# ------------------------------------------------------------------------------------------

BASE = ('name = "b"\n[camera]\nposition = [0.0, 0.0, 5.0]\nlook_at = [0.0, 0.0, 0.0]\n'
        '[[light]]\nkind = "point"\nposition = [0.0, 3.0, 0.0]\n'
        '[[material]]\nname = "m"\ndiffuse = [0.2, 0.4, 0.6]\n'
        '[[object]]\nmesh = "meshes/two.obj"\nmaterial = "m"\n'
        '[[object]]\nsphere = { subdivisions = 1 }\n')


def test_view_of_a_base_scene(tmp_path):
    """The view has the base's triangles and materials (its paths relative to the base) and
    its own name, camera and lights; what it does not set comes from the base."""
    (tmp_path / "meshes").mkdir()
    write(tmp_path / "meshes", "two.obj", TWO_TRIS)
    base = load_scene(write(tmp_path, "base.toml", BASE))
    (tmp_path / "views").mkdir()
    v = load_scene(write(tmp_path / "views", "above.toml",
                         'base = "../base.toml"\n[camera]\nposition = [0.0, 9.0, 1.0]\n'
                         'look_at = [0.0, 0.0, 0.0]\n[[light]]\nkind = "parallel"\n'
                         'direction = [0.0, -1.0, 0.0]\n'))
    check_invariants(v)
    assert np.array_equal(v.tris, base.tris) and np.array_equal(v.material, base.material)
    assert [m.name for m in v.materials] == [m.name for m in base.materials]
    assert v.name == "above" and np.allclose(v.camera.position, [0, 9, 1])
    assert [l.kind for l in v.lights] == ["parallel"]
    same = load_scene(write(tmp_path / "views", "same.toml", 'base = "../base.toml"\n'))
    assert np.allclose(same.camera.position, base.camera.position)
    assert [l.kind for l in same.lights] == ["point"]


@pytest.mark.parametrize("view,pattern", [
    ('base = "base.toml"\n[[object]]\nbox = { size = 1.0 }\n',
     r"unknown key 'object'; allowed keys: name, background, camera, light, base"),
    ('base = "nothere.toml"\n', r"'base'.* does not exist"),
    ('base = "m.obj"\n', r"'base' must name a TOML scene"),
    ('base = "chain.toml"\n', r"a base scene may not have a base itself"),
])
def test_bad_view(tmp_path, view, pattern):
    write(tmp_path, "base.toml", BOX)
    write(tmp_path, "chain.toml", 'base = "base.toml"\n')
    with pytest.raises(SceneError, match=pattern):
        load_scene(write(tmp_path, "v.toml", view))
