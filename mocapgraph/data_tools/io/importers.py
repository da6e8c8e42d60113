"""Bringing other tools' output into a capture: videos, detections and a calibration.

``docs/importing.md`` lists every accepted format with examples. The readers live next to this
module: :mod:`~mocapgraph.data_tools.io.keypoint_files` (OpenPose-style JSON folders, keypoint
arrays), :mod:`~mocapgraph.data_tools.io.calibration` (calibration files) and
:mod:`~mocapgraph.data_tools.io.pose2sim` (Pose2Sim project folders). Here:

- :func:`video_info` reads a video's size, frame rate and frame count;
- :func:`assemble_capture` writes a capture from videos, detections and a calibration.

Every problem with an input file raises one :class:`~mocapgraph.data_tools.io.capture.CaptureError`
that names the file (and the field, where there is one).
"""

from __future__ import annotations

import logging
import os
import shutil
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.data_tools.io.calibration import CameraCalibration
from mocapgraph.data_tools.io.capture import (
    MANIFEST,
    Camera,
    Capture,
    CaptureError,
    Detector,
    load_capture,
    write_capture,
)
from mocapgraph.data_tools.io.files import write_directory_atomically
from mocapgraph.errors import MocapgraphError

log = logging.getLogger(__name__)

DEFAULT_FOCAL_FACTOR = 1.2
"""Uncalibrated cameras get ``f = DEFAULT_FOCAL_FACTOR × max(width, height)`` pixels (a field of view
of about 45° across the longer side, typical of phone and action cameras in their normal mode)."""


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
    A ``source`` that is itself a symbolic link is followed (a hard link to the link would be one).
    """
    target.parent.mkdir(parents=True, exist_ok=True)
    source = source.resolve()
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


def _check_equal_length(cameras: Sequence[Camera]) -> None:
    spans = np.array([c.num_frames / c.frame_rate for c in cameras])
    slack = 1.0 / min(c.frame_rate for c in cameras)
    if spans.max() - spans.min() > slack + 1e-9:
        listing = "; ".join(f"{c.name}: {c.num_frames} frames at {c.frame_rate:g} fps = {s:.3f} s" for c, s in zip(cameras, spans))
        raise CaptureError(
            f"the cameras cover different lengths of time ({listing}); trim them to the same span, or give each "
            "camera its true frame rate (capture import: --fps CAMERA=F), or keep them as they are (--allow-unequal-length)"
        )


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
    require_equal_length: bool = False,
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
        require_equal_length: refuse cameras whose spans (frames / frame rate) differ by more than
            one frame of the slowest camera, naming every camera's frames, rate and span: cameras
            recording one scene cover the same time, so a longer one is a wrong file or frame rate.

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
    if require_equal_length:
        _check_equal_length(cameras)
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

    return write_directory_atomically(out, overwrite, write, load_capture, CaptureError, replaces=MANIFEST)
