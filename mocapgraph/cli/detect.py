"""``mocapgraph detect``: 2D body keypoints from videos (MediaPipe), one person across all cameras, written as a capture.

Nothing heavy is imported until the command runs.
"""

from __future__ import annotations

from pathlib import Path

from mocapgraph.cli.capture import add_capture_flags, calibration_from_args, moving_from_args, print_summary, videos_from_args
from mocapgraph.cli.common import command, function_flags
from mocapgraph.data_tools.io.files import reserve_output
from mocapgraph.errors import MocapgraphError
from mocapgraph.progress import progress_bar

VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".m4v", ".webm", ".mpg", ".mpeg", ".wmv")


def _expand_folders(items: list[str]) -> list[str]:
    """Each folder among ``items`` → the videos in it (by name); files and ``NAME=PATH`` stay."""
    out = []
    for item in items:
        path = Path(item)
        if not path.is_dir():
            out.append(item)
            continue
        found = sorted(p for p in path.iterdir() if p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES)
        if not found:
            raise MocapgraphError(f"{path}: no videos in this folder (looked for {', '.join(VIDEO_SUFFIXES)})")
        out += [str(p) for p in found]
    return out


def cmd_detect(args) -> None:
    from mocapgraph.data_tools.io.capture import MANIFEST as CAPTURE_MANIFEST
    from mocapgraph.data_tools.io.importers import video_info
    from mocapgraph.data_tools.tracking import detect_video as dv
    from mocapgraph.data_tools.tracking.people import parse_person, track_people, write_person_capture

    reserve_output(args.out, args.overwrite, CAPTURE_MANIFEST, inputs=args.videos)
    person = parse_person(args.person)
    if args.max_people < 1:
        raise MocapgraphError(f"--max-people must be at least 1, got {args.max_people}")
    videos = videos_from_args(_expand_folders(args.videos))
    calibration = calibration_from_args(args)
    info = {name: video_info(path) for name, path in videos.items()}  # every video readable before the slow part
    rates = {}
    for name, path in videos.items():
        rates[name] = args.fps or info[name][1]
        if not rates[name]:
            raise MocapgraphError(f"{path}: the video does not state its frame rate; pass --fps")
    counts = {name: info[name][2] for name in videos}
    if len(set(counts.values())) > 1 and not args.allow_unequal_length:
        listing = ", ".join(f"{videos[n].name}: {c} frames" for n, c in counts.items())
        raise MocapgraphError(
            f"the videos have different lengths ({listing}); cut them to the same frames, or pass --allow-unequal-length "
            "(frame t of every video is then taken as the same instant)"
        )

    tracks, sizes = {}, {}
    for name, path in progress_bar(videos.items(), total=len(videos), desc="videos", unit="video"):
        detections = dv.detect_video(path, args.max_people, args.model_complexity, args.min_confidence)
        tracks[name], sizes[name] = track_people(detections.people, dv.FORMAT), detections.size
        if tracks[name].num_tracks == 0:
            raise MocapgraphError(f"{path}: no person was found in any of its {detections.num_frames} frames")
    path, choice = write_person_capture(
        tracks, sizes, rates, args.out, calibration=calibration, person=person, videos=videos,
        detector=dv.DETECTOR_NAME, keypoint_format=dv.FORMAT, name=args.name, moving=moving_from_args(args),
        video_mode="copy" if args.copy_videos else "link", overwrite=args.overwrite,
        require_equal_length=not args.allow_unequal_length,
        metadata={"detector": {"name": dv.DETECTOR_NAME, "model_complexity": args.model_complexity,
                               "min_confidence": args.min_confidence, "max_people": args.max_people}},
    )  # fmt: skip
    print(choice.describe())
    print_summary(path)


def add_parsers(subparsers) -> None:
    parser = command(
        subparsers, "detect",
        "detect 2D body keypoints in videos (MediaPipe) and write a capture of one person",
        description="Run MediaPipe Pose (BlazePose, 33 points; the [video] extra) on every frame of each video, follow "
        "up to --max-people people per video, find which of them is the same person in every camera (epipolar "
        "geometry), and write a capture of the chosen person with one camera per video (named by the file stem or "
        "NAME=PATH). Frame t of every video is taken as the same instant.",
    )
    parser.add_argument(
        "videos", nargs="+", metavar="VIDEO",
        help="video file, NAME=PATH to name its camera, or a folder of videos (each named by its file stem)",
    )  # fmt: skip
    parser.add_argument("--fps", type=float, help="frames per second (default: what each video states)")
    parser.add_argument(
        "--person", default="largest",
        help="the person to fit: 'largest' (tallest in the images) or 'central' (nearest the images' centres) of those "
        "seen by the most cameras, or a RANK of the listed people (default: largest)",
    )  # fmt: skip
    parser.add_argument(
        "--allow-unequal-length", action="store_true",
        help="accept videos with different frame counts (default: refused); frame t is still the same instant in all",
    )  # fmt: skip
    from mocapgraph.data_tools.tracking.detect_video import detect_video

    function_flags(
        parser, detect_video,
        {"max_people": "most people followed per video",
         "model_complexity": ("MediaPipe landmark model; only 1 ships with mediapipe 0.10.14", {"choices": (0, 1, 2)}),
         "min_confidence": "detection/tracking threshold"},
    )  # fmt: skip
    add_capture_flags(parser)
    parser.set_defaults(func=cmd_detect)
