"""Config: the RTL-only parameters (FP latencies, intersection slots, list reads in flight) are
checked with errors that name them, and the units take their sizes from the Config."""
import pytest

from model.config import Config, ConfigError
from rtl.intersection import IntersectionUnit
from rtl.list import ListUnit
from rtl.traversal import TravSubunit

SMALL = dict(threads=2, tile_w=2, tile_h=2, trav_subunits=1, kd_max_depth=4)


@pytest.mark.parametrize("field,value", [
    ("fp_add_latency", -1), ("fp_mul_latency", 65), ("fp_div_latency", -3),
    ("int_tri_slots", 1), ("int_tri_slots", 6), ("list_outstanding", 3),
    ("list_outstanding", 1), ("fp_sqrt_latency", 65), ("rgs_lights", 15), ("reflect_depth", 16),
    ("shade_cache_kb", 0), ("delay_ram", 1), ("delay_ram", -2), ("rgs_buffers", 11),
    ("cache_topology", "per_rtc"), ("result_ports", 0), ("result_ports", 5),
    ("trav_stack", "one")])
def test_bad_rtl_parameters_are_named(field, value):
    with pytest.raises(ConfigError, match=field):
        Config(**{field: value})


def test_one_value_stack_needs_the_default_clock():
    with pytest.raises(ConfigError, match="trav_stack='one_value' is built for the default "
                                          "clock only: set fast_clock=False"):
        Config(trav_stack="one_value", fast_clock=True)


def test_units_take_latencies_and_sizes_from_config():
    base = Config(**SMALL)
    slow = base.replace(fp_add_latency=5, fp_mul_latency=4, int_tri_slots=16,
                        list_outstanding=4)
    assert base.fp_latencies() == {"add": None, "mul": None, "div": None, "sqrt": None,
                                   "cmp": None, "delay_ram": 0}
    assert slow.replace(fp_sqrt_latency=11).fp_latencies()["sqrt"] == 11
    sub0, sub1 = TravSubunit(base), TravSubunit(slow)
    assert (sub0.add.latency, sub0.mul.latency) == (3, 3)
    assert (sub1.add.latency, sub1.mul.latency) == (5, 4)
    assert sub1.LAT - sub0.LAT == 3
    i0, i1 = IntersectionUnit(base), IntersectionUnit(slow)
    assert (i0.tri_slots, i1.tri_slots) == (8, 16)
    assert i1.pipe.latency > i0.pipe.latency
    assert i1.pipe.latencies["add"] == 5 and i1.pipe.latencies["mul"] == 4
    assert ListUnit(slow).outstanding == 4 and ListUnit(base).outstanding == 8
    for u in (sub0, sub1, i0, i1):
        u._MustUse__silence = True


def config_names_the_hardware_reads() -> set[str]:
    """Every ``cfg.<name>`` in the RTL sources and the Verilator frame tops (what a binary's
    key must hold)."""
    import re
    from pathlib import Path
    root = Path(__file__).resolve().parent.parent
    files = sorted((root / "rtl").rglob("*.py")) + [root / "tb" / "harness" / n for n in (
        "frame.py", "chip_frame.py", "lfsr.py", "memory.py", "tops.py")]
    read = set()
    for p in files:
        read |= set(re.findall(r"cfg\.(\w+)", p.read_text()))
    return read


def test_host_fields_are_not_read_by_the_hardware():
    """A Verilator binary is shared across values of ``HOST_FIELDS`` (its key leaves them out),
    so no RTL source, simulation top or Config property the RTL reads may use them."""
    import ast
    import inspect
    from model.config import HOST_FIELDS
    read = config_names_the_hardware_reads()
    assert {"threads", "stack_depth", "fp_latencies"} <= read
    assert not read & set(HOST_FIELDS), read & set(HOST_FIELDS)
    for node in ast.walk(ast.parse(inspect.getsource(Config))):     # properties the RTL reads
        if isinstance(node, ast.FunctionDef) and node.name in read:
            used = {a.attr for a in ast.walk(node) if isinstance(a, ast.Attribute)}
            assert not used & set(HOST_FIELDS), (node.name, used & set(HOST_FIELDS))
    d = Config().hardware_dict()
    assert not set(HOST_FIELDS) & set(d) and {"rtcs", "fmt", "kd_max_depth"} <= set(d)


def test_reflect_depth_enters_the_hardware_key_as_secondary_rays():
    """The RTL reads ``reflect_depth`` only through ``Config.secondary_rays`` (the depth is a
    register loaded per frame), so a binary with light registers serves every depth up to
    where the fewest pending buffers grow with it (``Config.min_rgs_buffers``: reflect_depth
    + 2 for a frame without lights, above 2 (rgs_lights + 1) + 2), and the eye-ray-only chip
    (no lights, no reflections) is a binary of its own."""
    read = config_names_the_hardware_reads()
    assert "secondary_rays" in read and "reflect_depth" not in read
    lit = [Config(reflect_depth=d).hardware_dict() for d in (0, 1, 3, 10)]
    assert lit[0] == lit[1] == lit[2] == lit[3] and lit[0]["secondary_rays"] is True
    assert Config(reflect_depth=11).hardware_dict() != lit[0]
    dark = [Config(rgs_lights=0, reflect_depth=d).hardware_dict() for d in (0, 1, 2, 3)]
    assert dark[1] == dark[2] != dark[0] and dark[0]["secondary_rays"] is False
    assert dark[3] != dark[2] and Config(rgs_lights=0, reflect_depth=3).min_rgs_buffers == 5
    assert dark[0] != lit[0]


def test_slave_buffers_fill_the_threads():
    """The slave's pending buffers: by default enough for ``threads / (lights + 1)`` eye
    packets with their reservations (``threads + rgs_lights + 1``), never fewer than the
    deadlock-free ``2 (rgs_lights + 1) + 2``; ``rgs_buffers`` sets them."""
    from rtl.rgs import slave_buffers
    assert slave_buffers(Config()) == 16 + 4 + 1
    assert slave_buffers(Config(threads=2)) == 2 * (4 + 1) + 2 == Config().min_rgs_buffers
    assert slave_buffers(Config(rgs_lights=1, threads=4)) == 6
    assert slave_buffers(Config(rgs_buffers=13)) == 13
    assert Config(rgs_lights=2, rgs_buffers=8).rgs_buffers == 8


def test_every_config_option_has_help():
    """Every ``Config`` field's command-line option says what it is (the field's comment in
    ``model/config.py``), not only its default."""
    import argparse
    import dataclasses

    from model.config import field_help
    from saarcor.args import add_config_args
    text = field_help()
    names = {f.name for f in dataclasses.fields(Config)} - {"fmt"}
    assert names <= set(text), sorted(names - set(text))
    assert text["rtcs"] == "ray tracing cores on the chip"
    assert text["fp_add_latency"] == text["fp_div_latency"]   # one block, four fields
    assert "normals, flags" in text["shade_cache_kb"]                 # a trailing comment's lines
    ap = argparse.ArgumentParser()
    add_config_args(ap)
    helps = {a.dest: a.help for a in ap._actions}
    assert helps["rgs_buffers"].startswith("pending secondary packets per RGS slave")
    assert helps["rgs_buffers"].endswith("(default 0)")


def test_cache_topology_sets_the_rtcmi_count():
    """Shared (the paper's): one RTC-MI for the chip; private: one per RTC."""
    assert Config().cache_topology == "shared" and Config(rtcs=4).rtcmis == 1
    assert Config(rtcs=4, cache_topology="private").rtcmis == 4


def test_presets_start_from_the_defaults_and_options_override_them():
    import argparse

    from model.config import PRESETS, preset
    from saarcor.args import add_config_args, config_from_args
    assert preset("standard") == Config()
    paper = preset("paper")
    assert (paper.rgs_fp_adders, paper.rgs_fp_muls, paper.rgs_fp_pool) == (3, 4, True)
    assert paper.int_test == "projection" and paper.trav_stack == "one_value"
    assert paper.replace(**{k: getattr(Config(), k) for k in PRESETS["paper"]}) == Config()
    with pytest.raises(ConfigError, match="preset 'nope'"):
        preset("nope")
    ap = argparse.ArgumentParser()
    add_config_args(ap)
    cfg = config_from_args(ap.parse_args(["--preset", "paper", "--rgs-fp-muls", "2"]))
    assert (cfg.rgs_fp_adders, cfg.rgs_fp_muls, cfg.rgs_fp_pool) == (3, 2, True)
    assert config_from_args(ap.parse_args([])) == Config()
    with pytest.raises(SystemExit):
        ap.parse_args(["--preset", "fast"])
