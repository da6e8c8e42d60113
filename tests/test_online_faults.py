"""The online loop through what live streams do (issue 15's item 6), each against ground truth:
frames out of order, a camera that joins late, a camera silent for 5 s, a GPS outage on a UAV,
a body sliding out of one UAV's view, and a solver failure inside the loop."""

from __future__ import annotations

import numpy as np
import pytest
from test_online import OPTIONS, _feed, _state_error_m

from mocapgraph.data_tools.evaluation.alignment import umeyama
from mocapgraph.data_tools.evaluation.evaluate import evaluate
from mocapgraph.data_tools.sim.synthetic import synthesize
from mocapgraph.graphs.fixed_lag import FixedLagSmoother
from mocapgraph.pipelines.online import OnlineFusion, OnlineOptions, StreamFrame, static_rig, stream


@pytest.fixture(scope="module")
def rich():
    return synthesize("rich", seed=0, duration_s=3.0, detector_faults="none")


def _run(capture, frames, options=OPTIONS) -> OnlineFusion:
    fusion = OnlineFusion(static_rig(capture), options)
    _feed(fusion, frames)
    fusion.finish()
    return fusion


def _index(fusion, t: float) -> int:
    return int(round((t - fusion.t0) / fusion.period))


@pytest.mark.slow  # 6 s of CPU
def test_frames_out_of_order_used_within_the_lag_dropped_beyond(rich):
    """Frames jittered up to 0.15 s out of order (within the 0.5 s lag) are all used; a few
    delayed by 0.8 s are counted and dropped; the result is as accurate as in order."""
    rng = np.random.default_rng(2)
    frames = list(stream(rich))
    after = [j for j, f in enumerate(frames) if f.timestamp > 1.3 and f.timestamp < 2.0]
    delayed = set(rng.choice(after, 5, replace=False).tolist())
    arrival = np.array([f.timestamp + (0.8 if j in delayed else rng.uniform(0.0, 0.15) if f.timestamp > 1.1 else 0.0) for j, f in enumerate(frames)])
    fusion = _run(rich, [frames[j] for j in np.argsort(arrival, kind="stable")])
    assert fusion.stats.late_dropped == len(delayed)
    assert fusion.stats.late_used > 100
    _, smoothed = fusion.results()
    m = evaluate(smoothed, rich).metrics
    assert m["mpjpe_m"] < 0.06  # in order: 0.06 (test_online)
    for t in (1.5, 2.0, 2.5):
        assert _state_error_m(fusion, rich, _index(fusion, t)) < 0.06, t


@pytest.mark.slow  # 6 s of CPU
def test_camera_joining_after_the_bootstrap_is_placed(rich):
    """A static camera of the uncalibrated rig sends nothing until 1.6 s: after its first
    ``join_frames`` frames it is resected on the body and becomes a variable of the window from
    there (a prior at its resection), near its true pose: both where it was placed and at the end."""
    frames = [f for f in stream(rich) if not (f.camera == "cam3" and f.timestamp < 1.6)]
    fusion = _run(rich, frames)
    c = fusion.index["cam3"]
    assert c in fusion._static_keys and fusion.stats.unplaced == OPTIONS.join_frames - 1  # the last one is used
    # the camera's centre against the truth, through the similarity of the bootstrap's bodies onto it
    boot = sorted(i for i in fusion.filtered if i < fusion._bootstrap_states)
    gt = rich.ground_truth
    near = [int(np.argmin(np.abs(gt.timestamps - (fusion.t0 + i * fusion.period)))) for i in boot]
    joints = fusion.body.forward(fusion.shape, np.stack([fusion.filtered[i][0] for i in boot]), np.stack([fusion.filtered[i][1] for i in boot])).joints
    align = umeyama(joints.reshape(-1, 3), gt.joints[near].reshape(-1, 3), True)
    truth = np.asarray(rich.cameras[c].extrinsics).reshape(-1, 4, 4)[0, :3, 3]
    for pose in (next(iter(fusion._seed_cameras[c].values())), fusion.smoother.estimate.atPose3(fusion._static_keys[c]).matrix()):
        assert np.linalg.norm(align.apply(pose[None, :3, 3])[0] - truth) < 0.1
    for t in (2.0, 2.8):
        assert _state_error_m(fusion, rich, _index(fusion, t)) < 0.06, t


def test_solver_failure_restarts_the_window(rich, monkeypatch):
    """The smoother throws (as GTSAM does on an indeterminant system) at 2.0 s: the loop goes on,
    the states of that update are flagged ``solver_reset`` and keep the tracker's prediction, the
    window restarts from it, and 0.3 s later the body is within 6 cm of the truth again."""
    update = FixedLagSmoother.update
    failed = []

    def failing(self, factors, values, timestamps, keep=()):
        if not failed and self.newest > 2.0:
            failed.append(self.newest)
            raise RuntimeError("Indeterminant linear system detected while working near variable 7133701809754865664 (Symbol: r45).")
        return update(self, factors, values, timestamps, keep)

    monkeypatch.setattr(FixedLagSmoother, "update", failing)
    fusion = _run(rich, list(stream(rich)))
    assert failed and fusion.stats.solver_resets == 1
    _, smoothed = fusion.results()
    reset = smoothed.flags["solver_reset"]
    assert 1 <= reset.sum() <= 2 and np.all(np.abs(smoothed.timestamps[reset] - failed[0]) < 0.1)
    for t in (failed[0] + 0.3, 2.8):
        assert _state_error_m(fusion, rich, _index(fusion, t)) < 0.06, t
    assert evaluate(smoothed, rich).metrics["mpjpe_m"] < 0.07


@pytest.mark.slow  # 8 s stream
def test_cameras_silent_for_five_seconds_come_back():
    """The handheld camera and a static one stop for 5 s (10x the lag) and come back: the other
    cameras carry the body through it; the handheld one is placed again by resection on return."""
    capture = synthesize("rich", seed=0, duration_s=8.0, detector_faults="none")
    gap = (1.8, 6.8)
    frames = [f for f in stream(capture) if not (f.camera in ("handheld", "cam2") and gap[0] <= f.timestamp < gap[1])]
    fusion = _run(capture, frames)
    assert fusion.stats.late_dropped == 0 and fusion.stats.solver_resets == 0
    c = fusion.index["handheld"]
    times = np.array(sorted(fusion.smoothed_cameras[c]))
    assert not np.any((times > gap[0] + 0.05) & (times < gap[1] - 0.05)) and np.any(times > 7.0)
    for t in (4.0, 6.5, 7.2, 7.8):
        assert _state_error_m(fusion, capture, _index(fusion, t)) < 0.06, t
    _, smoothed = fusion.results()
    m = evaluate(smoothed, capture).metrics
    assert m["mpjpe_m"] < 0.05 and m["mcpe_m.handheld"] < 0.3


@pytest.mark.slow  # an AirCap bootstrap and a 5 s stream
def test_gps_outage_on_one_uav():
    """One UAV's onboard estimate stops for 2 s (a GPS/telemetry outage): its frames there are
    not used (flagged ``no_camera_prior`` per state), and the loop is back on the onboard
    estimate when it returns. The body is as accurate through the outage as
    without it (the other two UAVs keep their estimates)."""
    capture = synthesize("aircap", seed=0, duration_s=5.0)
    outage = (2.0, 4.0)
    frames = []
    for f in stream(capture):
        if f.camera == "uav1" and "self_pose" in f.sensors:
            pose = f.sensors["self_pose"]
            keep = (pose["t"] < outage[0]) | (pose["t"] >= outage[1])
            f = StreamFrame(f.camera, f.timestamp, f.keypoints, f.box, {**f.sensors, "self_pose": {k: v[keep] for k, v in pose.items()}}, f.detector)
        frames.append(f)
    options = OnlineOptions(lag_s=1.0)
    base = _run(capture, list(stream(capture)), options)
    fusion = _run(capture, frames, options)
    assert fusion.stats.solver_resets == 0 and fusion.stats.no_prior > 30 and base.stats.no_prior == 0
    _, smoothed = fusion.results()
    _, reference = base.results()
    flagged = smoothed.flags["no_camera_prior"]
    inside = (smoothed.timestamps > outage[0] + 0.3) & (smoothed.timestamps < outage[1] - 0.05)
    assert flagged[inside].all() and not flagged[smoothed.timestamps > outage[1] + 0.3].any()
    truth = capture.ground_truth

    def error(result, mask):
        near = [int(np.argmin(np.abs(truth.timestamps - t))) for t in result.timestamps[mask]]
        return float(np.linalg.norm(result.joints[mask] - truth.joints[near], axis=-1).mean())

    # measured 0.53 against 0.47 m during (0.52 / 0.52 before the AirCap rig's regulariser on the
    # joints the pose GMM leaves out; 0.95 / 0.47 with it while a camera alone in its update could
    # not relabel its whole body: uav2's detector flipped at 3.0-3.2 s with uav3 silent and the body,
    # held to that one flipped view, jumped 3.3 m and turned 75 deg; docs/online.md). After the
    # return 0.46 against 0.45 m; 1.30 against 0.40 m while a tie of two cameras (uav2 flipped at
    # 3.61-4.25 s, uav3 or the returning uav1 not) refused the relabelling: the body was lost at
    # 4.55-4.75 s (docs/online.md, "Ties in the vote"; the bound is back at 1.3x, 1.4x for that)
    during = (smoothed.timestamps > outage[0]) & (smoothed.timestamps < outage[1])
    assert error(smoothed, during) < 1.2 * error(reference, during)
    back = smoothed.timestamps > outage[1] + 0.3
    assert error(smoothed, back) < 1.3 * error(reference, back)


@pytest.mark.slow  # an AirCap bootstrap (two batch solves) and an 8 s stream
def test_body_sliding_out_of_one_uav_view_is_placed_again():
    """aircap seed 1 (the 10 s capture, streamed to 8.2 s): at 6.1 s uav2 and uav3 view the person
    from 12-32 deg apart, and a whole-body relabelling of uav1 (not in the truth) moved the body
    0.8 m along their rays, the direction only uav1 sees across; the tracker's prediction carried
    it on and uav1's detections were gated out, each run of rejections reset by the other UAVs'
    detections, so the body slid 2.7 m away by 7.1 s (smoothed, measured: 1.82 m over 6.2-8.2 s,
    1.67 m over 7.2-8.2 s). One camera's run of ``gate_reacquire`` rejections while the others
    pass now re-places the state where all its views triangulate the body (at 6.7 s; measured
    0.70 and 0.49 m; 0.21 m over 1-6 s either way)."""
    capture = synthesize("aircap", seed=1, duration_s=10.0)
    fusion = _run(capture, [f for f in stream(capture) if f.timestamp <= 8.2], OnlineOptions(lag_s=1.0))
    assert fusion.stats.camera_reacquired >= 1 and fusion.stats.solver_resets == 0
    _, smoothed = fusion.results()
    truth = capture.ground_truth

    def error(lo: float, hi: float) -> float:
        mask = (smoothed.timestamps >= lo) & (smoothed.timestamps < hi)
        near = np.abs(truth.timestamps[None] - smoothed.timestamps[mask][:, None]).argmin(1)
        return float(np.linalg.norm(smoothed.joints[mask] - truth.joints[near], axis=-1).mean())

    assert error(1.0, 6.0) < 0.3  # before the slide, as without the re-placing (0.20 m)
    assert error(6.2, 8.2) < 1.0
    assert error(7.2, 8.2) < 0.8
