"""Camera calibration files: OpenCV FileStorage (YAML / XML / JSON), plain JSON, Pose2Sim and
anipose TOML, and Qualisys ``.qca.txt`` exports, read into :class:`CameraCalibration` records.

``docs/importing.md`` lists the accepted layouts and field names. Every problem with a file raises
one :class:`~mocapgraph.data_tools.io.capture.CaptureError` naming the file and the field (or the
camera).
"""

from __future__ import annotations

import logging
import re
import tomllib
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from mocapgraph.body.rotations import nearest_rotation, rotvec_to_matrix
from mocapgraph.data_tools.io.capture import CaptureError, world_T_camera_from_Rt
from mocapgraph.data_tools.io.checks import check_limit, parse_json, read_text
from mocapgraph.data_tools.io.files import Where

log = logging.getLogger(__name__)

UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
"""Length units a calibration's translations may be in, as metres per unit."""

# Orthonormality error up to which a calibration's rotation is accepted (and projected onto SO(3)):
# hand-written or rounded files rarely hold more than 6 significant digits.
_ROTATION_TOLERANCE = 1e-3

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


def _is_camera(value, path: Path, where: str) -> bool:
    """A table with intrinsics is a camera; one that has a pose or distortion but no intrinsics is
    an error (a camera mocapgraph cannot use); anything else (``[metadata]``) is not a camera."""
    if not isinstance(value, Mapping):
        return False
    if _first(value, _K_KEYS)[0] is not None:
        return True
    found = [key for key in (*_R_KEYS, *_T_KEYS, *_DIST_KEYS) if key in value]
    if found:
        prefix = f"{where}: " if where else ""
        raise CaptureError(
            f"{path}: {prefix}camera without intrinsics (it has {', '.join(found)} but none of {', '.join(_K_KEYS)}); "
            "mocapgraph needs every camera's camera matrix"
        )
    return False


def _cameras_from_tree(tree, path: Path, scale: float) -> list[CameraCalibration]:
    """Find the cameras in a parsed file: one camera at the top, a ``cameras`` list / table, or one
    table per camera (other tables, e.g. ``[metadata]``, are ignored)."""
    if isinstance(tree, Mapping) and "cameras" in tree and not _is_camera(tree, path, ""):
        tree = tree["cameras"]
    cams: list[CameraCalibration] = []
    if isinstance(tree, list):
        for i, entry in enumerate(tree):
            if not _is_camera(entry, path, f"cameras[{i}]"):
                raise CaptureError(f"{path}: cameras[{i}]: not a camera (needs one of {', '.join(_K_KEYS)})")
            cams.append(_camera_from_table(entry, _camera_name(f"cam{i}", entry, strip_prefix=False), path, f"cameras[{i}]", scale))
    elif _is_camera(tree, path, ""):
        cams.append(_camera_from_table(tree, _camera_name(path.stem, tree, strip_prefix=False), path, "", scale))
    elif isinstance(tree, Mapping):
        for key, entry in tree.items():
            if _is_camera(entry, path, str(key)):
                cams.append(_camera_from_table(entry, _camera_name(str(key), entry), path, str(key), scale))
    if not cams:
        raise CaptureError(
            f"{path}: no camera found: expected a camera matrix under one of {', '.join(_K_KEYS)}, at the top "
            "level, in a 'cameras' list or in one table per camera (see docs/importing.md)"
        )
    return _unique_names(cams, path)


def _unique_names(cams: list[CameraCalibration], path: Path) -> list[CameraCalibration]:
    names = [c.name for c in cams]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise CaptureError(f"{path}: camera names must be unique, {duplicates} appear more than once")
    return cams


def _sniff(path: Path, text: str) -> str:
    suffix = path.suffix.lower()
    head = text.lstrip()[:64]
    if path.name.lower().endswith(".qca.txt") or re.match(r"\s*(<\?xml[^>]*\?>\s*)?<calibration[\s>]", text):
        return "qualisys"
    if suffix in (".yml", ".yaml", ".xml"):
        return "filestorage"
    if suffix == ".json":
        return "json"
    if suffix == ".toml":
        return "toml"
    if head.startswith("%YAML") or head.startswith("<?xml") or head.startswith("<opencv_storage"):
        return "filestorage"
    if head.startswith("{") or head.startswith("["):
        # a TOML file may open with a [table] header; JSON lists never hold a bare word
        return "toml" if re.match(r"\[\s*[A-Za-z_][\w.\-\"' ]*\]\s*$", head.splitlines()[0]) else "json"
    return "toml"


def read_calibration(path: str | Path, units: str | None = None) -> list[CameraCalibration]:
    """Read the cameras of a calibration file.

    The format is chosen by extension (``.yml``/``.yaml``/``.xml`` OpenCV FileStorage, ``.json``,
    ``.toml``, ``.qca.txt`` Qualisys) or, for other extensions, by content. ``units`` is the length
    unit of the file's translations (``m``, ``cm`` or ``mm``; default ``m``); they are scaled to
    metres. Qualisys files state millimetres themselves, and any other ``units`` for them is an
    error. Accepted layouts and field names: ``docs/importing.md``.
    """
    path = Path(path)
    if units is not None and units not in UNITS:
        raise CaptureError(f"{path}: unknown units {units!r}; use one of {', '.join(UNITS)}")
    if not path.is_file():
        raise CaptureError(f"{path}: calibration file not found")
    text = read_text(path, CaptureError, "a text file; calibrations are OpenCV YAML/XML/JSON, JSON, TOML or Qualisys .qca.txt")
    kind = _sniff(path, text)
    if kind == "qualisys":
        if units not in (None, "mm"):
            raise CaptureError(f"{path}: Qualisys calibrations are in millimetres and say so; leave out units={units!r}")
        return _in_range(_qualisys_cameras(path), path)
    if kind == "filestorage":
        tree = _filestorage_tree(path)
    elif kind == "json":
        tree = _opencv_matrix(parse_json(text, path, CaptureError))
    else:
        try:
            tree = tomllib.loads(text)
        except RecursionError:
            raise CaptureError(f"{path}: not valid TOML (nested too deeply)") from None
        except tomllib.TOMLDecodeError as exc:
            if path.suffix.lower() == ".toml":
                raise CaptureError(f"{path}: not valid TOML ({exc})") from None
            raise CaptureError(
                f"{path}: unknown calibration format (not OpenCV YAML/XML, JSON, TOML or Qualisys); see docs/importing.md"
            ) from None
    return _in_range(_cameras_from_tree(tree, path, UNITS[units or "m"]), path)


def _in_range(cameras: list[CameraCalibration], path: Path) -> list[CameraCalibration]:
    """The cameras, once their numbers lie in the capture format's physical ranges: refused here,
    naming the calibration file, rather than later against the capture written from it."""
    for cam in cameras:
        where = Where(str(path), cam.name, CaptureError)
        check_limit(cam.K, where("K"), "pixel")
        check_limit(cam.distortion, where("distortion"), "distortion")
        if cam.image_size is not None:
            check_limit(cam.image_size, where("image_size"), "image_size")
        if cam.world_T_camera is not None:
            check_limit(cam.world_T_camera[:3, 3], where("T (its camera centre)"), "position")
    return cameras


def intrinsics_only(cameras: Sequence[CameraCalibration]) -> list[CameraCalibration]:
    """The same cameras without their poses: intrinsics, distortion and image size only, so that a
    pipeline calibrates the extrinsics itself."""
    return [replace(cam, world_T_camera=None) for cam in cameras]


# ---------------------------------------------------------------------------------------------
# Qualisys (QTM's calibration export, ``*.qca.txt``)

QUALISYS_SUBPIXELS = 64
"""QTM states focal lengths and principal points in sub-pixel units of 1/64 pixel."""

# Qualisys' camera frame has y up and z pointing backwards; a half turn about x gives OpenCV's.
_QUALISYS_TO_OPENCV = np.diag([1.0, -1.0, -1.0])


def _xml_numbers(node: ET.Element | None, keys: Sequence[str], path: Path, where: str) -> list[float]:
    if node is None:
        raise CaptureError(f"{path}: {where}: missing")
    values = []
    for key in keys:
        text = node.get(key)
        try:
            value = float(text)
        except (TypeError, ValueError):
            state = "missing" if text is None else f"not a number ({text!r})"
            raise CaptureError(f"{path}: {where}.{key}: {state}") from None
        if not np.isfinite(value):
            raise CaptureError(f"{path}: {where}.{key}: not finite ({text!r})")
        values.append(value)
    return values


def _qualisys_cameras(path: Path) -> list[CameraCalibration]:
    """Cameras of a QTM ``.qca.txt`` export (XML: ``calibration/cameras/camera``, one per camera).

    Per camera, named by its ``serial``:

    - ``intrinsic``: ``focalLengthU/V`` and ``centerPointU/V`` in 1/64 pixel of the full sensor;
      the principal point is shifted by the ``fov_video`` box's ``left, top`` corner, and the
      image size is that box's (QTM records video inside the box).
    - ``radialDistortion1..3``, ``tangentalDistortion1..2``: OpenCV's ``k1, k2, k3, p1, p2`` on
      normalised coordinates, as written (dimensionless, so the 1/64 scale does not apply).
    - ``transform``: ``x, y, z`` is the camera centre in the world, millimetres; ``r11..r33``
      (row ``i``, column ``j``) rotate world vectors into Qualisys' camera frame (y up, z back),
      turned into OpenCV's (y down, z forward) by a half turn about x.
    """
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise CaptureError(f"{path}: not valid XML ({exc})") from None
    if root.tag != "calibration":
        raise CaptureError(f"{path}: expected a Qualisys <calibration> document, found <{root.tag}>")
    cams = []
    for i, node in enumerate(root.findall("cameras/camera")):
        name = node.get("serial") or f"cam{i}"
        where = f"camera {name}"
        if node.get("active", "1").strip() == "0":
            log.warning("%s: camera %s is marked inactive; skipped", path, name)
            continue
        intrinsic = node.find("intrinsic")
        if intrinsic is None:
            raise CaptureError(f"{path}: {where}: no <intrinsic> element; mocapgraph needs every camera's intrinsics")
        fu, fv, cu, cv = (
            v / QUALISYS_SUBPIXELS
            for v in _xml_numbers(intrinsic, ("focalLengthU", "focalLengthV", "centerPointU", "centerPointV"), path, f"{where}: intrinsic")
        )
        if fu <= 0 or fv <= 0:
            raise CaptureError(f"{path}: {where}: intrinsic.focalLengthU/V: must be positive, got {fu * 64:g}, {fv * 64:g}")
        (skew,) = _xml_numbers(intrinsic, ("skew",), path, f"{where}: intrinsic") if intrinsic.get("skew") is not None else (0.0,)
        if skew != 0:
            raise CaptureError(f"{path}: {where}: intrinsic.skew: {skew:g}; only zero skew is supported")
        k1, k2, k3, p1, p2 = _xml_numbers(
            intrinsic, ("radialDistortion1", "radialDistortion2", "radialDistortion3", "tangentalDistortion1", "tangentalDistortion2"),
            path, f"{where}: intrinsic",
        )  # fmt: skip
        left, top, right, bottom = _xml_numbers(node.find("fov_video"), ("left", "top", "right", "bottom"), path, f"{where}: fov_video")
        size = (int(right - left) + 1, int(bottom - top) + 1)
        if size[0] <= 0 or size[1] <= 0 or any(v != int(v) for v in (left, top, right, bottom)):
            raise CaptureError(f"{path}: {where}: fov_video: expected whole pixels with right > left and bottom > top")
        transform = node.find("transform")
        centre = np.array(_xml_numbers(transform, ("x", "y", "z"), path, f"{where}: transform")) * UNITS["mm"]
        M = np.array(_xml_numbers(transform, [f"r{r}{c}" for r in "123" for c in "123"], path, f"{where}: transform")).reshape(3, 3)
        R = _QUALISYS_TO_OPENCV @ _project_rotation(M, path, f"{where}: transform.r11..r33")
        cams.append(
            CameraCalibration(
                name=name,
                K=np.array([[fu, 0.0, cu - left], [0.0, fv, cv - top], [0.0, 0.0, 1.0]]),
                distortion=np.array([k1, k2, p1, p2, k3]),
                image_size=size,
                world_T_camera=world_T_camera_from_Rt(R, -R @ centre),
            )
        )
    if not cams:
        raise CaptureError(f"{path}: no active camera under <cameras>")
    return _unique_names(cams, path)
