"""Ground penetration: joints and cameras kept above the ground plane (SmartMocap's E_HGP, E_CGP).

The ground is the plane ``z = ground_z`` of the world frame (metres, Z up, as every capture's
world frame; docs/capture-format.md). The terms are one-sided: nothing is felt above the plane,
and below it the residual grows linearly with the depth,

    r_j = max(0, ground_z − z_j) / σ,

so ``½ r²`` is SmartMocap's squared hinge. The Jacobian is exact on either side; at ``z_j =
ground_z`` the cost has a continuous first derivative (zero from both sides).
"""

from __future__ import annotations

import gtsam
import numpy as np

from mocapgraph.body.skeleton import NUM_JOINTS
from mocapgraph.errors import MocapgraphError
from mocapgraph.factors.noise import positive
from mocapgraph.factors.reprojection import ShapeTableCache


class _JointsBelowGround:
    """Forward kinematics through the native kernel, then the hinge on each joint's height."""

    def __init__(self, cache: ShapeTableCache, keys, fixed_shape, sigma_m: float, ground_z: float):
        self.cache, self.keys, self.fixed_shape = cache, keys, fixed_shape
        self.sigma, self.ground = sigma_m, ground_z

    def __call__(self, this, values: gtsam.Values, H) -> np.ndarray:
        root_key, pose_key = self.keys[:2]
        shape = self.fixed_shape if len(self.keys) == 2 else values.atVector(self.keys[2])
        joints, d_joints = self.cache.state_joints(values.atPose3(root_key).matrix(), values.atVector(pose_key), shape, H is not None)
        depth = self.ground - joints[:, 2]
        below = depth > 0.0
        if H is not None:
            # d r_j / d x = −(d z_j / d x) / σ below the plane, 0 above.
            J = np.where(below[:, None], -d_joints[:, 2, :] / self.sigma, 0.0)
            H[0] = J[:, 0:6]
            H[1] = J[:, 6 : 6 + 3 * (NUM_JOINTS - 1)]
            if len(self.keys) == 3:
                H[2] = J[:, 6 + 3 * (NUM_JOINTS - 1) :]
        return np.where(below, depth, 0.0) / self.sigma


def joint_ground_factor(
    table_cache: ShapeTableCache,
    root_key: int,
    pose_key: int,
    shape_key: int | None,
    sigma_m: float = 0.01,
    ground_z: float = 0.0,
    fixed_shape=None,
) -> gtsam.CustomFactor:
    """E_HGP on one body state: every joint at least ``ground_z`` high (22 rows, metres / σ).

    Args:
        table_cache: a :class:`~mocapgraph.factors.reprojection.ShapeTableCache` of the body with
            keypoint format ``"body"`` (its joints are what is tested).
        root_key, pose_key: the state's ``Pose3`` and ``Vector(63)`` keys.
        shape_key: the shape's ``Vector(S)`` key, or None to hold ``fixed_shape``.
        sigma_m: the hinge's σ: a joint this far below the plane costs ½.
        ground_z: height of the ground plane in the world frame, metres.
        fixed_shape: ``(S,)`` the shape when ``shape_key`` is None.
    """
    sigma_m = float(positive(sigma_m, "sigma_m"))
    if (shape_key is None) == (fixed_shape is None):
        raise MocapgraphError("joint_ground_factor: give exactly one of shape_key and fixed_shape")
    if table_cache.keypoint_format != "body":
        raise MocapgraphError(f"joint_ground_factor: needs a ShapeTableCache of format 'body', got {table_cache.keypoint_format!r}")
    keys = [int(root_key), int(pose_key)] + ([] if shape_key is None else [int(shape_key)])
    shape = None if fixed_shape is None else np.asarray(fixed_shape, dtype=float)
    error = _JointsBelowGround(table_cache, keys, shape, sigma_m, float(ground_z))
    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(NUM_JOINTS), keys, error)


def camera_ground_factor(camera_key: int, sigma_m: float = 0.05, ground_z: float = 0.0, clearance_m: float = 0.0) -> gtsam.CustomFactor:
    """E_CGP on one camera pose (``world_T_camera``): its centre at least ``ground_z +
    clearance_m`` high (one row, metres / σ)."""
    sigma_m = float(positive(sigma_m, "sigma_m"))
    floor = float(ground_z) + float(clearance_m)

    def error(this, values: gtsam.Values, H) -> np.ndarray:
        T = values.atPose3(this.keys()[0])
        depth = floor - T.translation()[2]
        if H is not None:
            # The Pose3 tangent moves the centre by R v (rotation first): d z / d v = R[2, :].
            row = np.zeros((1, 6))
            if depth > 0.0:
                row[0, 3:] = -T.rotation().matrix()[2] / sigma_m
            H[0] = row
        return np.array([max(depth, 0.0) / sigma_m])

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(1), [int(camera_key)], error)
