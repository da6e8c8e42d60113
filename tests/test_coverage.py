"""Coverage of the joints' 95 % ellipsoids (the uncertainty score of `bench aircap`) against χ²₃."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from mocapgraph.data_tools.evaluation.metrics import Unit, covariance_coverage


def result_with_errors(scale: float, seed: int = 0, frames: int = 400):
    """Joints off the truth by draws of N(0, Σ) with random per-joint Σ, reported as ``scale² Σ``.
    Returns ``(estimate, covariances, truth)``."""
    rng = np.random.default_rng(seed)
    A = rng.normal(scale=0.02, size=(frames, 22, 3, 3))
    cov = A @ np.swapaxes(A, -1, -2) + 1e-6 * np.eye(3)
    truth = rng.normal(size=(frames, 22, 3))
    noise = np.einsum("tjab,tjb->tja", np.linalg.cholesky(cov), rng.normal(size=(frames, 22, 3)))
    return truth + noise, scale**2 * cov, truth


def coverage(est, cov, truth, states=slice(None)) -> float:
    result = covariance_coverage(est[states], truth, cov[states])
    assert result.unit is Unit.FRACTION
    return result.value


def test_coverage_of_honest_covariances_is_the_level():
    est, cov, truth = result_with_errors(1.0)
    assert coverage(est, cov, truth) == pytest.approx(0.95, abs=0.01)  # 8800 joints: 0.95 ± 0.005 (2σ)


def test_coverage_of_inflated_and_shrunk_covariances():
    """Doubling σ covers P(χ²₃ ≤ 4·7.81); halving it P(χ²₃ ≤ 7.81 / 4)."""
    est, inflated, truth = result_with_errors(2.0, seed=1)
    _, shrunk, _ = result_with_errors(0.5, seed=1)
    threshold = chi2.ppf(0.95, 3)
    assert coverage(est, inflated, truth) == pytest.approx(chi2.cdf(4 * threshold, 3), abs=0.01)
    assert coverage(est, shrunk, truth) == pytest.approx(chi2.cdf(threshold / 4, 3), abs=0.01)


def test_coverage_on_selected_states_and_skips_non_finite():
    est, cov, truth = result_with_errors(1.0, seed=2)
    est[5] = np.nan
    keep = np.zeros(len(truth), bool)
    keep[:200] = True
    full = coverage(est, cov, truth[keep], keep)
    cov[300:] = 1e-12  # states outside the selection do not count
    assert coverage(est, cov, truth[keep], keep) == full
    assert full == pytest.approx(0.95, abs=0.02)
    assert covariance_coverage(est[keep], truth[keep], cov[keep]).excluded == 22  # frame 5's joints


# ---------------------------------------------------------------------------------------------
# A result's covariances through the evaluation's alignment (evaluate.coverage)


def test_moved_covariances_are_the_similarity_applied_to_samples():
    """Points drawn from a joint's covariance, and poses perturbed along a camera's tangent, then
    mapped by a similarity: their spread is what :func:`moved_covariances` says (20 000 draws:
    a few per cent)."""
    import gtsam

    from mocapgraph.data_tools.evaluation.alignment import Similarity
    from mocapgraph.data_tools.evaluation.evaluate import moved_covariances

    rng = np.random.default_rng(3)
    align = Similarity(1.7, Rotation.random(random_state=rng).as_matrix(), rng.normal(size=3))
    A = rng.normal(scale=0.02, size=(3, 3))
    joint = A @ A.T + 1e-5 * np.eye(3)
    B = rng.normal(scale=0.01, size=(6, 6))
    pose_cov = B @ B.T + 1e-6 * np.eye(6)
    moved = moved_covariances({"joints": joint[None, None], "camera:a": pose_cov[None], "shape": np.eye(2)}, align)
    points = align.apply(rng.multivariate_normal(np.zeros(3), joint, size=20000))
    np.testing.assert_allclose(np.cov(points.T), moved["joints"][0, 0], rtol=0.05, atol=0.03 * np.abs(moved["joints"]).max())
    T = gtsam.Pose3(gtsam.Rot3(Rotation.random(random_state=rng).as_matrix()), rng.normal(size=3))
    base = gtsam.Pose3(align.apply_pose(T.matrix()[None])[0])
    xi = rng.multivariate_normal(np.zeros(6), pose_cov, size=20000)
    logs = np.array([base.logmap(gtsam.Pose3(align.apply_pose(T.compose(gtsam.Pose3.Expmap(x)).matrix()[None])[0])) for x in xi])
    np.testing.assert_allclose(np.cov(logs.T), moved["camera:a"][0], rtol=0.08, atol=0.03 * np.abs(moved["camera:a"]).max())
    assert moved["shape"] is not None and np.array_equal(moved["shape"], np.eye(2))


def test_coverage_after_the_alignment_is_the_level():
    """A result in a camera's frame (a rigid alignment with that camera's true pose), its joints
    and a moving camera's centres off the truth by draws of their stated covariances: covered at
    the level; with σ stated half as large, at P(χ²₃ ≤ 7.81 / 4)."""
    from mocapgraph.data_tools.evaluation.evaluate import coverage as result_coverage
    from mocapgraph.data_tools.io.capture import Camera, Capture, GroundTruth
    from mocapgraph.data_tools.io.result import CameraTrack, Result

    rng = np.random.default_rng(4)
    T = 300
    ts = np.arange(T) / 30.0
    K = np.array([[1000.0, 0, 640], [0, 1000, 360], [0, 0, 1]])
    fixed = np.eye(4)
    fixed[:3, :3], fixed[:3, 3] = Rotation.random(random_state=rng).as_matrix(), rng.normal(size=3)
    moving = np.repeat(np.eye(4)[None], T, axis=0)
    moving[:, :3, :3] = Rotation.random(T, random_state=rng).as_matrix()
    moving[:, :3, 3] = rng.normal(size=(T, 3))
    joints = rng.normal(size=(T, 22, 3))
    gt = GroundTruth("anny", ts, np.repeat(np.eye(4)[None], T, 0), np.zeros((T, 21, 3)), np.zeros(6), joints, {"fixed": np.repeat(fixed[None], T, 0), "walk": moving})
    cams = [Camera("fixed", K, np.zeros(5), (1280, 720), False, ts, 30.0), Camera("walk", K, np.zeros(5), (1280, 720), True, ts, 30.0)]
    capture = Capture("truth", cams, ground_truth=gt)

    A = rng.normal(scale=0.02, size=(T, 22, 3, 3))
    joint_cov = A @ np.swapaxes(A, -1, -2) + 1e-6 * np.eye(3)  # in the capture's world
    noisy = joints + np.einsum("tjab,tjb->tja", np.linalg.cholesky(joint_cov), rng.normal(size=(T, 22, 3)))
    C = rng.normal(scale=0.02, size=(T, 3, 3))
    centre_cov = C @ np.swapaxes(C, -1, -2) + 1e-6 * np.eye(3)  # in the camera's own frame
    est_moving = moving.copy()
    est_moving[:, :3, 3] += np.einsum("tab,tbc,tc->ta", moving[:, :3, :3], np.linalg.cholesky(centre_cov), rng.normal(size=(T, 3)))
    inv = np.linalg.inv(fixed)  # the result's world is camera fixed's frame
    camera_cov = np.zeros((T, 6, 6))
    camera_cov[:, :3, :3] = 1e-4 * np.eye(3)
    camera_cov[:, 3:, 3:] = centre_cov

    def result(scale: float) -> Result:
        return Result(
            pipeline="test", capture="-", world_frame="camera:fixed", timestamps=ts,
            joints=np.einsum("ij,tkj->tki", inv[:3, :3], noisy) + inv[:3, 3],
            cameras={"walk": CameraTrack(ts, inv @ est_moving)},
            covariances={"joints": scale**2 * np.einsum("ji,tkjl,lm->tkim", fixed[:3, :3], joint_cov, fixed[:3, :3]), "camera:walk": scale**2 * camera_cov},
        )  # fmt: skip

    from mocapgraph.data_tools.evaluation.evaluate import evaluate

    honest, shrunk = result_coverage(result(1.0), capture), result_coverage(result(0.5), capture)
    metrics = evaluate(result(1.0), capture).metrics
    assert {k: v for k, v in metrics.items() if k.startswith("coverage95_")} == {f"coverage95_{k}": v for k, v in honest.items()}
    assert honest["joints"] == pytest.approx(0.95, abs=0.01)  # 6600 joints: ± 0.005 (2σ)
    assert honest["cameras"] == honest["cameras.walk"] == pytest.approx(0.95, abs=0.03)  # 300 centres: ± 0.025
    assert shrunk["joints"] == pytest.approx(chi2.cdf(chi2.ppf(0.95, 3) / 4, 3), abs=0.02)
    # the same joints in the walking camera's frame at each instant (AirPose's world): the same share
    per_frame = np.linalg.inv(moving)
    airpose = Result(
        pipeline="test", capture="-", world_frame="camera_per_frame:walk", timestamps=ts,
        joints=np.einsum("tij,tkj->tki", per_frame[:, :3, :3], noisy) + per_frame[:, None, :3, 3],
        covariances={"joints": np.einsum("tji,tkjl,tlm->tkim", moving[:, :3, :3], joint_cov, moving[:, :3, :3])},
    )  # fmt: skip
    assert result_coverage(airpose, capture)["joints"] == pytest.approx(honest["joints"], abs=1e-12)
    assert shrunk["cameras"] == pytest.approx(chi2.cdf(chi2.ppf(0.95, 3) / 4, 3), abs=0.06)
