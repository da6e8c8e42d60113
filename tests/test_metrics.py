"""Alignment and metrics against known ground truth and independent computations (scipy's
rotations, Kabsch and least squares, explicit 4×4 inverses), plus NaN bookkeeping and input errors."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import orthogonal_procrustes
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from mocapgraph.data_tools.evaluation.alignment import Similarity, procrustes_trajectory, umeyama
from mocapgraph.data_tools.evaluation.metrics import (
    MetricResult,
    Unit,
    acceleration_error_m_s2,
    jitter_m_s3,
    joint_angle_error_rad,
    mcoe_rad,
    mcpe_m,
    moe_rad,
    mpe_m,
    mpjpe_m,
    mpvpe_m,
    num_detections,
    pa_mpjpe_m,
    per_joint_position_error_m,
    ra_mpjpe_m,
)
from mocapgraph.errors import MocapgraphError


def random_rotations(rng, n=None):
    return Rotation.random(n, random_state=rng).as_matrix()


def random_poses(rng, n):
    """``(n, 4, 4)`` rigid transforms, built independently of the code under test."""
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = random_rotations(rng, n)
    poses[:, :3, 3] = rng.normal(scale=2.0, size=(n, 3))
    return poses


def transform(poses, points):
    """Apply ``(T, 4, 4)`` to ``(T, J, 3)`` through homogeneous coordinates."""
    homogeneous = np.concatenate([points, np.ones(points.shape[:-1] + (1,))], axis=-1)
    return np.einsum("tij,tkj->tki", poses, homogeneous)[..., :3]


@pytest.fixture
def rng():
    return np.random.default_rng(7)


# ---- umeyama ------------------------------------------------------------------------------------


def test_umeyama_recovers_random_similarity(rng):
    src = rng.normal(size=(30, 3))
    R, s, t = random_rotations(rng), 1.7, rng.normal(size=3)
    sim = umeyama(src, s * src @ R.T + t, with_scale=True)
    assert abs(sim.scale - s) < 1e-10
    assert np.allclose(sim.R, R, atol=1e-10) and np.allclose(sim.t, t, atol=1e-10)
    assert np.allclose(sim.apply(src), (sim.as_matrix() @ np.c_[src, np.ones(30)].T).T[:, :3], atol=1e-12)


def test_umeyama_rigid_only(rng):
    src = rng.normal(size=(30, 3))
    R, t = random_rotations(rng), rng.normal(size=3)
    sim = umeyama(src, src @ R.T + t, with_scale=False)
    assert sim.scale == 1.0
    assert np.allclose(sim.R, R, atol=1e-10) and np.allclose(sim.t, t, atol=1e-10)
    # A scaled target: the rigid fit keeps scale 1 (the rotation is still the true one).
    scaled = umeyama(src, 2.0 * src @ R.T + t, with_scale=False)
    assert scaled.scale == 1.0 and np.allclose(scaled.R, R, atol=1e-10)


def test_umeyama_ignores_nan_rows_and_zero_weights(rng):
    src = rng.normal(size=(12, 3))
    tgt = 0.8 * src @ random_rotations(rng).T + 1.0 + rng.normal(scale=0.05, size=(12, 3))
    clean = umeyama(src[:8], tgt[:8], with_scale=True)
    src_nan, tgt_nan = src.copy(), tgt.copy()
    src_nan[8, 1] = np.nan
    tgt_nan[9:11] = np.nan
    weights = np.ones(12)
    weights[11] = 0.0
    masked = umeyama(src_nan, tgt_nan, with_scale=True, weights=weights)
    assert np.allclose(masked.as_matrix(), clean.as_matrix(), atol=1e-12)


def test_umeyama_integer_weights_equal_repeated_rows(rng):
    src = rng.normal(size=(6, 3))
    tgt = src @ random_rotations(rng).T + rng.normal(scale=0.1, size=(6, 3))
    counts = np.array([1, 3, 1, 2, 1, 1])
    weighted = umeyama(src, tgt, with_scale=True, weights=counts)
    repeated = umeyama(np.repeat(src, counts, axis=0), np.repeat(tgt, counts, axis=0), with_scale=True)
    assert np.allclose(weighted.as_matrix(), repeated.as_matrix(), atol=1e-12)


def test_umeyama_reflection_gives_best_proper_rotation(rng):
    src = rng.normal(size=(10, 3)) * [3.0, 2.0, 1.0]
    mirrored = src * [1.0, 1.0, -1.0]  # the best orthogonal map is a reflection
    sim = umeyama(src, mirrored, with_scale=False)
    assert np.isclose(np.linalg.det(sim.R), 1.0) and np.allclose(sim.R.T @ sim.R, np.eye(3), atol=1e-12)
    # Independent Kabsch over proper rotations on the centred points.
    kabsch, _ = Rotation.align_vectors(mirrored - mirrored.mean(0), src - src.mean(0))
    assert np.allclose(sim.R, kabsch.as_matrix(), atol=1e-9)


@pytest.mark.parametrize(
    "src, message",
    [
        (np.array([[0.0, 0, 0], [1, 0, 0], [np.nan, 0, 0], [0, np.nan, 1]]), "at least 3"),
        (np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]]), "collinear"),
    ],
)
def test_umeyama_degenerate_inputs(src, message):
    with pytest.raises(MocapgraphError, match=message):
        umeyama(src, src, with_scale=True)


def test_umeyama_bad_shapes_and_weights():
    with pytest.raises(MocapgraphError, match="target"):
        umeyama(np.zeros((5, 3)), np.zeros((4, 3)), with_scale=True)
    with pytest.raises(MocapgraphError, match="weights"):
        umeyama(np.eye(3), np.eye(3), with_scale=True, weights=[1.0, -1.0, 1.0])


def test_similarity_apply_pose_matches_matrix(rng):
    sim = Similarity(2.5, random_rotations(rng), rng.normal(size=3))
    poses = random_poses(rng, 4)
    mapped = sim.apply_pose(poses)
    assert np.allclose(mapped[:, :3, 3], (sim.as_matrix() @ poses[:, :, 3:])[:, :3, 0], atol=1e-12)
    assert np.allclose(mapped[:, :3, :3], sim.R @ poses[:, :3, :3], atol=1e-12)
    assert np.allclose(mapped[:, 3], [0, 0, 0, 1])
    with pytest.raises(MocapgraphError, match="scale"):
        Similarity(0.0, np.eye(3), np.zeros(3))
    with pytest.raises(MocapgraphError, match="R"):
        Similarity(1.0, np.diag([1.0, 1.0, -1.0]), np.zeros(3))


# ---- procrustes_trajectory ----------------------------------------------------------------------


def helix(frames):
    s = np.linspace(0.0, 4.0, frames)
    return np.c_[3 * np.cos(s), 3 * np.sin(s), 0.5 * s]


def test_procrustes_trajectory_recovers_similarity(rng):
    ref_poses = np.tile(np.eye(4), (40, 1, 1))
    ref_poses[:, :3, :3] = random_rotations(rng, 40)
    ref_poses[:, :3, 3] = helix(40)
    truth = Similarity(0.3, random_rotations(rng), rng.normal(size=3))  # reference → estimate
    est_poses = truth.apply_pose(ref_poses)
    est_poses[5] = np.nan  # a frame the estimate lost
    for orientations in (False, True):
        args = (est_poses[:, :3, :3], ref_poses[:, :3, :3]) if orientations else ()
        sim = procrustes_trajectory(est_poses[:, :3, 3], ref_poses[:, :3, 3], *args)
        assert abs(sim.scale - 1 / 0.3) < 1e-10
        assert np.allclose(sim.R, truth.R.T, atol=1e-10)
        mapped = sim.apply_pose(est_poses)
        assert np.allclose(np.delete(mapped, 5, axis=0), np.delete(ref_poses, 5, axis=0), atol=1e-10)


def test_procrustes_trajectory_recipe_on_noisy_data(rng):
    ref = helix(30)
    est = 2.0 * ref @ random_rotations(rng).T + 5.0 + rng.normal(scale=0.2, size=(30, 3))
    sim = procrustes_trajectory(est, ref)
    e, r = est - est.mean(0), ref - ref.mean(0)
    assert np.isclose(sim.scale, np.linalg.norm(r) / np.linalg.norm(e), rtol=1e-12)
    # scipy's orthogonal Procrustes on the normalised points (rows): e Q ≈ r  ⇒  our R = Qᵀ.
    Q, _ = orthogonal_procrustes(e / np.linalg.norm(e), r / np.linalg.norm(r))
    assert np.allclose(sim.R, Q.T, atol=1e-10)
    # The ratio-of-norms scale is symmetric, unlike a least-squares scale.
    assert np.isclose(procrustes_trajectory(ref, est).scale, 1 / sim.scale, rtol=1e-12)


def test_procrustes_trajectory_straight_line_needs_orientations(rng):
    ref_poses = random_poses(rng, 6)
    ref_poses[:, :3, 3] = np.outer(np.arange(6.0), [1.0, 2.0, 0.0])
    truth = Similarity(1.5, random_rotations(rng), rng.normal(size=3))
    est_poses = truth.apply_pose(ref_poses)
    with pytest.raises(MocapgraphError, match="orientations"):
        procrustes_trajectory(est_poses[:, :3, 3], ref_poses[:, :3, 3])
    sim = procrustes_trajectory(est_poses[:, :3, 3], ref_poses[:, :3, 3], est_poses[:, :3, :3], ref_poses[:, :3, :3])
    assert np.allclose(sim.apply_pose(est_poses), ref_poses, atol=1e-10)
    with pytest.raises(MocapgraphError, match="both or neither"):
        procrustes_trajectory(est_poses[:, :3, 3], ref_poses[:, :3, 3], est_poses[:, :3, :3])
    with pytest.raises(MocapgraphError, match="ref_positions"):
        procrustes_trajectory(est_poses[:, :3, 3], ref_poses[:5, :3, 3])


def short_track(rng, frames=90):
    """A carried phone's 3 s: 90 poses turning freely, centres within a few centimetres."""
    poses = np.tile(np.eye(4), (frames, 1, 1))
    poses[:, :3, :3] = (Rotation.from_rotvec(np.linspace(0, 1, frames)[:, None] * rng.normal(size=3)) * Rotation.from_matrix(random_rotations(rng))).as_matrix()
    poses[:, :3, 3] = np.cumsum(rng.normal(scale=0.004, size=(frames, 3)), axis=0) + [4.0, -2.0, 1.5]
    return poses


def test_procrustes_trajectory_rotation_from_orientations_exact(rng):
    ref_poses = short_track(rng)
    truth = Similarity(1.7, random_rotations(rng), rng.normal(size=3))  # reference → estimate
    est_poses = truth.apply_pose(ref_poses)
    sim = procrustes_trajectory(est_poses[:, :3, 3], ref_poses[:, :3, 3], est_poses[:, :3, :3], ref_poses[:, :3, :3], rotation_from="orientations")
    assert abs(sim.scale - 1 / 1.7) < 1e-10
    assert np.allclose(sim.R, truth.R.T, atol=1e-10)
    assert np.allclose(sim.apply_pose(est_poses), ref_poses, atol=1e-10)
    with pytest.raises(MocapgraphError, match="orientations"):
        procrustes_trajectory(est_poses[:, :3, 3], ref_poses[:, :3, 3], rotation_from="orientations")
    with pytest.raises(MocapgraphError, match="rotation_from"):
        procrustes_trajectory(est_poses[:, :3, 3], ref_poses[:, :3, 3], est_poses[:, :3, :3], ref_poses[:, :3, :3], rotation_from="centres")


def test_procrustes_trajectory_short_noisy_track_rotation_bounded(rng):
    """Centres 3 cm off on a track of a few centimetres, frames 0.03 rad off: the rotation from the
    orientations is within their averaged noise, and is the minimiser of Σ‖Q est_R − ref_R‖²_F
    found by a generic solver; the positions' rotation is not."""
    sigma_rad = 0.03
    errors = {"orientations": [], "both": []}
    for _ in range(10):
        ref_poses = short_track(rng)
        truth = Similarity(1.0, random_rotations(rng), rng.normal(size=3))
        est_poses = truth.apply_pose(ref_poses)
        est_poses[:, :3, 3] += rng.normal(scale=0.03, size=(90, 3))
        est_poses[:, :3, :3] = Rotation.from_rotvec(rng.normal(scale=sigma_rad, size=(90, 3))).as_matrix() @ est_poses[:, :3, :3]
        args = (est_poses[:, :3, 3], ref_poses[:, :3, 3], est_poses[:, :3, :3], ref_poses[:, :3, :3])
        for source in errors:
            sim = procrustes_trajectory(*args, rotation_from=source)
            errors[source].append(np.linalg.norm(Rotation.from_matrix(sim.R @ truth.R).as_rotvec()))
        fit = least_squares(lambda v: (Rotation.from_rotvec(v).as_matrix() @ est_poses[:, :3, :3] - ref_poses[:, :3, :3]).ravel(), np.zeros(3))
        assert np.allclose(Rotation.from_rotvec(fit.x).as_matrix(), procrustes_trajectory(*args, rotation_from="orientations").R, atol=1e-6)
    # the mean of 90 frames' offsets: about σ·√3/√90 ≈ 0.0055 rad; "both" follows the centres' noise
    assert max(errors["orientations"]) < 0.015
    assert np.median(errors["both"]) > 5 * np.median(errors["orientations"])


# ---- joint position metrics ---------------------------------------------------------------------


def test_mpjpe_of_known_offsets(rng):
    ref = rng.normal(size=(5, 22, 3))
    offsets = rng.normal(scale=0.05, size=(22, 3))
    res = mpjpe_m(ref + [0.03, 0.0, 0.04], ref)
    assert isinstance(res, MetricResult) and res.unit is Unit.METRE
    assert abs(float(res) - 0.05) < 1e-12 and res.count == 110 and res.excluded == 0
    per_joint = per_joint_position_error_m(ref + offsets, ref)
    assert np.allclose(per_joint.per_item, np.linalg.norm(offsets, axis=1), atol=1e-12)
    assert np.isclose(per_joint.value, np.linalg.norm(offsets, axis=1).mean())


def test_nan_estimates_are_excluded_and_counted(rng):
    ref = rng.normal(size=(4, 22, 3))
    est = ref + rng.normal(scale=0.02, size=ref.shape)
    est[1, 3, 0] = np.nan
    est[2] = np.nan  # a lost frame
    keep = np.isfinite(est).all(axis=-1)
    expected = np.linalg.norm(est - ref, axis=-1)[keep].mean()
    res = mpjpe_m(est, ref)
    assert np.isclose(res.value, expected, rtol=1e-13)
    assert (res.count, res.excluded) == (88 - 23, 23)
    assert np.isnan(res.per_item[2]) and np.isfinite(res.per_item[[0, 1, 3]]).all()
    empty = mpjpe_m(np.full((2, 3, 3), np.nan), np.zeros((2, 3, 3)))
    assert np.isnan(empty.value) and (empty.count, empty.excluded) == (0, 6)


def test_pa_mpjpe_removes_per_frame_similarity(rng):
    ref = rng.normal(scale=0.4, size=(6, 22, 3))
    est = np.stack([s * x @ random_rotations(rng).T + rng.normal(size=3) for s, x in zip(rng.uniform(0.5, 2, 6), ref)])
    assert pa_mpjpe_m(est, ref).value < 1e-12
    assert mpjpe_m(est, ref).value > 0.1


def test_pa_mpjpe_matches_least_squares_alignment(rng):
    ref = rng.normal(scale=0.4, size=(1, 22, 3))
    est = 1.2 * ref @ random_rotations(rng).T + 0.3 + rng.normal(scale=0.03, size=ref.shape)

    def residuals(p):  # scale, axis-angle, translation, solved numerically
        return (p[0] * Rotation.from_rotvec(p[1:4]).apply(est[0]) + p[4:] - ref[0]).ravel()

    fit = least_squares(residuals, np.r_[1.0, np.zeros(6)], xtol=1e-15, ftol=1e-15, gtol=1e-15)
    expected = np.linalg.norm(residuals(fit.x).reshape(-1, 3), axis=1).mean()
    assert np.isclose(pa_mpjpe_m(est, ref).value, expected, rtol=1e-6)


def test_pa_mpjpe_excludes_frames_that_cannot_be_aligned(rng):
    ref = rng.normal(size=(3, 5, 3))
    est = ref.copy()
    est[1, 2:] = np.nan  # only 2 joints left: frame 1 is excluded entirely
    res = pa_mpjpe_m(est, ref)
    assert (res.count, res.excluded) == (10, 5) and np.isnan(res.per_item[1])


def test_ra_mpjpe_invariant_to_rigid_motion_of_whole_body(rng):
    frames = 5
    ref_root = random_poses(rng, frames)
    ref_joints = transform(ref_root, rng.normal(scale=0.3, size=(frames, 22, 3)))
    est_root = ref_root @ random_poses(rng, frames)  # a different root pose
    est_joints = ref_joints + rng.normal(scale=0.02, size=ref_joints.shape)
    # Independent value: each skeleton in its own root frame through explicit 4×4 inverses.
    expected = np.linalg.norm(
        transform(np.linalg.inv(est_root), est_joints) - transform(np.linalg.inv(ref_root), ref_joints), axis=-1
    ).mean()
    base = ra_mpjpe_m(est_joints, ref_joints, est_root, ref_root)
    assert np.isclose(base.value, expected, rtol=1e-12)
    moved = random_poses(rng, frames)  # the same rigid motion per frame for the body and its root
    after = ra_mpjpe_m(transform(moved, est_joints), ref_joints, moved @ est_root, ref_root)
    assert np.isclose(after.value, base.value, rtol=1e-12)
    exact = ra_mpjpe_m(transform(moved, ref_joints), ref_joints, moved @ ref_root, ref_root)
    assert exact.value < 1e-12 and mpjpe_m(transform(moved, ref_joints), ref_joints).value > 0.5


def test_mpvpe_centres_at_root(rng):
    ref = rng.normal(scale=0.3, size=(23, 3))
    assert mpvpe_m(ref + [4.0, -1.0, 2.0], ref).value < 1e-14
    bigger = mpvpe_m(1.1 * ref, ref)
    assert np.isclose(bigger.value, 0.1 * np.linalg.norm(ref - ref[0], axis=1).mean(), rtol=1e-12)
    missing_root = ref.copy()
    missing_root[0] = np.nan
    with pytest.raises(MocapgraphError, match="root"):
        mpvpe_m(missing_root, ref)


# ---- rotations, root and cameras ----------------------------------------------------------------


def test_joint_angle_error_of_known_rotation_difference(rng):
    ref = Rotation.random(3 * 21, random_state=rng)
    angles = np.linspace(0.01, 3.1, 21)
    axes = Rotation.random(3 * 21, random_state=rng).apply([1.0, 0.0, 0.0])
    delta = Rotation.from_rotvec(axes * np.tile(angles, 3)[:, None])
    est = (ref * delta).as_rotvec().reshape(3, 21, 3)
    res = joint_angle_error_rad(est, ref.as_rotvec().reshape(3, 21, 3))
    assert res.unit is Unit.RADIAN and res.count == 63
    assert np.allclose(res.per_item, angles, atol=1e-10) and np.isclose(res.value, angles.mean())


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1.0, np.pi - 1e-7, np.pi])
def test_geodesic_root_orientation_error_up_to_pi(rng, angle):
    ref = random_rotations(rng, 2)
    axis = rng.normal(size=3)
    est = ref @ Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle).as_matrix()
    assert np.allclose(moe_rad(est, ref).per_item, angle, atol=1e-10)


def test_root_and_camera_errors(rng):
    ref = random_poses(rng, 4)
    est = ref.copy()
    est[:, :3, 3] += [0.0, 0.3, 0.4]
    est[:, :3, :3] = est[:, :3, :3] @ Rotation.from_rotvec([0.0, 0.0, 0.2]).as_matrix()
    est[3] = np.nan  # a camera without an estimate
    assert np.isclose(mpe_m(est[:, :3, 3], ref[:, :3, 3]).value, 0.5)
    cam = mcpe_m(est, ref)
    assert np.isclose(cam.value, 0.5) and (cam.count, cam.excluded) == (3, 1)
    assert np.isclose(mcoe_rad(est, ref).value, 0.2) and np.isclose(moe_rad(est[:, :3, :3], ref[:, :3, :3]).value, 0.2)


# ---- smoothness and detections ------------------------------------------------------------------


def test_acceleration_error_zero_and_known_quadratic(rng):
    fps, frames = 30.0, 31
    ref = rng.normal(size=(frames, 4, 3))
    assert acceleration_error_m_s2(ref, ref, fps).value == 0.0
    t = np.arange(frames) / fps
    a = np.array([0.0, 3.0, 4.0])  # m/s², constant
    est = ref + 0.5 * t[:, None, None] ** 2 * a
    res = acceleration_error_m_s2(est, ref, fps)
    assert res.unit is Unit.METRE_PER_SECOND_SQUARED and np.isclose(res.value, 5.0, rtol=1e-9)
    assert res.per_item.shape == (frames - 2,)
    est[10, 2] = np.nan  # one joint lost in one frame: three second differences lose it
    assert acceleration_error_m_s2(est, ref, fps).excluded == 3


def test_jitter_of_known_cubic():
    fps = 50.0
    t = np.arange(20) / fps
    c = np.array([6.0, 0.0, 8.0])  # m/s³
    est = (t[:, None, None] ** 3 / 6.0 * c) + np.zeros((20, 2, 3))
    res = jitter_m_s3(est, fps)
    assert res.unit is Unit.METRE_PER_SECOND_CUBED and np.isclose(res.value, 10.0, rtol=1e-8)
    est[7] = np.nan
    assert jitter_m_s3(est, fps).excluded == 4 * 2


def test_num_detections():
    kp = np.zeros((3, 5, 3))
    kp[0, :2] = np.nan
    kp[1, 4, 2] = np.nan
    kp[2] = np.nan
    res = num_detections(kp)
    assert res.unit is Unit.COUNT and res.per_item.dtype.kind == "i"
    assert res.per_item.tolist() == [3, 4, 0] and np.isclose(float(res), 7 / 3)


# ---- input errors and the result type -----------------------------------------------------------

J3 = np.zeros((4, 22, 3))
POSES = np.tile(np.eye(4), (4, 1, 1))


@pytest.mark.parametrize(
    "call, name",
    [
        (lambda: mpjpe_m(J3, J3[:, :21]), "ref"),
        (lambda: mpjpe_m(J3[0], J3[0]), "est"),
        (lambda: pa_mpjpe_m(J3, J3[:3]), "ref"),
        (lambda: ra_mpjpe_m(J3, J3, POSES, POSES[:3]), "ref_root"),
        (lambda: ra_mpjpe_m(J3, J3, POSES[:, :3], POSES), "est_root"),
        (lambda: joint_angle_error_rad(J3, J3), "est_pose"),
        (lambda: mpe_m(np.zeros((4, 3)), np.zeros((4, 2))), "ref"),
        (lambda: moe_rad(2 * POSES[:, :3, :3], POSES[:, :3, :3]), "est_root_R"),
        (lambda: mcpe_m(POSES, POSES[:, :3]), "ref"),
        (lambda: mcoe_rad(POSES[:, :3, :3], POSES), "est_cam"),
        (lambda: mpvpe_m(np.zeros((5, 3)), np.zeros((6, 3))), "ref"),
        (lambda: acceleration_error_m_s2(J3, J3, fps=0.0), "fps"),
        (lambda: acceleration_error_m_s2(J3[:2], J3[:2], fps=30), "at least 3 frames"),
        (lambda: jitter_m_s3(np.full((5, 2, 3), np.inf), 30), "est: contains inf"),
        (lambda: num_detections(np.zeros((3, 5, 2))), "keypoints"),
        (lambda: mpjpe_m(J3, np.full(J3.shape, np.nan)), "ref: contains NaN"),
    ],
)
def test_bad_inputs_name_the_argument(call, name):
    with pytest.raises(MocapgraphError, match=name):
        call()


def test_metric_result_and_units():
    res = MetricResult(0.0123, Unit.METRE, 10, 2)
    assert float(res) == 0.0123 and str(res) == "0.0123 m (10 used, 2 excluded)"
    assert Unit.METRE == "m" and len({u.value for u in Unit}) == len(Unit)
