"""``eval``: metrics against ground truth after the alignment the result's world frame calls for."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import random_root

from mocapgraph.body import load_body_model
from mocapgraph.body.rotations import rotvec_to_matrix
from mocapgraph.data_tools.evaluation.alignment import align_camera_centres
from mocapgraph.data_tools.evaluation.evaluate import evaluate
from mocapgraph.data_tools.geometry.timing import match_times
from mocapgraph.data_tools.io.capture import Camera, Capture, GroundTruth
from mocapgraph.data_tools.io.result import CameraTrack, Result
from mocapgraph.errors import MocapgraphError


@pytest.fixture(scope="module")
def truth():
    """A short ground-truth capture: the Anny body moving, one static and one moving camera."""
    body = load_body_model()
    rng = np.random.default_rng(0)
    T = 12
    ts = np.arange(T) / 30.0
    root = random_root(rng, T)
    pose = rng.normal(scale=0.3, size=(T, 21, 3))
    shape = np.array([0.4, 0.6, 0.5, 0.3, 0.45, 0.5])
    joints = body.forward(shape, root, pose).joints
    K = np.array([[1000.0, 0, 640], [0, 1000, 360], [0, 0, 1]])
    cams = [
        Camera("fixed", K, np.zeros(5), (1280, 720), False, ts, 30.0),
        Camera("handheld", K, np.zeros(5), (1280, 720), True, ts + 0.001, 30.0),
    ]
    gt = GroundTruth("anny", ts, root, pose, shape, joints,
                     {"fixed": np.repeat(random_root(rng, 1), T, axis=0), "handheld": random_root(rng, T)})  # fmt: skip
    return Capture("truth", cams, ground_truth=gt)


def perfect_result(capture: Capture, world_frame: str = "capture") -> Result:
    gt = capture.ground_truth
    return Result(
        pipeline="test", capture="-", world_frame=world_frame, timestamps=gt.timestamps, joints=gt.joints.copy(),
        body_model="anny", root=gt.root.copy(), pose=gt.pose.copy(), shape=gt.shape.copy(),
        cameras={n: CameraTrack(capture.camera(n).timestamps, p.copy()) for n, p in gt.cameras.items()},
    )  # fmt: skip


def test_match_times_nearest_within_tolerance():
    ref = np.array([0.0, 0.1, 0.2, 0.3])
    np.testing.assert_array_equal(match_times(ref, np.array([-0.5, 0.04, 0.06, 0.31, 0.9]), 0.05), [-1, 0, 1, 3, -1])


def test_match_times_ties_and_slack():
    # Equally near: the earlier reference time, also when it is the last one in range.
    np.testing.assert_array_equal(match_times(np.array([0.0, 1.0, 2.0]), np.array([0.5, 1.5, 3.0]), 1.0), [0, 1, 2])
    # 3/60 is half a 30 Hz period after 1/30, but in float64 it lands 3.5e-18 s beyond.
    ref, query, half = np.array([1 / 30]), np.array([3 / 60]), 0.5 / 30
    assert abs(query[0] - ref[0]) > half
    assert match_times(ref, query, half)[0] == -1
    assert match_times(ref, query, half, rtol=1e-9)[0] == 0
    assert match_times(ref, query, half, atol=1e-12)[0] == 0
    # The slack is a hair, not a wider window.
    assert match_times(ref, query + 1e-6, half, rtol=1e-9, atol=1e-12)[0] == -1


def test_perfect_result_scores_zero(truth):
    ev = evaluate(perfect_result(truth), truth)
    assert ev.alignment.startswith("none")
    for key in ("mpjpe_m", "pa_mpjpe_m", "ra_mpjpe_m", "mpe_m", "moe_rad", "joint_angle_error_rad", "mpvpe_m", "mcpe_m", "mcoe_rad"):
        assert ev.metrics[key] < 1e-9, key
    assert ev.frames_compared == 12


def test_known_offset_is_measured(truth):
    res = perfect_result(truth)
    res.joints = res.joints + [0.03, 0.0, 0.04]
    res.root[:, :3, 3] += [0.03, 0.0, 0.04]
    ev = evaluate(res, truth)
    assert ev.metrics["mpjpe_m"] == pytest.approx(0.05)
    assert ev.metrics["mpe_m"] == pytest.approx(0.05)
    assert ev.metrics["ra_mpjpe_m"] < 1e-9 and ev.metrics["pa_mpjpe_m"] < 1e-9


def similarity_moved(res: Result, scale: float, R: np.ndarray, t: np.ndarray) -> Result:
    res.joints = scale * res.joints @ R.T + t
    res.root[:, :3, :3] = R @ res.root[:, :3, :3]
    res.root[:, :3, 3] = scale * res.root[:, :3, 3] @ R.T + t
    for track in res.cameras.values():
        track.world_T_camera[:, :3, :3] = R @ track.world_T_camera[:, :3, :3]
        track.world_T_camera[:, :3, 3] = scale * track.world_T_camera[:, :3, 3] @ R.T + t
    return res


def test_ground_plane_results_are_aligned_by_a_similarity(truth):
    R = rotvec_to_matrix(np.array([0.1, -0.2, 1.0]))
    res = similarity_moved(perfect_result(truth, "ground_plane"), 1.3, R, np.array([2.0, -1.0, 0.5]))
    ev = evaluate(res, truth)
    assert ev.alignment.startswith("similarity") and "scale 0.769" in ev.alignment
    assert ev.metrics["mpjpe_m"] < 1e-9 and ev.metrics["mcpe_m"] < 1e-9 and ev.metrics["moe_rad"] < 1e-9


def test_camera_frame_results_use_that_cameras_true_pose(truth):
    cam0 = truth.ground_truth.cameras["fixed"][0]
    inverse = np.linalg.inv(cam0)
    res = similarity_moved(perfect_result(truth, "camera:fixed"), 1.0, inverse[:3, :3], inverse[:3, 3])
    ev = evaluate(res, truth)
    assert "camera fixed" in ev.alignment
    assert ev.metrics["mpjpe_m"] < 1e-9 and ev.metrics["mpe_m"] < 1e-9 and ev.metrics["mcpe_m"] < 1e-9


def test_keypoint_results_score_their_keypoints(truth):
    gt = truth.ground_truth
    body = load_body_model()
    kp = body.forward(gt.shape, gt.root, gt.pose, keypoints="coco17").keypoints
    res = Result("baseline", "-", "capture", gt.timestamps, np.full_like(gt.joints, np.nan), keypoints=kp + [0, 0, 0.02], keypoint_format="coco17")  # fmt: skip
    ev = evaluate(res, truth)
    assert ev.metrics["mpjpe_keypoints_m"] == pytest.approx(0.02)
    assert "mpjpe_m" not in ev.metrics


def test_no_ground_truth_is_a_clear_error(truth):
    bare = Capture("bare", truth.cameras)
    with pytest.raises(MocapgraphError, match="has no ground truth"):
        evaluate(perfect_result(truth), bare)


@pytest.fixture(scope="module")
def rig(truth):
    """The truth's body seen by four static cameras (ground truth for each), no handheld one."""
    rng = np.random.default_rng(1)
    fixed = truth.camera("fixed")
    cams = [Camera(f"cam{k}", fixed.K, fixed.distortion, fixed.image_size, False, fixed.timestamps, 30.0) for k in range(4)]
    poses = {c.name: np.repeat(random_root(rng, 1), len(fixed.timestamps), axis=0) for c in cams}
    gt = truth.ground_truth
    return Capture("rig", cams, ground_truth=GroundTruth("anny", gt.timestamps, gt.root, gt.pose, gt.shape, gt.joints, poses))


def points_result(capture: Capture, offset, scale: float, R: np.ndarray, t: np.ndarray) -> Result:
    """A result without body parameters (the uncalibrated baseline's kind): the joints moved by
    ``offset`` metres, then joints and cameras by the similarity ``x ↦ scale R x + t``."""
    gt = capture.ground_truth
    cameras = {n: CameraTrack(capture.camera(n).timestamps, p.copy()) for n, p in gt.cameras.items()}
    for track in cameras.values():
        track.world_T_camera[:, :3, :3] = R @ track.world_T_camera[:, :3, :3]
        track.world_T_camera[:, :3, 3] = scale * track.world_T_camera[:, :3, 3] @ R.T + t
    joints = scale * (gt.joints + offset) @ R.T + t
    return Result(pipeline="baseline", capture="-", world_frame="ground_plane", timestamps=gt.timestamps, joints=joints, cameras=cameras)


def test_results_without_a_body_are_aligned_by_the_camera_centres(rig):
    """A similarity (scale 1.3) moves the cameras and the joints; the joints are 5 cm off besides.
    Aligned by the cameras, the cameras come back exactly and the joints 5 cm off; aligned by the
    joints (as with two cameras only), the offset would vanish into the translation."""
    R, t = rotvec_to_matrix(np.array([0.3, 0.2, -2.0])), np.array([1.0, 4.0, -0.5])
    ev = evaluate(points_result(rig, [0.0, 0.03, 0.04], 1.3, R, t), rig)
    assert ev.alignment == "similarity (Umeyama with scale over the centres of 4 cameras; scale 0.769)"
    assert ev.metrics["mcpe_m"] < 1e-9 and ev.metrics["mcoe_rad"] < 1e-9
    assert ev.metrics["mpjpe_m"] == pytest.approx(0.05)

    two = Capture("two", rig.cameras, ground_truth=replace(rig.ground_truth, cameras={n: rig.ground_truth.cameras[n] for n in ("cam0", "cam1")}))
    ev = evaluate(points_result(rig, [0.0, 0.03, 0.04], 1.3, R, t), two)
    assert ev.alignment.startswith("similarity (Umeyama with scale over all joints")
    assert ev.metrics["mpjpe_m"] < 1e-9 and ev.metrics["mcpe_m"] == pytest.approx(0.05)


def test_a_body_result_is_still_aligned_by_its_joints(rig):
    res = perfect_result(rig, "ground_plane")
    ev = evaluate(similarity_moved(res, 0.8, np.eye(3), np.array([0.0, 0.0, 1.0])), rig)
    assert ev.alignment.startswith("similarity (Umeyama with scale over all joints") and "scale 1.250" in ev.alignment


def test_camera_centre_alignment_weighs_cameras_equally():
    """Three cameras' centres through a known similarity; a fourth, seen in 100 frames, is 0.3 m
    off: it pulls the fit as one camera does, not as 100 (the least-squares answer by hand)."""
    rng = np.random.default_rng(3)
    ref = rng.normal(scale=2.0, size=(4, 3))
    s, R, t = 0.5, rotvec_to_matrix(np.array([0.0, 0.4, 1.1])), np.array([0.2, -1.0, 3.0])
    est = (ref - t) @ R / s  # s R est + t = ref
    exact = align_camera_centres([e[None] for e in est[:3]], [r[None] for r in ref[:3]])
    assert exact.scale == pytest.approx(s) and np.allclose(exact.R, R) and np.allclose(exact.t, t)
    moved = ref.copy()
    moved[3] += [0.3, 0.0, 0.0]
    many = align_camera_centres([e[None] for e in est[:3]] + [np.repeat(est[3:], 100, axis=0)], [r[None] for r in moved[:3]] + [np.repeat(moved[3:], 100, axis=0)])
    once = align_camera_centres([e[None] for e in est], [m[None] for m in moved])
    assert many.scale == pytest.approx(once.scale) and np.allclose(many.R, once.R) and np.allclose(many.t, once.t)
    rigid = align_camera_centres([e[None] * s for e in est], [r[None] for r in ref], with_scale=False)
    assert rigid.scale == 1.0 and np.allclose(rigid.apply(est * s), ref)
    with_nan = align_camera_centres([est[:1], est[1:2], est[2:3], np.full((5, 3), np.nan)], [ref[:1], ref[1:2], ref[2:3], np.zeros((5, 3))])
    assert with_nan.scale == pytest.approx(s)
    with pytest.raises(MocapgraphError, match="2 cameras have centres in both; aligning by camera centres needs 3"):
        align_camera_centres([est[:1], est[1:2], np.full((1, 3), np.nan)], [ref[:1], ref[1:2], ref[2:3]])
    with pytest.raises(MocapgraphError, match="collinear"):
        align_camera_centres([np.array([[0.0, 0, k]]) for k in range(3)], [np.array([[1.0, 0, k]]) for k in range(3)])


def test_static_cameras_also_scored_as_a_rig_after_their_own_procrustes(rig):
    """The body turned by 0.02 rad about its joints' centroid, the cameras exact, all moved by a
    similarity: aligned by the joints, each camera lands turned the other way about that centroid
    (its error by hand); the static cameras as a rig, after their own Procrustes, exactly on the
    truth, that Procrustes' turn the body's. The body 1 % larger about its centroid: the rig's
    scale 1.01, the static cameras that much too near it. A rig with one camera 10 cm off: the
    Procrustes spreads it over the rig (by hand)."""
    turn = rotvec_to_matrix(np.array([0.0, 0.02, 0.0]))
    res = perfect_result(rig, "ground_plane")
    centroid = res.joints.reshape(-1, 3).mean(0)
    res.joints = (res.joints - centroid) @ turn.T + centroid
    R, t = rotvec_to_matrix(np.array([0.3, 0.2, -2.0])), np.array([1.0, 4.0, -0.5])
    ev = evaluate(similarity_moved(res, 1.3, R, t), rig)
    centres = np.stack([p[0, :3, 3] for p in rig.ground_truth.cameras.values()])
    by_hand = np.linalg.norm((centres - centroid) @ turn - (centres - centroid), axis=1).mean()  # turn⁻¹ = turnᵀ
    assert ev.metrics["static_mcpe_m"] == pytest.approx(by_hand, rel=1e-6) and by_hand > 0.01
    assert ev.metrics["static_mcoe_rad"] == pytest.approx(0.02, rel=1e-6)
    assert ev.metrics["static_mcpe_procrustes_m"] < 1e-9 and ev.metrics["static_mcoe_procrustes_rad"] < 1e-9
    # what the joints' alignment got wrong about the rig: the body's turn, no scale
    assert ev.metrics["static_rig_turn_rad"] == pytest.approx(0.02, rel=1e-6) and ev.metrics["static_rig_scale"] == pytest.approx(1.0, abs=1e-9)
    large = perfect_result(rig, "ground_plane")
    large.joints = 1.01 * (large.joints - centroid) + centroid  # the body 1 % larger than the cameras' distances say
    m = evaluate(similarity_moved(large, 0.8, R, t), rig).metrics
    assert m["static_rig_scale"] == pytest.approx(1.01, rel=1e-9) and m["static_rig_turn_rad"] < 1e-6
    assert m["static_mcpe_m"] == pytest.approx(np.linalg.norm(centres - centroid, axis=1).mean() * (1 - 1 / 1.01), rel=1e-6)

    two = perfect_result(rig, "ground_plane")
    two.cameras = {n: two.cameras[n] for n in ("cam0", "cam1")}
    two.cameras["cam1"].world_T_camera[:, :3, 3] += [0.1, 0.0, 0.0]
    m = evaluate(two, rig).metrics
    # orientations exact: rotation identity; centroids matched, the scale the baselines' ratio
    ref = centres[:2] - centres[:2].mean(0)
    est = ref + [[-0.05, 0, 0], [0.05, 0, 0]]
    scaled = est * np.linalg.norm(ref) / np.linalg.norm(est)
    assert m["static_mcpe_procrustes_m"] == pytest.approx(np.linalg.norm(scaled - ref, axis=1).mean(), rel=1e-9)
    assert m["static_mcoe_procrustes_rad"] < 1e-12
    one = perfect_result(rig, "ground_plane")
    one.cameras = {"cam0": one.cameras["cam0"]}
    assert "static_mcpe_procrustes_m" not in evaluate(one, rig).metrics  # one camera: no rig to align
    late = perfect_result(rig, "ground_plane")
    late.cameras["cam1"] = CameraTrack(late.cameras["cam1"].timestamps + 100.0, late.cameras["cam1"].world_T_camera)
    assert evaluate(late, rig).metrics["static_mcpe_procrustes_m"] < 1e-9  # a camera with no frame to compare is left out


def test_ground_similarity_keeps_ground_and_up():
    """Points moved by a turn about Z, a horizontal shift and a scale: recovered exactly. Tilted
    as well: the fit stays a turn about Z and leaves the tilt in (a similarity would take it out)."""
    from mocapgraph.data_tools.evaluation.alignment import ground_similarity, umeyama

    rng = np.random.default_rng(3)
    src = rng.normal(size=(40, 3)) + [0.0, 0.0, 1.0]
    yaw = rotvec_to_matrix(np.array([0.0, 0.0, 0.7]))
    dst = 1.2 * src @ yaw.T + [0.5, -2.0, 0.0]
    fit = ground_similarity(src, dst)
    assert fit.scale == pytest.approx(1.2, rel=1e-12) and np.allclose(fit.R, yaw, atol=1e-12) and np.allclose(fit.t, [0.5, -2.0, 0.0], atol=1e-12)
    tilt = rotvec_to_matrix(np.array([0.05, 0.0, 0.0]))
    tilted = ground_similarity(src @ tilt.T, dst)
    assert tilted.R[2, 2] == 1.0 and tilted.t[2] == 0.0
    residual = np.linalg.norm(tilted.apply(src @ tilt.T) - dst, axis=1).mean()
    assert residual > 0.02 and np.linalg.norm(umeyama(src @ tilt.T, dst, True).apply(src @ tilt.T) - dst, axis=1).mean() < 1e-9
    with pytest.raises(MocapgraphError, match="no horizontal spread"):
        ground_similarity(np.array([[0.0, 0, 1], [0, 0, 2]]), np.array([[0.0, 0, 1], [0, 0, 2]]))


def test_static_cameras_under_other_alignments(rig):
    """The body turned by 0.02 rad about the vertical through its joints' centroid, the cameras
    exact, all moved by a turn about Z, a shift and a scale (the ground kept): aligned over every
    camera's centres the static cameras are exact; aligned keeping the ground, as far off as after
    the joints' similarity (the same turn undone, by hand); over the joints and the static
    cameras in between. The first half of the states turned and the second not: the halves'
    fits differ by the 0.02 rad. A tilt of the whole result is taken out by a similarity, not by
    the ground's alignment."""
    capture = replace(rig, world_frame="Z up, metres, origin on the ground at the subject's start")
    turn = rotvec_to_matrix(np.array([0.0, 0.0, 0.02]))
    res = perfect_result(capture, "ground_plane")
    centroid = res.joints.reshape(-1, 3).mean(0)
    res.joints = (res.joints - centroid) @ turn.T + centroid
    m = evaluate(similarity_moved(res, 1.3, rotvec_to_matrix(np.array([0.0, 0.0, -2.0])), np.array([1.0, 4.0, 0.0])), capture).metrics
    centres = np.stack([p[0, :3, 3] for p in capture.ground_truth.cameras.values()])
    by_hand = np.linalg.norm((centres - centroid) @ turn - (centres - centroid), axis=1).mean()
    assert m["static_mcpe_m"] == pytest.approx(by_hand, rel=1e-6) and by_hand > 0.01
    assert m["static_mcpe_cameras_m"] < 1e-9
    assert m["static_mcpe_ground_m"] == pytest.approx(by_hand, rel=1e-6)
    assert 0.0 < m["static_mcpe_scene_m"] < 0.5 * by_hand
    assert m["alignment_halves_rad"] < 1e-6  # arccos near 1: ~1e-8 of rounding

    half = perfect_result(capture, "ground_plane")
    first = slice(0, len(half.joints) // 2)
    half.joints[first] = (half.joints[first] - centroid) @ turn.T + centroid
    m = evaluate(half, capture).metrics
    assert m["alignment_halves_rad"] == pytest.approx(0.02, rel=1e-6)
    distance = np.mean(np.linalg.norm(centres - capture.ground_truth.joints.reshape(-1, 3).mean(0), axis=1))
    assert m["static_alignment_noise_m"] == pytest.approx(0.01 * distance, rel=1e-6)

    tilt = rotvec_to_matrix(np.array([0.03, 0.0, 0.0]))
    m = evaluate(similarity_moved(perfect_result(capture, "ground_plane"), 1.0, tilt, np.zeros(3)), capture).metrics
    assert m["static_mcpe_m"] < 1e-9 and m["static_mcpe_ground_m"] > 0.5 * np.linalg.norm(centres @ tilt.T - centres, axis=1).mean() > 0.01
    assert "static_mcpe_ground_m" not in evaluate(perfect_result(rig, "ground_plane"), rig).metrics  # a world of unknown up: no ground to keep


def test_static_views_need_no_alignment(rig):
    """The body as each static camera sees it, unchanged by any similarity of the result: a
    perfect result moved by one is exact. The body turned about its joints' centroid: the centroid's
    bearings and distances stay, the turn is ``static_mcoe_rad`` (the view's third part). One
    camera turned about an axis across its view to the centroid: its bearing and the pairs with it
    off by that angle (by hand: three of the six pairs). The body 2 % larger about its centroid
    (the cameras as they were): every camera 2 % too near for its size."""
    R, t = rotvec_to_matrix(np.array([0.3, -0.2, 1.1])), np.array([1.0, -2.0, 0.5])
    m = evaluate(similarity_moved(perfect_result(rig, "ground_plane"), 0.7, R, t), rig).metrics
    assert m["static_view_bearing_rad"] < 1e-9 and m["static_view_distance_ratio"] == pytest.approx(1.0, abs=1e-9) and m["static_pair_turn_rad"] < 1e-6

    turn = rotvec_to_matrix(np.array([0.0, 0.0, 0.02]))
    res = perfect_result(rig, "ground_plane")
    centroid = res.joints.reshape(-1, 3).mean(0)
    res.joints = (res.joints - centroid) @ turn.T + centroid
    m = evaluate(similarity_moved(res, 1.3, R, t), rig).metrics
    assert m["static_view_bearing_rad"] < 1e-9 and m["static_view_distance_ratio"] == pytest.approx(1.0, abs=1e-9)
    assert m["static_pair_turn_rad"] < 1e-6 and m["static_mcoe_rad"] == pytest.approx(0.02, rel=1e-6)

    res = perfect_result(rig, "ground_plane")
    pose = res.cameras["cam0"].world_T_camera
    to_body = centroid - pose[0, :3, 3]
    axis = np.cross(to_body, [0.3, -0.5, 0.8])
    tilt = rotvec_to_matrix(0.01 * axis / np.linalg.norm(axis))
    pose[:, :3, :3] = tilt @ pose[:, :3, :3]  # turned about its centre, across its view
    m = evaluate(similarity_moved(res, 0.9, R, t), rig).metrics
    assert m["static_view_bearing_rad"] == pytest.approx(0.01 / 4, rel=1e-6)
    assert m["static_pair_turn_rad"] == pytest.approx(0.01 * 3 / 6, rel=1e-6)
    assert m["static_view_distance_ratio"] == pytest.approx(1.0, abs=1e-9)

    large = perfect_result(rig, "ground_plane")
    large.joints = 1.02 * (large.joints - centroid) + centroid
    m = evaluate(large, rig).metrics
    assert m["static_view_distance_ratio"] == pytest.approx(1 / 1.02, rel=1e-9) and m["static_view_bearing_rad"] < 1e-9
