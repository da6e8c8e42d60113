"""The static cameras adjusted on free points (``graphs.point_bundle.refine_static_cameras``),
against the simulator's cameras: from poses a few centimetres and degrees off, with the
detections' own left/right labels swapped and the solve's labels given back, and the gauge."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.labelling import SWAP_KINDS, swap_permutation
from mocapgraph.data_tools.evaluation.alignment import align_camera_centres
from mocapgraph.data_tools.sim.synthetic import synthesize
from mocapgraph.graphs.point_bundle import refine_static_cameras
from mocapgraph.graphs.state_model import Estimate
from mocapgraph.pipelines.observations import capture_state_model

START_CM, START_DEG = 6.0, 1.5
"""How far the start's cameras are put from the truth."""


@pytest.fixture(scope="module")
def rig():
    """Four static cameras of a 2 s ``rich`` capture, realistic detector faults, its state model
    and the true poses."""
    capture = synthesize("rich", seed=3, duration_s=2.0, detector_faults="realistic")
    capture.cameras = [c for c in capture.cameras if not c.moving][:4]
    model = capture_state_model(capture, "closest")
    truth = [capture.ground_truth.cameras[cam.name][0] for cam in model.cameras]
    return model, truth


def perturbed(truth: list[np.ndarray], seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    out = []
    for T in truth:
        P = T.copy()
        P[:3, :3] = Rotation.from_rotvec(np.radians(START_DEG) * Rotation.random(random_state=rng).as_rotvec() / np.pi).as_matrix() @ T[:3, :3]
        P[:3, 3] += rng.normal(size=3) / np.sqrt(3) * START_CM / 100
        out.append(P)
    return out


def longer(K: np.ndarray, factor: float) -> np.ndarray:
    """``K`` with its focal lengths ``factor`` times as long."""
    out = K.copy()
    out[:2, :2] *= factor
    return out


def estimate_with(model, poses: list[np.ndarray]) -> Estimate:
    n = model.num_states
    return Estimate(np.repeat(np.eye(4)[None], n, 0), np.zeros((n, 21, 3)), np.zeros(1), [np.repeat(T[None], len(c.timestamps), 0) for T, c in zip(poses, model.cameras)])


def centre_errors_cm(cameras: dict[int, np.ndarray], truth: list[np.ndarray]) -> np.ndarray:
    """Per camera, cm between its centre and the truth's after the best similarity of all centres."""
    similarity = align_camera_centres([cameras[c][None, :3, 3] for c in sorted(cameras)], [truth[c][None, :3, 3] for c in sorted(cameras)])
    return np.array([100 * np.linalg.norm(similarity.apply(cameras[c][:3, 3]) - truth[c][:3, 3]) for c in sorted(cameras)])


def test_cameras_come_back_to_the_truth_and_the_gauge_holds(rig):
    model, truth = rig
    start = perturbed(truth, seed=0)
    before = centre_errors_cm(dict(enumerate(start)), truth)
    codes = {c: np.zeros(len(cam.timestamps), dtype=np.int8) for c, cam in enumerate(model.cameras)}
    refined = refine_static_cameras(model, estimate_with(model, start), codes, gm_sigma_px=10.0, threshold_px=15.0, max_iterations=50)
    after = centre_errors_cm(refined.cameras, truth)
    assert np.median(before) > 2.0  # the start is off (guards the test itself)
    # the floor: the simulated detector's keypoint-definition offsets and noise over 2 s
    assert np.median(after) < 1.0 and np.all(after < before / 2.5), (before, after)
    a, b = refined.gauge
    np.testing.assert_allclose(refined.cameras[a], start[a], atol=1e-5)
    distance = np.linalg.norm(refined.cameras[a][:3, 3] - refined.cameras[b][:3, 3])
    assert distance == pytest.approx(np.linalg.norm(start[a][:3, 3] - start[b][:3, 3]), abs=1e-5)
    assert b == int(np.argmax([np.linalg.norm(T[:3, 3] - start[a][:3, 3]) for T in start]))
    assert refined.fmt == model.formats[0] and refined.points > 0.9 * model.num_states * get_format(refined.fmt).num_points
    assert refined.reprojection_px < 6.0


def test_the_solve_labels_are_applied(rig):
    """A camera's frames swapped left/right in the observations, the swap given as the solve's
    labels: the same cameras as without the swap; without the labels, worse."""
    model, truth = rig
    start = perturbed(truth, seed=1)
    estimate = estimate_with(model, start)
    zeros = {c: np.zeros(len(cam.timestamps), dtype=np.int8) for c, cam in enumerate(model.cameras)}
    swapped_frames = np.arange(5, 40)
    code = SWAP_KINDS.index("body")
    codes = {c: v.copy() for c, v in zeros.items()}
    codes[2][swapped_frames] = code
    swapped = model.relabelled(codes)  # each swap is its own inverse: relabelling swaps them
    plain = refine_static_cameras(model, estimate, zeros, 10.0, 15.0, 50)
    given = refine_static_cameras(swapped, estimate, codes, 10.0, 15.0, 50)
    for c in plain.cameras:
        np.testing.assert_allclose(given.cameras[c], plain.cameras[c], atol=1e-6)
    names = get_format(model.formats[0]).names
    assert not np.array_equal(swap_permutation(names, "body"), np.arange(len(names)))
    ignored = refine_static_cameras(swapped, estimate, zeros, 10.0, 15.0, 50)
    assert ignored.reprojection_px > plain.reprojection_px


def relative_pose_errors(a: np.ndarray, b: np.ndarray, true_a: np.ndarray, true_b: np.ndarray) -> tuple[float, float]:
    """Radians between ``b``'s orientation relative to ``a`` and the truth's, and between the
    directions of their baselines seen from ``a``: the two cameras' geometry, any gauge."""
    rel, true_rel = np.linalg.inv(a) @ b, np.linalg.inv(true_a) @ true_b
    turn = np.linalg.norm(Rotation.from_matrix(rel[:3, :3].T @ true_rel[:3, :3]).as_rotvec())
    u, v = rel[:3, 3] / np.linalg.norm(rel[:3, 3]), true_rel[:3, 3] / np.linalg.norm(true_rel[:3, 3])
    return float(turn), float(np.arccos(np.clip(u @ v, -1.0, 1.0)))


def test_two_static_cameras_facing_each_other_are_adjusted(rig):
    """Two static cameras 141° apart seen from the person, from poses a few centimetres and
    degrees off: their relative pose comes back towards the truth, the gauge camera and their
    distance held. Two 44° apart, or one, give none; a moving camera takes no part."""
    model, truth = rig
    codes = {c: np.zeros(len(cam.timestamps), dtype=np.int8) for c, cam in enumerate(model.cameras)}
    facing = model.only([True, False, False, True])
    start = perturbed(truth, seed=3)
    refined = refine_static_cameras(facing, estimate_with(facing, start), codes, 10.0, 15.0, 50)
    assert sorted(refined.cameras) == [0, 3]
    a, b = refined.gauge
    np.testing.assert_allclose(refined.cameras[a], start[a], atol=1e-5)
    distance = np.linalg.norm(refined.cameras[0][:3, 3] - refined.cameras[3][:3, 3])
    assert distance == pytest.approx(np.linalg.norm(start[0][:3, 3] - start[3][:3, 3]), abs=1e-5)
    before = relative_pose_errors(start[0], start[3], truth[0], truth[3])
    after = relative_pose_errors(refined.cameras[0], refined.cameras[3], truth[0], truth[3])
    assert before[0] > 0.02 and before[1] > 0.01  # the start is off (guards the test itself)
    assert after[0] < before[0] / 2 and after[1] < before[1] / 3, (before, after)
    side_by_side = model.only([True, True, False, False])
    assert refine_static_cameras(side_by_side, estimate_with(side_by_side, start), codes, 10.0, 15.0, 50) is None
    one = model.only([True, False, False, False])
    assert refine_static_cameras(one, estimate_with(one, truth), codes, 10.0, 15.0, 50) is None
    moving = replace(model, cameras=[replace(cam, moving=c in (1, 2)) for c, cam in enumerate(model.cameras)])
    assert sorted(refine_static_cameras(moving, estimate_with(moving, start), codes, 10.0, 15.0, 50).cameras) == [0, 3]


def test_the_estimated_focal_lengths_are_used(rig):
    """Intrinsics guessed 30 % long with the solve's focal estimate undoing it: the same cameras
    as with the true intrinsics (the principal point stays where it is)."""
    model, truth = rig
    start = perturbed(truth, seed=2)
    codes = {c: np.zeros(len(cam.timestamps), dtype=np.int8) for c, cam in enumerate(model.cameras)}
    guessed = replace(model, cameras=[replace(cam, K=longer(cam.K, 1.3)) for cam in model.cameras])
    estimate = estimate_with(guessed, start)
    estimate.focal_log = np.full(len(model.cameras), -np.log(1.3))
    true = refine_static_cameras(model, estimate_with(model, start), codes, 10.0, 15.0, 50)
    undone = refine_static_cameras(guessed, estimate, codes, 10.0, 15.0, 50)
    for c in true.cameras:
        np.testing.assert_allclose(undone.cameras[c], true.cameras[c], atol=1e-6)


def test_a_camera_with_too_few_points_is_left_as_it_is(rig):
    """A static camera that sees five keypoints once takes no part (nothing would hold it)."""
    model, truth = rig
    first = True
    states = []
    for obs in model.states:
        out = []
        for o in obs:
            if o.camera == 1:
                weights = np.zeros_like(o.weights)
                if first:
                    weights[:5], first = o.weights[:5], False
                o = replace(o, weights=weights)
            out.append(o)
        states.append(out)
    sparse = replace(model, states=states)
    codes = {c: np.zeros(len(cam.timestamps), dtype=np.int8) for c, cam in enumerate(model.cameras)}
    refined = refine_static_cameras(sparse, estimate_with(sparse, perturbed(truth, seed=3)), codes, 10.0, 15.0, 50)
    assert sorted(refined.cameras) == [0, 2, 3]
    assert np.median(centre_errors_cm(refined.cameras, truth)) < 1.0
