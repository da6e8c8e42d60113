"""The one variable-key scheme of every mocapgraph factor graph.

GTSAM keys are ``gtsam.symbol(char, index)``:

| variable | key | type |
|---|---|---|
| root pose of body state ``i`` (world_T_root) | ``root_key(i)`` = ``symbol('r', i)`` | ``gtsam.Pose3`` |
| joint rotations of body state ``i`` (21 axis-angle vectors, radians) | ``pose_key(i)`` = ``symbol('q', i)`` | ``Vector(63)`` |
| shape of the subject (one per sequence) | ``shape_key()`` = ``symbol('b', 0)`` | ``Vector(S)`` |
| pose of camera ``c`` at its frame ``j`` (world_T_camera) | ``camera_key(c, j)`` = ``symbol('c', c·10⁶ + j)`` | ``gtsam.Pose3`` |
| velocity of moving camera ``c`` at its frame ``j`` (world frame, m/s; cameras with an IMU log) | ``camera_velocity_key(c, j)`` = ``symbol('u', c·10⁶ + j)`` | ``Vector(3)`` |
| IMU bias of moving camera ``c`` at its frame ``j`` (accelerometer m/s², gyroscope rad/s) | ``camera_bias_key(c, j)`` = ``symbol('w', c·10⁶ + j)`` | ``imuBias.ConstantBias`` |
| common world-frame offset of camera ``c``'s GPS/IMU prior | ``camera_offset_key(c)`` = ``symbol('o', c)`` | ``gtsam.Pose3`` |
| vehicle navigation state ``n`` (GPS/IMU fusion, per vehicle graph) | ``nav_keys(n)`` = ``symbol('x'|'v'|'i', n)`` | ``Pose3``, ``Vector3``, ``imuBias.ConstantBias`` |
| GPS/barometer offsets at navigation state ``n`` (slow sensor drift) | ``drift_key(n)`` = ``symbol('d', n)`` | ``Vector(4)`` |
| pose-prior latent of body state ``i`` (pose VAE) | ``pose_latent_key(i)`` = ``symbol('z', i)`` | ``Vector(L)`` |
| motion-prior latent of window ``w`` (motion VAE) | ``motion_latent_key(w)`` = ``symbol('m', w)`` | ``Vector(L)`` |
| motion-prior canonical frame of window ``w`` (ground origin x, y in metres, yaw in radians) | ``motion_frame_key(w)`` = ``symbol('n', w)`` | ``Vector(3)`` |
| the ground plane (tilt about world X and Y in radians, height in metres) | ``ground_key()`` = ``symbol('g', 0)`` | ``Vector(3)`` |
| focal length of camera ``c``, as the log of its ratio to the capture's (``fx, fy = e^s·(fx₀, fy₀)``) | ``focal_key(c)`` = ``symbol('f', c)`` | ``Vector(1)`` |
| keypoint-definition offset parameters of detector format ``f`` (``mocapgraph.body.keypoint_offsets.offset_basis``, metres) | ``keypoint_offset_key(f)`` = ``symbol('k', f)`` | ``Vector(D)`` |

Body states are numbered in time order; cameras in capture order, frames in each camera's order.
"""

from __future__ import annotations

import gtsam

CAMERA_STRIDE = 1_000_000
"""Frames per camera the camera-key scheme allows (a camera index is ``key index // CAMERA_STRIDE``)."""


def root_key(i: int) -> int:
    return gtsam.symbol("r", i)


def pose_key(i: int) -> int:
    return gtsam.symbol("q", i)


def shape_key() -> int:
    return gtsam.symbol("b", 0)


def camera_key(camera: int, frame: int) -> int:
    if not 0 <= frame < CAMERA_STRIDE:
        raise ValueError(f"camera frame index {frame} outside [0, {CAMERA_STRIDE})")
    return gtsam.symbol("c", camera * CAMERA_STRIDE + frame)


def camera_velocity_key(camera: int, frame: int) -> int:
    return gtsam.symbol("u", camera_key(camera, frame) - gtsam.symbol("c", 0))


def camera_bias_key(camera: int, frame: int) -> int:
    return gtsam.symbol("w", camera_key(camera, frame) - gtsam.symbol("c", 0))


def camera_offset_key(camera: int) -> int:
    return gtsam.symbol("o", camera)


def pose_latent_key(i: int) -> int:
    return gtsam.symbol("z", i)


def motion_latent_key(w: int) -> int:
    return gtsam.symbol("m", w)


def motion_frame_key(w: int) -> int:
    return gtsam.symbol("n", w)


def ground_key() -> int:
    return gtsam.symbol("g", 0)


def focal_key(camera: int) -> int:
    return gtsam.symbol("f", camera)


def keypoint_offset_key(fmt_index: int) -> int:
    return gtsam.symbol("k", fmt_index)


def nav_keys(n: int) -> tuple[int, int, int]:
    """Pose, velocity and IMU-bias keys of navigation state ``n`` in a vehicle's fusion graph."""
    return gtsam.symbol("x", n), gtsam.symbol("v", n), gtsam.symbol("i", n)


def drift_key(n: int) -> int:
    """GPS (3) and barometer (1) offsets at navigation state ``n`` of a vehicle's fusion graph."""
    return gtsam.symbol("d", n)
