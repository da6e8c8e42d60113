"""2D keypoint files from other tools: OpenPose-style JSON folders (OpenPose, Pose2Sim, RTMPose,
AlphaPose in ``--format cmu``) and plain ``(T, K, 3)`` arrays (``.npy`` / ``.npz``).

Both give ``(T, K, 3)`` keypoints in one format of the registry
(:mod:`mocapgraph.body.keypoint_formats`), normalised: pixels, confidence in [0, 1], NaN where
missing; and ``(T, 5)`` boxes ``x0, y0, x1, y1, score`` of the kept person's detected points.
The format is named, or told from the number of points per person. Every problem raises one
:class:`~mocapgraph.data_tools.io.capture.CaptureError` naming the file and the field.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from mocapgraph.body.keypoint_formats import UNSUPPORTED_POINT_COUNTS, KeypointFormat, format_for_points, formats_with_points, get_format
from mocapgraph.data_tools.io.capture import CaptureError
from mocapgraph.data_tools.io.checks import load_npy, load_npz, parse_json, read_text
from mocapgraph.errors import MocapgraphError

OPENPOSE_SUFFIX = "_keypoints.json"
"""OpenPose's ``--write_json`` names every frame's file ``<stem>_<frame>_keypoints.json``."""

AUTO = "auto"
"""Format name meaning: tell the format from the number of points per person."""


def natural_key(path: Path) -> list:
    """``frame_2`` before ``frame_10``: digit runs compare as numbers."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.name)]


def person_box(kp: np.ndarray) -> np.ndarray:
    """``(K, 3)`` normalised keypoints → ``(5,)`` box of the present points and their mean confidence."""
    present = np.isfinite(kp[:, 2])
    if not present.any():
        return np.full(5, np.nan)
    xy, conf = kp[present, :2], kp[present, 2]
    return np.array([xy[:, 0].min(), xy[:, 1].min(), xy[:, 0].max(), xy[:, 1].max(), conf.mean()])


def _check_person(person, source) -> None:
    if not (person == "largest" or (isinstance(person, int) and not isinstance(person, bool) and person >= 0)):
        raise CaptureError(f"{source}: person must be 'largest' or a non-negative index, got {person!r}")


def _choose(candidates: list[tuple[np.ndarray, np.ndarray]], person: str | int):
    """One ``(keypoints, box)`` of a frame's people: the largest box, or ``people[person]``; None if absent."""
    if person == "largest":
        area = [(b[2] - b[0]) * (b[3] - b[1]) if np.isfinite(b[0]) else -1.0 for _, b in candidates]
        return candidates[int(np.argmax(area))] if candidates and max(area) >= 0 else None
    return candidates[person] if person < len(candidates) else None


def _named(fmt: str | KeypointFormat) -> KeypointFormat:
    try:
        return fmt if isinstance(fmt, KeypointFormat) else get_format(fmt)
    except MocapgraphError as exc:
        raise CaptureError(str(exc)) from None


def _resolve(fmt: str | KeypointFormat, num_points: int, source: str) -> KeypointFormat:
    """The named format (checked against ``num_points``) or, for ``"auto"``, the one with that many points."""
    if fmt == AUTO:
        try:
            return format_for_points(num_points, source)
        except MocapgraphError as exc:
            raise CaptureError(str(exc)) from None
    found = _named(fmt)
    if found.num_points != num_points:
        raise CaptureError(f"{source}: {num_points} points per person, but format {found.name} has {found.num_points}{_count_hint(num_points)}")
    return found


def _count_hint(num_points: int) -> str:
    same = formats_with_points(num_points)
    if same:
        return f" ({num_points} points is {' or '.join(same)}: say so with --format)"
    return f" ({num_points} points is {UNSUPPORTED_POINT_COUNTS[num_points]})" if num_points in UNSUPPORTED_POINT_COUNTS else ""


def _normalise(fmt: KeypointFormat, raw, source: str) -> np.ndarray:
    try:
        return fmt.normalise(raw, source=source)
    except MocapgraphError as exc:
        raise CaptureError(str(exc)) from None


def read_json_people(folder: str | Path, fmt: str | KeypointFormat = AUTO, suffix: str = ".json") -> tuple[list[np.ndarray], str]:
    """Read a folder of OpenPose-style JSON files, one per frame, keeping every person of each frame.

    Each file is ``{"people": [{"pose_keypoints_2d": [x0, y0, c0, x1, ...]}, ...]}`` (OpenPose's
    ``--write_json``, and what Pose2Sim writes for every detector it runs). A person entry whose
    ``pose_keypoints_2d`` is empty holds no detection (Pose2Sim's tracking writes such placeholders
    to keep its people's order) and is left out.

    Args:
        folder: holds the per-frame files, taken in natural order of their names
            (``x_2.json`` before ``x_10.json``); files not ending in ``suffix`` are ignored.
        fmt: keypoint format name, or ``"auto"``: the one format with as many points as the first
            person found (an error when no format or several have that many: BODY_25 and BODY_25B).
            Every person of every file must have that many points.
        suffix: the file name ending of the frames (OpenPose: ``_keypoints.json``).

    Returns:
        per frame, the people's keypoints ``(N_t, K, 3)`` pixels and confidence, normalised (NaN
        where missing; ``N_t`` may be 0), in the file's order; the format's registry name.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise CaptureError(f"{folder}: keypoint folder not found")
    files = sorted((p for p in folder.iterdir() if p.name.endswith(suffix) and p.is_file()), key=natural_key)
    if not files:
        hint = " (OpenPose writes them with --write_json)" if suffix == OPENPOSE_SUFFIX else ""
        raise CaptureError(f"{folder}: no *{suffix} files{hint}")
    auto = fmt == AUTO
    if not auto:
        fmt = _named(fmt)
    told_by = None  # with "auto": the file whose first person set the format
    frames: list[list[tuple[np.ndarray, str]]] = []
    for path in files:
        doc = parse_json(read_text(path, CaptureError, "a UTF-8 JSON file"), path, CaptureError)
        people = doc.get("people") if isinstance(doc, dict) else None
        if not isinstance(people, list):
            raise CaptureError(f"{path}: people: missing or not a list (is this OpenPose-style JSON output?)")
        found = []
        for i, entry in enumerate(people):
            where = f"{path}: people[{i}].pose_keypoints_2d"
            raw = entry.get("pose_keypoints_2d") if isinstance(entry, dict) else None
            if not isinstance(raw, list):
                raise CaptureError(f"{where}: missing or not a list")
            if not raw:
                continue
            if len(raw) % 3:
                raise CaptureError(f"{where}: {len(raw)} values is not x, y, confidence for each point (not a multiple of 3)")
            try:
                arr = np.asarray(raw, dtype=float).reshape(-1, 3)
            except (TypeError, ValueError):
                raise CaptureError(f"{where}: not all numbers") from None
            if auto and told_by is None:
                fmt, told_by = _resolve(AUTO, len(arr), where), path.name
            elif len(arr) != fmt.num_points:
                told = f"{fmt.name}, told from {told_by}" if auto else fmt.name
                raise CaptureError(
                    f"{where}: expected {3 * fmt.num_points} values ({told}: {fmt.num_points} points of x, y, c), "
                    f"got {len(raw)}{_count_hint(len(arr))}"
                )
            found.append((arr, f"{path}: people[{i}]"))
        frames.append(found)
    if auto and told_by is None:
        raise CaptureError(f"{folder}: no person in any of its {len(files)} files, so its keypoint format is unknown; give it with --format")
    people = [np.array([_normalise(fmt, arr, source) for arr, source in found]).reshape(len(found), fmt.num_points, 3) for found in frames]
    return people, fmt.name


def one_per_frame(people: list[np.ndarray], person: str | int = "largest") -> tuple[np.ndarray, np.ndarray]:
    """One person per frame of :func:`read_json_people`'s output, without following anyone.

    Args:
        people: per frame, ``(N_t, K, 3)`` normalised keypoints.
        person: ``"largest"`` keeps the person with the largest box of detected points in each
            frame; an int keeps ``people[person]`` (NaN where a frame has fewer people).

    Returns:
        keypoints ``(T, K, 3)``, NaN where missing; boxes ``(T, 5)`` ``x0, y0, x1, y1, score`` of
        the kept person's detected points (score = their mean confidence), NaN rows for frames
        without a person.
    """
    _check_person(person, "one_per_frame")
    num_points = people[0].shape[1] if people else 0
    keypoints = np.full((len(people), num_points, 3), np.nan)
    boxes = np.full((len(people), 5), np.nan)
    for t, found in enumerate(people):
        chosen = _choose([(kp, person_box(kp)) for kp in found], person)
        if chosen is not None:
            keypoints[t], boxes[t] = chosen
    return keypoints, boxes


def read_json_keypoints(
    folder: str | Path, fmt: str | KeypointFormat = AUTO, person: str | int = "largest", suffix: str = ".json"
) -> tuple[np.ndarray, np.ndarray, str]:
    """Read a folder of OpenPose-style JSON files keeping one person per frame
    (:func:`read_json_people`, then :func:`one_per_frame` with ``person``).

    Returns:
        keypoints ``(T, K, 3)`` pixels and confidence, NaN where missing; boxes ``(T, 5)``; the
        format's registry name.
    """
    _check_person(person, Path(folder))
    people, name = read_json_people(folder, fmt, suffix)
    keypoints, boxes = one_per_frame(people, person)
    return keypoints, boxes, name


def read_keypoint_array(path: str | Path, fmt: str | KeypointFormat = AUTO, key: str | None = None) -> tuple[np.ndarray, np.ndarray, str]:
    """Read one camera's keypoints from a ``(T, K, 3)`` array: x, y pixels and confidence per point.

    Args:
        path: a ``.npy`` file, or a ``.npz`` holding one array (or several, with ``key`` naming it).
        fmt: keypoint format name, or ``"auto"`` to tell it from ``K`` (see :func:`read_json_keypoints`).
        key: the array's name inside a ``.npz``.

    Returns:
        keypoints ``(T, K, 3)`` normalised (confidence in [0, 1], NaN where missing), boxes
        ``(T, 5)`` of each frame's detected points, and the format's registry name.
    """
    path = Path(path)
    if not path.is_file():
        raise CaptureError(f"{path}: keypoint file not found")
    suffix = path.suffix.lower()
    if suffix not in (".npy", ".npz"):
        raise CaptureError(f"{path}: keypoint arrays must be .npy or .npz files")
    if key is not None and suffix != ".npz":
        raise CaptureError(f"{path}: an array name ({key!r}) only applies to .npz files")
    source = str(path)
    if suffix == ".npy":
        arr = load_npy(path, source, CaptureError)
    else:
        arrays = load_npz(path, source, CaptureError)
        names = list(arrays)
        if key is None and len(names) != 1:
            raise CaptureError(f"{path}: holds {len(names)} arrays ({', '.join(names) or 'none'}); name one as FILE.npz:KEY")
        key = key if key is not None else names[0]
        if key not in names:
            raise CaptureError(f"{path}: no array {key!r} (it holds {', '.join(names)})")
        arr = arrays[key]
        source = f"{path}[{key}]"
    if arr.ndim != 3 or arr.shape[-1] != 3:
        raise CaptureError(f"{source}: expected shape (T, K, 3): frames, points, x y confidence; got {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number):
        raise CaptureError(f"{source}: expected numbers, got dtype {arr.dtype}")
    fmt = _resolve(fmt, arr.shape[1], source)
    keypoints = _normalise(fmt, arr, source)
    return keypoints, np.array([person_box(kp) for kp in keypoints]).reshape(len(keypoints), 5), fmt.name
