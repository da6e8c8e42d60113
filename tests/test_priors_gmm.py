"""The Gaussian-mixture pose prior: EM against a known mixture, file round trip, the max-mixture
factor's Jacobian and cost against scipy, the shipped weights, and `mocapgraph priors train pose`."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from scipy.stats import multivariate_normal
from test_cmu_motion import write_take
from test_factors import assert_jacobians

from mocapgraph.cli.main import main
from mocapgraph.errors import MocapgraphError
from mocapgraph.factors.keys import pose_key
from mocapgraph.graphs.initialisation import neutral_pose
from mocapgraph.priors import PoseGMM, fit_pose_gmm, load_default_pose_gmm, pose_gmm_factor
from mocapgraph.priors.training import nearest_mean_geodesic, split_by_subject

TRUE_WEIGHTS = np.array([0.5, 0.3, 0.2])
TRUE_MEANS = np.array([[0.0, 0.0, 0.0], [3.0, 3.0, 0.0], [-3.0, 2.0, 1.0]])
TRUE_SIGMAS = np.array([[0.5, 0.8, 0.3], [0.4, 0.4, 0.6], [0.7, 0.3, 0.5]])


def draw_mixture(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    k = rng.choice(3, size=n, p=TRUE_WEIGHTS)
    return TRUE_MEANS[k] + rng.normal(size=(n, 3)) * TRUE_SIGMAS[k]


def matched(gmm: PoseGMM) -> np.ndarray:
    """Component index of the fit closest to each true mean."""
    return np.argmin(np.linalg.norm(gmm.means[None] - TRUE_MEANS[:, None], axis=-1), axis=1)


def test_em_recovers_a_known_mixture():
    gmm = fit_pose_gmm(draw_mixture(4000, seed=1), components=3, seed=0, reg=1e-6)
    order = matched(gmm)
    assert sorted(order) == [0, 1, 2]
    np.testing.assert_allclose(gmm.weights[order], TRUE_WEIGHTS, atol=0.03)
    np.testing.assert_allclose(gmm.means[order], TRUE_MEANS, atol=0.06)
    np.testing.assert_allclose(np.sqrt(np.diagonal(gmm.covariances[order], axis1=1, axis2=2)), TRUE_SIGMAS, rtol=0.08)


def test_em_is_deterministic_under_a_seed_and_reports_progress():
    x = draw_mixture(600, seed=2)
    trace = []
    a = fit_pose_gmm(x, components=3, seed=5, progress=lambda it, ll: trace.append(ll))
    b = fit_pose_gmm(x, components=3, seed=5)
    np.testing.assert_array_equal(a.means, b.means)
    np.testing.assert_array_equal(a.covariances, b.covariances)
    assert len(trace) >= 2 and np.all(np.diff(trace) >= -1e-9)  # EM never lowers the likelihood


def test_log_likelihood_and_sampling_against_scipy():
    gmm = fit_pose_gmm(draw_mixture(500, seed=3), components=3, seed=0)
    x = draw_mixture(20, seed=4)
    want = np.log(sum(w * multivariate_normal(m, c).pdf(x) for w, m, c in zip(gmm.weights, gmm.means, gmm.covariances)))
    np.testing.assert_allclose(gmm.log_likelihood(x), want, rtol=1e-10)
    samples = gmm.sample(20000, np.random.default_rng(0))
    np.testing.assert_allclose(samples.mean(axis=0), gmm.weights @ gmm.means, atol=0.05)
    np.testing.assert_array_equal(gmm.sample(5, np.random.default_rng(1)), gmm.sample(5, np.random.default_rng(1)))


def test_save_load_round_trip_and_errors(tmp_path):
    gmm = fit_pose_gmm(draw_mixture(300, seed=5), components=2, seed=0, body_model="smpl")
    gmm = PoseGMM(gmm.weights, gmm.means, gmm.covariances, "smpl", {"val_mean_log_likelihood": -1.5})
    back = PoseGMM.load(gmm.save(tmp_path / "sub" / "gmm.npz"))
    assert back.body_model == "smpl" and back.info == {"val_mean_log_likelihood": -1.5}
    for name in ("weights", "means", "covariances", "precisions_cholesky"):
        np.testing.assert_array_equal(getattr(back, name), getattr(gmm, name))
    with pytest.raises(MocapgraphError, match="nothere.npz: pose GMM file not found"):
        PoseGMM.load(tmp_path / "nothere.npz")
    np.savez(tmp_path / "partial.npz", format_version=1, weights=gmm.weights)
    with pytest.raises(MocapgraphError, match="partial.npz: missing key 'body_model'"):
        PoseGMM.load(tmp_path / "partial.npz")
    with pytest.raises(MocapgraphError, match="positive definite"):
        PoseGMM(gmm.weights, gmm.means, -gmm.covariances)


def random_mixture(dim: int, components: int, seed: int) -> PoseGMM:
    """Well-separated components with random full covariances and unequal weights."""
    rng = np.random.default_rng(seed)
    A = rng.normal(scale=0.3, size=(components, dim, dim))
    cov = A @ np.swapaxes(A, 1, 2) + 0.05 * np.eye(dim)
    return PoseGMM(rng.dirichlet(np.ones(components) * 2), rng.normal(scale=1.0, size=(components, dim)), cov)


def test_factor_jacobian_matches_central_differences():
    gmm = random_mixture(63, 4, seed=0)
    rng = np.random.default_rng(1)
    factor = pose_gmm_factor(pose_key(3), gmm)
    for _ in range(4):
        values = gtsam.Values()
        values.insert(pose_key(3), gmm.means[rng.integers(4)] + rng.normal(scale=0.2, size=63))
        assert factor.whitenedError(values).shape == (64,)
        assert_jacobians(factor, values)


def test_a_mixture_over_some_joints_touches_only_their_dimensions(tmp_path):
    joints = np.array([0, 4, 9, 20])
    poses = np.random.default_rng(6).normal(scale=0.3, size=(400, 63))
    gmm = fit_pose_gmm(poses, components=2, seed=0, joints=joints)
    dims = (3 * joints[:, None] + np.arange(3)).ravel()
    assert gmm.dim == 12
    np.testing.assert_array_equal(gmm.dims, dims)
    np.testing.assert_allclose(gmm.log_likelihood(poses), fit_pose_gmm(poses[:, dims], components=2, seed=0).log_likelihood(poses[:, dims]))
    factor = pose_gmm_factor(pose_key(1), gmm)
    values = gtsam.Values()
    values.insert(pose_key(1), poses[0])
    assert_jacobians(factor, values)
    moved = poses[0].copy()
    moved[np.setdiff1d(np.arange(63), dims)] += 1.0  # unmodelled joints: no cost
    values.update(pose_key(1), moved)
    assert factor.error(values) == pytest.approx(pose_gmm_factor(pose_key(1), gmm).error(values))
    ref = gtsam.Values()
    ref.insert(pose_key(1), poses[0])
    assert factor.error(values) == pytest.approx(factor.error(ref), rel=1e-12)
    loaded = PoseGMM.load(gmm.save(tmp_path / "g.npz"))
    np.testing.assert_array_equal(loaded.joints, joints)
    with pytest.raises(MocapgraphError, match="joints"):
        PoseGMM(gmm.weights, gmm.means, gmm.covariances, joints=np.array([0, 1]))


def test_factor_cost_is_the_max_component_negative_log_density():
    """½‖r‖² + log max_k w_k N_k(θ) is one constant, −(D/2 log 2π + min c_k), across component switches."""
    dim = 5
    gmm = random_mixture(dim, 3, seed=2)
    factor = pose_gmm_factor(pose_key(0), gmm)
    components = [multivariate_normal(m, c) for m, c in zip(gmm.means, gmm.covariances)]
    c_min = np.min(-np.log(gmm.weights) + 0.5 * np.linalg.slogdet(gmm.covariances)[1])
    rng = np.random.default_rng(3)
    best, sums = set(), []
    for theta in gmm.means[rng.integers(3, size=30)] + rng.normal(scale=0.6, size=(30, dim)):
        values = gtsam.Values()
        values.insert(pose_key(0), theta)
        log_dens = [np.log(w) + c.logpdf(theta) for w, c in zip(gmm.weights, components)]
        best.add(int(np.argmax(log_dens)))
        sums.append(factor.error(values) + max(log_dens))
    assert best == {0, 1, 2}
    np.testing.assert_allclose(sums, -(0.5 * dim * np.log(2 * np.pi) + c_min), rtol=1e-9)


def test_levenberg_marquardt_on_the_factor_alone_lands_on_a_component_mean():
    gmm = random_mixture(63, 4, seed=4)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(pose_gmm_factor(pose_key(0), gmm))
    values = gtsam.Values()
    values.insert(pose_key(0), gmm.means[2] + np.random.default_rng(5).normal(scale=0.1, size=63))
    theta = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize().atVector(pose_key(0))
    k = np.argmin(np.abs(gmm.means - theta).max(axis=1))
    np.testing.assert_allclose(theta, gmm.means[k], atol=1e-8)


def test_shipped_weights_prefer_a_standing_pose_to_a_corrupted_one():
    gmm = load_default_pose_gmm()
    assert gmm.dim == 48 and gmm.body_model == "anny" and gmm.components == 8
    # Spine3, the feet and the collars never move in the retargeted CMU takes: not modelled.
    assert sorted(set(range(21)) - set(gmm.joints)) == [8, 9, 10, 12, 13]
    standing = neutral_pose()  # arms down
    rng = np.random.default_rng(0)
    axes = rng.normal(size=(21, 3))
    corrupted = standing + axes / np.linalg.norm(axes, axis=1, keepdims=True)  # 1 rad on every joint
    ll_standing, ll_corrupted = gmm.log_likelihood(np.stack([standing, corrupted]))
    assert ll_standing > ll_corrupted + 100
    assert nearest_mean_geodesic(gmm, standing[None])[0] < nearest_mean_geodesic(gmm, corrupted[None])[0]


def test_split_by_subject_holds_out_whole_subjects():
    subjects = np.repeat([1, 2, 3, 5, 7, 9, 11, 12, 13, 14], 7)
    val = split_by_subject(subjects, 0.2, seed=0)
    assert len(np.unique(subjects[val])) == 2
    assert not set(subjects[val]) & set(subjects[~val])
    np.testing.assert_array_equal(val, split_by_subject(subjects, 0.2, seed=0))


def test_cli_trains_on_a_tiny_motion_directory(tmp_path, capsys):
    motion = tmp_path / "motion"
    motion.mkdir()
    for i, subject in enumerate((1, 2, 3, 4, 6)):
        write_take(motion / f"cmu_{subject:02d}_01.npz", frames=40, seed=i)
    out = tmp_path / "gmm.npz"
    assert main(["priors", "train", "pose", "--motion", str(motion), "--out", str(out), "--components", "2"]) == 0
    captured = capsys.readouterr()
    assert "loaded 5/5 takes" in captured.err and "EM iteration 0" in captured.err
    assert "mean log-likelihood" in captured.out and "nearest-mean geodesic" in captured.out
    gmm = PoseGMM.load(out)
    assert gmm.components == 2 and gmm.info["train_poses"] + gmm.info["val_poses"] == 50


def test_cli_names_a_missing_or_empty_motion_directory(tmp_path, capsys):
    out = str(tmp_path / "gmm.npz")
    assert main(["priors", "train", "pose", "--motion", str(tmp_path / "nowhere"), "--out", out]) == 2
    assert f"{tmp_path / 'nowhere'}: motion directory not found" in capsys.readouterr().err
    assert main(["priors", "train", "pose", "--motion", str(tmp_path), "--out", out]) == 2
    assert f"{tmp_path}: no CMU takes" in capsys.readouterr().err
