#!/usr/bin/env python3
"""Rate-distortion plot of one preset: compression ratio (log axis) against MSSIM, one curve per method.

Usage: plot_rd.py CURVES.json OUT.png, where CURVES.json is {"title": str, "curves": {method: [{"ratio",
"mssim", "setting"}, ...]}} as bench_rate_distortion writes it.
"""
import json, sys

import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt

STYLE = {"btfvq": ("black", "o", 2.5)}

def main():
    src, out = sys.argv[1], sys.argv[2]
    with open(src) as fh:
        data = json.load(fh)
    fig, ax = plt.subplots(figsize=(6.4, 4.4), dpi=110)
    # btfvq first, so that it leads the legend.
    for method, pts in sorted(data["curves"].items(), key=lambda kv: kv[0] != "btfvq"):
        pts = sorted(pts, key=lambda p: p["mssim"])
        colour, marker, width = STYLE.get(method, (None, "s", 1.2))
        ax.plot([p["mssim"] for p in pts], [p["ratio"] for p in pts], marker=marker, linewidth=width,
                color=colour, label=method)
        for p in pts:
            ax.annotate(p["setting"].replace("thresholds ", ""), (p["mssim"], p["ratio"]), fontsize=6,
                        xytext=(3, 3), textcoords="offset points")
    ax.set_yscale("log")
    ax.set_xlabel("MSSIM (BT.601 luma, mean over the 6561 images)")
    ax.set_ylabel("compression ratio 1:x (log)")
    if data.get("floor") is not None:
        ax.axvline(data["floor"], color="grey", linestyle="--", linewidth=1)
        ax.annotate("resample + decode, no VQ", (data["floor"], ax.get_ylim()[0]), fontsize=6, rotation=90,
                    xytext=(-8, 4), textcoords="offset points", color="grey")
    ax.set_title(data["title"], fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out)

if __name__ == "__main__":
    main()
