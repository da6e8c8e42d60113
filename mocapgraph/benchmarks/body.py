"""``mocapgraph bench body``: native vs numpy forward kinematics, measured in one run."""

from __future__ import annotations

import time

import numpy as np

from mocapgraph.body.kinematics import SHAPE_START, forward_kinematics_numpy
from mocapgraph.body.model import BodyModel
from mocapgraph.body.native import forward_kinematics
from mocapgraph.body.rotations import rotvec_to_matrix


def random_bodies(rng: np.random.Generator, frames: int, pose_scale: float = 0.5):
    """``frames`` random root poses ``(T, 4, 4)`` and local rotations ``(T, 21, 3)``."""
    root = np.tile(np.eye(4), (frames, 1, 1))
    root[:, :3, :3] = rotvec_to_matrix(rng.normal(size=(frames, 3)))
    root[:, :3, 3] = rng.normal(size=(frames, 3))
    return root, rng.normal(scale=pose_scale, size=(frames, 21, 3))


def _best_rate(fn, frames: int, min_seconds: float) -> float:
    """Frames per second of the fastest of repeated calls (the least disturbed by other load)."""
    best, spent = np.inf, 0.0
    while spent < min_seconds:
        start = time.perf_counter()
        fn()
        took = time.perf_counter() - start
        best, spent = min(best, took), spent + took
    return frames / best


def jacobian_error(body: BodyModel, shape: np.ndarray, frames: int = 2, seed: int = 0) -> float:
    """Largest relative error of the native Jacobians against central differences.

    Relative to the largest Jacobian entry of the same output block; step 1e-6 (truncation and
    round-off both near 1e-10 in float64).
    """
    rng = np.random.default_rng(seed)
    root, pose = random_bodies(rng, frames)
    res = forward_kinematics(body.table(shape), root, pose, jacobians=True)
    analytic = np.concatenate([res.d_joints.reshape(-1, res.d_joints.shape[-1]), res.d_keypoints.reshape(-1, res.d_keypoints.shape[-1])])

    def outputs(delta: np.ndarray) -> np.ndarray:
        w, v, th, b = delta[:3], delta[3:6], delta[6:SHAPE_START], delta[SHAPE_START:]
        moved = root.copy()
        moved[:, :3, :3] = root[:, :3, :3] @ rotvec_to_matrix(w)
        moved[:, :3, 3] += root[:, :3, :3] @ v
        out = forward_kinematics(body.table(shape + b), moved, pose + th.reshape(21, 3))
        return np.concatenate([out.joints.ravel(), out.keypoints.ravel()])

    h = 1e-6
    cols = []
    for e in np.eye(analytic.shape[1]):
        cols.append((outputs(h * e) - outputs(-h * e)) / (2 * h))
    numeric = np.stack(cols, axis=-1)
    return float(np.abs(analytic - numeric).max() / np.abs(numeric).max())


def bench_body(body: BodyModel, frames: int = 256, min_seconds: float = 1.0, seed: int = 0) -> dict:
    """Throughput of posing with all Jacobians, native and numpy, on the same inputs."""
    rng = np.random.default_rng(seed)
    shape = body.default_shape
    table = body.table(shape)
    root, pose = random_bodies(rng, frames)
    native = _best_rate(lambda: forward_kinematics(table, root, pose, jacobians=True), frames, min_seconds)
    reference = _best_rate(lambda: forward_kinematics_numpy(table, root, pose, jacobians=True), frames, min_seconds)
    start = time.perf_counter()
    body.table(shape)
    table_ms = (time.perf_counter() - start) * 1e3
    return {
        "backend": body.name,
        "frames": frames,
        "keypoints": table.num_keypoints,
        "shape_dim": table.shape_dim,
        "native_frames_per_s": round(native, 1),
        "numpy_frames_per_s": round(reference, 1),
        "ratio": round(native / reference, 2),
        "shape_table_ms": round(table_ms, 2),
        # Anny's phenotype map has kinks at its anchors (0.5 is one); step off them for the check.
        "max_jacobian_rel_err": jacobian_error(body, shape + 0.0123),
    }
