"""Every person track of every camera of one recording, in one ``.npz`` file.

What :func:`~mocapgraph.data_tools.tracking.people.track_people` follows in each camera's video,
kept so that the choice of the person to fit (and the capture of them) can be made again without
the videos or the detector (``tests/data/real/tracks.npz`` is one).

The file holds ``cameras (C,)`` names; ``sizes (C, 2)`` width, height in pixels; ``fps (C,)``;
optionally ``keypoint_format`` (a registered format name; without it, MediaPipe's
``blazepose33``, which ``mocapgraph detect`` gives); and per camera ``tracks_<camera> (P, T, K, 3)`` float32: keypoints x, y in pixels and confidence
in [0, 1], NaN where a track has no detection, the tracks in the order they start (which track
is which person differs per camera).
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.data_tools.io.calibration import CameraCalibration
from mocapgraph.data_tools.io.files import Where, check_array
from mocapgraph.data_tools.tracking.people import PersonChoice, PersonTracks, write_person_capture
from mocapgraph.errors import MocapgraphError

DEFAULT_FORMAT = "blazepose33"
"""The format of a file that does not name one: MediaPipe's, which ``mocapgraph detect`` gives."""


@dataclass
class TrackSet:
    """The people followed in each camera of one recording.

    Attributes:
        cameras: names, in order.
        tracks: camera → its :class:`~mocapgraph.data_tools.tracking.people.PersonTracks`.
        sizes: camera → ``(width, height)`` pixels.
        fps: camera → frames per second.
        keypoint_format: the keypoints' format (canonical name of the registry).
    """

    cameras: list[str]
    tracks: dict[str, PersonTracks]
    sizes: dict[str, tuple[int, int]]
    fps: dict[str, float]
    keypoint_format: str = DEFAULT_FORMAT

    def write_capture(
        self, out: str | Path, *, calibration: Sequence[CameraCalibration] | None = None, person: str | int = "largest", moving: bool = False
    ) -> tuple[Path, PersonChoice]:
        """A capture of one person (:func:`~mocapgraph.data_tools.tracking.people.write_person_capture`):
        the cameras static unless ``moving``, with the ``calibration``'s intrinsics and poses
        where given (pass :func:`~mocapgraph.data_tools.io.calibration.intrinsics_only` to
        withhold the poses), guessed intrinsics elsewhere."""
        return write_person_capture(
            self.tracks, self.sizes, self.fps, out, calibration=calibration, person=person, moving={c: moving for c in self.cameras},
            keypoint_format=self.keypoint_format,
        )


def compact(keypoints) -> np.ndarray:
    """float32 with pixels rounded to 1/64 and confidences to 1/1024 (binary fractions, which
    compress): far below a detector's error of several pixels."""
    out = np.array(keypoints, dtype=np.float32)
    out[..., :2] = np.round(out[..., :2] * 64) / 64
    out[..., 2] = np.round(out[..., 2] * 1024) / 1024
    return out


def save_track_set(track_set: TrackSet, path: str | Path) -> Path:
    """Write ``track_set`` to ``path`` (compacted: :func:`compact`), atomically."""
    path = Path(path)
    arrays = {f"tracks_{c}": compact(track_set.tracks[c].keypoints) for c in track_set.cameras}
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".npz")
    os.close(fd)
    try:
        np.savez_compressed(
            tmp, cameras=np.array(track_set.cameras), sizes=np.array([track_set.sizes[c] for c in track_set.cameras]),
            fps=np.array([track_set.fps[c] for c in track_set.cameras]), keypoint_format=np.array(track_set.keypoint_format), **arrays,
        )  # fmt: skip
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def load_track_set(path: str | Path) -> TrackSet:
    """Read a file written by :func:`save_track_set`; one clear error naming the file and the field."""
    path = Path(path)
    if not path.is_file():
        raise MocapgraphError(f"{path}: person tracks file not found")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except (OSError, ValueError) as exc:
        raise MocapgraphError(f"{path}: not a readable .npz file ({exc})") from None
    where = Where(str(path))
    for key in ("cameras", "sizes", "fps"):
        if key not in arrays:
            raise where(key).fail(f"missing (the file has {', '.join(sorted(arrays)) or 'nothing'})")
    cameras = [str(c) for c in np.atleast_1d(arrays["cameras"])]
    if not cameras or len(set(cameras)) != len(cameras):
        raise where("cameras").fail(f"expected distinct camera names, got {cameras}")
    sizes = check_array(arrays["sizes"], where("sizes"), (len(cameras), 2))
    fps = check_array(arrays["fps"], where("fps"), (len(cameras),))
    if np.any(sizes < 1) or np.any(fps <= 0):
        raise where("sizes" if np.any(sizes < 1) else "fps").fail("must be positive")
    try:
        fmt = get_format(str(arrays.get("keypoint_format", DEFAULT_FORMAT)))
    except MocapgraphError as exc:
        raise where("keypoint_format").fail(str(exc)) from None
    tracks = {}
    for c in cameras:
        key = f"tracks_{c}"
        if key not in arrays:
            raise where(key).fail("missing")
        tracks[c] = PersonTracks(check_array(arrays[key], where(key), (None, None, fmt.num_points, 3), allow_nan=True))
    return TrackSet(
        cameras, tracks, {c: (int(w), int(h)) for c, (w, h) in zip(cameras, sizes)}, {c: float(r) for c, r in zip(cameras, fps)}, fmt.name
    )
