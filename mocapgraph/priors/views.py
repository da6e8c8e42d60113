"""What the multi-view initialisers exchange: one camera's keypoints in, its body estimate out.

Light on purpose (numpy only): the graphs' initialisation uses these types without loading the
fusion regressor's network.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapgraph.body.keypoint_formats import COCO17, get_format
from mocapgraph.errors import MocapgraphError

MIN_POINTS = 6
"""A view is valid at a frame when at least this many of the 17 COCO points are present."""


@dataclass
class ViewInput:
    """One camera's detections of one person.

    Attributes:
        keypoints: ``(T, F, 3)`` undistorted pixels and confidence in [0, 1], NaN where missing, in format ``fmt``.
        fmt: keypoint format name of the registry (coco17, openpose25, blazepose33, body23) or an alias.
        K: ``(3, 3)`` intrinsics, pixels.
    """

    keypoints: np.ndarray
    fmt: str
    K: np.ndarray


@dataclass
class ViewEstimate:
    """One camera's estimate of the body.

    Attributes:
        camera_T_root: ``(T, 4, 4)`` the body root (pelvis) in this camera's OpenCV frame (x right,
            y down, z forward), metres; ``world_T_camera @ camera_T_root`` is ``world_T_root``.
        pose: ``(T, 21, 3)`` local axis-angle, radians (the body model's convention, T-pose at zero).
        shape: ``(T, S)`` body shape, within the model's bounds.
        valid: ``(T,)`` at least :data:`MIN_POINTS` of the 17 COCO points present in this view.
    """

    camera_T_root: np.ndarray
    pose: np.ndarray
    shape: np.ndarray
    valid: np.ndarray


def coco_keypoints(keypoints, fmt: str) -> np.ndarray:
    """``(..., 17, 3)``: the COCO points of ``keypoints (..., F, 3)`` in format ``fmt``, by name."""
    f = get_format(fmt)
    keypoints = np.asarray(keypoints, dtype=float)
    if keypoints.ndim < 2 or keypoints.shape[-2:] != (f.num_points, 3):
        raise MocapgraphError(f"{f.name} keypoints must have shape (..., {f.num_points}, 3), got {keypoints.shape}")
    return keypoints[..., [f.names.index(n) for n in COCO17], :]
