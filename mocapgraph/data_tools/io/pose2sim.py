"""Pose2Sim project folders: per-camera OpenPose-style JSON, a calibration, videos and ``Config.toml``.

A Pose2Sim project (https://github.com/perfanalytics/pose2sim) is laid out as::

    Config.toml                 optional: [pose] pose_model, [project] frame_rate
    calibration/Calib.toml      or a Qualisys *.qca.txt (Pose2Sim converts it to a .toml next to it)
    videos/cam01.mp4 ...        optional
    pose/cam01_json/*.json ...  one folder per camera, one file per frame (also pose/cam01/)

Pose2Sim's later steps write ``pose-sync/`` (frames trimmed to synchronise the cameras) and
``pose-associated/`` (one person kept, or the same person order in every camera); the most
processed one present is read. Cameras are matched by name: a keypoint folder ``cam01_json`` is
camera ``cam01``, as are ``videos/cam01.mp4`` and the calibration's camera named ``cam01``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocapgraph.data_tools.io.calibration import CameraCalibration, read_calibration
from mocapgraph.data_tools.io.capture import CaptureError
from mocapgraph.data_tools.io.checks import parse_toml, read_text
from mocapgraph.data_tools.io.keypoint_files import AUTO, natural_key, one_per_frame, read_json_people

log = logging.getLogger(__name__)

POSE_FOLDERS = ("pose-associated", "pose-sync", "pose")
"""Keypoint folders of a project, most processed first; the first one present is read."""

POSE_MODELS = {
    "body_with_feet": "halpe26", "halpe_26": "halpe26", "lower_body": "halpe26", "body": "coco17", "coco_17": "coco17",
    "body_25": "openpose25", "body_25b": "openpose25b", "blazepose": "blazepose33",
}  # fmt: skip
"""Pose2Sim's ``[pose] pose_model`` names → keypoint formats (``Lower_body`` runs HALPE_26)."""

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".m4v", ".mpg", ".mpeg", ".webm", ".wmv")


@dataclass
class Pose2SimProject:
    """What :func:`read_pose2sim_project` found.

    Attributes:
        root: the project folder.
        pose_folder: the folder the keypoints were read from (``pose``, ``pose-sync`` or ``pose-associated``).
        keypoints: camera → (format name, keypoints ``(T, K, 3)`` pixels, confidence in [0, 1],
            NaN where missing; boxes ``(T, 5)``), one person per frame as ``person`` said,
            cameras in natural order of their names.
        people: camera → every person of each frame, ``(N_t, K, 3)`` per frame (for following
            several people: :func:`~mocapgraph.data_tools.tracking.people.track_people`).
        format_source: where the format came from (for the user: ``--format``, ``Config.toml``, or the point count).
        calibration: the cameras of the calibration, or None when the project has none.
        calibration_path: its file.
        videos: camera → video file (cameras without a video are absent).
        frame_rate: ``Config.toml``'s ``[project] frame_rate`` when it is a number (not ``'auto'``).
    """

    root: Path
    pose_folder: Path
    keypoints: dict[str, tuple[str, np.ndarray, np.ndarray]]
    people: dict[str, list[np.ndarray]]
    format_source: str
    calibration: list[CameraCalibration] | None
    calibration_path: Path | None
    videos: dict[str, Path]
    frame_rate: float | None


def _config(root: Path) -> dict:
    path = root / "Config.toml"
    if not path.is_file():
        return {}
    return parse_toml(read_text(path, CaptureError, "a UTF-8 TOML file"), path, CaptureError)


def _config_format(root: Path, config: dict) -> tuple[str, str]:
    model = config.get("pose", {}).get("pose_model") if isinstance(config.get("pose"), dict) else None
    if model is None:
        return AUTO, "the number of points per person"
    fmt = POSE_MODELS.get(str(model).lower())
    if fmt is None:
        known = ", ".join(sorted(POSE_MODELS))
        raise CaptureError(
            f"{root / 'Config.toml'}: pose.pose_model: {model!r} is not a keypoint format mocapgraph reads "
            f"(it reads {known}); pass --format if the JSON files hold one of those"
        )
    return fmt, f"Config.toml pose_model {model!r}"


def _frame_rate(root: Path, config: dict) -> float | None:
    rate = config.get("project", {}).get("frame_rate") if isinstance(config.get("project"), dict) else None
    if rate is None or (isinstance(rate, str) and rate.lower() == "auto"):
        return None
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not np.isfinite(rate) or rate <= 0:
        raise CaptureError(f"{root / 'Config.toml'}: project.frame_rate: expected a positive number or 'auto', got {rate!r}")
    return float(rate)


def _camera_folders(root: Path) -> tuple[Path, dict[str, Path]]:
    for name in POSE_FOLDERS:
        folder = root / name
        if not folder.is_dir():
            continue
        cams = {}
        for sub in sorted((p for p in folder.iterdir() if p.is_dir()), key=natural_key):
            if any(f.suffix.lower() == ".json" for f in sub.iterdir()):
                cam = sub.name.removesuffix("_json") or sub.name
                if cam in cams:
                    raise CaptureError(f"{folder}: {cams[cam].name} and {sub.name} are both camera {cam!r}")
                cams[cam] = sub
        if cams:
            return folder, cams
        log.warning("%s: no camera folder with .json files in it; trying the next keypoint folder", folder)
    raise CaptureError(
        f"{root}: no keypoints: expected one folder of .json files per camera in {' or '.join(f'{n}/' for n in POSE_FOLDERS)} "
        "(pose/cam01_json/*.json, ...)"
    )


def _calibration_file(root: Path) -> Path | None:
    folder = root / "calibration"
    if not folder.is_dir():
        return None
    # Pose2Sim converts a Qualisys file into a .toml next to it; the .toml is what it then uses.
    for pattern in ("*.toml", "*.qca.txt"):
        found = sorted(folder.glob(pattern))
        if len(found) == 1:
            return found[0]
        if found:
            raise CaptureError(f"{folder}: {len(found)} calibration files ({', '.join(p.name for p in found)}); choose one with --calibration")
    return None


def _videos(root: Path) -> dict[str, Path]:
    folder = root / "videos"
    if not folder.is_dir():
        return {}
    return {p.stem: p for p in sorted(folder.iterdir(), key=natural_key) if p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES}


def _names(items) -> str:
    return ", ".join(items) or "none"


def read_pose2sim_project(
    project: str | Path,
    fmt: str = AUTO,
    person: str | int = "largest",
    calibration: str | Path | None = None,
    units: str | None = None,
) -> Pose2SimProject:
    """Read a Pose2Sim project folder's keypoints, calibration and videos.

    Args:
        project: the project folder (the one holding ``pose/`` or ``pose-sync/``).
        fmt: keypoint format of the JSON files; ``"auto"`` takes ``Config.toml``'s ``pose_model``
            when there is one, else tells it from the number of points per person.
        person: which person to keep per frame and camera in ``keypoints`` (see :func:`~mocapgraph.data_tools.io.keypoint_files.one_per_frame`).
        calibration: a calibration file to use instead of the project's ``calibration/`` folder.
        units: the calibration's length unit (see :func:`read_calibration`).

    Every camera of the calibration must have a keypoint folder and every keypoint folder a camera
    in the calibration ("missing cameras" otherwise, naming both lists); every video must name a
    camera with keypoints.
    """
    root = Path(project)
    if not root.is_dir():
        raise CaptureError(f"{root}: Pose2Sim project folder not found")
    config = _config(root)
    source = "--format"
    if fmt == AUTO:
        fmt, source = _config_format(root, config)
    pose_folder, folders = _camera_folders(root)

    calib_path = Path(calibration) if calibration is not None else _calibration_file(root)
    cams = read_calibration(calib_path, units=units) if calib_path is not None else None
    if cams is not None:
        calibrated = [c.name for c in cams]
        missing = [n for n in calibrated if n not in folders]
        extra = [n for n in folders if n not in calibrated]
        if missing:
            raise CaptureError(
                f"{root}: missing cameras: the calibration {calib_path} has cameras without a keypoint folder in "
                f"{pose_folder}: {_names(missing)} (the keypoint folders are {_names(p.name for p in folders.values())})"
            )
        if extra:
            raise CaptureError(
                f"{root}: missing cameras: keypoint folders in {pose_folder} without a camera in the calibration "
                f"{calib_path}: {_names(folders[n].name for n in extra)} (the calibration has {_names(calibrated)})"
            )
    videos = _videos(root)
    stray = [p.name for n, p in videos.items() if n not in folders]
    if stray:
        raise CaptureError(
            f"{root / 'videos'}: {_names(stray)} match no keypoint folder in {pose_folder} ({_names(p.name for p in folders.values())}); "
            "name each video after its camera"
        )
    keypoints, people = {}, {}
    for cam, folder in folders.items():
        people[cam], found = read_json_people(folder, fmt)
        keypoints[cam] = (found, *one_per_frame(people[cam], person))
    return Pose2SimProject(
        root=root, pose_folder=pose_folder, keypoints=keypoints, people=people, format_source=source, calibration=cams,
        calibration_path=calib_path, videos=videos, frame_rate=_frame_rate(root, config),
    )  # fmt: skip
