#!/usr/bin/env python3
"""Selects the upper half of the person in frame 0 (y is down), cuts it to a clipboard,
checks that the frame lost exactly those points, then undoes the cut."""
import numpy as np

from _connect import database

db, args = database(__doc__)
ds = args.dataset
with db:
    before = db.frame(ds, frame=0)
    mid = float(np.median(before["position"][:, 1]))
    sel = db.select(ds, 5, y=(-1e9, mid), t=(0, 0))
    cut = db.cut(ds, 5, "upper", t=(0, 0))
    after = db.frame(ds, frame=0)
    print(f"selected {sel['selected']} points above y = {mid:.3f}, cut {cut['points']}; "
          f"frame 0: {len(before)} -> {len(after)} points")
    assert len(after) == len(before) - cut["points"]
    assert (after["position"][:, 1] > mid).all()
    db.undo(ds, cut["lsn"])
    print("undone: frame 0 has", len(db.frame(ds, frame=0)), "points again")
