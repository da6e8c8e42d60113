"""Captures: ``mocapgraph capture info|import``; the helpers here are shared with ``mocapgraph detect``.

Nothing heavy is imported until a command runs.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from mocapgraph.cli.common import command, group
from mocapgraph.data_tools.io.files import refuse_existing
from mocapgraph.errors import MocapgraphError


def _named_path(text: str) -> tuple[str | None, Path]:
    """``NAME=PATH`` → (NAME, PATH); a bare ``PATH`` → (None, PATH)."""
    name, sep, rest = text.partition("=")
    if sep and name and "/" not in name and not Path(text).exists():
        return name, Path(rest)
    return None, Path(text)


def videos_from_args(items: list[str] | None) -> dict[str, Path]:
    out: dict[str, Path] = {}
    for item in items or []:
        name, path = _named_path(item)
        name = name or path.stem
        if name in out:
            raise MocapgraphError(f"two videos for camera {name!r}; name them NAME=PATH")
        out[name] = path
    return out


def moving_from_args(args) -> dict[str, bool]:
    moving = {name: False for name in args.static or []}
    for name in args.moving or []:
        if name in moving:
            raise MocapgraphError(f"camera {name!r} is given as both --static and --moving")
        moving[name] = True
    return moving


def calibration_from_args(args):
    from mocapgraph.data_tools.io.importers import read_calibration

    return read_calibration(args.calibration, units=args.units) if args.calibration else None


def print_summary(path: Path) -> None:
    from mocapgraph.data_tools.io.capture import load_capture

    capture = load_capture(path)
    print(f"wrote {path.resolve()}")
    guessed = set(capture.metadata.get("imported", {}).get("guessed_intrinsics", []))
    for cam in capture.cameras:
        parts = [f"{cam.num_frames} frames at {cam.frame_rate:g} fps", f"{cam.image_size[0]}x{cam.image_size[1]}"]
        parts.append("guessed intrinsics" if cam.name in guessed else "calibrated intrinsics")
        parts.append("moving" if cam.moving else "static" + (" with pose" if cam.extrinsics is not None else ""))
        for det in cam.detectors.values():
            seen = np.isfinite(det.keypoints[..., 2]).any(axis=1).mean() if cam.num_frames else 0.0
            parts.append(f"{det.name} ({det.format}) person in {100 * seen:.0f}% of frames")
        if cam.video:
            parts.append(cam.video)
        print(f"  {cam.name}: " + ", ".join(parts))


def add_capture_flags(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, required=True, help="capture directory to write")
    parser.add_argument("--name", help="capture name (default: the directory name)")
    parser.add_argument(
        "--calibration", type=Path,
        help="camera calibration: OpenCV YAML/XML/JSON, JSON or Pose2Sim/anipose TOML (docs/importing.md)",
    )  # fmt: skip
    parser.add_argument(
        "--units", choices=("m", "cm", "mm"), default="m",
        help="length unit of the calibration's translations (default m; anipose uses its board's unit, often mm)",
    )  # fmt: skip
    parser.add_argument("--static", action="append", metavar="CAMERA", help="this camera does not move (repeatable)")
    parser.add_argument(
        "--moving", action="append", metavar="CAMERA",
        help="this camera moves (repeatable; default: moving unless the calibration gives its pose)",
    )  # fmt: skip
    parser.add_argument(
        "--copy-videos", action="store_true",
        help="copy the videos into the capture (default: hard-link them, copying only across file systems)",
    )  # fmt: skip
    parser.add_argument("--overwrite", action="store_true", help="replace an existing capture at --out")


def cmd_import(args) -> None:
    from mocapgraph.data_tools.io.importers import assemble_capture, read_openpose_json_folder

    refuse_existing(args.out, args.overwrite)
    person: str | int = args.person
    if person != "largest":
        try:
            person = int(person)
        except ValueError:
            raise MocapgraphError(f"--person must be 'largest' or an index, got {args.person!r}") from None
    keypoints = {}
    for item in args.openpose or []:
        name, folder = _named_path(item)
        name = name or folder.name
        if name in keypoints:
            raise MocapgraphError(f"two --openpose folders for camera {name!r}")
        kp, boxes = read_openpose_json_folder(folder, person=person)
        keypoints[name] = ("openpose", "openpose25", kp, boxes)
    if not keypoints and not args.videos:
        raise MocapgraphError("nothing to import: give --openpose CAMERA=FOLDER and/or --videos")
    path = assemble_capture(
        videos_from_args(args.videos), keypoints, calibration_from_args(args), args.fps, args.out, args.name,
        moving=moving_from_args(args), video_mode="copy" if args.copy_videos else "link", overwrite=args.overwrite,
    )  # fmt: skip
    print_summary(path)


def _add_import_parser(subparsers) -> None:
    parser = command(
        subparsers, "import",
        "make a capture from OpenPose JSON, videos and a calibration",
        description="Write a capture from OpenPose --write_json folders (one per camera), videos and a "
        "calibration file. Camera names must agree across them (docs/importing.md).",
    )
    parser.add_argument(
        "--openpose", action="append", metavar="CAMERA=FOLDER",
        help="a camera's OpenPose JSON folder (repeatable; a bare FOLDER names the camera after it)",
    )  # fmt: skip
    parser.add_argument(
        "--person", default="largest",
        help="which person to keep per frame: 'largest' box (default) or an index into OpenPose's people list",
    )  # fmt: skip
    parser.add_argument("--videos", nargs="+", metavar="VIDEO", help="videos: PATH (camera = file stem) or CAMERA=PATH")
    parser.add_argument("--fps", type=float, required=True, help="frames per second; timestamps are frame / fps")
    add_capture_flags(parser)
    parser.set_defaults(func=cmd_import)


def cmd_info(args) -> None:
    from mocapgraph.data_tools.io.capture import load_capture

    capture = load_capture(args.capture)
    print(f"capture {capture.name}: {len(capture.cameras)} cameras, world frame: {capture.world_frame}")
    for cam in capture.cameras:
        span = cam.timestamps[-1] - cam.timestamps[0]
        dets = ", ".join(
            f"{d.name} ({d.format}, {np.isfinite(d.keypoints[..., 0]).mean():.0%} points)" for d in cam.detectors.values()
        )
        print(
            f"  {cam.name:10s} {'moving' if cam.moving else 'static':6s} {cam.num_frames:5d} frames over {span:.1f} s "
            f"at {cam.frame_rate:g} fps; {cam.image_size[0]}x{cam.image_size[1]}; "
            f"calibrated: {'yes' if cam.extrinsics is not None else 'no'}; sensors: {', '.join(cam.sensors) or 'none'}"
        )
        print(f"  {'':10s} detectors: {dets or 'none'}")
    gt = capture.ground_truth
    print(f"ground truth: {'none' if gt is None else f'{len(gt.timestamps)} body states ({gt.body_model}), cameras: {len(gt.cameras)}'}")
    if capture.notes:
        print("repaired while loading:")
        for note in capture.notes:
            print(f"  {note}")


def add_parsers(subparsers) -> None:
    captures = group(subparsers, "capture", "inspect, import and assemble captures", "capture_command")
    info = command(captures, "info", "cameras, detectors, sensors and ground truth of a capture")
    info.add_argument("capture", type=Path, help="capture directory")
    info.set_defaults(func=cmd_info)
    _add_import_parser(captures)
