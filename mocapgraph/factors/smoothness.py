"""Temporal smoothness of root, cameras, joint rotations and joint positions, with exact Jacobians.

Conventions (``dt`` in seconds):

- **Pose3 smoothness** (:func:`root_smoothness_factor`, :func:`camera_smoothness_factor`) is a
  constant-pose model: the mean body-frame velocity over the step, ``Log(T_a⁻¹ T_b) / dt``
  (rotation first, GTSAM's Pose3 tangent), is ``N(0, diag(σ²))``. Hence the built-in
  ``BetweenFactorPose3`` (~1.5 µs) with the identity and sigmas ``σ·dt``: a longer gap allows
  a larger change.
- **Joint-rotation smoothness** works on the raw axis-angle 63-vector (no wrap-around handling:
  keep consecutive states on the same branch, as an optimiser started from a smooth
  initialisation does). :func:`pose_smoothness_factor` penalises the second derivative (rad/s²)
  with the three-point formula for non-uniform steps; :func:`pose_velocity_factor` the first
  (rad/s). Both are linear factors with constant Jacobians (:mod:`mocapgraph.factors.linear`).
  Each factor's cost does not depend on the frame rate, so more frames per second mean more
  factors and a smoother fit at the same σ.
- **3D joint smoothness** (:func:`joint_smoothness_factor`, SmartMocap's E_smooth on joint
  positions): the joints' mean velocity ``(J_b − J_a) / dt`` (m/s, world frame) is
  ``N(0, σ² I)``, 66 rows. Unlike the joint rotations' smoothness it weighs a rotation by how
  far it moves the limbs, so a wrist's jitter costs more than a twist of the forearm that moves
  nothing.
"""

from __future__ import annotations

import gtsam
import numpy as np

from mocapgraph.body.skeleton import NUM_JOINTS
from mocapgraph.errors import MocapgraphError, as_checked_array
from mocapgraph.factors.linear import DiagonalLinear
from mocapgraph.factors.noise import pose3_sigmas, positive, seconds
from mocapgraph.factors.reprojection import POSE_DIM, ShapeTableCache


def root_smoothness_factor(key_a: int, key_b: int, dt: float, sigmas) -> gtsam.BetweenFactorPose3:
    """Constant-pose smoothness between two root poses ``dt`` seconds apart.

    Args:
        sigmas: velocity standard deviations ``(rad/s, m/s)`` or 6 of them (rotation first),
            in the earlier root's frame; the factor's sigmas are ``sigmas · dt``.
    """
    noise = gtsam.noiseModel.Diagonal.Sigmas(pose3_sigmas(sigmas, "sigmas") * seconds(dt))
    return gtsam.BetweenFactorPose3(key_a, key_b, gtsam.Pose3(), noise)


def camera_smoothness_factor(
    key_a: int, key_b: int, dt: float, sigma_rot_rad_per_s: float, sigma_pos_m_per_s: float
) -> gtsam.BetweenFactorPose3:
    """Constant-pose smoothness between two poses of one camera ``dt`` seconds apart.

    The mean angular and linear velocity over the step (in the earlier camera frame) are zero
    with standard deviations ``sigma_rot_rad_per_s`` and ``sigma_pos_m_per_s``.
    """
    return root_smoothness_factor(key_a, key_b, dt, (sigma_rot_rad_per_s, sigma_pos_m_per_s))


def camera_acceleration_factor(keys, times, sigma_m_s2: float) -> gtsam.CustomFactor:
    """Constant-velocity model of a moving camera's centre over three consecutive poses.

    Residual ``(c0 p0 + c1 p1 + c2 p2) / σ`` (3,): the three-point second derivative
    (:func:`second_difference_coefficients`) of the centres ``p_i`` (world frame, metres), so
    the velocity is free and its change costs. A pose that goes round the person for a few
    frames (to explain a detector's left/right swap) needs hundreds of m/s² here, where the
    constant-pose factor (:func:`camera_smoothness_factor`) charges only its speed.

    Args:
        keys: the three ``world_T_camera`` Pose3 keys in time order.
        times: ``(3,)`` their times in seconds, strictly increasing.
        sigma_m_s2: standard deviation of the acceleration per axis, m/s².
    """
    keys = [int(k) for k in keys]
    if len(keys) != 3:
        raise MocapgraphError(f"camera_acceleration_factor needs 3 consecutive camera keys, got {len(keys)}")
    scaled = second_difference_coefficients(times) / float(positive(sigma_m_s2, "sigma_m_s2"))

    def error(this, values: gtsam.Values, H) -> np.ndarray:
        poses = [values.atPose3(k) for k in keys]
        if H is not None:
            # The Pose3 tangent moves the centre by R v (rotation first): d p / d v = R.
            for i, (pose, c) in enumerate(zip(poses, scaled)):
                H[i] = np.hstack([np.zeros((3, 3)), c * pose.rotation().matrix()])
        return sum(c * pose.translation() for pose, c in zip(poses, scaled))

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(3), keys, error)


def rotation_acceleration_factor(keys, times, sigma_rad_s2: float) -> gtsam.CustomFactor:
    """Constant angular velocity of three consecutive poses' rotations (e.g. the body's root).

    Residual ``(ω₁₂ − ω₀₁) / ((t₂ − t₀) / 2) / σ`` (3,) with ``ω₀₁ = Log(R₀ᵀ R₁) / (t₁ − t₀)`` and
    ``ω₁₂ = Log(R₁ᵀ R₂) / (t₂ − t₁)``, rad/s: both in the middle pose's frame (``Log(R₀ᵀ R₁)`` is
    the rotation's own axis, the same in either of its frames), so a pose turning at a constant
    body-frame rate costs nothing and the change of rate costs. The translations are free (the
    centre's is :func:`camera_acceleration_factor`).

    Args:
        keys: the three Pose3 keys in time order.
        times: ``(3,)`` their times in seconds, strictly increasing.
        sigma_rad_s2: standard deviation of the angular acceleration per axis, rad/s².
    """
    keys = [int(k) for k in keys]
    if len(keys) != 3:
        raise MocapgraphError(f"rotation_acceleration_factor needs 3 consecutive keys, got {len(keys)}")
    t = as_checked_array(times, "times (seconds)", (3,))
    second_difference_coefficients(t)  # checks the times increase
    h1, h2 = t[1] - t[0], t[2] - t[1]
    k = 2.0 / ((h1 + h2) * float(positive(sigma_rad_s2, "sigma_rad_s2")))

    def error(this, values: gtsam.Values, H) -> np.ndarray:
        R = [values.atPose3(key).rotation() for key in keys]
        A, B = R[0].between(R[1]), R[1].between(R[2])
        a, b = gtsam.Rot3.Logmap(A), gtsam.Rot3.Logmap(B)
        if H is not None:
            # right perturbations R_i Exp(d_i): Log(A) moves by Jr⁻¹(a) (d_1 − Aᵀ d_0), Log(B) by Jr⁻¹(b) (d_2 − Bᵀ d_1)
            Ja, Jb = gtsam.Rot3.LogmapDerivative(a), gtsam.Rot3.LogmapDerivative(b)
            blocks = (k * Ja @ A.matrix().T / h1, -k * (Jb @ B.matrix().T / h2 + Ja / h1), k * Jb / h2)
            for i, block in enumerate(blocks):
                H[i] = np.hstack([block, np.zeros((3, 3))])
        return k * (b / h2 - a / h1)

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(3), keys, error)


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
    inv_sigma = 1.0 / positive(sigma_rad_per_s2, "sigma_rad_per_s2", (POSE_DIM,))
    coeffs = second_difference_coefficients(times)
    return DiagonalLinear(keys, [c * inv_sigma for c in coeffs], np.zeros(POSE_DIM)).factor()


def pose_velocity_factor(key_a: int, key_b: int, dt: float, sigma_rad_per_s) -> gtsam.CustomFactor:
    """First-order smoothness of two joint-rotation states: residual ``(θ_b − θ_a) / (dt σ)`` (63,).

    Args:
        sigma_rad_per_s: scalar or ``(63,)`` standard deviation of the angular velocity.
    """
    inv = 1.0 / (seconds(dt) * positive(sigma_rad_per_s, "sigma_rad_per_s", (POSE_DIM,)))
    return DiagonalLinear([key_a, key_b], [-inv, inv], np.zeros(POSE_DIM)).factor()


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
