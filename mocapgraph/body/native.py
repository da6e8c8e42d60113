"""Posing through the native kernel, with the inputs validated once at the boundary."""

from __future__ import annotations

import numpy as np

from mocapgraph.body.kinematics import FKResult
from mocapgraph.body.skeleton import NUM_JOINTS
from mocapgraph.body.table import BodyTable
from mocapgraph.errors import MocapgraphError, as_checked_array


def native_module():
    """The compiled ``mocapgraph._native`` extension, or a MocapgraphError saying how to build it."""
    try:
        from mocapgraph import _native
    except ImportError as exc:
        raise MocapgraphError(
            f"the native extension mocapgraph._native is not built ({exc}); "
            "run `make install` (or `pip install -e .`) in the project directory"
        ) from None
    return _native


def table_arrays(table: BodyTable) -> tuple[np.ndarray, ...]:
    """The table as the contiguous float64/int64 arrays the kernels take, in their order."""
    c = np.ascontiguousarray
    return (
        c(table.parents, dtype=np.int64),
        c(table.offsets, dtype=float),
        c(table.d_offsets, dtype=float),
        c(table.weights, dtype=float),
        c(table.markers, dtype=float),
        c(table.d_markers, dtype=float),
    )


def check_pose(root, pose) -> tuple[np.ndarray, np.ndarray]:
    """Validate ``root (T, 4, 4)`` and ``pose (T, 21, 3)`` (a single frame may drop the T axis)."""
    if np.ndim(root) == 2:
        root = np.asarray(root)[None]
    if np.ndim(pose) == 2:
        pose = np.asarray(pose)[None]
    root = as_checked_array(root, "root pose world_T_root", (None, 4, 4))
    pose = as_checked_array(pose, "joint rotations (axis-angle)", (root.shape[0], NUM_JOINTS - 1, 3))
    rot = root[:, :3, :3]
    err = np.abs(rot @ np.swapaxes(rot, 1, 2) - np.eye(3)).max(initial=0.0)
    if err > 1e-6 or np.any(np.abs(np.linalg.det(rot) - 1) > 1e-6):
        raise MocapgraphError(f"root pose world_T_root: rotation block is not a rotation (error {err:.2g})")
    return np.ascontiguousarray(root), np.ascontiguousarray(pose)


def forward_kinematics(table: BodyTable, root, pose, jacobians: bool = False) -> FKResult:
    """Native forward kinematics; same contract as :func:`kinematics.forward_kinematics_numpy`."""
    root, pose = check_pose(root, pose)
    joints, keypoints, rotations, d_joints, d_keypoints = native_module().fk(
        *table_arrays(table), root, pose, jacobians
    )
    return FKResult(joints, keypoints, rotations, d_joints, d_keypoints)
