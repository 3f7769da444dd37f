#!/usr/bin/env python3
"""Renders a turntable of frame 0: 12 views around the person, written as PNGs (with Open3D's
image writer) into turntable/."""
import os

import numpy as np
import open3d as o3d

from _connect import database

db, args = database(__doc__)
with db:
    pts = db.frame(args.dataset, frame=0)
    c = pts["position"].mean(axis=0)
    os.makedirs("turntable", exist_ok=True)
    for i in range(12):
        a = 2 * np.pi * i / 12
        eye = c + 3.0 * np.array([np.sin(a), 0, -np.cos(a)])
        img = db.render(args.dataset, 0, look_at=(*eye, *c), fov=45, size=(480, 360))
        path = f"turntable/view_{i:02d}.png"
        o3d.io.write_image(path, o3d.geometry.Image(np.ascontiguousarray(img)))
        print(path, img.shape)
