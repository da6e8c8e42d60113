"""A moving camera's own IMU (a phone's gyroscope and accelerometer) as a prior on its motion.

Between two consecutive frames ``j``, ``j'`` of a moving camera that its IMU log covers without
a gap, GTSAM's preintegration of the log (read as hold intervals,
:func:`~mocapgraph.graphs.navigation.hold_intervals`) gives a ``CombinedImuFactor`` on the
camera's poses ``world_T_camera`` at both frames (the camera keys of the state model), its
velocities there (:func:`~mocapgraph.factors.keys.camera_velocity_key`, world frame, m/s) and
its IMU biases (:func:`~mocapgraph.factors.keys.camera_bias_key`, with their random walk between
the two). The camera is the preintegration's body frame: the capture's mount (``imu_T_camera``)
is GTSAM's ``body_P_sensor`` inverted, so the IMU's lever arm and axes are undone inside GTSAM.
Gravity is :data:`~mocapgraph.factors.navigation.GRAVITY_M_S2` along the world's −Z, as in
every world frame here (SmartMocap's: Z up from the ground plane).

What the factor holds: the rotation between the frames from the gyroscope, always; the change
of velocity and the displacement from the accelerometer only relative to gravity and to the
velocities, which nothing but the camera's poses (the body it sees, the other cameras through
the body) pins: a camera seen by nobody else keeps its rotations but drifts in translation.
``docs/phone-imu.md`` has the measured effect. The log's clock is taken as the camera's (the
simulator's phones are up to 10 ms apart); a step with a gap in the log gets no factor, and the
bias starts afresh, under its prior, after a gap.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property

import gtsam
import numpy as np

from mocapgraph.body.rotations import nearest_rotation
from mocapgraph.errors import MocapgraphError, as_checked_array
from mocapgraph.factors.navigation import FusionNoise, preintegration_params
from mocapgraph.graphs.navigation import hold_intervals

PHONE_IMU_NOISE = FusionNoise(
    accel_noise_m_s2_sqrt_hz=3.6e-3,
    gyro_noise_rad_s_sqrt_hz=2.4e-4,
    accel_bias_walk_m_s2_sqrt_s=3e-3,
    gyro_bias_walk_rad_s_sqrt_s=2e-5,
    accel_bias_prior_m_s2=0.1,
    gyro_bias_prior_rad_s=0.01,
)
"""A phone IMU's noise at its datasheet's: twice the white-noise densities of its datasheets (the
BMI160's, as the simulator's :class:`~mocapgraph.data_tools.sim.sensors.PhoneImu`), for what
the hold intervals and the unmodelled clock offset add; bias walks as simulated; bias priors
twice the simulated spread of the biases left after the phone's calibration."""

PHONE_GYRO_NOISE = FusionNoise(
    accel_noise_m_s2_sqrt_hz=1.0,
    gyro_noise_rad_s_sqrt_hz=2.4e-4,
    accel_bias_walk_m_s2_sqrt_s=0.05,
    gyro_bias_walk_rad_s_sqrt_s=2e-5,
    accel_bias_prior_m_s2=0.3,
    gyro_bias_prior_rad_s=0.01,
)
"""The gyroscope as :data:`PHONE_IMU_NOISE`, the accelerometer down-weighted to a motion model
(a velocity change of 0.18 m/s per 1/30 s step at 1σ, about the constant-velocity model's 4 m/s²):
for a world whose gravity direction and scale are only as good as the ground and the body's size
(with :data:`PHONE_IMU_NOISE` two of five 3 s ``phones`` takes went metres away; the default of
:class:`~mocapgraph.graphs.body_graph.GraphOptions`)."""

GAP_PERIODS = 3.0
"""Consecutive samples further apart than this many median sample periods are a gap in the log."""


@dataclass(frozen=True)
class CameraImu:
    """One camera's IMU log and where the camera sits on the IMU.

    Attributes:
        t: ``(N,)`` seconds on the camera's clock, strictly increasing.
        accel: ``(N, 3)`` specific force in the IMU frame, m/s² (at rest: ``(0, 0, +g)`` rotated into it).
        gyro: ``(N, 3)`` angular rate in the IMU frame, rad/s.
        imu_T_camera: ``(4, 4)`` the camera in the IMU's frame (the capture's ``mount``).
    """

    t: np.ndarray
    accel: np.ndarray
    gyro: np.ndarray
    imu_T_camera: np.ndarray

    @classmethod
    def from_log(cls, log: Mapping[str, np.ndarray], imu_T_camera, name: str) -> CameraImu:
        """Checked from a capture's ``imu`` log (``t``, ``accel``, ``gyro``) and mount; ``name`` for messages."""
        t = as_checked_array(log["t"], f"camera {name!r}: imu t", (None,))
        if len(t) < 2 or np.any(np.diff(t) <= 0):
            raise MocapgraphError(f"camera {name!r}: imu t: needs at least 2 strictly increasing sample times")
        accel = as_checked_array(log["accel"], f"camera {name!r}: imu accel", (len(t), 3))
        gyro = as_checked_array(log["gyro"], f"camera {name!r}: imu gyro", (len(t), 3))
        mount = as_checked_array(imu_T_camera, f"camera {name!r}: mount (imu_T_camera)", (4, 4))
        return cls(t, accel, gyro, mount)

    @cached_property
    def held(self) -> tuple[np.ndarray, np.ndarray]:
        """``(N-1, 3)`` specific force and rate held over each interval between samples."""
        accel, gyro, _ = hold_intervals({"t": self.t, "accel": self.accel, "gyro": self.gyro})
        return accel, gyro

    def segments(self) -> list[tuple[float, float]]:
        """``[(start, end)]`` seconds of the log's stretches without a gap (:data:`GAP_PERIODS`)."""
        dt = np.diff(self.t)
        breaks = np.flatnonzero(dt > GAP_PERIODS * np.median(dt))
        starts = np.r_[0, breaks + 1]
        ends = np.r_[breaks, len(self.t) - 1]
        return [(float(self.t[a]), float(self.t[b])) for a, b in zip(starts, ends) if b > a]

    def covers(self, t0: float, t1: float) -> bool:
        """Whether one stretch of the log without a gap spans ``[t0, t1]``."""
        return any(a <= t0 and t1 <= b for a, b in self.segments())

    def params(self, noise: FusionNoise = PHONE_GYRO_NOISE) -> gtsam.PreintegrationCombinedParams:
        """GTSAM's preintegration parameters with the camera as the body (gravity along −Z)."""
        params = preintegration_params(noise)
        params.setBodyPSensor(gtsam.Pose3(np.linalg.inv(self.imu_T_camera)))
        return params

    def preintegrate(self, t0: float, t1: float, params: gtsam.PreintegrationCombinedParams) -> gtsam.PreintegratedCombinedMeasurements:
        """The log from ``t0`` to ``t1`` (inside one stretch) preintegrated at zero bias; each hold
        interval cut to the part of it inside ``[t0, t1]``."""
        accel, gyro = self.held
        pim = gtsam.PreintegratedCombinedMeasurements(params, gtsam.imuBias.ConstantBias())
        k = int(np.clip(np.searchsorted(self.t, t0, side="right") - 1, 0, len(accel) - 1))
        start = t0
        while start < t1 - 1e-12 and k < len(accel):
            end = min(float(self.t[k + 1]), t1)
            if end > start:
                pim.integrateMeasurement(accel[k], gyro[k], end - start)
            start, k = end, k + 1
        return pim


def imu_factor(pose_keys, velocity_keys, bias_keys, pim: gtsam.PreintegratedCombinedMeasurements) -> gtsam.CombinedImuFactor:
    """GTSAM's ``CombinedImuFactor`` between a camera's two frames: ``(pose, velocity, bias)`` at each."""
    (p0, p1), (v0, v1), (b0, b1) = pose_keys, velocity_keys, bias_keys
    return gtsam.CombinedImuFactor(p0, v0, p1, v1, b0, b1, pim)


def bias_prior(key: int, noise: FusionNoise = PHONE_GYRO_NOISE) -> gtsam.PriorFactorConstantBias:
    """The bias at the start of a stretch of the log: zero, within the noise's bias priors."""
    sigma = np.r_[np.full(3, noise.accel_bias_prior_m_s2), np.full(3, noise.gyro_bias_prior_rad_s)]
    return gtsam.PriorFactorConstantBias(key, gtsam.imuBias.ConstantBias(), gtsam.noiseModel.Diagonal.Sigmas(sigma))



def covered_runs(imu: CameraImu, frames: np.ndarray, times: np.ndarray) -> list[np.ndarray]:
    """Runs of consecutive ``frames`` (indices into ``times``, increasing) whose steps the log
    covers, each at least two frames long."""
    runs, run = [], [int(frames[0])] if len(frames) else []
    for a, b in zip(frames[:-1], frames[1:]):
        if imu.covers(float(times[a]), float(times[b])):
            run.append(int(b))
            continue
        if len(run) > 1:
            runs.append(np.array(run))
        run = [int(b)]
    if len(run) > 1:
        runs.append(np.array(run))
    return runs


def gyro_aligned_rotations(imu: CameraImu, times: np.ndarray, rotations: np.ndarray, noise: FusionNoise = PHONE_GYRO_NOISE) -> np.ndarray:
    """``(M, 3, 3)`` world_R_camera at ``times (M,)`` (one covered run of frames): the
    gyroscope's track at zero bias, turned as a whole onto ``rotations (M, 3, 3)`` (e.g. the
    views' per-frame ones, noisy and now and then flipped) by the chordal mean of their offsets,
    twice dropping those more than three median angles (at least 0.1 rad) away."""
    params = imu.params(noise)
    track = [np.eye(3)]
    for t0, t1 in zip(times[:-1], times[1:]):
        track.append(track[-1] @ imu.preintegrate(float(t0), float(t1), params).deltaRij().matrix())
    track = np.stack(track)
    offsets = rotations @ np.swapaxes(track, 1, 2)  # world_R_camera(t) ≈ offset · track(t)
    keep = np.ones(len(offsets), dtype=bool)
    for _ in range(2):
        mean = nearest_rotation(offsets[keep].sum(axis=0))
        cos = np.clip((np.einsum("nij,ij->n", offsets, mean) - 1.0) / 2.0, -1.0, 1.0)
        angle = np.arccos(cos)
        keep = angle <= max(3.0 * np.median(angle), 0.1)
    return nearest_rotation(offsets[keep].sum(axis=0)) @ track
