"""RGS slave: a hit's secondary rays and their colour, in FP hardware.

The golden model is ``model/rgs/secondary.py`` (``secondary``, ``shadow_dir``,
``light_colour``, ``hit_colour``, ``to_fixed``); every FP operation here is one of its steps,
in its order (``docs/rgs.md``).

* :class:`SecondaryPipe`: a hit -> the secondary rays' origin, the oriented face and shading
  normals and the reflected direction (``hit``, ``face``, ``dir_norm``, ``offset``,
  ``normal``, ``reflect``).
* :class:`LightPipe`: (origin, normals, light, material) -> the shadow ray's direction, tmax
  and whether it is cast, and the colour contributions (:func:`to_fixed`: fixed point).
* :class:`ShadePool`: both datapaths on one pool of FP units.
* :class:`SlavePool`: those two, the eye rays' and the ray setup's on one pool
  (``Config.rgs_fp_pool``).
"""
from __future__ import annotations

from amaranth.hdl import Cat, Const, Elaboratable, Module, Mux, Value
from amaranth.lib import data
from amaranth.lib.wiring import In, Out

from model.fp import FPFormat
from model.layout import SHIN_BITS
from model.rgs.secondary import FIX_BITS, FIX_FRAC, FIX_MAX

from ..fp.common import bits_for, unpack, wire
from ..fp.schedule import Schedule, Share
from .common import _Datapath, _fp_const, _valid_chain

__all__ = ["SecondaryPipe", "LightPipe", "ShadePool", "SlavePool", "to_fixed"]


def _dot(sch: Schedule, a: list, b: list, name: str) -> tuple:
    """``dot``: (a0*b0 + a1*b1) + a2*b2 on scheduled values."""
    p = [sch.op("mul", a[i], b[i], f"{name}_m{i}") for i in range(3)]
    return sch.op("add", sch.op("add", p[0], p[1], f"{name}_a0"), p[2], f"{name}_a1")


def _positive(fmt: FPFormat, x: Value) -> Value:
    """x > 0 (a NaN is not; a denormal encoding reads as zero)."""
    u = unpack(fmt, x)
    return ~u.sign & ~u.zero & ~u.nan


def _negative(fmt: FPFormat, x: Value) -> Value:
    """x < 0 (-0 and NaN are not)."""
    u = unpack(fmt, x)
    return u.sign & ~u.zero & ~u.nan


def _neg_if(fmt: FPFormat, x: Value, cond: Value) -> Value:
    """-x where ``cond`` (the sign bit flipped; a NaN stays the canonical NaN), else x."""
    sign = Const(1 << (fmt.width - 1), fmt.width)
    return Mux(cond & ~unpack(fmt, x).nan, x ^ sign, x)


class SecondaryPipe(_Datapath):
    """Bare secondary-ray datapath: ``model.rgs.secondary`` as a pipeline.

    In: ``org``, ``dir`` (the ray, 3 format words each), ``t``, ``u``, ``v`` (its hit), ``nf``
    (the triangle's unit face normal), ``nv`` (vertex normals A, B, C: 3 x 3 words), ``tag``
    (carried along), ``i_valid``, ``en``; ``eps`` (the offset register, constant while rays are
    in flight). Out after ``latency`` enabled cycles: ``o_valid``, ``p0`` (the secondary rays'
    origin), ``g`` (face normal turned toward the ray), ``n`` (shading normal), ``r`` (reflected
    direction), ``o_tag``.

    Operations (the model's steps, ``docs/rgs.md``): ``hit`` 3 mul + 3 add, ``face`` a dot
    product (3 mul, 2 add) and a sign flip, ``dir_norm`` a dot product, a square root, a
    reciprocal (div) and 3 mul, ``offset`` 6 mul + 3 add + 3 sub, ``normal`` 2 sub, 9 mul,
    6 add, a dot product, a square root, a reciprocal, 3 mul, a zero test and mux and a dot
    product for the side, ``reflect`` a dot product, 1 mul by 2, 3 mul, 3 sub: 43 mul, 30
    add/sub, 2 sqrt, 2 div in all. Latency ``latency`` (binary32 with the default FP latencies:
    add 3, mul 3, div 8, sqrt 8 gives 70: ``normal``'s chain of two dot products, square
    root, reciprocal and the reflection ends the longest path). Throughput: one hit per cycle
    in which ``en`` is 1.
    ``latencies``: optional ``{"add": n, "mul": n, "div": n, "sqrt": n}``.

    ``refract`` (default off: the datapath above, unchanged): also the refracted ray
    (``model.rgs.refract``, ``docs/rgs.md``): inputs ``eta_in``, ``eta_out`` (the material's
    1 / ior and ior), outputs ``tp0``, ``tdir`` (its origin and direction: ``p0`` and ``r``
    where ``tir``) and ``tir`` (total internal reflection). It shares ``face``,
    ``dir_norm``, ``hit`` and ``offset``'s products and adds 13 mul, 14 add/sub, 1 sqrt;
    latency 90 at the binary32 defaults (70 without: the refraction ends 38 cycles after ``n``).
    """

    def __init__(self, fmt: FPFormat, tag_width: int = 1, latencies: dict | None = None,
                 budget: dict | None = None, refract: bool = False):
        w = fmt.width
        v3 = data.ArrayLayout(w, 3)
        self.refract = refract
        ins, outs = {}, {}
        if refract:
            ins = {"eta_in": In(w), "eta_out": In(w)}
            outs = {"tp0": Out(v3), "tdir": Out(v3), "tir": Out(1)}
        super().__init__(fmt, tag_width, latencies,
                         {"org": In(v3), "dir": In(v3), "t": In(w), "u": In(w), "v": In(w),
                          "nf": In(v3), "nv": In(data.ArrayLayout(v3, 3)), "eps": In(w), **ins},
                         {"p0": Out(v3), "g": Out(v3), "n": Out(v3), "r": Out(v3), **outs},
                         budget)

    def _build(self, m: Module, dry: bool = False) -> int:
        return self._emit(m, self._schedule(m, dry), dry)

    def _graph(self, m: Module, sch: Schedule, t0: int, dry: bool) -> tuple:
        """The operations, inputs ready at cycle ``t0``: ``(L, outputs)``, the cycle the
        outputs are ready in and ``{port name: value}`` (None when ``dry``)."""
        fmt = self.fmt
        at = sch.at
        vec = lambda port, name: [(wire(m, port[a], f"{name}{a}"), t0) for a in range(3)]  # noqa: E731
        d, o, nf = vec(self.dir, "d"), vec(self.org, "o"), vec(self.nf, "nf")
        nv = [vec(self.nv[c], f"nv{c}_") for c in range(3)]
        t, u, v, eps = ((wire(m, x, name), t0) for x, name in
                        ((self.t, "t"), (self.u, "u"), (self.v, "v"), (self.eps, "eps")))
        one = (_fp_const(fmt, "one"), t0)
        # -- face: g = -nf if dot(nf, d) > 0 -------------------------------------------------
        dn = _dot(sch, nf, d, "face_dot")
        flip = wire(m, _positive(fmt, dn[0]), "face_flip")
        g = [(wire(m, _neg_if(fmt, at(nf[a][0], t0, dn[1]), flip), f"g{a}"), dn[1])
             for a in range(3)]
        # -- dir_norm: w = d * (1 / sqrt(dot(d, d))) -----------------------------------------
        rl = sch.op("div", one, sch.op("sqrt", _dot(sch, d, d, "dir_dot"), None, "dir_len"),
                    "dir_rcp")
        w_ = [sch.op("mul", d[a], rl, f"w{a}") for a in range(3)]
        # -- hit, offset: p0 = (o + t*d + eps*g) - eps*w --------------------------------------
        p = [sch.op("add", o[a], sch.op("mul", t, d[a], f"hit_m{a}"), f"hit{a}") for a in range(3)]
        eg, ew, p0 = [], [], []
        for a in range(3):               # (the operations in the order of one expression)
            eg.append(sch.op("mul", eps, g[a], f"off_g{a}"))
            pa = sch.op("add", p[a], eg[a], f"off_a{a}")
            ew.append(sch.op("mul", eps, w_[a], f"off_w{a}"))
            p0.append(sch.op("sub", pa, ew[a], f"p0_{a}"))
        # -- normal: interpolate, normalize (g where the sum is zero), turn to g's side --------
        b = sch.op("sub", sch.op("sub", one, u, "bary_1u"), v, "bary_b")
        s = [sch.op("add", sch.op("add", sch.op("mul", b, nv[0][a], f"nrm_b{a}"),
                                  sch.op("mul", u, nv[1][a], f"nrm_u{a}"), f"nrm_a{a}"),
                    sch.op("mul", v, nv[2][a], f"nrm_v{a}"), f"nrm_s{a}") for a in range(3)]
        q = _dot(sch, s, s, "nrm_dot")
        rn = sch.op("div", one, sch.op("sqrt", q, None, "nrm_len"), "nrm_rcp")
        s1 = [sch.op("mul", s[a], rn, f"nrm_n{a}") for a in range(3)]
        tn = max(x[1] for x in s1)
        zero = wire(m, unpack(fmt, at(q[0], q[1], tn)).zero, "nrm_zero")
        n1 = [(wire(m, Mux(zero, at(g[a][0], g[a][1], tn), at(*s1[a], tn)), f"nrm_sel{a}"), tn)
              for a in range(3)]
        side = _dot(sch, n1, g, "side_dot")
        back = wire(m, _negative(fmt, side[0]), "side_flip")
        n = [(wire(m, _neg_if(fmt, at(n1[a][0], tn, side[1]), back), f"n{a}"), side[1])
             for a in range(3)]
        # -- reflect: r = d - (2 * dot(d, n)) * n ---------------------------------------------
        two = (Const(fmt.to_bits(2.0).item(), fmt.width), t0)
        k = sch.op("mul", two, _dot(sch, d, n, "refl_dot"), "refl_k")
        r = [sch.op("sub", d[a], sch.op("mul", k, n[a], f"refl_m{a}"), f"r{a}") for a in range(3)]
        rf = self._refract(m, sch, t0, dn[1], flip, w_, n, p, eg, ew) if self.refract else None
        L = max(x[1] for x in (*p0, *g, *n, *r, *(rf[0] + rf[1] + [rf[2]] if rf else [])))
        if dry:
            return L, None
        out = lambda xs: Cat(*(at(x[0], x[1], L) for x in xs))  # noqa: E731
        outs = {"p0": out(p0), "g": out(g), "n": out(n), "r": out(r),
                "o_tag": at(self.tag, t0, L)}
        if rf:
            pt, td, tir = rf
            tir_l = at(tir[0], tir[1], L)
            outs.update(tp0=Mux(tir_l, out(p0), out(pt)), tdir=Mux(tir_l, out(r), out(td)),
                        tir=tir_l)
        return L, outs

    def _refract(self, m: Module, sch: Schedule, t0: int, tf: int, flip: Value, w_: list,
                 n: list, p: list, eg: list, ew: list) -> tuple:
        """``model.rgs.refract``'s steps on the secondary datapath's values (``flip`` the face
        test, ready at ``tf``; ``w``, ``n``, ``p`` and the offset's products ``eps*g``,
        ``eps*w``): (origin, direction, tir), the first two before the tir mux."""
        fmt, at = self.fmt, sch.at
        one = (_fp_const(fmt, "one"), t0)
        eta = (wire(m, Mux(flip, at(self.eta_out, t0, tf), at(self.eta_in, t0, tf)),
                    "rfr_eta"), tf)
        cd = _dot(sch, w_, n, "rfr_dot")
        c = (wire(m, _neg_if(fmt, cd[0], Const(1, 1)), "rfr_c"), cd[1])
        s2 = sch.op("sub", one, sch.op("mul", c, c, "rfr_c2"), "rfr_s2")
        k = sch.op("sub", one, sch.op("mul", sch.op("mul", eta, eta, "rfr_e2"), s2, "rfr_es"),
                   "rfr_k")
        tir = (wire(m, _negative(fmt, k[0]), "rfr_tir"), k[1])
        mu = sch.op("sub", sch.op("mul", eta, c, "rfr_ec"), sch.op("sqrt", k, None, "rfr_root"),
                    "rfr_mu")
        td = [sch.op("add", sch.op("mul", eta, w_[a], f"rfr_ew{a}"),
                     sch.op("mul", mu, n[a], f"rfr_mn{a}"), f"rfr_t{a}") for a in range(3)]
        pt = [sch.op("add", sch.op("sub", p[a], eg[a], f"rfr_pg{a}"), ew[a], f"rfr_p{a}")
              for a in range(3)]
        return pt, td, tir


# ---------------------------------------------------------------------------------------------
# colour
# ---------------------------------------------------------------------------------------------

def to_fixed(fmt: FPFormat, x: Value) -> Value:
    """``model.rgs.to_fixed`` (combinational): floor(x * 2**FIX_FRAC) as FIX_BITS bits; 0 for a
    NaN, a zero or a negative x, all ones from 2**(FIX_BITS - FIX_FRAC) up. For
    0 < x < 2**8, x * 2**FIX_FRAC = sig * 2**(exp - bias - M + FIX_FRAC) with the significand
    ``sig`` (hidden bit included): ``sig`` padded with ``pad`` zeros and shifted right by
    ``c - exp`` (never negative there)."""
    u = unpack(fmt, x)
    M = fmt.frac_bits
    pad = max(0, (FIX_BITS - FIX_FRAC - 1) + FIX_FRAC - M)     # the largest left shift
    c = pad + fmt.bias + M - FIX_FRAC
    big = u.exp >= fmt.bias + (FIX_BITS - FIX_FRAC)
    shifted = (Cat(Const(0, pad), u.sig) >> (c - u.exp)[:bits_for(c)])[:FIX_BITS]
    return Mux(u.sign | u.zero | u.nan, 0, Mux(big, FIX_MAX, shifted))


class LightPipe(_Datapath):
    """The shadow ray of a (hit, light) pair and its colour: the shadow ray
    (``model.rgs.shadow_dir``), the Phong term the ray brings if it reaches its light
    (``model.rgs.light_colour``) and the hit's own terms (``model.rgs.hit_colour``), each made
    a fixed-point contribution (``model.rgs.to_fixed``), as a pipeline.

    In: ``p0``, ``g`` (the hit's secondary origin and oriented face normal, from
    :class:`SecondaryPipe`), ``light`` (3 format words: a point light's position, or a
    parallel light's reversed direction), ``point`` (1: point light); ``n``, ``r`` (the hit's
    shading normal and reflected direction, from :class:`SecondaryPipe`); ``kd``, ``ks``,
    ``kr``, ``shin`` (the material's record constants); ``lc`` (the light's colour), ``wt``
    (the hit ray's weight); registers ``amb``, ``bg``; ``tag``, ``i_valid``, ``en``. Out after
    ``latency`` enabled cycles: ``o_p0``, ``o_r`` (carried along), ``dir`` (light - p0, or the
    light vector itself for a parallel light), ``tmax`` (1 for a point light, +inf for a
    parallel one), ``cast`` (dot(g, dir) > 0: the light faces the surface; no ray otherwise),
    ``col`` (the light's contribution, 3 x ``FIX_BITS``), ``amb_col``
    (the ambient contribution), ``wr`` (the reflection ray's weight), ``rmiss`` (the reflection
    ray's contribution if it misses), ``o_tag``.

    Operations: the shadow ray's 3 sub, 3 mul, 2 add; four dot products (ld.ld, r.r, n.ld,
    r.ld: 12 mul, 8 add), 2 sqrt, 2 div (reciprocals), 3 mul, 2 clamps at +0 (a mux each, in
    a min/max unit's latency), the power by squaring (19 mul, 10 muxes), per channel 4 mul and
    an add; the hit's terms 10 mul: 59 mul, 16 add/sub, 2 sqrt, 2 div in all. Latency: the power's chain of 10 multiplications
    after the two reciprocals, then a fixed-point conversion (75 at the binary32 defaults).
    Throughput: one pair per enabled cycle.
    """

    def __init__(self, fmt: FPFormat, tag_width: int = 1, latencies: dict | None = None,
                 budget: dict | None = None):
        w = fmt.width
        v3 = data.ArrayLayout(w, 3)
        f3 = data.ArrayLayout(FIX_BITS, 3)
        super().__init__(fmt, tag_width, latencies,
                         {"p0": In(v3), "g": In(v3), "light": In(v3), "point": In(1),
                          "n": In(v3), "r": In(v3), "kd": In(v3), "ks": In(v3), "kr": In(w),
                          "shin": In(SHIN_BITS), "lc": In(v3), "wt": In(w), "amb": In(w),
                          "bg": In(v3)},
                         {"o_p0": Out(v3), "o_r": Out(v3), "dir": Out(v3), "tmax": Out(w),
                          "cast": Out(1), "col": Out(f3), "amb_col": Out(f3), "wr": Out(w),
                          "rmiss": Out(f3)}, budget)

    def _build(self, m: Module, dry: bool = False) -> int:
        return self._emit(m, self._schedule(m, dry), dry)

    def _graph(self, m: Module, sch: Schedule, t0: int, dry: bool) -> tuple:
        """The operations, inputs ready at cycle ``t0``: ``(L, outputs)``, the cycle the
        outputs are ready in and ``{port name: value}`` (None when ``dry``)."""
        fmt = self.fmt
        at = sch.at
        # -- the shadow ray (model.rgs.shadow_dir) ----------------------------------------------
        point = wire(m, self.point, "point")
        sub = [sch.op("sub", (self.light[a], t0), (self.p0[a], t0), f"ldir{a}")
               for a in range(3)]
        ts = max(x[1] for x in sub)
        ds = [(wire(m, Mux(at(point, t0, ts), at(*sub[a], ts), at(self.light[a], t0, ts)),
                    f"dir{a}"),
               ts) for a in range(3)]
        face = _dot(sch, [(self.g[a], t0) for a in range(3)], ds, "face_dot")
        vec = lambda port, name: [(wire(m, port[a], f"{name}{a}"), t0) for a in range(3)]  # noqa: E731
        n, r, kd, ks = vec(self.n, "n"), vec(self.r, "r"), vec(self.kd, "kd"), vec(self.ks, "ks")
        lc, bg = vec(self.lc, "lc"), vec(self.bg, "bg")
        wt, kr, amb = ((wire(m, x, name), t0) for x, name in
                       ((self.wt, "wt"), (self.kr, "kr"), (self.amb, "amb")))
        shin = wire(m, self.shin, "shin")
        one = (_fp_const(fmt, "one"), t0)
        # -- light: il = 1 / |ld|, ir = 1 / |r|; ndl, rdl clamped at +0 -----------------------
        il = sch.op("div", one, sch.op("sqrt", _dot(sch, ds, ds, "ll_dot"), None, "ll_len"),
                    "ll_rcp")
        ir = sch.op("div", one, sch.op("sqrt", _dot(sch, r, r, "rr_dot"), None, "rr_len"),
                    "rr_rcp")
        def clamp0(x, name):             # max(x, +0) as FPMinMax gives it, in its latency:
            u = unpack(fmt, x[0])        # +0 for a NaN or a value below zero (-0 stays)
            v = wire(m, Mux(u.nan | (u.sign & ~u.zero), 0, x[0]), name)
            t = x[1] + self.latencies["max"]
            return at(v, x[1], t), t
        ndl = clamp0(sch.op("mul", _dot(sch, n, ds, "nl_dot"), il, "ndl_m"), "ndl")
        rdl = clamp0(sch.op("mul", sch.op("mul", _dot(sch, r, ds, "rl_dot"), il, "rdl_m0"),
                            ir, "rdl_m1"), "rdl")
        # -- spec = rdl ** shin, by squaring ---------------------------------------------------
        acc, p = one, rdl
        for i in range(SHIN_BITS):
            prod = sch.op("mul", acc, p, f"pow_acc{i}")
            t = prod[1]
            bit = at(shin[i], t0, t)
            acc = (wire(m, Mux(bit, prod[0], at(acc[0], acc[1], t)), f"pow_sel{i}"), t)
            if i < SHIN_BITS - 1:
                p = sch.op("mul", p, p, f"pow_sq{i}")
        # -- per channel: ((kd * ndl) + (ks * spec)) * (lc * wt) -------------------------------
        col = [sch.op("mul", sch.op("add", sch.op("mul", kd[c], ndl, f"dif{c}"),
                                    sch.op("mul", ks[c], acc, f"spc{c}"), f"sum{c}"),
                      sch.op("mul", lc[c], wt, f"lw{c}"), f"col{c}") for c in range(3)]
        # -- the hit's own terms ---------------------------------------------------------------
        wr = sch.op("mul", wt, kr, "wr")
        amb_c = [sch.op("mul", sch.op("mul", kd[c], amb, f"ka{c}"), wt, f"amb{c}")
                 for c in range(3)]
        rmiss = [sch.op("mul", bg[c], wr, f"rmiss{c}") for c in range(3)]
        F = max(x[1] for x in (*col, *amb_c, *rmiss))      # the fixed-point conversions' cycle
        L = F + 1
        if dry:
            return L, None
        fixed = lambda xs, name: Cat(*(at(wire(m, to_fixed(fmt, at(x[0], x[1], F)),  # noqa: E731
                                               f"{name}{c}"), F, L)
                                       for c, x in enumerate(xs)))
        return L, {
            "o_p0": Cat(*(at(self.p0[a], t0, L) for a in range(3))),
            "o_r": Cat(*(at(x[0], x[1], L) for x in r)),
            "dir": Cat(*(at(x[0], x[1], L) for x in ds)),
            "tmax": Mux(at(point, t0, L), _fp_const(fmt, "one"), _fp_const(fmt, "+inf")),
            "cast": at(_positive(fmt, face[0]), face[1], L),
            "col": fixed(col, "fix_col"), "amb_col": fixed(amb_c, "fix_amb"),
            "wr": at(wr[0], wr[1], L), "rmiss": fixed(rmiss, "fix_rmiss"),
            "o_tag": at(self.tag, t0, L)}


class ShadePool(Elaboratable):
    """The shading datapaths on one pool of FP units: :class:`SecondaryPipe` and ``copies``
    copies of :class:`LightPipe`'s operation graph in one modulo schedule over ``budget``
    (``{"add": n, "mul": n}``, the paper's 3 and 4 for the shading), so the units serve
    whichever datapath has an operation in a phase.

    ``sec`` and ``shd`` are the two datapaths' components: their ports are the pool's (the
    pool drives their outputs; their own ``elaborate`` is not used, and ``en`` is not: the
    pool never stalls, so its consumers must take every output). In each interval of ``ii``
    cycles ``sec`` takes a hit in phase 0 (``sec.i_slot``) and ``shd`` a (hit, light) token
    in each of the phases ``t0`` (``shd.i_slot``; ``copies`` of them, spread over the
    interval): ``ii`` is the least interval at which the budget takes ``SecondaryPipe``'s
    operations and ``copies`` times ``LightPipe``'s. Every copy's outputs are delayed to one
    latency (``shd.latency``), so tokens leave in the order they entered, in distinct
    cycles, and ``shd`` looks like one pipe taking ``copies`` inputs per interval."""

    def __init__(self, fmt: FPFormat, sec_tag_width: int, shd_tag_width: int,
                 latencies: dict | None, budget: dict, copies: int, refract: bool = False):
        if copies < 1:
            raise ValueError(f"ShadePool: copies={copies}; LightPipe needs at least one")
        if not budget:
            raise ValueError("ShadePool: an FP unit budget ({'add': n, 'mul': n}) is needed")
        self.fmt, self.copies = fmt, copies
        self.sec = SecondaryPipe(fmt, sec_tag_width, latencies, refract=refract)
        self.shd = LightPipe(fmt, shd_tag_width, latencies)
        self.sec._MustUse__silence = self.shd._MustUse__silence = True   # ports only
        self.groups = [((self.shd,), copies, 0)] + list(self.more)
        pipes = [p for chain, _, _ in self.more for p in chain]
        self.counts = {c: self.sec.counts[c] + sum(n * sum(p.counts.get(c, 0) for p in chain)
                                                   for chain, n, _ in self.groups)
                       for c in self.sec.counts}
        self.share = Share.for_budget(self.counts, dict(budget), min_ii=max(2, copies))
        self.ii = ii = self.share.ii
        self.units = dict(self.share.units)
        self.t0 = self._t0s(0)
        sec_l, lats = self._build(_Datapath._dry(), dry=True)
        shd_l = lats[0][0]
        for pipe, lat, per in ((self.sec, sec_l, 1),
                               *((p, lat, n) for (chain, n, _), ls in zip(self.groups, lats)
                                 for p, lat in zip(chain, ls))):
            pipe.latency, pipe.ii, pipe.per_ii = lat, ii, per
            pipe.share, pipe.units = self.share, self.units
        self.latency = max(sec_l, shd_l)
        self.pipes = pipes

    #: further datapaths on the pool: ``(chain, copies, phase)``, a chain of pipes (each fed by
    #: the one before it; ``copies`` > 1 only for a chain of one) taking ``copies`` inputs an
    #: interval, the first in ``phase`` (a fraction of the interval)
    more: tuple = ()

    def _t0s(self, g: int) -> list:
        """The cycles (phases) group ``g``'s copies take their inputs in: spread over the
        interval from the group's phase."""
        _, n, phase = self.groups[g]
        return [int(phase * self.ii) + j * self.ii // n for j in range(n)]

    def _build(self, m: Module, dry: bool = False) -> tuple:
        """Every graph on one schedule: ``(sec latency, [[latency of each pipe] per group]``
        (a group's copies all at one latency: each copy's outputs delayed to the longest, so
        inputs leave in the order they entered, in distinct cycles, and the copies look like
        one pipe taking ``copies`` inputs per interval)."""
        sec = self.sec
        sch = Schedule(m, Const(1, 1), self.fmt, sec.latencies, dry, self.share)
        ls = sec._emit(m, sch, dry, en=Const(1, 1))        # as alone, on the pool's schedule
        if not dry:
            m.d.comb += sec.i_slot.eq(sch.slot)
        lats = []
        for g, (chain, n, _) in enumerate(self.groups):
            t0s = self._t0s(g)
            if len(chain) > 1:                             # a chain: one copy
                t, ls_g = t0s[0], []
                for j, pipe in enumerate(chain):
                    L, outs = pipe._graph(m, sch, t, dry)
                    ls_g.append(L - t)
                    if not dry:
                        v = _valid_chain(m, Const(1, 1), pipe.i_valid & sch.slot_at(t), L - t,
                                         f"g{g}_{j}_valid")
                        m.d.comb += [pipe.i_slot.eq(sch.slot_at(t)), pipe.o_valid.eq(v)]
                        m.d.comb += [getattr(pipe, k).eq(x) for k, x in outs.items()]
                    t = L
                lats.append(ls_g)
                continue
            pipe = chain[0]
            graphs = [pipe._graph(m, sch, t, dry) for t in t0s]
            lmax = max(L - t for (L, _), t in zip(graphs, t0s))
            lats.append([lmax])
            if dry:
                continue
            valids, outs = [], {}
            for j, ((L, o), t) in enumerate(zip(graphs, t0s)):
                v = _valid_chain(m, Const(1, 1), pipe.i_valid & sch.slot_at(t), lmax,
                                 f"g{g}_{j}_valid")
                for k, x in o.items():
                    x = sch.at(x, L, t + lmax)
                    outs[k] = x if j == 0 else Mux(v, x, outs[k])
                valids.append(v)
            m.d.comb += [pipe.i_slot.eq(Cat(*(sch.slot_at(t) for t in t0s)).any()),
                         pipe.o_valid.eq(Cat(*valids).any())]
            m.d.comb += [getattr(pipe, k).eq(v) for k, v in outs.items()]
        return ls, lats

    def elaborate(self, platform):
        m = Module()
        self._build(m)
        return m


class SlavePool(ShadePool):
    """Every ray datapath of the slave on one pool of FP units (``Config.rgs_fp_pool``): the
    shading's (:class:`ShadePool`'s SecondaryPipe and LightPipe entries), the eye rays'
    (``eye``: an :class:`~rtl.rgs.EyeRays` built ``pooled``; its EyeRayPipe feeds its
    RaySetupPipe, one chain) and ``setup_copies`` entries of the secondary rays' ray setup
    (``setup``: a :class:`~rtl.rgs.RaySetup` built ``pooled``; a hit spawns up to a shadow ray
    per light, a reflection ray and, with ``refract``, a refracted ray: SecondaryPipe is
    then built with its refraction), in one modulo schedule over ``budget``.

    In each interval of ``ii`` cycles SecondaryPipe takes a hit (phase 0), LightPipe
    ``copies`` (hit, light) tokens (from phase 0), the eye rays one sample (phase ``ii / 4``),
    the ray setup ``setup_copies`` rays (from phase ``ii / 2``) and, with ``tex`` (a
    :class:`~rtl.rgs.Texture` built ``pooled``), its TexCoordPipe and TexFilterPipe a hit each
    (phases ``3 ii / 4``, ``7 ii / 8``); ``ii`` is the least interval at which the budget takes
    all their operations. The pool never stalls: the eye rays, the ray setup and the texture
    unit put their outputs into queues as deep as their inputs in flight and take an input
    only while there is room (``rtl.rgs.eye``, ``rtl.rgs.texture``). Latency: each
    datapath's own, plus the cycles its operations wait for a free unit."""

    def __init__(self, fmt: FPFormat, sec_tag_width: int, shd_tag_width: int,
                 latencies: dict | None, budget: dict, copies: int, eye, setup,
                 setup_copies: int = 1, tex=None, refract: bool = False):
        if setup_copies < 1:
            raise ValueError(f"SlavePool: setup_copies={setup_copies} must be at least 1")
        self.more = (((eye.gen, eye.setup), 1, 1 / 4), ((setup.pipe,), setup_copies, 1 / 2),
                     *((((tex.coord,), 1, 3 / 4), ((tex.filter,), 1, 7 / 8))
                       if tex is not None else ()))
        super().__init__(fmt, sec_tag_width, shd_tag_width, latencies, budget, copies, refract)
