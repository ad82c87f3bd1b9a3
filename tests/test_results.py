"""``saarcor results`` (saarcor/results.py): a tiny plan fills every table of the page.

The golden-model sweeps run for real (Cornell 8x8); the chip points are put in the result
cache beforehand (a chip frame needs a Verilator build of minutes), with figures made up here,
so the test checks that each table shows what its sweep measured."""
import csv
import json
import os
import re
from pathlib import Path

import pytest

from model.config import Config
from saarcor import results
from saarcor import sweep
from saarcor.sim import relative_performance

from .conftest import ROOT

CORNELL = ROOT / "scenes" / "cornell.toml"
TINY = ROOT / "scenes" / "sweeps" / "tiny.toml"


def spec(path, backend, body, res="8x8", scenes=(CORNELL,)):
    names = ", ".join(f'"{s}"' for s in scenes)
    path.write_text(f'backend = "{backend}"\nscenes = [{names}]\nresolutions = ["{res}"]\n' + body)
    return path


def fake_chip_stats(cfg: Config, eye: int) -> dict:
    """Plausible figures of a chip frame of ``eye`` eye rays and the shadow (3 lights) and
    reflection rays its configuration asks for, different for every configuration."""
    kinds = {"eye": eye, "shadow": 3 * eye if cfg.shadows else 0,
             "reflection": eye // 8 if cfg.reflect_depth else 0}
    if cfg.refraction:              # a chip built without refraction has no such count
        kinds["refraction"] = eye // 16 if cfg.reflect_depth else 0
    rays = sum(kinds.values())
    cycles = 40_000 // cfg.rtcs + 9_000 * 144 // cfg.int_cache_kb + 3_000 * 4 // cfg.mem_chips
    cycles = cycles * rays // 256 + 7 * cfg.reflect_depth + 5 * cfg.refraction
    trav, inter = 30 * rays, 6 * rays
    per_rtc = [{"trav": 0.5 + 0.01 * r, "trav_subunits": 0.4, "list": 0.3, "int": 0.6}
               for r in range(cfg.rtcs)]
    return {"cycles": cycles, "rays_total": rays, "rays": kinds, "trav_ops": trav,
            "int_ops": inter,
            **relative_performance(cfg, cycles, trav, inter),
            "cache": {k: {"hit_rate": h + 0.01 * cfg.oversampling + 0.001 * cfg.reflect_depth
                              + 0.002 * (eye > 256), "memory_words": w}
                      for k, h, w in (("trav", 0.8, 300), ("list", 0.7, 100), ("int", 0.9, 600))},
            "units": {"per_rtc": per_rtc},
            "memory": {"per_chip": [{"share": 1 / cfg.mem_chips}] * cfg.mem_chips},
            "bus": {"words_per_cycle": 0.1},
            "limiter": {"limit": f"limit-of-{cfg.rtcs}", "why": "made up"}}


def precache(spec_path, cache):
    s = sweep.load_spec(spec_path)
    code = sweep.code_hash()
    stats = {}
    for p in s.points:
        cfg = p.cfg()
        st = fake_chip_stats(cfg, p.width * p.height * cfg.oversampling ** 2)
        key = sweep.point_key(p, code)
        sweep._cache_write(cache / f"{key}.json", key, p,
                           {"status": "ok", "error": None, "stats": st, "seconds": 2.0})
        stats[(cfg.rtcs, cfg.int_cache_kb, cfg.mem_chips, cfg.oversampling, cfg.reflect_depth,
               cfg.shadows, p.width)] = st
    return stats


def make_plan(tmp_path, scenes=(CORNELL,)):
    d = tmp_path / "plan"
    d.mkdir()
    spec(d / "rays.toml", "model", "", scenes=scenes)
    spec(d / "raykinds.toml", "model", "".join(
        f"[[point]]\nreflect_depth = {r}\nshadows = {s}\noversampling = {o}\n"
        for r, s, o in ((0, "false", 1), (3, "false", 1), (0, "true", 1), (3, "true", 1),
                        (0, "false", 2))))
    spec(d / "rtcs.toml", "chip", "[grid]\nrtcs = [1, 2, 4]\n", "16x16")
    spec(d / "intcache.toml", "chip", "[config]\nrtcs = 4\n[grid]\nint_cache_kb = [144, 576]\n"
                                      "mem_chips = [4, 8]\n", "16x16")
    # the chip's office cases, all-ray case (d) first: the table must find each by its fields
    spec(d / "raykinds_chip.toml", "chip", "".join(
        f"[[point]]\nreflect_depth = {r}\nshadows = {s}\n{extra}"
        for r, s, extra in ((3, "true", ""), (0, "false", ""), (3, "false", ""),
                            (0, "true", ""), (0, "false", 'resolutions = ["32x32"]\n'))), "16x16")
    # Figures 1 and 3: packets of 1 and 64 rays, two kd-tree depths
    spec(d / "packets.toml", "model", "[config]\nreflect_depth = 0\nshadows = false\n"
         "[[point]]\ntile_w = 1\ntile_h = 1\ntrav_subunits = 1\n"
         "[[point]]\ntile_w = 8\ntile_h = 8\n", "32x32")
    spec(d / "kddepth.toml", "model", "[grid]\nkd_max_depth = [3, 16]\n")
    spec(d / "refraction.toml", "chip", "[config]\nshadows = false\n" + "".join(
        f"[[point]]\nreflect_depth = {r}\nrefraction = {f}\n"
        for r, f in ((3, "true"), (0, "false"))), "16x16")
    classes = "".join(f'{s.stem} = "{p}"\n' for s, p in zip(scenes, ("Quake3", "Sodahall")))
    (d / "plan.toml").write_text(
        f'title = "tiny"\nusage_scene = "cornell"\n[class]\n{classes}[sweeps]\n'
        'rays = "rays.toml"\nrtcs = "rtcs.toml"\nintcache = "intcache.toml"\n'
        f'raykinds = "raykinds.toml"\nraykinds_chip = "raykinds_chip.toml"\n'
        'refraction = "refraction.toml"\n'
        'packets = "packets.toml"\nkddepth = "kddepth.toml"\n'
        f'scaling = "{TINY}"\n[threads]\nscene = "{CORNELL}"\nres = "16x16"\n'
        'counts = [1, 8]\n')
    return d


def table(page: str, title: str) -> list[list[str]]:
    """The rows (cells) of the first markdown table after the heading ``title``."""
    part = page[page.index(title):]
    rows = [l for l in part.splitlines() if l.startswith("|")]
    out = []
    for l in rows[2:]:
        out.append([c.strip() for c in l.strip("|").split("|")])
        nxt = part.index(l) + len(l) + 1
        if not part[nxt:].startswith("|"):
            break
    return out


def read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_tiny_plan_fills_every_table(tmp_path, kd_cache, capsys):
    d = make_plan(tmp_path)
    cache, work, page = tmp_path / "cache", tmp_path / "work", tmp_path / "docs" / "results.md"
    chip = {}
    for name in ("rtcs", "intcache", "raykinds_chip"):
        chip.update(precache(d / f"{name}.toml", cache))
    precache(d / "refraction.toml", cache)      # read back by its own keys below
    rc = results.main(["--plan", str(d / "plan.toml"), "--out", str(page.parent), "--work",
                       str(work), "--cache", str(cache), "--workers", "1", "--skip-threads",
                       "--kd-cache", str(kd_cache)])
    out = capsys.readouterr().out
    assert rc == 0, out
    text = page.read_text()
    # the header says how many points this run computed: the model's (the chip's were cached)
    ran = re.search(r"This run: [\d.]+ minutes of wall time \(load average [^)]*\), "
                    r"(\d+) of its (\d+) sweep points computed\. Each point", text)
    computed = int(re.search(r"; (\d+) point\(s\) computed", out).group(1))
    assert ran and int(ran.group(1)) == computed > 0 and int(ran.group(2)) > computed, ran
    cells = [c.strip() for l in text.splitlines() if l.startswith("|") for c in l.split("|")]
    assert "—" not in cells
    # Table 1: the golden model's own rays per frame
    model = read_csv(work / "rays" / "results.csv")
    assert table(text, "## The scenes")[0][2] == f"{int(model[0]['rays_total']):,}"
    # Table 2: the fps of each RTC count, as measured, with all the frame's rays
    allr = {n: chip[(n, 144, 4, 1, 3, True, 16)] for n in (1, 2, 4)}
    row = table(text, "## Table 2")[0]
    sec = allr[4]["rays"]["shadow"] + allr[4]["rays"]["reflection"]
    assert row[1:3] == [f"{allr[4]['rays_total']:,}", f"{sec / allr[4]['rays_total']:.0%}"]
    assert row[3:6] == [f"{allr[n]['fps']:,.2f}" for n in (1, 2, 4)]
    t2 = text[text.index("## Table 2"):text.index("## Table 4")]
    assert "**Chip columns: measured, all the rays each scene has (eye rays, a shadow" in t2
    assert "estimate" not in t2
    rel = table(text, "## Table 4")[0]
    assert rel[3] == (f"{100 * allr[4]['relative_performance']:.1f} % "
                      f"({allr[4]['bound']}; limit-of-4)")
    # Table 3: 2 bandwidths x 2 int-cache sizes
    t3 = table(text, "## Table 3")
    assert len(t3) == 2 and t3[1][2].startswith(f"{chip[(4, 576, 8, 1, 3, True, 16)]['fps']:,.2f} (")
    # Table 5: the model's ops of each ray kind; the chip's eye-ray frames
    kinds = {(r["reflect_depth"], r["shadows"], r["oversampling"]): r
             for r in read_csv(work / "raykinds" / "results.csv")}
    t5 = table(text, "## Table 5")
    assert t5[2][3] == f"{int(kinds[('0', 'True', '1')]['counters.trav_ops']):,}"
    assert int(kinds[("3", "True", "1")]["rays_total"]) > int(kinds[("0", "False", "1")]["rays_total"])
    # ... and the chip's frame of every case, each found by its fields (not by its order)
    case = {"a": (0, False, 16), "b": (3, False, 16), "c": (0, True, 16), "d": (3, True, 16),
            "e": (0, False, 32)}
    ch = {k: chip[(4, 144, 4, 1, *v)] for k, v in case.items()}
    for i, k in enumerate("abcde"):
        assert t5[i][7:10] == [f"{ch[k]['rays_total']:,}", f"{ch[k]['fps']:,.2f}",
                               f"{ch[k]['cycles'] / ch['a']['cycles']:.2f}×"], (k, t5[i])
    # refraction: each case found by its fields, its cost a ray against (a)'s
    rf = {}
    for p in sweep.load_spec(d / "refraction.toml").points:
        st = json.loads((cache / f"{sweep.point_key(p, sweep.code_hash())}.json").read_text())
        rf[(p.cfg().reflect_depth, p.cfg().refraction)] = st["stats"]
    t = table(text, "### Refraction")
    a, c = rf[(0, False)], rf[(3, True)]
    assert [r[0][:3] for r in t] == ["(a)", "(b)"]
    assert t[1][1:5] == [f"{c['rays_total']:,}", f"{c['rays']['reflection']:,}",
                         f"{c['rays']['refraction']:,}", f"{c['cycles']:,}"]
    x = (c["cycles"] / a["cycles"]) / (c["rays_total"] / a["rays_total"])
    assert t[1][8] == f"{x:.2f}" and t[0][3] == "0"
    assert (f"{x:.2f} a ray — **{'holds' if abs(x / (4.5 / 4.9) - 1) <= 0.15 else 'differs'}**"
            in text[text.index("*... also for refracted rays*"):])
    # Table 6: hit rates of eye rays without and with oversampling, and of all rays
    t6 = table(text, "## Table 6")
    assert t6[2][1:4] == [f"{100 * ch[k]['cache']['int']['hit_rate']:.1f} %" for k in "aed"]
    # the trends, from the tables: the made-up int-cache and bandwidth gains hold
    trends = text[text.index("## Which of the paper's trends hold"):]
    x = chip[(4, 576, 4, 1, 3, True, 16)]["fps"] / chip[(4, 144, 4, 1, 3, True, 16)]["fps"]
    p = 86.36 / 65.86                                # the paper's Table 3: 576 KB / 144 KB
    want = "holds" if abs(x / p - 1) <= 0.15 else "differs"
    assert (f"larger int-cache (144 → 576 KB) gives {x:.2f}× the fps (paper {p:.2f}×): "
            f"**{want}**") in trends
    assert "within ±15 % of the paper's" in trends
    # Figure 1: the model's words read, a frame and a packet, for 1 and 64 rays a packet
    pk = {int(r["tile_w"]): r for r in read_csv(work / "packets" / "results.csv")}
    f1 = table(text, "## Figure 1")
    words = {n: sum(int(pk[n][f"memory_reads_64bit.{u}"]) for u in ("trav", "list", "int"))
             for n in (1, 8)}
    assert [r[1] for r in f1] == ["1", "64"]
    assert f1[0][6] == f"**{8 * words[1] / 2 ** 20:,.1f}**"
    assert f1[1][7] == f"{8 * words[8] / 1024 / int(pk[8]['packets']):,.1f}"
    assert words[1] > words[8] and int(pk[1]["packets"]) == 64 * int(pk[8]["packets"])
    # Figure 3: ops a ray of each depth, and the paper's cost of them
    kd = {int(r["kd_max_depth"]): r for r in read_csv(work / "kddepth" / "results.csv")}
    f3 = table(text, "## Figure 3")
    for row, depth in zip(f3, (3, 16)):
        rays = int(kd[depth]["rays_total"])
        t, i = (int(kd[depth][f"counters.{k}_ops"]) / rays for k in ("trav", "int"))
        assert row[4:7] == [f"{t:.1f}", f"{i:.1f}", f"{4 * t + 25 * i:.0f}"]
    assert int(kd[3]["counters.int_ops"]) > int(kd[16]["counters.int_ops"])
    # scaling: both worker counts timed, every plot written
    assert len(table(text, "## Sweeps on more workers")) == 2
    for name in ("rtcs", "intcache", "raykinds", "usage", "packets", "kddepth"):
        assert (page.parent / "img" / f"results_{name}.png").stat().st_size > 1000
    assert "4 RTCs, " in text[text.index("## Table 3"):text.index("## Table 5")]
    # a second run computes no point of the plan; the skipped timing and threads bench are
    # the ones an earlier run kept in the work directory
    (work / "threads.json").write_text(json.dumps({
        "scene": str(CORNELL), "res": [16, 16], "mem_latency": 20,
        "runs": [{"threads": 1, "cycles": 9000, "speedup": 1.0, "wall_s": 3.0},
                 {"threads": 8, "cycles": 1500, "speedup": 6.0, "wall_s": 2.0}]}))
    rc = results.main(["--plan", str(d / "plan.toml"), "--out", str(page.parent), "--work",
                       str(work), "--cache", str(cache), "--skip-threads", "--skip-scaling",
                       "--kd-cache", str(kd_cache)])
    out = capsys.readouterr().out
    assert rc == 0 and "; 0 point(s) computed, 0 failed" in out
    assert "threads.json kept from an earlier run" in out
    assert "scaling.json kept from an earlier run" in out
    text = page.read_text()
    assert "This run computed no point: it read all " in text
    assert len(table(text, "## Sweeps on more workers")) == 2
    assert table(text, "## Threads")[1][:3] == ["8", "1,500", "6.00"]


def test_failed_point_leaves_a_gap_and_fails(tmp_path, kd_cache, capsys):
    """A scene that cannot be read: its cells stay empty and the command exits 1."""
    missing = tmp_path / "nowhere.toml"
    d = make_plan(tmp_path, scenes=(CORNELL, missing))
    cache = tmp_path / "cache"
    for name in ("rtcs", "intcache", "raykinds_chip", "refraction"):
        precache(d / f"{name}.toml", cache)
    page = tmp_path / "results.md"
    rc = results.main(["--plan", str(d / "plan.toml"), "--out", str(page.parent), "--work",
                       str(tmp_path / "work"), "--cache", str(cache), "--workers", "1",
                       "--skip-threads", "--skip-scaling", "--kd-cache", str(kd_cache),
                       # a cluster class named as for a batch system, made and scaled to 1
                       "--cluster", "distributed:LocalCluster", "--cluster-option",
                       "n_workers=0", "--cluster-option", "threads_per_worker=1"])
    out = capsys.readouterr().out
    assert rc == 1 and re.search(r"1 failed point\(s\), [1-9]\d* empty cell", out), out
    assert "on 1 distributed:LocalCluster worker(s)" in out
    rows = table(page.read_text(), "## The scenes")
    assert rows[1][0] == "`nowhere`" and rows[1][1] == "—"


def test_bad_plan(tmp_path):
    p = tmp_path / "plan.toml"
    p.write_text('[sweeps]\ntable9 = "x.toml"\n')
    with pytest.raises(SystemExit, match="unknown table 'table9'"):
        results.main(["--plan", str(p), "--out", str(tmp_path)])


def test_rays_text_and_chip_cases():
    """A table's caption names the rays its chip rows traced; the office cases are found by
    their fields, the oversampled one also as the frame of twice the size."""
    def row(d, sh, w=16, os_=1, **kw):
        return {"status": "ok", "reflect_depth": d, "shadows": sh, "oversampling": os_,
                "width": w, "height": w, **kw}
    assert results.rays_text([row(0, False), row(0, "False")]) == "eye rays only"
    t = results.rays_text([row(3, True), row(3, "True")])
    assert t.startswith("all the rays each scene has (eye rays, a shadow ray per light from "
                        "every hit, reflections up to depth 3")
    assert "where the row says so" in results.rays_text([row(0, False), row(3, True)])
    rows = [row(3, True, fps=1), row(0, False, w=32, fps=2), row(0, False, fps=3),
            row(0, True, fps=4), row(3, False, fps=5), row(0, False, w=64, fps=6)]
    c = results.chip_cases(rows)
    assert [c[n]["fps"] for n, _ in results.CASES] == [3, 5, 4, 1, 2]
    c = results.chip_cases([row(0, False), row(0, False, os_=2, fps=9)])
    assert c["(e) eye, 4x oversampling"]["fps"] == 9 and "(d) eye + reflections + 3 lights" not in c


def test_table3_not_in_the_plan_says_why(tmp_path):
    """A plan without the int-cache sweep prints Table 3's heading with the plan's note (why
    it was not run), and no table."""
    plan = results.Plan(tmp_path / "plan.toml", "t", {}, {}, None, None,
                        notes={"intcache": "Not run: four binaries."})
    w = results.Writer(plan, results.Run(), tmp_path / "img", tmp_path / "r.md")
    w.table3()
    assert w.parts == ["## Table 3: int-cache size and memory bandwidth\n\nNot run: four binaries.\n"]
    plan.sweeps["intcache"] = tmp_path / "intcache.toml"      # planned, but no rows: nothing
    w = results.Writer(plan, results.Run(), tmp_path / "img", tmp_path / "r.md")
    w.table3()
    assert w.parts == []


def _transmits(scene: Path) -> bool:
    """Whether a scene file (or the scene it is a view of) has a material that transmits."""
    import tomllib
    t = tomllib.loads(scene.read_text())
    if "base" in t:
        return _transmits(scene.parent / t["base"])
    return any(m.get("transmit", 0) > 0 for m in t.get("material", []))


def test_shipped_plan_and_its_specs_load():
    """The plan `make results` runs, and every sweep it names, parse; every chip sweep runs
    the paper preset, at 1024x768; Table 3 is the ship's int-cache x
    SDRAM-chip grid on 4 RTCs (eye rays), as its note says; the threads sweep is the paper
    preset's chip with 1 to 32 threads."""
    plan = results.load_plan(results.PLAN)
    assert set(plan.sweeps) >= {"rays", "rtcs", "intcache", "raykinds", "raykinds_chip"}
    specs = {k: sweep.load_spec(p) for k, p in plan.sweeps.items()}
    grid = {(p.cfg().int_cache_kb, p.cfg().mem_chips) for p in specs["intcache"].points}
    assert grid == {(k, c) for k in (144, 288, 576) for c in (4, 8)}
    for p in specs["intcache"].points:
        assert Path(p.scene_path).stem == "ship" and p.cfg().rtcs == 4 and p.cfg().reflect_depth == 0
    assert "Four RTCs, as in the paper" in plan.notes["intcache"]
    # refraction: the glass scene, the same 4-RTC chip with and without refracted rays
    rf = {(p.cfg().reflect_depth, p.cfg().refraction) for p in specs["refraction"].points}
    assert rf == {(0, False), (3, True)}
    assert {Path(p.scene_path).stem for p in specs["refraction"].points} == {"glass"}
    # the chip refuses reflections on a scene whose materials transmit unless it is built with
    # refraction (tb/harness/chip.py): no shipped chip point may ask for that
    for k, spec in specs.items():
        for p in spec.points:
            if spec.backend == "chip" and _transmits(Path(p.scene_path)):
                c = p.cfg()
                assert c.reflect_depth == 0 or c.refraction, (k, p.scene_path, c.reflect_depth)
    paper = lambda c: (c.int_test == "projection" and c.rgs_fp_pool and
                       c.trav_stack == "one_value")
    for k, s in specs.items():
        if s.backend == "chip":
            got = [paper(p.cfg()) for p in s.points]
            assert all(got) or (k == "presets" and sorted(set(got)) == [False, True]), k
            want = {(1024, 768)}
            small = [(Path(p.scene_path).stem, p.cfg().rtcs) for p in s.points
                     if (p.width, p.height) != (1024, 768) and p.width <= 1024]
            if k == "rtcs":     # the one frame too long for a session, stated in the note
                assert sorted(small) == [("outdoor_above", n) for n in (1, 2, 4)], small
                assert "outdoor_above" in plan.notes["rtcs"]
                assert not [p for p in s.points if Path(p.scene_path).stem == "outdoor_above"
                            and p.cfg().rtcs == 4 and p.width == 1024]
            else:
                assert not small, (k, small)
            assert {(p.width, p.height) for p in s.points} >= want, k
    # the threads section: the paper preset on its 4 RTCs with its caches and SDRAM, all rays
    from model.config import preset
    cfgs = [p.cfg() for p in specs["threads"].points]
    assert [c.threads for c in cfgs] == [1, 2, 4, 8, 16, 32]
    assert cfgs[-1] == preset("paper", threads=32, shadows=True, reflect_depth=3)


def test_threads_on_the_chip(tmp_path):
    """A chip sweep over threads (``[sweeps] threads``) makes the threads table: each count's
    cycles, the speed-up over the 1-thread frame, the relative performance, the paper's 7.5×,
    12.2× and 80–90 % beside them; the trends judge them by the ±15 % rule."""
    cycles = {1: 12_000_000, 8: 1_700_000, 16: 1_000_000, 32: 950_000}
    rel = {1: 0.08, 8: 0.55, 16: 0.62, 32: 0.60}
    rows = [{"status": "ok", "scene": "scenes/office_large.toml", "threads": str(n),
             "cycles": str(c), "relative_performance": str(rel[n]), "bound": "int",
             "rtcs": "4", "int_test": "projection", "rgs_fp_pool": "True", "width": "256",
             "height": "192", "reflect_depth": "3", "shadows": "True", "backend": "chip",
             "job_seconds": "60"} for n, c in reversed(cycles.items())]
    plan = results.Plan(tmp_path / "plan.toml", "t", {}, {}, None, None)
    run = results.Run(rows={"threads": rows})
    w = results.Writer(plan, run, tmp_path / "img", tmp_path / "r.md")
    w.threads()
    w.trends()
    text = "\n".join(w.parts)
    assert "The paper preset with 4 RTCs, its shared caches and SDRAM, with 1 to 32" in text
    t = table(text, "## Threads")
    assert [r[0] for r in t] == ["1", "8", "16", "32"]
    for r, n in zip(t, cycles):
        assert r[1] == f"{cycles[n]:,}" and r[2] == f"{cycles[1] / cycles[n]:.2f}"
        assert r[4].startswith(f"{100 * rel[n]:.1f} %")
    assert [t[1][3], t[2][3], t[3][5]] == ["7.5", "12.2", "80–90 %"]
    trends = text[text.index("## Which of the paper's trends hold"):]
    s8, s16 = cycles[1] / cycles[8], cycles[1] / cycles[16]
    verdict = lambda x, p: "holds" if abs(x / p - 1) <= 0.15 else "differs"
    assert (f"Ours (the chip with its caches and SDRAM): 8 threads {s8:.1f}× (paper 7.5×, "
            f"**{verdict(s8, 7.5)}**); 16 threads {s16:.1f}× (paper 12.2×, "
            f"**{verdict(s16, 12.2)}**); 32 threads 60 % relative performance (paper 80–90 %, "
            f"against its middle 85 %: **differs**)") in trends


def test_captions_name_the_chip_the_rows_ran_on():
    """A table's caption says which chip its rows ran on: the paper preset (the projection test
    and the slaves' pool, whatever else its sweep changes) or the standard chip."""
    paper = {"status": "ok", "int_test": "projection", "rgs_fp_pool": "True", "rtcs": "2"}
    std = {"status": "ok", "int_test": "watertight", "rgs_fp_pool": "False"}
    assert results._chip_name([paper]) == "the paper preset"
    assert results._chip_name([std]) == "the standard chip"
    assert results._chip_name([dict(paper, rgs_fp_pool="False")]) == "the standard chip"
    assert "`--preset paper`" in results._preset_text([paper])
    assert results._preset_text([std]) == ""


def test_beyond_the_paper(tmp_path):
    """The four chip sweeps beyond the paper's tables, each a sub-table of what it measured:
    the bus's load and waits against the RTCs (speed-up over 1 RTC), RTCs with as many SDRAM
    chips (the memory's bandwidth), the caches' ways (fps against direct-mapped, hit rates),
    and the paper preset beside the standard chip; sub-tables only for sweeps in the plan."""
    paper = {"int_test": "projection", "rgs_fp_pool": "True"}
    std = {"int_test": "watertight", "rgs_fp_pool": "False"}

    def row(scene, cycles, **kw):
        return {"status": "ok", "scene": f"scenes/{scene}.toml", "cycles": str(cycles),
                "fps": str(533e6 / cycles), "relative_performance": "0.5", "bound": "int-ops",
                "width": "1024", "height": "768", "reflect_depth": "0", "shadows": "False",
                "backend": "chip", "rtcs": "4", "mem_chips": "4", "result_ports": "1",
                "cache_ways": "1", **paper, **{k: str(v) for k, v in kw.items()}}
    bus = [row("game", 8_000_000 // n, rtcs=n, mem_chips=16, result_ports=min(n, 4),
               **{"cache.trav.bus.busy": 0.04 * n, "cache.trav.bus.wait": 0.003 * n * n,
                  "cache.int.bus.wait": 0.002 * n}) for n in (16, 1, 4)]
    sdram = [row("office_large", 9_000_000 // n, rtcs=n, mem_chips=n,
                 **{"memory.bandwidth_mb_s": 90.0 * n}) for n in (1, 2)]
    ways = [row(s, c, cache_ways=w, **{f"cache.{k}.hit_rate": 0.9 + 0.01 * w
                                       for k in ("trav", "list", "int")})
            for s, c0 in (("office_large", 2_000_000), ("conference_large", 3_000_000))
            for w, c in ((1, c0), (4, c0 - 100_000))]
    presets = [row("office_large", 1_000_000, **std),
               row("office_large", 2_300_000, **{"limiter.limit": "slave-pool-bound"})]
    plan = results.Plan(tmp_path / "plan.toml", "t", {}, {}, None, None)
    run = results.Run(rows={"bus": bus, "sdram": sdram, "ways": ways, "presets": presets})
    w = results.Writer(plan, run, tmp_path / "img", tmp_path / "r.md")
    w.beyond()
    text = "\n".join(w.parts)
    t = table(text, "### Where the round-robin bus saturates")
    assert [r[0] for r in t] == ["1", "4", "16"]
    assert t[2][1:4] == ["500,000", f"{533e6 / 500_000:,.1f}", "16.00×"]
    assert t[2][5:8] == ["0.640", "76.8 %", "3.2 %"]
    assert "16 SDRAM chips" in text and "(`(not in this plan)`)" in text
    assert "1 to 4 result streams (as many as the RTCs, up to 4)" in text
    t = table(text, "### RTCs and SDRAM chips together")
    assert t[1][:3] == ["2", "2", "4,500,000"] and t[1][4] == "2.00×" and t[1][6] == "180"
    assert t[1][5] == "50.0 % (int-ops)"
    t = table(text, "### The caches' associativity")
    assert [r[:2] for r in t] == [["`conference_large`", "1"], ["`conference_large`", "4"],
                                  ["`office_large`", "1"], ["`office_large`", "4"]]
    assert t[3][4] == f"{2_000_000 / 1_900_000:.3f}×" and t[3][5] == "94.0 %"
    t = table(text, "### The paper's chip beside ours")
    assert [r[1:3] for r in t] == [["paper preset", "2,300,000"], ["standard chip", "1,000,000"]]
    assert [r[4] for r in t] == ["1.00×", "2.30×"]
    assert [r[5] for r in t] == ["50.0 % (int-ops; slave-pool-bound)", "50.0 % (int-ops)"]
    w = results.Writer(plan, results.Run(rows={"ways": ways}), tmp_path / "img", tmp_path / "r.md")
    w.beyond()
    assert "### The caches' associativity" in w.parts[0] and "bus saturates" not in w.parts[0]


def test_cached_page_names_what_is_not_run(tmp_path, kd_cache, capsys):
    """``--cached`` computes nothing: the points in the cache fill their cells, the others show
    as not run, are counted in the header and listed by sweep under the cost; the cluster
    bound is the measured job times' arithmetic."""
    d = make_plan(tmp_path)
    cache, page = tmp_path / "cache", tmp_path / "docs" / "results.md"
    chip = precache(d / "rtcs.toml", cache)
    rc = results.main(["--plan", str(d / "plan.toml"), "--out", str(page.parent), "--work",
                       str(tmp_path / "work"), "--cache", str(cache), "--cached",
                       "--kd-cache", str(kd_cache)])
    out = capsys.readouterr().out
    assert rc == 1 and "; 0 point(s) computed, 0 failed" in out, out
    text = page.read_text()
    # the rtcs points are found wherever another sweep has the same point (the int-cache's
    # 144 KB, 4 chips and the office case (d) are its 4-RTC point)
    code = sweep.code_hash()
    keys = [sweep.point_key(p, code) for k in ("rays", "raykinds", "rtcs", "intcache",
                                               "raykinds_chip", "packets", "kddepth",
                                               "refraction")
            for p in sweep.load_spec(d / f"{k}.toml").points]
    done = sum((cache / f"{k}.json").exists() for k in keys)
    assert done == 5 and f"**Not complete: {done} of {len(keys)} points measured.**" in text
    # a section with no point yet shows its heading and what it waits for
    assert "### Refraction\n\n*Not measured yet*: the 2 point(s) of `" in text
    # the cost counts a point once however many sweeps share it
    assert "the sum over its 3 distinct points" in " ".join(text.split())
    pend = text[text.index("**Points not run yet**"):]
    assert f"- `{os.path.relpath(d / 'intcache.toml', ROOT)}`: " in pend
    assert "`: cornell 16x16 mem_chips=8 int_cache_kb=144; cornell 16x16 mem_chips=4 int_cache_kb=576; " in pend
    # Table 2 has the measured fps of every RTC count; Table 3 has none
    t2 = table(text, "## Table 2")
    assert t2[0][3:6] == [f"{chip[(n, 144, 4, 1, 3, True, 16)]['fps']:,.2f}" for n in (1, 2, 4)], t2
    # Table 3 has the one measured point (the 4-RTC frame) and no column of the others
    t3 = text[text.index("## Table 3"):text.index("## Table 6")]
    assert "| bandwidth | 144 KB | paper 144 KB |" in t3 and "576" not in t3


def test_kept_cache_names_no_machine_path(tmp_path):
    """A point's cached JSON names a scene of the checkout by its path in it; the page's kept
    points (``scenes/sweeps/results/cache``) hold no absolute path."""
    s = sweep.load_spec(spec(tmp_path / "s.toml", "model", ""))
    p = s.points[0]
    sweep._cache_write(tmp_path / "k.json", "k", p, {"status": "ok", "stats": {}})
    assert json.loads((tmp_path / "k.json").read_text())["point"]["scene_path"] == "scenes/cornell.toml"
    for f in results.CACHE.glob("*.json"):
        d = json.loads(f.read_text())
        assert d["key"] == f.stem and not Path(d["point"]["scene_path"]).is_absolute(), f
        assert str(ROOT) not in f.read_text(), f


def test_chip_text_from_the_rows():
    """A caption names the chip its rows ran: the figures they share, the caches' topology and
    ways, the SDRAM bandwidth from its chips, width and clock."""
    row = dict(status="ok", threads=16, trav_subunits=4, trav_cache_kb=64, list_cache_kb=64, int_cache_kb=144,
               cache_ways=1, cache_topology="shared", mem_chips=4, mem_chip_bits=16,
               clock_mhz=533.0, mem_clock_ratio=4)
    assert results._chip_text([row]) == ("16 threads, 4 traversal sub-units, direct-mapped caches "
                                         "of 64/64/144 KB shared by all RTCs, 4 SDRAM chips = "
                                         "1.07 GB/s, 533 MHz")
    two = dict(row, cache_ways=2, cache_topology="private", threads=8)
    t = results._chip_text([two, dict(two, threads=32)])
    assert t.startswith("4 traversal sub-units, 2-way caches of 64/64/144 KB in every RTC")


def test_limits_from_the_cached_stats(tmp_path):
    """A chip row without a limiter gets the one `saarcor sim` computes from the point's
    cached counters; a model row gets none."""
    from saarcor.sim import limiter
    stats = {"stalls": {"trav": {"work": 0.95, "memory": 0.01, "blocked": 0.02, "starved": 0.02},
                        "list": {"work": 0.2, "memory": 0.5, "blocked": 0.1, "starved": 0.2},
                        "int": {"work": 0.3, "memory": 0.1, "blocked": 0.5, "starved": 0.1}},
             "config": {"rtcs": 4}}
    s = sweep.load_spec(spec(tmp_path / "s.toml", "chip", ""))
    sweep._cache_write(tmp_path / "k.json", "k", s.points[0], {"status": "ok", "stats": stats})
    rows = [{"backend": "chip", "status": "ok", "key": "k"},
            {"backend": "model", "status": "ok", "key": "k"}]
    results.add_limits(rows, tmp_path)
    want = limiter(stats)
    assert want["limit"] == "trav-bound"
    assert (rows[0]["limiter.limit"], rows[0]["limiter.why"]) == (want["limit"], want["why"])
    assert "limiter.limit" not in rows[1]


def test_table3_trend_needs_two_points(tmp_path):
    """Table 3's trend compares two int-cache sizes (or two bandwidths): with only the 144 KB,
    4-chip frame measured it says nothing, rather than "a 1× larger int-cache"; with 576 KB
    measured too it compares them by the ±15 % rule."""
    def row(kb, chips, fps):
        return {"status": "ok", "scene": "scenes/ship.toml", "int_cache_kb": kb,
                "mem_chips": str(chips), "fps": str(fps), "rtcs": "4", "backend": "chip",
                "width": "1024", "height": "768", "job_seconds": "60"}
    plan = results.Plan(tmp_path / "plan.toml", "t", {}, {}, None, None)

    def trends(rows):
        w = results.Writer(plan, results.Run(rows={"intcache": rows}), tmp_path / "img",
                           tmp_path / "r.md")
        w.trends()
        return "\n".join(w.parts)
    assert "Table 3" not in trends([row(144, 4, 15.4)])
    text = trends([row(144, 4, 15.4), row(576, 4, 20.0), row(144, 8, 16.0)])
    x, y = 20.0 / 15.4, 16.0 / 15.4
    want = lambda v, p: "holds" if abs(v / p - 1) <= 0.15 else "differs"
    p576, p8 = 86.36 / 65.86, 87.24 / 65.86          # the paper's Table 3, CruiserGL
    assert (f"a 4× larger int-cache (144 → 576 KB) gives {x:.2f}× the fps (paper {p576:.2f}×): "
            f"**{want(x, p576)}**; twice the bandwidth gives {y:.2f}× (paper {p8:.2f}×): "
            f"**{want(y, p8)}**") in text
    # with 288 KB the largest measured, the paper's ratio is its 288 KB column's, not 576's
    text = trends([row(144, 4, 15.4), row(288, 4, 16.0)])
    p288 = 77.54 / 65.86
    assert (f"a 2× larger int-cache (144 → 288 KB) gives {16.0 / 15.4:.2f}× the fps (paper "
            f"{p288:.2f}×): **{want(16.0 / 15.4, p288)}**.") in text


def trend_line(plan, rows, start, tmp_path) -> str:
    """The line of the page's trends that starts with ``start``, from a Writer on ``rows``."""
    w = results.Writer(plan, results.Run(rows=rows), tmp_path / "img", tmp_path / "r.md")
    w.trends()
    text = "\n".join(w.parts)
    return text[text.index(start):].split("\n")[0]


def test_ray_cost_verdict_names_the_measured_limits(tmp_path):
    """The chip's "cost is about linear in the rays" verdict: where it differs it names both
    frames' measured limits (``limiter.limit``); where it holds, no reason."""
    def row(depth, shadows, rays, cycles, limit):
        return {"status": "ok", "scene": "scenes/office_large.toml", "backend": "chip",
                "width": "1024", "height": "768", "oversampling": "1", "rtcs": "4",
                "reflect_depth": str(depth), "shadows": str(shadows), "rays_total": str(rays),
                "cycles": str(cycles), "limiter.limit": limit, "job_seconds": "60"}
    plan = results.Plan(tmp_path / "plan.toml", "t", {}, {}, None, None)

    def trend(cycles_all):
        model = [{"status": "ok", "backend": "model", "reflect_depth": "0", "shadows": "False",
                  "oversampling": "1"}]
        chip = [row(0, False, 1000, 10_000, "slave-pool-bound"),
                row(3, True, 4000, cycles_all, "int-bound")]
        return trend_line(plan, {"raykinds": model, "raykinds_chip": chip},
                          "*Cost is about linear", tmp_path)
    assert trend(12_000).endswith("0.30 a ray — **differs** (limits measured: eye rays "
                                  "slave-pool-bound, all rays int-bound).")
    assert trend(37_000).endswith("0.93 a ray — **holds**.")


def test_relative_performance_and_hit_rate_verdicts(tmp_path):
    """Table 4's trend compares each scene's 4-RTC relative performance with the paper's and,
    where it differs, names the frame's measured limit; Table 6's compares the office's hit
    rates (all rays, no oversampling) with the paper's."""
    plan = results.Plan(tmp_path / "plan.toml", "t", {"office_large": "Office"}, {}, None, None)

    def trend(rel, hits, start):
        rtc = [{"status": "ok", "scene": "scenes/office_large.toml", "backend": "chip",
                "width": "1024", "height": "768", "rtcs": 4, "reflect_depth": "3",
                "shadows": "True", "relative_performance": str(rel),
                "limiter.limit": "slave-pool-bound", "fps": "20", "job_seconds": "60"}]
        chip = [{"status": "ok", "scene": "scenes/office_large.toml", "backend": "chip",
                 "width": "1024", "height": "768", "oversampling": "1", "rtcs": "4",
                 "reflect_depth": "3", "shadows": "True", "cycles": "100",
                 **{f"cache.{k}.hit_rate": str(h) for k, h in zip(("trav", "list", "int"), hits)}}]
        return trend_line(plan, {"rtcs": rtc, "raykinds_chip": chip}, start, tmp_path)
    rel = "*The chip reaches most"
    assert trend(0.32, (0.9, 0.9, 0.9), rel).endswith(
        "`office_large` 32 % (paper, Office: 68 %, **differs**; slave-pool-bound).")
    assert trend(0.66, (0.9, 0.9, 0.9), rel).endswith(
        "`office_large` 66 % (paper, Office: 68 %, **holds**).")
    hit = "*Small caches hit"
    assert trend(0.5, (0.908, 0.70, 0.971), hit).endswith(
        "trav-cache 90.8 % (paper 89.9 %, **holds**); list-cache 70.0 % (paper 89.7 %, "
        "**differs**); int-cache 97.1 % (paper 97.1 %, **holds**).")


def test_plan_note_under_an_unknown_table(tmp_path):
    """A note keyed to a table the page does not have is an error naming the key, not a
    paragraph silently dropped."""
    p = tmp_path / "plan.toml"
    p.write_text('[note]\nrelativ = "text"\n')
    with pytest.raises(results.ResultsError, match=r"\[note\]: unknown table\(s\) relativ"):
        results.load_plan(p)
    p.write_text('[note]\nrelative = "text"\n')
    assert results.load_plan(p).notes == {"relative": "text"}


def test_table3_cell_not_run(tmp_path):
    """A Table 3 cell whose point is not run yet shows as — beside the measured ones, and the
    measured cells are relative to 144 KB with 4 chips."""
    def row(kb, chips, fps):
        return {"status": "ok", "scene": "scenes/ship.toml", "int_cache_kb": kb,
                "mem_chips": chips, "fps": str(fps), "cache.int.hit_rate": "0.25",
                "cycles": str(int(533e6 / fps)), "width": "1024", "height": "768",
                "reflect_depth": "0", "shadows": "True", "backend": "chip", "rtcs": "4",
                "int_test": "projection", "rgs_fp_pool": "True"}
    rows = [row(144, 4, 10.0), row(288, 4, 12.0), row(144, 8, 15.0)]
    plan = results.Plan(tmp_path / "plan.toml", "t", {}, {}, None, None)
    w = results.Writer(plan, results.Run(rows={"intcache": rows}), tmp_path / "img",
                       tmp_path / "r.md")
    w.table3()
    t = table("\n".join(w.parts), "## Table 3")
    assert [r[1:3] for r in t] == [["10.00 (1.00×, int hit 25.0 %)", "12.00 (1.20×, int hit 25.0 %)"],
                                   ["15.00 (1.50×, int hit 25.0 %)", "—"]]


def test_table2_smaller_frame_row(tmp_path):
    """A scene whose 4-RTC frame at 1024x768 is not in the sweep but whose RTC counts all ran
    at a smaller frame gets a second Table 2 row at that frame; its 1024x768 row points there,
    and the RTC trend takes the smaller frame's ratio and says so."""
    def row(rtcs, w, h, fps):
        return {"status": "ok", "scene": "scenes/outdoor_above.toml", "rtcs": rtcs,
                "width": str(w), "height": str(h), "fps": str(fps), "rays_total": str(w * h),
                "relative_performance": "0.5", "limiter.limit": "memory-bandwidth-bound",
                "reflect_depth": "3", "shadows": "True", "backend": "chip",
                "int_test": "projection", "rgs_fp_pool": "True", "cycles": str(int(533e6 / fps))}
    rows = [row(1, 1024, 768, 4.0), row(2, 1024, 768, 5.0),
            row(1, 512, 384, 16.0), row(2, 512, 384, 20.0), row(4, 512, 384, 22.0)]
    plan = results.Plan(tmp_path / "plan.toml", "t", {"outdoor_above": "BQD-2"}, {}, None, None)
    w = results.Writer(plan, results.Run(rows={"rtcs": rows}), tmp_path / "img",
                       tmp_path / "r.md")
    w.table2()
    w.trends()
    text = "\n".join(w.parts)
    t = table(text, "## Table 2")
    assert [r[0] for r in t] == ["`outdoor_above` (BQD-2)", "`outdoor_above` (BQD-2), 512×384"]
    assert t[0][3:6] == ["4.00", "5.00", "smaller frame ↓"]
    assert t[1][3:6] == ["16.00", "20.00", "22.00"]
    assert "also at 512×384 (1/4 of the paper's pixels)" in text
    assert "`outdoor_above` at 512×384 1.38× (paper, BQD-2:" in text
    t4 = table(text, "## Table 4")
    assert t4[0][3] == "smaller frame ↓" and t4[1][3] == "50.0 % (memory-bandwidth-bound)"
    # the smaller frame's points not run yet are "not run" there, never an arrow
    w = results.Writer(plan, results.Run(rows={"rtcs": rows[:3]}), tmp_path / "img",
                       tmp_path / "r.md")
    w.table2()
    t = table("\n".join(w.parts), "## Table 2")
    assert t[0][3:6] == ["4.00", "5.00", "not run"]
    assert t[1][3:6] == ["16.00", "not run", "not run"]


def test_bus_trend_verdict(tmp_path):
    """The bus trend (Section 4.2.2: the bus breaks with 8 to 16 RTCs) holds where 16 RTCs gain
    less than 1.7x over 8 (linear less 15 %), and where it differs names the 16-RTC frame's
    measured limit."""
    def row(n, cycles):
        return {"status": "ok", "scene": "scenes/game.toml", "rtcs": n, "cycles": str(cycles),
                "width": "1024", "height": "768", "reflect_depth": "0", "shadows": "False",
                "backend": "chip", "int_test": "projection", "rgs_fp_pool": "True",
                "cache.trav.bus.busy": "0.5", "cache.trav.bus.wait": "0.9",
                "limiter.limit": "slave-pool-bound"}
    plan = results.Plan(tmp_path / "plan.toml", "t", {}, {}, None, None)

    def trend(c16):
        return trend_line(plan, {"bus": [row(8, 1000), row(16, c16)]},
                          "*The round-robin bus breaks", tmp_path)
    assert trend(800).endswith("16 RTCs 1.25× the 8 RTCs' speed, the trav cache's bus 0.50 "
                               "requests a cycle, waited 90.0 % — **holds**.")
    assert trend(500).endswith("2.00× the 8 RTCs' speed, the trav cache's bus 0.50 requests a "
                               "cycle, waited 90.0 % — **differs**; 16 RTCs slave-pool-bound.")
    assert "the paper preset, `game`, eye rays only" in trend(500)
    w = results.Writer(plan, results.Run(rows={"bus": [row(8, 1000)]}), tmp_path / "img",
                       tmp_path / "r.md")
    w.trends()
    assert "round-robin bus breaks" not in "\n".join(w.parts)
