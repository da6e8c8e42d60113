"""Importers: OpenPose JSON folders, calibration files, and captures assembled from them."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from mocapgraph.body.rotations import rotvec_to_matrix
from mocapgraph.cli.main import main
from mocapgraph.data_tools.io.calibration import CameraCalibration, read_calibration
from mocapgraph.data_tools.io.capture import CaptureError, load_capture
from mocapgraph.data_tools.io.importers import assemble_capture
from mocapgraph.data_tools.io.keypoint_files import OPENPOSE_SUFFIX, read_json_keypoints
from mocapgraph.errors import MocapgraphError


def read_openpose_json_folder(folder, person="largest"):
    """OpenPose's own output: BODY_25 unless told otherwise."""
    kp, boxes, fmt = read_json_keypoints(folder, "openpose25", person, suffix=OPENPOSE_SUFFIX)
    assert fmt == "openpose25"
    return kp, boxes

K1 = np.array([[1210.5, 0.0, 962.25], [0.0, 1205.0, 541.5], [0.0, 0.0, 1.0]])
DIST1 = np.array([-0.11, 0.052, 0.0007, -0.0012, 0.003])
RVEC1 = np.array([0.3, -1.2, 0.25])
T1 = np.array([0.4, -0.15, 3.2])


def camera_point(world_T_camera: np.ndarray, X: np.ndarray) -> np.ndarray:
    return (np.linalg.inv(world_T_camera) @ np.append(X, 1.0))[:3]


def assert_pose(world_T_camera, R, t):
    """The pose maps world points into the camera exactly as ``x_cam = R X + t`` does."""
    assert world_T_camera.shape == (4, 4)
    for X in ([0.0, 0.0, 0.0], [1.0, -2.0, 0.5], [3.0, 0.1, -1.0]):
        np.testing.assert_allclose(camera_point(world_T_camera, np.array(X)), R @ X + t, atol=1e-9)


# ---------------------------------------------------------------------------------------------
# OpenPose


def person(rng, x0, y0, scale, zero=()):
    kp = np.column_stack([x0 + rng.random(25) * scale, y0 + rng.random(25) * scale, 0.2 + 0.8 * rng.random(25)])
    kp[list(zero)] = 0.0
    return kp


def write_frame(folder, stem, people):
    doc = {"version": 1.3, "people": [{"person_id": [-1], "pose_keypoints_2d": p.ravel().tolist()} for p in people]}
    (folder / f"{stem}_keypoints.json").write_text(json.dumps(doc))


def test_openpose_folder_natural_order_largest_person_and_missing(tmp_path):
    rng = np.random.default_rng(0)
    small, large = person(rng, 10, 10, 50), person(rng, 300, 200, 400, zero=(3, 20))
    other = person(rng, 700, 100, 120)
    write_frame(tmp_path, "clip_2", [small, large])
    write_frame(tmp_path, "clip_10", [other])
    write_frame(tmp_path, "clip_1", [])  # nobody in this frame
    (tmp_path / "notes.json").write_text("not a keypoints file, ignored")

    kp, boxes = read_openpose_json_folder(tmp_path)
    assert kp.shape == (3, 25, 3) and boxes.shape == (3, 5)
    # natural order: clip_1, clip_2, clip_10
    assert np.isnan(kp[0]).all() and np.isnan(boxes[0]).all()
    expected = large.copy()
    expected[[3, 20]] = np.nan  # OpenPose's (0, 0, 0) means missing
    np.testing.assert_array_equal(kp[1], expected)
    np.testing.assert_array_equal(kp[2], other)
    present = large[np.isfinite(expected[:, 0])]
    np.testing.assert_allclose(
        boxes[1], [present[:, 0].min(), present[:, 1].min(), present[:, 0].max(), present[:, 1].max(), present[:, 2].mean()]
    )

    kp0, boxes0 = read_openpose_json_folder(tmp_path, person=0)
    np.testing.assert_array_equal(kp0[1], small)
    kp1, _ = read_openpose_json_folder(tmp_path, person=1)
    np.testing.assert_array_equal(kp1[1], expected)
    assert np.isnan(kp1[2]).all()  # that frame has one person only


@pytest.mark.parametrize(
    "content, words",
    [
        ("{not json", ["not valid JSON"]),
        (json.dumps({"people": [{"pose_keypoints_2d": [1.0] * 74}]}), ["people[0].pose_keypoints_2d", "74 values", "multiple of 3"]),
        (json.dumps({"people": [{"pose_keypoints_2d": [1.0] * 54}]}), ["expected 75", "got 54", "COCO-18"]),
        (json.dumps({"people": [{"pose_keypoints_2d": [1.0] * 78}]}), ["expected 75", "got 78", "26 points is halpe26"]),
        (json.dumps({"people": [{"face_keypoints_2d": []}]}), ["people[0].pose_keypoints_2d", "missing"]),
        (json.dumps({"version": 1.3}), ["people"]),
        (json.dumps({"people": [{"pose_keypoints_2d": ["a"] * 75}]}), ["not all numbers"]),
        (json.dumps({"people": [{"pose_keypoints_2d": [1.0, 1.0, -0.5] * 25}]}), ["negative confidence"]),
    ],
)
def test_openpose_bad_file_names_the_file(tmp_path, content, words):
    write_frame(tmp_path, "f_000", [person(np.random.default_rng(1), 0, 0, 10)])
    (tmp_path / "f_001_keypoints.json").write_text(content)
    with pytest.raises(CaptureError) as err:
        read_openpose_json_folder(tmp_path)
    assert "f_001_keypoints.json" in str(err.value)
    for word in words:
        assert word in str(err.value)


def test_openpose_empty_or_missing_folder(tmp_path):
    with pytest.raises(CaptureError, match="no \\*_keypoints.json files"):
        read_openpose_json_folder(tmp_path)
    with pytest.raises(CaptureError, match="not found"):
        read_openpose_json_folder(tmp_path / "nope")


# ---------------------------------------------------------------------------------------------
# Calibrations


def write_filestorage(path, cameras):
    """cameras: list of (node name or None for the top level, {key: value})."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for node, fields in cameras:
        if node is not None:
            fs.startWriteStruct(node, cv2.FILE_NODE_MAP)
        for key, value in fields.items():
            fs.write(key, value)
        if node is not None:
            fs.endWriteStruct()
    fs.release()


@pytest.mark.parametrize("ext", ["yml", "xml", "json"])
def test_opencv_filestorage_single_camera(tmp_path, ext):
    R = rotvec_to_matrix(RVEC1)
    path = tmp_path / f"left.{ext}"
    write_filestorage(path, [(None, {
        "image_width": 1920, "image_height": 1080, "camera_matrix": K1,
        "distortion_coefficients": DIST1.reshape(1, 5), "R": R, "T": T1.reshape(3, 1),
    })])  # fmt: skip
    (cam,) = read_calibration(path)
    assert cam.name == "left" and cam.image_size == (1920, 1080)
    np.testing.assert_allclose(cam.K, K1, rtol=0, atol=1e-12)
    np.testing.assert_allclose(cam.distortion, DIST1, rtol=0, atol=1e-12)
    assert_pose(cam.world_T_camera, R, T1)


@pytest.mark.parametrize("ext", ["yml", "xml", "json"])
def test_opencv_filestorage_cam_prefixed_nodes(tmp_path, ext):
    rvec2, t2 = np.array([0.0, 0.5, 0.0]), np.array([1.0, 0.0, 2.0])
    path = tmp_path / f"rig.{ext}"
    write_filestorage(path, [
        ("cam_left", {"K": K1, "D": DIST1[:4], "rvec": RVEC1.reshape(3, 1), "tvec": T1, "image_size": np.array([[1920, 1080]])}),
        # intrinsics only; calibrateCamera's per-view rvecs are not the camera's pose
        ("cam_right", {"cameraMatrix": K1 * [[2], [2], [1]], "distCoeffs": np.zeros(5), "rvecs": np.ones((4, 3))}),
        ("cam_top", {"K": K1, "dist_coeffs": DIST1, "rotation": rvec2, "translation": t2,
                     "width": 1280, "height": 720, "name": "ceiling"}),
        ("info", {"date": "today"}),
    ])  # fmt: skip
    cams = {c.name: c for c in read_calibration(path)}
    assert list(cams) == ["left", "right", "ceiling"]
    np.testing.assert_allclose(cams["left"].distortion, [*DIST1[:4], 0.0], atol=1e-12)
    assert_pose(cams["left"].world_T_camera, rotvec_to_matrix(RVEC1), T1)
    assert cams["left"].image_size == (1920, 1080)
    assert cams["right"].world_T_camera is None and cams["right"].image_size is None
    np.testing.assert_allclose(cams["right"].K[0, 0], 2 * K1[0, 0])
    assert cams["ceiling"].image_size == (1280, 720)
    assert_pose(cams["ceiling"].world_T_camera, rotvec_to_matrix(rvec2), t2)


def test_plain_json_dict_and_list(tmp_path):
    R = rotvec_to_matrix(RVEC1)
    doc = {
        "front": {"K": K1.tolist(), "dist": DIST1.tolist(), "size": [1920, 1080], "R": R.tolist(), "t": T1.tolist()},
        "side": {"K": K1.ravel().tolist(), "dist": [0, 0, 0, 0], "size": [1920, 1080], "R": RVEC1.tolist(), "t": [0, 0, 5]},
    }
    path = tmp_path / "calib.json"
    path.write_text(json.dumps(doc))
    cams = {c.name: c for c in read_calibration(path)}
    np.testing.assert_allclose(cams["front"].K, K1)
    np.testing.assert_allclose(cams["side"].K, K1)  # a flat row-major list works too
    assert_pose(cams["front"].world_T_camera, R, T1)
    assert_pose(cams["side"].world_T_camera, R, np.array([0.0, 0.0, 5.0]))

    listed = tmp_path / "list.json"
    listed.write_text(json.dumps({"cameras": [dict(doc["front"], name="a"), dict(doc["side"], name="b")]}))
    assert [c.name for c in read_calibration(listed)] == ["a", "b"]


POSE2SIM = """
[cam_01]
name = "cam01"
size = [ 1920.0, 1080.0,]
matrix = [ [ 1210.5, 0.0, 962.25,], [ 0.0, 1205.0, 541.5,], [ 0.0, 0.0, 1.0,],]
distortions = [ -0.11, 0.052, 0.0007, -0.0012,]
rotation = [ 0.3, -1.2, 0.25,]
translation = [ 0.4, -0.15, 3.2,]
fisheye = false

[cam_02]
name = "cam02"
size = [ 1920.0, 1080.0,]
matrix = [ [ 1100.0, 0.0, 960.0,], [ 0.0, 1100.0, 540.0,], [ 0.0, 0.0, 1.0,],]
distortions = [ 0.0, 0.0, 0.0, 0.0,]
rotation = [ 0.0, 0.5, 0.0,]
translation = [ 1.0, 0.0, 2.0,]
fisheye = false

[metadata]
adjusted = false
error = 0.0
"""


def test_pose2sim_toml(tmp_path):
    path = tmp_path / "Calib_scene.toml"
    path.write_text(POSE2SIM)
    cams = read_calibration(path)
    assert [c.name for c in cams] == ["cam01", "cam02"]  # [metadata] is not a camera
    np.testing.assert_allclose(cams[0].K, K1)
    np.testing.assert_allclose(cams[0].distortion, [*DIST1[:4], 0.0])
    assert cams[0].image_size == (1920, 1080)
    assert_pose(cams[0].world_T_camera, rotvec_to_matrix(RVEC1), T1)


def test_anipose_toml_in_millimetres(tmp_path):
    path = tmp_path / "calibration.toml"
    path.write_text(
        '[cam_0]\nname = "A"\nsize = [ 1280, 720,]\n'
        "matrix = [ [ 900.0, 0.0, 640.0,], [ 0.0, 900.0, 360.0,], [ 0.0, 0.0, 1.0,],]\n"
        "distortions = [ -0.2, 0.1, 0.0, 0.0, -0.03,]\nrotation = [ 0.3, -1.2, 0.25,]\n"
        "translation = [ 400.0, -150.0, 3200.0,]\n\n[metadata]\nerror = 0.4\n"
    )
    (cam,) = read_calibration(path, units="mm")
    np.testing.assert_allclose(cam.distortion, [-0.2, 0.1, 0.0, 0.0, -0.03])
    assert_pose(cam.world_T_camera, rotvec_to_matrix(RVEC1), T1)  # millimetres → metres
    (raw,) = read_calibration(path)
    np.testing.assert_allclose(raw.world_T_camera[:3, 3], cam.world_T_camera[:3, 3] * 1000)


@pytest.mark.parametrize(
    "name, content, words",
    [
        ("c.toml", POSE2SIM.replace("fisheye = false", "fisheye = true", 1), ["fisheye"]),
        ("c.toml", "[cam_1\nname=", ["not valid TOML"]),
        ("c.json", "{oops", ["not valid JSON"]),
        ("c.yml", "%YAML:1.0\nK: [1, 2\n", ["not a readable OpenCV FileStorage file"]),
        ("c.txt", "hello there, not a calibration", ["unknown calibration format"]),
        ("c.json", json.dumps({"foo": {"bar": 1}}), ["no camera found"]),
        ("c.json", json.dumps({"a": {"K": [[1, 0, 0], [0, 1, 0]]}}), ["a.K", "expected shape (3, 3)"]),
        ("c.json", json.dumps({"a": {"K": K1.tolist(), "R": [[1, 0, 0], [0, 1, 0], [0, 0, 2]], "t": [0, 0, 0]}}),
         ["a.R", "not a rotation"]),
        ("c.json", json.dumps({"a": {"K": K1.tolist(), "R": [0, 0, 0]}}), ["a.R", "without a translation"]),
        ("c.json", json.dumps({"a": {"K": K1.tolist(), "dist": [1, 2, 3]}}), ["a.dist", "4 or 5"]),
        ("c.json", json.dumps({"a": {"K": K1.tolist(), "size": [640.5, 480]}}), ["a.size", "whole pixels"]),
        ("c.json", json.dumps([{"K": K1.tolist(), "name": "x"}, {"K": K1.tolist(), "name": "x"}]), ["unique"]),
    ],
)  # fmt: skip
def test_bad_calibration_names_the_file(tmp_path, name, content, words):
    path = tmp_path / name
    path.write_text(content)
    with pytest.raises(CaptureError) as err:
        read_calibration(path)
    assert str(path) in str(err.value)
    for word in words:
        assert word in str(err.value)


def test_calibration_file_missing_or_bad_units(tmp_path):
    with pytest.raises(CaptureError, match="not found"):
        read_calibration(tmp_path / "none.yml")
    (tmp_path / "c.toml").write_text(POSE2SIM)
    with pytest.raises(CaptureError, match="unknown units"):
        read_calibration(tmp_path / "c.toml", units="ft")


def test_content_sniffing_without_a_known_extension(tmp_path):
    (tmp_path / "a.calib").write_text(POSE2SIM)
    assert [c.name for c in read_calibration(tmp_path / "a.calib")] == ["cam01", "cam02"]
    (tmp_path / "b.calib").write_text(json.dumps([{"K": K1.tolist(), "name": "x"}]))
    assert [c.name for c in read_calibration(tmp_path / "b.calib")] == ["x"]
    write_filestorage(tmp_path / "c.yml", [(None, {"K": K1})])
    (tmp_path / "c.calib").write_text((tmp_path / "c.yml").read_text())
    assert [c.name for c in read_calibration(tmp_path / "c.calib")] == ["c"]


# ---------------------------------------------------------------------------------------------
# Assembling a capture


def write_video(path, frames, size=(64, 48), fps=25.0):
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, size)
    assert writer.isOpened()
    for i in range(frames):
        writer.write(np.full((size[1], size[0], 3), (i * 37) % 255, np.uint8))
    writer.release()
    return path


def detections(frames, seed=0, points=25):
    rng = np.random.default_rng(seed)
    kp = np.column_stack([rng.random((frames * points, 2)) * 60, rng.random(frames * points)]).reshape(frames, points, 3)
    kp[1] = np.nan
    boxes = np.tile([1.0, 2.0, 50.0, 40.0, 0.8], (frames, 1))
    boxes[1] = np.nan
    return kp, boxes


def test_assemble_capture_round_trip(tmp_path):
    front = write_video(tmp_path / "front.avi", 6)
    side = write_video(tmp_path / "side.avi", 5)
    kp_f, boxes_f = detections(6)
    kp_s, _ = detections(5, seed=1)
    R = rotvec_to_matrix(RVEC1)
    K = np.array([[80.0, 0, 32], [0, 80, 24], [0, 0, 1]])
    from mocapgraph.data_tools.io.capture import world_T_camera_from_Rt

    calib = [CameraCalibration("front", K, DIST1, (64, 48), world_T_camera_from_Rt(R, T1))]
    out = assemble_capture(
        [front, side],
        {"front": ("openpose", "openpose25", kp_f, boxes_f), "side": ("openpose", "openpose25", kp_s, None)},
        calib, 30.0, tmp_path / "cap", "lab",
    )  # fmt: skip
    capture = load_capture(out)
    assert capture.name == "lab" and [c.name for c in capture.cameras] == ["front", "side"]
    f, s = capture.cameras
    assert not f.moving and s.moving
    np.testing.assert_allclose(f.K, K)
    np.testing.assert_allclose(f.distortion, DIST1)
    assert f.extrinsics.shape == (1, 4, 4)
    assert_pose(f.extrinsics[0], R, T1)
    assert s.extrinsics is None
    # the documented guess: f = 1.2 max(w, h), principal point at the centre, no distortion
    np.testing.assert_allclose(s.K, [[76.8, 0, 32], [0, 76.8, 24], [0, 0, 1]])
    np.testing.assert_array_equal(s.distortion, np.zeros(5))
    assert f.image_size == (64, 48) and s.image_size == (64, 48)
    np.testing.assert_allclose(f.timestamps, np.arange(6) / 30.0)
    np.testing.assert_allclose(s.timestamps, np.arange(5) / 30.0)
    assert f.frame_rate == 30.0
    det = f.detectors["openpose"]
    assert det.format == "openpose25"
    np.testing.assert_array_equal(det.keypoints, kp_f)
    np.testing.assert_array_equal(det.boxes, boxes_f)
    assert s.detectors["openpose"].boxes is None
    assert f.video == "cameras/front/video.avi"
    assert (out / f.video).read_bytes() == front.read_bytes()
    assert capture.metadata["imported"]["guessed_intrinsics"] == ["side"]


def test_assemble_capture_without_videos_and_overrides(tmp_path):
    kp, boxes = detections(4, points=33)
    calib = [
        CameraCalibration("a", K1, DIST1, (1920, 1080), None),
        CameraCalibration("b", K1, np.zeros(5), (1920, 1080), np.eye(4)),
    ]
    out = assemble_capture(
        None, {"a": ("mp", "blazepose33", kp, boxes), "b": [("mp", "blazepose33", kp, None)]},
        calib, {"a": 25.0, "b": 50.0}, tmp_path / "c2", moving={"a": False},
    )  # fmt: skip
    a, b = load_capture(out).cameras
    assert not a.moving and a.extrinsics is None  # told static, no pose known
    assert not b.moving and b.extrinsics is not None
    np.testing.assert_allclose(b.timestamps, np.arange(4) / 50.0)
    assert a.video is None
    with pytest.raises(CaptureError, match="already exists"):
        assemble_capture(None, {"a": ("mp", "blazepose33", kp, None)}, calib[:1], 25.0, out)
    assemble_capture(None, {"a": ("mp", "blazepose33", kp, None)}, calib[:1], 25.0, out, overwrite=True)
    assert [c.name for c in load_capture(out).cameras] == ["a"]


def test_assemble_capture_errors(tmp_path):
    video = write_video(tmp_path / "cam.avi", 3)
    kp, _ = detections(3)
    small = [CameraCalibration("cam", K1, DIST1, (1920, 1080), None)]
    with pytest.raises(CaptureError, match="calibration of camera cam is for 1920x1080"):
        assemble_capture([video], {}, small, 25.0, tmp_path / "x")
    with pytest.raises(CaptureError, match="camera other: image size unknown"):
        assemble_capture([video], {"other": ("op", "openpose25", kp, None)}, None, 25.0, tmp_path / "x")
    with pytest.raises(CaptureError, match="image size unknown.*calibrated cameras: c1"):
        assemble_capture(None, {"cam": ("op", "openpose25", kp, None)}, [CameraCalibration("c1", K1, DIST1, None)],
                         25.0, tmp_path / "x")  # fmt: skip
    with pytest.raises(CaptureError, match="keypoints must be \\(T, 33, 3\\)"):
        assemble_capture([video], {"cam": ("op", "blazepose33", kp, None)}, None, 25.0, tmp_path / "x")
    with pytest.raises(CaptureError, match="marked moving"):
        cal = [CameraCalibration("cam", K1, DIST1, None, np.eye(4))]
        assemble_capture([video], {}, cal, 25.0, tmp_path / "x", moving={"cam": True})
    with pytest.raises(CaptureError, match="nothing to import"):
        assemble_capture(None, {}, small, 25.0, tmp_path / "x")
    with pytest.raises(CaptureError, match="frame rate must be positive"):
        assemble_capture([video], {}, None, 0.0, tmp_path / "x")
    assert not (tmp_path / "x").exists()


def test_assemble_capture_mixes_calibrated_and_uncalibrated_cameras(tmp_path, caplog):
    video = write_video(tmp_path / "phone.avi", 3)
    calib = [CameraCalibration("c1", K1, DIST1, None, np.eye(4)), CameraCalibration("c2", K1, DIST1, (64, 48))]
    out = assemble_capture([video], {"c2": ("op", "openpose25", detections(4)[0], None)}, calib, 25.0, tmp_path / "m")
    phone, c2 = load_capture(out).cameras
    assert phone.moving and phone.K[0, 0] == pytest.approx(1.2 * 64)
    assert c2.moving and c2.video is None and c2.num_frames == 4  # intrinsics only: no pose, so moving
    assert "['c1'] have no video or keypoints; skipped" in caplog.text
    assert "['phone'] are not in the calibration" in caplog.text


def test_assemble_capture_video_only_counts_frames_and_copies(tmp_path):
    video = write_video(tmp_path / "solo.avi", 7)
    out = assemble_capture({"solo": video}, {}, None, 25.0, tmp_path / "c", video_mode="copy")
    (cam,) = load_capture(out).cameras
    assert cam.num_frames == 7 and cam.moving and cam.detectors == {}
    assert (out / "cameras/solo/video.avi").stat().st_ino != video.stat().st_ino


def test_a_symlinked_video_is_linked_to_its_file(tmp_path):
    video = write_video(tmp_path / "real.avi", 3)
    (tmp_path / "links").mkdir()
    (tmp_path / "links" / "cam.avi").symlink_to(video)
    out = assemble_capture([tmp_path / "links" / "cam.avi"], {}, None, 25.0, tmp_path / "c")
    placed = out / load_capture(out).cameras[0].video
    assert not placed.is_symlink() and placed.stat().st_ino == video.stat().st_ino


# ---------------------------------------------------------------------------------------------
# The `capture import` command


def run_cli(argv, capsys):
    """Run the real ``mocapgraph`` command line: (exit code, stdout, or the one-line error)."""
    code = main(argv)
    out = capsys.readouterr()
    return code, out.out if code == 0 else out.err.removeprefix("mocapgraph: error: ").strip()


def test_capture_import_command(tmp_path, capsys):
    rng = np.random.default_rng(3)
    for cam in ("cam01", "cam02"):
        (tmp_path / cam).mkdir()
        for i in range(4):
            write_frame(tmp_path / cam, f"{cam}_{i:012d}", [person(rng, 100, 100, 300)] if i != 2 else [])
    (tmp_path / "calib.toml").write_text(POSE2SIM)
    code, out = run_cli(
        ["capture", "import", "--openpose", f"cam01={tmp_path / 'cam01'}", "--openpose", str(tmp_path / "cam02"),
         "--calibration", str(tmp_path / "calib.toml"), "--fps", "50", "--out", str(tmp_path / "cap")],
        capsys,
    )  # fmt: skip
    assert code == 0, out
    assert "cam01: 4 frames at 50 fps, 1920x1080, calibrated intrinsics, static with pose" in out
    assert "openpose (openpose25) person in 75% of frames" in out
    capture = load_capture(tmp_path / "cap")
    assert [c.name for c in capture.cameras] == ["cam01", "cam02"]
    assert_pose(capture.cameras[0].extrinsics[0], rotvec_to_matrix(RVEC1), T1)
    assert np.isnan(capture.cameras[1].detectors["openpose"].keypoints[2]).all()

    code, message = run_cli(
        ["capture", "import", "--openpose", f"cam09={tmp_path / 'cam01'}", "--calibration", str(tmp_path / "calib.toml"),
         "--fps", "50", "--out", str(tmp_path / "cap2")],
        capsys,
    )  # fmt: skip
    assert code == 2 and "cam09" in message
    code, message = run_cli(["capture", "import", "--fps", "50", "--out", str(tmp_path / "cap")], capsys)
    assert code == 2 and "already exists" in message


def test_shared_capture_flags_give_intrinsics_only(tmp_path):
    """``detect`` and ``capture import`` read the calibration through the shared flags."""
    import argparse

    from mocapgraph.cli.capture import add_capture_flags, calibration_from_args

    parser = argparse.ArgumentParser()
    add_capture_flags(parser)
    (tmp_path / "c.toml").write_text(POSE2SIM)
    argv = ["--out", str(tmp_path / "x"), "--calibration", str(tmp_path / "c.toml")]
    full = calibration_from_args(parser.parse_args(argv))
    lens = calibration_from_args(parser.parse_args(argv + ["--intrinsics-only"]))
    assert [c.name for c in lens] == ["cam01", "cam02"] and all(c.world_T_camera is None for c in lens)
    assert all(c.world_T_camera is not None for c in full)
    for a, b in zip(full, lens):
        np.testing.assert_array_equal(a.K, b.K)
        np.testing.assert_array_equal(a.distortion, b.distortion)
        assert a.image_size == b.image_size
    with pytest.raises(MocapgraphError, match="--intrinsics-only needs a calibration"):
        calibration_from_args(parser.parse_args(["--out", "x", "--intrinsics-only"]))
    assert calibration_from_args(parser.parse_args(["--out", "x"])) is None
