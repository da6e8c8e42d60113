"""Priors and smoothness factors on cameras, root, joint rotations and shape, all with exact Jacobians.

Factor types, chosen by measured ``graph.linearize`` cost:

- Pose3 factors are GTSAM built-ins (``PriorFactorPose3``, ``BetweenFactorPose3``: ~1.5 µs).
- :func:`pose_regularizer_factor` is the built-in ``PriorFactorVector`` (~7 µs for 63-d; its
  Jacobian is a fixed identity). GTSAM's ``BetweenFactorVector`` on a 63-vector, in contrast,
  costs ~95 µs (dynamic-size Lie Jacobians, see the GTSAM performance notes).
- The other vector factors are linear CustomFactors with constant, precomputed Jacobians
  and a unit noise model (they whiten themselves, so ``factor.error(v) = ½‖residual‖²``):
  ~38 µs for the 3×63 second difference, most of it GTSAM copying the three 63×63
  Jacobians; a ``LinearContainerFactor`` of the same ``JacobianFactor`` would take ~7 µs.

Smoothness conventions (``dt`` in seconds):

- **Pose3 smoothness** (:func:`root_smoothness_factor`, :func:`camera_smoothness_factor`) is a
  constant-pose model: the mean body-frame velocity over the step, ``Log(T_a⁻¹ T_b) / dt``
  (rotation first, GTSAM's Pose3 tangent), is ``N(0, diag(σ²))``. Hence the
  ``BetweenFactorPose3`` with the identity and sigmas ``σ·dt``: a longer gap allows a larger change.
- **Joint-rotation smoothness** works on the raw axis-angle 63-vector (no wrap-around handling:
  keep consecutive states on the same branch, as an optimiser started from a smooth
  initialisation does). :func:`pose_smoothness_factor` penalises the second derivative (rad/s²)
  with the three-point formula for non-uniform steps; :func:`pose_velocity_factor` the first
  (rad/s), for sequences of two states. Each factor's cost does not depend on the frame rate, so
  more frames per second mean more factors and a smoother fit at the same σ.

Learned pose priors come as further factors on the same ``pose_key``; nothing here changes.
"""

from __future__ import annotations

import gtsam
import numpy as np

from mocapgraph.errors import MocapgraphError, as_checked_array

POSE_DIM = 63

_KERNELS = {
    # name: (mEstimator, default k giving 95 % efficiency on Gaussian data)
    "huber": (gtsam.noiseModel.mEstimator.Huber, 1.345),
    "cauchy": (gtsam.noiseModel.mEstimator.Cauchy, 2.3849),
    "gm": (gtsam.noiseModel.mEstimator.GemanMcClure, 3.8),
}


def _positive(value, name: str, shape: tuple[int, ...] | None = None) -> np.ndarray:
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


def _pose3(matrix, name: str) -> gtsam.Pose3:
    T = as_checked_array(matrix, name, (4, 4))
    R = T[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-6 or abs(np.linalg.det(R) - 1.0) > 1e-6:
        raise MocapgraphError(f"{name}: the rotation block is not a rotation matrix")
    return gtsam.Pose3(T)


def _pose3_sigmas(sigmas, name: str) -> np.ndarray:
    """``(rotation, translation)`` or 6 sigmas (rotation first) as a (6,) array."""
    arr = _positive(sigmas, name)
    if arr.shape == (2,):
        return np.repeat(arr, 3)
    if arr.shape != (6,):
        raise MocapgraphError(f"{name}: expected (sigma_rot, sigma_pos) or 6 sigmas (rotation first), got {arr.shape}")
    return arr


def _dt(dt) -> float:
    dt = float(dt)
    if not (np.isfinite(dt) and dt > 0):
        raise MocapgraphError(f"dt must be a finite number of seconds > 0, got {dt}")
    return dt


# --- Pose3 factors (built-in) -------------------------------------------------------------------


def camera_prior_factor(
    key: int,
    world_T_camera_prior,
    covariance=None,
    *,
    sigmas=None,
    kernel: str = "huber",
    k: float | None = None,
) -> gtsam.PriorFactorPose3:
    """Robust prior on a camera pose (AirCap's E_{r,p}: camera tracking as a soft constraint).

    Args:
        key: the camera's ``Pose3`` key.
        world_T_camera_prior: ``(4, 4)`` the tracked camera pose.
        covariance: ``(6, 6)`` in GTSAM's Pose3 tangent at the prior (rotation rad², then
            translation m², right perturbation); or give ``sigmas`` instead.
        sigmas: ``(6,)`` standard deviations, rotation first, or ``(sigma_rot, sigma_pos)``.
        kernel: ``"huber"``, ``"cauchy"``, ``"gm"`` (Geman-McClure) or ``"none"`` (Gaussian).
        k: kernel threshold in standard deviations of the whitened 6-vector (the kernel acts on
            its norm); default 1.345 / 2.3849 / 3.8, each 95 % efficient on Gaussian data.

    Returns:
        ``gtsam.PriorFactorPose3``; its error is the mEstimator's loss of the Mahalanobis
        distance, its linearisation GTSAM's reweighted (IRLS) one.
    """
    prior = _pose3(world_T_camera_prior, "world_T_camera_prior")
    return gtsam.PriorFactorPose3(key, prior, _robust_pose_noise(covariance, sigmas, kernel, k))


def camera_offset_prior_factor(
    offset_key: int,
    key: int,
    world_T_camera_prior,
    covariance=None,
    *,
    sigmas=None,
    kernel: str = "huber",
    k: float | None = None,
) -> gtsam.BetweenFactorPose3:
    """Camera prior relative to a shared world-frame offset: ``world_T_camera ≈ O · prior``.

    GPS/IMU trajectories drift slowly, so their errors at nearby frames are nearly the same; one
    offset ``O`` (a ``Pose3`` near identity, with its own prior) per camera carries that common
    error, and ``covariance`` is then only the frame-to-frame part. Without it, independent priors
    on every frame would average the common error away and report it far too confidently.
    Arguments as :func:`camera_prior_factor`.
    """
    prior = _pose3(world_T_camera_prior, "world_T_camera_prior")
    return gtsam.BetweenFactorPose3(offset_key, key, prior, _robust_pose_noise(covariance, sigmas, kernel, k))


def _robust_pose_noise(covariance, sigmas, kernel: str, k: float | None):
    """Gaussian noise of a Pose3 residual from ``covariance (6, 6)`` or ``sigmas``, robustified."""
    if (covariance is None) == (sigmas is None):
        raise MocapgraphError("camera prior: give exactly one of covariance (6, 6) and sigmas")
    if covariance is not None:
        cov = as_checked_array(covariance, "covariance (Pose3 tangent, rotation first)", (6, 6))
        if not np.allclose(cov, cov.T) or np.linalg.eigvalsh(0.5 * (cov + cov.T)).min() <= 0:
            raise MocapgraphError("covariance: must be symmetric positive definite")
        gaussian = gtsam.noiseModel.Gaussian.Covariance(cov)
    else:
        gaussian = gtsam.noiseModel.Diagonal.Sigmas(_pose3_sigmas(sigmas, "sigmas"))
    if kernel == "none":
        return gaussian
    if kernel not in _KERNELS:
        raise MocapgraphError(f"unknown kernel {kernel!r}; choose one of {', '.join(_KERNELS)}, none")
    estimator, default_k = _KERNELS[kernel]
    k = default_k if k is None else float(_positive(k, "k"))
    return gtsam.noiseModel.Robust.Create(estimator.Create(k), gaussian)


def root_smoothness_factor(key_a: int, key_b: int, dt: float, sigmas) -> gtsam.BetweenFactorPose3:
    """Constant-pose smoothness between two root poses ``dt`` seconds apart.

    Args:
        sigmas: velocity standard deviations ``(rad/s, m/s)`` or 6 of them (rotation first),
            in the earlier root's frame; the factor's sigmas are ``sigmas · dt``.
    """
    noise = gtsam.noiseModel.Diagonal.Sigmas(_pose3_sigmas(sigmas, "sigmas") * _dt(dt))
    return gtsam.BetweenFactorPose3(key_a, key_b, gtsam.Pose3(), noise)


def camera_smoothness_factor(
    key_a: int, key_b: int, dt: float, sigma_rot_rad_per_s: float, sigma_pos_m_per_s: float
) -> gtsam.BetweenFactorPose3:
    """Constant-pose smoothness between two poses of one camera ``dt`` seconds apart.

    The mean angular and linear velocity over the step (in the earlier camera frame) are zero
    with standard deviations ``sigma_rot_rad_per_s`` and ``sigma_pos_m_per_s``.
    """
    return root_smoothness_factor(key_a, key_b, dt, (sigma_rot_rad_per_s, sigma_pos_m_per_s))


# --- linear vector factors (CustomFactor, constant Jacobians) -----------------------------------


class _DiagonalLinear:
    """Residual ``Σ_i a_i ⊙ x_i − b`` of vector variables; Jacobians ``diag(a_i)``, built once."""

    def __init__(self, keys, diagonals, offset):
        self.keys = [int(k) for k in keys]
        self.diagonals = [np.asarray(a, dtype=float) for a in diagonals]
        self.offset = np.asarray(offset, dtype=float)
        # Column-major: GTSAM copies them into Eigen matrices as they are.
        self.jacobians = [np.asfortranarray(np.diag(a)) for a in self.diagonals]
        if len(set(self.keys)) != len(self.keys):
            raise MocapgraphError("the keys of a smoothness factor must all differ")

    def __call__(self, this, values: gtsam.Values, H) -> np.ndarray:
        r = -self.offset
        for key, a in zip(self.keys, self.diagonals):
            r = r + a * values.atVector(key)
        if H is not None:
            for i, J in enumerate(self.jacobians):
                H[i] = J
        return r

    def factor(self) -> gtsam.CustomFactor:
        return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(len(self.offset)), self.keys, self)


def second_difference_coefficients(times) -> np.ndarray:
    """``(c0, c1, c2)`` with ``f''(t1) ≈ c0 f(t0) + c1 f(t1) + c2 f(t2)``, exact for quadratics.

    With ``h1 = t1 − t0`` and ``h2 = t2 − t1``:
    ``c0 = 2/(h1(h1+h2))``, ``c1 = −2/(h1 h2)``, ``c2 = 2/(h2(h1+h2))``.
    """
    t = as_checked_array(times, "times (seconds)", (3,))
    h1, h2 = t[1] - t[0], t[2] - t[1]
    if not (h1 > 0 and h2 > 0):
        raise MocapgraphError(f"times must increase strictly, got {t.tolist()}")
    return np.array([2.0 / (h1 * (h1 + h2)), -2.0 / (h1 * h2), 2.0 / (h2 * (h1 + h2))])


def pose_smoothness_factor(keys, times, sigma_rad_per_s2) -> gtsam.CustomFactor:
    """Second-order smoothness of three consecutive joint-rotation states (any time steps).

    Residual ``(c0 θ0 + c1 θ1 + c2 θ2) / σ`` (63,), the three-point second derivative of
    :func:`second_difference_coefficients`.

    Args:
        keys: the three pose keys in time order.
        times: ``(3,)`` their times in seconds, strictly increasing.
        sigma_rad_per_s2: scalar or ``(63,)`` standard deviation of the angular acceleration.
    """
    keys = list(keys)
    if len(keys) != 3:
        raise MocapgraphError(f"pose_smoothness_factor needs 3 consecutive pose keys, got {len(keys)}")
    inv_sigma = 1.0 / _positive(sigma_rad_per_s2, "sigma_rad_per_s2", (POSE_DIM,))
    coeffs = second_difference_coefficients(times)
    return _DiagonalLinear(keys, [c * inv_sigma for c in coeffs], np.zeros(POSE_DIM)).factor()


def pose_velocity_factor(key_a: int, key_b: int, dt: float, sigma_rad_per_s) -> gtsam.CustomFactor:
    """First-order smoothness of two joint-rotation states: residual ``(θ_b − θ_a) / (dt σ)`` (63,).

    Args:
        sigma_rad_per_s: scalar or ``(63,)`` standard deviation of the angular velocity.
    """
    inv = 1.0 / (_dt(dt) * _positive(sigma_rad_per_s, "sigma_rad_per_s", (POSE_DIM,)))
    return _DiagonalLinear([key_a, key_b], [-inv, inv], np.zeros(POSE_DIM)).factor()


def shape_prior_factor(key: int, mean, sigma) -> gtsam.CustomFactor:
    """Gaussian prior on the shape vector: residual ``(β − mean) / sigma`` (S,).

    Args:
        mean: ``(S,)``, e.g. ``body.default_shape``.
        sigma: scalar or ``(S,)``, in the shape's own units.
    """
    mean = as_checked_array(mean, "mean (shape)", (None,))
    inv = 1.0 / _positive(sigma, "sigma (shape)", mean.shape)
    return _DiagonalLinear([key], [inv], mean * inv).factor()


def pose_regularizer_factor(key: int, sigma_rad, mean=None) -> gtsam.PriorFactorVector:
    """Gaussian prior on one state's joint rotations: whitened residual ``(θ − mean) / sigma_rad`` (63,).

    A built-in ``PriorFactorVector`` with a diagonal noise model (exact: identity Jacobian).

    Args:
        sigma_rad: scalar or ``(63,)`` standard deviation, radians.
        mean: ``(63,)`` or ``(21, 3)`` axis-angle; default the neutral T-pose (zeros).
    """
    mean = np.zeros(POSE_DIM) if mean is None else as_checked_array(mean, "mean (pose)", (None,) * np.ndim(mean))
    if mean.size != POSE_DIM:
        raise MocapgraphError(f"mean (pose): expected 63 values ((63,) or (21, 3)), got shape {mean.shape}")
    sigma = _positive(sigma_rad, "sigma_rad", (POSE_DIM,))
    return gtsam.PriorFactorVector(key, mean.reshape(POSE_DIM), gtsam.noiseModel.Diagonal.Sigmas(sigma))
