"""Synthetic camera rigs around a moving subject, modelled on the thesis' four kinds of capture.

:func:`scenario_cameras` takes the subject's root (pelvis) trajectory and returns every camera's
intrinsics, frame timestamps, true ``world_T_camera`` at those timestamps and, for cameras on
vehicles with sensors, the vehicle's true trajectory (100 Hz) and its sensor logs
(:mod:`mocapgraph.data_tools.sim.sensors`). World: ENU, Z up, metres, ground at z = 0. Cameras:
OpenCV (x right, y down, z forward). ``docs/scenarios.md`` tabulates every preset.

Presets: ``aircap`` (3 UAVs, no gimbal, unsynchronised, GPS/IMU/baro/self-pose), ``airpose``
(2 gimballed UAVs, synchronised, no sensors), ``rich`` (7 static room cameras + 1 hand-held),
``phones`` (2 static + 2 walking phones around a small field, the walking ones with an IMU
each by default). The same seed gives the same numbers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from mocapgraph.body.rotations import rotvec_to_matrix
from mocapgraph.data_tools.geometry.camera_model import in_frame_mask
from mocapgraph.data_tools.sim.sensors import (
    GRAVITY_M_S2,
    PhoneImu,
    VehicleSensors,
    VehicleTrajectory,
    position_spline,
    simulate_phone_imu,
    simulate_vehicle_sensors,
    smooth_noise,
)
from mocapgraph.errors import MocapgraphError, as_checked_array

PRESETS = ("aircap", "airpose", "rich", "phones")
VEHICLE_RATE_HZ = 100.0
FRAME_RATE_HZ = 30.0  # synchronised presets

# Calibration error of the "known" extrinsics of static cameras (per-axis std).
CALIBRATION_ROTATION_DEG = 0.05
CALIBRATION_TRANSLATION_M = 0.005


@dataclass
class SimCamera:
    """One simulated camera with its ground truth.

    Attributes:
        name: unique within a scenario.
        K: ``(3, 3)`` intrinsics, pixels.
        distortion: ``(5,)`` OpenCV ``k1, k2, p1, p2, k3``.
        image_size: ``(width, height)`` pixels.
        moving: whether the camera moves.
        frame_rate: nominal frames per second.
        timestamps: ``(T_c,)`` seconds of each frame.
        world_T_camera: ``(T_c, 4, 4)`` true pose at ``timestamps``.
        mount: ``(4, 4)`` vehicle_T_camera for cameras rigidly mounted on a vehicle with sensors
            (a carried phone: the camera in its IMU's frame).
        vehicle_poses: ``(N, 4, 4)`` true world_T_vehicle at ``vehicle_times`` (100 Hz), or None.
        vehicle_times: ``(N,)`` seconds, or None.
        sensors: sensor logs by kind in the ``SENSOR_FIELDS`` layout of the capture format.
        extrinsics: what a calibrated user knows: ``(1, 4, 4)`` for static cameras of ``rich`` and
            ``phones`` (true pose plus a small calibration error); None otherwise.
        imu_time_offset_s: for a phone with an IMU, its log's clock minus the camera's, seconds.
    """

    name: str
    K: np.ndarray
    distortion: np.ndarray
    image_size: tuple[int, int]
    moving: bool
    frame_rate: float
    timestamps: np.ndarray
    world_T_camera: np.ndarray
    mount: np.ndarray | None = None
    vehicle_poses: np.ndarray | None = None
    vehicle_times: np.ndarray | None = None
    sensors: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    extrinsics: np.ndarray | None = None
    imu_time_offset_s: float | None = None


# ---------------------------------------------------------------------------------------------
# Geometry helpers


def look_at(position, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """``world_T_camera (..., 4, 4)`` of an OpenCV camera at ``position`` looking at ``target``.

    +Z (optical axis) points at the target, +X (image right) is horizontal, ``z × up``; +Y (image
    down) is ``z × x``, so ``up`` appears upwards in the image. Broadcasts over leading axes. When the
    camera looks along ``±up``, image right is ``z × e`` with ``e`` the world axis least parallel
    to ``up``.
    """
    p, q = np.broadcast_arrays(np.asarray(position, dtype=float), np.asarray(target, dtype=float))
    up = np.asarray(up, dtype=float)
    z = q - p
    dist = np.linalg.norm(z, axis=-1, keepdims=True)
    if np.any(dist < 1e-12):
        raise MocapgraphError("look_at: position and target coincide")
    z = z / dist
    x = np.cross(z, up)
    nx = np.linalg.norm(x, axis=-1, keepdims=True)
    degenerate = nx[..., 0] < 1e-9 * np.linalg.norm(up)
    if np.any(degenerate):
        other = np.eye(3)[int(np.argmin(np.abs(up)))]
        x = np.where(degenerate[..., None], np.cross(z, other), x)
        nx = np.linalg.norm(x, axis=-1, keepdims=True)
    x = x / nx
    y = np.cross(z, x)
    out = np.zeros(p.shape[:-1] + (4, 4))
    out[..., :3, :3] = np.stack([x, y, z], axis=-1)
    out[..., :3, 3] = p
    out[..., 3, 3] = 1.0
    return out


def subject_visibility(camera: SimCamera, subject_times, subject_positions) -> tuple[np.ndarray, np.ndarray]:
    """Per frame of ``camera``: is the subject point in front (z > 0), and inside the image?"""
    points = _Subject(subject_times, subject_positions).at(camera.timestamps)
    _, z, inside = in_frame_mask(points, camera.world_T_camera, camera.K, camera.distortion, camera.image_size)
    return z > 0, inside


class _Subject:
    """The subject's root position at any time (linear interpolation, held beyond the ends)."""

    def __init__(self, times, positions):
        self.times = as_checked_array(times, "subject_times", (None,))
        self.positions = as_checked_array(positions, "subject_positions", (len(self.times), 3))
        if len(self.times) < 2 or np.any(np.diff(self.times) <= 0):
            raise MocapgraphError("subject_times: needs at least 2 strictly increasing timestamps")

    def at(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        return np.stack([np.interp(t, self.times, self.positions[:, i]) for i in range(3)], axis=-1)


def _lag(times: np.ndarray, x: np.ndarray, tau_s: float) -> np.ndarray:
    """First-order low-pass (time constant ``tau_s``) of ``x (N, ...)``, starting at ``x[0]``."""
    out = np.empty_like(x)
    out[0] = x[0]
    keep = np.exp(-np.diff(times) / tau_s)
    for k in range(1, len(times)):
        out[k] = keep[k - 1] * out[k - 1] + (1.0 - keep[k - 1]) * x[k]
    return out


def _roll(angles: np.ndarray) -> np.ndarray:
    """``(N, 3, 3)`` rotations by ``angles`` about the camera's optical axis (z)."""
    return rotvec_to_matrix(angles[:, None] * np.array([0.0, 0.0, 1.0]))


def _pointing(
    rng: np.random.Generator,
    times: np.ndarray,
    positions: np.ndarray,
    targets: np.ndarray,
    *,
    lag_s: float,
    jitter_deg: float,
    jitter_hz: tuple[float, float] = (0.5, 4.0),
    pitch_limits_deg: tuple[float, float] | None = None,
) -> np.ndarray:
    """Poses of a camera at ``positions`` aimed at ``targets`` by an operator or a gimbal.

    Yaw and pitch follow the target direction through a first-order lag, pitch (positive down)
    optionally clamped, plus smooth angular jitter in yaw, pitch and roll (hand shake, gimbal).
    """
    d = targets - positions
    yaw = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    pitch = np.arctan2(-d[:, 2], np.hypot(d[:, 0], d[:, 1]))
    if lag_s > 0:
        yaw, pitch = _lag(times, yaw, lag_s), _lag(times, pitch, lag_s)
    if pitch_limits_deg is not None:
        pitch = np.clip(pitch, *np.radians(pitch_limits_deg))
    jitter = math.radians(jitter_deg) * smooth_noise(rng, times, 3, jitter_hz)
    yaw, pitch = yaw + jitter[:, 0], pitch + jitter[:, 1]
    direction = np.stack([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), -np.sin(pitch)], axis=-1)
    poses = look_at(positions, positions + direction)
    poses[:, :3, :3] = poses[:, :3, :3] @ _roll(jitter[:, 2])
    return poses


def _intrinsics(rng: np.random.Generator, size: tuple[int, int], focal_px: tuple[float, float]) -> np.ndarray:
    """Square pixels, focal uniform in ``focal_px``, principal point within ~1% of the centre."""
    f = rng.uniform(*focal_px)
    w, h = size
    cx, cy = w / 2 + rng.normal(scale=0.005 * w), h / 2 + rng.normal(scale=0.005 * h)
    return np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])


def _distortion(rng: np.random.Generator, k1_range: tuple[float, float]) -> np.ndarray:
    k1 = rng.uniform(*k1_range)
    return np.array([k1, -0.3 * k1, 0.0, 0.0, 0.0])


def _calibrated(rng: np.random.Generator, pose: np.ndarray) -> np.ndarray:
    """``(1, 4, 4)``: ``pose`` with a small calibration error (rotation and translation)."""
    out = pose.copy()
    out[:3, :3] = rotvec_to_matrix(rng.normal(scale=math.radians(CALIBRATION_ROTATION_DEG), size=3)) @ pose[:3, :3]
    out[:3, 3] += rng.normal(scale=CALIBRATION_TRANSLATION_M, size=3)
    return out[None]


def _frame_times(
    rng: np.random.Generator, t0: float, t1: float, rate: float, offset: float = 0.0, jitter_s: float = 0.0
) -> np.ndarray:
    """Frames at ``t0 + offset + k / rate`` within ``[t0, t1]``, each with clipped Gaussian jitter."""
    n = int(math.floor((t1 - t0 - offset) * rate + 1e-9)) + 1
    t = t0 + offset + np.arange(n) / rate
    if jitter_s > 0:
        t = t + np.clip(rng.normal(scale=jitter_s, size=n), -3 * jitter_s, 3 * jitter_s)
    return t[(t >= t0) & (t <= t1)]


def _area(subject: _Subject, times: np.ndarray, half_min: tuple[float, float], margin: float):
    """Centre (x, y) and half sizes of an area around the subject's path: at least ``half_min``,
    grown so the path stays ``margin`` metres from its walls."""
    path = subject.at(times)[:, :2]
    lo, hi = path.min(axis=0), path.max(axis=0)
    centre = (lo + hi) / 2
    half = np.maximum(np.asarray(half_min), (hi - lo) / 2 + margin)
    return centre, half


def _camera(rng, name, poses, size, focal_px, k1_range, timestamps, rate=FRAME_RATE_HZ, moving=True) -> SimCamera:
    return SimCamera(
        name=name,
        K=_intrinsics(rng, size, focal_px),
        distortion=_distortion(rng, k1_range),
        image_size=size,
        moving=moving,
        frame_rate=rate,
        timestamps=timestamps.copy(),
        world_T_camera=poses,
    )


def _static_camera(rng, name, position, target, size, focal_px, k1_range, timestamps) -> SimCamera:
    """A camera on a tripod; its known extrinsics are the true pose plus a calibration error."""
    pose = look_at(position, target)
    poses = np.repeat(pose[None], len(timestamps), axis=0)
    camera = _camera(rng, name, poses, size, focal_px, k1_range, timestamps, moving=False)
    camera.extrinsics = _calibrated(rng, pose)
    return camera


# ---------------------------------------------------------------------------------------------
# aircap: three UAVs without gimbal, each with GPS, IMU, barometer and its own pose estimate


@dataclass(frozen=True)
class AircapParams:
    """Formation and flight dynamics of the ``aircap`` preset (documented in ``docs/scenarios.md``)."""

    altitude_m: float = 8.0
    distance_m: float = 8.0
    formation_drift_deg_s: tuple[float, float] = (2.0, 5.0)  # |rotation rate| of the formation
    formation_wobble_deg: float = 12.0
    reposition_every_s: tuple[float, float] = (5.0, 10.0)  # each vehicle now and then moves
    reposition_deg: tuple[float, float] = (50.0, 90.0)  # ... this far around the subject
    reposition_time_s: float = 4.0  # ... within this time (the controller's limits slow it)
    subject_estimate_lag_s: float = 0.5  # the vehicles track a lagged estimate of the subject
    subject_estimate_error_m: float = 0.3
    position_gain_1_s: float = 0.8  # cascaded P-P: critically damped with velocity gain 4× this
    max_speed_m_s: float = 5.0
    max_vertical_speed_m_s: float = 1.5
    max_accel_m_s2: float = 4.0
    max_vertical_accel_m_s2: float = 2.0
    attitude_lag_s: float = 0.15  # acceleration follows the command through this lag
    turbulence_m_s2: float = 1.0  # std of the smooth random acceleration disturbance (horizontal)
    turbulence_hz: tuple[float, float] = (0.1, 1.0)  # its frequency band
    yaw_lag_s: float = 1.0
    max_yaw_rate_deg_s: float = 30.0
    mount_pitch_deg: tuple[float, float] = (35.0, 45.0)
    mount_offset_m: tuple[float, float, float] = (0.10, 0.0, -0.06)  # camera in the vehicle frame
    frame_rate_hz: tuple[float, float] = (30.0, 40.0)
    frame_jitter_s: float = 0.5e-3
    focal_px: tuple[float, float] = (1200.0, 1500.0)
    image_size: tuple[int, int] = (1920, 1080)


def _formation_paths(rng, tv, subject: _Subject, count: int, p: AircapParams):
    """Formation points ``(N, count, 3)``, their velocities, and the subject estimate ``(N, 3)``."""
    estimate = _lag(tv, subject.at(tv), p.subject_estimate_lag_s)
    estimate[:, :2] += p.subject_estimate_error_m * smooth_noise(rng, tv, 2, (0.05, 0.5)) / math.sqrt(2)
    drift = math.radians(rng.uniform(*p.formation_drift_deg_s)) * rng.choice([-1.0, 1.0])
    phase = rng.uniform(0.0, 2.0 * np.pi)
    rel = tv - tv[0]
    angle = (
        phase
        + 2.0 * np.pi * np.arange(count)[None] / count
        + drift * rel[:, None]
        + math.radians(p.formation_wobble_deg) * smooth_noise(rng, tv, count, (1 / 40, 1 / 10))
    )
    angle += _repositioning(rng, tv, count, p)
    radius = p.distance_m + 0.8 * smooth_noise(rng, tv, count, (1 / 30, 1 / 8))
    height = p.altitude_m + 0.4 * smooth_noise(rng, tv, count, (1 / 30, 1 / 8))
    points = np.stack(
        [estimate[:, None, 0] + radius * np.cos(angle), estimate[:, None, 1] + radius * np.sin(angle), height],
        axis=-1,
    )
    return points, np.gradient(points, tv, axis=0), estimate


def _repositioning(rng, tv, count: int, p: AircapParams) -> np.ndarray:
    """``(N, count)`` formation angle offsets: smooth steps of ±reposition_deg at random times."""
    out = np.zeros((len(tv), count))
    for i in range(count):
        start = tv[0] + rng.uniform(0.3, 0.8) * p.reposition_every_s[0]
        while start < tv[-1]:
            step = math.radians(rng.uniform(*p.reposition_deg)) * rng.choice([-1.0, 1.0])
            u = np.clip((tv - start) / p.reposition_time_s, 0.0, 1.0)
            out[:, i] += step * u * u * (3.0 - 2.0 * u)
            start += rng.uniform(*p.reposition_every_s)
    return out


def _clip_norm(v: np.ndarray, limit: float) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v * np.minimum(1.0, limit / np.maximum(n, 1e-12))


def _fly(rng, tv, targets, target_vel, estimate, p: AircapParams):
    """Simulate the vehicles: positions ``(N, V, 3)`` and yaw ``(N, V)`` at ``tv``.

    Cascaded position → velocity → acceleration control (gains critically damped, speed and
    acceleration limited), the acceleration following its command through a first-order lag
    (attitude response) plus a turbulence disturbance; yaw turns towards the subject estimate
    through a rate-limited first-order lag.
    """
    n, count = targets.shape[:2]
    dt = np.diff(tv, append=tv[-1] + (tv[-1] - tv[-2]))
    kp, kv = p.position_gain_1_s, 4.0 * p.position_gain_1_s
    scale = p.turbulence_m_s2 * np.array([1.0, 1.0, 0.3])
    gust = smooth_noise(rng, tv, 3 * count, p.turbulence_hz).reshape(n, count, 3) * scale
    pos, vel, acc = targets[0].copy(), target_vel[0].copy(), np.zeros((count, 3))
    d0 = estimate[0, :2] - pos[:, :2]
    yaw = np.arctan2(d0[:, 1], d0[:, 0])
    positions, yaws = np.empty((n, count, 3)), np.empty((n, count))
    max_rate = math.radians(p.max_yaw_rate_deg_s)
    for k in range(n):
        positions[k], yaws[k] = pos, yaw
        v_des = target_vel[k] + kp * (targets[k] - pos)
        v_des[:, :2] = _clip_norm(v_des[:, :2], p.max_speed_m_s)
        v_des[:, 2] = np.clip(v_des[:, 2], -p.max_vertical_speed_m_s, p.max_vertical_speed_m_s)
        a_cmd = kv * (v_des - vel)
        a_cmd[:, :2] = _clip_norm(a_cmd[:, :2], p.max_accel_m_s2)
        a_cmd[:, 2] = np.clip(a_cmd[:, 2], -p.max_vertical_accel_m_s2, p.max_vertical_accel_m_s2)
        acc += (a_cmd - acc) * (1.0 - math.exp(-dt[k] / p.attitude_lag_s))
        vel = vel + (acc + gust[k]) * dt[k]
        pos = pos + vel * dt[k]
        d = estimate[k, :2] - pos[:, :2]
        error = np.angle(np.exp(1j * (np.arctan2(d[:, 1], d[:, 0]) - yaw)))
        yaw = yaw + np.clip(error / p.yaw_lag_s, -max_rate, max_rate) * dt[k]
    return positions, yaws


def multirotor_rotations(accelerations: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Vehicle → world rotations ``(N, 3, 3)`` of a multirotor (FLU body frame).

    Body z is the thrust direction ``a - g_world`` (the vehicle tilts with its acceleration); body x
    is the heading ``yaw`` projected onto the plane normal to body z.
    """
    thrust = accelerations + np.array([0.0, 0.0, GRAVITY_M_S2])
    zb = thrust / np.linalg.norm(thrust, axis=-1, keepdims=True)
    heading = np.stack([np.cos(yaw), np.sin(yaw), np.zeros_like(yaw)], axis=-1)
    yb = np.cross(zb, heading)
    yb /= np.linalg.norm(yb, axis=-1, keepdims=True)
    return np.stack([np.cross(yb, zb), yb, zb], axis=-1)


def _aircap(
    subject: _Subject, t0: float, t1: float, root: np.random.SeedSequence, p: AircapParams, sensors: VehicleSensors
) -> list[SimCamera]:
    count = 3
    formation_ss, *vehicle_ss = root.spawn(count + 1)
    rng = np.random.default_rng(formation_ss)
    n = int(math.floor((t1 - t0) * VEHICLE_RATE_HZ + 1e-9)) + 1
    tv = t0 + np.arange(n) / VEHICLE_RATE_HZ
    targets, target_vel, estimate = _formation_paths(rng, tv, subject, count, p)
    positions, yaws = _fly(rng, tv, targets, target_vel, estimate, p)
    cameras = []
    for i, ss in enumerate(vehicle_ss):
        camera_ss, sensor_ss = ss.spawn(2)
        cam_rng = np.random.default_rng(camera_ss)
        spline = position_spline(tv, positions[:, i])
        poses = np.tile(np.eye(4), (n, 1, 1))
        poses[:, :3, :3] = multirotor_rotations(spline(tv, 2), yaws[:, i])
        poses[:, :3, 3] = positions[:, i]
        trajectory = VehicleTrajectory(tv, poses)
        pitch = math.radians(cam_rng.uniform(*p.mount_pitch_deg))
        offset = np.asarray(p.mount_offset_m)
        mount = look_at(offset, offset + np.array([math.cos(pitch), 0.0, -math.sin(pitch)]))
        rate = cam_rng.uniform(*p.frame_rate_hz)
        start = cam_rng.uniform(3 * p.frame_jitter_s, 1.0 / rate)
        times = _frame_times(cam_rng, t0, tv[-1], rate, start, p.frame_jitter_s)
        camera = _camera(
            cam_rng, f"uav{i + 1}", trajectory.poses(times) @ mount, p.image_size, p.focal_px, (-0.12, -0.04), times, rate
        )
        camera.mount = mount
        camera.vehicle_times, camera.vehicle_poses = tv.copy(), poses
        camera.sensors = simulate_vehicle_sensors(tv, poses, sensor_ss, sensors)
        cameras.append(camera)
    return cameras


# ---------------------------------------------------------------------------------------------
# airpose: two gimballed UAVs, synchronised, no sensors


def _airpose(subject: _Subject, t0: float, t1: float, root: np.random.SeedSequence) -> list[SimCamera]:
    rng = np.random.default_rng(root)
    times = _frame_times(rng, t0, t1, FRAME_RATE_HZ)
    target = subject.at(times)
    altitude, distance = 6.5, 8.0
    # Hovering: fixed station ~10 m from where the subject starts, with a small hover wobble.
    bearing = rng.uniform(0.0, 2.0 * np.pi)
    station = subject.at(t0) + np.array([distance * math.cos(bearing), distance * math.sin(bearing), 0.0])
    station[2] = altitude
    hover = station + 0.1 * smooth_noise(rng, times, 3, (0.05, 0.5))
    # Circling: around the (lagged) subject, starting about 120° from the hovering one.
    centre = _lag(times, target, 2.0)
    rate = math.radians(rng.uniform(6.0, 10.0)) * rng.choice([-1.0, 1.0])
    angle = bearing + math.radians(rng.uniform(100.0, 140.0)) + rate * (times - t0)
    radius = distance + 0.5 * smooth_noise(rng, times, 1, (1 / 30, 1 / 8))[:, 0]
    circle = centre + np.stack([radius * np.cos(angle), radius * np.sin(angle), np.zeros_like(angle)], axis=-1)
    circle[:, 2] = altitude + 0.3 * smooth_noise(rng, times, 1, (1 / 30, 1 / 8))[:, 0]
    cameras = []
    for name, path in (("uav_hover", hover), ("uav_circle", circle)):
        poses = _pointing(rng, times, path, target, lag_s=0.3, jitter_deg=0.3, jitter_hz=(1.0, 5.0), pitch_limits_deg=(0.0, 45.0))
        cameras.append(_camera(rng, name, poses, (1920, 1080), (1300.0, 1500.0), (-0.08, -0.02), times))
    return cameras


# ---------------------------------------------------------------------------------------------
# Hand-held camera: a person walking with a phone or camera, aiming at the subject


def _handheld(rng, times, path_xy: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Poses of a hand-held camera carried along ``path_xy (T, 2)`` at chest height."""
    height = 1.45 + 0.02 * np.sin(2 * np.pi * 1.8 * (times - times[0])) + 0.03 * smooth_noise(rng, times, 1, (0.05, 0.3))[:, 0]
    position = np.column_stack([path_xy, height]) + 0.01 * smooth_noise(rng, times, 3, (1.0, 4.0))
    return _pointing(rng, times, position, target, lag_s=0.4, jitter_deg=0.8)


# ---------------------------------------------------------------------------------------------
# rich: seven static cameras around a room and one hand-held camera


def _rich(subject: _Subject, t0: float, t1: float, root: np.random.SeedSequence) -> list[SimCamera]:
    rng = np.random.default_rng(root)
    times = _frame_times(rng, t0, t1, FRAME_RATE_HZ)
    centre, half = _area(subject, times, (3.0, 3.0), 1.5)
    size, focal = (1920, 1080), (950.0, 1150.0)
    cameras = []
    first = rng.uniform(0.0, 2.0 * np.pi)
    for k in range(7):
        angle = first + 2 * np.pi * k / 7 + rng.uniform(-0.15, 0.15)
        c, s = math.cos(angle), math.sin(angle)
        reach = min(half[0] / max(abs(c), 1e-9), half[1] / max(abs(s), 1e-9)) - 0.25
        position = [centre[0] + reach * c, centre[1] + reach * s, rng.uniform(1.0, 2.5)]
        look = [centre[0] + rng.uniform(-0.3, 0.3), centre[1] + rng.uniform(-0.3, 0.3), 0.9]
        cameras.append(_static_camera(rng, f"cam{k + 1}", position, look, size, focal, (-0.05, 0.0), times))
    target = subject.at(times)
    middle = _lag(times, target, 1.5)[:, :2]
    rate = 0.16 * rng.choice([-1.0, 1.0])  # rad/s: ~0.4 m/s on a 2.5 m circle
    angle = rng.uniform(0.0, 2.0 * np.pi) + rate * (times - t0) + 0.2 * smooth_noise(rng, times, 1, (0.02, 0.1))[:, 0]
    radius = 2.5 + 0.3 * smooth_noise(rng, times, 1, (0.02, 0.1))[:, 0]
    path = middle + radius[:, None] * np.column_stack([np.cos(angle), np.sin(angle)])
    cameras.append(_camera(rng, "handheld", _handheld(rng, times, path, target), size, focal, (-0.05, 0.0), times))
    return cameras


# ---------------------------------------------------------------------------------------------
# phones: two phones on tripods and two carried by people walking along the walls of a field


# The back camera in the phone's IMU frame (Android's device axes: x right and y up along the
# screen held in portrait, z out of the screen): the lens 6 cm above and 2 cm beside the IMU,
# looking away from the screen; in landscape the phone is turned a quarter to the left.
PHONE_LENS_M = (0.02, 0.06, -0.005)
PHONE_MOUNTS = {
    (1080, 1920): np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]),  # portrait
    (1920, 1080): np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]),  # landscape
}


def phone_mount(image_size: tuple[int, int]) -> np.ndarray:
    """``(4, 4)`` imu_T_camera of a phone's back camera filming in ``image_size`` (portrait or landscape)."""
    mount = np.eye(4)
    mount[:3, :3] = PHONE_MOUNTS[tuple(image_size)]
    mount[:3, 3] = PHONE_LENS_M
    return mount


def _phones(subject: _Subject, t0: float, t1: float, root: np.random.SeedSequence, imu: PhoneImu | None) -> list[SimCamera]:
    rng = np.random.default_rng(root)
    imu_streams = root.spawn(2)  # apart from rng: the rig is the same with and without IMUs
    times = _frame_times(rng, t0, t1, FRAME_RATE_HZ)
    centre, half = _area(subject, times, (7.5, 5.0), 2.0)
    landscape, portrait, focal = (1920, 1080), (1080, 1920), (1350.0, 1500.0)
    look = [centre[0], centre[1], 0.9]
    statics = [
        [centre[0] + rng.uniform(-2.0, 2.0), centre[1] - half[1] + 0.3, rng.uniform(1.2, 1.6)],
        [centre[0] + half[0] - 0.5, centre[1] + half[1] - 0.5, rng.uniform(1.2, 1.6)],
    ]
    cameras = [
        _static_camera(rng, f"phone_static{k + 1}", pos, look, landscape, focal, (0.0, 0.06), times) for k, pos in enumerate(statics)
    ]
    target = subject.at(times)
    follow = _lag(times, target, 1.5)
    # Walker 1 along the far long wall (portrait), walker 2 along the west short wall (landscape).
    x = np.clip(follow[:, 0], centre[0] - half[0] + 0.5, centre[0] + half[0] - 0.5)
    y = np.clip(follow[:, 1], centre[1] - half[1] + 0.5, centre[1] + half[1] - 0.5)
    walls = [
        ("phone_walk1", np.column_stack([x, np.full_like(x, centre[1] + half[1] - 0.3)]), portrait),
        ("phone_walk2", np.column_stack([np.full_like(y, centre[0] - half[0] + 0.3), y]), landscape),
    ]
    for (name, path, size), stream in zip(walls, imu_streams):
        camera = _camera(rng, name, _handheld(rng, times, path, target), size, focal, (0.0, 0.06), times)
        if imu is not None:
            camera.mount = phone_mount(size)
            log, camera.imu_time_offset_s = simulate_phone_imu(times, camera.world_T_camera, camera.mount, np.random.default_rng(stream), imu)
            camera.sensors = {"imu": log}
        cameras.append(camera)
    return cameras


# ---------------------------------------------------------------------------------------------


def scenario_cameras(
    preset: str,
    subject_times,
    subject_positions,
    seed: int = 0,
    duration_s: float | None = None,
    *,
    aircap: AircapParams = AircapParams(),
    sensors: VehicleSensors = VehicleSensors(),
    phone_imu: PhoneImu | None = PhoneImu(),
) -> list[SimCamera]:
    """Cameras (and vehicles with sensors) of ``preset`` around the subject's root trajectory.

    Args:
        preset: one of :data:`PRESETS`.
        subject_times: ``(T,)`` seconds of the subject's root positions, strictly increasing.
        subject_positions: ``(T, 3)`` world positions of the pelvis (Z up, ground at z = 0).
        seed: the same seed gives the same cameras, trajectories and sensor noise.
        duration_s: the capture spans ``[subject_times[0], subject_times[0] + duration_s]``, cut
            to the subject's last timestamp; None = the whole subject trajectory.
        aircap: formation and flight dynamics of ``aircap`` (ignored by the other presets).
        sensors: noise of the vehicles' sensors in ``aircap`` (ignored by the other presets).
        phone_imu: the IMUs of the carried phones in ``phones`` (None: no IMU logs).
    """
    if preset not in PRESETS:
        raise MocapgraphError(f"unknown scenario preset {preset!r}; presets: {', '.join(PRESETS)}")
    subject = _Subject(subject_times, subject_positions)
    t0, t1 = float(subject.times[0]), float(subject.times[-1])
    if duration_s is not None:
        if duration_s <= 0:
            raise MocapgraphError(f"duration_s: must be positive, got {duration_s}")
        t1 = min(t1, t0 + float(duration_s))
    if t1 - t0 < 0.5:
        raise MocapgraphError(f"the capture would last {t1 - t0:.3f} s; scenarios need at least 0.5 s")
    root = np.random.SeedSequence([int(seed), PRESETS.index(preset)])
    if preset == "aircap":
        return _aircap(subject, t0, t1, root, aircap, sensors)
    if preset == "phones":
        return _phones(subject, t0, t1, root, phone_imu)
    return {"airpose": _airpose, "rich": _rich}[preset](subject, t0, t1, root)
