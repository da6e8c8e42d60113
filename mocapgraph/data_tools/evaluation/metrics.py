"""Accuracy metrics of bodies and cameras against (pseudo) ground truth, as the papers define them.

Every metric is a function whose name carries its unit (``mpjpe_m``, ``moe_rad``, …) and returns
a :class:`MetricResult`: the value, its :class:`Unit`, how many samples were used and how many
were excluded, and usually a per-frame or per-joint array. ``docs/metrics.md`` tabulates the
definitions, the paper each mirrors and the alignment each uses.

Conventions:

- Estimates may contain NaN: a NaN anywhere in a joint / point / pose marks that sample missing;
  it is excluded and counted in ``MetricResult.excluded``. Inf is an error.
- References must be finite (slice missing ground truth away before calling).
- A shape that does not fit raises :class:`~mocapgraph.errors.MocapgraphError` naming the argument.
- Poses are ``world_T_x (…, 4, 4)`` (rotation = x → world, translation = x's position);
  rotation matrices ``(…, 3, 3)`` and axis-angle ``(…, 3)`` in radians.
- When every sample is missing, ``value`` is NaN and ``count`` is 0 (no exception, so one failed
  sequence does not stop a report).
- These functions do not align frames except where the metric's definition says so (PA-, RA-,
  MPVPE); aligning a pipeline's world to the reference's (e.g. :func:`procrustes_trajectory`) is
  the caller's step, done once for all metrics.

References:
    AirCap: N. Saini et al., "Markerless outdoor human motion capture using multiple autonomous
    micro aerial vehicles", ICCV 2019; joint angle error as in the AirCap write-up's Table 2.1.
    AirPose: N. Saini et al., IJCV 2022. SmartMocap: N. Saini et al., IEEE RA-L 2023.
    Acceleration error: A. Kanazawa et al., "Learning 3D human dynamics from video", CVPR 2019.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum, unique

import numpy as np

from mocapgraph.body.rotations import matrix_to_rotvec, rotvec_to_matrix
from mocapgraph.body.skeleton import NUM_JOINTS
from mocapgraph.data_tools.evaluation.alignment import _fit_similarity
from mocapgraph.data_tools.io.files import Where, check_array, check_rotations
from mocapgraph.errors import MocapgraphError, as_checked_array


@unique
class Unit(str, Enum):
    """The unit of a :class:`MetricResult`; the value is the printed symbol."""

    METRE = "m"
    RADIAN = "rad"
    METRE_PER_SECOND_SQUARED = "m/s²"
    METRE_PER_SECOND_CUBED = "m/s³"
    COUNT = "count"
    FRACTION = "fraction"


@dataclass(frozen=True, eq=False)
class MetricResult:
    """One metric's outcome.

    Attributes:
        value: the mean over the samples used (NaN when none was usable), in ``unit``.
        unit: :class:`Unit` of ``value`` and ``per_item``.
        count: samples used (e.g. (frame, joint) pairs for MPJPE, frames for MPE).
        excluded: samples left out because the estimate was missing (NaN).
        per_item: per-frame or per-joint breakdown (each metric's docstring says which);
            NaN where an item had no usable sample.
    """

    value: float
    unit: Unit
    count: int
    excluded: int
    per_item: np.ndarray | None = None

    def __float__(self) -> float:
        return float(self.value)

    def __str__(self) -> str:
        return f"{self.value:.6g} {self.unit.value} ({self.count} used, {self.excluded} excluded)"


# ---- input checks and reductions ----------------------------------------------------------------


def _estimate(value, name: str, shape: tuple[int | None, ...]) -> np.ndarray:
    """An estimate: float array of ``shape``; NaN allowed (missing), inf not."""
    return check_array(value, Where(name), shape, allow_nan=True)


def _fps(fps) -> float:
    try:
        fps = float(fps)
    except (TypeError, ValueError):
        raise MocapgraphError(f"fps: expected a number, got {fps!r}") from None
    if not (np.isfinite(fps) and fps > 0):
        raise MocapgraphError(f"fps: must be positive and finite, got {fps!r}")
    return fps


def _usable(arr: np.ndarray, item_dims: int) -> np.ndarray:
    """True where every entry of the trailing ``item_dims`` axes is finite."""
    return np.all(np.isfinite(arr), axis=tuple(range(-item_dims, 0)))


def _check_poses(poses: np.ndarray, name: str) -> None:
    """The finite ``(…, 4, 4)`` poses are rigid transforms (rotation to 1e-6, last row 0 0 0 1)."""
    finite = poses[_usable(poses, 2)]
    check_rotations(finite[:, :3, :3], Where(name))
    if np.abs(finite[:, 3] - [0.0, 0.0, 0.0, 1.0]).max(initial=0.0) > 1e-9:
        raise MocapgraphError(f"{name}: last row of a 4×4 pose must be [0, 0, 0, 1]")


def _rotations(value, name: str, shape: tuple[int | None, ...], *, estimate: bool) -> np.ndarray:
    """Rotation matrices of ``shape`` (ending 3, 3); NaN matrices allowed for an estimate."""
    arr = _estimate(value, name, shape) if estimate else as_checked_array(value, name, shape)
    check_rotations(arr[_usable(arr, 2)], Where(name))
    return arr


def _geodesic_rad(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """``(…, 3, 3)`` pairs → ``(…)`` angle of ``Raᵀ Rb`` in [0, π]; NaN where ``Ra`` has NaN."""
    ok = _usable(Ra, 2) & _usable(Rb, 2)
    relative = np.where(ok[..., None, None], np.swapaxes(Ra, -1, -2) @ Rb, np.eye(3))
    return np.where(ok, np.linalg.norm(matrix_to_rotvec(relative), axis=-1), np.nan)


def _nanmean(errors: np.ndarray, axis: int) -> np.ndarray:
    """Mean of the finite entries along ``axis``; NaN (without a warning) where there are none."""
    ok = np.isfinite(errors)
    total = np.sum(np.where(ok, errors, 0.0), axis=axis)
    n = np.sum(ok, axis=axis)
    return np.divide(total, n, out=np.full(total.shape, np.nan), where=n > 0)


def _summarise(errors: np.ndarray, unit: Unit, per_item: np.ndarray | None) -> MetricResult:
    """Mean over the finite entries of ``errors`` (NaN = excluded sample)."""
    ok = np.isfinite(errors)
    count = int(np.count_nonzero(ok))
    value = float(np.mean(errors[ok])) if count else float("nan")
    return MetricResult(value, unit, count, int(errors.size - count), per_item)


def _per_frame(errors: np.ndarray, unit: Unit) -> MetricResult:
    """``errors (T, …)`` → result with the per-frame mean as ``per_item (T,)``."""
    return _summarise(errors, unit, _nanmean(errors.reshape(errors.shape[0], -1), axis=1))


def _joint_pair(est, ref, est_name: str = "est", ref_name: str = "ref"):
    """Checked ``est (T, J, 3)`` (NaN allowed) and ``ref`` of the same shape (finite)."""
    est = _estimate(est, est_name, (None, None, 3))
    return est, as_checked_array(ref, ref_name, est.shape)


# ---- joint positions ----------------------------------------------------------------------------


def mpjpe_m(est: np.ndarray, ref: np.ndarray) -> MetricResult:
    """Mean per-joint position error, metres, with no alignment.

    ``MPJPE = mean_{t,j} ‖est_tj − ref_tj‖`` over the (frame, joint) pairs whose estimate is finite.

    Args:
        est: ``(T, J, 3)`` estimated joints, metres; NaN = missing joint.
        ref: ``(T, J, 3)`` reference joints, metres, same frame as ``est``.

    Returns:
        :class:`MetricResult` in metres; ``per_item`` is the per-frame MPJPE ``(T,)``.
    """
    est, ref = _joint_pair(est, ref)
    return _per_frame(np.linalg.norm(est - ref, axis=-1), Unit.METRE)


def per_joint_position_error_m(est: np.ndarray, ref: np.ndarray) -> MetricResult:
    """MPJPE broken down by joint: ``per_item[j] = mean_t ‖est_tj − ref_tj‖``, metres, ``(J,)``.

    Same inputs as :func:`mpjpe_m`; ``value`` equals MPJPE.
    """
    est, ref = _joint_pair(est, ref)
    errors = np.linalg.norm(est - ref, axis=-1)
    return _summarise(errors, Unit.METRE, _nanmean(errors, axis=0))


def pa_mpjpe_m(est: np.ndarray, ref: np.ndarray) -> MetricResult:
    """Procrustes-aligned MPJPE, metres.

    Per frame t, the similarity ``(s_t, R_t, τ_t)`` minimising ``Σ_j ‖ref_tj − (s R est_tj + τ)‖²``
    over the frame's finite joints (Umeyama with scale, proper rotation) is applied to the
    estimate, then ``PA-MPJPE = mean_{t,j} ‖s_t R_t est_tj + τ_t − ref_tj‖``. Frames with fewer
    than 3 finite joints cannot be aligned and are excluded entirely.

    Args:
        est: ``(T, J, 3)`` estimated joints, metres; NaN = missing joint.
        ref: ``(T, J, 3)`` reference joints, metres.

    Returns:
        :class:`MetricResult` in metres; ``per_item`` is the per-frame PA-MPJPE ``(T,)``.
    """
    est, ref = _joint_pair(est, ref)
    found = _usable(est, 1)
    alignable = np.count_nonzero(found, axis=1) >= 3
    errors = np.full(found.shape, np.nan)
    if np.any(alignable):
        scale, R, t, _ = _fit_similarity(est[alignable], ref[alignable], found[alignable].astype(float), True)
        aligned = scale[:, None, None] * np.einsum("bij,bnj->bni", R, est[alignable]) + t[:, None]
        errors[alignable] = np.linalg.norm(aligned - ref[alignable], axis=-1)
    return _per_frame(errors, Unit.METRE)


def _in_root_frame(joints: np.ndarray, world_T_root: np.ndarray) -> np.ndarray:
    """``root_T_world · joints``: ``R_tᵀ (p_tj − t_t)`` for ``(T, J, 3)`` and ``(T, 4, 4)``."""
    R, t = world_T_root[:, :3, :3], world_T_root[:, :3, 3]
    return np.einsum("tji,tkj->tki", R, joints - t[:, None])


def ra_mpjpe_m(
    est_joints: np.ndarray, ref_joints: np.ndarray, est_root: np.ndarray, ref_root: np.ndarray
) -> MetricResult:
    """Root-aligned MPJPE, metres, as SmartMocap defines it.

    Per frame, each skeleton is expressed in its own root frame, i.e. translated so the root
    positions coincide and rotated so the root orientations coincide:

        ``RA-MPJPE = mean_{t,j} ‖ Rᵉ_tᵀ (pᵉ_tj − tᵉ_t) − Rʳ_tᵀ (pʳ_tj − tʳ_t) ‖``

    with ``(Rᵉ_t, tᵉ_t) = est_root[t]`` and ``(Rʳ_t, tʳ_t) = ref_root[t]``. This measures the
    articulated pose only: global position and orientation errors are MPE / MOE. Shape is not
    aligned separately: a wrong body shape shows up as wrong joint offsets from the root, so it
    stays in this error (no scale is fitted, unlike PA-MPJPE).

    Args:
        est_joints: ``(T, J, 3)`` estimated joints in the world, metres; NaN = missing joint.
        ref_joints: ``(T, J, 3)`` reference joints, metres.
        est_root: ``(T, 4, 4)`` estimated ``world_T_root``; a NaN pose excludes the whole frame.
        ref_root: ``(T, 4, 4)`` reference ``world_T_root``.

    Returns:
        :class:`MetricResult` in metres; ``per_item`` is the per-frame RA-MPJPE ``(T,)``.
    """
    est_joints, ref_joints = _joint_pair(est_joints, ref_joints, "est_joints", "ref_joints")
    frames = est_joints.shape[0]
    est_root = _estimate(est_root, "est_root", (frames, 4, 4))
    ref_root = as_checked_array(ref_root, "ref_root", (frames, 4, 4))
    _check_poses(est_root, "est_root")
    _check_poses(ref_root, "ref_root")
    diff = _in_root_frame(est_joints, est_root) - _in_root_frame(ref_joints, ref_root)
    return _per_frame(np.linalg.norm(diff, axis=-1), Unit.METRE)


def mpvpe_m(est_vertices_or_points: np.ndarray, ref: np.ndarray) -> MetricResult:
    """Shape-only error: mean point distance of two neutral-pose bodies, each centred at its root.

    Our body models expose rest-pose joints / keypoints rather than a mesh, so the caller passes
    the neutral-pose (all joint rotations zero, identity root) points of the estimated and the
    reference shape, root first. Both are translated so their first point is at the origin, then

        ``MPVPE = mean_i ‖(est_i − est_0) − (ref_i − ref_0)‖``

    over all N points (the root itself contributes 0). No rotation or scale is fitted: the
    neutral pose fixes the orientation, and a wrong size is exactly what this measures.

    Args:
        est_vertices_or_points: ``(N, 3)`` estimated rest-pose points, metres, root first;
            NaN = missing point (the root must be finite).
        ref: ``(N, 3)`` reference rest-pose points, metres, root first.

    Returns:
        :class:`MetricResult` in metres; ``per_item`` is the per-point distance ``(N,)``.
    """
    est = _estimate(est_vertices_or_points, "est_vertices_or_points", (None, 3))
    ref = as_checked_array(ref, "ref", est.shape)
    if est.shape[0] == 0 or not np.all(np.isfinite(est[0])):
        raise MocapgraphError("est_vertices_or_points: the first point (the root) must be given and finite")
    errors = np.linalg.norm((est - est[0]) - (ref - ref[0]), axis=-1)
    return _summarise(errors, Unit.METRE, errors)


# ---- joint rotations, root and cameras ----------------------------------------------------------


def joint_angle_error_rad(est_pose: np.ndarray, ref_pose: np.ndarray) -> MetricResult:
    """Geodesic angle between estimated and reference local joint rotations, radians.

    ``e_tj = ‖Log(Exp(θᵉ_tj)ᵀ Exp(θʳ_tj))‖ ∈ [0, π]`` for the 21 body joints (AirCap, Table 2.1);
    ``value`` is the mean over (frame, joint) pairs.

    Args:
        est_pose: ``(T, 21, 3)`` local axis-angle rotations of joints 1…21 (SMPL order), radians;
            NaN = missing joint.
        ref_pose: ``(T, 21, 3)`` reference rotations.

    Returns:
        :class:`MetricResult` in radians; ``per_item`` is the per-joint mean ``(21,)``.
    """
    est = _estimate(est_pose, "est_pose", (None, NUM_JOINTS - 1, 3))
    ref = as_checked_array(ref_pose, "ref_pose", est.shape)
    errors = _geodesic_rad(rotvec_to_matrix(est), rotvec_to_matrix(ref))
    return _summarise(errors, Unit.RADIAN, _nanmean(errors, axis=0))


def mpe_m(est_root_positions: np.ndarray, ref: np.ndarray) -> MetricResult:
    """Mean root position error, metres: ``mean_t ‖est_t − ref_t‖`` (SmartMocap's MPE).

    Args:
        est_root_positions: ``(T, 3)`` estimated root (pelvis) positions, metres; NaN = missing.
        ref: ``(T, 3)`` reference root positions, metres, same world frame.

    Returns:
        :class:`MetricResult` in metres; ``per_item`` is the per-frame error ``(T,)``.
    """
    est = _estimate(est_root_positions, "est_root_positions", (None, 3))
    ref = as_checked_array(ref, "ref", est.shape)
    errors = np.linalg.norm(est - ref, axis=-1)
    return _summarise(errors, Unit.METRE, errors)


def moe_rad(est_root_R: np.ndarray, ref: np.ndarray) -> MetricResult:
    """Mean root orientation error, radians: ``mean_t ‖Log(Rᵉ_tᵀ Rʳ_t)‖`` (SmartMocap's MOE).

    Args:
        est_root_R: ``(T, 3, 3)`` estimated root → world rotations; NaN = missing frame.
        ref: ``(T, 3, 3)`` reference rotations.

    Returns:
        :class:`MetricResult` in radians; ``per_item`` is the per-frame angle ``(T,)``.
    """
    est = _rotations(est_root_R, "est_root_R", (None, 3, 3), estimate=True)
    ref = _rotations(ref, "ref", est.shape, estimate=False)
    errors = _geodesic_rad(est, ref)
    return _summarise(errors, Unit.RADIAN, errors)


def _camera_pair(est_cam, ref):
    est = _estimate(est_cam, "est_cam", (None, 4, 4))
    ref = as_checked_array(ref, "ref", est.shape)
    _check_poses(est, "est_cam")
    _check_poses(ref, "ref")
    return est, ref


def mcpe_m(est_cam: np.ndarray, ref: np.ndarray) -> MetricResult:
    """Mean camera position error, metres: ``mean_n ‖tᵉ_n − tʳ_n‖`` of the ``world_T_camera`` translations.

    Args:
        est_cam: ``(N, 4, 4)`` estimated ``world_T_camera``, one per frame of a moving camera
            (``N = T``) or one per static camera, in the reference's world frame (align first,
            e.g. :func:`~mocapgraph.data_tools.evaluation.alignment.procrustes_trajectory`); NaN = missing.
        ref: ``(N, 4, 4)`` reference ``world_T_camera``.

    Returns:
        :class:`MetricResult` in metres; ``per_item`` is the per-pose error ``(N,)``.
    """
    est, ref = _camera_pair(est_cam, ref)
    errors = np.linalg.norm(est[:, :3, 3] - ref[:, :3, 3], axis=-1)
    return _summarise(errors, Unit.METRE, errors)


def mcoe_rad(est_cam: np.ndarray, ref: np.ndarray) -> MetricResult:
    """Mean camera orientation error, radians: ``mean_n ‖Log(Rᵉ_nᵀ Rʳ_n)‖`` of the ``world_T_camera`` rotations.

    Same inputs as :func:`mcpe_m`; ``per_item`` is the per-pose angle ``(N,)``.
    """
    est, ref = _camera_pair(est_cam, ref)
    errors = _geodesic_rad(est[:, :3, :3], ref[:, :3, :3])
    return _summarise(errors, Unit.RADIAN, errors)


# ---- motion smoothness and detections -----------------------------------------------------------


def acceleration_error_m_s2(est: np.ndarray, ref: np.ndarray, fps: float) -> MetricResult:
    """Mean acceleration error, m/s².

    With the second finite difference ``a_tj = (x_{t+1,j} − 2 x_tj + x_{t−1,j}) · fps²``:
    ``mean_{t,j} ‖aᵉ_tj − aʳ_tj‖`` over t = 1…T−2. A second difference touching a missing
    estimate is excluded (one NaN frame removes up to three samples).

    Args:
        est: ``(T, J, 3)`` estimated joints, metres, T ≥ 3; NaN = missing.
        ref: ``(T, J, 3)`` reference joints, metres.
        fps: frames per second of both sequences.

    Returns:
        :class:`MetricResult` in m/s²; ``per_item`` is the per-frame mean ``(T − 2,)`` (frames 1…T−2).
    """
    est, ref = _joint_pair(est, ref)
    fps = _fps(fps)
    if est.shape[0] < 3:
        raise MocapgraphError(f"est: need at least 3 frames for an acceleration, got {est.shape[0]}")
    diff = np.diff(est, n=2, axis=0) - np.diff(ref, n=2, axis=0)
    return _per_frame(np.linalg.norm(diff, axis=-1) * fps**2, Unit.METRE_PER_SECOND_SQUARED)


def jitter_m_s3(est: np.ndarray, fps: float) -> MetricResult:
    """Mean jerk magnitude, m/s³: ``mean_{t,j} ‖Δ³x_tj‖ · fps³`` (third finite difference).

    Args:
        est: ``(T, J, 3)`` joints, metres, T ≥ 4; NaN = missing.
        fps: frames per second.

    Returns:
        :class:`MetricResult` in m/s³; ``per_item`` is the per-frame mean ``(T − 3,)``.
    """
    est = _estimate(est, "est", (None, None, 3))
    fps = _fps(fps)
    if est.shape[0] < 4:
        raise MocapgraphError(f"est: need at least 4 frames for a jerk, got {est.shape[0]}")
    return _per_frame(np.linalg.norm(np.diff(est, n=3, axis=0), axis=-1) * fps**3, Unit.METRE_PER_SECOND_CUBED)


def num_detections(keypoints: np.ndarray) -> MetricResult:
    """Number of detected (non-NaN) keypoints per frame.

    Args:
        keypoints: ``(T, K, 3)`` keypoints (x, y, confidence, or 3D points); a keypoint counts
            when none of its three numbers is NaN.

    Returns:
        :class:`MetricResult` with unit count: ``per_item`` is the ``(T,)`` int array of
        detections per frame, ``value`` its mean, ``count`` = T frames.
    """
    kp = _estimate(keypoints, "keypoints", (None, None, 3))
    per_frame = np.count_nonzero(_usable(kp, 1), axis=1).astype(np.int64)
    value = float(per_frame.mean()) if per_frame.size else float("nan")
    return MetricResult(value, Unit.COUNT, int(per_frame.size), 0, per_frame)


def covariance_coverage(est: np.ndarray, ref: np.ndarray, covariances: np.ndarray, level: float = 0.95) -> MetricResult:
    """Fraction of points whose error lies inside the ``level`` ellipsoid of their covariance:
    ``(e − r)ᵀ Σ⁻¹ (e − r) ≤ χ²₃(level)``. Honest covariances cover ``level`` of the points.

    Args:
        est: ``(T, J, 3)`` estimated points (e.g. joints), metres; NaN = missing.
        ref: ``(T, J, 3)`` reference points.
        covariances: ``(T, J, 3, 3)`` the estimate's covariance of each point, m²; a non-finite one
            excludes its point.
        level: the ellipsoid's probability under the covariance, in (0, 1).

    Returns:
        :class:`MetricResult` as a fraction; ``per_item`` is the per-frame fraction ``(T,)``.
    """
    from scipy.stats import chi2

    est, ref = _joint_pair(est, ref)
    cov = _estimate(covariances, "covariances", est.shape + (3,))
    if not 0.0 < level < 1.0:
        raise MocapgraphError(f"level: must lie in (0, 1), got {level!r}")
    ok = _usable(est - ref, 1) & _usable(cov, 2)
    inside = np.full(est.shape[:-1], np.nan)
    err = (est - ref)[ok]
    inside[ok] = np.einsum("ni,nij,nj->n", err, np.linalg.inv(cov[ok]), err) <= chi2.ppf(level, 3)
    return _summarise(inside, Unit.FRACTION, _nanmean(inside, axis=1))
