"""Bringing other tools' output into a capture: OpenPose JSON, camera calibrations, videos.

``docs/importing.md`` lists every accepted format with examples. In short:

- :func:`read_openpose_json_folder` reads OpenPose's ``--write_json`` output (one
  ``*_keypoints.json`` per frame, BODY_25) and keeps one person per frame.
- :func:`read_calibration` reads OpenCV ``FileStorage`` files (YAML / XML / JSON), plain JSON and
  Pose2Sim / anipose TOML into :class:`CameraCalibration` records.
- :func:`assemble_capture` writes a capture from videos, detections and a calibration.

Every problem with an input file raises one :class:`~mocapgraph.data_tools.io.capture.CaptureError`
that names the file (and the field, where there is one).
"""

from __future__ import annotations

import json
import logging
import os
import re
import shutil
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.rotations import nearest_rotation, rotvec_to_matrix
from mocapgraph.data_tools.io.capture import (
    MANIFEST,
    Camera,
    Capture,
    CaptureError,
    Detector,
    load_capture,
    world_T_camera_from_Rt,
    write_capture,
)
from mocapgraph.data_tools.io.files import write_directory_atomically
from mocapgraph.errors import MocapgraphError

log = logging.getLogger(__name__)

OPENPOSE_SUFFIX = "_keypoints.json"
DEFAULT_FOCAL_FACTOR = 1.2
"""Uncalibrated cameras get ``f = DEFAULT_FOCAL_FACTOR × max(width, height)`` pixels (a field of view
of about 45° across the longer side, typical of phone and action cameras in their normal mode)."""

UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
"""Length units a calibration's translations may be in, as metres per unit."""

# Orthonormality error up to which a calibration's rotation is accepted (and projected onto SO(3)):
# hand-written or rounded files rarely hold more than 6 significant digits.
_ROTATION_TOLERANCE = 1e-3


# ---------------------------------------------------------------------------------------------
# OpenPose


def _natural_key(path: Path) -> list:
    """``frame_2`` before ``frame_10``: digit runs compare as numbers."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.name)]


def _person_box(kp: np.ndarray) -> np.ndarray:
    """``(25, 3)`` normalised keypoints → ``(5,)`` box of the present points and their mean confidence."""
    present = np.isfinite(kp[:, 2])
    if not present.any():
        return np.full(5, np.nan)
    xy, conf = kp[present, :2], kp[present, 2]
    return np.array([xy[:, 0].min(), xy[:, 1].min(), xy[:, 0].max(), xy[:, 1].max(), conf.mean()])


def read_openpose_json_folder(folder: str | Path, person: str | int = "largest") -> tuple[np.ndarray, np.ndarray]:
    """Read OpenPose ``--write_json`` output: one ``*_keypoints.json`` per frame.

    Args:
        folder: holds the per-frame files; they are taken in natural order of their names
            (``x_2_keypoints.json`` before ``x_10_keypoints.json``). Other files are ignored.
        person: ``"largest"`` keeps the person with the largest box of detected points in each
            frame; an int keeps ``people[person]`` of every frame (NaN where a frame has fewer).

    Returns:
        keypoints ``(T, 25, 3)`` BODY_25 in pixels with confidence, NaN where missing (OpenPose's
        ``(0, 0, 0)`` included); boxes ``(T, 5)`` ``x0, y0, x1, y1, score`` of the kept person's
        detected points (score = their mean confidence), NaN rows for frames without a person.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise CaptureError(f"{folder}: OpenPose folder not found")
    if not (person == "largest" or (isinstance(person, int) and not isinstance(person, bool) and person >= 0)):
        raise CaptureError(f"{folder}: person must be 'largest' or a non-negative index, got {person!r}")
    files = sorted((p for p in folder.iterdir() if p.name.endswith(OPENPOSE_SUFFIX)), key=_natural_key)
    if not files:
        raise CaptureError(f"{folder}: no *{OPENPOSE_SUFFIX} files (OpenPose writes them with --write_json)")
    fmt = get_format("openpose25")
    size = fmt.num_points * 3
    keypoints = np.full((len(files), fmt.num_points, 3), np.nan)
    boxes = np.full((len(files), 5), np.nan)
    for t, path in enumerate(files):
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise CaptureError(f"{path}: not valid JSON ({exc})") from None
        people = doc.get("people") if isinstance(doc, dict) else None
        if not isinstance(people, list):
            raise CaptureError(f"{path}: people: missing or not a list (is this OpenPose --write_json output?)")
        candidates = []
        for i, entry in enumerate(people):
            raw = entry.get("pose_keypoints_2d") if isinstance(entry, dict) else None
            if not isinstance(raw, list):
                raise CaptureError(f"{path}: people[{i}].pose_keypoints_2d: missing or not a list")
            if len(raw) != size:
                hint = " (54 values is the COCO-18 model: run OpenPose with the default BODY_25)" if len(raw) == 54 else ""
                raise CaptureError(
                    f"{path}: people[{i}].pose_keypoints_2d: expected {size} values (BODY_25 x, y, c), got {len(raw)}{hint}"
                )
            try:
                kp = fmt.normalise(np.asarray(raw, dtype=float).reshape(fmt.num_points, 3), source=f"{path}: people[{i}]")
            except (TypeError, ValueError):
                raise CaptureError(f"{path}: people[{i}].pose_keypoints_2d: not all numbers") from None
            except MocapgraphError as exc:
                raise CaptureError(str(exc)) from None
            candidates.append((kp, _person_box(kp)))
        if person == "largest":
            area = [(b[2] - b[0]) * (b[3] - b[1]) if np.isfinite(b[0]) else -1.0 for _, b in candidates]
            chosen = candidates[int(np.argmax(area))] if candidates and max(area) >= 0 else None
        else:
            chosen = candidates[person] if person < len(candidates) else None
        if chosen is not None:
            keypoints[t], boxes[t] = chosen
    return keypoints, boxes


# ---------------------------------------------------------------------------------------------
# Calibrations


@dataclass
class CameraCalibration:
    """One camera of a calibration file.

    Attributes:
        name: camera name (from the file; see :func:`read_calibration`).
        K: ``(3, 3)`` intrinsics, pixels.
        distortion: ``(5,)`` OpenCV ``k1, k2, p1, p2, k3`` (shorter lists are padded with zeros).
        image_size: ``(width, height)`` pixels, or None when the file does not say.
        world_T_camera: ``(4, 4)`` pose, translation in metres (after the unit scale), or None for
            an intrinsics-only calibration. Files store world→camera ``R, t``; this is its inverse.
    """

    name: str
    K: np.ndarray
    distortion: np.ndarray
    image_size: tuple[int, int] | None
    world_T_camera: np.ndarray | None = None


# Accepted spellings of each field (matched case-sensitively, first found wins). Plural per-view
# keys (calibrateCamera's rvecs / tvecs) are deliberately absent: they are not the camera's pose.
_K_KEYS = ("K", "camera_matrix", "cameraMatrix", "matrix", "intrinsics", "intrinsic", "M", "mtx")
_DIST_KEYS = ("distortion_coefficients", "dist_coeffs", "distCoeffs", "distortions", "distortion", "dist", "D")
_R_KEYS = ("R", "rotation", "rvec", "rotation_vector", "rotation_matrix")
_T_KEYS = ("T", "t", "tvec", "translation", "translation_vector")
_SIZE_KEYS = ("image_size", "imageSize", "size", "resolution")
_WIDTH_KEYS = ("image_width", "imageWidth", "width", "img_width")
_HEIGHT_KEYS = ("image_height", "imageHeight", "height", "img_height")
_CAMERA_PREFIX = "cam_"


def _first(table: Mapping, keys: Sequence[str]) -> tuple[str | None, object]:
    for key in keys:
        if key in table:
            return key, table[key]
    return None, None


def _opencv_matrix(value):
    """cv2.FileStorage JSON matrices (``{"type_id": "opencv-matrix", rows, cols, dt, data}`` or
    ``opencv-nd-matrix`` with ``sizes``) → ndarray, anywhere in a parsed document."""
    if isinstance(value, dict) and "data" in value and ({"rows", "cols"} <= set(value) or "sizes" in value):
        shape = (value["rows"], value["cols"]) if "rows" in value else value["sizes"]
        try:
            return np.asarray(value["data"], dtype=float).reshape([int(s) for s in np.atleast_1d(shape)])
        except (TypeError, ValueError):
            return value
    if isinstance(value, dict):
        return {k: _opencv_matrix(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_opencv_matrix(v) for v in value]
    return value


def _filestorage_tree(path: Path):
    """Read a cv2.FileStorage file (YAML / XML / JSON) into dicts, lists, arrays, numbers and strings."""
    import cv2

    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:
        # a parse error surfaces as SystemError caused by cv2.error; keep OpenCV's own words
        message = str(exc.__cause__ or exc).strip() or type(exc).__name__
        raise CaptureError(f"{path}: not a readable OpenCV FileStorage file ({message.splitlines()[-1]})") from None
    if not fs.isOpened():
        raise CaptureError(f"{path}: not a readable OpenCV FileStorage file")

    def convert(node):
        if node.isMap():
            keys = tuple(node.keys())
            if "data" in keys and ({"rows", "cols"} <= set(keys) or "sizes" in keys):  # opencv-(nd-)matrix
                return np.asarray(node.mat(), dtype=float)
            return {k: convert(node.getNode(k)) for k in keys}
        if node.isSeq():
            return [convert(node.at(i)) for i in range(node.size())]
        if node.isInt():
            return int(node.real())
        if node.isReal():
            return float(node.real())
        if node.isString():
            return node.string()
        return None

    try:
        return convert(fs.root())
    except (cv2.error, SystemError) as exc:
        raise CaptureError(f"{path}: could not read a node ({str(exc).strip()})") from None
    finally:
        fs.release()


def _as_array(value, path: Path, field: str, sizes: Sequence[tuple[int, ...]]) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise CaptureError(f"{path}: {field}: not a numeric array") from None
    for shape in sizes:
        # the shape itself, or the same numbers as a flat / column / row vector (row-major)
        if arr.shape == shape or (arr.size == int(np.prod(shape)) and sum(s > 1 for s in arr.shape) <= 1):
            arr = arr.reshape(shape)
            break
    else:
        want = " or ".join(str(s) for s in sizes)
        raise CaptureError(f"{path}: {field}: expected shape {want}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise CaptureError(f"{path}: {field}: contains NaN or inf")
    return arr


def _project_rotation(R: np.ndarray, path: Path, field: str) -> np.ndarray:
    err = np.abs(R @ R.T - np.eye(3)).max()
    if err > _ROTATION_TOLERANCE or np.linalg.det(R) <= 0:
        raise CaptureError(f"{path}: {field}: not a rotation matrix (orthonormality error {err:.2g}, det {np.linalg.det(R):.3g})")
    return nearest_rotation(R)


def _camera_from_table(table: Mapping, name: str, path: Path, where: str, scale: float) -> CameraCalibration:
    prefix = f"{where}." if where else ""
    fisheye = table.get("fisheye")
    if fisheye is True or (isinstance(fisheye, (int, float)) and fisheye == 1) or str(fisheye).lower() == "true":
        raise CaptureError(
            f"{path}: {prefix}fisheye: fisheye calibrations are not supported (mocapgraph uses the OpenCV pinhole "
            "model with k1, k2, p1, p2, k3); calibrate with the pinhole model"
        )
    key, value = _first(table, _K_KEYS)
    K = _as_array(value, path, prefix + key, [(3, 3)])
    if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0, 0, 1]):
        raise CaptureError(f"{path}: {prefix}{key}: needs fx > 0, fy > 0 and a last row [0, 0, 1]")

    distortion = np.zeros(5)
    key, value = _first(table, _DIST_KEYS)
    if key is not None:
        try:
            d = np.asarray(value, dtype=float).ravel()
        except (TypeError, ValueError):
            d = None
        if d is None or d.size not in (4, 5, 8, 12, 14) or not np.all(np.isfinite(d)):
            raise CaptureError(f"{path}: {prefix}{key}: expected 4 or 5 OpenCV coefficients k1, k2, p1, p2[, k3]")
        if d.size > 5 and np.any(d[5:] != 0):
            raise CaptureError(
                f"{path}: {prefix}{key}: the rational / thin-prism terms beyond k3 are not supported (they must be 0)"
            )
        distortion[: min(d.size, 5)] = d[:5]

    size = None
    key, value = _first(table, _SIZE_KEYS)
    wkey, width = _first(table, _WIDTH_KEYS)
    hkey, height = _first(table, _HEIGHT_KEYS)
    if key is not None:
        wh = _as_array(value, path, prefix + key, [(2,)])
        size = (wh[0], wh[1])
        field = prefix + key
    elif wkey is not None and hkey is not None:
        size = (width, height)
        field = f"{prefix}{wkey}/{hkey}"
    if size is not None:
        try:
            w, h = float(size[0]), float(size[1])
        except (TypeError, ValueError):
            raise CaptureError(f"{path}: {field}: expected two numbers (width, height)") from None
        if w <= 0 or h <= 0 or w != int(w) or h != int(h):
            raise CaptureError(f"{path}: {field}: expected positive whole pixels (width, height), got {size}")
        size = (int(w), int(h))

    rkey, rvalue = _first(table, _R_KEYS)
    tkey, tvalue = _first(table, _T_KEYS)
    pose = None
    if (rkey is None) != (tkey is None):
        have, missing = (rkey, "translation (T / t / tvec / translation)") if tkey is None else (tkey, "rotation (R / rvec / rotation)")
        raise CaptureError(f"{path}: {prefix}{have}: given without a {missing}")
    if rkey is not None:
        r = _as_array(rvalue, path, prefix + rkey, [(3, 3), (3,)])
        R = rotvec_to_matrix(r) if r.shape == (3,) else _project_rotation(r, path, prefix + rkey)
        t = _as_array(tvalue, path, prefix + tkey, [(3,)]) * scale
        pose = world_T_camera_from_Rt(R, t)
    return CameraCalibration(name=name, K=K, distortion=distortion, image_size=size, world_T_camera=pose)


def _camera_name(key: str, table: Mapping, strip_prefix: bool = True) -> str:
    """The table's ``name`` (or ``camera_name``), else its key without a leading ``cam_``."""
    name = table.get("name", table.get("camera_name"))
    if isinstance(name, str) and name:
        return name
    if strip_prefix and key.startswith(_CAMERA_PREFIX) and len(key) > len(_CAMERA_PREFIX):
        return key[len(_CAMERA_PREFIX) :]
    return key


def _is_camera(value) -> bool:
    return isinstance(value, Mapping) and _first(value, _K_KEYS)[0] is not None


def _cameras_from_tree(tree, path: Path, scale: float) -> list[CameraCalibration]:
    """Find the cameras in a parsed file: one camera at the top, a ``cameras`` list / table, or one
    table per camera (other tables, e.g. ``[metadata]``, are ignored)."""
    if isinstance(tree, Mapping) and "cameras" in tree and not _is_camera(tree):
        tree = tree["cameras"]
    cams: list[CameraCalibration] = []
    if isinstance(tree, list):
        for i, entry in enumerate(tree):
            if not _is_camera(entry):
                raise CaptureError(f"{path}: cameras[{i}]: not a camera (needs one of {', '.join(_K_KEYS)})")
            cams.append(_camera_from_table(entry, _camera_name(f"cam{i}", entry, strip_prefix=False), path, f"cameras[{i}]", scale))
    elif _is_camera(tree):
        cams.append(_camera_from_table(tree, _camera_name(path.stem, tree, strip_prefix=False), path, "", scale))
    elif isinstance(tree, Mapping):
        for key, entry in tree.items():
            if _is_camera(entry):
                cams.append(_camera_from_table(entry, _camera_name(str(key), entry), path, str(key), scale))
    if not cams:
        raise CaptureError(
            f"{path}: no camera found: expected a camera matrix under one of {', '.join(_K_KEYS)}, at the top "
            "level, in a 'cameras' list or in one table per camera (see docs/importing.md)"
        )
    names = [c.name for c in cams]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise CaptureError(f"{path}: camera names must be unique, {duplicates} appear more than once")
    return cams


def _sniff(path: Path, text: str) -> str:
    suffix = path.suffix.lower()
    if suffix in (".yml", ".yaml", ".xml"):
        return "filestorage"
    if suffix == ".json":
        return "json"
    if suffix == ".toml":
        return "toml"
    head = text.lstrip()[:64]
    if head.startswith("%YAML") or head.startswith("<?xml") or head.startswith("<opencv_storage"):
        return "filestorage"
    if head.startswith("{") or head.startswith("["):
        # a TOML file may open with a [table] header; JSON lists never hold a bare word
        return "toml" if re.match(r"\[\s*[A-Za-z_][\w.\-\"' ]*\]\s*$", head.splitlines()[0]) else "json"
    return "toml"


def read_calibration(path: str | Path, units: str = "m") -> list[CameraCalibration]:
    """Read the cameras of a calibration file.

    The format is chosen by extension (``.yml``/``.yaml``/``.xml`` OpenCV FileStorage, ``.json``,
    ``.toml``) or, for other extensions, by content. ``units`` is the length unit of the file's
    translations (``m``, ``cm`` or ``mm``); they are scaled to metres. Accepted layouts and field
    names: ``docs/importing.md``.
    """
    path = Path(path)
    if units not in UNITS:
        raise CaptureError(f"{path}: unknown units {units!r}; use one of {', '.join(UNITS)}")
    if not path.is_file():
        raise CaptureError(f"{path}: calibration file not found")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise CaptureError(f"{path}: not a text file; calibrations are OpenCV YAML/XML/JSON, JSON or TOML") from None
    kind = _sniff(path, text)
    if kind == "filestorage":
        tree = _filestorage_tree(path)
    elif kind == "json":
        try:
            tree = _opencv_matrix(json.loads(text))
        except json.JSONDecodeError as exc:
            raise CaptureError(f"{path}: not valid JSON ({exc})") from None
    else:
        try:
            tree = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            if path.suffix.lower() == ".toml":
                raise CaptureError(f"{path}: not valid TOML ({exc})") from None
            raise CaptureError(
                f"{path}: unknown calibration format (not OpenCV YAML/XML, JSON or TOML); see docs/importing.md"
            ) from None
    return _cameras_from_tree(tree, path, UNITS[units])


# ---------------------------------------------------------------------------------------------
# Videos


def video_info(path: str | Path) -> tuple[tuple[int, int], float, int]:
    """``(width, height)``, frames per second (0 when unknown) and frame count of a video.

    The size is that of the first decoded frame (as OpenCV delivers it, rotation metadata applied);
    the frame count is the container's, or counted by decoding when the container does not say.
    """
    import cv2

    path = Path(path)
    if not path.is_file():
        raise CaptureError(f"{path}: video not found")
    cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            raise CaptureError(f"{path}: OpenCV cannot open this video")
        fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        ok, frame = cap.read()
        if not ok or frame is None:
            raise CaptureError(f"{path}: no frame could be decoded")
        size = (int(frame.shape[1]), int(frame.shape[0]))
        count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        if count <= 0:
            count = 1
            while cap.grab():
                count += 1
    finally:
        cap.release()
    return size, (fps if np.isfinite(fps) and fps > 0 else 0.0), count


def _place_video(source: Path, target: Path, mode: str) -> None:
    """Hard-link ``source`` to ``target`` (``mode="link"``, copying when linking is impossible) or copy it.

    Symbolic links are not used: the capture loader refuses paths that lead outside the capture.
    """
    target.parent.mkdir(parents=True, exist_ok=True)
    if mode == "link":
        try:
            os.link(source, target)
            return
        except OSError:
            pass
    shutil.copy2(source, target)


# ---------------------------------------------------------------------------------------------
# Assembling a capture


KeypointEntry = tuple[str, str, np.ndarray, "np.ndarray | None"]


def _default_K(size: tuple[int, int]) -> np.ndarray:
    w, h = size
    f = DEFAULT_FOCAL_FACTOR * max(w, h)
    return np.array([[f, 0.0, w / 2.0], [0.0, f, h / 2.0], [0.0, 0.0, 1.0]])


def assemble_capture(
    videos: Sequence[str | Path] | Mapping[str, str | Path] | None,
    keypoints: Mapping[str, KeypointEntry | Sequence[KeypointEntry]],
    calibration: Sequence[CameraCalibration] | None,
    fps: float | Mapping[str, float],
    out: str | Path,
    name: str | None = None,
    *,
    moving: Mapping[str, bool] | None = None,
    video_mode: str = "link",
    overwrite: bool = False,
    metadata: Mapping | None = None,
) -> Path:
    """Write a capture at ``out`` from videos, 2D detections and an optional calibration.

    Args:
        videos: video files; a list names each camera by its file stem (``cam1.mp4`` → ``cam1``),
            a mapping gives camera name → file. Each is placed at ``cameras/<name>/video.<ext>``.
        keypoints: camera name → ``(detector name, format, keypoints (T, K, 3), boxes (T, 5) or
            None)``, or a list of such tuples for several detectors. Keypoints must already be
            normalised (pixels, confidence in [0, 1], NaN where missing).
        calibration: cameras of a calibration file (:func:`read_calibration`), matched by name.
        fps: frames per second of every camera, or per camera name. Timestamps are
            ``frame index / fps`` seconds.
        out: capture directory to write.
        name: capture name (default: the directory name).
        moving: camera name → whether it moves. Default: a camera whose calibration has a pose is
            static (``moving=False``, the pose stored as its extrinsics); any other camera moves.
        video_mode: ``"link"`` (hard link, falling back to a copy across file systems) or ``"copy"``.
        overwrite: replace an existing capture at ``out``.
        metadata: extra manifest entries.

    The cameras are those with a video or keypoints, matched to the calibration by name; calibrated
    cameras without data are skipped, cameras missing from the calibration are uncalibrated (both
    noted on stderr). A camera's image size comes from its
    calibration or its video (both must agree); its intrinsics from the calibration or, without
    one, the guess ``f = 1.2 × max(width, height)``, principal point at the image centre, no
    distortion (:data:`DEFAULT_FOCAL_FACTOR`). Its frame count is that of its detections, or
    of its video when it has none.
    """
    out = Path(out)
    if video_mode not in ("link", "copy"):
        raise CaptureError(f"video_mode must be 'link' or 'copy', got {video_mode!r}")
    moving = dict(moving or {})
    calib = {c.name: c for c in calibration or []}
    if len(calib) != len(calibration or []):
        raise CaptureError("calibration: camera names must be unique")

    video_map: dict[str, Path] = {}
    if isinstance(videos, Mapping):
        video_map = {str(k): Path(v) for k, v in videos.items()}
    else:
        for v in videos or []:
            v = Path(v)
            if v.stem in video_map:
                raise CaptureError(f"{v}: two videos name camera {v.stem!r} (name them NAME=PATH)")
            video_map[v.stem] = v

    dets: dict[str, list[KeypointEntry]] = {}
    for cam, entry in keypoints.items():
        entries = [entry] if isinstance(entry, tuple) and len(entry) == 4 and isinstance(entry[0], str) else list(entry)
        dets[str(cam)] = entries

    # The cameras are those with data; a calibration may hold more (they are skipped) or fewer
    # (the others get guessed intrinsics): a mix of calibrated and uncalibrated cameras is valid.
    names = list(video_map) + [n for n in dets if n not in video_map]
    if not names:
        raise CaptureError("nothing to import: give videos or keypoints")
    if calib:
        unused = [n for n in calib if n not in names]
        uncalibrated = [n for n in names if n not in calib]
        if unused:
            log.warning("note: calibrated camera(s) %s have no video or keypoints; skipped", unused)
        if uncalibrated:
            log.warning("note: camera(s) %s are not in the calibration (it has %s); their intrinsics are guessed", uncalibrated, list(calib))
    unknown_moving = [n for n in moving if n not in names]
    if unknown_moving:
        raise CaptureError(f"moving/static given for unknown camera(s) {unknown_moving} (cameras: {', '.join(names)})")

    cameras: list[Camera] = []
    placements: list[tuple[Path, str]] = []
    for cam_name in names:
        if not cam_name or "/" in cam_name or cam_name.startswith(".") or cam_name != cam_name.strip():
            raise CaptureError(f"camera name {cam_name!r} is not a plain file name")
        rate = float(fps[cam_name] if isinstance(fps, Mapping) else fps)
        if not np.isfinite(rate) or rate <= 0:
            raise CaptureError(f"camera {cam_name}: frame rate must be positive, got {rate}")
        cal = calib.get(cam_name)
        size = cal.image_size if cal is not None else None
        frames = None
        video_rel = None
        if cam_name in video_map:
            vsize, _, vcount = video_info(video_map[cam_name])
            if size is not None and tuple(size) != tuple(vsize):
                raise CaptureError(
                    f"{video_map[cam_name]}: frames are {vsize[0]}x{vsize[1]} but the calibration of camera {cam_name} "
                    f"is for {size[0]}x{size[1]}; calibrate at the video's resolution"
                )
            size, frames = vsize, vcount
            video_rel = f"cameras/{cam_name}/video{video_map[cam_name].suffix.lower()}"
            placements.append((video_map[cam_name], video_rel))
        if size is None:
            hint = f" (calibrated cameras: {', '.join(calib)})" if calib and cal is None else ""
            raise CaptureError(
                f"camera {cam_name}: image size unknown: give its video, or a calibration that states the image size{hint}"
            )
        detectors = {}
        for det_name, fmt_name, kp, boxes in dets.get(cam_name, []):
            try:
                fmt = get_format(fmt_name)
            except MocapgraphError as exc:
                raise CaptureError(f"camera {cam_name}: detector {det_name}: {exc}") from None
            kp = np.asarray(kp, dtype=float)
            if kp.ndim != 3 or kp.shape[1:] != (fmt.num_points, 3):
                raise CaptureError(
                    f"camera {cam_name}: detector {det_name}: keypoints must be (T, {fmt.num_points}, 3), got {kp.shape}"
                )
            if det_name in detectors:
                raise CaptureError(f"camera {cam_name}: detector {det_name!r} given twice")
            if detectors and len(kp) != len(next(iter(detectors.values())).keypoints):
                raise CaptureError(f"camera {cam_name}: its detectors have different frame counts")
            detectors[det_name] = Detector(det_name, fmt.name, kp, None if boxes is None else np.asarray(boxes, dtype=float))
        if detectors:
            det_frames = len(next(iter(detectors.values())).keypoints)
            if frames is not None and det_frames != frames:
                log.warning("camera %s: %d frames of detections, the video says %d; timestamps follow the detections", cam_name, det_frames, frames)
            frames = det_frames
        if frames is None:
            raise CaptureError(f"camera {cam_name}: frame count unknown: give its video or its keypoints")
        if frames == 0:
            raise CaptureError(f"camera {cam_name}: no frames")
        has_pose = cal is not None and cal.world_T_camera is not None
        is_moving = moving.get(cam_name, not has_pose)
        if has_pose and is_moving:
            raise CaptureError(
                f"camera {cam_name}: marked moving but the calibration gives one fixed pose; "
                "drop it from the calibration or do not mark it moving"
            )
        cameras.append(
            Camera(
                name=cam_name,
                K=cal.K if cal is not None else _default_K(size),
                distortion=cal.distortion if cal is not None else np.zeros(5),
                image_size=(int(size[0]), int(size[1])),
                moving=bool(is_moving),
                timestamps=np.arange(frames, dtype=np.float64) / rate,
                frame_rate=rate,
                detectors=detectors,
                extrinsics=cal.world_T_camera[None] if has_pose else None,
            )
        )
    any_pose = any(c.extrinsics is not None for c in cameras)
    meta = {"imported": {"calibrated": sorted(calib), "guessed_intrinsics": [c.name for c in cameras if c.name not in calib]}}
    meta.update(metadata or {})
    capture = Capture(
        name=name or out.name,
        cameras=cameras,
        world_frame="the calibration's world frame, metres" if any_pose else "unspecified",
        metadata=meta,
    )
    if not placements:
        return write_capture(capture, out, overwrite=overwrite)

    def write(tmp: Path) -> None:
        # write_capture validates that every video it lists exists, so the capture is written
        # without videos first; then the videos are placed and the manifest names them.
        import tomli_w

        write_capture(capture, tmp, overwrite=True)
        for source, rel in placements:
            _place_video(source, tmp / rel, video_mode)
        manifest = tmp / MANIFEST
        text = manifest.read_text(encoding="utf-8")
        header = "".join(line + "\n" for line in text.splitlines() if line.startswith("#"))
        doc = tomllib.loads(text)
        video_of = {Path(rel).parent.name: rel for _, rel in placements}
        for entry in doc["cameras"]:
            if entry["name"] in video_of:
                entry["video"] = video_of[entry["name"]]
        manifest.write_text(header + tomli_w.dumps(doc), encoding="utf-8")

    return write_directory_atomically(out, overwrite, write, load_capture, CaptureError)
