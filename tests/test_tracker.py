"""The CDT person tracker on a synthetic aircap capture (3 unsynchronised UAVs), against ground truth.

Errors are horizontal distances between the track and the true pelvis after the first second;
velocities are compared with the true pelvis velocity (gait sway included).
"""

from __future__ import annotations

import copy

import numpy as np
import pytest
from scipy.ndimage import uniform_filter1d

from mocapgraph.body.rotations import rotvec_to_matrix
from mocapgraph.data_tools.geometry.camera_model import in_image, project_points
from mocapgraph.data_tools.sim.synthetic import synthesize
from mocapgraph.data_tools.tracking.tracker import (
    Track,
    TrackerParams,
    boxes_from_keypoints,
    process_noise,
    track_person,
    transition,
)
from mocapgraph.errors import MocapgraphError

SETTLE_S = 1.0


@pytest.fixture(scope="module")
def capture():
    return synthesize("aircap", seed=2, duration_s=8.0)


@pytest.fixture(scope="module")
def true_poses(capture):
    return dict(capture.ground_truth.cameras)


@pytest.fixture(scope="module")
def track(capture, true_poses):
    return track_person(capture, true_poses)


def pelvis(capture, times=None):
    gt = capture.ground_truth
    p = gt.root[:, :3, 3]
    if times is None:
        return p
    return np.stack([np.interp(times, gt.timestamps, p[:, i]) for i in range(3)], axis=1)


def horizontal_errors(track: Track, capture, after: float = SETTLE_S) -> np.ndarray:
    gt = capture.ground_truth
    pos, _ = track.at(gt.timestamps)
    keep = gt.timestamps > after
    return np.linalg.norm(pos[keep, :2] - pelvis(capture)[keep, :2], axis=1)


def frame_mask(track: Track, camera: str, frames) -> np.ndarray:
    return (track.camera == camera) & np.isin(track.frame, frames)


# ---------------------------------------------------------------------------------------------
# Accuracy


def test_track_with_true_poses_is_accurate(track, capture):
    err = horizontal_errors(track, capture)
    assert err.mean() < 0.3, err.mean()
    assert np.all(np.isfinite(track.position)) and np.all(np.isfinite(track.covariance))
    assert track.observed.mean() > 0.95
    assert track.accepted.sum() >= 0.95 * track.detected.sum()
    assert np.all(np.diff(track.times) >= 0)
    assert np.all(np.linalg.eigvalsh(track.covariance) > 0)


def test_velocity_roughly_right(track, capture):
    gt = capture.ground_truth
    true_v = np.gradient(pelvis(capture), gt.timestamps, axis=0)
    v = track.velocity_at(gt.timestamps)
    keep = gt.timestamps > SETTLE_S
    err = np.linalg.norm(v[keep, :2] - true_v[keep, :2], axis=1)
    assert err.mean() < 0.4, err.mean()
    # most of that is the pelvis swaying with the gait; against its 0.5 s average the error is small
    t = np.arange(SETTLE_S, 7.9, 0.01)
    p = pelvis(capture, t)
    averaged = uniform_filter1d(np.gradient(p, t, axis=0), 50, axis=0, mode="nearest")
    err = np.linalg.norm(track.velocity_at(t)[:, :2] - averaged[:, :2], axis=1)
    assert err.mean() < 0.25, err.mean()


def test_noisy_camera_poses(capture, true_poses):
    rng = np.random.default_rng(11)
    noisy = {}
    for name, T in true_poses.items():
        T = T.copy()  # a constant bias per camera: 0.5 m per axis, 1° per axis
        T[:, :3, 3] += rng.normal(scale=0.5, size=3)
        T[:, :3, :3] = rotvec_to_matrix(np.radians(rng.normal(scale=1.0, size=3))) @ T[:, :3, :3]
        noisy[name] = T
    err = horizontal_errors(track_person(capture, noisy), capture)
    assert err.mean() < 0.8, err.mean()


def test_boxes_derived_from_keypoints(capture, true_poses):
    no_boxes = copy.deepcopy(capture)
    for cam in no_boxes.cameras:
        for det in cam.detectors.values():
            det.boxes = None
    err = horizontal_errors(track_person(no_boxes, true_poses), capture)
    assert err.mean() < 0.3, err.mean()


@pytest.fixture(scope="module")
def single_camera(capture, true_poses):
    name = capture.cameras[0].name
    return {name: true_poses[name]}


def test_single_camera_uses_box_height_for_range(capture, single_camera):
    tr = track_person(capture, single_camera)
    assert set(tr.camera) == set(single_camera)
    assert horizontal_errors(tr, capture).mean() < 0.6


# ---------------------------------------------------------------------------------------------
# Outliers and gaps


def inject_outlier_boxes(capture, detector: str, fraction: float, seed: int):
    """A copy with ``fraction`` of the detector's boxes replaced by random boxes at least 400 px
    away; returns it and the replaced frames per camera."""
    out = copy.deepcopy(capture)
    rng = np.random.default_rng(seed)
    injected = {}
    for cam in out.cameras:
        boxes = cam.detectors[detector].boxes
        have = np.flatnonzero(np.isfinite(boxes[:, 0]))
        frames = np.sort(rng.choice(have, size=int(round(fraction * len(have))), replace=False))
        w, h = cam.image_size
        for i in frames:
            x0, y0, x1, y1, _ = boxes[i]
            centre = np.array([x0 + x1, y0 + y1]) / 2
            size = np.array([x1 - x0, y1 - y0]) * rng.uniform(0.7, 1.3)
            while True:
                c = rng.uniform(size / 2, np.array([w, h]) - size / 2)
                if np.linalg.norm(c - centre) >= 400:
                    break
            boxes[i, :4] = np.concatenate([c - size / 2, c + size / 2])
            boxes[i, 4] = 0.9
        injected[cam.name] = frames
    return out, injected


def test_gate_rejects_outlier_boxes(capture, true_poses):
    clean = track_person(capture, true_poses, detector="openpose")
    dirty_capture, injected = inject_outlier_boxes(capture, "openpose", 0.10, seed=5)
    dirty = track_person(dirty_capture, true_poses, detector="openpose")
    bad = np.zeros(len(dirty.times), dtype=bool)
    for name, frames in injected.items():
        bad |= frame_mask(dirty, name, frames)
    assert bad.sum() > 60
    rejected = ~dirty.accepted[bad]
    assert rejected.mean() >= 0.8, rejected.mean()
    good = dirty.detected & ~bad
    assert dirty.accepted[good].mean() > 0.95
    e_clean = horizontal_errors(clean, capture).mean()
    e_dirty = horizontal_errors(dirty, capture).mean()
    assert e_dirty < 0.3 and e_dirty < e_clean + 0.1, (e_clean, e_dirty)


def test_gap_without_detections_coasts_and_recovers(capture, true_poses, track):
    gapped = copy.deepcopy(capture)
    for cam in gapped.cameras:
        gone = (cam.timestamps >= 3.0) & (cam.timestamps < 5.0)
        for det in cam.detectors.values():
            det.keypoints[gone] = np.nan
            det.boxes[gone] = np.nan
    tr = track_person(gapped, true_poses)
    in_gap = (tr.times >= 3.0) & (tr.times < 5.0)
    assert not tr.detected[in_gap].any()
    assert not tr.observed[(tr.times > 3.3) & (tr.times < 4.7)].any()
    assert tr.observed[tr.times > 5.5].mean() > 0.95
    # the forward filter coasts: its position variance grows through the gap
    var = tr.filtered_covariance[in_gap, 0, 0] + tr.filtered_covariance[in_gap, 1, 1]
    assert np.all(np.diff(var) >= 0) and var[-1] > 50 * var[0]
    # the smoothed track is least certain in the middle of the gap
    _, cov = tr.at([2.0, 4.0, 7.0])
    assert cov[1, 0, 0] > 4 * cov[0, 0, 0] and cov[1, 0, 0] > 4 * cov[2, 0, 0]
    assert np.all(np.isfinite(tr.position))
    after = horizontal_errors(tr, capture, after=5.5)
    assert after.mean() < 0.3, after.mean()
    assert after.mean() < horizontal_errors(track, capture, after=5.5).mean() + 0.1


def test_no_boxes_at_all_is_a_clear_error(capture, true_poses):
    empty = copy.deepcopy(capture)
    for cam in empty.cameras:
        for det in cam.detectors.values():
            det.keypoints[:] = np.nan
            det.boxes[:] = np.nan
    with pytest.raises(MocapgraphError, match="no person box"):
        track_person(empty, true_poses)


# ---------------------------------------------------------------------------------------------
# Regions of interest and keypoint rejection


def test_rois_contain_the_true_pelvis(track, capture, true_poses):
    rois = track.predicted_rois(capture, true_poses, margin=0.2)
    for cam in capture.cameras:
        roi = rois[cam.name]
        assert roi.shape == (cam.num_frames, 4)
        px, _ = project_points(pelvis(capture, cam.timestamps), true_poses[cam.name], cam.K, cam.distortion)
        seen = in_image(px, cam.image_size)
        inside = (px[:, 0] >= roi[:, 0]) & (px[:, 0] <= roi[:, 2]) & (px[:, 1] >= roi[:, 1]) & (px[:, 1] <= roi[:, 3])
        assert inside[seen].mean() > 0.9, (cam.name, inside[seen].mean())
        # and they stay tight: well under three box heights
        box = cam.detectors["openpose"].boxes
        assert np.nanmedian(roi[:, 3] - roi[:, 1]) < 2.5 * np.nanmedian(box[:, 3] - box[:, 1])


def test_inlier_detections_flag_far_keypoints(track, capture, true_poses):
    dirty = copy.deepcopy(capture)
    rng = np.random.default_rng(3)
    injected = {}
    for cam in dirty.cameras:
        kp = cam.detectors["openpose"].keypoints
        present = np.argwhere(np.isfinite(kp[..., 0]))
        pick = present[rng.random(len(present)) < 0.03]
        w, h = cam.image_size
        mask = np.zeros(kp.shape[:2], dtype=bool)
        for f, k in pick:
            angle = rng.uniform(0, 2 * np.pi)
            moved = np.clip(kp[f, k, :2] + 600 * np.array([np.cos(angle), np.sin(angle)]), 0, [w - 1, h - 1])
            if np.linalg.norm(moved - kp[f, k, :2]) >= 400:
                kp[f, k, :2] = moved
                mask[f, k] = True
        injected[cam.name] = mask
    inliers = track.inlier_detections(dirty, true_poses, detector="openpose")
    for cam in dirty.cameras:
        ok, mask = inliers[cam.name], injected[cam.name]
        present = np.isfinite(cam.detectors["openpose"].keypoints[..., 0])
        assert ok.shape == present.shape and not ok[~present].any()
        assert mask.sum() > 50
        assert (~ok[mask]).mean() >= 0.95, (cam.name, (~ok[mask]).mean())
        assert ok[present & ~mask].mean() >= 0.95, (cam.name, ok[present & ~mask].mean())


# ---------------------------------------------------------------------------------------------
# API details


def test_deterministic(capture, single_camera):
    first, again = track_person(capture, single_camera), track_person(capture, single_camera)
    for name in ("times", "position", "velocity", "covariance", "accepted", "observed", "mahalanobis2"):
        assert np.array_equal(getattr(first, name), getattr(again, name), equal_nan=name == "mahalanobis2")


def test_at_interpolates_and_extrapolates(track):
    i = len(track.times) // 2
    pos, cov = track.at(track.times[i : i + 1])
    assert np.allclose(pos[0], track.position[i], atol=1e-9)
    assert np.allclose(cov[0], track.covariance[i], atol=1e-12)
    mid = 0.5 * (track.times[i] + track.times[i + 1])
    pos, _ = track.at([mid])
    assert np.linalg.norm(pos[0] - 0.5 * (track.position[i] + track.position[i + 1])) < 0.01
    end = track.times[-1]
    pos, cov = track.at([end + 1.0])
    assert np.allclose(pos[0], track.position[-1] + track.velocity[-1], atol=1e-9)
    assert cov[0, 0, 0] > track.covariance[-1, 0, 0]


def test_motion_model():
    p = TrackerParams(accel_std_m_s2=2.0, vertical_accel_std_m_s2=0.5)
    F, Q = transition(0.5), process_noise(0.5, p)
    assert np.allclose(F @ np.r_[0, 0, 0, 1.0, 2.0, 3.0], [0.5, 1.0, 1.5, 1, 2, 3])
    assert np.allclose(Q, Q.T) and np.all(np.linalg.eigvalsh(Q) > 0)
    assert np.isclose(Q[3, 3], 4.0 * 0.5) and np.isclose(Q[5, 5], 0.25 * 0.5)
    assert np.allclose(process_noise(0.0, p), 0.0)


def test_params_and_poses_are_checked(capture, true_poses):
    with pytest.raises(MocapgraphError, match="gate_probability"):
        TrackerParams(gate_probability=1.5)
    with pytest.raises(MocapgraphError, match="accel_std_m_s2"):
        TrackerParams(accel_std_m_s2=0.0)
    name = capture.cameras[0].name
    with pytest.raises(MocapgraphError, match="camera_poses"):
        track_person(capture, {name: true_poses[name][:5]})
    with pytest.raises(MocapgraphError, match="detector"):
        track_person(capture, true_poses, detector="nope")


def test_boxes_from_keypoints():
    kp = np.full((2, 5, 3), np.nan)
    kp[0] = [[100, 200, 0.9], [140, 260, 0.8], [120, 300, 0.7], [110, 250, 0.9], [130, 280, 0.02]]
    kp[1, :3] = [[10, 10, 0.9], [20, 20, 0.9], [30, 30, 0.9]]  # too few points
    boxes = boxes_from_keypoints(kp, (640, 480), TrackerParams(keypoint_box_margin_frac=0.1, min_keypoints=4))
    assert np.allclose(boxes[0, :4], [90, 190, 150, 310])
    assert np.isclose(boxes[0, 4], np.mean([0.9, 0.8, 0.7, 0.9]) * np.sqrt(4 / 5))
    assert np.all(np.isnan(boxes[1]))


def test_lost_track_is_reinitialised(capture, true_poses):
    # The prior poses jump by 6 m at t = 3 s (a GPS reset): every box after it falls outside the
    # gate until the filter re-initialises from the rejected boxes.
    poses = {}
    for cam in capture.cameras:
        T = true_poses[cam.name].copy()
        T[cam.timestamps < 3.0, 0, 3] += 6.0
        poses[cam.name] = T
    tr = track_person(capture, poses)
    assert tr.reinitialised.sum() == 1
    assert 3.0 < tr.times[tr.reinitialised][0] < 3.6
    assert horizontal_errors(tr, capture, after=4.0).mean() < 0.3
