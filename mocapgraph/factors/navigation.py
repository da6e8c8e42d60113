"""Factors of a vehicle's GPS/IMU/barometer navigation graph and their noise model.

World frame ENU (Z up), metres, seconds. A navigation state ``n`` is the vehicle's pose
``world_T_vehicle`` (``gtsam.Pose3``), its velocity in the world frame and its IMU bias
(:func:`~mocapgraph.factors.keys.nav_keys`), plus the slowly drifting offsets of its GPS and
barometer, ``d = (east, north, up, baro)`` metres (:func:`~mocapgraph.factors.keys.drift_key`).

- :func:`preintegration_params`: GTSAM's IMU preintegration (``CombinedImuFactor``) with
  gravity :data:`GRAVITY_M_S2` along −Z;
- :func:`fix_factor`: a GPS fix and/or a barometer sample, ``p + d_gps = z_gps`` and
  ``p_z + d_baro = z_baro``, white noise only;
- :func:`offset_chain_factor`: the exact first-order Gauss-Markov step of ``d``;
- :class:`FusionNoise`: the noise model of all three and of the first state's priors.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from mocapgraph.errors import MocapgraphError, as_checked_array

GRAVITY_M_S2 = 9.81
"""Gravity magnitude, m/s². The simulator has its own constant; a test keeps the two equal."""

GRAVITY_WORLD = np.array([0.0, 0.0, -GRAVITY_M_S2])
"""Gravity in the world frame ``(3,)``, m/s² (Z up)."""
GRAVITY_WORLD.flags.writeable = False  # shared by every caller: an in-place edit would change them all

OFFSET_DIM = 4
"""Size of the offset state ``d``: GPS east, north, up; barometer."""


@dataclass(frozen=True)
class FusionNoise:
    """Noise model of the navigation graph (defaults: a consumer MEMS IMU and a
    single-frequency GPS on a small multirotor; ``docs/vehicle-fusion.md`` discusses them).

    The GPS and barometer logs carry their own 1σ (``sigma``), the *total* error. The graph
    splits it into a drifting part (a first-order Gauss-Markov offset with the std and
    correlation time below) and a white part ``sqrt(sigma² − drift²)``, floored.

    Attributes:
        accel_noise_m_s2_sqrt_hz: accelerometer white-noise density.
        gyro_noise_rad_s_sqrt_hz: gyroscope white-noise density.
        integration_noise_m_sqrt_s: GTSAM's integration uncertainty (position from velocity);
            also keeps the batch system well conditioned (at 1e-4 GTSAM's Cholesky reports an
            indeterminate system).
        accel_bias_walk_m_s2_sqrt_s: accelerometer bias random-walk density.
        gyro_bias_walk_rad_s_sqrt_s: gyroscope bias random-walk density.
        accel_bias_prior_m_s2: std of the accelerometer bias at the first state (prior mean 0).
        gyro_bias_prior_rad_s: std of the gyroscope bias at the first state (prior mean 0).
        gps_drift_horizontal_m: stationary std of the GPS offset, east and north.
        gps_drift_vertical_m: stationary std of the GPS offset, up.
        gps_drift_time_s: correlation time of the GPS offset.
        baro_drift_m: stationary std of the barometer offset from the world's z (set it large
            when the barometer is not referenced to the GPS altitude).
        baro_drift_time_s: correlation time of the barometer offset.
        min_white_sigma_m: floor of the white std of one GPS fix or barometer sample.
        initial_rotation_sigma_deg: prior std of the first orientation when it comes from the
            onboard estimate (``self_pose``), per axis: about the estimate's largest error, i.e.
            weaker than its typical error (about 1°).
        aligned_rotation_sigma_deg: the same when it comes from aligning the IMU to the GPS track.
        initial_velocity_sigma_m_s: prior std of the first velocity (about its initial guess).
        initial_position_sigma_m: prior std of the first position (the GPS fixes pin it).
    """

    accel_noise_m_s2_sqrt_hz: float = 2e-3
    gyro_noise_rad_s_sqrt_hz: float = 2e-4
    integration_noise_m_sqrt_s: float = 1e-3
    accel_bias_walk_m_s2_sqrt_s: float = 1e-3
    gyro_bias_walk_rad_s_sqrt_s: float = 1e-4
    accel_bias_prior_m_s2: float = 0.1
    gyro_bias_prior_rad_s: float = 0.01
    gps_drift_horizontal_m: float = 0.5
    gps_drift_vertical_m: float = 1.0
    gps_drift_time_s: float = 60.0
    baro_drift_m: float = 0.5
    baro_drift_time_s: float = 120.0
    min_white_sigma_m: float = 0.05
    initial_rotation_sigma_deg: float = 1.5
    aligned_rotation_sigma_deg: float = 30.0
    initial_velocity_sigma_m_s: float = 2.0
    initial_position_sigma_m: float = 10.0

    def drift_sigma(self) -> np.ndarray:
        """Stationary std of the offset state ``(4,)``, metres: GPS east, north, up; barometer."""
        h, v = self.gps_drift_horizontal_m, self.gps_drift_vertical_m
        return np.maximum(np.array([h, h, v, self.baro_drift_m]), 1e-3)

    def drift_time(self) -> np.ndarray:
        """Correlation times ``(4,)`` of the offset state, seconds."""
        return np.array([self.gps_drift_time_s] * 3 + [self.baro_drift_time_s])


def preintegration_params(noise: FusionNoise = FusionNoise()) -> gtsam.PreintegrationCombinedParams:
    """Parameters of ``gtsam.PreintegratedCombinedMeasurements`` (for ``CombinedImuFactor``).

    Gravity :data:`GRAVITY_M_S2` along −Z of the world (``MakeSharedU``); the IMU measures the
    specific force (m/s²) and the angular rate (rad/s) in the vehicle frame. Covariances are the
    continuous-time densities of ``noise``, squared.
    """
    params = gtsam.PreintegrationCombinedParams.MakeSharedU(GRAVITY_M_S2)
    I = np.eye(3)
    params.setAccelerometerCovariance(I * noise.accel_noise_m_s2_sqrt_hz**2)
    params.setGyroscopeCovariance(I * noise.gyro_noise_rad_s_sqrt_hz**2)
    params.setIntegrationCovariance(I * noise.integration_noise_m_sqrt_s**2)
    params.setBiasAccCovariance(I * noise.accel_bias_walk_m_s2_sqrt_s**2)
    params.setBiasOmegaCovariance(I * noise.gyro_bias_walk_rad_s_sqrt_s**2)
    return params


# Rows (A_p (k, 3), A_d (k, 4)) of the fix residual A_p p + A_d d − z per sensor.
_GPS_ROWS = (np.eye(3), np.eye(3, OFFSET_DIM))
_BARO_ROWS = (np.array([[0.0, 0.0, 1.0]]), np.eye(1, OFFSET_DIM, 3))


def fix_factor(pose_key: int, offset_key: int, gps=None, baro=None) -> gtsam.CustomFactor:
    """A GPS fix and/or a barometer sample at a navigation state, white noise only.

    Residual (GPS rows first): ``p + d[:3] − z_gps`` and ``p_z + d[3] − z_baro``, metres, with
    ``p`` the position of the pose (world ENU) and ``d`` the offset state. The offsets carry the
    sensors' drift, so ``sigma`` here is only the white part of their error.

    Args:
        pose_key: the state's ``Pose3`` key (world_T_vehicle).
        offset_key: the state's offset key (``Vector(4)``).
        gps: ``(z (3,), sigma (3,))``: position east, north, up and its std, metres; or None.
        baro: ``(z (1,), sigma (1,))``: altitude (world z) and its std, metres; or None.

    Jacobians: GTSAM retracts a Pose3 as ``(R Exp(ω), p + R v)``, so ``∂p/∂(ω, v) = [0, R]``;
    ``∂/∂d`` selects the sensor's offsets.
    """
    parts = []
    for name, measurement, rows in (("gps", gps, _GPS_ROWS), ("baro", baro, _BARO_ROWS)):
        if measurement is not None:
            size = len(rows[0])
            z = as_checked_array(measurement[0], f"{name} fix", (size,))
            sigma = as_checked_array(measurement[1], f"{name} fix sigma", (size,))
            parts.append((z, sigma, rows))
    if not parts:
        raise MocapgraphError("a fix factor needs a GPS fix, a barometer sample or both")
    z = np.concatenate([p[0] for p in parts])
    sigma = np.concatenate([p[1] for p in parts])
    A_p = np.vstack([p[2][0] for p in parts])
    A_d = np.vstack([p[2][1] for p in parts])
    zeros = np.zeros((len(z), 3))

    def error(_factor, values, H):
        pose = values.atPose3(pose_key)
        residual = A_p @ pose.translation() + A_d @ values.atVector(offset_key) - z
        if H is not None:
            H[0] = np.hstack([zeros, A_p @ pose.rotation().matrix()])
            H[1] = A_d
        return residual

    return gtsam.CustomFactor(gtsam.noiseModel.Diagonal.Sigmas(sigma), [pose_key, offset_key], error)


def offset_chain_factor(key_a: int, key_b: int, dt: float, noise: FusionNoise = FusionNoise()) -> gtsam.LinearContainerFactor:
    """The exact discrete first-order Gauss-Markov step of the offsets, ``dt`` seconds apart.

    ``d_b = Φ d_a + w`` with ``Φ = exp(−dt / τ)`` and ``w ~ N(0, σ²(1 − Φ²))`` per component
    (``σ``, ``τ``: :meth:`FusionNoise.drift_sigma`, :meth:`FusionNoise.drift_time`), so a chain
    started from the stationary prior ``N(0, σ²)`` stays stationary whatever the step. The
    residual ``d_b − Φ d_a`` (metres) is linear: a ``LinearContainerFactor`` needs no Python
    callback when GTSAM linearises it.
    """
    phi = np.exp(-dt / noise.drift_time())
    q = noise.drift_sigma() * np.sqrt(np.maximum(1.0 - phi**2, 1e-12))
    linear = gtsam.JacobianFactor(key_a, -np.diag(phi), key_b, np.eye(OFFSET_DIM), np.zeros(OFFSET_DIM), gtsam.noiseModel.Diagonal.Sigmas(q))
    zero = gtsam.Values()
    zero.insert(key_a, np.zeros(OFFSET_DIM))
    zero.insert(key_b, np.zeros(OFFSET_DIM))
    return gtsam.LinearContainerFactor(linear, zero)
