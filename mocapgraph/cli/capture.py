"""Captures: ``mocapgraph capture info|import``; the helpers here are shared with ``mocapgraph detect``.

Nothing heavy is imported until a command runs.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from mocapgraph.cli.common import command, group
from mocapgraph.data_tools.io.files import reserve_output
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
    """The cameras of ``--calibration`` (None without one), without their poses under ``--intrinsics-only``."""
    from mocapgraph.data_tools.io.calibration import read_calibration

    if not args.calibration:
        if args.intrinsics_only:
            raise MocapgraphError("--intrinsics-only needs a calibration to take the intrinsics from (--calibration FILE)")
        return None
    return _keep_intrinsics(read_calibration(args.calibration, units=args.units), args)


def _keep_intrinsics(cameras, args):
    from mocapgraph.data_tools.io.calibration import intrinsics_only

    return intrinsics_only(cameras) if args.intrinsics_only else cameras


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
        help="camera calibration: OpenCV YAML/XML/JSON, JSON, Pose2Sim/anipose TOML or Qualisys .qca.txt (docs/importing.md)",
    )  # fmt: skip
    parser.add_argument(
        "--units", choices=("m", "cm", "mm"),
        help="length unit of the calibration's translations (default m; Qualisys files say mm themselves; "
        "anipose uses its board's unit, often mm)",
    )  # fmt: skip
    parser.add_argument(
        "--intrinsics-only", action="store_true",
        help="keep the calibration's intrinsics and distortion, drop its camera poses (the pipelines then calibrate them)",
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


def _person(text: str) -> str | int:
    from mocapgraph.data_tools.tracking.people import parse_person

    try:
        person = parse_person(text)
    except MocapgraphError:
        person = -1
    if isinstance(person, int) and person < 0:
        raise MocapgraphError(f"--person must be 'largest', 'central' or an index (0, 1, ...), got {text!r}")
    return person


def _image_sizes(cameras, videos, calibration) -> dict[str, tuple[int, int]]:
    """Each camera's ``(width, height)`` from its video, else its calibration; an error naming the
    cameras that have neither (following people across cameras needs them)."""
    from mocapgraph.data_tools.io.importers import video_info

    calib = {c.name: c.image_size for c in calibration or [] if c.image_size is not None}
    sizes = {n: tuple(video_info(videos[n])[0]) if n in videos else calib.get(n) for n in cameras}
    unknown = [n for n, size in sizes.items() if size is None]
    if unknown:
        raise MocapgraphError(
            f"several people in the keypoints: following them across cameras needs each camera's image size, unknown for "
            f"{', '.join(unknown)} (no video, no size in the calibration); give the cameras' videos (--videos, or a Pose2Sim project's "
            "videos/) or a calibration with image sizes, or keep one person per file with --person INDEX"
        )
    return sizes


def _rates(items: list[str] | None) -> tuple[float | None, dict[str, float]]:
    """``--fps F`` and ``--fps CAMERA=F`` → (the rate of every camera or None, rate per named camera)."""
    everyone, per_camera = None, {}
    for item in items or []:
        name, sep, value = item.rpartition("=")
        try:
            rate = float(value)
        except ValueError:
            raise MocapgraphError(f"--fps {item}: expected F or CAMERA=F with a number F") from None
        if not (np.isfinite(rate) and rate > 0):
            raise MocapgraphError(f"--fps {item}: the frame rate must be positive")
        if sep:
            per_camera[name] = rate
        elif everyone is not None:
            raise MocapgraphError("--fps F given twice; name the cameras (--fps CAMERA=F) to give them different rates")
        else:
            everyone = rate
    return everyone, per_camera


def _array_path(item: str) -> tuple[str, Path, str | None]:
    """``[CAMERA=]FILE[:KEY]`` → (camera, file, key or None); the camera defaults to the file's stem."""
    name, path = _named_path(item)
    key = None
    if not path.exists() and ":" in path.name:
        base, _, key = str(path).rpartition(":")
        path = Path(base)
    return name or path.stem, path, key


def cmd_import(args) -> None:
    from mocapgraph.data_tools.io.capture import MANIFEST as CAPTURE_MANIFEST
    from mocapgraph.data_tools.io.importers import assemble_capture, video_info
    from mocapgraph.data_tools.io.keypoint_files import AUTO, OPENPOSE_SUFFIX, one_per_frame, read_json_people, read_keypoint_array

    inputs = [p for p in (args.pose2sim, args.calibration, *(args.openpose or []), *(args.keypoints or []), *(args.videos or [])) if p]
    reserve_output(args.out, args.overwrite, CAPTURE_MANIFEST, inputs=[_named_path(str(p))[1] for p in inputs])  # never into an input
    person = _person(args.person)
    keypoints: dict[str, tuple] = {}
    people: dict[str, list[np.ndarray]] = {}  # camera → every person of each frame, for JSON sources

    def add(camera: str, entry: tuple, flag: str) -> None:
        if camera in keypoints:
            raise MocapgraphError(f"camera {camera!r} has keypoints twice (the second from {flag}); name them CAMERA=PATH")
        keypoints[camera] = entry

    project_rate = None
    if args.pose2sim is not None:
        from mocapgraph.data_tools.io.pose2sim import read_pose2sim_project

        if args.openpose or args.keypoints or args.videos:
            raise MocapgraphError("--pose2sim reads the keypoints and videos of its project; leave out --openpose, --keypoints and --videos")
        project = read_pose2sim_project(args.pose2sim, args.format or AUTO, "largest" if isinstance(person, str) else person, args.calibration, args.units)
        for camera, (fmt, kp, boxes) in project.keypoints.items():
            add(camera, ("pose2sim", fmt, kp, boxes), "--pose2sim")
        people.update(project.people)
        videos, project_rate = project.videos, project.frame_rate
        if args.intrinsics_only and project.calibration is None:
            raise MocapgraphError(f"{project.root}: --intrinsics-only needs a calibration, and the project has none (calibration/)")
        calibration = _keep_intrinsics(project.calibration, args) if project.calibration is not None else None
        formats = sorted({entry[1] for entry in keypoints.values()})
        print(
            f"Pose2Sim project {project.root}: {len(keypoints)} cameras from {project.pose_folder.name}/ "
            f"({', '.join(formats)}, from {project.format_source}); calibration: {project.calibration_path or 'none'}; "
            f"videos: {len(videos)}"
        )
    else:
        videos, calibration = videos_from_args(args.videos), calibration_from_args(args)
    for item in args.openpose or []:
        name, folder = _named_path(item)
        frames, fmt = read_json_people(folder, args.format or "openpose25", suffix=OPENPOSE_SUFFIX)
        add(name or folder.name, ("openpose", fmt, *one_per_frame(frames, "largest" if isinstance(person, str) else person)), "--openpose")
        people[name or folder.name] = frames
    for item in args.keypoints or []:
        name, path, key = _array_path(item)
        kp, boxes, fmt = read_keypoint_array(path, args.format or AUTO, key)
        add(name, ("keypoints", fmt, kp, boxes), "--keypoints")
    if not keypoints and not videos:
        raise MocapgraphError("nothing to import: give --pose2sim PROJECT, --openpose CAMERA=FOLDER, --keypoints CAMERA=FILE and/or --videos")

    everyone, per_camera = _rates(args.fps)
    cameras = list(videos) + [n for n in keypoints if n not in videos]
    unknown = [n for n in per_camera if n not in cameras]
    if unknown:
        raise MocapgraphError(f"--fps names unknown camera(s) {', '.join(unknown)} (cameras: {', '.join(cameras)})")
    rates = {}
    for camera in cameras:
        rates[camera] = per_camera.get(camera) or everyone or project_rate or (video_info(videos[camera])[1] if camera in videos else 0.0)
        if not rates[camera]:
            where = "its video does not state it" if camera in videos else "it has no video"
            raise MocapgraphError(f"camera {camera}: frame rate unknown ({where}); pass --fps F or --fps {camera}=F")
    capture_options = dict(
        moving=moving_from_args(args), video_mode="copy" if args.copy_videos else "link", overwrite=args.overwrite,
        require_equal_length=not args.allow_unequal_length,
    )  # fmt: skip
    crowded = [n for n, frames in people.items() if any(len(found) > 1 for found in frames)]
    if crowded and isinstance(person, str):
        path = _import_following(args, keypoints, people, crowded, person, videos, calibration, rates, capture_options)
    else:
        path = assemble_capture(videos, keypoints, calibration, rates, args.out, args.name, **capture_options)
    print_summary(path)


def _import_following(args, keypoints, people, crowded, person, videos, calibration, rates, capture_options):
    """Several people in some camera's files: follow each camera's people over time, find the same
    person across the cameras and write a capture of the one ``person`` picks, as ``detect`` does."""
    from mocapgraph.data_tools.tracking.people import track_people, write_person_capture

    formats = sorted({entry[1] for entry in keypoints.values()})
    if len(formats) > 1:
        raise MocapgraphError(
            f"several people in the keypoints of {', '.join(crowded)}: following them across cameras needs one keypoint "
            f"format, got {', '.join(formats)}; keep one person per file with --person INDEX"
        )
    fmt = formats[0]
    tracks = {}
    for camera, (source, _, kp, _) in keypoints.items():
        frames = people.get(camera) or [kp[t][None] if np.isfinite(kp[t, :, 2]).any() else kp[t][:0] for t in range(len(kp))]
        tracks[camera] = track_people(frames, fmt)
        if tracks[camera].num_tracks == 0:
            raise MocapgraphError(f"camera {camera}: no person followed for 5 frames or more in its {len(frames)} frames ({source})")
    sources = sorted({entry[0] for entry in keypoints.values()})
    path, choice = write_person_capture(
        tracks, _image_sizes(list(keypoints), videos, calibration), rates, args.out, calibration=calibration, person=person,
        videos=videos, detector="+".join(sources), keypoint_format=fmt, name=args.name, **capture_options,
    )  # fmt: skip
    print(choice.describe())
    return path


def _add_import_parser(subparsers) -> None:
    parser = command(
        subparsers, "import",
        "make a capture from a Pose2Sim project, OpenPose JSON, keypoint arrays, videos and a calibration",
        description="Write a capture from a Pose2Sim project folder, or from OpenPose --write_json folders and "
        "keypoint arrays (one per camera), videos and a calibration file. Camera names must agree across them "
        "(docs/importing.md).",
    )
    parser.add_argument(
        "--pose2sim", type=Path, metavar="PROJECT",
        help="a Pose2Sim project folder: pose/<camera>_json/*.json, calibration/ and videos/ (docs/importing.md)",
    )  # fmt: skip
    parser.add_argument(
        "--openpose", action="append", metavar="CAMERA=FOLDER",
        help="a camera's OpenPose JSON folder (repeatable; a bare FOLDER names the camera after it)",
    )  # fmt: skip
    parser.add_argument(
        "--keypoints", action="append", metavar="CAMERA=FILE",
        help="a camera's (T, K, 3) keypoint array, x y confidence: FILE.npy, FILE.npz holding one array, or FILE.npz:KEY "
        "(repeatable; a bare FILE names the camera after its stem)",
    )  # fmt: skip
    parser.add_argument(
        "--format",
        help="keypoint format of the files: coco17, openpose25 (BODY_25), openpose25b (BODY_25B), halpe26, blazepose33 "
        "(default: --openpose openpose25; --pose2sim the project's pose_model; otherwise told from the points per person)",
    )  # fmt: skip
    parser.add_argument(
        "--person", default="largest",
        help="the person to import: 'largest' (tallest in the images, default) or 'central' (nearest the images' centres): where "
        "files hold several people, each camera's people are followed over time and matched across cameras (as detect), and that "
        "person of those seen by the most cameras is kept; or an INDEX into each file's people list (Pose2Sim's pose-associated order)",
    )  # fmt: skip
    parser.add_argument("--videos", nargs="+", metavar="VIDEO", help="videos: PATH (camera = file stem) or CAMERA=PATH")
    parser.add_argument(
        "--fps", action="append", metavar="[CAMERA=]F",
        help="frames per second, of every camera or of one (repeatable); timestamps are frame / fps. Default: the "
        "Pose2Sim project's frame_rate, else each camera's video",
    )  # fmt: skip
    parser.add_argument(
        "--allow-unequal-length", action="store_true",
        help="accept cameras that cover different lengths of time (default: refused, naming each camera's frames and rate)",
    )  # fmt: skip
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
