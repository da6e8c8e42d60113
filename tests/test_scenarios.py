"""Synthetic camera rigs (``data_tools.scenarios``) and vehicle sensors (``data_tools.sensors``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mocapgraph.body.rotations import matrix_to_rotvec, rotvec_to_matrix
from mocapgraph.data_tools.geometry.camera_model import project_points
from mocapgraph.data_tools.io.capture import SENSOR_FIELDS, Camera, Capture, load_capture, write_capture
from mocapgraph.data_tools.sim.scenarios import (
    PRESETS,
    look_at,
    multirotor_rotations,
    scenario_cameras,
    subject_visibility,
)
from mocapgraph.data_tools.sim.sensors import (
    GRAVITY_M_S2,
    GRAVITY_WORLD,
    BaroNoise,
    GpsNoise,
    ImuNoise,
    PhoneImu,
    SelfPoseError,
    VehicleTrajectory,
    simulate_baro,
    simulate_gps,
    simulate_imu,
    simulate_self_pose,
)
from mocapgraph.errors import MocapgraphError
from mocapgraph.graphs.navigation import hold_intervals

DURATION_S = 20.0


def walking_subject(duration_s: float = DURATION_S, rate: float = 30.0):
    """A pelvis walking a 6 × 4 m figure of eight at ~1.3 m/s, with a little vertical bob."""
    t = np.arange(int(duration_s * rate) + 1) / rate
    w = 2 * np.pi / 20.0
    pos = np.stack([3 * np.sin(w * t), 2 * np.sin(2 * w * t), 0.95 + 0.02 * np.sin(2 * np.pi * 1.8 * t)], axis=-1)
    return t, pos


SUBJECT = walking_subject()


@pytest.fixture(scope="module")
def rigs():
    return {preset: scenario_cameras(preset, *SUBJECT, seed=0) for preset in PRESETS}


def angle_deg(R: np.ndarray) -> np.ndarray:
    return np.degrees(np.linalg.norm(matrix_to_rotvec(R), axis=-1))


def helix(times: np.ndarray, radius=5.0, rate=0.4, height=8.0):
    """A vehicle flying a level circle at constant speed, nose along the path (FLU), tilting inwards."""
    angle = rate * times
    pos = np.stack([radius * np.cos(angle), radius * np.sin(angle), np.full_like(times, height)], axis=-1)
    acc = -(rate**2) * pos * np.array([1.0, 1.0, 0.0])
    poses = np.tile(np.eye(4), (len(times), 1, 1))
    poses[:, :3, :3] = multirotor_rotations(acc, angle + np.pi / 2)
    poses[:, :3, 3] = pos
    return poses, acc


# ---------------------------------------------------------------------------------------------
# Presets


def test_unknown_preset_lists_presets():
    with pytest.raises(MocapgraphError, match="aircap, airpose, rich, phones"):
        scenario_cameras("studio", *SUBJECT)


@pytest.mark.parametrize(
    "preset, static, moving", [("aircap", 0, 3), ("airpose", 0, 2), ("rich", 7, 1), ("phones", 2, 2)]
)
def test_camera_counts_and_fields(rigs, preset, static, moving):
    cams = rigs[preset]
    assert sum(not c.moving for c in cams) == static and sum(c.moving for c in cams) == moving
    assert len({c.name for c in cams}) == len(cams)
    for c in cams:
        T = len(c.timestamps)
        assert T > 0.9 * DURATION_S * 30 and np.all(np.diff(c.timestamps) > 0)
        assert c.timestamps[0] >= SUBJECT[0][0] and c.timestamps[-1] <= SUBJECT[0][-1]
        assert c.K.shape == (3, 3) and c.distortion.shape == (5,)
        assert 900 <= c.K[0, 0] <= 1500 and c.K[0, 0] == c.K[1, 1]
        w, h = c.image_size
        assert abs(c.K[0, 2] - w / 2) < 0.05 * w and abs(c.K[1, 2] - h / 2) < 0.05 * h
        R = c.world_T_camera[:, :3, :3]
        assert c.world_T_camera.shape == (T, 4, 4)
        assert np.allclose(R @ np.swapaxes(R, 1, 2), np.eye(3), atol=1e-9) and np.allclose(np.linalg.det(R), 1.0)
        if c.moving:
            assert c.extrinsics is None
            turned = angle_deg(np.swapaxes(c.world_T_camera[:1, :3, :3], 1, 2) @ c.world_T_camera[:, :3, :3])
            assert np.ptp(c.world_T_camera[:, :3, 3], axis=0).max() > 0.2 and turned.max() > 10.0
        else:
            assert np.allclose(c.world_T_camera, c.world_T_camera[:1])
            assert preset in ("rich", "phones") and c.extrinsics.shape == (1, 4, 4)
            error = np.linalg.inv(c.world_T_camera[0]) @ c.extrinsics[0]
            assert 0 < angle_deg(error[:3, :3]) < 2.0 and 0 < np.linalg.norm(error[:3, 3]) < 0.15
        if preset == "aircap":
            assert c.mount.shape == (4, 4) and c.vehicle_poses.shape == (len(c.vehicle_times), 4, 4)
            assert set(c.sensors) == set(SENSOR_FIELDS)
            for kind, spec in SENSOR_FIELDS.items():
                log = c.sensors[kind]
                assert set(log) == set(spec)
                for key, trailing in spec.items():
                    assert log[key].shape == (len(c.vehicle_times), *trailing), (kind, key)
            assert np.allclose(np.diff(c.vehicle_times), 0.01)
        elif preset == "phones" and c.moving:
            # a carried phone: its IMU log at 200 Hz over the frames, on a clock up to 30 ms off
            assert c.mount.shape == (4, 4) and c.vehicle_poses is None and set(c.sensors) == {"imu"}
            log = c.sensors["imu"]
            assert np.allclose(np.diff(log["t"]), 1 / 200) and abs(c.imu_time_offset_s) <= PhoneImu().max_time_offset_s
            assert np.isclose(log["t"][0], c.timestamps[0] + c.imu_time_offset_s) and log["t"][-1] <= c.timestamps[-1] + PhoneImu().max_time_offset_s
            assert log["accel"].shape == log["gyro"].shape == (len(log["t"]), 3)
        else:
            assert c.mount is None and c.vehicle_poses is None and c.sensors == {}


@pytest.mark.parametrize("preset", PRESETS)
def test_subject_in_view(rigs, preset):
    fractions = []
    for c in rigs[preset]:
        in_front, inside = subject_visibility(c, *SUBJECT)
        assert in_front.mean() > 0.99, c.name
        fractions.append(inside.mean())
        if preset == "aircap":
            assert inside.mean() > 0.6, c.name
        elif c.moving:
            assert inside.mean() > 0.95, c.name
        else:
            assert inside.mean() > 0.5, c.name
    if preset == "aircap":
        assert np.mean(fractions) < 0.97  # the tilting vehicles lose the subject now and then
    else:
        assert np.mean(fractions) > 0.8


def test_aircap_leaves_frame_sometimes_over_seeds():
    fractions = [
        subject_visibility(c, *SUBJECT)[1].mean() for seed in (1, 2, 3) for c in scenario_cameras("aircap", *SUBJECT, seed=seed)
    ]
    assert min(fractions) > 0.6 and 0.75 < np.mean(fractions) < 0.97


def test_look_at_is_opencv():
    pose = look_at([0.0, -5.0, 1.0], [0.0, 0.0, 1.0])
    R = pose[:3, :3]
    assert np.allclose(R.T @ R, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
    assert np.allclose(R[:, 2], [0, 1, 0]) and np.allclose(R[:, 0], [1, 0, 0]) and np.allclose(R[:, 1], [0, 0, -1])
    K = np.array([[1000.0, 0, 960], [0, 1000.0, 540], [0, 0, 1]])
    points = np.array([[0, 0, 1.0], [0, 0, 2.0], [1.0, 0, 1.0]])
    uv, z = project_points(points, np.repeat(pose[None], 3, axis=0), K)
    assert np.allclose(uv[0], [960, 540]) and np.all(z > 0)
    assert uv[1, 1] < 540 and uv[2, 0] > 960  # world up is image up; world +x is image right here
    down = look_at([1.0, 2.0, 8.0], [1.0, 2.0, 0.0])  # along -up: still a rotation
    assert np.isclose(np.linalg.det(down[:3, :3]), 1.0) and np.allclose(down[:3, 2], [0, 0, -1])
    batch = look_at(np.zeros((4, 3)), np.eye(4, 3) + [0, 0, 0.1])
    assert batch.shape == (4, 4, 4)
    with pytest.raises(MocapgraphError):
        look_at([1.0, 1.0, 1.0], [1.0, 1.0, 1.0])


def test_aircap_timing_is_unsynchronised(rigs):
    cams = rigs["aircap"]
    for c in cams:
        assert 30.0 <= c.frame_rate <= 40.0
        dt = np.diff(c.timestamps)
        assert abs(np.median(dt) - 1.0 / c.frame_rate) < 1e-4 and np.abs(dt - 1.0 / c.frame_rate).max() < 4e-3
        assert np.std(dt) > 1e-5  # jitter
        assert c.vehicle_times[0] <= c.timestamps[0] and c.timestamps[-1] <= c.vehicle_times[-1]
    for i in range(len(cams)):
        for j in range(i + 1, len(cams)):
            assert np.intersect1d(cams[i].timestamps, cams[j].timestamps).size == 0
            gaps = np.abs(cams[i].timestamps[:, None] - cams[j].timestamps[None]).min(axis=1)
            assert np.median(gaps) > 1e-3
    assert len({round(c.frame_rate, 3) for c in cams}) == len(cams)


def test_aircap_geometry_and_mount(rigs):
    subject_positions = SUBJECT[1]
    for c in rigs["aircap"]:
        p = c.vehicle_poses[:, :3, 3]
        s = np.stack([np.interp(c.vehicle_times, SUBJECT[0], subject_positions[:, i]) for i in range(3)], axis=-1)
        assert 7.0 < p[:, 2].mean() < 9.0 and p[:, 2].min() > 5.5
        distance = np.linalg.norm(p[:, :2] - s[:, :2], axis=1)
        assert 6.5 < distance.mean() < 9.5 and distance.min() > 2.0
        # Rigid mount, pitched 35-45° down, FLU vehicle frame: the optical axis looks forward and down.
        axis = c.mount[:3, 2]
        assert 35.0 <= math.degrees(math.asin(-axis[2])) <= 45.0 and axis[0] > 0 and abs(axis[1]) < 1e-12
        trajectory = VehicleTrajectory(c.vehicle_times, c.vehicle_poses)
        assert np.allclose(trajectory.poses(c.timestamps) @ c.mount, c.world_T_camera, atol=1e-9)
        # Multirotor: body z is the thrust direction a - g; the vehicle tilts noticeably.
        thrust = trajectory.acceleration(c.vehicle_times) - GRAVITY_WORLD
        cosine = np.einsum("ni,ni->n", c.vehicle_poses[:, :3, 2], thrust) / np.linalg.norm(thrust, axis=1)
        assert np.degrees(np.arccos(np.clip(cosine, -1, 1))).max() < 0.1
        tilt = np.degrees(np.arccos(c.vehicle_poses[:, 2, 2]))
        assert 3.0 < tilt.mean() < 25.0 and tilt.max() < 45.0
        speed = np.linalg.norm(trajectory.velocity(c.vehicle_times), axis=1)
        assert speed.max() < 8.0


def test_airpose_is_synchronised_and_gimballed(rigs):
    hover, circle = rigs["airpose"]
    assert np.array_equal(hover.timestamps, circle.timestamps)
    assert hover.frame_rate == circle.frame_rate == 30.0
    assert np.allclose(np.diff(hover.timestamps), 1 / 30.0)
    for c in (hover, circle):
        p = c.world_T_camera[:, :3, 3]
        assert 5.0 < p[:, 2].mean() < 12.0
        pitch = np.degrees(np.arcsin(-c.world_T_camera[:, 2, 2]))  # optical axis below the horizon
        assert pitch.min() > -2.0 and pitch.max() < 47.0
        roll = np.degrees(np.arcsin(c.world_T_camera[:, 2, 0]))  # image x stays level (gimbal)
        assert np.abs(roll).max() < 3.0
    assert np.ptp(hover.world_T_camera[:, :3, 3], axis=0).max() < 1.0
    assert np.ptp(circle.world_T_camera[:, :3, 3], axis=0).max() > 5.0
    s = SUBJECT[1][: len(hover.timestamps)]
    for c in (hover, circle):
        distance = np.linalg.norm(c.world_T_camera[:, :3, 3] - s, axis=1)
        assert 7.0 < np.median(distance) < 14.0


def test_rich_and_phones_geometry(rigs):
    rich = rigs["rich"]
    for c in rich:
        assert np.array_equal(c.timestamps, rich[0].timestamps) and c.frame_rate == 30.0
    heights = [c.world_T_camera[0, 2, 3] for c in rich if not c.moving]
    assert min(heights) >= 1.0 and max(heights) <= 2.5
    handheld = next(c for c in rich if c.moving)
    s = SUBJECT[1][: len(handheld.timestamps)]
    distance = np.linalg.norm(handheld.world_T_camera[:, :2, 3] - s[:, :2], axis=1)
    assert 1.5 < np.median(distance) < 3.5
    shake = np.diff(handheld.world_T_camera[:, :3, 3], axis=0)
    assert np.linalg.norm(shake, axis=1).max() < 0.1  # a walking person, not teleporting

    phones = rigs["phones"]
    sizes = {c.image_size for c in phones}
    assert (1080, 1920) in sizes and (1920, 1080) in sizes
    positions = np.concatenate([c.world_T_camera[:, :3, 3] for c in phones])
    extent = np.ptp(positions[:, :2], axis=0)
    assert extent.max() >= 12.0 and extent.min() >= 8.0  # walls of a ~15 × 10 m field


def test_determinism_and_duration():
    a = scenario_cameras("aircap", *SUBJECT, seed=7, duration_s=5.0)
    b = scenario_cameras("aircap", *SUBJECT, seed=7, duration_s=5.0)
    c = scenario_cameras("aircap", *SUBJECT, seed=8, duration_s=5.0)
    for x, y in zip(a, b):
        assert np.array_equal(x.timestamps, y.timestamps) and np.array_equal(x.world_T_camera, y.world_T_camera)
        assert np.array_equal(x.K, y.K) and np.array_equal(x.vehicle_poses, y.vehicle_poses)
        for kind in x.sensors:
            for key in x.sensors[kind]:
                assert np.array_equal(x.sensors[kind][key], y.sensors[kind][key])
    assert not np.allclose(a[0].world_T_camera[:10], c[0].world_T_camera[:10])
    assert all(cam.timestamps[-1] <= 5.0 and cam.vehicle_times[-1] <= 5.0 for cam in a)
    for preset in ("airpose", "rich", "phones"):
        x, y = (scenario_cameras(preset, *SUBJECT, seed=3, duration_s=4.0) for _ in range(2))
        z = scenario_cameras(preset, *SUBJECT, seed=4, duration_s=4.0)
        assert all(np.array_equal(p.world_T_camera, q.world_T_camera) and np.array_equal(p.K, q.K) for p, q in zip(x, y))
        assert not all(np.allclose(p.world_T_camera, q.world_T_camera) for p, q in zip(x, z))
    with pytest.raises(MocapgraphError, match="subject_positions"):
        scenario_cameras("rich", SUBJECT[0], SUBJECT[1][:, :2])
    with pytest.raises(MocapgraphError, match="duration_s"):
        scenario_cameras("rich", *SUBJECT, duration_s=-1.0)


def test_sim_cameras_fit_the_capture_format(rigs, tmp_path):
    cameras = [
        Camera(
            name=c.name, K=c.K, distortion=c.distortion, image_size=c.image_size, moving=c.moving,
            timestamps=c.timestamps, frame_rate=c.frame_rate, extrinsics=c.extrinsics, mount=c.mount,
            sensors=c.sensors,
        )  # fmt: skip
        for c in rigs["aircap"] + rigs["rich"]
    ]
    loaded = load_capture(write_capture(Capture("sim", cameras), tmp_path / "sim"))
    assert np.allclose(loaded.camera("uav2").sensors["self_pose"]["rotation"], rigs["aircap"][1].sensors["self_pose"]["rotation"])
    assert np.allclose(loaded.camera("cam3").extrinsics, rigs["rich"][2].extrinsics)


# ---------------------------------------------------------------------------------------------
# Sensors


def test_imu_matches_analytic_helix():
    times = np.arange(0.0, 10.0, 0.01)
    poses, acc = helix(times)
    imu = simulate_imu(times, poses, np.random.default_rng(0), ImuNoise.noiseless())
    inner = slice(50, -50)  # spline end effects stay within the first and last half second
    # Constant yaw rate about the (tilted) body z, and the specific force along body z only.
    expected_gyro = np.einsum("nji,j->ni", poses[:, :3, :3], [0.0, 0.0, 0.4])
    assert np.abs(imu["gyro"][inner] - expected_gyro[inner]).max() < 1e-4
    f = np.einsum("nji,nj->ni", poses[:, :3, :3], acc - GRAVITY_WORLD)
    assert np.abs(imu["accel"][inner] - f[inner]).max() < 1e-4
    assert np.allclose(imu["accel"][inner, :2], 0.0, atol=1e-4)
    assert np.allclose(imu["accel"][inner, 2], math.hypot(GRAVITY_M_S2, 0.4**2 * 5.0), atol=1e-4)
    hover = np.tile(np.eye(4), (100, 1, 1))
    still = simulate_imu(times[:100], hover, np.random.default_rng(0), ImuNoise.noiseless())
    assert np.allclose(still["accel"], [0.0, 0.0, GRAVITY_M_S2]) and np.allclose(still["gyro"], 0.0)


def integrate_imu(t, accel, gyro, R, p, v):
    """Trapezoidal strapdown integration (rotation by the mean rate, world acceleration linear)."""
    Rs, ps = [R], [p]
    for k in range(len(t) - 1):
        dt = t[k + 1] - t[k]
        a0 = R @ accel[k] + GRAVITY_WORLD
        R = R @ rotvec_to_matrix(0.5 * (gyro[k] + gyro[k + 1]) * dt)
        a1 = R @ accel[k + 1] + GRAVITY_WORLD
        p = p + v * dt + (2 * a0 + a1) * dt * dt / 6
        v = v + 0.5 * (a0 + a1) * dt
        Rs.append(R)
        ps.append(p)
    return np.array(Rs), np.array(ps)


def test_noise_free_imu_integrates_to_the_true_trajectory(rigs):
    worst_p, worst_r = 0.0, 0.0
    for c in rigs["aircap"]:
        t, poses = c.vehicle_times, c.vehicle_poses
        imu = simulate_imu(t, poses, np.random.default_rng(1), ImuNoise.noiseless())
        velocity = VehicleTrajectory(t, poses).velocity(t)
        for start in (100, 700, 1400):
            seg = slice(start, start + 401)  # 4 s
            R, p = integrate_imu(t[seg], imu["accel"][seg], imu["gyro"][seg], poses[start, :3, :3], poses[start, :3, 3], velocity[start])
            worst_p = max(worst_p, np.linalg.norm(p - poses[seg, :3, 3], axis=1).max())
            worst_r = max(worst_r, angle_deg(np.swapaxes(R, 1, 2) @ poses[seg, :3, :3]).max())
    assert worst_p < 0.05 and worst_r < 0.05, (worst_p, worst_r)


def test_gtsam_preintegration_predicts_next_pose(rigs):
    gtsam = pytest.importorskip("gtsam")
    params = gtsam.PreintegrationParams.MakeSharedU(GRAVITY_M_S2)
    for name in ("setAccelerometerCovariance", "setGyroscopeCovariance", "setIntegrationCovariance"):
        getattr(params, name)(np.eye(3) * 1e-8)
    c = rigs["aircap"][0]
    t, poses = c.vehicle_times, c.vehicle_poses
    imu = simulate_imu(t, poses, np.random.default_rng(2), ImuNoise.noiseless())
    accel, gyro, dt = hold_intervals(imu)
    velocity = VehicleTrajectory(t, poses).velocity(t)
    bias = gtsam.imuBias.ConstantBias()
    for start in range(0, len(t) - 101, 300):
        pim = gtsam.PreintegratedImuMeasurements(params, bias)
        for k in range(start, start + 100):  # 1 s
            pim.integrateMeasurement(accel[k], gyro[k], dt[k])
        state = gtsam.NavState(gtsam.Rot3(poses[start, :3, :3]), poses[start, :3, 3], velocity[start])
        predicted = pim.predict(state, bias)
        end = poses[start + 100]
        assert np.linalg.norm(predicted.position() - end[:3, 3]) < 0.01
        assert angle_deg(end[:3, :3].T @ predicted.attitude().matrix()) < 0.05
        assert np.linalg.norm(predicted.velocity() - velocity[start + 100]) < 0.02


def test_imu_noise_and_bias():
    times = np.arange(0.0, 30.0, 0.01)
    poses, _ = helix(times)
    clean = simulate_imu(times, poses, np.random.default_rng(0), ImuNoise.noiseless())
    white = ImuNoise(accel_noise_m_s2=0.05, gyro_noise_rad_s=0.01, accel_bias_m_s2=0, gyro_bias_rad_s=0,
                     accel_bias_walk_m_s2_sqrt_s=0, gyro_bias_walk_rad_s_sqrt_s=0)  # fmt: skip
    noisy = simulate_imu(times, poses, np.random.default_rng(3), white)
    assert np.allclose(np.std(noisy["accel"] - clean["accel"], axis=0), 0.05, rtol=0.08)
    assert np.allclose(np.std(noisy["gyro"] - clean["gyro"], axis=0), 0.01, rtol=0.08)
    biased = simulate_imu(times, poses, np.random.default_rng(4), ImuNoise(0, 0, 0.1, 0.01, 0, 0))
    offset = biased["gyro"] - clean["gyro"]
    assert np.allclose(offset, offset[0]) and np.abs(offset[0]).max() > 1e-4
    walk = ImuNoise(0, 0, 0, 0, 0, gyro_bias_walk_rad_s_sqrt_s=1e-3)
    drifts = [simulate_imu(times, poses, np.random.default_rng(s), walk)["gyro"][-1] - clean["gyro"][-1] for s in range(20)]
    assert 0.5 < np.std(drifts) / (1e-3 * math.sqrt(times[-1] - times[0])) < 1.5
    densities = ImuNoise().densities(100.0)
    assert math.isclose(densities["accel_noise_m_s2_sqrt_hz"], ImuNoise().accel_noise_m_s2 / 10.0)


def test_gps_noise_matches_sigma():
    times = np.arange(0.0, 60.0, 0.01)
    poses, _ = helix(times)
    white = GpsNoise(horizontal_sigma_m=1.5, vertical_sigma_m=3.0, horizontal_drift_m=0, vertical_drift_m=0, fix_rate_hz=None)
    gps = simulate_gps(times, poses, np.random.default_rng(0), white)
    error = gps["position"] - poses[:, :3, 3]
    assert np.allclose(gps["sigma"], [1.5, 1.5, 3.0])
    assert np.allclose(np.std(error, axis=0), [1.5, 1.5, 3.0], rtol=0.05)
    assert np.all(np.abs(error.mean(axis=0)) < 0.1)
    # Default: 10 Hz fixes held in a 100 Hz log, white noise plus a slow drift, honest total sigma.
    gps = simulate_gps(times, poses, np.random.default_rng(1))
    fresh = np.r_[True, np.any(np.diff(gps["position"], axis=0) != 0, axis=1)]
    assert abs(fresh.sum() - 10 * 60) <= 1 and np.array_equal(np.flatnonzero(fresh), np.arange(0, len(times), 10))
    normalised = (gps["position"] - poses[:, :3, 3])[fresh] / gps["sigma"][fresh]
    assert np.allclose(gps["sigma"][0], GpsNoise().sigma())
    assert 0.6 < np.sqrt(np.mean(normalised**2)) < 1.4
    assert np.all(GpsNoise().sigma()[:2] >= 0.5) and np.all(GpsNoise().sigma()[:2] <= 2.0)


def test_baro_and_self_pose(rigs):
    times = np.arange(0.0, 60.0, 0.01)
    poses, _ = helix(times)
    baro = simulate_baro(times, poses, np.random.default_rng(0), BaroNoise(sigma_m=0.4, drift_m=0.0))
    assert np.allclose(baro["sigma"], 0.4) and math.isclose(np.std(baro["altitude"] - 8.0), 0.4, rel_tol=0.05)
    error = SelfPoseError(position_error_m=0.4, rotation_error_deg=2.0, drift_time_s=15.0)
    est = simulate_self_pose(times, poses, np.random.default_rng(1), error)
    dp = np.linalg.norm(est["position"] - poses[:, :3, 3], axis=1)
    dr = angle_deg(est["rotation"] @ np.swapaxes(poses[:, :3, :3], 1, 2))
    assert math.isclose(dp.max(), 0.4, rel_tol=1e-9) and dp.mean() > 0.1
    assert math.isclose(dr.max(), 2.0, rel_tol=1e-6) and dr.mean() > 0.5
    assert np.abs(np.diff(dp)).max() < 0.01  # slow drift, no jumps
    for c in rigs["aircap"]:  # defaults in the scenario: a few dm, a degree or two
        sp = c.sensors["self_pose"]
        dp = np.linalg.norm(sp["position"] - c.vehicle_poses[:, :3, 3], axis=1)
        dr = angle_deg(sp["rotation"] @ np.swapaxes(c.vehicle_poses[:, :3, :3], 1, 2))
        assert dp.max() <= SelfPoseError().position_error_m + 1e-9 and dr.max() <= SelfPoseError().rotation_error_deg + 1e-6
        assert 0.1 < np.median(np.abs(c.sensors["baro"]["altitude"] - c.vehicle_poses[:, 2, 3])) < 2.0
