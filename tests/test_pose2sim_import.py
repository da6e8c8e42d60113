"""Pose2Sim projects, keypoint arrays and ``--intrinsics-only``, on a synthetic capture's ground truth.

The ground-truth body of a synthetic capture is projected into three of its static cameras and
written as a Pose2Sim project (per-camera JSON folders in one detector format, a ``Calib.toml``
in Pose2Sim's own layout). ``capture import`` must give back the written pixels and the cameras,
and a point triangulated with the imported calibration must land on the ground truth.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from test_importers import run_cli, write_video

from mocapgraph.body import load_body_model
from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.skeleton import BODY_KEYPOINT_NAMES
from mocapgraph.data_tools.io.calibration import read_calibration
from mocapgraph.data_tools.io.capture import CaptureError, load_capture
from mocapgraph.data_tools.io.keypoint_files import read_json_keypoints, read_keypoint_array
from mocapgraph.data_tools.io.pose2sim import read_pose2sim_project
from mocapgraph.data_tools.sim.synthetic import synthesize

CAMERAS = ("cam1", "cam2", "cam3")
FORMATS = ("openpose25", "openpose25b", "coco17", "halpe26", "blazepose33")


@pytest.fixture(scope="module")
def scene():
    """(capture, body) of a short synthetic capture; its static cameras see one walking person."""
    return synthesize("rich", seed=3, duration_s=0.5), load_body_model()


def projected(scene, camera: str, fmt: str, other: bool = False) -> np.ndarray:
    """``(T, K, 3)`` the ground-truth body's points of format ``fmt`` in ``camera``: pixels
    (OpenCV projection with the lens distortion) and a confidence in (0.3, 1). ``other``: a second
    person instead: the same body scaled by 0.7 about the world origin (a child's size, its feet
    still on the ground), set 1.2 m aside and moving backwards in time (a motion of its own, which
    epipolar geometry can tell apart from the first person's)."""
    capture, body = scene
    cam = next(c for c in capture.cameras if c.name == camera)
    gt = capture.ground_truth
    rows = np.searchsorted(gt.timestamps, cam.timestamps)
    points = body.forward(gt.shape, gt.root[rows], gt.pose[rows], keypoints=fmt).keypoints
    if other:
        points = 0.7 * points[::-1] + np.array([1.2, -0.6, 0.0])
    camera_T_world = np.linalg.inv(cam.extrinsics[0])
    rvec, tvec = cv2.Rodrigues(camera_T_world[:3, :3])[0], camera_T_world[:3, 3]
    uv = cv2.projectPoints(points.reshape(-1, 3), rvec, tvec, cam.K, cam.distortion)[0].reshape(len(rows), -1, 2)
    conf = 0.3 + 0.7 * np.random.default_rng(len(camera) + len(fmt)).random(uv.shape[:2])
    return np.concatenate([uv, conf[..., None]], axis=-1)


def write_people(folder, stem: str, frames: np.ndarray, distractor=True, missing=((1, 2),)) -> None:
    """One JSON file per frame in Pose2Sim's naming, with a second person first in the list (so
    that ``largest`` must choose) and a few points at confidence 0 (missing). ``distractor``: True
    for a copy of ``frames`` shrunk in the image (a per-frame choice tells it by size alone), the
    second person's own ``(T, K, 3)`` pixels, or False for none."""
    folder.mkdir(parents=True, exist_ok=True)
    for t, kp in enumerate(frames):
        kp = kp.copy()
        for frame, point in missing:
            if frame == t:
                kp[point] = 0.0
        people = [kp]
        if distractor is True:
            small = kp.copy()
            small[:, :2] = 0.2 * kp[:, :2] + 10.0
            people.insert(0, small)
        elif distractor is not False:
            people.insert(0, distractor[t])
        doc = {"version": 1.3, "people": [{"person_id": [-1], "pose_keypoints_2d": p.ravel().tolist()} for p in people]}
        (folder / f"{stem}_{t:06d}.json").write_text(json.dumps(doc))


def num(value) -> str:
    """A number as TOML / XML text that reads back to the same float64."""
    return repr(float(value))


def calib_toml(scene, cameras=CAMERAS, drop_matrix: str | None = None) -> str:
    """The cameras as Pose2Sim's calibration step writes them (Rodrigues world→camera, metres)."""
    capture, _ = scene
    out = []
    for i, name in enumerate(cameras):
        cam = next(c for c in capture.cameras if c.name == name)
        camera_T_world = np.linalg.inv(cam.extrinsics[0])
        r = cv2.Rodrigues(camera_T_world[:3, :3])[0].ravel()
        t, K, d = camera_T_world[:3, 3], cam.K, cam.distortion
        out.append(f"[cam_{i + 1:02d}]\nname = \"{name}\"\nsize = [ {num(float(cam.image_size[0]))}, {num(float(cam.image_size[1]))}]\n")
        if name != drop_matrix:
            out.append(f"matrix = [ [ {num(K[0, 0])}, 0.0, {num(K[0, 2])}], [ 0.0, {num(K[1, 1])}, {num(K[1, 2])}], [ 0.0, 0.0, 1.0]]\n")
        out.append(f"distortions = [ {num(d[0])}, {num(d[1])}, {num(d[2])}, {num(d[3])}]\n")
        out.append(f"rotation = [ {num(r[0])}, {num(r[1])}, {num(r[2])}]\ntranslation = [ {num(t[0])}, {num(t[1])}, {num(t[2])}]\nfisheye = false\n\n")
    out.append("[metadata]\nadjusted = false\nerror = 0.0\n")
    return "".join(out)


def make_project(root, scene, fmt="halpe26", pose_model: str | None = "Body_with_feet", frame_rate="auto", cameras=CAMERAS):
    """A Pose2Sim project; returns the written keypoints per camera."""
    written = {}
    for cam in cameras:
        written[cam] = projected(scene, cam, fmt)
        write_people(root / "pose" / f"{cam}_json", cam, written[cam], distractor=projected(scene, cam, fmt, other=True))
    (root / "calibration").mkdir(parents=True, exist_ok=True)
    (root / "calibration" / "Calib_scene.toml").write_text(calib_toml(scene))
    lines = ["[project]", f"frame_rate = {json.dumps(frame_rate)}", "multi_person = false"]
    if pose_model is not None:
        lines += ["[pose]", f"pose_model = '{pose_model}'"]
    (root / "Config.toml").write_text("\n".join(lines) + "\n")
    return written


def expected(written: np.ndarray, fmt: str, missing=((1, 2),)) -> np.ndarray:
    out = get_format(fmt).normalise(written)
    for frame, point in missing:
        out[frame, point] = np.nan
    return out


def triangulate(cameras, observations) -> np.ndarray:
    """DLT of one point seen as distorted pixels ``observations[name] (2,)`` by ``cameras`` (capture cameras)."""
    rows = []
    for cam in cameras:
        x, y = cv2.undistortPoints(observations[cam.name].reshape(1, 1, 2), cam.K, cam.distortion).ravel()
        P = np.linalg.inv(cam.extrinsics[0])[:3]
        rows += [x * P[2] - P[0], y * P[2] - P[1]]
    X = np.linalg.svd(np.array(rows))[2][-1]
    return X[:3] / X[3]


# ---------------------------------------------------------------------------------------------
# Pose2Sim projects


def test_pose2sim_project_round_trip(tmp_path, scene, capsys):
    capture, body = scene
    written = make_project(tmp_path / "proj", scene)
    code, out = run_cli(["capture", "import", "--pose2sim", str(tmp_path / "proj"), "--fps", "30", "--out", str(tmp_path / "cap")], capsys)
    assert code == 0, out
    assert "3 cameras from pose/ (halpe26, from Config.toml pose_model 'Body_with_feet')" in out
    assert "cam1: 16 frames at 30 fps, 1920x1080, calibrated intrinsics, static with pose, pose2sim (halpe26)" in out
    imported = load_capture(tmp_path / "cap")
    assert [c.name for c in imported.cameras] == list(CAMERAS)
    for cam in imported.cameras:
        truth = next(c for c in capture.cameras if c.name == cam.name)
        np.testing.assert_allclose(cam.K, truth.K, rtol=1e-15)
        np.testing.assert_allclose(cam.distortion, truth.distortion, rtol=0, atol=1e-15)
        np.testing.assert_allclose(cam.extrinsics[0], truth.extrinsics[0], rtol=0, atol=1e-12)
        det = cam.detectors["pose2sim"]
        assert det.format == "halpe26"
        np.testing.assert_allclose(det.keypoints, expected(written[cam.name], "halpe26"), rtol=0, atol=1e-9)
        np.testing.assert_allclose(cam.timestamps, np.arange(len(written[cam.name])) / 30.0)
    # Halpe's pelvis triangulated with the imported cameras is the midpoint of the true hips.
    gt = capture.ground_truth
    hips = body.forward(gt.shape, gt.root, gt.pose).keypoints[:, [BODY_KEYPOINT_NAMES.index(s + "_hip") for s in ("left", "right")]]
    for t in (0, 7, 14):
        X = triangulate(imported.cameras, {c.name: c.detectors["pose2sim"].keypoints[t, 19, :2] for c in imported.cameras})
        row = np.searchsorted(gt.timestamps, capture.cameras[0].timestamps[t])
        np.testing.assert_allclose(X, hips[row].mean(axis=0), atol=1e-6)


def test_several_people_are_followed_and_one_chosen_in_every_camera(tmp_path, scene, capsys):
    """Files holding two people (and Pose2Sim's empty placeholders): the import follows them and
    keeps one person in every camera, as ``detect`` does; the per-frame order of the files is
    shuffled, so no index and no per-frame rule could keep one person."""
    written = make_project(tmp_path / "p", scene)
    rng = np.random.default_rng(0)
    for cam in CAMERAS:
        child = projected(scene, cam, "halpe26", other=True)
        for t, path in enumerate(sorted((tmp_path / "p" / "pose" / f"{cam}_json").iterdir())):
            people = [written[cam][t], child[t]]
            if cam == "cam2" and t % 2:  # a per-frame rule on size alone would take the child here
                people[1] = child[t].copy()
                people[1][:, :2] = 3.0 * (child[t][:, :2] - child[t][0, :2]) + child[t][0, :2]
            entries = [{"pose_keypoints_2d": p.ravel().tolist()} for p in people] + [{"pose_keypoints_2d": []}]
            path.write_text(json.dumps({"people": [entries[i] for i in rng.permutation(3)]}))
    argv = ["capture", "import", "--pose2sim", str(tmp_path / "p"), "--fps", "30", "--out", str(tmp_path / "cap")]
    code, out = run_cli(argv, capsys)
    assert code == 0, out
    assert "fitting person 0: the largest of those seen by the most cameras" in out
    imported = load_capture(tmp_path / "cap")
    for cam in imported.cameras:
        np.testing.assert_allclose(cam.detectors["pose2sim"].keypoints, expected(written[cam.name], "halpe26", missing=()), rtol=0, atol=1e-9)
    people = imported.metadata["people"]
    assert people["chosen"] == 0 and all(len(p["tracks"]) == 3 for p in people["people"][:2])


def test_following_people_needs_the_image_sizes(tmp_path, scene, capsys):
    """OpenPose folders of two people each, without videos or a calibration: the image sizes the
    association needs are unknown, and the import says so, naming the cameras, and writes nothing."""
    argv = ["capture", "import", "--fps", "30", "--out", str(tmp_path / "cap")]
    for cam in CAMERAS[:2]:
        folder = tmp_path / cam
        folder.mkdir()
        own, child = projected(scene, cam, "openpose25"), projected(scene, cam, "openpose25", other=True)
        for t in range(len(own)):
            doc = {"people": [{"pose_keypoints_2d": p[t].ravel().tolist()} for p in (own, child)]}
            (folder / f"{cam}_{t:012d}_keypoints.json").write_text(json.dumps(doc))
        argv += ["--openpose", f"{cam}={folder}"]
    code, out = run_cli(argv, capsys)
    assert code == 2 and "needs each camera's image size, unknown for cam1, cam2" in out, out
    assert not (tmp_path / "cap").exists()


@pytest.mark.parametrize("fmt", FORMATS)
def test_every_format_from_the_point_count_or_format_flag(tmp_path, scene, capsys, fmt):
    written = make_project(tmp_path / "p", scene, fmt=fmt, pose_model=None)
    argv = ["capture", "import", "--pose2sim", str(tmp_path / "p"), "--fps", "30", "--out", str(tmp_path / "cap")]
    code, out = run_cli(argv, capsys)
    if get_format(fmt).num_points == 25:  # BODY_25 and BODY_25B: the count cannot tell them apart
        assert code == 2 and "25 points per person could be openpose25 or openpose25b; say which with --format" in out
        assert "cam1_000000.json: people[0]" in out
        code, out = run_cli(argv + ["--format", fmt], capsys)
    assert code == 0, out
    for cam in load_capture(tmp_path / "cap").cameras:
        det = cam.detectors["pose2sim"]
        assert det.format == fmt
        np.testing.assert_allclose(det.keypoints, expected(written[cam.name], fmt), rtol=0, atol=1e-9)


def test_pose2sim_person_index_frame_rate_and_later_folders(tmp_path, scene):
    make_project(tmp_path, scene, frame_rate=60)
    # pose-sync/ (Pose2Sim's synchronised copy) is read before pose/
    sync = {cam: projected(scene, cam, "halpe26")[2:] for cam in CAMERAS}
    for cam in CAMERAS:
        write_people(tmp_path / "pose-sync" / f"{cam}_json", cam, sync[cam], distractor=True, missing=())
    project = read_pose2sim_project(tmp_path, person=0)
    assert project.pose_folder.name == "pose-sync" and project.frame_rate == 60.0
    assert project.calibration_path.name == "Calib_scene.toml" and project.videos == {}
    fmt, kp, boxes = project.keypoints["cam2"]
    small = sync["cam2"].copy()
    small[..., :2] = 0.2 * small[..., :2] + 10.0  # people[0] is the small distractor
    np.testing.assert_allclose(kp, get_format(fmt).normalise(small), atol=1e-9)
    np.testing.assert_allclose(boxes[:, :2], np.nanmin(kp[..., :2], axis=1), atol=1e-12)


def test_pose2sim_with_videos_and_qualisys_calibration(tmp_path, scene, capsys):
    root = tmp_path / "proj"
    make_project(root, scene)
    (root / "calibration" / "Calib_scene.toml").unlink()
    (root / "calibration" / "Calib.qca.txt").write_text(qualisys_for(scene))
    (root / "videos").mkdir()
    for cam in CAMERAS:
        write_video(root / "videos" / f"{cam}.avi", 16, size=(1920, 1080), fps=30.0)
    code, out = run_cli(["capture", "import", "--pose2sim", str(root), "--out", str(tmp_path / "cap")], capsys)
    assert code == 0, out
    assert "calibration: " + str(root / "calibration" / "Calib.qca.txt") in out and "videos: 3" in out
    capture, _ = scene
    for cam in load_capture(tmp_path / "cap").cameras:
        truth = next(c for c in capture.cameras if c.name == cam.name)
        assert cam.frame_rate == 30.0 and cam.video == f"cameras/{cam.name}/video.avi"
        np.testing.assert_allclose(cam.K, truth.K, rtol=1e-12)
        np.testing.assert_allclose(cam.extrinsics[0], truth.extrinsics[0], atol=1e-9)


def qualisys_for(scene) -> str:
    """The scene's three cameras as a QTM export: 1/64-pixel intrinsics, the camera centre in mm,
    the world→camera rotation in Qualisys' camera axes (y up, z back)."""
    capture, _ = scene
    cams = []
    for name in CAMERAS:
        cam = next(c for c in capture.cameras if c.name == name)
        world_T_camera = cam.extrinsics[0]
        M = np.diag([1.0, -1.0, -1.0]) @ world_T_camera[:3, :3].T
        x, y, z = world_T_camera[:3, 3] * 1000
        K, d = cam.K * 64, cam.distortion
        w, h = cam.image_size
        rot = " ".join(f'r{i + 1}{j + 1}="{num(M[i, j])}"' for i in range(3) for j in range(3))
        cams.append(
            f'<camera active="1" serial="{name}" model="none" viewrotation="0">'
            f'<fov_video bottom="{h - 1}" left="0" right="{w - 1}" top="0"/>'
            f'<transform {rot} x="{num(x)}" y="{num(y)}" z="{num(z)}"/>'
            f'<intrinsic centerPointU="{num(K[0, 2])}" centerPointV="{num(K[1, 2])}" focalLengthU="{num(K[0, 0])}" '
            f'focalLengthV="{num(K[1, 1])}" radialDistortion1="{num(d[0])}" radialDistortion2="{num(d[1])}" radialDistortion3="{num(d[4])}" '
            f'tangentalDistortion1="{num(d[2])}" tangentalDistortion2="{num(d[3])}" skew="0"/></camera>'
        )
    return "<?xml version='1.0' encoding='ASCII'?>\n<calibration><cameras>" + "".join(cams) + "</cameras></calibration>\n"


# ---------------------------------------------------------------------------------------------
# Errors, one clear message each


def test_missing_cameras_either_way(tmp_path, scene, capsys):
    make_project(tmp_path / "a", scene, cameras=CAMERAS[:2])  # the calibration has cam3 too
    code, message = run_cli(["capture", "import", "--pose2sim", str(tmp_path / "a"), "--fps", "30", "--out", str(tmp_path / "c")], capsys)
    assert code == 2 and "missing cameras: the calibration" in message and "has cameras without a keypoint folder in" in message
    assert "pose: cam3 (the keypoint folders are cam1_json, cam2_json)" in message

    make_project(tmp_path / "b", scene)
    write_people(tmp_path / "b" / "pose" / "cam9_json", "cam9", projected(scene, "cam1", "halpe26"))
    code, message = run_cli(["capture", "import", "--pose2sim", str(tmp_path / "b"), "--fps", "30", "--out", str(tmp_path / "c")], capsys)
    assert code == 2 and "missing cameras: keypoint folders in" in message and "without a camera in the calibration" in message
    assert "Calib_scene.toml: cam9_json (the calibration has cam1, cam2, cam3)" in message
    assert not (tmp_path / "c").exists()


def test_calibration_without_intrinsics(tmp_path, scene, capsys):
    make_project(tmp_path, scene)
    path = tmp_path / "calibration" / "Calib_scene.toml"
    path.write_text(calib_toml(scene, drop_matrix="cam2"))
    with pytest.raises(CaptureError) as err:
        read_calibration(path)
    assert str(err.value).startswith(f"{path}: cam_02: camera without intrinsics (it has rotation, translation, distortions")
    code, message = run_cli(["capture", "import", "--pose2sim", str(tmp_path), "--fps", "30", "--out", str(tmp_path / "c")], capsys)
    assert code == 2 and message == str(err.value)


def test_cameras_of_different_lengths(tmp_path, scene, capsys):
    make_project(tmp_path / "p", scene)
    for extra in sorted((tmp_path / "p" / "pose" / "cam2_json").iterdir())[-6:]:
        extra.unlink()  # cam2: 10 frames, the others 16
    argv = ["capture", "import", "--pose2sim", str(tmp_path / "p"), "--out", str(tmp_path / "c")]
    code, message = run_cli(argv + ["--fps", "30"], capsys)
    assert code == 2
    assert "different lengths of time (cam1: 16 frames at 30 fps = 0.533 s; cam2: 10 frames at 30 fps = 0.333 s; cam3: 16" in message
    # a frame rate that explains it: cam2 ran at 20 fps over about the same half second
    code, out = run_cli(argv + ["--fps", "30", "--fps", "cam2=20"], capsys)
    assert code == 0, out
    cam2 = load_capture(tmp_path / "c").cameras[1]
    assert cam2.frame_rate == 20.0 and cam2.num_frames == 10
    code, out = run_cli(argv + ["--fps", "30", "--allow-unequal-length", "--overwrite"], capsys)
    assert code == 0 and "cam2: 10 frames at 30 fps" in out
    code, message = run_cli(argv + ["--fps", "cam7=30", "--overwrite"], capsys)
    assert code == 2 and "--fps names unknown camera(s) cam7" in message


def test_project_errors(tmp_path, scene, capsys):
    def fails(root, *extra):
        code, message = run_cli(["capture", "import", "--pose2sim", str(root), "--fps", "30", "--out", str(tmp_path / "c"), *extra], capsys)
        assert code == 2, message
        return message

    assert "no keypoints: expected one folder of .json files per camera in pose-associated/ or pose-sync/ or pose/" in fails(tmp_path)
    make_project(tmp_path / "p", scene, pose_model="Whole_body")
    assert "Config.toml: pose.pose_model: 'Whole_body' is not a keypoint format mocapgraph reads" in fails(tmp_path / "p")
    assert "expected 51 values (coco17: 17 points of x, y, c), got 78 (26 points is halpe26" in fails(tmp_path / "p", "--format", "coco17")
    make_project(tmp_path / "q", scene)
    (tmp_path / "q" / "videos").mkdir()
    write_video(tmp_path / "q" / "videos" / "side.avi", 3)
    assert "videos: side.avi match no keypoint folder" in fails(tmp_path / "q")
    (tmp_path / "q" / "calibration" / "other.toml").write_text("")
    assert "2 calibration files (Calib_scene.toml, other.toml); choose one with --calibration" in fails(tmp_path / "q")
    assert "leave out --openpose, --keypoints and --videos" in fails(tmp_path / "q", "--keypoints", "x.npy")


def test_a_folder_without_people_needs_a_format(tmp_path):
    (tmp_path / "cam_000000.json").write_text(json.dumps({"people": []}))
    with pytest.raises(CaptureError, match="no person in any of its 1 files, so its keypoint format is unknown"):
        read_json_keypoints(tmp_path)
    kp, boxes, fmt = read_json_keypoints(tmp_path, "halpe26")
    assert fmt == "halpe26" and kp.shape == (1, 26, 3) and np.isnan(kp).all() and np.isnan(boxes).all()


def test_people_with_different_point_counts(tmp_path, scene):
    write_people(tmp_path, "cam", projected(scene, "cam1", "halpe26")[:2], distractor=False, missing=())
    doc = {"people": [{"pose_keypoints_2d": [1.0] * 75}]}
    (tmp_path / "cam_000002.json").write_text(json.dumps(doc))
    with pytest.raises(CaptureError) as err:
        read_json_keypoints(tmp_path)
    assert "cam_000002.json: people[0].pose_keypoints_2d: expected 78 values (halpe26, told from cam_000000.json" in str(err.value)
    assert "got 75 (25 points is openpose25 or openpose25b" in str(err.value)


# ---------------------------------------------------------------------------------------------
# Keypoint arrays


def test_keypoint_arrays(tmp_path, scene, capsys):
    a, b = projected(scene, "cam1", "coco17"), projected(scene, "cam2", "coco17")
    np.save(tmp_path / "cam1.npy", a)
    np.savez(tmp_path / "both.npz", front=b, extra=np.zeros(3))
    (tmp_path / "calib.toml").write_text(calib_toml(scene))
    code, out = run_cli(
        ["capture", "import", "--keypoints", str(tmp_path / "cam1.npy"), "--keypoints", f"cam2={tmp_path / 'both.npz'}:front",
         "--format", "coco17", "--calibration", str(tmp_path / "calib.toml"), "--fps", "30", "--out", str(tmp_path / "c")],
        capsys,
    )  # fmt: skip
    assert code == 0, out
    c1, c2 = load_capture(tmp_path / "c").cameras
    np.testing.assert_allclose(c1.detectors["keypoints"].keypoints, a, rtol=0, atol=0)
    np.testing.assert_allclose(c2.detectors["keypoints"].keypoints, b, rtol=0, atol=0)
    assert c1.detectors["keypoints"].format == "coco17"

    code, message = run_cli(["capture", "import", "--keypoints", str(tmp_path / "cam1.npy"), "--out", str(tmp_path / "d")], capsys)
    assert code == 2 and message == "camera cam1: frame rate unknown (it has no video); pass --fps F or --fps cam1=F"
    code, message = run_cli(
        ["capture", "import", "--keypoints", str(tmp_path / "cam1.npy"), "--keypoints", f"cam1={tmp_path / 'both.npz'}:front",
         "--fps", "30", "--out", str(tmp_path / "d")], capsys,
    )  # fmt: skip
    assert code == 2 and "camera 'cam1' has keypoints twice (the second from --keypoints)" in message

    kp, boxes, fmt = read_keypoint_array(tmp_path / "cam1.npy")  # 17 points: COCO-17
    assert fmt == "coco17"
    np.testing.assert_allclose(boxes[:, 2:4], a[..., :2].max(axis=1))
    np.testing.assert_allclose(boxes[:, 4], a[..., 2].mean(axis=1))


@pytest.mark.parametrize(
    "make, kwargs, words",
    [
        (lambda p: np.save(p / "k.npy", np.zeros((4, 17, 2))), {}, ["k.npy", "expected shape (T, K, 3)", "(4, 17, 2)"]),
        (lambda p: np.save(p / "k.npy", np.zeros((4, 25, 3))), {"fmt": "halpe26"}, ["25 points per person, but format halpe26 has 26"]),
        (lambda p: np.save(p / "k.npy", np.zeros((4, 25, 3))), {}, ["could be openpose25 or openpose25b"]),
        (lambda p: np.save(p / "k.npy", np.zeros((4, 18, 3))), {}, ["18 points per person match no known format", "COCO-18"]),
        (lambda p: np.savez(p / "k.npz", a=np.zeros((4, 17, 3)), b=np.zeros(2)), {}, ["holds 2 arrays (a, b)", "FILE.npz:KEY"]),
        (lambda p: np.savez(p / "k.npz", a=np.zeros((4, 17, 3))), {"key": "kp"}, ["no array 'kp' (it holds a)"]),
        (lambda p: (p / "k.npy").write_text("garbage"), {}, ["k.npy: not a readable .npy file"]),
        (lambda p: np.save(p / "k.npy", np.array([[["a", "b", "c"]]])), {}, ["expected numbers"]),
        (lambda p: (p / "k.csv").write_text("1,2,3"), {}, ["must be .npy or .npz"]),
    ],
)  # fmt: skip
def test_bad_keypoint_arrays(tmp_path, make, kwargs, words):
    make(tmp_path)
    path = next(tmp_path.iterdir())
    with pytest.raises(CaptureError) as err:
        read_keypoint_array(path, **kwargs)
    assert str(path) in str(err.value)
    for word in words:
        assert word in str(err.value)


# ---------------------------------------------------------------------------------------------
# --intrinsics-only


def test_intrinsics_only(tmp_path, scene, capsys):
    capture, _ = scene
    make_project(tmp_path / "p", scene)
    code, out = run_cli(
        ["capture", "import", "--pose2sim", str(tmp_path / "p"), "--fps", "30", "--intrinsics-only", "--static", "cam1",
         "--out", str(tmp_path / "c")], capsys,
    )  # fmt: skip
    assert code == 0, out
    assert "cam1: 16 frames at 30 fps, 1920x1080, calibrated intrinsics, static," in out
    assert "cam2: 16 frames at 30 fps, 1920x1080, calibrated intrinsics, moving," in out
    imported = load_capture(tmp_path / "c")
    assert imported.world_frame == "unspecified"
    for cam in imported.cameras:
        truth = next(c for c in capture.cameras if c.name == cam.name)
        assert cam.extrinsics is None
        np.testing.assert_allclose(cam.K, truth.K, rtol=1e-15)
        np.testing.assert_allclose(cam.distortion, truth.distortion, atol=1e-15)
    assert imported.metadata["imported"]["guessed_intrinsics"] == []

    code, message = run_cli(
        ["capture", "import", "--keypoints", f"cam1={tmp_path / 'k.npy'}", "--intrinsics-only", "--fps", "30", "--out", str(tmp_path / "d")], capsys
    )  # fmt: skip
    assert code == 2 and "--intrinsics-only needs a calibration" in message
