"""Phone IMUs: the simulator's carried phones, their preintegrated factors, and SmartMocap with them."""

from __future__ import annotations

from dataclasses import replace

import gtsam
import numpy as np
import pytest

from mocapgraph.body.rotations import rotvec_to_matrix
from mocapgraph.data_tools.sim.scenarios import phone_mount, scenario_cameras
from mocapgraph.data_tools.sim.sensors import GRAVITY_WORLD, PhoneImu, VehicleTrajectory, imu_readings
from mocapgraph.errors import MocapgraphError
from mocapgraph.factors.keys import camera_bias_key, camera_key, camera_velocity_key
from mocapgraph.graphs.camera_imu import PHONE_GYRO_NOISE, PHONE_IMU_NOISE, CameraImu, bias_prior, covered_runs, gyro_aligned_rotations, imu_factor

NOISELESS = PhoneImu(
    accel_noise_m_s2_sqrt_hz=0.0, gyro_noise_rad_s_sqrt_hz=0.0, accel_bias_m_s2=0.0, gyro_bias_rad_s=0.0,
    accel_bias_walk_m_s2_sqrt_s=0.0, gyro_bias_walk_rad_s_sqrt_s=0.0, max_time_offset_s=0.0,
)


def walking_subject(duration_s: float = 4.0):
    t = np.arange(0.0, duration_s + 1e-9, 1 / 30)
    return t, np.c_[0.8 * np.sin(0.5 * t), 0.4 * t, np.full_like(t, 0.9)]


@pytest.fixture(scope="module")
def phones():
    """The carried phones of a 4 s ``phones`` rig with noise-free IMUs."""
    return [c for c in scenario_cameras("phones", *walking_subject(), seed=1, phone_imu=NOISELESS) if c.moving]


def test_noise_free_phone_imu_predicts_the_next_camera_pose(phones):
    """GTSAM's preintegration with the mount as body_P_sensor carries the true camera pose and
    velocity at one frame to the next frame's true pose: mount, gravity and time are consistent."""
    assert {c.image_size for c in phones} == {(1080, 1920), (1920, 1080)}
    for cam in phones:
        imu = CameraImu.from_log(cam.sensors["imu"], cam.mount, cam.name)
        params = imu.params()
        T, t = cam.world_T_camera, cam.timestamps
        velocity = VehicleTrajectory(t, T).velocity(t)
        steps = [j for j in range(len(t) - 1) if imu.covers(t[j], t[j + 1])]
        assert len(steps) >= len(t) - 2  # the log spans the frames
        for j in steps:
            pim = imu.preintegrate(t[j], t[j + 1], params)
            assert np.isclose(pim.deltaTij(), t[j + 1] - t[j], atol=1e-12)
            predicted = pim.predict(gtsam.NavState(gtsam.Pose3(T[j]), velocity[j]), gtsam.imuBias.ConstantBias()).pose()
            error = gtsam.Pose3(T[j + 1]).between(predicted)
            assert np.linalg.norm(error.translation()) < 1e-3 and np.linalg.norm(gtsam.Rot3.Logmap(error.rotation())) < 1e-4


def test_phone_imu_noise_matches_its_densities():
    """A phone at rest reads gravity plus its biases, with the datasheet densities' per-sample std."""
    phone = PhoneImu()
    times = np.arange(0.0, 2.0, 1 / 30)
    still = np.tile(np.eye(4), (len(times), 1, 1))
    t = np.arange(0.0, 1.9, 1 / phone.rate_hz)
    stds = {"accel": [], "gyro": [], "accel_mean": []}
    for seed in range(40):
        log = imu_readings(VehicleTrajectory(times, still), t, np.random.default_rng(seed), phone.noise())
        stds["accel"].append(np.std(np.diff(log["accel"], axis=0)) / np.sqrt(2))
        stds["gyro"].append(np.std(np.diff(log["gyro"], axis=0)) / np.sqrt(2))
        stds["accel_mean"].append(log["accel"].mean(0) + GRAVITY_WORLD)
    root = np.sqrt(phone.rate_hz)
    assert np.isclose(np.mean(stds["accel"]), phone.accel_noise_m_s2_sqrt_hz * root, rtol=0.05)
    assert np.isclose(np.mean(stds["gyro"]), phone.gyro_noise_rad_s_sqrt_hz * root, rtol=0.05)
    bias = np.concatenate(stds["accel_mean"])  # accel minus gravity: the bias (and its short walk)
    assert 0.6 * phone.accel_bias_m_s2 < bias.std() < 1.5 * phone.accel_bias_m_s2


def test_phones_capture_with_and_without_imu():
    """``synthesize(..., imu=False)`` (``synth --no-imu``): the same rig and detections, no logs."""
    from mocapgraph.data_tools.sim.synthetic import synthesize

    with_imu = synthesize("phones", seed=2, duration_s=1.0, detector_faults="none")
    without = synthesize("phones", seed=2, duration_s=1.0, detector_faults="none", imu=False)
    walking = [c.name for c in with_imu.cameras if c.moving]
    assert set(with_imu.metadata["imu_time_offsets_s"]) == set(walking) and "imu_time_offsets_s" not in without.metadata
    for a, b in zip(with_imu.cameras, without.cameras):
        assert np.array_equal(with_imu.ground_truth.cameras[a.name], without.ground_truth.cameras[b.name])
        assert np.array_equal(a.detectors["mediapipe"].keypoints, b.detectors["mediapipe"].keypoints, equal_nan=True)
        assert b.sensors == {} and b.mount is None
        assert set(a.sensors) == ({"imu"} if a.moving else set())
        if a.moving:
            assert np.allclose(a.mount, phone_mount(a.image_size))


def _retracted(values: gtsam.Values, key: int, delta: np.ndarray) -> gtsam.Values:
    out = gtsam.Values(values)
    try:
        out.update(key, values.atPose3(key).retract(delta))
    except RuntimeError:
        try:
            bias = values.atConstantBias(key)
            out.update(key, gtsam.imuBias.ConstantBias(bias.accelerometer() + delta[:3], bias.gyroscope() + delta[3:]))
        except RuntimeError:
            out.update(key, values.atVector(key) + delta)
    return out


@pytest.mark.parametrize("noise", [PHONE_GYRO_NOISE, PHONE_IMU_NOISE], ids=["gyro", "datasheet"])
def test_imu_factor_jacobians_match_numerical_differences(phones, noise):
    """The assembled factor (built-in CombinedImuFactor with the phone's mount, a noisy log, a
    perturbed state): its linearisation equals central differences of its whitened residual."""
    cam = phones[0]
    rng = np.random.default_rng(5)
    log = imu_readings(VehicleTrajectory(cam.timestamps, cam.world_T_camera @ np.linalg.inv(cam.mount)), cam.sensors["imu"]["t"], rng, PhoneImu().noise())
    imu = CameraImu.from_log(log, cam.mount, cam.name)
    t = cam.timestamps
    pim = imu.preintegrate(t[10], t[11], imu.params(noise))
    keys = (camera_key(3, 10), camera_key(3, 11)), (camera_velocity_key(3, 10), camera_velocity_key(3, 11)), (camera_bias_key(3, 10), camera_bias_key(3, 11))
    factor = imu_factor(*keys, pim)
    values = gtsam.Values()
    for j, key in zip((10, 11), keys[0]):
        values.insert(key, gtsam.Pose3(cam.world_T_camera[j]).retract(rng.normal(scale=0.02, size=6)))
    for key in keys[1]:
        values.insert(key, rng.normal(size=3))
    for key in keys[2]:
        values.insert(key, gtsam.imuBias.ConstantBias(rng.normal(scale=0.05, size=3), rng.normal(scale=0.005, size=3)))
    A, b = factor.linearize(values).jacobian()
    np.testing.assert_allclose(b, -factor.whitenedError(values), atol=1e-9)
    h, columns = 1e-6, []
    for key in factor.keys():
        for k in range(6 if key not in keys[1] else 3):
            step = np.zeros(6 if key not in keys[1] else 3)
            step[k] = h
            columns.append((factor.whitenedError(_retracted(values, key, step)) - factor.whitenedError(_retracted(values, key, -step))) / (2 * h))
    numeric = np.stack(columns, axis=1)
    assert np.abs(A - numeric).max() / max(1.0, np.abs(numeric).max()) < 1e-5
    prior = bias_prior(keys[2][0])
    sigma = np.r_[np.full(3, PHONE_GYRO_NOISE.accel_bias_prior_m_s2), np.full(3, PHONE_GYRO_NOISE.gyro_bias_prior_rad_s)]
    assert np.isclose(prior.error(values), 0.5 * np.sum((values.atConstantBias(keys[2][0]).vector() / sigma) ** 2))


def test_a_gap_in_the_log_splits_its_steps(phones):
    """A log that stops and resumes covers the frame steps of each stretch, none across the gap."""
    cam = phones[0]
    log = cam.sensors["imu"]
    keep = (log["t"] < 1.0) | (log["t"] > 2.0)
    imu = CameraImu.from_log({k: v[keep] for k, v in log.items()}, cam.mount, cam.name)
    stretches = imu.segments()
    assert len(stretches) == 2 and stretches[0][1] < 1.0 < 2.0 < stretches[1][0]
    t = cam.timestamps
    covered = np.array([imu.covers(t[j], t[j + 1]) for j in range(len(t) - 1)])
    across = (t[1:] > stretches[0][1]) & (t[:-1] < stretches[1][0])
    assert not covered[across].any() and covered[~across][1:-1].all()
    with pytest.raises(MocapgraphError, match="imu t"):
        CameraImu.from_log({**log, "t": log["t"][::-1]}, cam.mount, cam.name)


def test_gyro_track_turned_onto_noisy_flipped_rotations(phones):
    """The gyroscope's track aligned to per-frame rotations with 3° noise and a few flipped
    frames is within a few mrad of the truth at every frame (the truth's own noise averaged out)."""
    cam = phones[1]
    imu = CameraImu.from_log(cam.sensors["imu"], cam.mount, cam.name)
    times = cam.timestamps
    runs = covered_runs(imu, np.arange(len(times)), times)
    assert len(runs) == 1 and len(runs[0]) >= len(times) - 2
    run = runs[0]
    truth = cam.world_T_camera[run, :3, :3]
    rng = np.random.default_rng(0)
    noisy = rotvec_to_matrix(rng.normal(scale=np.radians(3.0), size=(len(run), 3))) @ truth
    noisy[::17] = noisy[::17] @ np.diag([-1.0, -1.0, 1.0])  # turned half round the optical axis
    aligned = gyro_aligned_rotations(imu, times[run], noisy)
    angle = np.arccos(np.clip((np.einsum("nij,nij->n", aligned, truth) - 1) / 2, -1, 1))
    assert angle.max() < 0.01


@pytest.mark.slow
def test_smartmocap_carried_phones_with_imu_and_a_log_that_stops():
    """3 s of ``phones``: the carried phones' trajectories (after their own Procrustes) are
    closer to the truth with their IMUs than without; a phone whose IMU stops mid-capture runs,
    keeps the IMU's gain before the stop, and the notes say what each camera rests on."""
    from mocapgraph.data_tools.evaluation.evaluate import evaluate
    from mocapgraph.data_tools.sim.synthetic import synthesize
    from mocapgraph.pipelines.smartmocap import SmartmocapOptions, run_smartmocap

    capture = synthesize("phones", seed=0, duration_s=3.0)
    options = SmartmocapOptions(covariances=False, keypoint_offsets=False)
    errors = {}
    for name, imu in (("imu", True), ("none", False)):
        result = run_smartmocap(capture, replace(options, imu=imu))
        errors[name] = evaluate(result, capture).metrics
        notes = result.parameters["notes"]
        for cam in ("phone_walk1", "phone_walk2"):
            assert any(n.startswith(f"camera {cam}: IMU on") if imu else n.startswith(f"camera {cam}: no IMU log") for n in notes)
    # after their own Procrustes, its rotation from the orientations (measured: 6.5 against 8.3 cm,
    # 0.015 against 0.028 rad; with the rotation from the positions, 4.3 against 7.3 cm)
    assert errors["imu"]["moving_mcpe_procrustes_m"] < 0.9 * errors["none"]["moving_mcpe_procrustes_m"]
    assert errors["imu"]["moving_mcoe_procrustes_rad"] < 0.7 * errors["none"]["moving_mcoe_procrustes_rad"]
    assert errors["imu"]["moving_mcpe_procrustes_m"] < 0.08 and errors["imu"]["moving_mcoe_procrustes_rad"] < 0.02

    walker = next(c for c in capture.cameras if c.name == "phone_walk1")
    log = walker.sensors["imu"]
    stopped = replace(walker, sensors={"imu": {k: v[log["t"] < 1.5] for k, v in log.items()}})
    cut = replace(capture, cameras=[stopped if c is walker else c for c in capture.cameras])
    result = run_smartmocap(cut, replace(options, imu=True))
    metrics = evaluate(result, cut).metrics
    note = next(n for n in result.parameters["notes"] if n.startswith("camera phone_walk1: IMU on"))
    assert "without IMU on those alone" in note
    steps = int(note.split("IMU on ")[1].split(" of ")[0])
    assert 40 <= steps <= 45  # 1.5 s of 3 s at 30 fps
    assert metrics["moving_mcpe_procrustes_m"] < errors["none"]["moving_mcpe_procrustes_m"]
    assert metrics["moving_mcoe_procrustes_rad"] < errors["none"]["moving_mcoe_procrustes_rad"]
