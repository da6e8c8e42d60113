"""Simulated 2D detectors: exact projection, noise scale, confidences, occlusion, rates, boxes."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import spearmanr

from mocapgraph.body import load_body_model
from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.rotations import rotvec_to_matrix
from mocapgraph.data_tools.geometry.camera_model import distortion_max_radius2, in_frame_mask, project_points
from mocapgraph.data_tools.sim.detectors import (
    DETECTOR_PRESETS,
    DetectorModel,
    occluded_by_capsules,
    segment_distance,
    self_occluded,
    simulate_detections,
    simulate_detections_with_info,
)
from mocapgraph.errors import MocapgraphError

K = np.array([[1000.0, 0.0, 640.0], [0.0, 1000.0, 360.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.08, 0.02, 0.0005, -0.0005, 0.0])
IMAGE = (1280, 720)
UPRIGHT = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # body +Y up → world +Z; the body faces -Y


@pytest.fixture(scope="module")
def body():
    return load_body_model()


def standing(frames: int):
    """``root, pose`` of a person standing at the origin, pelvis 0.95 m up, facing world -Y."""
    root = np.tile(np.eye(4), (frames, 1, 1))
    root[:, :3, :3] = UPRIGHT
    root[:, :3, 3] = [0.0, 0.0, 0.95]
    pose = np.zeros((frames, 21, 3))
    pose[:, 15] = [0.0, 0.0, -1.3]  # left shoulder (joint 16): arm down
    pose[:, 16] = [0.0, 0.0, 1.3]  # right shoulder (joint 17)
    return root, pose


def look_at(eye, target=(0.0, 0.0, 0.9), up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """world_T_camera of an OpenCV camera at ``eye`` looking at ``target``."""
    eye = np.asarray(eye, dtype=float)
    z = np.asarray(target, dtype=float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    out = np.eye(4)
    out[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    out[:3, 3] = eye
    return out


def format_points(body, root, pose, fmt: str) -> np.ndarray:
    return body.forward(body.default_shape, root, pose, keypoints=fmt).keypoints


def simulate(body, model, frames=1, camera=(0.0, -5.0, 1.0), seed=0, target=(0.0, 0.0, 0.9)):
    root, pose = standing(frames)
    return simulate_detections_with_info(
        body, body.default_shape, root, pose, look_at(camera, target), K, DIST, IMAGE, model, np.random.default_rng(seed)
    )


def quiet(fmt="coco17", **rates) -> DetectorModel:
    """A detector with every effect off except ``rates``."""
    return replace(DetectorModel(name="test", format=fmt).without_effects(), **rates)


# ---------------------------------------------------------------------------------------------
# Projection


def test_project_points_is_opencvs_model():
    cv2 = pytest.importorskip("cv2")
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(40, 3)) * [1.0, 1.0, 0.5] + [0.0, 0.0, 4.0]
    cam = np.eye(4)
    cam[:3, :3] = rotvec_to_matrix(np.array([0.1, -0.2, 0.3]))
    cam[:3, 3] = [0.3, -0.2, 0.1]
    px, depth = project_points(pts, cam, K, DIST)
    R = cam[:3, :3].T
    ref, _ = cv2.projectPoints(pts.reshape(-1, 1, 3), cv2.Rodrigues(R)[0], -R @ cam[:3, 3], K, DIST)
    assert np.all(depth > 0)
    assert np.abs(ref[:, 0] - px).max() < 1e-9
    # per-frame cameras broadcast over the points' leading dimensions
    cams = np.stack([cam, look_at((0, -5, 1))])
    px2, _ = project_points(np.stack([pts, pts]), cams, K, DIST)
    assert np.allclose(px2[0], px) and np.allclose(px2[1], project_points(pts, cams[1], K, DIST)[0])
    # behind the camera: NaN pixels
    behind, d = project_points(np.array([0.0, 0.0, -1.0]), np.eye(4), K, DIST)
    assert d < 0 and np.all(np.isnan(behind))


def test_points_where_the_distortion_folds_back_are_out_of_frame():
    dist = np.array([-0.3, 0.0, 0.0, 0.0, 0.0])
    assert distortion_max_radius2(dist) == pytest.approx(1 / 0.9)
    assert distortion_max_radius2(np.zeros(5)) == np.inf
    # r = 2 (far outside a 1000 px focal length's view) folds to r_d = 2 (1 - 1.2) = -0.4: in the image
    far = np.array([[2.0, 0.0, 1.0], [0.2, 0.0, 1.0]])
    px, _, seen = in_frame_mask(far, np.eye(4), K, dist, IMAGE)
    assert 0 <= px[0, 0] < IMAGE[0]
    assert seen.tolist() == [False, True]


# ---------------------------------------------------------------------------------------------
# Exactness, noise and confidence


def test_without_effects_detections_are_the_exact_projection(body):
    root, pose = standing(3)
    cam = look_at((1.0, -4.0, 1.5))
    det = simulate_detections(
        body, body.default_shape, root, pose, cam, K, DIST, IMAGE, quiet("openpose25"), np.random.default_rng(1)
    )
    exact, _ = project_points(format_points(body, root, pose, "openpose25"), cam, K, DIST)
    assert det.format == "openpose25" and det.keypoints.shape == (3, 25, 3)
    assert np.abs(det.keypoints[..., :2] - exact).max() < 1e-9
    assert np.all(det.keypoints[..., 2] == 1.0)
    assert np.all(np.isfinite(det.boxes))


def test_noise_scales_with_the_persons_image_height(body):
    model = quiet(noise_frac_of_height=0.01)
    near_det, near = simulate(body, model, frames=300, camera=(0, -5, 1.0), seed=1)
    far_det, far = simulate(body, model, frames=300, camera=(0, -10, 1.0), seed=2)
    assert near.person_height_px[0] == pytest.approx(2 * far.person_height_px[0], rel=0.01)
    assert near.person_height_px[0] == pytest.approx(1000 * 1.50 / 5.0, rel=0.02)  # stature heel-to-eye

    difficulty = model.difficulties()

    def std(det, info):  # pixel error std per axis, in units of the point's difficulty
        return np.std((det.keypoints[..., :2] - info.pixels) / difficulty[:, None])

    s_near, s_far = std(near_det, near), std(far_det, far)
    assert s_near / s_far == pytest.approx(2.0, rel=0.05)
    assert s_near == pytest.approx(0.01 * near.person_height_px[0], rel=0.05)
    assert s_far == pytest.approx(0.01 * far.person_height_px[0], rel=0.05)


def test_heavy_tails_and_frame_correlation(body):
    gauss_det, info = simulate(body, quiet(noise_frac_of_height=0.01), frames=400, seed=3)
    heavy_det, _ = simulate(body, quiet(noise_frac_of_height=0.01, noise_tail_dof=3.0), frames=400, seed=3)
    sigma = info.noise_sigma_px[..., None]
    z_gauss = (gauss_det.keypoints[..., :2] - info.pixels) / sigma
    z_heavy = (heavy_det.keypoints[..., :2] - info.pixels) / sigma
    assert np.mean(np.abs(z_gauss) > 4) < 5e-4
    assert np.mean(np.abs(z_heavy) > 4) > 5e-3  # t with 3 dof scaled to unit std: 1.4% beyond 4σ
    corr_det, _ = simulate(body, quiet(noise_frac_of_height=0.01, noise_frame_correlation=0.8), frames=400, seed=4)
    z = ((corr_det.keypoints[..., :2] - info.pixels) / sigma).reshape(400, -1)
    lag1 = np.mean(z[1:] * z[:-1]) / np.mean(z * z)
    assert lag1 == pytest.approx(0.8, abs=0.05)
    assert np.std(z) == pytest.approx(1.0, rel=0.1)


def test_confidence_falls_with_the_error(body):
    model = replace(DetectorModel(format="coco17"), frame_miss_prob=0.0, keypoint_miss_prob=0.0, outlier_prob=0.0)
    det, info = simulate(body, model, frames=200, seed=5)
    err = np.linalg.norm(det.keypoints[..., :2] - info.pixels, axis=-1)
    ok = np.isfinite(err)
    rho = spearmanr(det.keypoints[..., 2][ok], err[ok]).statistic
    assert rho < -0.3
    conf = det.keypoints[..., 2][ok]
    assert conf.min() >= 0 and conf.max() <= 1


# ---------------------------------------------------------------------------------------------
# Self-occlusion


def test_segment_distance_matches_sampling():
    rng = np.random.default_rng(6)
    p0, p1, q0, q1 = rng.normal(size=(4, 100, 3))
    q1[:20] = q0[:20]  # some capsules are spheres
    p1[20:30] = p0[20:30]  # and some rays points
    s = np.linspace(0, 1, 201)
    a = p0[:, None] + s[None, :, None] * (p1 - p0)[:, None]
    b = q0[:, None] + s[None, :, None] * (q1 - q0)[:, None]
    brute = np.linalg.norm(a[:, :, None] - b[:, None, :], axis=-1).min(axis=(1, 2))
    exact = segment_distance(p0, p1, q0, q1)
    assert np.all(exact <= brute + 1e-12)
    assert np.allclose(exact, brute, atol=3e-2)
    parallel = segment_distance(np.zeros(3), np.array([1.0, 0, 0]), np.array([0.5, 1.0, 0]), np.array([3.0, 1.0, 0]))
    assert parallel == pytest.approx(1.0)


def test_capsule_test_on_explicit_geometry():
    """One capsule along x (radius 0.1), a camera 5 m in front of it along -y."""
    segments = np.array([[[[-1.0, 0, 0], [1.0, 0, 0]]]])
    radii = np.array([0.1])
    camera = np.array([[0.0, -5.0, 0.0]])
    points = np.array(
        [[
            [0.0, 1.0, 0.0],     # behind the capsule: hidden
            [0.0, 1.0, 0.5],     # behind but above it: seen
            [0.0, -1.0, 0.0],    # in front: seen
            [1.5, 1.0, 0.0],     # behind, past its end: seen
            [0.0, 0.05, 0.0],    # inside, on the far side of the axis: hidden
            [0.0, -0.05, 0.0],   # inside, on the camera's side: seen (capsule shrunk to 4 cm for it)
        ]]
    )  # fmt: skip
    hidden = occluded_by_capsules(points, camera, segments, radii, clearance_m=0.01)
    assert hidden[0].tolist() == [True, False, False, False, True, False]


def test_nose_is_hidden_from_behind_and_seen_from_the_front(body):
    model = quiet("coco17")
    nose = get_format("coco17").names.index("nose")
    _, front = simulate(body, model, camera=(0.0, -4.0, 1.6))
    _, back = simulate(body, model, camera=(0.0, 4.0, 1.6))
    assert not front.occluded[0, nose] and back.occluded[0, nose]
    assert not front.occluded.any()  # arms down, seen from the front: nothing hidden
    # the same from the capsule test on the posed body directly
    root, pose = standing(1)
    res = body.forward(body.default_shape, root, pose)
    both = np.array([[0.0, -4.0, 1.6], [0.0, 4.0, 1.6]])
    hidden = self_occluded(
        np.repeat(res.keypoints, 2, 0), np.repeat(res.joints, 2, 0), np.repeat(res.keypoints, 2, 0), both
    )
    assert hidden[:, 0].tolist() == [False, True]
    # from the left side, the right side of the body is hidden, the left side is not
    _, side = simulate(body, model, camera=(4.0, 0.0, 1.2))
    names = get_format("coco17").names
    for part in ("shoulder", "elbow", "knee", "ankle"):
        assert side.occluded[0, names.index("right_" + part)]
        assert not side.occluded[0, names.index("left_" + part)]


def test_occluded_points_are_dropped_noisier_and_less_confident(body):
    model = quiet(noise_frac_of_height=0.01, conf_noise_std=0.0, occluded_drop_prob=0.5, occluded_noise_mult=3.0, occluded_conf_mult=0.5)
    det, info = simulate(body, model, frames=300, camera=(4.0, 0.0, 1.2), seed=7)
    occ, vis = info.occluded, info.in_frame & ~info.occluded
    missing = np.isnan(det.keypoints[..., 0])
    assert missing[occ].mean() == pytest.approx(0.5, abs=0.05)
    assert not missing[vis].any()
    expected = 0.01 * info.person_height_px[:, None] * model.difficulties() * np.where(occ, 3.0, 1.0)
    assert np.allclose(info.noise_sigma_px, expected)
    conf = det.keypoints[..., 2]
    assert conf[occ & ~missing].max() <= 0.5
    assert conf[vis].mean() > 0.8 and conf[occ & ~missing].mean() < 0.5 * conf[vis].mean()


# ---------------------------------------------------------------------------------------------
# Rates, swaps, frame


def test_empirical_rates_match_the_parameters(body):
    frames = 3000
    model = quiet(
        noise_frac_of_height=0.001, frame_miss_prob=0.1, keypoint_miss_prob=0.05, body_swap_prob=0.1,
        limb_swap_prob=0.1, limb_swap_leg_fraction=0.5, outlier_prob=0.05,
    )  # fmt: skip
    det, info = simulate(body, model, frames=frames, seed=8)
    kp, exact = det.keypoints, info.pixels
    names = get_format("coco17").names
    assert info.in_frame.all() and not info.occluded.any()

    found = ~np.all(np.isnan(kp[..., 0]), axis=1)
    assert 1 - found.mean() == pytest.approx(0.1, abs=0.02)
    kp, exact = kp[found], exact[found]
    assert np.isnan(kp[..., 0]).mean() == pytest.approx(0.05, abs=0.01)

    def swapped(parts):
        """Per frame: do most of these points sit on the other side's exact position?"""
        votes = np.zeros(len(kp))
        for part in parts:
            left, right = names.index("left_" + part), names.index("right_" + part)
            for own, other in ((left, right), (right, left)):
                to_own = np.linalg.norm(kp[:, own, :2] - exact[:, own], axis=-1)
                to_other = np.linalg.norm(kp[:, own, :2] - exact[:, other], axis=-1)
                votes += np.where(to_other < 3, 1, np.where(to_own < 3, -1, 0))
        return votes > 0

    body_swap = swapped(("eye", "ear", "shoulder", "hip"))
    leg_swap = swapped(("knee", "ankle")) ^ body_swap
    arm_swap = swapped(("elbow", "wrist")) ^ body_swap
    assert body_swap.mean() == pytest.approx(0.1, abs=0.02)
    # one swap per frame at most: a limb swaps in half of the 10 % of frames, where the body did not
    assert leg_swap.mean() == pytest.approx(0.9 * 0.05, abs=0.012)
    assert arm_swap.mean() == pytest.approx(0.9 * 0.05, abs=0.012)
    assert not np.any(leg_swap & arm_swap) and not np.any(body_swap & (leg_swap | arm_swap))
    assert np.array_equal(body_swap, info.body_swapped[found]) and np.array_equal(leg_swap, info.limb_swapped[found] == "leg")

    # outliers: reported points far from where their (possibly swapped) label says
    perm = np.arange(len(names))
    for left, right in get_format("coco17").left_right_pairs:
        perm[[left, right]] = right, left
    part = [n.removeprefix("left_").removeprefix("right_") for n in names]
    arm = np.isin(part, ("elbow", "wrist"))
    leg = np.isin(part, ("knee", "ankle"))
    flip = body_swap[:, None] ^ (leg_swap[:, None] & leg) ^ (arm_swap[:, None] & arm)
    expected = np.where(flip[..., None], exact[:, perm], exact)
    far = np.linalg.norm(kp[..., :2] - expected, axis=-1) > 3
    reported = np.isfinite(kp[..., 0])
    assert far[reported].mean() == pytest.approx(0.05, abs=0.01)
    conf = kp[..., 2][reported & far]
    assert conf.min() >= 0.3 and conf.max() <= 0.7


def test_body_swap_exchanges_the_pairs_coordinates(body):
    det, info = simulate(body, quiet("openpose25", body_swap_prob=1.0), frames=2, camera=(1.0, -4.0, 1.2))
    fmt = get_format("openpose25")
    kp = det.keypoints
    assert info.body_swapped.all()
    for left, right in fmt.left_right_pairs:
        assert np.abs(kp[:, left, :2] - info.pixels[:, right]).max() < 1e-9
        assert np.abs(kp[:, right, :2] - info.pixels[:, left]).max() < 1e-9
    for i in (fmt.names.index("nose"), fmt.names.index("neck"), fmt.names.index("mid_hip")):
        assert np.abs(kp[:, i, :2] - info.pixels[:, i]).max() < 1e-9


def test_limb_swap_exchanges_one_limb_only(body):
    det, info = simulate(body, quiet("coco17", limb_swap_prob=1.0, limb_swap_leg_fraction=1.0), frames=2)
    names = get_format("coco17").names
    for part in ("knee", "ankle"):
        left, right = names.index("left_" + part), names.index("right_" + part)
        assert np.abs(det.keypoints[:, left, :2] - info.pixels[:, right]).max() < 1e-9
    for part in ("shoulder", "hip", "elbow", "wrist"):
        left = names.index("left_" + part)
        assert np.abs(det.keypoints[:, left, :2] - info.pixels[:, left]).max() < 1e-9
    assert (info.limb_swapped == "leg").all()


def test_points_out_of_frame_are_nan(body):
    det, info = simulate(body, quiet("openpose25", noise_frac_of_height=0.01), frames=20, camera=(0.0, -2.0, 1.2), target=(0.0, 0.0, 1.2))
    kp = det.keypoints
    names = get_format("openpose25").names
    assert not info.in_frame[:, names.index("left_ankle")].any()  # the feet are below the image
    assert info.in_frame[:, names.index("nose")].all()
    assert np.all(np.isnan(kp[~info.in_frame]))
    ok = np.isfinite(kp[..., 0])
    assert np.all((kp[..., 0][ok] >= 0) & (kp[..., 0][ok] < IMAGE[0]))
    assert np.all((kp[..., 1][ok] >= 0) & (kp[..., 1][ok] < IMAGE[1]))
    # the camera looks away: nobody, no box
    root, pose = standing(3)
    away = look_at((0.0, -5.0, 1.0), target=(0.0, -10.0, 1.0))
    det = simulate_detections(body, body.default_shape, root, pose, away, K, DIST, IMAGE, quiet("openpose25"), 0)
    assert np.all(np.isnan(det.keypoints)) and np.all(np.isnan(det.boxes))


def test_border_dropout(body):
    model = quiet(border_dropout_px=60.0, border_drop_prob=1.0)
    det, info = simulate(body, model, frames=2, camera=(0.0, -2.0, 1.2), target=(0.0, 0.0, 1.2))
    v = info.pixels[..., 1]
    near = info.in_frame & (v >= IMAGE[1] - 60)
    assert near.any()
    assert np.all(np.isnan(det.keypoints[near])) and np.all(np.isfinite(det.keypoints[info.in_frame & ~near]))


def test_boxes_contain_the_detections(body):
    for name, model in DETECTOR_PRESETS.items():
        det, info = simulate(body, replace(model, outlier_prob=0.05), frames=200, camera=(2.0, -3.0, 1.5), seed=9)
        box, kp = det.boxes, det.keypoints
        has = np.isfinite(box[:, 0])
        assert np.all(np.isnan(box[~has]))
        assert np.all(np.isnan(kp[~has]))
        x, y = kp[has, :, 0], kp[has, :, 1]
        ok = np.isfinite(x)
        lo_x, lo_y, hi_x, hi_y = (np.broadcast_to(box[has, i : i + 1], x.shape)[ok] for i in range(4))
        assert np.all((lo_x <= x[ok]) & (x[ok] <= hi_x) & (lo_y <= y[ok]) & (y[ok] <= hi_y)), name
        assert np.all((box[has, 0] >= 0) & (box[has, 2] <= IMAGE[0]) & (box[has, 1] >= 0) & (box[has, 3] <= IMAGE[1]))
        assert np.all((box[has, 4] >= 0) & (box[has, 4] <= 1))
        # the box also holds the exact projections of every point in frame
        px = np.where(info.in_frame[has][..., None], info.pixels[has], np.nan)
        assert np.all(np.nanmin(px[..., 0], axis=1) >= box[has, 0]) and np.all(np.nanmax(px[..., 1], axis=1) <= box[has, 3])


def test_missing_points_are_nan_never_zero(body):
    model = replace(DETECTOR_PRESETS["openpose"], keypoint_miss_prob=0.4, frame_miss_prob=0.2)
    det, _ = simulate(body, model, frames=100, seed=10)
    kp = det.keypoints
    rows_nan = np.isnan(kp)
    assert np.all(rows_nan.all(axis=-1) | ~rows_nan.any(axis=-1))  # whole rows
    assert rows_nan[..., 0].mean() > 0.4
    assert not np.any(kp[~rows_nan] == 0)
    assert np.all(kp[..., 2][~rows_nan[..., 2]] > 0)


# ---------------------------------------------------------------------------------------------
# Presets, determinism, validation


@pytest.mark.parametrize(
    "preset, fmt, points",
    [("openpose", "openpose25", 25), ("alphapose", "coco17", 17), ("coco_hrnet", "coco17", 17), ("mediapipe", "blazepose33", 33)],
)
def test_presets_produce_their_formats(body, preset, fmt, points):
    det, _ = simulate(body, DETECTOR_PRESETS[preset], frames=40, seed=11)
    assert det.name == preset and det.format == fmt
    assert det.keypoints.shape == (40, points, 3) and det.boxes.shape == (40, 5)
    conf = det.keypoints[..., 2]
    assert np.nanmin(conf) > 0 and np.nanmax(conf) <= 1
    assert np.isfinite(conf).mean() > 0.5
    unmapped = get_format(fmt).mix().sum(axis=1) == 0
    assert np.all(np.isnan(det.keypoints[:, unmapped]))  # BlazePose's fingers, mouth, eye corners


def test_same_seed_same_detections(body):
    model = DETECTOR_PRESETS["openpose"]
    a, info = simulate(body, model, frames=300, seed=12)
    b, _ = simulate(body, model, frames=300, seed=12)
    c, _ = simulate(body, model, frames=300, seed=13)
    assert np.array_equal(a.keypoints, b.keypoints, equal_nan=True)
    assert np.array_equal(a.boxes, b.boxes, equal_nan=True)
    assert not np.array_equal(a.keypoints, c.keypoints, equal_nan=True)
    # turning one effect off leaves the others' random numbers alone
    d, _ = simulate(body, replace(model, body_swap_prob=0.0, limb_swap_prob=0.0), frames=300, seed=12)
    plain = ~info.body_swapped & (info.limb_swapped == "")
    assert 0 < plain.sum() < 300
    assert np.array_equal(a.keypoints[plain], d.keypoints[plain], equal_nan=True)
    assert not np.array_equal(a.keypoints[~plain], d.keypoints[~plain], equal_nan=True)


def test_invalid_model_parameters_are_errors():
    with pytest.raises(MocapgraphError, match="frame_miss_prob must lie in"):
        DetectorModel(frame_miss_prob=1.5)
    with pytest.raises(MocapgraphError, match="noise_tail_dof must be > 2"):
        DetectorModel(noise_tail_dof=2.0)
    with pytest.raises(MocapgraphError, match="unknown keypoint format"):
        DetectorModel(format="vitpose133")
    with pytest.raises(MocapgraphError, match="noise_frac_of_height must be a finite number"):
        DetectorModel(noise_frac_of_height=-0.1)
