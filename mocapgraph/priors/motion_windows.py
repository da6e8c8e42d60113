"""Motion windows for SmartMocap's motion prior: 25 frames of joint positions and orientations in
the window's canonical frame.

**Canonical frame** of a window (SmartMocap): origin at the ground projection (``z = 0``, the
ground plane of the Z-up world, metres) of the root at the window's first frame; Z up; rotated
about Z so that the root's forward direction at the first frame, projected on the ground, is
+Y (the root's forward direction is the third column of world_T_root's rotation, the body
frame's +Z; ``../shared/DESIGN.md``), which makes +X the subject's right. Heights stay absolute
above the ground, so the prior also learns where the ground is. The yaw ``γ`` of the canonical
frame is the angle from world +Y to the projected forward direction ``f``, counter-clockwise
about Z: ``γ = atan2(−f_x, f_y)``, ``world_R_canonical = Rz(γ)``; a canonical point is
``q = Rz(γ)ᵀ (p − o)``. The frame is undefined when the root faces straight up or down (the
projection vanishes); motion data has no such first frames.

**Features** of a frame, 198 channels: the 22 joint positions (66, joint-major x, y, z; metres)
then the 22 joint orientations in the continuous 6D representation (132, joint-major: the first
then the second column of the world-aligned joint frame ``G_c`` rotated into the canonical frame).
A window is ``(25, 198)``; the takes are 30 fps, so a window spans 0.8 s.

Training windows come from every ``cmu_SS_TT[...].npz`` of a motion directory retargeted onto
the body with its default shape (:func:`mocapgraph.data_tools.sim.cmu_motion.retarget`), one window
every ``stride`` frames of each take. After retargeting the CMU floors are at ``z ≈ 0`` (the 5th
percentile of the lowest foot keypoint per take lies within ±5 cm of 0 on 40 sampled takes).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from mocapgraph.body.model import BodyModel
from mocapgraph.body.rotations import axis_rotation
from mocapgraph.body.skeleton import NUM_JOINTS
from mocapgraph.errors import MocapgraphError

WINDOW = 25
"""Frames per window (30 fps: 0.8 s)."""
POSITION_CHANNELS = 3 * NUM_JOINTS
"""The first 66 channels of a frame: joint positions, canonical frame, metres."""
CHANNELS = POSITION_CHANNELS + 6 * NUM_JOINTS
"""198 channels per frame: 66 positions, then 132 for the 6D joint orientations."""


def canonical_frame(world_T_root0) -> tuple[np.ndarray, np.ndarray]:
    """Yaw ``γ (...)`` radians and origin ``o (..., 3)`` (world, metres, ``o_z = 0``) of the
    canonical frame of windows starting at ``world_T_root0 (..., 4, 4)``; ``world_R_canonical = Rz(γ)``."""
    T = np.asarray(world_T_root0, dtype=float)
    forward = T[..., :3, 2]
    yaw = np.arctan2(-forward[..., 0], forward[..., 1])
    origin = T[..., :3, 3].copy()
    origin[..., 2] = 0.0
    return yaw, origin


def to_canonical(points, world_T_root0) -> np.ndarray:
    """World points ``(..., P, 3)`` (one leading shape per window) into the window's canonical frame."""
    yaw, origin = canonical_frame(world_T_root0)
    R = axis_rotation("z", yaw)
    lead = np.ndim(yaw)
    points = np.asarray(points, dtype=float)
    extra = points.ndim - lead - 1  # axes between the window's and the xyz axis
    expand = (slice(None),) * lead + (None,) * extra
    # q = Rᵀ (p − o), written per point as (p − o) R.
    return np.einsum("...i,...ij->...j", points - origin[expand], R[expand])


def from_canonical(points, world_T_root0) -> np.ndarray:
    """Canonical points ``(..., P, 3)`` back to the world frame: ``p = Rz(γ) q + o``."""
    yaw, origin = canonical_frame(world_T_root0)
    R = axis_rotation("z", yaw)
    lead = np.ndim(yaw)
    points = np.asarray(points, dtype=float)
    expand = (slice(None),) * lead + (None,) * (points.ndim - lead - 1)
    return np.einsum("...ij,...j->...i", R[expand], points) + origin[expand]


def window_features(joint_positions, joint_orientations, world_T_root0) -> np.ndarray:
    """Features ``(..., 25, 198)`` of windows (leading axes ``...`` are windows, may be empty).

    Args:
        joint_positions: ``(..., 25, 22, 3)`` world, metres.
        joint_orientations: ``(..., 25, 22, 3, 3)`` world-aligned joint frames ``G_c``
            (:attr:`mocapgraph.body.FKResult.rotations`).
        world_T_root0: ``(..., 4, 4)`` the root pose at each window's first frame.
    """
    positions = np.asarray(joint_positions, dtype=float)
    orientations = np.asarray(joint_orientations, dtype=float)
    lead = positions.shape[:-3]
    if positions.shape[-3:] != (WINDOW, NUM_JOINTS, 3) or orientations.shape != lead + (WINDOW, NUM_JOINTS, 3, 3):
        raise MocapgraphError(
            f"window_features: expected positions (..., {WINDOW}, {NUM_JOINTS}, 3) and orientations "
            f"(..., {WINDOW}, {NUM_JOINTS}, 3, 3), got {positions.shape} and {orientations.shape}"
        )
    yaw, _ = canonical_frame(world_T_root0)
    Rt = np.swapaxes(axis_rotation("z", yaw), -1, -2)[(...,) + (None,) * 2 + (slice(None),) * 2]
    canonical_positions = to_canonical(positions, world_T_root0)
    six_d = (Rt @ orientations)[..., :, :2]  # (..., 25, 22, 3, 2): the first two columns
    six_d = np.swapaxes(six_d, -1, -2).reshape(lead + (WINDOW, 6 * NUM_JOINTS))
    return np.concatenate([canonical_positions.reshape(lead + (WINDOW, POSITION_CHANNELS)), six_d], axis=-1)


def feature_positions(features) -> np.ndarray:
    """Joint positions ``(..., 25, 22, 3)`` (canonical frame, metres) of features ``(..., 25, 198)``."""
    features = np.asarray(features)
    return features[..., :POSITION_CHANNELS].reshape(features.shape[:-1] + (NUM_JOINTS, 3))


def window_positions(features, world_T_root0) -> np.ndarray:
    """World joint positions ``(..., 25, 22, 3)`` (metres) of features ``(..., 25, 198)`` whose
    canonical frame is that of ``world_T_root0 (..., 4, 4)``; the inverse of :func:`window_features`
    for the positions."""
    return from_canonical(feature_positions(features), world_T_root0)


def window_starts(frames: int, stride: int) -> np.ndarray:
    """First frames of the windows of a ``frames``-long sequence, every ``stride`` frames."""
    if stride < 1:
        raise MocapgraphError(f"window stride must be >= 1, got {stride}")
    return np.arange(0, frames - WINDOW + 1, stride)


def motion_features(body: BodyModel, root, pose, starts, shape=None) -> np.ndarray:
    """Features ``(W, 25, 198)`` float32 of the windows starting at ``starts (W,)`` of a motion
    ``root (T, 4, 4)`` world_T_root, ``pose (T, 21, 3)`` axis-angle, on ``body`` (default shape)."""
    shape = body.default_shape if shape is None else shape
    fk = body.forward(shape, root, pose)
    index = np.asarray(starts)[:, None] + np.arange(WINDOW)
    features = window_features(fk.joints[index], fk.rotations[index], np.asarray(root)[np.asarray(starts)])
    return features.astype(np.float32)


@dataclass
class MotionWindows:
    """``features (N, 25, 198)`` float32 and ``subjects (N,)`` CMU subject ids of training windows."""

    features: np.ndarray
    subjects: np.ndarray


def load_motion_windows(
    motion_dir: str | Path,
    body: BodyModel,
    stride: int = 5,
    progress: Callable[[str], None] | None = None,
) -> MotionWindows:
    """A window every ``stride`` frames of every take in ``motion_dir``, retargeted onto ``body``
    (default shape).

    ``progress(message)`` is called every 100 takes. Raises a MocapgraphError naming the
    directory when it does not exist or holds no ``cmu_*.npz`` take.
    """
    from mocapgraph.data_tools.sim.cmu_motion import load_cmu_take, retarget
    from mocapgraph.priors.training import take_files, take_subject

    directory = Path(motion_dir)
    files = take_files(directory)
    features, subjects = [], []
    start = time.perf_counter()
    for i, path in enumerate(files):
        root, pose = retarget(load_cmu_take(path), body)
        starts = window_starts(len(root), stride)
        if len(starts):
            features.append(motion_features(body, root, pose, starts))
            subjects.append(np.full(len(starts), take_subject(path)))
        if progress is not None and ((i + 1) % 100 == 0 or i + 1 == len(files)):
            progress(f"loaded {i + 1}/{len(files)} takes ({time.perf_counter() - start:.0f} s)")
    if not features:
        raise MocapgraphError(f"{directory}: no take is {WINDOW} frames long")
    return MotionWindows(np.concatenate(features), np.concatenate(subjects))
