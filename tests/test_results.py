"""``saarcor results`` (tb/results.py): a tiny plan fills every table of the page.

The golden-model sweeps run for real (Cornell 8x8); the chip points are put in the result
cache beforehand (a chip frame needs a Verilator build of minutes), with figures made up here,
so the test checks that each table shows what its sweep measured."""
import csv
import re

import pytest

from model.config import Config
from tb import results, sweep
from tb.sim import relative_performance

from .conftest import ROOT

CORNELL = ROOT / "scenes" / "cornell.toml"
TINY = ROOT / "scenes" / "sweeps" / "tiny.toml"


def spec(path, backend, body, res="8x8", scenes=(CORNELL,)):
    names = ", ".join(f'"{s}"' for s in scenes)
    path.write_text(f'backend = "{backend}"\nscenes = [{names}]\nresolutions = ["{res}"]\n' + body)
    return path


def fake_chip_stats(cfg: Config, rays: int) -> dict:
    """Plausible figures of a chip frame, different for every configuration."""
    cycles = 40_000 // cfg.rtcs + 9_000 * 144 // cfg.int_cache_kb + 3_000 * 4 // cfg.mem_chips
    cycles *= cfg.oversampling ** 2
    trav, inter = 30 * rays, 6 * rays
    per_rtc = [{"trav": 0.5 + 0.01 * r, "trav_subunits": 0.4, "list": 0.3, "int": 0.6}
               for r in range(cfg.rtcs)]
    return {"cycles": cycles, "rays_total": rays, "trav_ops": trav, "int_ops": inter,
            **relative_performance(cfg, cycles, trav, inter),
            "cache": {k: {"hit_rate": h + 0.01 * cfg.oversampling, "memory_words": w}
                      for k, h, w in (("trav", 0.8, 300), ("list", 0.7, 100), ("int", 0.9, 600))},
            "units": {"per_rtc": per_rtc},
            "memory": {"per_chip": [{"share": 1 / cfg.mem_chips}] * cfg.mem_chips},
            "bus": {"words_per_cycle": 0.1}}


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
        stats[(cfg.rtcs, cfg.int_cache_kb, cfg.mem_chips, cfg.oversampling)] = st
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
    spec(d / "oversampling.toml", "chip", "[grid]\noversampling = [1, 2]\n", "16x16")
    classes = "".join(f'{s.stem} = "{p}"\n' for s, p in zip(scenes, ("Quake3", "Sodahall")))
    (d / "plan.toml").write_text(
        f'title = "tiny"\nusage_scene = "cornell"\n[class]\n{classes}[sweeps]\n'
        'rays = "rays.toml"\nrtcs = "rtcs.toml"\nintcache = "intcache.toml"\n'
        f'raykinds = "raykinds.toml"\noversampling = "oversampling.toml"\nscaling = "{TINY}"\n')
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
    for name in ("rtcs", "intcache", "oversampling"):
        chip.update(precache(d / f"{name}.toml", cache))
    rc = results.main(["--plan", str(d / "plan.toml"), "--out", str(page), "--work", str(work),
                       "--cache", str(cache), "--workers", "1", "--skip-threads",
                       "--kd-cache", str(kd_cache)])
    out = capsys.readouterr().out
    assert rc == 0, out
    text = page.read_text()
    cells = [c.strip() for l in text.splitlines() if l.startswith("|") for c in l.split("|")]
    assert "—" not in cells
    # Table 1: the golden model's own rays per frame
    model = read_csv(work / "rays" / "results.csv")
    assert table(text, "## The scenes")[0][2] == f"{int(model[0]['rays_total']):,}"
    # Table 2: the fps of each RTC count, as measured
    row = table(text, "## Table 2")[0]
    assert row[1:4] == [f"{chip[(n, 144, 4, 1)]['fps']:,.0f}" for n in (1, 2, 4)]
    rel = table(text, "## Table 4")[0]
    assert rel[3].startswith(f"{100 * chip[(4, 144, 4, 1)]['relative_performance']:.1f} %")
    # Table 3: 2 bandwidths x 2 int-cache sizes
    t3 = table(text, "## Table 3")
    assert len(t3) == 2 and t3[1][2].startswith(f"{chip[(4, 576, 8, 1)]['fps']:,.0f} (")
    # Table 5: the model's ops of each ray kind; the chip's eye-ray frames
    kinds = {(r["reflect_depth"], r["shadows"], r["oversampling"]): r
             for r in read_csv(work / "raykinds" / "results.csv")}
    t5 = table(text, "## Table 5")
    assert t5[2][3] == f"{int(kinds[('0', 'True', '1')]['counters.trav_ops']):,}"
    assert int(kinds[("3", "True", "1")]["rays_total"]) > int(kinds[("0", "False", "1")]["rays_total"])
    assert t5[0][7] == f"{chip[(4, 144, 4, 1)]['fps']:,.0f}"
    # Table 6: hit rates without and with oversampling
    t6 = table(text, "## Table 6")
    assert t6[2][1:3] == [f"{100 * chip[(4, 144, 4, o)]['cache']['int']['hit_rate']:.1f} %"
                          for o in (1, 2)]
    # the trends, from the tables: the made-up int-cache and bandwidth gains hold
    trends = text[text.index("## Which of the paper's trends hold"):]
    assert re.search(r"larger int-cache gives 1\.\d\d× the fps \(paper 1\.31×\): \*\*holds", trends)
    # scaling: both worker counts timed, every plot written
    assert len(table(text, "## Sweeps on more workers")) == 2
    for name in ("rtcs", "intcache", "raykinds", "usage"):
        assert (page.parent / "img" / f"results_{name}.png").stat().st_size > 1000
    # a second run computes no point of the plan
    rc = results.main(["--plan", str(d / "plan.toml"), "--out", str(page), "--work", str(work),
                       "--cache", str(cache), "--skip-threads", "--skip-scaling",
                       "--kd-cache", str(kd_cache)])
    assert rc == 0 and "; 0 point(s) computed, 0 failed" in capsys.readouterr().out


def test_failed_point_leaves_a_gap_and_fails(tmp_path, kd_cache, capsys):
    """A scene that cannot be read: its cells stay empty and the command exits 1."""
    missing = tmp_path / "nowhere.toml"
    d = make_plan(tmp_path, scenes=(CORNELL, missing))
    cache = tmp_path / "cache"
    for name in ("rtcs", "intcache", "oversampling"):
        precache(d / f"{name}.toml", cache)
    page = tmp_path / "results.md"
    rc = results.main(["--plan", str(d / "plan.toml"), "--out", str(page), "--work",
                       str(tmp_path / "work"), "--cache", str(cache), "--workers", "1",
                       "--skip-threads", "--skip-scaling", "--kd-cache", str(kd_cache)])
    out = capsys.readouterr().out
    assert rc == 1 and re.search(r"1 failed point\(s\), [1-9]\d* empty cell", out), out
    rows = table(page.read_text(), "## The scenes")
    assert rows[1][0] == "`nowhere`" and rows[1][1] == "—"


def test_bad_plan(tmp_path):
    p = tmp_path / "plan.toml"
    p.write_text('[sweeps]\ntable9 = "x.toml"\n')
    with pytest.raises(SystemExit, match="unknown table 'table9'"):
        results.main(["--plan", str(p), "--out", str(tmp_path / "r.md")])
