"""Video detection: the frame loop with fake estimators, the error without MediaPipe, the
``detect`` command on a synthetic two-person scene, and (where the [video] extra is installed)
MediaPipe on real photographs and, when its videos are at hand, on the real clip."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from people_scene import make_scene
from test_importers import run_cli

from mocapgraph.cli import detect as cli_detect
from mocapgraph.data_tools.io.capture import load_capture
from mocapgraph.data_tools.tracking import detect_video as dv
from mocapgraph.errors import MocapgraphError

HAVE_MEDIAPIPE = importlib.util.find_spec("mediapipe") is not None
SIZE = (80, 60)


def write_video(path: Path, frames: int, fps: float = 25.0, size=SIZE, camera: int = 0) -> Path:
    """Frame i is a flat colour: blue = 10 i + 20, green = 40 camera + 20 (BGR order on disk), red = 0."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, size)
    assert writer.isOpened()
    for i in range(frames):
        frame = np.zeros((size[1], size[0], 3), np.uint8)
        frame[..., 0] = 10 * i + 20
        frame[..., 1] = 40 * camera + 20
        writer.write(frame)
    writer.release()
    return path


def frame_index(rgb: np.ndarray) -> int:
    assert rgb.dtype == np.uint8 and rgb.ndim == 3
    assert rgb[..., 2].mean() > rgb[..., 0].mean()  # the estimator gets RGB, not BGR
    return round((rgb[..., 2].mean() - 20) / 10)


class FakePose:
    """A one-person detector: a 'person' on even frames, whose points encode the frame index; nobody on odd ones."""

    def __init__(self):
        self.calls = []

    def __call__(self, rgb):
        i = frame_index(rgb)
        self.calls.append(i)
        if i % 2:
            return None
        kp = np.zeros((33, 3))
        kp[:, 0] = 10 + np.arange(33) + i
        kp[:, 1] = 5 + np.arange(33)
        kp[:, 2] = 0.9
        kp[7, 2] = 0.0  # an invisible point: NaN after normalising
        kp[8, 2] = 0.2  # seen badly: kept
        return kp


def test_frame_loop_with_a_one_person_estimator(tmp_path, bars):
    made = bars(dv)
    video = write_video(tmp_path / "walk.avi", 6)
    fake = FakePose()
    found = dv.detect_video(video, estimator=fake)
    assert fake.calls == [0, 1, 2, 3, 4, 5]
    assert found.num_frames == 6 and found.fps == 25.0 and found.size == SIZE and found.frame_count == 6
    np.testing.assert_array_equal(found.counts, [1, 0, 1, 0, 1, 0])
    for i in (0, 2, 4):
        (kp,) = found.people[i]
        np.testing.assert_allclose(kp[0], [10 + i, 5, 0.9])
        assert np.isnan(kp[7]).all()
        np.testing.assert_allclose(kp[8], [18 + i, 13, 0.2])
    assert all(p.shape == (0, 33, 3) for p in found.people[1::2])
    (bar,) = made
    assert (bar.desc, bar.total, bar.updates) == ("walk.avi", 6, 6)


def test_frame_loop_with_several_people(tmp_path):
    """Frame i has i people (a list from the estimator), the k-th at x = 100 k."""

    def people(rgb):
        i = frame_index(rgb)
        return [np.column_stack([np.full(33, 100.0 * k), np.arange(33.0), np.full(33, 0.8)]) for k in range(i)]

    found = dv.detect_video(write_video(tmp_path / "crowd.avi", 4), estimator=people)
    np.testing.assert_array_equal(found.counts, [0, 1, 2, 3])
    np.testing.assert_allclose(found.people[3][:, 0, 0], [0.0, 100.0, 200.0])


def test_max_frames_and_quiet(tmp_path, capsys):
    video = write_video(tmp_path / "clip.avi", 5)
    assert dv.detect_video(video, estimator=FakePose(), max_frames=3).num_frames == 3
    assert capsys.readouterr().err == ""


def test_estimator_with_a_wrong_shape(tmp_path):
    video = write_video(tmp_path / "clip.avi", 2)
    with pytest.raises(MocapgraphError, match="clip.avi: frame 0: estimator returned shape \\(17, 3\\)"):
        dv.detect_video(video, estimator=lambda rgb: [np.zeros((33, 3)), np.zeros((17, 3))])


def test_unreadable_video(tmp_path):
    with pytest.raises(MocapgraphError, match="video not found"):
        dv.detect_video(tmp_path / "none.mp4", estimator=FakePose())
    (tmp_path / "bad.mp4").write_bytes(b"not a video at all")
    with pytest.raises(MocapgraphError, match="bad.mp4"):
        dv.detect_video(tmp_path / "bad.mp4", estimator=FakePose())


def test_without_mediapipe_the_error_says_how_to_install(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "mediapipe", None)  # import mediapipe now fails, installed or not
    video = write_video(tmp_path / "clip.avi", 2)
    with pytest.raises(MocapgraphError) as err:
        dv.detect_video(video)
    assert "install the video extra: pip install 'mocapgraph[video]'" in str(err.value)


# ---------------------------------------------------------------------------------------------
# The detect command on a synthetic scene: four cameras, two people


SCENE_SIZE = (320, 240)
SCENE_FRAMES = 24


@pytest.fixture(scope="module")
def scene():
    return make_scene(seed=4, frames=SCENE_FRAMES, size=SCENE_SIZE, noise_px=0.5)


class ScenePeople:
    """Stands in for :class:`~mocapgraph.data_tools.tracking.detect_video.MediaPipePeople`: reads the
    camera and frame from the video's colours and returns the scene's people seen there."""

    made: list = []

    def __init__(self, scene, max_people, model_complexity, min_confidence):
        self.scene, self.settings, self.closed = scene, (max_people, model_complexity, min_confidence), False
        self.made.append(self)

    def __call__(self, rgb):
        camera = f"cam{round((rgb[..., 1].mean() - 20) / 40) + 1}"
        people = self.scene.tracks[camera][:, frame_index(rgb)]
        return [kp for kp in people if np.isfinite(kp[:, 2]).any()][: self.settings[0]]

    def close(self):
        self.closed = True


@pytest.fixture
def scene_videos(tmp_path, scene, monkeypatch):
    ScenePeople.made = []
    monkeypatch.setattr(dv, "MediaPipePeople", lambda *args: ScenePeople(scene, *args))
    folder = tmp_path / "videos"
    folder.mkdir()
    for c in range(4):
        write_video(folder / f"cam{c + 1}.avi", SCENE_FRAMES, fps=20.0, size=SCENE_SIZE, camera=c)
    (folder / "notes.txt").write_text("not a video")
    return folder


def test_detect_command_follows_one_person_in_every_camera(tmp_path, capsys, scene, scene_videos, bars):
    made = bars(cli_detect)
    code, out = run_cli(["detect", str(scene_videos), "--out", str(tmp_path / "cap"), "--max-people", "4", "--person", "1", "--quiet"], capsys)
    assert code == 0, out
    assert len(ScenePeople.made) == 4 and all(f.closed and f.settings == (4, 1, 0.5) for f in ScenePeople.made)
    assert made[0].desc == "videos" and made[0].total == 4 and made[0].updates == 4
    capture = load_capture(tmp_path / "cap")
    assert [c.name for c in capture.cameras] == ["cam1", "cam2", "cam3", "cam4"]
    meta = capture.metadata["people"]
    assert meta["people_seen"] == 2 and meta["chosen"] == 1 and meta["rule"] == "index"
    assert capture.metadata["detector"]["max_people"] == 4
    chosen = {c: scene.truth[c][t[0]] for c, t in meta["people"][1]["tracks"].items()}
    (person,) = set(chosen.values())  # the same person in every camera
    for cam in capture.cameras:
        assert cam.frame_rate == 20.0 and cam.image_size == SCENE_SIZE and cam.video == f"cameras/{cam.name}/video.avi"
        truth = scene.tracks[cam.name][list(scene.truth[cam.name]).index(person)]
        det = cam.detectors["mediapipe"]
        np.testing.assert_allclose(det.keypoints, truth)
        assert det.format == "blazepose33"
    assert "2 people seen; tracks per camera: cam1 2, cam2 2, cam3 2, cam4 2" in out
    assert "fitting person 1: rank 1 as asked" in out and "<- chosen" in out
    assert "cam1: 24 frames at 20 fps, 320x240, guessed intrinsics, moving" in out


def test_detect_command_errors(tmp_path, capsys, scene_videos, monkeypatch):
    empty = tmp_path / "empty"
    empty.mkdir()
    code, message = run_cli(["detect", str(empty), "--out", str(tmp_path / "cap")], capsys)
    assert code == 2 and message.startswith(f"{empty}: no videos in this folder")

    (tmp_path / "bad.mp4").write_bytes(b"not a video at all")
    code, message = run_cli(["detect", str(scene_videos / "cam1.avi"), str(tmp_path / "bad.mp4"), "--out", str(tmp_path / "cap")], capsys)
    assert code == 2 and message.startswith(f"{tmp_path / 'bad.mp4'}: ")

    write_video(scene_videos / "cam5.avi", SCENE_FRAMES - 4, fps=20.0, size=SCENE_SIZE, camera=4)
    code, message = run_cli(["detect", str(scene_videos), "--out", str(tmp_path / "cap")], capsys)
    assert code == 2 and "the videos have different lengths (cam1.avi: 24 frames" in message and "cam5.avi: 20 frames" in message
    assert "--allow-unequal-length" in message
    (scene_videos / "cam5.avi").unlink()

    nobody = write_video(tmp_path / "nobody.avi", SCENE_FRAMES, fps=20.0, size=SCENE_SIZE)
    monkeypatch.setattr(dv, "MediaPipePeople", lambda *args: type("Nobody", (), {"__call__": lambda self, rgb: [], "close": lambda self: None})())
    code, message = run_cli(["detect", str(nobody), "--out", str(tmp_path / "cap")], capsys)
    assert code == 2 and message == f"{nobody}: no person was found in any of its 24 frames"

    code, message = run_cli(["detect", str(scene_videos), "--out", str(tmp_path / "cap"), "--person", "tallest"], capsys)
    assert code == 2 and "person must be largest or central or a rank" in message
    assert not (tmp_path / "cap").exists()


def test_detect_command_without_mediapipe(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "mediapipe", None)
    a = write_video(tmp_path / "a.avi", 2)
    code, message = run_cli(["detect", str(a), "--out", str(tmp_path / "cap")], capsys)
    assert code == 2 and "pip install 'mocapgraph[video]'" in message
    assert not (tmp_path / "cap").exists()


# ---------------------------------------------------------------------------------------------
# MediaPipe itself, where the [video] extra is installed (see `make test-video`)


def portrait() -> Path:
    """Grace Hopper's portrait, shipped inside matplotlib's wheel (no download)."""
    import matplotlib

    path = Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg"
    if not path.is_file():
        pytest.skip("matplotlib's sample photograph is not installed")
    return path


def still_video(path: Path, image: np.ndarray, frames: int = 3) -> Path:
    h, w = image.shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (w, h))
    for _ in range(frames):
        writer.write(image)
    writer.release()
    return path


@pytest.mark.skipif(not HAVE_MEDIAPIPE, reason="mediapipe (the [video] extra) is not installed")
def test_mediapipe_finds_the_person_in_a_photograph(tmp_path):
    image = cv2.imread(str(portrait()))
    h, w = image.shape[:2]  # 600 x 512
    found = dv.detect_video(still_video(tmp_path / "hopper.avi", image))
    assert found.size == (w, h) and found.fps == 10.0 and found.num_frames == 3
    np.testing.assert_array_equal(found.counts, [1, 1, 1])  # one person, found once (not again in her blanked-out mask)
    kp = found.people[-1][0]
    # where a person sees them: nose in the middle of the face, shoulders at the sides of the chest
    nose, left_shoulder, right_shoulder = kp[0], kp[11], kp[12]
    assert abs(nose[0] - 270) < 40 and abs(nose[1] - 225) < 40 and nose[2] > 0.9
    assert abs(left_shoulder[0] - 456) < 60 and abs(left_shoulder[1] - 428) < 60
    assert abs(right_shoulder[0] - 96) < 60 and abs(right_shoulder[1] - 423) < 60
    assert left_shoulder[0] > nose[0] > right_shoulder[0]  # the image is not mirrored


@pytest.mark.skipif(not HAVE_MEDIAPIPE, reason="mediapipe (the [video] extra) is not installed")
def test_mediapipe_finds_two_people_side_by_side(tmp_path):
    """The portrait twice, side by side (1024 x 600): two people per frame, noses 512 px apart,
    and no more with room for three."""
    image = cv2.imread(str(portrait()))
    found = dv.detect_video(still_video(tmp_path / "twice.avi", np.concatenate([image, image], axis=1), frames=4), max_people=3)
    np.testing.assert_array_equal(found.counts[1:], [2, 2, 2])  # the second is found once the first is followed
    noses = np.sort(found.people[-1][:, 0, 0])
    assert abs(noses[0] - 270) < 40 and abs(noses[1] - 782) < 40


@pytest.mark.skipif(not HAVE_MEDIAPIPE, reason="mediapipe (the [video] extra) is not installed")
def test_the_real_clip_is_what_detection_gives(tmp_path):
    """tests/data/real/tracks.npz is what detect_video and track_people give on the clip's videos
    (first 12 frames of cam01), where the videos are at hand: set POSE2SIM_DEMO_MULTIPERSON to
    the wheel's Demo_MultiPerson folder."""
    import os

    from real_clip import load_clip

    from mocapgraph.data_tools.tracking.people import track_people

    folder = os.environ.get("POSE2SIM_DEMO_MULTIPERSON")
    if not folder:
        pytest.skip("POSE2SIM_DEMO_MULTIPERSON is not set (the folder of the pose2sim wheel's Demo_MultiPerson)")
    found = dv.detect_video(Path(folder) / "videos" / "cam01.mp4", max_frames=12)
    tracks = track_people(found.people).keypoints
    stored = load_clip().tracks["cam01"].keypoints[:, :12]
    assert tracks.shape == stored.shape
    seen = np.isfinite(stored)
    np.testing.assert_array_equal(np.isfinite(tracks), seen)
    np.testing.assert_allclose(tracks[seen], stored[seen], atol=0.02)  # stored rounded to 1/64 px


@pytest.mark.skipif(not HAVE_MEDIAPIPE, reason="mediapipe (the [video] extra) is not installed")
def test_mediapipe_models_that_would_download_are_refused():
    from mediapipe.python.solutions import pose

    lite = Path(pose.__file__).resolve().parents[2] / "modules" / "pose_landmark" / "pose_landmark_lite.tflite"
    if lite.is_file():
        pytest.skip("the lite model has been placed in the mediapipe package")
    with pytest.raises(MocapgraphError, match="mocapgraph never downloads"):
        dv.MediaPipePose(model_complexity=0)
    assert not lite.exists()
