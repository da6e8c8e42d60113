"""``mocapgraph eval``: a result against its capture's ground truth, with the alignment each
metric's definition calls for (``docs/metrics.md``), reported by name."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from mocapgraph.body import load_body_model
from mocapgraph.body.rotations import relative_angle
from mocapgraph.data_tools.evaluation import metrics as M
from mocapgraph.data_tools.evaluation.alignment import MIN_ALIGNMENT_CAMERAS, Similarity, align_camera_centres, ground_similarity, procrustes_trajectory, umeyama
from mocapgraph.data_tools.geometry.timing import match_times
from mocapgraph.data_tools.io.capture import Capture
from mocapgraph.data_tools.io.result import PER_FRAME_CAMERA, CameraTrack, Result
from mocapgraph.errors import MocapgraphError


@dataclass
class Evaluation:
    """Metric values (units in the names), the alignment used, and per-frame curves.

    Attributes:
        metrics: name → value, e.g. ``mpjpe_m``, ``mcpe_m``; NaN where nothing could be compared.
        alignment: how the result's world frame was brought onto the ground truth's.
        frames_compared: body frames with ground truth; ``frames_without_truth`` the others.
        per_frame: ``(T,)`` curves for reports, e.g. ``mpjpe_m``, ``timestamps``.
    """

    metrics: dict[str, float]
    alignment: str
    frames_compared: int
    frames_without_truth: int
    per_frame: dict[str, np.ndarray] = field(default_factory=dict)


def matched_frames(result: Result, capture: Capture) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per camera with ground-truth poses: which of the result's camera timestamps lie within half
    a frame of one of the camera's frames (``(N,)`` bool) and those frames' indices."""
    out = {}
    for name, track in result.cameras.items():
        if name not in capture.ground_truth.cameras:
            continue
        cam = capture.camera(name)
        cidx = match_times(cam.timestamps, track.timestamps, tolerance=0.5 / cam.frame_rate)
        out[name] = (cidx >= 0, cidx[cidx >= 0])
    return out


def matched_cameras(result: Result, capture: Capture) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per camera with ground-truth poses, its estimated and true ``world_T_camera`` ``(N, 4, 4)``
    at the result's camera timestamps that lie within half a frame of one of the camera's frames."""
    return {
        name: (result.cameras[name].world_T_camera[ok], capture.ground_truth.cameras[name][frames])
        for name, (ok, frames) in matched_frames(result, capture).items()
    }


def _alignment(result: Result, capture: Capture, gt_joints: np.ndarray, est_joints: np.ndarray) -> tuple[Similarity, str]:
    """The map from the result's world frame into the capture's, and its description."""
    identity = Similarity(1.0, np.eye(3), np.zeros(3))
    frame = result.world_frame
    if frame == "capture":
        return identity, "none (result is in the capture's world frame)"
    if frame.startswith("camera:"):
        name = frame.split(":", 1)[1]
        poses = capture.ground_truth.cameras.get(name)
        if poses is None:
            raise MocapgraphError(f"result world frame {frame!r}: the capture has no ground-truth poses for camera {name!r}")
        T = poses[0]
        return Similarity(1.0, T[:3, :3], T[:3, 3]), f"rigid: camera {name}'s true pose at its first frame"
    cameras = {n: pair for n, pair in matched_cameras(result, capture).items() if len(pair[0])}
    if not result.has_body_parameters and len(cameras) >= MIN_ALIGNMENT_CAMERAS:
        # Without a body model the joints are points a detector placed (a hip keypoint is not the
        # hip joint), while camera centres are what a self-calibration estimates.
        fit = align_camera_centres([e[:, :3, 3] for e, _ in cameras.values()], [r[:, :3, 3] for _, r in cameras.values()])
        return fit, f"similarity (Umeyama with scale over the centres of {len(cameras)} cameras; scale {fit.scale:.3f})"
    usable = np.isfinite(est_joints).all(-1)
    if usable.sum() < 3:
        return identity, "none possible (fewer than 3 estimated joints)"
    fit = umeyama(est_joints[usable], gt_joints[usable], with_scale=True)
    return fit, f"similarity (Umeyama with scale over all joints; scale {fit.scale:.3f})"


def in_capture_frame(result: Result, capture: Capture) -> Result:
    """A result whose world is a camera's frame at every instant (``camera_per_frame:<name>``,
    AirPose's), moved into the capture's world by that camera's true pose at each body
    timestamp (the joints' covariances turned with it); the cameras' tracks by the pose at their
    own frames. Anything else is returned as is.
    """
    if not result.world_frame.startswith(PER_FRAME_CAMERA):
        return result
    name = result.world_frame[len(PER_FRAME_CAMERA) :]
    truth = capture.ground_truth.cameras.get(name)
    if truth is None:
        raise MocapgraphError(f"result world frame {result.world_frame!r}: the capture has no ground-truth poses for camera {name!r}")
    stamps = capture.camera(name).timestamps

    def pose_at(times: np.ndarray) -> np.ndarray:
        # The reference camera's frame at each time: its frame nearest in time (the states are its frames).
        idx = np.clip(np.searchsorted(stamps, times), 1, len(stamps) - 1)
        idx -= (times - stamps[idx - 1]) < (stamps[idx] - times)
        return truth[idx]

    T = pose_at(result.timestamps)
    moved = replace(result, world_frame="capture", cameras=dict(result.cameras))
    moved.joints = np.einsum("tij,tkj->tki", T[:, :3, :3], result.joints) + T[:, None, :3, 3]
    if result.keypoints is not None:
        moved.keypoints = np.einsum("tij,tkj->tki", T[:, :3, :3], result.keypoints) + T[:, None, :3, 3]
    if result.root is not None:
        moved.root = T @ result.root
    if "joints" in result.covariances:  # poses' covariances live in their own frames: unchanged
        moved.covariances = {**result.covariances, "joints": np.einsum("tij,tkjl,tml->tkim", T[:, :3, :3], result.covariances["joints"], T[:, :3, :3])}
    for cam_name, track in result.cameras.items():
        moved.cameras[cam_name] = CameraTrack(track.timestamps, pose_at(track.timestamps) @ track.world_T_camera)
    return moved


def matched_truth(result: Result, gt) -> tuple[np.ndarray, np.ndarray]:
    """Which body states have ground truth within half a frame (``(T,)`` bool) and its indices."""
    step = np.median(np.diff(gt.timestamps)) if len(gt.timestamps) > 1 else 1.0
    idx = match_times(gt.timestamps, result.timestamps, tolerance=0.5 * step)
    have = idx >= 0
    if not have.any():
        raise MocapgraphError("no result timestamp lies within half a ground-truth frame of the ground truth")
    return have, idx[have]


def aligned(result: Result, capture: Capture) -> tuple[Result, str]:
    """The result moved into the capture's world frame as its metrics' definitions say (rigid
    per frame for ``camera_per_frame``, rigid for ``camera:``, nothing for ``capture``; for other
    frames a similarity over the camera centres when the result has no body parameters and at
    least :data:`~mocapgraph.data_tools.evaluation.alignment.MIN_ALIGNMENT_CAMERAS` of its cameras
    have ground truth, else over all joints), and a description of the alignment."""
    gt = capture.ground_truth
    if gt is None:
        raise MocapgraphError(f"capture {capture.name!r} has no ground truth to evaluate against")
    per_frame = result.world_frame.startswith(PER_FRAME_CAMERA)
    result = in_capture_frame(result, capture)
    have, sel = matched_truth(result, gt)
    align, how = _alignment(result, capture, gt.joints[sel], result.joints[have])
    if per_frame:
        how = "rigid per frame: the reference camera's true pose at each body timestamp"
    moved = replace(result, cameras={n: CameraTrack(t.timestamps, align.apply_pose(t.world_T_camera)) for n, t in result.cameras.items()})
    moved.covariances = moved_covariances(result.covariances, align)
    moved.joints = align.apply(result.joints)
    moved.keypoints = None if result.keypoints is None else align.apply(result.keypoints)
    moved.root = None if result.root is None else align.apply_pose(result.root)
    return moved, how


def moved_covariances(covariances: dict[str, np.ndarray], align: Similarity) -> dict[str, np.ndarray]:
    """A result's ``covariances`` (docs/result-format.md) under the world map ``align``: points'
    (``joints``) turned by ``R`` and scaled by ``scale²``; poses' (``root``, ``camera:<name>``,
    GTSAM's tangent in the pose's own frame, rotation first) keep their rotation block and scale
    the translation's by ``scale`` per axis; the shape's as it is."""
    out = dict(covariances)
    if "joints" in out:
        out["joints"] = align.scale**2 * np.einsum("ij,...jk,lk->...il", align.R, covariances["joints"], align.R)
    scale = np.r_[np.ones(3), np.full(3, align.scale)]
    for key in [k for k in out if k == "root" or k.startswith("camera:")]:
        out[key] = covariances[key] * np.outer(scale, scale)
    return out


def coverage(result: Result, capture: Capture, level: float = 0.95) -> dict[str, float]:
    """How honest the result's covariances are: the share of its joints' errors and of its camera
    centres' errors inside their ``level`` ellipsoids, after the evaluation's alignment
    (:func:`aligned`, the covariances carried through it): ``{"joints": share, "cameras": share,
    "cameras.<name>": share}``, each present where the result has those covariances. Honest
    covariances cover ``level`` of the errors."""
    return _coverage(aligned(result, capture)[0], capture, level) if result.covariances else {}


def _coverage(moved: Result, capture: Capture, level: float) -> dict[str, float]:
    """:func:`coverage` of a result already in the capture's world."""
    out: dict[str, float] = {}
    if "joints" in moved.covariances:
        have, sel = matched_truth(moved, capture.ground_truth)
        out["joints"] = float(M.covariance_coverage(moved.joints[have], capture.ground_truth.joints[sel], moved.covariances["joints"][have], level))
    inside = []
    for name, (ok, frames) in matched_frames(moved, capture).items():
        cov = moved.covariances.get(f"camera:{name}")
        if cov is None or len(cov) != len(ok) or not ok.any():
            continue
        pose = moved.cameras[name].world_T_camera[ok]
        centre_cov = np.einsum("nij,njk,nlk->nil", pose[:, :3, :3], cov[ok][:, 3:, 3:], pose[:, :3, :3])  # the tangent's translation, in the world
        share = M.covariance_coverage(pose[None, :, :3, 3], capture.ground_truth.cameras[name][frames][None, :, :3, 3], centre_cov[None], level)
        out[f"cameras.{name}"] = float(share)
        inside.append((float(share), int(ok.sum())))
    if inside:
        out["cameras"] = sum(share * n for share, n in inside) / sum(n for _, n in inside)
    return out


def _static_rig(static_est: list[np.ndarray], static_ref: list[np.ndarray]) -> dict[str, float]:
    """``static_mcpe_procrustes_m`` / ``static_mcoe_procrustes_rad``: the static cameras as one
    rig after its own Procrustes (one pose per camera; the rotation from their orientations, the
    scale and translation from their centres, ``procrustes_trajectory``). The rig's geometry,
    free of the result's alignment: fitted to the joints of a person who barely moves (3 s of
    ``phones``, three of the bench's takes: 9-17 cm of horizontal spread), that alignment's
    rotation is a degree or two off, which alone puts a camera 8 m away 15-25 cm off. Nothing
    with fewer than two static cameras with a frame. Arrays ``(N_c, 4, 4)`` world_T_camera per
    static camera, as the result's alignment left them.

    That Procrustes, applied after the result's alignment, is what the alignment got wrong about
    the static cameras' frame: ``static_rig_turn_rad`` its angle (the body's frame turned against
    the cameras') and ``static_rig_scale`` its scale (above 1: the body larger than the cameras'
    distances say, the cameras too near the person after the alignment)."""
    pairs = [(e[0], r[0]) for e, r in zip(static_est, static_ref) if len(e)]
    if len(pairs) < 2:
        return {}
    est, ref = np.stack([e for e, _ in pairs]), np.stack([r for _, r in pairs])
    try:
        fit = procrustes_trajectory(est[:, :3, 3], ref[:, :3, 3], est[:, :3, :3], ref[:, :3, :3], rotation_from="orientations")
    except MocapgraphError:
        return {}
    moved = fit.apply_pose(est)
    return {
        "static_mcpe_procrustes_m": float(M.mcpe_m(moved, ref)), "static_mcoe_procrustes_rad": float(M.mcoe_rad(moved, ref)),
        "static_rig_turn_rad": float(relative_angle(fit.R, np.eye(3))), "static_rig_scale": float(fit.scale),
    }  # fmt: skip


def _static_views(raw: Result, capture: Capture) -> dict[str, float]:
    """The body as each static camera sees it, estimate against truth, with no alignment at all:
    every value is unchanged by any similarity of the result's world (``docs/metrics.md``, "The
    static cameras' views"). Per static camera with a frame, over the states with ground truth
    (the joints' centroid over all of them, the body's size the joints' RMS distance from each
    state's centroid), the means over those cameras:

    - ``static_view_bearing_rad``: the angle between the directions, in the camera's frame, to the
      joints' centroid: what the camera's image fixes (its rotation against the person);
    - ``static_view_distance_ratio``: the camera's distance to the centroid in body sizes, the
      estimate's over the truth's (above 1: the camera too far for the body's size);

    and ``static_pair_turn_rad``, the mean over pairs of static cameras of the angle of their
    relative rotation's error. The body's orientation against each camera, the third part, is
    ``static_mcoe_rad`` itself: the joints' similarity's rotation does not depend on its scale,
    so the camera's orientation error after it is the joints' turn seen from the camera. A result
    whose world is a camera's frame per instant gets none."""
    if raw.world_frame.startswith(PER_FRAME_CAMERA):
        return {}
    gt = capture.ground_truth
    have, sel = matched_truth(raw, gt)
    usable = np.isfinite(raw.joints[have]).all(axis=(-1, -2))
    if usable.sum() < 1:
        return {}
    est_j, ref_j = raw.joints[have][usable], gt.joints[sel][usable]
    poses = {n: (e[0], r[0]) for n, (e, r) in matched_cameras(raw, capture).items() if len(e) and not capture.camera(n).moving}
    if not poses:
        return {}

    def size(joints: np.ndarray) -> float:
        return float(np.sqrt(np.mean(np.sum((joints - joints.mean(axis=1, keepdims=True)) ** 2, axis=-1))))

    sizes = size(est_j), size(ref_j)
    bearing, ratio = [], []
    for e, r in poses.values():
        seen = [(j.reshape(-1, 3) - T[:3, 3]) @ T[:3, :3] for j, T in ((est_j, e), (ref_j, r))]  # camera_T_world · joints
        centroids = [s.mean(axis=0) for s in seen]
        bearing.append(float(np.arctan2(np.linalg.norm(np.cross(*centroids)), centroids[0] @ centroids[1])))  # exact at small angles, where arccos is not
        ratio.append(float((np.linalg.norm(centroids[0]) / sizes[0]) / (np.linalg.norm(centroids[1]) / sizes[1])))
    out = {"static_view_bearing_rad": float(np.mean(bearing)), "static_view_distance_ratio": float(np.mean(ratio))}
    pairs = [(a, b) for k, a in enumerate(poses.values()) for b in list(poses.values())[k + 1 :]]
    if pairs:
        out["static_pair_turn_rad"] = float(np.mean([relative_angle(a[0][:3, :3].T @ b[0][:3, :3], a[1][:3, :3].T @ b[1][:3, :3]) for a, b in pairs]))
    return out


def _static_alignments(raw: Result, capture: Capture) -> dict[str, float]:
    """The static cameras' error under alignments other than the evaluation's similarity over
    the joints, and how well the joints fix that one's rotation (``docs/metrics.md``,
    "Which alignment for the static cameras"), for a result in a world of its own
    (``ground_plane``) with body parameters and two or more static cameras with ground truth:

    - ``static_mcpe_cameras_m``: after the similarity over every camera's centres, each camera
      weighing the same (:func:`align_camera_centres`, the self-calibrations' convention; needs
      three cameras);
    - ``static_mcpe_scene_m``: after the similarity over the joints and the static cameras'
      centres, all joints together weighing as much as one camera: the rotation then rests on the
      cameras metres apart, but it is fitted to the cameras it scores;
    - ``static_mcpe_ground_m``: after the similarity that keeps the result's ground and up
      (:func:`ground_similarity` over the joints), when the capture's world is Z up on the ground:
      the result's tilt counts;
    - ``alignment_halves_rad``: the angle between the joints' similarities over the first and the
      second half of the states; ``static_alignment_noise_m``: half of it (the full fit's share
      if the halves' errors were independent) times the static cameras' mean distance from the
      joints' centroid, the error the alignment alone may put on them.
    """
    if raw.world_frame != "ground_plane" or not raw.has_body_parameters:
        return {}
    gt = capture.ground_truth
    have, sel = matched_truth(raw, gt)
    est_j, ref_j = raw.joints[have], gt.joints[sel]
    usable = np.isfinite(est_j).all(-1)
    cameras = {n: (e[:, :3, 3], r[:, :3, 3]) for n, (e, r) in matched_cameras(raw, capture).items() if len(e)}
    static = [n for n in cameras if not capture.camera(n).moving]
    if len(static) < 2 or usable.sum() < 6:
        return {}

    def static_error(fit: Similarity) -> float:
        return float(np.mean(np.concatenate([np.linalg.norm(fit.apply(cameras[n][0]) - cameras[n][1], axis=1) for n in static])))

    joints = (est_j[usable], ref_j[usable])
    out: dict[str, float] = {}
    if len(cameras) >= MIN_ALIGNMENT_CAMERAS:
        out["static_mcpe_cameras_m"] = static_error(align_camera_centres([e for e, _ in cameras.values()], [r for _, r in cameras.values()]))
    weights = np.concatenate([np.full(len(joints[0]), 1.0 / len(joints[0]))] + [np.full(len(cameras[n][0]), 1.0 / len(cameras[n][0])) for n in static])
    scene = umeyama(np.concatenate([joints[0]] + [cameras[n][0] for n in static]), np.concatenate([joints[1]] + [cameras[n][1] for n in static]), True, weights)
    out["static_mcpe_scene_m"] = static_error(scene)
    if "z up" in capture.world_frame.lower() and "on the ground" in capture.world_frame.lower():
        out["static_mcpe_ground_m"] = static_error(ground_similarity(*joints))
    half = len(est_j) // 2
    try:
        first, second = (umeyama(est_j[part][usable[part]], ref_j[part][usable[part]], True) for part in (slice(0, half), slice(half, None)))
    except MocapgraphError:  # a half too short or degenerate: no spread to report
        return out
    out["alignment_halves_rad"] = float(relative_angle(first.R, second.R))
    centroid = joints[1].mean(axis=0)
    out["static_alignment_noise_m"] = 0.5 * out["alignment_halves_rad"] * float(np.mean([np.linalg.norm(cameras[n][1].mean(0) - centroid) for n in static]))
    return out


def evaluate(result: Result, capture: Capture) -> Evaluation:
    """All metrics that the result's contents allow, against the capture's ground truth; with
    covariances, the share of errors inside their 95 % ellipsoids (``coverage95_*``, :func:`coverage`)."""
    raw = result
    result, how = aligned(result, capture)
    gt = capture.ground_truth
    have, sel = matched_truth(result, gt)
    ref_joints = gt.joints[sel]
    est_joints = result.joints[have]
    out: dict[str, float] = {}
    per_frame: dict[str, np.ndarray] = {"timestamps": result.timestamps[have]}

    if np.isfinite(est_joints).any():
        mpjpe = M.mpjpe_m(est_joints, ref_joints)
        out["mpjpe_m"] = float(mpjpe)
        per_frame["mpjpe_m"] = mpjpe.per_item
        out["pa_mpjpe_m"] = float(M.pa_mpjpe_m(est_joints, ref_joints))
        fps = 1.0 / np.median(np.diff(result.timestamps)) if len(result.timestamps) > 3 else None
        if fps is not None and len(est_joints) > 3:
            out["acceleration_error_m_s2"] = float(M.acceleration_error_m_s2(est_joints, ref_joints, fps))

    if result.has_body_parameters:
        est_root = result.root[have]
        ref_root = gt.root[sel]
        out["ra_mpjpe_m"] = float(M.ra_mpjpe_m(est_joints, ref_joints, est_root, ref_root))
        out["mpe_m"] = float(M.mpe_m(est_root[:, :3, 3], ref_root[:, :3, 3]))
        out["moe_rad"] = float(M.moe_rad(est_root[:, :3, :3], ref_root[:, :3, :3]))
        out["joint_angle_error_rad"] = float(M.joint_angle_error_rad(result.pose[have], gt.pose[sel]))
        if result.body_model == gt.body_model == "anny":
            body = load_body_model("anny")
            out["mpvpe_m"] = float(M.mpvpe_m(body.rest_joints(result.shape), body.rest_joints(gt.shape)))

    if result.keypoints is not None and gt.body_model == "anny":
        body = load_body_model("anny")
        ref_kp = body.forward(gt.shape, gt.root[sel], gt.pose[sel], keypoints=result.keypoint_format).keypoints
        mapped = body.table(gt.shape, result.keypoint_format).mapped
        est_kp = result.keypoints[have][:, mapped]
        out["mpjpe_keypoints_m"] = float(M.mpjpe_m(est_kp, ref_kp[:, mapped]))
        per_frame["mpjpe_keypoints_m"] = M.mpjpe_m(est_kp, ref_kp[:, mapped]).per_item

    est_cams, ref_cams, moving_pos, moving_ref, static_est, static_ref, moving_est = [], [], [], [], [], [], []
    for name, (est, ref) in matched_cameras(result, capture).items():
        cam = capture.camera(name)
        est_cams.append(est)
        ref_cams.append(ref)
        out[f"mcpe_m.{name}"] = float(M.mcpe_m(est, ref))
        if not cam.moving:
            static_est.append(est)
            static_ref.append(ref)
        if cam.moving:
            moving_est.append((est, ref))
        if cam.moving and len(est) >= 3:
            # the rotation from the orientations: a carried phone's few centimetres of track fix it
            # far worse than its frames do (alignment.procrustes_trajectory)
            fit = procrustes_trajectory(est[:, :3, 3], ref[:, :3, 3], est[:, :3, :3], ref[:, :3, :3], rotation_from="orientations")
            moving_pos.append(fit.apply_pose(est))
            moving_ref.append(ref)
    if est_cams:
        out["mcpe_m"] = float(M.mcpe_m(np.concatenate(est_cams), np.concatenate(ref_cams)))
        out["mcoe_rad"] = float(M.mcoe_rad(np.concatenate(est_cams), np.concatenate(ref_cams)))
    if static_est:
        out["static_mcpe_m"] = float(M.mcpe_m(np.concatenate(static_est), np.concatenate(static_ref)))
        out["static_mcoe_rad"] = float(M.mcoe_rad(np.concatenate(static_est), np.concatenate(static_ref)))
        out.update(_static_rig(static_est, static_ref))
        out.update(_static_alignments(raw, capture))
        out.update(_static_views(raw, capture))
    if moving_est:
        # after the result's alignment only (the ground-plane frame's similarity), not per camera
        out["moving_mcpe_m"] = float(M.mcpe_m(np.concatenate([e for e, _ in moving_est]), np.concatenate([r for _, r in moving_est])))
        out["moving_mcoe_rad"] = float(M.mcoe_rad(np.concatenate([e for e, _ in moving_est]), np.concatenate([r for _, r in moving_est])))
    if moving_pos:
        out["moving_mcpe_procrustes_m"] = float(M.mcpe_m(np.concatenate(moving_pos), np.concatenate(moving_ref)))
        out["moving_mcoe_procrustes_rad"] = float(M.mcoe_rad(np.concatenate(moving_pos), np.concatenate(moving_ref)))
    out.update({f"coverage95_{key}": share for key, share in _coverage(result, capture, 0.95).items()})
    return Evaluation(out, how, int(have.sum()), int((~have).sum()), per_frame)
