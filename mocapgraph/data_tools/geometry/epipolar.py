"""Two-view geometry of body keypoints: essential matrices, relative poses, left/right swap checks.

Cameras with known intrinsics and unknown poses watch the same person. Every keypoint that two
cameras see in the same frame is a correspondence, and pooled over a capture (hundreds of
frames, the person moving about) they fix each pair's essential matrix and relative pose, as
interest points do in structure from motion: :func:`relative_pose` (``cv2.findEssentialMat``
with RANSAC on normalised coordinates, ``cv2.recoverPose``), :func:`pair_geometries` for every
pair of a rig.

A 2D detector that confuses the person's left and right in a frame (whole body, or only the arms
or legs: :mod:`mocapgraph.body.labelling`) reports points that break the epipolar geometry of
every other camera; relabelled by the swap's permutation they fit it again. :func:`swap_costs`
scores each labelling of each camera-frame by its Sampson distances to the other cameras, and
:func:`resolve_swaps` alternates between estimating the essential matrices on the current
labels and relabelling, until the labels settle.

Arrays of a rig (``C`` cameras, ``N`` frames on one clock, ``K`` points of one format):

- ``x (C, N, K, 2)``: undistorted pixels (the pinhole image of ``Ks[c]``), NaN where not seen;
- ``w (C, N, K)``: confidences, 0 where not seen (or not to be used);
- ``Ks (C, 3, 3)``: intrinsics;
- labels ``(C, N)``: integer codes of :data:`~mocapgraph.body.labelling.SWAP_KINDS` (0 = as detected).

A relative pose ``(R, t)`` of cameras ``a, b`` maps camera ``a``'s coordinates to ``b``'s,
``X_b = R X_a + t`` (OpenCV cameras, +z forward), with ``‖t‖ = 1``: two views fix no scale.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from mocapgraph.body.labelling import SWAP_KINDS, swap_permutation
from mocapgraph.errors import MocapgraphError, as_checked_array

MIN_CORRESPONDENCES = 15
"""Fewest co-visible keypoints for a pair's essential matrix (the five-point solver needs 5; RANSAC
on a handful of points of one or two frames would fit their noise)."""

RANSAC_CONFIDENCE = 0.999
RANSAC_MAX_ITERATIONS = 2000

REFINE_SCALE_DIVISOR = 5.0
"""The refinement's robust scale is the RANSAC threshold over this (3 px for 15 px): near the
keypoints' noise, so the inliers count fully and the points near the threshold less."""

SWAP_NATS = 2.0
"""Prior cost of a swapped camera-frame, nats (negative log prior odds against a swap)."""

SWITCH_NATS = 4.0
"""Cost of a change of labelling from one frame to the next, nats: detectors swap in runs (a
tracker carries a wrong reading on), so one noisy frame should not flip a run or start one."""

_FLOOR_PX2 = 0.25
"""Added to a mean squared Sampson distance (px²) before its logarithm: below a quarter of a
squared pixel, differences are rounding, not evidence (and noise-free data stays finite)."""

MIN_SWAP_POINTS = 4
"""Fewest co-visible correspondences (over all other cameras) for a labelling to be scored."""


@dataclass(frozen=True)
class PairGeometry:
    """The epipolar geometry of cameras ``a < b`` from their co-visible keypoints.

    Attributes:
        a, b: camera indices.
        E: ``(3, 3)`` essential matrix, ``x̂_bᵀ E x̂_a = 0`` for normalised homogeneous points.
        R, t: ``(3, 3)``, ``(3,)``: ``X_b = R X_a + t``, ``‖t‖ = 1``.
        F: ``(3, 3)`` fundamental matrix of the undistorted pixels, ``x_bᵀ F x_a = 0``.
        inliers: correspondences consistent with ``E`` (within the threshold, in front of both cameras).
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

    def fundamental_from(self, c: int) -> np.ndarray:
        """``F`` with camera ``c`` (``a`` or ``b``) as the first view: ``x_otherᵀ F x_c = 0``."""
        if c == self.a:
            return self.F
        if c == self.b:
            return self.F.T
        raise ValueError(f"camera {c} is not in the pair ({self.a}, {self.b})")


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
    Fa = ha @ F.T  # F x_a: the epipolar line in b
    Fb = hb @ F  # Fᵀ x_b: the epipolar line in a
    e = np.sum(hb * Fa, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.abs(e) / np.sqrt(Fa[..., 0] ** 2 + Fa[..., 1] ** 2 + Fb[..., 0] ** 2 + Fb[..., 1] ** 2)


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


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


def relative_pose(x_a, x_b, K_a, K_b, *, threshold_px: float, a: int = 0, b: int = 1) -> PairGeometry | None:
    """The epipolar geometry of two cameras from correspondences.

    OpenCV's LO-RANSAC (``USAC_ACCURATE``) finds the essential matrix on normalised coordinates
    and ``recoverPose`` its pose in front of both cameras; :func:`refine_pose` then fits that
    pose to all the inliers; the inliers are counted again under the refined pose.

    Args:
        x_a, x_b: ``(M, 2)`` undistorted pixels of the same points in cameras ``a`` and ``b``
            (rows with a NaN are left out).
        K_a, K_b: ``(3, 3)`` intrinsics.
        threshold_px: RANSAC inlier threshold on the distance to the epipolar line, pixels (taken
            at the pair's mean focal length in normalised coordinates).
        a, b: the camera indices to record.

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
    # USAC seeds its sampler with a fixed state (UsacParams.randomGeneratorState): the same input gives the same model.
    E, mask = cv2.findEssentialMat(
        na, nb, np.eye(3), method=cv2.USAC_ACCURATE, prob=RANSAC_CONFIDENCE, threshold=threshold_px / focal, maxIters=RANSAC_MAX_ITERATIONS
    )
    if E is None or E.shape[0] < 3:
        return None
    # Degenerate samples can give several solutions stacked; the best comes first.
    _, R, t, mask = cv2.recoverPose(E[:3], na, nb, np.eye(3), mask=mask.copy())
    inlier = mask.ravel() > 0
    if inlier.sum() < MIN_CORRESPONDENCES:
        return None
    R, t = refine_pose(R, t, x_a[inlier], x_b[inlier], K_a, K_b, scale_px=threshold_px / REFINE_SCALE_DIVISOR)
    E = _skew(t) @ R
    F = fundamental_matrix(E, K_a, K_b)
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


def pair_geometries(x, w, Ks, *, threshold_px: float) -> dict[tuple[int, int], PairGeometry]:
    """:func:`relative_pose` of every pair ``a < b`` of a rig from all its frames' co-visible
    keypoints (``w > 0`` in both); pairs without a geometry are left out."""
    x, w, Ks = _check_rig(x, w, Ks)
    C = len(x)
    out = {}
    for a in range(C):
        for b in range(a + 1, C):
            both = (w[a] > 0) & (w[b] > 0)
            geometry = relative_pose(x[a][both], x[b][both], Ks[a], Ks[b], threshold_px=threshold_px, a=a, b=b)
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


def swap_costs(
    x, w, Ks, pairs: dict[tuple[int, int], PairGeometry], names: Sequence[str], labels=None, *, cap_px: float
) -> tuple[np.ndarray, np.ndarray]:
    """How badly each labelling of each camera-frame fits the other cameras' epipolar geometry.

    For camera ``c``, frame ``n`` and every kind of :data:`SWAP_KINDS`, ``c``'s points are
    permuted by that swap and compared with every other camera's points of the frame (under
    their current ``labels``) through the pair's fundamental matrix: ``m`` co-visible
    correspondences with Sampson distances ``d`` (pixels), truncated at ``cap_px`` so that one
    wrong point (an outlier, another person) cannot decide. The cost is the Gaussian negative
    log-likelihood with the frame's noise unknown, maximised over it:
    ``m/2 · log(mean(min(d, cap_px)²))`` nats (up to a constant). Its differences between
    labellings are therefore ``m/2 · log`` of the ratio of their mean squared distances: a frame
    whose points fit badly under every labelling (a side view, heavy noise) gives little evidence,
    however large its distances. A permutation can change which points are co-visible, so every
    kind is scored with the largest ``m`` of any kind.

    Args:
        x, w, Ks: the rig's arrays (module docstring), as detected.
        pairs: from :func:`pair_geometries`; a pair without a geometry contributes nothing.
        names: the format's point names (for the permutations).
        labels: ``(C, N)`` current codes of the cameras' labellings, default all 0.
        cap_px: truncation of the Sampson distance, pixels.

    Returns:
        ``nats (C, N, len(SWAP_KINDS))`` (NaN where fewer than :data:`MIN_SWAP_POINTS`
        correspondences) and ``count (C, N, len(SWAP_KINDS))`` of the correspondences scored.
    """
    x, w, Ks = _check_rig(x, w, Ks)
    C, N, K = w.shape
    if len(names) != K:
        raise MocapgraphError(f"names: {len(names)} point names for {K} keypoints")
    labels = np.zeros((C, N), dtype=int) if labels is None else np.asarray(labels, dtype=int)
    current_x, current_w = apply_labels(x, labels, names), apply_labels(w, labels, names)
    perms = [swap_permutation(names, kind) for kind in SWAP_KINDS]
    total = np.zeros((C, N, len(SWAP_KINDS)))
    count = np.zeros((C, N, len(SWAP_KINDS)), dtype=int)
    for (a, b), geometry in pairs.items():
        for c, other in ((a, b), (b, a)):
            F = geometry.fundamental_from(c)
            for code, perm in enumerate(perms):
                both = (w[c][:, perm] > 0) & (current_w[other] > 0)
                d = np.minimum(sampson_px(F, x[c][:, perm], current_x[other]), cap_px)
                total[c, :, code] += np.where(both, d**2, 0.0).sum(axis=1)
                count[c, :, code] += both.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        nats = 0.5 * count.max(axis=-1, keepdims=True) * np.log(total / count + _FLOOR_PX2)
    return np.where(count >= MIN_SWAP_POINTS, nats, np.nan), count


def _path_cost(unary: np.ndarray, path: np.ndarray, switch_nats: float) -> float:
    """The objective :func:`decide_labels` minimises, of ``path`` (indices into the kinds)."""
    padded = np.concatenate([[0], path, [0]])
    return float(np.take_along_axis(unary, path[:, None], axis=-1).sum() + switch_nats * np.count_nonzero(np.diff(padded)))


def _unary(nats: np.ndarray, codes: np.ndarray, swap_nats: float) -> np.ndarray:
    unary = np.nan_to_num(np.asarray(nats, dtype=float)[..., codes], nan=0.0)
    unary[..., 1:] += swap_nats
    return unary


def _kind_codes(kinds: Sequence[str]) -> np.ndarray:
    if any(k not in SWAP_KINDS[1:] for k in kinds):
        raise MocapgraphError(f"swap kinds: choose among {', '.join(SWAP_KINDS[1:])}, got {', '.join(kinds)}")
    return np.array([0] + [SWAP_KINDS.index(k) for k in kinds])


def decide_labels(nats, kinds: Sequence[str] = SWAP_KINDS[1:], *, swap_nats: float = SWAP_NATS, switch_nats: float = SWITCH_NATS) -> np.ndarray:
    """``(N,)`` label codes of one camera's frames from their costs ``nats (N, len(SWAP_KINDS))``
    (:func:`swap_costs`): the sequence of labellings, among ``"none"`` and ``kinds``, of least
    total cost plus ``swap_nats`` per swapped frame and ``switch_nats`` per change between
    consecutive frames (Viterbi). A frame without a cost (NaN) is decided by its neighbours."""
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
        step = best[:, None] + change  # [from, to]
        back[n] = np.argmin(step, axis=0)
        best = step[back[n], np.arange(S)] + unary[n]
    path = np.zeros(N, dtype=int)
    path[-1] = np.argmin(best + change[:, 0])
    for n in range(N - 1, 0, -1):
        path[n - 1] = back[n, path[n]]
    return codes[path]


def resolve_swaps(
    x,
    w,
    Ks,
    names: Sequence[str],
    *,
    threshold_px: float,
    kinds: Sequence[str] = SWAP_KINDS[1:],
    max_rounds: int = 5,
) -> SwapCheck:
    """Essential matrices and left/right labels of a rig, estimated in turn until they agree.

    Each round estimates every pair's geometry on the current labels (:func:`pair_geometries`),
    then relabels one camera at a time against the others' current labels
    (:func:`swap_costs`, :func:`decide_labels`): always the camera whose relabelling lowers its
    cost the most, until none would change. Taking the strongest evidence first keeps a camera
    with many swaps from making the clean ones look swapped where it disagrees with them. The
    rounds stop when one changes no label (or after ``max_rounds``); the returned geometries are
    those of the final labels. A whole-body swap in every camera at once is consistent
    geometry: it is not found.

    Args:
        x, w, Ks: the rig's arrays as detected (module docstring).
        names: the format's point names.
        threshold_px: RANSAC inlier threshold of the essential matrices, also the truncation of
            the swap costs.
        kinds: which swaps to consider.
        max_rounds: estimate-and-relabel rounds at most.
    """
    x, w, Ks = _check_rig(x, w, Ks)
    if max_rounds < 1:
        raise MocapgraphError(f"max_rounds: must be at least 1, got {max_rounds}")
    codes = _kind_codes(kinds)
    position = np.zeros(len(SWAP_KINDS), dtype=int)
    position[codes] = np.arange(len(codes))
    C, N, _ = w.shape
    labels = np.zeros((C, N), dtype=int)

    def relabel(pairs) -> np.ndarray:
        new = labels.copy()
        for _ in range(2 * C):
            nats, _ = swap_costs(x, w, Ks, pairs, names, new, cap_px=threshold_px)
            gains, proposals = np.zeros(C), []
            for c in range(C):
                proposal = decide_labels(nats[c], kinds)
                unary = _unary(nats[c], codes, SWAP_NATS)
                gains[c] = _path_cost(unary, position[new[c]], SWITCH_NATS) - _path_cost(unary, position[proposal], SWITCH_NATS)
                proposals.append(proposal)
            c = int(np.argmax(gains))
            if np.array_equal(proposals[c], new[c]):
                break
            new[c] = proposals[c]
        return new

    converged = False
    rounds = 0
    seen = [labels]
    while rounds < max_rounds and not converged:
        rounds += 1
        pairs = pair_geometries(apply_labels(x, labels, names), apply_labels(w, labels, names), Ks, threshold_px=threshold_px)
        new = relabel(pairs)
        converged = np.array_equal(new, labels)
        if not converged and any(np.array_equal(new, old) for old in seen):
            # A borderline frame flips the essential matrices' RANSAC just enough to flip back:
            # labels seen before will not settle.
            labels = new
            break
        seen.append(new)
        labels = new
    if not converged:
        pairs = pair_geometries(apply_labels(x, labels, names), apply_labels(w, labels, names), Ks, threshold_px=threshold_px)
    return SwapCheck(labels, pairs, rounds, converged)


__all__ = [
    "MIN_CORRESPONDENCES",
    "PairGeometry",
    "SwapCheck",
    "apply_labels",
    "decide_labels",
    "fundamental_matrix",
    "normalised",
    "pair_geometries",
    "relative_pose",
    "resolve_swaps",
    "sampson_px",
    "swap_costs",
]
