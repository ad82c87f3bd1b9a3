"""Intersection datapath, ``Config.int_test = "projection"``: the paper's triangle test.

:class:`ProjectionPipe` is ``model.intersection_projection.intersect_projection`` as a
pipeline (the projection test of Wald et al. 2001 on a precomputed triangle record,
``model.layout.projection_records``), built from the FP units of ``rtl/fp`` like
:class:`rtl.intersection.IntersectPipe`, whose place it takes in the intersection unit.
"""
from __future__ import annotations

from amaranth.hdl import Const, Mux
from amaranth.lib import data
from amaranth.lib.wiring import In

from model.fp import FPFormat
from model.layout import PROJ_K_BIT

from .fp.cmp import compare
from .fp.common import unpack
from .fp.schedule import Schedule as _Schedule
from .triangle_pipe import TrianglePipe, pick

__all__ = ["PROJ_K_BIT", "ProjectionPipe"]


class ProjectionPipe(TrianglePipe):
    """Bare projection-test datapath: ``model.intersection_projection.intersect_projection``.

    In: ``tri`` (9 format words of the record: n_u, n_v, n_d, b_nu, b_nv, b_d, c_nu, c_nv,
    c_d), ``tri_k`` (the record's axis k), ``org`` (3), ``dir`` (3), ``tag`` (carried along
    unchanged), ``i_valid``, ``en``. Out after ``latency`` enabled cycles: ``o_valid``, ``hit``
    (lambda >= 0, mu >= 0, lambda + mu <= 1), ``t``, ``u`` (lambda, the weight of B), ``v``
    (mu, of C), zero when not ``hit``, ``o_tag``; ``pre_tag``, ``pre2_tag``: the tag one and
    two stages earlier. The same outputs as ``IntersectPipe``.

    Operations (all rounded to the format, the model's order): 2 muls + 2 adds (the
    direction's component along the normal), 2 muls + 3 subs (the origin's distance to the
    plane), 1 div (t), 2 muls + 2 adds (the hit point in the projection plane), 4 muls + 4
    adds (lambda, mu), 1 add (lambda + mu) and three compares: 12 add/sub, 10 mul, 1 div. The
    operands are registered first (they come from block RAM); the verdict and t, u, v are
    registered once more after the last add (the compares' logic ends at a register).
    Latency (binary32, default FP latencies 3/3/8): 37 cycles.
    Throughput: one test per cycle in which ``en`` is 1 (``en`` = 0 holds every stage).
    ``latencies``: optional ``{"add": n, "mul": n, "div": n}`` for the FP units.
    """

    def __init__(self, fmt: FPFormat, tag_width: int = 1, latencies: dict | None = None):
        w = fmt.width
        super().__init__(fmt, tag_width, latencies, {
            "tri": In(data.ArrayLayout(w, 9)), "tri_k": In(2),
            "org": In(data.ArrayLayout(w, 3)), "dir": In(data.ArrayLayout(w, 3))})

    def _build(self, m, dry=False):
        fmt, w = self.fmt, self.fmt.width
        sch = _Schedule(m, self.en, fmt, self.latencies, dry)
        # the operands are registered first (they come straight from block RAM in the unit)
        t0 = 1
        k = sch.at(self.tri_k, 0, t0)
        ku = self._wire(m, Mux(k == 2, 0, k + 1), "ku")
        kv = self._wire(m, Mux(k == 0, 2, k - 1), "kv")
        rec = [(sch.at(self.tri[i], 0, t0), t0) for i in range(9)]
        org = [sch.at(self.org[i], 0, t0) for i in range(3)]
        dirn = [sch.at(self.dir[i], 0, t0) for i in range(3)]
        # one mux each, shared by every use
        ok, ou, ov = ((self._wire(m, pick(org, a), f"o{n}_pick"), t0)
                      for a, n in ((k, "k"), (ku, "u"), (kv, "v")))
        dk, du, dv = ((self._wire(m, pick(dirn, a), f"d{n}_pick"), t0)
                      for a, n in ((k, "k"), (ku, "u"), (kv, "v")))
        n_u, n_v, n_d, b_nu, b_nv, b_d, c_nu, c_nv, c_d = rec
        # -- the distance along the ray to the plane -----------------------------------------------
        nd = sch.op("add", sch.op("add", dk, sch.op("mul", n_u, du, "nu_du"), "nd_u"),
                    sch.op("mul", n_v, dv, "nv_dv"), "nd")
        num = sch.op("sub", sch.op("sub", sch.op("sub", n_d, ok, "num_k"),
                                   sch.op("mul", n_u, ou, "nu_ou"), "num_u"),
                     sch.op("mul", n_v, ov, "nv_ov"), "num")
        f = sch.op("div", num, nd, "f")
        # -- the hit point in the projection plane, its barycentric weights ----------------------
        hu = sch.op("add", ou, sch.op("mul", f, du, "f_du"), "hu")
        hv = sch.op("add", ov, sch.op("mul", f, dv, "f_dv"), "hv")
        lam = sch.op("add", sch.op("add", sch.op("mul", hu, b_nu, "hu_bnu"),
                                   sch.op("mul", hv, b_nv, "hv_bnv"), "lam_uv"), b_d, "lam")
        mu = sch.op("add", sch.op("add", sch.op("mul", hu, c_nu, "hu_cnu"),
                                  sch.op("mul", hv, c_nv, "hv_cnv"), "mu_uv"), c_d, "mu")
        s = sch.op("add", lam, mu, "lam_mu")
        # -- the verdict: lambda >= 0, mu >= 0 (-0 too; NaN never), lambda + mu <= 1 ---------------
        ge0 = [self._wire(m, ~(x.sign & ~x.zero) & ~x.nan, f"{n}_ge0")
               for x, n in ((unpack(fmt, lam[0]), "lam"), (unpack(fmt, mu[0]), "mu"))]
        one = Const(fmt.bias << fmt.frac_bits, w)
        le1 = self._wire(m, compare(fmt, s[0], one).le, "sum_le1")
        L0 = s[1]
        hit0 = sch.at(ge0[0], lam[1], L0) & sch.at(ge0[1], mu[1], L0) & le1
        L = L0 + 1                                        # verdict and results registered
        hit = sch.at(self._wire(m, hit0, "hit_d"), L0, L)
        return self._outputs(m, sch, hit, f, lam, mu, L, dry)
