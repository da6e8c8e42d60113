"""Synthetic captures end to end: every preset writes a valid capture whose ground truth explains
its detections, the same seed gives the same capture, and the baseline scores on it."""

from __future__ import annotations

import numpy as np
import pytest

from mocapgraph.body import load_body_model
from mocapgraph.cli.main import main
from mocapgraph.data_tools.geometry.camera_model import project_points
from mocapgraph.data_tools.io.capture import load_capture, write_capture
from mocapgraph.data_tools.sim.synthetic import PRESET_DETECTORS, synthesize
from mocapgraph.errors import MocapgraphError


@pytest.fixture(scope="module")
def captures():
    return {p: synthesize(p, seed=3, duration_s=2.0) for p in ("aircap", "airpose", "rich", "phones")}


@pytest.mark.parametrize("preset", ["aircap", "airpose", "rich", "phones"])
def test_ground_truth_explains_the_detections(captures, preset, tmp_path):
    capture = load_capture(write_capture(captures[preset], tmp_path / preset))
    gt = capture.ground_truth
    body = load_body_model()
    for cam in capture.cameras:
        idx = np.searchsorted(gt.timestamps, cam.timestamps)
        assert np.allclose(gt.timestamps[idx], cam.timestamps)  # truth at every frame time
        assert set(cam.detectors) == set(PRESET_DETECTORS[preset])
        for det in cam.detectors.values():
            truth = body.forward(gt.shape, gt.root[idx], gt.pose[idx], keypoints=det.format).keypoints
            pixels, _ = project_points(truth, gt.cameras[cam.name], cam.K, cam.distortion)
            err = np.linalg.norm(det.keypoints[..., :2] - pixels, axis=-1)
            seen = np.isfinite(err)
            assert seen.mean() > 0.3, (cam.name, det.name)
            # Most detections lie near the true projection; outliers and swaps are the rest.
            assert np.median(err[seen]) < 15.0, (cam.name, det.name, np.median(err[seen]))


def test_sensors_and_synchronisation_follow_the_presets(captures):
    air = captures["aircap"]
    assert all(cam.moving and set(cam.sensors) == {"gps", "imu", "baro", "self_pose"} for cam in air.cameras)
    stamps = [set(np.round(cam.timestamps, 9)) for cam in air.cameras]
    assert not (stamps[0] & stamps[1]) and not (stamps[1] & stamps[2])  # not synchronised
    rich = captures["rich"]
    assert sum(not cam.moving for cam in rich.cameras) == 7 and sum(cam.moving for cam in rich.cameras) == 1
    assert all(np.array_equal(cam.timestamps, rich.cameras[0].timestamps) for cam in rich.cameras)


def test_same_seed_same_capture_other_seed_other_capture():
    a, b, c = (synthesize("airpose", seed=s, duration_s=1.0) for s in (5, 5, 6))
    for x, y in zip(a.cameras, b.cameras):
        np.testing.assert_array_equal(x.detectors["openpose"].keypoints, y.detectors["openpose"].keypoints)
    np.testing.assert_array_equal(a.ground_truth.joints, b.ground_truth.joints)
    assert not np.allclose(a.ground_truth.joints, c.ground_truth.joints)


def test_noise_scale_multiplies_the_keypoint_noise():
    """The same seed draws the same standard-normal noise, so the detections' distance from the
    noise-free ones grows in proportion to the scale."""
    clean, base, heavy = (synthesize("rich", seed=2, duration_s=0.5, noise_scale=s) for s in (0.0, 1.0, 3.0))
    assert heavy.metadata["noise_scale"] == 3.0
    offsets = {}
    for name, capture in (("base", base), ("heavy", heavy)):
        d = [np.linalg.norm(c.detectors["coco_hrnet"].keypoints[..., :2] - r.detectors["coco_hrnet"].keypoints[..., :2], axis=-1)
             for c, r in zip(capture.cameras, clean.cameras)]  # fmt: skip
        d = np.concatenate([x.ravel() for x in d])
        offsets[name] = np.median(d[np.isfinite(d)])
    assert offsets["base"] > 0.5
    assert offsets["heavy"] / offsets["base"] == pytest.approx(3.0, rel=0.1)
    with pytest.raises(MocapgraphError, match="noise_scale"):
        synthesize("rich", noise_scale=-1.0)


def test_bad_requests_are_clear_errors():
    with pytest.raises(MocapgraphError, match="unknown scenario preset 'studio'"):
        synthesize("studio")
    with pytest.raises(MocapgraphError, match="unknown detector 'yolo'"):
        synthesize("rich", detectors=("yolo",))
    with pytest.raises(MocapgraphError, match="motion 'moonwalk': neither a procedural kind"):
        synthesize("rich", motion="moonwalk")


def test_synth_baseline_eval_from_the_command_line(tmp_path, capsys):
    """The calibrated baseline on a rich capture: centimetre-level keypoints, as triangulation gives."""
    cap, res = tmp_path / "cap", tmp_path / "res"
    assert main(["synth", "rich", "--out", str(cap), "--duration", "2", "--seed", "1"]) == 0
    assert main(["run", "baseline", str(cap), "--out", str(res)]) == 0
    out = capsys.readouterr().out
    assert "skipping uncalibrated cameras handheld" in out
    assert main(["eval", str(res), "--json"]) == 0
    import json

    metrics = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert metrics["pipeline"] == "baseline" and metrics["alignment"].startswith("none")
    assert 0.003 < metrics["mpjpe_keypoints_m"] < 0.03


def test_synth_detector_faults_flag(tmp_path, capsys):
    """``--detector-faults``: the capture records the level and the swaps it made; ``none`` makes none."""
    counts = {}
    for level in ("none", "heavy"):
        out = tmp_path / level
        assert main(["synth", "rich", "--out", str(out), "--duration", "2", "--seed", "4", "--detector-faults", level]) == 0
        printed = capsys.readouterr().out
        capture = load_capture(out)
        assert capture.metadata["detector_faults"] == level
        codes = np.concatenate([c for by_det in capture.ground_truth.swaps.values() for c in by_det.values()])
        assert len(codes) == sum(cam.num_frames for cam in capture.cameras)
        counts[level] = int(np.count_nonzero(codes))
        assert f"detector faults: {level}; left/right swapped in {counts[level]} of {len(codes)} camera-detector frames" in printed
    assert counts["none"] == 0 and counts["heavy"] > 0
    with pytest.raises(SystemExit):
        main(["synth", "rich", "--out", str(tmp_path / "x"), "--detector-faults", "wild"])
    with pytest.raises(MocapgraphError, match="unknown detector fault level 'wild'"):
        synthesize("rich", detector_faults="wild")
