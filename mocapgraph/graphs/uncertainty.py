"""Covariances of a solved body graph, in the units a user reads: joints in metres², root and
cameras in their Pose3 tangent (rotation first, radians then metres)."""

from __future__ import annotations

import gtsam
import numpy as np

from mocapgraph.body.model import BodyModel
from mocapgraph.body.skeleton import NUM_JOINTS
from mocapgraph.factors.keys import pose_key, root_key, shape_key


def joint_covariances(
    body: BodyModel, marginals: gtsam.Marginals, roots: np.ndarray, poses: np.ndarray, shape: np.ndarray, states=None
) -> tuple[np.ndarray, np.ndarray]:
    """Per body state: joints ``(N, 22, 3, 3)`` (m²) pushed through the forward-kinematics
    Jacobian, and root ``(N, 6, 6)`` (Pose3 tangent, rotation first); NaN for states not in
    ``states`` (default: all).

    ``marginals`` of the solved graph; ``roots (N, 4, 4)``, ``poses (N, 21, 3)``, ``shape (S,)``
    the solution. The joint marginal of (root, pose) of each state is exact; the shape, shared by
    all states, is added as an independent term. Its cross-covariance with one state is
    neglected: querying it costs about 100x more (0.4 s against 4 ms per state, measured), and
    the shape is pinned by the whole sequence.
    """
    n = len(roots)
    S = body.shape_dim
    shape_cov = marginals.marginalCovariance(shape_key())
    joints_cov = np.full((n, NUM_JOINTS, 3, 3), np.nan)
    root_cov = np.full((n, 6, 6), np.nan)
    fk = body.forward(shape, roots, poses.reshape(n, NUM_JOINTS - 1, 3), jacobians=True)
    diag = np.arange(NUM_JOINTS)
    for i in range(n) if states is None else states:
        keys = [root_key(i), pose_key(i)]
        joint = marginals.jointMarginalCovariance(gtsam.KeyVector(keys))
        cov = np.zeros((69 + S, 69 + S))
        cov[:69, :69] = np.block([[joint.at(a, b) for b in keys] for a in keys])
        cov[69:, 69:] = shape_cov
        J = fk.d_joints[i].reshape(NUM_JOINTS * 3, 69 + S)
        joints_cov[i] = (J @ cov @ J.T).reshape(NUM_JOINTS, 3, NUM_JOINTS, 3)[diag, :, diag, :]
        root_cov[i] = cov[:6, :6]
    return joints_cov, root_cov
