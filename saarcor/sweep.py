"""Design-space sweeps on Dask: every (configuration, scene, resolution) point of a TOML spec
as one independent job, results cached per point and gathered into one table.

A spec (format: ``docs/sweep.md``; examples in ``scenes/sweeps/``) names a ``backend``
(``chip``: a frame through the whole chip in Verilator — eye rays and, as the configuration's
``shadows`` and ``reflect_depth`` ask, the slaves' shadow and reflection rays — every ray checked, the
figures of ``make sim``'s ``stats.json``; ``model``: the golden model's full render, its
``RenderResult.stats``), the scenes, the resolutions and the configurations: a ``[grid]`` of
:class:`~model.config.Config` fields, each a list of values (cartesian product), and explicit
``[[point]]`` tables, both on top of the fixed fields of ``[config]``.

Each point runs on a ``dask.distributed`` worker: a local cluster by default (``--workers``
processes of one thread), a running scheduler (``--scheduler``) or any cluster class, such as
dask-jobqueue's SLURM and PBS clusters (``--cluster``). A point's result is stored as one JSON
file under the cache directory, named by a hash of the full configuration, the scene's
content (with the meshes and textures it reads), the resolution, the backend and the code
(``rtl/``, ``model/``, ``tb/``): a second run, or a run resumed after an interruption,
computes only what is missing. Failed points are not stored and are retried by the next run.
For the chip backend each distinct Verilator binary is built by one job before that
configuration's points start (``tb.harness.verilator.build`` caches binaries in ``build/verilator/``
under a file lock).

Outputs in ``--out`` (default ``build/sweep/<spec name>``): ``results.csv`` (and
``results.parquet`` when pyarrow is installed), one row per point: scene, resolution,
backend, every Config field, ``status`` (ok, mismatch, error), ``error``, ``key`` (the cache
file's name), ``job_seconds`` and every scalar of the stats dict (nested names joined with
dots: ``cache.trav.hit_rate``, ``memory.per_chip.0.words``); ``errors.txt``: the traceback of
every failed point.

CLI: ``saarcor sweep SPEC.toml [--out DIR] [--scheduler ADDR] [--workers N]
[--max-cycles N] ...`` (``--help``).
"""
from __future__ import annotations

import argparse
import csv
import dataclasses
import difflib
import functools
import hashlib
import importlib
import importlib.util
import io
import itertools
import json
import re
import sys
import time
import tomllib
import traceback
import uuid
from dataclasses import dataclass
from pathlib import Path

from model.config import PRESETS, Config, ConfigError
from model.fp import FPFormat
from saarcor.args import add_kd_cache_arg, parse_fmt, parse_res

__all__ = ["SpecError", "Point", "Spec", "load_spec", "code_hash", "point_key", "run_point",
           "build_chip", "flatten", "rows_table", "write_table", "run_sweep", "main"]

ROOT = Path(__file__).resolve().parents[1]
BACKENDS = ("chip", "model")
SPEC_KEYS = ("name", "backend", "scenes", "resolutions", "preset", "config", "grid", "point",
             "max_cycles", "skip_invalid", "mem_words")
POINT_KEYS = ("scenes", "resolutions")
CODE_DIRS = ("rtl", "model", "tb", "saarcor")
CODE_SUFFIXES = (".py", ".cpp", ".h", ".v", ".sv")
# sources no point's result depends on: the page writer reads the tables, computes none
CODE_EXCLUDE = ("saarcor/results.py",)
CACHE_VERSION = 1
FIELDS = {f.name: f for f in dataclasses.fields(Config)}
DEFAULT_MAX_CYCLES = 100_000_000
# a few cluster classes by short name (dask-jobqueue: pip install dask-jobqueue)
CLUSTERS = {"local": "distributed:LocalCluster",
            "slurm": "dask_jobqueue:SLURMCluster", "pbs": "dask_jobqueue:PBSCluster",
            "sge": "dask_jobqueue:SGECluster", "lsf": "dask_jobqueue:LSFCluster",
            "htcondor": "dask_jobqueue:HTCondorCluster"}


class SpecError(ValueError):
    """A sweep spec that cannot be run; the message names the file, the key and the fix."""


# --------------------------------------------------------------------------------------------
# the spec
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Point:
    """One job: a configuration (``Config.to_dict()``, fmt as ``"E8M23"``) on a scene at a
    resolution."""
    config: dict
    scene: str            # as written in the spec
    scene_path: str       # resolved (absolute)
    width: int
    height: int
    backend: str

    def cfg(self) -> Config:
        return config_of(self.config)

    def label(self) -> str:
        return f"{Path(self.scene).stem} {self.width}x{self.height}"


@dataclass
class Spec:
    path: Path
    name: str
    backend: str
    points: list[Point]
    max_cycles: int | None = None
    skipped: list[str] = dataclasses.field(default_factory=list)   # invalid grid combinations
    mem_words: int | None = None     # chip: memory words of every binary, at least


def config_of(d: dict) -> Config:
    """A :class:`Config` from a field dict whose ``fmt`` is ``"E<e>M<m>"`` or a table."""
    d = dict(d)
    if "fmt" in d:
        d["fmt"] = fmt_of(d["fmt"])
    return Config(**d)


def config_dict(cfg: Config) -> dict:
    """``cfg.to_dict()`` with ``fmt`` as ``"E<e>M<m>"``: one flat value per field."""
    d = cfg.to_dict()
    d["fmt"] = str(cfg.fmt)
    return d


def fmt_of(v) -> FPFormat:
    """A spec's ``fmt`` value: ``"E8M16"`` (:func:`saarcor.args.parse_fmt`) or a table
    ``{exp_bits = 8, frac_bits = 16}``."""
    if isinstance(v, FPFormat):
        return v
    if isinstance(v, dict):
        extra = set(v) - {"exp_bits", "frac_bits"}
        if extra:
            raise ConfigError(f"fmt table: unknown keys {sorted(extra)}; use exp_bits, frac_bits")
        return FPFormat(int(v.get("exp_bits", 8)), int(v.get("frac_bits", 23)))
    try:
        return parse_fmt(str(v))
    except ConfigError:
        raise ConfigError(f"fmt {v!r}: write the format as E<exp>M<frac>, e.g. \"E8M23\", or "
                          "as a table {exp_bits = 8, frac_bits = 23}") from None


def _check_field(name: str, value, where: str):
    """``value`` checked against Config field ``name``'s type; the value to use."""
    if name not in FIELDS:
        near = difflib.get_close_matches(name, FIELDS, n=3)
        hint = f" (did you mean {', '.join(near)}?)" if near else ""
        raise SpecError(f"{where}: unknown Config field {name!r}{hint}; the fields are those "
                        f"of model/config.py Config: {', '.join(FIELDS)}")
    if name == "fmt":
        try:
            return str(fmt_of(value))
        except (ConfigError, ValueError, TypeError) as e:
            raise SpecError(f"{where}: {e}") from None
    want = type(getattr(Config(), name))
    if want is bool:
        ok = isinstance(value, bool)
    elif want is float:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    elif want is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    else:
        ok = isinstance(value, want)
    if not ok:
        raise SpecError(f"{where}: {name} = {value!r} must be a{'n' if want is int else ''} "
                        f"{want.__name__}")
    return float(value) if want is float else value


def parse_resolution(text, where: str) -> tuple[int, int]:
    try:
        return parse_res(str(text))
    except argparse.ArgumentTypeError:
        raise SpecError(f"{where}: resolution {text!r}: write \"WxH\" with positive sizes, "
                        "e.g. \"32x24\"") from None


def _str_list(v, key: str, where: str) -> list[str]:
    if isinstance(v, str):
        v = [v]
    if not isinstance(v, list) or not v or not all(isinstance(x, str) for x in v):
        raise SpecError(f"{where}: {key} must be a non-empty list of strings, e.g. "
                        + ('["../cornell.toml"]' if key == "scenes" else '["32x24"]'))
    return v


def load_spec(path: str | Path) -> Spec:
    """Read and check a sweep spec; raise :class:`SpecError` naming what to fix."""
    path = Path(path)
    if not path.is_file():
        raise SpecError(f"spec {str(path)!r} not found (examples: scenes/sweeps/*.toml)")
    try:
        doc = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise SpecError(f"{path}: TOML syntax error: {e}") from None
    where = str(path)
    unknown = sorted(set(doc) - set(SPEC_KEYS))
    if unknown:
        raise SpecError(f"{where}: unknown key(s) {', '.join(unknown)}; a spec has "
                        f"{', '.join(SPEC_KEYS)} (docs/sweep.md)")
    backend = doc.get("backend")
    if backend not in BACKENDS:
        raise SpecError(f"{where}: backend = {backend!r}: write backend = \"chip\" (a frame "
                        "through the whole chip in Verilator) or \"model\" (the golden model)")
    name = doc.get("name", path.stem)
    if not isinstance(name, str) or not re.fullmatch(r"[\w.-]+", name):
        raise SpecError(f"{where}: name = {name!r}: letters, digits, '.', '-', '_' only")
    max_cycles = doc.get("max_cycles")
    if max_cycles is not None and (not isinstance(max_cycles, int) or max_cycles < 1):
        raise SpecError(f"{where}: max_cycles = {max_cycles!r} must be a positive integer")
    mem_words = doc.get("mem_words")
    if mem_words is not None and (not isinstance(mem_words, int) or mem_words < 1
                                  or mem_words & (mem_words - 1)):
        raise SpecError(f"{where}: mem_words = {mem_words!r} must be a power of two (the "
                        "memory words every chip binary holds, e.g. 67108864 = 2**26)")
    skip_invalid = doc.get("skip_invalid", False)
    if not isinstance(skip_invalid, bool):
        raise SpecError(f"{where}: skip_invalid must be true or false")
    if "scenes" not in doc or "resolutions" not in doc:
        raise SpecError(f"{where}: give scenes = [...] (scene files, relative to the spec) and "
                        "resolutions = [\"WxH\", ...]")
    scenes = _str_list(doc["scenes"], "scenes", where)
    resolutions = [parse_resolution(r, where) for r in _str_list(doc["resolutions"],
                                                                 "resolutions", where)]

    def table(key):
        v = doc.get(key, {})
        if not isinstance(v, dict):
            raise SpecError(f"{where}: [{key}] must be a table of Config fields")
        return v

    preset = doc.get("preset", "standard")
    if preset not in PRESETS:
        raise SpecError(f"{where}: preset = {preset!r}: choose one of {', '.join(PRESETS)} "
                        "(model/config.py PRESETS; [config] applies on top of it)")
    base = {**PRESETS[preset],
            **{k: _check_field(k, v, f"{where} [config]") for k, v in table("config").items()}}
    grid = {}
    for k, vals in table("grid").items():
        vals = vals if isinstance(vals, list) else [vals]
        if not vals:
            raise SpecError(f"{where} [grid]: {k} = [] has no values; give at least one")
        grid[k] = [_check_field(k, v, f"{where} [grid]") for v in vals]
    explicit = doc.get("point", [])
    if not isinstance(explicit, list) or not all(isinstance(p, dict) for p in explicit):
        raise SpecError(f"{where}: point must be [[point]] tables")

    # (overrides, scenes, resolutions, from the grid?) in spec order
    combos = []
    if grid or not explicit:
        for values in itertools.product(*grid.values()):
            combos.append(({**base, **dict(zip(grid, values))}, scenes, resolutions, True))
    for i, p in enumerate(explicit):
        w = f"{where} [[point]] {i + 1}"
        fields = {k: _check_field(k, v, w) for k, v in p.items() if k not in POINT_KEYS}
        sc = _str_list(p["scenes"], "scenes", w) if "scenes" in p else scenes
        rs = ([parse_resolution(r, w) for r in _str_list(p["resolutions"], "resolutions", w)]
              if "resolutions" in p else resolutions)
        combos.append(({**base, **fields}, sc, rs, False))

    points, seen, skipped = [], set(), []
    for fields, sc, rs, from_grid in combos:
        try:
            cfg = config_of(fields)
        except (ConfigError, ValueError) as e:
            desc = ", ".join(f"{k}={v}" for k, v in fields.items()) or "the defaults"
            if from_grid and skip_invalid:
                skipped.append(f"{desc}: {e}")
                continue
            raise SpecError(f"{where}: the configuration {desc} is invalid: {e}"
                            + ("; drop it from the grid, or set skip_invalid = true to skip "
                               "invalid grid combinations" if from_grid else "")) from None
        for s in sc:
            sp = Path(s).expanduser()
            sp = sp if sp.is_absolute() else path.parent / sp
            for w_, h_ in rs:
                pt = Point(config_dict(cfg), s, str(sp.resolve()), w_, h_, backend)
                ident = json.dumps([pt.config, pt.scene_path, w_, h_], sort_keys=True)
                if ident not in seen:
                    seen.add(ident)
                    points.append(pt)
    if not points:
        raise SpecError(f"{where}: no valid configuration left "
                        f"({len(skipped)} skipped as invalid: {skipped[:3]})")
    return Spec(path, name, backend, points, max_cycles, skipped, mem_words)


# --------------------------------------------------------------------------------------------
# cache keys
# --------------------------------------------------------------------------------------------

@functools.lru_cache(maxsize=None)
def code_hash(root: str = str(ROOT)) -> str:
    """Hash of the sources a result depends on: every file of ``rtl/``, ``model/``, ``tb/``,
    ``saarcor/`` with a source suffix (path and content)."""
    h = hashlib.sha256()
    for d in CODE_DIRS:
        for p in sorted(Path(root, d).rglob("*")):
            if (p.suffix in CODE_SUFFIXES and p.is_file() and "__pycache__" not in p.parts
                    and p.relative_to(root).as_posix() not in CODE_EXCLUDE):
                h.update(p.relative_to(root).as_posix().encode() + b"\0")
                h.update(p.read_bytes())
    return h.hexdigest()[:16]


def _referenced_files(doc, base: Path, depth: int = 0):
    """Mesh, texture and base-scene files a scene TOML reads (keys ``mesh``, ``texture``,
    ``base``; a base scene's own files too)."""
    if isinstance(doc, dict):
        for k, v in doc.items():
            if k in ("mesh", "texture") and isinstance(v, str):
                yield base / v
            elif k == "base" and isinstance(v, str) and depth == 0:
                f = base / v
                yield f
                try:
                    yield from _referenced_files(tomllib.loads(f.read_text()), f.parent, 1)
                except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError):
                    pass
            else:
                yield from _referenced_files(v, base, depth)
    elif isinstance(doc, list):
        for v in doc:
            yield from _referenced_files(v, base, depth)


def scene_hash(path: str | Path) -> str:
    """Hash of a scene's content: the file and, for a TOML scene, the files it reads.
    A missing file hashes its path (the point fails and is not cached)."""
    path = Path(path)
    h = hashlib.sha256()
    if not path.is_file():
        h.update(b"missing\0" + str(path).encode())
        return h.hexdigest()
    data = path.read_bytes()
    h.update(data)
    if path.suffix.lower() == ".toml":
        try:
            doc = tomllib.loads(data.decode())
        except (tomllib.TOMLDecodeError, UnicodeDecodeError):
            doc = {}
        for f in sorted(set(_referenced_files(doc, path.parent))):
            h.update(b"\0" + f.name.encode() + b"\0")
            h.update(f.read_bytes() if f.is_file() else b"missing")
    return h.hexdigest()


def point_key(point: Point, code: str, scene_digest: str | None = None) -> str:
    """The cache key of ``point``: configuration, scene content, resolution, backend, code."""
    ident = {"v": CACHE_VERSION, "config": point.config, "backend": point.backend,
             "scene": scene_digest or scene_hash(point.scene_path),
             "resolution": [point.width, point.height], "code": code}
    return hashlib.sha256(json.dumps(ident, sort_keys=True).encode()).hexdigest()[:24]


# --------------------------------------------------------------------------------------------
# the jobs (run on the workers)
# --------------------------------------------------------------------------------------------

def _jsonable(x):
    import numpy as np
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(f"{type(x).__name__} is not JSON serialisable")


def _error_text(e: BaseException) -> str:
    return f"{type(e).__name__}: {e}"


def _chip_mem_words(words: int, mem_words: int | None) -> int:
    """Memory words of the binary a chip frame of a ``words``-word image runs on."""
    from tb.harness.chip import CHIP_MIN_MEM_WORDS
    from tb.harness.verilator import _pow2
    return _pow2(max(words, mem_words or 0), CHIP_MIN_MEM_WORDS)


def build_chip(config: dict, scene_paths: list[str], kd_cache: str = "default",
               threads: int = 1, mem_words: int | None = None) -> dict:
    """Build (or find cached) the Verilator chip binaries a configuration needs for
    ``scene_paths`` (one per memory size, at least ``mem_words``; usually one for all:
    :func:`run_point` looks them up the same way). Never raises: ``{"error": text or None,
    "built": [...], "seconds": s}``."""
    from model.render import prepare
    from model.scene import load_scene

    from tb.harness.chip import chip_build
    t0 = time.perf_counter()
    log = io.StringIO()
    try:
        _set_threads(threads)
        cfg = config_of(config)
        sizes = set()
        for sp in ([] if mem_words else scene_paths):      # a fixed size: no scene to read
            try:
                scene = load_scene(sp)
            except Exception:       # the point reports its own scene error
                continue
            sizes.add(_chip_mem_words(len(prepare(scene, cfg, cache_dir=kd_cache).image.data),
                                      mem_words))
        if mem_words:        # a larger image gets its own binary when its point runs
            sizes.add(_chip_mem_words(0, mem_words))
        built = []
        for mw in sorted(sizes):
            b = chip_build(cfg, mw, log=log)
            built.append({"dir": b.dir.name, "built": b.built, "seconds": round(b.seconds, 1)})
        return {"error": None, "built": built, "seconds": time.perf_counter() - t0}
    except Exception as e:
        return {"error": _error_text(e), "built": [], "seconds": time.perf_counter() - t0,
                "traceback": traceback.format_exc() + log.getvalue()[-4000:]}


def _set_threads(n: int) -> None:
    """Numba threads of this worker thread (the golden model traces packets in parallel)."""
    import numba
    numba.set_num_threads(max(1, min(n, numba.config.NUMBA_NUM_THREADS)))


def run_point(point: Point, code: str, *, max_cycles: int | None = None,
              kd_cache: str = "default", build: dict | None = None,
              threads: int = 1, mem_words: int | None = None) -> dict:
    """One point on this worker, the golden model on ``threads`` threads. Never raises:
    ``{"status": "ok" | "mismatch" | "error", "error", "stats", "seconds", "traceback"}``;
    ``stats`` is ``make sim``'s ``stats.json`` dict (chip) or the model's
    ``RenderResult.stats`` (model), JSON-clean."""
    t0 = time.perf_counter()
    out = {"status": "error", "error": None, "stats": None, "traceback": None}
    try:
        _set_threads(threads)
        mine = code_hash()
        if mine != code:
            raise RuntimeError(f"this worker's code (hash {mine}, {ROOT}) differs from the "
                               f"client's ({code}): run the workers from the same checkout")
        if build is not None and build.get("error"):
            raise RuntimeError(f"Verilator build failed: {build['error']}")
        from model.render import prepare, render
        from model.scene import load_scene
        cfg = point.cfg()
        scene = load_scene(point.scene_path)
        prep = prepare(scene, cfg, cache_dir=kd_cache)
        if point.backend == "model":
            stats = render(scene, cfg, point.width, point.height, prepared=prep).stats
        else:
            from tb.harness.chip import run_chip_frame
            from tb.harness.compare import describe
            from saarcor.sim import frame_stats
            run = run_chip_frame(cfg, prep.image, scene.camera, point.width, point.height,
                                 max_cycles=max_cycles or DEFAULT_MAX_CYCLES, progress=False,
                                 log=io.StringIO(), scene=scene,
                                 mem_words=_chip_mem_words(len(prep.image.data), mem_words))
            stats = frame_stats(cfg, run, scene=point.scene, width=point.width,
                                height=point.height, backend="verilator",
                                wall=time.perf_counter() - t0)
            if run.mismatches:
                out.update(status="mismatch",
                           error=describe(run.mismatches, first=3, rays=run.frame_rays)
                           .replace("\n", ";"))
        out["stats"] = json.loads(json.dumps(stats, default=_jsonable))
        if out["status"] != "mismatch":
            out["status"] = "ok"
    except Exception as e:
        out.update(status="error", error=_error_text(e), traceback=traceback.format_exc())
    out["seconds"] = round(time.perf_counter() - t0, 3)
    return out


# --------------------------------------------------------------------------------------------
# the table
# --------------------------------------------------------------------------------------------

SKIP_MEASURES = ("config", "scene", "resolution", "backend")


def flatten(d, prefix: str = "") -> dict:
    """Scalars of nested dicts and lists as ``{"a.b.0.c": value}``."""
    out = {}
    items = d.items() if isinstance(d, dict) else enumerate(d)
    for k, v in items:
        name = f"{prefix}{k}"
        if isinstance(v, (dict, list, tuple)):
            out.update(flatten(v, name + "."))
        elif v is None or isinstance(v, (bool, int, float, str)):
            out[name] = v
    return out


def point_row(point: Point, key: str, result: dict) -> dict:
    """One table row: the point, every Config field, status, error and the stats' scalars."""
    row = {"scene": point.scene, "resolution": f"{point.width}x{point.height}",
           "width": point.width, "height": point.height, "backend": point.backend,
           **point.config, "status": result["status"], "error": result.get("error") or "",
           "key": key, "job_seconds": result.get("seconds")}
    stats = {k: v for k, v in (result.get("stats") or {}).items() if k not in SKIP_MEASURES}
    for k, v in flatten(stats).items():
        row.setdefault(k, v)
    return row


def rows_table(rows: list[dict]) -> tuple[list[str], list[dict]]:
    """Columns (union over the rows, first-seen order) and the rows."""
    cols: dict[str, None] = {}
    for r in rows:
        cols.update(dict.fromkeys(r))
    return list(cols), rows


def write_table(rows: list[dict], out: Path) -> list[Path]:
    """``results.csv`` and, when pyarrow is installed, ``results.parquet``; the paths."""
    cols, rows = rows_table(rows)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "results.csv"]
    with open(paths[0], "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=cols, restval="")
        w.writeheader()
        for r in rows:
            w.writerow(r)
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return paths
    arrays = []
    for c in cols:
        vals = [r.get(c) for r in rows]
        try:
            arrays.append(pa.array(vals))
        except (pa.ArrowInvalid, pa.ArrowTypeError):      # mixed types: as text
            arrays.append(pa.array([None if v is None else str(v) for v in vals]))
    pq.write_table(pa.Table.from_arrays(arrays, names=cols), out / "results.parquet")
    paths.append(out / "results.parquet")
    return paths


# --------------------------------------------------------------------------------------------
# the cluster and the run
# --------------------------------------------------------------------------------------------

def _option_value(text: str):
    """A ``--cluster-option`` value: int, float, true/false, a TOML list/table, else text."""
    for conv in (int, float):
        try:
            return conv(text)
        except ValueError:
            pass
    if text.lower() in ("true", "false"):
        return text.lower() == "true"
    if text[:1] in "[{":
        try:
            return tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError:
            pass
    return text


def make_cluster(kind: str, workers: int, options: list[str]):
    """A cluster object: ``local`` (processes of one thread, ``workers`` of them), a short
    name of :data:`CLUSTERS` or ``module:Class``, made with ``options`` (``KEY=VALUE``) and
    scaled to ``workers``."""
    opts = {}
    for o in options:
        k, eq, v = o.partition("=")
        if not eq or not k:
            raise SystemExit(f"sweep: --cluster-option {o!r}: write KEY=VALUE, e.g. cores=1")
        opts[k.strip()] = _option_value(v.strip())
    target = CLUSTERS.get(kind, kind)
    mod, colon, cls = target.partition(":")
    if not colon:
        mod, _, cls = target.rpartition(".")
    try:
        factory = getattr(importlib.import_module(mod), cls)
    except (ImportError, AttributeError, ValueError) as e:
        extra = " (pip install dask-jobqueue)" if mod == "dask_jobqueue" else ""
        raise SystemExit(f"sweep: --cluster {kind}: cannot load {target}{extra}: {e}")
    if kind == "local":
        import logging
        opts = {"n_workers": workers, "threads_per_worker": 1, "processes": True,
                "silence_logs": logging.ERROR, **opts}
        return factory(**opts)
    cluster = factory(**opts)
    cluster.scale(workers)
    return cluster


def _cache_read(path: Path) -> dict | None:
    try:
        d = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return d if d.get("status") == "ok" and d.get("v") == CACHE_VERSION else None


def _cache_write(path: Path, key: str, point: Point, result: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex}.tmp")
    pt = dataclasses.asdict(point)
    try:        # a scene of this checkout as a path in it: a kept cache names no machine path
        pt["scene_path"] = Path(pt["scene_path"]).relative_to(ROOT).as_posix()
    except ValueError:
        pass
    tmp.write_text(json.dumps({"v": CACHE_VERSION, "key": key, "point": pt, **result},
                              indent=1))
    tmp.replace(path)


def run_sweep(spec: Spec, *, out: Path | str, cache: Path | str, client=None,
              max_cycles: int | None = None, kd_cache: str = "default", progress: bool = True,
              log=None, threads: int = 1) -> dict:
    """Run (or take from ``cache``) every point of ``spec`` on ``client``; write the table to
    ``out``; each job runs the golden model on ``threads`` threads. Returns ``{"rows",
    "points", "cached", "computed", "failed", "paths"}``."""
    log = sys.stdout if log is None else log
    out, cache = Path(out), Path(cache)
    code = code_hash()
    digests = {sp: scene_hash(sp) for sp in {p.scene_path for p in spec.points}}
    keys = [point_key(p, code, digests[p.scene_path]) for p in spec.points]
    results: dict[int, dict] = {}
    for i, k in enumerate(keys):
        hit = _cache_read(cache / f"{k}.json")
        if hit is not None:
            results[i] = hit
    todo = [i for i in range(len(keys)) if i not in results]
    n_cached = len(results)
    if todo:
        if client is None:
            raise ValueError("run_sweep: points to compute but no Dask client")
        from distributed import as_completed
        from tqdm import tqdm
        token = uuid.uuid4().hex[:8]
        mc = max_cycles or spec.max_cycles
        builds = {}
        if spec.backend == "chip":
            need: dict[str, tuple[dict, list]] = {}
            for i in todo:
                p = spec.points[i]
                ident = json.dumps(p.config, sort_keys=True)
                need.setdefault(ident, (p.config, []))[1].append(p.scene_path)
            print(f"sweep: {len(need)} chip configuration(s) to build or find in "
                  "build/verilator/ first (a new one takes minutes)", file=log, flush=True)
            for j, (ident, (cfgd, scenes)) in enumerate(need.items()):
                builds[ident] = client.submit(build_chip, cfgd, sorted(set(scenes)), kd_cache,
                                              threads, spec.mem_words,
                                              key=f"build-{j}-{token}", priority=10,
                                              pure=False)
        futs = {}
        for i in todo:
            p = spec.points[i]
            b = builds.get(json.dumps(p.config, sort_keys=True))
            f = client.submit(run_point, p, code, max_cycles=mc, kd_cache=kd_cache, build=b,
                              threads=threads, mem_words=spec.mem_words,
                              key=f"point-{i}-{p.label().replace(' ', '-')}-{token}",
                              pure=False)
            futs[f] = i
        bar = tqdm(total=len(futs), desc=f"sweep {spec.name}", unit="point",
                   disable=not progress, file=sys.stderr)
        try:
            for f in as_completed(futs):
                i = futs[f]
                try:
                    r = f.result()
                except Exception as e:          # the worker died (memory, signal)
                    r = {"status": "error", "error": _error_text(e), "stats": None,
                         "seconds": None, "traceback": traceback.format_exc()}
                results[i] = r
                if r["status"] == "ok":
                    _cache_write(cache / f"{keys[i]}.json", keys[i], spec.points[i], r)
                else:
                    bar.write(f"sweep: {spec.points[i].label()} failed: {r['error'][:300]}")
                bar.update()
        finally:
            bar.close()
            for f in list(futs) + list(builds.values()):
                f.release()
    rows = [point_row(p, k, results[i]) for i, (p, k) in enumerate(zip(spec.points, keys))
            if i in results]
    paths = write_table(rows, out)
    failed = [i for i in results if results[i]["status"] != "ok"]
    errs = out / "errors.txt"
    if failed:
        errs.write_text("\n".join(
            f"== {spec.points[i].label()} {json.dumps(spec.points[i].config)}\n"
            f"{results[i]['error']}\n{results[i].get('traceback') or ''}" for i in sorted(failed)))
    elif errs.exists():
        errs.unlink()
    return {"rows": rows, "points": len(keys), "cached": n_cached,
            "computed": len(todo), "failed": len(failed), "paths": paths}


# --------------------------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------------------------

def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="saarcor sweep",
        description="Run a design-space sweep (a TOML spec: configurations x scenes x "
                    "resolutions, backend chip or model) as independent Dask jobs, with every "
                    "point's result cached, and write one table (CSV, and Parquet when pyarrow "
                    "is installed) with a row per point. A second run computes only the points "
                    "not cached yet. Exit status 1 when any point failed (its row says why).",
        epilog="Spec format, clusters and the table: docs/sweep.md. "
               "Example: saarcor sweep scenes/sweeps/rtcs.toml")
    ap.add_argument("spec", help="the sweep spec (TOML), e.g. scenes/sweeps/rtcs.toml")
    ap.add_argument("--out", metavar="DIR",
                    help="where results.csv, results.parquet and errors.txt go (default "
                         "build/sweep/<spec name>)")
    ap.add_argument("--cache", metavar="DIR", default="build/sweep/cache",
                    help="per-point result cache, one JSON file per point, shared by every "
                         "sweep (default build/sweep/cache)")
    ap.add_argument("--scheduler", metavar="ADDR",
                    help="use a running Dask scheduler (tcp://host:8786) instead of starting a "
                         "cluster; its workers must run from this checkout (same code)")
    ap.add_argument("--cluster", default="local", metavar="KIND",
                    help="the cluster to start when no --scheduler is given: local (default: "
                         "worker processes on this machine), slurm, pbs, sge, lsf, htcondor "
                         "(dask-jobqueue's clusters; pip install dask-jobqueue) or any class "
                         "as module:Class")
    ap.add_argument("--cluster-option", action="append", default=[], metavar="KEY=VALUE",
                    help="a keyword argument of the cluster class (repeatable), e.g. "
                         "--cluster-option cores=1 --cluster-option memory=4GB for slurm; "
                         "numbers and true/false are converted")
    ap.add_argument("--workers", type=int, default=2, metavar="N",
                    help="workers to start (local: processes of one thread each; jobqueue: "
                         "workers requested from the batch system); default 2")
    ap.add_argument("--job-threads", type=int, default=1, metavar="N",
                    help="threads of each job's golden model (numba traces packets in "
                         "parallel); default 1, so that a worker of one thread uses one core")
    ap.add_argument("--max-cycles", type=int, metavar="N",
                    help="chip backend: a point fails after this many cycles, naming what did "
                         "not finish (default: the spec's max_cycles, else 100000000)")
    add_kd_cache_arg(ap)
    ap.add_argument("--dry-run", action="store_true",
                    help="list the points and whether each is cached; run nothing")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    return ap


def main(argv=None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    if args.workers < 1:
        raise SystemExit("sweep: --workers must be >= 1")
    if args.job_threads < 1:
        raise SystemExit("sweep: --job-threads must be >= 1")
    if args.max_cycles is not None and args.max_cycles < 1:
        raise SystemExit("sweep: --max-cycles must be >= 1")
    try:
        spec = load_spec(args.spec)
    except SpecError as e:
        raise SystemExit(f"sweep: {e}")
    out = Path(args.out or Path("build/sweep") / spec.name)
    cache = Path(args.cache)
    for s in spec.skipped:
        print(f"sweep: skipped invalid grid configuration {s}")
    if args.dry_run:
        code = code_hash()
        for p in spec.points:
            k = point_key(p, code)
            state = "cached" if _cache_read(cache / f"{k}.json") else "to compute"
            cfg = {f: v for f, v in p.config.items() if v != config_dict(Config())[f]}
            print(f"{p.label():24s} {p.backend:5s} {state:10s} {k}  {cfg or 'defaults'}")
        return 0
    t0 = time.perf_counter()
    client = cluster = None
    code = code_hash()
    n_todo = sum(_cache_read(cache / f"{point_key(p, code)}.json") is None for p in spec.points)
    try:
        if n_todo:
            from distributed import Client
            if args.scheduler:
                client = Client(args.scheduler)
            else:
                cluster = make_cluster(args.cluster, args.workers, args.cluster_option)
                client = Client(cluster)
            print(f"sweep: Dask dashboard at {client.dashboard_link}"
                  + ("" if importlib.util.find_spec("bokeh") else
                     " (pip install bokeh to serve it)"), flush=True)
        res = run_sweep(spec, out=out, cache=cache, client=client, max_cycles=args.max_cycles,
                        kd_cache=args.kd_cache, progress=not args.quiet,
                        threads=args.job_threads)
    except KeyboardInterrupt:
        print(f"sweep {spec.name}: interrupted; the points finished so far are cached in "
              f"{cache}: run the same command again to resume", file=sys.stderr)
        return 130
    finally:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
    print(f"sweep {spec.name}: {res['points']} points, {res['cached']} cached, "
          f"{res['computed']} computed, {res['failed']} failed"
          + (" (failed points are retried by the next run; errors.txt)" if res["failed"] else "")
          + f"; {time.perf_counter() - t0:.1f} s -> {', '.join(map(str, res['paths']))}")
    return 1 if res["failed"] else 0


if __name__ == "__main__":
    sys.exit(main())
