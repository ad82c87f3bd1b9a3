"""``docs/results.md``: the paper's Section 5 tables on our chip and golden model, from sweeps.

One command runs every sweep of a plan (``scenes/sweeps/results/plan.toml``: which sweep
spec feeds which table), on one Dask cluster, through :func:`saarcor.sweep.run_sweep` (so every
point is cached and a second run computes nothing; the threads section from the chip sweep
``[sweeps] threads``, or the one-RTC threads bench of a ``[threads]`` table), and the
sweep's own scaling measurement (a small spec with 1 and 2 workers, uncached); then writes
the tables, each beside the paper's figures, and matplotlib plots into ``docs/img/``.

The chip columns are frames through the whole chip in Verilator with the rays their spec asks
for (``shadows``, ``reflect_depth``: the RGS slaves make the shadow and reflection rays from
their hits), every ray checked against the golden model; each table says which rays its chip
columns hold (:func:`rays_text`, from the rows). The golden model's columns are its operation
counts; estimates are marked as such.

Run: ``saarcor results [--plan PLAN] [--out docs] [--img docs/img] [--workers 2]
[--skip-threads] [--skip-scaling]`` (``make results``): writes ``OUT/results.md``.
"""
from __future__ import annotations

import argparse
import io
import json
import math
import os
import sys
import tempfile
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from model.config import Config
from model.raykind import RayKind

from saarcor import sweep as sw
from saarcor.args import add_kd_cache_arg, parse_res

ROOT = Path(__file__).resolve().parents[1]
PLAN = ROOT / "scenes" / "sweeps" / "results" / "plan.toml"
# the page's points, kept in the repository (a point's JSON as saarcor.sweep caches it): the
# frames at 1024x768 take hours each, so the page is rebuilt from them as long as the code they
# ran (saarcor.sweep.code_hash) is the checkout's
CACHE = ROOT / "scenes" / "sweeps" / "results" / "cache"
PLAN_KEYS = ("title", "resolution_note", "class", "sweeps", "threads", "usage_scene", "note")
NOTES = ("relative",)    # notes under a table no sweep is named after (Table 4)
SWEEPS = ("rtcs", "rays", "intcache", "raykinds", "raykinds_chip", "oversampling", "scaling",
          "packets", "kddepth", "threads", "bus", "sdram", "ways", "presets", "refraction")
HOLDS = 0.15            # a trend holds where our ratio is within 15 % of the paper's
# the paper's cost of an operation in FP units' operations (Section 4.2.1: a trav-op 3 adds and
# a multiply; an int-op 12 adds and 13 multiplies, a division counted as three)
FP_OPS = {"trav": 4, "int": 25}
# the chip's office cases of Table 5, as (reflect_depth, shadows, oversampled 4x)
CASES = [("(a) eye rays", (0, False, False)), ("(b) eye + reflections (depth 3)", (3, False, False)),
         ("(c) eye + 3 lights", (0, True, False)), ("(d) eye + reflections + 3 lights", (3, True, False)),
         ("(e) eye, 4x oversampling", (0, False, True))]

# ---- the paper's figures (Schmittler, Wald, Slusallek 2002, Section 5; 1024x768) ----------
PAPER_SCENES = {  # scene: (triangles, lights, reflection depth, rays shot)
    "Quake3": (34_772, 0, 0, 786_432), "Sodahall": (1_510_322, 0, 0, 786_432),
    "CruiserGL": (3_637_101, 0, 0, 786_432), "Conf": (282_000, 2, 0, 2_359_296),
    "Cruiser": (3_637_101, 2, 0, 2_359_296), "Office": (33_952, 3, 3, 3_863_846),
    "BQD-1": (2_133_537, 1, 3, 1_583_402), "BQD-2": (2_133_537, 1, 3, 1_548_632)}
PAPER_FPS = {  # Table 2: 1, 2, 4 RTCs
    "Quake3": (27.20, 54.45, 111.12), "Sodahall": (28.88, 56.71, 113.22),
    "CruiserGL": (28.58, 52.04, 65.86), "Conf": (8.91, 16.77, 31.56),
    "Cruiser": (9.82, 17.38, 20.05), "Office": (7.52, 14.34, 28.56),
    "BQD-1": (11.74, 23.12, 45.90), "BQD-2": (7.55, 12.98, 17.43)}
PAPER_REL = {  # Table 4: relative performance, 1, 2, 4 RTCs
    "Quake3": (0.76, 0.76, 0.78), "Sodahall": (0.80, 0.79, 0.79),
    "CruiserGL": (0.71, 0.65, 0.41), "Conf": (0.67, 0.63, 0.59),
    "Cruiser": (0.72, 0.63, 0.37), "Office": (0.71, 0.68, 0.68),
    "BQD-1": (0.73, 0.72, 0.71), "BQD-2": (0.54, 0.46, 0.31)}
PAPER_T3 = {(144, 4): 65.86, (288, 4): 77.54, (576, 4): 86.36,   # CruiserGL, 4 RTCs
            (144, 8): 87.24, (288, 8): 103.62, (576, 8): 113.89}
PAPER_T5 = [  # Office, 4 RTCs: case, rays, fps
    ("(a) eye rays", 786_432, 127.75), ("(b) eye + reflections (depth 3)", 966_275, 99.23),
    ("(c) eye + 3 lights", 3_145_728, 36.67), ("(d) eye + reflections + 3 lights", 3_863_846, 28.56),
    ("(e) eye, 4x oversampling", 3_145_728, 35.06)]
PAPER_T6 = {"trav": (0.899, 0.968), "list": (0.897, 0.957), "int": (0.971, 0.988)}
PAPER_THREADS = {8: 7.5, 16: 12.2}
PAPER_THREADS_32 = (0.80, 0.90)     # the paper's relative performance with 32 threads
RTCS = (1, 2, 4)


class ResultsError(ValueError):
    """A plan that cannot be run; the message names the file and the fix."""


@dataclass
class Plan:
    path: Path
    title: str
    classes: dict            # our scene (file stem) -> the paper's scene
    sweeps: dict             # table key -> spec path
    threads: dict | None     # {scene, res, counts}
    usage_scene: str | None
    resolution_note: str = ""
    notes: dict = field(default_factory=dict)   # table key -> a paragraph under its table


def load_plan(path: str | Path) -> Plan:
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text())
    except OSError as e:
        raise ResultsError(f"{path}: cannot read the plan: {e}") from None
    except tomllib.TOMLDecodeError as e:
        raise ResultsError(f"{path}: TOML syntax error: {e}") from None
    unknown = sorted(set(doc) - set(PLAN_KEYS))
    if unknown:
        raise ResultsError(f"{path}: unknown key(s) {', '.join(unknown)}; a plan has "
                           f"{', '.join(PLAN_KEYS)}")
    sweeps = {}
    for k, v in doc.get("sweeps", {}).items():
        if k not in SWEEPS:
            raise ResultsError(f"{path} [sweeps]: unknown table {k!r}; one of {', '.join(SWEEPS)}")
        sweeps[k] = path.parent / v
    bad = sorted(set(doc.get("class", {}).values()) - set(PAPER_SCENES))
    if bad:
        raise ResultsError(f"{path} [class]: {bad} are not the paper's scenes "
                           f"({', '.join(PAPER_SCENES)})")
    bad = sorted(set(doc.get("note", {})) - set(SWEEPS) - set(NOTES))
    if bad:
        raise ResultsError(f"{path} [note]: unknown table(s) {', '.join(bad)}; a note goes under "
                           f"one of {', '.join((*SWEEPS, *NOTES))}")
    thr = doc.get("threads")
    if thr is not None:
        thr = dict(thr, scene=str(path.parent / thr["scene"]))
    return Plan(path, doc.get("title", "Results"), dict(doc.get("class", {})), sweeps, thr,
                doc.get("usage_scene"), doc.get("resolution_note", ""), dict(doc.get("note", {})))


# ---- running ---------------------------------------------------------------------------------

@dataclass
class Run:
    rows: dict = field(default_factory=dict)      # sweep key -> rows (saarcor.sweep.point_row)
    specs: dict = field(default_factory=dict)     # sweep key -> Spec
    seconds: dict = field(default_factory=dict)   # sweep key -> wall seconds
    failed: int = 0
    computed: int = 0
    threads: dict | None = None
    scaling: dict | None = None
    pending: dict = field(default_factory=dict)   # sweep key -> labels of the points not run


def point_text(p: sw.Point, spec: sw.Spec) -> str:
    """A point as a reader finds it in its spec: scene, frame and what sets it apart."""
    vary = [k for k in p.config if len({json.dumps(q.config.get(k)) for q in spec.points}) > 1]
    if len(vary) > 4:       # a preset against another: name the chip
        return f"{p.label()} {_chip_name([{**p.config, 'status': 'ok'}])}"
    return p.label() + "".join(f" {k}={p.config[k]}" for k in vary)


def add_limits(rows: list[dict], cache: Path) -> None:
    """Each chip row gets its frame's measured limit (``limiter.limit``, ``limiter.why``:
    :func:`saarcor.sim.limiter` on the point's cached stats, the rule `saarcor sim` prints)."""
    from saarcor.sim import limiter
    for r in rows:
        if r.get("backend") != "chip" or r.get("status") != "ok" or r.get("limiter.limit"):
            continue
        hit = sw._cache_read(cache / f"{r['key']}.json")
        try:
            lim = limiter(hit["stats"])
        except (TypeError, KeyError, ValueError):
            continue
        r["limiter.limit"], r["limiter.why"] = lim["limit"], lim["why"]


def cached_rows(spec: sw.Spec, cache: Path) -> tuple[list[dict], list[str]]:
    """The rows of ``spec``'s points found in ``cache``, and the points not found."""
    code = sw.code_hash()
    rows, pending = [], []
    for p in spec.points:
        k = sw.point_key(p, code)
        hit = sw._cache_read(cache / f"{k}.json")
        if hit is None:
            pending.append(point_text(p, spec))
        else:
            rows.append(sw.point_row(p, k, hit))
    add_limits(rows, cache)
    return rows, pending


def run_plan(plan: Plan, *, workers: int, cache: Path, out_dir: Path, threads: bool,
             scaling: bool, kd_cache: str = "default", log=None, compute: bool = True,
             cluster_kind: str = "local", cluster_options: tuple = (),
             scheduler: str | None = None) -> Run:
    """Every sweep of ``plan`` on one Dask cluster (only if a point is not cached): local
    worker processes, a batch system's (``cluster_kind`` and ``cluster_options`` as
    ``saarcor sweep --cluster``), or a running ``scheduler``; with ``compute`` false only the
    points in ``cache``, the others listed in ``Run.pending``."""
    log = sys.stdout if log is None else log
    run = Run()
    code = sw.code_hash()
    specs = {k: sw.load_spec(p) for k, p in plan.sweeps.items() if k != "scaling"}
    if not compute:
        for k, spec in specs.items():
            run.rows[k], run.pending[k] = cached_rows(spec, cache)
            run.specs[k] = spec
            print(f"results: {spec.name}: {len(spec.points)} points, {len(run.rows[k])} "
                  f"cached, {len(run.pending[k])} not run", file=log, flush=True)
        if plan.threads:
            run.threads = _kept(out_dir / "threads.json", log)
        if "scaling" in plan.sweeps:
            run.scaling = _kept(out_dir / "scaling.json", log)
        return run
    todo = sum(sw._cache_read(cache / f"{sw.point_key(p, code)}.json") is None
               for s in specs.values() for p in s.points)
    client = cluster = None
    try:
        if todo:
            from distributed import Client
            if scheduler:
                client = Client(scheduler)
                where = scheduler
            else:
                opts = list(cluster_options)
                if cluster_kind == "local" and not any(o.startswith("dashboard_address=")
                                                       for o in opts):
                    opts.append("dashboard_address=:0")
                cluster = sw.make_cluster(cluster_kind, workers, opts)
                client = Client(cluster)
                where = f"{workers} {cluster_kind} worker(s)"
            print(f"results: {todo} point(s) to compute on {where}; Dask "
                  f"dashboard at {client.dashboard_link}", file=log, flush=True)
        for k, spec in specs.items():
            t0 = time.perf_counter()
            res = sw.run_sweep(spec, out=out_dir / spec.name, cache=cache, client=client,
                               progress=False, log=log, kd_cache=kd_cache)
            run.seconds[k] = time.perf_counter() - t0
            run.rows[k], run.specs[k] = res["rows"], spec
            add_limits(run.rows[k], cache)
            run.failed += res["failed"]
            run.computed += res["computed"]
            print(f"results: {spec.name}: {res['points']} points, {res['cached']} cached, "
                  f"{res['computed']} computed, {res['failed']} failed, "
                  f"{run.seconds[k]:.0f} s", file=log, flush=True)
    finally:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
    if plan.threads:
        run.threads = (run_threads(plan.threads, out_dir, log) if threads
                       else _kept(out_dir / "threads.json", log))
    if "scaling" in plan.sweeps:
        run.scaling = (measure_scaling(plan.sweeps["scaling"], out_dir, log, kd_cache)
                       if scaling else _kept(out_dir / "scaling.json", log))
    return run


def _kept(path: Path, log) -> dict | None:
    """A skipped measurement's JSON from an earlier run (``None`` when there is none)."""
    try:
        res = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    print(f"results: {path} kept from an earlier run", file=log, flush=True)
    return res


def run_threads(t: dict, out_dir: Path, log) -> dict:
    """The threads bench (one RTC in Verilator on ideal memories), kept as JSON."""
    from saarcor.bench.threads import sweep as threads_sweep
    cfg = Config()
    w, h = parse_res(t["res"])
    counts = list(t.get("counts", (1, 2, 4, 8, 16)))
    t0 = time.perf_counter()
    res = threads_sweep(t["scene"], w, h, cfg, counts, cfg.mem_latency, log=log,
                        backend="verilator")
    res["wall_seconds"] = time.perf_counter() - t0
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "threads.json").write_text(json.dumps(res, indent=1))
    return res


def measure_scaling(spec_path: Path, out_dir: Path, log, kd_cache: str = "default") -> dict:
    """The same small spec with 1 and 2 local workers, each with an empty result cache, kept
    as JSON."""
    from distributed import Client, LocalCluster
    spec = sw.load_spec(spec_path)
    out = {"spec": spec.name, "points": len(spec.points), "runs": []}
    for n in (1, 2):
        with tempfile.TemporaryDirectory() as d:
            load = os.getloadavg()[0]
            t0 = time.perf_counter()
            with LocalCluster(n_workers=n, threads_per_worker=1,
                              dashboard_address=":0") as cluster, Client(cluster) as client:
                res = sw.run_sweep(spec, out=Path(d) / "out", cache=Path(d) / "cache",
                                   client=client, progress=False, log=io.StringIO(),
                                   kd_cache=kd_cache)
            wall = time.perf_counter() - t0
        jobs = sum(float(r["job_seconds"] or 0) for r in res["rows"])
        out["runs"].append({"workers": n, "wall_seconds": wall, "job_seconds": jobs,
                            "failed": res["failed"], "load_before": load})
        print(f"results: scaling {spec.name}: {n} worker(s) {wall:.1f} s "
              f"(jobs {jobs:.1f} s)", file=log, flush=True)
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "scaling.json").write_text(json.dumps(out, indent=1))
    return out


# ---- tables ----------------------------------------------------------------------------------

def _f(x, fmt="{:.2f}", none="—"):
    if x is None or x == "" or (isinstance(x, float) and math.isnan(x)):
        return none
    return fmt.format(x)


def _pct(x):
    return _f(None if x is None else 100 * x, "{:.1f} %")


def _num(row, key):
    v = row.get(key) if row else None
    if v is None or v == "":
        return None
    return float(v)


def _stem(row) -> str:
    return Path(row["scene"]).stem


def _ok(rows, **match):
    """Rows with status ok whose fields equal ``match`` (scene by file stem)."""
    out = []
    for r in rows:
        if r.get("status") != "ok":
            continue
        if all((_stem(r) if k == "scene" else r.get(k)) == v for k, v in match.items()):
            out.append(r)
    return out


def _one(rows, **match):
    found = _ok(rows, **match)
    return found[0] if found else None


def _res(rows) -> str:
    rs = sorted({f"{r['width']}×{r['height']}" for r in rows})
    return ", ".join(rs) if rs else "—"


def _scenes(rows) -> str:
    return ", ".join(sorted({f"`{_stem(r)}`" for r in rows}))


def _rtcs(rows) -> str:
    n = sorted({int(r["rtcs"]) for r in rows})
    return " and ".join(map(str, n)) + (" RTC" if n == [1] else " RTCs")


def _frac(rows) -> str:
    """The share of the paper's 1024x768 rays a frame of ``rows``' resolution has."""
    px = {int(r["width"]) * int(r["height"]) for r in rows}
    if len(px) != 1:
        return "a fraction"
    f = px.pop() / (1024 * 768)
    return f"1/{1 / f:.0f}" if f < 1 and abs(1 / f - round(1 / f)) < 1e-9 else f"{f:.3g}×"


def _chip_name(rows) -> str:
    """The chip ``rows`` ran on: "the paper preset" (the projection test and the slaves' pool:
    ``--preset paper``), else "the standard chip"."""
    r = next((r for r in rows if r.get("status") == "ok"), rows[0] if rows else {})
    paper = r.get("int_test") == "projection" and _true(r.get("rgs_fp_pool"))
    return "the paper preset" if paper else "the standard chip"


def _chip_text(rows) -> str:
    """The chip's figures that every row of ``rows`` shares: threads, sub-units, the caches
    and their topology, SDRAM chips and bandwidth, clock."""
    ok = [r for r in rows if r.get("status") == "ok"] or list(rows)
    if not ok:
        return ""

    def same(k):
        vals = {str(r.get(k)) for r in ok}
        return ok[0].get(k) if len(vals) == 1 else None
    out = []
    if same("threads") is not None:
        out.append(f"{same('threads')} threads")
    if same("trav_subunits") is not None:
        out.append(f"{same('trav_subunits')} traversal sub-units")
    kb = [same(f"{u}_cache_kb") for u in ("trav", "list", "int")]
    if all(k is not None for k in kb):
        ways = same("cache_ways")
        assoc = ("direct-mapped" if str(ways) == "1" else
                 f"{ways}-way" if ways is not None else "")
        topo = same("cache_topology")
        where = (" shared by all RTCs" if topo == "shared" else
                 " in every RTC" if topo == "private" else "")
        out.append(f"{assoc} caches of {'/'.join(str(k) for k in kb)} KB{where}".strip())
    chips, mhz = same("mem_chips"), same("clock_mhz")
    if chips is not None and mhz is not None:
        bits, ratio = same("mem_chip_bits"), same("mem_clock_ratio")
        gbs = (f" = {int(chips) * int(bits) / 8 * float(mhz) / int(ratio) / 1e3:.2f} GB/s"
               if bits is not None and ratio is not None else "")
        out.append(f"{chips} SDRAM chips{gbs}")
    if mhz is not None:
        out.append(f"{float(mhz):.0f} MHz")
    return ", ".join(out)


def _grown(base, row) -> tuple[float, float]:
    """``row``'s rays and cycles over ``base``'s (two chip frames)."""
    return (_num(row, "rays_total") / _num(base, "rays_total"),
            _num(row, "cycles") / _num(base, "cycles"))


def _why(row) -> str:
    """A chip row's ideal bound and its measured limit: "int-ops; slave-pool-bound"."""
    if not row:
        return ""
    parts = [str(x) for x in (row.get("bound"), row.get("limiter.limit")) if x not in (None, "")]
    return "; ".join(parts)


def _streams(rows) -> str:
    """The result streams of ``rows``: "4 result streams", or "1 to 4 result streams (as many
    as the RTCs, up to 4)" where they grow with the RTCs."""
    n = sorted({int(r.get("result_ports") or 1) for r in rows})
    if len(n) == 1:
        return f"{n[0]} result stream" + ("s" if n[0] > 1 else "")
    grows = all(int(r.get("result_ports") or 1) == min(int(r["rtcs"]), n[-1]) for r in rows)
    return (f"{n[0]} to {n[-1]} result streams"
            + (f" (as many as the RTCs, up to {n[-1]})" if grows else ""))


def _cap(text: str) -> str:
    return text[:1].upper() + text[1:]


def _preset_text(rows) -> str:
    """What the paper preset changes, for a caption ("" on the standard chip)."""
    if _chip_name(rows) != "the paper preset":
        return ""
    return ("; the paper's cost: the projection test, each RGS slave on a pool of 3 FP adders "
            "and 4 multipliers, the one-value stack: `--preset paper`, docs/paper-preset.md")


def _true(v) -> bool:
    """A boolean field of a row (a bool, or its text in a CSV)."""
    return v is True or str(v).strip().lower() in ("true", "1")


def _asks_secondary(r) -> bool:
    """Does the row's configuration ask for shadow or reflection rays?"""
    return _true(r.get("shadows")) or int(r.get("reflect_depth") or 0) > 0


def _secondary_rays(r) -> float:
    return sum(_num(r, f"rays.{k.label}") or 0 for k in RayKind if k != RayKind.EYE)


def rays_text(rows, short: bool = False) -> str:
    """Which rays the chip ``rows`` traced, for a table's caption: eye rays only, or all the
    rays each scene has (with the reflection depth the rows ask for; ``short``: without the
    list of kinds), or a mix."""
    ok = [r for r in rows if r.get("status") == "ok"] or list(rows)
    asked = [_asks_secondary(r) for r in ok]
    if not any(asked):
        return "eye rays only"
    if short and all(asked):
        return "all the rays each scene has"
    depth = max(int(r.get("reflect_depth") or 0) for r in ok)
    lights = all(_true(r.get("shadows")) for r in ok)
    kinds = ", ".join(x for x in ("eye rays", "a shadow ray per light from every hit" if lights
                                  else "", f"reflections up to depth {depth}" if depth else "")
                      if x)
    if all(asked):
        return f"all the rays each scene has ({kinds}; a scene without lights or mirrors makes eye rays only)"
    return "eye rays, and where the row says so shadow and reflection rays"


def _refracted(r):
    """A frame's refracted rays: none where the chip was built without refraction (its
    stats then have no such count)."""
    n = _num(r, "rays.refraction")
    return 0 if n is None and r is not None and not _true(r.get("refraction")) else n


def _frame(r):
    return int(r["width"]), int(r["height"])


def _main_frame(rows):
    """The frame of a sweep's page rows: 1024x768 where any row has it, else the commonest."""
    fs = [_frame(r) for r in rows]
    if not fs:
        return None
    return (1024, 768) if (1024, 768) in fs else max(sorted(set(fs)), key=fs.count)


def _scene_frames(rows, scene, main):
    """The frames ``scene`` ran at among ``rows``: the page's frame ``main`` first, then the
    others from the largest down."""
    return [main] + sorted({_frame(r) for r in rows if _stem(r) == scene} - {main},
                           reverse=True)


def _at(rows, frame):
    """The rows of ``rows`` at ``frame`` (width, height)."""
    return [r for r in rows if _frame(r) == frame]


def chip_cases(rows) -> dict:
    """The chip's office cases of Table 5 among ok ``rows``: ``{case name: row}`` for the
    :data:`CASES` found. The frame is the smallest resolution of the rows; (e) is that frame
    with ``oversampling = 2``, or an eye-ray frame of twice its width and height (the same rays
    and packets)."""
    ok = [r for r in rows if r.get("status") == "ok"]
    if not ok:
        return {}
    w, h = min((_frame(r) for r in ok), key=lambda f: f[0] * f[1])
    out = {}
    for name, (depth, shadows, over) in CASES:
        for r in ok:
            if int(r.get("reflect_depth") or 0) != depth or _true(r.get("shadows")) != shadows:
                continue
            os_ = int(r.get("oversampling") or 1)
            if not over and os_ == 1 and _frame(r) == (w, h):
                out[name] = r
            elif over and ((os_ == 2 and _frame(r) == (w, h)) or
                           (os_ == 1 and _frame(r) == (2 * w, 2 * h))):
                out[name] = r
            if name in out:
                break
    return out


def _os_rows(rows):
    """(eye-ray frame, the same frame 4x oversampled) among ok chip rows (:func:`chip_cases`
    (a) and (e))."""
    c = chip_cases(rows)
    return c.get(CASES[0][0]), c.get(CASES[4][0])


def _os_text(eye, os_row) -> str:
    if eye is None:
        return "no frame"
    w, h = eye["width"], eye["height"]
    if os_row is None:
        return f"{w}×{h}; the oversampled frame is missing"
    how = ("`oversampling = 2`" if int(os_row["oversampling"]) == 2 else
           f"run as the {os_row['width']}×{os_row['height']} frame, whose rays and packets are "
           "exactly those of 2×2 rays per pixel")
    return f"{w}×{h}, and 4× oversampled ({how})"


def _commit() -> str:
    """The checkout's commit, ``-dirty`` when the sources the points depend on (those of
    ``saarcor.sweep.code_hash``) differ from it; the plan, the specs and this page writer may."""
    import subprocess
    paths = [*sw.CODE_DIRS, *(f":!{p}" for p in sw.CODE_EXCLUDE)]
    try:
        c = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                           capture_output=True, text=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "--", *paths],
                               capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        c = dirty = ""
    return f"`{c}{'-dirty' if dirty else ''}`" if c else "unknown"


def _build_text(root: Path = ROOT / "build" / "verilator") -> str:
    """How long the chip's Verilator binaries took to build here (the latest per RTC count,
    from their ``build.json``)."""
    took = {}
    for p in sorted(root.glob("*/build.json"), key=lambda p: p.stat().st_mtime):
        try:
            d = json.loads(p.read_text())
            if d.get("top") == "chip":
                took[int(d["config"]["rtcs"])] = float(d["build_s"])
        except (OSError, ValueError, KeyError, TypeError):
            continue
    if not took:
        return "minutes each"
    return "here " + ", ".join(f"{s / 60:.0f} min with {n} RTC{'s' if n > 1 else ''}"
                               for n, s in sorted(took.items()))


def _ideal_cycles(trav, inter, rtcs=4, sub=4):
    return max(trav / (rtcs * sub), inter / rtcs)


def _md_table(head, rows) -> str:
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


class Writer:
    """Builds the page section by section; ``missing`` counts table cells without a value."""

    def __init__(self, plan: Plan, run: Run, img: Path, page: Path):
        self.plan, self.run, self.img, self.page = plan, run, img, page
        self.parts: list[str] = []
        self.missing = 0
        self.figures: list[Path] = []
        self.commit = ""       # the checkout's commit when the run started (before the plots)

    def rel(self, p: Path) -> str:
        return os.path.relpath(p, self.page.parent)

    def fig(self, plt, fig, name: str) -> str:
        self.img.mkdir(parents=True, exist_ok=True)
        p = self.img / name
        fig.savefig(p, dpi=90, bbox_inches="tight")
        plt.close(fig)
        self.figures.append(p)
        return f"![{name}]({self.rel(p)})"

    def cell(self, x, fmt="{:.2f}", planned=True):
        """A value; an empty cell counts as missing unless nothing was planned there."""
        if x is None and planned:
            self.missing += 1
        return _f(x, fmt, "—" if planned else "not run")

    def note(self, key) -> str:
        n = self.plan.notes.get(key)
        return f"\n\n{n.strip()}" if n else ""

    def pcell(self, x):
        if x is None:
            self.missing += 1
        return _pct(x)

    def add(self, text: str):
        self.parts.append(text.strip("\n") + "\n")

    def not_yet(self, key: str, heading: str) -> None:
        """A section whose sweep has no point measured yet: its heading and how many are
        pending (listed in the last section), so the page shows what it will hold."""
        n = len(self.run.pending.get(key, []))
        if n:
            self.add(f"{heading}\n\n*Not measured yet*: the {n} point(s) of "
                     f"`{self._spec(key)}` are listed under the page's cost.")

    # -- the scene classes ---------------------------------------------------------------------
    def scenes(self):
        rows = self.run.rows.get("rays", [])
        body = []
        for ours, paper in self.plan.classes.items():
            r = _one(rows, scene=ours)
            pt = PAPER_SCENES[paper]
            body.append([f"`{ours}`", self.cell(_num(r, "triangles"), "{:,.0f}"),
                         self.cell(_num(r, "rays_total"), "{:,.0f}"),
                         self.cell(_num(r, "memory_image_bytes") and
                                   _num(r, "memory_image_bytes") / 2**20, "{:.0f} MB"),
                         self.cell(_num(r, "kdtree.depth"), "{:.0f}"),
                         paper, f"{pt[0]:,}", pt[1], pt[2], f"{pt[3]:,}"])
        self.add(f"""
## The scenes (the paper's Table 1)

Our scenes stand for the paper's classes (`docs/scenes.md`). Triangles, rays per frame (eye,
shadow and reflection rays of the golden model at {_res(rows)}, the scene's lights, reflection
depth 3), memory image and kd-tree depth come from the `{self._spec('rays')}` sweep; the
paper's columns are for 1024×768.

""" + _md_table(["our scene", "triangles", "rays per frame (model)", "memory image",
                 "kd-tree depth", "paper's scene", "triangles", "lights", "refl. depth",
                 "rays (1024×768)"], body))

    def _spec(self, key):
        s = self.run.specs.get(key)
        return os.path.relpath(s.path, ROOT) if s else "(not in this plan)"

    # -- Table 2 and 4 -------------------------------------------------------------------------
    def table2(self):
        all_rows = self.run.rows.get("rtcs", [])
        if not all_rows:
            return
        main = _main_frame(all_rows)
        rows = _at(all_rows, main)          # the page's frame; a scene's smaller frame below
        body, rel_body, fig_data, smaller = [], [], {}, []
        for ours, paper in self.plan.classes.items():
            mine = [r for r in all_rows if _stem(r) == ours]
            if not mine:
                continue
            for frame in _scene_frames(mine, ours, main):
                at = _at(mine, frame)
                if not at and frame == main:
                    continue
                other = frame != main
                if other:
                    smaller.append((ours, frame))
                label = f"`{ours}` ({paper})" + (f", {frame[0]}×{frame[1]}" if other else "")
                pts = [_one(at, rtcs=n) for n in RTCS]
                planned = [any(r.get("rtcs") == n for r in at) for n in RTCS]
                moved = [not other and not q and any(r.get("rtcs") == n and _frame(r) != main
                                                     for r in mine)
                         for q, n in zip(planned, RTCS)]      # run at a smaller frame only
                fps = [_num(p, "fps") for p in pts]
                rays = [_num(p, "rays_total") for p in pts]
                mr = [f * r / 1e6 if f and r else None for f, r in zip(fps, rays)]
                pr = [f * PAPER_SCENES[paper][3] / 1e6 for f in PAPER_FPS[paper]]
                n_rays = next((x for x in rays if x), None)     # the same frame on every chip
                n_sec = next((_secondary_rays(p) for p in pts if p), None)

                def c(x, fmt, q, m):
                    return "smaller frame ↓" if m else self.cell(x, fmt, q)
                body.append([label,
                             self.cell(n_rays, "{:,.0f}"),
                             self.cell(n_rays and n_sec is not None and n_sec / n_rays, "{:.0%}"),
                             *[c(x, "{:,.2f}", q, m) for x, q, m in zip(fps, planned, moved)],
                             *[c(x, "{:.1f}", q, m) for x, q, m in zip(mr, planned, moved)],
                             *[f"{x:.1f}" for x in pr],
                             f"{PAPER_SCENES[paper][3]:,}",
                             *[f"{x:.2f}" for x in PAPER_FPS[paper]]])
                rel = [_num(p, "relative_performance") for p in pts]
                bound = [_why(p) for p in pts]
                rel_body.append([label,
                                 *["smaller frame ↓" if m else
                                   (self.pcell(x) + (f" ({b})" if b else "")) if q else "not run"
                                   for x, b, q, m in zip(rel, bound, planned, moved)],
                                 *[f"{100 * x:.0f} %" for x in PAPER_REL[paper]]])
                fig_data[ours + (f" {frame[0]}×{frame[1]}" if other else "")] = (paper, mr, pr)
        res = _res(rows)
        frac = _frac(rows)
        frac_text = ("" if all(_frame(r) == (1024, 768) for r in rows) else
                     f"; a frame of {frac} of the paper's pixels (a smaller one starts with "
                     "cold caches for more of its rays)")
        if smaller:
            frac_text += ("; " + ", ".join(f"`{s}`" for s in sorted({s for s, _ in smaller}))
                          + " also at " + ", ".join(sorted({f"{w}×{h}" for _, (w, h) in smaller}))
                          + " (" + _frac(_at(all_rows, smaller[0][1])) + " of the paper's "
                          "pixels), a row that compares with itself across the RTCs, not with "
                          f"the {res} rows: a smaller frame starts with cold caches for more of "
                          "its rays, and its rays are less coherent")
        kinds = rays_text(rows)
        plt = _plt()
        fig, ax = plt.subplots(1, 2, figsize=(11, 4))
        drawn = set()
        for ours, (paper, mr, pr) in fig_data.items():
            if mr[0]:
                ax[0].plot(RTCS, [x / mr[0] if x else float("nan") for x in mr], "o-",
                           label=f"{ours}")
            if paper not in drawn:
                drawn.add(paper)
                ax[1].plot(RTCS, [x / pr[0] for x in pr], "s--", label=paper)
        short = "eye rays" if kinds == "eye rays only" else "all rays"
        for a, t in zip(ax, (f"our chip, {short}, {res}", "paper, 1024×768, all rays")):
            a.plot(RTCS, RTCS, "k:", label="linear")
            a.set_xlabel("RTCs")
            a.set_xticks(RTCS)
            a.set_ylabel("speed-up over 1 RTC")
            a.set_title(t, fontsize=10)
            a.legend(fontsize=7)
        figure = self.fig(plt, fig, "results_rtcs.png")
        self.add(f"""
## Table 2: frames per second with 1, 2 and 4 RTCs

{_cap(_chip_name(rows))} ({_chip_text(rows)}{_preset_text(rows)}) with 1, 2 and 4 RTCs. **Chip columns: measured, {kinds}**, one frame at
{res} through the whole chip in Verilator (`{self._spec('rtcs')}`), every ray checked against
the golden model{frac_text}. *Rays* counts every ray of the chip's frame (eye, shadow and reflection), *secondary*
the share of shadow and reflection rays. Frames of different sizes compare by rays per second
(M rays/s = fps × rays per frame), the paper's by its rays at 1024×768.

""" + _md_table(["scene", "rays", "secondary", "fps 1 RTC", "2 RTCs", "4 RTCs",
                 "M rays/s 1", "2", "4", "paper M rays/s 1", "2", "4", "paper rays",
                 "paper fps 1", "2", "4"], body) + self.note("rtcs") + f"""

{figure}

## Table 4: relative performance

Measured fps over the ideal fps of the same frame's operation counts (chip,
{rays_text(rows, short=True)}, {res});
in brackets the kind of unit the ideal is bound by, then what limited the frame as the chip's
counters measured it (`saarcor sim`'s limiter: a unit kind busy most of the cycles, the RGS
slaves' FP pool, memory bandwidth, the bus, memory latency, back-pressure or starvation;
`docs/chip.md`). Paper: 1024×768, all rays.

""" + _md_table(["scene", "1 RTC", "2 RTCs", "4 RTCs", "paper 1 RTC", "2", "4"], rel_body)
                 + self.note("relative"))

    # -- Table 3 -------------------------------------------------------------------------------
    def table3(self):
        rows = self.run.rows.get("intcache", [])
        if not rows:
            if "intcache" not in self.plan.sweeps and self.plan.notes.get("intcache"):
                self.add("## Table 3: int-cache size and memory bandwidth" + self.note("intcache"))
            self.not_yet("intcache", "## Table 3: int-cache size and memory bandwidth")
            return
        scene = _stem(rows[0])
        kbs = sorted({int(r["int_cache_kb"]) for r in rows})
        chips = sorted({int(r["mem_chips"]) for r in rows})
        base = _num(_one(rows, int_cache_kb=kbs[0], mem_chips=chips[0]), "fps")
        body = []
        for c in chips:
            fps = [_num(_one(rows, int_cache_kb=k, mem_chips=c), "fps") for k in kbs]
            hit = [_num(_one(rows, int_cache_kb=k, mem_chips=c), "cache.int.hit_rate")
                   for k in kbs]
            rel = [f / base if f and base else None for f in fps]
            gbs = Config(mem_chips=c).mem_bytes_per_s / 1e9
            body.append([f"{gbs:.2f} GB/s ({c} SDRAM chips)",
                         *[f"{self.cell(f, '{:,.2f}')} ({self.cell(r, '{:.2f}')}×, int hit "
                           f"{self.pcell(h)})" if f is not None else self.cell(None)
                           for f, r, h in zip(fps, rel, hit)],
                         *[f"{PAPER_T3.get((k, c), float('nan')):.2f} "
                           f"({PAPER_T3.get((k, c), float('nan')) / PAPER_T3[(144, 4)]:.2f}×)"
                           for k in kbs]])
        plt = _plt()
        fig, ax = plt.subplots(figsize=(6, 3.6))
        for c in chips:
            fps = [_num(_one(rows, int_cache_kb=k, mem_chips=c), "fps") for k in kbs]
            ax.plot(kbs, [f / base if f and base else float("nan") for f in fps], "o-",
                    label=f"ours, {c} chips")
            ax.plot(kbs, [PAPER_T3.get((k, c), float("nan")) / PAPER_T3[(144, 4)] for k in kbs],
                    "s--", label=f"paper, {c} chips")
        ax.set_xlabel("int-cache, KB")
        ax.set_xticks(kbs)
        ax.set_ylabel("fps relative to 144 KB, 4 chips")
        ax.legend(fontsize=7)
        figure = self.fig(plt, fig, "results_intcache.png")
        self.add(f"""
## Table 3: int-cache size and memory bandwidth

`{scene}`, {_rtcs(rows)}, {rays_text(rows)}, at {_res(rows)}
through the chip (`{self._spec('intcache')}`); int-cache {', '.join(f'{k} KB' for k in kbs)} ×
{' and '.join(str(c) for c in chips)} SDRAM chips. In brackets: fps relative to the paper's
int-cache and bandwidth (144 KB, 4 chips) and the int-cache hit rate. Paper: CruiserGL, 4 RTCs, 1024×768.

""" + _md_table(["bandwidth", *[f"{k} KB" for k in kbs], *[f"paper {k} KB" for k in kbs]],
                body) + self.note("intcache") + f"\n\n{figure}")

    # -- Tables 5 and 6 ------------------------------------------------------------------------
    def _chip_office(self):
        """The chip's office rows (Tables 5 and 6): the ``raykinds_chip`` sweep, or an older
        plan's ``oversampling`` sweep (eye rays with and without oversampling)."""
        key = "raykinds_chip" if "raykinds_chip" in self.run.rows else "oversampling"
        return key, self.run.rows.get(key, [])

    def table5(self):
        rows = self.run.rows.get("raykinds", [])
        if not rows:
            return
        ckey, chip = self._chip_office()
        cases = [(name, dict(reflect_depth=d, shadows=sh, oversampling=2 if o else 1))
                 for name, (d, sh, o) in CASES]
        scene = _stem(rows[0])
        found = chip_cases(chip)
        eye_row, os_row = found.get(CASES[0][0]), found.get(CASES[4][0])
        chip_eye = _num(eye_row, "cycles")
        planned = bool(chip) and ckey == "raykinds_chip"
        base = None
        body, pts = [], []
        for (name, match), (_, prays, pfps) in zip(cases, PAPER_T5):
            r = _one(rows, **match)
            n = _num(r, "rays_total")
            cyc = (_ideal_cycles(_num(r, "counters.trav_ops"), _num(r, "counters.int_ops"))
                   if r else None)
            if base is None:
                base = (n, cyc)
            ideal = Config().clock_mhz * 1e6 / cyc if cyc else None
            c = found.get(name)
            measured = _num(c, "fps")
            meas_cost = (_num(c, "cycles") / chip_eye) if (c and chip_eye) else None
            share = n and base[0] and base[0] / n
            cost = cyc and base[1] and cyc / base[1]
            want = planned or name[:3] in ("(a)", "(e)")
            body.append([name, self.cell(n, "{:,.0f}"), self.pcell(share),
                         self.cell(_num(r, "counters.trav_ops"), "{:,.0f}"),
                         self.cell(_num(r, "counters.int_ops"), "{:,.0f}"),
                         self.cell(ideal, "{:,.0f}"), self.cell(cost, "{:.2f}×"),
                         self.cell(_num(c, "rays_total"), "{:,.0f}", want),
                         self.cell(measured, "{:,.2f}", want),
                         self.cell(meas_cost, "{:.2f}×", want),
                         self.cell(_num(c, "relative_performance") and
                                   100 * _num(c, "relative_performance"), "{:.1f} %", want),
                         f"{prays:,}", f"{100 * PAPER_T5[0][1] / prays:.0f} %", f"{pfps:.2f}",
                         f"{PAPER_T5[0][2] / pfps:.2f}×"])
            crays = _num(c, "rays_total")
            pts.append((name[:3], n / base[0] if n and base[0] else None, cost,
                        crays / _num(eye_row, "rays_total") if crays and eye_row else None,
                        meas_cost, prays / PAPER_T5[0][1], PAPER_T5[0][2] / pfps))
        plt = _plt()
        fig, ax = plt.subplots(figsize=(6, 4))
        ax.plot([1, 5], [1, 5], "k:", label="cost = rays")
        ax.plot([p[1] for p in pts], [p[2] for p in pts], "o",
                label="ours: golden model's ideal cycles")
        ax.plot([p[3] for p in pts if p[4]], [p[4] for p in pts if p[4]], "D",
                label="ours: the chip's cycles (measured)")
        ax.plot([p[5] for p in pts], [p[6] for p in pts], "s", label="paper: 1/fps")
        for p in pts:
            x, y = (p[3], p[4]) if p[4] else (p[1], p[2])
            if x and y:
                ax.annotate(p[0], (x, y), fontsize=7, xytext=(3, -9),
                            textcoords="offset points")
        ax.set_xlabel("rays / eye rays")
        ax.set_ylabel("cost / cost of eye rays")
        ax.legend(fontsize=7)
        figure = self.fig(plt, fig, "results_raykinds.png")
        if planned:
            chip_text = (f"**Chip columns** (`{self._spec(ckey)}`): each case measured on the "
                         f"{_chip_name(chip)[4:]} (4 RTCs) in Verilator, the RGS slaves making the shadow "
                         f"and reflection rays, every ray checked against the golden model: "
                         f"rays traced, fps, cycles relative to (a) and the relative "
                         f"performance; {_os_text(eye_row, os_row)}.")
        else:
            chip_text = (f"**Chip columns** (`{self._spec(ckey)}`): measured fps of eye-ray "
                         f"frames with and without 4× oversampling "
                         f"({_os_text(eye_row, os_row)}); (b)–(d) were not run on the chip.")
        self.add(f"""
## Table 5: the office's cost per kind of ray

`{scene}` (the paper's Office class: 3 point lights, a mirror ball, reflection depth 3) at
{_res(rows)}. **Golden-model columns** (`{self._spec('raykinds')}`): rays shot, trav-ops and
int-ops of every ray kind, the ideal fps of 4 RTCs from those counts (533 MHz /
`max(trav-ops / 16, int-ops / 4)`, a bound, not a measurement) and the cost relative to eye
rays in those ideal cycles. {chip_text} Paper: Office, 4 RTCs, 1024×768.

""" + _md_table(["case", "rays (model)", "rays(er)/rays", "trav-ops", "int-ops",
                 "ideal fps, 4 RTCs", "cost / cost(er) (model)", "rays (chip)",
                 "chip fps, 4 RTCs", "cost / cost(er) (chip)", "relative perf. (chip)",
                 "paper rays", "rays(er)/rays", "paper fps", "fps(er)/fps"], body)
                 + f"\n\n{figure}")

    def table6(self):
        ckey, chip = self._chip_office()
        if not chip:
            return
        scene = _stem(chip[0])
        body = []
        found = chip_cases(chip)
        eye_row, os_row = found.get(CASES[0][0]), found.get(CASES[4][0])
        all_row = found.get(CASES[3][0])
        with_all = ckey == "raykinds_chip"
        for k in ("trav", "list", "int"):
            a = _num(eye_row, f"cache.{k}.hit_rate")
            b = _num(os_row, f"cache.{k}.hit_rate")
            c = [self.pcell(_num(all_row, f"cache.{k}.hit_rate"))] if with_all else []
            body.append([f"{k}-cache", self.pcell(a), self.pcell(b), *c,
                         f"{100 * PAPER_T6[k][0]:.1f} %", f"{100 * PAPER_T6[k][1]:.1f} %"])
        allcol = ["ours, all rays (d)"] if with_all else []
        alltext = (" The third column is case (d) of Table 5, the office with all its rays "
                   "(the paper's standard Office frame)." if with_all else "")
        self.add(f"""
## Table 6: cache hit rates with and without oversampling

`{scene}`, {_chip_name(chip)} (4 RTCs, {_chip_text(chip)}), through the chip
(`{self._spec(ckey)}`): eye rays, {_os_text(eye_row, os_row)}.{alltext}
Paper: Office, 1024×768, all rays.

""" + _md_table(["", "ours, eye rays", "ours, eye rays 4×", *allcol, "paper, none",
                 "paper, 4×"], body))

    def refraction(self):
        """Refracted rays against eye and reflection rays on the chip (the paper: "also true
        for refracted rays ... not shown here")."""
        rows = self.run.rows.get("refraction", [])
        ok = [r for r in rows if r.get("status") == "ok"]
        if not rows:
            self.not_yet("refraction", "### Refraction")
            return
        cases = [("(a) eye rays", 0, False),
                 ("(b) eye + reflections + refractions (depth 3)", 3, True)]
        found = {}
        for name, depth, refr in cases:
            found[name] = next((r for r in ok if int(r.get("reflect_depth") or 0) == depth
                                and _true(r.get("refraction")) == refr), None)
        a = found[cases[0][0]]
        body = []
        for name, _, _ in cases:
            r = found[name]
            n = _num(r, "rays_total")
            rays_x = n / _num(a, "rays_total") if r and a else None
            cost_x = _num(r, "cycles") / _num(a, "cycles") if r and a else None
            body.append([name, self.cell(n, "{:,.0f}"),
                         self.cell(_num(r, "rays.reflection"), "{:,.0f}"),
                         self.cell(_refracted(r), "{:,.0f}"),
                         self.cell(_num(r, "cycles"), "{:,.0f}"),
                         self.cell(_num(r, "fps"), "{:,.1f}"),
                         self.cell(rays_x, "{:.2f}×"), self.cell(cost_x, "{:.2f}×"),
                         self.cell(rays_x and cost_x and cost_x / rays_x, "{:.2f}"),
                         self.pcell(_num(r, "relative_performance"))])
        scene = _stem(ok[0]) if ok else _stem(rows[0])
        self.add(f"""
### Refraction

The paper: the cost is linear in the rays "also for refracted rays used to simulate
glass-effects (not shown here)". The office has no glass, so `{scene}` (the Cornell box with
a glass sphere and a glass block), {_chip_name(rows)} ({_rtcs(rows)}; {_chip_text(rows)}),
at {_res(rows)} through the chip (`{self._spec('refraction')}`), no shadow rays: (a) eye rays,
(b) with reflections and refractions (`--refraction true`, a build option), every ray checked
against the golden model. (No reflections-only case: with reflections the chip refuses a scene
whose materials transmit unless it is built with refraction, since the golden model would trace
refracted rays its slaves never make.) A hit on a material that reflects and transmits makes
one reflected and one refracted ray (under total internal reflection the refracted ray is the
mirror ray, still counted as refracted), so where only the glass reflects the two columns are
equal. *Cost a ray* is the cycles over (a)'s
divided by the rays over (a)'s: 1.00 is exactly linear (the paper's Table 5 has 0.92 for all
its kinds together).

""" + _md_table(["case", "rays", "reflected", "refracted", "cycles", "fps", "rays / rays(a)",
                 "cycles / cycles(a)", "cost a ray", "relative perf."], body))

    # -- threads, unit usage, scaling ----------------------------------------------------------
    def _thread_runs(self):
        """(source, runs): the chip sweep's points by thread count (``[sweeps] threads``), else
        the one-RTC bench's runs; each run ``{threads, cycles, speedup, rel, bound}``."""
        rows = sorted(_ok(self.run.rows.get("threads", [])), key=lambda r: int(r["threads"]))
        if rows:
            base = next((_num(r, "cycles") for r in rows if int(r["threads"]) == 1), None)
            return "chip", [{"threads": int(r["threads"]), "cycles": int(_num(r, "cycles")),
                             "speedup": base / _num(r, "cycles") if base else None,
                             "rel": _num(r, "relative_performance"), "bound": _why(r),
                             "limit": r.get("limiter.limit")}
                            for r in rows]
        t = self.run.threads
        if t:
            return "bench", [dict(r, rel=None, bound=None) for r in t["runs"]]
        return None, []

    def threads(self):
        source, runs = self._thread_runs()
        if source == "chip":
            return self._threads_chip(runs)
        t = self.run.threads
        if not t:
            self.not_yet("threads", "## Threads: speed-up over one thread")
            return
        runs = t["runs"]
        body = [[r["threads"], f"{r['cycles']:,}", _f(r["speedup"]),
                 _f(PAPER_THREADS.get(r["threads"]), "{:.1f}")] for r in runs]
        plt = _plt()
        fig, ax = plt.subplots(figsize=(5, 3.5))
        ax.plot([r["threads"] for r in runs], [r["speedup"] for r in runs], "o-", label="ours")
        ax.plot(list(PAPER_THREADS), list(PAPER_THREADS.values()), "s", label="paper")
        ax.plot([1, 16], [1, 16], "k:", label="linear")
        ax.set_xscale("log", base=2)
        ax.set_xlabel("threads per RTC")
        ax.set_ylabel("speed-up over 1 thread")
        ax.legend(fontsize=7)
        figure = self.fig(plt, fig, "results_threads.png")
        scene = os.path.relpath(t["scene"], ROOT)
        self.add(f"""
## Threads: speed-up over one thread

One RTC of the standard configuration (8×8 packets, 4 traversal sub-units, caches
64/64/144 KB) on ideal memories with a {t['mem_latency']}-cycle latency, eye rays of
`{scene}` at {t['res'][0]}×{t['res'][1]}, in Verilator (`saarcor.bench.threads`), every ray
checked. Paper: 8 threads 7.5×, 16 threads 12.2× (whole frames of the standard chip).

""" + _md_table(["threads", "cycles", "speed-up", "paper"], body) + f"\n\n{figure}")

    def _threads_chip(self, runs):
        rows = _ok(self.run.rows["threads"])
        r0 = rows[0]
        chip = ("the paper preset" if r0.get("int_test") == "projection" and
                _true(r0.get("rgs_fp_pool")) else "the standard chip")
        body = [[r["threads"], f"{r['cycles']:,}", _f(r["speedup"], "{:.2f}"),
                 _f(PAPER_THREADS.get(r["threads"]), "{:.1f}"),
                 self.pcell(r["rel"]) + (f" ({r['bound']})" if r["bound"] else ""),
                 "80–90 %" if r["threads"] == 32 else ""] for r in runs]
        plt = _plt()
        fig, ax = plt.subplots(figsize=(5, 3.5))
        ax.plot([r["threads"] for r in runs], [r["speedup"] or float("nan") for r in runs],
                "o-", label="ours")
        ax.plot(list(PAPER_THREADS), list(PAPER_THREADS.values()), "s", label="paper")
        top = max(r["threads"] for r in runs)
        ax.plot([1, top], [1, top], "k:", label="linear")
        ax.set_xscale("log", base=2)
        ax.set_xlabel("threads per RTC")
        ax.set_ylabel("speed-up over 1 thread")
        ax.legend(fontsize=7)
        figure = self.fig(plt, fig, "results_threads.png")
        self.add(f"""
## Threads: speed-up over one thread

{_cap(chip)} with {_rtcs(rows)}, its shared caches and SDRAM, with 1 to {top}
threads (packets in flight) per RTC: {rays_text(rows, short=True)} of
{", ".join(sorted({f"`{_stem(r)}`" for r in rows}))} at {_res(rows)} through the whole chip in
Verilator (`{self._spec('threads')}`), every ray checked against the golden model. The
speed-up is the 1-thread frame's cycles over the n-thread frame's (the same rays). Paper: 8
threads 7.5×, 16 threads 12.2×, and 80–90 % relative performance with 32 threads.

""" + _md_table(["threads", "cycles", "speed-up", "paper", "relative performance",
                 "paper"], body) + self.note("threads") + f"\n\n{figure}")

    # -- Figures 1 and 3: packet size and kd-tree depth (the golden model) --------------------
    def figure1(self):
        rows = _ok(self.run.rows.get("packets", []))
        if not rows:
            return
        units = ("trav", "list", "int")
        series, body = {}, []
        for r in sorted(rows, key=lambda r: (_stem(r), int(r["tile_w"]) * int(r["tile_h"]))):
            n = int(r["tile_w"]) * int(r["tile_h"])
            words = [_num(r, f"memory_reads_64bit.{u}") or 0 for u in units]
            mb = 8 * sum(words) / 2 ** 20
            kb = 8 * sum(words) / 1024 / max(1, _num(r, "packets") or 1)
            series.setdefault(_stem(r), []).append((n, mb, kb))
            body.append([f"`{_stem(r)}`", n, f"{_num(r, 'packets'):,.0f}",
                         *(f"{8 * x / 2 ** 20:,.1f}" for x in words), f"**{mb:,.1f}**",
                         f"{kb:,.1f}"])
        plt = _plt()
        fig, ax = plt.subplots(1, 2, figsize=(9, 3.5))
        for name, pts in series.items():
            ax[0].plot([p[0] for p in pts], [p[1] for p in pts], "o-", label=name)
            ax[1].plot([p[0] for p in pts], [p[2] for p in pts], "o-", label=name)
        for a, label in zip(ax, ("MB read in a frame", "KB read by a packet (mean)")):
            a.set_xscale("log", base=2)
            a.set_xlabel("rays per packet")
            a.set_ylabel(label)
            a.legend(fontsize=7)
        figure = self.fig(plt, fig, "results_packets.png")
        self.add(f"""
## Figure 1: rays per packet against the memory read

The memory the RTC's units read in a frame — kd-tree nodes, list entries and triangles, before
any cache: the bandwidth to the caches — and what one packet reads on average, the paper's
rough size for the smallest useful cache. Eye rays at {_res(rows)}, packets of 1 to 64 rays
(a packet's lane masks are 64 bits, so 64 is the most; the paper's standard packet), the
golden model's counts (`{self._spec('packets')}`: the chip's units read the same words, their
counters equal the model's on every frame checked). A packet reads a node once a pass and a
triangle once a leaf it lies in, so "read by a packet" counts a word it reads twice twice.
Packet size changes no ray's result, only what is read.

""" + _md_table(["scene", "rays a packet", "packets", "nodes (MB)", "lists (MB)",
                 "triangles (MB)", "a frame (MB)", "a packet (KB)"], body) + f"\n\n{figure}")

    def figure3(self):
        rows = _ok(self.run.rows.get("kddepth", []))
        if not rows:
            return
        series, body = {}, []
        for r in sorted(rows, key=lambda r: (_stem(r), int(r["kd_max_depth"]))):
            rays = max(1.0, _num(r, "rays_total") or 1)
            trav, inter = (_num(r, f"counters.{k}_ops") / rays for k in ("trav", "int"))
            cost = FP_OPS["trav"] * trav + FP_OPS["int"] * inter
            series.setdefault(_stem(r), []).append((int(r["kd_max_depth"]), trav, inter, cost))
            body.append([f"`{_stem(r)}`", int(r["kd_max_depth"]), _f(_num(r, "kdtree.depth"),
                         "{:.0f}"), _f(_num(r, "kdtree.mean_nonempty_leaf_size"), "{:.1f}"),
                         f"{trav:.1f}", f"{inter:.1f}", f"{cost:.0f}"])
        best = {k: min(v, key=lambda p: p[3]) for k, v in series.items()}
        plt = _plt()
        fig, ax = plt.subplots(1, 2, figsize=(9, 3.5))
        for name, pts in series.items():
            ax[0].plot([p[1] for p in pts], [p[2] for p in pts], "o-", label=name)
            for d, t, i, _ in pts:
                ax[0].annotate(str(d), (t, i), fontsize=6)
            ax[1].plot([p[0] for p in pts], [p[3] for p in pts], "o-", label=name)
        ax[0].set_xlabel("trav-ops a ray")
        ax[0].set_ylabel("int-ops a ray")
        ax[1].set_xlabel("kd_max_depth (scene subdivisions)")
        ax[1].set_ylabel("FP operations a ray (paper's costs)")
        for a in ax:
            a.legend(fontsize=7)
        figure = self.fig(plt, fig, "results_kddepth.png")
        least = "; ".join(f"`{k}` at depth {p[0]} ({p[3]:.0f} FP operations a ray)"
                          for k, p in best.items())
        self.add(f"""
## Figure 3: trav-ops against int-ops as the kd-tree deepens

Operations a ray for kd-trees of at most `kd_max_depth` levels (leaves of at most 4 triangles,
SAH: a tree stops where its SAH or leaf size says, so the deepest settings can build the same
tree), all the rays each scene has at {_res(rows)}, the golden model's counts
(`{self._spec('kddepth')}`). The cost column weighs them as the paper does, a trav-op 4 FP
operations (3 adds, 1 multiply) and an int-op 25 (12 adds, 13 multiplies, a division counted
as three): the least cost is {least}.

""" + _md_table(["scene", "kd_max_depth", "tree depth", "triangles a non-empty leaf",
                 "trav-ops a ray", "int-ops a ray", "FP operations a ray"], body)
                 + f"\n\n{figure}")

    def usage(self):
        rows = self.run.rows.get("rtcs", [])
        rows = _at(rows, _main_frame(rows))
        scene = self.plan.usage_scene
        r = _one(rows, scene=scene, rtcs=4) if scene else None
        if r is None:
            if scene and self.run.pending.get("rtcs"):
                self.add(f"## Unit usage (the paper's Figure 5)\n\n*Not measured yet*: "
                         f"`{scene}` on 4 RTCs, a point of `{self._spec('rtcs')}`.")
            return
        plt = _plt()
        fig, ax = plt.subplots(1, 5, figsize=(16, 3.2))
        n, subs = 4, int(r["trav_subunits"])
        def subs_mean(i):     # the sub-units' busy shares of RTC i (one column each)
            v = [_num(r, f"units.per_rtc.{i}.trav_subunits.{j}") for j in range(subs)]
            v = [x for x in v if x is not None]
            return sum(v) / len(v) if v else _num(r, f"units.per_rtc.{i}.trav_subunits")
        per = [[subs_mean(i)] + [_num(r, f"units.per_rtc.{i}.{k}") or 0
                                 for k in ("trav", "list", "int")] for i in range(n)]
        ax[0].bar(range(n), [100 * (p[0] or 0) for p in per])
        ax[0].set_title("(a) traversal sub-units, mean busy", fontsize=9)
        ax[0].set_xlabel("RTC")
        for j, (k, lab) in enumerate((("trav", "traversal"), ("list", "list"),
                                      ("int", "intersection"))):
            ax[1].bar([i + 0.25 * (j - 1) for i in range(n)], [100 * p[j + 1] for p in per],
                      width=0.25, label=lab)
        ax[1].set_title("(b) unit usage per RTC", fontsize=9)
        ax[1].set_xlabel("RTC")
        ax[1].legend(fontsize=7)
        hits = [_num(r, f"cache.{k}.hit_rate") or 0 for k in ("trav", "list", "int")]
        ax[2].bar(["trav", "list", "int"], [100 * h for h in hits])
        ax[2].set_title("(e) cache hit rates", fontsize=9)
        words = [_num(r, f"cache.{k}.memory_words") or 0 for k in ("trav", "list", "int")]
        ax[3].bar(["trav", "list", "int"], [100 * w / max(1, sum(words)) for w in words])
        ax[3].set_title("(f) memory words per cache", fontsize=9)
        chips = int(r["mem_chips"])
        ax[4].bar(range(chips), [100 * (_num(r, f"memory.per_chip.{i}.share") or 0)
                                 for i in range(chips)])
        ax[4].set_title("(h) accesses per SDRAM chip", fontsize=9)
        ax[4].set_xlabel("SDRAM chip")
        for a in ax:
            a.set_ylim(0, 105)
            a.set_ylabel("%")
        figure = self.fig(plt, fig, "results_usage.png")
        body = [[i, self.pcell(p[0]), self.pcell(p[1]), self.pcell(p[2]), self.pcell(p[3])]
                for i, p in enumerate(per)]
        self.add(f"""
## Unit usage (the paper's Figure 5)

`{scene}` on {_chip_name([r])} (4 RTCs, {subs} traversal sub-units each), {rays_text([r], True)},
at {r['width']}×{r['height']} (the `{self._spec('rtcs')}` point): busy share of the cycles of
each unit, the caches' hit rates, each cache's share of the memory words and each SDRAM
chip's share of the memory accesses — panels (a), (b), (e), (f) and (h) of the paper's
Figure 5 (BQD-1). Memory port: {_f(_num(r, 'bus.words_per_cycle'), '{:.3f}')}
words a cycle.

""" + _md_table(["RTC", "traversal sub-units", "traversal", "list", "intersection"], body)
                 + f"\n\n{figure}")

    # -- beyond the paper -----------------------------------------------------------------------
    def _perf(self, r) -> str:
        """A chip row's relative performance, and in brackets its ideal bound and measured
        limit (:func:`_why`)."""
        why = _why(r)
        return self.pcell(_num(r, "relative_performance")) + (f" ({why})" if why else "")

    def beyond(self):
        """What the paper states without a table, or leaves out, from four chip sweeps: where
        the bus saturates (``bus``: 1 to 16 RTCs), RTCs and SDRAM chips together (``sdram``),
        the caches' associativity (``ways``) and the paper preset beside the standard chip
        (``presets``). Each sub-table only when its sweep is in the plan."""
        parts = []
        rows = _ok(self.run.rows.get("bus", []))
        if rows:
            rows.sort(key=lambda r: int(r["rtcs"]))
            base = _num(rows[0], "cycles") if int(rows[0]["rtcs"]) == 1 else None
            body = [[r["rtcs"], f"{int(_num(r, 'cycles')):,}", self.cell(_num(r, "fps"), "{:,.1f}"),
                     _f(base and base / _num(r, "cycles"), "{:.2f}×"),
                     self._perf(r),
                     self.cell(_num(r, "cache.trav.bus.busy"), "{:.3f}"),
                     self.pcell(_num(r, "cache.trav.bus.wait")),
                     self.pcell(_num(r, "cache.int.bus.wait"))] for r in rows]
            parts.append(f"""### Where the round-robin bus saturates

The paper (Section 4.2.2): the bus between the RTCs and the shared caches "will break if too
many RTCs increase the bandwidth requirements to the caches beyond the bus capacity …
with 8 to 16 RTCs". {_cap(_chip_name(rows))}{_preset_text(rows)}, {rays_text(rows, True)} of
{_scenes(rows)} at {_res(rows)}, with {_rtcs(rows)}, {rows[0].get('mem_chips')} SDRAM chips and
{_streams(rows)} (`{self._spec('bus')}`), so that neither memory
nor the chip's output is the limit. *Bus busy*: requests the trav cache's bus carries a cycle;
*waited*: cycles a request waited for it.

""" + _md_table(["RTCs", "cycles", "fps", "speed-up", "relative performance",
                 "trav bus busy", "trav bus waited", "int bus waited"], body)
                         + self.note("bus"))
        rows = _ok(self.run.rows.get("sdram", []))
        if rows:
            rows.sort(key=lambda r: (int(r["rtcs"]), int(r["mem_chips"])))
            base = _num(rows[0], "cycles") if int(rows[0]["rtcs"]) == 1 else None
            body = [[r["rtcs"], r["mem_chips"], f"{int(_num(r, 'cycles')):,}",
                     self.cell(_num(r, "fps"), "{:,.1f}"),
                     _f(base and base / _num(r, "cycles"), "{:.2f}×"),
                     self._perf(r),
                     self.cell(_num(r, "memory.bandwidth_mb_s"), "{:,.0f}")] for r in rows]
            parts.append(f"""### RTCs and SDRAM chips together

n RTCs with n SDRAM chips (the memory's bandwidth grows with the RTCs):
{_chip_name(rows)}, {rays_text(rows, True)} of {_scenes(rows)} at {_res(rows)}
(`{self._spec('sdram')}`). *MB/s*: the memory's bandwidth the frame used.

""" + _md_table(["RTCs", "SDRAM chips", "cycles", "fps", "speed-up", "relative performance",
                 "memory MB/s"], body))
        rows = _ok(self.run.rows.get("ways", []))
        if rows:
            rows.sort(key=lambda r: (_stem(r), int(r["cache_ways"])))
            body = []
            for r in rows:
                one = next((x for x in rows if _stem(x) == _stem(r)
                            and int(x["cache_ways"]) == 1), None)
                b = _num(one, "fps")
                body.append([f"`{_stem(r)}`", r["cache_ways"], f"{int(_num(r, 'cycles')):,}",
                             self.cell(_num(r, "fps"), "{:,.1f}"),
                             _f(b and _num(r, "fps") / b, "{:.3f}×"),
                             *[self.pcell(_num(r, f"cache.{k}.hit_rate"))
                               for k in ("trav", "list", "int")]])
            parts.append(f"""### The caches' associativity

The paper's caches are direct-mapped. The same three shared caches 2- and 4-way
set-associative (`cache_ways`): {_chip_name(rows)}, {_rtcs(rows)}, {rays_text(rows, True)} at
{_res(rows)} (`{self._spec('ways')}`); fps relative to the direct-mapped caches.

""" + _md_table(["scene", "ways", "cycles", "fps", "× direct-mapped", "trav hits", "list hits",
                 "int hits"], body))
        rows = _ok(self.run.rows.get("presets", []))
        if rows:
            rows.sort(key=lambda r: (_stem(r), _chip_name([r])))
            body = []
            for r in rows:
                base = next((x for x in rows if _stem(x) == _stem(r)
                             and _chip_name([x]) == "the paper preset"), None)
                body.append([f"`{_stem(r)}`", _chip_name([r])[4:], f"{int(_num(r, 'cycles')):,}",
                             self.cell(_num(r, "fps"), "{:,.1f}"),
                             _f(base and _num(base, "cycles") / _num(r, "cycles"), "{:.2f}×"),
                             self._perf(r)])
            parts.append(f"""### The paper's chip beside ours

The paper preset (the paper's cost: 192 FP units; `docs/paper-preset.md`) and the standard
chip (a unit per operation in the slaves, the watertight triangle test), {_rtcs(rows)},
{rays_text(rows, True)} at {_res(rows)} (`{self._spec('presets')}`). *× paper preset*: the
paper preset's cycles over the chip's for the same scene; in brackets the kind of unit the
ideal is bound by and the frame's measured limit.

""" + _md_table(["scene", "chip", "cycles", "fps", "× paper preset", "relative performance"],
                body))
        if parts:
            self.add("## Beyond the paper\n\n" + "\n\n".join(p.strip("\n") for p in parts))

    def trends(self):
        """The paper's findings, each against our figures: **holds** where our ratio is within
        :data:`HOLDS` of the paper's, **differs** otherwise."""
        items = []

        def verdict(ours, paper):
            return ("**holds**" if abs(ours / paper - 1) <= HOLDS else "**differs**")
        every = self.run.rows.get("rtcs", [])
        main = _main_frame(every)
        rows = _at(every, main)

        def pair(ours, counts=(1, 4)):
            """(the scene's rows with ``counts`` RTCs, " at WxH" when not the page's frame):
            the page's frame where all ran, else a smaller frame where all did."""
            for fr in _scene_frames(every, ours, main):
                p = [_one(_at(every, fr), scene=ours, rtcs=n) for n in counts]
                if all(p):
                    return p, ("" if fr == main else f" at {fr[0]}×{fr[1]}")
            return None, ""
        sp = []
        for ours, cls in self.plan.classes.items():
            p, at = pair(ours)
            f = [_num(x, "fps") for x in p] if p else [None]
            if all(f) and cls in PAPER_FPS:
                paper = PAPER_FPS[cls][2] / PAPER_FPS[cls][0]
                v = verdict(f[1] / f[0], paper)
                lim = p[1]
                why = (f"; 4 RTCs {lim['limiter.limit']}" if "differs" in v
                       and lim.get("limiter.limit") else "")
                sp.append(f"`{ours}`{at} {f[1] / f[0]:.2f}× (paper, {cls}: {paper:.2f}×, "
                          f"{v}{why})")
        if sp:
            items.append(f"*Performance scales almost linearly with the RTCs, except where "
                         f"memory bounds it* (Table 2, 1 to 4 RTCs). Ours, "
                         f"{rays_text(rows, True)}, at {_res(rows)}: " + "; ".join(sp) + ".")
        rel = []
        for ours, cls in self.plan.classes.items():
            p, at = pair(ours, (4,))
            p = p[0] if p else None
            x = _num(p, "relative_performance")
            if x and cls in PAPER_REL:
                v = verdict(x, PAPER_REL[cls][2])
                why = (f"; {p['limiter.limit']}" if "differs" in v and p.get("limiter.limit")
                       else "")
                rel.append(f"`{ours}`{at} {100 * x:.0f} % (paper, {cls}: "
                           f"{100 * PAPER_REL[cls][2]:.0f} %, {v}{why})")
        if rel:
            items.append("*The chip reaches most of the performance its operations allow: 59–80 "
                         "% relative performance, less where memory bounds it* (Table 4, 4 "
                         f"RTCs). Ours, {rays_text(rows, True)}, at {_res(rows)}: "
                         + "; ".join(rel) + ".")
        _, chip = self._chip_office()
        all_row = chip_cases(chip).get(CASES[3][0]) if chip else None
        if all_row:
            hits = []
            for k in ("trav", "list", "int"):
                x = _num(all_row, f"cache.{k}.hit_rate")
                if x:
                    hits.append(f"{k}-cache {100 * x:.1f} % (paper {100 * PAPER_T6[k][0]:.1f} %, "
                                f"{verdict(x, PAPER_T6[k][0])})")
            if hits:
                items.append("*Small caches hit most accesses* (Table 6, the office with all its "
                             f"rays, no oversampling; the ratio of hit rates). Ours on the chip, "
                             f"`{_stem(all_row)}`, 4 RTCs, {_res([all_row])}: "
                             + "; ".join(hits) + ".")
        t3 = self.run.rows.get("intcache", [])
        if t3:
            g = {(int(r["int_cache_kb"]), int(r["mem_chips"])): _num(r, "fps")
                 for r in t3 if r.get("status") == "ok"}
            kb = sorted({k for k, _ in g})
            parts = []
            if len(kb) > 1 and g.get((kb[0], 4)) and g.get((kb[-1], 4)):   # two sizes measured
                x = g[(kb[-1], 4)] / g[(kb[0], 4)]
                p = PAPER_T3.get((kb[-1], 4), 0) / PAPER_T3.get((kb[0], 4), 1)
                if p:                   # the paper measured these sizes
                    parts.append(f"a {kb[-1] // kb[0]}× larger int-cache ({kb[0]} → {kb[-1]} "
                                 f"KB) gives {x:.2f}× the fps (paper {p:.2f}×): {verdict(x, p)}")
            if g.get((kb[0], 4)) and g.get((kb[0], 8)) and (kb[0], 8) in PAPER_T3:
                x = g[(kb[0], 8)] / g[(kb[0], 4)]
                p = PAPER_T3[(kb[0], 8)] / PAPER_T3[(kb[0], 4)]
                parts.append(f"twice the bandwidth gives {x:.2f}× (paper {p:.2f}×): "
                             f"{verdict(x, p)}")
            if parts:
                items.append("*Triangle fetches bound a complex scene: more int-cache and more "
                             "bandwidth both help* (Table 3). Ours: " + "; ".join(parts) + ".")
        rk = self.run.rows.get("raykinds", [])
        paper_rc = 4.5 / 4.9        # the paper's cost per ray, all rays against eye rays
        if rk:
            base = _one(rk, reflect_depth=0, shadows=False, oversampling=1)
            allr = _one(rk, reflect_depth=3, shadows=True, oversampling=1)
            found = chip_cases(self._chip_office()[1])
            ca, cd = found.get(CASES[0][0]), found.get(CASES[3][0])
            if ca and cd:          # measured on the chip
                rr, cc = _grown(ca, cd)
                v = verdict(cc / rr, paper_rc)
                why = (f" (limits measured: eye rays {ca['limiter.limit']}, all rays "
                       f"{cd['limiter.limit']})" if "differs" in v and ca.get("limiter.limit")
                       and cd.get("limiter.limit") else "")
                items.append(f"*Cost is about linear in the rays, whatever their kind* (Table 5; "
                             f"paper: 4.9× the rays for 4.5× the cost, {paper_rc:.2f} a ray). "
                             f"Ours on the chip: {rr:.2f}× the rays for {cc:.2f}× the cycles, "
                             f"{cc / rr:.2f} a ray — {v}{why}.")
            elif base and allr:
                rr = _num(allr, "rays_total") / _num(base, "rays_total")
                cc = (_ideal_cycles(_num(allr, "counters.trav_ops"),
                                    _num(allr, "counters.int_ops")) /
                      _ideal_cycles(_num(base, "counters.trav_ops"),
                                    _num(base, "counters.int_ops")))
                items.append(f"*Cost is about linear in the rays, whatever their kind* (Table 5; "
                             f"paper: 4.9× the rays for 4.5× the cost, {paper_rc:.2f} a ray). "
                             f"Ours (an estimate: the golden model's ideal cycles): {rr:.2f}× "
                             f"the rays for {cc:.2f}× the cost, {cc / rr:.2f} a ray — "
                             f"{verdict(cc / rr, paper_rc)}.")
        rf = [r for r in self.run.rows.get("refraction", []) if r.get("status") == "ok"]
        ra = next((r for r in rf if int(r.get("reflect_depth") or 0) == 0), None)
        rc = next((r for r in rf if _true(r.get("refraction"))), None)
        if ra and rc:
            rr, cc = _grown(ra, rc)
            items.append(f"*... also for refracted rays* (Section 5.3, not shown in the paper; "
                         f"its Table 5: {paper_rc:.2f} a ray). Ours on the chip, "
                         f"`{_stem(rc)}` with glass: {rr:.2f}× the rays for {cc:.2f}× the "
                         f"cycles, {cc / rr:.2f} a ray — {verdict(cc / rr, paper_rc)}.")
        eye_row, os_row = _os_rows(self._chip_office()[1])
        if eye_row and os_row:
            x = float(os_row["cycles"]) / float(eye_row["cycles"])
            d = [100 * (_num(os_row, f"cache.{k}.hit_rate") - _num(eye_row, f"cache.{k}.hit_rate"))
                 for k in ("trav", "list", "int")]
            items.append(f"*4× oversampling costs less than 4×, the caches hitting more* "
                         f"(Tables 5, 6; paper 3.6×, hit rates +6.9/+6.0/+1.7 points). Ours on "
                         f"the chip: {x:.2f}× the cycles — {verdict(x, 3.6)}; hit rates "
                         f"{d[0]:+.1f}/{d[1]:+.1f}/{d[2]:+.1f} points.")
        source, runs = self._thread_runs()
        if runs:
            sp = {r["threads"]: r["speedup"] for r in runs}
            got = "; ".join(f"{n} threads {sp[n]:.1f}× (paper {PAPER_THREADS[n]:.1f}×, "
                            f"{verdict(sp[n], PAPER_THREADS[n])})"
                            for n in (8, 16) if sp.get(n) and n in PAPER_THREADS)
            where = ("the chip with its caches and SDRAM" if source == "chip" else
                     "one RTC, ideal memory")
            rel32 = next((r["rel"] for r in runs if r["threads"] == 32 and r["rel"]), None)
            if rel32:
                mid = sum(PAPER_THREADS_32) / 2
                got += ("; " if got else "") + (
                    f"32 threads {100 * rel32:.0f} % relative performance (paper 80–90 %, "
                    f"against its middle {100 * mid:.0f} %: {verdict(rel32, mid)})")
            top = runs[-1]
            if got and "differs" in got and top.get("limit"):
                got += f"; what limits {top['threads']} threads: {top['limit']}"
            if got:
                items.append(f"*Multi-threading hides memory latency*. Ours ({where}): {got}.")
        bus = {int(r["rtcs"]): r for r in _ok(self.run.rows.get("bus", []))}
        if 8 in bus and 16 in bus:
            x = _num(bus[8], "cycles") / _num(bus[16], "cycles")
            v = "**holds**" if x / 2 < 1 - HOLDS else "**differs**"
            b = bus[16]
            why = (f"; 16 RTCs {b['limiter.limit']}" if "differs" in v
                   and b.get("limiter.limit") else "")
            items.append(
                "*The round-robin bus breaks with 8 to 16 RTCs* (Section 4.2.2; *breaks*: 8 to 16 "
                f"RTCs gain less than {2 * (1 - HOLDS):.1f}×, linear less {100 * HOLDS:.0f} %). "
                f"Ours ({_chip_name([b])}, {_scenes([b])}, {rays_text([b], True)}): 16 RTCs "
                f"{x:.2f}× the 8 RTCs' speed, the trav cache's bus "
                f"{_f(_num(b, 'cache.trav.bus.busy'), '{:.2f}')} requests a cycle, waited "
                f"{_pct(_num(b, 'cache.trav.bus.wait'))} — {v}{why}.")
        if items:
            self.add("## Which of the paper's trends hold\n\nComputed from the tables above. "
                     f"A trend **holds** where our ratio is within ±{100 * HOLDS:.0f} % of the "
                     "paper's (ours / paper between "
                     f"{1 - HOLDS:.2f} and {1 + HOLDS:.2f}), and **differs** otherwise:\n\n"
                     + "\n".join(f"* {i}" for i in items))

    def scaling(self):
        s = self.run.scaling
        if not s:
            return
        r1, r2 = s["runs"][0], s["runs"][1]
        speed = r1["wall_seconds"] / r2["wall_seconds"]
        chip = list({r["key"]: float(r["job_seconds"]) for rows in self.run.rows.values()
                     for r in rows if r.get("status") == "ok" and r.get("backend") == "chip"
                     and r.get("job_seconds") not in (None, "")}.values())
        body = [[f"{r['workers']}", f"{r['wall_seconds']:.1f} s", f"{r['job_seconds']:.1f} s",
                 f"{r['load_before']:.2f}"] for r in s["runs"]]
        bound = []
        if chip:
            tot, top = sum(chip), max(chip)
            for n in (1, 2, 8, 32, len(chip)):
                secs = max(top, tot / n)
                bound.append([n, f"{secs / 3600:.1f} h" if secs >= 3600 else
                              f"{secs / 60:.0f} min"])
        self.add(f"""
## Sweeps on more workers

**Measured**: the `{s['spec']}` spec ({s['points']} golden-model points), each run with an
empty result cache on a local cluster of 1 and of 2 workers (one process and one core each;
times include starting the cluster; load average of the machine just before):

""" + _md_table(["workers", "wall", "sum of the jobs' own times", "load average before"], body)
                 + f"""

Two workers are **{speed:.2f}×** as fast as one on this 2-core machine (the jobs are
independent; what is lost goes to starting workers and to the two jobs sharing memory
bandwidth and the machine with other work).

**This page's chip frames on a cluster** (arithmetic on the measured job times, not a
measurement): every frame is an independent job of one core, so {len(chip)} frames whose
own times sum to {_f(chip and sum(chip) / 3600, '{:.1f}')} h, the longest
{_f(chip and max(chip) / 60, '{:.0f}')} min, need at least the larger of the longest job and
the sum over the workers, plus the Verilator builds beforehand (one per configuration, in
parallel; {_build_text()}). A worker runs whole frames: beyond {len(chip)} workers nothing is
gained. `docs/sweep.md` says how to run the plan on a SLURM cluster.

""" + (_md_table(["workers", "at least"], bound) if bound else "(no chip points measured)"))

    def cost(self):
        """What each sweep's points cost when they were computed (job_seconds)."""
        body, once = [], {}
        for k, rows in self.run.rows.items():
            js = [float(r["job_seconds"]) for r in rows if r.get("job_seconds") not in (None, "")]
            once.update((r["key"], float(r["job_seconds"])) for r in rows
                        if r.get("job_seconds") not in (None, ""))
            spec = self.run.specs.get(k)
            body.append([f"`{self._spec(k)}`", spec.backend if spec else "", len(rows),
                         len(self.run.pending.get(k, [])), f"{sum(js) / 60:.1f} min",
                         f"{max(js, default=0) / 60:.1f} min"])
        total = sum(once.values())
        t = self.run.threads
        if t:
            ts = sum(r["wall_s"] for r in t["runs"])
            total += ts
            body.append(["threads bench", "one RTC", len(t["runs"]), 0, f"{ts / 60:.1f} min",
                         f"{max(r['wall_s'] for r in t['runs']) / 60:.1f} min"])
        self.add(f"""
## What this page costs

Each sweep point's own time when it was computed (`job_seconds`: loading the scene, the
kd-tree from its cache, the frame and its check; one worker process each), and the threads
bench's runs (without its builds). A point that several sweeps share runs once: from an empty result cache the page takes about the sum over its
{len(once)} distinct points, **{total / 3600:.1f} hours of job time**, divided among the
workers, plus the Verilator builds (one per chip configuration; {_build_text()}) and the 1-
and 2-worker timing.

""" + _md_table(["sweep", "backend", "points measured", "not run", "sum of job times",
                 "longest job"], body))
        pend = [(k, v) for k, v in self.run.pending.items() if v]
        if pend:
            self.add("\n**Points not run yet** (by sweep):\n\n" + "\n".join(
                f"- `{self._spec(k)}`: " + "; ".join(v) for k, v in pend) + "\n")

    def pending_text(self) -> str:
        n = sum(len(v) for v in self.run.pending.values())
        if not n:
            return ""
        done = sum(len(v) for v in self.run.rows.values())
        them, show, are, it = ((f"The {n} points", "show", "are", "them") if n > 1 else
                               ("The point", "shows", "is", "it"))
        return (f"\n\n**Not complete: {done} of {done + n} points measured.** {them} not run "
                f"yet {show} as — (or {are} absent from a plot); the last section lists {it}. "
                f"Nothing on this page stands in for {it}.")

    def render(self, total_seconds: float, load: tuple) -> str:
        head = f"""# {self.plan.title}

<!-- generated by `saarcor results` (saarcor/results.py) from {os.path.relpath(self.plan.path, ROOT)}; edit those, not this page -->

The paper's Section 5 measurements (Tables 1–6, Figures 1, 3 and 5, the thread speed-up, and
the refracted rays it did not show) on our chip and golden model, each table beside the
paper's figures, then what the paper did not measure (the bus with up to 16 RTCs, RTCs and
SDRAM chips together, the caches' associativity, the paper's chip beside ours), which of the
paper's trends hold, and what the page costs. Regenerate with `make results` (or
`saarcor results`; `--help` for options): every sweep point is kept, one JSON file each, in
`{os.path.relpath(CACHE, ROOT)}` (in the repository), and a run computes only the points
whose file is missing or ran other code (the key hashes the configuration, the scene's files,
the frame and the sources of `rtl/`, `model/`, `tb/` and `saarcor/` but this page's writer,
`saarcor/results.py`); the chip's Verilator
binaries are built once per configuration.{self.pending_text()}

**What is measured how.** Every *chip* figure is a frame through the whole chip (RGS, RTCs,
caches, bus, SDRAM model) in Verilator, with the rays its sweep asks for — eye rays, and the
shadow and reflection rays the RGS slaves make from their hits — every ray checked bit for
bit against the golden model; each table says which rays its chip columns hold. The *golden
model's* columns are its operation counts (the ops the chip's units perform: the chip's
counters equal the model's on every frame checked). Estimates are marked as such.
{self.plan.resolution_note}

Code: commit {self.commit or _commit()}, code hash `{sw.code_hash()}` (the sources of `rtl/`,
`model/`, `tb/` and `saarcor/` but `saarcor/results.py`, every point ran: its cache key). {self.run_text(total_seconds, load)}
"""
        return head + "\n" + "\n".join(self.parts)

    def run_text(self, total_seconds: float, load: tuple) -> str:
        """What this run did: how many points it computed, in what wall time and load."""
        points = sum(len(v) for v in self.run.rows.values())
        where = (f"(load average {load[0]:.2f} / {load[1]:.2f} before / after, on a 2-core "
                 f"machine shared with other work)")
        own = "Each point's own time, when it was computed, is in the last section."
        if not self.run.computed:
            return (f"This run computed no point: it read all {points} from the kept files "
                    f"in {total_seconds:.0f} s {where}. {own}")
        return (f"This run: {total_seconds / 60:.1f} minutes of wall time {where}, "
                f"{self.run.computed} of its {points} sweep points computed. {own}")


def write_page(plan: Plan, run: Run, page: Path, img: Path, total_seconds: float,
               load: tuple, commit: str = "") -> Writer:
    w = Writer(plan, run, img, page)
    w.commit = commit
    w.scenes()
    w.table2()
    w.table3()
    w.table5()
    w.refraction()
    w.table6()
    w.threads()
    w.figure1()
    w.figure3()
    w.usage()
    w.beyond()
    w.trends()
    w.scaling()
    w.cost()
    page.parent.mkdir(parents=True, exist_ok=True)
    page.write_text(w.render(total_seconds, load))
    return w


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="saarcor results",
        description="Regenerate docs/results.md (the paper's Section 5 tables beside ours) "
                    "from the sweeps of a plan, with matplotlib plots. Exit status 1 when a "
                    "sweep point failed or a table has cells without a value.",
        epilog="The plan names a sweep spec per table: scenes/sweeps/results/plan.toml.")
    ap.add_argument("--plan", default=str(PLAN), metavar="FILE",
                    help=f"the plan (default {PLAN.relative_to(ROOT)})")
    ap.add_argument("--out", default=str(ROOT / "docs"), metavar="DIR",
                    help="where the page goes: OUT/results.md (default docs)")
    ap.add_argument("--img", metavar="DIR", help="directory of the plots (default OUT/img)")
    ap.add_argument("--work", default="build/results", metavar="DIR",
                    help="the sweeps' tables and the threads bench (default build/results)")
    ap.add_argument("--cache", default=str(CACHE.relative_to(ROOT)), metavar="DIR",
                    help="per-point result cache (`saarcor sweep --cache DIR` fills it too; "
                         f"default {CACHE.relative_to(ROOT)}, kept in the repository)")
    ap.add_argument("--cached", action="store_true",
                    help="compute nothing: write the page from the points in the cache, the "
                         "others shown as not run and listed under the page's cost (the "
                         "threads bench and the scaling timing as kept in WORK)")
    ap.add_argument("--workers", type=int, default=2, metavar="N",
                    help="Dask workers: local processes, or batch jobs with --cluster "
                         "(default 2)")
    ap.add_argument("--cluster", default="local", metavar="KIND",
                    help="where the points run, as `saarcor sweep --cluster`: local (default), "
                         "slurm, pbs, sge, lsf, htcondor (dask-jobqueue) or module:Class; the "
                         "threads bench and the scaling timing always run here")
    ap.add_argument("--cluster-option", action="append", default=[], metavar="KEY=VALUE",
                    help="a keyword argument of the cluster class, e.g. walltime=12:00:00 "
                         "(repeatable; docs/sweep.md)")
    ap.add_argument("--scheduler", metavar="ADDR",
                    help="use a running Dask scheduler (tcp://host:8786) instead of starting "
                         "a cluster")
    add_kd_cache_arg(ap)
    ap.add_argument("--skip-threads", action="store_true",
                    help="no threads bench: the page shows the one kept in WORK/threads.json "
                         "by an earlier run, if any")
    ap.add_argument("--skip-scaling", action="store_true",
                    help="no 1- and 2-worker timing of the scaling spec: the page shows the "
                         "one kept in WORK/scaling.json by an earlier run, if any")
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if args.workers < 1:
        raise SystemExit("results: --workers must be >= 1")
    t0 = time.perf_counter()
    load0 = os.getloadavg()[0]
    commit = _commit()          # before the page and its plots change the checkout
    try:
        plan = load_plan(args.plan)
        page = Path(args.out) / "results.md"
        run = run_plan(plan, workers=args.workers, cache=Path(args.cache),
                       out_dir=Path(args.work), threads=not args.skip_threads,
                       scaling=not args.skip_scaling, kd_cache=args.kd_cache,
                       compute=not args.cached, cluster_kind=args.cluster,
                       cluster_options=tuple(args.cluster_option), scheduler=args.scheduler)
    except (ResultsError, sw.SpecError) as e:
        raise SystemExit(f"results: {e}")
    w = write_page(plan, run, page, Path(args.img) if args.img else page.parent / "img",
                   time.perf_counter() - t0, (load0, os.getloadavg()[0]), commit)
    print(f"results: wrote {page} and {len(w.figures)} plots in "
          f"{(time.perf_counter() - t0) / 60:.1f} min; {run.computed} point(s) computed, "
          f"{run.failed} failed point(s), "
          f"{w.missing} empty cell(s)")
    return 1 if run.failed or w.missing else 0


if __name__ == "__main__":
    sys.exit(main())
