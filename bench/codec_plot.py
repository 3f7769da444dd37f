#!/usr/bin/env python3
"""Rate-distortion plots of codec-bench's JSON: one PNG per data set and attribute (bits per
point against PSNR, hvdb7 fixed/progressive against Draco), and the quality of progressive
prefixes. Usage: codec_plot.py codec.json  (writes codec.<set>.<attribute>.png beside it)."""
import json
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

STYLE = {
    "ours_fixed": ("hvdb7 fixed-rate", "o-", "tab:blue"),
    "ours_progressive": ("hvdb7 progressive", "s--", "tab:cyan"),
    "draco_cl10": ("Draco cl 10", "^-", "tab:red"),
    "draco_cl7": ("Draco cl 7", "v--", "tab:orange"),
}
UNITS = {"position": "position PSNR (dB, peak = box diagonal)",
         "color": "luma (Y) PSNR (dB)", "normal": "normal PSNR (dB, peak 180°)"}


def main(path):
    with open(path) as f:
        j = json.load(f)
    base = os.path.splitext(path)[0]
    written = []
    for name, attrs in j["rd"].items():
        for attr, series in attrs.items():
            fig, ax = plt.subplots(figsize=(5.5, 4))
            for key, pts in series.items():
                label, fmt, color = STYLE.get(key, (key, "x-", None))
                pts = sorted(pts, key=lambda p: p["bpp"])
                ax.plot([p["bpp"] for p in pts], [p["psnr"] for p in pts], fmt, color=color,
                        label=label, markersize=4)
            ax.set_xlabel(f"{attr} bits per point")
            ax.set_ylabel(UNITS.get(attr, "PSNR (dB)"))
            ax.set_title(f"{name}: {attr}")
            ax.grid(alpha=0.3)
            ax.legend()
            out = f"{base}.{name}.{attr}.png"
            fig.tight_layout()
            fig.savefig(out, dpi=110)
            plt.close(fig)
            written.append(out)
    pre = j.get("progressive_prefixes", [])
    if pre:
        fig, ax = plt.subplots(figsize=(5.5, 4))
        ax.plot([p["bpp"] for p in pre], [p["position_psnr"] for p in pre], "o-", label="position")
        ax.plot([p["bpp"] for p in pre], [p["y_psnr"] for p in pre], "s-", label="luma")
        ax.set_xlabel("bits per point decoded so far")
        ax.set_ylabel("PSNR (dB)")
        ax.set_title("progressive prefixes (Panoptic frame 380)")
        ax.grid(alpha=0.3)
        ax.legend()
        out = f"{base}.prefixes.png"
        fig.tight_layout()
        fig.savefig(out, dpi=110)
        plt.close(fig)
        written.append(out)
    print("\n".join(written))


if __name__ == "__main__":
    main(sys.argv[1])
