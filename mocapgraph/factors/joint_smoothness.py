"""3D joint smoothness between two body states (SmartMocap's E_smooth on joint positions).

The joints' mean velocity over the step, ``(J_b − J_a) / dt`` (metres per second, world frame),
is ``N(0, σ² I)``: 66 rows, one per joint coordinate. Unlike the smoothness of the joint
rotations (:mod:`mocapgraph.factors.priors`), it weighs a rotation by how far it moves the limbs,
so a wrist's jitter costs more than a twist of the forearm that moves nothing.
"""

from __future__ import annotations

import gtsam
import numpy as np

from mocapgraph.body.skeleton import NUM_JOINTS
from mocapgraph.errors import MocapgraphError
from mocapgraph.factors.reprojection import POSE_DIM, ShapeTableCache


class _JointVelocity:
    def __init__(self, cache: ShapeTableCache, keys: list[int], fixed_shape, scale: float):
        self.cache, self.keys, self.fixed_shape, self.scale = cache, keys, fixed_shape, scale

    def __call__(self, this, values: gtsam.Values, H) -> np.ndarray:
        shape = self.fixed_shape if len(self.keys) == 4 else values.atVector(self.keys[4])
        want = H is not None
        a, da = self.cache.state_joints(values.atPose3(self.keys[0]).matrix(), values.atVector(self.keys[1]), shape, want)
        b, db = self.cache.state_joints(values.atPose3(self.keys[2]).matrix(), values.atVector(self.keys[3]), shape, want)
        if want:
            Ja = -da.reshape(3 * NUM_JOINTS, -1) * self.scale
            Jb = db.reshape(3 * NUM_JOINTS, -1) * self.scale
            H[0], H[1] = Ja[:, :6], Ja[:, 6 : 6 + POSE_DIM]
            H[2], H[3] = Jb[:, :6], Jb[:, 6 : 6 + POSE_DIM]
            if len(self.keys) == 5:
                H[4] = Ja[:, 6 + POSE_DIM :] + Jb[:, 6 + POSE_DIM :]
        return (b - a).ravel() * self.scale


def joint_smoothness_factor(
    table_cache: ShapeTableCache,
    state_a: tuple[int, int],
    state_b: tuple[int, int],
    shape_key: int | None,
    dt: float,
    sigma_m_s: float,
    fixed_shape=None,
) -> gtsam.CustomFactor:
    """Joint velocity between two states: 66 rows, ``(J_b − J_a) / (dt σ)``.

    Args:
        table_cache: a :class:`ShapeTableCache` of format ``"body"`` (its joints are compared).
        state_a, state_b: ``(root key, pose key)`` of the earlier and the later state.
        shape_key: the shape's key, or None to hold ``fixed_shape`` (``(S,)``).
        dt: seconds between the states (> 0).
        sigma_m_s: standard deviation of a joint's mean velocity, metres per second.
    """
    if table_cache.keypoint_format != "body":
        raise MocapgraphError(f"joint_smoothness_factor: needs a ShapeTableCache of format 'body', got {table_cache.keypoint_format!r}")
    if (shape_key is None) == (fixed_shape is None):
        raise MocapgraphError("joint_smoothness_factor: give exactly one of shape_key and fixed_shape")
    if not (np.isfinite(dt) and dt > 0 and np.isfinite(sigma_m_s) and sigma_m_s > 0):
        raise MocapgraphError(f"joint_smoothness_factor: dt and sigma_m_s must be finite and > 0, got {dt}, {sigma_m_s}")
    keys = [int(k) for k in (*state_a, *state_b)] + ([] if shape_key is None else [int(shape_key)])
    shape = None if fixed_shape is None else np.asarray(fixed_shape, dtype=float)
    error = _JointVelocity(table_cache, keys, shape, 1.0 / (dt * sigma_m_s))
    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(3 * NUM_JOINTS), keys, error)
