"""A solved state model written as a result: body states, camera tracks, per-state flags."""

from __future__ import annotations

import numpy as np

from mocapgraph.body.keypoint_formats import get_format
from mocapgraph.body.keypoint_offsets import drifted, with_offsets
from mocapgraph.body.labelling import SWAP_KINDS, then
from mocapgraph.body.model import BodyModel
from mocapgraph.body.native import forward_kinematics
from mocapgraph.body.skeleton import BODY_KEYPOINT_NAMES
from mocapgraph.data_tools.io.capture import Capture
from mocapgraph.data_tools.io.result import CameraTrack, Result
from mocapgraph.graphs.body_graph import BodyGraph
from mocapgraph.graphs.state_model import Estimate, StateModel


def estimate_result(
    pipeline: str,
    capture: Capture,
    model: StateModel,
    body: BodyModel,
    estimate: Estimate,
    world_frame: str,
    parameters: dict,
    capture_label: str = "",
    cameras: list[int] | None = None,
    all_frames: bool = False,
    swaps: dict[int, np.ndarray] | None = None,
    keypoint_offsets: dict[str, np.ndarray] | None = None,
    drift: dict[str, np.ndarray] | None = None,
) -> Result:
    """The result of a solve of ``model``.

    Args:
        cameras: indices of the cameras whose tracks to write (default: those with observations).
        all_frames: write a camera's pose at every frame of the capture (frames outside the
            states keep the estimate's initial value, e.g. a GPS/IMU prior); else only at its
            frames that belong to a body state.
        keypoint_offsets: per format, ``(K, 3)`` the definition offsets the solve used
            (:mod:`mocapgraph.body.keypoint_offsets`): the keypoints are then where the body puts
            the detector's points, the ones its reprojection was measured on.
        drift: per format, ``(N, K, 3)`` the per-state offsets on top of those the solve used
            (:func:`~mocapgraph.graphs.keypoint_fit.estimate_drift`), in the keypoints too.

    Joints and keypoints (of the first observed format; NaN for its points the body has no
    counterpart for) come from the body model's forward kinematics; ``flags`` hold each state's detection count and whether it had none.
    """
    fmt = model.formats[0]
    fk = body.forward(estimate.shape, estimate.roots, estimate.poses)
    table = body.table(estimate.shape, keypoints=fmt)
    if keypoint_offsets and fmt in keypoint_offsets:
        table = with_offsets(table, keypoint_offsets[fmt])
    posed = forward_kinematics(table, estimate.roots, estimate.poses)
    keypoints = posed.keypoints if not drift or fmt not in drift else drifted(posed.keypoints, posed.rotations, table, drift[fmt])
    keypoints[:, ~table.mapped] = np.nan  # points the body has no counterpart for
    detections = model.detections_per_state()
    result = Result(
        pipeline=pipeline, capture=capture_label or str(capture.path or capture.name), world_frame=world_frame,
        timestamps=model.times, joints=fk.joints, body_model=body.name, root=estimate.roots, pose=estimate.poses,
        shape=estimate.shape, keypoints=keypoints,
        keypoint_format=fmt, flags={"num_detections": detections, "unconstrained": detections == 0},
        log=list(estimate.log), parameters=parameters,
    )  # fmt: skip
    for c in model.observed_cameras() if cameras is None else cameras:
        cam = capture.cameras[c]
        frames = np.arange(cam.num_frames) if all_frames else model.camera_frames(c)
        if len(frames):
            codes = None if swaps is None or c not in swaps else np.maximum(swaps[c][frames], 0).astype(np.int8)
            result.cameras[cam.name] = CameraTrack(cam.timestamps[frames], estimate.cameras[c][frames], codes)
    return result


def combined_swaps(model: StateModel, before: dict[int, np.ndarray], solved: dict[int, np.ndarray]) -> dict[int, np.ndarray]:
    """Per camera, ``(F_c,)`` the labelling of each frame from the pre-pass that relabelled the
    model (``before``) followed by the solve's (``solved``, on the relabelled model), as codes of
    :data:`~mocapgraph.body.labelling.SWAP_KINDS` (:func:`~mocapgraph.body.labelling.then`)."""
    fmt = model.formats[0]
    names = BODY_KEYPOINT_NAMES if fmt == "body" else get_format(fmt).names
    out = {}
    for c, codes in solved.items():
        first = before.get(c)
        if first is None:
            out[c] = codes
            continue
        out[c] = np.array([then(names, int(a), int(b)) if b >= 0 else -1 for a, b in zip(first, codes)], dtype=np.int8)
    return out


def swap_notes(names: list[str], swaps: dict[int, np.ndarray]) -> list[str]:
    """One note per camera whose detections the solve relabelled: how many of its frames, of which kind."""
    notes = []
    for c, codes in sorted(swaps.items()):
        solved = codes >= 0
        counts = {kind: int(np.sum(codes == h)) for h, kind in enumerate(SWAP_KINDS) if h}
        total = sum(counts.values())
        if total:
            kinds = ", ".join(f"{n} {kind}" for kind, n in counts.items() if n)
            notes.append(f"camera {names[c]}: left/right labels undone in {total} of {int(solved.sum())} frames ({kinds})")
    return notes


STILL_MOTION_M = 0.15
"""A body whose :func:`joint_motion_m` is below this barely moved, and cameras placed from it
alone are poorly determined. Measured (one run each, every camera's pose self-calibrated): the
synthetic ``rich`` standing person (6 s, seed 0) 0.006 m, its static cameras 2.3 cm / 0.43° off
against 0.75 cm / 0.10° for the same rig's walk (1.19 m); on the lab clips the nearly still second
persons 0.047 m (BlazePose, cameras 4.4 cm / 2.0° off) and 0.089 m (BODY_25B: 97 cm / 43° off,
its reprojection 8.4 px looking fine), the treadmill runner 0.24 m (4.0 cm / 1.5°)."""


def joint_motion_m(joints: np.ndarray) -> float:
    """How far a body moved over a capture: the median over joints of each joint's root mean
    square distance from its own mean position, metres (``joints (T, J, 3)``, world; states with
    NaN joints left out; NaN without a finite state).

    A still person shows the cameras the same few points in every frame: the body's size and
    pose prior then carry the cameras' placement, where a moving one spreads new points through
    the volume every frame."""
    joints = np.asarray(joints, dtype=float)
    finite = np.isfinite(joints).all(axis=(1, 2))
    if not finite.any():
        return float("nan")
    kept = joints[finite]
    return float(np.median(np.sqrt(((kept - kept.mean(axis=0)) ** 2).sum(axis=-1).mean(axis=0))))


def still_body_notes(joints: np.ndarray) -> list[str]:
    """A note when the body barely moved (:func:`joint_motion_m` below :data:`STILL_MOTION_M`)."""
    motion = joint_motion_m(joints)
    if not motion < STILL_MOTION_M:
        return []
    return [
        f"the body barely moved: its joints' median RMS distance from their mean positions is {100 * motion:.1f} cm, under {100 * STILL_MOTION_M:.0f} cm; "
        "cameras placed from a still body are poorly determined, and a low reprojection does not say they are right ("
        "docs/smartmocap.md, \"A body that barely moves\")"
    ]


def focal_notes(model: StateModel, focals: dict[str, float]) -> list[str]:
    """One note per camera whose focal length the solve estimated: the estimate against the given one."""
    given = {cam.name: float(cam.K[0, 0]) for cam in model.cameras}
    return [f"camera {name}: focal length estimated {f:.0f} px (given {given[name]:.0f} px, {100 * (f / given[name] - 1):+.0f} %)" for name, f in focals.items()]


def frame_ranges(frames: np.ndarray) -> str:
    """``[3, 4, 5, 9]`` → ``"3-5, 9"``."""
    runs = np.split(frames, np.flatnonzero(np.diff(frames) > 1) + 1)
    return ", ".join(f"{r[0]}-{r[-1]}" if len(r) > 1 else f"{r[0]}" for r in runs if len(r))


def clock_offset_parameters(model: StateModel, clock_offsets: dict[int, float]) -> dict[str, float]:
    """The result's ``imu_clock_offsets_s``: camera name → its log's estimated clock offset,
    seconds (those that could be estimated)."""
    return {model.names[c]: round(float(o), 5) for c, o in clock_offsets.items() if np.isfinite(o)}


def imu_support_notes(bg: BodyGraph, clock_offsets: dict[int, float] | None = None) -> list[str]:
    """Per estimated moving camera, what its poses rest on: its views of the body (through which
    the other cameras), the constant-velocity model if used, and its IMU over which frames (in a
    reference camera's world, its gyroscope relative to that camera's); with the offset of each
    log's clock estimated (``clock_offsets``, seconds, NaN where it could not be), or the clocks
    taken as one."""
    notes = []
    model, offsets = bg.model, clock_offsets or {}
    views = "its views of the body (the other cameras through the body)" + (" and the constant-velocity model" if bg.options.camera_sigma_m_s2 is not None else "")
    reference = None if bg.imu_reference is None else model.names[bg.imu_reference]
    for c in bg.estimated:
        if not model.cameras[c].moving:
            continue
        name, frames = model.names[c], model.camera_frames(c)
        if c not in bg.imu or not bg.imu_steps[c]:
            why = "no IMU log" if c not in bg.imu else f"its IMU log covers none of its frame steps{'' if bg.reference_imu is not None or reference is None or not model.cameras[bg.imu_reference].moving else f' with the reference {reference} moving and no IMU log of its own'}"
            notes.append(f"camera {name}: {why}; its poses rest on {views}")
            continue
        missing = np.setdiff1d(frames, bg.imu_frames(c))
        what = (
            "rotation increments from the gyroscope, velocity changes from the accelerometer; its position still rests on"
            if reference is None else
            f"rotation increments relative to camera {reference} from the gyroscope{'s' if bg.reference_imu is not None else ''}; its position rests on"
        )  # fmt: skip
        offset = offsets.get(c)
        clock = "the log's clock taken as the camera's" if offset is None else (
            "the log's clock taken as the camera's (its offset could not be estimated)" if not np.isfinite(offset) else f"the log's clock {1000 * offset:+.1f} ms off the camera's (estimated)"
        )  # fmt: skip
        notes.append(
            f"camera {name}: IMU on {len(bg.imu_steps[c])} of {len(frames) - 1} frame steps: {what} {views}"
            + (f"; frames {frame_ranges(missing)} without IMU on those alone" if len(missing) else "")
            + f"; {clock}"
        )
    return notes
