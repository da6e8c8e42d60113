"""The capture format: what every pipeline reads (``docs/capture-format.md`` documents each field).

A capture is a directory with a ``capture.toml`` manifest and array files (``.npy`` / ``.npz``).
:func:`load_capture` validates everything on read and raises one :class:`CaptureError` naming
the file and the field. The one thing it repairs instead of refusing is a recorded time axis that
is not strictly increasing (camera timestamps, sensor sample times): it drops the samples that are
not later than an earlier one and says so in :attr:`Capture.notes`. :func:`write_capture` writes
into a temporary directory and renames it into place, so a crash never leaves a half-written
capture where a good one was; it refuses what the loader would have to repair.

In memory, camera poses are ``world_T_camera (…, 4, 4)`` (OpenCV camera: x right, y down,
z forward; the convention of ``gtsam.PinholeCamera``). Files store ``R, t`` world→camera
(``x_cam = R x_world + t``), as OpenCV does.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.labelling import SWAP_KINDS
from mocapgraph.data_tools.io.checks import check_limit, check_number, table_list, warn_unknown_keys
from mocapgraph.data_tools.io.files import (
    ArrayFiles,
    Where,
    check_array,
    check_increasing,
    check_rotations,
    read_manifest,
    require_key,
    write_directory_atomically,
    write_manifest,
)
from mocapgraph.errors import MocapgraphError

FORMAT_NAME = "mocapgraph-capture"
FORMAT_VERSION = 1
MANIFEST = "capture.toml"

# Arrays each sensor log must hold, with their trailing shapes (N leading rows, one per sample).
SENSOR_FIELDS: dict[str, dict[str, tuple[int, ...]]] = {
    "gps": {"t": (), "position": (3,), "sigma": (3,)},
    "imu": {"t": (), "accel": (3,), "gyro": (3,)},
    "baro": {"t": (), "altitude": (), "sigma": ()},
    "self_pose": {"t": (), "rotation": (3, 3), "position": (3,)},
}
# The physical range (a key of checks.LIMITS) of each sensor array other than times and rotations.
_SENSOR_LIMITS = {"position": "position", "sigma": "sigma_m", "accel": "accel", "gyro": "gyro", "altitude": "altitude"}

# Keys of the manifest's tables; anything else draws a warning naming the nearest of these.
_TOP_KEYS = ("format", "version", "name", "world_frame", "cameras", "ground_truth")
_CAMERA_KEYS = (
    "name", "K", "image_size", "distortion", "moving", "frame_rate", "timestamps", "detectors", "extrinsics", "mount", "sensors", "video",
)  # fmt: skip
_DETECTOR_KEYS = ("name", "format", "file")
_SENSOR_KEYS = ("kind", "file")
_GROUND_TRUTH_KEYS = ("body_model", "body", "cameras", "swaps")


class CaptureError(MocapgraphError):
    """A capture that cannot be read or written; the message names the file and the field."""


@dataclass
class Detector:
    """One 2D detector's output for one camera.

    Attributes:
        name: unique per camera (e.g. ``"openpose"``).
        format: keypoint format of the registry (``coco17``, ``openpose25``, ``blazepose33``, …).
        keypoints: ``(T_c, K, 3)`` pixels x, y and confidence in [0, 1]; NaN rows = missing.
        boxes: ``(T_c, 5)`` person box x0, y0, x1, y1 (pixels) and score, NaN when none; or None.
    """

    name: str
    format: str
    keypoints: np.ndarray
    boxes: np.ndarray | None = None


@dataclass
class Camera:
    """One camera of a capture.

    Attributes:
        name: unique, a plain file name (it names the camera's folder).
        K: ``(3, 3)`` intrinsic matrix, pixels.
        distortion: ``(5,)`` OpenCV ``k1, k2, p1, p2, k3``.
        image_size: ``(width, height)`` pixels.
        moving: whether the camera moves during the capture.
        timestamps: ``(T_c,)`` float64 seconds of each frame, strictly increasing.
        frame_rate: nominal frames per second.
        detectors: by name.
        extrinsics: known ``world_T_camera`` from a calibration, ``(1, 4, 4)`` (static) or
            ``(T_c, 4, 4)``; None when uncalibrated. Not ground truth.
        mount: ``(4, 4)`` vehicle_T_camera for cameras on a vehicle with sensors, else None.
        sensors: sensor logs by kind (keys of :data:`SENSOR_FIELDS`), each a dict of arrays.
        video: path of the camera's video relative to the capture directory, or None.
    """

    name: str
    K: np.ndarray
    distortion: np.ndarray
    image_size: tuple[int, int]
    moving: bool
    timestamps: np.ndarray
    frame_rate: float
    detectors: dict[str, Detector] = field(default_factory=dict)
    extrinsics: np.ndarray | None = None
    mount: np.ndarray | None = None
    sensors: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    video: str | None = None

    @property
    def num_frames(self) -> int:
        return len(self.timestamps)


@dataclass
class GroundTruth:
    """What really happened (synthetic captures, or a reference system).

    Attributes:
        body_model: backend name the body parameters refer to (``anny``, ``smpl``, …).
        timestamps: ``(T,)`` seconds of the body states.
        root: ``(T, 4, 4)`` world_T_root.
        pose: ``(T, 21, 3)`` local axis-angle.
        shape: ``(S,)``.
        joints: ``(T, 22, 3)`` world, metres.
        cameras: per camera name, ``(T_c, 4, 4)`` world_T_camera at that camera's timestamps.
        swaps: per camera name and detector name, ``(T_c,)`` int8 code of the left/right swap in
            that detector's keypoints at each frame (``SWAP_KINDS.index(kind)`` of
            :mod:`mocapgraph.body.labelling`; 0 = labels as true); empty when unknown (optional,
            captures written before it existed load without it).
    """

    body_model: str
    timestamps: np.ndarray
    root: np.ndarray
    pose: np.ndarray
    shape: np.ndarray
    joints: np.ndarray
    cameras: dict[str, np.ndarray] = field(default_factory=dict)
    swaps: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)


@dataclass
class Capture:
    """A multi-camera recording: cameras with detections and sensors, optional ground truth.

    Attributes:
        name: short identifier.
        cameras: in manifest order.
        world_frame: what the world frame of extrinsics, sensors and ground truth is
            (e.g. ``"ENU, metres, origin at the first GPS fix"``).
        ground_truth: or None.
        metadata: free-form manifest entries (generator, seed, scenario, …).
        path: the directory it was loaded from, or None.
        notes: human-readable repairs made while loading (e.g. frames dropped because a camera's
            timestamps go backwards); empty for a clean capture.
    """

    name: str
    cameras: list[Camera]
    world_frame: str = "unspecified"
    ground_truth: GroundTruth | None = None
    metadata: dict = field(default_factory=dict)
    path: Path | None = None
    notes: list[str] = field(default_factory=list)

    def camera(self, name: str) -> Camera:
        for cam in self.cameras:
            if cam.name == name:
                return cam
        raise CaptureError(f"capture {self.name!r} has no camera {name!r} (cameras: {', '.join(c.name for c in self.cameras)})")


# ---------------------------------------------------------------------------------------------
# Pose conversion between memory (world_T_camera) and files (R, t world→camera)


def world_T_camera_from_Rt(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``R (…, 3, 3), t (…, 3)`` world→camera → ``world_T_camera (…, 4, 4)``."""
    out = np.zeros(R.shape[:-2] + (4, 4))
    Rt = np.swapaxes(R, -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    out[..., 3, 3] = 1.0
    return out


def Rt_from_world_T_camera(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``world_T_camera (…, 4, 4)`` → ``R (…, 3, 3), t (…, 3)`` world→camera."""
    R = np.swapaxes(T[..., :3, :3], -1, -2)
    return R, -np.einsum("...ij,...j->...i", R, T[..., :3, 3])


# ---------------------------------------------------------------------------------------------
# Reading


def load_capture(path: str | Path, *, repair: bool = True) -> Capture:
    """Read and validate a capture directory (or its ``capture.toml``).

    Recorded time axes (a camera's timestamps, a sensor's sample times) that are not strictly
    increasing are repaired: only samples later than every earlier one are kept, in every array of
    that camera or sensor (and in the ground-truth poses of that camera), and ``Capture.notes``
    says what was dropped. With ``repair=False`` they are refused like any other bad field.
    """
    root, doc, where = read_manifest(path, MANIFEST, FORMAT_NAME, FORMAT_VERSION, CaptureError)
    files = ArrayFiles(root, CaptureError)
    warn_unknown_keys(doc, _TOP_KEYS, where, free_form=True)  # the rest is the user's metadata
    _check_imported(doc.get("imported"), where("imported"))
    cams = require_key(doc, "cameras", where, list)
    if not cams:
        raise where("cameras").fail("a capture needs at least one camera")
    notes: list[str] | None = [] if repair else None
    cameras, kept = [], {}
    for i, c in enumerate(cams):
        cam, keep = _read_camera(c, where(f"cameras[{i}]"), files, notes)
        cameras.append(cam)
        if keep is not None:
            kept[cam.name] = keep
    names = [c.name for c in cameras]
    if len(set(names)) != len(names):
        raise where("cameras").fail(f"camera names must be unique, got {names}")
    gt = None
    if "ground_truth" in doc:
        gt = _read_ground_truth(doc["ground_truth"], where("ground_truth"), files, cameras, kept)
    metadata = {k: v for k, v in doc.items() if k not in ("format", "version", "name", "world_frame", "cameras", "ground_truth")}
    return Capture(
        name=str(doc.get("name", root.name)),
        cameras=cameras,
        world_frame=str(doc.get("world_frame", "unspecified")),
        ground_truth=gt,
        metadata=metadata,
        path=root,
        notes=notes or [],
    )


def _check_imported(imported, where: Where) -> None:
    """The importer's record (``[imported]``), where the pipelines read ``guessed_intrinsics``."""
    if imported is None:
        return
    if not isinstance(imported, dict):
        raise where.fail(f"expected a table, got {type(imported).__name__}")
    guessed = imported.get("guessed_intrinsics", [])
    if not isinstance(guessed, list) or not all(isinstance(g, str) for g in guessed):
        raise where("guessed_intrinsics").fail("expected a list of camera names")


def _increasing_part(t: np.ndarray, where: Where, notes: list[str] | None, what: str, unit: str) -> np.ndarray | None:
    """Which samples of a recorded time axis ``t (N,)`` to keep: a mask ``(N,)``, or None for all.

    A sample is kept when it is strictly later than every earlier one, so a clock that jumps back
    loses its samples until it passes its earlier maximum again, and a repeated time loses the
    later copy; what remains is strictly increasing. The repair is described in ``notes``
    (``what`` names the axis, ``unit`` its samples); with ``notes`` None, ``t`` must already be
    strictly increasing.
    """
    if notes is None or t.size == 0:
        check_increasing(t, where)
        return None
    # The running maximum of all earlier samples is a kept sample (its first occurrence is).
    keep = t > np.maximum.accumulate(np.r_[-np.inf, t[:-1]])
    check_increasing(t[keep], where)  # what is left must be a usable clock
    if keep.all():
        return None
    i = int(np.argmin(keep))  # every sample before i is kept, so t[i - 1] is the maximum it fails
    if t[i] == t[i - 1]:
        how = f"repeat at {unit} {i} ({t[i]:.3f} s twice)"
    else:
        now, before = _distinct_seconds(t[i], t[i - 1])
        how = f"go backwards at {unit} {i} ({now} s after {before} s)"
    dropped = int(len(t) - keep.sum())
    notes.append(
        f"{what} ({where.file}) {how}; dropped {dropped} of {len(t)} {unit}s that were not later than an earlier {unit}"
    )
    return keep


def _distinct_seconds(a: float, b: float) -> tuple[str, str]:
    """Two different times printed with 3 decimals, or as many more as it takes to tell them apart."""
    for digits in range(3, 10):
        if f"{a:.{digits}f}" != f"{b:.{digits}f}":
            break
    return f"{a:.{digits}f}", f"{b:.{digits}f}"


def _read_camera(doc, where: Where, files: ArrayFiles, notes: list[str] | None) -> tuple[Camera, np.ndarray | None]:
    """The camera described by manifest table ``doc``, and which of its file's frames it kept.

    Arrays are validated against the frame count of the files; when the timestamps need a repair
    (:func:`_increasing_part`) every per-frame array then keeps the same frames, and the mask
    ``(T_file,)`` is returned (else None) so that the ground-truth poses can do the same.
    """
    if not isinstance(doc, dict):
        raise where.fail("expected a table")
    name = require_key(doc, "name", where, str)
    if not name or "/" in name or "\\" in name or "\0" in name or name.startswith(".") or len(name.encode()) > 200:
        raise where("name").fail(f"{name!r} is not a plain file name")
    where = Where(where.file, f"cameras.{name}", CaptureError)
    warn_unknown_keys(doc, _CAMERA_KEYS, where)
    K = check_array(require_key(doc, "K", where, list), where("K"), (3, 3), limit="pixel")
    if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0, 0, 1]):
        raise where("K").fail("needs fx > 0, fy > 0 and a last row [0, 0, 1]")
    size = require_key(doc, "image_size", where, list)
    if len(size) != 2:
        raise where("image_size").fail(f"expected [width, height] in pixels, got {size}")
    for i, s in enumerate(size):
        check_number(s, where(f"image_size[{i}]"), "image_size", integer=True)
    distortion = check_array(doc.get("distortion", [0.0] * 5), where("distortion"), (5,), limit="distortion")
    moving = require_key(doc, "moving", where, bool)
    rate = float(check_number(require_key(doc, "frame_rate", where), where("frame_rate"), "frame_rate"))
    ts_file = require_key(doc, "timestamps", where, str)
    timestamps = check_array(files.npy(ts_file, where("timestamps")), where.at(ts_file, "timestamps"), (None,))
    keep = _increasing_part(timestamps, where.at(ts_file, "timestamps"), notes, f"camera {name}: timestamps", "frame")
    T = len(timestamps)

    detectors = {}
    for i, det in enumerate(table_list(doc, "detectors", where)):
        d = _read_detector(det, where(f"detectors[{i}]"), files, T)
        if d.name in detectors:
            raise where("detectors").fail(f"detector name {d.name!r} appears twice")
        detectors[d.name] = d

    extrinsics = None
    if "extrinsics" in doc:
        rel = require_key(doc, "extrinsics", where, str)
        arrays = files.npz(rel, where("extrinsics"), ("R", "t"))
        R = check_array(arrays["R"], where.at(rel, "R"), (None, 3, 3))
        t = check_array(arrays["t"], where.at(rel, "t"), (R.shape[0], 3), limit="position")
        if R.shape[0] not in (1, T):
            raise where.at(rel, "R").fail(f"needs 1 (static) or {T} (one per frame) poses, got {R.shape[0]}")
        check_rotations(R, where.at(rel, "R"))
        extrinsics = world_T_camera_from_Rt(R, t)

    mount = None
    if "mount" in doc:
        mount = check_array(doc["mount"], where("mount"), (4, 4))
        check_rotations(mount[:3, :3], where("mount"))
        check_limit(mount[:3, 3], where("mount"), "position")
        if not np.array_equal(mount[3], [0.0, 0.0, 0.0, 1.0]):
            raise where("mount").fail(f"the last row must be [0, 0, 0, 1], got {mount[3].tolist()}")

    sensors = {}
    for i, sensor in enumerate(table_list(doc, "sensors", where)):
        kind, arrays = _read_sensor(sensor, where(f"sensors[{i}]"), files, notes, name)
        if kind in sensors:
            raise where("sensors").fail(f"sensor kind {kind!r} appears twice")
        sensors[kind] = arrays

    video = doc.get("video")
    if video is not None:
        files.resolve(require_key(doc, "video", where, str), where("video"))
    camera = Camera(
        name=name,
        K=K,
        distortion=distortion,
        image_size=(size[0], size[1]),
        moving=moving,
        timestamps=timestamps,
        frame_rate=rate,
        detectors=detectors,
        extrinsics=extrinsics,
        mount=mount,
        sensors=sensors,
        video=video,
    )
    if keep is None:
        return camera, None
    if video is not None:
        # Frame i of a camera is frame i of its video, and the format has no other mapping: after
        # dropping frames the video would sit out of step with the detections and timestamps.
        # Nothing in the pipelines reads the video, so the camera keeps its data without it.
        notes.append(f"camera {name}: its video {video} no longer matches the kept frames one to one; left out")
    return _keep_frames(camera, keep), keep


def _keep_frames(camera: Camera, keep: np.ndarray) -> Camera:
    """``camera`` with only the frames where ``keep (T_c,)`` is true, in every per-frame array.

    A static ``(1, 4, 4)`` calibration stays: ``keep`` only exists for two or more frames.
    """
    per_frame = camera.extrinsics is not None and len(camera.extrinsics) == len(keep)
    return replace(
        camera,
        timestamps=camera.timestamps[keep],
        detectors={
            name: replace(det, keypoints=det.keypoints[keep], boxes=None if det.boxes is None else det.boxes[keep])
            for name, det in camera.detectors.items()
        },
        extrinsics=camera.extrinsics[keep] if per_frame else camera.extrinsics,
        video=None,
    )


def _read_detector(doc, where: Where, files: ArrayFiles, frames: int) -> Detector:
    if not isinstance(doc, dict):
        raise where.fail("expected a table")
    warn_unknown_keys(doc, _DETECTOR_KEYS, where)
    name = require_key(doc, "name", where, str)
    fmt_name = require_key(doc, "format", where, str)
    try:
        fmt = get_format(fmt_name)
    except MocapgraphError as exc:
        raise where("format").fail(str(exc)) from None
    rel = require_key(doc, "file", where, str)
    arrays = files.npz(rel, where("file"), ("keypoints",))
    kp = check_array(arrays["keypoints"], where.at(rel, "keypoints"), (frames, fmt.num_points, 3), allow_nan=True, limit="pixel")
    conf = kp[..., 2][np.isfinite(kp[..., 2])]
    if np.any((conf < 0) | (conf > 1)):
        raise where.at(rel, "keypoints").fail("confidences must lie in [0, 1] (missing points are NaN, never 0)")
    boxes = None
    if "boxes" in arrays:
        boxes = check_array(arrays["boxes"], where.at(rel, "boxes"), (frames, 5), allow_nan=True, limit="pixel")
    return Detector(name=name, format=fmt.name, keypoints=kp, boxes=boxes)


def _read_sensor(
    doc, where: Where, files: ArrayFiles, notes: list[str] | None, camera: str
) -> tuple[str, dict[str, np.ndarray]]:
    """A sensor log of ``camera``: its kind and arrays ``(N, …)``, repaired like the timestamps."""
    if not isinstance(doc, dict):
        raise where.fail("expected a table")
    warn_unknown_keys(doc, _SENSOR_KEYS, where)
    kind = require_key(doc, "kind", where, str)
    if kind not in SENSOR_FIELDS:
        raise where("kind").fail(f"unknown sensor kind {kind!r}; known: {', '.join(SENSOR_FIELDS)}")
    rel = require_key(doc, "file", where, str)
    spec = SENSOR_FIELDS[kind]
    raw = files.npz(rel, where("file"), tuple(spec))
    t = check_array(raw["t"], where.at(rel, "t"), (None,))
    keep = _increasing_part(t, where.at(rel, "t"), notes, f"camera {camera}: {kind} sample times", "sample")
    arrays = {k: check_array(raw[k], where.at(rel, k), (len(t), *trailing), limit=_SENSOR_LIMITS.get(k)) for k, trailing in spec.items()}
    if kind == "self_pose":
        check_rotations(arrays["rotation"], where.at(rel, "rotation"))
    if keep is not None:
        arrays = {k: a[keep] for k, a in arrays.items()}
    return kind, arrays


def _read_ground_truth(
    doc, where: Where, files: ArrayFiles, cameras: list[Camera], kept: dict[str, np.ndarray]
) -> GroundTruth:
    """The ground truth; a camera's poses keep the frames ``kept[name] (T_file,)`` when given.

    The body's timestamps are generated, not recorded, so they must be strictly increasing.
    """
    if not isinstance(doc, dict):
        raise where.fail("expected a table")
    warn_unknown_keys(doc, _GROUND_TRUTH_KEYS, where)
    body_model = require_key(doc, "body_model", where, str)
    rel = require_key(doc, "body", where, str)
    body = files.npz(rel, where("body"), ("timestamps", "R", "t", "pose", "shape", "joints"))
    ts = check_array(body["timestamps"], where.at(rel, "timestamps"), (None,))
    check_increasing(ts, where.at(rel, "timestamps"))
    T = len(ts)
    R = check_array(body["R"], where.at(rel, "R"), (T, 3, 3))
    check_rotations(R, where.at(rel, "R"))
    root = np.tile(np.eye(4), (T, 1, 1))
    root[:, :3, :3] = R
    root[:, :3, 3] = check_array(body["t"], where.at(rel, "t"), (T, 3), limit="position")
    pose = check_array(body["pose"], where.at(rel, "pose"), (T, 21, 3), limit="body_parameter")
    shape = check_array(body["shape"], where.at(rel, "shape"), (None,), limit="body_parameter")
    joints = check_array(body["joints"], where.at(rel, "joints"), (T, 22, 3), limit="position")
    cams = {}
    if "cameras" in doc:
        crel = require_key(doc, "cameras", where, str)
        arrays = files.npz(crel, where("cameras"), ())
        for cam in cameras:
            if f"{cam.name}.R" not in arrays:
                continue
            keep = kept.get(cam.name)
            frames = cam.num_frames if keep is None else len(keep)  # the count in the files
            Rc = check_array(arrays[f"{cam.name}.R"], where.at(crel, f"{cam.name}.R"), (frames, 3, 3))
            if f"{cam.name}.t" not in arrays:
                raise where.at(crel, f"{cam.name}.t").fail(f"missing (given with {cam.name}.R)")
            tc = check_array(arrays[f"{cam.name}.t"], where.at(crel, f"{cam.name}.t"), (frames, 3), limit="position")
            check_rotations(Rc, where.at(crel, f"{cam.name}.R"))
            poses = world_T_camera_from_Rt(Rc, tc)
            cams[cam.name] = poses if keep is None else poses[keep]
        # Camera names may hold dots ("cam.1"): a key is known when it is <camera>.R or <camera>.t.
        unknown = set(arrays) - {f"{c.name}.{k}" for c in cameras for k in ("R", "t")}
        if unknown:
            raise where.at(crel).fail(f"arrays for unknown cameras (or fields): {sorted(unknown)}")
    swaps = _read_swaps(doc, where, files, cameras, kept) if "swaps" in doc else {}
    return GroundTruth(body_model, ts, root, pose, shape, joints, cams, swaps)


def _read_swaps(doc, where: Where, files: ArrayFiles, cameras: list[Camera], kept: dict[str, np.ndarray]) -> dict:
    """The ground truth's swap codes, ``{camera: {detector: (T_c,) int8}}``, keyed
    ``<camera>.<detector>`` in their file; a camera's codes keep the frames ``kept[name]``."""
    rel = require_key(doc, "swaps", where, str)
    arrays = files.npz(rel, where("swaps"), ())
    expected = {f"{cam.name}.{det}": cam for cam in cameras for det in cam.detectors}
    unknown = sorted(set(arrays) - set(expected))
    if unknown:
        raise where.at(rel).fail(f"swap codes for unknown camera detectors {unknown}")
    out: dict[str, dict[str, np.ndarray]] = {}
    for key, cam in expected.items():
        if key not in arrays:
            continue
        keep = kept.get(cam.name)
        frames = cam.num_frames if keep is None else len(keep)
        raw = np.asarray(arrays[key])
        if raw.shape != (frames,) or not np.issubdtype(raw.dtype, np.integer):
            raise where.at(rel, key).fail(f"expected ({frames},) integers, got {raw.dtype} {raw.shape}")
        if np.any((raw < 0) | (raw >= len(SWAP_KINDS))):
            raise where.at(rel, key).fail(f"swap codes must lie in 0..{len(SWAP_KINDS) - 1} ({', '.join(SWAP_KINDS)})")
        codes = raw.astype(np.int8)
        out.setdefault(cam.name, {})[key[len(cam.name) + 1 :]] = codes if keep is None else codes[keep]
    return out


# ---------------------------------------------------------------------------------------------
# Writing


def write_capture(capture: Capture, path: str | Path, overwrite: bool = False, extra_files=None) -> Path:
    """Write ``capture`` as a directory at ``path``, atomically; returns the path.

    Everything goes into a temporary sibling directory that replaces ``path`` only when complete.
    The capture is validated by reading the temporary copy back before it is moved into place,
    without repairs: a written capture never needs one. ``extra_files(tmp)``, when given, runs
    first and writes files the manifest refers to (e.g. rendered videos), setting the capture's
    fields that name them.
    """

    def write(tmp: Path) -> None:
        if extra_files is not None:
            extra_files(tmp)
        _write_into(capture, tmp)

    return write_directory_atomically(
        Path(path),
        overwrite,
        write,
        lambda tmp: load_capture(tmp, repair=False),
        CaptureError,
        replaces=MANIFEST,
    )


def _write_into(capture: Capture, root: Path) -> None:
    doc: dict = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "name": capture.name,
        "world_frame": capture.world_frame,
        **capture.metadata,
        "cameras": [],
    }
    for cam in capture.cameras:
        folder = root / "cameras" / cam.name
        folder.mkdir(parents=True, exist_ok=True)
        rel = f"cameras/{cam.name}"
        np.save(folder / "timestamps.npy", np.asarray(cam.timestamps, dtype=np.float64))
        entry = {
            "name": cam.name,
            "image_size": [int(cam.image_size[0]), int(cam.image_size[1])],
            "K": np.asarray(cam.K, dtype=float).tolist(),
            "distortion": np.asarray(cam.distortion, dtype=float).tolist(),
            "moving": bool(cam.moving),
            "frame_rate": float(cam.frame_rate),
            "timestamps": f"{rel}/timestamps.npy",
        }
        if cam.video is not None:
            entry["video"] = cam.video
        if cam.mount is not None:
            entry["mount"] = np.asarray(cam.mount, dtype=float).tolist()
        if cam.extrinsics is not None:
            R, t = Rt_from_world_T_camera(np.asarray(cam.extrinsics, dtype=float))
            np.savez(folder / "extrinsics.npz", R=R, t=t)
            entry["extrinsics"] = f"{rel}/extrinsics.npz"
        entry["detectors"] = []
        for det in cam.detectors.values():
            arrays = {"keypoints": np.asarray(det.keypoints, dtype=float)}
            if det.boxes is not None:
                arrays["boxes"] = np.asarray(det.boxes, dtype=float)
            np.savez_compressed(folder / f"detector_{det.name}.npz", **arrays)
            entry["detectors"].append({"name": det.name, "format": det.format, "file": f"{rel}/detector_{det.name}.npz"})
        entry["sensors"] = []
        for kind, arrays in cam.sensors.items():
            (folder / "sensors").mkdir(exist_ok=True)
            np.savez_compressed(folder / "sensors" / f"{kind}.npz", **arrays)
            entry["sensors"].append({"kind": kind, "file": f"{rel}/sensors/{kind}.npz"})
        doc["cameras"].append(entry)
    gt = capture.ground_truth
    if gt is not None:
        (root / "ground_truth").mkdir()
        np.savez_compressed(
            root / "ground_truth" / "body.npz",
            timestamps=gt.timestamps, R=gt.root[:, :3, :3], t=gt.root[:, :3, 3],
            pose=gt.pose, shape=gt.shape, joints=gt.joints,
        )  # fmt: skip
        doc["ground_truth"] = {"body_model": gt.body_model, "body": "ground_truth/body.npz"}
        if gt.cameras:
            arrays = {}
            for name, poses in gt.cameras.items():
                arrays[f"{name}.R"], arrays[f"{name}.t"] = Rt_from_world_T_camera(np.asarray(poses, dtype=float))
            np.savez_compressed(root / "ground_truth" / "cameras.npz", **arrays)
            doc["ground_truth"]["cameras"] = "ground_truth/cameras.npz"
        if gt.swaps:
            codes = {f"{cam}.{det}": np.asarray(c, dtype=np.int8) for cam, by_det in gt.swaps.items() for det, c in by_det.items()}
            np.savez_compressed(root / "ground_truth" / "swaps.npz", **codes)
            doc["ground_truth"]["swaps"] = "ground_truth/swaps.npz"
    write_manifest(root / MANIFEST, "capture", "docs/capture-format.md", doc)
