"""``saarcor bench simspeed``: where a chip frame's wall time goes, and which units cost what.

Runs ``saarcor sim`` on a fixed frame (default: the standard chip on ``scenes/cornell.toml``
at 128x96, all rays, as ``make sim``) and splits its wall time into the steps ``stats.json``
records (``wall_phases``): the scene, its kd-tree, the chip's build (with ``--fresh``: from
nothing, in a private build folder, itself split into constructing the design, the Verilog
export of each unit, Verilator's translation and the C++ compile), the input file, the
simulation, the golden model (it runs beside the simulation; ``golden_wait_s`` is the time the
host waited for it afterwards), the check and the outputs. With ``--profile`` (and ``perf`` on
the machine) the simulation runs under ``perf record`` and the report gives the share of the
simulation's CPU time by unit (the Verilated class: ``slave``, ``rtc``, ``rtcmi``, ...) and
its hottest functions.

Writes ``OUT/simspeed.json`` and appends one line (commit, cycles, cycles/s, seconds) to
``OUT/simspeed_history.jsonl``, so a change in simulation speed shows from one commit to the
next.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path
from saarcor.outputs import write_atomic

__all__ = ["main", "perf_shares"]

ROOT = Path(__file__).resolve().parents[2]


def _unit(symbol: str) -> str:
    """The unit a Verilated function's symbol belongs to: its class (``Vslave___024root...``
    -> ``slave``; ``Vframe___024root...`` -> ``frame``: the chip's glue, RGS master, bus and
    SDRAM model), ``boundary`` for the glue of the hierarchical units' ports
    (``*_protectlib_*``), ``runtime`` for Verilator's library and libc."""
    if "_protectlib_" in symbol:
        return "boundary"
    m = re.match(r"V([A-Za-z0-9_]+?)___024root", symbol)
    if m:
        return m.group(1)
    return "runtime"


def perf_shares(report: str) -> dict:
    """Percent of the samples of ``perf report --stdio --sort symbol`` text by unit (see
    :func:`_unit`), and the ten hottest functions."""
    by_unit, top = defaultdict(float), []
    for line in report.splitlines():
        m = re.match(r"\s*([\d.]+)%\s+\[[.k]\]\s+(\S+)", line)
        if not m:
            continue
        pct, sym = float(m.group(1)), m.group(2)
        by_unit[_unit(sym)] += pct
        if len(top) < 10:
            top.append([sym, pct])
    return {"by_unit_percent": {k: round(v, 2) for k, v in
                                sorted(by_unit.items(), key=lambda kv: -kv[1])},
            "hottest": top}


def _perf_missing(tmp: Path) -> str | None:
    """Why ``perf record`` cannot sample here, or None if it can."""
    if shutil.which("perf") is None:
        return "perf is not installed (apt-get install linux-perf)"
    p = subprocess.run(["perf", "record", "-q", "-e", "cpu-clock", "-o", str(tmp / "probe"),
                        "--", "true"], capture_output=True, text=True)
    if p.returncode:
        return f"perf record fails here: {(p.stderr or p.stdout).strip()[:200]}"
    return None


@contextlib.contextmanager
def _env(name: str, value: str | None):
    """``$name`` set to ``value`` (None: left as it is) inside the block, restored after."""
    before = os.environ.get(name)
    if value is not None:
        os.environ[name] = value
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = before


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                              capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def main(argv=None) -> int:
    from saarcor.args import RES_QUICK, SCENE, add_out_arg, add_res_arg, add_scene_arg
    ap = argparse.ArgumentParser(
        prog="saarcor bench simspeed",
        description="Time a chip frame step by step (scene, kd-tree, build, input, simulation, "
                    "golden model, check, outputs), optionally from a fresh build and with a "
                    "perf profile of the simulation by unit; writes OUT/simspeed.json and "
                    "appends to OUT/simspeed_history.jsonl.",
        epilog="Example: saarcor bench simspeed --fresh --profile  (the default frame: the "
               "standard chip on scenes/cornell.toml at 128x96, all rays)")
    add_scene_arg(ap, SCENE)
    add_res_arg(ap, RES_QUICK)
    ap.add_argument("--fresh", action="store_true",
                    help="build the chip from nothing in a temporary build folder (times the "
                         "build; default: reuse build/verilator's binary if there is one)")
    ap.add_argument("--profile", action="store_true",
                    help="run the simulation under `perf record` and report its CPU time by "
                         "unit (needs perf; skipped, saying why, where perf cannot sample)")
    add_out_arg(ap)
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    args, rest = ap.parse_known_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    from saarcor.sim import main as sim_main
    from tb.harness.verilator import BUILD_ROOT_ENV, WRAPPER_ENV

    tmp = Path(tempfile.mkdtemp(prefix="simspeed"))
    perf_data = tmp / "perf.data"
    try:
        no_perf = _perf_missing(tmp) if args.profile else None
        if no_perf:
            print(f"bench simspeed: no profile: {no_perf}", file=sys.stderr)
        wrapper = (f"perf record -q -F 499 -e cpu-clock -o {perf_data} --"
                   if args.profile and not no_perf else None)
        sim_args = ["--scene", args.scene, "--res", args.res, "--out", str(tmp / "sim"),
                    *(["--quiet"] if args.quiet else []), *rest]
        t0 = time.perf_counter()
        with _env(WRAPPER_ENV, wrapper), \
                _env(BUILD_ROOT_ENV, str(tmp / "verilator") if args.fresh else None):
            rc = sim_main(sim_args)
        wall = time.perf_counter() - t0
        stats = json.loads((tmp / "sim" / "stats.json").read_text())
        res = {"commit": _commit(), "scene": args.scene, "res": args.res, "fresh": args.fresh,
               "load_average": round(os.getloadavg()[0], 2), "wall_s": round(wall, 1),
               "cycles": stats["cycles"], "rays": stats["rays_total"],
               "sim_cycles_per_second": stats["sim_cycles_per_second"],
               "sim_seconds": stats["sim_seconds"], "wall_phases": stats["wall_phases"],
               "build": stats["build"], "mismatches": stats["mismatches"],
               "config": stats["config"], "options": rest}
        if no_perf:
            res["profile"] = {"error": no_perf}
        elif args.profile and perf_data.exists():
            rep = subprocess.run(["perf", "report", "-i", str(perf_data), "--stdio",
                                  "--sort", "symbol", "--no-children"],
                                 capture_output=True, text=True)
            res["profile"] = perf_shares(rep.stdout)
            (out / "simspeed_perf.txt").write_text(rep.stdout)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    write_atomic(out / "simspeed.json", json.dumps(res, indent=1))
    with open(out / "simspeed_history.jsonl", "a") as f:
        f.write(json.dumps({k: res[k] for k in ("commit", "scene", "res", "cycles",
                                                "sim_cycles_per_second", "sim_seconds",
                                                "wall_s", "load_average")}) + "\n")
    ph = res["wall_phases"]
    print(f"bench simspeed: {args.scene} {args.res}: {res['cycles']:,} cycles at "
          f"{res['sim_cycles_per_second']:,} cycles/s; wall {wall:.1f} s = "
          + ", ".join(f"{k[:-2]} {v:.1f}" for k, v in ph.items()) + f" -> {out}/simspeed.json")
    if "by_unit_percent" in res.get("profile", {}):
        print("  simulation CPU by unit: " + ", ".join(
            f"{k} {v:.1f} %" for k, v in res["profile"]["by_unit_percent"].items()))
    return rc


if __name__ == "__main__":
    sys.exit(main())
