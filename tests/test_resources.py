"""``tb.resources``: FP units by kind and memory bits counted from a component's netlist."""
import pytest

from model.cache import cache_geometry
from model.config import Config
from model.fp import FPFormat
from tb.resources import resources


@pytest.mark.filterwarnings("ignore:.*created but never used")
def test_secondary_pipe_units_as_documented():
    """The secondary-ray datapath's operations, counted by hand from its steps
    (``docs/rgs.md``): hit 3 mul 3 add; face 3 mul 2 add; dir_norm 6 mul 2 add 1 sqrt 1 div;
    offset 6 mul 6 add/sub; normal 18 mul 12 add/sub 1 sqrt 1 div; reflect 7 mul 5 add/sub."""
    from rtl.rgs import SecondaryPipe, ShadowPipe
    r = resources(lambda: SecondaryPipe(FPFormat(8, 12), tag_width=2))
    assert r["fp_units"] == {"mul": 43, "add": 30, "sqrt": 2, "div": 2}
    assert r["totals"]["flipflop_bits"] > 0 and r["totals"]["memory_bits"] == 0
    r = resources(lambda: ShadowPipe(FPFormat(8, 12)))
    assert r["fp_units"] == {"add": 5, "mul": 3}


def test_cache_memory_bits_hold_its_data():
    from rtl.cache import Cache
    g = cache_geometry(Config(trav_cache_kb=1), "trav")
    r = resources(lambda: Cache(g))
    assert r["fp_units"] == {}
    assert r["totals"]["memory_bits"] > g.size_bytes * 8       # data and tags
