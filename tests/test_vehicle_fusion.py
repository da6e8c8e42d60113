"""Camera pose priors from the vehicles' sensors: ``factors.navigation``, ``graphs.navigation``
and ``pipelines.camera_priors``."""

from __future__ import annotations

import dataclasses
import logging

import gtsam
import numpy as np
import pytest
from scipy.stats import chi2

from mocapgraph.body.rotations import matrix_to_rotvec, rotvec_to_matrix
from mocapgraph.data_tools.io.capture import Camera, Capture
from mocapgraph.data_tools.sim import scenarios, sensors
from mocapgraph.data_tools.sim.scenarios import scenario_cameras
from mocapgraph.data_tools.sim.sensors import BaroNoise, GpsNoise, ImuNoise, SelfPoseError, VehicleSensors, VehicleTrajectory
from mocapgraph.data_tools.sim.synthetic import synthesize
from mocapgraph.errors import MocapgraphError
from mocapgraph.factors import navigation as nav_factors
from mocapgraph.factors.keys import drift_key, nav_keys
from mocapgraph.factors.navigation import FusionNoise, fix_factor, offset_chain_factor
from mocapgraph.graphs.navigation import OnlineNoise, fuse_vehicle, hold_intervals, online_track
from mocapgraph.pipelines.camera_priors import camera_priors


@pytest.fixture(scope="module")
def capture():
    return synthesize("aircap", seed=1, duration_s=8.0)


@pytest.fixture(scope="module")
def fused(capture):
    tracks, notes = camera_priors(capture, "fused")
    assert notes == []
    return tracks


def angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    return np.degrees(np.linalg.norm(matrix_to_rotvec(np.swapaxes(Ra, -1, -2) @ Rb), axis=-1))


def gps_at(camera: Camera, times: np.ndarray) -> np.ndarray:
    """The GPS position a flight log shows at each time (its latest row)."""
    gps = camera.sensors["gps"]
    return gps["position"][np.clip(np.searchsorted(gps["t"], times, side="right") - 1, 0, len(gps["t"]) - 1)]


def fuse(camera, **options):
    """:func:`fuse_vehicle` on the arrays of a capture's or a scenario's camera."""
    return fuse_vehicle(camera.sensors, camera.mount, camera.timestamps, camera.name, **options)


def without(camera, *kinds: str):
    return dataclasses.replace(camera, sensors={k: v for k, v in camera.sensors.items() if k not in kinds})


# ---------------------------------------------------------------------------------------------
# Accuracy and consistency on the aircap scenario


def test_fused_track_beats_raw_gps_and_has_small_orientation_error(capture, fused):
    assert set(fused) == {"uav1", "uav2", "uav3"}
    orientation = []
    for name, track in fused.items():
        cam, truth = capture.camera(name), capture.ground_truth.cameras[name]
        assert track.source == "fused"
        np.testing.assert_array_equal(track.times, cam.timestamps)
        assert track.world_T_camera.shape == (cam.num_frames, 4, 4) and track.covariance.shape == (cam.num_frames, 6, 6)
        fused_error = np.linalg.norm(track.world_T_camera[:, :3, 3] - truth[:, :3, 3], axis=1).mean()
        vehicle = truth @ np.linalg.inv(cam.mount)  # GPS measures the vehicle origin
        gps_error = np.linalg.norm(gps_at(cam, cam.timestamps) - vehicle[:, :3, 3], axis=1).mean()
        print(f"{name}: fused {fused_error:.3f} m, GPS {gps_error:.3f} m")
        assert fused_error < 0.7 * gps_error
        orientation.append(angle_deg(track.world_T_camera[:, :3, :3], truth[:, :3, :3]))
    mean = np.concatenate(orientation).mean()
    print(f"orientation error: mean {mean:.2f} deg, per camera {[round(float(o.mean()), 2) for o in orientation]}")
    assert mean < 2.0


def test_fused_covariance_is_consistent(capture, fused):
    inside = []
    for name, track in fused.items():
        cov = track.covariance
        np.testing.assert_allclose(cov, np.swapaxes(cov, -1, -2), atol=1e-12)
        assert np.all(np.linalg.eigvalsh(cov) > 0)
        error = track.world_T_camera[:, :3, 3] - capture.ground_truth.cameras[name][:, :3, 3]
        C = track.position_covariance_world()
        m2 = np.einsum("ni,nij,nj->n", error, np.linalg.inv(C), error)
        inside.append(m2 <= chi2.ppf(0.95, 3))
    fraction = np.concatenate(inside).mean()
    per_camera = [round(float(i.mean()), 2) for i in inside]
    print(f"camera positions inside their 95 % ellipsoid: {fraction:.3f} (per camera {per_camera})")
    assert 0.6 <= fraction <= 1.0


def test_position_uncertainty_is_the_sensor_drift_not_the_averaged_white_noise(fused):
    """80 fixes of 1 m white noise average to ~0.1 m, but the fixes share a drifting offset:
    east/north keep the GPS drift (0.5 m), up combines GPS (1.0 m) and barometer (0.5 m) drifts."""
    sd = np.sqrt(np.diagonal(fused["uav1"].position_covariance_world(), axis1=1, axis2=2)).mean(axis=0)
    np.testing.assert_allclose(sd, [0.5, 0.5, 1 / np.sqrt(1 / 1.0**2 + 1 / 0.5**2)], rtol=0.15)


# ---------------------------------------------------------------------------------------------
# Noise-free sensors


def circling_subject(duration_s: float):
    t = np.arange(int(duration_s * 30) + 16) / 30.0
    w = 2 * np.pi / 20.0
    return t, np.stack([3 * np.sin(w * t), 2 * np.sin(2 * w * t), 0.95 + 0.0 * t], axis=-1)


@pytest.fixture(scope="module")
def clean_sims():
    clean = VehicleSensors(ImuNoise.noiseless(), GpsNoise(0.0, 0.0, 0.0, 0.0), BaroNoise(0.0, 0.0), SelfPoseError(0.0, 0.0))
    return scenario_cameras("aircap", *circling_subject(6.0), seed=3, duration_s=6.0, sensors=clean)


@pytest.mark.parametrize("start", ["self_pose", "alignment"])
def test_noise_free_sensors_give_a_near_exact_track(clean_sims, start):
    for sim in clean_sims:
        track = fuse(without(sim, "self_pose") if start == "alignment" else sim)
        error = np.linalg.norm(track.world_T_camera[:, :3, 3] - sim.world_T_camera[:, :3, 3], axis=1)
        rotation = angle_deg(track.world_T_camera[:, :3, :3], sim.world_T_camera[:, :3, :3])
        assert error.max() < 0.05, f"{sim.name}: {error.max():.4f} m"
        assert rotation.max() < 0.1, f"{sim.name}: {rotation.max():.4f} deg"


def test_frames_between_states_come_from_the_imu_not_interpolation(clean_sims):
    """Sparse states (1 Hz) still give exact frames: each frame is an IMU prediction."""
    sim = clean_sims[0]
    track = fuse(sim, nav_rate_hz=1.0)
    error = np.linalg.norm(track.world_T_camera[:, :3, 3] - sim.world_T_camera[:, :3, 3], axis=1)
    assert track.info["states"] == 7
    assert error.max() < 0.05


def worst_one_second_prediction(sim, accel, gyro, dt) -> float:
    """Largest position error of GTSAM's 1 s IMU prediction from the true state, held measurements given."""
    t, poses = sim.vehicle_times, sim.vehicle_poses
    velocity = VehicleTrajectory(t, poses).velocity(t)
    params = gtsam.PreintegrationParams.MakeSharedU(nav_factors.GRAVITY_M_S2)
    bias = gtsam.imuBias.ConstantBias()
    worst = 0.0
    for start in range(0, len(t) - 101, 50):
        pim = gtsam.PreintegratedImuMeasurements(params, bias)
        for k in range(start, start + 100):
            pim.integrateMeasurement(accel[k], gyro[k], dt[k])
        state = gtsam.NavState(gtsam.Rot3(poses[start, :3, :3]), poses[start, :3, 3], velocity[start])
        worst = max(worst, np.linalg.norm(pim.predict(state, bias).position() - poses[start + 100, :3, 3]))
    return worst


def test_hold_intervals_make_the_imu_prediction_second_order(clean_sims):
    for sim in clean_sims:
        imu = sim.sensors["imu"]
        np.testing.assert_array_equal(imu["t"], sim.vehicle_times)
        held = worst_one_second_prediction(sim, *hold_intervals(imu))
        raw = worst_one_second_prediction(sim, imu["accel"][:-1], imu["gyro"][:-1], np.diff(imu["t"]))
        assert held < 1e-3, f"{sim.name}: {held:.5f} m"
        assert raw > 10 * held, f"{sim.name}: raw samples {raw:.5f} m, hold intervals {held:.5f} m"


class Records(logging.Handler):
    def __init__(self):
        super().__init__()
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


def test_fusion_logs_one_info_line_per_vehicle_and_prints_nothing(clean_sims, capsys):
    # A handler on the module's own logger: the command line may stop propagation above it.
    logger, handler, sim = logging.getLogger("mocapgraph.graphs.navigation"), Records(), clean_sims[0]
    level = logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    try:
        fuse(sim, nav_rate_hz=1.0)
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)
    records = handler.records
    assert [r.levelno for r in records] == [logging.INFO]
    assert records[0].getMessage().startswith(f"vehicle fusion {sim.name}: 7 states over ")
    assert capsys.readouterr() == ("", "")


# ---------------------------------------------------------------------------------------------
# The online track


def test_online_track_equals_the_self_pose_log_at_its_timestamps(capture):
    cam = capture.camera("uav2")
    log = cam.sensors["self_pose"]
    track = online_track(cam.sensors, cam.mount, log["t"][3::7], cam.name)
    vehicle = track.world_T_camera @ np.linalg.inv(cam.mount)
    np.testing.assert_allclose(vehicle[:, :3, :3], log["rotation"][3::7], atol=1e-9)
    np.testing.assert_allclose(vehicle[:, :3, 3], log["position"][3::7], atol=1e-9)
    assert track.source == "online"
    assert np.all(track.covariance == track.covariance[0])


def test_online_track_interpolates_and_carries_its_covariance_through_the_mount(capture):
    cam = capture.camera("uav1")
    noise = OnlineNoise(rotation_sigma_deg=2.0, position_sigma_m=0.5)
    track = online_track(cam.sensors, cam.mount, cam.timestamps, cam.name, noise=noise)
    truth = capture.ground_truth.cameras["uav1"]
    assert np.linalg.norm(track.world_T_camera[:, :3, 3] - truth[:, :3, 3], axis=1).max() < 0.35
    # Rotation block: isotropic, unchanged by the mount; translation gains the lever arm's share.
    rot = np.radians(2.0) ** 2
    np.testing.assert_allclose(track.covariance[0, :3, :3], rot * np.eye(3), rtol=1e-9, atol=1e-15)
    assert np.all(np.diag(track.covariance[0])[3:] >= 0.5**2 - 1e-12)


# ---------------------------------------------------------------------------------------------
# Which cameras get a track


def test_cameras_without_the_needed_sensors_are_skipped_with_a_note(capture):
    uav = capture.camera("uav1")
    static = Camera(
        name="tripod", K=uav.K, distortion=uav.distortion, image_size=uav.image_size, moving=False,
        timestamps=uav.timestamps[:5], frame_rate=30.0,
    )  # fmt: skip
    cams = [without(uav, "gps"), dataclasses.replace(capture.camera("uav2"), mount=None), static]
    small = Capture(name="partial", cameras=cams)
    tracks, notes = camera_priors(small, "fused")
    assert tracks == {}
    assert len(notes) == 3
    assert "uav1" in notes[0] and "gps" in notes[0]
    assert "uav2" in notes[1] and "mount" in notes[1]
    assert "tripod" in notes[2] and "no sensor" in notes[2]
    tracks, notes = camera_priors(Capture(name="p", cameras=[without(uav, "self_pose"), capture.camera("uav3")]), "online")
    assert list(tracks) == ["uav3"] and "self_pose" in notes[0]


def test_frames_far_outside_the_imu_log_skip_the_camera(capture):
    cam = capture.camera("uav1")
    late = dataclasses.replace(cam, timestamps=cam.timestamps + 1.0)
    with pytest.raises(MocapgraphError, match="outside"):
        fuse(late)
    tracks, notes = camera_priors(Capture(name="late", cameras=[late]))
    assert tracks == {} and "outside" in notes[0]


def test_the_graph_names_the_camera_and_the_array_it_refuses(capture):
    cam = capture.camera("uav1")
    with pytest.raises(MocapgraphError, match=r"camera 'uav1': vehicle_T_camera: expected shape \(4, 4\)"):
        fuse_vehicle(cam.sensors, cam.mount[:3], cam.timestamps, cam.name)
    with pytest.raises(MocapgraphError, match=r"camera 'uav1': frame times: expected shape \(N\)"):
        online_track(cam.sensors, cam.mount, cam.timestamps[:, None], cam.name)
    with pytest.raises(MocapgraphError, match="camera 'uav1': no imu and no gps log"):
        fuse_vehicle(without(cam, "imu", "gps").sensors, cam.mount, cam.timestamps, cam.name)
    with pytest.raises(MocapgraphError, match="camera 'uav1': no onboard pose estimate without a self_pose log"):
        online_track(without(cam, "self_pose").sensors, cam.mount, cam.timestamps, cam.name)


def test_unknown_source_is_refused(capture):
    with pytest.raises(MocapgraphError, match="fused, online"):
        camera_priors(capture, "magic")


# ---------------------------------------------------------------------------------------------
# The factors


def whitened_residual(factor, values: gtsam.Values) -> np.ndarray:
    """A factor's whitened residual at ``values``: minus the right-hand side of its linearisation."""
    return -factor.linearize(values).jacobian()[1]


def assert_jacobian_matches_central_differences(factor, values: gtsam.Values) -> None:
    """The whitened Jacobian GTSAM linearises to against central differences of the whitened
    residual along each tangent direction (``Values.retract``: GTSAM's own chart).

    Step ``h = ε^(1/3)``, the central-difference optimum; the tolerance is its error bound,
    truncation ``h² · scale`` plus rounding ``ε · scale / h`` with 64 ulps of margin for the
    operations behind one residual, ``scale`` being the magnitude of the residual and Jacobian.
    """
    A, b = factor.linearize(values).jacobian()
    eps = np.finfo(float).eps
    h = eps ** (1 / 3)
    numeric = np.zeros_like(A)
    zero = values.zeroVectors()
    column = 0
    for key in factor.keys():
        for j in range(len(zero.at(key))):
            ends = []
            for sign in (1.0, -1.0):
                delta = gtsam.VectorValues()
                for other in values.keys():
                    step = np.zeros_like(zero.at(other))
                    if other == key:
                        step[j] = sign * h
                    delta.insert(other, step)
                ends.append(whitened_residual(factor, values.retract(delta)))
            numeric[:, column] = (ends[0] - ends[1]) / (2 * h)
            column += 1
    assert column == A.shape[1]
    scale = 1.0 + max(np.abs(b).max(), np.abs(A).max())
    np.testing.assert_allclose(A, numeric, rtol=0, atol=h**2 * scale + 64 * eps * scale / h)


def random_state(rng: np.random.Generator) -> tuple[int, int, gtsam.Values]:
    x, d = nav_keys(4)[0], drift_key(4)
    values = gtsam.Values()
    values.insert(x, gtsam.Pose3(gtsam.Rot3(rotvec_to_matrix(rng.normal(size=3))), rng.normal(size=3)))
    values.insert(d, rng.normal(size=4))
    return x, d, values


@pytest.mark.parametrize("sensors_at_state", ["gps and baro", "gps", "baro"])
def test_fix_factor_residual_and_jacobians(sensors_at_state):
    rng = np.random.default_rng(0)
    x, d, values = random_state(rng)
    gps = (rng.normal(size=3), np.array([1.0, 1.0, 2.0])) if "gps" in sensors_at_state else None
    baro = (rng.normal(size=1), np.array([0.3])) if "baro" in sensors_at_state else None
    factor = fix_factor(x, d, gps=gps, baro=baro)
    p, offsets = values.atPose3(x).translation(), values.atVector(d)
    expected = []
    if gps is not None:
        expected.append((p + offsets[:3] - gps[0]) / gps[1])
    if baro is not None:
        expected.append((p[2:] + offsets[3:] - baro[0]) / baro[1])
    np.testing.assert_allclose(whitened_residual(factor, values), np.concatenate(expected), rtol=1e-12, atol=1e-12)
    assert_jacobian_matches_central_differences(factor, values)


def test_fix_factor_needs_a_measurement():
    with pytest.raises(MocapgraphError, match="GPS fix, a barometer sample or both"):
        fix_factor(nav_keys(0)[0], drift_key(0))


def test_offset_chain_factor_residual_and_jacobians():
    rng = np.random.default_rng(1)
    noise = FusionNoise()
    values = gtsam.Values()
    values.insert(drift_key(0), rng.normal(size=4))
    values.insert(drift_key(1), rng.normal(size=4))
    factor = offset_chain_factor(drift_key(0), drift_key(1), 0.1, noise)
    phi = np.exp(-0.1 / noise.drift_time())
    q = noise.drift_sigma() * np.sqrt(1 - phi**2)
    expected = (values.atVector(drift_key(1)) - phi * values.atVector(drift_key(0))) / q
    np.testing.assert_allclose(whitened_residual(factor, values), expected, rtol=1e-12)
    assert_jacobian_matches_central_differences(factor, values)


def test_offset_chain_keeps_the_stationary_distribution():
    """From the stationary prior, the exact step leaves every offset with the stationary std,
    whatever the step (a white-noise or Euler step would let it grow or shrink)."""
    noise = FusionNoise()
    sigma = noise.drift_sigma()
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    graph.add(gtsam.PriorFactorVector(drift_key(0), np.zeros(4), gtsam.noiseModel.Diagonal.Sigmas(sigma)))
    values.insert(drift_key(0), np.zeros(4))
    for n, dt in enumerate([0.1, 1.0, 30.0, 0.01, 200.0], start=1):
        graph.add(offset_chain_factor(drift_key(n - 1), drift_key(n), dt, noise))
        values.insert(drift_key(n), np.zeros(4))
    marginals = gtsam.Marginals(graph, values)
    for n in range(6):
        np.testing.assert_allclose(marginals.marginalCovariance(drift_key(n)), np.diag(sigma**2), rtol=1e-9, atol=1e-15)


def test_fusion_noise_splits_drift_from_the_logged_sigma():
    noise = FusionNoise()
    np.testing.assert_allclose(noise.drift_sigma(), [0.5, 0.5, 1.0, 0.5])
    np.testing.assert_allclose(noise.drift_time(), [60.0, 60.0, 60.0, 120.0])


def test_navigation_gravity_is_the_simulators():
    assert nav_factors.GRAVITY_M_S2 == sensors.GRAVITY_M_S2 == scenarios.GRAVITY_M_S2
    np.testing.assert_array_equal(nav_factors.GRAVITY_WORLD, sensors.GRAVITY_WORLD)
