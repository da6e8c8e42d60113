"""``run baseline --uncalibrated`` end to end on small synthetic captures, against ground truth:
cameras after a similarity alignment of their centres, reprojection against the simulated noise,
left/right swaps against the runs injected (and the simulator's own), the metric world, the
command line and its errors."""

from __future__ import annotations

import json
import time
from copy import deepcopy
from dataclasses import replace

import numpy as np
import pytest

from mocapgraph.body import load_body_model
from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.labelling import SWAP_KINDS, swap_permutation
from mocapgraph.cli.main import main
from mocapgraph.data_tools.evaluation.alignment import umeyama
from mocapgraph.data_tools.geometry.camera_model import project_points
from mocapgraph.data_tools.io.capture import write_capture
from mocapgraph.data_tools.io.result import load_result
from mocapgraph.data_tools.sim.synthetic import synthesize
from mocapgraph.errors import MocapgraphError
from mocapgraph.pipelines.baseline import BaselineOptions, run_baseline
from mocapgraph.pipelines.uncalibrated_baseline import (
    ANKLE_HEIGHT_FRACTION,
    EYE_HEIGHT_FRACTION,
    UncalibratedOptions,
    run_uncalibrated_baseline,
)

SWAP_RUNS = [(5, 12), (30, 23), (70, 8), (95, 20), (130, 6)]
"""Frames of camera 3 whose whole-body labels the tests swap: runs of 0.2–0.8 s at 30 fps, 46 % of the clip."""


def static_rig(faults: str, seed: int = 0):
    """Four static cameras of a 5 s ``rich`` capture (the hand-held one left out)."""
    capture = synthesize("rich", seed=seed, duration_s=5.0, detector_faults=faults)
    cams = [c for c in capture.cameras if not c.moving][:4]
    gt = capture.ground_truth
    gt = replace(gt, cameras={c.name: gt.cameras[c.name] for c in cams}, swaps={c.name: gt.swaps[c.name] for c in cams})
    return replace(capture, cameras=cams, ground_truth=gt)


def with_swaps(capture):
    """The capture with camera 3's labels swapped in :data:`SWAP_RUNS`, and those frames."""
    out = deepcopy(capture)
    cam = out.cameras[2]
    det = next(iter(cam.detectors.values()))
    swapped = np.zeros(cam.num_frames, dtype=bool)
    for start, length in SWAP_RUNS:
        swapped[start : start + length] = True
    det.keypoints[swapped] = det.keypoints[swapped][:, swap_permutation(get_format(det.format).names, "body")]
    return out, swapped


def camera_errors(result, capture):
    """Per camera, position (m) and rotation (deg) error after the similarity that best maps the
    estimated camera centres onto the true ones, and that similarity."""
    names = [c.name for c in capture.cameras]
    est = np.stack([result.cameras[n].world_T_camera[0] for n in names])
    ref = np.stack([capture.ground_truth.cameras[n][0] for n in names])
    fit = umeyama(est[:, :3, 3], ref[:, :3, 3], with_scale=True)
    moved = fit.apply_pose(est)
    position = np.linalg.norm(moved[:, :3, 3] - ref[:, :3, 3], axis=1)
    cos = (np.einsum("cij,cij->c", moved[:, :3, :3], ref[:, :3, :3]) - 1.0) / 2.0
    return position, np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))), fit


def found_swaps(result, capture, c: int) -> np.ndarray:
    """``(F,)`` the result's label code per frame of camera ``c`` (0 where it has none)."""
    cam = capture.cameras[c]
    track = result.cameras[cam.name]
    out = np.zeros(cam.num_frames, dtype=int)
    out[np.searchsorted(cam.timestamps, track.timestamps)] = track.swaps
    return out


@pytest.fixture(scope="module")
def clean():
    return static_rig("none")


@pytest.fixture(scope="module")
def runs(clean):
    swapped, truth = with_swaps(clean)
    started = time.perf_counter()
    plain = run_uncalibrated_baseline(clean)
    seconds = time.perf_counter() - started
    return {
        "clean": plain, "seconds": seconds, "truth": truth, "capture": swapped,
        "swapped": run_uncalibrated_baseline(swapped),
        "unchecked": run_uncalibrated_baseline(swapped, UncalibratedOptions(swap_check=False)),
    }  # fmt: skip


def test_cameras_recovered(runs, clean):
    position, rotation, _ = camera_errors(runs["clean"], clean)
    assert position.max() < 0.02 and rotation.max() < 0.4, (position, rotation)
    assert runs["clean"].world_frame == "ground_plane" and runs["clean"].pipeline == "baseline"
    for name in ("cam1", "cam2", "cam3", "cam4"):
        track = runs["clean"].cameras[name]
        np.testing.assert_allclose(track.world_T_camera, track.world_T_camera[:1].repeat(len(track.timestamps), axis=0))  # static
        assert np.all(track.swaps == 0)  # no swap simulated, none found
    assert runs["seconds"] < 30.0  # seconds, not minutes (measured 1.5–3 s on 2 busy cores)


def test_reprojection_is_the_detectors_noise(runs, clean):
    """Per camera, the reprojection median lies between 40 % and 100 % of the median distance
    between the detections and the true keypoints' projections: free points absorb part of the
    noise (with 4 views, about sqrt(5/8) of it), never add to it."""
    body = load_body_model()
    gt = clean.ground_truth
    medians = runs["clean"].parameters["reprojection_median_px"]
    for cam in clean.cameras:
        det = next(iter(cam.detectors.values()))
        idx = np.searchsorted(gt.timestamps, cam.timestamps)
        truth = body.forward(gt.shape, gt.root[idx], gt.pose[idx], keypoints=det.format).keypoints
        pixels, _ = project_points(truth, gt.cameras[cam.name][0], cam.K, cam.distortion)
        used = det.keypoints[..., 2] >= UncalibratedOptions().min_confidence
        noise = float(np.nanmedian(np.linalg.norm(det.keypoints[..., :2] - pixels, axis=-1)[used]))
        assert 0.4 * noise < medians[cam.name] < noise, (cam.name, medians[cam.name], noise)


def test_sustained_swaps_found_and_undone(runs, clean):
    found = found_swaps(runs["swapped"], runs["capture"], 2) > 0
    truth = runs["truth"]
    seen = np.zeros_like(truth)
    seen[np.searchsorted(clean.cameras[2].timestamps, runs["swapped"].cameras["cam3"].timestamps)] = True
    tp = np.sum(found & truth)
    assert tp / found.sum() >= 0.95 and tp / np.sum(truth & seen) >= 0.95
    assert np.all(found_swaps(runs["swapped"], runs["capture"], 2)[found] == SWAP_KINDS.index("body"))
    for c in (0, 1, 3):
        assert not found_swaps(runs["swapped"], runs["capture"], c).any()
    p = runs["swapped"].parameters
    assert p["relabelled_counts"]["cam3"] == found.sum() and sorted(p["relabelled_frames"]["cam3"]["body"]) == list(np.flatnonzero(found))
    assert f"camera cam3: left/right labels undone in {found.sum()} of" in " ".join(p["notes"])
    # The cameras as without the swaps; without the check, clearly worse.
    clean_pos, clean_rot, _ = camera_errors(runs["clean"], clean)
    pos, rot, _ = camera_errors(runs["swapped"], clean)
    assert pos.mean() < 1.2 * clean_pos.mean() + 0.002 and rot.mean() < 1.2 * clean_rot.mean() + 0.02
    bad_pos, bad_rot, _ = camera_errors(runs["unchecked"], clean)
    assert bad_pos.mean() > 1.5 * pos.mean() and bad_pos.max() > 2 * pos.max()
    assert runs["unchecked"].parameters["reprojection_median_px"]["cam3"] > 1.3 * runs["swapped"].parameters["reprojection_median_px"]["cam3"]
    assert "swap check off: left/right labels as detected" in runs["unchecked"].parameters["notes"]


def test_the_simulators_own_swaps_are_found():
    """Realistic detector faults (sustained, view-dependent whole-body and limb swaps): every
    camera's relabelled frames against the simulator's record."""
    capture = static_rig("realistic")
    result = run_uncalibrated_baseline(capture)
    tp = fp = fn = 0
    for c, cam in enumerate(capture.cameras):
        truth = capture.ground_truth.swaps[cam.name][next(iter(cam.detectors))]
        found = found_swaps(result, capture, c)
        seen = np.zeros(cam.num_frames, dtype=bool)
        seen[np.searchsorted(cam.timestamps, result.cameras[cam.name].timestamps)] = True
        tp += np.sum((found == truth) & (truth > 0))
        fp += np.sum((found > 0) & (found != truth))
        fn += np.sum((found != truth) & (truth > 0) & seen)
    assert tp >= 20  # the capture has swaps to find
    assert tp / (tp + fp) >= 0.95 and tp / (tp + fn) >= 0.95, (tp, fp, fn)


def test_metric_ground_frame(runs, clean):
    """Z up and the ground at z = 0 within a few degrees and centimetres of the truth's, and the
    scale as the body's eye-to-ankle extent at rest says (the person is not 1.75 m tall)."""
    _, _, fit = camera_errors(runs["clean"], clean)
    up = fit.R @ np.array([0.0, 0.0, 1.0])
    assert np.degrees(np.arccos(up[2])) < 3.0
    assert abs(fit.apply(np.zeros(3))[2]) < 0.05  # the result's origin lies on the true ground
    body = load_body_model()
    rest = body.forward(clean.ground_truth.shape, np.eye(4)[None], np.zeros((1, 21, 3)), keypoints="coco17").keypoints[0]
    names = get_format("coco17").names
    extent = rest[names.index("left_eye"), 1] - rest[names.index("left_ankle"), 1]  # body frame: +Y up
    expected = extent / ((EYE_HEIGHT_FRACTION - ANKLE_HEIGHT_FRACTION) * UncalibratedOptions().height_m)
    assert abs(fit.scale / expected - 1.0) < 0.03, (fit.scale, expected)
    joints = runs["clean"].joints
    assert np.isfinite(joints[:, [1, 2, 4, 5, 7, 8, 16, 17, 18, 19, 20, 21]]).mean() > 0.95  # hips … wrists
    assert np.isnan(joints[:, 0]).all()  # the pelvis is not a keypoint of the format


def test_same_input_same_result(runs, clean):
    again = run_uncalibrated_baseline(clean)
    for name, track in runs["clean"].cameras.items():
        np.testing.assert_array_equal(again.cameras[name].world_T_camera, track.world_T_camera)


def test_routed_from_the_baseline_options(clean, runs):
    result = run_baseline(clean, BaselineOptions(uncalibrated=True))
    np.testing.assert_allclose(result.cameras["cam2"].world_T_camera, runs["clean"].cameras["cam2"].world_T_camera)
    assert result.parameters["uncalibrated"] is True and result.parameters["height_m"] == 1.75


def test_command_line_run_and_eval(tmp_path, capsys, runs):
    cap, res = tmp_path / "cap", tmp_path / "res"
    write_capture(runs["capture"], cap)
    assert main(["run", "baseline", "--uncalibrated", str(cap), "--out", str(res), "--height-m", "1.6"]) == 0
    out = capsys.readouterr().out
    assert "baseline --uncalibrated: 151 frames from 4 cameras (coco_hrnet, coco17)" in out
    assert "reprojection median" in out and "per camera: cam1" in out
    assert "note: camera cam3: left/right labels undone in" in out and "standing height of 1.6 m" in out
    result = load_result(res)
    assert result.parameters["height_m"] == 1.6 and result.cameras["cam3"].swaps.sum() > 0
    assert main(["eval", str(res), "--json"]) == 0
    metrics = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert metrics["alignment"].startswith("similarity")
    assert metrics["static_mcpe_m"] < 0.05 and metrics["static_mcoe_rad"] < 0.015


def test_clear_errors(clean):
    with pytest.raises(MocapgraphError, match="cameras handheld move"):
        run_uncalibrated_baseline(synthesize("rich", seed=0, duration_s=1.0, detector_faults="none"))
    with pytest.raises(MocapgraphError, match="needs at least 2 cameras"):
        run_uncalibrated_baseline(replace(clean, cameras=clean.cameras[:1]))
    blind = deepcopy(clean)
    next(iter(blind.cameras[1].detectors.values())).keypoints[:] = np.nan
    with pytest.raises(MocapgraphError, match="cameras cam2 have no keypoint of detector 'coco_hrnet'"):
        run_uncalibrated_baseline(blind)
    with pytest.raises(MocapgraphError, match="has no detector 'openpose'"):
        run_uncalibrated_baseline(clean, detector="openpose")
    with pytest.raises(MocapgraphError, match="height_m: must be a positive number"):
        run_uncalibrated_baseline(clean, UncalibratedOptions(height_m=-1.0))
    with pytest.raises(MocapgraphError, match="threshold_px"):
        run_uncalibrated_baseline(clean, threshold_px=0.0)
