"""2D body keypoints from a video with MediaPipe Pose (BlazePose, 33 landmarks).

MediaPipe is the optional ``[video]`` extra (``mediapipe==0.10.14``). Its wheel ships the pose
detector and the *full* landmark model (``model_complexity=1``) and nothing else; the legacy
``mediapipe.solutions.pose`` API would download the lite (0) and heavy (2) models from the
internet on first use. :func:`detect_video` never lets it: other complexities are refused unless
their model file is already inside the installed package.

Frames are decoded with ``cv2.VideoCapture``. The pose estimator is a plain callable, so the frame
loop can be tested (and another detector plugged in) without MediaPipe.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.errors import MocapgraphError
from mocapgraph.progress import progress_bar

INSTALL_HINT = "install the video extra: pip install 'mocapgraph[video]'"
FORMAT = "blazepose33"
DETECTOR_NAME = "mediapipe"
NUM_LANDMARKS = 33
_LANDMARK_FILES = {0: "pose_landmark_lite.tflite", 1: "pose_landmark_full.tflite", 2: "pose_landmark_heavy.tflite"}

Estimator = Callable[[np.ndarray], "np.ndarray | None"]
"""``estimator(rgb)``: an ``(H, W, 3)`` uint8 RGB frame → ``(33, 3)`` landmarks ``x, y`` in pixels
and visibility in [0, 1], or None when no person is found."""


def _import_mediapipe():
    try:
        from mediapipe.python.solutions import pose
    except ImportError:
        raise MocapgraphError(f"MediaPipe is not installed; {INSTALL_HINT}") from None
    return pose


class MediaPipePose:
    """The legacy ``mediapipe.solutions.pose.Pose`` as an :data:`Estimator` (video mode: tracks
    the person from frame to frame). Use as a context manager, or call :meth:`close`."""

    def __init__(self, model_complexity: int = 1, min_confidence: float = 0.5, static_image_mode: bool = False):
        pose = _import_mediapipe()
        if model_complexity not in _LANDMARK_FILES:
            raise MocapgraphError(f"model_complexity must be 0, 1 or 2, got {model_complexity!r}")
        if not 0.0 <= min_confidence <= 1.0:
            raise MocapgraphError(f"min_confidence must lie in [0, 1], got {min_confidence!r}")
        model = Path(pose.__file__).resolve().parents[2] / "modules" / "pose_landmark" / _LANDMARK_FILES[model_complexity]
        if not model.is_file():
            raise MocapgraphError(
                f"model_complexity={model_complexity} needs {model.name}, which the installed mediapipe does not "
                f"ship (MediaPipe would download it; mocapgraph never downloads at run time). Use model_complexity=1 "
                f"(the full model, bundled), or place the file at {model} yourself"
            )
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            self._pose = pose.Pose(
                static_image_mode=static_image_mode,
                model_complexity=model_complexity,
                smooth_landmarks=True,
                enable_segmentation=False,
                min_detection_confidence=min_confidence,
                min_tracking_confidence=min_confidence,
            )

    def __call__(self, rgb: np.ndarray) -> np.ndarray | None:
        with warnings.catch_warnings():
            # protobuf 4 warns that MediaPipe's use of SymbolDatabase.GetPrototype is deprecated
            warnings.simplefilter("ignore", UserWarning)
            result = self._pose.process(rgb)
        if result.pose_landmarks is None:
            return None
        h, w = rgb.shape[:2]
        return np.array([[p.x * w, p.y * h, p.visibility] for p in result.pose_landmarks.landmark], dtype=float)

    def close(self) -> None:
        self._pose.close()

    def __enter__(self) -> MediaPipePose:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _box(kp: np.ndarray, size: tuple[int, int], min_visibility: float = 0.5) -> np.ndarray:
    """Box of the landmarks seen with ``visibility ≥ min_visibility`` (all of them if fewer than
    two are), clipped to the image, scored by their mean visibility."""
    ok = np.isfinite(kp).all(axis=1)
    seen = ok & (kp[:, 2] >= min_visibility)
    use = seen if seen.sum() >= 2 else ok
    if not use.any():
        return np.full(5, np.nan)
    xy = kp[use, :2]
    w, h = size
    x0, x1 = np.clip([xy[:, 0].min(), xy[:, 0].max()], 0, w - 1)
    y0, y1 = np.clip([xy[:, 1].min(), xy[:, 1].max()], 0, h - 1)
    return np.array([x0, y0, x1, y1, kp[use, 2].mean()])


def detect_video(
    video_path: str | Path,
    model_complexity: int = 1,
    min_confidence: float = 0.5,
    *,
    estimator: Estimator | None = None,
    max_frames: int | None = None,
) -> tuple[np.ndarray, np.ndarray, float, tuple[int, int]]:
    """Detect one person's BlazePose-33 keypoints in every frame of a video.

    Args:
        video_path: any file ``cv2.VideoCapture`` decodes.
        model_complexity: MediaPipe landmark model; only 1 (full) ships with mediapipe 0.10.14.
        min_confidence: MediaPipe's detection and tracking thresholds.
        estimator: use this instead of MediaPipe (see :data:`Estimator`); for tests and other detectors.
        max_frames: stop after this many frames.

    Returns:
        keypoints ``(T, 33, 3)``: x, y pixels and visibility in [0, 1], NaN where not detected (a
        whole NaN row for a frame without a person, a NaN point where visibility is 0);
        boxes ``(T, 5)``: x0, y0, x1, y1 and score (NaN without a person); the video's frames per
        second (0.0 when the container does not say); image size ``(width, height)``.
    """
    import cv2

    path = Path(video_path)
    if not path.is_file():
        raise MocapgraphError(f"{path}: video not found")
    owned = None
    if estimator is None:
        owned = estimator = MediaPipePose(model_complexity, min_confidence)
    cap = cv2.VideoCapture(str(path))
    bar = progress_bar(desc=path.name, unit="frame")
    try:
        if not cap.isOpened():
            raise MocapgraphError(f"{path}: OpenCV cannot open this video")
        fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        fps = fps if np.isfinite(fps) and fps > 0 else 0.0
        total = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        if max_frames is not None:
            total = min(total, max_frames) if total > 0 else max_frames
        bar.reset(total=total or None)
        rows, boxes, size = [], [], None
        while max_frames is None or len(rows) < max_frames:
            ok, bgr = cap.read()
            if not ok or bgr is None:
                break
            if bgr.ndim == 2:
                bgr = cv2.cvtColor(bgr, cv2.COLOR_GRAY2BGR)
            frame_size = (int(bgr.shape[1]), int(bgr.shape[0]))
            if size is None:
                size = frame_size
            elif frame_size != size:
                raise MocapgraphError(
                    f"{path}: frame {len(rows)} is {frame_size[0]}x{frame_size[1]}, the first was {size[0]}x{size[1]}"
                )
            found = estimator(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
            if found is None:
                rows.append(np.full((NUM_LANDMARKS, 3), np.nan))
                boxes.append(np.full(5, np.nan))
            else:
                kp = np.asarray(found, dtype=float)
                if kp.shape != (NUM_LANDMARKS, 3):
                    raise MocapgraphError(f"estimator returned shape {kp.shape}, expected ({NUM_LANDMARKS}, 3)")
                rows.append(kp)
                boxes.append(_box(kp, size))
            bar.update()
        if not rows:
            raise MocapgraphError(f"{path}: no frame could be decoded")
    finally:
        bar.close()
        cap.release()
        if owned is not None:
            owned.close()
    keypoints = get_format(FORMAT).normalise(np.stack(rows), source=str(path))
    return keypoints, np.stack(boxes), fps, size
