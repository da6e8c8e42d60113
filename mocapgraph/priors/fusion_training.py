"""Training and evaluating the fusion regressor on synthetic views of CMU motion.

**Bodies.** Every ``stride``-th frame of the CMU takes, retargeted onto the body
(:func:`mocapgraph.data_tools.sim.cmu_motion.retarget`), stood at the world origin (the take's root
height and orientation kept), with a shape drawn uniformly within the body's bounds except Anny's
age, drawn within ``ADULT_AGE`` (one shape per run of ``frames_per_shape`` frames, so posing stays
one call per shape). Without that restriction a quarter of the bodies are babies and toddlers
(nose to ankle 0.3–0.9 m against 0.9–2.2 m for the others), whom keypoints alone cannot tell from an
adult 2–4 times as far away; the captures are of adults. Whole subjects are held
out (:func:`mocapgraph.priors.training.held_out_split`; seed 0 holds out the pose priors' subjects).

**Views** (drawn afresh for every batch, so the network never sees the same camera twice):
each camera at 5–20 m from the root, 0–45° above it (overhead views included), any yaw around
the person, aimed at the root and then panned and tilted so the person may sit anywhere in the
central 70 % of a 1920×1080 image, rolled by up to 5°; focal length 900–1600 px, principal point
within 20 px of the centre. A view is redrawn while fewer than 12 of the 17 COCO points fall in
the image. The projected points get Gaussian noise of σ = 2–5 px plus 0–2 % of the box size,
confidences uniform in [0.3, 1], and 5 % of them go missing (NaN), besides those outside the image.

**Loss** (on every stage, as HMR and AirPose): squared Frobenius distance of the root's and the
joints' rotation matrices, L1 of the root-relative joint positions in the camera frame (m, the
true shape's skeleton posed by the estimate), L1 of ``(x/z, y/z)`` and of ``log z`` of the root,
and squared error of the normalised shape; over the valid views of 1–3-view samples.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from mocapgraph.body.model import BodyModel
from mocapgraph.body.rotations import axis_rotation, relative_angle, rotvec_to_matrix
from mocapgraph.body.skeleton import PARENTS
from mocapgraph.priors.fusion_regressor import (
    ESTIMATE,
    POSE,
    ROOT,
    SHAPE,
    TRANSL,
    VARIANTS,
    FusionNet,
    FusionRegressor,
    crop_features,
    decode,
    load_default_fusion_regressor,
)  # fmt: skip
from mocapgraph.priors.pose_vae import rotmat_to_sixd
from mocapgraph.priors.training import held_out_split, take_files, take_subject
from mocapgraph.priors.views import ViewEstimate

IMAGE = (1920, 1080)
ADULT_AGE = (0.5, 1.0)
"""Range of Anny's age phenotype for training bodies: teenager (0.5) to old (1)."""
MIN_IN_IMAGE = 12
VIEW_COUNTS = (1, 2, 3)
VIEW_COUNT_PROBS = (0.15, 0.6, 0.25)


@dataclass
class BodyFrames:
    """Posed bodies in a Z-up world: ``world_T_root (N, 4, 4)``, ``pose (N, 21, 3)``, ``shape (N, S)``,
    ``keypoints (N, 17, 3)`` and ``joints (N, 22, 3)`` (world, m), ``rest (N, 22, 3)`` the shape's
    neutral joints (body frame), ``subjects (N,)`` CMU ids."""

    world_T_root: np.ndarray
    pose: np.ndarray
    shape: np.ndarray
    keypoints: np.ndarray
    joints: np.ndarray
    rest: np.ndarray
    subjects: np.ndarray

    def __len__(self) -> int:
        return len(self.pose)

    def take(self, idx) -> BodyFrames:
        return BodyFrames(*(getattr(self, k)[idx] for k in self.__dataclass_fields__))


def load_body_frames(
    files: list[Path], body: BodyModel, stride: int = 4, frames_per_shape: int = 20, seed: int = 0, progress=None
) -> BodyFrames:
    """Every ``stride``-th frame of the take ``files``, retargeted, with random shapes (module docstring)."""
    from mocapgraph.data_tools.sim.cmu_motion import load_cmu_take, retarget

    rng = np.random.default_rng(seed)
    roots, poses, subjects = [], [], []
    for i, path in enumerate(files):
        root, pose = retarget(load_cmu_take(path), body)
        roots.append(root[::stride])
        poses.append(pose[::stride])
        subjects.append(np.full(len(poses[-1]), take_subject(path)))
        if progress is not None and ((i + 1) % 200 == 0 or i + 1 == len(files)):
            progress(f"loaded {i + 1}/{len(files)} takes")
    root, pose, subjects = np.concatenate(roots), np.concatenate(poses), np.concatenate(subjects)
    root[:, :2, 3] = 0.0
    lo, hi = body.shape_bounds.T.copy()
    if "age" in body.shape_names:
        i = body.shape_names.index("age")
        lo[i], hi[i] = max(lo[i], ADULT_AGE[0]), min(hi[i], ADULT_AGE[1])
    shape = np.empty((len(pose), len(lo)))
    keypoints, joints, rest = np.empty((len(pose), 17, 3)), np.empty((len(pose), 22, 3)), np.empty((len(pose), 22, 3))
    for start in range(0, len(pose), frames_per_shape):
        run = slice(start, start + frames_per_shape)
        s = rng.uniform(lo, hi)
        fk = body.forward(s, root[run], pose[run], keypoints="coco17")
        shape[run], keypoints[run], joints[run], rest[run] = s, fk.keypoints, fk.joints, body.rest_joints(s)
    return BodyFrames(root, pose, shape, keypoints, joints, rest, subjects)


def split_frames(motion_dir, body: BodyModel, val_fraction: float = 0.2, seed: int = 0, stride: int = 4, progress=None):
    """``(training frames, held-out frames, held-out subjects)`` of the takes in ``motion_dir``;
    the held-out frames are :func:`held_out_frames` ``(…, held-out subjects, stride, seed)``."""
    files = take_files(motion_dir)
    subjects = np.array([take_subject(p) for p in files])
    val, held_out = held_out_split(subjects, val_fraction, seed, "takes", progress)
    train = load_body_frames([p for p, v in zip(files, val) if not v], body, stride, seed=seed, progress=progress)
    return train, held_out_frames(motion_dir, body, held_out, stride, seed, progress), held_out


def held_out_frames(motion_dir, body: BodyModel, subjects, stride: int = 4, seed: int = 0, progress=None) -> BodyFrames:
    """The frames of the takes of ``subjects`` in ``motion_dir``, as :func:`split_frames` evaluates
    a model trained with ``seed`` (the shapes drawn with ``seed + 1``)."""
    files = [p for p in take_files(motion_dir) if take_subject(p) in set(subjects)]
    return load_body_frames(files, body, stride, seed=seed + 1, progress=progress)


def ablation(motion_dir, body: BodyModel, variants=VARIANTS, views=(1, 2, 3), samples: int = 1000, seed: int = 0) -> list[dict]:
    """:func:`evaluate_fusion` of the shipped weights of every variant with every number of views,
    on the held-out subjects of the full model's file: one row per (variant, views) with its scores."""
    regressors = {v: load_default_fusion_regressor(v) for v in variants}
    info = regressors[variants[0]].info
    frames = held_out_frames(motion_dir, body, info["val_subjects"], info["stride"], info["seed"])
    return [
        {"variant": variant, "views": n, **evaluate_fusion(regressor, frames, body, samples=samples, views=n, seed=seed)}
        for n in views
        for variant, regressor in regressors.items()
    ]


def _look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """``(N, 3, 3)`` world_R_camera, OpenCV axes, looking from ``eye`` at ``target`` with world +Z up."""
    z = target - eye
    z /= np.linalg.norm(z, axis=-1, keepdims=True)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x, axis=-1, keepdims=True)
    return np.stack([x, np.cross(z, x), z], axis=-1)


def sample_cameras(target: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``world_T_camera (N, 4, 4)`` and ``K (N, 3, 3)`` of one random camera aimed near each ``target (N, 3)``."""
    n = len(target)
    distance, pitch = rng.uniform(5.0, 20.0, n), np.radians(rng.uniform(0.0, 45.0, n))
    yaw = rng.uniform(-np.pi, np.pi, n)
    eye = target + distance[:, None] * np.stack([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)], -1)
    f = rng.uniform(900.0, 1600.0, n)
    # Pan and tilt within the angles that keep the root in the central 70 % of the image.
    pan = rng.uniform(-1, 1, n) * np.arctan(0.35 * IMAGE[0] / f)
    tilt = rng.uniform(-1, 1, n) * np.arctan(0.35 * IMAGE[1] / f)
    roll = np.radians(rng.uniform(-5.0, 5.0, n))
    world_T_camera = np.tile(np.eye(4), (n, 1, 1))
    world_T_camera[:, :3, :3] = _look_at(eye, target) @ axis_rotation("y", pan) @ axis_rotation("x", tilt) @ axis_rotation("z", roll)
    world_T_camera[:, :3, 3] = eye
    K = np.tile(np.eye(3), (n, 1, 1))
    K[:, 0, 0] = K[:, 1, 1] = f
    K[:, :2, 2] = np.array(IMAGE) / 2 + rng.uniform(-20.0, 20.0, (n, 2))
    return world_T_camera, K


def project(points: np.ndarray, world_T_camera: np.ndarray, K: np.ndarray) -> np.ndarray:
    """``(N, P, 2)`` pixels of world ``points (N, P, 3)`` in cameras ``(N, 4, 4)``, ``K (N, 3, 3)``."""
    p = np.einsum("nji,npj->npi", world_T_camera[:, :3, :3], points - world_T_camera[:, None, :3, 3])
    uv = p[..., :2] / p[..., 2:3]
    return uv * K[:, None, [0, 1], [0, 1]] + K[:, None, :2, 2]


def _in_image(uv: np.ndarray) -> np.ndarray:
    return (uv[..., 0] >= 0) & (uv[..., 0] < IMAGE[0]) & (uv[..., 1] >= 0) & (uv[..., 1] < IMAGE[1])


@dataclass
class SyntheticViews:
    """``V`` view slots per body: ``keypoints (N, V, 17, 3)`` noisy pixels and confidence (NaN
    missing), ``K (N, V, 3, 3)``, ``world_T_camera (N, V, 4, 4)``, ``present (N, V)`` slot in use."""

    keypoints: np.ndarray
    K: np.ndarray
    world_T_camera: np.ndarray
    present: np.ndarray


def render_views(frames: BodyFrames, views, rng: np.random.Generator, missing: float = 0.05) -> SyntheticViews:
    """Random cameras and noisy keypoints for every body (module docstring). ``views`` is the number
    of cameras, an int or ``(N,)`` ints; slots beyond a body's count are absent (all NaN)."""
    n = len(frames)
    counts = np.broadcast_to(np.asarray(views), (n,))
    V = int(counts.max())
    target = frames.world_T_root[:, :3, 3]
    world_T_camera, K = np.empty((n, V, 4, 4)), np.empty((n, V, 3, 3))
    uv = np.empty((n, V, 17, 2))
    for v in range(V):
        todo = np.arange(n)
        # Redraw the cameras that see too little of the person; a handful of rounds suffices.
        for _ in range(20):
            world_T_camera[todo, v], K[todo, v] = sample_cameras(target[todo], rng)
            uv[todo, v] = project(frames.keypoints[todo], world_T_camera[todo, v], K[todo, v])
            todo = todo[_in_image(uv[todo, v]).sum(-1) < MIN_IN_IMAGE]
            if len(todo) == 0:
                break
    size = (uv.max(-2) - uv.min(-2)).max(-1)
    sigma = rng.uniform(2.0, 5.0, (n, V)) + rng.uniform(0.0, 0.02, (n, V)) * size
    uv = uv + sigma[..., None, None] * rng.standard_normal(uv.shape)
    keypoints = np.concatenate([uv, rng.uniform(0.3, 1.0, uv.shape[:-1] + (1,))], axis=-1)
    present = np.arange(V) < counts[:, None]
    gone = ~_in_image(uv) | (rng.random(uv.shape[:-1]) < missing) | ~present[..., None]
    keypoints[gone] = np.nan
    return SyntheticViews(keypoints, K, world_T_camera, present)


def camera_T_root(frames: BodyFrames, synthetic: SyntheticViews) -> np.ndarray:
    """``(N, V, 4, 4)`` the true root in every camera's frame."""
    return np.linalg.inv(synthetic.world_T_camera) @ frames.world_T_root[:, None]


def root_relative_joints(rest: torch.Tensor, R_root: torch.Tensor, R_pose: torch.Tensor) -> torch.Tensor:
    """``(..., 22, 3)`` joints minus the root, in the frame of ``R_root (..., 3, 3)``, for the
    skeleton ``rest (..., 22, 3)`` posed by local rotations ``R_pose (..., 21, 3, 3)``."""
    batch = torch.broadcast_shapes(R_root.shape[:-2], rest.shape[:-2])
    G, J = [R_root], [torch.zeros(batch + (3,), dtype=rest.dtype)]
    for c in range(1, len(PARENTS)):
        p = PARENTS[c]
        J.append(J[p] + (G[p] @ (rest[..., c, :] - rest[..., p, :])[..., None])[..., 0])
        G.append(G[p] @ R_pose[..., c - 1, :, :])
    return torch.stack(J, dim=-2)


def _targets(frames: BodyFrames, c_T_r: np.ndarray, shape_bounds: np.ndarray) -> dict[str, torch.Tensor]:
    R_pose = torch.as_tensor(rotvec_to_matrix(frames.pose), dtype=torch.float32)
    R_root = torch.as_tensor(c_T_r[..., :3, :3], dtype=torch.float32)
    t = c_T_r[..., :3, 3]
    lo, hi = shape_bounds.T
    rest = torch.as_tensor(frames.rest, dtype=torch.float32)[:, None]
    return {
        "R_root": R_root,
        "R_pose": R_pose[:, None].expand(R_root.shape[:2] + R_pose.shape[1:]),
        "shape": torch.as_tensor((frames.shape - lo) / (hi - lo), dtype=torch.float32)[:, None],
        "transl": torch.as_tensor(np.concatenate([t[..., :2] / t[..., 2:], np.log(t[..., 2:])], -1), dtype=torch.float32),
        "rest": rest,
        "joints": root_relative_joints(rest, R_root, R_pose[:, None]),
    }


def _mean_estimate(targets: dict[str, torch.Tensor]) -> torch.Tensor:
    """``(ESTIMATE,)`` the targets' mean, the network's starting estimate."""
    out = torch.empty(ESTIMATE)
    out[ROOT] = rotmat_to_sixd(targets["R_root"]).mean((0, 1))
    out[POSE] = rotmat_to_sixd(targets["R_pose"]).mean((0, 1)).reshape(-1)
    out[SHAPE] = targets["shape"].mean((0, 1))
    out[TRANSL] = targets["transl"].mean((0, 1))
    return out


def fusion_loss(estimate: torch.Tensor, targets: dict[str, torch.Tensor], mask: torch.Tensor) -> tuple[torch.Tensor, dict[str, float]]:
    """Mean over the ``mask (B, V)`` views of the loss of the module docstring for ``estimate (B, V, ESTIMATE)``."""
    R_root, R_pose, shape, _ = decode(estimate)
    joints = root_relative_joints(targets["rest"], R_root, R_pose)
    t, t_true = estimate[..., TRANSL], targets["transl"]
    terms = {
        "root": torch.square(R_root - targets["R_root"]).sum((-1, -2)),
        "pose": torch.square(R_pose - targets["R_pose"]).sum((-1, -2)).mean(-1),
        "joints": 5.0 * torch.linalg.norm(joints - targets["joints"], dim=-1).mean(-1),
        "centre": 10.0 * torch.abs(t[..., :2] - t_true[..., :2]).sum(-1),
        "depth": 2.0 * torch.abs(t[..., 2] - t_true[..., 2]),
        "shape": torch.square(shape - targets["shape"]).sum(-1),
    }
    w = mask.float() / mask.float().sum().clamp(min=1.0)
    means = {k: (v * w).sum() for k, v in terms.items()}
    return sum(means.values()), {k: float(v.detach()) for k, v in means.items()}


def _batch(frames: BodyFrames, views, rng, shape_bounds):
    synthetic = render_views(frames, views, rng)
    features, valid = crop_features(synthetic.keypoints, synthetic.K)
    targets = _targets(frames, camera_T_root(frames, synthetic), shape_bounds)
    return torch.as_tensor(features, dtype=torch.float32), torch.as_tensor(valid), targets


def fit_fusion_regressor(
    train: BodyFrames,
    shape_bounds: np.ndarray,
    variant: str = "full",
    width: int = 448,
    epochs: int = 28,
    samples: int = 32768,
    batch: int = 256,
    lr: float = 1e-3,
    seed: int = 0,
    body_model: str = "anny",
    progress: Callable[[str], None] | None = None,
) -> FusionRegressor:
    """Train a :class:`FusionRegressor` of ``variant`` with Adam on fresh synthetic views.

    Each epoch draws ``samples`` bodies of ``train`` with 1–3 views each (mostly 2); the rate
    decays to 0 by a cosine over the ``epochs × samples / batch`` steps. ``seed`` seeds the
    weights and every draw: the same seed (and torch thread count) gives the same model.
    """
    start = time.perf_counter()
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    net = FusionNet(variant, width)
    probe = train.take(rng.integers(len(train), size=4096))
    with torch.no_grad():
        net.mean.copy_(_mean_estimate(_batch(probe, 1, rng, shape_bounds)[2]))
    steps_per_epoch = max(1, samples // batch)
    optimiser = torch.optim.Adam(net.parameters(), lr=lr)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, epochs * steps_per_epoch)
    for epoch in range(epochs):
        totals: dict[str, float] = {}
        for _ in range(steps_per_epoch):
            frames = train.take(rng.integers(len(train), size=batch))
            counts = rng.choice(VIEW_COUNTS, size=batch, p=VIEW_COUNT_PROBS)
            features, valid, targets = _batch(frames, counts, rng, shape_bounds)
            loss = 0.0
            for estimate in net(features, valid):
                stage_loss, parts = fusion_loss(estimate, targets, valid)
                loss = loss + stage_loss
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            schedule.step()
            for k, v in parts.items():
                totals[k] = totals.get(k, 0.0) + v / steps_per_epoch
        if progress is not None:
            terms = ", ".join(f"{k} {v:.4f}" for k, v in totals.items())
            progress(f"{variant} epoch {epoch + 1}/{epochs} ({time.perf_counter() - start:.0f} s): last stage {terms}")
    info = {
        "variant": variant, "width": width, "epochs": epochs, "samples": samples, "batch": batch, "lr": lr,
        "seed": seed, "train_bodies": len(train), "fit_seconds": round(time.perf_counter() - start, 1),
        "parameters": sum(p.numel() for p in net.parameters()),
    }  # fmt: skip
    return FusionRegressor(net, shape_bounds, body_model=body_model, info=info)


def score_fusion(
    estimates: list[ViewEstimate],
    true_camera_T_root: list[np.ndarray],
    true_pose: np.ndarray,
    true_shape: np.ndarray,
    body: BodyModel,
) -> dict[str, float]:
    """Errors of per-view estimates against the truth, over frames where the views are valid.

    Args:
        estimates: ``V`` estimates from :meth:`FusionRegressor.predict` of one capture.
        true_camera_T_root: ``V`` arrays ``(T, 4, 4)``: the true root in each camera's frame.
        true_pose: ``(T, 21, 3)`` true local axis-angle.
        true_shape: ``(S,)`` or ``(T, S)`` true shape.
        body: the body model (for the skeleton of each shape).

    Returns:
        ``mpjpe_m``: mean over valid views and frames of the mean distance of the 22 joints,
        root-relative in the camera frame (so the root orientation counts), predicted shape's
        skeleton against the true one; ``root_position_m`` and ``root_depth_m``: the root's
        position error and depth error (|Δz|) in the camera frame; ``root_rotation_deg``; and,
        with two or more views, ``relative_camera_m`` / ``relative_camera_deg``: position and
        rotation error of camera ``v ≥ 2`` in camera 1's frame from ``cam1_T_root · inv(camv_T_root)``,
        over frames where both views are valid. Each error also has its median (``…_median_…``).
    """
    T = len(true_pose)
    true_shape = np.broadcast_to(np.asarray(true_shape, dtype=float), (T, body.shape_dim))
    rest_cache: dict[bytes, np.ndarray] = {}

    def rest(shapes: np.ndarray) -> torch.Tensor:
        out = []
        for s in shapes:
            key = s.tobytes()
            if key not in rest_cache:
                rest_cache[key] = body.rest_joints(s)
            out.append(rest_cache[key])
        return torch.as_tensor(np.array(out))

    true_R_pose = torch.as_tensor(rotvec_to_matrix(true_pose))
    mpjpe, position, depth, rotation = [], [], [], []
    for est, truth in zip(estimates, true_camera_T_root):
        ok = np.asarray(est.valid, dtype=bool)
        if not ok.any():
            continue
        joints = root_relative_joints(
            rest(est.shape[ok]), torch.as_tensor(est.camera_T_root[ok, :3, :3]), torch.as_tensor(rotvec_to_matrix(est.pose[ok]))
        )  # fmt: skip
        true_joints = root_relative_joints(rest(true_shape[ok]), torch.as_tensor(truth[ok, :3, :3]), true_R_pose[ok])
        mpjpe.append(torch.linalg.norm(joints - true_joints, dim=-1).mean(-1).numpy())
        diff = est.camera_T_root[ok, :3, 3] - truth[ok, :3, 3]
        position.append(np.linalg.norm(diff, axis=-1))
        depth.append(np.abs(diff[:, 2]))
        rotation.append(np.degrees(relative_angle(est.camera_T_root[ok, :3, :3], truth[ok, :3, :3])))
    out = {"views": len(estimates), "frames": T}
    _summarise(out, {"mpjpe_m": mpjpe, "root_position_m": position, "root_depth_m": depth, "root_rotation_deg": rotation})
    rel_position, rel_rotation = [], []
    for est, truth in zip(estimates[1:], true_camera_T_root[1:]):
        ok = np.asarray(estimates[0].valid, bool) & np.asarray(est.valid, bool)
        relative = estimates[0].camera_T_root[ok] @ np.linalg.inv(est.camera_T_root[ok])
        true_relative = true_camera_T_root[0][ok] @ np.linalg.inv(truth[ok])
        rel_position.append(np.linalg.norm(relative[:, :3, 3] - true_relative[:, :3, 3], axis=-1))
        rel_rotation.append(np.degrees(relative_angle(relative[:, :3, :3], true_relative[:, :3, :3])))
    if len(estimates) > 1:
        _summarise(out, {"relative_camera_m": rel_position, "relative_camera_deg": rel_rotation})
    return out


def _summarise(out: dict, errors: dict[str, list[np.ndarray]]) -> None:
    """Adds ``name`` (mean) and ``name`` with ``_median`` before its unit, NaN when there is no value."""
    for name, values in errors.items():
        values = np.concatenate(values) if values else np.zeros(0)
        stem, unit = name.rsplit("_", 1)
        out[name] = float(values.mean()) if len(values) else float("nan")
        out[f"{stem}_median_{unit}"] = float(np.median(values)) if len(values) else float("nan")


def synthetic_estimates(regressor: FusionRegressor, frames: BodyFrames, synthetic: SyntheticViews) -> list[ViewEstimate]:
    """The regressor's estimates for synthetic views, one :class:`ViewEstimate` per view slot with
    the bodies as its "frames" (each body seen by its own cameras)."""
    features, valid = crop_features(synthetic.keypoints, synthetic.K)
    out = regressor.estimate(features, valid)
    return [
        ViewEstimate(out["camera_T_root"][:, v], out["pose"][:, v], out["shape"][:, v], valid[:, v])
        for v in range(features.shape[1])
    ]


def evaluate_fusion(
    regressor: FusionRegressor, frames: BodyFrames, body: BodyModel, samples: int = 1000, views: int = 2, seed: int = 0
) -> dict[str, float]:
    """:func:`score_fusion` on ``samples`` bodies of ``frames`` (e.g. the held-out subjects),
    each seen by ``views`` random cameras (seeded: every variant sees the same views)."""
    rng = np.random.default_rng(seed)
    chosen = frames.take(rng.choice(len(frames), size=min(samples, len(frames)), replace=False))
    synthetic = render_views(chosen, views, rng)
    truth = camera_T_root(chosen, synthetic)
    estimates = synthetic_estimates(regressor, chosen, synthetic)
    return score_fusion(estimates, [truth[:, v] for v in range(views)], chosen.pose, chosen.shape, body)


def train_fusion_regressor(
    motion_dir: str | Path,
    body: BodyModel,
    variant: str = "full",
    epochs: int = 28,
    samples: int = 32768,
    seed: int = 0,
    stride: int = 4,
    eval_samples: int = 1000,
    progress: Callable[[str], None] | None = None,
) -> FusionRegressor:
    """Load and split the takes by subject, fit with :func:`fit_fusion_regressor`, evaluate on the
    held-out subjects with two views; ``info`` records the split, the numbers and the times."""
    start = time.perf_counter()
    train, test, held_out = split_frames(motion_dir, body, seed=seed, stride=stride, progress=progress)
    load_s = time.perf_counter() - start
    regressor = fit_fusion_regressor(
        train, body.shape_bounds, variant, epochs=epochs, samples=samples, seed=seed, body_model=body.name, progress=progress
    )  # fmt: skip
    scores = evaluate_fusion(regressor, test, body, samples=eval_samples)
    regressor.info = {
        "data": Path(motion_dir).name, "stride": stride, "val_subjects": held_out, **regressor.info,
        "val": scores, "load_seconds": round(load_s, 1),
    }  # fmt: skip
    return regressor
