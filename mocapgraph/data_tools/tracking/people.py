"""Several people in one camera's video, followed over time; the one person to fit, chosen across cameras.

A detector gives, per frame, the keypoints of every person it finds, in no particular order.
:func:`track_people` links them frame to frame into tracks (one per person while the camera sees
them), by the distance between a track's predicted keypoints and each detection, solved as an
assignment (Hungarian method, ``scipy.optimize.linear_sum_assignment``). :func:`select_person`
then asks :mod:`mocapgraph.data_tools.geometry.association` which tracks of the different cameras
are the same person, ranks the people and picks the one to fit.

Arrays: keypoints ``(..., K, 3)`` are x, y pixels and confidence in [0, 1], NaN where missing
(normalised by the keypoint format); boxes ``(..., 5)`` are x0, y0, x1, y1 pixels and a score.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.labelling import swap_permutation
from mocapgraph.data_tools.geometry.association import MIN_VISIBILITY, Association, associate_tracks
from mocapgraph.data_tools.io.calibration import CameraCalibration
from mocapgraph.data_tools.io.importers import _default_K as default_intrinsics
from mocapgraph.data_tools.io.importers import assemble_capture
from mocapgraph.errors import MocapgraphError

log = logging.getLogger(__name__)

_MIN_COMMON_POINTS = 3
_MIN_HEIGHT_PX = 1.0
_UNMATCHED = 1e6


def keypoint_box(keypoints, size: tuple[int, int] | None = None, min_visibility: float = MIN_VISIBILITY) -> np.ndarray:
    """``(..., K, 3)`` keypoints → ``(..., 5)`` boxes of the points seen with confidence ≥
    ``min_visibility`` (of all present points where fewer than two are), clipped to the image
    ``size = (width, height)`` when given, scored by those points' mean confidence; NaN without points."""
    kp = np.asarray(keypoints, dtype=float)
    present = np.isfinite(kp).all(axis=-1)
    seen = present & (kp[..., 2] >= min_visibility)
    use = np.where((seen.sum(axis=-1) >= 2)[..., None], seen, present)
    out = np.full(kp.shape[:-2] + (5,), np.nan)
    any_point = use.any(axis=-1)
    if not any_point.any():
        return out
    x = np.where(use, kp[..., 0], np.nan)[any_point]
    y = np.where(use, kp[..., 1], np.nan)[any_point]
    box = np.stack([np.nanmin(x, -1), np.nanmin(y, -1), np.nanmax(x, -1), np.nanmax(y, -1)], axis=-1)
    if size is not None:
        box = np.clip(box, 0.0, np.array([size[0], size[1], size[0], size[1]], dtype=float) - 1.0)
    score = np.nanmean(np.where(use, kp[..., 2], np.nan)[any_point], axis=-1)
    out[any_point] = np.concatenate([box, score[:, None]], axis=-1)
    return out


def pose_distance(a, b, min_visibility: float = MIN_VISIBILITY) -> float:
    """How far apart two detections ``(K, 3)`` are, in person heights: the median distance between
    the points both see (confidence ≥ ``min_visibility``) over the taller of the two boxes of those
    points. 0.1 means a tenth of the person's height; inf when they share fewer than 3 points."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    both = np.isfinite(a).all(-1) & np.isfinite(b).all(-1) & (a[:, 2] >= min_visibility) & (b[:, 2] >= min_visibility)
    if both.sum() < _MIN_COMMON_POINTS:
        return float("inf")
    height = max(np.ptp(a[both, 1]), np.ptp(b[both, 1]), _MIN_HEIGHT_PX)
    return float(np.median(np.linalg.norm(a[both, :2] - b[both, :2], axis=1)) / height)


@dataclass
class PersonTracks:
    """The people one camera follows over a video.

    Attributes:
        keypoints: ``(P, T, K, 3)`` one row per track (person while followed), NaN in the frames
            where the track has no detection.
    """

    keypoints: np.ndarray

    def __post_init__(self):
        self.keypoints = np.asarray(self.keypoints, dtype=float)
        if self.keypoints.ndim != 4 or self.keypoints.shape[-1] != 3:
            raise MocapgraphError(f"person tracks must be (P, T, K, 3), got {self.keypoints.shape}")

    @property
    def num_tracks(self) -> int:
        return self.keypoints.shape[0]

    @property
    def num_frames(self) -> int:
        return self.keypoints.shape[1]

    @property
    def seen(self) -> np.ndarray:
        """``(P, T)`` bool: the track has a detection in that frame."""
        return np.isfinite(self.keypoints[..., 2]).any(axis=-1)

    def boxes(self, size: tuple[int, int] | None = None) -> np.ndarray:
        """``(P, T, 5)`` each track's box per frame (:func:`keypoint_box`)."""
        return keypoint_box(self.keypoints, size)


@dataclass
class _Track:
    frames: list[int]
    detections: list[np.ndarray]
    velocity: np.ndarray  # pixels per frame of the box centre

    def predict(self, frame: int) -> np.ndarray:
        kp = self.detections[-1].copy()
        kp[:, :2] += self.velocity * (frame - self.frames[-1])
        return kp

    def add(self, frame: int, kp: np.ndarray) -> None:
        previous, gap = self.detections[-1], frame - self.frames[-1]
        step = (_centre(kp) - _centre(previous)) / gap
        if np.isfinite(step).all():
            # one step's velocity is noisy (the detector jitters by pixels); average it a little
            self.velocity = 0.5 * self.velocity + 0.5 * step
        self.frames.append(frame)
        self.detections.append(kp)


def _centre(kp: np.ndarray) -> np.ndarray:
    box = keypoint_box(kp)
    return 0.5 * (box[:2] + box[2:4])


def _as_frames(frames: Sequence, num_points: int) -> list[np.ndarray]:
    out = []
    for t, people in enumerate(frames):
        arr = np.asarray(people, dtype=float) if len(people) else np.zeros((0, num_points, 3))
        if arr.ndim != 3 or arr.shape[1:] != (num_points, 3):
            raise MocapgraphError(f"frame {t}: detections must be (N, {num_points}, 3), got {arr.shape}")
        out.append(arr)
    return out


def track_people(
    frames: Sequence,
    keypoint_format: str = "blazepose33",
    *,
    max_distance: float = 0.5,
    max_gap: int = 30,
    min_frames: int = 5,
) -> PersonTracks:
    """Link each frame's detections into tracks, one per person while the camera follows them.

    Every frame, the tracks seen in the last ``max_gap`` frames predict their keypoints (the last
    detection moved by the box centre's velocity) and the detections are assigned to them by
    minimum total :func:`pose_distance` (Hungarian method); a left/right-swapped detection counts
    at the smaller of its two distances, so a swap does not start a new track. A pair farther
    apart than ``max_distance`` is not linked; a detection left over starts a track.

    Args:
        frames: per frame, the people detected, ``(N_t, K, 3)`` (``N_t`` may be 0) or a sequence
            of ``(K, 3)`` arrays.
        keypoint_format: the detections' format (its left/right pairs give the swap).
        max_distance: largest distance (in person heights) between a prediction and its detection.
        max_gap: frames a track may go without a detection and still be continued.
        min_frames: tracks with fewer detections are dropped (spurious detections).

    Returns:
        the tracks, ordered by the frame they start in.
    """
    fmt = get_format(keypoint_format)
    swap = swap_permutation(fmt.names, "body")
    frames = _as_frames(frames, fmt.num_points)
    if max_distance <= 0 or max_gap < 1 or min_frames < 1:
        raise MocapgraphError(f"track_people: max_distance > 0, max_gap ≥ 1 and min_frames ≥ 1 needed, got {max_distance}, {max_gap}, {min_frames}")
    tracks: list[_Track] = []
    for t, detections in enumerate(frames):
        live = [k for k, tr in enumerate(tracks) if t - tr.frames[-1] <= max_gap]
        cost = np.full((len(live), len(detections)), _UNMATCHED)
        for r, k in enumerate(live):
            predicted = tracks[k].predict(t)
            for c, det in enumerate(detections):
                d = min(pose_distance(predicted, det), pose_distance(predicted, det[swap]))
                if d <= max_distance:
                    cost[r, c] = d
        rows, cols = linear_sum_assignment(cost) if cost.size else (np.zeros(0, int), np.zeros(0, int))
        matched = set()
        for r, c in zip(rows, cols):
            if cost[r, c] < _UNMATCHED:
                tracks[live[r]].add(t, detections[c])
                matched.add(c)
        for c, det in enumerate(detections):
            if c not in matched and np.isfinite(det[:, 2]).any():
                tracks.append(_Track([t], [det], np.zeros(2)))
    kept = [tr for tr in tracks if len(tr.frames) >= min_frames]
    if len(kept) < len(tracks):
        log.debug("dropped %d tracks shorter than %d frames", len(tracks) - len(kept), min_frames)
    out = np.full((len(kept), len(frames), fmt.num_points, 3), np.nan)
    for p, tr in enumerate(kept):
        out[p, tr.frames] = np.stack(tr.detections)
    return PersonTracks(out)


# ---------------------------------------------------------------------------------------------
# The person to fit


PERSON_RULES = ("largest", "central")
"""How :func:`select_person` picks among the people seen by the most cameras: the tallest in the
images (mean over the cameras of the median box height over the image height), or the one
nearest the images' centres (mean distance of the box centre from the image centre over the
image's half-diagonal). An integer picks by rank instead."""

MOVING_WINDOW_S = 0.5
"""Seconds per window over which tracks of a moving camera are matched to another camera's
(:func:`~mocapgraph.data_tools.geometry.association.score_moving_pair`)."""


@dataclass
class PersonSummary:
    """One person of an :class:`~mocapgraph.data_tools.geometry.association.Association`.

    Attributes:
        tracks: camera → its tracks of this person.
        frames: camera → frames in which the camera sees the person.
        height: mean over the cameras of the median box height as a fraction of the image height.
        offset: mean over the cameras of the median distance of the box centre from the image
            centre, as a fraction of the image's half-diagonal (0 = centred, 1 = in a corner).
        affinity: pooled inlier ratio of its tracks' pairs (NaN when one camera sees the person).
    """

    tracks: dict[str, tuple[int, ...]]
    frames: dict[str, int]
    height: float
    offset: float
    affinity: float


@dataclass
class PersonChoice:
    """The people seen across the cameras, and the one chosen.

    Attributes:
        people: ranked: seen by more cameras first, then taller in the images.
        chosen: index into ``people``.
        rule: how it was chosen (``"largest"``, ``"central"`` or ``"index"``).
        keypoints: camera → ``(T, K, 3)`` the chosen person's keypoints (its tracks there, merged),
            all NaN for a camera that does not see the person.
        association: the association the people come from (pair scores included).
    """

    people: list[PersonSummary]
    chosen: int
    rule: str
    keypoints: dict[str, np.ndarray]
    association: Association

    @property
    def person(self) -> PersonSummary:
        return self.people[self.chosen]

    def describe(self) -> str:
        """Lines for a person reading a terminal: the people seen, their tracks, and the choice."""
        cameras = self.association.cameras
        per_camera = self.metadata()["tracks_per_camera"]
        lines = [f"{len(self.people)} people seen; tracks per camera: " + ", ".join(f"{c} {per_camera[c]}" for c in cameras)]
        for k, p in enumerate(self.people):
            where = ", ".join(f"{c} track {'+'.join(map(str, p.tracks[c]))} ({p.frames[c]} frames)" for c in cameras if c in p.tracks)
            affinity = "" if np.isnan(p.affinity) else f", epipolar inliers {100 * p.affinity:.0f}%"
            lines.append(f"  person {k}: {where}; height {100 * p.height:.0f}% of the image{affinity}" + ("  <- chosen" if k == self.chosen else ""))
        how = f"rank {self.chosen} as asked" if self.rule == "index" else f"the {self.rule} of those seen by the most cameras"
        lines.append(f"fitting person {self.chosen}: {how}")
        return "\n".join(lines)

    def metadata(self) -> dict:
        """A manifest entry: people seen per camera, every person's tracks and numbers, the choice."""
        cameras = self.association.cameras
        return {
            "people_seen": len(self.people),
            "tracks_per_camera": {cam: sum(len(p.tracks.get(cam, ())) for p in self.people) for cam in cameras},
            "chosen": self.chosen,
            "rule": self.rule,
            "people": [
                {"tracks": {cam: list(t) for cam, t in p.tracks.items()}, "frames": dict(p.frames),
                 "height": round(p.height, 4), "offset": round(p.offset, 4), "affinity": round(p.affinity, 4)}
                for p in self.people
            ],
        }  # fmt: skip


def _summary(tracks: Mapping[str, PersonTracks], sizes: Mapping[str, tuple[int, int]], person, affinity) -> PersonSummary:
    heights, offsets, frames = [], [], {}
    for cam, indices in person.items():
        w, h = sizes[cam]
        boxes = tracks[cam].boxes((w, h))[list(indices)]
        frames[cam] = int(np.isfinite(boxes[..., 0]).any(0).sum())
        boxes = boxes.reshape(-1, 5)
        boxes = boxes[np.isfinite(boxes[:, 0])]
        heights.append(np.median(boxes[:, 3] - boxes[:, 1]) / h)
        centre = 0.5 * (boxes[:, :2] + boxes[:, 2:4])
        offsets.append(np.median(np.linalg.norm((centre - [w / 2, h / 2]) / (0.5 * np.hypot(w, h)), axis=1)))
    return PersonSummary(dict(person), frames, float(np.mean(heights)), float(np.mean(offsets)), float(affinity))


def parse_person(text: str | int) -> str | int:
    """``"largest"``, ``"central"`` or a rank (``"0"``, ``"1"``, …) as given on a command line."""
    if isinstance(text, int) or text in PERSON_RULES:
        return text
    try:
        return int(text)
    except ValueError:
        raise MocapgraphError(f"person must be {' or '.join(PERSON_RULES)} or a rank (0, 1, …), got {text!r}") from None


def choose_person(
    association: Association,
    tracks: Mapping[str, PersonTracks],
    image_sizes: Mapping[str, tuple[int, int]],
    person: str | int = "largest",
) -> PersonChoice:
    """Rank the people of an association and choose the one to fit.

    Args:
        association: which tracks are which person (:func:`~mocapgraph.data_tools.geometry.association.associate_tracks`).
        tracks: camera → its :class:`PersonTracks` (those the association grouped).
        image_sizes: camera → ``(width, height)``.
        person: ``"largest"`` or ``"central"`` of the people seen by the most cameras
            (:data:`PERSON_RULES`), or a rank in the ranked list (:func:`parse_person`).

    Returns:
        the people ranked (seen by more cameras first, then taller), the chosen one and its
        keypoints per camera.
    """
    person = parse_person(person)
    if not association.people:
        raise MocapgraphError("no person was found in any camera")
    summaries = [_summary(tracks, image_sizes, p, association.affinity(k)) for k, p in enumerate(association.people)]
    people = sorted(summaries, key=lambda p: (-len(p.tracks), -p.height))
    if isinstance(person, int):
        if not 0 <= person < len(people):
            raise MocapgraphError(f"person {person} does not exist: {len(people)} people were seen (ranks 0 to {len(people) - 1})")
        chosen, rule = person, "index"
    else:
        most = len(people[0].tracks)
        candidates = [k for k, p in enumerate(people) if len(p.tracks) == most]
        key = (lambda k: -people[k].height) if person == "largest" else (lambda k: people[k].offset)
        chosen, rule = min(candidates, key=key), person
    keypoints = {cam: merge_tracks(t.keypoints[list(people[chosen].tracks.get(cam, ()))], t.keypoints.shape[1:]) for cam, t in tracks.items()}
    return PersonChoice(people, chosen, rule, keypoints, association)


def select_person(
    tracks: Mapping[str, PersonTracks],
    image_sizes: Mapping[str, tuple[int, int]],
    intrinsics: Mapping[str, np.ndarray],
    distortion: Mapping[str, np.ndarray | None] | None = None,
    person: str | int = "largest",
    *,
    keypoint_format: str = "blazepose33",
    **association_options,
) -> PersonChoice:
    """Associate every camera's tracks into people (:func:`~mocapgraph.data_tools.geometry.association.associate_tracks`
    with ``intrinsics``, ``distortion`` and ``association_options``) and choose the one to fit
    (:func:`choose_person`)."""
    person = parse_person(person)
    assoc = associate_tracks(
        {cam: t.keypoints for cam, t in tracks.items()}, intrinsics, distortion, keypoint_format=keypoint_format, **association_options
    )
    return choose_person(assoc, tracks, image_sizes, person)


def merge_tracks(rows: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """One ``(T, K, 3)`` array from a person's tracks in a camera. They share a frame only where a
    detector split the person in two (at most ``MAX_SHARED_FRAMES``, the association's bound);
    there the piece with more points is kept."""
    out = np.full(shape, np.nan)
    for row in rows:
        more = np.isfinite(row[..., 2]).sum(-1) > np.isfinite(out[..., 2]).sum(-1)
        out[more] = row[more]
    return out


def write_person_capture(
    tracks: Mapping[str, PersonTracks],
    image_sizes: Mapping[str, tuple[int, int]],
    fps: float | Mapping[str, float],
    out: str | Path,
    *,
    calibration: Sequence[CameraCalibration] | None = None,
    person: str | int = "largest",
    videos: Mapping[str, str | Path] | None = None,
    detector: str = "mediapipe",
    keypoint_format: str = "blazepose33",
    metadata: Mapping | None = None,
    association_options: Mapping | None = None,
    **capture_options,
) -> tuple[Path, PersonChoice]:
    """Choose the person to fit (:func:`select_person`) and write a capture of them alone.

    The association uses each camera's calibrated intrinsics and distortion, or, for a camera
    missing from ``calibration``, the guess the capture gets too (``f = 1.2 × max(width, height)``).

    Args:
        tracks, image_sizes: per camera, its tracks and ``(width, height)``.
        fps: frames per second, of every camera or per camera.
        out: capture directory.
        calibration: cameras of a calibration file (poses included or not), matched by name.
        person: ``"largest"``, ``"central"`` or a rank (:func:`select_person`).
        videos: camera → its video, placed in the capture.
        detector, keypoint_format: the detections' detector name and format.
        metadata: more manifest entries (``people`` is added: :meth:`PersonChoice.metadata`).
        association_options: passed to :func:`~mocapgraph.data_tools.geometry.association.associate_tracks`.
        capture_options: passed to :func:`~mocapgraph.data_tools.io.importers.assemble_capture`; its
            ``moving`` also tells the association which cameras move.

    Returns:
        the capture's path and the choice. A chosen person some camera never sees is an error.
    """
    calib = {c.name: c for c in calibration or []}
    intrinsics = {n: calib[n].K if n in calib else default_intrinsics(image_sizes[n]) for n in tracks}
    distortion = {n: calib[n].distortion if n in calib else None for n in tracks}
    options = dict(association_options or {})
    moving = capture_options.get("moving")
    if isinstance(moving, Mapping) and any(moving.values()):
        rates = fps.values() if isinstance(fps, Mapping) else [fps]
        options = {"moving": moving, "window": max(2, round(MOVING_WINDOW_S * min(rates)))} | options
    choice = select_person(tracks, image_sizes, intrinsics, distortion, person, keypoint_format=keypoint_format, **options)
    unseen = [n for n in tracks if n not in choice.person.tracks]
    if unseen:
        raise MocapgraphError(
            f"person {choice.chosen} is not seen by camera(s) {', '.join(unseen)}; choose another (by rank), or leave out "
            "the cameras that do not see them. " + choice.describe().replace("\n", "; ")
        )
    keypoints = {n: (detector, keypoint_format, choice.keypoints[n], keypoint_box(choice.keypoints[n], image_sizes[n])) for n in tracks}
    meta = {**dict(metadata or {}), "people": choice.metadata()}
    # assemble_capture learns a camera's image size from its video or calibration only; a camera
    # with neither gets its guessed intrinsics as a calibration entry, and the manifest still
    # says they are guessed (the pipelines free a guessed focal length)
    stand_ins = [n for n in tracks if n not in calib and n not in (videos or {})]
    entries = list(calib.values()) + [CameraCalibration(n, intrinsics[n], np.zeros(5), tuple(image_sizes[n])) for n in stand_ins]
    if stand_ins:
        meta["imported"] = {"calibrated": sorted(calib), "guessed_intrinsics": [n for n in tracks if n not in calib]}
    path = assemble_capture(videos, keypoints, entries or None, fps, out, metadata=meta, **capture_options)
    return path, choice
