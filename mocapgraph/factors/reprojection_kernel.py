"""Multi-camera reprojection residual of one frame's body keypoints, with exact Jacobians.

Inputs (one frame, C cameras, K keypoints of the body table, S shape parameters):
    ``root (4, 4)``         world_T_root, metres;
    ``pose (21, 3)``        local joint axis-angle vectors, radians;
    ``cameras (C, 4, 4)``   world_T_camera poses ``(R_c, t_c)`` of OpenCV cameras
                            (x right, y down, z forward), metres;
    ``intrinsics (C, 4)``   ``fx, fy, cx, cy`` in pixels (pinhole, no distortion);
    ``observed (C, K, 2)``  detected pixels ``(u, v)``, NaN where a keypoint was not detected;
    ``obs_weights (C, K)``  ``w >= 0``, typically detector confidences;
    ``gm_sigma_px``         Geman-McClure scale in pixels (inf or <= 0 turns robustness off);
    ``min_depth``           metres; keypoints closer to (or behind) the camera are invalid.

Model: ``p = R_cᵀ (X - t_c)`` in the camera, ``u = fx·p.x/p.z + cx``, ``v = fy·p.y/p.z + cy``,
pixel error ``e = (u, v) - observed``, residual ``r = w·s·e`` with ``s = σ/√(σ² + |e|²)``, so that
``½|r|² = ½ w² σ²|e|²/(σ² + |e|²)`` is the Geman-McClure cost (``r = w·e`` without robustness).
The weight ``s`` is differentiated too: ``∂r/∂e = w·s·(I - e eᵀ/(σ² + |e|²))``.

Outputs (:class:`Reprojection`):
    ``residual (2CK,)``  pixels; rows camera-major, ``2 (c K + k) + {0: u, 1: v}``;
    ``jacobian (2CK, P + 6C)`` or None; ``P = 6 + 63 + S`` body columns laid out as in
        :mod:`mocapgraph.body.kinematics` (root rotation, root translation, the 21 axis-angle
        vectors, shape), then camera ``c``'s six columns ``[P + 6c, P + 6c + 6)``: the right
        perturbation of world_T_camera in GTSAM's Pose3 tangent, rotation first
        (``R_c ← R_c·Exp(ω)``, ``t_c ← t_c + R_c·v``);
    ``valid (C, K)`` bool; an invalid keypoint (NaN observation, zero weight, ``p.z < min_depth``,
        or a point the body cannot provide: ``table.mapped`` False) has residual and Jacobian
        rows exactly zero.

:func:`reproject` runs the native kernel; :func:`reproject_numpy` is the readable reference it is
tested against.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapgraph.body.kinematics import forward_kinematics_numpy
from mocapgraph.body.native import native_module, table_arrays
from mocapgraph.body.rotations import skew
from mocapgraph.body.skeleton import NUM_JOINTS
from mocapgraph.body.table import BodyTable
from mocapgraph.errors import MocapgraphError, as_checked_array


@dataclass
class Reprojection:
    """One frame's reprojection residual; shapes and layout as in the module docstring.

    Attributes:
        residual: ``(2CK,)`` robust pixel residuals.
        jacobian: ``(2CK, P + 6C)`` or None.
        valid: ``(C, K)`` bool, False where the rows are zero.
    """

    residual: np.ndarray
    jacobian: np.ndarray | None
    valid: np.ndarray


def _robust(gm_sigma_px: float) -> bool:
    return bool(np.isfinite(gm_sigma_px) and gm_sigma_px > 0)


def reproject_numpy(
    table: BodyTable,
    root,
    pose,
    cameras,
    intrinsics,
    observed,
    obs_weights,
    gm_sigma_px: float,
    min_depth: float = 0.05,
    jacobians: bool = True,
) -> Reprojection:
    """Numpy reference of :func:`reproject` (no input validation); vectorised over cameras."""
    root = np.asarray(root, dtype=float)
    pose = np.asarray(pose, dtype=float)
    cameras = np.asarray(cameras, dtype=float)
    intrinsics = np.asarray(intrinsics, dtype=float)
    observed = np.asarray(observed, dtype=float)
    # Unmapped points have all-zero table rows (they sit at the origin): never let them pull.
    obs_weights = np.asarray(obs_weights, dtype=float) * table.mapped[None]
    C, K, S = cameras.shape[0], table.num_keypoints, table.shape_dim
    P = 6 + 3 * (NUM_JOINTS - 1) + S

    fk = forward_kinematics_numpy(table, root[None], pose[None], jacobians=jacobians)
    X = fk.keypoints[0]
    R, t = cameras[:, :3, :3], cameras[:, :3, 3]
    p = np.einsum("cyx,cky->ckx", R, X[None] - t[:, None])
    # Comparing with >= makes a NaN depth invalid as well.
    valid = ~np.isnan(observed).any(axis=-1) & (obs_weights != 0) & (p[..., 2] >= min_depth)
    # Invalid entries are computed with harmless stand-ins and zeroed by their weight below.
    z = np.where(valid, p[..., 2], 1.0)
    w = np.where(valid, obs_weights, 0.0)
    fx, fy, cx, cy = (intrinsics[:, i, None] for i in range(4))
    uv = np.stack([fx * p[..., 0] / z + cx, fy * p[..., 1] / z + cy], axis=-1)
    e = np.where(valid[..., None], uv - np.where(valid[..., None], observed, 0.0), 0.0)

    eye2 = np.eye(2)
    if _robust(gm_sigma_px):
        denom = gm_sigma_px**2 + np.sum(e * e, axis=-1)
        scale = w * gm_sigma_px / np.sqrt(denom)
        drde = scale[..., None, None] * (eye2 - e[..., :, None] * e[..., None, :] / denom[..., None, None])
    else:
        scale = w
        drde = w[..., None, None] * eye2
    residual = (scale[..., None] * e).reshape(-1)
    if not jacobians:
        return Reprojection(residual, None, valid)

    zero = np.zeros_like(z)
    dedp = np.stack(
        [
            np.stack([fx / z, zero, -fx * p[..., 0] / z**2], axis=-1),
            np.stack([zero, fy / z, -fy * p[..., 1] / z**2], axis=-1),
        ],
        axis=-2,
    )  # (C, K, 2, 3)
    drdp = drde @ dedp
    jac = np.zeros((C, K, 2, P + 6 * C))
    # dp/dX = R_cᵀ
    jac[..., :P] = drdp @ np.swapaxes(R, 1, 2)[:, None] @ fk.d_keypoints[0][None]
    for c in range(C):
        # p ← Exp(-ω)(p - v) under the right perturbation: dp/dω = [p]×, dp/dv = -I.
        jac[c, :, :, P + 6 * c : P + 6 * c + 3] = drdp[c] @ skew(p[c])
        jac[c, :, :, P + 6 * c + 3 : P + 6 * c + 6] = -drdp[c]
    jac *= valid[..., None, None]
    return Reprojection(residual, jac.reshape(2 * C * K, P + 6 * C), valid)


def _check_scalar(value, name: str) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        raise MocapgraphError(f"{name}: expected a number, got {value!r}") from None


def reproject(
    table: BodyTable,
    root,
    pose,
    cameras,
    intrinsics,
    observed,
    obs_weights,
    gm_sigma_px: float,
    min_depth: float = 0.05,
    jacobians: bool = True,
) -> Reprojection:
    """Native reprojection residual and Jacobian of one frame; see the module docstring.

    Raises:
        MocapgraphError: naming the argument, for a wrong shape, a non-finite value (NaN is
            allowed in ``observed`` only), a negative weight, a non-rotation pose block, a
            non-positive focal length or ``min_depth``, or a NaN ``gm_sigma_px``.
    """
    K = table.num_keypoints
    root = as_checked_array(root, "root (world_T_root)", (4, 4))
    pose = as_checked_array(pose, "pose (joint axis-angle)", (NUM_JOINTS - 1, 3))
    cameras = as_checked_array(cameras, "cameras (world_T_camera)", (None, 4, 4))
    C = cameras.shape[0]
    intrinsics = as_checked_array(intrinsics, "intrinsics (fx, fy, cx, cy)", (C, 4))
    observed = as_checked_array(observed, "observed (pixels)", (C, K, 2), finite=False)
    obs_weights = as_checked_array(obs_weights, "obs_weights", (C, K)) * table.mapped[None]
    gm_sigma_px = _check_scalar(gm_sigma_px, "gm_sigma_px")
    min_depth = _check_scalar(min_depth, "min_depth")

    c = np.ascontiguousarray
    try:
        # The binding checks values (rotations, signs, inf, NaN sigma) in C++: done here in numpy
        # they would cost more than the kernel itself. Its ValueErrors name the argument.
        residual, jacobian, valid = native_module().reproject(
            *table_arrays(table),
            c(root),
            c(pose),
            c(cameras),
            c(intrinsics),
            c(observed),
            c(obs_weights),
            gm_sigma_px,
            min_depth,
            bool(jacobians),
        )
    except ValueError as exc:
        raise MocapgraphError(str(exc)) from None
    return Reprojection(residual, jacobian, valid)
