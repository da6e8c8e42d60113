"""``mocapgraph run baseline``: triangulation of calibrated cameras, written as a result.

The reference every pipeline is compared with: per frame and keypoint, confidence-weighted DLT
with RANSAC over views (the geometry is ``data_tools.geometry.triangulation``; here a capture's
cameras are put on one clock, undistorted and batched). It estimates 3D keypoints of the detector's
format, not a body, so the result's joints are NaN and ``eval`` scores its keypoints.

With ``uncalibrated=True`` (``run baseline --uncalibrated``) the cameras' poses are not read but
estimated from the keypoints: :mod:`mocapgraph.pipelines.uncalibrated_baseline`.

Conventions (``/work/shared/DESIGN.md``): world points in metres, in the capture's world frame;
timestamps in seconds; camera poses ``world_T_camera`` (OpenCV camera, +z forward).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace

import numpy as np

from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.skeleton import NUM_JOINTS
from mocapgraph.data_tools.geometry.camera_model import undistort_pixels
from mocapgraph.data_tools.geometry.epipolar import apply_labels, resolve_swaps
from mocapgraph.data_tools.geometry.timing import match_times
from mocapgraph.data_tools.geometry.triangulation import (
    DEFAULT_MAX_PAIRS,
    DEFAULT_THRESHOLD_PX,
    check_ransac_options,
    projection_matrix,
    triangulate_ransac,
)
from mocapgraph.data_tools.io.capture import Camera, Capture
from mocapgraph.data_tools.io.result import CameraTrack, Result, options_parameters
from mocapgraph.errors import MocapgraphError
from mocapgraph.pipelines import uncalibrated_baseline
from mocapgraph.pipelines.results import swap_notes
from mocapgraph.pipelines.uncalibrated_baseline import UncalibratedOptions, run_uncalibrated_baseline

log = logging.getLogger(__name__)

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
        swaps: ``(C, T)`` the left/right labelling each camera's detections took
            (:data:`~mocapgraph.body.labelling.SWAP_KINDS` codes, 0 as detected), or None
            without the swap check.
        frames: ``(C, T)`` each camera's frame at each reference time, -1 where it has none.
    """

    timestamps: np.ndarray
    points: np.ndarray
    format: str
    inliers: np.ndarray
    reprojection_error_px: np.ndarray
    cameras: tuple[str, ...] = ()
    detector: str = ""
    swaps: np.ndarray | None = None
    frames: np.ndarray | None = None


@dataclass
class BaselineOptions:
    """Parameters of the triangulation baseline."""

    detector: str | None = None  # default: the first detector every camera has
    threshold_px: float = DEFAULT_THRESHOLD_PX  # RANSAC inlier threshold
    seed: int = 0  # RANSAC's pair sampling
    swap_check: bool = True  # relabel left/right swaps against the calibrated cameras' epipolar geometry (static cameras)
    uncalibrated: bool = False  # estimate the static cameras' poses from the keypoints instead of reading them
    self_calibration: UncalibratedOptions = field(default_factory=UncalibratedOptions)  # used with uncalibrated


def run_baseline(capture: Capture, options: BaselineOptions | None = None, capture_label: str = "") -> Result:
    """Triangulate every frame from the capture's calibrated cameras (the others are skipped, and
    the result's parameters say which), or with ``options.uncalibrated`` self-calibrate them
    (:func:`~mocapgraph.pipelines.uncalibrated_baseline.run_uncalibrated_baseline`); nothing written."""
    options = options or BaselineOptions()
    if options.uncalibrated:
        calibration = replace(options.self_calibration, swap_check=options.swap_check and options.self_calibration.swap_check)
        return run_uncalibrated_baseline(
            capture, calibration, capture_label, detector=options.detector, threshold_px=options.threshold_px, seed=options.seed
        )
    calibrated = [cam for cam in capture.cameras if cam.extrinsics is not None]
    skipped = [cam.name for cam in capture.cameras if cam.extrinsics is None]
    if len(calibrated) < 2:
        raise MocapgraphError(
            f"capture {capture.name!r}: the baseline needs at least 2 calibrated cameras, found "
            f"{len(calibrated)} (uncalibrated: {', '.join(skipped) or 'none'}); --uncalibrated estimates static cameras' poses from the keypoints"
        )
    if skipped:
        log.info("baseline: skipping uncalibrated cameras %s", ", ".join(skipped))
    tri = triangulate_capture(
        replace(capture, cameras=calibrated), detector=options.detector, threshold_px=options.threshold_px, seed=options.seed, swap_check=options.swap_check
    )
    T = len(tri.timestamps)
    known = np.isfinite(tri.points).all(axis=2)
    tracks, notes = {}, []
    for c, cam in enumerate(calibrated):  # the cameras as given, with the labels their detections took
        has = tri.frames[c] >= 0
        ext = np.asarray(cam.extrinsics, dtype=float)
        poses = np.repeat(ext[:1], has.sum(), axis=0) if len(ext) == 1 else ext[tri.frames[c][has]]
        tracks[cam.name] = CameraTrack(tri.timestamps[has], poses, None if tri.swaps is None else tri.swaps[c][has])
    if tri.swaps is not None:
        notes = swap_notes(list(tri.cameras), {c: np.where(tri.frames[c] >= 0, tri.swaps[c], -1) for c in range(len(calibrated))})
    return Result(
        pipeline="baseline",
        capture=capture_label or str(capture.path or capture.name),
        world_frame="capture",
        timestamps=tri.timestamps,
        joints=np.full((T, NUM_JOINTS, 3), np.nan),
        keypoints=tri.points,
        keypoint_format=tri.format,
        flags={"num_views": tri.inliers.any(axis=2).sum(axis=1), "points_triangulated": known.sum(axis=1)},
        parameters={
            **options_parameters(replace(options, self_calibration=None)), "detector": tri.detector, "threshold_px": float(options.threshold_px),
            "cameras": list(tri.cameras), "skipped_cameras": skipped, "triangulated_share": float(known.mean()),
            "median_reprojection_error_px": float(np.nanmedian(tri.reprojection_error_px)) if known.any() else float("nan"),
            "notes": notes,
        },
        cameras=tracks,
    )  # fmt: skip


def summary(result: Result) -> str:
    """The line ``run baseline`` prints."""
    p = result.parameters
    if p.get("uncalibrated"):
        return uncalibrated_baseline.summary(result)
    skipped = f"baseline: skipping uncalibrated cameras {', '.join(p['skipped_cameras'])}\n" if p["skipped_cameras"] else ""
    return (
        f"{skipped}baseline: {len(result.timestamps)} frames from {len(p['cameras'])} cameras ({p['detector']}, {result.keypoint_format}); "
        f"{p['triangulated_share']:.0%} of keypoints triangulated, median reprojection error {p['median_reprojection_error_px']:.1f} px"
    ) + "".join(f"\n  note: {note}" for note in p.get("notes", []))


def triangulate_capture(
    capture: Capture,
    detector: str | None = None,
    *,
    threshold_px: float = DEFAULT_THRESHOLD_PX,
    seed: int = 0,
    max_time_offset_s: float | None = None,
    min_views: int = 2,
    refine: bool = True,
    swap_check: bool = False,
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
        swap_check: first relabel each static camera-frame's left/right swaps against the other
            static cameras' known epipolar geometry (moving cameras stay as detected)
            (:func:`~mocapgraph.data_tools.geometry.epipolar.resolve_swaps` with ``poses``).

    Returns:
        A :class:`Triangulation` in the capture's world frame.
    """
    if not isinstance(capture, Capture):
        raise MocapgraphError(f"capture: expected a Capture, got {type(capture).__name__}")
    if not capture.cameras:
        raise MocapgraphError(f"capture {capture.name!r}: has no cameras")
    check_ransac_options(threshold_px, min_views, DEFAULT_MAX_PAIRS)
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
        seen = np.isfinite(kp[..., 2]) & np.all(np.isfinite(kp[..., :2]), axis=-1)
        # NaN, not inf, for an unseen point: triangulate_ransac refuses inf observations.
        x[c, used] = np.where(seen[..., None], undistort_pixels(kp[..., :2], cam.K, cam.distortion), np.nan)
        w[c, used] = np.where(seen, kp[..., 2], 0.0)
        ext = np.asarray(cam.extrinsics, dtype=float)
        poses = ext[np.zeros_like(idx)] if len(ext) == 1 else ext[idx]
        P[c, used] = projection_matrix(cam.K, poses)
    if np.any(w < 0):
        c = int(np.argwhere(w < 0)[0][0])
        raise MocapgraphError(f"camera {cams[c].name!r}: detector {name!r} has negative confidences")
    swaps = None
    static = [c for c, cam in enumerate(cams) if len(np.asarray(cam.extrinsics)) == 1]
    if swap_check and len(static) >= 2:
        # moving cameras are left as detected: their epipolar geometry changes frame by frame
        names = get_format(fmt).names
        poses = np.stack([np.asarray(cams[c].extrinsics, dtype=float)[0] for c in static])
        swaps = np.zeros((C, T), dtype=np.int8)
        swaps[static] = resolve_swaps(x[static], w[static], np.stack([cams[c].K for c in static]), names, threshold_px=threshold_px, poses=poses).labels
        x, w = apply_labels(x, swaps, names), apply_labels(w, swaps, names)

    rng = np.random.default_rng(seed)
    points = np.full((T, K_pts, 3), np.nan)
    inliers = np.zeros((T, C, K_pts), dtype=bool)
    errors = np.full((T, K_pts), np.nan)
    # Frames are independent, so a chunk of them is solved as one batch of n·K points, each with
    # its frame's projections (zeros where a camera has no frame: those points are unseen there).
    for start in range(0, T, _FRAMES_PER_CHUNK):
        sl = slice(start, min(T, start + _FRAMES_PER_CHUNK))
        n = sl.stop - sl.start
        Pc = np.repeat(P[:, sl, None], K_pts, axis=2).reshape(C, n * K_pts, 3, 4)
        X, mask, err = triangulate_ransac(
            Pc, x[:, sl].reshape(C, n * K_pts, 2), w[:, sl].reshape(C, n * K_pts),
            threshold_px=threshold_px, min_views=min_views, max_pairs=DEFAULT_MAX_PAIRS, refine=refine, seed=rng,
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
        swaps=swaps,
        frames=frame_of,
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
    limits = [0.5 / cam.frame_rate if max_offset is None else max_offset for cam in cams]
    # Only the grid times some frame can match are built: over the whole span, clocks offset by
    # years or a camera's 1e-6 s steps would ask for billions of reference times, nearly all empty.
    before, after = [], []
    for cam, limit in zip(cams, limits):
        reach = limit * (1 + 1e-9) + 1e-12
        ts = np.asarray(cam.timestamps, dtype=float)
        for side, origin, sign, count in ((before, base[0], -1.0, n_before), (after, base[-1], 1.0, n_after)):
            d = sign * (ts - origin) / period  # grid steps away from the base, on this side
            first = np.maximum(np.ceil(d - reach / period - 1e-9), 1)  # a candidate too many is harmless
            last = np.minimum(np.floor(d + reach / period + 1e-9), count)
            n = np.maximum(last - first + 1, 0).astype(np.int64)
            if n.sum() > max(64 * (len(ts) + len(base)), 1_000_000):
                raise MocapgraphError(
                    f"camera {cam.name!r}: its matching tolerance {limit:.4g} s spans {float(n.max()):.3g} frame periods "
                    f"({period:.4g} s) of camera {cams[0].name!r}; do the frame rates and timestamps agree?"
                )
            start = np.repeat(first[n > 0].astype(np.int64), n[n > 0])
            side.append(start + np.arange(len(start)) - np.repeat(np.cumsum(n[n > 0]) - n[n > 0], n[n > 0]))
    k_before = np.unique(np.concatenate(before))[::-1]
    k_after = np.unique(np.concatenate(after))
    times = np.concatenate([base[0] - period * k_before, base, base[-1] + period * k_after])
    own = np.zeros(len(times), dtype=bool)
    own[len(k_before) : len(k_before) + len(base)] = True

    # A hair of slack so a frame exactly half a period away is not lost to rounding.
    frame_of = np.stack(
        [match_times(cam.timestamps, times, limit, rtol=1e-9, atol=1e-12) for cam, limit in zip(cams, limits)]
    )

    present = frame_of >= 0
    shared = present & (present.sum(axis=0) >= 2)
    for c, (cam, limit) in enumerate(zip(cams, limits)):
        if not np.any(shared[c]):
            spans = ", ".join(f"{o.name} {o.timestamps[0]:.3f}–{o.timestamps[-1]:.3f} s" for o in cams)
            raise MocapgraphError(
                f"camera {cam.name!r}: no frame within {limit:.4g} s of a frame of another camera; "
                f"are the clocks the same? (spans: {spans})"
            )
    keep = own | (present.sum(axis=0) >= min_views)
    return times[keep], frame_of[:, keep]
