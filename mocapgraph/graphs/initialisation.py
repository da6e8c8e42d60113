"""Initial values for uncalibrated captures: the person as the calibration target.

Each view gives the body relative to its own camera (a
:class:`~mocapgraph.priors.fusion_regressor.ViewEstimate`): from the fusion regressor
(:mod:`mocapgraph.priors.fusion_regressor`) or, as a fallback that needs no network, from a PnP
of the mean body to the view's keypoints (:func:`pnp_view`). Two views seeing the
same body at the same instant then give the pose of one camera relative to the other,
``ref_T_c = ref_T_root · (c_T_root)⁻¹`` (:func:`relative_cameras`). A static camera's pose is
the robust mean of these over the frames; a moving camera's is taken per frame.

:func:`ground_frame` then finds the ground plane under the person (a plane through the lowest
foot points, or the body's mean up direction when the feet do not spread enough to tilt a
plane) and builds SmartMocap's world: origin at the ground projection of the root in the
first frame, +Z up, +Y the person's facing direction then.

Frames: ``camera_T_root (T, 4, 4)``, OpenCV camera (x right, y down, z forward), metres;
``ref_T_c`` maps camera ``c``'s frame into the reference camera's.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import cv2
import numpy as np

from mocapgraph.body.keypoint_formats import COCO17, get_format
from mocapgraph.body.labelling import SWAP_KINDS, swap_permutations
from mocapgraph.body.model import BodyModel
from mocapgraph.body.rotations import nearest_rotation, relative_angle
from mocapgraph.body.skeleton import BODY_KEYPOINT_NAMES, JOINT_NAMES, NUM_JOINTS
from mocapgraph.data_tools.geometry.epipolar import resolve_swaps
from mocapgraph.data_tools.geometry.triangulation import triangulate_points
from mocapgraph.errors import MocapgraphError
from mocapgraph.graphs.state_model import StateModel
from mocapgraph.priors.views import ViewEstimate, ViewInput, coco_keypoints

MIN_POINTS = 6
"""Confident keypoints a view needs at a frame to place the body (PnP needs at least 4; 6
keeps it off the degenerate, nearly planar configurations of a torso alone)."""
MIN_CONFIDENCE = 0.3


def neutral_pose() -> np.ndarray:
    """``(21, 3)``: standing with the arms down (the T-pose's arms lowered by 70°)."""
    pose = np.zeros((NUM_JOINTS - 1, 3))
    pose[JOINT_NAMES.index("left_shoulder") - 1] = [0.0, 0.0, -1.2]
    pose[JOINT_NAMES.index("right_shoulder") - 1] = [0.0, 0.0, 1.2]
    return pose


def _rigid(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def pnp_view(body: BodyModel, keypoints: np.ndarray, fmt: str, K: np.ndarray, shape=None, pose=None) -> ViewEstimate:
    """A body placed in one view by PnP: the mean body (arms down) by default, or the body of
    ``shape (S,)`` in ``pose (T, 21, 3)`` per frame (e.g. a regressor's articulated estimate).

    Args:
        keypoints: ``(T, F, 3)`` undistorted pixels and confidences of format ``fmt``, NaN where missing.
        K: ``(3, 3)`` intrinsics of the (undistorted) image.

    Each frame with at least :data:`MIN_POINTS` confident mapped points gets ``camera_T_root``
    from OpenCV's SQPnP (globally optimal for the model's points) polished by Levenberg-
    Marquardt; others are invalid (identity). A solution with the body behind the camera or
    implausibly far (> 200 m) is invalid too.
    """
    T = len(keypoints)
    shape = body.default_shape if shape is None else np.asarray(shape, dtype=float)
    pose = np.repeat(neutral_pose()[None], T, axis=0) if pose is None else np.asarray(pose, dtype=float)
    model = body.forward(shape, np.tile(np.eye(4), (T, 1, 1)), pose, keypoints=fmt).keypoints
    mapped = np.asarray(body.table(shape, fmt).mapped, dtype=bool)
    out = np.tile(np.eye(4), (T, 1, 1))
    valid = np.zeros(T, dtype=bool)
    Kf = np.asarray(K, dtype=float)
    for t in range(T):
        conf = np.nan_to_num(keypoints[t, :, 2], nan=0.0)
        use = mapped & (conf >= MIN_CONFIDENCE) & np.isfinite(keypoints[t, :, :2]).all(-1)
        if use.sum() < MIN_POINTS:
            continue
        obj, img = model[t, use].astype(np.float64), keypoints[t, use, :2].astype(np.float64)
        ok, rvec, tvec = cv2.solvePnP(obj, img, Kf, None, flags=cv2.SOLVEPNP_SQPNP)
        if not ok:
            continue
        rvec, tvec = cv2.solvePnPRefineLM(obj, img, Kf, None, rvec, tvec)
        depth = float(tvec[2, 0])
        if not (0.1 < depth < 200.0):
            continue
        out[t] = _rigid(cv2.Rodrigues(rvec)[0], tvec[:, 0])
        valid[t] = True
    return ViewEstimate(out, pose, np.repeat(shape[None], T, axis=0), valid)


def rotation_mean(R: np.ndarray, weights=None) -> np.ndarray:
    """``(3, 3)`` chordal L2 mean of rotations ``(N, 3, 3)`` (the projection of their weighted sum)."""
    w = np.ones(len(R)) if weights is None else np.asarray(weights, dtype=float)
    return nearest_rotation(np.einsum("n,nij->ij", w, R))


def robust_pose_mean(poses: np.ndarray) -> np.ndarray:
    """``(4, 4)``: the mean of rigid transforms ``(N, 4, 4)`` after dropping outliers.

    Translation: the coordinate-wise median, then the mean of those within 3 median absolute
    deviations (at least 5 cm); rotation: the chordal mean of the same inliers.
    """
    if len(poses) == 0:
        raise MocapgraphError("robust_pose_mean: no poses")
    t = poses[:, :3, 3]
    centre = np.median(t, axis=0)
    dist = np.linalg.norm(t - centre, axis=1)
    inlier = dist <= max(3.0 * np.median(dist), 0.05)
    R = rotation_mean(poses[inlier, :3, :3])
    R_dist = np.linalg.norm(poses[:, :3, :3] - R, axis=(1, 2))
    inlier &= R_dist <= max(3.0 * np.median(R_dist), 0.1)
    if not inlier.any():
        inlier[:] = True
    return _rigid(rotation_mean(poses[inlier, :3, :3]), t[inlier].mean(axis=0))


def robust_pose_track(poses: np.ndarray, known: np.ndarray, half_window: int, keep_within_rad: float | None = None) -> np.ndarray:
    """``(T, 4, 4)``: at each frame, :func:`robust_pose_mean` of the ``known (T,)`` poses
    ``(T, 4, 4)`` within ``half_window`` frames (the pose itself where none is known there): a
    moving camera's per-frame poses with runs of outliers shorter than the window dropped. With
    ``keep_within_rad``, a known pose whose rotation lies within that angle of its window's mean
    is kept as it is (an accurate track keeps its detail; only its outliers are replaced)."""
    out = np.array(poses, dtype=float, copy=True)
    for t in range(len(poses)):
        window = slice(max(0, t - half_window), t + half_window + 1)
        if not known[window].any():
            continue
        mean = robust_pose_mean(poses[window][known[window]])
        if not (keep_within_rad is not None and known[t] and relative_angle(mean[:3, :3], out[t, :3, :3]) <= keep_within_rad):
            out[t] = mean
    return out


def relative_cameras(views: list[ViewEstimate], moving: list[bool], reference: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Every camera's pose in the reference camera's frame, from the body both see.

    Args:
        views: per camera, its view of the body (all the same T frames).
        moving: per camera, whether it moves (a static camera's frames are averaged).
        reference: index of the reference camera.

    Returns:
        ``ref_T_c (C, T, 4, 4)`` and ``known (C, T)``: where the pose came from a frame both saw
        (a moving camera's other frames are filled from its nearest known frames, linearly in
        position and by the nearest rotation; a static camera is known everywhere once it
        shares a frame with the reference; a camera that never shares one stays unknown).
        With a moving reference, a static camera is still taken per frame relative to it.
    """
    C, T = len(views), len(views[reference].valid)
    ref = views[reference]
    out = np.tile(np.eye(4), (C, T, 1, 1))
    known = np.zeros((C, T), dtype=bool)
    known[reference] = True
    for c, view in enumerate(views):
        if c == reference:
            continue
        both = ref.valid & view.valid
        if not both.any():
            continue
        rel = ref.camera_T_root[both] @ np.linalg.inv(view.camera_T_root[both])
        if not moving[c] and not moving[reference]:
            out[c] = robust_pose_mean(rel)
            known[c] = True
            continue
        frames = np.flatnonzero(both)
        out[c, frames] = rel
        known[c, frames] = _temporal_inliers(rel[:, :3, 3])
        out[c] = _fill_gaps(out[c], known[c])
    return out, known


def _temporal_inliers(positions: np.ndarray, half_window: int = 7) -> np.ndarray:
    """``(N,)`` which per-frame positions ``(N, 3)`` lie near their neighbours' median: a PnP
    of the mean body flips now and then (a person seen from afar is nearly planar), and a
    moving camera does not jump."""
    n = len(positions)
    keep = np.ones(n, dtype=bool)
    for i in range(n):
        window = positions[max(0, i - half_window) : i + half_window + 1]
        centre = np.median(window, axis=0)
        spread = np.median(np.linalg.norm(window - centre, axis=1))
        keep[i] = np.linalg.norm(positions[i] - centre) <= max(3.0 * spread, 0.3)
    return keep


def _nearest_known(known: np.ndarray) -> np.ndarray:
    """``(T,)`` for every frame, the index of the nearest frame where ``known (T,)`` holds."""
    frames = np.flatnonzero(known)
    return frames[np.abs(np.arange(len(known))[:, None] - frames[None, :]).argmin(axis=1)]


def _fill_gaps(poses: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Frames outside ``known``: positions interpolated linearly (held at the ends), rotation of
    the nearest known frame."""
    frames = np.flatnonzero(known)
    out = poses.copy()
    t = np.arange(len(poses))
    for a in range(3):
        out[:, a, 3] = np.interp(t, frames, poses[frames, a, 3])
    out[~known, :3, :3] = poses[_nearest_known(known)[~known], :3, :3]
    return out


def moving_cameras_from_static(
    keypoints: list[np.ndarray | None], Ks: list[np.ndarray], ref_T_c: np.ndarray, known: np.ndarray, moving: list[bool]
) -> tuple[np.ndarray, np.ndarray, dict[int, np.ndarray]]:
    """Moving cameras placed again by PnP against the keypoints triangulated from the static ones.

    A PnP of the mean body is poor for a camera far from a walking person (metres off, measured
    on ``phones``); the static cameras, averaged over every frame, are good, so their
    triangulation of the person's actual keypoints gives a moving camera real 3D points to
    resect from. Each frame is resected under every left/right labelling of the moving camera's
    points (:data:`~mocapgraph.body.labelling.SWAP_KINDS`) and keeps the one that fits clearly
    best (:func:`_clearly_better`) and puts the camera nearer where the labels as detected mostly
    put it around that time: a swapped frame would place the camera on the far side. The
    labelling only places the camera. Taken over as the frames' labels it did undo a hand-held
    camera's swaps on `rich` (2 s), but on a 10 s capture without any swap it relabelled runs of
    4 to 16 frames of a body seen from the front and put the camera 0.2 to 0.5 m off: a moving
    camera's whole-body swaps are left to the robust cost, but for one kind. Where the camera
    sees the person's back (its detector's face far less confident than the body,
    :data:`BACK_VIEW_FACE_RATIO`) and the labels as detected place it in front, they are the
    detector's usual back-view swap: the whole-body swap, which places it behind, is kept, as the
    frame's labels too. A detector that swaps most of a back view's frames otherwise outvotes
    the clean ones (``phones``, seed 2 of ``bench smartmocap``: 51 of 91 frames, the carried
    phone placed 8 m off on the far side). Needs two placed static cameras; otherwise the input
    is returned.

    Args:
        keypoints: per camera ``(N, 17, 3)`` COCO-17 undistorted pixels and confidences, or None.
        Ks: per camera ``(3, 3)``; ``ref_T_c``, ``known``: from :func:`relative_cameras`.

    Returns:
        ``ref_T_c``, ``known`` and per moving camera with such frames, ``(N,)`` bool: the states
        whose labels are to be swapped as a whole (back views the detector labelled as front ones).
    """
    static = [c for c in range(len(Ks)) if not moving[c] and keypoints[c] is not None and known[c].any()]
    if len(static) < 2:
        return ref_T_c, known, {}
    out, ok = ref_T_c.copy(), known.copy()
    back_views: dict[int, np.ndarray] = {}
    P = np.stack([Ks[c] @ np.linalg.inv(ref_T_c[c, 0])[:3] for c in static])
    N = len(ref_T_c[0])
    points = np.full((N, 17, 3), np.nan)
    for t in range(N):
        obs = np.stack([keypoints[c][t] for c in static])
        conf = np.where(np.nan_to_num(obs[..., 2]) >= MIN_CONFIDENCE, obs[..., 2], 0.0)
        points[t] = triangulate_points(P, obs[..., :2], conf)
    perms = swap_permutations(COCO17)
    pose_facing = list(zip(*body_facing(points)))
    for c in range(len(Ks)):
        if not moving[c] or keypoints[c] is None:
            continue
        poses, placed = np.tile(np.eye(4), (N, 1, 1)), np.zeros(N, dtype=bool)
        codes = np.zeros(N, dtype=np.int8)  # the labelling each frame was resected under
        as_detected = np.full((N, 3), np.nan)
        mirrored: dict[int, np.ndarray] = {}  # the whole-body swap's resections
        for t in range(N):
            best = None
            for code, perm in enumerate(perms):
                found = resect(points[t], keypoints[c][t, perm], Ks[c])
                if found is not None and (best is None or _clearly_better(found, best[1:], relabel=code > 0)):
                    best = (code, *found)
                if found is not None and code == 0:
                    as_detected[t] = found[0][:3, 3]
                if found is not None and SWAP_KINDS[code] == "body":
                    mirrored[t] = found[0]
            if best is not None:
                codes[t], poses[t], placed[t] = best[0], best[1], True
        behind = _seen_from_behind(keypoints[c])
        body = SWAP_KINDS.index("body")
        for t in np.flatnonzero(behind & placed):
            # A back view whose detector put the face towards the camera: its labels, swapped as a
            # whole, fit the body as well as the camera's mirror image in front of the person.
            if t in mirrored and facing_cosine(*pose_facing[t], poses[t, :3, 3]) > 0 > facing_cosine(*pose_facing[t], mirrored[t][:3, 3]):
                codes[t], poses[t] = body, mirrored[t]
        turned = behind & (codes == body)  # the consensus below leaves back views alone
        # A relabelling must also put the camera nearer where the labels as detected mostly put
        # it around that time: a mirrored fit of a body seen from the front lands elsewhere.
        for t in np.flatnonzero((codes > 0) & ~behind):
            window = as_detected[max(0, t - CONSENSUS_HALF_WINDOW) : t + CONSENSUS_HALF_WINDOW + 1]
            window = window[np.isfinite(window).all(axis=1)]
            if len(window) and np.isfinite(as_detected[t]).all():
                centre = np.median(window, axis=0)
                if np.linalg.norm(poses[t, :3, 3] - centre) >= np.linalg.norm(as_detected[t] - centre):
                    codes[t], poses[t] = 0, resect(points[t], keypoints[c][t], Ks[c])[0]
        if placed.sum() >= 2:
            placed[placed] = _temporal_inliers(poses[placed, :3, 3])
            out[c], ok[c] = _fill_gaps(poses, placed), placed
            if (turned & placed).any():
                back_views[c] = turned & placed
    return out, ok, back_views


CONSENSUS_HALF_WINDOW = 15
"""States on each side whose as-detected resections say where a moving camera mostly is."""

FACE_POINTS = ("nose", "left_eye", "right_eye")
BACK_VIEW_FACE_RATIO = 0.8
"""A camera sees the person's back where its detector's confidence in the face (nose and eyes, a
missing point 0) is below this fraction of its confidence in the body's other points, averaged
over :data:`CONSENSUS_HALF_WINDOW` states on each side: the head hides the face from behind. On
the five 3 s ``phones`` takes of ``bench smartmocap`` the simulated detector's ratio averaged
0.66 over views from behind (facing cosine < -0.5), 1.04 from the front and 1.04-1.31 from the
sides; per camera from behind 0.57-0.77, from the front 1.02-1.07."""


def _seen_from_behind(keypoints: np.ndarray) -> np.ndarray:
    """``(N,)`` bool: the states where a camera's COCO-17 ``keypoints (N, 17, 3)`` show the
    person's back (:data:`BACK_VIEW_FACE_RATIO`); False where it saw too little to tell, and
    everywhere when it never reports a face point (a format without them says nothing)."""
    conf = np.nan_to_num(keypoints[..., 2])
    face = conf[:, [COCO17.index(name) for name in FACE_POINTS]].mean(axis=1)
    if not np.any(face > 0):
        return np.zeros(len(conf), dtype=bool)
    rest = np.where(conf[:, 5:] > 0, conf[:, 5:], np.nan)
    seen = np.isfinite(rest).any(axis=1)
    body = np.nanmedian(np.where(seen[:, None], rest, 1.0), axis=1)
    ratio = np.where(seen, face / body, np.nan)
    out = np.zeros(len(ratio), dtype=bool)
    for t in range(len(ratio)):
        window = ratio[max(0, t - CONSENSUS_HALF_WINDOW) : t + CONSENSUS_HALF_WINDOW + 1]
        window = window[np.isfinite(window)]
        out[t] = len(window) > CONSENSUS_HALF_WINDOW and window.mean() < BACK_VIEW_FACE_RATIO
    return out


def body_facing(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per state, from a body's COCO-17 ``points (N, 17, 3)`` (NaN where not triangulated): its
    hips' centre, up (hips to shoulders) and facing direction (the left-right lines of the
    shoulders and of the hips, whichever are there, crossed with up), each ``(N, 3)``; a state
    without them takes those of the nearest state that has them (all NaN if none has)."""
    at = {name: points[:, COCO17.index(name)] for name in ("left_shoulder", "right_shoulder", "left_hip", "right_hip")}
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN states are filled below
        hips = np.nanmean(np.stack([at["left_hip"], at["right_hip"]]), axis=0)
        up = np.nanmean(np.stack([at["left_shoulder"], at["right_shoulder"]]), axis=0) - hips
        left = np.nanmean(np.stack([at["left_shoulder"] - at["right_shoulder"], at["left_hip"] - at["right_hip"]]), axis=0)
    facing = np.cross(left, up)
    ok = np.isfinite(facing).all(axis=1) & np.isfinite(hips).all(axis=1) & (np.linalg.norm(facing, axis=1) > 0)
    if not ok.any():
        return hips, up, facing
    have = np.flatnonzero(ok)
    nearest = have[np.abs(np.arange(len(points))[:, None] - have[None, :]).argmin(axis=1)]
    return hips[nearest], up[nearest], facing[nearest]


def facing_cosine(hips: np.ndarray, up: np.ndarray, facing: np.ndarray, centre: np.ndarray) -> float:
    """The cosine between a body's ``facing`` direction and the direction across its ``up`` from
    its ``hips`` to a camera ``centre`` (all ``(3,)``, :func:`body_facing`): > 0 the camera is in
    front, < 0 behind."""
    to_camera = centre - hips
    to_camera = to_camera - (to_camera @ up) / (up @ up) * up
    norm = np.linalg.norm(facing) * np.linalg.norm(to_camera)
    return float(facing @ to_camera / norm) if norm > 0 else float("nan")


RELABEL_ERROR_RATIO = 0.5
"""A moving camera's frame is resected under a swapped labelling only when that labelling has
more PnP inliers, or as many at less than this fraction of the median error: seen from the front
or the back a body is nearly symmetric, and the mirrored labelling fits nearly as well."""


def _clearly_better(found: tuple, best: tuple, relabel: bool) -> bool:
    """Whether the resection ``found`` ``(pose, inliers, -error)`` beats ``best``; a relabelling
    must win clearly (:data:`RELABEL_ERROR_RATIO`)."""
    if not relabel:
        return found[1:] > best[1:]
    return found[1] > best[1] or (found[1] == best[1] and -found[2] < RELABEL_ERROR_RATIO * -best[2])


def resect(points: np.ndarray, keypoints: np.ndarray, K: np.ndarray):
    """PnP (RANSAC, SQPnP) of ``keypoints (K, 3)`` (undistorted pixels, confidence) on ``points
    (K, 3)`` in a frame ``ref``: None, or ``(ref_T_camera (4, 4), inliers, -median error px)``
    (larger is better)."""
    conf = np.nan_to_num(keypoints[:, 2])
    use = (conf >= MIN_CONFIDENCE) & np.isfinite(points).all(-1) & np.isfinite(keypoints[:, :2]).all(-1)
    if use.sum() < MIN_POINTS:
        return None
    found, rvec, tvec, inliers = cv2.solvePnPRansac(
        points[use], keypoints[use, :2].astype(np.float64), K, None, reprojectionError=12.0, flags=cv2.SOLVEPNP_SQPNP
    )  # fmt: skip
    if not found or inliers is None or len(inliers) < MIN_POINTS:
        return None
    projected, _ = cv2.projectPoints(points[use], rvec, tvec, K, None)
    error = float(np.median(np.linalg.norm(projected[:, 0] - keypoints[use, :2], axis=1)))
    return np.linalg.inv(_rigid(cv2.Rodrigues(rvec)[0], tvec[:, 0])), len(inliers), -error


def fuse_bodies(views: list[ViewEstimate], ref_T_c: np.ndarray, known: np.ndarray) -> ViewEstimate:
    """One body per frame in the reference camera's frame: the views that saw it, each moved
    into the reference frame, averaged (chordal mean of the roots' rotations, mean position;
    mean joint rotation vectors and shape). Frames no view saw are filled from their neighbours."""
    T = len(views[0].valid)
    root = np.tile(np.eye(4), (T, 1, 1))
    pose = np.zeros((T, NUM_JOINTS - 1, 3))
    shape = np.zeros((T, views[0].shape.shape[1]))
    seen = np.zeros(T, dtype=bool)
    for t in range(T):
        members = [c for c, v in enumerate(views) if v.valid[t] and known[c, t]]
        if not members:
            continue
        roots = np.stack([ref_T_c[c, t] @ views[c].camera_T_root[t] for c in members])
        root[t] = _rigid(rotation_mean(roots[:, :3, :3]), roots[:, :3, 3].mean(axis=0))
        pose[t] = np.mean([views[c].pose[t] for c in members], axis=0)
        shape[t] = np.mean([views[c].shape[t] for c in members], axis=0)
        seen[t] = True
    if not seen.any():
        raise MocapgraphError("no frame has a view that saw enough of the body to place it")
    root = _fill_gaps(root, seen)
    nearest = _nearest_known(seen)[~seen]
    pose[~seen], shape[~seen] = pose[nearest], shape[nearest]
    return ViewEstimate(root, pose, shape, seen)


def fused_shape(body: BodyModel, fused: ViewEstimate) -> np.ndarray:
    """``(S,)`` the mean of the fused body's shapes over the frames it was seen, kept just inside
    the model's bounds (a solve's first step may not start on a bound)."""
    lo, hi = body.shape_bounds.T
    return np.clip(fused.shape[fused.valid].mean(axis=0), lo + 1e-6, hi - 1e-6)


@dataclass
class GroundEstimate:
    """SmartMocap's world in the reference camera's frame, and how it was found.

    Attributes:
        ref_T_world: ``(4, 4)``: world (ground plane, Z up, origin under the first root, +Y its
            facing direction) into the reference camera's frame.
        from_feet: whether the plane's tilt came from the feet's spread (else from the body's
            mean up direction: a person standing still does not tilt a plane).
        foot_spread_m: the feet points' second-largest standard deviation in the plane, metres.
    """

    ref_T_world: np.ndarray
    from_feet: bool
    foot_spread_m: float


MIN_FOOT_SPREAD_M = 0.5
"""The feet's second-largest horizontal spread (std, metres) above which they tilt the plane."""


def ground_frame(body: BodyModel, bodies: ViewEstimate, shape) -> GroundEstimate:
    """The ground plane under the body's feet (``bodies`` in the reference camera's frame)."""
    fk = body.forward(shape, bodies.camera_T_root, bodies.pose, keypoints="body")
    feet = [BODY_KEYPOINT_NAMES.index(n) for n in ("left_big_toe", "right_big_toe", "left_heel", "right_heel", "left_ankle", "right_ankle")]
    points = fk.keypoints[:, feet]  # (T, 6, 3)
    # The body's up (+Y of the root) averaged over the frames; the camera's y points down.
    up = bodies.camera_T_root[bodies.valid][:, :3, 1].mean(axis=0)
    up /= np.linalg.norm(up)
    lowest = points[np.arange(len(points)), np.argmin(points @ up, axis=1)]  # (T, 3)
    lowest = lowest[bodies.valid]
    centred = lowest - lowest.mean(axis=0)
    evals, evecs = np.linalg.eigh(np.cov(centred.T) if len(lowest) > 3 else np.eye(3) * 1e-6)
    spread = float(np.sqrt(max(evals[1], 0.0)))
    from_feet = spread >= MIN_FOOT_SPREAD_M
    normal = evecs[:, 0] * np.sign(evecs[:, 0] @ up) if from_feet else up
    # The soles touch the ground at the lowest contacts: a low quantile, robust to a lifted foot.
    height = float(np.quantile(lowest @ normal, 0.1))
    root0 = bodies.camera_T_root[0]
    origin = root0[:3, 3] - (root0[:3, 3] @ normal - height) * normal
    facing = root0[:3, 2] - (root0[:3, 2] @ normal) * normal
    if np.linalg.norm(facing) < 1e-6:  # lying flat, facing the sky: any horizontal direction
        facing = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    y = facing / np.linalg.norm(facing)
    x = np.cross(y, normal)
    return GroundEstimate(_rigid(np.column_stack([x, y, normal]), origin), from_feet, spread)


INITIALISERS = ("pnp", "regressor")
DISAGREEMENT = 0.5
"""Median relative difference of the body's depth between the regressor and the PnP of the mean
body above which the regressor's view is replaced by the PnP: the network was trained on
synthetic views and can be far off on one unlike them, while PnP is only as wrong as the mean body."""


def coco_views(model: StateModel) -> list[np.ndarray | None]:
    """Per camera, ``(N, 17, 3)`` its COCO-17 points at every state, or None without observations."""
    views = [model.view_keypoints(c) for c in range(model.num_cameras)]
    return [None if v is None else coco_keypoints(*v) for v in views]


def view_bodies(model: StateModel, body: BodyModel, initialiser: str, variant: str = "full") -> tuple[list[ViewEstimate], str]:
    """Per camera, the body relative to it at every state, from ``initialiser``:

    - ``"pnp"``: the mean body (arms down) placed by PnP, the geometric initialiser;
    - ``"regressor"``: the fusion regressor (``variant`` of its ablation), AirPose's initialiser,
      with the PnP for a view where the two disagree by more than :data:`DISAGREEMENT` in depth,
      and for every view when the regressor's weights cannot be loaded (said in the description).

    Returns the views and a description of what was used."""
    if initialiser not in INITIALISERS:
        raise MocapgraphError(f"initialiser {initialiser!r}: choose one of {', '.join(INITIALISERS)}")
    kps = [model.view_keypoints(c) for c in range(model.num_cameras)]
    N = model.num_states
    K = model.camera_matrices()
    empty = ViewEstimate(np.tile(np.eye(4), (N, 1, 1)), np.zeros((N, NUM_JOINTS - 1, 3)), np.tile(body.default_shape, (N, 1)), np.zeros(N, bool))
    pnp = [empty if kp is None else pnp_view(body, kp[0], kp[1], K[c]) for c, kp in enumerate(kps)]
    if initialiser == "pnp":
        return pnp, "pnp"
    from mocapgraph.priors.fusion_regressor import load_default_fusion_regressor  # torch: only when asked for

    try:
        regressor = load_default_fusion_regressor(variant)
    except MocapgraphError as exc:
        return pnp, f"pnp (the fusion regressor could not be loaded: {exc})"
    seen = [c for c in range(model.num_cameras) if kps[c] is not None]
    out = list(pnp)
    fallback = []
    for c, p in zip(seen, regressor.predict([ViewInput(kps[c][0], kps[c][1], K[c]) for c in seen])):
        both = p.valid & pnp[c].valid
        depth = pnp[c].camera_T_root[both, 2, 3]
        if both.any() and np.median(np.abs(p.camera_T_root[both, 2, 3] - depth) / depth) > DISAGREEMENT:
            fallback.append(model.cameras[c].name)
        else:
            out[c] = p
    used = "regressor" if variant == "full" else f"regressor ({variant})"
    return out, used + (f"; PnP for {', '.join(fallback)} (the two disagreed)" if fallback else "")


SWAP_THRESHOLD_FRACTION = 0.01
"""RANSAC threshold of the views' essential matrices in the epipolar swap check, as a fraction of
the larger image side of a camera's principal point box (2·max(cx, cy)): 19 px at 1920 px."""


def common_format_cameras(model: StateModel, cameras: list[int]) -> tuple[list[int], str] | None:
    """Of ``cameras``, those with observations in the most common keypoint format among them,
    and that format; None when fewer than two."""
    views = {c: model.view_keypoints(c) for c in cameras}
    views = {c: v for c, v in views.items() if v is not None}
    formats = [fmt for _, fmt in views.values()]
    if len(views) < 2:
        return None
    fmt = max(set(formats), key=formats.count)
    cams = [c for c, (_, f) in views.items() if f == fmt]
    return (cams, fmt) if len(cams) >= 2 else None


def _rig_swaps(model: StateModel, cams: list[int], fmt: str, poses=None, continuity: bool = False) -> dict[int, np.ndarray]:
    """:func:`~mocapgraph.data_tools.geometry.epipolar.resolve_swaps` on cameras ``cams``' keypoints
    of format ``fmt`` at every state (with their ``poses``, ``(C, 4, 4)`` or ``(C, N, 4, 4)``,
    when given; with each camera's track from state to state if ``continuity``), as per camera
    ``(F_c,)`` codes, -1 for frames without an observation."""
    views = [model.view_keypoints(c)[0] for c in cams]
    x = np.stack([v[..., :2] for v in views])
    w = np.stack([np.nan_to_num(v[..., 2]) for v in views])
    Ks = np.stack([model.cameras[c].K for c in cams])
    names = BODY_KEYPOINT_NAMES if fmt == "body" else get_format(fmt).names
    threshold = SWAP_THRESHOLD_FRACTION * 2.0 * float(np.max(Ks[:, :2, 2]))
    labels = resolve_swaps(x, w, Ks, names, threshold_px=threshold, poses=poses, continuity=continuity).labels  # (C, N) per state
    out: dict[int, np.ndarray] = {}
    for row, c in enumerate(cams):
        codes = np.full(len(model.cameras[c].timestamps), -1, dtype=np.int8)
        frames = model.camera_frames(c)
        codes[frames] = labels[row, model.frame_state[c][frames]]
        out[c] = codes
    return out


def view_swaps(model: StateModel) -> dict[int, np.ndarray]:
    """Per static camera, ``(F_c,)`` the left/right labelling of each of its frames that fits
    the other static cameras' epipolar geometry (:func:`mocapgraph.data_tools.geometry.epipolar.resolve_swaps`
    on every state's keypoints of the views' common format): codes of
    :data:`~mocapgraph.body.labelling.SWAP_KINDS`, -1 for frames without an observation.

    Before any camera is placed, a view whose labels are swapped would place the body turned
    around and its camera with it; the essential matrices of the views' pooled keypoints need
    no body. Moving cameras (whose pairs have no single essential matrix) and cameras of
    another keypoint format are left as detected (:func:`posed_view_swaps` checks them once they
    are placed); with fewer than two static cameras nothing is checked.

    Each camera's own 2D track joins the evidence (``continuity``): two static cameras' geometry
    says that a frame's labels disagree, not whose; the jumps of the swapped camera's track where
    its run starts and ends do. Without it, on the five 3 s ``phones`` takes of ``bench
    smartmocap`` the wrong static phone was relabelled on three (seed 2: 15 frames of the clean
    phone instead of 21 of the swapped one); over the five, 37 of the 102 swapped static frames
    found and 32 clean ones relabelled without it, 97 and none with it (``rich``, 4 s, seven
    static cameras: the same frames either way)."""
    rig = common_format_cameras(model, [c for c in range(model.num_cameras) if not model.cameras[c].moving])
    return {} if rig is None else _rig_swaps(model, *rig, continuity=True)


def posed_view_swaps(model: StateModel, cameras: list[np.ndarray], continuity: bool = False) -> dict[int, np.ndarray]:
    """Per camera, ``(F_c,)`` the left/right labelling of each of its frames that fits every
    other camera's epipolar geometry at that state, the geometry taken from the placed cameras'
    poses (``cameras``: per camera ``(F_c, 4, 4)`` world_T_camera, as
    :attr:`~mocapgraph.graphs.state_model.Estimate.cameras`): codes of
    :data:`~mocapgraph.body.labelling.SWAP_KINDS`, -1 for frames without an observation.

    Unlike :func:`view_swaps` this checks the moving cameras too, each pair's geometry frame by
    frame (:func:`~mocapgraph.data_tools.geometry.epipolar.pair_from_poses`), so that where one
    static camera sees the person a swapped view is outvoted by the moving ones. The geometry
    rests on the cameras' relative rotations and the directions of their baselines, which a
    placement tens of centimetres off barely changes: on ``phones`` (10 s, seed 0), from a
    solve's poses 25-90 cm off, it found 94 % of the swapped camera-frames at 96 % precision, from
    the true poses 95 % at 97 %. Cameras of another keypoint format are left as detected.

    With ``continuity``, each camera's own 2D track from state to state joins the evidence
    (:func:`~mocapgraph.data_tools.geometry.epipolar.track_tables`): with two cameras the pair's
    geometry tells that a frame's labels disagree but not whose, the jumps of a swapped camera's
    track where its run starts and ends do."""
    rig = common_format_cameras(model, list(range(model.num_cameras)))
    if rig is None:
        return {}
    cams, fmt = rig
    poses = np.stack([_state_poses(model, c, cameras[c]) for c in cams])
    return _rig_swaps(model, cams, fmt, poses, continuity)


def _state_poses(model: StateModel, c: int, frames: np.ndarray) -> np.ndarray:
    """``(N, 4, 4)`` camera ``c``'s pose at each state: that of its frame there, else of its
    frame nearest in time (such states have no observation of ``c``)."""
    own = model.camera_frames(c)
    times = model.cameras[c].timestamps[own]
    nearest = own[np.abs(model.times[:, None] - times[None, :]).argmin(axis=1)]
    nearest[model.frame_state[c][own]] = own
    return frames[nearest]
