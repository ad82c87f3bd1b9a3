"""Plots of the precision study (``saarcor.precision``'s JSON): error against FP-unit LUTs, against
golden-model run time, and against the fraction width M (``saarcor bench precision --replot``
redraws them from the JSON)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

PSNR_CAP = 100.0     # an identical image (infinite PSNR) is drawn at this height


def _psnr(row) -> float:
    v = row["image"]["psnr_db"]
    if v in ("inf", None) or (isinstance(v, float) and not np.isfinite(v)):
        return PSNR_CAP
    return min(float(v), PSNR_CAP)


def fp_luts(result: dict, fmt: str) -> float | None:
    """LUT4 of one adder + one multiplier + one divider at ``fmt`` (None if not synthesized)."""
    c = result.get("fp_units", {}).get(fmt)
    if not c:
        return None
    return float(sum(c[u]["LUT4"] for u in ("add", "mul", "div")))


def points(result: dict, scene: str, x_of):
    xs, ys, labels = [], [], []
    for fmt, row in result["scenes"][scene]["formats"].items():
        if "error" in row:
            continue
        x = x_of(fmt, row)
        if x is None:
            continue
        xs.append(x), ys.append(_psnr(row)), labels.append(fmt)
    order = np.argsort(xs)
    return np.array(xs)[order], np.array(ys)[order], [labels[i] for i in order]


def pareto(xs, ys):
    """Points not beaten by a cheaper (smaller x) point with at least the same PSNR."""
    keep, best = [], -np.inf
    for i in np.argsort(xs):
        if ys[i] > best:
            keep.append(i)
            best = ys[i]
    return np.array(keep, int)


def plot(result: dict, out_dir: Path) -> list[Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    scenes = list(result["scenes"])
    written = []
    axes_def = [
        ("psnr_vs_luts.png", "FP LUT4 (adder + multiplier + divider, ECP5)",
         lambda fmt, row: fp_luts(result, fmt), False),
        ("psnr_vs_runtime.png", "golden model run time (s per million eye rays)",
         lambda fmt, row: 1e6 / row["rays_per_second"], True),
        ("psnr_vs_m.png", "fraction bits M (E = 8)",
         lambda fmt, row: float(fmt.split("M")[1]) if fmt.startswith("E8") else None, False),
    ]
    for fname, xlabel, x_of, logx in axes_def:
        fig, ax = plt.subplots(figsize=(7.5, 5))
        ax.set_prop_cycle(color=plt.cm.tab20.colors)
        for s in scenes:
            xs, ys, labels = points(result, s, x_of)
            if not len(xs):
                continue
            line, = ax.plot(xs, ys, "o", ms=3, alpha=0.5)
            k = pareto(xs, ys) if fname != "psnr_vs_m.png" else np.arange(len(xs))
            ax.plot(xs[k], ys[k], "-", color=line.get_color(), label=s)
        ax.axhline(40, color="grey", ls="--", lw=0.8)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(f"PSNR against float64 (dB; identical drawn at {PSNR_CAP:.0f})")
        if logx:
            ax.set_xscale("log")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=2)
        ax.set_title("Precision study: " + ("Pareto fronts" if fname != "psnr_vs_m.png"
                                            else "image error against M"))
        fig.tight_layout()
        p = out_dir / fname
        fig.savefig(p, dpi=110)
        plt.close(fig)
        written.append(p)
    # eye-ray flips and t error against M
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.2))
    for a in (a1, a2):
        a.set_prop_cycle(color=plt.cm.tab20.colors)
    for s in scenes:
        ms, flips, t99 = [], [], []
        for fmt, row in result["scenes"][s]["formats"].items():
            if "error" in row or not fmt.startswith("E8"):
                continue
            ms.append(int(fmt.split("M")[1]))
            flips.append(max(row["eye"]["flip_share"] + row["eye"]["wrong_triangle_share"], 1e-7))
            t99.append(max(row["eye"]["t_rel_p99"], 1e-12))
        o = np.argsort(ms)
        a1.semilogy(np.array(ms)[o], np.array(flips)[o], "o-", ms=3, label=s)
        a2.semilogy(np.array(ms)[o], np.array(t99)[o], "o-", ms=3, label=s)
    a1.axhline(1e-3, color="grey", ls="--", lw=0.8)
    a1.set_xlabel("M (E = 8)"), a1.set_ylabel("eye rays: flips + wrong triangle (share; 1e-7 = none)")
    a2.set_xlabel("M (E = 8)"), a2.set_ylabel("eye rays: relative error of t, 99th percentile")
    for a in (a1, a2):
        a.grid(alpha=0.3)
    a1.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    p = out_dir / "rays_vs_m.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    written.append(p)
    return written


def tables(result: dict) -> str:
    """Markdown tables of the study: per scene and format, and the FP-unit cost per format."""
    def psnr(row):
        v = row["image"]["psnr_db"]
        return "∞" if v == "inf" else f"{v:.1f}"
    lines = ["| scene | format | PSNR dB | worst | >1 level | eye flips | wrong tri | t rel p50 "
             "| t rel p99 | t rel max | shadow flips | self hits | M rays/s |",
             "|" + "---|" * 13]
    for s, sr in result["scenes"].items():
        for fmt, r in sr["formats"].items():
            if "error" in r:
                lines.append(f"| {s} | {fmt} | {r['error'][:60]} |" + " |" * 11)
                continue
            e, sh = r["eye"], r["shadow"]
            lines.append(
                f"| {s} | {fmt} | {psnr(r)} | {r['image']['worst_levels']} | "
                f"{100 * r['image']['share_off_gt_1_level']:.2f} % | {e['flips']} | "
                f"{e['wrong_triangle']} | {e['t_rel_median']:.1e} | {e['t_rel_p99']:.1e} | "
                f"{e['t_rel_max']:.1e} | {sh.get('flips', 0)} | {sh.get('self_hits', 0)} | "
                f"{r['rays_per_second'] / 1e6:.2f} |")
    lines += ["", "| format | add LUT4/FF/DSP | mul LUT4/FF/DSP | div LUT4/FF/DSP (latency) |"
              " sum LUT4 |", "|---|---|---|---|---|"]
    for fmt, c in result.get("fp_units", {}).items():
        cell = lambda u: f"{c[u]['LUT4']}/{c[u]['FF']}/{c[u]['DSP']}"  # noqa: E731
        lines.append(f"| {fmt} | {cell('add')} | {cell('mul')} | {cell('div')} "
                     f"({c['div']['latency']}) | {fp_luts(result, fmt):.0f} |")
    lines += ["", "| closed mesh | " + " | ".join(result["formats"]) + " |",
              "|" + "---|" * (len(result["formats"]) + 1)]
    for name, rows in result.get("leaks", {}).items():
        lines.append(f"| {name} | " + " | ".join(
            f"{rows[f]['leaks']}/{rows[f]['grazing']}" for f in result["formats"]) + " |")
    lines += ["", "| scene | smallest M (E8): PSNR ≥ 40 dB, no leaks, < 0.1 % eye flips |",
              "|---|---|"]
    for s, sr in result["scenes"].items():
        lines.append(f"| {s} | {sr.get('smallest_m_psnr40_noleak_flips0.1pct')} |")
    return "\n".join(lines) + "\n"
