"""Held-out reprojection (:mod:`mocapgraph.benchmarks.heldout`, ``bench real``'s hidden
camera-frames): the split, the truth's own keypoints predicting hidden detections at the
simulator's noise level, and hidden camera-frames reaching no step of a run."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from mocapgraph.benchmarks.heldout import SPLITS, heldout_split, run_heldout, split_run_frames
from mocapgraph.body import load_body_model
from mocapgraph.data_tools.io.calibration import CameraCalibration
from mocapgraph.data_tools.io.result import CameraTrack, Result
from mocapgraph.data_tools.sim.detectors import DETECTOR_PRESETS, simulate_detections
from mocapgraph.data_tools.sim.synthetic import synthesize
from mocapgraph.data_tools.tracking.people import PersonTracks
from mocapgraph.data_tools.tracking.track_files import TrackSet
from mocapgraph.errors import MocapgraphError
from mocapgraph.pipelines.smartmocap import SmartmocapOptions, run_smartmocap
from mocapgraph.pipelines.uncalibrated_baseline import run_uncalibrated_baseline

SIGMA_PX = 2.0
"""The simulated detector's noise, per axis (Gaussian, the same for every point and frame)."""
RAYLEIGH_MEDIAN = math.sqrt(2 * math.log(2))
"""The median of the length of a 2D Gaussian error of σ 1 per axis (Rayleigh distribution)."""
RAYLEIGH_MEDIAN_DENSITY = RAYLEIGH_MEDIAN * math.exp(-(RAYLEIGH_MEDIAN**2) / 2)
"""The Rayleigh density (σ 1) at its median: r exp(-r²/2) = √(2 ln 2) / 2."""


def test_the_split_hides_every_camera_alike_and_one_camera_per_frame():
    cameras = ["a", "b", "c", "d"]
    for run_frames in (1, 5, 15):
        held = heldout_split(cameras, 100, 0.15, seed=3, run_frames=run_frames)
        assert {c: int(m.sum()) for c, m in held.items()} == dict.fromkeys(cameras, 15)
        assert np.stack(list(held.values())).sum(axis=0).max() == 1  # no frame loses two cameras
        for m in held.values():  # runs of the length asked
            edges = np.diff(np.concatenate([[0], m.astype(int), [0]]))
            lengths = np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)
            assert sorted(set(lengths.tolist())) == [run_frames] or run_frames == 1, lengths
        again = heldout_split(cameras, 100, 0.15, seed=3, run_frames=run_frames)
        assert all(np.array_equal(held[c], again[c]) for c in cameras)  # deterministic for a seed
    single = heldout_split(cameras, 100, 0.15, seed=3)
    # spread over the clip: every quarter of it hides some camera-frames of single frames
    assert all(np.stack(list(single.values()))[:, q * 25 : (q + 1) * 25].any() for q in range(4))
    assert not all(np.array_equal(single[c], heldout_split(cameras, 100, 0.15, seed=4)[c]) for c in cameras)
    assert split_run_frames("frames", 100) == 1 and split_run_frames("runs", 100, 0.15) == 15 and SPLITS == ("frames", "runs")
    with pytest.raises(MocapgraphError, match="share"):
        heldout_split(cameras, 100, 0.3)  # four cameras: at most a quarter, or a frame loses two
    with pytest.raises(MocapgraphError, match="at least 3 cameras"):
        heldout_split(cameras[:2], 100, 0.15)
    with pytest.raises(MocapgraphError, match="split"):
        split_run_frames("blocks", 100)


@pytest.fixture(scope="module")
def rig():
    """Four static cameras of a 2 s ``rich`` capture (30 fps, 61 frames), their detections made
    again by a detector whose only error is Gaussian noise of :data:`SIGMA_PX` per axis
    (confidence 1, nothing missed, swapped or offset), as one person track per camera; the
    truth's keypoints and cameras as a result on the frames' times."""
    capture = synthesize("rich", seed=0, duration_s=2.0, detector_faults="none")
    cams = [c for c in capture.cameras if not c.moving][:4]
    gt, body = capture.ground_truth, load_body_model()
    detector = next(iter(cams[0].detectors.values()))
    model = replace(DETECTOR_PRESETS[detector.name].without_effects(), noise_floor_px=SIGMA_PX, difficulty={})
    tracks, calibration = {}, []
    times = cams[0].timestamps
    idx = np.searchsorted(gt.timestamps, times)
    truth = body.forward(gt.shape, gt.root[idx], gt.pose[idx], keypoints=detector.format).keypoints
    for c, cam in enumerate(cams):
        assert np.allclose(cam.timestamps, times)  # one time line: the track file keeps frame numbers only
        det = simulate_detections(body, gt.shape, gt.root[idx], gt.pose[idx], gt.cameras[cam.name], cam.K, cam.distortion, cam.image_size, model, c, timestamps=times)
        tracks[cam.name] = PersonTracks(det.keypoints[None])
        calibration.append(CameraCalibration(cam.name, cam.K, cam.distortion, cam.image_size))
    names = [c.name for c in cams]
    track_set = TrackSet(names, tracks, {c.name: c.image_size for c in cams}, {c.name: c.frame_rate for c in cams}, detector.format)
    frame_times = np.arange(len(times)) / cams[0].frame_rate  # the times a capture written from tracks has
    result = Result(
        pipeline="truth", capture="", world_frame="capture", timestamps=frame_times, joints=np.zeros((len(times), 22, 3)),
        keypoints=truth, keypoint_format=detector.format,
        cameras={c.name: CameraTrack(frame_times, np.repeat(gt.cameras[c.name][:1], len(times), axis=0)) for c in cams},
    )  # fmt: skip
    return {"tracks": track_set, "calibration": calibration, "truth": result}


@pytest.mark.parametrize("split", SPLITS)
def test_the_truth_predicts_hidden_detections_at_the_noise_level(rig, tmp_path, split):
    """The truth's own keypoints through the true cameras predict each hidden detection up to the
    detector's noise alone: the distance is Rayleigh with σ :data:`SIGMA_PX`, its median
    √(2 ln 2) σ. The sample median of ``n`` independent distances has the standard deviation
    1 / (2 f(m) √n), ``f(m)`` the density at the median, i.e. 0.849 σ / √n: the bound is five of
    them (about 0.2 px for the 36 hidden views' ~600 detections). A hidden view matched to the
    wrong frame (the person moves ~4 cm, ~20 px, per frame) or projected through the wrong
    camera, intrinsics or distortion is pixels off."""
    tracks = rig["tracks"]
    run_frames = split_run_frames(split, tracks.tracks["cam1"].num_frames)
    report = run_heldout(tracks, rig["calibration"], tmp_path / "capture", {"truth": lambda capture: rig["truth"]}, run_frames=run_frames)
    truth = report["truth"]
    assert report["views"] == 4 * round(0.15 * 61) and report["hidden_per_camera"] == dict.fromkeys(tracks.cameras, round(0.15 * 61))
    assert truth["unpredicted"] == 0 and report["common"] == report["detections"] > 500
    expected = RAYLEIGH_MEDIAN * SIGMA_PX
    tolerance = 5 * SIGMA_PX / (2 * RAYLEIGH_MEDIAN_DENSITY * math.sqrt(report["detections"]))
    assert abs(truth["heldout_px"] - expected) < tolerance, (truth["heldout_px"], expected, tolerance)
    assert truth["heldout_px_as_detected"] == truth["heldout_px"]  # nothing swapped, no labelling fits better
    # the kept views too (about 5.6 times as many detections: the same bound is wider than it needs)
    assert abs(truth["in_sample_px"] - expected) < tolerance, (truth["in_sample_px"], expected)


def _run_twice(rig, tmp_path, runner, run_frames: int = 1) -> tuple[dict, dict, list]:
    """:func:`run_heldout` on the rig's tracks and on a copy whose hidden camera-frames are
    replaced by nonsense (points anywhere in the image, any confidence); the two reports and the
    two results."""
    tracks = rig["tracks"]
    T = tracks.tracks["cam1"].num_frames
    held = heldout_split(tracks.cameras, T, run_frames=run_frames)
    rng = np.random.default_rng(7)
    wild = {}
    for c in tracks.cameras:
        keypoints = tracks.tracks[c].keypoints.copy()
        hidden = keypoints[:, held[c]]
        hidden[..., 0] = rng.uniform(0, 1920, hidden.shape[:-1])
        hidden[..., 1] = rng.uniform(0, 1080, hidden.shape[:-1])
        hidden[..., 2] = rng.uniform(0.3, 1.0, hidden.shape[:-1])
        keypoints[:, held[c]] = hidden
        wild[c] = PersonTracks(keypoints)
    results = []

    def run(capture):
        results.append(runner(capture))
        return results[-1]

    calibration = rig["calibration"]
    plain = run_heldout(tracks, calibration, tmp_path / "plain", {"method": run}, run_frames=run_frames)
    perturbed = run_heldout(replace(tracks, tracks=wild), calibration, tmp_path / "wild", {"method": run}, run_frames=run_frames)
    return plain, perturbed, results


def _assert_same(a: Result, b: Result) -> None:
    np.testing.assert_array_equal(a.keypoints, b.keypoints)
    assert a.cameras.keys() == b.cameras.keys()
    for name in a.cameras:
        np.testing.assert_array_equal(a.cameras[name].world_T_camera, b.cameras[name].world_T_camera)
        np.testing.assert_array_equal(a.cameras[name].timestamps, b.cameras[name].timestamps)


def test_hidden_camera_frames_reach_no_step_of_the_baseline(rig, tmp_path):
    """Nonsense in the hidden camera-frames leaves the baseline's result the same to the bit,
    while the held-out measure sees it (the hidden detections are read after the run); the same
    nonsense in camera-frames that are not hidden changes the result (the check can fail)."""
    plain, perturbed, (a, b) = _run_twice(rig, tmp_path, run_uncalibrated_baseline)
    _assert_same(a, b)
    assert plain["method"]["in_sample_px"] == perturbed["method"]["in_sample_px"]
    assert perturbed["method"]["heldout_px"] > 20 * plain["method"]["heldout_px"]
    tracks = rig["tracks"]
    shifted = {c: PersonTracks(t.keypoints.copy()) for c, t in tracks.tracks.items()}
    shifted["cam2"].keypoints[0, 1, :, :2] += 300.0  # frame 1 of cam2 is not hidden at seed 0
    assert not heldout_split(tracks.cameras, 61)["cam2"][1]
    control = []
    run_heldout(replace(tracks, tracks=shifted), rig["calibration"], tmp_path / "control", {"method": lambda c: control.append(run_uncalibrated_baseline(c)) or control[-1]})
    assert not np.array_equal(np.nan_to_num(control[0].keypoints), np.nan_to_num(a.keypoints))


@pytest.mark.slow
def test_hidden_camera_frames_reach_no_step_of_smartmocap(rig, tmp_path):
    """SmartMocap (swaps, offsets, drift, the free-point adjustment of the static cameras: every
    step but the motion prior) gives the same result to the bit with nonsense in its hidden
    camera-frames; the held-out measure sees the nonsense."""
    options = SmartmocapOptions(motion_prior="none", covariances=False, workers=1)
    plain, perturbed, (a, b) = _run_twice(rig, tmp_path, lambda capture: run_smartmocap(capture, options), run_frames=split_run_frames("runs", 61))
    _assert_same(a, b)
    assert perturbed["method"]["heldout_px"] > 20 * plain["method"]["heldout_px"]
