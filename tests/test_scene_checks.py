"""Bad scene and mesh input: clear errors and warnings (``model.scene_data``,
``model.scene_checks``, ``docs/scenes.md`` "Checks on load")."""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from model.config import Config, ConfigError
from model.fp import FPFormat
from model.render import prepare
from model.scene import SceneError, SceneWarning, load_scene
from model.scene_checks import check_format, format_limits, probe_camera

from .conftest import ROOT, SHARED_MESHES, needs_shared_meshes, scene_params

CORNELL = ROOT / "scenes" / "cornell.toml"
TWO_TRIS = "v 0 0 0\nv 2 0 0\nv 0 1 0\nv 2 1 1\nf 1 2 3\nf 2 4 3\n"
TWO_TRIS_EXPECT = np.array([[[0, 0, 0], [2, 0, 0], [0, 1, 0]],
                            [[2, 0, 0], [2, 1, 1], [0, 1, 0]]], np.float32)


def write(tmp_path: Path, name: str, data: str | bytes) -> Path:
    p = tmp_path / name
    if isinstance(data, str):
        p.write_text(data)
    else:
        p.write_bytes(data)
    return p


def load_quietly(path) -> tuple:
    """Load, returning (scene, the SceneWarnings' messages)."""
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        s = load_scene(path)
    return s, [str(w.message) for w in rec if issubclass(w.category, SceneWarning)]


# ------------------------------------------------------------------------------------------
# mesh files
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("faces,index,have", [
    ("f 1 2 3\nf 1 2 99\n", "vertex 99", "has 3 vertices"),
    ("f 1 2 3\nf -1 -2 -9\n", "vertex -9", "has 3 vertices before that line"),
])
def test_obj_face_naming_a_missing_vertex(tmp_path, faces, index, have):
    p = write(tmp_path, "m.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n" + faces)
    with pytest.raises(SceneError) as e:
        load_scene(p)
    msg = str(e.value)
    assert "m.obj" in msg and "line 5" in msg and index in msg and have in msg
    assert "does not exist" in msg and "fix the index" in msg
    assert "IndexError" not in msg and "corrupt" not in msg


def test_obj_with_latin1_comment_loads(tmp_path):
    """One Latin-1 byte in a comment (not UTF-8): trimesh alone reports the file corrupt."""
    data = b"# caf\xe9 au lait\n" + TWO_TRIS.encode() + b"# na\xefve\n"
    s, warned = load_quietly(write(tmp_path, "latin.obj", data))
    assert np.array_equal(s.tris, TWO_TRIS_EXPECT) and s.tri_id.tolist() == [0, 1]
    assert not warned
    # the file's own normals survive the re-encoded path
    data = (b"# \xe9\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 1 0\nf 1//1 2//1 3//1\n")
    s, _ = load_quietly(write(tmp_path, "latin_n.obj", data))
    assert np.allclose(s.normals[0], [[0, 1, 0]] * 3)


@pytest.mark.parametrize("name,data", [
    ("o.off", b"OFF\n# caf\xe9\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"),
    ("a.stl", b"solid caf\xe9\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n"
              b"vertex 0 1 0\nendloop\nendfacet\nendsolid\n"),
    ("p.ply", b"ply\nformat ascii 1.0\ncomment caf\xe9\nelement vertex 3\nproperty float x\n"
              b"property float y\nproperty float z\nelement face 1\n"
              b"property list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n"
              b"3 0 1 2\n"),
])
def test_other_text_meshes_with_latin1_bytes_load(tmp_path, name, data):
    s, _ = load_quietly(write(tmp_path, name, data))
    assert np.array_equal(s.tris, np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], np.float32))


# ------------------------------------------------------------------------------------------
# the FP format must hold the scene
# ------------------------------------------------------------------------------------------

def test_format_limits():
    d_min, d_max, c_max = format_limits(FPFormat(8, 23))
    assert d_max == pytest.approx((FPFormat().max_finite / 2) ** (1 / 3))
    assert d_min == pytest.approx((2.0 ** -126 * 2.0 ** 24) ** (1 / 3))
    assert c_max == FPFormat().max_finite / 2
    assert format_limits(FPFormat(5, 10))[:2] == pytest.approx((0.5, 31.99), rel=1e-3)


def test_e2m1_cornell_is_a_config_error(tmp_path):
    scene, _ = load_quietly(CORNELL)
    with pytest.raises(ConfigError) as e:
        prepare(scene, Config(fmt=FPFormat(2, 1)), cache_dir=tmp_path)    # not KdTreeError
    msg = str(e.value)
    hard = FPFormat(2, 1).max_finite ** (1 / 3)      # extent**3 at most the largest finite
    assert "E2M1" in msg and "spans 24 along z" in msg and f"extent <= {hard:.4g}" in msg
    assert "more exponent bits (E5M1" in msg


def tetra(tmp_path, size: float) -> Path:
    """An OBJ of two faces of the tetrahedron with edges ``size`` along the axes."""
    return write(tmp_path, f"t{size:g}.obj", f"v 0 0 0\nv {size:g} 0 0\nv 0 {size:g} 0\n"
                                             f"v 0 0 {size:g}\nf 1 2 3\nf 1 3 4\n")


def format_error(tmp_path, size: float) -> str:
    """The ConfigError message of preparing :func:`tetra` of ``size`` at binary32."""
    scene, _ = load_quietly(tetra(tmp_path, size))
    with pytest.raises(ConfigError) as e:
        prepare(scene, Config(), cache_dir=tmp_path)
    return str(e.value)


def test_huge_obj_is_a_config_error(tmp_path):
    msg = format_error(tmp_path, 3e38)
    assert "E8M23" in msg and "overflow" in msg and "extent <= 6.981e+12" in msg
    assert "scale the scene down" in msg.lower()


def test_a_scene_near_the_formats_limit_warns(tmp_path):
    """Between max_finite / 2 and max_finite for extent**3 (E5M10: extent 32 .. 40): a
    warning, not an error; below it nothing."""
    fmt = FPFormat(5, 10)
    for size, warns in ((36.0, True), (20.0, False)):
        scene, _ = load_quietly(tetra(tmp_path, size))
        scene.camera.position[:] = [size / 4] * 3     # keep the camera inside the extent
        scene.camera.look_at[:] = [0, 0, 0]
        for lt in scene.lights:
            lt.position[:] = [size / 3] * 3
        with warnings.catch_warnings(record=True) as rec:
            warnings.simplefilter("always")
            check_format(scene, fmt)
        got = [str(w.message) for w in rec if issubclass(w.category, SceneWarning)]
        assert bool(got) == warns, (size, got)
        if warns:
            assert "barely holds" in got[0] and "E5M10" in got[0]


def test_tiny_obj_is_a_config_error(tmp_path):
    msg = format_error(tmp_path, 1e-30)
    assert "E8M23" in msg and "triangles span 1e-30" in msg and "smallest normal" in msg
    assert "extent >= 5.821e-11" in msg and "scale the scene up" in msg.lower()


# ------------------------------------------------------------------------------------------
# warnings on load
# ------------------------------------------------------------------------------------------

ROOM = """
[camera]
position = [0.0, 0.0, 1.5]
look_at = [0.0, 0.0, -1.0]

[[light]]
kind = "point"
position = {light}

[[object]]
box = {{ size = 4.0, inward = true }}
"""


def test_light_on_a_wall_warns(tmp_path):
    p = write(tmp_path, "room.toml", ROOM.format(light="[0.0, 2.0, 0.5]"))   # on the ceiling
    _, warned = load_quietly(p)
    assert len(warned) == 1
    assert "point light 0" in warned[0] and "lies on a surface" in warned[0]
    assert "room.toml" in warned[0] and "Move the light" in warned[0]
    # 1 % of the room's height below the ceiling: fine
    p = write(tmp_path, "room.toml", ROOM.format(light="[0.0, 1.96, 0.5]"))
    assert load_quietly(p)[1] == []


CUBE = """
[camera]
position = [0.0, 0.0, 0.0]
look_at = [0.0, 0.0, -1.0]

[[object]]
box = {{ size = 4.0{inward} }}
"""


def test_camera_inside_a_closed_cube_warns(tmp_path):
    p = write(tmp_path, "cube.toml", CUBE.format(inward=""))
    _, warned = load_quietly(p)
    assert len(warned) == 1 and "sees only back faces" in warned[0]
    assert "all 63 of 63 probe rays" in warned[0] and "inside a closed mesh" in warned[0]
    # the same cube as a room (faces pointing in): no warning
    room = write(tmp_path, "cube.toml", CUBE.format(inward=", inward = true"))
    scene, warned = load_quietly(room)
    assert warned == [] and probe_camera(scene) == (63, 63, 0)


# ------------------------------------------------------------------------------------------
# what ships passes
# ------------------------------------------------------------------------------------------

# the narrower formats the tests render these scenes in (tests/test_render_fused.py)
NARROW = {"office": [FPFormat(5, 10), FPFormat(8, 16)], "game": [FPFormat(6, 12)],
          "cornell": [FPFormat(8, 10)]}


@pytest.mark.parametrize("path", scene_params())
def test_shipped_scenes_load_without_warnings_and_fit_their_formats(path):
    with warnings.catch_warnings():
        warnings.simplefilter("error", SceneWarning)
        scene = load_scene(path)
    for fmt in [FPFormat()] + NARROW.get(path.stem, []):
        check_format(scene, fmt)


@needs_shared_meshes
def test_shared_meshes_load_without_warnings_and_fit_binary32():
    for path in sorted(SHARED_MESHES.glob("*.obj")):
        scene, warned = load_quietly(path)
        assert warned == [], path.name
        check_format(scene, FPFormat())
