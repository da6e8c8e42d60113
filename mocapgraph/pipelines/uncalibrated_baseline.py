"""``mocapgraph run baseline --uncalibrated``: structure from motion of body keypoints, no body model.

The generic method a new user would reach for when the intrinsics are known (or guessed) and the
static cameras' poses are not: the person's keypoints are the interest points.

1. **Keypoints** by the one road (:func:`~mocapgraph.pipelines.observations.capture_state_model`,
   undistorted once), one state per frame of the first camera (``"closest"``).
2. **Essential matrices and swap check**
   (:func:`~mocapgraph.data_tools.geometry.epipolar.resolve_swaps`): every pair's essential
   matrix from its co-visible keypoints pooled over all frames (robust estimators, refined),
   and each camera-frame's left/right labelling chosen by its Sampson distances to the other
   cameras, runs preferred over single frames, in turn until they settle. Relabelled frames are
   recorded per camera (``CameraTrack.swaps``) and counted in the notes.
3. **One frame**: the pair with the most inliers among those that triangulate well starts;
   its points are triangulated, every other camera is added by PnP (RANSAC) on them, the
   points re-triangulated with RANSAC over views after each. A swap shared by every camera of
   a frame is then undone where the skeleton from all cameras is mirrored
   (:func:`~mocapgraph.data_tools.geometry.epipolar.anatomy_scores`).
4. **Bundle adjustment** of the cameras and a free 3D point per keypoint and frame, Geman-McClure
   on the reprojection error (GTSAM's projection factor, this package's LM). The first camera
   of the starting pair holds the gauge, the pair's distance the (arbitrary) scale.
5. **Metric world**: the triangulated person is scaled to an assumed standing height
   (``height_m``) and the world put on the ground under them (:func:`body_frame`).

Conventions (``/work/shared/DESIGN.md``): metres, seconds; camera poses ``world_T_camera``
(OpenCV camera). The result's world (``"ground_plane"``): Z up, origin on the ground under the
hips' midpoint in the first frame that shows both hips, +Y the person's facing direction then.
Its keypoints are the triangulated points; its joints only those that are keypoints of the
format by name (hips, knees, ankles, shoulders, elbows, wrists), the rest NaN.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import cv2
import numpy as np

from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.labelling import SWAP_KINDS
from mocapgraph.body.skeleton import JOINT_NAMES
from mocapgraph.data_tools.geometry.epipolar import (
    ANATOMY_MARGIN,
    MIN_ANATOMY_PAIRS,
    PairGeometry,
    absolute_labels,
    anatomy_scores,
    apply_labels,
    pair_geometries,
    resolve_swaps,
)
from mocapgraph.data_tools.geometry.triangulation import DEFAULT_THRESHOLD_PX
from mocapgraph.data_tools.io.capture import Capture
from mocapgraph.data_tools.io.result import CameraTrack, Result, options_parameters
from mocapgraph.errors import MocapgraphError, is_positive_number
from mocapgraph.graphs.point_bundle import MIN_CONFIDENCE, bundle_adjust, reprojection_errors, triangulate_placed
from mocapgraph.pipelines.observations import capture_state_model, detector_names
from mocapgraph.pipelines.results import swap_notes

log = logging.getLogger(__name__)

EYE_HEIGHT_FRACTION = 0.936
ANKLE_HEIGHT_FRACTION = 0.039
"""Eye and ankle (lateral malleolus) heights of a standing adult as fractions of the stature
(Drillis and Contini 1966, as tabulated in Winter, *Biomechanics and Motor Control of Human
Movement*, 4th ed., 2009, fig. 4.1): the keypoints' eye-to-ankle extent is 0.897 of the height."""

MIN_PAIR_ANGLE_DEG = 4.0
"""A starting pair whose median triangulation angle is below this triangulates too poorly."""

MIN_GROUND_SPREAD_M = 0.3
"""A direction along which the feet's ground contacts spread at least this far (standard
deviation) is taken as horizontal: two such give the ground plane, one a line the vertical is
square to; the body's mean axis gives the rest."""

MAX_GROUND_TILT_DEG = 30.0
"""A ground plane further than this from the body's mean axis is not the floor (a stair, a fit to noise)."""

_GROUND_INLIER_M = 0.05
_MIN_PNP_POINTS = 12


@dataclass
class UncalibratedOptions:
    """Parameters of the uncalibrated baseline's self-calibration (units in the names)."""

    height_m: float = 1.75  # the person's standing height assumed for the metric scale
    swap_check: bool = True  # relabel camera-frames whose left/right labels fit the other cameras swapped
    gm_sigma_px: float = 10.0  # Geman-McClure scale of the bundle adjustment
    min_confidence: float = MIN_CONFIDENCE  # keypoints below are not used
    max_iterations: int = 50  # of the bundle adjustment

    def check(self) -> None:
        for name in ("height_m", "gm_sigma_px"):
            value = getattr(self, name)
            if not is_positive_number(value):
                raise MocapgraphError(f"{name}: must be a positive number, got {value!r}")
        if not (isinstance(self.min_confidence, (int, float)) and 0 <= self.min_confidence < 1):
            raise MocapgraphError(f"min_confidence: must lie in [0, 1), got {self.min_confidence!r}")
        if not (isinstance(self.max_iterations, int) and self.max_iterations >= 1):
            raise MocapgraphError(f"max_iterations: must be a positive integer, got {self.max_iterations!r}")


@dataclass
class Rig:
    """A capture's detections of one detector on one clock.

    Attributes:
        names: camera names; detector, fmt: the detector used and its keypoint format;
        times: ``(N,)`` seconds of the states (the first camera's frames).
        x: ``(C, N, K, 2)`` undistorted pixels, NaN where not seen; w: ``(C, N, K)`` confidences
            (0 where not seen or below the minimum); Ks: ``(C, 3, 3)``.
        frame: ``(C, N)`` each camera's frame at each state, -1 where none.
    """

    names: list[str]
    detector: str
    fmt: str
    times: np.ndarray
    x: np.ndarray
    w: np.ndarray
    Ks: np.ndarray
    frame: np.ndarray


def capture_rig(capture: Capture, detector: str | None, min_confidence: float) -> Rig:
    """The capture's static cameras' detections as a :class:`Rig`; a MocapgraphError for moving
    cameras, a camera without detections, or detectors in different formats."""
    moving = [cam.name for cam in capture.cameras if cam.moving]
    if moving:
        raise MocapgraphError(
            f"capture {capture.name!r}: cameras {', '.join(moving)} move; the uncalibrated baseline estimates one pose per "
            "static camera (use smartmocap or airpose for moving cameras)"
        )
    if len(capture.cameras) < 2:
        raise MocapgraphError(f"capture {capture.name!r}: the uncalibrated baseline needs at least 2 cameras, it has {len(capture.cameras)}")
    name = detector or next((n for n in detector_names(capture) if all(n in cam.detectors for cam in capture.cameras)), None)
    if name is None:
        listing = "; ".join(f"{c.name}: {', '.join(c.detectors) or 'none'}" for c in capture.cameras)
        raise MocapgraphError(f"capture {capture.name!r}: no detector is present on every camera ({listing})")
    for cam in capture.cameras:
        if name not in cam.detectors:
            raise MocapgraphError(f"camera {cam.name!r}: has no detector {name!r} (it has: {', '.join(cam.detectors) or 'none'})")
    formats = {cam.detectors[name].format for cam in capture.cameras}
    if len(formats) > 1:
        raise MocapgraphError(f"capture {capture.name!r}: detector {name!r} comes in several formats ({', '.join(sorted(formats))}); one is needed")
    model = capture_state_model(capture, "closest", detectors=(name,))
    fmt = formats.pop()
    C, N, K = model.num_cameras, model.num_states, get_format(fmt).num_points
    x = np.full((C, N, K, 2), np.nan)
    w = np.zeros((C, N, K))
    frame = np.full((C, N), -1)
    for n, observations in enumerate(model.states):
        for o in observations:
            # At most one frame per camera and state under "closest"; keep the first.
            if frame[o.camera, n] < 0:
                x[o.camera, n], w[o.camera, n], frame[o.camera, n] = o.observed, o.weights, o.frame
    w = np.where(w >= max(min_confidence, 1e-12), w, 0.0)
    blind = [model.names[c] for c in range(C) if not np.any(w[c] > 0)]
    if blind:
        raise MocapgraphError(
            f"capture {capture.name!r}: cameras {', '.join(blind)} have no keypoint of detector {name!r} with confidence >= {min_confidence}; "
            "every camera must see the person (leave the others out of the capture)"
        )
    return Rig(model.names, name, fmt, model.times, x, w, np.stack(model.camera_matrices()), frame)


# ---------------------------------------------------------------------------------------------
# Initial reconstruction


def _invert(T: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def starting_pair(pairs: dict[tuple[int, int], PairGeometry]) -> PairGeometry:
    """The pair with the most inliers among those whose median triangulation angle is at
    least :data:`MIN_PAIR_ANGLE_DEG` (else the widest)."""
    wide = [g for g in pairs.values() if g.median_angle_deg >= MIN_PAIR_ANGLE_DEG]
    return max(wide, key=lambda g: g.inliers) if wide else max(pairs.values(), key=lambda g: g.median_angle_deg)


def _pnp(points: np.ndarray, pixels: np.ndarray, K: np.ndarray, threshold_px: float, seed: int) -> tuple[np.ndarray, int] | None:
    """world_T_camera ``(4, 4)`` and its inlier count from 3D–2D correspondences (EPnP in
    RANSAC, then Levenberg-Marquardt on the inliers), or None with too few inliers."""
    cv2.setRNGSeed(int(seed))
    ok, rvec, tvec, inliers = cv2.solvePnPRansac(
        points, pixels, K, None, iterationsCount=1000, reprojectionError=float(threshold_px), confidence=0.999, flags=cv2.SOLVEPNP_EPNP
    )
    if not ok or inliers is None or len(inliers) < _MIN_PNP_POINTS:
        return None
    inliers = inliers.ravel()
    rvec, tvec = cv2.solvePnPRefineLM(points[inliers], pixels[inliers], K, None, rvec, tvec)
    camera_T_world = np.eye(4)
    camera_T_world[:3, :3] = cv2.Rodrigues(rvec)[0]
    camera_T_world[:3, 3] = tvec.ravel()
    return _invert(camera_T_world), len(inliers)


def initial_reconstruction(
    x: np.ndarray, w: np.ndarray, Ks: np.ndarray, pairs: dict[tuple[int, int], PairGeometry], names: list[str], threshold_px: float, seed: int
) -> tuple[list[np.ndarray], np.ndarray, tuple[int, int]]:
    """Cameras and points in the frame of the starting pair's first camera, its baseline of length 1.

    Returns:
        ``world_T_camera (4, 4)`` per camera, points ``(N, K, 3)`` (NaN where fewer than two
        cameras agree) and the starting pair.
    """
    if not pairs:
        raise MocapgraphError("no pair of cameras shares enough keypoints for an essential matrix; do the cameras see the same person at the same times?")
    first = starting_pair(pairs)
    poses: list[np.ndarray | None] = [None] * len(x)
    poses[first.a] = np.eye(4)
    a_T_b = np.eye(4)
    a_T_b[:3, :3], a_T_b[:3, 3] = first.R, first.t  # b's coordinates from a's
    poses[first.b] = _invert(a_T_b)
    points = triangulate_placed(poses, x, w, Ks, threshold_px, seed)
    while any(T is None for T in poses):
        known = np.isfinite(points).all(-1)
        waiting = [c for c, T in enumerate(poses) if T is None]
        shared = {c: int(np.count_nonzero(known & (w[c] > 0))) for c in waiting}
        c = max(waiting, key=lambda k: shared[k])
        use = known & (w[c] > 0)
        placed = _pnp(points[use], x[c][use], Ks[c], threshold_px, seed) if shared[c] >= _MIN_PNP_POINTS else None
        if placed is None:
            raise MocapgraphError(
                f"camera {names[c]!r}: could not be placed: {shared[c]} of its keypoints are triangulated from the others, "
                f"too few agree on one pose (PnP needs {_MIN_PNP_POINTS}); does it see the same person at the same times?"
            )
        poses[c] = placed[0]
        log.info("uncalibrated baseline: camera %s placed by PnP (%d of %d points agree)", names[c], placed[1], shared[c])
        points = triangulate_placed(poses, x, w, Ks, threshold_px, seed)
    return poses, points, (first.a, first.b)


# ---------------------------------------------------------------------------------------------
# Bundle adjustment


# ---------------------------------------------------------------------------------------------
# Metric world


@dataclass
class BodyFrame:
    """The similarity from the reconstruction's frame to a metric world on the ground.

    ``world = scale · R (p − origin)`` for a point ``p`` of the reconstruction.

    Attributes:
        scale: metres per unit of the reconstruction.
        R: ``(3, 3)`` rotation; origin: ``(3,)`` in the reconstruction's frame.
        stature: the person's height in reconstruction units, from their eye-to-ankle extent.
        vertical: ``"ground plane"`` (the normal of the feet's ground contacts), ``"body axis
            across the feet's line"`` (the body's mean axis made square to the line the contacts
            lie along) or ``"body axis"`` (the mean direction from the stance ankle to the shoulders).
        feet_spread_m: standard deviations of the feet's ground contacts along their two main directions.
        feet_tilt_deg: the angle between the vertical the contacts give and the body's mean axis.
    """

    scale: float
    R: np.ndarray
    origin: np.ndarray
    stature: float
    vertical: str
    feet_spread_m: tuple[float, float]
    feet_tilt_deg: float

    @property
    def why(self) -> str:
        """Why the vertical is what it is, for the notes."""
        wide, narrow = self.feet_spread_m
        if self.vertical == "ground plane":
            return f"the feet's ground contacts spread {wide:.2f} m by {narrow:.2f} m; {self.feet_tilt_deg:.1f}° from the body's axis"
        if self.vertical != "body axis":
            return f"the feet's ground contacts lie along a line ({wide:.2f} m, {narrow:.2f} m across it): the vertical is square to it, {self.feet_tilt_deg:.1f}° from the body's axis"
        if wide >= MIN_GROUND_SPREAD_M:
            return f"the feet's ground contacts lie {self.feet_tilt_deg:.0f}° off the body's axis: not the floor"
        return f"the feet's ground contacts spread only {wide:.2f} m"

    def points(self, p: np.ndarray) -> np.ndarray:
        return self.scale * (np.asarray(p) - self.origin) @ self.R.T

    def pose(self, world_T_camera: np.ndarray) -> np.ndarray:
        out = np.eye(4)
        out[:3, :3] = self.R @ world_T_camera[:3, :3]
        out[:3, 3] = self.points(world_T_camera[:3, 3])
        return out


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _middle(points: np.ndarray, names: tuple[str, ...], part: str) -> np.ndarray:
    """``(N, 3)`` midpoint of ``left_<part>`` and ``right_<part>`` (NaN unless both are known)."""
    return 0.5 * (points[:, names.index(f"left_{part}")] + points[:, names.index(f"right_{part}")])


def body_frame(points: np.ndarray, fmt: str, height_m: float) -> BodyFrame:
    """A metric, Z-up world under the person, from their triangulated keypoints ``(N, K, 3)``.

    - **Up**: the mean direction from the lower ankle to the shoulders' midpoint over the frames
      (the stance foot stands under the shoulders: on the simulator's walks, turns and stands
      within 2° of the vertical, where the eyes, ahead of the body's line, lean 3–6°); then made
      square to each main direction along which the lower ankles of the frames near the floor
      (the ground contacts) spread at least :data:`MIN_GROUND_SPREAD_M`: both, and it is the
      normal of their plane; one (a walk along a line), and the body's lean about that line is
      gone; none (a treadmill, standing), and it stays. Contacts that would tilt it more than
      :data:`MAX_GROUND_TILT_DEG` are not the floor.
    - **Scale**: the median height of the eyes above the lower ankle is
      ``EYE_HEIGHT_FRACTION − ANKLE_HEIGHT_FRACTION`` of the stature, set to ``height_m``; for a
      person walking upright that is their standing height (knees bend a little: a percent or two
      short); for someone sitting or crouching throughout, it is not.
    - **Ground**: the median height of the lower ankle minus ``ANKLE_HEIGHT_FRACTION`` of the stature.
    - **Origin and heading**: under the hips' midpoint in the first frame with both hips, +Y their
      facing direction (``left hip − right hip`` × up).
    """
    names = get_format(fmt).names
    eyes = _middle(points, names, "eye")
    shoulders = _middle(points, names, "shoulder")
    ankles = np.stack([points[:, names.index("left_ankle")], points[:, names.index("right_ankle")]], axis=1)
    hips = _middle(points, names, "hip")
    usable = np.isfinite(eyes).all(-1) & np.isfinite(shoulders).all(-1) & np.isfinite(ankles).all(-1).any(-1)
    if usable.sum() < 3:
        raise MocapgraphError(
            f"the reconstruction has eyes, shoulders and an ankle in {int(usable.sum())} frames; the world's scale and vertical need at least 3"
        )

    def lower_ankles(up: np.ndarray) -> np.ndarray:
        height = np.where(np.isfinite(ankles).all(-1), ankles @ up, np.inf)
        return np.take_along_axis(ankles, np.argmin(height, axis=1)[:, None, None], axis=1)[:, 0]

    # Which ankle is lower needs a vertical: the one from both ankles' directions first.
    rough = _unit(np.nanmean(_unit(shoulders[usable, None] - ankles[usable]).reshape(-1, 3), axis=0))
    axis = _unit(np.mean(_unit(shoulders[usable] - lower_ankles(rough)[usable]), axis=0))
    feet = lower_ankles(axis)[usable]
    stature = float(np.median((eyes[usable] - feet) @ axis)) / (EYE_HEIGHT_FRACTION - ANKLE_HEIGHT_FRACTION)
    if not stature > 0:
        raise MocapgraphError("the reconstruction's eyes are not above its ankles; the detections' labels may be wrong in every camera")
    scale = height_m / stature
    # A plane through the lower ankles, then again through those near it (the foot on the ground,
    # not mid-swing).
    contacts = feet
    for _ in range(2):
        centre = contacts.mean(axis=0)
        _, s, vt = np.linalg.svd(contacts - centre, full_matrices=False)
        normal = vt[2] if vt[2] @ axis > 0 else -vt[2]
        near = feet[np.abs((feet - centre) @ normal) * scale < _GROUND_INLIER_M]
        if len(near) < 3:
            break
        contacts = near
    # The contacts' spread along their two main directions; each direction they spread far along
    # is horizontal, so the vertical is made perpendicular to it.
    spread = s[:2] / np.sqrt(len(contacts)) * scale if len(contacts) >= 3 else np.zeros(2)
    along = [vt[i] for i in range(2) if spread[i] >= MIN_GROUND_SPREAD_M]
    up = _unit(axis - sum((axis @ d) * d for d in along)) if along else axis
    tilt = float(np.degrees(np.arccos(np.clip(up @ axis, -1.0, 1.0))))
    if tilt > MAX_GROUND_TILT_DEG:
        up, along = axis, []
    vertical = ("body axis", "body axis across the feet's line", "ground plane")[len(along)]
    feet = lower_ankles(up)[usable]
    ground = float(np.median(feet @ up)) - ANKLE_HEIGHT_FRACTION * stature
    both_hips = np.flatnonzero(np.isfinite(hips).all(-1) & np.isfinite(points[:, names.index("left_hip")]).all(-1))
    if both_hips.size == 0:
        raise MocapgraphError("the reconstruction never has both hips; the world's origin and heading need them")
    n = both_hips[0]
    left = points[n, names.index("left_hip")] - points[n, names.index("right_hip")]
    facing = _unit(np.cross(left, up))
    right = np.cross(facing, up)
    R = np.stack([right, facing, up])
    origin = hips[n] - (hips[n] @ up - ground) * up
    return BodyFrame(scale, R, origin, stature, vertical, (float(spread[0]), float(spread[1])), tilt)


# ---------------------------------------------------------------------------------------------
# The pipeline


def run_uncalibrated_baseline(
    capture: Capture,
    options: UncalibratedOptions | None = None,
    capture_label: str = "",
    *,
    detector: str | None = None,
    threshold_px: float = DEFAULT_THRESHOLD_PX,
    seed: int = 0,
) -> Result:
    """Self-calibrate the capture's static cameras from the person's keypoints; nothing written.

    Args:
        capture: static cameras with intrinsics (known or guessed) and detections; extrinsics,
            if any, are not used.
        options: the self-calibration's parameters.
        capture_label: the capture's path as the result records it.
        detector: which detector (default: the first every camera has).
        threshold_px: RANSAC inlier threshold of the essential matrices, PnP and triangulation;
            also where the swap check's distances are truncated.
        seed: RANSAC's sampling.

    Returns:
        A result in ``"ground_plane"``: every camera's pose at its frames, the keypoints
        ``(T, K, 3)``, joints ``(T, 22, 3)`` where the format names them, the relabelled frames
        per camera (``CameraTrack.swaps``), per-camera reprojection medians and notes in the
        parameters, the bundle adjustment's log.
    """
    options = options or UncalibratedOptions()
    options.check()
    if not (np.isfinite(threshold_px) and threshold_px > 0):
        raise MocapgraphError(f"threshold_px: must be a positive number of pixels, got {threshold_px!r}")
    started = time.perf_counter()
    rig = capture_rig(capture, detector, options.min_confidence)
    names = get_format(rig.fmt).names
    C, N, K = rig.w.shape
    if options.swap_check:
        check = resolve_swaps(rig.x, rig.w, rig.Ks, names, threshold_px=threshold_px)
        labels, pairs = check.labels, check.pairs
        log.info("uncalibrated baseline: swap check in %d rounds%s", check.rounds, "" if check.converged else " (not settled)")
    else:
        labels = np.zeros((C, N), dtype=int)
        pairs = pair_geometries(rig.x, rig.w, rig.Ks, threshold_px=threshold_px)
    x, w = apply_labels(rig.x, labels, names), apply_labels(rig.w, labels, names)
    poses, points, gauge = initial_reconstruction(x, w, rig.Ks, pairs, rig.names, threshold_px, seed)
    if options.swap_check:
        # The skeleton from every camera at once decides each frame's absolute side far more
        # often than pairs of cameras could (a nose or an ear seen by any two of them).
        # As with pairs, two cameras alone can agree on the other side's guessed points.
        seen = (rig.w > 0).any(axis=-1)
        scores = anatomy_scores(points, names)
        views = seen.sum(axis=0) >= MIN_ANATOMY_PAIRS + 1
        decided = {kind: views & (np.abs(np.nan_to_num(score)) >= ANATOMY_MARGIN[kind]) for kind, score in scores.items()}
        absolute = absolute_labels(labels, seen, scores, decided)
        if not np.array_equal(absolute, labels):
            log.info("uncalibrated baseline: the skeleton turned the labels of %d frames", int(np.any(absolute != labels, axis=0).sum()))
            labels = absolute
            x, w = apply_labels(rig.x, labels, names), apply_labels(rig.w, labels, names)
            points = triangulate_placed(poses, x, w, rig.Ks, threshold_px, seed)
    poses, points, solve_log = bundle_adjust(x, w, rig.Ks, poses, points, gauge, options.gm_sigma_px, options.max_iterations)
    errors = reprojection_errors(x, w, rig.Ks, poses, points)
    frame = body_frame(points, rig.fmt, options.height_m)
    world_points = frame.points(points)
    seconds = time.perf_counter() - started

    medians = {rig.names[c]: round(float(np.nanmedian(errors[c])), 3) for c in range(C)}
    # A state where a camera has no frame keeps the label its neighbours gave it; it is no frame's.
    labels = np.where(rig.frame >= 0, labels, 0)
    swaps = {}
    result = Result(
        pipeline="baseline", capture=capture_label or str(capture.path or capture.name), world_frame="ground_plane", timestamps=rig.times,
        joints=np.stack([world_points[:, names.index(j)] if j in names else np.full((N, 3), np.nan) for j in JOINT_NAMES], axis=1),
        keypoints=world_points, keypoint_format=rig.fmt, log=list(solve_log),
        flags={"num_views": (w > 0).any(axis=2).sum(axis=0), "points_triangulated": np.isfinite(points).all(-1).sum(axis=1),
               "relabelled_cameras": (labels > 0).sum(axis=0)},
    )  # fmt: skip
    for c, cam in enumerate(capture.cameras):
        per_frame = np.full(cam.num_frames, -1, dtype=int)
        used = rig.frame[c] >= 0
        per_frame[rig.frame[c][used]] = labels[c][used]
        swaps[c] = per_frame
        frames = rig.frame[c][used]
        result.cameras[cam.name] = CameraTrack(cam.timestamps[frames], np.repeat(frame.pose(poses[c])[None], len(frames), axis=0), labels[c][used].astype(np.int8))
    notes = list(capture.notes)
    notes += swap_notes(rig.names, swaps) if options.swap_check else ["swap check off: left/right labels as detected"]
    notes += [
        f"metric scale from an assumed standing height of {options.height_m:g} m (eye-to-ankle extent {EYE_HEIGHT_FRACTION - ANKLE_HEIGHT_FRACTION:.3f} of it); "
        "off by as much as the person's height is",
        f"vertical from the {frame.vertical} ({frame.why})",
    ]
    for note in notes:
        log.info("uncalibrated baseline: %s", note)
    result.parameters = {
        **options_parameters(options), "uncalibrated": True, "detector": rig.detector, "threshold_px": float(threshold_px),
        "seed": int(seed), "cameras": rig.names, "starting_pair": [rig.names[gauge[0]], rig.names[gauge[1]]],
        "reprojection_median_px": medians, "median_reprojection_error_px": round(float(np.nanmedian(errors)), 3),
        "relabelled_frames": {rig.names[c]: {kind: sorted(int(j) for j in rig.frame[c][labels[c] == code]) for code, kind in enumerate(SWAP_KINDS) if code}
                              for c in range(C)},
        "relabelled_counts": {rig.names[c]: int(np.count_nonzero(labels[c])) for c in range(C)},
        "metres_per_unit": float(frame.scale), "vertical": frame.vertical, "triangulated_share": float(np.isfinite(points).all(-1).mean()),
        "seconds": round(seconds, 3), "notes": notes,
    }  # fmt: skip
    return result


def summary(result: Result) -> str:
    """What ``run baseline --uncalibrated`` prints: a line, the per-camera reprojection medians, the notes."""
    p = result.parameters
    per_camera = ", ".join(f"{name} {px:.1f}" for name, px in p["reprojection_median_px"].items())
    lines = [
        f"baseline --uncalibrated: {len(result.timestamps)} frames from {len(p['cameras'])} cameras ({p['detector']}, {result.keypoint_format}) "
        f"in {p['seconds']:.1f} s; world: ground plane, scale from a {p['height_m']:g} m person",
        f"  reprojection median {p['median_reprojection_error_px']:.1f} px (per camera: {per_camera})",
    ]
    return "\n".join(lines + [f"  note: {note}" for note in p["notes"]])
