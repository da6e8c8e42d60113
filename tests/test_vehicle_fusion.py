"""Camera pose priors from the vehicles' sensors (``graphs.vehicle_fusion``)."""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np
import pytest
from scipy.stats import chi2

from mocapgraph.body.rotations import matrix_to_rotvec, rotvec_to_matrix
from mocapgraph.data_tools.io.capture import Camera, Capture
from mocapgraph.data_tools.sim.scenarios import scenario_cameras
from mocapgraph.data_tools.sim.sensors import BaroNoise, GpsNoise, ImuNoise, SelfPoseError, VehicleSensors
from mocapgraph.data_tools.sim.synthetic import synthesize
from mocapgraph.errors import MocapgraphError
from mocapgraph.factors.keys import drift_key, nav_keys
from mocapgraph.graphs.navigation import (
    FusionNoise,
    OnlineNoise,
    _fix_factor,
    camera_priors,
    fuse_vehicle,
    online_track,
)


@pytest.fixture(scope="module")
def capture():
    return synthesize("aircap", seed=1, duration_s=8.0)


@pytest.fixture(scope="module")
def fused(capture):
    tracks, notes = camera_priors(capture, "fused", verbose=False)
    assert notes == []
    return tracks


def angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    return np.degrees(np.linalg.norm(matrix_to_rotvec(np.swapaxes(Ra, -1, -2) @ Rb), axis=-1))


def gps_at(camera: Camera, times: np.ndarray) -> np.ndarray:
    """The GPS position a flight log shows at each time (its latest row)."""
    gps = camera.sensors["gps"]
    return gps["position"][np.clip(np.searchsorted(gps["t"], times, side="right") - 1, 0, len(gps["t"]) - 1)]


def sim_camera(sim) -> Camera:
    return Camera(
        name=sim.name, K=sim.K, distortion=sim.distortion, image_size=sim.image_size, moving=sim.moving,
        timestamps=sim.timestamps, frame_rate=sim.frame_rate, mount=sim.mount, sensors=dict(sim.sensors),
    )  # fmt: skip


def without(camera: Camera, *kinds: str) -> Camera:
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
        cam = sim_camera(sim)
        if start == "alignment":
            cam = without(cam, "self_pose")
        track = fuse_vehicle(cam, verbose=False)
        error = np.linalg.norm(track.world_T_camera[:, :3, 3] - sim.world_T_camera[:, :3, 3], axis=1)
        rotation = angle_deg(track.world_T_camera[:, :3, :3], sim.world_T_camera[:, :3, :3])
        assert error.max() < 0.05, f"{sim.name}: {error.max():.4f} m"
        assert rotation.max() < 0.1, f"{sim.name}: {rotation.max():.4f} deg"


def test_frames_between_states_come_from_the_imu_not_interpolation(clean_sims):
    """Sparse states (1 Hz) still give exact frames: each frame is an IMU prediction."""
    sim = clean_sims[0]
    track = fuse_vehicle(sim_camera(sim), nav_rate_hz=1.0, verbose=False)
    error = np.linalg.norm(track.world_T_camera[:, :3, 3] - sim.world_T_camera[:, :3, 3], axis=1)
    assert track.info["states"] == 7
    assert error.max() < 0.05


# ---------------------------------------------------------------------------------------------
# The online track


def test_online_track_equals_the_self_pose_log_at_its_timestamps(capture):
    cam = capture.camera("uav2")
    log = cam.sensors["self_pose"]
    at_log = dataclasses.replace(cam, timestamps=log["t"][3::7].copy())
    track = online_track(at_log)
    vehicle = track.world_T_camera @ np.linalg.inv(cam.mount)
    np.testing.assert_allclose(vehicle[:, :3, :3], log["rotation"][3::7], atol=1e-9)
    np.testing.assert_allclose(vehicle[:, :3, 3], log["position"][3::7], atol=1e-9)
    assert track.source == "online"
    assert np.all(track.covariance == track.covariance[0])


def test_online_track_interpolates_and_carries_its_covariance_through_the_mount(capture):
    cam = capture.camera("uav1")
    noise = OnlineNoise(rotation_sigma_deg=2.0, position_sigma_m=0.5)
    track = online_track(cam, noise=noise)
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
    tracks, notes = camera_priors(small, "fused", verbose=False)
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
        fuse_vehicle(late, verbose=False)
    tracks, notes = camera_priors(Capture(name="late", cameras=[late]), verbose=False)
    assert tracks == {} and "outside" in notes[0]


def test_unknown_source_is_refused(capture):
    with pytest.raises(MocapgraphError, match="fused, online"):
        camera_priors(capture, "magic")


# ---------------------------------------------------------------------------------------------
# The position-fix factor


def test_fix_factor_jacobians_match_numerical_differentiation():
    rng = np.random.default_rng(0)
    x, _, _ = nav_keys(4)
    d = drift_key(4)
    values = gtsam.Values()
    values.insert(x, gtsam.Pose3(gtsam.Rot3(rotvec_to_matrix(rng.normal(size=3))), rng.normal(size=3)))
    values.insert(d, rng.normal(size=4))
    A_p = np.vstack([np.eye(3), [[0.0, 0.0, 1.0]]])
    A_d = np.vstack([np.hstack([np.eye(3), np.zeros((3, 1))]), [[0.0, 0.0, 0.0, 1.0]]])
    factor = _fix_factor(x, d, rng.normal(size=4), A_p, A_d, np.array([1.0, 1.0, 2.0, 0.3]))
    A, _ = factor.linearize(values).jacobian()
    numeric = np.zeros_like(A)
    eps = 1e-6
    for column in range(10):
        step = np.zeros(10)
        step[column] = eps
        deltas = []
        for sign in (1.0, -1.0):
            delta = gtsam.VectorValues()
            delta.insert(x, sign * step[:6])
            delta.insert(d, sign * step[6:])
            deltas.append(factor.whitenedError(values.retract(delta)))
        numeric[:, column] = (deltas[0] - deltas[1]) / (2 * eps)
    np.testing.assert_allclose(A, numeric, atol=1e-7)


def test_fusion_noise_splits_drift_from_the_logged_sigma():
    noise = FusionNoise()
    np.testing.assert_allclose(noise.drift_sigma(), [0.5, 0.5, 1.0, 0.5])
    np.testing.assert_allclose(noise.drift_time(), [60.0, 60.0, 60.0, 120.0])
