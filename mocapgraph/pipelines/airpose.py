"""``mocapgraph run airpose``: body and cameras relative to camera 1, from uncalibrated moving
cameras (AirPose and AirPose+, Saini et al., IJCV 2022).

- **AirPose** (the initialiser): per frame, each view's body relative to its camera from the
  fusion regressor (or PnP of the mean body); camera ``c`` relative to camera 1 from the body
  both see, ``1_T_c = 1_T_root · (c_T_root)⁻¹``.
- **AirPose+** (``refine``): a sequence bundle adjustment over every frame at once: one
  articulated pose and one root per frame seen by all views, one shape for the sequence, every
  other camera's pose relative to camera 1 per frame, temporal smoothness of body and cameras,
  the pose prior. Frames whose keypoints' total confidence (summed over the views) is below
  ``min_confidence`` are left out (their joints are NaN, flagged ``left_out``).

The world is camera 1's frame at every instant (``world_frame = "camera_per_frame:<camera 1>"``):
camera 1 is the identity at every frame and holds the gauge; the scale comes from the body
model's size alone.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import gtsam
import numpy as np

from mocapgraph.body import load_body_model
from mocapgraph.data_tools.io.capture import Capture
from mocapgraph.data_tools.io.result import PER_FRAME_CAMERA, Result, options_parameters
from mocapgraph.errors import MocapgraphError
from mocapgraph.graphs.body_graph import BodyGraph, GraphOptions
from mocapgraph.graphs.camera_imu import check_max_offset, estimated_clock_offsets, start_from_gyroscopes
from mocapgraph.graphs.initialisation import (
    INITIALISERS,
    fuse_bodies,
    fused_shape,
    posed_view_swaps,
    relative_cameras,
    robust_pose_track,
    view_bodies,
    view_swaps,
)
from mocapgraph.graphs.solver import held, solve_staged
from mocapgraph.graphs.state_model import Estimate, StateModel
from mocapgraph.pipelines.observations import camera_imus, capture_state_model
from mocapgraph.pipelines.results import clock_offset_parameters, combined_swaps, estimate_result, focal_notes, imu_support_notes, swap_notes

log = logging.getLogger(__name__)


KEEP_SOLVED_RAD = np.radians(10.0)
"""AirPose+'s camera poses within this angle of their window's robust mean are kept as solved
by the swap check (5° off the truth in median on airpose); a camera taken round the person to
explain a swap is replaced by the window's mean."""


@dataclass
class AirposeOptions:
    """Parameters of AirPose / AirPose+ (units in the names)."""

    # The fusion regressor (AirPose's own initialiser). Before the two cameras' swaps were undone
    # the mean body's PnP started AirPose+ better; since, from the regressor it ends nearer on
    # 10 s airpose captures, seeds 0-5 (MPE 0.49/0.53/0.53/0.31/0.68/0.37 m against
    # 0.80/0.69/0.69/1.09/0.56/0.48 from PnP; camera 2 0.57/1.13/0.94/0.79/0.77/1.01 m against
    # 1.03/1.14/1.34/3.02/0.92/1.05; seeds 3-5 measured after the choice was made on 0-2).
    initialiser: str = "regressor"
    regressor_variant: str = "full"  # the regressor's ablation variants: "no_exchange", "no_crop"
    refine: bool = True  # AirPose+ (False: the initialiser's estimate alone)
    min_confidence: float = 3.0  # summed keypoint confidence over the views a frame needs
    iterations: int = 30
    # Two moving cameras' labels checked against their epipolar geometry, each camera's own 2D
    # track telling which of the two swapped (graphs.initialisation.posed_view_swaps with
    # continuity): first on the views' relative cameras (robustly smoothed over
    # `swap_window_frames` each side), the views made again on the new labels; then on AirPose+'s
    # cameras, the sequence solved again on them (with graph.swaps only).
    posed_swaps: bool = True
    swap_window_frames: int = 45
    swap_rounds: int = 3
    detectors: tuple[str, ...] | None = None
    covariances: bool = True
    # Moving cameras' IMU logs (with the capture's mount): each camera's gyroscope on its rotation
    # relative to camera 1 (and camera 1's own when it moves), biases as states
    # (BodyGraph's imu_reference; the accelerometer is not used: camera 1's frame has no known
    # gravity direction).
    imu: bool = True
    # The largest offset of a log's clock from its camera's searched for after the first
    # AirPose+ solve, on its body, as SmartMocap does (graphs.camera_imu.estimated_clock_offsets;
    # with camera 1 static only: the track's constant-velocity model needs a world that does not
    # turn); None: the clocks taken as one.
    imu_max_offset_s: float | None = 0.05
    graph: GraphOptions = field(default_factory=GraphOptions)

    def check(self) -> None:
        self.graph.check()
        if self.initialiser not in INITIALISERS:
            raise MocapgraphError(f"initialiser {self.initialiser!r}: choose one of {', '.join(INITIALISERS)}")
        if not (np.isfinite(self.min_confidence) and self.min_confidence >= 0):
            raise MocapgraphError(f"min_confidence: a finite number >= 0, got {self.min_confidence!r}")
        if not (isinstance(self.swap_window_frames, int) and self.swap_window_frames >= 1):
            raise MocapgraphError(f"swap_window_frames: an integer >= 1, got {self.swap_window_frames!r}")
        if not (isinstance(self.swap_rounds, int) and self.swap_rounds >= 0):
            raise MocapgraphError(f"swap_rounds: an integer >= 0, got {self.swap_rounds!r}")
        check_max_offset(self.imu_max_offset_s)


def run_airpose(capture: Capture, options: AirposeOptions | None = None, capture_label: str = "") -> Result:
    """Run AirPose (and AirPose+ when ``options.refine``) on a loaded capture; nothing written."""
    options = options or AirposeOptions()
    options.check()
    t_start = time.perf_counter()
    body = load_body_model()
    full = capture_state_model(capture, "closest", detectors=options.detectors, reference=0)
    if 0 not in full.observed_cameras():
        raise MocapgraphError(f"capture {capture.name!r}: camera 1 ({full.names[0]}) has no detections; AirPose's world is camera 1's frame")
    keep = full.keypoint_weight() >= options.min_confidence
    if keep.sum() < 2:
        raise MocapgraphError(
            f"capture {capture.name!r}: {int(keep.sum())} frames have a total keypoint confidence >= {options.min_confidence}; need 2"
        )
    # Relative to camera 1 every camera moves, unless both are static.
    reference_moves = full.cameras[0].moving
    model = full.select(np.flatnonzero(keep))
    before = view_swaps(model) if options.graph.swaps else {}  # on the cameras as captured: static pairs
    detected = model.with_moving([cam.moving or reference_moves for cam in full.cameras])
    model = detected.relabelled(before)
    notes = list(capture.notes)
    if (~keep).any():
        notes.append(f"{int((~keep).sum())} of {len(keep)} frames left out: total keypoint confidence below {options.min_confidence}")
    views, used = view_bodies(model, body, options.initialiser, options.regressor_variant)
    ref_T_c, known = relative_cameras(views, [cam.moving for cam in model.cameras], 0)
    if options.refine and options.graph.swaps and options.posed_swaps:
        # A swapped view turns its PnP body round, and the camera with it, for the run's frames:
        # the window's robust mean drops them.
        before = _checked(detected, before, [model.frames_from_states(c, ref_T_c[c]) for c in range(model.num_cameras)], options.swap_window_frames, None)
        model = detected.relabelled(before)
        views, used = view_bodies(model, body, options.initialiser, options.regressor_variant)
        ref_T_c, known = relative_cameras(views, [cam.moving for cam in model.cameras], 0)
    notes.append(f"initialised from the {used}")
    placed = [bool(known[c].any()) for c in range(model.num_cameras)]
    for c in range(1, model.num_cameras):
        if not placed[c]:
            notes.append(f"camera {model.names[c]}: never saw the person together with camera 1; not estimated")
    if sum(placed) == 1:
        notes.append("camera 1 alone: depth along its rays rests on the body's size and the priors; expect large covariances along them")
    notes.append("absolute scale: from the body model's size (shape prior) alone; the shape's covariance carries it")
    model, detected = model.only(placed), detected.only(placed)
    fused = fuse_bodies(views, ref_T_c, known)
    cameras = [model.frames_from_states(c, ref_T_c[c]) for c in range(model.num_cameras)]
    estimate = Estimate(fused.camera_T_root, fused.pose, fused_shape(body, fused), cameras)
    imu, imu_skipped = camera_imus(capture) if options.imu else ({}, [])
    notes += imu_skipped
    if not reference_moves:
        # camera 1's frame does not turn: the gyroscopes' tracks replace the views' noisy rotations
        start_from_gyroscopes(imu, model, estimate.cameras, options.graph.imu_noise)
    for note in notes:
        log.info("airpose: %s", note)
    bg = BodyGraph(model, body, options.graph, fixed_cameras={0: np.tile(np.eye(4), (len(capture.cameras[0].timestamps), 1, 1))}, imu=imu, imu_reference=0)
    graph = values = swaps = None
    clock_offsets: dict[int, float] = {}
    if options.refine:
        log.info("airpose: AirPose+, %d frames, %d camera poses", model.num_states, len(bg.camera_vars()))
        graph, values, estimate = _bundle_adjust(bg, estimate, options.iterations, "AirPose+")
        if imu and options.imu_max_offset_s is not None and not reference_moves:
            # each log's clock against its camera's, on this solve's body; then solved again on
            # the shifted logs (docs/phone-imu.md, "AirPose+")
            imu, clock_offsets = estimated_clock_offsets(body, model, estimate, imu, options.imu_max_offset_s, options.graph.imu_noise)
            bg = BodyGraph(model, body, options.graph, fixed_cameras=bg.fixed_cameras, imu=imu, imu_reference=0)
            graph, values, estimate = _bundle_adjust(bg, estimate, options.iterations, "AirPose+ (IMU clocks)")
        for _ in range(options.swap_rounds if options.graph.swaps and options.posed_swaps else 0):
            # The solve explains a run it did not relabel by taking the other camera round the
            # person; its cameras elsewhere check the labels again, and the sequence is solved
            # again on them, until they stay.
            checked = _checked(detected, before, estimate.cameras, options.swap_window_frames, KEEP_SOLVED_RAD)
            if all(np.array_equal(np.maximum(codes, 0), np.maximum(before.get(c, codes * 0), 0)) for c, codes in checked.items()):
                break
            before, model = checked, detected.relabelled(checked)
            bg = BodyGraph(model, body, options.graph, fixed_cameras=bg.fixed_cameras, imu=imu, imu_reference=0)
            # held as checked: the solve's own choice would put the runs back
            graph, values, estimate = _bundle_adjust(bg, estimate, options.iterations, "AirPose+ (relabelled)", relabel=False)
        swaps = combined_swaps(model, before, bg.relabelled(estimate))
        notes += swap_notes(model.names, swaps) + focal_notes(model, bg.focal_lengths(estimate)) + imu_support_notes(bg, clock_offsets)
    seconds = time.perf_counter() - t_start
    placed_cameras = [c for c in range(model.num_cameras) if placed[c]]
    result = estimate_result(
        "airpose", capture, model, body, estimate, PER_FRAME_CAMERA + model.names[0], options_parameters(options), capture_label, cameras=placed_cameras,
        swaps=swaps,
    )  # fmt: skip
    if options.covariances and graph is not None:
        result.covariances.update(bg.covariances(graph, values, estimate))
    result = _with_left_out(result, full.times, keep)
    result.parameters.update(
        focal_px=bg.focal_lengths(estimate) if options.refine else {}, initialiser_used=used, seconds=round(seconds, 3),
        frames_per_second=round(model.num_states / max(seconds, 1e-9), 2), notes=notes, imu_clock_offsets_s=clock_offset_parameters(model, clock_offsets),
    )
    return result


def _bundle_adjust(bg: BodyGraph, estimate: Estimate, iterations: int, progress: str, relabel: bool = True) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, Estimate]:
    """AirPose+'s sequence bundle adjustment of ``bg`` from ``estimate`` (without ``relabel``:
    the detections' labels held as the model has them): the graph, its solution and the
    estimate read from it, the solver's log appended."""
    graph, values = bg.sequence(estimate)
    if not relabel:
        bg.relabel(False)
    stages = bg.stages(iterations, bg.time_ordering(values))
    solved = solve_staged(held(graph, values, bg.held_keys()), values, stages, progress=progress, project=bg.project_shape)
    estimate = bg.read(solved.values, estimate)
    estimate.log += list(solved.log)
    return graph, solved.values, estimate


def _checked(detected: StateModel, before: dict[int, np.ndarray], cameras: list[np.ndarray], half_window: int, keep_within_rad: float | None) -> dict[int, np.ndarray]:
    """``before`` with every camera :func:`posed_view_swaps` checks (with continuity, on the
    labels as detected) taking its codes, against ``cameras`` (per camera ``(F_c, 4, 4)``) each
    robustly smoothed over ``half_window`` frames each side (:func:`robust_pose_track`)."""
    smoothed = [robust_pose_track(poses, detected.frame_state[c] >= 0, half_window, keep_within_rad) for c, poses in enumerate(cameras)]
    return {**before, **posed_view_swaps(detected, smoothed, continuity=True)}


def _with_left_out(result: Result, times: np.ndarray, keep: np.ndarray) -> Result:
    """The result on every frame of camera 1: NaN body and covariances where a frame was left out."""
    idx = np.flatnonzero(keep)

    def spread(arr, fill=np.nan):
        out = np.full((len(keep),) + arr.shape[1:], fill, dtype=np.result_type(arr, type(fill)))
        out[idx] = arr
        return out

    result.timestamps = times
    result.joints, result.root, result.pose = spread(result.joints), spread(result.root), spread(result.pose)
    result.keypoints = spread(result.keypoints)
    result.flags = {k: spread(v, 0) for k, v in result.flags.items()}
    result.flags["unconstrained"] = result.flags["unconstrained"].astype(bool) | ~keep
    result.flags["left_out"] = ~keep
    for name in ("joints", "root"):
        if name in result.covariances:
            result.covariances[name] = spread(result.covariances[name])
    return result


def summary(result: Result) -> str:
    """What ``run airpose`` prints: a line and the notes."""
    p = result.parameters
    kind = "AirPose+" if p["refine"] else "AirPose (initialiser only)"
    reference = result.world_frame.removeprefix(PER_FRAME_CAMERA)
    lines = [
        f"airpose: {kind}, {int((~result.flags['left_out']).sum())} of {len(result.timestamps)} frames, "
        f"{len(result.cameras)} cameras, {p['seconds']:.1f} s ({p['frames_per_second']:.1f} frames/s); world: camera {reference}'s frame per frame"
    ]
    return "\n".join(lines + [f"  note: {note}" for note in p["notes"]])
