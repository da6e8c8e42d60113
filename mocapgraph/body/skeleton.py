"""The skeleton every body model exposes: SMPL's first 22 joints, and the 23 body keypoints.

Body frame (all backends): SMPL's axes, +X the body's left, +Y up, +Z forward, origin at the
pelvis joint. Neutral pose: all 21 local rotations zero is a T-pose (arms horizontal, legs down,
facing +Z); see ``docs/body-model.md`` for how each backend realises it.
"""

from __future__ import annotations

import numpy as np

JOINT_NAMES: tuple[str, ...] = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2",
    "left_ankle", "right_ankle", "spine3", "left_foot", "right_foot", "neck",
    "left_collar", "right_collar", "head", "left_shoulder", "right_shoulder",
    "left_elbow", "right_elbow", "left_wrist", "right_wrist",
)  # fmt: skip

PARENTS: np.ndarray = np.array(
    [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19], dtype=np.int64
)

NUM_JOINTS = len(JOINT_NAMES)

# COCO-17 in COCO order, then the six foot points Anny's keypoint regressor provides.
BODY_KEYPOINT_NAMES: tuple[str, ...] = (
    "nose", "left_eye", "right_eye", "left_ear", "right_ear",
    "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist",
    "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle",
    "left_big_toe", "right_big_toe", "left_small_toe", "right_small_toe", "left_heel", "right_heel",
)  # fmt: skip


def left_right_pairs(names: tuple[str, ...] | list[str]) -> list[tuple[int, int]]:
    """Index pairs ``(i_left, i_right)`` of names that differ only by a ``left``/``right`` prefix."""
    index = {n: i for i, n in enumerate(names)}
    pairs = []
    for i, n in enumerate(names):
        if n.startswith("left_") and "right_" + n[5:] in index:
            pairs.append((i, index["right_" + n[5:]]))
    return pairs


def descendants_mask(parents: np.ndarray) -> np.ndarray:
    """``(J, J)`` bool: ``[c, d]`` is True when d is c or lies below c in the tree."""
    n = len(parents)
    mask = np.eye(n, dtype=bool)
    for d in range(n):
        p = parents[d]
        while p >= 0:
            mask[p, d] = True
            p = parents[p]
    return mask
