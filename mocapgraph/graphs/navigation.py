"""Camera pose priors from a vehicle's own sensors: the offline GPS/IMU/barometer fusion.

AirCap's step 2, re-run offline. Each vehicle (UAV) gets its own GTSAM graph with a navigation
state every ``1 / nav_rate_hz`` seconds (pose, velocity, IMU bias: :func:`~mocapgraph.factors.keys.nav_keys`)
and a slowly drifting offset of its GPS and barometer (:func:`~mocapgraph.factors.keys.drift_key`).
Its factors are those of :mod:`mocapgraph.factors.navigation`:

- ``CombinedImuFactor`` between consecutive states, from GTSAM's preintegration of the IMU log
  read as hold intervals (:func:`hold_intervals`), with a bias random walk;
- one position-fix factor per state: the GPS fixes and barometer samples nearest in time to the
  state, carried to its time along the IMU and averaged, ``p + d_gps = z_gps`` and
  ``p_z + d_baro = z_baro``, white noise only;
- an exact first-order Gauss-Markov chain on the sensor offsets ``d`` (a linear factor), so that
  errors that are correlated over a minute (multipath, weather) are not averaged away as if
  they were white: this is what keeps the covariances honest;
- priors on the first state: orientation (weak), velocity (weak), bias, and the offsets'
  stationary distribution.

Solved in batch by Levenberg-Marquardt (:func:`~mocapgraph.graphs.solver.levenberg_marquardt`,
driven from Python so that the CustomFactor callbacks stay O(N)); covariances from GTSAM's
marginals. A camera pose at a frame time is the IMU prediction from the previous navigation
state, times the mount: ``world_T_camera = world_T_vehicle · vehicle_T_camera``.
``docs/vehicle-fusion.md`` has the details and the measured accuracy.

:func:`online_track` gives the vehicle's own (onboard, online) estimate at the camera frames
instead. :class:`IncrementalNavigation` runs the same fusion as the logs arrive (a fixed-lag
smoother after a batch solve of the first second), for the online loop. Both take the vehicle's sensor logs as arrays: a mapping from the log's kind
(``imu``, ``gps``, ``baro``, ``self_pose``) to a dict of arrays in the capture format's
``SENSOR_FIELDS`` layout (``t`` seconds, world ENU metres, vehicle-frame IMU readings).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field

import gtsam
import numpy as np

from mocapgraph.body.rotations import matrix_to_rotvec, nearest_rotation, rotvec_to_matrix, skew
from mocapgraph.errors import MocapgraphError, as_checked_array, is_positive_number
from mocapgraph.factors.keys import drift_key, nav_keys
from mocapgraph.factors.navigation import (
    GRAVITY_M_S2,
    GRAVITY_WORLD,
    OFFSET_DIM,
    FusionNoise,
    fix_factor,
    offset_chain_factor,
    preintegration_params,
)
from mocapgraph.graphs.fixed_lag import FixedLagSmoother, Relinearisation
from mocapgraph.graphs.solver import SolverOptions, levenberg_marquardt, marginal_covariances

logger = logging.getLogger(__name__)

SensorLogs = Mapping[str, Mapping[str, np.ndarray]]
"""A vehicle's sensor logs by kind, each a dict of arrays (the capture format's ``SENSOR_FIELDS``)."""


@dataclass(frozen=True)
class OnlineNoise:
    """Typical error of the vehicle's onboard (online) estimate, the constant covariance of
    :func:`online_track`: 1σ per axis of the vehicle's orientation and position.

    The defaults fit an EKF that fuses GPS, IMU and barometer on board and whose error stays
    within about 0.3 m and 1.5° (the simulator's ``SelfPoseError`` bounds).
    """

    rotation_sigma_deg: float = 1.0
    position_sigma_m: float = 0.2


@dataclass
class VehicleTrack:
    """A camera's poses at its frame times, from its vehicle's sensors.

    Attributes:
        times: ``(T_c,)`` seconds, the camera's frame timestamps.
        world_T_camera: ``(T_c, 4, 4)``.
        covariance: ``(T_c, 6, 6)`` marginal covariance of each pose in GTSAM's Pose3 tangent
            (rotation first, then translation, both in the camera frame: the pose is
            ``world_T_camera · Exp(ξ)``).
        source: ``"fused"`` (offline fusion) or ``"online"`` (the onboard estimate).
        info: what the solve did (states, iterations, errors, seconds, …).
    """

    times: np.ndarray
    world_T_camera: np.ndarray
    covariance: np.ndarray
    source: str
    info: dict = field(default_factory=dict)

    def position_covariance_world(self) -> np.ndarray:
        """``(T_c, 3, 3)`` covariance of the camera positions in the world frame."""
        R = self.world_T_camera[:, :3, :3]
        return R @ self.covariance[:, 3:, 3:] @ np.swapaxes(R, -1, -2)


# ---------------------------------------------------------------------------------------------
# Small geometry helpers


def _interpolate_poses(t_log: np.ndarray, R_log: np.ndarray, p_log: np.ndarray, t: np.ndarray):
    """Rotations (slerp) and positions (linear) of a pose log at ``t``, held beyond its ends."""
    tq = np.clip(t, t_log[0], t_log[-1])
    if len(t_log) == 1:
        return np.repeat(R_log, len(t), axis=0), np.repeat(p_log, len(t), axis=0)
    # scipy's Slerp, R_k Exp(f Log(R_kᵀ R_k+1)), written out: building a Slerp cost ~1 ms per
    # call, and the online loop asks for one frame at a time (a third of its CPU per update)
    k = np.clip(np.searchsorted(t_log, tq, side="right") - 1, 0, len(t_log) - 2)
    f = (tq - t_log[k]) / (t_log[k + 1] - t_log[k])
    R0 = np.asarray(R_log, dtype=float)[k]
    R = R0 @ rotvec_to_matrix(f[:, None] * matrix_to_rotvec(np.swapaxes(R0, 1, 2) @ np.asarray(R_log, dtype=float)[k + 1]))
    p = np.stack([np.interp(tq, t_log, p_log[:, i]) for i in range(3)], axis=-1)
    return R, p


def _nearest(sorted_times: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Index of the element of ``sorted_times`` nearest to each ``t`` (the earlier one on a tie)."""
    t = np.asarray(t, dtype=float)
    if len(sorted_times) == 1:
        return np.zeros(t.shape, dtype=int)
    right = np.clip(np.searchsorted(sorted_times, t), 1, len(sorted_times) - 1)
    left = right - 1
    return np.where(t - sorted_times[left] <= sorted_times[right] - t, left, right)


def _mount_adjoint(mount: np.ndarray) -> np.ndarray:
    """``Ad(mount⁻¹)``: maps a vehicle-pose tangent ξ to the camera's, ``T Exp(ξ) M = T M Exp(Ad ξ)``."""
    return gtsam.Pose3(np.linalg.inv(mount)).AdjointMap()


# ---------------------------------------------------------------------------------------------
# The online track


def _mount_and_frames(vehicle_T_camera, frame_times, name: str) -> tuple[np.ndarray, np.ndarray]:
    mount = as_checked_array(vehicle_T_camera, f"camera {name!r}: vehicle_T_camera", (4, 4))
    return mount, as_checked_array(frame_times, f"camera {name!r}: frame times", (None,))


def online_track(
    sensors: SensorLogs, vehicle_T_camera, frame_times, name: str, *, noise: OnlineNoise = OnlineNoise()
) -> VehicleTrack:
    """The onboard estimate (``self_pose`` log) at the camera's frames, times the mount.

    Args:
        sensors: the vehicle's logs (:data:`SensorLogs`); needs ``self_pose``.
        vehicle_T_camera: ``(4, 4)`` the camera's mount on the vehicle.
        frame_times: ``(T_c,)`` seconds, the camera's frame timestamps.
        name: the camera's name, for messages.
        noise: the constant error of the onboard estimate (:class:`OnlineNoise`).

    Rotations are slerped and positions interpolated linearly between log samples, and held
    beyond the log's ends. The covariance is the constant :class:`OnlineNoise` of the vehicle
    pose carried to the camera by the mount's adjoint.
    """
    mount, frames = _mount_and_frames(vehicle_T_camera, frame_times, name)
    log = sensors.get("self_pose")
    if log is None:
        raise MocapgraphError(f"camera {name!r}: no onboard pose estimate without a self_pose log")
    R, p = _interpolate_poses(log["t"], log["rotation"], log["position"], frames)
    vehicle = np.tile(np.eye(4), (len(frames), 1, 1))
    vehicle[:, :3, :3], vehicle[:, :3, 3] = R, p
    sigma = np.r_[np.full(3, math.radians(noise.rotation_sigma_deg)), np.full(3, noise.position_sigma_m)]
    Ad = _mount_adjoint(mount)
    cov = Ad @ np.diag(sigma**2) @ Ad.T
    cov = 0.5 * (cov + cov.T)
    return VehicleTrack(
        times=frames.copy(),
        world_T_camera=vehicle @ mount,
        covariance=np.tile(cov, (len(frames), 1, 1)),
        source="online",
        info={"rotation_sigma_deg": noise.rotation_sigma_deg, "position_sigma_m": noise.position_sigma_m},
    )


# ---------------------------------------------------------------------------------------------
# The fusion graph: inputs


def hold_intervals(imu: Mapping[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The IMU log as zero-order-hold intervals, the way GTSAM's ``integrateMeasurement`` reads it.

    Args:
        imu: ``t (N,)`` seconds, ``accel (N, 3)`` specific force m/s² and ``gyro (N, 3)`` rate
            rad/s in the vehicle frame, each sample the instantaneous value at its time.

    Returns:
        ``accel (N-1, 3)``, ``gyro (N-1, 3)``, ``dt (N-1,)``: one held measurement per interval
        ``[t_k, t_k+1]``.

    Holding sample *k* over its interval is first-order wrong; the mean rate of the two ends and
    their mean specific force, turned by half the interval's rotation into the frame at its start
    (where a hold integrator applies it), is second-order: GTSAM then predicts 1 s of a noise-free
    scenario to under a millimetre instead of ~4 cm.
    """
    t, accel, gyro = (np.asarray(imu[k], dtype=float) for k in ("t", "accel", "gyro"))
    dt = np.diff(t)
    rate = 0.5 * (gyro[1:] + gyro[:-1])
    force = 0.5 * (accel[1:] + accel[:-1])
    return np.einsum("nij,nj->ni", rotvec_to_matrix(0.5 * rate * dt[:, None]), force), rate, dt


@dataclass
class _Imu:
    """The IMU log as hold intervals: interval k spans ``[t[k], t[k+1]]``."""

    t: np.ndarray
    accel: np.ndarray  # (N-1, 3) held specific force
    gyro: np.ndarray  # (N-1, 3) held rate
    dt: np.ndarray  # (N-1,)

    def integrate(self, pim, k0: int, t_end: float) -> None:
        """Integrate from sample ``k0`` to time ``t_end`` (the last interval possibly partial,
        extrapolated with the last interval's measurement beyond the log)."""
        k = k0
        last = len(self.dt) - 1
        while k <= last and self.t[k + 1] <= t_end + 1e-12:
            pim.integrateMeasurement(self.accel[k], self.gyro[k], self.dt[k])
            k += 1
        rest = t_end - self.t[k]
        if rest > 1e-9:
            j = min(k, last)
            pim.integrateMeasurement(self.accel[j], self.gyro[j], rest)


def _state_indices(t_imu: np.ndarray, rate_hz: float) -> np.ndarray:
    """IMU sample indices of the navigation states: nearest to a ``rate_hz`` grid, last sample included."""
    span = t_imu[-1] - t_imu[0]
    grid = t_imu[0] + np.arange(int(math.floor(span * rate_hz + 1e-9)) + 1) / rate_hz
    idx = np.unique(_nearest(t_imu, grid))
    last = len(t_imu) - 1
    if idx[-1] != last:
        # Keep the final state on the last sample; merge it with a state less than half a period away.
        if len(idx) > 1 and t_imu[last] - t_imu[idx[-1]] < 0.5 / rate_hz:
            idx[-1] = last
        else:
            idx = np.r_[idx, last]
    return idx


def _gps_fixes(gps: dict[str, np.ndarray]):
    """Distinct fixes of a GPS log (a log repeats the latest fix on every row): times, positions, sigmas."""
    pos = gps["position"]
    new = np.r_[True, np.any(pos[1:] != pos[:-1], axis=1)]
    return gps["t"][new], pos[new], gps["sigma"][new]


def _white_sigma(total: np.ndarray, drift: np.ndarray, floor: float) -> np.ndarray:
    return np.sqrt(np.maximum(total**2 - drift**2, floor**2))


def _nearest_states(state_t: np.ndarray, t: np.ndarray, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Measurements within half a state period of a state: their mask and nearest state."""
    near = _nearest(state_t, t)
    return np.abs(t - state_t[near]) <= 0.5 / rate_hz + 1e-9, near


class _Strapdown:
    """The initial guess integrated through the IMU from each state to the next: where the
    vehicle moves between states, to carry a measurement from its own time to a state's."""

    def __init__(self, imu: _Imu, idx: np.ndarray, R: np.ndarray, p: np.ndarray, v: np.ndarray):
        self.imu, self.idx = imu, idx
        n = len(imu.t)
        self.p, self.v, self.a = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
        self.end = np.zeros((len(idx), 3))  # position at state m + 1 integrated from state m
        steps = rotvec_to_matrix(imu.gyro * imu.dt[:, None])
        for m in range(len(idx) - 1):
            Rk, pk, vk = R[m], p[m].copy(), v[m].copy()
            for k in range(idx[m], idx[m + 1]):
                a = Rk @ imu.accel[k] + GRAVITY_WORLD
                self.p[k], self.v[k], self.a[k] = pk, vk, a
                dt = imu.dt[k]
                pk = pk + vk * dt + 0.5 * a * dt * dt
                vk = vk + a * dt
                Rk = Rk @ steps[k]
            self.end[m] = pk
        self.p[idx[-1]], self.state_p = p[-1], p

    def displacement(self, t: np.ndarray, state: np.ndarray) -> np.ndarray:
        """``p(t_state) − p(t)`` along the integration of the interval holding ``t`` ``(n, 3)``;
        ``state`` must be an end of that interval (the nearest state)."""
        idx, t_imu = self.idx, self.imu.t
        state_t = t_imu[idx]
        m = np.clip(np.searchsorted(state_t, t, side="right") - 1, 0, len(idx) - 2)
        m = np.where(state < m, state, np.where(state > m + 1, state - 1, m))
        k = np.clip(np.searchsorted(t_imu, t, side="right") - 1, idx[m], idx[m + 1] - 1)
        tau = (t - t_imu[k])[:, None]
        at_t = self.p[k] + self.v[k] * tau + 0.5 * self.a[k] * tau**2
        at_state = np.where((state == m)[:, None], self.state_p[m], self.end[m])
        return at_state - at_t


def _group_measurements(near: np.ndarray, values: np.ndarray, sigma: np.ndarray, shift: np.ndarray, states: int):
    """Per state: the mean of the measurements assigned to it (``near``, sorted), each moved to
    the state's time by ``shift``, and the std of that mean (white noise only:
    ``sqrt(mean σ² / count)``). Returns ``{state index: (mean (D,), sigma (D,), count)}``."""
    moved = values + shift
    count = np.bincount(near, minlength=states)
    out = {}
    for n in np.flatnonzero(count):
        sel = slice(np.searchsorted(near, n), np.searchsorted(near, n, side="right"))
        out[int(n)] = (moved[sel].mean(axis=0), np.sqrt(np.mean(sigma[sel] ** 2, axis=0) / count[n]), int(count[n]))
    return out


# ---------------------------------------------------------------------------------------------
# Initial values


def _initial_from_self_pose(log, state_t: np.ndarray):
    """Rotations, positions and velocities (central differences) of the onboard estimate."""
    R, p = _interpolate_poses(log["t"], log["rotation"], log["position"], state_t)
    h = 0.05
    _, ahead = _interpolate_poses(log["t"], log["rotation"], log["position"], state_t + h)
    _, behind = _interpolate_poses(log["t"], log["rotation"], log["position"], state_t - h)
    span = (np.clip(state_t + h, log["t"][0], log["t"][-1]) - np.clip(state_t - h, log["t"][0], log["t"][-1]))[:, None]
    v = (ahead - behind) / np.maximum(span, 1e-9)
    return R, p, v


def _gravity_aligned(accel: np.ndarray) -> np.ndarray:
    """world_R_body with body z along the mean specific force ``accel (n, 3)`` and yaw 0."""
    z = accel.mean(axis=0)
    z = z / np.linalg.norm(z)
    x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    if np.linalg.norm(x) < 1e-3:
        x = np.array([0.0, 1.0, 0.0]) - z[1] * z
    x /= np.linalg.norm(x)
    # Rows: the world axes in body coordinates.
    return np.stack([x, np.cross(z, x), z])


def _align_window(tau_fix, p_fix, tau_samples, dp, tilt: np.ndarray, yaw_starts: int = 8, iterations: int = 10):
    """Start pose of a window from its GPS fixes: least squares over ``R, p₀, v₀`` of
    ``z(τ) = p₀ + v₀ τ + ½ g τ² + R S(τ)``, or None when the window cannot tell.

    ``S(τ)`` (``dp`` at ``tau_samples``) is the double integral of the specific force in the
    window's first body frame. Gauss-Newton on ``R`` (``R Exp(δ)``, so ``∂(R S)/∂δ = −R [S]×``),
    with ``p₀, v₀`` solved alongside, from ``yaw_starts`` headings around the gravity-aligned
    ``tilt``; the lowest cost wins. A multirotor's specific force is nearly along its z axis, so
    heading shows only through the tilt changes over the window: too little motion, no answer.
    """
    if len(tau_fix) < 8 or tau_samples[-1] < 1.0:
        return None
    S = np.stack([np.interp(tau_fix, tau_samples, dp[:, i]) for i in range(3)], axis=-1)
    target = p_fix - 0.5 * GRAVITY_WORLD * tau_fix[:, None] ** 2
    A = np.zeros((len(tau_fix), 3, 9))
    A[:, :, :3] = np.eye(3)
    A[:, :, 3:6] = tau_fix[:, None, None] * np.eye(3)
    base = A.reshape(-1, 9)[:, :6].copy()  # the p₀, v₀ columns
    best = None
    for yaw in 2.0 * np.pi * np.arange(yaw_starts) / yaw_starts:
        R = rotvec_to_matrix(np.array([0.0, 0.0, yaw])) @ tilt
        for _ in range(iterations):
            predicted = S @ R.T
            A[:, :, 6:] = -R @ skew(S)
            x, *_ = np.linalg.lstsq(A.reshape(-1, 9), (target - predicted).reshape(-1), rcond=None)
            R = R @ rotvec_to_matrix(x[6:])
            if np.linalg.norm(x[6:]) < 1e-6:
                break
        x, *_ = np.linalg.lstsq(base, (target - S @ R.T).reshape(-1), rcond=None)
        cost = np.sum(((target - S @ R.T).reshape(-1) - base @ x) ** 2)
        if best is None or cost < best[0]:
            best = (cost, R, x[:3], x[3:6])
    _, R, p0, v0 = best
    # The heading must be determined: the fit's sensitivity to a turn about the vertical, with
    # p₀ and v₀ free, must beat the GPS noise (σ_yaw ≈ 1 m / ‖P⊥ j‖ under ~0.3 rad).
    j = np.cross([0.0, 0.0, 1.0], S @ R.T).reshape(-1)
    j_perp = j - base @ np.linalg.lstsq(base, j, rcond=None)[0]
    if np.linalg.norm(j_perp) < 3.0:
        return None
    return R, p0, v0


def _initial_from_alignment(imu: _Imu, idx: np.ndarray, fixes, window_s: float = 5.0):
    """Rotations, positions and velocities at the states from the IMU aligned to the GPS track.

    Within each window of about ``window_s`` seconds, the gyro gives the attitude relative to the
    window's first state and the double integral ``S(τ)`` of the specific force in that frame;
    :func:`_align_window` fits the window's start attitude, position and velocity to its GPS
    fixes. Windows restart the gyro integration, so its drift stays bounded. A window that cannot
    be solved (too few fixes, too little motion) continues the previous window's end state; the
    first one starts from the mean specific force (gravity alignment, yaw 0) at the first fix.
    Biases are ignored: this only seeds LM.
    """
    fix_t, fix_p, _ = fixes
    steps = rotvec_to_matrix(imu.gyro * imu.dt[:, None])
    state_t = imu.t[idx]
    last = len(idx) - 1
    R_out, p_out, v_out = np.empty((len(idx), 3, 3)), np.empty((len(idx), 3)), np.empty((len(idx), 3))
    start, carry = 0, None
    while True:
        end = int(np.searchsorted(state_t, state_t[start] + window_s, side="right")) - 1
        end = min(max(end, start + 1), last)
        if state_t[last] - state_t[end] < 0.5 * window_s:
            end = last  # no short window at the end
        k0, k1 = idx[start], idx[end]
        count = k1 - k0 + 1
        rel = np.empty((count, 3, 3))
        rel[0] = np.eye(3)
        dv, dp = np.zeros((count, 3)), np.zeros((count, 3))
        for j in range(count - 1):
            k = k0 + j
            a = rel[j] @ imu.accel[k]
            dp[j + 1] = dp[j] + dv[j] * imu.dt[k] + 0.5 * a * imu.dt[k] ** 2
            dv[j + 1] = dv[j] + a * imu.dt[k]
            rel[j + 1] = rel[j] @ steps[k]
        tau_samples = imu.t[k0 : k1 + 1] - imu.t[k0]
        sel = (fix_t >= imu.t[k0]) & (fix_t <= imu.t[k1])
        tilt = carry[0] if carry is not None else _gravity_aligned(imu.accel[k0 : max(k1, k0 + 1)])
        solved = _align_window(fix_t[sel] - imu.t[k0], fix_p[sel], tau_samples, dp, tilt)
        if solved is not None:
            R0, p0, v0 = solved
        elif carry is not None:
            R0, p0, v0 = carry
        else:
            R0, v0 = tilt, np.zeros(3)
            p0 = fix_p[_nearest(fix_t, state_t[:1])[0]]
        for n in range(start, end + 1):
            j = idx[n] - k0
            tau = tau_samples[j]
            R_out[n] = R0 @ rel[j]
            v_out[n] = v0 + GRAVITY_WORLD * tau + R0 @ dv[j]
            p_out[n] = p0 + v0 * tau + 0.5 * GRAVITY_WORLD * tau**2 + R0 @ dp[j]
        if end == last:
            return R_out, p_out, v_out
        carry = (R_out[end], p_out[end], v_out[end])
        start = end


# ---------------------------------------------------------------------------------------------
# The fusion graph


def _measurements(name: str, baro_log, imu: _Imu, idx: np.ndarray, fixes, initial, noise: FusionNoise, rate_hz: float):
    """GPS and barometer measurements per state: ``{state: (mean, sigma, count)}`` each.

    The GPS fixes and barometer samples within half a period of a state, carried to its time
    along the IMU-integrated initial guess (:class:`_Strapdown`), averaged; their std is the
    white part only (the drift is the offset state's).
    """
    state_t = imu.t[idx]
    strapdown = _Strapdown(imu, idx, *initial)
    drift = noise.drift_sigma()
    keep, near = _nearest_states(state_t, fixes[0], rate_hz)
    white = _white_sigma(fixes[2][keep], drift[:3], noise.min_white_sigma_m)
    shift = strapdown.displacement(fixes[0][keep], near[keep])
    gps = _group_measurements(near[keep], fixes[1][keep], white, shift, len(idx))
    if not gps:
        raise MocapgraphError(f"camera {name!r}: no GPS fix within the IMU log [{imu.t[0]:.3f}, {imu.t[-1]:.3f}] s")
    baro = {}
    if baro_log is not None:
        keep, near = _nearest_states(state_t, baro_log["t"], rate_hz)
        white = _white_sigma(np.asarray(baro_log["sigma"])[keep], drift[3], noise.min_white_sigma_m)
        shift = strapdown.displacement(baro_log["t"][keep], near[keep])[:, 2:]
        baro = _group_measurements(near[keep], baro_log["altitude"][keep, None], white[:, None], shift, len(idx))
    return gps, baro


def _graph(imu: _Imu, idx: np.ndarray, initial, gps: dict, baro: dict, noise: FusionNoise):
    """The fusion graph without the first pose's prior (:func:`_solve` adds it), and its initial values."""
    R_init, p_init, v_init = initial
    state_t = imu.t[idx]
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    zero_bias = gtsam.imuBias.ConstantBias()
    _, v0, b0 = nav_keys(0)
    graph.add(gtsam.PriorFactorVector(v0, v_init[0], gtsam.noiseModel.Isotropic.Sigma(3, noise.initial_velocity_sigma_m_s)))
    bias_sigma = np.r_[np.full(3, noise.accel_bias_prior_m_s2), np.full(3, noise.gyro_bias_prior_rad_s)]
    graph.add(gtsam.PriorFactorConstantBias(b0, zero_bias, gtsam.noiseModel.Diagonal.Sigmas(bias_sigma)))
    graph.add(gtsam.PriorFactorVector(drift_key(0), np.zeros(OFFSET_DIM), gtsam.noiseModel.Diagonal.Sigmas(noise.drift_sigma())))
    params = preintegration_params(noise)
    for n in range(len(idx)):
        x, v, b = nav_keys(n)
        values.insert(x, gtsam.Pose3(gtsam.Rot3(nearest_rotation(R_init[n])), p_init[n]))
        values.insert(v, v_init[n])
        values.insert(b, zero_bias)
        values.insert(drift_key(n), np.zeros(OFFSET_DIM))
        if n > 0:
            _add_edge(graph, imu, idx[n - 1], state_t[n - 1], state_t[n], n, params, noise)
        at_state = {kind: grouped[n][:2] for kind, grouped in (("gps", gps), ("baro", baro)) if n in grouped}
        if at_state:
            graph.add(fix_factor(x, drift_key(n), **at_state))
    return graph, values


def _add_edge(graph, imu: _Imu, k0: int, t_from: float, t_to: float, n: int, params, noise: FusionNoise) -> None:
    """The factors between navigation states ``n - 1`` (IMU sample ``k0``, time ``t_from``) and
    ``n`` (time ``t_to``): GTSAM's preintegration of the IMU between them (``CombinedImuFactor``,
    zero bias as the preintegration point: the factor corrects for the state's bias) and the
    sensor offsets' Gauss-Markov step."""
    xp, vp, bp = nav_keys(n - 1)
    x, v, b = nav_keys(n)
    pim = gtsam.PreintegratedCombinedMeasurements(params, gtsam.imuBias.ConstantBias())
    imu.integrate(pim, k0, t_to)
    graph.add(gtsam.CombinedImuFactor(xp, vp, x, v, bp, b, pim))
    graph.add(offset_chain_factor(drift_key(n - 1), drift_key(n), t_to - t_from, noise))


def _imu_predict(imu: _Imu, k0: int, pose: gtsam.Pose3, velocity: np.ndarray, bias, t: float) -> gtsam.NavState:
    """The vehicle's pose and world velocity at ``t``: GTSAM's IMU prediction from a state at
    sample ``k0`` (its pose, world velocity and bias)."""
    pim = gtsam.PreintegratedImuMeasurements(gtsam.PreintegrationParams.MakeSharedU(GRAVITY_M_S2), bias)
    imu.integrate(pim, k0, t)
    return pim.predict(gtsam.NavState(pose, velocity), bias)


def _vehicle_poses(imu: _Imu, idx: np.ndarray, result: gtsam.Values, times: np.ndarray) -> np.ndarray:
    """``(T, 4, 4)`` world_T_vehicle at ``times``: the IMU prediction from the previous state
    with its bias; before the first state, constant velocity and orientation."""
    state_t = imu.t[idx]
    previous = np.clip(np.searchsorted(state_t, times, side="right") - 1, 0, len(idx) - 1)
    out = np.empty((len(times), 4, 4))
    for f, (t, n) in enumerate(zip(times, previous)):
        x, v, b = nav_keys(int(n))
        pose, vel = result.atPose3(x), result.atVector(v)
        if t < state_t[0]:
            out[f] = gtsam.Pose3(pose.rotation(), pose.translation() + vel * (t - state_t[0])).matrix()
        elif t - state_t[n] < 1e-9:
            out[f] = pose.matrix()
        else:
            out[f] = _imu_predict(imu, idx[n], pose, vel, result.atConstantBias(b), t).pose().matrix()
    return out


_HEADING_STARTS = 8
"""Headings tried when the start comes from aligning the IMU to the GPS track (see :func:`_solve`)."""


def _solve(graph, values, states: int, position, rotation_sigma: float, noise: FusionNoise, headings: int, max_iterations: int):
    """Add the first pose's prior and solve; returns ``(graph with the prior, SolveResult)``.

    The prior is centred on the initial guess. With ``headings > 1`` the whole initial guess is
    also turned about the vertical by ``k·360°/headings`` (each with its own prior): a short GPS
    track may leave the heading in a wrong basin, and the lowest final cost picks the basin.

    GTSAM's own LM would copy the whole Values for every CustomFactor callback (O(N²) per
    iteration, docs/solver.md); the Python-driven loop hands GTSAM Python-owned Values instead.
    """
    x0 = nav_keys(0)[0]
    sigma = gtsam.noiseModel.Diagonal.Sigmas(np.r_[np.full(3, rotation_sigma), np.full(3, noise.initial_position_sigma_m)])
    options = SolverOptions(max_iterations=max_iterations, relative_tolerance=1e-6)
    # Each heading gets a few iterations; the best one then runs to convergence.
    screen = SolverOptions(max_iterations=min(max_iterations, 8), relative_tolerance=1e-6) if headings > 1 else options
    best = None
    for k in range(headings):
        turn = gtsam.Rot3.Rz(2.0 * math.pi * k / headings)
        start = gtsam.Values(values)
        if k:
            for n in range(states):
                x = nav_keys(n)[0]
                pose = values.atPose3(x)
                start.update(x, gtsam.Pose3(turn.compose(pose.rotation()), pose.translation()))
        candidate = gtsam.NonlinearFactorGraph(graph)
        candidate.add(gtsam.PriorFactorPose3(x0, gtsam.Pose3(start.atPose3(x0).rotation(), position), sigma))
        solved = levenberg_marquardt(candidate, start, screen)
        if best is None or solved.error < best[1].error:
            best = (candidate, solved)
    candidate, solved = best
    if headings > 1 and not solved.converged:
        more = levenberg_marquardt(candidate, solved.values, options)
        more.iterations += solved.iterations
        solved = more
    return candidate, solved


def _batch(name: str, sensors: SensorLogs, imu: _Imu, idx: np.ndarray, noise: FusionNoise, rate_hz: float, max_iterations: int):
    """The whole fusion graph of the logs, solved: ``(graph with the first pose's prior,
    SolveResult, GPS and barometer measurements per state, where the start came from)``. The
    start: the onboard estimate (``self_pose``) when logged, else the IMU aligned to the GPS
    track from :data:`_HEADING_STARTS` headings."""
    fixes = _gps_fixes(sensors["gps"])
    self_pose = sensors.get("self_pose")
    if self_pose is not None and len(self_pose["t"]):
        initial = _initial_from_self_pose(self_pose, imu.t[idx])
        rotation_sigma, start, headings = noise.initial_rotation_sigma_deg, "self_pose", 1
    else:
        initial = _initial_from_alignment(imu, idx, fixes)
        rotation_sigma, start, headings = noise.aligned_rotation_sigma_deg, "IMU aligned to GPS", _HEADING_STARTS
    gps, baro = _measurements(name, sensors.get("baro"), imu, idx, fixes, initial, noise, rate_hz)
    graph, values = _graph(imu, idx, initial, gps, baro, noise)
    graph, solved = _solve(graph, values, len(idx), initial[1][0], math.radians(rotation_sigma), noise, headings, max_iterations)
    return graph, solved, gps, baro, start


def fuse_vehicle(
    sensors: SensorLogs,
    vehicle_T_camera,
    frame_times,
    name: str,
    *,
    nav_rate_hz: float = 10.0,
    noise: FusionNoise = FusionNoise(),
    max_extrapolation_s: float = 0.1,
    max_iterations: int = 50,
) -> VehicleTrack:
    """Offline GPS/IMU/barometer fusion of a camera's vehicle; its poses at the camera frames.

    Logs one INFO line on this module's logger (states, measurements, LM, seconds).

    Args:
        sensors: the vehicle's logs (:data:`SensorLogs`); needs ``imu`` and ``gps``; ``baro``
            and ``self_pose`` are used when present (``self_pose`` only to start: initial values
            and the first orientation).
        vehicle_T_camera: ``(4, 4)`` the camera's mount on the vehicle.
        frame_times: ``(T_c,)`` seconds, the camera's frame timestamps.
        name: the camera's name, for messages.
        nav_rate_hz: navigation states per second (snapped to IMU samples; one more on the last).
        noise: the noise model (:class:`~mocapgraph.factors.navigation.FusionNoise`).
        max_extrapolation_s: camera frames may lie this far outside the IMU log (constant
            velocity and orientation there); farther raises.
        max_iterations: Levenberg-Marquardt iterations.

    Returns:
        ``VehicleTrack(source="fused")``; its covariance is each frame's nearest navigation
        state's marginal covariance carried to the camera by the mount's adjoint.
    """
    if not nav_rate_hz > 0:
        raise MocapgraphError(f"nav_rate_hz: must be positive, got {nav_rate_hz}")
    mount, frames = _mount_and_frames(vehicle_T_camera, frame_times, name)
    missing = [k for k in ("imu", "gps") if k not in sensors]
    if missing:
        raise MocapgraphError(f"camera {name!r}: no {' and no '.join(missing)} log")
    clock = time.perf_counter()
    imu_log = sensors["imu"]
    if len(imu_log["t"]) < 2:
        raise MocapgraphError(f"camera {name!r}: the IMU log needs at least 2 samples")
    imu = _Imu(np.asarray(imu_log["t"], dtype=float), *hold_intervals(imu_log))
    outside = np.maximum(imu.t[0] - frames, frames - imu.t[-1]).max(initial=-np.inf)
    if outside > max_extrapolation_s:
        raise MocapgraphError(
            f"camera {name!r}: frames span [{frames[0]:.3f}, {frames[-1]:.3f}] s but the IMU log only "
            f"[{imu.t[0]:.3f}, {imu.t[-1]:.3f}] s (more than {max_extrapolation_s} s outside)"
        )
    idx = _state_indices(imu.t, nav_rate_hz)
    if len(idx) < 2:
        raise MocapgraphError(f"camera {name!r}: the IMU log is too short for two navigation states")
    state_t = imu.t[idx]
    graph, solved, gps, baro, start = _batch(name, sensors, imu, idx, noise, nav_rate_hz, max_iterations)
    result = solved.values
    nearest = _nearest(state_t, frames)
    used = sorted(set(int(m) for m in nearest))
    marginals = marginal_covariances(graph, result, [nav_keys(m)[0] for m in used])

    # Camera frames: IMU prediction from the previous state; covariance of the nearest state.
    vehicle = _vehicle_poses(imu, idx, result, frames)
    Ad = _mount_adjoint(mount)
    cov = np.stack([Ad @ marginals[nav_keys(int(m))[0]] @ Ad.T for m in nearest])
    cov = 0.5 * (cov + np.swapaxes(cov, -1, -2))
    seconds = time.perf_counter() - clock
    info = {
        "states": len(idx),
        "gps_fixes": sum(m[2] for m in gps.values()),
        "baro_samples": sum(m[2] for m in baro.values()),
        "start": start,
        "iterations": solved.iterations,
        "converged": solved.converged,
        "initial_error": solved.initial_error,
        "final_error": solved.error,
        "seconds": seconds,
    }
    logger.info(
        "vehicle fusion %s: %d states over %.1f s, %d GPS fixes, %d baro samples, start from %s; "
        "LM %d iterations%s, error %.4g -> %.4g; %.2f s",
        name, len(idx), state_t[-1] - state_t[0], info["gps_fixes"], info["baro_samples"], start,
        solved.iterations, "" if solved.converged else f" (not converged: {solved.reason})",
        solved.initial_error, solved.error, seconds,
    )  # fmt: skip
    return VehicleTrack(times=frames.copy(), world_T_camera=vehicle @ mount, covariance=cov, source="fused", info=info)


# ---------------------------------------------------------------------------------------------
# The fusion run incrementally


@dataclass(frozen=True)
class IncrementalOptions:
    """Parameters of :class:`IncrementalNavigation` (units in the names).

    Attributes:
        nav_rate_hz: navigation states per second (each on an IMU sample).
        lag_s: the fixed-lag smoother's window.
        bootstrap_s: IMU log gathered before the first solve, with an onboard estimate
            (``self_pose``) to start from; ``align_s`` without one (the IMU aligned to the GPS
            track needs the vehicle to turn: :func:`_initial_from_alignment`).
        gps_timeout_s: no GPS fix for longer than this before a time: the fusion coasts on the
            IMU there (:attr:`NavigationPrior.coasting`).
        max_extrapolation_s: a pose is given up to this far past the newest IMU sample.
        noise: the navigation graph's noise model (as offline).
    """

    nav_rate_hz: float = 10.0
    lag_s: float = 3.0
    bootstrap_s: float = 1.0
    align_s: float = 5.0
    gps_timeout_s: float = 0.5
    max_extrapolation_s: float = 0.1
    noise: FusionNoise = FusionNoise()

    def check(self) -> None:
        for name in ("nav_rate_hz", "lag_s", "bootstrap_s", "align_s", "gps_timeout_s", "max_extrapolation_s"):
            value = getattr(self, name)
            if not is_positive_number(value):
                raise MocapgraphError(f"navigation.{name}: a finite number > 0, got {value!r}")
        if self.lag_s * self.nav_rate_hz < 2:
            raise MocapgraphError(f"navigation.lag_s: the window must hold at least 2 states at {self.nav_rate_hz} Hz, got {self.lag_s} s")


@dataclass
class NavigationPrior:
    """A camera's pose at one time from :class:`IncrementalNavigation`.

    Attributes:
        world_T_camera: ``(4, 4)``.
        covariance: ``(6, 6)`` the marginal covariance of the navigation state the pose is
            predicted from, carried to the camera by the mount's adjoint (Pose3 tangent, rotation
            first, camera frame; held between states, as offline).
        coasting: no GPS fix within ``gps_timeout_s`` before the time: the pose rests on the IMU
            (its covariance grows with the outage).
        since_fix_s: seconds since the newest GPS fix used (inf before any).
    """

    world_T_camera: np.ndarray
    covariance: np.ndarray
    coasting: bool
    since_fix_s: float


_FIELDS = {"imu": ("accel", "gyro"), "gps": ("position", "sigma"), "baro": ("altitude", "sigma"), "self_pose": ("rotation", "position")}


class IncrementalNavigation:
    """The GPS/IMU/barometer fusion of :func:`fuse_vehicle` run as the logs arrive: one vehicle's
    navigation graph in a fixed-lag smoother (:class:`~mocapgraph.graphs.fixed_lag.FixedLagSmoother`).

    The first ``bootstrap_s`` of logs (``align_s`` without an onboard estimate to start from)
    are solved in batch by the offline graph (:func:`_batch`, the same factors, initial values
    and headings), which starts the smoother. After that a navigation state is created at the
    first IMU sample ``1 / nav_rate_hz`` after the previous one: the IMU preintegrated between the
    two and the offsets' Gauss-Markov step (:func:`_add_edge`, as offline), and the GPS fixes and
    barometer samples since the previous state carried to its time along the IMU prediction from
    the previous state and averaged (white noise only), as offline carries them along its guess.
    Without fixes the states rest on the IMU factors alone: the fusion coasts and its covariance
    grows.

    :meth:`camera_prior` at ``t`` predicts through the IMU from the newest state at or before
    ``t``, using the samples added so far: fed as a stream delivers them (each frame with the
    samples up to its time) it uses no sample later than ``t``. Memory: the smoother's window and
    the IMU samples of its span.

    Args:
        name: the camera's name, for messages.
        vehicle_T_camera: ``(4, 4)`` the camera's mount on the vehicle.
        options: :class:`IncrementalOptions`.

    Attributes:
        ready: whether the bootstrap solve ran (:meth:`camera_prior` gives None before).
        stats: counters: ``states``, ``gps_fixes`` and ``baro_samples`` used, ``late`` samples
            dropped (older than a sample of their kind already added, or than the newest state).
    """

    def __init__(self, name: str, vehicle_T_camera, options: IncrementalOptions = IncrementalOptions()):
        options.check()
        self.name, self.options = name, options
        self.mount = as_checked_array(vehicle_T_camera, f"camera {name!r}: vehicle_T_camera", (4, 4))
        self._adjoint = _mount_adjoint(self.mount)
        # GTSAM's default relinearisation (every 10th update, threshold 0.1): each GPS fix moves
        # the window's positions and headings a little, so a check at every update relinearised
        # the whole window (a batch step at 48-65 of 69 updates, threshold 0.05 or per type;
        # solve p50 6-14 ms against 0.5 ms, the same accuracy to 5 mm and 0.1 deg); never
        # relinearising: 1.07 m and 1.9 deg against 1.01 m and 1.5 deg (aircap 8 s, seed 1, uav1)
        self.smoother = FixedLagSmoother(options.lag_s, Relinearisation(threshold=0.1, skip=10))
        self._params = preintegration_params(options.noise)
        self._logs: dict[str, dict[str, list]] = {kind: {f: [] for f in ("t", *fields)} for kind, fields in _FIELDS.items()}
        self._newest_t = {kind: -np.inf for kind in _FIELDS}
        self._last_gps_row: np.ndarray | None = None
        self._pending: dict[str, list] = {"gps": [], "baro": []}  # (t, value, sigma) after the newest state
        self._state_t: dict[int, float] = {}  # states in the window → time
        self._imu: list[tuple[float, np.ndarray, np.ndarray]] = []  # the samples of the window's span
        self._last_fix_t = -np.inf
        self._covariance: dict[int, np.ndarray] = {}
        self.newest = -1
        self.ready = False
        self.stats = {"states": 0, "gps_fixes": 0, "baro_samples": 0, "late": 0, "bootstrap_start": None}

    # -- input ----------------------------------------------------------------------------------

    def add(self, sensors: SensorLogs) -> None:
        """Take the vehicle's new log samples (:data:`SensorLogs`: ``imu``, ``gps``, ``baro``,
        ``self_pose``; other kinds are ignored), each kind in time order."""
        # the fixes before the IMU: a state created by this call takes the fixes up to its time
        for kind in ("gps", "baro", "self_pose", "imu"):
            fields = _FIELDS[kind]
            log_ = sensors.get(kind)
            if log_ is None or not len(log_["t"]):
                continue
            t = as_checked_array(log_["t"], f"camera {self.name!r}: sensors[{kind!r}]['t']", (None,))
            arrays = {f: np.asarray(log_[f], dtype=float) for f in fields}
            for f, a in arrays.items():
                if len(a) != len(t):
                    raise MocapgraphError(f"camera {self.name!r}: sensors[{kind!r}][{f!r}] has {len(a)} rows, 't' {len(t)}")
            keep = t > self._newest_t[kind]
            self.stats["late"] += int(len(t) - keep.sum())
            if not keep.any():
                continue
            t, arrays = t[keep], {f: a[keep] for f, a in arrays.items()}
            self._newest_t[kind] = float(t[-1])
            if kind == "gps":
                # a flight log repeats the latest fix on every row: only the rows where it changes are fixes
                previous = np.vstack([self._last_gps_row[None] if self._last_gps_row is not None else np.full((1, 3), np.nan), arrays["position"][:-1]])
                new = np.any(arrays["position"] != previous, axis=1)
                self._last_gps_row = arrays["position"][-1].copy()
                t, arrays = t[new], {f: a[new] for f, a in arrays.items()}
            if not self.ready:
                for f, a in (("t", t), *arrays.items()):
                    self._logs[kind][f].append(a)
                # waiting for a first GPS fix: what the first solve can use is bounded
                horizon = self._newest_t[kind] - 2.0 * max(self.options.bootstrap_s, self.options.align_s)
                while len(self._logs[kind]["t"]) > 1 and self._logs[kind]["t"][0][-1] < horizon:
                    for parts in self._logs[kind].values():
                        del parts[0]
            elif kind in self._pending:
                newer = t > self._state_t[self.newest]
                self.stats["late"] += int(len(t) - newer.sum())
                self._pending[kind] += [(float(s), *(arrays[f][j] for f in fields)) for j, s in enumerate(t) if newer[j]]
            elif kind == "imu":
                for j in range(len(t)):
                    self._imu.append((float(t[j]), arrays["accel"][j], arrays["gyro"][j]))
                    if self._imu[-1][0] - self._state_t[self.newest] >= (1.0 - 1e-3) / self.options.nav_rate_hz:
                        self._add_state()
        if not self.ready:
            self._try_bootstrap()

    def _gathered(self, kind: str) -> dict[str, np.ndarray] | None:
        parts = self._logs[kind]
        if not parts["t"]:
            return None
        return {f: np.concatenate(a) for f, a in parts.items()}

    def _try_bootstrap(self) -> None:
        """The first solve, once enough log is gathered: the offline batch graph on it."""
        imu_log, gps_log = self._gathered("imu"), self._gathered("gps")
        if imu_log is None or gps_log is None or len(imu_log["t"]) < 2:
            return
        self_pose = self._gathered("self_pose")
        span = self.options.bootstrap_s if self_pose is not None else self.options.align_s
        if imu_log["t"][-1] - imu_log["t"][0] < span - 1e-9:
            return
        rate = self.options.nav_rate_hz
        imu = _Imu(imu_log["t"], *hold_intervals(imu_log))
        idx = _state_indices(imu.t, rate)
        if len(idx) < 2 or not np.any((gps_log["t"] >= imu.t[0]) & (gps_log["t"] <= imu.t[-1])):
            return  # a GPS outage at the start: the batch waits for a fix
        logs = {"imu": imu_log, "gps": gps_log, **{k: v for k in ("baro", "self_pose") if (v := self._gathered(k)) is not None}}
        graph, solved, gps, baro, start = _batch(self.name, logs, imu, idx, self.options.noise, rate, 50)
        state_t = imu.t[idx]
        stamps = {}
        for n, t in enumerate(state_t):
            for key in (*nav_keys(n), drift_key(n)):
                stamps[key] = float(t)
            self._state_t[n] = float(t)
        self.smoother.update(graph, solved.values, stamps)
        self.newest = len(idx) - 1
        self.ready = True
        self.stats.update(states=len(idx), gps_fixes=sum(m[2] for m in gps.values()), baro_samples=sum(m[2] for m in baro.values()), bootstrap_start=start)
        if len(gps_log["t"]):
            self._last_fix_t = float(gps_log["t"][-1])
        # what the batch did not use: the samples after the last state's half period
        after = state_t[-1] + 0.5 / rate
        for kind in self._pending:
            log_ = logs.get(kind)
            if log_ is not None:
                self._pending[kind] = [(float(s), *(log_[f][j] for f in _FIELDS[kind])) for j, s in enumerate(log_["t"]) if s > after]
        self._imu = [(float(s), imu_log["accel"][k], imu_log["gyro"][k]) for k, s in enumerate(imu_log["t"])]
        self._forget()
        self._logs = {kind: {f: [] for f in fields} for kind, fields in self._logs.items()}
        logger.info("incremental navigation %s: started from %d states over %.1f s (%s), LM %d iterations", self.name, len(idx), state_t[-1] - state_t[0], start, solved.iterations)

    def _imu_since(self, t0: float) -> _Imu:
        """The kept IMU samples from ``t0`` (a state's sample) on, as hold intervals."""
        start = len(self._imu)
        while start > 0 and self._imu[start - 1][0] >= t0 - 1e-9:
            start -= 1
        kept = self._imu[start:]
        t = np.array([s[0] for s in kept])
        if len(t) < 2:
            return _Imu(t, np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
        return _Imu(t, *hold_intervals({"t": t, "accel": np.array([s[1] for s in kept]), "gyro": np.array([s[2] for s in kept])}))

    def _add_state(self) -> None:
        """A navigation state at the newest IMU sample: its factors and one smoother update."""
        noise = self.options.noise
        n, previous = self.newest + 1, self.newest
        t_prev, t_n = self._state_t[previous], self._imu[-1][0]
        imu, k0 = self._imu_since(t_prev), 0
        estimate = self.smoother.estimate
        x, v, b = nav_keys(previous)
        pose, velocity, bias = estimate.atPose3(x), estimate.atVector(v), estimate.atConstantBias(b)
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        _add_edge(graph, imu, k0, t_prev, t_n, n, self._params, noise)
        predicted = _imu_predict(imu, k0, pose, velocity, bias, t_n)
        values.insert(nav_keys(n)[0], predicted.pose())
        values.insert(nav_keys(n)[1], predicted.velocity())
        values.insert(nav_keys(n)[2], bias)
        phi = np.exp(-(t_n - t_prev) / noise.drift_time())
        values.insert(drift_key(n), phi * estimate.atVector(drift_key(previous)))
        drift = noise.drift_sigma()
        at_state = {}
        for kind, rows, white_drift in (("gps", slice(0, 3), drift[:3]), ("baro", slice(2, 3), drift[3])):
            taken = [m for m in self._pending[kind] if m[0] <= t_n]
            self._pending[kind] = [m for m in self._pending[kind] if m[0] > t_n]
            if not taken:
                continue
            times = np.array([m[0] for m in taken])
            values_ = np.array([np.atleast_1d(m[1]) for m in taken], dtype=float)
            sigma = np.array([np.broadcast_to(m[2], values_.shape[1:]) for m in taken], dtype=float)
            # carried to the state's time along the IMU prediction from the previous state
            shift = np.stack([predicted.position() - _imu_predict(imu, k0, pose, velocity, bias, s).position() for s in times])[:, rows]
            white = _white_sigma(sigma, white_drift, noise.min_white_sigma_m)
            mean, std, count = _group_measurements(np.zeros(len(times), dtype=int), values_, white, shift, 1)[0]
            at_state[kind] = (mean, std)
            self.stats["gps_fixes" if kind == "gps" else "baro_samples"] += count
            if kind == "gps":
                self._last_fix_t = max(self._last_fix_t, float(times[-1]))
        if at_state:
            graph.add(fix_factor(nav_keys(n)[0], drift_key(n), **at_state))
        stamps = {key: t_n for key in (*nav_keys(n), drift_key(n))}
        self.smoother.update(graph, values, stamps)
        self._state_t[n] = t_n
        self.newest = n
        self.stats["states"] += 1
        self._forget()

    def _forget(self) -> None:
        """Drop what left the window: states, cached covariances, IMU samples before the oldest state."""
        for n in [n for n in self._state_t if not self.smoother.holds(nav_keys(n)[0])]:
            del self._state_t[n]
        self._covariance = {}
        if self._state_t and self._imu:
            oldest = min(self._state_t.values())
            start = int(np.searchsorted([s[0] for s in self._imu], oldest - 1e-9))
            del self._imu[:start]

    # -- output ---------------------------------------------------------------------------------

    def camera_prior(self, t: float) -> NavigationPrior | None:
        """The camera's pose at ``t`` (the IMU prediction from the newest state at or before
        ``t``, times the mount) and its covariance; None before the bootstrap, before the window,
        or more than ``max_extrapolation_s`` past the newest IMU sample."""
        if not self.ready or not self._imu or t > self._imu[-1][0] + self.options.max_extrapolation_s:
            return None
        before = [n for n, s in self._state_t.items() if s <= t + 1e-9]
        if not before:
            return None
        n = max(before)
        estimate = self.smoother.estimate
        x, v, b = nav_keys(n)
        imu, k0 = self._imu_since(self._state_t[n]), 0
        if len(imu.dt):
            pose = _imu_predict(imu, k0, estimate.atPose3(x), estimate.atVector(v), estimate.atConstantBias(b), t).pose().matrix()
        else:  # the state's sample is the only one: constant velocity
            pose = gtsam.Pose3(estimate.atPose3(x).rotation(), estimate.atPose3(x).translation() + estimate.atVector(v) * (t - self._state_t[n])).matrix()
        if n not in self._covariance:
            cov = self._adjoint @ self.smoother.marginal_covariance(x) @ self._adjoint.T
            self._covariance[n] = 0.5 * (cov + cov.T)
        since = t - self._last_fix_t
        return NavigationPrior(pose @ self.mount, self._covariance[n], bool(since > self.options.gps_timeout_s), float(since))
