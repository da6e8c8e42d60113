"""BVH (Biovision hierarchy) of the 22-joint skeleton: offsets from the body's shape, per-frame
local joint rotations and the root's motion.

The body frame is SMPL's (Y up, zero rotations a T-pose), which is what BVH expects of a rest
pose, so joint offsets are the body table's offsets and local rotations are the pose's own. The
root's pose is turned from our Z-up world into BVH's Y up by :data:`Y_UP_FROM_Z_UP`; Blender's
BVH importer (forward −Z, up Y, scale 1) turns it back, so the body stands in our world frame.
Lengths in metres. Rotations are written as ``Zrotation Xrotation Yrotation`` channels in
degrees (``R = Rz · Rx · Ry``, CMU's order). Leaf joints (feet, head, wrists) end in an ``End
Site`` half the length of their own bone further along it.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from mocapgraph.body.rotations import rotvec_to_matrix
from mocapgraph.body.skeleton import JOINT_NAMES, PARENTS
from mocapgraph.data_tools.io.exporters import Y_UP_FROM_Z_UP, frame_time

EULER_ORDER = "ZXY"
"""Intrinsic order of the rotation channels (scipy notation: upper case is intrinsic)."""


def depth_first(parents: np.ndarray) -> list[int]:
    """Joint indices in the order BVH lists them: each joint followed by its subtrees."""
    order: list[int] = []

    def visit(j: int) -> None:
        order.append(j)
        for c in np.flatnonzero(parents == j):
            visit(int(c))

    visit(0)
    return order


def bvh_channels(result) -> tuple[np.ndarray, np.ndarray]:
    """The root's position ``(T, 3)`` (BVH frame, metres) and rotation matrices ``(T, 22, 3, 3)``:
    the root's world orientation in the BVH frame, then each joint's local rotation."""
    rotations = np.empty((len(result.timestamps), len(JOINT_NAMES), 3, 3))
    rotations[:, 0] = Y_UP_FROM_Z_UP @ result.root[:, :3, :3]
    rotations[:, 1:] = rotvec_to_matrix(result.pose)
    return result.root[:, :3, 3] @ Y_UP_FROM_Z_UP.T, rotations


def bvh_text(result, body) -> str:
    """The BVH file of the result's skeleton and motion (see the module docstring)."""
    offsets = body.table(result.shape).offsets  # (22, 3) in the parent's frame, body axes (Y up)
    position, rotations = bvh_channels(result)
    order = depth_first(PARENTS)
    lines = ["HIERARCHY"]

    def joint(j: int, depth: int) -> None:
        pad = "  " * depth
        lines.append(f"{pad}{'ROOT' if j == 0 else 'JOINT'} {JOINT_NAMES[j]}")
        lines.append(pad + "{")
        lines.append(f"{pad}  OFFSET {' '.join(f'{v:.6f}' for v in offsets[j])}")
        channels = "Zrotation Xrotation Yrotation"
        lines.append(f"{pad}  CHANNELS 6 Xposition Yposition Zposition {channels}" if j == 0 else f"{pad}  CHANNELS 3 {channels}")
        children = np.flatnonzero(PARENTS == j)
        for c in children:
            joint(int(c), depth + 1)
        if not len(children):
            lines.extend([f"{pad}  End Site", pad + "  {", f"{pad}    OFFSET {' '.join(f'{v:.6f}' for v in 0.5 * offsets[j])}", pad + "  }"])
        lines.append(pad + "}")

    joint(0, 0)
    euler = Rotation.from_matrix(rotations[:, order].reshape(-1, 3, 3)).as_euler(EULER_ORDER, degrees=True)
    frames = np.concatenate([position, euler.reshape(len(position), -1)], axis=1)
    lines += ["MOTION", f"Frames: {len(frames)}", f"Frame Time: {frame_time(result.timestamps):.8f}"]
    lines += [" ".join(f"{v:.6f}" for v in row) for row in frames]
    return "\n".join(lines) + "\n"
