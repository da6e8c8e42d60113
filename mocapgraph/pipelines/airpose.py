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

import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import gtsam
import numpy as np

from mocapgraph.body import load_body_model
from mocapgraph.data_tools.io.capture import Capture, load_capture
from mocapgraph.data_tools.evaluation.evaluate import PER_FRAME_CAMERA
from mocapgraph.data_tools.io.result import Result, options_parameters, write_result
from mocapgraph.errors import MocapgraphError
from mocapgraph.graphs.initialisation import fuse_bodies, fused_shape, relative_cameras
from mocapgraph.graphs.solver import solve_staged
from mocapgraph.pipelines.uncalibrated import (
    INITIALISERS,
    Estimate,
    GraphOptions,
    Rig,
    RigGraph,
    add_covariances,
    held_shape,
    hold,
    log,
    rig_from_capture,
    rig_result,
    time_ordering,
    view_bodies,
)



@dataclass
class AirposeOptions:
    """Parameters of AirPose / AirPose+ (units in the names)."""

    # The mean body's PnP: as a starting point it beat the fusion regressor (whose root is ~17°
    # off per view) on airpose, before and after the bundle adjustment (bench airpose).
    initialiser: str = "pnp"
    regressor_variant: str = "full"  # the regressor's ablation variants: "no_exchange", "no_crop"
    refine: bool = True  # AirPose+ (False: the initialiser's estimate alone)
    min_confidence: float = 3.0  # summed keypoint confidence over the views a frame needs
    iterations: int = 30
    detectors: tuple[str, ...] | None = None
    covariances: bool = True
    progress: bool = True
    graph: GraphOptions = field(default_factory=GraphOptions)

    def check(self) -> None:
        if self.initialiser not in INITIALISERS:
            raise MocapgraphError(f"initialiser {self.initialiser!r}: choose one of {', '.join(INITIALISERS)}")
        if not (np.isfinite(self.min_confidence) and self.min_confidence >= 0):
            raise MocapgraphError(f"min_confidence: a finite number >= 0, got {self.min_confidence!r}")


def _kept(rig: Rig, keep: np.ndarray) -> Rig:
    """The rig's states where ``keep``; every camera moves relative to camera 1 unless both are static."""
    moving = [bool(m or rig.moving[rig.reference]) for m in rig.moving]
    idx = np.flatnonzero(keep)
    return replace(rig, moving=moving, times=rig.times[idx], frames=rig.frames[:, idx], states=[rig.states[i] for i in idx])


def run_airpose(capture: Capture, options: AirposeOptions | None = None, capture_label: str = "") -> Result:
    """Run AirPose (and AirPose+ when ``options.refine``) on a loaded capture; nothing written."""
    options = options or AirposeOptions()
    options.check()
    t_start = time.perf_counter()
    say = lambda m: log("airpose", options.progress, m)  # noqa: E731
    body = load_body_model()
    full = rig_from_capture(capture, options.detectors, reference=0)
    if not any(o.camera == 0 for obs in full.states for o in obs):
        raise MocapgraphError(f"capture {capture.name!r}: camera 1 ({full.names[0]}) has no detections; AirPose's world is camera 1's frame")
    weight = full.keypoint_weight()
    keep = weight >= options.min_confidence
    if keep.sum() < 2:
        raise MocapgraphError(
            f"capture {capture.name!r}: {int(keep.sum())} frames have a total keypoint confidence >= {options.min_confidence}; need 2"
        )
    rig = _kept(full, keep)
    notes = list(capture.notes)
    if (~keep).any():
        notes.append(f"{int((~keep).sum())} of {len(keep)} frames left out: total keypoint confidence below {options.min_confidence}")
    views, used = view_bodies(rig, body, options.initialiser, options.regressor_variant)
    notes.append(f"initialised from the {used}")
    ref_T_c, known = relative_cameras(views, rig.moving, 0)
    placed = [bool(known[c].any()) for c in range(rig.num_cameras)]
    for c in range(1, rig.num_cameras):
        if not placed[c]:
            notes.append(f"camera {rig.names[c]}: never saw the person together with camera 1; not estimated")
    if sum(placed) == 1:
        notes.append("camera 1 alone: depth along its rays rests on the body's size and the priors; expect large covariances along them")
    notes.append("absolute scale: from the body model's size (shape prior) alone; the shape's covariance carries it")
    rig = rig.only(placed)
    fused = fuse_bodies(views, ref_T_c, known)
    shape = fused_shape(body, fused)
    estimate = Estimate(fused.camera_T_root, fused.pose, shape, ref_T_c)
    for note in notes:
        say(note)
    n = len(rig.states)
    rg = RigGraph(rig, body, options.graph, fixed_cameras={0: np.tile(np.eye(4), (n, 1, 1))})
    graph = values = None
    log_rows: list[dict] = []
    if options.refine:
        graph = gtsam.NonlinearFactorGraph()
        for i in range(n):
            rg.add_state(graph, i)
            if i:
                rg.add_smoothness(graph, i)
        rg.add_shape_prior(graph)
        values = rg.values(estimate)
        say(f"AirPose+: {n} frames, {len(rg.camera_keys())} camera poses")
        stages = rg.stages(options.iterations, time_ordering(rg, values))
        solved = solve_staged(hold(graph, values, held_shape(options.graph)), values, stages, project=rg.project_shape)
        values = solved.values
        estimate = rg.read(values, estimate)
        log_rows = list(solved.log)
    seconds = time.perf_counter() - t_start
    result = rig_result("airpose", capture, rig, body, estimate, PER_FRAME_CAMERA + rig.names[0], options_parameters(options), capture_label, placed)
    result.log = log_rows
    if options.covariances and graph is not None:
        add_covariances(result, rg, graph, values, estimate)
    result = _with_left_out(result, full.times, keep)
    result.parameters.update(initialiser_used=used, seconds=round(seconds, 3), frames_per_second=round(n / max(seconds, 1e-9), 2), notes=notes)
    return result


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


def run_airpose_command(capture_path: Path, out: Path, options: AirposeOptions, overwrite: bool = False) -> Result:
    """``mocapgraph run airpose``: load, run, write, and print a short summary."""
    capture = load_capture(capture_path)
    result = run_airpose(capture, options, capture_label=str(capture_path))
    write_result(result, out, overwrite=overwrite)
    p = result.parameters
    kind = "AirPose+" if options.refine else "AirPose (initialiser only)"
    print(
        f"airpose: {kind}, {int((~result.flags['left_out']).sum())} of {len(result.timestamps)} frames, "
        f"{len(result.cameras)} cameras, {p['seconds']:.1f} s ({p['frames_per_second']:.1f} frames/s); world: camera {capture.cameras[0].name}'s frame per frame"
    )
    for note in p["notes"]:
        print(f"  note: {note}")
    return result
