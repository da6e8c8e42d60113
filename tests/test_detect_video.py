"""Video detection: the frame loop with a fake estimator, the error without MediaPipe, the
``detect`` command, and (where the [video] extra is installed) MediaPipe on a real photograph."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from test_importers import run_cli

from mocapgraph.data_tools.io.capture import load_capture
from mocapgraph.data_tools.tracking import detect_video as dv
from mocapgraph.errors import MocapgraphError

HAVE_MEDIAPIPE = importlib.util.find_spec("mediapipe") is not None
SIZE = (80, 60)


def write_video(path: Path, frames: int, fps: float = 25.0) -> Path:
    """Frame i is a flat colour: blue = 10 i + 20 (BGR order on disk), red = 0."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, SIZE)
    assert writer.isOpened()
    for i in range(frames):
        frame = np.zeros((SIZE[1], SIZE[0], 3), np.uint8)
        frame[..., 0] = 10 * i + 20
        writer.write(frame)
    writer.release()
    return path


class FakePose:
    """Finds a 'person' on even frames, whose points encode the frame index; nobody on odd ones."""

    def __init__(self):
        self.calls = []
        self.closed = False

    def __call__(self, rgb):
        assert rgb.dtype == np.uint8 and rgb.shape == (SIZE[1], SIZE[0], 3)
        assert rgb[..., 2].mean() > rgb[..., 0].mean()  # the estimator gets RGB, not BGR
        i = round((rgb[..., 2].mean() - 20) / 10)
        self.calls.append(i)
        if i % 2:
            return None
        kp = np.zeros((33, 3))
        kp[:, 0] = 10 + np.arange(33) + i
        kp[:, 1] = 5 + np.arange(33)
        kp[:, 2] = 0.9
        kp[7, 2] = 0.0  # an invisible point: NaN after normalising
        kp[8, 2] = 0.2  # seen badly: kept, but not in the box
        kp[8, :2] = [500.0, 500.0]
        return kp

    def close(self):
        self.closed = True

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def test_frame_loop_with_a_fake_estimator(tmp_path, bars):
    made = bars(dv)
    video = write_video(tmp_path / "walk.avi", 6)
    fake = FakePose()
    kp, boxes, fps, size = dv.detect_video(video, estimator=fake)
    assert fake.calls == [0, 1, 2, 3, 4, 5]
    assert kp.shape == (6, 33, 3) and boxes.shape == (6, 5)
    assert fps == 25.0 and size == SIZE
    assert np.isnan(kp[1::2]).all() and np.isnan(boxes[1::2]).all()
    for i in (0, 2, 4):
        np.testing.assert_allclose(kp[i, 0], [10 + i, 5, 0.9])
        assert np.isnan(kp[i, 7]).all()
        np.testing.assert_allclose(kp[i, 8], [500, 500, 0.2])
        # the box spans the points seen with visibility >= 0.5 (not 7, not 8), clipped to the image
        np.testing.assert_allclose(boxes[i], [10 + i, 5, min(42 + i, SIZE[0] - 1), 37, 0.9])
    (bar,) = made
    assert (bar.desc, bar.total, bar.updates) == ("walk.avi", 6, 6)


def test_max_frames_and_quiet(tmp_path, capsys):
    video = write_video(tmp_path / "clip.avi", 5)
    kp, boxes, _, _ = dv.detect_video(video, estimator=FakePose(), max_frames=3)
    assert kp.shape == (3, 33, 3)
    assert capsys.readouterr().err == ""


def test_estimator_with_a_wrong_shape(tmp_path):
    video = write_video(tmp_path / "clip.avi", 2)
    with pytest.raises(MocapgraphError, match="estimator returned shape \\(17, 3\\)"):
        dv.detect_video(video, estimator=lambda rgb: np.zeros((17, 3)))


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


def test_detect_command_writes_a_capture(tmp_path, capsys, monkeypatch):
    made = []

    def factory(complexity, confidence):
        made.append(FakePose())
        made[-1].settings = (complexity, confidence)
        return made[-1]

    monkeypatch.setattr(dv, "MediaPipePose", factory)
    a = write_video(tmp_path / "a.avi", 4, fps=25.0)
    b = write_video(tmp_path / "b.avi", 3, fps=30.0)
    code, out = run_cli(
        ["detect", str(a), f"side={b}", "--out", str(tmp_path / "cap"), "--min-confidence", "0.6", "--quiet"], capsys
    )
    assert code == 0, out
    assert len(made) == 2 and all(f.closed for f in made)  # a fresh tracker per video
    assert made[0].settings == (1, 0.6)
    capture = load_capture(tmp_path / "cap")
    assert [c.name for c in capture.cameras] == ["a", "side"]
    cam_a, side = capture.cameras
    assert cam_a.frame_rate == 25.0 and side.frame_rate == 30.0
    np.testing.assert_allclose(side.timestamps, np.arange(3) / 30.0)
    det = cam_a.detectors["mediapipe"]
    assert det.format == "blazepose33" and det.keypoints.shape == (4, 33, 3)
    assert np.isnan(det.keypoints[1]).all() and np.isfinite(det.keypoints[0, 0]).all()
    assert cam_a.moving and side.video == "cameras/side/video.avi"
    assert capture.metadata["detector"]["model_complexity"] == 1
    assert "a: 4 frames at 25 fps, 80x60, guessed intrinsics, moving, mediapipe (blazepose33) person in 50% of frames" in out

    code, out = run_cli(["detect", str(a), "--out", str(tmp_path / "cap"), "--fps", "50", "--overwrite", "--quiet"], capsys)
    assert code == 0 and load_capture(tmp_path / "cap").cameras[0].frame_rate == 50.0


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


@pytest.mark.skipif(not HAVE_MEDIAPIPE, reason="mediapipe (the [video] extra) is not installed")
def test_mediapipe_finds_the_person_in_a_photograph(tmp_path):
    image = cv2.imread(str(portrait()))
    h, w = image.shape[:2]  # 600 x 512
    video = tmp_path / "hopper.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (w, h))
    for _ in range(3):
        writer.write(image)
    writer.release()
    kp, boxes, fps, size = dv.detect_video(video)
    assert size == (w, h) and fps == 10.0 and kp.shape == (3, 33, 3)
    assert np.isfinite(kp[:, 0]).all()  # the nose is found in every frame
    # where a person sees them: nose in the middle of the face, shoulders at the sides of the chest
    nose, left_shoulder, right_shoulder = kp[-1, 0], kp[-1, 11], kp[-1, 12]
    assert abs(nose[0] - 270) < 40 and abs(nose[1] - 225) < 40 and nose[2] > 0.9
    assert abs(left_shoulder[0] - 456) < 60 and abs(left_shoulder[1] - 428) < 60
    assert abs(right_shoulder[0] - 96) < 60 and abs(right_shoulder[1] - 423) < 60
    assert left_shoulder[0] > nose[0] > right_shoulder[0]  # the image is not mirrored
    assert np.isfinite(boxes).all() and boxes[-1, 0] < nose[0] < boxes[-1, 2]


@pytest.mark.skipif(not HAVE_MEDIAPIPE, reason="mediapipe (the [video] extra) is not installed")
def test_mediapipe_models_that_would_download_are_refused():
    from mediapipe.python.solutions import pose

    lite = Path(pose.__file__).resolve().parents[2] / "modules" / "pose_landmark" / "pose_landmark_lite.tflite"
    if lite.is_file():
        pytest.skip("the lite model has been placed in the mediapipe package")
    with pytest.raises(MocapgraphError, match="mocapgraph never downloads"):
        dv.MediaPipePose(model_complexity=0)
    assert not lite.exists()
