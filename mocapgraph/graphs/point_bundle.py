"""Bundle adjustment of cameras and free 3D points: the body's keypoints with no body.

A detector's keypoints are not the body model's: its hip, shoulder and knee points sit where it
learnt to put them, which shifts with the view and the pose. Free points absorb that; a body
cannot. The generic self-calibration (:mod:`~mocapgraph.pipelines.uncalibrated_baseline`)
adjusts every camera on them, and SmartMocap refines its static cameras on them last
(:func:`refine_static_cameras`), the body having settled what free points cannot: the labels,
the metric scale and the world.

Conventions (``/work/shared/DESIGN.md``): metres; ``world_T_camera`` (OpenCV camera); pixels of
the ideal pinhole image (undistorted).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import gtsam
import numpy as np

from mocapgraph.data_tools.geometry.triangulation import projection_matrix, triangulate_ransac
from mocapgraph.factors.keys import camera_key
from mocapgraph.graphs.initialisation import common_format_cameras
from mocapgraph.graphs.solver import SolverOptions, levenberg_marquardt
from mocapgraph.graphs.state_model import Estimate, StateModel

log = logging.getLogger(__name__)

_GAUGE_SIGMA = 1e-6
_RELATIVE_TOLERANCE = 1e-4
"""The bundle adjustment stops when an iteration lowers the cost by less than this fraction: the
Geman-McClure tail creeps on for tens of iterations that move the cameras by well under a millimetre."""


def point_key(index: int) -> int:
    """Key of the free 3D point ``index`` (``state · K + keypoint``) of the bundle adjustment."""
    return gtsam.symbol("l", index)


def triangulate_placed(poses: list[np.ndarray | None], x: np.ndarray, w: np.ndarray, Ks: np.ndarray, threshold_px: float, seed: int) -> np.ndarray:
    """``(N, K, 3)`` points from the placed cameras (RANSAC over views, at least 2 agreeing)."""
    placed = [c for c, T in enumerate(poses) if T is not None]
    C, N, K = w.shape
    P = np.stack([projection_matrix(Ks[c], poses[c]) for c in placed])
    X, _, _ = triangulate_ransac(
        P, x[placed].reshape(len(placed), N * K, 2), w[placed].reshape(len(placed), N * K), threshold_px=threshold_px, seed=seed
    )
    return X.reshape(N, K, 3)


def bundle_adjust(
    x: np.ndarray, w: np.ndarray, Ks: np.ndarray, poses: list[np.ndarray], points: np.ndarray, gauge: tuple[int, int], gm_sigma_px: float, max_iterations: int
) -> tuple[list[np.ndarray], np.ndarray, list[dict]]:
    """Cameras and free points that minimise the Geman-McClure reprojection error.

    Every known point (finite in ``points``) gets a variable and a projection factor per camera
    that sees it (``w > 0``), unweighted by confidence (its scale ``gm_sigma_px``: residuals
    beyond it count less and less). ``gauge = (a, b)``: camera ``a`` held where it is, the
    distance between ``a`` and ``b`` held at its current value.

    Returns:
        cameras ``world_T_camera (4, 4)``, points ``(N, K, 3)`` (NaN as given) and the solver's log.
    """
    C, N, K = w.shape
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.GemanMcClure.Create(gm_sigma_px), gtsam.noiseModel.Isotropic.Sigma(2, 1.0))
    calibrations = [gtsam.Cal3_S2(K[0, 0], K[1, 1], K[0, 1], K[0, 2], K[1, 2]) for K in Ks]
    for c, T in enumerate(poses):
        values.insert(camera_key(c, 0), gtsam.Pose3(T))
    known = np.isfinite(points).all(-1)
    for n, k in zip(*np.nonzero(known)):
        key = point_key(int(n) * K + int(k))
        values.insert(key, gtsam.Point3(points[n, k]))
        for c in np.flatnonzero(w[:, n, k] > 0):
            graph.add(gtsam.GenericProjectionFactorCal3_S2(gtsam.Point2(*x[c, n, k]), noise, camera_key(int(c), 0), key, calibrations[c]))
    a, b = gauge
    graph.add(gtsam.PriorFactorPose3(camera_key(a, 0), gtsam.Pose3(poses[a]), gtsam.noiseModel.Isotropic.Sigma(6, _GAUGE_SIGMA)))
    distance = float(np.linalg.norm(poses[a][:3, 3] - poses[b][:3, 3]))
    graph.add(gtsam.RangeFactorPose3(camera_key(a, 0), camera_key(b, 0), distance, gtsam.noiseModel.Isotropic.Sigma(1, _GAUGE_SIGMA)))
    # Points first: each is eliminated onto its few cameras (the Schur complement), leaving a
    # dense system of the cameras alone.
    ordering = [point_key(int(n) * K + int(k)) for n, k in zip(*np.nonzero(known))] + [camera_key(c, 0) for c in range(C)]
    solved = levenberg_marquardt(graph, values, SolverOptions(max_iterations=max_iterations, relative_tolerance=_RELATIVE_TOLERANCE, ordering=ordering), stage="bundle adjustment")
    log.info(
        "bundle adjustment of %d cameras and %d free points, cost %.4g -> %.4g in %d iterations (%s)",
        C, int(known.sum()), solved.initial_error, solved.error, solved.iterations, solved.reason,
    )  # fmt: skip
    out_poses = [solved.values.atPose3(camera_key(c, 0)).matrix() for c in range(C)]
    out_points = np.full_like(points, np.nan)
    for n, k in zip(*np.nonzero(known)):
        out_points[n, k] = solved.values.atPoint3(point_key(int(n) * K + int(k)))
    return out_poses, out_points, solved.log


def reprojection_errors(x: np.ndarray, w: np.ndarray, Ks: np.ndarray, poses: list[np.ndarray], points: np.ndarray) -> np.ndarray:
    """``(C, N, K)`` pixel distance between each used observation and its point's projection (NaN
    where unused or unknown)."""
    out = np.full(w.shape, np.nan)
    for c, T in enumerate(poses):
        P = projection_matrix(Ks[c], T)
        h = points @ P[:, :3].T + P[:, 3]
        with np.errstate(invalid="ignore", divide="ignore"):
            err = np.linalg.norm(h[..., :2] / h[..., 2:] - x[c], axis=-1)
        out[c] = np.where(w[c] > 0, err, np.nan)
    return out


# ---------------------------------------------------------------------------------------------
# SmartMocap's static cameras


MIN_CONFIDENCE = 0.2
"""Keypoints below this confidence take no part in the free points' adjustment."""
MIN_POINTS = 12
"""A static camera needs this many triangulated points of the format adjusted on to take part."""
MIN_STATIC_CAMERAS = 2
"""Fewer static cameras are not adjusted on free points."""
PAIR_MIN_ANGLE_DEG = 100.0
"""Two static cameras alone are adjusted only when they face each other across the person: the
angle at the free points' middle between the directions to them at least this. Measured (one
run each): on ``phones`` (3 s, five CMU takes, no offset passes; the static phones 103-144°
apart) the pair's geometry among themselves (after their own Procrustes) came nearer the truth
on every take, 3.6 → 2.0 cm median, their error after the evaluation's alignment 22.0 → 16.9
cm; on 2 s of ``rich`` from poses 6 cm and 1.5° off, of its static pairs 44-90° apart every one
ended with a relative rotation 0.03-0.13 rad off on one of two starts (two views' free points fit
a family of relative poses along their epipolar geometry), those 112° and 141° apart nearer the
truth on both."""


@dataclass
class StaticRefinement:
    """Static cameras adjusted on free points (:func:`refine_static_cameras`).

    Attributes:
        cameras: camera index → ``(4, 4)`` world_T_camera, in the frame of the gauge camera
            ``gauge[0]`` (held) with the distance to ``gauge[1]`` held.
        gauge: the two cameras.
        fmt: the keypoint format adjusted on (the one most static cameras observe).
        points: how many free points.
        reprojection_px: median pixel error of the free points after the adjustment.
    """

    cameras: dict[int, np.ndarray]
    gauge: tuple[int, int]
    fmt: str
    points: int
    reprojection_px: float


def _pair_angle_deg(poses: list[np.ndarray], points: np.ndarray) -> float:
    """Degrees between the directions from the middle of ``points`` ``(N, K, 3)`` (the median
    per axis, NaN ignored: two views triangulate a wrong match anywhere along its rays) to the
    two cameras ``poses`` (world_T_camera)."""
    centroid = np.nanmedian(points.reshape(-1, 3), axis=0)
    a, b = (T[:3, 3] - centroid for T in poses)
    return float(np.degrees(np.arccos(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)), -1.0, 1.0))))


def refine_static_cameras(
    model: StateModel, estimate: Estimate, codes: dict[int, np.ndarray], gm_sigma_px: float, threshold_px: float, max_iterations: int, seed: int = 0
) -> StaticRefinement | None:
    """The static cameras of a solved ``model`` adjusted on free points, from the solve's poses.

    The observations (labelled by the solve's ``codes``, :meth:`StateModel.relabelled`) of the
    static cameras in the format most of them observe
    (:func:`~mocapgraph.graphs.initialisation.common_format_cameras`) are triangulated from ``estimate``'s poses (RANSAC at
    ``threshold_px``) and adjusted with the cameras (:func:`bundle_adjust`, Geman-McClure at
    ``gm_sigma_px``), the focal lengths as estimated. The camera seeing the most keypoints holds
    the gauge with the one farthest from it. Only static cameras that see :data:`MIN_POINTS` of
    those points take part; None with fewer than :data:`MIN_STATIC_CAMERAS` of them, or with two
    less than :data:`PAIR_MIN_ANGLE_DEG` apart seen from the person (with two, the gauge holds one
    and their distance: the other keeps its relative pose, which the free points fix).
    """
    rig = common_format_cameras(model, [c for c, cam in enumerate(model.cameras) if not cam.moving])
    if rig is None:
        return None
    static, fmt = rig
    labelled = model.relabelled(codes)
    views = np.stack([labelled.view_keypoints(c)[0] for c in static])  # (C, N, K, 3)
    x, w = views[..., :2], np.nan_to_num(views[..., 2])
    w[w < MIN_CONFIDENCE] = 0.0
    Ks = np.stack([model.cameras[c].K for c in static])
    Ks[:, :2, :2] *= np.exp(estimate.focal_log[static])[:, None, None]
    points = triangulate_placed([estimate.cameras[c][0] for c in static], x, w, Ks, threshold_px, seed)
    seen = (w > 0) & np.isfinite(points).all(-1)[None]
    # a camera with too few of the format's points would be a variable nothing holds
    keep = np.flatnonzero(seen.sum(axis=(1, 2)) >= MIN_POINTS)
    if len(keep) < MIN_STATIC_CAMERAS or (len(keep) == 2 and _pair_angle_deg([estimate.cameras[static[k]][0] for k in keep], points) < PAIR_MIN_ANGLE_DEG):
        return None
    static, x, w, Ks, seen = [static[k] for k in keep], x[keep], w[keep], Ks[keep], seen[keep]
    poses = [estimate.cameras[c][0] for c in static]
    a = int(np.argmax(seen.sum(axis=(1, 2))))
    b = int(np.argmax([np.linalg.norm(T[:3, 3] - poses[a][:3, 3]) for T in poses]))
    adjusted, points, _ = bundle_adjust(x, w, Ks, poses, points, (a, b), gm_sigma_px, max_iterations)
    return StaticRefinement(
        cameras={c: T for c, T in zip(static, adjusted)}, gauge=(static[a], static[b]), fmt=fmt, points=int(np.isfinite(points).all(-1).sum()),
        reprojection_px=float(np.nanmedian(reprojection_errors(x, w, Ks, adjusted, points))),
    )  # fmt: skip
