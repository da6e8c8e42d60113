"""TRC marker trajectories (OpenSim, Pose2Sim): the joints and, when the result has them, the
keypoints of its detector format.

Written as Pose2Sim writes its triangulated TRC files, so a Pose2Sim user can put ours in their
place: tab-separated, five header lines, ``Units`` = ``m``, Y up by Pose2Sim's own axis
permutation :data:`TRC_FROM_Z_UP` ``(x, y, z) → (y, z, x)``, frames numbered from 1 with a time
column (the result's timestamps). Joints are named ``joint_<name>``; keypoints keep their format's
names. A point the result has no estimate for is an empty field.
"""

from __future__ import annotations

import numpy as np

from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.skeleton import JOINT_NAMES
from mocapgraph.data_tools.io.exporters import frame_time

TRC_FROM_Z_UP = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
"""``(3, 3)`` Pose2Sim's Z-up → Y-up permutation (its ``zup2yup``)."""


def trc_markers(result) -> tuple[list[str], np.ndarray]:
    """Marker names and positions ``(T, M, 3)`` in our world frame, metres."""
    names = [f"joint_{n}" for n in JOINT_NAMES]
    points = [result.joints]
    if result.keypoints is not None:
        names += list(get_format(result.keypoint_format).names)
        points.append(result.keypoints)
    return names, np.concatenate(points, axis=1)


def trc_text(result, file_name: str) -> str:
    """The TRC file of the result's markers (see the module docstring); ``file_name`` goes in its first line."""
    names, points = trc_markers(result)
    T, M = points.shape[:2]
    rate = 1.0 / frame_time(result.timestamps)
    lines = [
        f"PathFileType\t4\t(X/Y/Z)\t{file_name}",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
        f"{rate:.6g}\t{rate:.6g}\t{T}\t{M}\tm\t{rate:.6g}\t1\t{T}",
        "Frame#\tTime\t" + "\t\t\t".join(names) + "\t\t",
        "\t\t" + "\t".join(f"X{i}\tY{i}\tZ{i}" for i in range(1, M + 1)),
    ]
    values = (points @ TRC_FROM_Z_UP.T).reshape(T, 3 * M)
    for t in range(T):
        cells = ["" if np.isnan(v) else f"{v:.6f}" for v in values[t]]
        lines.append(f"{t + 1}\t{result.timestamps[t] - result.timestamps[0]:.6f}\t" + "\t".join(cells))
    return "\n".join(lines) + "\n"
