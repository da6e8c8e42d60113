"""Similarity alignment of point sets and trajectories: Umeyama's least squares (of points, and of
camera centres with every camera weighing the same) and SmartMocap's normalised Procrustes recipe
for camera trajectories.

A :class:`Similarity` maps a point ``x`` to ``scale · R x + t`` (metres, ``R`` a proper rotation).
Both solvers return the similarity that maps the *first* argument (source / estimate) onto the
*second* (target / reference). Rows with NaN in either argument are ignored, so an estimate's
missing frames or joints need no special handling by the caller.

References:
    S. Umeyama, "Least-squares estimation of transformation parameters between two point
    patterns", IEEE TPAMI 13(4), 1991 (notation below follows its Theorem / eqs. 34-42).
    N. Saini et al., "SmartMocap: Joint estimation of human and camera motion using uncalibrated
    RGB cameras", IEEE RA-L 2023 (evaluation of camera trajectories).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapgraph.data_tools.io.files import Where, check_array, check_rotations
from mocapgraph.errors import MocapgraphError, as_checked_array

# Second singular value of the cross-covariance below this fraction of the first: the points are
# (nearly) collinear and the rotation about their line is not determined.
_RANK_TOLERANCE = 1e-10


@dataclass(frozen=True, eq=False)
class Similarity:
    """``x ↦ scale · R x + t``; rigid when ``scale == 1``.

    Attributes:
        scale: positive, unitless.
        R: ``(3, 3)`` proper rotation.
        t: ``(3,)`` translation, metres.
    """

    scale: float
    R: np.ndarray
    t: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "scale", float(self.scale))
        object.__setattr__(self, "R", as_checked_array(self.R, "R", (3, 3)))
        object.__setattr__(self, "t", as_checked_array(self.t, "t", (3,)))
        if not self.scale > 0 or not np.isfinite(self.scale):
            raise MocapgraphError(f"scale: must be positive and finite, got {self.scale!r}")
        check_rotations(self.R, Where("R"))

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Points ``(..., 3)`` → ``scale · R p + t`` ``(..., 3)``."""
        points = np.asarray(points, dtype=float)
        if points.shape[-1:] != (3,):
            raise MocapgraphError(f"points: expected shape (..., 3), got {points.shape}")
        return self.scale * points @ self.R.T + self.t

    def apply_pose(self, world_T_x: np.ndarray) -> np.ndarray:
        """Poses ``(..., 4, 4)`` → the same poses in the target frame ``(..., 4, 4)``.

        The orientation is rotated (``R · R_x``) and the position mapped like a point
        (``scale · R t_x + t``); a pose's rotation block is never scaled.
        """
        world_T_x = np.asarray(world_T_x, dtype=float)
        if world_T_x.shape[-2:] != (4, 4):
            raise MocapgraphError(f"world_T_x: expected shape (..., 4, 4), got {world_T_x.shape}")
        out = np.zeros_like(world_T_x)
        out[..., :3, :3] = self.R @ world_T_x[..., :3, :3]
        out[..., :3, 3] = self.apply(world_T_x[..., :3, 3])
        out[..., 3, 3] = 1.0
        return out

    def as_matrix(self) -> np.ndarray:
        """``(4, 4)`` homogeneous ``[[scale · R, t], [0, 1]]``."""
        out = np.eye(4)
        out[:3, :3] = self.scale * self.R
        out[:3, 3] = self.t
        return out


def _rotation_from_cross_covariance(M: np.ndarray):
    """The proper rotation ``R`` maximising ``tr(Rᵀ M)`` for ``M (..., 3, 3)``.

    With ``M = U D Vᵀ`` and ``S = diag(1, 1, det(U Vᵀ))``: ``R = U S Vᵀ`` (Umeyama eq. 39-40);
    ``S`` turns a reflection into the best proper rotation. Returns ``R``, ``tr(D S)`` and ``D``.
    """
    U, D, Vt = np.linalg.svd(M)
    sign = np.where(np.linalg.det(U @ Vt) < 0, -1.0, 1.0)
    S = np.ones(D.shape)
    S[..., 2] = sign
    R = (U * S[..., None, :]) @ Vt
    return R, np.sum(D * S, axis=-1), D


def _fit_similarity(source, target, weights, with_scale: bool):
    """Weighted Umeyama on batches: ``source, target (B, N, 3)``, ``weights (B, N) ≥ 0``.

    Rows of weight 0 may hold NaN. Every batch needs a positive total weight. Returns
    ``scale (B,)``, ``R (B, 3, 3)``, ``t (B, 3)`` and the singular values ``(B, 3)`` of the
    cross-covariance. A source with no spread gets scale 0 (all of it maps to the target's centroid).
    """
    used = weights > 0
    source = np.where(used[..., None], source, 0.0)
    target = np.where(used[..., None], target, 0.0)
    w = weights / np.sum(weights, axis=-1, keepdims=True)
    mu_x = np.einsum("bn,bni->bi", w, source)
    mu_y = np.einsum("bn,bni->bi", w, target)
    x = source - mu_x[:, None]
    y = target - mu_y[:, None]
    sigma_xy = np.einsum("bn,bni,bnj->bij", w, y, x)
    sigma_x2 = np.einsum("bn,bni,bni->b", w, x, x)
    R, trace_ds, singular = _rotation_from_cross_covariance(sigma_xy)
    if with_scale:
        scale = np.divide(trace_ds, sigma_x2, out=np.zeros_like(trace_ds), where=sigma_x2 > 0)
    else:
        scale = np.ones_like(trace_ds)
    t = mu_y - scale[:, None] * np.einsum("bij,bj->bi", R, mu_x)
    return scale, R, t, singular


def _finite_rows(arr: np.ndarray) -> np.ndarray:
    """``(N, ...)`` → ``(N,)`` True where every entry of the row is finite."""
    return np.all(np.isfinite(arr.reshape(arr.shape[0], -1)), axis=1)


def umeyama(
    source: np.ndarray, target: np.ndarray, with_scale: bool, weights: np.ndarray | None = None
) -> Similarity:
    """The similarity (rigid if ``with_scale`` is False) minimising ``Σ wᵢ ‖target_i − (s R source_i + t)‖²``.

    Args:
        source: ``(N, 3)`` points, metres; rows with NaN are ignored.
        target: ``(N, 3)`` corresponding points, metres; rows with NaN are ignored.
        with_scale: estimate the scale (Umeyama's ``c = tr(D S) / σ_x²``); else ``scale = 1``.
        weights: ``(N,)`` non-negative weights (default all 1); rows of weight 0 are ignored.

    Returns:
        :class:`Similarity` mapping ``source`` onto ``target``. ``R`` is always a proper
        rotation: when the best orthogonal map is a reflection, the last singular direction is
        flipped (Umeyama's ``S`` matrix).

    Raises:
        MocapgraphError: mismatched shapes; fewer than 3 usable rows; the usable points are
            collinear (the rotation about their line is not determined) or all coincide.
    """
    source = check_array(source, Where("source"), (None, 3), allow_nan=True)
    target = check_array(target, Where("target"), (source.shape[0], 3), allow_nan=True)
    if weights is None:
        weights = np.ones(source.shape[0])
    weights = as_checked_array(weights, "weights", (source.shape[0],))
    if np.any(weights < 0):
        raise MocapgraphError(f"weights: must be non-negative (index {int(np.argmax(weights < 0))})")
    weights = np.where(_finite_rows(source) & _finite_rows(target), weights, 0.0)
    usable = int(np.count_nonzero(weights))
    if usable < 3:
        raise MocapgraphError(
            f"source/target: need at least 3 rows that are finite in both (and of positive weight), got {usable}"
        )
    scale, R, t, singular = _fit_similarity(source[None], target[None], weights[None], with_scale)
    if not singular[0, 1] > _RANK_TOLERANCE * singular[0, 0]:
        raise MocapgraphError(
            "source/target: the usable points are collinear or coincide; the rotation is not determined"
        )
    return Similarity(scale[0], R[0], t[0])


ROTATION_SOURCES = ("both", "orientations")
"""What :func:`procrustes_trajectory`'s rotation is fitted to."""


def procrustes_trajectory(
    est_positions: np.ndarray,
    ref_positions: np.ndarray,
    est_orientations: np.ndarray | None = None,
    ref_orientations: np.ndarray | None = None,
    rotation_from: str = "both",
) -> Similarity:
    """The similarity mapping an estimated camera trajectory onto the reference one.

    SmartMocap's normalised Procrustes recipe (the estimate lives in an arbitrary frame and scale):

    1. centre each trajectory on its mean position: ``Ê = E − ē``, ``R̂ = F − f̄`` (rows = frames);
    2. normalise each by its Frobenius norm: ``‖Ê‖_F``, ``‖R̂‖_F``;
    3. solve the orthogonal Procrustes problem ``min_Q ‖Q Ê/‖Ê‖ − R̂/‖R̂‖‖²`` over proper
       rotations (SVD of the cross-covariance, determinant corrected);
    4. the estimate's scale is the ratio of norms ``s = ‖R̂‖_F / ‖Ê‖_F`` and the translation
       ``t = f̄ − s Q ē``, so the result is ``x ↦ s Q x + t``.

    Unlike Umeyama's least-squares scale (which shrinks as noise grows), the ratio of norms is
    symmetric: aligning the reference onto the estimate gives exactly the inverse scale.

    When both orientation sequences are given (``world_T_camera`` rotations), step 3 also asks
    ``Q · est_Rᵢ ≈ ref_Rᵢ`` for every frame: it maximises ``tr(Qᵀ M)`` with
    ``M = Σᵢ r̂ᵢ êᵢᵀ + (1 / 3n) Σᵢ ref_Rᵢ est_Rᵢᵀ`` (n usable frames). The weight 1/3n gives the
    orientation term the same total squared norm (1) as the normalised positions, and it is what
    fixes the rotation when the positions alone cannot (a static camera pair, a straight track).
    Without noise the answer is exact whatever the weight.

    ``rotation_from="orientations"`` takes ``Q`` from the orientations alone (the same SVD of
    ``Σᵢ ref_Rᵢ est_Rᵢᵀ``: the chordal mean of the frames' rotation offsets); the positions give
    the scale and translation only. The weight above equalises the two terms' norms, not their
    information: the normalised positions of a track that spreads a few centimetres are mostly
    its noise, and they outweigh the orientations (a carried phone's 3 s track, 4-9 cm, 3 cm
    off: the rotation came out 0.45 rad off where the orientations were 0.05 rad off). From the
    orientations alone ``Q``'s error is that of the mean orientation offset, however short the
    track; a long track whose orientations are poorer than its shape is better served by "both".

    Args:
        est_positions: ``(T, 3)`` estimated camera positions, any frame and scale; NaN rows ignored.
        ref_positions: ``(T, 3)`` reference positions, metres; NaN rows ignored.
        est_orientations: optional ``(T, 3, 3)`` estimated camera-to-world rotations.
        ref_orientations: optional ``(T, 3, 3)`` reference camera-to-world rotations.
        rotation_from: ``"both"`` (positions and orientations) or ``"orientations"`` (which
            then must be given).

    Returns:
        :class:`Similarity` with ``apply(est_positions) ≈ ref_positions`` and
        ``apply_pose(est world_T_camera) ≈ ref world_T_camera``.

    Raises:
        MocapgraphError: mismatched shapes; only one of the orientation sequences given; fewer
            than 2 frames usable in both; a trajectory with no spread; the rotation undetermined
            (collinear positions and no orientations); ``rotation_from`` unknown, or
            "orientations" without them.
    """
    if rotation_from not in ROTATION_SOURCES:
        raise MocapgraphError(f"rotation_from {rotation_from!r}: choose one of {', '.join(ROTATION_SOURCES)}")
    est_positions = check_array(est_positions, Where("est_positions"), (None, 3), allow_nan=True)
    frames = est_positions.shape[0]
    ref_positions = check_array(ref_positions, Where("ref_positions"), (frames, 3), allow_nan=True)
    usable = _finite_rows(est_positions) & _finite_rows(ref_positions)
    if (est_orientations is None) != (ref_orientations is None):
        raise MocapgraphError("est_orientations/ref_orientations: give both or neither")
    with_orientations = est_orientations is not None
    if rotation_from == "orientations" and not with_orientations:
        raise MocapgraphError("rotation_from 'orientations': est_orientations and ref_orientations are needed")
    if with_orientations:
        est_orientations = check_array(est_orientations, Where("est_orientations"), (frames, 3, 3), allow_nan=True)
        ref_orientations = check_array(ref_orientations, Where("ref_orientations"), (frames, 3, 3), allow_nan=True)
        usable &= _finite_rows(est_orientations) & _finite_rows(ref_orientations)
        check_rotations(est_orientations[usable], Where("est_orientations"))
        check_rotations(ref_orientations[usable], Where("ref_orientations"))
    n = int(np.count_nonzero(usable))
    if n < 2:
        raise MocapgraphError(f"est_positions/ref_positions: need at least 2 frames finite in both, got {n}")

    est_mean = est_positions[usable].mean(axis=0)
    ref_mean = ref_positions[usable].mean(axis=0)
    est_centred = est_positions[usable] - est_mean
    ref_centred = ref_positions[usable] - ref_mean
    est_norm = np.linalg.norm(est_centred)
    ref_norm = np.linalg.norm(ref_centred)
    for name, norm in (("est_positions", est_norm), ("ref_positions", ref_norm)):
        if not norm > 0:
            raise MocapgraphError(f"{name}: all usable positions coincide; the scale is not determined")
    M = np.zeros((3, 3)) if rotation_from == "orientations" else (ref_centred / ref_norm).T @ (est_centred / est_norm)
    if with_orientations:
        M = M + np.einsum("nij,nkj->ik", ref_orientations[usable], est_orientations[usable]) / (3 * n)
    Q, _, singular = _rotation_from_cross_covariance(M)
    if not singular[1] > _RANK_TOLERANCE * singular[0]:
        raise MocapgraphError(
            "est_positions/ref_positions: the trajectory is a straight line; pass orientations to fix the rotation"
        )
    scale = ref_norm / est_norm
    return Similarity(scale, Q, ref_mean - scale * Q @ est_mean)


def ground_similarity(source: np.ndarray, target: np.ndarray) -> Similarity:
    """The similarity that keeps the ground (z = 0) and the up direction (+Z) of both frames:
    a turn about Z, a horizontal translation and a scale about the origin, minimising
    ``Σ ‖target_i − (s R_z source_i + t)‖²`` over ``source, target (N, 3)`` (NaN rows ignored).
    Between two ground-plane frames it leaves in what a similarity would take out: how far the
    source's ground and up are from the target's.

    Raises:
        MocapgraphError: mismatched shapes; fewer than 2 usable rows; no horizontal spread."""
    source = check_array(source, Where("source"), (None, 3), allow_nan=True)
    target = check_array(target, Where("target"), (source.shape[0], 3), allow_nan=True)
    usable = _finite_rows(source) & _finite_rows(target)
    if usable.sum() < 2:
        raise MocapgraphError(f"source/target: need at least 2 rows finite in both, got {int(usable.sum())}")
    p, q = source[usable], target[usable]
    pc, qc = p[:, :2] - p[:, :2].mean(0), q[:, :2] - q[:, :2].mean(0)
    cross = np.sum(pc[:, 0] * qc[:, 1] - pc[:, 1] * qc[:, 0])
    dot = np.sum(pc * qc)
    spread = np.sum(pc**2) + np.sum(p[:, 2] ** 2)
    if not spread > 0 or not np.hypot(cross, dot) > 0:
        raise MocapgraphError("source/target: no horizontal spread; the turn about Z is not determined")
    angle = np.arctan2(cross, dot)
    c, s = np.cos(angle), np.sin(angle)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    # with the turn fixed, the scale's least squares over the centred horizontal parts and the heights
    scale = (np.sum((pc @ R[:2, :2].T) * qc) + np.sum(p[:, 2] * q[:, 2])) / spread
    t = np.r_[q[:, :2].mean(0) - scale * R[:2, :2] @ p[:, :2].mean(0), 0.0]
    return Similarity(scale, R, t)


MIN_ALIGNMENT_CAMERAS = 3
"""Camera centres of at least this many cameras fix a similarity (two leave the rotation about
their baseline free)."""


def align_camera_centres(est_centres, ref_centres, with_scale: bool = True) -> Similarity:
    """The similarity (rigid if ``with_scale`` is False) mapping estimated camera centres onto
    reference ones, each camera weighing the same however many frames it has (Umeyama).

    Args:
        est_centres: per camera, ``(N_c, 3)`` estimated centres (the ``world_T_camera``
            translations), any frame and scale; NaN rows ignored. A static camera may give one row
            or the same row at each of its frames.
        ref_centres: per camera, ``(N_c, 3)`` the reference centres at the same frames, metres.
        with_scale: estimate the scale; else ``scale = 1`` (how far a result is from metric).

    Returns:
        :class:`Similarity` with ``apply(est) ≈ ref``.

    Raises:
        MocapgraphError: the lists' lengths or a camera's shapes differ; fewer than
            :data:`MIN_ALIGNMENT_CAMERAS` cameras with a finite pair; the centres collinear.
    """
    if len(est_centres) != len(ref_centres):
        raise MocapgraphError(f"est_centres/ref_centres: {len(est_centres)} cameras against {len(ref_centres)}")
    sources, targets, weights = [], [], []
    for c, (est, ref) in enumerate(zip(est_centres, ref_centres)):
        est = check_array(est, Where(f"est_centres[{c}]"), (None, 3), allow_nan=True)
        ref = check_array(ref, Where(f"ref_centres[{c}]"), (est.shape[0], 3), allow_nan=True)
        usable = _finite_rows(est) & _finite_rows(ref)
        if usable.any():
            sources.append(est[usable])
            targets.append(ref[usable])
            weights.append(np.full(int(usable.sum()), 1.0 / usable.sum()))
    if len(sources) < MIN_ALIGNMENT_CAMERAS:
        raise MocapgraphError(
            f"est_centres/ref_centres: {len(sources)} cameras have centres in both; aligning by camera centres needs {MIN_ALIGNMENT_CAMERAS}"
        )
    return umeyama(np.concatenate(sources), np.concatenate(targets), with_scale, np.concatenate(weights))
