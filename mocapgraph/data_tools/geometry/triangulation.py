"""Triangulating 2D keypoints seen by calibrated cameras: the baseline every pipeline is compared to.

This is what a Pose2Sim or anipose user would do with cameras whose poses are known: per frame and
per keypoint, a confidence-weighted linear triangulation (DLT), made robust by RANSAC over the
views and polished by a few Gauss-Newton steps on the reprojection error. No body model, no
temporal smoothing.

Conventions (``/work/shared/DESIGN.md``): world points in metres; pixels as the camera's image;
projection matrices ``P = K [R | t]`` map homogeneous world points to homogeneous pixels, with
``R, t`` world→camera (the inverse of ``world_T_camera``; OpenCV camera, +z forward).
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import cv2
import numpy as np

from mocapgraph.data_tools.io.capture import Camera, Capture
from mocapgraph.errors import MocapgraphError, as_checked_array

DEFAULT_THRESHOLD_PX = 15.0
"""Default RANSAC inlier threshold: a 2D detector is typically off by several pixels on HD video."""

DEFAULT_MAX_PAIRS = 100
"""Above this many view pairs, RANSAC samples pairs instead of trying them all (15 cameras and up)."""

_REFINE_ITERATIONS = 5
_FRAMES_PER_CHUNK = 256


@dataclass
class Triangulation:
    """Keypoints triangulated from a calibrated capture, one row per reference time.

    Attributes:
        timestamps: ``(T,)`` seconds of the reference clock.
        points: ``(T, K, 3)`` world points, metres; NaN where unknown.
        format: keypoint format name of the detector used (``coco17``, …).
        inliers: ``(T, C, K)`` whether camera ``c`` (in ``cameras`` order) supported the point.
        reprojection_error_px: ``(T, K)`` mean reprojection error over the inlier views, pixels of
            the undistorted image; NaN where the point is unknown.
        cameras: ``(C,)`` camera names, the order of ``inliers``' second axis.
        detector: name of the detector used.
    """

    timestamps: np.ndarray
    points: np.ndarray
    format: str
    inliers: np.ndarray
    reprojection_error_px: np.ndarray
    cameras: tuple[str, ...] = ()
    detector: str = ""


# ---------------------------------------------------------------------------------------------
# Public point-level API


def triangulate_points(projections, points, confidences=None) -> np.ndarray:
    """Confidence-weighted linear triangulation (DLT) of each keypoint from all views that see it.

    Args:
        projections: ``(C, 3, 4)`` pixel projection matrices ``K [R | t]`` (any scale and sign).
        points: ``(C, K, 2)`` pixel observations (undistorted); NaN = not seen by that view.
        confidences: ``(C, K)`` in ``[0, ∞)``, each view's two equations are scaled by it;
            NaN or 0 = not seen; None = all ones.

    Returns:
        ``(K, 3)`` world points, the units of the projections' translations (metres); NaN for a
        keypoint seen by fewer than 2 views or triangulated at infinity.
    """
    P, x, w = _check_inputs(projections, points, confidences)
    return _weighted_dlt(_per_point(P, x.shape[1]), x, w)


def triangulate_ransac(
    projections,
    points,
    confidences=None,
    *,
    threshold_px: float = DEFAULT_THRESHOLD_PX,
    min_views: int = 2,
    max_pairs: int = DEFAULT_MAX_PAIRS,
    refine: bool = True,
    seed: int | np.random.Generator | None = 0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triangulation robust to views that are wrong (a detector's swapped limb or wrong person).

    Per keypoint: every pair of views that both see it (or ``max_pairs`` random pairs when there
    are more pairs than that) proposes a point; the views that reproject it within
    ``threshold_px`` and see it in front of the camera are its inliers. The largest inlier set
    wins (ties: lower total reprojection error), is re-triangulated by weighted DLT and refined by
    Gauss-Newton on the confidence-weighted reprojection error; if the refined point changes which
    views are inliers, the new set is fitted once more.

    Args:
        projections: ``(C, 3, 4)`` pixel projection matrices ``K [R | t]``.
        points: ``(C, K, 2)`` undistorted pixel observations; NaN = not seen.
        confidences: ``(C, K)``; NaN or 0 = not seen; None = all ones.
        threshold_px: inlier threshold on the reprojection error, pixels.
        min_views: fewest inlier views for a point to be reported (at least 2).
        max_pairs: try all view pairs when there are at most this many, else sample this many.
        refine: run the Gauss-Newton refinement.
        seed: seed or generator for the pair sampling (unused when all pairs are tried).

    Returns:
        ``points (K, 3)`` world, NaN where fewer than ``min_views`` views agree;
        ``inliers (C, K)`` bool, the views the point was fitted to;
        ``error (K,)`` mean reprojection error over the inliers, pixels; NaN where no point.
    """
    P, x, w = _check_inputs(projections, points, confidences)
    _check_ransac_options(threshold_px, min_views, max_pairs)
    rng = np.random.default_rng(seed)
    return _ransac(_per_point(P, x.shape[1]), x, w, float(threshold_px), int(min_views), int(max_pairs), rng, refine)


def undistort_pixels(points, K, distortion) -> np.ndarray:
    """Pixels of a distorted image → pixels of the ideal pinhole camera with the same ``K``.

    Args:
        points: ``(..., 2)`` pixels; NaN rows stay NaN.
        K: ``(3, 3)`` intrinsics.
        distortion: OpenCV coefficients ``k1, k2, p1, p2[, k3, …]``.

    Returns:
        ``(..., 2)`` undistorted pixels (a copy; unchanged when the distortion is all zero).
    """
    pts = np.array(points, dtype=float, copy=True)
    dist = np.asarray(distortion, dtype=float).ravel()
    if not np.any(dist):
        return pts
    flat = pts.reshape(-1, 2)
    ok = np.all(np.isfinite(flat), axis=1)
    if np.any(ok):
        # OpenCV's default stops after 5 fixed-point iterations: with k1 = -0.3 that leaves ~0.2 px
        # of error half-way to the image edge and more beyond; iterate to convergence instead.
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
        Kf = np.asarray(K, dtype=float)
        und = cv2.undistortPoints(flat[ok].reshape(-1, 1, 2), Kf, dist, P=Kf, criteria=criteria)
        flat[ok] = und.reshape(-1, 2)
    return flat.reshape(pts.shape)


def projection_matrix(K, world_T_camera) -> np.ndarray:
    """``K (3, 3)`` and ``world_T_camera (…, 4, 4)`` → pixel projection ``K [R | t]`` ``(…, 3, 4)``."""
    T = np.asarray(world_T_camera, dtype=float)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)  # world→camera rotation
    t = -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3])
    return np.asarray(K, dtype=float) @ np.concatenate([Rt, t[..., None]], axis=-1)


# ---------------------------------------------------------------------------------------------
# Capture-level API


def triangulate_capture(
    capture: Capture,
    detector: str | None = None,
    *,
    threshold_px: float = DEFAULT_THRESHOLD_PX,
    seed: int = 0,
    max_time_offset_s: float | None = None,
    min_views: int = 2,
    refine: bool = True,
) -> Triangulation:
    """Triangulate one detector's keypoints from a capture whose cameras are all calibrated.

    The reference clock is the first camera's timestamps, extended before and after with its
    median frame period wherever other cameras recorded outside its span (those extra times are
    kept only where at least ``min_views`` cameras have a frame). Each camera contributes, at each
    reference time, its nearest frame if that is within ``max_time_offset_s`` (default: half of
    that camera's frame period), with its pose at that frame (static cameras: their one pose).
    Keypoints are undistorted with each camera's OpenCV distortion and triangulated by
    :func:`triangulate_ransac`.

    Args:
        capture: cameras with ``extrinsics`` (world_T_camera) and detections.
        detector: detector name; None = the first detector (in the first camera's order) that every
            camera has.
        threshold_px: RANSAC inlier threshold, pixels.
        seed: seed of RANSAC's pair sampling (only used with many cameras).
        max_time_offset_s: largest gap between a camera's frame and the reference time, seconds.
        min_views: fewest agreeing views for a point.
        refine: Gauss-Newton refinement of each point.

    Returns:
        A :class:`Triangulation` in the capture's world frame.
    """
    if not isinstance(capture, Capture):
        raise MocapgraphError(f"capture: expected a Capture, got {type(capture).__name__}")
    if not capture.cameras:
        raise MocapgraphError(f"capture {capture.name!r}: has no cameras")
    _check_ransac_options(threshold_px, min_views, DEFAULT_MAX_PAIRS)
    if max_time_offset_s is not None and not (np.isfinite(max_time_offset_s) and max_time_offset_s >= 0):
        raise MocapgraphError(f"max_time_offset_s: must be a non-negative number of seconds, got {max_time_offset_s!r}")
    cams = capture.cameras
    if len(cams) < min_views:
        raise MocapgraphError(
            f"capture {capture.name!r}: triangulation needs at least {min_views} cameras, it has {len(cams)}"
        )
    for cam in cams:
        _check_camera(cam)
    name = _pick_detector(capture, detector)
    fmt = cams[0].detectors[name].format
    for cam in cams[1:]:
        if cam.detectors[name].format != fmt:
            raise MocapgraphError(
                f"camera {cam.name!r}: detector {name!r} is in format {cam.detectors[name].format!r}, "
                f"but camera {cams[0].name!r} has it in {fmt!r}; triangulation needs one format"
            )
    K_pts = cams[0].detectors[name].keypoints.shape[1]
    for cam in cams[1:]:
        if cam.detectors[name].keypoints.shape[1] != K_pts:
            raise MocapgraphError(
                f"camera {cam.name!r}: detector {name!r} has {cam.detectors[name].keypoints.shape[1]} keypoints, "
                f"camera {cams[0].name!r} has {K_pts}"
            )

    times, frame_of = _match_frames(cams, max_time_offset_s, min_views)
    C, T = len(cams), len(times)

    # Everything per camera is gathered once onto the reference clock: (C, T, …).
    P = np.zeros((C, T, 3, 4))
    x = np.full((C, T, K_pts, 2), np.nan)
    w = np.zeros((C, T, K_pts))
    for c, cam in enumerate(cams):
        used = frame_of[c] >= 0
        idx = frame_of[c][used]
        kp = np.asarray(cam.detectors[name].keypoints, dtype=float)[idx]
        x[c, used] = undistort_pixels(kp[..., :2], cam.K, cam.distortion)
        conf = kp[..., 2]
        w[c, used] = np.where(np.isfinite(conf) & np.all(np.isfinite(kp[..., :2]), axis=-1), conf, 0.0)
        ext = np.asarray(cam.extrinsics, dtype=float)
        poses = ext[np.zeros_like(idx)] if len(ext) == 1 else ext[idx]
        P[c, used] = projection_matrix(cam.K, poses)
    if np.any(w < 0):
        c = int(np.argwhere(w < 0)[0][0])
        raise MocapgraphError(f"camera {cams[c].name!r}: detector {name!r} has negative confidences")

    rng = np.random.default_rng(seed)
    points = np.full((T, K_pts, 3), np.nan)
    inliers = np.zeros((T, C, K_pts), dtype=bool)
    errors = np.full((T, K_pts), np.nan)
    # Frames are independent, so a chunk of them is solved as one batch of T·K points.
    for start in range(0, T, _FRAMES_PER_CHUNK):
        sl = slice(start, min(T, start + _FRAMES_PER_CHUNK))
        n = sl.stop - sl.start
        Pc = np.repeat(P[:, sl, None], K_pts, axis=2).reshape(C, n * K_pts, 3, 4)
        X, mask, err = _ransac(
            Pc, x[:, sl].reshape(C, n * K_pts, 2), w[:, sl].reshape(C, n * K_pts),
            float(threshold_px), int(min_views), DEFAULT_MAX_PAIRS, rng, refine,
        )  # fmt: skip
        points[sl] = X.reshape(n, K_pts, 3)
        inliers[sl] = mask.reshape(C, n, K_pts).transpose(1, 0, 2)
        errors[sl] = err.reshape(n, K_pts)
    return Triangulation(
        timestamps=times,
        points=points,
        format=fmt,
        inliers=inliers,
        reprojection_error_px=errors,
        cameras=tuple(c.name for c in cams),
        detector=name,
    )


def _check_camera(cam: Camera) -> None:
    if cam.extrinsics is None:
        raise MocapgraphError(
            f"camera {cam.name!r}: has no extrinsics; triangulation needs every camera calibrated "
            "(use an uncalibrated pipeline such as airpose or smartmocap instead)"
        )
    ext = np.asarray(cam.extrinsics, dtype=float)
    T = len(cam.timestamps)
    if ext.ndim != 3 or ext.shape[1:] != (4, 4) or ext.shape[0] not in (1, T):
        raise MocapgraphError(
            f"camera {cam.name!r}: extrinsics must have shape (1, 4, 4) or ({T}, 4, 4), got {ext.shape}"
        )
    if not np.all(np.isfinite(ext)):
        raise MocapgraphError(f"camera {cam.name!r}: extrinsics contain NaN or inf")
    K = np.asarray(cam.K, dtype=float)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise MocapgraphError(f"camera {cam.name!r}: K must be a (3, 3) intrinsic matrix with fx, fy > 0")
    ts = np.asarray(cam.timestamps, dtype=float)
    if ts.ndim != 1 or ts.size == 0 or not np.all(np.isfinite(ts)) or np.any(np.diff(ts) <= 0):
        raise MocapgraphError(f"camera {cam.name!r}: timestamps must be a non-empty, strictly increasing 1D array")
    if not (np.isfinite(cam.frame_rate) and cam.frame_rate > 0):
        raise MocapgraphError(f"camera {cam.name!r}: frame_rate must be positive, got {cam.frame_rate!r}")


def _pick_detector(capture: Capture, detector: str | None) -> str:
    cams = capture.cameras
    if detector is not None:
        for cam in cams:
            if detector not in cam.detectors:
                have = ", ".join(cam.detectors) or "none"
                raise MocapgraphError(f"camera {cam.name!r}: has no detector {detector!r} (it has: {have})")
        name = detector
    else:
        common = [n for n in cams[0].detectors if all(n in c.detectors for c in cams[1:])]
        if not common:
            listing = "; ".join(f"{c.name}: {', '.join(c.detectors) or 'none'}" for c in cams)
            raise MocapgraphError(f"capture {capture.name!r}: no detector is present on every camera ({listing})")
        name = common[0]
    for cam in cams:
        kp = np.asarray(cam.detectors[name].keypoints)
        if kp.ndim != 3 or kp.shape[0] != len(cam.timestamps) or kp.shape[2] != 3:
            raise MocapgraphError(
                f"camera {cam.name!r}: detector {name!r} keypoints must have shape "
                f"({len(cam.timestamps)}, K, 3), got {kp.shape}"
            )
    return name


def _match_frames(cams: list[Camera], max_offset: float | None, min_views: int) -> tuple[np.ndarray, np.ndarray]:
    """Reference times ``(T,)`` and, per camera, the frame used at each ``(C, T)`` (-1 = none)."""
    base = np.asarray(cams[0].timestamps, dtype=float)
    period = float(np.median(np.diff(base))) if len(base) > 1 else 1.0 / cams[0].frame_rate
    lo = min(float(c.timestamps[0]) for c in cams)
    hi = max(float(c.timestamps[-1]) for c in cams)
    # Extend so every other camera's frame lies within half a period of some reference time.
    n_before = max(0, int(np.ceil((base[0] - lo) / period - 0.5)))
    n_after = max(0, int(np.ceil((hi - base[-1]) / period - 0.5)))
    before = base[0] - period * np.arange(n_before, 0, -1)
    after = base[-1] + period * np.arange(1, n_after + 1)
    times = np.concatenate([before, base, after])
    own = np.zeros(len(times), dtype=bool)
    own[n_before : n_before + len(base)] = True

    frame_of = np.full((len(cams), len(times)), -1, dtype=np.int64)
    for c, cam in enumerate(cams):
        ts = np.asarray(cam.timestamps, dtype=float)
        limit = 0.5 / cam.frame_rate if max_offset is None else max_offset
        right = np.clip(np.searchsorted(ts, times), 0, len(ts) - 1)
        left = np.clip(right - 1, 0, len(ts) - 1)
        nearest = np.where(np.abs(ts[left] - times) <= np.abs(ts[right] - times), left, right)
        # A hair of slack so a frame exactly half a period away is not lost to rounding.
        ok = np.abs(ts[nearest] - times) <= limit * (1 + 1e-9) + 1e-12
        frame_of[c, ok] = nearest[ok]

    present = frame_of >= 0
    shared = present & (present.sum(axis=0) >= 2)
    for c, cam in enumerate(cams):
        if not np.any(shared[c]):
            limit = 0.5 / cam.frame_rate if max_offset is None else max_offset
            spans = ", ".join(f"{o.name} {o.timestamps[0]:.3f}–{o.timestamps[-1]:.3f} s" for o in cams)
            raise MocapgraphError(
                f"camera {cam.name!r}: no frame within {limit:.4g} s of a frame of another camera; "
                f"are the clocks the same? (spans: {spans})"
            )
    keep = own | (present.sum(axis=0) >= min_views)
    return times[keep], frame_of[:, keep]


# ---------------------------------------------------------------------------------------------
# Input checks


def _check_inputs(projections, points, confidences) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    P = as_checked_array(projections, "projections", (None, 3, 4))
    C = P.shape[0]
    degenerate = ~np.any(_normalised(P), axis=(1, 2))
    if np.any(degenerate):
        raise MocapgraphError(
            f"projections[{int(np.argmax(degenerate))}]: its left 3×3 block is singular, not a camera's K [R | t]"
        )
    x = as_checked_array(points, "points", (C, None, 2), finite=False)
    if np.any(np.isinf(x)):
        raise MocapgraphError("points: contains inf (missing observations are NaN)")
    K = x.shape[1]
    if confidences is None:
        w = np.ones((C, K))
    else:
        w = as_checked_array(confidences, "confidences", (C, K), finite=False)
        if np.any(np.isinf(w)):
            raise MocapgraphError("confidences: contains inf")
        if np.any(w[np.isfinite(w)] < 0):
            raise MocapgraphError("confidences: must be non-negative (missing = NaN)")
    seen = np.all(np.isfinite(x), axis=-1) & np.isfinite(w)
    w = np.where(seen, w, 0.0)
    return P, x, w


def _check_ransac_options(threshold_px, min_views, max_pairs) -> None:
    if not (isinstance(threshold_px, numbers.Real) and np.isfinite(threshold_px) and threshold_px > 0):
        raise MocapgraphError(f"threshold_px: must be a positive number of pixels, got {threshold_px!r}")
    if not (isinstance(min_views, (int, np.integer)) and min_views >= 2):
        raise MocapgraphError(f"min_views: must be an integer of at least 2, got {min_views!r}")
    if not (isinstance(max_pairs, (int, np.integer)) and max_pairs >= 1):
        raise MocapgraphError(f"max_pairs: must be a positive integer, got {max_pairs!r}")


def _per_point(P: np.ndarray, n: int) -> np.ndarray:
    """``(C, 3, 4)`` → a read-only ``(C, n, 3, 4)`` view, the layout of the batched kernels."""
    return np.broadcast_to(P[:, None], (P.shape[0], n, 3, 4))


# ---------------------------------------------------------------------------------------------
# Batched kernels. Shapes: P (C, N, 3, 4), x (C, N, 2), w (C, N) with w = 0 where unseen.


def _normalised(P: np.ndarray) -> np.ndarray:
    """Scale each projection so its third row gives the depth in world units, positive in front.

    For ``P = K [R | t]``, ``det P[:, :3] > 0`` and ``|P[2, :3]| = 1``; rescaling to that makes the
    results independent of how the caller scaled ``P`` and lets the cheirality test read the sign.
    """
    M = P[..., :3]
    with np.errstate(divide="ignore", invalid="ignore"):
        det = np.einsum("...i,...i->...", M[..., 0, :], np.cross(M[..., 1, :], M[..., 2, :]))
        s = np.sign(det) / np.linalg.norm(M[..., 2, :], axis=-1)
    # A degenerate matrix (e.g. the zeros standing in for a camera without a frame) stays zero.
    s = np.where(np.isfinite(s), s, 0.0)
    return P * s[..., None, None]


def _weighted_dlt(P: np.ndarray, x: np.ndarray, w: np.ndarray, passes: int = 2) -> np.ndarray:
    """``(N, 3)`` points from the views with ``w > 0``; NaN where fewer than 2 such views."""
    P = _normalised(P)
    xs = np.where(w[..., None] > 0, x, 0.0)
    C, N = w.shape
    enough = np.count_nonzero(w > 0, axis=0) >= 2
    X = np.full((N, 3), np.nan)
    if not np.any(enough):
        return X
    P, xs, w = P[:, enough], xs[:, enough], w[:, enough]
    # Rows u·p3 - p1 and v·p3 - p2: their residual is depth × pixel error.
    rows = np.stack(
        [xs[..., 0, None] * P[..., 2, :] - P[..., 0, :], xs[..., 1, None] * P[..., 2, :] - P[..., 1, :]], axis=1
    )  # (C, 2, n, 4)
    rows = np.where((w > 0)[:, None, :, None], rows, 0.0)
    scale = w
    for i in range(passes):
        A = (rows * scale[:, None, :, None]).transpose(2, 0, 1, 3).reshape(-1, 2 * C, 4)
        Xh = np.linalg.svd(A)[2][:, -1, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            sol = Xh[:, :3] / Xh[:, 3:]
        at_infinity = np.abs(Xh[:, 3]) < 1e-12 * np.linalg.norm(Xh, axis=1)
        sol[at_infinity] = np.nan
        if i + 1 < passes:
            # Dividing by the first estimate's depth turns the algebraic error into pixels, so far
            # views are not favoured (the iterative linear method of Hartley & Sturm).
            depth = np.abs(np.einsum("cnj,nj->cn", P[..., 2, :3], np.nan_to_num(sol)) + P[..., 2, 3])
            floor = 1e-6 * np.maximum(np.max(depth, axis=0), 1e-12)
            scale = w / np.maximum(depth, floor)
    X[enough] = sol
    return X


def _project(P: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels ``(C, N, 2)`` and depths ``(C, N)`` of points ``(N, 3)`` (``P`` normalised)."""
    p = (P[..., :3] @ X[None, :, :, None])[..., 0] + P[..., 3]  # matmul: einsum is 3× slower here
    with np.errstate(divide="ignore", invalid="ignore"):
        return p[..., :2] / p[..., 2:], p[..., 2]


def _reprojection(P: np.ndarray, x: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel errors ``(C, N)`` (inf where unseen or undefined) and depths ``(C, N)``."""
    u, depth = _project(P, X)
    err = np.linalg.norm(u - x, axis=-1)
    return np.where(np.isfinite(err), err, np.inf), depth


def _refine(P: np.ndarray, x: np.ndarray, w: np.ndarray, X: np.ndarray, iterations: int) -> np.ndarray:
    """Damped Gauss-Newton on ``Σ_c (w_c |π_c(X) - x_c|)²`` per point; a step is kept only if it helps."""
    X = X.copy()
    live = np.all(np.isfinite(X), axis=1) & (np.count_nonzero(w > 0, axis=0) >= 2)
    if not np.any(live):
        return X
    P, x, w, Y = P[:, live], np.where(w[..., None] > 0, x, 0.0)[:, live], w[:, live], X[live]

    def cost(Z):
        u, _ = _project(P, Z)
        c = np.sum((w * np.linalg.norm(u - x, axis=-1)) ** 2, axis=0, where=w > 0)
        return np.where(np.isfinite(c), c, np.inf)

    current = cost(Y)
    damping = np.full(len(Y), 1e-4)
    for _ in range(iterations):
        u, depth = _project(P, Y)
        r = w[..., None] * (u - x)  # (C, n, 2)
        # d(u)/dX = (p_row - u p3) / depth for rows 1, 2 of P.
        J = (P[..., :2, :3] - u[..., None] * P[..., 2:3, :3]) / depth[..., None, None]
        J = np.where((w > 0)[..., None, None], w[..., None, None] * J, 0.0)
        r = np.where((w > 0)[..., None], r, 0.0)
        Jt = np.swapaxes(J, -1, -2)
        H = (Jt @ J).sum(axis=0)
        g = (Jt @ r[..., None])[..., 0].sum(axis=0)
        diag = np.einsum("nii->ni", H)
        H = H + (damping[:, None] * diag + 1e-12)[:, :, None] * np.eye(3)
        trial = Y - _solve3(H, g)  # a singular or non-finite system gives a NaN trial, rejected below
        new = cost(trial)
        better = new < current
        Y[better], current[better] = trial[better], new[better]
        damping = np.where(better, damping * 0.3, damping * 10.0)
    X[live] = Y
    return X


def _solve3(M: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Batched ``M (n, 3, 3) x = b (n, 3)`` by Cramer's rule: NaN/inf where singular, never an exception."""
    c0, c1, c2 = M[..., 0], M[..., 1], M[..., 2]
    c12 = np.cross(c1, c2)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_det = 1.0 / np.einsum("ni,ni->n", c0, c12)
        return np.stack(
            [
                np.einsum("ni,ni->n", b, c12) * inv_det,
                np.einsum("ni,ni->n", c0, np.cross(b, c2)) * inv_det,
                np.einsum("ni,ni->n", c0, np.cross(c1, b)) * inv_det,
            ],
            axis=-1,
        )


def _pair_points(P, x, w, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Points ``(N, 3)`` each from its own two views ``a[n], b[n]``; NaN where either is unseen.

    A hypothesis only has to land within the inlier threshold, so the DLT is solved with the
    homogeneous coordinate fixed to 1 (3×3 normal equations): a batched SVD would cost ten times
    more in this, the innermost loop. ``P`` must be :func:`_normalised`.
    """
    n = np.arange(w.shape[1])
    rows = []
    for v in (a, b):
        Pv, xv, wv = P[v, n], x[v, n], w[v, n]
        # A view with w = 0 gives zero rows, hence a singular system and a NaN point.
        xv = np.where((wv > 0)[:, None], xv, 0.0)
        rows.append(wv[:, None] * (xv[:, 0, None] * Pv[:, 2] - Pv[:, 0]))
        rows.append(wv[:, None] * (xv[:, 1, None] * Pv[:, 2] - Pv[:, 1]))
    A = np.stack(rows, axis=1)  # (N, 4, 4)
    M = np.einsum("nki,nkj->nij", A[..., :3], A[..., :3])
    X = _solve3(M, -np.einsum("nki,nk->ni", A[..., :3], A[..., 3]))
    X[~np.all(np.isfinite(X), axis=1) | (w[a, n] <= 0) | (w[b, n] <= 0)] = np.nan
    return X


def _ransac(P, x, w, threshold, min_views, max_pairs, rng, refine):
    C, N = w.shape
    P = _normalised(P)
    seen = w > 0
    best_count = np.zeros(N, dtype=np.int64)
    best_total = np.full(N, np.inf)
    best_mask = np.zeros((C, N), dtype=bool)

    def consider(X):
        err, depth = _reprojection(P, x, X)
        inl = seen & (depth > 0) & (err < threshold)
        count = inl.sum(axis=0)
        total = np.sum(np.where(inl, err, 0.0), axis=0)
        better = (count > best_count) | ((count == best_count) & (count > 0) & (total < best_total))
        best_count[better], best_total[better] = count[better], total[better]
        best_mask[:, better] = inl[:, better]

    if C * (C - 1) // 2 <= max_pairs:
        for i in range(C):
            for j in range(i + 1, C):
                consider(_pair_points(P, x, w, np.full(N, i), np.full(N, j)))
    else:
        # Sample among each point's own seen views, so missing views never waste a hypothesis.
        order = np.argsort(~seen, axis=0, kind="stable")  # seen views first, per point
        nseen = seen.sum(axis=0)
        pick = nseen >= 2
        cols = np.arange(N)
        for _ in range(max_pairs):
            ia = np.floor(rng.random(N) * nseen).astype(np.int64)
            ib = np.floor(rng.random(N) * np.maximum(nseen - 1, 1)).astype(np.int64)
            ib = ib + (ib >= ia)
            ia, ib = np.where(pick, ia, 0), np.where(pick, ib, 1)
            consider(_pair_points(P, x, w, order[ia, cols], order[ib, cols]))

    X = np.full((N, 3), np.nan)
    mask = np.zeros((C, N), dtype=bool)
    idx = np.flatnonzero(best_count >= min_views)
    fit_mask = best_mask[:, idx]
    for attempt in range(2):
        Pi, xi = P[:, idx], x[:, idx]
        wi = np.where(fit_mask, w[:, idx], 0.0)
        Xf = _weighted_dlt(Pi, xi, wi)
        if refine:
            Xf = _refine(Pi, xi, wi, Xf, _REFINE_ITERATIONS)
        X[idx], mask[:, idx] = Xf, fit_mask
        if attempt == 1:
            break
        # The fit to all inliers can see views the two-view hypothesis missed (a local
        # optimisation step, as in LO-RANSAC); refit once where that adds support.
        err, depth = _reprojection(Pi, xi, Xf)
        again = seen[:, idx] & (depth > 0) & (err < threshold)
        grew = np.any(again != fit_mask, axis=0) & (again.sum(axis=0) >= fit_mask.sum(axis=0))
        if not np.any(grew):
            break
        idx, fit_mask = idx[grew], again[:, grew]

    found = np.all(np.isfinite(X), axis=1)
    mask[:, ~found] = False
    X[~found] = np.nan
    err, _ = _reprojection(P, x, np.nan_to_num(X))
    with np.errstate(invalid="ignore"):
        mean_err = np.sum(np.where(mask, err, 0.0), axis=0) / mask.sum(axis=0)
    mean_err[~found] = np.nan
    return X, mask, mean_err
