"""Synthetic scenes of two people seen by several static cameras: the truth the people tests assert against.

Two bodies (Anny, procedural motions) walk away from each other; static cameras on a circle look
at them. Every camera's keypoint tracks are BlazePose-33 pixels with noise, in a random order per
camera, with chosen frames' left/right labels exchanged (a detector's sustained swap) and chosen
frames dropped.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.labelling import swap_permutation
from mocapgraph.data_tools.geometry.camera_model import in_frame_mask
from mocapgraph.data_tools.sim.motion_sources import procedural_motion
from mocapgraph.data_tools.sim.scenarios import look_at

FORMAT = get_format("blazepose33")
SWAP = swap_permutation(FORMAT.names, "body")


@lru_cache(maxsize=4)
def two_people(frames: int, fps: float) -> np.ndarray:
    """``(2, T, 33, 3)`` world keypoints (metres) of two people who start 1.2 m apart and walk
    away from each other (one along +X, the other turning away along -X and -Y); unmapped points NaN."""
    from mocapgraph.body import load_body_model

    body = load_body_model("anny")
    duration = (frames - 1) / fps
    a = procedural_motion("walk", duration, fps=fps, seed=1, body=body).keypoints(body, FORMAT.name)
    b = procedural_motion("turn", duration, fps=fps, seed=2, body=body).keypoints(body, FORMAT.name)
    turn = np.array([[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]])
    b = b @ turn.T + np.array([-0.4, 1.2, 0.0])
    people = np.stack([a, b])[:, :frames]
    unmapped = np.array([m is None for m in FORMAT.mapping])
    people[:, :, unmapped] = np.nan
    return people


@dataclass
class Scene:
    """Attributes:
    world: ``(2, T, 33, 3)`` the two people, metres.
    poses: camera → ``world_T_camera (4, 4)``, or ``(T, 4, 4)`` for a moving camera.
    K: the cameras' true intrinsics; size ``(width, height)``.
    tracks: camera → ``(2, T, 33, 3)`` pixel tracks, in the camera's own order.
    truth: camera → ``(2,)`` which person each track is (``tracks[c][i]`` shows person ``truth[c][i]``).
    swapped: camera → ``(2, T)`` frames whose labels are exchanged, per track.
    """

    world: np.ndarray
    poses: dict[str, np.ndarray]
    K: np.ndarray
    size: tuple[int, int]
    tracks: dict[str, np.ndarray] = field(default_factory=dict)
    truth: dict[str, np.ndarray] = field(default_factory=dict)
    swapped: dict[str, np.ndarray] = field(default_factory=dict)


def make_scene(
    seed: int = 0,
    cameras: int = 4,
    frames: int = 60,
    fps: float = 20.0,
    size: tuple[int, int] = (1280, 720),
    noise_px: float = 2.0,
    swap_runs: dict[str, tuple[int, int, int]] | None = None,
    drop: float = 0.05,
    moving: tuple[str, ...] = (),
) -> Scene:
    """A two-person scene; ``swap_runs`` maps a camera to ``(person, first frame, last frame)`` of
    a sustained whole-body swap; ``drop`` is the chance that a detection is missing; the cameras
    named in ``moving`` are carried round the people (0.2 rad/s on their circle, 1.4 m/s, bobbing 5 cm at
    a walker's 1.8 steps/s), their ``poses`` ``(T, 4, 4)``."""
    rng = np.random.default_rng(seed)
    world = two_people(frames, fps)
    w, h = size
    K = np.array([[1.0 * w, 0.0, w / 2], [0.0, 1.0 * w, h / 2], [0.0, 0.0, 1.0]])
    scene = Scene(world, {}, K, size)
    centre = np.nanmean(world[:, 0, :, :], axis=(0, 1)) * [1, 1, 0] + [0, 0, 0.9]
    for c in range(cameras):
        name = f"cam{c + 1}"
        angle = 2 * np.pi * c / cameras + rng.uniform(-0.3, 0.3)
        position = centre + [7.0 * np.cos(angle), 7.0 * np.sin(angle), rng.uniform(1.2, 2.5)]
        if name in moving:
            t = np.arange(frames) / fps
            path = centre + np.stack([7.0 * np.cos(angle + 0.2 * t), 7.0 * np.sin(angle + 0.2 * t), position[2] - centre[2] + 0.05 * np.sin(2 * np.pi * 1.8 * t)], axis=-1)
            scene.poses[name] = np.stack([look_at(p, centre) for p in path])
            projected = [in_frame_mask(world[:, k], scene.poses[name][k], K, None, size) for k in range(frames)]
            pixels, seen = np.stack([p[0] for p in projected], axis=1), np.stack([p[2] for p in projected], axis=1)
        else:
            scene.poses[name] = look_at(position, centre)
            pixels, _, seen = in_frame_mask(world, scene.poses[name], K, None, size)
        kp = np.concatenate([pixels + rng.normal(scale=noise_px, size=pixels.shape), np.full(seen.shape + (1,), 0.9)], axis=-1)
        kp[~seen] = np.nan
        kp[rng.random(kp.shape[:2]) < drop] = np.nan
        swapped = np.zeros(kp.shape[:2], dtype=bool)
        if swap_runs and name in swap_runs:
            person, first, last = swap_runs[name]
            swapped[person, first : last + 1] = True
            kp[person, first : last + 1] = kp[person, first : last + 1][:, SWAP]
        order = rng.permutation(2)
        scene.tracks[name], scene.truth[name], scene.swapped[name] = kp[order], order, swapped[order]
    return scene
