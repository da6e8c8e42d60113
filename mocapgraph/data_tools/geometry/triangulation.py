"""Triangulating 2D keypoints seen by calibrated cameras: the geometry of the triangulation baseline.

This is what a Pose2Sim or anipose user would do with cameras whose poses are known: per keypoint, a
confidence-weighted linear triangulation (DLT), made robust by RANSAC over the views and polished
by a few Gauss-Newton steps on the reprojection error. No body model, no temporal smoothing.
Arrays in, arrays out: :mod:`mocapgraph.pipelines.baseline` applies it to a whole capture.

Conventions (``/work/shared/DESIGN.md``): world points in metres; pixels as the camera's image;
projection matrices ``P = K [R | t]`` map homogeneous world points to homogeneous pixels, with
``R, t`` world→camera (the inverse of ``world_T_camera``; OpenCV camera, +z forward).
"""

from __future__ import annotations

import numbers

import numpy as np

from mocapgraph.errors import MocapgraphError, as_checked_array

DEFAULT_THRESHOLD_PX = 15.0
"""Default RANSAC inlier threshold: a 2D detector is typically off by several pixels on HD video."""

DEFAULT_MAX_PAIRS = 100
"""Above this many view pairs, RANSAC samples pairs instead of trying them all (15 cameras and up)."""

_REFINE_ITERATIONS = 5


# ---------------------------------------------------------------------------------------------
# Public point-level API


def triangulate_points(projections, points, confidences=None) -> np.ndarray:
    """Confidence-weighted linear triangulation (DLT) of each keypoint from all views that see it.

    Args:
        projections: pixel projection matrices ``K [R | t]`` (any scale and sign), either
            ``(C, 3, 4)``, one per view, or ``(C, K, 3, 4)``, one per view and keypoint (e.g.
            keypoints of several frames of moving cameras solved as one batch). A matrix whose
            left 3×3 block is singular is an error only where its view sees the keypoint.
        points: ``(C, K, 2)`` pixel observations (undistorted); NaN = not seen by that view.
        confidences: ``(C, K)`` in ``[0, ∞)``, each view's two equations are scaled by it;
            NaN or 0 = not seen; None = all ones.

    Returns:
        ``(K, 3)`` world points, the units of the projections' translations (metres); NaN for a
        keypoint seen by fewer than 2 views or triangulated at infinity.
    """
    return _weighted_dlt(*_check_inputs(projections, points, confidences))


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
        projections: pixel projection matrices ``K [R | t]``: ``(C, 3, 4)``, one per view, or
            ``(C, K, 3, 4)``, one per view and keypoint (as in :func:`triangulate_points`).
        points: ``(C, K, 2)`` undistorted pixel observations; NaN = not seen.
        confidences: ``(C, K)``; NaN or 0 = not seen; None = all ones.
        threshold_px: inlier threshold on the reprojection error, pixels.
        min_views: fewest inlier views for a point to be reported (at least 2).
        max_pairs: try all view pairs when there are at most this many, else sample this many.
        refine: run the Gauss-Newton refinement.
        seed: seed or generator for the pair sampling (unused when all pairs are tried); a
            generator is advanced, so calls sharing one draw different pairs.

    Returns:
        ``points (K, 3)`` world, NaN where fewer than ``min_views`` views agree;
        ``inliers (C, K)`` bool, the views the point was fitted to;
        ``error (K,)`` mean reprojection error over the inliers, pixels; NaN where no point.
    """
    P, x, w = _check_inputs(projections, points, confidences)
    check_ransac_options(threshold_px, min_views, max_pairs)
    rng = np.random.default_rng(seed)
    return _ransac(P, x, w, float(threshold_px), int(min_views), int(max_pairs), rng, refine)


def projection_matrix(K, world_T_camera) -> np.ndarray:
    """``K (3, 3)`` and ``world_T_camera (…, 4, 4)`` → pixel projection ``K [R | t]`` ``(…, 3, 4)``."""
    T = np.asarray(world_T_camera, dtype=float)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)  # world→camera rotation
    t = -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3])
    return np.asarray(K, dtype=float) @ np.concatenate([Rt, t[..., None]], axis=-1)


# ---------------------------------------------------------------------------------------------
# Input checks


def _check_inputs(projections, points, confidences) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``P (C, K, 3, 4)`` (a read-only view when one matrix serves all keypoints), ``x (C, K, 2)``
    and ``w (C, K)`` with ``w = 0`` where unseen: the layout of the batched kernels."""
    try:
        per_point = np.asarray(projections, dtype=float).ndim == 4
    except (TypeError, ValueError):
        per_point = False  # as_checked_array words the error
    P = as_checked_array(projections, "projections", (None, None, 3, 4) if per_point else (None, 3, 4))
    C = P.shape[0]
    x = as_checked_array(points, "points", (C, P.shape[1] if per_point else None, 2), finite=False)
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
    # Only matrices that are used must be cameras: callers batching frames put zeros where a view
    # has no frame.
    singular = ~np.any(_normalised(P), axis=(-2, -1)) & (w > 0 if per_point else np.any(w > 0, axis=1))
    if np.any(singular):
        where = ", ".join(str(int(i)) for i in np.argwhere(singular)[0])
        raise MocapgraphError(f"projections[{where}]: its left 3×3 block is singular, not a camera's K [R | t]")
    return (P if per_point else np.broadcast_to(P[:, None], (C, K, 3, 4))), x, w


def check_ransac_options(threshold_px, min_views, max_pairs) -> None:
    """Raise a :class:`MocapgraphError` naming the first bad option of :func:`triangulate_ransac`."""
    if not (isinstance(threshold_px, numbers.Real) and np.isfinite(threshold_px) and threshold_px > 0):
        raise MocapgraphError(f"threshold_px: must be a positive number of pixels, got {threshold_px!r}")
    if not (isinstance(min_views, (int, np.integer)) and min_views >= 2):
        raise MocapgraphError(f"min_views: must be an integer of at least 2, got {min_views!r}")
    if not (isinstance(max_pairs, (int, np.integer)) and max_pairs >= 1):
        raise MocapgraphError(f"max_pairs: must be a positive integer, got {max_pairs!r}")


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
