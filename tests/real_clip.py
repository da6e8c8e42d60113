"""The real multi-camera clip in ``tests/data/real/``: loading it, making captures from it, and remaking it.

Pose2Sim's ``Demo_MultiPerson`` (4 static cameras around a treadmill, 60 fps, 100 frames, two
people; BSD-3-Clause, David Pagnon: see ``tests/data/real/README.md``): every person track that
``mocapgraph detect``'s detector and tracker follow in each camera, and the lab's Qualisys
calibration. The loading lives in :mod:`mocapgraph.benchmarks.real` (``mocapgraph bench real``
uses it too); these are its calls for this folder. Remake the tracks from the videos (in the
video environment, with MediaPipe)::

    .venv-video/bin/python tests/real_clip.py PATH/TO/Demo_MultiPerson/videos
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from mocapgraph.benchmarks import real
from mocapgraph.data_tools.io.calibration import CameraCalibration
from mocapgraph.data_tools.tracking.people import PersonChoice, track_people
from mocapgraph.data_tools.tracking.track_files import TrackSet, save_track_set

CLIP = Path(__file__).resolve().parent / "data" / "real"
TRACKS = CLIP / real.TRACKS_FILE


def load_clip() -> TrackSet:
    """Every camera's person tracks, sizes and frame rates."""
    return real.load_clip(CLIP)


def calibration() -> list[CameraCalibration]:
    """The lab's Qualisys calibration (intrinsics, distortion and poses) of the four cameras."""
    return real.lab_calibration(CLIP)


def clip_capture(out: Path, person: str | int = "largest", intrinsics: str = "guessed") -> tuple[Path, PersonChoice]:
    """A capture of one person, static cameras with their poses withheld (:func:`mocapgraph.benchmarks.real.clip_capture`)."""
    return real.clip_capture(CLIP, out, person, intrinsics)


def remake(videos: Path, max_people: int) -> None:
    """Detect and track every person in each ``cam*.mp4`` of ``videos`` and write :data:`TRACKS`."""
    import time

    from mocapgraph.data_tools.tracking.detect_video import FORMAT, detect_video

    tracks, sizes, rates, cameras = {}, {}, {}, []
    for path in sorted(videos.glob("cam*.mp4")):
        start = time.perf_counter()
        detections = detect_video(path, max_people)
        tracks[path.stem] = track_people(detections.people, FORMAT)
        print(
            f"{path.name}: {detections.num_frames} frames, people per frame {np.bincount(detections.counts).tolist()}, "
            f"{tracks[path.stem].num_tracks} tracks seen in {tracks[path.stem].seen.sum(axis=1).tolist()} frames, {time.perf_counter() - start:.1f} s"
        )
        cameras.append(path.stem)
        sizes[path.stem] = detections.size
        rates[path.stem] = detections.fps
    save_track_set(TrackSet(cameras, tracks, sizes, rates, FORMAT), TRACKS)
    print(f"wrote {TRACKS} ({TRACKS.stat().st_size / 1024:.0f} KiB)")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description="Remake tests/data/real/tracks.npz from the clip's videos.")
    parser.add_argument("videos", type=Path, help="Demo_MultiPerson/videos of the pose2sim wheel")
    parser.add_argument("--max-people", type=int, default=3)
    args = parser.parse_args()
    remake(args.videos, args.max_people)
