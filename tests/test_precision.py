"""The precision study's measures (saarcor/precision.py) and its float64 reference
(model/reference.py): they score a correct render well and a deliberately wrong one badly."""
import numpy as np
import pytest
import trimesh

from model.config import Config
from model.fp import FPFormat
from model.raygen import eye_rays
from model.reference import Reference, render64
from model.render import prepare, render
from model.rtc import trace
from model.scene import load_scene
from saarcor.precision import (image_error, leaks, narrowest_format, ray_error, smallest_m,
                          study_scene)

from .conftest import ROOT

W, H = 40, 29          # odd height: no pixel centre on the centred camera's diagonals


@pytest.fixture(scope="module")
def cornell():
    return load_scene(ROOT / "scenes" / "cornell.toml")


@pytest.fixture(scope="module")
def ref(cornell):
    return Reference(cornell)


@pytest.fixture(scope="module")
def ref_image(ref):
    return render64(ref, W, H)


def test_image_error_known_values():
    ref = np.zeros((4, 5, 3), np.float32)
    assert image_error(ref, ref) == {"psnr_db": float("inf"), "worst_levels": 0,
                                     "share_off_gt_1_level": 0.0}
    img = np.full_like(ref, (10 / 255) / 12.92)       # sRGB8 level 10 (linear segment)
    e = image_error(img, ref)
    assert e["worst_levels"] == 10
    assert e["share_off_gt_1_level"] == 1.0
    # every channel off by exactly 10 levels: MSE = 100 exactly, so the PSNR is exact too
    assert e["psnr_db"] == 10 * np.log10(255.0 ** 2 / 100.0)
    one = ref.copy()
    one[2, 3, 1] = 1.0                                 # one channel of one pixel at 255
    e = image_error(one, ref)
    assert e["worst_levels"] == 255 and e["share_off_gt_1_level"] == 1 / 20
    # one of 60 channels off by 255: MSE = 255^2 / 60 = 1083.75 and 255^2 / MSE = 60, exactly
    assert e["psnr_db"] == 10 * np.log10(60.0)


def test_ray_error_counts():
    ref_tri = np.array([0, 1, 2, -1, -1, 5, 6, 7])
    ref_t = np.arange(1.0, 9.0)
    tri = np.array([0, 1, -1, 4, -1, 9, 6, 7])        # 1 false miss, 1 false hit, 1 wrong
    # relative errors that are powers of two: every product and quotient below is exact
    t = ref_t * np.array([1, 1 + 2**-10, 1, 1, 1, 1, 1 + 2**-9, 1 - 2**-8])
    e = ray_error(tri, t, ref_tri, ref_t)
    assert (e["flips"], e["false_hits"], e["false_misses"], e["wrong_triangle"]) == (2, 1, 1, 1)
    assert e["flip_share"] == 2 / 8
    assert e["t_rel_max"] == 2**-8
    assert e["t_rel_median"] == 1.5 * 2**-10   # of 0, 2^-10, 2^-9, 2^-8 (same-triangle hits)


def test_reference_traces_like_the_binary32_model(cornell, ref):
    """The float64 tracer and the binary32 model on the same rays: same triangles except at
    edges, t within binary32 rounding; flipping 1 % of the model's hits shows as 1 % flips."""
    cfg = Config()
    prep = prepare(cornell, cfg)
    rays = eye_rays(cornell.camera, W, H, cfg)
    hits, _ = trace(prep.image, rays, cfg)
    r_tri, r_t, _, _ = ref.trace(rays.org, rays.dir)
    e = ray_error(hits.tri, hits.t, r_tri, r_t)
    assert e["flips"] + e["wrong_triangle"] <= 0.002 * len(rays)
    assert e["t_rel_max"] < 1e-5 and e["t_rel_median"] < 1e-6
    bad = hits.tri.copy()
    k = np.arange(0, len(bad), 100)
    bad[k] = np.where(bad[k] >= 0, -1, 0)
    assert ray_error(bad, hits.t, r_tri, r_t)["flips"] >= len(k) - e["flips"]


def test_reference_render_matches_binary32_and_wrong_images_score_badly(cornell, ref_image):
    img64, _ = ref_image
    r = render(cornell, Config(), W, H)
    good = image_error(r.image, img64)
    assert good["psnr_db"] >= 45 and good["share_off_gt_1_level"] < 0.01
    shifted = image_error(np.roll(r.image, 1, axis=1), img64)
    assert shifted["psnr_db"] < 30 and shifted["share_off_gt_1_level"] > 0.05
    rng = np.random.default_rng(0)
    noisy = image_error(np.clip(r.image + rng.normal(0, 0.03, r.image.shape), 0, 1)
                        .astype(np.float32), img64)
    assert noisy["psnr_db"] < 40 and noisy["share_off_gt_1_level"] > 0.5


def test_study_scene_orders_formats(cornell):
    """The study on a tiny render: binary32 scores better than E8M10 in image and t error."""
    row = study_scene(cornell, [FPFormat(8, 23), FPFormat(8, 10)], W, H, repeat=1,
                      log=lambda s: None)
    hi, lo = row["formats"]["E8M23"], row["formats"]["E8M10"]
    assert hi["image"]["psnr_db"] > lo["image"]["psnr_db"]
    assert hi["eye"]["t_rel_p99"] < 1e-5 < lo["eye"]["t_rel_p99"]
    assert hi["shadow"]["self_hits"] == 0 and hi["shadow"]["self_hits_float64"] == 0
    # binary32 fields fill the laid-out 32-bit slots; at M = 10 packing would save space
    assert hi["memory"]["geometry_bytes_packed"] == hi["memory"]["geometry_bytes_32bit"]
    assert lo["memory"]["geometry_bytes_packed"] < 0.8 * lo["memory"]["geometry_bytes_32bit"]
    assert hi["memory"]["image_bytes"] >= hi["memory"]["geometry_bytes_32bit"]
    assert hi["rays_per_second"] > 0


def test_leaks_zero_on_closed_mesh_and_found_through_a_hole():
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=2.0)
    fmt = FPFormat(8, 12)
    assert leaks(mesh, fmt, 3000)["leaks"] == 0
    holed = np.asarray(mesh.faces)[np.arange(len(mesh.faces)) % 10 != 0]
    tris = np.asarray(mesh.vertices)[holed]
    assert leaks(mesh, fmt, 3000, tris=tris)["leaks"] > 50


def test_smallest_m_needs_every_larger_m_to_pass():
    def row(psnr, flips):
        return {"image": {"psnr_db": psnr}, "eye": {"flip_share": flips}}
    scene = {"formats": {"E8M23": row(60, 0), "E8M16": row(45, 0), "E8M14": row(41, 0.002),
                         "E8M12": row(42, 0), "E6M13": row(50, 0)}}
    assert smallest_m(scene, {}) == 16
    assert smallest_m(scene, {"box": {"E8M16": {"leaks": 1}}}) == 23
    scene["formats"]["E8M23"] = row(39, 0)
    assert smallest_m(scene, {}) is None


NARROW = (FPFormat(8, 23), FPFormat(8, 16), FPFormat(8, 14), FPFormat(8, 12), FPFormat(8, 10))


def test_narrowest_format_walks_down_and_stops_at_the_first_failure(cornell):
    """The chosen format and every wider one pass the rule, the next narrower one fails and
    the walk ends there; M = 10 never passes on Cornell (its PSNR is far below 40 dB)."""
    r = narrowest_format(cornell, W, H, candidates=NARROW, leak_rays=300)
    names = list(r["formats"])
    assert names == [str(f) for f in NARROW[:len(names)]]
    assert r["fmt"] is not None and r["fmt"] != FPFormat(8, 10)
    k = names.index(str(r["fmt"]))
    assert all(r["formats"][n]["ok"] for n in names[:k + 1])
    assert names[k + 1:] and not r["formats"][names[k + 1]]["ok"] and len(names) == k + 2
    for n in names[:k + 1]:
        row = r["formats"][n]
        assert row["psnr_db"] >= 40 and row["flip_share"] < 1e-3 and row["leaks"] == 0
    # the image measure is the study's own
    study = study_scene(cornell, [r["fmt"]], W, H, quick=True, log=lambda s: None)
    assert study["formats"][str(r["fmt"])]["image"]["psnr_db"] == r["formats"][names[k]]["psnr_db"]


def test_narrowest_format_needs_no_leak_and_can_find_none(cornell, monkeypatch):
    import saarcor.precision as tp
    # a leak at every format below binary32 stops the walk at binary32
    monkeypatch.setattr(tp, "leaks", lambda mesh, fmt, n: {"leaks": int(fmt.frac_bits < 23)})
    r = narrowest_format(cornell, W, H, candidates=NARROW, leak_rays=10)
    assert r["fmt"] == FPFormat(8, 23) and list(r["formats"]) == ["E8M23", "E8M16"]
    assert r["formats"]["E8M16"]["leaks"] > 0
    # a rule nothing meets: no format, and the walk stops at the first
    r = narrowest_format(cornell, W, H, candidates=NARROW, psnr_min=1e9, leak_rays=0)
    assert r["fmt"] is None and list(r["formats"]) == ["E8M23"]
