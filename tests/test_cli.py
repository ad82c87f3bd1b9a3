"""The golden model's command line: outputs, their formats, and errors for bad input."""
import json
import subprocess
import sys

import numpy as np
from PIL import Image

from .conftest import ROOT


def run(*args, cwd=ROOT):
    return subprocess.run([sys.executable, "-m", "model", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=600)


def test_render_writes_image_stats_rays_hits(tmp_path):
    out = tmp_path / "out"
    r = run("render", "scenes/cornell.toml", "--res", "24x16", "--out", str(out),
            "--reflect-depth", "1")
    assert r.returncode == 0, r.stderr
    assert "trav-ops" in r.stdout
    img = Image.open(out / "image.png")
    assert img.size == (24, 16)
    assert np.asarray(img).std() > 5                      # not a blank picture
    rays = np.load(out / "rays.npz")
    hits = np.load(out / "hits.npz")
    n = len(rays["kind"])
    assert rays["origin"].shape == (n, 3) and rays["origin"].dtype == np.float32
    assert rays["direction"].shape == (n, 3) and rays["direction"].dtype == np.float32
    assert rays["tmax"].dtype == np.float32 and rays["kind"].dtype == np.uint8
    assert rays["pixel"].dtype == np.int32 and rays["pixel"].max() < 24 * 16
    assert np.isinf(rays["tmax"][rays["kind"] == 0]).all()
    assert hits["tri"].dtype == np.int32 and len(hits["tri"]) == n
    for f in ("t", "u", "v"):
        assert hits[f].dtype == np.float32 and len(hits[f]) == n
    assert np.isinf(hits["t"][hits["tri"] < 0]).all()
    stats = json.loads((out / "stats.json").read_text())
    kinds = np.bincount(rays["kind"], minlength=3)
    assert stats["rays"]["eye"] == kinds[0] == 24 * 16
    assert stats["rays"]["shadow"] == kinds[1] > 0
    assert stats["rays_total"] == n
    for key in ("trav_ops", "int_ops", "list_ops"):
        assert stats["counters"][key] > 0
    assert set(stats["memory_reads_64bit"]) == {"trav", "list", "int"}
    assert stats["kdtree"]["depth"] <= stats["config"]["kd_max_depth"]
    assert stats["render_seconds"] > 0 and "build_seconds" in stats


def test_render_a_bare_mesh(tmp_path):
    obj = tmp_path / "tet.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    r = run("render", str(obj), "--res", "16x16", "--out", str(tmp_path / "o"), "--quiet")
    assert r.returncode == 0, r.stderr
    hits = np.load(tmp_path / "o" / "hits.npz")
    assert set(np.unique(hits["tri"][hits["tri"] >= 0])) <= {0, 1, 2, 3}
    assert (hits["tri"] >= 0).sum() > 10                  # the camera frames the mesh


def test_bad_input_gives_clear_errors(tmp_path):
    r = run("render", str(tmp_path / "missing.toml"), "--out", str(tmp_path))
    assert r.returncode == 2 and "missing.toml" in r.stderr and "Traceback" not in r.stderr
    r = run("render", "scenes/cornell.toml", "--res", "12by8")
    assert r.returncode == 2 and "--res" in r.stderr
    r = run("render", "scenes/cornell.toml", "--frac-bits", "30", "--out", str(tmp_path))
    assert r.returncode == 2 and "frac_bits" in r.stderr and "Traceback" not in r.stderr
    r = run("render", "scenes/cornell.toml", "--tile", "16x8", "--out", str(tmp_path))
    assert r.returncode == 2 and "64" in r.stderr
    bad = tmp_path / "nan.obj"
    bad.write_text("v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n")
    r = run("render", str(bad), "--out", str(tmp_path))
    assert r.returncode == 2 and "NaN" in r.stderr and "Traceback" not in r.stderr


def test_help_explains_every_option():
    r = run("render", "--help")
    assert r.returncode == 0
    for opt in ("--res", "--out", "--frac-bits", "--exp-bits", "--reflect-depth",
                "--oversampling", "--no-shadows", "--kd-depth", "--leaf-size", "--tile"):
        assert opt in r.stdout


def test_oversampling_traces_n_squared_rays_per_pixel(tmp_path):
    r = run("render", "scenes/cornell.toml", "--res", "16x8", "--oversampling", "2",
            "--reflect-depth", "0", "--no-shadows", "--out", str(tmp_path), "--quiet")
    assert r.returncode == 0, r.stderr
    rays = np.load(tmp_path / "rays.npz")
    eye = rays["kind"] == 0
    assert eye.sum() == 4 * 16 * 8
    assert np.array_equal(np.bincount(rays["pixel"][eye], minlength=128), np.full(128, 4))
    stats = json.loads((tmp_path / "stats.json").read_text())
    assert 0 < stats["lane_utilization"]["trav"] <= 1
