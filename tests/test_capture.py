"""The capture format: a full round trip, one clear error per bad field, atomic writes."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import random_root

from mocapgraph.data_tools.io import capture as cap
from mocapgraph.data_tools.io.capture import (
    Camera,
    Capture,
    CaptureError,
    Detector,
    GroundTruth,
    Rt_from_world_T_camera,
    load_capture,
    world_T_camera_from_Rt,
    write_capture,
)


def make_capture(seed: int = 0) -> Capture:
    rng = np.random.default_rng(seed)
    K = np.array([[1000.0, 0, 960], [0, 1000, 540], [0, 0, 1]])
    ts0 = np.arange(6) / 30.0
    ts1 = 0.013 + np.arange(5) / 35.0
    kp = rng.random((6, 25, 3)) * [1920, 1080, 1]
    kp[2, 4] = np.nan
    boxes = np.tile([100.0, 50, 400, 900, 0.9], (6, 1))
    boxes[3] = np.nan
    cams = [
        Camera(
            name="static0", K=K, distortion=np.array([0.1, -0.05, 0, 0, 0.01]), image_size=(1920, 1080),
            moving=False, timestamps=ts0, frame_rate=30.0,
            detectors={"openpose": Detector("openpose", "openpose25", kp, boxes)},
            extrinsics=random_root(rng, 1),
        ),
        Camera(
            name="uav1", K=K, distortion=np.zeros(5), image_size=(1920, 1080), moving=True, timestamps=ts1,
            frame_rate=35.0, detectors={"hrnet": Detector("hrnet", "coco17", rng.random((5, 17, 3)))},
            mount=random_root(rng, 1)[0],
            sensors={
                "gps": {"t": np.arange(10) / 100, "position": rng.normal(size=(10, 3)), "sigma": np.ones((10, 3))},
                "imu": {"t": np.arange(10) / 100, "accel": rng.normal(size=(10, 3)), "gyro": rng.normal(size=(10, 3))},
                "self_pose": {"t": np.arange(10) / 100, "rotation": random_root(rng, 10)[:, :3, :3],
                              "position": rng.normal(size=(10, 3))},
            },
        ),
    ]  # fmt: skip
    gt = GroundTruth(
        body_model="anny", timestamps=ts0, root=random_root(rng, 6), pose=rng.normal(size=(6, 21, 3)),
        shape=np.full(6, 0.5), joints=rng.normal(size=(6, 22, 3)),
        cameras={"static0": np.repeat(cams[0].extrinsics, 6, axis=0), "uav1": random_root(rng, 5)},
    )  # fmt: skip
    return Capture(name="unit", cameras=cams, world_frame="ENU test", ground_truth=gt, metadata={"seed": seed})


def test_round_trip_keeps_every_array(tmp_path):
    original = make_capture()
    path = write_capture(original, tmp_path / "cap")
    loaded = load_capture(path)
    assert loaded.name == "unit" and loaded.world_frame == "ENU test" and loaded.metadata == {"seed": 0}
    for a, b in zip(original.cameras, loaded.cameras):
        assert (a.name, a.moving, a.image_size, a.frame_rate) == (b.name, b.moving, b.image_size, b.frame_rate)
        for field in ("K", "distortion", "timestamps"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
        for name, det in a.detectors.items():
            np.testing.assert_array_equal(det.keypoints, b.detectors[name].keypoints)
            assert det.format == b.detectors[name].format
        assert a.sensors.keys() == b.sensors.keys()
        for kind in a.sensors:
            for key, arr in a.sensors[kind].items():
                np.testing.assert_allclose(arr, b.sensors[kind][key], atol=1e-12)
    np.testing.assert_allclose(loaded.cameras[0].extrinsics, original.cameras[0].extrinsics, atol=1e-12)
    np.testing.assert_allclose(loaded.cameras[1].mount, original.cameras[1].mount, atol=1e-12)
    for name, poses in original.ground_truth.cameras.items():
        np.testing.assert_allclose(loaded.ground_truth.cameras[name], poses, atol=1e-12)
    np.testing.assert_allclose(loaded.ground_truth.root, original.ground_truth.root, atol=1e-12)
    assert loaded.camera("uav1").num_frames == 5


def test_files_store_world_to_camera(tmp_path):
    """The stored R, t map world points into the camera, as OpenCV's extrinsics do."""
    original = make_capture()
    write_capture(original, tmp_path / "cap")
    with np.load(tmp_path / "cap" / "cameras" / "static0" / "extrinsics.npz") as f:
        R, t = f["R"][0], f["t"][0]
    T = original.cameras[0].extrinsics[0]
    point = np.array([0.3, -1.2, 2.0])
    np.testing.assert_allclose(R @ point + t, np.linalg.solve(T, np.r_[point, 1])[:3], atol=1e-12)
    R2, t2 = Rt_from_world_T_camera(world_T_camera_from_Rt(R, t))
    np.testing.assert_allclose(R2, R, atol=1e-15)
    np.testing.assert_allclose(t2, t, atol=1e-12)


def edit_manifest(path, old, new):
    manifest = path / "capture.toml"
    text = manifest.read_text()
    assert old in text, old
    manifest.write_text(text.replace(old, new, 1))


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda p: (p / "capture.toml").unlink(), r"capture.toml: missing"),
        (lambda p: (p / "capture.toml").write_text("not = [toml"), r"capture.toml: not valid TOML"),
        (lambda p: edit_manifest(p, "version = 1", "version = 7"), r"capture.toml: version: this mocapgraph reads version 1"),
        (lambda p: edit_manifest(p, "1000.0", "-1000.0"), r"capture.toml: cameras.static0.K: needs fx > 0"),
        (lambda p: edit_manifest(p, '"openpose25"', '"posenet9"'), r"cameras.static0.detectors\[0\].format: unknown keypoint format 'posenet9'"),
        (lambda p: edit_manifest(p, 'kind = "gps"', 'kind = "lidar"'), r"cameras.uav1.sensors\[0\].kind: unknown sensor kind 'lidar'"),
        (lambda p: edit_manifest(p, "image_size = [", "image_size = [0, "), r"cameras.static0.image_size: expected \[width, height\]"),
        (lambda p: edit_manifest(p, 'timestamps = "cameras/static0/timestamps.npy"', 'timestamps = "../elsewhere.npy"'), "points outside the directory"),
        (lambda p: (p / "cameras/uav1/detector_hrnet.npz").unlink(), r"cameras.uav1.detectors\[0\].file: file 'cameras/uav1/detector_hrnet.npz' not found"),
        (lambda p: np.save(p / "cameras/static0/timestamps.npy", np.array([0.0, 0.1, np.nan, 0.05, 0.3, 0.4])), r"cameras/static0/timestamps.npy: timestamps: contains NaN or inf \(first at \(2,\)\)"),
        (lambda p: np.save(p / "cameras/static0/timestamps.npy", np.zeros(0)), r"cameras/static0/timestamps.npy: timestamps: is empty"),
        (lambda p: np.save(p / "cameras/static0/timestamps.npy", np.array([0.0, 0.2, 0.1, 0.3, 0.4])), r"cameras/static0/detector_openpose.npz: keypoints: expected shape \(5, 25, 3\), got \(6, 25, 3\)"),
        (lambda p: np.savez(p / "cameras/static0/detector_openpose.npz", keypoints=np.zeros((5, 25, 3))), r"cameras/static0/detector_openpose.npz: keypoints: expected shape \(6, 25, 3\), got \(5, 25, 3\)"),
        (lambda p: np.savez(p / "cameras/static0/detector_openpose.npz", keypoints=np.full((6, 25, 3), 2.0)), r"keypoints: confidences must lie in \[0, 1\]"),
        (lambda p: np.savez(p / "cameras/uav1/sensors/gps.npz", t=np.arange(3.0), position=np.zeros((3, 3))), r"cameras/uav1/sensors/gps.npz: sigma: missing"),
        (lambda p: np.savez(p / "cameras/static0/extrinsics.npz", R=np.tile(np.eye(3), (2, 1, 1)), t=np.zeros((2, 3))), r"extrinsics.npz: R: needs 1 \(static\) or 6"),
        (lambda p: (p / "ground_truth/body.npz").write_bytes(b"garbage"), r"ground_truth/body.npz: not a readable .npz"),
    ],
)
def test_bad_fields_are_one_clear_error(tmp_path, mutate, message):
    path = write_capture(make_capture(), tmp_path / "cap")
    mutate(path)
    with pytest.raises(CaptureError, match=message):
        load_capture(path)


def test_missing_directory(tmp_path):
    with pytest.raises(CaptureError, match="nothing: directory not found"):
        load_capture(tmp_path / "nothing")


def test_write_refuses_to_clobber_and_overwrite_replaces(tmp_path):
    path = write_capture(make_capture(0), tmp_path / "cap")
    with pytest.raises(CaptureError, match="already exists"):
        write_capture(make_capture(1), path)
    write_capture(make_capture(1), path, overwrite=True)
    assert load_capture(path).metadata == {"seed": 1}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cap"]


def test_failed_write_leaves_the_old_capture_intact(tmp_path, monkeypatch):
    path = write_capture(make_capture(0), tmp_path / "cap")

    def crash(capture, root):
        (root / "capture.toml").write_text("half")
        raise RuntimeError("disk full")

    monkeypatch.setattr(cap, "_write_into", crash)
    with pytest.raises(RuntimeError, match="disk full"):
        write_capture(make_capture(1), path, overwrite=True)
    assert load_capture(path).metadata == {"seed": 0}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cap"]


def backwards_capture(tmp_path, timestamps):
    """A capture whose camera static0 has per-frame poses and ``timestamps`` written over its clean ones."""
    rng = np.random.default_rng(7)
    original = make_capture()
    static0 = original.cameras[0]
    static0.moving, static0.extrinsics = True, random_root(rng, 6)
    original.ground_truth.cameras["static0"] = random_root(rng, 6)
    path = write_capture(original, tmp_path / "cap")
    np.save(path / "cameras/static0/timestamps.npy", np.asarray(timestamps))
    return original, path


def assert_kept_frames(original: Capture, loaded: Capture, kept: list[int]):
    """Camera static0 of ``loaded`` holds exactly the frames ``kept`` of ``original``; uav1 is untouched."""
    a, b = original.camera("static0"), loaded.camera("static0")
    assert b.num_frames == len(kept)
    np.testing.assert_array_equal(b.detectors["openpose"].keypoints, a.detectors["openpose"].keypoints[kept])
    np.testing.assert_array_equal(b.detectors["openpose"].boxes, a.detectors["openpose"].boxes[kept])
    np.testing.assert_allclose(b.extrinsics, a.extrinsics[kept], atol=1e-12)
    np.testing.assert_allclose(loaded.ground_truth.cameras["static0"], original.ground_truth.cameras["static0"][kept], atol=1e-12)
    np.testing.assert_array_equal(loaded.camera("uav1").timestamps, original.camera("uav1").timestamps)
    np.testing.assert_allclose(loaded.ground_truth.cameras["uav1"], original.ground_truth.cameras["uav1"], atol=1e-12)
    np.testing.assert_array_equal(loaded.ground_truth.timestamps, original.ground_truth.timestamps)


@pytest.mark.parametrize(
    ("stamps", "kept", "note"),
    [
        (  # a clock that jumps back loses frames until it passes its earlier maximum
            [0.0, 0.1, 0.2, 0.05, 0.15, 0.3], [0, 1, 2, 5],
            "go backwards at frame 3 (0.050 s after 0.200 s); dropped 2 of 6 frames",
        ),
        (  # a repeated timestamp loses the later copy
            [0.0, 0.1, 0.1, 0.2, 0.2, 0.3], [0, 1, 3, 5],
            "repeat at frame 2 (0.100 s twice); dropped 2 of 6 frames",
        ),
    ],
)
def test_timestamps_that_do_not_increase_are_repaired_and_noted(tmp_path, stamps, kept, note):
    original, path = backwards_capture(tmp_path, stamps)
    loaded = load_capture(path)
    np.testing.assert_array_equal(loaded.camera("static0").timestamps, [0.0, 0.1, 0.2, 0.3])
    assert_kept_frames(original, loaded, kept)
    assert loaded.notes == [
        f"camera static0: timestamps (cameras/static0/timestamps.npy) {note} that were not later than an earlier frame"
    ]


def test_a_step_back_smaller_than_a_millisecond_is_printed_with_the_digits_it_needs(tmp_path):
    _, path = backwards_capture(tmp_path, [0.0, 0.1, 1.00021, 1.00014, 1.1, 1.2])
    assert load_capture(path).notes[0].startswith(
        "camera static0: timestamps (cameras/static0/timestamps.npy) go backwards at frame 3 (1.0001 s after 1.0002 s); "
        "dropped 1 of 6 frames"
    )


def test_a_clean_capture_has_no_notes(tmp_path):
    assert load_capture(write_capture(make_capture(), tmp_path / "cap")).notes == []


def test_a_repaired_camera_leaves_its_video_out(tmp_path):
    """Camera frame i is video frame i; with frames dropped that no longer holds."""
    _, path = backwards_capture(tmp_path, [0.0, 0.1, 0.2, 0.05, 0.15, 0.3])
    (path / "cameras/static0/video.mp4").write_bytes(b"")
    edit_manifest(path, 'name = "static0"\n', 'name = "static0"\nvideo = "cameras/static0/video.mp4"\n')
    loaded = load_capture(path)
    assert loaded.camera("static0").video is None and loaded.camera("static0").num_frames == 4
    assert loaded.notes[1] == "camera static0: its video cameras/static0/video.mp4 no longer matches the kept frames one to one; left out"
    np.save(path / "cameras/static0/timestamps.npy", np.arange(6) / 30.0)
    clean = load_capture(path)
    assert clean.camera("static0").video == "cameras/static0/video.mp4" and clean.notes == []


def test_a_sensor_log_going_backwards_is_repaired(tmp_path):
    original = make_capture()
    path = write_capture(original, tmp_path / "cap")
    gps = original.camera("uav1").sensors["gps"]
    t = np.array([0.0, 0.01, 0.02, 0.03, 0.04, 0.02, 0.03, 0.05, 0.06, 0.07])
    np.savez(path / "cameras/uav1/sensors/gps.npz", t=t, position=gps["position"], sigma=gps["sigma"])
    loaded = load_capture(path)
    kept = [0, 1, 2, 3, 4, 7, 8, 9]
    repaired = loaded.camera("uav1").sensors["gps"]
    np.testing.assert_array_equal(repaired["t"], t[kept])
    np.testing.assert_array_equal(repaired["position"], gps["position"][kept])
    np.testing.assert_array_equal(repaired["sigma"], gps["sigma"][kept])
    np.testing.assert_array_equal(loaded.camera("uav1").sensors["imu"]["t"], original.camera("uav1").sensors["imu"]["t"])
    assert loaded.notes == [
        "camera uav1: gps sample times (cameras/uav1/sensors/gps.npz) go backwards at sample 5 (0.020 s after 0.040 s); "
        "dropped 2 of 10 samples that were not later than an earlier sample"
    ]


def test_a_repair_is_refused_when_asked(tmp_path):
    _, path = backwards_capture(tmp_path, [0.0, 0.1, 0.2, 0.05, 0.15, 0.3])
    with pytest.raises(CaptureError, match=r"cameras/static0/timestamps.npy: timestamps: must be strictly increasing \(index 3: 0.05 after 0.2\)"):
        load_capture(path, repair=False)


def test_ground_truth_body_timestamps_are_never_repaired(tmp_path):
    path = write_capture(make_capture(), tmp_path / "cap")
    with np.load(path / "ground_truth/body.npz") as f:
        body = dict(f)
    body["timestamps"] = np.array([0.0, 0.1, 0.05, 0.2, 0.3, 0.4])
    np.savez(path / "ground_truth/body.npz", **body)
    with pytest.raises(CaptureError, match=r"ground_truth/body.npz: timestamps: must be strictly increasing \(index 2: 0.05 after 0.1\)"):
        load_capture(path)


def repeat_camera_frame(c: Capture) -> None:
    c.cameras[0].timestamps = np.array([0.0, 0.0, 1, 2, 3, 4])


def step_camera_back(c: Capture) -> None:
    c.cameras[0].timestamps = np.array([0.0, 1, 2, 1.5, 3, 4])


def step_sensor_back(c: Capture) -> None:
    c.cameras[1].sensors["imu"]["t"] = np.array([0.0, 0.01, 0.02, 0.01, 0.04, 0.05, 0.06, 0.07, 0.08, 0.09])


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (repeat_camera_frame, r"cameras/static0/timestamps.npy: timestamps: must be strictly increasing \(index 1: 0.0 after 0.0\)"),
        (step_camera_back, r"cameras/static0/timestamps.npy: timestamps: must be strictly increasing \(index 3: 1.5 after 2.0\)"),
        (step_sensor_back, r"cameras/uav1/sensors/imu.npz: t: must be strictly increasing \(index 3: 0.01 after 0.02\)"),
    ],
)
def test_an_invalid_capture_is_never_written(tmp_path, mutate, message):
    """A written capture never needs a repair: times that the loader would repair are refused."""
    bad = make_capture()
    mutate(bad)
    with pytest.raises(CaptureError, match=message):
        write_capture(bad, tmp_path / "cap")
    assert not list(tmp_path.iterdir())
