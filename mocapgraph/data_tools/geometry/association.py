"""The same person across cameras: every camera's person tracks matched to the others' by epipolar geometry.

Two tracks of two static cameras show the same person when one rigid two-view geometry explains
all their keypoints: every keypoint of every frame both tracks see is a correspondence, and an
essential matrix fitted to them by RANSAC (``cv2.findEssentialMat``, on coordinates normalised by
the intrinsics, known or guessed) leaves most of them within a few pixels of their epipolar
lines. Two different people give no such geometry once they move differently (their keypoints
would need a camera that moves with them). Left/right swaps of the detector are tolerated: each
frame's labels in the second camera are taken as detected or with left and right exchanged
(:func:`mocapgraph.body.labelling.swap_permutation`), whichever fits the geometry better. When
either camera moves, each window of about half a second gets its own geometry
(:func:`score_moving_pair`): the camera barely moves within it, and two people rarely move alike
for that long.

:func:`associate_tracks` scores every pair of tracks of every pair of cameras and groups the
tracks into people, greedily joining the two groups with the best pooled score: a person holds at
most one track per camera at any time (tracks of one camera that follow each other in time may
be fragments of one person), so the grouping is consistent around every cycle of cameras.

Arrays: tracks ``(P, T, K, 3)`` per camera (x, y pixels, confidence; NaN where missing), frame
``t`` of every camera the same instant; intrinsics ``(3, 3)`` pixels; distortion OpenCV's ``(5,)``.
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field

import cv2
import numpy as np

from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.labelling import swap_permutation
from mocapgraph.data_tools.geometry.camera_model import undistort_pixels
from mocapgraph.data_tools.geometry.epipolar import normalised, sampson_px
from mocapgraph.errors import MocapgraphError

log = logging.getLogger(__name__)

DEFAULT_THRESHOLD = 0.02
"""Epipolar distance within which a correspondence agrees with a pair's geometry, as a fraction
of the person's height in the image (the geometric mean of the two tracks' median heights): a 2D
detector's error grows with the person's size in pixels (15 px on a person 750 px tall)."""

DEFAULT_MIN_AFFINITY = 0.5
"""Pooled inlier ratio above which two groups of tracks are joined into one person."""

MIN_CORRESPONDENCES = 40
"""Fewer common keypoints than this say nothing about a pair (a few frames at the edge of a view)."""

MIN_VISIBILITY = 0.5
"""Keypoints below this confidence are the detector's guesses (BlazePose places occluded points
anyway): they make no correspondence here, and no box nor track link in
:mod:`mocapgraph.data_tools.tracking.people`."""

MAX_SHARED_FRAMES = 2
"""Frames two tracks of one camera may share and still be one person: a detector that splits a
person into two partial skeletons for a frame restarts the track there (OpenPose BODY_25B on the
man on Pose2Sim's treadmill, cam01 frame 37), and the two pieces overlap by that frame."""

_MAX_RELABEL_ROUNDS = 3
_RANSAC_CONFIDENCE = 0.999
_RANSAC_SAMPLE = 400


@dataclass(frozen=True)
class PairScore:
    """How well two tracks of two cameras fit one two-view geometry.

    Attributes:
        frames: frames in which both tracks have common keypoints.
        correspondences: keypoint pairs (every common keypoint of every such frame).
        inliers: correspondences within the threshold of the fitted geometry.
        median_error_px: median epipolar (Sampson) distance of all correspondences, pixels.
        swapped_frames: the frames whose second-camera labels fit better with left and right
            exchanged (relative to the first camera's: a swap in either camera).
    """

    frames: int
    correspondences: int
    inliers: int
    median_error_px: float
    swapped_frames: tuple[int, ...]

    @property
    def inlier_ratio(self) -> float:
        return self.inliers / self.correspondences


def normalised_points(keypoints, K, distortion=None, min_visibility: float = MIN_VISIBILITY) -> np.ndarray:
    """``(..., K, 3)`` pixel keypoints → ``(..., K, 2)`` undistorted coordinates on the plane
    ``z = 1`` of the camera; NaN where a point is missing or its confidence is below ``min_visibility``."""
    kp = np.asarray(keypoints, dtype=float)
    pixels = kp[..., :2] if distortion is None else undistort_pixels(kp[..., :2], K, distortion)
    out = normalised(pixels, K)
    out[~(np.isfinite(kp).all(-1) & (kp[..., 2] >= min_visibility))] = np.nan
    return out


def track_heights(tracks, min_visibility: float = MIN_VISIBILITY) -> np.ndarray:
    """``(..., T, K, 3)`` tracks → ``(...)`` median height in pixels of the points seen with
    confidence ≥ ``min_visibility`` over the frames with at least two such points (NaN: none)."""
    kp = np.asarray(tracks, dtype=float)
    seen = np.isfinite(kp).all(-1) & (kp[..., 2] >= min_visibility)
    y = np.where(seen, kp[..., 1], np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # frames and tracks without points: NaN
        span = np.nanmax(y, axis=-1) - np.nanmin(y, axis=-1)
        span[seen.sum(-1) < 2] = np.nan
        return np.nanmedian(span, axis=-1)


def _fit_essential(x1: np.ndarray, x2: np.ndarray, threshold: float, seed: int) -> np.ndarray | None:
    """RANSAC essential matrix of normalised correspondences; of several solutions, the one with
    the most inliers. None when OpenCV finds none."""
    if len(x1) > _RANSAC_SAMPLE:
        # RANSAC's time goes into scoring every hypothesis on every point; a random subset ranks
        # the hypotheses as well (the inliers are then counted on all points)
        keep = np.random.default_rng(seed).choice(len(x1), _RANSAC_SAMPLE, replace=False)
        x1, x2 = x1[keep], x2[keep]
    cv2.setRNGSeed(seed)
    E, _ = cv2.findEssentialMat(x1, x2, np.eye(3), method=cv2.RANSAC, prob=_RANSAC_CONFIDENCE, threshold=threshold)
    if E is None or E.shape[0] < 3:
        return None
    candidates = E.reshape(-1, 3, 3)
    counts = [(sampson_px(e, x1, x2) < threshold).sum() for e in candidates]
    return candidates[int(np.argmax(counts))]


def score_pair(
    a: np.ndarray,
    b: np.ndarray,
    focal_px: float,
    swap: np.ndarray | None = None,
    *,
    threshold_px: float,
    min_correspondences: int = MIN_CORRESPONDENCES,
    seed: int = 0,
) -> PairScore | None:
    """Score two tracks as one person seen by two static cameras.

    Args:
        a, b: ``(T, K, 2)`` normalised coordinates of the two tracks (:func:`normalised_points`),
            frame ``t`` the same instant in both (only the first ``min(len(a), len(b))`` frames count).
        focal_px: the focal length that turns normalised distances into pixels (the geometric
            mean of the two cameras').
        swap: ``(K,)`` left/right permutation (:func:`~mocapgraph.body.labelling.swap_permutation`)
            to try on ``b`` frame by frame; None: labels as detected.
        threshold_px: inlier distance, pixels.
        min_correspondences: fewer common keypoints give no score.
        seed: OpenCV's RANSAC seed.

    Returns:
        the score, or None when the tracks share too few keypoints.
    """
    T = min(len(a), len(b))
    a, b = a[:T], b[:T]
    # everything below is in normalised coordinates (sampson_px of an essential matrix measures
    # in them); the focal length converts the threshold and the reported error
    threshold = threshold_px / focal_px

    def pairs(labels_b: np.ndarray):
        common = np.isfinite(a).all(-1) & np.isfinite(labels_b).all(-1)
        return a[common], labels_b[common], common

    labellings = [b] if swap is None else [b, b[:, swap]]
    # start from the labelling that fits better as a whole: a detector may swap in most frames
    start = None
    for k, labels in enumerate(labellings):
        x1, x2, _ = pairs(labels)
        E = _fit_essential(x1, x2, threshold, seed) if len(x1) >= min_correspondences else None
        if E is not None:
            inliers = int((sampson_px(E, x1, x2) < threshold).sum())
            if start is None or inliers > start[0]:
                start = (inliers, E, k)
    if start is None:
        return None
    _, E, k = start
    swapped = np.full(T, k == 1)
    x1, x2, common = pairs(labellings[k])
    for _ in range(_MAX_RELABEL_ROUNDS if swap is not None else 0):
        errors = []
        for labels in labellings:
            y1, y2, mask = pairs(labels)
            per_point = np.full(mask.shape, np.nan)
            per_point[mask] = sampson_px(E, y1, y2)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # frames without common points: NaN
                # truncated at the threshold: a frame's outliers (a hand on the wrong person) count once
                errors.append(np.nanmean(np.minimum(per_point, threshold) ** 2, axis=1))
        better = np.nan_to_num(errors[1], nan=np.inf) < np.nan_to_num(errors[0], nan=np.inf)
        if np.array_equal(better, swapped):
            break
        swapped = better
        x1, x2, common = pairs(np.where(swapped[:, None, None], labellings[1], labellings[0]))
        refit = _fit_essential(x1, x2, threshold, seed) if len(x1) >= min_correspondences else None
        if refit is None:
            return None
        E = refit
    d = sampson_px(E, x1, x2)
    return PairScore(
        frames=int(common.any(-1).sum()),
        correspondences=len(d),
        inliers=int((d < threshold).sum()),
        median_error_px=float(np.median(d) * focal_px),
        swapped_frames=tuple(np.flatnonzero(swapped).tolist()),
    )


def score_moving_pair(a: np.ndarray, b: np.ndarray, focal_px: float, swap: np.ndarray | None = None, *, window: int, **kw) -> PairScore | None:
    """Score two tracks as one person when either camera moves: :func:`score_pair` on windows of
    ``window`` frames (a tail shorter than half a window joins the last), each with its own
    two-view geometry, pooled. Arguments and ``kw`` as :func:`score_pair`; the pooled
    ``median_error_px`` is the median of the windows' medians. None when no window shares
    enough keypoints."""
    if window < 2:
        raise MocapgraphError(f"window: at least 2 frames, got {window}")
    T = min(len(a), len(b))
    starts = list(range(0, T, window))
    if len(starts) > 1 and T - starts[-1] < window // 2:
        starts.pop()
    parts = []
    for k, start in enumerate(starts):
        stop = starts[k + 1] if k + 1 < len(starts) else T
        s = score_pair(a[start:stop], b[start:stop], focal_px, swap, **kw)
        if s is not None:
            parts.append((start, s))
    if not parts:
        return None
    return PairScore(
        frames=sum(s.frames for _, s in parts),
        correspondences=sum(s.correspondences for _, s in parts),
        inliers=sum(s.inliers for _, s in parts),
        median_error_px=float(np.median([s.median_error_px for _, s in parts])),
        swapped_frames=tuple(start + f for start, s in parts for f in s.swapped_frames),
    )


@dataclass
class Association:
    """Which track of which camera is which person.

    Attributes:
        cameras: camera names, in the order given.
        people: per person, camera → indices of its tracks there (several only when they follow
            one another in time); a camera that does not see the person is absent.
        scores: ``(camera a, track i, camera b, track j)`` → :class:`PairScore` of every pair of
            tracks that share enough keypoints, camera ``a`` before ``b`` in ``cameras``.
    """

    cameras: tuple[str, ...]
    people: list[dict[str, tuple[int, ...]]]
    scores: dict[tuple[str, int, str, int], PairScore] = field(default_factory=dict)

    def score(self, cam_a: str, i: int, cam_b: str, j: int) -> PairScore | None:
        if self.cameras.index(cam_a) > self.cameras.index(cam_b):
            cam_a, i, cam_b, j = cam_b, j, cam_a, i
        return self.scores.get((cam_a, i, cam_b, j))

    def affinity(self, person: int) -> float:
        """The person's pooled inlier ratio over all its pairs of tracks in different cameras
        (NaN for a person seen by one camera only)."""
        return _pooled(self, _nodes(self.people[person]), _nodes(self.people[person]))


def _nodes(person: Mapping[str, tuple[int, ...]]) -> list[tuple[str, int]]:
    return [(cam, i) for cam, tracks in person.items() for i in tracks]


def _pooled(assoc: Association, group_a, group_b) -> float:
    inliers = total = 0
    for cam_a, i in group_a:
        for cam_b, j in group_b:
            if cam_a != cam_b:
                s = assoc.score(cam_a, i, cam_b, j)
                if s is not None:
                    inliers, total = inliers + s.inliers, total + s.correspondences
    return inliers / total if total else float("nan")


def associate_tracks(
    tracks: Mapping[str, np.ndarray],
    intrinsics: Mapping[str, np.ndarray],
    distortion: Mapping[str, np.ndarray | None] | None = None,
    *,
    keypoint_format: str = "blazepose33",
    threshold: float = DEFAULT_THRESHOLD,
    min_affinity: float = DEFAULT_MIN_AFFINITY,
    min_correspondences: int = MIN_CORRESPONDENCES,
    seed: int = 0,
    moving: Mapping[str, bool] | None = None,
    window: int = 10,
) -> Association:
    """Group every camera's person tracks into people.

    Args:
        tracks: camera name → ``(P, T, K, 3)`` pixel keypoints of its tracks (``P`` may be 0).
        intrinsics: camera name → ``(3, 3)``, calibrated or guessed.
        distortion: camera name → OpenCV distortion ``(5,)`` or None (no distortion).
        keypoint_format: the keypoints' format (its left/right pairs give the swap to tolerate).
        threshold: inlier distance of :func:`score_pair` as a fraction of the person's height in pixels.
        min_affinity: two groups are joined only when their pooled inlier ratio is at least this.
        min_correspondences: see :func:`score_pair`.
        seed: RANSAC seed.
        moving: camera name → whether it moves (absent: static). A pair with a moving camera is
            scored on windows of ``window`` frames, each with its own geometry
            (:func:`score_moving_pair`).
        window: frames per window of a moving pair (about half a second: long enough that two
            people move differently within it, short enough that the camera barely moves).

    Returns:
        the association; people are ordered by how many cameras see them, then by affinity.
    """
    cameras = tuple(tracks)
    missing = [c for c in cameras if c not in intrinsics]
    if missing:
        raise MocapgraphError(f"associate_tracks: no intrinsics for camera(s) {missing}")
    fmt = get_format(keypoint_format)
    swap = swap_permutation(fmt.names, "body")
    distortion = distortion or {}
    coords, focal, seen, height = {}, {}, {}, {}
    for cam in cameras:
        kp = np.asarray(tracks[cam], dtype=float)
        if kp.ndim != 4 or kp.shape[2:] != (fmt.num_points, 3):
            raise MocapgraphError(f"camera {cam}: tracks must be (P, T, {fmt.num_points}, 3), got {kp.shape}")
        K = np.asarray(intrinsics[cam], dtype=float)
        coords[cam] = normalised_points(kp, K, distortion.get(cam))
        focal[cam] = float(np.sqrt(K[0, 0] * K[1, 1]))
        seen[cam] = np.isfinite(kp[..., 2]).any(-1)
        height[cam] = track_heights(kp)
    moves = {cam for cam, m in (moving or {}).items() if m}
    assoc = Association(cameras, [])
    for ca, cam_a in enumerate(cameras):
        for cam_b in cameras[ca + 1 :]:
            f = float(np.sqrt(focal[cam_a] * focal[cam_b]))
            for i, a in enumerate(coords[cam_a]):
                for j, b in enumerate(coords[cam_b]):
                    threshold_px = threshold * float(np.sqrt(height[cam_a][i] * height[cam_b][j]))
                    if not np.isfinite(threshold_px):
                        continue
                    kw = dict(threshold_px=threshold_px, min_correspondences=min_correspondences, seed=seed)
                    s = score_moving_pair(a, b, f, swap, window=window, **kw) if {cam_a, cam_b} & moves else score_pair(a, b, f, swap, **kw)
                    if s is not None:
                        assoc.scores[(cam_a, i, cam_b, j)] = s
                        log.debug("%s/%d ~ %s/%d: %.2f inliers, median %.1f px, %d swapped frames over %d",
                                  cam_a, i, cam_b, j, s.inlier_ratio, s.median_error_px, len(s.swapped_frames), s.frames)  # fmt: skip

    def compatible(group_a, group_b) -> bool:
        """No camera would see the person twice in more than :data:`MAX_SHARED_FRAMES` frames."""
        return not any(
            cam_a == cam_b and (seen[cam_a][i] & seen[cam_a][j]).sum() > MAX_SHARED_FRAMES for cam_a, i in group_a for cam_b, j in group_b
        )

    groups = [[(cam, i)] for cam in cameras for i in range(len(coords[cam]))]
    while True:
        best, pair = min_affinity, None
        for g in range(len(groups)):
            for h in range(g + 1, len(groups)):
                value = _pooled(assoc, groups[g], groups[h])
                if value >= best and compatible(groups[g], groups[h]):
                    best, pair = value, (g, h)
        if pair is None:
            break
        g, h = pair
        groups[g] = groups[g] + groups.pop(h)
    people = []
    for group in groups:
        person: dict[str, tuple[int, ...]] = {}
        for cam in cameras:
            mine = tuple(sorted(i for c, i in group if c == cam))
            if mine:
                person[cam] = mine
        people.append(person)
    assoc.people = people
    order = sorted(range(len(people)), key=lambda p: (-len(people[p]), -np.nan_to_num(assoc.affinity(p), nan=0.0)))
    assoc.people = [people[p] for p in order]
    return assoc
