"""The pose VAE: rotation maps against scipy, a tiny VAE learning a low-dimensional pose family,
determinism, the file round trip and its errors, the latent-variable factor's Jacobians, cost and
batching, a Levenberg-Marquardt denoise, the shipped weights and the sample grid."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation
from scipy.stats import multivariate_normal
from test_cmu_motion import write_take
from test_factors import max_rel_diff, numerical_jacobian

from mocapgraph.body import load_body_model
from mocapgraph.cli.main import main
from mocapgraph.errors import MocapgraphError
from mocapgraph.factors.keys import pose_key, pose_latent_key
from mocapgraph.graphs.initialisation import neutral_pose
from mocapgraph.priors.plots import pose_grid_png
from mocapgraph.priors.pose_vae import (
    PoseVAE,
    fit_pose_vae,
    load_default_pose_vae,
    rotmat_to_rotvec,
    rotmat_to_sixd,
    sixd_to_rotmat,
    train_pose_vae,
)
from mocapgraph.priors.pose_vae_factor import LATENT_SIGMA, PoseVAEPrior

MOVING = np.array([0, 1, 3, 15, 16, 17])  # hips, spine1, both shoulders, left elbow
TINY = dict(latent=4, width=64, epochs=60, batch=128, recon_sigma=0.2)


def family_of(u: np.ndarray) -> np.ndarray:
    """``(n, 63)`` poses on a 2-d manifold: the joints ``MOVING`` are a smooth function of
    ``u (n, 2)``, every other joint a constant (as the CMU collars and feet are)."""
    family = np.random.default_rng(123)
    A, b = family.normal(size=(len(MOVING), 3, 2)), family.normal(scale=0.5, size=(len(MOVING), 3))
    poses = np.tile(family.normal(scale=0.2, size=(21, 3)), (len(u), 1, 1))
    poses[:, MOVING] = 0.8 * np.tanh(np.einsum("jab,nb->nja", A, u) + b)
    return poses.reshape(len(u), 63)


def pose_family(n: int, seed: int) -> np.ndarray:
    """``(n, 63)`` poses of the family with ``u ~ N(0, I_2)``."""
    return family_of(np.random.default_rng(seed).normal(size=(n, 2)))


def distance_to_family(poses: np.ndarray) -> np.ndarray:
    """``(N,)`` rad: RMS per moving joint of the axis-angle distance to the nearest family pose (u on a grid)."""
    grid = np.linspace(-3.5, 3.5, 141)
    members = family_of(np.stack(np.meshgrid(grid, grid), -1).reshape(-1, 2)).reshape(-1, 21, 3)[:, MOVING].reshape(-1, 18)
    x = poses.reshape(-1, 21, 3)[:, MOVING].reshape(-1, 18)
    d2 = np.square(x).sum(axis=1)[:, None] + np.square(members).sum(axis=1) - 2 * x @ members.T
    return np.sqrt(np.maximum(d2.min(axis=1), 0.0) / len(MOVING))


@pytest.fixture(scope="module", autouse=True)
def _one_thread(one_torch_thread):
    """Tiny networks: a second torch thread only adds contention (4–5× slower on a busy machine)."""


@pytest.fixture(scope="module")
def tiny_vae() -> PoseVAE:
    return fit_pose_vae(pose_family(2000, seed=1), pose_family(400, seed=2), seed=0, **TINY)


def mean_geodesic(a: np.ndarray, b: np.ndarray, joints: np.ndarray) -> float:
    """Mean over poses and ``joints`` of the rotation angle between poses ``a`` and ``b`` ``(N, 63)``."""
    ra = Rotation.from_rotvec(a.reshape(-1, 21, 3)[:, joints].reshape(-1, 3))
    rb = Rotation.from_rotvec(b.reshape(-1, 21, 3)[:, joints].reshape(-1, 3))
    return float((ra.inv() * rb).magnitude().mean())


# ---------------------------------------------------------------------------------------------
# Rotation maps


def random_rotvecs(rng: np.random.Generator) -> np.ndarray:
    """Axis-angle vectors with angles spread over [0, π), near 0 and near π."""
    axes = rng.normal(size=(900, 3))
    angles = np.concatenate(
        [rng.uniform(0, np.pi, 300), 10 ** rng.uniform(-9, -1, 300), np.pi - 10 ** rng.uniform(-7, -1, 300)]
    )
    return axes / np.linalg.norm(axes, axis=1, keepdims=True) * angles[:, None]


def test_log_map_matches_scipy_near_zero_and_near_pi():
    rotvecs = random_rotvecs(np.random.default_rng(0))
    R = Rotation.from_rotvec(rotvecs).as_matrix()
    np.testing.assert_allclose(rotmat_to_rotvec(torch.as_tensor(R)).numpy(), rotvecs, atol=1e-12)
    got32 = rotmat_to_rotvec(torch.as_tensor(R, dtype=torch.float32)).double().numpy()
    np.testing.assert_allclose(Rotation.from_rotvec(got32).as_matrix(), R, atol=2e-6)


def test_sixd_round_trip_and_gram_schmidt():
    R = Rotation.random(50, random_state=1).as_matrix()
    sixd = rotmat_to_sixd(torch.as_tensor(R))
    np.testing.assert_array_equal(sixd.numpy(), np.concatenate([R[:, :, 0], R[:, :, 1]], axis=1))
    np.testing.assert_allclose(sixd_to_rotmat(sixd).numpy(), R, atol=1e-15)
    x = np.random.default_rng(2).normal(size=(50, 6))
    got = sixd_to_rotmat(torch.as_tensor(x)).numpy()
    np.testing.assert_allclose(got.transpose(0, 2, 1) @ got, np.broadcast_to(np.eye(3), got.shape), atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(got), 1.0, atol=1e-14)
    np.testing.assert_allclose(got[:, :, 0], x[:, :3] / np.linalg.norm(x[:, :3], axis=1, keepdims=True), atol=1e-15)
    assert np.all(np.einsum("na,na->n", got[:, :, 1], x[:, 3:]) > 0)  # second column on x[3:]'s side


@pytest.mark.parametrize("rotvec", [[0.0, 0.0, 0.0], [1e-9, 0.0, 0.0], [np.pi, 0.0, 0.0], [0.0, 2.2214415, 2.2214415]])
def test_log_map_derivatives_are_finite_at_zero_and_pi(rotvec):
    R = torch.as_tensor(Rotation.from_rotvec(rotvec).as_matrix())[None]
    R.requires_grad_(True)
    rotmat_to_rotvec(R).sum().backward()
    assert torch.isfinite(R.grad).all()
    assert torch.isfinite(torch.func.jacfwd(rotmat_to_rotvec)(R.detach())).all()


def test_decoder_jacobian_forward_and_reverse_mode_match_central_differences(tiny_vae):
    vae = PoseVAE(tiny_vae.joints, tiny_vae.static_pose, tiny_vae.latent, tiny_vae.width).double()
    vae.load_state_dict(tiny_vae.state_dict())
    z = torch.as_tensor(np.random.default_rng(3).normal(size=(1, vae.latent)))
    forward = torch.func.jacfwd(vae.decode_rotvec_torch)(z)[0, :, 0]
    reverse = torch.autograd.functional.jacobian(vae.decode_rotvec_torch, z)[0, :, 0]
    numeric = torch.stack([(vae.decode_rotvec_torch(z + d) - vae.decode_rotvec_torch(z - d))[0] / 2e-6
                           for d in 1e-6 * torch.eye(vae.latent, dtype=torch.float64)], dim=1)  # fmt: skip
    np.testing.assert_allclose(forward.detach().numpy(), numeric.detach().numpy(), atol=1e-7)
    np.testing.assert_allclose(reverse.detach().numpy(), numeric.detach().numpy(), atol=1e-7)


# ---------------------------------------------------------------------------------------------
# Training and the file


def test_tiny_vae_learns_the_family_far_better_than_the_mean_pose(tiny_vae):
    np.testing.assert_array_equal(tiny_vae.joints, MOVING)  # the constant joints are not modelled
    val = pose_family(400, seed=2)
    baseline = mean_geodesic(val, np.tile(pose_family(2000, seed=1).mean(axis=0), (400, 1)), MOVING)
    err = tiny_vae.geodesic_error(val).mean()
    assert np.isclose(err, tiny_vae.info["val_geodesic_err_rad"]) and err < 0.2 * baseline
    np.testing.assert_allclose(mean_geodesic(val, tiny_vae.decode(tiny_vae.encode(val)), MOVING), err, rtol=1e-5)
    # Decoded poses are full poses: the unmodelled joints are the training constants.
    decoded = tiny_vae.decode(np.zeros((1, 4)))[0].reshape(21, 3)
    others = np.setdiff1d(np.arange(21), MOVING)
    np.testing.assert_allclose(decoded[others], val[0].reshape(21, 3)[others], atol=1e-12)
    assert tiny_vae.sigma.shape == (18,) and np.all(tiny_vae.sigma >= 0.02)
    # Samples lie near the family: much nearer than the mean pose does.
    samples = tiny_vae.sample(200, np.random.default_rng(4))
    assert distance_to_family(samples).mean() < 0.5 * distance_to_family(val.mean(axis=0, keepdims=True))[0]
    # The ELBO prefers the family to poses pushed off it.
    off = val + np.random.default_rng(5).normal(scale=0.3, size=val.shape)
    assert tiny_vae.elbo(val).mean() > tiny_vae.elbo(off).mean() + 50


def test_training_is_deterministic_under_a_seed_and_reports_each_epoch():
    lines = []
    a = fit_pose_vae(pose_family(300, 6), pose_family(100, 7), seed=3, progress=lines.append, **{**TINY, "epochs": 3})
    b = fit_pose_vae(pose_family(300, 6), pose_family(100, 7), seed=3, **{**TINY, "epochs": 3})
    for name, tensor in a.state_dict().items():
        torch.testing.assert_close(tensor, b.state_dict()[name], rtol=0, atol=0)
    np.testing.assert_array_equal(a.sigma, b.sigma)
    assert len(lines) == 3 and lines[0].startswith("epoch 1/3: loss ") and "val geodesic" in lines[0]


def test_save_load_round_trip_and_errors(tiny_vae, tmp_path):
    back = PoseVAE.load(tiny_vae.save(tmp_path / "sub" / "vae.npz"))
    assert back.info == tiny_vae.info and back.latent == 4 and back.width == 64
    for name in ("joints", "static_pose", "sigma", "dims"):
        np.testing.assert_array_equal(getattr(back, name), getattr(tiny_vae, name))
    z = np.random.default_rng(6).normal(size=(5, 4))
    np.testing.assert_array_equal(back.decode(z), tiny_vae.decode(z))
    half = PoseVAE.load(tiny_vae.save(tmp_path / "half.npz", float16=True))
    assert np.abs(half.decode(z) - tiny_vae.decode(z)).max() < 0.01

    with pytest.raises(MocapgraphError, match="nothere.npz: pose VAE file not found"):
        PoseVAE.load(tmp_path / "nothere.npz")
    with np.load(tmp_path / "sub" / "vae.npz") as d:
        saved = dict(d)
    np.savez(tmp_path / "partial.npz", **{k: v for k, v in saved.items() if k != "sigma"})
    with pytest.raises(MocapgraphError, match="partial.npz: missing key 'sigma'"):
        PoseVAE.load(tmp_path / "partial.npz")
    np.savez(tmp_path / "noweight.npz", **{k: v for k, v in saved.items() if k != "state/decoder.2.bias"})
    with pytest.raises(MocapgraphError, match="noweight.npz: missing key 'state/decoder.2.bias'"):
        PoseVAE.load(tmp_path / "noweight.npz")
    np.savez(tmp_path / "wide.npz", **{**saved, "config": '{"latent": 4, "width": 65}'})
    with pytest.raises(MocapgraphError, match=r"wide.npz: key 'state/encoder.0.weight' has shape \(64, 36\)"):
        PoseVAE.load(tmp_path / "wide.npz")
    np.savez(tmp_path / "future.npz", **{**saved, "format_version": 2})
    with pytest.raises(MocapgraphError, match="future.npz: format_version 2"):
        PoseVAE.load(tmp_path / "future.npz")
    (tmp_path / "junk.npz").write_text("not a zip")
    with pytest.raises(MocapgraphError, match="junk.npz: not a readable pose VAE"):
        PoseVAE.load(tmp_path / "junk.npz")


def test_train_pose_vae_on_a_tiny_motion_directory(tmp_path, capsys):
    for i, subject in enumerate((1, 2, 3, 4, 6)):
        write_take(tmp_path / f"cmu_{subject:02d}_01.npz", frames=40, seed=i)
    lines = []
    vae = train_pose_vae(tmp_path, load_body_model("anny"), latent=3, width=16, epochs=2, batch=16, progress=lines.append)
    info = vae.info
    out = tmp_path / "vae.npz"
    args = ["priors", "train", "pose", "--model", "vae", "--motion", str(tmp_path), "--out", str(out), "--latent", "3", "--width", "16", "--epochs", "2"]
    assert main(args) == 0
    printed = capsys.readouterr()
    assert "epoch 2/2: " in printed.err and "reconstruction geodesic" in printed.out
    assert PoseVAE.load(out).latent == 3
    assert info["train_poses"] + info["val_poses"] == 50 and info["data"] == tmp_path.name and info["stride"] == 4
    assert set(info["val_subjects"]) < {1, 2, 3, 4, 6} and info["val_geodesic_err_rad"] > 0
    assert "loaded 5/5 takes" in lines and lines[-1].startswith("epoch 2/2: ")
    with pytest.raises(MocapgraphError, match="motion directory not found"):
        train_pose_vae(tmp_path / "nowhere", load_body_model("anny"))


# ---------------------------------------------------------------------------------------------
# The factor


def prior_graph(vae: PoseVAE, poses: np.ndarray, **kwargs) -> tuple[PoseVAEPrior, gtsam.NonlinearFactorGraph, gtsam.Values]:
    prior = PoseVAEPrior(vae, range(len(poses)), **kwargs)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for i, theta in enumerate(poses):
        values.insert(pose_key(i), theta)
    prior.add_to(graph, values, poses)
    return prior, graph, values


def test_factor_jacobians_match_central_differences(tiny_vae):
    vae = PoseVAE(tiny_vae.joints, tiny_vae.static_pose, 4, 64, tiny_vae.sigma).double()
    vae.load_state_dict(tiny_vae.state_dict())
    poses = pose_family(3, seed=8) + np.random.default_rng(9).normal(scale=0.1, size=(3, 63))
    _, graph, values = prior_graph(vae, poses)
    for f in range(1, graph.size(), 2):  # the (θ, z) factors
        factor = graph.at(f)
        A, b = factor.linearize(values).jacobian()
        assert A.shape == (18, 63 + 4)
        np.testing.assert_allclose(b, -factor.whitenedError(values), atol=1e-12)
        # The batched decoder feeds the network float32 latents, so the step is 1e-3, not 1e-6.
        assert max_rel_diff(A, numerical_jacobian(factor.whitenedError, factor, values, h=1e-3)) < 1e-4


def test_factor_cost_is_the_negative_log_joint_density(tiny_vae):
    """With the model's own latent prior (σ = 1); the default tempers it to σ = LATENT_SIGMA."""
    poses = pose_family(4, seed=10) + np.random.default_rng(11).normal(scale=0.1, size=(4, 63))
    _, graph, values = prior_graph(tiny_vae, poses, latent_sigma=1.0)
    _, tempered, _ = prior_graph(tiny_vae, poses)
    L, dims, sigma = 4, tiny_vae.dims, tiny_vae.sigma
    const = 0.5 * (L + len(dims)) * np.log(2 * np.pi) + np.log(sigma).sum()
    for i, theta in enumerate(poses):
        z = values.atVector(pose_latent_key(i))
        cost = graph.at(2 * i).error(values) + graph.at(2 * i + 1).error(values)
        log_joint = multivariate_normal(np.zeros(L)).logpdf(z) + multivariate_normal(
            tiny_vae.decode(z[None])[0, dims], np.diag(sigma**2)
        ).logpdf(theta[dims])
        np.testing.assert_allclose(cost, -log_joint - const, rtol=1e-5)
        np.testing.assert_allclose(tempered.at(2 * i).error(values), 0.5 * z @ z / LATENT_SIGMA**2, rtol=1e-12)


def test_one_batched_network_run_serves_every_state(tiny_vae):
    prior, graph, values = prior_graph(tiny_vae, pose_family(30, seed=12))
    graph.linearize(values)
    assert prior.decoder.evaluations == 1
    graph.error(values)  # the same latents: the cache answers
    assert prior.decoder.evaluations == 1
    values.update(pose_latent_key(7), np.zeros(4))
    graph.error(values)
    assert prior.decoder.evaluations == 2
    with pytest.raises(MocapgraphError, match="state 30 is not one of the prior's 30 states"):
        prior.factors(30)


def test_levenberg_marquardt_pulls_noisy_poses_onto_the_family(tiny_vae):
    truth = pose_family(40, seed=13)
    noisy = truth + np.random.default_rng(14).normal(scale=0.15, size=truth.shape)
    _, graph, values = prior_graph(tiny_vae, noisy)
    for i, theta in enumerate(noisy):  # the "measurement" of each pose
        graph.add(gtsam.PriorFactorVector(pose_key(i), theta, gtsam.noiseModel.Isotropic.Sigma(63, 0.15)))
    result = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    fitted = np.stack([result.atVector(pose_key(i)) for i in range(len(truth))])
    before, after = mean_geodesic(noisy, truth, MOVING), mean_geodesic(fitted, truth, MOVING)
    assert after < 0.6 * before


# ---------------------------------------------------------------------------------------------
# The shipped model


def test_shipped_weights_prefer_a_standing_pose_to_a_corrupted_one():
    vae = load_default_pose_vae()
    assert vae.latent == 32 and vae.body_model == "anny" and len(vae.joints) == 16
    assert vae.info["val_geodesic_err_rad"] < 0.15
    standing = neutral_pose().ravel()  # arms down
    axes = np.random.default_rng(0).normal(size=(21, 3))
    corrupted = standing + (axes / np.linalg.norm(axes, axis=1, keepdims=True)).ravel()  # 1 rad on every joint
    elbo_standing, elbo_corrupted = vae.elbo(np.stack([standing, corrupted]))
    assert elbo_standing > elbo_corrupted + 100
    err_standing, err_corrupted = vae.geodesic_error(np.stack([standing, corrupted]))
    assert err_standing < 0.5 * err_corrupted


def test_pose_grid_png(tmp_path):
    path = pose_grid_png(pose_family(4, seed=15), tmp_path / "grid.png", load_body_model("anny"), title="four")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and not list(tmp_path.glob("*.tmp.png"))
