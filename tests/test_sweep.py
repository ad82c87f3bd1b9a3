"""Design-space sweeps (``saarcor/sweep.py``): the spec, the per-point cache, the table, failures,
and the cluster options, on a local Dask cluster of two worker processes."""
import csv
import dataclasses
import json

import pytest

from model.config import Config
from saarcor import sweep

from .conftest import ROOT

TINY_SPEC = ROOT / "scenes/sweeps/tiny.toml"
CORNELL = ROOT / "scenes/cornell.toml"


@pytest.fixture(scope="module")
def scheduler():
    """The address of a local cluster of two worker processes (one thread each)."""
    import logging

    from distributed import LocalCluster
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=":0", silence_logs=logging.ERROR) as cluster:
        yield cluster.scheduler_address


def read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def run(args, capsys):
    """``saarcor.sweep.main(args)``: (exit status, printed output)."""
    rc = sweep.main([str(a) for a in args] + ["--quiet"])
    return rc, capsys.readouterr().out


def write_spec(path, text):
    path.write_text(text)
    return path


def test_tiny_sweep_table_then_all_cached(tmp_path, scheduler, kd_cache, capsys):
    """Two configurations of the golden model on Cornell 8x8: a table of 2 rows with every
    Config field and the model's own figures; a second run computes nothing and writes the
    same table."""
    from model.render import prepare, render
    from model.scene import load_scene
    out, cache = tmp_path / "out", tmp_path / "cache"
    args = [TINY_SPEC, "--out", out, "--cache", cache, "--scheduler", scheduler,
            "--kd-cache", kd_cache]
    rc, text = run(args, capsys)
    assert rc == 0, text
    assert "2 points, 0 cached, 2 computed, 0 failed" in text
    assert "dashboard" in text
    rows = read_csv(out / "results.csv")
    assert len(rows) == 2
    for f in dataclasses.fields(Config):
        assert f.name in rows[0], f.name
    assert [r["kd_max_depth"] for r in rows] == ["8", "16"]
    assert {r["reflect_depth"] for r in rows} == {"1"}
    assert {r["status"] for r in rows} == {"ok"} and {r["error"] for r in rows} == {""}
    assert {r["scene"] for r in rows} == {"../cornell.toml"}
    assert {r["resolution"] for r in rows} == {"8x8"}
    # the measures are the model's: the same render made here gives the same counts
    scene = load_scene(CORNELL)
    for r in rows:
        cfg = Config(kd_max_depth=int(r["kd_max_depth"]), reflect_depth=1)
        stats = render(scene, cfg, 8, 8, prepared=prepare(scene, cfg, cache_dir=kd_cache)).stats
        for name in ("rays_total", "counters.trav_ops", "counters.int_ops",
                     "counters_by_kind.shadow.node_reads", "kdtree.depth", "rays.eye"):
            want = sweep.flatten(stats)[name]
            assert int(r[name]) == want, name
    assert rows[0]["counters.trav_ops"] != rows[1]["counters.trav_ops"]
    assert len(list(cache.glob("*.json"))) == 2
    first = (out / "results.csv").read_text()

    rc, text = run(args, capsys)
    assert rc == 0
    assert "2 points, 2 cached, 0 computed, 0 failed" in text
    assert "dashboard" not in text            # nothing to compute: no cluster at all
    assert (out / "results.csv").read_text() == first
    try:
        import pyarrow.parquet as pq
    except ImportError:
        return
    t = pq.read_table(out / "results.parquet")
    assert t.num_rows == 2 and t.column("kd_max_depth").to_pylist() == [8, 16]


def test_failing_point_is_recorded_and_the_others_complete(tmp_path, scheduler, kd_cache,
                                                          capsys):
    """A missing scene fails its point (status error, the loader's message) without stopping
    the sweep; only the good point is cached, and the failed one is retried next time."""
    spec = write_spec(tmp_path / "fail.toml", f"""
backend = "model"
scenes = ["{CORNELL.as_posix()}", "no_such_scene.toml"]
resolutions = ["8x8"]
[config]
reflect_depth = 0
""")
    out, cache = tmp_path / "out", tmp_path / "cache"
    args = [spec, "--out", out, "--cache", cache, "--scheduler", scheduler,
            "--kd-cache", kd_cache]
    rc, text = run(args, capsys)
    assert rc == 1
    assert "2 points, 0 cached, 2 computed, 1 failed" in text
    rows = read_csv(out / "results.csv")
    assert [r["status"] for r in rows] == ["ok", "error"]
    assert int(rows[0]["rays.eye"]) == 64 and rows[0]["error"] == ""
    assert rows[1]["scene"] == "no_such_scene.toml"
    assert "SceneError" in rows[1]["error"] and "does not exist" in rows[1]["error"]
    assert rows[1]["rays.eye"] == ""
    assert "no_such_scene.toml" in (out / "errors.txt").read_text()
    assert len(list(cache.glob("*.json"))) == 1

    rc, text = run(args, capsys)
    assert rc == 1 and "2 points, 1 cached, 1 computed, 1 failed" in text


@pytest.mark.parametrize("body, message", [
    ('[grid]\nrtc = [1, 2]', "unknown Config field 'rtc' (did you mean rtcs"),
    ('[config]\nthreads = "two"', "threads = 'two' must be an int"),
    ('[grid]\ntrav_subunits = [2, 3]', "trav_subunits=3"),
    ('[[point]]\nfmt = "E8"', "fmt 'E8'"),
    ('[[point]]\nresolutions = ["8x"]', "resolution '8x'"),
])
def test_spec_errors_name_the_problem(tmp_path, body, message):
    spec = write_spec(tmp_path / "bad.toml",
                      f'backend = "model"\nscenes = ["x.toml"]\nresolutions = ["8x8"]\n{body}\n')
    with pytest.raises(SystemExit) as e:
        sweep.main([str(spec), "--cache", str(tmp_path / "c")])
    assert message in str(e.value) and "bad.toml" in str(e.value)


@pytest.mark.parametrize("text, message", [
    ('backend = "model"\nscenes = ["a.toml"]\nresolutions = ["64X"]', "resolution '64X'"),
    ('backend = "rtl"\nscenes = ["a.toml"]\nresolutions = ["8x8"]', 'backend = "chip"'),
    ('backend = "model"\nscene = ["a.toml"]\nresolutions = ["8x8"]', "unknown key(s) scene"),
    ('backend = "model"\nresolutions = ["8x8"]', "give scenes"),
    ('backend = "chip"\nscenes = ["a.toml"]\nresolutions = ["8x8"]\nmem_words = 1000',
     "mem_words = 1000 must be a power of two"),
    ('backend = "chip"\nscenes = ["a.toml"]\nresolutions = ["8x8"]\npreset = "papr"',
     "preset = 'papr': choose one of standard, paper"),
])
def test_spec_top_level_errors(tmp_path, text, message):
    with pytest.raises(sweep.SpecError) as e:
        sweep.load_spec(write_spec(tmp_path / "bad.toml", text))
    assert message in str(e.value)


def test_spec_grid_points_and_skip_invalid(tmp_path):
    """The grid's cartesian product over scenes and resolutions, then the explicit points
    (with their own scenes); duplicates once; invalid grid combinations skipped on request."""
    spec = sweep.load_spec(write_spec(tmp_path / "s.toml", """
backend = "chip"
scenes = ["a.toml", "b.toml"]
resolutions = ["8x8", "16x12"]
skip_invalid = true
[config]
mem_latency = 8
[grid]
rtcs = [1, 2]
trav_subunits = [2, 3]
[[point]]
rtcs = 1
trav_subunits = 2
scenes = ["a.toml"]
resolutions = ["8x8"]
[[point]]
fmt = {exp_bits = 6, frac_bits = 12}
cache_ways = 2
scenes = ["a.toml"]
"""))
    # 2 rtcs x (trav_subunits 2; 3 does not divide 64) x 2 scenes x 2 resolutions, then the
    # second point's 2 resolutions (the first point is a grid point already)
    assert len(spec.points) == 2 * 2 * 2 + 2
    assert len(spec.skipped) == 2 and "trav_subunits=3" in spec.skipped[0]
    p = spec.points[0]
    assert (p.config["rtcs"], p.config["mem_latency"], p.scene, p.width, p.height) == \
        (1, 8, "a.toml", 8, 8)
    assert p.scene_path == str((tmp_path / "a.toml").resolve())
    last = spec.points[-1]
    assert (last.config["fmt"], last.config["cache_ways"], last.width) == ("E6M12", 2, 16)
    assert last.cfg().fmt.frac_bits == 12


def test_spec_preset_is_the_start_of_every_point(tmp_path):
    """``preset = "paper"``: every point starts from the preset's fields, ``[config]`` and the
    grid on top of them."""
    from model.config import preset
    spec = sweep.load_spec(write_spec(tmp_path / "p.toml", """
backend = "chip"
scenes = ["a.toml"]
resolutions = ["8x8"]
preset = "paper"
[config]
rgs_fp_muls = 8
[grid]
rtcs = [1, 2]
"""))
    assert [p.cfg() for p in spec.points] == [preset("paper", rgs_fp_muls=8, rtcs=r)
                                              for r in (1, 2)]


def test_cache_key_follows_config_scene_and_resolution(tmp_path):
    scene = tmp_path / "s.toml"
    scene.write_bytes(CORNELL.read_bytes())
    spec = sweep.load_spec(write_spec(tmp_path / "k.toml", """
backend = "model"
scenes = ["s.toml"]
resolutions = ["8x8", "8x4"]
[grid]
rtcs = [1, 2]
"""))
    code = sweep.code_hash()
    keys = [sweep.point_key(p, code) for p in spec.points]
    assert len(set(keys)) == 4
    assert sweep.point_key(spec.points[0], code) == keys[0]
    assert sweep.point_key(spec.points[0], "other code") != keys[0]
    scene.write_text(scene.read_text() + "\n# an edit\n")
    assert sweep.point_key(spec.points[0], code) != keys[0]


def test_cache_key_follows_a_view_s_base_scene(tmp_path):
    """A view (base = "...") hashes its base scene and the files the base reads."""
    (tmp_path / "tex").mkdir()
    (tmp_path / "tex" / "t.png").write_bytes(b"one")
    base = tmp_path / "base.toml"
    base.write_text(CORNELL.read_text() + '\n[[material]]\nname = "pic"\ntexture = "tex/t.png"\n')
    (tmp_path / "views").mkdir()
    view = tmp_path / "views" / "v.toml"
    view.write_text('base = "../base.toml"\n')
    h0 = sweep.scene_hash(view)
    (tmp_path / "tex" / "t.png").write_bytes(b"two")
    h1 = sweep.scene_hash(view)
    base.write_text(base.read_text() + "\n# an edit\n")
    h2 = sweep.scene_hash(view)
    assert len({h0, h1, h2}) == 3


def test_flatten_names_nested_scalars():
    assert sweep.flatten({"a": 1, "b": {"c": 2.5, "d": [{"e": "x"}, 4]}, "f": None}) == \
        {"a": 1, "b.c": 2.5, "b.d.0.e": "x", "b.d.1": 4, "f": None}


def test_cluster_class_option_stands_in_for_jobqueue(tmp_path, kd_cache, capsys):
    """``--cluster module:Class`` with ``--cluster-option``s (how dask-jobqueue's SLURM or
    PBS clusters are used) with distributed's LocalCluster standing in, scaled to
    ``--workers``."""
    spec = write_spec(tmp_path / "one.toml", f"""
backend = "model"
scenes = ["{CORNELL.as_posix()}"]
resolutions = ["8x4"]
[config]
reflect_depth = 0
""")
    rc, text = run([spec, "--out", tmp_path / "out", "--cache", tmp_path / "cache",
                    "--kd-cache", kd_cache, "--cluster", "distributed:LocalCluster",
                    "--cluster-option", "n_workers=0", "--cluster-option", "processes=false",
                    "--cluster-option", "dashboard_address=:0", "--workers", "1"], capsys)
    assert rc == 0, text
    assert "1 points, 0 cached, 1 computed, 0 failed" in text
    assert int(read_csv(tmp_path / "out/results.csv")[0]["rays.eye"]) == 32
    with pytest.raises(SystemExit, match="KEY=VALUE"):
        sweep.main([str(spec), "--cache", str(tmp_path / "c2"), "--cluster-option", "cores"])
    with pytest.raises(SystemExit, match="cannot load"):
        sweep.main([str(spec), "--cache", str(tmp_path / "c2"), "--cluster", "nosuch:Cluster"])


def test_option_values_are_typed():
    assert sweep._option_value("4") == 4 and sweep._option_value("0.5") == 0.5
    assert sweep._option_value("true") is True
    assert sweep._option_value("4GB") == "4GB" and sweep._option_value("01:00:00") == "01:00:00"
    assert sweep._option_value('["--gres=gpu:1"]') == ["--gres=gpu:1"]


# the small chip of tests/test_chip.py (its Verilator binary is shared with those tests)
CHIP_SMALL = """
[config]
rtcs = 2
threads = 2
tile_w = 4
tile_h = 4
trav_subunits = 2
trav_cache_kb = 1
list_cache_kb = 1
int_cache_kb = 9
mem_latency = 8
"""


def test_chip_backend_point(tmp_path, scheduler, kd_cache, capsys):
    """A chip point: the binary is built (or found) by the build job before the point runs,
    so the point itself builds nothing; its row holds make sim's figures, the same cycles as
    a direct run, with the frame's shadow and reflection rays (the Config asks for them)."""
    from model.render import prepare
    from model.scene import load_scene
    from tb.harness.chip import run_chip_frame
    spec = write_spec(tmp_path / "chip.toml", f"""
backend = "chip"
scenes = ["{CORNELL.as_posix()}"]
resolutions = ["8x8"]
{CHIP_SMALL}""")
    rc, text = run([spec, "--out", tmp_path / "out", "--cache", tmp_path / "cache",
                    "--scheduler", scheduler, "--kd-cache", kd_cache], capsys)
    assert rc == 0, text
    assert "1 chip configuration(s) to build" in text
    row, = read_csv(tmp_path / "out/results.csv")
    assert row["status"] == "ok" and row["mismatches"] == "0"
    assert row["build.built"] == "False"
    assert (row["rtcs"], row["threads"], row["int_cache_kb"]) == ("2", "2", "9")
    for name in ("fps", "relative_performance", "cache.trav.hit_rate",
                 "memory.per_chip.3.words", "units.per_rtc.1.int", "counters.rtc.0.trav_ops"):
        assert row[name] != "", name
    cfg = sweep.load_spec(spec).points[0].cfg()
    scene = load_scene(CORNELL)
    direct = run_chip_frame(cfg, prepare(scene, cfg, cache_dir=kd_cache).image, scene.camera,
                            8, 8, progress=False, scene=scene)
    assert int(row["cycles"]) == direct.cycles
    assert int(row["rays_total"]) == len(direct.frame_rays) > int(row["rays.eye"]) == 64
    assert int(row["rays.shadow"]) > 0                 # the slaves' shadow rays, traced
    stored = json.loads(next((tmp_path / "cache").glob("*.json")).read_text())
    assert stored["stats"]["cycles"] == direct.cycles
