#!/usr/bin/env python3
"""Ingests a sequence made in numpy (a ring of coloured points turning over 30 frames) into a
new dataset, one transaction per frame, and reads a frame back."""
import numpy as np

import hvdb
from _connect import database

db, args = database(__doc__)
name = args.dataset + "_ring"
with db:
    if name in db.datasets():
        db.drop(name)
    db.create(name, fps=30)
    angles = np.linspace(0, 2 * np.pi, 2000, endpoint=False)
    for f in range(30):
        a = angles + f * 0.05
        xyz = np.stack([np.cos(a), np.zeros_like(a), np.sin(a)], axis=1)
        rgb = np.stack([(np.sin(a) + 1) / 2, (np.cos(a) + 1) / 2, np.full_like(a, 0.5)], axis=1)
        with db.transaction(name) as tx:
            tx.insert(hvdb.points(xyz, color=rgb, frame=f))
    back = db.frame(name, frame=12)
    print(f"{name}: {db.info(name)['point_count']} points in 30 frames; "
          f"frame 12 has {len(back)}, mean radius {np.linalg.norm(back['position'], axis=1).mean():.3f} m")
