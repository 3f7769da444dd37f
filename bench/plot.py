#!/usr/bin/env python3
"""Draws the curves of an hvdb-bench JSON file as PNG plots (python3-matplotlib).

usage: plot.py RESULTS.json [OUT_DIR]

Every entry of "curves" becomes OUT_DIR/<its "png" name>; hvdb-bench runs this after writing
the JSON (bench/README.md describes the schema).
"""
import json
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def draw(curve, run, out_dir):
    fig, ax = plt.subplots(figsize=(8, 5), dpi=110)
    for s in curve["series"]:
        pts = [(x, y) for x, y in zip(s["x"], s["y"]) if x is not None and y is not None]
        if not pts:
            continue
        xs, ys = zip(*pts)
        style = s.get("style", "line")
        if style == "points":
            many = len(xs) > 200
            ax.plot(xs, ys, linestyle="none", marker="." if many else "o",
                    markersize=2 if many else 6, alpha=0.35 if many else 1.0, label=s["label"])
        elif style == "dashed":
            ax.plot(xs, ys, linestyle="--", linewidth=1.2, label=s["label"])
        else:
            ax.plot(xs, ys, marker="o" if len(xs) <= 40 else None, markersize=4,
                    linewidth=1.6, label=s["label"])
    if curve.get("logx"):
        ax.set_xscale("log")
    if curve.get("logy"):
        ax.set_yscale("log")
    if curve.get("invertx"):
        ax.invert_xaxis()
    ax.set_title(curve["title"], fontsize=11)
    ax.set_xlabel(curve["xlabel"])
    ax.set_ylabel(curve["ylabel"])
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    m = run.get("machine", {})
    note = "hvdb-bench%s, %s, %s CPUs (%s), %s" % (
        " --quick" if run.get("quick") else "", run.get("started", ""), m.get("nproc", "?"),
        m.get("cpu_model", "?"), m.get("disk", {}).get("device", "?"))
    fig.text(0.01, 0.01, note, fontsize=6, alpha=0.7)
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    path = os.path.join(out_dir, curve["png"])
    fig.savefig(path)
    plt.close(fig)
    return path


def main():
    if len(sys.argv) < 2:
        print(__doc__, file=sys.stderr)
        return 2
    with open(sys.argv[1]) as f:
        run = json.load(f)
    out_dir = sys.argv[2] if len(sys.argv) > 2 else os.path.dirname(os.path.abspath(sys.argv[1]))
    os.makedirs(out_dir, exist_ok=True)
    for curve in run.get("curves", []):
        draw(curve, run, out_dir)
    return 0


if __name__ == "__main__":
    sys.exit(main())
