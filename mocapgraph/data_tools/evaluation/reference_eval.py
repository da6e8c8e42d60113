"""Camera tracks scored against a reference reconstruction (``eval --reference colmap``), as
SmartMocap scored its moving cameras against COLMAP.

A reference lives in its own world (COLMAP's: arbitrary origin, orientation and scale), so every
comparison first aligns one side onto the other by a similarity, then measures MCPE/MCOE:

- a moving camera: SmartMocap's normalised Procrustes of that camera's track alone, its rotation
  from the orientations (:func:`~mocapgraph.data_tools.evaluation.alignment.procrustes_trajectory`,
  as ``eval``'s own-Procrustes metrics);
- a static camera: its track has no spread to fit a similarity to, so it is compared after one
  similarity over the centres of all cameras (Umeyama, every camera weighing the same,
  :func:`~mocapgraph.data_tools.evaluation.alignment.align_camera_centres`), which needs
  :data:`~mocapgraph.data_tools.evaluation.alignment.MIN_ALIGNMENT_CAMERAS` cameras in both; with
  fewer it is reported as not evaluable.

Errors are in the units of the side that stays fixed: the reference is mapped onto the result
(metres when the result is metric) or onto the truth; a result is mapped onto the truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapgraph.data_tools.evaluation import metrics as M
from mocapgraph.data_tools.evaluation.alignment import MIN_ALIGNMENT_CAMERAS, align_camera_centres, procrustes_trajectory
from mocapgraph.data_tools.geometry.timing import match_times
from mocapgraph.errors import MocapgraphError

MIN_TRACK_FRAMES = 3
"""A moving camera needs this many frames in both tracks for its own Procrustes."""


@dataclass
class CameraScore:
    """One camera's errors after alignment; ``mcpe_m`` / ``mcoe_deg`` NaN when not evaluable.

    ``alignment`` names what was fitted (``procrustes``, ``similarity over N cameras``) or why
    nothing could be (``not evaluable: …``); ``frames`` how many frames were compared.
    """

    moving: bool
    frames: int
    mcpe_m: float
    mcoe_deg: float
    alignment: str


def tracks_at_frames(result, capture) -> dict[str, np.ndarray]:
    """Per camera of ``result``, ``(T_c, 4, 4)`` its ``world_T_camera`` at each of the camera's
    frames (the result's pose within half a frame, NaN where none); a static camera's single pose
    holds at every frame."""
    out = {}
    for name, track in result.cameras.items():
        cam = capture.camera(name)
        poses = np.asarray(track.world_T_camera, dtype=float)
        if not cam.moving and len(poses) == 1:
            out[name] = np.repeat(poses, cam.num_frames, axis=0)
            continue
        idx = match_times(np.asarray(track.timestamps, dtype=float), cam.timestamps, tolerance=0.5 / cam.frame_rate)
        out[name] = np.where((idx >= 0)[:, None, None], poses[np.maximum(idx, 0)], np.nan)
    return out


def _finite(poses: np.ndarray) -> np.ndarray:
    return np.all(np.isfinite(poses), axis=(1, 2))


def compare_tracks(
    moved: dict[str, np.ndarray], fixed: dict[str, np.ndarray], moving: dict[str, bool], groups: dict[str, int] | None = None
) -> dict[str, CameraScore]:
    """Align ``moved`` onto ``fixed`` camera by camera (see the module docstring) and score it.

    Args:
        moved: per camera, ``(T_c, 4, 4)`` world_T_camera at the camera's frames, NaN = none; any
            world frame and scale.
        fixed: per camera, the same frames in the frame whose units the errors are in.
        moving: per camera, whether it moves.
        groups: per camera, which world frame of ``moved`` it is in (COLMAP's separate models);
            the similarity for static cameras is fitted within a group. Default: one frame.

    Returns:
        Per camera present in both, its :class:`CameraScore`.
    """
    names = [n for n in moved if n in fixed]
    both = {n: _finite(moved[n]) & _finite(fixed[n]) for n in names}
    groups = groups or {}
    group_of = {n: groups.get(n, 0) for n in names}
    overall, members = {}, {}
    for g in set(group_of.values()):
        usable = [n for n in names if group_of[n] == g and both[n].any()]
        members[g] = len(usable)
        if len(usable) >= MIN_ALIGNMENT_CAMERAS:
            try:
                overall[g] = align_camera_centres([moved[n][both[n], :3, 3] for n in usable], [fixed[n][both[n], :3, 3] for n in usable])
            except MocapgraphError:
                pass  # collinear centres: static cameras then stay not evaluable
    out = {}
    for n in names:
        a, b = moved[n][both[n]], fixed[n][both[n]]
        if not len(a):
            out[n] = CameraScore(moving[n], 0, np.nan, np.nan, "not evaluable: no frame has a pose in both")
            continue
        if moving[n] and len(a) >= MIN_TRACK_FRAMES:
            try:
                fit = procrustes_trajectory(a[:, :3, 3], b[:, :3, 3], a[:, :3, :3], b[:, :3, :3], rotation_from="orientations")
                how = "procrustes"
            except MocapgraphError as exc:
                out[n] = CameraScore(True, len(a), np.nan, np.nan, f"not evaluable: {exc}")
                continue
        elif group_of[n] in overall:
            fit, how = overall[group_of[n]], f"similarity over {members[group_of[n]]} cameras"
        else:
            why = (f"{len(a)} frames in both" if moving[n] else
                   f"static, and only {members[group_of[n]]} cameras of its world in both (a similarity needs {MIN_ALIGNMENT_CAMERAS})")  # fmt: skip
            out[n] = CameraScore(moving[n], len(a), np.nan, np.nan, f"not evaluable: {why}")
            continue
        aligned = fit.apply_pose(a)
        out[n] = CameraScore(moving[n], len(a), float(M.mcpe_m(aligned, b)), float(np.degrees(float(M.mcoe_rad(aligned, b)))), how)
    return out


def reference_report(result, capture, reference) -> dict:
    """``eval --reference``: the result against the reference, and on a capture with true camera
    poses the reference against the truth and the result against the truth, camera by camera.

    Returns ``{"result_vs_reference": {camera: CameraScore}, "reference_vs_truth": …,
    "result_vs_truth": …}`` (the last two only with ground-truth cameras) and the reference's
    registration statistics under ``"reference_stats"``.
    """
    est = tracks_at_frames(result, capture)
    moving = {c.name: c.moving for c in capture.cameras}
    common = {n: reference.cameras[n] for n in est if n in reference.cameras}
    if not common:
        raise MocapgraphError(
            f"the result's cameras ({', '.join(est) or 'none'}) and the reference's ({', '.join(reference.cameras)}) have none in common"
        )
    groups = reference.groups()
    report = {"result_vs_reference": compare_tracks(common, {n: est[n] for n in common}, moving, groups)}
    gt = capture.ground_truth
    if gt is not None and gt.cameras:
        truth = {n: gt.cameras[n] for n in reference.cameras if n in gt.cameras}
        report["reference_vs_truth"] = compare_tracks({n: reference.cameras[n] for n in truth}, truth, moving, groups)
        # On the frames the reference has, so that the two scores of the result differ only by
        # what they are compared with.
        on_reference = {n: np.where(_finite(reference.cameras[n])[:, None, None], est[n], np.nan) for n in common if n in truth}
        report["result_vs_truth"] = compare_tracks(on_reference, truth, moving)
    report["reference_stats"] = reference.stats
    return report


def flat_metrics(report: dict) -> dict[str, float | str]:
    """``report`` as one flat mapping, e.g. ``result_vs_reference.mcpe_m.phone_walk1``."""
    out: dict[str, float | str] = {}
    for section, scores in report.items():
        if section == "reference_stats":
            out["reference.registration_rate"] = float(scores.get("registration_rate", np.nan))
            out["reference.mean_reprojection_error_px"] = float(scores.get("mean_reprojection_error_px", np.nan))
            continue
        for name, s in scores.items():
            out[f"{section}.mcpe_m.{name}"] = s.mcpe_m
            out[f"{section}.mcoe_deg.{name}"] = s.mcoe_deg
            out[f"{section}.alignment.{name}"] = s.alignment
        for kind, want in (("moving", True), ("static", False)):
            picked = [s for s in scores.values() if s.moving == want and np.isfinite(s.mcpe_m)]
            if picked:
                weights = np.array([s.frames for s in picked], dtype=float)
                out[f"{section}.{kind}_mcpe_m"] = float(np.average([s.mcpe_m for s in picked], weights=weights))
                out[f"{section}.{kind}_mcoe_deg"] = float(np.average([s.mcoe_deg for s in picked], weights=weights))
    return out
