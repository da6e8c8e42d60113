"""Priors on camera poses from their sensors (AirCap's E_{r,p}: camera tracking as a soft constraint).

Built-in Pose3 factors (``PriorFactorPose3``, ``BetweenFactorPose3``: ~1.5 µs per linearisation)
with a robust noise model (:func:`~mocapgraph.factors.noise.robust_pose_noise`).
"""

from __future__ import annotations

import gtsam

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
