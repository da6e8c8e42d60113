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
``docs/phone-imu.md`` has the measured effect. A step with a gap in the log gets no factor, and
the bias starts afresh, under its prior, after a gap.

In a world whose gravity direction is unknown (AirPose's: camera 1's frame), only the gyroscope
is used: :meth:`CameraImu.gyro_increment` for :func:`~mocapgraph.factors.camera_priors.camera_gyro_factor`.

The log's clock against the camera's (a phone's are tens of ms apart):
:func:`estimated_clock_offsets` finds each offset where the camera's track alone, on its views
of a solved body held, fits best with the gyroscope shifted by it (:func:`track_cost`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property

import gtsam
import numpy as np

from mocapgraph.body.model import BodyModel
from mocapgraph.body.rotations import nearest_rotation
from mocapgraph.errors import MocapgraphError, as_checked_array
from mocapgraph.factors.camera_priors import GyroIncrement, camera_gyro_factor, camera_points_factor
from mocapgraph.factors.keys import camera_bias_key, camera_key
from mocapgraph.factors.navigation import FusionNoise, preintegration_params
from mocapgraph.factors.smoothness import camera_acceleration_factor
from mocapgraph.graphs.keypoint_fit import camera_views
from mocapgraph.graphs.navigation import hold_intervals
from mocapgraph.graphs.state_model import Estimate, StateModel

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
        return self._segments

    @cached_property
    def _segments(self) -> list[tuple[float, float]]:
        dt = np.diff(self.t)
        breaks = np.flatnonzero(dt > GAP_PERIODS * np.median(dt))
        starts = np.r_[0, breaks + 1]
        ends = np.r_[breaks, len(self.t) - 1]
        return [(float(self.t[a]), float(self.t[b])) for a, b in zip(starts, ends) if b > a]

    def covers(self, t0: float, t1: float) -> bool:
        """Whether one stretch of the log without a gap spans ``[t0, t1]``."""
        return any(a <= t0 and t1 <= b for a, b in self._segments)

    def shifted(self, offset_s: float) -> CameraImu:
        """The log on the camera's clock when its own runs ``offset_s`` ahead (``log t = camera t + offset``)."""
        return CameraImu(self.t - offset_s, self.accel, self.gyro, self.imu_T_camera)

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

    def gyro_increment(self, t0: float, t1: float, params: gtsam.PreintegrationCombinedParams) -> GyroIncrement:
        """The camera's rotation from ``t0`` to ``t1`` (inside one stretch) by the gyroscope, for
        :func:`~mocapgraph.factors.camera_priors.camera_gyro_factor`: GTSAM's preintegration,
        its bias Jacobian by central differences of its own bias correction (not exposed in
        Python; exact for its first-order model), its rotation block of the covariance."""
        pim = self.preintegrate(t0, t1, params)
        rotation = pim.deltaRij()
        h, columns = 1e-4, []
        for k in range(3):
            step = np.eye(3)[k] * h
            turned = [rotation.between(pim.predict(gtsam.NavState(), gtsam.imuBias.ConstantBias(np.zeros(3), s)).attitude()) for s in (step, -step)]
            columns.append((gtsam.Rot3.Logmap(turned[0]) - gtsam.Rot3.Logmap(turned[1])) / (2 * h))
        return GyroIncrement(rotation.matrix(), np.stack(columns, axis=1), np.asarray(pim.preintMeasCov())[:3, :3])


def imu_factor(pose_keys, velocity_keys, bias_keys, pim: gtsam.PreintegratedCombinedMeasurements) -> gtsam.CombinedImuFactor:
    """GTSAM's ``CombinedImuFactor`` between a camera's two frames: ``(pose, velocity, bias)`` at each."""
    (p0, p1), (v0, v1), (b0, b1) = pose_keys, velocity_keys, bias_keys
    return gtsam.CombinedImuFactor(p0, v0, p1, v1, b0, b1, pim)


def bias_prior(key: int, noise: FusionNoise = PHONE_GYRO_NOISE) -> gtsam.PriorFactorConstantBias:
    """The bias at the start of a stretch of the log: zero, within the noise's bias priors."""
    sigma = np.r_[np.full(3, noise.accel_bias_prior_m_s2), np.full(3, noise.gyro_bias_prior_rad_s)]
    return gtsam.PriorFactorConstantBias(key, gtsam.imuBias.ConstantBias(), gtsam.noiseModel.Diagonal.Sigmas(sigma))



def bias_walk_factor(key_a: int, key_b: int, dt: float, noise: FusionNoise = PHONE_GYRO_NOISE) -> gtsam.BetweenFactorConstantBias:
    """The bias's random walk over ``dt`` seconds (what ``CombinedImuFactor`` holds inside, for
    the gyroscope-only factors): ``b_b − b_a ~ N(0, walk² dt)`` per axis."""
    sigma = np.r_[np.full(3, noise.accel_bias_walk_m_s2_sqrt_s), np.full(3, noise.gyro_bias_walk_rad_s_sqrt_s)] * np.sqrt(max(dt, 1e-9))
    return gtsam.BetweenFactorConstantBias(key_a, key_b, gtsam.imuBias.ConstantBias(), gtsam.noiseModel.Diagonal.Sigmas(sigma))


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


def start_from_gyroscopes(imus: Mapping[int, CameraImu], model: StateModel, cameras: list[np.ndarray], noise: FusionNoise = PHONE_GYRO_NOISE) -> None:
    """The views' per-frame rotations of each camera with a log (``cameras``: per camera ``(F_c,
    4, 4)``, world_T_camera in a world that does not turn, changed in place), noisy and now and
    then flipped, replaced over each covered run of its frames by its gyroscope's track turned
    onto them as a whole (:func:`gyro_aligned_rotations`)."""
    for c, imu in imus.items():
        times = model.cameras[c].timestamps
        for run in covered_runs(imu, model.camera_frames(c), times):
            cameras[c][run, :3, :3] = gyro_aligned_rotations(imu, times[run], cameras[c][run, :3, :3], noise)


CLOCK_TRACK_SIGMA_M_S2 = 1.0
"""The constant-velocity model's σ in the clock offset's track (:func:`track_cost`): stiffer than
the solve's 4 m/s² (and than a carried phone's 1-4 m/s² rms), since there the track only tells
the offset: the views' pan and tilt at the hand's jitter must go to the rotation, not to a shift.
On two 3 s ``phones`` takes (four phones, clocks 23-32 ms off), from the stitched chunks: 4.7,
3.0, 1.4 and 2.1 ms off at 1; 5.4, 4.2, 2.4, 3.0 at 2; 7.2, 7.7, 4.4, 3.0 at 4 (measured)."""


def track_cost(
    imu: CameraImu, offset_s: float, times: np.ndarray, start: np.ndarray, views: tuple, noise: FusionNoise = PHONE_GYRO_NOISE,
    sigma_px: float = 3.0, sigma_m_s2: float = CLOCK_TRACK_SIGMA_M_S2, iterations: int = 10,
) -> float:  # fmt: skip
    """The cost of the camera's track alone, solved with its log shifted by ``offset_s``
    (``imu.shifted``): its poses at ``times (M,)`` (started at ``start (M, 4, 4)`` world_T_camera,
    a world that does not turn) on their ``views`` of held points (``(points (M, N, 3),
    observed (M, N, 2), weights (M, N), K (3, 3))``: :func:`~mocapgraph.factors.camera_priors.camera_points_factor`,
    Huber once a view's rms error passes 2σ), the constant-velocity model of their centres (``sigma_m_s2``) and the
    gyroscope between the frames the shifted log covers (:func:`~mocapgraph.factors.camera_priors.camera_gyro_factor`,
    its bias a state under its prior and walk). A wrong offset makes the gyroscope's turns early
    or late against the views: the hand's jitter, turns of a few mrad at 1-5 Hz, which a shift of
    the camera cannot mimic without more than 10 m/s² (docs/phone-imu.md)."""
    points, observed, weights, K = views
    shifted = imu.shifted(offset_s)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    keys = [camera_key(0, j) for j in range(len(times))]
    for j, key in enumerate(keys):
        values.insert(key, gtsam.Pose3(start[j]))
        use = (weights[j] > 0) & np.isfinite(points[j]).all(axis=1) & np.isfinite(observed[j]).all(axis=1)
        if use.any():
            graph.add(camera_points_factor(key, points[j][use], observed[j][use], K, sigma_px, 2.0))
    for triple in zip(range(len(times) - 2), range(1, len(times) - 1), range(2, len(times))):
        graph.add(camera_acceleration_factor([keys[j] for j in triple], times[list(triple)], sigma_m_s2))
    add_gyro_chain(graph, values, shifted, times, keys, noise)
    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(iterations)
    return float(graph.error(gtsam.LevenbergMarquardtOptimizer(graph, values, lm).optimize()))


def add_gyro_chain(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, imu: CameraImu, times: np.ndarray, keys: list[int], noise: FusionNoise = PHONE_GYRO_NOISE) -> int:
    """The gyroscope between consecutive poses ``keys`` at ``times (M,)`` that ``imu`` covers
    (:func:`~mocapgraph.factors.camera_priors.camera_gyro_factor`), its bias a state per pose
    (``camera_bias_key(0, j)``, inserted at zero into ``values``) under its prior at the first
    pose of each covered run and its walk between poses; returns how many steps it holds."""
    params = imu.params(noise)
    previous, steps = None, 0
    for a, b in zip(range(len(times) - 1), range(1, len(times))):
        if not imu.covers(float(times[a]), float(times[b])):
            continue
        for j in (a, b):
            if not values.exists(camera_bias_key(0, j)):
                values.insert(camera_bias_key(0, j), gtsam.imuBias.ConstantBias())
        if a != previous:
            graph.add(bias_prior(camera_bias_key(0, a), noise))
        graph.add(camera_gyro_factor(keys[a], keys[b], camera_bias_key(0, a), imu.gyro_increment(float(times[a]), float(times[b]), params)))
        graph.add(bias_walk_factor(camera_bias_key(0, a), camera_bias_key(0, b), float(times[b] - times[a]), noise))
        previous, steps = b, steps + 1
    return steps


def estimate_time_offset(
    imu: CameraImu, times: np.ndarray, start: np.ndarray, views: tuple, max_offset_s: float, step_s: float = 0.005, noise: FusionNoise = PHONE_GYRO_NOISE,
    **costs,
) -> tuple[float, np.ndarray, np.ndarray]:  # fmt: skip
    """The offset of the log's clock from the camera's (``log t = camera t + offset``), seconds:
    the minimum of :func:`track_cost` (``costs`` its weights) over a grid ``[-max_offset_s,
    max_offset_s]``, ``step_s`` apart, refined by a parabola through the best and its
    neighbours. Every offset is scored on the same frames: those inside the log at both ends of
    the grid. Returns the offset, the grid ``(G,)`` and the costs ``(G,)``; a NaN offset
    when fewer than three frames are."""
    grid = offset_grid(max_offset_s, step_s)
    keep = frames_inside(imu, times, grid)
    if len(keep) < 3:
        return float("nan"), grid, np.full(len(grid), np.nan)
    views = tuple(v[keep] for v in views[:3]) + (views[3],)
    return grid_minimum(lambda o: track_cost(imu, o, times[keep], start[keep], views, noise, **costs), grid)


def offset_grid(max_offset_s: float, step_s: float) -> np.ndarray:
    """``(G,)`` the clock offsets tried: ``[-max_offset_s, max_offset_s]``, ``step_s`` apart."""
    return np.arange(-max_offset_s, max_offset_s + 0.5 * step_s, step_s)


def frames_inside(imu: CameraImu, times: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """``(M',)`` the consecutive frames at ``times (M,)`` from the first to the last that lie
    inside the log shifted by either end of the offsets' ``grid``: every offset is scored on them."""
    ends = [imu.shifted(float(o)) for o in (grid[0], grid[-1])]
    inside = [j for j in range(len(times)) if all(e.t[0] <= times[j] <= e.t[-1] for e in ends)]
    return np.arange(inside[0], inside[-1] + 1) if inside else np.zeros(0, dtype=int)


def grid_minimum(cost, grid: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """The offset minimising ``cost(offset_s) -> float`` over the evenly spaced ``grid (G,)``
    (:func:`offset_grid`), refined by a parabola through the best and its neighbours; with the
    grid and its costs ``(G,)``."""
    step_s = float(grid[1] - grid[0]) if len(grid) > 1 else 0.0
    scores = np.array([cost(float(o)) for o in grid])
    k = int(np.argmin(scores))
    best = float(grid[k])
    if 0 < k < len(grid) - 1:
        a, b, c = scores[k - 1 : k + 2]
        curvature = a - 2 * b + c
        if curvature > 0:
            best += 0.5 * step_s * (a - c) / curvature
    return best, grid, scores


def check_max_offset(max_offset_s: float | None) -> None:
    """``imu_max_offset_s`` of the pipelines' options: seconds in (0, 1], or None (the clocks taken as one)."""
    if max_offset_s is not None and not (isinstance(max_offset_s, (int, float)) and 0 < max_offset_s <= 1.0):
        raise MocapgraphError(f"imu_max_offset_s: a number of seconds in (0, 1] or None, got {max_offset_s!r}")


def estimated_clock_offsets(
    body: BodyModel, model: StateModel, estimate: Estimate, imus: Mapping[int, CameraImu], max_offset_s: float, noise: FusionNoise = PHONE_GYRO_NOISE,
    **costs,
) -> tuple[dict[int, CameraImu], dict[int, float]]:  # fmt: skip
    """Each camera's log put on the camera's clock: the offset (:func:`estimate_time_offset`)
    at which its track alone, on its views of the solved body held (``estimate``: its body and,
    to start from, its cameras; :func:`~mocapgraph.graphs.keypoint_fit.camera_views`), fits
    best. Returns the shifted logs and per camera its offset, seconds (NaN, and the log as it
    is, where fewer than three frames fall inside the log)."""
    logs, offsets = dict(imus), {}
    for c, imu in imus.items():
        frames, points, observed, weights, K = camera_views(body, model, estimate, c)
        times = model.cameras[c].timestamps[frames]
        offsets[c] = estimate_time_offset(imu, times, estimate.cameras[c][frames], (points, observed, weights, K), max_offset_s, noise=noise, **costs)[0]
        if np.isfinite(offsets[c]):
            logs[c] = imu.shifted(offsets[c])
    return logs, offsets
