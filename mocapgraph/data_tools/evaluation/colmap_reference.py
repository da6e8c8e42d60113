"""A COLMAP reconstruction of a capture's videos: every camera's track as pseudo-ground truth.

:func:`reconstruct` runs pycolmap on the videos, on the CPU: SIFT on every ``frame_step``-th frame
with the person masked out (the detectors' boxes, or their keypoints' box, grown by
:data:`MASK_MARGIN`: a person moves, and the background must be what is matched), matching each
frame with the next ``overlap`` sampled frames of its own video and, every ``keyframe_every``
sampled frames, with the other cameras' frames of the same instant; then incremental mapping
with the capture's intrinsics and distortion held fixed (COLMAP's ``FULL_OPENCV`` model; COLMAP
puts pixel centres at half-integers, so ``cx, cy`` gain 0.5). The largest model is the reference.

COLMAP's world is its own: arbitrary origin, orientation and scale. Compare in it only after a
similarity (``eval --reference``, :mod:`~mocapgraph.data_tools.evaluation.reference_eval`).

A reference is a directory ``<capture>/references/<name>/`` (``docs/capture-format.md``):
``reference.toml`` (source, options, statistics, failures) and ``poses.npz`` (``<camera>.R``,
``<camera>.t`` world→camera per camera frame, NaN where the frame was not sampled or not
registered; ``<camera>.sampled`` bool) and ``points.npz`` (``xyz``, ``error_px``, ``track_length``).
"""

from __future__ import annotations

import logging
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from mocapgraph.data_tools.io.capture import Rt_from_world_T_camera, world_T_camera_from_Rt
from mocapgraph.data_tools.io.files import ArrayFiles, Where, check_array, read_manifest, refuse_existing, require_key, write_directory_atomically, write_manifest
from mocapgraph.errors import MocapgraphError
from mocapgraph.progress import progress_bar

log = logging.getLogger(__name__)

FORMAT_NAME = "mocapgraph-reference"
FORMAT_VERSION = 1
MANIFEST = "reference.toml"
MASK_MARGIN = 0.15
"""The person's box grows by this fraction of its size on every side before it is masked."""
MASK_MARGIN_PX = 8
PARALLAX_CONFIGS = ("CALIBRATED", "UNCALIBRATED")
"""COLMAP's two-view configurations of a pair with a baseline to triangulate from (the others: a
plane's homography, a pure rotation, degenerate)."""


class ReferenceError(MocapgraphError):
    """A reference that cannot be made, read or written; the message says which file or camera."""


@dataclass
class ColmapOptions:
    """How :func:`reconstruct` samples, matches and maps.

    Attributes:
        frame_step: every ``frame_step``-th frame of each video is reconstructed.
        overlap: each sampled frame is matched with this many following sampled frames of its video.
        keyframe_every: every this many sampled frames, all cameras' frames of that instant are
            matched with each other (and with the instant's neighbouring keyframes).
        max_features: SIFT features per image.
        seed: COLMAP's random seed (RANSAC, mapping).
        threads: CPU threads for extraction, matching and mapping.
        init_min_tri_angle_deg: smallest triangulation angle of the first image pair (COLMAP: 16).
    """

    frame_step: int = 3
    overlap: int = 5
    keyframe_every: int = 4
    max_features: int = 4096
    seed: int = 0
    threads: int = 2
    init_min_tri_angle_deg: float = 4.0


@dataclass
class ColmapReference:
    """Every camera's track as COLMAP reconstructed it, in COLMAP's world (arbitrary similarity).

    Attributes:
        name: the reference's name (its folder under ``references/``).
        cameras: per camera, ``(T_c, 4, 4)`` ``world_T_camera`` at each of the camera's frames,
            NaN where the frame was not sampled or not registered.
        sampled: per camera, ``(T_c,)`` bool: the frame was given to COLMAP.
        points: ``(P, 3)`` the reconstructed background points, COLMAP's world.
        point_errors_px: ``(P,)`` mean reprojection error of each point, pixels.
        track_lengths: ``(P,)`` images each point is seen in.
        stats: summary numbers (``registration_rate``, ``mean_reprojection_error_px``,
            ``mean_track_length``, ``points``, seconds per stage, per camera registration).
        failures: one human-readable line per camera or span of frames that did not register.
        options: the :class:`ColmapOptions` used, as a dict.
    """

    name: str
    cameras: dict[str, np.ndarray]
    sampled: dict[str, np.ndarray]
    points: np.ndarray
    point_errors_px: np.ndarray
    track_lengths: np.ndarray
    stats: dict = field(default_factory=dict)
    failures: list[str] = field(default_factory=list)
    options: dict = field(default_factory=dict)

    def groups(self) -> dict[str, int]:
        """Per camera, the COLMAP model its track comes from (0 the largest; -1 none): tracks of
        different models share no world frame."""
        return {c: int(self.stats.get("cameras", {}).get(c, {}).get("model", 0)) for c in self.cameras}

    def registered(self, camera: str) -> np.ndarray:
        """``(T_c,)`` bool: the frame has a reconstructed pose."""
        return np.all(np.isfinite(self.cameras[camera]), axis=(1, 2))


def _pycolmap():
    try:
        import pycolmap
    except ImportError:
        raise ReferenceError("the COLMAP reference needs pycolmap: pip install 'mocapgraph[colmap]'") from None
    return pycolmap


def person_box(detectors: dict, frame: int) -> np.ndarray | None:
    """``(4,)`` x0, y0, x1, y1 pixels around the person at ``frame`` in any of a camera's detectors
    (their boxes, else their keypoints' extent), or None when nothing was detected."""
    found = []
    for det in detectors.values():
        if det.boxes is not None and np.all(np.isfinite(det.boxes[frame, :4])):
            found.append(det.boxes[frame, :4])
            continue
        kp = det.keypoints[frame]
        ok = np.all(np.isfinite(kp[:, :2]), axis=1)
        if ok.sum() >= 2:
            found.append(np.r_[kp[ok, :2].min(axis=0), kp[ok, :2].max(axis=0)])
    if not found:
        return None
    found = np.array(found)
    return np.r_[found[:, :2].min(axis=0), found[:, 2:].max(axis=0)]


def person_mask(detectors: dict, frame: int, image_size: tuple[int, int]) -> np.ndarray:
    """``(H, W)`` uint8: 0 over the person (the :func:`person_box` grown by :data:`MASK_MARGIN`
    and :data:`MASK_MARGIN_PX`), 255 elsewhere: COLMAP extracts features only where it is not 0."""
    width, height = image_size
    mask = np.full((height, width), 255, np.uint8)
    box = person_box(detectors, frame)
    if box is not None:
        grow = MASK_MARGIN * (box[2:] - box[:2]) + MASK_MARGIN_PX
        lo = np.clip(np.floor(box[:2] - grow), 0, [width, height]).astype(int)
        hi = np.clip(np.ceil(box[2:] + grow), 0, [width, height]).astype(int)
        mask[lo[1] : hi[1], lo[0] : hi[0]] = 0
    return mask


def _image_name(camera: str, frame: int) -> str:
    return f"{camera}/{frame:06d}.png"


def camera_videos(capture, cameras: list[str], video_dir: Path | None = None) -> dict[str, Path]:
    """Each camera's video: the capture's ``video`` field, else (or with ``video_dir`` given) the
    file in ``video_dir`` named like the camera (``mocapgraph detect`` names cameras by file stem)."""
    out = {}
    for name in cameras:
        cam = capture.camera(name)
        if video_dir is not None:
            found = sorted(p for p in Path(video_dir).glob(f"{name}.*") if p.is_file())
            if not found:
                raise ReferenceError(f"{video_dir}: no video named {name}.* for camera {name}")
            out[name] = found[0]
        elif cam.video is not None:
            out[name] = Path(capture.path or ".") / cam.video
        else:
            raise ReferenceError(
                f"capture {capture.path}: camera {name} names no video (cameras.{name}.video); pass the folder of the "
                "videos (--videos DIR), or render them for a synthetic capture (synth --render)"
            )
    return out


def _write_frames(capture, videos: dict[str, Path], options: ColmapOptions, images: Path, masks: Path) -> dict[str, np.ndarray]:
    """The sampled frames of every camera's video as PNGs with their masks; returns per camera the
    frame indices written ``(S_c,)``."""
    written = {}
    total = sum(len(range(0, capture.camera(c).num_frames, options.frame_step)) for c in videos)
    bar = progress_bar(total=total, desc="colmap: frames", unit="frame")
    for name, path in videos.items():
        cam = capture.camera(name)
        reader = cv2.VideoCapture(str(path))
        if not reader.isOpened():
            raise ReferenceError(f"{path}: OpenCV cannot open the video of camera {name}")
        (images / name).mkdir(parents=True, exist_ok=True)
        (masks / name).mkdir(parents=True, exist_ok=True)
        frames = []
        try:
            for i in range(cam.num_frames):
                ok, image = reader.read()
                if not ok:
                    log.warning("%s: the video ends at frame %d of the camera's %d", path, i, cam.num_frames)
                    break
                if i % options.frame_step:
                    continue
                if image.shape[1::-1] != tuple(cam.image_size):
                    raise ReferenceError(f"{path}: frames are {image.shape[1]}x{image.shape[0]}, the capture says {cam.image_size[0]}x{cam.image_size[1]} (cameras.{name}.image_size)")
                cv2.imwrite(str(images / _image_name(name, i)), image)
                cv2.imwrite(str(masks / (_image_name(name, i) + ".png")), person_mask(cam.detectors, i, cam.image_size))
                frames.append(i)
                bar.update(1)
        finally:
            reader.release()
        written[name] = np.array(frames, dtype=int)
    bar.close()
    return written


def _pairs(frames: dict[str, np.ndarray], options: ColmapOptions) -> list[tuple[str, str]]:
    """Image pairs to match: each sampled frame with its next ``overlap`` of the same video; at
    keyframes, every pair of cameras at the same frame index and at the neighbouring keyframes
    (cameras of a capture share one clock, frame ``i`` of every camera is about the same instant)."""
    pairs = []
    for name, idx in frames.items():
        for a in range(len(idx)):
            for b in range(a + 1, min(a + 1 + options.overlap, len(idx))):
                pairs.append((_image_name(name, idx[a]), _image_name(name, idx[b])))
    names = list(frames)
    keyframes: dict[str, list[int]] = {n: list(frames[n][:: options.keyframe_every]) for n in names}
    for i, first in enumerate(names):
        for second in names[i + 1 :]:
            for k, fa in enumerate(keyframes[first]):
                for fb in keyframes[second][max(0, k - 1) : k + 2]:
                    pairs.append((_image_name(first, fa), _image_name(second, fb)))
    return pairs


def _colmap_params(cam) -> str:
    """The camera as COLMAP's FULL_OPENCV parameters (pixel centres at half-integers)."""
    k1, k2, p1, p2, k3 = np.asarray(cam.distortion, dtype=float)
    K = cam.K
    return ",".join(f"{v:.12g}" for v in (K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5, k1, k2, p1, p2, k3, 0.0, 0.0, 0.0))


def _spans(frames: np.ndarray) -> str:
    """``[0, 3, 6, 30]`` → ``"0-6, 30"`` (runs of equally spaced frames)."""
    if not len(frames):
        return ""
    out, start, prev = [], frames[0], frames[0]
    step = np.min(np.diff(frames)) if len(frames) > 1 else 1
    for f in frames[1:]:
        if f - prev != step:
            out.append(f"{start}" if start == prev else f"{start}-{prev}")
            start = f
        prev = f
    out.append(f"{start}" if start == prev else f"{start}-{prev}")
    return ", ".join(out)


def reconstruct(
    capture, cameras: list[str] | None = None, options: ColmapOptions = ColmapOptions(), name: str = "colmap",
    work_dir: Path | None = None, video_dir: Path | None = None,
) -> ColmapReference:
    """Reconstruct the capture's camera tracks from its videos with COLMAP (see the module docstring).

    Args:
        capture: a loaded :class:`~mocapgraph.data_tools.io.capture.Capture` whose cameras have videos.
        cameras: which cameras (default all).
        video_dir: a folder with the videos, named like the cameras (default: the capture's own).
        options: sampling, matching and mapping settings.
        work_dir: where COLMAP's images and database go (default a temporary directory, removed).

    Raises:
        ReferenceError: no video, an unreadable video, or nothing to reconstruct (no features, no
            matches, no model): the message names the cameras.
    """
    pycolmap = _pycolmap()
    cameras = list(cameras or [c.name for c in capture.cameras])
    videos = camera_videos(capture, cameras, video_dir)
    if options.frame_step < 1 or options.overlap < 1 or options.keyframe_every < 1:
        raise ReferenceError("frame_step, overlap and keyframe_every must be at least 1")
    pycolmap.set_random_seed(options.seed)
    # COLMAP logs every step to stderr; its messages show only with -v (our DEBUG).
    pycolmap.logging.minloglevel = 0 if log.isEnabledFor(logging.DEBUG) else 2
    temporary = work_dir is None
    work = Path(tempfile.mkdtemp(prefix="mocapgraph-colmap-")) if temporary else Path(work_dir)
    try:
        return _reconstruct_in(pycolmap, capture, videos, options, name, work)
    finally:
        if temporary:
            shutil.rmtree(work, ignore_errors=True)


def _reconstruct_in(pycolmap, capture, videos: dict[str, Path], options: ColmapOptions, name: str, work: Path) -> ColmapReference:
    cameras = list(videos)
    images, masks, database = work / "images", work / "masks", work / "database.db"
    models = work / "models"
    models.mkdir(parents=True, exist_ok=True)
    database.unlink(missing_ok=True)
    seconds = {}
    start = time.perf_counter()
    frames = _write_frames(capture, videos, options, images, masks)
    seconds["frames"] = time.perf_counter() - start

    start = time.perf_counter()
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = options.threads
    extraction.use_gpu = False
    extraction.sift.max_num_features = options.max_features
    for cam_name in progress_bar(cameras, desc="colmap: SIFT", unit="camera"):
        cam = capture.camera(cam_name)
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = "FULL_OPENCV"
        reader.camera_params = _colmap_params(cam)
        reader.mask_path = str(masks)
        pycolmap.extract_features(
            database, images, image_names=[_image_name(cam_name, i) for i in frames[cam_name]],
            camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader, extraction_options=extraction,
            device=pycolmap.Device.cpu,
        )  # fmt: skip
    db = pycolmap.Database.open(str(database))
    try:
        ids = {image.name: image.image_id for image in db.read_all_images()}
        features = {n: db.num_keypoints_for_image(i) for n, i in ids.items()}
    finally:
        db.close()
    seconds["extraction"] = time.perf_counter() - start
    blank = [c for c in cameras if sum(features.get(_image_name(c, i), 0) for i in frames[c]) == 0]
    if blank:
        raise ReferenceError(
            f"capture {capture.path}: no SIFT features in any sampled frame of camera(s) {', '.join(blank)}: "
            "their videos are blank or featureless (nothing to reconstruct from)"
        )

    start = time.perf_counter()
    pairs = _pairs(frames, options)
    pair_file = work / "pairs.txt"
    pair_file.write_text("".join(f"{a} {b}\n" for a, b in pairs))
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = options.threads
    matching.use_gpu = False
    pairing = pycolmap.ImportedPairingOptions()
    pairing.match_list_path = str(pair_file)
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = options.seed
    log.info("colmap: matching %d image pairs", len(pairs))
    pycolmap.match_image_pairs(database, matching_options=matching, pairing_options=pairing, verification_options=verification, device=pycolmap.Device.cpu)
    seconds["matching"] = time.perf_counter() - start
    diagnosis = _match_diagnosis(pycolmap, database, cameras)

    start = time.perf_counter()
    mapping = pycolmap.IncrementalPipelineOptions()
    mapping.num_threads = options.threads
    mapping.random_seed = options.seed
    mapping.ba_refine_focal_length = False
    mapping.ba_refine_principal_point = False
    mapping.ba_refine_extra_params = False
    mapping.mapper.abs_pose_refine_focal_length = False
    mapping.mapper.abs_pose_refine_extra_params = False
    # Video frames are close together: COLMAP's 16° for the first pair rarely exists in a few
    # seconds of a walking camera, and with the intrinsics known a smaller angle is safe.
    mapping.mapper.init_min_tri_angle = options.init_min_tri_angle_deg
    total = sum(len(f) for f in frames.values())
    bar = progress_bar(total=total, desc="colmap: mapping", unit="image")
    reconstructions = pycolmap.incremental_mapping(database, images, models, options=mapping, next_image_callback=lambda: bar.update(1))
    bar.close()
    seconds["mapping"] = time.perf_counter() - start
    if not reconstructions:
        raise ReferenceError(
            f"capture {capture.path}: COLMAP built no model from cameras {', '.join(cameras)} "
            f"({sum(features.values())} SIFT features in {total} frames, {len(pairs)} pairs matched): "
            "too few matches between frames (blank, featureless or too different views)"
        )
    ranked = sorted(reconstructions.values(), key=lambda r: r.num_reg_images(), reverse=True)
    return _reference_from(ranked, capture, cameras, frames, options, name, seconds, total, diagnosis)


def _match_diagnosis(pycolmap, database: Path, cameras: list[str]) -> dict[str, dict]:
    """Per camera, from the pairs COLMAP verified: ``own_pairs`` of its own frames, ``own_parallax``
    of those with a baseline (:data:`PARALLAX_CONFIGS`), ``cross_inliers`` the most inlier matches
    of one of its frames with another camera's."""
    db = pycolmap.Database.open(str(database))
    try:
        owner = {image.image_id: image.name.split("/")[0] for image in db.read_all_images()}
        pair_ids, geometries = db.read_two_view_geometries()
    finally:
        db.close()
    out = {c: {"own_pairs": 0, "own_parallax": 0, "cross_inliers": 0} for c in cameras}
    for pair, geometry in zip(pair_ids, geometries):
        a, b = (owner[i] for i in pycolmap.pair_id_to_image_pair(pair))
        if a == b:
            out[a]["own_pairs"] += 1
            out[a]["own_parallax"] += pycolmap.TwoViewGeometryConfiguration(geometry.config).name in PARALLAX_CONFIGS
        else:
            for c in (a, b):
                out[c]["cross_inliers"] = max(out[c]["cross_inliers"], len(geometry.inlier_matches))
    return out


def _why_unregistered(d: dict) -> str:
    """Why a camera registered nowhere, from its :func:`_match_diagnosis`."""
    why = []
    if d["own_pairs"] and not d["own_parallax"]:
        why.append(f"its own frames show no parallax (COLMAP verified all {d['own_pairs']} pairs of them as a plane or a pure rotation: "
                   "a static or turning camera cannot triangulate on its own)")  # fmt: skip
    elif not d["own_pairs"]:
        why.append("no two of its own frames matched")
    why.append(f"with the other cameras' frames at most {d['cross_inliers']} inlier matches (their views share too little background)")
    return "; ".join(why)


def _reference_from(ranked, capture, cameras, frames, options, name, seconds, total, diagnosis) -> ColmapReference:
    """The reference from COLMAP's models ``ranked`` largest first: each camera's track comes from
    the model holding most of its frames (model 0 for every camera COLMAP connected); a camera
    registered nowhere is explained by its :func:`_match_diagnosis` entry."""
    sampled = {c: np.zeros(capture.camera(c).num_frames, bool) for c in cameras}
    for c in cameras:
        sampled[c][frames[c]] = True
    per_model = []  # per model: {camera: (T_c, 4, 4)}
    for model in ranked:
        poses = {c: np.full((capture.camera(c).num_frames, 4, 4), np.nan) for c in cameras}
        for image in model.images.values():
            if not image.has_pose:
                continue
            cam_name, stem = image.name.split("/")
            cam_from_world = np.vstack([image.cam_from_world().matrix(), [0.0, 0.0, 0.0, 1.0]])
            poses[cam_name][int(stem.split(".")[0])] = np.linalg.inv(cam_from_world)
        per_model.append(poses)
    counts = np.array([[np.all(np.isfinite(p[c]), axis=(1, 2)).sum() for c in cameras] for p in per_model])  # (models, cameras)
    chosen = {c: int(np.argmax(counts[:, k])) for k, c in enumerate(cameras)}  # ties: the larger model
    poses = {c: per_model[chosen[c]][c] for c in cameras}

    failures, per_camera = [], {}
    for c in cameras:
        done = np.all(np.isfinite(poses[c]), axis=(1, 2))
        missing = np.flatnonzero(sampled[c] & ~done)
        per_camera[c] = {
            "sampled": int(sampled[c].sum()), "registered": int(done.sum()),
            "registration_rate": float(done.sum() / max(1, sampled[c].sum())), "model": chosen[c] if done.any() else -1,
        }  # fmt: skip
        if not done.any():
            failures.append(f"camera {c}: none of its {len(missing)} sampled frames registered: {_why_unregistered(diagnosis[c])}")
            continue
        if chosen[c] > 0:
            failures.append(
                f"camera {c}: registered in COLMAP's model {chosen[c]}, not connected to the largest (model 0): "
                "its track is scored alone (Procrustes), never against the other cameras"
            )
        if len(missing):
            failures.append(f"camera {c}: {len(missing)} of {sampled[c].sum()} sampled frames not registered (frames {_spans(missing)})")
    model = ranked[0]
    points = model.points3D
    xyz = np.array([p.xyz for p in points.values()]).reshape(-1, 3)
    errors = np.array([p.error for p in points.values()], dtype=float)
    tracks = np.array([p.track.length() for p in points.values()], dtype=float)
    registered = sum(v["registered"] for v in per_camera.values())
    stats = {
        "registration_rate": registered / max(1, total),
        "registered_frames": registered,
        "sampled_frames": total,
        "mean_reprojection_error_px": float(model.compute_mean_reprojection_error()),
        "mean_track_length": float(model.compute_mean_track_length()),
        "points": int(len(xyz)),
        "models": len(ranked),
        "seconds": {k: float(v) for k, v in seconds.items()},
        "seconds_per_frame": float((seconds["extraction"] + seconds["matching"] + seconds["mapping"]) / max(1, total)),
        "cameras": per_camera,
    }
    for c in cameras:
        per_camera[c].update(diagnosis[c])
    opts = {k: getattr(options, k) for k in ColmapOptions.__dataclass_fields__}
    return ColmapReference(name, poses, sampled, xyz, errors, tracks, stats, failures, opts)


def reference_dir(capture_path: str | Path, name: str) -> Path:
    """Where the reference ``name`` of a capture lives."""
    if not name or "/" in name or name.startswith("."):
        raise ReferenceError(f"reference name {name!r} is not a plain file name")
    return Path(capture_path) / "references" / name


def write_reference(reference: ColmapReference, capture_path: str | Path, overwrite: bool = False) -> Path:
    """Write ``reference`` into the capture at ``capture_path`` (atomically); returns its directory."""
    import pycolmap

    path = reference_dir(capture_path, reference.name)

    def write(tmp: Path) -> None:
        arrays = {}
        for c, poses in reference.cameras.items():
            R, t = Rt_from_world_T_camera(poses)
            arrays[f"{c}.R"], arrays[f"{c}.t"], arrays[f"{c}.sampled"] = R, t, reference.sampled[c]
        np.savez_compressed(tmp / "poses.npz", **arrays)
        np.savez_compressed(tmp / "points.npz", xyz=reference.points, error_px=reference.point_errors_px, track_length=reference.track_lengths)
        doc = {
            "format": FORMAT_NAME, "version": FORMAT_VERSION, "name": reference.name,
            "source": f"COLMAP {pycolmap.COLMAP_version} via pycolmap {pycolmap.__version__}",
            "world_frame": "COLMAP's: arbitrary origin, orientation and scale; align by a similarity before comparing",
            "cameras": list(reference.cameras), "poses": "poses.npz", "points": "points.npz",
            "options": reference.options, "stats": reference.stats, "failures": reference.failures,
        }  # fmt: skip
        write_manifest(tmp / MANIFEST, "reference", "docs/capture-format.md", doc)

    return write_directory_atomically(
        path, overwrite, write, lambda tmp: load_reference(tmp.parent.parent, reference.name, directory=tmp), ReferenceError, replaces=MANIFEST
    )


def load_reference(capture_path: str | Path, name: str, *, directory: Path | None = None) -> ColmapReference:
    """Read the reference ``name`` of the capture at ``capture_path`` (``directory`` overrides where)."""
    path = directory or reference_dir(capture_path, name)
    if not path.exists():
        have = sorted(p.name for p in (Path(capture_path) / "references").glob("*") if p.is_dir() and not p.name.startswith("."))
        raise ReferenceError(f"{path}: the capture has no reference {name!r} (it has: {', '.join(have) or 'none'}; make one with `mocapgraph colmap {capture_path}`)")
    root, doc, where = read_manifest(path, MANIFEST, FORMAT_NAME, FORMAT_VERSION, ReferenceError)
    files = ArrayFiles(root, ReferenceError)
    cams = require_key(doc, "cameras", where, list)
    rel = require_key(doc, "poses", where, str)
    arrays = files.npz(rel, where("poses"), tuple(f"{c}.{k}" for c in cams for k in ("R", "t", "sampled")))
    poses, sampled = {}, {}
    for c in cams:
        R = check_array(arrays[f"{c}.R"], where.at(rel, f"{c}.R"), (None, 3, 3), allow_nan=True)
        t = check_array(arrays[f"{c}.t"], where.at(rel, f"{c}.t"), (R.shape[0], 3), allow_nan=True)
        poses[c] = world_T_camera_from_Rt(R, t)
        poses[c][~(np.all(np.isfinite(R), axis=(1, 2)) & np.all(np.isfinite(t), axis=1))] = np.nan  # the whole pose, not only R and t
        sampled[c] = np.asarray(arrays[f"{c}.sampled"], dtype=bool)
        if sampled[c].shape != (R.shape[0],):
            raise where.at(rel, f"{c}.sampled").fail(f"expected ({R.shape[0]},) booleans, got {sampled[c].shape}")
    prel = require_key(doc, "points", where, str)
    pts = files.npz(prel, where("points"), ("xyz", "error_px", "track_length"))
    xyz = check_array(pts["xyz"], Where(prel, "xyz", ReferenceError), (None, 3))
    return ColmapReference(
        str(doc.get("name", name)), poses, sampled, xyz,
        check_array(pts["error_px"], Where(prel, "error_px", ReferenceError), (len(xyz),)),
        check_array(pts["track_length"], Where(prel, "track_length", ReferenceError), (len(xyz),)),
        dict(doc.get("stats", {})), list(doc.get("failures", [])), dict(doc.get("options", {})),
    )  # fmt: skip


def check_writable(capture_path: str | Path, name: str, overwrite: bool) -> None:
    """Refuse before a long run when the reference exists and ``overwrite`` is not given."""
    refuse_existing(reference_dir(capture_path, name), overwrite, ReferenceError)
