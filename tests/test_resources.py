"""``saarcor.bench.resources``: FP units by kind and memory bits counted from a component's netlist."""
import pytest

from model.cache import cache_geometry
from model.config import Config
from model.fp import FPFormat
from saarcor.bench.resources import chip_resources, resources


@pytest.mark.filterwarnings("ignore:.*created but never used")
def test_secondary_pipe_units_as_documented():
    """The secondary-ray datapath's operations, counted by hand from its steps
    (``docs/rgs.md``): hit 3 mul 3 add; face 3 mul 2 add; dir_norm 6 mul 2 add 1 sqrt 1 div;
    offset 6 mul 6 add/sub; normal 18 mul 12 add/sub 1 sqrt 1 div; reflect 7 mul 5 add/sub.
    The light datapath (``LightPipe``): the shadow ray 3 mul 5 add/sub; the cosines 15 mul
    6 add 2 sqrt 2 div; the power 19 mul; the channels 12 mul 3 add; the hit's terms 10 mul."""
    from rtl.rgs import LightPipe, SecondaryPipe
    r = resources(lambda: SecondaryPipe(FPFormat(8, 12), tag_width=2))
    assert r["fp_units"] == {"mul": 43, "add": 30, "sqrt": 2, "div": 2}
    assert r["totals"]["flipflop_bits"] > 0 and r["totals"]["memory_bits"] == 0
    r = resources(lambda: LightPipe(FPFormat(8, 12)))
    assert r["fp_units"] == {"add": 16, "mul": 59, "sqrt": 2, "div": 2}


def test_cache_memory_bits_hold_its_data():
    from rtl.cache import Cache
    g = cache_geometry(Config(trav_cache_kb=1), "trav")
    r = resources(lambda: Cache(g))
    assert r["fp_units"] == {}
    assert r["totals"]["memory_bits"] > g.size_bytes * 8       # data and tags


@pytest.mark.filterwarnings("ignore:.*created but never used")
def test_yosys_counts_agree_with_the_netlist():
    """Through Yosys (proc, flatten, opt) a cache keeps every memory bit and the secondary-ray
    datapath one ``$mul`` per FP multiplier; optimization only removes flip-flops (constant or
    unused bits), it never adds any."""
    from rtl.cache import Cache
    from rtl.rgs import SecondaryPipe
    from saarcor.bench.resources import yosys_resources
    g = cache_geometry(Config(trav_cache_kb=1), "trav")
    net, y = resources(lambda: Cache(g)), yosys_resources(lambda: Cache(g), "cache")
    assert y["memory_bits"] == net["totals"]["memory_bits"] > g.size_bytes * 8
    assert 0 < y["flipflop_bits"] <= net["totals"]["flipflop_bits"]
    assert y["mul_cells"] == 0
    make = lambda: SecondaryPipe(FPFormat(6, 10), tag_width=2)    # noqa: E731
    net, y = resources(make), yosys_resources(make, "sec")
    assert y["mul_cells"] == net["fp_units"]["mul"] == 43
    assert y["memory_bits"] == 0
    assert 0.5 * net["totals"]["flipflop_bits"] < y["flipflop_bits"] \
        <= net["totals"]["flipflop_bits"]


def test_parse_stat_counts_flip_flop_bits_and_products():
    """Yosys' JSON statistics: flip-flop bits are count x width over every flip-flop kind,
    ``$mul`` cells by width; a report that is not one module's statistics is refused."""
    import json

    from saarcor.bench.resources import parse_stat
    mod = {"num_cells": 166138, "num_memories": 216, "num_memory_bits": 26354240,
           "num_cells_by_type": {"$dff_48": 12, "$dffe_1": 3, "$sdffe_7": 2, "$mul_48": 596,
                                 "$mul_40": 4, "$add_28": 396, "$mem_v2": 216}}
    r = parse_stat(json.dumps({"modules": {"\\chip": mod}}))
    assert r["memory_bits"] == 26354240 and r["memories"] == 216 and r["cells"] == 166138
    assert r["flipflop_bits"] == 12 * 48 + 3 + 2 * 7 and r["mul_cells"] == 600
    assert r["mul_cells_by_width"] == {40: 4, 48: 596}
    with pytest.raises(ValueError, match="one module"):
        parse_stat(json.dumps({"modules": {"\\a": mod, "\\b": mod}}))
    with pytest.raises(ValueError, match="one module"):
        parse_stat("2.64E+07 memory bits")


@pytest.fixture(scope="module")
def paper_one_rtc():
    """One RTC of the paper preset, elaborated and counted."""
    from model.config import preset
    cfg = preset("paper", rtcs=1)
    return cfg, chip_resources(cfg)


def test_paper_preset_is_at_the_papers_fp_budget(paper_one_rtc):
    """The paper's Section 5: 192 FP units for 4 RTCs with their slaves, 48 each. One RTC
    of the paper preset (``--preset paper``: the projection test, every slave datapath on one
    pool of 3 adders and 4 multipliers) elaborated: at most 48 arithmetic units (the int ->
    FP converters left out, as the paper counts), at most 4 multipliers and 3 adders beyond
    the RTC's (the traversal's 4, the projection test's 10 and 12)."""
    _, r = paper_one_rtc
    units = r["fp_units"]
    assert r["totals"]["fp_arith_units"] == sum(n for k, n in units.items() if k != "int_to_fp")
    assert r["totals"]["fp_arith_units"] <= 48, units
    assert units["mul"] <= 4 + 10 + 4 and units["add"] <= 4 + 12 + 3, units


def test_memory_by_kind_and_the_papers_way(paper_one_rtc):
    """Every memory bit has one kind; the caches' data are the paper's 64 + 64 + 144 KB; the
    traversal stack is threads x stack_depth entries of (node, mask) and, per lane, one
    value and a keep bit (the paper preset's ``trav_stack``; the paper's 34.5 bits), unpadded
    at 24 levels; the paper's register files at d levels are Section
    5.4's 287.6 KB + d x 17.25 KB."""
    from rtl.traversal import NODE_BITS
    from saarcor.bench.resources import paper_way
    cfg, r = paper_one_rtc
    kinds = r["memory_bits_by_kind"]
    assert sum(kinds.values()) == r["totals"]["memory_bits"]
    assert kinds["cache data"] == (64 + 64 + 144) * 8192
    T, D, P, w = cfg.threads, cfg.stack_depth, cfg.packet_size, cfg.fmt.width
    assert D == 24
    assert cfg.trav_stack == "one_value"
    assert kinds["traversal stack"] == T * D * (NODE_BITS + P + P * (w + 1))
    assert kinds["slave ray store"] > 0 and kinds["slave pending buffers"] > 0
    pw = paper_way(r, D)
    assert pw["paper_register_file_kb"] == pytest.approx(287.6 + 24 * 17.25)
    assert pw["cache_kb"] + pw["register_file_kb"] == pytest.approx(r["totals"]["memory_kb"])
