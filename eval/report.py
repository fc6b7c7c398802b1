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


def pareto_plot(d, path):
    groups = [g for g in d["groups"] if g.get("error") is not None]
    fig, ax = plt.subplots(figsize=(7.5, 5))
    colour_axis = d.get("colour_axis")
    values = sorted({json.dumps(g["settings"].get(colour_axis)) for g in groups}) if colour_axis else []
    cmap = plt.get_cmap("viridis", max(len(values), 1))
    for g in groups:
        c = cmap(values.index(json.dumps(g["settings"].get(colour_axis)))) if colour_axis else "tab:blue"
        ax.errorbar(g["time"], g["error"], yerr=g.get("error_sd") or None, fmt="o", color=c, ms=6, capsize=2,
                    markeredgecolor="black" if g["pareto"] else c, markeredgewidth=1.5 if g["pareto"] else 0)
    front = sorted((g for g in groups if g["pareto"]), key=lambda g: g["time"])
    if front:
        ax.step([g["time"] for g in front], [g["error"] for g in front], where="post", color="crimson", lw=1.5,
                label="Pareto front")
        for g in front:
            ax.annotate(g["short"], (g["time"], g["error"]), textcoords="offset points", xytext=(6, 4), fontsize=7)
    if colour_axis:
        for i, v in enumerate(values):
            ax.plot([], [], "o", color=cmap(i), label=f"{colour_axis} = {json.loads(v)}")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("GPU time per frame (ms, sum of all passes)")
    ax.set_ylabel(f"{d['metric']} against the reference (mean over seeds, ±1 sd)")
    ax.set_title("Speed against accuracy")
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
    row_h = 2.6 * im["height"] / im["width"] + 0.45  # panels keep the image's aspect; 0.45 for titles
    fig, axes = plt.subplots(3, n, figsize=(2.6 * n, 3 * row_h), squeeze=False)
    errs = [np.fromfile(c["error"], dtype="<f4").reshape(im["height"], im["width"]) for c in cols if c.get("error")]
    pos = np.concatenate([e[e > 0].ravel() for e in errs]) if errs else np.array([])
    lo = max(np.percentile(pos, 1), 1e-8) if pos.size else 1e-4
    hi = max(np.percentile(pos, 99.5), lo * 10) if pos.size else 1.0
    mappable = None
    for i, c in enumerate(cols):
        rgb = plt.imread(c["png"])
        a = axes[0][i]
        a.imshow(rgb, interpolation="nearest")
        a.add_patch(plt.Rectangle((x0 - 0.5, y0 - 0.5), cw, ch, fill=False, ec="yellow", lw=1))
        a.set_title(c["label"], fontsize=7)
        axes[1][i].imshow(rgb[y0:y0 + ch, x0:x0 + cw], interpolation="nearest")
        axes[1][i].set_title("crop", fontsize=7)
        if c.get("error"):
            e = np.fromfile(c["error"], dtype="<f4").reshape(im["height"], im["width"])
            mappable = axes[2][i].imshow(np.clip(e, lo, hi), cmap="magma", norm=LogNorm(lo, hi),
                                         interpolation="nearest")
            axes[2][i].set_title(f"{d['metric_map']} {c['mean_error']:.3g}", fontsize=7)
        else:
            axes[2][i].axis("off")
        for r in range(3):
            axes[r][i].set_xticks([])
            axes[r][i].set_yticks([])
    if mappable is not None:
        fig.colorbar(mappable, ax=[axes[2][i] for i in range(n)], shrink=0.8, label=d["metric_map"])
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
