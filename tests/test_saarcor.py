"""The ``saarcor`` command line (saarcor/cli.py): listing, forwarding, help and errors."""
import ast
import importlib.util
import json
import re
import subprocess
import sys
import tomllib

import pytest
from PIL import Image

from saarcor.cli import BENCHES, COMMANDS, main

from .conftest import ROOT

# an option each command's --help must show: proof that the module's own parser answered
OPTION = {
    ("render",): "--reflect-depth",
    ("verilog",): "--threads",
    ("scene",): "--prepare",
    ("fpga",): "--freq",
    ("synth",): "--keep",
    ("formal",): "--policy",
    ("verilator",): "--mem-stall",
    ("sweep",): "--scheduler",
    ("results",): "--skip-threads",
    ("sim",): "--mem-stall",
    ("bench", "chip"): "--seeds",
    ("bench", "memory"): "--words-per-chip",
    ("bench", "threads"): "--thread-counts",
    ("bench", "model"): "--build-copies",
    ("bench", "stress"): "--formats",
    ("bench", "ladder"): "--fraction",
    ("bench", "resources"): "--json",
    ("bench", "skipping"): "--second-run",
    ("bench", "simspeed"): "--profile",
    ("bench", "precision"): "--leak-rays",
    ("bench", "fp-cost"): "--units",
    ("bench", "fp-speed"): "--exhaustive",
    ("bench", "cocotb"): "--public",
}
# spellings retired for the one of each concept (--scene, --backend, --fp-latency,
# --addr-trace, --keep, ...): no command offers them
RETIRED = ("--mesh", "--meshes", "--scenes", "--sim", "--sims", "--latency", "--amaranth",
           "--rtl", "--workdir", "--plots")


def call(argv, capsys):
    """``saarcor *argv`` in this process: (exit status, stdout, stderr)."""
    try:
        status = main(argv)
    except SystemExit as e:
        status = e.code if isinstance(e.code, int) else (print(e.code, file=sys.stderr) or 1)
    out, err = capsys.readouterr()
    return status, out, err


def test_every_command_has_a_help_test():
    names = {(n,) for n in COMMANDS} | {("bench", n) for n in BENCHES}
    assert names == set(OPTION)


def test_help_lists_every_command_and_imports_none_of_them():
    code = ("import sys; from saarcor.cli import main\n"
            "try:\n    main(['--help'])\nexcept SystemExit as e:\n    assert e.code == 0, e.code\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] in "
            "('model', 'rtl', 'tb', 'numpy', 'amaranth')))")
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[-1] == "[]", f"saarcor --help imported {lines[-1]}"
    listing = "\n".join(lines[:-1])
    for name in [*COMMANDS, "bench"]:
        assert f"\n    {name} " in listing or f"\n    {name}\n" in listing, (name, listing)
    for name in BENCHES:                   # the bench group names its benches in its line
        assert name in listing


def test_python_m_saarcor_runs():
    r = subprocess.run([sys.executable, "-m", "saarcor", "bench", "--help"], cwd=ROOT,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    for name, cmd in BENCHES.items():
        assert f"    {name}" in r.stdout and cmd.help.split()[0] in r.stdout


@pytest.mark.parametrize("cmd", sorted(OPTION), ids=" ".join)
def test_command_help_is_the_modules_help(cmd, capsys):
    status, out, err = call([*cmd, "--help"], capsys)
    assert status == 0, err
    assert OPTION[cmd] in out, out
    assert out.startswith(f"usage: saarcor {' '.join(cmd)} "), out.splitlines()[0]
    description = " ".join(out.split("\n\n")[1].split())   # whole sentences, not a cut line
    assert description.endswith((".", ".``")), description
    if cmd in (("render",), ("verilog",), ("bench", "threads")):   # Config options, generated
        assert "--trav-cache-kb" in out and "--fmt" in out
    offered = set(re.findall(r"(?<![\w-])--[a-z][\w-]*", out))
    assert not offered & set(RETIRED), offered & set(RETIRED)
    if "--res" in offered:                 # the default resolution is named, or explained
        text = " ".join(out.split())
        res = text[text.index("--res WxH "):]
        assert re.match(r"--res WxH [^()]*width x height in pixels \(default \d+x\d+: \w", res), res


@pytest.mark.parametrize("argv, words", [
    ([], ["name a command", "render"]),
    (["rendr"], ["unknown command 'rendr'", "render"]),
    (["--threads", "4", "verilog"], ["'--threads'", "saarcor verilog --threads"]),
    (["bench"], ["name a command", "threads"]),
    (["bench", "speed"], ["unknown command 'speed'", "memory"]),
    (["verilog", "--no-such-option"], ["--no-such-option"]),
    (["bench", "threads", "--threads", "4"], ["--thread-counts"]),
    (["render", "--scene", "scenes/cornell.toml", "--fmt", "E8M30"], ["frac_bits"]),
    (["render", "scenes/cornell.toml"], ["unrecognized arguments", "scenes/cornell.toml"]),
    (["bench", "threads", "--sim", "amaranth"], ["--sim"]),
])
def test_bad_command_or_option_names_the_problem(argv, words, capsys):
    status, out, err = call(argv, capsys)
    assert status != 0
    for w in words:
        assert w in err, (w, err)
    assert "Traceback" not in err


def test_forwards_arguments_and_exit_status(capsys):
    status, out, err = call(["verilog", "--list"], capsys)
    assert status == 0, err
    assert "rtc" in [line.split()[0] for line in out.splitlines() if line.strip()], out
    status, out, err = call(["render", "--scene", "no-such-scene.toml", "--quiet"], capsys)
    assert status == 2 and "no-such-scene.toml" in err     # render's own status, returned


def test_render_writes_an_image(tmp_path, capsys):
    status, out, err = call(["render", "--scene", str(ROOT / "scenes" / "cornell.toml"),
                             "--res", "8x6", "--tile-w", "4", "--tile-h", "4",
                             "--reflect-depth", "0", "--out", str(tmp_path), "--no-cache",
                             "--quiet"], capsys)
    assert status == 0, err
    assert Image.open(tmp_path / "image.png").size == (8, 6)
    stats = json.loads((tmp_path / "stats.json").read_text())
    assert stats["rays"]["eye"] == 48
    assert stats["config"]["tile_w"] == 4 and stats["config"]["reflect_depth"] == 0


def test_console_script_is_declared():
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())
    module, _, func = meta["project"]["scripts"]["saarcor"].partition(":")
    assert callable(getattr(importlib.import_module(module), func))
    assert any(module.split(".")[0] + "*" == p
               for p in meta["tool"]["setuptools"]["packages"]["find"]["include"])


# the dependency rule: each package imports only the ones before it
LAYERS = ("model", "rtl", "tb", "saarcor")


def _imports() -> dict[str, set[str]]:
    """Every module of the four packages -> the modules of the four it imports (at any depth of
    the file: imports inside functions count too)."""
    files = {}
    for pkg in LAYERS:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            files[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    graph = {}
    for mod, path in files.items():
        here = mod.split(".") if path.name == "__init__.py" else mod.split(".")[:-1]
        out = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = (".".join(here[:len(here) - node.level + 1] + [node.module or ""])
                        if node.level else node.module or "").rstrip(".")
                names = [f"{base}.{a.name}" if f"{base}.{a.name}" in files else base
                         for a in node.names]
            else:
                continue
            out |= {n for n in names if n in files and n != mod}
        graph[mod] = out
    return graph


def test_each_package_imports_only_the_ones_below_it():
    """model <- rtl <- tb <- saarcor: the golden model imports none of the others, the hardware
    only the model, the harness and benches not the commands."""
    bad = [f"{m} imports {d}" for m, deps in _imports().items() for d in deps
           if LAYERS.index(d.split(".")[0]) > LAYERS.index(m.split(".")[0])]
    assert not bad, bad


def test_no_import_cycles():
    """No module reaches itself through imports (module-level or inside functions)."""
    graph = _imports()
    cycles, state = [], {}

    def visit(m, stack):
        state[m] = 1
        for d in sorted(graph[m]):
            if state.get(d) == 1:
                cycles.append(" -> ".join(stack[stack.index(d):] + [d]))
            elif d not in state:
                visit(d, stack + [d])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [m])
    # a package's __init__ importing its own modules is not a cycle of modules
    cycles = [c for c in cycles if not any(c.startswith(p + " ") or f" {p} -" in c
                                           for p in graph if (ROOT / p.replace(".", "/")).is_dir())]
    assert not cycles, cycles


def test_test_files_follow_the_naming_rule():
    """tests/__init__.py's rule: a unit on both sides is tested in test_<unit>_rtl.py (and
    test_<unit>_model.py), never in a bare test_<unit>.py or a test_model_<unit>.py."""
    both = {p.stem for p in (ROOT / "model").iterdir() if p.suffix == ".py" or p.is_dir()} & \
           {p.stem for p in (ROOT / "rtl").iterdir() if p.suffix == ".py" or p.is_dir()}
    both -= {"__init__", "__pycache__", "common"}
    names = {p.stem for p in (ROOT / "tests").glob("test_*.py")}
    bare = sorted(f"test_{u}.py" for u in both if f"test_{u}" in names)
    swapped = sorted(n for n in names if n.startswith("test_model_") or n.startswith("test_rtl_"))
    missing = sorted(u for u in both if f"test_{u}_rtl" not in names)
    assert not bare and not swapped and not missing, (bare, swapped, missing)


def test_rtl_is_hardware_only():
    """rtl/ drives no tool (no subprocess, no command line, no simulator) and each of its methods
    fits on a few screens (<= 150 lines): longer bodies are split into components."""
    long, tools = [], []
    for path in sorted((ROOT / "rtl").rglob("*.py")):
        tree = ast.parse(path.read_text(), str(path))
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                if node.end_lineno - node.lineno + 1 > 150:
                    long.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name}")
            names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                     [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            tools += [f"{path.relative_to(ROOT)}:{node.lineno} imports {n}" for n in names
                      if n.split(".")[0] in ("subprocess", "argparse", "amaranth.sim", "cocotb")
                      or n.startswith("amaranth.sim") or n.startswith("amaranth.back")]
    assert not long and not tools, (long, tools)
