"""Two-view geometry of body keypoints: essential matrices, relative poses, left/right swap checks.

Cameras with known intrinsics and unknown poses watch the same person. Every keypoint that two
cameras see in the same frame is a correspondence, and pooled over a capture (hundreds of
frames, the person moving about) they fix each pair's essential matrix and relative pose, as
interest points do in structure from motion: :func:`relative_pose` (``cv2.findEssentialMat``
with three robust estimators on normalised coordinates, ``cv2.recoverPose``, a robust Sampson
refinement, the best of them kept), :func:`pair_geometries` for every pair of a rig.

A 2D detector that confuses the person's left and right in a frame (whole body, or only the arms
or legs: :mod:`mocapgraph.body.labelling`) reports points that break the epipolar geometry of
every other camera; relabelled by the swap's permutation they fit it again.
:func:`pair_tables` scores every pair's fit under every combination of the two cameras'
labellings, :func:`labelling_cost` adds a prior against swaps and against changes from frame to
frame (detectors swap in runs), and :func:`resolve_swaps` lowers it, one camera
(:func:`decide_labels`, Viterbi) or one frame (:func:`best_frames`) at a time, or for a few
cameras all of them over the sequence (:func:`joint_labels`), alternating with
new essential matrices on the new labels. A swap every camera shares fits as well as none: the
skeleton's handedness and limbs (:func:`anatomy_scores`, :func:`absolute_labels`) decide those.
With two cameras a swap of either fits alike; each camera's own 2D track, which jumps where a
run starts and ends, tells whose (:func:`track_tables`, ``resolve_swaps(continuity=True)``).

Arrays of a rig (``C`` cameras, ``N`` frames on one clock, ``K`` points of one format):

- ``x (C, N, K, 2)``: undistorted pixels (the pinhole image of ``Ks[c]``), NaN where not seen;
- ``w (C, N, K)``: confidences, 0 where not seen (or not to be used);
- ``Ks (C, 3, 3)``: intrinsics;
- labels ``(C, N)``: integer codes of :data:`~mocapgraph.body.labelling.SWAP_KINDS` (0 = as detected).

A relative pose ``(R, t)`` of cameras ``a, b`` maps camera ``a``'s coordinates to ``b``'s,
``X_b = R X_a + t`` (OpenCV cameras, +z forward), with ``‖t‖ = 1``: two views fix no scale.
"""

from __future__ import annotations

import itertools
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from mocapgraph.body.labelling import SWAP_KINDS, swap_permutation, swap_permutations
from mocapgraph.errors import MocapgraphError, as_checked_array

MIN_CORRESPONDENCES = 15
"""Fewest co-visible keypoints for a pair's essential matrix (the five-point solver needs 5; RANSAC
on a handful of points of one or two frames would fit their noise)."""

RANSAC_CONFIDENCE = 0.999
RANSAC_MAX_ITERATIONS = 2000

ESSENTIAL_ESTIMATORS = (cv2.USAC_ACCURATE, cv2.RANSAC, cv2.LMEDS)
"""Robust estimators whose essential matrices :func:`relative_pose` refines and compares. Each
deterministic for the same input (OpenCV seeds them itself). On a person between two cameras
that face each other, the inlier count of a loose threshold barely tells the true pose from one
120° off (3302 against 3271 of 3392 correspondences), and LO-RANSAC took the wrong one; after
refinement, the truncated squared Sampson distance tells them apart (23 against 34 px²)."""

REFINE_SCALE_DIVISOR = 5.0
"""The refinement's robust scale is the RANSAC threshold over this (3 px for 15 px): near the
keypoints' noise, so the inliers count fully and the points near the threshold less."""

SWAP_NATS = 2.0
"""Prior cost of a swapped camera-frame, nats (negative log prior odds against a swap)."""

SWITCH_NATS = 4.0
"""Cost of a change of labelling from one frame to the next, nats: detectors swap in runs (a
tracker carries a wrong reading on), so one noisy frame should not flip a run or start one."""

ANATOMY_MARGIN = {"body": 0.3, "legs": 0.2, "arms": 0.2}
"""How far from 0 a frame's :func:`anatomy_scores` must lie to decide its labels' absolute
side; nearer, the labelling with fewer swaps is kept."""

MIN_ANATOMY_PAIRS = 2
"""Fewest camera pairs whose skeletons must be scored for the body to decide a frame's labels:
one pair's skeleton can be the other side's points guessed by a detector that sees the back."""

_FLOOR_PX2 = 0.25
"""Added to a mean squared Sampson distance (px²) before its logarithm: below a quarter of a
squared pixel, differences are rounding, not evidence (and noise-free data stays finite)."""

MAX_JOINT_CAMERAS = 6
"""Up to this many cameras, :func:`resolve_swaps` also tries every joint labelling of a frame
(:func:`best_frames`: 4096 per frame for 6 cameras); with more, only one camera at a time."""

MAX_SEQUENCE_CAMERAS = 4
"""Up to this many cameras, :func:`resolve_swaps` ends its moves with the least-cost labels of
all cameras over the whole sequence (:func:`joint_labels`: 256 joint labellings per frame for
4 cameras, 256² transitions). One camera's or one frame's moves can stop short of it: on a
4 s ``phones`` capture a carried phone's whole-body run beside a static phone's leg run was
found as arms in the one and legs in two others (60 nats above the truth's labels)."""

_MAX_MOVES = 100
_MIN_GAIN_NATS = 1e-6

MIN_SWAP_POINTS = 4
"""Fewest co-visible correspondences of a pair in a frame for its labellings to be scored."""

MAX_TRACK_GAP = 5
"""Frames without the person (a detector's misses) that :func:`track_tables` bridges at most:
0.17 s at 30 fps, over which the person's move in the image stays well below a swap's jump."""


@dataclass(frozen=True)
class PairGeometry:
    """The epipolar geometry of cameras ``a < b`` from their co-visible keypoints.

    Attributes:
        a, b: camera indices.
        E: ``(3, 3)`` essential matrix, ``x̂_bᵀ E x̂_a = 0`` for normalised homogeneous points.
        R, t: ``(3, 3)``, ``(3,)``: ``X_b = R X_a + t``, ``‖t‖ = 1``.
        F: ``(3, 3)`` fundamental matrix of the undistorted pixels, ``x_bᵀ F x_a = 0``.
        inliers: correspondences within the threshold of their epipolar geometry (Sampson distance).
        correspondences: co-visible keypoints offered.
        median_angle_deg: median angle between the two rays of the inliers: how well the pair
            triangulates (0 for a pure rotation).
    """

    a: int
    b: int
    E: np.ndarray
    R: np.ndarray
    t: np.ndarray
    F: np.ndarray
    inliers: int
    correspondences: int
    median_angle_deg: float


@dataclass
class SwapCheck:
    """The outcome of :func:`resolve_swaps`.

    Attributes:
        labels: ``(C, N)`` codes of :data:`SWAP_KINDS` that undo each camera-frame's swap.
        pairs: the pairs' geometries estimated on the final labels.
        rounds: estimate-and-relabel rounds run.
        converged: the last round changed no label (False also when the labels came back to
            those of an earlier round: a borderline frame flipping to and fro).
    """

    labels: np.ndarray
    pairs: dict[tuple[int, int], PairGeometry]
    rounds: int
    converged: bool


def normalised(pixels, K) -> np.ndarray:
    """``(…, 2)`` undistorted pixels → ``(…, 2)`` normalised image coordinates ``K⁻¹ [x, 1]``."""
    x = np.asarray(pixels, dtype=float)
    K = np.asarray(K, dtype=float)
    # K is upper triangular: solve for the normalised point without forming K⁻¹.
    v = (x[..., 1] - K[1, 2]) / K[1, 1]
    u = (x[..., 0] - K[0, 2] - K[0, 1] * v) / K[0, 0]
    return np.stack([u, v], axis=-1)


def fundamental_matrix(E, K_a, K_b) -> np.ndarray:
    """``(3, 3)`` ``F = K_b⁻ᵀ E K_a⁻¹``, the essential matrix ``E`` in undistorted pixels."""
    return np.linalg.inv(np.asarray(K_b, dtype=float)).T @ np.asarray(E, dtype=float) @ np.linalg.inv(np.asarray(K_a, dtype=float))


def sampson_px(F, x_a, x_b) -> np.ndarray:
    """``(…)`` Sampson distance (pixels) of correspondences ``x_a, x_b (…, 2)`` under ``F``
    (``x_bᵀ F x_a = 0``): the first-order estimate of the smallest total image displacement that
    makes the pair consistent; NaN where either point is NaN."""
    F = np.asarray(F, dtype=float)
    ha = np.concatenate([np.asarray(x_a, dtype=float), np.ones(np.shape(x_a)[:-1] + (1,))], axis=-1)
    hb = np.concatenate([np.asarray(x_b, dtype=float), np.ones(np.shape(x_b)[:-1] + (1,))], axis=-1)
    Fa = ha @ np.swapaxes(F, -1, -2)  # F x_a: the epipolar line in b
    Fb = hb @ F  # Fᵀ x_b: the epipolar line in a
    e = np.sum(hb * Fa, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.abs(e) / np.sqrt(Fa[..., 0] ** 2 + Fa[..., 1] ** 2 + Fb[..., 0] ** 2 + Fb[..., 1] ** 2)


def _skew(v: np.ndarray) -> np.ndarray:
    """``(…, 3, 3)`` the cross-product matrices of ``v (…, 3)``."""
    v = np.asarray(v, dtype=float)
    zero = np.zeros(v.shape[:-1])
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)], -2)


def _sampson_signed(F: np.ndarray, ha: np.ndarray, hb: np.ndarray) -> np.ndarray:
    Fa, Fb = ha @ F.T, hb @ F
    return np.sum(hb * Fa, axis=1) / np.sqrt(Fa[:, 0] ** 2 + Fa[:, 1] ** 2 + Fb[:, 0] ** 2 + Fb[:, 1] ** 2)


def refine_pose(R, t, x_a, x_b, K_a, K_b, *, scale_px: float) -> tuple[np.ndarray, np.ndarray]:
    """``(R, t)`` of :func:`relative_pose` moved to the least robust sum of the correspondences'
    Sampson distances (pixels; scipy's ``soft_l1`` loss at ``scale_px``): RANSAC's model comes
    from five points, and on body keypoints it is off by a degree or more. ``x_a, x_b (M, 2)``:
    undistorted pixels of the correspondences to fit (the inliers). Returns ``R (3, 3)`` and
    ``t (3,)`` with ``‖t‖ = 1``."""
    R0, t0 = np.asarray(R, dtype=float), np.asarray(t, dtype=float).ravel() / np.linalg.norm(t)
    tangent = np.linalg.svd(t0[None])[2][1:].T  # (3, 2): the directions t may move in on the unit sphere
    ha = np.column_stack([x_a, np.ones(len(x_a))])
    hb = np.column_stack([x_b, np.ones(len(x_b))])
    Ka_inv, Kb_inv_T = np.linalg.inv(K_a), np.linalg.inv(K_b).T

    def model(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t = t0 + tangent @ p[3:]
        return Rotation.from_rotvec(p[:3]).as_matrix() @ R0, t / np.linalg.norm(t)

    def residuals(p: np.ndarray) -> np.ndarray:
        R, t = model(p)
        return _sampson_signed(Kb_inv_T @ _skew(t) @ R @ Ka_inv, ha, hb)

    solution = least_squares(residuals, np.zeros(5), loss="soft_l1", f_scale=scale_px, x_scale="jac")
    return model(solution.x)


def _estimates(na: np.ndarray, nb: np.ndarray, threshold: float):
    """``(R, t, inliers)`` of every essential matrix the :data:`ESSENTIAL_ESTIMATORS` find for
    normalised correspondences ``na, nb (M, 2)`` (``threshold`` in normalised units), each posed
    in front of both cameras by ``recoverPose``."""
    for method in ESSENTIAL_ESTIMATORS:
        E, mask = cv2.findEssentialMat(na, nb, np.eye(3), method=method, prob=RANSAC_CONFIDENCE, threshold=threshold, maxIters=RANSAC_MAX_ITERATIONS)
        if E is None or mask is None:
            continue
        # A five-point sample can give several solutions, stacked.
        for k in range(E.shape[0] // 3):
            _, R, t, inlier = cv2.recoverPose(E[3 * k : 3 * k + 3], na, nb, np.eye(3), mask=mask.copy())
            yield R, t, inlier.ravel() > 0


def relative_pose(x_a, x_b, K_a, K_b, *, threshold_px: float, a: int = 0, b: int = 1, start: PairGeometry | None = None) -> PairGeometry | None:
    """The epipolar geometry of two cameras from correspondences.

    Each of :data:`ESSENTIAL_ESTIMATORS` finds essential matrices on normalised coordinates,
    ``recoverPose`` their poses in front of both cameras and :func:`refine_pose` fits each to its
    inliers; the pose of least mean truncated squared Sampson distance over all correspondences
    wins, and its inliers are counted again.

    Args:
        x_a, x_b: ``(M, 2)`` undistorted pixels of the same points in cameras ``a`` and ``b``
            (rows with a NaN are left out).
        K_a, K_b: ``(3, 3)`` intrinsics.
        threshold_px: RANSAC inlier threshold on the distance to the epipolar line, pixels (taken
            at the pair's mean focal length in normalised coordinates).
        a, b: the camera indices to record.
        start: a pose of the pair from nearly the same correspondences (the previous round of
            :func:`resolve_swaps`): refined from its inliers instead of searched for anew.

    Returns:
        A :class:`PairGeometry`, or None with fewer than :data:`MIN_CORRESPONDENCES`
        correspondences or inliers.
    """
    x_a = as_checked_array(x_a, "x_a", (None, 2), finite=False)
    x_b = as_checked_array(x_b, "x_b", (len(x_a), 2), finite=False)
    keep = np.isfinite(x_a).all(1) & np.isfinite(x_b).all(1)
    x_a, x_b = x_a[keep], x_b[keep]
    na, nb = normalised(x_a, K_a), normalised(x_b, K_b)
    M = len(na)
    if M < MIN_CORRESPONDENCES:
        return None
    focal = float(np.mean([K_a[0, 0], K_a[1, 1], K_b[0, 0], K_b[1, 1]]))
    best, best_cost = None, np.inf
    for R, t, inlier in [(start.R, start.t, sampson_px(start.F, x_a, x_b) < threshold_px)] if start is not None else _estimates(na, nb, threshold_px / focal):
        if inlier.sum() < MIN_CORRESPONDENCES:
            continue
        R, t = refine_pose(R, t, x_a[inlier], x_b[inlier], K_a, K_b, scale_px=threshold_px / REFINE_SCALE_DIVISOR)
        F = fundamental_matrix(_skew(t) @ R, K_a, K_b)
        cost = float(np.mean(np.minimum(sampson_px(F, x_a, x_b), threshold_px) ** 2))
        if cost < best_cost:
            best, best_cost = (R, t, F), cost
    if best is None:
        return None
    R, t, F = best
    E = _skew(t) @ R
    inlier = sampson_px(F, x_a, x_b) < threshold_px
    if inlier.sum() < MIN_CORRESPONDENCES:
        return None
    ray_a = np.column_stack([na[inlier], np.ones(inlier.sum())])
    ray_b = np.column_stack([nb[inlier], np.ones(inlier.sum())]) @ R  # Rᵀ ray_b: b's rays in a's frame
    cos = np.sum(ray_a * ray_b, axis=1) / (np.linalg.norm(ray_a, axis=1) * np.linalg.norm(ray_b, axis=1))
    angle = float(np.degrees(np.median(np.arccos(np.clip(cos, -1.0, 1.0)))))
    return PairGeometry(a, b, E, R, t, F, int(inlier.sum()), M, angle)


def _check_rig(x, w, Ks) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    x = as_checked_array(x, "x (C, N, K, 2)", (None, None, None, 2), finite=False)
    C, N, K = x.shape[:3]
    w = as_checked_array(w, "w (C, N, K)", (C, N, K))
    Ks = as_checked_array(Ks, "Ks (C, 3, 3)", (C, 3, 3))
    if np.any(w < 0):
        raise MocapgraphError("w (C, N, K): confidences must be >= 0")
    return x, np.where(np.isfinite(x).all(-1), w, 0.0), Ks


def pair_from_poses(a: int, b: int, world_T_a, world_T_b, K_a, K_b) -> PairGeometry:
    """The epipolar geometry of calibrated cameras ``a < b`` from their poses (``world_T_camera``,
    OpenCV axes), as :func:`relative_pose` would estimate it (no correspondences counted).

    Poses ``(4, 4)`` give one geometry; poses ``(N, 4, 4)`` of moving cameras give one per frame
    (``E``, ``R``, ``F`` ``(N, 3, 3)``, ``t`` ``(N, 3)``), which :func:`pair_tables`,
    :func:`sampson_px` and :func:`triangulate_pair` take frame by frame."""
    b_T_a = np.linalg.inv(np.asarray(world_T_b, dtype=float)) @ np.asarray(world_T_a, dtype=float)
    R, t = b_T_a[..., :3, :3], b_T_a[..., :3, 3]
    norm = np.linalg.norm(t, axis=-1, keepdims=True)
    if np.any(norm < 1e-9):
        raise MocapgraphError(f"cameras {a} and {b} share a centre: no epipolar geometry")
    t = t / norm
    E = _skew(t) @ R
    return PairGeometry(a, b, E, R, t, fundamental_matrix(E, K_a, K_b), 0, 0, 0.0)


def pair_geometries(x, w, Ks, *, threshold_px: float, previous: dict[tuple[int, int], PairGeometry] | None = None) -> dict[tuple[int, int], PairGeometry]:
    """:func:`relative_pose` of every pair ``a < b`` of a rig from all its frames' co-visible
    keypoints (``w > 0`` in both); pairs without a geometry are left out. ``previous``: the
    pairs' geometries from nearly the same keypoints, to refine instead of searching anew."""
    x, w, Ks = _check_rig(x, w, Ks)
    C = len(x)
    out = {}
    for a in range(C):
        for b in range(a + 1, C):
            both = (w[a] > 0) & (w[b] > 0)
            geometry = relative_pose(x[a][both], x[b][both], Ks[a], Ks[b], threshold_px=threshold_px, a=a, b=b, start=(previous or {}).get((a, b)))
            if geometry is not None:
                out[(a, b)] = geometry
    return out


def apply_labels(values, labels, names: Sequence[str]) -> np.ndarray:
    """``values (C, N, K, …)`` with camera-frame ``(c, n)``'s points permuted by the swap
    ``SWAP_KINDS[labels[c, n]]`` (a swap is its own inverse: applying labels twice restores)."""
    out = np.array(values, copy=True)
    labels = np.asarray(labels)
    for code, kind in enumerate(SWAP_KINDS):
        hit = labels == code
        if code and hit.any():
            out[hit] = out[hit][:, swap_permutation(names, kind)]
    return out


def _misfit_nats(total: np.ndarray, count: np.ndarray) -> np.ndarray:
    """``(..., S, S)`` nats from the truncated squared distances' sums ``total`` and their counts
    ``count`` under every pair of labellings (last two axes): ``m/2 · log(mean d²)`` with ``m``
    the most points any labelling pair shares there (:func:`pair_tables`); 0 with fewer than
    :data:`MIN_SWAP_POINTS`."""
    most = count.max(axis=(-2, -1), keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        nats = 0.5 * most * np.log(total / count + _FLOOR_PX2)
    return np.where((count >= MIN_SWAP_POINTS) & (most >= MIN_SWAP_POINTS), nats, 0.0)


def pair_tables(x, w, Ks, pairs: dict[tuple[int, int], PairGeometry], names: Sequence[str], *, cap_px: float) -> dict[tuple[int, int], np.ndarray]:
    """Each pair's epipolar misfit, in nats, under every combination of the two cameras' labellings.

    For pair ``(a, b)`` and frame ``n``, with ``a``'s points under swap ``SWAP_KINDS[i]`` and
    ``b``'s under ``SWAP_KINDS[j]``: ``m`` co-visible correspondences with Sampson distances ``d``
    (pixels), truncated at ``cap_px`` so that one wrong point (an outlier, another person) cannot
    decide. The cost is the Gaussian negative log-likelihood with the frame's noise unknown,
    maximised over it: ``m/2 · log(mean(min(d, cap_px)²))`` (up to a constant), so differences
    between labellings are ``m/2 · log`` of the ratio of their mean squared distances: a frame
    that fits badly under every labelling (a side view, heavy noise) gives little evidence,
    however large its distances. A permutation can change which points are co-visible, so every
    combination is scored with the frame's largest ``m``; fewer than :data:`MIN_SWAP_POINTS`
    correspondences give no evidence (0).

    Returns:
        Per pair ``(a, b)``, ``(N, S, S)`` nats at ``[n, i, j]`` (``S = len(SWAP_KINDS)``).
    """
    x, w, Ks = _check_rig(x, w, Ks)
    C, N, K = w.shape
    if len(names) != K:
        raise MocapgraphError(f"names: {len(names)} point names for {K} keypoints")
    perms = swap_permutations(names)
    S = len(perms)
    tables = {}
    for (a, b), geometry in pairs.items():
        total, count = np.zeros((N, S, S)), np.zeros((N, S, S), dtype=int)
        for i, pa in enumerate(perms):
            for j, pb in enumerate(perms):
                both = (w[a][:, pa] > 0) & (w[b][:, pb] > 0)
                d = np.minimum(sampson_px(geometry.F, x[a][:, pa], x[b][:, pb]), cap_px)
                total[:, i, j] = np.where(both, d**2, 0.0).sum(axis=1)
                count[:, i, j] = both.sum(axis=1)
        tables[(a, b)] = _misfit_nats(total, count)
    return tables


def track_tables(x, w, names: Sequence[str], *, cap_px: float, max_gap: int = MAX_TRACK_GAP) -> np.ndarray:
    """Each camera's own 2D track, in nats, under every combination of its labellings in two
    consecutive frames: ``(C, N, S, S)`` at ``[c, n, i, j]`` with frame ``n - 1``'s points under
    swap ``SWAP_KINDS[i]`` and frame ``n``'s under ``SWAP_KINDS[j]`` (``S = len(SWAP_KINDS)``).

    A swap exchanges the left and right points in the image, so where a run starts or ends the
    points as detected jump by the sides' separation, while between frames the person and the
    camera move little; relabelled, the track goes on. This tells which camera of a pair swapped,
    which the pair's epipolar geometry cannot (:func:`pair_tables` scores a swap of either camera
    alike). The cost has :func:`pair_tables`' form, ``m/2 · log(mean(min(d, cap_px)²))`` over
    the ``m`` points seen in both frames, ``d`` each point's move in pixels less the mean move
    of them all (the camera's turn shifts the whole person; a permutation leaves the mean as it
    is). Only the labels' change counts: ``[c, n, i, i]`` are equal for every ``i``.

    A frame where the camera saw fewer than :data:`MIN_SWAP_POINTS` points (missed by the
    detector) is bridged: frame ``n`` is compared with the last frame before it that has them,
    up to ``max_gap`` frames back, under the label of frame ``n - 1`` (which the change prior
    ties to the earlier frame's, having no evidence of its own). Frame 0, and frames with no
    such predecessor, give 0.

    Args:
        x, w: ``(C, N, K, 2)`` pixels and ``(C, N, K)`` confidences (module docstring).
        names: the format's point names.
        cap_px: truncation of a point's move (a jump larger than this counts as this).
        max_gap: frames without the person that a track bridges at most.
    """
    x = as_checked_array(x, "x (C, N, K, 2)", (None, None, None, 2), finite=False)
    C, N, K = x.shape[:3]
    w = np.where(np.isfinite(x).all(-1), as_checked_array(w, "w (C, N, K)", (C, N, K)), 0.0)
    if len(names) != K:
        raise MocapgraphError(f"names: {len(names)} point names for {K} keypoints")
    perms = swap_permutations(names)
    S = len(perms)
    if N < 2:
        return np.zeros((C, N, S, S))
    # each frame's predecessor: the last earlier frame with enough points, within max_gap
    tracked = (w > 0).sum(axis=-1) >= MIN_SWAP_POINTS
    last = np.maximum.accumulate(np.where(tracked, np.arange(N), -1), axis=1)
    prev = np.concatenate([np.full((C, 1), -1), last[:, :-1]], axis=1)
    prev = np.where(np.arange(N) - prev <= max_gap + 1, prev, -1)
    rows = np.arange(C)[:, None]
    x0, w0 = x[rows, np.maximum(prev, 0)], np.where((prev >= 0)[..., None], w[rows, np.maximum(prev, 0)], 0.0)
    seen = (w0 > 0) & (w > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        shift = np.where(seen[..., None], x - x0, 0.0).sum(axis=2, keepdims=True) / seen.sum(axis=-1)[..., None, None]
    shift = np.nan_to_num(shift)  # frames that share no point with their predecessor score nothing
    total, count = np.zeros((C, N, S, S)), np.zeros((C, N, S, S), dtype=int)
    for i, pi in enumerate(perms):
        for j, pj in enumerate(perms):
            both = (w0[..., pi] > 0) & (w[..., pj] > 0)
            d = np.minimum(np.linalg.norm(x[:, :, pj] - x0[:, :, pi] - shift, axis=-1), cap_px)
            total[..., i, j] = np.where(both, d**2, 0.0).sum(axis=-1)
            count[..., i, j] = both.sum(axis=-1)
    return _misfit_nats(total, count)


def swap_costs(tables: dict[tuple[int, int], np.ndarray], labels) -> np.ndarray:
    """``(C, N, len(SWAP_KINDS))`` nats: how badly each labelling of each camera-frame fits the
    other cameras' epipolar geometry under their current ``labels (C, N)``: the sum of its
    pairs' :func:`pair_tables` entries (the part of :func:`labelling_cost` that camera ``c``'s
    label at frame ``n`` changes, but for the prior and the changes in time)."""
    labels = np.asarray(labels, dtype=int)
    C, N = labels.shape
    frames = np.arange(N)
    nats = np.zeros((C, N, len(SWAP_KINDS)))
    for (a, b), table in tables.items():
        nats[a] += table[frames, :, labels[b]]
        nats[b] += table[frames, labels[a], :]
    return nats


def labelling_cost(
    tables: dict[tuple[int, int], np.ndarray], labels, *, swap_nats: float = SWAP_NATS, switch_nats: float = SWITCH_NATS, tracks: np.ndarray | None = None
) -> float:
    """The objective :func:`resolve_swaps` lowers: every pair's misfit (:func:`pair_tables`) at
    every frame, plus ``swap_nats`` per swapped camera-frame and ``switch_nats`` per change of a
    camera's labelling from one frame to the next (frames before the first and after the last
    count as unswapped), plus, given ``tracks`` (:func:`track_tables`), each camera's own track
    from frame to frame under its labels."""
    labels = np.asarray(labels, dtype=int)
    frames = np.arange(labels.shape[1])
    misfit = sum(float(table[frames, labels[a], labels[b]].sum()) for (a, b), table in tables.items())
    if tracks is not None and labels.shape[1] > 1:
        misfit += float(sum(tracks[c, frames[1:], row[:-1], row[1:]].sum() for c, row in enumerate(labels)))
    padded = np.pad(labels, ((0, 0), (1, 1)))
    return misfit + swap_nats * np.count_nonzero(labels) + switch_nats * np.count_nonzero(np.diff(padded, axis=1))


def _unary(nats: np.ndarray, codes: np.ndarray, swap_nats: float) -> np.ndarray:
    unary = np.nan_to_num(np.asarray(nats, dtype=float)[..., codes], nan=0.0)
    unary[..., 1:] += swap_nats
    return unary


def _kind_codes(kinds: Sequence[str]) -> np.ndarray:
    if any(k not in SWAP_KINDS[1:] for k in kinds):
        raise MocapgraphError(f"swap kinds: choose among {', '.join(SWAP_KINDS[1:])}, got {', '.join(kinds)}")
    return np.array([0] + [SWAP_KINDS.index(k) for k in kinds])


def decide_labels(
    nats, kinds: Sequence[str] = SWAP_KINDS[1:], *, swap_nats: float = SWAP_NATS, switch_nats: float = SWITCH_NATS, tracks: np.ndarray | None = None
) -> np.ndarray:
    """``(N,)`` label codes of one camera's frames from their costs ``nats (N, len(SWAP_KINDS))``
    (:func:`swap_costs`): the sequence of labellings, among ``"none"`` and ``kinds``, of least
    total cost plus ``swap_nats`` per swapped frame and ``switch_nats`` per change between
    consecutive frames (Viterbi), plus, given this camera's ``tracks (N, S, S)`` (a camera's
    slice of :func:`track_tables`), its track under the labels. A frame without a cost (NaN) is
    decided by its neighbours."""
    codes = _kind_codes(kinds)
    unary = _unary(nats, codes, swap_nats)
    N, S = unary.shape
    if N == 0:
        return np.zeros(0, dtype=int)
    change = switch_nats * (1.0 - np.eye(S))
    # Frames before the first and after the last count as unswapped: a run at either end pays
    # for its one change as much as a run inside pays for its two.
    best = unary[0] + change[0]
    back = np.zeros((N, S), dtype=int)
    for n in range(1, N):
        step = best[:, None] + change + (0.0 if tracks is None else tracks[n][np.ix_(codes, codes)])  # [from, to]
        back[n] = np.argmin(step, axis=0)
        best = step[back[n], np.arange(S)] + unary[n]
    path = np.zeros(N, dtype=int)
    path[-1] = np.argmin(best + change[:, 0])
    for n in range(N - 1, 0, -1):
        path[n - 1] = back[n, path[n]]
    return codes[path]


def triangulate_pair(geometry: PairGeometry, x_a, x_b, K_a, K_b) -> np.ndarray:
    """``(…, 3)`` points in camera ``a``'s frame (its baseline to ``b`` of length 1) from
    undistorted pixels ``x_a, x_b (…, 2)``: the midpoint of the two rays' closest points; NaN
    where either pixel is NaN or the rays are parallel."""
    ray_a = np.concatenate([normalised(x_a, K_a), np.ones(np.shape(x_a)[:-1] + (1,))], axis=-1)
    ray_b = np.concatenate([normalised(x_b, K_b), np.ones(np.shape(x_b)[:-1] + (1,))], axis=-1) @ geometry.R  # Rᵀ ray_b
    centre_b = -np.einsum("...ji,...j->...i", geometry.R, geometry.t)
    if centre_b.ndim > 1:  # a geometry per frame: its centre for every point of the frame
        centre_b = centre_b[..., None, :]
    # Closest points λ ray_a and centre_b + μ ray_b: a 2×2 linear system per point.
    aa, bb, ab = np.sum(ray_a * ray_a, -1), np.sum(ray_b * ray_b, -1), np.sum(ray_a * ray_b, -1)
    ca, cb = np.sum(ray_a * centre_b, -1), np.sum(ray_b * centre_b, -1)
    with np.errstate(invalid="ignore", divide="ignore"):
        det = aa * bb - ab**2
        lam = (ca * bb - cb * ab) / det
        mu = (ca * ab - cb * aa) / det
        return 0.5 * (lam[..., None] * ray_a + centre_b + mu[..., None] * ray_b)


def _nanmean(vectors: list[np.ndarray]) -> np.ndarray:
    """The mean of the finite ones among ``vectors`` (each ``(…, 3)``), NaN where none is."""
    stacked = np.stack(vectors)
    finite = np.isfinite(stacked).all(axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(finite, stacked, 0.0).sum(axis=0) / finite.sum(axis=0)


def anatomy_scores(points, names: Sequence[str]) -> dict[str, np.ndarray]:
    """How well the labels of a 3D skeleton ``points (…, K, 3)`` (any right-handed frame and
    scale) fit a human body, per swap kind, positive where they do (NaN where points are missing):

    - ``"body"``: ``det[l, u, f]`` of the person's left, up and forward directions as unit
      vectors, right-handed for a person (about +0.9); with every label swapped it changes sign,
      while the epipolar geometry cannot tell. Each direction is the mean of the cues the
      skeleton has (a detector drops occluded points): left, the left minus the right shoulder,
      hip, ear and eye; up, the mean of the head and shoulder points minus that of the hips,
      knees and ankles; forward, the nose ahead of the ears' midpoint, the nose ahead of the
      shoulders (across the up direction) and each foot's toe ahead of its heel.
    - ``"legs"`` / ``"arms"``: how much nearer each knee (elbow) is to the hip (shoulder) of its
      own side than to the other's, over the hips' (shoulders') width.
    """
    names = list(names)
    p = np.asarray(points, dtype=float)
    nan = np.full(p.shape[:-2] + (3,), np.nan)
    pick = lambda n: p[..., names.index(n), :] if n in names else nan  # noqa: E731
    sides = lambda part: (pick(f"left_{part}"), pick(f"right_{part}"))  # noqa: E731
    with np.errstate(invalid="ignore", divide="ignore"):
        left = _nanmean([_unit(a - b) for a, b in map(sides, ("shoulder", "hip", "ear", "eye"))])
        upper = _nanmean([pick(n) for n in ("nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_shoulder", "right_shoulder")])
        lower = _nanmean([pick(f"{s}_{part}") for part in ("hip", "knee", "ankle") for s in ("left", "right")])
        up = _unit(upper - lower)
        lean = pick("nose") - _nanmean(list(sides("shoulder")))
        cues = [pick("nose") - 0.5 * np.sum(sides("ear"), axis=0), lean - np.sum(lean * up, axis=-1, keepdims=True) * up]
        toe = "big_toe" if "left_big_toe" in names else "foot_index"
        cues += [pick(f"{s}_{toe}") - pick(f"{s}_heel") for s in ("left", "right")]
        forward = _nanmean([_unit(c) for c in cues])
        scores = {"body": np.linalg.det(np.stack([_unit(left), up, _unit(forward)], axis=-1))}
        for kind, (root, end) in {"legs": ("hip", "knee"), "arms": ("shoulder", "elbow")}.items():
            (l_root, r_root), (l_end, r_end) = sides(root), sides(end)
            crossed = np.linalg.norm(l_end - r_root, axis=-1) + np.linalg.norm(r_end - l_root, axis=-1)
            own = np.linalg.norm(l_end - l_root, axis=-1) + np.linalg.norm(r_end - r_root, axis=-1)
            scores[kind] = (crossed - own) / np.linalg.norm(l_root - r_root, axis=-1)
    return scores


def _unit(v: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / np.linalg.norm(v, axis=-1, keepdims=True)


def absolute_labels(
    labels, seen, scores: dict[str, np.ndarray], decided: dict[str, np.ndarray], kinds: Sequence[str] = SWAP_KINDS[1:], *, fewer_swaps: bool = True
) -> np.ndarray:
    """``(C, N)`` labels with, in each frame, a swap of one kind in every camera added or taken
    away where the body says so.

    Swapping a kind in every camera at once changes no correspondence: the epipolar geometry
    fixes the cameras' labels only relative to each other. In a frame whose cameras (those that
    see the person, ``seen (C, N)``) carry only ``"none"`` and one kind, the labelling and its
    complement are told apart by the skeleton's ``scores[kind] (N,)`` (:func:`anatomy_scores`
    under the current labels) where ``decided[kind] (N,)``: a negative score means the complement;
    elsewhere the one with fewer swaps is kept (with ``fewer_swaps``; without, the labels as they
    are: where each camera's own track has decided them, :func:`track_tables`, a frame's flip
    alone would break every track). Cameras that do not see the person get label 0.
    """
    seen = np.asarray(seen, dtype=bool)
    labels = np.where(seen, np.asarray(labels, dtype=int), 0)
    count = seen.sum(axis=0)
    for code in _kind_codes(kinds)[1:]:
        kind = SWAP_KINDS[code]
        only = np.all(~seen | (labels == 0) | (labels == code), axis=0)
        flip = only & np.where(decided[kind], scores[kind] < 0, fewer_swaps & (2 * np.sum(labels == code, axis=0) > count))
        labels[:, flip] = np.where(seen[:, flip], code - labels[:, flip], 0)
    return labels


def pair_anatomy(x, w, Ks, pairs: dict[tuple[int, int], PairGeometry], names: Sequence[str], labels) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Per frame and kind, the median over camera pairs of :func:`anatomy_scores` of the
    skeleton each pair triangulates under ``labels`` ``(N,)``, and whether it decides
    (:data:`MIN_ANATOMY_PAIRS` pairs score it, beyond :data:`ANATOMY_MARGIN`): the input of
    :func:`absolute_labels` before the cameras are placed in one frame."""
    x, w, Ks = _check_rig(x, w, Ks)
    xl = np.where(apply_labels(w, labels, names)[..., None] > 0, apply_labels(x, labels, names), np.nan)
    per_pair = [anatomy_scores(triangulate_pair(g, xl[g.a], xl[g.b], Ks[g.a], Ks[g.b]), names) for g in pairs.values()]
    scores, decided = {}, {}
    for kind in SWAP_KINDS[1:]:
        stacked = np.stack([s[kind] for s in per_pair]) if per_pair else np.full((1, w.shape[1]), np.nan)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # frames no pair triangulates
            scores[kind] = np.nanmedian(stacked, axis=0)
        decided[kind] = (np.isfinite(stacked).sum(axis=0) >= MIN_ANATOMY_PAIRS) & (np.abs(scores[kind]) >= ANATOMY_MARGIN[kind])
    return scores, decided


def best_frames(tables: dict[tuple[int, int], np.ndarray], labels, kinds: Sequence[str] = SWAP_KINDS[1:], tracks: np.ndarray | None = None) -> np.ndarray:
    """``(C, N)`` labels where each frame, given its neighbours, takes the labelling of all its
    cameras at once that lowers :func:`labelling_cost` (with ``tracks``, if given) the most (even
    frames first, then odd ones against the new even ones). Where several cameras are wrong
    together, no single camera's relabelling helps; this move can. It tries
    ``(1 + len(kinds))^C`` labellings per frame."""
    labels = np.asarray(labels, dtype=int)
    C, N = labels.shape
    codes = _kind_codes(kinds)
    position = np.zeros(len(SWAP_KINDS), dtype=int)
    position[codes] = np.arange(len(codes))
    states = np.array(list(itertools.product(codes, repeat=C)))  # (J, C), the first camera most significant
    misfit = np.zeros((N, len(states)))
    for (a, b), table in tables.items():
        misfit += table[:, states[:, a], states[:, b]]
    misfit += SWAP_NATS * np.count_nonzero(states, axis=1)
    out = labels.copy()
    if tracks is not None:
        ahead = np.concatenate([tracks[:, 1:], np.zeros_like(tracks[:, :1])], axis=1)  # into frame n + 1 (none past the last)
    for parity in (0, 1):
        padded = np.pad(out, ((0, 0), (1, 1)))
        before, after = padded[:, :-2].T, padded[:, 2:].T  # (N, C): each frame's neighbours
        cost = misfit + SWITCH_NATS * (np.sum(states[None] != before[:, None], axis=-1) + np.sum(states[None] != after[:, None], axis=-1))
        if tracks is not None:  # frame n's track from frame n - 1 and into frame n + 1
            for c in range(C):
                cost += tracks[c, np.arange(N)[:, None], before[:, c, None], states[None, :, c]]
                cost += ahead[c, np.arange(N)[:, None], states[None, :, c], after[:, c, None]]
        current = np.sum(position[out.T] * len(codes) ** np.arange(C - 1, -1, -1), axis=1)
        frames = np.arange(parity, N, 2)
        best = np.argmin(cost[frames], axis=1)
        better = cost[frames, best] < cost[frames, current[frames]] - _MIN_GAIN_NATS
        out[:, frames[better]] = states[best[better]].T
    return out


def joint_labels(tables: dict[tuple[int, int], np.ndarray], shape: tuple[int, int], kinds: Sequence[str] = SWAP_KINDS[1:], tracks: np.ndarray | None = None) -> np.ndarray:
    """``(C, N)`` = ``shape`` labels of least :func:`labelling_cost` (with ``tracks``, if given)
    over every joint labelling of the cameras at every frame (Viterbi over ``(1 + len(kinds))^C``
    states per frame: exact, for a few cameras)."""
    C, N = shape
    codes = _kind_codes(kinds)
    states = np.array(list(itertools.product(codes, repeat=C)))  # (J, C)
    misfit = np.zeros((N, len(states)))
    for (a, b), table in tables.items():
        misfit += table[:, states[:, a], states[:, b]]
    misfit += SWAP_NATS * np.count_nonzero(states, axis=1)
    change = SWITCH_NATS * np.sum(states[:, None, :] != states[None, :, :], axis=-1)  # [from, to]
    # frames before the first and after the last count as unswapped (labelling_cost)
    edge = SWITCH_NATS * np.count_nonzero(states, axis=1)
    best = misfit[0] + edge
    back = np.zeros((N, len(states)), dtype=np.int32)
    for n in range(1, N):
        step = best[:, None] + change
        if tracks is not None:
            step = step + sum(tracks[c, n][np.ix_(states[:, c], states[:, c])] for c in range(C))
        back[n] = np.argmin(step, axis=0)
        best = step[back[n], np.arange(len(states))] + misfit[n]
    path = np.zeros(N, dtype=int)
    path[-1] = np.argmin(best + edge)
    for n in range(N - 1, 0, -1):
        path[n - 1] = back[n, path[n]]
    return states[path].T


def resolve_swaps(
    x,
    w,
    Ks,
    names: Sequence[str],
    *,
    threshold_px: float,
    kinds: Sequence[str] = SWAP_KINDS[1:],
    max_rounds: int = 5,
    poses=None,
    continuity: bool = False,
) -> SwapCheck:
    """Essential matrices and left/right labels of a rig, estimated in turn until they agree.

    Each round estimates every pair's geometry on the current labels (:func:`pair_geometries`,
    refined from the previous round's) and lowers :func:`labelling_cost` by moves: relabel the
    camera whose best sequence of labels (:func:`decide_labels` against the others' current
    ones) lowers it the most; when no camera helps, relabel frames jointly (:func:`best_frames`);
    with at most :data:`MAX_SEQUENCE_CAMERAS` cameras, the least-cost labels of all of them
    over the sequence (:func:`joint_labels`) replace the moves' where they cost less; then
    the body decides each frame's absolute side (:func:`absolute_labels`
    from :func:`pair_anatomy`: a swap shared by every camera fits the epipolar geometry as well
    as none). Taking the strongest evidence first
    keeps a camera with many swaps from making the clean ones look swapped. The rounds stop when
    one changes no label (or after ``max_rounds``); the returned geometries are those of the
    final labels.

    Args:
        x, w, Ks: the rig's arrays as detected (module docstring).
        names: the format's point names.
        threshold_px: RANSAC inlier threshold of the essential matrices, also the truncation of
            the swap costs.
        kinds: which swaps to consider.
        max_rounds: estimate-and-relabel rounds at most.
        poses: world_T_camera of placed cameras, ``(C, 4, 4)`` (static) or ``(C, N, 4, 4)`` (per
            frame, for moving ones): their geometry is taken from the poses
            (:func:`pair_from_poses`) and only the labels are decided.
        continuity: add each camera's own 2D track to the objective (:func:`track_tables`):
            with two cameras the epipolar geometry says that a frame's labels disagree but not
            whose, the jumps of a camera's track where its run starts and ends do.
    """
    x, w, Ks = _check_rig(x, w, Ks)
    if max_rounds < 1:
        raise MocapgraphError(f"max_rounds: must be at least 1, got {max_rounds}")
    C, N, _ = w.shape
    labels = np.zeros((C, N), dtype=int)
    seen = (w > 0).any(axis=-1)
    tracks = track_tables(x, w, names, cap_px=threshold_px) if continuity else None

    def relabel(pairs) -> np.ndarray:
        new = labels.copy()
        tables = pair_tables(x, w, Ks, pairs, names, cap_px=threshold_px)
        cost = lambda labels: labelling_cost(tables, labels, tracks=tracks)  # noqa: E731
        for _ in range(_MAX_MOVES):
            nats = swap_costs(tables, new)
            proposals = [decide_labels(nats[c], kinds, tracks=None if tracks is None else tracks[c]) for c in range(C)]
            gains = [cost(new) - cost(np.vstack([new[:c], p[None], new[c + 1 :]])) for c, p in enumerate(proposals)]
            c = int(np.argmax(gains))
            if gains[c] > _MIN_GAIN_NATS:
                new[c] = proposals[c]
                continue
            if C <= MAX_JOINT_CAMERAS:
                joint = best_frames(tables, new, kinds, tracks)
                if cost(joint) < cost(new) - _MIN_GAIN_NATS:
                    new = joint
                    continue
            break
        if C <= MAX_SEQUENCE_CAMERAS:
            joint = joint_labels(tables, new.shape, kinds, tracks)
            if cost(joint) < cost(new) - _MIN_GAIN_NATS:
                new = joint
        # The body's side may cost a prior or a change in time: it comes last, after the moves
        # (the next round starts from it).
        return absolute_labels(new, seen, *pair_anatomy(x, w, Ks, pairs, names, new), kinds, fewer_swaps=not continuity)

    if poses is not None:
        # calibrated cameras: their geometry is known, only the labels are to find
        poses = np.asarray(poses, dtype=float)
        poses = as_checked_array(poses, "poses (world_T_camera)", (C, 4, 4) if poses.ndim == 3 else (C, N, 4, 4))
        pairs = {(a, b): pair_from_poses(a, b, poses[a], poses[b], Ks[a], Ks[b]) for a in range(C) for b in range(a + 1, C)}
        return SwapCheck(relabel(pairs), pairs, 1, True)
    converged = False
    rounds = 0
    history = [labels]
    pairs = None
    while rounds < max_rounds and not converged:
        rounds += 1
        pairs = pair_geometries(apply_labels(x, labels, names), apply_labels(w, labels, names), Ks, threshold_px=threshold_px, previous=pairs)
        new = relabel(pairs)
        converged = np.array_equal(new, labels)
        if not converged and any(np.array_equal(new, old) for old in history):
            # A borderline frame flips the essential matrices' RANSAC just enough to flip back:
            # labels seen before will not settle.
            labels = new
            break
        history.append(new)
        labels = new
    if not converged:
        pairs = pair_geometries(apply_labels(x, labels, names), apply_labels(w, labels, names), Ks, threshold_px=threshold_px, previous=pairs)
    return SwapCheck(labels, pairs, rounds, converged)


__all__ = [
    "MIN_CORRESPONDENCES",
    "PairGeometry",
    "SwapCheck",
    "apply_labels",
    "best_frames",
    "decide_labels",
    "absolute_labels",
    "anatomy_scores",
    "pair_anatomy",
    "fundamental_matrix",
    "joint_labels",
    "labelling_cost",
    "normalised",
    "pair_from_poses",
    "pair_geometries",
    "relative_pose",
    "resolve_swaps",
    "sampson_px",
    "pair_tables",
    "swap_costs",
    "track_tables",
    "triangulate_pair",
]
