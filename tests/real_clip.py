"""The real multi-camera clip in ``tests/data/real/``: loading it, making captures from it, and remaking it.

Pose2Sim's ``Demo_MultiPerson`` (4 static cameras around a treadmill, 60 fps, 100 frames, two
people; BSD-3-Clause, David Pagnon: see ``tests/data/real/README.md``): every person track that
``mocapgraph detect``'s detector and tracker follow in each camera, and the lab's Qualisys
calibration. Remake the tracks from the videos (in the video environment, with MediaPipe)::

    .venv-video/bin/python tests/real_clip.py PATH/TO/Demo_MultiPerson/videos
"""

from __future__ import annotations

import argparse
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocapgraph.data_tools.io.calibration import CameraCalibration, intrinsics_only, read_calibration
from mocapgraph.data_tools.tracking.people import PersonChoice, PersonTracks, track_people, write_person_capture

CLIP = Path(__file__).resolve().parent / "data" / "real"
TRACKS = CLIP / "tracks.npz"
CALIBRATION = CLIP / "Calib.qca.txt"


@dataclass
class RealClip:
    """Attributes: cameras in order; per camera its tracks, ``(width, height)`` and frame rate."""

    cameras: list[str]
    tracks: dict[str, PersonTracks]
    sizes: dict[str, tuple[int, int]]
    fps: dict[str, float]


def load_clip() -> RealClip:
    with np.load(TRACKS) as data:
        cameras = [str(c) for c in data["cameras"]]
        return RealClip(
            cameras,
            {c: PersonTracks(data[f"tracks_{c}"].astype(float)) for c in cameras},
            {c: tuple(int(v) for v in size) for c, size in zip(cameras, data["sizes"])},
            {c: float(r) for c, r in zip(cameras, data["fps"])},
        )


def calibration() -> list[CameraCalibration]:
    """The lab's Qualisys calibration (intrinsics, distortion and poses) of the four cameras."""
    return read_calibration(CALIBRATION)


def clip_capture(out: Path, person: str | int = "largest", intrinsics: str = "guessed") -> tuple[Path, PersonChoice]:
    """A capture of one person of the clip, as ``mocapgraph detect`` would write it, the cameras'
    poses withheld: ``intrinsics="calibrated"`` keeps the lab's intrinsics and distortion,
    ``"guessed"`` leaves the capture to guess them (as without a calibration)."""
    if intrinsics not in ("guessed", "calibrated"):
        raise ValueError(f"intrinsics must be 'guessed' or 'calibrated', got {intrinsics!r}")
    clip = load_clip()
    known = intrinsics_only(calibration()) if intrinsics == "calibrated" else None
    return write_person_capture(clip.tracks, clip.sizes, clip.fps, out, calibration=known, person=person)


def compact(keypoints: np.ndarray) -> np.ndarray:
    """float32 with pixels rounded to 1/64 and confidences to 1/1024 (binary fractions, which
    compress): far below the detector's error of several pixels."""
    out = np.array(keypoints, dtype=np.float32)
    out[..., :2] = np.round(out[..., :2] * 64) / 64
    out[..., 2] = np.round(out[..., 2] * 1024) / 1024
    return out


def remake(videos: Path, max_people: int) -> None:
    """Detect and track every person in each ``cam*.mp4`` of ``videos`` and write :data:`TRACKS`."""
    import time

    from mocapgraph.data_tools.tracking.detect_video import FORMAT, detect_video

    arrays, sizes, rates, cameras = {}, [], [], []
    for path in sorted(videos.glob("cam*.mp4")):
        start = time.perf_counter()
        detections = detect_video(path, max_people)
        tracks = track_people(detections.people, FORMAT)
        print(
            f"{path.name}: {detections.num_frames} frames, people per frame {np.bincount(detections.counts).tolist()}, "
            f"{tracks.num_tracks} tracks seen in {tracks.seen.sum(axis=1).tolist()} frames, {time.perf_counter() - start:.1f} s"
        )
        cameras.append(path.stem)
        arrays[f"tracks_{path.stem}"] = compact(tracks.keypoints)
        sizes.append(detections.size)
        rates.append(detections.fps)
    fd, tmp = tempfile.mkstemp(dir=CLIP, suffix=".npz")
    os.close(fd)
    np.savez_compressed(tmp, cameras=np.array(cameras), sizes=np.array(sizes), fps=np.array(rates), **arrays)
    os.replace(tmp, TRACKS)
    print(f"wrote {TRACKS} ({TRACKS.stat().st_size / 1024:.0f} KiB)")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description="Remake tests/data/real/tracks.npz from the clip's videos.")
    parser.add_argument("videos", type=Path, help="Demo_MultiPerson/videos of the pose2sim wheel")
    parser.add_argument("--max-people", type=int, default=3)
    args = parser.parse_args()
    remake(args.videos, args.max_people)
