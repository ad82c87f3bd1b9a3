"""Memory-system bench: cache hit rates per associativity, SDRAM bandwidth per chip count.

    saarcor bench memory [--out build/bench] [--packets N] [--addr-trace trav=t.npy ...]
                         [--scene PATH [--res WxH]]

Writes ``<out>/memory.json`` with

* ``hit_rates``: for the trav, list and int caches at the configured sizes, hit rate and memory
  words read for direct-mapped, 2-way and 4-way (``model.cache.CacheModel``, which the RTL cache
  matches request for request), and the spread between the best and worst associativity (the
  paper saw < 3 % difference in performance). The access streams are per-unit item-address
  arrays (int64 ``.npy``: node, list-entry and triangle indices in request order, from
  ``--addr-trace`` or recorded by the golden model on ``--scene``); without either a
  synthetic kd-tree-like stream (``model.cache.synthetic_traces``) is used and the JSON says
  so.
* ``bandwidth``: sustained bandwidth of the SDRAM model (``tb/harness/memory.py``, simulated in
  Amaranth) for 1, 2 and 4 chips with spread, random and single-chip ("hot") access patterns,
  in bits per chip cycle and MB/s at the configured clock, against chips x 16 bit x clock / 4.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from model.cache import UNITS, CacheModel, cache_geometry, synthetic_traces
from model.config import Config, ConfigError
from saarcor.outputs import write_atomic


def hit_rates(cfg: Config, traces: dict[str, np.ndarray]) -> dict:
    out = {}
    for unit in UNITS:
        if unit not in traces:
            continue
        tr = traces[unit]
        res = {}
        for ways in (1, 2, 4):
            g = cache_geometry(cfg, unit, ways=ways)
            m = CacheModel(g)
            t0 = time.perf_counter()
            m.access(tr)
            res[f"{ways}-way"] = {"hit_rate": m.hit_rate, "hits": m.hits, "misses": m.misses,
                                  "words_read": m.words_read, "sets": g.sets,
                                  "seconds": time.perf_counter() - t0}
        rates = [r["hit_rate"] for r in res.values()]
        out[unit] = {"accesses": int(tr.size), "size_kb": g.size_bytes / 1024,
                     "line_items": g.line_items, "item_bits": g.item_bits, **res,
                     "spread_percent_points": 100 * (max(rates) - min(rates))}
    return out


def bandwidth(cfg: Config, words_per_chip: int) -> list[dict]:
    from tb.units.memory import sdram_bandwidth
    rows = []
    for chips in (1, 2, 4):
        for pattern in ("spread", "random", "hot"):
            if pattern != "spread" and chips == 1:
                continue
            t0 = time.perf_counter()
            r = sdram_bandwidth(chips, words_per_chip * chips, pattern=pattern,
                                chip_bits=cfg.mem_chip_bits, clock_ratio=cfg.mem_clock_ratio,
                                latency=cfg.mem_latency, chip_queue=cfg.mem_chip_queue)
            mbs = lambda bits: bits / 8 * cfg.clock_mhz  # noqa: E731  bits/cycle -> MB/s
            ideal = cfg.mem_chip_bits / cfg.mem_clock_ratio
            rows.append({
                "chips": chips, "pattern": pattern, "words": r["words"],
                "bits_per_cycle": r["bits_per_cycle"],
                "MB_per_s": mbs(r["bits_per_cycle"]),
                "ideal_MB_per_s": mbs(chips * ideal),
                "per_chip_MB_per_s": [mbs(b) for b in r["bits_per_cycle_per_chip"]],
                "ideal_per_chip_MB_per_s": mbs(ideal),
                "words_per_chip": r["words_per_chip"],
                "first_latency_cycles": r["first_latency"],
                "sim_seconds": time.perf_counter() - t0,
            })
    return rows


def main(argv=None) -> dict:
    from saarcor.args import (RES_BENCH, add_config_args, add_out_arg, add_res_arg,
                              add_scene_arg, config_from_args, parse_res)
    ap = argparse.ArgumentParser(prog="saarcor bench memory",
                                 description=__doc__.split("\n")[0] + " The hit rates are "
                                 "measured for 1, 2 and 4 ways whatever --cache-ways says.")
    add_out_arg(ap)
    ap.add_argument("--packets", type=int, default=50_000,
                    help="packets of the synthetic trace (ignored for units given by "
                         "--addr-trace)")
    ap.add_argument("--depth", type=int, default=20, help="levels of the synthetic kd-tree")
    ap.add_argument("--addr-trace", action="append", default=[], metavar="UNIT=FILE.npy",
                    help="recorded item-address stream of a unit (trav, list or int); repeat "
                         "for several units")
    ap.add_argument("--words-per-chip", type=int, default=100,
                    help="words per chip in each SDRAM bandwidth run (Amaranth simulation)")
    ap.add_argument("--no-bandwidth", action="store_true", help="skip the SDRAM simulation")
    add_scene_arg(ap, None, help="record the golden model's access streams on this scene (eye "
                                 "rays; packets in order) instead of a synthetic stream: a "
                                 ".toml scene or a bare mesh")
    add_res_arg(ap, RES_BENCH, what="--scene's image")
    add_config_args(ap)
    args = ap.parse_args(argv)
    try:
        cfg = config_from_args(args)
    except (ConfigError, ValueError) as e:
        ap.error(str(e))

    traces, source = {}, {}
    if args.scene:
        from model.raygen import eye_rays
        from model.render import prepare
        from model.rtc import item_trace, trace
        from model.scene import load_scene
        scene = load_scene(args.scene)
        try:
            w, h = parse_res(args.res)
        except argparse.ArgumentTypeError as e:
            ap.error(str(e))
        prep = prepare(scene, cfg)
        _, _, events = trace(prep.image, eye_rays(scene.camera, w, h, cfg), cfg, record=True)
        for unit, tr in item_trace(events).items():
            traces[unit] = tr
            source[unit] = (f"golden model, {scene.name} {w}x{h} eye rays, packets in order "
                            f"({len(tr)} requests)")
    for spec in args.addr_trace:
        unit, _, path = spec.partition("=")
        if unit not in UNITS or not path:
            ap.error(f"--addr-trace {spec!r}: expected UNIT=FILE.npy with UNIT one of {UNITS}")
        traces[unit] = np.load(path).astype(np.int64)
        source[unit] = path
    if len(traces) < len(UNITS):
        t0 = time.perf_counter()
        syn = synthetic_traces(args.packets, depth=args.depth, seed=1)
        for unit in UNITS:
            if unit not in traces:
                traces[unit] = syn[unit]
                source[unit] = (f"synthetic kd-tree-like stream: {args.packets} packets, "
                                f"depth {args.depth} (model.cache.synthetic_traces)")
        print(f"synthetic traces: {time.perf_counter() - t0:.1f} s")

    result = {"config": {k: v for k, v in cfg.to_dict().items()
                         if k.startswith(("mem_", "cache_", "clock", "trav_cache", "list_cache",
                                          "int_cache", "int_item"))},
              "trace_source": source, "hit_rates": hit_rates(cfg, traces)}
    for unit, r in result["hit_rates"].items():
        print(f"{unit:5s} " + "  ".join(f"{w}: {100 * r[w]['hit_rate']:.2f} %"
                                        for w in ("1-way", "2-way", "4-way")) +
              f"   spread {r['spread_percent_points']:.2f} points")
    if not args.no_bandwidth:
        result["bandwidth"] = bandwidth(cfg, args.words_per_chip)
        for row in result["bandwidth"]:
            print(f"{row['chips']} chip(s) {row['pattern']:6s}: {row['MB_per_s']:7.1f} MB/s "
                  f"(ideal {row['ideal_MB_per_s']:.1f})")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_atomic(out / "memory.json", json.dumps(result, indent=1, default=float))
    print(f"wrote {out / 'memory.json'}")
    return result


if __name__ == "__main__":
    main()
