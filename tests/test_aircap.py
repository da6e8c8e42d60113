"""The AirCap pipeline end to end on small synthetic captures, against ground truth."""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np
import pytest

from mocapgraph.cli.main import main
from mocapgraph.data_tools.evaluation.evaluate import evaluate
from mocapgraph.data_tools.io.capture import load_capture, write_capture
from mocapgraph.data_tools.io.result import load_result
from mocapgraph.data_tools.sim.synthetic import synthesize
from mocapgraph.pipelines.aircap import AircapOptions, run_aircap


@pytest.fixture(scope="module")
def capture():
    # 5 s rather than 3 s: over 3 s of seed 0 the body's height and size trade off against its
    # depth below the UAVs (the sequence fit floated 0.57 m up with a 10 % smaller body, inside
    # the GPS uncertainty), so absolute MPJPE compared GPS realisations rather than the fits.
    return synthesize("aircap", seed=0, duration_s=5.0)


def options(**kw) -> AircapOptions:
    """AircapOptions with ``pose_prior`` routed to the graph options."""
    graph = replace(AircapOptions().graph, pose_prior=kw.pop("pose_prior", "none"))
    return AircapOptions(graph=graph, **kw)


def run(capture, **kw):
    result = run_aircap(capture, options(covariances=kw.pop("covariances", False), **kw))
    return result, evaluate(result, capture).metrics


@pytest.fixture(scope="module")
def faultless():
    """The capture without the detector's systematic faults: the lens comparisons below are
    millimetres, which the faults' own effect would blur."""
    return synthesize("aircap", seed=0, duration_s=5.0, detector_faults="none")


@pytest.fixture(scope="module")
def variants(capture):
    return {
        "sequence": run(capture, mode="sequence", cameras="refine", covariances=True),
        "per_frame": run(capture, mode="per-frame", cameras="refine"),
        "cameras_at_gps": run(capture, mode="sequence", cameras="prior"),
    }


def test_sequence_beats_per_frame_and_gps_cameras(variants):
    seq, per_frame, gps = (variants[k][1] for k in ("sequence", "per_frame", "cameras_at_gps"))
    assert seq["mpjpe_m"] < per_frame["mpjpe_m"]
    assert seq["mpjpe_m"] < gps["mpjpe_m"]
    assert seq["ra_mpjpe_m"] < per_frame["ra_mpjpe_m"] and seq["ra_mpjpe_m"] < 0.08
    assert seq["pa_mpjpe_m"] < 0.05


def test_refined_cameras_improve_on_their_priors(variants):
    assert variants["sequence"][1]["mcpe_m"] < variants["cameras_at_gps"][1]["mcpe_m"]


def test_result_carries_uncertainty_and_flags(variants, capture):
    result, _ = variants["sequence"]
    cov = result.covariances["joints"]
    assert cov.shape == (len(result.timestamps), 22, 3, 3) and np.isfinite(cov).all()
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    assert result.flags["num_detections"].sum() > 0 and not result.flags["unconstrained"].all()
    assert {"uav1", "uav2", "uav3"} == set(result.cameras)
    assert result.log and all("cost_after" in row for row in result.log)


@pytest.mark.slow  # 6 s: a whole AirCap sequence run for its flags
def test_person_out_of_every_view_for_a_while(capture):
    """Detections removed from all cameras for 0.8 s: finite estimates, those states flagged."""
    gap = (1.0, 1.8)
    cams = []
    for cam in capture.cameras:
        hide = (cam.timestamps > gap[0]) & (cam.timestamps < gap[1])
        dets = {}
        for name, det in cam.detectors.items():
            kp = det.keypoints.copy()
            kp[hide] = np.nan
            boxes = None if det.boxes is None else np.where(hide[:, None], np.nan, det.boxes)
            dets[name] = replace(det, keypoints=kp, boxes=boxes)
        cams.append(replace(cam, detectors=dets))
    result, metrics = run(replace(capture, cameras=cams), mode="sequence", cameras="refine")
    inside = (result.timestamps > gap[0] + 0.05) & (result.timestamps < gap[1] - 0.05)
    assert result.flags["unconstrained"][inside].all()
    flagged = int(result.flags["unconstrained"].sum())
    assert f"{flagged} of {len(result.timestamps)} body states have no detection near them" in " ".join(result.parameters["notes"])
    assert np.isfinite(result.joints).all() and np.isfinite(result.root).all()
    assert metrics["ra_mpjpe_m"] < 0.15


@pytest.mark.slow  # 7 s: two per-frame passes; test_executors covers the fork executor
def test_per_frame_pass_in_two_processes_matches_one(faultless):
    """The spans solved in forked workers give the serial answer: exactly on the first span
    (same warm starts), and to within a few millimetres after the second span's cold start."""
    serial, _ = run(faultless, mode="per-frame", workers=1)
    forked, _ = run(faultless, mode="per-frame", workers=2)
    np.testing.assert_array_equal(serial.timestamps, forked.timestamps)
    half = len(serial.timestamps) // 2
    np.testing.assert_allclose(forked.joints[:half], serial.joints[:half], rtol=0, atol=1e-9)
    assert np.median(np.linalg.norm(forked.joints - serial.joints, axis=-1)) < 0.005
    for name, track in serial.cameras.items():
        np.testing.assert_allclose(forked.cameras[name].world_T_camera, track.world_T_camera, atol=0.05)


def test_camera_without_detections_or_gps_is_reported_not_fatal(capture, caplog):
    caplog.set_level(logging.INFO, logger="mocapgraph")
    cams = list(capture.cameras)
    cams[0] = replace(cams[0], detectors={})
    cams[1] = replace(cams[1], sensors={k: v for k, v in cams[1].sensors.items() if k != "gps"})
    result = run_aircap(replace(capture, cameras=cams), options(mode="per-frame", cameras="refine", covariances=False))
    assert "camera uav2: no GPS/IMU" in caplog.text  # the UAV without GPS is named
    assert "camera uav1: no usable detections" in caplog.text  # and the camera that saw nothing
    assert np.isfinite(result.joints).all()


@pytest.mark.slow  # 9 s: a whole AirCap run; the repair itself is tested in test_capture
def test_camera_clock_going_backwards_is_repaired_and_reported(capture, tmp_path, caplog):
    """uav2's clock jumps back 0.3 s at frame 40: the loader drops the frames not later than an
    earlier one, the run says so (stderr and the result's notes) and still fits the body."""
    path = write_capture(capture, tmp_path / "cap")
    stamps_file = path / "cameras" / "uav2" / "timestamps.npy"
    stamps = np.load(stamps_file)
    stamps[40:] -= 0.3
    np.save(stamps_file, stamps)
    loaded = load_capture(path)
    kept = loaded.camera("uav2").num_frames
    assert kept < len(stamps) and np.all(np.diff(loaded.camera("uav2").timestamps) > 0)
    caplog.set_level(logging.INFO, logger="mocapgraph")
    result = run_aircap(loaded, options(mode="sequence", covariances=False))
    assert "uav2" in caplog.text and "backwards" in caplog.text
    assert any("uav2" in n and "backwards" in n for n in result.parameters["notes"])
    assert np.isfinite(result.joints).all() and np.isfinite(result.root).all()
    assert len(result.cameras["uav2"].timestamps) == kept
    assert evaluate(result, loaded).metrics["ra_mpjpe_m"] < 0.1


def test_command_line_writes_a_result(tmp_path, capsys):
    cap = tmp_path / "cap"
    assert main(["synth", "aircap", "--out", str(cap), "--duration", "1.5", "--seed", "4"]) == 0
    assert main(["run", "aircap", str(cap), "--out", str(tmp_path / "res"), "--mode", "per-frame", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "aircap (per-frame, cameras refine)" in out
    result = load_result(tmp_path / "res")
    assert result.pipeline == "aircap" and result.has_body_parameters
    assert "joints" in result.covariances


@pytest.mark.slow  # 30 s: three sequence fits with the networks; the priors' factors have their own fast tests
def test_learned_priors_run_on_the_sequence_fit(capture):
    for priors in ({"pose_prior": "gmm"}, {"pose_prior": "vae", "motion_prior": "vae"}):
        result, metrics = run(capture, **priors)
        assert metrics["ra_mpjpe_m"] < 0.08 and metrics["pa_mpjpe_m"] < 0.05, priors
        assert result.parameters["graph"]["pose_prior"] == priors["pose_prior"]


def test_learned_prior_options_that_cannot_work_are_clear_errors():
    from mocapgraph.errors import MocapgraphError

    with pytest.raises(MocapgraphError, match="pose_prior 'vae' runs on the sequence fit"):
        options(mode="per-frame", pose_prior="vae").check()
    with pytest.raises(MocapgraphError, match="25 states at 30 Hz"):
        AircapOptions(motion_prior="vae", grid_hz=20.0).check()
    with pytest.raises(MocapgraphError, match="motion_prior 'lstm'"):
        AircapOptions(motion_prior="lstm").check()


def test_motion_prior_on_a_capture_shorter_than_a_window_is_a_note():
    short = synthesize("aircap", seed=0, duration_s=0.6)
    result, _ = run(short, motion_prior="vae", workers=1)
    assert any("fewer than one window" in note for note in result.parameters["notes"])


def relensed(capture, distortion):
    """The same detections seen through another lens: keypoints and box centres undistorted
    through each camera's own lens into the ideal pinhole image, then distorted through
    ``distortion`` by the OpenCV model (box sizes kept)."""
    from mocapgraph.data_tools.geometry.camera_model import project_points, undistort_pixels

    def through(cam, pixels):
        ideal = undistort_pixels(pixels, cam.K, cam.distortion)
        rays = np.concatenate([ideal, np.ones(ideal.shape[:-1] + (1,))], axis=-1) @ np.linalg.inv(cam.K).T
        return project_points(rays, np.eye(4), cam.K, distortion)[0]

    cams = []
    for cam in capture.cameras:
        dets = {}
        for name, det in cam.detectors.items():
            kp = det.keypoints.copy()
            kp[..., :2] = through(cam, kp[..., :2])
            boxes = det.boxes
            if boxes is not None:
                boxes = boxes.copy()
                centre = through(cam, 0.5 * (boxes[:, :2] + boxes[:, 2:4]))
                half = 0.5 * (boxes[:, 2:4] - boxes[:, :2])
                boxes[:, :2], boxes[:, 2:4] = centre - half, centre + half
            dets[name] = replace(det, keypoints=kp, boxes=boxes)
        cams.append(replace(cam, detectors=dets, distortion=np.asarray(distortion, dtype=float)))
    return replace(capture, cameras=cams)


STRONG_LENS = np.array([-0.3, 0.08, 1e-3, -1e-3, 0.0])
"""Barrel distortion moving keypoints by a median 7 px and up to 70 px at the image's edges."""


def test_keypoints_are_undistorted_once_into_the_ideal_image(faultless):
    """Through a strongly distorted lens the state model holds the observations of the ideal
    pinhole, to the undistortion's precision."""
    from mocapgraph.pipelines.observations import capture_state_model

    ideal, strong = relensed(faultless, np.zeros(5)), relensed(faultless, STRONG_LENS)
    shift = np.concatenate([
        np.linalg.norm(s.detectors[n].keypoints[..., :2] - i.detectors[n].keypoints[..., :2], axis=-1).ravel()
        for s, i in zip(strong.cameras, ideal.cameras) for n in s.detectors
    ])  # fmt: skip
    assert np.nanmedian(shift) > 5.0 and np.nanmax(shift) > 50.0  # the lens matters
    a, b = capture_state_model(ideal, "grid"), capture_state_model(strong, "grid")
    pairs = [(oa, ob) for sa, sb in zip(a.states, b.states) for oa, ob in zip(sa, sb, strict=True)]
    assert len(pairs) > 500  # every detected frame of 3 UAVs and 2 detectors over 5 s
    for oa, ob in pairs:
        assert (oa.camera, oa.frame, oa.fmt) == (ob.camera, ob.frame, ob.fmt)
        np.testing.assert_array_equal(oa.weights, ob.weights)
        np.testing.assert_allclose(ob.observed, oa.observed, rtol=0, atol=1e-6)  # pixels


@pytest.mark.slow  # 30 s, three AirCap runs; the undistortion itself is checked exactly above
def test_distorted_lenses_fit_as_well_as_ideal_ones(faultless):
    """AirCap through the strong lens is as accurate as through the ideal one; ignoring the lens
    (as AirCap did before the one keypoint road) is worse. The two fits are not identical: the
    tracker reads box sizes in the distorted image, so its gates and starts differ a little."""
    ideal, strong = relensed(faultless, np.zeros(5)), relensed(faultless, STRONG_LENS)
    ignored = replace(strong, cameras=[replace(cam, distortion=np.zeros(5)) for cam in strong.cameras])
    (_, mi), (_, ms), (_, mx) = (run(c, workers=1) for c in (ideal, strong, ignored))
    for key, slack in (("ra_mpjpe_m", 0.005), ("pa_mpjpe_m", 0.003)):
        assert ms[key] < mi[key] + slack, key
        assert mx[key] > ms[key] + slack, key
