"""2D body keypoints of every person in a video with MediaPipe Pose (BlazePose, 33 landmarks).

MediaPipe is the optional ``[video]`` extra (``mediapipe==0.10.14``). Its wheel ships the pose
detector and the *full* landmark model (``model_complexity=1``) and nothing else; the legacy
``mediapipe.solutions.pose`` API would download the lite (0) and heavy (2) models from the
internet on first use. :func:`detect_video` never lets it: other complexities are refused unless
their model file is already inside the installed package.

MediaPipe Pose follows one person. :class:`MediaPipePeople` follows up to ``max_people``: one
MediaPipe tracker per person, each shown the frame with the other people blanked out (their
segmentation masks from the previous frame, grown to cover a frame's motion), and one more run on
the frame with everybody found blanked, to find a person not followed yet.

Frames are decoded with ``cv2.VideoCapture``. The pose estimator is a plain callable, so the frame
loop can be tested (and another detector plugged in) without MediaPipe.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.data_tools.tracking.people import pose_distance
from mocapgraph.errors import MocapgraphError
from mocapgraph.progress import progress_bar

INSTALL_HINT = "install the video extra: pip install 'mocapgraph[video]'"
FORMAT = "blazepose33"
DETECTOR_NAME = "mediapipe"
NUM_LANDMARKS = 33
DEFAULT_MAX_PEOPLE = 3
_LANDMARK_FILES = {0: "pose_landmark_lite.tflite", 1: "pose_landmark_full.tflite", 2: "pose_landmark_heavy.tflite"}
_MASK_THRESHOLD = 0.5
# A person's mask from the last frame, grown by this fraction of the image's longer side, still
# covers them after a frame's motion (60 fps: a few pixels; a fast arm at 25 fps: a few percent).
_MASK_GROWTH = 0.02
_BLANK = 127
# Two detections closer than this (in person heights) are one person found twice.
_DUPLICATE_DISTANCE = 0.1

Estimator = Callable[[np.ndarray], "Sequence[np.ndarray] | np.ndarray | None"]
"""``estimator(rgb)``: an ``(H, W, 3)`` uint8 RGB frame → the people found, each ``(33, 3)``
landmarks ``x, y`` in pixels and visibility in [0, 1]: a sequence (empty when nobody is found),
or, from a one-person detector, one ``(33, 3)`` array or None."""


def _import_mediapipe():
    try:
        from mediapipe.python.solutions import pose
    except ImportError:
        raise MocapgraphError(f"MediaPipe is not installed; {INSTALL_HINT}") from None
    return pose


class MediaPipePose:
    """The legacy ``mediapipe.solutions.pose.Pose`` as a one-person :data:`Estimator` (video mode:
    tracks the person from frame to frame). Use as a context manager, or call :meth:`close`."""

    def __init__(
        self, model_complexity: int = 1, min_confidence: float = 0.5, static_image_mode: bool = False, segmentation: bool = False
    ):
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
                enable_segmentation=segmentation,
                min_detection_confidence=min_confidence,
                min_tracking_confidence=min_confidence,
            )

    def process(self, rgb: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None]:
        """``(33, 3)`` landmarks (None: nobody found) and, with ``segmentation``, the person's
        ``(H, W)`` bool mask (else None)."""
        with warnings.catch_warnings():
            # protobuf 4 warns that MediaPipe's use of SymbolDatabase.GetPrototype is deprecated
            warnings.simplefilter("ignore", UserWarning)
            result = self._pose.process(rgb)
        if result.pose_landmarks is None:
            return None, None
        h, w = rgb.shape[:2]
        kp = np.array([[p.x * w, p.y * h, p.visibility] for p in result.pose_landmarks.landmark], dtype=float)
        mask = None if result.segmentation_mask is None else result.segmentation_mask > _MASK_THRESHOLD
        return kp, mask

    def __call__(self, rgb: np.ndarray) -> np.ndarray | None:
        return self.process(rgb)[0]

    def reset(self) -> None:
        """Forget the person followed (the next frame starts with the person detector)."""
        self._pose.reset()

    def close(self) -> None:
        self._pose.close()

    def __enter__(self) -> MediaPipePose:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass
class _Follower:
    pose: MediaPipePose
    mask: np.ndarray  # where the person was in the last frame, grown by _MASK_GROWTH


class MediaPipePeople:
    """Up to ``max_people`` people per frame with MediaPipe Pose, as an :data:`Estimator`.

    One MediaPipe tracker (video mode) per person followed; each sees the frame with the other
    followed people blanked out, so it keeps to its own person. While fewer than ``max_people``
    are followed, a fresh tracker looks at the frame with everybody found blanked out and follows
    whoever it finds. A tracker that loses its person, or finds one another tracker already has,
    is dropped. Which list entry is which person is not kept from frame to frame: that is
    :func:`~mocapgraph.data_tools.tracking.people.track_people`'s job.
    """

    def __init__(self, max_people: int = DEFAULT_MAX_PEOPLE, model_complexity: int = 1, min_confidence: float = 0.5):
        if not (isinstance(max_people, int) and max_people >= 1):
            raise MocapgraphError(f"max_people must be a positive integer, got {max_people!r}")
        self.max_people = max_people
        self._settings = (model_complexity, min_confidence)
        self._followers: list[_Follower] = []
        self._spare: MediaPipePose | None = MediaPipePose(model_complexity, min_confidence, segmentation=True)

    def __call__(self, rgb: np.ndarray) -> list[np.ndarray]:
        import cv2

        side = max(1, round(_MASK_GROWTH * max(rgb.shape[:2]))) * 2 + 1
        # a square grows a mask as well as a disc here, and OpenCV dilates by it in two cheap passes
        grow = cv2.getStructuringElement(cv2.MORPH_RECT, (side, side))

        def grown(mask: np.ndarray) -> np.ndarray:
            return cv2.dilate(mask.astype(np.uint8), grow).astype(bool)

        def without(masks: list[np.ndarray]) -> np.ndarray:
            if not masks:
                return rgb
            out = rgb.copy()
            out[np.logical_or.reduce(masks)] = _BLANK
            return out

        found: list[np.ndarray] = []
        for follower in list(self._followers):
            kp, mask = follower.pose.process(without([f.mask for f in self._followers if f is not follower]))
            if kp is None or any(pose_distance(kp, other) < _DUPLICATE_DISTANCE for other in found):
                follower.pose.close()
                self._followers.remove(follower)
                continue
            follower.mask = grown(mask)
            found.append(kp)
        if len(self._followers) < self.max_people:
            spare = self._spare or MediaPipePose(*self._settings, segmentation=True)
            kp, mask = spare.process(without([f.mask for f in self._followers]))
            if kp is not None and not any(pose_distance(kp, other) < _DUPLICATE_DISTANCE for other in found):
                self._followers.append(_Follower(spare, grown(mask)))
                self._spare = None
                found.append(kp)
            else:
                spare.reset()
                self._spare = spare
        return found

    def close(self) -> None:
        for follower in self._followers:
            follower.pose.close()
        self._followers = []
        if self._spare is not None:
            self._spare.close()
            self._spare = None

    def __enter__(self) -> MediaPipePeople:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass
class VideoDetections:
    """Every person found in every frame of one video.

    Attributes:
        path: the video.
        people: per frame, ``(N_t, 33, 3)`` BlazePose keypoints of the ``N_t`` people found (in no
            particular order): x, y pixels and visibility in [0, 1], NaN for a point whose
            visibility is 0.
        fps: the video's frames per second (0.0 when the container does not say).
        size: ``(width, height)`` of its frames, pixels.
        frame_count: frames the container announces (0 when it does not say; ``len(people)``
            is what was decoded).
    """

    path: Path
    people: list[np.ndarray]
    fps: float
    size: tuple[int, int]
    frame_count: int

    @property
    def num_frames(self) -> int:
        return len(self.people)

    @property
    def counts(self) -> np.ndarray:
        """``(T,)`` people found per frame."""
        return np.array([len(p) for p in self.people], dtype=int)


def _people(found, path: Path, frame: int) -> np.ndarray:
    """An estimator's answer as ``(N, 33, 3)``."""
    if found is None:
        return np.zeros((0, NUM_LANDMARKS, 3))
    if isinstance(found, np.ndarray) and found.ndim == 2:
        found = [found]
    people = [np.asarray(kp, dtype=float) for kp in found]
    for kp in people:
        if kp.shape != (NUM_LANDMARKS, 3):
            raise MocapgraphError(f"{path}: frame {frame}: estimator returned shape {kp.shape}, expected ({NUM_LANDMARKS}, 3)")
    return np.stack(people) if people else np.zeros((0, NUM_LANDMARKS, 3))


def detect_video(
    video_path: str | Path,
    max_people: int = DEFAULT_MAX_PEOPLE,
    model_complexity: int = 1,
    min_confidence: float = 0.5,
    *,
    estimator: Estimator | None = None,
    max_frames: int | None = None,
) -> VideoDetections:
    """Detect the BlazePose-33 keypoints of every person (up to ``max_people``) in every frame of a video.

    Args:
        video_path: any file ``cv2.VideoCapture`` decodes.
        max_people: most people followed at once (:class:`MediaPipePeople`).
        model_complexity: MediaPipe landmark model; only 1 (full) ships with mediapipe 0.10.14.
        min_confidence: MediaPipe's detection and tracking thresholds.
        estimator: use this instead of MediaPipe (see :data:`Estimator`); for tests and other detectors.
        max_frames: stop after this many frames.

    Returns:
        the people found per frame, the video's frame rate and image size.
    """
    import cv2

    path = Path(video_path)
    if not path.is_file():
        raise MocapgraphError(f"{path}: video not found")
    owned = None
    if estimator is None:
        owned = estimator = MediaPipePeople(max_people, model_complexity, min_confidence)
    fmt = get_format(FORMAT)
    cap = cv2.VideoCapture(str(path))
    bar = progress_bar(desc=path.name, unit="frame")
    try:
        if not cap.isOpened():
            raise MocapgraphError(f"{path}: OpenCV cannot open this video")
        fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        fps = fps if np.isfinite(fps) and fps > 0 else 0.0
        count = max(int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0), 0)
        total = count if max_frames is None else (min(count, max_frames) if count > 0 else max_frames)
        bar.reset(total=total or None)
        people, size = [], None
        while max_frames is None or len(people) < max_frames:
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
                    f"{path}: frame {len(people)} is {frame_size[0]}x{frame_size[1]}, the first was {size[0]}x{size[1]}"
                )
            found = _people(estimator(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)), path, len(people))
            people.append(fmt.normalise(found, source=f"{path}: frame {len(people)}"))
            bar.update()
        if not people:
            raise MocapgraphError(f"{path}: no frame could be decoded")
    finally:
        bar.close()
        cap.release()
        if owned is not None:
            owned.close()
    return VideoDetections(path, people, fps, size, count)
