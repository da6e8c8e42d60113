"""Checked noise parameters of the factors: positive sigmas, Pose3 sigmas, robust kernels.

Every factor constructor takes its standard deviations through these, so a bad value is one
:class:`~mocapgraph.errors.MocapgraphError` naming the argument, never a GTSAM exception later.
"""

from __future__ import annotations

import gtsam
import numpy as np

from mocapgraph.errors import MocapgraphError, as_checked_array

KERNELS = {
    # name: (mEstimator, default k giving 95 % efficiency on Gaussian data)
    "huber": (gtsam.noiseModel.mEstimator.Huber, 1.345),
    "cauchy": (gtsam.noiseModel.mEstimator.Cauchy, 2.3849),
    "gm": (gtsam.noiseModel.mEstimator.GemanMcClure, 3.8),
}


def positive(value, name: str, shape: tuple[int, ...] | None = None) -> np.ndarray:
    """``value`` as a float array of positive finite entries (a scalar broadcast to ``shape``)."""
    arr = as_checked_array(value, name, (None,) * np.ndim(value))
    if shape is not None:
        if arr.ndim == 0:
            arr = np.full(shape, float(arr))
        elif arr.shape != shape:
            raise MocapgraphError(f"{name}: expected a scalar or shape {shape}, got {arr.shape}")
    if np.any(arr <= 0):
        raise MocapgraphError(f"{name}: must be > 0")
    return arr


def seconds(dt) -> float:
    """``dt`` as a finite number of seconds > 0."""
    dt = float(dt)
    if not (np.isfinite(dt) and dt > 0):
        raise MocapgraphError(f"dt must be a finite number of seconds > 0, got {dt}")
    return dt


def pose3(matrix, name: str) -> gtsam.Pose3:
    """A ``(4, 4)`` rigid transform as a ``gtsam.Pose3``, its rotation block checked."""
    T = as_checked_array(matrix, name, (4, 4))
    R = T[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-6 or abs(np.linalg.det(R) - 1.0) > 1e-6:
        raise MocapgraphError(f"{name}: the rotation block is not a rotation matrix")
    return gtsam.Pose3(T)


def pose3_sigmas(sigmas, name: str) -> np.ndarray:
    """``(rotation, translation)`` or 6 sigmas (rotation first) as a (6,) array."""
    arr = positive(sigmas, name)
    if arr.shape == (2,):
        return np.repeat(arr, 3)
    if arr.shape != (6,):
        raise MocapgraphError(f"{name}: expected (sigma_rot, sigma_pos) or 6 sigmas (rotation first), got {arr.shape}")
    return arr


def robust_pose_noise(covariance, sigmas, kernel: str, k: float | None):
    """Gaussian noise of a Pose3 residual from ``covariance (6, 6)`` or ``sigmas``, robustified
    by ``kernel`` (one of :data:`KERNELS` or ``"none"``) at ``k`` standard deviations."""
    if (covariance is None) == (sigmas is None):
        raise MocapgraphError("camera prior: give exactly one of covariance (6, 6) and sigmas")
    if covariance is not None:
        cov = as_checked_array(covariance, "covariance (Pose3 tangent, rotation first)", (6, 6))
        if not np.allclose(cov, cov.T) or np.linalg.eigvalsh(0.5 * (cov + cov.T)).min() <= 0:
            raise MocapgraphError("covariance: must be symmetric positive definite")
        gaussian = gtsam.noiseModel.Gaussian.Covariance(cov)
    else:
        gaussian = gtsam.noiseModel.Diagonal.Sigmas(pose3_sigmas(sigmas, "sigmas"))
    if kernel == "none":
        return gaussian
    if kernel not in KERNELS:
        raise MocapgraphError(f"unknown kernel {kernel!r}; choose one of {', '.join(KERNELS)}, none")
    estimator, default_k = KERNELS[kernel]
    k = default_k if k is None else float(positive(k, "k"))
    return gtsam.noiseModel.Robust.Create(estimator.Create(k), gaussian)
