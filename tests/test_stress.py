"""Numerical stress cases (``tb/stress.py``): the golden model against the exact oracle
(``tb/exact.py``, integer arithmetic), and the RTC (Verilator) against the model, bit for bit.

The RTL cases share one small configuration (2 threads, 2 sub-units, 4x4 packets, memory
latency 4: the one ``tests/test_verilator.py`` builds), so one cached binary serves them all.
"""
from fractions import Fraction

import numpy as np
import pytest

from model.config import Config
from model.fp import FPFormat
from tb import stress
from tb.exact import exact_closest, exact_pairs, moller_trumbore32

vl = pytest.importorskip("tb.verilator")
try:
    vl.verilator_exe()
    HAVE_VERILATOR = True
except vl.VerilatorMissing:
    HAVE_VERILATOR = False
needs_verilator = pytest.mark.skipif(not HAVE_VERILATOR,
                                     reason="verilator not installed (run `make setup`)")

CFG = Config()
TINY = Config(threads=2, tile_w=4, tile_h=4, trav_subunits=2)
LATENCY = 4


def rtl_matches_model(case, cfg=TINY):
    """Run the case's rays on the RTC in Verilator; every ray and counter equals the model's."""
    r = vl.run_frame(case.image, case.rays, cfg, mem_latency=LATENCY, progress=False)
    assert r.rays == len(case.rays)
    assert r.mismatches == [], r.mismatches[:8]
    assert r.counter_mismatches() == {}
    return r


# --- the exact oracle itself ------------------------------------------------------------------

def test_exact_oracle_on_hand_cases():
    """Hand-computed answers: interior hit, exact edge and vertex hits (closed triangle), a
    miss by one float32 ulp, a ray parallel to the plane, a hit behind the origin, tmax."""
    tri = np.array([[[0, 0, 0], [4, 0, 0], [0, 4, 0]]], np.float32)
    ulp = float(np.spacing(np.float32(2.0)))
    org = np.array([[1, 1, 3], [2, 2, 3], [0, 0, 3], [2 + ulp, 2, 3], [1, 1, 0], [1, 1, -3],
                    [1, 1, 3]], np.float32)
    d = np.array([[0, 0, -1], [0, 0, -2], [0, 0, -1], [0, 0, -1], [1, 0, 0], [0, 0, -1],
                  [0, 0, -1]], np.float32)
    tmax = np.array([np.inf] * 6 + [3.0], np.float32)
    ex = exact_closest(tri, org, d, tmax=tmax)
    assert ex.tri.tolist() == [0, 0, 0, -1, -1, -1, -1]
    assert ex.t[:3] == [Fraction(3), Fraction(3, 2), Fraction(3)]


# --- exact ties: a hit at exactly the leaf's far distance ---------------------------------------

def test_tie_case_is_a_tie():
    """The construction holds: on every ray the model's t on P equals the near leaf's tfar bit
    for bit, Q's rounded t is smaller, and exactly P is closer."""
    case = stress.tie_case(CFG)
    assert len(case.rays) == 16
    assert (case.exact.tri == 0).all()
    n = len(case.rays)
    hit, num, den = exact_pairs(case.tris, case.rays.org, case.rays.dir, np.arange(n),
                                np.ones(n, np.int64))
    assert hit.all()
    assert all(Fraction(int(a), int(b)) > t for a, b, t in zip(num, den, case.exact.t))
    tq = stress.single_t(case.tris[1], case.rays.org, case.rays.dir, CFG)
    tp = stress.single_t(case.tris[0], case.rays.org, case.rays.dir, CFG)
    assert (tq < tp).all()


@pytest.mark.parametrize("cfg", [CFG, Config(fmt=FPFormat(8, 16))], ids=["E8M23", "E8M16"])
def test_hit_at_leaf_far_distance_ends_the_ray(cfg):
    """A hit at t == tfar of the leaf terminates the ray there (``t <= tfar``): the model
    reports P, the exact closest triangle, and never visits the lower leaf. A traversal that
    terminates only on ``t < tfar`` reports Q here."""
    from model.rtc import counter_totals, trace
    case = stress.tie_case(cfg)
    hits, ctrs = trace(case.image, case.rays, cfg)
    assert hits.tri.tolist() == case.exact.tri.tolist()
    tot = counter_totals(ctrs)
    assert tot["leaf_visits"] == tot["passes"]          # only the near leaf, once per pass


@needs_verilator
def test_hit_at_leaf_far_distance_rtl():
    """The same rays on the RTC: results and counters equal the model's (so the RTC ends the
    ray in the near leaf and reports P)."""
    case = stress.tie_case(TINY)
    rtl_matches_model(case)


# --- shared edges and vertices of closed meshes -------------------------------------------------

@pytest.mark.parametrize("fmt", [FPFormat(8, 23), FPFormat(8, 12)], ids=str)
@pytest.mark.parametrize("exact", [True, False], ids=["exact_targets", "rounded_targets"])
def test_no_leaks_through_shared_edges(fmt, exact):
    """Rays through vertices and shared edges of closed meshes: the exact oracle says every one
    enters the mesh there; the model reports a hit on every ray, and never a triangle whose
    plane the ray meets away from the entry point. (The float32 Möller–Trumbore baseline on the
    same rounded rays leaks: counted, not asserted, in ``python -m tb.stress``.)"""
    cfg = Config(fmt=fmt)
    for name, mesh in stress.closed_meshes().items():
        case = stress.watertight_case(mesh, cfg, n_max=400, exact=exact)
        v, _ = stress.model_judge(case, cfg)
        assert v["exact_hits"] == v["rays"] >= 300, (name, v)
        assert v["leaks"] == 0 and v["ghosts"] == 0 and v["other_tri_far"] == 0, (name, v)
        if exact:                  # exact targets: a triangle at the target, t within an ulp
            assert v["other_tri"] == 0 and v["t_rel_max"] <= 2.0 ** -fmt.frac_bits, (name, v)


def test_moller_trumbore_baseline_leaks():
    """The baseline really is non-watertight on rays rounded near shared edges (else the
    watertight numbers above would show nothing)."""
    case = stress.watertight_case(stress.closed_meshes()["icosphere"], CFG, n_max=2000,
                                  exact=False)
    assert stress.mt_leaks(case)["leaks"] > 20


# --- axis-parallel, split-plane, grazing and on-surface rays ------------------------------------

@pytest.mark.parametrize("fmt", [FPFormat(8, 23), FPFormat(8, 12)], ids=str)
def test_special_rays_match_exact(fmt):
    """Zero direction components (±0, infinite reciprocals), rays in a split plane, along a
    face's plane, from a point of the surface: hit/miss as the exact oracle says, the right
    triangle, t within 4 ulps. Rays on a face plane of the scene box with a ±0 component
    (0 * inf = NaN in the slab test) used to start inactive and miss."""
    cfg = Config(fmt=fmt)
    case = stress.special_rays_case(cfg)
    v, _ = stress.model_judge(case, cfg)
    g = case.info["groups"]
    assert {k: int((g == k).sum()) for k in set(g)} == {
        "axis": 64, "split_plane": 64, "grazing": 64, "on_surface": 64}
    assert v["exact_hits"] > 100
    assert v["leaks"] == 0 and v["ghosts"] == 0 and v["other_tri"] == 0, v
    assert v["t_rel_max"] <= 2.0 ** (2 - fmt.frac_bits), v


def test_ray_in_box_face_plane_is_not_clipped_away():
    """Ray setup: a ray lying in a face plane of the scene box (d = ±0 on that axis) keeps its
    interval; it hits the box's edge at t = 4 (hand-computed)."""
    from model.raygen import setup
    tris = np.array([[[-1, -1, -1], [1, -1, -1], [1, 1, -1]],
                     [[-1, -1, 1], [1, 1, 1], [1, -1, 1]]], np.float32)
    case_tris, image = stress.image_of(tris, CFG)
    for dx in (0.0, -0.0):
        rays = stress.make_rays([[1.0, 0.25, -5.0]], [[dx, 0.0, 1.0]])
        rs = setup(rays, image.bounds, CFG.fmt)
        assert rs.tnear[0] == 4.0 and rs.tfar[0] == 6.0
        from model.rtc import trace
        hits, _ = trace(image, rays, CFG)
        assert hits.tri[0] == 0 and hits.t[0] == 4.0


@needs_verilator
def test_edge_and_special_rays_rtl():
    """The RTC on the exact-target edge rays (icosphere) and the special rays: bit-identical
    to the model (whose answers the tests above check against the exact oracle)."""
    mesh = stress.closed_meshes()["icosphere"]
    rtl_matches_model(stress.watertight_case(mesh, TINY, n_max=256, exact=False, packet=16))
    rtl_matches_model(stress.special_rays_case(TINY, n_each=32, packet=16))
