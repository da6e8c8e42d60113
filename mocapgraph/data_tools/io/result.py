"""The result format: what every pipeline writes and ``mocapgraph eval`` reads.

A result is a directory: ``result.toml`` (pipeline, version, parameters, source capture, world
frame, format version) plus arrays. ``body.npz`` holds the body: timestamps, joints ``(T, 22, 3)``
world metres, optionally the body parameters and 3D keypoints. ``cameras.npz`` holds each
camera's pose per frame, as ``R, t`` world→camera like the capture format. ``covariances.npz``,
``flags.npz`` (per-frame arrays) and ``log.json`` (the solve's iterations) are optional.
Documented in ``docs/result-format.md``; written atomically like captures.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from mocapgraph import __version__
from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.labelling import SWAP_KINDS
from mocapgraph.body.skeleton import NUM_JOINTS
from mocapgraph.data_tools.io.capture import Rt_from_world_T_camera, world_T_camera_from_Rt
from mocapgraph.data_tools.io.checks import parse_json, read_text, warn_unknown_keys
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

FORMAT_NAME = "mocapgraph-result"
FORMAT_VERSION = 1
MANIFEST = "result.toml"
_KEYS = (
    "format", "version", "pipeline", "pipeline_version", "capture", "world_frame", "body", "body_model", "keypoint_format",
    "cameras", "covariances", "flags", "log", "parameters",
)  # fmt: skip
"""Keys of ``result.toml``; anything else draws a warning naming the nearest of these."""
PER_FRAME_CAMERA = "camera_per_frame:"
"""Prefix of the world frame of a result relative to a camera at each body timestamp (AirPose's)."""


class ResultError(MocapgraphError):
    """A result that cannot be read or written; the message names the file and the field."""


@dataclass
class CameraTrack:
    """One camera's estimated poses: ``timestamps (T_c,)`` and ``world_T_camera (T_c, 4, 4)``;
    ``swaps (T_c,)`` int8, where the solve relabelled the camera's detections: the index into
    :data:`mocapgraph.body.labelling.SWAP_KINDS` (0 as detected), or None."""

    timestamps: np.ndarray
    world_T_camera: np.ndarray
    swaps: np.ndarray | None = None


@dataclass
class Result:
    """A pipeline's output, in the world frame named by ``world_frame``.

    Attributes:
        pipeline: e.g. ``"aircap"``, ``"baseline"``.
        capture: path of the capture it came from (as given to the pipeline).
        world_frame: ``"capture"`` (the capture's own world frame), ``"camera:<name>"`` (that
            camera's frame at its first timestamp), ``"camera_per_frame:<name>"`` (that camera's
            frame at each body timestamp: AirPose's, where everything is relative to camera 1), or
            ``"ground_plane"`` (SmartMocap's frame).
        timestamps: ``(T,)`` seconds of the body states.
        joints: ``(T, 22, 3)`` world metres; NaN where a frame was not estimated.
        body_model, root ``(T, 4, 4)``, pose ``(T, 21, 3)``, shape ``(S,)``: the body parameters,
            all or none.
        keypoints: ``(T, K, 3)`` world metres of ``keypoint_format`` points, or None.
        cameras: estimated camera tracks by camera name.
        covariances: named arrays, e.g. ``joints (T, 22, 3, 3)``, ``root (T, 6, 6)``,
            ``camera:<name> (T_c, 6, 6)`` (Pose3 tangent order, rotation first).
        flags: per-frame arrays ``(T,)``, e.g. ``num_detections``, ``unconstrained``.
        log: the solve's iterations (dicts with at least ``iteration`` and ``cost``).
        parameters: the pipeline's parameters as run.
        pipeline_version: mocapgraph version that produced it.
    """

    pipeline: str
    capture: str
    world_frame: str
    timestamps: np.ndarray
    joints: np.ndarray
    body_model: str | None = None
    root: np.ndarray | None = None
    pose: np.ndarray | None = None
    shape: np.ndarray | None = None
    keypoints: np.ndarray | None = None
    keypoint_format: str | None = None
    cameras: dict[str, CameraTrack] = field(default_factory=dict)
    covariances: dict[str, np.ndarray] = field(default_factory=dict)
    flags: dict[str, np.ndarray] = field(default_factory=dict)
    log: list[dict] = field(default_factory=list)
    parameters: dict = field(default_factory=dict)
    pipeline_version: str = __version__
    path: Path | None = None

    @property
    def has_body_parameters(self) -> bool:
        return self.root is not None


# ---------------------------------------------------------------------------------------------
# Reading


def options_parameters(options) -> dict:
    """A pipeline's options dataclass as the result's ``parameters``: nested options as tables,
    tuples as lists (TOML has no tuples), unset (None) options left out."""

    def plain(table: dict) -> dict:
        return {k: plain(v) if isinstance(v, dict) else list(v) if isinstance(v, tuple) else v for k, v in table.items() if v is not None}

    return plain(asdict(options))


def load_result(path: str | Path) -> Result:
    """Read and validate a result directory (or its ``result.toml``)."""
    root, doc, where = read_manifest(path, MANIFEST, FORMAT_NAME, FORMAT_VERSION, ResultError)
    files = ArrayFiles(root, ResultError)
    warn_unknown_keys(doc, _KEYS, where)

    body_rel = require_key(doc, "body", where, str)
    body = files.npz(body_rel, where("body"), ("timestamps", "joints"))
    at = where.at(body_rel)
    ts = check_array(body["timestamps"], at("timestamps"), (None,))
    check_increasing(ts, at("timestamps"))
    T = len(ts)
    result = Result(
        pipeline=require_key(doc, "pipeline", where, str),
        capture=require_key(doc, "capture", where, str),
        world_frame=require_key(doc, "world_frame", where, str),
        timestamps=ts,
        joints=check_array(body["joints"], at("joints"), (T, NUM_JOINTS, 3), allow_nan=True, limit="position"),
        parameters=require_key(doc, "parameters", where, dict) if "parameters" in doc else {},
        pipeline_version=require_key(doc, "pipeline_version", where, str) if "pipeline_version" in doc else "unknown",
        path=root,
    )
    if "pose" in body:
        _require_arrays(body, ("R", "t", "shape"), at, "the body parameters need R, t, pose and shape together")
        result.body_model = require_key(doc, "body_model", where, str)
        R = check_array(body["R"], at("R"), (T, 3, 3))
        check_rotations(R, at("R"))
        result.root = np.tile(np.eye(4), (T, 1, 1))
        result.root[:, :3, :3] = R
        result.root[:, :3, 3] = check_array(body["t"], at("t"), (T, 3), limit="position")
        result.pose = check_array(body["pose"], at("pose"), (T, NUM_JOINTS - 1, 3), limit="body_parameter")
        result.shape = check_array(body["shape"], at("shape"), (None,), limit="body_parameter")
    if "keypoints" in body:
        fmt_name = require_key(doc, "keypoint_format", where, str)
        try:
            fmt = get_format(fmt_name)
        except MocapgraphError as exc:
            raise where("keypoint_format").fail(str(exc)) from None
        result.keypoint_format = fmt.name
        result.keypoints = check_array(body["keypoints"], at("keypoints"), (T, fmt.num_points, 3), allow_nan=True, limit="position")

    if "cameras" in doc:
        rel = require_key(doc, "cameras", where, str)
        arrays = files.npz(rel, where("cameras"), ())
        at = where.at(rel)
        for name in sorted({k.rsplit(".", 1)[0] for k in arrays}):
            _require_arrays(arrays, tuple(f"{name}.{k}" for k in ("timestamps", "R", "t")), at, "each camera needs timestamps, R and t")
            cts = check_array(arrays[f"{name}.timestamps"], at(f"{name}.timestamps"), (None,))
            check_increasing(cts, at(f"{name}.timestamps"))
            R = check_array(arrays[f"{name}.R"], at(f"{name}.R"), (len(cts), 3, 3))
            check_rotations(R, at(f"{name}.R"))
            t = check_array(arrays[f"{name}.t"], at(f"{name}.t"), (len(cts), 3), limit="position")
            swaps = None
            if f"{name}.swaps" in arrays:
                swaps = check_array(arrays[f"{name}.swaps"], at(f"{name}.swaps"), (len(cts),)).astype(np.int8)
                if np.any((swaps < 0) | (swaps >= len(SWAP_KINDS))):
                    raise at(f"{name}.swaps").fail(f"codes must index {', '.join(SWAP_KINDS)} (0 to {len(SWAP_KINDS) - 1})")
            result.cameras[name] = CameraTrack(cts, world_T_camera_from_Rt(R, t), swaps)
    if "covariances" in doc:
        rel = require_key(doc, "covariances", where, str)
        for name, arr in files.npz(rel, where("covariances"), ()).items():
            result.covariances[name] = check_array(arr, where.at(rel, name), (None,) * np.ndim(arr), allow_nan=True)
    if "flags" in doc:
        rel = require_key(doc, "flags", where, str)
        for name, arr in files.npz(rel, where("flags"), ()).items():
            if np.shape(arr)[:1] != (T,):
                raise where.at(rel, name).fail(f"per-frame flags need {T} rows, got shape {np.shape(arr)}")
            result.flags[name] = arr
    if "log" in doc:
        rel = require_key(doc, "log", where, str)
        path = files.resolve(rel, where("log"))
        result.log = parse_json(read_text(path, ResultError, "a UTF-8 JSON file"), path, ResultError)
        if not isinstance(result.log, list) or not all(isinstance(entry, dict) for entry in result.log):
            raise where.at(rel).fail("expected a list of objects (one per solver iteration)")
    return result


def _require_arrays(arrays: dict, keys: tuple[str, ...], at: Where, why: str) -> None:
    for key in keys:
        if key not in arrays:
            raise at(key).fail(f"missing ({why})")


# ---------------------------------------------------------------------------------------------
# Writing


def write_result(result: Result, path: str | Path, overwrite: bool = False) -> Path:
    """Write ``result`` at ``path`` atomically (validated by reading it back first)."""
    return write_directory_atomically(
        Path(path), overwrite, lambda tmp: _write_into(result, tmp), load_result, ResultError, replaces=MANIFEST
    )


def _write_into(result: Result, root: Path) -> None:
    doc: dict = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "pipeline": result.pipeline,
        "pipeline_version": result.pipeline_version,
        "capture": str(result.capture),
        "world_frame": result.world_frame,
        "body": "body.npz",
    }
    body = {"timestamps": result.timestamps, "joints": result.joints}
    if result.root is not None:
        doc["body_model"] = result.body_model
        body.update(R=result.root[:, :3, :3], t=result.root[:, :3, 3], pose=result.pose, shape=result.shape)
    if result.keypoints is not None:
        doc["keypoint_format"] = result.keypoint_format
        body["keypoints"] = result.keypoints
    np.savez_compressed(root / "body.npz", **body)
    if result.cameras:
        arrays = {}
        for name, track in result.cameras.items():
            arrays[f"{name}.timestamps"] = track.timestamps
            arrays[f"{name}.R"], arrays[f"{name}.t"] = Rt_from_world_T_camera(np.asarray(track.world_T_camera))
            if track.swaps is not None:
                arrays[f"{name}.swaps"] = np.asarray(track.swaps, dtype=np.int8)
        np.savez_compressed(root / "cameras.npz", **arrays)
        doc["cameras"] = "cameras.npz"
    for key, arrays in (("covariances", result.covariances), ("flags", result.flags)):
        if arrays:
            np.savez_compressed(root / f"{key}.npz", **arrays)
            doc[key] = f"{key}.npz"
    if result.log:
        (root / "log.json").write_text(json.dumps(result.log, indent=1), encoding="utf-8")
        doc["log"] = "log.json"
    doc["parameters"] = result.parameters
    write_manifest(root / MANIFEST, "result", "docs/result-format.md", doc)
