# The figures of `haze report` (eval/report.cpp prepares data.json and the images; this only plots).
# Embedded in the haze binary at build time and run as `python3 - data.json`; needs Debian's
# python3-matplotlib and python3-numpy (scripts/setup.sh).
import json
import os
import sys

import matplotlib

matplotlib.use("Agg")  # no display: files only
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import LogNorm  # noqa: E402

DPI = 110


def save(fig, path):
    # Write beside, then rename: a killed report never leaves half a PNG.
    tmp = path + ".tmp.png"
    fig.savefig(tmp, dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    os.replace(tmp, path)


MARKERS = "osD^v<>pPX*h"


def curve_styles(d):
    # One colour and marker per curve (a setting of every axis but the cost axis), in the sweep's order.
    curves = []
    for g in d["groups"]:
        if g["curve"] not in curves:
            curves.append(g["curve"])
    cmap = plt.get_cmap("tab10" if len(curves) <= 10 else "tab20")
    return {c: (cmap(i % cmap.N), MARKERS[i % len(MARKERS)]) for i, c in enumerate(curves)}


def pareto_plot(d, path):
    groups = [g for g in d["groups"] if g.get("error") is not None]
    fig, ax = plt.subplots(figsize=(8.5, 5.5))
    styles = curve_styles(d)
    for curve, (c, m) in styles.items():
        pts = sorted((g for g in groups if g["curve"] == curve), key=lambda g: g["time"])
        if not pts:
            continue
        ax.plot([g["time"] for g in pts], [g["error"] for g in pts], "-", color=c, lw=1, alpha=0.6)
        for g in pts:
            ax.errorbar(g["time"], g["error"], yerr=g.get("error_sd") or None, fmt=m, color=c, ms=7, capsize=2,
                        markeredgecolor="black" if g["pareto"] else c, markeredgewidth=1.5 if g["pareto"] else 0)
        ax.plot([], [], m + "-", color=c, label=curve if curve != "base scene" or len(styles) > 1 else "runs")
    front = sorted((g for g in groups if g["pareto"]), key=lambda g: g["time"])
    if front:
        ax.step([g["time"] for g in front], [g["error"] for g in front], where="post", color="crimson", lw=1.5,
                label="Pareto front")
        for g in front:
            ax.annotate(g["short"], (g["time"], g["error"]), textcoords="offset points", xytext=(6, 4), fontsize=7)
    et = d.get("equal_time") or {}
    for i, b in enumerate(et.get("budgets", [])):
        ax.axvline(b["ms"], color="grey", ls=":", lw=1, label="equal-time budgets" if i == 0 else None)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("GPU time per frame (ms, sum of all passes)")
    ax.set_ylabel(f"{d['metric']} against the reference (mean over seeds, ±1 sd)")
    ax.set_title("Speed against accuracy" + (f" (points along {d['cost_axis']})" if d.get("cost_axis") else ""))
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    save(fig, path)


def stacked_bars(d, key, unit, title, path):
    groups = d["groups"]
    names = []
    for g in groups:
        for k in g[key]:
            if k not in names:
                names.append(k)
    fig, ax = plt.subplots(figsize=(8, 0.35 * len(groups) + 1.6))
    left = np.zeros(len(groups))
    cmap = plt.get_cmap("tab20")
    y = np.arange(len(groups))
    for i, n in enumerate(names):
        w = np.array([g[key].get(n, 0.0) for g in groups])
        ax.barh(y, w, left=left, color=cmap(i % 20), label=n)
        left += w
    ax.set_yticks(y, [g["short"] for g in groups], fontsize=7)
    ax.invert_yaxis()
    ax.set_xlabel(unit)
    ax.set_title(title)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1))
    ax.grid(True, axis="x", alpha=0.3)
    save(fig, path)


def image_grid(d, path):
    im = d["images"]
    cols = im["columns"]
    x0, y0, cw, ch = im["crop"]
    n = len(cols)
    # Panels large enough to judge noise: 3.6 inches wide (about 400 pixels), at the image's aspect.
    pw = 3.6
    ph = pw * im["height"] / im["width"]
    crop_h = pw * ch / cw
    fig = plt.figure(figsize=(pw * n + 0.9, ph * 2 + crop_h + 1.2))
    # One grid for the three rows and a narrow last column for the colour bar alone, so that the images,
    # their crops and their heat maps share columns exactly.
    gs = fig.add_gridspec(3, n + 1, width_ratios=[1] * n + [0.06], height_ratios=[ph, crop_h, ph],
                          wspace=0.04, hspace=0.18)
    errs = [np.fromfile(c["error"], dtype="<f4").reshape(im["height"], im["width"]) for c in cols if c.get("error")]
    pos = np.concatenate([e[e > 0].ravel() for e in errs]) if errs else np.array([])
    lo = max(np.percentile(pos, 1), 1e-8) if pos.size else 1e-4
    hi = max(np.percentile(pos, 99.5), lo * 10) if pos.size else 1.0
    mappable = None
    for i, c in enumerate(cols):
        rgb = plt.imread(c["png"])
        a = fig.add_subplot(gs[0, i])
        a.imshow(rgb, interpolation="nearest")
        a.add_patch(plt.Rectangle((x0 - 0.5, y0 - 0.5), cw, ch, fill=False, ec="yellow", lw=1))
        a.set_title(c["label"], fontsize=8)
        b = fig.add_subplot(gs[1, i])
        b.imshow(rgb[y0:y0 + ch, x0:x0 + cw], interpolation="nearest")
        b.set_title("crop", fontsize=7)
        e_ax = fig.add_subplot(gs[2, i])
        if c.get("error"):
            e = np.fromfile(c["error"], dtype="<f4").reshape(im["height"], im["width"])
            mappable = e_ax.imshow(np.clip(e, lo, hi), cmap="magma", norm=LogNorm(lo, hi), interpolation="nearest")
            e_ax.set_title(f"{d['metric_map']} {c['mean_error']:.3g}", fontsize=7)
        else:
            e_ax.axis("off")
        for a_ in (a, b, e_ax):
            a_.set_xticks([])
            a_.set_yticks([])
    if mappable is not None:
        fig.colorbar(mappable, cax=fig.add_subplot(gs[2, n]), label=d["metric_map"])
    save(fig, path)


def main():
    with open(sys.argv[1]) as f:
        d = json.load(f)
    out = d["figures_dir"]
    made = []
    if any(g.get("error") is not None for g in d["groups"]):
        pareto_plot(d, os.path.join(out, "pareto.png"))
        made.append("pareto.png")
    stacked_bars(d, "passes", "GPU ms per frame", "Time per pass", os.path.join(out, "passes.png"))
    made.append("passes.png")
    stacked_bars(d, "memory", "MB", "Memory ledger per category (live at the last frame)",
                 os.path.join(out, "memory.png"))
    made.append("memory.png")
    if d.get("images"):
        image_grid(d, os.path.join(out, "images.png"))
        made.append("images.png")
    print(json.dumps(made))


main()
