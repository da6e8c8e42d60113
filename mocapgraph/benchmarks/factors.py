"""``mocapgraph bench factors``: the reprojection factor's cost per evaluation, as GTSAM calls it.

One body state seen by C = 1, 4 and 8 refined cameras on a ring (SmartMocap's case: shape and
cameras are variables; coco17 detections with 1.5 px noise, one outlier, one missed point and one
left/right swap per camera), at a Geman-McClure scale of 40 px. Per C it reports microseconds
per ``factor.error(values)`` (the error-only call LM's trial steps make) and per
``factor.linearize(values)`` (residual and Jacobians), with the labelling hypotheses of the
solvers (left/right swaps) and without, and the bare native kernel's time on the same inputs
(what the factor adds around it is the rest). Each figure is the process CPU time of the
fastest of repeated batches, the least disturbed by other load on the machine.
"""

from __future__ import annotations

import time

import gtsam
import numpy as np

from mocapgraph.body import load_body_model
from mocapgraph.body.native import native_module, table_arrays
from mocapgraph.body.rotations import rotvec_to_matrix
from mocapgraph.data_tools.sim.scenarios import look_at
from mocapgraph.factors.keys import camera_key, pose_key, root_key, shape_key
from mocapgraph.factors.reprojection import Labelling, ShapeTableCache, reprojection_factor
from mocapgraph.factors.robust import RobustScale
from mocapgraph.graphs.body_graph import swap_hypotheses

FORMAT = "coco17"
INTRINSICS = (1000.0, 1000.0, 960.0, 540.0)
CALLS = 200  # evaluations per timed batch


def _scene(body, cameras: int, rng: np.random.Generator) -> dict:
    """Truth, detections and cameras of one body state seen by ``cameras`` cameras on a 4 m ring."""
    root = np.eye(4)
    root[:3, :3] = rotvec_to_matrix(np.array([0.0, 0.0, rng.uniform(-np.pi, np.pi)])) @ rotvec_to_matrix(np.array([np.pi / 2, 0.0, 0.0]))
    root[:3, 3] = [0.0, 0.0, 1.0]
    pose = rng.normal(scale=0.2, size=63)
    shape = body.default_shape
    angles = 2 * np.pi * np.arange(cameras) / cameras
    world_T_camera = look_at(np.stack([4 * np.cos(angles), 4 * np.sin(angles), np.full(cameras, 1.5)], axis=-1), [0.0, 0.0, 1.0])
    intrinsics = np.tile(INTRINSICS, (cameras, 1))
    truth = body.forward(shape, root[None], pose.reshape(1, 21, 3), keypoints=FORMAT).keypoints[0]
    p = np.einsum("cyx,cky->ckx", world_T_camera[:, :3, :3], truth[None] - world_T_camera[:, None, :3, 3])
    observed = p[..., :2] / p[..., 2:] * intrinsics[:, None, :2] + intrinsics[:, None, 2:] + rng.normal(scale=1.5, size=(cameras, 17, 2))
    observed[:, 9] += 60.0  # an outlier per camera
    observed[:, 3] = np.nan  # a missed point per camera
    observed[:, [13, 14]] = observed[:, [14, 13]]  # the knees' labels swapped
    return {"root": root, "pose": pose, "shape": shape, "cameras": world_T_camera, "intrinsics": intrinsics, "observed": observed,
            "weights": rng.uniform(0.5, 1.0, size=(cameras, 17))}  # fmt: skip


def _values(scene: dict, rng: np.random.Generator) -> gtsam.Values:
    """Python-owned values a little off the truth (so the robust weights' derivatives matter)."""
    values = gtsam.Values()
    values.insert(root_key(0), gtsam.Pose3(scene["root"]).retract(rng.normal(scale=0.02, size=6)))
    values.insert(pose_key(0), scene["pose"] + rng.normal(scale=0.05, size=63))
    values.insert(shape_key(), scene["shape"])
    for c, T in enumerate(scene["cameras"]):
        values.insert(camera_key(c, 0), gtsam.Pose3(T).retract(rng.normal(scale=0.01, size=6)))
    return values


def _microseconds(fn, min_seconds: float) -> float:
    """CPU microseconds per call of ``fn``: the fastest batch of :data:`CALLS` within ``min_seconds``."""
    best, spent = np.inf, 0.0
    while spent < min_seconds:
        start = time.process_time()
        for _ in range(CALLS):
            fn()
        took = time.process_time() - start
        best, spent = min(best, took), spent + took
    return round(1e6 * best / CALLS, 1)


def bench_factors(seed: int = 0, min_seconds: float = 0.5) -> dict:
    """Microseconds per reprojection-factor evaluation for C = 1, 4 and 8 cameras (module docstring).

    Returns ``{"C=<n>": {"error_us", "linearize_us", "labelled_error_us", "labelled_linearize_us",
    "kernel_us", "kernel_jacobians_us", "rows"}}`` plus the settings.
    """
    body = load_body_model()
    rng = np.random.default_rng(seed)
    scale = RobustScale(40.0)
    out: dict = {"format": FORMAT, "gm_sigma_px": scale.sigma_px, "calls_per_batch": CALLS}
    for cameras in (1, 4, 8):
        scene = _scene(body, cameras, rng)
        values = _values(scene, rng)
        cache = ShapeTableCache(body, FORMAT)
        keys = [camera_key(c, 0) for c in range(cameras)]

        def factor(labelling):
            return reprojection_factor(
                body, cache, root_key(0), pose_key(0), shape_key(), keys, [None] * cameras, scene["intrinsics"], scene["observed"],
                scene["weights"], FORMAT, scale, noise_px=1.5, labelling=labelling,
            )  # fmt: skip

        plain = factor(None)
        labelled = factor(Labelling(swap_hypotheses(body, FORMAT), 0.5 * 3.0**2))
        current = np.stack([values.atPose3(k).matrix() for k in keys])
        kernel_args = (*table_arrays(cache(values.atVector(shape_key()))), values.atPose3(root_key(0)).matrix(), values.atVector(pose_key(0)).reshape(21, 3),
                       current, scene["intrinsics"], scene["observed"], scene["weights"] / 1.5, scale.sigma_px, 0.05)  # fmt: skip
        kernel = native_module().reproject
        out[f"C={cameras}"] = {
            "rows": plain.dim(),
            "error_us": _microseconds(lambda: plain.error(values), min_seconds),
            "linearize_us": _microseconds(lambda: plain.linearize(values), min_seconds),
            "labelled_error_us": _microseconds(lambda: labelled.error(values), min_seconds),
            "labelled_linearize_us": _microseconds(lambda: labelled.linearize(values), min_seconds),
            "kernel_us": _microseconds(lambda: kernel(*kernel_args, False), min_seconds),
            "kernel_jacobians_us": _microseconds(lambda: kernel(*kernel_args, True), min_seconds),
        }
    return out
