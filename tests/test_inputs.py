"""Bad input at every entry: each Config field, each command's options, the output folder, a
full disk and Ctrl-C give one clear line (or a documented handling), never a traceback."""
import dataclasses
import errno
import json
import math
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from model.config import Config, ConfigError
from saarcor.args import MAX_PIXELS, parse_bool, parse_res
from saarcor.cli import main
from saarcor.outputs import OutputDir

from .conftest import ROOT

FIELDS = [f for f in dataclasses.fields(Config) if f.name != "fmt"]
KIND = {f.name: type(f.default) for f in FIELDS}

# every command that takes the configuration options (saarcor.args.add_config_args)
CONFIG_COMMANDS = [["render"], ["sim"], ["verilog"], ["verilator"], ["fpga"], ["bench", "chip"],
                   ["bench", "memory"], ["bench", "resources"], ["bench", "threads"]]

WRONG_TYPE = {
    int: st.one_of(st.floats(allow_nan=True).filter(lambda x: not float(x).is_integer()
                                                    if math.isfinite(x) else True),
                   st.text(max_size=5), st.none(), st.booleans()),
    float: st.one_of(st.just(math.nan), st.just(math.inf), st.just(-math.inf),
                     st.text(max_size=5), st.none(), st.booleans()),
    bool: st.one_of(st.integers(), st.text(max_size=5), st.none(), st.floats()),
    str: st.one_of(st.integers(), st.none(), st.floats(), st.booleans()),
}


def _exit_line(argv, capsys) -> tuple[int, str]:
    """Run ``saarcor *argv`` in this process; its exit status and stderr (SystemExit's message
    counted as stderr)."""
    try:
        status = main(list(argv))
    except SystemExit as e:
        status = e.code if isinstance(e.code, int) else 1
        if not isinstance(e.code, int) and e.code is not None:
            print(e.code, file=sys.stderr)
    return status, capsys.readouterr().err


# -- Config ----------------------------------------------------------------------------------
@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.sampled_from(FIELDS).flatmap(
    lambda f: st.tuples(st.just(f.name), WRONG_TYPE[type(f.default)])))
def test_config_rejects_every_wrong_type_with_config_error(case):
    name, value = case
    with pytest.raises(ConfigError) as e:
        Config(**{name: value})
    assert name in str(e.value)


@settings(max_examples=400, deadline=None, derandomize=True)
@given(st.sampled_from(FIELDS).flatmap(
    lambda f: st.tuples(st.just(f.name),
                        st.integers(-10**6, 10**6) if type(f.default) is int else
                        st.floats(-1e6, 1e6) if type(f.default) is float else
                        st.booleans() if type(f.default) is bool else st.text(max_size=8))))
def test_config_either_accepts_or_names_the_field(case):
    """Any value of the right type: a Config, or a ConfigError naming the field (never another
    exception from deep inside)."""
    name, value = case
    try:
        cfg = Config(**{name: value})
    except ConfigError as e:
        assert name in str(e) or any(n in str(e) for n in KIND)
    else:
        assert getattr(cfg, name) == value


@pytest.mark.parametrize("name,value,words", [
    ("clock_mhz", -5.0, "> 0"), ("clock_mhz", 0.0, "> 0"), ("clock_mhz", math.nan, "finite"),
    ("mem_latency", -5, ">= 0"), ("kd_cost_int", math.nan, "finite"),
    ("shadows", "maybe", "true or false"), ("rtcs", 2.5, "integer"),
    ("trav_cache_kb", 0, ">= 1"), ("mem_chip_bits", 0, ">= 1")])
def test_config_errors_name_the_field_and_the_rule(name, value, words):
    with pytest.raises(ConfigError, match=name) as e:
        Config(**{name: value})
    assert words in str(e.value)


def test_numpy_integers_are_taken_as_ints():
    cfg = Config(rtcs=np.int64(2), clock_mhz=np.float32(500))
    assert type(cfg.rtcs) is int and cfg.rtcs == 2 and type(cfg.clock_mhz) is float


# -- the command line --------------------------------------------------------------------------
def _bad_text(kind):
    if kind is int:
        return st.sampled_from(["abc", "2.5", "", "1e3", "0x", "--"])
    if kind is float:
        return st.sampled_from(["nan", "inf", "-inf", "abc", ""])
    if kind is bool:
        return st.sampled_from(["maybe", "2", "", "yess", "none"])
    return st.sampled_from(["", "ring", "SHARED "])


@settings(max_examples=150, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.sampled_from(CONFIG_COMMANDS),
       st.sampled_from(FIELDS).flatmap(lambda f: st.tuples(st.just(f.name),
                                                           _bad_text(type(f.default)))))
def test_every_command_rejects_bad_config_text_in_one_line(capsys, command, case):
    name, text = case
    status, err = _exit_line([*command, f"--{name.replace('_', '-')}={text}"], capsys)
    assert status not in (0, None), (command, name, text)
    assert "Traceback" not in err
    assert name.replace("_", "-") in err or name in err, err


@settings(max_examples=60, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.sampled_from(CONFIG_COMMANDS),
       st.sampled_from([f for f in FIELDS if type(f.default) in (int, float)]).flatmap(
           lambda f: st.tuples(st.just(f.name), st.integers(-10**4, 0)
                               if type(f.default) is int else st.floats(-1e4, 0))))
def test_every_command_rejects_an_impossible_number_in_one_line(capsys, command, case):
    """Numbers the Config refuses (it is the oracle): every command refuses them too, in one
    line naming the field, before any work."""
    name, value = case
    try:
        Config(**{name: value})
    except ConfigError:
        pass
    else:
        return                               # a possible value: the command would run
    status, err = _exit_line([*command, f"--{name.replace('_', '-')}={value}"], capsys)
    assert status not in (0, None) and "Traceback" not in err and name in err, err


@pytest.mark.parametrize("text", ["maybe", "", "2", "truee"])
def test_booleans_are_parsed_strictly(text):
    import argparse
    with pytest.raises(argparse.ArgumentTypeError, match="true or false"):
        parse_bool(text)
    assert parse_bool("TRUE") is True and parse_bool("off") is False


def test_resolution_limits_are_stated(capsys):
    import argparse
    with pytest.raises(argparse.ArgumentTypeError, match="65535"):
        parse_res("100000x10")
    with pytest.raises(argparse.ArgumentTypeError, match="16384x16384"):
        parse_res("20000x20000")
    assert 20000 * 20000 > MAX_PIXELS
    status, err = _exit_line(["sim", "--res", "-5x10"], capsys)
    assert status and "width and height must be >= 1" in err and "expected one" not in err


def test_estimate_refuses_a_backend_it_would_ignore(capsys):
    status, err = _exit_line(["sim", "--fidelity", "estimate", "--backend", "amaranth"], capsys)
    assert status and "no effect" in err


def test_default_scene_is_found_from_another_folder(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    status, err = _exit_line(["sim", "--fidelity", "estimate", "--res", "16x12", "--quiet",
                              "--out", str(tmp_path / "o")], capsys)
    assert status == 0, err
    assert json.loads((tmp_path / "o" / "stats.json").read_text())["rays_total"] == 16 * 12


def test_a_missing_scene_names_the_shipped_ones(capsys):
    status, err = _exit_line(["sim", "--scene", "scenes/nope.toml"], capsys)
    assert status and "nope.toml" in err and "cornell.toml" in err


# -- the output folder -------------------------------------------------------------------------
def test_out_naming_a_file_fails_before_any_work(tmp_path, capsys):
    f = tmp_path / "afile"
    f.write_text("x")
    t0 = time.perf_counter()
    for cmd in (["sim"], ["render"]):
        status, err = _exit_line([*cmd, "--out", str(f)], capsys)
        assert status and "is a file, not a folder" in err and "Traceback" not in err
    assert time.perf_counter() - t0 < 20            # refused at once, no frame was made
    status, err = _exit_line(["render", "--out", str(f / "sub")], capsys)
    assert status and "cannot write" in err


def test_output_dir_stages_then_renames_together(tmp_path):
    d = tmp_path / "o"
    OutputDir(d, owns=("a.txt", "b.txt", "c.txt")).check()
    (d / "c.txt").write_text("old c")               # an earlier run's file this run won't write
    with OutputDir(d, owns=("a.txt", "b.txt", "c.txt")) as out:
        out.write_text("a.txt", "new a")
        out.file("b.txt").write_text("new b")
        assert not (d / "a.txt").exists()           # nothing in place before the end
    assert (d / "a.txt").read_text() == "new a" and (d / "b.txt").read_text() == "new b"
    assert not (d / "c.txt").exists()               # no mixture of two runs
    assert [p.name for p in d.iterdir() if p.name.startswith(".")] == []


def test_a_failed_write_keeps_the_previous_outputs(tmp_path):
    d = tmp_path / "o"
    with OutputDir(d, owns=("a.txt",)).check() as out:
        out.write_text("a.txt", "first")
    with pytest.raises(OSError):
        with OutputDir(d, owns=("a.txt",)) as out:
            out.write_text("a.txt", "second")
            raise OSError(errno.ENOSPC, "No space left on device")
    assert (d / "a.txt").read_text() == "first"
    assert [p.name for p in d.iterdir()] == ["a.txt"]


def test_disk_full_is_one_line_and_keeps_earlier_outputs(tmp_path, capsys, monkeypatch):
    out = tmp_path / "o"
    status, err = _exit_line(["render", "--res", "16x12", "--quiet", "--out", str(out)], capsys)
    assert status == 0, err
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device", str(out / "rays.npz"))
    monkeypatch.setattr(np, "savez", full)
    status, err = _exit_line(["render", "--res", "20x12", "--quiet", "--out", str(out)], capsys)
    assert status == 1 and "No space left on device" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_ctrl_c_exits_130_in_one_line_and_keeps_earlier_outputs(tmp_path):
    """SIGINT while tracing a frame (numba code): exit 130, one line, the previous run's files
    byte for byte. The signal goes once the progress bar shows (the handler is in place)."""
    import os
    out = tmp_path / "o"
    cmd = [sys.executable, "-m", "saarcor", "render", "--out", str(out)]
    r = subprocess.run([*cmd, "--res", "16x12", "--quiet"], cwd=ROOT, capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    p = subprocess.Popen([*cmd, "--res", "4096x3072"], cwd=ROOT, stderr=subprocess.PIPE)
    seen, t0 = b"", time.perf_counter()
    while b"tracing" not in seen and time.perf_counter() - t0 < 300:
        chunk = os.read(p.stderr.fileno(), 4096)
        if not chunk:
            break
        seen += chunk
    p.send_signal(signal.SIGINT)
    err = (seen + p.communicate(timeout=120)[1]).decode(errors="replace")
    assert p.returncode == 130, err          # 12.6 M rays: seconds of tracing still to go
    assert "interrupted" in err and "Traceback" not in err
    assert {q.name: q.read_bytes() for q in out.iterdir() if not q.name.startswith(".")} \
        == before
