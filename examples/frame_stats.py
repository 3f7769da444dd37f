#!/usr/bin/env python3
"""Points per frame of a dataset, its bounding box, and the points per level of detail of its
first frame. Run the README's first command (the demo), then: python3 examples/frame_stats.py"""
import numpy as np

from _connect import database

db, args = database(__doc__)
with db:
    info = db.info(args.dataset)
    print(f"{args.dataset} on {db.where}: {info['frame_count']} frames at {info['fps']} fps, "
          f"{info['point_count']} points")
    print("bounds (m):", np.round(info["bounds_min"], 3), "..", np.round(info["bounds_max"], 3))
    for f in range(info["frame_count"]):
        pts = db.frame(args.dataset, frame=f)
        lo, hi = pts["position"].min(axis=0), pts["position"].max(axis=0)
        print(f"frame {f:3d}: {len(pts):7d} points, box {np.round(lo, 2)} .. {np.round(hi, 2)}")
    levels = {}
    for batch, level in db.stream(args.dataset, t=(0, 0), progressive=True):
        levels[level] = levels.get(level, 0) + len(batch)
    print("frame 0 by level of detail (coarsest first):",
          ", ".join(f"L{k}: {v}" for k, v in sorted(levels.items(), reverse=True)))
