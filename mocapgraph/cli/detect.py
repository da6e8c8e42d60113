"""``mocapgraph detect``: 2D body keypoints from videos (MediaPipe), written as a capture.

Nothing heavy is imported until the command runs.
"""

from __future__ import annotations

from mocapgraph.cli.capture import add_capture_flags, calibration_from_args, moving_from_args, print_summary, videos_from_args
from mocapgraph.cli.common import command, function_flags
from mocapgraph.data_tools.io.files import refuse_existing
from mocapgraph.errors import MocapgraphError


def cmd_detect(args) -> None:
    from mocapgraph.data_tools.io.importers import assemble_capture, video_info
    from mocapgraph.data_tools.tracking import detect_video as dv

    refuse_existing(args.out, args.overwrite)
    videos = videos_from_args(args.videos)
    calibration = calibration_from_args(args)
    rates = {}
    for name, path in videos.items():  # every video readable and timed before the slow part
        rates[name] = args.fps or video_info(path)[1]
        if not rates[name]:
            raise MocapgraphError(f"{path}: the video does not state its frame rate; pass --fps")
    keypoints = {}
    for name, path in videos.items():
        # a fresh estimator per video: the tracker must not carry a person over from the last one
        with dv.MediaPipePose(args.model_complexity, args.min_confidence) as estimator:
            kp, boxes, _, _ = dv.detect_video(path, estimator=estimator)
        keypoints[name] = (dv.DETECTOR_NAME, dv.FORMAT, kp, boxes)
    path = assemble_capture(
        videos, keypoints, calibration, rates, args.out, args.name,
        moving=moving_from_args(args), video_mode="copy" if args.copy_videos else "link", overwrite=args.overwrite,
        metadata={"detector": {"name": dv.DETECTOR_NAME, "model_complexity": args.model_complexity,
                               "min_confidence": args.min_confidence}},
    )  # fmt: skip
    print_summary(path)


def add_parsers(subparsers) -> None:
    parser = command(
        subparsers, "detect",
        "detect 2D body keypoints in videos (MediaPipe) and write a capture",
        description="Run MediaPipe Pose (BlazePose, 33 points; the [video] extra) on every frame of each video "
        "and write a capture with one camera per video, named by the file stem or NAME=PATH.",
    )
    parser.add_argument("videos", nargs="+", metavar="VIDEO", help="video file, or NAME=PATH to name its camera")
    parser.add_argument("--fps", type=float, help="frames per second (default: what each video states)")
    from mocapgraph.data_tools.tracking.detect_video import detect_video

    function_flags(
        parser, detect_video,
        {"model_complexity": ("MediaPipe landmark model; only 1 ships with mediapipe 0.10.14", {"choices": (0, 1, 2)}),
         "min_confidence": "detection/tracking threshold"},
    )  # fmt: skip
    add_capture_flags(parser)
    parser.set_defaults(func=cmd_detect)
