"""The real multi-camera clip in ``tests/data/real/``: loading it, making captures from it, and remaking it.

Pose2Sim's ``Demo_MultiPerson`` (4 static cameras around a treadmill, 60 fps, 100 frames, two
people; BSD-3-Clause, David Pagnon: see ``tests/data/real/README.md``): every person track that
``mocapgraph detect``'s detector and tracker follow in each camera, and the lab's Qualisys
calibration. The loading lives in :mod:`mocapgraph.benchmarks.real` (``mocapgraph bench real``
uses it too); these are its calls for this folder. Remake the tracks from the videos (in the
video environment, with MediaPipe)::

    .venv-video/bin/python tests/real_clip.py PATH/TO/Demo_MultiPerson/videos

``tests/data/real_body25b/`` holds the same lab's OpenPose BODY_25B keypoints of a two-participant
trial, shipped in the ``pose2sim`` 0.8.4 wheel (its README says where from); remake its tracks with::

    .venv/bin/python tests/real_clip.py --openpose PATH/TO/S00_P01_T02_Participants1-2/pose
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
BODY25B_CLIP = CLIP.parent / "real_body25b"


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


def remake_openpose(pose: Path) -> None:
    """Follow every person in each ``cam*_json`` folder of ``pose`` (OpenPose BODY_25B JSON, 1088x1920
    at 60 fps) and write ``tests/data/real_body25b/tracks.npz``."""
    from mocapgraph.data_tools.io.keypoint_files import read_json_people

    cameras = sorted(p.name.removesuffix("_json") for p in pose.glob("cam*_json"))
    tracks = {}
    for cam in cameras:
        people, fmt = read_json_people(pose / f"{cam}_json", "openpose25b")
        tracks[cam] = track_people(people, fmt)
        print(f"{cam}: {len(people)} frames, people per frame {np.bincount([len(p) for p in people]).tolist()}, "
              f"{tracks[cam].num_tracks} tracks seen in {tracks[cam].seen.sum(axis=1).tolist()} frames")  # fmt: skip
    out = BODY25B_CLIP / real.TRACKS_FILE
    save_track_set(TrackSet(cameras, tracks, {c: (1088, 1920) for c in cameras}, {c: 60.0 for c in cameras}, "openpose25b"), out)
    print(f"wrote {out} ({out.stat().st_size / 1024:.0f} KiB)")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description="Remake tests/data/real/tracks.npz from the clip's videos (or, with --openpose, tests/data/real_body25b/tracks.npz).")
    parser.add_argument("videos", type=Path, nargs="?", help="Demo_MultiPerson/videos of the pose2sim wheel")
    parser.add_argument("--max-people", type=int, default=3)
    parser.add_argument("--openpose", type=Path, help="the pose/ folder of pose2sim 0.8.4's S00_P01_T02_Participants1-2")
    args = parser.parse_args()
    if args.openpose is not None:
        remake_openpose(args.openpose)
    elif args.videos is not None:
        remake(args.videos, args.max_people)
    else:
        parser.error("give the videos folder, or --openpose POSE_FOLDER")
