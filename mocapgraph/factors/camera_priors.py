"""Priors on camera poses from their sensors (AirCap's E_{r,p}: camera tracking as a soft constraint).

Built-in Pose3 factors (``PriorFactorPose3``, ``BetweenFactorPose3``: ~1.5 µs per linearisation)
with a robust noise model (:func:`~mocapgraph.factors.noise.robust_pose_noise`); and a camera's
gyroscope on its rotation relative to a reference camera (:func:`camera_gyro_factor`, AirPose+'s
world), a ``CustomFactor``.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from mocapgraph.errors import MocapgraphError
from mocapgraph.factors.noise import pose3, robust_pose_noise


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
    prior = pose3(world_T_camera_prior, "world_T_camera_prior")
    return gtsam.PriorFactorPose3(key, prior, robust_pose_noise(covariance, sigmas, kernel, k))


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
    prior = pose3(world_T_camera_prior, "world_T_camera_prior")
    return gtsam.BetweenFactorPose3(offset_key, key, prior, robust_pose_noise(covariance, sigmas, kernel, k))


def camera_motion_prior_factor(
    key_a: int,
    key_b: int,
    a_T_b,
    *,
    sigmas,
    kernel: str = "huber",
    k: float | None = None,
) -> gtsam.BetweenFactorPose3:
    """Prior on a camera's motion between two of its frames: ``inv(world_T_a) · world_T_b ≈ a_T_b``.

    A reconstruction of the background (COLMAP) knows a camera's track up to a similarity of its
    world: the motion between two frames, in the first frame's axes, depends on that world's
    scale only, not on its orientation or origin. Once ``a_T_b``'s translation is in metres, the
    prior holds the track's shape and leaves its placement to the other factors.

    Args:
        key_a, key_b: the camera's ``Pose3`` keys at the two frames.
        a_T_b: ``(4, 4)`` the motion, translation in metres.
        sigmas: ``(6,)`` or ``(sigma_rot rad, sigma_pos m)``, rotation first.
        kernel, k: as :func:`camera_prior_factor` (a frame the reconstruction got wrong is an outlier).
    """
    motion = pose3(a_T_b, "a_T_b")
    return gtsam.BetweenFactorPose3(key_a, key_b, motion, robust_pose_noise(None, sigmas, kernel, k))


@dataclass(frozen=True)
class GyroIncrement:
    """A gyroscope's rotation between two camera frames, preintegrated at zero bias.

    Attributes:
        rotation: ``(3, 3)`` ``ΔR = R(t_a)ᵀ R(t_b)`` of the camera (its own axes), zero bias.
        bias_jacobian: ``(3, 3)`` ``J`` of the first-order bias correction ``ΔR(b) = ΔR Exp(J b)``
            (``b`` the gyroscope bias, rad/s).
        covariance: ``(3, 3)`` of ``Log(ΔR)``'s error from the gyroscope's white noise, rad².
    """

    rotation: np.ndarray
    bias_jacobian: np.ndarray
    covariance: np.ndarray

    def at(self, bias: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``ΔR(b)`` ``(3, 3)`` and ``∂Log/∂b`` ``(3, 3)``: ``ΔR(b + δ) = ΔR(b) Exp(Jr(J b) J δ)``."""
        phi = self.bias_jacobian @ bias
        return self.rotation @ gtsam.Rot3.Expmap(phi).matrix(), gtsam.Rot3.ExpmapDerivative(phi) @ self.bias_jacobian


def camera_gyro_factor(
    key_a: int, key_b: int, bias_key: int, increment: GyroIncrement, *, reference_bias_key: int | None = None, reference: GyroIncrement | None = None
) -> gtsam.CustomFactor:
    """A moving camera's gyroscope on its rotation relative to a reference camera's frame.

    The camera's poses ``X_a``, ``X_b`` (Pose3 keys, ``ref_T_camera`` at two frames) are
    relative to a reference camera whose own rotation from ``t_a`` to ``t_b`` is ``ΔR_r`` (the
    identity when it stands still, else its own gyroscope's ``reference`` with its bias at
    ``reference_bias_key``). Since ``ref_R_c(t) = R_r(t)ᵀ R_c(t)``:

        r = Log( (ΔR_r(b_r)ᵀ R_a ΔR_c(b_c))ᵀ R_b )         (3,) rad

    with ``b`` the gyroscope parts of ``imuBias.ConstantBias`` keys (accelerometer first, not
    touched). Noise: the increments' covariances added (the reference's isotropically, by its
    trace, since its axes turn with the state). The translation is free: in a frame whose
    gravity direction is unknown the accelerometer says nothing about it.

    Jacobians (right perturbations, ``E = Aᵀ R_b``, ``A = ΔR_rᵀ R_a ΔR_c``, ``Jr⁻¹ = Jr⁻¹(r)``):
    ``∂r/∂ω_b = Jr⁻¹``, ``∂r/∂ω_a = −Jr⁻¹ Eᵀ ΔR_cᵀ``, ``∂r/∂b_c = −Jr⁻¹ Eᵀ Jr(J_c b_c) J_c``,
    ``∂r/∂b_r = Jr⁻¹ R_bᵀ Jr(J_r b_r) J_r``; zero for the translations and the accelerometer biases.
    """
    keys = [int(key_a), int(key_b), int(bias_key)]
    if (reference is None) != (reference_bias_key is None):
        raise MocapgraphError("camera_gyro_factor: give the reference camera's increment and its bias key together, or neither")
    covariance = np.asarray(increment.covariance, dtype=float)
    if reference is not None:
        keys.append(int(reference_bias_key))
        covariance = covariance + np.trace(reference.covariance) / 3.0 * np.eye(3)
    zeros = np.zeros((3, 3))

    def error(_factor, values, H):
        Ra, Rb = values.atPose3(keys[0]).rotation().matrix(), values.atPose3(keys[1]).rotation().matrix()
        dRc, Jc = increment.at(values.atConstantBias(keys[2]).gyroscope())
        dRr, Jr_ = (np.eye(3), None) if reference is None else reference.at(values.atConstantBias(keys[3]).gyroscope())
        A = dRr.T @ Ra @ dRc
        E = A.T @ Rb
        r = gtsam.Rot3.Logmap(gtsam.Rot3(E))
        if H is not None:
            inv = gtsam.Rot3.LogmapDerivative(r)
            H[0] = np.hstack([-inv @ E.T @ dRc.T, zeros])
            H[1] = np.hstack([inv, zeros])
            H[2] = np.hstack([zeros, -inv @ E.T @ Jc])
            if reference is not None:
                H[3] = np.hstack([zeros, inv @ Rb.T @ Jr_])
        return r

    return gtsam.CustomFactor(gtsam.noiseModel.Gaussian.Covariance(covariance), keys, error)


def camera_points_factor(key: int, points, observed, K, sigma_px: float, huber_rms_sigmas: float | None = None) -> gtsam.CustomFactor:
    """A camera's view of known points: the pixel residuals ``π(K, X⁻¹ p_k) − z_k`` of points
    ``p_k`` held where they are (e.g. a solved body's keypoints), the camera pose ``X``
    (world_T_camera, Pose3 ``key``) the only variable.

    Args:
        points: ``(N, 3)`` world, metres, in front of the camera.
        observed: ``(N, 2)`` undistorted pixels.
        K: ``(3, 3)`` intrinsics.
        sigma_px: the pixel noise.
        huber_rms_sigmas: Huber on the whole view (GTSAM's robust models weigh a factor by the
            norm of its whitened residual): down-weighted once its root-mean-square error
            exceeds this many ``sigma_px`` (None: Gaussian), so that a view with swapped or wrong
            points does not pull the camera.

    Jacobians: with ``q = Rᵀ(p − t)`` in the camera, GTSAM's retraction ``(R Exp(ω), t + R v)``
    gives ``∂q/∂ω = [q]×``, ``∂q/∂v = −I``; ``∂π/∂q = f/q_z [[1, 0, −q_x/q_z], [0, 1, −q_y/q_z]]``.
    """
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    observed = np.asarray(observed, dtype=float).reshape(-1, 2)
    if len(points) != len(observed) or not len(points):
        raise MocapgraphError(f"camera_points_factor: {len(points)} points against {len(observed)} observations; need as many, at least one")
    K = np.asarray(K, dtype=float)
    focal, centre = np.array([K[0, 0], K[1, 1]]), K[:2, 2]
    noise = gtsam.noiseModel.Isotropic.Sigma(2 * len(points), float(sigma_px))
    if huber_rms_sigmas is not None:
        noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(float(huber_rms_sigmas) * np.sqrt(2 * len(points))), noise)

    def error(_factor, values, H):
        pose = values.atPose3(key)
        R = pose.rotation().matrix()
        q = (points - pose.translation()) @ R
        z = q[:, 2:3]
        r = focal * q[:, :2] / z + centre - observed
        if H is not None:
            dpi = np.zeros((len(q), 2, 3))
            dpi[:, 0, 0], dpi[:, 1, 1] = focal[0] / z[:, 0], focal[1] / z[:, 0]
            dpi[:, :, 2] = -focal * q[:, :2] / z**2
            skew = np.zeros((len(q), 3, 3))
            skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -q[:, 2], q[:, 1], -q[:, 0]
            skew -= np.swapaxes(skew, 1, 2)
            H[0] = np.concatenate([dpi @ skew, -dpi], axis=2).reshape(-1, 6)
        return r.ravel()

    return gtsam.CustomFactor(noise, [int(key)], error)
