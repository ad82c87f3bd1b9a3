"""Golden-model ray tracing against Intel Embree, plus self-consistency of the packet tracer."""
import numpy as np
import pytest

from model.config import Config
from model.fp import FPFormat
from model.kdtree import build_kdtree
from model.layout import build_image
from model.oracle import Embree, compare
from model.raygen import Rays, eye_rays
from model.raykind import RayKind
from model.render import prepare, render
from model.rtc import C, trace
from model.scene import load_scene

from .conftest import ROOT, SHARED_MESHES, needs_shared_meshes, scene_params

CFG = Config(reflect_depth=2)
CONFERENCE = ROOT / "scenes" / "conference.toml"      # a mid-sized scene of many objects


def rays_from(org, dirn, tmax=None, packet=64, kind=0):
    n = len(dirn)
    tmax = np.full(n, np.inf, np.float32) if tmax is None else tmax.astype(np.float32)
    pk = np.arange(0, n + packet, packet)
    pk[-1] = n
    pk = np.unique(pk)
    return Rays(np.ascontiguousarray(org, np.float32), np.ascontiguousarray(dirn, np.float32),
                tmax, np.full(n, kind, np.uint8), np.arange(n, dtype=np.int32), pk.astype(np.int64))


def image_of(tris, cfg, kd_cache):
    tris = cfg.fmt.quantize(tris).astype(np.float32)
    tree = build_kdtree(tris, cfg, cache_dir=kd_cache)
    return tris, build_image(tris, tree, cfg)


def check_against_embree(scene, cfg, res, kd_cache):
    prep = prepare(scene, cfg, cache_dir=kd_cache)
    result = render(scene, cfg, *res, prepared=prep)
    r, h = result.rays, result.hits
    by_id = np.zeros((scene.n_scene_tris, 3, 3), np.float32)
    by_id[scene.tri_id] = prep.tris
    emb = Embree(prep.tris, scene.tri_id).intersect(r.org, r.dir, r.tmax)
    rep = compare((h.tri, h.t), emb, r.org, r.dir, by_id, closest=r.kind != RayKind.SHADOW)
    assert rep["hit_agreement"] >= 0.9999, rep
    assert rep["disagreements"] == rep["disagreements_explained"], rep
    assert not rep["t_errors"], rep
    return rep, result


@pytest.mark.parametrize("path", scene_params())
def test_shipped_scenes_agree_with_embree(path, kd_cache):
    scene = load_scene(path)
    rep, result = check_against_embree(scene, CFG, (48, 36), kd_cache)
    assert rep["both_hit"] > 100                         # the scene is actually in view
    assert set(result.stats["rays"]) >= ({"eye", "shadow"} if scene.lights else {"eye"})


MESHES = ["teapot", "bunny", "spot", "cruiser", "f-16", "dragon", "nefertiti"]


@needs_shared_meshes
@pytest.mark.parametrize("name", MESHES)
def test_real_meshes_agree_with_embree(name, kd_cache):
    scene = load_scene(SHARED_MESHES / f"{name}.obj")
    rep, _ = check_against_embree(scene, Config(reflect_depth=1), (64, 48), kd_cache)
    assert rep["both_hit"] > 100                         # the mesh is in view


def test_random_soup_agrees_with_embree(kd_cache):
    rng = np.random.default_rng(7)
    centers = rng.uniform(-10, 10, (3000, 1, 3))
    tris = (centers + rng.normal(0, 0.6, (3000, 3, 3))).astype(np.float32)
    tris, image = image_of(tris, CFG, kd_cache)
    org = CFG.fmt.quantize(rng.uniform(-14, 14, (20000, 3)))
    dirn = CFG.fmt.quantize(rng.normal(0, 1, (20000, 3)))
    rays = rays_from(org, dirn)
    hits, _ = trace(image, rays, CFG)
    emb = Embree(tris).intersect(org, dirn)
    rep = compare((hits.tri, hits.t), emb, org, dirn, tris)
    assert rep["hit_agreement"] >= 0.9999 and rep["both_hit"] > 5000, rep
    assert rep["disagreements"] == rep["disagreements_explained"], rep
    assert not rep["t_errors"], rep


@pytest.mark.parametrize("fmt", [FPFormat(8, 23), FPFormat(8, 14)], ids=str)
def test_packets_equal_single_rays(fmt, kd_cache):
    """Packets (with mixed direction octants) give bit-identical results to one-ray packets."""
    cfg = Config(fmt=fmt)
    scene = load_scene(CONFERENCE)
    prep = prepare(scene, cfg, cache_dir=kd_cache)
    rays = eye_rays(scene.camera, 40, 24, cfg)
    rng = np.random.default_rng(3)
    # perturb directions so packets mix octants; tmax finite on some rays; some shadow rays
    d = cfg.fmt.quantize(rays.dir + rng.normal(0, 0.3, rays.dir.shape))
    tmax = np.where(rng.random(len(d)) < 0.3, np.float32(2.5), np.float32(np.inf))
    packed = rays_from(rays.org, d, tmax)
    packed.anyhit = rng.random(len(d)) < 0.2
    single = rays_from(rays.org, d, tmax, packet=1)
    single.anyhit = packed.anyhit
    h64, c64 = trace(prep.image, packed, cfg)
    h1, c1 = trace(prep.image, single, cfg)
    closest = ~packed.anyhit
    for f in ("tri", "t", "u", "v"):
        a, b = getattr(h64, f), getattr(h1, f)
        assert np.array_equal(a[closest].view(np.uint32), b[closest].view(np.uint32)), f
    assert np.array_equal(h64.tri >= 0, h1.tri >= 0)      # any-hit rays: hit/miss only
    assert c64[:, C["passes"]].sum() > packed.n_packets   # some packets did split by octant
    # per ray, packets do the same ray work or less than... the same: trav-ops may differ
    # (a packet visits nodes a lone ray would skip only with an inactive mask), int-ops too;
    # but node fetches are shared: far fewer per ray in packets.
    assert c64[:, C["node_reads"]].sum() < c1[:, C["node_reads"]].sum() / 4


def test_counters_are_consistent(kd_cache):
    scene = load_scene(CONFERENCE)
    prep = prepare(scene, CFG, cache_dir=kd_cache)
    rays = eye_rays(scene.camera, 64, 48, CFG)
    hits, ctr, ev = trace(prep.image, rays, CFG, record=True)
    tot = ctr.sum(axis=0)
    # int_steps and int_reads against counts of the event log (not the counters' own formula):
    # one triangle fetch of 5 consecutive words per triangle request of the list unit
    from model.events import EV_TRI
    from model.rtc import memory_trace
    assert (ev["kind"] == EV_TRI).sum() == tot[C["int_steps"]] == tot[C["list_ops"]]
    words = np.asarray(memory_trace(ev, prep.image)["int"])
    assert len(words) == tot[C["int_reads"]] == 5 * (ev["kind"] == EV_TRI).sum()
    assert (np.diff(words.reshape(-1, 5), axis=1) == 1).all()
    assert tot[C["trav_ops"]] <= 64 * tot[C["trav_steps"]]
    assert tot[C["int_ops"]] <= 64 * tot[C["int_steps"]]
    assert tot[C["node_reads"]] >= tot[C["trav_steps"]] + tot[C["leaf_visits"]]
    assert 0 < ctr[:, C["max_stack"]].max() <= CFG.kd_max_depth
    # independent count of int-ops: brute force says every hit ray was tested at least once
    assert tot[C["int_ops"]] >= (hits.tri >= 0).sum()


def test_reduced_precision_still_close_to_embree(kd_cache):
    """M=16: results are not binary32's, but stay geometrically right (hit/miss vs Embree)."""
    cfg = Config(fmt=FPFormat(8, 16), reflect_depth=0)
    scene = load_scene(CONFERENCE)
    prep = prepare(scene, cfg, cache_dir=kd_cache)
    rays = eye_rays(scene.camera, 48, 36, cfg)
    hits, _ = trace(prep.image, rays, cfg)
    emb = Embree(prep.tris, scene.tri_id).intersect(rays.org, rays.dir)
    assert ((hits.tri >= 0) == (emb[0] >= 0)).mean() > 0.995


def test_event_log_matches_counters_and_results(kd_cache):
    """The recorded unit streams add up to the counters and reproduce every ray's result."""
    from model.events import EV_DONE, EV_INT, EV_NODE, EV_TRI
    from model.rtc import memory_trace
    scene = load_scene(CONFERENCE)
    prep = prepare(scene, CFG, cache_dir=kd_cache)
    rays = eye_rays(scene.camera, 24, 16, CFG)
    hits, ctr, ev = trace(prep.image, rays, CFG, record=True)
    hits2, ctr2 = trace(prep.image, rays, CFG)
    assert np.array_equal(ctr, ctr2) and np.array_equal(hits.t.view(np.uint32), hits2.t.view(np.uint32))
    kind = ev["kind"]
    tot = ctr.sum(axis=0)
    assert (kind == EV_NODE).sum() == tot[C["trav_steps"]]
    assert (kind == EV_TRI).sum() == tot[C["list_ops"]]
    assert (kind == EV_INT).sum() == tot[C["int_ops"]]
    assert (kind == EV_DONE).sum() == rays.n_packets
    popc = [bin(int(m)).count("1") for m in ev["mask"][kind == EV_NODE]]
    assert sum(popc) == tot[C["trav_ops"]] == np.bitwise_count(ev["mask"][kind == EV_NODE]).sum()
    # the last accepted int-op of each ray is its result
    ints = ev[(kind == EV_INT) & ((ev["flags"] & 2) != 0)]
    ray = rays.pk_start[ints["packet"]] + ints["lane"]
    last = {}
    for r, tb in zip(ray, ints["t"]):
        last[r] = tb
    hit_rays = np.nonzero(hits.tri >= 0)[0]
    assert set(last) == set(hit_rays.tolist())
    assert all(hits.t[r].view(np.uint32) == last[r] for r in hit_rays)
    mt = memory_trace(ev, prep.image)
    assert len(mt["trav"]) == tot[C["node_reads"]]
    assert len(mt["list"]) == tot[C["list_reads"]]
    assert len(mt["int"]) == tot[C["int_reads"]]
    assert (mt["trav"] >= prep.image.node_base).all() and (mt["int"] >= prep.image.tri_base).all()


def test_scatter_visits_every_task_once():
    """The parallel kernels' task order (``scatter_task``) is a permutation of the tasks, and
    each half of it (what one of two threads gets) spreads over the whole range."""
    from model.rtc import scatter_step, scatter_task
    for n in list(range(1, 300)) + [768, 1024, 12288]:
        step = scatter_step(n)
        order = np.array([scatter_task(j, step, n) for j in range(n)])
        assert np.array_equal(np.sort(order), np.arange(n)), n
        if n >= 100:
            first = order[: n // 2]
            assert first.min() < n // 10 and first.max() > n - n // 10
            assert abs(np.mean(first) - (n - 1) / 2) < n / 20


@pytest.mark.parametrize("fmt", [FPFormat(8, 23), FPFormat(8, 14)], ids=str)
def test_one_value_stack_decides_as_two_values(fmt, kd_cache):
    """``trav_stack="one_value"`` (one value and a bit a lane and level) takes every decision
    the far interval's two values take: the same hits, bit for bit, and the same counts of
    every unit, packet by packet. The rays mix direction octants, shadow rays and finite tmax,
    and a quarter of them have a zero direction component from an origin on a grid of
    coordinates (a ray in a split plane has a NaN distance and needs both children)."""
    scene = load_scene(CONFERENCE)
    two = Config(fmt=fmt)
    one = two.replace(trav_stack="one_value")
    prep = prepare(scene, two, cache_dir=kd_cache)
    rays = eye_rays(scene.camera, 48, 32, two)
    rng = np.random.default_rng(11)
    d = rays.dir + rng.normal(0, 0.3, rays.dir.shape)
    flat = rng.random(len(d)) < 0.25
    d[flat, rng.integers(0, 3, flat.sum())] = 0
    org = rays.org.copy()
    org[flat] = np.round(org[flat])
    tmax = np.where(rng.random(len(d)) < 0.3, np.float32(2.5), np.float32(np.inf))
    packed = rays_from(fmt.quantize(org), fmt.quantize(d), tmax)
    packed.anyhit = rng.random(len(d)) < 0.2
    h2, c2 = trace(prep.image, packed, two)
    h1, c1 = trace(prep.image, packed, one)
    for f in ("tri", "t", "u", "v"):
        assert np.array_equal(getattr(h1, f).view(np.uint32), getattr(h2, f).view(np.uint32)), f
    assert np.array_equal(c1, c2)
    assert c2[:, C["pushes"]].sum() > packed.n_packets        # the stack was used
    assert (h2.tri >= 0).sum() > len(d) // 4
