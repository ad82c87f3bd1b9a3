"""Speed of the cocotb benches: ``saarcor bench cocotb [--unit list] [--backend icarus,verilator]``.

Runs one bench on each simulator and prints a Markdown table: build time (export + compile;
0 when the build is reused), the simulator run (start-up included), the cycles of the bench's
clock loop and its cycles/s (the loop alone: cocotb's Python plus the simulator).
"""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from model.config import Config

from tb.harness.cocotb.runner import SIMULATORS

UNITS = ("fp_mul", "list", "traversal", "intersect_pipe", "rtc", "chip", "chip_scene")
# the RTC's units as tests/test_cocotb.py configures them: 2 threads, 4x4 packets, small caches
TINY = Config(threads=2, tile_w=4, tile_h=4, trav_subunits=2, trav_cache_kb=1, list_cache_kb=1,
              int_cache_kb=9)
# the chip as tests/test_chip.py configures it: one RTC of TINY, SDRAM latency 8
CHIP = TINY.replace(rtcs=1, mem_latency=8)


def bench(unit: str, sim: str, run_dir: Path, public: str):
    """Run ``unit``'s bench on ``sim``: the same stimulus as the CI tests (tests/test_cocotb.py)."""
    root = Path(__file__).resolve().parents[2]
    if unit == "fp_mul":
        from tb.harness.cocotb.fp import run_fp
        return run_fp("mul", sim, run_dir, n=3000, seed=1, public=public)
    if unit == "list":
        from tb.units.list import golden
        from tb.harness.cocotb.list import run_list
        g = golden(root / "scenes" / "cornell.toml", 16, 16, Config(), tempfile.mkdtemp())
        return run_list(g, sim, run_dir, seed=3, public=public)
    if unit == "traversal":
        from tb.units.traversal import small_case
        from tb.harness.cocotb.traversal import run_traversal
        image, rays = small_case(root / "scenes" / "cornell.toml", 12, 4, TINY,
                                 tempfile.mkdtemp())
        return run_traversal(image, rays, TINY, sim, run_dir, seed=1, public=public)
    if unit == "intersect_pipe":
        from model.fp import BINARY32
        from tb.units.intersection import random_tests
        from tb.harness.cocotb.intersection import run_pipe
        return run_pipe(random_tests(240, BINARY32, seed=1), sim, run_dir, seed=1,
                        public=public)
    if unit == "rtc":
        from tb.units.traversal import small_case
        from tb.harness.cocotb.rtc import run_rtc
        image, rays = small_case(root / "scenes" / "cornell.toml", 4, 4, TINY,
                                 tempfile.mkdtemp())
        run, r = run_rtc(image, rays, TINY, sim, run_dir, top="rtc", seed=2, public=public)
        assert run.mismatches == [] and run.counter_mismatches() == {}
        return r
    if unit in ("chip", "chip_scene"):
        from model.render import prepare
        from model.scene import load_scene
        from tb.harness.cocotb.chip import run_chip
        scene = load_scene(root / "scenes" / "cornell.toml")
        image = prepare(scene, CHIP, cache_dir=tempfile.mkdtemp()).image
        run, r = run_chip(CHIP, image, scene.camera, 4, 4, sim, run_dir, stall=0.25, seed=3,
                          mem_stall=0.25, scene=scene if unit == "chip_scene" else None,
                          public=public)
        assert run.mismatches == []
        return r
    raise SystemExit(f"--unit {unit!r}: choose one of {', '.join(UNITS)}")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(prog="saarcor bench cocotb",
                                 description=__doc__.split("\n")[0].split(":")[0] + ": one bench "
                                 "on each simulator, a Markdown table of build and run times.")
    ap.add_argument("--unit", default="list", choices=UNITS, help="the bench (default list)")
    ap.add_argument("--backend", default=",".join(SIMULATORS), metavar="SIM,...",
                    help="simulators, comma-separated: " + ", ".join(SIMULATORS) +
                         " (default %(default)s)")
    ap.add_argument("--public", default="ports", choices=("ports", "all"),
                    help="Verilator: make only the ports (default) or every signal public")
    args = ap.parse_args(argv)
    sims = args.backend.split(",")
    bad = [s for s in sims if s not in SIMULATORS]
    if bad:
        ap.error(f"--backend: unknown simulator(s) {bad}; choose from {', '.join(SIMULATORS)}")
    print("| unit | simulator | build s | run s | cycles | cycles/s |\n|---|---|---|---|---|---|")
    for sim in sims:
        with tempfile.TemporaryDirectory() as d:
            r = bench(args.unit, sim, Path(d), args.public)
        v = r.values
        label = sim + (f" (public {args.public})" if sim == "verilator" else "")
        print(f"| {args.unit} | {label} | {r.build.seconds:.1f} | {r.seconds:.1f} | "
              f"{v['cycles']} | {v['cycles'] / v['seconds']:.0f} |", flush=True)


if __name__ == "__main__":
    main()
