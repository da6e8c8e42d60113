"""The state model every pipeline builds from, and the graph built on it, on small exact cases."""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np
import pytest

from mocapgraph.body import load_body_model
from mocapgraph.data_tools.geometry.camera_model import project_points
from mocapgraph.errors import MocapgraphError
from mocapgraph.factors.keys import camera_key, pose_key, root_key, shape_key
from mocapgraph.graphs.body_graph import BodyGraph, GraphOptions, LearnedPriors, motion_windows
from mocapgraph.graphs.state_model import CameraDetections, CameraInfo, Estimate, build_state_model

K = np.array([[900.0, 0.0, 640.0], [0.0, 900.0, 360.0], [0.0, 0.0, 1.0]])
LENS = np.array([-0.25, 0.05, 0.0, 0.0, 0.0])


def rig(times_static, times_moving):
    return [CameraInfo("static", K, False, np.asarray(times_static, float), 30.0), CameraInfo("moving", K, True, np.asarray(times_moving, float), 30.0)]


def detections(cameras, points, world_T_camera, distortion=None, fmt="coco17"):
    """Every camera frame's projections of ``points (F, 17, 3)`` through the lens, confidence 0.9."""
    out = []
    for c, cam in enumerate(cameras):
        px, _ = project_points(points[: len(cam.timestamps)], world_T_camera[c], K, distortion)
        kp = np.concatenate([px, np.full(px.shape[:-1] + (1,), 0.9)], axis=-1)
        out.append(CameraDetections(c, fmt, fmt, kp, distortion))
    return out


def scene(frames=6, seed=0):
    rng = np.random.default_rng(seed)
    points = rng.normal(scale=0.4, size=(frames, 17, 3)) + [0.0, 0.0, 5.0]
    cams = np.tile(np.eye(4), (2, 1, 1))
    return points, cams


def test_observations_are_undistorted_once_into_the_pinhole_image():
    points, cams = scene()
    cameras = rig(np.arange(6) / 30, np.arange(6) / 30)
    ideal = build_state_model(cameras, detections(cameras, points, cams), "closest")
    lensed = build_state_model(cameras, detections(cameras, points, cams, LENS), "closest")
    for a, b in zip(ideal.states, lensed.states):
        for oa, ob in zip(a, b, strict=True):
            np.testing.assert_allclose(ob.observed, oa.observed, rtol=0, atol=1e-6)
    raw = detections(cameras, points, cams, LENS)[0].keypoints[..., :2]
    assert np.abs(raw - np.stack([s[0].observed for s in ideal.states])).max() > 5.0  # the lens moved them


def test_grid_fractions_states_and_counts():
    """Camera 1 runs half a frame late: each of its frames lies halfway between two grid states."""
    points, cams = scene()
    cameras = rig(np.arange(6) / 30, (np.arange(6) + 0.5) / 30)
    model = build_state_model(cameras, detections(cameras, points, cams), "grid", rate_hz=30.0)
    assert model.num_states == 7
    np.testing.assert_array_equal(model.frame_state[1], np.arange(6))
    np.testing.assert_allclose(model.frame_fraction[1], 0.5)
    assert [o.fraction for o in model.states[0]] == [0.0, 0.5]
    assert model.frame_time(1, 2) == pytest.approx(2.5 / 30)
    # state 0: its own 2 x 17 points; state 6 only the 17 interpolated towards it from state 5
    np.testing.assert_array_equal(model.detections_per_state(), [34] + [51] * 5 + [17])


def test_select_and_span_drop_what_needs_a_missing_state():
    points, cams = scene()
    cameras = rig(np.arange(6) / 30, (np.arange(6) + 0.5) / 30)
    model = build_state_model(cameras, detections(cameras, points, cams), "grid", rate_hz=30.0)
    part = model.span(1, 4)
    np.testing.assert_array_equal(part.times, model.times[1:4])
    assert [len(s) for s in part.states] == [2, 2, 1]  # the last state's interpolated frame needs state 4
    np.testing.assert_array_equal(part.frame_state[1], [-1, 0, 1, -1, -1, -1])
    gap = model.select([0, 1, 3])
    assert [len(s) for s in gap.states] == [2, 1, 1]  # states 1 and 3 lose their frames towards states 2 and 4
    only = model.only([True, False])
    assert only.observed_cameras() == [0] and not (only.frame_state[1] >= 0).any()


def test_bad_detections_name_the_camera_and_detector():
    cameras = rig(np.arange(3) / 30, np.arange(3) / 30)
    with pytest.raises(MocapgraphError, match="camera 'moving': detector 'd': keypoints must be \\(3, K, 3\\)"):
        build_state_model(cameras, [CameraDetections(1, "d", "coco17", np.zeros((2, 17, 3)))])
    bad = np.ones((3, 17, 3))
    bad[0, 0, 2] = -1.0
    with pytest.raises(MocapgraphError, match="camera 'static': detector 'd': confidences must be >= 0"):
        build_state_model(cameras, [CameraDetections(0, "d", "coco17", bad)])


def test_frames_of_no_state_take_the_nearest_state():
    cameras = rig(np.arange(4) / 10, np.array([0.0, 0.04, 0.11, 0.29]))
    model = build_state_model(cameras, [], "closest")
    np.testing.assert_array_equal(model.frame_state[1], [0, -1, 1, 3])  # 0.04 is farther than 1/60 s from every state
    np.testing.assert_array_equal(model.frames_from_states(1, np.arange(4) * 10), [0, 0, 10, 30])


@pytest.fixture(scope="module")
def body():
    return load_body_model()


def body_graph(body, **kw):
    points, cams = scene(frames=6)
    cameras = rig(np.arange(6) / 30, np.arange(6) / 30)
    model = build_state_model(cameras, detections(cameras, points, cams), "closest")
    return BodyGraph(model, body, GraphOptions(pose_prior="none"), learned=LearnedPriors(), **kw)


def estimate_for(bg, body, seed=1):
    rng = np.random.default_rng(seed)
    n = bg.model.num_states
    roots = np.tile(np.eye(4), (n, 1, 1))
    roots[:, :3, 3] = rng.normal(size=(n, 3)) + [0, 0, 5]
    cams = [np.tile(np.eye(4), (len(c.timestamps), 1, 1)) for c in bg.model.cameras]
    for c in cams:
        c[:, :3, 3] = rng.normal(size=(len(c), 3))
    cams[0][:] = cams[0][0]  # a static camera: one pose
    return Estimate(roots, rng.normal(scale=0.1, size=(n, 21, 3)), body.default_shape, cams)


def test_static_camera_is_one_variable_moving_one_per_frame(body):
    bg = body_graph(body)
    keys = bg.camera_vars()
    assert keys[camera_key(0, 0)] == (0, 0) and sum(c == 0 for c, _ in keys.values()) == 1
    assert [j for c, j in keys.values() if c == 1] == list(range(6))
    held = body_graph(body, fixed_cameras={0: np.tile(np.eye(4), (6, 1, 1))})
    assert all(c == 1 for c, _ in held.camera_vars().values())


def test_values_and_read_round_trip(body):
    bg = body_graph(body)
    est, start = estimate_for(bg, body), estimate_for(bg, body, seed=9)
    back = bg.read(bg.values(est), start)
    np.testing.assert_allclose(back.roots, est.roots, atol=1e-12)
    np.testing.assert_allclose(back.poses, est.poses, atol=1e-12)
    for a, b in zip(back.cameras, est.cameras):
        np.testing.assert_allclose(a, b, atol=1e-12)
    assert start.roots[0, 2, 3] != est.roots[0, 2, 3]  # read copied, it did not write into start


def test_time_ordering_runs_along_the_chain_with_shared_variables_last(body):
    bg = body_graph(body)
    graph, values = bg.sequence(estimate_for(bg, body))
    order = bg.time_ordering(values)
    assert sorted(order) == sorted(values.keys())
    for i in range(6):  # a moving camera's frame right before the state it is seen at
        k = order.index(camera_key(1, i))
        assert order[k + 1 : k + 3] == [root_key(i), pose_key(i)]
    assert set(order[-2:]) == {shape_key(), camera_key(0, 0)}
    assert graph.size() > 0 and np.isfinite(graph.error(values))


def test_motion_windows_cover_every_state():
    assert motion_windows(24) == []
    assert motion_windows(25) == [0]
    assert motion_windows(61) == [0, 25, 36]
    assert motion_windows(61, stride=10) == [0, 10, 20, 30, 36]


def test_bad_graph_options_are_one_clear_error(body):
    with pytest.raises(MocapgraphError, match="pose_prior 'lstm'"):
        BodyGraph(body_graph(body).model, body, GraphOptions(pose_prior="lstm"))
    with pytest.raises(MocapgraphError, match="noise_px: a finite number > 0"):
        GraphOptions(noise_px=0.0).check()


def test_estimate_moves_rigidly(body):
    est = estimate_for(body_graph(body), body)
    A = gtsam.Pose3(gtsam.Rot3.Rz(0.3), np.array([1.0, 2.0, 0.0])).matrix()
    moved = est.transformed(A)
    np.testing.assert_allclose(moved.roots, A @ est.roots)
    np.testing.assert_allclose(moved.cameras[1], A @ est.cameras[1])
    np.testing.assert_array_equal(moved.poses, est.poses)


def test_whole_body_relabelling_allowed_where_a_camera_cannot_go_round(body):
    """The static camera may relabel its whole body; the moving one only with
    ``moving_body_swaps`` or when it is held (AirPose's reference); limbs everywhere."""
    from mocapgraph.body.labelling import SWAP_KINDS

    whole = SWAP_KINDS.index("body")

    def allowed(bg):
        bg.add_state(gtsam.NonlinearFactorGraph(), 0)
        ((labelling, obs),) = bg.labellings[0]
        return {bg.model.cameras[o.camera].name: labelling.allowed[row] for row, o in enumerate(obs)}

    free = allowed(body_graph(body))
    assert free["static"].all() and not free["moving"][whole] and np.delete(free["moving"], whole).all()
    held = allowed(body_graph(body, fixed_cameras={1: np.tile(np.eye(4), (6, 1, 1))}))
    assert held["moving"].all()
    # unless held_body_swaps says no (the online loop's AirCap bootstrap)
    bg = body_graph(body, fixed_cameras={1: np.tile(np.eye(4), (6, 1, 1))})
    bg.options = dataclasses.replace(bg.options, held_body_swaps=False)
    refused = allowed(bg)
    assert refused["static"].all() and not refused["moving"][whole] and np.delete(refused["moving"], whole).all()
