"""Onboard sensors of a vehicle simulated from its true trajectory: IMU, GPS, barometer, self-pose.

The input is ``world_T_vehicle`` sampled at the log rate (100 Hz in the scenarios), world ENU
(Z up, metres). :class:`VehicleTrajectory` turns the samples into one smooth continuous trajectory
(a quintic spline through the positions, scipy's C² rotation spline through the attitudes); it is
*the* truth: it passes exactly through every sample and every derivative the IMU reports is its
analytic derivative, so velocities, accelerations and angular rates are consistent with the poses.

Vehicle frame: FLU (x forward, y left, z up). The IMU sits at the vehicle origin with its axes
aligned to the vehicle frame, so a vehicle at rest reads ``accel = (0, 0, +g)`` (specific force
``f = R^T (a - g_world)`` with ``g_world = (0, 0, -g)``) — the convention of GTSAM's
``PreintegrationParams.MakeSharedU(GRAVITY_M_S2)``.

Each sample is the *instantaneous* value at its timestamp. Zeroth-order-hold integrators (GTSAM's
``PreintegratedImuMeasurements.integrateMeasurement(acc, omega, dt)`` treats the measurement as
constant over ``dt``) are more accurate when fed the mean of two consecutive samples for the
interval between them (see ``docs/scenarios.md``).

Every function returns a dict of arrays in the :data:`~mocapgraph.data_tools.io.capture.SENSOR_FIELDS`
layout and draws its noise from the generator it is given (same generator state, same numbers).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import make_interp_spline
from scipy.spatial.transform import Rotation, RotationSpline

from mocapgraph.body.rotations import rotvec_to_matrix
from mocapgraph.errors import MocapgraphError, as_checked_array

# Gravity magnitude of every simulation here; use the same number in GTSAM's MakeSharedU.
GRAVITY_M_S2 = 9.81
GRAVITY_WORLD = np.array([0.0, 0.0, -GRAVITY_M_S2])


# ---------------------------------------------------------------------------------------------
# The true trajectory


def position_spline(times: np.ndarray, positions: np.ndarray):
    """The quintic interpolating spline :class:`VehicleTrajectory` puts through positions ``(N, 3)``."""
    return make_interp_spline(times, positions, k=5)


class VehicleTrajectory:
    """A smooth ``world_T_vehicle(t)`` through samples ``times (N,)``, ``poses (N, 4, 4)``.

    Positions: quintic interpolating spline (continuous jerk and snap). Rotations: scipy's
    :class:`~scipy.spatial.transform.RotationSpline` (continuous angular rate and acceleration).
    Queries must lie within ``[times[0], times[-1]]``.
    """

    def __init__(self, times: np.ndarray, poses: np.ndarray):
        times = as_checked_array(times, "times", (None,))
        poses = as_checked_array(poses, "poses", (len(times), 4, 4))
        if len(times) < 6:
            raise MocapgraphError(f"times: a vehicle trajectory needs at least 6 samples, got {len(times)}")
        if np.any(np.diff(times) <= 0):
            raise MocapgraphError("times: must be strictly increasing")
        self.times = times
        self.poses_at_samples = poses
        self._position = position_spline(times, poses[:, :3, 3])
        self._rotation = RotationSpline(times, Rotation.from_matrix(poses[:, :3, :3]))

    def _check(self, t) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, dtype=float))
        slack = 1e-9 * max(1.0, abs(self.times[-1]))
        if t.size and (t.min() < self.times[0] - slack or t.max() > self.times[-1] + slack):
            raise MocapgraphError(
                f"times [{t.min():.3f}, {t.max():.3f}] s outside the trajectory [{self.times[0]:.3f}, {self.times[-1]:.3f}] s"
            )
        return np.clip(t, self.times[0], self.times[-1])

    def position(self, t) -> np.ndarray:
        """``(n, 3)`` world positions."""
        return self._position(self._check(t))

    def velocity(self, t) -> np.ndarray:
        """``(n, 3)`` world velocities, m/s."""
        return self._position(self._check(t), 1)

    def acceleration(self, t) -> np.ndarray:
        """``(n, 3)`` world accelerations (gravity not included), m/s²."""
        return self._position(self._check(t), 2)

    def rotation(self, t) -> np.ndarray:
        """``(n, 3, 3)`` vehicle → world rotations."""
        return self._rotation(self._check(t)).as_matrix()

    def angular_velocity(self, t) -> np.ndarray:
        """``(n, 3)`` angular velocity in the vehicle frame (``R^T dR/dt = skew(ω)``), rad/s."""
        return np.atleast_2d(self._rotation(self._check(t), 1))

    def poses(self, t) -> np.ndarray:
        """``(n, 4, 4)`` world_T_vehicle."""
        t = self._check(t)
        out = np.tile(np.eye(4), (len(t), 1, 1))
        out[:, :3, :3] = self.rotation(t)
        out[:, :3, 3] = self.position(t)
        return out


# ---------------------------------------------------------------------------------------------
# Random processes shared by the sensors and the scenarios


def gauss_markov(rng: np.random.Generator, times: np.ndarray, sigma, tau_s: float, dims: int) -> np.ndarray:
    """First-order Gauss-Markov (Ornstein-Uhlenbeck) process ``(N, dims)``, stationary std ``sigma``.

    Exact discretisation on any increasing ``times``; starts from its stationary distribution.
    ``sigma`` is a scalar or ``(dims,)``.
    """
    times = np.asarray(times, dtype=float)
    sigma = np.broadcast_to(np.asarray(sigma, dtype=float), (dims,))
    white = rng.standard_normal((len(times), dims))
    out = np.empty((len(times), dims))
    if len(times) == 0:
        return out
    out[0] = white[0]
    decay = np.exp(-np.diff(times) / tau_s)
    drive = np.sqrt(1.0 - decay**2)
    for k in range(1, len(times)):
        out[k] = decay[k - 1] * out[k - 1] + drive[k - 1] * white[k]
    return out * sigma


def smooth_noise(
    rng: np.random.Generator, times: np.ndarray, dims: int, freq_range_hz: tuple[float, float], components: int = 8
) -> np.ndarray:
    """Smooth random signal ``(N, dims)`` with unit std per dimension (in expectation).

    A sum of ``components`` sinusoids per dimension, frequencies log-uniform in ``freq_range_hz``
    and random phases: infinitely differentiable and defined at any time (not only on a grid).
    """
    times = np.asarray(times, dtype=float)
    lo, hi = freq_range_hz
    freqs = np.exp(rng.uniform(np.log(lo), np.log(hi), size=(components, dims)))
    phases = rng.uniform(0.0, 2.0 * np.pi, size=(components, dims))
    waves = np.sin(2.0 * np.pi * freqs[None] * times[:, None, None] + phases[None])
    return waves.sum(axis=1) * math.sqrt(2.0 / components)


def _samples(times, poses) -> tuple[np.ndarray, np.ndarray]:
    times = as_checked_array(times, "times", (None,))
    poses = as_checked_array(poses, "poses", (len(times), 4, 4))
    if len(times) == 0 or np.any(np.diff(times) <= 0):
        raise MocapgraphError("times: must be non-empty and strictly increasing")
    return times, poses


# ---------------------------------------------------------------------------------------------
# IMU


@dataclass(frozen=True)
class ImuNoise:
    """IMU errors (consumer MEMS, as on small multirotors). Noise std is per sample at the log rate.

    Attributes:
        accel_noise_m_s2: white noise std of each accelerometer sample (0.02 at 100 Hz, i.e. a
            density of 2e-3 m/s²/√Hz).
        gyro_noise_rad_s: white noise std of each gyroscope sample (0.002 at 100 Hz: 2e-4 rad/s/√Hz).
        accel_bias_m_s2: std of the constant accelerometer bias, drawn once per axis.
        gyro_bias_rad_s: std of the constant gyroscope bias (0.005 rad/s ≈ 0.3°/s).
        accel_bias_walk_m_s2_sqrt_s: random-walk density of the accelerometer bias (std grows as
            this × √t).
        gyro_bias_walk_rad_s_sqrt_s: random-walk density of the gyroscope bias.
    """

    accel_noise_m_s2: float = 0.02
    gyro_noise_rad_s: float = 0.002
    accel_bias_m_s2: float = 0.05
    gyro_bias_rad_s: float = 0.005
    accel_bias_walk_m_s2_sqrt_s: float = 1e-3
    gyro_bias_walk_rad_s_sqrt_s: float = 1e-4

    @classmethod
    def noiseless(cls) -> ImuNoise:
        return cls(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

    def densities(self, rate_hz: float) -> dict[str, float]:
        """Continuous-time densities for a filter or GTSAM's PreintegrationParams at ``rate_hz``.

        ``σ_density = σ_sample / √rate``; square them for GTSAM's covariances.
        """
        root = math.sqrt(rate_hz)
        return {
            "accel_noise_m_s2_sqrt_hz": self.accel_noise_m_s2 / root,
            "gyro_noise_rad_s_sqrt_hz": self.gyro_noise_rad_s / root,
            "accel_bias_walk_m_s2_sqrt_s": self.accel_bias_walk_m_s2_sqrt_s,
            "gyro_bias_walk_rad_s_sqrt_s": self.gyro_bias_walk_rad_s_sqrt_s,
        }


def _bias(rng, times, constant_std: float, walk: float) -> np.ndarray:
    """Constant bias plus a random walk, ``(N, 3)``; the walk starts at zero at ``times[0]``."""
    start = rng.normal(scale=constant_std, size=3)
    steps = rng.standard_normal((len(times), 3)) * walk
    steps[0] = 0.0
    steps[1:] *= np.sqrt(np.diff(times))[:, None]
    return start + np.cumsum(steps, axis=0)


def simulate_imu(times, poses, rng: np.random.Generator, noise: ImuNoise = ImuNoise()) -> dict[str, np.ndarray]:
    """IMU log ``{t, accel, gyro}`` at ``times`` from ``world_T_vehicle`` samples ``poses (N, 4, 4)``.

    ``accel``: specific force ``R^T (a - g_world)`` in the vehicle frame + bias + noise;
    ``gyro``: angular velocity in the vehicle frame + bias + noise. Derivatives are those of the
    :class:`VehicleTrajectory` through the samples.
    """
    times, poses = _samples(times, poses)
    return imu_readings(VehicleTrajectory(times, poses), times, rng, noise)


def imu_readings(traj: VehicleTrajectory, times: np.ndarray, rng: np.random.Generator, noise: ImuNoise) -> dict[str, np.ndarray]:
    """IMU log ``{t, accel, gyro}`` of ``traj`` read at ``times (N,)`` (within its span), as
    :func:`simulate_imu` describes."""
    R = traj.rotation(times)
    specific = np.einsum("nji,nj->ni", R, traj.acceleration(times) - GRAVITY_WORLD)
    omega = traj.angular_velocity(times)
    accel = specific + _bias(rng, times, noise.accel_bias_m_s2, noise.accel_bias_walk_m_s2_sqrt_s)
    gyro = omega + _bias(rng, times, noise.gyro_bias_rad_s, noise.gyro_bias_walk_rad_s_sqrt_s)
    accel = accel + rng.normal(scale=noise.accel_noise_m_s2, size=accel.shape)
    gyro = gyro + rng.normal(scale=noise.gyro_noise_rad_s, size=gyro.shape)
    return {"t": times.copy(), "accel": accel, "gyro": gyro}


@dataclass(frozen=True)
class PhoneImu:
    """A phone's IMU: consumer MEMS as in today's phones, read at ``rate_hz`` on its own clock.

    White-noise densities from the datasheets of the Bosch BMI160 (gyroscope 0.007 °/s/√Hz,
    accelerometer 180 µg/√Hz) and the TDK ICM-20600 (0.004 °/s/√Hz, 100 µg/√Hz); the constant
    biases are what is left after the phone's own calibration (the raw parts' zero offsets are
    ±3 °/s and ±40 mg); the bias random walks are the values visual-inertial odometry uses for
    phone IMUs (OpenVINS' and Kalibr's example configurations, about 2e-5 rad/s/√s and
    3e-3 m/s²/√s). ``docs/phone-imu.md`` discusses them.

    Attributes:
        rate_hz: samples per second.
        accel_noise_m_s2_sqrt_hz: accelerometer white-noise density (1.8e-3: 180 µg/√Hz).
        gyro_noise_rad_s_sqrt_hz: gyroscope white-noise density (1.2e-4: 0.007 °/s/√Hz).
        accel_bias_m_s2: std of the constant accelerometer bias per axis (about 5 mg).
        gyro_bias_rad_s: std of the constant gyroscope bias per axis (about 0.3 °/s).
        accel_bias_walk_m_s2_sqrt_s: accelerometer bias random-walk density.
        gyro_bias_walk_rad_s_sqrt_s: gyroscope bias random-walk density.
        max_time_offset_s: the log's clock is the camera's plus an offset drawn uniformly within
            ± this: a phone stamps its frames and its sensor samples on different paths (exposure
            and readout against the sensor hub's batches), unsynchronised by tens of ms, which is
            why visual-inertial odometry on phones estimates the offset online (Qin and Shen,
            IROS 2018; Ling et al., ECCV 2018).
    """

    rate_hz: float = 200.0
    accel_noise_m_s2_sqrt_hz: float = 1.8e-3
    gyro_noise_rad_s_sqrt_hz: float = 1.2e-4
    accel_bias_m_s2: float = 0.05
    gyro_bias_rad_s: float = 0.005
    accel_bias_walk_m_s2_sqrt_s: float = 3e-3
    gyro_bias_walk_rad_s_sqrt_s: float = 2e-5
    max_time_offset_s: float = 0.03

    def noise(self) -> ImuNoise:
        """The per-sample errors at ``rate_hz`` (``σ_sample = density · √rate``)."""
        root = math.sqrt(self.rate_hz)
        return ImuNoise(
            self.accel_noise_m_s2_sqrt_hz * root, self.gyro_noise_rad_s_sqrt_hz * root, self.accel_bias_m_s2, self.gyro_bias_rad_s,
            self.accel_bias_walk_m_s2_sqrt_s, self.gyro_bias_walk_rad_s_sqrt_s,
        )  # fmt: skip


def simulate_phone_imu(
    times, world_T_camera, imu_T_camera, rng: np.random.Generator, phone: PhoneImu = PhoneImu()
) -> tuple[dict[str, np.ndarray], float]:
    """A hand-held phone's IMU log ``{t, accel, gyro}`` and the offset of its clock, seconds.

    Args:
        times: ``(T,)`` the camera's frame times (at least 6), seconds.
        world_T_camera: ``(T, 4, 4)`` the camera's true poses at ``times``.
        imu_T_camera: ``(4, 4)`` the camera in the IMU's frame (the capture's ``mount``).
        rng: the noise, biases and clock offset are drawn from it.
        phone: the IMU's errors and rate.

    The IMU's trajectory is :class:`VehicleTrajectory` through ``world_T_camera · camera_T_imu``;
    it is read every ``1 / rate_hz`` s over the frames' span, and the log's times are those on
    the phone's IMU clock, ``t + offset``.
    """
    times, poses = _samples(times, world_T_camera)
    imu_T_camera = as_checked_array(imu_T_camera, "imu_T_camera", (4, 4))
    traj = VehicleTrajectory(times, poses @ np.linalg.inv(imu_T_camera))
    n = int(math.floor((times[-1] - times[0]) * phone.rate_hz + 1e-9)) + 1
    log = imu_readings(traj, times[0] + np.arange(n) / phone.rate_hz, rng, phone.noise())
    offset = float(rng.uniform(-phone.max_time_offset_s, phone.max_time_offset_s))
    log["t"] = log["t"] + offset
    return log, offset


# ---------------------------------------------------------------------------------------------
# GPS


@dataclass(frozen=True)
class GpsNoise:
    """GPS position errors (single-frequency receiver on a small UAV).

    The error of a fix is white noise plus a slowly drifting first-order Gauss-Markov offset
    (multipath, atmosphere). The logged ``sigma`` is the honest total 1σ per axis,
    ``sqrt(white² + drift²)``.

    Attributes:
        horizontal_sigma_m: white noise std of each fix, east and north.
        vertical_sigma_m: white noise std of each fix, up.
        horizontal_drift_m: stationary std of the drifting offset, east and north.
        vertical_drift_m: stationary std of the drifting offset, up.
        drift_time_s: correlation time of the drift.
        fix_rate_hz: receiver fix rate. The log has one row per trajectory sample (100 Hz) and holds
            the latest fix between fixes (what a flight-controller log shows). ``None``: a new,
            independent fix on every row.
    """

    horizontal_sigma_m: float = 1.0
    vertical_sigma_m: float = 2.0
    horizontal_drift_m: float = 0.5
    vertical_drift_m: float = 1.0
    drift_time_s: float = 60.0
    fix_rate_hz: float | None = 10.0

    def sigma(self) -> np.ndarray:
        """Total 1σ per axis ``(3,)`` (east, north, up), as logged."""
        white = np.array([self.horizontal_sigma_m, self.horizontal_sigma_m, self.vertical_sigma_m])
        drift = np.array([self.horizontal_drift_m, self.horizontal_drift_m, self.vertical_drift_m])
        return np.sqrt(white**2 + drift**2)


def _fix_rows(times: np.ndarray, fix_rate_hz: float | None) -> np.ndarray:
    """For each row, the index of the row whose time is the latest fix at or before it."""
    if fix_rate_hz is None:
        return np.arange(len(times))
    bucket = np.floor((times - times[0]) * fix_rate_hz + 1e-6).astype(int)
    first = np.r_[0, np.flatnonzero(np.diff(bucket)) + 1]
    return first[np.cumsum(np.r_[0, np.diff(bucket) != 0])]


def simulate_gps(times, poses, rng: np.random.Generator, noise: GpsNoise = GpsNoise()) -> dict[str, np.ndarray]:
    """GPS log ``{t, position, sigma}``: world position of the vehicle origin + drift + noise."""
    times, poses = _samples(times, poses)
    white_std = np.array([noise.horizontal_sigma_m, noise.horizontal_sigma_m, noise.vertical_sigma_m])
    drift_std = np.array([noise.horizontal_drift_m, noise.horizontal_drift_m, noise.vertical_drift_m])
    fixes = _fix_rows(times, noise.fix_rate_hz)
    unique = np.unique(fixes)
    error = gauss_markov(rng, times[unique], drift_std, noise.drift_time_s, 3)
    error += rng.standard_normal((len(unique), 3)) * white_std
    measured = poses[unique, :3, 3] + error
    position = measured[np.searchsorted(unique, fixes)]
    return {"t": times.copy(), "position": position, "sigma": np.tile(noise.sigma(), (len(times), 1))}


# ---------------------------------------------------------------------------------------------
# Barometer


@dataclass(frozen=True)
class BaroNoise:
    """Barometric altimeter errors; the logged ``sigma`` is ``sqrt(sigma_m² + drift_m²)``.

    Attributes:
        sigma_m: white noise std of each sample.
        drift_m: stationary std of the slowly drifting offset (weather, temperature).
        drift_time_s: correlation time of the drift.
    """

    sigma_m: float = 0.3
    drift_m: float = 0.5
    drift_time_s: float = 120.0


def simulate_baro(times, poses, rng: np.random.Generator, noise: BaroNoise = BaroNoise()) -> dict[str, np.ndarray]:
    """Barometer log ``{t, altitude, sigma}``: world z of the vehicle origin + drift + noise."""
    times, poses = _samples(times, poses)
    drift = gauss_markov(rng, times, noise.drift_m, noise.drift_time_s, 1)[:, 0]
    altitude = poses[:, 2, 3] + drift + rng.normal(scale=noise.sigma_m, size=len(times))
    sigma = np.full(len(times), math.hypot(noise.sigma_m, noise.drift_m))
    return {"t": times.copy(), "altitude": altitude, "sigma": sigma}


# ---------------------------------------------------------------------------------------------
# Onboard pose estimate


@dataclass(frozen=True)
class SelfPoseError:
    """Error of the vehicle's own state estimate (its EKF): smooth, slowly drifting, bounded.

    The position and rotation errors are smooth random 3D signals scaled so that their largest
    magnitude over the log equals the bound exactly.

    Attributes:
        position_error_m: largest position error (norm) over the log.
        rotation_error_deg: largest rotation error (angle) over the log.
        drift_time_s: typical time scale of the drift (periods between 1× and 4× this).
    """

    position_error_m: float = 0.3
    rotation_error_deg: float = 1.5
    drift_time_s: float = 20.0


def _bounded_drift(rng, times, bound: float, timescale_s: float) -> np.ndarray:
    signal = smooth_noise(rng, times, 3, (1.0 / (4.0 * timescale_s), 1.0 / timescale_s))
    peak = np.linalg.norm(signal, axis=1).max(initial=0.0)
    return signal * (bound / peak) if peak > 0 else signal


def simulate_self_pose(
    times, poses, rng: np.random.Generator, error: SelfPoseError = SelfPoseError()
) -> dict[str, np.ndarray]:
    """Onboard estimate ``{t, rotation, position}``: ``R_est = Exp(δθ) R``, ``p_est = p + δp`` (world)."""
    times, poses = _samples(times, poses)
    dp = _bounded_drift(rng, times, error.position_error_m, error.drift_time_s)
    dtheta = _bounded_drift(rng, times, math.radians(error.rotation_error_deg), error.drift_time_s)
    rotation = rotvec_to_matrix(dtheta) @ poses[:, :3, :3]
    return {"t": times.copy(), "rotation": rotation, "position": poses[:, :3, 3] + dp}


# ---------------------------------------------------------------------------------------------
# All of a vehicle's sensors


@dataclass(frozen=True)
class VehicleSensors:
    """Noise settings of every sensor of one vehicle."""

    imu: ImuNoise = ImuNoise()
    gps: GpsNoise = GpsNoise()
    baro: BaroNoise = BaroNoise()
    self_pose: SelfPoseError = SelfPoseError()


def simulate_vehicle_sensors(
    times, poses, seed_sequence: np.random.SeedSequence, config: VehicleSensors = VehicleSensors()
) -> dict[str, dict[str, np.ndarray]]:
    """Every sensor log of one vehicle, each from its own child stream of ``seed_sequence``."""
    imu_ss, gps_ss, baro_ss, pose_ss = seed_sequence.spawn(4)
    return {
        "imu": simulate_imu(times, poses, np.random.default_rng(imu_ss), config.imu),
        "gps": simulate_gps(times, poses, np.random.default_rng(gps_ss), config.gps),
        "baro": simulate_baro(times, poses, np.random.default_rng(baro_ss), config.baro),
        "self_pose": simulate_self_pose(times, poses, np.random.default_rng(pose_ss), config.self_pose),
    }
