"""CSV of the joints per frame: one row per body state, ``frame, time_s`` then ``<joint>_x_m,
<joint>_y_m, <joint>_z_m`` for the 22 joints, in the result's world frame (Z up, metres); a
joint the result has no estimate for is an empty field."""

from __future__ import annotations

import numpy as np

from mocapgraph.body.skeleton import JOINT_NAMES


def csv_text(result) -> str:
    """The CSV file of the result's joints (see the module docstring)."""
    header = ["frame", "time_s"] + [f"{n}_{axis}_m" for n in JOINT_NAMES for axis in "xyz"]
    lines = [",".join(header)]
    flat = result.joints.reshape(len(result.joints), -1)
    for t, (time, row) in enumerate(zip(result.timestamps, flat)):
        lines.append(f"{t},{time:.6f}," + ",".join("" if np.isnan(v) else f"{v:.6f}" for v in row))
    return "\n".join(lines) + "\n"
