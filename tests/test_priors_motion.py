"""The motion prior: canonical windows, the VAE (training, file format, ELBO) and its latent-variable factor."""

import json

import gtsam
import numpy as np
import pytest
import torch
from test_cmu_motion import write_take  # shared helpers (tests/ is on sys.path)
from test_factors import perturbed, random_shape, variable_dim

from mocapgraph.body import load_body_model
from mocapgraph.body.rotations import axis_rotation
from mocapgraph.data_tools.sim.motion_sources import procedural_motion
from mocapgraph.errors import MocapgraphError
from mocapgraph.factors.keys import ground_key, motion_frame_key, motion_latent_key, pose_key, root_key, shape_key
from mocapgraph.graphs.solver import SolverOptions, levenberg_marquardt
from mocapgraph.priors.latent import BatchedDecoder
from mocapgraph.priors.motion_factor import MotionVAEPrior
from mocapgraph.priors.motion_vae import (
    MotionVAE,
    MotionVAEConfig,
    MotionVAENet,
    fit_motion_vae,
    kl_weight,
    load_default_motion_vae,
    train_motion_vae,
)  # fmt: skip
from mocapgraph.priors.motion_windows import (
    CHANNELS,
    WINDOW,
    canonical_frame,
    feature_positions,
    load_motion_windows,
    motion_features,
    window_features,
    window_positions,
)  # fmt: skip


@pytest.fixture(scope="module", autouse=True)
def _one_thread(one_torch_thread):
    """Tiny networks: a second torch thread only adds contention (4–5× slower on a busy machine)."""


@pytest.fixture(scope="module")
def body():
    return load_body_model("anny")


@pytest.fixture(scope="module")
def walk():
    """A 2 s procedural walk on the default Anny body (61 states at 30 Hz)."""
    return procedural_motion("walk", 2.0, seed=3)


def _moved(root: np.ndarray, yaw: float, shift) -> np.ndarray:
    """``root (..., 4, 4)`` moved by a rotation ``yaw`` about world Z and a ground shift."""
    G = np.eye(4)
    G[:3, :3] = axis_rotation("z", yaw)
    G[:3, 3] = shift
    return G @ root


# --------------------------------------------------------------------------------------------
# Canonical windows


def test_features_are_invariant_to_yaw_and_ground_shift(body, walk):
    root, pose = walk.root[:WINDOW], walk.pose[:WINDOW]
    fk = body.forward(walk.shape, root, pose)
    features = window_features(fk.joints, fk.rotations, root[0])
    moved = _moved(root, 2.1, [3.0, -1.5, 0.0])
    fk2 = body.forward(walk.shape, moved, pose)
    np.testing.assert_allclose(window_features(fk2.joints, fk2.rotations, moved[0]), features, atol=1e-9)
    # Heights are the world's, the first root sits above the origin and faces +Y.
    positions = feature_positions(features)
    np.testing.assert_allclose(positions[..., 2], fk.joints[..., 2], atol=1e-12)
    np.testing.assert_allclose(positions[0, 0, :2], 0.0, atol=1e-12)
    yaw, origin = canonical_frame(root[0])
    forward = axis_rotation("z", yaw).T @ root[0, :3, 2]
    assert abs(forward[0]) < 1e-12 and forward[1] > 0 and origin[2] == 0.0
    # The 6D channels hold the first two columns of each canonical joint frame.
    R = axis_rotation("z", yaw).T @ fk.rotations[7, 4]
    np.testing.assert_allclose(features[7, 66 + 24 : 66 + 30], R[:, :2].T.ravel(), atol=1e-12)
    # Positions go back to the world exactly.
    np.testing.assert_allclose(window_positions(features, root[0]), fk.joints, atol=1e-12)


def test_windows_load_from_a_motion_directory_and_errors_name_it(tmp_path, body):
    write_take(tmp_path / "cmu_01_01.npz", frames=40, seed=0)
    write_take(tmp_path / "cmu_02_01_s0.npz", frames=30, seed=1)
    lines = []
    windows = load_motion_windows(tmp_path, body, stride=5, progress=lines.append)
    assert windows.features.shape == (4 + 2, WINDOW, CHANNELS) and windows.features.dtype == np.float32
    assert windows.subjects.tolist() == [1, 1, 1, 1, 2, 2] and lines
    with pytest.raises(MocapgraphError, match="nowhere: motion directory not found"):
        load_motion_windows(tmp_path / "nowhere", body)
    (tmp_path / "empty").mkdir()
    with pytest.raises(MocapgraphError, match="empty: no CMU takes"):
        load_motion_windows(tmp_path / "empty", body)


# --------------------------------------------------------------------------------------------
# The VAE


def _synthetic_windows(n: int, seed: int) -> np.ndarray:
    """``(n, 25, 198)`` windows of a 3-parameter family: per-channel sinusoids of a random phase
    and amplitude plus a random offset along a fixed direction."""
    rng = np.random.default_rng(seed)
    fixed = np.random.default_rng(99)
    a, b, c = fixed.normal(size=(3, CHANNELS)) * [[0.2], [0.2], [0.3]]
    t = np.arange(WINDOW)[:, None] / 10.0
    phase, amp, offset = rng.uniform(0, 2 * np.pi, n), rng.uniform(0.5, 1.5, n), rng.normal(size=n)
    s, co = np.sin(t + phase[:, None, None]), np.cos(t + phase[:, None, None])
    return (amp[:, None, None] * (s * a + co * b) + offset[:, None, None] * c).astype(np.float32)


TINY = MotionVAEConfig(width=32, latent=4, blocks=1)


def test_tiny_vae_reconstructs_synthetic_windows_better_than_their_mean():
    train, val = _synthetic_windows(512, 0), _synthetic_windows(128, 1)
    lines = []
    vae = fit_motion_vae(train, val, TINY, epochs=12, cycle=6, batch_size=32, learning_rate=3e-3, progress=lines.append)
    baseline = np.linalg.norm(feature_positions(val) - feature_positions(train.mean(axis=0)), axis=-1).mean()
    assert vae.info["val_mpjpe_m"] < 0.3 * baseline
    assert len(lines) == 12 and lines[2].startswith("epoch 3/12: loss ") and "val mpjpe" in lines[2]
    assert vae.sigma.shape == (WINDOW, CHANNELS) and np.all(vae.sigma >= 0.01)
    assert vae.info["train_windows"] == 512 and vae.info["val_windows"] == 128
    # Real (in-family) windows get a higher ELBO than the same windows with noise.
    noisy = val + np.random.default_rng(2).normal(scale=0.2, size=val.shape)
    assert vae.elbo(val).mean() > vae.elbo(noisy).mean()
    assert vae.sample(3, seed=0).shape == (3, WINDOW, CHANNELS)


def test_training_is_deterministic_under_a_seed():
    train, val = _synthetic_windows(96, 0), _synthetic_windows(16, 1)

    def weights(seed):
        vae = fit_motion_vae(train, val, TINY, epochs=2, seed=seed, batch_size=32)
        return np.concatenate([p.detach().numpy().ravel() for p in vae.net.parameters()])

    first = weights(5)
    np.testing.assert_array_equal(weights(5), first)
    assert not np.allclose(weights(6), first)


def test_kl_weight_ramps_over_half_a_cycle_then_stays():
    assert kl_weight(0.0, 0.01, 20) == 0.0
    assert np.isclose(kl_weight(5.0, 0.01, 20), 0.005)
    assert kl_weight(10.0, 0.01, 20) == kl_weight(19.9, 0.01, 20) == 0.01
    assert np.isclose(kl_weight(25.0, 0.01, 20), 0.005)


def _random_vae(config=TINY, seed=0) -> MotionVAE:
    """An untrained network with a plausible normalisation (heights about 1 m)."""
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        net = MotionVAENet(config)
    rng = np.random.default_rng(seed)
    mean = rng.normal(scale=0.3, size=CHANNELS)
    mean[2:66:3] += 1.0
    return MotionVAE(net, mean, rng.uniform(0.05, 0.3, CHANNELS), rng.uniform(0.02, 0.05, (WINDOW, CHANNELS)))


def test_save_and_load_round_trip_and_errors(tmp_path):
    vae = _random_vae()
    vae = MotionVAE(vae.net, vae.mean, vae.std, vae.sigma, info={"val_mpjpe_m": 0.03})
    z = np.random.default_rng(0).normal(size=(3, TINY.latent))
    exact = MotionVAE.load(vae.save(tmp_path / "m32.npz", dtype=np.float32))
    np.testing.assert_array_equal(exact.decode(z), vae.decode(z))
    assert exact.info == {"val_mpjpe_m": 0.03} and exact.config == TINY
    half = MotionVAE.load(vae.save(tmp_path / "m16.npz"))
    np.testing.assert_allclose(half.decode(z), vae.decode(z), atol=5e-3)
    assert not list(tmp_path.glob("*.tmp*"))

    with pytest.raises(MocapgraphError, match="nope.npz: motion VAE file not found"):
        MotionVAE.load(tmp_path / "nope.npz")
    with np.load(tmp_path / "m32.npz") as d:
        arrays = dict(d)
    for key, change, message in [
        ("sigma", None, "missing key 'sigma'"),
        ("state/decoder_out.bias", None, "missing key 'state/decoder_out.bias'"),
        ("format_version", 99, "format_version 99"),
        ("config", json.dumps({"width": 16, "latent": 4, "blocks": 1}), "key 'state/encoder_in.weight' has shape"),
        ("config", json.dumps({"width": 16}) + "}", "unreadable 'config'"),
    ]:
        broken = {k: v for k, v in arrays.items() if k != key}
        if change is not None:
            broken[key] = change
        np.savez(tmp_path / "broken.npz", **broken)
        with pytest.raises(MocapgraphError, match=f"broken.npz: .*{message}"):
            MotionVAE.load(tmp_path / "broken.npz")
    (tmp_path / "junk.npz").write_text("not a zip")
    with pytest.raises(MocapgraphError, match="junk.npz: not a readable motion VAE"):
        MotionVAE.load(tmp_path / "junk.npz")


def test_train_motion_vae_splits_by_subject_and_records_the_run(tmp_path, body):
    for subject in (1, 2, 3):
        write_take(tmp_path / f"cmu_{subject:02d}_01.npz", frames=35, seed=subject)
    vae = train_motion_vae(tmp_path, body, width=16, latent=4, epochs=1, seed=0, stride=5, val_fraction=0.34, blocks=1)
    info = vae.info
    assert len(info["val_subjects"]) == 1 and info["train_subjects"] == 2
    assert info["train_windows"] + info["val_windows"] == 9 and info["data"] == tmp_path.name
    assert vae.body_model == "anny" and info["val_mpjpe_m"] > 0


# --------------------------------------------------------------------------------------------
# The factor


def _state_values(root: np.ndarray, pose: np.ndarray, shape) -> gtsam.Values:
    values = gtsam.Values()
    for i in range(len(root)):
        values.insert(root_key(i), gtsam.Pose3(root[i]))
        values.insert(pose_key(i), pose[i].ravel())
    if shape is not None:
        values.insert(shape_key(), np.asarray(shape, dtype=float))
    return values


def _numeric_jacobian(factor, values: gtsam.Values, key: int, h: float) -> np.ndarray:
    """Central differences of the whitened error along ``key``'s retraction (Pose3: its tangent)."""
    columns = []
    for j in range(variable_dim(values, key)):
        step = np.zeros(variable_dim(values, key))
        step[j] = h
        plus, minus = (factor.whitenedError(perturbed(values, key, s)) for s in (step, -step))
        columns.append((plus - minus) / (2 * h))
    return np.stack(columns, axis=1)


@pytest.mark.parametrize("with_shape", [True, False])
def test_frame_factor_jacobians_match_central_differences(body, walk, with_shape):
    vae = _random_vae()
    rng = np.random.default_rng(4)
    root = walk.root[:30].copy()
    # Tilt the roots a little so the yaw's derivative sees a forward axis off the ground plane.
    for i in range(len(root)):
        root[i, :3, :3] = root[i, :3, :3] @ axis_rotation("x", 0.3) @ axis_rotation("z", 0.2)
    pose = walk.pose[:30] + rng.normal(scale=0.1, size=walk.pose[:30].shape)
    # Away from the default shape: Anny's shape map has kinks at its anchors.
    shape = random_shape(body, rng)
    values = _state_values(root, pose, shape if with_shape else None)
    # A tilted, raised ground about a pivot, so every term of the ground's Jacobian is exercised.
    values.insert(ground_key(), np.array([0.05, -0.08, 0.3]))
    prior = MotionVAEPrior(vae, body, [0, 3], **({"shape_key": shape_key()} if with_shape else {"fixed_shape": shape}))
    prior.ground_pivot = np.array([0.4, -1.1])
    for w, frame in enumerate(prior.initial_frames(values)):
        values.insert(motion_latent_key(w), rng.normal(size=TINY.latent))
        # Off the tie's optimum, so every term of the frame's Jacobian is exercised.
        values.insert(motion_frame_key(w), frame + rng.normal(scale=[0.05, 0.05, 0.1]))
    # BatchedDecoder feeds float32 latents; a float64 network after that keeps the differences in
    # z (with a step large enough for float32 latents) free of the network's rounding.
    vae.net.double()
    prior.decoder.fn = lambda z: vae.decode_positions(z.double())
    for w, t in [(0, 0), (1, 0), (1, 7), (0, 24)]:
        factor = prior.frame_factor(w, t)
        keys = list(factor.keys())
        assert len(keys) == len(set(keys)) == 6 - (not with_shape)
        assert keys[:5] == [motion_latent_key(w), motion_frame_key(w), ground_key(), root_key(3 * w + t), pose_key(3 * w + t)]
        A, b = factor.linearize(values).jacobian()
        np.testing.assert_allclose(-b, factor.whitenedError(values), atol=1e-9)
        column = 0
        for key in keys:
            latent = key == motion_latent_key(w)
            numeric = _numeric_jacobian(factor, values, key, 1e-3 if latent else 1e-6)
            analytic = A[:, column : column + numeric.shape[1]]
            tol = (1e-4 if latent else 2e-6) * np.abs(numeric).max()
            np.testing.assert_allclose(analytic, numeric, atol=tol, err_msg=gtsam.DefaultKeyFormatter(key))
            column += numeric.shape[1]


@pytest.mark.parametrize("yaw", [0.4, np.pi - 1e-4, -np.pi + 1e-4])
def test_tie_factor_jacobians_match_central_differences_and_wrap_the_yaw(body, walk, yaw):
    """Yaw near ±π: the frame's yaw sits on the other side of the cut, the residual stays small."""
    root = walk.root[:1].copy()
    root[0, :3, :3] = axis_rotation("x", 0.3) @ axis_rotation("z", 0.2) @ root[0, :3, :3]
    # Turn the root about world Z so its canonical yaw is `yaw`.
    current, _ = canonical_frame(root[0])
    root = _moved(root, yaw - current, [0.7, -0.2, 0.0])
    values = _state_values(root, walk.pose[:1], None)
    values.insert(ground_key(), np.zeros(3))
    prior = MotionVAEPrior(_random_vae(), body, [0], fixed_shape=body.default_shape)
    frame = prior.initial_frames(values)[0]
    assert abs(frame[2] - yaw) < 1e-9
    # Then tilt and raise the ground a little, about a pivot: the frame follows the root seen from it.
    values.update(ground_key(), np.array([0.03, -0.02, 0.2]))
    prior.ground_pivot = np.array([-0.5, 2.0])
    frame = prior.initial_frames(values)[0]
    # Across the cut: the frame's yaw 2π away, plus a small offset on every row.
    offset = np.array([2e-4, -3e-4, 5e-4])
    values.insert(motion_frame_key(0), frame + offset - [0.0, 0.0, 2 * np.pi * np.sign(yaw)])
    factor = prior.tie_factor(0)
    assert list(factor.keys()) == [motion_frame_key(0), ground_key(), root_key(0)]
    np.testing.assert_allclose(factor.unwhitenedError(values), offset, atol=1e-9)
    A, b = factor.linearize(values).jacobian()
    np.testing.assert_allclose(-b, factor.whitenedError(values), atol=1e-6)
    column = 0
    for key in factor.keys():
        numeric = _numeric_jacobian(factor, values, key, 1e-6)
        np.testing.assert_allclose(A[:, column : column + numeric.shape[1]], numeric, atol=1e-5 * np.abs(numeric).max())
        column += numeric.shape[1]


def test_one_batched_decoder_run_per_linearisation(body, walk):
    vae = _random_vae()
    values = _state_values(walk.root[:40], walk.pose[:40], body.default_shape)
    prior = MotionVAEPrior(vae, body, [0, 5, 15], shape_key=shape_key())
    graph = gtsam.NonlinearFactorGraph()
    prior.add_to(graph, values)
    assert graph.size() == 1 + 3 * (2 + WINDOW) and values.exists(motion_latent_key(2))
    np.testing.assert_array_equal(values.atVector(ground_key()), np.zeros(3))
    # The ground turns about where the person is: the mean of the windows' first roots.
    np.testing.assert_allclose(prior.ground_pivot, walk.root[[0, 5, 15], :2, 3].mean(0), atol=1e-12)
    # The canonical frames start at their first roots' (origins from the pivot), the tie factors at zero.
    yaw, origin = canonical_frame(walk.root[5])
    expected = [origin[0] - prior.ground_pivot[0], origin[1] - prior.ground_pivot[1], yaw]
    np.testing.assert_allclose(values.atVector(motion_frame_key(1)), expected, atol=1e-12)
    assert prior.tie_factor(1).error(values) < 1e-20
    # The latents start at the encoder's μ of the current windows.
    starts = np.array([0, 5, 15])
    expected = vae.encode(motion_features(body, walk.root[:40], walk.pose[:40], starts))[0]
    np.testing.assert_allclose(values.atVector(motion_latent_key(1)), expected[1], atol=1e-9)
    graph.linearize(values)
    assert prior.decoder.evaluations == 1
    graph.error(values)
    assert prior.decoder.evaluations == 1
    values.update(motion_latent_key(0), values.atVector(motion_latent_key(0)) + 0.1)
    graph.linearize(values)
    assert prior.decoder.evaluations == 2


def test_chunked_jacobians_equal_the_one_pass_ones():
    vae = _random_vae()
    keys = [motion_latent_key(w) for w in range(11)]
    values = gtsam.Values()
    for key, z in zip(keys, np.random.default_rng(0).normal(size=(11, TINY.latent))):
        values.insert(key, z)
    whole, chunked = (BatchedDecoder(vae.decode_positions, keys, TINY.latent, chunk_size=c) for c in (None, 4))
    for key in keys:
        # float32 batches of 4 and of 11 sum in different orders: ulps of the Jacobian's scale
        J = whole(values, key, True)[1]
        np.testing.assert_allclose(chunked(values, key, True)[1], J, rtol=0, atol=256 * np.finfo(np.float32).eps * np.abs(J).max())
    assert chunked.evaluations == whole.evaluations == 1


def test_prior_rejects_bad_arguments(body):
    vae = _random_vae()
    with pytest.raises(MocapgraphError, match="exactly one of shape_key and fixed_shape"):
        MotionVAEPrior(vae, body, [0])
    with pytest.raises(MocapgraphError, match="window_starts"):
        MotionVAEPrior(vae, body, [-1], shape_key=shape_key())
    with pytest.raises(MocapgraphError, match="ground_sigmas"):
        MotionVAEPrior(vae, body, [0], shape_key=shape_key(), ground_sigmas=(0.05, float("nan")))
    with pytest.raises(MocapgraphError, match="body state 3"):
        three_states = _state_values(np.tile(np.eye(4), (3, 1, 1)), np.zeros((3, 63)), body.default_shape)
        MotionVAEPrior(vae, body, [0], shape_key=shape_key()).initial_latents(three_states)


# --------------------------------------------------------------------------------------------
# The shipped model


@pytest.fixture(scope="module")
def shipped():
    return load_default_motion_vae()


def _corrupted(walk, kind: str, rng) -> tuple[np.ndarray, np.ndarray]:
    root, pose = walk.root.copy(), walk.pose.copy()
    if kind == "jitter":
        pose += rng.normal(scale=0.12, size=pose.shape)
        root[:, :3, 3] += rng.normal(scale=0.02, size=root[:, :3, 3].shape)
    elif kind == "foot skating":
        # The body glides sideways at 1 m/s on top of its walk: planted feet slide.
        root[:, :3, 3] += np.outer(np.arange(len(root)) / walk.fps, root[0, :3, 0])
    elif kind == "90° root flip":
        # Every 25 frames' second half turned by 90° about the vertical through the pelvis.
        turned = np.arange(len(root)) % WINDOW >= WINDOW // 2
        root[turned, :3, :3] = axis_rotation("z", np.pi / 2) @ root[turned, :3, :3]
    return root, pose


def test_shipped_model_scores_real_windows_above_corrupted_ones(body, walk, shipped):
    starts = np.arange(0, len(walk.root) - WINDOW + 1, WINDOW)
    real = shipped.elbo(motion_features(body, walk.root, walk.pose, starts))
    rng = np.random.default_rng(0)
    for kind in ("jitter", "foot skating", "90° root flip"):
        root, pose = _corrupted(walk, kind, rng)
        corrupted = shipped.elbo(motion_features(body, root, pose, starts))
        assert real.mean() > corrupted.mean() + 200, kind
    assert shipped.info["val_mpjpe_m"] < 0.03 and shipped.latent_dim == shipped.info["latent"]


def test_lm_pulls_a_jittered_walk_toward_the_prior(body, walk, shipped):
    """The jittered walk plus weak data terms: the prior smooths it back toward the clean walk."""
    n = WINDOW
    rng = np.random.default_rng(1)
    root, pose = _corrupted(walk, "jitter", rng)
    root, pose = root[:n], pose[:n]
    values = _state_values(root, pose, None)
    graph = gtsam.NonlinearFactorGraph()
    for i in range(n):
        graph.add(gtsam.PriorFactorPose3(root_key(i), gtsam.Pose3(root[i]), gtsam.noiseModel.Isotropic.Sigma(6, 0.05)))
        graph.add(gtsam.PriorFactorVector(pose_key(i), pose[i].ravel(), gtsam.noiseModel.Isotropic.Sigma(63, 0.15)))
    prior = MotionVAEPrior(shipped, body, [0], fixed_shape=body.default_shape)
    prior.add_to(graph, values)
    before = prior.frame_factor(0, 12).error(values)
    result = levenberg_marquardt(graph, values, SolverOptions(max_iterations=15))
    solved = result.values
    joints = lambda r, p: body.forward(walk.shape, r, p).joints  # noqa: E731
    clean = joints(walk.root[:n], walk.pose[:n])
    start_error = np.linalg.norm(joints(root, pose) - clean, axis=-1).mean()
    roots = np.stack([solved.atPose3(root_key(i)).matrix() for i in range(n)])
    poses = np.stack([solved.atVector(pose_key(i)) for i in range(n)]).reshape(n, 21, 3)
    end_error = np.linalg.norm(joints(roots, poses) - clean, axis=-1).mean()
    assert prior.frame_factor(0, 12).error(solved) < 0.5 * before
    assert end_error < 0.8 * start_error


def test_the_ground_variable_finds_a_raised_tilted_ground(body, walk, shipped):
    """The walk on a ground raised 0.1 m and tilted 0.05 rad about X through the person, the body
    held: the ground variable moves by that much against the walk on the world's z = 0."""
    starts = [0, 25, 36]
    pivot = walk.root[starts, :2, 3].mean(0)
    ground = np.eye(4)
    ground[:3, :3] = axis_rotation("x", 0.05)
    ground[:3, 3] = np.array([pivot[0], pivot[1], 0.1]) - ground[:3, :3] @ [pivot[0], pivot[1], 0.0]
    solved = []
    for root in (walk.root, ground @ walk.root):
        values = _state_values(root, walk.pose, None)
        graph = gtsam.NonlinearFactorGraph()
        for i in range(len(root)):
            graph.add(gtsam.PriorFactorPose3(root_key(i), gtsam.Pose3(root[i]), gtsam.noiseModel.Isotropic.Sigma(6, 1e-5)))
            graph.add(gtsam.PriorFactorVector(pose_key(i), walk.pose[i].ravel(), gtsam.noiseModel.Isotropic.Sigma(63, 1e-5)))
        prior = MotionVAEPrior(shipped, body, starts, fixed_shape=walk.shape, ground_sigmas=(1.0, 1.0))
        prior.add_to(graph, values)
        # The pivot is the windows' first roots (tilted, they move 4 cm: 2 mm of the ground's height).
        np.testing.assert_allclose(prior.ground_pivot, root[starts, :2, 3].mean(0), atol=1e-12)
        solved.append(levenberg_marquardt(graph, values, SolverOptions(max_iterations=30)).values.atVector(ground_key()))
    np.testing.assert_allclose(solved[1] - solved[0], [0.05, 0.0, 0.1], atol=0.01)


def test_motion_windows_png_draws_the_shipped_samples(tmp_path, shipped):
    from mocapgraph.priors.plots import motion_windows_png

    path = motion_windows_png(feature_positions(shipped.sample(2, seed=0)), tmp_path / "strips.png", title="samples")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and not list(tmp_path.glob("*.tmp*"))
