"""cocotb benches of the intersection datapath's and unit's exported Verilog (tops
``intersect_pipe`` and ``intersection``).

:func:`run_pipe`: ray/triangle tests (``tb.intersection.random_tests``: hits, exact edge and
vertex hits, degenerate triangles, overflow, tiny values; or ``golden_tests``: a traced
scene's int-ops) through the fixed-latency datapath, every output at its exact cycle: the FP
units' bench (:func:`tb.cocotb.fp.fixed_latency`) with the datapath's ports
(``tb.intersection.pipe_ports``).
"""
from __future__ import annotations


def run_pipe(tests, sim: str, run_dir, *, fmt=None, seed: int = 0, p_bubble: float = 0.2,
             p_stall: float = 0.2, **build_kw):
    """``tests`` (a ``tb.intersection.PipeTests``) through the exported ``intersect_pipe``."""
    from model.config import Config
    from model.fp import BINARY32
    from rtl.export import build_top
    from tb.intersection import pipe_ports

    from .fp import run_fixed_latency
    from .runner import build
    cfg = Config(fmt=fmt or BINARY32)
    pipe = build_top("intersect_pipe", cfg)
    ins, outs = pipe_ports(tests, cfg.fmt, pipe.tag_width)
    b = build("intersect_pipe", cfg, sim, **build_kw)
    return run_fixed_latency(b, run_dir, ins, outs, pipe.latency, seed=seed,
                             p_bubble=p_bubble, p_stall=p_stall)
