"""Forward kinematics of joints and keypoints with analytic Jacobians (numpy reference).

This is the readable reference the native kernel (``mocapgraph._native``) is tested against;
production code calls :func:`mocapgraph.body.forward_kinematics`, which dispatches to the kernel.

Jacobian columns, ``P = 6 + 63 + S``:
    ``[0:3]``   root rotation, right perturbation ``R ← R·Exp(ω)`` (GTSAM Pose3 tangent, rotation first);
    ``[3:6]``   root translation in the root frame, ``t ← t + R·v`` (GTSAM Pose3 tangent);
    ``[6:69]``  the 21 local axis-angle vectors θ_1..θ_21 themselves (not a tangent perturbation);
    ``[69:]``   the shape vector β.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapgraph.body.rotations import right_jacobian, rotvec_to_matrix, skew
from mocapgraph.body.skeleton import NUM_JOINTS, descendants_mask
from mocapgraph.body.table import BodyTable

ROOT_COLUMNS = slice(0, 6)
POSE_COLUMNS = slice(6, 6 + 3 * (NUM_JOINTS - 1))
SHAPE_START = 6 + 3 * (NUM_JOINTS - 1)


@dataclass
class FKResult:
    """Posed body for T frames.

    Attributes:
        joints: ``(T, 22, 3)`` world, metres.
        keypoints: ``(T, K, 3)`` world, metres.
        rotations: ``(T, 22, 3, 3)`` world-aligned joint frames ``G_c``.
        d_joints: ``(T, 22, 3, P)`` or None; columns as in the module docstring.
        d_keypoints: ``(T, K, 3, P)`` or None.
    """

    joints: np.ndarray
    keypoints: np.ndarray
    rotations: np.ndarray
    d_joints: np.ndarray | None = None
    d_keypoints: np.ndarray | None = None


def forward_kinematics_numpy(
    table: BodyTable, root: np.ndarray, pose: np.ndarray, jacobians: bool = False
) -> FKResult:
    """Pose the body: ``root (T, 4, 4)`` world_T_root, ``pose (T, 21, 3)`` local axis-angle.

    Straightforward loops over joints, vectorised over frames.
    """
    root = np.asarray(root, dtype=float)
    pose = np.asarray(pose, dtype=float)
    T = root.shape[0]
    parents = table.parents
    G = np.empty((T, NUM_JOINTS, 3, 3))
    J = np.empty((T, NUM_JOINTS, 3))
    G[:, 0] = root[:, :3, :3]
    J[:, 0] = root[:, :3, 3]
    local = rotvec_to_matrix(pose)
    for c in range(1, NUM_JOINTS):
        p = parents[c]
        G[:, c] = G[:, p] @ local[:, c - 1]
        J[:, c] = J[:, p] + G[:, p] @ table.offsets[c]
    K = np.einsum("kc,tcx->tkx", table.weights, J) + np.einsum(
        "tcxy,kcy->tkx", G, table.markers
    )
    result = FKResult(joints=J, keypoints=K, rotations=G)
    if not jacobians:
        return result

    S = table.shape_dim
    P = SHAPE_START + S
    below = descendants_mask(parents)
    R0, t0 = G[:, 0], J[:, 0]
    dJ = np.zeros((T, NUM_JOINTS, 3, P))
    dK = np.zeros((T, table.num_keypoints, 3, P))

    # Root: rotating the root by ω turns every point x about t0: δx = -R0 [R0ᵀ (x - t0)]× ω.
    dJ[..., 0:3] = -R0[:, None] @ skew(np.einsum("tyx,tjy->tjx", R0, J - t0[:, None]))
    dJ[..., 3:6] = R0[:, None]
    weight_sum = table.weights.sum(axis=1)
    rel_k = K - weight_sum[None, :, None] * t0[:, None]
    dK[..., 0:3] = -R0[:, None] @ skew(np.einsum("tyx,tky->tkx", R0, rel_k))
    dK[..., 3:6] = weight_sum[None, :, None, None] * R0[:, None]

    # Joint c's rotation turns its subtree about J_c by the world axis G_c Jr(θ_c) δθ_c.
    world_marker = np.einsum("tcxy,kcy->tkcx", G, table.markers)
    for c in range(1, NUM_JOINTS):
        axis_map = G[:, c] @ right_jacobian(pose[:, c - 1])  # (T, 3, 3)
        cols = slice(6 + 3 * (c - 1), 9 + 3 * (c - 1))
        sub = below[c]
        lever_j = (J - J[:, c : c + 1]) * sub[None, :, None]
        dJ[..., cols] = -skew(lever_j) @ axis_map[:, None]
        lever_k = np.einsum("kd,tdx->tkx", table.weights * sub, J - J[:, c : c + 1]) + np.einsum(
            "tkdx,d->tkx", world_marker, sub.astype(float)
        )
        dK[..., cols] = -skew(lever_k) @ axis_map[:, None]

    # Shape moves each joint by the shape derivative of every offset on its path to the root.
    for c in range(1, NUM_JOINTS):
        p = parents[c]
        d_own = np.einsum("txy,ys->txs", G[:, p], table.d_offsets[c])
        dJ[:, c, :, SHAPE_START:] = dJ[:, p, :, SHAPE_START:] + d_own
    dK[..., SHAPE_START:] = np.einsum("kc,tcxs->tkxs", table.weights, dJ[..., SHAPE_START:])
    dK[..., SHAPE_START:] += np.einsum("tcxy,kcys->tkxs", G, table.d_markers)
    result.d_joints, result.d_keypoints = dJ, dK
    return result
